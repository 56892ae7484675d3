"""Frames that agree with their neighbours: a temporal check of the volume curve.

A heart moves smoothly, so each frame's LV cavity volume is predicted from the frames
around it: the cubic through the two nearest *trusted* frames on either side
(Lagrange interpolation in frame number; on a cine that closes on itself the frames
wrap around). A frame whose volume departs from that prediction by more than
:data:`SUPPORT_BOUND` (relative) and by more than :data:`SUPPORT_SIGMAS` robust
standard deviations of every frame's departure is a frame whose sections are
incomplete or noisy: it is *supported*, i.e. its volumes are taken from its trusted
neighbours by the same interpolation, and it no longer supports others. Frames are
supported one at a time, the worst first, until none is left beyond the bounds (at
most a quarter of the frames). docs/metrics.md, Frames.

The raw volumes stay beside the consistent ones (metrics.json ``volume_curve``), ED
and ES are found on the consistent curve, and every supported frame is a QC flag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: a frame is supported when its volume departs from its neighbours' prediction by more
#: than this fraction of the prediction ...
SUPPORT_BOUND = 0.04
#: ... and by more than this many robust standard deviations (1.4826 MAD) of all departures
SUPPORT_SIGMAS = 3.0
#: fewest frames a curve needs to be checked (two trusted neighbours on each side)
MIN_FRAMES = 6


@dataclass
class CycleCheck:
    """The outcome of :func:`check_curve`.

    ``raw`` and ``consistent``: frame -> mL; ``supported``: frame -> the frames it was
    interpolated from; ``departure``: frame -> raw / prediction − 1 when it was supported;
    ``cyclic``: whether the frames were taken to wrap around."""

    raw: dict[int, float]
    consistent: dict[int, float]
    supported: dict[int, list[int]] = field(default_factory=dict)
    departure: dict[int, float] = field(default_factory=dict)
    cyclic: bool = False

    def describe(self, frame: int) -> str:
        """One line naming a supported frame, its raw and its consistent volume."""
        src = ", ".join(str(g) for g in self.supported[frame])
        return (f"frame {frame} supported by its neighbours: LV cavity {self.raw[frame]:.1f} mL "
                f"departs {100 * self.departure[frame]:+.1f} % from frames {src} "
                f"({self.consistent[frame]:.1f} mL used)")


def is_cyclic(values: np.ndarray) -> bool:
    """True when the curve closes on itself: the step from the last frame back to the
    first is no larger than the largest step between consecutive frames."""
    if len(values) < MIN_FRAMES:
        return False
    steps = np.abs(np.diff(values))
    return bool(abs(values[-1] - values[0]) <= steps.max())


def _neighbours(i: int, trusted: np.ndarray, cyclic: bool) -> np.ndarray | None:
    """Positions (index offsets, may lie beyond the ends when cyclic) of the two nearest
    trusted frames on each side of position ``i``; None when a side has fewer than two."""
    n = len(trusted)
    out = []
    for step in (-1, 1):
        got, k = [], i + step
        while len(got) < 2 and abs(k - i) < n:
            if not cyclic and not 0 <= k < n:
                break
            if trusted[k % n]:
                got.append(k)
            k += step
        if len(got) < 2:
            return None
        out += got
    return np.array(sorted(out))


def lagrange_weights(x: np.ndarray, at: float) -> np.ndarray:
    """Weights w with sum(w · y(x)) = the polynomial through (x, y) evaluated at ``at``."""
    x = np.asarray(x, float)
    w = np.ones(len(x))
    for j in range(len(x)):
        for m in range(len(x)):
            if m != j:
                w[j] *= (at - x[m]) / (x[j] - x[m])
    return w


def check_curve(volumes: dict[int, float], *, bound: float = SUPPORT_BOUND,
                sigmas: float = SUPPORT_SIGMAS) -> CycleCheck:
    """Find the frames of a volume curve (frame -> mL) that their neighbours contradict.

    Parameters
    ----------
    volumes : dict int -> float
        Per frame, the raw volume (mL); NaN frames are neither checked nor used.
    bound, sigmas : float
        A frame is supported when ``|raw / prediction − 1| > bound`` and
        ``|raw − prediction| > sigmas`` robust standard deviations of all departures.

    Returns
    -------
    CycleCheck
    """
    frames = sorted(f for f, v in volumes.items() if v is not None and math.isfinite(v))
    raw = {f: float(volumes[f]) for f in frames}
    out = CycleCheck(raw=dict(raw), consistent=dict(raw))
    y = np.array([raw[f] for f in frames])
    if len(frames) < MIN_FRAMES:
        return out
    out.cyclic = cyclic = is_cyclic(y)
    trusted = np.ones(len(y), bool)
    for _ in range(len(y) // 4):
        pred = np.full(len(y), np.nan)
        src: dict[int, np.ndarray] = {}
        for i in np.flatnonzero(trusted):
            nb = _neighbours(i, trusted, cyclic)
            if nb is not None:
                pred[i] = lagrange_weights(nb, i) @ y[nb % len(y)]
                src[i] = nb
        resid = y - pred
        ok = np.isfinite(resid)
        if not ok.any():
            break
        scale = 1.4826 * float(np.median(np.abs(resid[ok] - np.median(resid[ok]))))
        rel = np.where(ok, np.abs(resid) / np.abs(pred), 0.0)
        bad = ok & (rel > bound) & (np.abs(np.where(ok, resid, 0.0)) > sigmas * scale)
        if not bad.any():
            break
        i = int(np.argmax(np.where(bad, rel, -1.0)))
        trusted[i] = False
        out.departure[frames[i]] = float(y[i] / pred[i] - 1.0)
    for i in np.flatnonzero(~trusted):     # each from the trusted frames around it
        nb = _neighbours(int(i), trusted, cyclic)
        if nb is None:
            trusted[i] = True
            out.departure.pop(frames[i], None)
            continue
        f = frames[int(i)]
        out.supported[f] = [frames[k % len(y)] for k in nb]
        out.consistent[f] = float(lagrange_weights(nb, i) @ y[nb % len(y)])
    out.departure = {f: d for f, d in out.departure.items() if f in out.supported}
    return out


def interpolate(values: dict[int, float], frames: list[int], sources: list[int],
                frame: int, cyclic: bool) -> float:
    """A supported frame's value of another volume, by the same interpolation from the
    frames ``sources`` (``values``: frame -> mL; NaN when a source lacks it)."""
    pos = {f: k for k, f in enumerate(frames)}
    i = pos[frame]
    x = []
    for g in sources:
        k = pos[g]
        if cyclic and k - i > len(frames) / 2:
            k -= len(frames)
        elif cyclic and i - k > len(frames) / 2:
            k += len(frames)
        x.append(k)
    y = np.array([values.get(g, math.nan) for g in sources], float)
    return float(lagrange_weights(np.array(x, float), i) @ y)
