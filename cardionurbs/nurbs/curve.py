"""Rational B-spline (NURBS) curves, open (clamped) or closed (periodic).

A curve of degree p with control points ``P_i`` and weights ``w_i > 0`` is

    C(u) = sum_i N_{i,p}(u) w_i P_i / sum_i N_{i,p}(u) w_i          (paper eq. 5)

evaluated in homogeneous coordinates ``Pw_i = (w_i P_i, w_i)`` (NURBS Book
A4.1) with the vectorised basis of :mod:`cardionurbs.nurbs.basis`;
derivatives follow A4.2.

Open curves use a clamped knot vector (``n + p + 1`` knots, end knots repeated
p + 1 times) and interpolate their end control points.  Closed curves use the
periodic representation described in :mod:`cardionurbs.nurbs.knots`:
``control_points`` are the ``n`` distinct points, ``knots`` the full unclamped
vector of ``n + 2p + 1`` knots, u in [0, 1] covers the loop once and the curve
is C^(p-1) across the seam (for simple knots).  :meth:`NurbsCurve.to_clamped`
gives the equivalent clamped open curve.
"""

from __future__ import annotations

from math import comb
from typing import Any

from functools import cached_property

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs import _validate as V
from cardionurbs.nurbs.basis import basis_function_derivatives, find_spans
from cardionurbs.nurbs.knots import canonical_periodic, clamp_periodic
from cardionurbs.nurbs.serialize import curve_fields, curve_to_dict

__all__ = ["NurbsCurve", "rational_derivatives"]


def rational_derivatives(Aw: np.ndarray) -> np.ndarray:
    """Derivatives of a rational curve from those of its homogeneous form (A4.2).

    Parameters
    ----------
    Aw : (k, order + 1, d + 1) float ndarray
        Derivatives 0 .. order of the homogeneous curve ``(w C, w)`` at k
        parameters (last column: the weight function).

    Returns
    -------
    (k, order + 1, d) float ndarray
        The Euclidean derivatives ``d^r C / du^r`` (control points' units per unit parameter^r).
    """
    A = Aw[..., :-1]
    w = Aw[..., -1]
    order = Aw.shape[1] - 1
    C = np.empty_like(A)
    for k in range(order + 1):
        v = A[:, k].copy()
        for i in range(1, k + 1):
            v -= comb(k, i) * w[:, i, None] * C[:, k - i]
        C[:, k] = v / w[:, 0, None]
    return C


