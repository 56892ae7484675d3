"""Per-subject 95 % intervals (cardionurbs.analysis.uncertainty, docs/metrics.md Uncertainty):
the truth of a noise-free phantom lies inside them, injected contour noise widens them, a
one-frame study has no EF interval (null, with the reason), and the API, metrics.json,
cohort CSV and ``--max-halfwidth`` carry them."""

from __future__ import annotations

import importlib
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cardionurbs.analysis.uncertainty as U
from cardionurbs import measure, reconstruct
from cardionurbs.analysis.uncertainty import (COVERED, INTERVAL_COLUMNS, _normal_scatter,
                                              halfwidth_flags, intervals, parse_max_halfwidth)
from cardionurbs.cli import main
from cardionurbs.cohort import cohort
from cardionurbs.pipeline import write_analysis

generate = importlib.import_module("cardionurbs.phantom.generate")

MAIN = ("LVEDV (mL)", "LVESV (mL)", "LVSV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVESV (mL)",
        "RVEF (%)", "RVM (g)")


def _phantom(noise_px: float):
    ph = generate.generate("normal", seed=3, frames=2, noise_px=noise_px)
    ph.study.tags = []                      # not needed here (and they cost time)
    model = reconstruct(ph.study)
    return ph, model, measure(model, uncertainty=True)


@pytest.fixture(scope="module")
def clean():
    return _phantom(0.0)


@pytest.fixture(scope="module")
def noisy():
    return _phantom(1.0)


def _halfwidth(m: dict, col: str) -> float:
    return 0.5 * (m[f"{col} hi95"] - m[f"{col} lo95"])


def test_noise_free_phantom_truth_inside_every_interval(clean):
    ph, model, m = clean
    truth = ph.truth["metrics"]
    for col in COVERED:
        lo, hi = m[f"{col} lo95"], m[f"{col} hi95"]
        assert lo <= m[col] <= hi, col
        assert lo <= truth[col] <= hi, (col, lo, truth[col], hi)
        assert hi - lo > 0, col


def test_contour_noise_widens_the_intervals(clean, noisy):
    """1 px of contour noise widens every interval, and its contours source at least twice
    (the model-error terms, which no noise changes, keep the RV's total from doubling)."""
    _, model_a, a = clean
    _, model_b, b = noisy
    sd_a, sd_b = intervals(model_a, a)["sd"], intervals(model_b, b)["sd"]
    for col in MAIN:
        assert _halfwidth(b, col) > 1.15 * _halfwidth(a, col), col
        assert sd_b[col]["contours"] > 2.0 * sd_a[col]["contours"], col
    ph, model, m = noisy                     # and the noisy truth is still inside (loosely:
    inside = sum(m[f"{c} lo95"] <= ph.truth["metrics"][c] <= m[f"{c} hi95"] for c in MAIN)
    assert inside >= len(MAIN) - 1           # a 95 % interval may miss one of nine)


def test_sources_and_method_in_the_result(clean):
    _, model, m = clean
    iv = intervals(model, m)
    assert U.lv_input_kind(model) is None       # long-axis contours fix the base: observed
    assert iv["sd"]["LVEDV (mL)"]["lv shape"] == pytest.approx(
        U.LV_SHAPE_ED_FACTOR["observed"] * U.LV_SHAPE_REL["observed"] * m["LVEDV (mL)"], rel=1e-3)
    assert iv["sd"]["LVESV (mL)"]["lv shape"] == pytest.approx(
        U.LV_SHAPE_REL["observed"] * m["LVESV (mL)"], rel=1e-3)
    assert "analytic" in iv["method"]
    sd = iv["sd"]["LVEDV (mL)"]
    assert {"contours", "between", "base", "apex"} <= set(sd)
    assert all(v >= 0 and math.isfinite(v) for v in sd.values())
    # SA-only ends are placed by a rule: the base and apex allowances grow without LA views
    assert {k: v for k, v in iv["notes"].items() if k in COVERED} == {}
    assert iv["notes"]["Twist (deg)"] == "the metric is empty"     # no tags here


