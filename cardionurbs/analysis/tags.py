"""LV twist, torsion, CL shear and longitudinal shortening from tag surfaces (docs/metrics.md, Tags).

Public API (the pipeline's ``measure``/``analyze`` call these):

- :func:`tag_surfaces` (study, frame) -> {(family, index): NurbsSurface}
- :func:`material_points` (study, ed_frame, es_frame) -> :class:`MaterialPoints`
- :func:`tag_metrics` (study, ed_frame, es_frame, long_axis=None) -> :class:`TagMetrics`
- :func:`tag_qc` (study, threshold=0.5) -> list of :class:`TagFlag`
- :func:`tag_figure_data` (study, frame) -> tessellated tag surfaces with flag status
- :func:`tag_surfaces_dict` (study) -> JSON-safe tag surfaces to save with the model

Definitions (docs/metrics.md)
------------------------------
Long axis
    From the apex (the ``apex`` landmark at ED, or the model's apex) to the
    centre of the mitral valve plane (mean of the ``mitral`` landmarks), at ED.
Rotation φ of a level (LA tag plane ``k``)
    Mean over its material points of the angle swept ED → ES about the ED
    long axis, counter-clockwise positive as seen from the apex looking
    toward the base, i.e. right-handed about the unit vector base → apex:

        φ_k = mean_p wrap(θ_ES(p) − θ_ED(p)),  θ = atan2((x − a)·e2, (x − a)·e1)      (T1)

    with (e1, e2, e) the axis frame of :func:`axis_frame`.
Levels
    LA tag planes with at least 2 material points tracked at ED and ES whose
    mean position lies strictly between the most basal and the most apical
    SA slices tagged at both ED and ES, at ED and at ES (docs/metrics.md). The
    ES position of a level is read off the pooled map h_ES = a + b h_ED
    fitted on all material points (:func:`longitudinal_height_map`), not
    off the level's own few noisy points, so noise cannot move a level
    across an end slice.
    Distance from the apex
    z_k = mean over the level's points of (x_ED − apex)·ê, ê = unit(base − apex).
Twist, torsion, CL shear (docs/metrics.md)
    Twist = φ_apex − φ_base between the most apical and most basal levels;
    D = z_base − z_apex (mm); Torsion = Twist / (D / 10) deg/cm;
    CL shear = Twist (ρ_apex + ρ_base) / (2 D) deg, ρ = mean LV epicardial
    radius at the level at ED (SA ``lv_epi`` contours, mean distance from
    the long axis, cubic spline along it).
LS
    L_f = mean z(basal level points at f) − mean z(apical level points at f)
    measured along the ED axis; LS = 100 (L_ED − L_ES) / L_ED.
Twist 2D
    The slice-based measure: in the most basal and most apical SA slices
    tagged at ED and ES, the crossings of sa1 and sa2 tag lines (same
    index pair at both frames) rotated about each slice's LV centroid
    (``lv_endo`` contour centroid at that frame, else the crossings' mean);
    Twist 2D = φ_2D(apical slice) − φ_2D(basal slice). It mixes different
    tissue at ED and ES (through-plane motion), hence reported beside the
    3D value.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cardionurbs.anatomy.sections import stacking_direction, study_long_axis
from cardionurbs.analysis.material import MaterialPoints, SplineData, material_points
from cardionurbs.analysis.tag_surfaces import (axis_frame, build_tag_surfaces,
                                               fit_tag_curve, resolve_frames, tag_surfaces)
from cardionurbs.analysis.tagqc import TagFlag, tag_qc
from cardionurbs.analysis.columns import ColumnMapping
from cardionurbs.errors import CardioNurbsError
from cardionurbs.geometry import polygon_centroid
from cardionurbs.median import median
from cardionurbs.study import Study

__all__ = ["tag_surfaces", "material_points", "tag_metrics", "tag_qc", "tag_figure_data",
           "tag_surfaces_dict", "TagMetrics", "MaterialPoints", "TagFlag", "TAG_COLUMNS"]

TAG_COLUMNS = ("Twist (deg)", "Twist 2D (deg)", "Torsion (deg/cm)", "CL shear (deg)", "LS (%)",
               "Tag QC flags")
MIN_LEVEL_POINTS = 2
NAN = float("nan")


# ------------------------------------------------------------ frames, axis
def _wrap_deg(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def rotation_deg(x0: np.ndarray, x1: np.ndarray, apex: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Angle (deg) swept about the long axis from x0 to x1 (T1), CCW seen from the apex.

    Parameters
    ----------
    x0, x1 : (n, 3) ndarray
        Positions at ED and at the frame, mm.
    apex, base : (3,) ndarray
        The long axis, mm.

    Returns
    -------
    (n,) ndarray
        deg.
    """
    e1, e2, _ = axis_frame(apex, base)
    d0, d1 = x0 - apex, x1 - apex
    th0 = np.arctan2(d0 @ e2, d0 @ e1)
    th1 = np.arctan2(d1 @ e2, d1 @ e1)
    return _wrap_deg(np.degrees(th1 - th0))


