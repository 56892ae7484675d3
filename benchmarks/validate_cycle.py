"""The cycle of bivme-patient1 against biv-me (issue #30), as a markdown section.

    cardionurbs analyze ../shared/data/bivme-patient1 --outputs metrics,meshes --out OUT
    python benchmarks/validate_cycle.py OUT >> reports/validation-quality.md

Reads OUT/metrics.json (the meshes output gives every frame's four volumes) and prints
the raw and consistent LV and RV cavity curves, each frame's departure from the mean of
its two neighbours, ES volumes against biv-me's own fit of the same guide points, the
myocardial volumes at ES against ED, and the two stroke volumes with the QC verdict.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

#: biv-me's own fit of bivme-patient1 (mL), as ../shared/tools/realcheck.py has them
BIVME = {"LVESV (mL)": 72.02, "RVESV (mL)": 76.66, "LVSV (mL)": 107.0, "RVSV (mL)": 91.2}


def departures(v: list) -> list:
    """Per interior frame, 100 · (v / mean of its two neighbours − 1), None at the ends."""
    out = [None]
    for i in range(1, len(v) - 1):
        a, b, c = v[i - 1], v[i], v[i + 1]
        ok = None not in (a, b, c)
        out.append(100 * (b / ((a + c) / 2) - 1) if ok else None)
    return out + [None]


def worst(d: list) -> str:
    vals = [(abs(x), i) for i, x in enumerate(d) if x is not None]
    if not vals:
        return "n/a"
    x, i = max(vals)
    return f"{x:.1f} % (frame {i})"


def main(out: str) -> None:
    m = json.loads((Path(out) / "metrics.json").read_text())
    vc, met = m["volume_curve"], m["metrics"]
    ed, es = m["ed_frame"], m["es_frame"]
    print("\n## The cycle of bivme-patient1 (issue #30)\n")
    print("```\ncardionurbs analyze ../shared/data/bivme-patient1 --outputs metrics,meshes --out OUT"
          "\npython benchmarks/validate_cycle.py OUT\n```\n")
    rv = vc.get("rv_basal_supported")
    print(f"ED frame {ed}, ES frame {es} (on the consistent curve); frames supported by their "
          f"neighbours: {vc.get('supported')}; RV basal region supported: {rv}.\n")
    print("| frame | LV raw (mL) | LV (mL) | LV vs neighbours (%) | RV raw (mL) | RV (mL) "
          "| RV vs neighbours (%) |")
    print("|---|---|---|---|---|---|---|")
    lv, rv = vc["lv_cavity (mL)"], vc["rv_cavity (mL)"]
    dl, dr = departures(lv), departures(rv)
    for i, f in enumerate(vc["frame"]):
        def n(x):
            return "" if x is None else f"{x:.1f}"
        print(f"| {f} | {n(vc['lv_cavity raw (mL)'][i])} | {n(lv[i])} | {n(dl[i])} "
              f"| {n(vc['rv_cavity raw (mL)'][i])} | {n(rv[i])} | {n(dr[i])} |")
    print(f"\nWorst frame against the mean of its two neighbours (goal <= 5 %): LV raw "
          f"{worst(departures(vc['lv_cavity raw (mL)']))}, LV consistent {worst(dl)}; RV raw "
          f"{worst(departures(vc['rv_cavity raw (mL)']))}, RV consistent {worst(dr)}.\n")
    print("| quantity | cardionurbs | biv-me | difference | goal |")
    print("|---|---|---|---|---|")
    for k, goal in (("LVESV (mL)", 5), ("RVESV (mL)", 8)):
        e = 100 * (met[k] / BIVME[k] - 1)
        print(f"| {k} | {met[k]:.1f} | {BIVME[k]:.1f} | {e:+.1f} % | {goal} % |")
    for k in ("LVSV (mL)", "RVSV (mL)"):
        print(f"| {k} | {met[k]:.1f} | {BIVME[k]:.1f} | {100 * (met[k] / BIVME[k] - 1):+.1f} % | |")
    my = vc["lv_myocardium (mL)"]
    ry = vc["rv_myocardium (mL)"]
    fi = vc["frame"].index
    print(f"| LV myocardial volume ES / ED | {my[fi(es)]:.1f} / {my[fi(ed)]:.1f} mL "
          f"({100 * (my[fi(es)] / my[fi(ed)] - 1):+.1f} %) | under 1 % | | 5 % |")
    print(f"| RV myocardial volume ES / ED | {ry[fi(es)]:.1f} / {ry[fi(ed)]:.1f} mL "
          f"({100 * (ry[fi(es)] / ry[fi(ed)] - 1):+.1f} %) | about -25 % | | 40 % (flag) |")
    sv = [f for f in m["quality"]["metrics"]["LVSV (mL)"]["flags"] if f.startswith("stroke")]
    print(f"\nLVSV {met['LVSV (mL)']:.1f} mL and RVSV {met['RVSV (mL)']:.1f} mL side by side "
          f"(biv-me {BIVME['LVSV (mL)']} and {BIVME['RVSV (mL)']}), `LVSV-RVSV (mL)` "
          f"{met['LVSV-RVSV (mL)']:.1f}; QC verdict: {sv[0] if sv else 'stroke volumes agree'}. "
          f"MR RegVol / RegFrac: {met['MR RegVol (mL)']} ({m['notes'].get('MR RegVol (mL)', '')}).")
    wall = [f for c in ("LVM (g)", "RVM (g)") for f in m["quality"]["metrics"][c]["flags"]
            if "myocardium (" in f]
    print(f"\nMass-over-time flags: {'; '.join(wall) if wall else 'none'}.")


if __name__ == "__main__":
    main(sys.argv[1])
