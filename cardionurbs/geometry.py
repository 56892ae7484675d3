"""Shared plane and polygon geometry, and the LV long axis rule (a leaf module).

One home for the small geometric helpers that anatomy, analysis, phantom,
io and report all need (docs/architecture.md, "Where a concept lives"):

* planes: :func:`fit_plane` (least squares), :func:`in_plane_basis`;
* polygons: :func:`polygon_area` (signed about a normal, or unsigned) and
  :func:`polygon_centroid` (area centroid), for 2-D polygons and planar
  3-D loops alike — the shoelace formula, or its 3-D form, the vector area
  ½ Σ pᵢ × pᵢ₊₁ (Stokes) — and :func:`chord_length` of a 2-D polygon;
* stacks of parallel slices: :func:`stack_normal`, :func:`slice_spacing`;
* the LV long axis: :func:`long_axis`, with the one fallback order of
  docs/metrics.md (Geometry conventions);
* surfaces as samples: :func:`averaged_normals` (normals averaged over a disc).

Everything here works on plain arrays in scanner millimetres with numpy
(and scipy's k-d tree and sparse matrices inside :func:`averaged_normals`);
nothing imports the rest of the package except :mod:`cardionurbs.errors`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cardionurbs.errors import ReconstructionError

__all__ = ["fit_plane", "in_plane_basis", "polygon_area", "polygon_centroid", "chord_length", "stack_normal",
           "slice_spacing", "long_axis", "centroid_line_axis", "polyline_crossings"]


# ----------------------------------------------------------------- planes
def fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane through (n, 3) points: (centroid (3,), unit normal (3,)).

    The normal is the right singular vector of the centred points with the
    smallest singular value (total least squares).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Points in mm (scanner coordinates), n >= 3.

    Returns
    -------
    centroid : ndarray, shape (3,)
        The points' mean, in mm.
    normal : ndarray, shape (3,)
        Unit normal of the plane (its sign is the SVD's).
    """
    p = np.asarray(points, dtype=float)
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    return c, vt[-1]


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross has a large fixed overhead)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def in_plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal in-plane axes (e1, e2) of a plane with this normal, with
    (e1, e2, n̂) right-handed; e1 ⟂ the coordinate axis least aligned with n̂.

    Parameters
    ----------
    normal : ndarray, shape (3,)
        The plane's normal (any length but 0).

    Returns
    -------
    ndarray, shape (2, 3)
        Rows e1, e2: unit, orthogonal to each other and to the normal.
    """
    n = np.asarray(normal, dtype=float)
    n = n / np.sqrt(n @ n)
    t = np.eye(3)[np.argmin(np.abs(n))]
    e1 = _cross3(n, t)
    e1 /= np.sqrt(e1 @ e1)
    return np.stack([e1, _cross3(n, e1)])


# --------------------------------------------------------------- polygons
def _vector_area(points: np.ndarray) -> np.ndarray:
    """½ Σ pᵢ × pᵢ₊₁ of a closed 3-D loop (points centred first, for accuracy)."""
    p = points - points.mean(axis=0)
    q = np.concatenate((p[1:], p[:1]))                    # the next point (np.roll's rows)
    cross = np.column_stack([p[:, 1] * q[:, 2] - p[:, 2] * q[:, 1],    # np.cross's products
                             p[:, 2] * q[:, 0] - p[:, 0] * q[:, 2],
                             p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]])
    return 0.5 * cross.sum(axis=0)


def polygon_area(points: np.ndarray, normal: np.ndarray | None = None, *,
                 signed: bool = False) -> float:
    """Area (mm²) enclosed by a closed polygon (first point not repeated).

    ``points`` (n, 2): the shoelace area. ``points`` (n, 3), a planar loop:
    with ``normal``, the area of its projection on the plane ⟂ ``normal``
    (vector area · n̂; a unit ``normal`` is assumed); without, the area of the
    loop itself, |vector area|. ``signed=True`` keeps the sign: positive when
    the loop runs counter-clockwise (about ``normal`` in 3-D). Fewer than 3
    points enclose no area (0).

    Parameters
    ----------
    points : ndarray, shape (n, 2) or (n, 3)
        The polygon's vertices in order, in mm.
    normal : ndarray, shape (3,), optional
        Unit normal of the projection plane (3-D loops only).
    signed : bool, optional
        Keep the sign (counter-clockwise positive); a 3-D loop then needs ``normal``.

    Returns
    -------
    float
        The area in mm² (0 for fewer than 3 points).

    Raises
    ------
    ValueError
        ``signed`` for a 3-D loop without ``normal``.
    """
    p = np.asarray(points, dtype=float)
    if len(p) < 3:
        return 0.0
    if p.shape[1] == 2:
        q = p - p.mean(axis=0)
        x, y = q[:, 0], q[:, 1]
        a = 0.5 * float((x * np.roll(y, -1) - np.roll(x, -1) * y).sum())
    elif normal is not None:
        a = float(_vector_area(p) @ np.asarray(normal, dtype=float))
    else:
        if signed:
            raise ValueError("polygon_area: a signed area of a 3-D loop needs a normal")
        return float(np.linalg.norm(_vector_area(p)))
    return a if signed else abs(a)


def polygon_centroid(points: np.ndarray, normal: np.ndarray | None = None) -> np.ndarray:
    """Area centroid of a closed polygon (shoelace): (2,) for (n, 2) points, (3,) for a
    planar (n, 3) loop, computed in its plane (normal ``normal``, else the best-fit
    plane). A polygon enclosing (almost) no area gives the mean of its points.

    Parameters
    ----------
    points : ndarray, shape (n, 2) or (n, 3)
        The polygon's vertices in order, in mm.
    normal : ndarray, shape (3,), optional
        The plane's normal for a 3-D loop; default: the best-fit plane's (:func:`fit_plane`).

    Returns
    -------
    ndarray, shape (2,) or (3,)
        The area centroid, in mm (the vertices' mean for a degenerate polygon).
    """
    p = np.asarray(points, dtype=float)
    c0 = p.mean(axis=0)
    if p.shape[1] == 3:
        b = in_plane_basis(fit_plane(p)[1] if normal is None else normal)
        xy = (p - c0) @ b.T
    else:
        b, xy = None, p - c0
    x, y = xy[:, 0], xy[:, 1]
    xn, yn = np.concatenate((x[1:], x[:1])), np.concatenate((y[1:], y[:1]))   # np.roll(., -1)
    cr = x * yn - xn * y
    a = cr.sum() / 2.0
    if abs(a) < 1e-9:
        return c0
    cxy = np.array([((x + xn) * cr).sum(), ((y + yn) * cr).sum()]) / (6.0 * a)
    return c0 + (cxy if b is None else cxy @ b)


def polyline_crossings(polyline: np.ndarray, direction: np.ndarray, level: float,
                       closed: bool = False) -> np.ndarray:
    """Points (k, 3) where a polyline (n, 3) crosses the plane x·direction = level: linear
    interpolation on every segment that changes side (a vertex on the plane counts once);
    ``closed``: the last point joins the first.

    Parameters
    ----------
    polyline : ndarray, shape (n, 3)
        The polyline's points in order, in mm.
    direction : ndarray, shape (3,)
        The plane's normal (the level is measured along it; unit for ``level`` in mm).
    level : float
        The plane's offset: points x with x · direction = level, in mm for a unit direction.
    closed : bool, optional
        The polyline is a loop (last point joined to the first).

    Returns
    -------
    ndarray, shape (k, 3)
        The crossing points in the polyline's order, in mm (k = 0: no crossing).
    """
    p = np.vstack([polyline, polyline[:1]]) if closed else np.asarray(polyline)
    h = p @ direction - level
    a, b = h[:-1], h[1:]
    idx = np.nonzero((a == 0) | (a * b < 0))[0]
    if idx.size == 0:
        return np.empty((0, 3))
    t = a[idx] / np.where(a[idx] - b[idx] == 0, 1.0, a[idx] - b[idx])
    return p[idx] + t[:, None] * (p[idx + 1] - p[idx])


def points_in_polygon(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Which 2-D points (m, 2) lie inside a closed polygon (n, 2): the even-odd
    crossing-number test (a horizontal ray from each point crosses the boundary an odd
    number of times), vectorised over points and edges. Points exactly on the boundary
    may fall either way, as with any floating-point inside test.

    Parameters
    ----------
    xy : ndarray, shape (m, 2)
        The points to test (any shape reshapable to (m, 2)), in mm.
    polygon : ndarray, shape (n, 2)
        The polygon's vertices in order (first not repeated), in mm.

    Returns
    -------
    ndarray of bool, shape (m,)
        True for a point inside.
    """
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    a = np.asarray(polygon, dtype=float)
    b = np.roll(a, -1, axis=0)
    x, y = p[:, 0:1], p[:, 1:2]                                   # (m, 1)
    straddles = (a[None, :, 1] > y) != (b[None, :, 1] > y)         # (m, n)
    dy = np.where(b[:, 1] == a[:, 1], 1.0, b[:, 1] - a[:, 1])
    x_cross = a[None, :, 0] + (y - a[None, :, 1]) * ((b[:, 0] - a[:, 0]) / dy)[None, :]
    return (np.count_nonzero(straddles & (x < x_cross), axis=1) % 2) == 1


def chord_length(xy: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> float:
    """Length of the chord of a closed polygon along the line origin + t·direction.

    All intersections of the line with the polygon's edges are found at once;
    the chord runs from the smallest to the largest t (the polygon is assumed
    star-shaped about ``origin``, as a cavity is about its centroid).

    Parameters
    ----------
    xy : ndarray, shape (n, 2)
        The closed polygon's vertices in order, in mm (in-plane coordinates).
    origin : ndarray, shape (2,)
        A point of the line, in mm (e.g. the cavity's centroid).
    direction : ndarray, shape (2,)
        The line's direction (any length but 0).

    Returns
    -------
    float
        The chord length in mm; NaN when the line misses the polygon.
    """
    d = direction / np.linalg.norm(direction)
    a, b = xy, np.roll(xy, -1, axis=0)
    e = b - a
    # solve origin + t d = a + s e  for (t, s), vectorised over edges (Cramer's rule)
    den = d[0] * (-e[:, 1]) - d[1] * (-e[:, 0])
    r = a - origin
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (r[:, 0] * (-e[:, 1]) - r[:, 1] * (-e[:, 0])) / den
        s = (d[0] * r[:, 1] - d[1] * r[:, 0]) / den
    ok = np.isfinite(t) & (s >= -1e-9) & (s <= 1 + 1e-9)   # a vertex hit counts
    if not ok.any():
        return float("nan")
    return float(t[ok].max() - t[ok].min())


# ------------------------------------------------------------------ stacks
def stack_normal(normals: np.ndarray) -> np.ndarray:
    """Mean unit normal (3,) of a stack of planes, each normal first signed like the first.

    The sign of the result is the first normal's; orienting it base → apex is
    the caller's rule (e.g. :func:`cardionurbs.anatomy.sections.stacking_direction`).

    Parameters
    ----------
    normals : ndarray, shape (k, 3)
        The slice planes' normals (unit or not; any shape reshapable to (k, 3)).

    Returns
    -------
    ndarray, shape (3,)
        The unit mean normal, signed like ``normals[0]``.
    """
    normals = np.asarray(normals, float).reshape(-1, 3)
    signs = np.where(normals @ normals[0] < 0, -1.0, 1.0)
    m = (normals * signs[:, None]).mean(axis=0)
    return m / np.linalg.norm(m)


def slice_spacing(positions_along_normal: ArrayLike) -> float:
    """Median gap (mm) between consecutive distinct slice positions (rounded to 1e-6 mm);
    NaN for fewer than two distinct positions.

    Parameters
    ----------
    positions_along_normal : array_like of float, shape (k,)
        Each slice's position along the stack normal, in mm (repeats allowed).

    Returns
    -------
    float
        The median gap in mm, NaN for fewer than two distinct positions.
    """
    s = np.unique(np.round(np.asarray(positions_along_normal, float), 6))
    if s.size < 2:
        return float("nan")
    return float(np.median(np.diff(s)))


# --------------------------------------------------------------- long axis
def centroid_line_axis(centroids: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(apex, base) of the line fitted through SA contour centres (k >= 2, (k, 3)).

    The line is the principal direction of the centres, signed along
    ``direction`` (base → apex); the base is the most basal centre's foot on
    it, the apex lies half a (median) centre gap beyond the most apical one.

    Parameters
    ----------
    centroids : ndarray, shape (k, 3)
        SA contour centres in mm (scanner coordinates), k >= 2.
    direction : ndarray, shape (3,)
        The stacking direction, base to apex.

    Returns
    -------
    apex : ndarray, shape (3,)
        Half a median centre gap beyond the most apical centre, on the line, in mm.
    base : ndarray, shape (3,)
        The most basal centre's foot on the line, in mm.
    """
    P = np.asarray(centroids, float).reshape(-1, 3)
    P = P[np.argsort(P @ np.asarray(direction, float), kind="stable")]
    ctr = P.mean(axis=0)
    d = np.linalg.svd(P - ctr, full_matrices=False)[2][0]
    if d @ direction < 0:
        d = -d
    t = (P - ctr) @ d
    gap = float(np.median(np.diff(np.sort(t)))) if len(t) > 1 else 0.0
    return ctr + (t.max() + gap / 2) * d, ctr + t.min() * d


def long_axis(apex_landmarks: ArrayLike | None = None, mitral_landmarks: ArrayLike | None = None,
              *, model_apex: np.ndarray | None = None, valve_origin: np.ndarray | None = None,
              sa_centroids: np.ndarray | None = None, stack_direction: np.ndarray | None = None,
              where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """The LV long axis: (apex (3,), base centre (3,)) in mm (docs/metrics.md).

    One fallback order, taking the first input that is given:

    apex
        1. the mean of the ``apex`` landmarks; 2. the model's LV apex
        (``model_apex``: epicardial, else endocardial); 3. the centroid line
        (:func:`centroid_line_axis` of ``sa_centroids`` along ``stack_direction``):
        half a slice gap beyond the most apical SA centre.
    base centre
        1. the mean of the ``mitral`` landmarks; 2. the origin of the LV valve
        plane (``valve_origin``); 3. the centroid line's most basal centre.

    Raises :class:`~cardionurbs.errors.ReconstructionError` (prefixed with
    ``where``) when no input fixes an end.

    Parameters
    ----------
    apex_landmarks : ndarray, shape (k, 3), optional
        LV apex landmarks in mm (scanner coordinates); their mean is the apex.
    mitral_landmarks : ndarray, shape (k, 3), optional
        Mitral valve landmarks in mm; their mean is the base centre.
    model_apex : ndarray, shape (3,), optional
        The model's LV apex in mm (second choice for the apex).
    valve_origin : ndarray, shape (3,), optional
        The origin of the LV valve plane in mm (second choice for the base centre).
    sa_centroids : ndarray, shape (k, 3), optional
        SA contour centres in mm, k >= 2 (last choice for both ends).
    stack_direction : ndarray, shape (3,), optional
        The SA stacking direction, base to apex (needed with ``sa_centroids``).
    where : str, optional
        Prefix of the error message (the study or frame).

    Returns
    -------
    apex : ndarray, shape (3,)
        The LV apex, in mm.
    base : ndarray, shape (3,)
        The base (mitral) centre, in mm.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        No input fixes the apex or the base centre.
    """
    def given(a):
        return a is not None and np.asarray(a).size > 0

    apex = base = None
    if given(apex_landmarks):
        apex = np.asarray(apex_landmarks, float).reshape(-1, 3).mean(axis=0)
    elif given(model_apex):
        apex = np.asarray(model_apex, float).reshape(3)
    if given(mitral_landmarks):
        base = np.asarray(mitral_landmarks, float).reshape(-1, 3).mean(axis=0)
    elif given(valve_origin):
        base = np.asarray(valve_origin, float).reshape(3)
    if (apex is None or base is None) and given(sa_centroids) and stack_direction is not None \
            and len(np.asarray(sa_centroids).reshape(-1, 3)) >= 2:
        line_apex, line_base = centroid_line_axis(np.asarray(sa_centroids, float), stack_direction)
        apex = line_apex if apex is None else apex
        base = line_base if base is None else base
    if apex is None or base is None:
        missing = "apex" if apex is None else "base (mitral) centre"
        raise ReconstructionError(f"{where + ': ' if where else ''}no LV {missing} to define the "
                                  "long axis (no landmarks, model apex or SA contours)")
    return apex, base


def averaged_normals(points: np.ndarray, normals: np.ndarray, weights: np.ndarray,
                     radius_mm: float) -> np.ndarray:
    """Unit normals (n, 3) of surface samples ``points`` (n, 3) averaged, weighted by
    ``weights`` (n,) (e.g. area), over the samples within ``radius_mm`` of each sample
    (itself included).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Surface sample positions, in mm.
    normals : ndarray, shape (n, 3)
        Their normals (unit or not).
    weights : ndarray, shape (n,)
        Each sample's weight (e.g. its area in mm²).
    radius_mm : float
        The averaging radius, in mm.

    Returns
    -------
    ndarray, shape (n, 3)
        The unit averaged normals.
    """
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree
    pairs = cKDTree(points).query_pairs(radius_mm, output_type="ndarray")
    n = len(points)
    rows = np.r_[pairs[:, 0], pairs[:, 1], np.arange(n)]
    cols = np.r_[pairs[:, 1], pairs[:, 0], np.arange(n)]
    W = csr_matrix((np.asarray(weights, float)[cols], (rows, cols)), shape=(n, n))
    out = W @ np.asarray(normals, float)
    return out / np.linalg.norm(out, axis=1)[:, None]
