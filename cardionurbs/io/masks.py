"""Label masks -> contours: sub-pixel boundaries of one 2-D label image, in pixels.

Boundaries are iso-lines at level 1/2 of the structure's indicator function,
lightly smoothed by a Gaussian of ``sigma`` pixels (marching squares,
:func:`skimage.measure.find_contours`; Lorensen & Cline 1987), so that a
straight edge between two pixel rows lies half-way between their centres and
staircases become smooth. Pixel coordinates follow the image plane: ``(c, r)``
with ``c`` along the first array axis (see :mod:`cardionurbs.io.nifti`).

What a short-axis slice gives (:func:`sa_slice_contours`):

* ``lv_endo`` — the boundary of the LV cavity with its holes filled
  (papillary muscles and trabeculae lie inside the cavity, as the volume
  convention of the metrics requires); largest connected part only;
* ``lv_epi`` — the outer boundary of LV cavity ∪ myocardium (holes filled);
* ``rv_freewall`` + ``rv_septum`` — the RV cavity boundary split where it
  lies on the LV epicardium (the septum) and where it does not (the free
  wall), the open parts CAP guide points give; a closed ``rv_endo`` when the
  RV does not touch the LV, or touches it along more than one run;
* ``rv_epi`` — the outer boundary of RV cavity ∪ RV myocardium, where the
  convention has an RV wall.

What is left out, with a reason (``skipped``): extra islands (the largest
connected part is kept), an LV cavity that the myocardium does not ring (see
below), loops under ``MIN_AREA_PX`` pixels (beyond the apex). An LV cavity ringed
over less than ``MIN_RING_FRACTION`` of its boundary — a basal slice where
the wall opens to the LV outflow tract or the mitral orifice — is kept, with
a note, when the myocardium faces at least ``MIN_OPEN_RING_FRACTION`` of its
boundary and ``MIN_ENCLOSED_FRACTION`` of the cavity lies inside the convex
hull of the myocardium it borders (:func:`enclosed_fraction`; a blob lying
against the outside of the wall has next to none there): its contour runs
along the labels' edge across the opening, so the section holds the cavity the
labels (and voxel counting) hold there, and dropping it would lose a slab.

Long-axis slices (:func:`la_slice_contours`) give open contours: the part of
the LV cavity boundary that faces the myocardium (``lv_endo``), the part of
the LV epicardium not facing the cavity (``lv_epi``), and, where the atria
are labelled, the RV cavity boundary not facing the right atrium; the ends
of the LV endocardium are the mitral annulus and those of the RV endocardium
the tricuspid annulus. A boundary point counts as facing the myocardium when
myocardium lies within one pixel of the point just outside it, so that the
open contour runs up to the valve plane (the corner where the wall ends).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.measure import find_contours
from skimage.morphology import convex_hull_image

from cardionurbs.geometry import polygon_area
from cardionurbs.io.labels import LabelRoles

SIGMA_PX = 0.5            # Gaussian smoothing of the indicator, pixels
MIN_AREA_PX = 3.0         # smaller loops are noise or the apical tip
MIN_RING_FRACTION = 0.6   # share of the LV cavity boundary that must face myocardium
MIN_OPEN_RING_FRACTION = 0.1  # an open basal cavity: the share that must face myocardium
MIN_ENCLOSED_FRACTION = 0.25  # ... and of it inside the hull of the wall it borders
MIN_SEPTUM_PX = 3         # septal runs shorter than this (boundary points) are free wall
GAP_PX = 4                # free-wall gaps shorter than this within the septum are septum


@dataclass
class SliceContours:
    """Contours of one 2-D label image, pixel coordinates (c, r).

    Attributes
    ----------
    closed : dict of str to (n, 2) ndarray
        Structure -> its closed loop (first point not repeated), pixels (c, r).
    open : dict of str to list of (n, 2) ndarray
        Structure -> its open traces (RV septum and free wall, LA contours), pixels.
    landmarks : dict of str to (k, 2) ndarray
        Landmark name -> its points, pixels.
    skipped : list of str
        Structures present in the labels but not contoured (too small, not a ring).
    notes : list of str
        One-line notes on what was left out and why.
    """

    closed: dict[str, np.ndarray] = field(default_factory=dict)
    open: dict[str, list[np.ndarray]] = field(default_factory=dict)
    landmarks: dict[str, np.ndarray] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def largest_component(mask: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(largest 8-connected part, number of other parts, their pixels).

    Parameters
    ----------
    mask : (H, W) ndarray of bool
        A binary image.

    Returns
    -------
    part : (H, W) ndarray of bool
        Its largest 8-connected component.
    others : int
        The number of other components.
    other_pixels : int
        Their pixel count.
    """
    lab, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n <= 1:
        return mask, 0, 0
    sizes = np.bincount(lab.ravel())[1:]
    k = int(np.argmax(sizes)) + 1
    return lab == k, n - 1, int(sizes.sum() - sizes[k - 1])


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask with its holes filled: background pixels not 4-connected to the image
    border become foreground (what :func:`scipy.ndimage.binary_fill_holes` does, by one
    labelling pass instead of an iterated dilation).

    Parameters
    ----------
    mask : (H, W) ndarray of bool
        A binary image.

    Returns
    -------
    (H, W) ndarray of bool
    """
    bg, n = ndimage.label(~mask)
    if n == 0:
        return mask.copy()
    edge = np.unique(np.concatenate([bg[0], bg[-1], bg[:, 0], bg[:, -1]]))
    outside = np.zeros(n + 1, bool)
    outside[edge] = True
    outside[0] = False
    return ~outside[bg]


def _bbox(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, last) indices of the True pixels along each axis of a non-empty 2-D mask."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return np.array([rows[0], cols[0]]), np.array([rows[-1], cols[-1]])


def boundary_loop(mask: np.ndarray, sigma: float = SIGMA_PX) -> np.ndarray | None:
    """The outer boundary of a binary mask as one closed (n, 2) loop in pixels (c, r),
    first point not repeated; None when the mask is empty or smaller than MIN_AREA_PX.

    Parameters
    ----------
    mask : (H, W) ndarray of bool
        A binary image.
    sigma : float
        Gaussian smoothing of the mask before the iso-contour is traced, pixels.

    Returns
    -------
    (n, 2) ndarray of float or None
        The loop, pixels (c, r).
    """
    if mask.sum() < MIN_AREA_PX:
        return None
    first, last = _bbox(mask)
    lo = np.maximum(first - 3, 0)
    hi = np.minimum(last + 4, mask.shape)
    crop = np.zeros(tuple(hi - lo + 2), float)           # one background pixel all round
    crop[1:-1, 1:-1] = mask[lo[0]:hi[0], lo[1]:hi[1]]
    f = ndimage.gaussian_filter(crop, sigma) if sigma > 0 else crop
    loops = [c for c in find_contours(f, 0.5)
             if len(c) >= 4 and np.all(np.abs(c[0] - c[-1]) <= 1e-8 + 1e-5 * np.abs(c[-1]))]
    if not loops:
        return None
    areas = [abs(_area(c)) for c in loops]
    k = int(np.argmax(areas))
    if areas[k] < MIN_AREA_PX:
        return None
    return loops[k][:-1] + (lo - 1)


def _area(xy: np.ndarray) -> float:
    """Signed shoelace area (pixels², positive counter-clockwise in (c, r))."""
    return polygon_area(xy, signed=True)


def outside_labels(loop: np.ndarray, labels: np.ndarray, push_px: float = 0.75) -> np.ndarray:
    """Label of the pixel just outside each point of a closed loop (pushed along the
    outward normal by ``push_px``; the loop encloses its mask).

    Parameters
    ----------
    loop : (n, 2) ndarray of float
        A closed loop, pixels (c, r).
    labels : (H, W) ndarray of int
        The label image.
    push_px : float
        How far outside each point is looked at, pixels.

    Returns
    -------
    (n,) ndarray of int
        The label there (0 outside the image).
    """
    p = np.asarray(loop, float)
    t = np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)
    nrm = np.column_stack([t[:, 1], -t[:, 0]])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    if _area(p) < 0:                                    # clockwise: flip to point outwards
        nrm = -nrm
    q = np.rint(p + push_px * nrm).astype(int)
    q[:, 0] = np.clip(q[:, 0], 0, labels.shape[0] - 1)
    q[:, 1] = np.clip(q[:, 1], 0, labels.shape[1] - 1)
    return labels[q[:, 0], q[:, 1]]


def _close_gaps(flag: np.ndarray, gap: int) -> np.ndarray:
    """Cyclic boolean run cleanup: False runs shorter than ``gap`` between True runs become True."""
    n = len(flag)
    if flag.all() or not flag.any():
        return flag
    start = int(np.argmax(~flag & np.roll(flag, 1)))    # first False after a True
    f = np.roll(flag, -start).copy()
    runs = _runs(f)
    for a, b, v in runs:
        if not v and b - a < gap:
            f[a:b] = True
    return np.roll(f, start)


def _runs(f: np.ndarray) -> list[tuple[int, int, bool]]:
    """(start, stop, value) of the runs of a 1-D boolean array (not cyclic)."""
    edges = np.flatnonzero(np.diff(f.astype(np.int8))) + 1
    bounds = np.r_[0, edges, len(f)]
    return [(int(a), int(b), bool(f[a])) for a, b in zip(bounds[:-1], bounds[1:])]


def cyclic_runs(flag: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the cyclic True runs of a boolean array (a run may wrap).

    Parameters
    ----------
    flag : (n,) ndarray of bool
        Flags along a closed loop.

    Returns
    -------
    list of ndarray of int
        The indices of each run, in loop order (a wrapping run continues past n - 1 at 0).
    """
    if flag.all():
        return [np.arange(len(flag))]
    if not flag.any():
        return []
    start = int(np.argmax(~flag))                       # rotate so index 0 is False
    f = np.roll(flag, -start)
    return [(np.arange(a, b) + start) % len(flag) for a, b, v in _runs(f) if v]


