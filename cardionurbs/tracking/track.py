"""Tag lines tracked from a study's SPAMM-tagged DICOM images (HARP), with 3-D tag indices.

:func:`track_tags` (``cn.track_tags``): for every slice of the study whose
images name DICOM files,

1. **Tag geometry** (:mod:`cardionurbs.tracking.spectral`): the first frame's
   spectral peaks give each family's k (one family in LA views, two in SA
   grids); k in scanner mm (k_c / Δc · row cosine + k_r / Δr · column
   cosine) gives the tag normal direction and spacing, cross-checked
   against the tag planes the study expects (``study.meta["tag_planes"]``,
   else the study's own tag lines at the first frame): a spacing off by
   more than ``SPACING_TOL`` or a direction by more than ``ANGLE_TOL_DEG``
   is a :class:`TagTrackingError`, and so is a first frame without a tag
   pattern (peak contrast below :data:`spectral.MIN_CONTRAST`).
2. **Harmonic phase** (:mod:`cardionurbs.tracking.harp`) of every frame, on a
   crop around the slice's contours, after a *myocardial window*
   (:func:`myocardial_window`): everything outside the frame's myocardium is
   set to the myocardium's mean intensity. The band-pass reaches a few pixels;
   without the window the bright blood pool's edge adds its own spectrum at
   the tag frequency and biases the phase near the endocardium by up to half
   a spacing, a bias that moves with the wall (the main source of tag jumps
   at end systole). A frame whose median myocardial
   harmonic magnitude has fallen below ``FADED`` of the first frame's ends the
   tracking of that slice (the tags have faded).
3. **Tag lines at the first frame**: the iso-phase lines φ = π (the tag
   minima: a dark tag's first harmonic has phase π at its centre) clipped to
   the myocardium of the study's contours (SA: inside ``lv_epi`` and outside
   ``lv_endo``; LA: between the open ``lv_epi`` and ``lv_endo`` curves closed
   across the base), ordered along the tag. At the first frame a tag lies on
   its plane: a piece whose median offset from the nearest plane exceeds
   ``ON_PLANE_LINE`` spacings (a plane grazing the border leaves such a piece)
   is no tag line.
4. **Tag index** of each line: its position along the family's 3-D tag normal
   N in scanner mm, p = median N·x over its points, gives
   i = round((p − index0) / d) — the expected planes' ``index0_mm`` and
   ``spacing_mm`` when the study has them, else index0 from the circular
   mean of p mod d over every slice of the family, indices shifted to start
   at 0. The same tag plane seen in different slices gets the same index,
   so the tag surfaces, material points, metrics and QC use the lines as
   they are.
5. **Tracking**: every first-frame line point is HARP-tracked through the
   cycle (temporal prior: the contours' motion). SA grids: the line at frame
   t is its tracked material points (both phases pin them), less those a
   spacing off the rest (slipped onto a neighbouring tag: a robust quadratic
   across the line). LA views: the iso-phase lines φ_t = π, each point
   labelled by the nearest line predicted from the previous frame plus the
   whole spacings between them. Both are moved onto the tag trough and kept
   inside frame t's myocardium, 1 px from its borders. A slice without
   contours at a frame the study contours elsewhere has left the ventricle (a
   basal slice in systole: its tissue was above the base at ED, so no LV tag
   runs through it — docs/metrics.md, Levels): its tracking stops there. Only
   frames the study contours nowhere (e.g. ED + ES studies) borrow the
   nearest contoured frame's myocardium.
6. **Confidence** per line (``study.meta["tag_tracking"]["lines"]``, one
   column per field): ``magnitude`` — median harmonic magnitude along the
   line over the first frame's median myocardial magnitude (1 at the first
   frame, falling as the tags fade); ``phase_residual`` — RMS of the wrapped
   phase left after Newton over the tracked material points the line is made
   of (SA) or over its index's tracked points (LA), rad (points that lost
   their tag: SA lines leave out points above ``CONVERGED_RAD``, so a few
   lost points near the border do not condemn a good line). The tag QC flags lines below
   ``MIN_MAGNITUDE`` or above ``MAX_PHASE_RESIDUAL``.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import binary_dilation
from scipy.spatial import cKDTree

from cardionurbs.analysis.tag_surfaces import family_direction
from cardionurbs.analysis.tagqc import tag_spacing
from cardionurbs.anatomy.sections import study_long_axis
from cardionurbs.errors import StudyError, TagTrackingError
from cardionurbs.imaging.dicom import read_pixels
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import atomic, load_study
from cardionurbs.io.native import write_study
from cardionurbs.io.outputs import check_output_dir
from cardionurbs.study import Study, TagLine
from cardionurbs.tracking import harp, spectral
from cardionurbs.tracking.labelmaps import LabelMaps, LabelMyocardium, load_label_maps

SPACING_TOL = 0.2          # relative
ANGLE_TOL_DEG = 15.0
FADED = 0.15               # harmonic magnitude ratio to the first frame that ends tracking
CROP_MARGIN_PX = 24
MIN_LINE_POINTS = 3
ON_PLANE = 0.25            # first frame: a line point within this many spacings of its plane
ON_PLANE_LINE = 0.12       # first frame: a line's median offset from its plane, at most (spacings)
TROUGH_REACH = 0.45        # trough search: this many spacings either side of the iso-phase line
REFINE = True
CONVERGED_RAD = 0.3        # a tracked point whose phase is further than this from its target
                           # (Newton did not converge: low magnitude, phase singularity) is dropped
BORDER_MARGIN_PX = 1.0    # line points closer than this to the endo/epicardium are left out:
                           # there the filter mixes in blood and the tag runs into the border
ON_LINE = 0.3              # later frames: within this many spacings of its tracked points
WINDOW_BORROWED_PX = 4     # myocardium borrowed from another frame: window this much wider
MIN_MAGNITUDE = 0.15       # QC: confidence thresholds
MAX_PHASE_RESIDUAL = 0.6   # rad
TAG_CURVE_DEGREE = 2       # SA lines after the first frame: least-squares polynomial of this degree
FAMILIES = {"SA": ("sa1", "sa2"), "LA": ("la",)}


# ------------------------------------------------------------------ inputs
def _slice_images(study: Study) -> dict[str, list[ImagePlane]]:
    """The study's images with a DICOM file, by slice, sorted by frame."""
    out: dict[str, list[ImagePlane]] = defaultdict(list)
    for im in study.images:
        if im.file:
            out[im.slice].append(im)
    for ims in out.values():
        ims.sort(key=lambda im: im.frame)
    return dict(out)


def _study_folder(study: Study) -> Path:
    """The study's folder (:class:`TagTrackingError` when it has none)."""
    if not study.source:
        raise TagTrackingError("the study has no folder, so its DICOM images cannot be found",
                               field="images")
    return Path(study.source)


def _read_frames(study: Study, images: list[ImagePlane]) -> np.ndarray:
    folder = _study_folder(study)
    arrs = []
    for im in images:
        path = folder / str(im.file)
        if not path.is_file():
            raise StudyError(f"image {im.id!r} refers to file {im.file!r}, which does not exist",
                             file=folder / "study.json", slice=im.slice, frame=im.frame, field="file")
        a = read_pixels(path)
        if a.shape != (im.rows, im.columns):
            raise StudyError(f"pixel matrix {a.shape[0]}x{a.shape[1]} differs from the study's "
                             f"{im.rows}x{im.columns}", file=path, slice=im.slice, frame=im.frame,
                             field="Rows")
        arrs.append(a)
    return np.array(arrs)


