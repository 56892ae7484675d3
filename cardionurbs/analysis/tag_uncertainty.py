"""95 % intervals of the tag metrics: twist, LS and the global tag strains (docs/metrics.md,
Uncertainty).

Read off what the tag analysis already measured (:func:`cardionurbs.analysis.tags.tag_metrics`,
:func:`cardionurbs.analysis.strain.tag_strain`); nothing is refitted:

* **Twist** = φ_apex − φ_base, each φ the mean of the per-point rotations of one level's
  material points (docs/metrics.md, Tags): its standard error is that of the mean of those
  rotations, two-way cluster-robust by the ``sa1`` and ``sa2`` tag line each point lies on
  (:func:`mean_se`), the two levels taken as independent (a line shared by both moves them
  alike and cancels in the difference: this errs wide), SD = √(se_apex² + se_base²). On a phantom every point of a level rotates by the
  same angle, so the scatter is the tag tracking noise; on a heart it is also the level's
  real variation round the wall, whose mean is the metric.
* **LS** = 100 (1 − L_ES / L_ED), L the distance along the ED long axis between the mean
  heights of the apical and basal levels' points: the placement of each end level at ED
  and at ES has the standard error of its points' heights over √n (on a phantom the ED
  heights of one tag plane differ only by noise and the tilt of the model's axis against
  the true one), the four independent, propagated by the delta method. A tilt α of the
  axis itself scales L_ED and L_ES alike (by cos α): second order in LS, left out.
* **Global strain** (``Ecc_Global``, ``Ell_Global``, ``Err_Global``): the mean over the AHA
  segments 1-16 of the segment strains. The tag-line fit gives each segment's standard
  error (``regional.strain.segment_se``, σ² S⁻¹ of the unregularised fit); whatever their
  correlation, the SD of a mean is at most the mean of the SDs (Minkowski), which is taken
  (the unregularised SE, not the smaller regularised SD: the prior's pull is a bias the
  SD does not show). To it is added, in quadrature, the motion model's own error,
  :data:`STRAIN_MODEL_REL` of the value (noise-free phantoms: the smooth map misses a few
  tenths of a strain point of the exact motion, which no noise term shows).

Not covered: Twist 2D, Torsion, CL shear, the segment strains and the surface strains.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cardionurbs.analysis.tags import rotation_deg

#: the tag columns given an interval
TAG_COVERED = ("Twist (deg)", "LS (%)", "Ecc_Global (%)", "Ell_Global (%)", "Err_Global (%)")
#: SD of the motion model's own error in a global strain, relative to its value (set on
#: noise-free tagged phantoms, reports/validation-uncertainty.md, Tag metrics)
STRAIN_MODEL_REL = 0.01
NAN = float("nan")


def _axis(model: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """(apex, base centre) at ED, mm: the axis :func:`~cardionurbs.analysis.tags.tag_metrics`
    measured the levels about (the model's, else the study's landmarks)."""
    from cardionurbs.anatomy.sections import study_long_axis
    from cardionurbs.errors import CardioNurbsError
    try:
        apex, base = model.long_axis()
    except (KeyError, AttributeError, TypeError, CardioNurbsError):
        try:
            apex, base = study_long_axis(model.study, model.ed_frame)
        except (KeyError, AttributeError, TypeError, CardioNurbsError):
            return None
    return np.asarray(apex, float), np.asarray(base, float)


def mean_se(values: np.ndarray, lines: np.ndarray | None = None) -> float:
    """Standard error of the mean of ``values`` (n,): i.i.d., or with ``lines`` (n, 2) the
    two tag lines (sa1, sa2 index) each value's point lies on, two-way cluster-robust
    (Cameron, Gelbach & Miller, *J Bus Econ Stat* 29:238-249, 2011): V = V_sa1 + V_sa2 −
    V_point, each V = Σ_g (Σ_{i∈g} r_i)² / n² with the small-sample factor G / (G − 1), and
    never below any of the three (the points of one tag line share that line's error).

    Parameters
    ----------
    values : (n,) ndarray
        The values (any unit).
    lines : (n, 2) ndarray of int or None
        The (sa1, sa2) tag indices of each value's point; None: i.i.d.

    Returns
    -------
    float
        In the values' unit.
    """
    v = np.asarray(values, float)
    n = len(v)
    r = v - v.mean()

    def var(groups: np.ndarray) -> float:
        _, inv = np.unique(groups, return_inverse=True)
        g = int(inv.max()) + 1
        sums = np.bincount(inv, weights=r, minlength=g)
        return float(np.sum(sums ** 2)) / n ** 2 * (g / (g - 1) if g > 1 else 1.0)

    v0 = var(np.arange(n))
    if lines is None:
        return math.sqrt(v0)
    va, vb = var(lines[:, 0]), var(lines[:, 1])
    return math.sqrt(max(va + vb - v0, va, vb, v0))


def level_statistics(tags: Any, es_frame: int, apex: np.ndarray, base: np.ndarray,
                     clustered: bool = True) -> list[dict] | None:
    """The two end levels of the twist (apex, base): per level, n, the standard errors of
    its mean rotation (deg; :func:`mean_se`, clustered by tag line unless ``clustered`` is
    False) and of its mean height along the ED axis at ED and at ES (mm, i.i.d.: every
    point of a level lies on the same LA tag surface).

    Parameters
    ----------
    tags : TagMetrics
        The result of :func:`cardionurbs.analysis.tags.tag_metrics` (its ``levels`` and
        ``material`` points are read).
    es_frame : int
        The frame the levels were measured at.
    apex, base : (3,) mm
        The ED long axis the rotations were measured about.
    clustered : bool
        Cluster the rotation's standard error by tag line (False: i.i.d., for comparison).

    Returns
    -------
    list of dict or None
        ``[{"index", "n", "se_rotation_deg", "se_height_ed_mm", "se_height_es_mm"}]`` for
        the apical and the basal level; None without two levels or a level of < 2 points.
    """
    mp = getattr(tags, "material", None)
    ends = [lv for lv in getattr(tags, "levels", []) if lv.get("in_twist")]
    if mp is None or len(ends) < 2 or es_frame not in mp.positions:
        return None
    ez = (base - apex) / np.linalg.norm(base - apex)
    X0, X1 = mp.positions[mp.ed_frame], mp.positions[es_frame]
    tracked = mp.tracked(mp.ed_frame, es_frame)
    out = []
    for lv in (ends[0], ends[-1]):
        sel = (mp.triples[:, 2] == lv["index"]) & tracked
        n = int(sel.sum())
        if n < 2:
            return None
        rot = rotation_deg(X0[sel], X1[sel], apex, base)
        lines = mp.triples[sel, :2] if clustered else None
        out.append({"index": int(lv["index"]), "n": n,
                    "se_rotation_deg": mean_se(rot, lines),
                    "se_height_ed_mm": mean_se((X0[sel] - apex) @ ez),
                    "se_height_es_mm": mean_se((X1[sel] - apex) @ ez)})
    return out


def _ls_sd(levels: list[dict], tags: Any) -> float:
    """SD (LS points) of LS = 100 (1 − L_ES / L_ED) from the end levels' height errors."""
    ends = [lv for lv in tags.levels if lv.get("in_twist")]
    a, b = ends[0], ends[-1]
    d_ed = b["distance_from_apex_mm"] - a["distance_from_apex_mm"]
    d_es = b["distance_at_frame_mm"] - a["distance_at_frame_mm"]
    var_ed = sum(lv["se_height_ed_mm"] ** 2 for lv in levels)
    var_es = sum(lv["se_height_es_mm"] ** 2 for lv in levels)
    return 100.0 * math.sqrt(var_es / d_ed ** 2 + (d_es / d_ed ** 2) ** 2 * var_ed)


def _strain_sd(regional: Any, column: str, value: float) -> dict[str, float] | None:
    """Sources (SD, strain points) of one global tag strain: ``tag fit`` (the mean of the
    segments' unregularised standard errors; 0 for a fit without noise, which computes
    none) and ``motion model``; None without a tag-line fit."""
    strain = getattr(regional, "strain", None) or {}
    if strain.get("method") is None:
        return None
    kind = column.split("_")[0]
    se = [v for v in ((strain.get("segment_se") or {}).get(kind) or {}).values()
          if math.isfinite(v)]
    return {"tag fit": float(np.mean(se)) if se else 0.0,
            "motion model": STRAIN_MODEL_REL * abs(value)}


def tag_intervals(model: Any, metrics: dict, z: float) -> tuple[dict, dict, dict]:
    """The 95 % intervals of :data:`TAG_COVERED`.

    Parameters
    ----------
    model : BiventricularModel
        Its ``tag_result`` (the :class:`~cardionurbs.analysis.tags.TagMetrics` that
        :func:`cardionurbs.pipeline.analyse` measured) and ``regional`` (the tag strain fit)
        are read; a bare ``measure`` has neither.
    metrics : dict
        docs/metrics.md column -> value.
    z : float
        The normal quantile (1.96 for 95 %).

    Returns
    -------
    (intervals, notes, sd) : dict, dict, dict
        column -> [lo, hi] (the column's unit) or None; column -> why None; column ->
        source -> SD.
    """
    out: dict = {c: None for c in TAG_COVERED}
    notes: dict[str, str] = {}
    parts: dict[str, dict] = {}
    tags = getattr(model, "tag_result", None)
    axis = _axis(model) if tags is not None else None
    levels = (level_statistics(tags, model.es_frame, *axis) if axis is not None else None)
    sds: dict[str, dict[str, float] | None] = {c: None for c in TAG_COVERED}
    if levels is not None:
        sds["Twist (deg)"] = {"tag points": math.hypot(*(lv["se_rotation_deg"] for lv in levels))}
        sds["LS (%)"] = {"level placement": _ls_sd(levels, tags)}
    for c in TAG_COVERED[2:]:
        v = metrics.get(c, NAN)
        if isinstance(v, float) and math.isfinite(v):
            sds[c] = _strain_sd(getattr(model, "regional", None), c, v)
    for c in TAG_COVERED:
        v = metrics.get(c, NAN)
        src = sds[c]
        if not (isinstance(v, float) and math.isfinite(v)):
            notes[c] = "the metric is empty"
        elif src is None:
            notes[c] = ("no tag result on the model (measured without the tag analysis)"
                        if tags is None and c in TAG_COVERED[:2] else
                        "fewer than two points on an end level" if c in TAG_COVERED[:2] else
                        "no tag-line strain fit on the model")
        else:
            sd = math.sqrt(sum(x * x for x in src.values()))
            out[c], parts[c] = [float(v - z * sd), float(v + z * sd)], src
    return out, notes, parts
