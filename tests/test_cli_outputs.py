"""Outputs never destroy anything (issue 10): --out is checked before any work, replaced
atomically, interrupted runs leave the previous output intact and no debris after the next
run, files follow the umask. User files are compared byte for byte afterwards."""

from __future__ import annotations

import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cardionurbs.cli import main
from cardionurbs.io.atomic import MARKER, STUDY_MARKER

ROOT = Path(__file__).resolve().parents[1]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes), hidden files included."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def cli(*argv, cwd=None, env=None, **kw):
    return subprocess.run([sys.executable, "-m", "cardionurbs.cli", *map(str, argv)],
                          capture_output=True, text=True, cwd=cwd or ROOT,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), **(env or {})), **kw)


def one_error_line(r, *words):
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith("cardionurbs: error: ") and r.stderr.count("cardionurbs:") == 1
    for w in words:
        assert w in r.stderr, (w, r.stderr)


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """A small native phantom study (2 frames, no DICOM) with a user file in it."""
    s = tmp_path_factory.mktemp("cli_outputs") / "S"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom",
                 "--out", str(s)]) == 0
    (s / "notes.txt").write_text("the user's own notes\n")
    return s


def test_analyze_out_equal_to_study_keeps_it_byte_for_byte(study):
    before = snapshot(study)
    r = cli("analyze", study, "--out", study, "--no-figures")
    one_error_line(r, "--out", "input")
    r = cli("analyze", study, "--out", study, "--no-figures", "--overwrite")
    one_error_line(r, "--out", "input")
    r = cli("analyze", study / "study.json", "--out", study, "--overwrite")
    one_error_line(r, "--out", "input")
    assert snapshot(study) == before


def test_out_inside_the_study_is_refused(study):
    before = snapshot(study)
    r = cli("analyze", study, "--out", study / "sub" / "o", "--no-figures")
    one_error_line(r, "inside the input")
    assert snapshot(study) == before and not (study / "sub").exists()


def test_out_containing_the_study_is_refused(study):
    before = snapshot(study)
    r = cli("analyze", study, "--out", study.parent, "--overwrite")
    one_error_line(r, "contains the input")
    assert snapshot(study) == before


def test_out_an_unrelated_non_empty_folder_is_refused(study, tmp_path):
    user = tmp_path / "user"
    (user / "deep").mkdir(parents=True)
    (user / "thesis.tex").write_text("\\section{years of work}\n")
    (user / "deep" / "data.bin").write_bytes(bytes(range(256)))
    before = snapshot(user)
    for cmd in (["analyze", study, "--no-figures"],
                ["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom"]):
        for extra in ([], ["--overwrite"]):
            r = cli(*cmd, "--out", user, *extra)
            one_error_line(r, "did not write")
    assert snapshot(user) == before


def test_out_dot_fails_before_any_work(study, tmp_path, monkeypatch, capsys):
    (tmp_path / "mine.txt").write_text("mine")
    monkeypatch.chdir(tmp_path)
    import cardionurbs.pipeline as pipeline

    def no_work(*a, **k):
        raise AssertionError("the study was read before --out was checked")
    monkeypatch.setattr(pipeline, "load_study", no_work)
    assert main(["analyze", str(study), "--out", ".", "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out ." in err
    assert (tmp_path / "mine.txt").read_text() == "mine"


def test_existing_file_is_not_swapped_for_a_folder(study, tmp_path):
    f = tmp_path / "result"
    f.write_bytes(b"precious\x00bytes")
    r = cli("analyze", study, "--out", f, "--no-figures", "--overwrite")
    one_error_line(r, "existing file")
    r = cli("phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--out", f,
            "--overwrite")
    one_error_line(r, "existing file")
    assert f.read_bytes() == b"precious\x00bytes"


def test_cohort_csv_cannot_replace_a_study_file(study):
    before = snapshot(study)
    r = cli("cohort", study, "--csv", study / "points.csv")
    one_error_line(r, "--csv", "input")
    assert snapshot(study) == before


def test_earlier_output_needs_overwrite_and_is_then_replaced(study, tmp_path):
    out = tmp_path / "o"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--seed", "1",
                 "--out", str(out)]) == 0
    assert (out / STUDY_MARKER).is_file() and not (out / MARKER).exists()   # a study
    before = snapshot(out)
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--seed", "2",
                 "--out", str(out)]) == 2
    assert snapshot(out) == before
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--seed", "2",
                 "--out", str(out), "--overwrite"]) == 0
    assert snapshot(out) != before and (out / STUDY_MARKER).is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["o"]        # no debris


