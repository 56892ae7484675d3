"""Control points needed to fit the Sunnybrook contours within 0.5 pixel.

Run from the project root::

    .venv/bin/python benchmarks/fitting_study.py [--tol 0.5] [--out reports/fitting.md]

For every expert contour of ../shared/data/sunnybrook (inner and outer LV
contours, pixel units, closed), the fewest control points of a closed cubic
NURBS whose maximum point-to-curve distance is <= tol, for:

* uniform knots (``knot_rule="uniform"``);
* the paper's eq. 9 knots, centred form (``knot_rule="eq9"``, the default);
* eq. 9 knots with optimised weights (``fit_curve(..., rational=True)``):
  below the eq. 9 polynomial count, the fewest control points whose fit with
  optimised weights (least squares over log-weights, control points by eq. 10
  inside) still meets tol, found by bisection.

Paper §3.2 (chord-length parameters, eq. 9 knots, eq. 10 least squares; the
closed form is periodic).  The paper claims weights reduce the control points
needed; this measures it.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # small matrices; shared 2-core machine

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs import nurbs  # noqa: E402
from cardionurbs.io.atomic import write_text  # noqa: E402

SUNNYBROOK = ROOT.parent / "shared" / "data" / "sunnybrook"


def max_distance(curve: nurbs.NurbsCurve, Q: np.ndarray) -> float:
    return float(nurbs.closest_points(curve, Q)[1].max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tol", type=float, default=0.5, help="max distance in pixels")
    ap.add_argument("--out", default=str(ROOT / "reports" / "fitting.md"))
    ap.add_argument("--limit", type=int, default=0, help="only the first N contours (0 = all)")
    args = ap.parse_args()
    files = sorted(SUNNYBROOK.glob("*/[io]-contours/*.txt"))
    if args.limit:
        files = files[:args.limit]
    if not files:
        sys.exit(f"no contours under {SUNNYBROOK}")
    rows = []
    t_variant = {"uniform": 0.0, "eq9": 0.0, "weights": 0.0}
    for f in files:
        Q = np.loadtxt(f)
        row = {"file": f"{f.parent.parent.name}/{f.parent.name}/{f.name}", "points": len(Q)}
        for rule in ("uniform", "eq9"):
            t0 = time.perf_counter()
            c = nurbs.fit_curve(Q, closed=True, tol=args.tol, knot_rule=rule)
            t_variant[rule] += time.perf_counter() - t0
            row[rule] = c.n_control
            row[rule + "_err"] = max_distance(c, Q)
        t0 = time.perf_counter()
        c = nurbs.fit_curve(Q, closed=True, tol=args.tol, rational=True)
        t_variant["weights"] += time.perf_counter() - t0
        row["weights"] = c.n_control
        row["weights_err"] = max_distance(c, Q)
        rows.append(row)
        print(f"{row['file']}: m={row['points']} uniform={row['uniform']} eq9={row['eq9']} "
              f"weights={row['weights']}", flush=True)
    write_text(args.out, report(rows, args, t_variant))
    print(f"wrote {args.out}")


def report(rows: list[dict], args: argparse.Namespace, t_variant: dict) -> str:
    cols = ("uniform", "eq9", "weights")
    names = {"uniform": "uniform knots", "eq9": "eq. 9 knots (periodic form)",
             "weights": "eq. 9 + optimised weights"}
    A = {c: np.array([r[c] for r in rows]) for c in cols}
    E = {c: np.array([r[c + "_err"] for r in rows]) for c in cols}
    pts = np.array([r["points"] for r in rows])
    lines = [
        "# Control points needed to fit the Sunnybrook contours (paper §3.2)",
        "",
        "Command (from the project root):",
        "",
        "```",
        f".venv/bin/python benchmarks/fitting_study.py --tol {args.tol}",
        "```",
        "",
        f"- Date: {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- Machine: 2 cores, shared with other jobs; Python {platform.python_version()}, "
        f"numpy {np.__version__}; OPENBLAS_NUM_THREADS=1",
        f"- Data: {len(rows)} expert LV contours (inner and outer) of 3 Sunnybrook patients "
        f"(SC-HF-I-1/2/4), {pts.min()}–{pts.max()} points each (median {int(np.median(pts))}), "
        "pixel units, fitted as closed cubic NURBS (periodic, C² across the seam).",
        f"- Criterion: maximum distance from every contour point to the curve <= {args.tol} px "
        "(true distance by Newton projection); the fewest control points that meet it, adding "
        "one at a time (paper §3.2.3).",
        "- Weighted fits (`fit_curve(..., rational=True)`): below the eq. 9 polynomial count, "
        "the fewest control points whose fit with optimised weights (trust-region least "
        "squares over log-weights in [-3, 3] with the variable-projection Jacobian, control "
        "points by eq. 10 inside, residuals at the chord-length parameters) still meets the "
        "tolerance, found by bisection (assumes more control points never hurt).",
        "",
        "## Summary (distinct control points per contour)",
        "",
        "| knots / weights | mean | median | min | max | total | max distance (px) | fit time, all contours (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in cols:
        lines.append(f"| {names[c]} | {A[c].mean():.2f} | {np.median(A[c]):.0f} | {A[c].min()} | "
                     f"{A[c].max()} | {A[c].sum()} | {E[c].max():.3f} | {t_variant[c]:.1f} |")
    d_u = A["uniform"] - A["eq9"]
    d_w = A["eq9"] - A["weights"]
    lines += [
        "",
        "## Findings",
        "",
        f"- eq. 9 vs uniform knots: eq. 9 needs fewer control points on {np.sum(d_u > 0)} "
        f"contours, the same on {np.sum(d_u == 0)}, more on {np.sum(d_u < 0)} "
        f"(mean difference uniform − eq. 9 = {d_u.mean():+.2f}; totals {A['uniform'].sum()} vs "
        f"{A['eq9'].sum()}). The contours are traced pixel by pixel with nearly even spacing "
        "(chords of 0.5 or 0.71 px), so chord-length parameters are almost uniform and eq. 9 "
        "knots are close to uniform ones: on these data eq. 9 brings no gain. Its guarantee "
        "(every span holds data, so N^T N is positive definite) matters when the sampling "
        "density varies along a contour.",
        "- Periodic form of eq. 9: break j of n sits at the parameter of the fractional data "
        "index j(m+1)/n, so each of the n spans holds (m+1)/n >= 1 parameters; for closed "
        "curves there is no end, so the open-curve choice between the printed index jd − 1 "
        "and the centred jd − ½ (the package default, symmetric under reversal) does not arise.",
        f"- Optimised weights: fewer control points on {np.sum(d_w > 0)} of {len(rows)} "
        f"contours, none on {np.sum(d_w == 0)}; mean saving {d_w.mean():.2f} control points "
        f"per contour, total {A['weights'].sum()} vs {A['eq9'].sum()} "
        f"({100 * (A['weights'].sum() / A['eq9'].sum() - 1):+.0f}%), largest saving "
        f"{d_w.max()} (contour {rows[int(np.argmax(d_w))]['file']}: "
        f"{rows[int(np.argmax(d_w))]['eq9']} -> {rows[int(np.argmax(d_w))]['weights']}). "
        "So the paper's claim holds on these data: weights reduce the control points needed, "
        "most where the tracing has pixel-scale kinks (a one-pixel notch forces small knot "
        "spans everywhere when knots follow the data evenly, while a few large weights pull "
        "the curve into the corner locally). The price is fitting time: "
        f"{t_variant['weights']:.0f} s vs {t_variant['eq9']:.0f} s for all contours "
        "(machine heavily shared during the run, so absolute times are inflated).",
        "",
        "## Per contour",
        "",
        "| contour | points | uniform | eq. 9 | eq. 9 + weights |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['file']} | {r['points']} | {r['uniform']} | {r['eq9']} | "
                     f"{r['weights']} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
