"""Fitting NURBS curves to ordered points within a tolerance (paper §3.2).

Steps (paper §3.2.1–3.2.3, NURBS Book §9.4.1):

1. chord-length parameters ``ū_k`` (eqs. 6–8; eq. 8 is printed with
   ``ū_{k+1}`` on the right, the recursion is over ``ū_{k-1}``; for a closed
   contour the closing chord ``|Q_0 - Q_m|`` is part of the length ``d`` and
   ``ū`` runs over [0, 1) -- the point Q_0 sits at both 0 and 1);
2. knots by eq. 9 (every knot span holds parameters); the periodic analogue
   puts break j of n at the parameter of the fractional data index j (m+1)/n;
3. control points by least squares.  Open curves keep their end points fixed,
   ``P_0 = Q_0``, ``P_n = Q_m`` (eq. 10); closed curves solve the periodic
   problem with the folded design matrix (no end constraints).

``tol`` is a bound on the true maximum point-to-curve distance (computed by
:func:`~cardionurbs.nurbs.projection.curve_closest_points`); the fit starts
with the fewest control points the degree allows and adds one at a time until
the bound holds (paper §3.2.3, first strategy).  ``rational=True`` also
optimises the weights (variable projection: least squares in the control
points inside a trust-region search over log-weights); with ``tol`` it then
bisects for the fewest control points whose weighted fit still meets it.

Eq. 9 is applied at the *centred* fractional data index ``j d - 1/2``
(the book's formula uses ``j d - 1``).  The centred rule makes the knot vector
mirror-symmetric under reversal of the data, so reversed points give exactly
the reversed curve, and still leaves at least one parameter in every span
(spans are ``d >= 1`` data indices wide).  ``knot_rule="book"`` gives the
literal formula, ``"uniform"`` equally spaced knots (for comparison).  For
closed curves "eq9" and "book" are the same periodic rule.
"""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple, Sequence

import numpy as np
from scipy import linalg, sparse
from scipy.optimize import least_squares
from scipy.sparse.linalg import MatrixRankWarning, spsolve

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs import _validate as V
from cardionurbs.nurbs.basis import basis_matrix
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.knots import periodic_knot_vector
from cardionurbs.nurbs.projection import (curve_closest_points, curve_distance_bounds,
                                          curve_seed_distances)

__all__ = ["fit_curve", "fit_compatible_curves", "CompatibleFit", "chord_length_parameters",
           "approximation_knots", "periodic_approximation_breaks", "least_squares_curve",
           "solve_normal_equations", "KNOT_RULES"]

KNOT_RULES = ("eq9", "book", "uniform")


def chord_length_parameters(points: np.ndarray, closed: bool = False) -> np.ndarray:
    """Chord-length parameters ``ū_k`` (paper eqs. 6–8).

    Open: ``ū_0 = 0``, ``ū_m = 1``.  Closed: the closing chord counts, so
    ``ū_0 = 0`` and ``ū_m = 1 - |Q_0 - Q_m| / d`` < 1.

    Parameters
    ----------
    points : (m + 1, d) float ndarray
        Ordered points (any units).
    closed : bool, default False
        The points form a loop (no repeated end point).

    Returns
    -------
    (m + 1,) float ndarray
        Non-decreasing parameters in [0, 1] (dimensionless).
    """
    Q = np.asarray(points, dtype=float)
    chords = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    if closed:
        chords = np.append(chords, np.linalg.norm(Q[0] - Q[-1]))
    d = chords.sum()                                                  # eq. 6
    if not d > 0:
        raise NurbsInputError("points: zero chord length (all points coincide)")
    u = np.concatenate([[0.0], np.cumsum(chords) / d])                # eqs. 7, 8
    if closed:
        return u[:-1]
    u[-1] = 1.0
    return u


def _fractional_index(params: np.ndarray, x: np.ndarray, closed: bool) -> np.ndarray:
    """Linear interpolation of the parameters at fractional data indices ``x``."""
    ext = np.append(params, 1.0) if closed else params
    return np.interp(x, np.arange(ext.size), ext)