def _closed_polygon(points_px: np.ndarray):
    from matplotlib.path import Path as MplPath
    return MplPath(np.vstack([points_px, points_px[:1]]), closed=True)


@dataclass
class Myocardium:
    """LV myocardium of one image: polygons in pixel coordinates (outer minus inner), or the
    myocardium pixels of a label map (``labels``).

    Attributes
    ----------
    outer : matplotlib.path.Path or None
        The epicardium polygon in pixel coordinates (c, r); None with ``labels``.
    inner : matplotlib.path.Path or None
        The endocardium polygon (None: no cavity cut out).
    drawn : bool
        False when borrowed from the slice's nearest contoured frame.
    labels : cardionurbs.tracking.labelmaps.LabelMyocardium or None
        The label map's myocardium pixels, used instead of the polygons.
    """

    outer: Any              #: matplotlib.path.Path of the epicardium, or None with labels
    inner: Any | None       #: that of the endocardium
    drawn: bool = True      # False: borrowed from the slice's nearest contoured frame
    labels: LabelMyocardium | None = None

    def contains(self, pts: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Points (n, 2) px inside the myocardium, at least ``margin`` px from its borders.

        Parameters
        ----------
        pts : ndarray, shape (n, 2)
            Pixel positions (column c, row r).
        margin : float, optional
            Least distance from the borders, in px (0: inside at all).

        Returns
        -------
        ndarray of bool, shape (n,)
            True for a point inside, ``margin`` px clear of the borders.
        """
        if len(pts) == 0:
            return np.zeros(0, bool)
        if self.labels is not None:
            d = self.labels.distance(np.asarray(pts, float))
            return d >= margin if margin > 0 else d > 0
        inside = self.outer.contains_points(pts)
        if self.inner is not None:
            inside &= ~self.inner.contains_points(pts)
        if margin > 0 and inside.any():
            for poly in (self.outer, self.inner):
                if poly is not None:
                    inside[inside] &= _distance_to_polygon(pts[inside], poly.vertices) >= margin
        return inside


def _distance_to_polygon(pts: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Distance (px) of points (n, 2) to a closed polygon's edges (vertices (m, 2), closed)."""
    a, b = vertices[:-1], vertices[1:]
    ab = b - a
    t = np.clip(((pts[:, None, :] - a[None]) * ab[None]).sum(-1)
                / np.maximum((ab * ab).sum(-1), 1e-12)[None], 0.0, 1.0)
    d = pts[:, None, :] - (a[None] + t[..., None] * ab[None])
    return np.sqrt((d * d).sum(-1).min(axis=1))


def _myocardium(study: Study, plane: ImagePlane, frame: int) -> Myocardium | None:
    """LV myocardium of ``plane``'s slice at ``frame`` from its lv_epi / lv_endo contours."""
    cs = {c.structure: c for c in study.contours_at(frame, ("lv_epi", "lv_endo"))
          if c.slice == plane.slice}
    if "lv_epi" not in cs:
        return None
    outer = _closed_polygon(plane.scanner_to_pixel(cs["lv_epi"].points))
    inner = _closed_polygon(plane.scanner_to_pixel(cs["lv_endo"].points)) if "lv_endo" in cs else None
    return Myocardium(outer, inner)


def _masks(study: Study, images: list[ImagePlane],
           labelmaps: LabelMaps | None = None) -> list[Myocardium | None]:
    """Myocardium per frame of a slice, from its own contours at that frame.

    A frame the study contours on other slices but not on this one is a frame where this
    slice has left the ventricle (a basal slice in systole: the tissue in it was above the
    base at ED, so no tag of the LV runs through it): None, no tag lines there. A frame the
    study contours nowhere (e.g. a study contoured at ED and ES only) takes the slice's
    nearest contoured frame's myocardium, marked ``drawn=False``. With ``labelmaps`` (a
    slice they cover) the myocardium is the label maps' myocardium pixels, by the same rule
    (frames the label maps label nowhere borrow).
    """
    if labelmaps is not None and labelmaps.contours_slice(images[0].slice) is not None:
        px = [labelmaps.pixels(im.slice, im.frame) for im in images]
        own = [None if m is None else Myocardium(None, None, labels=LabelMyocardium(m)) for m in px]
        contoured = labelmaps.frames
    else:
        own = [_myocardium(study, im, im.frame) for im in images]
        contoured = {c.frame for c in study.contours if c.structure == "lv_epi"}
    have = [i for i, m in enumerate(own) if m is not None]
    if not have:
        return own
    out = []
    for i, im in enumerate(images):
        if own[i] is not None or im.frame in contoured:
            out.append(own[i])
        else:
            near = own[min(have, key=lambda j: abs(images[j].frame - im.frame))]
            assert near is not None                 # one of ``have``
            out.append(dataclasses.replace(near, drawn=False))
    return out


def _crop_box(study: Study, images: list[ImagePlane],
              slice_id: str | None = None) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1) around the slice's contours at every frame, plus a margin (the
    contours of ``study``'s slice ``slice_id``, default the images' own)."""
    plane = images[0]
    sid = slice_id or plane.slice
    pts = [plane.scanner_to_pixel(c.points) for c in study.contours if c.slice == sid]
    if not pts:
        return 0, plane.rows, 0, plane.columns
    P = np.vstack(pts)
    c0, r0 = np.floor(P.min(axis=0)).astype(int) - CROP_MARGIN_PX
    c1, r1 = np.ceil(P.max(axis=0)).astype(int) + CROP_MARGIN_PX + 1
    return max(r0, 0), min(r1, plane.rows), max(c0, 0), min(c1, plane.columns)


# ------------------------------------------------------------ expectations
@dataclass
class TagPlanes:
    """One family's 3-D tag planes: unit normal N (scanner), spacing d (mm), index0 (mm or None).

    Attributes
    ----------
    normal : ndarray, shape (3,)
        The planes' unit normal N, scanner coordinates.
    spacing : float
        The tag spacing d along N, in mm.
    index0 : float or None
        The offset of tag index 0 along N (x · N = index0 + i d), in mm; None when unknown.
    """

    normal: np.ndarray
    spacing: float
    index0: float | None


def expected_tag_planes(study: Study) -> dict[str, TagPlanes]:
    """What the study expects: ``meta["tag_planes"]``, else its own tag lines at their first frame.

    Parameters
    ----------
    study : cardionurbs.study.Study
        The tagged study (``meta["tag_planes"]`` or its tag lines).

    Returns
    -------
    dict of str to TagPlanes
        Family (``"sa1"``, ``"sa2"``, ``"la"``) -> its expected planes; empty when the study
        says nothing.

    Raises
    ------
    cardionurbs.errors.StudyError
        A ``meta["tag_planes"]`` entry lacks a 3-number ``normal`` or ``spacing_mm``.
    """
    out: dict[str, TagPlanes] = {}
    given = study.meta.get("tag_planes") if isinstance(study.meta, dict) else None
    if isinstance(given, dict):
        for fam, d in given.items():
            try:
                n = np.asarray(d["normal"], float)
                out[fam] = TagPlanes(n / np.linalg.norm(n), float(d["spacing_mm"]),
                                     None if d.get("index0_mm") is None else float(d["index0_mm"]))
            except (KeyError, TypeError, ValueError):
                raise StudyError(f"tag_planes[{fam!r}] needs normal (3 numbers) and spacing_mm",
                                 file=study.source, field="meta.tag_planes") from None
        return out
    if not study.tags:
        return out
    f0 = study.tagged_frames[0]
    for fam in ("sa1", "sa2", "la"):
        lines = study.tags_at(f0, fam)
        if len(lines) < 2:
            continue
        d = tag_spacing(study, fam, f0)
        if not np.isfinite(d) or d <= 0:
            continue
        if fam == "la":
            try:
                apex, base = study_long_axis(study)
            except StudyError:
                continue
            n = (base - apex) / np.linalg.norm(base - apex)
        else:
            along = family_direction([t.points for t in lines])
            n = np.cross(study.slice_plane(lines[0].slice).normal, along)
            n /= np.linalg.norm(n)
        off = np.array([float(np.median(t.points @ n)) - t.index * d for t in lines])
        out[fam] = TagPlanes(n, float(d), float(np.median(off)))
    return out


# ------------------------------------------------------------------ per slice
@dataclass
class SliceGeometry:
    """Tag families found in one slice: family -> (k px, in-plane scanner unit normal, spacing mm).

    Attributes
    ----------
    slice : str
        The slice id.
    view : str
        ``"SA"`` or ``"LA"``.
    k : dict of str to ndarray
        Family -> harmonic peak (k_c, k_r), in cycles/pixel.
    normal : dict of str to ndarray
        Family -> in-plane unit tag normal, scanner coordinates (3,).
    spacing_mm : dict of str to float
        Family -> tag spacing in the image plane, in mm.
    contrast : dict of str to float
        Family -> spectral peak contrast of the slice's first frame (dimensionless).
    """

    slice: str
    view: str
    k: dict[str, np.ndarray]
    normal: dict[str, np.ndarray]
    spacing_mm: dict[str, float]
    contrast: dict[str, float]


def _k_scanner(k: np.ndarray, plane: ImagePlane) -> np.ndarray:
    """k (cycles/px, (c, r)) as a scanner-space wave vector (cycles/mm)."""
    return (k[0] / plane.pixel_spacing[1]) * plane.row_cosine + (k[1] / plane.pixel_spacing[0]) * plane.column_cosine


def _k_pixels(k_mm: np.ndarray, plane: ImagePlane) -> np.ndarray:
    """A scanner wave vector (cycles/mm) as (k_c, k_r) cycles/px of ``plane`` (in-plane part)."""
    return np.array([(k_mm @ plane.row_cosine) * plane.pixel_spacing[1],
                     (k_mm @ plane.column_cosine) * plane.pixel_spacing[0]])


def _in_plane(n: np.ndarray, plane: ImagePlane) -> np.ndarray:
    return n - (n @ plane.normal) * plane.normal


def first_frame_peaks(image: np.ndarray, plane: ImagePlane, path,
                      expected: dict[str, TagPlanes]) -> list[spectral.TagPeak]:
    """The tag peaks of one slice's first frame (one per family of its view), searched near the
    expected spacing when the study has one (weak peaks included; the caller judges).

    Parameters
    ----------
    image : ndarray, shape (rows, columns)
        The slice's first tagged frame.
    plane : cardionurbs.imaging.geometry.ImagePlane
        Its image plane.
    path : path-like
        Its file, for the messages.
    expected : dict of str to TagPlanes
        The study's expected tag planes (:func:`expected_tag_planes`).

    Returns
    -------
    list of cardionurbs.tracking.spectral.TagPeak
        One peak per family of the view (fewer when none is found), strongest first.

    Raises
    ------
    cardionurbs.errors.TagTrackingError
        Expected tag planes nearly parallel to the image plane.
    """
    fams = FAMILIES[plane.view]
    where = dict(file=path, slice=plane.slice, frame=plane.frame)
    exp_px = []
    for f in fams:
        if f in expected:
            e_in = _in_plane(expected[f].normal, plane)
            if np.linalg.norm(e_in) < 0.5:
                raise TagTrackingError(f"the expected {f} tag planes are nearly parallel to this "
                                       "image plane", field="meta.tag_planes", **where)
            exp_px.append(expected[f].spacing / np.linalg.norm(e_in)
                          / float(np.mean(plane.pixel_spacing)))
    peaks = spectral.tag_peaks(image, len(fams))
    if exp_px:   # look near the expected spacing; keep the full band's answer to report it
        near = spectral.tag_peaks(image, len(fams), min_period_px=max(min(exp_px) / 1.6, 2.0),
                                  max_period_px=max(exp_px) / 0.6)
        strong = len(peaks) == len(fams) and min(p.contrast for p in peaks) >= spectral.MIN_CONTRAST
        good = len(near) == len(fams) and min(p.contrast for p in near) >= spectral.MIN_CONTRAST
        if good or not strong:
            return near
    return peaks


def resolve_geometry(group: list[tuple[ImagePlane, object, list[spectral.TagPeak]]],
                     expected: dict[str, TagPlanes]) -> dict[str, SliceGeometry]:
    """Tag families of a group of parallel slices (the SA stack, or one LA view), labelled,
    oriented and cross-checked against ``expected``.

    The group has a tag pattern when at least half its slices show every family's peak
    above :data:`spectral.MIN_CONTRAST`; the consensus wave vector of each family (median
    over those slices, scanner cycles/mm) then stands in for a slice whose own peak is weak,
    more than ``ANGLE_TOL_DEG`` off or ``SPACING_TOL`` from it in spacing (a small apical
    section has little tagged tissue, or its strongest peak is a harmonic).

    Parameters
    ----------
    group : list of tuple
        (image plane, file, first-frame peaks) of each slice of the group.
    expected : dict of str to TagPlanes
        The study's expected tag planes.

    Returns
    -------
    dict of str to SliceGeometry
        Slice id -> its tag families.

    Raises
    ------
    cardionurbs.errors.TagTrackingError
        Fewer than half the slices show a tag pattern (untagged or faded series), or the
        consensus disagrees with ``expected`` (naming file, slice and frame).
    """
    plane0, path0, _ = group[0]
    fams = FAMILIES[plane0.view]
    where = dict(file=path0, slice=plane0.slice, frame=plane0.frame)
    contrast = [min([p.contrast for p in pk], default=0.0) if len(pk) == len(fams) else 0.0
                for _, _, pk in group]
    strong = [i for i, c in enumerate(contrast) if c >= spectral.MIN_CONTRAST]
    if 2 * len(strong) < len(group):
        c = float(np.median(contrast))
        raise TagTrackingError(f"no SPAMM tag pattern in the first frame (untagged series, or the "
                               f"tags have faded): spectral peak {c:.1f} x its surroundings, needs "
                               f">= {spectral.MIN_CONTRAST:g}", field="PixelData", **where)
    consensus = _consensus_k(group, strong, fams, expected)
    _check_consensus(consensus, expected, plane0, where)
    return {plane.slice: _slice_geometry(plane, [_k_scanner(p.k, plane) for p in pk] if i in strong
                                         else [], consensus, contrast[i])
            for i, (plane, _, pk) in enumerate(group)}


def _consensus_k(group: list[tuple[ImagePlane, object, list[spectral.TagPeak]]], strong: list[int],
                 fams: tuple[str, ...], expected: dict[str, TagPlanes]) -> dict[str, np.ndarray]:
    """Each family's consensus wave vector (scanner cycles/mm, (3,)): the strong slices' peaks
    labelled and oriented by the expected tag normals (else the first strong slice's), and
    their median taken (one slice locked on a harmonic does not move it)."""
    refs = {f: expected[f].normal for f in fams if f in expected}
    sums: dict[str, list] = {f: [] for f in fams}
    for i in strong:
        plane, _, pk = group[i]
        kmm = [_k_scanner(p.k, plane) for p in pk]
        for f in fams:
            if f not in refs:
                refs[f] = kmm[fams.index(f)] / np.linalg.norm(kmm[fams.index(f)])
        order = [0]
        if len(fams) == 2:
            u = [k / np.linalg.norm(k) for k in kmm]
            score = [abs(u[0] @ refs[fams[0]]) + abs(u[1] @ refs[fams[1]]),
                     abs(u[1] @ refs[fams[0]]) + abs(u[0] @ refs[fams[1]])]
            order = [0, 1] if score[0] >= score[1] else [1, 0]
        for f, j in zip(fams, order):
            k = kmm[j] if kmm[j] @ refs[f] >= 0 else -kmm[j]
            sums[f].append(k)
    return {f: np.median(np.array(sums[f]), axis=0) for f in fams}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between the lines along ``a`` and ``b`` (sign ignored), degrees."""
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)),
                                              0, 1))))


