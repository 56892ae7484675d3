"""CAP / biv-me guide-point files: ``GPFile_NNN.txt`` per frame + ``SliceInfoFile.txt``.

Read and written so that a study can go to biv-me and back.

Two layouts: one ``GPFile_NNN.txt`` per frame (any number of digits: biv-me's examples mix
``GPFile_03.txt`` with ``GPFile_000.txt``; two files for one frame are refused), or, as in
biv-me's ``test_data``, one ``GPFile.txt`` holding every frame, split by its ``time frame``
column (each line's frame, a whole number >= 0; one warning says the frames come from the
column). A folder with both reads the per-frame files; ``GPFile.txt`` itself as the path
reads the single file. A study read from one file is written back as one file.

``GPFile_NNN.txt`` (one per frame NNN = 0, 1, ...), tab separated, one header
line, then one guide point per line in scanner mm::

    x  y  z  contour type  frameID  weight  time frame

``frameID`` is the slice number of ``SliceInfoFile.txt`` (CAP naming),
``weight`` the fitting weight, ``time frame`` the frame number as the source
tool wrote it. Consecutive lines with the same (contour type, frameID) form
one contour, in drawing order.

``SliceInfoFile.txt``, in either of two styles (tabs or spaces between tokens)::

    <image>  sliceID:  <n>  ImagePositionPatient  x y z
    ImageOrientationPatient  rx ry rz cx cy cz  PixelSpacing  dr dc          (ours)

    <image>  frameID:  <n>  [timeFrame  <t>]  ImagePositionPatient ...      (CAP exports)

``<image>`` is a DICOM file name or a UID. The CAP export lists each slice once
per frame, under one number or (biv-me ``test_data``) a number per image: lines of one
number, and numbers of one geometry (one warning counts them), are merged when their
geometry agrees (1e-3 mm,
1e-5 in the direction cosines) and a StudyError names both lines when it does
not. With ``timeFrame`` numbers, every GPFile frame must be listed (0- or
1-based). :func:`write_study` writes a study back in the style it was read in
(byte-identical for an unchanged study), or in the style asked for.

Mapping to the Study vocabulary. A contour's slice and view are those of the slice plane
its points lie on (median distance <= ``ON_PLANE_MM``), whatever its ``SAX_``/``LAX_``
prefix or frameID say: each disagreement is one warning naming file, lines, label and
slice, and points on no slice plane are refused (:func:`_placed`):

==============================  ===================  ==============================
GPFile type                      Study                closed
==============================  ===================  ==============================
SAX_/LAX_LV_ENDOCARDIAL          ``lv_endo``          SA closed, LA open
SAX_/LAX_LV_EPICARDIAL           ``lv_epi``           SA closed, LA open
SAX_/LAX_RV_ENDOCARDIAL          ``rv_endo``          SA: closed when it is a loop
SAX_/LAX_RV_FREEWALL             ``rv_freewall``      open
SAX_/LAX_RV_SEPTUM               ``rv_septum``        open
SAX_/LAX_RV_EPICARDIAL           ``rv_epi``           SA: closed when it is a loop
SAX_RV_OUTLET                    ``rv_outlet``        closed when it is a loop
MITRAL/TRICUSPID/AORTA/          landmark ``mitral``, ``tricuspid``, ``aortic``,
PULMONARY_VALVE (+ ``_PHANTOM``)  ``pulmonary``
APEX_POINT, RV_INSERT            landmark ``apex``, ``rv_insert``
LAX_LA, LAX_RA, SAX_LA, SAX_RA,  ``la``, ``ra``, ``laa``, ``lpv``, ``rpv``, ``svc``,
SAX_LAA, SAX_LPV, SAX_RPV,       ``ivc``, ``<x>_extent``: kept, not used for the
SAX_SVC, SAX_IVC, LAX_*_EXTENT   ventricles (counted in one warning)
EXCLUDED                         dropped (counted in one warning)
==============================  ===================  ==============================

(``*_PHANTOM``: ``MITRAL_PHANTOM`` or ``MITRAL_VALVE_PHANTOM`` etc., the points a
CAP tool adds to complete a valve ring.) "A loop": the trace's ends and every step
along it are within 3 median point spacings, and closing it does not make it cross
itself (:func:`is_loop`). An undivided RV endocardial trace is split into septum and
free wall by its contact with the LV epicardium where the reconstruction needs the
septum (:func:`cardionurbs.anatomy.sections.septal_parts`). The ``weight`` column
becomes ``Contour.weights``: weight 0 leaves a point out of every fit, other weights
weigh the long-axis points in the least-squares correction of the LV surfaces
(:func:`cardionurbs.anatomy.refine.refine_surface`).

Slice ids: the slices of SliceInfoFile whose normals are parallel (the largest
such group, :func:`cardionurbs.imaging.stack.split_stack`) are the SA stack,
named ``sa_00`` (base) ... towards the apex, the direction told by the
APEX_POINT landmark, else the MITRAL_VALVE points, else the LPS prior
(:mod:`cardionurbs.imaging.stack`). Every other slice is ``la_<n>ch`` when its
DICOM file name says so (``..._4ch_...``, as this writer writes them), else
``la_<sliceID>``.
Every slice gets one image per frame, id ``<slice>_f<NNN>``; SliceInfoFile has
no matrix size or thickness, so images use 256 x 256 and 8 mm (noted in
``Study.meta["gpfile"]["defaults"]``). There is no timing: ``frame_times_ms``
and ``heart_rate_bpm`` stay empty.

What the Study cannot hold is kept in ``Study.meta["gpfile"]`` — header line,
file names, original type names, line order, weights and time-frame fields as
written, SliceInfoFile numbers as written — so that :func:`write_study` of an
unchanged study gives byte-identical files. Numbers are written with the
shortest repr that reads back to the same float.
"""

from __future__ import annotations

import io
import re
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cardionurbs.confine import checked, files_inside, study_file
from cardionurbs.errors import StudyError
from cardionurbs.geometry import stack_normal
from cardionurbs.safe import excerpt
from cardionurbs.imaging import stack
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import atomic
from cardionurbs.io.checks import in_plane_coordinates, self_intersections
from cardionurbs.study import Contour, Landmark, Study

if TYPE_CHECKING:    # pandas (~0.3 s to import): only for a file the plain reader declines
    import pandas as pd

SLICE_INFO = "SliceInfoFile.txt"
GP_FILE = re.compile(r"^GPFile_(\d+)\.txt$")
#: biv-me's single-file layout: every frame in one file, told apart by its time-frame column
SINGLE_GP_FILE = "GPFile.txt"
HEADER = "x\ty\tz\tcontour type\tframeID\tweight\ttime frame"
CONTOUR_TYPES = {"LV_ENDOCARDIAL": "lv_endo", "LV_EPICARDIAL": "lv_epi",
                 "RV_ENDOCARDIAL": "rv_endo", "RV_FREEWALL": "rv_freewall",
                 "RV_SEPTUM": "rv_septum", "RV_EPICARDIAL": "rv_epi"}
#: contour types with one view only: GPFile type -> (structure, view)
SINGLE_VIEW_TYPES = {"SAX_RV_OUTLET": ("rv_outlet", "SA")}
#: atrial, venous and extent traces: kept in the Study, not used for the ventricles
OTHER_TYPES = {"LAX_LA": ("la", "LA"), "LAX_RA": ("ra", "LA"), "SAX_LA": ("la", "SA"),
               "SAX_RA": ("ra", "SA"), "SAX_LAA": ("laa", "SA"), "SAX_LPV": ("lpv", "SA"),
               "SAX_RPV": ("rpv", "SA"), "SAX_SVC": ("svc", "SA"), "SAX_IVC": ("ivc", "SA"),
               "LAX_LA_EXTENT": ("la_extent", "LA"), "LAX_RA_EXTENT": ("ra_extent", "LA"),
               "LAX_LV_EXTENT": ("lv_extent", "LA"), "LAX_RV_EXTENT": ("rv_extent", "LA")}
LANDMARK_TYPES = {"MITRAL_VALVE": "mitral", "TRICUSPID_VALVE": "tricuspid",
                  "AORTA_VALVE": "aortic", "PULMONARY_VALVE": "pulmonary",
                  "APEX_POINT": "apex", "RV_INSERT": "rv_insert",
                  # points a CAP tool adds around a valve ring to complete it
                  "MITRAL_PHANTOM": "mitral", "TRICUSPID_PHANTOM": "tricuspid",
                  "AORTA_PHANTOM": "aortic", "PULMONARY_PHANTOM": "pulmonary",
                  "MITRAL_VALVE_PHANTOM": "mitral", "TRICUSPID_VALVE_PHANTOM": "tricuspid",
                  "AORTA_VALVE_PHANTOM": "aortic", "PULMONARY_VALVE_PHANTOM": "pulmonary"}
