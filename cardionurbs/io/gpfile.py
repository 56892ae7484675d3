"""CAP / biv-me guide-point files: ``GPFile_NNN.txt`` per frame + ``SliceInfoFile.txt``.

Read and written so that a study can go to biv-me and back.

``GPFile_NNN.txt`` (one per frame NNN = 0, 1, ...), tab separated, one header
line, then one guide point per line in scanner mm::

    x  y  z  contour type  frameID  weight  time frame

``frameID`` is the slice number of ``SliceInfoFile.txt`` (CAP naming),
``weight`` the fitting weight, ``time frame`` the frame number as the source
tool wrote it. Consecutive lines with the same (contour type, frameID) form
one contour, in drawing order.

``SliceInfoFile.txt``: one line per slice::

    <dicom file>  sliceID:  <n>  ImagePositionPatient  x y z
    ImageOrientationPatient  rx ry rz cx cy cz  PixelSpacing  dr dc

Mapping to the Study vocabulary (view from the ``SAX_``/``LAX_`` prefix):

==========================  =============  ==================================
GPFile type                  Study           closed
==========================  =============  ==================================
SAX_/LAX_LV_ENDOCARDIAL      ``lv_endo``     SA closed, LA open
SAX_/LAX_LV_EPICARDIAL       ``lv_epi``      SA closed, LA open
SAX_/LAX_RV_FREEWALL         ``rv_freewall`` open
SAX_/LAX_RV_SEPTUM           ``rv_septum``   open
SAX_/LAX_RV_EPICARDIAL       ``rv_epi``      open (closed=False)
MITRAL_VALVE                 landmark ``mitral``
TRICUSPID_VALVE              landmark ``tricuspid``
AORTA_VALVE                  landmark ``aortic``
PULMONARY_VALVE              landmark ``pulmonary``
APEX_POINT                   landmark ``apex``
RV_INSERT                    landmark ``rv_insert``
==========================  =============  ==================================

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
from pathlib import Path

import numpy as np
import pandas as pd

from cardionurbs.confine import files_inside, study_file
from cardionurbs.errors import StudyError
from cardionurbs.geometry import stack_normal
from cardionurbs.safe import excerpt
from cardionurbs.imaging import stack
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import atomic
from cardionurbs.study import Contour, Landmark, Study

SLICE_INFO = "SliceInfoFile.txt"
GP_FILE = re.compile(r"^GPFile_(\d+)\.txt$")
HEADER = "x\ty\tz\tcontour type\tframeID\tweight\ttime frame"
CONTOUR_TYPES = {"LV_ENDOCARDIAL": "lv_endo", "LV_EPICARDIAL": "lv_epi",
                 "RV_FREEWALL": "rv_freewall", "RV_SEPTUM": "rv_septum",
                 "RV_EPICARDIAL": "rv_epi"}
LANDMARK_TYPES = {"MITRAL_VALVE": "mitral", "TRICUSPID_VALVE": "tricuspid",
                  "AORTA_VALVE": "aortic", "PULMONARY_VALVE": "pulmonary",
                  "APEX_POINT": "apex", "RV_INSERT": "rv_insert"}
VIEW_PREFIX = {"SAX": "SA", "LAX": "LA"}
GP_OF_STRUCTURE = {v: k for k, v in CONTOUR_TYPES.items()}
GP_OF_LANDMARK = {v: k for k, v in LANDMARK_TYPES.items()}
DEFAULT_ROWS = DEFAULT_COLUMNS = 256
DEFAULT_THICKNESS_MM = 8.0
#: rv_endo points closer than this to the LV epicardium are written as RV_SEPTUM, mm.
SEPTUM_TOL_MM = 0.5


def detect(path: str | Path) -> bool:
    """True when ``path`` is a folder (or a file in one) with GPFile_*.txt and SliceInfoFile.txt."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    return (folder / SLICE_INFO).is_file() and any(GP_FILE.match(q.name) for q in folder.iterdir())


