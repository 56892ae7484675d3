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

``--sections`` measures instead the fit the reconstruction uses for the
sections of one surface (they must share a knot vector, §3.2.4), on every
surface at ED and ES of three 2-frame phantoms (normal, mr, phtn, seed 0),
bivme-patient1 and the Sunnybrook studies: the path of
:func:`cardionurbs.nurbs.fit_compatible_curves` (eq. 9 knots on averaged
chord-length parameters, true closest-point distance) against the earlier
private loop of ``anatomy/surfaces.fit_sections`` (uniform knots, each
section by ``fit_curve(n_ctrl=...)``, distance to a 400-point sampling),
reproduced here as the baseline. Both grow the common count through
12, 16, 20, 26, 32, 40, 52 until every contour point is within 1 pixel.
The result replaces the block between the ``sections`` markers of the report.
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
    ap.add_argument("--sections", action="store_true",
                    help="measure the reconstruction's section fits (see module doc)")
    args = ap.parse_args()
    if args.sections:
        _replace_block(Path(args.out), sections_study())
        return
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
    out = Path(args.out)
    old = out.read_text() if out.exists() else ""
    kept = old[old.index(BEGIN) + len(BEGIN):old.index(END)] if BEGIN in old and END in old else ""
    write_text(out, report(rows, args, t_variant))
    if kept.strip():                # the --sections block is measured separately: keep it
        _replace_block(out, kept.strip("\n"))
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


BEGIN, END = "<!-- sections:begin -->", "<!-- sections:end -->"


def _replace_block(path: Path, block: str) -> None:
    """Put ``block`` between the sections markers of ``path`` (appended when absent)."""
    text = path.read_text() if path.exists() else ""
    if BEGIN in text and END in text:
        text = text[:text.index(BEGIN)] + text[text.index(END) + len(END):].lstrip("\n")
    write_text(path, text.rstrip("\n") + "\n\n" + BEGIN + "\n" + block.rstrip("\n") + "\n" + END + "\n")


def _sampled_distance(curve: nurbs.NurbsCurve, points: np.ndarray, n_eval: int = 400) -> np.ndarray:
    """The baseline's error measure: distance to the nearest segment of a 400-point sampling."""
    from scipy.spatial import cKDTree
    c = curve.evaluate(np.linspace(0.0, 1.0, n_eval))
    _, k = cKDTree(c).query(points)
    best = np.full(len(points), np.inf)
    for off in (-1, 0):
        a, b = c[np.clip(k + off, 0, n_eval - 1)], c[np.clip(k + off + 1, 0, n_eval - 1)]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", points - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0, 1)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


def baseline_fit(loops, sources, tols, steps):
    """The earlier private loop (uniform knots, sampled distance), for comparison only."""
    need, ok_all, tried = 0, True, {}
    for i, (lp, src, tol) in enumerate(zip(loops, sources, tols)):
        if src is None:
            continue
        for k in range(need, len(steps)):
            c = nurbs.fit_curve(lp, degree=3, closed=True, n_ctrl=steps[k], knot_rule="uniform")
            tried[i, k] = c
            if float(_sampled_distance(c, src).max()) <= tol:
                need = k
                break
        else:
            need, ok_all = len(steps) - 1, False
    curves = [tried.get((i, need)) or nurbs.fit_curve(lp, degree=3, closed=True, n_ctrl=steps[need],
                                                      knot_rule="uniform")
              for i, lp in enumerate(loops)]
    return curves, steps[need], ok_all


