"""DICOM cine series -> image planes in scanner coordinates (pydicom).

:func:`read_dicom_folder` reads every DICOM file under a folder (recursively),
headers only unless ``pixels=True``, and returns a :class:`DicomSeries`: one
:class:`~cardionurbs.imaging.geometry.ImagePlane` per image, with

* **slices**: images grouped by series (SeriesInstanceUID) and slice position
  (plane normal, then position along it, within 0.01 mm);
* **views**: the largest group of parallel slices is the short-axis stack
  (``sa_00`` at the base ... ``sa_NN`` at the apex, see
  :mod:`cardionurbs.imaging.stack`), other slices are long-axis views named
  from their SeriesDescription (``la_2ch``, ``la_3ch``, ``la_4ch``) or
  ``la_<k>`` (k = 1, 2, ... by SeriesNumber);
* **frames**: per slice, by TriggerTime (:func:`cardionurbs.imaging.phases.phase_indices`);
* **geometry**: pixel <-> scanner by DICOM PS3.3 C.7.6.2.1.1 (ImagePositionPatient,
  ImageOrientationPatient, PixelSpacing); slice spacing from positions;
* **heart rate** from HeartRate (0018,1088), else NominalInterval (0018,1062).

Enhanced (multi-frame) MR objects are read frame by frame from their
functional groups (PS3.3 C.7.6.16: PlanePositionSequence,
PlaneOrientationSequence, PixelMeasuresSequence, CardiacSynchronizationSequence
NominalCardiacTriggerDelayTime); each frame is one image with id
``<SOPInstanceUID>#<frame number>``.
"""

from __future__ import annotations

import math
import re
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
import pydicom
from pydicom.errors import InvalidDicomError

from cardionurbs.errors import StudyError, UnsupportedInputError
from cardionurbs.geometry import slice_spacing, stack_normal
from cardionurbs.confine import checked, files_inside
from cardionurbs.safe import excerpt
from cardionurbs.imaging import phases, stack
from cardionurbs.imaging.geometry import ImagePlane

#: SOP classes of multi-frame ("enhanced") MR objects.
ENHANCED_MR_SOP_CLASSES = {
    "1.2.840.10008.5.1.4.1.1.4.1": "Enhanced MR Image Storage",
    "1.2.840.10008.5.1.4.1.1.4.3": "Enhanced MR Color Image Storage",
    "1.2.840.10008.5.1.4.1.1.4.4": "Legacy Converted Enhanced MR Image Storage",
}
#: file suffixes that are never DICOM (skipped when scanning a folder).
NOT_DICOM_SUFFIXES = {".txt", ".csv", ".json", ".md", ".png", ".jpg", ".jpeg", ".html", ".toml",
                      ".xml", ".py", ".npz", ".npy", ".stl", ".obj", ".ply", ".zip", ".gz",
                      ".pdf", ".log", ".yaml", ".yml"}
#: slices of one series closer than this along their normal are one slice, mm.
SLICE_POSITION_TOL_MM = 0.01
#: normals closer than this angle are one orientation within a series, degrees.
ORIENTATION_TOL_DEG = 0.01


@contextmanager
def _quiet_pydicom() -> Iterator[None]:
    """Read leniently and silently: no pydicom validation warnings on stderr."""
    cfg = pydicom.config.settings
    old = cfg.reading_validation_mode
    cfg.reading_validation_mode = pydicom.config.IGNORE
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        cfg.reading_validation_mode = old


