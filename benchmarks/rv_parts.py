"""Each frame's RV cavity in parts (issue #30): where a frame of the RV curve departs from
its neighbours.

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE OPENBLAS_NUM_THREADS=1 nice -n 10 \\
        python benchmarks/rv_parts.py ../shared/data/bivme-patient1

Per frame of the study's own reconstruction (no support in time): the RV cavity, its body
(RV endocardium − LV epicardium on the apical side of the tricuspid plane) and RVOT lumen
(the rest), its part basal to the RV's reference slice (the most basal slice of every
frame's RV endocardial stack, :func:`cardionurbs.anatomy.cycle.basal_edges`) and apical to
it, each with its departure from the mean of the two adjacent frames (%), the tricuspid
plane's distance from the reference slice's plane along the stack (mm) and its tilt from
the SA planes (degrees), and the RV endocardial section areas (mm²), as a markdown table.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from cardionurbs import reconstruct
from cardionurbs.anatomy.cycle import section_areas
from cardionurbs.io import load_study

PARTS = ("total", "body", "rvot", "basal", "apical")


def frame_parts(model, frame: int, ref: str) -> dict:
    """One frame's RV cavity in parts (mL), its tricuspid plane (mm, deg) and section areas."""
    geo = model.geometry[frame]
    n = np.asarray(geo.direction, float)
    total = model.solids(frame)["rv_cavity"].volume() / 1000.0
    lv_epi = model._trim(model._solid(frame, "lv_epi"), frame, "lv", 0.01, "lv_epi")
    body = model._trim(model._solid(frame, "rv_endo") - lv_epi, frame, "rv",
                       what="rv body").volume() / 1000.0
    sec = next(x for x in geo.sections["rv_endo"] if x.slice == ref)
    basal = model._rv_basal_ml(frame, ref)
    plane = model.base_planes[frame].get("rv")
    dist = tilt = math.nan
    if plane is not None:
        dist = abs(float(plane.origin @ n) - float(sec.points.mean(axis=0) @ n))
        tilt = math.degrees(math.acos(min(1.0, abs(float(plane.normal @ n)))))
    return {"total": total, "body": body, "rvot": total - body, "basal": basal,
            "apical": total - basal, "tricuspid_mm": dist, "tilt_deg": tilt,
            "areas": section_areas(geo).get("rv_endo", {})}


def departure(rows: list[dict], key: str, i: int) -> str:
    """100 · (row i / mean of rows i ± 1 − 1) of one part, blank at the ends."""
    if not 0 < i < len(rows) - 1:
        return ""
    return f"{100 * (rows[i][key] / ((rows[i - 1][key] + rows[i + 1][key]) / 2) - 1):+.1f}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study")
    a = ap.parse_args(argv)
    model = reconstruct(load_study(a.study))
    edges = model._rv_basal_edges()
    if edges is None:
        raise SystemExit("no RV reference slice, or no edge of its basal slice's run")
    ref, edge = edges
    rows = [frame_parts(model, f, ref) for f in model.frames]
    print(f"RV reference slice {ref}; frames at an edge of its basal slice's run: {sorted(edge)}\n")
    print("| frame | " + " | ".join(f"{k} (mL) | vs adjacent (%)" for k in PARTS)
          + " | tricuspid plane from ref (mm) | tilt (deg) | RV endo areas (mm²) |")
    print("|---" * (2 + 2 * len(PARTS) + 2) + "|")
    for i, (f, r) in enumerate(zip(model.frames, rows)):
        cells = " | ".join(f"{r[k]:.1f} | {departure(rows, k, i)}" for k in PARTS)
        areas = ", ".join(f"{s} {v:.0f}" for s, v in r["areas"].items())
        print(f"| {f} | {cells} | {r['tricuspid_mm']:.1f} | {r['tilt_deg']:.1f} | {areas} |")


if __name__ == "__main__":
    main()
