"""Why a metric is null, and every warning of an analysis (docs/metrics.md, Notes and warnings).

A metric the study cannot give is NaN (None in metrics.json, an empty cell in the CSV),
never 0, and has one reason. Call :func:`null` from anywhere in the analysis::

    from cardionurbs.analysis.notes import null
    null(metrics, "LVEF (%)", "one frame only")    # metrics: the dict being filled

``metrics`` is the :class:`Metrics` dict that :func:`cardionurbs.analysis.function.measure`
returns (a plain dict gets the NaN without the reason). A reader (io layer, no access to the
metrics) records a reason in ``study.meta["metric_notes"]`` (column -> reason); the
analysis adopts those (:func:`adopt_study_notes`).

Warnings carry their source: ``load`` (``study.warnings``), ``reconstruct``
(``model.warnings``) and ``measure`` (``metrics.warnings``, the tag and regional notes);
:func:`collect_warnings` lists them as ``{"source", "message"}`` for metrics.json.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

NAN = float("nan")

#: the sources of a warning, in the order of an analysis
SOURCES = ("load", "reconstruct", "measure")


class Metrics(dict):
    """docs/metrics.md column -> float (NaN where not measured), with ``notes``
    (column -> why it is null) and ``warnings`` (one-line measure warnings).

    Parameters
    ----------
    *args, **kwargs
        As for :class:`dict`: the columns and their values.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.notes: dict[str, str] = {}
        self.warnings: list[str] = []

    def copy(self) -> "Metrics":
        """A copy of the columns, the notes and the warnings.

        Returns
        -------
        Metrics
            A shallow copy, with copies of ``notes`` and ``warnings``.
        """
        out = Metrics(self)
        out.notes, out.warnings = dict(self.notes), list(self.warnings)
        return out


def notes_of(metrics: Mapping) -> dict[str, str]:
    """The ``notes`` dict of ``metrics`` ({} for a mapping without one).

    Parameters
    ----------
    metrics : mapping
        A :class:`Metrics` or any column -> value mapping.

    Returns
    -------
    dict of str to str
        Column -> reason it is null.
    """
    return getattr(metrics, "notes", {})


def null(metrics: dict, column: str, reason: str, *, keep_first: bool = True) -> None:
    """Make ``column`` null (NaN) in ``metrics`` and record why.

    Parameters
    ----------
    metrics : dict
        The metrics being filled (a :class:`Metrics`; for a plain dict only the value is set).
    column : str
        A docs/metrics.md column name.
    reason : str
        Short, for a reader: ``"one frame only"``, ``"no RV contours"``.
    keep_first : bool
        Keep an earlier reason (the first cause is the one worth reading).
    """
    metrics[column] = NAN
    notes = getattr(metrics, "notes", None)
    if notes is not None and (not keep_first or column not in notes):
        notes[column] = " ".join(str(reason).split())


def warn(metrics: dict, message: str) -> None:
    """Record a measure warning (one line) on ``metrics`` (a :class:`Metrics`).

    Parameters
    ----------
    metrics : Metrics
        The metrics the warning is about.
    message : str
        The warning, one line.
    """
    if hasattr(metrics, "warnings"):
        metrics.warnings.append(" ".join(str(message).split()))


def is_null(value) -> bool:
    """True for None and NaN (a metric with no number).

    Parameters
    ----------
    value : object
        A metric value.

    Returns
    -------
    bool
    """
    if value is None:
        return True
    try:
        return math.isnan(float(value))
    except (TypeError, ValueError):
        return False


def adopt_study_notes(metrics: dict, meta: Mapping | None) -> None:
    """Reasons a reader recorded (``study.meta["metric_notes"]``, column -> reason) for
    columns it knows the study cannot give: those columns become null with that reason.

    Parameters
    ----------
    metrics : Metrics
        The metrics, changed in place.
    meta : mapping or None
        ``study.meta``.
    """
    for column, reason in dict((meta or {}).get("metric_notes") or {}).items():
        if column in metrics:
            null(metrics, column, reason)