@dataclass(frozen=True, eq=False)
class DicomHeader:
    """The header fields of one image file that geometry and timing need.

    Attributes
    ----------
    file : pathlib.Path
        The DICOM file the image is in.
    sop_instance_uid : str
        SOPInstanceUID (0008,0018): the image's id.
    series_instance_uid : str
        SeriesInstanceUID (0020,000E).
    series_number : int or None
        SeriesNumber (0020,0011).
    series_description : str
        SeriesDescription (0008,103E), ``""`` when absent.
    instance_number : int or None
        InstanceNumber (0020,0013).
    position : ndarray, shape (3,)
        ImagePositionPatient: the centre of the first pixel, in mm (scanner coordinates).
    orientation : ndarray, shape (6,)
        ImageOrientationPatient: row direction cosine, then column direction cosine.
    pixel_spacing : tuple of (float, float)
        PixelSpacing: (between rows, between columns), in mm.
    rows : int
        Rows (pixels per column).
    columns : int
        Columns (pixels per row).
    thickness : float or None
        SliceThickness, in mm.
    trigger_time : float or None
        TriggerTime: time after the R wave, in ms.
    heart_rate : float or None
        HeartRate, in beats/min.
    nominal_interval : float or None
        NominalInterval: the R-R interval, in ms.
    cardiac_number_of_images : int or None
        CardiacNumberOfImages: phases per cycle.
    frame_number : int or None
        The 1-based frame of a multi-frame (enhanced) object, None for a classic image.
    patient_id : str
        PatientID (0010,0020).
    study_instance_uid : str
        StudyInstanceUID (0020,000D).
    frame_of_reference_uid : str
        FrameOfReferenceUID (0020,0052).
    normal : ndarray, shape (3,)
        The unit image normal, row cosine × column cosine.
    """

    file: Path
    sop_instance_uid: str
    series_instance_uid: str
    series_number: int | None
    series_description: str
    instance_number: int | None
    position: np.ndarray
    orientation: np.ndarray
    pixel_spacing: tuple[float, float]
    rows: int
    columns: int
    thickness: float | None
    trigger_time: float | None
    heart_rate: float | None
    nominal_interval: float | None
    cardiac_number_of_images: int | None
    frame_number: int | None = None  # 1-based frame of a multi-frame (enhanced) object
    patient_id: str = ""
    study_instance_uid: str = ""
    frame_of_reference_uid: str = ""

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.orientation[:3], self.orientation[3:])
        return n / np.linalg.norm(n)


def _numbers(ds, keyword: str, count: int, path: Path, required: bool = True):
    """Tag ``keyword`` of ``ds`` as a float array of ``count`` finite numbers."""
    value = ds.get(keyword)
    if value is None or value == "":
        if required:
            raise StudyError(_missing(keyword), file=path, field=keyword)
        return None
    try:
        seq = list(value) if isinstance(value, (list, tuple, pydicom.multival.MultiValue)) else [value]
        arr = np.array([float(v) for v in seq], dtype=float)
    except (TypeError, ValueError):
        raise StudyError(f"{keyword} is not numeric ({excerpt(value)})", file=path, field=keyword) from None
    if arr.size != count or not np.all(np.isfinite(arr)):
        raise StudyError(f"{keyword} must be {count} finite number(s), got {excerpt(value)}", file=path,
                         field=keyword)
    return arr


def _opt_number(ds, keyword: str, path: Path) -> float | None:
    arr = _numbers(ds, keyword, 1, path, required=False)
    return None if arr is None else float(arr[0])


def _dcmread(path: Path, pixels: bool):
    checked(path, what="DICOM file")
    try:
        with _quiet_pydicom():
            return pydicom.dcmread(path, stop_before_pixels=not pixels)
    except InvalidDicomError:
        raise StudyError("not a DICOM file (no DICM preamble)", file=path) from None
    except (OSError, EOFError, ValueError, TypeError, KeyError, IndexError, AttributeError,
            NotImplementedError, OverflowError, MemoryError) as exc:
        raise StudyError(f"unreadable DICOM ({type(exc).__name__}: {_first_line(exc)})",
                         file=path) from None
    except Exception as exc:  # noqa: BLE001 - struct.error and friends from a truncated file
        raise StudyError(f"unreadable DICOM ({type(exc).__name__}: {_first_line(exc)})",
                         file=path) from None


def _dcmread_header(path: Path):
    """(dataset without pixel data, file offset of the PixelData element or None)."""
    checked(path, what="DICOM file")
    try:
        with open(path, "rb") as f:
            with _quiet_pydicom():
                ds = pydicom.dcmread(f, stop_before_pixels=True)
            offset = f.tell()
    except StudyError:
        raise
    except OSError:
        return _dcmread(path, pixels=False), None
    except Exception:  # noqa: BLE001 - the path-based read names the problem
        return _dcmread(path, pixels=False), None
    at_pixels = offset < path.stat().st_size
    return ds, offset if at_pixels else None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def headers_from_dataset(ds, path: Path) -> list[DicomHeader]:
    """One :class:`DicomHeader` per image: one for a classic image, one per frame of an
    enhanced (multi-frame) MR object.

    Parameters
    ----------
    ds : pydicom.Dataset
        A read DICOM dataset (its pixel data need not be loaded).
    path : pathlib.Path
        The file it was read from, for the messages.

    Returns
    -------
    list of DicomHeader
        One per image, in frame order.

    Raises
    ------
    cardionurbs.errors.StudyError
        A geometry tag is missing or not a number (the message names the file and the tag).
    """
    with _quiet_pydicom():
        if _is_multiframe(ds, path):
            return _enhanced_headers(ds, Path(path))
        return [_header_from_dataset(ds, Path(path))]


