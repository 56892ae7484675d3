"""What a clinician reads (issue 32): every warning reaches metrics.json, the CSV and stderr;
a metric the study cannot give is null with its reason, never 0; body size (BSA, indexed
columns) from Info.cfg, DICOM headers, the manifest or the command line; reference-range
flags."""

from __future__ import annotations

import json
import math
import re

import pandas as pd
import pydicom
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import cardionurbs as cn
from cardionurbs.analysis.body import INDEXED, bsa_mosteller
from cardionurbs.analysis.notes import Metrics, collect_warnings, notes_text, null
from cardionurbs.analysis.ranges import (check_table, find_range, flag, limits, load_ranges,
                                         range_flags)
from cardionurbs.cli import main
from cardionurbs.analysis.uncertainty import INTERVAL_COLUMNS
from cardionurbs.cohort import CSV_COLUMNS, RANGE_COLUMNS, measure_study
from cardionurbs.io.body import attach_body, clean_value
from cardionurbs.io.native import write_study

from conftest import shared_data
from test_model_fixtures import heart, study_from_hearts


@pytest.fixture(scope="module")
def one_frame(tmp_path_factory):
    """A native study with contours at one frame only."""
    st = study_from_hearts([heart(1.0)], subject="oneframe", la=False)
    return write_study(st, tmp_path_factory.mktemp("one") / "oneframe")


@pytest.fixture(scope="module")
def no_heart_rate(tmp_path_factory):
    """A two-frame native study without a heart rate: a known load warning."""
    st = study_from_hearts([heart(1.0), heart(0.8)], subject="nohr", la=False)
    st.heart_rate_bpm = None
    return write_study(st, tmp_path_factory.mktemp("nohr") / "nohr")


# ------------------------------------------------------------------ null with a reason
def test_null_records_the_first_reason():
    m = Metrics({"LVEF (%)": 55.0})
    null(m, "LVEF (%)", "one frame only")
    null(m, "LVEF (%)", "a later reason")
    assert math.isnan(m["LVEF (%)"]) and m.notes == {"LVEF (%)": "one frame only"}
    text = notes_text(m.notes, [{"source": "load", "message": "no heart rate"}])
    assert text == "LVEF (%): one frame only; load: no heart rate"


def test_notes_cell_groups_reasons_and_says_what_is_left_out():
    notes = {f"C{i}": "same" for i in range(5)} | {"LVEF (%)": "same", "X": "other"}
    text = notes_text(notes, [{"source": "measure", "message": f"w{i}"} for i in range(4)])
    assert text.startswith("LVEF (%): same (also C0 and 4 more); X: other; measure: w0; measure: w1")
    assert text.endswith("(+2 more)")


def test_one_frame_gives_null_ef_with_its_reason_in_api_json_and_csv(one_frame, tmp_path):
    model = cn.reconstruct(cn.load_study(one_frame))
    m = cn.measure(model)
    assert model.ed_frame == model.es_frame
    assert m["LVEDV (mL)"] > 50                                 # the one frame is measured
    for col in ("LVEF (%)", "RVEF (%)", "LVSV (mL)", "LVESV (mL)", "LVCO (L/min)",
                "MR RegVol (mL)", "GCS surface (%)"):
        assert math.isnan(m[col]), col                          # not 0
        assert "one frame only" in m.notes[col], col
    out = tmp_path / "out"
    assert main(["analyze", str(one_frame), "--out", str(out), "--outputs", "metrics",
                 "--age", "55", "--sex", "M"]) == 0
    d = json.loads((out / "metrics.json").read_text())
    assert d["metrics"]["LVEF (%)"] is None and "one frame only" in d["notes"]["LVEF (%)"]
    ranges = d["ranges"]                        # null metric: no flag, the metric's reason
    assert ranges["citation"].startswith("Petersen SE") and ranges["url"].startswith("https://")
    assert ranges["flags"]["LVEF (%)"]["flag"] is None
    assert ranges["flags"]["LVEF (%)"]["reason"].startswith("metric is null: one frame only")
    assert "body size unknown" in ranges["flags"]["LVMi (g/m²)"]["reason"]
    assert ranges["flags"]["RVEDVi (mL/m²)"]["reason"] == "not in the reference source"
    assert d["metrics"]["GCS surface (%)"] is None
    assert any(w["source"] == "reconstruct" and "only one frame" in w["message"]
               for w in d["warnings"])
    row = measure_study(str(one_frame))
    assert row["status"] == "ok" and math.isnan(row["LVEF (%)"])
    assert "LVEF (%): one frame only" in row["notes"] and row["warnings"] >= 1


