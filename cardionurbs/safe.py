"""Safe strings: names from input files are checked once, on load, and quoted safely on output.

A subject, slice, image or structure name comes from a file the user may not
control. On load (:func:`check_name`) it must be printable text of at most
:data:`cardionurbs.limits.MAX_NAME_LENGTH` characters (no control characters,
no path separators for names that become file names). On output each sink
gets its own quoting:

* messages: :func:`excerpt` -- at most a short, printable quotation;
* figure text: :func:`plain_text` -- ``$`` escaped so that matplotlib never
  starts mathtext on a name, and a character that no font of the figures has
  written as ``[U+XXXX]`` (matplotlib would draw an empty box and warn);
* HTML ``<script type="application/json">`` blocks: :func:`json_for_script` --
  ``<``, ``>``, ``&`` and the line separators written as ``\\u003c`` etc., so
  ``</script>`` and ``<!--`` cannot end or comment out the block;
* CSV cells: :func:`csv_cell` -- a cell starting with ``= + - @``, a tab or a
  carriage return is prefixed with ``'`` (OWASP CSV-injection rule) so that
  spreadsheets do not run it as a formula.
"""

from __future__ import annotations

import functools
import json
import re
import unicodedata

from cardionurbs.limits import MAX_NAME_LENGTH

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def printable(text: object) -> str:
    """``text`` with control characters shown as ``\\xNN`` escapes (one printable line).

    Parameters
    ----------
    text : object
        Any value; its ``str()`` is escaped.

    Returns
    -------
    str
        One printable line: each non-printable character (control, U+2028/U+2029) as its
        ``\\xNN`` / ``\\uXXXX`` escape, the rest unchanged.
    """
    s = str(text)
    if not _CONTROL.search(s) and s.isprintable():
        return s
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii")
                   for ch in s)


def excerpt(text: object, n: int = 40) -> str:
    """A short printable quotation of user input: ``repr``-quoted, at most ``n`` characters
    of it, ``...`` and the full length when cut.

    Parameters
    ----------
    text : object
        User input (its ``str()``), of any length.
    n : int, optional
        Characters of it quoted at most (default 40).

    Returns
    -------
    str
        The ``repr`` of the printable first ``n`` characters, followed by
        ``... (<length> characters)`` when the text was longer.
    """
    s = str(text)
    cut = s[:n]
    q = repr(printable(cut))
    return q if len(s) <= n else f"{q}... ({len(s)} characters)"


def check_name(value: object, what: str, *, file_name: bool = False,
               max_length: int = MAX_NAME_LENGTH) -> str:
    """Validate a name read from input (subject, slice id, image id, structure).

    It must be a string of 1..``max_length`` printable characters; with
    ``file_name`` also usable as one path component (no ``/``, ``\\``, not ``.``
    or ``..``). Raises ValueError with a one-line message quoting at most an
    excerpt; callers turn it into a StudyError naming file and field.

    Parameters
    ----------
    value : object
        The name as read from the file; must be a ``str``.
    what : str
        What the name is, for the message (``"slice id in study.json"``).
    file_name : bool, optional
        Also require a single path component (no ``/`` or ``\\``, not ``.`` or ``..``).
    max_length : int, optional
        Longest name accepted, in characters (default :data:`~cardionurbs.limits.MAX_NAME_LENGTH`).

    Returns
    -------
    str
        ``value`` itself, unchanged, once valid.

    Raises
    ------
    ValueError
        Not text, empty, too long, holding control characters, or (``file_name``) not one
        path component; the one-line message quotes an :func:`excerpt`.
    """
    if not isinstance(value, str):
        raise ValueError(f"{what} must be text, got {type(value).__name__}")
    if not value:
        raise ValueError(f"{what} is empty")
    if len(value) > max_length:
        raise ValueError(f"{what} has {len(value)} characters (limit {max_length}): "
                         f"{excerpt(value)}")
    if _CONTROL.search(value) or not value.isprintable():
        raise ValueError(f"{what} holds control characters: {excerpt(value)}")
    if file_name and (value in (".", "..") or "/" in value or "\\" in value):
        raise ValueError(f"{what} cannot be used as a file name: {excerpt(value)}")
    return value


def file_name(value: str) -> str:
    """``value`` as a safe single path component: letters, digits, ``._-`` kept (NFKC),
    anything else as ``_``; never empty, ``.`` or ``..``.

    Parameters
    ----------
    value : str
        Any name (subject, slice, structure).

    Returns
    -------
    str
        At most :data:`~cardionurbs.limits.MAX_NAME_LENGTH` characters of ``[A-Za-z0-9_.-]``
        (NFKC-normalised, other characters as ``_``), never empty, ``.`` or ``..``.
    """
    s = unicodedata.normalize("NFKC", str(value))
    s = re.sub(r"[^\w.\-]", "_", s, flags=re.ASCII)[:MAX_NAME_LENGTH]
    return s if s.strip(".") else "_" + s


