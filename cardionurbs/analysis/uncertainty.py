"""Per-subject 95 % intervals of the global metrics (docs/metrics.md, Uncertainty).

An analytic propagation of what one study's own data leave open, with no refit: every
cavity and wall volume is read as a sum of slabs between short-axis sections (Cavalieri),
and each of four independent error sources gets a standard deviation from that study's
sections, contour points and frames:

* **contours** -- the scatter of the contour points: the normal noise σ of each SA
  contour (the larger of its points' RMS distance to the fitted surface and the scatter
  of their second differences along the contour, which a tolerance fit does not absorb)
  gives an area variance σ² · P · ds (P the perimeter, ds the point spacing: the area is
  the integral of the normal error, whose independent parts are ds apart), times the
  slab thickness squared, times :data:`CONTOUR_FACTOR`;
* **between** -- the unobserved space between slices: the trapezoid error of each gap,
  h · |Δ²A| / 12 (A the section areas, h the spacing), scaled by :data:`BETWEEN_FACTOR`
  (the lofted surface follows the area curve's curvature, not a straight line);
* **base** and **apex** -- the unobserved space beyond the end slices: a valve plane or
  apex placed by a rule (half a slice beyond the end section, or the taper of a label
  map) lies anywhere within about one slice spacing, uniformly: σ = A_end · h / √12
  (apex: times :data:`CAP_SHAPE`, a tapering cap); with landmarks or long-axis
  contours the end is observed, σ from their scatter about the surface;
* **lv shape** -- the LV cavity's reconstruction error by input kind (label maps with and
  without long-axis maps, SA contours with a rule-placed base): :data:`LV_SHAPE_REL` of its
  volume at ED and ES, their errors correlated by :data:`LV_SHAPE_CORR` (by input kind; a
  model-error term set on the calibration phantoms);
* **rv shape** -- an RV cavity no landmark or long-axis contour closes (label maps, SA-only
  contours): :data:`RV_SHAPE_REL` of its volume by input kind (a model-error term set on the
  calibration phantoms);
* **the LV wall's own width** -- the LV myocardium's SD (all of the above, propagated to
  the wall) times :data:`LVM_FACTOR` of its input kind: a wall's error is not its
  cavity's (set on the calibration phantoms);
* **one-sided allowances** -- an end the stack leaves open beyond one slice gap, an outflow
  tract the model did not build, an epicardial cap beyond a rule-placed apex;
* **ES sampling** -- on a sampled cycle whose ES (ED) frame is the volume minimum
  (maximum), the true extreme lies within half a frame interval: one-sided, up to
  |Δ²V| / 8 (the parabola through the three frames), added to the lower end of ESV.

EF and SV follow by the delta method (their ED and ES errors independent except where
the model ties the two frames: the label maps' ES valve plane is placed from ED, so their
base errors are one). Twist, LS and the global tag strains:
:mod:`cardionurbs.analysis.tag_uncertainty`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from cardionurbs.analysis.tag_uncertainty import TAG_COVERED, tag_intervals
from cardionurbs.geometry import polygon_area

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Sequence

    from cardionurbs.anatomy.model import BiventricularModel
    from cardionurbs.study import Contour, Landmark

METHOD = ("analytic propagation: contour scatter, between-slice interpolation, base and apex "
          "placement, ES sampling; tag-point scatter of the twist levels, level placement (LS), "
          "tag-fit standard errors and motion-model error (global strain) "
          "(docs/metrics.md, Uncertainty)")
#: the columns given an interval
COVERED = ("LVEDV (mL)", "LVESV (mL)", "LVSV (mL)", "LVEF (%)", "LVM (g)",
           "RVEDV (mL)", "RVESV (mL)", "RVSV (mL)", "RVEF (%)", "RVM (g)")
Z95 = 1.959963984540054
#: relative SD of an RV cavity by input kind (:func:`lv_input_kind`; label maps, SA-only
#: contours; ``observed``: a cavity the landmarks or long-axis contours close): ED and ES
#: independent
RV_SHAPE_REL = {"labels": 0.05, "labels 5mm": 0.03, "labels+LA": 0.05, "contours": 0.05,
                "observed": 0.01}
#: relative SD of an LV cavity by input kind (:func:`lv_input_kind`, ``observed`` for None):
#: the reconstruction's
#: own error at a base no SA section closes, one error at ED and ES (a model-error term set
#: on the calibration phantoms, docs/metrics.md, Uncertainty)
LV_SHAPE_REL = {"labels": 0.02, "labels 5mm": 0.02, "labels+LA": 0.02, "contours": 0.08,
                "observed": 0.005}
#: correlation of the lv shape errors at ED and ES by input kind (as :data:`LV_SHAPE_REL`;
#: 1: one error, the same share of the cavity missed at both, which cancels in EF; 0:
#: independent), set on the calibration phantoms (docs/metrics.md, Uncertainty)
LV_SHAPE_CORR = {"labels": 0.5, "labels 5mm": 1.0, "labels+LA": 0.0, "contours": 0.5,
                 "observed": 1.0}
#: the ED share of the lv shape term over :data:`LV_SHAPE_REL` (the ES share) by input kind:
#: a rule-placed base misses more of the small ES cavity, relatively, than of the ED one
#: (set on the calibration phantoms, docs/metrics.md, Uncertainty)
LV_SHAPE_ED_FACTOR = {"labels": 1.0, "labels 5mm": 0.25, "labels+LA": 1.0, "contours": 0.5,
                      "observed": 0.25}
#: factor over the LV wall's propagated SD (every source above; not the one-sided
#: allowances) by input kind (:func:`lv_input_kind`, ``observed`` for contours whose base the
#: data fix): the wall's error is not its cavity's (epicardium and endocardium share most of
#: a slice's misplacement and its between-slice shape), so LVM gets its own width, set on the
#: calibration phantoms (docs/metrics.md, Uncertainty)
LVM_FACTOR = {"labels": 1.25, "labels 5mm": 0.15, "labels+LA": 1.0, "contours": 0.7,
              "observed": 1.0}
#: the SA slice spacing (mm) each ``labels`` entry of the per-kind tables above is set at
#: (``labels``: 10 mm, the ACDC and UK Biobank spacing; ``labels 5mm``: 5 mm). A label map
#: without long-axis maps takes the two entries interpolated linearly in its own SA spacing,
#: the nearer one beyond them (:func:`kind_entry`); ``labels+LA`` is set at 10 mm only
LABELS_SPACING_MM = {"labels 5mm": 5.0, "labels": 10.0}
#: the contours term's factor over independent point noise (docs/metrics.md, Uncertainty)
CONTOUR_FACTOR = 1.0
#: fraction of the trapezoid error that a lofted (cubic) surface keeps between slices
BETWEEN_FACTOR = 1.0
#: cap volume per (end area × cap length): 1/2 for a paraboloid, 1/3 for a cone
CAP_SHAPE = 0.5
#: factor over the base term's SD (1: the valve plane anywhere in the reach, a full slab
#: of the basal area; below 1: the basal cap tapers, as the apex's does), set on the
#: calibration phantoms (docs/metrics.md, Uncertainty)
BASE_FACTOR = 0.25
#: how far (mm) at least an end the stack leaves open may reach beyond its end section
OPEN_SLAB_MM = 10.0
#: systematic boundary placement of a label map's contours, in pixels (1 SD)
PIXEL_BIAS = 0.1
#: share of the basal LV section that continues into an unseen outflow tract
OUTFLOW_SHARE = 0.0
SQRT12 = math.sqrt(12.0)
NAN = float("nan")


@dataclass
class VolumeError:
    """One solid's volume error at one frame: standard deviations (mL) by source, the
    sources shared with the other frame (one error, not two), and one-sided allowances
    (mL) the volume may lie above or below the Gaussian interval.

    Attributes
    ----------
    sd : dict of str to float
        Source -> standard deviation, mL.
    shared : frozenset of str
        The sources shared with the other frame.
    above, below : float
        The one-sided allowances, mL.
    corr : float
        The correlation of its ``lv shape`` source with the other frame's (when shared).
    """

    sd: dict[str, float] = field(default_factory=dict)
    shared: frozenset = frozenset()
    above: float = 0.0
    below: float = 0.0
    corr: float = 1.0

    def total(self) -> float:
        """The root sum of squares of the sources' standard deviations, mL.

        Returns
        -------
        float
        """
        return math.sqrt(sum(v * v for v in self.sd.values()))


def _normal_scatter(points: np.ndarray, normal: np.ndarray) -> tuple[float, float]:
    """(σ mm, point spacing mm) of a closed planar contour: the in-plane normal component of
    the points' second differences, σ² = E[(n·Δ²x)²] / 6 for independent noise
    (robust: from the median of squares, 0.4549 the χ²₁ median)."""
    p = np.asarray(points, float)
    if len(p) < 5:
        return 0.0, 0.0
    steps = np.roll(p, -1, axis=0) - p
    ds = float(np.median(np.linalg.norm(steps, axis=1)))
    d2 = np.roll(p, -1, axis=0) - 2 * p + np.roll(p, 1, axis=0)
    tangent = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
    tn = tangent / np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    inplane = np.cross(normal, tn)
    dn = np.einsum("ij,ij->i", d2, inplane)
    sigma2 = float(np.median(dn * dn)) / 0.4549 / 6.0
    return math.sqrt(max(sigma2, 0.0)), ds


def _perimeter(points: np.ndarray) -> float:
    p = np.asarray(points, float)
    return float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())


def _residual_rms(model: "BiventricularModel", frame: int, structure: str) -> dict:
    """slice -> RMS distance (mm) of that SA slice's contour points to the fitted surface."""
    out: dict = {}
    for p in model.point_residual_arrays():
        if p["frame"] != frame or p["structure"] != structure:
            continue
        sa = p["view"] == "SA"
        for sl in sorted(set(p["slice"][sa])):
            d = p["dist_mm"][sa & (p["slice"] == sl)]
            out[sl] = float(np.sqrt(np.mean(d * d)))
    return out


