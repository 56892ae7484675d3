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

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs import _validate as V
from cardionurbs.nurbs.basis import basis_function_derivatives, find_spans
from cardionurbs.nurbs.knots import canonical_periodic, clamp_periodic
from cardionurbs.nurbs.serialize import curve_fields, curve_to_dict

__all__ = ["NurbsCurve", "rational_derivatives"]


def rational_derivatives(Aw: np.ndarray) -> np.ndarray:
    """Derivatives of a rational curve from those of its homogeneous form (A4.2).

    ``Aw`` has shape ``(k, order + 1, d + 1)`` (last column the weight
    function); returns ``(k, order + 1, d)`` Euclidean derivatives.
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
    """A NURBS curve; ``closed=True`` for the periodic form (see module doc).

    Parameters
    ----------
    degree : int >= 1
    knots : (n + p + 1,) clamped, or (n + 2p + 1,) periodic when ``closed``
    control_points : (n, d) Euclidean control points (distinct ones if closed)
    weights : (n,) positive weights, default ones
    closed : periodic curve
    """

    __slots__ = ("degree", "knots", "control_points", "weights", "closed", "_hom")

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
        self._hom: np.ndarray | None = None

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

    @property
    def homogeneous_control_points(self) -> np.ndarray:
        """``(n_full, d + 1)`` homogeneous points ``(w P, w)``, wrapped when closed."""
        if self._hom is None:
            Pw = np.column_stack([self.control_points * self.weights[:, None], self.weights])
            if self.closed:
                n = Pw.shape[0]
                Pw = Pw[np.arange(n + self.degree) % n]
            Pw.flags.writeable = False
            self._hom = Pw
        return self._hom

    def __repr__(self) -> str:
        kind = "closed" if self.closed else "open"
        return (f"NurbsCurve(degree={self.degree}, n_control={self.n_control}, "
                f"dimension={self.dimension}, {kind}, rational={self.is_rational})")

    # -------------------------------------------------------------- evaluation
    def _params(self, u: Any, name: str = "u") -> np.ndarray:
        lo, hi = self.domain
        return V.parameters(u, name, lo, hi, self.closed)

    def derivatives(self, u: Any, order: int = 1) -> np.ndarray:
        """``C`` and its derivatives up to ``order``: shape ``(k, order + 1, d)``
        (A3.2 on the homogeneous curve, then A4.2)."""
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
        """Points ``C(u)`` for parameters ``u`` (k,) -> (k, d)."""
        u = self._params(u)
        p = self.degree
        spans = find_spans(self.knots, p, u)
        N = basis_function_derivatives(spans, u, p, self.knots, 0)[:, 0, :]
        idx = spans[:, None] - p + np.arange(p + 1)[None, :]
        Cw = np.einsum("kj,kjc->kc", N, self.homogeneous_control_points[idx])
        return Cw[:, :-1] / Cw[:, -1:]

    def derivative(self, u: Any, order: int = 1) -> np.ndarray:
        """``d^order C / du^order`` at ``u`` (k,) -> (k, d)."""
        return self.derivatives(u, order)[:, order]

    # ------------------------------------------------------------ conversions
    def reversed(self) -> "NurbsCurve":
        """The same point set traversed backwards: ``C'(u) = C(a + b - u)``."""
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
        """
        if not self.closed:
            return self
        Pw = np.column_stack([self.control_points * self.weights[:, None], self.weights])
        Uc, Qw = clamp_periodic(self.knots, Pw, self.degree)
        return NurbsCurve(self.degree, Uc, Qw[:, :-1] / Qw[:, -1:], Qw[:, -1])

    def to_dict(self) -> dict[str, Any]:
        """Lossless JSON-safe dict (floats round-trip exactly through json)."""
        return curve_to_dict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "NurbsCurve":
        """Inverse of :meth:`to_dict`."""
        args, kwargs = curve_fields(data)
        return cls(*args, **kwargs)
