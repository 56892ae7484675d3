"""Section hygiene: loops that cannot be whole LV cross-sections are left out, with a warning."""

from __future__ import annotations

import numpy as np

from cardionurbs.anatomy.sections import (MIN_LV_ROUNDNESS, Section, _drop_degenerate_loops,
                                          isoperimetric_quotient)

N = np.array([0.0, 0.0, 1.0])


def _ellipse(a, b, z, n=40):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([a * np.cos(t), b * np.sin(t), np.full(n, z)])


def _sec(points, slice_id):
    return Section("lv_endo", 3, points, slice=slice_id)


def test_isoperimetric_quotient_circle_and_folded_loop():
    assert abs(isoperimetric_quotient(_ellipse(20, 20, 0, 400), N) - 1) < 1e-3
    folded = np.vstack([_ellipse(20, 0.5, 0)[:20], _ellipse(20, 0.5, 0)[:20][::-1] + [0, 0.3, 0]])
    assert isoperimetric_quotient(folded, N) < MIN_LV_ROUNDNESS


def test_small_basal_loop_and_folded_loop_are_dropped_with_warnings():
    secs = [_sec(_ellipse(6, 5, 0), "sa_00"), _sec(_ellipse(25, 22, -10), "sa_01"),
            _sec(_ellipse(22, 20, -20), "sa_02"), _sec(_ellipse(15, 14, -30), "sa_03")]
    warnings: list[str] = []
    kept = _drop_degenerate_loops(secs, N, warnings)
    assert [s.slice for s in kept] == ["sa_01", "sa_02", "sa_03"]
    assert len(warnings) == 1 and "sa_00" in warnings[0] and "frame 3" in warnings[0]


def test_apical_narrowing_is_kept():
    secs = [_sec(_ellipse(25, 22, 0), "sa_00"), _sec(_ellipse(20, 18, -10), "sa_01"),
            _sec(_ellipse(4, 3, -20), "sa_02")]
    warnings: list[str] = []
    assert len(_drop_degenerate_loops(secs, N, warnings)) == 3 and not warnings


def test_fill_short_gaps_closes_only_short_runs_between_true():
    from cardionurbs.anatomy.sections import fill_short_gaps
    m = np.zeros(40, dtype=bool)
    m[0:10] = True
    m[12:20] = True          # gap of 2 between septal runs -> filled
    m[38:40] = True          # wraps round to index 0: the free run 20..37 (18) is kept
    out = fill_short_gaps(m, 4)
    assert out[10:12].all() and not out[20:38].any() and out[m].all()
    assert np.array_equal(fill_short_gaps(m, 0), m)
    assert np.array_equal(fill_short_gaps(np.zeros(5, bool), 3), np.zeros(5, bool))
    assert fill_short_gaps(m, 18).all()


def test_septal_mask_keeps_a_noisy_septum_contiguous():
    """An RV loop whose septal half lies on the LV epicardial circle, with 0.3 mm noise:
    some septal points fall outside the 0.5 mm band on their own; with gap filling the
    septum is one run and the free wall is untouched."""
    from cardionurbs.anatomy.sections import septal_mask
    rng = np.random.default_rng(7)
    lv = _ellipse(20.0, 20.0, 0.0, n=200)
    t = np.linspace(-np.pi / 2, np.pi / 2, 60)
    sept = np.column_stack([20 * np.cos(t), 20 * np.sin(t), np.zeros_like(t)])
    s = np.linspace(np.pi / 2, -np.pi / 2, 60)[1:-1]
    free = np.column_stack([20 * np.cos(s) + 25 * np.cos(s), 20 * np.sin(s) * 1.6, np.zeros_like(s)])
    loop = np.vstack([sept, free])
    loop[:60, :2] += rng.normal(0, 0.3, (60, 2))
    raw = septal_mask(loop, lv, N, near_mm=0.5)
    closed = septal_mask(loop, lv, N, near_mm=0.5, max_gap=len(loop) // 8)
    assert not raw[:60].all()                 # noise alone splits the septum
    assert closed[:60].all() and not closed[62:-2].any()
