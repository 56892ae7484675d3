"""Validation of the regional analysis against phantom truth; writes reports/validation-regional.md.

Run from the repository root::

    .venv/bin/python benchmarks/validate_regional.py [--seeds 1]

Against ``truth.json`` of freshly generated phantoms (normal seed 1, mr seed 2,
phtn seed 3; with ``--seeds N`` also the next N − 1 seeds of each):

1. noise-free 2-frame phantoms: segmental wall thickness (ED, ES) and
   thickening, Ecc/Ell/Err per segment and global, det F, GLS/GCS surface;
2. the same with 0.5 px contour and tag noise;
3. filling rates at 20, 30 and 40 frames (noise-free);
4. Sunnybrook (heart failure with infarction): GCS surface beside the published
   heart-failure range;
5. the regional analysis time on a 2-frame tagged phantom (median of 5 after a warm-up).
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

from cardionurbs.analysis.rates import RATE_COLUMNS, model_filling_rates  # noqa: E402
from cardionurbs.analysis.regional import regional_metrics  # noqa: E402
from cardionurbs.analysis.tags import tag_metrics  # noqa: E402
from cardionurbs.anatomy.model import reconstruct  # noqa: E402
from cardionurbs.io import atomic  # noqa: E402
from cardionurbs.phantom.generate import generate  # noqa: E402

PRESETS = (("normal", 1), ("mr", 2), ("phtn", 3))
SEG = range(1, 17)
HF_GCS = (-6.6, 3.6)   # mid-LV circumferential strain in HFrEF, mean ± SD (see NOTES)


def seg_err(m, t, fmt):
    e = [abs(m[fmt.format(k)] - t[fmt.format(k)]) for k in SEG]
    return max(e), float(np.mean(e))


def one(pathology, seed, noise):
    ph = generate(pathology, seed=seed, frames=2, volume_check=False, noise_px=noise)
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    r = regional_metrics(model, tags)
    t = ph.truth["metrics"]
    row = {"subject": f"{pathology} {seed}", "noise": noise}
    for name, fmt in (("WT ED", "WT_AHA_{} (mm)"), ("WT ES", "WT_ES_AHA_{} (mm)"),
                      ("Thickening", "Thickening_AHA_{} (%)"), ("Ecc", "Ecc_AHA_{} (%)"),
                      ("Ell", "Ell_AHA_{} (%)"), ("Err", "Err_AHA_{} (%)")):
        row[name] = seg_err(r, t, fmt)
    for c in ("Ecc_Global (%)", "Ell_Global (%)", "Err_Global (%)", "GLS surface (%)",
              "GCS surface (%)", "WT_Global (mm)", "Thickening_Global (%)"):
        row[c] = (r[c], t[c])
    row["det F"] = r.strain.get("det_F", float("nan"))
    row["det F truth"] = ph.truth["tags"]["det_F_es"]
    row["points"] = r.strain.get("n_points", 0)
    return row


def table(rows):
    out = ["| phantom | WT ED max/mean (mm) | WT ES max/mean (mm) | Thickening max (%) | "
           "Ecc seg max/mean | Ell seg max/mean | Err seg max/mean | GCS (Ecc_Global) err | "
           "GLS (Ell_Global) err | Err_Global err | det F (truth 1) | GLS surface err | "
           "GCS surface err |", "|" + "---|" * 13]
    for r in rows:
        def d(c):
            return r[c][0] - r[c][1]
        out.append(f"| {r['subject']} | {r['WT ED'][0]:.2f} / {r['WT ED'][1]:.2f} | "
                   f"{r['WT ES'][0]:.2f} / {r['WT ES'][1]:.2f} | {r['Thickening'][0]:.2f} | "
                   f"{r['Ecc'][0]:.2f} / {r['Ecc'][1]:.2f} | {r['Ell'][0]:.2f} / {r['Ell'][1]:.2f} | "
                   f"{r['Err'][0]:.1f} / {r['Err'][1]:.1f} | {d('Ecc_Global (%)'):+.2f} | "
                   f"{d('Ell_Global (%)'):+.2f} | {d('Err_Global (%)'):+.1f} | {r['det F']:.3f} | "
                   f"{d('GLS surface (%)'):+.2f} | {d('GCS surface (%)'):+.2f} |")
    return out


def truth_rows(rows):
    out = ["| phantom | Ecc_Global | Ell_Global | Err_Global | WT_Global (mm) | Thickening_Global | "
           "GLS surface | GCS surface |", "|" + "---|" * 8]
    for r in rows:
        out.append(f"| {r['subject']} | " + " | ".join(
            f"{r[c][1]:.2f}" for c in ("Ecc_Global (%)", "Ell_Global (%)", "Err_Global (%)",
                                       "WT_Global (mm)", "Thickening_Global (%)",
                                       "GLS surface (%)", "GCS surface (%)")) + " |")
    return out


def rates(frames):
    out = []
    for pathology, seed in PRESETS:
        ph = generate(pathology, seed=seed, frames=frames, volume_check=False)
        got, _ = model_filling_rates(reconstruct(ph.study))
        t = ph.truth["metrics"]
        out.append((pathology, frames, {c: (got[c], t[c]) for c in RATE_COLUMNS}))
    return out


def sunnybrook():
    from cardionurbs.io import load_study
    base = ROOT.parent / "shared" / "data" / "sunnybrook"
    rows = []
    for p in sorted(base.glob("SC-*")):
        model = reconstruct(load_study(p))
        r = regional_metrics(model, None)
        rows.append((p.name, r["GCS surface (%)"], r.surface.get("gcs_slice")))
    return rows


def timing():
    ph = generate("normal", seed=1, frames=2, volume_check=False)
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    regional_metrics(model, tags)                       # warm-up: surfaces, axes built
    ts = []
    for _ in range(5):
        t0 = time.perf_counter()
        regional_metrics(model, tags)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), min(ts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "reports" / "validation-regional.md"))
    a = ap.parse_args(argv)
    presets = [(p, s + k) for p, s in PRESETS for k in range(a.seeds)]
    clean = [one(p, s, 0.0) for p, s in presets]
    noisy = [one(p, s, 0.5) for p, s in presets]
    rr = [x for n in (20, 30, 40) for x in rates(n)]
    sb = sunnybrook()
    med, best = timing()
    L = ["# Validation: regional function (AHA segments, wall thickness, strain, rates)", "",
         "Command: `.venv/bin/python benchmarks/validate_regional.py"
         + (f" --seeds {a.seeds}" if a.seeds != 1 else "") + "`", "",
         f"Generated {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC on {platform.node()} "
         f"({os.cpu_count()} cores, Python {platform.python_version()}). Truth: `truth.json` of "
         "each phantom, computed from the analytic model (`cardionurbs.phantom.regional`), "
         "never from the reconstruction. Errors are measured − truth; strains in strain points "
         "(%), segment errors over AHA segments 1–16.", "",
         "## 1. Noise-free phantoms (2 frames: ED, ES)", ""]
    L += table(clean)
    L += ["", "Truth values of the global columns:", ""] + truth_rows(clean)
    L += ["", "## 2. With 0.5 px contour and tag noise", ""] + table(noisy)
    L += ["", "## 3. Filling and ejection rates (noise-free, relative error %)", "",
          "| phantom | frames | PER | PEFR | PAFR | E/A | truth PER / PEFR / PAFR (mL/s) |",
          "|---|---|---|---|---|---|---|"]
    for p, n, d in rr:
        e = {c: 100 * (d[c][0] / d[c][1] - 1) for c in d}
        L.append(f"| {p} | {n} | {e['PER (mL/s)']:+.1f} | {e['PEFR (mL/s)']:+.1f} | "
                 f"{e['PAFR (mL/s)']:+.1f} | {e['E/A ratio']:+.1f} | "
                 f"{d['PER (mL/s)'][1]:.0f} / {d['PEFR (mL/s)'][1]:.0f} / {d['PAFR (mL/s)'][1]:.0f} |")
    lo, hi = HF_GCS[0] - 2 * HF_GCS[1], HF_GCS[0] + 2 * HF_GCS[1]
    L += ["", "## 4. Sunnybrook (heart failure with infarction): GCS surface", "",
          "| study | GCS surface (%) | mid SA slice | within HF range |", "|---|---|---|---|"]
    for name, g, s in sb:
        L.append(f"| {name} | {g:.1f} | {s} | {'yes' if lo <= g <= hi else 'no'} |")
    L += ["", f"Published range for heart failure with reduced EF: mid-LV circumferential strain "
          f"{HF_GCS[0]} ± {HF_GCS[1]} % (mean ± SD; normal controls −14.6 ± 3.4 %), cine feature "
          "tracking, 1.5 T (Comparisons of myocardial strain and strain rate in patients with "
          "heart failure with preserved and reduced ejection fraction using Feature Tracking of "
          "cine MR images, *J Cardiovasc Magn Reson* 16(Suppl 1):P300, 2014, "
          "https://jcmr-online.biomedcentral.com/articles/10.1186/1532-429X-16-S1-P300). "
          f"Range used: mean ± 2 SD = [{lo:.1f}, {hi:.1f}] %. Sunnybrook has no long-axis "
          "views, so GLS surface is empty there.", "",
          "## 5. Speed", "",
          f"`regional_metrics` (AHA segments at ED and ES, thickness by ray casting, tag strain "
          f"with its fit, surface strains) on a 2-frame tagged normal phantom after the analysis "
          f"has built its surfaces: median {med * 1000:.0f} ms, best {best * 1000:.0f} ms "
          "(5 runs).", ""]
    L += NOTES.splitlines()
    atomic.write_text(a.out, "\n".join(L) + "\n")
    print("\n".join(L))
    return 0


NOTES = """## Notes

