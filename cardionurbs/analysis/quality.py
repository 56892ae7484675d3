"""Quality flags: the evidence behind every metric (docs/metrics.md, Quality flags).

Every metric comes from some surfaces at some frames (its *sources*): LVEDV
from the LV endocardium at ED, RVM from the RV endo- and epicardium and the LV
epicardium at ED, and so on (:data:`SOURCES`). The evidence for a metric is

* the fit residuals of those surfaces at those frames — the distance of every
  contour point to the boundary it was fitted by
  (:meth:`cardionurbs.anatomy.model.BiventricularModel.point_residuals`):
  median, 95th percentile and maximum, in mm and in pixels of each point's image;
* the contours left out of those surfaces (partial tracings,
  :func:`cardionurbs.anatomy.sections.frame_geometry`);
* for CO, the heart rate; for tag metrics, the tag lines flagged as mistracked.

A metric is *flagged* when any of its evidence fails:

* a surface it uses has a contour point farther than ``QC_LIMIT_PX`` (3) pixels
  from it, at a frame it uses — ``RV epi fit max 13.3 mm (9.4 px) > 3 px at frame 24``;
* a contour of one of its surfaces was left out at one of its frames;
* ``heart rate unknown`` (HR, CO); ``N tag line(s) flagged as mistracked`` (tag metrics);
* ``implausible time axis`` (the filling rates) when the reader found the frames ×
  interval outside a cardiac cycle (:func:`cardionurbs.io.nifti.time_step_ms`);
* ``SA stack contradicts the long-axis views`` (every measured metric of that frame's
  surfaces) when the most apical SA section lies far beyond the LA contours' apex
  (:meth:`cardionurbs.anatomy.model.BiventricularModel.stack_flag`).

Derived metrics (SV, EF, CO, MR RegVol and RegFrac, the RV/LV ratios) inherit
their inputs' flags: ``MR RegFrac`` is flagged when either ventricle's SV is.
A metric that is not measured (NaN) carries no flag except an unknown heart rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeGuard

import numpy as np

from cardionurbs.analysis.function import COLUMNS, TAG_COLUMNS
from cardionurbs.analysis.voxels import is_finite_number, label_map_flags

if TYPE_CHECKING:  # pragma: no cover
    from cardionurbs.anatomy.model import BiventricularModel

#: a contour point farther than this from its surface flags the surface, pixels
QC_LIMIT_PX = 3.0
SURFACE_LABELS = {"lv_endo": "LV endo", "lv_epi": "LV epi", "rv_endo": "RV endo",
                  "rv_epi": "RV epi"}
_LV_CAV, _RV_CAV = ("lv_endo",), ("rv_endo", "lv_epi")     # RV cavity = RV endo − LV epi
#: metric -> (surfaces, frames ('ED' / 'ES')) it is computed from
SOURCES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "LVEDV (mL)": (_LV_CAV, ("ED",)), "LVESV (mL)": (_LV_CAV, ("ES",)),
    "LVSV (mL)": (_LV_CAV, ("ED", "ES")), "LVEF (%)": (_LV_CAV, ("ED", "ES")),
    "LVCO (L/min)": (_LV_CAV, ("ED", "ES")), "LVM (g)": (("lv_endo", "lv_epi"), ("ED",)),
    "RVEDV (mL)": (_RV_CAV, ("ED",)), "RVESV (mL)": (_RV_CAV, ("ES",)),
    "RVSV (mL)": (_RV_CAV, ("ED", "ES")), "RVEF (%)": (_RV_CAV, ("ED", "ES")),
    "RVM (g)": (("rv_endo", "rv_epi", "lv_epi"), ("ED",)),
    "EI ES": (("lv_endo", "rv_endo"), ("ES",)),
}
#: derived metric -> the metrics it is computed from (it inherits their flags)
DERIVED: dict[str, tuple[str, ...]] = {
    "MR RegVol (mL)": ("LVSV (mL)", "RVSV (mL)"), "MR RegFrac (%)": ("LVSV (mL)", "RVSV (mL)"),
    "LVSV-RVSV (mL)": ("LVSV (mL)", "RVSV (mL)"),
    "RV/LV EDV ratio": ("RVEDV (mL)", "LVEDV (mL)"), "RV/LV mass ratio": ("RVM (g)", "LVM (g)"),
}
#: without valve disease or a shunt both ventricles eject the same volume: flagged beyond
#: this fraction of the mean of the two stroke volumes (and beyond SV_MIN_ML)
SV_BOUND, SV_MIN_ML = 0.10, 5.0
#: the myocardium is nearly incompressible: its volume at ES within this fraction of ED's,
#: LV and (thin, sparsely traced wall) RV
WALL_BOUND = {"lv_myocardium": 0.05, "rv_myocardium": 0.40}
_WALL = {"lv_myocardium": ("LVM (g)", "LV myocardium", "LV endo, LV epi"),
         "rv_myocardium": ("RVM (g)", "RV myocardium", "RV endo, RV epi, LV epi")}
_STATS = ("median", "p95", "max")
#: the cohort CSV's quality columns (after the metric columns)
QC_COLUMNS = tuple(f"{s} fit {q} ({u})" for s in SURFACE_LABELS.values() for u in ("mm", "px")
                   for q in _STATS) + ("left out", "QC")


def residual_stats(d_mm: np.ndarray, d_px: np.ndarray) -> dict[str, float]:
    """Median, 95th percentile and maximum of point distances, in mm and pixels.

    Parameters
    ----------
    d_mm : (n,) ndarray
        Point distances, mm.
    d_px : (n,) ndarray
        The same, pixels.

    Returns
    -------
    dict of str to float
        ``n_points`` and ``median``, ``p95``, ``max`` in ``_mm`` and ``_px`` (NaN without
        points).
    """
    out: dict[str, float] = {"n_points": int(len(d_mm))}
    for unit, d in (("mm", np.asarray(d_mm, float)), ("px", np.asarray(d_px, float))):
        q = np.percentile(d, [50, 95, 100]) if len(d) else [math.nan] * 3
        out.update({f"{k}_{unit}": float(v) for k, v in zip(_STATS, q)})
    return out


@dataclass
class Quality:
    """The evidence and the flags of one model's metrics (see module doc).

    Attributes
    ----------
    surfaces : dict of int to dict of str to dict
        ``surfaces[frame][surface]``: residual stats (:func:`residual_stats`).
    left_out : dict of int to list
        ``left_out[frame]``: [(structure, slice, why)].
    metrics : dict of str to dict
        ``metrics[column]``: ``flags`` (list of str), the ``surfaces`` and ``frames`` it
        comes from.
    limit_px : float
        The residual limit of the flags, pixels.
    cycle : list of str
        Flags of the cycle (frames supported by their neighbours) that no metric carries."""

    surfaces: dict[int, dict[str, dict]] = field(default_factory=dict)
    left_out: dict[int, list] = field(default_factory=dict)
    metrics: dict[str, dict] = field(default_factory=dict)
    limit_px: float = QC_LIMIT_PX

    #: flags of the cycle (frames supported by their neighbours) that no metric carries
    cycle: list[str] = field(default_factory=list)

    @property
    def flags(self) -> list[str]:
        """Every distinct flag of the metrics, in column order, then the cycle's."""
        out: list[str] = []
        for m in self.metrics.values():
            out += [f for f in m["flags"] if f not in out]
        return out + [f for f in self.cycle if f not in out]

    def flagged(self, column: str) -> bool:
        """Whether the metric ``column`` carries a quality flag.

        Parameters
        ----------
        column : str
            A docs/metrics.md column.

        Returns
        -------
        bool
        """
        return bool(self.metrics.get(column, {}).get("flags"))

    def row(self) -> dict:
        """The cohort row's quality columns (:data:`QC_COLUMNS`): each surface's residuals
        over ED and ES, the contours left out, and ``QC`` = the flags joined by '; '.

        Returns
        -------
        dict
        """
        out: dict = {c: math.nan for c in QC_COLUMNS}
        for s, label in SURFACE_LABELS.items():
            st = self._pooled.get(s)
            if st is None:
                continue
            for u in ("mm", "px"):
                for q in _STATS:
                    out[f"{label} fit {q} ({u})"] = st[f"{q}_{u}"]
        out["left out"] = "; ".join(f"frame {f} {s} {sl}" for f, lst in sorted(self.left_out.items())
                                    for s, sl, _ in lst)
        out["QC"] = "; ".join(self.flags)
        return out

    def to_json(self) -> dict:
        """JSON-safe: metrics.json's ``quality`` (limit, residuals, left-out contours, flags).

        Returns
        -------
        dict
        """
        return {"limit_px": self.limit_px,
                "surfaces": {str(f): d for f, d in self.surfaces.items()},
                "pooled": self._pooled,
                "left_out": {str(f): [list(x) for x in lst] for f, lst in self.left_out.items()},
                "metrics": self.metrics, "cycle": self.cycle, "QC": "; ".join(self.flags)}

    _pooled: dict[str, dict] = field(default_factory=dict)


