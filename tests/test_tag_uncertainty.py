"""95 % intervals of twist, LS and the global tag strains (cardionurbs.analysis.tag_uncertainty,
docs/metrics.md Uncertainty): the noise-free tagged phantom's truth lies inside them, the
level standard errors grow with tag noise, the clustered standard error covers a shared
tag-line error that the i.i.d. one does not, and a study measured without its tag analysis
has none (null, with the reason)."""

from __future__ import annotations

import importlib
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import measure
from cardionurbs.analysis.tag_uncertainty import TAG_COVERED, level_statistics, mean_se
from cardionurbs.analysis.uncertainty import INTERVAL_COLUMNS, intervals
from cardionurbs.pipeline import analyse

generate = importlib.import_module("cardionurbs.phantom.generate")


@pytest.fixture(scope="module")
def tagged():
    ph = generate.generate("normal", seed=0, frames=2)
    model, metrics, _ = analyse(ph.study, over_time=False, jobs=1)
    return ph, model, metrics


def test_noise_free_tagged_phantom_truth_inside(tagged):
    ph, model, m = tagged
    iv = intervals(model, m)
    for col in TAG_COVERED:
        lo, hi = iv[col]
        assert lo <= m[col] <= hi, col
        assert lo <= ph.truth["metrics"][col] <= hi, (col, lo, ph.truth["metrics"][col], hi)
        assert iv["sd"][col] and all(v >= 0 for v in iv["sd"][col].values())
    assert {f"{c} lo95" for c in TAG_COVERED} <= set(INTERVAL_COLUMNS)


def test_no_tag_result_no_tag_interval(tagged):
    _, model, _ = tagged
    bare = SimpleNamespace(**{k: getattr(model, k) for k in ("study", "ed_frame", "es_frame")})
    m = {"Twist (deg)": 10.0, "LS (%)": 15.0, "Ecc_Global (%)": float("nan")}
    from cardionurbs.analysis.tag_uncertainty import tag_intervals
    out, notes, _ = tag_intervals(bare, m, 1.96)
    assert out["Twist (deg)"] is None and "no tag result" in notes["Twist (deg)"]
    assert out["Ecc_Global (%)"] is None and "empty" in notes["Ecc_Global (%)"]
    plain = measure(model, uncertainty=True)          # a bare measure: tag columns empty
    assert all(math.isnan(plain[f"{c} lo95"]) for c in TAG_COVERED)


def _levels(sigma_deg: float, sigma_mm: float, rng, n_lines: int = 5):
    """A fake tag result: two levels (LA planes 0 and 1, 20 mm apart at ED, 17 mm at ES) of
    n_lines × n_lines points round a circle of 25 mm, rotated by 10° and 2°, with noise."""
    apex, base = np.zeros(3), np.array([0.0, 0.0, 60.0])
    i, j = np.meshgrid(np.arange(n_lines), np.arange(n_lines), indexing="ij")
    th = 2 * np.pi * (i.ravel() * n_lines + j.ravel()) / n_lines ** 2
    X0, X1, tri = [], [], []
    for k, (z0, z1, rot) in enumerate(((20.0, 19.0, 10.0), (40.0, 36.0, 2.0))):
        t1 = th + np.radians(rot + rng.normal(0, sigma_deg, th.size))
        X0.append(np.c_[25 * np.cos(th), 25 * np.sin(th), z0 + rng.normal(0, sigma_mm, th.size)])
        X1.append(np.c_[25 * np.cos(t1), 25 * np.sin(t1), z1 + rng.normal(0, sigma_mm, th.size)])
        tri.append(np.c_[i.ravel(), j.ravel(), np.full(th.size, k)])
    triples = np.vstack(tri)
    mp = SimpleNamespace(positions={0: np.vstack(X0), 1: np.vstack(X1)}, triples=triples,
                         ed_frame=0, tracked=lambda a, b: np.ones(len(triples), bool))
    levels = [{"index": 0, "in_twist": True, "distance_from_apex_mm": 20.0,
               "distance_at_frame_mm": 19.0},
              {"index": 1, "in_twist": True, "distance_from_apex_mm": 40.0,
               "distance_at_frame_mm": 36.0}]
    return SimpleNamespace(material=mp, levels=levels), apex, base


def test_level_errors_grow_with_tag_noise():
    rng = np.random.default_rng(1)
    se = []
    for s in (0.0, 0.5, 2.0):
        tags, apex, base = _levels(s, s, rng)
        lv = level_statistics(tags, 1, apex, base)
        assert [x["n"] for x in lv] == [25, 25]
        se.append(lv[0]["se_rotation_deg"] + lv[0]["se_height_ed_mm"] + lv[1]["se_height_es_mm"])
    assert se[0] < 1e-9 < se[1] < se[2]
    tags, apex, base = _levels(1.0, 0.0, np.random.default_rng(2))
    iid = level_statistics(tags, 1, apex, base, clustered=False)[0]["se_rotation_deg"]
    assert iid == pytest.approx(1.0 / 5.0, rel=0.5)          # σ / √n, n = 25


@settings(max_examples=20, deadline=None)
@given(g=st.integers(4, 9), seed=st.integers(0, 2 ** 16))
def test_clustered_se_covers_a_shared_line_error(g, seed):
    """Points on a g × g grid of tag lines whose error is each sa1 line's own offset: the
    clustered standard error is never below the i.i.d. one and covers the true mean (0)
    about as often as it should, where the i.i.d. one, √g times too small, does not."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(g), np.arange(g), indexing="ij")
    lines = np.c_[i.ravel(), j.ravel()]
    hits_c = hits_i = 0
    trials = 200
    for _ in range(trials):
        v = rng.normal(0, 1, g)[lines[:, 0]] + rng.normal(0, 0.05, g * g)
        c, s = mean_se(v, lines), mean_se(v)
        assert c >= s
        hits_c += abs(v.mean()) <= 1.96 * c
        hits_i += abs(v.mean()) <= 1.96 * s
    # expected (4000 trials): clustered 0.85 (g = 4, few clusters) to 0.92 (g = 9), i.i.d.
    # 0.55 to 0.44; 0.75 lies > 4 SD of 200 trials from both (0.8 failed ~1 run in 5 at g = 4)
    assert hits_c / trials > 0.75 > hits_i / trials