# ------------------------------------------------------------------ SliceInfoFile
def read_slice_info(path: str | Path) -> list[dict]:
    """Parse SliceInfoFile.txt: per line {file, id, position, orientation, pixel_spacing,
    and the same numbers as written (``tokens``)}; StudyError names the line and field."""
    path = Path(path)
    if not path.is_file():
        raise StudyError("SliceInfoFile.txt is missing", file=path)
    text = path.read_text(encoding="utf-8", errors="replace")
    out, ids = [], set()
    for k, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        tok = [t.strip() for t in line.split("\t")]
        tok = [t for t in tok if t != ""] if len(tok) > 1 else line.split()
        rec = {"file": tok[0], "line": k}
        for key, n in (("sliceID:", 1), ("ImagePositionPatient", 3),
                       ("ImageOrientationPatient", 6), ("PixelSpacing", 2)):
            if key not in tok:
                raise StudyError(f"line {k}: missing {key.rstrip(':')}", file=path,
                                 field=key.rstrip(":"))
            i = tok.index(key)
            vals = tok[i + 1:i + 1 + n]
            try:
                nums = [float(v) for v in vals]
            except ValueError:
                nums = []
            if len(nums) != n or not np.all(np.isfinite(nums)):
                raise StudyError(f"line {k}: {key.rstrip(':')} needs {n} finite number(s), got "
                                 f"{excerpt(' '.join(vals))}", file=path, field=key.rstrip(":"))
            rec[key] = (nums, vals)
        sid = rec["sliceID:"][0][0]
        if sid != int(sid):
            raise StudyError(f"line {k}: sliceID must be a whole number", file=path, field="sliceID")
        sid = int(sid)
        if sid in ids:
            raise StudyError(f"line {k}: sliceID {sid} appears twice", file=path, field="sliceID")
        ids.add(sid)
        out.append({"file": rec["file"], "id": sid,
                    "position": rec["ImagePositionPatient"][0],
                    "orientation": rec["ImageOrientationPatient"][0],
                    "pixel_spacing": rec["PixelSpacing"][0],
                    "tokens": {"position": rec["ImagePositionPatient"][1],
                               "orientation": rec["ImageOrientationPatient"][1],
                               "pixel_spacing": rec["PixelSpacing"][1]}})
    if not out:
        raise StudyError("SliceInfoFile.txt has no slices", file=path)
    return out


# ------------------------------------------------------------------------ GPFile
def read_gp_table(path: str | Path) -> tuple[pd.DataFrame, str, int | None]:
    """One GPFile as a table (x, y, z floats; type, slice id, weight and time tokens as text),
    its header line and the fixed number of decimals of its x y z text (None if not fixed).
    StudyError names the file and line of any bad value."""
    path = Path(path)
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
    table = _fast_table(text, start) if all(ln.strip() for ln in lines[start:]) else None
    if table is None:
        table = _slow_table(lines, start, path)
    decimals = _fixed_decimals(table[["x", "y", "z"]])
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
    return table, header, decimals


_COLUMNS = ["x", "y", "z", "type", "slice", "weight", "time"]


def _fast_table(text: str, start: int) -> pd.DataFrame | None:
    """Parse with pandas' C reader; None when some line has not exactly 7 fields."""
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
    files = sorted((int(m.group(1)), q) for q in folder.iterdir() if (m := GP_FILE.match(q.name)))
    frames = [f for f, _ in files]
    if len(set(frames)) != len(frames):
        dup = next(f for f in frames if frames.count(f) > 1)
        raise StudyError(f"two GPFiles for frame {dup}", file=folder)
    return files