#: guide points a tool has marked as not to be used
EXCLUDED_TYPES = ("EXCLUDED",)
VIEW_PREFIX = {"SAX": "SA", "LAX": "LA"}
GP_OF_STRUCTURE = {v: k for k, v in CONTOUR_TYPES.items()}
GP_OF_STRUCTURE.update({v[0]: k for k, v in SINGLE_VIEW_TYPES.items()})
GP_OF_LANDMARK = {v: k for k, v in list(LANDMARK_TYPES.items())[:6]}
#: an SA RV_ENDOCARDIAL / RV_OUTLET trace is a closed loop when its ends are no farther
#: apart than this many times its median point spacing
LOOP_GAP_STEPS = 3.0
DEFAULT_ROWS = DEFAULT_COLUMNS = 256
DEFAULT_THICKNESS_MM = 8.0
#: rv_endo points closer than this to the LV epicardium are written as RV_SEPTUM, mm.
SEPTUM_TOL_MM = 0.5


def detect(path: str | Path) -> bool:
    """True when ``path`` is a folder (or a file in one) with SliceInfoFile.txt and either
    GPFile_NNN.txt files or one GPFile.txt holding every frame.

    Parameters
    ----------
    path : str or pathlib.Path
        A file or folder.

    Returns
    -------
    bool
    """
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    if not (folder / SLICE_INFO).is_file():
        return False
    return (folder / SINGLE_GP_FILE).is_file() or any(GP_FILE.match(q.name)
                                                     for q in folder.iterdir())


# ------------------------------------------------------------------ SliceInfoFile
#: SliceInfoFile labels of the slice number: ours, and the CAP / biv-me exports' own
SLICE_LABELS = ("sliceID:", "frameID:")
#: geometry of two lines of one slice agrees within these (mm; direction cosines)
SAME_POSITION_MM, SAME_COSINE = 1e-3, 1e-5


def _slice_tokens(line: str) -> tuple[list[str], str]:
    """Tokens of one SliceInfoFile line and its separator (a tab, or the whitespace run
    that separates every token when the line has no tab)."""
    if "\t" in line:
        tok = [t.strip() for t in line.split("\t")]
        return [t for t in tok if t != ""], "\t"
    runs = set(re.findall(r"\s+", line.strip()))
    return line.split(), (runs.pop() if len(runs) == 1 else " ")


def read_slice_info(path: str | Path) -> list[dict]:
    """Parse SliceInfoFile.txt in either style: one line per slice labelled ``sliceID:``
    (ours), or the CAP / biv-me export's ``frameID:`` lines, where each slice may be listed
    once per frame (with an optional ``timeFrame N`` pair); tabs or spaces; the first token
    names the image (a DICOM file name or a UID).

    Lines of one slice number are merged when their geometry is the same; different
    geometry for one slice is a StudyError naming both lines. Returns one dict per slice
    (first-listed order): file, id, line, position, orientation, pixel_spacing, the numbers
    as written (``tokens``) and ``entries`` [(line, time frame or None, image token)].
    The style (label, separator, line order) is on the first dict's ``style``.

    Parameters
    ----------
    path : str or pathlib.Path
        The SliceInfoFile.txt.

    Returns
    -------
    list of dict
        As above (positions mm).

    Raises
    ------
    StudyError
        A missing file, field or number, or one slice listed with two geometries.
    """
    path = Path(path)
    if not path.is_file():
        raise StudyError("SliceInfoFile.txt is missing", file=path)
    text = checked(path, what="SliceInfoFile").read_text(encoding="utf-8", errors="replace")
    out: dict[int, dict] = {}
    order, labels, seps = [], [], []
    for k, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        tok, sep = _slice_tokens(line)
        label = next((t for t in tok if t in SLICE_LABELS), None)
        if label is None:
            raise StudyError(f"line {k}: missing sliceID (expected a 'sliceID:' or 'frameID:' "
                             "label before the slice number)", file=path, field="sliceID")
        raw = next(t for t in line.split(sep) if t.strip() == label) if sep == "\t" else label
        labels.append(raw)
        seps.append(sep)
        rec: dict[str, Any] = {"file": tok[0], "line": k}
        for key, n in ((label, 1), ("ImagePositionPatient", 3),
                       ("ImageOrientationPatient", 6), ("PixelSpacing", 2)):
            name = "sliceID" if key in SLICE_LABELS else key
            if key not in tok:
                raise StudyError(f"line {k}: missing {name}", file=path, field=name)
            i = tok.index(key)
            vals = tok[i + 1:i + 1 + n]
            try:
                nums = [float(v) for v in vals]
            except ValueError:
                nums = []
            if len(nums) != n or not np.all(np.isfinite(nums)):
                raise StudyError(f"line {k}: {name} needs {n} finite number(s), got "
                                 f"{excerpt(' '.join(vals))}", file=path, field=name)
            rec[name] = (nums, vals)
        time = None
        if "timeFrame" in tok:
            i = tok.index("timeFrame")
            val = tok[i + 1] if i + 1 < len(tok) else ""
            try:
                time = int(val)
            except ValueError:
                raise StudyError(f"line {k}: timeFrame needs a whole number, got {excerpt(val)}",
                                 file=path, field="timeFrame") from None
        sid = rec["sliceID"][0][0]
        if sid != int(sid):
            raise StudyError(f"line {k}: sliceID must be a whole number", file=path, field="sliceID")
        sid = int(sid)
        geo = {"position": rec["ImagePositionPatient"][0],
               "orientation": rec["ImageOrientationPatient"][0],
               "pixel_spacing": rec["PixelSpacing"][0]}
        order.append([sid, time, rec["file"]])
        if sid in out:
            first = out[sid]
            diff = _geometry_difference(first, geo)
            if diff:
                raise StudyError(f"lines {first['line']} and {k}: slice {sid} is listed with "
                                 f"different geometry ({diff})", file=path, field="sliceID")
            if time is not None and any(t == time for _, t, _ in first["entries"]):
                raise StudyError(f"lines {first['line']} and {k}: slice {sid} is listed twice "
                                 f"for timeFrame {time}", file=path, field="timeFrame")
            first["entries"].append((k, time, rec["file"]))
            continue
        out[sid] = {"file": rec["file"], "id": sid, "line": k, **geo,
                    "tokens": {"position": rec["ImagePositionPatient"][1],
                               "orientation": rec["ImageOrientationPatient"][1],
                               "pixel_spacing": rec["PixelSpacing"][1]},
                    "entries": [(k, time, rec["file"])]}
    if not out:
        raise StudyError("SliceInfoFile.txt has no slices", file=path)
    slices = list(out.values())
    slices[0]["style"] = {"label": max(set(labels), key=labels.count),
                          "sep": max(set(seps), key=seps.count), "order": order,
                          "per_frame": len(order) > len(slices)}
    return slices


def _geometry_difference(a: dict, b: dict) -> str:
    """'' when two slice geometries agree, else which field differs and by how much."""
    dp = float(np.abs(np.subtract(a["position"], b["position"])).max())
    if dp > SAME_POSITION_MM:
        return f"ImagePositionPatient differs by {dp:.3g} mm"
    do = float(np.abs(np.subtract(a["orientation"], b["orientation"])).max())
    if do > SAME_COSINE:
        return f"ImageOrientationPatient differs by {do:.3g}"
    ds = float(np.abs(np.subtract(a["pixel_spacing"], b["pixel_spacing"])).max())
    if ds > SAME_POSITION_MM:
        return f"PixelSpacing differs by {ds:.3g} mm"
    return ""


def _merge_same_geometry(slices: list[dict]) -> tuple[list[dict], dict[int, int]]:
    """Merge the slice numbers whose geometry agrees (:func:`_geometry_difference`) into the
    first-listed one: CAP exports can number each frame's image of one slice apart.

    Parameters
    ----------
    slices : list of dict
        :func:`read_slice_info`'s slices.

    Returns
    -------
    slices : list of dict
        One per distinct geometry (the first-listed number; its ``entries`` gain the others').
    alias : dict of int to int
        Merged slice number -> the number kept (empty when nothing merged).
    """
    kept: list[dict] = []
    alias: dict[int, int] = {}
    geo = np.array([[*s["position"], *s["orientation"], *s["pixel_spacing"]] for s in slices])
    tol = np.r_[[SAME_POSITION_MM] * 3, [SAME_COSINE] * 6, [SAME_POSITION_MM] * 2]
    owner = np.full(len(slices), -1)
    for i, s in enumerate(slices):
        if owner[i] >= 0:
            continue
        same = np.flatnonzero((np.abs(geo - geo[i]) <= tol).all(axis=1) & (owner < 0))
        owner[same] = i
        kept.append(s)
        for j in same[same != i]:
            alias[int(slices[j]["id"])] = int(s["id"])
            s["entries"] = s["entries"] + slices[j]["entries"]
    if alias and "style" in slices[0] and "style" not in kept[0]:
        kept[0]["style"] = slices[0]["style"]
    return kept, alias


