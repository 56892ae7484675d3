"""End-diastolic biventricular anatomy of the analytic phantom (heart frame, mm).

Heart frame
-----------
Right-handed Cartesian ``(x, y, z)`` in mm. ``z`` is the LV long axis, from the
LV epicardial apex (the origin) toward the base; ``x`` points from the LV axis
toward the RV; ``y = z × x``. Cylindrical coordinates about the axis are
``(s, θ, z)`` with ``s = r² = x² + y²`` (the squared radius is the natural
coordinate of the motion, see :mod:`cardionurbs.phantom.motion`).

LV (cardiac-geometries naming)
------------------------------
Endocardium and epicardium are confocal-free prolate spheroids sharing the
centre ``(0, 0, z_c)`` with ``z_c = r_long_epi`` (so the epicardial apex is at
the origin):

    s_endo(z) = r_short_endo² (1 − ((z − z_c) / r_long_endo)²)       (A1)
    s_epi(z)  = r_short_epi²  (1 − ((z − z_c) / r_long_epi)²)

both truncated by the base (mitral valve) plane ``z = z_b = z_c + base_height``.
The LV cavity is ``{s < s_endo(z), z < z_b}``; the LV myocardium is
``{s_endo ≤ s ≤ s_epi, 0 ≤ z ≤ z_b}``.

RV
--
The RV endocardial and epicardial shells are "sheared" half-ellipsoids whose
equator lies in the base plane. Their section at height ``z`` is an ellipse
with centre ``(x_c g(z), 0)`` and semi-axes ``(A g(z), B g(z))``:

    g(z) = sqrt(1 − ((z − z_b) / C)²),  z_b − C ≤ z ≤ z_b                (A2)

(endo: ``A = r_free_endo``, ``B = r_wrap_endo``, ``C = r_long_rv_endo``;
epi: each semi-axis plus the free-wall thickness; both with centre offset
``x_c = rv_offset · r_free_endo < A`` so that the LV axis lies inside every
section). Because the axis is inside the ellipse, each ray from the axis at
angle θ leaves the section exactly once, at radius ``g(z) ρ(θ)`` with ρ the
far root of the ray–ellipse quadratic:

    ρ(θ) = (b + sqrt(b² − a c)) / a,  a = cos²θ/A² + sin²θ/B²,
           b = x_c cosθ / A²,  c = x_c²/A² − 1 < 0                      (A3)

so the RV shells are ``s = S_rv(θ, z) = g(z)² P(θ)`` with ``P = ρ²``. The RV
cavity is the part of the RV endocardial shell outside the LV epicardium,
``{s_epi(z) < s < S_rv_endo(θ, z)}`` (a crescent wrapped on the septum); the
RV free wall is ``{max(s_epi, S_rv_endo) ≤ s ≤ S_rv_epi}``. Validation checks
that ``P`` decreases monotonically in |θ| so that each section's crescent is
one sector ``|θ| < θ_e(z)``.

Volumes (method A of the truth)
-------------------------------
LV: closed-form truncated spheroid volumes (A4). RV: polar quadrature

    V = ∫ dz ∫_{−θ_e}^{θ_e} ½ (g² P(θ) − s_epi(z)) dθ                   (A5)

with the sector edge θ_e(z) solved by bisection to machine precision and
Gauss–Legendre rules on smooth intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cardionurbs.errors import PhantomError

_GL_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [0, 1]."""
    if n not in _GL_CACHE:
        x, w = np.polynomial.legendre.leggauss(n)
        _GL_CACHE[n] = (0.5 * (x + 1.0), 0.5 * w)
    return _GL_CACHE[n]


def spheroid_section_s(z: np.ndarray, r_short: float, r_long: float, z_center: float) -> np.ndarray:
    """Squared radius of a prolate spheroid's section at height z (eq. A1); 0 outside it."""
    u = (np.asarray(z, dtype=float) - z_center) / r_long
    return np.where(np.abs(u) < 1.0, r_short * r_short * (1.0 - u * u), 0.0)


