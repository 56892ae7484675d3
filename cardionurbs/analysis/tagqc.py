"""Tag-jump QC: leave-one-out departure of each tag line from its tag surface.

"Tag jumping" (paper §4.2.3, Fig. 8): a 2D tracker assigns a tag line in
one slice to the neighbouring tag plane, so the lofted tag surface gets a
one-spacing step. For every tag (family, index) at every tagged frame, and
every slice (SA families) or view (``la``) showing it, we

1. loft the tag surface through the *other* slices' fitted curves with
   degree 1 across the slices (paper §3.2.4 with q = 1): with sections on
   one knot vector this is the blend S(u, v) = (1 − t) C_a(u) + t C_b(u)
   between two remaining sections a, b. Several pairs predict the left-out
   line — inside the stack the pairs bracketing it (also skipping the
   nearest section on one side), at a stack end the pairs among the three
   nearest (linear extension) — and the line's departure is the smallest
   of them, so that one jumped neighbour cannot make a good line look bad. For ``la`` the sections are the spokes
   of the other views around the long axis, a and b the spokes on either
   side of the left-out spoke's angle, blended in cylindrical coordinates;
2. cut that surface with the left-out image plane: for every u, t(u) =
   d_a / (d_a − d_b) with d the signed distances of C_a(u), C_b(u) from the
   plane, giving the trace T(u) in the plane;
3. measure each left-out tag point's signed distance from the trace
   across its tangent (the trace extended by its end tangents) and take
   the median over the line: the residual r of the line for that pair;
4. (SA families) compare r with the trend t of the same residual over the
   neighbouring tags of the same slice (a robust local quadratic in the tag
   index): where the tag surfaces bend (the apical slices near
   end-systole) every tag's loft misses by a similar, smoothly varying
   amount, whereas a jump is a one-tag step. The line's departure is
   min(|r|, |r − t|) over the predicting pairs, in tag spacings.

Degree 1 rather than 3 across the slices: a cubic loft through a jumped
line swings by about a spacing at every other slice (and more where it
extrapolates), whereas the linear blend confines a jump's influence to its
two neighbours (about half a spacing each). Lines whose departure exceeds
the threshold (0.5 spacing) are flagged one at a time, worst first, and
left out of the lofts before the others are measured again, so a jumped
line (about one spacing) is flagged and its neighbours, measured again
without it, are not.

Tracked lines (:mod:`cardionurbs.tracking`) also carry a confidence per line;
those below it are flagged with reason "low confidence" (:func:`confidence_flags`).

Tag spacing: ``study.meta["tag_spacing_mm"]`` when given, else estimated
per family and frame from neighbouring indices (median over slices of the
distance between consecutive tag lines' centroids across the lines,
divided by their index difference).
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from functools import lru_cache
from itertools import product

import numpy as np

from cardionurbs.analysis.strain import cylindrical
from cardionurbs.analysis.tag_surfaces import TagSection, family_direction
from cardionurbs.anatomy.sections import study_long_axis
from cardionurbs.median import median
from cardionurbs.study import TAG_FAMILIES, Study

DEFAULT_THRESHOLD = 0.5
_NU = 48


@dataclass(frozen=True)
class TagFlag:
    """One tag line judged mistracked: departure in tag spacings from the others' surface.

    Attributes
    ----------
    family : {"sa1", "sa2", "la"}
        The tag family.
    index : int
        The tag's index.
    slice : str
        The slice of the line.
    frame : int
        The frame.
    departure : float
        Tag spacings (NaN for a low-confidence flag).
    reason : {"jump", "low confidence"}
        Why it is flagged.
    """

    family: str
    index: int
    slice: str
    frame: int
    departure: float
    reason: str = "jump"     # "jump", or "low confidence" (tracked from images, see below)

    def as_tuple(self) -> tuple:
        """(family, index, slice, frame, departure).

        Returns
        -------
        tuple
        """
        return (self.family, self.index, self.slice, self.frame, self.departure)


@dataclass(frozen=True)
class LineDeparture:
    """Leave-one-out departure of one tag line (every line, flagged or not).

    Attributes
    ----------
    family : {"sa1", "sa2", "la"}
        The tag family.
    index : int
        The tag's index.
    slice : str
        The slice of the line.
    frame : int
        The frame.
    departure : float
        Tag spacings.
    flagged : bool
        Whether it was flagged.
    """

    family: str
    index: int
    slice: str
    frame: int
    departure: float
    flagged: bool


# ---------------------------------------------------------------- geometry
def _samples(section, ns: int = _NU) -> np.ndarray:
    """(ns, 3) points of a section's fitted curve at uniform u."""
    return _uniform_basis(np.asarray(section.knots, float).tobytes(), ns) @ section.ctrl


@lru_cache(maxsize=64)
def _uniform_basis(knots: bytes, ns: int) -> np.ndarray:
    """(ns, n) cubic basis at ns uniform u of a knot vector (float64 bytes): the sections of
    one fit share one knot vector (fit_sections)."""
    from cardionurbs.nurbs.basis import basis_matrix
    return basis_matrix(np.frombuffer(knots), 3, np.linspace(0.0, 1.0, ns))


