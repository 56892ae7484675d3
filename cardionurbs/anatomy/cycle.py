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
cavity cannot be built at all, is *supported* (at the curve's highest frame, ED, a
cusp the cubic under-reaches, only when it also lies above both one-sided linear
extrapolations; at its lowest an incomplete frame only when it lies below both:
:func:`_evidence`):
its volumes are taken from the cubic through the two nearest trusted frames on each side
(Lagrange interpolation in frame number), and it supports no other (at most a quarter of
the frames, the worst, are supported). A cine of
fewer than :data:`MIN_FRAMES` frames is not checked: its neighbours are too far apart in
time to tell noise from motion. docs/metrics.md, Frames.

The raw volumes stay beside the consistent ones (metrics.json ``volume_curve``), ED
and ES are found on the consistent curve, and every supported frame is a QC flag.

Before that check, at the level of sections, :func:`support_sections` fills a gap in a
frame's own stack (a slice traced in most frames but not in this one) with the section
interpolated in time from the nearest frames that trace it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from cardionurbs.anatomy.sections import FrameGeometry, Section
from cardionurbs.cache import attached
from cardionurbs.errors import CardioNurbsError

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
    basal : dict of int to BasalSupport
        Supported frame -> how its basal region was supported (:func:`support_basal`), for
        the frames supported that way.
    """

    raw: dict[int, float]
    consistent: dict[int, float]
    supported: dict[int, list[int]] = field(default_factory=dict)
    departure: dict[int, float] = field(default_factory=dict)
    cyclic: bool = False
    basal: dict[int, "BasalSupport"] = field(default_factory=dict)

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
        b = self.basal.get(frame)
        if b is not None and b.sources == self.supported[frame]:
            return (f"frame {frame} supported by its neighbours' basal region: {b.why}; its LV "
                    f"cavity basal to slice {b.slice} {b.basal:.1f} mL departs "
                    f"{b.basal - b.used:+.1f} mL from frames {src} ({b.used:.1f} mL), so "
                    f"{self.consistent[frame]:.1f} mL used instead of {self.raw[frame]:.1f}")
        own = f"LV cavity {self.raw[frame]:.1f} mL"
        if b is not None:        # basal-supported first, then by the whole curve
            own += f" ({b.total:.1f} mL with its basal region from frames " \
                   f"{', '.join(map(str, b.sources))})"
            dep = b.total / self.consistent[frame] - 1.0
        else:
            dep = self.departure[frame]
        if not math.isfinite(self.raw[frame]):
            return (f"frame {frame} supported by its neighbours: its LV cavity cannot be built; "
                    f"{self.consistent[frame]:.1f} mL from frames {src} used")
        return (f"frame {frame} supported by its neighbours: {own} "
                f"departs {100 * dep:+.1f} % from frames {src} "
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
                contours: dict[int, int] | None = None,
                basal: Mapping[int, "BasalSupport"] | None = None) -> CycleCheck:
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
    basal : mapping int -> BasalSupport, optional
        Frames whose basal region their neighbours support (:func:`support_basal`): the
        curve is checked with their :attr:`BasalSupport.total`, their raw volume is their
        own, and they are supported (by their basal sources) unless the check supports
        them as a whole.

    Returns
    -------
    CycleCheck
    """
    out = _check_curve(volumes if not basal else
                       {f: basal[f].total if f in basal else v for f, v in volumes.items()},
                       bound, contours)
    for f, b in sorted((basal or {}).items()):
        out.raw[f] = b.own
        out.basal[f] = b
        if f not in out.supported:
            out.supported[f] = list(b.sources)
        out.departure[f] = float(b.own / out.consistent[f] - 1.0)
    return out