def approximation_knots(params: np.ndarray, n_ctrl: int, degree: int,
                        rule: str = "eq9") -> np.ndarray:
    """Clamped knot vector for ``n_ctrl`` control points (paper eq. 9).

    ``d = (m+1)/(n-p+1)``; interior knot j = the parameter at fractional data
    index ``j d - 1/2`` (rule "eq9"), ``j d - 1`` (rule "book": ``i = int(jd)``,
    ``α = jd - i``, ``u_{p+j} = (1-α) ū_{i-1} + α ū_i``), or ``j / (n-p+1)``
    (rule "uniform").

    Parameters
    ----------
    params : (m + 1,) float ndarray
        Data parameters in [0, 1] (:func:`chord_length_parameters`).
    n_ctrl : int
        Number of control points n + 1, p + 1 <= n_ctrl <= m + 1.
    degree : int
        The degree p.
    rule : {"eq9", "book", "uniform"}, default "eq9"

    Returns
    -------
    (n_ctrl + p + 1,) float ndarray
        Clamped knots on [0, 1].
    """
    p = degree
    n = n_ctrl - 1
    j = np.arange(1, n - p + 1)
    if rule == "uniform":
        inner = j / (n - p + 1)
    else:
        d = params.size / (n - p + 1)
        shift = 0.5 if rule == "eq9" else 1.0
        inner = _fractional_index(params, j * d - shift, False)
    return np.concatenate([np.zeros(p + 1), inner, np.ones(p + 1)])


def periodic_approximation_breaks(params: np.ndarray, n_ctrl: int, rule: str = "eq9") -> np.ndarray:
    """Breaks ``0 = B_0 < ... < B_n = 1`` of a periodic fit with ``n_ctrl`` spans:
    ``B_j`` = parameter at fractional data index ``j (m+1)/n`` (the periodic
    analogue of eq. 9: each span holds ``(m+1)/n >= 1`` parameters), or ``j/n``
    ("uniform").

    Parameters
    ----------
    params : (m + 1,) float ndarray
        Data parameters in [0, 1).
    n_ctrl : int
        Number of distinct control points n (= spans per period).
    rule : {"eq9", "book", "uniform"}, default "eq9"

    Returns
    -------
    (n_ctrl + 1,) float ndarray
        The breaks, from 0 to 1.
    """
    n = n_ctrl
    j = np.arange(n + 1)
    if rule == "uniform":
        B = j / n
    else:
        B = _fractional_index(params, j * params.size / n, True)
    B[0], B[-1] = 0.0, 1.0
    return B


#: up to this many unknowns eq. 10 is solved dense (Cholesky), above it sparse (SuperLU)
DENSE_SOLVE_MAX = 64


