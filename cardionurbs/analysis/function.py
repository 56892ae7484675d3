"""Global cardiac function from a biventricular model (docs/metrics.md, paper §5).

:func:`measure` returns every column of the cohort CSV (docs/metrics.md, in
order) as a float, NaN where the input does not allow it: RV columns without
RV contours, CO without a heart rate, tag columns (filled in by
:mod:`cardionurbs.analysis.tags` where tag lines exist).

Formulas (volumes from closed manifold meshes, mL; mass density 1.05 g/mL)::

    SV  = EDV − ESV                       EF = 100 · SV / EDV
    CO  = SV · HR / 1000  (L/min)         M  = 1.05 · V_myo(ED)
    LVSV-RVSV = LVSV − RVSV               (always, where both SVs are measured)
    MR RegVol = max(0, LVSV − RVSV)       MR RegFrac = 100 · RegVol / LVSV
                                          (only where regurgitation is the stated question:
                                           :func:`regurgitation_stated`)
    EI  = D_parallel / D_perpendicular    (LV cavity chords through its centroid
                                           on the mid-ventricular SA slice at ES)
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cardionurbs.analysis.body import INDEXED, INDEXED_COLUMNS, add_body_columns
from cardionurbs.analysis.notes import Metrics, adopt_study_notes, explain_missing, is_null, null
from cardionurbs.analysis.regional_columns import REGIONAL_COLUMNS
from cardionurbs.analysis.uncertainty import interval_columns, intervals
from cardionurbs.errors import CardioNurbsError
from cardionurbs.limits import HEART_RATE_RANGE_BPM
from cardionurbs.geometry import chord_length, fit_plane, in_plane_basis, polygon_centroid

if TYPE_CHECKING:  # pragma: no cover
    from cardionurbs.anatomy.model import BiventricularModel

MYOCARDIAL_DENSITY_G_PER_ML = 1.05

#: The cohort CSV's metric columns, in docs/metrics.md order (``subject`` and
#: ``status`` come first in the CSV); the regional columns
#: (:mod:`cardionurbs.analysis.regional_columns`) come last.
COLUMNS = (
    "HR (bpm)",
    "LVEDV (mL)", "LVESV (mL)", "LVSV (mL)", "LVEF (%)", "LVCO (L/min)", "LVM (g)",
    "RVEDV (mL)", "RVESV (mL)", "RVSV (mL)", "RVEF (%)", "RVM (g)",
    "MR RegVol (mL)", "MR RegFrac (%)", "LVSV-RVSV (mL)",
    "RV/LV EDV ratio", "RV/LV mass ratio",
    "EI ES",
    "Twist (deg)", "Twist 2D (deg)", "Torsion (deg/cm)", "CL shear (deg)", "LS (%)",
    "Tag QC flags",
) + REGIONAL_COLUMNS
TAG_COLUMNS = ("Twist (deg)", "Twist 2D (deg)", "Torsion (deg/cm)", "CL shear (deg)", "LS (%)",
               "Tag QC flags")
NAN = float("nan")


def _ratio(a: float, b: float) -> float:
    return a / b if (np.isfinite(a) and np.isfinite(b) and b != 0) else NAN


def ventricular_function(edv: float, esv: float, hr_bpm: float) -> dict[str, float]:
    """SV (mL), EF (%) and CO (L/min) of one ventricle from EDV, ESV (mL) and HR (bpm).

    Parameters
    ----------
    edv, esv : float
        End-diastolic and end-systolic volume, mL.
    hr_bpm : float
        Heart rate, bpm (NaN: no CO).

    Returns
    -------
    dict of str to float
        ``SV`` (mL), ``EF`` (%, NaN for a zero or missing EDV), ``CO`` (L/min, NaN without HR).
    """
    sv = edv - esv
    ef = 100.0 * _ratio(sv, edv)
    co = sv * hr_bpm / 1000.0 if np.isfinite(hr_bpm) else NAN
    return {"SV": sv, "EF": ef, "CO": co}


def regurgitation(lvsv: float, rvsv: float) -> tuple[float, float]:
    """Mitral regurgitant volume (mL) and fraction (%): max(0, LVSV − RVSV), 100·RegVol/LVSV.

    Valid when no other valve leaks (the forward flow then equals RVSV).

    Parameters
    ----------
    lvsv, rvsv : float
        LV and RV stroke volume, mL.

    Returns
    -------
    regvol : float
        mL.
    regfrac : float
        %.
    """
    if not (np.isfinite(lvsv) and np.isfinite(rvsv)):
        return NAN, NAN
    reg = max(0.0, lvsv - rvsv)
    return reg, 100.0 * _ratio(reg, lvsv)


#: a study's stated pathology (``Study.meta["pathology"]``: a phantom's preset, a study's own
#: metadata or ``analyze --pathology``) makes regurgitation a stated question
NOT_STATED_NOTE = ("regurgitation is not the stated question (no pathology in the study's "
                   "metadata, nor analyze --pathology): LVSV - RVSV is reported as "
                   "'LVSV-RVSV (mL)'")


def regurgitation_stated(meta: dict) -> bool:
    """True when the study states its pathology (``meta["pathology"]``, any non-empty text:
    a phantom's preset, the study's metadata or ``analyze --pathology``), so that MR RegVol
    and RegFrac answer a question someone asked; otherwise LVSV − RVSV is only a difference
    of two measurements (docs/metrics.md).

    Parameters
    ----------
    meta : dict
        ``study.meta``.

    Returns
    -------
    bool
    """
    p = (meta or {}).get("pathology")
    return isinstance(p, str) and p.strip() != ""


def mass_g(myocardial_volume_ml: float) -> float:
    """Myocardial mass (g) = 1.05 g/mL · volume (mL).

    Parameters
    ----------
    myocardial_volume_ml : float
        Myocardial volume, mL.

    Returns
    -------
    float
        g.
    """
    return MYOCARDIAL_DENSITY_G_PER_ML * myocardial_volume_ml


def eccentricity_index(lv_xy: np.ndarray, rv_xy: np.ndarray) -> float:
    """LV eccentricity index on one SA slice (docs/metrics.md).

    ``lv_xy``, ``rv_xy``: LV and RV cavity boundaries in in-plane mm. The
    septum direction is perpendicular to (RV centroid − LV centroid); EI is the
    LV chord through its centroid along the septum over the chord across it.

    Parameters
    ----------
    lv_xy : (n, 2) ndarray
        The LV cavity boundary, in-plane mm.
    rv_xy : (m, 2) ndarray
        The RV cavity boundary, in-plane mm.

    Returns
    -------
    float
        EI (dimensionless).
    """
    c_lv, c_rv = polygon_centroid(lv_xy), polygon_centroid(rv_xy)
    across = c_rv - c_lv
    if np.linalg.norm(across) < 1e-9:
        return NAN
    along = np.array([-across[1], across[0]])
    return _ratio(chord_length(lv_xy, c_lv, along), chord_length(lv_xy, c_lv, across))


def eccentricity_index_es(model: "BiventricularModel") -> float:
    """EI at ES on the mid-ventricular SA slice (docs/metrics.md), NaN without RV contours.

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    float
    """
    fr = model.es_frame
    secs = model.sections.get(fr, {})
    lv = {s.slice: s for s in secs.get("lv_endo", []) if s.slice is not None}
    rv = {s.slice: s for s in secs.get("rv_endo", []) if s.slice is not None}
    common = [k for k in lv if k in rv]
    if not common:
        return NAN
    apex = model.apex_points.get(fr, {}).get("lv_endo")
    base = model.base_planes.get(fr, {}).get("lv")
    if apex is None or base is None:
        return NAN
    mid = 0.5 * (apex + base.origin)
    planes = {k: fit_plane(lv[k].points) for k in common}
    best = min(common, key=lambda k: abs((mid - planes[k][0]) @ planes[k][1]))
    c, nrm = planes[best]
    b = in_plane_basis(nrm).T
    return eccentricity_index((lv[best].points - c) @ b, (rv[best].points - c) @ b)


def measure(model: "BiventricularModel", *, heart_rate_bpm: float | None = None,
            uncertainty: bool = False) -> Metrics:
    """Every docs/metrics.md column for one model, as floats (NaN where not measurable),
    with the reason of every NaN in ``.notes`` (:mod:`cardionurbs.analysis.notes`).

    Tag columns are NaN here (:func:`cardionurbs.pipeline.analyse` adds them). The body-size
    columns (:mod:`cardionurbs.analysis.body`) follow from ``model.study.meta["body"]``.

    Parameters
    ----------
    model : BiventricularModel
        The model of :func:`cardionurbs.anatomy.model.reconstruct`.
    heart_rate_bpm : float or None
        Heart rate (bpm), used when the study carries none (the user-given value of
        docs/metrics.md, Frames).
    uncertainty : bool
        Also the 95 % interval of each global metric as ``<column> lo95`` and
        ``<column> hi95`` (NaN where there is none; docs/metrics.md, Uncertainty;
        :func:`cardionurbs.analysis.uncertainty.intervals` gives the reasons and sources).

    Returns
    -------
    Metrics
        A dict column -> float in the column's unit (mL, g, %, ms, mm, deg; NaN where the
        study cannot give one), with ``.notes`` column -> reason of each NaN.

    Raises
    ------
    CardioNurbsError
        ``heart_rate_bpm`` outside 20-300 bpm.

    Examples
    --------
    A phantom's LV end-diastolic volume against its closed-form truth:

    >>> import pathlib, tempfile
    >>> import cardionurbs as cn
    >>> from cardionurbs.phantom import generate, write_phantom
    >>> phantom = generate("normal", seed=1, frames=2, n_sa=6, matrix=128, volume_check=False)
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = write_phantom(phantom, pathlib.Path(tmp.name) / "p1", dicom=False)
    >>> m = cn.measure(cn.reconstruct(cn.load_study(folder)))
    >>> truth = phantom.truth["metrics"]["LVEDV (mL)"]
    >>> bool(abs(m["LVEDV (mL)"] - truth) < 0.01 * truth)
    True
    >>> tmp.cleanup()
    """
    if heart_rate_bpm is not None and not (
            HEART_RATE_RANGE_BPM[0] <= heart_rate_bpm <= HEART_RATE_RANGE_BPM[1]):
        raise CardioNurbsError(f"heart_rate_bpm must be between {HEART_RATE_RANGE_BPM[0]:g} and "
                               f"{HEART_RATE_RANGE_BPM[1]:g} bpm, got {heart_rate_bpm!r}")
    hr = model.study.heart_rate_bpm
    if hr is None or not np.isfinite(hr):
        hr = heart_rate_bpm
    hr = float(hr) if hr is not None else NAN
    ed, es = model.ed_frame, model.es_frame
    vol = {f: (model.consistent_volumes(f) if hasattr(model, "consistent_volumes")
               else model.volumes.get(f, {})) for f in {ed, es}}

    def v(frame: int, key: str) -> float:
        return float(vol.get(frame, {}).get(key, NAN))

    out = {c: NAN for c in COLUMNS}
    out["HR (bpm)"] = hr
    for side, cav, myo in (("LV", "lv_cavity", "lv_myocardium"), ("RV", "rv_cavity", "rv_myocardium")):
        edv, esv = v(ed, cav), v(es, cav)
        f = ventricular_function(edv, esv, hr)
        if ed == es:           # one frame: no stroke volume to measure (null, the model warns)
            f = {"SV": NAN, "EF": NAN, "CO": NAN}
        out[f"{side}EDV (mL)"], out[f"{side}ESV (mL)"] = edv, esv
        out[f"{side}SV (mL)"], out[f"{side}EF (%)"] = f["SV"], f["EF"]
        if side == "LV":
            out["LVCO (L/min)"] = f["CO"]
        out[f"{side}M (g)"] = mass_g(v(ed, myo))
    lvsv, rvsv = out["LVSV (mL)"], out["RVSV (mL)"]
    out["LVSV-RVSV (mL)"] = lvsv - rvsv
    stated = regurgitation_stated(model.study.meta)
    if stated:
        out["MR RegVol (mL)"], out["MR RegFrac (%)"] = regurgitation(lvsv, rvsv)
    out["RV/LV EDV ratio"] = _ratio(out["RVEDV (mL)"], out["LVEDV (mL)"])
    out["RV/LV mass ratio"] = _ratio(out["RVM (g)"], out["LVM (g)"])
    out["EI ES"] = eccentricity_index_es(model)
    from cardionurbs.analysis.rates import model_filling_rates
    rates, why_no_rates = model_filling_rates(model)
    out.update(rates)
    metrics = Metrics({k: (float(x) if x is not None and math.isfinite(float(x)) else NAN)
                       for k, x in out.items()})
    if why_no_rates:
        for column in rates:
            null(metrics, column, why_no_rates)
    if not stated and np.isfinite(lvsv - rvsv):     # null with its reason (metrics.json notes)
        for column in ("MR RegVol (mL)", "MR RegFrac (%)"):
            null(metrics, column, NOT_STATED_NOTE)
    add_body_columns(metrics, model.study.meta.get("body"))
    explain_nulls(model, metrics)
    if uncertainty:
        metrics.update(interval_columns(intervals(model, metrics)))
    return metrics


#: columns that compare ED with ES (or need the cycle): null with one contoured frame
_ONE_FRAME_KEEP = ("HR (bpm)", "LVEDV (mL)", "LVM (g)", "RVEDV (mL)", "RVM (g)", "RV/LV EDV ratio",
                   "RV/LV mass ratio", "Tag QC flags")


def explain_nulls(model: "BiventricularModel", metrics: dict) -> dict:
    """Null with a reason what ``model``'s study cannot give (docs/metrics.md, Notes):
    with one contoured frame (ED = ES) every column that compares ED with ES is null
    ("one frame only"), not 0; the readers' reasons (``study.meta["metric_notes"]``) are
    adopted; every other NaN gets the first reason that applies (no RV contours, no heart
    rate, no tag lines, ...). Called by :func:`measure` and again once the tag and
    regional columns are in (:func:`cardionurbs.pipeline.analyse`). Returns ``metrics``.

    Parameters
    ----------
    model : BiventricularModel
        The model measured.
    metrics : dict
        Its metrics (a :class:`~cardionurbs.analysis.notes.Metrics`), changed in place.

    Returns
    -------
    dict
        ``metrics``.
    """
    study = model.study
    notes = getattr(metrics, "notes", {})
    for column in [c for c in notes if c in metrics and not is_null(metrics[c])]:
        del notes[column]                       # measured after all (tags, regional)
    adopt_study_notes(metrics, study.meta)
    if model.ed_frame == model.es_frame:
        keep = _ONE_FRAME_KEEP + ("LVEDVi (mL/m²)", "LVMi (g/m²)", "RVEDVi (mL/m²)",
                                  "WT_Global (mm)")
        for column in [c for c in COLUMNS + INDEXED_COLUMNS if c in metrics]:
            if column not in keep and not column.startswith("WT_AHA_"):
                null(metrics, column, "one frame only (ED = ES)")
    for column, source in INDEXED.items():
        if column in metrics and is_null(metrics[column]) and source in notes:
            null(metrics, column, notes[source])
    rv = {c.structure for c in study.contours} & {"rv_endo", "rv_epi", "rv_septum", "rv_freewall"}
    rv_cols = [c for c in metrics if c.startswith("RV") or c.startswith("MR ")]
    tag_cols = list(TAG_COLUMNS) + [c for c in metrics if c.startswith(("Ecc_", "Ell_", "Err_"))]
    explain_missing(metrics, [
        (["HR (bpm)", "LVCO (L/min)", "CI (L/min/m²)"],
         "no heart rate (not in the study; give --heart-rate)"),
        (rv_cols + ["EI ES"], "no RV contours" if not rv else "RV not measured"),
        (tag_cols, "no tag lines" if not study.tags else "tags not measured"),
    ])
    explain_missing(metrics, [(list(metrics), "not measurable from this study")])
    return metrics


def volume_curve(model: "BiventricularModel", every_structure: bool = True) -> dict[str, list]:
    """The volume–time curve: per reconstructed frame, trigger time (ms, None where
    unknown) and the four volumes (mL; NaN where a structure is missing): ``<mesh> (mL)``
    the consistent ones (a supported frame's from its neighbours,
    :mod:`cardionurbs.anatomy.cycle`), ``<mesh> raw (mL)`` each frame's own (the LV cavity
    of a frame with sections interpolated in time from its own contours alone, its other
    volumes with those sections), ``supported`` the frames that needed their
    neighbours' support, and ``rv_basal_supported`` those whose RV cavity took its
    neighbours' basal region (:meth:`BiventricularModel.rv_basal_support`; in a
    metrics-only analysis only ED and ES are asked).

    ``every_structure=False`` (a metrics-only analysis) reports what the metrics already
    measured and builds nothing more: the LV cavity at every frame (the cavities ED, ES
    and the filling rates come from) and the other three volumes at ED and ES only (NaN
    at the other frames). Building every frame's other surfaces and booleans just for
    this curve would cost several times the whole metrics analysis.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    every_structure : bool
        As above.

    Returns
    -------
    dict of str to list
        ``frame``, ``time (ms)``, the ``<mesh> (mL)`` and ``<mesh> raw (mL)`` columns,
        ``supported`` and ``rv_basal_supported``.
    """
    frames = list(getattr(model, "curve_frames", model.frames))
    built = set(model.frames)
    times = [model.study.frame_times_ms.get(f) for f in frames]
    out: dict[str, list] = {"frame": frames, "time_ms": times}
    keys = ("lv_cavity", "rv_cavity", "lv_myocardium", "rv_myocardium")
    supported = getattr(model, "supported", {})
    every_structure = every_structure or not hasattr(model, "lv_cavity_volume")
    reported = {model.ed_frame, model.es_frame}
    if every_structure:
        raw = {f: (model.volumes.get(f, {}) if f in built else {}) for f in frames}
    else:
        raw = {f: (dict(model.volumes[f]) if f in reported else
                   {"lv_cavity": model.lv_cavity_volume(f)} if f in built else {})
               for f in frames}
    consistent = {}
    for f in frames:
        if f not in supported:      # its own (the RV's basal region may be supported)
            consistent[f] = (model.consistent_volumes(f) if f in built and (
                every_structure or f in reported) and hasattr(model, "consistent_volumes")
                else raw[f])
        elif every_structure or f in reported:
            consistent[f] = model.consistent_volumes(f)
        else:               # metrics only: the neighbours' other solids are not built for this
            consistent[f] = {"lv_cavity": model.consistent_lv_cavity_volume(f)}
    for key in keys:
        out[f"{key} (mL)"] = [float(consistent[f].get(key, NAN)) for f in frames]
    for f in getattr(model, "sections_in_time", {}):     # raw: the frame's own contours
        if "lv_cavity" in raw.get(f, {}):
            raw[f] = {**raw[f], "lv_cavity": model.own_lv_cavity_volume(f)}
    for key in keys:
        out[f"{key} raw (mL)"] = [float(raw[f].get(key, NAN)) for f in frames]
    out["supported"] = sorted(supported)
    rv_basal = getattr(model, "rv_basal_support", None)
    out["rv_basal_supported"] = sorted(             # the frames whose RV basal region is
        f for f in frames if f in built and f not in supported and rv_basal is not None
        and (every_structure or f in reported) and rv_basal(f) is not None)   # supported
    return out
