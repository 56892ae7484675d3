"""Cross-sections of the ventricles: contour ordering and closing, RV assembly,
the stacking direction, apex points and valve planes of one frame.

Everything here works on point arrays in scanner mm; the NURBS fitting and
lofting is in :mod:`cardionurbs.anatomy.surfaces`.

Conventions
-----------
* A *section* is one closed loop of points (no repeated end point) in one
  plane, with the slice it came from (``synthetic`` sections are built from
  long-axis contours between or beyond the short-axis slices).
* The *stacking direction* ``n`` is the mean SA plane normal oriented from
  base to apex; the *level* of a point x is (x − o)·n for a fixed origin o.
* A valve :class:`~cardionurbs.anatomy.mesh.Plane` has its normal pointing to
  the apical (kept) side.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree
from scipy.spatial import cKDTree

from cardionurbs.anatomy.mesh import Plane
from cardionurbs.cache import attached
from cardionurbs.errors import ReconstructionError
from cardionurbs.geometry import (fit_plane, in_plane_basis, long_axis, points_in_polygon,
                                  polygon_area, polygon_centroid, stack_normal)
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.study import Contour, Study
from cardionurbs.median import median

SURFACES = ("lv_endo", "lv_epi", "rv_endo", "rv_epi")


@dataclass(eq=False)
class Section:
    """One closed planar cross-section of a surface (scanner mm, ordered loop).

    Attributes
    ----------
    structure : str
        The surface (``"lv_endo"``, ``"lv_epi"``, ``"rv_endo"``, ``"rv_epi"``).
    frame : int
        The frame index, 0-based.
    points : ndarray, shape (k, 3)
        The ordered loop, in mm (scanner coordinates).
    slice : str or None
        The SA slice it comes from (None: synthetic).
    plane : cardionurbs.imaging.geometry.ImagePlane or None
        That slice's image plane.
    synthetic : bool
        Made by :func:`scaled_section`, not from a contour.
    source_points : ndarray, shape (m, 3) or None
        The contour points it was made of, in mm.
    septum_of : ndarray, shape (n, 3) or None
        RV sections: the LV epicardial loop of the slice, in mm.
    scale : float
        Synthetic sections: the scale s of their template.
    template : int or None
        Synthetic sections: 0 (basal) or -1 (apical) template.
    """

    structure: str
    frame: int
    points: np.ndarray
    slice: str | None = None
    plane: ImagePlane | None = None
    synthetic: bool = False
    source_points: np.ndarray | None = None   # the contour points it was made of
    septum_of: np.ndarray | None = None       # RV sections: the LV epicardial loop of the slice
    scale: float = 1.0                        # synthetic sections: scale of their template
    template: int | None = None               # synthetic sections: 0 basal / -1 apical template


@dataclass(eq=False)
class FrameGeometry:
    """What one frame offers to reconstruct from.

    ``sections[structure]`` are SA sections ordered base -> apex; ``la_points
    [structure]`` the LA contour polylines (each (k, 3)); ``apex[structure]``
    the collapsed-end point of each surface; ``base_planes['lv'|'rv']`` the
    valve planes; ``direction`` the stacking direction (base -> apex).

    Attributes
    ----------
    frame : int
        The frame index, 0-based.
    direction : ndarray, shape (3,)
        The unit stacking direction, base to apex.
    sections : dict of str to list of Section
        Structure -> SA sections, base to apex.
    la_points : dict of str to list of ndarray
        Structure -> LA contour polylines, each (k, 3) in mm.
    apex : dict of str to ndarray
        Structure -> the collapsed-end (apex) point (3,), in mm.
    base_planes : dict of str to cardionurbs.anatomy.mesh.Plane
        ``"lv"`` / ``"rv"`` -> the valve plane (apical side kept).
    la_slices : dict of str to list of str
        Structure -> the LA slice id of each polyline.
    la_pixel_mm : dict of str to list of float
        Structure -> the pixel spacing of each polyline's image, in mm.
    la_weights : dict of str to list of ndarray
        Structure -> each polyline's point weights (k,).
    left_out : list of tuple of (str, str or None, str)
        (structure, slice, why) of every contour left out.
    thickness : float
        The mean SA slice thickness, in mm.
    reference : ndarray, shape (3,) or None
        The in-plane LV → RV direction (section seams).
    taper : dict of str to ApicalTaper
        Structure -> the apical taper of an SA-only surface (label maps).
    base_from_slices : set of str
        ``"lv"`` / ``"rv"``: valve planes placed by the half-slice rule.
    base_slack : float
        How far a half-slice valve plane may later move basally, in mm.
    warnings : list of str
        The frame's warnings, one line each.
    in_time : dict
        (surface, slice) -> (frame, frame): sections interpolated in time from those two
        frames (:func:`cardionurbs.anatomy.cycle.support_sections`).
    """

    frame: int
    direction: np.ndarray
    sections: dict[str, list[Section]] = field(default_factory=dict)
    la_points: dict[str, list[np.ndarray]] = field(default_factory=dict)
    apex: dict[str, np.ndarray] = field(default_factory=dict)
    base_planes: dict[str, Plane] = field(default_factory=dict)
    la_slices: dict[str, list[str]] = field(default_factory=dict)
    la_pixel_mm: dict[str, list[float]] = field(default_factory=dict)
    la_weights: dict[str, list[np.ndarray]] = field(default_factory=dict)
    left_out: list[tuple[str, str | None, str]] = field(default_factory=list)  # (structure, slice, why)
    thickness: float = 8.0
    reference: np.ndarray | None = None     # in-plane LV -> RV direction (section seams)
    taper: dict[str, "ApicalTaper"] = field(default_factory=dict)  # SA-only apex (label maps)
    base_from_slices: set = field(default_factory=set)  # 'lv'/'rv' planes by the half-slice rule
    base_slack: float = 0.0     # how far (mm) a half-slice valve plane may later move basally
    in_time: dict = field(default_factory=dict)  # (surface, slice) -> (frame, frame) interpolated from
    warnings: list[str] = field(default_factory=list)


# --------------------------------------------------------------- point order
def _in_drawing_order(points: np.ndarray, closed: bool) -> bool:
    """True when consecutive points are neighbours: no step exceeds 4 median steps and
    the median step is at most 3 median nearest-neighbour distances (noise-tolerant;
    the nearest-neighbour distance is estimated on up to 24 of the points)."""
    if len(points) < 3:
        return True
    q = np.vstack([points, points[:1]]) if closed else points
    diff = np.diff(q, axis=0)
    steps = np.sqrt(np.add.reduce(diff * diff, axis=1))      # np.linalg.norm's numbers
    med = max(median(steps), 1e-9)
    if (steps > 4.0 * med).any():
        return False
    probe = points[np.linspace(0, len(points) - 1, min(24, len(points))).astype(int)]
    g = probe[:, None] - points[None]
    sq = np.add.reduce(g * g, axis=2)                         # squared distances: the
    sq[sq == 0] = np.inf                                      # nearest by them, then its root
    return bool(med <= 3.0 * max(median(np.sqrt(sq.min(axis=1))), 1e-9))


def _nearest_neighbour_chain(points: np.ndarray, start: int) -> np.ndarray:
    """Greedy nearest-neighbour ordering of points from ``start`` (indices)."""
    n = len(points)
    tree = cKDTree(points)
    visited = np.zeros(n, dtype=bool)
    order = [start]
    visited[start] = True
    cur = start
    k0 = min(n, 8)
    # every point's k0 nearest, queried once for all points; a point whose k0 nearest
    # are all taken asks the tree again with more (as a query per step would)
    near = np.asarray(tree.query(points, k=k0)[1]).reshape(n, k0).tolist()
    for _ in range(n - 1):
        nxt = next((j for j in near[cur] if not visited[j]), None)
        k = k0
        while nxt is None and k < n:
            k = min(n, k * 4)
            idx = np.atleast_1d(tree.query(points[cur], k=k)[1])
            free = idx[~visited[idx]]
            nxt = int(free[0]) if free.size else None
        nxt = int(nxt)
        visited[nxt] = True
        order.append(nxt)
        cur = nxt
    return np.asarray(order)


def _cut_at_largest_step(p: np.ndarray) -> np.ndarray:
    """The points rotated so that their largest step, the closing one (last to first)
    included, falls between the last point and the first."""
    steps = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)
    return np.roll(p, -(int(np.argmax(steps)) + 1), axis=0)


def order_open(points: np.ndarray) -> np.ndarray:
    """Order an open contour's points from one end to the other.

    Points in drawing order are kept (a cyclic rotation is undone by cutting at
    the largest gap); otherwise the chain starts at one end of the diameter of
    the points' Euclidean minimum spanning tree and follows nearest neighbours.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        An open contour's points, any order, in mm.

    Returns
    -------
    ndarray of int, shape (n,)
        The order (indices into ``points``), end to end.
    """
    p = np.asarray(points, dtype=float)
    if len(p) < 3:
        return p
    if _in_drawing_order(p, closed=False):
        return p
    rolled = _cut_at_largest_step(p)
    if _in_drawing_order(rolled, closed=False):
        return rolled
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    mst = minimum_spanning_tree(d)
    sym = mst + mst.T
    far = lambda s: int(breadth_first_order(sym, s, directed=False, return_predecessors=False)[-1])  # noqa: E731
    end = far(far(0))
    return p[_nearest_neighbour_chain(p, end)]


def order_closed(points: np.ndarray) -> np.ndarray:
    """Order a closed contour's points around the loop (drawing order kept if present).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed contour's points, any order, in mm.

    Returns
    -------
    ndarray of int, shape (n,)
        The order (indices into ``points``) around the loop.
    """
    p = np.asarray(points, dtype=float)
    if len(p) < 4 or _in_drawing_order(p, closed=True):
        return p
    return p[_nearest_neighbour_chain(p, 0)]


#: a trace in drawing order whose ends are farther apart than this many median point
#: spacings is an open arc, not a loop
ARC_GAP_STEPS = 3.0


def is_open_arc(points: np.ndarray, gap_steps: float = ARC_GAP_STEPS) -> bool:
    """True when a trace, ordered from one end to the other (:func:`order_open`: a trace
    written from the middle of its arc is rotated), leaves a gap between its ends wider
    than ``gap_steps`` median point spacings and a quarter of its extent (an arc, such as
    a CAP LV epicardial trace that stops at the RV insertions); False for a loop.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A trace's points, in mm.
    gap_steps : float, optional
        The gap, in median point spacings, above which the ends do not meet.

    Returns
    -------
    bool
        Whether the trace is an open arc.
    """
    p = np.asarray(points, float)
    if len(p) < 5:
        return False
    # the ends of a trace in drawing order (from any point of it) are where its largest
    # step, the closing one included, is: cut there, else order the points from scratch
    p_cut = _cut_at_largest_step(p)
    p = p_cut if _in_drawing_order(p_cut, closed=False) else order_open(p)
    if not _in_drawing_order(p, closed=False):
        return False
    step = median(np.linalg.norm(np.diff(p, axis=0), axis=1))
    gap = float(np.linalg.norm(p[-1] - p[0]))
    extent = float(np.linalg.norm(p - p[0], axis=1).max())
    return gap > gap_steps * max(step, 1e-9) and gap > 0.25 * extent


def join_open_parts(parts: list[np.ndarray]) -> np.ndarray:
    """Join open curves end to end into one closed loop.

    Each part is ordered, then the parts are chained greedily: the next part is
    the one with an end nearest the current loop end, reversed if needed.

    Parameters
    ----------
    parts : list of ndarray, shape (k, 3)
        Open curves, in mm.

    Returns
    -------
    ndarray, shape (n, 3)
        The loop's points, in mm.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        No points to join.
    """
    parts = [order_open(p) for p in parts if len(p)]
    if not parts:
        raise ReconstructionError("no points to join")
    loop = parts.pop(0)
    while parts:
        end = loop[-1]
        cost = [(min(np.linalg.norm(q[0] - end), np.linalg.norm(q[-1] - end)), i)
                for i, q in enumerate(parts)]
        _, i = min(cost)
        q = parts.pop(i)
        if np.linalg.norm(q[-1] - end) < np.linalg.norm(q[0] - end):
            q = q[::-1]
        loop = np.concatenate([loop, q])
    # drop a duplicated junction point
    keep = np.ones(len(loop), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(loop, axis=0), axis=1) > 1e-9
    return loop[keep]


# --------------------------------------------------------------- plane helpers
def ray_exit(points: np.ndarray, origin: np.ndarray, direction: np.ndarray,
             normal: np.ndarray | None = None) -> float:
    """Largest t with origin + t·direction on the closed loop (in-plane, mm); NaN if none.

    Vectorised over the loop's edges (line–segment intersection by Cramer's rule
    in the loop's plane, of normal ``normal`` — fitted when not given).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed planar loop, in mm.
    origin : ndarray, shape (3,)
        The ray's origin, in mm (in the loop's plane).
    direction : ndarray, shape (3,)
        The ray's direction (t in mm for a unit direction).
    normal : ndarray, shape (3,), optional
        The loop's plane normal (default: fitted).

    Returns
    -------
    float
        The largest t, NaN when the ray misses.
    """
    return float(ray_exits(points, origin, np.asarray(direction, float)[None], normal)[0])


def ray_exits(points: np.ndarray, origin: np.ndarray, directions: np.ndarray,
              normal: np.ndarray | None = None) -> np.ndarray:
    """:func:`ray_exit` of many rays (k, 3) from one origin: (k,) largest t, NaN where a
    ray misses. The loop's in-plane coordinates and edges are computed once for all rays
    (the same arithmetic per ray).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed planar loop, in mm.
    origin : ndarray, shape (3,)
        The rays' origin, in mm.
    directions : ndarray, shape (k, 3)
        The rays' directions.
    normal : ndarray, shape (3,), optional
        The loop's plane normal (default: fitted).

    Returns
    -------
    ndarray, shape (k,)
        The largest t of each ray, NaN where it misses.
    """
    b = in_plane_basis(fit_plane(points)[1] if normal is None else normal)
    xy = (points - origin) @ b.T
    a, e = xy, np.roll(xy, -1, axis=0) - xy
    dd = np.array([b @ (d / np.linalg.norm(d)) for d in directions]).reshape(-1, 2)
    d0, d1 = dd[:, :1], dd[:, 1:]                                   # (k, 1)
    den = d0 * (-e[:, 1]) + d1 * e[:, 0]                            # (k, edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[:, 0] * (-e[:, 1]) + a[:, 1] * e[:, 0]) / den
        s = (d0 * a[:, 1] - d1 * a[:, 0]) / den
    ok = np.isfinite(t) & (s >= -1e-9) & (s <= 1 + 1e-9) & (t > 0)   # a vertex hit counts
    return np.where(ok.any(axis=1), np.where(ok, t, -np.inf).max(axis=1), np.nan)


# --------------------------------------------------------------- level planes
def scaled_section(template: Section, level: float, direction: np.ndarray,
                   centre: np.ndarray, targets: np.ndarray | None,
                   default_scale: float | None = None,
                   anchor: np.ndarray | None = None) -> tuple[np.ndarray, float] | None:
    """A section at ``level`` shaped like ``template``: centre + s·(T − a), moved to the level.

    ``a`` is the scaling anchor in the template's plane (default: its centroid;
    for the RV, the LV centre, so that the crescent thins onto the LV rather
    than shrinking about its own centroid). The scale s is the mean, over
    target points (LA contour crossings of the level plane), of
    |q − centre| / r_T(θ_q), r_T the template's radius from the anchor in the
    direction of q; without targets ``default_scale`` is used (None: no section).

    Parameters
    ----------
    template : Section
        The section whose shape is copied.
    level : float
        The new section's level along ``direction``, in mm.
    direction : ndarray, shape (3,)
        The unit stacking direction.
    centre : ndarray, shape (3,)
        The new section's centre, in mm.
    targets : ndarray, shape (m, 3) or None
        LA contour crossings of the level plane, in mm.
    default_scale : float or None, optional
        The scale without targets (None: no section).
    anchor : ndarray, shape (3,), optional
        The scaling anchor a (default: the template's centroid).

    Returns
    -------
    tuple of (ndarray, float) or None
        (points (k, 3) in mm, scale s), or None without targets and default.
    """
    t = template.points
    ct = polygon_centroid(t, direction) if anchor is None else anchor
    rel = t - ct
    rel -= np.outer(rel @ direction, direction)           # in-plane
    centre = centre - (centre @ direction - level) * direction
    if targets is not None and len(targets):
        q = targets - centre
        q -= np.outer(q @ direction, direction)
        rq = np.linalg.norm(q, axis=1)
        use = rq >= 1e-6
        r_t = ray_exits(ct + rel, ct, q[use], normal=direction) if use.any() else np.zeros(0)
        hit = np.isfinite(r_t) & (r_t > 1e-6)
        ratios = list(rq[use][hit] / r_t[hit])
        if not ratios:
            return None
        s = float(np.mean(ratios))
    elif default_scale is not None:
        s = float(default_scale)
    else:
        return None
    return centre + s * rel, s


def fill_short_gaps(mask: np.ndarray, max_gap: int) -> np.ndarray:
    """Circular morphological closing of a boolean sequence: runs of False of at most
    ``max_gap`` entries with True on both sides become True (the septum of an RV loop is
    one contiguous run; contour noise must not split it).

    Parameters
    ----------
    mask : ndarray of bool, shape (n,)
        A circular sequence.
    max_gap : int
        The longest run of False filled.

    Returns
    -------
    ndarray of bool, shape (n,)
        The closed sequence.
    """
    m = np.asarray(mask, dtype=bool)
    if max_gap <= 0 or m.all() or not m.any():
        return m
    start = int(np.argmax(m))                           # a True entry: runs are bounded
    r = np.roll(m, -start)
    d = np.diff(np.concatenate([r, [True]]).astype(np.int8))
    lo, hi = np.flatnonzero(d == -1) + 1, np.flatnonzero(d == 1) + 1   # False runs [lo, hi)
    short = (hi - lo) <= max_gap
    if not short.any():
        return m
    cover = np.zeros(len(r) + 1, dtype=np.int32)
    np.add.at(cover, lo[short], 1)
    np.add.at(cover, hi[short], -1)
    r = r | (np.cumsum(cover[:-1]) > 0)
    return np.roll(r, start)


def septal_mask(rv_points: np.ndarray, lv_epi_loop: np.ndarray, normal: np.ndarray,
                near_mm: float = 0.5, max_gap: int = 0) -> np.ndarray:
    """Which RV contour points lie on the septum: inside the LV epicardial loop or within
    ``near_mm`` of it (vectorised point-segment distances in the plane); for an ordered
    loop, free-wall runs of at most ``max_gap`` points between septal ones are septal too
    (:func:`fill_short_gaps`).

    Parameters
    ----------
    rv_points : ndarray, shape (n, 3)
        An RV contour's points, in mm.
    lv_epi_loop : ndarray, shape (m, 3)
        The LV epicardial loop of the same slice, in mm.
    normal : ndarray, shape (3,)
        The slice's normal.
    near_mm : float, optional
        Distance within which a point is septal, in mm.
    max_gap : int, optional
        Longest free-wall run between septal points made septal (ordered loops).

    Returns
    -------
    ndarray of bool, shape (n,)
        True for a septal point.
    """
    b = in_plane_basis(normal)
    c = polygon_centroid(lv_epi_loop, normal)
    poly = (lv_epi_loop - c) @ b.T
    xy = (rv_points - c) @ b.T
    inside = points_in_polygon(xy, poly)
    a, e = poly, np.roll(poly, -1, axis=0) - poly
    rel = xy[:, None, :] - a[None]
    t = np.clip(np.einsum("ijk,jk->ij", rel, e) / np.maximum((e * e).sum(1), 1e-18), 0, 1)
    d = np.linalg.norm(rel - t[..., None] * e[None], axis=2).min(axis=1)
    return fill_short_gaps(inside | (d <= near_mm), max_gap)


def embed_septum(rv_loop: np.ndarray, lv_epi_loop: np.ndarray, normal: np.ndarray,
                 near_mm: float = 0.5, depth_mm: float = 4.0, max_gap: int = 0,
                 mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Move the septal part of an RV loop into the LV wall; returns (loop, free-wall points).

    The septal part of an SA rv_endo / rv_epi contour lies on the LV epicardium
    (docs/metrics.md), meeting the free wall in sharp corners at the insertion
    points that no smooth curve follows within a pixel. Since the RV meshes
    subtract the LV epicardial solid anyway, the septal points
    (:func:`septal_mask`: within ``near_mm`` of the LV epicardial contour, or
    inside it; with ``max_gap`` > 0 short free-wall runs between septal points
    of an ordered loop as well) are moved ``depth_mm`` towards the LV centroid:
    the RV boundary on the septum then comes exactly from the LV epicardial
    surface, and the loop's corners lie inside the LV wall where their rounding
    does not matter. The free-wall points (the ones kept) are what the
    residuals are measured on. ``mask``: the septal points when already known.

    Parameters
    ----------
    rv_loop : ndarray, shape (n, 3)
        An ordered RV loop, in mm.
    lv_epi_loop : ndarray, shape (m, 3)
        The LV epicardial loop of the slice, in mm.
    normal : ndarray, shape (3,)
        The slice's normal.
    near_mm : float, optional
        Septal distance, in mm.
    depth_mm : float, optional
        How far the septal points move towards the LV centroid, in mm.
    max_gap : int, optional
        Longest free-wall run made septal.
    mask : ndarray of bool, shape (n,), optional
        The septal points, when known (default :func:`septal_mask`).

    Returns
    -------
    loop : ndarray, shape (n, 3)
        The loop with its septal points moved, in mm.
    free_wall : ndarray, shape (f, 3)
        The free-wall points, in mm.
    """
    sept = septal_mask(rv_loop, lv_epi_loop, normal, near_mm, max_gap) if mask is None else mask
    if not sept.any() or sept.all():
        return rv_loop, rv_loop
    b = in_plane_basis(normal)
    c = polygon_centroid(lv_epi_loop, normal)
    xy = (rv_loop[sept] - c) @ b.T
    r = np.linalg.norm(xy, axis=1, keepdims=True)
    moved = rv_loop.copy()
    moved[sept] = c + (xy * (1 - depth_mm / np.maximum(r, depth_mm + 1e-9))) @ b
    return moved, rv_loop[~sept]


# --------------------------------------------------------------- frame geometry
def _slice_rank(slice_id: str) -> tuple[int, str]:
    m = re.fullmatch(r"sa_(\d+)", slice_id or "")
    return (int(m.group(1)), "") if m else (10**6, slice_id or "")


def stacking_direction(study: Study, frame: int | None = None) -> tuple[np.ndarray, float]:
    """Mean SA plane normal oriented base -> apex, and the mean SA slice thickness (mm).

    The SA images of ``frame`` (all SA images when ``frame`` is None or has
    none); their :func:`~cardionurbs.geometry.stack_normal`, oriented (docs/metrics.md,
    Geometry conventions) towards the apex landmark when given; else towards
    increasing ``sa_NN`` slice number (numbered from base to apex); else
    towards the end with the smaller LV endocardial area. Cached on the study per frame
    (again when its images, landmarks or contours lists are replaced or change length):
    the tag analysis asks for it once per family and frame.

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study.
    frame : int or None, optional
        The frame index, 0-based (None: all SA images).

    Returns
    -------
    direction : ndarray, shape (3,)
        The unit stacking direction, base to apex.
    thickness : float
        The mean SA slice thickness, in mm.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The study has no SA image plane.
    """
    n, thickness = attached(study, "_stacking_direction", _stacking_direction,
                            depends=("images", "landmarks", "contours"))(frame)
    return n.copy(), thickness


def _stacking_direction(study: Study, frame: int | None) -> tuple[np.ndarray, float]:
    ims = [im for im in study.images if im.view == "SA" and im.frame == frame]
    if not ims:
        ims = [im for im in study.images if im.view == "SA"]
    if not ims:
        raise ReconstructionError(f"frame {frame}: no short-axis image planes")
    n = stack_normal(np.array([im.normal for im in ims]))
    thickness = float(np.mean([im.thickness for im in ims]))
    apex = [lm.point for lm in study.landmarks_at(frame, "apex")] or \
        [lm.point for lm in study.landmarks if lm.name == "apex"]
    centres = {im.slice: im.position for im in ims}
    if apex:
        mean_pos = np.mean(list(centres.values()), axis=0)
        if (np.mean(apex, axis=0) - mean_pos) @ n < 0:
            n = -n
        return n, thickness
    ranked = sorted((s for s in centres if re.fullmatch(r"sa_\d+", s)), key=_slice_rank)
    if len(ranked) >= 2 and (centres[ranked[-1]] - centres[ranked[0]]) @ n != 0:
        if (centres[ranked[-1]] - centres[ranked[0]]) @ n < 0:
            n = -n
        return n, thickness
    endo = [c for c in study.contours_at(frame, "lv_endo", view="SA") if c.closed]
    if len(endo) >= 2:
        lev = np.array([c.points.mean(axis=0) @ n for c in endo])
        area = np.array([polygon_area(c.points, n) for c in endo])
        lo, hi = np.argmin(lev), np.argmax(lev)
        if area[hi] > area[lo]:
            n = -n
    return n, thickness


def study_long_axis(study: Study, frame: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The LV long axis (apex, base centre) of a study without a model, in mm.

    :func:`cardionurbs.geometry.long_axis` (the one rule, docs/metrics.md) fed
    with the ``apex`` and ``mitral`` landmarks of ``frame`` and, for an end
    they leave open, the line through the centres (mean points) of the
    closed SA ``lv_endo`` contours along the stacking direction.
    ``frame`` None: ED (the study's label, else its first tagged frame, else
    0); when that frame has no apex landmark and no LV contour, the first
    frame that has an apex landmark.

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study.
    frame : int or None, optional
        The frame index, 0-based (None: as above).

    Returns
    -------
    apex : ndarray, shape (3,)
        The LV apex, in mm.
    base : ndarray, shape (3,)
        The base (mitral) centre, in mm.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        No landmark or SA contour fixes an end.
    """
    if frame is None:
        frame = study.ed_frame if study.ed_frame is not None else \
            (study.tagged_frames[0] if study.tagged_frames else 0)
        if not study.landmarks_at(frame, "apex"):
            with_apex = sorted({lm.frame for lm in study.landmarks if lm.name == "apex"})
            if with_apex and not study.contours_at(frame, "lv_endo"):
                frame = with_apex[0]
    cents = [c.points.mean(axis=0) for c in study.contours_at(frame, "lv_endo", view="SA")
             if c.closed]
    try:
        direction = stacking_direction(study)[0] if len(cents) >= 2 else None
    except ReconstructionError:
        direction = None
    return long_axis([lm.point for lm in study.landmarks_at(frame, "apex")],
                     [lm.point for lm in study.landmarks_at(frame, "mitral")],
                     sa_centroids=np.array(cents) if cents else None,
                     stack_direction=direction, where=f"frame {frame}")


def _sa_loops(study: Study, frame: int) -> dict[str, list[tuple[str, np.ndarray, np.ndarray]]]:
    """Closed SA loops per surface: (slice, ordered loop points, source points).

    Closed contours are ordered; CAP open parts are joined: rv_endo =
    rv_freewall + rv_septum; an open rv_epi is closed through the slice's
    rv_septum (the septal part lies on the LV epicardium, which the RV
    myocardium boolean removes anyway); an lv_epi traced over the free wall
    only (:func:`is_open_arc`) is closed through the slice's rv_septum, the
    LV epicardium across the septum (docs/metrics.md, RV contours).
    """
    out: dict[str, list] = {s: [] for s in SURFACES}
    by_slice: dict[str, dict[str, list[Contour]]] = {}
    for c in study.contours_at(frame, view="SA"):
        by_slice.setdefault(c.slice, {}).setdefault(c.structure, []).append(weighted_part(c))
    for sl, d in by_slice.items():
        sept = [c.points for c in d.get("rv_septum", [])]
        _lv_slice_loops(sl, d, sept, out)
        rv_whole, fw = _rv_endo_slice_loops(sl, d, sept, out)
        _rv_epi_slice_loops(sl, d, sept, rv_whole, fw, out)
    return out


_Loops = dict[str, list[tuple[str, np.ndarray, np.ndarray]]]


def _lv_slice_loops(sl: str, d: dict[str, list[Contour]], sept: list[np.ndarray],
                    out: _Loops) -> None:
    """One SA slice's LV endo- and epicardial loops into ``out`` (:func:`_sa_loops`)."""
    for s in ("lv_endo", "lv_epi"):
        for c in d.get(s, []):
            if len(c.points) < 5:
                continue
            if s == "lv_epi" and sept and is_open_arc(c.points):
                # CAP convention: the LV epicardium is traced over the free wall only;
                # across the septum it is the RV septal endocardium
                parts = [c.points] + sept
                out[s].append((sl, join_open_parts(parts), np.concatenate(parts)))
                continue
            endo = [e.points for e in d.get("lv_endo", []) if len(e.points) >= 5]
            if s == "lv_epi" and not sept and endo and is_open_arc(c.points):
                # ... and without a septal trace: the septum as thick as the free wall
                across = septum_from_endocardium(c.points, endo[0])
                if across is not None:
                    out[s].append((sl, join_open_parts([c.points, across]), c.points))
                    continue
            out[s].append((sl, order_closed(c.points) if c.closed else order_open(c.points),
                           c.points))


def _rv_endo_slice_loops(sl: str, d: dict[str, list[Contour]], sept: list[np.ndarray],
                         out: _Loops) -> tuple[list[Contour], list[np.ndarray]]:
    """One SA slice's RV endocardial loop into ``out``; returns its undivided RV endocardial
    traces and its free-wall parts (:func:`_sa_loops`)."""
    fw = [c.points for c in d.get("rv_freewall", [])]
    rv_whole = [c for c in d.get("rv_endo", []) if len(c.points) >= 5]
    if rv_whole:
        # an undivided RV endocardial trace (closed, or open but round the whole cavity)
        for c in rv_whole:
            out["rv_endo"].append((sl, order_closed(c.points), c.points))
    elif fw:
        parts = fw + sept
        pts = np.concatenate(parts)
        if len(pts) >= 5:
            out["rv_endo"].append((sl, join_open_parts(parts), pts))
    return rv_whole, fw


def _rv_epi_slice_loops(sl: str, d: dict[str, list[Contour]], sept: list[np.ndarray],
                        rv_whole: list[Contour], fw: list[np.ndarray], out: _Loops) -> None:
    """One SA slice's RV epicardial loops into ``out`` (:func:`_sa_loops`)."""
    open_epi = [c for c in d.get("rv_epi", []) if not c.closed]
    if open_epi and not sept and rv_whole and d.get("lv_epi"):
        # the septal part of an undivided RV endocardium, by its contact with the LV
        # epicardium, closes an open RV epicardial trace
        sept = septal_parts(np.concatenate([c.points for c in rv_whole]),
                            d["lv_epi"][0].points)
    if "rv_outlet" in d and not (rv_whole or fw or sept):
        return      # an outlet-only slice: its RV epicardium is the RVOT's (anatomy.outflow)
    for c in d.get("rv_epi", []):
        if c.closed:
            out["rv_epi"].append((sl, order_closed(c.points), c.points))
        elif sept:
            out["rv_epi"].append((sl, join_open_parts([c.points] + sept),
                                  np.concatenate([c.points] + sept)))
        elif d.get("lv_epi") and len(c.points) >= 5:
            # no septal trace: closed by its chord between the RV insertions, which
            # lies inside the (convex) LV epicardium the RV myocardium boolean removes
            out["rv_epi"].append((sl, order_open(c.points), c.points))


def septum_from_endocardium(arc: np.ndarray, lv_endo: np.ndarray) -> np.ndarray | None:
    """The septal run of an LV epicardium traced over the free wall only (``arc``), for a
    slice without an RV septal trace: the LV endocardium's septal part moved outwards by
    the free wall's median thickness, in polar coordinates about the endocardium's
    centroid, sampled at the arc's point spacing across its angular gap (mm, (k, 3));
    None when the arc covers no clear gap.

    Parameters
    ----------
    arc : ndarray, shape (n, 3)
        The LV epicardial arc over the free wall, in mm.
    lv_endo : ndarray, shape (m, 3)
        The slice's LV endocardial loop, in mm.

    Returns
    -------
    ndarray, shape (k, 3) or None
        The septal run, in mm.
    """
    c, n = fit_plane(lv_endo)
    b = in_plane_basis(n)
    c = polygon_centroid(lv_endo, n)
    ea = (lv_endo - c) @ b.T
    aa = (arc - c) @ b.T
    th_e, r_e = np.arctan2(ea[:, 1], ea[:, 0]), np.hypot(ea[:, 0], ea[:, 1])
    th_a, r_a = np.arctan2(aa[:, 1], aa[:, 0]), np.hypot(aa[:, 0], aa[:, 1])
    order = np.argsort(th_e)
    te, re = th_e[order], r_e[order]
    te, re = np.r_[te - 2 * np.pi, te, te + 2 * np.pi], np.r_[re, re, re]

    def endo_r(t):
        return np.interp(np.mod(t + np.pi, 2 * np.pi) - np.pi, te, re)
    thick = float(np.median(r_a - endo_r(th_a)))
    sa = np.sort(th_a)
    gaps = np.diff(np.r_[sa, sa[0] + 2 * np.pi])
    k = int(np.argmax(gaps))
    if thick <= 0 or gaps[k] < np.pi / 6:
        return None
    step = float(np.median(np.linalg.norm(np.diff(arc, axis=0), axis=1)))
    mean_r = float(np.median(r_a))
    m = max(int(gaps[k] * mean_r / max(step, 1e-6)) - 1, 2)
    t = sa[k] + gaps[k] * np.arange(1, m + 1) / (m + 1)
    r = endo_r(t) + thick
    return c + np.column_stack([r * np.cos(t), r * np.sin(t)]) @ b


def septal_parts(rv_points: np.ndarray, lv_epi: np.ndarray, near_mm: float = 1.0
                 ) -> list[np.ndarray]:
    """The septal part of an undivided RV endocardial trace: its points on (within
    ``near_mm`` of) or inside the LV epicardial contour of the same image, as one
    array in trace order ([] when none touches it).

    Parameters
    ----------
    rv_points : ndarray, shape (n, 3)
        The RV endocardial trace, in trace order, in mm.
    lv_epi : ndarray, shape (m, 3)
        The LV epicardial contour of the same image, in mm.
    near_mm : float, optional
        Distance within which a point is septal, in mm.

    Returns
    -------
    list of ndarray
        ``[septal points (k, 3)]`` in mm, or ``[]``.
    """
    n = fit_plane(lv_epi)[1]
    mask = septal_mask(rv_points, order_closed(lv_epi), n, near_mm)
    return [rv_points[mask]] if mask.sum() >= 2 else []


def _la_polylines(study: Study, frame: int) -> tuple[dict, dict, dict]:
    """LA contours per surface as ordered open polylines (CAP parts mapped to rv_endo),
    with their slice ids, pixel sizes (mm) and point weights."""
    pts: dict[str, list[np.ndarray]] = {s: [] for s in SURFACES}
    sls: dict[str, list[str]] = {s: [] for s in SURFACES}
    pxs: dict[str, list[float]] = {s: [] for s in SURFACES}
    wts: dict[str, list[np.ndarray]] = {s: [] for s in SURFACES}
    idx = study._image_index()
    for c in study.contours_at(frame, view="LA"):
        key = "rv_endo" if c.structure in ("rv_septum", "rv_freewall") else c.structure
        c = weighted_part(c)
        if key in pts and len(c.points) >= 3:
            ordered = order_open(c.points)
            pts[key].append(ordered)
            wts[key].append(np.ones(len(ordered)) if c.weights is None
                            else c.weights[cKDTree(c.points).query(ordered)[1]])
            sls[key].append(c.slice)
            im = idx.get(c.image) if c.image else None
            if im is None:
                im = next((i for i in study.images if i.slice == c.slice), None)
            pxs[key].append(float(np.mean(im.pixel_spacing)) if im is not None else 1.0)
    return pts, sls, pxs, wts


def weighted_part(c: Contour) -> Contour:
    """The contour without its zero-weight points (a weight of 0 in the input means: do not
    fit this point); the contour itself when every weight is positive.

    Parameters
    ----------
    c : cardionurbs.study.Contour
        A contour with point weights.

    Returns
    -------
    cardionurbs.study.Contour
        The contour of its positively weighted points.
    """
    if c.weights is None or np.all(c.weights > 0):
        return c
    keep = c.weights > 0
    return Contour(c.structure, c.view, c.slice, c.frame, c.points[keep], image=c.image,
                   closed=c.closed, index=c.index, weights=c.weights[keep])


def valve_plane(points: np.ndarray, axis: np.ndarray) -> Plane:
    """Plane through annulus landmark points, normal oriented along ``axis`` (apical side kept).

    Three or more points: least-squares plane (SVD). Two points: the plane that
    contains both and is as perpendicular to the axis as possible. One: the
    plane through it perpendicular to the axis.

    Parameters
    ----------
    points : ndarray, shape (k, 3)
        Annulus landmarks, in mm, k >= 1.
    axis : ndarray, shape (3,)
        The direction the normal is oriented along (base to apex).

    Returns
    -------
    cardionurbs.anatomy.mesh.Plane
        The valve plane (origin the points' mean, in mm).
    """
    p = np.atleast_2d(points)
    if len(p) >= 3:
        c, nrm = fit_plane(p)
    elif len(p) == 2:
        c = p.mean(axis=0)
        t = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
        nrm = axis - (axis @ t) * t
    else:
        c, nrm = p[0], axis
    if nrm @ axis < 0:
        nrm = -nrm
    return Plane(c, nrm)


#: smallest isoperimetric quotient 4*pi*A / P**2 of an LV loop (circle 1, 4:1 ellipse 0.54)
MIN_LV_ROUNDNESS = 0.2


def isoperimetric_quotient(points: np.ndarray, normal: np.ndarray) -> float:
    """4*pi*|A| / P**2 of a closed loop (1 for a circle, near 0 for a loop that folds back).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed planar loop, in mm.
    normal : ndarray, shape (3,)
        Its plane's unit normal.

    Returns
    -------
    float
        The quotient, in (0, 1].
    """
    perimeter = float(np.linalg.norm(np.diff(np.vstack([points, points[:1]]), axis=0), axis=1).sum())
    if perimeter <= 0:
        return 0.0
    return 4.0 * np.pi * polygon_area(points, normal) / perimeter ** 2


#: a basal LV loop smaller than this fraction of the next one is taken as a partial tracing
#: (hand contours only: a label map's basal section is the labelled cavity, whole)
MIN_BASAL_AREA_RATIO = 0.35


def _drop_degenerate_loops(secs: list, n: np.ndarray, warnings: list[str],
                           left_out: list | None = None, labelled: bool = False) -> list:
    """Leave out LV loops (sorted base -> apex) that cannot be whole cross-sections.

    Two signs of a partial or back-and-forth tracing (typically a basal slice
    through the outflow tract, drawn on some frames only): a loop that encloses
    almost no area for its length (isoperimetric quotient below
    ``MIN_LV_ROUNDNESS``), and a basal loop whose area is below
    ``MIN_BASAL_AREA_RATIO`` of the loop apical to it — the LV is widest near
    its base, so a section that collapses there is not the ventricle's. Lofted
    as full sections they bend the surface and distort the cavity volume.
    The second is a sign only in hand contours: a label map's loop is the
    boundary of what is labelled on the slice, so a small basal loop there is a
    small basal section (the slice cuts the annulus' saddle or opens to the
    outflow tract), which voxel counting and the truth hold (``labelled``: kept).

    Parameters
    ----------
    secs : list of Section
        One LV surface's sections of one frame, sorted base to apex.
    n : ndarray, shape (3,)
        The stacking direction (unit, base to apex).
    warnings : list of str
        Appended: one line per loop left out.
    left_out : list or None
        Appended: (structure, slice, reason) per loop left out.
    labelled : bool
        The sections are a label map's (the basal-area rule does not apply).

    Returns
    -------
    list of Section
        The sections kept, base to apex.
    """
    def drop(sec, why):
        if left_out is not None:
            left_out.append((sec.structure, sec.slice, why))
        warnings.append(f"frame {sec.frame}: slice {sec.slice}: {sec.structure} contour {why}; "
                        "left out of the surface (a partial tracing?)")

    kept = []
    for sec in secs:
        q = isoperimetric_quotient(sec.points, n)
        if q < MIN_LV_ROUNDNESS:
            drop(sec, f"encloses almost no area (isoperimetric quotient {q:.2f})")
        else:
            kept.append(sec)
    while len(kept) >= 3 and not labelled:
        a0 = polygon_area(kept[0].points, n)
        a1 = polygon_area(kept[1].points, n)
        if a0 >= MIN_BASAL_AREA_RATIO * a1:
            break
        drop(kept[0], f"encloses {a0:.0f} mm^2, under {MIN_BASAL_AREA_RATIO:.0%} of the "
                      f"next slice's {a1:.0f} mm^2, at the base")
        kept.pop(0)
    return kept


#: ``study.meta["sa_apex"]`` value that asks for the apex from the taper of the section areas
SA_APEX_TAPER = "taper"


@dataclass(frozen=True)
class ApicalTaper:
    """Section area beyond the most apical SA section of an SA-only surface.

    ``level`` is the last section's level and ``apex`` the apex level (mm along
    the stacking direction); ``coeffs`` the area profile A(h) (mm², highest power
    first) fitted to the apical sections, whose root beyond ``level`` is ``root``.
    When the apex is held before that root (a more apical slice without the
    structure), the profile is compressed into [level, apex].

    Attributes
    ----------
    level : float
        The last section's level, in mm along the stacking direction.
    apex : float
        The apex level, in mm.
    root : float
        The area profile's root beyond ``level``, in mm.
    coeffs : tuple of float
        The profile A(h) in mm² (polynomial coefficients, highest power first).
    """

    level: float
    apex: float
    root: float
    coeffs: tuple[float, ...]

    def area_ratio(self, h: np.ndarray | float) -> np.ndarray:
        """A(h) / A(level) for levels between the last section and the apex (0 beyond).

        Parameters
        ----------
        h : float or ndarray
            Levels, in mm along the stacking direction.

        Returns
        -------
        ndarray
            A(h) / A(level), in [0, 1], shape of ``h``.
        """
        h = np.asarray(h, float)
        t = np.clip((h - self.level) / max(self.apex - self.level, 1e-9), 0.0, 1.0)
        hp = self.level + t * (self.root - self.level)
        a0 = float(np.polyval(self.coeffs, self.level))
        return np.clip(np.polyval(self.coeffs, hp) / a0, 0.0, 1.0)


def apical_taper(levels: np.ndarray, areas: np.ndarray,
                 limit: float | None = None) -> ApicalTaper | None:
    """The apex of a surface known from SA sections alone, from the taper of their areas.

    A prolate spheroid (the classical ellipsoidal model of the LV, as in the
    area–length method) cut perpendicular to its long axis has section areas
    quadratic in the level h: A(h) = π a² (1 − (h − h_c)² / c²). The parabola
    through the (level, area) pairs of the three most apical sections is
    therefore extrapolated to its first zero beyond the last section. When it
    is not concave (the areas taper like a cone or slower), the straight line
    through the last two areas is used instead (a paraboloid tip), which ends
    sooner. The apex is held at most the sectioned length beyond the last
    section, and at most at ``limit`` (a more apical slice that shows no such
    structure). None when there are fewer than three sections or the areas do
    not decrease towards the apex (the half-slice rule applies then).

    Parameters
    ----------
    levels : ndarray, shape (k,)
        The sections' levels, in mm along the stacking direction.
    areas : ndarray, shape (k,)
        Their areas, in mm².
    limit : float or None, optional
        The most apical level the apex may reach, in mm.

    Returns
    -------
    ApicalTaper or None
        The taper, or None as above.
    """
    h = np.asarray(levels, float)[-3:]
    a = np.asarray(areas, float)[-3:]
    if len(h) < 3 or not (np.all(np.diff(h) > 0) and a[2] < a[1] and a[2] > 0):
        return None
    c = np.polyfit(h, a, 2)
    root = None
    if c[0] < 0:
        r = np.roots(c)
        r = r[np.isreal(r)].real
        r = r[r > h[-1]]
        root = float(r.min()) if len(r) else None
    if root is None:
        slope = (a[2] - a[1]) / (h[2] - h[1])
        c = np.array([0.0, slope, a[2] - slope * h[2]])
        root = float(h[2] - a[2] / slope)
    apex = min(root, h[2] + (h[2] - float(np.asarray(levels, float)[0])))
    if limit is not None:
        apex = min(apex, float(limit))
    if apex <= h[2]:
        return None
    return ApicalTaper(level=float(h[2]), apex=float(apex), root=root,
                       coeffs=tuple(float(x) for x in c))


def _taper_apices(study: Study, geo: FrameGeometry, n: np.ndarray) -> None:
    """geo.taper and geo.apex of the surfaces that have neither LA contours nor an apex
    landmark, for studies that ask for it (label maps: a slice without a label shows
    that the structure is absent there, which a missing hand-drawn contour does not)."""
    planes = [im for im in study.images if im.view == "SA" and im.frame == geo.frame]
    landmark = bool(study.landmarks_at(geo.frame, "apex"))
    for s, secs in geo.sections.items():
        if not secs or geo.la_points.get(s) or (s == "lv_epi" and landmark):
            continue
        # a section lies in its SA plane: the mean of its points has the plane's level; the
        # taper needs the areas of the three most apical sections only
        levels = np.array([float(sec.points.mean(axis=0) @ n) for sec in secs])
        areas = np.full(len(secs), np.nan)
        areas[-3:] = [polygon_area(sec.points, n) for sec in secs[-3:]]
        have = {sec.slice for sec in secs}
        beyond = [float(im.position @ n) for im in planes
                  if im.slice not in have and float(im.position @ n) > levels[-1] + 0.5]
        tp = apical_taper(levels, areas, limit=min(beyond) if beyond else None)
        if tp is not None:
            geo.taper[s] = tp
    for endo, epi in (("lv_endo", "lv_epi"), ("rv_endo", "rv_epi")):
        a, b = geo.taper.get(endo), geo.taper.get(epi)
        if a is not None and b is not None and b.apex < a.apex:   # the wall encloses the cavity
            geo.taper[epi] = ApicalTaper(b.level, a.apex, b.root, b.coeffs)
    tip = geo.taper.get("lv_epi")
    for s in ("rv_endo", "rv_epi"):                # the LV forms the heart's apex
        tp = geo.taper.get(s)
        if tip is not None and tp is not None and tp.apex > tip.apex > tp.level:
            geo.taper[s] = ApicalTaper(tp.level, tip.apex, tp.root, tp.coeffs)
    for s, tp in geo.taper.items():
        last = geo.sections[s][-1].points
        c = polygon_centroid(last, n)
        geo.apex[s] = c + (tp.apex - float(c @ n)) * n


def frame_geometry(study: Study, frame: int) -> FrameGeometry:
    """Sections, LA polylines, apex points and valve planes of one frame.

    Apex points (collapsed surface ends): lv_epi = the ``apex`` landmark, else
    the most apical point of the LA lv_epi contours; lv_endo, rv_endo, rv_epi =
    the most apical point of their LA contours (where the contours turn);
    without any of these, half a slice thickness beyond the most apical contour
    centroid along the stacking direction (docs/metrics.md).
    Valve planes: ``mitral`` (LV) and ``tricuspid`` (RV) landmarks; else the
    most basal SA contour's plane moved half a slice thickness towards the base.

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study.
    frame : int
        The frame index, 0-based.

    Returns
    -------
    FrameGeometry
        The frame's sections, LA polylines, apex points and valve planes, with its warnings.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The frame has no SA image plane, or its contours cannot be made into sections.
    """
    n, thick = stacking_direction(study, frame)
    geo = FrameGeometry(frame=frame, direction=n, thickness=thick)
    planes = {}
    for im in study.images:
        if im.view == "SA" and (im.frame == frame or im.slice not in planes):
            planes[im.slice] = im
    labelled = isinstance(study.meta, dict) and bool(study.meta.get("voxel_volumes_ml"))
    for s, loops in _sa_loops(study, frame).items():
        secs = []
        for sl, pts, src in loops:
            secs.append(Section(s, frame, pts, slice=sl, plane=planes.get(sl), source_points=src))
        secs.sort(key=lambda sec: float(sec.points.mean(axis=0) @ n))
        if s in ("lv_endo", "lv_epi"):
            secs = _drop_degenerate_loops(secs, n, geo.warnings, geo.left_out, labelled)
        geo.sections[s] = secs
    lv_epi = {sec.slice: sec for sec in geo.sections.get("lv_epi", [])}
    for s in ("rv_endo", "rv_epi"):
        for sec in geo.sections.get(s, []):
            ep = lv_epi.get(sec.slice)
            if ep is not None:
                sec.septum_of = ep.points
    geo.la_points, geo.la_slices, geo.la_pixel_mm, geo.la_weights = _la_polylines(study, frame)

    lm_apex = [lm.point for lm in study.landmarks_at(frame, "apex")]
    for s, secs in geo.sections.items():
        if not secs:
            continue
        la = geo.la_points.get(s, [])
        if s == "lv_epi" and lm_apex:
            geo.apex[s] = np.mean(lm_apex, axis=0)
        elif la:
            allp = np.concatenate(la)
            lev = allp @ n
            far = lev.max()
            tip = allp[lev >= far - 0.5].mean(axis=0)
            geo.apex[s] = tip + (far - tip @ n) * n
        else:
            last = secs[-1].points
            geo.apex[s] = polygon_centroid(last, n) + 0.5 * thick * n
        if (geo.apex[s] - secs[-1].points.mean(axis=0)) @ n <= 0:
            geo.warnings.append(f"frame {frame}: {s} apex is not beyond the most apical section; "
                                f"moved half a slice thickness beyond it")
            last = secs[-1].points
            geo.apex[s] = polygon_centroid(last, n) + 0.5 * thick * n
    if study.meta.get("sa_apex") == SA_APEX_TAPER:
        _taper_apices(study, geo, n)

    for side, lm_name, surf in (("lv", "mitral", "lv_endo"), ("rv", "tricuspid", "rv_endo")):
        lms = [lm.point for lm in study.landmarks_at(frame, lm_name)]
        secs = geo.sections.get(surf) or []
        if lms:
            geo.base_planes[side] = valve_plane(np.array(lms), n)
        elif secs:
            first = secs[0]
            nrm = first.plane.normal if first.plane is not None else n
            nrm = nrm if nrm @ n > 0 else -nrm
            c = polygon_centroid(first.points, nrm)
            geo.base_planes[side] = Plane(c - 0.5 * thick * nrm, nrm)
            geo.base_from_slices.add(side)
    if study.meta.get("sa_apex") == SA_APEX_TAPER and geo.base_from_slices:
        geo.base_slack = 0.5 * thick      # up to the next slice (BiventricularModel, ES base)
    return geo


# --------------------------------------------------------------- label-map closing at ES
#: largest change of the labels' LV myocardial volume from ED to ES that partial volume
#: explains: on 42 phantoms written as label maps (myocardium conserved exactly; normal, MR,
#: PHTN, seeds 0-9, 5 and 10 mm slices) the voxel count changes by -9.5 to +8.5 %
MYO_CONSERVED_BOUND = 0.12


def labelled_myocardium_ratio(study: Study, ed: int, es: int) -> float | None:
    """The label map's LV myocardial voxel count at ES over that at ED, or None when the
    study is not a label map or lacks either count (``study.meta["voxel_volumes_ml"]``).

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study.
    ed, es : int
        The ED and ES frame indices, 0-based.

    Returns
    -------
    float or None
        The ratio (dimensionless), or None.
    """
    vox = study.meta.get("voxel_volumes_ml") if isinstance(study.meta, dict) else None
    if not vox:
        return None

    def myo(f: int) -> float | None:
        d = vox.get(f, vox.get(str(f))) or {}
        return d.get("lv_myocardium")
    a, b = myo(ed), myo(es)
    return float(b) / float(a) if a and b else None


def labels_do_not_conserve(ratio: float, es: int) -> str:
    """The warning of an ES valve plane left at the labels' slab (see
    :data:`MYO_CONSERVED_BOUND`).

    Parameters
    ----------
    ratio : float
        :func:`labelled_myocardium_ratio`.
    es : int
        The ES frame index.

    Returns
    -------
    str
        The warning, one line.
    """
    return (f"frame {es}: the labels' LV myocardium changes by {100 * (ratio - 1):+.0f} % from "
            f"ED to ES, more than partial volume explains (±{100 * MYO_CONSERVED_BOUND:.0f} %): "
            "the ES valve plane is kept half a slice beyond the most basal labelled slice, as "
            "voxel counting has it, not moved to conserve the myocardium")


def moves_with_lv(geo: FrameGeometry) -> list[str]:
    """The half-slice valve planes that move with the LV's at ES (the atrioventricular
    plane moves as one): the LV's, and the RV's when its most basal section lies on the
    same slice as the LV's — an RV that starts slices more apically has its own slab.

    Parameters
    ----------
    geo : FrameGeometry
        The ES frame's geometry.

    Returns
    -------
    list of str
        ``["lv"]`` or ``["lv", "rv"]``: the planes that move together.
    """
    out = [s for s in geo.base_from_slices if s == "lv"]
    lv, rv = geo.sections.get("lv_endo") or [], geo.sections.get("rv_endo") or []
    if "rv" in geo.base_from_slices and lv and rv and lv[0].slice == rv[0].slice:
        out.append("rv")
    return out


def labelled_beyond_base_ml(study: Study, geo: FrameGeometry, what: str = "lv_cavity") -> float:
    """LV cavity (or myocardium, ``what``) a label map holds on SA slices basal to the
    surface's base (mL): each labelled slice stands for its slab (what voxel counting and
    ACDC's evaluation assume), and slices beyond the most basal LV endocardial section — an outflow tract without a
    myocardial ring, a slice across the annulus' saddle that no closed loop describes —
    hold cavity that the lofted surface, closed at its half-slice valve plane, does not.
    Each such slice counts with the part of its slab beyond the LV valve plane (the
    half-slice plane, or the mitral landmarks' plane where it meets the stacking line
    through the slice's labelled cavity). 0 for a study that is not a label map, and where
    aortic landmarks give the frame an LVOT tube (which holds that cavity).

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study (``meta["lv_slice_ml"]``: frame -> SA slice -> ``lv_cavity`` and
        ``lv_myocardium`` -> the labels' volume on the slice, mL, and ``centroid`` -> the
        labelled cavity's centroid, scanner mm).
    geo : FrameGeometry
        One frame's geometry (its LV endocardial sections and LV valve plane).
    what : {"lv_cavity", "lv_myocardium"}
        Which label.

    Returns
    -------
    float
        The labels' volume beyond the valve plane, mL (>= 0).
    """
    per = study.meta.get("lv_slice_ml") if isinstance(study.meta, dict) else None
    per = (per or {}).get(geo.frame, (per or {}).get(str(geo.frame)))
    secs = geo.sections.get("lv_endo") or []
    plane = geo.base_planes.get("lv")
    if not per or not secs or plane is None or study.landmarks_at(geo.frame, "aortic"):
        return 0.0
    n = geo.direction
    cos = float(plane.normal @ n)
    if cos < 0.2:                         # a valve plane along the stacking direction
        return 0.0
    level = {im.slice: float(im.position @ n) for im in study.images
             if im.view == "SA" and im.frame == geo.frame}
    if secs[0].slice not in level or len(level) < 2:
        return 0.0
    spacing = float(np.median(np.diff(np.sort(list(level.values())))))
    base = level[secs[0].slice]
    total = 0.0
    for sl, ml in per.items():
        z = level.get(sl)
        if z is None or z >= base - 0.5 * spacing:
            continue                      # the base section's own slab or apical to it
        c = np.asarray(ml.get("centroid", secs[0].points.mean(axis=0)), dtype=float)
        reach = float(c @ n) + float((plane.origin - c) @ plane.normal) / cos   # plane's level there
        top, bottom = z - 0.5 * spacing, min(z + 0.5 * spacing, reach)
        total += float(ml.get(what, 0.0)) * float(np.clip((bottom - top) / spacing, 0.0, 1.0))
    return total
