"""Cohort figures: distributions by group, measured vs truth, Bland–Altman limits."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.analysis.function import COLUMNS
from cardionurbs.report import cohort_figures as C
from test_report_figures import check_png

METRICS = ["LVEDV (mL)", "LVEF (%)", "RVEDV (mL)", "Twist (deg)"]


def synthetic_cohort(seed: int = 0, error_rows: int = 1):
    """12 subjects (5 normal, 3 MR, 4 PHTN), measured = truth · (1 + 3 % noise) + offset."""
    rng = np.random.default_rng(seed)
    rows, trows = [], []
    for g, n in (("normal", 5), ("mr", 3), ("phtn", 4)):
        for k in range(n):
            s = f"{g}{k:02d}"
            t = {c: rng.uniform(20, 150) for c in COLUMNS}
            trows.append({"subject": s, "pathology": g, **t})
            rows.append({"subject": s, "status": "ok",
                         **{c: v * (1 + rng.normal(0, 0.03)) + 1.0 for c, v in t.items()}})
    for k in range(error_rows):
        rows.append({"subject": f"bad{k}", "status": "error: no contours",
                     **{c: np.nan for c in COLUMNS}})
    return pd.DataFrame(rows), pd.DataFrame(trows)


def test_bland_altman_values():
    ba = C.bland_altman([11, 12, 13, 14], [10, 10, 10, 10])
    d = np.array([1, 2, 3, 4.0])
    assert ba.n == 4 and ba.bias == pytest.approx(2.5)
    assert ba.sd == pytest.approx(d.std(ddof=1))
    assert ba.lower == pytest.approx(2.5 - 1.96 * d.std(ddof=1))
    assert ba.upper == pytest.approx(2.5 + 1.96 * d.std(ddof=1))
    one = C.bland_altman([1.0, np.nan], [0.5, 2.0])
    assert one.n == 1 and one.bias == 0.5 and np.isnan(one.sd) and np.isnan(one.upper)
    assert np.isnan(C.bland_altman([], []).bias)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=30), st.floats(-100, 100))
def test_bland_altman_shift_moves_bias_only(values, shift):
    t = np.asarray(values)
    m = t + np.linspace(-1, 1, t.size)
    a, b = C.bland_altman(m, t), C.bland_altman(m + shift, t)
    assert b.bias == pytest.approx(a.bias + shift, abs=1e-6)
    assert b.sd == pytest.approx(a.sd, abs=1e-6)
    assert b.upper - b.bias == pytest.approx(b.bias - b.lower, abs=1e-6)


def test_cohort_figures_with_truth(tmp_path):
    df, truth = synthetic_cohort()
    df.to_csv(tmp_path / "cohort.csv", index=False)
    truth.to_csv(tmp_path / "truth.csv", index=False)
    fs = C.write_cohort_figures(tmp_path / "cohort.csv", tmp_path / "figs",
                                truth=tmp_path / "truth.csv", metrics=METRICS)
    assert [f.name for f in fs.figures] == ["cohort_distributions", "cohort_measured_vs_truth",
                                            "cohort_bland_altman"]
    assert fs.skipped == {}
    for res in fs.figures:
        assert set(res.colours) == {"normal", "MR", "PHTN"}
        assert "error" in res.caption                   # the error row is counted
        check_png(res, min_pixels=15, caption_word="n = " if res.name == "cohort_distributions" else "truth")
    agree = pd.read_csv(tmp_path / "figs" / "cohort_agreement.csv").set_index("metric")
    ok = df[df.status == "ok"].set_index("subject")
    t = truth.set_index("subject").loc[ok.index]
    d = ok["LVEF (%)"] - t["LVEF (%)"]
    assert agree.loc["LVEF (%)", "bias"] == pytest.approx(d.mean())
    assert agree.loc["LVEF (%)", "upper"] == pytest.approx(d.mean() + 1.96 * d.std(ddof=1))
    assert agree.loc["LVEF (%)", "n"] == 12


def test_groups_from_truth_folders(tmp_path):
    df, truth = synthetic_cohort(error_rows=0)
    for _, r in truth.iterrows():
        (tmp_path / r["subject"]).mkdir()
        (tmp_path / r["subject"] / "truth.json").write_text(json.dumps(
            {"subject": r["subject"], "pathology": r["pathology"],
             "metrics": {c: float(r[c]) for c in COLUMNS}}))
    t = C.read_truth(tmp_path)
    groups = C.cohort_groups(df, t)
    assert groups.value_counts().to_dict() == {"normal": 5, "PHTN": 4, "MR": 3}
    explicit = C.cohort_groups(df, None, {"normal00": "control"})
    assert explicit["normal00"] == "control" and explicit["mr00"] == "other"


def test_missing_truth_and_failed_cohort_leave_figures_out(tmp_path):
    df, _ = synthetic_cohort()
    fs = C.write_cohort_figures(df, tmp_path / "a", metrics=METRICS[:2])
    assert [f.name for f in fs.figures] == ["cohort_distributions"]
    assert set(fs.skipped) == {"cohort_measured_vs_truth", "cohort_bland_altman"}
    assert "no truth" in fs.skipped["cohort_bland_altman"]
    assert (tmp_path / "a" / "skipped.txt").read_text().count("\n") == 2
    bad = df.assign(status="error: x")
    fs = C.write_cohort_figures(bad, tmp_path / "b")
    assert fs.figures == [] and len(fs.skipped) == 3


def test_unreadable_inputs_raise_one_line(tmp_path):
    with pytest.raises(C.CohortInputError, match="nope.csv"):
        C.write_cohort_figures(tmp_path / "nope.csv", tmp_path / "o")
    (tmp_path / "x.csv").write_text("a,b\n1,2\n")
    with pytest.raises(C.CohortInputError, match="subject"):
        C.write_cohort_figures(tmp_path / "x.csv", tmp_path / "o")
