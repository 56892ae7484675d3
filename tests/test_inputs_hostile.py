"""Hostile inputs (issue 31, findings 4, 5 and 8): every one gives one line and exit 2 --
sizes checked from NIfTI headers before any allocation, a gzip stream bounded, numbers
range-checked at the reader (no numpy warning, no 300-digit echo), values in range (GPFile
time frames, ``closed``, Sunnybrook pixels, image files that are DICOM), bad ``--out``
names and ``--dask`` addresses refused before any work."""

from __future__ import annotations

import gzip
import json
import shutil
import struct
import time
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

from broken.corpus import make_gpfile, make_native, make_sunnybrook, sb_contour
from cardionurbs.cli import main
from cardionurbs.errors import StudyError
from cardionurbs import load_study


def _exit2(capsys, argv, *words) -> str:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("cardionurbs: error: "), err
    assert "Warning" not in err and len(err) < 400, err
    for w in words:
        assert w in err, (w, err)
    return err


def _nifti(path: Path, shape, *, nifti2=False, code=None) -> Path:
    """A gzip NIfTI whose header claims ``shape`` (and datatype ``code``) over 64 bytes."""
    cls = nib.Nifti2Header if nifti2 else nib.Nifti1Header
    h = cls()
    h.set_data_dtype(np.uint8)
    h.set_data_shape((2, 2, 2))
    b = bytearray(h.binaryblock)
    dims = [len(shape), *shape] + [1] * (7 - len(shape))
    if nifti2:
        b[16:80] = struct.pack("<8q", *dims)
        if code:
            b[12:14] = struct.pack("<h", code)
    else:
        b[40:56] = struct.pack("<8h", *dims)
        if code:
            b[70:72] = struct.pack("<h", code)
    path.parent.mkdir(parents=True, exist_ok=True)
    with gzip.open(path, "wb") as f:
        f.write(bytes(b) + b"\0" * (int(h.get_data_offset()) - len(b)) + b"\0" * 64)
    return path


@pytest.mark.parametrize("shape, nifti2, code, words", [
    ((32767, 32767, 32767), False, None, ["voxels"]),
    ((8, 8, 4, 600), False, None, ["600 frames", "512"]),
    ((2048, 2048, 256), False, None, ["voxels", "limit"]),       # a gzip bomb's claim
    ((2**40, 2, 2), True, None, ["voxels"]),
    ((8, 8, 4), False, 255, ["data code 255"]),
], ids=["32767^3", "600-frames", "bomb", "nifti2-2^40", "datatype-255"])
def test_nifti_headers_past_the_limits_exit_2_fast(tmp_path, capsys, shape, nifti2, code, words):
    f = _nifti(tmp_path / "S" / "map.nii.gz", shape, nifti2=nifti2, code=code)
    t = time.monotonic()
    _exit2(capsys, ["analyze", f, "--out", tmp_path / "o"], *words)
    assert time.monotonic() - t < 10 and not (tmp_path / "o").exists()


def test_truncated_points_gz_is_one_line(tmp_path, capsys):
    root = make_native(tmp_path / "S")
    data = (root / "points.csv").read_bytes()
    (root / "points.csv").unlink()
    (root / "points.csv.gz").write_bytes(gzip.compress(data)[:-40])
    m = json.loads((root / "study.json").read_text())
    m["points"] = "points.csv.gz"
    (root / "study.json").write_text(json.dumps(m))
    _exit2(capsys, ["analyze", root, "--out", tmp_path / "o"], "points.csv.gz", "truncated")


def test_a_300_character_out_name_is_refused_before_any_work(tmp_path, capsys):
    root = make_native(tmp_path / "S")
    _exit2(capsys, ["analyze", root, "--out", tmp_path / ("a" * 300)], "--out", "300 bytes")


@pytest.mark.parametrize("text", ["[]", "null", "[" * 100_000 + "]" * 100_000])
def test_report_on_a_metrics_json_that_is_not_an_object(tmp_path, capsys, text):
    out = tmp_path / "A"
    out.mkdir()
    (out / "metrics.json").write_text(text)
    (out / "model.json").write_text(text)
    _exit2(capsys, ["report", out, "--out", tmp_path / "r.html"])
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("address, words", [("nonsense", ["not an address"]),
                                            ("tcp://127.0.0.1:1", ["no scheduler answers"])])
