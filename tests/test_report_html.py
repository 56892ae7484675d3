"""The self-contained HTML report: content, CLI, and a headless-Chromium run (no console
errors, no network requests, a screenshot that shows the model, working controls)."""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from cardionurbs import nurbs
from cardionurbs.cli import main
from cardionurbs.report import html as H
from cardionurbs.report.chromium import find_chromium, open_page

READY = "document.getElementById('cn-status').getAttribute('data-ok') === '1'"


@pytest.fixture(scope="module")
def analysis(tmp_path_factory):
    """A 3-frame tagged phantom written to disk (truth.json beside it) and analysed by
    ``cardionurbs analyze`` (figures and report.html through the pipeline hook)."""
    from cardionurbs.phantom import generate
    from cardionurbs.phantom.generate import write_phantom
    root = tmp_path_factory.mktemp("report")
    ph = generate("phtn", seed=4, frames=3, tag_jumps=1, volume_check=False)
    write_phantom(ph, root / "study", dicom=False)
    assert main(["analyze", str(root / "study"), "--out", str(root / "out")]) == 0
    return root / "out", ph


def test_analyze_writes_figures_and_report(analysis):
    out, ph = analysis
    assert (out / "report.html").is_file()
    assert sorted(p.name for p in (out / "figures").glob("fig*.png"))
    idx = json.loads((out / "figures" / "figures.json").read_text())
    assert idx["subject"] == ph.study.subject and idx["figures"]


def test_payload_round_trips_the_surfaces(analysis):
    """Decoded viewer coordinates match the NURBS tessellation within the 0.1 mm quantum."""
    from cardionurbs.anatomy.model import BiventricularModel
    out, _ = analysis
    p = H.report_payload(out)
    model = BiventricularModel.from_dict(json.loads((out / "model.json").read_text()))
    g = next(g for g in p["groups"] if g["key"] == "lv_endo")
    f = model.es_frame
    q = np.frombuffer(base64.b64decode(g["frames"][str(f)]["v"]), "<i2").reshape(-1, 3)
    xyz = np.asarray(p["origin"]) + q * p["quantum_mm"]
    v, faces = nurbs.tessellate(model.surfaces[f]["lv_endo"], *H.SURFACE_GRID)
    assert np.abs(xyz - v).max() <= 0.05 + 1e-9
    tag = p["faces"][g["frames"][str(f)]["f"]]
    fc = np.frombuffer(base64.b64decode(tag[3:]), "<u2" if tag.startswith("u2") else "<u4")
    assert np.array_equal(fc.reshape(-1, 3), faces)
    keys = {g["key"] for g in p["groups"]}
    assert {"lv_endo", "lv_epi", "rv_endo", "rv_epi"} <= keys and any(k.startswith("tags_") for k in keys)
    assert p["has_truth"] and p["truth_file"].endswith("truth.json")
    row = next(r for r in p["metrics"] if r["metric"] == "LVEDV (mL)")
    assert row["truth"] is not None and abs(row["difference"]) < 0.05 * row["truth"]


def test_report_size_for_twenty_frames(analysis):
    """Size grows linearly with frames (fixed tessellation grids); extrapolated from this
    3-frame report to 20 frames it stays under 10 MB (benchmarks/bench_report.py measures
    a real 20-frame study)."""
    out, _ = analysis
    p = H.report_payload(out)
    per_frame = sum(len(json.dumps(e)) for g in p["groups"] for e in g["frames"].values())
    n = len(p["frames"])
    total = (out / "report.html").stat().st_size
    assert total + per_frame / n * (20 - n) < 10e6


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 40), st.just(3)),
              elements=st.floats(-3000, 3000, allow_nan=False)),
       arrays(np.float64, 3, elements=st.floats(-200, 200, allow_nan=False)))
