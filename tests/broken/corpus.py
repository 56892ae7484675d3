"""Small synthetic studies (DICOM + Sunnybrook contours, GPFile, native) and a corpus of
broken variants of them, each with the phrase its one-line error must contain.

Everything is generated into a temporary folder; nothing here reads ../shared/data.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pydicom
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian, generate_uid
from pydicom.valuerep import DSfloat

from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import gpfile, native
from cardionurbs.study import Contour, Landmark, Study

MR_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.4"
ENHANCED_MR_STORAGE = "1.2.840.10008.5.1.4.1.1.4.1"

# an oblique SA orientation (row, column cosines) and its normal
_A, _B = np.deg2rad(35.0), np.deg2rad(25.0)
SA_ROW = np.array([np.cos(_A), np.sin(_A), 0.0])
SA_COL = np.array([-np.sin(_A) * np.cos(_B), np.cos(_A) * np.cos(_B), np.sin(_B)])
SA_NORMAL = np.cross(SA_ROW, SA_COL)
if SA_NORMAL @ np.array([1.0, -1.0, -1.0]) < 0:  # make +normal point base -> apex (LPS prior)
    SA_COL = -SA_COL
    SA_NORMAL = -SA_NORMAL
SA_ORIGIN = np.array([-60.0, -80.0, 40.0])


def ds_text(v: float) -> str:
    """A DICOM DS string (at most 16 characters, as many digits as fit)."""
    return str(DSfloat(float(v), auto_format=True))


def _set_pixel_module(ds: Dataset, rows: int, columns: int, pixels, frames: int | None) -> None:
    """Image Pixel module: 16-bit MONOCHROME2, ``pixels`` or a test pattern
    (one image, or ``frames`` images of a multi-frame object)."""
    ds.Rows, ds.Columns = rows, columns
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated = ds.BitsStored = 16
    ds.HighBit = 15
    ds.PixelRepresentation = 0
    shape = (rows, columns) if frames is None else (frames, rows, columns)
    px = pixels if pixels is not None else (np.arange(int(np.prod(shape))) % 251).reshape(shape)
    ds.PixelData = np.asarray(px, dtype=np.uint16).tobytes()


def write_dicom_image(path: Path, *, position, row, col, spacing=(2.0, 2.0), rows=32, columns=32,
                      trigger_time: float | None = 0.0, instance: int = 1, series_uid: str,
                      series_number: int = 1, description: str = "", sop_uid: str | None = None,
                      thickness: float = 8.0, heart_rate: float | None = 60.0,
                      nominal_interval: float | None = 1000.0, n_phases: int | None = 20,
                      sop_class: str = MR_IMAGE_STORAGE, pixels: np.ndarray | None = None,
                      omit: tuple[str, ...] = (), edit: Callable[[Dataset], None] | None = None) -> str:
    """Write one classic single-frame MR image; returns its SOPInstanceUID."""
    sop_uid = sop_uid or generate_uid()
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop_class
    meta.MediaStorageSOPInstanceUID = sop_uid
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = sop_class
    ds.SOPInstanceUID = sop_uid
    ds.Modality = "MR"
    ds.SeriesInstanceUID = series_uid
    ds.SeriesNumber = series_number
    ds.SeriesDescription = description
    ds.InstanceNumber = instance
    ds.ImagePositionPatient = [ds_text(v) for v in position]
    ds.ImageOrientationPatient = [ds_text(v) for v in np.r_[row, col]]
    ds.PixelSpacing = [ds_text(v) for v in spacing]
    ds.SliceThickness = f"{thickness:g}"
    if trigger_time is not None:
        ds.TriggerTime = f"{trigger_time:.6g}"
    if heart_rate is not None:
        ds.HeartRate = int(heart_rate)
    if nominal_interval is not None:
        ds.NominalInterval = int(nominal_interval)
    if n_phases is not None:
        ds.CardiacNumberOfImages = n_phases
    _set_pixel_module(ds, rows, columns, pixels, frames=None)
    for kw in omit:
        if kw in ds:
            delattr(ds, kw)
    if edit is not None:
        edit(ds)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save_as(path, enforce_file_format=True)
    return sop_uid


def write_enhanced_mr(path: Path, *, positions, row, col, trigger_times, spacing=(2.0, 2.0),
                      rows=32, columns=32, rr_ms: float = 900.0, series_uid: str | None = None,
                      pixels: np.ndarray | None = None, drop_position_of: int | None = None) -> str:
    """Write one Enhanced MR Image Storage object, one frame per (position, trigger time) pair,
    geometry in the functional groups (shared orientation and pixel measures)."""
    n = len(positions)
    sop_uid = generate_uid()
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = ENHANCED_MR_STORAGE
    meta.MediaStorageSOPInstanceUID = sop_uid
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID, ds.Modality = ENHANCED_MR_STORAGE, sop_uid, "MR"
    ds.SeriesInstanceUID = series_uid or generate_uid()
    ds.SeriesNumber, ds.InstanceNumber = 1, 1
    ds.NumberOfFrames = n
    orient = Dataset()
    orient.ImageOrientationPatient = [ds_text(v) for v in np.r_[row, col]]
    measures = Dataset()
    measures.PixelSpacing = [ds_text(v) for v in spacing]
    measures.SliceThickness = "8"
    shared = Dataset()
    shared.PlaneOrientationSequence = [orient]
    shared.PixelMeasuresSequence = [measures]
    ds.SharedFunctionalGroupsSequence = [shared]
    per = []
    for k, (p, t) in enumerate(zip(positions, trigger_times)):
        item = Dataset()
        if k != drop_position_of:
            pos = Dataset()
            pos.ImagePositionPatient = [ds_text(v) for v in p]
            item.PlanePositionSequence = [pos]
        sync = Dataset()
        sync.NominalCardiacTriggerDelayTime = float(t)
        sync.RRIntervalTimeNominal = float(rr_ms)
        item.CardiacSynchronizationSequence = [sync]
        per.append(item)
    ds.PerFrameFunctionalGroupsSequence = per
    _set_pixel_module(ds, rows, columns, pixels, frames=n)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save_as(path, enforce_file_format=True)
    return sop_uid


def circle_pixels(center=(16.0, 15.0), radius=6.0, n=24, phase=0.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + phase
    return np.column_stack([center[0] + radius * np.cos(t), center[1] + radius * np.sin(t)])


def write_contour(path: Path, pix: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"{x:.2f} {y:.2f}\n" for x, y in pix))


# ------------------------------------------------------------------ Sunnybrook-like
SB_PHASES = 20
SB_ED, SB_ES = 19, 7


def make_sunnybrook(root: Path, n_slices: int = 4, spacing_mm: float = 10.0,
                    full_cine: bool = False, seed: int = 0) -> Path:
    """A Sunnybrook-layout study: dicom/ (SA stack, base->apex along +SA_NORMAL),
    i-contours at ED and ES, o-contours at ED. Instance number = slice * 20 + phase + 1."""
    series = generate_uid()
    rr = 900.0
    phases = range(SB_PHASES) if full_cine else (SB_ES, SB_ED)
    for s in range(n_slices):
        pos = SA_ORIGIN + s * spacing_mm * SA_NORMAL
        for k in phases:
            inst = s * SB_PHASES + k + 1
            write_dicom_image(root / "dicom" / f"{inst}.dcm", position=pos, row=SA_ROW, col=SA_COL,
                              trigger_time=k * rr / SB_PHASES + 3.0 + 0.1 * s, instance=inst,
                              series_uid=series, heart_rate=None, nominal_interval=rr,
                              n_phases=SB_PHASES, thickness=8.0)
        for k, r in ((SB_ED, 7.0 - 0.8 * s), (SB_ES, 4.5 - 0.6 * s)):
            inst = s * SB_PHASES + k + 1
            write_contour(root / "i-contours" / f"IM-0001-{inst:04d}-icontour-manual.txt",
                          circle_pixels(radius=r, phase=0.1 * s))
        inst = s * SB_PHASES + SB_ED + 1
        write_contour(root / "o-contours" / f"IM-0001-{inst:04d}-ocontour-manual.txt",
                      circle_pixels(radius=10.0 - 0.8 * s))
    return root


def sb_contour(root: Path, slice_index: int = 1, frame: int = SB_ED, kind: str = "i") -> Path:
    inst = slice_index * SB_PHASES + frame + 1
    return root / f"{kind}-contours" / f"IM-0001-{inst:04d}-{kind}contour-manual.txt"


# ----------------------------------------------------------------- a Study to write
def synthetic_study(frames: int = 2) -> Study:
    """SA stack of 3 slices + one LA slice, LV/RV contours and landmarks, in scanner mm."""
    images, contours, landmarks = [], [], []
    la_row, la_col = SA_NORMAL, SA_ROW  # LA plane containing the long axis
    for f in range(frames):
        for s in range(3):
            images.append(ImagePlane(id=f"sa_{s:02d}_f{f}", slice=f"sa_{s:02d}", view="SA", frame=f,
                                     position=SA_ORIGIN + 10.0 * s * SA_NORMAL, row_cosine=SA_ROW,
                                     column_cosine=SA_COL, pixel_spacing=(2.0, 2.0), rows=32,
                                     columns=32, trigger_time=100.0 * f))
        images.append(ImagePlane(id=f"la_4ch_f{f}", slice="la_4ch", view="LA", frame=f,
                                 position=SA_ORIGIN - 20 * SA_NORMAL + 30 * SA_COL, row_cosine=la_row,
                                 column_cosine=la_col, pixel_spacing=(2.0, 2.0), rows=40, columns=40,
                                 trigger_time=100.0 * f))
    for im in images:
        if im.view == "SA":
            r = 6.0 - im.frame - 0.7 * int(im.slice[-1])
            contours.append(Contour("lv_endo", "SA", im.slice, im.frame,
                                    im.pixel_to_scanner(circle_pixels(radius=r)), image=im.id))
            contours.append(Contour("lv_epi", "SA", im.slice, im.frame,
                                    im.pixel_to_scanner(circle_pixels(radius=r + 3)), image=im.id))
            arc = circle_pixels(center=(16, 15), radius=13, n=12)[:6]
            contours.append(Contour("rv_freewall", "SA", im.slice, im.frame,
                                    im.pixel_to_scanner(arc), image=im.id, closed=False))
            contours.append(Contour("rv_septum", "SA", im.slice, im.frame,
                                    im.pixel_to_scanner(circle_pixels(radius=r + 3, n=12)[:5]),
                                    image=im.id, closed=False))
            for k, p in enumerate(im.pixel_to_scanner([[8.0, 10.0], [9.0, 22.0]])):
                landmarks.append(Landmark("rv_insert", im.frame, p, index=len(
                    [lm for lm in landmarks if lm.name == "rv_insert" and lm.frame == im.frame]),
                    slice=im.slice, view="SA", image=im.id))
        else:
            u = np.linspace(-1, 1, 15)
            pix = np.column_stack([20 + 12 * np.sin(u * 1.4), 20 + 10 * np.cos(u * 1.4)])
            contours.append(Contour("lv_endo", "LA", im.slice, im.frame, im.pixel_to_scanner(pix),
                                    image=im.id, closed=False))
            landmarks.append(Landmark("apex", im.frame, im.pixel_to_scanner([[35.0, 20.0]])[0],
                                      slice=im.slice, view="LA", image=im.id))
            for k, p in enumerate(im.pixel_to_scanner([[5.0, 12.0], [5.0, 28.0]])):
                landmarks.append(Landmark("mitral", im.frame, p, index=k, slice=im.slice,
                                          view="LA", image=im.id))
    return Study("synthetic", images=images, contours=contours, landmarks=landmarks,
                 frame_times_ms={f: 100.0 * f for f in range(frames)}, heart_rate_bpm=60.0,
                 ed_frame=0, es_frame=frames - 1)


def make_gpfile(root: Path) -> Path:
    gpfile.write_study(synthetic_study(), root)
    return root


def make_native(root: Path) -> Path:
    native.write_study(synthetic_study(), root)
    return root


# --------------------------------------------------------------------- the corpus
@dataclass(frozen=True)
class Broken:
    name: str
    build: Callable[[Path], Path]
    expect: str  # a phrase the one-line error message must contain


def _edit(path: Path, fn: Callable[[str], str]) -> None:
    path.write_text(fn(path.read_text()))


def _sb(root: Path, change: Callable[[Path], None], **kw) -> Path:
    make_sunnybrook(root, **kw)
    change(root)
    return root


def _gp(root: Path, change: Callable[[Path], None]) -> Path:
    make_gpfile(root)
    change(root)
    return root


def _nat(root: Path, change: Callable[[Path], None]) -> Path:
    make_native(root)
    change(root)
    return root


def _first_dcm(root: Path) -> Path:
    return sorted((root / "dicom").glob("*.dcm"), key=lambda p: int(p.stem))[0]


def _rewrite_dicom(root: Path, edit: Callable[[Dataset], None], which: int = 0) -> None:
    path = sorted((root / "dicom").glob("*.dcm"), key=lambda p: int(p.stem))[which]
    ds = pydicom.dcmread(path)
    edit(ds)
    ds.save_as(path, enforce_file_format=True)


def _truncate(root: Path) -> None:
    p = _first_dcm(root)
    p.write_bytes(p.read_bytes()[:400])


def _tilt_slice(root: Path) -> None:
    def edit(ds):
        c, s = np.cos(np.deg2rad(8)), np.sin(np.deg2rad(8))
        row = SA_ROW * c + SA_NORMAL * s
        ds.ImageOrientationPatient = [ds_text(v) for v in np.r_[row, SA_COL]]
    for k in (2, 3):  # both images of slice 1
        _rewrite_dicom(root, edit, k)


def _duplicate_slice(root: Path) -> None:
    # a second series repeating slice 0
    for p in sorted((root / "dicom").glob("*.dcm"), key=lambda p: int(p.stem))[:2]:
        ds = pydicom.dcmread(p)
        ds.SeriesInstanceUID = "1.2.3.4.5"
        ds.SOPInstanceUID = generate_uid()
        ds.file_meta.MediaStorageSOPInstanceUID = ds.SOPInstanceUID
        ds.InstanceNumber = int(ds.InstanceNumber) + 1000
        ds.save_as(p.with_name(f"{int(p.stem) + 1000}.dcm"), enforce_file_format=True)


def _copy_file(root: Path) -> None:
    p = _first_dcm(root)
    shutil.copy(p, p.with_name("999.dcm"))


def _text_as_dcm(root: Path) -> None:
    (root / "dicom" / "500.dcm").write_text("this is not DICOM\n")


def _no_trigger(root: Path) -> None:
    _rewrite_dicom(root, lambda ds: delattr(ds, "TriggerTime"), 0)


def _enhanced(root: Path) -> None:
    def edit(ds):
        ds.SOPClassUID = ENHANCED_MR_STORAGE
        ds.file_meta.MediaStorageSOPClassUID = ENHANCED_MR_STORAGE
        ds.NumberOfFrames = 1
    _rewrite_dicom(root, edit, 0)


def _enhanced_no_position(root: Path) -> None:
    write_enhanced_mr(root / "dicom" / "900.dcm", positions=[SA_ORIGIN - 50 * SA_NORMAL] * 2,
                      row=SA_ROW, col=SA_COL, trigger_times=[10.0, 400.0], drop_position_of=1)


def _bad_spacing(root: Path) -> None:
    def edit(ds):
        ds["PixelSpacing"].value = ["0", "2.0"]
    _rewrite_dicom(root, edit, 0)


def _gp_file(root: Path, frame: int = 0) -> Path:
    return root / f"GPFile_{frame:03d}.txt"


def _gp_line(root: Path, k: int, fn: Callable[[list[str]], list[str]]) -> None:
    p = _gp_file(root)
    lines = p.read_text().splitlines()
    lines[k] = "\t".join(fn(lines[k].split("\t")))
    p.write_text("\n".join(lines) + "\n")


def _set(idx: int, value: str) -> Callable[[list[str]], list[str]]:
    def fn(tok):
        tok[idx] = value
        return tok
    return fn


def _gp_off_plane(root: Path) -> None:
    p = _gp_file(root)
    lines = p.read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        t = ln.split("\t")
        if t[3] == "SAX_LV_ENDOCARDIAL":
            t[2] = repr(float(t[2]) + 25.0)
        out.append("\t".join(t))
    p.write_text("\n".join(out) + "\n")


def _gp_frameid(root: Path, change: Callable[[Path], None]) -> Path:
    """The synthetic study written in the CAP export's SliceInfoFile style (frameID:, one line
    per slice and frame with its timeFrame), then broken by ``change``."""
    gpfile.write_study(synthetic_study(), root, style="frameID")
    change(root)
    return root


def _slice_info_lines(root: Path, fn: Callable[[list[str]], list[str]]) -> None:
    p = root / "SliceInfoFile.txt"
    p.write_text("\n".join(fn(p.read_text().splitlines())) + "\n")


def _moved_copy_of_first(lines: list[str]) -> list[str]:
    tok = lines[0].split("\t")
    k = tok.index("ImagePositionPatient") + 1
    tok[k] = repr(float(tok[k]) + 4.0)
    return lines + ["\t".join(tok)]


def _native_csv(root: Path, fn: Callable[[list[str]], list[str]]) -> None:
    """Edit points.csv as a careful user would: study.json's points_rows follows the edit."""
    p = root / "points.csv"
    lines = fn(p.read_text().splitlines())
    p.write_text("\n".join(lines) + "\n")
    _native_manifest(root, lambda m: m.update(points_rows=len(lines) - 1))


