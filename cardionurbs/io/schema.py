"""The strict schema of a native ``study.json``: types, ranges, depth, sizes.

:func:`check_manifest` runs before anything else is built from the manifest,
so that every malformed field ends in one :class:`~cardionurbs.errors.StudyError`
naming the file and the field (CLI exit 2), never in a TypeError deep inside.

Rules (``?`` = may be absent or null):

=====================  =====================================================
format                 ``"cardionurbs-native"``
version                the whole number 1
subject?               text, 1..MAX_NAME_LENGTH printable characters
heart_rate_bpm?        a number in HEART_RATE_RANGE_BPM (20..300 bpm)
frame_times_ms?        object: frame index text ("0", "1", ...) -> finite number
ed_frame?, es_frame?   a whole number 0..MAX_FRAMES-1
images                 list (at most MAX_IMAGES) of image objects (below)
points?                text (a relative file name inside the study)
points_rows?           a whole number >= 0: rows of ``points`` (truncation check)
coordinate_decimals?   a whole number 0..17: decimals of the coordinates in ``points``
points_sidecar?        text (a relative file name inside the study): points.parquet
meta?                  object
=====================  =====================================================

Image object: ``id``, ``slice`` (names as above), ``view`` (SA or LA),
``frame`` (whole number), ``position`` (3 finite numbers), ``orientation``
(6 finite numbers), ``pixel_spacing`` (2 numbers in PIXEL_SPACING_RANGE_MM),
``rows``?, ``columns``? (whole numbers 1..65535), ``thickness``? (a number in
THICKNESS_RANGE_MM), ``trigger_time``? (finite number), ``file``? (text).

Booleans are never accepted as numbers (``true`` is not frame 1), nor
numbers as text. The whole document may nest at most MAX_JSON_DEPTH levels.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from cardionurbs.confine import checked
from cardionurbs.errors import StudyError
from cardionurbs.limits import (HEART_RATE_RANGE_BPM, MAX_FRAMES, MAX_IMAGES, MAX_JSON_DEPTH,
                                MAX_MANIFEST_BYTES, MAX_POINTS_PER_STUDY, PIXEL_SPACING_RANGE_MM,
                                THICKNESS_RANGE_MM)
from cardionurbs.safe import check_name, excerpt

VIEWS = ("SA", "LA")


def load_manifest(path: Path) -> Any:
    """Parse ``path`` as JSON within the size and depth limits (StudyError otherwise).

    Parameters
    ----------
    path : pathlib.Path
        The ``study.json`` file.

    Returns
    -------
    object
        The parsed JSON (the caller checks its schema, :func:`check_manifest`).

    Raises
    ------
    StudyError
        Unreadable, too large, too deep or not JSON.
    """
    checked(path, what="manifest")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise StudyError(f"cannot read ({exc.strerror})", file=path) from None
    if size > MAX_MANIFEST_BYTES:
        raise StudyError(f"manifest is {size} bytes (limit {MAX_MANIFEST_BYTES})", file=path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise StudyError(f"JSON nested deeper than {MAX_JSON_DEPTH} levels", file=path) from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise StudyError(f"not valid JSON ({' '.join(str(exc).split())[:120]})", file=path) from None
    if _depth(doc) > MAX_JSON_DEPTH:
        field = next((k for k, v in doc.items() if _depth(v) >= MAX_JSON_DEPTH), None) \
            if isinstance(doc, dict) else None
        raise StudyError(f"JSON nested deeper than {MAX_JSON_DEPTH} levels", file=path,
                         field=field)
    return doc


def _depth(doc: Any) -> int:
    """Nesting depth of a JSON value (iterative: no recursion limit)."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, (dict, list)):
            deepest = max(deepest, d)
            if d > MAX_JSON_DEPTH:
                return d
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


class _Checker:
    def __init__(self, path: Path):
        self.path = path

    def fail(self, field: str, msg: str, **where) -> None:
        raise StudyError(msg, file=self.path, field=field, **where)

    def number(self, v, field, lo=-math.inf, hi=math.inf, *, optional=False, **where):
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(field, f"must be a number, got {_kind(v)}", **where)
        if not math.isfinite(v) or not (lo <= v <= hi):
            rng = f" in [{lo:g}, {hi:g}]" if (lo, hi) != (-math.inf, math.inf) else ""
            self.fail(field, f"must be a finite number{rng}, got {excerpt(v)}", **where)
        return v

    def whole(self, v, field, lo=0, hi=2**31, *, optional=False, **where):
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, int):
            if isinstance(v, float) and v.is_integer() and not isinstance(v, bool):
                v = int(v)
            else:
                self.fail(field, f"must be a whole number, got {_kind(v)}", **where)
        if not (lo <= v <= hi):
            self.fail(field, f"must be between {lo} and {hi}, got {excerpt(v)}", **where)
        return v

    def numbers(self, v, field, n, lo=-math.inf, hi=math.inf, **where):
        if not isinstance(v, list) or len(v) != n:
            self.fail(field, f"must be a list of {n} numbers, got {_kind(v)}", **where)
        if all(type(x) in (int, float) and math.isfinite(x) and lo <= x <= hi for x in v):
            return                  # the usual case, in one pass (each number's message below)
        for x in v:
            self.number(x, field, lo, hi, **where)

    def name(self, v, field, *, optional=False, **where):
        if v is None and optional:
            return None
        try:
            return check_name(v, field)
        except ValueError as exc:
            self.fail(field, str(exc), **where)


