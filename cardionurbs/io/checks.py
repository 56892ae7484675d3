"""Checks a user sees before any model is built: one line per problem.

:func:`check_study` raises :class:`~cardionurbs.errors.StudyError` for the
first fatal problem and returns the list of warnings otherwise. Every message
is one line naming the file, the slice and the frame.

Fatal (StudyError)
    * two images at one (slice, frame); two slices at the same place (duplicate slice);
    * an SA slice not parallel to the stack (> ``MAX_TILT_DEG``);
    * an annotation referring to an image that is not in the study, or to an
      image of another slice / frame;
    * a closed or LV contour with fewer than ``MIN_CONTOUR_POINTS`` points (an open
      RV part may be shorter), a closed contour that crosses itself, a tag
      line with fewer than 2 points;
    * a contour or tag point farther than half the slice thickness (at least
      ``OFF_PLANE_ERROR_MM``) from its image plane;
    * no LV endocardial contour at all, or none at the labelled ED or ES frame;
    * trigger times for some frames but not for others, or frame times that do
      not increase with the frame index.

Warnings
    * points slightly off their plane (> ``OFF_PLANE_WARN_MM``); landmarks off the
      plane of the slice they name, however far (a landmark is a 3-D point);
    * an open contour that crosses itself; an open RV part (CAP ``rv_septum``,
      ``rv_freewall``, ``rv_epi`` guide points) with 1 to 4 points — real CAP
      data has such short septal runs;
    * a gap in the SA stack wider than 1.5 x the median spacing (missing slice?);
    * a slice without an image at some frame that other slices have;
    * a structure present in some frames but missing at ED or ES (labelled, or
      estimated from the summed SA ``lv_endo`` areas when unlabelled);
    * no frame timing or no heart rate at all.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from cardionurbs import limits
from cardionurbs.errors import LimitError, StudyError
from cardionurbs.geometry import polygon_area, stack_normal
from cardionurbs.safe import check_name, excerpt
from cardionurbs.imaging import stack
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.study import Study

MIN_CONTOUR_POINTS = 5
MAX_TILT_DEG = 1.0
OFF_PLANE_WARN_MM = 0.1
OFF_PLANE_ERROR_MM = 1.0
DUPLICATE_SLICE_MM = 0.01
GAP_FACTOR = 1.5


# --------------------------------------------------------------------- geometry
def in_plane_coordinates(points: np.ndarray, plane: ImagePlane | None = None) -> np.ndarray:
    """(n, 2) coordinates of (n, 3) points in the image plane (mm along row and column
    cosines); without a plane, in the best-fit plane (SVD).

    Parameters
    ----------
    points : (n, 3) ndarray
        Scanner points, mm.
    plane : ImagePlane or None
        The image plane; None: the points' best-fit plane.

    Returns
    -------
    (n, 2) ndarray
        mm.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if plane is not None:
        d = p - plane.position
        return np.column_stack([d @ plane.row_cosine, d @ plane.column_cosine])
    c = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    return c @ vt[:2].T