def _cropped(fn):
    """Run a slice-contour function on the bounding box of the labels (plus a margin), and
    shift its pixel coordinates back: the heart fills a small part of the field of view."""
    def wrapper(labels: np.ndarray, roles: LabelRoles, sigma: float = SIGMA_PX) -> SliceContours:
        if not labels.any():
            return SliceContours()
        first, last = _bbox(labels)
        margin = int(np.ceil(4 * sigma)) + 4
        lo = np.maximum(first - margin, 0)
        hi = np.minimum(last + margin + 1, labels.shape)
        out = fn(labels[lo[0]:hi[0], lo[1]:hi[1]], roles, sigma)
        out.closed = {k: v + lo for k, v in out.closed.items()}
        out.open = {k: [v + lo for v in parts] for k, parts in out.open.items()}
        out.landmarks = {k: v + lo for k, v in out.landmarks.items()}
        return out
    wrapper.__doc__, wrapper.__name__ = fn.__doc__, fn.__name__
    return wrapper


@_cropped
def sa_slice_contours(labels: np.ndarray, roles: LabelRoles, sigma: float = SIGMA_PX) -> SliceContours:
    """Contours of one short-axis label image (see the module docstring).

    Parameters
    ----------
    labels : (H, W) ndarray of int
        One short-axis label image.
    roles : LabelRoles
        Which label value is LV cavity, myocardium, RV (:mod:`cardionurbs.io.labels`).
    sigma : float
        Smoothing of each mask before its boundary is traced, pixels (:func:`boundary_loop`).

    Returns
    -------
    SliceContours
    """
    out = SliceContours()
    lv = labels == roles.lv
    myo = labels == roles.myo
    if lv.any():
        lv, n_isl, px = largest_component(lv)
        if n_isl:
            out.notes.append(f"LV cavity: {n_isl} island(s) of {px} pixel(s) left out")
        lv = fill_holes(lv)
    wall = lv | myo
    if wall.any():
        wall, n_isl, px = largest_component(wall)
        if n_isl:
            out.notes.append(f"LV myocardium: {n_isl} island(s) of {px} pixel(s) left out")
        wall = fill_holes(wall)
        lv &= wall
    endo = boundary_loop(lv, sigma) if lv.any() else None
    if endo is not None and not _lv_cavity_kept(endo, lv, myo, labels, roles, out):
        endo = None
    elif endo is None and lv.any():
        out.skipped.append("LV cavity smaller than the smallest contour: left out (apex?)")
    if endo is not None:
        out.closed["lv_endo"] = endo
    epi = boundary_loop(wall, sigma) if myo.any() else None
    if epi is not None:
        out.closed["lv_epi"] = epi
    if roles.rv is not None:
        _rv_contours(labels, roles, wall, sigma, out)
    return out