def _frame_of_time(slices: list[dict], files: list[tuple[int, Path]], path: Path,
                   lines: dict[int, int] | None = None) -> int | None:
    """Offset from the SliceInfoFile's timeFrame numbers to GPFile frame numbers (0, or 1
    for 1-based exports), None when no line has a timeFrame. StudyError names the first
    GPFile whose frame no SliceInfoFile line lists (and, from ``lines``: frame -> line, the
    frame's first line in a single GPFile.txt)."""
    times = {t for s in slices for _, t, _ in s["entries"] if t is not None}
    if not times:
        return None
    frames = [f for f, _ in files]
    offset = max((0, 1), key=lambda o: (sum(f + o in times for f in frames), -o))
    for f, q in files:
        if f + offset not in times:
            at = f"line {lines[f]}: " if lines and f in lines and q.name == SINGLE_GP_FILE else ""
            raise StudyError(f"{at}no line of {SLICE_INFO} lists this frame (its lines list timeFrame "
                             f"{min(times)}-{max(times)})", file=q, frame=f, field="timeFrame")
    return offset


# ------------------------------------------------------------------------ GPFile
def read_gp_table(path: str | Path) -> tuple[dict[str, np.ndarray], str, int | None]:
    """One GPFile as numpy columns (``x``, ``y``, ``z`` floats; ``type``, ``weight`` and
    ``time`` as the text written; ``slice_id`` and ``line`` integers), its header line and
    the fixed number of decimals of its x y z text (None if not fixed). StudyError names
    the file and line of any bad value.

    A plain file (ASCII, tab-separated, 7 fields on every line, every number an ordinary
    decimal) is split and converted by numpy (:func:`_plain_rows`); any other is read by
    pandas, whose reader and messages define what is accepted and how it is reported.

    Parameters
    ----------
    path : str or pathlib.Path
        A GPFile_NNN.txt.

    Returns
    -------
    columns : dict of str to ndarray
        The columns above.
    header : str
        The header line.
    decimals : int or None
        The fixed decimals of x y z.

    Raises
    ------
    StudyError
        A bad value (naming file and line).
    """
    path = checked(path, what="GPFile")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise StudyError("not a text file (cannot decode as UTF-8)", file=path) from None
    lines = text.splitlines()
    if not any(ln.strip() for ln in lines):
        raise StudyError("empty GPFile (expected a header and x y z contour_type frameID weight "
                         "time_frame lines)", file=path)
    header, start = "", 0
    try:
        float(lines[0].split("\t")[0].strip())
    except ValueError:
        header, start = lines[0], 1
    perm = header_order(header)
    if perm is not None:                       # columns named in another order: reorder them
        lines = lines[:start] + [_reordered(ln, perm) for ln in lines[start:]]
        text = "\n".join(lines) + "\n"
    rows = _plain_rows(text, lines, start)
    if rows is not None:
        return rows, header, _fixed_decimals([rows.pop(f"{c}_text") for c in "xyz"])
    import pandas as pd
    table = _fast_table(text, start) if all(ln.strip() for ln in lines[start:]) else None
    if table is None:
        table = _slow_table(lines, start, path)
    decimals = _fixed_decimals([table[c].to_numpy(str) for c in ("x", "y", "z")])
    for col in ("x", "y", "z", "slice", "weight"):
        num = pd.to_numeric(table[col], errors="coerce").to_numpy(float)
        bad = ~np.isfinite(num)
        if col == "slice":
            bad |= num != np.round(num)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            what = "NaN or infinite" if table[col].iloc[i].lower() in ("nan", "inf", "-inf") \
                else "not a number"
            raise StudyError(f"line {table['line'].iloc[i]}: {col} is {what} "
                             f"({excerpt(table[col].iloc[i])})", file=path,
                             field="frameID" if col == "slice" else col)
        if col in ("x", "y", "z"):
            table[col] = num
        elif col == "slice":
            table["slice_id"] = num.astype(int)
    return {"x": table["x"].to_numpy(float), "y": table["y"].to_numpy(float),
            "z": table["z"].to_numpy(float), "type": table["type"].to_numpy(object),
            "slice_id": table["slice_id"].to_numpy(int),
            "weight": table["weight"].to_numpy(object), "time": table["time"].to_numpy(object),
            "line": table["line"].to_numpy(int)}, header, decimals


#: a GPFile header's column names (lower case, without spaces and underscores) -> column
_COLUMN_NAMES = {"x": "x", "y": "y", "z": "z", "contourtype": "type", "type": "type",
                 "frameid": "slice", "sliceid": "slice", "slice": "slice", "weight": "weight",
                 "timeframe": "time", "time": "time"}
_HEADER_TOKEN = re.compile(r"contour[ _]?type|time[ _]?frame|frame[ _]?id|slice[ _]?id|[^\s]+", re.I)


def header_order(header: str) -> list[int] | None:
    """Where a GPFile's header puts each of the columns x, y, z, contour type, frameID
    (``sliceID``), weight, time frame: the file column of each, in that order; None when the
    header names them in that order (or does not name the seven; the order is then taken to
    be that one). biv-me reads the columns by these names, so a file may order them its way.

    Parameters
    ----------
    header : str
        The header line ("" for none).

    Returns
    -------
    list of int or None
        Seven file-column indices, or None.
    """
    names = [_COLUMN_NAMES.get(re.sub(r"[\s_]", "", t).lower()) for t in _HEADER_TOKEN.findall(header)]
    if len(names) != 7 or sorted(map(str, names)) != sorted(_COLUMNS):
        return None
    perm = [names.index(c) for c in _COLUMNS]
    return None if perm == list(range(7)) else perm


def _reordered(line: str, perm: list[int]) -> str:
    """One data line with its fields (tab or whitespace separated) in the standard order."""
    tok = line.split("\t")
    if len(tok) != 7:
        tok = line.split()
    if len(tok) != 7:
        return line                            # left to the readers' error naming the line
    return "\t".join(tok[i].strip() for i in perm)


#: characters that make a file not plain (:func:`_plain_rows`): controls other than tab and
#: line ends (Python's line splitting and stripping treat some of them as breaks or space)
_NOT_PLAIN = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def _plain_rows(text: str, lines: list[str], start: int) -> dict[str, np.ndarray] | None:
    """The rows of a plain GPFile as numpy columns (see :func:`read_gp_table`, plus the
    ``x_text``, ``y_text``, ``z_text`` tokens), without pandas; None when the file is not
    plain: a non-ASCII or control character, a blank line, a line without exactly 7 tab
    fields, an empty time field, or a number field that is not a finite decimal (slice:
    integral) without underscores. Such a file goes to the pandas reader, which reports
    what is wrong with it. On a plain file both readers give the same columns (numbers
    parsed by the correctly rounded conversion numpy shares with Python's ``float``)."""
    body = lines[start:]
    if not body or not text.isascii() or _NOT_PLAIN.search(text) \
            or not all(ln.strip() for ln in body):
        return None
    fields = [ln.split("\t") for ln in body]
    if any(len(f) != 7 for f in fields):
        return None
    x, y, z, types, slices, weight, time = (np.array(c, dtype=object) for c in zip(*fields))
    if any(t == "" for t in time):
        return None
    num = {}
    for name, col in (("x", x), ("y", y), ("z", z), ("slice", slices), ("weight", weight)):
        if "_" in "".join(col):               # numpy's float() takes 1_0; pandas does not
            return None
        try:
            v = col.astype(str).astype(float)
        except ValueError:
            return None
        if not np.isfinite(v).all() or (name == "slice" and np.any(v != np.round(v))):
            return None
        num[name] = v
    return {"x": num["x"], "y": num["y"], "z": num["z"],
            "type": np.array([t.strip() for t in types], dtype=object),
            "slice_id": num["slice"].astype(int), "weight": weight, "time": time,
            "line": np.arange(len(body)) + start + 1,
            "x_text": x.astype(str), "y_text": y.astype(str), "z_text": z.astype(str)}


def _take(rows: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, np.ndarray]:
    return {k: v[keep] for k, v in rows.items()}


