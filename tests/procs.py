"""Child processes of a process, for the orphan checks of the tests and benchmarks
(tests/test_cohort_runs.py, tests/test_parallel_orphans.py, benchmarks/kill_cohort.py,
benchmarks/fuzz_inputs.py): psutil, which dask.distributed already brings."""

from __future__ import annotations

import psutil


def children(pid: int) -> list[int]:
    """Pids whose parent is ``pid`` ([] when ``pid`` is gone)."""
    try:
        return [c.pid for c in psutil.Process(pid).children()]
    except psutil.NoSuchProcess:
        return []


def alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie, dead but not yet reaped, is not alive)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False
