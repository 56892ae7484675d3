"""Every Sunnybrook expert contour (inner and outer, pixel units) is fitted by
a closed cubic NURBS within 0.5 pixel maximum distance (paper §3.2)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cardionurbs import nurbs
from conftest import shared_data

pytestmark = pytest.mark.realdata

TOL_PX = 0.5


@pytest.mark.parametrize("patient", ["SC-HF-I-1", "SC-HF-I-2", "SC-HF-I-4"])
def test_every_contour_fits_within_half_a_pixel(patient):
    folder = shared_data("sunnybrook", patient)
    files = sorted(folder.glob("[io]-contours/*.txt"))
    assert files, f"no contour files in {folder}"
    for f in files:
        Q = np.loadtxt(f)
        c = nurbs.fit_curve(Q, degree=3, closed=True, tol=TOL_PX)
        assert c.closed and c.n_control < len(Q), f.name
        _, d = nurbs.closest_points(c, Q)
        assert d.max() <= TOL_PX, f"{f.name}: {d.max():.3f} px"
        # independent check: distance to a dense polyline of the curve (an
        # upper bound of the true distance, off by at most the sample spacing)
        S = c.evaluate(np.linspace(0, 1, 20001))
        spacing = np.linalg.norm(np.diff(S, axis=0), axis=1).max()
        dense, _ = cKDTree(S).query(Q)
        assert dense.max() <= TOL_PX + spacing, f.name
        # the fit is not looser than needed: one control point fewer fails
        if c.n_control > 4:
            fewer = nurbs.fit_curve(Q, degree=3, closed=True, n_ctrl=c.n_control - 1)
            _, d_fewer = nurbs.closest_points(fewer, Q)
            assert d_fewer.max() > TOL_PX, f.name