def _la_scatter(model: "BiventricularModel", frame: int, structure: str) -> float:
    """RMS distance (mm) of the long-axis contour points of one surface to it (0 without)."""
    for p in model.point_residual_arrays():
        if p["frame"] == frame and p["structure"] == structure:
            d = p["dist_mm"][p["view"] == "LA"]
            if len(d):
                return float(np.sqrt(np.mean(d * d)))
    return 0.0


def section_table(model: "BiventricularModel", frame: int, structure: str) -> dict:
    """The SA sections of one surface at one frame (base -> apex): levels (n,) mm along
    the stacking direction, areas (n,) mm², perimeters (n,) mm, σ (n,) mm and point
    spacing ds (n,) mm of their contour points; contoured sections only.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        The frame.
    structure : str
        The surface (``lv_endo`` ...).

    Returns
    -------
    dict of str to (n,) ndarray
        ``level``, ``area``, ``perimeter``, ``sigma``, ``ds`` ({} without sections).
    """
    geo = model.geometry[frame]
    n = geo.direction
    secs = [s for s in model.sections[frame].get(structure, []) if not s.synthetic
            and s.source_points is not None]
    rms = _residual_rms(model, frame, structure)
    rows = []
    for s in secs:
        sig, ds = _normal_scatter(s.source_points, s.plane.normal if s.plane is not None else n)
        sig = max(sig, rms.get(s.slice, 0.0))
        rows.append((float(np.mean(s.points, axis=0) @ n), polygon_area(s.points, n),
                     _perimeter(s.points), sig, ds))
    if not rows:
        return {}
    a = np.array(rows)
    return dict(zip(("level", "area", "perimeter", "sigma", "ds"), a.T))


