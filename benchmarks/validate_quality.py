"""Quality flags on the paper's 12-subject phantom cohort and on bivme-patient1.

    python -m cardionurbs.cli demo --out DEMO --jobs 1
    python benchmarks/validate_quality.py DEMO        # -> reports/validation-quality.md

Reads the demo's cohort.csv (the quality columns of every subject) and analyses
bivme-patient1; checks that no metric is unflagged while a surface it uses has a
contour point beyond 3 px of it, and that the noise-free phantoms raise no flag.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT))

from cardionurbs import load_study, measure, reconstruct  # noqa: E402
from cardionurbs.analysis.quality import QC_LIMIT_PX, assess  # noqa: E402

SURFACES = ("LV endo", "LV epi", "RV endo", "RV epi")


def cohort_rows(csv: Path) -> list[str]:
    d = pd.read_csv(csv, keep_default_na=False, na_values=[""])
    out = ["| subject | status | " + " | ".join(f"{s} fit median / p95 / max (px)" for s in SURFACES)
           + " | left out | QC |", "|---" * (len(SURFACES) + 4) + "|"]
    for _, r in d.iterrows():
        cells = [f"{r[f'{s} fit median (px)']:.2f} / {r[f'{s} fit p95 (px)']:.2f} / "
                 f"{r[f'{s} fit max (px)']:.2f}" for s in SURFACES]
        qc = r["QC"] if isinstance(r["QC"], str) else ""
        lo = r["left out"] if isinstance(r["left out"], str) else ""
        out.append(f"| {r['subject']} | {r['status']} | " + " | ".join(cells) + f" | {lo} | {qc} |")
    worst = max(float(d[f"{s} fit max (px)"].max()) for s in SURFACES)
    flagged = int(d["QC"].fillna("").astype(str).str.len().gt(0).sum())
    return out + ["", f"Largest contour-point distance of any surface in the cohort: {worst:.2f} px "
                  f"(limit {QC_LIMIT_PX:g} px); subjects with a flag: {flagged} of {len(d)}."]


def bivme_rows() -> list[str]:
    p = DATA / "bivme-patient1"
    if not p.exists():
        return ["(bivme-patient1 absent: ../shared/data)"]
    model = reconstruct(load_study(p))
    metrics = measure(model)
    q = assess(model, metrics)
    pts = model.point_residuals()
    out = ["| metric | value | surfaces (frames) | point beyond 3 px | flags |", "|---|---|---|---|---|"]
    bad = 0
    for col, e in q.metrics.items():
        v = metrics[col]
        if not e["surfaces"]:
            if e["flags"]:
                out.append(f"| {col} | {v:.4g} | | | {'; '.join(e['flags'])} |")
            continue
        sel = pts["structure"].isin(e["surfaces"]) & pts["frame"].isin(e["frames"])
        beyond = bool((pts.loc[sel, "dist_px"] > QC_LIMIT_PX).any())
        bad += int(beyond and not e["flags"] and v == v)
        out.append(f"| {col} | {v:.4g} | {', '.join(e['surfaces'])} ({', '.join(map(str, e['frames']))}) "
                   f"| {'yes' if beyond else 'no'} | {'; '.join(e['flags'])} |")
    return out + ["", f"Metrics unflagged although a surface they use has a point beyond 3 px: {bad}."]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("demo", type=Path, help="output folder of `cardionurbs demo`")
    a = ap.parse_args()
    lines = ["# Validation: quality flags", "", "```",
             "python -m cardionurbs.cli demo --out DEMO --jobs 1",
             "python benchmarks/validate_quality.py DEMO", "```", "",
             f"- date: {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC", "",
             "## The paper's 12 phantom subjects (noise-free contours, 20 frames)", "",
             "Residuals over ED and ES (pixels), contours left out and QC of every cohort row.", ""]
    lines += cohort_rows(a.demo / "cohort.csv")
    lines += ["", "## bivme-patient1", "",
              "Each metric, the surfaces and frames it comes from, whether one of their contour points "
              "lies beyond 3 px (computed from the point residuals, independently of the flags), and "
              "its flags.", ""]
    lines += bivme_rows()
    out = ROOT / "reports" / "validation-quality.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
