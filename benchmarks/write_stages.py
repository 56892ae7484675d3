"""CPU seconds of each stage of ``write_analysis`` (all outputs), interleaved on two source trees.

    python benchmarks/write_stages.py BEFORE_TREE AFTER_TREE STUDY [--rounds 3]

Each round runs, once per tree in alternating order, a fresh process that loads the study,
runs ``analyse`` (with the tag time course, as ``analyze`` with figures does) and then
``write_analysis`` with every output, recording the process CPU time (user + system, all
threads: manifold3d's booleans are multithreaded) of each stage it reports (meshes, model,
metrics, figures, report; the figures stage includes importing matplotlib). BLAS runs on one
thread, as the CLI runs it. Prints every run and the per-stage medians.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

CHILD = r"""
import json, os, sys, tempfile, time
from cardionurbs.io import load_study
from cardionurbs.pipeline import analyse, write_analysis
from cardionurbs.progress import Progress

class StageCPU(Progress):
    def __init__(self):
        super().__init__(False)
        self.cpu, self._c = {}, None
    def stage(self, name):
        self.done()
        self._name, self._c = name, time.process_time()
        return self
    def done(self):
        if self._name is not None:
            self.cpu[self._name] = self.cpu.get(self._name, 0.0) + time.process_time() - self._c
        self._name = None

model, metrics, tags = analyse(load_study(sys.argv[1]))
p = StageCPU()
t = time.process_time()
write_analysis(model, metrics, os.path.join(tempfile.mkdtemp(), "out"), tags=tags, progress=p)
p.cpu["write_analysis"] = time.process_time() - t
print(json.dumps(p.cpu))
"""


def run_once(tree: str, study: str) -> dict[str, float]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", CHILD, study], cwd=tree, env=env,
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{tree}: failed: {out.stderr.strip()[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("study")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args(argv)
    trees = {"before": os.path.abspath(a.before), "after": os.path.abspath(a.after)}
    runs: dict[str, list[dict]] = {k: [] for k in trees}
    for i in range(a.rounds):
        for k in (list(trees) if i % 2 == 0 else list(trees)[::-1]):
            r = run_once(trees[k], os.path.abspath(a.study))
            runs[k].append(r)
            print(f"round {i + 1} {k:6s} " + "  ".join(f"{s} {v:.2f}" for s, v in r.items()),
                  flush=True)
    stages = list(runs["after"][0])
    print(f"\n{a.study}: CPU s per write_analysis stage, {a.rounds} rounds (medians)")
    print("| stage | before | after |\n|---|---:|---:|")
    for s in stages:
        med = {k: statistics.median(r.get(s, 0.0) for r in rs) for k, rs in runs.items()}
        print(f"| {s} | {med['before']:.2f} | {med['after']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
