"""The image NIfTI beside a label map, with the contours the label map gave drawn over it.

A label-map study (:mod:`cardionurbs.io.nifti`) may have its cine image beside the labels
(``study.meta["image_files"]``: ACDC ``patientNNN_4d``, UK Biobank ``sa``, M&Ms
``<code>_sa``). :func:`sa_overlay` reads the short-axis image of one slice and frame and
maps the study's contours of that slice (scanner LPS mm) into its pixel grid through the
image's own affine (NIfTI RAS+ -> LPS as in the reader), so the figure shows whether
the contours sit on the image's edges: an independent check of the geometry, since the
image and the labels are separate files with their own headers.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: image files of the layouts, short axis (the names :mod:`cardionurbs.io.nifti` records)
SA_IMAGE = re.compile(r"(sa|.+_4d|.+_sa)\.nii(\.gz)?", re.I)
RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


@dataclass
class SliceOverlay:
    """One SA image (columns, rows) and the contours on it in pixel coordinates (c, r).

    Attributes
    ----------
    slice : str
        The slice id (``"sa_04"``).
    frame : int
        The frame index, 0-based.
    image : ndarray of float, shape (columns, rows)
        The NIfTI image's voxels of that slice and frame (first voxel axis first).
    contours : dict of str to list of ndarray
        Structure (``"lv_endo"``, ``"lv_epi"``, ``"rv_endo"``) -> its contours on the slice,
        each (n, 2) in voxel coordinates (i, j) of ``image``.
    """

    slice: str
    frame: int
    image: np.ndarray
    contours: dict[str, list[np.ndarray]]


def sa_image_path(study) -> Path | None:
    """The short-axis image NIfTI beside a label-map study, or None.

    Parameters
    ----------
    study : cardionurbs.study.Study
        A study read from label maps (its ``meta["image_files"]`` and ``source``).

    Returns
    -------
    pathlib.Path or None
        The first short-axis image file (``sa.nii.gz``, ``*_4d.nii.gz``, ``*_sa.nii.gz``)
        that exists beside the label map; None when there is none.
    """
    names = [n for n in (study.meta.get("image_files") or []) if SA_IMAGE.fullmatch(n)]
    if not names or not study.source:
        return None
    src = Path(study.source)
    folder = src if src.is_dir() else src.parent
    path = folder / sorted(names)[0]
    return path if path.is_file() else None


def _image(path: Path):
    import nibabel as nib

    img = nib.load(str(path))
    code = int(img.header["sform_code"])
    aff = img.get_sform() if code > 0 else img.get_qform()
    return img, RAS_TO_LPS @ np.asarray(aff, float)


def sa_overlay(study, frame: int, slice_id: str | None = None) -> SliceOverlay | str:
    """The SA image of ``slice_id`` (default: the middle SA slice with an LV endocardium at
    ``frame``) at ``frame``, with that slice's contours in its pixels; a reason (str) when
    there is no image, or it does not hold that slice or frame.

    Parameters
    ----------
    study : cardionurbs.study.Study
        A label-map study with its SA image NIfTI beside it.
    frame : int
        The frame index, 0-based.
    slice_id : str or None, optional
        The SA slice (default: the middle one with an LV endocardium at ``frame``).

    Returns
    -------
    SliceOverlay or str
        The image and its contours, or the reason there is none (one line).
    """
    path = sa_image_path(study)
    if path is None:
        return "no short-axis image NIfTI beside the label map"
    if study.meta.get("layout") == "ukbb" and any("seg_sa_E" in f for f in
                                                   study.meta.get("label_files", [])):
        return "ED/ES label files: their frames are not the image's frame numbers"
    if slice_id is None:
        sl = sorted({c.slice for c in study.contours_at(frame, "lv_endo", view="SA")})
        if not sl:
            return f"no SA LV endocardium at frame {frame}"
        slice_id = sl[len(sl) // 2]
    plane = next((im for im in study.images if im.slice == slice_id and im.frame == frame), None)
    if plane is None:
        return f"no image plane of slice {slice_id} at frame {frame}"
    img, aff = _image(path)
    inv = np.linalg.inv(aff)
    k = float((inv @ np.r_[plane.position, 1.0])[2])
    shape = img.shape
    if abs(k - round(k)) > 0.05 or not 0 <= round(k) < (shape[2] if len(shape) > 2 else 1):
        return f"slice {slice_id} is not a slice of {path.name}"
    t = frame if len(shape) > 3 else 0
    if len(shape) > 3 and t >= shape[3]:
        return f"frame {frame} is not in {path.name} ({shape[3]} frames)"
    index = (slice(None), slice(None), int(round(k))) + ((t,) if len(shape) > 3 else ())
    image = np.asarray(img.dataobj[index], float)
    out: dict[str, list[np.ndarray]] = {}
    for c in study.contours_at(frame, view="SA"):
        if c.slice != slice_id:
            continue
        pix = (np.asarray(c.points, float) - aff[:3, 3]) @ inv[:3, :3].T
        out.setdefault(c.structure, []).append(pix[:, :2])
    return SliceOverlay(slice_id, frame, image, out)
