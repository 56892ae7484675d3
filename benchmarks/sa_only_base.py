"""SA-only hand contours: the valve-plane rule before and after ``base_between_slices``.

    nice -n 10 python benchmarks/sa_only_base.py --seed0 1000 > FILE.jsonl   # design rows 1, 7, ..., 55
    nice -n 10 python benchmarks/sa_only_base.py --seed0 3000 > FILE.jsonl
    nice -n 10 python benchmarks/sa_only_base.py --extra > FILE.jsonl        # normal/PHTN, noise, breath-hold
    python benchmarks/sa_only_base.py --table FILE.jsonl ...                  # the markdown table

Each subject is built as benchmarks/validate_uncertainty.py builds it (2 frames, the first SA
slice uniform over one gap below the base, drawn from the seed), the long-axis views and every
landmark dropped; it is analysed twice: with
:func:`cardionurbs.anatomy.model.base_between_slices` made a no-op (the half-slice rule: the
valve plane half a slice thickness beyond the most basal section at ED and ES) and as it is
(half-way to the next imaged SA plane; at ES where the LV myocardium keeps ED's volume).
One JSON line per subject and rule: the errors against the phantom's analytic truth.
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import validate_uncertainty as V  # noqa: E402

from cardionurbs.anatomy import model as M  # noqa: E402
from cardionurbs.phantom.generate import generate  # noqa: E402
from cardionurbs.phantom.geometry import Acquisition  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

KEYS = ("LVEDV (mL)", "LVESV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVESV (mL)", "RVEF (%)")
RULE = M.base_between_slices


def subjects(seed0: int | None) -> list[dict]:
    """The design's SA-only rows (seed0 given) or the extra normal/PHTN set with noise."""
    if seed0 is not None:
        return [c for c in V.conditions(60, seed0) if c["input"] == "contours SA-only"]
    out = []
    for path in ("normal", "phtn"):
        for anat in ("ideal", "realistic"):
            for noise, breath in ((0.5, 0.0), (1.0, 1.5)):
                out.append({"seed": 5000 + len(out), "input": "contours SA-only", "pathology": path,
                            "anatomy": anat, "noise_px": noise, "breath_hold_mm": breath})
    return out


def sa_only_subject(c: dict):
    """(phantom, first-slice offset mm) of a design row: its SA stack starting a seeded
    0.5-10 mm below the base, tags and long-axis views left out."""
    offset = float(np.random.default_rng(c["seed"]).uniform(0.5, 10.0))
    V.phantom_generate.Acquisition = functools.partial(Acquisition, sa_first_offset_mm=offset)
    try:
        ph = generate(c["pathology"], seed=c["seed"], frames=2, noise_px=c["noise_px"],
                      breath_hold_mm=c["breath_hold_mm"], anatomy_model=c["anatomy"])
    finally:
        V.phantom_generate.Acquisition = Acquisition
    ph.study.tags = []
    V._sa_only(ph.study)
    return ph, offset


def measure(c: dict) -> list[dict]:
    """The subject's errors under both rules."""
    ph, _ = sa_only_subject(c)
    t, out = ph.truth["metrics"], []
    try:
        for rule, fn in (("before", lambda study, geo: None), ("after", RULE)):
            M.base_between_slices = fn
            _, m = analyse_study(ph.study)
            out.append({**c, "rule": rule, "err": {k: m[k] - t[k] for k in KEYS}})
    finally:
        M.base_between_slices = RULE
    return out


def table(rows: list[dict]) -> list[str]:
    """Mean error / mean |error| per anatomy and rule (a group without subjects left out)."""
    g: dict = collections.defaultdict(list)
    for r in rows:
        g[(r["anatomy"], r["rule"])].append(r["err"])
    out = ["| anatomy (subjects) | rule | " + " | ".join(KEYS) + " |", "|---|---|" + "---|" * len(KEYS)]
    for anat in ("ideal", "realistic"):
        for rule in ("before", "after"):
            es = g[(anat, rule)]
            if not es:
                continue
            cells = [f"{np.mean([e[k] for e in es]):+.2f} / {np.mean([abs(e[k]) for e in es]):.2f}"
                     for k in KEYS]
            out.append(f"| {anat} ({len(es)}) | {rule} | " + " | ".join(cells) + " |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed0", type=int)
    ap.add_argument("--extra", action="store_true")
    ap.add_argument("--table", nargs="+")
    a = ap.parse_args(argv)
    if a.table:
        print("\n".join(table([json.loads(line) for f in a.table for line in open(f)])))
        return 0
    for c in subjects(None if a.extra else a.seed0):
        for r in measure(c):
            print(json.dumps(r), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
