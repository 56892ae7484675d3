"""Knot vectors and the algorithms that change them without changing the curve.

Array-level implementations (no curve class) of The NURBS Book algorithms:

* :func:`insert_knot` -- A5.1 (CurveKnotIns), also valid on unclamped
  (periodic) knot vectors, used to clamp a periodic curve;
* :func:`refine_knot_vector` -- A5.4 (RefineKnotVectCurve), clamped curves;
* :func:`elevate_degree_clamped` -- A5.9 (DegreeElevateCurve), clamped curves
  with any interior knots;
* periodic (closed) splines: :func:`periodic_knot_vector`,
  :func:`insert_knot_periodic` (Boehm's insertion with cyclic indices),
  :func:`rotate_periodic` (move the seam), :func:`clamp_periodic`,
  :func:`elevate_degree_periodic`.

Control points are always *homogeneous* ``Pw = (w * P, w)`` with the control
index first; any trailing shape is allowed, so a surface's rows can be refined
in one call.

Periodic representation (used by closed curves and surfaces closed in u)
----------------------------------------------------------------------------
A closed spline of degree p with ``n`` distinct control points ``P_0..P_{n-1}``
is stored with the full, unclamped knot vector ``U`` of ``n + 2p + 1`` knots
built from the *breaks* ``B = U[p : n + p + 1]`` (``B[0] = 0``, ``B[n] = 1``)
by periodic extension ``U[i + n] = U[i] + 1``.  With the wrapped control points
``W_j = P_{j mod n}`` (``j = 0..n+p-1``), ``(U, W)`` is an ordinary B-spline
whose domain ``[U[p], U[n+p]] = [0, 1]`` covers the loop once; it is
C^(p-m) at a knot of multiplicity m, in particular across the seam u = 0 = 1.
Canonical form: the run of knots at the seam starts at index p
(``U[p-1] < 0``), so two closed splines with the same knot multiset have the
same ``U`` element by element.
"""

from __future__ import annotations

from math import comb

import numpy as np

from cardionurbs.nurbs.basis import basis_matrix, find_spans

__all__ = [
    "periodic_knot_vector", "periodic_knot", "knot_multiplicity", "insert_knot",
    "refine_knot_vector", "insert_knot_periodic", "refine_periodic", "rotate_periodic",
    "canonical_periodic", "clamp_periodic", "elevate_degree_clamped",
    "elevate_degree_periodic", "distinct_knots",
]

_KNOT_EPS = 1e-12


