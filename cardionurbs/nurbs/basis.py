"""B-spline basis functions, vectorised over many parameters at once.

The functions map one-to-one to The NURBS Book (Piegl & Tiller, 2nd ed.):

* :func:`find_spans`  -- A2.1 (FindSpan) for an array of parameters;
* :func:`basis_functions` -- A2.2 (BasisFuns), the p+1 non-zero functions;
* :func:`basis_function_derivatives` -- A2.3 (DersBasisFuns);
* :func:`basis_matrix` -- the dense collocation ("design") matrix built from
  A2.3, optionally folded for periodic (closed) splines.

Every routine loops only over the degree (a handful of iterations); the work
per parameter is done by numpy on whole arrays.  A knot vector ``U`` of a
spline with ``n`` control points has ``n + p + 1`` entries and its parameter
domain is ``[U[p], U[n]]``.
"""

from __future__ import annotations

import numpy as np

from cardionurbs.errors import NurbsInputError

__all__ = ["find_spans", "basis_functions", "basis_function_derivatives", "basis_matrix"]


def find_spans(knots: np.ndarray, degree: int, u: np.ndarray) -> np.ndarray:
    """Knot span index ``k`` with ``U[k] <= u < U[k+1]`` for every ``u`` (A2.1).

    Parameters outside the domain ``[U[p], U[n]]`` are treated as the first or
    last non-empty span (so that a parameter a rounding error outside the
    domain still evaluates the end polynomial piece).  The returned spans are
    always non-degenerate (``U[k] < U[k+1]``).

    Parameters
    ----------
    knots : (m,) float ndarray, or (k, m)
        The knot vector, non-decreasing; or one knot vector per parameter
        ``u[r]``, all of length m -- pad a shorter vector by repeating its last
        knot (a higher end multiplicity only adds empty spans; the spans
        returned stay those of the unpadded vector).
    degree : int
        The degree p >= 1.
    u : (k,) float ndarray
        Parameters (dimensionless, in the knots' units).

    Returns
    -------
    (k,) int ndarray
        The span index of each parameter, in ``[p, m - p - 2]``.
    """
    U = np.asarray(knots, dtype=float)
    p = int(degree)
    u = np.asarray(u, dtype=float)
    if U.ndim == 2:
        n = U.shape[1] - p - 1
        first = (U <= U[:, p:p + 1]).sum(axis=1)
        last = (U < U[:, n:n + 1]).sum(axis=1)
        return np.clip((U <= u[:, None]).sum(axis=1), first, last) - 1
    n = len(U) - p - 1
    first = int(np.searchsorted(U, U[p], side="right")) - 1
    last = int(np.searchsorted(U, U[n], side="left")) - 1
    spans = np.searchsorted(U, u, side="right") - 1
    return np.clip(spans, first, last)


def basis_functions(spans: np.ndarray, u: np.ndarray, degree: int, knots: np.ndarray) -> np.ndarray:
    """Non-zero basis functions ``N[k, j] = N_{span_k - p + j, p}(u_k)`` (A2.2).

    Parameters
    ----------
    spans : (k,) int ndarray
        Knot spans of the parameters (:func:`find_spans`).
    u : (k,) float ndarray
        Parameters.
    degree : int
        The degree p.
    knots : (m,) float ndarray
        The knot vector.

    Returns
    -------
    (k, p + 1) float ndarray
        The p + 1 basis functions that are non-zero at each parameter (they sum to 1).
    """
    return basis_function_derivatives(spans, u, degree, knots, 0)[:, 0, :]