def self_intersections(xy: np.ndarray, closed: bool, first: bool = False) -> np.ndarray:
    """(k, 2) index pairs (i, j) of non-adjacent segments of a 2-D polyline that meet.

    Segment i runs from point i to point i+1 (and the last to the first when
    ``closed``); repeated consecutive points are dropped first, so indices refer
    to the de-duplicated polyline. Two segments meet when each one's end points
    are not strictly on one side of the other's line (orientation-sign
    predicate, with collinear segments tested for overlap) -- crossings and
    touchings both count, since either makes the curve non-simple. With
    ``first`` only the first pair found is returned (what the checks need).

    Cost: curves turning monotonically around their centroid are simple (O(n)
    fast path); otherwise candidate pairs come from a sorted sweep of the
    segments' extents along the best of four directions (0, 45, 90, 135 deg:
    the one with the fewest overlapping extents, counted in O(n log n) by
    binary search before any pair is made), then the exact predicate, in
    vectorised chunks of at most ``_PAIR_CHUNK`` pairs, so memory stays
    O(n + chunk) and time O(n log n + k) for k candidate pairs along that
    direction (measured in reports/limits.md).

    Parameters
    ----------
    xy : (n, 2) ndarray
        The polyline's points (mm or pixels).
    closed : bool
        Whether the last point joins the first.
    first : bool
        Stop at the first pair found.

    Returns
    -------
    (k, 2) ndarray of int
        Index pairs (i, j), i < j, into the de-duplicated polyline.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    keep_pt = np.r_[True, np.any(np.diff(xy, axis=0) != 0, axis=1)]
    xy = xy[keep_pt]
    if closed and len(xy) > 1 and np.array_equal(xy[0], xy[-1]):
        xy = xy[:-1]
    none = np.zeros((0, 2), dtype=int)
    if _angularly_monotone(xy, closed):
        return none
    a = xy if closed else xy[:-1]
    b = np.roll(xy, -1, axis=0) if closed else xy[1:]
    m = len(a)
    if m < 3:
        return none
    scale = max(float(np.ptp(xy, axis=0).max()), 1e-12)
    eps = 1e-12 * scale * scale
    found = []
    for i, j in _overlapping_extents(a, b):
        pair = (j - i >= 2) & ~(closed & (i == 0) & (j == m - 1))
        i, j = i[pair], j[pair]
        hit = _segments_meet(a[i], b[i], a[j], b[j], eps)
        if hit.any():
            found.append(np.column_stack([i[hit], j[hit]]))
            if first:
                return found[0][:1]
    if not found:
        return none
    out = np.concatenate(found)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def _segments_meet(A, B, C, D, eps: float) -> np.ndarray:
    """Whether segments AB and CD (rows) meet: orientation signs, collinear overlap."""
    def side(p, q, r):
        o = (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])
        return np.where(np.abs(o) <= eps, 0, np.sign(o))

    s1, s2, s3, s4 = side(A, B, C), side(A, B, D), side(C, D, A), side(C, D, B)
    meet = (s1 * s2 <= 0) & (s3 * s4 <= 0)
    collinear = (s1 == 0) & (s2 == 0)
    if collinear.any():
        d = B - A
        t = lambda p: np.einsum("ij,ij->i", p - A, d)  # noqa: E731 - projection on AB
        lo, hi = np.minimum(t(C), t(D)), np.maximum(t(C), t(D))
        overlap = (hi >= 0) & (lo <= np.einsum("ij,ij->i", d, d))
        meet = np.where(collinear, overlap, meet)
    return meet


#: polylines of at most this many segments are judged all pairs at once by :func:`known_simple`
_BRUTE_MAX_SEGMENTS = 128
#: segment pairs per vectorised block of :func:`known_simple`
_BRUTE_BLOCK = 1 << 18


def _deduplicated(xy: np.ndarray, closed: bool) -> np.ndarray:
    """The polyline without repeated consecutive points (nor a repeated end point, closed):
    the vertices :func:`self_intersections` numbers its segments by."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    xy = xy[np.r_[True, np.any(np.diff(xy, axis=0) != 0, axis=1)]]
    if closed and len(xy) > 1 and np.array_equal(xy[0], xy[-1]):
        xy = xy[:-1]
    return xy


def _angularly_monotone_many(xy: np.ndarray, closed: bool) -> np.ndarray:
    """:func:`_angularly_monotone` of K polylines of one length at once, xy (K, n, 2)."""
    K, n = xy.shape[:2]
    if n < 3:
        return np.ones(K, dtype=bool)
    d = xy - xy.mean(axis=1, keepdims=True)
    ok = ~np.any(np.hypot(d[..., 0], d[..., 1]) == 0, axis=1)
    ang = np.arctan2(d[..., 1], d[..., 0])
    steps = np.diff(np.concatenate([ang, ang[:, :1]], axis=1) if closed else ang, axis=1)
    steps = (steps + np.pi) % (2 * np.pi) - np.pi
    ok &= (np.all(steps > 0, axis=1) | np.all(steps < 0, axis=1))
    ok &= ~np.any(np.abs(steps) >= np.pi - 1e-9, axis=1)
    total = np.abs(steps.sum(axis=1))
    return ok & ((np.abs(total - 2 * np.pi) < 1e-6) if closed else (total < 2 * np.pi - 1e-9))


