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