# ------------------------------------------------------------- interrupted runs
_SLOW = """
import pathlib, sys, time
import importlib
g = importlib.import_module("cardionurbs.phantom.generate")
orig = g.write_study
def slow(study, folder, *a, **k):
    r = orig(study, folder, *a, **k)
    pathlib.Path(sys.argv[1]).write_text("half-way")
    time.sleep(120)
    return r
g.write_study = slow
from cardionurbs.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _default_signals() -> None:
    """As from a terminal: SIGINT and SIGTERM neither ignored nor blocked (a pytest-xdist
    worker may have done either, and children inherit both)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def _interrupt(out: Path, sentinel: Path, sig: int) -> int:
    args = ["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--seed", "9",
            "--out", str(out), "--overwrite"]
    p = subprocess.Popen([sys.executable, "-c", _SLOW, str(sentinel), *args], cwd=ROOT,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)), stderr=subprocess.PIPE,
                         stdout=subprocess.DEVNULL, text=True,
                         preexec_fn=_default_signals)
    t0 = time.monotonic()
    while not sentinel.exists():
        assert p.poll() is None, p.stderr.read()
        assert time.monotonic() - t0 < 60
        time.sleep(0.05)
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    if sig != signal.SIGKILL:
        assert err.count("\n") == 1 and "Traceback" not in err, err
    return p.returncode


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143),
                                       (signal.SIGKILL, -9)])
def test_interrupted_run_keeps_previous_output_and_leaves_no_debris(tmp_path, sig, code):
    out = tmp_path / "o"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom",
                 "--out", str(out)]) == 0
    before = snapshot(out)
    assert _interrupt(out, tmp_path / "sentinel", sig) == code
    assert snapshot(out) == before
    debris = [p.name for p in tmp_path.iterdir() if p.name.startswith(".o.")]
    if sig == signal.SIGKILL:
        assert debris                    # a killed process cannot clean up ...
        assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom",
                     "--out", str(out), "--overwrite"]) == 0
        debris = [p.name for p in tmp_path.iterdir() if p.name.startswith(".o.")]
    assert debris == []                  # ... the next run does


@pytest.mark.parametrize("mask", [0o022, 0o027])
def test_files_follow_the_umask(tmp_path, mask):
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "phantom", "--pathology",
                        "normal", "--frames", "2", "--no-dicom", "--out", str(out)], cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True,
                       preexec_fn=lambda: os.umask(mask))
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~mask
    for f in ("study.json", "points.csv", "truth.json", STUDY_MARKER):
        assert stat.S_IMODE((out / f).stat().st_mode) == 0o666 & ~mask, f


# ------------------------------------------- inputs and outputs told apart (issue 31, 2 and 3)
def test_no_output_command_replaces_a_generated_study(study, tmp_path):
    other = tmp_path / "B"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--seed", "3",
                 "--out", str(other)]) == 0
    before = snapshot(other)
    r = cli("analyze", study, "--out", other, "--overwrite", "--no-figures")
    one_error_line(r, "--out", "study cardionurbs generated")
    assert snapshot(other) == before


def test_overwrite_refuses_naming_files_it_did_not_write(study, tmp_path):
    out = tmp_path / "o"
    assert main(["analyze", str(study), "--out", str(out), "--outputs", "metrics"]) == 0
    (out / "my_notes.txt").write_text("mine")
    (out / "sub").mkdir()
    (out / "sub" / "data.bin").write_bytes(b"\0")
    r = cli("analyze", study, "--out", out, "--overwrite", "--outputs", "metrics")
    one_error_line(r, "--out", "my_notes.txt", "sub/data.bin")
    assert (out / "my_notes.txt").read_text() == "mine" and (out / "sub" / "data.bin").exists()
    (out / "my_notes.txt").unlink()
    shutil.rmtree(out / "sub")
    assert main(["analyze", str(study), "--out", str(out), "--overwrite", "--outputs",
                 "metrics"]) == 0


def test_cohort_writes_nothing_into_a_study(study, tmp_path):
    before = snapshot(study)
    r = cli("cohort", study, "--csv", tmp_path / "c.csv", "--run-dir", study / "rows")
    one_error_line(r, "--run-dir", "input")
    r = cli("cohort", study, "--csv", study / "c.csv")
    one_error_line(r, "--csv", "input")
    assert snapshot(study) == before and not (tmp_path / "c.csv").exists()


def test_cohort_csv_onto_a_users_file_needs_overwrite(study, tmp_path):
    mine = tmp_path / "results.csv"
    mine.write_text("patient,ef\nA,55\n")
    r = cli("cohort", study, "--csv", mine)
    one_error_line(r, "--csv", "did not write", "--overwrite")
    assert mine.read_text() == "patient,ef\nA,55\n"
    assert main(["cohort", str(study), "--csv", str(mine), "--overwrite"]) == 0
    assert main(["cohort", str(study), "--csv", str(mine)]) == 0      # now a cohort table
