"""The myocardial motion fitted to the tag lines themselves (docs/metrics.md, Regional function).

Tags are laid down as planes at ED (the R-wave trigger) and move with the
tissue, so every point x_i tracked on tag (family, index) k at frame t is the
image of some material point X_i of the ED tag plane Π_k = {X : n_k·X = d_k}:

    x_i = φ(X_i) + δ_i,   n_k·X_i = d_k                                    (T1)

with φ the motion ED → t and δ_i the tracking noise (in the image plane).
φ is the cylindrical map (S1) of :class:`cardionurbs.analysis.strain.CylindricalMotionFit`;
X_i has two free coordinates in its plane. (φ, X_1 … X_n) minimise

    Σ_i |φ(X_i) − x_i|²      over the coefficients of φ and X_i ∈ Π_k(i)     (T2)

— an orthogonal-distance regression: at the optimum x_i − φ(X_i) is the
normal distance of the tag point to the deformed tag surface φ(Π_k). Unlike
a regression of the ED plane coordinate n·φ⁻¹(x) on the noisy points x (which
shrinks the fitted transmural gradient by the ratio of the noise variance to
the spread of the points across the wall and so over-states radial strain),
the noise enters (T2) only as the misfit, so it leaves the fit unbiased to
first order.

Why tag points and not material points
    The material points (:mod:`cardionurbs.analysis.material`) are
    intersections of tag surfaces lofted from tag *curves*, each a cubic with
    one control point per ~12 mm: too smooth to follow an end-systolic tag
    line's bend across a thickening wall, and with one material point every
    tag spacing (6–8 mm) there are one or two across the wall. The tag lines
    carry a point every ~1 mm through the wall, so (T2) resolves the
    transmural gradient the radial strain needs, and each point constrains the
    motion only where it was measured.

Solution
    Gauss–Newton on (T2) with the point unknowns eliminated per point (a
    Schur complement, as in bundle adjustment: Triggs et al., *Bundle
    adjustment — a modern synthesis*, 2000, §6.1), started from the fit of
    the material points (:func:`cardionurbs.analysis.strain.CylindricalMotionFit`)
    with each X_i its point's fixed-point preimage projected on Π_k. Points
    farther than :data:`OUTLIER_MM` and 4 × the median from the fitted surface
    after the first iterations (a mistracked line) are left out.

Near-incompressibility, as a prior
    Myocardium keeps its volume to within a few per cent over the cycle, so det F ≈ 1. The
    tags measure the in-plane stretches (Ecc, Ell) far better than the transmural one (one
    or two tag lines across a ~1 cm wall), and det F ties the three together. With noisy
    tags (tracking noise σ) the fit (T2) is therefore read as a Bayesian estimate: the data
    term Σ_i |φ(X_i) − x_i|² / (2σ²) (the profile likelihood of the tag points) plus the
    prior that each AHA segment's volume mean J̄_s of det F is independently N(1, s²), with
    s = :data:`VOLUME_PRIOR_SD` fixed a priori from the literature (systolic volume losses of
    4–10 % across the wall), not from the data. Multiplied by σ², the prior is the penalty
    ½ (σ² / s²) Σ_s (J̄_s − 1)² (:func:`volume_prior_weight`), re-linearised at every
    Gauss–Newton step: its weight against the data is the ratio of the fit's own noise
    estimate to the stated spread, so noise-free tags (σ → 0) are not pulled at all, and
    a segment whose tags say clearly that its volume changed keeps that change. The ridge
    groups of :func:`penalty_groups` are Gaussian priors too; their weights are chosen by
    maximising the marginal likelihood (the evidence; :func:`choose_penalty` with
    ``criterion="evidence"``) — less variable than the unbiased risk estimate used before,
    which, with the prior weight free as well, swung from 0 to 1000 between phantoms of the
    same kind. Because the prior pulls det F towards 1, the det F of the final fit is no
    independent check any more: the det F of the unregularised fit is reported beside it
    (``det_F_unregularised``). The earlier estimator (the prior weight κ chosen by the risk
    estimate with the ridge weights) stays available for comparison: ``volume_prior_sd=None``
    with ``volume_samples``.

The wall's boundaries as data (T3)
    The endo- and epicardium are material surfaces: the tissue on them at ED is on them
    at every frame. So each contour point y_j of the frame on the endo- (epi-)cardium is
    the image of a point Y_j of the ED endo- (epi-)cardial surface Σ:

        y_j = φ(Y_j) + ε_j,   Y_j ∈ Σ                                           (T3)

    — the form of (T1) with the ED tag plane replaced by Σ, which Y_j slides on (its
    tangent plane at the nearest of dense samples of the ED NURBS surface, re-found after
    every step). Only the distance of y_j from φ(Σ) is data: how far the wall's boundaries
    moved along their normals, i.e. the wall's thickening, which the one or two tag lines
    across the wall measure poorly. Both terms are summed, each point weighted by the
    inverse variance of its noise: ε_j's standard deviation σ_c is estimated from the
    boundary points' own misfit to the tag-only fit (a contour's in-plane noise and the
    ED surface's error), relative to the tags' σ. This is how model-based tag analysis
    has long used contours (Young, Kraitchman, Dougherty & Axel, *Tracking and finite
    element analysis of stripe deformation in magnetic resonance tagging*, IEEE TMI
    14:413–421, 1995: the model is fitted to the tag stripes and the contours together).
    Only contour points between the lowest and highest tag point of the frame (along the
    long axis) are used, where the motion model (S1) is fitted to tags as well.

The misfit as noise
    The regularisation needs σ, the noise of the tag points about the fitted surfaces. The
    ED-plane residual measures the tracking noise; at the frame, the misfit of the tag
    points to the unregularised fit also holds what the map (S1) cannot follow — a real
    wall's motion has more regional detail than a smooth global map. Fitted unregularised,
    the map bends its weakly determined terms (the transmural ones: one or two tag lines
    across the wall) to absorb that remainder, which moves the radial strain most: on
    realistic phantoms with exact tags (ED-plane residual ~0, misfit 0.02–0.04 mm) the
    worst segment Err was off by up to 6 strain points, within 3 with the exact motion.
    So σ is the larger of the two (the misfit with the degrees-of-freedom correction
    √(n / (n − p))): the model error is then treated as noise, and the volume prior and
    the evidence-chosen ridges tie the transmural terms to what the data do determine.
    Exact tags on the ideal phantoms, whose motion the map spans, leave a misfit below
    :data:`NOISE_FLOOR_MM` and stay unregularised.

The ED planes are the total-least-squares planes of each tag's ED lines;
their RMS residual (mm) is the tracking noise normal to the tag, reported as
``tag_noise_mm``. Only points inside the LV myocardium at their frame (SA
contours of that frame, :func:`cardionurbs.analysis.material.myocardium_margin`)
are used.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cardionurbs.analysis.material import myocardium_margin
from cardionurbs.geometry import fit_plane
from cardionurbs.study import Study

#: a tag point farther than this (mm, and 4 x the median) from the fitted surface is left out
OUTLIER_MM = 1.5
#: Gauss–Newton iterations of (T2) before and after leaving out outliers
ITERATIONS = (2, 1)
#: tag points kept at most this far (mm) outside the LV myocardium contours
MARGIN_MM = 0.5
MIN_TAG_POINTS = 300
#: the penalty weights λ tried per group by :func:`choose_penalty` (0: no penalty)
LAMBDA_GRID = np.r_[0.0, np.logspace(-2, 3, 11)]
#: tracking noise (mm) below which the tags count as exact (no regularisation)
NOISE_FLOOR_MM = 0.01
#: tag points are kept up to this many times the tracking noise outside the myocardium
#: contours (and at least MARGIN_MM): a tighter cut selects points by their noise
NOISE_MARGIN = 3.0
#: Gauss–Newton iterations of (T2) with the chosen regulariser (its incompressibility term is
#: not quadratic in the coefficients: its gradient is re-evaluated at every step)
REGULARISED_ITERATIONS = 2
#: a priori standard deviation s of each AHA segment's mean volume ratio J̄_s = mean det F
#: (ED → frame; prior J̄_s ~ N(1, s²)). Myocardium loses some volume in systole as
#: intramyocardial blood is squeezed out: in the canine LV the largest systolic decrease was
#: 4.1, 6.8 and 10.3 % at the subepicardium, midwall and subendocardium (Ashikaga et al.,
#: Am J Physiol Heart Circ Physiol 295:H610–H618, 2008, implanted markers). A zero-mean
#: prior with s = 5 % puts the wall-average decrease (~7 %) at 1.4 s and the subendocardial
#: one at 2 s: it states "a few per cent", not incompressibility.
VOLUME_PRIOR_SD = 0.05
#: confidence level of the F-test that keeps a tag family's planes separate (:func:`tag_grid`)
GRID_TEST_LEVEL = 0.999
#: (u, v) samples of each ED wall surface whose tangent planes the boundary points slide on
#: (:class:`Boundary`): ~1–2 mm apart, so a tangent plane departs from the surface by
#: < 0.03 mm within a sample's reach on the LV's >= 20 mm radii of curvature
BOUNDARY_SAMPLES = (160, 96)
#: Gauss–Newton iterations of (T2) with the tag and boundary points together, before the
#: regularisation
JOINT_ITERATIONS = 2
#: a Gauss–Newton step that makes the fit worse is halved up to this many times (backtracking:
#: from a poor start — the material points of a heart with a sharp regional defect — a full
#: step overshot to a misfit of metres)
MAX_HALVINGS = 8


@dataclass(frozen=True)
class Boundary:
    """The contour points of one frame on one material surface of the LV wall (endo- or
    epicardium), ``points`` (c, 3) mm, and that surface at ED as dense ``samples`` (m, 3)
    with unit ``normals`` (m, 3) (term (T3) of the module docstring); ``tree``: a
    :class:`scipy.spatial.cKDTree` of the samples when one is at hand (shared by the frames of
    a time course), else built when needed.

    Attributes
    ----------
    points : (c, 3) ndarray
        The contour points, mm.
    samples : (m, 3) ndarray
        The ED surface samples, mm.
    normals : (m, 3) ndarray
        Their unit normals.
    tree : scipy.spatial.cKDTree or None
        A k-d tree of ``samples``.
    """
    points: np.ndarray
    samples: np.ndarray
    normals: np.ndarray
    tree: object = None


@dataclass(frozen=True)
class TagPlanes:
    """The ED tag planes: keys (family, index), unit normals (k, 3), offsets d (k,) with
    n·X = d on the plane, and the RMS distance (mm) of the ED tag points to them.

    Attributes
    ----------
    keys : tuple of (str, int)
        (family, index) of each plane.
    normals : (k, 3) ndarray
        Unit normals.
    offsets : (k,) ndarray
        d, mm.
    rms_mm : float
        The ED tag points' RMS distance to their planes, mm.
    """

    keys: tuple
    normals: np.ndarray
    offsets: np.ndarray
    rms_mm: float

    def index(self) -> dict:
        """Key (family, index) -> its row in ``normals`` and ``offsets``.

        Returns
        -------
        dict of (str, int) to int
        """
        return {k: j for j, k in enumerate(self.keys)}


def ed_tag_planes(study: Study, ed_frame: int, exclude: frozenset | set = frozenset()) -> TagPlanes | None:
    """Total-least-squares plane of every tag's ED lines (two or more lines, or one LA line);
    ``exclude``: {(family, index, slice, frame)} lines left out. None without tags at ED.

    Parameters
    ----------
    study : Study
        The study.
    ed_frame : int
        The ED frame.
    exclude : set of (str, int, str, int)
        As above.

    Returns
    -------
    TagPlanes or None
    """
    groups: dict[tuple, list[np.ndarray]] = {}
    for t in study.tags_at(ed_frame):
        if (t.family, t.index, t.slice, t.frame) in exclude:
            continue
        groups.setdefault((t.family, t.index), []).append(np.asarray(t.points, float))
    keys, normals, offsets, sq, count = [], [], [], 0.0, 0
    for k, lines in sorted(groups.items()):
        P = np.vstack(lines)
        if len(P) < 3:
            continue
        c, n = fit_plane(P)
        keys.append(k)
        normals.append(n)
        offsets.append(float(n @ c))
        sq += float(np.sum(((P - c) @ n) ** 2))
        count += len(P)
    if not keys:
        return None
    planes = TagPlanes(tuple(keys), np.array(normals), np.array(offsets), float(np.sqrt(sq / count)))
    return tag_grid(planes, {k: np.vstack(v) for k, v in groups.items()})


def tag_grid(planes: TagPlanes, points: dict, level: float = GRID_TEST_LEVEL) -> TagPlanes:
    """The ED tag planes of each family as one SPAMM grid.

    SPAMM lays the tags of a family down as parallel, equally spaced planes (the
    modulation is periodic along one direction). Fitted so, a family's planes share one
    normal — the least-squares normal of all the family's ED points, each about its own
    plane's centroid — and have offsets d_k = a + b k (k the tag index; weighted least
    squares, weights the point counts): every plane is then estimated from all of the
    family's points, not its own few. Separately fitted planes carry an offset error of
    σ / √n_k each (n_k ≈ 20–60 points per LA tag), which the strain fit reads as real
    stretch between neighbouring tags (≈ 1 strain point of Ell between two tags 8 mm apart
    at σ = 0.6 mm) and which the fit's own standard errors do not include.

    A family keeps its separately fitted planes when it has fewer than three, or when the
    grid is rejected by the F-test of the nested least-squares fits (3 parameters per plane
    against 4 per family) at ``level``: its tags are not one parallel, equally spaced set.

    Parameters
    ----------
    planes : TagPlanes
        The separately fitted planes.
    points : dict
        Key (family, index) -> its ED tag points (n, 3), mm.
    level : float
        The F-test's level.

    Returns
    -------
    TagPlanes
    """
    from scipy.special import fdtri  # the F distribution's quantile (scipy.stats.f.ppf calls it)
    fam_of = [k[0] for k in planes.keys]
    normals, offsets = planes.normals.copy(), planes.offsets.copy()
    for fam in dict.fromkeys(fam_of):
        rows = [j for j, f in enumerate(fam_of) if f == fam]
        if len(rows) < 3:
            continue
        P = [points[planes.keys[j]] for j in rows]
        ref = planes.normals[rows[0]]
        C = [p.mean(axis=0) for p in P]
        scatter = sum((p - c).T @ (p - c) for p, c in zip(P, C))
        n = np.linalg.eigh(scatter)[1][:, 0]
        n = n if n @ ref >= 0 else -n
        idx = np.array([planes.keys[j][1] for j in rows], float)
        w = np.array([len(p) for p in P], float)
        dc = np.array([n @ c for c in C])
        A = np.column_stack([np.ones_like(idx), idx]) * np.sqrt(w)[:, None]
        ab = np.linalg.lstsq(A, dc * np.sqrt(w), rcond=None)[0]
        d = ab[0] + ab[1] * idx
        sep = sum(float(np.sum(((p - p.mean(axis=0)) @ planes.normals[j]) ** 2)) for p, j in zip(P, rows))
        grid = sum(float(np.sum((p @ n - dk) ** 2)) for p, dk in zip(P, d))
        n_pts, dfn = int(w.sum()), 3 * len(rows) - 4
        dfd = n_pts - 3 * len(rows)
        exact = grid <= 1e-12 * n_pts                  # both fits exact (noise-free tags)
        if not exact and (dfd < 1 or (grid - sep) / dfn > fdtri(dfn, dfd, level) * sep / dfd):
            continue
        normals[rows] = n
        offsets[rows] = d
    return TagPlanes(planes.keys, normals, offsets, planes.rms_mm)


def frame_tag_points(study: Study, frame: int, planes: TagPlanes,
                     exclude: frozenset | set = frozenset(), margin_mm: float | None = None):
    """Tag points of ``frame`` on tags with an ED plane, inside the LV myocardium of that frame:
    (points (n, 3), plane index (n,)); None when the frame has no SA myocardial contours.

    "Inside" allows ``margin_mm`` outside the contours; default :data:`NOISE_MARGIN` × the
    tracking noise (:attr:`TagPlanes.rms_mm`), at least :data:`MARGIN_MM`. The noise moves a
    tag point along its line as well as across it; a cut at the contours drops the points
    near the endo- and epicardium that the noise moved out of the wall and keeps those it
    moved in, so for a line crossing the wall obliquely it shifts the kept points across
    the tag near both surfaces, in opposite directions — a bias of the transmural gradient
    (at 0.6 mm noise a 0.5 mm margin made the mean segment Err of a phantom 1–4 points lower
    than 1.75 mm did).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    planes : TagPlanes
        The ED tag planes.
    exclude : set of (str, int, str, int)
        Lines left out.
    margin_mm : float or None
        As above.

    Returns
    -------
    (points (n, 3) ndarray, plane index (n,) ndarray) or None
        mm.
    """
    if margin_mm is None:
        margin_mm = max(MARGIN_MM, NOISE_MARGIN * planes.rms_mm)
    where = planes.index()
    pts, idx = [], []
    for t in study.tags_at(frame):
        j = where.get((t.family, t.index))
        if j is None or (t.family, t.index, t.slice, t.frame) in exclude:
            continue
        pts.append(np.asarray(t.points, float))
        idx.append(np.full(len(t.points), j))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, int)
    x, k = np.vstack(pts), np.concatenate(idx)
    margin = myocardium_margin(study, frame, x)
    if margin is None:
        return None
    keep = margin >= -margin_mm
    return x[keep], k[keep]


def plane_bases(normals: np.ndarray) -> np.ndarray:
    """(n, 2, 3) orthonormal in-plane axes of planes with unit ``normals`` (n, 3), vectorised
    :func:`cardionurbs.geometry.in_plane_basis`.

    Parameters
    ----------
    normals : (n, 3) ndarray
        Unit normals.

    Returns
    -------
    (n, 2, 3) ndarray
    """
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return np.stack([e1, np.cross(normals, e1)], axis=1)


def _schur_step(T: np.ndarray, D: np.ndarray, free: np.ndarray, J_pt: np.ndarray, res: np.ndarray,
                ridge: float, penalty: np.ndarray | None = None,
                penalty_grad: np.ndarray | None = None):
    """One Gauss–Newton step of (T2): (Δparams, Δw, S) with the per-point 2-vectors w eliminated
    (S the reduced Gauss–Newton matrix of the data over the free coefficients).

    The Jacobian of the points with respect to the coefficients comes factored, as
    :meth:`~cardionurbs.analysis.strain.CylindricalMotionFit.linearisation` gives it:
    ∂x_n/∂coef[j, c] = T[n, :, c] · D[n, j] (``T`` (n, 3, 3), ``D`` (n, b); ``free`` the mask of
    the coefficients in use over ``coef.T.ravel()``). Every block of the Schur complement is
    then Dᵀ diag(g) D for a per-point weight g (one per pair of components), which costs
    6 n b² instead of the (3 n) p² of the explicit Jacobian. ``J_pt`` (n, 3, 2) the derivative
    with respect to the point unknowns, ``res`` (n, 3); ``penalty`` (p, p) the Hessian of a
    regulariser added to the objective and ``penalty_grad`` (p,) its gradient at the current
    coefficients (for a quadratic cᵀ R c / 2: R and R · c)."""
    b = D.shape[1]
    H_pp = np.einsum("nik,nil->nkl", J_pt, J_pt)
    inv = np.linalg.inv(H_pp)
    H_pt = np.einsum("nik,nic->nkc", J_pt, T)                           # (n, 2, 3): J_ptᵀ T
    M = inv @ H_pt                                                     # (n, 2, 3)
    g_p = np.einsum("nik,ni->nk", J_pt, res)
    # per-point weights of the blocks: Tᵀ T − H_ptᵀ H_pp⁻¹ H_pt, and of the right-hand side
    G = np.einsum("nic,nid->ncd", T, T) - np.einsum("nkc,nkd->ncd", H_pt, M)
    r = np.einsum("nic,ni->nc", T, res) - np.einsum("nkc,nk->nc", M, g_p)
    # each component's columns in use (the blocks are formed for those alone)
    Dc = [D[:, free[c * b:(c + 1) * b]] for c in range(3)]
    at = np.cumsum([0] + [d.shape[1] for d in Dc])
    m = int(at[-1])
    S_data = np.empty((m, m))
    for c1 in range(3):
        for c2 in range(c1, 3):
            block = (Dc[c1] * G[:, c1, c2][:, None]).T @ Dc[c2]
            S_data[at[c1]:at[c1 + 1], at[c2]:at[c2 + 1]] = block
            S_data[at[c2]:at[c2 + 1], at[c1]:at[c1 + 1]] = block.T
    rhs = np.concatenate([Dc[c].T @ r[:, c] for c in range(3)])
    S = S_data
    if penalty is not None:
        S = S + penalty
        rhs = rhs + penalty_grad
    S = S + ridge * np.trace(S) / m * np.eye(m)
    d_coef = -np.linalg.solve(S, rhs)
    moved = np.column_stack([Dc[c] @ d_coef[at[c]:at[c + 1]] for c in range(3)])  # Δ(q', θ', ζ')
    d_pt = -np.einsum("nkl,nl->nk", inv, g_p + np.einsum("nkc,nc->nk", H_pt, moved))
    return d_coef, d_pt, S_data


@dataclass(frozen=True)
class PointQuantities:
    """Quantities of a motion fit that are functions of its deformation gradient at fixed ED
    points: ``parts`` ((points (n, 3), reduce), …), reduce mapping F (k, n, 3, 3) to (k, q);
    the quantities are the parts' outputs concatenated. Called with a fit, they are its
    values; :func:`quantity_jacobian` evaluates all central differences in one batch
    (:meth:`~cardionurbs.analysis.strain.CylindricalMotionFit.perturbed_gradients`).

    Attributes
    ----------
    parts : tuple of ((n, 3) ndarray, callable)
        The (points, reduce) parts.
    """
    parts: tuple

    def __call__(self, fit) -> np.ndarray:
        return np.concatenate([reduce(fit.gradient(P)[None])[0] for P, reduce in self.parts])

    def __add__(self, other: "PointQuantities") -> "PointQuantities":
        return PointQuantities(self.parts + other.parts)


def quantity_jacobian(fit, quantities, coef: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """∂q/∂params (k, p) of ``quantities(fit)`` by central differences, step 1e-3 × ``scale``
    (the coefficients' standard errors), the fit's coefficients restored after.
    :class:`PointQuantities` are differenced in one batch (the same differences).

    Parameters
    ----------
    fit : CylindricalMotionFit
        The fit.
    quantities : callable
        fit -> (k,) quantities (a :class:`PointQuantities` is differenced in one batch).
    coef : (p,) ndarray
        The free coefficients to difference about.
    scale : (p,) ndarray
        Their standard errors.

    Returns
    -------
    (k, p) ndarray
    """
    h = 1e-3 * np.maximum(scale, 1e-12)
    if isinstance(quantities, PointQuantities):
        fit.params = coef
        p, cols, last = len(coef), [], (None, None)
        for P, reduce in quantities.parts:
            if last[0] is None or not np.array_equal(last[0], P):      # parts at the same points
                last = (P, fit.perturbed_gradients(P, h))              # share one batch of F
            q = reduce(last[1])                                        # (2p, k)
            cols.append(((q[:p] - q[p:]) / (2 * h[:, None])).T)
        return np.vstack(cols)
    cols = []
    for j in range(len(coef)):
        c = coef.copy()
        c[j] += h[j]
        fit.params = c
        up = quantities(fit)
        c[j] -= 2 * h[j]
        fit.params = c
        cols.append((up - quantities(fit)) / (2 * h[j]))
    fit.params = coef
    return np.array(cols).T


def penalty_groups(fit) -> list[np.ndarray]:
    """Masks over the free coefficients (``fit.params``) of the terms (S1) that the
    regulariser shrinks towards zero, one mask per group:

    1. the *transmural variation*: the r² terms other than the constant one (how the
       transmural gradient changes with height and angle) — the terms that carry the
       noise of the radial strain, since only the tag spacing across a ~1 cm wall
       informs them;
    2. the highest Legendre order in height (the finest longitudinal detail).

    Parameters
    ----------
    fit : CylindricalMotionFit
        The fit.

    Returns
    -------
    list of (p,) ndarray of bool
    """
    a, b, m = fit._index
    groups = [(b == 1) & ~((a == 0) & (m == 0)), (b == 0) & (a == a.max())]
    return [np.tile(g, 3)[fit.free] for g in groups]


def choose_penalty(S: np.ndarray, coef: np.ndarray, groups: list[np.ndarray], sigma_mm: float,
                   B: np.ndarray, grid=LAMBDA_GRID, ridge: float = 1e-8,
                   terms: tuple = (), fixed: tuple = (), criterion: str = "risk"
                   ) -> tuple[np.ndarray, tuple]:
    """The regulariser that minimises an unbiased estimate of the mean squared error of the
    quantities B·c (e.g. the segment strains, B their derivative with respect to the
    coefficients) of the linearised fit (T2), over weights λ on a grid.

    The regulariser is a sum of quadratics weighted by λ_g: for each coefficient group g of
    ``groups`` the ridge ½ Σ_{j∈g} S_jj c_j² (Hessian Q_g = diag(S_jj on g), gradient Q_g c),
    and for each (Q, r) of ``terms`` a quadratic with Hessian Q and gradient r at ``coef``
    (e.g. the linearised incompressibility penalty of :func:`incompressibility_term`). With c the
    unregularised optimum, Cov(c) = σ² S⁻¹ (S the reduced Gauss–Newton matrix, σ the tag
    tracking noise in mm), P_λ = Σ λ_g Q_g, ρ_λ = Σ λ_g r_g (the penalty's gradient at c)
    and A = (S + P_λ)⁻¹, the regularised optimum is c_λ = c − A ρ_λ; its error
    B(c_λ − c_true) has mean square |B A E[ρ_λ]|² + σ² tr(B A S A Bᵀ), and since ρ_λ is
    affine in c with Cov(ρ_λ) = σ² P_λ S⁻¹ P_λ,

        R(λ) = |B A ρ_λ|² − σ² tr(B A P_λ S⁻¹ P_λ A Bᵀ) + σ² tr(B A S A Bᵀ)

    estimates it without bias (Stein's unbiased risk estimate for a linear smoother; Vogel,
    *Computational Methods for Inverse Problems*, 2002, §7.1). Scaling each ridge
    coefficient by S_jj makes λ dimensionless (λ = 1: as much prior as data on that
    coefficient). ``fixed``: further (Q, r) quadratics with weight 1 in every candidate (a
    prior whose strength is stated, not chosen: :func:`volume_prior_weight`); they are part
    of P_λ and ρ_λ.

    ``criterion="evidence"`` chooses the ridge weights instead by the marginal likelihood
    of the linearised model (type-II maximum likelihood: MacKay, *Bayesian interpolation*,
    Neural Computation 4:415–447, 1992; for smoothing parameters it varies less than
    risk-type criteria and undersmooths less often: Wahba, Ann. Statist. 13:1378–1402, 1985;
    Reiss & Ogden, J. R. Stat. Soc. B 71:505–523, 2009). Reading the ridge g as the prior
    c_j ~ N(0, σ² / (λ_g S_jj)) on its n_g coefficients and the ``fixed`` terms as a prior
    of stated strength, the data as c ~ N(c_true, σ² S⁻¹), it minimises

        −2 log p(data | λ) = [Σ_g λ_g cᵀQ_g c − ρ_λᵀ (S + P_λ)⁻¹ ρ_λ] / σ²
                             + log det(S + P_λ) − Σ_g n_g log λ_g  + const

    over the positive grid values (λ = 0 is a flat prior, whose evidence vanishes); it
    needs no ``B`` and takes no ``terms``. With σ = 0, λ = 0 (and no fixed term).

    Parameters
    ----------
    S, coef : (m, m) ndarray; (m,) ndarray
        The reduced Gauss–Newton matrix; the unregularised optimum c.
    groups : list of (m,) ndarray of bool
        The ridge groups (:func:`penalty_groups`).
    sigma_mm : float
        The tag tracking noise σ, mm.
    B : (k, m) ndarray
        The quantities' derivative with respect to the coefficients.
    grid, ridge : (g,) ndarray; float
        The candidate weights λ; a relative ridge keeping S + P regular.
    terms, fixed : tuple of (Q, r)
        Quadratics whose weights are chosen; quadratics of weight 1.
    criterion : {"risk", "evidence"}
        The unbiased risk estimate, or the marginal likelihood (above).

    Returns
    -------
    P, weights : (m, m) ndarray; tuple of float
        P_λ including the fixed terms; λ per group, then per term.
    """
    if criterion not in ("risk", "evidence") or (criterion == "evidence" and terms):
        raise ValueError(f"criterion {criterion!r}: 'risk', or 'evidence' without terms")
    m = len(coef)
    reg = ridge * np.trace(S) / m * np.eye(m)
    d = np.diag(S)
    S_inv = np.linalg.inv(S + reg)
    Qs = [np.diag(np.where(g, d, 0.0)) for g in groups] + [np.asarray(Q, float) for Q, _ in terms]
    rs = [Q @ coef for Q in Qs[:len(groups)]] + [np.asarray(r, float) for _, r in terms]
    best, choice = np.inf, tuple(0.0 for _ in Qs)
    if sigma_mm < NOISE_FLOOR_MM:
        return np.zeros((m, m)), choice
    P0 = sum((np.asarray(Q, float) for Q, _ in fixed), np.zeros((m, m)))
    r0 = sum((np.asarray(r, float) for _, r in fixed), np.zeros(m))
    if Qs or fixed:
        s2 = sigma_mm ** 2
        for lams in itertools.product(grid, repeat=len(Qs)):
            Pl = sum((lam * Q for lam, Q in zip(lams, Qs) if lam), P0.copy())
            rho = sum((lam * r for lam, r in zip(lams, rs) if lam), r0.copy())
            if criterion == "evidence":
                if not all(lams[:len(groups)]):
                    continue                      # a flat prior: the evidence vanishes
                H = S + Pl + reg
                logdet = np.linalg.slogdet(H)[1]
                shift = np.linalg.solve(H, rho)
                risk = ((sum(lam * float(coef @ Q @ coef) for lam, Q in zip(lams, Qs))
                         - float(rho @ shift)) / s2 + logdet
                        - sum(int(g.sum()) * np.log(lam) for lam, g in zip(lams, groups)))
            else:
                BA = np.linalg.solve(S + Pl + reg, B.T).T              # B A (A symmetric)
                BAP = BA @ Pl
                risk = (float(np.sum((BA @ rho) ** 2)) - s2 * float(np.sum((BAP @ S_inv) * BAP))
                        + s2 * float(np.sum((BA @ S) * BA)))
            if risk < best:
                best, choice = risk, lams
    P = sum((lam * Q for lam, Q in zip(choice, Qs) if lam), P0)
    return P, tuple(float(v) for v in choice)


def incompressibility_term(G: np.ndarray, g: np.ndarray, weights: np.ndarray, scale: float):
    """(Q, r): Hessian and gradient of the linearised near-incompressibility penalty

        ½ κ · scale · Σ_s w_s (J̄_s − 1)²,   J̄_s = the volume mean of det F over segment s,

    with g_s = J̄_s − 1 at the current coefficients, G = ∂J̄/∂coef (k, m) and ``weights``
    w_s (normalised here to sum 1; e.g. the segments' volumes). ``scale``
    (:func:`incompressibility_scale`) makes κ dimensionless.

    Parameters
    ----------
    G : (k, m) ndarray
        ∂J̄/∂coef.
    g : (k,) ndarray
        J̄_s − 1.
    weights : (k,) ndarray
        w_s.
    scale : float
        :func:`incompressibility_scale`.

    Returns
    -------
    Q : (m, m) ndarray
    r : (m,) ndarray
    """
    w = np.asarray(weights, float) / np.sum(weights)
    return scale * (G.T @ (w[:, None] * G)), scale * (G.T @ (w * g))


def volume_prior_weight(noise_mm: float, prior_sd: float) -> float:
    """σ² / s²: the weight of ½ Σ_s (J̄_s − 1)² beside the data term ½ Σ_i |φ(X_i) − x_i|² (mm²)
    when the segment-mean volume ratios J̄_s are a priori independent N(1, s²) and the tag
    points have isotropic tracking noise σ (mm): the negative log posterior times σ².

    Parameters
    ----------
    noise_mm : float
        σ, mm.
    prior_sd : float
        s.

    Returns
    -------
    float
        mm².
    """
    return float(noise_mm) ** 2 / float(prior_sd) ** 2


def incompressibility_scale(G: np.ndarray, weights: np.ndarray, S: np.ndarray) -> float:
    """tr S / tr(Gᵀ W G): with it κ = 1 gives the incompressibility penalty the trace of the
    data's Gauss–Newton matrix S, as λ = 1 does for a ridge group.

    Parameters
    ----------
    G : (k, m) ndarray
        ∂J̄/∂coef.
    weights : (k,) ndarray
        The segments' weights W.
    S : (m, m) ndarray
        The Gauss–Newton matrix.

    Returns
    -------
    float
    """
    w = np.asarray(weights, float) / np.sum(weights)
    return float(np.trace(S) / max(float(np.einsum("ka,k,ka->", G, w, G)), 1e-300))


def segment_mean_matrix(labels: np.ndarray, volumes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M (k, n), v (k,)): M @ values gives the volume means of per-sample ``values`` over the
    k segments present in ``labels``, v the segments' volumes.

    Parameters
    ----------
    labels : (n,) ndarray of int
        Segment of each sample.
    volumes : (n,) ndarray
        Their volumes, mm³.

    Returns
    -------
    M : (k, n) ndarray
    v : (k,) ndarray
        mm³.
    """
    segs = np.unique(labels)
    M = (np.asarray(labels)[None, :] == segs[:, None]) * np.asarray(volumes, float)[None, :]
    v = M.sum(axis=1)
    return M / v[:, None], v


def boundary_start(fit, boundary, ed_tag_points: np.ndarray):
    """The boundary points (T3) that start the joint fit: (y (c, 3) the contour points whose
    ED preimage lies between the lowest and highest ED tag point along the long axis, Y
    (c, 3) those preimages on the ED surfaces, their tangent-plane bases (c, 2, 3), and
    ``slide``: points -> (the points put back on the tangent plane of their nearest ED
    surface sample, the bases of those planes)).

    Y starts at the fixed-point preimage of y under ``fit`` and is then moved along its
    surface by Gauss–Newton with the motion held (three steps), so that φ(Y) − y is y's
    distance from the moved surface.

    Parameters
    ----------
    fit : CylindricalMotionFit
        The motion fit (ED → frame).
    boundary : Boundary
        One surface's contour points and ED samples.
    ed_tag_points : (n, 3) ndarray
        The ED tag points, mm.

    Returns
    -------
    tuple
        (y, Y, bases, slide) as above.
    """
    from scipy.spatial import cKDTree
    trees = [cKDTree(b.samples) if b.tree is None else b.tree for b in boundary]
    label = np.concatenate([np.full(len(b.points), i) for i, b in enumerate(boundary)])

    def slide(P, label=label):
        out, nrm = np.array(P, float), np.zeros((len(P), 3))
        for i, b in enumerate(boundary):
            m = label == i
            j = trees[i].query(out[m])[1]
            nn = b.normals[j]
            out[m] -= np.einsum("ni,ni->n", out[m] - b.samples[j], nn)[:, None] * nn
            nrm[m] = nn
        return out, plane_bases(nrm)
    y = np.vstack([np.asarray(b.points, float) for b in boundary])
    Y = y.copy()
    for _ in range(3):
        Y = slide(Y + (y - fit.position(Y)))[0]
    for _ in range(3):
        Y, B = slide(Y)
        J = fit.gradient(Y) @ B.transpose(0, 2, 1)                     # (c, 3, 2)
        H = np.einsum("nik,nil->nkl", J, J)
        H += 1e-9 * (np.trace(H, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(2)
        g = np.einsum("nik,ni->nk", J, fit.position(Y) - y)
        ok = np.isfinite(H).all(axis=(1, 2)) & np.isfinite(g).all(axis=1)
        step = np.zeros_like(g)
        step[ok] = np.linalg.solve(H[ok], g[ok][:, :, None])[:, :, 0]
        Y = Y - np.einsum("nk,nkj->nj", step, B)
    axis = fit.frame0[2]                               # heights along the ED long axis
    zeta = (Y - fit.apex0) @ axis
    z_tag = (ed_tag_points - fit.apex0) @ axis
    inside = ((zeta >= z_tag.min()) & (zeta <= z_tag.max())
              & np.isfinite(fit.position(Y)).all(axis=1))
    y, Y, label = y[inside], Y[inside], label[inside]

    def slide_inside(P):
        return slide(P, label)
    Y, B = slide_inside(Y)
    return y, Y, B, slide_inside


def fit_tag_motion(fit, points: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                   noise_mm: float = 0.0, quantities=None, ridge: float = 1e-8,
                   volume_samples: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                   volume_prior_sd: float | None = None,
                   boundary: list[Boundary] | tuple[Boundary, ...] = (),
                   misfit_noise: bool = True) -> dict:
    """Refine a :class:`~cardionurbs.analysis.strain.CylindricalMotionFit` ``fit`` (ED → frame,
    started from the material points) on tag points by (T2), in place.

    Regularisation: with a noise σ (the tracking noise ``noise_mm``, or the misfit if
    larger: ``misfit_noise``) of at least :data:`NOISE_FLOOR_MM` and ``quantities``, the
    fit is refined once more with the ridge penalties of :func:`choose_penalty` on the
    groups of :func:`penalty_groups` and, given ``volume_samples``, a near-incompressibility
    term on the segments' mean det F (:func:`incompressibility_term`): with
    ``volume_prior_sd`` s the prior J̄_s ~ N(1, s²) (weight σ² / s²,
    :func:`volume_prior_weight`) and the ridge weights that maximise the evidence; with
    ``volume_prior_sd=None`` a weight κ chosen with the ridge weights to minimise the
    estimated mean squared error of the quantities (see "Near-incompressibility, as a
    prior" above).

    Parameters
    ----------
    fit : CylindricalMotionFit
        The map ED → frame, refined in place.
    points : (n, 3) float ndarray
        The frame's tag points, mm.
    normals, offsets : (n, 3) and (n,) float ndarray
        Their ED tag planes (n · X = d), mm.
    noise_mm : float
        The tracking noise, e.g. :attr:`TagPlanes.rms_mm`.
    quantities : callable or PointQuantities, optional
        The fit -> the vector of quantities the fit is for, e.g. the segment strains
        (:class:`PointQuantities` are differenced faster); None: no regularisation.
    ridge : float
        The relative ridge that keeps the normal matrix invertible.
    volume_samples : ((k, 3), (k,), (k,)) ndarrays, optional
        ED wall points, their volumes and their AHA segments, for the
        near-incompressibility term.
    volume_prior_sd : float, optional
        The prior's s (None: κ chosen by the risk estimate).
    boundary : sequence of Boundary
        Contour points on the wall's material surfaces with those surfaces at ED
        (:class:`Boundary`, term (T3)); they join the fit after the tag-only iterations,
        weighted σ / σ_c against the tags.
    misfit_noise : bool
        The σ of the regularisation is the larger of ``noise_mm`` and the tag points'
        misfit to the unregularised fit, √(Σ e_i² / (n − p)) (p the free coefficients);
        False: ``noise_mm`` alone (the estimator before, for comparison).

    Returns
    -------
    dict
        "residual_mm" (RMS distance to the fitted surfaces), "outliers", "n_points",
        "lambda" (penalty weight per group, then the incompressibility weight κ with
        ``volume_samples`` and no ``volume_prior_sd``), "ed_points" (the fitted X_i),
        "quantity_se" (the standard errors σ √diag(B S⁻¹ Bᵀ) of the quantities for the
        unregularised fit, B their derivative with respect to the coefficients; None
        without regularisation), "regularised_sd" (the standard deviations
        σ √diag(B A S A Bᵀ) of the regularised fit's quantities, A = (S + P)⁻¹: its noise,
        not its bias), "det_F_unregularised" (volume-weighted mean, min, max of det F over
        ``volume_samples`` for the unregularised fit: the incompressibility check
        independent of the penalty), "boundary_points" and "boundary_residual_mm" (the
        contour points of ``boundary`` used and their RMS distance to the moved ED
        surfaces; 0 and None without), "boundary_noise_mm" (σ_c), "misfit_mm" and
        "sigma_mm" (the σ used).
    """
    state = _TagLineFit(fit, points, normals, offsets, ridge)
    S = state.tag_only()
    S, sigma_c = state.join_boundary(boundary, noise_mm, S)
    volume = _segment_volumes(fit, volume_samples)
    # the σ of the regularisation: the tracking noise, or the tag points' misfit if larger
    # (what the map (S1) cannot follow is noise to it too; see "The misfit as noise" above)
    misfit = state.misfit()
    sigma = max(float(noise_mm), misfit) if misfit_noise else float(noise_mm)
    lams, se, sd = (), None, None
    if sigma >= NOISE_FLOOR_MM and quantities is not None:
        lams, se, sd = _regularise(state, S, quantities, volume, sigma, volume_prior_sd)
    return state.result(lams, se, sd, volume, sigma_c, misfit, sigma)


class _TagLineFit:
    """The data and state of the orthogonal-distance regression (T2) of a motion ``fit``,
    with the boundary points of (T3) appended once they join.

    Attributes
    ----------
    fit : CylindricalMotionFit
        Refined in place.
    x : (m, 3) float ndarray
        The points at the frame, mm: the n_tag tag points, then the boundary points.
    X : (m, 3) float ndarray
        Their ED preimages on their ED planes (boundary points: on their ED surfaces), mm.
    basis : (m, 2, 3) float ndarray
        An orthonormal basis of each point's ED plane (tangent plane).
    use : (m,) bool ndarray
        The points fitted (not outliers).
    weight : (m,) float ndarray
        Their weights (1 for tags, σ / σ_c for boundary points).
    slide : callable or None
        Boundary preimages -> (back on the ED surfaces, their tangent bases).
    err : (m,) float ndarray
        Each point's distance from the fitted map's image of its preimage, mm (after the
        last stage).
    """

    def __init__(self, fit, points: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                 ridge: float) -> None:
        self.fit, self.ridge = fit, ridge
        self.x = np.asarray(points, float)
        n = np.asarray(normals, float)
        d = np.asarray(offsets, float)
        self.n_tag = len(self.x)
        self.n_boundary = 0
        self.basis = plane_bases(n)                                    # (n, 2, 3)
        # start: the fixed-point preimage of each point under the start map, on its plane
        X = self.x.copy()
        for _ in range(3):
            X = X + (self.x - fit.position(X))
            X -= ((np.einsum("ni,ni->n", n, X) - d))[:, None] * n
        self.X = X
        self.use = np.ones(len(self.x), bool)
        self.weight = np.ones(len(self.x))
        self.slide = None            # the boundary points' surfaces (after the tag-only fit)
        self.err = np.zeros(len(self.x))

    def step(self, penalty: np.ndarray | None = None,
             penalty_grad: np.ndarray | None = None) -> np.ndarray:
        """One Gauss–Newton step of coefficients and preimages (:func:`_schur_step`), halved
        until the data term does not grow (a regularised step is judged with its penalty);
        returns the data term's normal matrix S (p, p)."""
        fit, x, X, basis, use = self.fit, self.x, self.X, self.basis, self.use
        pos, (T, D), F = fit.linearisation(X[use])
        J_pt = F @ basis[use].transpose(0, 2, 1)                         # (n, 3, 2)
        coef = fit.params                                               # component-major
        w = self.weight[use][:, None]
        d_coef, d_pt, S = _schur_step(T * w[:, :, None], D, fit.free, J_pt * w[:, :, None],
                                      (pos - x[use]) * w, self.ridge, penalty, penalty_grad)
        before = float(np.sum(((pos - x[use]) * w) ** 2))
        X0, basis0, move = X.copy(), basis.copy(), np.einsum("nk,nkj->nj", d_pt, basis[use])
        for halving in range(MAX_HALVINGS + 1):
            t = 0.5 ** halving
            fit.params = coef + t * d_coef
            X[:], basis[:] = X0, basis0
            X[use] += t * move
            if self.slide is not None:   # back onto the ED surfaces; their new tangent planes
                X[self.n_tag:], basis[self.n_tag:] = self.slide(X[self.n_tag:])
            # the data term must not grow (a regularised step is judged with its penalty)
            if penalty is not None or float(np.sum(((fit.position(X[use]) - x[use]) * w) ** 2)) <= before:
                break
        return S

    def measure(self) -> None:
        """Each point's distance from the fitted map's image of its preimage (``err``)."""
        self.err = np.linalg.norm(self.fit.position(self.X) - self.x, axis=1)

    def tag_only(self) -> np.ndarray:
        """The tag-only stages of :data:`ITERATIONS`, the outliers left out after the first;
        returns the last step's S."""
        S = None
        for stage, iters in enumerate(ITERATIONS):
            for _ in range(iters):
                S = self.step()
            self.measure()
            if stage == 0:
                self.use = self.err <= max(OUTLIER_MM, 4.0 * float(np.median(self.err)))
        assert S is not None, "ITERATIONS takes at least one step"
        return S

    def join_boundary(self, boundary, noise_mm: float,
                      S: np.ndarray) -> tuple[np.ndarray, float | None]:
        """Join the boundary points (term (T3)) and run :data:`JOINT_ITERATIONS` steps.

        Parameters
        ----------
        boundary : sequence of Boundary
            May be empty.
        noise_mm : float
            The tag tracking noise σ_t, mm.
        S : (p, p) ndarray
            The last step's normal matrix (returned when no boundary point joins).

        Returns
        -------
        S : (p, p) ndarray
            The last step's normal matrix.
        sigma_c : float or None
            The boundary noise σ_c, mm: the RMS distance of the points (gross outliers
            left out) from the ED surfaces moved by the tag-only fit; None without.
        """
        if not len(boundary):
            return S, None
        y, Y, basis_b, self.slide = boundary_start(self.fit, boundary, self.X[self.use])
        self.n_boundary = len(y)
        if not self.n_boundary:
            return S, None
        e_b = np.linalg.norm(self.fit.position(Y) - y, axis=1)
        keep_b = e_b <= max(OUTLIER_MM, 4.0 * float(np.median(e_b)))
        sigma_c = max(float(np.sqrt(np.mean(e_b[keep_b] ** 2))), NOISE_FLOOR_MM)
        sigma_t = max(float(noise_mm), NOISE_FLOOR_MM)
        self.x = np.r_[self.x, y]
        self.X = np.r_[self.X, Y]
        self.basis = np.r_[self.basis, basis_b]
        self.use = np.r_[self.use, keep_b]
        self.weight = np.r_[self.weight, np.full(len(y), sigma_t / sigma_c)]
        for _ in range(JOINT_ITERATIONS):
            S = self.step()
        self.measure()
        return S, sigma_c

    def misfit(self) -> float:
        """The tag points' misfit √(Σ e_i² / (n − p)), mm (p the free coefficients)."""
        tags = self.use[:self.n_tag]
        n_used = int(tags.sum())
        return float(np.sqrt(np.sum(self.err[:self.n_tag][tags] ** 2)
                             / max(n_used - len(self.fit.params), 1)))

    def result(self, lams, se, sd, volume: "_SegmentVolumes | None", sigma_c: float | None,
               misfit: float, sigma: float) -> dict:
        """The dict :func:`fit_tag_motion` returns."""
        n_tag, use, err = self.n_tag, self.use, self.err
        tags = use[:n_tag]
        b_rms = float(np.sqrt(np.mean(err[n_tag:][use[n_tag:]] ** 2))) if self.n_boundary else None
        return {"residual_mm": float(np.sqrt(np.mean(err[:n_tag][tags] ** 2))),
                "outliers": int((~tags).sum()), "n_points": int(tags.sum()),
                "lambda": [float(v) for v in lams], "ed_points": self.X[:n_tag][tags],
                "quantity_se": se, "regularised_sd": sd,
                "det_F_unregularised": None if volume is None else volume.det0,
                "boundary_points": int(use[n_tag:].sum()), "boundary_residual_mm": b_rms,
                "boundary_noise_mm": sigma_c, "misfit_mm": misfit, "sigma_mm": sigma}


@dataclass
class _SegmentVolumes:
    """The segments' mean det F of a fit, for the near-incompressibility term.

    Attributes
    ----------
    change : PointQuantities
        A fit -> (k,) J̄_s − 1, each segment's volume-weighted mean det F minus 1.
    seg_vol : (k,) float ndarray
        The segments' volumes (their weights in the risk-chosen term).
    det0 : (float, float, float)
        Volume-weighted mean, min and max of det F over the samples for the fit as it was
        before the regularisation.
    """

    change: PointQuantities
    seg_vol: np.ndarray
    det0: tuple[float, float, float]


def _segment_volumes(fit, volume_samples) -> _SegmentVolumes | None:
    """:class:`_SegmentVolumes` of ``volume_samples`` ((k, 3) ED wall points, (k,) their
    volumes, (k,) their AHA segments) for ``fit`` as it is now; None without samples."""
    if volume_samples is None:
        return None
    V, vol, lab = (np.asarray(v) for v in volume_samples)
    M, seg_vol = segment_mean_matrix(lab, vol)

    def mean_det_minus_one(F):                                     # J̄_s − 1, F (k, n, 3, 3)
        return np.linalg.det(F) @ M.T - 1.0
    dj = np.linalg.det(fit.gradient(V))
    return _SegmentVolumes(PointQuantities(((V, mean_det_minus_one),)), seg_vol,
                           (float(np.average(dj, weights=vol)), float(dj.min()), float(dj.max())))


def _with_volume_change(quantities, volume: _SegmentVolumes | None) -> Callable[[Any], np.ndarray]:
    """A fit -> its ``quantities`` followed by the segments' J̄_s − 1 (with ``volume``)."""
    if isinstance(quantities, PointQuantities) and volume is not None:
        return quantities + volume.change

    def all_quantities(f):
        q = quantities(f)
        return q if volume is None else np.r_[q, volume.change(f)]
    return all_quantities


def _incompressibility(J_v: np.ndarray, S: np.ndarray, fit, volume: _SegmentVolumes | None,
                       noise_mm: float, volume_prior_sd: float | None) -> tuple:
    """The near-incompressibility term of the regularised fit (:func:`incompressibility_term`).

    Parameters
    ----------
    J_v : (k, p) float ndarray
        The derivative of the segments' J̄_s − 1 with respect to the coefficients.
    S : (p, p) float ndarray
        The data term's normal matrix.
    fit : CylindricalMotionFit
    volume : _SegmentVolumes or None
    noise_mm : float
        The fit's σ, mm.
    volume_prior_sd : float or None
        The prior's s (None: the weight is chosen with the ridge weights).

    Returns
    -------
    terms : tuple
        The term whose weight κ :func:`choose_penalty` chooses (risk), or empty.
    fixed : tuple
        The prior's term (weight 1), or empty.
    scale : float
        The term's scale.
    inc_w : (k,) float ndarray or None
        The segments' weights in the term.
    """
    if volume is None:
        return (), (), 0.0, None
    if volume_prior_sd is not None:
        # the prior J̄_s ~ N(1, s²), independent per segment, against the data's σ
        inc_w = np.ones(len(volume.seg_vol))
        scale = len(volume.seg_vol) * volume_prior_weight(noise_mm, volume_prior_sd)
        return (), (incompressibility_term(J_v, volume.change(fit), inc_w, scale),), scale, inc_w
    scale = incompressibility_scale(J_v, volume.seg_vol, S)
    return ((incompressibility_term(J_v, volume.change(fit), volume.seg_vol, scale),), (), scale,
            volume.seg_vol)


def _regularise(state: _TagLineFit, S: np.ndarray, quantities, volume: _SegmentVolumes | None,
                noise_mm: float, volume_prior_sd: float | None) -> tuple:
    """Choose the penalties for the quantities and refine the fit with them.

    Parameters
    ----------
    state : _TagLineFit
        After the unregularised stages; refined in place.
    S : (p, p) float ndarray
        The data term's normal matrix of the last step.
    quantities : callable or PointQuantities
        A fit -> the (k,) quantities the fit is for.
    volume : _SegmentVolumes or None
        The segments' volume change (the near-incompressibility term), if any.
    noise_mm : float
        The fit's σ, mm.
    volume_prior_sd : float or None
        The prior's s.

    Returns
    -------
    lams : list of float
        The penalty weight per group (then κ with a risk-chosen incompressibility term).
    se : (k,) float ndarray
        The unregularised fit's standard errors σ √diag(B S⁻¹ Bᵀ) of the quantities.
    sd : (k,) float ndarray
        The regularised fit's standard deviations σ √diag(B A S A Bᵀ).
    """
    fit = state.fit
    coef = fit.params
    k = len(quantities(fit))
    all_quantities = _with_volume_change(quantities, volume)
    S_inv = np.linalg.pinv(S)
    step_scale = np.sqrt(np.diag(S_inv)) * noise_mm
    J = quantity_jacobian(fit, all_quantities, coef, step_scale)
    B = J[:k]
    # the unregularised fit's standard errors of the quantities, σ √diag(B S⁻¹ Bᵀ): the
    # Cramér–Rao bound of any unbiased estimate within the motion model (S1)
    se = noise_mm * np.sqrt(np.maximum(np.einsum("ka,ab,kb->k", B, S_inv, B), 0.0))
    groups = penalty_groups(fit)
    terms, fixed, scale, inc_w = _incompressibility(J[k:], S, fit, volume, noise_mm,
                                                    volume_prior_sd)
    P, lams = choose_penalty(S, coef, groups, noise_mm, B, terms=terms, fixed=fixed,
                             criterion="evidence" if fixed else "risk")
    A = np.linalg.inv(S + P + state.ridge * np.trace(S) / len(coef) * np.eye(len(coef)))
    sd = noise_mm * np.sqrt(np.maximum(np.einsum("ka,ab,kb->k", B, A @ S @ A, B), 0.0))
    if any(lams) or fixed:
        diag = np.diag(S)
        ridge_P = sum((lam * np.diag(np.where(gr, diag, 0.0)) for lam, gr in zip(lams, groups)),
                      np.zeros((len(coef), len(coef))))
        kappa = lams[-1] if terms else (1.0 if fixed else 0.0)
        _penalised_steps(state, ridge_P, kappa, volume, inc_w, scale, step_scale)
    return lams, se, sd


def _penalised_steps(state: _TagLineFit, ridge_P: np.ndarray, kappa: float,
                     volume: _SegmentVolumes | None, inc_w, scale: float,
                     step_scale: np.ndarray) -> None:
    """:data:`REGULARISED_ITERATIONS` Gauss–Newton steps on data + penalty, the
    incompressibility term (weight ``kappa``) re-linearised at the current coefficients.

    Parameters
    ----------
    state : _TagLineFit
        Refined in place (its ``err`` measured after).
    ridge_P : (p, p) float ndarray
        The ridge penalties.
    kappa : float
        The incompressibility term's weight (0: none).
    volume : _SegmentVolumes or None
        Needed when ``kappa`` is not 0.
    inc_w : (k,) float ndarray or None
        The segments' weights in the term.
    scale : float
        The term's scale.
    step_scale : (p,) float ndarray
        The coefficients' difference steps.
    """
    fit = state.fit
    for _ in range(REGULARISED_ITERATIONS):
        c = fit.params
        P, grad = ridge_P, ridge_P @ c
        if kappa:
            assert volume is not None, "an incompressibility weight needs the segment volumes"
            G = quantity_jacobian(fit, volume.change, c, step_scale)
            Q, r = incompressibility_term(G, volume.change(fit), inc_w, scale)
            P, grad = P + kappa * Q, grad + kappa * r
        state.step(P, grad)
    state.measure()
