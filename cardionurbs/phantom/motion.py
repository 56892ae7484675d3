"""Analytic, invertible, myocardium-volume-preserving motion of the phantom.

The map φ_t takes a material point (ED position, heart frame, cylindrical
``(s = r², θ, z)`` about the LV long axis, apex at z = 0) to its position at
time t. With the cycle phase f(t) ∈ [0, 1] (0 at ED, 1 at ES, see
:class:`VolumeCurve`):

    z' = λ z,                     λ = 1 − LS · f                       (M1)
    θ' = θ − ψ(z),                ψ(z) = f [ψ_apex + (ψ_base − ψ_apex) z / z_b]   (M2)
    s' = G(s; θ, z)               piecewise linear in s                  (M3)

With outflow tracts (:mod:`cardionurbs.phantom.outflow`) ψ is held at its value at
``z_twist_max`` (the top of the mitral saddle) above it: the tracts turn with the base.
ψ is the rotation counter-clockwise **as seen from the apex looking toward the
base** (a negative rotation about +z), so ψ_apex > 0 and ψ_base < 0 give the
normal wringing twist. With the ED section radii² S1 = s_endo(z),
S2 = s_epi(z), S3 = max(S2, S_rv_endo(θ, z)):

    G(s) = κ_L s / λ                                   s ≤ S1   (LV cavity)
         = (κ_L S1 + (s − S1)) / λ                     S1 ≤ s ≤ S2 (LV wall)
         = (κ_L S1 + S2 − S1 + κ_R (s − S2)) / λ       S2 ≤ s ≤ S3 (RV cavity)
         = (κ_L S1 + S2 − S1 + κ_R (S3 − S2) + s − S3) / λ    s ≥ S3 (RV wall, outside)

with κ_L(θ) = (1 − EF_L f)(1 − ε f cos 2θ) and κ_R = 1 − EF_R f. This is the
brief's ``r'² = r²/λ + b(θ, z, t)`` in every tissue layer (b is constant in s
within a layer) and a scaling inside each cavity, so φ_t is a continuous
bijection of space.

Volume. dV = ½ ds dθ dz. The Jacobian of (s, θ, z) ↦ (s', θ', z') is upper
triangular (θ' depends on θ, z; z' on z), so det = ∂s'/∂s · 1 · λ. In every
myocardial layer ∂s'/∂s = 1/λ, hence **dV' = dV exactly** and myocardial
volume is constant for any parameters. In the LV cavity det = κ_L, so
V_LV(t) = ∫∫ ½ κ_L S1 dθ dz = (1 − EF_L f) V_LV(ED) (the cos 2θ term has zero
mean), and likewise V_RV(t) = (1 − EF_R f) V_RV(ED): ejection fractions are
prescribed exactly. ε flattens the septum at ES (eccentricity index
EI ≈ sqrt((1 + ε)/(1 − ε)) on every section), used for pulmonary hypertension.

Inverse. z = z'/λ, θ = θ' + ψ(z), then G is inverted layer by layer (its
breakpoints are G(S1), G(S2), G(S3)) — closed form, vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PchipInterpolator

from cardionurbs.errors import PhantomError
from cardionurbs.phantom.anatomy import Anatomy


@dataclass(frozen=True)
class VolumeCurve:
    """Normalised cycle phase f(τ), τ = t / RR ∈ [0, 1): 0 at ED, 1 at ES (τ = es_fraction).

    Monotone piecewise-cubic (PCHIP) through physiological knots: isovolumic
    contraction, ejection (fast then slow) up to ES, then isovolumic relaxation,
    rapid filling, diastasis and the atrial kick (fraction of the stroke volume
    refilled in each phase given by the knot values).

    Attributes
    ----------
    es_fraction : float
        τ of ES, in [0.2, 0.6].
    rapid_filling : float
        Fraction of the stroke volume refilled in rapid filling.
    diastasis : float
        Further fraction refilled in diastasis (the rest is the atrial kick).

    Raises
    ------
    cardionurbs.errors.PhantomError
        ``es_fraction`` out of range, or the filling fractions not positive or summing to 1 or
        more.
    """

    es_fraction: float = 0.35
    rapid_filling: float = 0.65     # fraction of SV refilled in rapid filling
    diastasis: float = 0.12         # further fraction in diastasis
    # the rest (1 - rapid - diastasis) is the atrial kick

    def __post_init__(self) -> None:
        if not (0.2 <= self.es_fraction <= 0.6):
            raise PhantomError(f"es_fraction must be in [0.2, 0.6], got {self.es_fraction!r}")
        if not (0 < self.rapid_filling and 0 <= self.diastasis
                and self.rapid_filling + self.diastasis < 1):
            raise PhantomError("filling fractions must be positive and sum below 1")

    def knots(self) -> tuple[np.ndarray, np.ndarray]:
        """The PCHIP knots of the curve.

        Returns
        -------
        tau : ndarray, shape (10,)
            Knot times τ = t / RR, from 0 to 1.
        f : ndarray, shape (10,)
            The phase at each knot (0 at ED, 1 at ES).
        """
        e = self.es_fraction
        d = 1.0 - e
        ts = [0.0, 0.1 * e, 0.5 * e, 0.8 * e, e,
              e + 0.12 * d, e + 0.35 * d, e + 0.75 * d, e + 0.85 * d, 1.0]
        fs = [0.0, 0.02, 0.62, 0.93, 1.0,
              0.98, 1.0 - self.rapid_filling, 1.0 - self.rapid_filling - self.diastasis,
              1.0 - self.rapid_filling - self.diastasis, 0.0]
        return np.asarray(ts), np.asarray(fs)

    def __call__(self, tau: np.ndarray) -> np.ndarray:
        ts, fs = self.knots()
        return PchipInterpolator(ts, fs)(np.mod(np.asarray(tau, dtype=float), 1.0))

    def derivative(self, tau: np.ndarray) -> np.ndarray:
        """df/dτ, exact (the derivative of the piecewise cubic); one-sided at the knots
        (at τ = 0 the slope of the start of the beat, τ -> 1 the end: the curve has a
        corner at ED).

        Parameters
        ----------
        tau : float or ndarray
            τ = t / RR (taken modulo 1).

        Returns
        -------
        ndarray
            df/dτ, shape of ``tau``.
        """
        ts, fs = self.knots()
        return PchipInterpolator(ts, fs).derivative()(np.mod(np.asarray(tau, dtype=float), 1.0))


@dataclass(frozen=True)
class Motion:
    """Prescribed motion parameters at ES (f = 1), see the module docstring.

    Attributes
    ----------
    ls : float
        Longitudinal shortening fraction (1 − λ at ES), in [0, 0.5).
    lv_ef, rv_ef : float
        Ejection fractions (fractions, not %), in [0, 0.95).
    septal_flattening : float
        ε at ES, in [0, 0.8).
    apex_rotation_deg, base_rotation_deg : float
        ψ at z = 0 and z = z_b at ES, degrees counter-clockwise seen from the apex (M2).
    z_base : float
        Base height used in ψ(z), mm.
    curve : VolumeCurve
        The phase curve f.
    z_twist_max : float or None
        Height above which ψ is held (the top of the mitral saddle), mm; None: not held.

    Raises
    ------
    cardionurbs.errors.PhantomError
        A parameter out of its range, or an LV cavity that ejection and septal flattening
        would collapse.
    """

    ls: float
    lv_ef: float
    rv_ef: float
    septal_flattening: float
    apex_rotation_deg: float
    base_rotation_deg: float
    z_base: float
    curve: VolumeCurve = field(default_factory=VolumeCurve)
    z_twist_max: float | None = None    # ψ(z) is held at ψ(z_twist_max) above this height (mm)

    def __post_init__(self) -> None:
        for name, lo, hi in (("ls", 0.0, 0.5), ("lv_ef", 0.0, 0.95), ("rv_ef", 0.0, 0.95),
                             ("septal_flattening", 0.0, 0.8)):
            v = getattr(self, name)
            if not (np.isfinite(v) and lo <= v < hi):
                raise PhantomError(f"motion parameter {name} must be in [{lo}, {hi}), got {v!r}")
        if (1 - self.lv_ef) * (1 - self.septal_flattening) <= 0.02:
            raise PhantomError("LV ejection with septal flattening collapses the cavity")

    # ------------------------------------------------------------ fields
    def lam(self, f) -> np.ndarray:
        """λ(f) of eq. (M1).

        Parameters
        ----------
        f : float or ndarray
            The cycle phase.

        Returns
        -------
        ndarray
            λ, shape of ``f``.
        """
        return 1.0 - self.ls * np.asarray(f, dtype=float)

    def psi(self, z, f) -> np.ndarray:
        """ψ(z, f) of eq. (M2), radians, CCW seen from the apex.

        Parameters
        ----------
        z : float or ndarray
            Material height, mm.
        f : float or ndarray
            The cycle phase.

        Returns
        -------
        ndarray
            ψ in rad, broadcast shape.
        """
        a, b = np.radians(self.apex_rotation_deg), np.radians(self.base_rotation_deg)
        z = np.asarray(z, dtype=float)
        if self.z_twist_max is not None:
            # the outflow tracts above the LV walls turn with the base, not beyond it
            z = np.minimum(z, self.z_twist_max)
        return np.asarray(f, dtype=float) * (a + (b - a) * z / self.z_base)

    def kappa_lv(self, theta, f, z=None, anatomy: Anatomy | None = None) -> np.ndarray:
        """κ_L(θ, f); with an infarcted realistic anatomy the ejection term is reduced by the
        hypokinesis inside the territory: 1 − EF f (1 − η w_i(θ, z/z_b)).

        Parameters
        ----------
        theta : float or ndarray
            Material angle θ, rad.
        f : float or ndarray
            The cycle phase.
        z : float or ndarray, optional
            Material height, mm (needed for the infarct).
        anatomy : cardionurbs.phantom.anatomy.Anatomy, optional
            The anatomy (its infarct).

        Returns
        -------
        ndarray
            κ_L, broadcast shape.
        """
        f = np.asarray(f, dtype=float)
        eject = self.lv_ef * f
        shape = anatomy.shape if anatomy is not None else None
        if shape is not None and shape.infarct is not None and z is not None:
            w = shape.infarct_weight(theta, np.asarray(z, dtype=float) / anatomy.z_base)
            eject = eject * (1.0 - shape.infarct_hypokinesis * w)
        return (1.0 - eject) * (1.0 - self.septal_flattening * f * np.cos(2.0 * np.asarray(theta)))

    def kappa_rv(self, f) -> np.ndarray:
        """κ_R(f) = 1 − EF_R f, the RV cavity's scaling in (M3).

        Parameters
        ----------
        f : float or ndarray
            The cycle phase (0 at ED, 1 at ES).

        Returns
        -------
        ndarray
            κ_R, shape of ``f``.
        """
        return 1.0 - self.rv_ef * np.asarray(f, dtype=float)

    # ------------------------------------------------------------ the map
    def _knots(self, anatomy: Anatomy, theta, z, f, layers=None):
        """The piecewise-linear map (M3) at material (θ, z), phase f, before the 1/λ: its knots
        S1, S2, S3 (``layers`` when the caller has them), the slopes κ_LV, κ_RV of the cavity
        layers and the images λ·G(S_k) = B1, B2, B3 of the knots (slope 1 in the walls)."""
        if layers is None:
            s1, s2 = anatomy.lv_sections(z, theta)
            s3 = np.maximum(s2, anatomy.s_rv(theta, z))
        else:
            s1, s2, s3 = layers
        kl, kr = self.kappa_lv(theta, f, z, anatomy), self.kappa_rv(f)
        b1 = kl * s1
        b2 = b1 + (s2 - s1)
        b3 = b2 + kr * (s3 - s2)
        return (s1, s2, s3), (kl, kr), (b1, b2, b3)

    def knots(self, anatomy: Anatomy, theta, z, f, layers=None):
        """The knots, slopes and knot images of (M3) at material (θ, z), phase f (:meth:`_knots`),
        to pass as ``knots=`` to :meth:`radial_map` and :meth:`inverse_radial_map` when several
        maps share one place (the same values as computing them in each call).

        Parameters
        ----------
        anatomy : cardionurbs.phantom.anatomy.Anatomy
            The anatomy.
        theta : float or ndarray
            Material angle θ, rad.
        z : float or ndarray
            Material height, mm.
        f : float
            The cycle phase.
        layers : tuple of ndarray, optional
            (S1, S2, S3) at (θ, z), mm².

        Returns
        -------
        tuple
            ((S1, S2, S3), (κ_L, κ_R), (B1, B2, B3)), the S and B in mm².
        """
        return self._knots(anatomy, np.asarray(theta, dtype=float), np.asarray(z, dtype=float), f,
                           layers)

    def radial_map(self, anatomy: Anatomy, s, theta, z, f, layers=None, knots=None) -> np.ndarray:
        """s' = G(s; θ, z) of eq. (M3) for material (s, θ, z) at phase f. ``layers``: the section
        values (S1, S2, S3) at (θ, z) when the caller has them already (several s at one place);
        ``knots``: :meth:`knots` at (θ, z), f, likewise.

        Parameters
        ----------
        anatomy : cardionurbs.phantom.anatomy.Anatomy
            The anatomy.
        s : float or ndarray
            Material s = r², mm².
        theta : float or ndarray
            Material angle θ, rad.
        z : float or ndarray
            Material height, mm.
        f : float
            The cycle phase.
        layers : tuple of ndarray, optional
            (S1, S2, S3) at (θ, z), mm².
        knots : tuple, optional
            :meth:`knots` at (θ, z), f.

        Returns
        -------
        ndarray
            s' in mm², broadcast shape.
        """
        if knots is None:
            s, theta, z = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (s, theta, z)))
            knots = self._knots(anatomy, theta, z, f, layers)
        else:
            s = np.asarray(s, dtype=float)
        (s1, s2, s3), (kl, kr), (b1, b2, b3) = knots
        out = np.where(s <= s1, kl * s,
                       np.where(s <= s2, b1 + (s - s1),
                                np.where(s <= s3, b2 + kr * (s - s2), b3 + (s - s3))))
        return out / self.lam(f)

    def _inverse_layers(self, anatomy: Anatomy, s_def, theta, z, f, layers=None, knots=None):
        """Material s from deformed s' at material (θ, z) (inverse of eq. M3), with S1, S2, S3
        (``layers``: those section values when the caller has them already; ``knots``: :meth:`knots`)."""
        (s1, s2, s3), (kl, kr), (b1, b2, b3) = (knots if knots is not None
                                                else self._knots(anatomy, theta, z, f, layers))
        u = s_def * self.lam(f)
        s = np.where(u <= b1, u / kl,
                     np.where(u <= b2, s1 + (u - b1),
                              np.where(u <= b3, s2 + (u - b2) / kr, s3 + (u - b3))))
        return s, s1, s2, s3

    def inverse_radial_map(self, anatomy: Anatomy, s_def, theta, z, f, layers=None,
                           knots=None) -> np.ndarray:
        """Material s from deformed s' at material (θ, z): inverse of eq. (M3).

        Parameters
        ----------
        anatomy : cardionurbs.phantom.anatomy.Anatomy
            The anatomy.
        s_def : float or ndarray
            Deformed s' = r'², mm².
        theta : float or ndarray
            Material angle θ, rad.
        z : float or ndarray
            Material height, mm.
        f : float
            The cycle phase.
        layers : tuple of ndarray, optional
            (S1, S2, S3) at (θ, z), mm².
        knots : tuple, optional
            :meth:`knots` at (θ, z), f.

        Returns
        -------
        ndarray
            Material s in mm², broadcast shape.
        """
        if knots is not None:
            return self._inverse_layers(anatomy, np.asarray(s_def, dtype=float), theta, z, f,
                                        knots=knots)[0]
        sp, theta, z = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (s_def, theta, z)))
        return self._inverse_layers(anatomy, sp, theta, z, f, layers)[0]

    def forward(self, anatomy: Anatomy, points: np.ndarray, f: float) -> np.ndarray:
        """φ_f: (n, 3) material heart-frame points (ED, mm) -> positions at phase f (mm).

        Parameters
        ----------
        anatomy : cardionurbs.phantom.anatomy.Anatomy
            The anatomy.
        points : ndarray, shape (n, 3)
            Material (ED) heart-frame points, mm.
        f : float
            The cycle phase.

        Returns
        -------
        ndarray, shape (n, 3)
            Positions at phase f, mm.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        s, theta = x * x + y * y, np.arctan2(y, x)
        sp = self.radial_map(anatomy, s, theta, z, f)
        thp = theta - self.psi(z, f)
        r = np.sqrt(np.maximum(sp, 0.0))
        return np.column_stack([r * np.cos(thp), r * np.sin(thp), self.lam(f) * z])

    def inverse_cylindrical(self, anatomy: Anatomy, points: np.ndarray, f: float):
        """φ_f⁻¹ in cylindrical form: material (s, θ, z) of (n, 3) heart-frame positions at phase f,
        with the section values S1 = s_endo, S2 = s_epi, S3 = max(S2, S_rv_endo) at (θ, z).

        Parameters
        ----------
        anatomy : cardionurbs.phantom.anatomy.Anatomy
            The anatomy.
        points : ndarray, shape (n, 3)
            Heart-frame positions at phase f, mm.
        f : float
            The cycle phase.

        Returns
        -------
        tuple of ndarray, each shape (n,)
            (s, θ, z, S1, S2, S3): s and the S in mm², θ in rad, z in mm.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        z = p[:, 2] / self.lam(f)
        theta = np.arctan2(p[:, 1], p[:, 0]) + self.psi(z, f)
        s, s1, s2, s3 = self._inverse_layers(anatomy, p[:, 0] ** 2 + p[:, 1] ** 2, theta, z, f)
        return s, theta, z, s1, s2, s3

    def inverse(self, anatomy: Anatomy, points: np.ndarray, f: float) -> np.ndarray:
        """φ_f⁻¹: (n, 3) heart-frame positions at phase f -> material ED points (mm).

        Parameters
        ----------
        anatomy : cardionurbs.phantom.anatomy.Anatomy
            The anatomy.
        points : ndarray, shape (n, 3)
            Heart-frame positions at phase f, mm.
        f : float
            The cycle phase.

        Returns
        -------
        ndarray, shape (n, 3)
            Material (ED) points, mm.
        """
        s, theta, z = self.inverse_cylindrical(anatomy, points, f)[:3]
        r = np.sqrt(np.maximum(s, 0.0))
        return np.column_stack([r * np.cos(theta), r * np.sin(theta), z])

    def to_dict(self) -> dict:
        """JSON-safe parameters (truth.json ``motion``).

        Returns
        -------
        dict
            The fields (``z_base_mm``, ``z_twist_max_mm`` when set, in mm; rotations in
            degrees) and the curve's ``es_fraction``, ``rapid_filling``, ``diastasis``.
        """
        return {"ls": self.ls, "lv_ef": self.lv_ef, "rv_ef": self.rv_ef,
                "septal_flattening": self.septal_flattening,
                "apex_rotation_deg": self.apex_rotation_deg,
                "base_rotation_deg": self.base_rotation_deg, "z_base_mm": self.z_base,
                "es_fraction": self.curve.es_fraction, "rapid_filling": self.curve.rapid_filling,
                "diastasis": self.curve.diastasis,
                **({} if self.z_twist_max is None else {"z_twist_max_mm": self.z_twist_max})}