# ------------------------------------------------------------- epi radius
def epicardial_radius_profile(study: Study, frame: int, apex: np.ndarray,
                              base: np.ndarray):
    """ρ(z): mean LV epicardial radius (mm) at distance z (mm) from the apex along the axis.

    One sample per SA ``lv_epi`` contour at ``frame`` — the contour resampled
    uniformly by arc length, ρ its mean distance from the long axis, z its
    mean axial position — joined by a cubic spline (not-a-knot; linear with
    two slices, constant beyond the ends). None without contours.

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    apex, base : (3,) ndarray
        The long axis, mm.

    Returns
    -------
    callable or None
        ρ(z), mm.
    """
    from scipy.interpolate import CubicSpline
    ez = (base - apex) / np.linalg.norm(base - apex)
    zs, rs = [], []
    for c in study.contours_at(frame, "lv_epi", view="SA"):
        if not c.closed or len(c.points) < 3:
            continue
        p = np.vstack([c.points, c.points[:1]])
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        s = np.r_[0.0, np.cumsum(seg)]
        t = np.linspace(0, s[-1], 200, endpoint=False)
        q = np.column_stack([np.interp(t, s, p[:, k]) for k in range(3)])
        rel = q - apex
        z = rel @ ez
        r = np.linalg.norm(rel - np.outer(z, ez), axis=1)
        zs.append(float(z.mean()))
        rs.append(float(r.mean()))
    if not zs:
        return None
    order = np.argsort(zs)
    z, r = np.asarray(zs)[order], np.asarray(rs)[order]
    if len(z) < 3:
        return lambda x: np.interp(x, z, r)
    spline = CubicSpline(z, r)
    return lambda x: spline(np.clip(x, z[0], z[-1]))


