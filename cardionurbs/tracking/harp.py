"""Harmonic phase (HARP) images and phase-invariant point tracking.

Osman, Kerwin, McVeigh & Prince, *Cardiac motion tracking using CINE
harmonic phase (HARP) magnetic resonance imaging*, MRM 42 (1999) 1048–1060,
and Osman, McVeigh & Prince, *Imaging heart motion using harmonic phase
MRI*, IEEE TMI 19 (2000) 186–202.

Harmonic image
    A band-pass filter around one tag family's first harmonic peak k
    (cycles/pixel) isolates H(x) = A(x) exp(iφ(x)): A the harmonic magnitude
    (anatomy × tag depth), φ the harmonic phase, a material property — at
    the first frame φ = 2π k·X + const, and a material point keeps its phase
    as it moves (phase invariance, up to the 2π wrap). The filter here is an
    isotropic Gaussian of standard deviation ``sigma`` |k| around k, which
    leaves out the DC peak, the other family (|k_1 − k_2| = √2 |k| for a grid)
    and the second harmonic.
Baseband storage
    H is stored demodulated, D(x) = H(x) exp(−2πi k·x), which varies slowly
    (only with the motion): bilinear interpolation of D at sub-pixel
    positions and finite differences of its angle are accurate, and
    φ(x) = arg D(x) + 2π k·x, ∇φ(x) = 2π k + ∇ arg D(x) (no wrap in the
    gradient).
Tracking
    A point x_0 at the first frame carries the target phases φ_j(x_0) of
    every family j. At frame t it is found by Newton's method on
    r_j(x) = wrap(φ_j,t(x) − φ_j(x_0)) (Osman 1999, eq. 12): with two
    families (SA grids) the 2×2 step −J⁻¹ r, J rows ∇φ_j; with one family
    (LA views) the minimum-norm step −r ∇φ / |∇φ|² along the tag normal
    (motion along the tag is not observable). The start is the temporal
    prior: x_{t−1} moved by the displacement of the nearby myocardial contours
    from t − 1 to t when the study has them (the wall's own motion, which
    keeps a fast basal descent from slipping a tag), else x_{t−1} +
    ½ (x_{t−1} − x_{t−2}) (damped constant velocity).
    Newton on the wrapped phase converges to the solution nearest the
    start *in phase*; when the start is more than half a tag spacing off,
    it lands one tag away (the "tag jump" of HARP, a 2π slip). The
    refinement step (Osman 2000, §III-C) catches these: each point's
    displacement is compared with the median displacement of its nearest
    neighbours, and a point more than ``SLIP`` of a spacing off along a tag
    normal is restarted from its neighbours' displacement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft
from scipy.spatial import cKDTree

from cardionurbs.cache import memoized

#: Gaussian band-pass standard deviation, as a fraction of |k|
FILTER_SIGMA = 0.25
#: Newton iterations per frame
NEWTON_ITERATIONS = 6
#: a displacement this many tag spacings off its neighbours' (along a tag normal) is a slip
SLIP = 0.35


def wrap(a: np.ndarray) -> np.ndarray:
    """Angle(s) wrapped to [−π, π).

    Parameters
    ----------
    a : array_like of float
        Angles in rad, any shape.

    Returns
    -------
    ndarray
        The angles wrapped to [−π, π), same shape.
    """
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def harmonic_filter(shape: tuple[int, int], k: np.ndarray, sigma: float = FILTER_SIGMA) -> np.ndarray:
    """Gaussian band-pass (rows, columns) around k = (k_c, k_r), std ``sigma`` |k| (cycles/px).

    Parameters
    ----------
    shape : tuple of (int, int)
        The image shape (rows, columns).
    k : ndarray, shape (2,)
        The harmonic peak (k_c, k_r), in cycles/pixel.
    sigma : float, optional
        The filter's standard deviation as a fraction of |k| (default :data:`FILTER_SIGMA`).

    Returns
    -------
    ndarray of float, shape (rows, columns)
        The filter in FFT order (:func:`numpy.fft.fftfreq` frequencies), 1 at k.
    """
    kr = np.fft.fftfreq(shape[0])[:, None]
    kc = np.fft.fftfreq(shape[1])[None, :]
    s = sigma * float(np.linalg.norm(k))
    return np.exp(-0.5 * ((kc - k[0]) ** 2 + (kr - k[1]) ** 2) / s ** 2)


@dataclass
class HarmonicSeries:
    """Baseband harmonic images D_t (T, rows, columns) of one tag family, and their k.

    Attributes
    ----------
    k : ndarray, shape (2,)
        The family's harmonic peak (k_c, k_r), in cycles/pixel.
    baseband : ndarray of complex, shape (T, rows, columns)
        D_t(x) = H_t(x) exp(−2πi k·x) of every frame t (0-based).
    """

    k: np.ndarray
    baseband: np.ndarray

    @classmethod
    def from_images(cls, images: np.ndarray, k: np.ndarray, sigma: float = FILTER_SIGMA,
                    spectra: np.ndarray | None = None) -> "HarmonicSeries":
        """Band-pass every frame of ``images`` (T, rows, columns) around k and demodulate.

        ``spectra``: the frames' 2-D FFTs when already computed (shared by the families).

        Parameters
        ----------
        images : ndarray, shape (T, rows, columns)
            The tagged cine frames of one slice (intensities).
        k : ndarray, shape (2,)
            The family's harmonic peak (k_c, k_r), in cycles/pixel.
        sigma : float, optional
            The filter's width as a fraction of |k|.
        spectra : ndarray of complex, shape (T, rows, columns), optional
            ``scipy.fft.fft2`` of ``images`` over the last two axes.

        Returns
        -------
        HarmonicSeries
            The baseband harmonic images of the family.
        """
        images = np.asarray(images, dtype=float)
        if spectra is None:
            spectra = sfft.fft2(images, axes=(-2, -1))
        H = sfft.ifft2(spectra * harmonic_filter(images.shape[-2:], k, sigma), axes=(-2, -1))
        rows, cols = images.shape[-2:]
        carrier = np.exp(-2j * np.pi * (k[0] * np.arange(cols)[None, :]
                                        + k[1] * np.arange(rows)[:, None]))
        return cls(np.asarray(k, float), H * carrier)

    @property
    def frames(self) -> int:
        return self.baseband.shape[0]

    def harmonic(self, t: int) -> np.ndarray:
        """H_t on the pixel grid (complex).

        Parameters
        ----------
        t : int
            The frame index, 0-based.

        Returns
        -------
        ndarray of complex, shape (rows, columns)
            H_t = A exp(iφ): magnitude and harmonic phase at every pixel.
        """
        rows, cols = self.baseband.shape[1:]
        carrier = np.exp(2j * np.pi * (self.k[0] * np.arange(cols)[None, :]
                                       + self.k[1] * np.arange(rows)[:, None]))
        return self.baseband[t] * carrier

    @memoized
    def _grid_fields(self, t: int) -> np.ndarray:
        """(4, rows, cols): Re D, Im D, ∂ arg D/∂c, ∂ arg D/∂r at frame t (cached)."""
        D = self.baseband[t]
        gc = np.zeros(D.shape)
        gr = np.zeros(D.shape)
        gc[:, 1:-1] = np.angle(D[:, 2:] * np.conj(D[:, :-2])) / 2
        gc[:, 0], gc[:, -1] = gc[:, 1], gc[:, -2]
        gr[1:-1] = np.angle(D[2:] * np.conj(D[:-2])) / 2
        gr[0], gr[-1] = gr[1], gr[-2]
        return np.stack([D.real, D.imag, gc, gr])

    def sample(self, t: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(phase φ (n,), gradient ∇φ (n, 2) rad/px in (c, r), magnitude (n,)) at (n, 2) (c, r).

        Parameters
        ----------
        t : int
            The frame index, 0-based.
        points : ndarray, shape (n, 2)
            Pixel positions (column c, row r), sub-pixel.

        Returns
        -------
        phase : ndarray, shape (n,)
            The unwrapped-by-carrier harmonic phase φ, in rad.
        gradient : ndarray, shape (n, 2)
            ∇φ in rad/px, (∂/∂c, ∂/∂r).
        magnitude : ndarray, shape (n,)
            The harmonic magnitude |H| (image intensity units).
        """
        p = np.asarray(points, float)
        re, im, gc, gr = bilinear(self._grid_fields(t), p)
        phase = np.angle(re + 1j * im) + 2 * np.pi * (p @ self.k)
        grad = np.column_stack([gc, gr]) + 2 * np.pi * self.k[None, :]
        return phase, grad, np.hypot(re, im)


