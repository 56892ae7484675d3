"""One exit-code contract (issue 10): 0 done; 2 bad input or usage, one line with one
``cardionurbs: error:`` prefix; 1 internal error, one line naming the traceback file
(--debug prints it); 130 / 143 on SIGINT / SIGTERM (tests/test_cli_outputs.py); help texts
with defaults and no raw markup."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cardionurbs.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]

_CRASH = """
import sys
import cardionurbs.pipeline as p
def boom(*a, **k):
    raise RuntimeError("a bug deep inside")
p.load_study = boom
from cardionurbs.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _crash(tmp_path, *extra):
    return subprocess.run([sys.executable, "-c", _CRASH, *extra, "analyze", str(tmp_path / "S"),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True,
                          cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT),
                                             TMPDIR=str(tmp_path)))


def test_internal_error_is_one_line_naming_the_traceback_file(tmp_path):
    r = _crash(tmp_path)
    assert r.returncode == 1
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert r.stderr.startswith("cardionurbs: internal error: RuntimeError: a bug deep inside")
    path = Path(re.search(r"traceback in (\S+)", r.stderr).group(1))
    assert path.is_file() and path.parent == tmp_path
    text = path.read_text()
    assert "Traceback (most recent call last)" in text and "boom" in text


def test_debug_prints_the_traceback(tmp_path):
    r = _crash(tmp_path, "--debug")
    assert r.returncode == 1 and "Traceback (most recent call last)" in r.stderr
    assert "RuntimeError: a bug deep inside" in r.stderr
    r = _crash(tmp_path, )
    assert r.returncode == 1


@pytest.mark.parametrize("argv, words", [
    (["analyze"], ["analyze:", "required"]),
    ([], ["a command is required"]),
    (["analyze", "S", "--out", "o", "--heart-rate", "-60"], ["--heart-rate", "-60", "20"]),
    (["analyze", "S", "--out", "o", "--heart-rate", "nan"], ["--heart-rate"]),
    (["analyze", "S", "--out", "o", "--heart-rate", "400"], ["--heart-rate", "300"]),
    (["phantom", "--pathology", "normal", "--frames", "100000", "--out", "o"], ["--frames"]),
    (["phantom", "--pathology", "normal", "--noise-px", "inf", "--out", "o"], ["--noise-px"]),
    (["cohort", "S", "--csv", "c.csv", "--jobs", "0"], ["--jobs"]),
])
def test_usage_errors_have_one_prefix_and_one_line(argv, words, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("cardionurbs: error: ")
    assert err.count("cardionurbs") == 1, err          # never "cardionurbs: error: cardionurbs: ..."
    for w in words:
        assert w in err


def test_missing_study_is_named_once(tmp_path, capsys):
    assert main(["analyze", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.count("cardionurbs: error:") == 1 and "nope" in err


def _subparsers(parser):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return a.choices
    return {}


def test_every_option_has_help_and_shows_its_default_once():
    """Each default is said once and right: ``(default: X)`` for an option with a value
    default, nothing for on/off flags (off unless given), never both a hand-written and
    an added default."""
    parser = build_parser()
    top = parser.format_help()
    assert "``" not in top and "(default: False)" not in top
    for name, sub in _subparsers(parser).items():
        text = " ".join(sub.format_help().split())
        assert "``" not in text and "(default: False)" not in text, name
        for a in sub._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            assert a.help, f"{name} {a.dest} has no help text"
            shown = HelpFormatterProbe(sub).help_of(a)
            assert shown.count("default") <= 1, (name, a.dest, shown)
            flag = isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction))
            if not a.required and a.default is not None and a.option_strings and not flag:
                assert "default" in shown, (name, a.dest)
                if "default" not in a.help:
                    assert f"(default: {a.default})" in shown, (name, a.dest)


class HelpFormatterProbe:
    """The help text of one action as the parser's formatter shows it (defaults added)."""

    def __init__(self, parser):
        self.formatter = parser._get_formatter()

    def help_of(self, action) -> str:
        return " ".join(self.formatter._expand_help(action).split())