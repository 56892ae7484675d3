"""The native study format: a JSON manifest plus one long-format CSV of points.

A native study is a folder::

    STUDY/
      study.json      manifest (below)
      points.csv      every annotation point, one per row (points.parquet for large studies)
      dicom/...       optional image files referenced by the manifest
      truth.json      optional ground truth (phantoms)

``study.json``::

    {"format": "cardionurbs-native", "version": 1,
     "subject": "normal_000", "heart_rate_bpm": 60.0,
     "frame_times_ms": {"0": 0.0, "1": 50.0, ...},
     "ed_frame": 0, "es_frame": 7,            # optional labels
     "images": [ {"id", "slice", "view", "frame", "position"[3],
                  "orientation"[6], "pixel_spacing"[2], "rows", "columns",
                  "thickness", "trigger_time"?, "file"?}, ... ],
     "points": "points.csv", "points_rows": 1234,   # rows of points.csv
     "meta": {...}}

The full schema (types, ranges, depth) is :mod:`cardionurbs.io.schema`;
``points_rows`` lets a truncated points.csv be caught (older manifests
without it still load, with a warning).

``points.csv`` columns (one row per point, in drawing order):

=========  ==================================================================
kind       ``contour``, ``tag`` or ``landmark``
name       structure (contours), family (tags) or landmark name
index      piece index (contours), tag index (tags), point index (landmarks)
view       ``SA`` or ``LA``
slice      slice id (empty allowed for landmarks)
frame      frame index
image      image id of the manifest (may be empty when x, y, z are given)
closed     1 or 0 for contours, empty otherwise
x, y, z    scanner mm (LPS), written with 3 decimals (1 µm)
px, py     pixel column and row on ``image``, 3 decimals (1/1000 pixel); used when
           x, y, z are empty
=========  ==================================================================

Consecutive rows sharing (kind, name, index, view, slice, frame, image) form
one annotation. Reading then writing a study gives equal files.

Precision: coordinates are written at a fixed precision, stated in the manifest
(``"coordinate_decimals": 3``): 1 µm in scanner mm, far below a pixel (about
1 mm) and below the 0.1 mm off-plane tolerance of the checks, so every number
measured from a study is unchanged at the precision it is reported to; a
20-frame phantom's points.csv shrinks from 20 MB (17 significant digits) to
about 8 MB. ``write_study(..., decimals=None)`` writes 17 significant digits
(lossless for any float); files of either kind, and files written before the
precision was fixed (no ``coordinate_decimals``), load alike.

Large studies: a study of more than ``PARQUET_ROWS`` points (a tagged phantom of more than
about ten frames) is written with ``points.parquet`` as its points file instead of the CSV
(the manifest's ``points`` names it): the same table, same columns and meaning, in Apache
Parquet (columnar, binary, zstd-compressed), with x, y, z, px, py stored as the decimal
values the CSV would hold (the nearest double to the 3-decimal number). A 20-frame tagged
phantom's points go from 13.7 MB of CSV to 2.2 MB, and load about four times faster.
``write_study(..., points="csv")`` (or ``"parquet"``) chooses the form whatever the size.
A Parquet points file is read with pyarrow (``pandas.read_parquet`` reads it too); a
truncated one fails its footer check, and ``points_rows`` is checked as for the CSV.

Sidecar (older option, still read): ``write_study(..., sidecar=True)`` also writes ``points.parquet``
(the same table, columnar binary, named by the manifest's ``points_sidecar``)
for large studies, which loads several times faster than the CSV. The CSV
stays the reference: the sidecar carries the CRC-32 of the CSV it was made
from and is used only when the CSV still has it (a CSV edited by hand wins).
"""

from __future__ import annotations

import gzip
import io
import json
import zlib
from contextlib import contextmanager
from pathlib import Path

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from cardionurbs.confine import checked, study_file
from cardionurbs.errors import StudyError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import atomic
from cardionurbs.io.schema import check_manifest, load_manifest
from cardionurbs.safe import excerpt
from cardionurbs.study import Contour, Landmark, Study, TagLine

if TYPE_CHECKING:    # pandas (~0.3 s to import) only where a table is written or a CSV read
    import pandas as pd

FORMAT = "cardionurbs-native"
VERSION = 1
MANIFEST = "study.json"
POINTS = "points.csv"
SIDECAR = "points.parquet"
POINTS_PARQUET = "points.parquet"
#: studies with more points than this get points.parquet as their points file (module doc)
PARQUET_ROWS = 50_000
POINT_FORMATS = ("auto", "csv", "parquet")
#: decimals of x, y, z (mm) and px, py (pixels) in points.csv: 1 µm, 1/1000 pixel
DECIMALS = 3
_CRC_KEY = b"cardionurbs.points_csv_crc32"
COLUMNS = ["kind", "name", "index", "view", "slice", "frame", "image", "closed",
           "x", "y", "z", "px", "py"]
_KEY = ["kind", "name", "index", "view", "slice", "frame", "image"]
_TEXT = ("kind", "name", "view", "slice", "image", "closed")


def is_native(path: str | Path) -> bool:
    """True when ``path`` is a native study folder (or its manifest).

    Parameters
    ----------
    path : str or pathlib.Path
        A file or folder.

    Returns
    -------
    bool
    """
    p = Path(path)
    manifest = p / MANIFEST if p.is_dir() else p
    if manifest.name != MANIFEST or not manifest.is_file():
        return False
    checked(manifest, what="manifest")          # a study.json linked out: refused, not read
    try:
        return json.loads(manifest.read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError, RecursionError):
        return False


