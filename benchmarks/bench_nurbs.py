"""NURBS core speed and accuracy against geomdl, splipy and scipy, side by side.

Run from the project root::

    .venv/bin/python benchmarks/bench_nurbs.py [--repeat 7] [--out reports/benchmark-nurbs.md]

Measures in one run, on the same inputs:

1. tessellation of a 20 x 20 control-point rational cubic surface at 200 x 200
   parameters: ``nurbs.tessellate`` (grid + triangles) and the bare grid
   evaluation, against geomdl (``NURBS.Surface.evaluate`` with sample size
   200) and splipy (``Surface(u, v)`` grid evaluation);
2. fitting a 120-point closed contour (uneven spacing, 0.2 mm noise):
   ``nurbs.fit_curve`` (periodic, 16 control points; and with ``tol``) against
   geomdl ``fitting.approximate_curve`` (16 control points, open curve through
   the repeated first point) and scipy ``make_splprep`` (periodic smoothing
   spline, s = m sigma^2); time and maximum point-to-curve distance (all
   curves measured the same way: distance to a 200 000-point polyline);
3. lofting 8 closed sections of 24 control points: ``nurbs.loft`` (periodic
   sections) against splipy ``surface_factory.loft`` (the same sections as
   clamped curves).

geomdl and splipy are test/benchmark-only oracles; the package never imports
them.  Targets (issue 2): tessellation >= 1000x geomdl and faster than splipy.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # shared 2-core machine: no BLAS threads

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs import nurbs  # noqa: E402
from cardionurbs.io.atomic import write_text  # noqa: E402


def interleaved(fns: dict, repeat: int, slow: dict | None = None) -> dict:
    """Time several functions round-robin (one call each per round) so that all
    see the same machine load; ``slow`` ones run only in the first rounds.
    Returns name -> (median, best, last result)."""
    slow = slow or {}
    results = {k: f() for k, f in fns.items()}            # warm-up
    times: dict = {k: [] for k in fns}
    for r in range(repeat):
        for k, f in fns.items():
            if r >= slow.get(k, repeat):
                continue
            t0 = time.perf_counter()
            results[k] = f()
            times[k].append(time.perf_counter() - t0)
    return {k: (statistics.median(t), min(t), results[k]) for k, t in times.items()}


# ------------------------------------------------------------ 1. tessellation
def test_surface(n: int = 20, p: int = 3) -> nurbs.NurbsSurface:
    rng = np.random.default_rng(2026)
    K = np.concatenate([np.zeros(p), np.linspace(0, 1, n - p + 1), np.ones(p)])
    g = np.linspace(0, 1, n)
    P = np.stack(np.meshgrid(g * 100, g * 100, indexing="ij"), axis=-1)
    P = np.concatenate([P, rng.normal(scale=5.0, size=(n, n, 1))], axis=-1)
    return nurbs.NurbsSurface(p, p, K, K, P, rng.uniform(0.5, 2.0, (n, n)))


def bench_tessellation(repeat: int) -> list[dict]:
    from geomdl import NURBS as GNURBS
    from splipy import BSplineBasis, Surface

    s = test_surface()
    N = 200
    u = np.linspace(0, 1, N)
    nu, nv = s.control_points.shape[:2]
    bu = BSplineBasis(s.degree_u + 1, s.knots_u)
    bv = BSplineBasis(s.degree_v + 1, s.knots_v)
    cp = np.concatenate([s.control_points * s.weights[..., None], s.weights[..., None]], -1)
    ss = Surface(bu, bv, cp.transpose(1, 0, 2).reshape(-1, 4), rational=True)
    g = GNURBS.Surface()
    g.degree_u, g.degree_v = s.degree_u, s.degree_v
    g.ctrlpts_size_u, g.ctrlpts_size_v = nu, nv
    g.ctrlpts = s.control_points.reshape(-1, 3).tolist()
    g.weights = s.weights.ravel().tolist()
    g.knotvector_u, g.knotvector_v = s.knots_u.tolist(), s.knots_v.tolist()
    g.sample_size = N

    def geomdl_eval():
        g.reset(evalpts=True)
        g.evaluate()
        return np.array(g.evalpts)

    res = interleaved({"tess": lambda: nurbs.tessellate(s, N, N),
                       "grid": lambda: s.evaluate(u, u),
                       "splipy": lambda: ss(u, u),
                       "geomdl": geomdl_eval}, repeat, slow={"geomdl": 3})
    grid = res["grid"][2]
    V, F = res["tess"][2]
    rows = [
        dict(lib="cardionurbs `tessellate` (grid + triangles)", median=res["tess"][0],
             best=res["tess"][1], points=V.shape[0], note=f"{F.shape[0]} triangles"),
        dict(lib="cardionurbs `NurbsSurface.evaluate` (grid)", median=res["grid"][0],
             best=res["grid"][1], points=N * N, note=""),
        dict(lib="splipy `Surface(u, v)` (grid)", median=res["splipy"][0], best=res["splipy"][1],
             points=N * N, note=f"max |difference| {np.abs(res['splipy'][2] - grid).max():.1e}"),
        dict(lib="geomdl `NURBS.Surface.evaluate` (sample size 200)", median=res["geomdl"][0],
             best=res["geomdl"][1], points=N * N,
             note=f"max |difference| {np.abs(res['geomdl'][2].reshape(N, N, 3) - grid).max():.1e}"),
    ]
    return rows


# ----------------------------------------------------------------- 2. fitting
def test_contour(m: int = 120, seed: int = 3) -> np.ndarray:
    """An LV-like closed contour (mm), uneven spacing, 0.2 mm noise."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, 2 * np.pi, m))
    r = 25 + 3 * np.cos(2 * t) + 1.5 * np.sin(3 * t)
    pts = np.c_[r * np.cos(t), 0.8 * r * np.sin(t)]
    return pts + rng.normal(scale=0.2, size=pts.shape)