def test_lvm_factor_scales_the_wall_interval_alone(clean, monkeypatch):
    """LVM's own width: its input kind's LVM_FACTOR multiplies the wall's propagated SD (every
    source) and nothing else; the one-sided allowances and the other columns are kept."""
    _, model, m = clean
    assert U.lvm_factor(model) == U.LVM_FACTOR["observed"]    # long-axis contours: observed
    before = intervals(model, m)
    monkeypatch.setitem(U.LVM_FACTOR, "observed", 0.5 * U.LVM_FACTOR["observed"])
    after = intervals(model, m)
    col, v = "LVM (g)", m["LVM (g)"]
    for k, sd in before["sd"][col].items():
        assert after["sd"][col][k] == pytest.approx(0.5 * sd, abs=1e-12), k
    total = math.sqrt(sum(x * x for x in before["sd"][col].values()))
    assert (before[col][1] - v) - (after[col][1] - v) == pytest.approx(0.5 * U.Z95 * total)
    assert (v - before[col][0]) - (v - after[col][0]) == pytest.approx(0.5 * U.Z95 * total)
    for c in COVERED:
        if c != col:
            assert after[c] == before[c], c
    monkeypatch.setitem(U.LVM_FACTOR, "labels", 7.0)           # another kind's entry: no effect
    assert intervals(model, m)[col] == after[col]


@pytest.fixture(scope="module")
def sa_only():
    """The clean fixture's phantom without its long-axis views (SA contours alone)."""
    ph = generate.generate("normal", seed=3, frames=2)
    st = ph.study
    st.tags = []
    st.contours = [c for c in st.contours if c.view == "SA"]
    st.landmarks = [lm for lm in st.landmarks if lm.view == "SA"]
    st.images = [im for im in st.images if im.view == "SA"]
    model = reconstruct(st)
    return ph, model, measure(model)


def test_contours_with_and_without_long_axis_views_are_two_kinds(clean, sa_only, monkeypatch):
    """The same hand contours with long-axis views (``observed``: the data fix the LV base)
    and without (``contours``: the half-slice rule places it) are two input kinds, each
    interval keyed by its own kind's entries and by no other's."""
    (_, la, m_la), (_, sa, m_sa) = clean, sa_only
    assert U.lv_input_kind(la) is None and U.lv_input_kind(sa) == "contours"
    before = {k: intervals(model, m) for k, model, m in (("la", la, m_la), ("sa", sa, m_sa))}
    for kind, moved, kept in (("observed", ("la", la, m_la), ("sa", sa, m_sa)),
                              ("contours", ("sa", sa, m_sa), ("la", la, m_la))):
        with monkeypatch.context() as mp:
            mp.setitem(U.LV_SHAPE_REL, kind, 4.0 * U.LV_SHAPE_REL[kind] + 0.01)
            mp.setitem(U.LVM_FACTOR, kind, 2.0 * U.LVM_FACTOR[kind])
            a, b = intervals(*moved[1:]), intervals(*kept[1:])
        for col in ("LVEDV (mL)", "LVESV (mL)", "LVM (g)"):
            assert a[col][1] - a[col][0] > before[moved[0]][col][1] - before[moved[0]][col][0], col
            assert b[col] == before[kept[0]][col], col


def test_labels_entries_interpolate_in_the_slice_spacing(monkeypatch):
    """A label map without long-axis maps takes the ``labels 5mm`` entry at 5 mm, the
    ``labels`` entry at 10 mm, the two linearly between and the nearer one beyond; the other
    kinds their own entry whatever the spacing."""
    table = {"labels": 1.0, "labels 5mm": 0.4, "labels+LA": 2.0}
    for h, want in ((5.0, 0.4), (10.0, 1.0), (7.5, 0.7), (6.0, 0.52), (3.0, 0.4), (14.0, 1.0),
                    (float("nan"), 1.0)):
        monkeypatch.setattr(U, "sa_spacing_mm", lambda model, h=h: h)
        assert U.kind_entry(table, None, "labels", 9.0) == pytest.approx(want), h
        assert U.kind_entry(table, None, "labels+LA", 9.0) == 2.0
        assert U.kind_entry(table, None, "contours", 9.0) == 9.0
    assert U.kind_entry({"labels": 1.0}, None, "labels", 9.0) == 1.0   # no 5 mm entry


