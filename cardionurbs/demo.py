"""`cardionurbs demo`: the paper's 12-subject phantom cohort, end to end.

Generates the subjects of ``paper12.toml`` (5 normal, 3 mitral
regurgitation, 4 pulmonary hypertension; 20 phases each) into ``--out`` (or
a temporary folder), reconstructs and measures every subject, writes the
cohort CSV (``cohort.csv``, docs/metrics.md columns) beside ``truth.csv`` (the
phantoms' analytic ground truth), and prints every metric beside its truth.

The studies are written in the native format without synthetic DICOM images
(``cardionurbs phantom --cohort`` writes those too), to keep the demo fast.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pandas as pd

from cardionurbs.analysis.function import COLUMNS, NAN
from cardionurbs.cohort import CSV_COLUMNS, _one_line, ignore_interrupts, write_csv

#: metrics whose error is shown in percentage points (already percentages) or absolute units
_ABSOLUTE = ("LVEF (%)", "RVEF (%)", "MR RegFrac (%)", "LS (%)", "EI ES", "Twist (deg)",
             "Twist 2D (deg)", "Torsion (deg/cm)", "CL shear (deg)", "Tag QC flags",
             "MR RegVol (mL)", "LVSV-RVSV (mL)", "HR (bpm)")


def demo_subject(spec, out_dir: str) -> tuple[dict, dict]:
    """Generate, write and measure one cohort subject: (CSV row, truth row)."""
    from cardionurbs.phantom.generate import generate, write_phantom
    from cardionurbs.pipeline import analyse_study

    row = {c: NAN for c in COLUMNS}
    row["subject"] = spec.id
    truth = {"subject": spec.id, "pathology": spec.pathology}
    try:
        ph = generate(spec.pathology, seed=spec.seed, frames=spec.frames, noise_px=spec.noise_px,
                      tag_jumps=spec.tag_jumps, subject=spec.id)
        truth.update({c: (NAN if ph.truth["metrics"].get(c) is None else float(ph.truth["metrics"][c]))
                      for c in COLUMNS})
        write_phantom(ph, Path(out_dir) / spec.id, dicom=False)
        model, metrics = analyse_study(ph.study)
        row.update(metrics)
        from cardionurbs.analysis.quality import assess
        row.update(assess(model, metrics).row())
        row["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - recorded in the row, the demo goes on
        row.update({c: NAN for c in COLUMNS})
        row["status"] = f"error: {_one_line(exc)}"
    return row, truth


def comparison_table(measured: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Long table: subject, metric, measured, truth, error (relative % for volumes and
    masses, absolute for percentages, ratios-of-percent and tag metrics)."""
    rows = []
    t = truth.set_index("subject")
    for _, r in measured.iterrows():
        for c in COLUMNS:
            m, tv = float(r[c]), float(t.loc[r["subject"], c])
            if math.isnan(m) and math.isnan(tv):
                continue
            if c in _ABSOLUTE or "ratio" in c:
                err, unit = m - tv, "abs"
            else:
                err, unit = (100.0 * (m / tv - 1.0) if tv else NAN), "%"
            rows.append({"subject": r["subject"], "metric": c, "measured": m, "truth": tv,
                         "error": err, "error_unit": unit})
    return pd.DataFrame(rows, columns=["subject", "metric", "measured", "truth", "error",
                                       "error_unit"])


def format_comparison(comp: pd.DataFrame, measured: pd.DataFrame) -> str:
    """The printed table: one block per subject, then the mean |error| per metric."""
    lines = []
    for subject, g in comp.groupby("subject", sort=False):
        status = measured.loc[measured["subject"] == subject, "status"].iloc[0]
        lines.append(f"{subject}  [{status}]")
        lines.append(f"  {'metric':20s} {'model':>10s} {'truth':>10s} {'error':>10s}")
        for _, r in g.iterrows():
            err = "" if math.isnan(r["error"]) else (
                f"{r['error']:+.2f} %" if r["error_unit"] == "%" else f"{r['error']:+.3f}")
            meas = "" if math.isnan(r["measured"]) else f"{r['measured']:.3f}"
            lines.append(f"  {r['metric']:20s} {meas:>10s} {r['truth']:>10.3f} {err:>10s}")
    for _, r in measured[measured["status"] != "ok"].iterrows():
        lines.append(f"{r['subject']}  [{r['status']}]")
    lines.append("")
    lines.append("mean |error| over subjects (relative % for volumes and masses, absolute otherwise)")
    summary = comp.dropna(subset=["error"]).groupby("metric", sort=False).agg(
        n=("error", "size"), mean_abs=("error", lambda e: float(e.abs().mean())),
        max_abs=("error", lambda e: float(e.abs().max())), unit=("error_unit", "first"))
    for metric, r in summary.iterrows():
        u = " %" if r["unit"] == "%" else ""
        lines.append(f"  {metric:20s} n={r['n']:2d}  mean {r['mean_abs']:.3f}{u}  max {r['max_abs']:.3f}{u}")
    return "\n".join(lines)


