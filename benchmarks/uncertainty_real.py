"""The 95 % intervals on real data, beside the field's reference: the ten ACDC patients
(model against voxel counting of the same label maps) and bivme-patient1 (against biv-me).

    nice -n 10 python benchmarks/uncertainty_real.py --out /tmp/real.md

biv-me's figures for bivme-patient1 are those of reports/validation-function.md (biv-me's
ED frame 24 and ES frame 9; ours may pick another ES frame, as that report says).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT))

from cardionurbs.analysis.uncertainty import intervals  # noqa: E402
from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

ACDC = ("LVEDV (mL)", "LVESV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVESV (mL)", "RVEF (%)")
VOXEL = {"LVEDV (mL)": "LVEDV voxel (mL)", "LVESV (mL)": "LVESV voxel (mL)",
         "LVEF (%)": "LVEF voxel (%)", "LVM (g)": "LVM voxel (g)", "RVEDV (mL)": "RVEDV voxel (mL)",
         "RVESV (mL)": "RVESV voxel (mL)", "RVEF (%)": "RVEF voxel (%)"}
#: biv-me's own figures for bivme-patient1 (reports/validation-function.md)
BIVME = {"LVEDV (mL)": 179.0, "LVESV (mL)": 72.0, "LVEF (%)": 59.8, "LVM (g)": 131.3,
         "RVEDV (mL)": 167.8, "RVESV (mL)": 76.7, "RVEF (%)": 54.3, "RVM (g)": 51.9}


def _cells(value: float, iv, ref: float | None) -> str:
    if iv is None:
        return f"{value:.1f} | (none) | | {'' if ref is None else f'{ref:.1f}'} | |"
    hw = 0.5 * (iv[1] - iv[0])
    if ref is None or not math.isfinite(ref):
        return f"{value:.1f} | [{iv[0]:.1f}, {iv[1]:.1f}] | ± {hw:.1f} | | |"
    d = value - ref
    inside = "yes" if iv[0] <= ref <= iv[1] else "no"
    return f"{value:.1f} | [{iv[0]:.1f}, {iv[1]:.1f}] | ± {hw:.1f} | {ref:.1f} | {d:+.1f} ({inside}) |"


def acdc_rows() -> list[str]:
    out = ["| patient | metric | model | 95 % interval | half-width | voxel count "
           "| model − voxel (voxel inside?) |", "|---|---|---|---|---|---|---|"]
    inside = total = 0
    for p in sorted((DATA / "acdc").glob("patient*")):
        model, m = analyse_study(load_study(p))
        iv = intervals(model, m)
        for col in ACDC:
            ref = m.get(VOXEL[col])
            out.append(f"| {p.name} | {col} | " + _cells(m[col], iv[col], ref))
            if iv[col] is not None and ref is not None and math.isfinite(ref):
                total += 1
                inside += iv[col][0] <= ref <= iv[col][1]
        print(p.name, "done", file=sys.stderr, flush=True)
    return out + ["", f"Voxel count inside the model's 95 % interval: {inside} of {total}."]


def bivme_rows() -> list[str]:
    p = DATA / "bivme-patient1"
    model, m = analyse_study(load_study(p))
    iv = intervals(model, m)
    out = [f"Our ED frame {model.ed_frame}, ES frame {model.es_frame} (biv-me: 24 and 9).", "",
           "| metric | model | 95 % interval | half-width | biv-me | model − biv-me (biv-me inside?) |",
           "|---|---|---|---|---|---|"]
    for col, ref in BIVME.items():
        out.append(f"| {col} | " + _cells(m[col], iv[col], ref))
    out += ["", "Sources (SD, metric units):", "", "| metric | " + " | ".join(
        ("contours", "pixels", "between", "base", "apex")) + " |", "|---" * 6 + "|"]
    for col in BIVME:
        sd = iv["sd"].get(col, {})
        out.append(f"| {col} | " + " | ".join(f"{sd.get(k, 0.0):.2f}" for k in
                                             ("contours", "pixels", "between", "base", "apex")) + " |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    text = ["## Real data", "", "```", "nice -n 10 python benchmarks/uncertainty_real.py --out FILE",
            "```", "", "### ACDC (ten patients, label maps): model against voxel counting", "",
            *acdc_rows(), "", "### bivme-patient1 (CAP guide points): model against biv-me", "",
            *bivme_rows(), ""]
    a.out.write_text("\n".join(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
