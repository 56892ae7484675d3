"""Segmentation label maps in NIfTI-1/2 (nibabel): one file, or the ACDC, UK Biobank and
M&Ms folder layouts, read into a :class:`~cardionurbs.study.Study` of contours.

Layouts (:func:`detect`)
------------------------
``file``   one ``.nii``/``.nii.gz`` label map: 3-D (x, y, slices) is one frame;
           4-D has the frames along the last axis, their interval from the
           header's ``pixdim[4]`` and time unit. Its slices form the SA stack.
``acdc``   ``patientNNN_frameMM_gt.nii.gz`` (one 3-D map per labelled frame,
           MM counted from 1) and ``Info.cfg`` (``ED:``, ``ES:``, ``Height:``,
           ``Weight:``); label preset ``acdc``.
``ukbb``   ukbb_cardiac output: ``seg_sa.nii.gz`` (4-D) or ``seg_sa_ED.nii.gz``
           + ``seg_sa_ES.nii.gz``; long-axis ``seg4_la_4ch.nii.gz`` (preferred)
           or ``seg_la_4ch``/``seg_la_2ch``/``seg_la_3ch.nii.gz`` (their ``_ED`` +
           ``_ES`` pairs beside ``seg_sa_ED/_ES``) when they hold ventricles
           (:func:`_not_ventricular`: ukbb_cardiac's atrial maps do not); label
           preset ``ukbb``. ED is frame 0 (ukbb_cardiac's
           convention), ES the frame of the smallest LV cavity by voxel count.
``mnms``   ``<code>_sa_gt.nii.gz`` (4-D, only ED and ES labelled); ED/ES frame
           indices from a CSV in the subject folder or (``--allow-outside``) up to
           :data:`MNMS_CSV_LEVELS` folders above it (columns ``External code``,
           ``ED``, ``ES``) or the ``ed_frame``/``es_frame`` arguments, else the
           labelled frames (a warning); label preset ``mnms``.
``mnms2``  ``NNN_SA_ED_gt`` + ``NNN_SA_ES_gt`` (3-D, frames 0 = ED and 1 = ES) and
           ``NNN_LA_ED_gt`` + ``NNN_LA_ES_gt`` (the 4-chamber slice, used as the
           ukbb long-axis maps are); label preset ``mnms`` (1 LV, 2 MYO, 3 RV).
ED and ES defined by the layout are used as given by the model
(``meta["ed_es_given"]``; ``meta["ed_es_source"]`` names the rule); ED = ES
is allowed and leaves SV and EF null.
An image NIfTI beside the labels (``patientNNN_4d``, ``sa``/``la_*``,
``<code>_sa``) is recorded in ``study.meta["image_files"]``.

Geometry
--------
The voxel-to-world affine is the sform when its code is set (with the
``pixdim`` spacing where the two disagree, as in ACDC's files), else the
qform, else (with a warning) the voxel sizes alone; sform, qform and pixdim
are compared on every file (:func:`_header_notes`, ``meta["headers"]``). The
frame interval honours ``xyzt_units``, and an unknown unit is read as the one
giving a plausible cardiac cycle (:func:`time_step_ms`, ``meta["time_axis"]``). NIfTI world coordinates
are RAS+; the study's scanner frame is DICOM patient LPS, so x and y change
sign: ``A_lps = diag(-1, -1, 1, 1) · A_ras``. For slice k the image plane
(DICOM Image Plane module) is: ImagePositionPatient = ``A_lps (0, 0, k, 1)``,
row cosine = unit first column of ``A_lps`` (the direction in which the first
array index grows), column cosine = unit second column, PixelSpacing = (length
of the second column, length of the first), slice thickness = length of the
third column. Pixel coordinates (c, r) are the first two array indices. The
SA slices are named ``sa_00`` at the base towards the apex: which end is the
base comes from the anatomy the labels show (:func:`cardionurbs.io.masks.stack_anatomy`,
:func:`cardionurbs.imaging.stack.sa_base_direction`), cross-checked with the mitral
annulus of the long-axis maps; the patient-frame prior of the header's axes only
when neither says (a warning).

Contours come from :mod:`cardionurbs.io.masks`; what is left out is
reported in ``study.warnings`` naming slice and frame. Voxel-count volumes
(the figures ukbb_cardiac reports) are kept in
``study.meta["voxel_volumes_ml"]`` (frame -> structure -> mL).
"""

from __future__ import annotations

import csv
import re
import zlib
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy import ndimage

from cardionurbs.confine import checked, is_inside, outside_allowed
from cardionurbs.errors import ReconstructionError, StudyError
from cardionurbs.imaging import stack
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import masks
from cardionurbs.io.labels import PRESETS, LabelRoles, check_values, infer_roles, parse_labels
from cardionurbs.limits import HEART_RATE_RANGE_BPM
from cardionurbs.study import Contour, Landmark, Study

RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])
LAYOUTS = ("file", "acdc", "ukbb", "mnms", "mnms2")
_MNMS2 = re.compile(r"(?P<code>.+)_(?P<view>SA|LA)_(?P<phase>ED|ES)_gt\.nii(\.gz)?")
LA_FILES = {"la_4ch": ("seg4_la_4ch", "seg_la_4ch"), "la_2ch": ("seg_la_2ch",),
            "la_3ch": ("seg_la_3ch",)}
MAX_LABEL = 255
_TIME_UNIT_MS = {"sec": 1000.0, "msec": 1.0, "usec": 1e-3}
#: a plausible cardiac cycle (frames x interval), ms: the R-R interval at the heart-rate limits
RR_RANGE_MS = (60000.0 / HEART_RATE_RANGE_BPM[1], 60000.0 / HEART_RATE_RANGE_BPM[0])


def is_nifti(path: str | Path) -> bool:
    """True for a file named ``*.nii`` or ``*.nii.gz``.

    Parameters
    ----------
    path : str or pathlib.Path
        A path.

    Returns
    -------
    bool
    """
    name = Path(path).name.lower()
    return name.endswith(".nii") or name.endswith(".nii.gz")


def _stem(path: Path) -> str:
    return re.sub(r"\.nii(\.gz)?$", "", path.name, flags=re.I)


def detect(path: str | Path) -> str | None:
    """The layout of ``path`` (``file``, ``acdc``, ``ukbb``, ``mnms``, ``mnms2``) or None.

    Parameters
    ----------
    path : str or pathlib.Path
        A label-map file or a folder.

    Returns
    -------
    str or None
    """
    p = Path(path)
    if p.is_file():
        return "file" if is_nifti(p) else None
    if not p.is_dir():
        return None
    names = [q.name for q in p.iterdir() if is_nifti(q)]
    if any(re.fullmatch(r".+_frame\d+_gt\.nii(\.gz)?", n) for n in names):
        return "acdc"
    if any(re.fullmatch(r"seg_sa(_ED|_ES)?\.nii(\.gz)?", n) for n in names):
        return "ukbb"
    if any(re.fullmatch(r".+_sa_gt\.nii(\.gz)?", n) for n in names):
        return "mnms"
    if any(_MNMS2.fullmatch(n) and "_SA_" in n for n in names):
        return "mnms2"
    return None


# ------------------------------------------------------------------ one file
class LabelVolume:
    """One label map: integer data (x, y, slices, frames), LPS affine, frame interval.

    Parameters
    ----------
    path : pathlib.Path
        The file read.
    data : (x, y, slices, frames) ndarray of int
        The label values.
    affine_lps : (4, 4) ndarray
        Voxel index -> scanner LPS mm.
    dt_ms : float or None
        The frame interval, ms (None: unknown).
    warnings : list of str
        The reader's warnings about this file.
    header : dict or None
        What the header said and what was used.
    """

    def __init__(self, path: Path, data: np.ndarray, affine_lps: np.ndarray,
                 dt_ms: float | None, warnings: list[str], header: dict | None = None) -> None:
        self.path, self.data, self.affine, self.dt_ms = path, data, affine_lps, dt_ms
        self.warnings = warnings
        #: what the header said and what was used (:func:`_header_notes`, :func:`time_step_ms`)
        self.header = header or {}

    @property
    def voxel_ml(self) -> float:
        """The volume of one voxel, mL."""
        return abs(float(np.linalg.det(self.affine[:3, :3]))) / 1000.0

    def same_grid(self, other: "LabelVolume") -> bool:
        """Whether ``other`` has the same voxel grid: shape (x, y, slices) and affine
        (to 1e-4 mm).

        Parameters
        ----------
        other : LabelVolume
            Another map.

        Returns
        -------
        bool
        """
        return (self.data.shape[:3] == other.data.shape[:3]
                and np.allclose(self.affine, other.affine, atol=1e-4))


