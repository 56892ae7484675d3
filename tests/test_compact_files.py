"""Compact study files: native coordinates at 1 µm, the optional Parquet sidecar (used only
while it matches the CSV), old 17-digit files still load, and RLE Lossless phantom DICOM
that decodes to exactly the uncompressed pixels."""

from __future__ import annotations

import json

import numpy as np
import pydicom
import pytest
from pydicom.uid import ExplicitVRLittleEndian, RLELossless

from cardionurbs.io import load_study, native
from cardionurbs.phantom import generate
from cardionurbs.phantom.dicom import write_dicom


@pytest.fixture(scope="module")
def phantom():
    return generate("phtn", seed=2, frames=2, tag_jumps=1, volume_check=False)


def _same_points(a, b):
    for x, y in ((a.contours, b.contours), (a.tags, b.tags)):
        assert len(x) == len(y)
        assert all(np.array_equal(p.points, q.points) and p.image == q.image for p, q in zip(x, y))
    assert all(np.array_equal(p.point, q.point) for p, q in zip(a.landmarks, b.landmarks))


def test_fixed_precision_is_stated_and_within_half_a_micrometre(phantom, tmp_path):
    native.write_study(phantom.study, tmp_path / "s")
    manifest = json.loads((tmp_path / "s" / "study.json").read_text())
    assert manifest["coordinate_decimals"] == 3
    row = (tmp_path / "s" / "points.csv").read_text().splitlines()[1].split(",")
    assert all(len(v.split(".")[1]) == 3 for v in row[-5:])      # x y z px py
    back = native.read_study(tmp_path / "s")
    for a, b in zip(phantom.study.contours, back.contours):
        assert np.abs(a.points - b.points).max() <= 0.5e-3 + 1e-12


def test_old_full_precision_files_still_load(phantom, tmp_path):
    native.write_study(phantom.study, tmp_path / "old", decimals=None)
    assert "coordinate_decimals" not in json.loads((tmp_path / "old" / "study.json").read_text())
    _same_points(phantom.study, native.read_study(tmp_path / "old"))


def test_sidecar_gives_the_same_study_and_yields_to_an_edited_csv(phantom, tmp_path):
    d = tmp_path / "s"
    native.write_study(phantom.study, d, sidecar=True)
    assert json.loads((d / "study.json").read_text())["points_sidecar"] == "points.parquet"
    with_sidecar = native.read_study(d)
    manifest = json.loads((d / "study.json").read_text())
    del manifest["points_sidecar"]
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "points.csv").write_bytes((d / "points.csv").read_bytes())
    (plain / "study.json").write_text(json.dumps(manifest))
    _same_points(native.read_study(plain), with_sidecar)
    # edit one coordinate of the CSV by hand: the sidecar no longer matches and is ignored
    lines = (d / "points.csv").read_text().splitlines()
    cols = lines[1].split(",")
    cols[8] = f"{float(cols[8]) + 1.0:.3f}"
    lines[1] = ",".join(cols)
    (d / "points.csv").write_text("\n".join(lines) + "\n")
    edited = native.read_study(d)
    assert edited.contours[0].points[0, 0] == pytest.approx(with_sidecar.contours[0].points[0, 0] + 1)


def test_rle_dicom_decodes_to_the_uncompressed_pixels_and_is_smaller(phantom, tmp_path):
    rle = write_dicom(phantom, tmp_path / "rle")
    raw = write_dicom(phantom, tmp_path / "raw", compression=None)
    assert len(rle) == len(raw) == len(phantom.study.images)
    for a, b in zip(rle[::7], raw[::7]):
        da, db = pydicom.dcmread(a), pydicom.dcmread(b)
        assert da.file_meta.TransferSyntaxUID == RLELossless
        assert db.file_meta.TransferSyntaxUID == ExplicitVRLittleEndian
        assert np.array_equal(da.pixel_array, db.pixel_array)
        assert da.SOPInstanceUID == db.SOPInstanceUID
    size = lambda paths: sum(p.stat().st_size for p in paths)  # noqa: E731
    assert size(rle) < 0.8 * size(raw)
    with pytest.raises(ValueError, match="compression"):
        write_dicom(phantom, tmp_path / "x", compression="jpeg")


def test_phantom_with_rle_dicom_loads_with_header_cross_check(phantom, tmp_path):
    from cardionurbs.phantom.generate import write_phantom
    out = write_phantom(phantom, tmp_path / "p")
    st = load_study(out)
    assert len(st.images) == len(phantom.study.images)
    assert native.check_dicom_geometry(st) == len(st.images)
