"""`cardionurbs demo`: subjects generated, analysed, CSVs written, metrics printed beside truth
(run here on two small subjects; the full 12-subject demo is timed in the benchmark)."""

from __future__ import annotations

import pandas as pd
import pytest

from cardionurbs.analysis.function import COLUMNS
from cardionurbs.cli import main
from cardionurbs.cohort import CSV_COLUMNS

from cardionurbs.phantom import presets


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    small = [presets.SubjectSpec("nrm01", "normal", 101, frames=2),
             presets.SubjectSpec("phtn01", "phtn", 301, frames=2)]
    mp = pytest.MonkeyPatch()
    mp.setattr(presets, "load_cohort_spec", lambda path: small)
    out = tmp_path_factory.mktemp("demo")
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["demo", "--out", str(out)])
    mp.undo()
    return code, out, buf.getvalue()


def test_demo_exits_zero_and_writes_csvs(demo_run):
    code, out, _ = demo_run
    assert code == 0
    measured = pd.read_csv(out / "cohort.csv")
    truth = pd.read_csv(out / "truth.csv")
    assert list(measured.columns) == list(CSV_COLUMNS)
    assert list(measured["subject"]) == ["nrm01", "phtn01"] and (measured["status"] == "ok").all()
    assert list(truth.columns[2:]) == list(COLUMNS)
    assert (out / "nrm01" / "study.json").exists() and (out / "nrm01" / "truth.json").exists()


def test_demo_metrics_match_truth(demo_run):
    _, out, _ = demo_run
    m = pd.read_csv(out / "cohort.csv").set_index("subject")
    t = pd.read_csv(out / "truth.csv").set_index("subject")
    for c in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "RVESV (mL)"):
        assert ((m[c] / t[c] - 1).abs() < 0.01).all(), c


def test_demo_prints_one_summary_table_and_existing_paths(demo_run):
    _, out, text = demo_run
    comp = pd.read_csv(out / "comparison.csv")              # every metric is in the CSV
    assert set(comp["metric"]) >= {"LVEDV (mL)", "LVEF (%)", "RVM (g)", "MR RegFrac (%)", "EI ES"}
    lines = text.strip().splitlines()
    assert len(lines) <= 40
    head = next(i for i, l in enumerate(lines) if l.startswith("subject"))
    for name in ("pathology", "LVEDV", "LVEF", "RVEF", "LVM", "twist"):
        assert name in lines[head], name
    rows = {l.split()[0]: l.split() for l in lines[head + 1:head + 3]}
    assert set(rows) == {"nrm01", "phtn01"} and rows["nrm01"][1] == "normal"
    t = pd.read_csv(out / "truth.csv").set_index("subject")
    m = pd.read_csv(out / "cohort.csv").set_index("subject")
    measured, truth = rows["nrm01"][2].split("/")          # LVEDV measured/truth, rounded
    assert float(measured) == round(m.loc["nrm01", "LVEDV (mL)"])
    assert float(truth) == round(t.loc["nrm01", "LVEDV (mL)"])
    assert "mean |error|" in text and f"wrote {out}" in lines[-1]


def test_demo_draws_the_cohort_figures(demo_run):
    _, out, text = demo_run
    for name in ("cohort_distributions", "cohort_measured_vs_truth", "cohort_bland_altman"):
        png = out / "figures" / f"{name}.png"
        assert png.is_file() and png.stat().st_size > 10_000, name
    assert "cohort figures" in text


def test_demo_without_out_names_no_removed_path(tmp_path):
    from cardionurbs import demo
    text = demo.format_comparison(pd.DataFrame(columns=["metric", "error", "error_unit"]),
                                  pd.DataFrame([{"subject": "x", "status": "error: boom"}]),
                                  pd.DataFrame([{"subject": "x", "pathology": "normal"}]))
    assert "x" in text and "error: boom" in text
