"""Where the ES valve plane of an SA-only label map goes, and what it does to LVESV.

    python benchmarks/es_plane.py acdc [PATIENT_DIR ...]     # default: ../shared/data/acdc/patient*
    python benchmarks/es_plane.py phantoms                    # ACDC-convention phantoms, HCM-like too

``acdc``: per patient, the labels' LV myocardial voxel count at ES over ED, the ES plane's
shift (mm, basally), how far the nearest plane of its range leaves the model's ES myocardium
from ED's (``conservation_miss``, %), the warning that kept it at the labels' slab, and LVESV
model / voxel count. ``phantoms``: normal, MR, PHTN (seed 0) and two HCM-like hearts (normal
and MR with a 14 mm wall and a small cavity, ``HCM`` below) at 10 and 5 mm slices, written
as ACDC distributes its files (``--labels acdc --label-quirks real``): the same columns and
LVESV, LVEF errors against the truth, model / voxel count. Prints Markdown rows.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _accuracy import metric_error  # noqa: E402
from cardionurbs.anatomy import model as model_module  # noqa: E402
from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.phantom.generate import generate, write_phantom  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

#: Anatomy overrides of an HCM-like phantom: a 14 mm LV wall around a small cavity
HCM = {"r_short_endo": 21.0, "r_short_epi": 35.0, "r_long_endo": 66.0}
_misses: list[float] = []
_conservation_miss = model_module.conservation_miss


def _logged_miss(target: float, volumes: np.ndarray) -> float:
    miss = _conservation_miss(target, volumes)
    _misses.append(miss)
    return miss


model_module.conservation_miss = _logged_miss      # read-only logging of the rule's input


def _plane(study):
    """(model, metrics, ES shift mm, miss %, ES-plane warnings) of one study."""
    _misses.clear()
    model, m = analyse_study(study)
    shift = model.base_shift_mm.get(model.es_frame, float("nan"))
    miss = 100 * _misses[0] if _misses else float("nan")
    ws = [w.split(": ", 1)[1].split(" (")[0] for w in model.warnings
          if "conserve the myocardium" in w or "conserves the LV myocardium" in w]
    return model, m, shift, miss, "; ".join(ws) or "-"


def _ratio(study, model) -> float:
    vox = study.meta["voxel_volumes_ml"]
    return vox[model.es_frame]["lv_myocardium"] / vox[model.ed_frame]["lv_myocardium"]


def acdc(dirs: list[str]) -> None:
    print("| patient | labels' myocardium ES/ED | ES shift (mm) | miss (%) | kept at the slab because | "
          "LVESV model / voxel (mL, diff %) | LVEF model / voxel (points) |")
    print("|---|---|---|---|---|---|---|")
    for d in dirs:
        study = load_study(d)
        model, m, shift, miss, why = _plane(study)
        mv, vv = m["LVESV (mL)"], m["LVESV voxel (mL)"]
        print(f"| {Path(d).name} | {_ratio(study, model):.3f} | {shift:+.2f} | {miss:+.1f} | {why} | "
              f"{mv:.1f} / {vv:.1f} ({100 * (mv / vv - 1):+.1f}) | "
              f"{m['LVEF (%)']:.1f} / {m['LVEF voxel (%)']:.1f} ({m['LVEF (%)'] - m['LVEF voxel (%)']:+.1f}) |",
              flush=True)


def phantoms() -> None:
    print("| subject | slices (mm) | truth LVESV (mL) | labels' myocardium ES/ED | ES shift (mm) | miss (%) | "
          "kept because | LVESV model / voxel (% vs truth) | LVEF model / voxel (points vs truth) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for spacing, thick in ((10.0, 8.0), (5.0, 5.0)):
        for p, over in (("normal", None), ("mr", None), ("phtn", None), ("normal", HCM), ("mr", HCM)):
            ph = generate(p, seed=0, frames=20, sa_spacing_mm=spacing, sa_thickness_mm=thick, anatomy=over)
            with tempfile.TemporaryDirectory() as tmp:
                write_phantom(ph, Path(tmp) / "ph", dicom=False, labels="acdc", label_quirks="real")
                study = load_study(Path(tmp) / "ph" / "labelmaps")
                model, m, shift, miss, why = _plane(study)
            t = ph.truth["metrics"]
            e = {k: (metric_error(k, m[k], t[k]), metric_error(k, m[k.replace(" (", " voxel (")], t[k]))
                 for k in ("LVESV (mL)", "LVEF (%)")}
            print(f"| {p}{' HCM-like' if over else ''} | {spacing:g} | {t['LVESV (mL)']:.1f} | "
                  f"{_ratio(study, model):.3f} | {shift:+.2f} | {miss:+.1f} | {why} | "
                  f"{e['LVESV (mL)'][0]:+.2f} / {e['LVESV (mL)'][1]:+.2f} | "
                  f"{e['LVEF (%)'][0]:+.2f} / {e['LVEF (%)'][1]:+.2f} |", flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "acdc"
    if what == "acdc":
        root = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "acdc"
        acdc(sys.argv[2:] or sorted(str(p) for p in root.glob("patient*")))
    elif what == "phantoms":
        phantoms()
    else:
        sys.exit(f"usage: {__doc__.splitlines()[2].strip()}")
