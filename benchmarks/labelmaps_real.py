"""Label maps in the real datasets' conventions to metrics, voxel counting timed beside (issue 29).

    python benchmarks/labelmaps_real.py [REPS]   # -> the "Real conventions" section of reports/benchmark-nifti.md

* a 2-frame ACDC patient, as distributed (../shared/data/acdc, the first patient folder found;
  unit-scale sform code 2, spacing in pixdim), and the same with a phantom written with
  ``--label-quirks real`` in the ACDC layout;
* a 50-frame UK Biobank-size ukbb_cardiac folder (208 x 208 x 10 x 50 phantom, SA only),
  written once with our header (interval in ms) and once as UK Biobank writes it (seconds,
  time unit unknown): ED/ES from the layout, PER against the truth for both.
Each: read -> model -> every docs/metrics.md column (``analyse_study``), median (best) of
``reps`` runs after a warm-up, beside voxel counting (read + count) of the same maps.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from labelmaps import header  # noqa: E402
from cardionurbs.io import load_study, nifti  # noqa: E402
from cardionurbs.io.labels import PRESETS  # noqa: E402
from cardionurbs.phantom.generate import generate  # noqa: E402
from cardionurbs.phantom.labelmaps import write_labelmaps  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

TITLE = "## Real conventions (issue 29): ACDC as distributed, UK Biobank 50 frames"
COMMAND = "OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/labelmaps_real.py"


def _time(fn, reps: int) -> tuple[list[float], list[float], object]:
    fn()                                                   # warm-up (imports, caches)
    wall, cpu, out = [], [], None
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return wall, cpu, out


def _voxels(paths: list[Path], preset: str) -> dict:
    out = {}
    for p in paths:
        vol = nifti.read_label_volume(p)
        out[p.name] = nifti.voxel_volumes(vol, PRESETS[preset], {t: t for t in range(vol.data.shape[3])})
    return out


def _voxel_per(folder: Path, model) -> tuple[float, float]:
    """PER (mL/s) of the voxel-count LV curve of a ukbb folder: the plain spline, and with the
    slab steps taken out as the model's curve is (analysis.rates)."""
    from cardionurbs.analysis.rates import extent_steps, filling_rates
    st = load_study(folder)
    fr = sorted(st.meta["voxel_volumes_ml"])
    times = [st.frame_times_ms[f] for f in fr]
    args = (times, [st.meta["voxel_volumes_ml"][f]["lv_cavity"] for f in fr],
            fr.index(model.ed_frame), fr.index(model.es_frame))
    plain, _ = filling_rates(*args)
    stepped, _ = filling_rates(*args, steps=extent_steps(st, fr, times))
    return plain["PER (mL/s)"], stepped["PER (mL/s)"]


def _row(name: str, wall, cpu) -> str:
    return f"| {name} | {np.median(cpu):.2f} ({min(cpu):.2f}) | {np.median(wall):.2f} ({min(wall):.2f}) |"


def cases(tmp: Path, reps: int) -> tuple[list[str], list[str]]:
    rows, notes = [], []
    acdc_root = ROOT.parent / "shared" / "data" / "acdc"
    real = sorted(p for p in acdc_root.glob("patient*") if p.is_dir())[:1]
    ph = generate("normal", seed=0, frames=20, matrix=208, volume_check=False)
    write_labelmaps(ph, tmp / "acdc_phantom", "acdc", quirks="real", images=False)
    for label, folder in [(f"ACDC {p.name} as distributed", p) for p in real] + [
            ("ACDC-convention phantom (--label-quirks real, 208 px, 10 mm)", tmp / "acdc_phantom")]:
        gts = sorted(folder.glob("*_frame*_gt.nii.gz"))
        w, c, (model, m) = _time(lambda: analyse_study(load_study(folder)), reps)
        rows.append(_row(f"{label}: read + model + metrics (2 frames)", w, c))
        w, c, _ = _time(lambda: _voxels(gts, "acdc"), reps)
        rows.append(_row(f"{label}: voxel counting beside it", w, c))
        vox = _voxels(gts, "acdc")
        ed_v, es_v = (vox[gts[i].name][0]["lv_cavity"] for i in (0, -1))
        ref = (f"truth LVEDV {ph.truth['metrics']['LVEDV (mL)']:.1f} mL, LVEF "
               f"{ph.truth['metrics']['LVEF (%)']:.1f} %" if folder.name == "acdc_phantom" else
               "no truth")
        notes.append(f"{label}: ED {model.ed_frame}, ES {model.es_frame}, LVEDV {m['LVEDV (mL)']:.1f} mL, "
                     f"LVEF {m['LVEF (%)']:.1f} % (voxel count {ed_v:.1f} mL, "
                     f"{100 * (1 - es_v / ed_v):.1f} %; {ref}).")
    big = generate("normal", seed=0, frames=50, matrix=208, n_sa=10, sa_spacing_mm=8.0,
                   volume_check=False)
    truth = big.truth["metrics"]
    for label, quirks in (("our header (ms)", None), ("UK Biobank header (s, unit unknown)", "real")):
        folder = tmp / f"ukbb_{quirks}"
        write_labelmaps(big, folder, "ukbb", quirks=quirks, images=False)
        for q in folder.glob("seg*la*"):
            q.unlink()                                      # SA stack only
        w, c, (model, m) = _time(lambda: analyse_study(load_study(folder)), reps)
        rows.append(_row(f"ukbb 208x208x10x50, {label}: read + model + metrics", w, c))
        w, c, _ = _time(lambda: _voxels([folder / "seg_sa.nii.gz"], "ukbb"), reps)
        rows.append(_row(f"ukbb 208x208x10x50, {label}: voxel counting beside it", w, c))
        per, per_t = m["PER (mL/s)"], truth["PER (mL/s)"]
        notes.append(f"ukbb 50 frames, {label}: ED {model.ed_frame}, ES {model.es_frame} (truth ES "
                     f"{big.es_frame}); PER {per:.1f} mL/s vs truth {per_t:.1f} "
                     f"({100 * (per / per_t - 1):+.1f} %); LVESV {m['LVESV (mL)']:.1f} vs "
                     f"{truth['LVESV (mL)']:.1f} mL; "
                     "the voxel-count curve's PER {:.1f} mL/s (spline), {:.1f} with its steps "
                     "taken out.".format(*_voxel_per(folder, model)))
    return rows, notes


def main(reps: int = 3) -> None:
    out = ROOT / "reports" / "benchmark-nifti.md"
    with tempfile.TemporaryDirectory() as tmp:
        rows, notes = cases(Path(tmp), reps)
    load = os.getloadavg()
    head = header("x", COMMAND)
    lines = [TITLE, "", "```", COMMAND, "```", "", *head[6:9],
             "Unset for the run: OPENBLAS_CORETYPE, OPENBLAS_L2_SIZE. Median (best) of "
             f"{reps} runs after a warm-up, one process; wall times are upper bounds on the "
             "shared 2 cores.", "",
             "| case | CPU median (best) s | wall median (best) s |", "|---|---|---|", *rows, "",
             *[f"- {n}" for n in notes],
             f"- load average at the end: {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}", ""]
    text = out.read_text() if out.exists() else ""
    if TITLE in text:
        text = text[:text.index(TITLE)].rstrip() + "\n"
    out.write_text(text.rstrip() + "\n\n" + "\n".join(lines))
    print(f"wrote {out}", file=sys.stderr)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
