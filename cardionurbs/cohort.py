"""Many studies -> one table (docs/metrics.md columns, one row per study).

A study that fails (bad input, a surface that cannot be built, a hang past
``timeout``, a worker process that dies) is recorded in its row as
``status = "error: <one line>"`` with empty numbers, and the run goes on.
Studies are measured on local worker processes (``jobs``) or on a Dask cluster
(``dask="local"`` or ``"tcp://host:port"``; :mod:`cardionurbs.executor`); rows
keep the input order.

Durable runs (``run_dir``, the CLI's ``<csv>.rows/`` by default): each finished
subject's row is written at once to its own small file ``rows/<key>.json``
(temporary file, fsync, rename, fsync of the folder), so a run killed at any
moment (even ``kill -9``) keeps every subject it finished; ``resume=True``
measures only the subjects without a row. The table -- and so the CSV -- is
always assembled from the stored rows in input order, which makes a resumed
run's CSV byte-identical to an uninterrupted one.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import sys
import time
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from cardionurbs.analysis.body import BODY_COLUMNS, INDEXED_COLUMNS
from cardionurbs.analysis.function import COLUMNS, NAN
from cardionurbs.analysis.quality import QC_COLUMNS
from cardionurbs.analysis.uncertainty import (INTERVAL_COLUMNS, halfwidth_flags, interval_columns,
                                              intervals)
from cardionurbs.analysis.ranges import range_column_names
from cardionurbs.io import atomic

#: the ``<column> range`` cells (below / normal / above) of the metrics with a reference range
RANGE_COLUMNS = range_column_names()
#: subject, status, the metrics, then their evidence (fit residuals per surface, contours
#: left out) and ``QC``, what failed (cardionurbs.analysis.quality); body size and the
#: indexed metrics, the reference-range flags, and the number of warnings with a readable
#: ``notes`` cell (why columns are null, the first warnings)
BODY_CSV_COLUMNS = BODY_COLUMNS + ("Sex",) + INDEXED_COLUMNS
CSV_COLUMNS = (("subject", "status") + COLUMNS + QC_COLUMNS + BODY_CSV_COLUMNS + RANGE_COLUMNS
               + ("warnings", "notes"))
_NUMBERS = COLUMNS + BODY_CSV_COLUMNS + QC_COLUMNS + RANGE_COLUMNS


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


#: environment variable that arms :func:`_test_fault` (the test suite's fault injection)
TEST_FAULTS_ENV = "CARDIONURBS_TEST_FAULTS"


def _test_fault(path: str) -> None:
    """Test-only hook: with ``CARDIONURBS_TEST_FAULTS=1`` in the environment, a study folder
    holding a file ``TEST_FAULT`` misbehaves as it says -- ``hang`` (sleeps for an hour),
    ``exit`` (the worker process ends at once, as if killed) or ``raise`` (an internal
    error). Does nothing otherwise."""
    if os.environ.get(TEST_FAULTS_ENV) != "1":
        return
    marker = Path(path) / "TEST_FAULT"
    if not marker.is_file():
        return
    what = marker.read_text().strip()
    if what == "hang":
        time.sleep(3600)
    elif what == "exit":
        os._exit(17)
    elif what == "raise":
        raise RuntimeError(f"injected fault in {path}")


def ignore_interrupts() -> None:
    """Worker-process initializer: Ctrl-C reaches the whole process group, but only the
    parent handles it (one message, exit 130), so workers ignore SIGINT."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def measure_study(path: str, format: str = "auto", heart_rate_bpm: float | None = None,
                  allow_outside: bool = False, labels: str | None = None,
                  strict: bool = False, uncertainty: bool = True,
                  max_halfwidth: dict[str, float] | None = None) -> dict:
    """One cohort row for the study at ``path`` (never raises for a bad study); label-map
    studies add the voxel-count columns (cardionurbs.analysis.voxels.VOXEL_COLUMNS).

    ``uncertainty``: the ``<column> lo95`` / ``hi95`` interval columns
    (cardionurbs.analysis.uncertainty); ``max_halfwidth`` (column -> largest half-width
    allowed, in the column's unit): a wider (or missing) interval is a quality flag in ``QC``.

    ``strict``: a row whose metrics carry a quality flag (``QC`` not empty) is a
    failure: ``status = "error: QC: <flags>"`` and its numbers are emptied.

    Parameters
    ----------
    path : str
        The study's folder (or single file).
    format : str, optional
        The study format (``"auto"``: detected; see :func:`cardionurbs.io.load_study`).
    heart_rate_bpm : float or None, optional
        Heart rate in beats/min for the rate metrics (None: the study's own, if any).
    allow_outside : bool, optional
        Let the study name files outside its folder (:func:`cardionurbs.confine.allow_outside`).
    labels : str or None, optional
        NIfTI label maps only: a preset (``acdc``, ``ukbb``, ``mnms``, ``bivme``) or a
        ``lv=…,myo=…,rv=…`` mapping; None: the layout's preset or inferred roles.
    strict : bool, optional
        A quality flag makes the row a failure.
    uncertainty : bool, optional
        Add the 95 % interval columns.
    max_halfwidth : dict of str to float, optional
        Column -> largest interval half-width allowed, in the column's unit.

    Returns
    -------
    dict
        The row: ``subject``, ``status`` (``"ok"`` or ``"error: <one line>"``), every metric
        column (mL, %, g, deg ...; NaN where not measured or on failure), ``QC``, the
        interval, range, ``Sex``, ``warnings`` and ``notes`` cells.
    """
    _test_fault(path)
    row: dict[str, Any] = {c: NAN for c in _NUMBERS}
    row["subject"], row["warnings"], row["notes"] = Path(path).name, NAN, ""
    try:
        from cardionurbs.io import load_study
        from cardionurbs.pipeline import analyse_study
        study = load_study(path, format=format, allow_outside=allow_outside, labels=labels)
        row["subject"] = study.subject
        from cardionurbs.analysis.quality import assess
        model, metrics = analyse_study(study, heart_rate_bpm=heart_rate_bpm)
        row.update(metrics)
        row.update(assess(model, metrics).row())
        if uncertainty or max_halfwidth:
            row.update(measure_intervals(model, metrics, row, uncertainty, max_halfwidth))
        row.update(_clinical_cells(model, metrics))
        row["status"] = "ok"
        if strict and row["QC"]:
            row.update({c: NAN for c in COLUMNS + INTERVAL_COLUMNS if c in row})
            row["status"] = f"error: QC: {row['QC']}"
    except Exception as exc:  # noqa: BLE001 - recorded in the row, the run goes on
        kind = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
        row.update({c: NAN for c in _NUMBERS + INTERVAL_COLUMNS if c in _NUMBERS or c in row})
        row["warnings"], row["notes"] = NAN, ""
        row["status"] = f"error: {kind}{_one_line(exc)}"
    return row