def _kind(v) -> str:
    if isinstance(v, bool):
        return f"a boolean ({'true' if v else 'false'})"
    if v is None:
        return "null"
    if isinstance(v, str):
        return f"text {excerpt(v)}"
    if isinstance(v, (dict, list)):
        return "an object" if isinstance(v, dict) else f"a list of {len(v)}"
    return excerpt(v)


def check_manifest(m: Any, path: Path) -> None:
    """Check a parsed native manifest against the schema above; StudyError on the first
    violation, naming ``path`` and the field.

    Parameters
    ----------
    m : object
        The parsed manifest (:func:`load_manifest`).
    path : pathlib.Path
        Its file, for the messages.

    Raises
    ------
    StudyError
        The first violation, naming ``path`` and the field.
    """
    c = _Checker(path)
    if not isinstance(m, dict):
        c.fail("format", f"the manifest must be a JSON object, got {_kind(m)}")
    c.whole(m.get("version"), "version", 1, 1)
    c.name(m.get("subject"), "subject", optional=True)
    c.number(m.get("heart_rate_bpm"), "heart_rate_bpm", *HEART_RATE_RANGE_BPM, optional=True)
    times = m.get("frame_times_ms")
    if times is not None:
        if not isinstance(times, dict):
            c.fail("frame_times_ms", f"must be an object frame -> ms, got {_kind(times)}")
        if len(times) > MAX_FRAMES:
            c.fail("frame_times_ms", f"{len(times)} frames (limit {MAX_FRAMES})")
        for k, v in times.items():
            if not (k.isdigit() and int(k) < MAX_FRAMES):
                c.fail("frame_times_ms", f"key {excerpt(k)} is not a frame index 0..{MAX_FRAMES - 1}")
            c.number(v, "frame_times_ms", -1e7, 1e7, frame=int(k))
    for key in ("ed_frame", "es_frame"):
        c.whole(m.get(key), key, 0, MAX_FRAMES - 1, optional=True)
    images = m.get("images", [])
    if not isinstance(images, list):
        c.fail("images", f"must be a list, got {_kind(images)}")
    if len(images) > MAX_IMAGES:
        c.fail("images", f"{len(images)} images (limit {MAX_IMAGES})")
    for k, im in enumerate(images):
        _check_image(c, im, k)
    points = m.get("points")
    if points is not None and not isinstance(points, str):
        c.fail("points", f"must be a file name, got {_kind(points)}")
    c.whole(m.get("points_rows"), "points_rows", 0, MAX_POINTS_PER_STUDY, optional=True)
    c.whole(m.get("coordinate_decimals"), "coordinate_decimals", 0, 17, optional=True)
    sidecar = m.get("points_sidecar")
    if sidecar is not None and not isinstance(sidecar, str):
        c.fail("points_sidecar", f"must be a file name, got {_kind(sidecar)}")
    meta = m.get("meta")
    if meta is not None and not isinstance(meta, dict):
        c.fail("meta", f"must be an object, got {_kind(meta)}")


def _check_image(c: _Checker, im: Any, k: int) -> None:
    f = f"images[{k}]"
    if not isinstance(im, dict):
        c.fail(f, f"must be an object, got {_kind(im)}")
    for key in ("id", "slice", "view", "frame", "position", "orientation", "pixel_spacing"):
        if key not in im:
            c.fail(f"{f}.{key}", "is missing")
    c.name(im["id"], f"{f}.id")
    sl = c.name(im["slice"], f"{f}.slice")
    fr = c.whole(im["frame"], f"{f}.frame", 0, MAX_FRAMES - 1, slice=sl)
    where = {"slice": sl, "frame": fr}
    if im["view"] not in VIEWS:
        c.fail(f"{f}.view", f"must be SA or LA, got {_kind(im['view'])}", **where)
    c.numbers(im["position"], f"{f}.position", 3, -1e6, 1e6, **where)
    c.numbers(im["orientation"], f"{f}.orientation", 6, -1.0001, 1.0001, **where)
    c.numbers(im["pixel_spacing"], f"{f}.pixel_spacing", 2, *PIXEL_SPACING_RANGE_MM, **where)
    for key in ("rows", "columns"):
        c.whole(im.get(key), f"{f}.{key}", 1, 65535, optional=True, **where)
    c.number(im.get("thickness"), f"{f}.thickness", *THICKNESS_RANGE_MM, optional=True, **where)
    c.number(im.get("trigger_time"), f"{f}.trigger_time", -1e7, 1e7, optional=True, **where)
    if im.get("file") is not None and not isinstance(im["file"], str):
        c.fail(f"{f}.file", f"must be a file name, got {_kind(im['file'])}", **where)