def test_bad_dask_addresses_exit_2_quickly(tmp_path, capsys, address, words):
    root = make_native(tmp_path / "S")
    t = time.monotonic()
    _exit2(capsys, ["cohort", root, "--csv", tmp_path / "c.csv", "--dask", address], *words)
    assert time.monotonic() - t < 15 and not (tmp_path / "c.csv").exists()


def _points_edit(root: Path, column: str, value: str, row: int = 3) -> None:
    lines = (root / "points.csv").read_text().splitlines()
    head = lines[0].split(",")
    fields = lines[row].split(",")
    fields[head.index(column)] = value
    lines[row] = ",".join(fields)
    (root / "points.csv").write_text("\n".join(lines) + "\n")


def test_a_coordinate_of_1e308_is_one_short_line_without_numpy_warnings(tmp_path, capsys,
                                                                         recwarn):
    root = make_native(tmp_path / "S")
    _points_edit(root, "x", "1e308")
    err = _exit2(capsys, ["analyze", root, "--out", tmp_path / "o"], "1e+308", "line 4")
    assert "0000000000" not in err
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


@pytest.mark.parametrize("value", ["nan", "2", "yes"])
def test_closed_must_be_1_or_0(tmp_path, value):
    root = make_native(tmp_path / "S")
    lines = (root / "points.csv").read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("contour,"))
    _points_edit(root, "closed", value, row=k)
    with pytest.raises(StudyError, match="closed must be 1 or 0"):
        load_study(root)


@pytest.mark.parametrize("value", ["abc", "nan", "-5", "500", "1.5"])
def test_gpfile_time_frame_must_be_a_frame_of_the_study(tmp_path, value):
    root = make_gpfile(tmp_path / "G")
    f = root / "GPFile_000.txt"
    lines = f.read_text().splitlines()
    fields = lines[2].split("\t")
    fields[6] = value
    lines[2] = "\t".join(fields)
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(StudyError, match="time frame") as info:
        load_study(root)
    assert "line 3" in str(info.value) and "\n" not in str(info.value)


def test_gpfile_coordinate_past_the_bore_is_refused(tmp_path):
    root = make_gpfile(tmp_path / "G")
    f = root / "GPFile_000.txt"
    lines = f.read_text().splitlines()
    fields = lines[1].split("\t")
    fields[0] = "1e308"
    lines[1] = "\t".join(fields)
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(StudyError, match="lies past"):
        load_study(root)


def test_sunnybrook_contour_far_outside_its_image_is_refused(tmp_path):
    root = make_sunnybrook(tmp_path / "SB")
    c = sb_contour(root)
    lines = c.read_text().splitlines()
    lines[0] = "1000000.0 12.0"
    c.write_text("\n".join(lines) + "\n")
    with pytest.raises(StudyError, match="outside the 32 x 32 image") as info:
        load_study(root)
    assert c.name in str(info.value)


def test_an_image_file_naming_study_json_is_refused(tmp_path):
    root = make_native(tmp_path / "S")
    m = json.loads((root / "study.json").read_text())
    m["images"][0]["file"] = "study.json"
    (root / "study.json").write_text(json.dumps(m))
    with pytest.raises(StudyError, match="not a DICOM image"):
        load_study(root)


def test_third_party_warnings_and_log_lines_stay_off_stderr():
    """matplotlib's "Glyph missing" (a non-ASCII subject name), numpy RuntimeWarnings and
    nibabel's log lines never reach stderr raw once the CLI has started (--debug shows them)."""
    import subprocess
    import sys
    code = ("import logging, warnings, numpy as np\n"
            "from cardionurbs.safe import CAUGHT_WARNINGS, quiet_third_party\n"
            "quiet_third_party()\n"
            "warnings.warn('Glyph 12354 missing from font(s) DejaVu Sans.', UserWarning)\n"
            "np.float64(1e308) * 10\n"
            "import nibabel\n"
            "logging.getLogger('nibabel.global').error('data code 255 not supported')\n"
            "assert any('Glyph' in w for w in CAUGHT_WARNINGS), CAUGHT_WARNINGS\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
