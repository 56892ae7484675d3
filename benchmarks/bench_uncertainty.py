"""CPU cost of the 95 % intervals: `analyze --outputs metrics` with `--uncertainty on` against
`off`, on a 20-frame phantom and on bivme-patient1, and the API (`measure(model)` against
`measure(model, uncertainty=True)` on the same model).

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE nice -n 10 \
        python benchmarks/bench_uncertainty.py --out reports/benchmark-uncertainty.md

CPU seconds of the child process (user + system, resource.getrusage), one worker
(`--jobs 1`), the runs alternating off/on, the median of ``--repeats``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT))

from cardionurbs import load_study, measure, reconstruct  # noqa: E402

generate = importlib.import_module("cardionurbs.phantom.generate")
CLI = [sys.executable, "-m", "cardionurbs.cli"]


def child_cpu(cmd: list[str]) -> float:
    """CPU seconds (user + system) of one child process run to its end."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def analyze_cost(study: Path, tmp: Path, repeats: int) -> dict[str, float]:
    times: dict[str, list[float]] = {"off": [], "on": []}
    for k in range(repeats):
        for mode in ("off", "on"):
            out = tmp / f"out_{study.name}_{mode}_{k}"
            times[mode].append(child_cpu([*CLI, "analyze", str(study), "--outputs", "metrics",
                                          "--jobs", "1", "--uncertainty", mode, "--out", str(out)]))
    return {m: float(np.median(v)) for m, v in times.items()}


def api_cost(study_path: Path) -> tuple[float, float]:
    """(measure CPU s, measure with uncertainty CPU s) on one reconstructed model each."""
    out = []
    for unc in (False, True):
        model = reconstruct(load_study(study_path))
        t = time.process_time()
        measure(model, uncertainty=unc)
        out.append(time.process_time() - t)
    return out[0], out[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args(argv)
    rows = ["| study | metrics only, --uncertainty off (CPU s) | on (CPU s) | ratio |",
            "|---|---|---|---|"]
    api = ["| study | measure(model) (CPU s) | measure(model, uncertainty=True) (CPU s) | ratio |",
           "|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ph = generate.generate("normal", seed=0, frames=20)
        phantom = generate.write_phantom(ph, tmp / "phantom20", dicom=False)
        studies = [("20-frame phantom (normal, seed 0, tags)", phantom)]
        if (DATA / "bivme-patient1").exists():
            studies.append(("bivme-patient1", DATA / "bivme-patient1"))
        for name, path in studies:
            c = analyze_cost(path, tmp, a.repeats)
            rows.append(f"| {name} | {c['off']:.2f} | {c['on']:.2f} | {c['on'] / c['off']:.2f} |")
            m0, m1 = api_cost(path)
            api.append(f"| {name} | {m0:.2f} | {m1:.2f} | {m1 / m0:.2f} |")
            print(rows[-1], api[-1], flush=True)
    load = os.getloadavg()
    text = ["# Benchmark: the cost of the 95 % intervals", "", "```",
            "env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE nice -n 10 python "
            "benchmarks/bench_uncertainty.py --out reports/benchmark-uncertainty.md", "```", "",
            f"- date: {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M UTC}; machine: "
            f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"load {load[0]:.1f} (2 cores shared with other work); OPENBLAS_CORETYPE and "
            "OPENBLAS_L2_SIZE unset for this command only",
            f"- CPU seconds of the process (user + system), median of {a.repeats} alternating runs; "
            "target: with intervals at most 3x metrics only", "",
            "`cardionurbs analyze STUDY --outputs metrics --jobs 1 --uncertainty off|on`:", "",
            *rows, "", "The API on one reconstructed model (`cn.measure`; the intervals need the "
            "fit residuals at ED and ES, which `analyze` computes for the quality flags anyway "
            "and a bare `measure` does not):", "", *api, ""]
    a.out.write_text("\n".join(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