def _observed(model: "BiventricularModel", frame: int, structure: str, end: str) -> bool:
    """Whether an end of a surface is fixed by the data (landmarks or long-axis contours)
    rather than placed by a rule."""
    geo = model.geometry[frame]
    if end == "base":
        return structure[:2] not in geo.base_from_slices
    if structure in geo.taper:
        return False
    if model.study.landmarks_at(frame, "apex") and structure.startswith("lv"):
        return True
    return bool(geo.la_points.get(structure))


def _open_slab(model: "BiventricularModel", frame: int, structure: str, level: float,
               sign: float, h: float) -> float:
    """How far (mm) beyond an end section (at ``level``, ``sign`` -1 towards the base, +1
    towards the apex) the surface may reach: to the nearest imaged SA plane beyond it that
    shows none of the structure, else at least :data:`OPEN_SLAB_MM` (the stack ends there
    and says nothing more)."""
    n = model.geometry[frame].direction
    drawn = {c.slice for c in model.study.contours_at(frame, structure)}
    beyond = [sign * (float(im.position @ n) - level) for im in model.study.images_at(frame, "SA")
              if im.slice not in drawn]
    beyond = [d for d in beyond if d > 0.25 * h]
    return min(beyond) if beyond else max(h, OPEN_SLAB_MM)


def _pixel_mm(model: "BiventricularModel", frame: int) -> float:
    ims = model.study.images_at(frame, "SA")
    return float(np.median([min(im.pixel_spacing) for im in ims])) if ims else 1.0