def _residual_arrays(model, frames) -> list[dict]:
    """The model's point residuals at ``frames`` as numpy parts (structure, frame,
    dist_mm, dist_px: :meth:`BiventricularModel.point_residual_arrays`); a model without
    that method (or its table) gives them through :meth:`point_residuals`."""
    if not model.study.contours:
        return []
    if hasattr(model, "point_residual_arrays"):
        return model.point_residual_arrays(frames)
    pts = model.point_residuals(frames)
    return [{"structure": s, "frame": f, "dist_mm": g["dist_mm"].to_numpy(),
             "dist_px": g["dist_px"].to_numpy()}
            for (s, f), g in pts.groupby(["structure", "frame"], sort=False)]


def residual_summary(model: "BiventricularModel", frames=None) -> dict[str, dict[str, float]]:
    """Per surface, over the given frames (default ED and ES), the fit residuals as
    metrics.json's ``residuals`` has them: ``mean_mm`` the mean over the contours (one
    slice and view of one frame) of each contour's mean point distance, ``max_mm`` and
    ``max_px`` the largest point distance (mm, pixels); surfaces in name order. The same
    numbers as the per-contour table (:meth:`BiventricularModel.residual_table`), without
    pandas.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frames : iterable of int or None
        The frames; None: ED and ES.

    Returns
    -------
    dict of str to dict of str to float
        Surface -> ``mean_mm``, ``max_mm``, ``max_px``.
    """
    if frames is None:
        frames = sorted({model.ed_frame, model.es_frame})
    out: dict[str, dict[str, float]] = {}
    parts = _residual_arrays(model, frames) if hasattr(model, "point_residual_arrays") else None
    if parts is None:                      # a model without the numpy parts: the table
        res = model.residual_table(frames)
        return {s: {"mean_mm": float(g["mean_mm"].mean()), "max_mm": float(g["max_mm"].max()),
                    "max_px": float(g["max_px"].max())} for s, g in res.groupby("structure")}
    for s in sorted({p["structure"] for p in parts}):
        means, max_mm, max_px = [], [], []
        for p in (p for p in parts if p["structure"] == s):
            groups: dict = {}
            for i, k in enumerate(zip(p["slice"], p["view"])):
                if k[0] is not None:          # the table's groups leave out a contour without slice
                    groups.setdefault(k, []).append(i)
            for idx in groups.values():       # one contour: a slice and view of one frame
                means.append(float(np.mean(p["dist_mm"][idx])))
                max_mm.append(float(np.max(p["dist_mm"][idx])))
                max_px.append(float(np.max(p["dist_px"][idx])))
        if means:
            out[s] = {"mean_mm": float(np.mean(means)), "max_mm": max(max_mm), "max_px": max(max_px)}
    return out


