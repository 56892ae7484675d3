"""CLI contract: usage errors are one line on stderr with exit code 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from cardionurbs.cli import main


@pytest.mark.parametrize("argv", [[], ["bogus"], ["phantom"], ["cohort", "x"],
                                  ["phantom", "--pathology", "nope", "--out", "x"],
                                  ["phantom", "--pathology", "normal", "--frames", "0", "--out", "x"]])
def test_usage_errors_exit_2_with_one_line(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_missing_study_is_one_line(tmp_path):
    r = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "analyze", str(tmp_path / "nope"),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "nope" in r.stderr
    assert not (tmp_path / "o").exists()


def test_phantom_breath_hold_flag_is_recorded_in_truth(tmp_path):
    import json

    out = tmp_path / "p"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--breath-hold-mm", "2",
                 "--no-dicom", "--out", str(out)]) == 0
    faults = json.loads((out / "truth.json").read_text())["faults"]
    assert faults["breath_hold_mm"] == 2.0
    shifts = [v for v in faults["breath_hold_shifts_mm"].values()]
    assert shifts and max(abs(x) for v in shifts for x in v) > 0
