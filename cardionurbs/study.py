"""The in-memory study: image planes, contours, tag lines and landmarks in scanner mm.

A :class:`Study` is what every reader produces (DICOM + native, Sunnybrook,
CAP GPFile, phantom) and what reconstruction consumes. All coordinates are
scanner (patient LPS) millimetres; pixel coordinates live only in the files.

Vocabulary
----------
structures (``Contour.structure``)
    ``lv_endo``, ``lv_epi``, ``rv_endo``, ``rv_epi`` — closed in SA views;
    ``rv_septum`` and ``rv_freewall`` — the two open parts of an RV
    endocardial contour as CAP guide points give it; ``rv_outlet`` — the RV
    endocardium of the outflow tract above the tricuspid valve (CAP
    ``SAX_RV_OUTLET``).
other structures (``OTHER_STRUCTURES``)
    atria, veins and long-axis extents as CAP tools trace them (``la``,
    ``ra``, ``laa``, ``lpv``, ``rpv``, ``svc``, ``ivc``, ``la_extent``,
    ``ra_extent``, ``lv_extent``, ``rv_extent``): kept, never used for the
    ventricles.
tag families (``TagLine.family``)
    ``sa1``, ``sa2`` — the two orthogonal SA families of tag planes (parallel
    to the long axis), seen as lines in SA images; ``la`` — the planes
    perpendicular to the long axis, seen as lines in LA images.
landmarks (``Landmark.name``)
    ``apex``, ``mitral``, ``tricuspid``, ``aortic``, ``pulmonary``,
    ``rv_insert`` (several points may share a name; ``index`` tells them apart).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from cardionurbs.cache import memoized
from cardionurbs.errors import StudyError
from cardionurbs.imaging.geometry import VIEWS, ImagePlane

STRUCTURES = ("lv_endo", "lv_epi", "rv_endo", "rv_epi", "rv_septum", "rv_freewall", "rv_outlet")
#: non-ventricular structures some CAP tools trace (kept in the Study, not reconstructed)
OTHER_STRUCTURES = ("la", "ra", "laa", "lpv", "rpv", "svc", "ivc", "la_extent", "ra_extent",
                    "lv_extent", "rv_extent")
CLOSED_STRUCTURES = ("lv_endo", "lv_epi", "rv_endo", "rv_epi")
TAG_FAMILIES = ("sa1", "sa2", "la")
LANDMARKS = ("apex", "mitral", "tricuspid", "aortic", "pulmonary", "rv_insert")


def _points(value, what: str, *, slice=None, frame=None, ndim: int = 3) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and ndim and arr.size == ndim:
        arr = arr.reshape(1, ndim)
    if arr.ndim != 2 or arr.shape[1] != ndim:
        raise StudyError(f"{what}: points must be an (n, {ndim}) array, got shape {arr.shape}",
                         slice=slice, frame=frame)
    if not np.all(np.isfinite(arr)):
        raise StudyError(f"{what}: points contain NaN or infinity", slice=slice, frame=frame)
    return arr


@dataclass(eq=False)
class Contour:
    """One delineated boundary on one image: (n, 3) scanner-mm points in drawing order.

    Attributes
    ----------
    structure : str
        One of :data:`STRUCTURES` (``lv_endo``, ``lv_epi``, ``rv_endo``, ``rv_epi``, the RV
        parts) or :data:`OTHER_STRUCTURES` (kept, not reconstructed).
    view : {"SA", "LA"}
        Short- or long-axis image.
    slice : str
        The slice id (the same at every frame).
    frame : int
        Cardiac frame index (0-based).
    points : (n, 3) ndarray of float
        Scanner (patient LPS) coordinates, mm, in drawing order.
    image : str or None
        Id of the :class:`~cardionurbs.imaging.geometry.ImagePlane` the contour lies on.
    closed : bool
        True for a closed loop (SA ``lv_endo`` etc.; the first point is not repeated at the
        end); LA contours and RV septum / free-wall parts are open.
    index : int
        Tells apart several pieces of one structure on one image.
    weights : (n,) ndarray of float or None
        Each point's fitting weight (>= 0) as the input gives it (CAP guide-point files);
        None means 1 for every point.

    Raises
    ------
    StudyError
        An unknown structure or view, points not (n, 3) finite numbers, or bad weights.
    """

    structure: str
    view: str
    slice: str
    frame: int
    points: np.ndarray
    image: str | None = None
    closed: bool = True
    index: int = 0
    weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.structure not in STRUCTURES + OTHER_STRUCTURES:
            raise StudyError(f"unknown structure {self.structure!r}; expected one of "
                             f"{', '.join(STRUCTURES + OTHER_STRUCTURES)}", slice=self.slice,
                             frame=self.frame, field="structure")
        if self.view not in VIEWS:
            raise StudyError(f"unknown view {self.view!r}", slice=self.slice, frame=self.frame,
                             field="view")
        self.frame = int(self.frame)
        self.points = _points(self.points, f"{self.structure} contour", slice=self.slice,
                              frame=self.frame)
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=float).reshape(-1)
            if w.shape != (len(self.points),) or not np.all(np.isfinite(w)) or np.any(w < 0):
                raise StudyError(f"{self.structure} contour: weights must be {len(self.points)} "
                                 "finite numbers >= 0", slice=self.slice, frame=self.frame,
                                 field="weight")
            self.weights = None if np.all(w == 1.0) else w

    @property
    def ventricular(self) -> bool:
        """True for the structures the ventricles are reconstructed from."""
        return self.structure in STRUCTURES


@dataclass(eq=False)
class TagLine:
    """One tracked tag line on one image: family, tag index, (n, 3) scanner-mm points.

    Attributes
    ----------
    family : {"sa1", "sa2", "la"}
        The tag plane family (:data:`TAG_FAMILIES`): two SA grid directions, the LA spokes.
    index : int
        The tag's index within its family (the same tag plane at every frame).
    view : {"SA", "LA"}
        The image view.
    slice : str
        The slice id.
    frame : int
        Cardiac frame index (0-based).
    points : (n, 3) ndarray of float
        Scanner coordinates, mm, along the line.
    image : str or None
        Id of the image plane the line lies on.

    Raises
    ------
    StudyError
        An unknown family or view, or points not (n, 3) finite numbers.
    """

    family: str
    index: int
    view: str
    slice: str
    frame: int
    points: np.ndarray
    image: str | None = None

    def __post_init__(self) -> None:
        if self.family not in TAG_FAMILIES:
            raise StudyError(f"unknown tag family {self.family!r}; expected one of "
                             f"{', '.join(TAG_FAMILIES)}", slice=self.slice, frame=self.frame,
                             field="family")
        if self.view not in VIEWS:
            raise StudyError(f"unknown view {self.view!r}", slice=self.slice, frame=self.frame,
                             field="view")
        self.frame, self.index = int(self.frame), int(self.index)
        self.points = _points(self.points, f"tag {self.family}#{self.index}", slice=self.slice,
                              frame=self.frame)


@dataclass(eq=False)
class Landmark:
    """An anatomical landmark point (scanner mm) at one frame.

    Attributes
    ----------
    name : str
        One of :data:`LANDMARKS` (``apex``, ``mitral``, ``tricuspid``, ``aortic``,
        ``pulmonary``, ``rv_insert``).
    frame : int
        Cardiac frame index (0-based).
    point : (3,) ndarray of float
        Scanner coordinates, mm.
    index : int
        Tells apart several points of one name on one slice.
    slice, view, image : str or None
        The slice, view and image the point was picked on, where known.

    Raises
    ------
    StudyError
        An unknown name, or a point that is not three finite numbers.
    """

    name: str
    frame: int
    point: np.ndarray
    index: int = 0
    slice: str | None = None
    view: str | None = None
    image: str | None = None

    def __post_init__(self) -> None:
        if self.name not in LANDMARKS:
            raise StudyError(f"unknown landmark {self.name!r}; expected one of "
                             f"{', '.join(LANDMARKS)}", slice=self.slice, frame=self.frame,
                             field="name")
        self.frame, self.index = int(self.frame), int(self.index)
        self.point = _points(self.point, f"landmark {self.name}", slice=self.slice,
                             frame=self.frame)[0]


@dataclass(eq=False)
class Study:
    """Everything known about one subject's scan, in scanner mm.

    Attributes
    ----------
    subject : str
        Study identifier (the cohort CSV's ``subject``).
    images : list of ImagePlane
        Every image plane (one per slice and frame) the annotations refer to.
    contours, tags, landmarks : lists
        Annotations, see :class:`Contour`, :class:`TagLine`, :class:`Landmark`.
    frame_times_ms : dict frame -> ms
        Trigger time of each frame, where known.
    heart_rate_bpm : float or None
        See docs/metrics.md (Frames).
    ed_frame, es_frame : int or None
        ED/ES labels given by the input (the label wins when only two frames
        are contoured).
    source : str or None
        Where the study was read from.
    meta : dict
        Free-form provenance (format, series descriptions, pathology...).
    warnings : list of str
        One-line warnings of the readers and input checks (``load_study`` fills
        it; ``analyze`` writes them to metrics.json as ``load`` warnings).
    """

    subject: str
    images: list[ImagePlane] = field(default_factory=list)
    contours: list[Contour] = field(default_factory=list)
    tags: list[TagLine] = field(default_factory=list)
    landmarks: list[Landmark] = field(default_factory=list)
    frame_times_ms: dict[int, float] = field(default_factory=dict)
    heart_rate_bpm: float | None = None
    ed_frame: int | None = None
    es_frame: int | None = None
    source: str | None = None
    meta: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    # ----------------------------------------------------------------- queries
    @property
    def frames(self) -> list[int]:
        """Sorted frame indices that carry images or annotations."""
        fr = {im.frame for im in self.images}
        fr |= {c.frame for c in self.contours} | {t.frame for t in self.tags}
        fr |= {lm.frame for lm in self.landmarks}
        return sorted(fr)

    @property
    def contoured_frames(self) -> list[int]:
        """Sorted frames that have at least one LV endocardial contour."""
        return sorted({c.frame for c in self.contours if c.structure == "lv_endo"})

    @property
    def tagged_frames(self) -> list[int]:
        """Sorted frames that have at least one tag line."""
        return sorted({t.frame for t in self.tags})

    def image(self, image_id: str) -> ImagePlane:
        """The image plane with this id.

        Parameters
        ----------
        image_id : str
            An :attr:`ImagePlane.id <cardionurbs.imaging.geometry.ImagePlane.id>`.

        Returns
        -------
        ImagePlane

        Raises
        ------
        StudyError
            No image of the study has this id (naming it).
        """
        idx = self._image_index()
        if image_id not in idx:
            raise StudyError(f"reference to image {image_id!r} that is not in the study",
                             file=self.source, field="image")
        return idx[image_id]

    @memoized(depends=("images",))
    def _image_index(self) -> dict[str, ImagePlane]:
        """{id: image}; made again when ``images`` is replaced or changes length."""
        return {im.id: im for im in self.images}

    def images_at(self, frame: int, view: str | None = None) -> list[ImagePlane]:
        """Image planes of one frame, in the order of ``images``.

        Parameters
        ----------
        frame : int
            Cardiac frame index.
        view : {"SA", "LA"} or None
            Only this view; None: both.

        Returns
        -------
        list of ImagePlane
        """
        return [im for im in self.images if im.frame == frame and (view is None or im.view == view)]

    def contours_at(self, frame: int, structure: str | Iterable[str] | None = None,
                    view: str | None = None) -> list[Contour]:
        """Contours of one frame, optionally of some structures and one view.

        Parameters
        ----------
        frame : int
            Cardiac frame index.
        structure : str, iterable of str, or None
            Only these structures (e.g. ``"lv_endo"``); None: every structure.
        view : {"SA", "LA"} or None
            Only this view; None: both.

        Returns
        -------
        list of Contour
            In the order of ``contours``.
        """
        if isinstance(structure, str):
            structure = (structure,)
        return [c for c in self._contour_index().get(frame, ())
                if (structure is None or c.structure in structure)
                and (view is None or c.view == view)]

    @memoized(depends=("contours",))
    def _contour_index(self) -> dict[int, list[Contour]]:
        """{frame: contours}, in the order of ``contours``; rebuilt when ``contours`` is
        replaced or changes length (as :meth:`_tag_index`)."""
        idx: dict[int, list[Contour]] = {}
        for c in self.contours:
            idx.setdefault(c.frame, []).append(c)
        return idx

    def tags_at(self, frame: int, family: str | None = None) -> list[TagLine]:
        """Tag lines of one frame (optionally of one family), in the order of ``tags``.

        Parameters
        ----------
        frame : int
            Cardiac frame index.
        family : {"sa1", "sa2", "la"} or None
            Only this tag family; None: every family.

        Returns
        -------
        list of TagLine
        """
        return list(self._tag_index().get((frame, family), ()))

    @memoized(depends=("tags",))
    def _tag_index(self) -> dict[tuple[int, str | None], list[TagLine]]:
        """{(frame, family or None): lines}, rebuilt when ``tags`` is replaced or changes
        length (the analysis asks for one frame's lines thousands of times: a scan of
        every line each time was quadratic in the study's size)."""
        idx: dict[tuple[int, str | None], list[TagLine]] = {}
        for t in self.tags:
            idx.setdefault((t.frame, None), []).append(t)
            idx.setdefault((t.frame, t.family), []).append(t)
        return idx

    def landmarks_at(self, frame: int, name: str | None = None) -> list[Landmark]:
        """Landmarks of one frame, in the order of ``landmarks``.

        Parameters
        ----------
        frame : int
            Cardiac frame index.
        name : str or None
            Only this landmark name (:data:`LANDMARKS`); None: every name.

        Returns
        -------
        list of Landmark
        """
        return [lm for lm in self.landmarks if lm.frame == frame and (name is None or lm.name == name)]

    def slice_plane(self, slice_id: str, frame: int | None = None) -> ImagePlane:
        """The plane of a slice.

        Parameters
        ----------
        slice_id : str
            The slice id.
        frame : int or None
            The plane at this frame; None: the first image of the slice (any frame, for a
            static slice).

        Returns
        -------
        ImagePlane

        Raises
        ------
        StudyError
            The slice has no image (at that frame).
        """
        for im in self.images:
            if im.slice == slice_id and (frame is None or im.frame == frame):
                return im
        raise StudyError("no image for this slice", file=self.source, slice=slice_id, frame=frame)

    def summary(self) -> str:
        """One line for logs: counts of what the study holds.

        Returns
        -------
        str
            ``"<subject>: <n> frames, <k> SA + <l> LA slices, ... landmarks"``.
        """
        views = sorted({(im.view, im.slice) for im in self.images})
        n_sa = sum(v == "SA" for v, _ in views)
        n_la = sum(v == "LA" for v, _ in views)
        return (f"{self.subject}: {len(self.frames)} frames, {n_sa} SA + {n_la} LA slices, "
                f"{len(self.contours)} contours, {len(self.tags)} tag lines, "
                f"{len(self.landmarks)} landmarks")
