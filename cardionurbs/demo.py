"""`cardionurbs demo`: the paper's 12-subject phantom cohort, end to end.

Generates the subjects of ``paper12.toml`` (5 normal, 3 mitral
regurgitation, 4 pulmonary hypertension; 20 phases each) into ``--out`` (or
a temporary folder), reconstructs and measures every subject, writes the
cohort CSV (``cohort.csv``, docs/metrics.md columns) beside ``truth.csv`` (the
phantoms' analytic ground truth) and ``comparison.csv`` (every metric beside its truth),
and prints one summary table (subject, pathology, measured vs truth for LVEDV, LVEF,
RVEF, LVM and twist; at most 40 lines in all) and where the files are.

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
from typing import Any

import pandas as pd

from cardionurbs.analysis.function import COLUMNS, NAN
from cardionurbs.cohort import CSV_COLUMNS, _one_line, ignore_interrupts, write_csv

#: metrics whose error is shown in percentage points (already percentages) or absolute units
_ABSOLUTE = ("LVEF (%)", "RVEF (%)", "MR RegFrac (%)", "LS (%)", "EI ES", "Twist (deg)",
             "Twist 2D (deg)", "Torsion (deg/cm)", "CL shear (deg)", "Tag QC flags",
             "MR RegVol (mL)", "LVSV-RVSV (mL)", "HR (bpm)")


def demo_subject(spec, out_dir: str) -> tuple[dict, dict]:
    """Generate, write and measure one cohort subject: (CSV row, truth row).

    Parameters
    ----------
    spec : cardionurbs.phantom.presets.SubjectSpec
        One subject of the cohort file (id, pathology, seed, frames, noise in px, tag jumps).
    out_dir : str
        Folder the subject's study is written into (as ``out_dir/<id>``, native format).

    Returns
    -------
    row : dict
        The cohort CSV row (:data:`~cardionurbs.cohort.CSV_COLUMNS`: metrics in mL, %, g,
        deg ..., QC and clinical cells, ``status`` ``"ok"`` or ``"error: ..."``); every metric
        NaN when the subject failed.
    truth : dict
        ``subject``, ``pathology`` and the phantom's analytic value of every metric column
        (NaN where the phantom has none).
    """
    from cardionurbs.phantom.generate import generate, write_phantom
    from cardionurbs.pipeline import analyse_study

    row: dict[str, Any] = {c: NAN for c in COLUMNS}
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
        from cardionurbs.cohort import _clinical_cells
        row.update(_clinical_cells(model, metrics))
        row["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - recorded in the row, the demo goes on
        row.update({c: NAN for c in COLUMNS})
        row["status"] = f"error: {_one_line(exc)}"
    return row, truth


def comparison_table(measured: pd.DataFrame, truth: pd.DataFrame) -> pd.DataFrame:
    """Long table: subject, metric, measured, truth, error (relative % for volumes and
    masses, absolute for percentages, ratios-of-percent and tag metrics).

    Parameters
    ----------
    measured : pandas.DataFrame
        The cohort table, one row per subject (``subject`` and the metric columns).
    truth : pandas.DataFrame
        The truth table, one row per subject (``subject`` and the same metric columns).

    Returns
    -------
    pandas.DataFrame
        Columns ``subject, metric, measured, truth, error, error_unit``: one row per subject
        and metric where either value is known; ``error`` is ``100 (measured / truth - 1)``
        (``error_unit`` ``"%"``) or ``measured - truth`` in the metric's own unit (``"abs"``).
    """
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


#: the metrics of the printed summary table: (column, short name, format)
SUMMARY = (("LVEDV (mL)", "LVEDV mL", "{:.0f}"), ("LVEF (%)", "LVEF %", "{:.1f}"),
           ("RVEF (%)", "RVEF %", "{:.1f}"), ("LVM (g)", "LVM g", "{:.0f}"),
           ("Twist (deg)", "twist °", "{:.1f}"))


def _cell(fmt: str, value) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "—"
    return "—" if math.isnan(v) else fmt.format(v)


def format_comparison(comp: pd.DataFrame, measured: pd.DataFrame,
                      truth: pd.DataFrame | None = None) -> str:
    """The printed summary: one line per subject (pathology, then measured / truth for
    :data:`SUMMARY`), a failed subject with its status, and the mean |error| per metric.
    Every metric is in comparison.csv.

    Parameters
    ----------
    comp : pandas.DataFrame
        The long table of :func:`comparison_table`.
    measured : pandas.DataFrame
        The cohort table (``subject``, ``status`` and the metric columns).
    truth : pandas.DataFrame or None, optional
        The truth table; None shows ``—`` for every truth cell and no pathology.

    Returns
    -------
    str
        The table's lines joined by newlines (a header, one line per subject, the mean
        |error| of each :data:`SUMMARY` metric).
    """
    t = truth.set_index("subject") if truth is not None else None
    head = f"{'subject':10s} {'pathology':9s} " + " ".join(f"{n:>13s}" for _, n, _ in SUMMARY)
    lines = ["measured / truth", head]
    for _, r in measured.iterrows():
        s = r["subject"]
        path = "" if t is None or s not in t.index else str(t.loc[s, "pathology"])
        if r["status"] != "ok":
            lines.append(f"{s:10s} {path:9s} {r['status'][:70]}")
            continue
        cells = [f"{_cell(f, r[c])}/{_cell(f, t.loc[s, c] if t is not None else None)}"
                 for c, _, f in SUMMARY]
        lines.append(f"{s:10s} {path:9s} " + " ".join(f"{x:>13s}" for x in cells))
    err = comp.dropna(subset=["error"]).groupby("metric", sort=False)["error"]
    mean_abs = err.apply(lambda e: float(e.abs().mean()))
    units = comp.groupby("metric", sort=False)["error_unit"].first()
    parts = [f"{n} {mean_abs[c]:.2f}{' %' if units[c] == '%' else ''}"
             for c, n, _ in SUMMARY if c in mean_abs.index]
    lines.append("mean |error|: " + ", ".join(parts) + " (relative % for volumes and mass)")
    return "\n".join(lines)


def run_demo(args: argparse.Namespace) -> int:
    """`cardionurbs demo [--out DIR [--overwrite]] [--keep] [--jobs N]` (default: one job per
    CPU core). With ``--out`` the folder is checked first and written atomically; without it
    the demo works in a temporary folder, removed at the end unless ``--keep``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line: ``out`` (folder or None), ``overwrite``, ``keep`` and
        ``jobs`` (worker processes; None or 0: one per CPU core).

    Returns
    -------
    int
        The exit code, 0 (bad input raises before anything is written).
    """
    import shutil

    from cardionurbs.io.atomic import atomic_dir
    from cardionurbs.io.outputs import check_output_dir
    from cardionurbs.phantom.presets import data_path, load_cohort_spec

    if getattr(args, "out", None):
        out = check_output_dir(args.out, overwrite=getattr(args, "overwrite", False))
        with atomic_dir(out) as tmp:
            written = _demo(args, tmp, shown=out, load=(data_path, load_cohort_spec))
        print(f"wrote {out}: {written}")
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="cardionurbs-demo-"))
    keep = bool(getattr(args, "keep", False))
    try:
        written = _demo(args, tmp, shown=tmp, load=(data_path, load_cohort_spec))
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)
    if keep:
        print(f"kept {tmp}: {written}")
    else:
        print("the outputs were written to a temporary folder, now removed; "
              "--out DIR (or --keep) keeps them")
    return 0


def _demo(args: argparse.Namespace, out: Path, shown: Path, load) -> str:
    """Generate, measure and compare the paper12 cohort into ``out``; returns what was
    written (for the closing line, once the folder is in place)."""
    data_path, load_cohort_spec = load
    subjects = load_cohort_spec(data_path("paper12.toml"))
    jobs = max(1, int(getattr(args, "jobs", None) or os.cpu_count() or 1))
    print(f"generating and analysing {len(subjects)} phantom subjects "
          f"({jobs} job{'s' if jobs > 1 else ''})", file=sys.stderr)
    from tqdm import tqdm
    results: list = [None] * len(subjects)
    with tqdm(total=len(subjects), desc="subjects", unit="subject", file=sys.stderr,
              disable=not sys.stderr.isatty()) as bar:
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
    print(format_comparison(comp, measured, truth))
    from cardionurbs.report.cohort_figures import write_cohort_figures
    figs = write_cohort_figures(measured, out / "figures", truth=truth)
    for name, why in figs.skipped.items():
        print(f"figure {name} left out: {why}", file=sys.stderr)
    ok = int((measured["status"] == "ok").sum())
    print(f"{ok} of {len(measured)} subjects measured")
    return (f"cohort.csv, truth.csv, comparison.csv (every metric beside its truth), the "
            f"{len(subjects)} studies and {len(figs.figures)} cohort figures in figures/ "
            "(distributions by group, measured vs truth, Bland-Altman)")