def _lv_cavity_kept(endo: np.ndarray, lv: np.ndarray, myo: np.ndarray, labels: np.ndarray,
                    roles: LabelRoles, out: SliceContours) -> bool:
    """Whether an SA slice's LV cavity is the LV's (its reason in ``out`` when not, a note
    when it is kept open): ringed by myocardium over MIN_RING_FRACTION of its boundary, or
    — a basal slice where the wall opens to the LV outflow or the mitral orifice — over
    MIN_OPEN_RING_FRACTION with MIN_ENCLOSED_FRACTION of it inside the wall it borders."""
    outside = outside_labels(endo, labels)
    ring = float(np.mean((outside == roles.myo) | (outside == roles.lv)))
    if not myo.any():
        out.skipped.append("LV cavity without myocardium: left out")
        return False
    if ring >= MIN_RING_FRACTION:
        return True
    inside = enclosed_fraction(lv, myo) if ring >= MIN_OPEN_RING_FRACTION else 0.0
    if inside < MIN_ENCLOSED_FRACTION:
        out.skipped.append(f"LV cavity not ringed by myocardium ({ring:.0%} of its boundary, "
                           f"{inside:.0%} of it within the wall it touches: not the LV's "
                           "cavity?): lv_endo left out")
        return False
    out.notes.append(f"LV cavity ringed by myocardium over {ring:.0%} of its boundary (open "
                     "to the outflow tract or the atrium): kept as an open basal section, "
                     "bounded by the labels across the opening")
    return True


