"""SA-only hand contours: the RV valve plane before and after the untraced-slice rule.

    nice -n 10 python benchmarks/rv_untraced_base.py --seed0 200 > FILE.jsonl   # design rows 1, 7, ..., 55
    nice -n 10 python benchmarks/rv_untraced_base.py --seed0 5000 > FILE.jsonl
    nice -n 10 python benchmarks/rv_untraced_base.py --extra > FILE.jsonl        # normal/PHTN, noise, breath-hold
    nice -n 10 python benchmarks/rv_untraced_base.py --subject 203:normal:realistic > FILE.jsonl
    python benchmarks/rv_untraced_base.py --table FILE.jsonl ...                  # the markdown tables

Each subject is built as benchmarks/validate_uncertainty.py builds it (its SA-only rows;
benchmarks/sa_only_base.py's builder: 2 frames, the first SA slice uniform over one gap below
the base, drawn from the seed, the long-axis views and every landmark dropped) and analysed
twice: with :func:`cardionurbs.anatomy.model.rv_untraced_basal_level` made to return None
(before: the RV's half-slice plane half-way to the next imaged SA plane even when that plane
carries an LV contour but no RV one) and as it is (after: the RV closed half-way beyond that
plane). One JSON line per subject and rule: the errors against the phantom's analytic truth,
and whether the rule fired at ED / ES.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import sa_only_base as B  # noqa: E402

from cardionurbs.anatomy import model as M  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

KEYS = B.KEYS
RULE = M.rv_untraced_basal_level


def measure(c: dict) -> list[dict]:
    """The subject's errors under both rules (and where the rule fires)."""
    ph, offset = B.sa_only_subject(c)
    t, out = ph.truth["metrics"], []
    try:
        for rule, fn in (("before", lambda study, geo: None), ("after", RULE)):
            M.rv_untraced_basal_level = fn
            model, m = analyse_study(ph.study)
            fired = [RULE(ph.study, model.own_geometry[f]) is not None for f in model.frames]
            out.append({**c, "offset": offset, "rule": rule, "fired": fired,
                        "err": {k: m[k] - t[k] for k in KEYS}})
    finally:
        M.rv_untraced_basal_level = RULE
    return out


def table(rows: list[dict]) -> list[str]:
    """Mean error / mean |error| per anatomy and rule, then every subject the rule reaches."""
    out = B.table(rows)
    out += ["", "Every subject (error before -> after; fired: the rule at ED / ES):", "",
            "| seed | pathology | anatomy | noise px | breath mm | fired | RVEDV (mL) | RVESV (mL) | RVEF (%) |",
            "|---|---|---|---|---|---|---|---|---|"]
    pairs: dict = collections.defaultdict(dict)
    for r in rows:
        pairs[(r["seed"], r["pathology"], r["anatomy"])][r["rule"]] = r
    for (seed, path, anat), p in sorted(pairs.items()):
        if not {"before", "after"} <= set(p):
            continue
        b, a = p["before"], p["after"]
        fired = " / ".join("yes" if x else "-" for x in a["fired"])
        cells = [f"{b['err'][k]:+.1f} -> {a['err'][k]:+.1f}" for k in KEYS[4:]]
        out.append(f"| {seed} | {path} | {anat} | {a['noise_px']:g} | {a['breath_hold_mm']:g} | "
                   f"{fired} | " + " | ".join(cells) + " |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed0", type=int)
    ap.add_argument("--extra", action="store_true")
    ap.add_argument("--subject", action="append", default=[], metavar="SEED:PATHOLOGY:ANATOMY",
                    help="a noise-free subject of one's own choosing instead (repeatable)")
    ap.add_argument("--table", nargs="+")
    a = ap.parse_args(argv)
    if a.table:
        print("\n".join(table([json.loads(line) for f in a.table for line in open(f)])))
        return 0
    todo = [{"seed": int(seed), "input": "contours SA-only", "pathology": path, "anatomy": anat,
             "noise_px": 0.0, "breath_hold_mm": 0.0}
            for seed, path, anat in (x.split(":") for x in a.subject)]
    for c in todo or B.subjects(None if a.extra else a.seed0):
        for r in measure(c):
            print(json.dumps(r), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