def _check_consensus(consensus: dict[str, np.ndarray], expected: dict[str, TagPlanes],
                     plane0: ImagePlane, where: dict) -> None:
    """:class:`TagTrackingError` when a family's consensus spacing is more than ``SPACING_TOL``
    off the expected one (in the image plane), or its direction more than ``ANGLE_TOL_DEG``."""
    for f, c in consensus.items():
        if f not in expected:
            continue
        e = expected[f]
        got_d = 1.0 / np.linalg.norm(c)
        e_in = _in_plane(e.normal, plane0)
        d_exp = e.spacing / np.linalg.norm(e_in)
        if abs(got_d / d_exp - 1.0) > SPACING_TOL:
            raise TagTrackingError(f"{f} tag spacing in the images is {got_d:.2f} mm, the study "
                                   f"expects {d_exp:.2f} mm (tolerance {SPACING_TOL:.0%})",
                                   field="tag spacing", **where)
        ang = _angle_deg(c, e_in)
        if ang > ANGLE_TOL_DEG:
            raise TagTrackingError(f"{f} tag normal in the images is {ang:.1f} deg from the "
                                   f"expected direction (tolerance {ANGLE_TOL_DEG:g} deg)",
                                   field="tag orientation", **where)


def _slice_geometry(plane: ImagePlane, kmm_own: list[np.ndarray], consensus: dict[str, np.ndarray],
                    contrast: float) -> SliceGeometry:
    """One slice's tag geometry: per family its own peak (scanner cycles/mm, ``kmm_own``) when
    within the tolerances of the consensus, else the consensus in its plane; oriented along
    the consensus."""
    ks, ns, ds, cs = {}, {}, {}, {}
    for f, c in consensus.items():
        own = [k for k in kmm_own if _angle_deg(k, c) <= ANGLE_TOL_DEG
               and abs(np.linalg.norm(c) / np.linalg.norm(k) - 1.0) <= SPACING_TOL]
        k = own[0] if own else _in_plane(c, plane)
        k = k if k @ c >= 0 else -k
        ks[f] = _k_pixels(k, plane)
        ns[f] = k / np.linalg.norm(k)
        ds[f] = float(1.0 / np.linalg.norm(k))
        cs[f] = contrast
    return SliceGeometry(plane.slice, plane.view, ks, ns, ds, cs)


