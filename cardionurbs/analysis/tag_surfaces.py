"""Tag surfaces: tracked tag lines fitted as curves and lofted across slices.

Paper §3.2 (curve approximation, eqs. 6–10) and §4.2.3 (tag surface
reconstruction): every tracked tag line (one tag (family, index) in one image
at one frame, scanner mm) is approximated by a degree-3 NURBS curve, and the
curves of one tag at one frame are lofted (§3.2.4) into a tag surface.

Families and how they are lofted
--------------------------------
``sa1``, ``sa2``
    Tag planes parallel to the long axis, seen as lines in the short-axis
    (SA) stack. The lines of one tag are ordered along the stack normal
    (base → apex, the order of ``sa_00, sa_01, ...``) and lofted across the
    stack: ``u`` runs along the tag line, ``v`` across the slices.
``la``
    Tag planes perpendicular to the long axis, seen as lines in the long-axis
    (LA) views. The views (2-, 3-, 4-chamber) are half-planes pairs at
    different angles around the long axis, so one LA tag line crosses the
    axis once. **Decision**: each LA line is cut where it crosses the long
    axis (at the middle of its cavity gap when it has one, else at its point
    nearest the axis) into two *spokes* running from the axis outward; the
    spokes of all views are ordered by their angle about the long axis and
    lofted *around* it, the first spoke repeated at the end so that the
    surface closes (``u`` radial, ``v`` angular, ``v = 0`` and ``v = 1`` on
    the same spoke). Three LA views give six spokes 60° apart on average:
    enough for a cubic loft that follows a tilted or dished plane. A lofted
    spoke fan stays inside the plane when the lines are coplanar (lofting is
    an affine combination of control points), so at ED the surface is the
    tag plane itself.

Every line is oriented before lofting (SA: along the family's mean
direction; LA spokes: outward) so that the sections' ``u`` directions agree.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from cardionurbs import nurbs
from cardionurbs.anatomy.sections import stacking_direction, study_long_axis
from cardionurbs.cache import attached
from cardionurbs.errors import TagError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.nurbs.loft import loft_compatible  # noqa: F401  (old import path, benchmarks)
from cardionurbs.study import TAG_FAMILIES, Study, TagLine
from cardionurbs.median import median

#: the image view each tag family is seen in
FAMILY_VIEW = {"sa1": "SA", "sa2": "SA", "la": "LA"}
#: a step between consecutive points longer than this many times the line's
#: median step, and longer than ``GAP_MIN_MM``, is a gap (the line crosses a
#: cavity); tracking noise of a pixel or so never makes one
GAP_FACTOR = 4.0
GAP_MIN_MM = 5.0


# ----------------------------------------------------------------- validation
def check_tags(study: Study, ed_frame: int | None = None) -> None:
    """Raise :class:`TagError` (one line naming it) on bad tag input.

    Checks: every family is ``sa1``/``sa2``/``la`` and seen in its view; every
    line has >= 2 points; no (family, index) appears twice in one slice at
    one frame; and, when tags exist and ``ed_frame`` is given, that the ED
    frame is tagged. The lines are checked once per ``study.tags`` list (again when the
    list is replaced or changes length, as for the study's tag index): the analysis asks
    at every stage.

    Parameters
    ----------
    study : Study
        The study.
    ed_frame : int or None
        The ED frame, checked to be tagged.

    Raises
    ------
    TagError
        The first problem, naming family, index, slice and frame.
    """
    attached(study, "_tags_checked", _check_tag_lines, depends=("tags",))()
    if ed_frame is not None and study.tags and not any(t.frame == ed_frame for t in study.tags):
        raise TagError(f"tag lines exist (frames {study.tagged_frames}) but none at the ED frame "
                       f"{ed_frame}", field="ed_frame")


def _check_tag_lines(study: Study) -> None:
    """The per-line checks of :func:`check_tags` (TagError on the first bad line)."""
    seen: set[tuple] = set()
    for t in study.tags:
        where = dict(slice=t.slice, frame=t.frame)
        if t.family not in TAG_FAMILIES:
            raise TagError(f"unknown tag family {t.family!r} (tag index {t.index}); expected one of "
                           f"{', '.join(TAG_FAMILIES)}", field="family", **where)
        if t.view != FAMILY_VIEW[t.family]:
            raise TagError(f"tag {t.family}#{t.index} is in a {t.view} view; family {t.family} is "
                           f"seen in {FAMILY_VIEW[t.family]} views", field="view", **where)
        pts = np.asarray(t.points)
        if pts.ndim != 2 or len(pts) < 2:
            raise TagError(f"tag {t.family}#{t.index} has {len(pts)} point(s), needs >= 2",
                           field="points", **where)
        key = (t.family, t.index, t.slice, t.frame)
        if key in seen:
            raise TagError(f"tag {t.family}#{t.index} appears twice in this slice",
                           field="index", **where)
        seen.add(key)


def resolve_frames(study: Study, ed_frame: int | None, es_frame: int | None) -> tuple[int, int]:
    """ED and ES frames: the arguments, else the study's labels; TagError when unknown.

    Parameters
    ----------
    study : Study
        The study.
    ed_frame, es_frame : int or None
        The frames asked for; None: the study's labels.

    Returns
    -------
    (int, int)
        ED and ES.

    Raises
    ------
    TagError
        A frame neither given nor labelled.
    """
    ed = study.ed_frame if ed_frame is None else int(ed_frame)
    es = study.es_frame if es_frame is None else int(es_frame)
    if ed is None:
        raise TagError(f"tag lines exist (frames {study.tagged_frames}) but no ED frame is "
                       "given or labelled", field="ed_frame")
    check_tags(study, ed)
    if es is None:
        raise TagError("no ES frame is given or labelled for tag tracking", field="es_frame")
    return ed, es


# --------------------------------------------------------------- line helpers
def gap_limit(points: np.ndarray) -> float:
    """Step length (mm) above which consecutive points of a line are across a gap.

    Parameters
    ----------
    points : (n, 3) ndarray
        A tag line's points, mm.

    Returns
    -------
    float
        mm.
    """
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    if len(steps) < 2:
        return np.inf
    return max(GAP_FACTOR * median(steps), GAP_MIN_MM)


def uniform_knots(n_ctrl: int, degree: int = 3) -> np.ndarray:
    """Clamped knot vector on [0, 1] with uniformly spaced interior knots.

    Parameters
    ----------
    n_ctrl : int
        Control points.
    degree : int
        Curve degree p.

    Returns
    -------
    (n_ctrl + p + 1,) ndarray
    """
    inner = np.arange(1, n_ctrl - degree) / (n_ctrl - degree)
    return np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])


def control_count(lines: list[np.ndarray]) -> int:
    """Control points for a family's tag lines: one per ~12 mm of the median line, 4..8.

    Parameters
    ----------
    lines : list of (n, 3) ndarray
        The family's tag lines, mm.

    Returns
    -------
    int
    """
    lengths = polyline_lengths(lines)
    return int(np.clip(round(median(lengths) / 12.0) + 3, 4, 8))


def polyline_lengths(lines: list[np.ndarray]) -> np.ndarray:
    """Length (mm) of each polyline (sum of its steps), all lines in one batch.

    Parameters
    ----------
    lines : list of (n, 3) ndarray
        Polylines, mm.

    Returns
    -------
    (L,) ndarray
        mm.
    """
    n = np.array([len(p) for p in lines])
    if len(lines) == 0:
        return np.zeros(0)
    Q = np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in lines])
    steps = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    steps = np.r_[steps, 0.0]
    ends = np.cumsum(n) - 1
    steps[ends[n > 0]] = 0.0                       # no step from one line to the next
    starts = np.r_[0, np.cumsum(n)[:-1]]
    out = np.zeros(len(lines))
    nz = n > 0
    out[nz] = np.add.reduceat(steps, starts[nz])
    return out


def fit_tag_curves(lines: list[np.ndarray], n_ctrl: int, degree: int = 3,
                   smoothing: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares degree-3 curves through many tag lines at once (paper §3.2, eqs. 6–10).

    Every line gets chord-length parameters (eqs. 6–8), end control points
    on its end points (P_0 = Q_0, P_n = Q_m) and the interior control points
    by least squares (eq. 10), all lines solved together. Two departures
    from the paper, both for lofting: the knots are uniform in the
    chord-length parameter (every section of a tag then shares one knot
    vector, so lofting needs no knot insertion), and a tiny second-difference
    penalty (``smoothing`` × the mean diagonal of NᵀN) keeps the system
    regular where a cavity gap leaves a control point without data (the
    curve bridges the gap smoothly) or where a line has fewer points than
    control points. The number of control points is fixed (not a
    tolerance), so tracking noise is smoothed rather than interpolated.

    Returns (knots (n + p + 1,), control points (L, n, 3)).

    Parameters
    ----------
    lines : list of (m, 3) ndarray
        L tag lines, mm.
    n_ctrl : int
        Control points per curve.
    degree : int
        Curve degree p.
    smoothing : float
        The second-difference penalty's relative weight.

    Returns
    -------
    knots : (n + p + 1,) ndarray
        The shared knot vector.
    ctrl : (L, n, 3) ndarray
        The control points of each line's curve, mm.
    """
    from cardionurbs.nurbs.basis import basis_matrix
    U = uniform_knots(n_ctrl, degree)
    L = len(lines)
    m = np.array([len(q) for q in lines])
    Q = np.vstack(lines)
    starts = np.r_[0, np.cumsum(m)[:-1]]
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    seg = np.r_[0.0, seg]
    seg[starts] = 0.0                                    # no chord between two lines
    cum = np.cumsum(seg)
    cum -= np.repeat(cum[starts], m)
    total = np.repeat(cum[starts + m - 1], m)
    u = np.where(total > 0, cum / np.where(total > 0, total, 1.0), 0.0)   # eqs. 6–8
    B = basis_matrix(U, degree, u)                       # (N, n)
    line = np.repeat(np.arange(L), m)
    Q0, Qm = Q[starts], Q[starts + m - 1]
    rhs = Q - B[:, :1] * Q0[line] - B[:, -1:] * Qm[line]
    Bi = B[:, 1:-1]
    A = np.add.reduceat(Bi[:, :, None] * Bi[:, None, :], starts, axis=0)      # (L, n-2, n-2)
    b = np.add.reduceat(Bi[:, :, None] * rhs[:, None, :], starts, axis=0)     # (L, n-2, 3)
    # second differences of the full control polygon, restricted to the interior unknowns
    D = np.diff(np.eye(n_ctrl), 2, axis=0)
    R = D.T @ D
    scale = np.trace(A, axis1=1, axis2=2) / max(n_ctrl - 2, 1)
    lam = smoothing * np.maximum(scale, 1e-3)
    Rin = R[1:-1, 1:-1]
    b_reg = -(R[1:-1, :1][None] * Q0[:, None, :] + R[1:-1, -1:][None] * Qm[:, None, :])
    P_in = np.linalg.solve(A + lam[:, None, None] * Rin[None], b + lam[:, None, None] * b_reg)
    P = np.concatenate([Q0[:, None, :], P_in, Qm[:, None, :]], axis=1)
    return U, P


def fit_tag_curve(points: np.ndarray) -> "nurbs.NurbsCurve":
    """One tag line's curve (:func:`fit_tag_curves` with the count of :func:`control_count`).

    Parameters
    ----------
    points : (m, 3) ndarray
        A tag line, mm.

    Returns
    -------
    NurbsCurve
    """
    U, P = fit_tag_curves([np.asarray(points, float)], control_count([points]))
    return nurbs.NurbsCurve(3, U, P[0])


# ------------------------------------------------------------------ sections
@dataclass(eq=False)
class TagSection:
    """One tag line (or, for ``la``, one spoke of it) ready for lofting.

    Attributes
    ----------
    family : {"sa1", "sa2", "la"}
        The tag family.
    index : int
        The tag's index in its family.
    slice : str
        The slice the line is on.
    frame : int
        The frame.
    points : (n, 3) ndarray
        Scanner mm, oriented (SA: along the family direction; LA spoke: from the long
        axis outward).
    plane : ImagePlane
        The image plane of the line.
    key : float
        Orders sections within a surface: the position along the SA stack normal (mm)
        or the spoke's angle about the long axis (rad).
    half : int
        Which spoke of an LA line (0, 1); 0 for SA.
    knots : (n + p + 1,) ndarray or None
        The fitted curve's knot vector (:func:`fit_sections`), None before fitting.
    ctrl : (k, 3) ndarray or None
        Its control points, mm.
    """

    family: str
    index: int
    slice: str
    frame: int
    points: np.ndarray
    plane: ImagePlane
    key: float
    half: int = 0
    knots: np.ndarray | None = None
    ctrl: np.ndarray | None = None
    _curve: object = None

    @property
    def curve(self):
        """The fitted :class:`~cardionurbs.nurbs.NurbsCurve` (built on first use)."""
        if self._curve is None and self.ctrl is not None:
            self._curve = nurbs.NurbsCurve(3, self.knots, self.ctrl)
        return self._curve


@dataclass(eq=False)
class TagSurface:
    """The tag surface of one (family, index) at one frame, with its sections.

    Attributes
    ----------
    family : {"sa1", "sa2", "la"}
        The tag family.
    index : int
        The tag's index in its family.
    frame : int
        The frame.
    surface : NurbsSurface
        The lofted surface, scanner mm.
    sections : list of TagSection
        Its sections in loft order.
    periodic_v : bool
        Closed in v (the LA spoke fan).
    """

    family: str
    index: int
    frame: int
    surface: object
    sections: list[TagSection] = field(default_factory=list)
    periodic_v: bool = False

    @property
    def slices(self) -> list[str]:
        seen: list[str] = []
        for s in self.sections:
            if s.slice not in seen:
                seen.append(s.slice)
        return seen


def _principal_direction(points: np.ndarray) -> np.ndarray:
    d = points[-1] - points[0]
    n = float(np.linalg.norm(d))
    if n < 1e-9:
        c = points - points.mean(axis=0)
        d = np.linalg.svd(c, full_matrices=False)[2][0]
        n = 1.0
    return d / n


def principal_directions(lines: list[np.ndarray]) -> np.ndarray:
    """(n, 3) unit direction of each line: :func:`_principal_direction` of every line in one
    batch (first to last point; the principal axis where the two nearly coincide).

    Parameters
    ----------
    lines : list of (n, 3) ndarray
        Lines, mm.

    Returns
    -------
    (L, 3) ndarray
    """
    d = np.array([p[-1] for p in lines], dtype=float) - np.array([p[0] for p in lines], dtype=float)
    n = np.linalg.norm(d, axis=1)
    short = n < 1e-9
    if short.any():
        d[short] = [_principal_direction(np.asarray(lines[k], float)) for k in np.flatnonzero(short)]
        n[short] = 1.0
    return d / n[:, None]


def family_direction(lines: list[np.ndarray], dirs: np.ndarray | None = None) -> np.ndarray:
    """Mean unit direction of a family's lines (signs aligned to the first line);
    ``dirs``: their :func:`principal_directions` when already known.

    Parameters
    ----------
    lines : list of (n, 3) ndarray
        The family's lines, mm.
    dirs : (L, 3) ndarray or None
        Their directions, if known.

    Returns
    -------
    (3,) ndarray
    """
    dirs = principal_directions(lines) if dirs is None else np.array(dirs)
    ref = dirs[0]
    dirs *= np.where(dirs @ ref < 0, -1.0, 1.0)[:, None]
    d = dirs.sum(axis=0)
    return d / np.linalg.norm(d)


def sa_sections(study: Study, family: str, frame: int) -> dict[int, list[TagSection]]:
    """Oriented SA sections of every tag index of one family at one frame, ordered base → apex.

    Parameters
    ----------
    study : Study
        The study.
    family : {"sa1", "sa2"}
        The SA family.
    frame : int
        The frame.

    Returns
    -------
    dict of int to list of TagSection
        Tag index -> its sections.
    """
    lines = [t for t in study.tags_at(frame, family)]
    if not lines:
        return {}
    n_stack = stacking_direction(study)[0]
    dirs = principal_directions([t.points for t in lines])
    d_fam = family_direction([t.points for t in lines], dirs)
    flip = dirs @ d_fam < 0
    out: dict[int, list[TagSection]] = defaultdict(list)
    for t, reverse in zip(lines, flip):
        pts = np.asarray(t.points, dtype=float)
        if reverse:
            pts = pts[::-1]
        plane = _plane_of(study, t)
        out[t.index].append(TagSection(t.family, t.index, t.slice, t.frame, pts, plane,
                                       key=float(plane.position @ n_stack)))
    for secs in out.values():
        secs.sort(key=lambda s: s.key)
    return dict(out)


def _plane_of(study: Study, t: TagLine) -> ImagePlane:
    if t.image is not None:
        idx = study._image_index()
        if t.image in idx:
            return idx[t.image]
    try:
        return study.slice_plane(t.slice, t.frame)
    except Exception:
        return study.slice_plane(t.slice)


def axis_frame(apex: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed unit frame (e1, e2, e) about the long axis.

    ``e`` points from the base to the apex, so an angle measured
    right-handed about ``e`` (from e1 towards e2) is counter-clockwise as
    seen from the apex looking toward the base (docs/metrics.md sign).

    Parameters
    ----------
    apex, base : (3,) ndarray
        The long axis' ends, mm.

    Returns
    -------
    e1, e2, e : (3,) ndarray
    """
    apex, base = np.asarray(apex, float), np.asarray(base, float)
    # asked thousands of times per study (tag QC): cached per (apex, base)
    return tuple(x.copy() for x in _axis_frame(apex.tobytes(), base.tobytes()))


@lru_cache(maxsize=64)
def _axis_frame(apex: bytes, base: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`axis_frame` of the (3,) float64 points given as bytes."""
    e = np.frombuffer(apex) - np.frombuffer(base)
    e /= np.linalg.norm(e)
    helper = np.eye(3)[np.argmin(np.abs(e))]
    e1 = np.cross(e, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e, e1)
    return e1, e2, e


def la_sections(study: Study, frame: int, apex: np.ndarray,
                base: np.ndarray) -> dict[int, list[TagSection]]:
    """Spokes of every LA tag at one frame, ordered by angle about the long axis.

    Each LA line is cut where it crosses the long axis — the middle of its
    first gap around the axis when it crosses the cavity, else its point
    nearest the axis — into two spokes running outward. A spoke keeps the
    cut point and the first wall segment beyond it (so the RV walls of a
    four-chamber line are left out).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    apex, base : (3,) ndarray
        The long axis' ends at ED, mm.

    Returns
    -------
    dict of int to list of TagSection
        Tag index -> its spokes.
    """
    apex, base = np.asarray(apex, float), np.asarray(base, float)
    e = (base - apex) / np.linalg.norm(base - apex)
    e1, e2, _ = axis_frame(apex, base)
    out: dict[int, list[TagSection]] = defaultdict(list)
    lines = study.tags_at(frame, "la")
    if not lines:
        return {}
    # every line's radial offsets from the axis and steps at once (row by row, the same
    # numbers as line by line), then each line's cut
    P = np.concatenate([np.asarray(t.points, dtype=float) for t in lines])
    ends = np.cumsum([len(t.points) for t in lines])
    REL = P - apex
    RADIAL = REL - np.outer(REL @ e, e)
    R = np.linalg.norm(RADIAL, axis=1)
    STEPS = np.linalg.norm(np.diff(P, axis=0), axis=1)
    for t, stop in zip(lines, ends):
        start = stop - len(t.points)
        pts, radial, r = P[start:stop], RADIAL[start:stop], R[start:stop]
        steps = STEPS[start:stop - 1]
        limit = max(GAP_FACTOR * median(steps), GAP_MIN_MM) if len(steps) >= 2 else np.inf
        gaps = np.flatnonzero(steps > limit)                # (gap_limit of the line)
        # the gap nearest the axis, if the axis lies across it
        cut_pt: np.ndarray | None = None
        lo = hi = 0
        if len(gaps):
            mid_r = np.linalg.norm(((radial[gaps] + radial[gaps + 1]) / 2), axis=1)
            g = gaps[np.argmin(mid_r)]
            # the axis is across the gap when the two ends lie on opposite sides
            if radial[g] @ radial[g + 1] < 0:
                cut_pt, lo, hi = (pts[g] + pts[g + 1]) / 2, g, g + 1
        if cut_pt is None:
            k = int(np.argmin(r))
            cut_pt, lo, hi = pts[k], k - 1, k + 1
        halves = []
        inner = pts[: lo + 1][::-1] if lo >= 0 else pts[:0]
        outer = pts[hi:]
        # each half's steps, from the line's (a step is as long either way): the first wall
        # ends at the first gap
        inner_steps = steps[: max(lo, 0)][::-1]
        outer_steps = steps[hi:]
        for h, (seg, seg_steps) in enumerate(((inner, inner_steps), (outer, outer_steps))):
            if len(seg) == 0:
                continue
            cut = np.flatnonzero(seg_steps > limit)
            first_wall = seg[: cut[0] + 1] if len(cut) else seg
            spoke = np.vstack([cut_pt, first_wall])
            if len(spoke) < 2:
                continue
            halves.append((h, spoke))
        plane = _plane_of(study, t)
        for h, spoke in halves:
            d = spoke[-1] - apex
            ang = float(np.arctan2(d @ e2, d @ e1)) % (2 * np.pi)
            out[t.index].append(TagSection("la", t.index, t.slice, t.frame, spoke, plane,
                                           key=ang, half=h))
    for secs in out.values():
        secs.sort(key=lambda s: s.key)
    return dict(out)


# ------------------------------------------------------------------- lofting
def fit_sections(sections: list[TagSection]) -> None:
    """Fit every section's curve (:func:`fit_tag_curves`, one batch per call), in place.

    Parameters
    ----------
    sections : list of TagSection
        Sections; their ``knots`` and ``ctrl`` are set.
    """
    todo = [s for s in sections if s.ctrl is None]
    if not todo:
        return
    U, P = fit_tag_curves([s.points for s in todo], control_count([s.points for s in todo]))
    for s, ctrl in zip(todo, P):
        s.knots, s.ctrl = U, ctrl


def loft_sections(sections: list[TagSection], periodic: bool = False,
                  degree_v: int = 3):
    """Loft fitted sections (paper §3.2.4) into one surface.

    Sections sharing one knot vector (the usual case: :func:`fit_sections`)
    go through :func:`cardionurbs.nurbs.loft_compatible`, others through
    :func:`cardionurbs.nurbs.loft`. ``periodic`` repeats the first section
    at the end (the LA spoke fan). Returns None with fewer than two sections.

    Parameters
    ----------
    sections : list of TagSection
        Sections in loft order.
    periodic : bool
        Close the loft (the LA spoke fan).
    degree_v : int
        Degree across the sections.

    Returns
    -------
    NurbsSurface or None
    """
    fit_sections(sections)
    secs = list(sections) + ([sections[0]] if periodic and len(sections) >= 2 else [])
    if len(secs) < 2:
        return None
    U = secs[0].knots
    if U is not None and all(s.knots is not None and s.knots.shape == U.shape and np.array_equal(s.knots, U)
           for s in secs):
        return nurbs.loft_compatible(np.array([s.ctrl for s in secs]), U, 3, degree_v)
    return nurbs.loft([s.curve for s in secs], degree_v=min(degree_v, len(secs) - 1))


def build_tag_surfaces(study: Study, frame: int, long_axis: tuple | None = None,
                       families: tuple[str, ...] = TAG_FAMILIES,
                       exclude: set | frozenset = frozenset()) -> dict[tuple[str, int], TagSurface]:
    """Every tag surface at one frame, with its sections (see :func:`tag_surfaces`).

    ``exclude``: {(family, index, slice)} tag lines left out (e.g. flagged
    by the tag-jump QC).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    long_axis : (apex (3,), base (3,)) or None
        At ED, mm; None: from the ED landmarks.
    families : tuple of str
        The families built.
    exclude : set of (str, int, str)
        As above.

    Returns
    -------
    dict of (str, int) to TagSurface
    """
    check_tags(study)
    out: dict[tuple[str, int], TagSurface] = {}
    for fam in families:
        if fam == "la":
            if not study.tags_at(frame, "la"):
                continue
            if long_axis is None:
                long_axis = study_long_axis(study)
            groups = la_sections(study, frame, *long_axis)
            periodic = True
        else:
            groups = sa_sections(study, fam, frame)
            periodic = False
        if exclude:
            groups = {i: [sec for sec in secs if (fam, i, sec.slice) not in exclude]
                      for i, secs in groups.items()}
        fit_sections([sec for secs in groups.values() for sec in secs])
        for idx, secs in groups.items():
            if periodic and len(secs) < 3:
                continue
            surf = loft_sections(secs, periodic=periodic)
            if surf is not None:
                out[(fam, idx)] = TagSurface(fam, idx, frame, surf, secs, periodic_v=periodic)
    return out


def tag_surfaces(study: Study, frame: int, long_axis: tuple | None = None) -> dict:
    """Tag surfaces of one frame: ``{(family, index): NurbsSurface}`` in scanner mm.

    SA families are lofted across the SA slices that show the tag; the LA
    family is lofted around the long axis through the spokes of its lines
    (module docstring). ``long_axis`` = (apex, base centre) at ED, mm; taken
    from the ED landmarks when omitted (needed for ``la`` only). A tag seen in
    fewer than two slices (three spokes for ``la``) has no surface.

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    long_axis : (apex (3,), base (3,)) or None
        As above.

    Returns
    -------
    dict of (str, int) to NurbsSurface
    """
    return {k: ts.surface for k, ts in build_tag_surfaces(study, frame, long_axis).items()}
