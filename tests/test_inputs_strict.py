"""No silent wrong answers (issue 10): a strict study.json schema, a truncated points.csv
caught, one subject per DICOM folder, short pixel data flagged, implausible numbers refused,
documented limits with a clear error -- always one StudyError line (CLI exit 2)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pydicom
import pytest

from broken.corpus import make_native, make_sunnybrook
from cardionurbs import StudyError, load_study
from cardionurbs.errors import LimitError
from cardionurbs.io.checks import self_intersections
from cardionurbs.limits import MAX_NAME_LENGTH, MAX_POINTS_PER_CONTOUR

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def native_template(tmp_path_factory) -> Path:
    return make_native(tmp_path_factory.mktemp("strict") / "S")


@pytest.fixture
def native(native_template, tmp_path) -> Path:
    import shutil
    return Path(shutil.copytree(native_template, tmp_path / "S"))


def _set(path: str, value):
    """A manifest edit: set the dotted ``path`` (list indices as numbers) to ``value``."""
    def fn(m):
        keys = [int(k) if k.isdigit() else k for k in path.split(".")]
        d = m
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value
    return fn


def _nest(depth: int):
    v: object = 1
    for _ in range(depth):
        v = {"a": v}
    return v


MALFORMED = [
    ("version", "1"), ("version", True), ("subject", 5), ("subject", "x" * (MAX_NAME_LENGTH + 1)),
    ("subject", "a\x1b[2Jb"), ("heart_rate_bpm", "60"), ("heart_rate_bpm", True),
    ("heart_rate_bpm", -60.0), ("heart_rate_bpm", 1e308), ("frame_times_ms", [0, 100]),
    ("frame_times_ms", {"x": 1.0}), ("frame_times_ms", {"0": "a"}), ("frame_times_ms", {"0": True}),
    ("ed_frame", True), ("ed_frame", 1.5), ("ed_frame", -1), ("es_frame", "1"),
    ("images", {}), ("images", [1]), ("images.0.frame", True), ("images.0.position", [1, 2]),
    ("images.0.orientation", "abc"), ("images.0.pixel_spacing", [1e-320, 1.0]),
    ("images.0.pixel_spacing", [True, 1.0]), ("images.0.rows", 0), ("images.0.thickness", -1),
    ("images.0.trigger_time", "x"), ("images.0.file", 7), ("images.0.id", None),
    ("images.0.slice", ["a"]), ("images.0.view", "XX"), ("points", 5), ("points_rows", -1),
    ("meta", []), ("meta", _nest(40)),
]


@pytest.mark.parametrize("field, value", MALFORMED, ids=[f"{f}={str(v)[:12]}" for f, v in MALFORMED])
def test_malformed_manifest_field_is_one_line_naming_the_field(native, field, value):
    m = json.loads((native / "study.json").read_text())
    _set(field, value)(m)
    (native / "study.json").write_text(json.dumps(m))
    with pytest.raises(StudyError) as info:
        load_study(native)
    msg = str(info.value)
    assert "\n" not in msg and len(msg) < 400, msg
    assert field.split(".")[0] in msg, msg


def test_json_nested_beyond_the_recursion_limit_is_one_line(native):
    text = (native / "study.json").read_text()
    (native / "study.json").write_text(text[:-2] + ', "x": ' + "[" * 100_000 + "]" * 100_000 + "}\n")
    with pytest.raises(StudyError, match="nested deeper"):
        load_study(native)


def test_ed_frame_true_is_exit_2_not_frame_1(native):
    m = json.loads((native / "study.json").read_text())
    m["ed_frame"] = True
    (native / "study.json").write_text(json.dumps(m))
    r = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "analyze", str(native), "--out",
                        str(native.parent / "o")], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "ed_frame" in r.stderr, r.stderr


def test_points_cut_mid_row_is_caught(native):
    p = native / "points.csv"
    data = p.read_bytes()
    p.write_bytes(data[:len(data) // 2])
    with pytest.raises(StudyError, match="truncated"):
        load_study(native)


def test_points_cut_at_a_row_boundary_is_caught(native):
    p = native / "points.csv"
    lines = p.read_text().splitlines(keepends=True)
    p.write_text("".join(lines[:len(lines) // 2]))
    with pytest.raises(StudyError, match="points_rows"):
        load_study(native)


def test_old_manifest_without_row_count_loads_with_a_warning(native):
    m = json.loads((native / "study.json").read_text())
    assert m.pop("points_rows") > 0
    (native / "study.json").write_text(json.dumps(m))
    study = load_study(native)
    assert any("points_rows" in w for w in study.warnings)


@pytest.fixture
def sunnybrook(tmp_path) -> Path:
    return make_sunnybrook(tmp_path / "SB")


def _dicoms(root: Path) -> list[Path]:
    return sorted((root / "dicom").glob("*.dcm"), key=lambda p: int(p.stem))


@pytest.mark.parametrize("keyword", ["PatientID", "StudyInstanceUID"])
def test_images_of_another_patient_or_study_are_rejected_naming_the_files(sunnybrook, keyword):
    files = _dicoms(sunnybrook)
    for f in files:
        ds = pydicom.dcmread(f)
        setattr(ds, keyword, "1.2.3" if f != files[3] else "1.2.4")
        ds.save_as(f)
    with pytest.raises(StudyError) as info:
        load_study(sunnybrook)
    msg = str(info.value)
    assert keyword in msg and files[3].name in msg


def test_series_that_disagree_on_frame_of_reference_are_rejected(sunnybrook):
    files = _dicoms(sunnybrook)
    for k, f in enumerate(files):
        ds = pydicom.dcmread(f)
        ds.FrameOfReferenceUID = "1.2.3"
        if k == 0:
            ds.FrameOfReferenceUID, ds.SeriesInstanceUID = "1.2.9", "1.2.99"
        ds.save_as(f)
    with pytest.raises(StudyError, match="FrameOfReferenceUID"):
        load_study(sunnybrook)


def test_pixel_data_shorter_than_promised_is_flagged(sunnybrook):
    f = _dicoms(sunnybrook)[2]
    f.write_bytes(f.read_bytes()[:-64])
    with pytest.raises(StudyError, match="PixelData") as info:
        load_study(sunnybrook)
    assert f.name in str(info.value)


def test_denormal_pixel_spacing_is_refused(sunnybrook):
    f = _dicoms(sunnybrook)[0]
    ds = pydicom.dcmread(f)
    ds.PixelSpacing = ["1e-320", "1e-320"]
    ds.save_as(f)
    with pytest.raises(StudyError, match="PixelSpacing"):
        load_study(sunnybrook)


def test_contour_past_the_point_limit_is_rejected_with_a_clear_error(native):
    p = native / "points.csv"
    lines = p.read_text().splitlines()
    head, first = lines[0], lines[1]
    n = 20_000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    cols = head.split(",")
    row = first.split(",")
    rows = []
    for k in range(n):
        r = list(row)
        r[cols.index("x")], r[cols.index("y")], r[cols.index("z")] = "", "", ""
        r[cols.index("px")] = f"{16 + 6 * np.cos(t[k]):.4f}"
        r[cols.index("py")] = f"{15 + 6 * np.sin(t[k]):.4f}"
        rows.append(",".join(r))
    rest = [ln for ln in lines[1:] if ln.split(",")[:7] != row[:7]]
    p.write_text("\n".join([head, *rows, *rest]) + "\n")
    m = json.loads((native / "study.json").read_text())
    m["points_rows"] = n + len(rest)
    (native / "study.json").write_text(json.dumps(m))
    with pytest.raises(LimitError) as info:
        load_study(native)
    assert str(MAX_POINTS_PER_CONTOUR) in str(info.value) and "20000" in str(info.value)


def test_huge_subject_name_is_refused_on_load(native):
    m = json.loads((native / "study.json").read_text())
    m["subject"] = "s" * 100_000
    (native / "study.json").write_text(json.dumps(m))
    with pytest.raises(StudyError) as info:
        load_study(native)
    assert len(str(info.value)) < 400 and "subject" in str(info.value)


def test_self_intersection_check_is_not_quadratic_on_a_zigzag():
    """Long parallel segments that all overlap along x: the old x-sweep made every pair
    (20,000 points: 9.5 GB, 330 s); the best-direction sweep makes O(n) pairs."""
    n = 20_000
    x = np.where(np.arange(n) % 2 == 0, 0.0, 100.0)
    y = np.arange(n) * 0.01
    from cardionurbs.io import checks
    calls = []
    orig = checks._segments_meet
    checks._segments_meet = lambda A, *a: calls.append(len(A)) or orig(A, *a)
    try:
        assert len(self_intersections(np.c_[x, y], closed=False)) == 0
    finally:
        checks._segments_meet = orig
    assert sum(calls) < 10 * n


def test_implausible_dicom_heart_rates_are_ignored():
    from cardionurbs.imaging.phases import heart_rate_bpm
    assert heart_rate_bpm([-60.0, 1e6, 0.0]) is None
    assert heart_rate_bpm([None], [1e-3]) is None             # a 6e7 bpm NominalInterval
    assert heart_rate_bpm([72.0, 1e6]) == 72.0
    assert heart_rate_bpm([None], [1000.0]) == 60.0