def bilinear(fields: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of (m, rows, cols) fields at (n, 2) (c, r) points -> (m, n);
    points beyond the grid take the border values.

    Parameters
    ----------
    fields : ndarray, shape (m, rows, columns)
        The fields sampled.
    points : ndarray, shape (n, 2)
        Pixel positions (column c, row r).

    Returns
    -------
    ndarray, shape (m, n)
        Each field's value at each point.
    """
    R, C = fields.shape[1:]
    c = np.clip(points[:, 0], 0.0, C - 1 - 1e-9)
    r = np.clip(points[:, 1], 0.0, R - 1 - 1e-9)
    c0, r0 = c.astype(int), r.astype(int)
    wc, wr = c - c0, r - r0
    f00, f01 = fields[:, r0, c0], fields[:, r0, c0 + 1]
    f10, f11 = fields[:, r0 + 1, c0], fields[:, r0 + 1, c0 + 1]
    return (f00 * (1 - wc) + f01 * wc) * (1 - wr) + (f10 * (1 - wc) + f11 * wc) * wr


def newton_step(residuals: list[np.ndarray], gradients: list[np.ndarray]) -> np.ndarray:
    """Newton step (n, 2) for wrapped phase residuals of one or two families (see module doc).

    Parameters
    ----------
    residuals : list of ndarray, shape (n,)
        Wrapped phase residuals r_j in rad, one array per family (one or two).
    gradients : list of ndarray, shape (n, 2)
        The phase gradients ∇φ_j in rad/px, (c, r), one array per family.

    Returns
    -------
    ndarray, shape (n, 2)
        The step (Δc, Δr) in px: −J⁻¹ r for two families, −r ∇φ / |∇φ|² for one
        (Osman 1999, eq. 12).
    """
    if len(residuals) == 1:
        g, r = gradients[0], residuals[0]
        return -(r / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
    g1, g2 = gradients[0], gradients[1]
    r1, r2 = residuals[0], residuals[1]
    det = g1[:, 0] * g2[:, 1] - g1[:, 1] * g2[:, 0]
    det = np.where(np.abs(det) < 1e-9, 1e-9, det)
    dc = -(g2[:, 1] * r1 - g1[:, 1] * r2) / det
    dr = -(-g2[:, 0] * r1 + g1[:, 0] * r2) / det
    return np.column_stack([dc, dr])


def solve_phase(series: list[HarmonicSeries], t: int, start: np.ndarray, targets: list[np.ndarray],
                iterations: int = NEWTON_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 2) at frame t whose phases equal ``targets`` (Newton from ``start``), and
    the final residual (n,) rad (largest over the families).

    Parameters
    ----------
    series : list of HarmonicSeries
        The families of the slice (one or two).
    t : int
        The frame index, 0-based.
    start : ndarray, shape (n, 2)
        Start positions (c, r), in px.
    targets : list of ndarray, shape (n,)
        Each family's target phase of each point, in rad.
    iterations : int, optional
        Newton iterations (default :data:`NEWTON_ITERATIONS`); each step is capped at a
        quarter tag period.

    Returns
    -------
    positions : ndarray, shape (n, 2)
        The found positions (c, r), in px.
    residual : ndarray, shape (n,)
        The largest |wrapped phase residual| over the families, in rad.
    """
    x = np.array(start, float)
    max_step = 0.25 / max(float(np.linalg.norm(s.k)) for s in series)
    for _ in range(iterations):
        res, grads = [], []
        for s, tg in zip(series, targets):
            ph, g, _ = s.sample(t, x)
            res.append(wrap(ph - tg))
            grads.append(g)
        step = newton_step(res, grads)
        n = np.linalg.norm(step, axis=1, keepdims=True)
        x = x + step * np.minimum(1.0, max_step / np.maximum(n, 1e-12))
    resid = np.max([np.abs(wrap(s.sample(t, x)[0] - tg)) for s, tg in zip(series, targets)], axis=0)
    return x, resid


def track(series: list[HarmonicSeries], seeds: np.ndarray, frames: int | None = None,
          neighbours: int = 8, prior=None) -> tuple[np.ndarray, np.ndarray]:
    """HARP-track ``seeds`` (n, 2) (c, r) px from frame 0 through ``frames`` frames.

    Returns positions (T, n, 2) and phase residuals (T, n) rad (0 at frame 0).
    See the module docstring: temporal prior, Newton on the wrapped phase, and the
    neighbour refinement that restarts 2π slips. ``prior(t, positions)``, when given,
    returns the expected displacement (n, 2) from frame t − 1 to t (e.g. from the moving
    contours), or None to use the damped constant-velocity prior at that frame.

    Parameters
    ----------
    series : list of HarmonicSeries
        The families of the slice (one or two).
    seeds : ndarray, shape (n, 2)
        The points at frame 0, (c, r) in px.
    frames : int or None, optional
        Frames tracked, T (default: all of the series).
    neighbours : int, optional
        Neighbours whose median displacement tests each point for a slip.
    prior : callable, optional
        ``prior(t, positions) -> (n, 2) displacement in px or None``.

    Returns
    -------
    positions : ndarray, shape (T, n, 2)
        The tracked positions (c, r) in px at every frame.
    residuals : ndarray, shape (T, n)
        Phase residuals in rad (0 at frame 0).
    """
    T = series[0].frames if frames is None else int(frames)
    seeds = np.asarray(seeds, float)
    n = len(seeds)
    X = np.zeros((T, n, 2))
    R = np.zeros((T, n))
    X[0] = seeds
    if n == 0:
        return X, R
    targets = [s.sample(0, seeds)[0] for s in series]
    units = [s.k / np.linalg.norm(s.k) for s in series]
    periods = [1.0 / np.linalg.norm(s.k) for s in series]
    kk = min(neighbours, n - 1)
    for t in range(1, T):
        prev = X[t - 1]
        step = prior(t, prev) if prior is not None else None
        if step is None:
            step = 0.5 * (prev - X[t - 2]) if t >= 2 else 0.0
        x, res = solve_phase(series, t, prev + step, targets)
        if kk >= 1:
            disp = x - prev
            _, nb = cKDTree(prev).query(prev, k=kk + 1)
            med = np.median(disp[nb[:, 1:]], axis=1)
            off = np.max([np.abs((disp - med) @ u) / p for u, p in zip(units, periods)], axis=0)
            slip = off > SLIP
            if slip.any():
                x2, res2 = solve_phase(series, t, prev[slip] + med[slip],
                                       [tg[slip] for tg in targets])
                x[slip], res[slip] = x2, res2
        X[t], R[t] = x, res
    return X, R


def phase_isolines(series: HarmonicSeries, t: int, level: float = np.pi,
                   mask: np.ndarray | None = None) -> list[np.ndarray]:
    """Iso-phase lines φ_t = level (mod 2π), each (m, 2) in (c, r) px (marching squares).

    Contoured on ψ = wrap(φ − level), continuous away from its branch cut ψ = ±π, which the
    cells with |ψ| > 2 rad leave out (a line of ψ = 0 never comes near it).

    Parameters
    ----------
    series : HarmonicSeries
        One tag family.
    t : int
        The frame index, 0-based.
    level : float, optional
        The phase of the lines, in rad (default π: the tag troughs).
    mask : ndarray of bool, shape (rows, columns), optional
        Pixels where lines may run (e.g. the myocardium).

    Returns
    -------
    list of ndarray, shape (m, 2)
        The lines, (c, r) in px, each at least 2 points.
    """
    from skimage.measure import find_contours
    psi = np.angle(series.harmonic(t) * np.exp(-1j * level))
    ok = np.abs(psi) < 2.0
    if mask is not None:
        ok &= mask
    return [c[:, ::-1] for c in find_contours(psi, 0.0, mask=ok) if len(c) >= 2]


def trough_refine(image: np.ndarray, points: np.ndarray, gradients: np.ndarray,
                  reach: float, smooth: int = 5) -> np.ndarray:
    """Move ordered line points (n, 2) (c, r) onto the tag trough of ``image``.

    The harmonic phase is a band-limited (smoothed) view of the tags, biased near strong
    intensity edges (blood pool, epicardium) where the filter's support takes in other
    tissue. The tag itself is a narrow intensity minimum: along each point's phase gradient
    (the tag normal) the image is sampled at whole-pixel steps within ``reach`` pixels, the
    smallest sample and its two neighbours fitted by a parabola give the trough's sub-pixel
    offset, and the offsets are median-filtered along the line (``smooth`` points) against
    noise. A point whose trough is at the end of its search range keeps its position.

    Parameters
    ----------
    image : ndarray, shape (rows, columns)
        The tagged image (intensities).
    points : ndarray, shape (n, 2)
        Ordered points of one tag line, (c, r) in px.
    gradients : ndarray, shape (n, 2)
        The phase gradient at each point (the tag normal), any length.
    reach : float
        Search half-width along the normal, in px.
    smooth : int, optional
        Median-filter length along the line, in points.

    Returns
    -------
    ndarray, shape (n, 2)
        The moved points, (c, r) in px.
    """
    from scipy.ndimage import median_filter
    p = np.asarray(points, float)
    if len(p) == 0:
        return p
    n = gradients / np.maximum(np.linalg.norm(gradients, axis=1, keepdims=True), 1e-12)
    R = max(int(np.floor(reach)), 1)
    s = np.arange(-R, R + 1, dtype=float)
    q = p[:, None, :] + s[None, :, None] * n[:, None, :]
    v = bilinear(np.asarray(image, float)[None], q.reshape(-1, 2))[0].reshape(len(p), len(s))
    j = np.argmin(v, axis=1)
    inner = (j > 0) & (j < len(s) - 1)
    jj = np.clip(j, 1, len(s) - 2)
    a, b, c = (v[np.arange(len(p)), jj + d] for d in (-1, 0, 1))
    den = a - 2 * b + c
    frac = np.where(den > 1e-12, 0.5 * (a - c) / np.where(den > 1e-12, den, 1.0), 0.0)
    off = np.where(inner, s[jj] + np.clip(frac, -0.5, 0.5), np.nan)
    ok = np.isfinite(off)
    if ok.sum() >= 1:
        filled = np.where(ok, off, np.interp(np.arange(len(p)), np.flatnonzero(ok), off[ok]))
        off = median_filter(filled, size=min(smooth, len(p)), mode="nearest")
        off = np.where(ok, off, 0.0)
    else:
        off = np.zeros(len(p))
    return p + off[:, None] * n
