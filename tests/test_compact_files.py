"""Compact study files: native coordinates at 1 µm, Parquet as the points file of large
studies (the same study as the CSV), the optional Parquet sidecar (used only while it matches
the CSV), old 17-digit files still load, and JPEG-LS / RLE Lossless phantom DICOM that decodes
to exactly the uncompressed pixels, stored at a grey-level step matched to the noise."""

from __future__ import annotations

import json

import numpy as np
import pydicom
import pytest
from pydicom.uid import ExplicitVRLittleEndian, JPEGLSLossless, RLELossless

from cardionurbs.io import load_study, native
from cardionurbs.phantom import generate
from cardionurbs.errors import StudyError
from cardionurbs.phantom import dicom as phantom_dicom
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


def test_lossless_dicom_decodes_to_the_uncompressed_pixels_and_is_smaller(phantom, tmp_path):
    jls = write_dicom(phantom, tmp_path / "jls")
    rle = write_dicom(phantom, tmp_path / "rle", compression="rle")
    raw = write_dicom(phantom, tmp_path / "raw", compression=None)
    assert len(jls) == len(rle) == len(raw) == len(phantom.study.images)
    for a, b, c in zip(jls[::7], rle[::7], raw[::7]):
        da, db, dc = pydicom.dcmread(a), pydicom.dcmread(b), pydicom.dcmread(c)
        assert da.file_meta.TransferSyntaxUID == JPEGLSLossless
        assert db.file_meta.TransferSyntaxUID == RLELossless
        assert dc.file_meta.TransferSyntaxUID == ExplicitVRLittleEndian
        assert np.array_equal(da.pixel_array, dc.pixel_array)
        assert np.array_equal(db.pixel_array, dc.pixel_array)
        assert da.SOPInstanceUID == dc.SOPInstanceUID
    size = lambda paths: sum(p.stat().st_size for p in paths)  # noqa: E731
    assert size(jls) < 0.5 * size(rle) < 0.5 * size(raw)
    with pytest.raises(ValueError, match="compression"):
        write_dicom(phantom, tmp_path / "x", compression="jpeg")


def test_grey_level_step_matches_the_noise(phantom, tmp_path):
    """Stored grey levels: the channel noise σ spans NOISE_GREY_LEVELS of them, so rounding
    adds Δ²/12 < 2 % of σ² to the noise variance; measured on the lung background, where the
    image is Rician noise around a constant, against the float image rendered with the same
    seed."""
    levels = phantom_dicom.grey_levels_per_unit(phantom_dicom.noise_sigma(None))
    assert levels == pytest.approx(phantom_dicom.NOISE_GREY_LEVELS / phantom_dicom.NOISE)
    assert (1 / levels) ** 2 / 12 < 0.02 * phantom_dicom.NOISE ** 2
    assert phantom_dicom.grey_levels_per_unit(0.0) == phantom_dicom.SCALE       # noise-free
    assert phantom_dicom.grey_levels_per_unit(1e-6) == phantom_dicom.SCALE      # capped
    files = write_dicom(phantom, tmp_path / "d", compression=None)
    im = phantom.study.images[0]
    path = tmp_path / "d" / im.file
    assert path in files
    stored = pydicom.dcmread(path).pixel_array.astype(float)
    cfg = phantom.config
    rng = np.random.default_rng(np.random.SeedSequence(
        [cfg["seed"], im.frame, int.from_bytes(im.slice.encode()[:6].ljust(6, b"_"), "little")]))
    exact = phantom_dicom.render_image(phantom, im, rng) * levels
    err = stored - exact
    assert np.abs(err).max() <= 0.5 + 1e-9                       # rounding, nothing else
    clean = phantom_dicom.render_image(phantom, im)
    lung = clean == phantom_dicom.LUNG
    assert np.var(err[lung]) == pytest.approx(1 / 12, rel=0.1)   # uniform rounding error, Δ²/12
    sigma2 = phantom_dicom.NOISE_GREY_LEVELS ** 2                  # channel noise variance, levels²
    assert abs(np.var(stored[lung]) - np.var(exact[lung])) < 0.02 * sigma2
    assert float(pydicom.dcmread(path).WindowCenter) == pytest.approx(0.4 * levels, abs=0.05)


