"""Body size and demographics of a study: height, weight, age, sex (docs/metrics.md, Body size).

:func:`attach_body` fills ``study.meta["body"]`` = ``{"height_cm", "weight_kg", "age_y",
"sex", "source": {field: where it came from}}`` from, first wins:

1. the values given by the user (``analyze --height-cm --weight-kg --age --sex``);
2. the native manifest (study.json ``meta``: ``height_cm``, ``weight_kg``, ``age_y`` or
   ``age``, ``sex``; or the same keys in ``meta["body"]``);
3. the dataset's own files: ACDC ``Info.cfg`` (``Height`` cm, ``Weight`` kg, read by the
   NIfTI reader into ``meta``), the M&Ms CSV row of the subject (``Age``, ``Sex``,
   ``Height``, ``Weight``);
4. the DICOM header of the study's first image (``PatientSize`` m, ``PatientWeight`` kg,
   ``PatientAge`` ``nnnY|M|W|D``, ``PatientSex`` ``M|F``).

A value that is not a plausible number (height 30–250 cm, weight 1–400 kg, age 0–120 y;
sex ``M`` or ``F``) is left out with a warning naming its source; a user-given one is
refused (:class:`~cardionurbs.errors.UsageError`).
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Mapping

from cardionurbs.errors import UsageError

FIELDS = ("height_cm", "weight_kg", "age_y", "sex")
#: plausible values (inclusive), per field
LIMITS = {"height_cm": (30.0, 250.0), "weight_kg": (1.0, 400.0), "age_y": (0.0, 120.0)}
_AGE_UNITS = {"Y": 1.0, "M": 1 / 12, "W": 7 / 365.25, "D": 1 / 365.25}


def clean_value(field: str, value) -> float | str | None:
    """``value`` as the field's number (str for ``sex``: ``"M"``/``"F"``); None when absent
    or unknown (``""``, ``"O"``); ValueError naming the field when implausible.

    Parameters
    ----------
    field : {"height_cm", "weight_kg", "age_y", "sex"}
        The field (:data:`FIELDS`).
    value : object
        The raw value (number or text).

    Returns
    -------
    float, str or None
        cm, kg or years; ``"M"``/``"F"`` for ``sex``; None when absent or unknown.

    Raises
    ------
    ValueError
        An implausible value (naming the field).
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    if field == "sex":
        s = str(value).strip().upper()
        s = {"MALE": "M", "FEMALE": "F", "MAN": "M", "WOMAN": "F"}.get(s, s)
        if s in ("M", "F"):
            return s
        if s in ("O", "U", "OTHER", "UNKNOWN"):
            return None
        raise ValueError(f"sex {value!r} is not M or F")
    if field == "age_y" and isinstance(value, str):
        m = re.fullmatch(r"\s*(\d{1,3})\s*([YMWD]?)\s*", value.upper())
        if not m:
            raise ValueError(f"age {value!r} is not a number of years (or DICOM nnnY/M/W/D)")
        value = int(m.group(1)) * _AGE_UNITS[m.group(2) or "Y"]
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} {value!r} is not a number") from None
    lo, hi = LIMITS[field]
    if not (math.isfinite(x) and lo <= x <= hi):
        raise ValueError(f"{field} {value!r} is outside {lo:g}-{hi:g}")
    return x


def _merge(body: dict, values: Mapping, source: str, warnings: list[str]) -> None:
    for field in FIELDS:
        if body.get(field) is not None or field not in values:
            continue
        try:
            v = clean_value(field, values[field])
        except ValueError as exc:
            warnings.append(f"{source}: {exc}; left out")
            continue
        if v is not None:
            body[field] = v
            body["source"][field] = source


def _manifest_values(meta: Mapping) -> dict:
    d = dict(meta.get("body") or {}) if isinstance(meta.get("body"), Mapping) else {}
    for key in FIELDS + ("age",):
        if key in meta and not isinstance(meta[key], Mapping):
            d.setdefault("age_y" if key == "age" else key, meta[key])
    return d