def measure_intervals(model, metrics: dict, row: dict, columns: bool,
                      max_halfwidth: dict[str, float] | None) -> dict:
    """The interval columns of one row (``columns``) and its ``QC`` with the half-width
    flags of ``max_halfwidth`` added.

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model of the study.
    metrics : dict
        Its metrics (:func:`cardionurbs.pipeline.analyse_study`).
    row : dict
        The row so far (its ``QC`` cell is extended).
    columns : bool
        Return the ``<column> lo95`` / ``hi95`` columns too.
    max_halfwidth : dict of str to float or None
        Column -> largest interval half-width allowed, in the column's unit.

    Returns
    -------
    dict
        The interval columns (when ``columns``; in each metric's unit) and ``QC``: the row's
        flags with the half-width flags appended (``"; "``-separated).
    """
    iv = intervals(model, metrics)
    flags = halfwidth_flags(iv, max_halfwidth or {})
    qc = "; ".join([q for q in [row.get("QC") or ""] if q] + flags)
    return {**(interval_columns(iv) if columns else {}), "QC": qc}
def _clinical_cells(model, metrics: dict) -> dict:
    """Sex, the ``<column> range`` flags, the warning count and the ``notes`` cell of a row."""
    from cardionurbs.analysis.notes import notes_of, notes_text
    from cardionurbs.analysis.ranges import range_columns, range_flags
    from cardionurbs.pipeline import analysis_warnings, body_json
    body = body_json(model.study)
    warnings = analysis_warnings(model, metrics)
    return {"Sex": body.get("sex") or NAN,
            **range_columns(range_flags(metrics, body.get("sex"), body.get("age_y"))),
            "warnings": len(warnings), "notes": notes_text(notes_of(metrics), warnings)}


