"""Cohort runs that survive trouble: on a real Dask LocalCluster (scheduler and worker
processes on 127.0.0.1) and on local worker processes, a study that raises, one that
hangs past --timeout and one whose worker process dies each end as an error row while
the others are measured; a run killed with SIGKILL and rerun with --resume gives the
uninterrupted run's CSV byte for byte without measuring its finished studies again."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from cardionurbs.cohort import TEST_FAULTS_ENV, RowStore, cohort
from cardionurbs.io.native import write_study

from procs import alive, children
from test_model_fixtures import heart, study_from_hearts

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    good = []
    for i, s in enumerate((1.0, 0.97, 0.94)):
        st = study_from_hearts([heart(s), heart(0.8 * s)], subject=f"good{i}", la=False)
        good.append(str(write_study(st, root / f"good{i}")))
    faulty = {}
    for what in ("raise", "hang", "exit"):
        d = root / what
        write_study(study_from_hearts([heart(1.0), heart(0.8)], subject=what, la=False), d)
        (d / "TEST_FAULT").write_text(what)
        faulty[what] = str(d)
    # the timeout: well above what a good study takes on this machine now (the cores may be
    # shared), so that only the hanging study reaches it
    t = time.perf_counter()
    assert cohort([good[0]])["status"][0] == "ok"
    timeout = float(max(10, round(8 * (time.perf_counter() - t))))
    return good, faulty, timeout


def _check_rows(table: pd.DataFrame, good, faulty, timeout) -> None:
    by = dict(zip(table["subject"], table["status"]))
    for p in good:
        assert by[Path(p).name] == "ok", by
    assert by["raise"].startswith("error: RuntimeError: injected fault"), by
    assert by["hang"].startswith(f"error: timeout: no result after {timeout:g} s"), by
    assert by["exit"].startswith("error: worker died"), by
    assert table["LVEDV (mL)"].notna().sum() == len(good)


def test_dask_local_cluster_turns_raise_hang_and_dead_worker_into_error_rows(
        studies, tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    good, faulty, timeout = studies
    monkeypatch.setenv(TEST_FAULTS_ENV, "1")
    paths = [good[0], faulty["raise"], faulty["hang"], good[1], faulty["exit"], good[2]]
    table = cohort(paths, jobs=2, dask="local", timeout=timeout, run_dir=tmp_path / "run")
    assert list(table["subject"]) == [Path(p).name for p in paths]     # input order
    _check_rows(table, good, faulty, timeout)
    assert len(list((tmp_path / "run" / "rows").glob("*.json"))) == len(paths)


def test_local_processes_turn_raise_hang_and_dead_worker_into_error_rows(
        studies, tmp_path, monkeypatch):
    good, faulty, timeout = studies
    monkeypatch.setenv(TEST_FAULTS_ENV, "1")
    paths = [faulty["hang"], good[0], faulty["exit"], good[1], faulty["raise"], good[2]]
    table = cohort(paths, jobs=2, timeout=timeout)
    _check_rows(table, good, faulty, timeout)


def _cli(args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "cardionurbs.cli", "cohort", *args],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


@pytest.fixture(scope="module")
def reference_csv(studies, tmp_path_factory) -> bytes:
    """The uninterrupted run's CSV of the good studies (``--jobs 2``): the one the killed
    and resumed runs of both kill tests must give, whatever their job count."""
    good, _, _ = studies
    csv = tmp_path_factory.mktemp("ref") / "ref.csv"
    ref = _cli([*good, "--csv", str(csv), "--jobs", "2"])
    ref.communicate(timeout=300)
    assert ref.returncode == 0
    return csv.read_bytes()


def test_sigkill_midway_then_resume_gives_the_same_csv_without_redoing_rows(
        studies, reference_csv, tmp_path):
    good, _, _ = studies
    paths = list(good)
    # the same run, killed with SIGKILL once it has finished at least one subject
    csv = tmp_path / "killed.csv"
    rows = RowStore(tmp_path / "killed.csv.rows").rows_dir
    run = _cli([*paths, "--csv", str(csv)], start_new_session=True)
    t0 = time.monotonic()
    while not (rows.is_dir() and list(rows.glob("*.json"))):
        assert run.poll() is None, "the run ended before it could be killed"
        assert time.monotonic() - t0 < 240
        time.sleep(0.02)
    os.killpg(run.pid, signal.SIGKILL)
    run.communicate()
    assert run.returncode == -signal.SIGKILL
    assert not csv.exists()
    done = {f.name: f.stat().st_mtime_ns for f in rows.glob("*.json")}
    assert 1 <= len(done) < len(paths)
    again = _cli([*paths, "--csv", str(csv), "--resume"])
    again.communicate(timeout=300)
    assert again.returncode == 0
    assert csv.read_bytes() == reference_csv            # run with one job, the reference with two
    for name, mtime in done.items():        # finished subjects were not measured again
        assert (rows / name).stat().st_mtime_ns == mtime
    assert len(list(rows.glob("*.json"))) == len(paths)


def test_exit_status_and_parquet(studies, tmp_path, monkeypatch):
    from cardionurbs.cli import main
    good, faulty, _ = studies
    monkeypatch.setenv(TEST_FAULTS_ENV, "1")
    args = ["cohort", good[0], faulty["raise"], "--csv", str(tmp_path / "c.csv"), "--parquet"]
    assert main(args) == 3
    t = pd.read_parquet(tmp_path / "c.parquet")
    assert list(t["status"] == "ok") == [True, False]
    assert main(args + ["--resume", "--allow-failures"]) == 0


def test_fresh_run_clears_only_row_files(tmp_path):
    """A fresh run forgets stored rows but never removes a user's other files in --run-dir."""
    from cardionurbs.cohort import RowStore
    store = RowStore(tmp_path / "run")
    store.put("a", "auto", {"subject": "a", "status": "ok"})
    mine = store.rows_dir / "notes.txt"
    mine.write_bytes(b"keep me")
    store.clear()
    assert store.get("a") is None
    assert mine.read_bytes() == b"keep me"


