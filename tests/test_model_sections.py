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
