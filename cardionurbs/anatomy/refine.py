"""Least-squares correction of a lofted surface towards long-axis contour points.

Beyond the paper: the loft (§3.2.4) passes through the SA sections, and
between them it only interpolates; long-axis (LA) contours show where the
surface really runs between and beyond the SA slices. The correction moves
each control point P_j along its control normal n_j (the surface normal at
the control point's Greville abscissae, NURBS Book eq. 9.8 averages) by δ_j,
minimising (a linearised, smoothed least-squares fit)

    Σ_i w_i (Σ_j N_j(u_i, v_i) (n_j · N_i) δ_j − r_i)²  +  λ Σ_(j,k) (δ_j − δ_k)²  +  ε Σ_j δ_j²

over the SA contour points (weight ``anchor_weight``, r_i ≈ 0: stay through
them) and the LA points
(r_i = signed normal distance to the surface), where (u_i, v_i) is each
point's closest surface point (nearest node of a fine parameter grid,
:func:`grid_projection`) and N_i the unit normal there; the second sum
runs over neighbouring control points (periodic around u). The collapsed apex
row and its ring neighbours keep δ = 0 (the apex is a measured point).
Two passes (re-projecting the points) are made.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from cardionurbs import nurbs
from cardionurbs.nurbs.basis import basis_matrix


def greville(knots: np.ndarray, degree: int, n: int, periodic: bool) -> np.ndarray:
    """Greville abscissae (n,) of n control points: mean of the p knots after each.

    Parameters
    ----------
    knots : ndarray, shape (m,)
        The knot vector (normalised parameter).
    degree : int
        The degree p.
    n : int
        Control points (for a periodic direction: the distinct ones).
    periodic : bool
        Wrap the abscissae into [0, 1) (a closed direction).

    Returns
    -------
    ndarray, shape (n,)
        The parameter value of each control point.
    """
    U = np.asarray(knots, float)
    g = np.array([U[j + 1:j + degree + 1].mean() for j in range(n)])
    return np.mod(g, 1.0) if periodic else g


def collocation(surface, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Tensor-product basis matrix (k, nu·nv) of a non-rational surface at (u_i, v_i).

    Parameters
    ----------
    surface : cardionurbs.nurbs.NurbsSurface
        A non-rational surface (``nu x nv`` control points).
    u, v : ndarray, shape (k,)
        Parameter values of the k points.

    Returns
    -------
    ndarray, shape (k, nu * nv)
        N_i(u) N_j(v) for every point and control point (row-major over (i, j)).
    """
    nu, nv = surface.control_points.shape[:2]
    Bu = basis_matrix(surface.knots_u, surface.degree_u, u,
                      n_periodic=nu if surface.closed_u else None)
    Bv = basis_matrix(surface.knots_v, surface.degree_v, v)
    return (Bu[:, :, None] * Bv[:, None, :]).reshape(len(u), nu * nv)


def grid_laplacian(nu: int, nv: int, periodic_u: bool) -> np.ndarray:
    """Graph Laplacian (nu·nv, nu·nv) of the control grid (4-neighbours, periodic in u).

    Parameters
    ----------
    nu, nv : int
        The control grid's size.
    periodic_u : bool
        The first index wraps around (a closed direction).

    Returns
    -------
    ndarray, shape (nu * nv, nu * nv)
        The dense Laplacian (degree on the diagonal, −1 per neighbour pair).
    """
    idx = np.arange(nu * nv).reshape(nu, nv)
    pairs = [np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)]
    if periodic_u:
        pairs.append(np.stack([idx.ravel(), np.roll(idx, -1, axis=0).ravel()], 1))
    else:
        pairs.append(np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1))
    e = np.concatenate(pairs)
    L = np.zeros((nu * nv, nu * nv))
    np.add.at(L, (e[:, 0], e[:, 0]), 1.0)
    np.add.at(L, (e[:, 1], e[:, 1]), 1.0)
    np.add.at(L, (e[:, 0], e[:, 1]), -1.0)
    np.add.at(L, (e[:, 1], e[:, 0]), -1.0)
    return L