def check_volume_size(path: Path, shape: tuple[int, ...], itemsize: int) -> None:
    """Refuse, from the header alone and before any allocation, a map past the limits of
    :mod:`cardionurbs.limits`: frames, voxels per axis and in all, and the bytes its gzip
    stream expands to: nibabel decompresses only the header's voxel bytes, so bounding those
    bounds a decompression bomb. Raises LimitError naming the file.

    Parameters
    ----------
    path : pathlib.Path
        The file, for the message.
    shape : tuple of int
        The header's data shape.
    itemsize : int
        Bytes per voxel.

    Raises
    ------
    LimitError
        A limit exceeded.
    """
    from cardionurbs.errors import LimitError
    from cardionurbs.limits import (MAX_DECOMPRESSED_BYTES, MAX_FRAMES, MAX_LABEL_AXIS,
                                    MAX_LABEL_VOXELS)
    if len(shape) == 4 and shape[3] > MAX_FRAMES:
        raise LimitError(f"{shape[3]} frames (limit {MAX_FRAMES})", file=str(path))
    if max(shape[:3]) > MAX_LABEL_AXIS:
        raise LimitError(f"an axis of {max(shape[:3])} voxels (limit {MAX_LABEL_AXIS})",
                         file=str(path))
    n = int(np.prod(np.asarray(shape, dtype=object)))
    if n > MAX_LABEL_VOXELS:
        raise LimitError(f"{n:.3g} voxels (limit {MAX_LABEL_VOXELS:.3g})", file=str(path))
    if n * itemsize > MAX_DECOMPRESSED_BYTES:
        raise LimitError(f"{n * itemsize} bytes of voxel data (limit "
                         f"{MAX_DECOMPRESSED_BYTES})", file=str(path))


def read_label_volume(path: str | Path) -> LabelVolume:
    """Read one NIfTI label map (StudyError naming the file for anything unusable).

    Parameters
    ----------
    path : str or Path
        A NIfTI-1 or NIfTI-2 file (.nii or .nii.gz), 3-D (x, y, slices) or 4-D
        (x, y, slices, frames).

    Returns
    -------
    LabelVolume
        uint8 labels (x, y, slices, frames), the voxel-to-LPS affine (mm), the frame
        interval (ms, None when unknown), the warnings and the header notes.
    """
    path = checked(path, what="label map")
    where = str(path)
    warnings: list[str] = []
    img = _load_nifti(path, where, warnings)
    shape = _label_shape(img, where)
    check_volume_size(path, shape, img.header.get_data_dtype().itemsize)
    data = _label_data(img, shape, where)
    aff = _label_affine(img, path, where, warnings)
    header = _header_notes(img, aff, where, warnings)
    dt, header["time"] = time_step_ms(img.header, data.shape[3], where, warnings)
    return LabelVolume(path, data, RAS_TO_LPS @ aff, dt, warnings, header)


def _load_nifti(path: Path, where: str, warnings: list[str] | None = None):
    """The nibabel image of a NIfTI-1 or NIfTI-2 file (StudyError for anything else).

    A file whose content and name disagree -- a ``.nii.gz`` that is not gzip-compressed,
    or a ``.nii`` that is (some converters write them; ITK, Slicer and FSL read them by
    content) -- is read by its content, with a warning.

    Parameters
    ----------
    path : Path
        The file.
    where : str
        The file as named in messages.
    warnings : list of str, optional
        Appended to when the name and the content disagree.

    Returns
    -------
    nibabel.Nifti1Image or nibabel.Nifti2Image
        The image, its voxel data not yet read.
    """
    import nibabel as nib
    from nibabel.filebasedimages import ImageFileError
    from nibabel.spatialimages import HeaderDataError
    try:
        gz = _is_gzip(path)
        if gz is not None and gz != path.name.lower().endswith(".gz"):
            img = _load_by_content(path, gz)
            if warnings is not None:
                warnings.append(f"{where}: the file is {'' if gz else 'not '}gzip-compressed, its "
                                f"name says {'not' if gz else 'it is'}: read by its content")
        else:
            img = nib.load(str(path))
    except FileNotFoundError:
        raise StudyError("no such file", file=where) from None
    except (ImageFileError, HeaderDataError, EOFError, OSError, zlib.error, ValueError) as exc:
        raise StudyError(f"not a readable NIfTI file ({' '.join(str(exc).split())[:120]})",
                         file=where) from None
    if not isinstance(img, (nib.Nifti1Image, nib.Nifti2Image)):
        raise StudyError(f"not a NIfTI image ({type(img).__name__})", file=where)
    return img


def _is_gzip(path: Path) -> bool | None:
    """Whether the file starts with the gzip magic number (None: unreadable)."""
    try:
        with path.open("rb") as fh:
            return fh.read(2) == b"\x1f\x8b"
    except OSError:
        return None


def _load_by_content(path: Path, gz: bool):
    """A NIfTI-1 (else NIfTI-2) image from the file's bytes, decompressed when ``gz``; the
    voxel data stays unread (lazy, from the open stream) until the header is checked."""
    import gzip

    import nibabel as nib
    from nibabel.filebasedimages import ImageFileError
    why = ""
    for klass in (nib.Nifti1Image, nib.Nifti2Image):
        fh = gzip.open(path, "rb") if gz else path.open("rb")
        try:
            return klass.from_stream(fh)
        except Exception as exc:  # noqa: BLE001 - the other NIfTI version, else reported
            fh.close()
            why = f"{type(exc).__name__}: {exc}"
    raise ImageFileError(f"neither NIfTI-1 nor NIfTI-2 by its content ({why})")


def _label_shape(img, where: str) -> tuple[int, ...]:
    """The image's shape as (x, y, slices) or (x, y, slices, frames): trailing unit axes
    dropped, time moved from the 5th axis (x, y, z, 1, t) to the 4th.

    Parameters
    ----------
    img : nibabel NIfTI image
    where : str
        The file, for the errors.

    Returns
    -------
    tuple of int
        3 or 4 lengths, none 0; StudyError for any other shape.
    """
    shape = tuple(int(s) for s in img.shape)
    while len(shape) > 4 and shape[-1] == 1:
        shape = shape[:-1]
    if len(shape) == 5 and shape[3] == 1:              # (x, y, z, 1, t): time in the 5th axis
        shape = shape[:3] + shape[4:]
    if len(shape) < 3:
        raise StudyError(f"a {len(shape)}-D image: a label map must be 3-D (x, y, slices) or "
                         "4-D (x, y, slices, frames)", file=where)
    if len(shape) > 4:
        raise StudyError(f"a {len(shape)}-D image of shape {shape}: expected 3-D or 4-D",
                         file=where)
    if len(shape) == 4 and shape[3] == 0:
        raise StudyError("the time axis has length 0 (no frames)", file=where)
    if min(shape) == 0:
        raise StudyError(f"an empty image (shape {shape})", file=where)
    return shape


def _label_data(img, shape: tuple[int, ...], where: str) -> np.ndarray:
    """The voxel labels as uint8 (x, y, slices, frames), checked to be labels.

    Parameters
    ----------
    img : nibabel NIfTI image
    shape : tuple of int
        From :func:`_label_shape`.
    where : str
        The file, for the errors.

    Returns
    -------
    (x, y, slices, frames) uint8 ndarray
        StudyError for unreadable voxels, a non-integer or non-label type, or values
        outside 0..MAX_LABEL.
    """
    try:
        raw = np.asanyarray(img.dataobj)
    except (EOFError, OSError, zlib.error, ValueError) as exc:
        raise StudyError(f"cannot read the voxel data (truncated or corrupt file: "
                         f"{' '.join(str(exc).split())[:80]})", file=where) from None
    raw = raw.reshape(shape if len(shape) == 4 else shape + (1,))
    if raw.dtype.kind == "f":
        if not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
            raise StudyError("the map holds non-integer values: an image, not a label map?",
                             file=where)
    elif raw.dtype.kind not in "iub":
        raise StudyError(f"voxel type {raw.dtype} is not a label type", file=where)
    if raw.size and (raw.min() < 0 or raw.max() > MAX_LABEL):
        raise StudyError(f"label values must lie in 0..{MAX_LABEL}, got {raw.min():g}..{raw.max():g}: "
                         "an image, not a label map?", file=where)
    return raw.astype(np.uint8)


