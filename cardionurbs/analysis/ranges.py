"""Age- and sex-specific normal ranges and the below / normal / above flag of each metric
(docs/metrics.md, Reference ranges).

The ranges are data: ``cardionurbs/data/reference_ranges.json`` holds one published source
(its ``citation``, ``url``, what was ``checked`` and what is ``missing``), the ``columns``
read against it and ``rows`` of::

    {"column": "LVEF (%)", "sex": "M" | "F" | null (both), "age_min": 45, "age_max": 74,
     "mean": 58, "sd": 5, "where": "Abstract, Results"}

(``age_min``/``age_max`` inclusive years, null for no bound; a row gives either the
published ``lower`` and ``upper`` limits or the published ``mean`` and ``sd``, whose limits
are mean ∓ ``sd_multiplier`` · SD). A metric is ``below`` when it is under the lower limit,
``above`` when over the upper one, else ``normal``; its flag is None, with the reason, when
the metric is null, when the source has no row for it, when the subject's sex or age is
unknown, or when no row covers that sex and age.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from importlib import resources
from typing import Any, Mapping

FLAGS = ("below", "normal", "above")
NOT_COVERED = "not in the reference source"


@lru_cache(maxsize=1)
def load_ranges() -> dict:
    """The packaged reference-range file (citation, url, columns, rows; see the module).

    Returns
    -------
    dict
        The parsed ``cardionurbs/data/reference_ranges.json``, checked by
        :func:`check_table`.
    """
    text = resources.files("cardionurbs").joinpath("data/reference_ranges.json").read_text("utf-8")
    return check_table(json.loads(text))


def check_table(table: dict) -> dict:
    """``table`` unchanged when its rows are well formed, else ValueError naming the row.

    Each row names a column of ``columns``, a sex of M / F / null, and either a published
    limit or a mean and a positive SD (with ``sd_multiplier`` set).

    Parameters
    ----------
    table : dict
        Shaped as the packaged file (see the module).

    Returns
    -------
    dict
        ``table`` itself.
    """
    columns = set(table.get("columns") or [])
    for i, r in enumerate(table["rows"]):
        has_limits = r.get("lower") is not None or r.get("upper") is not None
        has_sd = r.get("mean") is not None and (r.get("sd") or 0) > 0
        if (r["column"] not in columns or r.get("sex") not in (None, "M", "F")
                or not (has_limits or (has_sd and table.get("sd_multiplier")))):
            raise ValueError(f"reference ranges: row {i} ({r.get('column')!r}) is malformed")
    return table


def _age_text(row: Mapping) -> str:
    lo, hi = row.get("age_min"), row.get("age_max")
    return f"{lo if lo is not None else ''}–{hi if hi is not None else ''} y"


def _matches(row: Mapping, sex: str | None, age: float | None) -> tuple[bool, str]:
    """(does ``row`` cover this sex and age, why not)."""
    lo, hi = row.get("age_min"), row.get("age_max")
    age_known = age is not None and math.isfinite(age)
    unknown = [what for what, needed, known in (("age", lo is not None or hi is not None, age_known),
                                                ("sex", row.get("sex") is not None, sex is not None))
               if needed and not known]
    if unknown:
        return False, " and ".join(unknown) + " unknown"
    if row.get("sex") is not None and row["sex"] != sex:
        return False, f"no row for sex {sex}"
    if age is not None and age_known and ((lo is not None and age < lo) or (hi is not None and age >= hi + 1)):
        return False, f"age {age:g} y is outside the source's ages ({_age_text(row)})"
    return True, ""


def find_range(column: str, sex: str | None, age: float | None,
               table: Mapping | None = None) -> tuple[dict | None, str]:
    """The row of ``column`` for this sex and age, and why there is none.

    Parameters
    ----------
    column : str
        A docs/metrics.md column, e.g. ``"LVEF (%)"``.
    sex : {"M", "F"} or None
    age : float or None
        Years.
    table : mapping, optional
        Shaped as the packaged file (default :func:`load_ranges`).

    Returns
    -------
    (dict or None, str)
        The first matching row (a copy) and ``""``; or None and the reason (those of
        the column's rows for this sex, else "no row for sex ...", joined with "and").
    """
    rows = [r for r in (table or load_ranges())["rows"] if r["column"] == column]
    if not rows:
        return None, NOT_COVERED
    why: dict[str, None] = {}
    for r in rows:
        ok, reason = _matches(r, sex, age)
        if ok:
            return dict(r), ""
        why[reason] = None
    near = [w for w in why if not w.startswith("no row for sex")]   # rows of this sex say why
    return None, " and ".join(sorted(near or why))


def limits(row: Mapping, table: Mapping | None = None) -> tuple[float | None, float | None, str]:
    """The limits of a row: its published ones, else mean ∓ k · SD.

    Parameters
    ----------
    row : mapping
        A row of the table (``lower``/``upper``, or ``mean`` and ``sd``).
    table : mapping, optional
        Gives ``k``, its ``sd_multiplier`` (default :func:`load_ranges`).

    Returns
    -------
    (float or None, float or None, str)
        Lower and upper limit (the column's unit) and how they were found, e.g.
        ``"mean 58 ∓ 1.96 × SD 5"`` or ``"as published"``.
    """
    if row.get("lower") is not None or row.get("upper") is not None:
        return row.get("lower"), row.get("upper"), "as published"
    k = float((table or load_ranges())["sd_multiplier"])
    mean, sd = float(row["mean"]), float(row["sd"])
    return mean - k * sd, mean + k * sd, f"mean {mean:g} ∓ {k:g} × SD {sd:g}"


def flag(value: float, lower: float | None, upper: float | None) -> str:
    """``below`` / ``normal`` / ``above`` of ``value`` against [lower, upper] (inclusive).

    Parameters
    ----------
    value : float
    lower, upper : float or None
        The limits, in the unit of ``value``; None for no limit.

    Returns
    -------
    str
        One of :data:`FLAGS`.
    """
    if lower is not None and value < lower:
        return "below"
    if upper is not None and value > upper:
        return "above"
    return "normal"


def _bound_text(f: str, lower: float | None, upper: float | None, how: str) -> str:
    """The bound a flag is read against, named (``under the lower limit 48.2 (…)``)."""
    def fmt(x: float | None) -> str:
        return "" if x is None else f"{x:.1f}"
    if f == "below":
        return f"under the lower limit {fmt(lower)} ({how})"
    if f == "above":
        return f"over the upper limit {fmt(upper)} ({how})"
    return f"within {fmt(lower)}–{fmt(upper)} ({how})"


def _number(value: Any) -> float | None:
    """``value`` as a float, None when it is not a number (None, a bool, a string)."""
    if value is None or isinstance(value, (bool, str)):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _entry(column: str, value: Any, sex: str | None, age: float | None, table: Mapping,
           notes: Mapping[str, str]) -> dict:
    """One metric's flag entry (see :func:`range_flags`)."""
    entry: dict[str, Any] = {"flag": None, "lower": None, "upper": None, "where": None,
                             "bound": None, "reason": ""}
    row, why = find_range(column, sex, age, table)
    number = _number(value)
    if row is not None:
        lower, upper, how = limits(row, table)
        entry.update(lower=lower, upper=upper, where=row.get("where"))
    if why != NOT_COVERED and (number is None or not math.isfinite(number)):
        entry["reason"] = "metric is null" + (f": {notes[column]}" if notes.get(column) else "")
        return entry                # (the metric's own reason before the demographics')
    if row is None or number is None:
        entry["reason"] = why
        return entry
    entry["flag"] = flag(number, lower, upper)
    entry["bound"] = _bound_text(entry["flag"], lower, upper, how)
    return entry


def range_flags(metrics: Mapping, sex: str | None = None, age: float | None = None,
                table: Mapping | None = None) -> dict[str, dict]:
    """Per column the source is read for (the table's ``columns``): its flag entry.

    Parameters
    ----------
    metrics : mapping
        docs/metrics.md column -> float (NaN / None where null); when it has ``notes``
        (:class:`cardionurbs.analysis.notes.Metrics`), a null metric's reason is quoted.
    sex : {"M", "F"} or None
    age : float or None
        Years.
    table : mapping, optional
        A range table shaped as the packaged file (default: :func:`load_ranges`).

    Returns
    -------
    dict
        column -> ``{"flag": "below" | "normal" | "above" | None, "lower", "upper"
        (the limits, in the column's unit), "where" (in the source), "bound" (the limit the
        flag is read against, named), "reason" (why ``flag`` is None, else "")}``.
    """
    table = table or load_ranges()
    notes = getattr(metrics, "notes", None) or {}
    columns = table.get("columns") or list(dict.fromkeys(r["column"] for r in table["rows"]))
    return {c: _entry(c, metrics.get(c), sex, age, table, notes) for c in columns}


def range_columns(flags: Mapping[str, dict]) -> dict[str, str | None]:
    """The cohort CSV's ``<column> range`` cells.

    Parameters
    ----------
    flags : mapping
        :func:`range_flags` result.

    Returns
    -------
    dict
        ``"<column> range"`` -> ``below`` / ``normal`` / ``above`` or None.
    """
    return {f"{c} range": e["flag"] for c, e in flags.items()}


def range_column_names(table: Mapping | None = None) -> tuple[str, ...]:
    """The ``<column> range`` CSV column names, in the table's ``columns`` order.

    Parameters
    ----------
    table : mapping, optional
        Default :func:`load_ranges`.

    Returns
    -------
    tuple of str
    """
    table = table or load_ranges()
    columns = table.get("columns") or list(dict.fromkeys(r["column"] for r in table["rows"]))
    return tuple(f"{c} range" for c in columns)
