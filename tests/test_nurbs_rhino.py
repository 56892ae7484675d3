"""Export to .3dm through rhino3dm (the ``cad`` extra): same shape in Rhino."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs import nurbs

rhino3dm = pytest.importorskip("rhino3dm", reason="rhino3dm (the 'cad' extra) is not installed")
from cardionurbs.nurbs.rhino import to_rhino, write_3dm  # noqa: E402


def sections():
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    out = []
    for k in range(3):
        pts = np.c_[(20 - 3 * k) * np.cos(t), (15 - 2 * k) * np.sin(t), np.full(40, 8.0 * k)]
        out.append(nurbs.fit_curve(pts, closed=True, n_ctrl=10, rational=k == 1))
    return out


def test_curves_and_surfaces_keep_their_shape_in_rhino(tmp_path):
    curves = sections()
    surf = nurbs.loft(curves + [np.array([0.0, 0.0, 30.0])])
    u = np.linspace(0, 1, 17)
    for c in curves:
        rc = to_rhino(c)
        assert rc.IsValid
        lo, hi = rc.Domain.T0, rc.Domain.T1
        got = np.array([[p.X, p.Y, p.Z] for p in (rc.PointAt(lo + x * (hi - lo)) for x in u)])
        np.testing.assert_allclose(got, c.evaluate(u), atol=1e-9)
    path = write_3dm(tmp_path / "model.3dm", curves + [surf], names=["a", "b", "c", "lv"])
    model = rhino3dm.File3dm.Read(str(path))
    assert len(model.Objects) == 4
    rs = model.Objects[3].Geometry
    assert model.Objects[3].Attributes.Name == "lv"
    v = np.linspace(0, 1, 5)
    got = np.array([[[getattr(rs.PointAt(a, b), k) for k in "XYZ"] for b in v] for a in u])
    np.testing.assert_allclose(got, surf.evaluate(u, v), atol=1e-9)


def test_export_rejects_other_objects(tmp_path):
    with pytest.raises(nurbs.NurbsInputError, match="geometry"):
        to_rhino("not a curve")