class NurbsCurve:
    """A NURBS curve (paper eq. 5); ``closed=True`` for the periodic form (see module doc).

    The arrays are validated and stored read-only; every evaluation is vectorised
    over parameters.

    Parameters
    ----------
    degree : int
        The degree p >= 1.
    knots : (n + p + 1,) float array_like
        Clamped knot vector (end knots repeated p + 1 times); when ``closed``,
        the (n + 2p + 1,) periodic vector with domain [U[p], U[n + p]] = [0, 1]
        and U[i + n] = U[i] + 1.
    control_points : (n, d) float array_like
        Euclidean control points, n >= p + 1 (the n distinct ones if closed);
        units of the caller (e.g. mm).
    weights : (n,) float array_like, optional
        Positive weights; default ones (a polynomial B-spline).
    closed : bool, default False
        The periodic (closed, C^(p-1) across the seam) form.

    Raises
    ------
    NurbsInputError
        A non-integer degree, too few control points, a bad knot vector, non-finite
        values or non-positive weights (the message names the argument).

    Examples
    --------
    A quarter of the unit circle, exactly (rational quadratic):

    >>> import numpy as np
    >>> from cardionurbs.nurbs import NurbsCurve
    >>> c = NurbsCurve(2, [0, 0, 0, 1, 1, 1], [[1, 0], [1, 1], [0, 1]],
    ...                weights=[1, np.sqrt(0.5), 1])
    >>> bool(np.allclose(np.linalg.norm(c.evaluate(np.linspace(0, 1, 9)), axis=1), 1.0))
    True
    >>> c.domain, c.n_control, c.is_rational
    ((0.0, 1.0), 3, True)
    """

    def __init__(self, degree: int, knots: Any, control_points: Any, weights: Any = None,
                 closed: bool = False) -> None:
        p = V.degree_value(degree)
        P = V.finite_array(control_points, "control_points", ndim=2)
        n = P.shape[0]
        if n < p + 1:
            raise NurbsInputError(f"control_points: degree {p} needs at least {p + 1} control "
                                  f"points, got {n}")
        w = V.weight_vector(weights, "weights", (n,))
        if closed:
            U = V.periodic_knot_vector(knots, "knots", p, n, "a closed curve")
            U, Pw = canonical_periodic(U, np.column_stack([P, w]), p)  # re-indexing only
            P, w = Pw[:, :-1].copy(), Pw[:, -1].copy()
        else:
            U = V.knot_vector(knots, "knots", p, n, clamped=True)
        for arr in (U, P, w):
            arr.flags.writeable = False
        self.degree = p
        self.knots = U
        self.control_points = P
        self.weights = w
        self.closed = bool(closed)

    # ------------------------------------------------------------------ basics
    @property
    def dimension(self) -> int:
        """Number of coordinates d of the control points."""
        return int(self.control_points.shape[1])

    @property
    def n_control(self) -> int:
        """Number of (distinct) control points."""
        return int(self.control_points.shape[0])

    @property
    def is_rational(self) -> bool:
        """True when the weights are not all equal."""
        return bool(np.ptp(self.weights) > 1e-12 * np.max(self.weights))

    @property
    def domain(self) -> tuple[float, float]:
        """Parameter domain ``(U[p], U[n_full])``; (0, 1) for closed curves."""
        n_full = self.knots.size - self.degree - 1
        return float(self.knots[self.degree]), float(self.knots[n_full])

    @cached_property
    def homogeneous_control_points(self) -> np.ndarray:
        """``(n_full, d + 1)`` homogeneous points ``(w P, w)``, wrapped when closed (read-only)."""
        Pw = np.column_stack([self.control_points * self.weights[:, None], self.weights])
        if self.closed:
            n = Pw.shape[0]
            Pw = Pw[np.arange(n + self.degree) % n]
        Pw.flags.writeable = False
        return Pw

    def __repr__(self) -> str:
        kind = "closed" if self.closed else "open"
        return (f"NurbsCurve(degree={self.degree}, n_control={self.n_control}, "
                f"dimension={self.dimension}, {kind}, rational={self.is_rational})")

    # -------------------------------------------------------------- evaluation
    def _params(self, u: Any, name: str = "u") -> np.ndarray:
        lo, hi = self.domain
        return V.parameters(u, name, lo, hi, self.closed)

    def derivatives(self, u: Any, order: int = 1) -> np.ndarray:
        """``C`` and its derivatives up to ``order`` (A3.2 on the homogeneous curve, then A4.2).

        Parameters
        ----------
        u : float or (k,) float array_like
            Parameters in the domain (wrapped into it when closed).
        order : int, default 1
            Highest derivative order, >= 0.

        Returns
        -------
        (k, order + 1, d) float ndarray
            ``D[:, r] = d^r C / du^r`` (control points' units per unit parameter^r).
        """
        order = V.degree_value(order, "order", minimum=0)
        u = self._params(u)
        p = self.degree
        spans = find_spans(self.knots, p, u)
        D = basis_function_derivatives(spans, u, p, self.knots, order)
        idx = spans[:, None] - p + np.arange(p + 1)[None, :]
        Pw = self.homogeneous_control_points[idx]          # (k, p+1, d+1)
        Aw = np.einsum("krj,kjc->krc", D, Pw)
        return rational_derivatives(Aw)

    def evaluate(self, u: Any) -> np.ndarray:
        """Points ``C(u)``.

        Parameters
        ----------
        u : float or (k,) float array_like
            Parameters in the domain (wrapped into it when closed).

        Returns
        -------
        (k, d) float ndarray
            The curve points (control points' units).
        """
        u = self._params(u)
        p = self.degree
        spans = find_spans(self.knots, p, u)
        N = basis_function_derivatives(spans, u, p, self.knots, 0)[:, 0, :]
        idx = spans[:, None] - p + np.arange(p + 1)[None, :]
        Cw = np.einsum("kj,kjc->kc", N, self.homogeneous_control_points[idx])
        return Cw[:, :-1] / Cw[:, -1:]

    def derivative(self, u: Any, order: int = 1) -> np.ndarray:
        """The ``order``-th derivative ``d^order C / du^order``.

        Parameters
        ----------
        u : float or (k,) float array_like
            Parameters in the domain.
        order : int, default 1
            The derivative order, >= 0.

        Returns
        -------
        (k, d) float ndarray
            Control points' units per unit parameter^order.
        """
        return self.derivatives(u, order)[:, order]

    # ------------------------------------------------------------ conversions
    def reversed(self) -> "NurbsCurve":
        """The same point set traversed backwards: ``C'(u) = C(a + b - u)`` on the domain [a, b].

        Returns
        -------
        NurbsCurve
            Same degree, form and point set.
        """
        U = self.knots
        if self.closed:
            p, n = self.degree, self.n_control
            idx = (n + p - 1 - np.arange(n)) % n
            return NurbsCurve(p, 1.0 - U[::-1], self.control_points[idx], self.weights[idx],
                              closed=True)
        lo, hi = self.domain
        return NurbsCurve(self.degree, (lo + hi) - U[::-1], self.control_points[::-1],
                          self.weights[::-1])

    def to_clamped(self) -> "NurbsCurve":
        """An equivalent open clamped curve on [0, 1] (itself if already open).

        For a closed curve the seam knot is inserted to multiplicity p at both
        ends (A5.1); the first and last control points coincide.

        Returns
        -------
        NurbsCurve
            Open; the same points at the same parameters.
        """
        if not self.closed:
            return self
        Pw = np.column_stack([self.control_points * self.weights[:, None], self.weights])
        Uc, Qw = clamp_periodic(self.knots, Pw, self.degree)
        return NurbsCurve(self.degree, Uc, Qw[:, :-1] / Qw[:, -1:], Qw[:, -1])

    def to_dict(self) -> dict[str, Any]:
        """Lossless JSON-safe dict (floats round-trip exactly through json).

        Returns
        -------
        dict
            ``degree``, ``knots``, ``control_points``, ``weights``, ``closed`` (lists of floats).
        """
        return curve_to_dict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "NurbsCurve":
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        data : dict
            As :meth:`to_dict` writes it.

        Returns
        -------
        NurbsCurve
        """
        args, kwargs = curve_fields(data)
        return cls(*args, **kwargs)