def _label_affine(img, path: Path, where: str, warnings: list[str]) -> np.ndarray:
    """The voxel-to-RAS affine (mm): the sform, else the qform, else the voxel sizes alone
    (with a warning), its spacing from ``pixdim`` (:func:`_spacing_from_pixdim`), checked.

    Parameters
    ----------
    img : nibabel NIfTI image
    path : Path
        The file (its raw ``pixdim`` when neither form is set).
    where : str
        The file, for the errors and warnings.
    warnings : list of str
        Appended to (no geometry, replaced spacing, identity affine).

    Returns
    -------
    (4, 4) float ndarray
        StudyError for a non-finite, singular or sheared affine.
    """
    hdr = img.header
    scode, qcode = int(hdr["sform_code"]), int(hdr["qform_code"])
    if scode > 0:
        aff = img.get_sform()
    elif qcode > 0:
        aff = img.get_qform()
    else:
        zooms = _raw_pixdim(path, type(hdr))
        if not (np.all(np.isfinite(zooms)) and np.all(zooms > 0)):
            raise StudyError("no affine (sform and qform codes 0) and no valid voxel sizes: the "
                             "map has no geometry", file=where, field="affine")
        aff = np.diag([*zooms, 1.0])
        warnings.append(f"{where}: no sform or qform: voxel sizes only, identity orientation "
                        "(positions and volumes in scanner mm are not real)")
    aff = np.asarray(aff, float)
    if not np.all(np.isfinite(aff)):
        raise StudyError("the affine holds NaN or infinity", file=where, field="affine")
    aff = _spacing_from_pixdim(aff, hdr, scode, where, warnings)
    _check_voxel_axes(aff[:3, :3], where)
    if scode > 0 and np.allclose(aff, np.eye(4)) or (scode == 0 and qcode > 0 and np.allclose(aff, np.eye(4))):
        warnings.append(f"{where}: identity affine: 1 mm voxels at the origin, no real scanner "
                        "position or orientation")
    return aff


def _check_voxel_axes(m: np.ndarray, where: str) -> None:
    """StudyError unless the voxel axes (columns of ``m``, (3, 3), mm) span space and the
    two in-plane axes are perpendicular (cos below 1e-3)."""
    lengths = np.linalg.norm(m, axis=0)
    if np.any(lengths < 1e-6) or abs(np.linalg.det(m)) < 1e-6 * np.prod(np.maximum(lengths, 1e-6)):
        raise StudyError("singular affine (voxel axes of zero length or in one plane)",
                         file=where, field="affine")
    cos = abs(float(m[:, 0] @ m[:, 1]) / (lengths[0] * lengths[1]))
    if cos > 1e-3:
        raise StudyError(f"in-plane voxel axes are not perpendicular (cos {cos:.3g}): sheared "
                         "affine", file=where, field="affine")


def _spacing_from_pixdim(aff: np.ndarray, hdr, scode: int, where: str,
                         warnings: list[str]) -> np.ndarray:
    """The sform with its voxel sizes taken from ``pixdim`` where the two disagree.

    ``pixdim[1:4]`` is the voxel size the header declares (the qform is built from
    it); ACDC's files as distributed, for one, carry a unit-scale sform beside the
    real spacing in ``pixdim``, and ACDC's own evaluation, like most tools, measures
    with ``pixdim`` (nibabel's ``get_zooms``). The sform's directions and origin are
    kept; only the column lengths become the ``pixdim`` spacing, with a warning that
    names the file and both spacings.

    Parameters
    ----------
    aff : (4, 4) float ndarray
        The chosen voxel-to-RAS affine (sform or qform), mm.
    hdr : nibabel NIfTI header
    scode : int
        ``sform_code``; only an sform (code > 0) can disagree with ``pixdim``.
    where : str
        The file, for the warning.
    warnings : list of str
        Appended to when the spacing is replaced.

    Returns
    -------
    (4, 4) float ndarray
        The affine to use, mm.
    """
    if scode <= 0:
        return aff
    zooms = np.asarray(hdr.get_zooms()[:3], float)
    lengths = np.linalg.norm(aff[:3, :3], axis=0)
    if not (np.all(np.isfinite(zooms)) and np.all(zooms > 0)) or np.any(lengths < 1e-9):
        return aff
    if np.allclose(lengths, zooms, rtol=1e-3, atol=1e-4):
        return aff
    out = aff.copy()
    out[:3, :3] = aff[:3, :3] / lengths * zooms
    warnings.append(f"{where}: the sform's voxel size ({' x '.join(f'{v:.4g}' for v in lengths)} mm) "
                    f"disagrees with pixdim ({' x '.join(f'{v:.4g}' for v in zooms)} mm): measured "
                    "with pixdim, as ACDC's evaluation and nibabel's get_zooms do")
    return out


def _header_notes(img, aff: np.ndarray, where: str, warnings: list[str]) -> dict:
    """Compare sform, qform and ``pixdim`` of one file; warn where they disagree.

    The affine used is the sform where its code is set (nibabel's rule), with the
    ``pixdim`` spacing (:func:`_spacing_from_pixdim`). A qform that is also set but
    points the voxel axes elsewhere, or puts the first voxel more than 1 mm away,
    is named in one warning (both readings given; the sform is used). A spacing of
    exactly 1 mm along every axis is named too: cine SA stacks have 5-10 mm between
    slices, so such a header most likely carries no real spacing.

    Parameters
    ----------
    img : nibabel NIfTI image
    aff : (4, 4) float ndarray
        The voxel-to-RAS affine chosen, mm.
    where : str
        The file, for the warnings.
    warnings : list of str
        Appended to.

    Returns
    -------
    dict
        ``sform_code``, ``qform_code``, ``pixdim`` (3 floats, mm), ``spacing_mm``
        (the spacing used), ``orientation`` (``"placeholder"`` when the axes are the
        scanner axes and the origin is 0, as in ACDC's files, else ``"scanner"``).
    """
    hdr = img.header
    scode, qcode = int(hdr["sform_code"]), int(hdr["qform_code"])
    spacing = np.linalg.norm(aff[:3, :3], axis=0)
    if scode > 0 and qcode > 0:
        q = np.asarray(img.get_qform(), float)
        qd = q[:3, :3] / np.maximum(np.linalg.norm(q[:3, :3], axis=0), 1e-12)
        sd = aff[:3, :3] / spacing
        angle = float(np.degrees(np.arccos(np.clip(np.min(np.sum(qd * sd, axis=0)), -1, 1))))
        shift = float(np.linalg.norm(q[:3, 3] - aff[:3, 3]))
        if angle > 1.0 or shift > 1.0:
            warnings.append(f"{where}: the sform and the qform disagree (voxel axes {angle:.3g} deg "
                            f"apart, origins {shift:.3g} mm apart): the sform (code {scode}) is "
                            "used, as nibabel does")
    if np.allclose(spacing, 1.0, atol=1e-6) and not np.allclose(aff, np.eye(4)):
        warnings.append(f"{where}: voxel size 1 x 1 x 1 mm in sform, qform and pixdim alike: most "
                        "likely no real spacing (volumes in mm^3 of unit voxels)")
    rot = aff[:3, :3] / spacing
    placeholder = bool(np.allclose(np.abs(rot), np.round(np.abs(rot)), atol=1e-6)
                       and np.allclose(aff[:3, 3], 0.0))
    return {"sform_code": scode, "qform_code": qcode,
            "pixdim": [float(v) for v in hdr.get_zooms()[:3]],
            "spacing_mm": [round(float(v), 6) for v in spacing],
            "orientation": "placeholder" if placeholder else "scanner"}


