"""Speed of the tag analysis; writes reports/benchmark-tags.md.

Run from the repository root::

    .venv/bin/python benchmarks/bench_tags.py [--repeat 7]

Measured side by side on one 2-frame phantom (normal, seed 0: two SA
families of ~12 tags crossing the LV on 7-9 SA slices, and the LA family
on 3 views):

- tag surfaces of ED and ES (fits + lofts), material points, and the full
  ``tag_metrics`` (surfaces + material points + metrics + Twist 2D), the
  issue's < 0.5 s figure;
- the tag-jump QC of both frames;
- the building blocks against the per-item NURBS-module calls they replace:
  batched line fits vs one ``nurbs.fit_curve`` per line, the compatible-
  section loft vs ``nurbs.loft``, batched surface evaluation in Newton vs
  ``NurbsSurface.derivatives`` per surface.

Times are the minimum and median of ``--repeat`` runs (wall clock, the
machine is shared by several engineers, so the minimum is the fairest).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs import nurbs  # noqa: E402
from cardionurbs.analysis.material import SurfaceBatch, material_points  # noqa: E402
from cardionurbs.analysis.tag_surfaces import (build_tag_surfaces, control_count,  # noqa: E402
                                               fit_tag_curves, loft_compatible)
from cardionurbs.analysis.tagqc import tag_qc  # noqa: E402
from cardionurbs.analysis.tags import tag_metrics  # noqa: E402
from cardionurbs.anatomy.sections import study_long_axis  # noqa: E402
from cardionurbs.io import atomic  # noqa: E402
from cardionurbs.phantom import generate  # noqa: E402


def timed(fn, repeat: int) -> tuple[float, float]:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), statistics.median(ts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmark-tags.md"))
    args = ap.parse_args(argv)
    ph = generate("normal", seed=0, frames=2, volume_check=False)
    st, es = ph.study, ph.truth["es_frame"]
    axis = study_long_axis(st, 0)
    n_lines = len(st.tags)
    per_fam = {f: len({t.index for t in st.tags if t.family == f}) for f in ("sa1", "sa2", "la")}
    rows = []

    def add(name, fn, note=""):
        lo, med = timed(fn, args.repeat)
        rows.append((name, lo, med, note))

    add("tag surfaces, ED + ES", lambda: [build_tag_surfaces(st, f, axis) for f in (0, es)],
        "fits + lofts of every tag")
    surfs = {f: build_tag_surfaces(st, f, axis) for f in (0, es)}
    add("material points, ED + ES (surfaces given)",
        lambda: material_points(st, 0, es, frames=[0, es], long_axis=axis, surfaces=surfs),
        "plane start, batched Newton, myocardium test")
    add("**tag_metrics: surfaces + material points + metrics + Twist 2D**",
        lambda: tag_metrics(st, 0, es, qc=False), "the issue's < 0.5 s figure")
    add("tag-jump QC, 2 frames", lambda: tag_qc(st), "leave-one-out, every line")
    add("tag_metrics with QC", lambda: tag_metrics(st, 0, es, qc=True), "")

    # building blocks vs the NURBS module's per-item calls
    lines = [t.points for t in st.tags if t.family != "la"]
    n = control_count(lines)
    add(f"fit {len(lines)} SA lines, batched (fit_tag_curves)", lambda: fit_tag_curves(lines, n), "")
    add(f"fit {len(lines)} SA lines, one nurbs.fit_curve each",
        lambda: [nurbs.fit_curve(p, degree=3, n_ctrl=min(n, len(p)), knot_rule="uniform")
                 if len(p) >= 4 else None for p in lines], "")
    secs = [ts.sections for k, ts in surfs[es].items() if k[0] != "la"]
    add(f"loft {len(secs)} SA tag surfaces, loft_compatible",
        lambda: [loft_compatible(np.array([s.ctrl for s in ss]), ss[0].knots) for ss in secs], "")
    add(f"loft {len(secs)} SA tag surfaces, nurbs.loft",
        lambda: [nurbs.loft([s.curve for s in ss]) for ss in secs], "")
    sl = [ts.surface for k, ts in surfs[es].items() if k[0] == "sa1"]
    rng = np.random.default_rng(0)
    sid = rng.integers(0, len(sl), 1500)
    u, v = rng.uniform(0, 1, 1500), rng.uniform(0, 1, 1500)
    batch = SurfaceBatch(sl)
    add("1500 surface derivatives, SurfaceBatch", lambda: batch.derivatives(sid, u, v), "")
    add("1500 surface derivatives, NurbsSurface.derivatives per surface",
        lambda: [sl[k].derivatives(u[sid == k], v[sid == k], 1) for k in range(len(sl))], "")

    cmd = "python benchmarks/bench_tags.py " + " ".join(sys.argv[1:] if argv is None else argv)
    out = ["# Tag analysis benchmark", "",
           f"Command: `{cmd.strip()}`  ",
           f"Date: {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC  ",
           f"Machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs, "
           f"Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}", "",
           f"Study: 2-frame phantom `normal` seed 0: {n_lines} tag lines; tags crossing the LV: "
           f"sa1 {per_fam['sa1']}, sa2 {per_fam['sa2']}, la {per_fam['la']}. "
           f"{args.repeat} runs each.", "",
           "| step | min (s) | median (s) | note |", "|---|---|---|---|"]
    out += [f"| {name} | {lo:.3f} | {med:.3f} | {note} |" for name, lo, med, note in rows]
    out += ["", "Target: tag surfaces + material points + tag metrics of a 2-frame phantom < 0.5 s "
            "(the bold row). The QC is reported separately (its cost grows with the number of "
            "tagged frames; a 20-frame phantom takes about ten times the 2-frame figure)."]
    p = Path(args.out)
    p.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(p, "\n".join(out) + "\n")
    os.chmod(p, 0o644)
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
