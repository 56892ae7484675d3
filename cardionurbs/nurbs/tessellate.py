"""Triangle meshes of NURBS surfaces.

:func:`tessellate` samples a regular ``nu x nv`` parameter grid (one grid
evaluation, two matrix products) and triangulates it with precomputed index
arrays:

* periodic u (``closed_u``): ``nu`` columns at u = i/nu, the seam column is
  shared -- the last quad column reuses the first vertex column;
* a collapsed v end (apex): its whole grid row becomes one vertex and the
  quads touching it become single triangles (no degenerate triangles);
* orientation: every triangle ``(a, b, c)`` has ``(b - a) x (c - a)`` along
  ``Su x Sv`` (for a lofted surface: away from the loft axis).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.surface import NurbsSurface

__all__ = ["tessellate", "grid_faces"]


def grid_faces(nu: int, nv: int, closed_u: bool, collapsed_start: bool,
               collapsed_end: bool) -> tuple[np.ndarray, np.ndarray]:
    """See :func:`_grid_faces`; returns fresh (writable) copies of cached arrays."""
    faces, vertex_of = _grid_faces(int(nu), int(nv), bool(closed_u), bool(collapsed_start),
                                   bool(collapsed_end))
    return faces.copy(), vertex_of.copy()


@lru_cache(maxsize=32)
def _grid_faces(nu: int, nv: int, closed_u: bool, collapsed_start: bool,
                collapsed_end: bool) -> tuple[np.ndarray, np.ndarray]:
    """Faces of an ``nu x nv`` grid and the map grid index -> vertex index.

    Returns ``(faces (F, 3), vertex_of (nu, nv))``; grid point (i, j) is
    vertex ``vertex_of[i, j]``.
    """
    vertex_of = np.arange(nu * nv, dtype=np.int64).reshape(nu, nv)
    if collapsed_start or collapsed_end:
        keep = np.ones((nu, nv), dtype=bool)
        if collapsed_start:
            keep[1:, 0] = False
        if collapsed_end:
            keep[1:, -1] = False
        vertex_of = (np.cumsum(keep.ravel()) - 1).reshape(nu, nv)
        if collapsed_start:
            vertex_of[:, 0] = vertex_of[0, 0]
        if collapsed_end:
            vertex_of[:, -1] = vertex_of[0, -1]
    ni = nu if closed_u else nu - 1
    nxt = np.roll(vertex_of, -1, axis=0)[:ni]          # column i + 1 (wraps when closed)
    cur = vertex_of[:ni]
    a, b = cur[:, :-1], nxt[:, :-1]
    c, d = nxt[:, 1:], cur[:, 1:]
    tri = np.empty((ni, nv - 1, 2, 3), dtype=np.int64)
    tri[..., 0, 0], tri[..., 0, 1], tri[..., 0, 2] = a, b, c     # lower-right triangle
    tri[..., 1, 0], tri[..., 1, 1], tri[..., 1, 2] = a, c, d     # upper-left triangle
    if collapsed_start or collapsed_end:
        use = np.ones((ni, nv - 1, 2), dtype=bool)
        if collapsed_start:
            use[:, 0, 0] = False            # a == b on the apex row
        if collapsed_end:
            use[:, -1, 1] = False           # c == d on the apex row
        faces = tri[use]
    else:
        faces = tri.reshape(-1, 3)
    faces.flags.writeable = False          # shared by every call with this grid: never mutate
    vertex_of.flags.writeable = False
    return faces, vertex_of


def tessellate(surface: NurbsSurface, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangle faces (F, 3) of ``surface`` on an
    ``nu x nv`` parameter grid (see module doc for seam, apex and orientation).

    The faces depend only on the grid and the surface's topology (closed u,
    collapsed ends), so they come from a cache and are returned read-only:
    copy them (``faces.copy()``) before modifying in place.
    """
    if not isinstance(surface, NurbsSurface):
        raise NurbsInputError(f"surface: expected a NurbsSurface, got {type(surface).__name__}")
    for name, val in (("nu", nu), ("nv", nv)):
        if int(val) != val or val < 2:
            raise NurbsInputError(f"{name}: must be an integer >= 2, got {val!r}")
    nu, nv = int(nu), int(nv)
    if surface.closed_u and nu < 3:
        raise NurbsInputError(f"nu: a surface closed in u needs nu >= 3, got {nu}")
    (ulo, uhi), (vlo, vhi) = surface.domain_u, surface.domain_v
    u = ulo + (uhi - ulo) * (np.arange(nu) / nu if surface.closed_u else np.linspace(0, 1, nu))
    v = np.linspace(vlo, vhi, nv)
    grid = surface.evaluate(u, v)
    c0, c1 = surface.collapsed_v()
    faces, vertex_of = _grid_faces(nu, nv, bool(surface.closed_u), bool(c0), bool(c1))
    flat = np.ascontiguousarray(grid).reshape(-1, grid.shape[-1])
    if not (c0 or c1):
        return flat, faces
    n_vert = int(vertex_of.max()) + 1
    vertices = np.empty((n_vert, grid.shape[-1]))
    vertices[vertex_of.ravel()] = flat
    return vertices, faces
