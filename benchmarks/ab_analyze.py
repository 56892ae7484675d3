"""Interleaved A/B cost of ``cardionurbs analyze`` as a fresh process, on two source trees.

    python benchmarks/ab_analyze.py BEFORE_TREE AFTER_TREE STUDY [--outputs all] [--rounds 5]
        [--before-args "..."] [--after-args "--jobs 1"] [--idle 0.9]

Each round runs ``python -m cardionurbs.cli analyze STUDY --outputs OUTPUTS --out TMP`` once
per tree (with that tree's extra arguments, e.g. ``--jobs 1``; the same tree may be given
twice to compare options), in alternating order (so that both see the same load on a shared
machine), and records its wall time, its CPU time (user + system, start-up and imports
included: what the command costs the machine) and its peak resident memory. ``wait4``
reports a process's resources with those of its descendants it waited for, which
``analyze --jobs`` does for every worker it forks: the CPU time is the whole process
tree's, and the peak memory the largest resident set of any one process of the tree (Linux
ru_maxrss: the maximum, not the sum). Prints every run, the medians, the CPUs this process
may use and the load average before and after; ``--idle`` starts each run only when the
CPUs were free over the second before (shared machine). BLAS threads are limited to one
(``OPENBLAS_NUM_THREADS=1``), as in ``bench_throughput.py``.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time


def _cpu_times() -> tuple[int, int]:
    """(idle, total) jiffies of all CPUs so far (/proc/stat)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    return v[3] + v[4], sum(v)


def wait_idle(fraction: float, longest_s: float) -> float:
    """Wait until the CPUs were at least ``fraction`` idle over one second (at most
    ``longest_s`` s); return that idle fraction (Linux; 1.0 elsewhere)."""
    if not os.path.exists("/proc/stat"):
        return 1.0
    deadline = time.monotonic() + longest_s
    while True:
        i0, t0 = _cpu_times()
        time.sleep(1.0)
        i1, t1 = _cpu_times()
        idle = (i1 - i0) / max(t1 - t0, 1)
        if idle >= fraction or time.monotonic() > deadline:
            return idle


def run_once(tree: str, study: str, outputs: str, out: str,
             extra: list[str] = ()) -> tuple[float, float, float]:
    """(CPU s, wall s, peak MB) of one fresh ``analyze`` process run from ``tree`` (CPU: the
    process and the workers it waited for; peak: its largest process)."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONPATH=tree)
    t = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "cardionurbs.cli", "analyze", study,
                          "--outputs", outputs, "--out", out, *extra], cwd=tree, env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    err = p.stderr.read().decode(errors="replace")
    p.stderr.close()
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise SystemExit(f"{tree}: analyze failed ({p.returncode}): {err.strip()}")
    return ru.ru_utime + ru.ru_stime, wall, ru.ru_maxrss / 1024


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("study")
    ap.add_argument("--outputs", default="all")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--before-args", default="", help="extra analyze arguments for BEFORE")
    ap.add_argument("--after-args", default="", help="extra analyze arguments for AFTER")
    ap.add_argument("--idle", type=float, default=None, metavar="FRACTION",
                    help="start each run once the CPUs were this idle over one second (e.g. "
                         "0.9; at most 300 s of waiting): on a shared machine, runs that see "
                         "the cores free (a parallel run's wall time needs them)")
    a = ap.parse_args(argv)
    trees = {"before": os.path.abspath(a.before), "after": os.path.abspath(a.after)}
    extra = {"before": shlex.split(a.before_args), "after": shlex.split(a.after_args)}
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:
        cpus = os.cpu_count()
    print(f"{cpus} usable CPUs; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} "
          "(1, 5, 15 min) at the start", flush=True)
    runs: dict[str, list[tuple[float, float, float]]] = {k: [] for k in trees}
    with tempfile.TemporaryDirectory(prefix="cn-ab-analyze-") as tmp:
        for i in range(a.rounds):
            for k in (list(trees) if i % 2 == 0 else list(trees)[::-1]):
                idle = "" if a.idle is None else f"  (idle before: {wait_idle(a.idle, 300):.2f})"
                r = run_once(trees[k], os.path.abspath(a.study), a.outputs, os.path.join(tmp, k),
                             extra[k])
                runs[k].append(r)
                print(f"round {i + 1} {k:6s} CPU {r[0]:6.2f} s  wall {r[1]:6.2f} s  "
                      f"peak {r[2]:5.0f} MB{idle}", flush=True)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the end")
    print(f"\n{a.study}, --outputs {a.outputs}, {a.rounds} rounds (medians):")
    for k, rs in runs.items():
        label = " ".join([trees[k], *extra[k]])
        print(f"  {k:6s} CPU {statistics.median(r[0] for r in rs):6.2f} s  "
              f"wall {statistics.median(r[1] for r in rs):6.2f} s  "
              f"peak {statistics.median(r[2] for r in rs):5.0f} MB  ({label})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
