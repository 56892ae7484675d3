"""Closed meshes through manifold3d: capping, orientation, trimming, booleans, checks."""

from __future__ import annotations

import math

import manifold3d
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.anatomy import mesh as M
from cardionurbs.errors import ReconstructionError


def open_ellipsoid(a: float, b: float, c: float, z_cut: float, n: int = 48):
    """A UV ellipsoid tessellation with the faces above z_cut removed (a tube with
    a closed bottom and an open top ring), like a tessellated ventricle."""
    s = trimesh.creation.uv_sphere(radius=1.0, count=[n, n])
    s.apply_scale([a, b, c])
    f = s.faces[s.vertices[s.faces].mean(axis=1)[:, 2] < z_cut]
    return s.vertices, f


def assert_closed(tm: trimesh.Trimesh) -> None:
    assert tm.is_watertight and tm.is_winding_consistent and tm.is_volume
    assert tm.volume > 0
    m = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(tm.vertices, np.float32),
                                            tri_verts=np.asarray(tm.faces, np.uint32)))
    assert m.status() == manifold3d.Error.NoError
    # outward normals: for a closed, consistently wound mesh the signed volume
    # (divergence theorem) is positive exactly when the normals point outward
    assert M.signed_volume(tm.vertices, tm.faces) > 0


def test_boundary_loop_of_open_tube():
    v, f = open_ellipsoid(10, 8, 20, 5.0)
    loops = M.boundary_loops(f)
    assert len(loops) == 1
    ring = v[loops[0]]
    assert np.ptp(ring[:, 2]) < 1e-9          # the cut ring is planar in this mesh


@pytest.mark.parametrize("flip", [False, True])
def test_closed_mesh_is_outward_whatever_the_input_winding(flip):
    v, f = open_ellipsoid(10, 8, 20, 5.0)
    if flip:
        f = f[:, ::-1]
    v2, f2 = M.closed_mesh(v, f)
    tm = trimesh.Trimesh(v2, f2, process=False)
    assert_closed(tm)
    assert M.signed_volume(v2, f2) > 0


def test_trimmed_solid_matches_spherical_cap():
    r, h = 10.0, 13.0                         # keep z <= -10 + 13 = 3
    v, f = open_ellipsoid(r, r, r, 6.0, n=96)
    m = M.solid(v, f, plane=M.Plane([0, 0, 3.0], [0, 0, -1.0]), what="cap", frame=0)
    tm = M.to_trimesh(m, what="cap", frame=0)
    assert_closed(tm)
    exact = math.pi * h * h * (3 * r - h) / 3
    assert abs(tm.volume / exact - 1) < 0.005
    assert abs(M.volume_ml(m) - tm.volume / 1000) < 1e-9
    assert tm.vertices[:, 2].max() <= 3.0 + 1e-9


def test_boolean_shell_volume():
    vo, fo = open_ellipsoid(12, 12, 24, 8.0, n=96)
    vi, fi = open_ellipsoid(9, 9, 20, 8.0, n=96)
    plane = M.Plane([0, 0, 4.0], [0, 0, -1.0])
    shell = M.solid(vo, fo, plane=plane) - M.solid(vi, fi, plane=plane)
    tm = M.to_trimesh(shell, what="myocardium", frame=0)
    assert_closed(tm)

    def cut(a, c, z):   # ellipsoid volume below z
        return math.pi * a * a * ((z + c) - (z ** 3 + c ** 3) / (3 * c * c))
    exact = cut(12, 24, 4.0) - cut(9, 20, 4.0)
    assert abs(tm.volume / exact - 1) < 0.01


@settings(max_examples=15, deadline=None)
@given(a=st.floats(5, 30), c=st.floats(10, 60), frac=st.floats(-0.6, 0.6))
def test_trimmed_ellipsoid_volume_property(a, c, frac):
    z = frac * c
    v, f = open_ellipsoid(a, 0.8 * a, c, z + 0.3 * c + 1.0, n=64)
    m = M.solid(v, f, plane=M.Plane([0, 0, z], [0, 0, -1.0]))
    tm = M.to_trimesh(m)
    assert_closed(tm)
    exact = math.pi * a * 0.8 * a * ((z + c) - (z ** 3 + c ** 3) / (3 * c * c))
    assert abs(tm.volume / exact - 1) < 0.01


def test_cap_of_non_convex_ring_is_not_a_fan():
    # a crescent-shaped open prism: the cap must follow the crescent (ear clipping)
    t = np.linspace(0, np.pi, 40)
    outer = np.column_stack([20 * np.cos(t), 20 * np.sin(t)])
    inner = np.column_stack([12 * np.cos(t[::-1]), 12 * np.sin(t[::-1]) + 2])
    ring = np.vstack([outer, inner])
    n = len(ring)
    bottom = np.column_stack([ring, np.zeros(n)])
    top = np.column_stack([ring, np.full(n, 10.0)])
    v = np.vstack([bottom, top])
    i = np.arange(n)
    j = (i + 1) % n
    f = np.concatenate([np.column_stack([i, j, j + n]), np.column_stack([i, j + n, i + n])])
    v2, f2 = M.closed_mesh(v, f)
    tm = trimesh.Trimesh(v2, f2, process=False)
    assert_closed(tm)
    area = 0.5 * abs(np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1]))
    assert tm.volume == pytest.approx(area * 10.0, rel=1e-9)


def test_non_manifold_input_is_a_reconstruction_error():
    v, f = open_ellipsoid(10, 8, 20, 5.0)
    f_bad = np.concatenate([f, f[:1]])          # a face twice: a directed edge used twice
    with pytest.raises(ReconstructionError, match="edge"):
        M.closed_mesh(v, f_bad)


def test_empty_trim_names_structure_and_frame():
    v, f = open_ellipsoid(10, 8, 20, 5.0)
    with pytest.raises(ReconstructionError, match=r"lv_endo, frame 3"):
        M.solid(v, f, plane=M.Plane([0, 0, -50.0], [0, 0, -1.0]), what="lv_endo", frame=3)


def test_plane_round_trip_and_signed_distance():
    p = M.Plane([1, 2, 3], [0, 0, 2])
    assert np.allclose(p.normal, [0, 0, 1])
    q = M.Plane.from_dict(p.to_dict())
    assert np.allclose(q.signed_distance(np.array([[0, 0, 5.0]])), [2.0])
