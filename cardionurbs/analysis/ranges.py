"""Age- and sex-specific normal ranges and the below / normal / above flag of each metric
(docs/metrics.md, Reference ranges).

The ranges are data: ``cardionurbs/data/reference_ranges.json`` holds one published source
(its ``citation``) and ``rows`` of::

    {"column": "LVEDVi (mL/m²)", "sex": "M" | "F" | null (both), "age_min": 20, "age_max": 29,
     "lower": 57, "upper": 105, "table": "Table 2"}

(``age_min``/``age_max`` inclusive years, null for no bound). A metric is ``below`` when
it is under ``lower``, ``above`` when over ``upper``, else ``normal``; it has no flag (None,
with the reason) when it is null, when no row matches the subject's sex and age, or when
the sex or age a row needs is unknown.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from importlib import resources
from typing import Mapping

FLAGS = ("below", "normal", "above")


@lru_cache(maxsize=1)
def load_ranges() -> dict:
    """The packaged reference-range file (citation, technique, rows)."""
    text = resources.files("cardionurbs").joinpath("data/reference_ranges.json").read_text("utf-8")
    return json.loads(text)


def _matches(row: Mapping, sex: str | None, age: float | None) -> tuple[bool, str]:
    if row.get("sex") is not None:
        if sex is None:
            return False, "sex unknown"
        if row["sex"] != sex:
            return False, ""
    lo, hi = row.get("age_min"), row.get("age_max")
    if lo is not None or hi is not None:
        if age is None or not math.isfinite(age):
            return False, "age unknown"
        if (lo is not None and age < lo) or (hi is not None and age >= hi + 1):
            return False, ""
    return True, ""


def find_range(column: str, sex: str | None, age: float | None,
               table: Mapping | None = None) -> tuple[dict | None, str]:
    """(the row for ``column`` at this sex and age, or None; why none when None).

    Parameters
    ----------
    column : str
        A docs/metrics.md column.
    sex : {"M", "F"} or None
        The subject's sex.
    age : float or None
        Years.
    table : mapping or None
        A range table; None: the packaged one (:func:`load_ranges`).

    Returns
    -------
    row : dict or None
        The reference row (``lower``, ``upper`` in the column's unit).
    reason : str
        Why there is none ("" with a row).
    """
    rows = [r for r in (table or load_ranges())["rows"] if r["column"] == column]
    if not rows:
        return None, "no reference range"
    why = set()
    for r in rows:
        ok, reason = _matches(r, sex, age)
        if ok:
            return dict(r), ""
        if reason:
            why.add(reason)
    return None, " and ".join(sorted(why)) or "no reference range for this sex and age"


def flag(value: float, lower: float | None, upper: float | None) -> str:
    """``below`` / ``normal`` / ``above`` of ``value`` against [lower, upper] (inclusive).

    Parameters
    ----------
    value : float
        The metric, in its unit.
    lower, upper : float or None
        The range's bounds (None: unbounded).

    Returns
    -------
    str
    """
    if lower is not None and value < lower:
        return "below"
    if upper is not None and value > upper:
        return "above"
    return "normal"


def range_flags(metrics: Mapping, sex: str | None = None, age: float | None = None,
                table: Mapping | None = None) -> dict[str, dict]:
    """Per metric with a reference row: ``{"flag": below|normal|above|None, "lower",
    "upper", "table", "reason"}`` (``reason`` says why ``flag`` is None).

    Parameters
    ----------
    metrics : mapping
        docs/metrics.md column -> float (NaN / None where null).
    sex : {"M", "F"} or None
        The subject's sex.
    age : float or None
        Years.
    table : mapping, optional
        A range table shaped as the packaged file (default: :func:`load_ranges`).

    Returns
    -------
    dict of str to dict
        Column -> its entry.
    """
    table = table or load_ranges()
    out: dict[str, dict] = {}
    for column in dict.fromkeys(r["column"] for r in table["rows"]):
        if column not in metrics:
            continue
        row, why = find_range(column, sex, age, table)
        entry = {"flag": None, "lower": None, "upper": None, "table": None, "reason": why}
        if row is not None:
            entry.update(lower=row.get("lower"), upper=row.get("upper"), table=row.get("table"),
                         reason="")
            value = metrics.get(column)
            if value is None or not math.isfinite(float(value)):
                entry["reason"] = "metric is null"
            else:
                entry["flag"] = flag(float(value), row.get("lower"), row.get("upper"))
        out[column] = entry
    return out


def range_columns(flags: Mapping[str, dict]) -> dict[str, str | None]:
    """The cohort CSV's ``<column> range`` cells (``below``/``normal``/``above``, None).

    Parameters
    ----------
    flags : mapping of str to dict
        :func:`range_flags`' output.

    Returns
    -------
    dict of str to str or None
    """
    return {f"{c} range": e["flag"] for c, e in flags.items()}