# --------------------------------------------------------------- Twist 2D
def curve_crossings(curves: list, raw: list[np.ndarray], pairs: np.ndarray,
                    iterations: int = 12) -> np.ndarray:
    """Crossing points of curve pairs (Gauss–Newton on (u1, u2), all pairs at once).

    ``pairs`` (k, 2) indexes ``curves``; returns (k, 3), NaN where the curves
    do not meet within 0.01 mm or the crossing is not on the data of both
    lines (farther than two point spacings from every tag point, i.e. across
    a cavity gap). Started from the nearest pair of 24-point samples.

    Parameters
    ----------
    curves : list of NurbsCurve
        Fitted tag curves, mm.
    raw : list of (n, 3) ndarray
        Their tag points, mm.
    pairs : (k, 2) ndarray of int
        Indices into ``curves``.
    iterations : int
        Gauss–Newton iterations.

    Returns
    -------
    (k, 3) ndarray
        mm.
    """
    from cardionurbs.analysis.material import CurveBatch
    k = len(pairs)
    if k == 0:
        return np.zeros((0, 3))
    batch = CurveBatch(curves)
    ns = 24
    t = np.linspace(0.0, 1.0, ns)
    ids = np.repeat(np.arange(len(curves)), ns)
    samples = batch.derivatives(ids, np.tile(t, len(curves)))[0].reshape(len(curves), ns, 3)
    a, b = samples[pairs[:, 0]], samples[pairs[:, 1]]
    d2 = ((a[:, :, None, :] - b[:, None, :, :]) ** 2).sum(-1).reshape(k, -1)
    j = np.argmin(d2, axis=1)
    u = np.column_stack([t[j // ns], t[j % ns]])
    for _ in range(iterations):
        c1, d1 = batch.derivatives(pairs[:, 0], u[:, 0])
        c2, d2_ = batch.derivatives(pairs[:, 1], u[:, 1])
        F = c1 - c2
        J = np.stack([d1, -d2_], axis=2)                        # (k, 3, 2)
        JtJ = np.einsum("kia,kib->kab", J, J) + 1e-12 * np.eye(2)
        step = -np.linalg.solve(JtJ, np.einsum("kia,ki->ka", J, F)[..., None])[..., 0]
        step = np.clip(step, -0.2, 0.2)
        u = np.clip(u + step, 0.0, 1.0)
    c1, _ = batch.derivatives(pairs[:, 0], u[:, 0])
    c2, _ = batch.derivatives(pairs[:, 1], u[:, 1])
    X = (c1 + c2) / 2
    ok = np.linalg.norm(c1 - c2, axis=1) < 0.01
    # on the data of both lines: within two point spacings of a tag point
    m = max(len(p) for p in raw)
    pad = np.full((len(raw), m, 3), np.inf)
    reach = np.empty(len(raw))
    for li, P in enumerate(raw):
        pad[li, :len(P)] = P
        steps = np.linalg.norm(np.diff(P, axis=0), axis=1)
        reach[li] = max(2.0 * median(steps) if len(steps) else 0.0, 1.0)
    for col in (0, 1):
        ends = pairs[:, col]
        with np.errstate(invalid="ignore"):
            d2 = ((pad[ends] - X[:, None, :]) ** 2).sum(-1)
        ok &= np.sqrt(np.nanmin(d2, axis=1)) <= reach[ends]
    X[~ok] = np.nan
    return X


def _slice_centroid(study: Study, slice_id: str, frame: int, fallback: np.ndarray) -> np.ndarray:
    for c in study.contours_at(frame, "lv_endo", view="SA"):
        if c.slice == slice_id and c.closed and len(c.points) >= 3:
            return polygon_centroid(c.points)
    return fallback


def twist_2d(study: Study, ed_frame: int, es_frame: int, apex: np.ndarray, base: np.ndarray,
             surfaces: dict | None = None, exclude: set | frozenset = frozenset()
             ) -> tuple[float, list[dict]]:
    """Slice-based twist (deg) and per-slice rotations (see module docstring).

    Parameters
    ----------
    study : Study
        A tagged study.
    ed_frame, es_frame : int
        The frames the rotation is measured between.
    apex, base : (3,) float ndarray
        The ED long axis, mm.
    surfaces : dict, optional
        {frame: build_tag_surfaces(...)}: lends its fitted section curves; lines not
        found there are fitted here.
    exclude : set
        {(family, index, slice, frame)} lines left out (flagged by the QC).

    Returns
    -------
    twist : float
        The most basal slice's rotation minus the most apical's, deg (NaN with fewer than
        two slices measured).
    rows : list of dict
        Per slice measured, in stack order: {"slice", "rotation_deg", "n_crossings"}.
    """
    frames = (ed_frame, es_frame)
    lines = _sa_tag_lines(study, frames, exclude)
    n_stack = stacking_direction(study)[0]
    ax = (apex - base) / np.linalg.norm(apex - base)
    slices = sorted({k[2] for k in lines}, key=lambda s: float(study.slice_plane(s).position @ n_stack))
    curves, raw, pairs, meta = _crossing_pairs(lines, _fitted_sections(surfaces), slices, frames)
    if not pairs:
        return NAN, []
    X = curve_crossings(curves, raw, np.asarray(pairs, int))
    meta_arr = np.array([(m[0], m[3]) for m in meta], dtype=object)
    rows = []
    for s in slices:
        row = _slice_rotation(study, s, X, meta_arr, frames, ax)
        if row is not None:
            rows.append(row)
    if len(rows) < 2:
        return NAN, rows
    return rows[-1]["rotation_deg"] - rows[0]["rotation_deg"], rows


def _fitted_sections(surfaces: dict | None) -> dict[tuple, tuple]:
    """(family, index, slice, frame) -> (SplineData, points) of every fitted SA section of
    ``surfaces`` ({frame: {(family, index): TagSurface}})."""
    fitted: dict[tuple, tuple] = {}
    for f, surfs in (surfaces or {}).items():
        for (fam, idx), ts in surfs.items():
            if fam not in ("sa1", "sa2"):
                continue
            for sec in ts.sections:
                if sec.ctrl is not None:
                    fitted[(fam, idx, sec.slice, f)] = (
                        SplineData(3, sec.knots, sec.ctrl, np.ones(len(sec.ctrl))), sec.points)
    return fitted


def _sa_tag_lines(study: Study, frames: tuple[int, int],
                  exclude: set | frozenset) -> dict[tuple, np.ndarray]:
    """(family, index, slice, frame) -> (n, 3) points of every SA tag line at ``frames``
    that is not excluded."""
    lines = {}
    for f in frames:
        for t in study.tags_at(f):
            if t.family in ("sa1", "sa2") and (t.family, t.index, t.slice, f) not in exclude:
                lines[(t.family, t.index, t.slice, f)] = t.points
    return lines


def _crossing_pairs(lines: dict, fitted: dict, slices: list[str],
                    frames: tuple[int, int]) -> tuple[list, list, list, list]:
    """The (sa1, sa2) line pairs whose crossings give a slice's rotation: every pair of a
    slice present at both ``frames``, each line's curve fitted once.

    Parameters
    ----------
    lines : dict
        (family, index, slice, frame) -> (n, 3) points (:func:`_sa_tag_lines`).
    fitted : dict
        (family, index, slice, frame) -> (curve, points) already fitted
        (:func:`_fitted_sections`); the other lines are fitted here.
    slices : list of str
        The slices, in stack order.
    frames : (int, int)
        ED and ES.

    Returns
    -------
    curves, raw : list
        Each line's curve and its points (float (n, 3)).
    pairs : list of (int, int)
        Indices into ``curves`` of the two lines that cross.
    meta : list of (slice, sa1 index, sa2 index, frame)
        One per pair.
    """
    curves: list = []
    raw: list[np.ndarray] = []
    pairs, meta = [], []
    pos: dict[tuple, int] = {}

    def line_id(key):
        if key not in pos:
            c, pts = fitted.get(key, (None, None))
            if c is None:
                c, pts = fit_tag_curve(lines[key]), lines[key]
            pos[key] = len(curves)
            curves.append(c)
            raw.append(np.asarray(pts, float))
        return pos[key]

    for s in slices:
        i_s = sorted({k[1] for k in lines if k[0] == "sa1" and k[2] == s})
        j_s = sorted({k[1] for k in lines if k[0] == "sa2" and k[2] == s})
        for i, j in itertools.product(i_s, j_s):
            if all((fam, x, s, f) in lines for fam, x in (("sa1", i), ("sa2", j)) for f in frames):
                for f in frames:
                    pairs.append((line_id(("sa1", i, s, f)), line_id(("sa2", j, s, f))))
                    meta.append((s, i, j, f))
    return curves, raw, pairs, meta


def _slice_rotation(study: Study, s: str, X: np.ndarray, meta_arr: np.ndarray,
                    frames: tuple[int, int], ax: np.ndarray) -> dict | None:
    """One slice's mean rotation ED -> ES of its tag crossings about its centroid.

    Parameters
    ----------
    study : Study
    s : str
        The slice.
    X : (m, 3) float ndarray
        The crossings of every pair, mm (NaN where two lines do not cross).
    meta_arr : (m, 2) object ndarray
        Each pair's (slice, frame).
    frames : (int, int)
        ED and ES.
    ax : (3,) float ndarray
        The unit long axis, base to apex.

    Returns
    -------
    dict or None
        {"slice", "rotation_deg", "n_crossings"}; None with fewer than
        MIN_LEVEL_POINTS crossings found at both frames.
    """
    ed_frame, es_frame = frames
    sel = {f: np.flatnonzero((meta_arr[:, 0] == s) & (meta_arr[:, 1] == f)) for f in frames}
    if len(sel[ed_frame]) == 0:
        return None
    X0, X1 = X[sel[ed_frame]], X[sel[es_frame]]
    ok = np.all(np.isfinite(X0), 1) & np.all(np.isfinite(X1), 1)
    if ok.sum() < MIN_LEVEL_POINTS:
        return None
    plane = study.slice_plane(s)
    n = plane.normal if plane.normal @ ax > 0 else -plane.normal
    e1 = plane.row_cosine
    e2 = np.cross(n, e1)
    ang = {}
    for f, Xf in ((ed_frame, X0), (es_frame, X1)):
        c = _slice_centroid(study, s, f, Xf[ok].mean(axis=0))
        d = Xf[ok] - c
        ang[f] = np.arctan2(d @ e2, d @ e1)
    rot = _wrap_deg(np.degrees(ang[es_frame] - ang[ed_frame]))
    return {"slice": s, "rotation_deg": float(rot.mean()), "n_crossings": int(ok.sum())}


# ---------------------------------------------------------------- results
@dataclass
class TagMetrics(ColumnMapping):
    """Tag metrics of one study; a read-only mapping docs/metrics.md column -> float.

    ``dict(result)`` gives the columns; the rest are attributes.

    Attributes
    ----------
    columns : dict of str to float
        docs/metrics.md tag columns -> value (deg, %, NaN when not measurable).
    levels : list of dict
        (index, distance_from_apex_mm, rotation_deg, epi_radius_mm, n_points, in_twist),
        sorted apex → base.
    flags : list of TagFlag
        The tag lines the QC flagged.
    slices_2d : list of dict
        Per-slice rotations of the Twist 2D measure.
    notes : list of str
        One-line remarks (e.g. "no tag lines").
    over_time : dict of int to dict of str to float
        {frame: {"Twist (deg)", "LS (%)"}} when computed.
    material : MaterialPoints or None
        The material points the metrics come from.
    surfaces : dict
        {frame: {(family, index): TagSurface}} the tag surfaces the metrics were
        measured on (flagged lines left out), for saving with the model.
    """

    columns: dict[str, float]
    levels: list[dict] = field(default_factory=list)
    flags: list[TagFlag] = field(default_factory=list)
    slices_2d: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    over_time: dict[int, dict[str, float]] = field(default_factory=dict)
    material: MaterialPoints | None = None
    surfaces: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """JSON-safe dict for metrics.json (NaN -> None).

        Returns
        -------
        dict
        """
        def num(x):
            return None if x is None or (isinstance(x, float) and not np.isfinite(x)) else x
        return {
            "columns": {k: num(v) for k, v in self.columns.items()},
            "levels": [{k: num(v) for k, v in lv.items()} for lv in self.levels],
            "flags": [{"family": f.family, "index": f.index, "slice": f.slice, "frame": f.frame,
                       "departure_spacings": num(round(f.departure, 4)), "reason": f.reason}
                      for f in self.flags],
            "twist_2d_slices": self.slices_2d,
            "over_time": {str(k): {kk: num(vv) for kk, vv in v.items()}
                          for k, v in self.over_time.items()},
            "notes": self.notes,
        }


def _empty(note: str) -> TagMetrics:
    return TagMetrics({k: NAN for k in TAG_COLUMNS}, notes=[note])


def tagged_stack_range(study: Study, ed_frame: int, frame: int) -> tuple[np.ndarray, float, float] | None:
    """(stack normal, lowest, highest plane position) of the SA slices tagged at both frames.

    Parameters
    ----------
    study : Study
        The study.
    ed_frame, frame : int
        The two frames.

    Returns
    -------
    (normal (3,), lowest, highest) or None
        Positions in mm along the normal; None without SA slices tagged at both.
    """
    n = stacking_direction(study)[0]
    both = ({t.slice for t in study.tags_at(ed_frame) if t.family != "la"}
            & {t.slice for t in study.tags_at(frame) if t.family != "la"})
    if len(both) < 2:
        return None
    h = np.array([float(study.slice_plane(s).position @ n) for s in both])
    return n, float(h.min()), float(h.max())


def longitudinal_height_map(h_ed: np.ndarray, h_at: np.ndarray, use: np.ndarray):
    """Pooled map ED stack height -> height at a frame, h_f = a + b h_ED (mm), least squares.

    Fitted on every material point ``use`` of every level at once (not per
    level), so a level's position at the frame is read off a line through
    hundreds of points: the tag-line noise on the few points of one level
    cannot move it across an end slice. b is the longitudinal stretch of the
    tagged stack (b = λ for an axial scaling z -> λ z). Returns a callable;
    with fewer than 2 distinct ED heights the identity shift by the mean
    displacement.

    Parameters
    ----------
    h_ed : (n,) ndarray
        Material points' ED stack heights, mm.
    h_at : (n,) ndarray
        Their heights at the frame, mm.
    use : (n,) ndarray of bool
        The points fitted on.

    Returns
    -------
    callable
        h_ED (mm) -> h_f (mm).
    """
    h0, h1 = np.asarray(h_ed, float)[use], np.asarray(h_at, float)[use]
    if len(h0) >= 2 and np.ptp(h0) > 0:
        b, a = np.polyfit(h0, h1, 1)
    else:
        b, a = 1.0, float((h1 - h0).mean()) if len(h0) else 0.0
    return lambda h: float(a + b * h)


def level_table(mp: MaterialPoints, frame: int, apex: np.ndarray, base: np.ndarray,
                radius,
                stack: tuple[np.ndarray, float, float] | None = None) -> list[dict]:
    """Per-level rotation ED → ``frame`` and ED distance from apex (see module docstring).

    ``stack`` (:func:`tagged_stack_range`): a level is kept only when the
    mean position of its points lies strictly between the most basal and
    most apical SA slices tagged at both frames, at ED and at ``frame`` (the
    position at ``frame`` from the pooled :func:`longitudinal_height_map`).

    Parameters
    ----------
    mp : MaterialPoints
        The material points.
    frame : int
        The frame.
    apex, base : (3,) ndarray
        The ED long axis, mm.
    radius : callable or None
        ρ(z) (:func:`epicardial_radius_profile`).
    stack : (normal, lowest, highest) or None
        As above.

    Returns
    -------
    list of dict
        As :attr:`TagMetrics.levels`.
    """
    ez = (base - apex) / np.linalg.norm(base - apex)
    X0 = mp.positions[mp.ed_frame]
    X1 = mp.positions[frame]
    tracked = mp.tracked(mp.ed_frame, frame)
    found = mp.found(mp.ed_frame, frame)
    rows = []
    if stack is not None:
        n, lo, hi = stack
        es_height = longitudinal_height_map(X0 @ n, X1 @ n, found)
    for k in np.unique(mp.triples[:, 2]) if len(mp.triples) else []:
        at = mp.triples[:, 2] == k
        sel = at & tracked
        if sel.sum() < MIN_LEVEL_POINTS:
            continue
        if stack is not None:   # placed with the points on the surfaces' extensions too
            h0 = float((X0[at & found] @ n).mean())
            if not (lo < h0 < hi and lo < es_height(h0) < hi):
                continue
        z0 = float(((X0[sel] - apex) @ ez).mean())
        z1 = float(((X1[sel] - apex) @ ez).mean())
        rot = rotation_deg(X0[sel], X1[sel], apex, base)
        rho = float(radius(z0)) if radius is not None else NAN
        rows.append({"index": int(k), "distance_from_apex_mm": z0, "distance_at_frame_mm": z1,
                     "rotation_deg": float(rot.mean()), "epi_radius_mm": rho,
                     "n_points": int(sel.sum()), "in_twist": False})
    rows.sort(key=lambda r: r["distance_from_apex_mm"])
    if len(rows) >= 2:
        rows[0]["in_twist"] = rows[-1]["in_twist"] = True
    return rows


def twist_from_levels(levels: list[dict]) -> dict[str, float]:
    """Twist, Torsion, CL shear and LS from a level table (docs/metrics.md formulas).

    Parameters
    ----------
    levels : list of dict
        :func:`level_table`'s rows.

    Returns
    -------
    dict of str to float
        Column -> deg, deg/cm, deg or %.
    """
    if len(levels) < 2:
        return {"Twist (deg)": NAN, "Torsion (deg/cm)": NAN, "CL shear (deg)": NAN, "LS (%)": NAN}
    a, b = levels[0], levels[-1]
    twist = a["rotation_deg"] - b["rotation_deg"]
    D = b["distance_from_apex_mm"] - a["distance_from_apex_mm"]
    L_es = b["distance_at_frame_mm"] - a["distance_at_frame_mm"]
    return {
        "Twist (deg)": twist,
        "Torsion (deg/cm)": twist / (D / 10.0),
        "CL shear (deg)": twist * (a["epi_radius_mm"] + b["epi_radius_mm"]) / (2.0 * D),
        "LS (%)": 100.0 * (D - L_es) / D,
    }


def tag_metrics(study: Any, ed_frame: int | None = None, es_frame: int | None = None,
                long_axis: tuple | None = None, qc: bool = True, over_time: bool = False,
                threshold: float = 0.5, exclude_flagged: bool = True) -> TagMetrics:
    """Twist, Twist 2D, Torsion, CL shear, LS and tag QC of a study (docs/metrics.md, Tags).

    Parameters
    ----------
    study : Study, or a BiventricularModel
        A model supplies its study, its ED/ES frames and its long axis
        (``model.long_axis()``) as defaults.
    ed_frame, es_frame : int, optional
        Default to the study's labels.
    long_axis : (apex, base centre) at ED, mm, optional
        From the model when given, else from the landmarks
        (:func:`cardionurbs.anatomy.sections.study_long_axis`).
    qc : bool
        Run the tag-jump QC (:func:`tag_qc`) on every tagged frame and fill
        ``Tag QC flags`` (the number of flagged lines).
    over_time : bool
        Also twist and LS at every tagged frame (relative to ED).
    threshold : float
        The QC's departure (tag spacings) beyond which a line is flagged.
    exclude_flagged : bool
        Leave the flagged lines out of the tag surfaces the material points
        are computed from (with ``qc``).

    Returns
    -------
    TagMetrics
        A mapping of the columns, with the level table, flags and notes as
        attributes. A study without tag lines gives NaN columns and one note.
    """
    study, ed_frame, es_frame, long_axis = _model_defaults(study, ed_frame, es_frame, long_axis)
    if not study.tags:
        return _empty("no tag lines: tag metrics not measured")
    ed_frame, es_frame = resolve_frames(study, ed_frame, es_frame)
    if long_axis is None:
        long_axis = study_long_axis(study, ed_frame)
    apex, base = (np.asarray(x, float) for x in long_axis)
    frames = study.tagged_frames if over_time else [ed_frame, es_frame]
    surfaces = {f: build_tag_surfaces(study, f, (apex, base)) for f in frames}
    flags: list[TagFlag] = []
    notes: list[str] = []
    bad: set = set()
    if qc:
        flags, bad, notes = _flag_and_leave_out(study, threshold, (apex, base), surfaces,
                                                frames, exclude_flagged)
    mp = material_points(study, ed_frame, es_frame, frames=frames, long_axis=(apex, base),
                         surfaces=surfaces)
    notes += list(mp.notes)
    radius = epicardial_radius_profile(study, ed_frame, apex, base)
    if radius is None:
        notes.append(f"frame {ed_frame}: no SA lv_epi contours; CL shear not measured")
    cols = {k: NAN for k in TAG_COLUMNS}
    levels = (level_table(mp, es_frame, apex, base, radius,
                          tagged_stack_range(study, ed_frame, es_frame))
              if es_frame in mp.positions else [])
    cols.update(twist_from_levels(levels))
    if len(levels) < 2:
        notes.append("fewer than two LA tag levels with material points: twist not measured")
    t2d, rows2d = twist_2d(study, ed_frame, es_frame, apex, base, surfaces,
                           exclude=bad if exclude_flagged else frozenset())
    cols["Twist 2D (deg)"] = t2d
    if qc:
        cols["Tag QC flags"] = float(len(flags))
    times = _twist_over_time(study, mp, frames, ed_frame, (apex, base), radius) if over_time else {}
    return TagMetrics(cols, levels, flags, rows2d, notes, times, mp, surfaces)


def _model_defaults(study: Any, ed_frame: int | None, es_frame: int | None,
                    long_axis: tuple | None) -> tuple[Study, int | None, int | None, tuple | None]:
    """The study, ED and ES frames and long axis of :func:`tag_metrics`: a model
    (anything with a ``study``) lends its study, frames and long axis where not given.

    Parameters
    ----------
    study : Study or BiventricularModel
    ed_frame, es_frame : int, optional
    long_axis : (apex, base centre), mm, optional

    Returns
    -------
    (Study, int or None, int or None, tuple or None)
        The long axis stays None when the model cannot give one.
    """
    if isinstance(study, Study) or not hasattr(study, "study"):
        return study, ed_frame, es_frame, long_axis
    model = study
    study = model.study
    ed_frame = model.ed_frame if ed_frame is None else ed_frame
    es_frame = model.es_frame if es_frame is None else es_frame
    if long_axis is None and study.tags:
        try:
            long_axis = model.long_axis()
        except (KeyError, AttributeError, TypeError, CardioNurbsError):
            long_axis = None
    return study, ed_frame, es_frame, long_axis


def _flag_and_leave_out(study: Study, threshold: float, long_axis: tuple, surfaces: dict,
                        frames: list[int], exclude_flagged: bool
                        ) -> tuple[list[TagFlag], set, list[str]]:
    """The tag QC (:func:`tag_qc`) on every tagged frame; with ``exclude_flagged`` the
    flagged lines are left out of the tag surfaces of ``frames`` (``surfaces`` rebuilt in
    place).

    Parameters
    ----------
    study : Study
    threshold : float
        Departure (tag spacings) beyond which a line is flagged.
    long_axis : (apex, base), mm
    surfaces : dict
        Frame -> {(family, index): TagSurface}, updated in place.
    frames : list of int
        The frames measured.
    exclude_flagged : bool

    Returns
    -------
    flags : list of TagFlag
    bad : set
        (family, index, slice, frame) of the flagged lines.
    notes : list of str
        How many lines were left out (empty when none).
    """
    flags = tag_qc(study, threshold, frames=study.tagged_frames, long_axis=long_axis,
                   surfaces=surfaces)
    bad = {(fl.family, fl.index, fl.slice, fl.frame) for fl in flags}
    notes: list[str] = []
    if exclude_flagged and any(b[3] in surfaces for b in bad):
        for f in frames:
            ex = {(b[0], b[1], b[2]) for b in bad if b[3] == f}
            if ex:
                surfaces[f] = build_tag_surfaces(study, f, long_axis, exclude=ex)
        notes.append(f"{sum(b[3] in surfaces for b in bad)} flagged tag line(s) left out of "
                     "the tag surfaces")
    return flags, bad, notes


def _twist_over_time(study: Study, mp: MaterialPoints, frames: list[int], ed_frame: int,
                     long_axis: tuple, radius) -> dict[int, dict[str, float]]:
    """Frame -> {"Twist (deg)", "LS (%)"} relative to ED at every one of ``frames``.

    Parameters
    ----------
    study : Study
    mp : MaterialPoints
        The material points of the frames.
    frames : list of int
    ed_frame : int
    long_axis : (apex, base), mm
    radius : callable or None
        The ED epicardial radius profile (:func:`epicardial_radius_profile`).

    Returns
    -------
    dict
    """
    apex, base = long_axis
    times = {}
    for f in frames:
        lv = level_table(mp, f, apex, base, radius, tagged_stack_range(study, ed_frame, f))
        t = twist_from_levels(lv)
        times[f] = {"Twist (deg)": t["Twist (deg)"], "LS (%)": t["LS (%)"]}
    return times


# ---------------------------------------------------------------- export
def tag_surfaces_dict(study: Study, frames: list[int] | None = None,
                      long_axis: tuple | None = None, surfaces: dict | None = None) -> dict:
    """JSON-safe tag surfaces for saving with the model.

    ``{"long_axis": {"apex", "base"}, "frames": {"<frame>": {"<family>:<index>":
    NurbsSurface.to_dict(), ...}}}``, scanner mm; ``frames`` defaults to every
    tagged frame. Read back with :meth:`cardionurbs.nurbs.NurbsSurface.from_dict`.
    ``surfaces`` ({frame: {(family, index): TagSurface}}, e.g.
    :attr:`TagMetrics.surfaces`) are used where given instead of being rebuilt.

    Parameters
    ----------
    study : Study
        The study.
    frames : list of int or None
        As above.
    long_axis : (apex (3,), base (3,)) or None
        At ED, mm; None: from the landmarks.
    surfaces : dict or None
        As above.

    Returns
    -------
    dict
    """
    surfaces = surfaces or {}
    frames = study.tagged_frames if frames is None else list(frames)
    if long_axis is None and any(study.tags_at(f, "la") for f in frames):
        long_axis = study_long_axis(study)
    out: dict = {"frames": {}}
    if long_axis is not None:
        out["long_axis"] = {"apex": [float(x) for x in long_axis[0]],
                            "base": [float(x) for x in long_axis[1]]}
    for f in frames:
        built = surfaces.get(f)
        if built is None:
            built = build_tag_surfaces(study, f, long_axis)
        out["frames"][str(f)] = {f"{fam}:{idx}": ts.surface.to_dict()
                                 for (fam, idx), ts in sorted(built.items())}
    return out


# ---------------------------------------------------------------- figures
def tag_figure_data(study: Study, frame: int, long_axis: tuple | None = None,
                    flags: list[TagFlag] | None = None, nu: int = 24, nv: int = 16,
                    surfaces: dict | None = None) -> list[dict]:
    """Tessellated tag surfaces of one frame, with flag status, for figures (paper Fig. 8).

    Returns one dict per tag surface: ``family``, ``index``, ``frame``,
    ``vertices`` (k, 3) mm, ``faces`` (m, 3) int, ``flagged`` (bool: a line
    of this tag at this frame is flagged), ``flagged_slices`` (list), and
    ``lines``: [{"slice", "points" (n, 3), "flagged"}] the tag lines.
    ``flags`` defaults to :func:`tag_qc` of that frame. ``surfaces``: that frame's
    ``build_tag_surfaces(study, frame, long_axis)`` when already built (every line kept).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    long_axis : (apex (3,), base (3,)) or None
        At ED, mm.
    flags : list of TagFlag or None
        As above.
    nu, nv : int
        Tessellation samples per surface.
    surfaces : dict or None
        As above.

    Returns
    -------
    list of dict
        As above.
    """
    from cardionurbs import nurbs
    if long_axis is None and study.tags_at(frame, "la"):
        long_axis = study_long_axis(study)
    surfs = surfaces if surfaces is not None else build_tag_surfaces(study, frame, long_axis)
    if flags is None:
        flags = tag_qc(study, frames=[frame], long_axis=long_axis, surfaces={frame: surfs})
    bad = {(f.family, f.index, f.slice) for f in flags if f.frame == frame}
    out = []
    for (fam, idx), ts in sorted(surfs.items()):
        verts, faces = nurbs.tessellate(ts.surface, nu, nv)
        flagged_slices = sorted({s for (f_, i_, s) in bad if f_ == fam and i_ == idx})
        out.append({
            "family": fam, "index": idx, "frame": frame,
            "vertices": np.asarray(verts), "faces": np.asarray(faces),
            "flagged": bool(flagged_slices), "flagged_slices": flagged_slices,
            "lines": [{"slice": t.slice, "points": np.asarray(t.points),
                       "flagged": (fam, idx, t.slice) in bad}
                      for t in study.tags_at(frame, fam) if t.index == idx],
        })
    return out