def enclosed_fraction(lv: np.ndarray, myo: np.ndarray) -> float:
    """Share of an LV cavity mask inside the convex hull of the myocardium pixels bordering
    it: near 1 for a cavity the wall wraps (also where it opens over half its border, 0.5
    and more), near 0 for a blob lying against the outside of the wall.

    Parameters
    ----------
    lv : (H, W) ndarray of bool
        The LV cavity mask (non-empty).
    myo : (H, W) ndarray of bool
        The myocardium mask.

    Returns
    -------
    float
        In [0, 1]; 0 when fewer than three myocardium pixels border the cavity.
    """
    face = ndimage.binary_dilation(lv) & ~lv & myo
    if np.count_nonzero(face) < 3:
        return 0.0
    hull = convex_hull_image(face)
    return float(np.count_nonzero(lv & hull)) / max(int(np.count_nonzero(lv)), 1)


def _rv_contours(labels, roles: LabelRoles, wall: np.ndarray, sigma: float, out: SliceContours) -> None:
    rv = labels == roles.rv
    if not rv.any():
        return
    rv, n_isl, px = largest_component(rv)
    if n_isl:
        out.notes.append(f"RV cavity: {n_isl} island(s) of {px} pixel(s) left out")
    rv = fill_holes(rv) & ~wall
    loop = boundary_loop(rv, sigma)
    if loop is None:
        out.skipped.append("RV cavity smaller than the smallest contour: left out")
        return
    lab = np.where(wall, roles.myo, labels)
    on_lv = outside_labels(loop, lab) == roles.myo
    on_lv = _close_gaps(on_lv, GAP_PX)
    runs = [r for r in cyclic_runs(on_lv) if len(r) >= MIN_SEPTUM_PX]
    if len(runs) == 1 and len(runs[0]) < len(loop) - MIN_SEPTUM_PX:
        sept = runs[0]
        start = (sept[-1] + 1) % len(loop)                # free wall runs from the septum's end
        free = (start + np.arange(len(loop) - len(sept))) % len(loop)
        # each part carries its junction points so the joined loop has no gap
        out.open["rv_freewall"] = [loop[np.r_[sept[-1], free, sept[0]]]]
        out.open["rv_septum"] = [loop[sept]]
    else:
        out.closed["rv_endo"] = loop
    if roles.rv_myo is not None and (labels == roles.rv_myo).any():
        rvw, _, _ = largest_component((labels == roles.rv_myo) | rv)
        rvw = fill_holes(rvw) & ~wall
        epi = boundary_loop(rvw, sigma)
        if epi is not None:
            out.closed["rv_epi"] = epi