def _native_manifest(root: Path, fn: Callable[[dict], None]) -> None:
    p = root / "study.json"
    m = json.loads(p.read_text())
    fn(m)
    p.write_text(json.dumps(m))


def _replace_in_row(k: int, old: str, new: str) -> Callable[[list[str]], list[str]]:
    def fn(lines):
        lines[k] = lines[k].replace(old, new, 1)
        return lines
    return fn


def _figure_eight(root: Path) -> None:
    t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    write_contour(sb_contour(root), np.column_stack([16 + 6 * np.sin(t), 15 + 6 * np.sin(2 * t)]))


def _partial_times(m: dict) -> None:
    m["frame_times_ms"] = {"0": 0.0}


def _missing_dicom_file(m: dict) -> None:
    m["images"][0]["file"] = "dicom/nothere.dcm"


def _lv_endo_missing_at_es(lines: list[str]) -> list[str]:
    head = lines[0].split(",")
    k, f = head.index("name"), head.index("frame")
    return [lines[0]] + [ln for ln in lines[1:]
                         if not (ln.split(",")[k] == "lv_endo" and ln.split(",")[f] == "1")]


CORPUS: list[Broken] = [
    # --- DICOM series (Sunnybrook layout)
    Broken("dicom_truncated", lambda r: _sb(r, _truncate),
           "dicom/8.dcm: field ImagePositionPatient: truncated DICOM file"),
    Broken("dicom_no_orientation", lambda r: _sb(r, lambda r: _rewrite_dicom(
        r, lambda ds: delattr(ds, "ImageOrientationPatient"))), "missing ImageOrientationPatient"),
    Broken("dicom_no_position", lambda r: _sb(r, lambda r: _rewrite_dicom(
        r, lambda ds: delattr(ds, "ImagePositionPatient"))), "missing ImagePositionPatient"),
    Broken("dicom_zero_pixel_spacing", lambda r: _sb(r, _bad_spacing),
           "PixelSpacing must be positive, got [0.0, 2.0]"),
    Broken("dicom_text_file", lambda r: _sb(r, _text_as_dcm),
           "dicom/500.dcm: not a DICOM file (no DICM preamble)"),
    Broken("dicom_duplicate_file", lambda r: _sb(r, _copy_file), "duplicate image"),
    Broken("dicom_enhanced_no_groups", lambda r: _sb(r, _enhanced),
           "needs a PerFrameFunctionalGroupsSequence with one item per frame"),
    Broken("dicom_enhanced_no_position", lambda r: _sb(r, _enhanced_no_position),
           "frame 2: missing ImagePositionPatient (in PlanePositionSequence)"),
    Broken("dicom_trigger_time_missing", lambda r: _sb(r, _no_trigger), "TriggerTime"),
    Broken("stack_not_parallel", lambda r: _sb(r, _tilt_slice),
           "dicom/28.dcm: slice sa_01, frame 7: SA slice is not parallel to the stack (tilted 8.00"),
    Broken("stack_duplicate_slice", lambda r: _sb(r, _duplicate_slice),
           "are at the same position (duplicate slice)"),
    # --- Sunnybrook contour files
    Broken("contour_non_numeric", lambda r: _sb(r, lambda r: _edit(
        sb_contour(r), lambda t: t.replace("\n", "\nabc 12.5\n", 1))), "not a number"),
    Broken("contour_empty_file", lambda r: _sb(r, lambda r: sb_contour(r).write_text("")),
           "empty contour file"),
    Broken("contour_nan", lambda r: _sb(r, lambda r: _edit(
        sb_contour(r), lambda t: t.replace("\n", "\nnan 12.5\n", 1))), "NaN"),
    Broken("contour_three_columns", lambda r: _sb(r, lambda r: _edit(
        sb_contour(r), lambda t: t.replace("\n", " 4.0\n", 1))), "expected two numbers"),
    Broken("contour_missing_image", lambda r: _sb(r, lambda r: write_contour(
        r / "i-contours" / "IM-0001-0777-icontour-manual.txt", circle_pixels())), "not in"),
    Broken("contour_too_few_points", lambda r: _sb(r, lambda r: write_contour(
        sb_contour(r), circle_pixels(n=4))),
        "IM-0001-0040-icontour-manual.txt: slice sa_01, frame 19: lv_endo contour has 4 point(s), needs >= 5"),
    Broken("contour_self_intersecting", lambda r: _sb(r, _figure_eight),
           "IM-0001-0040-icontour-manual.txt: slice sa_01, frame 19: lv_endo contour crosses itself"),
    Broken("contour_unknown_kind", lambda r: _sb(r, lambda r: write_contour(
        r / "i-contours" / "IM-0001-0020-xcontour-manual.txt", circle_pixels())),
        "unknown contour kind"),
    Broken("contour_bad_name", lambda r: _sb(r, lambda r: write_contour(
        r / "i-contours" / "slice3-icontour.txt", circle_pixels())), "file name must look like"),
    # --- CAP GPFile
    Broken("gpfile_unknown_type", lambda r: _gp(r, lambda r: _gp_line(
        r, 1, _set(3, "SAX_LV_PAPILLARY"))), "unknown contour type"),
    Broken("gpfile_non_numeric", lambda r: _gp(r, lambda r: _gp_line(r, 2, _set(0, "1.2.3"))),
           "not a number"),
    Broken("gpfile_nan", lambda r: _gp(r, lambda r: _gp_line(r, 3, _set(2, "nan"))), "NaN"),
    Broken("gpfile_unknown_slice", lambda r: _gp(r, lambda r: _gp_line(r, 1, _set(4, "42"))),
           "not in SliceInfoFile.txt"),
    Broken("gpfile_empty", lambda r: _gp(r, lambda r: _gp_file(r, 1).write_text("")), "empty GPFile"),
    Broken("gpfile_short_line", lambda r: _gp(r, lambda r: _gp_line(r, 4, lambda t: t[:5])),
           "expected 7"),
    Broken("gpfile_off_plane", lambda r: _gp(r, _gp_off_plane),
           "GPFile_000.txt: field frameID: lines 2-25: SAX_LV_ENDOCARDIAL points lie on no slice plane"),
    Broken("sliceinfo_no_orientation", lambda r: _gp(r, lambda r: _edit(
        r / "SliceInfoFile.txt", lambda t: t.replace("ImageOrientationPatient", "Orientation", 1))),
        "missing ImageOrientationPatient"),
    Broken("sliceinfo_conflicting_duplicate", lambda r: _gp(r, lambda r: _slice_info_lines(
        r, _moved_copy_of_first)), "lines 1 and 5: slice 1 is listed with different geometry"),
    Broken("sliceinfo_frame_without_entry", lambda r: _gp_frameid(r, lambda r: _slice_info_lines(
        r, lambda ls: [ln for ln in ls if "timeFrame\t1\t" not in ln])),
        "GPFile_001.txt: frame 1, field timeFrame: no line of SliceInfoFile.txt lists this frame"),
    Broken("sliceinfo_no_label", lambda r: _gp(r, lambda r: _edit(
        r / "SliceInfoFile.txt", lambda t: t.replace("sliceID: ", "slice", 1))),
        "line 1: missing sliceID"),
    Broken("sliceinfo_bad_time_frame", lambda r: _gp_frameid(r, lambda r: _edit(
        r / "SliceInfoFile.txt", lambda t: t.replace("timeFrame\t0", "timeFrame\tfirst", 1))),
        "line 1: timeFrame needs a whole number"),
    Broken("sliceinfo_time_frame_twice", lambda r: _gp_frameid(r, lambda r: _slice_info_lines(
        r, lambda ls: ls + ls[:1])), "slice 1 is listed twice for timeFrame 0"),
    Broken("gpfile_weight_non_numeric", lambda r: _gp(r, lambda r: _gp_line(r, 2, _set(5, "high"))),
           "GPFile_000.txt: field weight: line 3: weight is not a number"),
    Broken("gpfile_weight_negative", lambda r: _gp(r, lambda r: _gp_line(r, 2, _set(5, "-1.0"))),
           "line 3: weight must be >= 0"),
    # --- native
    Broken("native_unknown_structure", lambda r: _nat(r, lambda r: _native_csv(
        r, _replace_in_row(1, "lv_endo", "lv_papillary"))), "unknown structure"),
    Broken("native_missing_image", lambda r: _nat(r, lambda r: _native_csv(
        r, _replace_in_row(1, "sa_00_f0", "sa_77_f0"))), "not in the manifest"),
    Broken("native_bad_json", lambda r: _nat(r, lambda r: (r / "study.json").write_text("{oops")),
           "not valid JSON"),
    Broken("native_missing_dicom_file", lambda r: _nat(r, lambda r: _native_manifest(
        r, _missing_dicom_file)), "does not exist"),
    Broken("native_partial_timing", lambda r: _nat(r, lambda r: _native_manifest(
        r, _partial_times)), "no trigger time"),
    Broken("native_lv_endo_missing_at_es", lambda r: _nat(r, lambda r: _native_csv(
        r, _lv_endo_missing_at_es)), "ES"),
    # --- paths
    Broken("no_such_folder", lambda r: r / "absent", "no such file or folder"),
    Broken("unknown_format", lambda r: (r.mkdir(parents=True), (r / "notes.txt").write_text("x"))[0]
           or r, "cannot tell the study format"),
]