@pytest.mark.parametrize("spacing, moved, kept", [(5.0, "labels 5mm", "labels"),
                                                  (10.0, "labels", "labels 5mm")])
def test_label_maps_at_5_and_10_mm_take_their_own_entries(tmp_path, monkeypatch, spacing, moved,
                                                          kept):
    """A 5 mm and a 10 mm ACDC-layout label map: the SA spacing read from the map, and each
    interval moved by its own spacing's entries only."""
    from cardionurbs import load_study
    from cardionurbs.phantom.labelmaps import write_labelmaps

    ph = generate.generate("normal", seed=3, frames=2, sa_spacing_mm=spacing,
                           sa_thickness_mm=min(8.0, spacing))
    ph.study.tags = []
    write_labelmaps(ph, tmp_path, "acdc", images=False)
    model = reconstruct(load_study(tmp_path))
    m = measure(model)
    assert U.lv_input_kind(model) == "labels"
    assert U.sa_spacing_mm(model) == pytest.approx(spacing, abs=1e-6)
    before = intervals(model, m)
    with monkeypatch.context() as mp:
        mp.setitem(U.LVM_FACTOR, kept, 5.0 * U.LVM_FACTOR[kept])
        mp.setitem(U.LV_SHAPE_REL, kept, 4.0 * U.LV_SHAPE_REL[kept] + 0.01)
        assert intervals(model, m)["LVM (g)"] == before["LVM (g)"]
        assert intervals(model, m)["LVEDV (mL)"] == before["LVEDV (mL)"]
    with monkeypatch.context() as mp:
        mp.setitem(U.LVM_FACTOR, moved, 2.0 * U.LVM_FACTOR[moved])
        mp.setitem(U.LV_SHAPE_REL, moved, 4.0 * U.LV_SHAPE_REL[moved] + 0.01)
        after = intervals(model, m)
    for col in ("LVM (g)", "LVEDV (mL)", "LVESV (mL)"):
        assert after[col][1] - after[col][0] > before[col][1] - before[col][0], col


