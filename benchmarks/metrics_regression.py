"""Before/after check of the analyze speed-ups: the metrics of a set of studies must not move.

    python benchmarks/metrics_regression.py record BASELINE.json STUDY...   # before a change
    python benchmarks/metrics_regression.py compare BASELINE.json            # after it

``compare`` re-measures every study recorded in the baseline (same paths) and exits 1
when any metric differs by more than 1e-6 relative (NaN must stay NaN).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

REL_TOL = 1e-6


def measure(path: str) -> dict:
    _, m = analyse_study(load_study(path))
    return {k: (None if isinstance(v, float) and math.isnan(v) else float(v)) for k, v in m.items()}


def differences(before: dict, after: dict, rel_tol: float = REL_TOL) -> list[str]:
    """One line per metric whose value moved by more than ``rel_tol`` (relative; absolute
    below 1e-9 in magnitude)."""
    out = []
    for k in sorted(set(before) | set(after)):
        a, b = before.get(k), after.get(k)
        if a is None or b is None:
            if (a is None) != (b is None):
                out.append(f"{k}: {a} -> {b}")
            continue
        if abs(a - b) > rel_tol * max(abs(a), abs(b), 1e-9 / rel_tol):
            out.append(f"{k}: {a!r} -> {b!r} (rel {abs(a - b) / max(abs(a), abs(b)):.2e})")
    return out


def largest_change(before: dict, after: dict) -> float:
    """The largest relative change of any metric (0 when every value is the same)."""
    out = 0.0
    for k in set(before) & set(after):
        a, b = before[k], after[k]
        if a is not None and b is not None and a != b:
            out = max(out, abs(a - b) / max(abs(a), abs(b)))
    return out


def main(argv: list[str]) -> int:
    cmd, baseline = argv[0], Path(argv[1])
    if cmd == "record":
        rec = {}
        for p in argv[2:]:
            t = time.perf_counter()
            rec[p] = measure(p)
            print(f"{p}: {time.perf_counter() - t:.2f} s", file=sys.stderr)
        baseline.write_text(json.dumps(rec, indent=1) + "\n")
        return 0
    rec = json.loads(baseline.read_text())
    bad = 0
    for p, before in rec.items():
        t = time.perf_counter()
        after = measure(p)
        diff = differences(before, after)
        print(f"{p}: {time.perf_counter() - t:.2f} s, {len(before)} metrics, "
              f"{len(diff)} differ beyond {REL_TOL:g} relative (largest relative change "
              f"{largest_change(before, after):.1e})", file=sys.stderr)
        for line in diff:
            print("   ", line, file=sys.stderr)
        bad += bool(diff)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