def run_demo(args: argparse.Namespace) -> int:
    """`cardionurbs demo [--out DIR [--overwrite]] [--keep] [--jobs N]` (default: one job per
    CPU core). With ``--out`` the folder is checked first and written atomically; without it
    the demo works in a temporary folder, removed at the end unless ``--keep``."""
    import shutil

    from cardionurbs.io.atomic import atomic_dir
    from cardionurbs.io.outputs import check_output_dir
    from cardionurbs.phantom.presets import data_path, load_cohort_spec

    if getattr(args, "out", None):
        out = check_output_dir(args.out, overwrite=getattr(args, "overwrite", False))
        with atomic_dir(out) as tmp:
            _demo(args, tmp, shown=out, load=(data_path, load_cohort_spec))
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="cardionurbs-demo-"))
    keep = bool(getattr(args, "keep", False))
    try:
        _demo(args, tmp, shown=tmp, load=(data_path, load_cohort_spec))
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)
    print(f"kept {tmp}" if keep else f"removed the temporary folder {tmp} (--keep or --out "
          "DIR keeps the output)", file=sys.stderr)
    return 0


def _demo(args: argparse.Namespace, out: Path, shown: Path, load) -> None:
    """Generate, measure and compare the paper12 cohort into ``out`` (printed as ``shown``)."""
    data_path, load_cohort_spec = load
    subjects = load_cohort_spec(data_path("paper12.toml"))
    jobs = max(1, int(getattr(args, "jobs", None) or os.cpu_count() or 1))
    print(f"generating and analysing {len(subjects)} phantom subjects in {shown} "
          f"({jobs} job{'s' if jobs > 1 else ''})", file=sys.stderr)
    from tqdm import tqdm
    results: list = [None] * len(subjects)
    with tqdm(total=len(subjects), desc="subjects", unit="subject", file=sys.stderr) as bar:
        if jobs == 1:
            for i, s in enumerate(subjects):
                results[i] = demo_subject(s, str(out))
                bar.update(1)
        else:
            with ProcessPoolExecutor(max_workers=min(jobs, len(subjects)),
                                     initializer=ignore_interrupts) as pool:
                futs = {pool.submit(demo_subject, s, str(out)): i for i, s in enumerate(subjects)}
                from concurrent.futures import as_completed
                for fut in as_completed(futs):
                    results[futs[fut]] = fut.result()
                    bar.update(1)
    measured = pd.DataFrame([r for r, _ in results], columns=list(CSV_COLUMNS))
    truth = pd.DataFrame([t for _, t in results], columns=["subject", "pathology"] + list(COLUMNS))
    write_csv(measured, out / "cohort.csv")
    write_csv(truth, out / "truth.csv")
    comp = comparison_table(measured, truth)
    write_csv(comp, out / "comparison.csv")
    print(format_comparison(comp, measured))
    from cardionurbs.report.cohort_figures import write_cohort_figures
    figs = write_cohort_figures(measured, out / "figures", truth=truth)
    for name, why in figs.skipped.items():
        print(f"figure {name} left out: {why}", file=sys.stderr)
    ok = int((measured["status"] == "ok").sum())
    print(f"\n{ok} of {len(measured)} subjects measured; wrote {shown / 'cohort.csv'}, "
          f"{shown / 'truth.csv'}, {shown / 'comparison.csv'} and {len(figs.figures)} cohort "
          f"figures in {shown / 'figures'} (distributions by group, measured vs truth, "
          "Bland-Altman)")