def _order_along_index(points: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Indices ordering points (n, 2) along the tag (perpendicular to k)."""
    return np.argsort(points @ np.array([-k[1], k[0]]), kind="stable")


def _order_along(points: np.ndarray, k: np.ndarray) -> np.ndarray:
    return points[_order_along_index(points, k)]


def _isolines_in_myocardium(hs: harp.HarmonicSeries, t: int, myo: Myocardium,
                            offset: np.ndarray, grid_mask: np.ndarray,
                            image: np.ndarray | None = None) -> list[np.ndarray]:
    """Iso-phase π pieces (crop px) at frame t inside the myocardium (runs of inside points),
    moved onto the tag trough of ``image`` when given (:func:`harp.trough_refine`)."""
    pieces = []
    reach = TROUGH_REACH / float(np.linalg.norm(hs.k))
    for line in harp.phase_isolines(hs, t, np.pi, grid_mask):
        if image is not None and REFINE:
            line = harp.trough_refine(image, line, hs.sample(t, line)[1], reach)
        inside = myo.contains(line + offset, BORDER_MARGIN_PX)
        if not inside.any():
            continue
        edges = np.flatnonzero(np.diff(np.r_[0, inside.astype(int), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= 2:
                pieces.append(line[a:b])
    return pieces


def _grid_mask(myo: Myocardium, box, dilate_px: int = 3) -> np.ndarray:
    """The myocardium rasterised on the crop's pixel grid (scan-line polygon fill), dilated."""
    from scipy.ndimage import binary_dilation
    from skimage.draw import polygon
    r0, r1, c0, c1 = box
    shape = (r1 - r0, c1 - c0)

    def fill(path) -> np.ndarray:
        v = path.vertices
        m = np.zeros(shape, bool)
        rr, cc = polygon(v[:, 1] - r0, v[:, 0] - c0, shape)
        m[rr, cc] = True
        return m

    if myo.labels is not None:
        m = np.zeros(shape, bool)
        px = myo.labels.pixels[r0:r1, c0:c1]
        m[:px.shape[0], :px.shape[1]] = px
        return binary_dilation(m, iterations=dilate_px) if dilate_px > 0 else m
    m = fill(myo.outer)
    if myo.inner is not None:
        m &= ~fill(myo.inner)
    return binary_dilation(m, iterations=dilate_px) if dilate_px > 0 else m


@dataclass
class SliceTracking:
    """Tracked lines of one slice: [(family, index, frame, points px (full image), magnitude,
    phase_residual)], and notes.

    Attributes
    ----------
    lines : list of tuple
        (family, tag index, frame (0-based), points (n, 2) in full-image px (c, r), harmonic
        magnitude, phase residual in rad) per tracked line piece.
    notes : list of str
        What the tracking left out or changed, one line each.
    frames_tracked : int
        Frames tracked before the tags faded.
    """

    lines: list[tuple]
    notes: list[str]
    frames_tracked: int


def _first_frame_lines(hs_by_fam, geom, myo, box, mask, plane, tag_planes, image=None,
                       max_line_offset: float | None = None):
    """[(family, index, points crop px, offset)] of the first frame, indexed by position along N.

    offset: the line's median distance from its tag plane, in spacings. At the first frame a
    tag lies on its plane; a piece whose offset exceeds ``max_line_offset`` (when given) is
    no tag line — typically a short piece running along the border, where a plane that only
    grazes the myocardium leaves an iso-phase line inside it."""
    offset = np.array([box[2], box[0]], float)
    out = []
    for fam, hs in hs_by_fam.items():
        tp = tag_planes[fam]
        for piece in _isolines_in_myocardium(hs, 0, myo, offset, mask, image):
            s = (plane.pixel_to_scanner(piece + offset) @ tp.normal - tp.index0) / tp.spacing
            i = np.round(np.median(s))
            keep = np.abs(s - i) <= ON_PLANE      # points off the tag plane: not this line
            if keep.sum() < MIN_LINE_POINTS:
                continue
            frac = float(np.median(s[keep]) - i)
            if max_line_offset is None or abs(frac) <= max_line_offset:
                out.append((fam, int(i), piece[keep], frac))
    return out


def _resample(P: np.ndarray, closed: bool, n: int = 96) -> np.ndarray:
    Q = np.vstack([P, P[:1]]) if closed else P
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))]
    u = np.linspace(0.0, s[-1], n, endpoint=not closed)
    return np.column_stack([np.interp(u, s, Q[:, 0]), np.interp(u, s, Q[:, 1])])