def assess(model: "BiventricularModel", metrics: dict[str, float]) -> Quality:
    """The evidence and flags of every metric of ``model`` (module doc).

    Parameters
    ----------
    model : BiventricularModel
        The reconstructed model.
    metrics : dict
        Its docs/metrics.md column -> value (a column without a finite value carries no
        surface flag).

    Returns
    -------
    Quality
        The surfaces' residuals, the contours left out and each column's evidence.
    """
    ed, es = model.ed_frame, model.es_frame
    q = _surface_evidence(model, sorted({ed, es}))
    extra = _input_flags(model, metrics)
    for col in COLUMNS:
        q.metrics[col] = _column_entry(q, col, metrics, (ed, es), extra.get(col, []))
    _cycle_flags(model, q)
    _wall_flags(model, q, metrics)
    _stroke_volume_flags(model, q, metrics)
    _stack_flags(model, q, metrics)
    for col, flags in label_map_flags(model, metrics).items():   # label maps (analysis.voxels)
        if col in q.metrics and is_finite_number(metrics.get(col, math.nan)):
            q.metrics[col]["flags"] += flags
    _derived_entries(q, metrics)
    return q


def _surface_evidence(model: "BiventricularModel", frames: list[int]) -> Quality:
    """A Quality with the fit residuals of every surface at ``frames`` and pooled over them
    (surfaces in name order) and the contours left out of each frame's fit.

    Parameters
    ----------
    model : BiventricularModel
    frames : list of int
        ED and ES, ascending (one frame when they are the same).

    Returns
    -------
    Quality
        ``surfaces``, ``left_out`` and the pooled residuals filled, no metric yet.
    """
    q = Quality()
    parts = _residual_arrays(model, frames)
    for f in frames:
        q.surfaces[f] = {}
        q.left_out[f] = list(model.geometry[f].left_out) if model.study.contours else []
    for s in sorted({p["structure"] for p in parts}):
        mine = [p for p in parts if p["structure"] == s]           # in frame order
        for p in sorted(mine, key=lambda p: p["frame"]):
            q.surfaces[int(p["frame"])][s] = residual_stats(p["dist_mm"], p["dist_px"])
        q._pooled[s] = residual_stats(np.concatenate([p["dist_mm"] for p in mine]),
                                      np.concatenate([p["dist_px"] for p in mine]))
    return q