def volume_error(model: "BiventricularModel", frame: int, structure: str) -> dict[str, float]:
    """Standard deviations (mL) of the volume inside one surface at one frame, by source
    (contours, pixels, between, base, apex; see the module docstring) and the one-sided
    allowances ``open base``, ``open apex`` (mL, volume the model may miss beyond an end
    the stack leaves open); {} without sections.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        The frame.
    structure : str
        The surface (``lv_endo`` ...).

    Returns
    -------
    dict of str to float
        Source -> mL.
    """
    t = section_table(model, frame, structure)
    if not t or len(t["area"]) < 2:
        return {}
    lev, area = t["level"], t["area"]
    gaps = np.abs(np.diff(lev))
    h = float(np.median(gaps))
    w = np.empty(len(lev))                         # slab of each section (trapezoid weights)
    w[1:-1] = 0.5 * (gaps[:-1] + gaps[1:])
    w[0], w[-1] = 0.5 * gaps[0] + 0.5 * h, 0.5 * gaps[-1] + 0.5 * h
    var_area = t["sigma"] ** 2 * t["perimeter"] * np.maximum(t["ds"], 1e-3)
    sd = {"contours": CONTOUR_FACTOR * math.sqrt(float(np.sum(w * w * var_area))) / 1000.0}
    labels = bool(model.study.meta.get("voxel_volumes_ml")) if isinstance(model.study.meta, dict) \
        else False
    sd["pixels"] = (PIXEL_BIAS * _pixel_mm(model, frame) * float(np.sum(w * t["perimeter"])) / 1000.0
                    if labels else 0.0)
    if len(area) >= 3:
        d2 = np.abs(area[2:] - 2 * area[1:-1] + area[:-2])
        per_gap = BETWEEN_FACTOR * gaps[1:] * d2 / 12.0
        sd["between"] = math.sqrt(float(np.sum(per_gap ** 2))) / 1000.0
    else:
        sd["between"] = BETWEEN_FACTOR * h * float(area.max()) / 12.0 / 1000.0
    la = _la_scatter(model, frame, structure)
    half = 0.5 * model.geometry[frame].thickness     # where the half-slice rule puts an end
    for end, i, sign, shape in (("base", 0, -1.0, 1.0), ("apex", -1, 1.0, CAP_SHAPE)):
        a_end = float(area[i])
        if _observed(model, frame, structure, end):
            r = math.sqrt(a_end / math.pi) if a_end > 0 else 1.0
            sd[end] = shape * a_end * (h / 2.0) * 2.0 * la / r / 1000.0   # area 2δr/r, half a gap
            sd[f"open {end}"] = 0.0
            continue
        # the end lies anywhere in [0, reach] beyond the end section, uniformly; the rule put
        # it at ``half`` (the taper of a label map nearer the truth: the same allowance)
        reach = _open_slab(model, frame, structure, float(lev[i]), sign, h)
        sd[end] = shape * a_end * reach / SQRT12 / 1000.0
        sd[f"open {end}"] = shape * a_end * max(0.5 * reach - half, 0.0) / 1000.0
    sd["base"] *= BASE_FACTOR                      # the SD only; the allowance stays
    return sd


#: solid -> (outer surface, inner surface or None)
SOLIDS = {"lv_cavity": ("lv_endo", None), "rv_cavity": ("rv_endo", None),
          "lv_myocardium": ("lv_epi", "lv_endo"), "rv_myocardium": ("rv_epi", "rv_endo")}


def _end_areas(model: "BiventricularModel", frame: int, structure: str) -> tuple[float, float]:
    """(basal, apical) section area (mm²) of one surface (0, 0 without sections)."""
    t = section_table(model, frame, structure)
    return (float(t["area"][0]), float(t["area"][-1])) if t else (0.0, 0.0)


def _split(e: dict[str, float]) -> tuple[dict[str, float], float]:
    """(the SDs, the one-sided allowance) of a :func:`volume_error` result."""
    return ({k: v for k, v in e.items() if not k.startswith("open")},
            sum(v for k, v in e.items() if k.startswith("open")))


def solid_error(model: "BiventricularModel", frame: int, solid: str) -> VolumeError | None:
    """The :class:`VolumeError` of one solid (``lv_cavity``, ``rv_cavity``, ``lv_myocardium``,
    ``rv_myocardium``) at one frame; None when its surfaces have no sections. A wall is the
    outer surface less the inner: their errors add in quadrature, except the base plane,
    which cuts both (its error is the wall's basal area times the plane's); an apex the
    stack leaves open may add wall (the epicardium's) or take it (the endocardium's).

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        The frame.
    solid : str
        ``lv_cavity``, ``rv_cavity``, ``lv_myocardium`` or ``rv_myocardium``.

    Returns
    -------
    VolumeError or None
    """
    outer, inner = SOLIDS[solid]
    a = volume_error(model, frame, outer)
    if not a:
        return None
    shared = {"pixels", "lv shape"} | ({"base"} if frame in getattr(model, "base_shift_mm", {})
                                       else set())
    if inner is None:
        sd, above = _split(a)
        if solid == "rv_cavity":
            sd["rv shape"] = _rv_shape(model, frame)
        else:
            sd["lv shape"] = _lv_shape(model, frame)
        return VolumeError(sd, frozenset(shared), above + _outflow_allowance(model, frame, solid),
                           0.0, lv_shape_corr(model))
    b = volume_error(model, frame, inner)
    if not b:
        return None
    sd = {k: math.hypot(a[k], b[k]) for k in ("contours", "between", "apex")}
    sd["pixels"] = abs(a["pixels"] - b["pixels"])
    (ob, _), (ib, _) = _end_areas(model, frame, outer), _end_areas(model, frame, inner)
    frac = max(ob - ib, 0.0) / ob if ob > 0 else 0.0
    sd["base"] = a["base"] * frac
    return VolumeError(sd, frozenset(shared),
                       a["open base"] * frac + a["open apex"] + _epicardial_cap(model, frame, outer,
                                                                                inner),
                       b["open apex"])


