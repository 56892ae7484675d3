"""Export to Rhino ``.3dm`` files through rhino3dm (the ``cad`` extra).

openNURBS stores control points homogeneously, ``(w x, w y, w z, w)``, and
knot vectors without the two superfluous end knots (``n + p - 1`` knots).
Closed (periodic) curves and surfaces are written in their equivalent clamped
form (:meth:`NurbsCurve.to_clamped`, :meth:`NurbsSurface.to_clamped`), which
Rhino reads as closed geometry with the same shape.

The same geometries give the same bytes (:func:`write_3dm`, docs/safety.md): object and
layer ids are name-based UUIDs (RFC 4122 version 5) of the names and numbers written,
no revision history (creation and edit times) is stamped, and the file is encoded in
memory, so no file name is stored in it.
"""

from __future__ import annotations

import base64
import hashlib
import os
import uuid
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.surface import NurbsSurface

__all__ = ["to_rhino", "write_3dm"]

#: the namespace of the name-based ids of the objects and the layer a .3dm file holds
ID_NAMESPACE = uuid.uuid5(uuid.NAMESPACE_URL, "cardionurbs:3dm")


def _rhino3dm() -> Any:
    try:
        import rhino3dm
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError("rhino3dm is needed for .3dm export: pip install 'cardionurbs[cad]'") from None
    return rhino3dm


def _xyz(points: np.ndarray) -> np.ndarray:
    """Control points as 3-d (2-d ones get z = 0)."""
    if points.shape[-1] == 3:
        return points
    if points.shape[-1] == 2:
        return np.concatenate([points, np.zeros(points.shape[:-1] + (1,))], axis=-1)
    raise NurbsInputError(f"geometry: .3dm export needs 2-d or 3-d control points, got "
                          f"{points.shape[-1]}-d")


def to_rhino(geometry: NurbsCurve | NurbsSurface) -> Any:
    """A ``rhino3dm.NurbsCurve`` or ``rhino3dm.NurbsSurface`` of the same shape.

    Needs the ``cad`` extra (rhino3dm, imported here).

    Parameters
    ----------
    geometry : NurbsCurve or NurbsSurface
        2-D or 3-D control points (2-D ones get z = 0).

    Returns
    -------
    rhino3dm.NurbsCurve or rhino3dm.NurbsSurface
    """
    r = _rhino3dm()
    if isinstance(geometry, NurbsCurve):
        c = geometry.to_clamped()
        P, w = _xyz(c.control_points), c.weights
        rc = r.NurbsCurve(3, bool(c.is_rational), c.degree + 1, c.n_control)
        for i, (x, y, z) in enumerate(P):
            rc.Points[i] = r.Point4d(w[i] * x, w[i] * y, w[i] * z, w[i])
        for i, k in enumerate(c.knots[1:-1]):
            rc.Knots[i] = float(k)
        return rc
    if isinstance(geometry, NurbsSurface):
        s = geometry.to_clamped()
        P, w = _xyz(s.control_points), s.weights
        nu, nv = w.shape
        rational = bool(np.ptp(w) > 1e-12 * w.max())
        rs = r.NurbsSurface.Create(3, rational, s.degree_u + 1, s.degree_v + 1, nu, nv)
        for i in range(nu):
            for j in range(nv):
                x, y, z = P[i, j]
                rs.Points[i, j] = r.Point4d(w[i, j] * x, w[i, j] * y, w[i, j] * z, w[i, j])
        for i, k in enumerate(s.knots_u[1:-1]):
            rs.KnotsU[i] = float(k)
        for i, k in enumerate(s.knots_v[1:-1]):
            rs.KnotsV[i] = float(k)
        return rs
    raise NurbsInputError(f"geometry: expected a NurbsCurve or NurbsSurface, got {type(geometry).__name__}")


def geometry_id(geometry: NurbsCurve | NurbsSurface, name: str | None) -> uuid.UUID:
    """The object id of ``geometry`` in a .3dm file: a version-5 UUID of its name and
    the bytes of its degrees, knots, control points and weights (the same geometry
    and name, the same id; another, another id).

    Parameters
    ----------
    geometry : NurbsCurve or NurbsSurface
    name : str or None
        The object's name.

    Returns
    -------
    uuid.UUID
    """
    h = hashlib.sha256(f"{type(geometry).__name__}\0{name or ''}".encode())
    if isinstance(geometry, NurbsCurve):
        parts = [[geometry.degree], geometry.knots]
    else:
        parts = [[geometry.degree_u, geometry.degree_v], geometry.knots_u, geometry.knots_v]
    for a in (*parts, geometry.control_points, geometry.weights):
        h.update(np.ascontiguousarray(a, "<f8").tobytes())
    return uuid.uuid5(ID_NAMESPACE, h.hexdigest())


def write_3dm(path: str | os.PathLike, geometries: Iterable[NurbsCurve | NurbsSurface],
              names: Iterable[str] | None = None, version: int = 7) -> Path:
    """Write curves and surfaces to a ``.3dm`` file, the same bytes for the same input.

    A plain write (this package knows no file policy): callers that must never
    leave a half-written file write to a temporary path and rename it
    (:func:`cardionurbs.io.export.export_model_3dm` does).

    Reproducible bytes: each object's id is :func:`geometry_id`, the one layer's id
    a version-5 UUID of those ids; the model's revision count is set so that openNURBS
    stamps no revision history (``ONX_Model::Write`` adds one with the current time
    when the count is 0); the file is encoded in memory (``File3dm.Encode``), where
    openNURBS records no file name (``File3dm.Write`` records the path written).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    geometries : iterable of NurbsCurve or NurbsSurface
    names : iterable of str, optional
        One object name per geometry.
    version : int, default 7
        The 3dm file version.

    Returns
    -------
    Path
        ``path``.
    """
    r = _rhino3dm()
    model = r.File3dm()
    model.Revision = 1
    geoms = list(geometries)
    labels = list(names) if names is not None else [None] * len(geoms)
    if len(labels) != len(geoms):
        raise NurbsInputError(f"names: {len(labels)} names for {len(geoms)} geometries")
    ids = [geometry_id(g, name) for g, name in zip(geoms, labels)]
    layer = r.Layer()
    layer.Name = "Default"
    layer.Id = uuid.uuid5(ID_NAMESPACE, "layer:" + ",".join(map(str, ids)))
    model.Layers.Add(layer)
    for g, name, oid in zip(geoms, labels, ids):
        rg = to_rhino(g)
        attrs = r.ObjectAttributes()
        attrs.Id, attrs.LayerIndex = oid, 0
        if name:
            attrs.Name = str(name)
        if isinstance(g, NurbsCurve):
            model.Objects.AddCurve(rg, attrs)
        else:
            model.Objects.AddSurface(rg, attrs)
    options = r.File3dmWriteOptions()
    options.Version = int(version)
    data = base64.b64decode(model.Encode(options))
    if not data:
        raise OSError(f"{path}: rhino3dm could not encode the file")
    Path(path).write_bytes(data)
    return Path(path)
