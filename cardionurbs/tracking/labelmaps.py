"""The LV myocardium of a tagged study's images from NIfTI label maps (pixels, not contours).

A study whose segmentation is a set of label maps (:mod:`cardionurbs.io.nifti`: one file, or
the ACDC, UK Biobank and M&Ms layouts; the phantom writes them with ``--labels``) gives the
tracker its myocardium as the label maps' myocardium pixels: the myocardial window before the
band-pass and the clipping of every tag line use those pixels, and the label study's contours
(traced from the same maps) give the crop and the temporal prior.

Each tagged (DICOM) slice is matched to the label-map slice on the same pixel grid: same
matrix size, pixel spacing within 0.1 %, row and column cosines within 1e-3 and
ImagePositionPatient within 5 % of a pixel. A tagged slice no label slice matches keeps the
tagged study's own contours, if it has any (:func:`cardionurbs.tracking.track.track_tags`
notes it). Frames are matched by their index.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy import ndimage

from cardionurbs.errors import StudyError, TagTrackingError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.study import Study

POSITION_TOL = 0.05        # pixels
COSINE_TOL = 1e-3
SPACING_TOL = 1e-3         # relative


def same_grid(a: ImagePlane, b: ImagePlane) -> bool:
    """True when two image planes share their pixel grid (size, spacing, orientation, origin).

    Parameters
    ----------
    a, b : cardionurbs.imaging.geometry.ImagePlane
        The two images.

    Returns
    -------
    bool
        Same matrix size, pixel spacing within :data:`SPACING_TOL` (relative), cosines within
        :data:`COSINE_TOL` and ImagePositionPatient within :data:`POSITION_TOL` pixels.
    """
    if (a.rows, a.columns) != (b.rows, b.columns):
        return False
    sa, sb = np.asarray(a.pixel_spacing, float), np.asarray(b.pixel_spacing, float)
    if np.any(np.abs(sa / sb - 1.0) > SPACING_TOL):
        return False
    if (np.abs(np.asarray(a.row_cosine) - b.row_cosine).max() > COSINE_TOL
            or np.abs(np.asarray(a.column_cosine) - b.column_cosine).max() > COSINE_TOL):
        return False
    return float(np.linalg.norm(np.asarray(a.position) - b.position)) <= POSITION_TOL * float(sa.min())


def signed_border_distance(mask: np.ndarray) -> np.ndarray:
    """Signed distance (px) of every pixel centre to the border of ``mask`` (rows, columns):
    positive inside, negative outside; the border runs between the pixels, half a pixel from
    the centres next to it (Euclidean distance transform, scipy.ndimage).

    Parameters
    ----------
    mask : ndarray of bool, shape (rows, columns)
        The region's pixels.

    Returns
    -------
    ndarray of float, shape (rows, columns)
        The signed distance in px (> 0 inside).
    """
    inside = ndimage.distance_transform_edt(mask)
    outside = ndimage.distance_transform_edt(~mask)
    return np.where(mask, inside - 0.5, 0.5 - outside)


@dataclass
class LabelMyocardium:
    """Myocardium pixels of one image (rows, columns) of a label map, with the signed
    distance to their border for the clipping margin.

    Parameters
    ----------
    pixels : ndarray of bool, shape (rows, columns)
        The myocardium pixels of one tagged image.
    """

    pixels: np.ndarray

    @cached_property
    def signed_distance(self) -> np.ndarray:
        """Signed distance (px) of every pixel centre to the myocardium's border: > 0 inside."""
        return signed_border_distance(self.pixels)

    def distance(self, pts: np.ndarray) -> np.ndarray:
        """Signed distance (px, bilinear between pixel centres) of points (n, 2) (c, r) to the
        border of the myocardium pixels: > 0 inside.

        Parameters
        ----------
        pts : ndarray, shape (n, 2)
            Pixel positions (column c, row r), sub-pixel.

        Returns
        -------
        ndarray, shape (n,)
            The signed distance in px (> 0 inside).
        """
        return ndimage.map_coordinates(self.signed_distance, [pts[:, 1], pts[:, 0]], order=1,
                                       mode="nearest")


def _myo_value(label_study: Study) -> int:
    m = re.search(r"\bmyo=(\d+)", str(label_study.meta.get("labels", "")))
    if not m:
        raise TagTrackingError("the label-map study does not say which label is the myocardium",
                               file=label_study.source, field="labels")
    return int(m.group(1))