def _rv_shape(model: "BiventricularModel", frame: int) -> float:
    """SD (mL) of the RV cavity's shape: :data:`RV_SHAPE_REL` (by input kind) of its volume.
    Where no valve landmark or long-axis contour closes it (a label map, or the half-slice
    rule) the SA stack cuts the RV's basal third and outflow region obliquely, and what lies
    between those sections is the loft's guess; where the data close it (``observed``), the
    loft's own error (docs/metrics.md, Uncertainty: set on the phantoms)."""
    labels = isinstance(model.study.meta, dict) and bool(model.study.meta.get("voxel_volumes_ml"))
    if not (labels or "rv" in model.geometry[frame].base_from_slices):
        rel = RV_SHAPE_REL.get("observed", 0.0)      # closed by the data: the loft's own error
    else:
        rel = kind_entry(RV_SHAPE_REL, model, lv_input_kind(model) or "contours", 0.0)
    return rel * float(model.volumes[frame].get("rv_cavity", 0.0))


def lv_input_kind(model: "BiventricularModel") -> str | None:
    """The input kind the ``lv shape`` term is keyed to (:data:`LV_SHAPE_REL`): ``labels`` (a
    label map whose LV base the SA slices give), ``labels+LA`` (a label map whose long-axis
    maps give the mitral annulus), ``contours`` (SA contours whose LV base the half-slice rule
    placed) or None (contours with the base observed: valve landmarks or long-axis contours).

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    str or None
    """
    labels = isinstance(model.study.meta, dict) and bool(model.study.meta.get("voxel_volumes_ml"))
    rule = "lv" in model.geometry[model.ed_frame].base_from_slices
    if labels:
        return "labels" if rule else "labels+LA"
    return "contours" if rule else None


def _lv_kind(model: "BiventricularModel") -> str:
    """The key of the per-kind LV tables: :func:`lv_input_kind`, ``observed`` when it is None."""
    return lv_input_kind(model) or "observed"


def sa_spacing_mm(model: "BiventricularModel") -> float:
    """The median spacing of the model's SA image planes at ED (their origins along the first
    plane's normal; a label map's slice spacing).

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    float
        mm; NaN with fewer than two SA planes.
    """
    ims = model.study.images_at(model.ed_frame, "SA")
    if len(ims) < 2:
        return NAN
    lev = np.unique(np.round([float(im.position @ ims[0].normal) for im in ims], 6))
    return float(np.median(np.diff(lev))) if len(lev) > 1 else NAN


def kind_entry(table: dict[str, float], model: "BiventricularModel", kind: str,
               default: float) -> float:
    """One input kind's entry of a per-kind table (:data:`LV_SHAPE_REL` ...). A ``labels``
    kind whose table has the ``labels 5mm`` entry too: the two entries interpolated linearly in
    the model's SA spacing between their :data:`LABELS_SPACING_MM` (the nearer one beyond them,
    ``labels`` where the spacing is unknown).

    Parameters
    ----------
    table : dict of str to float
        The table.
    model : BiventricularModel
        The model (its SA spacing).
    kind : str
        The kind (``labels``, ``labels+LA``, ``contours``, ``observed``).
    default : float
        The entry of a kind the table lacks.

    Returns
    -------
    float
    """
    if kind != "labels" or "labels 5mm" not in table or "labels" not in table:
        return float(table.get(kind, default))
    lo, hi = LABELS_SPACING_MM["labels 5mm"], LABELS_SPACING_MM["labels"]
    h = sa_spacing_mm(model)
    t = 1.0 if not math.isfinite(h) else min(max((h - lo) / (hi - lo), 0.0), 1.0)
    return float((1.0 - t) * table["labels 5mm"] + t * table["labels"])


def lvm_factor(model: "BiventricularModel") -> float:
    """The :data:`LVM_FACTOR` of the model's input kind (:func:`lv_input_kind`; ``observed``
    when it is None): the factor over the LV wall's propagated SD.

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    float
    """
    return kind_entry(LVM_FACTOR, model, _lv_kind(model), 1.0)


def lv_shape_corr(model: "BiventricularModel") -> float:
    """The :data:`LV_SHAPE_CORR` of the model's input kind (:func:`lv_input_kind`;
    ``observed`` when it is None): the correlation of its lv shape errors at ED and ES.

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    float
    """
    return kind_entry(LV_SHAPE_CORR, model, _lv_kind(model), 1.0)