def max_distance_polyline(curve_points: np.ndarray, Q: np.ndarray) -> float:
    return float(cKDTree(curve_points).query(Q)[0].max())


def bench_fitting(repeat: int) -> list[dict]:
    from geomdl import fitting as gfit
    from scipy.interpolate import make_splprep

    Q = test_contour()
    m = Q.shape[0]
    dense = np.linspace(0, 1, 200_001)
    Qc = np.vstack([Q, Q[:1]]).tolist()
    x = np.vstack([Q, Q[:1]]).T
    s_val = m * 0.2 ** 2
    res = interleaved({
        "n16": lambda: nurbs.fit_curve(Q, closed=True, n_ctrl=16),
        "tol": lambda: nurbs.fit_curve(Q, closed=True, tol=0.5),
        "rat": lambda: nurbs.fit_curve(Q, closed=True, n_ctrl=16, rational=True),
        "geomdl": lambda: gfit.approximate_curve(Qc, 3, ctrlpts_size=16),
        "scipy": lambda: make_splprep(x, s=s_val, bc_type="periodic"),
    }, repeat)
    rows = []
    for key, lib, note in (
            ("n16", "cardionurbs `fit_curve(closed=True, n_ctrl=16)`", "periodic, C² at the seam"),
            ("tol", "cardionurbs `fit_curve(closed=True, tol=0.5)`",
             "adds control points until max distance <= 0.5"),
            ("rat", "cardionurbs `fit_curve(closed=True, n_ctrl=16, rational=True)`",
             "weights optimised")):
        med, best, c = res[key]
        rows.append(dict(lib=lib, median=med, best=best, ctrl=c.n_control,
                         err=max_distance_polyline(c.evaluate(dense), Q), note=note))
    med, best, g = res["geomdl"]
    g.delta = 1.0 / 20000
    rows.append(dict(lib="geomdl `fitting.approximate_curve(ctrlpts_size=16)`", median=med,
                     best=best, ctrl=16, err=max_distance_polyline(np.array(g.evalpts), Q),
                     note="open curve through the repeated first point (no periodic fit)"))
    med, best, (spl, _) = res["scipy"]
    n_coef = spl.t.size - spl.k - 1 - spl.k      # distinct periodic coefficients
    rows.append(dict(lib=f"scipy `make_splprep(s={s_val:g}, bc_type='periodic')`", median=med,
                     best=best, ctrl=n_coef, err=max_distance_polyline(np.asarray(spl(dense)).T, Q),
                     note="knots chosen by the smoothing criterion"))
    return rows


# ----------------------------------------------------------------- 3. lofting
def loft_sections(K: int = 8, n_pts: int = 90) -> list[nurbs.NurbsCurve]:
    rng = np.random.default_rng(11)
    out = []
    for k in range(K):
        t = np.linspace(0, 2 * np.pi, n_pts, endpoint=False) + 0.1 * k
        r = 30 - 2.5 * k + 2 * np.cos(2 * t + 0.2 * k)
        pts = np.c_[r * np.cos(t), r * np.sin(t), np.full(n_pts, 10.0 * k)]
        pts[:, :2] += rng.normal(scale=0.1, size=(n_pts, 2))
        out.append(nurbs.fit_curve(pts, closed=True, n_ctrl=24))
    return out