def _near(mask: np.ndarray) -> np.ndarray:
    """uint8 mask of the pixels within one pixel (8-neighbourhood) of ``mask``: a boundary
    point counts as facing a structure up to the corner where the structure ends, so the
    open contour reaches the valve plane instead of stopping a pixel short of it."""
    return ndimage.binary_dilation(mask, structure=np.ones((3, 3), bool)).astype(np.uint8)


def _open_part(loop: np.ndarray, keep: np.ndarray) -> np.ndarray | None:
    """The longest cyclic run of ``keep`` along a closed loop, as an open polyline."""
    runs = cyclic_runs(_close_gaps(keep, GAP_PX))
    if not runs:
        return None
    run = max(runs, key=len)
    if len(run) == len(loop):
        return None                                     # no opening: not a long-axis cavity
    return loop[run]


@_cropped
def la_slice_contours(labels: np.ndarray, roles: LabelRoles, sigma: float = SIGMA_PX) -> SliceContours:
    """Open contours of one long-axis label image (see the module docstring).

    Parameters
    ----------
    labels : (H, W) ndarray of int
        One long-axis label image.
    roles : LabelRoles
        Which label value is LV cavity, myocardium, RV (:mod:`cardionurbs.io.labels`).
    sigma : float
        Smoothing of each mask before its boundary is traced, pixels (:func:`boundary_loop`).

    Returns
    -------
    SliceContours
    """
    out = SliceContours()
    lv, myo = labels == roles.lv, labels == roles.myo
    if not (lv.any() and myo.any()):
        if lv.any() or myo.any():
            out.skipped.append("long-axis view without both LV cavity and myocardium: left out")
        return out
    lv, _, _ = largest_component(lv)
    lv = fill_holes(lv)
    wall, _, _ = largest_component(lv | myo)
    loop = boundary_loop(lv, sigma)
    if loop is not None:
        endo = _open_part(loop, outside_labels(loop, _near(myo)) > 0)
        if endo is not None and len(endo) >= 5:
            out.open["lv_endo"] = [endo]
            out.landmarks["mitral"] = endo[[0, -1]]
    loop = boundary_loop(wall, sigma)
    if loop is not None:
        # the epicardium is the part of the wall's boundary where myocardium lies inside
        inside = outside_labels(loop, labels, push_px=-0.75)
        epi = _open_part(loop, inside == roles.myo)
        if epi is not None and len(epi) >= 5:
            out.open["lv_epi"] = [epi]
    if roles.rv is not None and roles.ra is not None and (labels == roles.ra).any():
        rv, _, _ = largest_component(labels == roles.rv)
        loop = boundary_loop(rv, sigma)
        if loop is not None:
            endo = _open_part(loop, outside_labels(loop, _near(~((labels == roles.ra) | rv))) > 0)
            if endo is not None and len(endo) >= 5:
                out.open["rv_endo"] = [endo]
                out.landmarks["tricuspid"] = endo[[0, -1]]
    return out