def _lv_shape(model: "BiventricularModel", frame: int) -> float:
    """SD (mL) of the LV cavity's own reconstruction error for its input kind:
    :data:`LV_SHAPE_REL` of its volume (``observed``: contours whose base the data fix). The SA
    sections leave the basal LV (the annulus' saddle, the outflow root) to the rule or the
    map's last slice, and the realistic base differs from the loft's guess by a share of the
    cavity that is alike at ED and ES (correlated by :data:`LV_SHAPE_CORR`; at ED times
    :data:`LV_SHAPE_ED_FACTOR`)."""
    kind = _lv_kind(model)
    rel = kind_entry(LV_SHAPE_REL, model, kind, 0.0)
    if frame == model.ed_frame:
        rel *= kind_entry(LV_SHAPE_ED_FACTOR, model, kind, 1.0)
    return rel * float(model.volumes[frame].get("lv_cavity", 0.0))


def _outflow_allowance(model: "BiventricularModel", frame: int, solid: str) -> float:
    """One-sided allowance (mL) for an outflow tract (and an annulus' saddle) the model did
    not build (docs/metrics.md: only with outflow evidence) beyond a valve plane that the
    half-slice rule placed or that a label map gives: the basal section's area times
    :data:`OUTFLOW_SHARE` over half a slice gap. None when the frame has outflow evidence
    (``aortic`` landmarks for the LV; ``pulmonary`` landmarks or ``rv_outlet`` contours for
    the RV)."""
    side = solid[:2]
    if solid not in ("lv_cavity", "rv_cavity"):
        return 0.0
    evidence: Sequence[Landmark | Contour] = model.study.landmarks_at(
        frame, "aortic" if side == "lv" else "pulmonary")
    if side == "rv":
        evidence = evidence or model.study.contours_at(frame, "rv_outlet")
    labels = isinstance(model.study.meta, dict) and bool(model.study.meta.get("voxel_volumes_ml"))
    if evidence or not (labels or side in model.geometry[frame].base_from_slices):
        return 0.0
    t = section_table(model, frame, f"{side}_endo")
    if not t or len(t["level"]) < 2:
        return 0.0
    h = float(np.median(np.abs(np.diff(t["level"]))))
    return OUTFLOW_SHARE * float(t["area"][0]) * 0.5 * h / 1000.0


def _epicardial_cap(model: "BiventricularModel", frame: int, outer: str, inner: str) -> float:
    """One-sided allowance (mL) for the wall beyond the cavity's apex that the half-slice
    rule leaves out when the stack ends at the last cavity section: the epicardial cap
    lies one wall thickness (from the last sections' equivalent radii) farther."""
    if _observed(model, frame, outer, "apex") or outer in model.geometry[frame].taper:
        return 0.0
    to, ti = section_table(model, frame, outer), section_table(model, frame, inner)
    if not to or not ti:
        return 0.0
    a_out, a_in = float(to["area"][-1]), float(ti["area"][-1])
    wall = max(math.sqrt(a_out / math.pi) - math.sqrt(max(a_in, 0.0) / math.pi), 0.0)
    return CAP_SHAPE * a_out * wall / 1000.0


def _sampling_bias(model: "BiventricularModel") -> tuple[float, float]:
    """(ED, ES) one-sided sampling allowances (mL) of the LV cavity: |Δ²V| / 8 at the frame
    of the sampled maximum (minimum) of a cycle of >= 3 frames whose ED/ES came from the
    volumes (0 when the frames were labelled or given)."""
    lv = getattr(model, "lv_volume_by_frame", None)
    if not lv or len(lv) < 3:
        return 0.0, 0.0
    frames = sorted(lv)
    v = np.array([lv[f] for f in frames], float)
    out = []
    for fr, sign in ((model.ed_frame, -1.0), (model.es_frame, 1.0)):
        if fr not in lv:
            out.append(0.0)
            continue
        i = frames.index(fr)
        d2 = v[(i + 1) % len(v)] - 2 * v[i] + v[i - 1]
        out.append(max(0.0, sign * float(d2)) / 8.0)
    return out[0], out[1]


def _combine(ed: VolumeError, es: VolumeError, grad_ed: float, grad_es: float) -> float:
    """SD of grad_ed · δEDV + grad_es · δESV: independent sources in quadrature, a shared
    source (ES's ``shared``) as one error (``lv shape``: correlated by ES's ``corr``, the
    input kind's :data:`LV_SHAPE_CORR`)."""
    var = 0.0
    for k in sorted(set(ed.sd) | set(es.sd)):
        a, b = grad_ed * ed.sd.get(k, 0.0), grad_es * es.sd.get(k, 0.0)
        rho = (es.corr if k == "lv shape" else 1.0) if k in es.shared else 0.0
        var += a * a + b * b + 2.0 * rho * a * b
    return math.sqrt(max(var, 0.0))


def _allowance(ed: VolumeError, es: VolumeError, grad_ed: float, grad_es: float
               ) -> tuple[float, float]:
    """(below, above) one-sided allowances of grad_ed · EDV + grad_es · ESV."""
    lo = hi = 0.0
    for e, g in ((ed, grad_ed), (es, grad_es)):
        up, down = g * e.above, -g * e.below          # the volume's allowances, signed
        for x in (up, down):
            hi, lo = (hi + x, lo) if x > 0 else (hi, lo - x)
    return lo, hi