def read_study(path: str | Path) -> Study:
    """Read a GPFile folder (GPFile_NNN.txt per frame + SliceInfoFile.txt) into a Study."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    files = _gp_files(folder)
    if not files:
        raise StudyError("no GPFile_NNN.txt files in this folder", file=folder)
    files_inside(folder, [folder / SLICE_INFO] + [f for _, f in files], what="GPFile")
    slices = read_slice_info(folder / SLICE_INFO)
    for s in slices:                           # names only (never opened), kept confined
        study_file(folder, s["file"], file=folder / SLICE_INFO, field="file")
    slice_by_id = {s["id"]: s for s in slices}
    tables = []
    header = None
    decimals = set()
    for frame, f in files:
        t, h, dec = read_gp_table(f)
        header = h if header is None else header
        decimals.add(dec)
        t["frame"] = frame
        t["file"] = f.name
        unknown = ~t["slice_id"].isin(list(slice_by_id))
        if unknown.any():
            i = int(np.flatnonzero(unknown.to_numpy())[0])
            raise StudyError(f"line {t['line'].iloc[i]}: reference to slice (frameID) "
                             f"{t['slice_id'].iloc[i]} that is not in {SLICE_INFO}", file=f,
                             field="frameID")
        tables.append(t)
    planes, names, views, rule = _slice_planes(slices, tables, folder)
    frames = [fr for fr, _ in files]
    images = [ImagePlane(id=f"{names[s['id']]}_f{fr:03d}", slice=names[s["id"]],
                         view=views[s["id"]], frame=fr, position=planes[s["id"]].position,
                         row_cosine=planes[s["id"]].row_cosine,
                         column_cosine=planes[s["id"]].column_cosine,
                         pixel_spacing=planes[s["id"]].pixel_spacing, rows=DEFAULT_ROWS,
                         columns=DEFAULT_COLUMNS, thickness=DEFAULT_THICKNESS_MM)
              for s in slices for fr in frames]  # DICOM names: meta only (files are absent)
    contours: list[Contour] = []
    landmarks: list[Landmark] = []
    frame_meta = {}
    for (frame, f), t in zip(files, tables):
        blocks, runs = _read_blocks(t, frame, f, names, views, contours, landmarks)
        frame_meta[str(frame)] = {"file": f.name, "blocks": blocks, "runs": runs}
    meta = {"format": "gpfile", "base_apex_rule": rule,
            "gpfile": {"header": header, "frames": frame_meta,
                       "decimals": decimals.pop() if len(decimals) == 1 else None,
                       "slices": [{"slice": names[s["id"]], "id": s["id"], "file": s["file"],
                                   "tokens": s["tokens"]} for s in slices],
                       "n_contours": len(contours), "n_landmarks": len(landmarks),
                       "defaults": "rows, columns (256) and thickness (8 mm) are not in "
                                   "SliceInfoFile.txt"}}
    return Study(subject=folder.name, images=images, contours=contours, landmarks=landmarks,
                 source=str(folder), meta=meta)


def _slice_planes(slices: list[dict], tables: list[pd.DataFrame], folder: Path):
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
    all_rows = pd.concat(tables, ignore_index=True)
    apex = all_rows.loc[all_rows["type"] == "APEX_POINT", ["x", "y", "z"]].to_numpy(float)
    mitral = all_rows.loc[all_rows["type"] == "MITRAL_VALVE", ["x", "y", "z"]].to_numpy(float)
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
    counts = pd.Series(list(la_names.values()), dtype=object).value_counts()
    for i, name in la_names.items():
        names[i], views[i] = (name if counts[name] == 1 else f"la_{i}"), "LA"
    return planes, names, views, rule


_LA_VIEW = re.compile(r"(?<![0-9a-z])([234])\s*-?\s*ch(?![a-z])", re.IGNORECASE)


def _read_blocks(t: pd.DataFrame, frame: int, f: Path, names: dict, views: dict,
                 contours: list, landmarks: list):
    """Contours and landmarks of one frame's table, in file order; the block order and the
    (weight, time frame) runs for write-back."""
    types = t["type"].to_numpy()
    sids = t["slice_id"].to_numpy()
    xyz = t[["x", "y", "z"]].to_numpy(float)
    lines = t["line"].to_numpy()
    key = np.array([f"{a}\x1f{b}" for a, b in zip(types, sids)]) if len(t) else np.array([])
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(t) else np.array([], int)
    ends = np.r_[starts[1:], len(t)].astype(int)
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
        prefix, _, base = gp_type.partition("_")
        if prefix not in VIEW_PREFIX or base not in CONTOUR_TYPES:
            raise StudyError(f"line {lines[s]}: unknown contour type {excerpt(gp_type)}; expected "
                             f"SAX_/LAX_ + {', '.join(CONTOUR_TYPES)} or a landmark "
                             f"({', '.join(LANDMARK_TYPES)})", file=f, field="contour type")
        if VIEW_PREFIX[prefix] != view:
            raise StudyError(f"line {lines[s]}: {gp_type} on slice {sid} ({slice_id}), which is a "
                             f"{'short' if view == 'SA' else 'long'}-axis slice by its orientation",
                             file=f, field="contour type")
        structure = CONTOUR_TYPES[base]
        closed = view == "SA" and structure in ("lv_endo", "lv_epi")
        k = piece.get((structure, slice_id), 0)
        piece[(structure, slice_id)] = k + 1
        blocks.append(["c", len(contours), gp_type])
        try:
            contours.append(Contour(structure, view, slice_id, frame, xyz[s:e], image=image,
                                    closed=closed, index=k))
        except StudyError as exc:
            raise StudyError(f"line {lines[s]}: {exc}", file=f) from None
    wt = t["weight"].to_numpy()
    tm = t["time"].to_numpy()
    runs = []
    for w, tt in zip(wt, tm):
        if runs and runs[-1][1] == w and runs[-1][2] == tt:
            runs[-1][0] += 1
        else:
            runs.append([1, str(w), str(tt)])
    return blocks, runs


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


def _fixed_decimals(columns: pd.DataFrame) -> int | None:
    """The common number of decimals of fixed-point number text columns, or None."""
    tok = np.concatenate([columns[c].to_numpy(str) for c in columns.columns])
    if tok.size == 0:
        return None
    dot = np.char.find(tok, ".")
    dec = np.char.str_len(tok) - dot - 1
    if np.any(dot < 1) or np.any(dec < 1) or dec.min() != dec.max():
        return None
    digits = np.char.isdigit(np.char.replace(np.char.lstrip(tok, "-"), ".", ""))
    return int(dec[0]) if digits.all() else None


def write_study(study: Study, folder: str | Path) -> Path:
    """Write ``study`` as GPFile_NNN.txt (one per frame) + SliceInfoFile.txt into ``folder``.

    Slice geometry must be static (one plane per slice). ``rv_endo`` contours
    (no GPFile type) are split into RV_SEPTUM (points within 0.5 mm of the LV
    epicardium of the same image) and RV_FREEWALL (the rest). Tag lines have
    no GPFile type and are not written. Files are written atomically.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    gp = study.meta.get("gpfile") if isinstance(study.meta.get("gpfile"), dict) else {}
    slice_ids, slice_files, slice_tokens = _slice_numbering(study, gp)
    planes = _static_planes(study)
    lines = []
    for sl, sid in sorted(slice_ids.items(), key=lambda kv: kv[1]):
        im = planes[sl]
        tok = slice_tokens.get(sl)
        if tok is not None and _tokens_plane(tok, im).same_geometry(im, tol=1e-9):
            pos, ori, sp = tok["position"], tok["orientation"], tok["pixel_spacing"]
        else:
            pos, ori, sp = _fmt(im.position), _fmt(im.orientation), _fmt(im.pixel_spacing)
        name = slice_files.get(sl) or (Path(im.file).name if im.file else f"{sl}.dcm")
        lines.append("\t".join([name, "sliceID: ", str(sid), "ImagePositionPatient", *pos,
                                "ImageOrientationPatient", *ori, "PixelSpacing", *sp]))
    atomic.write_text(folder / SLICE_INFO, "\n".join(lines) + "\n")
    exact = (gp.get("n_contours") == len(study.contours)
             and gp.get("n_landmarks") == len(study.landmarks))
    frame_meta = gp.get("frames", {}) if exact else {}
    header = gp.get("header") or HEADER
    for frame in study.frames:
        fm = frame_meta.get(str(frame))
        rows = _frame_rows(study, frame, fm, slice_ids, planes)
        n = sum(len(r[0]) for r in rows)
        weights, times = ["1.0"] * n, [str(frame)] * n
        if fm and sum(r[0] for r in fm["runs"]) == n:
            weights = [w for c, w, _ in fm["runs"] for _ in range(c)]
            times = [tt for c, _, tt in fm["runs"] for _ in range(c)]
        points = _expand(rows, gp.get("decimals"))
        body = [f"{x}\t{y}\t{z}\t{ty}\t{sid}\t{w}\t{tt}"
                for (x, y, z, ty, sid), w, tt in zip(points, weights, times)]
        name = (fm or {}).get("file") or f"GPFile_{frame:03d}.txt"
        atomic.write_text(folder / name, "\n".join([header, *body]) + "\n")
    return folder