def test_without_long_axis_views_the_ends_dominate(sa_only, monkeypatch):
    # a positive entry with ρ 1 and one share at ED and ES is set here (whatever the
    # calibrated ones are) so that the term's propagation is what is checked
    monkeypatch.setitem(U.LV_SHAPE_REL, "contours", 0.03)
    monkeypatch.setitem(U.LV_SHAPE_CORR, "contours", 1.0)  # one error at ED and ES (below)
    monkeypatch.setitem(U.LV_SHAPE_ED_FACTOR, "contours", 1.0)  # the same share at both
    ph, model, m = sa_only
    iv = intervals(model, m)
    sd = iv["sd"]["LVEDV (mL)"]
    assert sd["base"] > 5 * sd["contours"]
    lo, hi = iv["LVEDV (mL)"]
    assert lo <= ph.truth["metrics"]["LVEDV (mL)"] <= hi
    # the rule-placed base's model-error term: the input kind's share of each volume, one
    # error at ED and ES, so that it cancels in EF
    assert U.lv_input_kind(model) == "contours"
    assert U.lvm_factor(model) == U.LVM_FACTOR["contours"]
    rel = U.LV_SHAPE_REL["contours"]
    assert sd["lv shape"] == pytest.approx(rel * m["LVEDV (mL)"], rel=1e-3)
    assert iv["sd"]["LVESV (mL)"]["lv shape"] == pytest.approx(rel * m["LVESV (mL)"], rel=1e-3)
    assert iv["sd"]["LVSV (mL)"]["lv shape"] == pytest.approx(rel * m["LVSV (mL)"], rel=1e-3)
    assert iv["sd"]["LVEF (%)"]["lv shape"] == pytest.approx(0.0, abs=1e-9)
    # independent ED and ES errors (the kind's LV_SHAPE_CORR 0): SV and EF get the term,
    # EDV keeps it
    monkeypatch.setitem(U.LV_SHAPE_CORR, "observed", 0.0)   # another kind's entry: no effect
    assert intervals(model, m)["sd"]["LVEF (%)"]["lv shape"] == pytest.approx(0.0, abs=1e-9)
    monkeypatch.setitem(U.LV_SHAPE_CORR, "contours", 0.0)
    ind = intervals(model, m)["sd"]
    a, b = rel * m["LVEDV (mL)"], rel * m["LVESV (mL)"]
    assert ind["LVEDV (mL)"]["lv shape"] == pytest.approx(a, rel=1e-3)
    assert ind["LVSV (mL)"]["lv shape"] == pytest.approx(math.hypot(a, b), rel=1e-3)
    ef = 100.0 * b / m["LVEDV (mL)"] * math.sqrt(2.0)
    assert ind["LVEF (%)"]["lv shape"] == pytest.approx(ef, rel=1e-3)
    # the ED share of the term its own (LV_SHAPE_ED_FACTOR): EDV's lv shape halves, ESV's stays,
    # EF's follows the delta method with ρ 0
    monkeypatch.setitem(U.LV_SHAPE_ED_FACTOR, "contours", 0.5)
    half_iv = intervals(model, m)
    half = half_iv["sd"]
    assert half["LVEDV (mL)"]["lv shape"] == pytest.approx(0.5 * a, rel=1e-3)
    assert half["LVESV (mL)"]["lv shape"] == pytest.approx(b, rel=1e-3)
    g_ed, g_es = 100.0 * m["LVESV (mL)"] / m["LVEDV (mL)"] ** 2, 100.0 / m["LVEDV (mL)"]
    assert half["LVEF (%)"]["lv shape"] == pytest.approx(math.hypot(g_ed * 0.5 * a, g_es * b),
                                                         rel=1e-3)
    # the base term's factor scales the base SD alone, not the one-sided allowances
    monkeypatch.setattr(U, "BASE_FACTOR", 0.5 * U.BASE_FACTOR)
    based = intervals(model, m)
    for col in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)"):
        assert half[col]["base"] > 0, col
        assert based["sd"][col]["base"] == pytest.approx(0.5 * half[col]["base"], rel=1e-9)
        for iv in (half_iv, based):
            tot = U.Z95 * math.sqrt(sum(x * x for x in iv["sd"][col].values()))
            iv[col] = (iv[col][1] - m[col]) - tot              # the allowance above
        assert based[col] == pytest.approx(half_iv[col], abs=1e-9), col


def test_one_frame_study_has_no_ef_interval(clean):
    ph, _, _ = clean
    st = ph.study
    one = type(st)(subject="one", images=[im for im in st.images if im.frame == 0],
                   contours=[c for c in st.contours if c.frame == 0],
                   landmarks=[lm for lm in st.landmarks if lm.frame == 0],
                   frame_times_ms={0: 0.0}, heart_rate_bpm=st.heart_rate_bpm, ed_frame=0,
                   es_frame=0)
    model = reconstruct(one)
    m = measure(model, uncertainty=True)
    iv = intervals(model, m)
    for col in ("LVEF (%)", "LVESV (mL)", "RVEF (%)"):
        assert iv[col] is None
        assert "one frame" in iv["notes"][col]
        assert math.isnan(m[f"{col} lo95"]) and math.isnan(m[f"{col} hi95"])
    assert iv["LVEDV (mL)"] is not None          # ED alone still has its volume
    assert json.loads(json.dumps(iv))["LVEF (%)"] is None


def test_metrics_json_carries_the_intervals(clean, tmp_path):
    _, model, m = clean
    plain = {k: v for k, v in m.items() if k not in INTERVAL_COLUMNS}
    write_analysis(model, plain, tmp_path / "on", outputs=("metrics",))
    write_analysis(model, plain, tmp_path / "off", outputs=("metrics",), uncertainty=False)
    on = json.loads((tmp_path / "on" / "metrics.json").read_text())
    assert on["uncertainty"]["LVEF (%)"] == pytest.approx([m["LVEF (%) lo95"], m["LVEF (%) hi95"]])
    assert on["uncertainty"]["method"]
    assert json.loads((tmp_path / "off" / "metrics.json").read_text())["uncertainty"] is None


