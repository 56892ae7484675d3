"""kill -9 of ``cardionurbs cohort --jobs 2`` at random instants (issue 31, Done-when).

For each of ``--times`` seeded instants in [0.5 s, the uninterrupted run's wall time]: start
the run, SIGKILL the parent process alone (not its group) at that instant, wait 2 s, count
the processes of the run still alive (the parent's children recorded just before the kill),
then ``--resume`` and compare its CSV with the uninterrupted run's, byte for byte.

    nice -n 10 .venv/bin/python benchmarks/kill_cohort.py --times 20 --seed 31
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from procs import alive, children  # noqa: E402 (tests/ is on the path now)


def _cohort(args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "cardionurbs.cli", "cohort", *map(str, args)],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, **kw)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--times", type=int, default=20)
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--studies", type=int, default=4)
    args = ap.parse_args(argv)
    from cardionurbs.io.native import write_study
    from test_model_fixtures import heart, study_from_hearts

    tmp = Path(tempfile.mkdtemp(prefix="cn-kill-"))
    paths = [write_study(study_from_hearts([heart(s), heart(0.8 * s)], subject=f"s{i}", la=False),
                         tmp / f"s{i}") for i, s in enumerate(1 - 0.03 * k for k in
                                                              range(args.studies))]
    t = time.monotonic()
    ref = _cohort([*paths, "--csv", tmp / "ref.csv", "--jobs", 2])
    ref.wait()
    wall = time.monotonic() - t
    rnd = random.Random(args.seed)
    orphans = mismatches = 0
    for k in range(args.times):
        at = rnd.uniform(0.5, wall)
        csv = tmp / f"k{k}.csv"
        run = _cohort([*paths, "--csv", csv, "--jobs", 2])
        time.sleep(at)
        kids = children(run.pid)
        os.kill(run.pid, signal.SIGKILL)
        run.wait()
        time.sleep(2.0)
        left = [c for c in kids if alive(c)]
        for c in left:
            os.kill(c, signal.SIGKILL)
        orphans += bool(left)
        again = _cohort([*paths, "--csv", csv, "--jobs", 2, "--resume"])
        again.wait()
        same = csv.is_file() and csv.read_bytes() == (tmp / "ref.csv").read_bytes()
        mismatches += not same
        print(f"kill {k + 1} at {at:.2f} s: {len(kids)} children, {len(left)} alive 2 s later; "
              f"resume {'identical' if same else 'DIFFERENT'}", flush=True)
    print(f"uninterrupted run {wall:.1f} s; {args.times} kills: {orphans} with a process left "
          f"alive after 2 s, {mismatches} resumed CSVs different")
    return 1 if orphans or mismatches else 0


if __name__ == "__main__":
    sys.exit(main())
