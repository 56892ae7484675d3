"""Open basal SA slices of label maps: the model's LV volumes and mass against phantom truth
and against the map's own voxel count (issue #29).

    nice -n 10 python benchmarks/basal_slices.py --seeds 210 1010 --spacing 5 10 [--before]
    nice -n 10 python benchmarks/basal_slices.py --seeds 240 247 --spacing 10 --half-slice-es

Each seed is the validate_uncertainty.py condition "labels acdc" of a PHTN realistic
phantom (2 frames; where the stack starts below the base drawn from the seed as there),
written in the ACDC layout and read back; one row per seed and slice spacing, and a comment
line with the ES valve plane's shift (mm, basal > 0) from the myocardial conservation.
``--half-slice-es``: every ES valve plane left half a slice beyond its most basal section
(the conservation's plane refused, as where it cannot conserve), to show what the
conservation does.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs.anatomy import model as model_module  # noqa: E402
from cardionurbs.io import load_study, masks  # noqa: E402
from cardionurbs.phantom.generate import generate  # noqa: E402
from cardionurbs.phantom.geometry import Acquisition  # noqa: E402
from cardionurbs.phantom.labelmaps import write_labelmaps  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

gen_mod = importlib.import_module("cardionurbs.phantom.generate")
KEYS = ("LVEDV (mL)", "LVESV (mL)", "LVM (g)")


def run(seed: int, spacing: float, pathology: str = "phtn") -> dict:
    """Truth, model and voxel-count LVEDV/LVESV/LVM of one subject, and the skipped-slice notes."""
    offset = float(np.random.default_rng(seed).uniform(0.5, spacing))
    gen_mod.Acquisition = functools.partial(Acquisition, sa_first_offset_mm=offset)
    try:
        ph = generate(pathology, seed=seed, frames=2, anatomy_model="realistic",
                      sa_spacing_mm=spacing, sa_thickness_mm=min(8.0, spacing))
    finally:
        gen_mod.Acquisition = Acquisition
    ph.study.tags = []
    with tempfile.TemporaryDirectory() as tmp:
        write_labelmaps(ph, tmp, "acdc", images=False)
        study = load_study(tmp)
        model, metrics = analyse_study(study)
    vox = {k: metrics.get(k.replace(" (", " voxel (")) for k in KEYS}
    return {"truth": {k: ph.truth["metrics"][k] for k in KEYS},
            "model": {k: metrics[k] for k in KEYS}, "voxels": vox,
            "warnings": [w for w in study.warnings if "ringed" in w or "basal" in w],
            "es_shift_mm": model.base_shift_mm.get(model.es_frame)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[210, 1010])
    ap.add_argument("--spacing", type=float, nargs="+", default=[5.0, 10.0])
    ap.add_argument("--pathology", default="phtn", choices=("normal", "mr", "phtn"))
    ap.add_argument("--before", action="store_true",
                    help="the rule before issue #29's change: every cavity ringed under "
                         "MIN_RING_FRACTION left out")
    ap.add_argument("--half-slice-es", action="store_true",
                    help="every ES valve plane kept half a slice beyond its most basal section")
    a = ap.parse_args(argv)
    if a.half_slice_es:
        model_module.MYO_PLANE_MISS_BOUND = -1.0      # no plane "conserves": the labels' slab
    if a.before:
        masks.MIN_OPEN_RING_FRACTION = masks.MIN_RING_FRACTION
    print("| seed | slices | metric | truth | model | model − truth | voxels | model − voxels |")
    print("|---|---|---|---|---|---|---|---|")
    for seed in a.seeds:
        for sp in a.spacing:
            r = run(seed, sp, a.pathology)
            for k in KEYS:
                t, m, v = r["truth"][k], r["model"][k], r["voxels"][k]
                dv = f"{m - v:+.1f}" if v is not None and m is not None else "—"
                vs = f"{v:.1f}" if v is not None else "—"
                print(f"| {seed} | {sp:g} mm | {k} | {t:.1f} | {m:.1f} | {m - t:+.1f} "
                      f"({100 * (m - t) / t:+.1f} %) | {vs} | {dv} |", flush=True)
            print(f"<!-- {seed} {sp:g} mm: ES valve plane shift {r['es_shift_mm']} mm -->", flush=True)
            for w in r["warnings"]:
                print(f"<!-- {seed} {sp:g} mm: {w} -->", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
