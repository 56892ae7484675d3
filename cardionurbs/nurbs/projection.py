"""Closest points on curves and surfaces (point inversion, NURBS Book §6.1).

Vectorised over all query points: seeds from the nearest of a dense sample
(:class:`scipy.spatial.cKDTree`), then Newton iterations on the
squared-distance function with second derivatives (eqs. 6.3 and 6.6 of the
NURBS Book), falling back to Gauss-Newton where the Hessian is not positive
definite; a step is kept only where it lowers the distance.  Parameters are
clamped to the domain, or wrapped around a periodic direction.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs import _validate as V
from cardionurbs.nurbs.basis import basis_function_derivatives, find_spans
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.knots import distinct_knots
from cardionurbs.nurbs.surface import NurbsSurface

__all__ = ["closest_points", "curve_closest_points", "surface_closest_points",
           "curve_distance_bounds", "curve_seed_distances"]

# step fractions tried in turn (backtracking); a point keeps the first that helps
_BACKTRACK = (1.0, 0.25, 1.0 / 16, 1.0 / 64)


def _backtrack(params: tuple[np.ndarray, ...], dist: np.ndarray,
               trial: Callable[[np.ndarray, float], tuple[tuple[np.ndarray, ...], np.ndarray]]
               ) -> np.ndarray:
    """The backtracking of a Newton step, for every point at once: each point keeps the first
    step fraction of :data:`_BACKTRACK` whose trial lowers its distance. ``trial(idx, scale)``
    gives the trial parameters (one array per parameter direction) and their distances for
    the points ``idx``; ``params`` (arrays (k,)) and ``dist`` (k,) are updated in place.
    Returns the (k,) bool mask of the points no fraction helped."""
    todo = np.ones(dist.size, dtype=bool)
    for scale in _BACKTRACK:
        idx = np.flatnonzero(todo)
        if idx.size == 0:
            break
        cand, cd = trial(idx, scale)
        ok = cd < dist[idx]
        for arr, c in zip(params, cand):
            arr[idx[ok]] = c[ok]
        dist[idx[ok]] = cd[ok]
        todo[idx[ok]] = False
    return todo


def _span_samples(knots: np.ndarray, degree: int, lo: float, hi: float, per_span: int,
                  periodic: bool, minimum: int = 64) -> np.ndarray:
    """Parameters sampling every non-empty knot span ``per_span`` times (at
    least ``minimum`` samples in all)."""
    inner = knots[(knots > lo) & (knots < hi)]
    edges = np.concatenate([[lo], distinct_knots(inner)[0], [hi]])
    per_span = max(per_span, -(-minimum // (edges.size - 1)))
    t = np.arange(per_span) / per_span
    u = (edges[:-1, None] + np.diff(edges)[:, None] * t[None, :]).ravel()
    return u if periodic else np.append(u, hi)


@functools.lru_cache(maxsize=256)
def _sample_basis(degree: int, closed: bool, knots: bytes, u: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The basis values (k, p + 1) and control-point rows (k, p + 1) of the parameters ``u`` on
    the knot vector ``knots`` (both float64 buffers, as ``ndarray.tobytes`` gives them)."""
    U, p = np.frombuffer(knots), degree
    uu = V.parameters(np.frombuffer(u), "u", float(U[p]), float(U[U.size - p - 1]), closed)
    spans = find_spans(U, p, uu)
    N = basis_function_derivatives(spans, uu, p, U, 0)[:, 0, :]
    return N, spans[:, None] - p + np.arange(p + 1)[None, :]


def _sample_points(curve: Any, u: np.ndarray) -> np.ndarray:
    """``curve.evaluate(u)`` for a sample ``u`` that many curves on the same knots ask for
    (the fits of one surface's sections share a knot vector, and so the samples of their
    distance bounds): the basis values are computed once per knots and sample
    (:func:`_sample_basis`), and each curve only contracts them with its control points
    (the same arithmetic)."""
    N, idx = _sample_basis(curve.degree, curve.closed, np.ascontiguousarray(curve.knots, float).tobytes(),
                           np.ascontiguousarray(u, float).tobytes())
    Cw = np.einsum("kj,kjc->kc", N, curve.homogeneous_control_points[idx])
    return Cw[:, :-1] / Cw[:, -1:]


def _wrap_or_clip(u: np.ndarray, lo: float, hi: float, periodic: bool) -> np.ndarray:
    return lo + np.mod(u - lo, hi - lo) if periodic else np.clip(u, lo, hi)


