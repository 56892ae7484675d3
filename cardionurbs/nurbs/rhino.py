"""Export to Rhino ``.3dm`` files through rhino3dm (the ``cad`` extra).

openNURBS stores control points homogeneously, ``(w x, w y, w z, w)``, and
knot vectors without the two superfluous end knots (``n + p - 1`` knots).
Closed (periodic) curves and surfaces are written in their equivalent clamped
form (:meth:`NurbsCurve.to_clamped`, :meth:`NurbsSurface.to_clamped`), which
Rhino reads as closed geometry with the same shape.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.surface import NurbsSurface

__all__ = ["to_rhino", "write_3dm"]


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


def write_3dm(path: str | os.PathLike, geometries: Iterable[NurbsCurve | NurbsSurface],
              names: Iterable[str] | None = None, version: int = 7) -> Path:
    """Write curves and surfaces to a ``.3dm`` file.

    A plain write (this package knows no file policy): callers that must never
    leave a half-written file write to a temporary path and rename it
    (:func:`cardionurbs.io.export.export_model_3dm` does).

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
    geoms = list(geometries)
    labels = list(names) if names is not None else [None] * len(geoms)
    if len(labels) != len(geoms):
        raise NurbsInputError(f"names: {len(labels)} names for {len(geoms)} geometries")
    for g, name in zip(geoms, labels):
        rg = to_rhino(g)
        attrs = r.ObjectAttributes()
        if name:
            attrs.Name = str(name)
        if isinstance(g, NurbsCurve):
            model.Objects.AddCurve(rg, attrs)
        else:
            model.Objects.AddSurface(rg, attrs)
    if not model.Write(str(path), version):
        raise OSError(f"{path}: rhino3dm could not write the file")
    return Path(path)