def time_step_ms(hdr, n_frames: int, where: str, warnings: list[str]) -> tuple[float | None, dict]:
    """The frame interval (ms) of a 4-D map from ``pixdim[4]`` and ``xyzt_units``.

    A declared unit (``sec``, ``msec``, ``usec``) is honoured. An unknown unit (code
    0, as in UK Biobank's maps, whose ``pixdim[4]`` holds seconds) is read as the one
    of ms and s that makes the cycle, ``n_frames × dt``, a plausible R-R interval
    (:data:`RR_RANGE_MS`, from the heart-rate limits), with a warning. A cycle
    outside that range under the unit used is an *implausible time axis*: a warning,
    and ``plausible`` False in the returned notes (the pipeline's QC names it).
    Where no unit gives a plausible cycle, the frame times are left unknown (None).

    Parameters
    ----------
    hdr : nibabel NIfTI header
    n_frames : int
        Length of the time axis.
    where : str
        The file, for the warnings.
    warnings : list of str
        Appended to.

    Returns
    -------
    dt_ms : float or None
        Frame interval, ms; None for one frame or no usable interval.
    notes : dict
        ``pixdim4``, ``unit`` (declared), ``unit_used``, ``dt_ms``, ``cycle_ms``,
        ``plausible`` (None for a single frame).
    """
    zooms = hdr.get_zooms()
    raw = float(zooms[3]) if len(zooms) > 3 else float("nan")
    unit = str(hdr.get_xyzt_units()[1])
    notes: dict = {"pixdim4": raw if np.isfinite(raw) else None, "unit": unit, "unit_used": None, "dt_ms": None,
                   "cycle_ms": None, "plausible": None}
    if n_frames <= 1:
        return None, notes
    lo, hi = RR_RANGE_MS
    if not (np.isfinite(raw) and raw > 0):
        notes["plausible"] = False
        warnings.append(f"{where}: {n_frames} frames but no frame interval (pixdim[4] = {raw:g}): "
                        "frame times unknown")
        return None, notes
    if unit in _TIME_UNIT_MS:
        used, dt = unit, raw * _TIME_UNIT_MS[unit]
    else:
        fits = [u for u in ("msec", "sec") if lo <= n_frames * raw * _TIME_UNIT_MS[u] <= hi]
        if not fits:
            notes["plausible"] = False
            warnings.append(f"{where}: implausible time axis: frame interval {raw:g} in an unknown "
                            f"time unit ({unit}) gives a cycle of {n_frames} x {raw:g} = "
                            f"{n_frames * raw:g} ms or s, neither within {lo:g}-{hi:g} ms: frame "
                            "times unknown")
            return None, notes
        used, dt = fits[0], raw * _TIME_UNIT_MS[fits[0]]
        warnings.append(f"{where}: frame interval {raw:g} with unknown time unit ({unit}): read as "
                        f"{used} ({dt:.4g} ms per frame, a {n_frames * dt:.0f} ms cycle over "
                        f"{n_frames} frames; the other unit gives no plausible R-R interval)")
    cycle = n_frames * dt
    notes.update(unit_used=used, dt_ms=dt, cycle_ms=cycle, plausible=bool(lo <= cycle <= hi))
    if not notes["plausible"]:
        warnings.append(f"{where}: implausible time axis: {n_frames} frames x {dt:.4g} ms "
                        f"({raw:g} {used}) = {cycle:.4g} ms, outside a cardiac cycle of "
                        f"{lo:g}-{hi:g} ms: filling rates and times are not to be trusted")
    return dt, notes


def _raw_pixdim(path: Path, header_class) -> np.ndarray:
    """pixdim[1:4] as stored in the file (nibabel's load silently sets zeros to 1)."""
    from nibabel.openers import ImageOpener

    try:
        with ImageOpener(str(path)) as fh:
            raw = header_class.from_fileobj(fh, check=False)
        return np.asarray(raw["pixdim"][1:4], float)
    except Exception:  # noqa: BLE001 - an unreadable header has no voxel sizes either
        return np.zeros(3)


# ------------------------------------------------------------------ geometry
def slice_plane(vol: LabelVolume, k: int, *, slice_id: str, view: str, frame: int,
                trigger_time: float | None, image_id: str) -> ImagePlane:
    """The image plane of slice k of a label volume (see the module docstring).

    Parameters
    ----------
    vol : LabelVolume
        The label map.
    k : int
        The slice index.
    slice_id : str
        The slice id of the plane.
    view : {"SA", "LA"}
        Its view.
    frame : int
        Its frame.
    trigger_time : float or None
        Its trigger time, ms.
    image_id : str
        Its image id.

    Returns
    -------
    ImagePlane
    """
    a = vol.affine
    dc, dr, dk = (float(np.linalg.norm(a[:3, i])) for i in range(3))
    return ImagePlane(id=image_id, slice=slice_id, view=view, frame=frame,
                      position=a[:3, 3] + k * a[:3, 2], row_cosine=a[:3, 0] / dc,
                      column_cosine=a[:3, 1] / dr, pixel_spacing=(dr, dc),
                      rows=vol.data.shape[1], columns=vol.data.shape[0], thickness=dk,
                      trigger_time=trigger_time, file=vol.path.name)


def to_scanner(vol: LabelVolume, k: int, pixels: np.ndarray) -> np.ndarray:
    """(n, 2) pixel coordinates (c, r) of slice k -> (n, 3) scanner LPS mm.

    Parameters
    ----------
    vol : LabelVolume
        The label map.
    k : int
        The slice index.
    pixels : (n, 2) ndarray
        Pixel coordinates (c, r) in slice k.

    Returns
    -------
    (n, 3) ndarray
        Scanner LPS mm.
    """
    p = np.asarray(pixels, float).reshape(-1, 2)
    a = vol.affine
    return a[:3, 3] + k * a[:3, 2] + p[:, :1] * a[:3, 0] + p[:, 1:2] * a[:3, 1]


# ------------------------------------------------------------------ study assembly
class _Builder:
    """Collects planes, contours, landmarks and aggregated warnings of one study."""

    def __init__(self, subject: str, source: Path, roles: LabelRoles) -> None:
        self.study = Study(subject=subject, source=str(source))
        self.roles = roles
        self.files: list[str | None] = []
        self.issues: dict[tuple[str, str], list[int]] = defaultdict(list)

    def note(self, slice_id: str, message: str, frame: int) -> None:
        self.issues[(slice_id, message)].append(frame)

    def add_contour(self, structure, view, plane: ImagePlane, pts, closed, index=0) -> None:
        self.study.contours.append(Contour(structure, view, plane.slice, plane.frame, pts,
                                           image=plane.id, closed=closed, index=index))
        self.files.append(plane.file)

    def flush_warnings(self) -> list[str]:
        out = []
        for (sl, msg), frames in sorted(self.issues.items()):
            fr = sorted(set(frames))
            shown = ", ".join(map(str, fr[:8])) + (", ..." if len(fr) > 8 else "")
            out.append(f"{self.study.source}: slice {sl}: {msg} (frame{'s' if len(fr) > 1 else ''} "
                       f"{shown})")
        return out


def _frame_indices(vol: LabelVolume) -> list[int]:
    """Frames of a volume that hold any label."""
    return [t for t in range(vol.data.shape[3]) if vol.data[..., t].any()]


def _add_la(b: _Builder, view_id: str, vol: LabelVolume, frames: dict[int, int],
            times: dict[int, float]) -> None:
    """Long-axis contours and annulus landmarks of one LA label map (every slice k)."""
    for t_vol, frame in frames.items():
        for k in range(vol.data.shape[2]):
            sid = view_id if vol.data.shape[2] == 1 else f"{view_id}_{k}"
            plane = slice_plane(vol, k, slice_id=sid, view="LA", frame=frame,
                                trigger_time=times.get(frame), image_id=f"{sid}_f{frame:03d}")
            b.study.images.append(plane)
            sc = masks.la_slice_contours(vol.data[:, :, k, t_vol], b.roles)
            for msg in sc.skipped:
                b.note(sid, msg, frame)
            for name, parts in sc.open.items():
                for i, pix in enumerate(parts):
                    b.add_contour(name, "LA", plane, to_scanner(vol, k, pix), False, i)
            for name, pix in sc.landmarks.items():
                for i, p in enumerate(to_scanner(vol, k, pix)):
                    idx = len(b.study.landmarks_at(frame, name))
                    b.study.landmarks.append(Landmark(name, frame, p, index=idx, slice=sid,
                                                      view="LA", image=plane.id))