- **Thickness** is measured along the outward endocardial normal of the NURBS surface to the
  epicardial NURBS (Newton on (u, v, t) per ray, 64 × 48 rays); the truth bisects the same
  distance on the exact moved surfaces (80 × 160 cells). Both weight by endocardial area.
- **Ecc and Ell** are the volume means of the fitted strain over the tagged myocardium of each
  segment; the truth is the exact strain (central differences of the analytic motion) on a
  1 mm grid of the same region (between the outermost tag levels).
- **Err and det F** are biased low. The cause is upstream of the strain fit: the material
  points at ES (tag-surface intersections) carry a transmural error — about +0.4 mm at the
  endocardium to −0.6 mm at the epicardium on the normal phantom, i.e. the tagged wall looks
  ~1 mm thinner at ES than it is — because each tag line is fitted with one control point per
  ~12 mm and a second-difference penalty (`analysis.tag_surfaces.control_count`,
  `fit_tag_curves(smoothing=0.1)`), which cannot follow the bend of an ES tag line across a
  thickening wall. Fed the exact material-point motion, the same fit reproduces F to 1e-3
  (tests/test_regional_strain.py). An experiment with one control point per ~5 mm and
  smoothing 0.01 (not the package default) brings det F to 0.998 and the tag-surface residual
  from 0.24 to 0.06 mm; changing the tag-line fit changes the twist validation as well and is
  left to a follow-up.
- **Filling rates** need ≥ 10 frames. The phantom's atrial kick lasts ~0.1 RR and its volume
  curve has a corner at ED, so PAFR is under-resolved at 20 frames; from 30 frames all rates
  are within 5 %.
"""


if __name__ == "__main__":
    sys.exit(main())