def failure_row(path: str, reason: str) -> dict:
    """The row of a study that gave no result (a hang, a dead worker): reason, empty numbers.

    Parameters
    ----------
    path : str
        The study path (its last component becomes ``subject``).
    reason : str
        Why no result came (e.g. ``"timeout: 600 s"``); whitespace collapsed to one line.

    Returns
    -------
    dict
        A row with ``status = "error: <reason>"`` and every number NaN.
    """
    row: dict[str, Any] = {c: NAN for c in _NUMBERS}
    row["warnings"], row["notes"] = NAN, ""
    row["subject"] = Path(path).name
    row["status"] = f"error: {' '.join(str(reason).split())}"
    return row


_ROW_FILE = re.compile(r"\.?[0-9a-f]{20}\.json(\.\d+\.tmp)?")


class RowStore:
    """Finished rows of a cohort run, one small JSON file per subject under ``folder/rows``.

    A row is written to a temporary file, flushed and fsynced, renamed into place and
    the folder fsynced: once :meth:`put` returns the row survives a crash of the process
    or the machine. Rows are keyed by the study path as given (plus the format), so a
    rerun with the same arguments finds them.

    Parameters
    ----------
    folder : path-like
        The run directory (``--run-dir``); rows go to ``folder/rows``.
    """

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.rows_dir = self.folder / "rows"

    @staticmethod
    def key(path: str, format: str = "auto") -> str:
        """The file stem of a row.

        Parameters
        ----------
        path : str
            The study path as given to the cohort run.
        format : str, optional
            The study format.

        Returns
        -------
        str
            20 hexadecimal digits of the SHA-1 of format and path.
        """
        return hashlib.sha1(f"{format}\0{path}".encode()).hexdigest()[:20]

    def clear(self) -> None:
        """Forget every stored row (a fresh run). Only files named as :meth:`put` names
        them (``<20 hex digits>.json`` and their ``.<name>.<pid>.tmp`` temporaries) are
        removed, so a ``--run-dir`` that holds anything else keeps it."""
        if self.rows_dir.is_dir():
            for f in self.rows_dir.iterdir():
                if f.is_file() and _ROW_FILE.fullmatch(f.name):
                    f.unlink()

    def put(self, path: str, format: str, row: dict) -> None:
        """Store one finished row durably (written, fsynced, renamed into place).

        Parameters
        ----------
        path : str
            The study path as given to the cohort run.
        format : str
            The study format it was measured with.
        row : dict
            The row (NaN numbers stored as JSON null).
        """
        self.rows_dir.mkdir(parents=True, exist_ok=True)
        data = json.dumps({"path": path, "format": format,
                           "row": {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                   for k, v in row.items()}}, allow_nan=False)
        final = self.rows_dir / f"{self.key(path, format)}.json"
        tmp = self.rows_dir / f".{final.name}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
        fd = os.open(self.rows_dir, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def get(self, path: str, format: str = "auto") -> dict | None:
        """The stored row of one study (NaN for empty numbers), or None.

        Parameters
        ----------
        path : str
            The study path as given to the cohort run.
        format : str, optional
            The study format the row was measured with.

        Returns
        -------
        dict or None
            The row (NaN for its empty numbers), or None when none is stored for this path and
            format.
        """
        f = self.rows_dir / f"{self.key(path, format)}.json"
        try:
            d = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None                      # absent (or, impossibly, torn): measure again
        if d.get("path") != path or d.get("format") != format:
            return None
        return {k: (NAN if v is None and k not in ("subject", "status") else v)
                for k, v in d["row"].items()}


def cohort(paths: Iterable[str | os.PathLike], jobs: int = 1, *, format: str = "auto",
           progress: bool = False, heart_rate_bpm: float | None = None,
           dask: str | None = None, timeout: float | None = None,
           run_dir: str | os.PathLike | None = None, resume: bool = False,
           allow_outside: bool = False, labels: str | None = None,
           strict: bool = False, uncertainty: bool = True,
           max_halfwidth: dict[str, float] | None = None) -> pd.DataFrame:
    """Measure every study: a DataFrame, one row per path in input order, with ``subject``,
    ``status`` (a failure's error) and the docs/metrics.md columns (label maps: voxel counts).

    Parameters
    ----------
    paths : iterable of str or os.PathLike
        The study folders or files (as :func:`cardionurbs.io.load_study` takes them).
    jobs : int
        Worker processes (Dask workers for ``dask="local"``); 1: this process.
    format, allow_outside, labels
        Passed to :func:`cardionurbs.io.load_study` for every study.
    progress, heart_rate_bpm : bool; float or None
        A progress bar on stderr; the heart rate (bpm) of the studies that carry none.
    dask, timeout : str or None; float or None
        A Dask cluster (``"local"`` or a scheduler address); seconds per study before an error row.
    run_dir, resume : str, os.PathLike or None; bool
        Store each finished row durably in ``run_dir`` (:class:`RowStore`); resume from them.
    strict, uncertainty, max_halfwidth
        Flagged rows are failures; the 95 % interval columns; column -> largest 95 %
        half-width (the column's unit) before a row is flagged (:func:`measure_study`).

    Returns
    -------
    pandas.DataFrame
        Metrics in their docs/metrics.md units, NaN where a study cannot give one.

    Examples
    --------
    >>> import pathlib, tempfile, cardionurbs as cn
    >>> from cardionurbs.phantom import generate, write_phantom
    >>> phantom = generate("normal", seed=1, frames=2, n_sa=6, matrix=128, volume_check=False)
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = write_phantom(phantom, pathlib.Path(tmp.name) / "p1", dicom=False)
    >>> table = cn.cohort([folder])
    >>> table.loc[0, "subject"], table.loc[0, "status"], bool(table.loc[0, "LVEDV (mL)"] > 0)
    ('normal_001', 'ok', True)
    >>> tmp.cleanup()
    """
    from cardionurbs.executor import TaskFailure, run_tasks

    studies = [str(p) for p in paths]
    store = RowStore(run_dir) if run_dir is not None else None
    rows: list[dict | None] = [None] * len(studies)
    if store is not None:
        if resume:
            rows = [store.get(p, format) for p in studies]
        else:
            store.clear()
    todo = [i for i, r in enumerate(rows) if r is None]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(studies), initial=len(studies) - len(todo), desc="studies",
                   unit="study", file=sys.stderr)

    def finished(k: int, result) -> None:
        i = todo[k]
        if isinstance(result, TaskFailure):
            row = failure_row(studies[i], result.message if result.kind == "error" else str(result))
        else:
            row = result
        if store is not None:
            store.put(studies[i], format, row)
            rows[i] = store.get(studies[i], format)  # exactly what a resumed run would read
        else:
            rows[i] = row
        if bar is not None:
            bar.update(1)

    try:
        if dask is None and jobs <= 1 and timeout is None:
            for k, i in enumerate(todo):             # in this process: no worker to start
                try:
                    result: dict | TaskFailure = measure_study(
                        studies[i], format, heart_rate_bpm, allow_outside, labels, strict,
                        uncertainty, max_halfwidth)
                except Exception as exc:  # noqa: BLE001 - as a worker would report it
                    result = TaskFailure("error", f"{type(exc).__name__}: {_one_line(exc)}")
                finished(k, result)
        else:
            run_tasks(measure_study, [(studies[i], format, heart_rate_bpm, allow_outside, labels,
                                       strict, uncertainty, max_halfwidth)
                                      for i in todo],
                      finished, jobs=jobs, dask=dask, timeout=timeout)
    finally:
        if bar is not None:
            bar.close()
    from cardionurbs.analysis.voxels import VOXEL_COLUMNS
    extra = [c for c in VOXEL_COLUMNS if any(c in r for r in rows if r)]
    # the 95 % intervals (when measured) just before warnings and notes
    iv = [c for c in INTERVAL_COLUMNS if any(c in r for r in rows if r)]
    return pd.DataFrame(rows, columns=list(CSV_COLUMNS[:-2]) + iv + list(CSV_COLUMNS[-2:]) + extra)


