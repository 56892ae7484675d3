"""3-D Lagrangian strain from tag material points (docs/metrics.md, Regional function).

Material points (:mod:`cardionurbs.analysis.material`) are the same tissue at
every frame, so their displacements ED → frame sample the motion directly.

Motion field
    The tracked points are mapped in cylindrical coordinates: ED (q = r², θ, ζ)
    about the ED long axis (ζ along ê = base → apex, θ right-handed about ê)
    to (r'², θ' − θ, ζ') about the frame's long axis (its e1 the ED e1 turned
    onto the new axis). Each of the three is fitted by linear least squares (a
    tiny ridge, 1e-8 of the normal matrix's trace; points the first fit misses by
    more than :data:`OUTLIER_MM` and 4 × the median are left out and the fit
    repeated once) on the tensor-product basis

        P_a(ζ̃) · q̃^b · {1, cos mθ, sin mθ}_{m ≤ 2},  a ≤ 3, b ≤ 1,
        with the q̃ terms (b = 1) only for a ≤ 1                           (S1)

    (Legendre P_a of the height scaled to [−1, 1], q̃ the squared radius
    standardised over the points): 30 functions per component. Squared radii
    make a wall that keeps its volume while the cavity shrinks (r'² − r² the
    same across the wall) exactly linear; twist, shortening, a cos 2θ
    flattening and a rigid turn of the axis are in the span too.

    Fitted to the tag lines, the terms constant across the wall (b = 0) of r'²
    and θ' − θ go up to harmonic 6 (:data:`TAG_LINE_ORDERS`; the ζ' component and
    the transmural terms keep theirs): a real LV section departs from its ellipse
    (papillary muscles, a flattened septum, a hypokinetic territory) in harmonics
    3 and up, and so does how far each part of its wall moves; with harmonics up
    to 2 the map cannot tell six 60° segments apart. On realistic phantoms (shape
    modes, an apex bent off the axis) the map of (S1) left 0.4–0.7 mm of misfit on
    exact tags, which its transmural terms absorbed (Err off by up to 60 points).

    The fit of the material points is the start; with the frame's tag lines it is
    refined by orthogonal-distance regression of the tag points to the moved ED
    tag planes (:mod:`cardionurbs.analysis.tag_motion`), which resolves the
    transmural gradient (one point per ~1 mm through the wall, not one material
    point per tag spacing).

Deformation gradient
    F = ∂x/∂X by the chain rule through (S1)::

        F = [e_r', r' e_θ', ê'] · ∂(r', θ', ζ')/∂(q, θ, ζ) · [2r e_r; e_θ / r; ê]    (S2)

    (columns: the frame's cylindrical tangents at the mapped point; rows of
    the last factor: the gradients of q, θ, ζ at the ED point).

Strain
    Green–Lagrange E = ½ (FᵀF − I); Ecc = 100 cᵀEc, Ell = 100 lᵀEl,
    Err = 100 rᵀEr with r the outward unit normal of the ED endocardial
    surface at its point nearest the material point (averaged over 10 mm of
    surface, :func:`smoothed_normals`, :data:`DIRECTION_SMOOTHING_MM`), c the circumferential
    direction e_θ made orthogonal to r, and l = r × c (the base → apex
    direction projected off the normal, up to sign). det F is reported as
    the incompressibility check (1 for myocardium); with noisy tags the fit carries
    the prior that each segment's mean det F is N(1, s²) with a stated s
    (:mod:`cardionurbs.analysis.tag_motion`, near-incompressibility as a prior), so the
    check is then the det F of the unregularised fit, reported beside it.

Per segment: the volume mean of the fitted strain over the ED myocardium of
AHA segment k (:mod:`cardionurbs.analysis.aha`), sampled between the
reconstructed endo- and epicardium (:func:`myocardium_samples`) within the
height range of the tracked points (the fit is not extrapolated beyond the
tagged tissue) and at least :data:`AXIS_CLEARANCE_MM` from the long axis at ED and,
moved by the fitted map, from the frame's long axis (the near-axis rule);
global: the mean of the segment values 1–16.
"""

from __future__ import annotations

import copy

import numpy as np
from numpy.polynomial import legendre
from scipy.spatial import cKDTree

from cardionurbs.analysis.tag_surfaces import axis_frame
from cardionurbs.geometry import averaged_normals

NAN = float("nan")
STRAIN_KINDS = ("Ecc", "Ell", "Err")
STRAIN_COLUMNS = tuple(f"{k}_AHA_{s} (%)" if s != "Global" else f"{k}_Global (%)"
                       for k in STRAIN_KINDS for s in [*range(1, 17), "Global"])
#: basis orders of eq. S1 for the fit of the material points: Legendre in height, powers of
#: radius, Fourier harmonics
ORDERS = (3, 1, 2)
#: the transmural (q̃) terms: Legendre order and harmonic at most
TRANSMURAL_ORDERS = (1, 2)
#: the orders of the fit to the tag lines (:mod:`cardionurbs.analysis.tag_motion`): harmonics
#: up to 6 in the terms constant across the wall. Six 60° segments per ring need harmonics
#: up to 3 to be told apart, and an LV section's departure from its ellipse (papillary
#: muscles, a flattened septum, a regional motion defect) and how far each part of the wall
#: moves vary on the scale of a segment or less (a harmonic m resolves 180°/m). The SA tag
#: grid samples the in-plane motion (r'², θ') every tag spacing (~7 mm, ≥ 25 samples round
#: the wall) at every tagged slice, so these terms are well determined, unlike the
#: transmural ones (one or two tag lines across the wall), which keep their orders, and the
#: height order, which the slices (~8 mm apart) limit
TAG_LINE_ORDERS = (3, 1, 6)
#: the highest harmonic of the ζ' (longitudinal) component in the tag-line fit: only the
#: tags of the long-axis views measure it, i.e. at the 2 × 3 half-planes of three views
#: (2-, 3- and 4-chamber), which determine at most 5 functions of θ
AXIAL_HARMONICS = 2
#: a tracked point farther than this (mm, and 4 x the median) from the first fit is left out
OUTLIER_MM = 1.5
MIN_POINTS = 80
#: radius (mm) over which endocardial normals are averaged for the wall-thickness rays
NORMAL_SMOOTHING_MM = 6.0
#: radius (mm) over which endocardial normals are averaged for the strain directions (r, c, l).
#: A tilt α of r raises Ecc by about α² (Err − Ecc) ≈ 85 α² strain points, always upward, so
#: the residual tilt of a surface fitted to noisy contours biases Ecc even where it barely
#: changes a thickness (T / cos α): with 0.5 px contour noise the mean segment Ecc error was
#: +0.25 points at 6 mm (24 noisy phantoms, reports/validation-regional.md). The cost: on a
#: smooth LV-sized spheroid the 10 mm average tilts the normal by ~1° on average where
#: strain is measured (α² · 85 < 0.1 point), and noise-free segment strains change by ≤ 0.2
DIRECTION_SMOOTHING_MM = 10.0
#: the near-axis rule: myocardium nearer the long axis than this (mm) at ED, or whose image at
#: the frame is nearer the frame's long axis than this (the apical tip around the cavity apex),
#: is left out of the segment means: the cylindrical chart (S1) is singular on the axis, where
#: ∂r'/∂(r'²) = 1/(2r') amplifies any error of the fitted r'² (the phantom truth applies the
#: same rule with the exact motion)
AXIS_CLEARANCE_MM = 10.0
#: wall samples (about) used to choose the regularisation of the tag-line fit
RISK_SAMPLES = 600