def bench_loft(repeat: int) -> list[dict]:
    from splipy import BSplineBasis, Curve
    from splipy import surface_factory

    sections = loft_sections()
    clamped = [c.to_clamped() for c in sections]

    def sp(c):
        cp = np.column_stack([c.control_points * c.weights[:, None], c.weights])
        return Curve(BSplineBasis(c.degree + 1, c.knots), cp, rational=True)

    sp_curves = [sp(c) for c in clamped]
    res = interleaved({"ours": lambda: nurbs.loft(sections, degree_v=3),
                       "splipy": lambda: surface_factory.loft(sp_curves)}, repeat)
    return [
        dict(lib="cardionurbs `loft` (8 periodic sections, 24 ctrl each)", median=res["ours"][0],
             best=res["ours"][1], net=res["ours"][2].control_points.shape[:2],
             note="orientation, seam alignment, compatibility, paper v parameters"),
        dict(lib="splipy `surface_factory.loft` (same sections, clamped)",
             median=res["splipy"][0], best=res["splipy"][1], net=tuple(res["splipy"][2].shape),
             note="no orientation or seam handling"),
    ]


# ------------------------------------------------------------------- report
def fmt_ms(x: float) -> str:
    return f"{1e3 * x:.3f}" if x < 0.1 else f"{1e3 * x:.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmark-nurbs.md"))
    args = ap.parse_args()
    import geomdl
    import scipy
    import splipy

    tess = bench_tessellation(args.repeat)
    fit = bench_fitting(args.repeat)
    lof = bench_loft(args.repeat)
    ours = tess[0]["best"]
    ours_grid = tess[1]["best"]
    geom = tess[3]["best"]
    spl = tess[2]["best"]
    lines = [
        "# Benchmark: NURBS core (issue 2)",
        "",
        "Command (from the project root):",
        "",
        "```",
        ".venv/bin/python benchmarks/bench_nurbs.py",
        "```",
        "",
        f"- Date: {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- Machine: 2 cores ({platform.processor() or platform.machine()}), shared with other "
        f"jobs; Python {platform.python_version()}, numpy {np.__version__}, scipy "
        f"{scipy.__version__}, geomdl {geomdl.__version__}, splipy {splipy.__version__}; "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')} (for every library).",
        f"- Wall time: median and best of {args.repeat} runs after one warm-up call, one "
        "process; within each table the implementations run round-robin (one call each per "
        "round) so that they share the same machine load (geomdl surface: 3 rounds). Ratios "
        "below use the best times.",
        "",
        "## 1. Tessellation: 20 x 20 rational cubic surface at 200 x 200",
        "",
        "| implementation | median (ms) | best (ms) | points | points/s (best) | note |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for r in tess:
        lines.append(f"| {r['lib']} | {fmt_ms(r['median'])} | {fmt_ms(r['best'])} | {r['points']} | "
                     f"{r['points'] / r['best'] / 1e6:.1f} M | {r['note']} |")
    lines += [
        "",
        f"- `tessellate` (grid + triangles) vs geomdl: **{geom / ours:.0f}x** faster "
        f"(target >= 1000x); grid evaluation alone: {geom / ours_grid:.0f}x.",
        f"- vs splipy grid evaluation: `tessellate` {spl / ours:.2f}x, grid evaluation "
        f"{spl / ours_grid:.2f}x (target: faster than splipy).",
        "",
        "## 2. Fitting a 120-point closed contour",
        "",
        "LV-like contour (radius ~25 mm), uneven spacing, 0.2 mm noise. Max error = largest "
        "distance from a data point to the fitted curve (to a 200 000-point polyline of it, "
        "the same for every library).",
        "",
        "| implementation | median (ms) | best (ms) | control points | max error (mm) | note |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for r in fit:
        lines.append(f"| {r['lib']} | {fmt_ms(r['median'])} | {fmt_ms(r['best'])} | {r['ctrl']} | "
                     f"{r['err']:.3f} | {r['note']} |")
    lines += [
        "",
        "- With `tol`, `fit_curve` tries 4, 5, ... control points (paper §3.2.3) and checks "
        "each fit by the true point-to-curve distance, so it costs about a dozen least-squares "
        "fits; at a fixed count it is the fastest here. geomdl fits an open curve (no "
        "continuity at the seam); scipy chooses its own knots by the smoothing criterion and "
        "ends with more coefficients.",
    ]
    lines += [
        "",
        "## 3. Lofting 8 closed sections",
        "",
        "| implementation | median (ms) | best (ms) | control net | note |",
        "|---|---:|---:|---|---|",
    ]
    for r in lof:
        lines.append(f"| {r['lib']} | {fmt_ms(r['median'])} | {fmt_ms(r['best'])} | "
                     f"{r['net'][0]} x {r['net'][1]} | {r['note']} |")
    lines.append("")
    write_text(args.out, "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
