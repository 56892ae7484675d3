"""Outflow tracts: the reconstruction against the realistic phantom's truth, with and without
its outflow tracts (same seeds), and what the tracts add.

    OPENBLAS_NUM_THREADS=1 python benchmarks/validate_outflow.py [--jobs 2] [--subjects 3]
        -> reports/validation-outflow.md (+ reports/figures/validation/outflow_phantom.png)

Per preset (normal, mr, phtn) and seed: the noise-free realistic phantom generated with
``outflow=True`` (RVOT to a pulmonary valve, LVOT to an aortic valve; truth by the
convention of docs/metrics.md) and with ``outflow=False``; our metrics against each truth
(relative error for volumes and masses, points for EF); the RVOT and LVOT lumen volumes our
reconstruction adds at ED against the phantom's tract volumes; the quality flags raised.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _accuracy import metric_error  # noqa: E402

COLS = ("LVEDV (mL)", "LVESV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVESV (mL)",
        "RVEF (%)", "RVM (g)")
PRESETS = ("normal", "mr", "phtn")
COMMAND = "OPENBLAS_NUM_THREADS=1 python benchmarks/validate_outflow.py --jobs 2 --subjects 5"


FINDINGS = [
    "- RV: RVEDV within 1 % of the truth on every subject (tracts included), the RVOT lumen "
    "within 5 % of the phantom's (lofted through the rv_outlet contours). RVESV within 1 % but "
    "on two subjects (-2.3 %, -3.7 %), against at most -1.7 % for the same seeds without tracts: "
    "not explained yet.",
    "- LV: LVEDV within 0.7 %, the LVOT lumen within 12 % of the phantom's (a small volume: "
    "circular sections from one 3-chamber wall and the aortic annulus). LVESV within 0.6 % but "
    "on two subjects (+1.8 %, +3.5 %): on phtn seed 0 the phantom's LVOT lumen shrinks from "
    "3.4 mL at ED to 1.5 mL at ES (the tract contracts with the LV cavity), while the tube we "
    "build at ES holds 3.4 mL (trimmed solid): the ES tube's sections are too wide, the "
    "difference (+1.8 mL) is the LVESV error. Not fixed yet.",
    "- LVM within 0.5 %: the LV myocardium does not involve the tracts (the same construction "
    "with and without them). The phantom's truth once subtracted the LVOT lumen from the wall "
    "(LVM then read 2.6-4.1 % high here); fixed in the truth.",
    "- Quality flags are raised on every phantom with tracts (none without): LV endocardial "
    "3-chamber points that run up the aortic root 15-20 mm from any surface we build, and RV "
    "LA points 4-6 mm from the RV surfaces. The target 'no flag on noise-free phantoms' is not "
    "met with outflow tracts.",
]


def subject(args) -> dict:
    pathology, seed, outflow = args
    from cardionurbs.analysis.function import measure
    from cardionurbs.analysis.quality import assess
    from cardionurbs.anatomy.mesh import volume_ml
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.phantom import truth_realistic as trr
    from cardionurbs.phantom.generate import generate
    from cardionurbs.errors import PhantomError
    try:
        ph = generate(pathology, seed=seed, frames=2, anatomy_model="realistic", outflow=outflow,
                      volume_check=False)
    except PhantomError as exc:      # a draw the phantom rejects: reported, not measured
        return {"pathology": pathology, "seed": seed, "outflow": outflow, "failed": str(exc)}
    st = ph.study
    st.tags = []
    t0 = time.perf_counter()
    m = reconstruct(st)
    got = measure(m)
    secs = time.perf_counter() - t0
    truth = ph.truth["metrics"]
    out = {"pathology": pathology, "seed": seed, "outflow": outflow, "seconds": secs,
           "err": {c: metric_error(c, got[c], truth[c]) for c in COLS},
           "flags": [f for f in assess(m, got).flags if "heart rate" not in f]}
    if outflow:
        out["tracts"] = {}
        for which, frame in (("ED", m.ed_frame), ("ES", m.es_frame)):
            f = float(ph.phases[frame])
            tract = trr._outflow_section_volumes(ph.anatomy, ph.motion, f,
                                                 trr.valve_planes(ph.anatomy, ph.motion, f), 96)
            for s in ("rv_endo", "lv_endo"):
                part = m._tract_part(frame, s)
                out["tracts"][(which, s)] = (tract.get(s, float("nan")),
                                             0.0 if part is None else volume_ml(part))
            if which == "ED":       # the RVOT free wall: the RV myocardium beyond the tricuspid plane
                b = m.geometry[frame].base_planes["rv"]
                beyond = m.solids(frame)["rv_myocardium"].trim_by_plane(
                    -b.normal, -float(b.origin @ b.normal))
                out["tracts"][("ED", "wall")] = (tract["rv_epi"] - tract["rv_endo"],
                                                 volume_ml(beyond))
    return out


def table(rows: list[dict], outflow: bool) -> list[str]:
    sel = [r for r in rows if r["outflow"] == outflow]
    lines = ["| subject | " + " | ".join(COLS) + " | flags |", "|---" * (len(COLS) + 2) + "|"]
    for r in sel:
        cells = [f"{r['err'][c]:+.2f}" for c in COLS]
        lines.append(f"| {r['pathology']} seed {r['seed']} | " + " | ".join(cells)
                     + f" | {'; '.join(r['flags']) or 'none'} |")
    worst = [max(abs(r["err"][c]) for r in sel) for c in COLS]
    lines.append("| **largest** | " + " | ".join(f"**{w:.2f}**" for w in worst) + " | |")
    return lines


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 3.8))
    x = np.arange(len(COLS))
    for k, outflow in enumerate((False, True)):
        sel = [r for r in rows if r["outflow"] == outflow]
        for j, r in enumerate(sel):
            ax.scatter(x + (k - 0.5) * 0.3, [r["err"][c] for c in COLS], s=14,
                       color="tab:orange" if outflow else "tab:blue",
                       label=("with outflow tracts" if outflow else "without") if j == 0 else None)
    ax.axhline(0, color="k", lw=0.6)
    for b in (-2, 2):
        ax.axhline(b, color="grey", ls="--", lw=0.6)
    ax.set_xticks(x, [c.replace(" (mL)", "").replace(" (g)", "").replace(" (%)", "") for c in COLS])
    ax.set_ylabel("error (% ; EF: points)")
    ax.set_title("Noise-free realistic phantoms: reconstruction against truth")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--subjects", type=int, default=3, help="seeds per preset")
    a = ap.parse_args()
    jobs = [(p, s, o) for p in PRESETS for s in range(a.subjects) for o in (True, False)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        rows = list(ex.map(subject, jobs))
    wall = time.perf_counter() - t0
    failed = [r for r in rows if "failed" in r]
    bad = {(r["pathology"], r["seed"]) for r in failed}
    rows = [r for r in rows if (r["pathology"], r["seed"]) not in bad]
    fig = "figures/validation/outflow_phantom.png"
    figure(rows, ROOT / "reports" / fig)
    lines = ["# Outflow tracts on realistic phantoms", "", f"Command: `{COMMAND}`", "",
             f"{len(rows)} reconstructions in {wall:.0f} s wall ({os.cpu_count()} cores, shared).",
             "", "Noise-free realistic phantoms (2 frames) with their outflow tracts: the RV "
             "continues beyond the tricuspid plane to the pulmonary valve, the LV beyond the mitral "
             "plane to the aortic valve (docs/metrics.md, Cavities and walls). Errors of our metrics "
             "against the phantom's truth (%; EF in points); `flags`: the quality flags raised "
             "(heart rate left out).", "", "## With outflow tracts", ""]
    if failed:
        lines += ["Not measured (the phantom generator rejected the draw; the same seed without "
                  "tracts left out too): " + "; ".join(
                      f"{r['pathology']} seed {r['seed']} outflow={r['outflow']}: {r['failed']}"
                      for r in failed) + ".", ""]
    lines += table(rows, True)
    lines += ["", "## The same seeds without outflow tracts", ""]
    lines += table(rows, False)
    lines += ["", f"![errors with and without outflow tracts]({fig})", "",
              "## Tracts at ED and ES: phantom truth against what the reconstruction adds", "",
              "The reconstruction's tract is the part beyond the body's valve plane (the RV "
              "body and the LV body are bounded by their surfaces below it; the tube alone, "
              "before the LV epicardium is taken out of the RVOT); the phantom's is its "
              "tract lumen beyond the tricuspid / mitral plane. RVOT wall: the phantom's RVOT "
              "free wall against our RV myocardium beyond the tricuspid plane, at ED. Each cell "
              "truth / ours (mL).", "",
              "| subject | RVOT ED | RVOT ES | LVOT ED | LVOT ES | RVOT wall ED |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        if r["outflow"]:
            t = r["tracts"]
            cells = [t[k] for k in (("ED", "rv_endo"), ("ES", "rv_endo"), ("ED", "lv_endo"),
                                    ("ES", "lv_endo"), ("ED", "wall"))]
            lines.append(f"| {r['pathology']} seed {r['seed']} | "
                         + " | ".join(f"{a:.2f} / {b:.2f}" for a, b in cells) + " |")
    lines += ["", "## Reading", "", *FINDINGS]
    (ROOT / "reports" / "validation-outflow.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