def _frames_of(which: tuple[str, ...], ed: int, es: int) -> list[int]:
    """The frames ("ED", "ES") of ``which``, ascending and distinct."""
    return sorted({ed if w == "ED" else es for w in which})


def _surface_flags(q: Quality, surfaces: tuple[str, ...], which: tuple[str, ...], ed: int,
                   es: int) -> list[str]:
    """The flags a metric measured on ``surfaces`` at ``which`` frames carries: each
    surface's worst fit beyond ``q.limit_px`` and its contours left out.

    Parameters
    ----------
    q : Quality
        With the surfaces' residuals and left-out contours (:func:`_surface_evidence`).
    surfaces : tuple of str
        The surfaces the metric comes from.
    which : tuple of str
        "ED" and/or "ES".
    ed, es : int
        The ED and ES frames.

    Returns
    -------
    list of str
    """
    out = []
    fr = _frames_of(which, ed, es)
    for s in surfaces:
        worst = None
        for f in fr:
            st = q.surfaces.get(f, {}).get(s)
            if st and st["max_px"] > q.limit_px and (worst is None or st["max_px"] > worst[1]["max_px"]):
                worst = (f, st)
        if worst:
            f, st = worst
            out.append(f"{SURFACE_LABELS[s]} fit max {st['max_mm']:.1f} mm "
                       f"({st['max_px']:.1f} px) > {q.limit_px:g} px at frame {f}")
        for f in fr:
            out += [f"{s} slice {sl} left out at frame {f}" for st_, sl, _ in q.left_out.get(f, [])
                    if st_ == s]
    return out