def slice_contours_px(study: Study, images: list[ImagePlane],
                      slice_id: str | None = None) -> list[list[tuple[np.ndarray, bool]] | None]:
    """Per frame of a slice: its lv_endo and lv_epi contours resampled by arc length (px), or
    None when not both are drawn (the contours of ``study``'s slice ``slice_id``, default the
    images' own).

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study holding the contours.
    images : list of cardionurbs.imaging.geometry.ImagePlane
        The slice's images, one per frame.
    slice_id : str or None, optional
        The study's slice whose contours are taken (default each image's own).

    Returns
    -------
    list of (list of tuple of (ndarray, bool)) or None
        Per frame, [(lv_endo points (96, 2) px, closed), (lv_epi points, closed)] or None.
    """
    out: list[list[tuple[np.ndarray, bool]] | None] = []
    for im in images:
        cs = {c.structure: c for c in study.contours_at(im.frame, ("lv_endo", "lv_epi"))
              if c.slice == (slice_id or im.slice)}
        if set(cs) != {"lv_endo", "lv_epi"}:
            out.append(None)
            continue
        out.append([(_resample(im.scanner_to_pixel(cs[k].points), cs[k].closed), cs[k].closed)
                    for k in ("lv_endo", "lv_epi")])
    return out


def best_cyclic_shift(a: np.ndarray, b: np.ndarray) -> int:
    """The k minimising Σ |roll(b, k) − a|² for two closed curves of n samples (n, 2): the
    maximum of the circular cross-correlation Σ_i a_i · b_{i−k}, by FFT.

    Parameters
    ----------
    a, b : ndarray, shape (n, 2)
        Two closed curves sampled alike (px).

    Returns
    -------
    int
        The shift k in 0..n-1.
    """
    fa, fb = np.fft.rfft(a, axis=0), np.fft.rfft(b, axis=0)
    corr = np.fft.irfft((fa * np.conj(fb)).sum(axis=1), n=len(a))
    return int(np.argmax(corr))


def _contour_prior(contours, offset: np.ndarray):
    """Displacement prior for :func:`harp.track`: each point moves as the mean of the 4
    nearest contour samples between frames t − 1 and t (closed contours matched by the cyclic
    shift that fits best), or None when either frame lacks contours."""
    def prior(t: int, prev: np.ndarray):
        if t >= len(contours) or contours[t] is None or contours[t - 1] is None:
            return None
        starts, moves = [], []
        for (a, closed), (b, _) in zip(contours[t - 1], contours[t]):
            if closed:
                b = np.roll(b, best_cyclic_shift(a, b), axis=0)
            starts.append(a)
            moves.append(b - a)
        P0, D = np.vstack(starts) - offset, np.vstack(moves)
        d, j = cKDTree(P0).query(prev, k=4)
        w = 1.0 / np.maximum(d, 0.5)
        return (D[j] * w[..., None]).sum(1) / w.sum(1)[:, None]
    return prior


def _on_one_tag(P: np.ndarray, k: np.ndarray, tol: float = 0.35) -> np.ndarray:
    """Mask of the points of one tracked line that lie on one tag: a robust quadratic of the
    offset along k against the position along the tag (iteratively refitted on the points
    within ``tol`` spacings of it); points a spacing off (slipped onto a neighbouring tag)
    are left out."""
    n = len(P)
    if n < 5:
        return np.ones(n, bool)
    period = 1.0 / float(np.linalg.norm(k))
    khat = k / np.linalg.norm(k)
    u = P @ np.array([-khat[1], khat[0]])
    o = P @ khat
    keep = np.abs(o - np.median(o)) <= 0.5 * period + 0.1 * np.ptp(u)   # a tilt of ~6 deg
    for deg in (1, 2, 2):
        if keep.sum() <= deg + 2:
            return np.ones(n, bool)
        c = np.polyfit(u[keep], o[keep], deg)
        keep = np.abs(o - np.polyval(c, u)) <= tol * period
    return keep


def tag_curve(P: np.ndarray, k: np.ndarray, deg: int = TAG_CURVE_DEGREE) -> np.ndarray:
    """Points (n, 2) of one tracked SA tag line moved onto the least-squares polynomial of
    degree ``deg`` of their offset o along k against their position u along the tag, o(u).

    A tag line in a short-axis image is the cut of a smoothly deformed tag plane; the tracked
    points carry, beyond it, the per-point jitter of the trough search (image noise, the
    three-point parabola), independent from point to point and from one wall piece of the line
    to the other. The tag surfaces lofted through the lines across slices follow it, and the
    material points where three surfaces meet inherit it amplified: on phantoms at SNR 20 the
    raw points gave +0.4 to +1.0 deg of Twist error, always of the same sign, the fitted
    curves +0.2 to +0.55 deg (five phantoms; reports/validation-tracking.md). One quadratic
    across the whole line (both wall pieces) is the model :func:`_on_one_tag` already rejects
    slipped points against; a fit per wall piece does not remove the bias. On the phantoms'
    own (true) lines the model moves points by a few hundredths of a pixel typically, up to
    ~0.5 px at end systole, and changes Twist by less than 0.02 deg.

    Parameters
    ----------
    P : ndarray, shape (n, 2)
        The line's tracked points, px (c, r).
    k : ndarray, shape (2,)
        The family's harmonic peak (the tag normal), cycles/pixel.
    deg : int, optional
        The polynomial degree (default :data:`TAG_CURVE_DEGREE`).

    Returns
    -------
    ndarray, shape (n, 2)
        The points on the fitted curve, px (c, r), at their own positions along the tag.
    """
    khat = k / np.linalg.norm(k)
    along = np.array([-khat[1], khat[0]])
    u, o = P @ along, P @ khat
    c = np.polyfit(u, o, deg)
    return u[:, None] * along + np.polyval(c, u)[:, None] * khat


def myocardial_window(crop: np.ndarray, myo_masks: list[np.ndarray | None],
                      drawn: list[bool] | None = None) -> np.ndarray:
    """Frames (T, rows, columns) with everything outside the myocardium set to the
    myocardium's mean intensity (the image HARP band-passes; see module docstring, step 2).

    The Gaussian band-pass has a support of a few pixels: next to the bright blood pool or
    the RV, the edge's own spectrum at the tag frequency adds to the harmonic and biases the
    phase by up to half a spacing — and the bias moves with the wall, so phase-invariant
    tracking follows it (tag jumps near the endocardium at end systole). Inside the myocardium
    the tags are a truncated sinusoid, whose band-passed phase stays that of the tags up to
    the border. A frame whose myocardium is borrowed from a neighbouring frame
    (``drawn[t]`` False) keeps ``WINDOW_BORROWED_PX`` more pixels around it; a frame without
    one (None) is left as it is.

    Parameters
    ----------
    crop : ndarray, shape (T, rows, columns)
        The cropped frames of one slice.
    myo_masks : list of (ndarray of bool or None)
        Per frame, the myocardium pixels of the crop (None: none known).
    drawn : list of bool, optional
        Per frame, whether its myocardium was drawn (not borrowed).

    Returns
    -------
    ndarray of float, shape (T, rows, columns)
        The windowed frames.
    """
    out = np.array(crop, float)
    for t, m in enumerate(myo_masks):
        if m is None or not m.any():
            continue
        if drawn is not None and not drawn[t]:
            m = binary_dilation(m, iterations=WINDOW_BORROWED_PX)
        mu = float(out[t][m].mean())
        out[t][~m] = mu
    return out


