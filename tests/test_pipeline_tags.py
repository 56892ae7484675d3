"""`analyze` on a tagged study: one tag analysis serves the metrics, metrics.json (level
table, QC flags, twist and LS over time), model.json (tag surfaces) and the figures."""

from __future__ import annotations

import json

import pytest

import cardionurbs.analysis.tags as tags_module
from cardionurbs import nurbs
from cardionurbs.phantom import generate
from cardionurbs.pipeline import analyse, write_analysis


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    ph = generate("normal", seed=4, frames=3, tag_jumps=1, volume_check=False)
    # each call's keywords to a file: the tag metrics may run on a worker process
    log = tmp_path_factory.mktemp("calls") / "tag_metrics.jsonl"
    real = tags_module.tag_metrics

    def logged(*a, **k):
        with open(log, "a") as fh:
            fh.write(json.dumps({key: v for key, v in k.items() if key == "over_time"}) + "\n")
        return real(*a, **k)
    mp = pytest.MonkeyPatch()
    mp.setattr(tags_module, "tag_metrics", logged)
    model, metrics, tags = analyse(ph.study)
    out = write_analysis(model, metrics, tmp_path_factory.mktemp("a") / "out", tags=tags)
    mp.undo()
    calls = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    return ph, out, calls


def test_tag_analysis_runs_once_for_metrics_outputs_and_figures(analysed):
    _, out, calls = analysed
    assert len(calls) == 1 and calls[0].get("over_time") is True
    assert (out / "figures" / "fig12_twist_time.png").is_file()


def test_metrics_json_carries_levels_flags_and_time_course(analysed):
    ph, out, _ = analysed
    d = json.loads((out / "metrics.json").read_text())
    t = d["tags"]
    assert d["metrics"]["Twist (deg)"] == pytest.approx(ph.truth["metrics"]["Twist (deg)"], abs=0.5)
    assert len(t["levels"]) >= 2 and all("rotation_deg" in lv for lv in t["levels"])
    assert len(t["flags"]) == d["metrics"]["Tag QC flags"] == 1
    assert sorted(int(f) for f in t["over_time"]) == [0, 1, 2]


def test_model_json_saves_the_tag_surfaces(analysed):
    ph, out, _ = analysed
    from cardionurbs.io.modelfile import read_model_file
    ts = read_model_file(out / "model.json")["tag_surfaces"]
    assert sorted(int(f) for f in ts["frames"]) == ph.study.tagged_frames
    fams = {k.split(":")[0] for k in ts["frames"]["0"]}
    assert fams == {"sa1", "sa2", "la"}
    s = nurbs.NurbsSurface.from_dict(next(iter(ts["frames"]["0"].values())))
    assert s.evaluate([0.5], [0.5]).shape == (1, 1, 3)


def test_study_without_tags_writes_null_tags(tmp_path):
    ph = generate("normal", seed=5, frames=2, volume_check=False)
    ph.study.tags.clear()
    model, metrics, tags = analyse(ph.study)
    out = write_analysis(model, metrics, tmp_path / "o", figures=False, tags=tags)
    assert json.loads((out / "metrics.json").read_text())["tags"] is None
    assert "tag_surfaces" not in json.loads((out / "model.json").read_text())


def test_report_from_memory_is_the_report_read_back(analysed, tmp_path):
    """analyze builds report.html from the model and tag surfaces in memory; `cardionurbs
    report` on the folder reads model.json and report_tags.json back: the same page."""
    from cardionurbs.report.html import write_report
    _, out, _ = analysed
    again = write_report(out, tmp_path / "again.html")
    assert again.read_bytes() == (out / "report.html").read_bytes()