def solve_normal_equations(N: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Least-squares control points from ``(N^T N) P = N^T R`` (paper eq. 10).

    N^T N is symmetric positive definite when every knot span holds data
    (eq. 9). Up to ``DENSE_SOLVE_MAX`` unknowns it is factorised dense
    (Cholesky); larger systems, whose N^T N is (cyclically) banded with p + 1
    non-zeros per row of N, are formed and factorised sparse (SuperLU).
    Either falls back to an SVD least-squares solve when N^T N is singular
    (a knot span without data).

    Parameters
    ----------
    N : (m, n) float ndarray
        Design matrix (basis functions at the data parameters).
    R : (m, d) float ndarray
        Right-hand sides (data points, minus fixed end-point terms).

    Returns
    -------
    (n, d) float ndarray
        The control points (units of R).
    """
    if N.shape[1] <= DENSE_SOLVE_MAX:
        # small systems (contours: tens of control points): a dense Cholesky of the
        # banded N^T N costs less than building and factorising a sparse matrix
        try:
            P = linalg.cho_solve(linalg.cho_factor(N.T @ N, check_finite=False), N.T @ R,
                                 check_finite=False)
        except linalg.LinAlgError:
            P = None
        if P is not None and np.all(np.isfinite(P)):
            return P.reshape(N.shape[1], -1)
        P, *_ = np.linalg.lstsq(N, R, rcond=None)
        return P.reshape(N.shape[1], -1)
    Ns = sparse.csr_matrix(N)
    A = (Ns.T @ Ns).tocsc()
    b = Ns.T @ R
    with warnings.catch_warnings():
        warnings.simplefilter("error", MatrixRankWarning)
        try:
            P = spsolve(A, b)
        except (MatrixRankWarning, RuntimeError):
            P = None
    P = None if P is None else np.asarray(P).reshape(A.shape[0], -1)
    if P is None or not np.all(np.isfinite(P)):
        P, *_ = np.linalg.lstsq(N, R, rcond=None)
    return P.reshape(N.shape[1], -1)


def _rational_basis(B: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Rational basis ``R_i = N_i w_i / sum_j N_j w_j`` from the B-spline one."""
    Bw = B * weights[None, :]
    return Bw / Bw.sum(axis=1, keepdims=True)


def _design(params: np.ndarray, degree: int, n_ctrl: int, closed: bool, rule: str
            ) -> tuple[np.ndarray, np.ndarray]:
    """Knot vector and B-spline design matrix ``N[k, i] = N_i,p(ū_k)`` (folded when closed)."""
    U = _knots(params, degree, n_ctrl, closed, rule)
    if closed:
        return U, basis_matrix(U, degree, params, n_periodic=n_ctrl)
    return U, basis_matrix(U, degree, params)


def _knots(params: np.ndarray, degree: int, n_ctrl: int, closed: bool, rule: str) -> np.ndarray:
    """The knot vector of :func:`_design` alone (paper eq. 9, or its periodic analogue)."""
    if closed:
        return periodic_knot_vector(periodic_approximation_breaks(params, n_ctrl, rule), degree)
    return approximation_knots(params, n_ctrl, degree, rule)


def _control_points(N: np.ndarray, w: np.ndarray, Q: np.ndarray, closed: bool
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Control points for weights ``w``, and the rational design matrix R."""
    R = _rational_basis(N, w)
    if closed:
        return solve_normal_equations(R, Q), R
    n_ctrl = N.shape[1]
    P = np.empty((n_ctrl, Q.shape[1]))
    P[0], P[-1] = Q[0], Q[-1]
    if n_ctrl > 2:
        rhs = Q[1:-1] - R[1:-1, :1] * Q[0] - R[1:-1, -1:] * Q[-1]     # R_k of eq. 10
        P[1:-1] = solve_normal_equations(R[1:-1, 1:-1], rhs)
    return P, R


def least_squares_curve(points: np.ndarray, params: np.ndarray, degree: int, n_ctrl: int,
                        closed: bool, rule: str = "eq9", weights: np.ndarray | None = None
                        ) -> NurbsCurve:
    """Least-squares NURBS with ``n_ctrl`` control points at fixed parameters.

    Open: end points fixed, the other control points from the normal
    equations (paper eq. 10).  Closed: periodic, all ``n_ctrl`` points free.
    With ``weights`` the rational basis ``R_i = N_i w_i / sum_j N_j w_j``
    replaces N (the problem stays linear in the control points).

    Parameters
    ----------
    points : (m + 1, d) float ndarray
        Ordered data points (any units).
    params : (m + 1,) float ndarray
        Their parameters in [0, 1].
    degree : int
        The degree p.
    n_ctrl : int
        Number of (distinct) control points.
    closed : bool
        Fit a periodic curve.
    rule : {"eq9", "book", "uniform"}, default "eq9"
        Knot placement (:func:`approximation_knots`).
    weights : (n_ctrl,) float ndarray, optional
        Fixed positive weights; default ones.

    Returns
    -------
    NurbsCurve
    """
    Q = np.asarray(points, dtype=float)
    w = np.ones(n_ctrl) if weights is None else np.asarray(weights, dtype=float)
    U, N = _design(params, degree, n_ctrl, closed, rule)
    P, _ = _control_points(N, w, Q, closed)
    return NurbsCurve(degree, U, P, w, closed=closed)


def _optimise_weights(points: np.ndarray, params: np.ndarray, degree: int, n_ctrl: int,
                      closed: bool, rule: str, max_iterations: int = 60) -> NurbsCurve:
    """Weights minimising the squared residuals at the fixed parameters.

    Variable projection (Golub & Pereyra 1973): for every trial of weights
    the control points are re-solved by eq. 10, so only the log-weights
    ``theta_j`` of control points 1..n-1 are searched (w_0 = 1 removes the
    scale invariance; bounds [-3, 3]), by scipy's trust-region least squares
    with Kaufman's Jacobian: with ``R_kj = N_kj w_j / sum_l N_kl w_l``,
    ``d(R P)_k / d theta_j = R_kj (P_j - C_k)``, projected onto the orthogonal
    complement of the columns of R that are solved for.
    """
    Q = np.asarray(points, dtype=float)
    U, N = _design(params, degree, n_ctrl, closed, rule)
    m, d = Q.shape
    free = slice(None) if closed else slice(1, n_ctrl - 1)

    def state(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = np.exp(np.concatenate([[0.0], theta]))
        P, R = _control_points(N, w, Q, closed)
        return P, R, R @ P

    def residuals(theta: np.ndarray) -> np.ndarray:
        return (state(theta)[2] - Q).ravel()

    def jacobian(theta: np.ndarray) -> np.ndarray:
        P, R, C = state(theta)
        # J0[k, c, j] = R_kj (P_jc - C_kc)
        J0 = R[:, None, :] * (P.T[None, :, :] - C[:, :, None])
        Rf = R[:, free]
        # Kaufman: remove the part the (re-solved) free control points absorb
        coef = solve_normal_equations(Rf, J0.reshape(m, d * n_ctrl)).reshape(-1, d, n_ctrl)
        J = J0 - np.einsum("ki,icj->kcj", Rf, coef)
        return J.reshape(m * d, n_ctrl)[:, 1:]

    res = least_squares(residuals, np.zeros(n_ctrl - 1), jac=jacobian, bounds=(-3.0, 3.0),
                        method="trf", x_scale=1.0, max_nfev=max_iterations)
    w = np.exp(np.concatenate([[0.0], res.x]))
    P, _ = _control_points(N, w, Q, closed)
    return NurbsCurve(degree, U, P, w, closed=closed)


def max_distance(curve: NurbsCurve, points: np.ndarray) -> float:
    """Maximum true distance from ``points`` to ``curve``, as the closest points of
    :func:`curve_closest_points` give it.

    Each point's seed distance (:func:`curve_seed_distances`) bounds its projected
    distance from above, so only the points whose seed distance exceeds the largest
    projected distance found so far can hold the maximum: the 16 farthest by seed are
    projected first, then only those of the rest that can still beat them.

    Parameters
    ----------
    curve : NurbsCurve
    points : (m, d) float ndarray
        Points in the curve's units.

    Returns
    -------
    float
        The largest point-to-curve distance (points' units; 0 for no points).
    """
    points = V.point_rows(points, "points", curve.dimension)
    seed = curve_seed_distances(curve, points)
    order = np.argsort(-seed)
    _, dist = curve_closest_points(curve, points[order[:16]])
    best = float(dist.max())
    rest = order[16:][seed[order[16:]] >= best - 1e-9 * max(best, 1.0)]
    if rest.size:
        best = max(best, float(curve_closest_points(curve, points[rest])[1].max()))
    return best


def _error_within(curve: NurbsCurve, points: np.ndarray, params: np.ndarray | None,
                  tol: float) -> tuple[bool, float]:
    """Whether max distance <= tol, and that distance (or an upper bound <= tol).

    The residual at the fit parameters ``max |Q_k - C(ū_k)|`` (when ``params`` are
    given) bounds the true distance from above; the cheap bounds of
    :func:`curve_distance_bounds` settle most other points; the projection is computed
    only for the points they leave undecided."""
    if params is not None:
        bound = float(np.max(np.linalg.norm(curve.evaluate(params) - points, axis=1)))
        if bound <= tol:
            return True, bound
    lower, upper = curve_distance_bounds(curve, points)
    if lower.max() > tol:                   # surely too far: skip the projection
        return False, float(upper.max())
    near = np.flatnonzero(upper > tol)      # only these can violate the bound
    if near.size == 0:
        return True, float(upper.max())
    near = near[np.argsort(-upper[near])]
    worst, rest = near[:8], near[8:]        # a violation is usually among the worst seeds
    _, dist = curve_closest_points(curve, points[worst])
    if dist.max() > tol or rest.size == 0:
        err = max(float(dist.max()), float(np.delete(upper, near).max(initial=0.0)))
        return err <= tol, err
    _, dist_rest = curve_closest_points(curve, points[rest])
    err = max(float(dist.max()), float(dist_rest.max()),
              float(np.delete(upper, near).max(initial=0.0)))
    return err <= tol, err


def fit_curve(points: Any, degree: int = 3, closed: bool = False, tol: float | None = None,
              n_ctrl: int | None = None, rational: bool = False, knot_rule: str = "eq9"
              ) -> NurbsCurve:
    """Fit a NURBS curve to ordered points (paper §3.2).

    Parameters
    ----------
    points : (m, d) float array_like
        Points in drawing order, any units (e.g. mm); closed: no repeated end point
        (a repeated one is dropped).
    degree : int, default 3
        Curve degree p (the paper's order 3 is degree 3 here by default).
    closed : bool, default False
        Fit a periodic curve, C^(p-1) across the seam.
    tol : float, optional
        Maximum allowed point-to-curve distance, in the points' units; control
        points are added until it holds.  Default (with ``n_ctrl`` None): 1e-3
        of the diagonal of the points' bounding box.
    n_ctrl : int, optional
        A fixed number of (distinct) control points instead of ``tol``.
    rational : bool, default False
        Also optimise the weights: with ``tol``, once the polynomial fit meets it,
        the fewest control points whose weighted fit still meets it are searched
        by bisection below the polynomial count.
    knot_rule : {"eq9", "book", "uniform"}, default "eq9"
        Knot placement, see module doc.

    Returns
    -------
    NurbsCurve
        Open (clamped, interpolating the end points) or closed, with the fewest
        control points that meet ``tol`` (or ``n_ctrl`` of them).

    Raises
    ------
    NurbsInputError
        Too few points for the degree, non-finite points, a bad option, or
        ``tol`` not met even with as many control points as points.

    Examples
    --------
    A circle of radius 30 mm sampled at 60 points, fitted within 0.05 mm:

    >>> import numpy as np
    >>> from cardionurbs import nurbs
    >>> t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    >>> pts = np.column_stack([30 * np.cos(t), 30 * np.sin(t)])
    >>> c = nurbs.fit_curve(pts, degree=3, closed=True, tol=0.05)
    >>> c.closed, c.degree, c.dimension
    (True, 3, 2)
    >>> bool(nurbs.fitting.max_distance(c, pts) <= 0.05)
    True
    """
    p = V.degree_value(degree)
    Q = V.finite_array(points, "points", ndim=2)
    if Q.shape[1] < 1:
        raise NurbsInputError(f"points: need at least one coordinate, got shape {Q.shape}")
    if knot_rule not in KNOT_RULES:
        raise NurbsInputError(f"knot_rule: must be one of {KNOT_RULES}, got {knot_rule!r}")
    if closed and Q.shape[0] > 1 and np.array_equal(Q[0], Q[-1]):
        Q = Q[:-1]
    m1 = Q.shape[0]
    if m1 < p + 1:
        raise NurbsInputError(f"points: degree {p} needs at least {p + 1} points, got {m1}")
    params = chord_length_parameters(Q, closed)
    n_min, n_max = p + 1, m1
    if n_ctrl is not None:
        n = V.degree_value(n_ctrl, "n_ctrl", minimum=n_min)
        if n > n_max:
            raise NurbsInputError(f"n_ctrl: {n} control points need at least {n} points, got {m1}")
        if rational:
            return _optimise_weights(Q, params, p, n, closed, knot_rule)
        return least_squares_curve(Q, params, p, n, closed, knot_rule)
    tol = _tolerance(tol, Q)
    found = _fewest_within(Q, params, p, closed, knot_rule, tol, n_min, n_max)
    if rational:
        # fewest control points whose weighted fit meets tol: bisection between
        # the minimum and the polynomial count (assumes more points never hurt)
        lo, hi = n_min - 1, found.n_control
        while hi - lo > 1:
            mid = (lo + hi) // 2
            c = _optimise_weights(Q, params, p, mid, closed, knot_rule)
            ok, _ = _error_within(c, Q, params, tol)
            if ok:
                hi, found = mid, c
            else:
                lo = mid
    return found


def _tolerance(tol: float | None, Q: np.ndarray) -> float:
    """:func:`fit_curve`'s ``tol`` checked (a finite number > 0), or its default: 1e-3 of the
    diagonal of the points' bounding box."""
    if tol is None:
        return 1e-3 * float(np.linalg.norm(np.ptp(Q, axis=0)))
    try:
        tol = float(tol)
    except (TypeError, ValueError):
        raise NurbsInputError(f"tol: must be a number, got {tol!r}") from None
    if not np.isfinite(tol) or tol <= 0:
        raise NurbsInputError(f"tol: must be a finite number > 0, got {tol}")
    return tol


def _fewest_within(Q: np.ndarray, params: np.ndarray, p: int, closed: bool, knot_rule: str,
                   tol: float, n_min: int, n_max: int) -> NurbsCurve:
    """The polynomial least-squares fit with the fewest control points (from ``n_min``) that
    lies within ``tol`` of every point (paper §3.2.3, first strategy); NurbsInputError
    naming the best distance reached when none up to ``n_max`` does."""
    best: tuple[float, NurbsCurve] | None = None
    for n in range(n_min, n_max + 1):
        c = least_squares_curve(Q, params, p, n, closed, knot_rule)
        ok, err = _error_within(c, Q, params, tol)
        if ok:
            return c
        if best is None or err < best[0]:
            best = (err, c)
    assert best is not None
    raise NurbsInputError(f"tol: {tol} not reached with up to {n_max} control points "
                          f"(best maximum distance {best[0]:.3g})")


# ------------------------------------------------------- sections sharing knots
class CompatibleFit(NamedTuple):
    """Result of :func:`fit_compatible_curves`.

    Attributes
    ----------
    curves : list of NurbsCurve
        One curve per section, all on the same knot vector.
    n_ctrl : int
        The common number of (distinct) control points.
    max_error : float
        Largest point-to-curve distance (points' units; NaN: not measured).
    met : bool
        Every section within its tolerance.
    """

    curves: list[NurbsCurve]    #: one curve per section, all on the same knot vector
    n_ctrl: int                 #: the common number of (distinct) control points
    max_error: float            #: largest point-to-curve distance (points' units; NaN: not measured)
    met: bool                   #: every section within its tolerance


def fit_compatible_curves(point_sets: Sequence[Any], degree: int = 3, closed: bool = False,
                          tol: float | Sequence[float] | None = None,
                          error_points: Sequence[Any | None] | None = None,
                          counts: Sequence[int] | None = None, knot_rule: str = "eq9",
                          measure_error: bool = True) -> CompatibleFit:
    """Fit sections that must share one knot vector, within a tolerance (paper §3.2.4).

    Lofting needs compatible sections: same degree and knot vector. Every
    section holds the same number of points m + 1 (resample them first); their
    chord-length parameters (eqs. 6–8) are averaged over the sections, as for
    surface fitting (NURBS Book §9.2.5), and the averaged parameters give the
    one knot vector by eq. 9 (``knot_rule``; the periodic analogue when
    ``closed``). Each section is then the least-squares fit (eq. 10) at its
    own chord-length parameters on that knot vector.

    The control-point count grows as in :func:`fit_curve` (paper §3.2.3, first
    strategy) through ``counts``: sections are visited in order and the count is
    raised until each meets its tolerance; the first count at which every section
    with a tolerance holds is used for all. When no count meets every tolerance
    the largest is used and ``met`` is False.

    Parameters
    ----------
    point_sets : sequence of (m + 1, d) float array_like
        The sections' ordered points (any units, e.g. mm), all of one shape.
    degree : int, default 3
        The degree p.
    closed : bool, default False
        Periodic sections.
    tol : float or sequence of float, optional
        Bound on the true distance (closest point, :func:`max_distance`) from
        ``error_points[i]`` to the section's curve, one value or one per section
        (points' units); default 1e-3 of the largest section's bounding-box diagonal.
    error_points : sequence of (k, d) array_like or None, optional
        The points each section is judged against (default: its own points;
        ``None`` for a section: not judged).
    counts : sequence of int, optional
        The control-point counts to try (default: every count from p + 1 to m + 1).
    knot_rule : {"eq9", "book", "uniform"}, default "eq9"
    measure_error : bool, default True
        Measure ``max_error`` by projecting the points; False skips that for a fit
        that met every tolerance (the projections cost as much as the fit itself)
        and reports NaN: each section is then known to lie within its tolerance.

    Returns
    -------
    CompatibleFit
        The curves, the common count, the largest distance and whether every
        tolerance was met.
    """
    p, Q, error_points, tols, steps = _compatible_inputs(point_sets, degree, tol, error_points,
                                                         counts, knot_rule)
    search = _CompatibleSearch(Q, p, closed, knot_rule, steps, tols)
    judged = [(i, V.finite_array(pts, f"error_points[{i}]", ndim=2))
              for i, pts in enumerate(error_points) if pts is not None]
    need, met = search.common_count(judged)
    curves = search.curves_at(need)
    if met and not measure_error:
        return CompatibleFit(curves, steps[need], float("nan"), met)
    worst = 0.0
    for i, ep in enumerate(error_points):
        if ep is not None:
            worst = max(worst, max_distance(curves[i], np.asarray(ep, float)))
    return CompatibleFit(curves, steps[need], worst, met)


def _compatible_inputs(point_sets: Sequence[Any], degree: int,
                       tol: float | Sequence[float] | None,
                       error_points: Sequence[Any | None] | None,
                       counts: Sequence[int] | None, knot_rule: str
                       ) -> tuple[int, list[np.ndarray], Sequence[Any | None], np.ndarray, list[int]]:
    """The checked arguments of :func:`fit_compatible_curves`: degree, sections (each
    (m + 1, d) float), error point sets, per-section tolerances (len(Q),) and the sorted
    control-point counts to try."""
    p = V.degree_value(degree)
    if knot_rule not in KNOT_RULES:
        raise NurbsInputError(f"knot_rule: must be one of {KNOT_RULES}, got {knot_rule!r}")
    Q = [V.finite_array(pts, f"point_sets[{i}]", ndim=2) for i, pts in enumerate(point_sets)]
    if not Q:
        raise NurbsInputError("point_sets: need at least one section")
    shapes = {q.shape for q in Q}
    if len(shapes) != 1:
        raise NurbsInputError(f"point_sets: every section needs the same number of points and "
                              f"coordinates (resample first), got shapes {sorted(shapes)}")
    m1 = Q[0].shape[0]
    if m1 < p + 1:
        raise NurbsInputError(f"point_sets: degree {p} needs at least {p + 1} points, got {m1}")
    if error_points is None:
        error_points = Q
    if len(error_points) != len(Q):
        raise NurbsInputError(f"error_points: {len(error_points)} sets for {len(Q)} sections")
    tols = np.broadcast_to(np.asarray(
        1e-3 * max(float(np.linalg.norm(np.ptp(q, axis=0))) for q in Q) if tol is None else tol,
        dtype=float), (len(Q),))
    if not np.all(np.isfinite(tols)) or np.any(tols <= 0):
        raise NurbsInputError(f"tol: must be finite numbers > 0, got {tol!r}")
    steps = sorted({int(n) for n in (range(p + 1, m1 + 1) if counts is None else counts)})
    if not steps or steps[0] < p + 1 or steps[-1] > m1:
        raise NurbsInputError(f"counts: must lie in [{p + 1}, {m1}], got {list(counts or [])}")
    return p, Q, error_points, tols, steps


class _CompatibleSearch:
    """The count search of :func:`fit_compatible_curves`: fits and tolerance decisions per
    (count index, section), each made once and only when asked."""

    def __init__(self, Q: list[np.ndarray], p: int, closed: bool, knot_rule: str,
                 steps: list[int], tols: np.ndarray) -> None:
        self.Q, self.p, self.closed, self.knot_rule = Q, p, closed, knot_rule
        self.steps, self.tols = steps, tols
        self.own = [chord_length_parameters(q, closed) for q in Q]
        self.params = np.mean(self.own, axis=0)
        self.knots_at: dict[int, np.ndarray] = {}
        self.fitted: dict[tuple[int, int], NurbsCurve] = {}
        self.decided: dict[tuple[int, int], bool] = {}

    def curve_at(self, k: int, i: int) -> NurbsCurve:
        """Section ``i`` fitted with ``steps[k]`` control points (eq. 10)."""
        # each section is fitted only when asked: the search raises the count for one
        # section at a time, and the other sections' fits at a rejected count are never used
        if (k, i) not in self.fitted:
            n, p = self.steps[k], self.p
            if k not in self.knots_at:
                self.knots_at[k] = _knots(self.params, p, n, self.closed, self.knot_rule)
            U = self.knots_at[k]
            N = (basis_matrix(U, p, self.own[i], n_periodic=n) if self.closed
                 else basis_matrix(U, p, self.own[i]))
            P, _ = _control_points(N, np.ones(n), self.Q[i], self.closed)
            self.fitted[(k, i)] = NurbsCurve(p, U, P, closed=self.closed)
        return self.fitted[(k, i)]

    def curves_at(self, k: int) -> list[NurbsCurve]:
        """Every section at count index ``k``."""
        return [self.curve_at(k, i) for i in range(len(self.Q))]

    def holds(self, k: int, i: int, pts: np.ndarray) -> bool:
        """Whether section ``i`` at count index ``k`` lies within its tolerance of ``pts``."""
        # the same decision as max_distance <= tol, projecting only the points the
        # cheap distance bounds leave undecided (most counts fail or pass outright);
        # each (count, section) is judged once (the final check asks again)
        if (k, i) not in self.decided:
            self.decided[(k, i)] = bool(
                _error_within(self.curve_at(k, i), pts, None, float(self.tols[i]))[0])
        return self.decided[(k, i)]

    def common_count(self, judged: list[tuple[int, np.ndarray]]) -> tuple[int, bool]:
        """The first count index at which every judged section holds, and whether one does
        (else the largest index and False)."""
        last = len(self.steps) - 1
        need = 0
        while True:
            for i, pts in judged:
                k = next((k for k in range(need, last + 1) if self.holds(k, i, pts)), None)
                if k is None:
                    return last, False
                need = k
            # a least-squares fit is not monotone in its count: raising the count for a later
            # section can lose an earlier one, so the count must hold for every section at once
            if all(self.holds(need, i, pts) for i, pts in judged):
                return need, True
            if need == last:
                return need, False
            need += 1