def truncated_spheroid_volume(r_short: float, r_long: float, z_center: float, z_top: float) -> float:
    """Volume (mm³) of a spheroid below the plane z = z_top (eq. A4).

    V = π a² [(z_top − z_lo) − ((z_top − z_c)³ − (z_lo − z_c)³) / (3 c²)], z_lo = z_c − c.
    """
    z_top = min(max(z_top, z_center - r_long), z_center + r_long)
    lo, hi = -r_long, z_top - z_center
    return float(np.pi * r_short ** 2 * ((hi - lo) - (hi ** 3 - lo ** 3) / (3.0 * r_long ** 2)))


def ellipse_far_radius_sq(theta: np.ndarray, a_free: float, b_wrap: float, x_center: float) -> np.ndarray:
    """P(θ) = ρ(θ)²: squared distance from the origin to the ellipse boundary along θ (eq. A3)."""
    ct, st = np.cos(theta), np.sin(theta)
    a = ct * ct / a_free ** 2 + st * st / b_wrap ** 2
    b = x_center * ct / a_free ** 2
    c = x_center ** 2 / a_free ** 2 - 1.0
    rho = (b + np.sqrt(b * b - a * c)) / a
    return rho * rho


@dataclass(frozen=True)
class Anatomy:
    """End-diastolic biventricular geometry (all lengths mm), see the module docstring.

    Attributes follow cardiac-geometries where they overlap: ``r_short_endo``,
    ``r_short_epi``, ``r_long_endo``, ``r_long_epi``; ``base_height`` is the
    base-plane height above the spheroids' equator. RV: ``r_free_endo``
    (semi-axis toward the free wall), ``r_wrap_endo`` (semi-axis along the
    septum), ``r_long_rv_endo``, ``rv_wall`` (free-wall thickness),
    ``rv_offset`` (section centre offset as a fraction of ``r_free_endo``).
    """

    r_short_endo: float
    r_short_epi: float
    r_long_endo: float
    r_long_epi: float
    base_height: float
    r_free_endo: float
    r_wrap_endo: float
    r_long_rv_endo: float
    rv_wall: float
    rv_offset: float

    def __post_init__(self) -> None:
        for name in ("r_short_endo", "r_short_epi", "r_long_endo", "r_long_epi", "r_free_endo",
                     "r_wrap_endo", "r_long_rv_endo", "rv_wall"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise PhantomError(f"anatomy parameter {name} must be a positive length in mm, got {v!r}")
        if self.r_short_epi <= self.r_short_endo:
            raise PhantomError(f"LV wall thickness (r_short_epi - r_short_endo = "
                               f"{self.r_short_epi - self.r_short_endo:g} mm) must be positive and "
                               f"smaller than r_short_epi")
        if self.r_long_epi <= self.r_long_endo:
            raise PhantomError("r_long_epi must exceed r_long_endo (apical wall thickness > 0)")
        if not (0 <= self.base_height < 0.9 * self.r_long_endo):
            raise PhantomError(f"base_height must be in [0, 0.9 r_long_endo), got {self.base_height!r}")
        if not (0 <= self.rv_offset < 1):
            raise PhantomError(f"rv_offset must be in [0, 1), got {self.rv_offset!r}")
        if self.r_long_rv_endo >= self.z_base:
            raise PhantomError("r_long_rv_endo must be shorter than the LV (RV apex above the LV apex)")

    # ------------------------------------------------------------ LV
    @property
    def z_center(self) -> float:
        return self.r_long_epi

    @property
    def z_base(self) -> float:
        """Height of the base (mitral and tricuspid valve) plane above the apex, mm."""
        return self.r_long_epi + self.base_height

    @property
    def z_endo_apex(self) -> float:
        """Height of the LV endocardial apex (apical wall thickness), mm."""
        return self.r_long_epi - self.r_long_endo

    def s_lv_endo(self, z: np.ndarray) -> np.ndarray:
        """Squared LV endocardial radius at height z (eq. A1), mm²."""
        return spheroid_section_s(z, self.r_short_endo, self.r_long_endo, self.z_center)

    def s_lv_epi(self, z: np.ndarray) -> np.ndarray:
        """Squared LV epicardial radius at height z (eq. A1), mm²."""
        return spheroid_section_s(z, self.r_short_epi, self.r_long_epi, self.z_center)

    # ------------------------------------------------------------ RV
    @property
    def rv_x_center(self) -> float:
        return self.rv_offset * self.r_free_endo

    def rv_g2(self, z: np.ndarray, epi: bool = False) -> np.ndarray:
        """g(z)² of eq. (A2) for the RV endocardial (or epicardial) shell; 0 above the base."""
        c = self.r_long_rv_endo + (self.rv_wall if epi else 0.0)
        z = np.asarray(z, dtype=float)
        u = (z - self.z_base) / c
        return np.where((u <= 0) & (u > -1), 1.0 - u * u, 0.0)

    def rv_p(self, theta: np.ndarray, epi: bool = False) -> np.ndarray:
        """P(θ) of eq. (A3) for the RV endocardial (or epicardial) shell, mm²."""
        t = self.rv_wall if epi else 0.0
        return ellipse_far_radius_sq(theta, self.r_free_endo + t, self.r_wrap_endo + t,
                                     self.rv_x_center)

    def s_rv(self, theta: np.ndarray, z: np.ndarray, epi: bool = False) -> np.ndarray:
        """Squared radius of the RV endo/epi shell along θ at height z, mm² (0 where absent)."""
        return self.rv_g2(z, epi) * self.rv_p(theta, epi)

    def _p_table(self, epi: bool) -> tuple[np.ndarray, np.ndarray]:
        key = "_ptab_epi" if epi else "_ptab_endo"
        tab = self.__dict__.get(key)
        if tab is None:
            th = np.linspace(0.0, np.pi, 4097)
            tab = (th, self.rv_p(th, epi))
            object.__setattr__(self, key, tab)
        return tab

    def rv_sector_edge(self, z: np.ndarray, epi: bool = False) -> np.ndarray:
        """θ_e(z) in [0, π]: half-angle of the RV crescent at height z (0 where there is none).

        Solves g(z)² P(θ) = s_epi(z), i.e. P(θ) = s_epi / g², for θ: P decreases monotonically
        on [0, π] (checked by :meth:`validate`), so a 4097-point table of P gives a start to
        ~1e-7 rad by linear interpolation, then three Newton steps (central-difference
        derivative) reach machine precision.
        """
        z = np.atleast_1d(np.asarray(z, dtype=float))
        g2, s2 = self.rv_g2(z, epi), self.s_lv_epi(z)
        th_tab, p_tab = self._p_table(epi)
        has = g2 * p_tab[0] > s2
        full = g2 * p_tab[-1] > s2
        target = np.where(has & ~full, s2 / np.where(g2 > 0, g2, 1.0), p_tab[0])
        th = np.interp(-target, -p_tab, th_tab)
        h = 1e-6
        for _ in range(3):
            dp = (self.rv_p(th + h, epi) - self.rv_p(th - h, epi)) / (2 * h)
            dp = np.where(dp < 0, dp, -1.0)
            th = np.clip(th - (self.rv_p(th, epi) - target) / dp, 0.0, np.pi)
        edge = np.where(has, th, 0.0)
        return np.where(full, np.pi, edge)

    def rv_onset(self, epi: bool = False, iters: int = 80) -> float:
        """Lowest height z0 where the RV shell leaves the LV epicardium (crescent onset), mm."""
        c = self.r_long_rv_endo + (self.rv_wall if epi else 0.0)
        p0 = float(self.rv_p(np.array(0.0), epi))
        lo, hi = self.z_base - c, self.z_base
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            if float(self.rv_g2(mid, epi)) * p0 > float(self.s_lv_epi(mid)):
                hi = mid
            else:
                lo = mid
        return 0.5 * (lo + hi)

    def validate(self) -> "Anatomy":
        """Check the RV crescent is a single sector on every section; PhantomError otherwise."""
        th = np.linspace(0.0, np.pi, 1025)
        for epi in (False, True):
            p = self.rv_p(th, epi)
            if np.any(np.diff(p) > 1e-9 * p[0]):
                raise PhantomError("RV shape parameters give a section that is not a single crescent "
                                   "(r_wrap_endo too large for r_free_endo)")
            if float(self.rv_g2(self.z_base, epi)) * p[0] <= float(self.s_lv_epi(self.z_base)):
                raise PhantomError("the RV does not reach beyond the LV epicardium at the base "
                                   "(r_free_endo too small)")
            if float(self.rv_p(np.array(np.pi), epi)) >= float(self.s_lv_epi(self.z_base - 1e-9)):
                raise PhantomError("the RV surrounds the LV completely at the base (rv_offset too small)")
        zs = np.linspace(self.z_base - self.r_long_rv_endo - self.rv_wall, self.z_base, 400)
        e_endo, e_epi = self.rv_sector_edge(zs), self.rv_sector_edge(zs, epi=True)
        if np.any(e_endo > e_epi + 1e-9):
            raise PhantomError("the RV endocardium leaves its epicardium (rv_wall too thin)")
        if np.any(e_epi >= np.pi - 1e-6):
            raise PhantomError("the RV wraps all around the LV on some section")
        return self

    # ------------------------------------------------------------ volumes (method A)
    def lv_cavity_volume(self) -> float:
        """LV cavity volume at ED closed by the base plane, mm³ (eq. A4)."""
        return truncated_spheroid_volume(self.r_short_endo, self.r_long_endo, self.z_center, self.z_base)

    def lv_epi_volume(self) -> float:
        """Volume inside the LV epicardium below the base plane, mm³ (eq. A4)."""
        return truncated_spheroid_volume(self.r_short_epi, self.r_long_epi, self.z_center, self.z_base)

    def lv_myocardial_volume(self) -> float:
        return self.lv_epi_volume() - self.lv_cavity_volume()

    def rv_shell_volume(self, epi: bool = False, n_z: int = 256, n_theta: int = 64) -> float:
        """Volume of the RV endo (epi) shell outside the LV epicardium, mm³, by eq. (A5).

        Inner integral ∫_0^{θ_e} (g² P − s_epi) dθ on [0, θ_e(z)] with an n_theta-point
        Gauss–Legendre rule (smooth integrand there); outer integral over [z0, z_b] with an
        n_z-point Gauss–Legendre rule after the substitution z = z0 + (z_b − z0) u^2, which
        removes the (z − z0)^{3/2} onset singularity of the section area.
        """
        z0 = self.rv_onset(epi)
        u, wu = gauss_legendre(n_z)
        z = z0 + (self.z_base - z0) * u * u
        wz = wu * 2.0 * u * (self.z_base - z0)
        edge = self.rv_sector_edge(z, epi)
        v, wv = gauss_legendre(n_theta)
        th = edge[:, None] * v[None, :]
        integrand = self.rv_g2(z, epi)[:, None] * self.rv_p(th, epi) - self.s_lv_epi(z)[:, None]
        area = (integrand * wv[None, :]).sum(axis=1) * edge
        return float((area * wz).sum())

    def rv_cavity_volume(self) -> float:
        """RV cavity volume at ED (inside the RV endocardium, outside the LV), mm³."""
        return self.rv_shell_volume(epi=False)

    def rv_myocardial_volume(self) -> float:
        """RV free-wall volume at ED, mm³."""
        return self.rv_shell_volume(epi=True) - self.rv_shell_volume(epi=False)

    def to_dict(self) -> dict:
        return {k: float(getattr(self, k)) for k in self.__dataclass_fields__}
