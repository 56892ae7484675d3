"""What the accuracy settings of the reconstruction would buy: one study's metrics-only cost
in a running process (``load_study`` + ``analyse(jobs=1)`` + the quality check: a cohort
row) with each setting made cheaper, the metrics' largest relative change, and the volume
errors against the phantom's truth.

    OPENBLAS_NUM_THREADS=1 python benchmarks/speed_knobs.py [--rounds 3] STUDY...

Each setting is changed alone, then all together; rounds alternate the configurations
(the median CPU of each). The settings are module defaults patched for the run, not
options of the package: this asks whether relaxing "the same metrics to 1e-6" would reach
issue 16's times, not how to run faster.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cardionurbs.analysis.regional  # noqa: E402,F401  (imported before the timing)
import cardionurbs.analysis.tagqc  # noqa: E402,F401
import cardionurbs.analysis.tags as tags_module  # noqa: E402
import cardionurbs.anatomy.model as model_module  # noqa: E402
import cardionurbs.anatomy.refine as refine_module  # noqa: E402
import cardionurbs.anatomy.surfaces as surfaces_module  # noqa: E402
import cardionurbs.nurbs.projection as projection_module  # noqa: E402
from cardionurbs.analysis.quality import assess  # noqa: E402
from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.pipeline import analyse  # noqa: E402

VOLUMES = ("LVEDV (mL)", "LVESV (mL)", "LVM (g)", "RVEDV (mL)", "RVESV (mL)")


def _patch(obj, attr: str, value):
    old = getattr(obj, attr)
    setattr(obj, attr, value)
    return lambda: setattr(obj, attr, old)


def _defaults(fn, **new):
    """Patch keyword defaults of ``fn`` (positional ``__defaults__`` and ``__kwdefaults__``)."""
    import inspect
    params = [p for p in inspect.signature(fn).parameters.values()
              if p.default is not inspect.Parameter.empty and p.kind != p.KEYWORD_ONLY]
    old_d, old_kw = fn.__defaults__, fn.__kwdefaults__
    if fn.__defaults__ is not None:
        d = list(fn.__defaults__)
        for i, p in enumerate(params[-len(d):]):
            if p.name in new:
                d[i] = new[p.name]
        fn.__defaults__ = tuple(d)
    if fn.__kwdefaults__ is not None:
        fn.__kwdefaults__ = {**fn.__kwdefaults__, **{k: v for k, v in new.items()
                                                     if k in fn.__kwdefaults__}}

    def undo():
        fn.__defaults__, fn.__kwdefaults__ = old_d, old_kw
    return undo


#: setting -> a function applying it and returning its undo
KNOBS = {
    "contour samples 120 -> 60": lambda: _defaults(surfaces_module.resample_loop, m=60),
    "tessellation 56 x 36 -> 28 x 18": lambda: _defaults(model_module.reconstruct,
                                                         resolution=(28, 18)),
    "LA refinement grid 192 x 96 -> 96 x 48": lambda: _defaults(refine_module.grid_projection,
                                                                nu=96, nv=48),
    "closest-point seeds 3 -> 1": lambda: _defaults(projection_module.surface_closest_points,
                                                    seeds=1),
    "no tag QC": lambda: _defaults(tags_module.tag_metrics, qc=False),
}


def cost(path: str) -> tuple[float, dict]:
    t = time.process_time()
    study = load_study(path)
    model, metrics, _ = analyse(study, over_time=False, jobs=1)
    assess(model, metrics)
    return time.process_time() - t, metrics


def largest_change(a: dict, b: dict) -> tuple[float, str]:
    worst, name = 0.0, ""
    for k, x in a.items():
        y = b.get(k, float("nan"))
        if math.isnan(x) or math.isnan(y):
            continue
        r = abs(x - y) / max(abs(x), 1e-9)
        if r > worst:
            worst, name = r, k
    return worst, name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("studies", nargs="+")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args(argv)
    configs = ["default", *KNOBS, "all together"]
    cpu: dict = {(c, s): [] for c in configs for s in a.studies}
    metrics: dict = {}
    for s in a.studies:
        cost(s)                                   # warm: imports, caches
    for _ in range(a.rounds):
        for c in configs:
            undo = [KNOBS[k]() for k in KNOBS] if c == "all together" else \
                ([KNOBS[c]()] if c in KNOBS else [])
            try:
                for s in a.studies:
                    t, m = cost(s)
                    cpu[(c, s)].append(t)
                    metrics[(c, s)] = m
            finally:
                for u in reversed(undo):
                    u()
    print(f"# in-process CPU (s), median of {a.rounds}; largest metric change against the "
          "default; volume errors against truth (%)\n")
    for s in a.studies:
        truth_file = Path(s) / "truth.json"
        truth = json.loads(truth_file.read_text())["metrics"] if truth_file.exists() else None
        print(f"## {Path(s).name}\n")
        print("| setting | CPU (s) | largest change |" +
              ("".join(f" {v} err % |" for v in VOLUMES) if truth else ""))
        print("|---|---:|---|" + ("---:|" * len(VOLUMES) if truth else ""))
        for c in configs:
            m = metrics[(c, s)]
            ch, name = largest_change(metrics[("default", s)], m)
            row = f"| {c} | {statistics.median(cpu[(c, s)]):.2f} | " + \
                (f"{100 * ch:.3g} % ({name})" if ch else "0") + " |"
            if truth:
                row += " " + " | ".join(f"{100 * (m[v] - truth[v]) / truth[v]:+.2f}"
                                        for v in VOLUMES) + " |"
            print(row)
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
