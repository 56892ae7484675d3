"""tessellate() shares its cached triangle indices read-only: a write fails loudly instead of
corrupting every later mesh of the same grid."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs import nurbs


def _surface():
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    secs = [nurbs.fit_curve(np.column_stack([20 * np.cos(t), 15 * np.sin(t), np.full(24, z)]),
                            closed=True, n_ctrl=8) for z in (0.0, 10.0, 20.0)]
    return nurbs.loft(secs + [np.array([0.0, 0.0, 35.0])])


def test_faces_are_shared_and_read_only():
    s = _surface()
    v1, f1 = nurbs.tessellate(s, 24, 10)
    v2, f2 = nurbs.tessellate(s, 24, 10)
    assert f1 is f2 and not f1.flags.writeable
    with pytest.raises(ValueError):
        f1[0, 0] = 0
    g = f1.copy()
    g[:, [1, 2]] = g[:, [2, 1]]                  # a copy may be modified freely
    assert np.array_equal(nurbs.tessellate(s, 24, 10)[1], f2)


def test_public_grid_faces_returns_writable_copies():
    f, vertex_of = nurbs.tessellate.__globals__["grid_faces"](6, 4, True, False, True)
    assert f.flags.writeable and vertex_of.flags.writeable
