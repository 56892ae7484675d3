"""Lofting: a NURBS surface through section curves (paper §3.2.4, NURBS
Book §10.3).

u runs along the sections (around them, periodic, when they are closed), v
across the sections from the first to the last.  Steps:

0. closed sections are turned to one orientation -- counter-clockwise about
   the loft axis (first section's centroid -> last section's centroid), so
   ``Su x Sv`` points away from the axis -- and each seam is rotated (exact
   periodic reparameterisation ``C(u + s)``) to minimise the twist with the
   previous section.  When all sections share one uniform periodic knot
   vector the shift is rounded to whole knot spans (a cyclic relabelling of
   the control points), so the sections stay compatible and the net does not
   grow.  Open sections are reversed where that pairs their end points
   better with the previous section's.  ``align=False`` skips this step;
1.–3. all sections are raised to the highest degree (A5.9) and brought to one
   knot vector (A5.4) by :func:`~cardionurbs.nurbs.operations.make_compatible`;
4.–5. :func:`loft_compatible` (public: sections that already share degree and
   knots, e.g. fitted on one knot vector, skip steps 0–3):
4. section parameters by the paper's formula
   ``v_k = v_{k-1} + 1/(n+1) sum_i |P_{i,k} - P_{i,k-1}| / d_i`` with
   ``d_i = sum_k |P_{i,k} - P_{i,k-1}|``, degree ``q = min(degree_v, K)`` and
   knots by averaging (NURBS Book eq. 9.8);
5. n + 1 interpolations across the homogeneous control points (one linear
   solve with many right-hand sides).

A single point may be given as the first and/or the last section (an apex):
that row of the net collapses to the point, with the weights of the
neighbouring section.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs import _validate as V
from cardionurbs.nurbs.basis import basis_matrix
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.operations import make_compatible, rotate_seam
from cardionurbs.nurbs.surface import NurbsSurface

__all__ = ["loft", "loft_compatible", "section_parameters", "averaging_knots",
           "align_sections"]

_ALIGN_SAMPLES = 256


def averaging_knots(params: np.ndarray, degree: int) -> np.ndarray:
    """Clamped knots by averaging (NURBS Book eq. 9.8), for interpolation.

    Parameters
    ----------
    params : (K + 1,) float ndarray
        Non-decreasing parameters in [0, 1].
    degree : int
        The degree q <= K.

    Returns
    -------
    (K + q + 2,) float ndarray
    """
    q = degree
    K = params.size - 1
    inner = np.array([params[j:j + q].mean() for j in range(1, K - q + 1)])
    return np.concatenate([np.full(q + 1, params[0]), inner, np.full(q + 1, params[-1])])


def section_parameters(P: np.ndarray) -> np.ndarray:
    """Paper §3.2.4: the section parameters ``v_k`` from the sections' control points.

    Columns i with ``d_i = 0`` (a point shared by every section) are left out
    of the average.

    Parameters
    ----------
    P : (K + 1, n, d) float ndarray
        ``P[k, i]``: control point i of section k (any units).

    Returns
    -------
    (K + 1,) float ndarray
        From 0 to 1 (dimensionless).
    """
    steps = np.linalg.norm(np.diff(P, axis=0), axis=-1)          # (K, n)
    d = steps.sum(axis=0)                                         # d_i
    ok = d > 0
    if not np.any(ok):
        raise NurbsInputError("sections: all sections coincide (zero distance between them)")
    inc = (steps[:, ok] / d[ok]).mean(axis=1)
    v = np.concatenate([[0.0], np.cumsum(inc)])
    v[-1] = 1.0
    if np.any(np.diff(v) <= 0):
        k = int(np.flatnonzero(np.diff(v) <= 0)[0]) + 1
        raise NurbsInputError(f"sections: section {k} coincides with section {k - 1}")
    return v


def _samples(c: NurbsCurve) -> np.ndarray:
    u = np.arange(_ALIGN_SAMPLES) / _ALIGN_SAMPLES if c.closed else np.linspace(0, 1, _ALIGN_SAMPLES)
    return c.evaluate(u)


def _newell_normal(points: np.ndarray) -> np.ndarray:
    """Area vector of a closed polygon (Newell's method), length = 2 * area."""
    return np.cross(points, np.roll(points, -1, axis=0)).sum(axis=0)


def _best_shift(prev: np.ndarray, cur: np.ndarray) -> float:
    """Shift s in [0, 1) minimising sum_i |cur(u_i + s) - prev(u_i)|^2 for
    centred, scale-normalised samples (circular correlation + parabolic refinement)."""
    M = prev.shape[0]
    A = prev - prev.mean(axis=0)
    B = cur - cur.mean(axis=0)
    A /= max(np.sqrt((A ** 2).sum(axis=1).mean()), 1e-300)
    B /= max(np.sqrt((B ** 2).sum(axis=1).mean()), 1e-300)
    # corr[j] = sum_i A_i . B_{i+j}, all shifts at once by FFT
    corr = np.fft.irfft(np.conj(np.fft.rfft(A, axis=0)) * np.fft.rfft(B, axis=0), n=M,
                        axis=0).sum(axis=1)
    cost = -corr
    j = int(np.argmin(cost))
    c0, cm, cp = cost[j], cost[(j - 1) % M], cost[(j + 1) % M]
    den = cm - 2 * c0 + cp
    delta = 0.5 * (cm - cp) / den if den > 0 else 0.0
    return ((j + float(np.clip(delta, -0.5, 0.5))) / M) % 1.0


def _uniform_shared_step(curves: Sequence[NurbsCurve]) -> float | None:
    """Knot spacing 1/n when all closed curves share one degree and one uniform
    periodic knot vector (simple knots), else None."""
    c0 = curves[0]
    p, n = c0.degree, c0.n_control
    breaks = c0.knots[p:n + p + 1]
    if not np.allclose(breaks, np.linspace(0.0, 1.0, n + 1), rtol=0, atol=1e-12):
        return None
    for c in curves[1:]:
        if c.degree != p or c.knots.shape != c0.knots.shape or \
                not np.allclose(c.knots, c0.knots, rtol=0, atol=1e-12):
            return None
    return 1.0 / n


def align_sections(curves: Sequence[NurbsCurve], axis: np.ndarray | None) -> list[NurbsCurve]:
    """Orientation and seam alignment of the section curves (step 0 of :func:`loft`).

    Parameters
    ----------
    curves : sequence of NurbsCurve
        The sections in loft order.
    axis : (d,) float ndarray or None
        The direction closed 3-D sections are oriented along (None: the first
        section's own normal); open sections are oriented end to end.

    Returns
    -------
    list of NurbsCurve
        The same curves, reversed and seam-rotated where needed.
    """
    curves = list(curves)
    if curves[0].closed:
        if curves[0].dimension == 3:
            ref = axis if axis is not None and np.linalg.norm(axis) > 0 else \
                _newell_normal(_samples(curves[0]))
            curves = [c.reversed() if float(_newell_normal(_samples(c)) @ ref) < 0 else c
                      for c in curves]
        step = _uniform_shared_step(curves)
        out = [curves[0]]
        for c in curves[1:]:
            s = _best_shift(_samples(out[-1]), _samples(c))
            if step is not None:            # whole knot spans: a relabelling, knots stay shared
                s = (round(s / step) * step) % 1.0
            out.append(rotate_seam(c, s))
        return out
    out = [curves[0]]
    for c in curves[1:]:
        a0, a1 = out[-1].evaluate(np.array([0.0, 1.0]))
        b0, b1 = c.evaluate(np.array([0.0, 1.0]))
        straight = np.linalg.norm(a0 - b0) + np.linalg.norm(a1 - b1)
        crossed = np.linalg.norm(a0 - b1) + np.linalg.norm(a1 - b0)
        out.append(c.reversed() if crossed < straight else c)
    return out


def loft(sections: Sequence[Any], degree_v: int = 3, align: bool = True) -> NurbsSurface:
    """Loft a surface through ``sections`` (paper §3.2.4).

    Parameters
    ----------
    sections : sequence
        K + 1 >= 2 items, each a :class:`NurbsCurve` (all open or all closed,
        same dimension) or, as the first and/or last item only, a point (d,)
        where the surface collapses (an apex).  Any length unit (e.g. mm).
    degree_v : int, default 3
        Degree across the sections; ``q = min(degree_v, K)``.
    align : bool, default True
        Orient the sections and align their seams (step 0); pass False when
        the caller has done so.

    Returns
    -------
    NurbsSurface
        u along the sections (``closed_u`` when the sections are closed), v from
        the first to the last section; it interpolates every section.

    Raises
    ------
    NurbsInputError
        Fewer than two sections, mixed open and closed sections, a point inside
        the sequence, mismatched dimensions.

    Examples
    --------
    Two circles (radius 20 mm at z = 0, 25 mm at z = 30) and an apex at z = 50:

    >>> import numpy as np
    >>> from cardionurbs import nurbs
    >>> t = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    >>> c0, c1 = (nurbs.fit_curve(np.column_stack([r * np.cos(t), r * np.sin(t), np.full(36, z)]),
    ...                           closed=True, n_ctrl=8) for r, z in ((20, 0), (25, 30)))
    >>> s = nurbs.loft([c0, c1, np.array([0.0, 0.0, 50.0])], degree_v=2)
    >>> s.closed_u, s.degree_v, s.collapsed_v()
    (True, 2, (False, True))
    >>> np.round(s.evaluate_points([0.3], [1.0])[0], 9) + 0.0     # the apex
    array([ 0.,  0., 50.])
    """
    items = list(sections)
    q_req = V.degree_value(degree_v, "degree_v")
    if len(items) < 2:
        raise NurbsInputError(f"sections: need at least 2 sections, got {len(items)}")
    K = len(items) - 1
    kinds = []
    for k, s in enumerate(items):
        if isinstance(s, NurbsCurve):
            kinds.append("curve")
        else:
            pt = V.finite_array(s, f"sections[{k}]", ndim=1)
            if k not in (0, K):
                raise NurbsInputError(f"sections[{k}]: a point section is only allowed first or last")
            items[k] = pt
            kinds.append("point")
    curve_idx = [k for k, t in enumerate(kinds) if t == "curve"]
    if not curve_idx:
        raise NurbsInputError("sections: need at least one curve section")
    curves = [items[k] for k in curve_idx]
    dims = {c.dimension for c in curves} | {items[k].size for k, t in enumerate(kinds) if t == "point"}
    if len(dims) != 1:
        raise NurbsInputError(f"sections: sections have different dimensions {sorted(dims)}")
    if len({c.closed for c in curves}) != 1:
        raise NurbsInputError("sections: mix of open and closed curves")
    closed = curves[0].closed

    def centroid(k: int) -> np.ndarray:
        return items[k] if kinds[k] == "point" else _samples(items[k]).mean(axis=0)

    axis = centroid(K) - centroid(0)
    curves = make_compatible(align_sections(curves, axis) if align else curves)
    return loft_compatible(np.stack([c.control_points for c in curves]), curves[0].knots,
                           curves[0].degree, q_req,
                           weights=np.stack([c.weights for c in curves]), closed_u=closed,
                           start_point=items[0] if kinds[0] == "point" else None,
                           end_point=items[K] if kinds[K] == "point" else None)


def loft_compatible(control_points: Any, knots_u: Any, degree_u: int = 3, degree_v: int = 3,
                    weights: Any = None, closed_u: bool = False, start_point: Any = None,
                    end_point: Any = None) -> NurbsSurface:
    """Loft sections that already share one degree and one knot vector
    (paper §3.2.4 steps 4–5; NURBS Book §10.3, skinning).

    Steps 1–3 of :func:`loft` are identities for such sections, so only the
    interpolation across them remains: section parameters ``v_k`` by the
    paper's formula (:func:`section_parameters`), degree
    ``q = min(degree_v, K)``, knots by averaging (NURBS Book eq. 9.8) and one
    linear solve for all control-point columns.  :func:`loft` ends with this
    function, so both give the same surface for compatible, aligned sections.

    Parameters
    ----------
    control_points : (L, n, d) float array_like
        Row ``k`` is section ``k``'s control polygon (all rows on ``knots_u``,
        already oriented and seam-aligned; any length unit).
    knots_u : float array_like
        The sections' common knot vector (clamped, or periodic when
        ``closed_u``); becomes the surface's ``knots_u``.
    degree_u : int, default 3
        The sections' common degree.
    degree_v : int, default 3
        Requested degree across the sections.
    weights : (L, n) float array_like, optional
        Section weights, or None for non-rational sections (the interpolation
        then runs on the Euclidean points and the surface has unit weights);
        given weights are interpolated in homogeneous coordinates ``(w P, w)``.
    closed_u : bool, default False
        The sections are closed (periodic ``knots_u``).
    start_point, end_point : (d,) float array_like, optional
        Points where the surface collapses before the first / after the last
        section (an apex): an extra row of the net equal to the point, weighted
        like its neighbouring section; the collapsed row of the result is exactly
        the point.

    Returns
    -------
    NurbsSurface
        u along the sections, v from the first (or ``start_point``) to the last
        (or ``end_point``); ``K + 1 = L`` plus the number of end points, ``K >= 1``.
    """
    C = V.finite_array(control_points, "control_points", ndim=3)
    p = V.degree_value(degree_u, "degree_u")
    q_req = V.degree_value(degree_v, "degree_v")
    L, n, d = C.shape
    given: list[np.ndarray | None] = [
        None if pt is None else V.finite_array(pt, name, ndim=1, last_dim=d)
        for name, pt in (("start_point", start_point), ("end_point", end_point))]
    K = L - 1 + sum(e is not None for e in given)
    if K < 1:
        raise NurbsInputError(f"control_points: need at least 2 sections, got {K + 1}")
    k0 = 1 if given[0] is not None else 0
    ends = [(k, pt) for k, pt in ((0, given[0]), (K, given[1])) if pt is not None]
    P = np.empty((K + 1, n, d))
    P[k0:k0 + L] = C
    for k, pt in ends:
        P[k] = pt
    v = section_parameters(P)
    q = min(q_req, K)
    Vk = averaging_knots(v, q)
    M = basis_matrix(Vk, q, v)
    if weights is None:
        Q = np.linalg.solve(M, P.reshape(K + 1, -1)).reshape(P.shape).transpose(1, 0, 2)
        for k, pt in ends:                      # the collapsed row is exactly the point
            Q[:, k] = pt
        return NurbsSurface(p, q, knots_u, Vk, Q, closed_u=closed_u)
    W = V.weight_vector(weights, "weights", (L, n))
    Pw = np.empty((K + 1, n, d + 1))
    Pw[k0:k0 + L] = np.concatenate([C * W[..., None], W[..., None]], axis=-1)
    for k, pt in ends:                          # weighted like the neighbouring section
        nb = W[0] if k == 0 else W[-1]
        Pw[k] = np.column_stack([np.outer(nb, pt), nb])
    Qw = np.linalg.solve(M, Pw.reshape(K + 1, -1)).reshape(K + 1, n, d + 1)
    Qw = Qw.transpose(1, 0, 2)                                  # (n, K+1, d+1)
    w = Qw[..., -1]
    if np.any(w <= 0):
        raise NurbsInputError("sections: interpolating the section weights gave weights <= 0; "
                              "use sections with less different weights")
    for k, pt in ends:                          # the collapsed row is exactly the point
        Qw[:, k, :-1] = w[:, k, None] * pt[None, :]
    return NurbsSurface(p, q, knots_u, Vk, Qw[..., :-1] / w[..., None], w, closed_u=closed_u)