def _expand(rows, decimals):
    for pts, gp_type, sid in rows:
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
    return ImagePlane(id="t", slice=like.slice, view=like.view, frame=0,
                      position=[float(v) for v in tok["position"]], row_cosine=ori[:3],
                      column_cosine=ori[3:], pixel_spacing=[float(v) for v in tok["pixel_spacing"]])


def _static_planes(study: Study) -> dict[str, ImagePlane]:
    planes: dict[str, ImagePlane] = {}
    for im in sorted(study.images, key=lambda im: im.frame):
        first = planes.setdefault(im.slice, im)
        if not first.same_geometry(im, tol=1e-6):
            raise StudyError("slice moves between frames; SliceInfoFile.txt holds one geometry "
                             "per slice", slice=im.slice, frame=im.frame)
    return planes


def _gp_type(structure: str, view: str) -> str:
    return f"{'SAX' if view == 'SA' else 'LAX'}_{GP_OF_STRUCTURE[structure]}"


def _frame_rows(study: Study, frame: int, fm: dict | None, slice_ids: dict,
                planes: dict) -> list[tuple[np.ndarray, str, int]]:
    """(points, GP type, slice number) blocks of one frame, in file order."""
    out = []
    if fm:
        for b in fm["blocks"]:
            if b[0] == "c":
                c = study.contours[b[1]]
                out.append((c.points, b[2], slice_ids[c.slice]))
            else:
                lms = study.landmarks[b[1]:b[1] + b[2]]
                out.append((np.array([lm.point for lm in lms]), b[3], slice_ids[lms[0].slice]))
        return out
    for c in study.contours_at(frame):
        if c.structure == "rv_endo":
            out.extend(_split_rv_endo(study, c, slice_ids))
        else:
            out.append((c.points, _gp_type(c.structure, c.view), slice_ids[c.slice]))
    for lm in study.landmarks_at(frame):
        sl = lm.slice if lm.slice in slice_ids else _nearest_slice(study, lm, planes)
        out.append((lm.point.reshape(1, 3), GP_OF_LANDMARK[lm.name], slice_ids[sl]))
    return out