def track_slice(frames_px: np.ndarray, images: list[ImagePlane], myos: list[Myocardium],
                geom: SliceGeometry, tag_planes: dict[str, TagPlanes], box,
                study_contours=None) -> SliceTracking:
    """HARP tracking of one slice's tag lines through its frames (module docstring, 2–6).

    Parameters
    ----------
    frames_px : ndarray, shape (T, rows, columns)
        The slice's tagged frames (full images).
    images : list of cardionurbs.imaging.geometry.ImagePlane
        Their image planes, one per frame.
    myos : list of Myocardium or None
        Per frame, the LV myocardium (None: the frame is not tracked).
    geom : SliceGeometry
        The slice's tag families.
    tag_planes : dict of str to TagPlanes
        The study's tag planes (line indices).
    box : tuple of int
        The crop (row0, row1, col0, col1), in px.
    study_contours : list, optional
        :func:`slice_contours_px` of the slice, for the temporal prior.

    Returns
    -------
    SliceTracking
        The tracked line pieces and notes.
    """
    plane = images[0]
    offset = np.array([box[2], box[0]], float)
    crop, inner, masks, hs_by_fam = _harmonic_series(frames_px, myos, geom, box)
    # fading: median myocardial harmonic magnitude per frame over the first frame's
    ref = {fam: float(np.median(np.abs(hs.baseband[0])[inner[0]])) for fam, hs in hs_by_fam.items()}
    T, notes = _frames_tracked(images, inner, hs_by_fam, ref)
    first = _first_frame_lines(hs_by_fam, geom, myos[0], box, masks[0], plane, tag_planes, crop[0],
                               max_line_offset=ON_PLANE_LINE)
    if not first:
        return SliceTracking([], notes + [f"slice {plane.slice}: no tag line in the myocardium"], T)
    fam_list = list(hs_by_fam)
    seeds = np.vstack([piece for _, _, piece, _ in first])
    fam_of = np.concatenate([np.full(len(piece), fam_list.index(fam)) for fam, _, piece, _ in first])
    index_of = np.concatenate([np.full(len(piece), idx) for _, idx, piece, _ in first])
    X, R = harp.track([hs_by_fam[f] for f in fam_list], seeds, frames=T,
                      prior=_contour_prior(study_contours, offset) if study_contours else None)
    run = _SliceRun(images, myos, masks, crop, offset, hs_by_fam, fam_list, first, X, R, fam_of,
                    index_of)
    # each line's last seen points and frame: the prediction at the next frame moves them by the
    # median HARP displacement of the line's tracked points since then (robust to a few slips)
    last: dict[tuple[int, int], tuple[int, np.ndarray]] = {}
    for fam, idx, piece, _ in first:
        fi = fam_list.index(fam)
        prev = last.get((fi, idx))
        last[(fi, idx)] = (0, piece if prev is None else np.vstack([prev[1], piece]))
    lines: list[tuple] = []
    for t in range(T):
        if myos[t] is None:
            continue
        for fi, fam in enumerate(fam_list):
            if (fam_of == fi).any():
                lines += run.frame_lines(t, fi, last, ref[fam])
    return SliceTracking(lines, notes, T)


def _harmonic_series(frames_px: np.ndarray, myos: Sequence[Myocardium | None], geom: SliceGeometry,
                     box):
    """The slice's frames cropped to ``box`` and myocardially windowed (T, h, w), the
    myocardium masks per frame (crop px; the second list dilated by 3 px; None where the frame
    has none) and each family's harmonic series of the windowed crops."""
    r0, r1, c0, c1 = box
    crop = frames_px[:, r0:r1, c0:c1]
    inner = [_grid_mask(m, box, 0) if m is not None else None for m in myos]
    # the harmonic phase and the tag trough are both taken on the windowed frames (outside
    # the myocardium the dark lung would otherwise pass for a tag trough)
    crop = myocardial_window(crop, inner, [m is None or m.drawn for m in myos])
    spectra = sfft.fft2(crop, axes=(-2, -1))
    hs_by_fam = {fam: harp.HarmonicSeries.from_images(crop, geom.k[fam], spectra=spectra)
                 for fam in geom.k}
    masks = [binary_dilation(m, iterations=3) if m is not None else None for m in inner]
    return crop, inner, masks, hs_by_fam


def _frames_tracked(images: list[ImagePlane], inner: list, hs_by_fam: dict,
                    ref: dict[str, float]) -> tuple[int, list[str]]:
    """How many frames the slice is tracked through, and why it stops earlier: the first frame
    without an LV contour (the slice has left the ventricle) or whose median myocardial
    harmonic magnitude has fallen below ``FADED`` of the first frame's (``ref``)."""
    slc = images[0].slice
    for t in range(1, len(images)):
        if inner[t] is None:
            # the slice has left the ventricle (basal slices in systole): its material points
            # cannot be followed through tissue that is not there, so tracking stops
            return t, [f"slice {slc}: no LV contour at frame {images[t].frame}; tracked "
                       f"up to frame {images[t - 1].frame}"]
        ratio = min(float(np.median(np.abs(hs.baseband[t])[inner[t]])) / ref[fam]
                    for fam, hs in hs_by_fam.items())
        if ratio < FADED:
            return t, [f"slice {slc}: tags faded below {FADED:.0%} of the first frame's "
                       f"harmonic magnitude at frame {images[t].frame}; tracked up to frame "
                       f"{images[t - 1].frame}"]
    return len(images), []