def _sa_order(vol: LabelVolume, study: Study, roles: LabelRoles, frames) -> list[int]:
    """Slice indices k of an SA volume from base to apex: which end is the base from the
    anatomy (:func:`cardionurbs.imaging.stack.sa_base_direction`), never from the slice
    order or the header's axes alone (ACDC's headers have none)."""
    nk = vol.data.shape[2]
    if nk == 1:
        return [0]
    a = vol.affine
    normal = np.cross(a[:3, 0], a[:3, 1])
    normal /= np.linalg.norm(normal)
    centres = np.array([a[:3, 3] + k * a[:3, 2] for k in range(nk)])
    mitral = np.array([lm.point for lm in study.landmarks if lm.name == "mitral"])
    anat = masks.stack_anatomy(vol.data, roles, list(frames))
    try:
        u, rule = stack.sa_base_direction(normal, centres, anat,
                                          mitral=mitral if len(mitral) else None)
    except ReconstructionError as exc:
        raise StudyError(str(exc), file=str(vol.path), field="slice order") from None
    study.meta["sa_orientation"] = rule
    if rule.startswith("LPS prior"):
        study.meta.setdefault("orientation_warnings", []).append(
            f"{vol.path}: base and apex of the short-axis stack from the header's patient axes "
            "only (the labels show no taper, cap or outflow): check the slice order")
    depth = centres @ u
    return [int(k) for k in np.argsort(depth, kind="stable")]


def _add_sa(b: _Builder, vol: LabelVolume, frames: dict[int, int], times: dict[int, float]) -> None:
    """SA planes and contours of every labelled slice at the given (volume frame -> frame)."""
    order = _sa_order(vol, b.study, b.roles, frames)
    labelled = [k for k in order if any(vol.data[:, :, k, t].any() for t in frames)]
    for k in order:
        if k not in labelled:
            b.note(f"k={k}", "no labels at any frame: slice left out", min(frames.values()))
    for n, k in enumerate(labelled):
        sid = f"sa_{n:02d}"
        for t_vol, frame in frames.items():
            plane = slice_plane(vol, k, slice_id=sid, view="SA", frame=frame,
                                trigger_time=times.get(frame), image_id=f"{sid}_f{frame:03d}")
            b.study.images.append(plane)
            lab = vol.data[:, :, k, t_vol]
            if not lab.any():
                b.note(sid, "no labels (beyond the apex or base?): left out", frame)
                continue
            sc = masks.sa_slice_contours(lab, b.roles)
            if (lab == b.roles.lv).any():   # what the slice holds (sections.labelled_beyond_base_ml)
                got: dict[str, float | list[float]] = {
                    key: float(np.count_nonzero(lab == v)) * vol.voxel_ml
                    for key, v in (("lv_cavity", b.roles.lv), ("lv_myocardium", b.roles.myo))}
                got["centroid"] = [float(x) for x in
                                   to_scanner(vol, k, np.argwhere(lab == b.roles.lv).mean(axis=0))[0]]
                b.study.meta.setdefault("lv_slice_ml", {}).setdefault(frame, {})[sid] = got
            for msg in sc.skipped + sc.notes:
                b.note(sid, msg, frame)
            for name, pix in sc.closed.items():
                b.add_contour(name, "SA", plane, to_scanner(vol, k, pix), True)
            for name, parts in sc.open.items():
                for i, pix in enumerate(parts):
                    b.add_contour(name, "SA", plane, to_scanner(vol, k, pix), False, i)


def label_counts(data: np.ndarray) -> np.ndarray:
    """Number of voxels of each label value 1..MAX_LABEL (index = value; index 0 set to 0);
    the label values are whole numbers ≥ 0 (checked when the map is read).

    Parameters
    ----------
    data : ndarray of int
        Label values.

    Returns
    -------
    (MAX_LABEL + 1,) ndarray of int
    """
    counts = np.bincount(data.ravel(), minlength=MAX_LABEL + 1)
    counts[0] = 0
    return counts


def voxel_volumes(vol: LabelVolume, roles: LabelRoles, frames: dict[int, int]) -> dict[int, dict]:
    """Voxel-count volumes (mL) per frame: LV cavity, LV myocardium, RV cavity (and RV
    myocardium where labelled) — number of voxels times the voxel volume.

    Parameters
    ----------
    vol : LabelVolume
        The SA label map.
    roles : LabelRoles
        Which label is which structure.
    frames : dict of int to int
        Study frame -> volume frame index.

    Returns
    -------
    dict of int to dict of str to float
        Study frame -> structure -> mL.
    """
    out = {}
    for t_vol, frame in frames.items():
        counts = label_counts(vol.data[..., t_vol])
        d = {"lv_cavity": counts[roles.lv] * vol.voxel_ml,
             "lv_myocardium": counts[roles.myo] * vol.voxel_ml}
        if roles.rv is not None:
            d["rv_cavity"] = counts[roles.rv] * vol.voxel_ml
        if roles.rv_myo is not None:
            d["rv_myocardium"] = counts[roles.rv_myo] * vol.voxel_ml
        out[frame] = {k: float(v) for k, v in d.items()}
    return out


def _resolve_roles(labels, default: str | None, vol: LabelVolume, frames) -> tuple[LabelRoles, str | None]:
    roles = parse_labels(labels)
    if roles is None and default is not None:
        roles = PRESETS[default]
    note = None
    if roles is None:
        sample = list(frames)[:1] + list(frames)[-1:]
        roles, note = infer_roles(vol.data[..., sorted(set(sample))], where=str(vol.path))
    return roles, note


def _check_roles(vol: LabelVolume, roles: LabelRoles) -> None:
    present = {0} | set(label_counts(vol.data).nonzero()[0].tolist())
    check_values(present, roles, str(vol.path))
    non_zero = sorted(present - {0})
    if len(non_zero) == 1:
        raise StudyError(f"the map holds a single label ({non_zero[0]}): an LV cavity and a "
                         f"myocardium are needed ({roles.describe()})", file=str(vol.path),
                         field="labels")
    for role in ("lv", "myo"):
        if getattr(roles, role) not in present:
            raise StudyError(f"no {role} label ({getattr(roles, role)}) anywhere in the map "
                             f"({roles.describe()})", file=str(vol.path), field="labels")


def _build(subject: str, source: Path, sa: LabelVolume, frames: dict[int, int],
           times: dict[int, float], roles: LabelRoles, note: str | None,
           la: dict[str, tuple[LabelVolume, dict[int, int]]] | None = None,
           meta: dict | None = None) -> Study:
    b = _Builder(subject, source, roles)
    for view_id, (lvol, lframes) in (la or {}).items():
        _add_la(b, view_id, lvol, lframes, times)
    _add_sa(b, sa, frames, times)
    study = b.study
    study.frame_times_ms = {f: times[f] for f in sorted(set(frames.values())) if f in times}
    study.meta.update({"format": "nifti", "labels": roles.describe(), "sa_apex": "taper",
                       "voxel_volumes_ml": voxel_volumes(sa, roles, frames),
                       "metric_notes": {"RVM (g)": "label maps have no RV wall: RV mass not "
                                                   "measured"} if roles.rv_myo is None else {},
                       "contour_files": b.files, **(meta or {})})
    warn = list(sa.warnings) + [w for v, _ in (la or {}).values() for w in v.warnings]
    warn += study.meta.pop("orientation_warnings", [])
    if note:
        warn.append(f"{source}: {note}")
    study.meta["reader_warnings"] = warn + b.flush_warnings()
    _header_meta(study, sa, [v for v, _ in (la or {}).values()])
    return study


def _header_meta(study: Study, sa: LabelVolume, la: list[LabelVolume]) -> None:
    """``meta["headers"]`` (file -> what its header said), ``meta["time_axis"]`` (the SA
    map's); an implausible time axis gives the filling-rate columns (analysis.rates) a reason."""
    study.meta["headers"] = {v.path.name: v.header for v in [sa, *la] if v.header}
    axis = sa.header.get("time") or {}
    study.meta["time_axis"] = axis or None
    if axis.get("plausible") is False:
        step = "no" if axis.get("pixdim4") is None else f"{axis['pixdim4']:g}"
        why = (f"implausible time axis ({sa.path.name}: {step} per frame, unit "
               f"{axis.get('unit')}): filling rates not to be trusted")
        for col in ("PER (mL/s)", "PEFR (mL/s)", "PAFR (mL/s)", "E/A ratio"):
            study.meta["metric_notes"][col] = why