def test_load_warning_in_metrics_json_csv_and_stderr(no_heart_rate, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["analyze", str(no_heart_rate), "--out", str(out), "--outputs", "metrics"]) == 0
    err = capsys.readouterr().err
    d = json.loads((out / "metrics.json").read_text())
    load = [w for w in d["warnings"] if w["source"] == "load"]
    assert any("no heart rate" in w["message"] for w in load)
    assert re.search(r"^\d+ warnings? \(load \d+", err, re.M) and "no heart rate" in err
    assert d["metrics"]["LVCO (L/min)"] is None and "heart rate" in d["notes"]["LVCO (L/min)"]
    csv = tmp_path / "c.csv"
    assert main(["cohort", str(no_heart_rate), "--csv", str(csv)]) == 0
    df = pd.read_csv(csv)
    assert list(df.columns) == (list(CSV_COLUMNS[:-2]) + list(INTERVAL_COLUMNS)   # the 95 %
                                + list(CSV_COLUMNS[-2:]))                     # intervals
    assert df.loc[0, "warnings"] == len(d["warnings"])
    assert "no heart rate" in df.loc[0, "notes"]


def test_collect_warnings_names_sources_and_drops_repeats():
    class S:
        warnings = ["a", "a", "b"]
    class M:
        warnings = ["c"]
    w = collect_warnings(S(), M(), Metrics(), measure_notes=["d"])
    assert w == [{"source": "load", "message": "a"}, {"source": "load", "message": "b"},
                 {"source": "reconstruct", "message": "c"}, {"source": "measure", "message": "d"}]


# ------------------------------------------------------------------------- body size
def test_mosteller_bsa_by_hand():
    assert bsa_mosteller(180.0, 80.0) == pytest.approx(2.0)            # sqrt(14400/3600)
    assert bsa_mosteller(165.0, 77.0) == pytest.approx(math.sqrt(165 * 77 / 3600))


def test_body_values_are_checked():
    assert clean_value("age_y", "045Y") == 45 and clean_value("age_y", "006M") == 0.5
    assert clean_value("sex", "female") == "F" and clean_value("sex", "O") is None
    with pytest.raises(ValueError):
        clean_value("height_cm", 1.7)                   # metres given as centimetres
    with pytest.raises(ValueError):
        clean_value("weight_kg", "heavy")


def _info_cfg(path):
    return {k.strip(): v.strip() for k, v in
            (line.split(":", 1) for line in path.read_text().splitlines() if ":" in line)}


def test_acdc_patient_gets_bsa_and_indexed_values_from_info_cfg():
    folder = shared_data("acdc", "patient005")
    info = _info_cfg(folder / "Info.cfg")
    h, w = float(info["Height"]), float(info["Weight"])
    study = cn.load_study(folder)
    assert study.meta["body"]["height_cm"] == h and study.meta["body"]["source"]["height_cm"] == "Info.cfg"
    m = cn.measure(cn.reconstruct(study))
    bsa = math.sqrt(h * w / 3600.0)
    assert m["BSA (m²)"] == pytest.approx(bsa)
    for col, src in INDEXED.items():
        if math.isfinite(m[src]):
            assert m[col] == pytest.approx(m[src] / bsa), col
        else:
            assert math.isnan(m[col]) and col in m.notes, col
    body = study.meta["body"]                   # Info.cfg gives no age or sex: no flag, why
    assert body["age_y"] is None and body["sex"] is None
    f = range_flags(m, body["sex"], body["age_y"])
    assert f["LVEF (%)"] == {"flag": None, "lower": None, "upper": None, "where": None,
                             "bound": None, "reason": "age and sex unknown"}
    body = attach_body(study, {"age_y": 55, "sex": "M"})      # analyze --age 55 --sex M
    f = range_flags(m, body["sex"], body["age_y"])
    assert info["Group"] == "DCM" and m["LVEF (%)"] < 48.2
    assert f["LVEF (%)"]["flag"] == "below" and f["LVEF (%)"]["lower"] == pytest.approx(48.2)
    assert f["LVMi (g/m²)"]["flag"] in ("normal", "above") and m["LVMi (g/m²)"] > 35.36


