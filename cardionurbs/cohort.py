"""Many studies -> one table (docs/metrics.md columns, one row per study).

A study that fails (bad input, a surface that cannot be built) is recorded
in its row as ``status = "error: <one line>"`` with empty numbers, and the
run goes on. ``jobs > 1`` measures studies in worker processes
(concurrent.futures); rows keep the input order.
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Iterable

import pandas as pd

from cardionurbs.analysis.function import COLUMNS, NAN
from cardionurbs.analysis.quality import QC_COLUMNS
from cardionurbs.io import atomic

#: subject, status, the metrics, then their evidence (fit residuals per surface, contours
#: left out) and ``QC``, what failed (cardionurbs.analysis.quality)
CSV_COLUMNS = ("subject", "status") + COLUMNS + QC_COLUMNS


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def ignore_interrupts() -> None:
    """Worker-process initializer: Ctrl-C reaches the whole process group, but only the
    parent handles it (one message, exit 130), so workers ignore SIGINT."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def measure_study(path: str, format: str = "auto", heart_rate_bpm: float | None = None,
                  allow_outside: bool = False, labels: str | None = None,
                  strict: bool = False) -> dict:
    """One cohort row for the study at ``path`` (never raises for a bad study); label-map
    studies add the voxel-count columns (cardionurbs.analysis.voxels.VOXEL_COLUMNS).

    ``strict``: a row whose metrics carry a quality flag (``QC`` not empty) is a
    failure: ``status = "error: QC: <flags>"`` and its numbers are emptied."""
    row = {c: NAN for c in COLUMNS + QC_COLUMNS}
    row["subject"] = Path(path).name
    try:
        from cardionurbs.io import load_study
        from cardionurbs.pipeline import analyse_study
        study = load_study(path, format=format, allow_outside=allow_outside,
                           **({} if labels is None else {"labels": labels}))
        row["subject"] = study.subject
        from cardionurbs.analysis.quality import assess
        model, metrics = analyse_study(study, heart_rate_bpm=heart_rate_bpm)
        row.update(metrics)
        row.update(assess(model, metrics).row())
        row["status"] = "ok"
        if strict and row["QC"]:
            row.update({c: NAN for c in COLUMNS})
            row["status"] = f"error: QC: {row['QC']}"
    except Exception as exc:  # noqa: BLE001 - recorded in the row, the run goes on
        kind = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
        row.update({c: NAN for c in COLUMNS + QC_COLUMNS})
        row["status"] = f"error: {kind}{_one_line(exc)}"
    return row


def cohort(paths: Iterable[str | os.PathLike], jobs: int = 1, *, format: str = "auto",
           progress: bool = False, heart_rate_bpm: float | None = None,
           allow_outside: bool = False, labels: str | None = None,
           strict: bool = False) -> pd.DataFrame:
    """Measure every study: a DataFrame with ``subject``, ``status``, the docs/metrics.md
    columns in order and the quality columns, one row per path (input order); when any
    study is a label map the voxel-count columns follow (``labels``: its convention, see
    load_study); ``strict``: flagged rows are failures (:func:`measure_study`)."""
    paths = [str(p) for p in paths]
    rows: list[dict | None] = [None] * len(paths)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(paths), desc="studies", unit="study", file=sys.stderr)
    try:
        if jobs <= 1 or len(paths) <= 1:
            for i, p in enumerate(paths):
                rows[i] = measure_study(p, format, heart_rate_bpm, allow_outside, labels, strict)
                if bar is not None:
                    bar.update(1)
        else:
            with ProcessPoolExecutor(max_workers=min(jobs, len(paths)),
                                     initializer=ignore_interrupts) as pool:
                futs = {pool.submit(measure_study, p, format, heart_rate_bpm, allow_outside,
                                    labels, strict): i
                        for i, p in enumerate(paths)}
                for fut in as_completed(futs):
                    rows[futs[fut]] = fut.result()
                    if bar is not None:
                        bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    from cardionurbs.analysis.voxels import VOXEL_COLUMNS
    extra = [c for c in VOXEL_COLUMNS if any(c in r for r in rows if r)]
    return pd.DataFrame(rows, columns=list(CSV_COLUMNS) + extra)


def write_csv(table: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write the cohort table as CSV, atomically (empty cells for NaN)."""
    from cardionurbs.safe import csv_safe_table
    return atomic.write_text(path, csv_safe_table(table).to_csv(index=False, float_format="%.6g"))


def run_cohort(args: argparse.Namespace) -> int:
    """`cardionurbs cohort STUDY... --csv FILE [--jobs N]`; ``--csv`` is checked
    (cardionurbs.io.outputs) before any study is read."""
    from cardionurbs.io.outputs import check_output_file
    from cardionurbs.pipeline import study_folder
    check_output_file(args.csv, inputs=[study_folder(s) for s in args.studies], option="--csv")
    table = cohort(args.studies, jobs=args.jobs, format=getattr(args, "format", "auto"),
                   progress=True, allow_outside=getattr(args, "allow_outside", False),
                   labels=getattr(args, "labels", None), strict=getattr(args, "strict", False))
    write_csv(table, args.csv)
    failed = table[table["status"] != "ok"]
    print(f"{len(table) - len(failed)} of {len(table)} studies measured; wrote {args.csv}",
          file=sys.stderr)
    for _, r in failed.iterrows():
        print(f"  {r['subject']}: {r['status']}", file=sys.stderr)
    return 0