def _unrepeated(warnings: list[str], shown: list[str]) -> list[str]:
    """A long-axis map's warnings less those the SA map's already say about its own file
    (the same time step in every map of a layout is named once)."""
    seen = {w.split(": ", 1)[-1] for w in shown}
    return [w for w in warnings if w.split(": ", 1)[-1] not in seen]


def _times(vol: LabelVolume, frames) -> dict[int, float]:
    if vol.dt_ms is None:
        return {}
    return {f: round(f * vol.dt_ms, 6) for f in frames}


# ------------------------------------------------------------------ layouts
def read_file(path: Path, labels=None) -> Study:
    """One 3-D or 4-D label map (all its slices are the SA stack). A 4-D map named
    ``seg_sa.nii[.gz]`` has ukbb_cardiac's ED and ES (frame 0, the smallest LV cavity), as
    in its folder.

    Parameters
    ----------
    path : pathlib.Path
        The ``.nii``/``.nii.gz`` file.
    labels : str, LabelRoles or None
        The label convention (:func:`cardionurbs.io.labels.parse_labels`); None: inferred.

    Returns
    -------
    Study
    """
    vol = read_label_volume(path)
    if not vol.data.any():
        raise StudyError("the label map is empty (every voxel is 0)", file=str(path))
    fr = _frame_indices(vol)
    roles, note = _resolve_roles(labels, None, vol, fr)
    _check_roles(vol, roles)
    frames = {t: t for t in fr}
    study = _build(_stem(path), path, vol, frames, _times(vol, frames), roles, note,
                   meta={"layout": "file", "label_files": [path.name]})
    if _stem(path) == "seg_sa" and vol.data.shape[3] > 1:
        _ukbb_ed_es(study, vol, roles, frames)     # named as ukbb_cardiac names it: its rule
    return study


def _info_cfg(path: Path) -> dict[str, str]:
    out = {}
    # utf-8-sig: a byte-order mark (as Windows editors write) must not hide the first key
    for line in checked(path, what="Info.cfg").read_text(encoding="utf-8-sig",
                                                          errors="replace").splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            out[k.strip()] = v.strip()
    return out


def read_acdc(folder: Path, labels=None) -> Study:
    """ACDC: patientNNN_frameMM_gt.nii.gz per labelled frame + Info.cfg (ED, ES, Height, Weight).

    Parameters
    ----------
    folder : pathlib.Path
        The patient folder.
    labels : str, LabelRoles or None
        The label convention; None: ``acdc``.

    Returns
    -------
    Study

    Raises
    ------
    StudyError
        A bad Info.cfg value, a missing or mismatched frame map.
    """
    gts = sorted(q for q in folder.iterdir() if re.fullmatch(r".+_frame\d+_gt\.nii(\.gz)?", q.name))
    info_path = folder / "Info.cfg"
    info = _info_cfg(info_path) if info_path.is_file() else {}
    by_frame: dict[int, Path] = {}
    for q in gts:
        number = re.search(r"_frame(\d+)_gt", q.name)
        assert number is not None                   # the fullmatch above holds it
        by_frame[int(number.group(1)) - 1] = q
    ed = es = None
    for key in ("ED", "ES"):
        if key in info:
            try:
                n = int(float(info[key])) - 1
            except ValueError:
                raise StudyError(f"{key} is not a frame number: {info[key]!r}", file=str(info_path),
                                 field=key) from None
            if n not in by_frame:
                raise StudyError(f"{key} is frame {n + 1} but there is no "
                                 f"*_frame{n + 1:02d}_gt label map", file=str(info_path), field=key)
            ed, es = (n, es) if key == "ED" else (ed, n)
    vols = {f: read_label_volume(q) for f, q in sorted(by_frame.items())}
    first = next(iter(vols.values()))
    for f, v in vols.items():
        if v.data.shape[3] != 1:
            raise StudyError("an ACDC frame label map must be 3-D", file=str(v.path))
        if not v.same_grid(first):
            raise StudyError(f"frame {f + 1} does not share the grid (shape and affine) of "
                             f"{first.path.name}: mismatched label maps", file=str(v.path))
    data = np.concatenate([v.data for v in vols.values()], axis=3)
    sa = LabelVolume(first.path.with_name(re.sub(r"_frame\d+_gt", "_gt", first.path.name)), data,
                     first.affine, None, [w for v in vols.values() for w in v.warnings], first.header)
    if not data.any():
        raise StudyError("the label maps are empty (every voxel is 0)", file=str(first.path))
    frames = {i: f for i, f in enumerate(vols)}
    roles, note = _resolve_roles(labels, "acdc", sa, range(len(frames)))
    for v in vols.values():
        _check_roles(v, roles)
    subject = re.sub(r"_frame\d+_gt.*$", "", first.path.name)
    meta = {"layout": "acdc", "label_files": [v.path.name for v in vols.values()]}
    for key, name in (("Height", "height_cm"), ("Weight", "weight_kg"), ("Group", "group")):
        if key in info:
            meta[name] = info[key]
    images = [q.name for q in folder.iterdir() if re.fullmatch(r".+_4d\.nii(\.gz)?", q.name)]
    if images:
        meta["image_files"] = images
    study = _build(subject, folder, sa, frames, {}, roles, note, meta=meta)
    _layout_ed_es(study, ed, es, "ACDC Info.cfg (ED, ES)")
    return study


def _find(folder: Path, stem: str) -> Path | None:
    for ext in (".nii.gz", ".nii"):
        if (folder / (stem + ext)).is_file():
            return folder / (stem + ext)
    return None


def read_ukbb(folder: Path, labels=None) -> Study:
    """UK Biobank / ukbb_cardiac: seg_sa (4-D) or seg_sa_ED + seg_sa_ES; LA maps where present.

    Parameters
    ----------
    folder : pathlib.Path
        The subject folder.
    labels : str, LabelRoles or None
        The label convention; None: ``ukbb``.

    Returns
    -------
    Study
    """
    sa_path = _find(folder, "seg_sa")
    meta: dict = {"layout": "ukbb"}
    if sa_path is not None:
        sa = read_label_volume(sa_path)
        files = [sa_path.name]
    else:
        ed_p, es_p = _find(folder, "seg_sa_ED"), _find(folder, "seg_sa_ES")
        if ed_p is None or es_p is None:
            raise StudyError("UK Biobank layout needs seg_sa.nii.gz, or both seg_sa_ED.nii.gz and "
                             "seg_sa_ES.nii.gz", file=str(folder))
        v_ed, v_es = read_label_volume(ed_p), read_label_volume(es_p)
        for v in (v_ed, v_es):
            if v.data.shape[3] != 1:
                raise StudyError("seg_sa_ED/ES must be 3-D label maps", file=str(v.path))
        if not v_ed.same_grid(v_es):
            raise StudyError(f"seg_sa_ES does not share the grid (shape and affine) of {ed_p.name}: "
                             "mismatched ED/ES label maps", file=str(es_p))
        sa = LabelVolume(folder / "seg_sa_ED+ES", np.concatenate([v_ed.data, v_es.data], axis=3),
                         v_ed.affine, None, v_ed.warnings + v_es.warnings, v_ed.header)
        files = [ed_p.name, es_p.name]
    if not sa.data.any():
        raise StudyError("the label map is empty (every voxel is 0)", file=str(sa.path))
    fr = _frame_indices(sa)
    roles, note = _resolve_roles(labels, "ukbb", sa, fr)
    _check_roles(sa, roles)
    frames = {t: t for t in fr}
    times = _times(sa, frames)
    la: dict = {}
    skipped: list[str] = []
    for view_id, stems in LA_FILES.items():
        got = _ukbb_la(folder, stems, sa, roles, paired=sa_path is None, skipped=skipped)
        if got is not None:
            la[view_id] = (got[0], frames)
            files += got[1]
    meta["label_files"] = files
    images = [q.name for q in folder.iterdir()
              if re.fullmatch(r"(sa|la_[234]ch)\.nii(\.gz)?", q.name)]
    if images:
        meta["image_files"] = sorted(images)
    study = _build(folder.name, folder, sa, frames, times, roles, note, la=la, meta=meta)
    study.meta["reader_warnings"] += skipped
    if sa_path is None:
        _layout_ed_es(study, 0, 1, "ukbb_cardiac: seg_sa_ED and seg_sa_ES")
    else:
        _ukbb_ed_es(study, sa, roles, frames)
    return study