def _is_multiframe(ds, path: Path) -> bool:
    try:
        sop_class = str(ds.get("SOPClassUID", "") or "")
        n_frames = ds.get("NumberOfFrames", None)
        n_frames = int(n_frames) if n_frames not in (None, "") else 1
    except Exception as exc:  # noqa: BLE001 - a truncated element can fail on access
        raise StudyError(f"unreadable DICOM header ({_first_line(exc)})", file=path) from None
    return sop_class in ENHANCED_MR_SOP_CLASSES or n_frames > 1


def _check_plane(pos, ori, spacing, path: Path, where: str = "") -> None:
    r, c = ori[:3], ori[3:]
    if abs(np.linalg.norm(r) - 1) > 1e-3 or abs(np.linalg.norm(c) - 1) > 1e-3 or abs(r @ c) > 1e-3:
        raise StudyError(f"{where}ImageOrientationPatient is not two orthonormal vectors "
                         f"({ori.tolist()})", file=path, field="ImageOrientationPatient")
    if np.any(spacing <= 0):
        raise StudyError(f"{where}PixelSpacing must be positive, got {spacing.tolist()}", file=path,
                         field="PixelSpacing")


def _enhanced_headers(ds, path: Path) -> list[DicomHeader]:
    """Per-frame headers of an enhanced MR object (PS3.3 C.7.6.16 multi-frame functional
    groups): plane position, orientation, pixel measures and cardiac trigger delay of each
    frame, from its PerFrameFunctionalGroupsSequence item or the shared one."""
    try:
        n = int(ds.get("NumberOfFrames", 1) or 1)
        per = ds.get("PerFrameFunctionalGroupsSequence")
        shared = ds.get("SharedFunctionalGroupsSequence")
        shared = shared[0] if shared else None
        if per is None or len(per) != n:
            raise StudyError(f"multi-frame object needs a PerFrameFunctionalGroupsSequence with "
                             f"one item per frame (NumberOfFrames = {n}, items = "
                             f"{0 if per is None else len(per)})", file=path,
                             field="PerFrameFunctionalGroupsSequence")
        uid = str(ds.get("SOPInstanceUID", "") or "").strip()
        if not uid:
            raise StudyError("missing SOPInstanceUID (0008,0018)", file=path, field="SOPInstanceUID")
        rows = int(_numbers(ds, "Rows", 1, path)[0])
        cols = int(_numbers(ds, "Columns", 1, path)[0])
        series_no = _opt_number(ds, "SeriesNumber", path)
        inst = _opt_number(ds, "InstanceNumber", path)
        out = []
        for i in range(n):
            def group(name):
                for src in (per[i], shared):
                    if src is not None and name in src and len(src[name].value):
                        return src[name].value[0]
                return None

            where = f"frame {i + 1}: "
            pp, po = group("PlanePositionSequence"), group("PlaneOrientationSequence")
            pm, cs = group("PixelMeasuresSequence"), group("CardiacSynchronizationSequence")
            for item, kw, seq in ((pp, "ImagePositionPatient", "PlanePositionSequence"),
                                  (po, "ImageOrientationPatient", "PlaneOrientationSequence"),
                                  (pm, "PixelSpacing", "PixelMeasuresSequence")):
                if item is None or item.get(kw) in (None, ""):
                    raise StudyError(f"{where}missing {kw} (in {seq})", file=path, field=kw)
            pos = _numbers(pp, "ImagePositionPatient", 3, path)
            ori = _numbers(po, "ImageOrientationPatient", 6, path)
            spacing = _numbers(pm, "PixelSpacing", 2, path)
            _check_plane(pos, ori, spacing, path, where)
            thickness = _opt_number(pm, "SliceThickness", path)
            out.append(DicomHeader(
                file=path, sop_instance_uid=f"{uid}#{i + 1}",
                series_instance_uid=str(ds.get("SeriesInstanceUID", "") or ""),
                series_number=None if series_no is None else int(series_no),
                series_description=str(ds.get("SeriesDescription", "") or ""),
                instance_number=None if inst is None else int(inst),
                position=pos, orientation=ori, pixel_spacing=(float(spacing[0]), float(spacing[1])),
                rows=rows, columns=cols,
                thickness=thickness if thickness is not None and thickness > 0 else None,
                trigger_time=None if cs is None else _opt_number(cs, "NominalCardiacTriggerDelayTime", path),
                heart_rate=_opt_number(ds, "HeartRate", path),
                nominal_interval=(None if cs is None else _opt_number(cs, "RRIntervalTimeNominal", path))
                or _opt_number(ds, "NominalInterval", path),
                cardiac_number_of_images=_opt_int(ds, "CardiacNumberOfImages", path),
                frame_number=i + 1))
        return out
    except StudyError:
        raise
    except Exception as exc:  # noqa: BLE001 - malformed functional groups
        raise StudyError(f"unreadable multi-frame header ({type(exc).__name__}: {_first_line(exc)})",
                         file=path) from None