def _input_flags(model: "BiventricularModel", metrics: dict[str, float]) -> dict[str, list[str]]:
    """Column -> the flags of its inputs other than the surfaces: an unknown heart rate
    (HR, LVCO), an implausible time axis (the filling and ejection rates).

    Parameters
    ----------
    model : BiventricularModel
    metrics : dict
        docs/metrics.md column -> value.

    Returns
    -------
    dict
        Only the columns such inputs feed.
    """
    from cardionurbs.analysis.rates import RATE_COLUMNS
    hr_flag = [] if _finite(metrics.get("HR (bpm)", math.nan)) else ["heart rate unknown"]
    axis = (model.study.meta or {}).get("time_axis") or {}
    time_flag = ["implausible time axis"] if axis.get("plausible") is False else []
    out = {col: list(hr_flag) for col in ("HR (bpm)", "LVCO (L/min)")}
    for col in RATE_COLUMNS:
        out[col] = out.get(col, []) + time_flag
    return out


def _column_entry(q: Quality, col: str, metrics: dict[str, float], ed_es: tuple[int, int],
                  extra: list[str]) -> dict:
    """One column's evidence: {"flags", "surfaces", "frames"}.

    Parameters
    ----------
    q : Quality
        With the surfaces' residuals (:func:`_surface_evidence`).
    col : str
        A docs/metrics.md column.
    metrics : dict
        Column -> value (a column without a finite value carries no surface flag).
    ed_es : (int, int)
        The ED and ES frames.
    extra : list of str
        The flags of its other inputs (:func:`_input_flags`).

    Returns
    -------
    dict
        A tag column's flags are the tag QC's alone.
    """
    entry: dict = {"flags": [], "surfaces": [], "frames": []}
    if col in SOURCES:
        surfaces, which = SOURCES[col]
        entry["surfaces"] = list(surfaces)
        entry["frames"] = _frames_of(which, *ed_es)
        if _finite(metrics.get(col, math.nan)):
            entry["flags"] = _surface_flags(q, surfaces, which, *ed_es)
    entry["flags"] = entry["flags"] + extra
    if col in TAG_COLUMNS:
        n = metrics.get("Tag QC flags", math.nan)
        if _finite(n) and n > 0:
            entry["flags"] = [f"{int(n)} tag line(s) flagged as mistracked"]
    return entry


def _derived_entries(q: Quality, metrics: dict[str, float]) -> None:
    """A derived column's evidence (:data:`DERIVED`) is its inputs': their surfaces, frames
    and, where it has a finite value, their flags (each once)."""
    for col, inputs in DERIVED.items():
        e = q.metrics[col]
        e["inputs"] = list(inputs)
        e["surfaces"] = sorted({s for i in inputs for s in q.metrics[i]["surfaces"]})
        e["frames"] = sorted({f for i in inputs for f in q.metrics[i]["frames"]})
        if _finite(metrics.get(col, math.nan)):
            for i in inputs:
                e["flags"] += [f for f in q.metrics[i]["flags"] if f not in e["flags"]]


def _finite(x: object) -> TypeGuard[int | float]:
    return isinstance(x, (int, float)) and math.isfinite(x)


def partial_tracings(model, frame: int) -> set:
    """The (surface, slice) sections of a frame left out as partial tracings against its
    neighbouring frames (:func:`cardionurbs.anatomy.cycle.partial_sections`).

    Parameters
    ----------
    model : BiventricularModel
    frame : int

    Returns
    -------
    set of (str, str)
        (surface, slice) pairs; empty for a model read back or a frame not built.
    """
    from cardionurbs.anatomy.cycle import PARTIAL_PREFIX
    geo = getattr(model, "geometry", None)
    if geo is None or frame not in (getattr(geo, "computed", None) or []):
        return set()
    return {(s, sl) for s, sl, why in geo[frame].left_out if why.startswith(PARTIAL_PREFIX)}


def section_support_flag(frame: int, sections: dict, partial: set | None = None) -> str:
    """The QC flag of a frame whose sections were interpolated in time
    (:func:`cardionurbs.anatomy.cycle.support_sections`).

    Parameters
    ----------
    frame : int
    sections : dict (str, str) -> (int, int)
        (surface, slice) -> (frame before, frame after) each was interpolated from.
    partial : set of (str, str), optional
        The sections among them that the frame traced, but partially
        (:func:`partial_tracings`).

    Returns
    -------
    str
        One line naming the frame, every section and its two source frames.
    """
    partial = partial or set()
    names = ", ".join(f"{s} {sl} ({'a partial tracing, ' if (s, sl) in partial else ''}"
                      f"from frames {a} and {b})" for (s, sl), (a, b) in sorted(sections.items()))
    what = "not traced or partially traced" if partial else "not traced"
    return f"frame {frame} supported by its neighbours' sections: {what}, interpolated in time: {names}"


