"""Model and mesh export: meshes through trimesh by file extension, the model as JSON.

Mesh formats: ``.stl``, ``.ply``, ``.obj``, ``.glb`` (trimesh's exporters,
chosen by extension, as trimesh does). The NURBS model is written as
``model.json`` (:meth:`BiventricularModel.to_dict`, lossless). All files are
written atomically (:mod:`cardionurbs.io.atomic`).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cardionurbs.errors import ExportError
from cardionurbs.io import atomic
from cardionurbs.nurbs import write_3dm

if TYPE_CHECKING:    # trimesh (~0.3 s to import) only where meshes are made
    import trimesh

MESH_FORMATS = ("stl", "ply", "obj", "glb")


def mesh_format(path: str | os.PathLike) -> str:
    """The mesh format of ``path`` from its extension (ExportError if unsupported).

    Parameters
    ----------
    path : str or os.PathLike
        A mesh file name.

    Returns
    -------
    str
        One of :data:`MESH_FORMATS` (``stl``, ``ply``, ``obj``, ``glb``).

    Raises
    ------
    ExportError
        Another extension.
    """
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in MESH_FORMATS:
        raise ExportError(f"{path}: unsupported mesh format {ext!r}; expected one of "
                          f"{', '.join(MESH_FORMATS)}")
    return ext


def export_mesh(mesh: trimesh.Trimesh, path: str | os.PathLike) -> Path:
    """Write one mesh (scanner mm) to ``path`` in the format its extension names.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        A triangle mesh, scanner mm; written in :func:`canonical_order` (the same bytes
        whatever the order it was built in).
    path : str or os.PathLike
        The file; its extension names the format (:func:`mesh_format`).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ExportError
        An unsupported extension.
    """
    fmt = mesh_format(path)
    import trimesh as _tm
    v, f = canonical_order(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    mesh = _tm.Trimesh(v, f, process=False)          # the same bytes whatever the build order
    data = mesh.export(file_type=fmt)
    if isinstance(data, str):
        data = data.encode("utf-8")
    assert isinstance(data, bytes)                  # every MESH_FORMATS format is one file
    return atomic.write_bytes(path, data)


def canonical_order(v, f):
    """The same mesh in one order whatever order it was built in (so the same surfaces give
    the same bytes, whatever ``--jobs`` or the boolean engine's threads did): vertices
    sorted by (x, y, z), each face rotated to start at its smallest vertex index (its
    orientation kept), faces sorted.

    Parameters
    ----------
    v : (n, 3) float array
        Vertices, mm.
    f : (m, 3) int array
        Triangles as vertex indices.

    Returns
    -------
    (v, f)
        Reordered copies."""
    v = np.asarray(v)
    order, f = canonical_permutation(v, f)
    return v[order], f


def canonical_permutation(v, f):
    """The vertex order and the renumbered, sorted faces of :func:`canonical_order`.

    Parameters
    ----------
    v : (n, 3) float array
        Vertices, mm.
    f : (m, 3) int array
        Triangles as vertex indices.

    Returns
    -------
    order : (n,) int64 array
        ``v[order]`` are the vertices in canonical order (point data permute the same way).
    f : (m, 3) int64 array
        The faces in canonical order, indexing ``v[order]``."""
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
    rank = np.empty(len(v), dtype=np.int64)
    rank[order] = np.arange(len(v))
    f = rank[f] if len(f) else f
    if len(f):
        k = f.argmin(axis=1)[:, None]
        f = np.take_along_axis(f, (k + np.arange(3)) % 3, axis=1)
        f = f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]
    return order, f


def write_ply(vertices, faces, path: str | os.PathLike) -> Path:
    """Write one triangle mesh as binary little-endian PLY (vertices as float32 x, y, z in
    mm, faces as a uchar count and three int32 indices: the layout trimesh's exporter
    writes), atomically.

    ``analyze`` writes every frame's meshes this way straight from the manifold3d arrays
    (:func:`cardionurbs.anatomy.mesh.mesh_arrays`): importing trimesh only to serialise
    them costs about 0.4 s and 20 MB per study, more than writing all of them.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Vertex coordinates, mm.
    faces : (F, 3) array_like of int
        Vertex indices of each triangle.
    path : str or os.PathLike
        The ``.ply`` file.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    v = np.asarray(vertices, dtype="<f4").reshape(-1, 3)
    f = np.asarray(faces).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ExportError(f"{path}: face indices outside the {len(v)} vertices")
    v, f = canonical_order(v, f)
    rec = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = f
    header = ("ply\nformat binary_little_endian 1.0\ncomment cardionurbs\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    return atomic.write_bytes(path, header.encode("ascii") + v.tobytes() + rec.tobytes())


def table_csv(columns: dict) -> str:
    """CSV text of a table given as equal-length columns (name -> sequence), as
    ``pandas.DataFrame(columns).to_csv(index=False)`` writes it, without pandas: a header
    line, ``\\n`` line ends, minimal quoting (the csv module's rules, pandas' too); text
    cells through :func:`cardionurbs.safe.csv_cell` (no spreadsheet formulas); floats in
    numpy's shortest round-trip form (``str``), NaN and None as empty cells; integers as
    they are.

    Parameters
    ----------
    columns : dict of str to sequence
        Column name -> its cells, all of one length.

    Returns
    -------
    str
        The CSV text.
    """
    import csv
    import io


    from cardionurbs.safe import csv_cell

    def cells(values) -> list:
        a = np.asarray(values)
        if a.dtype.kind == "f":
            text = a.astype(str).tolist()
            return ["" if v != v else t for v, t in zip(a.tolist(), text)]
        if a.dtype.kind in "iub":
            return a.tolist()
        return ["" if v is None or (isinstance(v, float) and v != v) else csv_cell(v)
                for v in a.tolist()]

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([str(c) for c in columns])
    w.writerows(zip(*(cells(v) for v in columns.values())))
    return buf.getvalue()


def _json_safe(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if hasattr(x, "item") and not isinstance(x, (str, bytes)):
        try:
            return _json_safe(x.item())
        except (ValueError, AttributeError):
            pass
    return x


def _plain(x):
    """``default`` hook of the fast path: numpy scalars and arrays as Python values."""
    if hasattr(x, "tolist"):
        return x.tolist()
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def write_json(obj, path: str | os.PathLike, indent: int | None = 1) -> Path:
    """Atomically write JSON (NaN and infinity become null).

    ``indent=None`` writes compact JSON through the C encoder (large files such as
    model.json: several times faster). Values without NaN or infinity are encoded as
    they are; otherwise every value goes through :func:`_json_safe` first.

    Parameters
    ----------
    obj : object
        JSON-serialisable data (numpy scalars and arrays included).
    path : str or os.PathLike
        The file to write.
    indent : int or None
        Indentation; None: compact.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    try:
        text = json.dumps(obj, indent=indent, allow_nan=False, default=_plain)
    except (ValueError, TypeError):
        text = json.dumps(_json_safe(obj), indent=indent, default=_plain)
    return atomic.write_text(path, text + "\n")


def export_model_3dm(model, path: str | os.PathLike, frame: int | None = None) -> Path:
    """Write one frame's NURBS surfaces (frame defaults to ED) as a Rhino .3dm file,
    atomically, through :func:`cardionurbs.nurbs.write_3dm` (needs the ``cad`` extra,
    rhino3dm). Objects are named ``<surface>_frame<N>``.

    Parameters
    ----------
    model : BiventricularModel
        The reconstructed model.
    path : str or os.PathLike
        The ``.3dm`` file.
    frame : int or None
        The frame; None: ED.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    frame = model.ed_frame if frame is None else frame
    surfaces = model.surfaces[frame]
    try:
        with atomic.atomic_path(path) as tmp:
            write_3dm(tmp, list(surfaces.values()),
                      names=[f"{name}_frame{frame}" for name in surfaces])
    except ImportError as exc:  # pragma: no cover - depends on the extra
        raise ExportError("writing .3dm needs rhino3dm: pip install 'cardionurbs[cad]'") from exc
    except OSError as exc:
        raise ExportError(f"{path}: {exc}") from exc
    return Path(path)