def _opt_int(ds, keyword: str, path: Path) -> int | None:
    v = _opt_number(ds, keyword, path)
    return None if v is None or v < 1 else int(v)


def _header_from_dataset(ds, path: Path) -> DicomHeader:
    try:
        pos = _numbers(ds, "ImagePositionPatient", 3, path)
        ori = _numbers(ds, "ImageOrientationPatient", 6, path)
        spacing = _numbers(ds, "PixelSpacing", 2, path)
        rows = _numbers(ds, "Rows", 1, path)
        cols = _numbers(ds, "Columns", 1, path)
        uid = str(ds.get("SOPInstanceUID", "") or "").strip()
        if not uid:
            raise StudyError("missing SOPInstanceUID (0008,0018)", file=path, field="SOPInstanceUID")
        _check_plane(pos, ori, spacing, path)
        thickness = _opt_number(ds, "SliceThickness", path)
        inst = _opt_number(ds, "InstanceNumber", path)
        series_no = _opt_number(ds, "SeriesNumber", path)
        n_img = _opt_number(ds, "CardiacNumberOfImages", path)
        return DicomHeader(
            file=path, sop_instance_uid=uid,
            series_instance_uid=str(ds.get("SeriesInstanceUID", "") or ""),
            series_number=None if series_no is None else int(series_no),
            series_description=str(ds.get("SeriesDescription", "") or ""),
            instance_number=None if inst is None else int(inst),
            position=pos, orientation=ori, pixel_spacing=(float(spacing[0]), float(spacing[1])),
            rows=int(rows[0]), columns=int(cols[0]),
            thickness=thickness if thickness is not None and thickness > 0 else None,
            trigger_time=_opt_number(ds, "TriggerTime", path),
            heart_rate=_opt_number(ds, "HeartRate", path),
            nominal_interval=_opt_number(ds, "NominalInterval", path),
            cardiac_number_of_images=None if n_img is None or n_img < 1 else int(n_img),
            **_identity(ds),
        )
    except StudyError:
        raise
    except Exception as exc:  # noqa: BLE001 - malformed values in a damaged header
        raise StudyError(f"unreadable DICOM header ({type(exc).__name__}: {_first_line(exc)})",
                         file=path) from None


def _identity(ds) -> dict[str, Any]:
    """PatientID, StudyInstanceUID and FrameOfReferenceUID of a dataset ('' when absent)."""
    return {"patient_id": str(ds.get("PatientID", "") or "").strip(),
            "study_instance_uid": str(ds.get("StudyInstanceUID", "") or "").strip(),
            "frame_of_reference_uid": str(ds.get("FrameOfReferenceUID", "") or "").strip()}


#: header fields that must agree across every image of one study
IDENTITY_FIELDS = (("patient_id", "PatientID"), ("study_instance_uid", "StudyInstanceUID"),
                   ("frame_of_reference_uid", "FrameOfReferenceUID"))


def check_one_subject(headers: list[DicomHeader]) -> None:
    """StudyError when the images belong to more than one patient (PatientID) or study
    (StudyInstanceUID), a missing value counting as one more; or, when every series keeps
    one FrameOfReferenceUID, when series disagree on it (a patient repositioned between
    series). Series that give each image its own FrameOfReferenceUID (as the Sunnybrook
    export does) are not compared. The message names one file of each.

    Parameters
    ----------
    headers : list of DicomHeader
        Every image header of the study.

    Raises
    ------
    cardionurbs.errors.StudyError
        PatientID, StudyInstanceUID or (as above) FrameOfReferenceUID differ between images.
    """
    series_for: dict[str, set[str]] = {}
    for h in headers:
        series_for.setdefault(h.series_instance_uid, set()).add(h.frame_of_reference_uid)
    check_for = all(len(v) == 1 for v in series_for.values())
    for attr, keyword in IDENTITY_FIELDS:
        if attr == "frame_of_reference_uid" and not check_for:
            continue
        first: dict[str, Path] = {}
        for h in headers:
            v = getattr(h, attr)
            if v not in first:
                first[v] = h.file
        if len(first) > 1:
            (a, fa), (b, fb) = list(first.items())[:2]
            raise StudyError(f"images of more than one {keyword}: {fa.name} has {excerpt(a)}, "
                             f"{fb.name} has {excerpt(b)} (one study per folder)", file=fb,
                             field=keyword)


