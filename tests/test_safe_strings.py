"""Safe strings (issue 10): a subject named like HTML, a formula or mathtext still gives every
figure, an HTML report whose JSON data block is intact, CSV cells that spreadsheets show as
text, and no absolute local path in the report."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest

from cardionurbs.cli import main
from cardionurbs.cohort import write_csv
from cardionurbs.safe import csv_cell, json_for_script, plain_text

NASTY = "=1+1<!--<script>a$\\undefinedmacro$b</script>"


@pytest.fixture(scope="module")
def nasty_analysis(tmp_path_factory):
    from cardionurbs.phantom import generate
    from cardionurbs.phantom.generate import write_phantom
    root = tmp_path_factory.mktemp("nasty")
    ph = generate("normal", seed=3, frames=2, volume_check=False)
    write_phantom(ph, root / "study", dicom=False)
    m = json.loads((root / "study" / "study.json").read_text())
    m["subject"] = NASTY
    (root / "study" / "study.json").write_text(json.dumps(m))
    assert main(["analyze", str(root / "study"), "--out", str(root / "out")]) == 0
    return root / "out"


def test_mathtext_in_a_name_does_not_drop_figures(nasty_analysis):
    idx = json.loads((nasty_analysis / "figures" / "figures.json").read_text())
    names = {f["name"] for f in idx["figures"]}
    assert {"fig10_biventricular", "fig11_volume_time"} <= {n.split(".")[0] for n in names} or \
        len(names) >= 5, names
    skipped = " ".join(idx.get("skipped", {}).values())
    assert "mathtext" not in skipped.lower() and "parse" not in skipped.lower(), skipped


def test_html_data_block_survives_comment_and_script_in_the_subject(nasty_analysis):
    page = (nasty_analysis / "report.html").read_text()
    start = page.index('<script type="application/json" id="cn-data">') + len(
        '<script type="application/json" id="cn-data">')
    block = page[start:page.index("</script>", start)]
    assert "<!--" not in block and "<" not in block
    assert json.loads(block)["subject"] == NASTY
    for script in re.findall(r"<script[^>]*>(.*?)</script>", page, flags=re.S):
        assert "<!--" not in script


def test_report_shows_no_absolute_local_path(nasty_analysis):
    page = (nasty_analysis / "report.html").read_text()
    root = str(nasty_analysis.parent)
    assert root not in page
    assert "/tmp/" not in page


def test_cohort_csv_cells_never_start_a_formula(tmp_path):
    table = pd.DataFrame({"subject": ["=1+1", "=HYPERLINK(\"http://x\")", "+a", "-b", "@c",
                                      "\tt", "\rr", "ok"],
                          "status": ["ok"] * 8, "LVEDV (mL)": [-1.0] * 8})
    write_csv(table, tmp_path / "c.csv")
    back = pd.read_csv(tmp_path / "c.csv", keep_default_na=False)
    for cell in back["subject"]:
        assert cell[:1] not in ("=", "+", "-", "@", "\t", "\r"), cell
    assert back["subject"].iloc[0] == "'=1+1"
    assert float(back["LVEDV (mL)"].iloc[0]) == -1.0     # numbers are not quoted


def test_quoting_helpers():
    assert csv_cell("=x") == "'=x" and csv_cell(-3.0) == -3.0 and csv_cell("x=1") == "x=1"
    assert plain_text("a$b$") == r"a\$b\$"
    s = json_for_script({"k": "</script><!--&\u2028"})
    assert "<" not in s and ">" not in s and "&" not in s and "\u2028" not in s
    assert json.loads(s) == {"k": "</script><!--&\u2028"}


def test_viewer_has_one_legend(nasty_analysis):
    """The structure toggles carry the colour swatches; the 3-D plot adds no second legend."""
    page = (nasty_analysis / "report.html").read_text()
    js = page[page.rindex("<script>"):]
    layout = js[js.index("const layout"):js.index("const gd")]
    assert "showlegend:false" in layout and "showlegend:true" not in layout
