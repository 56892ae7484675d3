"""SPAMM tag geometry from the spectrum of a tagged image.

A SPAMM tag pattern multiplies the image by a periodic modulation
m(x) = Σ_n c_n exp(2πi n k·x); its spectrum is the anatomy's spectrum
repeated around the harmonics n k (Axel & Dougherty 1989; Osman et al.
1999, §II). The first harmonic peaks ±k of each tag family stand far above
the anatomy's spectrum at that frequency, so the tag orientation (the
direction of k, normal to the tag lines) and spacing (1 / |k|) are read off
the position of the largest peaks:

* the image minus its mean, times a 2-D Hann window (leakage of the bright
  anatomy into the tag band), is Fourier transformed (numpy FFT);
* the largest magnitude with a period between ``min_period_px`` and
  ``max_period_px`` pixels (one half-plane: k and −k are the same family)
  is the first family's peak; for a grid (SA views) the second family's is
  the largest at 50–130° from it, between 0.6 and 1.6 |k_1| (which leaves
  out the cross terms k_1 ± k_2 at 45°);
* each peak is refined to a fraction of a frequency bin by a parabola
  through the log magnitudes of its two neighbours along each axis (a
  Gaussian peak interpolation);
* peaks are chosen, and judged, by their **contrast**: the magnitude over
  the mean magnitude of the bins 3–6 bins away (a square annulus). The
  anatomy's spectrum is smooth on that scale, a tag peak is a spike as
  narrow as the window allows; an untagged or faded image has no bin
  standing out by more than :data:`MIN_CONTRAST`. When a chosen peak is
  the 2nd or 3rd harmonic of a peak that also stands out, the fundamental
  is taken.

Frequencies are in cycles per pixel, ``k = (k_c, k_r)`` along the column
index c (the row direction cosine) and the row index r (the column
direction cosine), the pixel convention of :mod:`cardionurbs.imaging.geometry`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a peak whose magnitude is below this many times the band's median is no tag pattern
MIN_CONTRAST = 4.2


@dataclass(frozen=True)
class TagPeak:
    """One tag family's first harmonic peak: k (cycles/pixel, (k_c, k_r)), magnitude, contrast.

    Attributes
    ----------
    k : ndarray, shape (2,)
        The peak's wave vector (k_c, k_r), in cycles/pixel (sub-bin).
    magnitude : float
        |FFT| at the peak's bin (image intensity × pixels).
    contrast : float
        The magnitude over the mean of its square annulus (dimensionless; a tag family
        stands out above :data:`MIN_CONTRAST`).
    period_px : float
        Tag spacing along k, in px.
    direction : ndarray, shape (2,)
        Unit (c, r) normal of the tag lines.
    """

    k: np.ndarray
    magnitude: float
    contrast: float

    @property
    def period_px(self) -> float:
        """Tag spacing along k, pixels."""
        return float(1.0 / np.linalg.norm(self.k))

    @property
    def direction(self) -> np.ndarray:
        """Unit (c, r) direction of k: normal to the tag lines, in pixel axes."""
        return self.k / np.linalg.norm(self.k)


def frequency_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(k_c, k_r) of every FFT bin of an image of ``shape`` = (rows, columns), cycles/pixel.

    Parameters
    ----------
    shape : tuple of (int, int)
        The image shape (rows, columns).

    Returns
    -------
    k_c, k_r : ndarray, shape (rows, columns)
        The frequency of every bin along the columns and the rows, in cycles/pixel (FFT order).
    """
    kr = np.fft.fftfreq(shape[0])[:, None]
    kc = np.fft.fftfreq(shape[1])[None, :]
    return np.broadcast_to(kc, shape), np.broadcast_to(kr, shape)


def windowed_spectrum(image: np.ndarray) -> np.ndarray:
    """|FFT| of the mean-free, Hann-windowed image.

    Parameters
    ----------
    image : ndarray, shape (rows, columns)
        One image (intensities).

    Returns
    -------
    ndarray of float, shape (rows, columns)
        The magnitude spectrum, FFT order.
    """
    img = np.asarray(image, dtype=float)
    w = np.outer(np.hanning(img.shape[0]), np.hanning(img.shape[1]))
    return np.abs(np.fft.fft2((img - img.mean()) * w))


def annulus_mean(mag: np.ndarray, inner: int = 2, outer: int = 6) -> np.ndarray:
    """Mean of ``mag`` over the square annulus inner < max(|dr|, |dc|) <= outer around each bin
    (periodic, as the spectrum).

    Parameters
    ----------
    mag : ndarray, shape (rows, columns)
        A magnitude spectrum.
    inner : int, optional
        Half-width of the square left out, in bins.
    outer : int, optional
        Half-width of the square averaged, in bins.

    Returns
    -------
    ndarray, shape (rows, columns)
        The annulus mean around every bin.
    """
    from scipy.ndimage import uniform_filter
    a, b = 2 * outer + 1, 2 * inner + 1
    big = uniform_filter(mag, a, mode="wrap") * a * a
    small = uniform_filter(mag, b, mode="wrap") * b * b
    return (big - small) / (a * a - b * b)