def test_max_halfwidth_parsing_and_flags():
    assert parse_max_halfwidth("LVEF=5,lvedv (ml)=10") == {"LVEF (%)": 5.0, "LVEDV (mL)": 10.0}
    for bad in ("LVXX=5", "LVEF", "LVEF=-1", "LVEF=abc", ""):
        with pytest.raises(ValueError, match="--max-halfwidth"):
            parse_max_halfwidth(bad)
    iv = {"LVEF (%)": [50.0, 62.0], "LVEDV (mL)": [100.0, 104.0], "RVEF (%)": None,
          "notes": {"RVEF (%)": "the metric is empty"}}
    flags = halfwidth_flags(iv, {"LVEF (%)": 5.0, "LVEDV (mL)": 10.0, "RVEF (%)": 5.0})
    assert len(flags) == 2
    assert flags[0].startswith("LVEF (%) 95 % interval ± 6")
    assert "the metric is empty" in flags[1]


def test_cli_refuses_a_bad_max_halfwidth(tmp_path, capsys):
    assert main(["cohort", str(tmp_path), "--csv", str(tmp_path / "c.csv"),
                 "--max-halfwidth", "LVEF=x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--max-halfwidth" in err[0]


def test_cohort_columns_and_imprecise_subject_flagged(tmp_path):
    ph = generate.generate("normal", seed=4, frames=2, noise_px=0.5)
    ph.study.tags = []
    ph.study.contours = [c for c in ph.study.contours if c.view == "SA"]    # ends left open
    ph.study.landmarks = [lm for lm in ph.study.landmarks if lm.view == "SA"]
    generate.write_phantom(ph, tmp_path / "s", dicom=False)
    t = cohort([tmp_path / "s"], max_halfwidth={"LVEDV (mL)": 1.0, "LVEF (%)": 50.0})
    r = t.iloc[0]
    assert r["status"] == "ok"
    assert list(t.columns[-len(INTERVAL_COLUMNS) - 2:-2]) == list(INTERVAL_COLUMNS)
    assert r["LVEDV (mL) lo95"] < r["LVEDV (mL)"] < r["LVEDV (mL) hi95"]
    assert "LVEDV (mL) 95 % interval" in r["QC"] and "LVEF (%) 95 % interval" not in r["QC"]
    strict = cohort([tmp_path / "s"], max_halfwidth={"LVEDV (mL)": 1.0}, strict=True)
    assert strict.iloc[0]["status"].startswith("error: QC:")
    assert np.isnan(strict.iloc[0]["LVEDV (mL) lo95"])


@settings(max_examples=30, deadline=None)
@given(r=st.floats(15, 40), n=st.integers(60, 200), frac=st.floats(0.05, 0.4),
       seed=st.integers(0, 2 ** 16))
def test_contour_scatter_of_a_noisy_circle(r, n, frac, seed):
    """The second-difference scatter of a circle's points recovers i.i.d. radial noise σ (to
    sampling error) while σ is below half the point spacing (a hand contour's or a phantom's:
    60 points round a 25 mm LV, σ <= 1 px), above the curvature floor a clean contour has."""
    sigma = frac * 2 * np.pi * r / n
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rad = r + rng.normal(0, sigma, n)
    pts = np.c_[rad * np.cos(t), rad * np.sin(t), np.zeros(n)]
    est, ds = _normal_scatter(pts, np.array([0.0, 0.0, 1.0]))
    step = 2 * np.pi * r / n                 # noise lengthens the steps: ds is then conservative
    assert 0.9 * step < ds < 1.25 * np.sqrt(step ** 2 + 2 * sigma ** 2)
    # a clean circle's second differences are its curvature, ds²/r: a conservative floor
    floor = (2 * np.pi * r / n) ** 2 / r / np.sqrt(0.4549 * 6)
    # a median of >= 60 second differences, neighbours sharing points (σ's relative sampling
    # SD ~ 15-20 %): within ~4 of it (r 15, n 60, 0.25 spacing, seed 43082 gave 1.56 σ)
    assert 0.5 * sigma < est < 1.8 * np.hypot(sigma, floor)
    clean, _ = _normal_scatter(np.c_[r * np.cos(t), r * np.sin(t), np.zeros(n)],
                               np.array([0.0, 0.0, 1.0]))
    assert clean == pytest.approx(floor, rel=0.05)