def _worker_diagnostics() -> tuple:
    import dask
    return (dask.config.get("distributed.worker.profile.enabled"),
            dask.config.get("distributed.admin.tick.interval"))


def test_dask_local_workers_run_without_the_profiler_and_with_slow_ticks():
    """The local cluster's workers get WORKER_CONFIG (the profiler and the 20 ms tick cost a
    CPU-bound task a quarter of its time; reports/benchmark-throughput.md)."""
    pytest.importorskip("distributed")
    from cardionurbs.executor import WORKER_CONFIG, dask_client
    client, cluster = dask_client("local", 1)
    try:
        seen = set(client.run(_worker_diagnostics).values())
    finally:
        client.close()
        cluster.close()
    assert seen == {(False, WORKER_CONFIG["distributed.admin.tick.interval"])}


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_kill_9_of_the_parent_alone_leaves_no_worker_and_resume_matches(
        studies, reference_csv, tmp_path):
    """Issue 31, finding 6: SIGKILL of ``cohort --jobs 2`` itself (not its process group):
    both workers end within 2 s (the death-of-parent watch of cardionurbs.workers), and
    ``--resume`` then gives the uninterrupted run's CSV byte for byte."""
    good, _, _ = studies
    csv = tmp_path / "killed.csv"
    rows = RowStore(tmp_path / "killed.csv.rows").rows_dir
    run = _cli([*good, "--csv", str(csv), "--jobs", "2"], start_new_session=True)
    t0 = time.monotonic()
    workers: list[int] = []
    while len(workers) < 2:
        assert run.poll() is None and time.monotonic() - t0 < 120, "no workers started"
        workers = children(run.pid)
        time.sleep(0.02)
    time.sleep(0.3)                                    # the workers are busy with studies
    os.kill(run.pid, signal.SIGKILL)
    run.wait()                   # not communicate(): an orphan would hold the pipes open
    time.sleep(2.0)
    orphans = [w for w in workers if alive(w)]
    for w in orphans:            # leave nothing behind, whatever the outcome
        os.kill(w, signal.SIGKILL)
    run.communicate()
    assert orphans == [], "orphan workers still alive 2 s later"
    again = _cli([*good, "--csv", str(csv), "--resume", "--jobs", "2"])
    again.communicate(timeout=300)
    assert again.returncode == 0
    assert csv.read_bytes() == reference_csv
    assert len(list(rows.glob("*.json"))) == len(good)
