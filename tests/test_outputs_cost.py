"""The cheaper `analyze` outputs (issue 16) mean what they meant: meshes written without
trimesh are trimesh's PLY files, checked closed as trimesh checks them; the GC pause
around writing leaves the collector as it found it."""

from __future__ import annotations

import gc

import manifold3d
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from cardionurbs.anatomy import mesh as M
from cardionurbs.errors import ExportError, ReconstructionError
from cardionurbs.io.export import canonical_order, export_mesh, write_ply
from cardionurbs.heap import acyclic, long_lived


def _ring_solid() -> manifold3d.Manifold:
    """A boolean result like a myocardium: a cylinder minus a thinner one, trimmed."""
    outer = manifold3d.Manifold.cylinder(40.0, 30.0, 30.0, 48)
    inner = manifold3d.Manifold.cylinder(50.0, 22.0, 22.0, 40).translate((1.0, 0.5, -5.0))
    return (outer - inner).trim_by_plane((0.2, 0.1, 1.0), 5.0)


def _body(data: bytes) -> bytes:
    return data[data.index(b"end_header\n") + len(b"end_header\n"):]


def test_ply_is_trimesh_ply(tmp_path):
    v, f = M.mesh_arrays(_ring_solid(), what="ring")
    path = write_ply(v, f, tmp_path / "ring.ply")
    tm = trimesh.Trimesh(v, f, process=False)
    # the same bytes as trimesh's exporter after the header (float32 x y z; uchar 3, int32 i j k)
    assert _body(path.read_bytes()) == _body(export_mesh(tm, tmp_path / "t.ply").read_bytes())
    back = trimesh.load(path, process=False)
    cv, cf = canonical_order(v, f)           # written in one order whatever the build order
    assert np.array_equal(back.faces, cf)
    assert np.allclose(back.vertices, cv, atol=1e-4)                # float32 of mm coordinates
    assert back.is_watertight and back.is_volume
    assert back.volume == pytest.approx(_ring_solid().volume(), rel=1e-6)


def test_ply_rejects_faces_outside_the_vertices(tmp_path):
    with pytest.raises(ExportError, match="bad.ply"):
        write_ply(np.zeros((3, 3)), np.array([[0, 1, 3]]), tmp_path / "bad.ply")
    assert not (tmp_path / "bad.ply").exists()


def test_mesh_arrays_are_the_trimesh_mesh():
    m = _ring_solid()
    v, f = M.mesh_arrays(m)
    tm = M.to_trimesh(m)
    assert np.array_equal(v, tm.vertices) and np.array_equal(f, tm.faces)


def _tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def test_closed_check_catches_holes_flips_and_inward_normals():
    v, f = _tetra()
    M.check_closed_arrays(v, f)
    with pytest.raises(ReconstructionError, match="lv_cavity, frame 3: mesh is not watertight"):
        M.check_closed_arrays(v, f[:3], what="lv_cavity", frame=3)
    flipped = f.copy()
    flipped[1] = flipped[1, ::-1]
    with pytest.raises(ReconstructionError, match="winding is not consistent"):
        M.check_closed_arrays(v, flipped)
    with pytest.raises(ReconstructionError, match="inward"):
        M.check_closed_arrays(v, f[:, ::-1])
    with pytest.raises(ReconstructionError, match="empty"):
        M.check_closed_arrays(v, f[:0])


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(5, 60), st.integers(0, 2))
def test_closed_check_agrees_with_trimesh(seed, n, damage):
    """Random convex hulls, intact or with one face removed or flipped: the numpy check
    passes exactly when trimesh finds the mesh watertight, consistently wound and a
    positive volume."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * [3.0, 2.0, 1.0]
    hull = ConvexHull(p)
    tm = trimesh.Trimesh(p, hull.simplices, process=False)
    trimesh.repair.fix_normals(tm)
    f = np.asarray(tm.faces).copy()
    k = int(rng.integers(len(f)))
    if damage == 1:
        f = np.delete(f, k, axis=0)
    elif damage == 2:
        f[k] = f[k, ::-1]
    ref = trimesh.Trimesh(p, f, process=False)
    ok = ref.is_watertight and ref.is_winding_consistent and ref.volume > 0
    try:
        M.check_closed_arrays(p, f)
        mine = True
    except ReconstructionError:
        mine = False
    assert mine == ok == (damage == 0)


def test_collector_pauses_are_undone():
    before = gc.get_freeze_count()
    with pytest.raises(RuntimeError):
        with long_lived():
            assert gc.get_freeze_count() > before
            with acyclic():
                assert not gc.isenabled()
            assert gc.isenabled()
            raise RuntimeError("outputs failed")
    assert gc.get_freeze_count() == before and gc.isenabled()
    gc.disable()
    try:
        with acyclic():
            pass
        assert not gc.isenabled()          # left as found
    finally:
        gc.enable()