def explain_missing(metrics: dict, reasons: Iterable[tuple[Iterable[str], str]],
                    columns: Iterable[str] | None = None) -> None:
    """Give every null column without a reason the first matching one.

    ``reasons``: (columns, reason) pairs tried in order; ``columns``: which columns to
    consider (default: all of ``metrics``).

    Parameters
    ----------
    metrics : Metrics
        The metrics, whose ``notes`` are filled in place.
    reasons : iterable of (iterable of str, str)
        (columns, reason) pairs, tried in order.
    columns : iterable of str or None
        The columns to consider; None: all of ``metrics``.
    """
    notes = getattr(metrics, "notes", None)
    if notes is None:
        return
    table = [(set(cols), why) for cols, why in reasons]
    for column in (metrics if columns is None else columns):
        if column in notes or not is_null(metrics.get(column)):
            continue
        for cols, why in table:
            if column in cols:
                notes[column] = why
                break


def collect_warnings(study=None, model=None, metrics: Mapping | None = None,
                     measure_notes: Iterable[str] = ()) -> list[dict[str, str]]:
    """Every warning of one analysis as ``[{"source": load|reconstruct|measure,
    "message": ...}]`` (duplicates within a source dropped, order kept).

    Parameters
    ----------
    study : Study or None
        Its ``warnings`` are the ``load`` ones.
    model : BiventricularModel or None
        Its ``warnings`` are the ``reconstruct`` ones.
    metrics : mapping or None
        Its ``warnings`` (a :class:`Metrics`) are ``measure`` ones.
    measure_notes : iterable of str
        More ``measure`` warnings.

    Returns
    -------
    list of dict
        ``{"source": ..., "message": ...}`` in order.
    """
    out: list[dict[str, str]] = []
    parts = (("load", getattr(study, "warnings", None) or []),
             ("reconstruct", getattr(model, "warnings", None) or []),
             ("measure", list(getattr(metrics, "warnings", None) or []) + list(measure_notes)))
    for source, messages in parts:
        seen: set[str] = set()
        for m in messages:
            m = " ".join(str(m).split())
            if m and m not in seen:
                seen.add(m)
                out.append({"source": source, "message": m})
    return out


#: columns named first in a notes cell (what a reader looks for)
HEADLINE = ("LVEF (%)", "RVEF (%)", "LVEDV (mL)", "RVEDV (mL)", "LVM (g)", "RVM (g)",
            "LVSV (mL)", "LVCO (L/min)", "HR (bpm)", "BSA (m²)", "LVEDVi (mL/m²)", "Twist (deg)")


def notes_text(notes: Mapping[str, str], warnings: list[dict] | None = None, *,
               reasons: int = 3, shown_warnings: int = 2) -> str:
    """One readable cell for the cohort CSV: the first ``reasons`` null reasons, grouped
    by reason, each as ``LVEF (%): one frame only (also LVESV (mL) and 40 more)``, then
    the first ``shown_warnings`` warnings (``load: ...``), ``; ``-separated, and
    ``(+N more)`` for what is left out (all of it is in metrics.json).

    Parameters
    ----------
    notes : mapping of str to str
        Column -> reason it is null.
    warnings : list of dict or None
        :func:`collect_warnings`'s list.
    reasons : int
        How many reasons are shown.
    shown_warnings : int
        How many warnings are shown.

    Returns
    -------
    str
        The cell (empty when there is nothing to say).
    """
    groups: dict[str, list[str]] = {}
    for column in sorted(notes, key=lambda c: HEADLINE.index(c) if c in HEADLINE else 99):
        groups.setdefault(notes[column], []).append(column)
    items = []
    for reason, cols in groups.items():
        also = ""
        if len(cols) > 1:
            more = len(cols) - 2
            also = f" (also {cols[1]}" + (f" and {more} more)" if more > 0 else ")")
        items.append(f"{cols[0]}: {reason}{also}")
    warned = [f"{w['source']}: {w['message']}" for w in (warnings or [])]
    shown = items[:reasons] + warned[:shown_warnings]
    left = len(items) + len(warned) - len(shown)
    return "; ".join(shown) + (f" (+{left} more)" if left else "")