class LabelMaps:
    """A label-map study's myocardium pixels, by tagged slice and frame.

    ``LabelMaps(tagged, label_study)`` pairs every slice of ``tagged`` (the study whose images
    name the tagged DICOM) with the slice of ``label_study`` (read by
    :func:`cardionurbs.io.nifti.read_study`) on the same pixel grid.

    Parameters
    ----------
    tagged : cardionurbs.study.Study
        The tagged study (its images are the tagged DICOM).
    label_study : cardionurbs.study.Study
        The label-map study (``meta["format"] == "nifti"``, ``labels`` naming ``myo=<value>``).

    Attributes
    ----------
    slice_of : dict of str to str
        Tagged slice id -> the label study's slice id on the same grid.
    frames : set of int
        The label study's frames (0-based) with an LV epicardium.

    Raises
    ------
    cardionurbs.errors.TagTrackingError
        ``label_study`` is not read from NIfTI label maps, has no folder, or does not say
        which label is the myocardium.
    """

    def __init__(self, tagged: Study, label_study: Study) -> None:
        if label_study.meta.get("format") != "nifti":
            raise TagTrackingError("the myocardium labels must be a study read from NIfTI label "
                                   "maps", file=label_study.source, field="labels")
        self.study = label_study
        self.myo = _myo_value(label_study)
        if not label_study.source:
            raise TagTrackingError("the label maps' study has no folder", field="labels")
        src = Path(label_study.source)
        self.folder = src if src.is_dir() else src.parent
        self._volumes: dict[str, object] = {}
        first: dict[str, ImagePlane] = {}
        for im in sorted(label_study.images, key=lambda i: i.frame):
            first.setdefault(im.slice, im)
        self.slice_of: dict[str, str] = {}
        for im in sorted(tagged.images, key=lambda i: i.frame):
            if im.slice in self.slice_of:
                continue
            hit = [s for s, lim in first.items() if lim.view == im.view and same_grid(im, lim)]
            if hit:
                self.slice_of[im.slice] = hit[0]
        self._by_key = {(im.slice, im.frame): im for im in label_study.images}
        self.frames = {c.frame for c in label_study.contours if c.structure == "lv_epi"}

    def _volume(self, name: str):
        from cardionurbs.io.nifti import read_label_volume
        vol = self._volumes.get(name)
        if vol is None:
            path = self.folder / name
            if not path.is_file():
                raise StudyError("label map named by the study is missing", file=path,
                                 field="labels")
            vol = self._volumes[name] = read_label_volume(path)
        return vol

    def pixels(self, slice_id: str, frame: int) -> np.ndarray | None:
        """Myocardium pixels (rows, columns) of the tagged slice ``slice_id`` at ``frame``, or
        None when the label maps have no such slice or frame, or no myocardium there.

        Parameters
        ----------
        slice_id : str
            The tagged study's slice id.
        frame : int
            The frame index, 0-based.

        Returns
        -------
        ndarray of bool, shape (rows, columns) or None
            The myocardium pixels, or None (see above).

        Raises
        ------
        cardionurbs.errors.StudyError
            The label map file named by the study is missing or unreadable.
        """
        lslice = self.slice_of.get(slice_id)
        lim = self._by_key.get((lslice, frame)) if lslice is not None else None
        if lim is None or not lim.file:
            return None
        vol = self._volume(lim.file)
        a = vol.affine
        k = int(round(float((np.asarray(lim.position) - a[:3, 3]) @ a[:3, 2] / (a[:3, 2] @ a[:3, 2]))))
        t = frame if vol.data.shape[3] > 1 else 0
        if not (0 <= k < vol.data.shape[2] and 0 <= t < vol.data.shape[3]):
            return None
        m = vol.data[:, :, k, t].T == self.myo          # (x = column, y = row) -> (rows, columns)
        return m if m.any() else None

    def contours_slice(self, slice_id: str) -> str | None:
        """The label study's slice id matched to the tagged slice ``slice_id``.

        Parameters
        ----------
        slice_id : str
            The tagged study's slice id.

        Returns
        -------
        str or None
            The label study's slice id, None when no label slice lies on its grid.
        """
        return self.slice_of.get(slice_id)


def load_label_maps(tagged: Study, labels: "Study | str | Path") -> LabelMaps:
    """:class:`LabelMaps` from a label-map study or its path (any :mod:`cardionurbs.io.nifti`
    layout); a TagTrackingError when no slice of ``tagged`` lies on a label map's grid.

    Parameters
    ----------
    tagged : cardionurbs.study.Study
        The tagged study.
    labels : cardionurbs.study.Study, str or path-like
        The label-map study, or the path of its NIfTI file or folder.

    Returns
    -------
    LabelMaps
        The pairing of tagged and label slices.

    Raises
    ------
    cardionurbs.errors.TagTrackingError
        No tagged slice lies on a label map's grid, or the labels are unusable (see
        :class:`LabelMaps`).
    cardionurbs.errors.StudyError
        ``labels`` cannot be read as a label-map study.
    """
    if not isinstance(labels, Study):
        from cardionurbs.io.nifti import read_study
        labels = read_study(labels)
    lm = LabelMaps(tagged, labels)
    if not lm.slice_of:
        raise TagTrackingError("no tagged slice lies on the pixel grid of a label-map slice (the "
                               "label maps must be segmentations of the tagged images)",
                               file=labels.source, field="labels")
    return lm