_COLUMNS = ["x", "y", "z", "type", "slice", "weight", "time"]


def _fast_table(text: str, start: int) -> pd.DataFrame | None:
    """Parse with pandas' C reader; None when some line has not exactly 7 fields."""
    import pandas as pd
    try:
        t = pd.read_csv(io.StringIO(text), sep="\t", header=None, names=_COLUMNS, dtype=str,
                        keep_default_na=False, skiprows=start, engine="c", quoting=3)
    except (pd.errors.ParserError, ValueError):
        return None
    if len(t) and (t["time"] == "").any():
        return None
    if len(t):
        t["type"] = t["type"].str.strip()
    t["line"] = np.arange(len(t)) + start + 1
    return t


def _slow_table(lines: list[str], start: int, path: Path) -> pd.DataFrame:
    """Line-by-line parse (blank lines, whitespace separators) with exact error lines."""
    import pandas as pd
    rows = []
    for k in range(start, len(lines)):
        ln = lines[k]
        if not ln.strip():
            continue
        tok = ln.split("\t")
        if len(tok) != 7:
            tok = ln.split()
        if len(tok) != 7:
            raise StudyError(f"line {k + 1}: expected 7 tab-separated fields (x y z contour_type "
                             f"frameID weight time_frame), got {len(tok)}", file=path)
        rows.append([t.strip() for t in tok] + [k + 1])
    return pd.DataFrame(rows, columns=[*_COLUMNS, "line"])


def _gp_files(folder: Path) -> list[tuple[int, Path]]:
    """(frame, file) of the folder's GPFile_NNN.txt (any number of digits), by frame;
    StudyError naming both files when two name one frame (GPFile_03 and GPFile_003)."""
    files = sorted((int(m.group(1)), q) for q in folder.iterdir() if (m := GP_FILE.match(q.name)))
    for (f, a), (g, b) in zip(files, files[1:]):
        if f == g:
            raise StudyError(f"two GPFiles for frame {f} ({a.name} and {b.name})", file=folder)
    return files


def _single_file(p: Path, folder: Path) -> Path | None:
    """The one GPFile.txt holding every frame: ``p`` itself when it is that file, else the
    folder's GPFile.txt when the folder has no GPFile_NNN.txt; None otherwise."""
    if p.is_file() and p.name == SINGLE_GP_FILE:
        return p
    if (folder / SINGLE_GP_FILE).is_file() and not _gp_files(folder):
        return folder / SINGLE_GP_FILE
    return None


