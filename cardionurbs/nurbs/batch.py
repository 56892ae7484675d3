"""Many NURBS curves or surfaces evaluated together, one (spline, parameter) per row.

Newton iterations over many splines at once (tag-surface triple
intersections, tag-line crossings) need, per iteration, the point and first
derivatives of spline ``id[r]`` at parameter ``u[r]`` for thousands of rows
``r``.  Calling :meth:`NurbsSurface.derivatives` once per spline costs a
Python round trip per spline; here the splines' knot vectors and homogeneous
control nets are padded into one array per degree (knot vectors by
repeating their last knot, nets with zeros), and one call evaluates every row with a few
array operations:

* spans: :func:`~cardionurbs.nurbs.basis.find_spans` (A2.1) on per-row knot
  vectors;
* basis functions and first derivatives:
  :func:`~cardionurbs.nurbs.basis.basis_function_derivatives` (A2.2/A2.3) on
  per-row knot vectors;
* homogeneous point and first derivatives by the tensor product (A3.6 /
  A4.3), Euclidean ones by :func:`~cardionurbs.nurbs.curve.rational_derivatives`
  (A4.2) and :func:`~cardionurbs.nurbs.surface.rational_surface_derivatives`
  (A4.4) -- the routines behind ``NurbsCurve.derivatives`` and
  ``NurbsSurface.derivatives``.

Only open (clamped) splines, all of one dimension d; units are those of the
control points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.basis import basis_function_derivatives, find_spans
from cardionurbs.nurbs.curve import rational_derivatives
from cardionurbs.nurbs.surface import rational_surface_derivatives

__all__ = ["SplineData", "CurveBatch", "SurfaceBatch"]


@dataclass(frozen=True)
class SplineData:
    """The arrays of an open NURBS curve (what :class:`CurveBatch` reads),
    without the validation of :class:`~cardionurbs.nurbs.NurbsCurve`.

    Parameters
    ----------
    degree : int
        The degree p >= 1.
    knots : (n + p + 1,) float ndarray
        Clamped knot vector.
    control_points : (n, d) float ndarray
        Euclidean control points (units of the caller, e.g. mm).
    weights : (n,) float ndarray
        Positive weights.
    """

    degree: int
    knots: np.ndarray
    control_points: np.ndarray
    weights: np.ndarray


class CurveBatch:
    """Many open NURBS curves (:class:`~cardionurbs.nurbs.NurbsCurve` or
    :class:`SplineData`) evaluated together, one (curve, u) per row (A4.2, k = 1).

    Parameters
    ----------
    curves : sequence of NurbsCurve or SplineData
        Open (clamped) curves, all of one dimension d.

    Raises
    ------
    NurbsInputError
        A closed curve.
    """

    def __init__(self, curves: Sequence[Any]) -> None:
        self.curves = list(curves)
        if any(getattr(c, "closed", False) for c in self.curves):
            raise NurbsInputError("curves: CurveBatch handles open curves only")
        self.dimension = int(np.shape(self.curves[0].control_points)[-1]) if self.curves else 3
        self.deg = np.array([c.degree for c in self.curves], dtype=int)
        self.pos = np.zeros(len(self.curves), int)
        self.by_degree: dict[int, dict] = {}
        for p in sorted(set(self.deg.tolist())):
            ids = np.flatnonzero(self.deg == p)
            n = np.array([len(self.curves[i].control_points) for i in ids])
            K = np.empty((len(ids), n.max() + p + 1))
            Pw = np.zeros((len(ids), n.max(), self.dimension + 1))
            for g, i in enumerate(ids):
                c = self.curves[i]
                K[g] = c.knots[-1]
                K[g, :len(c.knots)] = c.knots
                w = np.asarray(c.weights, float)[:, None]
                Pw[g, :n[g]] = np.column_stack([c.control_points * w, w])
                self.pos[i] = g
            self.by_degree[p] = {"K": K, "Pw": Pw}

    def derivatives(self, cid: Any, u: Any) -> tuple[np.ndarray, np.ndarray]:
        """C and C' of curve ``cid[r]`` at ``u[r]``, for every row r.

        Parameters outside a curve's domain evaluate its end polynomial piece.

        Parameters
        ----------
        cid : (k,) int array_like
            Index into ``curves`` per row.
        u : (k,) float array_like
            Parameter per row.

        Returns
        -------
        C, dC : (k, d) float ndarray
            Points (control points' units) and first derivatives (units per unit parameter).
        """
        cid = np.asarray(cid, int)
        u = np.asarray(u, float)
        d = self.dimension
        C = np.empty((len(cid), d))
        dC = np.empty_like(C)
        for p, grp in self.by_degree.items():
            rows = np.flatnonzero(self.deg[cid] == p)
            if len(rows) == 0:
                continue
            g = self.pos[cid[rows]]
            K = grp["K"][g]
            sp = find_spans(K, p, u[rows])
            D = basis_function_derivatives(sp, u[rows], p, K, 1)          # (k, 2, p+1)
            idx = sp[:, None] - p + np.arange(p + 1)
            Aw = D @ grp["Pw"][g[:, None], idx]                           # (k, 2, d+1)
            Cd = rational_derivatives(Aw)
            C[rows], dC[rows] = Cd[:, 0], Cd[:, 1]
        return C, dC


class SurfaceBatch:
    """Many open NURBS surfaces evaluated together, one (surface, u, v) per row.

    Knot vectors and homogeneous control nets are padded per (degree_u,
    degree_v) group, so one call costs a few array operations whatever the
    number of surfaces (A3.6/A4.4 with first derivatives, vectorised).

    Parameters
    ----------
    surfaces : sequence of NurbsSurface
        Surfaces open in u (``closed_u`` False), all of one dimension d.

    Raises
    ------
    NurbsInputError
        A surface closed in u.
    """

    def __init__(self, surfaces: Sequence[Any]) -> None:
        self.surfaces = list(surfaces)
        if any(getattr(s, "closed_u", False) for s in self.surfaces):
            raise NurbsInputError("surfaces: SurfaceBatch handles open surfaces only")
        self.dimension = int(self.surfaces[0].control_points.shape[-1]) if self.surfaces else 3
        keys = sorted({(s.degree_u, s.degree_v) for s in self.surfaces})
        self.keys = keys
        self.group_of = np.array([keys.index((s.degree_u, s.degree_v)) for s in self.surfaces],
                                 dtype=int)
        self.pos_in_group = np.zeros(len(self.surfaces), int)
        self.groups: list[dict] = []
        for gi, (p, q) in enumerate(keys):
            ids = np.flatnonzero(self.group_of == gi)
            srfs = [self.surfaces[i] for i in ids]
            nu = np.array([s.control_points.shape[0] for s in srfs])
            nv = np.array([s.control_points.shape[1] for s in srfs])
            Ku = np.empty((len(ids), nu.max() + p + 1))
            Kv = np.empty((len(ids), nv.max() + q + 1))
            Pw = np.zeros((len(ids), nu.max(), nv.max(), self.dimension + 1))
            for g, s in enumerate(srfs):
                Ku[g], Kv[g] = s.knots_u[-1], s.knots_v[-1]
                Ku[g, :len(s.knots_u)] = s.knots_u
                Kv[g, :len(s.knots_v)] = s.knots_v
                w = s.weights[..., None]
                Pw[g, :nu[g], :nv[g]] = np.concatenate([s.control_points * w, w], axis=-1)
            rows = np.arange(len(ids))
            self.groups.append({"p": p, "q": q, "Ku": Ku, "Kv": Kv, "Pw": Pw,
                                "dom_u": np.column_stack([Ku[:, p], Ku[rows, nu]]),
                                "dom_v": np.column_stack([Kv[:, q], Kv[rows, nv]])})
            self.pos_in_group[ids] = np.arange(len(ids))

    def derivatives(self, sid: Any, u: Any, v: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """S, ∂S/∂u and ∂S/∂v of surface ``sid[r]`` at (u[r], v[r]), for every row r.

        Parameters outside a surface's domain evaluate the C¹ linear extension
        ``S(u_c, v_c) + (u − u_c) S_u + (v − v_c) S_v``, (u_c, v_c) the
        parameters clamped to the domain (derivatives those at the clamped pair).

        Parameters
        ----------
        sid : (k,) int array_like
            Index into ``surfaces`` per row.
        u, v : (k,) float array_like
            Parameters per row.

        Returns
        -------
        S, Su, Sv : (k, d) float ndarray
            Points (control points' units) and first partial derivatives (units per
            unit parameter).
        """
        sid = np.asarray(sid, int)
        u_in, v_in = np.asarray(u, float), np.asarray(v, float)
        d = self.dimension
        S = np.empty((len(sid), d))
        Su = np.empty_like(S)
        Sv = np.empty_like(S)
        gid = self.group_of[sid]
        for gi, grp in enumerate(self.groups):
            rows = np.flatnonzero(gid == gi) if len(self.groups) > 1 else np.arange(len(sid))
            if len(rows) == 0:
                continue
            p, q = grp["p"], grp["q"]
            g = self.pos_in_group[sid[rows]]
            Ku, Kv = grp["Ku"][g], grp["Kv"][g]
            du, dv = grp["dom_u"][g], grp["dom_v"][g]
            uc = np.clip(u_in[rows], du[:, 0], du[:, 1])
            vc = np.clip(v_in[rows], dv[:, 0], dv[:, 1])
            su = find_spans(Ku, p, uc)
            sv = find_spans(Kv, q, vc)
            Du = basis_function_derivatives(su, uc, p, Ku, 1)              # (k, 2, p+1)
            Dv = basis_function_derivatives(sv, vc, q, Kv, 1)              # (k, 2, q+1)
            iu = su[:, None] - p + np.arange(p + 1)
            iv = sv[:, None] - q + np.arange(q + 1)
            P = grp["Pw"][g[:, None, None], iu[:, :, None], iv[:, None, :]]  # (k, p+1, q+1, d+1)
            Pv = (Dv[:, None] @ P).reshape(len(rows), p + 1, 2 * (d + 1))    # sum over v first
            Aw = (Du @ Pv).reshape(len(rows), 2, 2, d + 1)   # Aw[:, a, b] = d^(a+b) Sw/du^a dv^b
            D = rational_surface_derivatives(Aw)
            Su[rows], Sv[rows] = D[:, 1, 0], D[:, 0, 1]
            S[rows] = (D[:, 0, 0] + (u_in[rows] - uc)[:, None] * D[:, 1, 0]
                       + (v_in[rows] - vc)[:, None] * D[:, 0, 1])
        return S, Su, Sv