def grid_projection(surface, points: np.ndarray, nu: int = 192, nv: int = 96
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Approximate closest surface points: the nearest node of a (nu × nv) parameter grid.

    Returns (u, v, S(u, v), unit normal N(u, v)). The signed normal distance
    (q − S)·N is what the linearised correction uses; it is insensitive to the
    tangential offset of a grid node (error O(h²), h the grid spacing), so a
    grid projection replaces Newton projection here at a fraction of the cost.

    Parameters
    ----------
    surface : cardionurbs.nurbs.NurbsSurface
        The surface (control points in mm).
    points : ndarray, shape (k, 3)
        The points to project, in mm.
    nu, nv : int, optional
        The parameter grid's size.

    Returns
    -------
    u, v : ndarray, shape (k,)
        The nearest grid node's parameters.
    S : ndarray, shape (k, 3)
        The surface point there, in mm.
    N : ndarray, shape (k, 3)
        The unit surface normal there.
    """
    lo_u, hi_u = surface.domain_u
    lo_v, hi_v = surface.domain_v
    ug = lo_u + (hi_u - lo_u) * (np.arange(nu) / nu if surface.closed_u else np.linspace(0, 1, nu))
    vg = np.linspace(lo_v, hi_v, nv)
    G = surface.evaluate(ug, vg).reshape(-1, 3)
    # leaves of 64 nodes: a quicker build for the one query of a few hundred points (exact
    # either way; the only exact ties, the collapsed apex row, carry no free control point)
    _, k = cKDTree(G, leafsize=64, balanced_tree=False, compact_nodes=False).query(points)
    u, v = ug[k // nv], vg[k % nv]
    return u, v, G[k], surface.normal_points(u, v)      # normals at the chosen nodes only


def refine_surface(surface, anchors: np.ndarray, targets: np.ndarray, *,
                   smoothing: float = 0.05, ridge: float = 1e-4, passes: int = 2,
                   anchor_weight: float = 1.0, max_step_mm: float = 10.0,
                   target_weights: np.ndarray | None = None):
    """Correct ``surface`` towards ``targets`` (LA points) while keeping it through
    ``anchors`` (SA contour points); see module doc. Returns the new surface.

    ``smoothing`` (λ) and ``ridge`` (ε) are relative to the mean diagonal of the
    normal equations, so they do not depend on the point counts. ``target_weights``
    (len(targets),): each LA point's weight w_i in the least squares (the input's
    guide-point weights; default 1).

    Parameters
    ----------
    surface : cardionurbs.nurbs.NurbsSurface
        The lofted surface (control points in mm).
    anchors : ndarray, shape (a, 3)
        SA contour points it must keep passing through, in mm.
    targets : ndarray, shape (t, 3)
        LA contour points it is moved towards, in mm.
    smoothing : float, optional
        λ, relative to the mean diagonal of the normal equations.
    ridge : float, optional
        ε, relative likewise.
    passes : int, optional
        Projection and solve passes.
    anchor_weight : float, optional
        The weight w_i of every anchor.
    max_step_mm : float, optional
        Largest move of a control point per pass, in mm.
    target_weights : ndarray, shape (t,), optional
        Each target's weight w_i (default 1).

    Returns
    -------
    cardionurbs.nurbs.NurbsSurface
        The corrected surface (``surface`` itself when there are no targets).
    """
    if len(targets) == 0:
        return surface
    pts = np.concatenate([anchors, targets])
    nu, nv = surface.control_points.shape[:2]
    fixed = np.zeros((nu, nv), dtype=bool)
    collapsed_start, collapsed_end = surface.collapsed_v()
    if collapsed_end:
        fixed[:, -2:] = True
    if collapsed_start:
        fixed[:, :2] = True
    free = ~fixed.ravel()
    L = grid_laplacian(nu, nv, surface.closed_u)[np.ix_(free, free)]
    gu = greville(surface.knots_u, surface.degree_u, nu, surface.closed_u)
    gv = greville(surface.knots_v, surface.degree_v, nv, False)
    for _ in range(passes):
        u, v, S, N = grid_projection(surface, pts)
        r = np.einsum("ij,ij->i", pts - S, N)
        r[: len(anchors)] = np.einsum("ij,ij->i", anchors - S[: len(anchors)], N[: len(anchors)])
        n_ctrl = surface.normal(gu, gv).reshape(nu * nv, 3)
        B = collocation(surface, u, v)
        A = B * (N @ n_ctrl.T)                         # (k, nu·nv): N_j(u_i,v_i) (n_j · N_i)
        A = A[:, free]
        w = np.ones(len(pts))
        w[: len(anchors)] = anchor_weight
        if target_weights is not None:
            w[len(anchors):] = target_weights
        AtA = A.T @ (A * w[:, None])
        scale = float(np.mean(np.diag(AtA))) or 1.0
        M = AtA + smoothing * scale * L + ridge * scale * np.eye(AtA.shape[0])
        delta = np.zeros(nu * nv)
        delta[free] = np.linalg.solve(M, A.T @ (w * r))
        delta = np.clip(delta, -max_step_mm, max_step_mm)
        P = surface.control_points.reshape(nu * nv, 3) + delta[:, None] * n_ctrl
        surface = nurbs.NurbsSurface(surface.degree_u, surface.degree_v, surface.knots_u,
                                     surface.knots_v, P.reshape(nu, nv, 3),
                                     closed_u=surface.closed_u)
    return surface
