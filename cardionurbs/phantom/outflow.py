"""Outflow tracts of the realistic phantom: the RVOT to a pulmonary valve, the LVOT to an aortic valve.

Material (end-diastolic, unbent heart frame) geometry, in the cylindrical coordinates of
:mod:`cardionurbs.phantom.anatomy` (θ = 0 toward the RV, z from the apex to the base plane z_b).

RV outflow tract
----------------
Above the tricuspid plane z = z_b the RV crescent continues in an angular window
``|θ − α| < β(z)`` on its anterior side (θ > 0), which narrows toward the pulmonary valve.
The free wall of the tract is

    R_ot(θ, z) = min( r_b(θ),  r_2(θ, z) + w(z) k(θ, z) ),
    k(θ, z) = (cos(θ − α) − cos β(z)) / (1 − cos β(z))                       (O1)

with r_b(θ) the RV endocardial radius in the base plane (the body's section at its widest,
where its wall is vertical, so the tract continues the body's free wall with a continuous
tangent), r_2 the LV epicardial radius (the tract's inner wall), and w(z) the lumen's radial
width at the window centre. k is 1 at θ = α and changes sign at |θ − α| = β, so the section
{r_2 < r < R_ot} is one crescent whose tips are on the LV epicardium, like the body's. The
window is [θ_a, θ_b] at the base (θ_a = ``rvot_start_deg``, θ_b two degrees inside the body
crescent's anterior tip) and β, w shrink to β_1, w_1 at the valve height H
(ease-out in u = (z − z_b)/H). The epicardium of the tract is (O1) with the body's
epicardial radius, the width w + t and the half-angle β + Δ (t the RV wall thickness,
Δ = t / r_b(α)), so the tract has a free wall of thickness t and side walls at its tips.

The tract ends at the pulmonary valve, a plane through the tract centre at height z_b + H
tilted by τ_p toward the free wall: material points with n_p · (x − c_p) < 0 are below it.

LV outflow tract
----------------
A vertical cylinder of radius ρ whose axis is at distance d from the LV axis at azimuth
α_ao (in the 3-chamber plane), intersected with the LV endocardium continued above the
mitral annulus: D = {s < S_endo(θ, z)} ∩ {|(x, y) − c_ao| < ρ}, up to the aortic valve plane
(through the cylinder axis at z_b + H_ao, tilted by τ_a toward the septal wall). Its septal
wall is the LV endocardium; the rest of its boundary is the aorto-mitral curtain (not
myocardium, not contoured).

The metric definitions (docs/metrics.md) add each tract's lumen below its valve plane to the
cavity, and the RVOT free wall to the RV myocardium.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

import numpy as np

from cardionurbs.errors import PhantomError


@dataclass(frozen=True)
class OutflowTracts:
    """Outflow-tract parameters (angles in degrees, lengths in mm, ratios dimensionless).

    Attributes
    ----------
    rvot_start_deg : float
        θ_a, the septal-side edge of the RVOT window at the base, degrees.
    rvot_height_mm : float
        H, the pulmonary valve centre above the tricuspid plane, mm (10-35).
    rvot_narrowing : float
        β_1 / β_0, the window's narrowing towards the valve (0.3-1).
    rvot_width_mm : float
        w_1, the radial lumen width at the valve, mm.
    pulmonary_tilt_deg : float
        τ_p, the pulmonary valve plane's tilt, degrees (0-25).
    lvot_azimuth_deg : float
        α_ao, the LVOT's azimuth about the LV axis, degrees.
    lvot_offset : float
        d / r_short_endo, the LVOT axis's distance from the LV axis.
    lvot_radius : float
        ρ / r_short_endo, the LVOT cylinder's radius.
    aortic_height_mm : float
        H_ao, the aortic valve centre above z_b, mm (6-25).
    aortic_tilt_deg : float
        τ_a, the aortic valve plane's tilt, degrees (0-20).

    Raises
    ------
    cardionurbs.errors.PhantomError
        A parameter out of its range.
    """

    rvot_start_deg: float = 24.0          # θ_a, septal-side edge of the RVOT window at the base
    rvot_height_mm: float = 20.0          # H, pulmonary valve centre above the tricuspid plane
    rvot_narrowing: float = 0.6           # β_1 / β_0
    rvot_width_mm: float = 14.0           # w_1, radial lumen width at the valve
    pulmonary_tilt_deg: float = 15.0      # τ_p
    lvot_azimuth_deg: float = -45.0       # α_ao (the septal half of the 3-chamber view)
    lvot_offset: float = 0.62             # d / r_short_endo
    lvot_radius: float = 0.36             # ρ / r_short_endo
    aortic_height_mm: float = 13.0        # H_ao, aortic valve centre above z_b
    aortic_tilt_deg: float = 10.0         # τ_a

    def __post_init__(self) -> None:
        if not 10.0 <= self.rvot_height_mm <= 35.0:
            raise PhantomError("rvot_height_mm must be in [10, 35]")
        if not 0.3 <= self.rvot_narrowing <= 1.0:
            raise PhantomError("rvot_narrowing must be in [0.3, 1]")
        if not 0.0 <= self.pulmonary_tilt_deg <= 25.0 or not 0.0 <= self.aortic_tilt_deg <= 20.0:
            raise PhantomError("valve tilts must be in [0, 25] (pulmonary) and [0, 20] (aortic) degrees")
        if not (0.0 < self.lvot_radius < 0.62 * self.lvot_offset and self.lvot_offset < 0.8):
            # (the cylinder then spans less than ±39° about its azimuth: the 2- and 4-chamber
            # views, 45° away, pass beside it)
            raise PhantomError("the LVOT cylinder must lie off the LV axis: 0 < radius < 0.62 offset, "
                               "offset < 0.8")
        if not 6.0 <= self.aortic_height_mm <= 25.0:
            raise PhantomError("aortic_height_mm must be in [6, 25]")

    def to_dict(self) -> dict:
        """JSON-safe fields.

        Returns
        -------
        dict of str to float
            Field -> value (degrees, mm, ratios).
        """
        return {k: float(v) for k, v in asdict(self).items()}


def draw_outflow(rng: np.random.Generator) -> OutflowTracts:
    """Outflow tracts drawn per subject from ranges that give an RVOT of roughly 10–15 % of the
    RV end-diastolic volume, a 25–30 mm pulmonary and an about 20 mm LVOT diameter.

    Parameters
    ----------
    rng : numpy.random.Generator
        The subject's generator.
    Returns
    -------
    OutflowTracts
        The drawn parameters.
    """
    return OutflowTracts(rvot_start_deg=float(rng.uniform(22.0, 28.0)),
                         rvot_height_mm=float(rng.uniform(18.0, 24.0)),
                         rvot_narrowing=float(rng.uniform(0.55, 0.7)),
                         rvot_width_mm=float(rng.uniform(12.0, 16.0)),
                         pulmonary_tilt_deg=float(rng.uniform(8.0, 20.0)),
                         lvot_offset=float(rng.uniform(0.61, 0.64)),
                         lvot_radius=float(rng.uniform(0.34, 0.37)),
                         aortic_height_mm=float(rng.uniform(11.0, 15.0)),
                         aortic_tilt_deg=float(rng.uniform(5.0, 15.0)))


# ----------------------------------------------------------------- RVOT
@dataclass(frozen=True)
class RvotFrame:
    """Derived RVOT geometry of one anatomy (radians, mm).

    Attributes
    ----------
    z_base : float
        The base height z_b, mm.
    height : float
        H, mm.
    alpha : float
        The window's centre angle, rad.
    beta0, beta1 : float
        The window's half-width at the base and at the valve, rad.
    delta : float
        Angular thickness of the side walls, rad.
    w0, w1 : float
        The radial lumen width at the base and at the valve, mm.
    wall : float
        The RV wall thickness, mm.
    plane_point : tuple of float
        A point of the pulmonary valve plane (material), mm.
    plane_normal : tuple of float
        Its unit normal.
    """

    z_base: float
    height: float
    alpha: float
    beta0: float
    beta1: float
    delta: float        # angular thickness of the side walls
    w0: float
    w1: float
    wall: float
    plane_point: tuple  # pulmonary valve plane (material), point and unit normal
    plane_normal: tuple

    def profile(self, z, epi: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(β(z), w(z)) of eq. (O1): ease-out from the base values to the valve values over H.

        Parameters
        ----------
        z : float or ndarray
            Material height, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        Returns
        -------
        beta : ndarray
            The window half-width β(z), rad.
        w : ndarray
            The lumen width w(z), mm.
        """
        u = np.minimum(np.maximum((np.asarray(z, dtype=float) - self.z_base) / self.height, 0.0), 1.0)
        m = 1.0 - (1.0 - u) ** 2
        beta = self.beta0 + (self.beta1 - self.beta0) * m
        w = self.w0 + (self.w1 - self.w0) * m
        if epi:
            return beta + self.delta, w + self.wall
        return beta, w

    def window(self, z, epi: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(θ_lo, θ_hi) of the tract's crescent at material height z (> z_b).

        Parameters
        ----------
        z : float or ndarray
            Material height, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        Returns
        -------
        theta_lo, theta_hi : ndarray
            The window's angular limits, rad.
        """
        beta = self.profile(z, epi)[0]
        return self.alpha - beta, self.alpha + beta

    def top(self, x, y) -> np.ndarray:
        """Height of the pulmonary valve plane above material (x, y), mm.

        Parameters
        ----------
        x, y : float or ndarray
            Material coordinates, mm.
        Returns
        -------
        ndarray
            The plane's height z there, mm.
        """
        c, n = np.asarray(self.plane_point), np.asarray(self.plane_normal)
        return c[2] - (n[0] * (np.asarray(x) - c[0]) + n[1] * (np.asarray(y) - c[1])) / n[2]


def rvot_base_radius(anatomy, theta, epi: bool = False) -> np.ndarray:
    """r_b(θ): the RV body's endo- (epi-)cardial radius in the base plane, mm (the cap of the
    tract's radius, eq. O1).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    theta : float or ndarray
        Material angle θ, rad.
    epi : bool, optional
        The epicardial shell (else the endocardial).
    Returns
    -------
    ndarray
        r_b(θ), mm.
    """
    return _rb(anatomy, theta, epi)


def _rb(anatomy, theta, epi: bool) -> np.ndarray:
    """r_b(θ): the RV body's endo- (epi-)cardial radius in the base plane, mm."""
    th = np.asarray(theta, dtype=float)
    return np.sqrt(anatomy.rv_p(th, epi, np.full(th.shape, anatomy.z_base)))


@functools.lru_cache(maxsize=64)
def rvot_frame(anatomy) -> RvotFrame:
    """The RVOT window, widths and valve plane of an anatomy with outflow tracts."""
    ot = anatomy.shape.outflow
    zb = anatomy.z_base
    lo, hi = (float(v[0]) for v in anatomy.rv_sector(np.array([zb]), False))
    hi_e = float(anatomy.rv_sector(np.array([zb]), True)[1][0])
    ta, tb = np.radians(ot.rvot_start_deg), hi - np.radians(2.0)
    if tb - ta < np.radians(20.0) or ta < lo:
        raise PhantomError("the RV crescent at the base is too narrow for an outflow tract")
    alpha, beta0 = 0.5 * (ta + tb), 0.5 * (tb - ta)
    delta = float(min(anatomy.rv_wall / _rb(anatomy, alpha, False), 0.8 * (hi_e - tb)))
    th = np.linspace(ta, tb, 181)
    gap = _rb(anatomy, th, False) - np.sqrt(anatomy.s_lv_epi(np.full(th.shape, zb), th))
    w0 = 1.3 * float(gap.max())
    w1 = min(ot.rvot_width_mm, 0.9 * w0)
    zv = zb + ot.rvot_height_mm
    r_c = float(np.sqrt(anatomy.s_lv_epi(np.array([zv]), np.array([alpha]))[0])) + 0.5 * w1
    tau = np.radians(ot.pulmonary_tilt_deg)
    # tilted toward the free wall (outward at α): the valve plane is lower on the free-wall side
    normal = (np.sin(tau) * np.cos(alpha), np.sin(tau) * np.sin(alpha), np.cos(tau))
    point = (r_c * np.cos(alpha), r_c * np.sin(alpha), zv)
    return RvotFrame(z_base=zb, height=ot.rvot_height_mm, alpha=float(alpha), beta0=float(beta0),
                     beta1=float(ot.rvot_narrowing * beta0), delta=delta, w0=w0, w1=float(w1),
                     wall=float(anatomy.rv_wall), plane_point=tuple(float(v) for v in point),
                     plane_normal=tuple(float(v) for v in normal))


def rvot_radius(anatomy, theta, z, epi: bool = False, s_epi=None, r_b=None) -> np.ndarray:
    """R_ot(θ, z) of eq. (O1) (endo- or epicardial), mm; below r_2 outside the window. ``s_epi``:
    the LV epicardial S(θ, z), ``r_b``: :func:`rvot_base_radius` at θ, when the caller has them.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    theta : float or ndarray
        Material angle θ, rad.
    z : float or ndarray
        Material height, mm.
    epi : bool, optional
        The epicardial shell (else the endocardial).
    s_epi : ndarray, optional
        The LV epicardial S(θ, z), mm².
    r_b : ndarray, optional
        :func:`rvot_base_radius` at θ, mm.
    Returns
    -------
    ndarray
        R_ot(θ, z), mm.
    """
    fr = rvot_frame(anatomy)
    theta = np.asarray(theta, dtype=float)
    z = np.asarray(z, dtype=float)
    beta, w = fr.profile(z, epi)
    cb = np.cos(beta)
    k = (np.cos(theta - fr.alpha) - cb) / (1.0 - cb)
    s2 = anatomy.s_lv_epi(z, theta) if s_epi is None else s_epi
    r2 = np.sqrt(np.maximum(s2, 0.0))
    return np.minimum(_rb(anatomy, theta, epi) if r_b is None else r_b, r2 + w * k)


def s_rvot_pair(anatomy, theta, z, s_epi=None, r_b=None) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`s_rvot` endo, epi) at the same (θ, z), sharing cos(θ − α) and the LV epicardium;
    ``r_b``: the pair of base radii when the caller has them. The same values as two calls.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    theta : float or ndarray
        Material angle θ, rad.
    z : float or ndarray
        Material height, mm.
    s_epi : ndarray, optional
        The LV epicardial S(θ, z), mm².
    r_b : tuple of ndarray, optional
        The (endo, epi) base radii at θ, mm.
    Returns
    -------
    s_endo, s_epi : ndarray
        The squared radii of both shells, mm².
    """
    fr = rvot_frame(anatomy)
    theta = np.asarray(theta, dtype=float)
    z = np.asarray(z, dtype=float)
    s2 = anatomy.s_lv_epi(z, theta) if s_epi is None else s_epi
    r2 = np.sqrt(np.maximum(s2, 0.0))
    c = np.cos(theta - fr.alpha)
    out = []
    for k, epi in enumerate((False, True)):
        beta, w = fr.profile(z, epi)
        cb = np.cos(beta)
        rb = _rb(anatomy, theta, epi) if r_b is None else r_b[k]
        out.append(np.maximum(np.minimum(rb, r2 + w * ((c - cb) / (1.0 - cb))), 0.0) ** 2)
    return out[0], out[1]


def s_rvot(anatomy, theta, z, epi: bool = False, s_epi=None, r_b=None) -> np.ndarray:
    """Squared radius of the RVOT endo- (epi-)cardial shell, mm² (below S_epi outside the tract).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    theta : float or ndarray
        Material angle θ, rad.
    z : float or ndarray
        Material height, mm.
    epi : bool, optional
        The epicardial shell (else the endocardial).
    s_epi : ndarray, optional
        The LV epicardial S(θ, z), mm².
    r_b : ndarray, optional
        :func:`rvot_base_radius` at θ, mm.
    Returns
    -------
    ndarray
        The squared radius, mm².
    """
    r = rvot_radius(anatomy, theta, z, epi, s_epi, r_b)
    return np.maximum(r, 0.0) ** 2


def rvot_top_term(anatomy, x, y, z) -> np.ndarray:
    """Signed height above the pulmonary valve plane (mm; negative below it) of material points.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    x, y, z : float or ndarray
        Material coordinates, mm.
    Returns
    -------
    ndarray
        z − top(x, y), mm.
    """
    return np.asarray(z, dtype=float) - rvot_frame(anatomy).top(x, y)


# ----------------------------------------------------------------- LVOT
@dataclass(frozen=True)
class LvotFrame:
    """Derived LVOT geometry of one anatomy (mm): the cylinder and the aortic valve plane.

    Attributes
    ----------
    center : tuple of float
        The cylinder axis (x, y), mm.
    radius : float
        ρ, mm.
    z_base : float
        The base height z_b, mm.
    plane_point : tuple of float
        A point of the aortic valve plane (material), mm.
    plane_normal : tuple of float
        Its unit normal.
    """

    center: tuple       # cylinder axis (x, y), mm
    radius: float       # ρ, mm
    z_base: float
    plane_point: tuple  # aortic valve plane (material)
    plane_normal: tuple

    def top(self, x, y) -> np.ndarray:
        """Height of the aortic valve plane above material (x, y).

        Parameters
        ----------
        x, y : float or ndarray
            Material coordinates, mm.

        Returns
        -------
        ndarray
            The plane's height z there, mm.
        """
        c, n = np.asarray(self.plane_point), np.asarray(self.plane_normal)
        return c[2] - (n[0] * (np.asarray(x) - c[0]) + n[1] * (np.asarray(y) - c[1])) / n[2]


@functools.lru_cache(maxsize=64)
def lvot_frame(anatomy) -> LvotFrame:
    ot = anatomy.shape.outflow
    a = np.radians(ot.lvot_azimuth_deg)
    R = anatomy.r_short_endo
    d, rho = ot.lvot_offset * R, ot.lvot_radius * R
    c = (d * np.cos(a), d * np.sin(a))
    tau = np.radians(ot.aortic_tilt_deg)
    # tilted toward the septal wall of the tract: the valve plane is lower there
    normal = (np.sin(tau) * np.cos(a), np.sin(tau) * np.sin(a), np.cos(tau))
    point = (c[0], c[1], anatomy.z_base + ot.aortic_height_mm)
    return LvotFrame(center=tuple(float(v) for v in c), radius=float(rho), z_base=anatomy.z_base,
                     plane_point=tuple(float(v) for v in point),
                     plane_normal=tuple(float(v) for v in normal))


def lvot_cylinder_term(anatomy, x, y) -> np.ndarray:
    """Signed distance (mm, negative inside) of material (x, y) to the LVOT cylinder.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    x, y : float or ndarray
        Material coordinates, mm.
    Returns
    -------
    ndarray
        The signed distance, mm.
    """
    fr = lvot_frame(anatomy)
    return np.hypot(np.asarray(x) - fr.center[0], np.asarray(y) - fr.center[1]) - fr.radius


def lvot_top_term(anatomy, x, y, z) -> np.ndarray:
    """Signed height above the aortic valve plane (mm; negative below it) of material points.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts.
    x, y, z : float or ndarray
        Material coordinates, mm.

    Returns
    -------
    ndarray
        z − top(x, y), mm.
    """
    return np.asarray(z, dtype=float) - lvot_frame(anatomy).top(x, y)


def lvot_boundary(anatomy, phi, z, iters: int = 12) -> np.ndarray:
    """Material (x, y) of the LVOT section boundary at height z along the rays from the cylinder axis
    at angles φ (broadcast together): the ray meets the cylinder (t = ρ) or, first, the LV
    endocardium (the root of |c + t u|² = S_endo(θ, z) in (0, ρ), Illinois regula falsi). (…, 2).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (material frame, mm).
    phi : float or ndarray
        Ray angles about the cylinder axis, rad.
    z : float or ndarray
        Material height, mm.
    iters : int, optional
        Regula falsi iterations.
    Returns
    -------
    ndarray, shape (..., 2)
        The boundary's (x, y), mm.

    Raises
    ------
    cardionurbs.errors.PhantomError
        The LVOT axis leaves the LV endocardium.
    """
    fr = lvot_frame(anatomy)
    phi, z = np.broadcast_arrays(np.asarray(phi, dtype=float), np.asarray(z, dtype=float))
    cx, cy = fr.center
    ux, uy = np.cos(phi), np.sin(phi)

    def g(t):
        x, y = cx + t * ux, cy + t * uy
        return x * x + y * y - anatomy.s_lv_endo(z, np.arctan2(y, x))

    a, b = np.zeros(phi.shape), np.full(phi.shape, fr.radius)
    fa, fb = g(a), g(b)
    if np.any(fa >= 0):
        raise PhantomError("the LVOT axis leaves the LV endocardium (LVOT too far off the axis)")
    out = fb > 0
    if np.any(out):
        ao, bo, fao, fbo = a[out], b[out], fa[out], fb[out]
        zo, uxo, uyo = z[out], ux[out], uy[out]
        side = np.zeros(len(ao))
        for _ in range(iters):
            t = bo - fbo * (bo - ao) / (fbo - fao)
            x, y = cx + t * uxo, cy + t * uyo
            ft = x * x + y * y - anatomy.s_lv_endo(zo, np.arctan2(y, x))
            left = ft < 0
            # Illinois: halve the retained end's value when the same end is kept twice
            fbo = np.where(left & (side == 1), 0.5 * fbo, fbo)
            fao = np.where(~left & (side == -1), 0.5 * fao, fao)
            ao, fao = np.where(left, t, ao), np.where(left, ft, fao)
            bo, fbo = np.where(left, bo, t), np.where(left, fbo, ft)
            side = np.where(left, 1, -1)
        b = b.copy()
        b[out] = np.where(np.abs(fao) < np.abs(fbo), ao, bo)
    return np.stack([cx + b * ux, cy + b * uy], axis=-1)


# ----------------------------------------------------------------- annuli
def _fixed_point_z(surface_xy, top, z0: np.ndarray, iters: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """z = top(x(z), y(z)) for boundary points (x, y) = surface_xy(z): fixed-point iteration (the
    valve tilt times the boundary's slope is far below 1), then the points (…, 3)."""
    z = np.array(z0, dtype=float)
    for _ in range(iters):
        xy = surface_xy(z)
        z = top(xy[..., 0], xy[..., 1])
    xy = surface_xy(z)
    return np.concatenate([xy, z[..., None]], axis=-1), z


@functools.lru_cache(maxsize=64)
def pulmonary_ring(anatomy, n: int = 48) -> np.ndarray:
    """Material points of the pulmonary annulus (the tract's endocardial section on the valve
    plane), free wall from θ_lo to θ_hi then back along the inner wall: (2n − 2, 3), closed."""
    fr = rvot_frame(anatomy)
    v = np.linspace(0.0, 1.0, n)

    def free(z):
        lo, hi = fr.window(z)
        th = lo + (hi - lo) * v
        r = np.maximum(rvot_radius(anatomy, th, z), 0.0)
        return np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)

    def sept(z):
        lo, hi = fr.window(z)
        th = lo + (hi - lo) * v[::-1][1:-1]
        r = np.sqrt(np.maximum(anatomy.s_lv_epi(z, th), 0.0))
        return np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)

    zv = fr.z_base + fr.height
    a, _ = _fixed_point_z(free, fr.top, np.full(n, zv))
    b, _ = _fixed_point_z(sept, fr.top, np.full(n - 2, zv))
    ring = np.concatenate([a, b])
    ring.setflags(write=False)
    return ring


@functools.lru_cache(maxsize=64)
def aortic_ring(anatomy, n: int = 96) -> np.ndarray:
    """Material points of the aortic annulus (the LVOT section on the aortic valve plane), (n, 3)."""
    fr = lvot_frame(anatomy)
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    pts, _ = _fixed_point_z(lambda z: lvot_boundary(anatomy, phi, z), fr.top,
                            np.full(n, fr.plane_point[2]))
    pts.setflags(write=False)
    return pts
