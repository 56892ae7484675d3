"""check_study: geometry predicates (against brute force) and warning / error rules."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from broken.corpus import synthetic_study
from cardionurbs import StudyError
from cardionurbs.geometry import polygon_area
from cardionurbs.io.checks import check_study, input_ed_es_frames, self_intersections


def _brute(xy, closed):
    """Every non-adjacent pair of segments, closed orientation-sign test (the definition)."""
    a = xy if closed else xy[:-1]
    b = np.roll(xy, -1, 0) if closed else xy[1:]
    m = len(a)

    def o(p, q, r):
        return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    out = []
    for i in range(m):
        for j in range(i + 2, m):
            if closed and i == 0 and j == m - 1:
                continue
            s1, s2 = o(a[i], b[i], a[j]), o(a[i], b[i], b[j])
            s3, s4 = o(a[j], b[j], a[i]), o(a[j], b[j], b[i])
            if s1 == s2 == 0:  # collinear: meet when the boxes overlap
                lo_i, hi_i = np.minimum(a[i], b[i]), np.maximum(a[i], b[i])
                lo_j, hi_j = np.minimum(a[j], b[j]), np.maximum(a[j], b[j])
                if np.all(lo_i <= hi_j) and np.all(lo_j <= hi_i):
                    out.append((i, j))
            elif s1 * s2 <= 0 and s3 * s4 <= 0:
                out.append((i, j))
    return sorted(out)


@settings(max_examples=150, deadline=None)
@given(arrays(float, st.tuples(st.integers(4, 25), st.just(2)),
              elements=st.floats(-50, 50, allow_nan=False).map(lambda v: round(v, 3))),
       st.booleans())
def test_self_intersections_equal_brute_force(xy, closed):
    if len(np.unique(xy, axis=0)) < len(xy) or np.any(np.all(np.diff(xy, axis=0) == 0, axis=1)):
        return  # repeated points are de-duplicated by design
    if np.ptp(xy, axis=0).min() == 0:
        return
    got = sorted(map(tuple, self_intersections(xy, closed).tolist()))
    assert got == _brute(xy, closed)


def test_simple_and_figure_eight():
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    assert len(self_intersections(np.c_[np.cos(t), 2 * np.sin(t)], True)) == 0
    assert len(self_intersections(np.c_[np.sin(t), np.sin(2 * t)], True)) > 0


@settings(max_examples=50, deadline=None)
@given(st.floats(1, 50), st.floats(1, 50), st.integers(3, 60))
def test_polygon_area_is_the_shoelace_area_in_any_plane(rx, ry, n):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    x, y = rx * np.cos(t), ry * np.sin(t)
    shoelace = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    q, _ = np.linalg.qr(np.random.default_rng(n).normal(size=(3, 3)))
    pts = np.c_[x, y, np.zeros(n)] @ q.T + [10, -20, 30]
    assert polygon_area(pts) == pytest.approx(shoelace, rel=1e-9)


def test_synthetic_study_is_clean():
    assert check_study(synthetic_study()) == []


def test_gap_in_stack_and_missing_structure_are_warnings():
    s = synthetic_study()
    extra = [dataclasses.replace(im, id=f"sa_03_f{im.frame}", slice="sa_03",
                                 position=im.position + 50.0 * im.normal)
             for im in s.images if im.slice == "sa_00"]
    s.images += extra
    w = check_study(s)
    assert len(w) == 1 and "slice sa_03: gap of 30.0 mm from sa_02 (median spacing 10.0 mm)" in w[0]
    s2 = synthetic_study()
    s2.contours = [c for c in s2.contours if not (c.structure == "lv_epi" and c.frame == 1)]
    w2 = check_study(s2)
    assert any("lv_epi (SA) is missing at ES (labelled)" in x and "frame 1" in x for x in w2)


def test_tilted_and_duplicate_slices_are_fatal():
    s = synthetic_study()
    c, si = np.cos(np.deg2rad(3)), np.sin(np.deg2rad(3))
    s.images = [dataclasses.replace(im, row_cosine=im.row_cosine * c + im.normal * si)
                if im.slice == "sa_01" else im for im in s.images]
    s.contours = [ct for ct in s.contours if ct.slice != "sa_01"]
    s.landmarks = [lm for lm in s.landmarks if lm.slice != "sa_01"]
    with pytest.raises(StudyError, match=r"slice sa_01, frame 0: SA slice is not parallel .*3.00 deg"):
        check_study(s)
    s = synthetic_study()
    s.images += [dataclasses.replace(im, id=f"x{im.frame}", slice="sa_09")
                 for im in s.images if im.slice == "sa_02"]
    with pytest.raises(StudyError, match="slices sa_02 and sa_09 are at the same position"):
        check_study(s)


def test_unlabelled_ed_es_estimated_from_areas():
    s = synthetic_study()
    s.ed_frame = s.es_frame = None
    assert input_ed_es_frames(s) == (0, 1, "estimated from SA lv_endo areas")


def test_contour_on_wrong_image_is_fatal():
    s = synthetic_study()
    s.contours[0].image = "sa_01_f0"
    with pytest.raises(StudyError, match="belongs to slice sa_01"):
        check_study(s)


def test_no_lv_endo_is_fatal():
    s = synthetic_study()
    s.contours = [c for c in s.contours if c.structure != "lv_endo"]
    with pytest.raises(StudyError, match="no LV endocardial"):
        check_study(s)


def test_touching_segment_found_when_the_diagonal_sweep_rounds_past_it():
    """A segment starting on another (non-adjacent) one touches it: found even though along
    the 135-degree sweep direction the two extents miss each other by a 1e-16 rounding of
    the projection (a case hypothesis found)."""
    xy = np.array([[-5.0, -5.0], [3.0, 3.0], [0.0, 0.0], [1.0, 0.0]])
    assert self_intersections(xy, closed=False).tolist() == [[0, 2]]
    assert _brute(xy, False) == [(0, 2)]
