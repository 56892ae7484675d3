"""`cardionurbs report OUTPUT_DIR --out report.html`: one self-contained, offline HTML viewer.

The file embeds everything it needs (no network fetches, no sibling files):

* plotly.js, inline (``plotly.offline.get_plotlyjs``), drawing WebGL ``mesh3d``
  traces;
* the model's surfaces per frame, re-tessellated from ``model.json`` (NURBS,
  :data:`SURFACE_GRID`), coordinates quantised to 0.1 mm as little-endian
  int16 relative to the model's centre and base64-encoded (2 bytes per
  coordinate; faces as uint16, shared between frames when identical);
* tag surfaces per tagged frame with their QC flags (``figures/report_tags.json``
  written by :func:`cardionurbs.report.figures.write_figures`), the flagged tag
  lines, and a table of the flags;
* the metrics table (``metrics.json``) beside the truth (``truth.json`` in
  OUTPUT_DIR, else beside the study source named in ``figures/figures.json``);
* the volume–time curve and the static PNG figures (base64 data URIs).

Controls: one checkbox per structure / tag group (toggles its trace), a frame
slider and a play button cycling through the frames.

Size: a 20-frame study with tags stays well under 10 MB (plotly.js is ~4.8 MB
of it).
"""

from __future__ import annotations

import argparse
import base64
import html
import json
import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from cardionurbs import nurbs
from cardionurbs.anatomy.model import BiventricularModel
from cardionurbs.errors import ReportInputError
from cardionurbs.heap import acyclic
from cardionurbs.io import atomic
from cardionurbs.report.figures import view_frame
from cardionurbs.safe import json_for_script

__all__ = ["write_report", "run_report", "report_payload", "ReportInputError", "SURFACE_GRID"]

SURFACE_GRID = (36, 14)        # (nu, nv) per wall surface in the viewer
QUANTUM_MM = 0.1               # coordinate quantisation
STRUCTURE_COLOURS = {"lv_endo": "#D55E00", "lv_epi": "#E69F00", "rv_endo": "#0072B2",
                     "rv_epi": "#56B4E9"}
STRUCTURE_OPACITY = {"lv_endo": 1.0, "lv_epi": 0.35, "rv_endo": 1.0, "rv_epi": 0.35}
FAMILY_COLOURS = {"sa1": "#009E73", "sa2": "#CC79A7", "la": "#F0E442"}
FLAG_COLOUR = "#D55E00"
NAMES = {"lv_endo": "LV endocardium", "lv_epi": "LV epicardium", "rv_endo": "RV endocardium",
         "rv_epi": "RV epicardium", "sa1": "tags SA family 1", "sa2": "tags SA family 2",
         "la": "tags LA family", "flagged": "tag surfaces with QC flags"}


# ----------------------------------------------------------------- encoding
def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode("ascii")


def quantise(vertices: np.ndarray, origin: np.ndarray, quantum: float = QUANTUM_MM) -> str:
    """base64 of little-endian int16 ``round((v − origin) / quantum)`` (±3.2 m at 0.1 mm).

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Vertex positions, in mm (scanner coordinates).
    origin : ndarray, shape (3,)
        The model centre the offsets are taken from, in mm.
    quantum : float, optional
        The step of the integer grid, in mm (default :data:`QUANTUM_MM`, 0.1 mm).

    Returns
    -------
    str
        base64 text of the (n, 3) int16 offsets, little-endian, row-major.

    Raises
    ------
    cardionurbs.errors.ReportInputError
        A vertex lies farther than 32767 quanta from ``origin``.
    """
    q = np.rint((np.asarray(vertices, float) - origin) / quantum)
    if q.size and np.abs(q).max() > 32767:
        raise ReportInputError(f"coordinates farther than {32767 * quantum:.0f} mm from the "
                               "model centre cannot be quantised")
    return _b64(q.astype("<i2"))


def _faces_b64(faces: np.ndarray) -> str:
    """``"u2:<base64>"`` (uint16 indices) or ``"u4:<base64>"`` when a mesh is larger."""
    f = np.asarray(faces)
    if f.size == 0 or f.max() < 65536:
        return "u2:" + _b64(f.astype("<u2"))
    return "u4:" + _b64(f.astype("<u4"))


class _FacePool:
    """Shared face arrays: identical faces (e.g. one structure's grid at every frame) are
    stored once and referenced by index."""

    def __init__(self) -> None:
        self.items: list[str] = []
        self._index: dict[str, int] = {}

    def add(self, faces: np.ndarray) -> int:
        key = _faces_b64(faces)
        if key not in self._index:
            self._index[key] = len(self.items)
            self.items.append(key)
        return self._index[key]


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate meshes into one (vertices, faces) with offset face indices."""
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(np.asarray(v, float))
        faces.append(np.asarray(f, np.int64) + off)
        off += len(v)
    return np.concatenate(verts), np.concatenate(faces)


# ----------------------------------------------------------------- inputs
def _local_path(path: str | None, out: Path) -> str | None:
    """A path as the report shows it: relative to the analysis folder when inside it, else
    its last two components (never an absolute local path)."""
    if not path:
        return path
    p = Path(path)
    try:
        return p.resolve().relative_to(Path(out).resolve()).as_posix()
    except ValueError:
        return Path(*p.parts[-2:]).as_posix()


def _strip_local(text: str, source) -> str:
    """A warning without the absolute study folder: the folder's name instead."""
    if source:
        text = str(text).replace(str(Path(source)), Path(source).name)
    return str(text)



