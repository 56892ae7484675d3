"""The metrics-only speed-ups of issue 16 (helper B, session 10) compute what they replace:
the fast median equals ``np.median`` bit for bit, the batched simplicity test of the input
checks agrees with the per-contour crossing search, and the tag-line checks run once per
tag list but again when the list changes."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_data
from hypothesis import given, settings, strategies as st

from cardionurbs.errors import TagError
from cardionurbs.io.checks import known_simple, self_intersections
from cardionurbs.median import median


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), max_size=40), st.booleans(),
       st.integers(0, 3))
def test_median_equals_numpy_bit_for_bit(values, with_nan, repeats):
    x = np.array(values * (1 + repeats), dtype=float)
    if with_nan and len(x):
        x[len(x) // 2] = np.nan
    want = float(np.median(x)) if len(x) else float("nan")
    got = median(x)
    assert (np.isnan(want) and np.isnan(got)) or got == want


def _polyline(rng, kind: str, n: int) -> tuple[np.ndarray, bool]:
    t = np.sort(rng.uniform(0, 2 * np.pi, n))
    if kind == "loop":           # star-shaped about its centre: the angular fast path
        r = rng.uniform(5, 30) * (1 + 0.3 * rng.uniform(-1, 1, n))
        return np.c_[r * np.cos(t), r * np.sin(t)], True
    if kind == "crescent":       # an RV-like crescent: not star-shaped about its centroid
        a = np.linspace(-2.2, 2.2, n // 2)
        outer = np.c_[30 * np.cos(a), 30 * np.sin(a)]
        inner = np.c_[22 * np.cos(a[::-1]) + 6, 22 * np.sin(a[::-1])]
        p = np.vstack([outer, inner]) + rng.normal(0, rng.choice([0.0, 0.5, 4.0]), (2 * (n // 2), 2))
        return p, True
    if kind == "scribble":       # random points: usually crossing
        return rng.uniform(-20, 20, (n, 2)), bool(rng.integers(2))
    # an open wiggly arc, sometimes with repeated points and a closing duplicate
    p = np.c_[np.linspace(0, 40, n), 3 * np.sin(np.linspace(0, rng.uniform(1, 12), n))]
    p = np.repeat(p, rng.integers(1, 3, n), axis=0)
    return p, False


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 12))
def test_known_simple_agrees_with_the_crossing_search(seed, count):
    rng = np.random.default_rng(seed)
    curves, closed = [], []
    for _ in range(count):
        kind = rng.choice(["loop", "crescent", "scribble", "arc"])
        p, cl = _polyline(rng, kind, int(rng.choice([4, 12, 48, 60, 140])))
        curves.append(p)
        closed.append(cl)
    got = known_simple(curves, closed)
    for p, cl, g in zip(curves, closed, got):
        simple = len(self_intersections(p, cl)) == 0
        assert g <= simple                      # never calls a crossing curve simple
        if len(p) <= 128:                       # and, where it judges, misses no simple one
            assert g == simple


@pytest.mark.realdata
def test_known_simple_on_a_real_study_matches_contour_by_contour():
    """bivme-patient1 (CAP): a thousand contours, some open ones crossing themselves."""
    from cardionurbs.io import load_study
    from cardionurbs.io.checks import _annotation_files, _plane_of, in_plane_coordinates
    s = load_study(shared_data("bivme-patient1"))
    cs = [(c, f) for c, f in zip(s.contours, _annotation_files(s))
          if c.ventricular and len(c.points) >= 3]
    xys = [in_plane_coordinates(c.points, _plane_of(s, c, f)) for c, f in cs]
    got = known_simple(xys, [c.closed for c, _ in cs])
    want = [len(self_intersections(xy, c.closed, first=True)) == 0 for xy, (c, _) in zip(xys, cs)]
    assert not all(want) and all(len(xy) <= 128 for xy in xys)
    assert [bool(g) for g in got] == want


def test_tag_lines_are_checked_again_when_the_list_changes():
    from cardionurbs.analysis.tag_surfaces import check_tags
    from cardionurbs.study import TagLine
    from test_tags_analytic import AnalyticHeart
    study = AnalyticHeart().study()
    check_tags(study)
    line = study.tags[0]
    study.tags.append(TagLine(line.family, line.index, line.view, line.slice, line.frame,
                              line.points.copy(), line.image))
    with pytest.raises(TagError, match="appears twice"):
        check_tags(study)
    study.tags.pop()
    check_tags(study)
    study.tags = list(study.tags) + [line]          # a new list of the same length + 1
    with pytest.raises(TagError, match="appears twice"):
        check_tags(study)


def test_stacking_direction_is_cached_per_frame_and_follows_changes():
    from cardionurbs.anatomy.sections import _stacking_direction, stacking_direction
    from test_tags_analytic import AnalyticHeart
    study = AnalyticHeart().study()
    n, th = stacking_direction(study)
    assert np.array_equal(n, _stacking_direction(study, None)[0]) and th == _stacking_direction(study, None)[1]
    n[:] = 0                                        # the caller's copy, not the cache
    assert np.array_equal(stacking_direction(study)[0], _stacking_direction(study, None)[0])
    sa = [im for im in study.images if im.view == "SA"]     # a new, shorter image list
    study.images = [im for im in study.images if im.view != "SA"] + sa[: len(sa) // 2]
    want = _stacking_direction(study, None)
    got = stacking_direction(study)
    assert np.array_equal(got[0], want[0]) and got[1] == want[1]


def test_manifest_numbers_fast_path_keeps_each_message(tmp_path):
    from cardionurbs.errors import StudyError
    from cardionurbs.io.schema import _Checker
    c = _Checker(tmp_path / "study.json")
    c.numbers([1.0, 2, -3.5], "position", 3, -10, 10)
    for bad, msg in (([1.0, True, 2.0], "must be a number"), ([1.0, float("nan"), 2.0], "finite"),
                     ([1.0, 11.0, 2.0], r"in \[-10, 10\]"), ([1.0, "2", 3.0], "must be a number")):
        with pytest.raises(StudyError, match=msg):
            c.numbers(bad, "position", 3, -10, 10)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.booleans(), st.booleans())
def test_sample_points_equal_curve_evaluate(seed, closed, rational):
    """The distance bounds' samples from cached basis values: curve.evaluate's numbers, bit
    for bit, for every curve sharing the knots."""
    from cardionurbs.nurbs import NurbsCurve
    from cardionurbs.nurbs.projection import _sample_points, _span_samples
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 14))
    inner = np.sort(rng.uniform(0.05, 0.95, n - 4 if not closed else n - 1))
    for k in range(3):                   # three curves on one knot vector (the cache hits)
        P = rng.normal(0, 20, (n, 3))
        w = rng.uniform(0.5, 2.0, n) if rational else None
        if closed:
            U = np.concatenate([inner[-3:] - 1, [0.0], inner, [1.0], inner[:3] + 1])
            c = NurbsCurve(3, U, P, w, closed=True)
        else:
            c = NurbsCurve(3, np.concatenate([[0] * 4, inner, [1] * 4]), P, w)
        lo, hi = c.domain
        us = _span_samples(c.knots, c.degree, lo, hi, 16, c.closed, minimum=256)
        assert np.array_equal(_sample_points(c, us), c.evaluate(us))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-50, 50), min_size=1, max_size=8, unique=True), st.data())
def test_stack_ends_equal_is_extrapolated(keys, data):
    from types import SimpleNamespace
    from cardionurbs.analysis.tagqc import _is_extrapolated, _stack_ends
    secs = [SimpleNamespace(slice=f"sa_{k:02d}", key=v) for k, v in enumerate(keys)]
    names = [s.slice for s in secs]
    exclude = set(data.draw(st.lists(st.sampled_from(names), max_size=len(names))))
    slices = data.draw(st.lists(st.sampled_from(names), min_size=1, unique=True))
    got = _stack_ends(secs, slices, exclude)
    assert got == {s: _is_extrapolated(secs, s, exclude) for s in slices}


def test_contours_at_index_equals_a_scan_and_follows_changes():
    from test_tags_analytic import AnalyticHeart
    study = AnalyticHeart().study()

    def scan(frame, structure=None, view=None):
        structure = (structure,) if isinstance(structure, str) else structure
        return [c for c in study.contours if c.frame == frame
                and (structure is None or c.structure in structure)
                and (view is None or c.view == view)]

    frames = sorted({c.frame for c in study.contours})
    for f in frames + [999]:
        for structure in (None, "lv_endo", ("lv_endo", "rv_endo")):
            for view in (None, "SA", "LA"):
                assert study.contours_at(f, structure, view) == scan(f, structure, view)
    gone = study.contours.pop()                     # the list changes: the index follows
    assert gone not in study.contours_at(gone.frame)
    study.contours = study.contours + [gone]        # a new list
    assert study.contours_at(gone.frame) == scan(gone.frame)


def test_off_plane_distances_equal_one_line_at_a_time():
    from cardionurbs.io.checks import _Normals, _off_plane_distances, _plane_of
    from test_tags_analytic import AnalyticHeart
    study = AnalyticHeart().study()
    normals = _Normals()
    planes = [_plane_of(study, t, None) for t in study.tags]
    got = _off_plane_distances(study.tags, planes, normals)
    want = [float(np.abs((t.points - p.position) @ normals.of(p)).max())
            for t, p in zip(study.tags, planes)]
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.05, 6.0))
def test_merged_newton_seeds_find_the_same_closest_points(seed, noise_mm):
    """Seeds of one point that have met after a few Newton steps are merged
    (projection._MERGE_AFTER): the distances equal those of iterating every seed to the
    end (to rounding), on an LV-like surface with an apex, from points near and far."""
    from cardionurbs import nurbs
    from cardionurbs.nurbs import projection
    from tests.test_nurbs_api import lv_like_surface
    rng = np.random.default_rng(seed)
    s = lv_like_surface()
    P = s.evaluate_points(rng.random(150), rng.random(150)) + rng.normal(0, noise_mm, (150, 3))
    u, v, d = nurbs.closest_points(s, P)
    saved = projection._MERGE_AFTER
    try:
        projection._MERGE_AFTER = 10 ** 6             # never merge
        u0, v0, d0 = nurbs.closest_points(s, P)
    finally:
        projection._MERGE_AFTER = saved
    np.testing.assert_allclose(d, d0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(s.evaluate_points(u, v) - P, axis=1), d, atol=1e-12)