def _pixel_data_short(path: Path, ds, offset: int | None) -> str | None:
    """A message when the file holds fewer pixel-data bytes than Rows x Columns x
    SamplesPerPixel x BitsAllocated/8 x NumberOfFrames promise (uncompressed data only)."""
    try:
        ts = ds.file_meta.get("TransferSyntaxUID") if hasattr(ds, "file_meta") else None
        if ts is not None and getattr(ts, "is_compressed", False):
            return None
        need = (int(ds.Rows) * int(ds.Columns) * int(ds.get("SamplesPerPixel", 1) or 1)
                * int(ds.get("BitsAllocated", 16) or 16) // 8 * int(ds.get("NumberOfFrames", 1) or 1))
    except Exception:  # noqa: BLE001 - the header checks report bad values
        return None
    size = path.stat().st_size
    if offset is None or offset >= size:
        return f"no pixel data ({need} bytes promised)" if need else None
    have = size - offset - 12 if ts is None or not ts.is_implicit_VR else size - offset - 8
    if have < need:
        return f"pixel data holds {max(have, 0)} of the {need} bytes its header promises (truncated)"
    return None


def read_header(path: str | Path) -> DicomHeader:
    """Read and validate the header of one single-frame DICOM image file (no pixel data).

    Parameters
    ----------
    path : path-like
        A single-frame DICOM image file.

    Returns
    -------
    DicomHeader
        Its validated header.

    Raises
    ------
    cardionurbs.errors.UnsupportedInputError
        The file is a multi-frame object.
    cardionurbs.errors.StudyError
        Not DICOM, truncated, or a geometry tag missing (naming the file and the tag).
    """
    headers = read_file_headers(path)
    if len(headers) != 1:
        raise UnsupportedInputError(f"multi-frame object ({len(headers)} frames): read it with "
                                    "read_file_headers", file=path, field="NumberOfFrames")
    return headers[0]


def read_file_headers(path: str | Path) -> list[DicomHeader]:
    """Headers of the images in one DICOM file: one for a classic image, one per frame for
    an enhanced (multi-frame) MR object.

    When a required tag is missing, the file is read once more in full to tell
    a truncated file (it ends before its pixel data) from an incomplete header.

    Parameters
    ----------
    path : path-like
        A DICOM file.

    Returns
    -------
    list of DicomHeader
        One per image (frame) of the file.

    Raises
    ------
    cardionurbs.errors.StudyError
        Not DICOM, truncated (pixel data shorter than Rows x Columns x bits), or a
        geometry tag missing; the message names the file and the tag.
    """
    path = Path(path)
    try:
        ds, offset = _dcmread_header(path)
        headers = headers_from_dataset(ds, path)
        short = _pixel_data_short(path, ds, offset)
        if short:
            raise StudyError(short, file=path, field="PixelData")
        return headers
    except UnsupportedInputError:
        raise
    except StudyError as exc:
        if exc.field in _REQUIRED and str(exc).endswith(_missing(exc.field)) and _is_truncated(path):
            raise StudyError(f"truncated DICOM file (it ends before its pixel data; "
                             f"{_missing(exc.field)})", file=path, field=exc.field) from None
        raise


_REQUIRED = ("ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing", "Rows", "Columns")


def _missing(keyword: str) -> str:
    tag = pydicom.datadict.tag_for_keyword(keyword)
    if tag is None:
        return f"missing {keyword}"
    return f"missing {keyword} ({tag >> 16:04X},{tag & 0xFFFF:04X})"


def _is_truncated(path: Path) -> bool:
    """True when the file has no or too short PixelData for its Rows x Columns x bits."""
    try:
        with _quiet_pydicom():
            ds = pydicom.dcmread(path, force=True)
            if "PixelData" not in ds:
                return True
            need = int(ds.Rows) * int(ds.Columns) * int(ds.get("SamplesPerPixel", 1)) \
                * int(ds.BitsAllocated) // 8 * int(ds.get("NumberOfFrames", 1) or 1)
            return len(ds.PixelData) < need
    except Exception:  # noqa: BLE001 - unreadable enough to be called truncated
        return True


def read_pixels(path: str | Path, frame_number: int | None = None) -> np.ndarray:
    """The pixel array (rows, columns) of one DICOM image file, as float; of frame
    ``frame_number`` (1-based) for a multi-frame object.

    Parameters
    ----------
    path : path-like
        A DICOM image file.
    frame_number : int or None, optional
        The 1-based frame of a multi-frame object (ignored for a single frame).

    Returns
    -------
    ndarray of float, shape (rows, columns)
        The stored pixel values (no rescale applied).

    Raises
    ------
    cardionurbs.errors.StudyError
        The pixel data cannot be decoded (truncated, or compressed without a decoder).
    """
    path = Path(path)
    ds = _dcmread(path, pixels=True)
    try:
        with _quiet_pydicom():
            arr = ds.pixel_array
    except Exception as exc:  # noqa: BLE001 - truncated or compressed pixel data
        raise StudyError(f"cannot decode pixel data ({_first_line(exc)})", file=path,
                         field="PixelData") from None
    if frame_number is not None and int(ds.get("NumberOfFrames", 1) or 1) > 1:
        arr = arr[frame_number - 1]
    return np.asarray(arr, dtype=float)


def find_dicom_files(folder: str | Path, exclude: Iterable[str | Path] = ()) -> list[Path]:
    """Candidate DICOM files under ``folder`` (recursive, sorted, hidden files skipped).

    Files with a suffix in :data:`NOT_DICOM_SUFFIXES` and everything under a
    path in ``exclude`` are left out.

    Parameters
    ----------
    folder : path-like
        The folder to walk (or a single file, returned as is).
    exclude : iterable of path-like, optional
        Files and folders left out (e.g. the contour folders of a Sunnybrook study).

    Returns
    -------
    list of pathlib.Path
        The candidate files, in natural order (``img2`` before ``img10``).

    Raises
    ------
    cardionurbs.errors.StudyError
        A file found is a symbolic link leading out of the study (:func:`~cardionurbs.confine.files_inside`).
    """
    folder = Path(folder)
    if folder.is_file():
        return [folder]
    excl = [Path(e).resolve() for e in exclude]
    out = []
    for p in folder.rglob("*"):
        if not p.is_file() or p.suffix.lower() in NOT_DICOM_SUFFIXES:
            continue
        if any(part.startswith(".") for part in p.relative_to(folder).parts):
            continue
        if excl and any(e == p.resolve() or e in p.resolve().parents for e in excl):
            continue
        out.append(p)
    return sorted(files_inside(folder, out, what="DICOM file"), key=_natural_key)


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(p))]


