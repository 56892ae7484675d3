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
    "- LV: every LV volume within 0.5 %, LVEF within 0.2 points, LVM within 0.2 % with the "
    "tracts. LVESV once read +3.5 % (phtn seed 0) and +1.8 % (normal seed 2): the phantom's "
    "3-chamber LV endocardial contour joined a short piece of LVOT septal wall (cut off from the "
    "ventricle's wall by the LVOT cylinder) to the mitral hinge by a spline across the aortic "
    "valve, 10-20 mm off every boundary of the phantom's own cavity; the reconstruction took that "
    "arc as LVOT wall and built the end-systolic LVOT 2.3 times too large. The phantom's open "
    "contour is now the longest wall run only (tests/test_outflow_reconstruction.py checks every "
    "LV LA point on its region's boundary); the LVOT lumen at ES is within 0.25 mL of the truth.",
    "- RV volumes: RVEDV within 0.5 %, RVESV within 1.6 % on every subject (bound 2 %). RVESV once "
    "read -3.7 % (phtn seed 2) and -2.3 % (normal seed 2): with one outlet contour at ES the RVOT "
    "below it was that contour moved along the stacking direction, while the tract widens into "
    "the RV body there; the moved contour is now stretched through the tract's LA crossings every "
    "2 mm. mr seed 2 read -2.8 % (the lofted RV endocardium folded between its last two SA "
    "sections, 1 mm from the apex at ES); it reads -1.3 % since the RV sections are resampled "
    "after the septal move.",
    "- The tract alone against the whole: our RVOT reads 0.7-2.3 mL (ED) and 0.3-1.4 mL (ES) "
    "below the phantom's tract while the whole RV cavity stays within the figures above. Since "
    "the phantoms' tricuspid annulus is saddle-shaped (the realistic default), the phantom's "
    "tract begins at the annulus' best-fit plane and ours beyond the RV body's valve plane, so "
    "the two split the same cavity at different heights; before the saddle the RVOT at ES was "
    "within 0.7 mL on every subject. The split, not the total, differs; this reading of the "
    "cause is not separately measured.",
    "- RVM: the RVOT free wall was the lumen widened by one median thickness all round (RVM "
    "+1.5 to +3.3 %): the tract's septal side, where the RV epicardial contours run on the "
    "lumen's wall, gained a wall no contour shows. It is now widened position by position by the "
    "local thickness of the epicardial points: RVM -3.2 to +0.3 %, within 2 % on 12 of 15 "
    "subjects (not met on phtn seeds 2, 3, 4: -3.2, -2.3, -2.2 %; our RVOT wall reads 0.1-2.1 mL "
    "thinner than the phantom's, whose side walls at the crescent's tips no contour shows).",
    "- Quality flags: none on 12 of 15 noise-free subjects with tracts (before the RVOT work: every "
    "one, LV endo up to 19 mm, RV up to 8 mm). The RVOT valve section is the spline through the "
    "pulmonary annulus points (the least-squares circle of a crescent annulus missed the points "
    "and the la_rvot contour ends by up to 4.5 mm). Left: RV epi fit max 3.6-3.9 mm (3.1-3.3 px) "
    "at ED on mr seed 2, phtn seeds 1 and 4; on the first two these are la_rvot free-wall points "
    "8-12 mm beyond the tricuspid plane between the two outlet contours, where the tube is ruled "
    "between contours 10 mm apart and the wall curves (phtn seed 4 not yet located).",
    "- Without the tracts the reconstruction is untouched by these changes (no tract is built "
    "without outflow evidence, and phantoms without tracts generate the same contours).",
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
