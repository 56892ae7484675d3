"""Body surface area and the indexed columns (docs/metrics.md, Body size).

BSA by Mosteller (N Engl J Med 1987;317:1098)::

    BSA (m²) = sqrt(height (cm) · weight (kg) / 3600)

Indexed column = column / BSA (``LVEDVi (mL/m²)`` = ``LVEDV (mL)`` / BSA, ``CI`` = LVCO /
BSA). Without height or weight every indexed column is null with the reason.
"""

from __future__ import annotations

import math
from typing import Mapping

from cardionurbs.analysis.notes import null

NAN = float("nan")
BODY_COLUMNS = ("Height (cm)", "Weight (kg)", "Age (y)", "BSA (m²)")
#: indexed column -> the column it divides by BSA
INDEXED = {
    "LVEDVi (mL/m²)": "LVEDV (mL)", "LVESVi (mL/m²)": "LVESV (mL)", "LVSVi (mL/m²)": "LVSV (mL)",
    "LVMi (g/m²)": "LVM (g)",
    "RVEDVi (mL/m²)": "RVEDV (mL)", "RVESVi (mL/m²)": "RVESV (mL)", "RVSVi (mL/m²)": "RVSV (mL)",
    "CI (L/min/m²)": "LVCO (L/min)",
}
INDEXED_COLUMNS = tuple(INDEXED)


def bsa_mosteller(height_cm: float, weight_kg: float) -> float:
    """Body surface area (m²) by Mosteller: sqrt(height cm · weight kg / 3600).

    Parameters
    ----------
    height_cm : float
        Height, cm.
    weight_kg : float
        Weight, kg.

    Returns
    -------
    float
        m².
    """
    return math.sqrt(float(height_cm) * float(weight_kg) / 3600.0)


def _num(x) -> float:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return NAN
    return x if math.isfinite(x) else NAN


def add_body_columns(metrics: dict, body: Mapping | None) -> dict:
    """Add :data:`BODY_COLUMNS` and :data:`INDEXED_COLUMNS` to ``metrics`` (in place).

    Parameters
    ----------
    metrics : dict
        docs/metrics.md column -> float, with the unindexed columns already measured.
    body : mapping or None
        ``study.meta["body"]`` (:func:`cardionurbs.io.body.attach_body`): ``height_cm``,
        ``weight_kg``, ``age_y`` (None where unknown).

    Returns
    -------
    dict
        ``metrics``; a column that cannot be given is null with its reason.
    """
    body = dict(body or {})
    h, w, age = _num(body.get("height_cm")), _num(body.get("weight_kg")), _num(body.get("age_y"))
    metrics["Height (cm)"], metrics["Weight (kg)"], metrics["Age (y)"] = h, w, age
    for column, value, option in (("Height (cm)", h, "--height-cm"), ("Weight (kg)", w, "--weight-kg"),
                                  ("Age (y)", age, "--age")):
        if math.isnan(value):
            null(metrics, column, f"not in the study (give {option})")
    if math.isnan(h) or math.isnan(w):
        missing = " and ".join(n for n, v in (("height", h), ("weight", w)) if math.isnan(v))
        null(metrics, "BSA (m²)", f"no {missing}: give --height-cm and --weight-kg")
        for column in INDEXED:
            null(metrics, column, "body size unknown (no BSA)")
        return metrics
    bsa = bsa_mosteller(h, w)
    metrics["BSA (m²)"] = bsa
    for column, source in INDEXED.items():
        metrics[column] = _num(metrics.get(source)) / bsa
    return metrics
