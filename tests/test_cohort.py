"""`cohort`: one row per study, failures recorded in their row, --jobs, the CLI and CSV."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

from cardionurbs.analysis.function import COLUMNS
from cardionurbs.cli import main
from cardionurbs.analysis.quality import QC_COLUMNS
from cardionurbs.analysis.uncertainty import INTERVAL_COLUMNS
from cardionurbs.cohort import CSV_COLUMNS, cohort
from cardionurbs.io.native import write_study

from test_model_fixtures import heart, study_from_hearts


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    root = tmp_path_factory.mktemp("cohort")
    good = []
    for i, s in enumerate((1.0, 0.95)):
        st = study_from_hearts([heart(s), heart(0.8 * s)], subject=f"ell{i}")
        good.append(write_study(st, root / f"ell{i}"))
    broken = root / "broken"
    broken.mkdir()
    (broken / "study.json").write_text(json.dumps({"format": "cardionurbs-native", "version": 1,
                                                   "subject": "broken", "images": []}))
    (broken / "points.csv").write_text("kind,name,index,view,slice,frame,image,closed,x,y,z,px,py\n")
    missing = root / "does-not-exist"
    return [str(good[0]), str(missing), str(broken), str(good[1])]


@pytest.fixture(scope="module")
def table(studies):
    return cohort(studies, jobs=1)


def test_rows_in_input_order_with_metrics_columns(table):
    assert list(table.columns) == (list(CSV_COLUMNS[:-2]) + list(INTERVAL_COLUMNS)
                                   + list(CSV_COLUMNS[-2:]))
    assert list(table.columns[2:2 + len(COLUMNS)]) == list(COLUMNS)
    qc_end = 2 + len(COLUMNS) + len(QC_COLUMNS)
    assert list(table.columns[2 + len(COLUMNS):qc_end]) == list(QC_COLUMNS)
    assert list(table.columns[-2:]) == ["warnings", "notes"]
    assert list(table["subject"]) == ["ell0", "does-not-exist", "broken", "ell1"]
    assert list(table["status"] == "ok") == [True, False, False, True]


def test_failed_rows_have_one_line_reason_and_empty_numbers(table):
    for i in (1, 2):
        st = table.loc[i, "status"]
        assert st.startswith("error: ") and "\n" not in st and len(st) > 10
        assert all(math.isnan(table.loc[i, c]) for c in COLUMNS)
    assert "does-not-exist" in table.loc[1, "status"]


def test_good_rows_are_measured(table):
    for i in (0, 3):
        assert 50 < table.loc[i, "LVEDV (mL)"] < 120
        assert 0 < table.loc[i, "LVEF (%)"] < 100
        assert table.loc[i, "RVEDV (mL)"] > 0
        assert table.loc[i, "HR (bpm)"] == 60.0
    assert table.loc[3, "LVEDV (mL)"] < table.loc[0, "LVEDV (mL)"]


def test_jobs_two_gives_the_same_table(studies, table):
    t2 = cohort(studies, jobs=2)
    pd.testing.assert_frame_equal(t2, table)


def test_cli_writes_csv_and_reports_failures(studies, tmp_path, capsys):
    out = tmp_path / "sub" / "cohort.csv"
    assert main(["cohort", *studies, "--csv", str(out), "--jobs", "1"]) == 3   # some failed
    err = capsys.readouterr().err
    assert "2 of 4 studies measured, 2 failed" in err and "does-not-exist" in err
    assert main(["cohort", *studies, "--csv", str(out), "--allow-failures"]) == 0
    df = pd.read_csv(out)
    assert list(df.columns) == (list(CSV_COLUMNS[:-2]) + list(INTERVAL_COLUMNS)
                                + list(CSV_COLUMNS[-2:]))
    assert df["status"].tolist()[0] == "ok" and df["status"].tolist()[1].startswith("error: ")
    assert not list(out.parent.glob(".*tmp"))        # atomic write left no temporary file
