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

Volume-corrected grids (``volume_corrected=True``, what the model's solids use): the
vertices of a mesh on the surface cut across its curvature, so a closed mesh of a convex
surface holds less volume than the surface by about the mean gap between the surface and
its bilinear interpolant, (κ_u h_u² + κ_v h_v²)/12 per unit area (κ the normal curvatures,
h the grid steps: for z = (a x² + b y²)/2 the mean of a x(h − x)/2 over a cell is a h²/12).
Each vertex is therefore moved along the unit normal N by −N·(Δ²_u S + Δ²_v S)/12, with Δ²
the grid's second differences (≈ S_uu Δu², S_vv Δv²): the mesh's volume and section areas
then err by O(h⁴) instead of O(h²) (a circle's N-gon loses πR²(2π/N)²/6 of its area; the
corrected one about (2π/N)² less of that). Collapsed (apex) rows and the ends of an open u
are not moved; the open v ends take the u term only.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.surface import NurbsSurface

__all__ = ["tessellate", "grid_faces", "volume_correction"]


def grid_faces(nu: int, nv: int, closed_u: bool, collapsed_start: bool,
               collapsed_end: bool) -> tuple[np.ndarray, np.ndarray]:
    """Faces of an ``nu x nv`` grid and the map grid index -> vertex index
    (fresh, writable copies of cached arrays).

    Parameters
    ----------
    nu, nv : int
        Grid size in u and v.
    closed_u : bool
        The u columns wrap around (the seam column is shared).
    collapsed_start, collapsed_end : bool
        The first / last v row is one vertex (an apex).

    Returns
    -------
    faces : (F, 3) int ndarray
        Triangles, oriented along ``Su x Sv``.
    vertex_of : (nu, nv) int ndarray
        Grid point (i, j) is vertex ``vertex_of[i, j]``.
    """
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


def volume_correction(grid: np.ndarray, closed_u: bool, collapsed_start: bool,
                      collapsed_end: bool) -> np.ndarray:
    """Displacements that make a grid's mesh hold its surface's volume to O(h⁴).

    −N (N·(Δ²_u S + Δ²_v S)) / 12 at every vertex (module doc), N the unit normal
    from the grid's central differences; zero on collapsed rows and at the ends of an open
    u; the first and last v rows (open ends) take the u term only.

    Parameters
    ----------
    grid : (nu, nv, 3) float ndarray
        Surface points on the parameter grid (any length unit, e.g. mm).
    closed_u : bool
    collapsed_start, collapsed_end : bool
        As for :func:`grid_faces`.

    Returns
    -------
    (nu, nv, 3) float ndarray
        Displacements in the grid's units.
    """
    S = np.asarray(grid, float)
    if closed_u:
        d2u = np.roll(S, -1, axis=0) - 2 * S + np.roll(S, 1, axis=0)
        su = np.roll(S, -1, axis=0) - np.roll(S, 1, axis=0)
    else:
        d2u = np.zeros_like(S)
        d2u[1:-1] = S[2:] - 2 * S[1:-1] + S[:-2]
        su = np.gradient(S, axis=0)
    d2v = np.zeros_like(S)
    d2v[:, 1:-1] = S[:, 2:] - 2 * S[:, 1:-1] + S[:, :-2]
    sv = np.gradient(S, axis=1)
    n = np.cross(su, sv)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    ok = norm[..., 0] > 1e-12 * max(float(np.abs(S).max()), 1.0) ** 2
    n = np.where(ok[..., None], n / np.where(norm > 0, norm, 1.0), 0.0)
    d = -np.einsum("ijk,ijk->ij", n, d2u + d2v)[..., None] * n / 12.0
    if collapsed_start:
        d[:, 0] = 0.0
    if collapsed_end:
        d[:, -1] = 0.0
    if not closed_u:
        d[0] = d[-1] = 0.0
    return d


def tessellate(surface: NurbsSurface, nu: int, nv: int,
               volume_corrected: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of ``surface`` on an ``nu x nv`` parameter grid (see module doc
    for seam, apex and orientation).

    The faces depend only on the grid and the surface's topology (closed u,
    collapsed ends), so they come from a cache and are returned read-only:
    copy them (``faces.copy()``) before modifying in place.

    Parameters
    ----------
    surface : NurbsSurface
        A 3-D surface.
    nu, nv : int
        Grid size in u and v, >= 2 (nu >= 3 when ``closed_u``).
    volume_corrected : bool, default False
        Move the vertices off the surface so that the mesh's volume is the
        surface's to O(h⁴) (:func:`volume_correction`).

    Returns
    -------
    vertices : (V, 3) float ndarray
        In the surface's units (e.g. mm); a collapsed row is one vertex.
    faces : (F, 3) int ndarray
        Read-only triangle indices into ``vertices``.

    Raises
    ------
    NurbsInputError
        Not a NurbsSurface, or a grid size too small.

    Examples
    --------
    Three rings lofted to an apex, then meshed:

    >>> import numpy as np
    >>> from cardionurbs import nurbs
    >>> t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    >>> rings = [nurbs.fit_curve(np.column_stack([r * np.cos(t), r * np.sin(t), np.full(40, z)]),
    ...                          closed=True, n_ctrl=8) for r, z in ((20, 0), (25, 20), (20, 40))]
    >>> s = nurbs.loft(rings + [np.array([0.0, 0.0, 60.0])], degree_v=3)
    >>> vertices, faces = nurbs.tessellate(s, 32, 16)
    >>> vertices.shape, faces.shape          # 32 x 15 grid vertices + the apex
    ((481, 3), (928, 3))
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
    if volume_corrected:
        grid = grid + volume_correction(grid, bool(surface.closed_u), bool(c0), bool(c1))
    faces, vertex_of = _grid_faces(nu, nv, bool(surface.closed_u), bool(c0), bool(c1))
    flat = np.ascontiguousarray(grid).reshape(-1, grid.shape[-1])
    if not (c0 or c1):
        return flat, faces
    n_vert = int(vertex_of.max()) + 1
    vertices = np.empty((n_vert, grid.shape[-1]))
    vertices[vertex_of.ravel()] = flat
    return vertices, faces