def _check_curve(volumes: dict[int, float], bound: float,
                 contours: dict[int, int] | None) -> CycleCheck:
    """:func:`check_curve` of the curve as given."""
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
            dep = _departure(y, nb, int(i))
            spike = _spike(y[i], y[nb[1] % len(y)], y[nb[2] % len(y)], bound) > 0
            partial = bool(contours) and _incomplete(contours, frames, nb, int(i))
            if dep > bound and _evidence(y, nb, int(i), spike, partial, bound):
                excess[i] = dep        # ranked by the departure from the cubic without it
    # the worst first, at most a quarter; a frame beside one already supported was judged
    # against it and is not (a spike's neighbours depart from their cubics too, by about
    # two thirds of its own departure: the cubic's weight on an adjacent frame); a frame
    # two away from one is judged again with the supported frames' cubic values in
    # their place (their raw volume pulled its cubic: a deep dip beside an ES trough made
    # the trough itself depart)
    beside: set[int] = set()
    work = y.copy()
    for i in np.argsort(-excess, kind="stable")[:len(y) // 4]:
        if excess[i] > 0 and int(i) not in beside and _departs(work, int(i), finite, cyclic,
                                                               bound):
            i = _the_outlier(y, int(i), excess, finite, cyclic)
            trusted[i] = False
            nb = _neighbours(int(i), finite, cyclic)
            beside |= {int(nb[1]) % len(y), int(nb[2]) % len(y)}
            work[i] = _within(work, nb, int(i))
    for i in np.flatnonzero(~trusted):     # each from the trusted frames around it
        nb = _neighbours(int(i), trusted, cyclic)
        f = frames[int(i)]
        if nb is None:
            if np.isfinite(y[i]):
                trusted[i] = True
            out.departure.pop(f, None)
            continue
        out.supported[f] = [frames[k % len(y)] for k in nb]
        out.consistent[f] = _within(y, nb, int(i))
        out.departure[f] = float(y[i] / out.consistent[f] - 1.0)
    return out


def _departs(y: np.ndarray, i: int, finite: np.ndarray, cyclic: bool, bound: float) -> bool:
    """Whether position ``i`` still departs beyond ``bound`` from the cubic through its
    neighbours in ``y`` (the curve with the frames supported so far replaced)."""
    nb = _neighbours(i, finite, cyclic)
    return nb is not None and _departure(y, nb, i) > bound


def _departure(y: np.ndarray, nb: np.ndarray, i: int) -> float:
    """|y[i] / the bounded cubic through its neighbours ``nb`` (:func:`_within`) - 1|."""
    return abs(y[i] / _within(y, nb, i) - 1.0)


def _cubic(y: np.ndarray, nb: np.ndarray, i: int) -> float:
    """The cubic through the volumes at positions ``nb`` (:func:`_neighbours`), at ``i``."""
    return float(lagrange_weights(nb, i) @ y[nb % len(y)])


def _within(y: np.ndarray, nb: np.ndarray, i: int) -> float:
    """The cubic at ``i`` (:func:`_cubic`), held within the range of the nearest frame on
    each side when the frame's own volume lies within it: the interpolant may not make an
    extreme (an ES trough, an ED peak) that neither the frame nor its neighbours show. Near
    a trough with one steep side the cubic overshoots below both neighbours (a phantom at
    1 px noise: 55.1 mL between 57.4 and 62.5, the frame's own 58.1;
    reports/validation-quality.md)."""
    cub = _cubic(y, nb, i)
    lo, hi = sorted((y[nb[1] % len(y)], y[nb[2] % len(y)]))
    if not (np.isfinite(y[i]) and lo <= y[i] <= hi):
        return cub
    return float(min(max(cub, lo), hi))


def _cubic_at(y: np.ndarray, i: int, finite: np.ndarray, cyclic: bool) -> float:
    """The cubic through the two nearest finite frames on each side of position ``i``."""
    nb = _neighbours(i, finite, cyclic)
    return math.nan if nb is None else _cubic(y, nb, i)


def _the_outlier(y: np.ndarray, i: int, excess: np.ndarray, finite: np.ndarray,
                 cyclic: bool) -> int:
    """Of candidate ``i`` and an adjacent candidate (both beyond the bound), the frame to
    support: the one whose replacement by its cubic leaves the other consistent. On a steep
    limb a spike makes its neighbour look like one too, by a departure that can come within
    a few percent of its own (near-ties that the ranking alone decides at random).

    Parameters
    ----------
    y : ndarray, shape (n,)
        The raw volumes (mL) in frame order.
    i : int
        The candidate's position.
    excess : ndarray, shape (n,)
        Each position's departure from its cubic where it is a candidate, else 0.
    finite, cyclic
        As in :func:`check_curve`.

    Returns
    -------
    int
        ``i``, or the adjacent candidate's position.
    """
    n = len(y)
    for j in (i - 1, i + 1):
        j %= n
        if j == i or excess[j] <= 0:
            continue
        left = []
        for a, b in ((i, j), (j, i)):
            z = y.copy()
            z[a] = _cubic_at(y, a, finite, cyclic)
            left.append(abs(z[b] / _cubic_at(z, b, finite, cyclic) - 1.0))
        if left[1] < left[0]:
            return j
    return i


def _evidence(y: np.ndarray, nb: np.ndarray, i: int, spike: bool, partial: bool,
              bound: float) -> bool:
    """Whether a frame off its cubic is a candidate for support: a spike or an incomplete
    frame, judged at the curve's extremes by what an exact extreme cannot do.

    At the highest frame (ED) the cubic is no reference: ED is a cusp (filling stops,
    ejection starts) that the cubic through its neighbours under-reaches (a phantom's
    analytic truth by +3.5 to +5.1 %, 30 phantoms of 20 frames), so a frame there is a
    candidate only when it also lies above both one-sided linear extrapolations by more
    than ``bound`` (:func:`_beyond_both_sides`): ejection starts from rest, so the
    extrapolation of the ejection limb lies above an exact ED (the truth's by 6.3 to
    9.8 %, at 1 px noise by 4.0 to 12.1 %). At the lowest frame (ES) the trough is
    rounded (the truth departs -0.3 to +0.8 % from the cubic) and a spike is judged
    against the cubic as elsewhere (bivme-patient1's ES frame 10 lies 8.7 % below it, yet
    above the extrapolation of its steep filling limb), but incompleteness alone is no
    evidence unless the frame lies below both one-sided extrapolations by more than
    ``bound`` too: an ES frame often has a section fewer (the apical cavity closes) and the
    cubic across a gap beside the trough overshoots it (the truth departs up to +2.9 % from
    the cubic through ES - 3, ES - 2, ES + 1, ES + 2). reports/validation-quality.md.

    Parameters
    ----------
    y : ndarray, shape (n,)
        The volumes (mL) in frame order, NaN where not built.
    nb : ndarray, shape (4,)
        The positions of the frame's two nearest built frames on each side
        (:func:`_neighbours`).
    i : int
        The frame's position.
    spike, partial : bool
        Whether the frame is a spike (:func:`_spike`) and whether it is incomplete
        (:func:`_incomplete`).
    bound : float
        How far beyond each extrapolation (a fraction of it) an extreme must lie.

    Returns
    -------
    bool
    """
    if np.nanargmax(y) == i:
        return (spike or partial) and _beyond_both_sides(y, nb, i, +1, bound)
    if np.nanargmin(y) == i:
        return spike or (partial and _beyond_both_sides(y, nb, i, -1, bound))
    return spike or partial


def _beyond_both_sides(y: np.ndarray, nb: np.ndarray, i: int, sign: int,
                       bound: float) -> bool:
    """Whether the volume at position ``i`` lies above (``sign`` +1) or below (-1) both
    linear extrapolations to ``i``, each through the two nearest frames on one side
    (``nb``, :func:`_neighbours`), each by more than ``bound`` of it."""
    sides = [float(lagrange_weights(x, i) @ y[x % len(y)]) for x in (nb[:2], nb[2:])]
    return bool(all(sign * (y[i] - v) > bound * abs(v) for v in sides))


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


# --------------------------------------------------------------- the basal region
@dataclass
class BasalSupport:
    """A frame whose LV cavity basal to a reference slice comes from its neighbours
    (:func:`support_basal`): its own cavity apical to that slice, their basal region.

    Attributes
    ----------
    own : float
        The frame's own LV cavity volume, in mL.
    basal : float
        Its own cavity basal to the reference slice, in mL.
    used : float
        The basal region the cubic through the sources gives at the frame, in mL.
    sources : list of int
        The frames (two nearest on each side whose basal evidence is whole).
    slice : str
        The reference slice (the most basal slice of every frame's stack).
    why : str
        Why the frame's basal evidence is partial (:func:`basal_edges`).
    """

    own: float
    basal: float
    used: float
    sources: list[int]
    slice: str
    why: str

    @property
    def total(self) -> float:
        """The LV cavity volume used (mL): its own apical part plus the supported basal one."""
        return self.own - self.basal + self.used


def _names(slices: set[str]) -> str:
    return ", ".join(sorted(slices)) or "none"


def basal_edges(stacks: Mapping[int, list[str]], frames: list[int],
                cyclic: bool) -> tuple[str | None, dict[int, str]]:
    """The frames at an edge of a basal slice's run in time, and the reference slice.

    The reference slice is the most basal SA slice of every frame's own LV endocardial
    stack; a frame's *basal stack* is its own slices basal to it. Where the base moves
    through a slice (it leaves the basal slice in systole and enters it again in
    filling), the frames on either side of the change have a basal stack that differs
    from an adjacent frame's: the slice cuts the cavity at the annulus, where the
    tracing is partial (a section traced at part of its area, or left out) and the
    basal region rests on it. Such a frame's basal evidence is partial.

    Parameters
    ----------
    stacks : mapping frame -> list of str
        Per frame whose LV cavity was built, the SA slices of its LV endocardium, base ->
        apex (its own and those interpolated in time: a gap filled inside its stack, or a
        partial tracing replaced, is not a change at its base).
    frames : list of int
        The frames of the curve, in order.
    cyclic : bool
        Whether the frames wrap around (the last is adjacent to the first).

    Returns
    -------
    (str or None, dict int -> str)
        The reference slice (None when no slice is in every stack) and frame -> why its
        basal evidence is partial.
    """
    order = [f for f in frames if f in stacks]
    common = set.intersection(*(set(v) for v in stacks.values())) if stacks else set()
    if not common or len(order) < 3:
        return None, {}
    ref = next(sl for sl in stacks[order[0]] if sl in common)
    basal = {f: set(stacks[f][:stacks[f].index(ref)]) for f in order}
    out: dict[int, str] = {}
    for k, f in enumerate(order):
        for j in (k - 1, k + 1):
            if not (cyclic or 0 <= j < len(order)):
                continue
            g = order[j % len(order)]
            if basal[g] != basal[f] and f not in out:
                out[f] = (f"its basal stack ({_names(basal[f])}, basal to {ref}) differs from "
                          f"frame {g}'s ({_names(basal[g])}): the base passes through the "
                          "basal slice")
    return ref, out


#: a frame's basal region is supported when it departs from its neighbours' by more than
#: this fraction of the frame's LV cavity: twice :data:`SUPPORT_BOUND`, as that region is
#: interpolated across a gap of at least one frame and its own is the frame's evidence (on
#: phantoms at 1 px noise the held cubic departs up to 4.3 % of the cavity from a basal
#: region that is right, normal seed 2 frame 9; bivme-patient1's partial basal tracing at
#: frame 14: 12.5 %; reports/validation-quality.md)
BASAL_SUPPORT_BOUND = 2 * SUPPORT_BOUND


def support_basal(volumes: dict[int, float], edges: Mapping[int, str], ref: str,
                  basal_ml, *, bound: float = BASAL_SUPPORT_BOUND) -> dict[int, BasalSupport]:
    """The frames at an edge of a basal slice's run whose basal region their neighbours
    support: a temporal prior on the base, the part of the cavity a partial basal tracing
    shapes.

    For each frame of ``edges`` (:func:`basal_edges`), the cavity basal to the reference
    slice is compared with the cubic through the two nearest frames on each side whose
    basal evidence is whole (Lagrange interpolation in frame number, wrapping round a
    whole cycle), held within the range of the nearest of them on each side (across a gap
    the cubic may make a trough they do not show), when those lie within
    :data:`PARTIAL_MAX_STEP` frames of it; where they differ by more than ``bound`` of the frame's volume, the
    frame keeps its own cavity apical to the slice and takes the cubic's basal region.
    A cine of fewer than :data:`MIN_FRAMES` frames is not supported.

    Parameters
    ----------
    volumes : dict int -> float
        Per frame, the LV cavity volume (mL; NaN: not built).
    edges : mapping int -> str
        Frame -> why its basal evidence is partial.
    ref : str
        The reference slice.
    basal_ml : callable
        ``basal_ml(frame) -> float``: a frame's own LV cavity basal to ``ref`` (mL; NaN
        when it cannot be measured). Asked only of the edge frames and their sources.
    bound : float
        The departure (a fraction of the frame's volume) beyond which it is supported.

    Returns
    -------
    dict int -> BasalSupport
        The supported frames.
    """
    frames = sorted(volumes)
    y = np.array([volumes[f] for f in frames], float)
    finite = np.isfinite(y)
    if len(frames) < MIN_FRAMES or finite.sum() < 5:
        return {}
    cyclic = is_cyclic(y[finite])
    whole = finite & np.array([f not in edges for f in frames])
    out: dict[int, BasalSupport] = {}
    for f in sorted(edges):
        i = frames.index(f)
        nb = _neighbours(i, whole, cyclic) if finite[i] else None
        if nb is None or max(i - nb[1], nb[2] - i) > PARTIAL_MAX_STEP:
            continue            # too far apart in time to stand in for the frame's own base
        src = [frames[k % len(frames)] for k in nb]
        b = np.array([basal_ml(g) for g in src], float)
        # held within the nearest source on each side: across a gap that spans the ES trough
        # the cubic undershoots both (a phantom whose base leaves the basal slice at ES alone)
        used = float(np.clip(lagrange_weights(nb, i) @ b, *sorted(b[1:3])))
        own = float(basal_ml(f))
        if used >= 0 and abs(used - own) > bound * y[i]:
            out[f] = BasalSupport(float(y[i]), own, used, src, ref, edges[f])
    return out


# --------------------------------------------------------------- the RV's basal region
#: an RV frame's basal region is supported when it departs from its neighbours' by more
#: than this fraction of its RV cavity: above every departure measured on phantoms where
#: the frame's own basal region is right (190 edge frames of 48 phantoms, 20 frames at 1 px
#: noise, ideal and realistic: 99th percentile 12.3 %, largest 15.4 %, realistic MR seed 1;
#: benchmarks/rv_basal_bound.py, reports/validation-quality.md). The LV's
#: :data:`BASAL_SUPPORT_BOUND` (8 %) is exceeded there by 10 of them, ED of realistic
#: normal seed 3 (RVEDV 13 % low) and MR seed 1 (11 % low) and ES of ideal normal seed 7
#: (RVESV 8 % high) among them. A partial basal tracing (the slice's RV contours at 60 % of
#: their area) departs 1.2-14.7 %, so the two cannot be told apart by this departure alone.
RV_BASAL_SUPPORT_BOUND = 0.16


def support_rv_basal(frame: int, frames: list[int], edges: Mapping[int, str], ref: str,
                     volume: float, basal_ml, *, cyclic: bool,
                     bound: float = RV_BASAL_SUPPORT_BOUND) -> BasalSupport | None:
    """The RV cavity's basal region at one frame, supported by its neighbours: the rule of
    :func:`support_basal` (the LV's) for the RV curve, frame by frame, with the RV's own
    bound (:data:`RV_BASAL_SUPPORT_BOUND`).

    The base passes through the RV's basal slice as it does through the LV's (on
    bivme-patient1 the RV's sa_01 is traced at 2073 mm² at frame 5 after 3023 at frame 4,
    at 1100 mm² at frame 14 after none at frame 13), and the RV cavity's basal region
    rests on that tracing. ``edges`` and ``ref`` come from :func:`basal_edges` of the RV
    endocardial stacks. One frame is decided at a time, from its own volume and its
    sources' basal regions alone, so that a metrics-only analysis, which builds the RV at
    ED and ES only, asks for the RV solids of nothing more unless ED or ES is an edge.

    Parameters
    ----------
    frame : int
        The frame.
    frames : list of int
        The frames of the curve, in order (each with its RV built or buildable).
    edges : mapping int -> str
        Frame -> why its RV basal evidence is partial (:func:`basal_edges`).
    ref : str
        The reference slice (the most basal slice of every frame's RV stack).
    volume : float
        The frame's own RV cavity volume, in mL.
    basal_ml : callable
        ``basal_ml(frame) -> float``: a frame's own RV cavity basal to ``ref`` (mL; NaN
        when it cannot be measured). Asked only of ``frame`` and its sources.
    cyclic : bool
        Whether the frames wrap around (the last is adjacent to the first).
    bound : float
        The departure (a fraction of the frame's volume) beyond which it is supported.

    Returns
    -------
    BasalSupport or None
        The support (``own`` the frame's RV cavity), None when the frame keeps its own.
    """
    if frame not in edges or frame not in frames or len(frames) < MIN_FRAMES \
            or not math.isfinite(volume):
        return None
    whole = np.array([g not in edges for g in frames])
    i = frames.index(frame)
    nb = _neighbours(i, whole, cyclic)
    if nb is None or max(i - nb[1], nb[2] - i) > PARTIAL_MAX_STEP:
        return None             # too far apart in time to stand in for the frame's own base
    src = [frames[k % len(frames)] for k in nb]
    b = np.array([basal_ml(g) for g in src], float)
    own = float(basal_ml(frame))
    if not (np.isfinite(b).all() and math.isfinite(own)):
        return None
    used = float(np.clip(lagrange_weights(nb, i) @ b, *sorted(b[1:3])))
    if used >= 0 and abs(used - own) > bound * volume:
        return BasalSupport(float(volume), own, used, src, ref, edges[frame])
    return None


# --------------------------------------------------------------- section-level support
#: a section (slice × surface) missing at a frame is interpolated in time only when its
#: slice is traced in more than this fraction of the frames (its gaps shorter than its runs)
SECTION_TRACED_FRACTION = 0.5
#: the surfaces in the order they are supported (the RV sections take the septum of the
#: slice's LV epicardium, own or interpolated)
_SUPPORT_ORDER = ("lv_endo", "lv_epi", "rv_endo", "rv_epi")


def traced_slices(geo: FrameGeometry) -> dict[str, set]:
    """Per surface, the SA slices one frame's own (not interpolated) sections lie on.

    Parameters
    ----------
    geo : FrameGeometry

    Returns
    -------
    dict str -> set of str
        surface -> slice identifiers.
    """
    return {s: {sec.slice for sec in secs if sec.slice is not None
                and (s, sec.slice) not in geo.in_time}
            for s, secs in geo.sections.items()}


def _traced_or_none(raw: Mapping[int, FrameGeometry], frame: int) -> dict[str, set]:
    """:func:`traced_slices` of one frame, nothing when its geometry cannot be made."""
    try:
        return traced_slices(raw[frame])
    except CardioNurbsError:
        return {}


def bracketing_frames(frame: int, frames: list[int], traced: set[int],
                      cyclic: bool) -> tuple[int, int, float] | None:
    """The nearest frames of ``traced`` before and after ``frame`` in ``frames``.

    Parameters
    ----------
    frame : int
        A frame of ``frames``.
    frames : list of int
        The frames of the cine, in order.
    traced : set of int
        The frames that have the section.
    cyclic : bool
        Whether the frames wrap around (the last is followed by the first).

    Returns
    -------
    (int, int, float) or None
        The frame before, the frame after and the weight of the later one (linear in
        frame position, in [0, 1]); None when one side has none.
    """
    n, i = len(frames), frames.index(frame)
    found = []
    for step in (-1, 1):
        k = i + step
        while abs(k - i) < n and (cyclic or 0 <= k < n) and frames[k % n] not in traced:
            k += step
        if abs(k - i) >= n or not (cyclic or 0 <= k < n):
            return None
        found.append(k)
    (a, b) = found
    return frames[a % n], frames[b % n], (i - a) / (b - a)


def _between(geo: FrameGeometry, structure: str, sec: Section) -> bool:
    """Whether a section lies between two of the frame's own sections of that surface.

    Only such a gap is filled: beyond its end sections a frame's surface ends where its
    motion takes it (the base descends through the basal slice in systole, the apical
    cavity closes as the wall thickens), and its long-axis contours and valve planes say
    where; a section interpolated there from frames of another phase contradicts them
    (reports/validation-quality.md: on bivme-patient1 and on phantoms it moved ES the
    wrong way)."""
    n = geo.direction
    levels = [float(s.points.mean(axis=0) @ n) for s in geo.sections.get(structure, [])]
    lev = float(sec.points.mean(axis=0) @ n)
    return len(levels) >= 2 and min(levels) < lev < max(levels)


#: a frame's own section is a *partial tracing* when its area is below this fraction of its
#: slice's area interpolated in time (linear, from the nearest frames that trace it) and its
#: ratio to each adjacent slice of its stack below this fraction of that ratio interpolated
#: likewise (a fifth of it missing: on phantoms at 1 px noise, 20 frames, no section whose
#: shortfall matters falls below 0.91 on both, reports/validation-quality.md)
PARTIAL_AREA_FRACTION = 0.8
#: ... and the area it lacks exceeds this fraction of the frame's largest section of that
#: surface (an apical section a few mm² across may halve from one frame to the next; a
#: shortfall of a tenth of the largest section moves a five-slice cavity by about 2 %)
PARTIAL_DEFICIT_FRACTION = 0.1
#: ... judged only when the frames that trace it lie within this many frames on each side:
#: at the edge of a slice's run in time (the base leaving or entering the slice) a section
#: shrinks for real, faster than any interpolation across the gap can follow
PARTIAL_MAX_STEP = 2
#: how a section left out as a partial tracing against its neighbouring frames is named
PARTIAL_PREFIX = "a partial tracing against its neighbouring frames"


def section_areas(geo: FrameGeometry) -> dict[str, dict[str, float]]:
    """Per surface, the area (mm²) of each of one frame's own SA sections.

    Parameters
    ----------
    geo : FrameGeometry

    Returns
    -------
    dict str -> dict str -> float
        surface -> slice -> area in mm² (interpolated sections and sections without a
        slice left out), the slices in the frame's stack order (base -> apex).
    """
    return {s: {sec.slice: _area(sec, geo.direction) for sec in secs
                if sec.slice is not None and (s, sec.slice) not in geo.in_time}
            for s, secs in geo.sections.items()}


def _area(sec: Section, direction: np.ndarray) -> float:
    """The section's area (mm²) about the stack direction, kept on the section
    (:func:`cardionurbs.cache.attached`): every frame's areas are asked for at every frame."""
    return attached(sec, "_area_along", _section_area)(tuple(map(float, direction)))


def _section_area(sec: Section, direction: tuple[float, float, float]) -> float:
    from cardionurbs.geometry import polygon_area
    return float(polygon_area(sec.points, np.array(direction)))


def _areas_or_none(raw: Mapping[int, FrameGeometry], frame: int) -> dict[str, dict[str, float]]:
    try:
        return section_areas(raw[frame])
    except CardioNurbsError:
        return {}


def partial_sections(frame: int, areas: Mapping[int, dict[str, dict[str, float]]],
                     frames: list[int]) -> dict[tuple[str, str], str]:
    """The sections of one frame that are partial tracings against the same slice in the
    neighbouring frames (see :data:`PARTIAL_AREA_FRACTION`, :data:`PARTIAL_DEFICIT_FRACTION`
    and :data:`PARTIAL_MAX_STEP`; the cine taken as periodic).

    Parameters
    ----------
    frame : int
    areas : mapping frame -> (surface -> slice -> mm²)
        :func:`section_areas` of every frame.
    frames : list of int
        The frames of the cine, in order.

    Returns
    -------
    dict (str, str) -> str
        (surface, slice) -> why (its area, the interpolated one and their frames).
    """
    out: dict[tuple[str, str], str] = {}
    n = len(frames)
    for s, own in areas.get(frame, {}).items():
        stack, largest = list(own), max(own.values(), default=0.0)
        for k, sl in enumerate(stack):
            have = {g for g in frames if g != frame and sl in areas.get(g, {}).get(s, {})}
            br = bracketing_frames(frame, frames, have, cyclic=True)
            if br is None:
                continue
            a, b, w = br
            i = frames.index(frame)
            if min((i - frames.index(a)) % n, (frames.index(b) - i) % n) < 1 or \
                    max((i - frames.index(a)) % n, (frames.index(b) - i) % n) > PARTIAL_MAX_STEP:
                continue
            expect = (1 - w) * areas[a][s][sl] + w * areas[b][s][sl]
            if not (own[sl] < PARTIAL_AREA_FRACTION * expect
                    and expect - own[sl] > PARTIAL_DEFICIT_FRACTION * largest):
                continue
            adj = [stack[j] for j in (k - 1, k + 1) if 0 <= j < len(stack)
                   and all(stack[j] in areas[g][s] for g in (a, b))]
            ratios = [(own[sl] / own[m]) / ((1 - w) * areas[a][s][sl] / areas[a][s][m]
                                            + w * areas[b][s][sl] / areas[b][s][m]) for m in adj]
            if ratios and max(ratios) < PARTIAL_AREA_FRACTION:
                out[(s, sl)] = (f"encloses {own[sl]:.0f} mm^2, {100 * own[sl] / expect:.0f} % of "
                                f"the {expect:.0f} mm^2 frames {a} and {b} give its slice "
                                f"(under {PARTIAL_AREA_FRACTION:.0%}, and under it against "
                                f"the adjacent slice{'s' if len(adj) > 1 else ''} "
                                f"{', '.join(adj)})")
    return out


def support_sections(frame: int, raw: Mapping[int, FrameGeometry],
                     frames: list[int]) -> FrameGeometry:
    """One frame's geometry with the sections it lacks interpolated in time.

    A section (SA slice × surface) traced at other frames but not at ``frame`` (not
    traced, or left out as a partial tracing) is made from the nearest frames before and
    after that trace it (:func:`bracketing_frames`, wrapping round a periodic cine): both
    loops resampled from the same anatomical seam (:func:`cardionurbs.anatomy.surfaces.
    resample_loop`) and blended linearly in frame position, point by point. Only slices
    traced in more than :data:`SECTION_TRACED_FRACTION` of the frames are supported, and
    only between two of the frame's own sections of that surface (:func:`_between`: a gap
    in its stack, not beyond its ends). docs/metrics.md, Frames.

    Parameters
    ----------
    frame : int
    raw : mapping frame -> FrameGeometry
        Every frame's geometry from its own contours (with ``reference`` set).
    frames : list of int
        The frames of the cine, in order. A cine of fewer than :data:`MIN_FRAMES` is not
        supported (its frames are too far apart in time); a longer one is taken to cover
        the whole cycle, so that the frames wrap around.

    Returns
    -------
    FrameGeometry
        ``raw[frame]`` itself when nothing is missing, else a copy whose ``sections``
        hold the interpolated ones (``source_points`` None: they have no contour points)
        and whose ``in_time`` maps (surface, slice) -> (frame before, frame after).
    """
    from cardionurbs.anatomy.surfaces import resample_loop
    geo = raw[frame]
    if len(frames) < MIN_FRAMES or frame not in frames:
        return geo
    areas = {g: _areas_or_none(raw, g) for g in frames}
    partial = {g: partial_sections(g, areas, frames) for g in frames}
    traced = {g: {s: v - {sl for t, sl in partial[g] if t == s}
                  for s, v in _traced_or_none(raw, g).items()} for g in frames}
    mine = partial[frame]
    if mine:
        geo = _without(geo, mine)
    new: dict[str, list[Section]] = {}
    in_time: dict[tuple[str, str], tuple[int, int]] = {}
    for s in _SUPPORT_ORDER:
        slices = sorted({sl for g in frames for sl in traced[g].get(s, ())})
        for sl in slices:
            have = {g for g in frames if sl in traced[g].get(s, ())}
            if frame in have or len(have) <= SECTION_TRACED_FRACTION * len(frames):
                continue
            br = bracketing_frames(frame, frames, have, cyclic=True)
            if br is None:
                continue
            a, b, w = br
            sa, sb = (next(x for x in raw[g].sections[s] if x.slice == sl) for g in (a, b))
            n, ref = geo.direction, geo.reference
            pts = (1 - w) * resample_loop(sa.points, n, ref) + w * resample_loop(sb.points, n, ref)
            sec = Section(s, frame, pts, slice=sl, plane=sa.plane)
            if (s, sl) in mine or _between(geo, s, sec):
                new.setdefault(s, []).append(sec)
                in_time[(s, sl)] = (a, b)
    if not new:
        return geo
    return _with_sections(geo, new, in_time)


def _without(geo: FrameGeometry, partial: dict[tuple[str, str], str]) -> FrameGeometry:
    """A copy of ``geo`` without its ``partial`` sections ((surface, slice) -> why), each
    left out (``left_out``) with one warning; :func:`support_sections` replaces them."""
    sections = {s: [sec for sec in secs if (s, sec.slice) not in partial]
                for s, secs in geo.sections.items()}
    out = dataclasses.replace(geo, sections=sections, warnings=list(geo.warnings),
                              left_out=list(geo.left_out))
    for (s, sl), why in sorted(partial.items()):
        out.left_out.append((s, sl, f"{PARTIAL_PREFIX} {why}"))
        out.warnings.append(f"frame {geo.frame}: slice {sl}: {s} contour {why}; "
                            f"{PARTIAL_PREFIX}, replaced by its slice's section interpolated "
                            "in time (QC flag)")
    return out


def _with_sections(geo: FrameGeometry, new: dict[str, list[Section]],
                   in_time: dict[tuple[str, str], tuple[int, int]]) -> FrameGeometry:
    """A copy of ``geo`` with the ``new`` sections among its own (ordered base -> apex),
    the RV sections' septa taken from their slice's LV epicardium, and one warning."""
    n = geo.direction
    sections = {s: list(secs) for s, secs in geo.sections.items()}
    for s, secs in new.items():
        sections[s] = sorted(sections.get(s, []) + secs,
                             key=lambda sec: float(sec.points.mean(axis=0) @ n))
    epi = {sec.slice: sec for sec in sections.get("lv_epi", [])}
    for s in ("rv_endo", "rv_epi"):
        sections[s] = [dataclasses.replace(sec, septum_of=epi[sec.slice].points)
                       if sec.slice in epi and (sec.septum_of is None or ("lv_epi", sec.slice)
                                                in in_time) else sec
                       for sec in sections.get(s, [])]
    by_src: dict[tuple[int, int], list[str]] = {}
    for (s, sl), src in in_time.items():
        by_src.setdefault(src, []).append(f"{s} {sl}")
    text = "; ".join(f"{', '.join(v)} from frames {a} and {b}" for (a, b), v in by_src.items())
    out = dataclasses.replace(geo, sections=sections, in_time=dict(in_time),
                              warnings=list(geo.warnings))
    out.warnings.append(f"frame {geo.frame}: sections not traced at this frame interpolated in "
                        f"time (section-level support): {text}")
    return out