def curve_closest_points(curve: Any, points: Any, iterations: int = 8,
                         samples_per_span: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Parameters and distances of the curve points closest to ``points``
    (point inversion, NURBS Book eq. 6.3, Newton from the nearest of a dense sample).

    Parameters
    ----------
    curve : NurbsCurve
    points : (m, d) or (d,) float array_like
        Query points in the curve's units; one point counts as m = 1.
    iterations : int, default 8
        Newton iterations at most.
    samples_per_span : int, default 16
        Seed samples per knot span.

    Returns
    -------
    u : (m,) float ndarray
        Parameters of the closest points.
    distance : (m,) float ndarray
        Distances, points' units.
    """
    Q = V.point_rows(points, "points", curve.dimension)
    lo, hi = curve.domain
    us = _span_samples(curve.knots, curve.degree, lo, hi, samples_per_span, curve.closed)
    _, idx = cKDTree(_sample_points(curve, us)).query(Q)
    u = us[idx]
    dist = np.linalg.norm(curve.evaluate(u) - Q, axis=1)   # the seed distance: Newton only lowers it
    active = np.arange(u.size)
    for _ in range(iterations):
        if active.size == 0:
            break
        ua, Qa, da = u[active], Q[active], dist[active]
        D = curve.derivatives(ua, 2)
        r = D[:, 0] - Qa
        f = np.einsum("kd,kd->k", D[:, 1], r)
        g2 = np.einsum("kd,kd->k", D[:, 1], D[:, 1])
        fp = g2 + np.einsum("kd,kd->k", D[:, 2], r)
        fp = np.where(fp > 1e-12 * np.maximum(g2, 1e-300), fp, np.maximum(g2, 1e-300))
        step = -f / fp

        def trial(idx: np.ndarray, scale: float) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
            cand = _wrap_or_clip(ua[idx] + scale * step[idx], lo, hi, curve.closed)
            return (cand,), np.linalg.norm(curve.evaluate(cand) - Qa[idx], axis=1)

        todo = _backtrack((ua,), da, trial)
        u[active], dist[active] = ua, da
        # keep iterating where the step helped and was not negligible
        active = active[~todo & (np.abs(step) > 1e-14 * (hi - lo))]
    return u, dist


def curve_seed_distances(curve: Any, points: Any, samples_per_span: int = 16) -> np.ndarray:
    """Distance of each point to the nearest of the samples :func:`curve_closest_points`
    seeds its Newton iterations from (same ``samples_per_span``): an upper bound of the
    distance that function returns for the point, since Newton only accepts steps that
    bring the point closer.

    Parameters
    ----------
    curve : NurbsCurve
    points : (m, d) or (d,) float array_like
    samples_per_span : int, default 16

    Returns
    -------
    (m,) float ndarray
        Points' units.
    """
    Q = V.point_rows(points, "points", curve.dimension)
    lo, hi = curve.domain
    us = _span_samples(curve.knots, curve.degree, lo, hi, samples_per_span, curve.closed)
    return cKDTree(_sample_points(curve, us)).query(Q)[0]


def curve_distance_bounds(curve: Any, points: np.ndarray, samples_per_span: int = 16
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Cheap lower and upper bounds of each point's distance to the curve.

    Upper: distance to the nearest of a dense sample.  Lower: that minus the
    longest chord between consecutive samples (every curve point lies within
    half an arc of a sample; arcs are chord-long to first order, so a whole
    chord is a safe margin).

    Parameters
    ----------
    curve : NurbsCurve
    points : (m, d) float ndarray
    samples_per_span : int, default 16

    Returns
    -------
    lower, upper : (m,) float ndarray
        Points' units.
    """
    lo, hi = curve.domain
    us = _span_samples(curve.knots, curve.degree, lo, hi, samples_per_span, curve.closed,
                       minimum=256)
    S = _sample_points(curve, us)
    chords = np.linalg.norm(np.diff(np.concatenate([S, S[:1]]) if curve.closed else S, axis=0),
                            axis=1)
    upper, _ = cKDTree(S).query(points)
    return upper - chords.max(), upper


#: Newton iterations after which seeds of one point that have met are merged (the
#: later seeds are dropped: from there on they would repeat the first one's steps)
_MERGE_AFTER = 3
#: seeds closer than this fraction of each parameter range count as met
_MERGE_TOL = 1e-7


def _distinct_seeds(active: np.ndarray, u: np.ndarray, v: np.ndarray, k: int,
                    ranges: tuple[float, float], closed_u: bool) -> np.ndarray:
    """``active`` (indices into the k-seeds-per-point arrays) less every seed whose
    (u, v) lies within :data:`_MERGE_TOL` of an earlier seed of the same point (still
    active or not): both are converging to the same closest point."""
    U, Vv = u.reshape(-1, k), v.reshape(-1, k)
    du = np.abs(U[:, :, None] - U[:, None, :])
    if closed_u:
        du = np.minimum(du, ranges[0] - du)
    same = (du <= _MERGE_TOL * ranges[0]) & \
        (np.abs(Vv[:, :, None] - Vv[:, None, :]) <= _MERGE_TOL * ranges[1])
    dup = np.triu(np.ones((k, k), dtype=bool), 1)       # seed j > i, i earlier
    drop = (same & dup[None]).any(axis=1).ravel()         # seed j met an earlier seed
    return active[~drop[active]]


def surface_closest_points(surface: Any, points: Any, iterations: int = 16,
                           samples_per_span: int = 6, seeds: int = 3
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parameters and distances of the surface points closest to ``points``
    (NURBS Book eq. 6.6).

    Newton runs from the ``seeds`` nearest samples of each point and the
    best result is kept (guards against local minima, e.g. near an apex).

    Parameters
    ----------
    surface : NurbsSurface
    points : (m, 3) or (3,) float array_like
        Query points in the surface's units; one point counts as m = 1.
    iterations : int, default 16
        Newton iterations at most.
    samples_per_span : int, default 6
        Seed samples per knot span in each direction.
    seeds : int, default 3
        Newton starts per point.

    Returns
    -------
    u, v : (m,) float ndarray
        Parameters of the closest points.
    distance : (m,) float ndarray
        Distances, points' units.
    """
    P = V.point_rows(points, "points", surface.dimension)
    (ulo, uhi), (vlo, vhi) = surface.domain_u, surface.domain_v
    us = _span_samples(surface.knots_u, surface.degree_u, ulo, uhi, samples_per_span,
                       surface.closed_u)
    vs = _span_samples(surface.knots_v, surface.degree_v, vlo, vhi, samples_per_span, False)
    # seeds on a collapsed end carry no u information: seed from the next row
    c0, c1 = surface.collapsed_v()
    keep = np.ones(vs.size, dtype=bool)
    if c0:
        keep &= vs > vlo
    if c1:
        keep &= vs < vhi
    vs = vs[keep]
    grid = surface.evaluate(us, vs)
    m = P.shape[0]
    k = max(1, min(int(seeds), us.size * vs.size))
    _, idx = cKDTree(grid.reshape(-1, grid.shape[-1])).query(P, k=k)
    idx = np.asarray(idx).reshape(m, k).ravel()
    P0, P = P, np.repeat(P, k, axis=0)      # Newton from each of the k nearest seeds
    u, v = us[idx // vs.size], vs[idx % vs.size]
    dist = np.linalg.norm(surface.evaluate_points(u, v) - P, axis=1)
    # A point whose step helps at no backtracking scale keeps (u, v), so the next
    # iteration would compute the same step and fail again: it is done. Only the
    # points still moving are iterated (the same result, a fraction of the work).
    active = np.arange(u.size)
    dot = lambda a, b: np.einsum("kd,kd->k", a, b)  # noqa: E731
    for it in range(iterations):
        if it == _MERGE_AFTER and k > 1:
            active = _distinct_seeds(active, u, v, k, (uhi - ulo, vhi - vlo), surface.closed_u)
        if active.size == 0:
            break
        ua, va, Pa, da = u[active], v[active], P[active], dist[active]
        D = surface.derivatives(ua, va, 2)
        r = D[:, 0, 0] - Pa
        Su, Sv = D[:, 1, 0], D[:, 0, 1]
        gu, gv = dot(Su, r), dot(Sv, r)
        juu, juv, jvv = dot(Su, Su), dot(Su, Sv), dot(Sv, Sv)
        huu = juu + dot(D[:, 2, 0], r)
        huv = juv + dot(D[:, 1, 1], r)
        hvv = jvv + dot(D[:, 0, 2], r)
        det = huu * hvv - huv * huv
        newton_ok = (huu > 0) & (det > 1e-12 * np.maximum(juu * jvv, 1e-300))
        huu, huv, hvv = (np.where(newton_ok, huu, juu), np.where(newton_ok, huv, juv),
                         np.where(newton_ok, hvv, jvv))
        lam = 1e-9 * (huu + hvv) + 1e-300
        huu, hvv = huu + lam, hvv + lam
        det = huu * hvv - huv * huv
        du = -(hvv * gu - huv * gv) / det
        dv = -(huu * gv - huv * gu) / det

        def trial(idx: np.ndarray, scale: float) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
            cu = _wrap_or_clip(ua[idx] + scale * du[idx], ulo, uhi, surface.closed_u)
            cv = np.clip(va[idx] + scale * dv[idx], vlo, vhi)
            return (cu, cv), np.linalg.norm(surface.evaluate_points(cu, cv) - Pa[idx], axis=1)

        todo = _backtrack((ua, va), da, trial)
        u[active], v[active], dist[active] = ua, va, da
        active = active[~todo]
    best = dist.reshape(m, k).argmin(axis=1) + np.arange(m) * k
    assert P[best].shape == P0.shape
    return u[best], v[best], dist[best]


def closest_points(geometry: Any, points: Any, iterations: int = 16) -> tuple[np.ndarray, ...]:
    """Closest points on a curve or a surface.

    Parameters
    ----------
    geometry : NurbsCurve or NurbsSurface
    points : (m, d) or (d,) float array_like
        Query points (one point: m = 1), geometry's units.
    iterations : int, default 16
        Newton iterations at most.

    Returns
    -------
    tuple of (m,) float ndarray
        Surface: ``(u, v, distance)``; curve: ``(u, distance)``.

    Raises
    ------
    NurbsInputError
        ``geometry`` is neither.
    """
    if isinstance(geometry, NurbsSurface):
        return surface_closest_points(geometry, points, iterations)
    if isinstance(geometry, NurbsCurve):
        return curve_closest_points(geometry, points, iterations)
    raise NurbsInputError(f"geometry: expected a NurbsCurve or NurbsSurface, got {type(geometry).__name__}")