def ring_fraction(lv: np.ndarray, myo: np.ndarray) -> float:
    """Share of the pixels bordering an LV cavity mask (4-neighbours outside it) that are
    myocardium: 1 for a cavity ringed all round, low for one open to the outflow tract or
    the atrium. NaN without a cavity.

    Parameters
    ----------
    lv : (H, W) ndarray of bool
        The LV cavity mask.
    myo : (H, W) ndarray of bool
        The myocardium mask.

    Returns
    -------
    float
        In [0, 1], or NaN.
    """
    if not lv.any():
        return float("nan")
    border = ndimage.binary_dilation(lv) & ~lv
    return float(np.count_nonzero(border & myo)) / max(int(np.count_nonzero(border)), 1)


@dataclass
class StackAnatomy:
    """What the labels of an SA stack show about its base and apex, per slice k (the
    inputs of :func:`cardionurbs.imaging.stack.base_end_from_anatomy`).

    ``lv``, ``myo``, ``rv``: (k,) label areas in pixels summed over the frames; ``cap`` and
    ``outflow``: whether the first / last labelled slice of some frame shows myocardium
    without cavity (and less of it than the other end slice's LV holds), or a cavity not
    ringed by myocardium (ring < MIN_RING_FRACTION).

    Attributes
    ----------
    lv, myo : (k,) ndarray of float
        LV cavity and myocardium label areas per slice, pixels summed over the frames.
    rv : (k,) ndarray of float or None
        The RV's, None without an RV label.
    cap : (bool, bool)
        Whether the first / last labelled slice shows myocardium without cavity (an apical cap).
    outflow : (bool, bool)
        Whether the first / last labelled slice shows a cavity not ringed by myocardium
        (ring < :data:`MIN_RING_FRACTION`: an outflow tract or the atrium).
    """

    lv: np.ndarray
    myo: np.ndarray
    rv: np.ndarray | None
    cap: tuple[bool, bool]
    outflow: tuple[bool, bool]


def stack_anatomy(data: np.ndarray, roles: LabelRoles, frames) -> StackAnatomy:
    """:class:`StackAnatomy` of a (x, y, k, t) label array at the volume frames ``frames``.

    Parameters
    ----------
    data : (x, y, k, t) ndarray of int
        The SA label volume over time.
    roles : LabelRoles
        Which label value is LV cavity, myocardium, RV.
    frames : iterable of int
        The volume frames to sum over (ED and ES).

    Returns
    -------
    StackAnatomy
    """
    nk = data.shape[2]
    lv, myo, rv = np.zeros(nk), np.zeros(nk), np.zeros(nk)
    cap, outflow = [False, False], [False, False]
    for t in frames:
        d = data[..., t]
        lvm, myom = d == roles.lv, d == roles.myo
        a_lv, a_myo = lvm.sum(axis=(0, 1)), myom.sum(axis=(0, 1))
        lv += a_lv
        myo += a_myo
        if roles.rv is not None:
            rv += (d == roles.rv).sum(axis=(0, 1))
        held = np.flatnonzero((a_lv + a_myo) > 0)
        if len(held) < 2:
            continue
        ends = (held[0], held[-1])
        for end, k in enumerate(ends):
            # a wall closing over the apex is the narrower end (a basal slice through the
            # annulus at ES can show myocardium alone, as a wide ring)
            other = ends[1 - end]
            cap[end] |= bool(a_myo[k] > 0 and a_lv[k] == 0
                             and a_myo[k] < a_lv[other] + a_myo[other])
            if a_lv[k] > 0 and a_myo[k] > 0:
                outflow[end] |= ring_fraction(fill_holes(lvm[:, :, k]), myom[:, :, k]) \
                    < MIN_RING_FRACTION
    return StackAnatomy(lv, myo, rv if roles.rv is not None else None,
                        (cap[0], cap[1]), (outflow[0], outflow[1]))
