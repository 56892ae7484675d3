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
from functools import cached_property, lru_cache

import numpy as np

from cardionurbs.cache import memoized
from cardionurbs.errors import PhantomError
from cardionurbs.phantom.shape import ShapeModes

@lru_cache(maxsize=None)
def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [0, 1] (cached per n: :func:`functools.lru_cache`).

    Parameters
    ----------
    n : int
        Number of nodes.

    Returns
    -------
    nodes, weights : (n,) float64 ndarray
        Nodes in (0, 1) and their weights (summing to 1); shared, not to be modified.
    """
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def spheroid_s_unclamped(z, r_short: float, r_long: float, z_center: float) -> np.ndarray:
    """a² (1 − ((z − z_c)/c)²): the spheroid's squared section radius (eq. A1), negative beyond its
    poles (the continuation the realistic LA contours use below an apex).

    Parameters
    ----------
    z : float or ndarray
        Height above the epicardial apex, mm.
    r_short : float
        The spheroid's equatorial semi-axis a, mm.
    r_long : float
        Its polar semi-axis c, mm.
    z_center : float
        The height of its centre z_c, mm.
    Returns
    -------
    ndarray
        a² (1 − ((z − z_c)/c)²), mm², shape of ``z``.
    """
    u = (np.asarray(z, dtype=float) - z_center) / r_long
    return r_short * r_short * (1.0 - u * u)


def spheroid_section_s(z: np.ndarray, r_short: float, r_long: float, z_center: float) -> np.ndarray:
    """Squared radius of a prolate spheroid's section at height z (eq. A1); 0 outside it (where
    the continuation of :func:`spheroid_s_unclamped` is ≤ 0).

    Parameters
    ----------
    z : float or ndarray
        Height above the epicardial apex, mm.
    r_short : float
        The spheroid's equatorial semi-axis a, mm.
    r_long : float
        Its polar semi-axis c, mm.
    z_center : float
        The height of its centre z_c, mm.
    Returns
    -------
    ndarray
        The squared section radius, mm² (0 outside), shape of ``z``.
    """
    return np.maximum(spheroid_s_unclamped(z, r_short, r_long, z_center), 0.0)


def truncated_spheroid_volume(r_short: float, r_long: float, z_center: float, z_top: float) -> float:
    """Volume (mm³) of a spheroid below the plane z = z_top (eq. A4).

    V = π a² [(z_top − z_lo) − ((z_top − z_c)³ − (z_lo − z_c)³) / (3 c²)], z_lo = z_c − c.

    Parameters
    ----------
    r_short : float
        The spheroid's equatorial semi-axis a, mm.
    r_long : float
        Its polar semi-axis c, mm.
    z_center : float
        The height of its centre z_c, mm.
    z_top : float
        The cutting plane's height, mm.
    Returns
    -------
    float
        The volume, mm³.
    """
    z_top = min(max(z_top, z_center - r_long), z_center + r_long)
    lo, hi = -r_long, z_top - z_center
    return float(np.pi * r_short ** 2 * ((hi - lo) - (hi ** 3 - lo ** 3) / (3.0 * r_long ** 2)))


def unit_phasor(theta) -> np.ndarray:
    """e^{iθ}: its real and imaginary parts are exactly ``np.cos(θ)`` and ``np.sin(θ)`` (one
    evaluation serves the shape modes and every cos θ, sin θ of the same angles).

    Parameters
    ----------
    theta : float or array_like
        Angles, rad.
    Returns
    -------
    ndarray of complex
        e^{iθ}, shape of ``theta``.
    """
    return np.exp(1j * np.asarray(theta, dtype=float))


def wrap_angle(theta) -> np.ndarray:
    """θ wrapped to [−π, π] (radians): θ − 2π round(θ / 2π), without complex exponentials.

    Parameters
    ----------
    theta : float or array_like
        Angles, rad.
    Returns
    -------
    ndarray
        The wrapped angles, rad.
    """
    theta = np.asarray(theta, dtype=float)
    return theta - (2.0 * np.pi) * np.round(theta / (2.0 * np.pi))


def ellipse_far_radius_sq_cs(ct: np.ndarray, st: np.ndarray, a_free: float, b_wrap: float,
                             x_center: float) -> np.ndarray:
    """P(θ) = ρ(θ)²: squared distance from the origin to the ellipse boundary along θ (eq. A3),
    from cos θ and sin θ (several ellipses along the same rays share them).

    Parameters
    ----------
    ct, st : ndarray
        cos θ and sin θ of the rays.
    a_free : float
        The ellipse's semi-axis toward the free wall, mm.
    b_wrap : float
        Its semi-axis along the septum, mm.
    x_center : float
        Its centre's offset along x, mm.
    Returns
    -------
    ndarray
        P(θ), mm², shape of ``ct``.
    """
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

    ``shape`` (None for the ideal anatomy) adds the realistic departures of
    :mod:`cardionurbs.phantom.shape`; every section function then needs the angle θ.

    Attributes
    ----------
    r_short_endo, r_short_epi : float
        LV equatorial semi-axes of the endo- and epicardial spheroids, mm.
    r_long_endo, r_long_epi : float
        Their polar semi-axes, mm.
    base_height : float
        Base-plane height above the spheroids' equator, mm.
    r_free_endo : float
        RV endocardial semi-axis toward the free wall, mm.
    r_wrap_endo : float
        RV endocardial semi-axis along the septum, mm.
    r_long_rv_endo : float
        RV endocardial length (apex to base), mm.
    rv_wall : float
        RV free-wall thickness, mm.
    rv_offset : float
        RV section centre offset, as a fraction of ``r_free_endo``.
    shape : cardionurbs.phantom.shape.ShapeModes or None
        The realistic departures (None: the ideal spheroids).

    Raises
    ------
    cardionurbs.errors.PhantomError
        A length not positive, walls not nested, or a base or RV out of range.
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
    shape: ShapeModes | None = None

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

    @property
    def realistic(self) -> bool:
        return self.shape is not None

    def _need_theta(self, theta) -> None:
        if theta is None and self.shape is not None:
            raise ValueError("a realistic anatomy's sections depend on the angle: pass theta")

    def zeta(self, z) -> np.ndarray:
        """Normalised height ζ = (z − z_c) / r_long_endo of the shape modes.

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        Returns
        -------
        ndarray
            ζ (dimensionless), shape of ``z``.
        """
        return (np.asarray(z, dtype=float) - self.z_center) / self.r_long_endo

    def s_lv_endo(self, z: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """Squared LV endocardial radius at height z (eq. A1; × the modes of eq. R1), mm².

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        theta : float or ndarray, optional
            Angle θ about the LV axis, rad (needed for a realistic anatomy).
        Returns
        -------
        ndarray
            S_endo, mm², broadcast shape.
        """
        s = spheroid_section_s(z, self.r_short_endo, self.r_long_endo, self.z_center)
        if self.shape is None:
            return s
        self._need_theta(theta)
        s = s * self.shape.endo_factor(theta, self.zeta(z))
        if self.shape.infarct is None:
            return s
        # infarct: the endocardium moves out toward the (unchanged) epicardium, r1 -> r2 − (r2 − r1)
        # (1 − τ w), faded out over the last ~2 mm of radius before the endocardial apex
        w = self.shape.infarct_weight(theta, np.asarray(z, dtype=float) / self.z_base) * (s / (s + 4.0))
        r1 = np.sqrt(np.maximum(s, 0.0))
        r2 = np.sqrt(np.maximum(self._s_epi(z, theta), 0.0))
        return (r2 - (r2 - r1) * (1.0 - self.shape.infarct_thinning * w)) ** 2

    def s_lv_epi(self, z: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """Squared LV epicardial radius at height z (eq. A1; realistic: wall-following modes and
        septal thickening of :mod:`cardionurbs.phantom.shape`), mm². An infarct thins the wall
        from the inside (:meth:`s_lv_endo`): the epicardium, hence the RV, is unchanged.

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        theta : float or ndarray, optional
            Angle θ about the LV axis, rad (needed for a realistic anatomy).
        Returns
        -------
        ndarray
            S_epi, mm², broadcast shape.
        """
        s = spheroid_section_s(z, self.r_short_epi, self.r_long_epi, self.z_center)
        if self.shape is None:
            return s
        self._need_theta(theta)
        return self._s_epi(z, theta)

    def _s_epi(self, z, theta) -> np.ndarray:
        s = spheroid_section_s(z, self.r_short_epi, self.r_long_epi, self.z_center)
        s_endo0 = spheroid_section_s(z, self.r_short_endo, self.r_long_endo, self.z_center)
        ratio = np.sqrt(s_endo0 / np.where(s > 0, s, 1.0))
        return s * self.shape.epi_factor(theta, self.zeta(z), ratio)

    def lv_sections(self, z: np.ndarray, theta: np.ndarray | None = None,
                    e: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(S_endo, S_epi) at (z, θ): :meth:`s_lv_endo` and :meth:`s_lv_epi` sharing one evaluation
        of the shape modes, mm². ``e`` = e^{iθ} when the caller has it (it needs cos θ and sin θ
        too: :func:`unit_phasor`).

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        theta : float or ndarray, optional
            Angle θ about the LV axis, rad (needed for a realistic anatomy).
        e : ndarray of complex, optional
            e^{iθ}.
        Returns
        -------
        s_endo, s_epi : ndarray
            mm², broadcast shape.
        """
        if self.shape is None or self.shape.infarct is not None:
            return self.s_lv_endo(z, theta), self.s_lv_epi(z, theta)
        z = np.asarray(z, dtype=float)
        s1 = spheroid_section_s(z, self.r_short_endo, self.r_long_endo, self.z_center)
        s2 = spheroid_section_s(z, self.r_short_epi, self.r_long_epi, self.z_center)
        zeta = self.zeta(z)
        if e is None:
            e = unit_phasor(theta)                              # its real part is cos θ
        m = self.shape.endo_factor(theta, zeta, e) - 1.0
        ratio = np.sqrt(s1 / np.where(s2 > 0, s2, 1.0))
        return s1 * (1.0 + m), s2 * (1.0 + ratio * m + self.shape.septal_thickening * e.real)

    def z_top(self, theta: np.ndarray | None = None) -> np.ndarray:
        """Height of the mitral annulus (top of the LV walls) at angle θ, mm: z_b (ideal) or
        z_b + h cos 2(θ − θ_s) (saddle).

        Parameters
        ----------
        theta : float or ndarray, optional
            Angle θ about the LV axis, rad (needed for a realistic anatomy).
        Returns
        -------
        ndarray
            The annulus height, mm.
        """
        if self.shape is None:
            return np.full(np.shape(theta) if theta is not None else (), self.z_base)
        return self.z_base + self.shape.saddle(theta)

    @property
    def z_top_min(self) -> float:
        return self.z_base - (self.shape.saddle_mm if self.shape is not None else 0.0)

    @property
    def tricuspid_dip(self) -> float:
        """h_t, mm: how far the tricuspid annulus dips below the base plane (0: planar)."""
        return float(self.shape.tricuspid_dip_mm) if self.shape is not None else 0.0

    def tricuspid_span(self) -> tuple[float, float]:
        """(θ_0, θ_1): the angles of the tricuspid annulus' dip — the endocardial RV crescent at the
        base, with an outflow tract only up to the tract's epicardial window (the tract and its
        side wall rise from the plane z = z_b).

        Returns
        -------
        tuple of (float, float)
            (θ_0, θ_1), rad.
        """
        return self._tricuspid_span

    @cached_property
    def _tricuspid_span(self) -> tuple[float, float]:
        lo, hi = (float(v[0]) for v in self.rv_sector(np.array([self.z_base])))
        if self.outflow is not None:
            from cardionurbs.phantom.outflow import rvot_frame
            hi = min(hi, float(rvot_frame(self).window(self.z_base, epi=True)[0]))
        return lo, hi

    def z_top_rv(self, theta) -> np.ndarray:
        """Height of the tricuspid annulus (top of the RV walls and cavity) at angle θ, mm: z_b, or
        with a dip h_t (realistic) z_b − h_t sin²(π (θ − θ_0) / (θ_1 − θ_0)) over the tricuspid
        span [θ_0, θ_1] (:meth:`tricuspid_span`) and z_b outside it. The crescent's tips stay at
        z_b and its free wall and septum dip at the middle angle: around the annulus ring (free
        wall out, septum back) two highs and two lows, a saddle.

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad.
        Returns
        -------
        ndarray
            The annulus height, mm, shape of ``theta``.
        """
        theta = np.asarray(theta, dtype=float)
        if self.tricuspid_dip == 0.0:
            return np.full(theta.shape, self.z_base)
        lo, hi = self.tricuspid_span()
        mid = 0.5 * (lo + hi)
        t = wrap_angle(theta - mid) + mid                           # θ wrapped about the span
        u = np.minimum(np.maximum((t - lo) / (hi - lo), 0.0), 1.0)     # clipped
        return self.z_base - self.tricuspid_dip * np.sin(np.pi * u) ** 2

    @property
    def z_top_rv_min(self) -> float:
        """Lowest point of the tricuspid annulus, mm."""
        return self.z_base - self.tricuspid_dip

    # ------------------------------------------------------------ RV
    @property
    def rv_x_center(self) -> float:
        return self.rv_offset * self.r_free_endo

    def rv_g2(self, z: np.ndarray, epi: bool = False) -> np.ndarray:
        """g(z)² of eq. (A2) for the RV endocardial (or epicardial) shell; 0 above the base.

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        Returns
        -------
        ndarray
            g(z)² (dimensionless), shape of ``z``.
        """
        c = self.r_long_rv_endo + (self.rv_wall if epi else 0.0)
        z = np.asarray(z, dtype=float)
        u = (z - self.z_base) / c
        return np.where((u <= 0) & (u > -1), 1.0 - u * u, 0.0)

    def _rv_rays(self, theta: np.ndarray, z: np.ndarray | None):
        """(cos, sin) of the ray angle along which the RV ellipse of eq. (A3) is evaluated at
        (θ, z), and the reach factor (None for ideal anatomy): realistic, θ stretched about the
        axis by the wrap factor w(z)."""
        if self.shape is None:
            th, reach = np.asarray(theta, dtype=float), None
        else:
            if z is None:
                raise ValueError("a realistic RV section depends on the height: pass z")
            u = 1.0 + (np.asarray(z, dtype=float) - self.z_base) / self.r_long_rv_endo
            th = np.minimum(np.abs(np.asarray(theta, dtype=float)) / self.shape.rv_wrap(u), np.pi)
            reach = self.shape.rv_reach_factor(u)
        return np.cos(th), np.sin(th), reach

    def rv_p(self, theta: np.ndarray, epi: bool = False, z: np.ndarray | None = None) -> np.ndarray:
        """P(θ) of eq. (A3) for the RV endocardial (or epicardial) shell, mm²; realistic: the
        ellipse stretched about the axis by the wrap factor w(z) and scaled by the reach factor.

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        z : ndarray, optional
            Height, mm (needed for a realistic anatomy).
        Returns
        -------
        ndarray
            P(θ), mm².
        """
        t = self.rv_wall if epi else 0.0
        ct, st, reach = self._rv_rays(theta, z)
        p = ellipse_far_radius_sq_cs(ct, st, self.r_free_endo + t, self.r_wrap_endo + t,
                                     self.rv_x_center)
        return p if reach is None else p * reach

    def rv_p_pair(self, theta: np.ndarray, z: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(P_endo, P_epi) of :meth:`rv_p` at the same (θ, z): both ellipses along the same rays
        (one cosine and sine of the ray angle for both; the same values as two calls).

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad.
        z : ndarray, optional
            Height, mm.
        Returns
        -------
        p_endo, p_epi : ndarray
            mm².
        """
        ct, st, reach = self._rv_rays(theta, z)
        out = tuple(ellipse_far_radius_sq_cs(ct, st, self.r_free_endo + w, self.r_wrap_endo + w,
                                             self.rv_x_center) for w in (0.0, self.rv_wall))
        return out if reach is None else (out[0] * reach, out[1] * reach)

    def s_rv_pair(self, theta: np.ndarray, z: np.ndarray, s_epi=None) -> tuple[np.ndarray, np.ndarray]:
        """(S_rv_endo, S_rv_epi) of :meth:`s_rv` at the same (θ, z), sharing every common factor
        (the ray's cosine and sine, the tract's inputs); ``s_epi``: the LV epicardial S at (θ, z)
        when the caller has it (the RVOT's inner side). The same values as two calls.

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad.
        z : float or ndarray
            Height above the epicardial apex, mm.
        s_epi : ndarray, optional
            The LV epicardial S at (θ, z), mm².
        Returns
        -------
        s_rv_endo, s_rv_epi : ndarray
            mm², broadcast shape.
        """
        theta, z = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(z, dtype=float))
        p_endo, p_epi = self.rv_p_pair(theta, z)
        body = (self.rv_g2(z, False) * p_endo, self.rv_g2(z, True) * p_epi)
        if self.outflow is None:
            return body
        above = z > self.z_base
        if not np.any(above):
            return body
        from cardionurbs.phantom.outflow import s_rvot_pair
        th_a, z_a = theta[above], z[above]
        rb_endo, rb_epi = self.rv_p_pair(th_a, np.full(th_a.shape, self.z_base))
        s2 = None if s_epi is None else np.broadcast_to(s_epi, z.shape)[above]
        tract = s_rvot_pair(self, th_a, z_a, s_epi=s2, r_b=(np.sqrt(rb_endo), np.sqrt(rb_epi)))
        out = []
        for b, t in zip(body, tract):
            o = np.array(b, dtype=float)
            o[above] = t
            out.append(o)
        return out[0], out[1]

    def s_rv(self, theta: np.ndarray, z: np.ndarray, epi: bool = False, body=None,
             r_b=None, s_epi=None) -> np.ndarray:
        """Squared radius of the RV endo/epi shell along θ at height z, mm² (0 where absent).
        ``body`` (:meth:`s_rv_body`), ``r_b`` (the tract's base radius,
        :func:`cardionurbs.phantom.outflow.rvot_base_radius`) and ``s_epi`` (the LV epicardial S)
        at the same (θ, z) when the caller has them already (the same values).

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad.
        z : float or ndarray
            Height above the epicardial apex, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        body : ndarray, optional
            :meth:`s_rv_body` at (θ, z), mm².
        r_b : ndarray, optional
            The tract's base radius at θ, mm.
        s_epi : ndarray, optional
            The LV epicardial S at (θ, z), mm².
        Returns
        -------
        ndarray
            mm², broadcast shape.
        """
        if self.shape is None:
            return self.rv_g2(z, epi) * self.rv_p(theta, epi)
        if body is None:
            body = self.rv_g2(z, epi) * self.rv_p(theta, epi, z)
        if self.shape.outflow is None:
            return body
        # above the tricuspid plane: the RV outflow tract (phantom/outflow.py, eq. O1)
        theta, z = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(z, dtype=float))
        above = z > self.z_base
        if not np.any(above):
            return body
        from cardionurbs.phantom.outflow import s_rvot
        out = np.array(np.broadcast_to(body, z.shape), dtype=float)
        out[above] = s_rvot(self, theta[above], z[above], epi,
                            s_epi=None if s_epi is None else np.broadcast_to(s_epi, z.shape)[above],
                            r_b=None if r_b is None else np.broadcast_to(r_b, z.shape)[above])
        return out

    def s_rv_body(self, theta: np.ndarray, z: np.ndarray, epi: bool = False) -> np.ndarray:
        """The RV body's shell alone (0 above the tricuspid plane, also with an outflow tract), mm².

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad.
        z : float or ndarray
            Height above the epicardial apex, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        Returns
        -------
        ndarray
            mm², broadcast shape.
        """
        if self.shape is None:
            return self.rv_g2(z, epi) * self.rv_p(theta, epi)
        return self.rv_g2(z, epi) * self.rv_p(theta, epi, z)

    @property
    def outflow(self):
        """The OutflowTracts of a realistic anatomy that has them, else None."""
        return None if self.shape is None else self.shape.outflow

    def rv_sector(self, z: np.ndarray, epi: bool = False, n_table: int = 181) -> tuple[np.ndarray, np.ndarray]:
        """(θ_lo, θ_hi): the RV crescent at height z spans θ_lo ≤ θ ≤ θ_hi (both 0 where there is
        none). Ideal: ±θ_e(z). Realistic: going out both ways from the angle where the crescent is
        widest (max of S_rv − S_epi on a 2 (n_table − 1) grid), the first sign change, refined by
        eight regula falsi steps; both edges equal that angle where there is no crescent.

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        n_table : int, optional
            Grid size of the realistic search.

        Returns
        -------
        theta_lo, theta_hi : ndarray
            The crescent's angular limits, rad, shape of ``atleast_1d(z)``.
        """
        if self.shape is not None and np.ndim(z) == 0 and n_table == 181:
            lo, hi = self._rv_sector_at(float(z), bool(epi))
            return np.array([lo]), np.array([hi])
        z = np.atleast_1d(np.asarray(z, dtype=float))
        if self.shape is None:
            e = self.rv_sector_edge(z, epi)
            return -e, e
        n = 2 * (n_table - 1)
        th = np.linspace(-np.pi, np.pi, n, endpoint=False)
        step = 2 * np.pi / n
        d = self.s_rv(th[None, :], z[:, None], epi) - self.s_lv_epi(z[:, None], th[None, :])
        m = d.argmax(axis=1)
        rows = np.arange(len(z))[:, None]
        has = d[rows[:, 0], m] > 0
        theta_m = th[m]

        # both edges at once: row 0 going down in θ from θ_m, row 1 going up (element by element
        # the same arithmetic as one side at a time)
        z2 = np.broadcast_to(z[None, :], (2, len(z)))

        def dd(t):
            return self.s_rv(t, z2, epi) - self.s_lv_epi(z2, t)

        sign = np.array([-1.0, 1.0])[:, None]
        ring = d[rows[None, :, :], (m[None, :, None] + (sign[:, :, None] * np.arange(n)).astype(int)) % n]
        ends = np.where(ring > 0, n, np.arange(n)[None, None, :]).min(axis=2)
        full = ends >= n
        j = np.clip(ends, 1, n - 1)
        a, b = theta_m + sign * (j - 1) * step, theta_m + sign * j * step
        fa, fb = dd(a), dd(b)
        for _ in range(8):
            mid = b - fb * (b - a) / np.where(fb != fa, fb - fa, 1.0)
            fm = dd(mid)
            left = np.sign(fm) == np.sign(fa)
            a, fa = np.where(left, mid, a), np.where(left, fm, fa)
            b, fb = np.where(left, b, mid), np.where(left, fb, fm)
        edge = np.where(np.abs(fa) < np.abs(fb), a, b)
        edge = np.where(full, theta_m + sign * np.pi, edge)
        out = np.where(has, edge, theta_m)
        return out[0], out[1]

    @memoized
    def _rv_sector_at(self, z: float, epi: bool) -> tuple[float, float]:
        """:meth:`rv_sector` of a realistic anatomy at one height (cached per (z, surface);
        :meth:`prime_rv_sectors` solves many at once)."""
        lo, hi = self.rv_sector(np.array([z]), epi)
        return float(lo[0]), float(hi[0])

    @memoized
    def _p_table(self, epi: bool) -> tuple[np.ndarray, np.ndarray]:
        """(θ, P(θ)) on 4097 angles of [0, π] (per surface, computed once)."""
        th = np.linspace(0.0, np.pi, 4097)
        return th, self.rv_p(th, epi)

    def rv_sector_edge(self, z: np.ndarray, epi: bool = False) -> np.ndarray:
        """θ_e(z) in [0, π]: half-angle of the RV crescent at height z (0 where there is none).

        Solves g(z)² P(θ) = s_epi(z), i.e. P(θ) = s_epi / g², for θ: P decreases monotonically
        on [0, π] (checked by :meth:`validate`), so a 4097-point table of P gives a start to
        ~1e-7 rad by linear interpolation, then three Newton steps (central-difference
        derivative) reach machine precision.

        Parameters
        ----------
        z : float or ndarray
            Height above the epicardial apex, mm.
        epi : bool, optional
            The epicardial shell (else the endocardial).
        Returns
        -------
        ndarray
            θ_e(z), rad, shape of ``z``.
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

    def prime_rv_sectors(self, z: np.ndarray) -> None:
        """Solve the realistic RV sectors (endo and epi) at many heights in one vectorised call, for
        the scalar look-ups of the SA contours and insertion points (the same arithmetic
        element by element, so the same values).

        Parameters
        ----------
        z : ndarray
            Heights, mm.
        """
        if self.shape is None:
            return
        z = np.unique(np.asarray(z, dtype=float))
        for epi in (False, True):
            lo, hi = self.rv_sector(z, epi)
            for a, b, c in zip(z, lo, hi):
                self._rv_sector_at.store((float(b), float(c)), float(a), epi)

    def rv_onset(self, epi: bool = False, iters: int = 80) -> float:
        """Lowest height z0 where the RV shell leaves the LV epicardium (crescent onset), mm.

        Parameters
        ----------
        epi : bool, optional
            The epicardial shell (else the endocardial).
        iters : int, optional
            Bisection steps.
        Returns
        -------
        float
            z0, mm.
        """
        c = self.r_long_rv_endo + (self.rv_wall if epi else 0.0)
        lo, hi = self.z_base - c, self.z_base
        if self.shape is not None:
            th = np.linspace(-np.pi, np.pi, 721)

            def reaches(z):
                return bool(np.any(self.s_rv(th, np.full_like(th, z), epi) > self.s_lv_epi(z, th)))
        else:
            p0 = float(self.rv_p(np.array(0.0), epi))

            def reaches(z):
                return float(self.rv_g2(z, epi)) * p0 > float(self.s_lv_epi(z))
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            if mid <= lo or mid >= hi:      # the bracket is two neighbouring floats: converged
                break
            if reaches(mid):
                hi = mid
            else:
                lo = mid
        return 0.5 * (lo + hi)

    def validate(self) -> "Anatomy":
        """Check the RV crescent is a single sector on every section; PhantomError otherwise.

        Returns
        -------
        Anatomy
            ``self``, once checked.

        Raises
        ------
        cardionurbs.errors.PhantomError
            The crescent is not one sector on some section (or, realistic, the walls not nested).
        """
        if self.shape is not None:
            return self._validate_realistic()
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

    def _validate_realistic(self) -> "Anatomy":
        """Realistic shapes: positive, nested LV walls; one RV crescent per section, inside its
        epicardium, never wrapping the LV."""
        th = np.linspace(-np.pi, np.pi, 721, endpoint=False)
        z = np.linspace(0.02 * self.z_base, self.z_top_min, 200)
        T, Z = np.meshgrid(th, z)
        s1, s2 = self.s_lv_endo(Z, T), self.s_lv_epi(Z, T)
        if np.any(self.shape.endo_factor(T, self.zeta(Z)) <= 0.2):
            raise PhantomError("endocardial shape modes fold the section (factor <= 0.2)")
        if np.any(np.sqrt(s2) - np.sqrt(np.maximum(s1, 0.0)) < 1.0):
            raise PhantomError("the realistic LV wall is thinner than 1 mm somewhere")
        zr = np.linspace(self.z_base - self.r_long_rv_endo - self.rv_wall, self.z_base, 200)
        for epi in (False, True):
            d = self.s_rv(th[None, :], zr[:, None], epi) - self.s_lv_epi(zr[:, None], th[None, :])
            runs = np.count_nonzero(np.diff((d > 0).astype(int), axis=1, append=(d[:, :1] > 0)) != 0,
                                    axis=1)
            if np.any(runs > 2):
                raise PhantomError("realistic RV shape gives a section that is not a single crescent")
            if np.all(d[-1] > 0):
                raise PhantomError("the RV wraps all around the LV at the base")
        lo_n, hi_n = self.rv_sector(zr)
        lo_p, hi_p = self.rv_sector(zr, epi=True)
        has = hi_n > lo_n
        if np.any(lo_n[has] < lo_p[has] - 1e-6) or np.any(hi_n[has] > hi_p[has] + 1e-6):
            raise PhantomError("the RV endocardium leaves its epicardium (rv_wall too thin)")
        return self

    # ------------------------------------------------------------ volumes (method A)
    def _section_quadrature(self, fn, z_lo: float, z_hi: float, n_z: int = 192, n_theta: int = 256) -> float:
        """∫_{z_lo}^{z_hi} ½ ∮ fn(z, θ) dθ dz: Gauss–Legendre in z, the periodic trapezoid rule
        (spectrally accurate for smooth periodic integrands) in θ, mm³."""
        u, wu = gauss_legendre(n_z)
        z = z_lo + (z_hi - z_lo) * u
        th = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
        area = 0.5 * fn(z[:, None], th[None, :]).mean(axis=1) * 2 * np.pi
        return float((area * wu).sum() * (z_hi - z_lo))

    def lv_cavity_volume(self) -> float:
        """LV cavity volume at ED closed by the base plane z = z_b, mm³ (eq. A4; realistic:
        section quadrature).

        Returns
        -------
        float
            The volume, mm³.
        """
        if self.shape is not None:
            return self._section_quadrature(self.s_lv_endo, self.z_endo_apex, self.z_base)
        return truncated_spheroid_volume(self.r_short_endo, self.r_long_endo, self.z_center, self.z_base)

    def lv_epi_volume(self) -> float:
        """Volume inside the LV epicardium below the base plane, mm³ (eq. A4; realistic: section
        quadrature).

        Returns
        -------
        float
            The volume, mm³.
        """
        if self.shape is not None:
            return self._section_quadrature(self.s_lv_epi, 0.0, self.z_base)
        return truncated_spheroid_volume(self.r_short_epi, self.r_long_epi, self.z_center, self.z_base)

    def lv_myocardial_volume(self) -> float:
        """LV myocardial volume: :meth:`lv_epi_volume` − :meth:`lv_cavity_volume`.

        Returns
        -------
        float
            The volume, mm³.
        """
        return self.lv_epi_volume() - self.lv_cavity_volume()

    def rv_shell_volume(self, epi: bool = False, n_z: int = 256, n_theta: int = 64) -> float:
        """Volume of the RV endo (epi) shell outside the LV epicardium, mm³, by eq. (A5).

        Inner integral ∫_0^{θ_e} (g² P − s_epi) dθ on [0, θ_e(z)] with an n_theta-point
        Gauss–Legendre rule (smooth integrand there); outer integral over [z0, z_b] with an
        n_z-point Gauss–Legendre rule after the substitution z = z0 + (z_b − z0) u^2, which
        removes the (z − z0)^{3/2} onset singularity of the section area.

        Parameters
        ----------
        epi : bool, optional
            The epicardial shell (else the endocardial).
        n_z : int, optional
            Gauss–Legendre points along z.
        n_theta : int, optional
            Gauss–Legendre points along θ.
        Returns
        -------
        float
            The volume, mm³.
        """
        z0 = self.rv_onset(epi)
        u, wu = gauss_legendre(n_z)
        z = z0 + (self.z_base - z0) * u * u
        wz = wu * 2.0 * u * (self.z_base - z0)
        if self.shape is not None:
            v, wv = gauss_legendre(n_theta)
            area = np.zeros(len(z))
            for edge in self.rv_sector(z, epi):
                th = edge[:, None] * v[None, :]
                zz = z[:, None]
                integrand = self.s_rv(th, zz, epi) - self.s_lv_epi(zz, th)
                area += 0.5 * (integrand * wv[None, :]).sum(axis=1) * np.abs(edge)
            return float((area * wz).sum())
        edge = self.rv_sector_edge(z, epi)
        v, wv = gauss_legendre(n_theta)
        th = edge[:, None] * v[None, :]
        integrand = self.rv_g2(z, epi)[:, None] * self.rv_p(th, epi) - self.s_lv_epi(z)[:, None]
        area = (integrand * wv[None, :]).sum(axis=1) * edge
        return float((area * wz).sum())

    def rv_cavity_volume(self) -> float:
        """RV cavity volume at ED (inside the RV endocardium, outside the LV), mm³.

        Returns
        -------
        float
            The volume, mm³.
        """
        return self.rv_shell_volume(epi=False)

    def rv_myocardial_volume(self) -> float:
        """RV free-wall volume at ED, mm³.

        Returns
        -------
        float
            The volume, mm³.
        """
        return self.rv_shell_volume(epi=True) - self.rv_shell_volume(epi=False)

    def to_dict(self) -> dict:
        """The size parameters (mm; the shape modes are in :meth:`shape_dict`).

        Returns
        -------
        dict of str to float
            Field -> value, mm (``rv_offset`` a fraction), without ``shape``.
        """
        return {k: float(getattr(self, k)) for k in self.__dataclass_fields__ if k != "shape"}

    def shape_dict(self) -> dict | None:
        """The shape modes as JSON-safe data.

        Returns
        -------
        dict or None
            :meth:`cardionurbs.phantom.shape.ShapeModes.to_dict`, None for the ideal anatomy.
        """
        return None if self.shape is None else self.shape.to_dict()
