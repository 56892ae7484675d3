"""Broken NIfTI label maps: each fails with one clear line naming the file; the CLI exits 2
and writes nothing."""

from __future__ import annotations

import gzip
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import nibabel as nib
import numpy as np
import pytest

from cardionurbs import StudyError, load_study
from cardionurbs.cli import main


def _ring(n=48, shape3=4, lv=1, myo=2, rv=3) -> np.ndarray:
    yy, xx = np.mgrid[:n, :n]
    r = np.hypot(xx - 22, yy - 24)
    sl = np.zeros((n, n), np.uint8)
    sl[r < 12] = myo
    sl[r < 8] = lv
    sl[(np.hypot(xx - 36, yy - 24) < 7) & (r >= 12)] = rv
    return np.repeat(sl[:, :, None], shape3, axis=2)


AFFINE = np.diag([1.5, 1.5, 10.0, 1.0])


def _save(data, path: Path, affine=AFFINE, codes=1) -> Path:
    img = nib.Nifti1Image(data, affine)
    img.set_sform(affine, code=codes)
    img.set_qform(affine, code=codes)
    path.parent.mkdir(parents=True, exist_ok=True)
    nib.save(img, str(path))
    return path


@dataclass
class Case:
    name: str
    build: Callable[[Path], Path]
    expect: str


def _not_nifti(d: Path) -> Path:
    d.mkdir(parents=True)
    (d / "seg.nii.gz").write_text("this is not a NIfTI file\n")
    return d / "seg.nii.gz"


def _truncated(d: Path) -> Path:
    p = _save(np.repeat(_ring()[..., None], 6, axis=3), d / "seg.nii.gz")
    raw = p.read_bytes()
    p.write_bytes(raw[: len(raw) // 2])
    return p


def _two_d(d: Path) -> Path:
    return _save(_ring()[:, :, 0], d / "seg.nii.gz", affine=np.diag([1.5, 1.5, 1, 1]))


def _no_affine(d: Path) -> Path:
    """sform and qform codes 0 and zero voxel sizes, written byte by byte (nibabel would
    repair the header on save)."""
    data = _ring()
    hdr = nib.Nifti1Header()
    hdr.set_data_shape(data.shape)
    hdr.set_data_dtype(np.uint8)
    arr = hdr.structarr
    arr["pixdim"][1:4] = 0.0
    arr["sform_code"] = arr["qform_code"] = 0
    arr["vox_offset"] = 352
    d.mkdir(parents=True)
    p = d / "seg.nii"
    p.write_bytes(arr.tobytes() + b"\x00" * 4 + data.tobytes(order="F"))
    return p


def _singular(d: Path) -> Path:
    a = AFFINE.copy()
    a[:3, 2] = a[:3, 0] * 2                      # third voxel axis along the first
    return _save(_ring(), d / "seg.nii.gz", affine=a)


def _outside_convention(d: Path) -> Path:
    data = _ring()
    data[0:3, 0:3, :] = 7
    return _save(data, d / "patient001_frame01_gt.nii.gz").parent


def _empty(d: Path) -> Path:
    return _save(np.zeros((32, 32, 4), np.uint8), d / "seg.nii.gz")


def _one_label(d: Path) -> Path:
    data = np.zeros((32, 32, 4), np.uint8)
    data[8:20, 8:20] = 1
    return _save(data, d / "seg.nii.gz")


def _time_zero(d: Path) -> Path:
    p = _save(_ring(), d / "seg.nii.gz")
    img = nib.load(str(p))
    hdr = img.header.copy()
    hdr["dim"][0] = 4
    hdr["dim"][4] = 0
    raw = hdr.binaryblock + b"\x00" * 4
    with gzip.open(p, "wb") as fh:
        fh.write(raw)
    return p


def _mismatched_ed_es(d: Path) -> Path:
    _save(_ring(), d / "seg_sa_ED.nii.gz")
    _save(_ring(n=40), d / "seg_sa_ES.nii.gz")
    return d


def _float_image(d: Path) -> Path:
    return _save(np.random.default_rng(0).random((32, 32, 4)).astype(np.float32), d / "img.nii.gz")


def _acdc_missing_es(d: Path) -> Path:
    _save(_ring(lv=3, myo=2, rv=1), d / "patient001_frame01_gt.nii.gz")
    (d / "Info.cfg").write_text("ED: 1\nES: 9\n")
    return d


def _ambiguous(d: Path) -> Path:
    a = _ring()
    b = np.where(a == 1, 4, np.where(a == 2, 5, 0)).astype(np.uint8)
    return _save(np.concatenate([a, b], axis=0), d / "seg.nii.gz")


CORPUS = [
    Case("not_nifti", _not_nifti, "not a readable NIfTI file"),
    Case("truncated_gzip", _truncated, "truncated or corrupt"),
    Case("two_d_image", _two_d, "a 2-D image"),
    Case("no_affine", _no_affine, "no affine"),
    Case("singular_affine", _singular, "singular affine"),
    Case("labels_outside_convention", _outside_convention, "label 7 is not in the label convention"),
    Case("empty_map", _empty, "empty"),
    Case("all_one_label", _one_label, "label"),
    Case("time_axis_zero", _time_zero, "time axis has length 0"),
    Case("mismatched_ed_es", _mismatched_ed_es, "mismatched ED/ES"),
    Case("float_image_not_labels", _float_image, "non-integer values"),
    Case("acdc_es_frame_missing", _acdc_missing_es, "no *_frame09_gt"),
    Case("ambiguous_labels", _ambiguous, "ambiguous label map"),
]


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 10 and len({c.name for c in CORPUS}) == len(CORPUS)


@pytest.mark.parametrize("case", CORPUS, ids=[c.name for c in CORPUS])
def test_broken_label_map_fails_with_one_line(case, tmp_path):
    path = case.build(tmp_path / "study")
    with pytest.raises(StudyError) as info:
        load_study(path)
    msg = str(info.value)
    assert "\n" not in msg and case.expect in msg, msg
    assert str(tmp_path / "study") in msg, msg


@pytest.mark.parametrize("case", CORPUS, ids=[c.name for c in CORPUS])
def test_cli_exit_2_nothing_written(case, tmp_path, capsys):
    path = case.build(tmp_path / "study")
    rc = main(["analyze", str(path), "--format", "nifti", "--no-figures",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("cardionurbs: error: ") and case.expect in err
    assert not (tmp_path / "out").exists()
