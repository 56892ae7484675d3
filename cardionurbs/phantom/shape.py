"""Realistic anatomy of the phantom: smooth shape modes on top of the ideal spheroids.

The ideal phantom (:mod:`cardionurbs.phantom.anatomy`) has elliptic-free circular
LV sections, a uniform wall, a symmetric RV crescent, a planar base and the apex
on the long axis. :class:`ShapeModes` departs from all of these while keeping
every property the truth and the motion rely on:

* **Star-shaped sections.** Every surface is still a squared radius about the
  heart-frame z axis, now a function of angle and height,
  ``S(θ, z) = S_ideal(z) · (1 + Σ_k a_k(z) cos k(θ − φ_k))``           (R1)
  with ``k = 2, 3, 4`` on the LV endocardium. Because the modulation has zero
  mean over θ, each section's area ½∮S dθ is that of the ideal section, so the
  ideal closed forms still give the volume below any plane z = const, and the
  preset targets stay met. The k ≥ 3 modes are what an ellipse cannot follow.
* **Wall thickness by segment.** The LV epicardium carries the endocardial
  modes scaled by ``sqrt(S_endo/S_epi)`` (so the wall follows the endocardium
  radially) plus a ``cos θ`` mode that thickens the septum (θ = 0 faces the
  RV) and thins the lateral wall by the same amount; the apex is thinner
  through the preset's apical wall ratio.
* **RV crescent varying base to apex.** The RV shell's section ellipse is
  stretched about the axis by a wrap factor ``w(z)`` (wider wrap at the base,
  narrower toward the RV apex) and its free-wall reach scaled by ``(1 + ν u)``
  with ``u`` the normalised height, both smooth in z.
* **Saddle-shaped mitral annulus.** The LV endo- and epicardium end at
  ``z_top(θ) = z_b + h cos 2(θ − θ_s)`` instead of the plane z = z_b; the
  cavity is closed at the best-fit plane of the annulus points (docs/metrics.md).
* **Saddle-shaped tricuspid annulus.** The RV walls end at
  ``z_tri(θ) = z_b − h_t sin²(π (θ − θ_0) / (θ_1 − θ_0))`` over the tricuspid span
  [θ_0, θ_1] of the base crescent (the whole crescent, or with an outflow tract the part
  short of the tract's window) and at z_b elsewhere: the annulus is high at the crescent's
  tips and dips at the middle of the free wall and of the septum — two highs and two lows
  around the ring, a saddle (see :meth:`cardionurbs.phantom.anatomy.Anatomy.z_top_rv`).
* **Apex off the long axis.** Positions are displaced within their z-plane by
  ``d(z) = D (1 − z / z_b)²`` (D a 2-vector of a few mm) after the motion. The
  map (x, y, z) ↦ (x + d_x(z), y + d_y(z), z) has unit Jacobian, so volumes,
  in-plane shapes and rotations about a section's centroid are unchanged, and
  its inverse is explicit.
* **Infarct.** A coronary territory (``lad``, ``rca``, ``lcx``) is a smooth
  weight ``w_i(θ, z) ∈ [0, 1]`` (a cosine border zone of 20° around and 10 % of
  the length along); inside it the wall is thinner (the endocardium moves out, a
  thinned and dilated segment; the epicardium and the RV are unchanged) and the
  cavity contraction κ of the motion is reduced (hypokinesis), which reduces
  thickening and strain.

All amplitudes are drawn per seed from physiological ranges by :func:`draw_shape`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from cardionurbs.errors import PhantomError

#: coronary territories: (centre angle θ in degrees about the LV axis, θ = 0 toward the RV
#: i.e. the septum; half-width in degrees; lowest and highest normalised height z / z_b)
TERRITORIES = {
    "lad": (25.0, 70.0, 0.0, 0.75),    # anterior and anteroseptal wall, apex included
    "rca": (-80.0, 50.0, 0.1, 1.0),    # inferior (and inferoseptal) wall, base to mid
    "lcx": (180.0, 55.0, 0.25, 1.0),   # lateral wall, base to mid
}
ANATOMIES = ("ideal", "realistic")
INFARCT_THINNING, INFARCT_HYPOKINESIS = 0.4, 0.8


def _smooth_window(x: np.ndarray, lo: float, hi: float, border: float) -> np.ndarray:
    """1 inside [lo, hi], 0 outside [lo − border, hi + border], a cosine ramp between."""
    t = np.clip(np.minimum(x - (lo - border), (hi + border) - x) / border, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * t)


@dataclass(frozen=True)
class ShapeModes:
    """Shape departures from the ideal spheroids (all dimensionless unless in mm or degrees).

    Attributes
    ----------
    endo_modes : tuple of (int, float, float, float)
        ((k, a0, a1, phase_deg), ...) — mode k of the LV endocardium with amplitude
        ``a0 + a1 ζ`` on S (ζ = (z − z_c)/r_long_endo, clipped to [−1, 1]); eq. (R1).
    septal_thickening : float
        Amplitude of the ``cos θ`` mode on the LV epicardial S (≈ twice the relative radius
        change at the septum).
    rv_wrap_base, rv_wrap_apex : float
        Wrap factor w of the RV section at the base and at the RV apex, in [0.6, 1.4].
    rv_reach : float
        ν, relative change of the RV free-wall reach from base (+ν/2) to apex (−ν/2).
    saddle_mm, saddle_phase_deg : float
        Mitral annulus height amplitude h (mm) and orientation θ_s (degrees).
    tricuspid_dip_mm : float
        h_t, how far the tricuspid annulus dips below the base plane, mm (0: planar).
    apex_shift_mm : tuple of (float, float)
        D, the in-plane displacement of the apex (x, y), mm.
    infarct : str or None
        Coronary territory (``"lad"``, ``"rca"``, ``"lcx"``) or None.
    infarct_thinning, infarct_hypokinesis : float
        Wall thinning and loss of contraction in the territory, in [0, 1).
    outflow : cardionurbs.phantom.outflow.OutflowTracts or None
        The outflow tracts, or None.
    bends : bool
        Whether the apex is shifted off the axis (``apex_shift_mm`` not zero).

    Raises
    ------
    cardionurbs.errors.PhantomError
        An amplitude out of its range or an unknown territory.
    """

    endo_modes: tuple = ()
    septal_thickening: float = 0.0
    rv_wrap_base: float = 1.0
    rv_wrap_apex: float = 1.0
    rv_reach: float = 0.0
    saddle_mm: float = 0.0
    saddle_phase_deg: float = 0.0
    apex_shift_mm: tuple = (0.0, 0.0)
    tricuspid_dip_mm: float = 0.0
    infarct: str | None = None
    infarct_thinning: float = 0.0
    infarct_hypokinesis: float = 0.0
    outflow: object = None      # OutflowTracts (phantom/outflow.py) or None

    def __post_init__(self) -> None:
        total = sum(abs(a0) + abs(a1) for _, a0, a1, _ in self.endo_modes)
        if total >= 0.6:
            raise PhantomError(f"endocardial shape modes too large (sum of amplitudes {total:.2f} >= 0.6)")
        if not 0 <= abs(self.septal_thickening) < 0.5:
            raise PhantomError("septal_thickening must be in (-0.5, 0.5)")
        for name in ("rv_wrap_base", "rv_wrap_apex"):
            if not 0.6 <= getattr(self, name) <= 1.4:
                raise PhantomError(f"{name} must be in [0.6, 1.4]")
        if self.infarct is not None and self.infarct not in TERRITORIES:
            raise PhantomError(f"unknown infarct territory {self.infarct!r}; expected one of "
                               f"{', '.join(TERRITORIES)}")
        for name in ("infarct_thinning", "infarct_hypokinesis"):
            if not 0 <= getattr(self, name) < 1:
                raise PhantomError(f"{name} must be in [0, 1)")
        if self.saddle_mm < 0:
            raise PhantomError("saddle_mm must be >= 0")
        if not 0 <= self.tricuspid_dip_mm <= 8.0:
            raise PhantomError("tricuspid_dip_mm must be in [0, 8] mm")

    # ------------------------------------------------------------ LV
    def endo_factor(self, theta, zeta, e=None) -> np.ndarray:
        """1 + Σ a_k(ζ) cos k(θ − φ_k): the zero-mean modulation of eq. (R1) (powers of e^{iθ}
        instead of one cosine per mode; ``e`` = e^{iθ} when the caller has it).

        Parameters
        ----------
        theta : float or ndarray
            Angle θ about the LV axis, rad (θ = 0 towards the RV).
        zeta : float or ndarray
            ζ = (z − z_c) / r_long_endo (clipped to [−1, 1]).
        e : ndarray of complex, optional
            e^{iθ}.

        Returns
        -------
        ndarray
            The factor on S_ideal, broadcast shape of ``theta`` and ``zeta``.
        """
        theta = np.asarray(theta, dtype=float)
        zeta = np.minimum(np.maximum(np.asarray(zeta, dtype=float), -1.0), 1.0)     # clipped
        out = np.ones(np.broadcast(theta, zeta).shape)
        if not self.endo_modes:
            return out
        if e is None:
            e = np.exp(1j * theta)
        power, k_now = np.ones_like(e), 0
        for k, a0, a1, ph in sorted(self.endo_modes):
            while k_now < k:
                power, k_now = power * e, k_now + 1
            out = out + (a0 + a1 * zeta) * (power * np.exp(-1j * k * np.radians(ph))).real
        return out

    def epi_factor(self, theta, zeta, ratio) -> np.ndarray:
        """Epicardial modulation: the endocardial modes scaled by ``ratio`` = sqrt(S_endo/S_epi)
        (equal radial displacement), plus the septal ``cos θ`` mode.

        Parameters
        ----------
        theta : float or ndarray
            Angle θ, rad.
        zeta : float or ndarray
            ζ as in :meth:`endo_factor`.
        ratio : float or ndarray
            sqrt(S_endo / S_epi).

        Returns
        -------
        ndarray
            The factor on the ideal epicardial S.
        """
        theta = np.asarray(theta, dtype=float)
        e = np.exp(1j * theta)          # shared by the modes and the septal cos θ (its real part)
        return (1.0 + np.asarray(ratio) * (self.endo_factor(theta, zeta, e) - 1.0)
                + self.septal_thickening * e.real)

    def infarct_weight(self, theta, zn) -> np.ndarray:
        """w_i(θ, z/z_b) ∈ [0, 1]: 1 in the infarcted territory, 0 outside, cosine border zone.

        Parameters
        ----------
        theta : float or ndarray
            Angle θ, rad.
        zn : float or ndarray
            Normalised height z / z_b.

        Returns
        -------
        ndarray
            The weight, broadcast shape (0 without an infarct).
        """
        theta = np.asarray(theta, dtype=float)
        if self.infarct is None:
            return np.zeros(np.broadcast(theta, zn).shape)
        c, half, lo, hi = TERRITORIES[self.infarct]
        d = np.degrees(np.angle(np.exp(1j * (theta - np.radians(c)))))
        return _smooth_window(d, -half, half, 20.0) * _smooth_window(np.asarray(zn, dtype=float),
                                                                      lo, hi, 0.1)

    # ------------------------------------------------------------ RV
    def rv_wrap(self, u) -> np.ndarray:
        """w at normalised RV height u ∈ [0, 1] (0 at the RV apex, 1 at the base).

        Parameters
        ----------
        u : float or ndarray
            Normalised RV height, clipped to [0, 1].

        Returns
        -------
        ndarray
            The wrap factor w, shape of ``u``.
        """
        u = np.minimum(np.maximum(np.asarray(u, dtype=float), 0.0), 1.0)     # clipped
        return self.rv_wrap_apex + (self.rv_wrap_base - self.rv_wrap_apex) * u

    def rv_reach_factor(self, u) -> np.ndarray:
        """(1 + ν (u − ½))²: the factor of the RV free-wall reach on S at normalised RV
        height u.

        Parameters
        ----------
        u : float or ndarray
            Normalised RV height, clipped to [0, 1] (0 at the RV apex, 1 at the base).

        Returns
        -------
        ndarray
            The factor, shape of ``u``.
        """
        u = np.minimum(np.maximum(np.asarray(u, dtype=float), 0.0), 1.0)     # clipped
        return (1.0 + self.rv_reach * (u - 0.5)) ** 2

    # ------------------------------------------------------------ base and apex
    def saddle(self, theta) -> np.ndarray:
        """Height of the mitral annulus above the nominal base plane, mm: h cos 2(θ − θ_s).

        Parameters
        ----------
        theta : float or ndarray
            Angle θ, rad.

        Returns
        -------
        ndarray
            The height in mm, shape of ``theta``.
        """
        return self.saddle_mm * np.cos(2.0 * (np.asarray(theta, dtype=float)
                                              - np.radians(self.saddle_phase_deg)))

    def apex_shift(self, z, z_base: float) -> np.ndarray:
        """d(z) = D (1 − z/z_b)² for z below the base (0 above it), (n, 2) mm.

        Parameters
        ----------
        z : float or ndarray, shape (n,)
            Heights in the heart frame, mm.
        z_base : float
            The base height z_b, mm.

        Returns
        -------
        ndarray, shape (n, 2)
            The in-plane displacement (x, y), mm.
        """
        z = np.atleast_1d(np.asarray(z, dtype=float))
        w = np.maximum(1.0 - z / z_base, 0.0) ** 2
        return w[:, None] * np.asarray(self.apex_shift_mm, dtype=float)[None, :]

    @property
    def bends(self) -> bool:
        return bool(np.any(np.asarray(self.apex_shift_mm) != 0.0))

    def displace(self, points: np.ndarray, z_base: float, sign: float = 1.0) -> np.ndarray:
        """(n, 3) points moved by ``sign`` · d(z) within their z-planes (+1: the apex bend, −1: its
        inverse, exact because z is kept); a copy.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Heart-frame positions, mm.
        z_base : float
            The base height z_b, mm.
        sign : float, optional
            +1 (the bend) or −1 (its inverse).

        Returns
        -------
        ndarray, shape (n, 3)
            The moved points, mm.
        """
        p = np.array(points, dtype=float).reshape(-1, 3)
        if self.bends:
            p[:, :2] += sign * self.apex_shift(p[:, 2], z_base)
        return p

    def to_dict(self) -> dict:
        """JSON-safe fields (truth.json ``shape``).

        Returns
        -------
        dict
            Every field, tuples as lists, ``outflow`` as its dict; ``outflow`` and a zero
            ``tricuspid_dip_mm`` left out (the files of older phantoms stay the same).
        """
        d = asdict(self)
        d["endo_modes"] = [list(m) for m in self.endo_modes]
        d["apex_shift_mm"] = [float(v) for v in self.apex_shift_mm]
        if self.outflow is None:        # absent, as before outflow tracts existed
            del d["outflow"]
        else:
            d["outflow"] = self.outflow.to_dict()
        if self.tricuspid_dip_mm == 0.0:    # absent for a planar tricuspid annulus (ideal + infarct)
            del d["tricuspid_dip_mm"]
        return d


def draw_shape(rng: np.random.Generator, infarct: str | None = None) -> ShapeModes:
    """Realistic shape departures drawn per subject (ranges chosen so that a mid-ventricular
    endocardial section departs from its best-fit ellipse by 1–2 mm RMS and the annulus from its
    plane by 2.5–4 mm at the high points). The tricuspid dip comes from its own generator
    (:func:`draw_tricuspid_dip`), so that adding it changed no other draw.

    Parameters
    ----------
    rng : numpy.random.Generator
        The subject's shape generator.
    infarct : str or None, optional
        A coronary territory (``"lad"``, ``"rca"``, ``"lcx"``).

    Returns
    -------
    ShapeModes
        The drawn departures (no tricuspid dip, no outflow tracts).
    """
    modes = []
    for k, lo, hi in ((2, 0.06, 0.12), (3, 0.11, 0.14), (4, 0.07, 0.09)):
        a0 = float(rng.uniform(lo, hi))
        a1 = float(rng.uniform(-0.3, 0.3)) * a0
        modes.append((k, a0, a1, float(rng.uniform(0.0, 360.0 / k))))
    return ShapeModes(
        endo_modes=tuple(modes),
        septal_thickening=float(rng.uniform(0.08, 0.14)),
        rv_wrap_base=float(rng.uniform(1.05, 1.15)),
        rv_wrap_apex=float(rng.uniform(0.8, 0.9)),
        rv_reach=float(rng.uniform(0.1, 0.25)),
        saddle_mm=float(rng.uniform(3.0, 4.0)),
        saddle_phase_deg=float(rng.uniform(-20.0, 20.0)),
        apex_shift_mm=_apex_shift(rng),
        infarct=infarct,
        infarct_thinning=INFARCT_THINNING if infarct else 0.0,
        infarct_hypokinesis=INFARCT_HYPOKINESIS if infarct else 0.0)


def draw_tricuspid_dip(rng: np.random.Generator) -> float:
    """h_t, how far the saddle-shaped tricuspid annulus dips below the base plane: 3–5 mm.

    Parameters
    ----------
    rng : numpy.random.Generator
        Its own generator.

    Returns
    -------
    float
        h_t in mm.
    """
    return float(rng.uniform(3.0, 5.0))


def _apex_shift(rng: np.random.Generator) -> tuple:
    ang = rng.uniform(0.0, 2 * np.pi)
    mag = rng.uniform(4.0, 8.0)
    return (float(mag * np.cos(ang)), float(mag * np.sin(ang)))


def infarct_only(infarct: str) -> ShapeModes:
    """The ideal shapes with only an infarct (thinning 40 %, hypokinesis 80 % in the territory).

    Parameters
    ----------
    infarct : str
        A coronary territory.

    Returns
    -------
    ShapeModes
        The modes.

    Raises
    ------
    cardionurbs.errors.PhantomError
        An unknown territory.
    """
    return ShapeModes(infarct=infarct, infarct_thinning=INFARCT_THINNING,
                      infarct_hypokinesis=INFARCT_HYPOKINESIS)
