"""Workers die with their parent (issue 31, finding 6; the worker core of issue 35): after
SIGKILL of a process running fork_map (analyze --jobs) or run_tasks (cohort, phantom
--cohort), none of its workers is alive 2 s later."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from procs import alive, children

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")

PARENTS = {
    "fork_map": ("import time\nfrom cardionurbs.parallel import fork_map\n"
                 "fork_map(time.sleep, [60, 60, 60], jobs=2)\n"),
    "run_tasks": ("import time\nfrom cardionurbs.executor import run_tasks\n"
                  "run_tasks(time.sleep, [(60,), (60,)], lambda i, r: None, jobs=2)\n"),
}


@pytest.mark.parametrize("runner", sorted(PARENTS))
def test_workers_end_within_two_seconds_of_their_parents_death(runner):
    p = subprocess.Popen([sys.executable, "-c", PARENTS[runner]], cwd=ROOT,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    t0 = time.monotonic()
    kids: list[int] = []
    while len(kids) < 2:
        assert p.poll() is None and time.monotonic() - t0 < 60, "the workers did not start"
        kids = children(p.pid)
        time.sleep(0.05)
    time.sleep(0.3)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    time.sleep(2.0)
    left = [k for k in kids if alive(k)]
    for k in left:
        os.kill(k, signal.SIGKILL)
    assert left == [], f"{runner}: workers alive 2 s after the parent's death"