def test_dicom_header_gives_the_same_body_size(tmp_path):
    root = tmp_path / "ph"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--out", str(root)]) == 0
    for f in sorted((root / "dicom").rglob("*.dcm")):
        ds = pydicom.dcmread(f)
        ds.PatientSize, ds.PatientWeight, ds.PatientAge, ds.PatientSex = 1.65, 77, "045Y", "F"
        ds.save_as(f)
    study = cn.load_study(root)
    body = study.meta["body"]
    assert body["height_cm"] == pytest.approx(165.0) and body["weight_kg"] == 77.0
    assert body["age_y"] == 45.0 and body["sex"] == "F"
    assert body["source"]["height_cm"].startswith("DICOM header")
    attach_body(study, {"height_cm": 180.0, "weight_kg": None})   # the command line wins
    assert study.meta["body"]["height_cm"] == 180.0 and study.meta["body"]["weight_kg"] == 77.0


def test_unknown_body_size_gives_null_indexed_columns_with_reason(one_frame):
    m = cn.measure(cn.reconstruct(cn.load_study(one_frame)))
    for col in ("BSA (m²)",) + tuple(INDEXED):
        assert math.isnan(m[col]) and m.notes[col], col
    assert "--height-cm" in m.notes["BSA (m²)"]


def test_cli_refuses_implausible_body_size(one_frame, tmp_path, capsys):
    code = main(["analyze", str(one_frame), "--out", str(tmp_path / "o"), "--height-cm", "1.8"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--height-cm" in err
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------- reference ranges
TABLE = {"citation": "test", "sd_multiplier": 2.0,
         "columns": ["LVEF (%)", "LVEDVi (mL/m²)", "RVEF (%)"], "rows": [
    {"column": "LVEF (%)", "sex": "M", "age_min": 20, "age_max": 39, "lower": 55, "upper": 73,
     "where": "T1"},
    {"column": "LVEF (%)", "sex": "M", "age_min": 40, "age_max": None, "mean": 64, "sd": 5.5,
     "where": "T1"},
    {"column": "LVEDVi (mL/m²)", "sex": None, "age_min": None, "age_max": None, "lower": 60,
     "upper": 100, "where": "T2"}]}


def test_range_flags_by_hand():
    assert flag(54.9, 55, 73) == "below" and flag(55, 55, 73) == "normal"
    assert flag(73.1, 55, 73) == "above"
    row, _ = find_range("LVEF (%)", "M", 39.5, TABLE)        # 39.5 y is still the 20-39 band
    assert row["lower"] == 55
    row, _ = find_range("LVEF (%)", "M", 40.0, TABLE)
    assert limits(row, TABLE)[:2] == (53.0, 75.0)             # 64 -+ 2 x 5.5
    assert find_range("LVEF (%)", None, 30, TABLE) == (None, "sex unknown")
    assert find_range("LVEF (%)", "F", 30, TABLE) == (None, "no row for sex F")
    assert find_range("LVEF (%)", "M", 19, TABLE) == (None, (     # the reasons of both rows
        "age 19 y is outside the source's ages (20–39 y) and "
        "age 19 y is outside the source's ages (40– y)"))
    f = range_flags({"LVEF (%)": 54.0, "LVEDVi (mL/m²)": float("nan")}, "M", 45, TABLE)
    assert f["LVEF (%)"]["flag"] == "normal" and f["LVEF (%)"]["where"] == "T1"
    assert f["LVEF (%)"]["bound"].startswith("within 53.0–75.0 (mean 64")
    assert f["LVEDVi (mL/m²)"]["flag"] is None and f["LVEDVi (mL/m²)"]["reason"] == "metric is null"
    assert range_flags({"LVEF (%)": None}, None, None, TABLE)["LVEF (%)"]["reason"] == \
        "metric is null"                        # the metric's own reason before the demographics'
    assert f["RVEF (%)"] == {"flag": None, "lower": None, "upper": None, "where": None,
                             "bound": None, "reason": "not in the reference source"}
    low = range_flags({"LVEF (%)": 54.0}, "M", 30, TABLE)["LVEF (%)"]
    assert low["flag"] == "below" and low["bound"] == "under the lower limit 55.0 (as published)"
    m = Metrics({"LVEF (%)": 60.0})
    null(m, "LVEF (%)", "one frame only")
    assert range_flags(m, "M", 30, TABLE)["LVEF (%)"]["reason"] == "metric is null: one frame only"


@settings(max_examples=60, deadline=None)
@given(mean=st.floats(1.0, 200.0), sd=st.floats(0.1, 50.0), value=st.floats(-100.0, 400.0))
def test_flag_is_the_z_score_against_the_multiplier(mean, sd, value):
    """A row of mean and SD: below iff z < -k, above iff z > k (k = sd_multiplier)."""
    z = (value - mean) / sd
    assume(abs(abs(z) - 1.96) > 1e-6)
    table = check_table({"sd_multiplier": 1.96, "columns": ["X"],
                         "rows": [{"column": "X", "sex": None, "mean": mean, "sd": sd}]})
    e = range_flags({"X": value}, None, None, table)["X"]
    assert e["flag"] == ("below" if z < -1.96 else "above" if z > 1.96 else "normal")
    assert e["lower"] == pytest.approx(mean - 1.96 * sd) and e["reason"] == ""


def test_malformed_range_rows_are_refused():
    bad = {"sd_multiplier": 1.96, "columns": ["LVEF (%)"],
           "rows": [{"column": "LVEF (%)", "sex": "X", "mean": 60, "sd": 5}]}
    with pytest.raises(ValueError, match="row 0"):
        check_table(bad)
    bad["rows"][0]["sex"] = "M"
    bad["rows"][0]["sd"] = 0
    with pytest.raises(ValueError, match="malformed"):
        check_table(bad)


def test_packaged_ranges_cite_one_source_and_say_what_was_checked():
    data = load_ranges()
    assert "Petersen SE" in data["citation"] and "2017;19:18" in data["citation"]
    assert "10.1186/s12968-017-0327-9" in data["citation"] and data["url"].endswith("0327-9")
    assert data["checked_against_paper"] is True and "abstract (Results)" in data["checked"]
    assert data["sd_multiplier"] == 1.96 and "tables" in data["missing"]
    for r in data["rows"]:                      # only what the source's stored text gives
        assert r["where"].startswith("Abstract") and r["sex"] in ("M", "F")
        assert (r["age_min"], r["age_max"]) == (45, 74) and r["sd"] > 0
        assert "lower" not in r and "upper" not in r
    assert {r["column"] for r in data["rows"]} == {"LVEF (%)", "LVMi (g/m²)"}
    assert set(RANGE_COLUMNS) == {f"{c} range" for c in data["columns"]}


def test_packaged_rows_flag_hand_checked_values():
    """Petersen et al. 2017 (UK Biobank), Abstract, Results: LVEF 58 ± 5 % (men), 61 ± 5 %
    (women); LV mass 53 ± 9 g/m² (men), 42 ± 7 g/m² (women); ages 45-74; limits mean ±
    1.96 SD worked out here by hand: LVEF men 48.2-67.8, women 51.2-70.8; LVMi men
    35.36-70.64, women 28.28-55.72."""
    def f(col, value, sex, age=60.0):
        return range_flags({col: value}, sex, age)[col]
    assert f("LVEF (%)", 48.1, "M")["flag"] == "below" and f("LVEF (%)", 48.3, "M")["flag"] == "normal"
    assert f("LVEF (%)", 67.9, "M")["flag"] == "above"
    assert f("LVEF (%)", 51.0, "F")["flag"] == "below"       # normal for a man, low for a woman
    assert f("LVEF (%)", 70.7, "F")["flag"] == "normal"
    e = f("LVMi (g/m²)", 71.0, "M")
    assert e["flag"] == "above" and e["upper"] == pytest.approx(70.64)
    assert e["bound"] == "over the upper limit 70.6 (mean 53 ∓ 1.96 × SD 9)"
    assert e["where"].startswith("Abstract")
    assert f("LVMi (g/m²)", 56.0, "F")["flag"] == "above" and f("LVMi (g/m²)", 56.0, "M")["flag"] == "normal"
    assert f("LVMi (g/m²)", 28.0, "F")["flag"] == "below"
    assert f("LVEF (%)", 60.0, "M", 74.9)["flag"] == "normal"  # still the 45-74 cohort
    out = f("LVEF (%)", 60.0, "M", 25.0)
    assert out["flag"] is None and "outside the source's ages (45–74 y)" in out["reason"]
    assert f("LVEF (%)", 60.0, "M", 75.0)["flag"] is None
    assert f("LVEF (%)", 60.0, None)["reason"] == "sex unknown"
    assert f("LVEF (%)", 60.0, "M", None)["reason"] == "age unknown"
    assert f("RVEF (%)", 30.0, "M")["reason"] == "not in the reference source"   # not "normal"


@pytest.mark.parametrize("pathology, expect", [
    ("normal", {"LVEF (%)": "normal", "LVMi (g/m²)": "normal"}),
    ("mr", {"LVMi (g/m²)": "above"}),                        # volume overload: eccentric LVH
    ("phtn", {"LVEF (%)": "normal", "LVMi (g/m²)": "normal", "RVEF (%)": None}),
])
def test_phantom_presets_against_the_reference_ranges(pathology, expect):
    """The presets' analytic truth, for a man of 55 with BSA 1.9 m², read against the same
    ranges: the normal heart is normal, each pathology is flagged where it is designed to be
    and where the source has a range (pulmonary hypertension's low RVEF has none: null, with
    the reason, never "normal")."""
    from cardionurbs.analysis.body import add_body_columns
    from cardionurbs.phantom.generate import generate
    truth = dict(generate(pathology, seed=0, frames=2).truth["metrics"])
    h = 180.0
    add_body_columns(truth, {"height_cm": h, "weight_kg": 1.9 ** 2 * 3600 / h})
    assert truth["BSA (m²)"] == pytest.approx(1.9)
    f = range_flags(truth, "M", 55)
    assert {c: f[c]["flag"] for c in expect} == expect
    if pathology == "phtn":
        assert truth["RVEF (%)"] < 40 and f["RVEF (%)"]["reason"] == "not in the reference source"


def test_mnms_csv_row_gives_demographics(tmp_path):
    from cardionurbs.io.body import mnms_values
    folder = tmp_path / "A0S9V9"
    folder.mkdir()
    (tmp_path / "mnms.csv").write_text("External code,VendorName,ED,ES,Age,Sex,Height,Weight\n"
                                       "B1,Siemens,0,9,30,F,160,55\nA0S9V9,GE,0,10,67,M,175.5,80\n")
    v = mnms_values(folder, "A0S9V9")
    assert v == {"age_y": "67", "sex": "M", "height_cm": "175.5", "weight_kg": "80"}
    assert mnms_values(folder, "nobody") == {}


def test_stderr_summary_counts_and_verbose_shows_all():
    import io
    from cardionurbs.pipeline import report_warnings
    ws = [{"source": "load", "message": f"l{i}"} for i in range(4)] + \
         [{"source": "reconstruct", "message": "r0"}]
    out = io.StringIO()
    report_warnings(ws, file=out)
    lines = out.getvalue().splitlines()
    assert lines[0] == "5 warnings (load 4, reconstruct 1; all in metrics.json; --verbose shows all)"
    assert lines[1:] == ["  load: l0", "  load: l1", "  load: l2"]
    out = io.StringIO()
    report_warnings(ws, verbose=True, file=out)
    assert len(out.getvalue().splitlines()) == 6 and "r0" in out.getvalue()
    out = io.StringIO()
    report_warnings([], file=out)
    assert out.getvalue() == ""