def _ukbb_ed_es(study: Study, sa: LabelVolume, roles: LabelRoles, frames: dict[int, int]) -> None:
    """ukbb_cardiac's ED and ES of a 4-D ``seg_sa``: the first frame, and the frame of the
    smallest LV cavity by voxel count (where frame 0 is labelled)."""
    if 0 not in frames:
        return
    es = _smallest_lv_cavity(sa, roles, frames)
    if es == 0:
        study.ed_frame = 0
    else:
        _layout_ed_es(study, 0, es, f"ukbb_cardiac: ED the first frame, ES the frame of the "
                                    f"smallest LV cavity by voxel count ({es})")


#: a long-axis map's LV cavity is bordered by myocardium over at least this share of its
#: boundary (median over its labelled slices and frames; the rest is the mitral opening): a
#: ventricular map gives 0.6-0.9, ukbb_cardiac's atrial ``seg_la_4ch`` (1 LA, 2 RA, which
#: touch only along the atrial septum) well under it
MIN_LA_WALL_FRACTION = 0.45
#: the gap (pixels) between a long-axis map's cavity and wall labels still read as touching
WALL_GAP_PX = 2


def _not_ventricular(vol: LabelVolume, roles: LabelRoles, present: set[int]) -> str | None:
    """Why a long-axis map does not label the ventricles in ``roles`` (None when it does): no
    LV cavity or myocardium label, or a "cavity" the "myocardium" borders too little of (the
    atria of ukbb_cardiac's ``seg_la_2ch``/``seg_la_4ch``, labelled 1 LA and 2 RA)."""
    if not {roles.lv, roles.myo} <= present:
        return f"no LV cavity and myocardium labels ({roles.describe()})"
    # the myocardium taken 2 px wider: a map whose labels leave a thin gap between cavity and
    # wall (an eroded or hand-drawn myocardium) is still ventricular; the atria stay apart
    fr = [masks.ring_fraction(vol.data[:, :, k, t] == roles.lv,
                              ndimage.binary_dilation(vol.data[:, :, k, t] == roles.myo,
                                                      iterations=WALL_GAP_PX))
          for t in range(vol.data.shape[3]) for k in range(vol.data.shape[2])]
    fr = [f for f in fr if np.isfinite(f)]
    share = float(np.median(fr)) if fr else 0.0
    if share < MIN_LA_WALL_FRACTION:
        return (f"label {roles.myo} borders label {roles.lv} over {share:.0%} of its boundary (a "
                f"ventricular map: > {MIN_LA_WALL_FRACTION:.0%}), so they are not the LV cavity "
                f"and myocardium of {roles.describe()}")
    return None


def _ukbb_la(folder: Path, stems: tuple[str, ...], sa: LabelVolume, roles: LabelRoles, *,
             paired: bool, skipped: list[str]) -> tuple[LabelVolume, list[str]] | None:
    """One view's long-axis map of a ukbb_cardiac folder, on the SA map's frames: the cine map
    (``seg4_la_4ch``, ...) with as many frames, or, beside ``seg_sa_ED`` + ``seg_sa_ES``, the
    ``<stem>_ED`` + ``<stem>_ES`` pair ukbb_cardiac writes with them. None (the reason appended
    to ``skipped``) when absent, on other frames, or not a ventricular map."""
    for stem in stems:
        p = _find(folder, stem)
        pair = (_find(folder, f"{stem}_ED"), _find(folder, f"{stem}_ES"))
        if paired and None not in pair:
            assert pair[0] is not None and pair[1] is not None
            try:
                v = _ed_es_pair(pair[0], pair[1], folder / f"{stem}_ED+ES")
            except StudyError as exc:
                skipped.append(f"{exc}: long-axis maps left out")
                return None
            names = [pair[0].name, pair[1].name]
        elif p is not None:
            v, names = read_label_volume(p), [p.name]
        else:
            if None not in pair:
                skipped.append(f"{folder}: {stem}_ED/_ES beside a 4-D seg_sa, whose frames they "
                               f"do not name: long-axis maps left out (the cine {stem} is used)")
            continue
        v.warnings = _unrepeated(v.warnings, sa.warnings)
        if v.data.shape[3] != sa.data.shape[3]:
            skipped.append(f"{v.path}: {v.data.shape[3]} frame(s) where the SA map has "
                           f"{sa.data.shape[3]}: long-axis map left out")
            return None
        present = {int(x) for x in np.unique(v.data)} - {0}
        problem = _not_ventricular(v, roles, present)
        if problem:
            skipped.append(f"{v.path}: {problem}: an atrial segmentation? long-axis map left out")
            continue
        check_values(present, roles, str(v.path))
        return v, names
    return None


def _smallest_lv_cavity(vol: LabelVolume, roles: LabelRoles, frames: dict[int, int]) -> int:
    """The study frame whose LV cavity has the fewest voxels (the first of equals)."""
    counts = {frame: int(np.count_nonzero(vol.data[..., t] == roles.lv)) for t, frame in frames.items()}
    return min(sorted(counts), key=lambda f: counts[f])


def _layout_ed_es(study: Study, ed: int | None, es: int | None, source: str) -> None:
    """Set ED and ES as the layout defines them; the model uses them as given
    (``meta["ed_es_given"]``) and ``meta["ed_es_source"]`` says where they come from."""
    study.ed_frame, study.es_frame = ed, es
    if ed is not None and es is not None and ed != es:
        study.meta["ed_es_given"] = ["ED", "ES"]
        study.meta["ed_es_source"] = source


#: how far above a subject folder the M&Ms dataset table is looked for: the challenge ships
#: it at the dataset root, OpenDataset/<split>/[Labeled/]<code>/ (read with --allow-outside)
MNMS_CSV_LEVELS = 3


def _mnms_csv(folder: Path, code: str) -> tuple[int, int] | None:
    for d in (folder, *list(folder.resolve().parents)[:MNMS_CSV_LEVELS]):
        for q in sorted(d.glob("*.csv")):
            if not (outside_allowed() or is_inside(folder, q)):
                continue                        # the dataset's table beside the study: opt-in
            try:
                with q.open(newline="", encoding="utf-8-sig", errors="replace") as fh:
                    for row in csv.DictReader(fh):
                        row = {k.strip(): v for k, v in row.items() if k}
                        if row.get("External code", "").strip() == code and "ED" in row and "ES" in row:
                            return int(float(row["ED"])), int(float(row["ES"]))
            except (OSError, ValueError, csv.Error):
                continue
    return None


def read_mnms(folder: Path, labels=None, ed_frame: int | None = None,
              es_frame: int | None = None) -> Study:
    """M&Ms: <code>_sa_gt.nii.gz (4-D, ED and ES labelled); ED/ES from arguments or a CSV.

    Parameters
    ----------
    folder : pathlib.Path
        The subject folder.
    labels : str, LabelRoles or None
        The label convention; None: ``mnms``.
    ed_frame, es_frame : int or None
        ED and ES frame indices (0-based); None: from the dataset's CSV, else the labelled
        frames.

    Returns
    -------
    Study
    """
    gts = sorted(q for q in folder.iterdir() if re.fullmatch(r".+_sa_gt\.nii(\.gz)?", q.name))
    if len(gts) != 1:
        raise StudyError(f"M&Ms layout needs one *_sa_gt.nii.gz, found {len(gts)}", file=str(folder))
    sa = read_label_volume(gts[0])
    code = re.sub(r"_sa_gt.*$", "", gts[0].name)
    if not sa.data.any():
        raise StudyError("the label map is empty (every voxel is 0)", file=str(sa.path))
    source = "given (--ed-frame/--es-frame)"
    if ed_frame is None and es_frame is None:
        got = _mnms_csv(folder, code)
        if got is not None:
            ed_frame, es_frame = got
            source = "M&Ms CSV (External code, ED, ES)"
    n_t = sa.data.shape[3]
    for name, v in (("ED", ed_frame), ("ES", es_frame)):
        if v is not None and not (0 <= v < n_t):
            raise StudyError(f"{name} frame {v} is outside the map's {n_t} frames", file=str(sa.path),
                             field=name)
        if v is not None and not sa.data[..., v].any():
            raise StudyError(f"{name} frame {v} has no labels", file=str(sa.path), frame=v, field=name)
    fr = _frame_indices(sa)
    if ed_frame is not None and es_frame is not None:
        fr = sorted({ed_frame, es_frame})
    roles, note = _resolve_roles(labels, "mnms", sa, fr)
    _check_roles(sa, roles)
    frames = {t: t for t in fr}
    meta = {"layout": "mnms", "label_files": [gts[0].name]}
    img = _find(folder, f"{code}_sa")
    if img is not None:
        meta["image_files"] = [img.name]
    study = _build(code, folder, sa, frames, _times(sa, frames), roles, note, meta=meta)
    _layout_ed_es(study, ed_frame, es_frame, source)
    if ed_frame is None and es_frame is None:
        where = (f"the subject folder or the {MNMS_CSV_LEVELS} above it" if outside_allowed()
                 else "the subject folder (one above it is read with --allow-outside)")
        study.meta["reader_warnings"].append(
            f"{folder}: no row for {code} in an M&Ms dataset table (a *.csv with External code, "
            f"ED, ES) in {where}: ED and ES from the LV volumes of the labelled frames "
            f"{', '.join(map(str, fr))}")
    return study


