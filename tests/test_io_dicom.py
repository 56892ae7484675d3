"""DICOM series reading (synthetic series written with pydicom): grouping, frames, geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydicom.uid import generate_uid

from broken.corpus import (SA_COL, SA_NORMAL, SA_ORIGIN, SA_ROW, ds_text, make_sunnybrook,
                           write_dicom_image, write_enhanced_mr)
from cardionurbs.errors import StudyError
from cardionurbs.imaging import phases
from cardionurbs.imaging.dicom import read_dicom_folder, read_header, read_pixels


def test_cine_stack_grouped_by_slice_and_phase(tmp_path):
    make_sunnybrook(tmp_path, n_slices=5, spacing_mm=9.5, full_cine=True)
    s = read_dicom_folder(tmp_path / "dicom")
    assert len(s.images) == 100
    assert sorted({im.slice for im in s.images}) == [f"sa_{k:02d}" for k in range(5)]
    for im in s.images:
        inst = im.meta["instance_number"]
        assert im.frame == (inst - 1) % 20
        assert im.slice == f"sa_{(inst - 1) // 20:02d}"  # written base -> apex along +SA_NORMAL
        assert im.view == "SA" and im.id == s.headers[im.id].sop_instance_uid
    assert s.slice_spacing_mm == pytest.approx(9.5, abs=1e-8)
    assert s.heart_rate_bpm == pytest.approx(60000 / 900)  # from NominalInterval only
    assert list(s.frame_times_ms) == list(range(20))
    assert s.base_apex_rule == "LPS prior"


def test_frames_of_a_partial_series_are_cardiac_phases(tmp_path):
    """Only ED and ES images present, trigger times differing per slice: frame = phase index."""
    make_sunnybrook(tmp_path, n_slices=3)
    s = read_dicom_folder(tmp_path / "dicom")
    assert sorted({im.frame for im in s.images}) == [7, 19]


def test_sa_and_la_series_and_slice_thickness_fallback(tmp_path):
    make_sunnybrook(tmp_path, n_slices=3)
    la = generate_uid()
    for k in (7, 19):
        write_dicom_image(tmp_path / "dicom" / "la" / f"{k}.dcm", position=SA_ORIGIN - 40 * SA_COL,
                          row=SA_NORMAL, col=SA_ROW, trigger_time=k * 45.0 + 2, instance=900 + k,
                          series_uid=la, series_number=7, description="CINE 4CH",
                          nominal_interval=900, omit=("SliceThickness",))
    s = read_dicom_folder(tmp_path / "dicom")
    la_images = [im for im in s.images if im.view == "LA"]
    assert {im.slice for im in la_images} == {"la_4ch"} and len(la_images) == 2
    assert {im.frame for im in la_images} == {7, 19}
    assert la_images[0].thickness == pytest.approx(10.0)  # missing SliceThickness: stack spacing
    assert la_images[0].file.startswith("la/")


def test_spacing_from_positions_not_slice_thickness(tmp_path):
    series = generate_uid()
    for k in range(4):
        write_dicom_image(tmp_path / f"{k}.dcm", position=SA_ORIGIN + 12.0 * k * SA_NORMAL,
                          row=SA_ROW, col=SA_COL, series_uid=series, instance=k + 1, thickness=6.0)
    s = read_dicom_folder(tmp_path)
    assert s.slice_spacing_mm == pytest.approx(12.0)
    assert {im.thickness for im in s.images} == {6.0}


def test_pixels_read_on_request(tmp_path):
    px = np.arange(32 * 32).reshape(32, 32) % 97
    write_dicom_image(tmp_path / "a.dcm", position=SA_ORIGIN, row=SA_ROW, col=SA_COL,
                      series_uid=generate_uid(), pixels=px)
    s = read_dicom_folder(tmp_path)
    assert not s.pixels
    s2 = read_dicom_folder(tmp_path, pixels=True)
    assert np.array_equal(s2.pixels[s2.images[0].id], px)
    assert np.array_equal(read_pixels(tmp_path / "a.dcm"), px)


def test_enhanced_mr_reads_like_the_classic_series(tmp_path):
    """One multi-frame object holding 3 slices x 4 phases gives the same planes, frames and
    pixels as 12 classic images with the same header values."""
    positions, times, pix = [], [], []
    rng = np.random.default_rng(0)
    for s_ in range(3):
        for k in range(4):
            positions.append(SA_ORIGIN + 9.0 * s_ * SA_NORMAL)
            times.append(k * 225.0 + 5.0 + s_)
            pix.append(rng.integers(0, 1000, (32, 32)))
    uid = write_enhanced_mr(tmp_path / "enh" / "cine.dcm", positions=positions, row=SA_ROW,
                            col=SA_COL, trigger_times=times, pixels=np.array(pix))
    series = generate_uid()
    for i, (p, t, px) in enumerate(zip(positions, times, pix)):
        write_dicom_image(tmp_path / "classic" / f"{i}.dcm", position=p, row=SA_ROW, col=SA_COL,
                          trigger_time=t, series_uid=series, instance=i + 1, heart_rate=None,
                          nominal_interval=900, n_phases=None, pixels=px)
    enh = read_dicom_folder(tmp_path / "enh", pixels=True)
    cla = read_dicom_folder(tmp_path / "classic", pixels=True)
    assert len(enh.images) == len(cla.images) == 12
    key = lambda im: (im.slice, im.frame)  # noqa: E731
    for a, b in zip(sorted(enh.images, key=key), sorted(cla.images, key=key)):
        assert key(a) == key(b) and a.same_geometry(b, tol=1e-12) and a.thickness == b.thickness
        assert a.id.startswith(uid + "#")
        assert np.array_equal(enh.pixels[a.id], cla.pixels[b.id])
    assert enh.heart_rate_bpm == cla.heart_rate_bpm == pytest.approx(60000 / 900)
    assert enh.slice_spacing_mm == pytest.approx(9.0)


def test_non_dicom_files_without_suffix_are_skipped(tmp_path):
    write_dicom_image(tmp_path / "IM0001", position=SA_ORIGIN, row=SA_ROW, col=SA_COL,
                      series_uid=generate_uid())
    (tmp_path / "README").write_text("not an image")
    assert len(read_dicom_folder(tmp_path).images) == 1
    with pytest.raises(StudyError, match="no DICOM image found"):
        read_dicom_folder(tmp_path / "README")


@settings(max_examples=25, deadline=None)
@given(st.floats(0, np.pi), st.floats(-np.pi / 2, np.pi / 2), st.floats(0, 2 * np.pi),
       st.floats(0.5, 3.0), st.floats(0.5, 3.0),
       st.lists(st.floats(-300, 300), min_size=3, max_size=3))
def test_header_geometry_is_the_dicom_image_plane(tmp_path_factory, a, b, c, dr, dc, pos):
    """P(c, r) = S + c*dc*X + r*dr*Y (PS3.3 C.7.6.2.1.1) for any orientation and spacing."""
    ca, sa_, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rot = np.array([[ca, -sa_, 0], [sa_, ca, 0], [0, 0, 1]]) @ \
        np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]]) @ np.array([[1, 0, 0], [0, cc, -sc], [0, sc, cc]])
    X, Y = rot[:, 0], rot[:, 1]
    path = tmp_path_factory.mktemp("h") / "x.dcm"
    write_dicom_image(path, position=pos, row=X, col=Y, spacing=(dr, dc), series_uid="1.2.3")
    s = read_dicom_folder(path)
    im = s.images[0]
    pix = np.array([[0, 0], [31, 0], [0, 31], [12.5, 7.25]])
    S, Xh, Yh = (np.array([float(ds_text(v)) for v in vec]) for vec in (pos, X, Y))
    Xh, Yh = Xh / np.linalg.norm(Xh), Yh / np.linalg.norm(Yh)
    dr_, dc_ = float(ds_text(dr)), float(ds_text(dc))
    expected = S + pix[:, :1] * dc_ * Xh + pix[:, 1:] * dr_ * Yh
    assert np.abs(im.pixel_to_scanner(pix) - expected).max() < 1e-9
    assert np.allclose(read_header(path).normal, np.cross(Xh, Yh), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 40), st.floats(400, 1500), st.floats(0, 0.99),
       st.lists(st.integers(0, 39), min_size=1, max_size=40, unique=True))
def test_phase_indices_recover_phases_of_any_subset(n, rr, offset, picks):
    """t_k = (k + offset) * RR / N for any subset of phases k -> k (partial) or rank (complete)."""
    k = np.array(sorted({p % n for p in picks}))
    t = (k + offset) * rr / n
    got = phases.phase_indices(t[::-1], n, rr)[::-1]
    assert np.array_equal(got, k if len(k) < n else np.arange(n))


def test_phase_indices_duplicate_trigger_time():
    with pytest.raises(StudyError, match="share TriggerTime"):
        phases.phase_indices([10.0, 50.0, 10.0], slice="sa_01")


def test_heart_rate_rules():
    assert phases.heart_rate_bpm([80, 82, None]) == 81
    assert phases.heart_rate_bpm([0, None], [750.0]) == 80
    assert phases.heart_rate_bpm([None], [None]) is None
