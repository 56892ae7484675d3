"""Interleaved A/B cost of one study on two source trees (e.g. the code before and after a change).

    OPENBLAS_NUM_THREADS=1 python benchmarks/ab_cost.py BEFORE_TREE AFTER_TREE STUDY... [--rounds 7]

On a shared machine the CPU time of the same command drifts by 10-30 % within minutes as
the other jobs come and go, so two benchmark runs minutes apart cannot resolve a 10 %
change. Here one long-lived worker process per tree (imports paid once) measures
``load_study`` + ``analyse_study`` + ``residual_table`` (what ``analyze --outputs metrics``
computes, without start-up and writing), and the two workers take turns, in alternating
order, so that both see the same load; the medians and every run (CPU s) are printed.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time


def worker(root: str) -> None:
    """Child: import cardionurbs from ``root``; for each study path on stdin print the CPU s
    of one load + analysis + residual table."""
    sys.path.insert(0, root)
    from cardionurbs.io import load_study
    from cardionurbs.pipeline import analyse_study
    for line in sys.stdin:
        t = time.process_time()
        model, _ = analyse_study(load_study(line.strip()))
        model.residual_table()
        print(f"{time.process_time() - t:.4f}", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("studies", nargs="+")
    ap.add_argument("--rounds", type=int, default=7)
    a = ap.parse_args(argv)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    trees = {"before": a.before, "after": a.after}
    procs = {k: subprocess.Popen([sys.executable, __file__, "--worker", root], text=True,
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
             for k, root in trees.items()}

    def ask(k: str, path: str) -> float:
        procs[k].stdin.write(path + "\n")
        procs[k].stdin.flush()
        return float(procs[k].stdout.readline())

    try:
        for path in a.studies:
            for k in procs:                                  # warm: imports and caches
                ask(k, path)
            runs: dict[str, list[float]] = {k: [] for k in procs}
            for i in range(a.rounds):
                for k in (list(procs) if i % 2 == 0 else list(procs)[::-1]):
                    runs[k].append(ask(k, path))
            b, c = statistics.median(runs["before"]), statistics.median(runs["after"])
            print(f"{path}: before {b:.2f} s, after {c:.2f} s CPU (median of {a.rounds}; "
                  f"{100 * (c / b - 1):+.1f} %); load {os.getloadavg()[0]:.1f}; runs before "
                  f"{[round(x, 2) for x in runs['before']]}, after "
                  f"{[round(x, 2) for x in runs['after']]}", flush=True)
    finally:
        for p in procs.values():
            p.stdin.close()
            p.wait()
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        worker(sys.argv[2])
    else:
        sys.exit(main())