def read_mnms2(folder: Path, labels=None) -> Study:
    """M&Ms-2: ``NNN_SA_ED_gt`` + ``NNN_SA_ES_gt`` (3-D SA maps, frames 0 = ED and 1 = ES) and
    ``NNN_LA_ED_gt`` + ``NNN_LA_ES_gt`` (one 4-chamber slice each) where present; images
    ``NNN_{SA,LA}_{ED,ES}`` beside them; label preset ``mnms`` (1 LV, 2 MYO, 3 RV).

    Parameters
    ----------
    folder : pathlib.Path
        The subject folder.
    labels : str, LabelRoles or None
        The label convention; None: ``mnms``.

    Returns
    -------
    Study
    """
    found: dict[tuple[str, str], Path] = {}
    codes = set()
    for q in sorted(folder.iterdir()):
        m = _MNMS2.fullmatch(q.name)
        if m:
            codes.add(m["code"])
            found[(m["view"], m["phase"])] = q
    if len(codes) != 1:
        raise StudyError(f"M&Ms-2 layout needs the maps of one subject, found {len(codes)} "
                         f"({', '.join(sorted(codes))})", file=str(folder))
    code = codes.pop()
    missing = [f"{code}_SA_{ph}_gt.nii.gz" for ph in ("ED", "ES") if ("SA", ph) not in found]
    if missing:
        raise StudyError(f"M&Ms-2 layout needs {missing[0]}", file=str(folder))
    sa = _ed_es_pair(found[("SA", "ED")], found[("SA", "ES")], folder / f"{code}_SA_ED+ES")
    if not sa.data.any():
        raise StudyError("the label maps are empty (every voxel is 0)", file=str(sa.path))
    frames = {0: 0, 1: 1}
    roles, note = _resolve_roles(labels, "mnms", sa, [0, 1])
    _check_roles(sa, roles)
    meta: dict = {"layout": "mnms2", "label_files": [found[("SA", p)].name for p in ("ED", "ES")]}
    la, skipped = {}, []
    if ("LA", "ED") in found and ("LA", "ES") in found:
        try:
            lvol = _ed_es_pair(found[("LA", "ED")], found[("LA", "ES")], folder / f"{code}_LA_ED+ES")
            present = {int(x) for x in np.unique(lvol.data)} - {0}
            check_values(present, roles, str(lvol.path))
            problem = _not_ventricular(lvol, roles, present)
            if problem:
                raise StudyError(problem, file=str(lvol.path))
            la["la_4ch"] = (lvol, frames)
            meta["label_files"] += [found[("LA", p)].name for p in ("ED", "ES")]
        except StudyError as exc:
            skipped.append(f"{exc}: long-axis maps left out")
    elif ("LA", "ED") in found or ("LA", "ES") in found:
        skipped.append(f"{folder}: only one of {code}_LA_ED_gt / {code}_LA_ES_gt: long-axis maps "
                       "left out")
    images = [q.name for q in folder.iterdir()
              if re.fullmatch(rf"{re.escape(code)}_(SA|LA)_(ED|ES)\.nii(\.gz)?", q.name)]
    if images:
        meta["image_files"] = sorted(images)
    study = _build(code, folder, sa, frames, {}, roles, note, la=la, meta=meta)
    study.meta["reader_warnings"] += skipped
    _layout_ed_es(study, 0, 1, "M&Ms-2 file names (SA_ED, SA_ES)")
    return study


def _ed_es_pair(ed_p: Path, es_p: Path, name: Path) -> LabelVolume:
    """Two 3-D maps on one grid (ED, ES) as one 2-frame volume (StudyError naming the file)."""
    v_ed, v_es = read_label_volume(ed_p), read_label_volume(es_p)
    for v in (v_ed, v_es):
        if v.data.shape[3] != 1:
            raise StudyError("an ED or ES label map must be 3-D", file=str(v.path))
    if not v_ed.same_grid(v_es):
        raise StudyError(f"does not share the grid (shape and affine) of {ed_p.name}: mismatched "
                         "ED/ES label maps", file=str(es_p))
    return LabelVolume(name, np.concatenate([v_ed.data, v_es.data], axis=3), v_ed.affine, None,
                       v_ed.warnings + v_es.warnings, v_ed.header)


def read_study(path: str | Path, *, labels: "str | LabelRoles | None" = None,
               ed_frame: int | None = None, es_frame: int | None = None) -> Study:
    """Read a label-map study in any layout (:func:`detect`); ``labels`` is a preset name,
    a ``lv=…,myo=…,rv=…`` mapping or None (the layout's preset; for a single file, inferred
    from topology with a warning). Reader warnings are in ``study.meta["reader_warnings"]``.

    Parameters
    ----------
    path : str or pathlib.Path
        A label-map file or a dataset folder.
    labels : str, LabelRoles or None
        As above.
    ed_frame, es_frame : int or None
        ED and ES frame indices (0-based; M&Ms, a single file).

    Returns
    -------
    Study
        In scanner LPS mm, with ``meta["voxel_volumes_ml"]`` (the voxel-count reference).

    Raises
    ------
    StudyError
        An unreadable, unsafe or inconsistent map (naming file, slice, frame and field).
    """
    p = Path(path)
    if not p.exists():
        raise StudyError("no such file or folder", file=str(p))
    layout = detect(p)
    if layout is None:
        if p.is_file():
            raise StudyError("not a NIfTI file (expected a .nii or .nii.gz name)", file=str(p))
        raise StudyError("no NIfTI label maps in a known layout (a single .nii/.nii.gz file, ACDC "
                         "*_frameMM_gt, UK Biobank seg_sa, M&Ms *_sa_gt, M&Ms-2 NNN_SA_ED_gt)", file=str(p))
    if layout == "file":
        study = read_file(p, labels)
    elif layout == "acdc":
        study = read_acdc(p, labels)
    elif layout == "ukbb":
        study = read_ukbb(p, labels)
    elif layout == "mnms2":
        study = read_mnms2(p, labels)
    else:
        study = read_mnms(p, labels, ed_frame, es_frame)
    given = {k: v for k, v in (("ED", ed_frame), ("ES", es_frame)) if v is not None}
    if given:
        _check_given_frames(study, given)
        if ed_frame is not None:
            study.ed_frame = int(ed_frame)
        if es_frame is not None:
            study.es_frame = int(es_frame)
        layout_given = set(study.meta.get("ed_es_given") or ())
        study.meta["ed_es_given"] = sorted(set(given) | layout_given)
        study.meta["ed_es_source"] = ("given (--ed-frame/--es-frame)" if not layout_given - set(given)
                                      else f"{'/'.join(sorted(given))} given, the rest from the "
                                           f"layout ({study.meta.get('ed_es_source')})")
    return study


def _check_given_frames(study: Study, given: dict[str, int]) -> None:
    """ED/ES frames named by the user must be distinct labelled frames of the study."""
    labelled = sorted({c.frame for c in study.contours if c.structure == "lv_endo"})
    shown = ", ".join(map(str, labelled[:12])) + (", ..." if len(labelled) > 12 else "")
    for name, v in given.items():
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise StudyError(f"{name} frame must be a whole number >= 0, got {v!r}",
                             file=study.source, field=f"{name.lower()}_frame")
        if v not in labelled:
            raise StudyError(f"{name} frame {v} is not a labelled frame of the map (frames with an "
                             f"LV cavity: {shown})", file=study.source, field=f"{name.lower()}_frame")

