"""Closed, manifold meshes from tessellated NURBS surfaces (manifold3d booleans).

A ventricular surface tessellates to a tube closed at its collapsed apex and
open at its base ring. :func:`solid` caps every open boundary loop with a
planar triangulation (manifold3d's ear clipper), orients the result outward,
turns it into a :class:`manifold3d.Manifold` and trims it by the valve plane.
Cavities and walls are then booleans of these solids (docs/metrics.md):

    lv_cavity     = LV endo solid ∩ H_mitral
    lv_myocardium = (LV epi solid − LV endo solid) ∩ H_mitral
    rv_cavity     = (RV endo solid − LV epi solid) ∩ H_tricuspid
    rv_myocardium = (RV epi solid − RV endo solid − LV epi solid) ∩ H_tricuspid

where H is the half-space on the apical side of a valve plane. Every mesh
handed out is checked watertight and a volume by both trimesh and
manifold3d (meshes written to files: by manifold3d and :func:`check_closed_arrays`);
a failure raises :class:`ReconstructionError` naming the structure and frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import manifold3d
import numpy as np

from cardionurbs.errors import ReconstructionError

if TYPE_CHECKING:    # trimesh (~0.3 s to import) only where meshes are made
    import trimesh


@dataclass
class Plane:
    """An oriented plane: points x with (x − origin)·normal = 0; ``normal`` (3,) unit,
    pointing to the side that is KEPT (the apical side of a valve plane).

    Attributes
    ----------
    origin : ndarray, shape (3,)
        A point of the plane, in mm (scanner coordinates).
    normal : ndarray, shape (3,)
        The unit normal (normalised on construction), towards the kept side.
    """

    origin: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=float)
        self.origin = np.asarray(self.origin, dtype=float)
        self.normal = n / np.linalg.norm(n)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (mm) of (n, 3) points; positive on the kept side.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Points in mm.

        Returns
        -------
        ndarray, shape (n,)
            (x − origin) · normal, in mm.
        """
        return (np.asarray(points, dtype=float) - self.origin) @ self.normal

    def to_dict(self) -> dict:
        """JSON-safe plane.

        Returns
        -------
        dict
            ``{"origin": 3 numbers (mm), "normal": 3 numbers}``.
        """
        return {"origin": [float(x) for x in self.origin], "normal": [float(x) for x in self.normal]}

    @classmethod
    def from_dict(cls, d: dict) -> "Plane":
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            ``origin`` and ``normal``, 3 numbers each.

        Returns
        -------
        Plane
            The plane (normal made unit).
        """
        return cls(np.asarray(d["origin"], float), np.asarray(d["normal"], float))


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Open boundary loops of a triangle mesh, each as vertex indices in the
    direction the boundary edges run in their faces.

    A boundary edge is a directed edge (a, b) whose reverse (b, a) belongs to
    no face. Raises ReconstructionError when the boundary is not a set of
    simple loops (a non-manifold edge or a vertex where two loops touch).

    Parameters
    ----------
    faces : ndarray of int, shape (F, 3)
        Consistently oriented triangles.

    Returns
    -------
    list of ndarray of int
        One array of vertex indices per loop ([] for a closed mesh).

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        A directed edge used twice, or a boundary that is not a set of simple loops.
    """
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = int(f.max()) + 1 if f.size else 0
    key = e[:, 0] * n + e[:, 1]
    rkey = e[:, 1] * n + e[:, 0]
    # one sort serves both questions (np.unique and np.isin would each sort again)
    sk = np.sort(key)
    if (sk[1:] == sk[:-1]).any():
        raise ReconstructionError("surface mesh has a directed edge used twice (inconsistent "
                                  "orientation or a non-manifold edge)")
    pos = np.minimum(np.searchsorted(sk, rkey), sk.size - 1)
    bnd = e[sk[pos] != rkey]                  # edges whose reverse belongs to no face
    if bnd.size == 0:
        return []
    nxt = {}
    for a, b in bnd:
        if a in nxt:
            raise ReconstructionError("surface boundary touches itself at a vertex")
        nxt[int(a)] = int(b)
    loops, seen = [], set()
    for start in list(nxt):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            if v not in nxt:
                raise ReconstructionError("surface boundary is not a closed loop")
            v = nxt[v]
        if v != start:
            raise ReconstructionError("surface boundary is not a simple loop")
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def cap_loop(vertices: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Triangles (k, 3) that close one boundary loop, wound against the loop.

    The loop is projected on its least-squares plane (principal axes of its
    points) and triangulated by manifold3d's ear clipper; the cap's triangles
    run the boundary edges in the reverse direction, so that the capped mesh
    is consistently oriented (every edge used once in each direction).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        The mesh's vertices, in mm.
    loop : ndarray of int, shape (k,)
        One boundary loop (:func:`boundary_loops`).

    Returns
    -------
    ndarray of int, shape (k - 2, 3)
        The cap's triangles (vertex indices).
    """
    p = vertices[loop]
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    xy = (p - c) @ vt[:2].T
    # ear clipping wants CCW; the cap must run opposite to the loop's edges
    area2 = np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    order = np.arange(len(loop)) if area2 > 0 else np.arange(len(loop))[::-1]
    tri = np.asarray(manifold3d.triangulate([np.ascontiguousarray(xy[order])]), dtype=np.int64)
    tri = loop[order][tri]
    # orient against the loop: the loop's edge (loop[0] -> loop[1]) must appear reversed
    a, b = loop[0], loop[1]
    rev = np.any((tri == b) & (np.roll(tri, -1, axis=1) == a))
    return tri if rev else tri[:, ::-1]


def closed_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cap every open boundary loop of (vertices, faces) and orient it outward.

    Returns (vertices, faces) of a closed, consistently oriented triangle mesh
    whose signed volume (divergence theorem) is positive.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        The surface's vertices, in mm.
    faces : ndarray of int, shape (F, 3)
        Its consistently oriented triangles.

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        Unchanged, in mm.
    faces : ndarray of int, shape (F + c, 3)
        The triangles with the caps, oriented outward.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The boundary is not a set of simple loops.
    """
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    caps = [cap_loop(v, loop) for loop in boundary_loops(f)]
    if caps:
        f = np.concatenate([f] + caps)
    if signed_volume(v, f) < 0:
        f = f[:, ::-1]
    return v, f


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed triangle mesh (divergence theorem), units³.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Vertices (mm for mm³).
    faces : ndarray of int, shape (F, 3)
        Triangles.

    Returns
    -------
    float
        Σ a · (b × c) / 6, positive for outward normals.
    """
    t = np.asarray(vertices, dtype=float)[np.asarray(faces, dtype=np.int64)]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def clipped_volume(vertices: np.ndarray, faces: np.ndarray, plane: Plane | None) -> float:
    """Volume (units³) of the part of a closed, outward-oriented triangle mesh on the kept
    side of ``plane`` (all of it when ``plane`` is None), without building the clipped solid.

    Divergence theorem with the origin on the plane: V = Σ (a · (b × c)) / 6 over the
    triangles clipped to the half-space (Sutherland–Hodgman against one plane: a
    triangle with one vertex kept becomes one triangle, with two kept a quadrilateral,
    two triangles). The cap that closes the cut lies in the plane through the origin,
    where x · n = 0, so it adds nothing and is never built. Equals the volume of
    :func:`solid` trimmed by the plane (manifold3d) to rounding; it does not check the
    mesh (:func:`solid` does).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        A closed, outward-oriented mesh's vertices (mm for mm³).
    faces : ndarray of int, shape (F, 3)
        Its triangles.
    plane : Plane or None
        The clipping plane (its kept side), or None for the whole mesh.

    Returns
    -------
    float
        The clipped volume, in the vertices' unit cubed.
    """
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    if plane is None:
        return signed_volume(v, f)
    t = v[f] - plane.origin                               # (m, 3, 3), origin on the plane
    d = t @ plane.normal                                  # (m, 3) signed distances
    kept = d >= 0
    n_kept = kept.sum(axis=1)

    def triple(a, b, c):
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum())

    total = triple(*(t[n_kept == 3].transpose(1, 0, 2)))
    for count in (1, 2):
        sel = np.flatnonzero(n_kept == count)
        if sel.size == 0:
            continue
        # roll each triangle (keeping its orientation) so that its odd vertex comes first:
        # the one kept vertex (count 1) or the one cut-off vertex (count 2)
        odd = kept[sel] if count == 1 else ~kept[sel]
        s = np.argmax(odd, axis=1)
        idx = (s[:, None] + np.arange(3)[None, :]) % 3
        tt = np.take_along_axis(t[sel], idx[:, :, None], axis=1)
        dd = np.take_along_axis(d[sel], idx, axis=1)
        a, b, c = tt[:, 0], tt[:, 1], tt[:, 2]
        ab = a + (b - a) * (dd[:, 0] / (dd[:, 0] - dd[:, 1]))[:, None]
        ac = a + (c - a) * (dd[:, 0] / (dd[:, 0] - dd[:, 2]))[:, None]
        if count == 1:
            total += triple(a, ab, ac)
        else:                                           # a cut off: (ab, b, c), (ab, c, ac)
            total += triple(ab, b, c) + triple(ab, c, ac)
    return total / 6.0


def to_manifold(vertices: np.ndarray, faces: np.ndarray, *, what: str = "surface",
                frame: int | None = None) -> manifold3d.Manifold:
    """A manifold3d solid from a closed, outward-oriented triangle mesh.

    Raises ReconstructionError naming ``what`` and ``frame`` if manifold3d
    rejects the mesh (not a closed 2-manifold).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Vertices in mm.
    faces : ndarray of int, shape (F, 3)
        Outward-oriented triangles.
    what : str, optional
        What the mesh is, for the message (``"lv_endo"``).
    frame : int or None, optional
        The frame index, for the message.

    Returns
    -------
    manifold3d.Manifold
        The solid.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        manifold3d rejects the mesh.
    """
    mesh = manifold3d.Mesh64(vert_properties=np.ascontiguousarray(vertices, dtype=np.float64),
                             tri_verts=np.ascontiguousarray(faces, dtype=np.uint64))
    m = manifold3d.Manifold(mesh)
    status = m.status()
    if status != manifold3d.Error.NoError:
        raise ReconstructionError(f"{what}, frame {frame}: mesh is not a closed manifold "
                                  f"({status.name})")
    return m


def solid(vertices: np.ndarray, faces: np.ndarray, *, plane: Plane | None = None,
          what: str = "surface", frame: int | None = None) -> manifold3d.Manifold:
    """The solid bounded by a tessellated surface, capped, and trimmed by ``plane``.

    ``plane.normal`` points to the side that is kept (manifold3d trim_by_plane).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        The tessellated surface's vertices, in mm.
    faces : ndarray of int, shape (F, 3)
        Its triangles.
    plane : Plane or None, optional
        The trimming plane (valve plane).
    what : str, optional
        What the surface is, for the messages.
    frame : int or None, optional
        The frame index, for the messages.

    Returns
    -------
    manifold3d.Manifold
        The capped, trimmed solid (mm).

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The capped mesh is not a closed manifold, or nothing lies on the kept side.
    """
    v, f = closed_mesh(vertices, faces)
    m = to_manifold(v, f, what=what, frame=frame)
    if plane is not None:
        m = m.trim_by_plane(plane.normal, float(plane.origin @ plane.normal))
    if m.is_empty():
        raise ReconstructionError(f"{what}, frame {frame}: nothing of the surface lies on the "
                                  "apical side of the valve plane")
    return m


def to_trimesh(m: manifold3d.Manifold, *, what: str = "mesh",
               frame: int | None = None) -> trimesh.Trimesh:
    """Convert a manifold3d solid to a trimesh.Trimesh, checking it is closed.

    The result is watertight, a volume (consistent outward winding) and has
    positive volume, as both trimesh and manifold3d see it; otherwise
    ReconstructionError naming ``what`` and ``frame``.

    Parameters
    ----------
    m : manifold3d.Manifold
        A solid.
    what : str, optional
        What it is, for the messages.
    frame : int or None, optional
        The frame index, for the messages.

    Returns
    -------
    trimesh.Trimesh
        The closed mesh (vertices in mm).

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The solid is empty, not manifold, or its mesh fails :func:`check_closed`.
    """
    if m.status() != manifold3d.Error.NoError or m.is_empty():
        raise ReconstructionError(f"{what}, frame {frame}: boolean result is empty or not "
                                  f"manifold ({m.status().name})")
    import trimesh
    mesh = m.to_mesh64()
    tm = trimesh.Trimesh(vertices=np.asarray(mesh.vert_properties)[:, :3],
                         faces=np.asarray(mesh.tri_verts, dtype=np.int64), process=False)
    check_closed(tm, what=what, frame=frame)
    return tm


def check_closed(tm: trimesh.Trimesh, *, what: str = "mesh", frame: int | None = None) -> None:
    """Raise ReconstructionError unless ``tm`` is watertight, a volume with outward
    normals (trimesh) and a valid manifold3d solid.

    Parameters
    ----------
    tm : trimesh.Trimesh
        The mesh.
    what : str, optional
        What it is, for the messages.
    frame : int or None, optional
        The frame index, for the messages.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        Empty, not watertight, inconsistent winding, or inward normals.
    """
    if len(tm.faces) == 0:
        raise ReconstructionError(f"{what}, frame {frame}: mesh is empty")
    if not tm.is_watertight:
        raise ReconstructionError(f"{what}, frame {frame}: mesh is not watertight")
    if not tm.is_winding_consistent:
        raise ReconstructionError(f"{what}, frame {frame}: mesh winding is not consistent")
    if signed_volume(tm.vertices, tm.faces) <= 0:
        raise ReconstructionError(f"{what}, frame {frame}: mesh normals point inward")


def mesh_arrays(m: manifold3d.Manifold, *, what: str = "mesh",
                frame: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 mm, faces (F, 3) int64) of a manifold3d solid, checked
    closed by :func:`check_closed_arrays` -- what :func:`to_trimesh` hands out, without
    making (or importing) trimesh, for writing meshes to files.

    Parameters
    ----------
    m : manifold3d.Manifold
        A solid.
    what : str, optional
        What it is, for the messages.
    frame : int or None, optional
        The frame index, for the messages.

    Returns
    -------
    vertices : ndarray of float64, shape (V, 3)
        In mm.
    faces : ndarray of int64, shape (F, 3)
        Outward-oriented triangles.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The solid is empty, not manifold, or its mesh not closed.
    """
    if m.status() != manifold3d.Error.NoError or m.is_empty():
        raise ReconstructionError(f"{what}, frame {frame}: boolean result is empty or not "
                                  f"manifold ({m.status().name})")
    mesh = m.to_mesh64()
    v = np.ascontiguousarray(np.asarray(mesh.vert_properties)[:, :3], dtype=np.float64)
    f = np.asarray(mesh.tri_verts, dtype=np.int64)
    check_closed_arrays(v, f, what=what, frame=frame)
    return v, f


def check_closed_arrays(vertices: np.ndarray, faces: np.ndarray, *, what: str = "mesh",
                        frame: int | None = None) -> None:
    """The checks of :func:`check_closed` on plain arrays (numpy only).

    A closed, consistently wound triangle mesh uses every directed edge (i, j) once, and
    its reverse (j, i) once, in the neighbouring face: a directed edge used twice means
    two faces wound the same way along it (or more than two faces at the edge); an edge
    without its reverse is a boundary (a hole). Then the signed volume (divergence
    theorem) is positive when the normals point outward. Raises ReconstructionError
    naming ``what`` and ``frame``.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Vertices in mm.
    faces : ndarray of int, shape (F, 3)
        Triangles.
    what : str, optional
        What the mesh is, for the messages.
    frame : int or None, optional
        The frame index, for the messages.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        Empty, not watertight, inconsistent winding, or inward normals.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        raise ReconstructionError(f"{what}, frame {frame}: mesh is empty")
    n = int(f.max()) + 1
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(edges[:, 0] * n + edges[:, 1])
    if np.any(key[1:] == key[:-1]):
        raise ReconstructionError(f"{what}, frame {frame}: mesh winding is not consistent")
    rev = edges[:, 1] * n + edges[:, 0]
    at = np.minimum(np.searchsorted(key, rev), len(key) - 1)
    if not np.array_equal(key[at], rev):
        raise ReconstructionError(f"{what}, frame {frame}: mesh is not watertight")
    if signed_volume(vertices, f) <= 0:
        raise ReconstructionError(f"{what}, frame {frame}: mesh normals point inward")


def volume_ml(m: manifold3d.Manifold) -> float:
    """Volume of a solid in scanner mm³ expressed in mL (1 mL = 1000 mm³).

    Parameters
    ----------
    m : manifold3d.Manifold
        A solid in mm.

    Returns
    -------
    float
        Its volume in mL.
    """
    return float(m.volume()) / 1000.0