# --------------------------------------------------------------------- writing
def study_to_frames(study: Study, pixel_coordinates: bool = True,
                    decimals: int | None = None) -> tuple[dict, pd.DataFrame]:
    """The manifest dict and the points table of a study (what :func:`write_study` writes).

    Each column is built once for all annotations (metadata repeated by point
    count with ``np.repeat``; pixel coordinates mapped per image in one call),
    so writing costs a few array operations whatever the number of annotations.
    ``decimals``: round x, y, z to that many decimals first (what :func:`write_study`
    writes), so that px, py are those of the coordinates a reader will see.

    Parameters
    ----------
    study : Study
        The study.
    pixel_coordinates : bool
        Also px, py columns (pixel coordinates in each point's image).
    decimals : int or None
        Round x, y, z to this many decimals; None: as they are.

    Returns
    -------
    manifest : dict
        The ``study.json`` content.
    points : pandas.DataFrame
        One row per annotation point (docs/formats.md, native).
    """
    import pandas as pd
    images = study._image_index()
    meta: list[tuple] = []      # (kind, name, index, view, slice, frame, image, closed)
    blocks: list[np.ndarray] = []
    for c in study.contours:
        meta.append(("contour", c.structure, c.index, c.view, c.slice, c.frame, c.image,
                     str(int(c.closed))))
        blocks.append(c.points)
    for t in study.tags:
        meta.append(("tag", t.family, t.index, t.view, t.slice, t.frame, t.image, ""))
        blocks.append(t.points)
    for lm in study.landmarks:
        meta.append(("landmark", lm.name, lm.index, lm.view, lm.slice, lm.frame, lm.image, ""))
        blocks.append(lm.point.reshape(1, 3))
    if not meta:
        table = pd.DataFrame(columns=COLUMNS)
    else:
        counts = np.array([len(b) for b in blocks])
        xyz = np.concatenate(blocks).reshape(-1, 3)
        if decimals is not None:
            # the coordinates as they will be read back, so that the pixel columns are
            # computed from them and a study read and written again gives equal files
            xyz = np.round(xyz, int(decimals))
        image_per_block = np.array([m[6] or "" for m in meta], dtype=object)
        image_col = np.repeat(image_per_block, counts)
        pix = np.full((len(xyz), 2), np.nan)
        if pixel_coordinates:
            codes, uniques = pd.factorize(image_col)
            order = np.argsort(codes, kind="stable")
            bounds = np.searchsorted(codes[order], np.arange(len(uniques) + 1))
            for k, image_id in enumerate(uniques):
                if image_id and image_id in images:
                    sel = order[bounds[k]:bounds[k + 1]]
                    pix[sel] = images[image_id].scanner_to_pixel(xyz[sel])

        def col(i, empty=""):
            return np.repeat(np.array([empty if m[i] is None else m[i] for m in meta],
                                      dtype=object), counts)

        table = pd.DataFrame({
            "kind": col(0), "name": col(1), "index": np.repeat([int(m[2]) for m in meta], counts),
            "view": col(3), "slice": col(4), "frame": np.repeat([int(m[5]) for m in meta], counts),
            "image": image_col, "closed": col(7),
            "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "px": pix[:, 0], "py": pix[:, 1]})
    manifest = {
        "format": FORMAT, "version": VERSION, "subject": study.subject,
        "heart_rate_bpm": study.heart_rate_bpm,
        "frame_times_ms": {str(k): float(v) for k, v in sorted(study.frame_times_ms.items())},
        "ed_frame": study.ed_frame, "es_frame": study.es_frame,
        "images": [im.to_dict() for im in study.images],
        "points": POINTS, "points_rows": len(table), "meta": _written_meta(study.meta),
    }
    return manifest, table[COLUMNS]


def write_study(study: Study, folder: str | Path, pixel_coordinates: bool = True,
                decimals: int | None = DECIMALS, sidecar: bool = False,
                points: str = "auto") -> Path:
    """Write ``study`` as a native study into ``folder`` (files written atomically).

    ``decimals``: fixed decimals of the coordinates (default 3: 1 µm, 1/1000 pixel);
    None writes 17 significant digits (lossless). ``points``: the points file's form,
    ``"csv"``, ``"parquet"`` or ``"auto"`` (Parquet above ``PARQUET_ROWS`` points).
    ``sidecar``: with a CSV points file, also write ``points.parquet`` beside it (see the
    module docstring).

    Parameters
    ----------
    study : Study
        The study.
    folder : str or pathlib.Path
        The study folder (created).
    pixel_coordinates : bool
        Also px, py columns.
    decimals : int or None
        As above.
    sidecar : bool
        As above.
    points : {"auto", "csv", "parquet"}
        As above.

    Returns
    -------
    pathlib.Path
        ``folder``.
    """
    if points not in POINT_FORMATS:
        raise ValueError(f"points must be one of {', '.join(POINT_FORMATS)}, got {points!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest, table = study_to_frames(study, pixel_coordinates, decimals)
    if points == "parquet" or (points == "auto" and not sidecar and len(table) > PARQUET_ROWS):
        if decimals is not None:
            manifest["coordinate_decimals"] = int(decimals)
        _write_parquet_points(table, folder / POINTS_PARQUET, decimals)
        manifest["points"] = POINTS_PARQUET
        for stale in (POINTS,):              # a CSV left by an earlier write would mislead
            if (folder / stale).is_file():
                (folder / stale).unlink()
        atomic.write_text(folder / MANIFEST, json.dumps(manifest, indent=1, sort_keys=False) + "\n")
        return folder
    fmt = "%.17g" if decimals is None else f"%.{int(decimals)}f"
    text = table.to_csv(index=False, float_format=fmt, lineterminator="\n")
    if decimals is not None:
        manifest["coordinate_decimals"] = int(decimals)
    data = text.encode("utf-8")
    atomic.write_bytes(folder / POINTS, data)
    if sidecar:
        _write_sidecar(folder / POINTS, folder / SIDECAR, zlib.crc32(data))
        manifest["points_sidecar"] = SIDECAR
    atomic.write_text(folder / MANIFEST, json.dumps(manifest, indent=1, sort_keys=False) + "\n")
    return folder


def _write_parquet_points(table: pd.DataFrame, path: Path, decimals: int | None) -> Path:
    """The points table as Parquet: string columns as written in the CSV, index and frame as
    64-bit integers, coordinates as the nearest doubles to their ``decimals``-decimal values
    (rint(v · 10^d) / 10^d, one correctly rounded division), empty ones null."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    table = table.copy()
    if decimals is not None:
        scale = 10.0 ** int(decimals)
        for col in ("x", "y", "z", "px", "py"):
            table[col] = np.rint(table[col].to_numpy(float) * scale) / scale
    for col in ("index", "frame"):
        table[col] = table[col].astype(np.int64)
    for col in ("kind", "name", "view", "slice", "image", "closed"):
        table[col] = table[col].astype(str)
    arrow = pa.Table.from_pandas(table[COLUMNS], preserve_index=False)
    with atomic.atomic_path(path) as tmp:
        pq.write_table(arrow, tmp, compression="zstd")
    return path


def _write_sidecar(csv_path: Path, path: Path, crc: int) -> Path:
    """points.parquet: the table exactly as read back from ``csv_path`` (so both files give
    identical studies), with the CSV's CRC-32 in the schema metadata."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    table = pa.Table.from_pandas(_points_table(csv_path), preserve_index=False)
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           _CRC_KEY: str(crc).encode()})
    with atomic.atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    return path


# --------------------------------------------------------------------- reading
def read_study(path: str | Path) -> Study:
    """Read a native study folder (or its ``study.json``) into a :class:`Study`.

    Parameters
    ----------
    path : str or pathlib.Path
        The study folder or its ``study.json``.

    Returns
    -------
    Study

    Raises
    ------
    StudyError
        A missing, unreadable or inconsistent file (naming file, row and field).
    """
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise StudyError("no study.json manifest in this folder", file=folder)
    manifest = load_manifest(manifest_path)
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise StudyError(f"field 'format' must be {FORMAT!r}", file=manifest_path)
    if manifest.get("version") != VERSION:
        raise StudyError(f"unsupported version {excerpt(manifest.get('version'))}", file=manifest_path,
                         field="version")
    check_manifest(manifest, manifest_path)
    try:
        images = [ImagePlane.from_dict(d) for d in manifest.get("images", [])]
    except StudyError as exc:
        raise StudyError(str(exc), file=manifest_path) from None
    except (KeyError, TypeError, ValueError) as exc:
        raise StudyError(f"malformed image entry ({exc})", file=manifest_path, field="images") from None
    study = Study(
        subject=str(manifest.get("subject") or folder.name),
        images=images,
        frame_times_ms={int(k): float(v) for k, v in (manifest.get("frame_times_ms") or {}).items()},
        heart_rate_bpm=_opt_float(manifest.get("heart_rate_bpm")),
        ed_frame=manifest.get("ed_frame"), es_frame=manifest.get("es_frame"),
        source=str(folder), meta=manifest.get("meta") or {},
    )
    ids = [im.id for im in images]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise StudyError(f"image id {excerpt(dup)} appears twice", file=manifest_path, field="images")
    points_path = _points_path(folder, manifest, manifest_path)
    for im in images:
        if im.file is not None:
            study_file(folder, im.file, file=manifest_path, field="images.file", slice=im.slice,
                       frame=im.frame)
    _read_points(study, points_path, expected_rows=manifest.get("points_rows"),
                 sidecar=_sidecar_path(folder, manifest, manifest_path))
    return study


def _points_path(folder: Path, manifest: dict, manifest_path: Path) -> Path:
    """The points file the manifest names, confined to the study folder."""
    return study_file(folder, manifest.get("points", POINTS), file=manifest_path, field="points")


def _sidecar_path(folder: Path, manifest: dict, manifest_path: Path) -> Path | None:
    """The points sidecar the manifest names (confined to the study folder), or None."""
    name = manifest.get("points_sidecar")
    if not name:
        return None
    return study_file(folder, name, file=manifest_path, field="points_sidecar")


def _sidecar_table(path: Path, csv_path: Path) -> pd.DataFrame | None:
    """The sidecar's points table when it was made from the CSV as it is now; else None."""
    try:
        import pyarrow.parquet as pq
        meta = pq.read_schema(path).metadata or {}
        crc = int(meta.get(_CRC_KEY, b"-1"))
        if crc != zlib.crc32(csv_path.read_bytes()):
            return None
        return pq.read_table(path).to_pandas()
    except (ImportError, OSError, ValueError):
        return None


def _opt_float(v):
    return None if v is None else float(v)


class _Columns:
    """The points table as numpy columns: ``numbers[col]`` float (NaN where empty) for
    x, y, z, px, py, frame, index; ``text[col]`` = (integer codes, values) with
    ``values[codes]`` the column's strings (empty where the file has none)."""

    def __init__(self, n: int, numbers: dict, text: dict) -> None:
        self.n, self.numbers, self.text = n, numbers, text

    def strings(self, col: str, rows=slice(None)) -> np.ndarray:
        codes, values = self.text[col]
        return values[codes[rows]]


def _pixels_to_scanner(table: _Columns, need: np.ndarray, pix: np.ndarray, xyz: np.ndarray,
                       images: dict, points_path: Path) -> None:
    """Fill ``xyz[need]`` from (px, py) through each row's image plane, all rows at once:
    P = S + px * dc * X + py * dr * Y (DICOM PS3.3 C.7.6.2.1.1, same operation order as
    ImagePlane.pixel_to_scanner, so results are bit-identical)."""
    rows = np.flatnonzero(need)
    image_codes, image_values = table.text["image"]
    used, first, codes = np.unique(image_codes[rows], return_index=True, return_inverse=True)
    uniques = [str(image_values[u]) for u in used]
    for k in np.argsort(first, kind="stable"):     # in file order: the first bad line is told
        image_id = uniques[k]
        line = int(rows[first[k]]) + 2
        if not image_id:
            raise StudyError(f"line {line}: no x, y, z and no image to map px, py",
                             file=points_path, field="image")
        if image_id not in images:
            raise StudyError(f"line {line}: reference to image {excerpt(image_id)} that is not in the "
                             "manifest", file=points_path, field="image")
    p = pix[need]
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise StudyError(f"line {int(rows[np.argmax(bad)]) + 2}: neither x, y, z nor px, py are "
                         "given", file=points_path, field="px")
    planes = [images[i] for i in uniques]
    S = np.array([im.position for im in planes])[codes]
    X = np.array([im.row_cosine for im in planes])[codes]
    Y = np.array([im.column_cosine for im in planes])[codes]
    dc = np.array([im.pixel_spacing[1] for im in planes])[codes]
    dr = np.array([im.pixel_spacing[0] for im in planes])[codes]
    xyz[need] = S + (p[:, 0] * dc)[:, None] * X + (p[:, 1] * dr)[:, None] * Y


def _check_complete(points_path: Path, n_rows: int, expected_rows) -> str | None:
    """A points file cut short is an error: a CSV must end with a line break (Parquet and
    gzip files carry their own footer and checksum), and every file must hold the
    ``points_rows`` the manifest records; a manifest without the count (written before it
    existed) gives a warning instead."""
    text = points_path.suffix.lower() not in (".parquet", ".gz")   # binary: own integrity checks
    with open(points_path, "rb") as f:
        f.seek(0, 2)
        if text and f.tell():
            f.seek(-1, 2)
            if f.read(1) not in (b"\n", b"\r"):
                raise StudyError("the last row is cut short (no line break at the end): the "
                                 "file is truncated", file=points_path)
    if expected_rows is None:
        return (f"{points_path}: study.json records no points_rows, so a truncated points "
                "file cannot be detected (rewrite the study to add it)")
    if n_rows != expected_rows:
        raise StudyError(f"{n_rows} rows but study.json's points_rows says {expected_rows}: the "
                         "file is truncated or was edited", file=points_path, field="points_rows")
    return None


def _written_meta(meta: dict) -> dict:
    """``study.meta`` as study.json keeps it: the body size that loading attached
    (:func:`cardionurbs.io.body.attach_body`) only with its known values and without their
    sources, so that a study read and written again is the same file."""
    body = meta.get("body") if isinstance(meta, dict) else None
    if not isinstance(body, dict):
        return meta
    known = {k: v for k, v in body.items() if k != "source" and v is not None}
    out = {k: v for k, v in meta.items() if k != "body"}
    return {**out, "body": known} if known else out


def _bounded_gunzip(path: Path) -> io.BytesIO:
    """The decompressed bytes of a gzip points file, read in chunks and refused past
    :data:`cardionurbs.limits.MAX_DECOMPRESSED_BYTES` (a decompression bomb) before more is
    allocated; a cut stream raises EOFError."""
    from cardionurbs.limits import MAX_DECOMPRESSED_BYTES
    out = io.BytesIO()
    with gzip.open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            out.write(chunk)
            if out.tell() > MAX_DECOMPRESSED_BYTES:
                raise StudyError(f"expands past {MAX_DECOMPRESSED_BYTES} bytes (the limit): a "
                                 "gzip bomb?", file=path)
    out.seek(0)
    return out


def _points_table(points_path: Path) -> pd.DataFrame:
    """The points file as a DataFrame (strings kept as written, empty coordinates NaN):
    Parquet when its name ends in ``.parquet``, else CSV (gzip-compressed when it ends in
    ``.gz``, as pandas infers)."""
    import pandas as pd
    if points_path.suffix.lower() == ".parquet":
        return _parquet_table(points_path)
    try:
        source = _bounded_gunzip(points_path) if points_path.suffix.lower() == ".gz" \
            else points_path
        return pd.read_csv(source, dtype={"kind": str, "name": str, "view": str, "slice": str,
                                               "image": str, "closed": str},
                           keep_default_na=False, na_values={"x": [""], "y": [""], "z": [""],
                                                            "px": [""], "py": [""]})
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        raise StudyError(f"cannot parse CSV ({excerpt(_first_line(exc), 120)})",
                         file=points_path) from None
    except (EOFError, OSError, zlib.error) as exc:     # a cut or corrupt gzip stream
        raise StudyError(f"truncated or corrupt compressed file ({_first_line(exc)[:100]})",
                         file=points_path) from None


def _codes(column: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """(integer codes, values) of a text column: values[codes] is the column (a categorical
    column's own codes, else pandas.factorize)."""
    import pandas as pd
    if isinstance(column.dtype, pd.CategoricalDtype):
        return column.cat.codes.to_numpy(), np.asarray(column.cat.categories, dtype=object)
    codes, uniques = pd.factorize(column, use_na_sentinel=False)
    return codes, np.asarray(uniques, dtype=object)


def _columns_of(table: pd.DataFrame, points_path: Path) -> _Columns:
    """A points DataFrame (a CSV, a sidecar) checked and turned into :class:`_Columns`:
    StudyError names the first line whose number column holds something else (or, for
    frame and index, no integer)."""
    import pandas as pd
    numbers = {}
    for col in ("x", "y", "z", "px", "py", "frame", "index"):
        num = pd.to_numeric(table[col], errors="coerce")
        if pd.api.types.is_numeric_dtype(table[col]):  # parsed as numbers: only NaN can be bad
            bad = pd.Series(np.zeros(len(table), dtype=bool), index=table.index)
        else:
            bad = num.isna() & (table[col].astype(str).str.strip() != "") & table[col].notna()
        if col in ("frame", "index"):
            bad |= num.isna() | (num != np.round(num))
        if bad.any():
            line = int(np.flatnonzero(bad.to_numpy())[0]) + 2
            raise StudyError(f"line {line}: {col} is not a number "
                             f"({excerpt(table[col].iloc[line - 2])})",
                             file=points_path, field=col)
        numbers[col] = num.to_numpy(float)
    return _Columns(len(table), numbers, {col: _codes(table[col]) for col in _TEXT})


@contextmanager
def _arrow_reading(points_path: Path):
    """The reading of a Parquet points file: pyarrow allocating, on one thread, from the C
    library's allocator (``pyarrow.system_memory_pool``, yielded), not its default mimalloc
    pool, which keeps its arenas after the table is converted (about 20 MB less resident
    memory for the rest of the process on a 20-frame phantom of 106,052 points, at the same
    speed); any error of pyarrow's as one StudyError naming the file; the default pool
    restored and the system pool's unused memory released after."""
    import pyarrow as pa
    pool, default = pa.system_memory_pool(), pa.default_memory_pool()
    pa.set_memory_pool(pool)          # the reader allocates from the default pool
    try:
        yield pool
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for a broken file
        raise StudyError(f"cannot read Parquet ({_first_line(exc)})", file=points_path) from None
    finally:
        pa.set_memory_pool(default)
        pool.release_unused()


def _parquet_table(points_path: Path) -> pd.DataFrame:
    """A Parquet points file as a DataFrame (the CSV's columns; null strings read as empty;
    read as :func:`_arrow_reading` says)."""
    import pyarrow.parquet as pq
    with _arrow_reading(points_path) as pool:
        arrow = pq.read_table(points_path, use_threads=False, read_dictionary=[
            c for c in _TEXT if c in pq.read_schema(points_path).names])
        table = arrow.to_pandas(memory_pool=pool, use_threads=False)
        del arrow
    for col in _TEXT:
        if col in table.columns and table[col].isna().any():
            table[col] = table[col].astype(object).fillna("").astype(str)
    return table


def _arrow_values(chunk, dtype) -> tuple[np.ndarray, np.ndarray | None]:
    """(values, valid) of one pyarrow array of a fixed-width numeric type, read from its
    buffers (Arrow columnar format: a little-endian validity bitmap, then the values);
    ``valid`` None when nothing is null. (pyarrow's own ``to_numpy`` imports pandas.)"""
    n, off = len(chunk), chunk.offset
    bitmap, data = chunk.buffers()[:2]
    values = np.frombuffer(data, dtype=dtype, count=off + n)[off:] if n else np.zeros(0, dtype)
    if not chunk.null_count:
        return values, None
    bits = np.unpackbits(np.frombuffer(bitmap, np.uint8), bitorder="little")
    return values, bits[off:off + n].astype(bool)


def _parquet_columns(points_path: Path) -> _Columns | None:
    """A Parquet points file as written by :func:`write_study` (text columns strings, the
    others numbers) straight into numpy columns, without pandas (about 0.3 s of a
    start-up); None when the file has another schema (a missing column, text in a
    number column), which :func:`_parquet_table` and :func:`_columns_of` then read
    and report as for any table. The same numbers as that path, read as
    :func:`_arrow_reading` says."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    numeric = {pa.float64(): np.float64, pa.float32(): np.float32, pa.int64(): np.int64,
               pa.int32(): np.int32}
    try:
        schema = pq.read_schema(points_path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for a broken file
        raise StudyError(f"cannot read Parquet ({_first_line(exc)})", file=points_path) from None
    types = {name: schema.field(name).type for name in schema.names}
    if any(c not in types for c in COLUMNS) \
            or not all(types[c] in (pa.string(), pa.large_string()) for c in _TEXT) \
            or not all(types[c] in numeric for c in ("x", "y", "z", "px", "py", "frame", "index")):
        return None
    with _arrow_reading(points_path) as pool:
        # ParquetFile, not read_table: the latter's dataset layer imports pandas
        arrow = pq.ParquetFile(points_path, read_dictionary=list(_TEXT),
                               memory_map=False).read(columns=COLUMNS, use_threads=False)
        arrow = arrow.unify_dictionaries(memory_pool=pool)
        n = arrow.num_rows
        numbers = {}
        for c in ("x", "y", "z", "px", "py", "frame", "index"):
            parts = []
            for ch in arrow.column(c).chunks:
                v, valid = _arrow_values(ch, numeric[ch.type])
                v = v.astype(float)
                if valid is not None:
                    v[~valid] = np.nan
                parts.append(v)
            numbers[c] = np.concatenate(parts) if parts else np.zeros(0)
        text = {}
        for c in _TEXT:
            chunks = arrow.column(c).chunks
            values = (chunks[0].dictionary.to_pylist() if chunks else []) + [""]   # "": null
            parts = []
            for ch in chunks:
                idx = ch.indices
                if idx.type not in (pa.int8(), pa.int16(), pa.int32(), pa.int64()):
                    return None
                k, valid = _arrow_values(idx, np.dtype(f"int{idx.type.bit_width}"))
                parts.append(k if valid is None else np.where(valid, k, len(values) - 1))
            text[c] = (np.concatenate(parts) if parts else np.zeros(0, np.int64),
                       np.array(values, dtype=object))
        del arrow
    for c in ("frame", "index"):          # integers: a null or a fraction is no index
        v = numbers[c]
        bad = ~np.isfinite(v) | (v != np.round(v))
        if bad.any():
            line = int(np.flatnonzero(bad)[0]) + 2
            raise StudyError(f"line {line}: {c} is not a number ({excerpt(v[line - 2])})",
                             file=points_path, field=c)
    return _Columns(n, numbers, text)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return excerpt(text.splitlines()[0] if text else type(exc).__name__)


def _check_closed(kinds, closed, starts, points_path: Path) -> None:
    """A contour's ``closed`` is 1 or 0 (true/false accepted); anything else (``nan``, ``2``)
    is refused naming the line, rather than read as closed."""
    for k, (kind, c) in enumerate(zip(kinds, closed)):
        v = str(c).strip().lower()
        if kind == "contour" and v not in ("0", "1", "true", "false", "0.0", "1.0"):
            raise StudyError(f"line {int(starts[k]) + 2}: closed must be 1 or 0, got "
                             f"{excerpt(c)}", file=points_path, field="closed")


def _check_coordinate_range(xyz: np.ndarray, points_path: Path) -> None:
    """Refuse a coordinate past :data:`cardionurbs.limits.MAX_COORDINATE_MM` (before any
    arithmetic on it: 1e308 squared overflows), naming its line with a short number."""
    from cardionurbs.limits import MAX_COORDINATE_MM
    with np.errstate(invalid="ignore"):
        far = np.abs(xyz) > MAX_COORDINATE_MM
    if far.any():
        row, col = np.argwhere(far)[0]
        raise StudyError(f"line {int(row) + 2}: {'xyz'[col]} = {xyz[row, col]:.3g} mm lies past "
                         f"{MAX_COORDINATE_MM:g} mm from the scanner origin", file=points_path,
                         field="xyz"[col])


def _read_points(study: Study, points_path: Path, prefer_pixels: bool = False,
                 expected_rows: int | None = None, sidecar: Path | None = None) -> None:
    """Append the contours, tag lines and landmarks of a points file to ``study``.

    Parameters
    ----------
    study : Study
        The study being read (its images already known); its warnings are appended to.
    points_path : Path
        points.csv (or .csv.gz, .parquet).
    prefer_pixels : bool
        Place every row with pixel coordinates through its image, not only the rows
        without scanner coordinates.
    expected_rows : int, optional
        The row count the manifest states (a shorter file is warned about).
    sidecar : Path, optional
        An older points.parquet beside the CSV, read in its place where it is current.
    """
    if not checked(points_path, what="points file").is_file():
        raise StudyError("points file is missing", file=points_path)
    cols, table = _point_source(points_path, sidecar)
    n = cols.n if cols is not None else len(table)
    warning = _check_complete(points_path, n, expected_rows)
    if warning:
        study.warnings.append(warning)
    if n == 0:
        return
    if cols is None:
        cols = _columns_of(table, points_path)
        del table
    images = study._image_index()
    xyz = _scanner_points(cols, images, prefer_pixels, points_path)
    starts = _annotation_starts(cols, n)
    _add_annotations(study, cols, xyz, starts, images, points_path)


def _point_source(points_path: Path, sidecar: Path | None):
    """The points as columns read straight from Parquet, or else as a table.

    Parameters
    ----------
    points_path : Path
        The points file.
    sidecar : Path, optional
        A current points.parquet beside it (read in its place).

    Returns
    -------
    (_Columns or None, DataFrame or None)
        Exactly one of the two; StudyError when the table lacks a column.
    """
    table = cols = None
    if sidecar is not None and checked(sidecar).is_file() and sidecar != points_path:
        table = _sidecar_table(sidecar, points_path)
    if table is None and points_path.suffix.lower() == ".parquet":
        cols = _parquet_columns(points_path)
    if cols is None:
        if table is None:
            table = _points_table(points_path)
        missing = [c for c in COLUMNS if c not in table.columns]
        if missing:
            raise StudyError(f"missing column(s) {', '.join(missing)}", file=points_path)
    return cols, table


def _scanner_points(cols: _Columns, images: dict, prefer_pixels: bool,
                    points_path: Path) -> np.ndarray:
    """Every row's scanner position, the pixel-only rows (every row with pixels when
    ``prefer_pixels``) placed through their image.

    Parameters
    ----------
    cols : _Columns
        The points file's columns.
    images : dict
        Image id -> ImagePlane of the study.
    prefer_pixels : bool
        See :func:`_read_points`.
    points_path : Path
        The file, for the errors.

    Returns
    -------
    (n, 3) float ndarray, Fortran order
        Scanner mm; StudyError for a coordinate out of range.
    """
    num = cols.numbers
    # column-major, as a DataFrame's block gives them: the points of each annotation are
    # views of these, and their layout steers the rounding of later products
    xyz = np.asfortranarray(np.column_stack([num["x"], num["y"], num["z"]]))
    pix = np.asfortranarray(np.column_stack([num["px"], num["py"]]))
    need = ~np.isfinite(xyz).all(axis=1)
    if prefer_pixels:
        image_codes, image_values = cols.text["image"]
        known = np.array([v in images for v in image_values], dtype=bool)
        need |= np.isfinite(pix).all(axis=1) & known[image_codes]
    if need.any():
        _pixels_to_scanner(cols, need, pix, xyz, images, points_path)
    _check_coordinate_range(xyz, points_path)
    return xyz


def _annotation_starts(cols: _Columns, n: int) -> np.ndarray:
    """The first row of every annotation: where any key column differs from the row before
    (vectorised, on integer codes of the text columns: no per-row Python strings).

    Parameters
    ----------
    cols : _Columns
        The points file's columns.
    n : int
        Its number of rows (at least 1).

    Returns
    -------
    (k,) int ndarray
        Row indices, ascending, the first 0.
    """
    change = np.zeros(max(n - 1, 0), dtype=bool)
    for col in _KEY:
        values = cols.text[col][0] if col in cols.text else cols.numbers[col]
        change |= values[1:] != values[:-1]
    return np.flatnonzero(np.r_[True, change])


class _Run(NamedTuple):
    """One annotation of a points file: its key columns and its rows' scanner points."""

    name: str
    view: str
    slice: str
    frame: int
    number: int
    closed: object
    image: str | None
    points: np.ndarray


def _add_contour(study: Study, run: _Run) -> None:
    study.contours.append(Contour(run.name, run.view, run.slice, run.frame, run.points,
                                  image=run.image, closed=str(run.closed).strip().lower() not in
                                  ("0", "false", "0.0"), index=run.number))


def _add_tag(study: Study, run: _Run) -> None:
    study.tags.append(TagLine(run.name, run.number, run.view, run.slice, run.frame, run.points,
                              image=run.image))


def _add_landmarks(study: Study, run: _Run) -> None:
    for point in run.points:
        study.landmarks.append(Landmark(run.name, run.frame, point, index=run.number,
                                        slice=run.slice or None, view=run.view or None,
                                        image=run.image))


#: what each ``kind`` of a points file row adds to the study
_ADD = {"contour": _add_contour, "tag": _add_tag, "landmark": _add_landmarks}


def _add_annotations(study: Study, cols: _Columns, xyz: np.ndarray, starts: np.ndarray,
                     images: dict, points_path: Path) -> None:
    """Append one contour, tag line or landmark(s) per annotation (rows ``starts[k]`` up to
    the next start) to ``study``, in file order.

    Parameters
    ----------
    study : Study
        The study being read.
    cols : _Columns
        The points file's columns.
    xyz : (n, 3) float ndarray
        Every row's scanner position, mm (:func:`_scanner_points`).
    starts : (k,) int ndarray
        The annotations' first rows (:func:`_annotation_starts`).
    images : dict
        Image id -> ImagePlane of the study.
    points_path : Path
        The file, for the errors (each naming its line).
    """
    ends = np.r_[starts[1:], len(xyz)]
    kinds, names, views, slices, imgs, closed = (
        cols.strings(col, starts) for col in ("kind", "name", "view", "slice", "image", "closed"))
    frames, idxs = cols.numbers["frame"].astype(int)[starts], cols.numbers["index"].astype(int)[starts]
    _check_closed(kinds, closed, starts, points_path)
    for k, (s, e) in enumerate(zip(starts, ends)):
        kind, image = kinds[k], imgs[k] or None
        if image is not None and image not in images:
            raise StudyError(f"line {s + 2}: reference to image {excerpt(image)} that is not in the manifest",
                             file=points_path, field="image")
        try:
            add = _ADD.get(kind)
            if add is None:
                raise StudyError(f"line {s + 2}: unknown kind {excerpt(kind)} (contour, tag or landmark)",
                                 file=points_path, field="kind")
            add(study, _Run(names[k], views[k], slices[k], frames[k], idxs[k], closed[k], image,
                            xyz[s:e]))
        except StudyError as exc:
            if exc.file is not None:
                raise
            raise StudyError(f"line {s + 2}: {exc}", file=points_path) from None


# ------------------------------------------------------- DICOM images of a study
#: largest tolerated difference between manifest and DICOM header geometry
#: (DICOM DS values carry at most 16 characters).
DICOM_POSITION_TOL_MM = 1e-4
DICOM_DIRECTION_TOL = 1e-6


def _dicom_files(study: Study) -> list[tuple[ImagePlane, Path]]:
    """(image, DICOM file) for every image whose ``file`` names a DICOM file."""
    if not study.source:
        return []
    folder = Path(study.source)
    out = []
    for im in study.images:
        if not im.file:
            continue
        path = study_file(folder, im.file, file=folder / MANIFEST, field="images.file",
                          slice=im.slice, frame=im.frame)
        if Path(im.file).suffix.lower() not in ("", ".dcm", ".ima", ".dicom"):
            raise StudyError(f"image {excerpt(im.id)} names {excerpt(im.file)}, which is not a "
                             "DICOM image (.dcm, .ima, .dicom or no suffix)",
                             file=folder / MANIFEST, slice=im.slice, frame=im.frame, field="file")
        if not path.is_file():
            raise StudyError(f"image {excerpt(im.id)} refers to file {excerpt(im.file)}, which does not exist",
                             file=folder / MANIFEST, slice=im.slice, frame=im.frame, field="file")
        out.append((im, path))
    return out


def check_dicom_geometry(study: Study) -> int:
    """Cross-check each image's manifest geometry against the header of the DICOM file it
    names (ImagePositionPatient, ImageOrientationPatient, PixelSpacing, Rows, Columns, and
    SOPInstanceUID = image id when the id looks like a UID). Returns the number of images
    checked; StudyError names the DICOM file, slice, frame and field that disagree.
    pydicom is imported only when the study names DICOM files (0.2 s of a start-up).

    Parameters
    ----------
    study : Study
        A native study read from its manifest.

    Returns
    -------
    int
        Images checked.

    Raises
    ------
    StudyError
        A disagreement.
    """
    pairs = _dicom_files(study)
    if not pairs:
        return 0
    from cardionurbs.imaging.dicom import read_header

    for im, path in pairs:
        h = read_header(path)
        where = dict(file=path, slice=im.slice, frame=im.frame)
        d = float(np.linalg.norm(h.position - im.position))
        if d > DICOM_POSITION_TOL_MM:
            raise StudyError(f"ImagePositionPatient is {d:.3g} mm from study.json's position of "
                             f"image {excerpt(im.id)}", field="ImagePositionPatient", **where)
        if np.abs(h.orientation / np.repeat(np.linalg.norm(h.orientation.reshape(2, 3), axis=1), 3)
                  - im.orientation).max() > DICOM_DIRECTION_TOL:
            raise StudyError(f"ImageOrientationPatient differs from study.json's image {excerpt(im.id)}",
                             field="ImageOrientationPatient", **where)
        if np.abs(np.subtract(h.pixel_spacing, im.pixel_spacing)).max() > 1e-9 * max(im.pixel_spacing):
            raise StudyError(f"PixelSpacing {list(h.pixel_spacing)} differs from study.json's "
                             f"{list(im.pixel_spacing)}", field="PixelSpacing", **where)
        if (h.rows, h.columns) != (im.rows, im.columns):
            raise StudyError(f"matrix {h.rows}x{h.columns} differs from study.json's "
                             f"{im.rows}x{im.columns}", field="Rows", **where)
        if im.id.replace(".", "").isdigit() and "." in im.id and h.sop_instance_uid != im.id:
            raise StudyError(f"SOPInstanceUID {h.sop_instance_uid} is not the image id {im.id}",
                             field="SOPInstanceUID", **where)
    return len(pairs)


def read_study_from_dicom(path: str | Path) -> Study:
    """Read a native study taking image geometry from the DICOM files its images name.

    Slice, view and frame labels come from the manifest; position, orientation,
    pixel spacing, matrix, thickness and trigger time from the DICOM headers;
    every annotation point given in pixels (px, py) is mapped through the DICOM
    geometry (DICOM PS3.3 C.7.6.2.1.1), its x, y, z column ignored.

    Parameters
    ----------
    path : str or pathlib.Path
        The study folder or its ``study.json``.

    Returns
    -------
    Study

    Raises
    ------
    StudyError
        A missing DICOM file, or no image naming one.
    """
    from cardionurbs.imaging.dicom import read_header

    study = read_study(path)
    pairs = dict((im.id, p) for im, p in _dicom_files(study))
    if not pairs:
        raise StudyError("no image of this study names a DICOM file", file=study.source)
    images = []
    for im in study.images:
        if im.id not in pairs:
            images.append(im)
            continue
        h = read_header(pairs[im.id])
        images.append(ImagePlane(id=im.id, slice=im.slice, view=im.view, frame=im.frame,
                                 position=h.position, row_cosine=h.orientation[:3],
                                 column_cosine=h.orientation[3:], pixel_spacing=h.pixel_spacing,
                                 rows=h.rows, columns=h.columns,
                                 thickness=h.thickness or im.thickness,
                                 trigger_time=h.trigger_time if h.trigger_time is not None
                                 else im.trigger_time, file=im.file))
    study.images = images
    study.contours, study.tags, study.landmarks = [], [], []
    assert study.source is not None                 # read_study names the study folder
    folder = Path(study.source)
    manifest = load_manifest(folder / MANIFEST)
    _read_points(study, _points_path(folder, manifest, folder / MANIFEST), prefer_pixels=True,
                 expected_rows=manifest.get("points_rows"),
                 sidecar=_sidecar_path(folder, manifest, folder / MANIFEST))
    study.meta = dict(study.meta, geometry="dicom")
    return study