def blend_trace(Ca: np.ndarray, Cb: np.ndarray, origin: np.ndarray, normal: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Trace (k, 3) and unit tangents of the degree-1 loft between two sampled sections in a plane.

    T(u) = C_a(u) + t(u) (C_b(u) − C_a(u)), t = d_a / (d_a − d_b), d the
    signed distances from the plane (t outside [0, 1] extends the blend).

    Parameters
    ----------
    Ca, Cb : (k, 3) ndarray
        The two sections sampled at the same k parameters, mm.
    origin : (3,) ndarray
        A point of the plane, mm.
    normal : (3,) ndarray
        The plane's unit normal.

    Returns
    -------
    trace : (k, 3) ndarray
        mm.
    tangents : (k, 3) ndarray
        Unit tangents.
    """
    da = (Ca - origin) @ normal
    db = (Cb - origin) @ normal
    den = da - db
    ok = np.abs(den) > 1e-9
    t = np.where(ok, da / np.where(ok, den, 1.0), 0.0)
    T = Ca + t[:, None] * (Cb - Ca)
    T = T[ok]
    T -= np.outer((T - origin) @ normal, normal)
    if len(T) < 2:
        return T, np.zeros_like(T)
    tan = np.gradient(T, axis=0)
    tan -= np.outer(tan @ normal, normal)
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-12)
    return T, tan


def signed_distance_to_trace(points: np.ndarray, trace: np.ndarray, tangents: np.ndarray,
                             normal: np.ndarray) -> np.ndarray:
    """In-plane distance (mm) of points from a trace across its tangent, signed along
    normal × tangent (the same side for every tag of a family: their lines share one
    orientation).

    Parameters
    ----------
    points : (n, 3) ndarray
        Points in the plane, mm.
    trace : (k, 3) ndarray
        The trace, mm.
    tangents : (k, 3) ndarray
        Its unit tangents.
    normal : (3,) ndarray
        The plane's unit normal.

    Returns
    -------
    (n,) ndarray
        mm.
    """
    if len(trace) == 0:
        return np.full(len(points), np.nan)
    diff = points[:, None, :] - trace[None]
    j = np.argmin((diff ** 2).sum(-1), axis=1)
    dd = diff[np.arange(len(points)), j]
    return (dd * _cross_rows(normal, tangents[j])).sum(1)


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for one vector a (3,) and rows b (n, 3): the same products and differences as
    ``np.cross`` (bit-identical) without its per-call overhead."""
    return np.column_stack([a[1] * b[:, 2] - a[2] * b[:, 1], a[2] * b[:, 0] - a[0] * b[:, 2],
                            a[0] * b[:, 1] - a[1] * b[:, 0]])


def distance_to_trace(points: np.ndarray, trace: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point from the nearest trace point, across the trace's tangent.

    Parameters
    ----------
    points : (n, 3) ndarray
        Points, mm.
    trace : (k, 3) ndarray
        The trace, mm.
    tangents : (k, 3) ndarray
        Its unit tangents.

    Returns
    -------
    (n,) ndarray
        mm.
    """
    if len(trace) == 0:
        return np.full(len(points), np.inf)
    diff = points[:, None, :] - trace[None]
    j = np.argmin((diff ** 2).sum(-1), axis=1)
    dd = diff[np.arange(len(points)), j]
    t = tangents[j]
    perp = dd - (dd * t).sum(1, keepdims=True) * t
    return np.linalg.norm(perp, axis=1)


# ------------------------------------------------------------------ spacing
def tag_spacing(study: Study, family: str, frame: int,
                sections: dict[int, list[TagSection]] | None = None) -> float:
    """Tag spacing (mm) of one family at one frame (see module docstring); NaN when unknown.

    Parameters
    ----------
    study : Study
        The study.
    family : {"sa1", "sa2", "la"}
        The tag family.
    frame : int
        The frame.
    sections : dict of int to list of TagSection or None
        The family's sections, when already built.

    Returns
    -------
    float
        mm.
    """
    given = study.meta.get("tag_spacing_mm") if isinstance(study.meta, dict) else None
    if given:
        return float(given)
    lines = study.tags_at(frame, family)
    if not lines:
        return float("nan")
    by_slice: dict[str, list[int]] = {}
    for k, t in enumerate(lines):
        by_slice.setdefault(t.slice, []).append(k)
    pts = [t.points for t in lines]
    d_fam = family_direction(pts)
    centroids = [p.mean(axis=0) for p in pts]
    index = np.array([t.index for t in lines])
    est = []
    for slc, ks in by_slice.items():
        if len(ks) < 2:
            continue
        plane = study.slice_plane(slc)
        along = family_direction([pts[k] for k in ks]) if family == "la" else d_fam
        across = _cross_rows(plane.normal, along[None])[0]
        across /= np.linalg.norm(across)
        idx = index[ks]
        pos = np.array([centroids[k] @ across for k in ks])
        order = np.argsort(idx)
        di, dp = np.diff(idx[order]), np.diff(pos[order])
        ok = di > 0
        if ok.any():
            est.append(median(np.abs(dp[ok]) / di[ok]))
    return median(est) if est else float("nan")


# ----------------------------------------------------------------- LOO core
def _neighbour_pairs(keys, h: float) -> list[tuple[int, int]]:
    """Pairs of remaining sections that predict the section at stack position h.

    Inside the stack the pairs that bracket h — the nearest section on each
    side, and each of them with the second nearest on the other side — so
    that whichever single neighbour jumped, a bracketing pair without it
    remains; beyond the first or last remaining section, the pairs among
    the three nearest (linear extension by one or two gaps). Extension pairs
    are not used inside the stack — two jumps on one tag could otherwise
    explain each other — except next to a stack end, where one side has a
    single section: every bracketing pair contains it, so the two nearest
    on the other side, extended by one gap, are the witness without it.
    ``keys``: the remaining sections' stack positions, ascending (a list or an array).
    """
    n = len(keys)
    j = bisect_left(keys, h)            # np.searchsorted's index, without its call overhead
    L = [i for i in (j - 1, j - 2) if 0 <= i < n]
    R = [i for i in (j, j + 1) if 0 <= i < n]
    if L and R:
        pairs = [(L[0], R[0])]
        pairs += [(L[1], R[0])] if len(L) > 1 else []
        pairs += [(L[0], R[1])] if len(R) > 1 else []
        if len(R) == 1 and len(L) > 1:     # R[0] is in every bracketing pair: extend the
            pairs.append((L[1], L[0]))      # other side by one gap, the witness without it
        elif len(L) == 1 and len(R) > 1:
            pairs.append((R[0], R[1]))
        return pairs
    side = sorted([i for i in (j - 1, j - 2, j - 3) if 0 <= i < n] if not R
                  else [i for i in (j, j + 1, j + 2) if 0 <= i < n])
    return [(side[a], side[b]) for a in range(len(side)) for b in range(a + 1, len(side))]


def _neighbours_cyclic(angles: np.ndarray, a: float) -> tuple[int, int] | None:
    """Indices of the remaining spokes just before and just after angle a (cyclic)."""
    if len(angles) < 2:
        return None
    d = (angles - a) % (2 * np.pi)
    after = int(np.argmin(d))
    before = int(np.argmax(d))
    return before, after


def spoke_height_departure(points: np.ndarray, Ca: np.ndarray, Cb: np.ndarray,
                           axis: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Axial distance (mm) of LA spoke points from the linear loft of two neighbouring spokes.

    The loft is taken in cylindrical coordinates (r, θ, z) about the long
    axis: z_pred(r, θ) = (1 − w) z_a(r) + w z_b(r), w the angular fraction of
    θ between the spokes' angles, z_a(r) the neighbour's height at radius r
    (its samples interpolated in r, held constant beyond its ends). A
    straight blend of two radial spokes would follow their chord, far inside
    the wall at the left-out angle.

    Parameters
    ----------
    points : (n, 3) ndarray
        The left-out spoke's points, mm.
    Ca, Cb : (k, 3) ndarray
        The neighbouring spokes sampled, mm.
    axis : (apex (3,), base (3,))
        The long axis, mm.

    Returns
    -------
    (n,) ndarray
        mm.
    """
    frame = _axis_cylinder(axis)
    return _spoke_departure(cylindrical(points, *frame), _spoke_profile(Ca, frame),
                            _spoke_profile(Cb, frame))


def _axis_cylinder(axis: tuple[np.ndarray, np.ndarray]) -> tuple:
    """(apex, (e1, e2, e)): the cylindrical frame about the long axis (apex, base), as
    :func:`cardionurbs.analysis.strain.cylindrical` takes it."""
    from cardionurbs.analysis.tag_surfaces import axis_frame
    apex, base = axis
    return apex, axis_frame(apex, base)


def _spoke_profile(C: np.ndarray, frame: tuple) -> tuple[float, np.ndarray, np.ndarray]:
    """A neighbouring spoke's angle (circular mean of its outer half) and its heights
    z(r) sorted by radius: what :func:`spoke_height_departure` interpolates."""
    r, t, z = cylindrical(C, *frame)
    th = float(np.angle(np.exp(1j * t[r > 0.5 * r.max()]).mean()))
    o = np.argsort(r)
    return th, r[o], z[o]


def _spoke_profiles(samples: list[np.ndarray], frame: tuple) -> list[tuple]:
    """:func:`_spoke_profile` of every spoke at once (one cylindrical transform of all
    their samples; the circular means as masked sums, equal to rounding)."""
    C = np.stack(samples)                                        # (K, S, 3)
    K, S = C.shape[:2]
    r, t, z = (x.reshape(K, S) for x in cylindrical(C.reshape(-1, 3), *frame))
    o = np.argsort(r, axis=1)
    rows = np.arange(K)[:, None]
    rs, zs = r[rows, o], z[rows, o]
    outer = r > 0.5 * r.max(axis=1, keepdims=True)               # each spoke's outer half
    th = np.angle(np.where(outer, np.exp(1j * t), 0).sum(axis=1) / outer.sum(axis=1))
    return [(float(th[k]), rs[k], zs[k]) for k in range(K)]


def _spoke_points_cylindrical(secs: list[TagSection], frame: tuple) -> list[tuple]:
    """(r, θ, ζ) of every spoke's data points (its first point, the cut on the axis, left
    out), for all spokes with one cylindrical transform."""
    pts = [s.points[1:] for s in secs]
    n = np.cumsum([len(p) for p in pts])[:-1]
    r, t, z = cylindrical(np.concatenate(pts), *frame)
    return list(zip(np.split(r, n), np.split(t, n), np.split(z, n)))


def _spoke_departure(cyl: tuple, prof_a: tuple, prof_b: tuple) -> np.ndarray:
    rp, tp, zp = cyl
    tha, ra, za = prof_a
    thb, rb, zb = prof_b
    span = (thb - tha) % (2 * np.pi)
    w = np.clip(((tp - tha) % (2 * np.pi)) / max(span, 1e-9), 0.0, 1.0)
    z_a = np.interp(rp, ra, za)
    z_b = np.interp(rp, rb, zb)
    return np.abs(zp - ((1 - w) * z_a + w * z_b))


def loo_departures(secs: list[TagSection], samples: list[np.ndarray], spacing: float,
                   periodic: bool, exclude: AbstractSet[str] = frozenset(),
                   axis: tuple | None = None, profiles: dict | None = None) -> dict[str, float]:
    """Leave-one-out departure (tag spacings) of each slice's line of one tag at one frame.

    Used for the LA spoke fan (``periodic``); the SA families go through
    :func:`sa_family_departures`, which also compares neighbouring tags.
    ``secs`` and ``samples`` (their fitted curves at uniform u) in loft
    order; ``exclude``: slices already flagged, left out of every loft;
    ``axis`` (apex, base) for the LA spoke fan (``periodic``); ``profiles``: a dict that
    keeps each spoke's profile (:func:`_spoke_profile`, by its index in ``secs``) and its
    points' cylindrical coordinates (key ``("points", index)``) between calls on the same
    ``secs``, ``samples`` and ``axis`` (the worst-first passes).
    Returns {slice: departure}; slices that cannot be judged are absent.

    Parameters
    ----------
    secs : list of TagSection
        As above.
    samples : list of (k, 3) ndarray
        As above.
    spacing : float
        The family's tag spacing, mm.
    periodic : bool
        The LA spoke fan.
    exclude : set of str
        As above.
    axis : (apex (3,), base (3,)) or None
        As above.
    profiles : dict or None
        As above.

    Returns
    -------
    dict of str to float
    """
    names = list(dict.fromkeys(s.slice for s in secs if s.slice not in exclude))
    out: dict[str, float] = {}
    if len(names) < 3:
        return out
    if periodic:       # each spoke's profile once, however many left-out spokes it predicts
        assert axis is not None, "the LA spoke fan's departures need its axis"
        cyl = _axis_cylinder(axis)
        profiles = {} if profiles is None else profiles
        if not profiles:                 # every spoke's profile and points, in one batch
            profiles.update(enumerate(_spoke_profiles(samples, cyl)))
            profiles.update({("points", k): c
                             for k, c in enumerate(_spoke_points_cylindrical(secs, cyl))})

        known = profiles

        def profile(k: int) -> tuple:
            return known[k]
    for left in names:
        keep = [k for k, s in enumerate(secs) if s.slice != left and s.slice not in exclude]
        mine = [k for k, s in enumerate(secs) if s.slice == left]
        keys = np.array([secs[k].key for k in keep])
        if periodic:   # LA: both spokes of the left-out view against their angular neighbours
            dist = []
            for k in mine:
                nb = _neighbours_cyclic(keys, secs[k].key)
                if nb is not None:   # a spoke's first point is the cut on the axis, not data
                    dist.append(_spoke_departure(known[("points", k)],
                                                 profile(keep[nb[0]]), profile(keep[nb[1]])))
            if dist:
                out[left] = median(np.concatenate(dist)) / spacing
            continue
        sec = secs[mine[0]]
        plane = sec.plane
        best = np.inf
        for a, b in _neighbour_pairs(keys, sec.key):
            trace, tan = blend_trace(samples[keep[a]], samples[keep[b]], plane.position,
                                     plane.normal)
            best = min(best, median(distance_to_trace(sec.points, trace, tan)))
        if np.isfinite(best):
            out[left] = best / spacing
    return out


def loo_residuals(secs: list[TagSection], samples: list[np.ndarray],
                  exclude: AbstractSet[str] = frozenset()) -> dict[str, dict[tuple[str, str], float]]:
    """Signed leave-one-out residual (mm) of each SA slice's line of one tag, per predictor.

    {slice: {(slice_a, slice_b): median signed in-plane distance of the line's
    points from the degree-1 loft of sections a, b}} (module docstring, steps 1–3).

    Parameters
    ----------
    secs : list of TagSection
        One tag's SA sections in loft order.
    samples : list of (k, 3) ndarray
        Their fitted curves at uniform u, mm.
    exclude : set of str
        Slices left out of every loft.

    Returns
    -------
    dict of str to dict of (str, str) to float
        mm.
    """
    return loo_residuals_many([(secs, samples, exclude)])[0]


def loo_residuals_many(tags: Sequence[tuple[Sequence[TagSection], list[np.ndarray], AbstractSet[str]]]
                       ) -> list[dict[str, dict[tuple[str, str], float]]]:
    """:func:`loo_residuals` of several tags, ``tags`` = [(secs, samples, exclude)], with
    every (left-out line, predictor pair) of all of them measured in one batch
    (:func:`_pair_residuals_many`): the same numbers, without a numpy call per line.

    Parameters
    ----------
    tags : sequence of (sections, samples, exclude)
        As :func:`loo_residuals`' arguments, one triple per tag.

    Returns
    -------
    list of dict
        :func:`loo_residuals` of each tag, in order.
    """
    lines = []            # (tag, slice, pair names) per problem
    points, Ca, Cb, origins, normals = [], [], [], [], []
    for t, (secs, samples, exclude) in enumerate(tags):
        active = [k for k, s in enumerate(secs) if s.slice not in exclude]
        if len(active) < 3:
            continue
        active_keys = [secs[k].key for k in active]
        for pos, i in enumerate(active):
            sec = secs[i]
            keep = active[:pos] + active[pos + 1:]
            keys = active_keys[:pos] + active_keys[pos + 1:]
            for a, b in _neighbour_pairs(keys, sec.key):
                lines.append((t, sec.slice, (secs[keep[a]].slice, secs[keep[b]].slice)))
                points.append(sec.points)
                Ca.append(samples[keep[a]])
                Cb.append(samples[keep[b]])
                origins.append(sec.plane.position)
                normals.append(sec.plane.normal)
    out: list[dict] = [{} for _ in tags]
    for (t, slc, pair), m in zip(lines, _pair_residuals_many(points, Ca, Cb, origins, normals)):
        if m is not None:
            out[t].setdefault(slc, {})[pair] = m
    return out


def _pair_residuals(points: np.ndarray, Ca: list[np.ndarray], Cb: list[np.ndarray],
                    origin: np.ndarray, normal: np.ndarray) -> list[float | None]:
    """Median signed distance (mm) of ``points`` from the trace of every predictor pair
    (:func:`blend_trace` of Ca[k], Cb[k] cut by the plane, then
    :func:`signed_distance_to_trace`); None where it is undefined."""
    n = len(Ca)
    return _pair_residuals_many([points] * n, Ca, Cb, [origin] * n, [normal] * n)


def _pair_residual_one(points, a, b, origin, normal) -> float | None:
    trace, tan = blend_trace(a, b, origin, normal)
    d = signed_distance_to_trace(points, trace, tan, normal)
    return median(d) if len(d) and np.isfinite(d).all() else None


#: the largest (problems x points x samples) block :func:`_pair_residuals_many` forms at once
_BLOCK = 400_000


def _pair_residuals_many(points: list[np.ndarray], Ca: list[np.ndarray], Cb: list[np.ndarray],
                         origins: list[np.ndarray], normals: list[np.ndarray]
                         ) -> list[float | None]:
    """Median signed distance (mm) of ``points[k]`` from the trace of ``Ca[k]``, ``Cb[k]``
    in the plane (``origins[k]``, ``normals[k]``), for every k: :func:`blend_trace`, then
    :func:`signed_distance_to_trace`, then the median; None where it is undefined.

    Problems in blocks of similar point counts (arrays (problems, points, samples, 3),
    the shorter point sets padded with NaN and left out of the median) when every sample
    of the pair cuts the plane, which is the rule; one by one otherwise (the trace then
    loses samples)."""
    K = len(points)
    out: list[float | None] = [None] * K
    if K == 0:
        return out
    A, B = np.stack(Ca), np.stack(Cb)                               # (K, S, 3)
    O, N = np.stack(origins), np.stack(normals)                     # (K, 3)
    da = ((A - O[:, None]) @ N[:, :, None])[..., 0]
    db = ((B - O[:, None]) @ N[:, :, None])[..., 0]
    den = da - db
    npts = np.array([len(p) for p in points])
    batch = (npts > 0) & (np.abs(den) > 1e-9).all(axis=1) & (A.shape[1] >= 2)
    for k in np.flatnonzero(~batch):
        out[k] = _pair_residual_one(points[k], A[k], B[k], O[k], N[k])
    todo = np.flatnonzero(batch)
    todo = todo[np.argsort(npts[todo], kind="stable")]
    S = A.shape[1]
    start = 0
    while start < len(todo):
        stop = start + 1
        while stop < len(todo) and (stop + 1 - start) * npts[todo[stop]] * S <= _BLOCK:
            stop += 1
        ks = todo[start:stop]
        start = stop
        M = int(npts[ks].max())
        P = np.full((len(ks), M, 3), np.nan)
        for r, k in enumerate(ks):
            P[r, :npts[k]] = points[k]
        n, o = N[ks], O[ks]
        t = da[ks] / den[ks]
        T = A[ks] + t[..., None] * (B[ks] - A[ks])
        T -= ((T - o[:, None]) @ n[:, :, None]) * n[:, None, :]
        tan = np.gradient(T, axis=1)
        tan -= (tan @ n[:, :, None]) * n[:, None, :]
        tan /= np.maximum(np.linalg.norm(tan, axis=2, keepdims=True), 1e-12)
        # squared distances (k, points, samples), summed x, y, z in that order, in two
        # reused buffers from contiguous coordinate planes (no temporaries per term)
        Pc, Tc = P.transpose(2, 0, 1).copy(), T.transpose(2, 0, 1).copy()
        sq = np.subtract(Pc[0][:, :, None], Tc[0][:, None, :])
        np.multiply(sq, sq, out=sq)
        buf = np.empty_like(sq)
        for c in (1, 2):
            np.subtract(Pc[c][:, :, None], Tc[c][:, None, :], out=buf)
            np.multiply(buf, buf, out=buf)
            np.add(sq, buf, out=sq)
        j = np.argmin(sq, axis=2)                                    # (k, points)
        R = np.arange(len(ks))[:, None]
        dd = P - T[R, j]                                             # (k, points, 3)
        tj = tan[R, j]
        nn = n[:, None, :]
        across = np.stack([nn[..., 1] * tj[..., 2] - nn[..., 2] * tj[..., 1],
                           nn[..., 2] * tj[..., 0] - nn[..., 0] * tj[..., 2],
                           nn[..., 0] * tj[..., 1] - nn[..., 1] * tj[..., 0]], axis=-1)
        d = (dd * across).sum(-1)                                     # (k, points), NaN padded
        real = np.arange(M)[None, :] < npts[ks][:, None]
        finite = (np.isfinite(d) | ~real).all(axis=1)
        d = np.sort(np.where(real, d, np.inf), axis=1)
        m = npts[ks]
        med = (d[R[:, 0], (m - 1) // 2] + d[R[:, 0], m // 2]) / 2  # np.median's middle
        for r, k in enumerate(ks):
            out[k] = float(med[r]) if finite[r] else None
    return out


def _index_trend(values: list[tuple[int, float]], i: int, outlier: float) -> float:
    """Residual expected at tag index i from the other tags' (index, residual) in its slice.

    A weighted least-squares polynomial in the index — quadratic with four
    or more tags, else linear or constant — with weights 1 / (1 + |j − i|)²
    (the nearest tags count most), refitted once without the tags that
    depart from the first fit by more than ``outlier`` (jumped lines);
    evaluated at i. No other tag: 0 (no correction).
    """
    return float(_index_trends([values], [i], outlier)[0])


def _weighted_polyfits(x: np.ndarray, y: np.ndarray, w: np.ndarray, n: np.ndarray,
                       deg: int) -> np.ndarray:
    """Coefficients (rows, highest power first) of the weighted least-squares polynomials
    of degree ``deg`` through the rows of (x, y), weights ``w`` on the residuals (0 where a
    row has no point), ``n`` points per row: what ``np.polyfit(x, y, deg, w=w)`` computes, for
    every row at once (scaled Vandermonde columns, least squares by SVD with its cut-off
    n·eps)."""
    A = (x[..., None] ** np.arange(deg, -1, -1)) * w[..., None]          # (rows, m, deg + 1)
    scale = np.sqrt((A * A).sum(axis=1))                                   # (rows, deg + 1)
    U, sv, Vt = np.linalg.svd(A / scale[:, None, :], full_matrices=False)
    cut = (n * np.finfo(float).eps)[:, None] * sv[:, :1]
    inv = np.where(sv > cut, 1.0 / np.where(sv > 0, sv, 1.0), 0.0)
    c = np.einsum("rji,rj,rkj,rk->ri", Vt, inv, U, y * w)
    return c / scale


def _index_trends(values: list[list[tuple[int, float]]], at: list[int],
                  outlier: float) -> np.ndarray:
    """:func:`_index_trend` of many (values, i) at once: the weighted fits of every
    problem with the same number of kept tags solved as one batch."""
    P = len(values)
    out = np.zeros(P)
    m = np.array([len(v) for v in values])
    if P == 0 or m.max(initial=0) == 0:
        return out
    M = int(m.max())
    J, Rv = np.zeros((P, M)), np.zeros((P, M))
    valid = np.arange(M)[None, :] < m[:, None]
    flat = np.array([x for v in values for x in v], dtype=float).reshape(-1, 2)
    J[valid], Rv[valid] = flat[:, 0], flat[:, 1]          # row by row, in order
    X = J - np.asarray(at, float)[:, None]
    keep = valid.copy()
    active = m > 0
    for _ in range(2):
        n = keep.sum(axis=1)
        for p in np.flatnonzero(active & (n == 0)):
            out[p] = 0.0
        for p in np.flatnonzero(active & (n == 1)):
            out[p] = Rv[p][keep[p]][0]
        active &= n >= 2
        if not active.any():
            break
        fit = np.zeros((P, M))
        for deg in (1, 2):
            rows = np.flatnonzero(active & ((n >= 4) if deg == 2 else (n < 4)))
            if not len(rows):
                continue
            w = np.where(keep[rows], 1.0 / (1.0 + np.abs(X[rows])), 0.0)   # sqrt of 1/(1+|j-i|)^2
            c = _weighted_polyfits(X[rows], Rv[rows], w, n[rows], deg)
            out[rows] = c[:, -1]
            fit[rows] = np.einsum("rmd,rd->rm", X[rows][..., None] ** np.arange(deg, -1, -1), c)
        new = (np.abs(Rv - fit) <= outlier) & valid
        stop = (new.sum(axis=1) < 1) | (new == keep).all(axis=1)
        active &= ~stop
        keep = np.where(active[:, None], new, keep)
    return out


def _is_extrapolated(secs: list[TagSection], slc: str, exclude: set[str]) -> bool:
    """True when slice ``slc`` lies beyond the first or last remaining section of its tag
    (its line can only be predicted by extending the loft)."""
    keys = [s.key for s in secs if s.slice != slc and s.slice not in exclude]
    mine = next(s.key for s in secs if s.slice == slc)
    return bool(keys) and not (min(keys) <= mine <= max(keys))


def _stack_ends(secs: list[TagSection], slices, exclude: set[str]) -> dict[str, bool]:
    """:func:`_is_extrapolated` of each of ``slices`` (lines of one tag), from one pass over
    the tag's sections."""
    keys = [(s.slice, s.key) for s in secs if s.slice not in exclude]
    own: dict[str, float] = {}
    for s in secs:
        own.setdefault(s.slice, s.key)
    out = {}
    for slc in slices:
        others = [k for sl, k in keys if sl != slc]
        out[slc] = bool(others) and not (min(others) <= own[slc] <= max(others))
    return out


def _time_witnesses(temporal: Sequence[dict], i: int, slc: str, pair: tuple[str, str]) -> list[float]:
    """Residuals (mm) of the same line against the same pair at the neighbouring frames (each
    a separate witness, so that a jump at one neighbouring frame cannot make a good line look
    bad); empty when no neighbouring frame has it."""
    return [R[i][slc][pair] for R in temporal if i in R and slc in R[i] and pair in R[i][slc]]


def sa_family_departures(groups: dict[int, list[TagSection]], spacing: float,
                         threshold: float, residuals: dict | None = None,
                         temporal: Sequence[dict] = ()) -> list[tuple[int, str, float, bool]]:
    """Departures (tag spacings) of every line of one SA family at one frame, with flags.

    A line's residual r against a predictor pair is also compared with the
    trend t of the other tags' residuals in the same slice against the same
    pair (:func:`_index_trend`, a robust local polynomial in the tag index):
    the loft's own error where the tag surfaces bend (the apical slices
    near end-systole) varies smoothly from tag to tag, a jump does not. The
    departure is min(|r|, |r − t|) over the predictor pairs: a line is
    flagged only when neither its own tag's other slices nor its
    neighbouring tags explain it. Worst first, lines above ``threshold`` are flagged and left out,
    and the family is measured again. Returns (index, slice, departure, flagged).

    A line beyond the remaining sections of its tag (a stack end) is only
    predicted by extending the loft one or two gaps, whose error is large
    and differs between tags (the edge tags have few neighbours sharing its
    predictor pair, so the index trend is a far tag's); there t is instead
    the same line's residual against the same pair at the previous and at
    the next tagged frame, each a witness (``temporal``: the initial
    ``residuals`` of this family at those frames): the extension's error
    changes smoothly over the cycle, a jump is a step at one frame. Only
    when both neighbouring frames have it (bracketed in time, as interior
    lines are bracketed in space); otherwise — the first or last frame, an
    ED + ES study — the index trend is kept.

    Parameters
    ----------
    groups : dict of int to list of TagSection
        Tag index -> its SA sections.
    spacing : float
        The family's tag spacing, mm.
    threshold : float
        The flag threshold, tag spacings.
    residuals : dict or None
        Tag index -> its :func:`loo_residuals`, when already measured.
    temporal : sequence of dict
        As above.

    Returns
    -------
    list of (int, str, float, bool)
        (index, slice, departure in tag spacings, flagged).
    """
    samples: dict[int, list[np.ndarray]] = {}     # each tag's sampled sections, when needed

    def sampled(i: int) -> list[np.ndarray]:
        if i not in samples:
            samples[i] = [_samples(s) for s in groups[i]]
        return samples[i]

    excl: dict[int, set[str]] = {i: set() for i in groups}
    R = dict(residuals) if residuals is not None else \
        {i: loo_residuals(groups[i], sampled(i)) for i in groups}

    def departures() -> dict[tuple[int, str], float]:
        lines, index_problems = [], []        # index trends of every line, one batch
        by_pair: dict[tuple[str, tuple], list] = {}    # (slice, pair) -> [(tag, residual)]
        for j in R:
            for slc in R[j]:
                for pair, r in R[j][slc].items():
                    by_pair.setdefault((slc, pair), []).append((j, r))
        for i in R:
            ends = _stack_ends(groups[i], R[i], excl[i]) if temporal else {}
            for slc in R[i]:
                extrap = ends.get(slc, False)
                for pair, r in R[i][slc].items():
                    trends = _time_witnesses(temporal, i, slc, pair) if extrap else []
                    bracketed = len(trends) >= 2
                    if not bracketed:        # not bracketed in time: the index trend
                        nb = [(j, r_j) for j, r_j in by_pair[(slc, pair)] if j != i]
                        index_problems.append((nb, i))
                    lines.append(((i, slc), r, trends if bracketed else None))
        fitted = iter(_index_trends([v for v, _ in index_problems], [i for _, i in index_problems],
                                    0.5 * spacing))
        best: dict[tuple[int, str], float] = {}
        for key, r, witnesses in lines:
            trends = [float(next(fitted))] if witnesses is None else witnesses
            best[key] = min(best.get(key, np.inf), abs(r), *(abs(r - t) for t in trends))
        return {k: v / spacing for k, v in best.items()}

    flagged: dict[tuple[int, str], float] = {}
    while True:
        deps = departures()
        over = {k: v for k, v in deps.items() if v > threshold}
        if not over:
            break
        worst = max(over, key=over.__getitem__)
        flagged[worst] = over[worst]
        excl[worst[0]].add(worst[1])
        R[worst[0]] = loo_residuals(groups[worst[0]], sampled(worst[0]), excl[worst[0]])
    out = [(i, slc, d, False) for (i, slc), d in deps.items()]
    out += [(i, slc, d, True) for (i, slc), d in flagged.items()]
    return out


def _qc_axis(study: Study, long_axis: tuple | None) -> tuple | None:
    if long_axis is not None or not _can_axis(study, None):
        return long_axis
    return study_long_axis(study)


def qc_sections(study: Study, frame: int, long_axis: tuple | None) -> dict[tuple[str, int], list]:
    """Fitted sections of every tag at one frame (no lofting), keyed (family, index).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    long_axis : (apex (3,), base (3,)) or None
        At ED, mm (for the LA spokes).

    Returns
    -------
    dict of (str, int) to list of TagSection
    """
    from cardionurbs.analysis.tag_surfaces import fit_sections, la_sections, sa_sections
    out: dict[tuple[str, int], list] = {}
    for fam in ("sa1", "sa2"):
        groups = sa_sections(study, fam, frame)
        fit_sections([s for g in groups.values() for s in g])
        out.update({(fam, k): g for k, g in groups.items()})
    if study.tags_at(frame, "la") and long_axis is not None:
        groups = la_sections(study, frame, *long_axis)
        fit_sections([s for g in groups.values() for s in g])
        out.update({("la", k): g for k, g in groups.items()})
    return out


#: SA tags whose initial leave-one-out residuals :func:`tag_departures` measures in one batch
_TAGS_PER_BATCH = 160


def tag_departures(study: Study, threshold: float = DEFAULT_THRESHOLD,
                   frames: list[int] | None = None, long_axis: tuple | None = None,
                   surfaces: dict | None = None) -> list[LineDeparture]:
    """Departure of every judgeable tag line, with the iterative worst-first flagging.

    See the module docstring.

    Parameters
    ----------
    study : Study
        A tagged study.
    threshold : float
        Departure (tag spacings) beyond which a line is flagged.
    frames : list of int, optional
        The frames judged (default: every tagged frame).
    long_axis : (apex, base), mm, optional
        Default: from the study's landmarks where it has apex and mitral ones.
    surfaces : dict, optional
        {frame: build_tag_surfaces(...)} whose fitted sections are reused.

    Returns
    -------
    list of LineDeparture
        Per frame (ascending): the SA lines family by family, then the LA lines.
    """
    from cardionurbs.analysis.tag_surfaces import check_tags
    check_tags(study)
    frames = sorted(study.tagged_frames if frames is None else list(frames))
    long_axis = _qc_axis(study, long_axis)
    groups_at: dict[int, dict] = {}
    spacing_at: dict[int, dict] = {}
    for f in frames:
        groups_at[f] = _frame_sections(study, f, long_axis, surfaces)
        spacing_at[f] = {fam: tag_spacing(study, fam, f) for fam in TAG_FAMILIES}
    R0 = _initial_sa_residuals(frames, groups_at)
    out: list[LineDeparture] = []
    for n, f in enumerate(frames):
        near = [frames[m] for m in (n - 1, n + 1) if 0 <= m < len(frames)]
        out += _sa_departures(f, groups_at[f], spacing_at[f], threshold, R0, near)
        out += _la_departures(f, groups_at[f], spacing_at[f], threshold, long_axis)
    return out


def _frame_sections(study: Study, frame: int, long_axis: tuple | None,
                    surfaces: dict | None) -> dict:
    """{(family, index): sections} of a frame's tags: the fitted sections of ``surfaces``
    where it has the frame, else fitted here (:func:`qc_sections`)."""
    if surfaces is not None and frame in surfaces:
        return {k: ts.sections for k, ts in surfaces[frame].items()}
    return qc_sections(study, frame, long_axis)


def _initial_sa_residuals(frames: list[int], groups_at: dict[int, dict]) -> dict:
    """The leave-one-out residuals of every SA tag of every frame with no line left out,
    many frames' tags per batch (a few megabytes of samples each).

    Parameters
    ----------
    frames : list of int
        The frames, ascending.
    groups_at : dict
        Frame -> {(family, index): sections} (:func:`_frame_sections`).

    Returns
    -------
    dict
        (frame, family) -> {index: residuals} for the families sa1 and sa2.
    """
    R0: dict[tuple[int, str], dict] = {key: {} for key in product(frames, ("sa1", "sa2"))}
    sa = [(f, fam, i, secs) for f in frames for (fam, i), secs in groups_at[f].items()
          if fam in ("sa1", "sa2")]
    for start in range(0, len(sa), _TAGS_PER_BATCH):
        part = sa[start:start + _TAGS_PER_BATCH]
        res = loo_residuals_many([(secs, [_samples(s) for s in secs], frozenset())
                                  for _, _, _, secs in part])
        for (f, fam, i, _), r in zip(part, res):
            R0[(f, fam)][i] = r
    return R0


def _usable_spacing(sp: float) -> bool:
    """A tag spacing departures can be measured in (finite and positive)."""
    return bool(np.isfinite(sp) and sp > 0)


def _sa_departures(f: int, groups: dict, spacing: dict, threshold: float, R0: dict,
                   near: list[int]) -> list[LineDeparture]:
    """The departures of frame ``f``'s SA tag lines, family by family
    (:func:`sa_family_departures`, the neighbouring frames ``near`` as references).

    Parameters
    ----------
    f : int
        The frame.
    groups : dict
        {(family, index): sections} of the frame.
    spacing : dict
        Family -> tag spacing at the frame, mm.
    threshold : float
        Departure (tag spacings) beyond which a line is flagged.
    R0 : dict
        The initial residuals (:func:`_initial_sa_residuals`).
    near : list of int
        The frames before and after ``f`` (where there are).

    Returns
    -------
    list of LineDeparture
    """
    out = []
    for fam in ("sa1", "sa2"):
        sp = spacing[fam]
        fam_groups = {i: secs for (g, i), secs in groups.items() if g == fam}
        if not fam_groups or not _usable_spacing(sp):
            continue
        for i, slc, d, fl in sa_family_departures(fam_groups, sp, threshold, R0[(f, fam)],
                                                  [R0[(g, fam)] for g in near]):
            out.append(LineDeparture(fam, i, slc, f, d, fl))
    return out


def _la_departures(f: int, groups: dict, spacing: dict, threshold: float,
                   long_axis: tuple | None) -> list[LineDeparture]:
    """The departures of frame ``f``'s LA tag lines, each tag on its own, its worst line
    flagged and left out again and again while beyond ``threshold``.

    Parameters
    ----------
    f : int
        The frame.
    groups : dict
        {(family, index): sections} of the frame.
    spacing : dict
        Family -> tag spacing at the frame, mm.
    threshold : float
        Departure (tag spacings) beyond which a line is flagged.
    long_axis : tuple or None
        (apex, base), mm.

    Returns
    -------
    list of LineDeparture
        In (family, index) order.
    """
    out = []
    for (fam, idx), secs in sorted(groups.items()):
        sp = spacing[fam]
        if fam != "la" or not _usable_spacing(sp):
            continue
        last, flagged = _worst_first(secs, sp, threshold, long_axis)
        for slc, d in last.items():
            out.append(LineDeparture(fam, idx, slc, f, flagged.get(slc, d), slc in flagged))
    return out


def _worst_first(secs: list, sp: float, threshold: float,
                 long_axis: tuple | None) -> tuple[dict[str, float], dict[str, float]]:
    """Leave-one-out departures of one LA tag's lines, flagging the worst line and leaving it
    out while it departs beyond ``threshold``.

    Parameters
    ----------
    secs : list
        The tag's sections, one per slice.
    sp : float
        Its spacing, mm.
    threshold : float
        Tag spacings.
    long_axis : tuple or None
        (apex, base), mm.

    Returns
    -------
    last : dict
        Slice -> departure in the last pass that measured it (tag spacings).
    flagged : dict
        Slice -> departure when flagged, for the flagged lines.
    """
    samples = [_samples(s) for s in secs]
    flagged: dict[str, float] = {}
    last: dict[str, float] = {}
    profiles: dict[int, tuple] = {}      # each spoke's profile, for every pass
    while True:
        dep = loo_departures(secs, samples, sp, True, exclude=set(flagged),
                             axis=long_axis, profiles=profiles)
        if not dep:
            break
        last.update(dep)
        worst = max(dep, key=lambda k: dep[k])
        if dep[worst] <= threshold:
            break
        flagged[worst] = dep[worst]
    return last, flagged


def _can_axis(study: Study, long_axis) -> bool:
    if long_axis is not None:
        return True
    return bool([lm for lm in study.landmarks if lm.name == "apex"]) and \
        bool([lm for lm in study.landmarks if lm.name == "mitral"])


def tag_qc(study: Study, threshold: float = DEFAULT_THRESHOLD, frames: list[int] | None = None,
           long_axis: tuple | None = None, surfaces: dict | None = None) -> list[TagFlag]:
    """Flag mistracked tag lines ("tag jumping") by leave-one-out lofting.

    Returns one :class:`TagFlag` (family, index, slice, frame, departure in
    tag spacings) per line whose departure from the surface lofted through
    the other slices of its tag exceeds ``threshold`` spacings, sorted by
    frame, family, index, slice.

    Parameters
    ----------
    study : Study
        The study.
    threshold : float
        Tag spacings.
    frames : list of int or None
        The frames judged; None: every tagged frame.
    long_axis : (apex (3,), base (3,)) or None
        At ED, mm; None: from the landmarks.
    surfaces : dict or None
        Frame -> its tag surfaces (:func:`~cardionurbs.analysis.tag_surfaces.build_tag_surfaces`),
        when already built.

    Returns
    -------
    list of TagFlag
    """
    deps = tag_departures(study, threshold, frames, long_axis, surfaces)
    flags = [TagFlag(d.family, d.index, d.slice, d.frame, d.departure) for d in deps if d.flagged]
    seen = {f.as_tuple()[:4] for f in flags}
    flags += [f for f in confidence_flags(study, frames) if f.as_tuple()[:4] not in seen]
    return sorted(flags, key=lambda x: (x.frame, x.family, x.index, x.slice))


#: tracked lines (``study.meta["tag_tracking"]["lines"]``) below this harmonic magnitude
#: (relative to the first frame's) or above this phase residual (rad) are flagged
MIN_MAGNITUDE = 0.15
MAX_PHASE_RESIDUAL = 0.6


def confidence_flags(study: Study, frames: list[int] | None = None) -> list[TagFlag]:
    """Low-confidence tracked lines: the per-line confidence the image tracker
    (:mod:`cardionurbs.tracking`) records — harmonic magnitude over the first frame's
    below :data:`MIN_MAGNITUDE` (faded tags), or RMS phase residual of the line's tracked
    points above :data:`MAX_PHASE_RESIDUAL` rad (points that lost their tag). ``departure``
    is NaN for these flags (they are not measured against the other slices).

    Parameters
    ----------
    study : Study
        A study with ``meta["tag_tracking"]``.
    frames : list of int or None
        The frames; None: all.

    Returns
    -------
    list of TagFlag
    """
    info = study.meta.get("tag_tracking") if isinstance(study.meta, dict) else None
    cols = info.get("lines") if isinstance(info, dict) else None
    if not isinstance(cols, dict) or not cols.get("family"):
        return []
    want = None if frames is None else set(frames)
    out = []
    for fam, idx, slc, fr, mag, res in zip(cols["family"], cols["index"], cols["slice"],
                                           cols["frame"], cols["magnitude"], cols["phase_residual"]):
        if want is not None and fr not in want:
            continue
        low = mag is not None and mag < MIN_MAGNITUDE
        slip = res is not None and res > MAX_PHASE_RESIDUAL
        if low or slip:
            out.append(TagFlag(fam, int(idx), slc, int(fr), float("nan"), "low confidence"))
    return out
