"""Which choosing rule carries to subjects it did not see? A nested check of
``validate_uncertainty.py --min-inside``: the constants are chosen on the other folds by
each rule (a target share of the train subjects inside for each of the six, every input kind at
least ``--kind-floor``), fold by fold: each ``--fold`` is the test set of the constants chosen on
the others, and the pooled out-of-fold coverage says how the rule carries.
Used to fix the rule before a fresh held-out run (reports/validation-uncertainty.md).

    python benchmarks/uncertainty_rule_check.py --fold A=a1.jsonl,a2.jsonl --fold B=b.jsonl \
        --fold C=c.jsonl --targets 0.94 0.95 --kind-floor 0.9
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import validate_uncertainty as V  # noqa: E402


def kind_floor_row(rows: list[dict], consts: dict) -> str:
    """The lowest coverage (%) of any input kind, over the six, under ``consts``."""
    kinds = sorted({V.INPUT_KIND[r["input"]] for r in rows})
    low = 100.0
    for k in kinds:
        ins, n, _ = V.inside_counts([r for r in rows if V.INPUT_KIND[r["input"]] == k], consts)
        low = min(low, float(np.min(100.0 * ins / np.maximum(n, 1))))
    return f"{low:.1f}"


def _read(files: str) -> list[dict]:
    return [r for f in files.split(",") for r in V._read_raw(Path(f))]


def _pct(ins: np.ndarray, n: np.ndarray) -> str:
    return " / ".join(f"{100 * i / k:.1f}" for i, k in zip(ins, n))


def margin(ins: np.ndarray, n: np.ndarray) -> float:
    """The smallest distance (points) of the six coverages to the 90-98 % band's edges
    (negative: outside)."""
    cov = 100.0 * ins / n
    return float(np.min(np.minimum(cov - 90.0, 98.0 - cov)))


def check_target(folds: dict[str, list[dict]], target: float, floor: float) -> list[str]:
    """One target's rows: each fold chosen on the others and tested, then the pooled
    out-of-fold coverage."""
    out, pooled_i, pooled_n = [], 0, 0
    for name, test in folds.items():
        train = [r for k, rows in folds.items() if k != name for r in rows]
        n_min = math.ceil(target * len(train) - 1e-9)
        consts, _ = V.choose_min_inside(train, n_min, True, floor)
        tr, tn, _ = V.inside_counts(train, consts)
        te, en, w = V.inside_counts(test, consts)
        pooled_i, pooled_n = pooled_i + te, pooled_n + en
        band = int(sum(0.9 * k <= i <= 0.98 * k for i, k in zip(te, en)))
        out.append(f"| {target:g} | {name} ({len(test)}) | {n_min} of {len(train)} | "
                   f"{_pct(tr, tn)} | {_pct(te, en)} | {band} of 6 | "
                   f"{kind_floor_row(test, consts)} | {100 * w:.2f} % |")
        print(out[-1], flush=True)
        print("    constants: " + ", ".join(f"{k}={v:g}" for k, v in consts.items()), flush=True)
    out.append(f"| {target:g} | **pooled out-of-fold** | | | {_pct(pooled_i, pooled_n)} | "
               f"margin {margin(pooled_i, pooled_n):+.2f} | | |")
    print(out[-1], flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fold", action="append", required=True,
                    help="NAME=FILE[,FILE...]: one fold's --raw files (repeat, at least two)")
    ap.add_argument("--targets", type=float, nargs="+", default=[0.95])
    ap.add_argument("--kind-floor", type=float, default=0.9)
    a = ap.parse_args(argv)
    folds = {f.split("=", 1)[0]: _read(f.split("=", 1)[1]) for f in a.fold}
    rows = [r for fold in folds.values() for r in fold]
    # the settings are rescaled from the run's constants (its OUTFLOW_SHARE kept: exact)
    if len({tuple(sorted(V.run_constants(r).items())) for r in rows}) != 1:
        raise SystemExit("every subject must carry the same run_constants (one code version)")
    V.RUN_CONSTANTS.update(V.run_constants(rows[0]))
    print(f"{len(rows)} subjects in {len(folds)} folds; kind floor {a.kind_floor}\n")
    print("| target | test fold | min inside (train) | train % of the six | test % of the six "
          "| test in 90-98 % | test lowest kind % | test mean half-width / value |")
    print("|---|---|---|---|---|---|---|---|", flush=True)
    for target in a.targets:
        check_target(folds, target, a.kind_floor)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