def _nearest_slice(study: Study, lm: Landmark, planes: dict) -> str:
    d = {s: abs(float(p.distance_to_plane(lm.point)[0])) for s, p in planes.items()}
    return min(d, key=d.get)


def _split_rv_endo(study: Study, c: Contour, slice_ids: dict):
    """RV_SEPTUM (on the LV epicardium) and RV_FREEWALL runs of one rv_endo contour."""
    sid = slice_ids[c.slice]
    epi = [e for e in study.contours_at(c.frame, "lv_epi") if e.slice == c.slice]
    kind = _gp_type("rv_freewall", c.view)
    if not epi:
        return [(c.points, kind, sid)]
    d = np.min([_distance_to_polyline(c.points, e.points, e.closed) for e in epi], axis=0)
    on = d < SEPTUM_TOL_MM
    if on.all() or not on.any():
        return [(c.points, kind if not on.all() else _gp_type("rv_septum", c.view), sid)]
    # rotate a closed loop so that it starts at a septum run's first point
    pts = c.points
    if c.closed:
        start = int(np.flatnonzero(on & ~np.roll(on, 1))[0])
        pts, on = np.roll(pts, -start, axis=0), np.roll(on, -start)
    cuts = np.flatnonzero(np.diff(on.astype(int))) + 1
    out = []
    for part_pts, part_on in zip(np.split(pts, cuts), np.split(on, cuts)):
        out.append((part_pts, _gp_type("rv_septum" if part_on[0] else "rv_freewall", c.view), sid))
    return out


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
