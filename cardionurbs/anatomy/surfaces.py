"""NURBS surfaces of one ventricular boundary at one frame (paper §3.2, §4.2).

Steps for one surface (lv_endo, lv_epi, rv_endo or rv_epi):

1. **Sections.** The SA contours (ordered base -> apex), plus *synthetic*
   sections where long-axis (LA) contours show the surface beyond the SA
   stack: between the most apical SA slice and the apex, and between the most
   basal SA slice and the valve plane, the nearest SA section's shape is
   scaled about a centre line to pass through the LA contours' crossings of
   the level plane (:func:`cardionurbs.anatomy.sections.scaled_section`),
   every ``SYNTHETIC_STEP_MM``; for the RV surfaces the spacing next to the
   SA stack is graded from half the SA gap down to that step
   (:func:`synthetic_offsets`), so that the loft does not overshoot in a wide
   SA gap next to closely spaced sections. One more section, the basal one moved beyond the valve plane, lets the
   mesh be cut exactly by that plane.
2. **Common parameterisation.** Each closed section is resampled uniformly in
   arc length from a start point on a common anatomical ray (towards the RV
   free wall) and in one winding sense, so that the same parameter u means
   the same side of the heart on every section (no twist in the loft). RV
   sections are resampled so again once their septal run has been moved into
   the LV wall (:func:`embed_septa`).
3. **Curve fit within tolerance (paper §3.2, eqs. 6–10, §3.2.4).** Every
   section is fitted with a closed (periodic) degree-3 NURBS curve by
   :func:`cardionurbs.nurbs.fit_compatible_curves`: one knot vector for all
   sections of the surface, by eq. 9 (periodic form) on their averaged
   chord-length parameters, and the control-point count, common to all
   sections, is the smallest of ``N_CTRL_STEPS`` (12, 16, 20, 26, 32, 40, 52)
   at which every contour point lies within ``tol_px`` (default 1) pixel of
   its section's curve (true closest-point distance); the largest count, with
   a warning, when none does.
4. **Lofting (paper §3.2.4).** The curves, base to apex, are lofted with
   degree 3 across sections and the apex as a collapsed end (a point).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from cardionurbs import nurbs
from cardionurbs.anatomy.sections import (FrameGeometry, Section, embed_septum,
                                          fill_short_gaps, ray_exit, scaled_section,
                                          septal_mask)
from cardionurbs.errors import ReconstructionError
from cardionurbs.geometry import (in_plane_basis, points_in_polygon, polygon_area, polygon_centroid,
                                  polyline_crossings)

#: control-point counts tried (common to all sections of a surface)
N_CTRL_STEPS = (12, 16, 20, 26, 32, 40, 52)
#: distance (mm) within which an RV section point counts as septal for the taper anchor
SEPTUM_NEAR_MM_TAPER = 1.5
#: points per resampled section
N_SAMPLES = 120
#: spacing (mm) of synthetic sections built from LA contours
SYNTHETIC_STEP_MM = 2.5
#: largest ratio of neighbouring section intervals in a graded stack (:func:`synthetic_offsets`)
GRADING_RATIO = 2.0
#: surfaces whose synthetic sections are graded next to the SA stack (the LV surfaces are
#: corrected towards the LA points afterwards, anatomy.refine, and keep every 2.5 mm)
GRADED_STRUCTURES = ("rv_endo", "rv_epi")
#: RV contour points within this many pixels of the LV epicardial contour are septal
SEPTUM_NEAR_PX = 0.5
#: free-wall runs shorter than this fraction of an RV loop, between septal points, are septal
SEPTUM_GAP_FRACTION = 0.125


@dataclass(eq=False)
class SurfaceFit:
    """A lofted surface and what it was made of.

    Attributes
    ----------
    structure : str
        The surface (``"lv_endo"``, ``"lv_epi"``, ``"rv_endo"``, ``"rv_epi"``).
    frame : int
        The frame index, 0-based.
    surface : cardionurbs.nurbs.NurbsSurface
        The lofted surface (control points in mm; u around, v base to apex).
    sections : list of cardionurbs.anatomy.sections.Section
        The sections lofted, base to apex (real and synthetic).
    apex : ndarray, shape (3,)
        The collapsed apex point, in mm.
    n_ctrl : int
        Control points per section curve.
    curve_error_mm : float
        The largest distance of a contour point to its section curve where it exceeds the
        tolerance, in mm; NaN when every section met it.
    warnings : list of str
        What the fit left out or could not meet, one line each.
    """

    structure: str
    frame: int
    surface: "nurbs.NurbsSurface"
    sections: list[Section]
    apex: np.ndarray
    n_ctrl: int
    curve_error_mm: float          # max distance of a contour point to its section curve when
    #                                it exceeds the tolerance; NaN when every section met it
    warnings: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- resampling
def periodic_spline(points: np.ndarray) -> tuple[CubicSpline, float]:
    """Periodic cubic interpolant through a closed loop, parameterised by chord
    length (paper eq. 6–8 applied to the closed polygon); returns (spline, length).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed loop (first point not repeated), in mm.

    Returns
    -------
    spline : scipy.interpolate.CubicSpline
        The loop as a function of arc parameter s in mm, periodic.
    length : float
        The chord length of the loop, in mm.
    """
    p = np.asarray(points, dtype=float)
    step = np.linalg.norm(np.diff(np.vstack([p, p[:1]]), axis=0), axis=1)
    p = p[step > 1e-9]                      # drop repeated points (and a repeated end point)
    closed = np.vstack([p, p[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    return CubicSpline(s, closed, bc_type="periodic"), float(s[-1])


def resample_loop(points: np.ndarray, direction: np.ndarray, ref: np.ndarray,
                  origin: np.ndarray | None = None, m: int = N_SAMPLES) -> np.ndarray:
    """``m`` points uniformly spaced in arc length around a closed loop,
    counter-clockwise about ``direction``, starting where the ray from ``origin``
    (default: the loop's centroid) along ``ref`` leaves the loop.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed loop, in mm.
    direction : ndarray, shape (3,)
        The unit stacking direction (the loop runs counter-clockwise about it).
    ref : ndarray, shape (3,)
        The seam direction (LV → RV).
    origin : ndarray, shape (3,), optional
        The seam ray's origin, in mm (default the loop's area centroid).
    m : int, optional
        Points of the result (default :data:`N_SAMPLES`).

    Returns
    -------
    ndarray, shape (m, 3)
        The resampled loop, in mm.
    """
    p = np.asarray(points, dtype=float)
    if polygon_area(p, direction, signed=True) < 0:
        p = p[::-1]
    spline, length = periodic_spline(p)
    dense_s = np.linspace(0.0, length, 8 * m, endpoint=False)
    dense = spline(dense_s)
    seg = np.linalg.norm(np.diff(np.vstack([dense, dense[:1]]), axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    total = arc[-1]
    o = polygon_centroid(dense, direction) if origin is None else origin
    r = ref - (ref @ direction) * direction
    t = ray_exit(dense, o, r, normal=direction)
    if np.isfinite(t):
        hit = o + t * r / np.linalg.norm(r)
        k = int(np.argmin(np.linalg.norm(dense - hit, axis=1)))
        start = arc[k]
    else:
        start = 0.0
    target = (start + total * np.arange(m) / m) % total
    s_of_arc = np.interp(target, arc, np.concatenate([dense_s, [length]]))
    return spline(s_of_arc)


# ---------------------------------------------------------------- sections
def _level(x: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.asarray(x) @ n


def free_wall_targets(targets: np.ndarray, centre: np.ndarray,
                      side: np.ndarray | None) -> np.ndarray:
    """The LA crossing on the RV free wall: of the crossings on the RV side of the LV
    centre ((q − centre)·side > 0, ``side`` the LV -> RV direction), the one farthest
    from it (the septal crossings lie on the LV epicardium, nearer the centre).
    ``side`` None: all targets (LV surfaces).

    Parameters
    ----------
    targets : ndarray, shape (k, 3)
        LA contour crossings of a level plane, in mm.
    centre : ndarray, shape (3,)
        The LV centre at that level, in mm.
    side : ndarray, shape (3,) or None
        The LV → RV direction.

    Returns
    -------
    ndarray, shape (j, 3)
        The kept crossings (j <= 1 with ``side``), in mm.
    """
    if side is None or not len(targets):
        return targets
    rel = targets - centre
    rv_side = targets[rel @ side > 0]
    if not len(rv_side):
        return rv_side
    return rv_side[[int(np.argmax(np.linalg.norm(rv_side - centre, axis=1)))]]


def synthetic_offsets(span: float, step: float, sa_gap: float | None = None,
                      ratio: float | None = None, reach_end: bool = False) -> np.ndarray:
    """Distances (mm, increasing) from the end SA section of a stack to its synthetic
    sections, all within ``span`` (the distance to the valve plane's reach, or to the apex).

    Without ``sa_gap``: every ``step`` mm. With ``sa_gap`` (the spacing between the end SA
    section and its neighbour in the stack) the spacing is *graded*: the first interval is
    ``sa_gap / ratio`` (default ``GRADING_RATIO``), each next one ``ratio`` times smaller,
    until it reaches ``step``;
    so no two neighbouring intervals of the whole stack (SA gap included) differ by more
    than ``ratio``. A degree-3 interpolating loft across sections inherits the slope of its
    closely spaced sections into a wide neighbouring interval and overshoots there (the
    mesh-ratio condition of spline interpolation: de Boor, *A Practical Guide to Splines*,
    ch. XII; NURBS Book §9.2.1 on chord-length parameters with uneven spacing); a bounded
    ratio keeps that slope to what the SA gap itself resolves.

    ``reach_end``: the sections divide the rest of the span into equal intervals of at most
    ``step`` up to its end (the apex, which is itself a section of the loft); otherwise they
    continue every ``step`` while inside the span.

    Parameters
    ----------
    span : float
        The distance available, in mm.
    step : float
        The largest spacing, in mm.
    sa_gap : float or None, optional
        The end SA section's spacing to its neighbour, in mm.
    ratio : float or None, optional
        The grading ratio (default :data:`GRADING_RATIO`).
    reach_end : bool, optional
        Divide the rest of the span equally up to its end.

    Returns
    -------
    ndarray, shape (k,)
        The offsets, in mm, increasing.
    """
    ratio = GRADING_RATIO if ratio is None else float(ratio)
    graded: list[float] = []
    d = 0.0
    if sa_gap is not None:
        inc = sa_gap / ratio
        while inc > step and d + inc + step <= span:
            d += inc
            graded.append(d)
            inc /= ratio
    rest = span - d
    if rest <= 0:
        return np.asarray(graded)
    # (a rest a rounding error above a whole number of steps is that number of steps: no
    # section a rounding error inside the span's end)
    k = int(np.ceil(rest / step * (1.0 - 1e-12)))
    tail = d + (rest * np.arange(1, k) / k if reach_end else step * np.arange(1, k))
    return np.concatenate([graded, tail])


def end_gap(secs: list[Section], direction: np.ndarray, end: int) -> float | None:
    """Spacing (mm) along ``direction`` between the end SA section (``end`` 0: basal, -1:
    apical) and its neighbour; None for a single section.

    Parameters
    ----------
    secs : list of cardionurbs.anatomy.sections.Section
        The SA sections, base to apex.
    direction : ndarray, shape (3,)
        The unit stacking direction.
    end : int
        0 (basal) or -1 (apical).

    Returns
    -------
    float or None
        The spacing in mm.
    """
    if len(secs) < 2:
        return None
    nb = 1 if end == 0 else -2
    return abs(float(_level(secs[nb].points, direction).mean())
               - float(_level(secs[end].points, direction).mean()))


def synthetic_sections(geo: FrameGeometry, structure: str, secs: list[Section],
                       apex: np.ndarray) -> tuple[list[Section], list[Section]]:
    """Synthetic (basal, apical) sections from LA contour crossings (see module doc).

    Parameters
    ----------
    geo : cardionurbs.anatomy.sections.FrameGeometry
        The frame's geometry.
    structure : str
        The surface.
    secs : list of cardionurbs.anatomy.sections.Section
        Its SA sections, base to apex.
    apex : ndarray, shape (3,)
        Its apex point, in mm.

    Returns
    -------
    basal : list of cardionurbs.anatomy.sections.Section
        Synthetic sections beyond the basal SA section, towards the valve plane.
    apical : list of cardionurbs.anatomy.sections.Section
        Synthetic sections beyond the apical SA section, towards the apex.
    """
    n = geo.direction
    la = geo.la_points.get(structure, [])
    if not la and secs and structure in geo.taper:
        return [], taper_sections(geo, structure, secs)
    if not la or not secs:
        return [], []
    rv = structure.startswith("rv")
    graded = structure in GRADED_STRUCTURES
    side = geo.reference if rv else None
    first, last = secs[0], secs[-1]
    h0 = float(_level(first.points, n).mean())
    hk = float(_level(last.points, n).mean())
    ha = float(apex @ n)

    def anchor_of(sec: Section) -> tuple[np.ndarray, np.ndarray | None]:
        """(centre of the shape, scaling anchor): the RV scales about the LV centre."""
        if rv and sec.septum_of is not None:
            a = polygon_centroid(sec.septum_of, n)
            return a, a
        return polygon_centroid(sec.points, n), None

    c_last, a_last = anchor_of(last)
    step = SYNTHETIC_STEP_MM      # next to the stack an RV surface is graded (synthetic_offsets)
    apical = []
    gap = ha - hk
    if gap > step:
        for f in synthetic_offsets(gap, step, sa_gap=end_gap(secs, n, -1) if graded else None,
                                   reach_end=True) / gap:
            h = hk + f * gap
            targets = np.concatenate([polyline_crossings(pl, n, h) for pl in la])
            centre = c_last if a_last is not None else (1 - f) * c_last + f * apex
            res = scaled_section(last, h, n, centre, free_wall_targets(targets, centre, side),
                                 anchor=a_last)
            if res is not None and res[1] > 0.02:
                apical.append(Section(structure, geo.frame, res[0], synthetic=True, scale=res[1],
                                      template=-1))
    basal = []
    plane = geo.base_planes.get("rv" if rv else "lv")
    c_first, a_first = anchor_of(first)
    if plane is not None:
        # the most basal level any part of the valve plane reaches inside the LA contours
        la_all = np.concatenate(la)
        h_top = float(_level(la_all, n).min())
        for off in synthetic_offsets(h0 - h_top - 0.5, step,
                                     sa_gap=end_gap(secs, n, 0) if graded else None):
            h = h0 - off
            targets = np.concatenate([polyline_crossings(pl, n, h) for pl in la])
            # only LA crossings on the apical side of the valve plane
            if len(targets):
                targets = targets[plane.signed_distance(targets) >= -0.5]
            if not len(targets):
                break
            res = scaled_section(first, h, n, c_first, free_wall_targets(targets, c_first, side),
                                 anchor=a_first)
            if res is None:
                break
            basal.insert(0, Section(structure, geo.frame, res[0], synthetic=True, scale=res[1],
                                    template=0))
    return basal, apical


def septal_anchor(sec: Section, direction: np.ndarray) -> np.ndarray | None:
    """The middle of an RV section's septal run (of its points on the LV epicardium, the one
    nearest their centroid): the point a tapering crescent shrinks towards, so that it keeps
    its septal middle on the septum (scaled about the LV centre it would sink into the LV
    wall, which the RV solids subtract). None without an LV epicardial loop or septal
    points (then the crescent scales about its centroid).

    Parameters
    ----------
    sec : cardionurbs.anatomy.sections.Section
        An RV section (with ``septum_of``).
    direction : ndarray, shape (3,)
        The unit stacking direction.

    Returns
    -------
    ndarray, shape (3,) or None
        The anchor, in mm.
    """
    if sec.septum_of is None:
        return None
    sept = septal_mask(sec.points, sec.septum_of, direction, SEPTUM_NEAR_MM_TAPER)
    if not sept.any() or sept.all():
        return None
    run = sec.points[sept]
    return run[np.argmin(np.linalg.norm(run - run.mean(axis=0), axis=1))]


def taper_sections(geo: FrameGeometry, structure: str, secs: list[Section]) -> list[Section]:
    """Synthetic apical sections of an SA-only surface: the most apical section scaled so
    that its area follows the fitted taper (:class:`~cardionurbs.anatomy.sections.ApicalTaper`)
    at every ``SYNTHETIC_STEP_MM`` up to the apex, its centre moving to the apex.

    An RV crescent shrinks towards its septal run (:func:`septal_anchor`), and its scale
    is chosen so that the part outside the LV epicardium at that level (the RV solids
    subtract the LV) has the tapered area (:func:`crescent_scale`); scaled by the square
    root of the area ratio alone, its tips would sink into the LV wall and the RV apex
    would come out too small.

    Parameters
    ----------
    geo : cardionurbs.anatomy.sections.FrameGeometry
        The frame's geometry (its ``taper``).
    structure : str
        The surface.
    secs : list of cardionurbs.anatomy.sections.Section
        Its SA sections, base to apex.

    Returns
    -------
    list of cardionurbs.anatomy.sections.Section
        The synthetic apical sections, base to apex.
    """
    n, tp = geo.direction, geo.taper[structure]
    last = secs[-1]
    rv = structure.startswith("rv")
    anchor = septal_anchor(last, n) if rv else None
    centre0 = polygon_centroid(last.points, n) if anchor is None else anchor
    apex = geo.apex[structure]
    a_last = polygon_area(last.points, n)
    gap = tp.apex - tp.level
    out = []
    k = int(np.ceil(gap / SYNTHETIC_STEP_MM))
    for f in np.arange(1, k) / k:
        h = tp.level + f * gap
        ratio = float(tp.area_ratio(h))
        scale = float(np.sqrt(ratio))
        if scale <= 0.02:
            break
        if anchor is not None:
            lv = lv_epi_loop_at(geo, h)
            if lv is not None:
                scale = crescent_scale(last.points, anchor, ratio * a_last, lv, n)
        centre = centre0 if anchor is not None else (1 - f) * centre0 + f * apex
        res = scaled_section(last, h, n, centre, None, default_scale=scale, anchor=anchor)
        out.append(Section(structure, geo.frame, res[0], synthetic=True, scale=res[1], template=-1))
    return out


def _polar_loop(loop: np.ndarray, centre: np.ndarray, basis: np.ndarray,
                phi: np.ndarray) -> np.ndarray:
    """Radii (mm) of a star-shaped loop about ``centre`` at the in-plane angles ``phi``."""
    xy = (loop - centre) @ basis.T
    ang = np.arctan2(xy[:, 1], xy[:, 0])
    order = np.argsort(ang)
    return np.interp(phi, ang[order], np.linalg.norm(xy, axis=1)[order], period=2 * np.pi)


def lv_epi_loop_at(geo: FrameGeometry, level: float, n_angles: int = 180) -> np.ndarray | None:
    """The LV epicardial section at ``level`` (mm along the stacking direction) of an SA-only
    frame: between two SA sections the radii about their centroids interpolated linearly in
    the level; beyond the most apical one, that section scaled by its apical taper; None
    where there is no LV epicardium.

    Parameters
    ----------
    geo : cardionurbs.anatomy.sections.FrameGeometry
        An SA-only frame's geometry.
    level : float
        The level, in mm along the stacking direction.
    n_angles : int, optional
        Points of the loop.

    Returns
    -------
    ndarray, shape (n_angles, 3) or None
        The loop, in mm.
    """
    secs = geo.sections.get("lv_epi") or []
    if not secs:
        return None
    n = geo.direction
    basis = in_plane_basis(n)
    levels = np.array([float(sec.points.mean(axis=0) @ n) for sec in secs])
    phi = np.linspace(-np.pi, np.pi, n_angles, endpoint=False)
    ring = np.stack([np.cos(phi), np.sin(phi)], axis=1) @ basis
    if level > levels[-1]:
        tp = geo.taper.get("lv_epi")
        ratio = float(tp.area_ratio(level)) if tp is not None else 0.0
        if ratio <= 0.0:
            return None
        c = polygon_centroid(secs[-1].points, n)
        r = np.sqrt(ratio) * _polar_loop(secs[-1].points, c, basis, phi)
    else:
        i = int(np.clip(np.searchsorted(levels, level) - 1, 0, len(secs) - 2)) if len(secs) > 1 else 0
        j = min(i + 1, len(secs) - 1)
        t = 0.0 if j == i else float(np.clip((level - levels[i]) / (levels[j] - levels[i]), 0, 1))
        ci, cj = polygon_centroid(secs[i].points, n), polygon_centroid(secs[j].points, n)
        c = (1 - t) * ci + t * cj
        r = ((1 - t) * _polar_loop(secs[i].points, ci, basis, phi)
             + t * _polar_loop(secs[j].points, cj, basis, phi))
    c = c + (level - float(c @ n)) * n
    return c + r[:, None] * ring


def crescent_scale(template: np.ndarray, anchor: np.ndarray, target_area: float,
                   lv_epi: np.ndarray, normal: np.ndarray, samples: int = 60) -> float:
    """The scale s of ``anchor + s·(template − anchor)`` (in-plane) whose part outside the LV
    epicardial loop ``lv_epi`` has ``target_area`` (mm²): the template's interior sampled on a
    grid (``samples`` steps across its extent), each sample weighing s²·dA, bisection on s
    in (0, 1] (the crescent only shrinks towards the apex).

    Parameters
    ----------
    template : ndarray, shape (k, 3)
        The RV section loop, in mm.
    anchor : ndarray, shape (3,)
        The scaling anchor, in mm.
    target_area : float
        The area wanted outside the LV epicardium, in mm².
    lv_epi : ndarray, shape (m, 3)
        The LV epicardial loop at that level, in mm.
    normal : ndarray, shape (3,)
        The plane's unit normal.
    samples : int, optional
        Grid steps across the template.

    Returns
    -------
    float
        The scale s in (0, 1].
    """
    basis = in_plane_basis(normal)
    t = (template - anchor) @ basis.T
    lv = (lv_epi - anchor) @ basis.T
    lo, hi = t.min(axis=0), t.max(axis=0)
    step = float((hi - lo).max()) / samples
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], step) + step / 2,
                         np.arange(lo[1], hi[1], step) + step / 2)
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    inside = grid[points_in_polygon(grid, t)]
    if not len(inside) or target_area <= 0:
        return 0.0

    def outside_area(s: float) -> float:
        return s * s * step * step * np.count_nonzero(~points_in_polygon(s * inside, lv))

    if outside_area(1.0) <= target_area:
        return 1.0
    a, b = 0.0, 1.0
    for _ in range(10):                 # to 1e-3 of the scale
        m = 0.5 * (a + b)
        a, b = (m, b) if outside_area(m) < target_area else (a, m)
    return 0.5 * (a + b)


def embed_septa(real: list[Section], synthetic: list[Section], direction: np.ndarray,
                near_px: float, ref: np.ndarray | None = None) -> None:
    """Move the septal part of RV sections into the LV wall (see
    :func:`cardionurbs.anatomy.sections.embed_septum`), in place, after the
    common resampling: real sections by their slice's LV epicardial loop,
    synthetic ones by their template's displacement times their scale.

    With ``ref`` (the seam direction of :func:`resample_loop`) every moved loop is then
    resampled again, uniformly in arc length from the same seam: the septal run moves a
    fixed depth, which opens a step of about that depth at each insertion between two
    neighbouring samples. On a section a few millimetres across (the last slice before the
    RV apex) such a step spans many sample spacings; fitted on the loop's uniform
    parameters the curve must jump there, its control points swing tens of millimetres
    out, and the loft folds through them (a negative volume that the divergence theorem
    subtracts from the cavity).

    Parameters
    ----------
    real : list of cardionurbs.anatomy.sections.Section
        The RV surface's SA sections (moved in place).
    synthetic : list of cardionurbs.anatomy.sections.Section
        Its synthetic sections (moved in place).
    direction : ndarray, shape (3,)
        The unit stacking direction.
    near_px : float
        Septal distance, in pixels of each section's image.
    ref : ndarray, shape (3,) or None, optional
        The seam direction; given, every moved loop is resampled from it.
    """
    disp = []
    for sec in real:
        d = np.zeros_like(sec.points)
        if sec.septum_of is not None:
            near = near_px * _pixel_mm(sec)
            raw = septal_mask(sec.points, sec.septum_of, direction, near)
            sept = fill_short_gaps(raw, septum_gap(len(sec.points)))
            d = embed_septum(sec.points, sec.septum_of, direction, mask=sept)[0] - sec.points
            sec.source_points = free_wall_points(sec, direction, near_px, loop_mask=raw)
        disp.append(d)
        sec.points = sec.points + d
    for sec in synthetic:
        sec.points = sec.points + sec.scale * disp[sec.template]
    if ref is not None:
        for sec in real + synthetic:
            sec.points = resample_loop(sec.points, direction, ref, m=len(sec.points))


def septum_gap(n_points: int) -> int:
    """Longest run of an ordered RV loop's points (``SEPTUM_GAP_FRACTION`` of them) that
    may lie between septal points and still be septal (contour noise, not free wall).

    Parameters
    ----------
    n_points : int
        Points of the loop.

    Returns
    -------
    int
        The longest run, in points.
    """
    return int(SEPTUM_GAP_FRACTION * n_points)


def free_wall_points(sec: Section, direction: np.ndarray, near_px: float = SEPTUM_NEAR_PX,
                     loop_mask: np.ndarray | None = None) -> np.ndarray:
    """The contour points of an RV section that are not on the septum (the septal
    ones lie on the LV epicardium, which bounds the RV there; see embed_septum).

    A source point is septal by its own distance to the LV epicardial loop, or when
    its nearest point of the section's ordered loop lies in a short gap of the loop's
    septal run (:func:`cardionurbs.anatomy.sections.fill_short_gaps`), so that the
    points classified agree with the loop that is embedded (``loop_mask``: the loop's
    own septal points before the gaps are filled, when already known).

    Parameters
    ----------
    sec : cardionurbs.anatomy.sections.Section
        An RV section with ``source_points`` and ``septum_of``.
    direction : ndarray, shape (3,)
        The unit stacking direction.
    near_px : float, optional
        Septal distance, in pixels of the section's image.
    loop_mask : ndarray of bool, optional
        The loop's septal points before the gaps are filled.

    Returns
    -------
    ndarray, shape (f, 3)
        The free-wall source points, in mm.
    """
    if sec.septum_of is None or sec.source_points is None:
        return sec.source_points
    near = near_px * _pixel_mm(sec)
    src = sec.source_points
    own = septal_mask(src, sec.septum_of, direction, near)
    loop_raw = septal_mask(sec.points, sec.septum_of, direction, near) if loop_mask is None \
        else loop_mask
    filled = fill_short_gaps(loop_raw, septum_gap(len(sec.points))) & ~loop_raw
    sept = own
    if filled.any():
        _, k = cKDTree(sec.points).query(src)
        sept = own | filled[k]
    if not sept.any() or sept.all():
        return src
    return src[~sept]


def extension_section(basal: Section, geo: FrameGeometry, structure: str,
                      margin_mm: float = 2.0) -> Section:
    """The basal section moved along −n until all of it lies ≥ ``margin_mm`` beyond
    the valve plane (and at least half a slice thickness, plus ``geo.base_slack``
    and the margin when the plane may still move basally), so that trimming by
    the plane leaves a clean planar base.

    Parameters
    ----------
    basal : cardionurbs.anatomy.sections.Section
        The most basal section.
    geo : cardionurbs.anatomy.sections.FrameGeometry
        The frame's geometry (valve planes, thickness, base slack).
    structure : str
        The surface.
    margin_mm : float, optional
        The least distance beyond the valve plane, in mm.

    Returns
    -------
    cardionurbs.anatomy.sections.Section
        The moved (synthetic) section.
    """
    n = geo.direction
    plane = geo.base_planes.get("lv" if structure.startswith("lv") else "rv")
    t = 0.5 * geo.thickness + (geo.base_slack + margin_mm if geo.base_slack > 0 else 0.0)
    if plane is not None:
        k = float(n @ plane.normal)
        if k > 0.05:
            d = plane.signed_distance(basal.points)
            t = max(t, (float(d.max()) + margin_mm) / k)
    return Section(structure, geo.frame, basal.points - t * n, synthetic=True)


# ---------------------------------------------------------------- lofting
def skin(curves: list, apex: np.ndarray, degree_v: int = 3):
    """Loft compatible closed sections and a collapsed apex into one surface
    (paper §3.2.4 steps 4–5; NURBS Book §10.3 skinning).

    The sections here already share degree, knot vector, orientation and seam
    (:func:`resample_loop`, :func:`cardionurbs.nurbs.fit_compatible_curves`), so steps 1–3 of
    :func:`cardionurbs.nurbs.loft` are identities; its seam re-alignment would
    only perturb the shared knots (and multiply the control points through knot
    merging), so only the interpolation across sections is done, by
    :func:`cardionurbs.nurbs.loft_compatible` (the loft's own last step).
    Falls back to :func:`cardionurbs.nurbs.loft` when the knots differ.

    Parameters
    ----------
    curves : list of cardionurbs.nurbs.NurbsCurve
        Compatible closed section curves, base to apex (control points in mm).
    apex : ndarray, shape (3,)
        The collapsed apex point, in mm.
    degree_v : int, optional
        The degree across sections.

    Returns
    -------
    cardionurbs.nurbs.NurbsSurface
        The lofted surface (u around, v base to apex, the last row collapsed at ``apex``).
    """
    k0 = curves[0].knots
    if not all(c.knots.shape == k0.shape and np.allclose(c.knots, k0, atol=1e-12)
               and c.degree == curves[0].degree and np.allclose(c.weights, 1.0) for c in curves):
        return nurbs.loft(list(curves) + [apex], degree_v=degree_v)
    return nurbs.loft_compatible(np.stack([c.control_points for c in curves]), k0,
                                 curves[0].degree, degree_v, closed_u=True, end_point=apex)


def _pixel_mm(sec: Section) -> float:
    return float(np.mean(sec.plane.pixel_spacing)) if sec.plane is not None else 1.0


def build_surface(geo: FrameGeometry, structure: str, ref: np.ndarray,
                  tol_px: float = 1.0) -> SurfaceFit:
    """Loft one surface of one frame (module doc, steps 1–4).

    ``ref`` is the in-plane reference direction (from LV towards RV) that fixes
    where every section's parameterisation starts.

    Parameters
    ----------
    geo : cardionurbs.anatomy.sections.FrameGeometry
        The frame's geometry.
    structure : str
        The surface (``"lv_endo"``, ``"lv_epi"``, ``"rv_endo"``, ``"rv_epi"``).
    ref : ndarray, shape (3,)
        The in-plane reference direction (LV → RV).
    tol_px : float, optional
        The section curves' fitting tolerance, in pixels of each section's image.

    Returns
    -------
    SurfaceFit
        The surface, its sections, apex and warnings.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        Too few SA contours, or the loft fails.
    """
    secs = geo.sections.get(structure) or []
    frame = geo.frame
    if len(secs) < 2:
        raise ReconstructionError(f"{structure}, frame {frame}: needs SA contours on at least "
                                  f"2 slices, has {len(secs)}")
    n = geo.direction
    apex = geo.apex[structure]
    warnings: list[str] = []
    # common parameterisation of the real sections first (templates for synthetic ones)
    real = [Section(s.structure, s.frame, resample_loop(s.points, n, ref), s.slice, s.plane,
                    False, s.source_points, s.septum_of) for s in secs]
    basal, apical = synthetic_sections(geo, structure, real, apex)
    if structure.startswith("rv"):
        embed_septa(real, basal + apical, n, SEPTUM_NEAR_PX, ref)
    stack = basal + real + apical
    ext = extension_section(stack[0], geo, structure)
    stack = [ext] + stack
    loops = [s.points for s in stack]
    sources = [None if s.synthetic else s.source_points for s in stack]
    tol = [tol_px * (_pixel_mm(s) if not s.synthetic else 1.0) for s in stack]
    curves, n_ctrl, err, ok = nurbs.fit_compatible_curves(loops, degree=3, closed=True, tol=tol,
                                                          error_points=sources, counts=N_CTRL_STEPS,
                                                          measure_error=False)
    if not ok:
        warnings.append(f"{structure}, frame {frame}: contour fit error {err:.2f} mm exceeds "
                        f"{tol_px:g} px with {n_ctrl} control points")
    try:
        surface = skin(curves, apex, degree_v=3)
    except Exception as exc:  # a NURBS input error is a reconstruction failure here
        raise ReconstructionError(f"{structure}, frame {frame}: loft failed: {exc}") from exc
    return SurfaceFit(structure, frame, surface, stack, apex, n_ctrl, err, warnings)