def read_headers(files: Iterable[Path]) -> list[DicomHeader]:
    """Headers of the DICOM files among ``files``.

    A file with a ``.dcm``/``.ima`` suffix must be readable DICOM; a file with
    another or no suffix that lacks the DICM preamble is skipped.

    Parameters
    ----------
    files : iterable of pathlib.Path
        Candidate DICOM files (:func:`find_dicom_files`).

    Returns
    -------
    list of DicomHeader
        The headers of every image of the DICOM files, in file order.

    Raises
    ------
    cardionurbs.errors.StudyError
        A ``.dcm``, ``.ima`` or ``.dicom`` file that cannot be read, or any DICOM file that is
        truncated or lacks a geometry tag.
    """
    out = []
    for f in files:
        try:
            out.extend(read_file_headers(f))
        except StudyError as exc:
            strict = f.suffix.lower() in (".dcm", ".ima", ".dicom")
            if not strict and str(exc).endswith("not a DICOM file (no DICM preamble)"):
                continue
            raise
    return out


@dataclass(eq=False)
class DicomSeries:
    """Image planes read from a DICOM folder (see :func:`read_dicom_folder`).

    ``images`` carry ``meta`` entries ``instance_number``, ``series_uid``,
    ``series_number``, ``series_description``; ``pixels`` maps image id to
    its pixel array when read with ``pixels=True``.

    Attributes
    ----------
    root : pathlib.Path
        The folder (or file) read.
    images : list of cardionurbs.imaging.geometry.ImagePlane
        Every image plane, SA slices first (base to apex ``sa_00``, ``sa_01`` ...), then LA,
        each by frame (0-based).
    frame_times_ms : dict of int to float
        Frame index -> mean TriggerTime of its images, in ms.
    heart_rate_bpm : float or None
        From HeartRate or NominalInterval (:func:`cardionurbs.imaging.phases.heart_rate_bpm`).
    slice_spacing_mm : float or None
        Median gap between SA slices along their normal, in mm.
    base_apex_rule : str or None
        How the SA stack's base-to-apex direction was decided (None without an SA stack).
    headers : dict of str to DicomHeader
        Image id (SOPInstanceUID) -> its header.
    pixels : dict of str to ndarray
        Image id -> pixel array (rows, columns), float, for the images read so far.
    """

    root: Path
    images: list[ImagePlane]
    frame_times_ms: dict[int, float]
    heart_rate_bpm: float | None
    slice_spacing_mm: float | None
    base_apex_rule: str | None
    headers: dict[str, DicomHeader] = field(default_factory=dict)
    pixels: dict[str, np.ndarray] = field(default_factory=dict)

    def by_instance_number(self) -> dict[int, ImagePlane]:
        """InstanceNumber -> image (StudyError when a number is used twice).

        Returns
        -------
        dict of int to cardionurbs.imaging.geometry.ImagePlane
            InstanceNumber -> image, for the images that have one.

        Raises
        ------
        cardionurbs.errors.StudyError
            Two images share an InstanceNumber.
        """
        out: dict[int, ImagePlane] = {}
        for im in self.images:
            n = im.meta.get("instance_number")
            if n is None:
                continue
            if n in out:
                raise StudyError(f"InstanceNumber {n} is used by two images ({out[n].file} and "
                                 f"{im.file}); cannot tell which one a contour refers to",
                                 file=self.root, field="InstanceNumber")
            out[n] = im
        return out

    def read_pixels(self, image_id: str) -> np.ndarray:
        """Pixel array of one image (read now unless already loaded).

        Parameters
        ----------
        image_id : str
            The image's SOPInstanceUID.

        Returns
        -------
        ndarray of float, shape (rows, columns)
            Its pixel values (kept in :attr:`pixels`).

        Raises
        ------
        cardionurbs.errors.StudyError
            The pixel data cannot be decoded.
        """
        if image_id not in self.pixels:
            h = self.headers[image_id]
            self.pixels[image_id] = read_pixels(h.file, h.frame_number)
        return self.pixels[image_id]