@dataclass
class _SliceRun:
    """One slice's HARP run in :func:`track_slice`: crops, masks and harmonic series per frame,
    the first frame's lines and their points tracked through the frames."""

    images: list[ImagePlane]
    myos: list
    masks: list
    crop: np.ndarray            #: (T, h, w) windowed frames
    offset: np.ndarray          #: (2,) crop origin in image px (column, row)
    hs_by_fam: dict
    fam_list: list[str]
    first: list                 #: [(family, index, points crop px, offset)] at the first frame
    X: np.ndarray               #: (T, n, 2) tracked seed points, crop px
    R: np.ndarray               #: (T, n) wrapped phase residual of each, rad
    fam_of: np.ndarray          #: (n,) family number of each seed
    index_of: np.ndarray        #: (n,) tag index of each seed

    def frame_lines(self, t: int, fi: int, last: dict, mag_ref: float) -> list[tuple]:
        """Family ``fi``'s lines at frame ``t``: [(family, index, frame, points image px,
        magnitude, phase_residual)]; ``last`` (line -> (frame, points)) updated."""
        fam = self.fam_list[fi]
        hs = self.hs_by_fam[fam]
        sel = self.fam_of == fi
        by_index: dict[int, list[np.ndarray]] = defaultdict(list)
        emitted: dict[int, list[np.ndarray]] = defaultdict(list)
        if t == 0:
            for f_, idx, p, _ in self.first:
                if f_ == fam:
                    by_index[idx].append(p)
        elif len(self.fam_list) == 2:
            self._grid_lines(t, hs, sel, by_index, emitted)
        else:
            self._isophase_lines(t, fi, hs, sel, last, by_index)
        out = []
        for idx, ps in by_index.items():
            P = _order_along(np.vstack(ps), hs.k)
            if len(P) < MIN_LINE_POINTS:
                continue
            last[(fi, idx)] = (t, P)
            mag = float(np.median(hs.sample(t, P)[2])) / mag_ref
            # SA: the points the line is made of; LA (iso-phase lines): the index's seeds
            mine = np.concatenate(emitted[idx]) if emitted.get(idx) else \
                np.flatnonzero(sel & (self.index_of == idx))
            res = float(np.sqrt(np.mean(self.R[t, mine] ** 2))) if len(mine) else float("nan")
            out.append((fam, idx, self.images[t].frame, P + self.offset, mag, res))
        return out

    def _grid_lines(self, t: int, hs, sel: np.ndarray, by_index: dict, emitted: dict) -> None:
        """Grids (SA): each line is its tracked material points (both phases pin them), kept
        inside the frame's myocardium and moved onto the tag trough."""
        reach = TROUGH_REACH * (1.0 / np.linalg.norm(hs.k))     # spacings -> px
        X, myo = self.X, self.myos[t]
        for idx in np.unique(self.index_of[sel]):
            mine = np.flatnonzero(sel & (self.index_of == idx) & (self.R[t] <= CONVERGED_RAD))
            if not len(mine):
                continue
            mine = mine[_order_along_index(X[t, mine], hs.k)]
            P = X[t, mine]
            if REFINE:
                P = harp.trough_refine(self.crop[t], P, hs.sample(t, P)[1], reach)
            ok = myo.contains(P + self.offset, BORDER_MARGIN_PX)
            P, mine = P[ok], mine[ok]
            ok = _on_one_tag(P, hs.k)
            P, mine = P[ok], mine[ok]
            if TAG_CURVE_DEGREE is not None and len(P) >= TAG_CURVE_DEGREE + 3:
                P = tag_curve(P, hs.k, TAG_CURVE_DEGREE)
            if len(P):
                by_index[int(idx)].append(P)
                emitted[int(idx)].append(mine)

    def _isophase_lines(self, t: int, fi: int, hs, sel: np.ndarray, last: dict,
                        by_index: dict) -> None:
        """LA views: the iso-phase lines of frame ``t``, each point labelled by the nearest line
        predicted from its last frame plus the whole spacings between them."""
        period = 1.0 / np.linalg.norm(hs.k)
        pred, pred_idx = [], []
        for key in [key for key in last if key[0] == fi]:
            t0, P0 = last[key]
            mine = sel & (self.index_of == key[1])
            shift = np.median(self.X[t, mine] - self.X[t0, mine], axis=0) if mine.any() else 0.0
            pred.append(P0 + shift)
            pred_idx.append(np.full(len(P0), key[1]))
        tree = cKDTree(np.vstack(pred))
        pidx = np.concatenate(pred_idx)
        khat = hs.k / np.linalg.norm(hs.k)
        for piece in _isolines_in_myocardium(hs, t, self.myos[t], self.offset, self.masks[t],
                                             self.crop[t]):
            # each point's index: its nearest predicted line point's index plus the
            # whole spacings between them along k (a line that enters the slice later,
            # by through-plane motion, gets its own index, not its neighbour's)
            _, j = tree.query(piece)
            o = ((piece - tree.data[j]) @ khat) / period
            n = np.round(o)
            idx_pt = pidx[j] + n.astype(int)
            ok = np.abs(o - n) <= ON_LINE
            if ok.sum() < 2:
                continue
            vals, counts = np.unique(idx_pt[ok], return_counts=True)
            idx = int(vals[np.argmax(counts)])
            keep = ok & (idx_pt == idx)
            if keep.sum() >= 2:
                by_index[idx].append(piece[keep])


# ------------------------------------------------------------------ study
def _index_origins(firsts: dict[str, list], planes_by_fam: dict[str, TagPlanes]) -> None:
    """index0 for families the study gives none: circular mean of p mod d, then the lowest
    index shifted to 0 (``firsts``: family -> positions p along N of every first-frame line)."""
    for fam, ps in firsts.items():
        tp = planes_by_fam[fam]
        if tp.index0 is not None or not ps:
            continue
        p = np.asarray(ps)
        ang = 2 * np.pi * p / tp.spacing
        c = float(np.angle(np.exp(1j * ang).mean())) * tp.spacing / (2 * np.pi)
        lowest = np.floor((p.min() - c) / tp.spacing + 0.5)
        tp.index0 = c + lowest * tp.spacing


def track_tags(study: Study, slices: list[str] | None = None,
               labels: "Study | str | Path | None" = None) -> Study:
    """A copy of ``study`` whose tag lines are tracked from its tagged DICOM images (HARP).

    See the module docstring. Every slice with DICOM files and LV epicardial contours is
    tracked (or those named in ``slices``); the study's own tag lines (if any) are replaced. ``meta["tag_tracking"]`` records
    the per-slice geometry and the per-line confidence. Raises :class:`TagTrackingError`
    (untagged or faded series, spacing or orientation far from the expected) or
    :class:`StudyError` (missing DICOM files), naming file, slice and frame.

    Parameters
    ----------
    study : Study
        A study whose images name tagged DICOM files (:func:`cardionurbs.io.load_study`).
    slices : list of str or None
        Only these slice ids; None: every slice with DICOM files and LV epicardial contours.
    labels : Study, str, pathlib.Path or None
        The study's segmentation as NIfTI label maps (a study read by
        :func:`cardionurbs.io.nifti.read_study`, or its path) on the tagged images' pixel grid
        (:mod:`cardionurbs.tracking.labelmaps`): the myocardial window and the clipping of the
        lines then use the label maps' myocardium pixels, and the crop and the temporal prior
        their contours, in every slice they cover; the other slices keep the study's contours.

    Returns
    -------
    Study
        A copy of ``study`` with the tracked :class:`~cardionurbs.study.TagLine` s (scanner
        mm) and ``meta["tag_tracking"]``.

    Raises
    ------
    TagTrackingError
        An untagged or faded series, or a tag spacing or orientation far from the expected.
    StudyError
        Missing DICOM files (naming file, slice and frame).
    """
    by_slice = _tracked_slices(study, slices)
    expected = expected_tag_planes(study)
    lm = load_label_maps(study, labels) if labels is not None else None
    work, notes = _prepare_slices(study, by_slice, expected, lm)
    planes_by_fam = _study_tag_planes(work, expected)
    tags: list[TagLine] = []
    rec = defaultdict(list)
    series = {}
    for slc, images, myos, geom, box, pix in work:
        lslice = lm.contours_slice(slc) if lm is not None else None
        res = track_slice(pix, images, myos, geom, planes_by_fam, box,
                          slice_contours_px(lm.study, images, lslice) if lm is not None and lslice
                          else slice_contours_px(study, images))
        notes += res.notes
        frame_image = {im.frame: im for im in images}
        for fam, idx, frame, P, mag, phres in res.lines:
            im = frame_image[frame]
            tags.append(TagLine(fam, idx, im.view, slc, frame, im.pixel_to_scanner(P), image=im.id))
            for key, v in (("family", fam), ("index", idx), ("slice", slc), ("frame", frame),
                           ("magnitude", round(mag, 4)),
                           ("phase_residual", None if not np.isfinite(phres) else round(phres, 4))):
                rec[key].append(v)
        series[slc] = {"spacing_mm": {f: round(v, 4) for f, v in geom.spacing_mm.items()},
                       "normal": {f: [round(float(x), 6) for x in v] for f, v in geom.normal.items()},
                       "peak_contrast": {f: round(v, 2) for f, v in geom.contrast.items()},
                       "frames_tracked": res.frames_tracked}
    # duplicates (two pieces voted into one index are merged above; one index per line)
    meta = dict(study.meta)
    meta["tag_tracking"] = {
        "method": "HARP (Osman et al. 1999/2000), cardionurbs.tracking",
        "myocardium": (f"label maps {lm.study.source} ({lm.study.meta.get('labels')})"
                       if lm is not None else "the study's contours"),
        "tag_planes": {f: {"normal": [float(x) for x in tp.normal], "spacing_mm": tp.spacing,
                           "index0_mm": tp.index0} for f, tp in planes_by_fam.items()},
        "series": series, "lines": dict(rec), "notes": notes}
    return dataclasses.replace(study, tags=tags, meta=meta, warnings=list(study.warnings) + notes)