def _side_intervals(model, metrics: dict, side: str, bias: tuple[float, float],
                    out: dict, notes: dict, parts: dict) -> None:
    """The intervals of one ventricle's EDV, ESV, SV, EF and mass into ``out`` (``bias``:
    the (ED, ES) sampling allowances, mL)."""
    ed, es = model.ed_frame, model.es_frame
    cav, myo = f"{side.lower()}_cavity", f"{side.lower()}_myocardium"
    edv, esv = metrics.get(f"{side}EDV (mL)", NAN), metrics.get(f"{side}ESV (mL)", NAN)
    e_ed = solid_error(model, ed, cav) if math.isfinite(edv) else None
    if e_ed is not None:
        e_ed.above += bias[0]
        out[f"{side}EDV (mL)"] = _interval(edv, e_ed.total(), e_ed.below, e_ed.above)
        parts[f"{side}EDV (mL)"] = e_ed.sd
    mass = metrics.get(f"{side}M (g)", NAN)
    e_m = solid_error(model, ed, myo) if math.isfinite(mass) else None
    if e_m is not None:
        density = mass / model.volumes[ed][myo]
        f = lvm_factor(model) if side == "LV" else 1.0
        out[f"{side}M (g)"] = _interval(mass, f * density * e_m.total(), density * e_m.below,
                                        density * e_m.above)
        parts[f"{side}M (g)"] = {k: f * density * v for k, v in e_m.sd.items()}
    cols = (f"{side}ESV (mL)", f"{side}SV (mL)", f"{side}EF (%)")
    if ed == es:
        for c in cols:
            notes[c] = f"one frame ({ed}) only: ED = ES, no {c.split(' ')[0]} interval"
        return
    e_es = solid_error(model, es, cav) if math.isfinite(esv) else None
    if e_ed is None or e_es is None:
        return
    e_es.below += bias[1]
    out[cols[0]] = _interval(esv, e_es.total(), e_es.below, e_es.above)
    parts[cols[0]] = e_es.sd
    out[cols[1]] = _interval(edv - esv, _combine(e_ed, e_es, 1.0, -1.0),
                             *_allowance(e_ed, e_es, 1.0, -1.0))
    parts[cols[1]] = _parts(e_ed, e_es, 1.0, -1.0)
    if edv > 0 and math.isfinite(metrics.get(cols[2], NAN)):
        g_ed, g_es = 100.0 * esv / edv ** 2, -100.0 / edv
        out[cols[2]] = _interval(metrics[cols[2]], _combine(e_ed, e_es, g_ed, g_es),
                                 *_allowance(e_ed, e_es, g_ed, g_es))
        parts[cols[2]] = _parts(e_ed, e_es, g_ed, g_es)


def _parts(ed: VolumeError, es: VolumeError, g_ed: float, g_es: float) -> dict[str, float]:
    """Per source, the SD of g_ed · δEDV + g_es · δESV."""
    return {k: _combine(VolumeError({k: ed.sd.get(k, 0.0)}),
                        VolumeError({k: es.sd.get(k, 0.0)}, es.shared, corr=es.corr), g_ed, g_es)
            for k in sorted(set(ed.sd) | set(es.sd))}


def _interval(value: float, sd: float, below: float = 0.0, above: float = 0.0) -> list[float]:
    """[value − 1.96 sd − below, value + 1.96 sd + above]."""
    return [float(value - Z95 * sd - below), float(value + Z95 * sd + above)]


def intervals(model: "BiventricularModel", metrics: dict) -> dict:
    """The 95 % intervals of the :data:`ALL_COVERED` metrics of one model, for metrics.json
    (the tag metrics' from :func:`cardionurbs.analysis.tag_uncertainty.tag_intervals`).

    Parameters
    ----------
    model : BiventricularModel
        The reconstructed model the metrics come from (its sections, contour points,
        fit residuals at ED and ES and per-frame LV volumes are read; nothing is refitted).
    metrics : dict
        docs/metrics.md column -> value (:func:`cardionurbs.analysis.function.measure`).

    Returns
    -------
    dict
        column -> [lo, hi] (the metric's unit) or None where no interval can be given,
        ``"method"`` (str), ``"notes"`` (column -> why it is None) and ``"sd"`` (column ->
        source -> standard deviation in the metric's unit, before the one-sided
        ES-sampling allowance).
    """
    out: dict = {c: None for c in COVERED}
    notes: dict[str, str] = {}
    parts: dict[str, dict] = {}
    bias_lv = _sampling_bias(model)
    for side in ("LV", "RV"):
        bias = bias_lv
        if side == "RV":       # the RV curve is sampled at ED and ES only: the LV's, scaled
            r_ed = _ratio(metrics.get("RVEDV (mL)"), metrics.get("LVEDV (mL)"))
            r_es = _ratio(metrics.get("RVESV (mL)"), metrics.get("LVESV (mL)"))
            bias = (bias_lv[0] * r_ed, bias_lv[1] * r_es)
        _side_intervals(model, metrics, side, bias, out, notes, parts)
    t_out, t_notes, t_parts = tag_intervals(model, metrics, Z95)
    out.update(t_out)
    notes.update(t_notes)
    parts.update(t_parts)
    for c in COVERED:
        v = metrics.get(c, NAN)
        if out[c] is None and c not in notes:
            notes[c] = ("the metric is empty" if not (isinstance(v, float) and math.isfinite(v))
                        else "its surfaces have fewer than two contoured SA sections")
        elif out[c] is not None and not all(math.isfinite(x) for x in out[c]):
            out[c], notes[c] = None, "not finite"
    return {**out, "method": METHOD, "notes": notes,
            "sd": {c: {k: float(v) for k, v in p.items()} for c, p in parts.items()}}


