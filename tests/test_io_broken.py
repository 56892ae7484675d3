"""Every broken input fails with one clear line (StudyError), and the CLI shows no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from broken.corpus import CORPUS, make_gpfile, make_native, make_sunnybrook
from cardionurbs import StudyError, load_study
from cardionurbs.cli import main

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 20
    assert len({c.name for c in CORPUS}) == len(CORPUS)


@pytest.mark.parametrize("make", [make_sunnybrook, make_gpfile, make_native],
                         ids=["sunnybrook", "gpfile", "native"])
def test_unbroken_originals_load(make, tmp_path):
    """The corpus breaks valid studies: the originals load without error."""
    study = load_study(make(tmp_path / "study"))
    assert study.contours and study.images


@pytest.mark.parametrize("case", CORPUS, ids=[c.name for c in CORPUS])
def test_broken_input_fails_with_one_clear_line(case, tmp_path):
    path = case.build(tmp_path / "study")
    with pytest.raises(StudyError) as info:
        load_study(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert case.expect in msg, msg
    assert str(tmp_path / "study") in msg, f"message does not name the file: {msg}"


@pytest.mark.parametrize("case", CORPUS, ids=[c.name for c in CORPUS])
def test_cli_analyze_broken_input_exits_2_with_one_line(case, tmp_path, capsys):
    path = case.build(tmp_path / "study")
    rc = main(["analyze", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("cardionurbs: error: ") and case.expect in err
    assert not (tmp_path / "out").exists()


def test_cli_subprocess_no_traceback(tmp_path):
    """The real command line, a few cases run side by side: exit 2, exactly one stderr line."""
    picks = [c for c in CORPUS if c.name in ("dicom_truncated", "contour_non_numeric",
                                               "gpfile_unknown_slice", "native_missing_image")]
    procs = []
    for c in picks:
        path = c.build(tmp_path / c.name)
        procs.append((c, subprocess.Popen(
            [sys.executable, "-m", "cardionurbs.cli", "analyze", str(path), "--out",
             str(tmp_path / f"out_{c.name}")], cwd=ROOT, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)))
    for c, p in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 2, (c.name, err)
        assert err.count("\n") == 1 and "Traceback" not in err and c.expect in err, (c.name, err)