def _tracked_slices(study: Study, slices: list[str] | None) -> dict[str, list[ImagePlane]]:
    """The images of every slice to track (those with DICOM files; of ``slices`` when given);
    :class:`TagTrackingError` for a label-map study, a study without a folder or DICOM files."""
    if isinstance(study.meta, dict) and study.meta.get("format") == "nifti":
        raise TagTrackingError("this study was read from label maps, which hold no tagged "
                               "images: track the tagged DICOM study and give the label maps "
                               "as its labels (cardionurbs track STUDY --label-maps PATH)",
                               file=study.source, field="images")
    if not study.source:
        raise TagTrackingError("the study has no folder, so its DICOM images cannot be found",
                               field="images")
    by_slice = _slice_images(study)
    if slices is not None:
        by_slice = {s: v for s, v in by_slice.items() if s in set(slices)}
    if not by_slice:
        raise TagTrackingError("no image of this study names a DICOM file", file=study.source,
                               field="images")
    return by_slice


def _prepare_slices(study: Study, by_slice: dict[str, list[ImagePlane]],
                    expected: dict[str, TagPlanes], lm: LabelMaps | None) -> tuple[list[list], list[str]]:
    """Per trackable slice (SA first): [slice, images, myocardium per frame, geometry, crop
    box, pixels (T, rows, columns)], the geometry resolved per group of parallel slices
    (:func:`resolve_geometry`); and notes on the slices left out or clipped by contours."""
    folder = _study_folder(study)
    work: list[list] = []
    notes: list[str] = []
    order = sorted(by_slice, key=lambda s: (by_slice[s][0].view != "SA", s))
    groups: dict[str, list] = defaultdict(list)
    for slc in order:
        images = by_slice[slc]
        lslice = lm.contours_slice(slc) if lm is not None else None
        if lm is not None and lslice is None:
            notes.append(f"slice {slc}: on no label map's pixel grid; clipped by the study's "
                         "contours")
        myos = _masks(study, images, lm)
        if myos[0] is None:
            notes.append(f"slice {slc}: no lv_epi {'label' if lslice else 'contour'} at its "
                         "first frame; not tracked")
            continue
        pix = _read_frames(study, images)
        box = _crop_box(lm.study, images, lslice) if lm is not None and lslice else _crop_box(study, images)
        first = pix[0, box[0]:box[1], box[2]:box[3]]
        path = folder / str(images[0].file)
        peaks = first_frame_peaks(first, images[0], path, expected)
        groups["SA" if images[0].view == "SA" else slc].append((images[0], path, peaks))
        work.append([slc, images, myos, None, box, pix])
    geoms: dict[str, SliceGeometry] = {}
    for g in groups.values():
        geoms.update(resolve_geometry(g, expected))
    for w in work:
        w[3] = geoms[w[0]]
    return work, notes


def _study_tag_planes(work: list[list], expected: dict[str, TagPlanes]) -> dict[str, TagPlanes]:
    """The 3-D tag planes per family: the expected ones, else from the measured directions and
    spacings, with index0 from the first-frame lines (:func:`_index_origins`) where unknown."""
    planes_by_fam: dict[str, TagPlanes] = {}
    for fam in ("sa1", "sa2", "la"):
        geoms = [g for _, _, _, g, _, _ in work if fam in g.normal]
        if not geoms:
            continue
        if fam in expected:
            planes_by_fam[fam] = dataclasses.replace(expected[fam])
        else:
            n = np.sum([g.normal[fam] for g in geoms], axis=0)
            planes_by_fam[fam] = TagPlanes(n / np.linalg.norm(n),
                                           float(np.median([g.spacing_mm[fam] for g in geoms])), None)
    if any(tp.index0 is None for tp in planes_by_fam.values()):
        positions: dict[str, list] = defaultdict(list)
        for slc, images, myos, geom, box, pix in work:
            crop = pix[:1, box[0]:box[1], box[2]:box[3]]
            hs = {f: harp.HarmonicSeries.from_images(crop, geom.k[f]) for f in geom.k}
            probe = {f: TagPlanes(planes_by_fam[f].normal, planes_by_fam[f].spacing, 0.0)
                     for f in geom.k}
            for fam, idx, piece, frac in _first_frame_lines(hs, geom, myos[0], box,
                                                            _grid_mask(myos[0], box), images[0], probe):
                positions[fam].append((idx + frac) * planes_by_fam[fam].spacing)
        _index_origins(positions, planes_by_fam)
    return planes_by_fam


# ------------------------------------------------------------------ output
def _link_or_copy(src: Path, dst: Path) -> None:
    import os
    import shutil
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def write_tracked_study(study: Study, out: str | Path) -> Path:
    """Write a tracked study as a native study folder ``out``, atomically (complete or absent;
    the CLI checks ``out`` first with :func:`cardionurbs.io.outputs.check_output_dir`).

    The DICOM files it references are hard-linked (copied across file systems) beside it under
    the same relative paths, and ``truth.json`` (phantoms) with them, so the folder stands alone.

    Parameters
    ----------
    study : cardionurbs.study.Study
        A study returned by :func:`track_tags`.
    out : path-like
        The new study folder (must not be the study's own).

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    cardionurbs.errors.StudyError
        ``out`` is the study's own folder.
    """
    src = _study_folder(study)
    out = Path(out)
    if out.resolve() == src.resolve():
        raise StudyError("the output folder is the study itself; give another --out", file=out,
                         field="--out")
    with atomic.atomic_dir(out) as tmp:
        for im in study.images:
            if im.file and (src / im.file).is_file():
                _link_or_copy(src / im.file, tmp / im.file)
        if isinstance(study.meta.get("truth"), str) and (src / study.meta["truth"]).is_file():
            _link_or_copy(src / study.meta["truth"], tmp / study.meta["truth"])
        write_study(study, tmp)
    return out


def run_track(args) -> int:
    """``cardionurbs track STUDY --out DIR [--label-maps PATH]``: the study with its tag lines
    tracked from its tagged DICOM (:func:`track_tags`; with ``--label-maps`` clipped to the
    label maps' myocardium pixels), written as a native study (exit 2 on bad input).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line: ``study``, ``out``, ``label_maps``, ``overwrite``,
        ``allow_outside``.

    Returns
    -------
    int
        The exit code, 0.

    Raises
    ------
    cardionurbs.errors.OutputError
        ``--out`` may not be written.
    cardionurbs.errors.StudyError
        The study cannot be read.
    cardionurbs.errors.TagTrackingError
        No tag pattern can be tracked.
    """
    import sys
    given = Path(args.study)
    folder = given if given.is_dir() or not given.exists() else given.parent
    labels = getattr(args, "label_maps", None)
    check_output_dir(args.out, inputs=[folder] + ([Path(labels)] if labels else []),
                     overwrite=getattr(args, "overwrite", False))
    study = load_study(args.study, allow_outside=getattr(args, "allow_outside", False))
    tracked = track_tags(study, labels=labels)
    write_tracked_study(tracked, args.out)
    info = tracked.meta["tag_tracking"]
    n_slices = len(info["series"])
    print(f"{tracked.subject}: {len(tracked.tags)} tag lines tracked on {n_slices} slices "
          f"({len(tracked.tagged_frames)} frames); wrote {args.out}", file=sys.stdout)
    for note in info["notes"]:
        print(f"note: {note}", file=sys.stdout)
    return 0