def _float_arrays(knots: np.ndarray, Pw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A knot vector and homogeneous control points as float arrays (not copied when
    they already are)."""
    return np.asarray(knots, dtype=float), np.asarray(Pw, dtype=float)


def distinct_knots(values: np.ndarray, tol: float = _KNOT_EPS) -> tuple[np.ndarray, np.ndarray]:
    """Distinct values of a sorted knot sequence and their multiplicities.

    Parameters
    ----------
    values : (m,) float ndarray
        Sorted knots.
    tol : float
        Knots closer than this are one value.

    Returns
    -------
    values : (k,) float ndarray
        The distinct knots.
    counts : (k,) int ndarray
        Their multiplicities.
    """
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return v, np.zeros(0, dtype=int)
    new = np.concatenate([[True], np.diff(v) > tol])
    starts = np.flatnonzero(new)
    mult = np.diff(np.concatenate([starts, [v.size]]))
    return v[starts], mult


def knot_multiplicity(knots: np.ndarray, x: float, tol: float = _KNOT_EPS) -> int:
    """Number of knots equal to ``x`` (within ``tol``).

    Parameters
    ----------
    knots : (m,) float ndarray
    x : float
    tol : float

    Returns
    -------
    int
    """
    return int(np.count_nonzero(np.abs(np.asarray(knots, dtype=float) - x) <= tol))


def periodic_knot_vector(breaks: np.ndarray, degree: int) -> np.ndarray:
    """Full periodic knot vector ``U`` (n + 2p + 1 knots) from the breaks.

    ``U = (B[n-p:n] - 1, B, B[1:p+1] + 1)``.

    Parameters
    ----------
    breaks : (n + 1,) float ndarray
        The knots ``0 = B[0] <= ... <= B[n] = 1`` of one period, n >= p.
    degree : int
        The degree p.

    Returns
    -------
    (n + 2p + 1,) float ndarray
    """
    B = np.asarray(breaks, dtype=float)
    p = int(degree)
    n = B.size - 1
    return np.concatenate([B[n - p:n] - 1.0, B, B[1:p + 1] + 1.0])


def periodic_knot(knots: np.ndarray, degree: int, n: int, j: np.ndarray) -> np.ndarray:
    """Knot ``T_j`` of the bi-infinite periodic sequence (``T_j = U[j]`` in range).

    Parameters
    ----------
    knots : (n + 2p + 1,) float ndarray
        Periodic knot vector.
    degree : int
        The degree p.
    n : int
        Number of distinct control points (the period in indices).
    j : int ndarray
        Indices, any integers.

    Returns
    -------
    float ndarray
        ``T_j``, shape of ``j``.
    """
    U = np.asarray(knots, dtype=float)
    j = np.asarray(j) - degree
    q, r = np.divmod(j, n)
    return U[degree + r] + q


def insert_knot(knots: np.ndarray, Pw: np.ndarray, degree: int, u: float, times: int = 1
                ) -> tuple[np.ndarray, np.ndarray]:
    """Insert ``u`` ``times`` times (A5.1, Boehm).

    Works on any knot vector (clamped or not) as long as ``U[p] <= u <= U[n]``.

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector.
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    u : float
        The knot to insert.
    times : int, default 1

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U, Pw = _float_arrays(knots, Pw)
    p = int(degree)
    r = int(times)
    if r <= 0:
        return U.copy(), Pw.copy()
    k = int(np.searchsorted(U, u, side="right")) - 1
    s = knot_multiplicity(U, u)
    if r + s > p + 1 or k - s < 0:
        raise ValueError(f"cannot insert knot {u} {r} times (multiplicity {s}, degree {p})")
    npi = Pw.shape[0] - 1
    UQ = np.concatenate([U[:k + 1], np.full(r, float(u)), U[k + 1:]])
    Qw = np.zeros((npi + 1 + r,) + Pw.shape[1:])
    Qw[:k - p + 1] = Pw[:k - p + 1]
    Qw[k - s + r:] = Pw[k - s:]
    Rw = Pw[k - p:k - s + 1].copy()
    L = k - p + 1
    for j in range(1, r + 1):
        L = k - p + j
        for i in range(0, p - j - s + 1):
            alpha = (u - U[L + i]) / (U[i + k + 1] - U[L + i])
            Rw[i] = alpha * Rw[i + 1] + (1.0 - alpha) * Rw[i]
        Qw[L] = Rw[0]
        Qw[k + r - j - s] = Rw[p - j - s]
    for i in range(L + 1, k - s):
        Qw[i] = Rw[i - L]
    return UQ, Qw


def refine_knot_vector(knots: np.ndarray, Pw: np.ndarray, degree: int, X: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Insert all knots ``X`` at once (A5.4), for clamped knot vectors.

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (clamped).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    X : (r,) float ndarray
        Sorted knots inside the domain.

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U, Pw = _float_arrays(knots, Pw)
    X = np.sort(np.asarray(X, dtype=float))
    if X.size == 0:
        return U.copy(), Pw.copy()
    p = int(degree)
    n = Pw.shape[0] - 1
    m = n + p + 1
    r = X.size - 1
    a = int(find_spans(U, p, X[:1])[0])
    b = int(find_spans(U, p, X[-1:])[0]) + 1
    Qw = np.zeros((n + r + 2,) + Pw.shape[1:])
    Ub = np.zeros(m + r + 2)
    Qw[:a - p + 1] = Pw[:a - p + 1]
    Qw[b - 1 + r + 1:] = Pw[b - 1:]
    Ub[:a + 1] = U[:a + 1]
    Ub[b + p + r + 1:] = U[b + p:]
    i = b + p - 1
    k = b + p + r
    for j in range(r, -1, -1):
        while X[j] <= U[i] and i > a:
            Qw[k - p - 1] = Pw[i - p - 1]
            Ub[k] = U[i]
            k -= 1
            i -= 1
        Qw[k - p - 1] = Qw[k - p]
        for ell in range(1, p + 1):
            ind = k - p + ell
            alfa = Ub[k + ell] - X[j]
            if abs(alfa) == 0.0:
                Qw[ind - 1] = Qw[ind]
            else:
                alfa = alfa / (Ub[k + ell] - U[i - p + ell])
                Qw[ind - 1] = alfa * Qw[ind - 1] + (1.0 - alfa) * Qw[ind]
        Ub[k] = X[j]
        k -= 1
    return Ub, Qw


def insert_knot_periodic(knots: np.ndarray, Pw: np.ndarray, degree: int, u: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Insert ``u`` in [0, 1) once into a periodic spline (Boehm with cyclic
    indices; the periodic counterpart of A5.1).

    The copies ``u + k`` in the other periods are inserted implicitly, so the
    result is again periodic with ``n + 1`` control points.

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (periodic, n + 2p + 1 knots; Pw: the n distinct points).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    u : float

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U, Pw = _float_arrays(knots, Pw)
    p = int(degree)
    n = Pw.shape[0]
    u = float(u) % 1.0
    k = int(np.searchsorted(U, u, side="right")) - 1
    k = min(max(k, p), n + p - 1)
    Q = np.zeros((n + 1,) + Pw.shape[1:])
    js = np.arange(k - p + 1, k + 1)
    T = periodic_knot(U, p, n, js)
    Tp = periodic_knot(U, p, n, js + p)
    alpha = (u - T) / (Tp - T)
    alpha = alpha.reshape((-1,) + (1,) * (Pw.ndim - 1))
    Q[js % (n + 1)] = alpha * Pw[js % n] + (1.0 - alpha) * Pw[(js - 1) % n]
    rest = np.arange(k + 1, k + n - p + 2)
    Q[rest % (n + 1)] = Pw[(rest - 1) % n]
    B = np.concatenate([U[p:k + 1], [u], U[k + 1:n + p + 1]])
    return canonical_periodic(periodic_knot_vector(B, p), Q, p)


def refine_periodic(knots: np.ndarray, Pw: np.ndarray, degree: int, X: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Insert all knots ``X`` into a periodic spline at once: the Oslo algorithm
    (Cohen, Lyche & Riesenfeld 1980), the general form of A5.4, vectorised over
    the new control points.

    New control point j is the blossom of the curve at the new knots
    ``tau_{j+1} .. tau_{j+p}``, evaluated by a de Boor triangle on the old
    span mu with ``T_mu <= tau_j < T_{mu+1}`` (indices cyclic).

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (periodic; Pw: the n distinct points).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    X : (r,) float array_like
        Values in [0, 1), repeats allowed.

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U, Pw = _float_arrays(knots, Pw)
    p = int(degree)
    n = Pw.shape[0]
    X = np.sort(np.mod(np.asarray(X, dtype=float).ravel(), 1.0))
    if X.size == 0:
        return U.copy(), Pw.copy()
    old = U[p:n + p]                                   # one period, seam run first
    B = np.concatenate([np.sort(np.concatenate([old, X]), kind="stable"), [1.0]])
    Un, _ = canonical_periodic(periodic_knot_vector(B, p), np.zeros((B.size - 1, 1)), p)
    nn = B.size - 1
    j = np.arange(nn)
    # locate tau_j by its stored value in one period (exact, no "- 1" rounding)
    q, rem = np.divmod(j - p, nn)
    mu = np.searchsorted(old, Un[p + rem], side="right") - 1 + p + q * n
    shape = (nn,) + (1,) * (Pw.ndim - 1)
    d = [Pw[(mu - p + i) % n] for i in range(p + 1)]   # local de Boor points
    for r in range(1, p + 1):
        x = periodic_knot(Un, p, nn, j + r).reshape(shape)
        for i in range(p, r - 1, -1):
            lo = periodic_knot(U, p, n, mu - p + i).reshape(shape)
            hi = periodic_knot(U, p, n, mu + i + 1 - r).reshape(shape)
            a = (x - lo) / (hi - lo)
            d[i] = a * d[i] + (1.0 - a) * d[i - 1]
    return Un, d[p]


def rotate_periodic(knots: np.ndarray, Pw: np.ndarray, degree: int, shift: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Move the seam: the returned spline ``C'`` satisfies ``C'(u) = C(u + shift)``.

    Inserts a knot at ``shift`` first when there is none (exact).

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (periodic; Pw: the n distinct points).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    shift : float
        Parameter shift.

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    p = int(degree)
    s = float(shift) % 1.0
    U, Pw = _float_arrays(knots, Pw)
    if s < _KNOT_EPS or 1.0 - s < _KNOT_EPS:
        return U.copy(), Pw.copy()
    if knot_multiplicity(U[p:U.size - p], s) == 0:
        U, Pw = insert_knot_periodic(U, Pw, p, s)
    n = Pw.shape[0]
    cand = np.flatnonzero(np.abs(U - s) <= _KNOT_EPS)
    j0 = int(cand[cand >= p][0])
    B = periodic_knot(U, p, n, np.arange(j0, j0 + n + 1)) - periodic_knot(U, p, n, np.array([j0]))[0]
    B[0], B[-1] = 0.0, 1.0
    idx = (np.arange(n) + j0 - p) % n
    return canonical_periodic(periodic_knot_vector(B, p), Pw[idx], p)


def canonical_periodic(knots: np.ndarray, Pw: np.ndarray, degree: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Re-index a periodic spline so that the seam knot run starts at index p.

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (periodic; Pw: the n distinct points).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U = np.asarray(knots, dtype=float)
    p = int(degree)
    n = Pw.shape[0]
    if U[p - 1] < -_KNOT_EPS or p == 0:
        return U, Pw
    j0 = p
    while j0 > 0 and abs(U[j0 - 1]) <= _KNOT_EPS:
        j0 -= 1
    # T_{j0} = 0 is the first knot of the seam run; start the period there.
    B = periodic_knot(U, p, n, np.arange(j0, j0 + n + 1))
    B[0], B[-1] = 0.0, 1.0
    idx = (np.arange(n) + j0 - p) % n
    return periodic_knot_vector(B, p), Pw[idx]


def clamp_periodic(knots: np.ndarray, Pw: np.ndarray, degree: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Equivalent clamped spline on [0, 1] of a periodic one (A5.1 at 0 and 1).

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (periodic; Pw: the n distinct points).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.

    Returns
    -------
    U : float ndarray
        Clamped knots.
    Qw : float ndarray
        Homogeneous control points; the first and last are the curve point at the seam.
    """
    p = int(degree)
    U, Pw = _float_arrays(knots, Pw)
    n = Pw.shape[0]
    W = Pw[np.arange(n + p) % n]
    s0 = knot_multiplicity(U, 0.0)
    U2, W2 = insert_knot(U, W, p, 0.0, p - s0)
    s1 = knot_multiplicity(U2, 1.0)
    U2, W2 = insert_knot(U2, W2, p, 1.0, p - s1)
    j0 = int(np.searchsorted(U2, _KNOT_EPS, side="left")) - p - 1
    j1 = int(np.searchsorted(U2, 1.0 - _KNOT_EPS, side="left")) - 1
    Uc = U2[j0:j1 + p + 2].copy()
    Uc[:p + 1] = 0.0
    Uc[-p - 1:] = 1.0
    return Uc, W2[j0:j1 + 1].copy()


def _bezier_elevation_coefficients(p: int, t: int) -> np.ndarray:
    """``bezalfs[i, j]`` of A5.9: elevated Bezier point i = sum_j bezalfs[i, j] P_j."""
    ph = p + t
    a = np.zeros((ph + 1, p + 1))
    for i in range(ph + 1):
        for j in range(max(0, i - t), min(p, i) + 1):
            a[i, j] = comb(p, j) * comb(t, i - j) / comb(ph, i)
    return a


def _a59_insert(bpts: np.ndarray, nextbpts: np.ndarray, alfs: np.ndarray, U: np.ndarray, a: int,
                ua: float, ub: float, p: int, mul: int, r: int) -> None:
    """A5.9's "insert knot u = U[b] r times" into the Bezier segment ``bpts`` (in place; the
    leftmost control points of the next segment go to ``nextbpts``)."""
    numer = ub - ua
    for k in range(p, mul, -1):
        alfs[k - mul - 1] = numer / (U[a + k] - ua)
    for j in range(1, r + 1):
        save = r - j
        s = mul + j
        for k in range(p, s - 1, -1):
            bpts[k] = alfs[k - s] * bpts[k] + (1.0 - alfs[k - s]) * bpts[k - 1]
        nextbpts[save] = bpts[p]


def _a59_remove(Qw: np.ndarray, ebpts: np.ndarray, Uh: np.ndarray, ua: float, ub: float, kind: int,
                cind: int, lbz: int, ph: int, oldr: int) -> None:
    """A5.9's "remove knot u = U[a] oldr times" between the elevated control points ``Qw``
    written so far and the elevated segment ``ebpts`` (both in place)."""
    first = kind - 2
    last = kind
    den = ub - ua
    bet = (ub - Uh[kind - 1]) / den
    for tr in range(1, oldr):
        i = first
        j = last
        kj = j - kind + 1
        while j - i > tr:
            if i < cind:
                alf = (ub - Uh[i]) / (ua - Uh[i])
                Qw[i] = alf * Qw[i] + (1.0 - alf) * Qw[i - 1]
            if j >= lbz:
                if j - tr <= kind - ph + oldr:
                    gam = (ub - Uh[j - tr]) / den
                    ebpts[kj] = gam * ebpts[kj] + (1.0 - gam) * ebpts[kj + 1]
                else:
                    ebpts[kj] = bet * ebpts[kj] + (1.0 - bet) * ebpts[kj + 1]
            i += 1
            j -= 1
            kj -= 1
        first -= 1
        last += 1


def elevate_degree_clamped(knots: np.ndarray, Pw: np.ndarray, degree: int, times: int
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Raise the degree of a clamped spline by ``times`` (A5.9, DegreeElevateCurve).

    Every distinct interior knot gains multiplicity ``times`` (continuity is
    kept); exact.

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (clamped).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    times : int
        Degree increase, >= 0.

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U, Pw = _float_arrays(knots, Pw)
    p = int(degree)
    t = int(times)
    if t <= 0:
        return U.copy(), Pw.copy()
    n = Pw.shape[0] - 1
    m = n + p + 1
    ph = p + t
    bezalfs = _bezier_elevation_coefficients(p, t)
    shape = Pw.shape[1:]
    # Upper bounds on the output sizes.
    n_int = len(distinct_knots(U[p + 1:m - p])[0])
    Qw = np.zeros((n + 1 + t * (n_int + 1) + 1,) + shape)
    Uh = np.zeros(Qw.shape[0] + ph + 1)
    bpts = np.zeros((p + 1,) + shape)
    ebpts = np.zeros((ph + 1,) + shape)
    nextbpts = np.zeros((max(p - 1, 0) + 1,) + shape)
    alfs = np.zeros(max(p - 1, 0) + 1)
    mh = ph
    kind = ph + 1
    r = -1
    a = p
    b = p + 1
    cind = 1
    ua = U[0]
    Qw[0] = Pw[0]
    Uh[:ph + 1] = ua
    bpts[:] = Pw[:p + 1]
    while b < m:
        i = b
        while b < m and U[b] == U[b + 1]:
            b += 1
        mul = b - i + 1
        mh = mh + mul + t
        ub = U[b]
        oldr = r
        r = p - mul
        lbz = (oldr + 2) // 2 if oldr > 0 else 1
        rbz = ph - (r + 1) // 2 if r > 0 else ph
        if r > 0:
            _a59_insert(bpts, nextbpts, alfs, U, a, ua, ub, p, mul, r)
        for i in range(lbz, ph + 1):
            ebpts[i] = np.tensordot(bezalfs[i], bpts, axes=(0, 0))
        if oldr > 1:
            _a59_remove(Qw, ebpts, Uh, ua, ub, kind, cind, lbz, ph, oldr)
        if a != p:
            for _ in range(ph - oldr):
                Uh[kind] = ua
                kind += 1
        for j in range(lbz, rbz + 1):
            Qw[cind] = ebpts[j]
            cind += 1
        if b < m:
            bpts[:r] = nextbpts[:r]
            for j in range(r, p + 1):
                bpts[j] = Pw[b - p + j]
            a = b
            b += 1
            ua = ub
        else:
            Uh[kind:kind + ph + 1] = ub
    nh = mh - ph - 1
    return Uh[:nh + ph + 2].copy(), Qw[:nh + 1].copy()


def elevate_degree_periodic(knots: np.ndarray, Pw: np.ndarray, degree: int, times: int
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Raise the degree of a periodic spline by ``times``, exactly.

    The elevated spline space (every distinct knot's multiplicity + ``times``)
    contains the curve (in homogeneous coordinates each piece is a polynomial
    of degree p <= p + times), so its control points are the unique solution
    of a collocation at ``p + times + 1`` parameters per non-empty span.

    Parameters
    ----------
    knots : (n + p + 1,) float ndarray
        The knot vector (periodic; Pw: the n distinct points).
    Pw : (n, ...) float ndarray
        Homogeneous control points ``(w P, w)`` along axis 0 (any trailing shape,
        e.g. (n, d + 1) for a curve, (n, nv, d + 1) for a surface's u rows).
    degree : int
        The degree p.
    times : int
        Degree increase, >= 0.

    Returns
    -------
    U : float ndarray
        The new knot vector.
    Qw : float ndarray
        The new homogeneous control points (trailing shape of ``Pw``).
    """
    U, Pw = _float_arrays(knots, Pw)
    p = int(degree)
    t = int(times)
    if t <= 0:
        return U.copy(), Pw.copy()
    n = Pw.shape[0]
    ph = p + t
    vals, mult = distinct_knots(U[p:n + p])  # one period [0, 1), seam first
    B = np.concatenate([np.repeat(vals, mult + t), [1.0]])
    Uh = periodic_knot_vector(B, ph)
    nh = B.size - 1
    edges = np.concatenate([vals, [1.0]])
    frac = (np.arange(ph + 1) + 0.5) / (ph + 1)
    us = (edges[:-1, None] + np.diff(edges)[:, None] * frac[None, :]).ravel()
    A = basis_matrix(U, p, us, n_periodic=n)
    Ah = basis_matrix(Uh, ph, us, n_periodic=nh)
    rhs = (A @ Pw.reshape(n, -1))
    Qw, *_ = np.linalg.lstsq(Ah, rhs, rcond=None)
    return Uh, Qw.reshape((nh,) + Pw.shape[1:])
