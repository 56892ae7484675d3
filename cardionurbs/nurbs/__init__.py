"""cardionurbs.nurbs -- rational B-spline curves and surfaces (pure geometry).

Fitting contours (paper §3.2, eqs. 6–10), lofting sections (§3.2.4), knot
insertion/refinement (NURBS Book A5.1/A5.4), degree elevation (A5.9),
vectorised evaluation (A2.2/A2.3, A4.2/A4.4; many splines at once:
:mod:`~cardionurbs.nurbs.batch`), closest points, tessellation and
lossless (de)serialisation, ``.3dm`` export (rhino3dm, the ``cad`` extra,
imported only when used).  Knows nothing about hearts.

    from cardionurbs import nurbs
    c = nurbs.fit_curve(points, degree=3, closed=True, tol=0.5)
    s = nurbs.loft([c0, c1, c2, apex_point], degree_v=3)
    vertices, faces = nurbs.tessellate(s, 64, 32)
"""

from __future__ import annotations

from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.batch import CurveBatch, SplineData, SurfaceBatch
from cardionurbs.nurbs.curve import NurbsCurve
from cardionurbs.nurbs.fitting import (CompatibleFit, chord_length_parameters, fit_compatible_curves,
                                       fit_curve)
from cardionurbs.nurbs.loft import loft, loft_compatible
from cardionurbs.nurbs.operations import (elevate_degree, insert_knots, make_compatible,
                                          rotate_seam)
from cardionurbs.nurbs.projection import (closest_points, curve_closest_points,
                                          surface_closest_points)
from cardionurbs.nurbs.rhino import to_rhino, write_3dm
from cardionurbs.nurbs.surface import NurbsSurface
from cardionurbs.nurbs.tessellate import tessellate

__all__ = [
    "NurbsCurve", "NurbsSurface", "NurbsInputError",
    "fit_curve", "fit_compatible_curves", "CompatibleFit", "chord_length_parameters", "loft", "loft_compatible", "tessellate",
    "elevate_degree", "insert_knots", "make_compatible", "rotate_seam",
    "closest_points", "curve_closest_points", "surface_closest_points",
    "to_rhino", "write_3dm", "CurveBatch", "SurfaceBatch", "SplineData",
]