def is_cohort_table(path: str | os.PathLike) -> bool:
    """True when ``path`` is a cohort table this package wrote: a CSV whose header line
    starts with ``subject,status,`` and the metric columns, or a Parquet file whose columns
    do (what ``--csv`` / ``--parquet`` may replace without ``--overwrite``).

    Parameters
    ----------
    path : path-like
        A CSV or ``.parquet`` file (need not exist).

    Returns
    -------
    bool
        Whether its header matches a cohort table's first columns (False when unreadable).
    """
    head = ",".join(CSV_COLUMNS[:4])
    p = Path(path)
    try:
        if p.suffix.lower() == ".parquet":
            import pyarrow.parquet as pq
            return ",".join(pq.read_schema(p).names[:4]) == head
        with open(p, "rb") as fh:
            return fh.readline(4096).decode("utf-8", "replace").startswith(head)
    except (OSError, ValueError, ImportError):
        return False


def write_csv(table: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write the cohort table as CSV, atomically (empty cells for NaN).

    Parameters
    ----------
    table : pandas.DataFrame
        The cohort table (text cells made spreadsheet-safe, :func:`cardionurbs.safe.csv_safe_table`).
    path : path-like
        The CSV file to write (replaced atomically).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from cardionurbs.safe import csv_safe_table
    return atomic.write_text(path, csv_safe_table(table).to_csv(index=False, float_format="%.6g"))


def write_parquet(table: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write the cohort table as Parquet (pyarrow), atomically.

    Parameters
    ----------
    table : pandas.DataFrame
        The cohort table.
    path : path-like
        The Parquet file to write (replaced atomically).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    with atomic.atomic_path(path) as tmp:
        table.to_parquet(tmp, index=False, engine="pyarrow")
    return Path(path)


#: exit status of ``cohort`` when the run finished but some study failed (without
#: ``--allow-failures``): distinct from 1 (internal error) and 2 (bad usage)
EXIT_SOME_FAILED = 3


def expand_folders(paths: Iterable[str]) -> list[str]:
    """Each path, or, for a folder that is no study but holds some (a dataset's tree), the
    studies below it (:func:`cardionurbs.io.studies_in`); a path with neither is kept so that
    its row names what is wrong with it.

    Parameters
    ----------
    paths : iterable of str
        The STUDY arguments.

    Returns
    -------
    list of str
        The studies to measure, in order.
    """
    from cardionurbs.io import studies_in
    out: list[str] = []
    for p in paths:
        found = studies_in(p)
        out += [str(q) for q in found] if found else [str(p)]
    return out


def run_cohort(args: argparse.Namespace) -> int:
    """`cardionurbs cohort STUDY... --csv FILE [--jobs N] [--dask local|tcp://HOST:PORT]
    [--timeout S] [--resume] [--run-dir DIR] [--parquet] [--allow-failures]`; ``--csv`` is
    checked (cardionurbs.io.outputs) before any study is read.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (``studies``, ``csv``, ``jobs`` and the options above).

    Returns
    -------
    int
        The exit code: 0, or :data:`EXIT_SOME_FAILED` (3) when a study failed without
        ``--allow-failures``.

    Raises
    ------
    cardionurbs.errors.UsageError
        A bad ``--dask`` address, or an output (``--csv``, ``--parquet``, ``--run-dir``) that
        may not be written (checked before any study is read).
    """
    from cardionurbs.executor import check_dask_address
    from cardionurbs.io.outputs import check_output_file, check_output_place
    from cardionurbs.pipeline import study_folder
    if getattr(args, "dask", None):
        check_dask_address(args.dask)           # before any file is touched
    args.studies = expand_folders(args.studies)
    studies = [study_folder(s) for s in args.studies]
    overwrite = getattr(args, "overwrite", False)
    check_output_file(args.csv, inputs=studies, option="--csv", ours=is_cohort_table,
                      overwrite=overwrite)
    csv = Path(args.csv)
    if getattr(args, "parquet", False):
        check_output_file(csv.with_suffix(".parquet"), inputs=studies, option="--parquet",
                          ours=is_cohort_table, overwrite=overwrite)
    run_dir = getattr(args, "run_dir", None) or csv.with_name(csv.name + ".rows")
    check_output_place(run_dir, inputs=studies,
                       option="--run-dir" if getattr(args, "run_dir", None) else "--csv")
    table = cohort(args.studies, jobs=args.jobs, format=getattr(args, "format", "auto"),
                   progress=sys.stderr.isatty(), dask=getattr(args, "dask", None),
                   timeout=getattr(args, "timeout", None), run_dir=run_dir,
                   resume=getattr(args, "resume", False),
                   allow_outside=getattr(args, "allow_outside", False),
                   labels=getattr(args, "labels", None),
                   strict=getattr(args, "strict", False),
                   uncertainty=getattr(args, "uncertainty", "on") == "on",
                   max_halfwidth=getattr(args, "max_halfwidth", None))
    write_csv(table, csv)
    wrote = [str(csv)]
    if getattr(args, "parquet", False):
        wrote.append(str(write_parquet(table, csv.with_suffix(".parquet"))))
    failed = table[table["status"] != "ok"]
    print(f"cohort: {len(table) - len(failed)} of {len(table)} studies measured, "
          f"{len(failed)} failed; wrote {', '.join(wrote)}", file=sys.stderr)
    for _, r in failed.iterrows():
        print(f"  {r['subject']}: {r['status']}", file=sys.stderr)
    if len(failed) and not getattr(args, "allow_failures", False):
        return EXIT_SOME_FAILED
    return 0