_LA_NAME = re.compile(r"(?<![0-9])([234])\s*-?\s*ch", re.IGNORECASE)


def read_dicom_folder(folder: str | Path, *, pixels: bool = False,
                      exclude: Iterable[str | Path] = (),
                      relative_to: str | Path | None = None) -> DicomSeries:
    """Read every DICOM image under ``folder`` into image planes (see module docstring).

    Parameters
    ----------
    folder : path
        Folder searched recursively (or a single file).
    pixels : bool
        Also read the pixel data (slower); by default headers only.
    exclude : paths
        Sub-folders or files to leave out (e.g. contour folders).
    relative_to : path, optional
        Folder that ``ImagePlane.file`` paths are relative to (default ``folder``).

    Raises
    ------
    StudyError
        No DICOM image, unreadable or truncated file, missing geometry tag,
        duplicate SOPInstanceUID or duplicate (slice, phase); the message names
        the file and the tag.

    Returns
    -------
    DicomSeries
        The image planes, frame times (ms), heart rate (beats/min) and SA slice spacing (mm).
    """
    root = Path(folder)
    if not root.exists():
        raise StudyError("no such file or folder", file=root)
    headers = read_headers(find_dicom_files(root, exclude))
    if not headers:
        raise StudyError("no DICOM image found", file=root)
    check_one_subject(headers)
    base = Path(relative_to) if relative_to is not None else (root if root.is_dir() else root.parent)
    seen: dict[str, Path] = {}
    for h in headers:
        if h.sop_instance_uid in seen:
            raise StudyError(f"SOPInstanceUID {h.sop_instance_uid} also in {seen[h.sop_instance_uid]} "
                             "(duplicate image)", file=h.file, field="SOPInstanceUID")
        seen[h.sop_instance_uid] = h.file
    slices = _group_slices(headers)
    names, views, spacing, rule = _name_slices(slices)
    images: list[ImagePlane] = []
    times: dict[int, list[float]] = {}
    for members, name, view in zip(slices, names, views):
        frames = _frames_of_slice(members, name)
        thick_default = spacing if spacing else 8.0
        for h, fr in zip(members, frames):
            rel = h.file.relative_to(base).as_posix() if h.file.is_relative_to(base) else str(h.file)
            images.append(ImagePlane(
                id=h.sop_instance_uid, slice=name, view=view, frame=int(fr), position=h.position,
                row_cosine=h.orientation[:3], column_cosine=h.orientation[3:],
                pixel_spacing=h.pixel_spacing, rows=h.rows, columns=h.columns,
                thickness=h.thickness if h.thickness else thick_default,
                trigger_time=h.trigger_time, file=rel,
                meta={"instance_number": h.instance_number, "series_uid": h.series_instance_uid,
                      "series_number": h.series_number,
                      "series_description": h.series_description,
                      "frame_number": h.frame_number}))
            if h.trigger_time is not None:
                times.setdefault(int(fr), []).append(h.trigger_time)
    images.sort(key=lambda im: (im.view != "SA", im.slice, im.frame))
    series = DicomSeries(
        root=root, images=images,
        frame_times_ms={f: float(np.mean(v)) for f, v in sorted(times.items())},
        heart_rate_bpm=phases.heart_rate_bpm([h.heart_rate for h in headers],
                                             [h.nominal_interval for h in headers]),
        slice_spacing_mm=spacing, base_apex_rule=rule,
        headers={h.sop_instance_uid: h for h in headers})
    if pixels:
        for im in images:
            series.read_pixels(im.id)
    return series