def _cycle_flags(model, q: Quality) -> None:
    """Every frame supported by its neighbours (:mod:`cardionurbs.anatomy.cycle`) is a flag:
    on the metrics of ED or ES when it is one of them, else on the cycle."""
    cycle = getattr(model, "cycle", None)
    if cycle is None:                    # no cycle check made, no frame supported by it
        return
    for f in sorted(getattr(model, "supported", {}) or {}):
        flag = cycle.describe(f)
        users = [m for m in q.metrics.values() if f in m["frames"]]
        for m in users:
            m["flags"].append(flag)
        if not users:
            q.cycle.append(flag)
    for f, secs in (getattr(model, "sections_in_time", None) or {}).items():
        flag = section_support_flag(f, secs, partial_tracings(model, f))
        users = [m for m in q.metrics.values() if f in m["frames"]]
        for m in users:
            m["flags"].append(flag)
        if not users:
            q.cycle.append(flag)


def _wall_flags(model, q: Quality, metrics: dict) -> None:
    """The myocardial volume at ES against ED's (:data:`WALL_BOUND`): a flag naming the
    surfaces on the mass beyond the bound."""
    ed, es = model.ed_frame, model.es_frame
    if ed == es or not hasattr(model, "consistent_volumes"):
        return
    v_ed, v_es = model.consistent_volumes(ed), model.consistent_volumes(es)
    for key, bound in WALL_BOUND.items():
        col, name, surfaces = _WALL[key]
        a, b = v_ed.get(key), v_es.get(key)
        if not (_finite(a) and _finite(b) and a > 0 and _finite(metrics.get(col))):
            continue
        change = b / a - 1.0
        if abs(change) > bound:
            q.metrics[col]["flags"].append(
                f"{name} ({surfaces}): volume at ES {b:.1f} mL is {100 * change:+.1f} % of ED's "
                f"{a:.1f} mL (bound {100 * bound:g} %)")


def _stroke_volume_flags(model, q: Quality, metrics: dict) -> None:
    """``stroke volumes disagree`` on LVSV, RVSV and their difference when
    |LVSV − RVSV| exceeds :data:`SV_BOUND` of their mean and SV_MIN_ML, unless mitral
    regurgitation is the stated pathology (then the difference is the finding)."""
    lv, rv = metrics.get("LVSV (mL)"), metrics.get("RVSV (mL)")
    if not (_finite(lv) and _finite(rv)):
        return
    if str(model.study.meta.get("pathology") or "").strip().lower() in ("mr", "mitral regurgitation"):
        return
    d, mean = lv - rv, 0.5 * (lv + rv)
    limit = max(SV_BOUND * abs(mean), SV_MIN_ML)
    if abs(d) > limit:
        flag = (f"stroke volumes disagree: LVSV {lv:.1f} mL, RVSV {rv:.1f} mL, difference "
                f"{d:+.1f} mL > {limit:.1f} mL ({100 * SV_BOUND:g} % of their mean)")
        for col in ("LVSV (mL)", "RVSV (mL)", "LVSV-RVSV (mL)"):
            q.metrics[col]["flags"].append(flag)


def _stack_flags(model, q: Quality, metrics: dict) -> None:
    """An SA stack its long-axis contours contradict at ED or ES
    (:meth:`~cardionurbs.anatomy.model.BiventricularModel.stack_flag`) flags every measured
    metric of its surfaces at that frame."""
    flag_of = getattr(model, "stack_flag", None)
    if flag_of is None:
        return
    for f in sorted({model.ed_frame, model.es_frame}):
        flag = flag_of(f)
        if flag is None:
            continue
        for col, entry in q.metrics.items():
            if col in SOURCES and f in entry["frames"] and _finite(metrics.get(col)):
                entry["flags"].append(flag)