def _refine(mag: np.ndarray, r: int, c: int) -> tuple[float, float]:
    """Sub-bin offsets (dr, dc) of a peak from parabolas through the log magnitudes."""
    R, C = mag.shape
    out = []
    for (a, b, d) in ((mag[(r - 1) % R, c], mag[r, c], mag[(r + 1) % R, c]),
                      (mag[r, (c - 1) % C], mag[r, c], mag[r, (c + 1) % C])):
        la, lb, ld = np.log(np.maximum([a, b, d], 1e-300))
        den = la - 2 * lb + ld
        out.append(float(np.clip(0.5 * (la - ld) / den, -0.5, 0.5)) if den < 0 else 0.0)
    return out[0], out[1]


def _fundamental(white: np.ndarray, allowed: np.ndarray, kc: np.ndarray, kr: np.ndarray,
                 r: int, c: int) -> tuple[int, int]:
    """The bin of the first harmonic when (r, c) is a higher harmonic n k of a peak k that also
    stands out (whitened magnitude at least a quarter of the candidate's and above 4)."""
    R, C = white.shape
    for n in (3, 2):
        tc, tr = kc[r, c] / n, kr[r, c] / n
        rr, cc = int(round(tr * R)) % R, int(round(tc * C)) % C
        win = [((rr + a) % R, (cc + b) % C) for a in (-1, 0, 1) for b in (-1, 0, 1)]
        win = [(i, j) for i, j in win if allowed[i, j]]
        if not win:
            continue
        i, j = max(win, key=lambda ij: white[ij])
        if white[i, j] > max(4.0, 0.25 * white[r, c]):
            return i, j
    return r, c


def tag_peaks(image: np.ndarray, families: int, min_period_px: float = 3.0,
              max_period_px: float = 25.0) -> list[TagPeak]:
    """The first harmonic peak of each of ``families`` (1 or 2) tag families, strongest first.

    Returns fewer peaks when the band has no candidate (tiny images); the caller judges
    ``contrast`` against :data:`MIN_CONTRAST`.

    Parameters
    ----------
    image : ndarray, shape (rows, columns)
        The first tagged frame of a slice (intensities).
    families : int
        Tag families expected: 2 for an SA grid, 1 for LA lines.
    min_period_px, max_period_px : float, optional
        The band searched: tag spacings from 3 to 25 px by default.

    Returns
    -------
    list of TagPeak
        At most ``families`` peaks, strongest first; the second at 50-90° from the first and
        0.6 to 1.6 times its frequency.
    """
    mag = windowed_spectrum(image)
    kc, kr = frequency_grid(mag.shape)
    rad = np.hypot(kc, kr)
    half = (kr > 0) | ((kr == 0) & (kc > 0))
    band = half & (rad >= 1.0 / max_period_px) & (rad <= 1.0 / min_period_px)
    # local contrast of every bin: its magnitude over the mean magnitude 3-6 bins around it
    # (the anatomy's spectrum is smooth there; a tag peak is a spike as narrow as the window)
    white = np.where(band, mag / np.maximum(annulus_mean(mag), 1e-12), -1.0)
    peaks: list[TagPeak] = []
    allowed = band.copy()
    for n in range(families):
        if not allowed.any():
            break
        flat = int(np.argmax(np.where(allowed, white, -1.0)))
        r, c = divmod(flat, mag.shape[1])
        r, c = _fundamental(white, allowed, kc, kr, r, c)
        R, C = mag.shape
        r, c = max((((r + a) % R, (c + b) % C) for a in (-1, 0, 1) for b in (-1, 0, 1)),
                   key=lambda ij: mag[ij] if band[ij] else -1.0)
        dr, dc = _refine(mag, r, c)
        k = np.array([kc[r, c] + dc / mag.shape[1], kr[r, c] + dr / mag.shape[0]])
        # the contrast of the peak's own bin: the refined k may round to a bin across the
        # half-plane's edge (a wave vector along ±c), outside the band where white = -1
        peaks.append(TagPeak(k, float(mag[r, c]), float(white[r, c])))
        if n == 0:
            k1 = k
            cosang = np.abs(kc * k1[0] + kr * k1[1]) / np.maximum(rad * np.linalg.norm(k1), 1e-12)
            ratio = rad / np.linalg.norm(k1)
            allowed = band & (cosang < np.cos(np.radians(50.0))) & (ratio > 0.6) & (ratio < 1.6)
    return peaks