def _segment_pairs(m: int, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Every pair (i, j), i < j, of non-adjacent segments of a polyline of m segments."""
    i, j = np.triu_indices(m, 2)
    keep = ~(closed & (i == 0) & (j == m - 1))
    return i[keep], j[keep]


def known_simple(curves: list[np.ndarray], closed: list[bool]) -> np.ndarray:
    """Which 2-D polylines are simple (no two non-adjacent segments meet), judged for all
    of them at once: True where :func:`self_intersections` finds no pair, False where it
    finds one *or* the polyline was not judged here (more than ``_BRUTE_MAX_SEGMENTS``
    segments and not angularly monotone) -- ask :func:`self_intersections` there.

    Polylines of one length and closure are stacked: first the angular fast path of
    :func:`_angularly_monotone`, then for the rest every pair of non-adjacent segments
    whose bounding boxes overlap through the predicate of :func:`_segments_meet` (with
    each curve's own tolerance), in blocks -- what the per-curve sweep does, without a
    numpy call per curve (a study holds hundreds of contours of a few dozen points).

    Parameters
    ----------
    curves : list of (n, 2) ndarray
        2-D polylines.
    closed : list of bool
        Whether each is closed.

    Returns
    -------
    (len(curves),) ndarray of bool
    """
    out = np.zeros(len(curves), dtype=bool)
    dedup = [_deduplicated(c, cl) for c, cl in zip(curves, closed)]
    groups: dict[tuple[int, bool], list[int]] = defaultdict(list)
    for k, (xy, cl) in enumerate(zip(dedup, closed)):
        groups[(len(xy), bool(cl))].append(k)
    for (n, cl), ks in groups.items():
        m = n if cl else n - 1
        if m < 3:                                   # too few segments to cross
            out[ks] = True
            continue
        XY = np.stack([dedup[k] for k in ks])       # (K, n, 2)
        mono = _angularly_monotone_many(XY, cl)
        out[[k for k, s in zip(ks, mono) if s]] = True
        rest = [r for r, s in enumerate(mono) if not s]
        if not rest or m > _BRUTE_MAX_SEGMENTS:
            continue
        XY = XY[rest]
        A = XY if cl else XY[:, :-1]
        B = np.roll(XY, -1, axis=1) if cl else XY[:, 1:]
        scale = np.maximum(np.ptp(XY, axis=1).max(axis=1), 1e-12)
        eps = 1e-12 * scale * scale
        pi, pj = _segment_pairs(m, cl)
        lo, hi = np.minimum(A, B), np.maximum(A, B)
        meets = np.zeros(len(rest), dtype=bool)
        step = max(1, _BRUTE_BLOCK // max(len(pi), 1))
        for s in range(0, len(rest), step):
            r = np.arange(s, min(s + step, len(rest)))
            R = np.repeat(r, len(pi))
            I, J = np.tile(pi, len(r)), np.tile(pj, len(r))
            box = ((lo[R, I, 0] <= hi[R, J, 0]) & (lo[R, J, 0] <= hi[R, I, 0])
                   & (lo[R, I, 1] <= hi[R, J, 1]) & (lo[R, J, 1] <= hi[R, I, 1]))
            R, I, J = R[box], I[box], J[box]
            hit = _segments_meet(A[R, I], B[R, I], A[R, J], B[R, J], eps[R])
            meets[np.unique(R[hit])] = True
        out[[ks[r] for r, bad in zip(rest, meets) if not bad]] = True
    return out


#: candidate segment pairs tested per vectorised chunk (bounds memory: ~100 bytes a pair)
_PAIR_CHUNK = 1 << 20
_SWEEP_DIRECTIONS = np.array([[1.0, 0.0], [np.sqrt(0.5), np.sqrt(0.5)], [0.0, 1.0],
                              [-np.sqrt(0.5), np.sqrt(0.5)]])


def _overlapping_extents(a: np.ndarray, b: np.ndarray):
    """Yield chunks (i, j), i < j, of segment pairs a->b whose extents overlap along the
    sweep direction with the fewest such pairs and whose bounding boxes overlap."""
    m = len(a)
    best: tuple[int, np.ndarray, np.ndarray] | None = None
    for u in _SWEEP_DIRECTIONS:
        pa, pb = a @ u, b @ u
        lo, hi = np.minimum(pa, pb), np.maximum(pa, pb)
        # extents that touch may miss each other by a rounding error of the projection
        # (a point on another segment projects 1e-16 beyond it along a diagonal): widen by
        # a relative 1e-9, which only adds candidates for the exact predicate
        tol = 1e-9 * max(float(np.abs(hi).max()), float(np.abs(lo).max()), 1e-300)
        order = np.argsort(lo, kind="stable")
        end = np.searchsorted(lo[order], hi[order] + tol, side="right")
        counts = np.maximum(end - np.arange(m) - 1, 0)
        total = int(counts.sum())
        if best is None or total < best[0]:
            best = (total, order, counts)
    assert best is not None                     # _SWEEP_DIRECTIONS is not empty
    _, order, counts = best
    blo, bhi = np.minimum(a, b), np.maximum(a, b)
    csum = np.cumsum(counts)
    start = 0
    while start < m:
        stop = int(np.searchsorted(csum, (csum[start - 1] if start else 0) + _PAIR_CHUNK,
                                   side="right"))
        stop = max(stop, start + 1)
        c = counts[start:stop]
        p = np.repeat(np.arange(start, stop), c)
        q = p + 1 + (np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c))
        i, j = order[p], order[q]
        i, j = np.minimum(i, j), np.maximum(i, j)
        keep = ((blo[i, 0] <= bhi[j, 0]) & (blo[j, 0] <= bhi[i, 0])
                & (blo[i, 1] <= bhi[j, 1]) & (blo[j, 1] <= bhi[i, 1]))
        yield i[keep], j[keep]
        start = stop


def _angularly_monotone(xy: np.ndarray, closed: bool) -> bool:
    """Fast sufficient test of simplicity: seen from the centroid, the polar angle of the
    points turns strictly one way, each step by less than pi, in total exactly one turn
    (closed) or less than one turn (open). Each edge then lies in its own angular wedge
    and wedges of non-adjacent edges meet only at the centroid, which no edge reaches."""
    if len(xy) < 3:
        return True
    d = xy - xy.mean(axis=0)
    if np.any(np.hypot(d[:, 0], d[:, 1]) == 0):
        return False
    ang = np.arctan2(d[:, 1], d[:, 0])
    steps = np.diff(np.r_[ang, ang[0]] if closed else ang)
    steps = (steps + np.pi) % (2 * np.pi) - np.pi
    if not (np.all(steps > 0) or np.all(steps < 0)) or np.any(np.abs(steps) >= np.pi - 1e-9):
        return False
    total = abs(float(steps.sum()))
    return abs(total - 2 * np.pi) < 1e-6 if closed else total < 2 * np.pi - 1e-9


# ----------------------------------------------------------------------- checks
def check_study(study: Study) -> list[str]:
    """Check ``study`` (see module docstring): raise StudyError on the first fatal
    problem, else return the warnings, one line each.

    Parameters
    ----------
    study : Study
        A study just read.

    Returns
    -------
    list of str
        The warnings.

    Raises
    ------
    StudyError
        The first fatal problem (naming file, slice, frame and field).
    """
    warnings: list[str] = []
    check_bounds(study)
    planes = _check_images(study, warnings)
    _check_stack(study, planes, warnings)
    _check_annotations(study, warnings)
    _check_frames(study, warnings)
    return warnings


def check_bounds(study: Study) -> None:
    """The documented limits (:mod:`cardionurbs.limits`) and safe names, checked once on
    load: subject, slice, image, structure, tag family and landmark names are printable
    text of at most MAX_NAME_LENGTH characters; at most MAX_IMAGES images, frame indices
    0..MAX_FRAMES-1, MAX_CONTOURS_PER_STUDY contours (and tag lines), MAX_POINTS_PER_CONTOUR
    points per contour or tag line, MAX_POINTS_PER_STUDY points in all. Raises LimitError /
    StudyError naming the file, slice, frame and field.

    Parameters
    ----------
    study : Study
        A study just read.

    Raises
    ------
    LimitError
        A documented limit exceeded.
    StudyError
        A name that is not safe printable text.
    """
    src = study.source
    try:
        check_name(study.subject, "subject")
    except ValueError as exc:
        raise StudyError(str(exc), file=src, field="subject") from None
    if len(study.images) > limits.MAX_IMAGES:
        raise LimitError(f"{len(study.images)} images (limit {limits.MAX_IMAGES})", file=src)
    for what, items in (("contours", study.contours), ("tag lines", study.tags),
                        ("landmarks", study.landmarks)):
        if len(items) > limits.MAX_CONTOURS_PER_STUDY:
            raise LimitError(f"{len(items)} {what} (limit {limits.MAX_CONTOURS_PER_STUDY})",
                             file=src)
    names: dict[str, set] = defaultdict(set)
    frames: set = set()
    total = 0
    for im in study.images:
        names["slice"].add(im.slice)
        names["image id"].add(im.id)
        frames.add(im.frame)
    for ann, field, label in ([(c, "structure", c.structure) for c in study.contours]
                              + [(t, "tag family", t.family) for t in study.tags]):
        names[field].add(label)
        if ann.slice is not None:
            names["slice"].add(ann.slice)
        frames.add(ann.frame)
        n = len(ann.points)
        total += n
        if n > limits.MAX_POINTS_PER_CONTOUR:
            raise LimitError(f"{label} has {n} points (limit {limits.MAX_POINTS_PER_CONTOUR} per "
                             "contour or tag line)", file=src, slice=ann.slice, frame=ann.frame)
    for lm in study.landmarks:
        names["landmark"].add(lm.name)
        frames.add(lm.frame)
    total += len(study.landmarks)
    if total > limits.MAX_POINTS_PER_STUDY:
        raise LimitError(f"{total} points (limit {limits.MAX_POINTS_PER_STUDY})", file=src)
    bad = [f for f in frames if not (0 <= int(f) < limits.MAX_FRAMES)]
    if bad:
        raise LimitError(f"frame index {excerpt(bad[0])} outside 0..{limits.MAX_FRAMES - 1}",
                         file=src, field="frame")
    for field, values in names.items():
        for v in values:
            if field == "slice" and not v:
                continue
            try:
                check_name(v, field)
            except ValueError as exc:
                raise StudyError(str(exc), file=src, field=field) from None


def _src(study: Study, file=None):
    """The file to name in a message: ``file`` (under the study folder) or the study."""
    if file is None:
        return study.source
    if study.source and not Path(str(file)).is_absolute():
        return (Path(study.source) / str(file)).as_posix()
    return file


def _check_images(study: Study, warnings: list[str]) -> dict[str, ImagePlane]:
    """Duplicate images / slices; returns one representative plane per slice."""
    seen: dict[tuple, ImagePlane] = {}
    ids: dict[str, ImagePlane] = {}
    for im in study.images:
        if im.id in ids:
            raise StudyError(f"image id {excerpt(im.id)} is used twice", file=_src(study, im.file),
                             slice=im.slice, frame=im.frame)
        ids[im.id] = im
        key = (im.slice, im.frame)
        if key in seen:
            raise StudyError(f"two images at the same slice and frame ({seen[key].id} and {im.id})",
                             file=_src(study, im.file), slice=im.slice, frame=im.frame)
        seen[key] = im
    planes: dict[str, ImagePlane] = {}
    for im in sorted(study.images, key=lambda im: im.frame):
        planes.setdefault(im.slice, im)
    # duplicate slices: two slice ids with the same plane at one frame
    by_frame: dict[int, list[ImagePlane]] = defaultdict(list)
    for im in study.images:
        by_frame[im.frame].append(im)
    for frame, ims in by_frame.items():
        if len(ims) < 2:
            continue
        normals = np.array([im.normal for im in ims])
        pos = np.array([im.position for im in ims])
        parallel = np.abs(normals @ normals.T) > np.cos(np.deg2rad(0.1))
        depth_gap = np.abs(np.einsum("ij,kj->ik", normals, pos) - np.sum(normals * pos, axis=1)[:, None])
        dup = np.triu(parallel & (depth_gap < DUPLICATE_SLICE_MM), k=1)
        if dup.any():
            i, j = map(int, np.argwhere(dup)[0])
            raise StudyError(f"slices {ims[i].slice} and {ims[j].slice} are at the same position "
                             "(duplicate slice)", file=_src(study, ims[j].file), slice=ims[j].slice,
                             frame=frame)
    # slices lacking an image at a frame other slices of their view have
    frames_by_view: dict[str, set[int]] = defaultdict(set)
    frames_of_slice: dict[str, set[int]] = defaultdict(set)
    view_of: dict[str, str] = {}
    for im in study.images:
        frames_by_view[im.view].add(im.frame)
        frames_of_slice[im.slice].add(im.frame)
        view_of[im.slice] = im.view
    for sl, frs in sorted(frames_of_slice.items()):
        missing = sorted(frames_by_view[view_of[sl]] - frs)
        if missing and len(frs) > 1:
            warnings.append(f"{study.source}: slice {sl}: no image at frame(s) "
                            f"{_short_list(missing)} (missing images?)")
    return planes


def _short_list(values, n: int = 6) -> str:
    v = [str(x) for x in values]
    return ", ".join(v[:n]) + (", ..." if len(v) > n else "")


def _check_stack(study: Study, planes: dict[str, ImagePlane], warnings: list[str]) -> None:
    """SA slices parallel; gaps in the stack."""
    sa = [p for s, p in sorted(planes.items()) if p.view == "SA"]
    if len(sa) < 2:
        return
    normals = np.array([p.normal for p in sa])
    groups = stack.group_parallel(normals, MAX_TILT_DEG)
    main = int(np.bincount(groups).argmax())
    ref = stack_normal(normals[groups == main])
    for p, g in zip(sa, groups):
        if g != main:
            tilt = np.degrees(np.arccos(np.clip(abs(float(p.normal @ ref)), 0, 1)))
            raise StudyError(f"SA slice is not parallel to the stack (tilted {tilt:.2f} deg > "
                             f"{MAX_TILT_DEG} deg)", file=_src(study, p.file), slice=p.slice,
                             frame=p.frame)
    depth = np.array([p.position @ ref for p in sa])
    order = np.argsort(depth)
    gaps = np.diff(depth[order])
    if len(gaps) >= 2:
        med = float(np.median(gaps))
        for k in np.flatnonzero(gaps > GAP_FACTOR * med):
            a, b = sa[order[k]], sa[order[k + 1]]
            warnings.append(f"{study.source}: slice {b.slice}: gap of {gaps[k]:.1f} mm from "
                            f"{a.slice} (median spacing {med:.1f} mm): missing slice?")


def _annotation_files(study: Study) -> list:
    """Source file of each contour where the reader recorded it (else None)."""
    files = study.meta.get("contour_files") if isinstance(study.meta, dict) else None
    if isinstance(files, list) and len(files) == len(study.contours):
        return files
    gp = study.meta.get("gpfile") if isinstance(study.meta, dict) else None
    if isinstance(gp, dict) and isinstance(gp.get("frames"), dict):
        return [gp["frames"].get(str(c.frame), {}).get("file") for c in study.contours]
    if study.meta.get("format") in (None, "cardionurbs-native") and study.source:
        name = "points.csv"                 # a large native study's points file is Parquet
        if not (Path(study.source) / name).is_file() and (Path(study.source) / "points.parquet").is_file():
            name = "points.parquet"
        return [name] * len(study.contours)
    return [None] * len(study.contours)


def _plane_of(study: Study, ann, file) -> ImagePlane | None:
    """The image plane an annotation lies on (its image, else its slice at its frame)."""
    index = study._image_index()
    if ann.image is not None:
        im = index.get(ann.image)
        if im is None:
            raise StudyError(f"reference to image {excerpt(ann.image)} that does not exist in the study",
                             file=_src(study, file), slice=ann.slice, frame=ann.frame, field="image")
        if (ann.slice and im.slice != ann.slice) or im.frame != ann.frame:
            raise StudyError(f"image {excerpt(ann.image)} belongs to slice {im.slice}, frame {im.frame}",
                             file=_src(study, file), slice=ann.slice, frame=ann.frame, field="image")
        return im
    if ann.slice is None:
        return None
    for im in study.images:
        if im.slice == ann.slice and im.frame == ann.frame:
            return im
    return None


class _Normals(dict):
    """Unit normal of each image plane, computed once per plane (keyed by plane id)."""

    def of(self, plane: ImagePlane) -> np.ndarray:
        n = self.get(plane.id)
        if n is None:
            n = self[plane.id] = plane.normal
        return n


def _off_plane(study: Study, plane: ImagePlane, pts: np.ndarray, what: str, file, ann,
               warnings: list[str], normals: _Normals, fatal: bool = True,
               d: float | None = None) -> None:
    """Error (or warning) when points lie off their image plane; ``d``: their largest
    distance from it when already known (:func:`_off_plane_distances`)."""
    if d is None:
        d = float(np.abs((np.asarray(pts, float).reshape(-1, 3) - plane.position)
                         @ normals.of(plane)).max())
    limit = max(OFF_PLANE_ERROR_MM, 0.5 * plane.thickness)
    if d > limit and fatal:
        raise StudyError(f"{what} lies {d:.2f} mm off its image plane (limit {limit:.2f} mm)",
                         file=_src(study, file), slice=ann.slice, frame=ann.frame)
    if d > OFF_PLANE_WARN_MM:
        warnings.append(f"{_src(study, file)}: slice {ann.slice}, frame {ann.frame}: {what} lies "
                        f"up to {d:.2f} mm off its image plane")


def _off_plane_distances(items: list, planes: list[ImagePlane], normals: _Normals) -> np.ndarray:
    """Largest distance (mm) of each item's points from its plane, for all items at once."""
    n = np.array([len(it.points) for it in items])
    P = np.concatenate([np.asarray(it.points, float).reshape(-1, 3) for it in items])
    origin = np.repeat(np.array([p.position for p in planes]), n, axis=0)
    normal = np.repeat(np.array([normals.of(p) for p in planes]), n, axis=0)
    d = np.abs(np.einsum("ij,ij->i", P - origin, normal))
    return np.maximum.reduceat(d, np.r_[0, np.cumsum(n)[:-1]])


def _check_annotations(study: Study, warnings: list[str]) -> None:
    """Check every contour, tag line and landmark against its image plane, in that order.

    Parameters
    ----------
    study : Study
        The study; StudyError (naming file, slice and frame) on its first fatal problem.
    warnings : list of str
        Appended to, one line per warning.
    """
    files = _annotation_files(study)
    normals = _Normals()
    no_plane = _check_contours(study, files, warnings, normals)
    _check_tags(study, warnings, normals)
    _check_landmarks(study, warnings, normals)
    if no_plane:
        warnings.append(f"{study.source}: {no_plane} contour(s) have no image plane to check "
                        "them against")


def _contour_planes(study: Study, files: list) -> tuple[dict, dict, dict]:
    """Every ventricular contour's plane and in-plane points, and which of them are simple,
    judged all at once (:func:`known_simple`), so that the checks contour by contour run the
    exact crossing search only where that batch was not sure.

    Parameters
    ----------
    study : Study
    files : list
        Each contour's source file (:func:`_annotation_files`).

    Returns
    -------
    planes : dict
        Contour number -> ImagePlane or None (contours whose plane raised are left out:
        the error is raised again, in its turn, by :func:`_check_contours`).
    xys : dict
        Contour number -> (n, 2) in-plane coordinates, mm.
    simple : dict
        Contour number -> True where the contour is known not to cross itself.
    """
    planes: dict[int, ImagePlane | None] = {}
    xys: dict[int, np.ndarray] = {}
    for k, (c, file) in enumerate(zip(study.contours, files)):
        if c.ventricular and len(c.points) >= 3:
            try:
                planes[k] = _plane_of(study, c, file)
            except StudyError:
                continue
            xys[k] = in_plane_coordinates(c.points, planes[k])
    order = list(xys)
    simple = dict(zip(order, known_simple([xys[k] for k in order],
                                          [bool(study.contours[k].closed) for k in order])))
    return planes, xys, simple


def _refuse_or_warn(study: Study, c, file, msg: str, fatal: bool, warnings: list[str]) -> None:
    """Raise ``msg`` as a StudyError naming the contour's file, slice and frame when
    ``fatal``, else warn it as a problem of an open contour."""
    if fatal:
        raise StudyError(msg, file=_src(study, file), slice=c.slice, frame=c.frame)
    warnings.append(f"{_src(study, file)}: slice {c.slice}, frame {c.frame}: open {msg}")


def _check_contours(study: Study, files: list, warnings: list[str], normals: _Normals) -> int:
    """Check each contour in order: its plane (every contour), and for the ventricular ones
    its number of points and whether it crosses itself (fatal for closed contours).

    Parameters
    ----------
    study : Study
    files : list
        Each contour's source file (:func:`_annotation_files`).
    warnings : list of str
        Appended to.
    normals : _Normals
        The shared plane-normal cache.

    Returns
    -------
    int
        The number of ventricular contours without an image plane to check them against.
    """
    planes, xys, simple = _contour_planes(study, files)
    no_plane = 0
    for k, (c, file) in enumerate(zip(study.contours, files)):
        what = f"{c.structure} contour" + (f" #{c.index}" if c.index else "")
        if not c.ventricular:  # atrial / venous / extent traces: only their plane is checked
            plane = _plane_of(study, c, file)
            if plane is not None:
                _off_plane(study, plane, c.points, what, file, c, warnings, normals)
            continue
        if len(c.points) < MIN_CONTOUR_POINTS:
            _refuse_or_warn(study, c, file, f"{what} has {len(c.points)} point(s), needs >= "
                            f"{MIN_CONTOUR_POINTS}",
                            bool(c.closed or c.structure in ("lv_endo", "lv_epi")), warnings)
        plane = planes[k] if k in planes else _plane_of(study, c, file)
        if plane is None:
            no_plane += 1
        else:
            _off_plane(study, plane, c.points, what, file, c, warnings, normals)
        if not simple.get(k, False):
            xy = xys[k] if k in xys else in_plane_coordinates(c.points, plane)
            _check_crossing(study, c, file, what, xy, warnings)
    return no_plane


def _check_crossing(study: Study, c, file, what: str, xy: np.ndarray,
                    warnings: list[str]) -> None:
    """Refuse a closed contour that crosses itself (warn for an open one), naming the first
    two segments that cross.

    Parameters
    ----------
    study : Study
    c : Contour
    file
        The contour's source file.
    what : str
        The contour as named in messages.
    xy : (n, 2) float ndarray
        Its in-plane coordinates, mm.
    warnings : list of str
        Appended to.
    """
    cross = self_intersections(xy, c.closed, first=True)
    if len(cross):
        i, j = map(int, cross[0])
        msg = (f"{what} crosses itself (segment {i}-{i + 1} crosses segment "
               f"{j}-{(j + 1) % len(c.points)})")
        _refuse_or_warn(study, c, file, msg, bool(c.closed), warnings)


def _check_tags(study: Study, warnings: list[str], normals: _Normals) -> None:
    """Each tag line needs 2 points and must lie in its image plane; the planes and the
    distances from them are found first, in one batch, then checked line by line.

    Parameters
    ----------
    study : Study
    warnings : list of str
        Appended to.
    normals : _Normals
        The shared plane-normal cache.
    """
    tag_planes: dict[int, ImagePlane | None] = {}
    for k, t in enumerate(study.tags):
        if len(t.points) >= 2:
            try:
                tag_planes[k] = _plane_of(study, t, None)
            except StudyError:              # raised again, in its turn, below
                continue
    placed = {k: p for k, p in tag_planes.items() if p is not None}
    tag_d = dict(zip(placed, _off_plane_distances([study.tags[k] for k in placed],
                                                  list(placed.values()), normals)
                     if placed else []))
    for k, t in enumerate(study.tags):
        what = f"tag {t.family}#{t.index}"
        if len(t.points) < 2:
            raise StudyError(f"{what} has {len(t.points)} point(s), needs >= 2",
                             file=_src(study), slice=t.slice, frame=t.frame)
        plane = tag_planes[k] if k in tag_planes else _plane_of(study, t, None)
        if plane is not None:
            _off_plane(study, plane, t.points, what, None, t, warnings, normals,
                       d=float(tag_d[k]) if k in tag_d else None)


def _check_landmarks(study: Study, warnings: list[str], normals: _Normals) -> None:
    """Warn (never refuse) a landmark off its image plane: a landmark is a 3-D point, its
    slice only where it was picked."""
    for lm in study.landmarks:
        plane = _plane_of(study, lm, None)
        if plane is not None:
            _off_plane(study, plane, lm.point, f"landmark {lm.name}", None, lm, warnings, normals,
                       fatal=False)


def input_ed_es_frames(study: Study) -> tuple[int | None, int | None, str]:
    """ED and ES frames *for the input checks*: the input's labels, else estimated as the
    frames of largest and smallest summed SA ``lv_endo`` area (a volume proxy); and how
    they were found. The metrics use the model's rule instead
    (:func:`cardionurbs.anatomy.model.ed_es_frames`, docs/metrics.md, Frames).

    Parameters
    ----------
    study : Study
        The study.

    Returns
    -------
    ed, es : int or None
        The frames (None without labels or SA ``lv_endo`` contours).
    how : str
        ``labelled``, ``estimated from SA lv_endo areas`` or ``unknown``.
    """
    ed, es = study.ed_frame, study.es_frame
    if ed is not None and es is not None:
        return ed, es, "labelled"
    areas: dict[int, float] = defaultdict(float)
    for c in study.contours:
        if c.structure == "lv_endo" and c.view == "SA" and c.closed:
            areas[c.frame] += polygon_area(c.points)
    if not areas:
        return ed, es, "labelled" if ed is not None or es is not None else "unknown"
    frames = sorted(areas)
    a = np.array([areas[f] for f in frames])
    ed = ed if ed is not None else frames[int(np.argmax(a))]
    es = es if es is not None else frames[int(np.argmin(a))]
    return ed, es, "estimated from SA lv_endo areas"


def _check_frames(study: Study, warnings: list[str]) -> None:
    if not any(c.structure == "lv_endo" for c in study.contours):
        raise StudyError("no LV endocardial (lv_endo) contour in the study: nothing to "
                         "reconstruct", file=study.source)
    ed, es, how = input_ed_es_frames(study)
    present: dict[tuple[str, str], set[int]] = defaultdict(set)
    for c in study.contours:
        present[(c.structure, c.view)].add(c.frame)
    for label, frame in (("ED", ed), ("ES", es)):
        if frame is None:
            continue
        if frame not in present[("lv_endo", "SA")] | present[("lv_endo", "LA")]:
            raise StudyError(f"no lv_endo contour at the {label} frame the input labels",
                             file=study.source, frame=frame)
        for (structure, view), seen in sorted(present.items()):
            if frame not in seen and structure != "lv_endo":
                warnings.append(f"{study.source}: frame {frame}: {structure} ({view}) is missing "
                                f"at {label} ({how}) but present at frame(s) {_short_list(sorted(seen))}")
    frames = sorted({im.frame for im in study.images} | {c.frame for c in study.contours})
    timed = [f for f in frames if f in study.frame_times_ms]
    if timed and len(timed) < len(frames):
        missing = [f for f in frames if f not in study.frame_times_ms]
        raise StudyError(f"frame(s) {_short_list(missing)} have no trigger time while other frames "
                         "do", file=study.source, frame=missing[0], field="TriggerTime")
    if not timed:
        warnings.append(f"{study.source}: no frame timing (TriggerTime): frame times unknown")
    else:
        t = np.array([study.frame_times_ms[f] for f in timed])
        if np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise StudyError(f"frame times do not increase ({t[k]:g} ms then {t[k + 1]:g} ms)",
                             file=study.source, frame=timed[k + 1], field="TriggerTime")
    if study.heart_rate_bpm is None:
        warnings.append(f"{study.source}: no heart rate (HeartRate / NominalInterval): HR and "
                        "cardiac output need --heart-rate")