def _recorded_section_fits() -> list[tuple[str, tuple]]:
    """(study/frame/surface, (loops, sources, tols)) of every surface the reconstruction fits
    at ED and ES (recorded by wrapping the fit the reconstruction calls)."""
    from cardionurbs.anatomy import model as model_mod
    from cardionurbs.anatomy import surfaces
    from cardionurbs.io import load_study
    from cardionurbs.phantom import generate
    real_fit, real_build = nurbs.fit_compatible_curves, model_mod.build_surface
    current: list[str] = [""]
    calls: list = []

    def record(loops, **kw):
        calls.append((current[0], (loops, kw["error_points"], kw["tol"])))
        return real_fit(loops, **kw)

    def build(geo, structure, *a, **kw):
        current[0] = f"frame {geo.frame} {structure}"
        return real_build(geo, structure, *a, **kw)

    studies = [(f"phantom {p}", generate(p, seed=0, frames=2, volume_check=False).study)
               for p in ("normal", "mr", "phtn")]
    data = ROOT.parent / "shared" / "data"
    for path in [data / "bivme-patient1", *sorted((data / "sunnybrook").glob("SC-*"))]:
        if path.exists():
            studies.append((path.name, load_study(path)))
    out = []
    surfaces.nurbs.fit_compatible_curves, model_mod.build_surface = record, build
    try:
        for name, study in studies:
            model = model_mod.reconstruct(study)
            calls.clear()
            for fr in dict.fromkeys((model.ed_frame, model.es_frame)):
                model.meshes(fr)
            out += [(f"{name} {label}", args) for label, args in calls
                    if int(label.split()[1]) in (model.ed_frame, model.es_frame)]
    finally:
        surfaces.nurbs.fit_compatible_curves, model_mod.build_surface = real_fit, real_build
    return out


def sections_study() -> str:
    from cardionurbs.anatomy.surfaces import N_CTRL_STEPS
    rows = []
    t0 = time.perf_counter()
    for label, (loops, sources, tols) in _recorded_section_fits():
        judged = [(i, np.asarray(src, float)) for i, src in enumerate(sources) if src is not None]
        if not judged:
            continue
        old, n_old, ok_old = baseline_fit(loops, sources, tols, N_CTRL_STEPS)
        new = nurbs.fit_compatible_curves(loops, degree=3, closed=True, tol=tols,
                                          error_points=sources, counts=N_CTRL_STEPS)
        err_old = max(max_distance(old[i], src) for i, src in judged)
        rows.append({"surface": label, "sections": len(loops), "old_n": n_old, "new_n": new.n_ctrl,
                     "old_err": err_old, "new_err": new.max_error,
                     "old_ok": all(max_distance(old[i], src) <= tols[i] for i, src in judged),
                     "new_ok": new.met})
    elapsed = time.perf_counter() - t0
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    n = len(rows)
    mean = lambda k: float(np.mean([r[k] for r in rows]))  # noqa: E731
    lines = [
        "## Reconstruction: the sections of one surface on one knot vector (paper §3.2.4)",
        "",
        "Command (from the project root):",
        "",
        "```",
        ".venv/bin/python benchmarks/fitting_study.py --sections",
        "```",
        "",
        f"- Date: {now}; {n} surfaces (every surface at ED and ES of the 2-frame phantoms "
        "normal/mr/phtn seed 0, bivme-patient1 and the Sunnybrook studies); "
        f"{elapsed:.0f} s in all (shared machine).",
        "- Tolerance: 1 pixel of the contour's image (synthetic sections are not judged); "
        f"control-point counts tried: {', '.join(map(str, N_CTRL_STEPS))}.",
        "- **before**: the earlier private loop of `anatomy/surfaces.fit_sections` — uniform "
        "knots, each section fitted alone by `fit_curve(n_ctrl=...)` at its own chord-length "
        "parameters, error measured against a 400-point sampling of the curve.",
        "- **after**: `nurbs.fit_compatible_curves` — eq. 9 knots (periodic form) on the "
        "sections' averaged chord-length parameters, each section fitted at its own chord-length "
        "parameters on it, "
        "error = true closest-point distance.",
        "- Both errors in the table are true closest-point distances (mm).",
        "",
        "| | mean control points | surfaces needing more (after > before) | fewer | max error (mm) | within 1 px |",
        "|---|---:|---:|---:|---:|---:|",
        f"| before | {mean('old_n'):.2f} | | | {max(r['old_err'] for r in rows):.3f} | "
        f"{sum(r['old_ok'] for r in rows)}/{n} |",
        f"| after | {mean('new_n'):.2f} | {sum(r['new_n'] > r['old_n'] for r in rows)} | "
        f"{sum(r['new_n'] < r['old_n'] for r in rows)} | {max(r['new_err'] for r in rows):.3f} | "
        f"{sum(r['new_ok'] for r in rows)}/{n} |",
        "",
        "| surface | sections | control points before | after | max error before (mm) | after (mm) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['surface']} | {r['sections']} | {r['old_n']} | {r['new_n']} | "
                     f"{r['old_err']:.3f} | {r['new_err']:.3f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