def _ratio(a, b) -> float:
    if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)) or b == 0:
        return 0.0
    return float(a) / float(b)


def interval_columns(uncertainty: dict) -> dict[str, float]:
    """``<column> lo95`` and ``<column> hi95`` (NaN where there is no interval) of an
    :func:`intervals` result: the cohort CSV's columns.

    Parameters
    ----------
    uncertainty : dict
        An :func:`intervals` result.

    Returns
    -------
    dict of str to float
        Column -> bound, in the metric's unit.
    """
    out = {}
    for c in ALL_COVERED:
        iv = uncertainty.get(c)
        out[f"{c} lo95"], out[f"{c} hi95"] = (float(iv[0]), float(iv[1])) if iv else (NAN, NAN)
    return out


#: every column given an interval: the volumes' and the tag metrics'
ALL_COVERED = COVERED + TAG_COVERED
#: the cohort CSV's interval columns, in :data:`ALL_COVERED` order
INTERVAL_COLUMNS = tuple(f"{c} {end}" for c in ALL_COVERED for end in ("lo95", "hi95"))


def _column_named(name: str) -> str | None:
    """The covered column a ``--max-halfwidth`` key names: the column itself or its first
    word (``LVEF`` -> ``LVEF (%)``), case-insensitive."""
    key = name.strip().lower()
    for c in ALL_COVERED:
        if key in (c.lower(), c.split(" ")[0].lower()):
            return c
    return None


def parse_max_halfwidth(text: str) -> dict[str, float]:
    """``"LVEF=5,LVEDV=10"`` -> {``"LVEF (%)"``: 5.0, ``"LVEDV (mL)"``: 10.0}; ValueError (one
    line naming the item) for an unknown metric or a limit that is not a number > 0.

    Parameters
    ----------
    text : str
        Comma-separated ``metric=limit`` items (metric names as in docs/metrics.md, without
        the unit).

    Returns
    -------
    dict of str to float
        Column -> largest half-width, the column's unit.

    Raises
    ------
    ValueError
        An unknown metric or a limit that is not a number > 0.
    """
    out: dict[str, float] = {}
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        name, eq, value = item.partition("=")
        col = _column_named(name)
        if col is None or not eq:
            raise ValueError(f"--max-halfwidth: {item!r} is not METRIC=LIMIT with METRIC one of "
                             + ", ".join(c.split(" ")[0] for c in ALL_COVERED))
        try:
            limit = float(value)
        except ValueError:
            limit = NAN
        if not (math.isfinite(limit) and limit > 0):
            raise ValueError(f"--max-halfwidth: the limit of {name.strip()!r} must be a number > 0, "
                             f"got {value!r}")
        out[col] = limit
    if not out:
        raise ValueError("--max-halfwidth: name at least one METRIC=LIMIT")
    return out


def halfwidth_flags(uncertainty: dict, limits: dict[str, float]) -> list[str]:
    """Quality flags of an :func:`intervals` result against half-width ``limits`` (column ->
    largest half-width, the column's unit): one per column whose interval is wider, or
    missing (with the reason).

    Parameters
    ----------
    uncertainty : dict
        An :func:`intervals` result.
    limits : dict of str to float
        Column -> largest half-width.

    Returns
    -------
    list of str
    """
    flags = []
    for col, limit in limits.items():
        iv = uncertainty.get(col)
        if iv is None:
            why = (uncertainty.get("notes") or {}).get(col, "no interval")
            flags.append(f"{col} has no 95 % interval ({why}); --max-halfwidth {limit:g}")
            continue
        hw = 0.5 * (iv[1] - iv[0])
        if hw > limit:
            flags.append(f"{col} 95 % interval ± {hw:.3g} > {limit:g} (imprecise)")
    return flags