def split_frames(t: dict[str, np.ndarray], path: Path) -> list[tuple[int, dict[str, np.ndarray]]]:
    """Split the rows of a single-file GPFile (every frame in one file) by its ``time frame``
    column, keeping each row's line number.

    Parameters
    ----------
    t : dict of str to ndarray
        The file's columns (:func:`read_gp_table`).
    path : pathlib.Path
        The file, for the messages.

    Returns
    -------
    list of (int, dict)
        (frame, that frame's rows) by frame; frames as the column numbers them.

    Raises
    ------
    StudyError
        A row whose time frame is missing or not a whole number >= 0 (naming its line).
    """
    text = np.char.strip(np.asarray(t["time"], dtype=str))
    uniq, inverse = np.unique(text, return_inverse=True)
    v = np.array([_number_or_nan(u) for u in uniq], float)[inverse]  # few distinct frames
    with np.errstate(invalid="ignore"):
        bad = ~(np.isfinite(v) & (v == np.round(v)) & (v >= 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        got = "nothing" if text[i] == "" else excerpt(text[i])
        raise StudyError(f"line {t['line'][i]}: time frame is {got}; {path.name} holds every "
                         "frame, so each line needs its frame as a whole number >= 0 in the "
                         "time frame column", file=path, field="time frame")
    frames = v.astype(int)
    return [(int(f), _take(t, frames == f)) for f in np.unique(frames)]


def _read_tables(files: list[tuple[int, Path]], single: Path | None):
    """Each frame's rows, the header and the set of x y z decimals, from the GPFile_NNN.txt
    files or from the single GPFile.txt (split by :func:`split_frames`)."""
    if single is None:
        out = []
        header, decimals = None, set()
        for frame, f in files:
            t, h, dec = read_gp_table(f)
            header = h if header is None else header
            decimals.add(dec)
            out.append((frame, f, t))
        return out, header, decimals
    t, header, dec = read_gp_table(single)
    return [(fr, single, tf) for fr, tf in split_frames(t, single)], header, {dec}


def _checked_tables(raw: list, alias: dict[int, int], slice_ids: set[int],
                    last_frame: int) -> tuple[list[dict[str, np.ndarray]], int]:
    """Each frame's rows without EXCLUDED points, slice numbers merged by ``alias``, checked
    (slice reference, weight, values); and how many EXCLUDED points were dropped."""
    tables = []
    excluded = 0
    for _frame, f, t in raw:
        drop = np.array([ty in EXCLUDED_TYPES for ty in t["type"]], dtype=bool)
        excluded += int(drop.sum())
        t = _take(t, ~drop)
        if alias:
            t["slice_id"] = np.array([alias.get(int(i), int(i)) for i in t["slice_id"]], int)
        unknown = ~np.isin(t["slice_id"], list(slice_ids))
        if unknown.any():
            i = int(np.flatnonzero(unknown)[0])
            raise StudyError(f"line {t['line'][i]}: reference to slice (frameID) "
                             f"{t['slice_id'][i]} that is not in {SLICE_INFO}", file=f,
                             field="frameID")
        w = t["weight"].astype(str).astype(float)
        if (w < 0).any():
            i = int(np.flatnonzero(w < 0)[0])
            raise StudyError(f"line {t['line'][i]}: weight must be >= 0, got "
                             f"{t['weight'][i]!r}", file=f, field="weight")
        check_gp_values(t, f, last_frame)
        tables.append(t)
    return tables, excluded


def _images(slices: list[dict], frames: list[int], planes: dict, names: dict,
            views: dict) -> list[ImagePlane]:
    """One ImagePlane per slice and frame; the DICOM names are meta only (files are absent)."""
    return [ImagePlane(id=f"{names[s['id']]}_f{fr:03d}", slice=names[s["id"]],
                       view=views[s["id"]], frame=fr, position=planes[s["id"]].position,
                       row_cosine=planes[s["id"]].row_cosine,
                       column_cosine=planes[s["id"]].column_cosine,
                       pixel_spacing=planes[s["id"]].pixel_spacing, rows=DEFAULT_ROWS,
                       columns=DEFAULT_COLUMNS, thickness=DEFAULT_THICKNESS_MM)
            for s in slices for fr in frames]


def _reading_warnings(folder: Path, contours: list[Contour], excluded: int, single: Path | None,
                      files: list[tuple[int, Path]], alias: dict[int, int],
                      n_slices: int) -> list[str]:
    """What reading changed or set aside: non-ventricular contours, EXCLUDED points, frames
    told apart in one file, slice numbers merged."""
    warnings = []
    other = Counter(c.structure for c in contours if not c.ventricular)
    if other:
        counts = ", ".join(f"{k} x{v}" for k, v in sorted(other.items()))
        warnings.append(f"{folder}: {sum(other.values())} atrial, venous or extent contour(s) "
                        f"kept but not used for the ventricles ({counts})")
    if excluded:
        warnings.append(f"{folder}: {excluded} EXCLUDED guide point(s) dropped")
    if single is not None:
        span = (f"1 frame ({files[0][0]})" if len(files) == 1
                else f"{len(files)} frames ({files[0][0]}-{files[-1][0]})")
        warnings.append(f"{single}: one file for every frame: {span} told apart by its time "
                        "frame column")
    if alias:
        warnings.append(f"{folder / SLICE_INFO}: {len(alias)} slice number(s) with the geometry "
                        f"of another (one image number per frame, as CAP exports number them) "
                        f"merged into {n_slices} slice(s)")
    return warnings


def read_study(path: str | Path) -> Study:
    """Read a GPFile folder (GPFile_NNN.txt per frame, or one GPFile.txt holding every
    frame, + SliceInfoFile.txt) into a Study.

    EXCLUDED guide points are dropped; atrial, venous and extent traces are kept as
    non-ventricular contours (one warning counts them); the weight column becomes each
    contour's point weights (``Contour.weights``).

    Parameters
    ----------
    path : str or pathlib.Path
        The GPFile folder, or a file in it (``GPFile.txt``: that single file).

    Returns
    -------
    Study
        Scanner mm.

    Raises
    ------
    StudyError
        A missing or bad file, or points on no slice plane (naming file, line and field).
    """
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    single = _single_file(p, folder)
    files = _gp_files(folder) if single is None else []
    if not files and single is None:
        raise StudyError(f"no GPFile_NNN.txt files and no {SINGLE_GP_FILE} in this folder",
                         file=folder)
    files_inside(folder, [folder / SLICE_INFO] + ([single] if single else [f for _, f in files]),
                 what="GPFile")
    slices = read_slice_info(folder / SLICE_INFO)
    raw, header, decimals = _read_tables(files, single)
    if single is not None:
        files = [(fr, single) for fr, _, _ in raw]
    _frame_of_time(slices, files, folder / SLICE_INFO,
                   lines={fr: int(t["line"][0]) for fr, _, t in raw if len(t["line"])})
    for s in slices:                           # names only (never opened), kept confined
        for _, _, name in s["entries"]:
            study_file(folder, name, file=folder / SLICE_INFO, field="file")
    slices, alias = _merge_same_geometry(slices)
    tables, excluded = _checked_tables(raw, alias, {s["id"] for s in slices},
                                       max(fr for fr, _ in files))
    planes, names, views, rule = _slice_planes(slices, tables, folder)
    frames = [fr for fr, _ in files]
    images = _images(slices, frames, planes, names, views)
    contours: list[Contour] = []
    landmarks: list[Landmark] = []
    frame_meta = {}
    warnings: list[str] = []
    for (frame, f), t in zip(files, tables):
        blocks, runs = _read_blocks(t, frame, f, names, views, contours, landmarks, planes,
                                    warnings)
        frame_meta[str(frame)] = {"file": None if single else f.name, "blocks": blocks,
                                  "runs": runs}
    warnings += _reading_warnings(folder, contours, excluded, single, files, alias, len(slices))
    warnings += _export_warnings(folder, rule, landmarks, files)
    style = slices[0]["style"]
    meta = {"format": "gpfile", "base_apex_rule": rule,
            "gpfile": {"header": header, "frames": frame_meta,
                       "decimals": decimals.pop() if len(decimals) == 1 else None,
                       "single_file": single.name if single is not None else None,
                       "slices": [{"slice": names[s["id"]], "id": s["id"], "file": s["file"],
                                   "tokens": s["tokens"]} for s in slices],
                       "slice_info": {"label": style["label"], "sep": style["sep"],
                                      "order": style["order"] if style["per_frame"] else None},
                       "n_contours": len(contours), "n_landmarks": len(landmarks),
                       "defaults": "rows, columns (256) and thickness (8 mm) are not in "
                                   "SliceInfoFile.txt"}}
    return Study(subject=folder.name, images=images, contours=contours, landmarks=landmarks,
                 source=str(folder), meta=meta, warnings=warnings)


def _export_warnings(folder: Path, rule: str | None, landmarks: list[Landmark],
                     files: list[tuple[int, Path]]) -> list[str]:
    """What an export lacks that changes how it is reconstructed: the APEX_POINT and
    MITRAL_VALVE points that order the stack, the valve points that place the bases, and
    GPFiles missing from the frame series."""
    out = []
    if rule == "LPS prior":
        out.append(f"{folder}: no APEX_POINT or MITRAL_VALVE guide points: base and apex of the "
                   "short-axis stack from the patient axes (LPS prior) only: check the slice order")
    valves = {lm.name for lm in landmarks} & {"mitral", "tricuspid"}
    for side, name, gp_name in (("LV", "mitral", "MITRAL_VALVE"), ("RV", "tricuspid", "TRICUSPID_VALVE")):
        if name not in valves:
            out.append(f"{folder}: no {gp_name} guide points: the {side} base closed half a slice "
                       "beyond its most basal short-axis contour (volumes need not match a fit to "
                       "the valve)")
    frames = [f for f, _ in files]
    gaps = sorted(set(range(frames[0], frames[-1] + 1)) - set(frames))
    if gaps:
        shown = ", ".join(map(str, gaps[:8])) + (", ..." if len(gaps) > 8 else "")
        span = (f"frames {frames[0]} and {frames[-1]} of {files[0][1].name}"
                if files[0][1] == files[-1][1] else f"{files[0][1].name} and {files[-1][1].name}")
        out.append(f"{folder}: no GPFile for frame{'s' if len(gaps) > 1 else ''} {shown} (between "
                   f"{span}): missing from the volume curve, ED and ES chosen among the other "
                   "frames")
    return out


def _slice_planes(slices: list[dict], tables: list[dict[str, np.ndarray]], folder: Path):
    """ImagePlane per slice id, slice names, views and the base/apex rule."""
    planes = {}
    for s in slices:
        ori = np.asarray(s["orientation"], float)
        try:
            planes[s["id"]] = ImagePlane(id=str(s["id"]), slice=str(s["id"]), view="SA", frame=0,
                                         position=s["position"], row_cosine=ori[:3],
                                         column_cosine=ori[3:], pixel_spacing=s["pixel_spacing"],
                                         thickness=DEFAULT_THICKNESS_MM, file=s["file"])
        except StudyError as exc:
            raise StudyError(f"line {s.get('line', '?')}: {exc}", file=folder / SLICE_INFO) from None
    ids = [s["id"] for s in slices]
    normals = np.array([planes[i].normal for i in ids])
    centers = np.array([planes[i].position for i in ids])
    is_sa = stack.split_stack(normals)
    types = np.concatenate([t["type"] for t in tables])
    xyz = np.column_stack([np.concatenate([t[c] for t in tables]) for c in ("x", "y", "z")])
    apex = xyz[types == "APEX_POINT"]
    mitral = xyz[types == "MITRAL_VALVE"]
    names, views, rule = {}, {}, None
    sa = [i for i, m in zip(ids, is_sa) if m]
    if sa:
        sa_idx = np.flatnonzero(is_sa)
        u, rule = stack.base_to_apex_direction(
            stack_normal(normals[sa_idx]), centers[sa_idx],
            apex=apex.mean(axis=0) if len(apex) else None,
            mitral=mitral if len(mitral) else None)
        depth = centers[sa_idx] @ u
        for k, j in enumerate(np.argsort(depth, kind="stable")):
            names[sa[j]], views[sa[j]] = f"sa_{k:02d}", "SA"
    by_id = {s["id"]: s for s in slices}
    la_names = {}
    for i, m in zip(ids, is_sa):
        if not m:
            hit = _LA_VIEW.search(Path(by_id[i]["file"]).name)
            la_names[i] = f"la_{hit.group(1)}ch" if hit else f"la_{i}"
    counts = Counter(la_names.values())
    for i, name in la_names.items():
        names[i], views[i] = (name if counts[name] == 1 else f"la_{i}"), "LA"
    return planes, names, views, rule


_LA_VIEW = re.compile(r"(?<![0-9a-z])([234])\s*-?\s*ch(?![a-z])", re.IGNORECASE)


def _contour_kind(gp_type: str) -> tuple[str, str | None] | None:
    """(structure, view or None for either) of a GPFile contour type, None if unknown."""
    if gp_type in SINGLE_VIEW_TYPES:
        return SINGLE_VIEW_TYPES[gp_type]
    if gp_type in OTHER_TYPES:
        return OTHER_TYPES[gp_type]
    prefix, _, base = gp_type.partition("_")
    if prefix in VIEW_PREFIX and base in CONTOUR_TYPES:
        return CONTOUR_TYPES[base], VIEW_PREFIX[prefix]
    return None


def is_loop(points: np.ndarray, gap_steps: float = LOOP_GAP_STEPS) -> bool:
    """True when an ordered trace closes on itself: it has >= 5 points, its ends are no
    farther apart than ``gap_steps`` times its median point spacing and than a quarter
    of its extent, no step along it is longer than that either (an open arc written from
    its middle jumps between its ends), and closing it does not make it cross itself.

    Parameters
    ----------
    points : (n, 3) ndarray
        An ordered trace, mm.
    gap_steps : float
        The closing gap allowed, in median point spacings.

    Returns
    -------
    bool
    """
    if len(points) < 5:
        return False
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    gap = float(np.linalg.norm(points[-1] - points[0]))
    extent = float(np.linalg.norm(points - points[0], axis=1).max())
    limit = gap_steps * max(float(np.median(step)), 1e-9)
    if gap > limit or gap > 0.25 * extent or float(step.max()) > limit:
        return False
    return len(self_intersections(in_plane_coordinates(points), True)) == 0


#: contour points farther than this (median) from a slice plane do not lie on it, mm
ON_PLANE_MM = 1.0


def _placed(pts: np.ndarray, sid: int, gp_type: str, planes: dict, names: dict, views: dict,
            f: Path, lines: np.ndarray, warnings: list[str]) -> int:
    """The slice whose plane a contour's points lie on (median distance <= ON_PLANE_MM):
    its frameID's, else the nearest other; a warning when that slice or its view is not
    what the file says (the SAX_/LAX_ prefix), a StudyError when no plane holds them."""
    where = f"lines {lines[0]}-{lines[-1]}" if len(lines) > 1 else f"line {lines[0]}"

    def off(i: int) -> float:
        return float(np.median(np.abs(planes[i].distance_to_plane(pts))))
    placed = sid
    if off(sid) > ON_PLANE_MM:
        dist = {i: off(i) for i in planes}
        placed = min(dist, key=dist.__getitem__)
        if dist[placed] > ON_PLANE_MM:
            raise StudyError(f"{where}: {gp_type} points lie on no slice plane of {SLICE_INFO} "
                             f"({off(sid):.1f} mm from slice {sid}, their frameID; nearest plane "
                             f"{dist[placed]:.1f} mm away, slice {placed})", file=f,
                             field="frameID")
    label = VIEW_PREFIX.get(gp_type.partition("_")[0])
    if placed != sid or (label is not None and label != views[placed]):
        axis = {"SA": "short", "LA": "long"}[views[placed]]
        moved = f" (frameID {sid}: {off(sid):.1f} mm off that plane)" if placed != sid else ""
        warnings.append(f"{f}: {where}: {gp_type} lies on slice {placed} ({names[placed]}), a "
                        f"{axis}-axis slice by its geometry{moved}: used as {views[placed]} "
                        "(the slice geometry wins over the label)")
    return placed


def _read_blocks(t: dict[str, np.ndarray], frame: int, f: Path, names: dict, views: dict,
                 contours: list, landmarks: list, planes: dict[int, ImagePlane],
                 warnings: list[str] | None = None):
    """Contours and landmarks of one frame's rows (:func:`read_gp_table`), in file order;
    the block order and the (weight, time frame) runs for write-back. A contour's slice
    and view are those of the plane its points lie on (:func:`_placed`; ``planes``: slice
    id -> ImagePlane), its disagreements with the file told in ``warnings``."""
    warnings = [] if warnings is None else warnings
    types = t["type"]
    sids = t["slice_id"]
    n = len(types)
    # column-major (as a DataFrame block gives them): each contour's points are views of
    # these, and their layout steers the rounding of later products
    xyz = np.asfortranarray(np.column_stack([t["x"], t["y"], t["z"]]).astype(float))
    weights = t["weight"].astype(str).astype(float)
    lines = t["line"]
    key = np.array([f"{a}\x1f{b}" for a, b in zip(types, sids)]) if n else np.array([])
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if n else np.array([], int)
    ends = np.r_[starts[1:], n].astype(int)
    blocks = []
    piece: dict[tuple, int] = {}
    lm_count: dict[tuple[str, str], int] = {}
    for s, e in zip(starts, ends):
        gp_type, sid = str(types[s]), int(sids[s])
        slice_id, view = names[sid], views[sid]
        image = f"{slice_id}_f{frame:03d}"
        if gp_type in LANDMARK_TYPES:
            name = LANDMARK_TYPES[gp_type]
            blocks.append(["l", len(landmarks), int(e - s), gp_type])
            for k in range(s, e):  # index counts the points of a name on one slice
                n = lm_count.get((name, slice_id), 0)
                landmarks.append(Landmark(name, frame, xyz[k], index=n, slice=slice_id, view=view,
                                          image=image))
                lm_count[(name, slice_id)] = n + 1
            continue
        kind = _contour_kind(gp_type)
        if kind is not None and gp_type not in SINGLE_VIEW_TYPES:    # geometry over labels
            sid = _placed(xyz[s:e], sid, gp_type, planes, names, views, f, lines[s:e], warnings)
            slice_id, view = names[sid], views[sid]
            image = f"{slice_id}_f{frame:03d}"
            kind = (kind[0], view)
        if kind is None:
            raise StudyError(f"line {lines[s]}: unknown contour type {excerpt(gp_type)}; expected "
                             f"SAX_/LAX_ + {', '.join(CONTOUR_TYPES)}, "
                             f"{', '.join([*SINGLE_VIEW_TYPES, *OTHER_TYPES])}, a landmark "
                             f"({', '.join(LANDMARK_TYPES)}) or EXCLUDED", file=f,
                             field="contour type")
        structure, want = kind
        if want != view:
            raise StudyError(f"line {lines[s]}: {gp_type} on slice {sid} ({slice_id}), which is a "
                             f"{'short' if view == 'SA' else 'long'}-axis slice by its orientation",
                             file=f, field="contour type")
        pts = xyz[s:e]
        if view == "SA" and structure in ("lv_endo", "lv_epi"):
            closed = True
        elif view == "SA" and structure in ("rv_endo", "rv_epi", "rv_outlet"):
            closed = is_loop(pts)
        else:
            closed = False
        k = piece.get((structure, slice_id), 0)
        piece[(structure, slice_id)] = k + 1
        blocks.append(["c", len(contours), gp_type])
        try:
            contours.append(Contour(structure, view, slice_id, frame, pts, image=image,
                                    closed=closed, index=k, weights=weights[s:e]))
        except StudyError as exc:
            raise StudyError(f"line {lines[s]}: {exc}", file=f) from None
    wt = t["weight"]
    tm = t["time"]
    runs: list[list[Any]] = []                      # [count, weight, time frame]
    for w, tt in zip(wt, tm):
        if runs and runs[-1][1] == w and runs[-1][2] == tt:
            runs[-1][0] += 1
        else:
            runs.append([1, str(w), str(tt)])
    return blocks, runs


def check_gp_values(t: dict[str, np.ndarray], path: Path, last_frame: int) -> None:
    """Values in range, before any arithmetic: |x|, |y|, |z| within
    :data:`cardionurbs.limits.MAX_COORDINATE_MM`, and each ``time frame`` (when given) a
    whole number from 0 to ``last_frame + 1`` (1-based exports). StudyError names the line
    with a short excerpt of the value.

    Parameters
    ----------
    t : dict of str to ndarray
        The file's columns (:func:`read_gp_table`).
    path : pathlib.Path
        The file, for the messages.
    last_frame : int
        The study's last frame index.

    Raises
    ------
    StudyError
        A value out of range.
    """
    from cardionurbs.limits import MAX_COORDINATE_MM
    for col in ("x", "y", "z"):
        far = np.abs(np.asarray(t[col], float)) > MAX_COORDINATE_MM
        if far.any():
            i = int(np.flatnonzero(far)[0])
            raise StudyError(f"line {t['line'][i]}: {col} = {float(t[col][i]):.3g} mm lies past "
                             f"{MAX_COORDINATE_MM:g} mm from the scanner origin", file=path,
                             field=col)
    text = np.char.strip(np.asarray(t["time"], dtype=str))
    rows = np.flatnonzero(text != "")
    uniq, inverse = np.unique(text[rows], return_inverse=True)
    v = np.array([_number_or_nan(u) for u in uniq], float)[inverse]   # few distinct frames
    with np.errstate(invalid="ignore"):
        bad = ~(np.isfinite(v) & (v == np.round(v)) & (v >= 0) & (v <= last_frame + 1))
    if bad.any():
        i = int(rows[np.flatnonzero(bad)[0]])
        raise StudyError(f"line {t['line'][i]}: time frame {excerpt(text[i])} is not a whole "
                         f"number from 0 to {last_frame + 1} (the study's frames)",
                         file=path, field="time frame")


def _number_or_nan(text: str) -> float:
    """``float(text)``, NaN where it is not a number (no pandas on the metrics path)."""
    try:
        return float(text) if "_" not in text else float("nan")
    except ValueError:
        return float("nan")


# ----------------------------------------------------------------------- writing
def _fmt(values, decimals: int | None = None) -> list[str]:
    """Text of each float: with ``decimals`` fixed decimals when that reads back to the very
    same float, else the shortest text that does (Python repr)."""
    values = np.asarray(values, dtype=float).reshape(-1)
    if decimals is not None:
        text = [f"{v:.{decimals}f}" for v in values]
        if np.array_equal(np.array(text, dtype=float), values):
            return text
    return [repr(float(v)) for v in values]


def _fixed_decimals(columns: list[np.ndarray]) -> int | None:
    """The common number of decimals of fixed-point number text columns (str arrays), or None."""
    tok = np.concatenate([np.asarray(c, dtype=str) for c in columns])
    if tok.size == 0:
        return None
    dot = np.char.find(tok, ".")
    dec = np.char.str_len(tok) - dot - 1
    if np.any(dot < 1) or np.any(dec < 1) or dec.min() != dec.max():
        return None
    digits = np.char.isdigit(np.char.replace(np.char.lstrip(tok, "-"), ".", ""))
    return int(dec[0]) if digits.all() else None


#: SliceInfoFile styles :func:`write_study` can write: ours (one tab-separated line per
#: slice labelled ``sliceID:``) and the CAP / biv-me export's (``frameID:``, each slice listed
#: once per frame with its ``timeFrame``)
SLICE_INFO_STYLES = {"sliceID": {"label": "sliceID: ", "sep": "\t", "per_frame": False},
                     "frameID": {"label": "frameID:", "sep": "\t", "per_frame": True},
                     "frameID-spaces": {"label": "frameID:", "sep": " ", "per_frame": True}}
VOCABULARIES = ("parts", "undivided")


def write_study(study: Study, folder: str | Path, *, style: str | None = None,
                vocabulary: str = "parts") -> Path:
    """Write ``study`` as GPFile_NNN.txt (one per frame) + SliceInfoFile.txt into ``folder``.

    Slice geometry must be static (one plane per slice). Tag lines have no GPFile type and
    are not written. Files are written atomically.

    Parameters
    ----------
    study : Study
        The study (scanner mm).
    folder : str or Path
        The folder to write into (made if missing).
    style : str, optional
        The SliceInfoFile style (:data:`SLICE_INFO_STYLES`); default the style the study
        was read in (a study read from GPFiles), else ``sliceID``.
    vocabulary : str
        ``parts`` writes an ``rv_endo`` contour as RV_SEPTUM (points within 0.5 mm of the
        LV epicardium of the same image) and RV_FREEWALL (the rest), and the SA epicardial
        contours without their septal run, as CAP and biv-me exports do (LV_EPICARDIAL over
        the LV free wall, RV_EPICARDIAL over the RV free wall: :func:`_free_wall_epi`), so
        that a study written here and fitted by biv-me is compared on equal terms;
        ``undivided`` writes ``rv_endo`` as one RV_ENDOCARDIAL trace and the epicardia whole.

    Returns
    -------
    Path
        ``folder``.
    """
    _check_write_options(style, vocabulary)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    read_as = study.meta.get("gpfile")
    gp: dict = read_as if isinstance(read_as, dict) else {}
    slice_ids, slice_files, slice_tokens = _slice_numbering(study, gp)
    planes = _static_planes(study)
    atomic.write_text(folder / SLICE_INFO, _slice_info_text(study, gp, style, slice_ids,
                                                           slice_files, slice_tokens, planes))
    exact = (gp.get("n_contours") == len(study.contours)
             and gp.get("n_landmarks") == len(study.landmarks) and vocabulary == "parts")
    frame_meta = gp.get("frames", {}) if exact else {}
    texts = {}
    for frame in study.frames:
        fm = frame_meta.get(str(frame))
        name = (fm or {}).get("file") or f"GPFile_{frame:03d}.txt"
        texts[name if not gp.get("single_file") else frame] = _gp_file_text(
            study, frame, fm, gp, slice_ids, planes, vocabulary)
    if gp.get("single_file"):         # read from one GPFile.txt: written back as one file
        bodies = [t.split("\n", 1)[1] for t in texts.values()]
        head = gp.get("header") or HEADER
        atomic.write_text(folder / gp["single_file"], head + "\n" + "".join(bodies))
        return folder
    for name, text in texts.items():
        atomic.write_text(folder / str(name), text)
    return folder


def _check_write_options(style: str | None, vocabulary: str) -> None:
    """StudyError naming the option for an unknown SliceInfoFile style or vocabulary."""
    if style is not None and style not in SLICE_INFO_STYLES:
        raise StudyError(f"unknown SliceInfoFile style {style!r}; expected one of "
                         f"{', '.join(SLICE_INFO_STYLES)}", field="style")
    if vocabulary not in VOCABULARIES:
        raise StudyError(f"unknown vocabulary {vocabulary!r}; expected one of "
                         f"{', '.join(VOCABULARIES)}", field="vocabulary")


def _slice_info_format(gp: dict, style: str | None) -> tuple[dict, list | None]:
    """The SliceInfoFile format ({"label", "sep", "per_frame"}) and the row order read with
    the study (None: none kept) for ``style``, default the style the study was read in.

    Parameters
    ----------
    gp : dict
        ``study.meta["gpfile"]`` (empty for a study not read from GPFiles).
    style : str, optional
        A key of :data:`SLICE_INFO_STYLES`.

    Returns
    -------
    (dict, list or None)
    """
    if style is not None:
        return SLICE_INFO_STYLES[style], None
    si = gp.get("slice_info") or {}
    fmt = {"label": si.get("label", "sliceID: "), "sep": si.get("sep", "\t"),
           "per_frame": si.get("order") is not None}
    return fmt, si.get("order")


def _slice_geometry(slice_ids: dict, slice_tokens: dict, planes: dict) -> dict[int, list]:
    """GP slice number -> the tokens of its geometry: the tokens read with the study where
    they still give the slice's plane (to 1e-9), else the plane's numbers formatted anew.

    Parameters
    ----------
    slice_ids : dict
        Slice -> GP slice number (:func:`_slice_numbering`).
    slice_tokens : dict
        Slice -> the geometry tokens read with the study.
    planes : dict
        Slice -> its ImagePlane (:func:`_static_planes`).

    Returns
    -------
    dict
        Slice number -> [position..., "ImageOrientationPatient", orientation...,
        "PixelSpacing", spacing...] (str).
    """
    geometry = {}
    for sl, sid in slice_ids.items():
        im = planes[sl]
        tok = slice_tokens.get(sl)
        if tok is not None and _tokens_plane(tok, im).same_geometry(im, tol=1e-9):
            geometry[sid] = [*tok["position"], "ImageOrientationPatient", *tok["orientation"],
                             "PixelSpacing", *tok["pixel_spacing"]]
        else:
            geometry[sid] = [*_fmt(im.position), "ImageOrientationPatient", *_fmt(im.orientation),
                             "PixelSpacing", *_fmt(im.pixel_spacing)]
    return geometry


def _slice_info_text(study: Study, gp: dict, style: str | None, slice_ids: dict,
                     slice_files: dict, slice_tokens: dict, planes: dict) -> str:
    """The text of SliceInfoFile.txt: one line per slice (per slice and frame in the
    ``frameID`` styles), in the order the study was read in where that still fits.

    Parameters
    ----------
    study : Study
    gp : dict
        ``study.meta["gpfile"]`` (empty for a study not read from GPFiles).
    style : str, optional
        A key of :data:`SLICE_INFO_STYLES` (default: the style read).
    slice_ids, slice_files, slice_tokens : dict
        Slice -> GP slice number, DICOM file name, geometry tokens
        (:func:`_slice_numbering`).
    planes : dict
        Slice -> its ImagePlane (:func:`_static_planes`).

    Returns
    -------
    str
        The file's lines, each ending in a newline.
    """
    fmt, order = _slice_info_format(gp, style)
    geometry = _slice_geometry(slice_ids, slice_tokens, planes)
    name_of = {sid: slice_files.get(sl) or (Path(planes[sl].file).name if planes[sl].file
                                             else f"{sl}.dcm") for sl, sid in slice_ids.items()}
    known = set(slice_ids.values())
    if fmt["per_frame"]:
        if not order or {int(o[0]) for o in order} != known:
            order = [[sid, fr, f"{name_of[sid]}"] for fr in study.frames for sid in sorted(known)]
        rows = [(sid, t, name) for sid, t, name in order if int(sid) in known]
    else:
        rows = [(sid, None, name_of[sid]) for sid in sorted(known)]
    lines = []
    for sid, t, name in rows:
        time = [] if t is None else ["timeFrame", str(t)]
        lines.append(fmt["sep"].join([name, fmt["label"], str(sid), *time, "ImagePositionPatient",
                                      *geometry[int(sid)]]))
    return "\n".join(lines) + "\n"


def _gp_file_text(study: Study, frame: int, fm: dict | None, gp: dict, slice_ids: dict,
                  planes: dict, vocabulary: str) -> str:
    """The text of one frame's GPFile: the header, then one line per point (x, y, z, type,
    slice number, weight, time frame), with the weights and time tokens read with the study
    where its point count still matches.

    Parameters
    ----------
    study : Study
    frame : int
    fm : dict, optional
        The frame's file layout read with the study (``gp["frames"]``), None if not kept.
    gp : dict
        ``study.meta["gpfile"]`` (empty for a study not read from GPFiles).
    slice_ids : dict
        Slice -> GP slice number.
    planes : dict
        Slice -> its ImagePlane.
    vocabulary : str
        A member of :data:`VOCABULARIES`.

    Returns
    -------
    str
        The file's lines, each ending in a newline.
    """
    rows = _frame_rows(study, frame, fm, slice_ids, planes, vocabulary)
    n = sum(len(r[0]) for r in rows)
    weights = [w for r in rows for w in _fmt(r[3])]
    times = [str(frame)] * n
    if fm and sum(r[0] for r in fm["runs"]) == n:
        weights = [w for c, w, _ in fm["runs"] for _ in range(c)]
        times = [tt for c, _, tt in fm["runs"] for _ in range(c)]
    points = _expand(rows, gp.get("decimals"))
    perm = header_order(gp.get("header") or HEADER)
    order = range(7) if perm is None else [perm.index(i) for i in range(7)]
    body = ["\t".join(str(f[i]) for i in order)
            for f in ((*p, w, tt) for p, w, tt in zip(points, weights, times))]
    return "\n".join([gp.get("header") or HEADER, *body]) + "\n"


def _expand(rows, decimals):
    for pts, gp_type, sid, _ in rows:
        xs, ys, zs = (_fmt(pts[:, k], decimals) for k in range(3))
        for x, y, z in zip(xs, ys, zs):
            yield x, y, z, gp_type, sid


def _slice_numbering(study: Study, gp: dict):
    """GP slice number, DICOM file name and original tokens of every slice of the study."""
    ids, files, tokens = {}, {}, {}
    for s in gp.get("slices", []):
        ids[s["slice"]] = int(s["id"])
        files[s["slice"]] = s.get("file")
        tokens[s["slice"]] = s.get("tokens")
    present = sorted({im.slice for im in study.images}, key=lambda s: (not s.startswith("sa_"), s))
    ids = {s: i for s, i in ids.items() if s in present}
    for s in present:  # la_<n> keeps its number n (how the reader names LA slices)
        m = re.fullmatch(r"la_(\d+)", s)
        if s not in ids and m and int(m.group(1)) not in ids.values():
            ids[s] = int(m.group(1))
    nxt = 1
    for s in present:
        if s not in ids:
            while nxt in ids.values():
                nxt += 1
            ids[s] = nxt
    return ids, files, tokens


def _tokens_plane(tok: dict, like: ImagePlane) -> ImagePlane:
    ori = np.array([float(v) for v in tok["orientation"]])
    row, column = (float(v) for v in tok["pixel_spacing"])
    return ImagePlane(id="t", slice=like.slice, view=like.view, frame=0,
                      position=np.array([float(v) for v in tok["position"]]), row_cosine=ori[:3],
                      column_cosine=ori[3:], pixel_spacing=(row, column))


def _static_planes(study: Study) -> dict[str, ImagePlane]:
    planes: dict[str, ImagePlane] = {}
    for im in sorted(study.images, key=lambda im: im.frame):
        first = planes.setdefault(im.slice, im)
        if not first.same_geometry(im, tol=1e-6):
            raise StudyError("slice moves between frames; SliceInfoFile.txt holds one geometry "
                             "per slice", slice=im.slice, frame=im.frame)
    return planes


def _gp_type(structure: str, view: str) -> str:
    for gp_type, kind in (*SINGLE_VIEW_TYPES.items(), *OTHER_TYPES.items()):
        if kind == (structure, view):
            return gp_type
    return f"{'SAX' if view == 'SA' else 'LAX'}_{GP_OF_STRUCTURE[structure]}"


def _weights(c: Contour | None, n: int) -> np.ndarray:
    return np.ones(n) if c is None or c.weights is None else np.asarray(c.weights, float)


def _frame_rows(study: Study, frame: int, fm: dict | None, slice_ids: dict, planes: dict,
                vocabulary: str = "parts") -> list[tuple[np.ndarray, str, int, np.ndarray]]:
    """(points, GP type, slice number, weights) blocks of one frame, in file order."""
    out = []
    if fm:
        for b in fm["blocks"]:
            if b[0] == "c":
                c = study.contours[b[1]]
                out.append((c.points, b[2], slice_ids[c.slice], _weights(c, len(c.points))))
            else:
                lms = study.landmarks[b[1]:b[1] + b[2]]
                out.append((np.array([lm.point for lm in lms]), b[3], slice_ids[lms[0].slice],
                            np.ones(len(lms))))
        return out
    for c in study.contours_at(frame):
        if c.structure == "rv_endo" and vocabulary == "parts":
            out.extend(_split_rv_endo(study, c, slice_ids))
        elif c.structure in ("lv_epi", "rv_epi") and c.view == "SA" and vocabulary == "parts":
            out.extend(_free_wall_epi(study, c, slice_ids))
        else:
            out.append((c.points, _gp_type(c.structure, c.view), slice_ids[c.slice],
                        _weights(c, len(c.points))))
    for lm in study.landmarks_at(frame):
        sl = lm.slice if lm.slice in slice_ids else _nearest_slice(study, lm, planes)
        out.append((lm.point.reshape(1, 3), GP_OF_LANDMARK[lm.name], slice_ids[sl], np.ones(1)))
    return out


def _nearest_slice(study: Study, lm: Landmark, planes: dict) -> str:
    d = {s: abs(float(p.distance_to_plane(lm.point)[0])) for s, p in planes.items()}
    return min(d, key=d.__getitem__)


def _split_rv_endo(study: Study, c: Contour, slice_ids: dict):
    """RV_SEPTUM (on the LV epicardium) and RV_FREEWALL runs of one rv_endo contour."""
    sid = slice_ids[c.slice]
    w = _weights(c, len(c.points))
    epi = [e for e in study.contours_at(c.frame, "lv_epi") if e.slice == c.slice]
    kind = _gp_type("rv_freewall", c.view)
    if not epi:
        return [(c.points, kind, sid, w)]
    d = np.min([_distance_to_polyline(c.points, e.points, e.closed) for e in epi], axis=0)
    on = d < SEPTUM_TOL_MM
    if on.all() or not on.any():
        return [(c.points, kind if not on.all() else _gp_type("rv_septum", c.view), sid, w)]
    # rotate a closed loop so that it starts at a septum run's first point
    pts = c.points
    if c.closed:
        start = int(np.flatnonzero(on & ~np.roll(on, 1))[0])
        pts, on, w = np.roll(pts, -start, axis=0), np.roll(on, -start), np.roll(w, -start)
    cuts = np.flatnonzero(np.diff(on.astype(int))) + 1
    out = []
    for part_pts, part_on, part_w in zip(np.split(pts, cuts), np.split(on, cuts), np.split(w, cuts)):
        out.append((part_pts, _gp_type("rv_septum" if part_on[0] else "rv_freewall", c.view), sid,
                    part_w))
    return out


def _free_wall_epi(study: Study, c: Contour, slice_ids: dict):
    """An SA epicardial contour as CAP and biv-me trace it: over the free wall only. The
    septal run is left out — of the LV epicardium the points on the RV endocardium of the
    same image (within SEPTUM_TOL_MM), of the RV epicardium those on the LV epicardium —
    and the rest written as one open run starting after the gap (the reader closes it
    through the RV_SEPTUM trace, :func:`cardionurbs.anatomy.sections._sa_loops`)."""
    kind = _gp_type(c.structure, c.view)
    sid, w = slice_ids[c.slice], _weights(c, len(c.points))
    other = "rv_endo" if c.structure == "lv_epi" else "lv_epi"
    near = [o for o in study.contours_at(c.frame, other) if o.slice == c.slice]
    if not near or len(c.points) < 5:
        return [(c.points, kind, sid, w)]
    d = np.min([_distance_to_polyline(c.points, o.points, o.closed) for o in near], axis=0)
    on = d < max(SEPTUM_TOL_MM, 1e-3)
    if not on.any() or on.all():
        return [(c.points, kind, sid, w)]
    keep = ~on
    if c.closed:           # start at the first free-wall point after the septal run
        start = int(np.flatnonzero(keep & np.roll(on, 1))[0])
        order = np.roll(np.arange(len(keep)), -start)
        order = order[keep[order]]
    else:
        order = np.flatnonzero(keep)
    return [(c.points[order], kind, sid, w[order])]


def _distance_to_polyline(points: np.ndarray, poly: np.ndarray, closed: bool) -> np.ndarray:
    """(n,) distance of each point to the polyline (segments a_i -> a_{i+1}), mm."""
    a = poly if closed else poly[:-1]
    b = np.roll(poly, -1, axis=0) if closed else poly[1:]
    ab = b - a
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("nkj,kj->nk", ap, ab) / np.maximum(np.einsum("kj,kj->k", ab, ab), 1e-300),
                0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(axis=1)