def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except RecursionError:
        raise ReportInputError(f"{path}: JSON nested too deeply to be an analysis file") from None
    except (OSError, ValueError) as exc:
        raise ReportInputError(f"{path}: not readable JSON ({' '.join(str(exc).split())})") from None


def _find_truth(out: Path, fig_index: Mapping | None) -> tuple[Mapping | None, str | None]:
    cands = [out / "truth.json"]
    src = (fig_index or {}).get("source")
    if src:
        p = Path(src)
        cands.append((p if p.is_dir() else p.parent) / "truth.json")
    for c in cands:
        if c.is_file():
            try:
                return json.loads(c.read_text()), str(c)
            except (OSError, ValueError):
                continue
    return None, None


def _load_analysis(out: Path, model: BiventricularModel | None = None):
    """(model, metrics.json, figures folder, figures.json or None) of an analyze folder;
    ReportInputError naming the file when something is missing or unreadable. ``model``:
    the model ``model.json`` was written from (``analyze`` writing its own report), used
    instead of reading that file back."""
    if not out.is_dir():
        raise ReportInputError(f"{out}: not a folder (expected the output of cardionurbs analyze)")
    for need in ("model.json", "metrics.json"):
        if not (out / need).is_file():
            raise ReportInputError(f"{out / need}: missing (expected the output of cardionurbs "
                                   "analyze)")
    try:
        if model is None:
            model = BiventricularModel.from_dict(_read_json(out / "model.json"))
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise ReportInputError(f"{out / 'model.json'}: not a cardionurbs model "
                               f"({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    fig_dir = out / "figures"
    fig_index = _read_json(fig_dir / "figures.json") if (fig_dir / "figures.json").is_file() else None
    metrics = _read_json(out / "metrics.json")
    if not isinstance(metrics, dict):
        raise ReportInputError(f"{out / 'metrics.json'}: not an analysis's metrics (a JSON "
                               f"object is expected, got {type(metrics).__name__})")
    return model, metrics, fig_dir, fig_index


def _surface_groups(model, frames: list[int], pool: "_FacePool"):
    """Viewer groups of the model's surfaces (tessellated per frame), the tessellations,
    and the quantisation origin (centre of all their vertices, 0.1 mm)."""
    structures = [s for s in ("lv_endo", "lv_epi", "rv_endo", "rv_epi")
                  if any(s in model.surfaces[f] for f in frames)]
    tess = {f: {s: nurbs.tessellate(model.surfaces[f][s], *SURFACE_GRID)
                for s in structures if s in model.surfaces[f]} for f in frames}
    allv = np.concatenate([v for d in tess.values() for v, _ in d.values()])
    origin = np.round((allv.min(axis=0) + allv.max(axis=0)) / 2, 1)
    groups = []
    for s in structures:
        per = {str(f): {"v": quantise(tess[f][s][0], origin), "f": pool.add(tess[f][s][1])}
               for f in frames if s in tess[f]}
        groups.append({"key": s, "name": NAMES[s], "colour": STRUCTURE_COLOURS[s],
                       "opacity": STRUCTURE_OPACITY[s], "kind": "mesh", "frames": per})
    return groups, tess, origin


def _flagged_lines(surfs: list[dict], origin: np.ndarray) -> str | None:
    """The flagged tag lines of one frame, quantised, separated by a NaN row (sentinel
    -32768), base64; None when there are none."""
    pts = [np.asarray(p, float) for d in surfs for p in d.get("flagged_lines", [])]
    if not pts:
        return None
    seq = np.concatenate([np.vstack([p, np.full((1, 3), np.nan)]) for p in pts])
    q = np.rint((seq - origin) / QUANTUM_MM)
    q[~np.isfinite(q)] = -32768
    return _b64(q.astype("<i2"))


def _tag_groups(fig_dir: Path, fig_index: dict | None, origin: np.ndarray, pool: "_FacePool",
                tag_data: Mapping | None = None):
    """(viewer groups of the tag surfaces per family and of the flagged lines, QC flags,
    note saying why there are none or None) from ``figures/report_tags.json`` (``tag_data``:
    its content, when the caller has just written it)."""
    tag_path = fig_dir / "report_tags.json"
    if tag_data is None and not tag_path.is_file():
        skipped = (fig_index or {}).get("skipped", {})
        note = (skipped.get("fig09_all_tag_surfaces") or "no tag surfaces in this analysis"
                if fig_index else "no figures/report_tags.json: tag surfaces not available")
        return [], [], note
    td = _read_json(tag_path) if tag_data is None else tag_data
    fams = ("sa1", "sa2", "la", "flagged")
    per_fam: dict[str, dict] = {k: {} for k in fams}
    lines: dict[str, str] = {}
    for f, surfs in td.get("frames", {}).items():
        parts: dict[str, list] = {k: [] for k in fams}
        for d in surfs:
            key = "flagged" if d.get("flagged") else d["family"]
            parts[key].append((np.asarray(d["vertices"], float), np.asarray(d["faces"])))
        for k in fams:
            if parts[k]:
                v, fc = _merge(parts[k])
                per_fam[k][f] = {"v": quantise(v, origin), "f": pool.add(fc)}
        encoded = _flagged_lines(surfs, origin)
        if encoded is not None:
            lines[f] = encoded
    groups = [{"key": f"tags_{k}", "name": NAMES[k],
               "colour": FLAG_COLOUR if k == "flagged" else FAMILY_COLOURS[k],
               "opacity": 0.9 if k == "flagged" else 0.6, "kind": "mesh", "frames": per_fam[k]}
              for k in fams if per_fam[k]]
    if lines:
        groups.append({"key": "flagged_lines", "name": "tag lines flagged as mistracked",
                       "colour": FLAG_COLOUR, "opacity": 1.0, "kind": "lines", "frames": lines})
    return groups, td.get("flags", []), None


def _metric_rows(metrics: dict, truth: Mapping | None) -> list[dict]:
    """One row per measured metric with the phantom truth and the difference beside it, its
    reference range and flag (metrics.json ``ranges``), why it is null (``notes``), its
    quality flags and the surfaces they concern."""
    tmet = (truth or {}).get("metrics", {})
    quality = (metrics.get("quality") or {}).get("metrics", {})
    notes = metrics.get("notes") or {}
    ranges = (metrics.get("ranges") or {}).get("flags", {})
    unc = metrics.get("uncertainty") or {}       # the 95 % intervals (docs/metrics.md, Uncertainty)
    rows = []
    for k, v in metrics.get("metrics", {}).items():
        t = tmet.get(k) if truth else None
        diff = (v - t) if isinstance(v, (int, float)) and isinstance(t, (int, float)) else None
        flags = list((quality.get(k) or {}).get("flags", []))
        rng = ranges.get(k) or {}
        rows.append({"metric": k, "measured": _num(v), "truth": _num(t), "difference": _num(diff),
                     "qc": "; ".join(flags), "qc_surfaces": sorted({_flag_surface(f) for f in flags}),
                     "note": notes.get(k) if _num(v) is None else None,
                     "range": ([rng.get("lower"), rng.get("upper")]
                               if rng.get("lower") is not None or rng.get("upper") is not None
                               else None),
                     "range_flag": rng.get("flag"), "range_table": rng.get("where"),
                     "range_reason": (rng.get("reason") or None) if _num(v) is not None else None,
                     "halfwidth": (_num(0.5 * (unc[k][1] - unc[k][0]))
                                   if isinstance(unc.get(k), list) else None)})
    return rows


#: the report's metric groups: (title, test of a column name), in page order; a column
#: goes to the first group whose test it passes
GROUPS = (
    ("LV function", lambda c: c in ("HR (bpm)", "LVEDV (mL)", "LVESV (mL)", "LVSV (mL)", "LVEF (%)",
                                    "LVCO (L/min)", "LVM (g)", "EI ES")),
    ("RV function", lambda c: c.startswith(("RVEDV (", "RVESV (", "RVSV (", "RVEF (", "RVM (",
                                            "MR ", "RV/LV"))),
    ("Body size and indexed values", lambda c: c.endswith("/m²)") or c in (
        "Height (cm)", "Weight (kg)", "Age (y)", "BSA (m²)")),
    ("Tags", lambda c: c in ("Twist (deg)", "Twist 2D (deg)", "Torsion (deg/cm)",
                             "CL shear (deg)", "LS (%)", "Tag QC flags")),
    ("Voxel counting", lambda c: " voxel " in c),
    ("Regional", lambda c: True),
)


def group_rows(rows: list[dict]) -> list[tuple[str, list[dict]]]:
    """The metric rows by :data:`GROUPS` (empty groups left out), in page order.

    Parameters
    ----------
    rows : list of dict
        The metric rows of the report (each with ``metric``: a docs/metrics.md column).

    Returns
    -------
    list of tuple of (str, list of dict)
        (group title, its rows in input order) for every non-empty group.
    """
    out: dict[str, list[dict]] = {t: [] for t, _ in GROUPS}
    for r in rows:
        out[next(t for t, test in GROUPS if test(r["metric"]))].append(r)
    return [(t, rs) for t, rs in out.items() if rs]


def _flag_surface(flag: str) -> str:
    """The surface or input a quality flag is about (``RV epi fit max ...`` -> ``RV epi``)."""
    for label in ("LV endo", "LV epi", "RV endo", "RV epi"):
        if flag.startswith(label):
            return label
    return flag.split(":")[0].split(" fit")[0][:40]


def quality_lines(rows: list[dict]) -> list[dict]:
    """One line per surface (or input) with a quality flag: its distinct evidence and the
    metrics it flags (the report shows each as one expandable line).

    Parameters
    ----------
    rows : list of dict
        The metric rows (``metric`` and ``qc``: ``"; "``-separated quality flags).

    Returns
    -------
    list of dict
        ``{"surface", "evidence": [flag, ...], "metrics": [column, ...]}`` per flagged surface
        or input, in order of first appearance.
    """
    by: dict[str, dict] = {}
    for r in rows:
        for f in filter(None, (r.get("qc") or "").split("; ")):
            e = by.setdefault(_flag_surface(f), {"evidence": [], "metrics": []})
            if f not in e["evidence"]:
                e["evidence"].append(f)
            if r["metric"] not in e["metrics"]:
                e["metrics"].append(r["metric"])
    return [{"surface": k, **v} for k, v in by.items()]


def _figure_images(fig_dir: Path, fig_index: dict | None) -> list[dict]:
    """The PNG figures (under 2 MB each) as data URIs, with name and caption."""
    figures = []
    for item in (fig_index or {}).get("figures", []):
        p = fig_dir / item["file"]
        if p.is_file() and p.stat().st_size < 2_000_000:
            figures.append({"name": item["name"], "caption": item["caption"],
                            "src": "data:image/png;base64," + _b64(np.frombuffer(p.read_bytes(),
                                                                                   np.uint8))})
    return figures


def _camera(model, tess: dict) -> dict:
    """Initial viewer camera: looking along the long axis, the RV to one side."""
    ed = int(model.ed_frame)
    side = None
    if {"lv_endo", "rv_endo"} <= set(tess[ed]):
        side = tess[ed]["rv_endo"][0].mean(axis=0) - tess[ed]["lv_endo"][0].mean(axis=0)
    eye, up = view_frame(model.long_axis(), side)
    return {"eye": (2.1 * eye).tolist(), "up": up.tolist()}


def report_payload(output_dir: str | Path, *, model: BiventricularModel | None = None,
                   tag_data: Mapping | None = None) -> dict:
    """The data embedded in the report (JSON-safe), from an ``analyze`` output folder:
    the surfaces and tag surfaces per frame, the metrics beside the truth, the figures.

    ``model`` and ``tag_data``: the model that ``model.json`` was written from and the
    content of ``figures/report_tags.json``, when the caller (``analyze``) has them in
    memory: the same report without reading those files back (the model's surfaces
    survive the JSON round trip exactly, so the page is the same).

    Parameters
    ----------
    output_dir : path-like
        An ``analyze`` output folder (``metrics.json``, ``model.json``, ``figures/``).
    model : cardionurbs.anatomy.model.BiventricularModel, optional
        The model ``model.json`` was written from (not read back when given).
    tag_data : mapping, optional
        The content of ``figures/report_tags.json`` (not read back when given).

    Returns
    -------
    dict
        JSON-safe: subject, frames and ED/ES (0-based), frame times (ms), origin (mm) and
        quantum (mm) of the quantised surfaces, camera, faces, surface groups, metric rows
        (with truth, ranges, QC, notes), warnings, body, figures.

    Raises
    ------
    cardionurbs.errors.ReportInputError
        The folder is not an analysis output (a file missing or unreadable, named).
    """
    out = Path(output_dir)
    model, metrics, fig_dir, fig_index = _load_analysis(out, model)
    truth, truth_path = _find_truth(out, fig_index)
    frames = sorted(int(f) for f in model.frames)
    pool = _FacePool()
    groups, tess, origin = _surface_groups(model, frames, pool)
    tag_groups, flags, tags_note = _tag_groups(fig_dir, fig_index, origin, pool, tag_data)
    return {
        "subject": str(metrics.get("subject", model.study.subject)),
        "frames": frames, "ed_frame": int(model.ed_frame), "es_frame": int(model.es_frame),
        "frame_times_ms": (metrics.get("volume_curve") or {}).get("time_ms"),
        "origin": origin.tolist(), "quantum_mm": QUANTUM_MM,
        "camera": _camera(model, tess),
        "faces": pool.items, "groups": groups + tag_groups,
        "metrics": _metric_rows(metrics, truth), "truth_file": _local_path(truth_path, out),
        "has_truth": truth is not None,
        "flags": flags, "tags_note": tags_note,
        "volume_curve": metrics.get("volume_curve"),
        "warnings": [_strip_local(f"{w['source']}: {w['message']}" if isinstance(w, dict) else w,
                                  model.study.source or (fig_index or {}).get("source"))
                     for w in list(metrics.get("warnings", []))[:50]],
        "n_warnings": len(metrics.get("warnings", [])),
        "citation": (metrics.get("ranges") or {}).get("citation"),
        "body": metrics.get("body") or {},
        "skipped": (fig_index or {}).get("skipped", {}), "figures": _figure_images(fig_dir, fig_index),
    }


def _num(x: Any) -> Any:
    if isinstance(x, bool) or x is None:
        return x
    if isinstance(x, (int, float)):
        return None if not math.isfinite(float(x)) else float(x)
    return x


# ----------------------------------------------------------------- page
_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0;color:#222}
header{padding:10px 18px;background:#f4f4f4;border-bottom:1px solid #ddd}
h1{font-size:20px;margin:0} h2{font-size:16px;margin:18px 0 6px}
main{display:flex;flex-wrap:wrap;gap:14px;padding:10px 18px}
#viewer{flex:1 1 600px;min-width:480px} #side{flex:0 1 600px}
#plot{width:100%;height:620px;border:1px solid #ddd}
.controls{display:flex;flex-wrap:wrap;gap:8px 16px;margin:6px 0;font-size:13px;align-items:center}
.sw{display:inline-block;width:12px;height:12px;margin-right:4px;border:1px solid #888;vertical-align:middle}
table{border-collapse:collapse;font-size:12.5px} td,th{border-bottom:1px solid #e3e3e3;padding:2px 8px;text-align:right}
td:first-child,th:first-child{text-align:left} .bad{color:#D55E00;font-weight:600}
.gallery figure{margin:10px 0} .gallery img{max-width:100%;border:1px solid #eee}
figcaption{font-size:12px;color:#444} #frameLabel{min-width:150px;display:inline-block}
.note{font-size:12.5px;color:#555} #volplot{width:100%;height:260px}
.qc{font-size:11.5px;color:#a33} .qcflag{color:#c22}
tr.group th{text-align:left;background:#eef2f6;font-size:13px;padding-top:6px}
.why{font-size:11px;color:#777} #metrics td:first-child,#regional td:first-child{white-space:nowrap} details{margin:4px 0;font-size:12.5px} summary{cursor:pointer}
"""

_JS = r"""
(function(){
const D = JSON.parse(document.getElementById('cn-data').textContent);
const status = document.getElementById('cn-status');
function dec16(b64){const s=atob(b64);const u=new Uint8Array(s.length);for(let i=0;i<s.length;i++)u[i]=s.charCodeAt(i);return new Int16Array(u.buffer);}
function decFaces(tagged){const s=atob(tagged.slice(3));const u=new Uint8Array(s.length);for(let i=0;i<s.length;i++)u[i]=s.charCodeAt(i);
  return tagged.slice(0,2)==='u2' ? new Uint16Array(u.buffer) : new Uint32Array(u.buffer);}
const Q = D.quantum_mm, O = D.origin;
const faceCache = {};
function faces(idx){ if(!(idx in faceCache)){ const f = decFaces(D.faces[idx]); const n=f.length/3;
  const I=new Array(n),J=new Array(n),K=new Array(n); for(let t=0;t<n;t++){I[t]=f[3*t];J[t]=f[3*t+1];K[t]=f[3*t+2];}
  faceCache[idx]={i:I,j:J,k:K}; } return faceCache[idx]; }
function coords(b64){ const q=dec16(b64); const n=q.length/3; const x=new Array(n),y=new Array(n),z=new Array(n);
  for(let p=0;p<n;p++){ const a=q[3*p],b=q[3*p+1],c=q[3*p+2];
    if(a===-32768){x[p]=null;y[p]=null;z[p]=null;} else {x[p]=O[0]+a*Q;y[p]=O[1]+b*Q;z[p]=O[2]+c*Q;} }
  return {x:x,y:y,z:z}; }
function traceData(g, f){
  const e = g.frames[String(f)];
  if(g.kind==='lines'){ if(!e) return {x:[],y:[],z:[]}; return coords(e); }
  if(!e) return {x:[],y:[],z:[],i:[],j:[],k:[]};
  const c = coords(e.v), fc = faces(e.f); return {x:c.x,y:c.y,z:c.z,i:fc.i,j:fc.j,k:fc.k};
}
const frames = D.frames; let cur = frames.indexOf(D.ed_frame); if(cur<0) cur=0;
const traces = D.groups.map(function(g){
  const d = traceData(g, frames[cur]);
  if(g.kind==='lines') return Object.assign({type:'scatter3d',mode:'lines',name:g.name,
      line:{color:g.colour,width:7},hoverinfo:'name'}, d);
  return Object.assign({type:'mesh3d',name:g.name,color:g.colour,opacity:g.opacity,flatshading:false,
      lighting:{ambient:0.55,diffuse:0.7,specular:0.1},hoverinfo:'name'}, d);
});
const w = D.camera.eye, u = D.camera.up;
// one legend: the colour swatches of the toggles above the plot (no plotly legend beside it)
const layout = {margin:{l:0,r:0,t:0,b:0}, showlegend:false,
  scene:{aspectmode:'data', camera:{eye:{x:w[0],y:w[1],z:w[2]}, up:{x:u[0],y:u[1],z:u[2]}},
    xaxis:{title:{text:'x (mm, →L)'}}, yaxis:{title:{text:'y (mm, →P)'}}, zaxis:{title:{text:'z (mm, →H)'}}}};
const gd = document.getElementById('plot');
const shown = D.groups.map(function(){return true;});
function label(f){ let s='frame '+f; if(f===D.ed_frame) s+=' (ED)'; else if(f===D.es_frame) s+=' (ES)';
  const t=D.frame_times_ms; const k=frames.indexOf(f); if(t && t[k]!=null) s+=', '+Math.round(t[k])+' ms'; return s; }
function show(k){
  cur = k; const f = frames[k];
  const upd = {x:[],y:[],z:[],i:[],j:[],k:[]}; const idx=[];
  D.groups.forEach(function(g,n){ const d=traceData(g,f); idx.push(n);
    upd.x.push(d.x); upd.y.push(d.y); upd.z.push(d.z);
    upd.i.push(d.i||null); upd.j.push(d.j||null); upd.k.push(d.k||null); });
  Plotly.restyle(gd, upd, idx);
  document.getElementById('frameLabel').textContent = label(f);
  document.getElementById('slider').value = k;
}
Plotly.newPlot(gd, traces, layout, {displaylogo:false, responsive:true}).then(function(){
  status.textContent = 'rendered ' + traces.length + ' traces, ' + frames.length + ' frames';
  status.setAttribute('data-ok','1');
});
const boxes = document.getElementById('toggles');
D.groups.forEach(function(g,n){
  const l=document.createElement('label'); const c=document.createElement('input'); c.type='checkbox'; c.checked=true;
  c.id='toggle-'+g.key; c.addEventListener('change',function(){ shown[n]=c.checked; Plotly.restyle(gd,{visible:c.checked},[n]); });
  const sw=document.createElement('span'); sw.className='sw'; sw.style.background=g.colour;
  l.appendChild(c); l.appendChild(sw); l.appendChild(document.createTextNode(g.name)); boxes.appendChild(l); });
const slider = document.getElementById('slider'); slider.max = frames.length-1; slider.value=cur;
slider.addEventListener('input', function(){ show(parseInt(slider.value,10)); });
document.getElementById('frameLabel').textContent = label(frames[cur]);
let timer=null; const play=document.getElementById('play');
play.disabled = frames.length < 2;
play.addEventListener('click', function(){
  if(timer){clearInterval(timer); timer=null; play.textContent='▶ play'; return;}
  play.textContent='❚❚ pause'; timer=setInterval(function(){ show((cur+1)%frames.length); }, 180); });
if(D.volume_curve && D.volume_curve.frame && D.volume_curve.frame.length>2){
  const vc=D.volume_curve; const haveT = vc.time_ms && vc.time_ms.every(function(t){return t!=null;});
  const xs = haveT ? vc.time_ms : vc.frame; const tr=[];
  [['lv_cavity (mL)','LV cavity','#D55E00'],['rv_cavity (mL)','RV cavity','#0072B2']].forEach(function(s){
    if(vc[s[0]] && vc[s[0]].some(function(v){return v!=null && !isNaN(v);}))
      tr.push({x:xs,y:vc[s[0]],name:s[1],mode:'lines+markers',line:{color:s[2]}}); });
  if(tr.length) Plotly.newPlot('volplot', tr, {margin:{l:50,r:10,t:10,b:40},
    xaxis:{title:{text: haveT?'time (ms)':'frame'}}, yaxis:{title:{text:'volume (mL)'}}, legend:{orientation:'h',x:0,y:1.12}},
    {displaylogo:false, responsive:true, staticPlot:false});
  else document.getElementById('volplot').style.display='none';
} else { const v=document.getElementById('volplot'); v.style.height='auto'; v.className='note';
  v.textContent='Fewer than 3 reconstructed frames: no volume–time curve.'; }
})();
"""


def _departure(flag: dict) -> str:
    """A flag's departure in spacings, or its reason when it has none (low tracking confidence)."""
    d = flag.get("departure_spacings")
    return f"{d:.2f}" if isinstance(d, (int, float)) else html.escape(str(flag.get("reason", "")))


def _fmt(x: Any) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        return f"{x:.2f}" if abs(x) < 1000 else f"{x:.0f}"
    return html.escape(str(x))


def _range_cell(r: Mapping) -> str:
    if not r.get("range"):
        why = html.escape(r.get("range_reason") or "")
        short = "–" if why == "not in the reference source" else why   # the common case, short
        return "<td></td><td>" + (f"<span class='why' title='{why}'>{short}</span>" if why else "") + "</td>"
    lo, hi = r["range"]
    text = f"{'' if lo is None else f'{lo:.4g}'}–{'' if hi is None else f'{hi:.4g}'}"
    f = r.get("range_flag")
    cls = "" if f in (None, "normal") else " class='bad'"
    return (f"<td title='{html.escape(str(r.get('range_table') or ''))}'>{text}</td>"
            f"<td{cls}>{html.escape(f or '')}</td>")


def _row_html(r: Mapping, has_truth: bool) -> str:
    esc = html.escape
    measured = _fmt(r["measured"])
    if r.get("halfwidth") is not None:
        measured += f" <span class='pm' title='95 % interval'>± {_fmt(r['halfwidth'])}</span>"
    if r.get("note"):
        measured += f" <span class='why'>{esc(r['note'])}</span>"
    if r.get("qc"):
        measured += (f" <span class='qcflag' title='{esc(r['qc'])}'>&#9873;</span>")
    return (f"<tr><td>{esc(r['metric'])}</td><td>{measured}</td>" + _range_cell(r)
            + (f"<td>{_fmt(r['truth'])}</td><td>{_fmt(r['difference'])}</td>" if has_truth else "")
            + f"<td class='qc'>{esc(', '.join(r.get('qc_surfaces') or []))}</td></tr>")


def _metric_tables(p: Mapping) -> tuple[str, dict[str, str]]:
    """(header row, {"main": the grouped rows of the metrics table, "regional": the
    regional table, collapsed})."""
    has_truth = p["has_truth"]
    cols = ["metric", "measured", "normal range", "flag"] + (
        ["truth", "measured − truth"] if has_truth else []) + ["QC"]
    head = "<tr>" + "".join(f"<th>{c}</th>" for c in cols) + "</tr>"
    main, regional = [], ""
    for title, rows in group_rows(p["metrics"]):
        body = "".join(_row_html(r, has_truth) for r in rows)
        if title == "Regional":
            n = sum(r["measured"] is not None for r in rows)
            regional = (f"<details id='regional'><summary>Regional ({n} of {len(rows)} columns "
                        f"measured)</summary><table>{head}{body}</table></details>")
        else:
            main.append(f"<tr class='group'><th colspan='{len(cols)}'>{title}</th></tr>{body}")
    return head, {"main": "".join(main), "regional": regional}


def _quality_html(rows: list[dict]) -> str:
    """One expandable line per surface with a quality flag: the evidence and the metrics."""
    esc = html.escape
    lines = quality_lines(rows)
    if not lines:
        return "<p class='note'>No quality flag: every fit residual within the limit.</p>"
    out = []
    for q in lines:
        shown = ", ".join(q["metrics"][:4]) + (f" and {len(q['metrics']) - 4} more"
                                               if len(q["metrics"]) > 4 else "")
        out.append(f"<details class='qcline'><summary><b>{esc(q['surface'])}</b>: "
                   f"{len(q['evidence'])} finding(s), flags {esc(shown)}</summary><ul class='note'>"
                   + "".join(f"<li>{esc(e)}</li>" for e in q["evidence"]) + "</ul></details>")
    return "".join(out)


def _body_note(p: Mapping) -> str:
    b = p.get("body") or {}
    parts = [f"{k} {b[f]:g}{u}" for k, f, u in (("height", "height_cm", " cm"),
                                                 ("weight", "weight_kg", " kg"),
                                                 ("age", "age_y", " y"))
             if isinstance(b.get(f), (int, float))]
    if b.get("sex"):
        parts.append(f"sex {b['sex']}")
    return html.escape("Body: " + (", ".join(parts) if parts else "unknown (no BSA, no indexed "
                                   "values; give --height-cm and --weight-kg)") + ".")


def page_parts(payload: Mapping) -> list[str]:
    """The report page for a :func:`report_payload` as consecutive pieces (their
    concatenation is the page): written one after another, the page (plotly.js,
    the data, the figures: several MB) is never held whole as text and again as bytes.

    Parameters
    ----------
    payload : mapping
        A :func:`report_payload` dict.

    Returns
    -------
    list of str
        The page's pieces, in order (HTML, plotly.js, the JSON data, the figures).
    """
    from plotly.offline import get_plotlyjs

    esc = html.escape
    p = payload
    has_truth = p["has_truth"]
    head, groups = _metric_tables(p)
    truth_note = (f"Truth: {esc(p['truth_file'])}" if has_truth
                  else "No truth.json found: measured values only.")
    if p["flags"]:
        flag_rows = "".join(
            f"<tr><td>{esc(str(f['family']))} #{f['index']}</td><td>{esc(str(f['slice']))}</td>"
            f"<td>{f['frame']}</td><td class='bad'>{_departure(f)}</td></tr>"
            for f in p["flags"])
        n_fr = len({f["frame"] for f in p["flags"]})
        flags_html = (f"<p class='note'>{len(p['flags'])} tag line(s) flagged by the "
                      f"leave-one-out tag-jump QC over the tagged frames (in {n_fr} frame(s)); "
                      "shown in vermillion in the viewer.</p>"
                      "<table id='flags'><tr><th>tag</th><th>slice/view</th><th>frame</th>"
                      "<th>departure (spacings)</th></tr>" + flag_rows + "</table>")
    elif p["tags_note"]:
        flags_html = f"<p class='note'>{esc(p['tags_note'])}</p>"
    else:
        flags_html = "<p class='note'>Tag QC: no tag line flagged as mistracked.</p>"
    skipped = "".join(f"<li>{esc(k)}: {esc(v)}</li>" for k, v in p["skipped"].items())
    first, rest = p["warnings"][:5], p["warnings"][5:]
    warns = "".join(f"<li>{esc(w)}</li>" for w in first)
    if rest:
        warns += (f"<li><details><summary>{len(rest)} more</summary><ul>"
                  + "".join(f"<li>{esc(w)}</li>" for w in rest) + "</ul></details></li>")
    if p.get("n_warnings", 0) > len(p["warnings"]):
        warns += f"<li>… {p['n_warnings'] - len(p['warnings'])} more in metrics.json</li>"
    quality = _quality_html(p["metrics"])
    gallery = "".join(f"<figure><img alt='{esc(f['name'])}' src='{f['src']}'>"
                      f"<figcaption>{esc(f['caption'])}</figcaption></figure>" for f in p["figures"])
    data = json_for_script({k: v for k, v in p.items() if k not in ("figures",)},
                           separators=(",", ":"))
    return [f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; script-src 'unsafe-inline' 'unsafe-eval'; style-src 'unsafe-inline'; img-src data: blob:; font-src data:; connect-src 'none'; worker-src blob:">
<title>cardionurbs report: {esc(p['subject'])}</title><style>{_CSS}</style></head>
<body><header><h1>cardionurbs report: {esc(p['subject'])}</h1>
<div class="note">Biventricular NURBS model, scanner (LPS) mm; ED frame {p['ed_frame']},
ES frame {p['es_frame']}; {len(p['frames'])} reconstructed frame(s).
<span id="cn-status">loading…</span></div></header>
<main><section id="viewer">
<div class="controls" id="toggles"></div>
<div class="controls"><button id="play">▶ play</button>
<input type="range" id="slider" min="0" max="0" step="1" style="width:320px">
<span id="frameLabel"></span></div>
<div id="plot"></div>
<h2>Volume–time curve</h2><div id="volplot"></div>
</section>
<section id="side"><h2>Metrics</h2><p class="note">{truth_note} {_body_note(p)}</p>
<table id="metrics">{head}{groups["main"]}</table>
{groups["regional"]}
<h2>Quality</h2>{quality}
<h2>Tag QC flags</h2>{flags_html}
{"<h2>Figures left out</h2><ul class='note'>" + skipped + "</ul>" if skipped else ""}
{"<h2>Warnings (" + str(p.get("n_warnings", 0)) + ")</h2><ul class='note'>" + warns + "</ul>" if warns else ""}
{"<p class='note'>Normal ranges: " + esc(p["citation"]) + "</p>" if p.get("citation") else ""}
</section></main>
{"<section class='gallery' style='padding:0 18px'><h2>Figures</h2>" + gallery + "</section>" if gallery else ""}
<script type="application/json" id="cn-data">""", data, """</script>
<script>""", get_plotlyjs(), f"""</script>
<script>{_JS}</script>
</body></html>
"""]


def write_report(output_dir: str | Path, out_path: str | Path, *,
                 model: BiventricularModel | None = None, tag_data: Mapping | None = None) -> Path:
    """Write the self-contained HTML report of an ``analyze`` output folder; return its path.
    ``model``, ``tag_data``: see :func:`report_payload`.

    Raises :class:`ReportInputError` (one line, naming the file) when the folder is not an
    analysis output.

    Parameters
    ----------
    output_dir : path-like
        An ``analyze`` output folder.
    out_path : path-like
        The HTML file to write (replaced atomically).
    model : cardionurbs.anatomy.model.BiventricularModel, optional
        The model already in memory (see :func:`report_payload`).
    tag_data : mapping, optional
        The report tag surfaces already in memory.

    Returns
    -------
    pathlib.Path
        ``out_path``.
    """
    with acyclic():                  # plain lists, dicts and strings (cardionurbs.heap)
        parts = page_parts(report_payload(output_dir, model=model, tag_data=tag_data))
        with atomic.atomic_path(out_path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            for i in range(len(parts)):          # each piece let go once written
                fh.write(parts[i])
                parts[i] = ""
    return Path(out_path)


def run_report(args: argparse.Namespace) -> int:
    """CLI: ``cardionurbs report OUTPUT_DIR --out report.html``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line: ``output_dir`` and ``out``.

    Returns
    -------
    int
        The exit code, 0.

    Raises
    ------
    cardionurbs.errors.OutputError
        ``--out`` may not be written (an input of the report, or a file cardionurbs did not
        write).
    cardionurbs.errors.ReportInputError
        ``output_dir`` is not an analysis output.
    """
    from cardionurbs.io.outputs import check_output_file
    src = Path(args.output_dir)
    check_output_file(args.out, inputs=[src / n for n in ("metrics.json", "model.json", "figures",
                                                           "meshes", "residuals.csv")])
    path = write_report(args.output_dir, args.out)
    size = Path(path).stat().st_size / 1e6
    print(f"wrote {path} ({size:.1f} MB)")
    return 0
