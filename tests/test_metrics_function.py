"""Metric formulas (docs/metrics.md), ED/ES detection, eccentricity index, Simpson's disks."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cardionurbs.analysis import function as F
from cardionurbs.analysis.simpson import disk_volumes
from cardionurbs.geometry import chord_length, polygon_area, polygon_centroid, slice_spacing
from cardionurbs.anatomy.model import ed_es_frames
from cardionurbs.errors import ReconstructionError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.study import Contour, Study


def test_columns_follow_metrics_md():
    from cardionurbs.analysis.regional_columns import REGIONAL_COLUMNS
    n = len(F.COLUMNS) - len(REGIONAL_COLUMNS)
    assert F.COLUMNS[0] == "HR (bpm)" and F.COLUMNS[n - 1] == "Tag QC flags"
    assert F.COLUMNS[n:] == REGIONAL_COLUMNS
    assert len(F.COLUMNS) == len(set(F.COLUMNS)) == 24 + len(REGIONAL_COLUMNS)
    assert set(F.TAG_COLUMNS) <= set(F.COLUMNS)


def test_ventricular_function_formulas():
    f = F.ventricular_function(150.0, 60.0, 70.0)
    assert f["SV"] == 90.0
    assert f["EF"] == pytest.approx(60.0)
    assert f["CO"] == pytest.approx(90.0 * 70.0 / 1000.0)
    assert math.isnan(F.ventricular_function(150.0, 60.0, float("nan"))["CO"])


def test_regurgitation_and_mass():
    assert F.regurgitation(100.0, 70.0) == (30.0, 30.0)
    assert F.regurgitation(70.0, 100.0) == (0.0, 0.0)
    assert all(math.isnan(x) for x in F.regurgitation(70.0, float("nan")))
    assert F.mass_g(100.0) == pytest.approx(105.0)


@settings(max_examples=30, deadline=None)
@given(a=st.floats(5, 40), b=st.floats(5, 40), ang=st.floats(0, np.pi))
@example(a=5.6, b=5.6, ang=0.25742153837376686)     # the chord passes exactly through vertices
def test_eccentricity_index_of_an_ellipse(a, b, ang):
    # LV cavity: ellipse with axis a along the septum; RV centroid across it
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    c, s = np.cos(ang), np.sin(ang)
    R = np.array([[c, -s], [s, c]])
    lv = np.column_stack([a * np.cos(t), b * np.sin(t)]) @ R.T + [3.0, -2.0]
    rv = np.column_stack([5 * np.cos(t), 5 * np.sin(t)]) + [3.0, -2.0] + (R @ [0.0, 2 * b + 10.0])
    assert F.eccentricity_index(lv, rv) == pytest.approx(a / b, rel=1e-4)


def test_chord_length_and_centroid_of_a_square():
    sq = np.array([[0, 0], [4, 0], [4, 2], [0, 2]], float)
    assert np.allclose(polygon_centroid(sq), [2, 1])
    assert chord_length(sq, np.array([2.0, 1.0]), np.array([1.0, 0.0])) == pytest.approx(4.0)
    assert chord_length(sq, np.array([2.0, 1.0]), np.array([0.0, 3.0])) == pytest.approx(2.0)


def test_ed_es_detection_and_labels():
    vols = {0: 120.0, 3: 60.0, 5: 80.0, 9: 118.0}
    assert ed_es_frames(vols) == (0, 3)
    assert ed_es_frames(vols, ed_label=9, es_label=5) == (0, 3)      # > 2 frames: volumes win
    two = {2: 100.0, 7: 110.0}
    assert ed_es_frames(two) == (7, 2)
    assert ed_es_frames(two, ed_label=2, es_label=7) == (2, 7)       # 2 frames: labels win
    assert ed_es_frames({4: 90.0, 6: float("nan")}) == (4, 4)
    with pytest.raises(ReconstructionError):
        ed_es_frames({1: float("nan")})


def _fake_model(volumes, ed, es, hr=75.0):
    study = Study(subject="fake", heart_rate_bpm=hr, frame_times_ms={0: 0.0, 1: 300.0})
    return SimpleNamespace(study=study, volumes=volumes, ed_frame=ed, es_frame=es, frames=[0, 1],
                           sections={}, apex_points={}, base_planes={})


def test_measure_from_volumes():
    vols = {0: {"lv_cavity": 150.0, "rv_cavity": 160.0, "lv_myocardium": 100.0, "rv_myocardium": 30.0},
            1: {"lv_cavity": 60.0, "rv_cavity": 90.0, "lv_myocardium": 101.0, "rv_myocardium": 31.0}}
    m = F.measure(_fake_model(vols, 0, 1))
    from cardionurbs.analysis.body import BODY_COLUMNS, INDEXED_COLUMNS
    assert list(m) == list(F.COLUMNS) + list(BODY_COLUMNS + INDEXED_COLUMNS)
    assert m["LVSV (mL)"] == 90.0 and m["LVEF (%)"] == pytest.approx(60.0)
    assert m["LVCO (L/min)"] == pytest.approx(90.0 * 75 / 1000)
    assert m["LVM (g)"] == pytest.approx(105.0) and m["RVM (g)"] == pytest.approx(31.5)
    assert m["RVSV (mL)"] == 70.0 and m["RVEF (%)"] == pytest.approx(43.75)
    assert m["LVSV-RVSV (mL)"] == 20.0
    # no stated pathology: the difference is not called a regurgitant volume (null + note)
    assert math.isnan(m["MR RegVol (mL)"]) and math.isnan(m["MR RegFrac (%)"])
    model = _fake_model(vols, 0, 1)
    assert "not the stated question" in F.measure(model).notes["MR RegVol (mL)"]
    model.study.meta["pathology"] = "mr"                  # stated: a phantom, metadata, --pathology
    m = F.measure(model)
    assert m["MR RegVol (mL)"] == 20.0 and m["MR RegFrac (%)"] == pytest.approx(100 * 20 / 90)
    assert m["RV/LV EDV ratio"] == pytest.approx(160 / 150)
    assert m["RV/LV mass ratio"] == pytest.approx(30 / 100)
    assert all(math.isnan(m[c]) for c in F.TAG_COLUMNS)
    assert math.isnan(m["EI ES"])                                     # no sections


def test_measure_without_rv_or_heart_rate():
    vols = {0: {"lv_cavity": 150.0}, 1: {"lv_cavity": 60.0}}
    m = F.measure(_fake_model(vols, 0, 1, hr=None))
    assert math.isnan(m["HR (bpm)"]) and math.isnan(m["LVCO (L/min)"])
    assert math.isnan(m["RVEDV (mL)"]) and math.isnan(m["MR RegVol (mL)"])
    m2 = F.measure(_fake_model(vols, 0, 1, hr=None), heart_rate_bpm=60.0)
    assert m2["LVCO (L/min)"] == pytest.approx(90 * 60 / 1000)


def test_volume_curve():
    vols = {0: {"lv_cavity": 150.0}, 1: {"lv_cavity": 60.0}}
    c = F.volume_curve(_fake_model(vols, 0, 1))
    assert c["frame"] == [0, 1] and c["time_ms"] == [0.0, 300.0]
    assert c["lv_cavity (mL)"] == [150.0, 60.0] and math.isnan(c["rv_cavity (mL)"][0])


# ------------------------------------------------------------------ Simpson
def _cylinder_study(radius=20.0, n_slices=6, spacing=10.0):
    st = Study(subject="cyl")
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    for k in range(n_slices):
        z = -k * spacing
        im = ImagePlane(id=f"sa_{k:02d}", slice=f"sa_{k:02d}", view="SA", frame=0,
                        position=[-100, -100, z], row_cosine=[1, 0, 0], column_cosine=[0, 1, 0],
                        pixel_spacing=(1.0, 1.0), thickness=8.0)
        st.images.append(im)
        for s, r in (("lv_endo", radius), ("lv_epi", radius + 5)):
            pts = np.column_stack([r * np.cos(t), r * np.sin(t), np.full(len(t), z)])
            st.contours.append(Contour(s, "SA", im.slice, 0, pts, image=im.id))
    return st


def test_polygon_area_and_spacing():
    sq = np.array([[0, 0, 1], [3, 0, 1], [3, 2, 1], [0, 2, 1]], float)
    assert polygon_area(sq, np.array([0, 0, 1.0])) == pytest.approx(6.0)
    assert slice_spacing(np.array([0, 10, 20.0, 30])) == pytest.approx(10.0)


def test_disk_summation_of_a_cylinder():
    st = _cylinder_study()
    v = disk_volumes(st, 0)
    area = lambda r: 0.5 * 400 * r * r * np.sin(2 * np.pi / 400)   # noqa: E731 (inscribed polygon)
    assert v["lv_cavity"] == pytest.approx(6 * 10 * area(20) / 1000, rel=1e-9)
    assert v["lv_myocardium"] == pytest.approx(6 * 10 * (area(25) - area(20)) / 1000, rel=1e-9)
    assert math.isnan(v["rv_cavity"])
