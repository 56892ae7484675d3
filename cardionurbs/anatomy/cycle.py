"""Frames that agree with their neighbours: a temporal check of the volume curve.

A heart moves smoothly, so a frame whose volume lies beyond *both* of its neighbours
(the nearest trusted frames on either side; on a cine that closes on itself the frames
wrap around) by more than :data:`SUPPORT_BOUND` of the nearer one, and by more than the
two neighbours differ from each other, is contradicted by them: a spike that no motion
makes (a physiological peak or trough has steep sides, so its neighbours lie far apart;
ED and ES of a cine of :data:`MIN_FRAMES` frames or more lie within a few per cent of
theirs), and that departs by more than that bound as well from the cubic through the two
nearest frames on each side (which follows a smooth peak or trough). Such a frame, and a
frame that is *incomplete* (built from fewer LV endocardial contours than both its
neighbours, or with one of them left out as a partial tracing) and departs from that
cubic by more than the bound, and a frame whose LV
cavity cannot be built at all, is *supported*:
its volumes are taken from the cubic through the two nearest trusted frames on each side
(Lagrange interpolation in frame number), and it supports no other (at most a quarter of
the frames, the worst, are supported). A cine of
fewer than :data:`MIN_FRAMES` frames is not checked: its neighbours are too far apart in
time to tell noise from motion. docs/metrics.md, Frames.

The raw volumes stay beside the consistent ones (metrics.json ``volume_curve``), ED
and ES are found on the consistent curve, and every supported frame is a QC flag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: a frame is supported when its volume lies beyond both neighbours by more than this
#: fraction of the nearer one (and by more than they differ from each other)
SUPPORT_BOUND = 0.04
#: fewest frames a curve needs to be checked: in a coarser cine the neighbours are too far
#: apart in time to tell noise from motion
MIN_FRAMES = 16


@dataclass
class CycleCheck:
    """The outcome of :func:`check_curve`.

    ``raw`` and ``consistent``: frame -> mL; ``supported``: frame -> the frames it was
    interpolated from; ``departure``: frame -> raw / consistent − 1 (NaN: not built);
    ``cyclic``: whether the frames were taken to wrap around.

    Attributes
    ----------
    raw : dict of int to float
        Frame -> the LV cavity volume built from its own contours, in mL (NaN: not built).
    consistent : dict of int to float
        Frame -> the volume used, in mL (the raw one, or its neighbours' interpolation).
    supported : dict of int to list of int
        Supported frame -> the frames (0-based) it was interpolated from.
    departure : dict of int to float
        Supported frame -> raw / consistent − 1 (dimensionless; NaN: not built).
    cyclic : bool
        Whether the frames were taken to wrap around (a whole cine cycle).
    """

    raw: dict[int, float]
    consistent: dict[int, float]
    supported: dict[int, list[int]] = field(default_factory=dict)
    departure: dict[int, float] = field(default_factory=dict)
    cyclic: bool = False

    def describe(self, frame: int) -> str:
        """One line naming a supported frame, its raw and its consistent volume.

        Parameters
        ----------
        frame : int
            A frame of :attr:`supported`.

        Returns
        -------
        str
            The line, volumes in mL and the departure in %.
        """
        src = ", ".join(str(g) for g in self.supported[frame])
        if not math.isfinite(self.raw[frame]):
            return (f"frame {frame} supported by its neighbours: its LV cavity cannot be built; "
                    f"{self.consistent[frame]:.1f} mL from frames {src} used")
        return (f"frame {frame} supported by its neighbours: LV cavity {self.raw[frame]:.1f} mL "
                f"departs {100 * self.departure[frame]:+.1f} % from frames {src} "
                f"({self.consistent[frame]:.1f} mL used)")


def is_cyclic(values: np.ndarray) -> bool:
    """True when the curve closes on itself: the step from the last frame back to the
    first is no larger than the largest step between consecutive frames.

    Parameters
    ----------
    values : ndarray, shape (n,)
        The curve in frame order (e.g. mL).

    Returns
    -------
    bool
        Whether the curve wraps (False for fewer than :data:`MIN_FRAMES` frames).
    """
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
    """Weights w with sum(w · y(x)) = the polynomial through (x, y) evaluated at ``at``.

    Parameters
    ----------
    x : ndarray, shape (k,)
        Distinct abscissae (frame positions).
    at : float
        Where the polynomial is evaluated.

    Returns
    -------
    ndarray, shape (k,)
        The Lagrange basis polynomials at ``at``.
    """
    x = np.asarray(x, float)
    w = np.ones(len(x))
    for j in range(len(x)):
        for m in range(len(x)):
            if m != j:
                w[j] *= (at - x[m]) / (x[j] - x[m])
    return w


def check_curve(volumes: dict[int, float], *, bound: float = SUPPORT_BOUND,
                contours: dict[int, int] | None = None) -> CycleCheck:
    """Find the frames of a volume curve (frame -> mL) that their neighbours contradict.

    Parameters
    ----------
    volumes : dict int -> float
        Per frame, the raw volume (mL); a NaN frame (its cavity could not be built) is not
        used and gets its value from its neighbours.
    bound : float
        A frame is supported when it lies beyond both neighbours by more than this
        fraction of the nearer one and by more than they differ (:func:`_spike`), or
        when it is *incomplete* and departs by more than this from the cubic.
    contours : dict int -> int, optional
        Per frame, how many contours its LV endocardium was built from, negative when one
        of its contours was left out (a partial tracing): a frame with fewer than both
        its neighbours, or with one left out, is incomplete.

    Returns
    -------
    CycleCheck
    """
    frames = sorted(volumes)
    y = np.array([volumes[f] if volumes[f] is not None else math.nan for f in frames], float)
    raw = {f: float(v) for f, v in zip(frames, y)}
    out = CycleCheck(raw=dict(raw), consistent=dict(raw))
    trusted = np.isfinite(y)
    if len(y) < MIN_FRAMES or trusted.sum() < 5:
        return out
    out.cyclic = cyclic = is_cyclic(y[trusted])
    out.departure = {f: math.nan for f, t in zip(frames, trusted) if not t}
    finite = trusted.copy()
    excess = np.zeros(len(y))
    for i in np.flatnonzero(finite):          # against the nearest built frame on each side
        nb = _neighbours(int(i), finite, cyclic)
        if nb is not None:
            dep = abs(y[i] / (lagrange_weights(nb, i) @ y[nb % len(y)]) - 1.0)
            if dep > bound and (_spike(y[i], y[nb[1] % len(y)], y[nb[2] % len(y)], bound) > 0
                                or contours and _incomplete(contours, frames, nb, int(i))):
                excess[i] = dep        # ranked by the departure from the cubic without it
    # the worst first, at most a quarter; a frame beside one already supported was judged
    # against it and is not (a spike's neighbours depart from their cubics too, by about
    # two thirds of its own departure: the cubic's weight on an adjacent frame)
    beside: set[int] = set()
    for i in np.argsort(-excess, kind="stable")[:len(y) // 4]:
        if excess[i] > 0 and int(i) not in beside:
            trusted[i] = False
            nb = _neighbours(int(i), finite, cyclic)
            beside |= {int(nb[1]) % len(y), int(nb[2]) % len(y)}
    for i in np.flatnonzero(~trusted):     # each from the trusted frames around it
        nb = _neighbours(int(i), trusted, cyclic)
        f = frames[int(i)]
        if nb is None:
            if np.isfinite(y[i]):
                trusted[i] = True
            out.departure.pop(f, None)
            continue
        out.supported[f] = [frames[k % len(y)] for k in nb]
        out.consistent[f] = float(lagrange_weights(nb, i) @ y[nb % len(y)])
        out.departure[f] = float(y[i] / out.consistent[f] - 1.0)
    return out


def _incomplete(contours: dict[int, int], frames: list[int], nb: np.ndarray, i: int) -> bool:
    """True when frame position ``i`` has fewer contours than both nearest neighbours, or
    had one left out (a negative count, see :func:`check_curve`)."""
    n = contours.get(frames[i])
    if n is not None and n < 0:
        return True
    side = [contours.get(frames[int(k) % len(frames)]) for k in (nb[1], nb[2])]
    return n is not None and None not in side and all(n < abs(m) for m in side)


def _spike(v: float, before: float, after: float, bound: float) -> float:
    """How far (relative) a volume lies beyond both its neighbours, 0 unless it is a spike:
    above (or below) both by more than ``bound`` of the nearer one and by more than the
    neighbours differ from each other (a physiological peak or trough, whose sides are
    steep, has neighbours far apart)."""
    a, b = v - before, v - after
    if a * b <= 0:
        return 0.0
    nearer = before if abs(a) < abs(b) else after
    excess = min(abs(a), abs(b))
    if excess <= bound * abs(nearer) or excess <= abs(after - before):
        return 0.0
    return excess / abs(nearer)


def interpolate(values: dict[int, float], frames: list[int], sources: list[int],
                frame: int, cyclic: bool) -> float:
    """A supported frame's value of another volume: the polynomial through the frames
    ``sources`` (their positions in ``frames``, wrapped when ``cyclic``) at ``frame``
    (``values``: frame -> mL; NaN when a source lacks it).

    Parameters
    ----------
    values : dict of int to float
        Frame -> value (mL).
    frames : list of int
        Every frame of the curve, in order.
    sources : list of int
        The frames interpolated from (:attr:`CycleCheck.supported`).
    frame : int
        The supported frame.
    cyclic : bool
        Wrap positions round the cycle.

    Returns
    -------
    float
        The interpolated value (mL), NaN when a source lacks a value.
    """
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
