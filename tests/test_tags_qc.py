"""Leave-one-out tag-jump QC on the analytic tagged heart (SA and LA families)."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs.analysis.tagqc import (_index_trend, _neighbour_pairs, blend_trace, tag_departures,
                                        tag_qc)
from test_tags_analytic import AnalyticHeart, SP

JUMPS = [("sa1", 0, "sa_03", 1), ("sa2", -2, "sa_00", 0), ("sa1", 2, "sa_06", 1),
         ("la", 5, "la_3ch", 1), ("la", 3, "la_2ch", 0)]


@pytest.fixture(scope="module")
def heart():
    return AnalyticHeart()


def test_every_jump_flagged_at_about_one_spacing(heart):
    flags = tag_qc(heart.study(jumps=JUMPS))
    assert {(f.family, f.index, f.slice, f.frame) for f in flags} == set(JUMPS)
    assert all(0.9 < f.departure < 1.4 for f in flags)


@pytest.mark.parametrize("noise", [0.0, 0.5])
def test_clean_study_has_no_flags(heart, noise):
    deps = tag_departures(heart.study(noise_px=noise, seed=11))
    assert deps and not [d for d in deps if d.flagged]
    assert max(d.departure for d in deps) < 0.3


def test_threshold_is_honoured(heart):
    st = heart.study(jumps=JUMPS)
    assert tag_qc(st, threshold=2.0) == []


def test_blend_trace_of_two_parallel_sections_is_the_midline():
    """The degree-1 loft between lines at z = 0 and z = 2 crosses z = 1 on their mean."""
    u = np.linspace(0, 1, 11)
    A = np.column_stack([u * 10, np.zeros_like(u), np.zeros_like(u)])
    B = np.column_stack([u * 10, np.full_like(u, 4.0), np.full_like(u, 2.0)])
    T, tan = blend_trace(A, B, np.array([0, 0, 1.0]), np.array([0, 0, 1.0]))
    assert np.allclose(T[:, 1], 2.0) and np.allclose(T[:, 2], 1.0)
    assert np.allclose(np.abs(tan[:, 0]), 1.0)


def test_neighbour_pairs_always_leave_a_witness_without_any_one_section():
    keys = np.arange(6) * 10.0
    for h in (-10.0, 5.0, 25.0, 45.0, 55.0, 70.0):     # 5, 45: next to a stack end
        pairs = _neighbour_pairs(keys, h)
        used = {k for p in pairs for k in p}
        for k in used:   # whichever single section jumped, a pair without it remains
            assert any(k not in p for p in pairs)


def test_index_trend_follows_a_smooth_pattern_and_ignores_one_jump():
    idx = np.arange(-4, 5)
    r = 0.3 + 0.1 * idx + 0.03 * idx ** 2      # loft error varying smoothly over the tags
    vals = [(int(j), float(v)) for j, v in zip(idx, r) if j != 4]
    assert _index_trend(vals, 4, 0.5 * SP) == pytest.approx(r[-1], abs=1e-9)   # edge: extrapolated
    vals = [(int(j), float(v) + (SP if j == 1 else 0.0)) for j, v in zip(idx, r) if j != 0]
    assert _index_trend(vals, 0, 0.5 * SP) == pytest.approx(0.3, abs=1e-9)     # jumped neighbour dropped