def mnms_values(folder: Path, code: str) -> dict:
    """Age, sex, height and weight of M&Ms subject ``code`` from a CSV beside its folder
    ({} when there is none).

    Parameters
    ----------
    folder : pathlib.Path
        The subject's folder.
    code : str
        The subject's M&Ms code.

    Returns
    -------
    dict
        Field (:data:`FIELDS`) -> raw value found.
    """
    keys = {"age": "age_y", "sex": "sex", "height": "height_cm", "weight": "weight_kg"}
    for d in (folder, folder.parent):
        for q in sorted(d.glob("*.csv")):
            try:
                with q.open(newline="", errors="replace") as fh:
                    for row in csv.DictReader(fh):
                        row = {(k or "").strip().lower(): v for k, v in row.items()}
                        if (row.get("external code") or "").strip() == code:
                            return {keys[k]: v for k, v in row.items() if k in keys}
            except (OSError, csv.Error):
                continue
    return {}


def dicom_values(path: str | Path) -> dict:
    """Height (cm), weight, age and sex from one DICOM header ({} when unreadable).

    Parameters
    ----------
    path : str or pathlib.Path
        A DICOM file.

    Returns
    -------
    dict
        Field (:data:`FIELDS`) -> value: cm, kg, years, ``"M"``/``"F"``.
    """
    import pydicom
    try:
        ds = pydicom.dcmread(str(path), stop_before_pixels=True, force=True)
    except Exception:  # noqa: BLE001 - demographics are optional
        return {}
    out: dict = {}
    size = ds.get("PatientSize")
    if size not in (None, ""):
        try:
            out["height_cm"] = float(size) * 100.0
        except (TypeError, ValueError):
            out["height_cm"] = str(size)
    for key, field in (("PatientWeight", "weight_kg"), ("PatientAge", "age_y"),
                       ("PatientSex", "sex")):
        v = ds.get(key)
        if v not in (None, ""):
            out[field] = str(v) if key != "PatientWeight" else v
    return out


def _first_dicom(study) -> Path | None:
    from cardionurbs.confine import is_inside
    folder = Path(study.source or ".")
    folder = folder if folder.is_dir() else folder.parent
    for im in study.images:
        f = getattr(im, "file", None)
        if f and (folder / f).is_file() and is_inside(folder, folder / f):
            return folder / f
    return None


def attach_body(study, given: Mapping | None = None) -> dict:
    """Fill ``study.meta["body"]`` (see the module docstring) and return it; warnings about
    left-out values are appended to ``study.warnings``. ``given``: the user's values
    (field -> value or None), refused with UsageError when implausible.

    Parameters
    ----------
    study : Study
        The study; ``meta["body"]`` and ``warnings`` are filled in place.
    given : mapping or None
        The user's values, field (:data:`FIELDS`) -> value or None.

    Returns
    -------
    dict
        ``study.meta["body"]``: the four fields (cm, kg, years, sex; None where unknown) and
        ``source``: field -> where it came from.

    Raises
    ------
    UsageError
        An implausible user-given value.
    """
    body: dict = {f: None for f in FIELDS}
    body["source"] = {}
    for field, value in (given or {}).items():
        if value is not None:
            try:
                body[field] = clean_value(field, value)
            except ValueError as exc:
                raise UsageError(f"--{field.replace('_', '-')}: {exc}") from None
            body["source"][field] = "command line"
    warnings: list[str] = []
    meta = study.meta if isinstance(study.meta, dict) else {}
    _merge(body, _manifest_values(meta), "study manifest" if meta.get("layout") != "acdc"
           else "Info.cfg", warnings)
    if str(meta.get("layout") or "").startswith("mnms") and study.source:
        _merge(body, mnms_values(Path(study.source), study.subject), "M&Ms CSV", warnings)
    if any(body[f] is None for f in FIELDS):
        dcm = _first_dicom(study)
        if dcm is not None:
            _merge(body, dicom_values(dcm), f"DICOM header {dcm.name}", warnings)
    study.meta["body"] = body
    old = list(study.warnings or [])
    study.warnings = old + [w for w in warnings if w not in old]
    return body