def basis_function_derivatives(spans: np.ndarray, u: np.ndarray, degree: int,
                               knots: np.ndarray, n_derivatives: int) -> np.ndarray:
    """Basis functions and their derivatives up to ``n_derivatives`` (A2.3).

    Derivatives above the degree are zero.  Vectorised over the ``k`` parameters.

    Parameters
    ----------
    spans : (k,) int ndarray
        Knot spans of the parameters (:func:`find_spans`); ``spans[r]`` indexes
        row ``r`` of ``knots`` when it is (k, m).
    u : (k,) float ndarray
        Parameters.
    degree : int
        The degree p.
    knots : (m,) or (k, m) float ndarray
        One knot vector shared by all parameters, or row ``r`` the knot vector
        of ``u[r]`` (many splines evaluated at once, e.g.
        :class:`~cardionurbs.nurbs.batch.SurfaceBatch`; shorter vectors padded as
        for :func:`find_spans`).
    n_derivatives : int
        Highest derivative order, >= 0.

    Returns
    -------
    (k, n_derivatives + 1, p + 1) float ndarray
        ``D[:, r, j] = d^r N_{span - p + j, p} / du^r`` (per unit parameter^r).
    """
    U = np.asarray(knots, dtype=float)
    p = int(degree)
    u = np.atleast_1d(np.asarray(u, dtype=float))
    spans = np.atleast_1d(np.asarray(spans))
    k = u.shape[0]
    if U.ndim == 2:
        if U.shape[0] != k or spans.shape[0] != k:
            raise NurbsInputError(f"knots: per-parameter knot vectors need {k} rows, got "
                                  f"{U.shape[0]} (and {spans.shape[0]} spans)")
        rows = np.arange(k)[:, None]

        def knot(i: np.ndarray) -> np.ndarray:
            return U[rows, i]
    else:
        def knot(i: np.ndarray) -> np.ndarray:
            return U[i]
    nd = int(n_derivatives)
    ndu = np.zeros((k, p + 1, p + 1))
    ndu[:, 0, 0] = 1.0
    jj = np.arange(p + 1)
    left = u[:, None] - knot(spans[:, None] + 1 - jj)     # left[:, j] = u - U[span + 1 - j]
    right = knot(spans[:, None] + jj) - u[:, None]        # right[:, j] = U[span + j] - u
    for j in range(1, p + 1):
        saved = np.zeros(k)
        for r in range(j):
            ndu[:, j, r] = right[:, r + 1] + left[:, j - r]
            temp = ndu[:, r, j - 1] / ndu[:, j, r]
            ndu[:, r, j] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        ndu[:, j, j] = saved
    ders = np.zeros((k, nd + 1, p + 1))
    ders[:, 0, :] = ndu[:, :, p]
    if nd == 0:
        return ders
    # A2.3's loop over r (which function) runs for all r at once: a[s][:, r, j]
    # is the book's a[s][j] of function r, the same operations in the same
    # order.  The r of each term form a range: j = 0 needs r >= kk, the inner
    # j (1 .. kk-1) kk - j <= r <= p - j, j = kk needs r <= p - kk.
    a = np.zeros((2, k, p + 1, p + 1))
    a[0, :, :, 0] = 1.0
    s1, s2 = 0, 1
    for kk in range(1, min(nd, p) + 1):
        pk = p - kk
        a1, a2 = a[s1], a[s2]
        d = np.zeros((k, p + 1))
        a2[:, kk:, 0] = a1[:, kk:, 0] / ndu[:, pk + 1, :pk + 1]           # r = kk .. p
        d[:, kk:] = a2[:, kk:, 0] * ndu[:, :pk + 1, pk]
        for j in range(1, kk):                                            # r = kk-j .. p-j
            rs = slice(kk - j, p - j + 1)
            a2[:, rs, j] = (a1[:, rs, j] - a1[:, rs, j - 1]) / ndu[:, pk + 1, :pk + 1]
            d[:, rs] += a2[:, rs, j] * ndu[:, :pk + 1, pk]
        a2[:, :pk + 1, kk] = -a1[:, :pk + 1, kk - 1] / ndu[:, pk + 1, :pk + 1]  # r = 0 .. pk
        d[:, :pk + 1] += a2[:, :pk + 1, kk] * ndu[:, :pk + 1, pk]
        ders[:, kk, :] = d
        s1, s2 = s2, s1
    factor = float(p)
    for kk in range(1, min(nd, p) + 1):
        ders[:, kk, :] *= factor
        factor *= p - kk
    return ders


def basis_matrix(knots: np.ndarray, degree: int, u: np.ndarray, derivative: int = 0,
                 n_periodic: int | None = None) -> np.ndarray:
    """Dense collocation matrix ``B[k, i] = d^r N_{i,p}(u_k) / du^r``.

    Parameters
    ----------
    knots : (m,) float ndarray
        The knot vector (m = n + p + 1; periodic: n + 2p + 1).
    degree : int
        The degree p.
    u : (k,) float ndarray
        Parameters.
    derivative : int, default 0
        The derivative order r.
    n_periodic : int, optional
        For a periodic spline, the number n of distinct control points: the
        ``n + p`` wrapped basis functions are folded so that column ``i``
        multiplies the control point ``P_i`` (``P_{n+i} = P_i``).

    Returns
    -------
    (k, n_ctrl) float ndarray
        One row per parameter, one column per (distinct) control point.
    """
    U = np.asarray(knots, dtype=float)
    p = int(degree)
    u = np.atleast_1d(np.asarray(u, dtype=float))
    n_full = len(U) - p - 1
    spans = find_spans(U, p, u)
    D = basis_function_derivatives(spans, u, p, U, derivative)[:, derivative, :]
    cols = spans[:, None] - p + np.arange(p + 1)[None, :]
    rows = np.broadcast_to(np.arange(len(u))[:, None], cols.shape)
    if n_periodic is not None:
        cols = cols % int(n_periodic)
        n_full = int(n_periodic)
    B = np.zeros((len(u), n_full))
    B[rows, cols] = D   # the p+1 columns of a row are distinct (n >= p + 1)
    return B