def test_quantise_round_trip_within_half_a_quantum(v, origin):
    origin = np.round(origin, 1)
    v = np.clip(v, origin - 3270, origin + 3270)
    q = np.frombuffer(base64.b64decode(H.quantise(v, origin)), "<i2").reshape(-1, 3)
    assert np.abs(origin + q * H.QUANTUM_MM - v).max() <= H.QUANTUM_MM / 2 + 1e-9


def test_quantise_refuses_far_coordinates():
    with pytest.raises(H.ReportInputError):
        H.quantise(np.array([[4000.0, 0, 0]]), np.zeros(3))


def test_report_of_an_analysis_without_figures(analysis, tmp_path):
    """analyze --no-figures output: the report still works (no tag surfaces, one line why)."""
    out, _ = analysis
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("model.json", "metrics.json"):
        shutil.copy2(out / name, bare / name)
    p = H.report_payload(bare)
    assert not any(g["key"].startswith("tags_") for g in p["groups"])
    assert "report_tags.json" in p["tags_note"] and p["figures"] == [] and not p["has_truth"]
    assert H.write_report(bare, bare / "r.html").stat().st_size > 1e6


def test_cli_report_and_bad_folder(analysis, tmp_path, capsys):
    out, _ = analysis
    assert main(["report", str(out), "--out", str(tmp_path / "r.html")]) == 0
    assert (tmp_path / "r.html").stat().st_size > 1e6
    assert main(["report", str(tmp_path / "nope"), "--out", str(tmp_path / "x.html")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "metrics.json").write_text("{}")
    assert main(["report", str(tmp_path / "half"), "--out", str(tmp_path / "x.html")]) == 2
    assert "model.json" in capsys.readouterr().err


def test_page_embeds_everything(analysis):
    text = (analysis[0] / "report.html").read_text()
    assert "<script src" not in text and "<link" not in text
    assert "connect-src 'none'" in text                       # CSP: no fetch/XHR/websocket


# --------------------------------------------------------------- chromium
def chromium_or_skip() -> str:
    exe = find_chromium()
    if exe:
        return exe
    if os.environ.get("CI", "").lower() == "true" and hasattr(os, "geteuid") and os.geteuid() == 0:
        import fcntl
        # one installer at a time across pytest-xdist workers (dpkg holds a lock)
        with open("/tmp/cardionurbs-chromium-install.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not find_chromium():
                subprocess.run(["apt-get", "update"], check=False, capture_output=True)
                subprocess.run(["apt-get", "install", "-y", "--no-install-recommends", "chromium"],
                               check=False, capture_output=True)
        exe = find_chromium()
        if exe:
            return exe
        pytest.fail("CI: apt-get install chromium did not provide a chromium executable")
    pytest.skip("chromium is not installed (apt-get install chromium); the test installs it "
                "itself only in CI (CI=true) as root")


CONTROLS_JS = """(async function(){
  const gd = document.getElementById('plot');
  const r = {n: gd.data.length, names: gd.data.map(t => t.name)};
  const x0 = gd.data[0].x[0];
  const box = document.getElementById('toggle-lv_endo'); box.click();
  r.hidden = gd.data[0].visible;
  const s = document.getElementById('slider'); s.value = s.max; s.dispatchEvent(new Event('input'));
  r.label = document.getElementById('frameLabel').textContent;
  r.moved = gd.data[0].x[0] !== x0;
  r.metricsRows = document.querySelectorAll('#metrics tr').length;
  r.truthHeader = document.querySelector('#metrics tr').textContent;
  return r; })()"""


def test_report_in_headless_chromium(analysis, tmp_path):
    exe = chromium_or_skip()
    out, ph = analysis
    run = open_page(out / "report.html", chromium=exe, ready_js=READY, value_js=CONTROLS_JS,
                    timeout=90)
    assert run.ready, f"page did not finish rendering; console: {run.console[-5:]}"
    assert run.errors == []
    assert run.requests == []
    v = run.value
    assert v["n"] >= 5 and "LV endocardium" in v["names"]
    assert v["hidden"] is False                                 # the toggle hid the trace
    assert v["label"].startswith(f"frame {max(ph.study.frames)}") and v["moved"]
    assert v["metricsRows"] > 20 and "truth" in v["truthHeader"]
    # the screenshot shows the model: LV and RV colours in the 3D view
    img = np.asarray(Image.open(io.BytesIO(run.screenshot)).convert("RGB")).astype(float) / 255
    assert img.shape[0] >= 900
    Image.fromarray((img * 255).astype(np.uint8)).save(tmp_path / "shot.png")

    def hue_pixels(hex_colour: str) -> int:
        c = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255
        k = (img @ c) / (c @ c)
        resid = np.linalg.norm(img - k[..., None] * c, axis=-1)
        return int(((k > 0.3) & (k < 1.2) & (resid < 0.12)).sum())

    assert hue_pixels(H.STRUCTURE_COLOURS["rv_endo"]) > 2000
    assert hue_pixels(H.STRUCTURE_COLOURS["lv_endo"]) + hue_pixels(H.STRUCTURE_COLOURS["lv_epi"]) > 500


def test_chromium_check_catches_network_and_errors(tmp_path):
    """The browser check can fail: a page fetching a remote image and throwing."""
    exe = chromium_or_skip()
    page = tmp_path / "bad.html"
    page.write_text("<!DOCTYPE html><html><body><img src='http://example.invalid/x.png'>"
                    "<script>console.error('boom'); undefinedFunction();</script></body></html>")
    run = open_page(page, chromium=exe, timeout=60, settle=0.5)
    assert any("example.invalid" in u for u in run.requests)
    assert any("boom" in e for e in run.errors) and any("undefinedFunction" in e for e in run.errors)


def test_report_groups_metrics_shows_ranges_and_collapses_qc_evidence():
    """Grouped tables (LV, RV, indexed with ranges, tags; regional collapsed), the null
    reason beside a null value, one expandable quality line per surface."""
    rows = [{"metric": m, "measured": v, "truth": None, "difference": None, "qc": qc,
             "qc_surfaces": sorted({H._flag_surface(f) for f in qc.split("; ") if f}),
             "note": note, "range": rng, "range_flag": flag, "range_table": "Table 3" if rng else None,
             "range_reason": None}
            for m, v, qc, note, rng, flag in (
                ("LVEDV (mL)", 150.0, "LV endo fit max 6.1 mm (4.3 px) > 3 px at frame 24", None, None, None),
                ("LVEF (%)", 40.0, "LV endo fit max 6.1 mm (4.3 px) > 3 px at frame 24; "
                                   "LV endo fit max 8.3 mm (5.9 px) > 3 px at frame 10", None, [46, 74], "below"),
                ("RVM (g)", None, "", "no RV contours", None, None),
                ("LVEDVi (mL/m²)", 80.0, "", None, [61, 112], "normal"),
                ("Twist (deg)", 12.0, "", None, None, None),
                ("WT_AHA_1 (mm)", 8.0, "", None, None, None))]
    groups = dict(H.group_rows(rows))
    assert list(groups) == ["LV function", "RV function", "Body size and indexed values", "Tags",
                            "Regional"]
    q = H.quality_lines(rows)
    assert len(q) == 1 and q[0]["surface"] == "LV endo" and len(q[0]["evidence"]) == 2
    assert q[0]["metrics"] == ["LVEDV (mL)", "LVEF (%)"]
    payload = {"has_truth": False, "metrics": rows}
    head, tables = H._metric_tables(payload)
    assert "normal range" in head and "<th colspan='5'>LV function</th>" in tables["main"]
    assert "46–74" in tables["main"] and ">below<" in tables["main"]
    assert "no RV contours" in tables["main"] and "WT_AHA_1" not in tables["main"]
    assert tables["regional"].startswith("<details id='regional'>")
    html_q = H._quality_html(rows)
    assert html_q.count("<details class='qcline'>") == 1 and "frame 10" in html_q