def test_large_study_writes_parquet_points_that_read_as_the_csv(phantom, tmp_path):
    native.write_study(phantom.study, tmp_path / "csv", points="csv")
    native.write_study(phantom.study, tmp_path / "pq", points="parquet")
    manifest = json.loads((tmp_path / "pq" / "study.json").read_text())
    assert manifest["points"] == "points.parquet" and manifest["coordinate_decimals"] == 3
    assert not (tmp_path / "pq" / "points.csv").exists()
    assert manifest["points_rows"] == json.loads((tmp_path / "csv" / "study.json").read_text())["points_rows"]
    a, b = native.read_study(tmp_path / "csv"), native.read_study(tmp_path / "pq")
    _same_points(a, b)                                            # bit for bit
    assert [(c.structure, c.slice, c.frame, c.closed, c.index) for c in a.contours] == \
        [(c.structure, c.slice, c.frame, c.closed, c.index) for c in b.contours]
    assert (tmp_path / "pq" / "points.parquet").stat().st_size < 0.3 * (tmp_path / "csv" / "points.csv").stat().st_size
    # read, write again: same bytes; pandas reads it as a plain table
    native.write_study(b, tmp_path / "pq2", points="parquet")
    assert (tmp_path / "pq" / "points.parquet").read_bytes() == (tmp_path / "pq2" / "points.parquet").read_bytes()
    import pandas as pd
    assert list(pd.read_parquet(tmp_path / "pq" / "points.parquet").columns) == native.COLUMNS
    # "auto" picks Parquet above PARQUET_ROWS points only
    native.write_study(phantom.study, tmp_path / "auto")
    assert json.loads((tmp_path / "auto" / "study.json").read_text())["points"] == (
        "points.parquet" if manifest["points_rows"] > native.PARQUET_ROWS else "points.csv")
    with pytest.raises(ValueError, match="points"):
        native.write_study(phantom.study, tmp_path / "x", points="xml")


def test_truncated_or_miscounted_parquet_points_are_errors(phantom, tmp_path):
    d = tmp_path / "pq"
    native.write_study(phantom.study, d, points="parquet")
    data = (d / "points.parquet").read_bytes()
    (d / "points.parquet").write_bytes(data[: len(data) // 2])
    with pytest.raises(StudyError, match="Parquet") as e:
        native.read_study(d)
    assert "points.parquet" in str(e.value)
    (d / "points.parquet").write_bytes(data)
    manifest = json.loads((d / "study.json").read_text())
    manifest["points_rows"] += 1
    (d / "study.json").write_text(json.dumps(manifest))
    with pytest.raises(StudyError, match="points_rows"):
        native.read_study(d)


def test_gzipped_csv_points_load(phantom, tmp_path):
    import gzip
    d = tmp_path / "gz"
    native.write_study(phantom.study, d, points="csv")
    plain = native.read_study(d)
    (d / "points.csv.gz").write_bytes(gzip.compress((d / "points.csv").read_bytes()))
    (d / "points.csv").unlink()
    manifest = json.loads((d / "study.json").read_text())
    manifest["points"] = "points.csv.gz"
    (d / "study.json").write_text(json.dumps(manifest))
    _same_points(plain, native.read_study(d))


def test_phantom_with_compressed_dicom_loads_with_header_cross_check(phantom, tmp_path):
    from cardionurbs.phantom.generate import write_phantom
    out = write_phantom(phantom, tmp_path / "p")
    st = load_study(out)
    assert len(st.images) == len(phantom.study.images)
    assert native.check_dicom_geometry(st) == len(st.images)
