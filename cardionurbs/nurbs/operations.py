"""Shape-preserving operations on curves: knot insertion/refinement (A5.1,
A5.4), degree elevation (A5.9), bringing several curves to one degree and one
knot vector (paper §3.2.4 steps 1–3), moving the seam of a closed curve.

All of them return new :class:`~cardionurbs.nurbs.curve.NurbsCurve` objects
describing the same point set with the same parameterisation (to rounding,
~1e-15 relative).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs import _validate as V
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.knots import (distinct_knots, elevate_degree_clamped,
                                     elevate_degree_periodic, refine_periodic,
                                     refine_knot_vector, rotate_periodic)

__all__ = ["insert_knots", "elevate_degree", "make_compatible", "rotate_seam",
           "reparameterise"]


def _homogeneous(curve: NurbsCurve) -> np.ndarray:
    """Distinct homogeneous control points ``(w P, w)``, shape (n, d + 1)."""
    return np.column_stack([curve.control_points * curve.weights[:, None], curve.weights])


def _from_homogeneous(degree: int, knots: np.ndarray, Qw: np.ndarray, closed: bool) -> NurbsCurve:
    w = Qw[:, -1]
    return NurbsCurve(degree, knots, Qw[:, :-1] / w[:, None], w, closed=closed)


def _check_curve(curve: Any, name: str = "curve") -> NurbsCurve:
    if not isinstance(curve, NurbsCurve):
        raise NurbsInputError(f"{name}: expected a NurbsCurve, got {type(curve).__name__}")
    return curve


def insert_knots(curve: NurbsCurve, knots: Any) -> NurbsCurve:
    """Insert the knots ``knots`` (each value once per occurrence) -- A5.4 for open
    curves, the Oslo algorithm with cyclic indices for closed ones.

    The curve keeps its shape and parameterisation.  Interior multiplicity may
    reach the degree.

    Parameters
    ----------
    curve : NurbsCurve
    knots : float array_like
        Knot values inside the domain (closed: taken modulo 1).

    Returns
    -------
    NurbsCurve
        The same curve with more control points.
    """
    curve = _check_curve(curve)
    X = np.sort(np.atleast_1d(V.finite_array(knots, "knots")).ravel())
    if X.size == 0:
        return curve
    p = curve.degree
    lo, hi = curve.domain
    if curve.closed:
        X = np.mod(X, 1.0)
    elif X.min() <= lo or X.max() >= hi:
        raise NurbsInputError(f"knots: inserted knots must lie inside the domain ({lo}, {hi}), "
                              f"got [{X.min()}, {X.max()}]")
    merged = np.sort(np.concatenate([_period_knots(curve), X]))
    vals, mult = distinct_knots(merged, 0.0)
    if mult.max() > p:
        bad = vals[np.argmax(mult)]
        raise NurbsInputError(f"knots: inserting {bad} would give multiplicity "
                              f"{mult.max()} > degree {p}")
    Pw = _homogeneous(curve)
    if curve.closed:
        U, Qw = refine_periodic(curve.knots, Pw, p, X)
        return _from_homogeneous(p, U, Qw, True)
    U, Qw = refine_knot_vector(curve.knots, Pw, p, X)
    return _from_homogeneous(p, U, Qw, False)


def elevate_degree(curve: NurbsCurve, times: int = 1) -> NurbsCurve:
    """The same curve with its degree raised by ``times`` (A5.9 for open curves;
    exact re-representation in the elevated periodic spline space for closed
    ones).  Every distinct knot gains multiplicity ``times``.

    Parameters
    ----------
    curve : NurbsCurve
    times : int, default 1
        Degree increase, >= 0.

    Returns
    -------
    NurbsCurve
    """
    curve = _check_curve(curve)
    t = V.degree_value(times, "times", minimum=0)
    if t == 0:
        return curve
    Pw = _homogeneous(curve)
    if curve.closed:
        U, Qw = elevate_degree_periodic(curve.knots, Pw, curve.degree, t)
        return _from_homogeneous(curve.degree + t, U, Qw, True)
    U, Qw = elevate_degree_clamped(curve.knots, Pw, curve.degree, t)
    return _from_homogeneous(curve.degree + t, U, Qw, False)


def reparameterise(curve: NurbsCurve, lo: float = 0.0, hi: float = 1.0) -> NurbsCurve:
    """Open curve with its domain mapped linearly onto [lo, hi] (same shape).

    Parameters
    ----------
    curve : NurbsCurve
        An open curve.
    lo, hi : float
        The new domain, lo < hi.

    Returns
    -------
    NurbsCurve
    """
    a, b = curve.domain
    if curve.closed or (a == lo and b == hi):
        return curve
    U = lo + (curve.knots - a) * ((hi - lo) / (b - a))
    U[:curve.degree + 1], U[-curve.degree - 1:] = lo, hi
    return NurbsCurve(curve.degree, U, curve.control_points, curve.weights)


def rotate_seam(curve: NurbsCurve, shift: float) -> NurbsCurve:
    """Closed curve ``C'`` with ``C'(u) = C(u + shift)`` (the seam moves to
    ``C(shift)``); exact, inserts a knot at ``shift`` when needed.

    Parameters
    ----------
    curve : NurbsCurve
        A closed curve.
    shift : float
        Parameter shift (modulo 1).

    Returns
    -------
    NurbsCurve
    """
    curve = _check_curve(curve)
    if not curve.closed:
        raise NurbsInputError("curve: rotate_seam needs a closed curve")
    U, Qw = rotate_periodic(curve.knots, _homogeneous(curve), curve.degree, float(shift))
    return _from_homogeneous(curve.degree, U, Qw, True)


def _period_knots(curve: NurbsCurve) -> np.ndarray:
    """Knot values of one period [0, 1) (closed) or interior knots (open)."""
    p = curve.degree
    if curve.closed:
        return curve.knots[p:curve.knots.size - p - 1]
    return curve.knots[p + 1:curve.knots.size - p - 1]


def make_compatible(curves: Sequence[NurbsCurve]) -> list[NurbsCurve]:
    """Bring curves (all open or all closed) to one degree and one knot vector
    (paper §3.2.4 steps 1–3): elevate to the highest degree, map open domains
    to [0, 1], then insert in each curve the knots the others have (the union
    of the knot multisets).  Shapes are unchanged.

    Parameters
    ----------
    curves : sequence of NurbsCurve

    Returns
    -------
    list of NurbsCurve
        Same order, one degree and one knot vector.
    """
    curves = [_check_curve(c, f"curves[{i}]") for i, c in enumerate(curves)]
    if not curves:
        raise NurbsInputError("curves: need at least one curve")
    closed = {c.closed for c in curves}
    if len(closed) != 1:
        raise NurbsInputError("curves: mix of open and closed curves")
    pmax = max(c.degree for c in curves)
    curves = [reparameterise(elevate_degree(c, pmax - c.degree)) for c in curves]
    # union multiset: every distinct knot value with its largest multiplicity
    per_curve = [distinct_knots(_period_knots(c)) for c in curves]
    merged, _ = distinct_knots(np.sort(np.concatenate([v for v, _ in per_curve])), 1e-12)
    counts = np.zeros((len(curves), merged.size), dtype=int)
    for row, (vals, mult) in zip(counts, per_curve):
        idx = np.clip(np.searchsorted(merged, vals - 1e-12), 0, merged.size - 1)
        np.add.at(row, idx, mult)
    need = counts.max(axis=0)
    out = []
    for c, row in zip(curves, counts):
        X = np.repeat(merged, need - row)
        out.append(insert_knots(c, X) if X.size else c)
    ref = out[0].knots
    for c in out[1:]:
        if c.knots.shape != ref.shape or np.max(np.abs(c.knots - ref)) > 1e-9:
            raise NurbsInputError("curves: knot vectors could not be unified")
    return [NurbsCurve(c.degree, ref, c.control_points, c.weights, closed=c.closed) for c in out]