def _group_slices(headers: list[DicomHeader]) -> list[list[DicomHeader]]:
    """Images grouped by (series, orientation, position along the normal)."""
    by_series: dict[str, list[DicomHeader]] = {}
    for h in headers:
        by_series.setdefault(h.series_instance_uid, []).append(h)
    out: list[list[DicomHeader]] = []
    for uid in sorted(by_series, key=lambda u: (by_series[u][0].series_number or 0, u)):
        hs = by_series[uid]
        normals = np.array([h.normal for h in hs])
        labels = stack.group_parallel(normals, ORIENTATION_TOL_DEG)
        for g in np.unique(labels):
            members = [h for h, lab in zip(hs, labels) if lab == g]
            n0 = members[0].normal
            s = np.array([h.position @ n0 for h in members])
            order = np.argsort(s, kind="stable")
            cuts = np.flatnonzero(np.diff(s[order]) > SLICE_POSITION_TOL_MM) + 1
            for part in np.split(order, cuts):
                out.append([members[i] for i in part])
    return out


def _name_slices(slices: list[list[DicomHeader]]):
    """Slice ids and views (SA stack base->apex, LA by description), spacing, base/apex rule."""
    normals = np.array([s[0].normal for s in slices])
    centers = np.array([_center(s[0]) for s in slices])
    is_sa = stack.split_stack(normals)
    names: list[str] = [""] * len(slices)
    views = ["SA" if m else "LA" for m in is_sa]
    spacing = rule = None
    sa_idx = np.flatnonzero(is_sa)
    if sa_idx.size:
        n = stack_normal(normals[sa_idx])
        u, rule = stack.base_to_apex_direction(n, centers[sa_idx])
        depth = centers[sa_idx] @ u
        spacing = slice_spacing(np.array([slices[i][0].position for i in sa_idx]) @ u)
        spacing = None if math.isnan(spacing) else spacing
        for k, i in enumerate(sa_idx[np.argsort(depth, kind="stable")]):
            names[i] = f"sa_{k:02d}"
    used: set[str] = set()
    la_idx = [i for i in range(len(slices)) if not is_sa[i]]
    la_idx.sort(key=lambda i: (slices[i][0].series_number or 0, slices[i][0].series_instance_uid))
    for k, i in enumerate(la_idx, start=1):
        m = _LA_NAME.search(slices[i][0].series_description)
        name = f"la_{m.group(1)}ch" if m else f"la_{k}"
        if name in used:
            name = f"la_{k}"
        used.add(name)
        names[i] = name
    return names, views, spacing, rule


def _center(h: DicomHeader) -> np.ndarray:
    return (h.position + (h.columns - 1) / 2 * h.pixel_spacing[1] * h.orientation[:3]
            + (h.rows - 1) / 2 * h.pixel_spacing[0] * h.orientation[3:])


def _frames_of_slice(members: list[DicomHeader], name: str) -> np.ndarray:
    """Frame index of each image of one slice (by TriggerTime, see phases.phase_indices)."""
    tt = [h.trigger_time for h in members]
    missing = [h for h in members if h.trigger_time is None]
    if len(members) == 1 and missing:
        return np.zeros(1, dtype=int)
    if missing and len(missing) < len(members):
        raise StudyError(f"TriggerTime missing here but present in other images of slice {name}",
                         file=missing[0].file, field="TriggerTime")
    if missing:
        # no timing at all: acquisition order (InstanceNumber, then file name)
        keys = [(h.instance_number if h.instance_number is not None else 0, _natural_key(h.file))
                for h in members]
        order = sorted(range(len(members)), key=lambda i: keys[i])
        frames = np.empty(len(members), dtype=int)
        frames[order] = np.arange(len(members))
        return frames
    n_phases = _mode([h.cardiac_number_of_images for h in members])
    rr = phases.rr_interval_ms(
        heart_rate_bpm=_mean([h.heart_rate for h in members]),
        nominal_interval_ms=_mean([h.nominal_interval for h in members]))
    try:
        return phases.phase_indices([t for t in tt if t is not None], n_phases, rr, slice=name)
    except StudyError as exc:
        t = np.asarray(tt, float)
        dup = [h.file.name for h in members if np.sum(t == h.trigger_time) > 1]
        raise StudyError(f"{exc} in files {', '.join(dup[:3])}", file=members[0].file.parent) from None


def _mode(values) -> int | None:
    v = [x for x in values if x is not None]
    if not v:
        return None
    vals, counts = np.unique(v, return_counts=True)
    return int(vals[np.argmax(counts)])


def _mean(values) -> float | None:
    v = np.array([x for x in values if x is not None and x > 0], dtype=float)
    return float(v.mean()) if v.size else None