@functools.lru_cache(maxsize=1)
def _drawable() -> frozenset[int] | None:
    """The code points the figures' fonts can draw: the union of the character maps of
    the fonts matplotlib finds for its default font families (the fonts it falls back
    through, in order); None when matplotlib or a font cannot be read."""
    try:
        from matplotlib import font_manager, ft2font
        prop = font_manager.FontProperties()
        paths = set()
        for family in prop.get_family():
            try:
                paths.add(font_manager.findfont(font_manager.FontProperties(family=family),
                                                fallback_to_default=False))
            except ValueError:
                continue
        paths = paths or {font_manager.findfont(prop)}
        return frozenset().union(*(ft2font.FT2Font(p).get_charmap() for p in paths))
    except Exception:   # noqa: BLE001 - figure text stays as it is
        return None


def plain_text(text: object) -> str:
    """``text`` for matplotlib: every ``$`` escaped so mathtext never starts on it, and
    each character that the figures' fonts cannot draw (e.g. CJK in DejaVu Sans) written
    as ``[U+XXXX]`` instead of the empty box matplotlib draws with a "Glyph missing"
    warning. Line breaks and spaces are kept.

    Parameters
    ----------
    text : object
        Any value; its ``str()`` is used.

    Returns
    -------
    str
        The text with every ``$`` written ``\\$`` and every undrawable character as
        ``[U+XXXX]``.
    """
    s = str(text).replace("$", r"\$")
    have = _drawable()
    if have is None or s.isascii():
        return s
    return "".join(c if c.isspace() or ord(c) in have else f"[U+{ord(c):04X}]" for c in s)


def json_for_script(obj, **kw) -> str:
    """JSON text safe inside an HTML ``<script>`` element: ``<``, ``>``, ``&``, U+2028 and
    U+2029 as ``\\uXXXX`` escapes (still the same JSON value).

    Parameters
    ----------
    obj : object
        A JSON-serialisable value (dicts, lists, numbers, strings).
    **kw
        Passed to :func:`json.dumps` (``indent``, ``sort_keys``, ...).

    Returns
    -------
    str
        The JSON text, with ``&``, ``<``, ``>``, U+2028 and U+2029 escaped as ``\\uXXXX``.
    """
    s = json.dumps(obj, **kw)
    return (s.replace("&", "\\u0026").replace("<", "\\u003c").replace(">", "\\u003e")
            .replace("\u2028", "\\u2028").replace("\u2029", "\\u2029"))


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value):
    """A text cell that a spreadsheet shows as text: ``'`` before a leading ``= + - @``, tab
    or carriage return (OWASP). Numbers and other non-text values are returned unchanged.

    Parameters
    ----------
    value : object
        One cell of a table (text, number, None).

    Returns
    -------
    object
        ``"'" + value`` for text starting with ``= + - @``, a tab or a carriage return;
        ``value`` unchanged otherwise.
    """
    if isinstance(value, str) and value.startswith(_FORMULA_START):
        return "'" + value
    return value


def csv_safe_table(table):
    """A copy of a pandas DataFrame with every text cell passed through :func:`csv_cell`.

    Parameters
    ----------
    table : pandas.DataFrame
        Any table about to be written as CSV; it is not modified.

    Returns
    -------
    pandas.DataFrame
        A copy with every object or string column's cells passed through :func:`csv_cell`.
    """
    import pandas as pd
    out = table.copy()
    for col in out.columns:
        if out[col].dtype == object or pd.api.types.is_string_dtype(out[col].dtype):
            out[col] = out[col].map(csv_cell)
    return out


#: third-party warnings the CLI caught instead of printing (message text, excerpted)
CAUGHT_WARNINGS: list[str] = []
#: loggers of libraries that print straight to stderr (nibabel's "not attempting fix")
_CHATTY_LOGGERS = ("nibabel", "nibabel.global", "matplotlib", "matplotlib.font_manager",
                   "pydicom", "distributed", "fontTools")


def quiet_third_party(show: bool = False) -> None:
    """Keep library warnings and log lines off stderr, so that a run prints at most its own
    one-line result or error: Python warnings (numpy RuntimeWarnings, matplotlib's "Glyph
    missing", nibabel's) are collected in :data:`CAUGHT_WARNINGS` and the chatty loggers
    raised to CRITICAL. ``show`` (``--debug``) keeps the usual printing.

    Parameters
    ----------
    show : bool, optional
        ``True`` (``--debug``): change nothing, let libraries print as usual.
    """
    import logging
    import warnings

    if show:
        return

    def collect(message, category, filename, lineno, file=None, line=None) -> None:
        if len(CAUGHT_WARNINGS) < 1000:
            CAUGHT_WARNINGS.append(f"{category.__name__}: {excerpt(str(message), 120)}")

    warnings.showwarning = collect
    for name in _CHATTY_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL)