def aligned_frame(e1: np.ndarray, apex: np.ndarray, base: np.ndarray):
    """(e1', e2', e') about the axis apex–base, with e1' the ED e1 made orthogonal to e'
    (the minimal turn of the ED frame onto the new axis).

    Parameters
    ----------
    e1 : (3,) ndarray
        The ED frame's first axis.
    apex, base : (3,) ndarray
        The frame's long axis, mm.

    Returns
    -------
    e1, e2, e : (3,) ndarray
    """
    e = np.asarray(apex, float) - np.asarray(base, float)
    e /= np.linalg.norm(e)
    a = e1 - (e1 @ e) * e
    a /= np.linalg.norm(a)
    return a, np.cross(e, a), e


def cylindrical(X: np.ndarray, apex: np.ndarray, frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(r, θ, ζ) of (n, 3) points in the axis frame (e1, e2, e) through ``apex``.

    Parameters
    ----------
    X : (n, 3) ndarray
        Points, mm.
    apex : (3,) ndarray
        The axis origin, mm.
    frame : (e1, e2, e)
        The axis frame (:func:`~cardionurbs.analysis.tag_surfaces.axis_frame`).

    Returns
    -------
    r : (n,) ndarray
        Distance from the axis, mm.
    theta : (n,) ndarray
        Angle, rad.
    zeta : (n,) ndarray
        Height along e, mm.
    """
    e1, e2, e = frame
    d = np.asarray(X, float) - apex
    zeta = d @ e
    return np.linalg.norm(d - np.outer(zeta, e), axis=1), np.arctan2(d @ e2, d @ e1), zeta


class CylindricalMotionFit:
    """The least-squares map (S1) of ED (q = r², θ, ζ) to the frame's (r'², θ' − θ, ζ').

    Fitted twice: gross outliers (farther than max(:data:`OUTLIER_MM`, 4 × the median
    error)) are left out of the second fit; ``outliers`` counts them, ``residual_mm`` is
    the RMS error of the others (mm).

    Parameters
    ----------
    X : (n, 3) ndarray
        ED points (the material points), scanner mm.
    x : (n, 3) ndarray
        Their positions at the frame, mm.
    ed_axis : (apex (3,), base (3,))
        The ED long axis, mm.
    axis : (apex (3,), base (3,)) or None
        The frame's long axis; None: ``ed_axis``.
    orders : (int, int, int)
        Polynomial orders in ζ and q and the harmonic order in θ of (S1).
    ridge : float
        Relative ridge weight keeping the normal equations regular.
    transmural : (int, int)
        The ζ and θ orders of the transmural (q-dependent) terms.
    """

    def __init__(self, X: np.ndarray, x: np.ndarray, ed_axis: tuple, axis: tuple | None = None,
                 orders: tuple[int, int, int] = ORDERS, ridge: float = 1e-8,
                 transmural: tuple[int, int] = TRANSMURAL_ORDERS) -> None:
        self._set_basis(orders, transmural)
        self.apex0 = np.asarray(ed_axis[0], float)
        self.frame0 = axis_frame(*ed_axis)
        axis = ed_axis if axis is None else axis
        self.apex1 = np.asarray(axis[0], float)
        self.frame1 = aligned_frame(self.frame0[0], *axis)
        r, th, zeta = cylindrical(X, self.apex0, self.frame0)
        r1, th1, zeta1 = cylindrical(x, self.apex1, self.frame1)
        q = r * r
        self.q0, self.sq = float(q.mean()), float(q.std()) or 1.0
        self.z0, self.sz = float(0.5 * (zeta.max() + zeta.min())), float(0.5 * np.ptp(zeta)) or 1.0
        target = np.column_stack([r1 * r1, np.angle(np.exp(1j * (th1 - th))), zeta1])
        A = self._design(q, th, zeta, derivatives=False)[0]
        use = np.ones(len(X), bool)
        for _ in range(2):          # fit, leave out gross outliers (mistracked points), refit
            N = A[use].T @ A[use]
            N += ridge * np.trace(N) / len(N) * np.eye(len(N))
            self.coef = np.linalg.solve(N, A[use].T @ target[use])      # (n_basis, 3)
            err = np.linalg.norm(self._position(A @ self.coef, th) - x, axis=1)
            use = err <= max(OUTLIER_MM, 4.0 * float(np.median(err)))
        self.outliers = int((~use).sum())
        self.residual_mm = float(np.sqrt(np.mean(err[use] ** 2)))

    def _set_basis(self, orders: tuple[int, int, int], transmural: tuple[int, int],
                   axial_harmonics: int | None = None) -> None:
        """The terms of (S1): all P_a · {1, cos mθ, sin mθ} (a ≤ orders[0], m ≤ orders[2]) and the
        transmural ones P_a · q̃ · {…} only for a ≤ transmural[0], m ≤ transmural[1]; the
        ζ' component's terms only up to harmonic ``axial_harmonics`` (default all). ``free``:
        the mask of the coefficients in use over ``coef.T.ravel()`` (component-major), the
        others held at 0; :attr:`params` are the free ones."""
        self.orders, self.transmural = tuple(orders), tuple(transmural)
        pa, pb, pm = orders
        a, b, m = np.meshgrid(np.arange(pa + 1), np.arange(pb + 1), np.arange(2 * pm + 1), indexing="ij")
        keep = ((b == 0) | ((a <= transmural[0]) & (m <= 2 * transmural[1]))).ravel()
        self._index = (a.ravel()[keep], b.ravel()[keep], m.ravel()[keep])
        axial = self._index[2] <= 2 * (pm if axial_harmonics is None else axial_harmonics)
        self.free = np.r_[np.ones(2 * len(axial), bool), axial]

    @property
    def params(self) -> np.ndarray:
        """The free coefficients (component-major: ``coef.T.ravel()[free]``)."""
        return self.coef.T.reshape(-1)[self.free]

    @params.setter
    def params(self, value: np.ndarray) -> None:
        c = np.zeros(self.free.size)
        c[self.free] = value
        self.coef = c.reshape(3, -1).T

    def expanded(self, orders: tuple[int, int, int], transmural: tuple[int, int],
                 axial_harmonics: int | None = None) -> "CylindricalMotionFit":
        """A copy on a basis containing this one (same charts and scalings; the arguments as
        :meth:`_set_basis`'s) whose added terms start at zero: the same map, free to refine on
        more data (the tag lines).

        Parameters
        ----------
        orders : (int, int, int)
            The larger basis' orders.
        transmural : (int, int)
            Its transmural orders.
        axial_harmonics : int or None
            The ζ' component's highest harmonic; None: all.

        Returns
        -------
        CylindricalMotionFit
        """
        old = list(zip(*self._index))
        out = copy.copy(self)
        out._set_basis(orders, transmural, axial_harmonics)
        where = {t: j for j, t in enumerate(zip(*out._index))}
        if any(t not in where for t in old):
            raise ValueError(f"orders {orders}, {transmural} do not contain {self.orders}, {self.transmural}")
        out.coef = np.zeros((len(where), 3))
        out.coef[[where[t] for t in old]] = self.coef
        out.coef[~out.free.reshape(3, -1).T] = 0.0
        return out

    def _position(self, m: np.ndarray, th: np.ndarray) -> np.ndarray:
        e1, e2, e = self.frame1
        rr = np.sqrt(np.maximum(m[:, 0], 0.0))
        t = th + m[:, 1]
        return (self.apex1 + rr[:, None] * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
                + m[:, 2:3] * e)

    def _factors(self, q, th, zeta, derivatives: bool = True):
        """The factors of the basis (S1) at (q, θ, ζ): Legendre in height L (n, a), powers of
        the radius R (n, b), harmonics T (n, 2m + 1: 1, cos θ, sin θ, cos 2θ, …) and (with
        ``derivatives``) their derivatives dL/dζ, dR/dq, dT/dθ."""
        pa, pb, pm = self.orders
        zt = (zeta - self.z0) / self.sz
        qt = (q - self.q0) / self.sq
        eye = np.eye(pa + 1)
        L = np.stack([legendre.legval(zt, eye[a]) for a in range(pa + 1)], axis=1)
        R = np.stack([qt ** b for b in range(pb + 1)], axis=1)
        k = np.arange(1, pm + 1)
        c, sn = np.cos(np.outer(th, k)), np.sin(np.outer(th, k))
        T = np.empty((len(th), 2 * pm + 1))
        T[:, 0], T[:, 1::2], T[:, 2::2] = 1.0, c, sn
        if not derivatives:
            return L, R, T
        dL = np.stack([legendre.legval(zt, legendre.legder(eye[a])) for a in range(pa + 1)],
                      axis=1) / self.sz
        dR = np.stack([b * qt ** max(b - 1, 0) for b in range(pb + 1)], axis=1) / self.sq
        dT = np.zeros_like(T)
        dT[:, 1::2], dT[:, 2::2] = -k * sn, k * c
        return L, R, T, dL, dR, dT

    def _design(self, q, th, zeta, derivatives: bool = True):
        """Basis values and (with ``derivatives``) derivatives d/dq, d/dθ, d/dζ: (n, n_basis) arrays."""
        ia, ib, ic = self._index
        if not derivatives:
            L, R, T = self._factors(q, th, zeta, False)
            return (self._basis_values(L, R, T),)
        L, R, T, dL, dR, dT = self._factors(q, th, zeta)
        LT, Rb = L[:, ia] * T[:, ic], R[:, ib]
        return LT * Rb, LT * dR[:, ib], L[:, ia] * dT[:, ic] * Rb, dL[:, ia] * T[:, ic] * Rb

    def _basis_values(self, L, R, T) -> np.ndarray:
        """The (n, b) basis values of (S1) from its factors."""
        ia, ib, ic = self._index
        return L[:, ia] * T[:, ic] * R[:, ib]

    def _mapped(self, X: np.ndarray, derivatives: bool = True, factors: bool = False):
        """(r, θ, ζ) of ED points X and the map's values (q', θ' − θ, ζ') there, each (n, 3), with
        (``derivatives``) their derivatives d/dq, d/dθ, d/dζ: Σ coef · basis contracted factor
        by factor (harmonics, then height and radius), never forming the (n, b) design;
        ``factors``: also the basis factors (:meth:`_factors`) as a last item."""
        want_factors = factors
        r, th, zeta = cylindrical(X, self.apex0, self.frame0)
        basis = self._factors(r * r, th, zeta, derivatives)
        L, R, T = basis[:3]
        pa, pb, pm = self.orders
        C: np.ndarray = np.zeros((2 * pm + 1, pa + 1, pb + 1, 3))
        ia, ib, ic = self._index
        C[ic, ia, ib] = self.coef
        C = C.reshape(2 * pm + 1, -1)
        shape = (len(th), (pa + 1) * (pb + 1), 3)
        W = (T @ C).reshape(shape)                               # Σ_m T_m coef[a, b, m]

        def contract(La, Rb, W):                                 # Σ_ab La_a Rb_b W_abc
            return np.einsum("nk,nkc->nc", (La[:, :, None] * Rb[:, None, :]).reshape(len(th), -1), W)
        values = contract(L, R, W)
        if not derivatives:
            return ((r, th, zeta), values) + ((basis,) if want_factors else ())
        dL, dR, dT = basis[3:]
        d_theta = contract(L, R, (dT @ C).reshape(shape))
        return ((r, th, zeta), values, (contract(L, dR, W), d_theta, contract(dL, R, W))) + (
            (basis,) if want_factors else ())

    def image_radius(self, X: np.ndarray) -> np.ndarray:
        """r' (mm): the fitted distance of the images of ED points X (n, 3) from the frame's
        long axis (the square root of the fitted r'², 0 where that is negative).

        Parameters
        ----------
        X : (n, 3) ndarray
            ED points, mm.

        Returns
        -------
        (n,) ndarray
            mm.
        """
        m = self._mapped(X, derivatives=False)[1]
        return np.sqrt(np.maximum(m[:, 0], 0.0))

    def position(self, X: np.ndarray) -> np.ndarray:
        """The fitted image x (n, 3) of ED points X (n, 3).

        Parameters
        ----------
        X : (n, 3) ndarray
            ED points, mm.

        Returns
        -------
        (n, 3) ndarray
            mm.
        """
        (_, th, _), m = self._mapped(X, derivatives=False)
        return self._position(m, th)

    def linearisation(self, X: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], np.ndarray]:
        """(x (n, 3), (T (n, 3, 3), D (n, b)), F (n, 3, 3)) at ED points X: the image, its
        derivative with respect to the coefficients in factored form — ∂x/∂coef[j, c] =
        T[:, :, c] · D[:, j], with T = ∂x/∂(q', θ', ζ') and D the basis values (of which
        :attr:`free` selects the coefficients in use) — and the deformation gradient.

        Parameters
        ----------
        X : (n, 3) ndarray
            ED points, mm.

        Returns
        -------
        x : (n, 3) ndarray
            mm.
        derivative : ((n, 3, 3) ndarray, (n, b) ndarray)
            (T, D).
        F : (n, 3, 3) ndarray
        """
        (r, th, _), m, dm, factors = self._mapped(X, factors=True)
        D = self._basis_values(*factors[:3])                    # the derivatives stay contracted
        e1, e2, e = self.frame1
        rr = np.sqrt(np.maximum(m[:, 0], 1.0))
        t = th + m[:, 1]
        c, s = np.cos(t)[:, None], np.sin(t)[:, None]
        dpos = np.stack([(c * e1 + s * e2) / (2.0 * rr[:, None]), rr[:, None] * (-s * e1 + c * e2),
                         np.broadcast_to(e, (len(t), 3))], axis=2)      # (n, 3, 3): ∂x/∂(q', θ', ζ')
        return self._position(m, th), (dpos, D), self._gradient(r, th, m, dm)

    def perturbed_gradients(self, X: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """F (2p, n, 3, 3) at ED points X (n, 3) for the p free coefficients (:attr:`params`)
        moved one at a time by +steps[j] (rows 0 … p − 1) and by −steps[j] (rows p … 2p − 1):
        the evaluation points of central differences with respect to the coefficients. The
        map (S1) is linear in its coefficients, so moving coefficient j by h moves the map's
        values and derivatives at X by h times basis function j's; F follows from them by
        (S2), all perturbations in one batch.

        Parameters
        ----------
        X : (n, 3) ndarray
            ED points, mm.
        steps : (p,) ndarray
            The step of each free coefficient.

        Returns
        -------
        (2p, n, 3, 3) ndarray
        """
        r, th, zeta = cylindrical(X, self.apex0, self.frame0)
        D = self._design(r * r, th, zeta)                        # values, d/dq, d/dθ, d/dζ: (n, b)
        nb = D[0].shape[1]
        comp, basis = np.divmod(np.flatnonzero(self.free), nb)   # params -> (component, basis)
        p = len(comp)
        h = np.r_[steps, -np.asarray(steps, float)]
        rows, comp2 = np.arange(2 * p), np.r_[comp, comp]
        moved = []
        for A in D:
            base = A @ self.coef                                # (n, 3) at the current coefficients
            out = np.repeat(base[None], 2 * p, axis=0)          # (2p, n, 3)
            out[rows, :, comp2] += h[:, None] * A[:, np.r_[basis, basis]].T
            moved.append(out)
        return self._gradient(r, th, moved[0], moved[1:])

    def radius_and_gradient(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`image_radius`, :meth:`gradient`) of ED points X (n, 3), the map evaluated once.

        Parameters
        ----------
        X : (n, 3) ndarray
            ED points, mm.

        Returns
        -------
        radius : (n,) ndarray
            mm.
        F : (n, 3, 3) ndarray
        """
        (r, th, _), m, dm = self._mapped(X)
        return np.sqrt(np.maximum(m[:, 0], 0.0)), self._gradient(r, th, m, dm)

    def gradient(self, X: np.ndarray) -> np.ndarray:
        """F = ∂x/∂X (n, 3, 3), Cartesian, by the chain rule through (S1).

        Parameters
        ----------
        X : (n, 3) ndarray
            ED points, mm.

        Returns
        -------
        (n, 3, 3) ndarray
        """
        (r, th, _), m, dm = self._mapped(X)
        return self._gradient(r, th, m, dm)

    def _gradient(self, r, th, m, dm) -> np.ndarray:
        """F (…, n, 3, 3) from the map's values m and derivatives dm = (d/dq, d/dθ, d/dζ), each
        (…, n, 3) (a leading batch axis: the same n points under several maps), at ED points
        with cylindrical (r, θ) (n,)."""
        J = np.stack(dm, axis=-1)                                # (…, n, 3 out, 3 in)
        J[..., 1, 1] += 1.0                                     # θ' = θ + g2
        rr = np.sqrt(np.maximum(m[..., 0], 1.0))                # r' >= 1 mm (never near the axis)
        J[..., 0, :] /= (2.0 * rr)[..., None]                   # rows: r', θ', ζ'
        e1, e2, e = self.frame0
        c, s = np.cos(th)[:, None], np.sin(th)[:, None]
        dX = np.stack([2 * r[:, None] * (c * e1 + s * e2), (-s * e1 + c * e2) / r[:, None],
                       np.broadcast_to(e, (len(r), 3))], axis=1)              # rows: ∇q, ∇θ, ∇ζ
        f1, f2, fe = self.frame1
        t1 = th + m[..., 1]
        c1, s1 = np.cos(t1)[..., None], np.sin(t1)[..., None]
        dx = np.stack([c1 * f1 + s1 * f2, rr[..., None] * (-s1 * f1 + c1 * f2),
                       np.broadcast_to(fe, c1.shape[:-1] + (3,))], axis=-1)   # columns: ∂x/∂(r',θ',ζ')
        return dx @ (J @ dX)


def green_lagrange(F: np.ndarray) -> np.ndarray:
    """E = ½ (FᵀF − I) for (n, 3, 3) F.

    Parameters
    ----------
    F : (..., 3, 3) ndarray
        Deformation gradients.

    Returns
    -------
    (..., 3, 3) ndarray
    """
    return 0.5 * (np.einsum("nki,nkj->nij", F, F) - np.eye(3))


def cardiac_directions(X: np.ndarray, endo_points: np.ndarray, endo_normals: np.ndarray,
                       apex: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Unit (c, l, r) rows (n, 3, 3) at ED points: r the outward normal of the nearest
    endocardial sample, c the circumferential direction orthogonal to r, l = r × c.

    Parameters
    ----------
    X : (n, 3) ndarray
        ED wall points, mm.
    endo_points : (k, 3) ndarray
        ED endocardial samples, mm.
    endo_normals : (k, 3) ndarray
        Their outward unit normals.
    apex, base : (3,) ndarray
        The ED long axis, mm.

    Returns
    -------
    (n, 3, 3) ndarray
    """
    _, idx = cKDTree(endo_points).query(X)
    r = endo_normals[idx]
    e1, e2, e = axis_frame(apex, base)
    d = X - apex
    th = np.arctan2(d @ e2, d @ e1)
    c = -np.sin(th)[:, None] * e1 + np.cos(th)[:, None] * e2
    c = c - np.einsum("ni,ni->n", c, r)[:, None] * r
    c /= np.linalg.norm(c, axis=1)[:, None]
    return np.stack([c, np.cross(r, c), r], axis=1)


def directional_strains(E: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(…, n, 3) strains in % along the rows of ``dirs`` (n, 3, 3): 100 dᵀEd (Cartesian E
    (…, n, 3, 3) and d; a leading batch axis of E shares the directions).

    Parameters
    ----------
    E : (..., n, 3, 3) ndarray
        Green–Lagrange strains.
    dirs : (n, 3, 3) ndarray
        Unit directions as rows.

    Returns
    -------
    (..., n, 3) ndarray
        %.
    """
    return 100.0 * np.einsum("...nki,...nij,...nkj->...nk", dirs, E, dirs)


def segment_strain_quantities(points: np.ndarray, directions: np.ndarray, labels: np.ndarray,
                              weights: np.ndarray):
    """The segment strains at ED wall ``points`` as a function of F:
    :class:`~cardionurbs.analysis.tag_motion.PointQuantities` giving, for F (k, n, 3, 3), the
    weighted means (k, 3 s) over the segments 1–16 present (segment-major, then Ecc, Ell,
    Err) of the strains along ``directions`` (:func:`directional_strains` of the Green–Lagrange
    strain, every F of the batch at once).

    Parameters
    ----------
    points : (n, 3) ndarray
        ED wall points, mm.
    directions : (n, 3, 3) ndarray
        Their (c, l, r) directions (:func:`cardiac_directions`).
    labels : (n,) ndarray of int
        Their AHA segments.
    weights : (n,) ndarray
        Their volumes, mm³.

    Returns
    -------
    PointQuantities
    """
    from cardionurbs.analysis.tag_motion import PointQuantities, segment_mean_matrix
    seg = (labels >= 1) & (labels <= 16)
    M = np.zeros((len(np.unique(labels[seg])), len(labels)))
    M[:, seg] = segment_mean_matrix(labels[seg], weights[seg])[0]

    def reduce(F):
        v = directional_strains(green_lagrange(F.reshape(-1, 3, 3)).reshape(F.shape), directions)
        return np.einsum("sn,knc->ksc", M, v).reshape(len(F), -1)
    return PointQuantities(((points, reduce),))


def strain_columns(values: np.ndarray, labels: np.ndarray, weights: np.ndarray | None = None
                   ) -> tuple[dict[str, float], dict]:
    """Ecc/Ell/Err per segment and global from per-point (n, 3) strains (%), labels and
    (volume) weights.

    Parameters
    ----------
    values : (n, 3) ndarray
        Per-point (Ecc, Ell, Err), %.
    labels : (n,) ndarray of int
        AHA segments.
    weights : (n,) ndarray or None
        Volumes; None: equal.

    Returns
    -------
    columns : dict of str to float
        docs/metrics.md strain column -> %.
    counts : dict
        Points per segment.
    """
    out: dict[str, float] = {}
    w = np.ones(len(labels)) if weights is None else np.asarray(weights, float)
    counts = {k: int((labels == k).sum()) for k in range(1, 17)}
    for j, kind in enumerate(STRAIN_KINDS):
        seg = [float(np.average(values[labels == k, j], weights=w[labels == k])) if counts[k] else NAN
               for k in range(1, 17)]
        for k, v in zip(range(1, 17), seg):
            out[f"{kind}_AHA_{k} (%)"] = v
        fin = [v for v in seg if np.isfinite(v)]
        out[f"{kind}_Global (%)"] = float(np.mean(fin)) if fin else NAN
    return out, counts


def myocardium_samples(endo_points: np.ndarray, endo_normals: np.ndarray, thickness: np.ndarray,
                       area: np.ndarray, apex: np.ndarray, base: np.ndarray, layers: int = 5,
                       grid: tuple[tuple[int, int], np.ndarray] | None = None,
                       subdivide: int = 1):
    """Points filling the ED myocardium and their volumes (mm³): ``layers`` points along each
    endocardial thickness ray (mid-points of equal steps), each with the ray's area x step x
    r / r_endo (the circumferential widening of the wall outward).

    ``grid``: ((n_u, n_v), flat grid index of each ray) when the rays come from a (u, v) grid
    of the endocardium (:func:`cardionurbs.analysis.thickness.surface_samples`, v along the
    long axis); each ray's cell is then split into ``subdivide`` rays along v, their foot
    points and ray vectors (thickness x normal) interpolated linearly from the neighbouring
    ray on that side (extrapolated from the other side where there is none). A mean over a
    height range (:func:`tag_strain`) is then taken over thin slices: with one ray per
    ~3 mm of height, the layers of a ray inclined to the axis (near the apex) cross a range's
    ends at heights several mm apart, so a range of a few mm kept the inner layers of some
    rays and the outer layers of others (+4 strain points of Err in apical segments on a
    noise-free phantom, whose exact motion gave the same error at those samples).

    Parameters
    ----------
    endo_points : (k, 3) ndarray
        Ray feet on the ED endocardium, mm.
    endo_normals : (k, 3) ndarray
        Ray directions (outward unit normals).
    thickness : (k,) ndarray
        Wall thickness along each ray, mm (NaN rays left out).
    area : (k,) ndarray
        Each ray's endocardial area, mm².
    apex, base : (3,) ndarray
        The ED long axis, mm.
    layers : int
        Points per ray.
    grid : ((int, int), (k,) ndarray) or None
        As above.
    subdivide : int
        As above.

    Returns
    -------
    points : (m, 3) ndarray
        mm.
    volumes : (m,) ndarray
        mm³.
    """
    ok = np.isfinite(thickness)
    P, N, t, A = endo_points[ok], endo_normals[ok], thickness[ok], area[ok]
    if grid is not None and subdivide > 1:
        P, N, t, A = _subdivide_rays(P, N * t[:, None], A, grid[0], np.asarray(grid[1])[ok],
                                     subdivide)
    e = (base - apex) / np.linalg.norm(base - apex)

    def radius(x):
        d = x - apex
        return np.linalg.norm(d - np.outer(d @ e, e), axis=1)
    r0 = np.maximum(radius(P), 1e-6)
    pts, vol = [], []
    for j in range(layers):
        x = P + ((j + 0.5) / layers * t)[:, None] * N
        pts.append(x)
        vol.append(A * t / layers * radius(x) / r0)
    return np.concatenate(pts), np.concatenate(vol)


def _subdivide_rays(P: np.ndarray, ray: np.ndarray, A: np.ndarray, shape: tuple[int, int],
                    index: np.ndarray, k: int):
    """Rays (foot P (n, 3), vector ``ray`` (n, 3), area A) on cells of an (n_u, n_v) grid
    (flat ``index``) split into k along v: (P, unit normals, lengths, areas) of the n k rays."""
    n_v = shape[1]
    where = np.full(shape[0] * n_v, -1)
    where[index] = np.arange(len(index))
    iv = index % n_v

    def neighbour(step):
        return np.where((iv + step >= 0) & (iv + step < n_v), where[np.clip(index + step, 0, where.size - 1)], -1)
    lo, hi = neighbour(-1), neighbour(1)
    tau = (np.arange(k) + 0.5) / k - 0.5                       # offsets within the cell, in cells
    V = np.hstack([P, ray])                                    # foot and ray vector, interpolated together
    out = []
    for s in tau:
        side, other = (hi, lo) if s > 0 else (lo, hi)
        # the neighbour on the offset's side, or the mirror image of the one on the other side
        dV = np.where((side >= 0)[:, None], V[side] - V, np.where((other >= 0)[:, None], V - V[other], 0.0))
        out.append(V + abs(s) * dV)
    P2, R2 = np.split(np.concatenate(out), 2, axis=1)
    t2 = np.linalg.norm(R2, axis=1)
    return P2, R2 / np.where(t2 > 0, t2, 1.0)[:, None], t2, np.tile(A / k, k)


def smoothed_normals(points: np.ndarray, normals: np.ndarray, weights: np.ndarray,
                     radius_mm: float = NORMAL_SMOOTHING_MM) -> np.ndarray:
    """Unit normals averaged (weighted by ``weights``, e.g. area) over the samples within
    ``radius_mm`` of each sample.

    The radial direction enters Ecc and Ell at second order: a normal tilted by α moves
    Ecc by about α² (Err − Ecc), so the scatter of a surface fitted to noisy contours
    biases Ecc up and Err down (≈ 1.7 strain points at 0.5 px contour noise). Averaging
    over a disc of 6 mm (:data:`NORMAL_SMOOTHING_MM`, the thickness rays) — small against
    the ≥ 20 mm radii of curvature of the LV wall, so a smooth surface's normal changes by
    < 0.1° — removes most of it; 10 mm (:data:`DIRECTION_SMOOTHING_MM`, the strain
    directions) most of the rest. (:func:`cardionurbs.geometry.averaged_normals`, which the
    phantom's strain truth uses with the same radius.)

    Parameters
    ----------
    points : (k, 3) ndarray
        Samples, mm.
    normals : (k, 3) ndarray
        Their unit normals.
    weights : (k,) ndarray
        Their weights.
    radius_mm : float
        The averaging radius, mm.

    Returns
    -------
    (k, 3) ndarray
    """
    return averaged_normals(points, normals, weights, radius_mm)


def tag_strain(material, frame: int, apex: np.ndarray, base: np.ndarray, endo_points: np.ndarray,
               endo_normals: np.ndarray, aha, axis: tuple | None = None,
               myocardium: tuple[np.ndarray, np.ndarray] | None = None,
               tag_lines: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
               noise_mm: float = 0.0, incompressibility: bool | str = "prior",
               volume_prior_sd: float | None = None, boundary=(), deformation=None,
               misfit_noise: bool = True) -> dict | None:
    """Strain ED → ``frame`` from the tracked material points.

    Parameters
    ----------
    material : MaterialPoints
        The tracked material points.
    frame : int
        The frame the strain is measured at (relative to ED).
    apex, base : (3,) float ndarray
        The ED long axis, mm.
    endo_points, endo_normals : (m, 3) float ndarray
        The ED endocardium's points and normals, for the strain directions
        (:func:`cardiac_directions`).
    aha
        The AHA segments at ED (``aha.segments(points)``).
    axis : (apex, base) at ``frame``, optional
        Default ED's.
    myocardium : tuple, optional
        (points, volumes) filling the ED wall (:func:`myocardium_samples`): the fitted
        field is averaged over those between the most apical and most basal tracked points
        (a volume mean over the tagged myocardium); default: the material points. It may
        carry the samples' strain directions and AHA segments as third and fourth items
        (:func:`cardiac_directions` with these ``endo_points``/``endo_normals``/axis, and
        ``aha.segments``): both are per point and the same at every frame, so a time course
        computes them once.
    tag_lines : (points (n, 3), ED plane normals (n, 3), offsets (n,)), optional
        The frame's tag points (:mod:`cardionurbs.analysis.tag_motion`): the fit of the
        material points is then refined on them by orthogonal-distance regression (method
        "tag lines"); else the material points alone are fitted (method "material points").
    noise_mm : float
        The tag tracking noise (the ED tag-plane residual), which sets the regularisation
        of that fit; with it the result also has "segment_se": {kind: {segment: standard
        error (strain points)}} of the unregularised fit (a Cramér–Rao bound for unbiased
        estimates in (S1)), "segment_sd" (the same for the regularised fit: its noise,
        without its bias), and "det_F_unregularised" (volume mean over the wall samples the
        penalty is evaluated on) with "det_F_unregularised_range": det F of the fit before
        the penalties, the incompressibility check that the near-incompressibility penalty
        does not pull towards 1.
    incompressibility : bool or str
        How the noisy-tag fit uses the near-incompressibility of myocardium
        (:mod:`cardionurbs.analysis.tag_motion`): "prior" (or True; the default) — the
        Bayesian prior J̄_s ~ N(1, s²) on each segment's mean det F with the stated s
        (:data:`~cardionurbs.analysis.tag_motion.VOLUME_PRIOR_SD`), the ridge weights chosen
        by the evidence; "risk" — a penalty whose weight the unbiased risk estimate chooses
        with the ridge weights (the estimator before the prior); False — the ridge
        penalties alone.
    volume_prior_sd : float, optional
        The prior's s (default :data:`~cardionurbs.analysis.tag_motion.VOLUME_PRIOR_SD`;
        other values only to show how much the result depends on it).
    boundary : sequence of Boundary
        The frame's contour points on the LV endo- and epicardium with those surfaces at ED
        (:class:`~cardionurbs.analysis.tag_motion.Boundary`): the wall's material
        boundaries join the tag-line fit as data (term (T3) of
        :mod:`cardionurbs.analysis.tag_motion`).
    deformation : callable, optional
        (points, frame) -> F (n, 3, 3), used in place of the fitted map's F for the strains
        (validation: a phantom's exact motion,
        :meth:`cardionurbs.phantom.generate.Phantom.deformation_gradient`; the fit, the
        near-axis rule and the averaging unchanged).
    misfit_noise : bool
        The fit's σ is the larger of ``noise_mm`` and the tag points' misfit
        (:func:`~cardionurbs.analysis.tag_motion.fit_tag_motion`; "sigma_mm" in the
        result); False: ``noise_mm`` alone, for comparison.

    Returns
    -------
    dict or None
        {"columns", "det_F" (mean), "det_F_range", "n_points", "counts",
        "fit_residual_mm", "method", ...}; None with too few points.
    """
    from cardionurbs.analysis.tag_motion import MIN_TAG_POINTS
    ok = material.tracked(material.ed_frame, frame)
    if ok.sum() < MIN_POINTS:
        return None
    X = material.positions[material.ed_frame][ok]
    x = material.positions[frame][ok]
    apex, base = np.asarray(apex, float), np.asarray(base, float)
    fit = CylindricalMotionFit(X, x, (apex, base), axis)
    info = {"n_points": int(ok.sum()), "outliers": fit.outliers, "fit_residual_mm": fit.residual_mm,
            "method": "material points"}
    Y, vol, dirs, labels = _wall_samples(X, apex, base, myocardium, endo_points, endo_normals, aha)
    if tag_lines is not None and len(tag_lines[0]) >= MIN_TAG_POINTS:
        fit, tag_info = _refine_on_tag_lines(
            fit, tag_lines, (Y, dirs, labels, np.ones(len(Y)) if vol is None else vol),
            noise_mm=noise_mm, incompressibility=incompressibility,
            volume_prior_sd=volume_prior_sd, boundary=boundary, misfit_noise=misfit_noise)
        info.update(tag_info)
    return _frame_strains(fit, frame, (Y, vol, dirs, labels), deformation, info)


def _wall_samples(X: np.ndarray, apex: np.ndarray, base: np.ndarray, myocardium, endo_points,
                  endo_normals, aha) -> tuple:
    """The points :func:`tag_strain` averages over, with their volumes, strain directions
    and AHA segments.

    Parameters
    ----------
    X : (n, 3) float ndarray
        The tracked material points at ED, mm.
    apex, base : (3,) float ndarray
        The ED long axis, mm.
    myocardium : tuple or None
        (points, volumes[, directions, segments]) filling the ED wall
        (:func:`myocardium_samples`); None: the material points themselves.
    endo_points, endo_normals : ndarray
        The ED endocardium, for the directions (:func:`cardiac_directions`).
    aha
        The AHA segments (``aha.segments(points)``).

    Returns
    -------
    Y : (k, 3) float ndarray
        The samples: those of ``myocardium`` between the most apical and most basal
        tracked points and clear of the axis, else ``X``.
    vol : (k,) float ndarray or None
        Their volumes (None for the material points).
    dirs : (k, 3, 3) float ndarray
        Their circumferential, longitudinal and radial directions.
    labels : (k,) int ndarray
        Their AHA segments.
    """
    Y, vol = X, None
    if myocardium is not None:
        e = (base - apex) / np.linalg.norm(base - apex)
        h, hy = (X - apex) @ e, (myocardium[0] - apex) @ e
        radial = myocardium[0] - apex - np.outer(hy, e)
        inside = ((hy >= h.min()) & (hy <= h.max())
                  & (np.linalg.norm(radial, axis=1) >= AXIS_CLEARANCE_MM))
        Y, vol = myocardium[0][inside], myocardium[1][inside]
        if len(myocardium) == 4:
            return Y, vol, myocardium[2][inside], myocardium[3][inside]
    return Y, vol, cardiac_directions(Y, endo_points, endo_normals, apex, base), aha.segments(Y)


def _risk_subsample(fit: CylindricalMotionFit, Y: np.ndarray) -> np.ndarray:
    """About :data:`RISK_SAMPLES` of the samples ``Y`` (indices), evenly spread and clear of
    the axis under the material-point fit: where the segment strains the regularisation is
    chosen for are evaluated."""
    sub = np.arange(0, len(Y), max(1, len(Y) // (2 * RISK_SAMPLES)))
    sub = sub[fit.image_radius(Y[sub]) >= AXIS_CLEARANCE_MM]
    return sub[::max(1, len(sub) // RISK_SAMPLES)]


def _refine_on_tag_lines(fit: CylindricalMotionFit,
                         tag_lines: tuple[np.ndarray, np.ndarray, np.ndarray], samples: tuple, *,
                         noise_mm: float, incompressibility: bool | str,
                         volume_prior_sd: float | None, boundary, misfit_noise: bool
                         ) -> tuple[CylindricalMotionFit, dict]:
    """The material-point fit expanded and refined on the frame's tag lines
    (:func:`~cardionurbs.analysis.tag_motion.fit_tag_motion`), regularised for the segment
    strains over a subsample of the wall.

    Parameters
    ----------
    fit : CylindricalMotionFit
        The material-point fit.
    tag_lines : (points (n, 3), ED plane normals (n, 3), offsets (n,))
        The frame's tag points.
    samples : (Y, dirs, labels, weights)
        The wall samples (:func:`_wall_samples`), their weights (volumes, or 1).
    noise_mm, incompressibility, volume_prior_sd, boundary, misfit_noise
        As :func:`tag_strain`.

    Returns
    -------
    fit : CylindricalMotionFit
        The refined fit.
    info : dict
        The fit's summary: method, n_tag_points, penalty, tag_outliers, fit_residual_mm,
        sigma_mm, and where they apply the boundary points, the prior's s, the
        unregularised det F and the segments' standard errors.
    """
    from cardionurbs.analysis.tag_motion import VOLUME_PRIOR_SD, fit_tag_motion
    Y, dirs, labels, w = samples
    # the quantities the regularisation is chosen for: the segment strains over a
    # subsample of the wall, the near-axis rule applied with the material-point fit
    sub = _risk_subsample(fit, Y)
    segment_strains = segment_strain_quantities(Y[sub], dirs[sub], labels[sub], w[sub])
    if incompressibility not in (True, False, None, "prior", "risk"):
        raise ValueError(f"incompressibility: 'prior', 'risk' or False, not {incompressibility!r}")
    prior_sd = None
    if incompressibility in (True, "prior"):
        prior_sd = VOLUME_PRIOR_SD if volume_prior_sd is None else float(volume_prior_sd)
    fit = fit.expanded(TAG_LINE_ORDERS, TRANSMURAL_ORDERS, AXIAL_HARMONICS)
    out = fit_tag_motion(fit, *tag_lines, noise_mm=noise_mm, quantities=segment_strains,
                         volume_samples=(Y[sub], w[sub], labels[sub]) if incompressibility else None,
                         volume_prior_sd=prior_sd, boundary=boundary, misfit_noise=misfit_noise)
    present = [k for k in range(1, 17) if (labels[sub] == k).any()]
    return fit, _tag_fit_info(out, prior_sd, present)


def _tag_fit_info(out: dict, prior_sd: float | None, present: list[int]) -> dict:
    """The summary :func:`tag_strain` reports of a tag-line fit.

    Parameters
    ----------
    out : dict
        :func:`~cardionurbs.analysis.tag_motion.fit_tag_motion`'s result.
    prior_sd : float or None
        The volume prior's s used (None: no prior).
    present : list of int
        The AHA segments of the subsample, ascending (the order of the per-segment
        standard errors).

    Returns
    -------
    dict
    """
    info = dict(method="tag lines", n_tag_points=out["n_points"], penalty=out["lambda"],
                tag_outliers=out["outliers"], fit_residual_mm=out["residual_mm"],
                sigma_mm=out["sigma_mm"])
    if out["boundary_points"]:
        info.update(boundary_points=out["boundary_points"],
                    boundary_residual_mm=out["boundary_residual_mm"],
                    boundary_noise_mm=out["boundary_noise_mm"])
    if prior_sd is not None and out["lambda"]:
        info["volume_prior_sd"] = prior_sd
    if out["det_F_unregularised"] is not None:
        info["det_F_unregularised"] = out["det_F_unregularised"][0]
        info["det_F_unregularised_range"] = list(out["det_F_unregularised"][1:])
    for key, name in (("quantity_se", "segment_se"), ("regularised_sd", "segment_sd")):
        if out[key] is not None:     # per segment present, (Ecc, Ell, Err) each
            se = out[key].reshape(-1, 3)
            info[name] = {kind: {str(k): float(v) for k, v in zip(present, se[:, j])}
                          for j, kind in enumerate(STRAIN_KINDS)}
    return info


def _frame_strains(fit: CylindricalMotionFit, frame: int, samples: tuple, deformation,
                   info: dict) -> dict:
    """The strain columns at ``frame`` of the fit's F (or ``deformation``'s) over the wall
    samples clear of the axis at that frame (the near-axis rule with the final fit).

    Parameters
    ----------
    fit : CylindricalMotionFit
        The final fit.
    frame : int
    samples : (Y, vol, dirs, labels)
        The wall samples (:func:`_wall_samples`).
    deformation : callable or None
        (points, frame) -> F (n, 3, 3), in place of the fit's.
    info : dict
        The fit's summary; ``near_axis_excluded`` is added.

    Returns
    -------
    dict
        {"columns", "det_F", "det_F_range", "counts", **info}.
    """
    Y, vol, dirs, labels = samples
    radius, F = fit.radius_and_gradient(Y)
    if deformation is not None:
        F = deformation(Y, frame)
    clear = radius >= AXIS_CLEARANCE_MM
    info["near_axis_excluded"] = int((~clear).sum())
    dirs, labels = dirs[clear], labels[clear]
    vol = None if vol is None else vol[clear]
    F = F[clear]
    vals = directional_strains(green_lagrange(F), dirs)
    cols, counts = strain_columns(vals, labels, vol)
    det = np.linalg.det(F)
    return {"columns": cols, "det_F": float(det.mean()),
            "det_F_range": [float(det.min()), float(det.max())], "counts": counts, **info}
