"""GPFile contours take the view of the slice plane their points lie on, not of their
SAX_/LAX_ label (issue #30, item 1): a disagreement is one warning naming file, lines, label
and slice; only points on no slice plane are refused."""

from __future__ import annotations

import importlib
import shutil

import numpy as np
import pandas as pd
import pytest

from cardionurbs import load_study, measure, reconstruct
from cardionurbs.errors import StudyError
from cardionurbs.io import gpfile
from conftest import shared_data

generate = importlib.import_module("cardionurbs.phantom.generate")


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


def _relabel(folder, frame, old, new, slice_id=None):
    """Rename contour type ``old`` to ``new`` in one GPFile (on one slice if given); the
    1-based line numbers of the rows renamed."""
    path = folder / f"GPFile_{frame:03d}.txt"
    lines = path.read_text().splitlines()
    hit = []
    for k, ln in enumerate(lines[1:], start=2):
        tok = ln.split("\t")
        if tok[3] == old and (slice_id is None or int(tok[4]) == slice_id):
            tok[3] = new
            lines[k - 1] = "\t".join(tok)
            hit.append(k)
    path.write_text("\n".join(lines) + "\n")
    assert hit, (old, slice_id)
    return hit


def _same_contours(a, b):
    key = lambda c: (c.frame, c.structure, c.view, c.slice, c.index)   # noqa: E731
    ca, cb = sorted(a.contours, key=key), sorted(b.contours, key=key)
    assert [key(c) for c in ca] == [key(c) for c in cb]
    for x, y in zip(ca, cb):
        assert x.closed == y.closed and np.array_equal(x.points, y.points)


def _view_warnings(study):
    return [w for w in study.warnings if "the slice geometry wins over the label" in w]


@pytest.fixture(scope="module")
def bivme_untouched():
    folder = shared_data("bivme-patient1")
    study = load_study(folder)
    return folder, study


def test_bivme_mislabelled_slices_load_as_their_geometry_says(bivme_untouched, tmp_path):
    src, untouched = bivme_untouched
    folder = _copy(src, tmp_path / "bivme")
    # slice 8 is long-axis, slice 3 short-axis (SliceInfoFile geometry)
    la = _relabel(folder, 10, "LAX_LV_ENDOCARDIAL", "SAX_LV_ENDOCARDIAL", slice_id=8)
    sa = _relabel(folder, 3, "SAX_LV_EPICARDIAL", "LAX_LV_EPICARDIAL", slice_id=3)
    study = load_study(folder)
    warn = _view_warnings(study)
    assert len(warn) == 2
    assert any("GPFile_010.txt" in w and f"lines {la[0]}-{la[-1]}" in w and "SAX_LV_ENDOCARDIAL" in w
               and "slice 8" in w and "long-axis" in w for w in warn)
    assert any("GPFile_003.txt" in w and f"lines {sa[0]}-{sa[-1]}" in w and "LAX_LV_EPICARDIAL" in w
               and "slice 3" in w and "short-axis" in w for w in warn)
    _same_contours(study, untouched)          # used as the geometry says: the same study
    # and the same volumes (a quick reconstruction of the two frames touched)
    a = measure(reconstruct(study, frames=[3, 10]))
    b = measure(reconstruct(untouched, frames=[3, 10]))
    for k in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "LVM (g)"):
        assert abs(a[k] / b[k] - 1) < 0.05, k


def test_points_on_no_slice_plane_are_refused(bivme_untouched, tmp_path):
    src, _ = bivme_untouched
    folder = _copy(src, tmp_path / "bivme")
    path = folder / "GPFile_002.txt"
    t = pd.read_csv(path, sep="\t", dtype=str)
    rows = np.flatnonzero((t["contour type"] == "SAX_LV_ENDOCARDIAL") & (t["frameID"] == "4"))
    t.loc[t.index[rows], "z"] = (t.loc[t.index[rows], "z"].astype(float) + 5.0).map(repr)
    t.to_csv(path, sep="\t", index=False)
    with pytest.raises(StudyError) as e:
        load_study(folder)
    msg = str(e.value)
    assert "GPFile_002.txt" in msg and f"lines {rows[0] + 2}-{rows[-1] + 2}" in msg
    assert "no slice plane" in msg and "slice 4" in msg


def test_points_on_another_slice_than_their_frame_id_move_there(bivme_untouched, tmp_path):
    src, untouched = bivme_untouched
    folder = _copy(src, tmp_path / "bivme")
    path = folder / "GPFile_005.txt"
    t = pd.read_csv(path, sep="\t", dtype=str)
    rows = (t["contour type"] == "LAX_LV_EPICARDIAL") & (t["frameID"] == "9")
    t.loc[rows, "frameID"] = "2"                 # wrong slice number, points on slice 9
    t.to_csv(path, sep="\t", index=False)
    study = load_study(folder)
    warn = _view_warnings(study)
    assert len(warn) == 1 and "slice 9" in warn[0] and "frameID 2" in warn[0]
    _same_contours(study, untouched)


@pytest.fixture(scope="module")
def phantom_gp(tmp_path_factory):
    ph = generate.generate("normal", seed=1, frames=2, volume_check=False)
    ph.study.tags = []
    return gpfile.write_study(ph.study, tmp_path_factory.mktemp("gp") / "ph")


def test_phantom_mislabelled_slices_load_as_their_geometry_says(phantom_gp, tmp_path):
    untouched = load_study(phantom_gp)
    folder = _copy(phantom_gp, tmp_path / "ph")
    info = gpfile.read_slice_info(folder / "SliceInfoFile.txt")
    ids = {s["file"]: s["id"] for s in info}
    la_id = next(i for f, i in ids.items() if "ch" in f.lower())
    sa_id = next(s.slice for s in untouched.images if s.view == "SA" and s.slice == "sa_03")
    sa_num = next(d["id"] for d in untouched.meta["gpfile"]["slices"] if d["slice"] == sa_id)
    _relabel(folder, 0, "LAX_LV_ENDOCARDIAL", "SAX_LV_ENDOCARDIAL", slice_id=la_id)
    _relabel(folder, 1, "SAX_LV_ENDOCARDIAL", "LAX_LV_ENDOCARDIAL", slice_id=sa_num)
    study = load_study(folder)
    assert len(_view_warnings(study)) == 2
    _same_contours(study, untouched)


def test_regurgitation_only_where_it_is_the_stated_question(phantom_gp, tmp_path):
    """A GPFile study states no pathology: LVSV-RVSV is reported, MR RegVol / RegFrac are
    null with their reason; ``analyze --pathology mr`` states it (issue #30, item 3)."""
    import json
    from cardionurbs.cli import main
    got = {}
    for name, extra in (("plain", []), ("mr", ["--pathology", "mr"])):
        out = tmp_path / name
        assert main(["analyze", str(phantom_gp), "--outputs", "metrics", "--jobs", "1",
                     "--out", str(out), *extra]) == 0
        got[name] = json.loads((out / "metrics.json").read_text())
    plain, mr = got["plain"]["metrics"], got["mr"]["metrics"]
    diff = plain["LVSV (mL)"] - plain["RVSV (mL)"]
    assert plain["LVSV-RVSV (mL)"] == pytest.approx(diff)
    assert plain["MR RegVol (mL)"] is None and plain["MR RegFrac (%)"] is None
    assert "not the stated question" in got["plain"]["notes"]["MR RegVol (mL)"]
    assert mr["MR RegVol (mL)"] == pytest.approx(max(0.0, diff))
    assert mr["LVSV-RVSV (mL)"] == pytest.approx(diff)
    assert "MR RegVol (mL)" not in got["mr"]["notes"]
