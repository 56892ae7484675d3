"""Method-B truth volumes: the plane-clipped divergence-theorem volume of a closed mesh
(phantom/truth_realistic._volume) against manifold3d's trimmed solid and closed forms."""

import manifold3d
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.errors import PhantomError
from cardionurbs.phantom.truth_realistic import _volume


def _manifold_trimmed(v, faces, c, n) -> float:
    m = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(v, dtype=float),
                                              tri_verts=np.ascontiguousarray(faces, dtype=np.uint64)))
    return m.trim_by_plane(-n, float(-(c @ n))).volume() / 1000.0


@pytest.fixture(scope="module")
def blob():
    """A closed, outward, non-convex mesh (a bumpy sphere, mm)."""
    s = trimesh.creation.icosphere(subdivisions=4, radius=30.0)
    v = np.asarray(s.vertices, dtype=float)
    r = 1.0 + 0.2 * np.sin(3 * v[:, 0] / 30.0) * np.cos(2 * v[:, 2] / 30.0)
    return v * r[:, None], np.asarray(s.faces)


@settings(max_examples=40, deadline=None)
@given(st.floats(-35.0, 35.0), st.floats(0.0, np.pi), st.floats(0.0, 2 * np.pi))
def test_clipped_volume_matches_manifold3d(blob, offset, polar, azimuth):
    v, faces = blob
    n = np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    c = offset * n + np.array([1.0, -2.0, 0.5])
    got = _volume(v, faces, plane=(c, n))
    ref = _manifold_trimmed(v, faces, c, n)
    assert got == pytest.approx(ref, rel=1e-9, abs=1e-9)


def test_clipped_sphere_cap_closed_form():
    s = trimesh.creation.icosphere(subdivisions=6, radius=20.0)
    v, faces = np.asarray(s.vertices, dtype=float), np.asarray(s.faces)
    whole = _volume(v, faces)
    assert whole == pytest.approx(4.0 / 3.0 * np.pi * 20.0 ** 3 / 1000.0, rel=2e-3)
    # the apical side of a plane through the centre is half, of a plane 10 mm below it the cap
    n = np.array([0.0, 0.0, 1.0])
    assert _volume(v, faces, plane=(np.zeros(3), n)) == pytest.approx(0.5 * whole, rel=1e-9)
    h = 10.0
    cap = np.pi * h * h * (3 * 20.0 - h) / 3.0 / 1000.0
    assert _volume(v, faces, plane=(np.array([0.0, 0.0, -h]), n)) == pytest.approx(cap, rel=5e-3)
    assert _volume(v, faces, plane=(np.array([0.0, 0.0, -25.0]), n)) == 0.0


def test_open_mesh_is_refused():
    s = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    faces = np.asarray(s.faces)[1:]
    with pytest.raises(PhantomError, match="not closed"):
        _volume(np.asarray(s.vertices, dtype=float), faces, plane=(np.zeros(3), np.array([0, 0, 1.0])))
    flipped = np.asarray(s.faces).copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(PhantomError, match="not closed"):
        _volume(np.asarray(s.vertices, dtype=float), flipped)
