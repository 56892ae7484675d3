"""VTK files for ParaView: triangle meshes with point data (``.vtp``) and time series (``.pvd``).

A ``.vtp`` file is VTK's XML PolyData, written by VTK itself
(``vtkXMLPolyDataWriter``, the ``vtk`` wheel: ``pip install "cardionurbs[vtk]"``), with
its arrays zlib-compressed and base64-encoded inline, so the file is plain XML text.
Point-data arrays are named as in docs/formats.md (``wall thickness (mm)``,
``AHA segment``, ``Err (%)`` ...); the frame's time is in the field data ``TimeValue``
(ms, the array ParaView reads for one file) and, for colouring, in the point data
``time (ms)``. A ``.pvd`` file is ParaView's collection of such files, one
``<DataSet timestep=...>`` per frame, so ParaView's time slider plays the cycle with
the study's real frame times.

Every file is written atomically (:mod:`cardionurbs.io.atomic`) and is the same byte
for byte for the same input (no dates, no paths, arrays in a fixed order).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence
from xml.sax.saxutils import quoteattr

import numpy as np

from cardionurbs.errors import ExportError
from cardionurbs.io import atomic
from cardionurbs.io.export import canonical_permutation

__all__ = ["write_vtp", "write_pvd", "require_vtk", "VTK_MISSING"]

VTK_MISSING = "writing .vtp needs VTK: pip install 'cardionurbs[vtk]' (the vtk wheel)"


def _vtk():
    """The VTK modules the writer needs (ExportError naming the extra when VTK is absent)."""
    try:
        from vtkmodules.util import numpy_support
        from vtkmodules.vtkCommonCore import vtkPoints
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
        from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter
    except ImportError as exc:
        raise ExportError(VTK_MISSING) from exc
    return numpy_support, vtkPoints, vtkCellArray, vtkPolyData, vtkXMLPolyDataWriter


def require_vtk() -> None:
    """Raise :class:`~cardionurbs.errors.ExportError` (naming the extra) unless VTK imports:
    checked before an analysis that will write ``.vtp`` starts."""
    _vtk()


def canonical_order(vertices: np.ndarray, faces: np.ndarray,
                    point_data: Mapping[str, np.ndarray] | None = None):
    """The same mesh in an order that depends on its geometry alone: vertices sorted by
    (x, y, z), each triangle rotated to start at its smallest index (orientation kept),
    triangles sorted; the point data permuted with the vertices. (The booleans of
    manifold3d may list the same faces in another order from run to run.)

    Parameters
    ----------
    vertices : (V, 3) array
    faces : (F, 3) array of int
    point_data : mapping name -> (V,) array, optional

    Returns
    -------
    tuple
        (vertices (V, 3), faces (F, 3), point data dict).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    order, f = canonical_permutation(v, faces)
    data = {k: np.asarray(a)[order] for k, a in (point_data or {}).items()}
    return v[order], f, data


def polydata(vertices: np.ndarray, faces: np.ndarray,
             point_data: Mapping[str, np.ndarray] | None = None,
             time_ms: float | None = None):
    """A ``vtkPolyData`` of one triangle mesh with point-data arrays and its time.

    Parameters
    ----------
    vertices : (V, 3) array of float
        Vertex positions, scanner mm (stored as float64).
    faces : (F, 3) array of int
        Triangles, indices into ``vertices``.
    point_data : mapping name -> (V,) array, optional
        Per-vertex scalars; integer arrays stay integer (int32), the others float64
        (NaN where a value is unknown).
    time_ms : float, optional
        The frame time, stored as the field data ``TimeValue``.

    Returns
    -------
    vtkPolyData
    """
    ns, vtkPoints, vtkCellArray, vtkPolyData, _ = _vtk()
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ExportError(f"face indices outside the {len(v)} vertices")
    pts = vtkPoints()
    pts.SetData(ns.numpy_to_vtk(v, deep=True))
    cells = vtkCellArray()
    offsets = np.arange(0, 3 * len(f) + 1, 3, dtype=np.int64)
    cells.SetData(ns.numpy_to_vtkIdTypeArray(offsets, deep=True),
                  ns.numpy_to_vtkIdTypeArray(f.ravel().copy(), deep=True))
    poly = vtkPolyData()
    poly.SetPoints(pts)
    poly.SetPolys(cells)
    for name, values in (point_data or {}).items():
        a = np.asarray(values)
        if a.shape[0] != len(v):
            raise ExportError(f"point data {name!r}: {a.shape[0]} values for {len(v)} vertices")
        a = np.ascontiguousarray(a, dtype=np.int32 if a.dtype.kind in "iub" else np.float64)
        arr = ns.numpy_to_vtk(a, deep=True)
        arr.SetName(str(name))
        poly.GetPointData().AddArray(arr)
    if time_ms is not None:
        t = ns.numpy_to_vtk(np.array([float(time_ms)]), deep=True)
        t.SetName("TimeValue")
        poly.GetFieldData().AddArray(t)
    return poly


def write_vtp(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
              point_data: Mapping[str, np.ndarray] | None = None,
              time_ms: float | None = None) -> Path:
    """Write one triangle mesh with point data as VTK XML PolyData (``.vtp``), atomically.

    Parameters
    ----------
    path : path-like
        The ``.vtp`` file to write.
    vertices, faces, point_data, time_ms
        As for :func:`polydata`; the mesh is written in :func:`canonical_order` (the
        same mesh gives the same bytes).

    Returns
    -------
    Path
        ``path``.
    """
    *_, vtkXMLPolyDataWriter = _vtk()
    writer = vtkXMLPolyDataWriter()
    f = np.asarray(faces).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(np.asarray(vertices).reshape(-1, 3))):
        raise ExportError(f"{path}: face indices outside the vertices")
    v, f, data = canonical_order(vertices, f, point_data)
    writer.SetInputData(polydata(v, f, data, time_ms))
    writer.SetDataModeToBinary()                 # base64 inline: the file is XML text
    writer.SetCompressorTypeToZLib()
    writer.SetWriteToOutputString(True)
    if not writer.Write():
        raise ExportError(f"{path}: VTK could not write the PolyData")
    return atomic.write_text(path, writer.GetOutputString())


def write_pvd(path: str | os.PathLike, datasets: Sequence[tuple[float, str]]) -> Path:
    """Write a ParaView collection (``.pvd``) of ``(time, file)`` pairs, atomically.

    Parameters
    ----------
    path : path-like
        The ``.pvd`` file to write.
    datasets : sequence of (float, str)
        Each frame's time (ms) and its file, relative to the ``.pvd``'s folder; written in
        increasing time.

    Returns
    -------
    Path
        ``path``.
    """
    rows = [f'    <DataSet timestep="{float(t)!r}" part="0" file={quoteattr(str(name))}/>'
            for t, name in sorted(datasets, key=lambda d: (float(d[0]), str(d[1])))]
    text = ('<?xml version="1.0"?>\n'
            '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
            '  <Collection>\n' + "".join(r + "\n" for r in rows) +
            '  </Collection>\n</VTKFile>\n')
    return atomic.write_text(path, text)
