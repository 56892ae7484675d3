"""ACDC patients rewritten in other conventions read back the same (issue 29: nothing tuned to
the slice order or array orientation of the ten distributed patients).

    python benchmarks/acdc_variants.py [PATIENT ...]    # default: three of ../shared/data/acdc

Each patient's label maps (and Info.cfg) are copied with (a) the slices in reverse order and
(b) the in-plane array axes reversed too, the header left as distributed (ACDC's headers carry
no orientation, so the base must come from the anatomy); every metric of `analyse_study` on the
copies is compared with the original's and with voxel counting. Printed as a markdown table.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import nibabel as nib
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

KEYS = ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "RVESV (mL)", "LVM (g)", "LVEF (%)", "RVEF (%)")
DATA = ROOT.parent / "shared" / "data" / "acdc"


def variant(src: Path, dest: Path, flip: tuple) -> Path:
    """A copy of ``src`` whose label maps' arrays are reversed along ``flip`` (header kept)."""
    dest.mkdir(parents=True)
    shutil.copy(src / "Info.cfg", dest / "Info.cfg")
    for f in sorted(src.glob("*_gt.nii.gz")):
        img = nib.load(str(f))
        a = np.asanyarray(img.dataobj)
        nib.save(nib.Nifti1Image(np.flip(a, axis=flip).copy(), img.affine, img.header), str(dest / f.name))
    return dest


def main(names: list[str]) -> None:
    print("| patient | variant | orientation | " + " | ".join(k.split(" ")[0] for k in KEYS) + " |")
    print("|---|---|---|" + "---|" * len(KEYS))
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            src = DATA / name
            runs = {"as distributed": src,
                    "slices reversed": variant(src, Path(tmp) / name / "z", (2,)),
                    "slices and rows/columns reversed": variant(src, Path(tmp) / name / "xyz", (0, 1, 2))}
            ref = None
            for label, folder in runs.items():
                study = load_study(folder)
                _, m = analyse_study(study)
                ref = ref or m
                cells = [f"{m[k]:.1f} ({m[k] - ref[k]:+.1f})" for k in KEYS]
                print(f"| {name[-3:]} | {label} | {study.meta.get('sa_orientation', '').split(' (')[0]} | "
                      + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["patient015", "patient055", "patient085"])
