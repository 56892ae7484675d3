"""The public API of cardionurbs.nurbs: construction, evaluation, fitting,
lofting, tessellation, closest points, serialisation and input errors."""

from __future__ import annotations

import json
from functools import lru_cache

import numpy as np
import pytest

from cardionurbs import nurbs
from cardionurbs.errors import CardioNurbsError, NurbsInputError


def ellipse_points(m: int = 80, a: float = 30.0, b: float = 18.0, z: float | None = None,
                   phase: float = 0.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, m, endpoint=False) + phase
    pts = np.c_[a * np.cos(t) + 3 * np.cos(3 * t), b * np.sin(t)]
    if z is not None:
        pts = np.c_[pts, np.full(m, z)]
    return pts


@lru_cache(maxsize=1)
def lv_like_surface() -> nurbs.NurbsSurface:
    sections = [nurbs.fit_curve(ellipse_points(60, 25 - 4 * k, 20 - 3 * k, 10.0 * k, 0.2 * k),
                                closed=True, tol=0.01) for k in range(4)]
    return nurbs.loft(sections + [np.array([0.0, 0.0, 45.0])], degree_v=3)


# ---------------------------------------------------------------- curves
def test_bezier_curve_matches_bernstein_form():
    P = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 3.0], [4.0, 0.0]])
    c = nurbs.NurbsCurve(3, [0, 0, 0, 0, 1, 1, 1, 1], P)
    u = np.linspace(0, 1, 11)
    bern = np.stack([(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u ** 2 * (1 - u), u ** 3], axis=1)
    np.testing.assert_allclose(c.evaluate(u), bern @ P, atol=1e-14)
    dbern = np.stack([-3 * (1 - u) ** 2, 3 * (1 - u) ** 2 - 6 * u * (1 - u),
                      6 * u * (1 - u) - 3 * u ** 2, 3 * u ** 2], axis=1)
    np.testing.assert_allclose(c.derivative(u, 1), dbern @ P, atol=1e-13)


def test_rational_derivatives_match_finite_differences():
    rng = np.random.default_rng(3)
    P = rng.normal(size=(7, 3))
    w = rng.uniform(0.5, 2.0, 7)
    c = nurbs.NurbsCurve(3, [0, 0, 0, 0, .2, .45, .8, 1, 1, 1, 1], P, w)
    u = np.linspace(0.03, 0.97, 13)      # no parameter on a knot
    h = 1e-5
    fd1 = (c.evaluate(u + h) - c.evaluate(u - h)) / (2 * h)
    fd2 = (c.evaluate(u + h) - 2 * c.evaluate(u) + c.evaluate(u - h)) / h ** 2
    np.testing.assert_allclose(c.derivative(u, 1), fd1, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(c.derivative(u, 2), fd2, rtol=1e-3, atol=1e-3)


def test_fit_closed_contour_within_tolerance_and_periodic():
    pts = ellipse_points()
    c = nurbs.fit_curve(pts, closed=True, tol=0.05)
    assert c.closed and c.degree == 3
    _, d = nurbs.closest_points(c, pts)
    assert d.max() <= 0.05
    D0 = c.derivatives(np.array([0.0]), 2)
    D1 = c.derivatives(np.array([1.0]), 2)
    np.testing.assert_allclose(D0, D1, atol=1e-9 * np.abs(D0).max())
    fewer = nurbs.fit_curve(pts, closed=True, tol=0.5)
    assert fewer.n_control < c.n_control


def test_fit_open_fixes_end_points_and_n_ctrl():
    pts = ellipse_points(50)[:30]
    c = nurbs.fit_curve(pts, n_ctrl=8)
    assert c.n_control == 8 and not c.closed
    np.testing.assert_array_equal(c.control_points[[0, -1]], pts[[0, -1]])
    np.testing.assert_allclose(c.evaluate([0.0, 1.0]), pts[[0, -1]], atol=1e-12)


def test_rational_fit_is_no_worse_than_polynomial():
    pts = ellipse_points(60)
    poly = nurbs.fit_curve(pts, closed=True, n_ctrl=8)
    rat = nurbs.fit_curve(pts, closed=True, n_ctrl=8, rational=True)
    params = nurbs.chord_length_parameters(pts, closed=True)
    rp = np.linalg.norm(poly.evaluate(params) - pts, axis=1)
    rr = np.linalg.norm(rat.evaluate(params) - pts, axis=1)
    assert (rr ** 2).sum() <= (rp ** 2).sum() * (1 + 1e-9)
    assert rat.is_rational


def test_rational_tol_fit_meets_tol_with_no_more_control_points():
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    r = 20 + 1.5 * np.exp(-((t - 2.0) / 0.15) ** 2)          # a sharp local bump
    pts = np.c_[r * np.cos(t), r * np.sin(t)]
    poly = nurbs.fit_curve(pts, closed=True, tol=0.2)
    rat = nurbs.fit_curve(pts, closed=True, tol=0.2, rational=True)
    assert rat.n_control < poly.n_control and rat.is_rational
    _, d = nurbs.closest_points(rat, pts)
    assert d.max() <= 0.2


def test_closed_curve_to_clamped_and_back_shape():
    c = nurbs.fit_curve(ellipse_points(), closed=True, n_ctrl=12)
    cc = c.to_clamped()
    u = np.linspace(0, 1, 301)
    assert not cc.closed
    np.testing.assert_allclose(cc.evaluate(u), c.evaluate(u), atol=1e-12)


# -------------------------------------------------------------- surfaces
def test_loft_passes_through_sections_and_collapses_at_apex():
    s = lv_like_surface()
    assert s.closed_u and s.collapsed_v() == (False, True)
    np.testing.assert_allclose(s.evaluate(np.linspace(0, 1, 9), [1.0])[:, 0],
                               np.tile([0.0, 0.0, 45.0], (9, 1)), atol=1e-12)
    sec0 = nurbs.fit_curve(ellipse_points(60, 25, 20, 0.0, 0.0), closed=True, tol=0.01)
    _, _, d = nurbs.closest_points(s, sec0.evaluate(np.linspace(0, 1, 40)))
    assert d.max() < 1e-9


def test_normals_unit_outward_and_finite_at_apex():
    s = lv_like_surface()
    u = np.linspace(0, 1, 16, endpoint=False)
    v = np.array([0.0, 0.3, 0.7, 0.999999, 1.0])
    n = s.normal(u, v)
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    # at the apex the normal is the limit of the normals next to it
    np.testing.assert_allclose(n[:, -1], n[:, -2], atol=1e-4)
    pts = s.evaluate(u, v[:3])
    radial = pts[..., :2] - pts[..., :2].mean(axis=0)
    assert np.all(np.einsum("abk,abk->ab", n[:, :3, :2], radial) > 0)   # away from the axis


def test_tessellate_shared_seam_apex_and_orientation():
    s = lv_like_surface()
    nu, nv = 40, 20
    V, F = nurbs.tessellate(s, nu, nv)
    assert V.shape == (nu * (nv - 1) + 1, 3)
    assert F.shape == (2 * nu * (nv - 1) - nu, 3)
    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert area.min() > 0
    # every interior edge is shared by exactly two faces, in opposite directions
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == len(edges)
    # only the v = 0 boundary is open: nu boundary edges
    undirected, counts = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
    assert np.count_nonzero(counts == 1) == nu
    # faces follow Su x Sv (outward)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(axis=1)
    assert np.all(np.einsum("fk,fk->f", fn[:, :2], centre[:, :2]) > 0)


def test_closest_points_match_dense_sampling():
    from scipy.spatial import cKDTree
    s = lv_like_surface()
    rng = np.random.default_rng(7)
    P = s.evaluate_points(rng.random(200), rng.random(200)) + rng.normal(scale=0.8, size=(200, 3))
    u, v, d = nurbs.closest_points(s, P)
    np.testing.assert_allclose(np.linalg.norm(s.evaluate_points(u, v) - P, axis=1), d, atol=1e-12)
    G = s.evaluate(np.linspace(0, 1, 600, endpoint=False), np.linspace(0, 1, 600)).reshape(-1, 3)
    dense, _ = cKDTree(G).query(P)
    assert np.all(d <= dense + 1e-9)
    assert np.all(dense - d < 0.2)          # grid spacing ~0.25 mm


def test_closest_points_accept_one_point():
    """A single (3,) point is one query point: (1,) results equal to the (1, 3) call."""
    s = lv_like_surface()
    q = s.evaluate_points([0.3], [0.6])[0] + [0.4, -0.2, 0.3]
    one = nurbs.closest_points(s, q)
    rows = nurbs.closest_points(s, q[None, :])
    assert len(one) == 3 and all(a.shape == (1,) for a in one)
    for a, b in zip(one, rows):
        np.testing.assert_array_equal(a, b)
    c = nurbs.fit_curve(np.c_[np.linspace(0, 10, 20), np.sin(np.linspace(0, 3, 20))], n_ctrl=6)
    u, d = nurbs.closest_points(c, [5.0, 2.0])
    assert u.shape == d.shape == (1,)
    np.testing.assert_allclose(d, np.linalg.norm(c.evaluate(u) - [5.0, 2.0], axis=1), atol=1e-12)
    for bad in ([1.0, 2.0], np.zeros((2, 2)), np.zeros((1, 2, 3))):
        with pytest.raises(NurbsInputError, match="points"):
            nurbs.closest_points(s, bad)


def test_surface_derivatives_match_finite_differences():
    s = lv_like_surface()
    u = np.array([0.1, 0.4, 0.77])
    v = np.array([0.2, 0.5, 0.8])
    D = s.derivatives(u, v, 2)
    h = 1e-5
    Su = (s.evaluate_points(u + h, v) - s.evaluate_points(u - h, v)) / (2 * h)
    Sv = (s.evaluate_points(u, v + h) - s.evaluate_points(u, v - h)) / (2 * h)
    np.testing.assert_allclose(D[:, 1, 0], Su, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(D[:, 0, 1], Sv, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(D[:, 0, 0], s.evaluate_points(u, v), atol=1e-12)


# --------------------------------------------------------- serialisation
@pytest.mark.parametrize("closed", [False, True])
def test_curve_dict_round_trip_is_lossless(closed):
    rng = np.random.default_rng(1)
    pts = ellipse_points(40) if closed else ellipse_points(40)[:25]
    c = nurbs.fit_curve(pts, closed=closed, n_ctrl=9, rational=True)
    back = nurbs.NurbsCurve.from_dict(json.loads(json.dumps(c.to_dict())))
    for a in ("knots", "control_points", "weights"):
        np.testing.assert_array_equal(getattr(back, a), getattr(c, a))
    assert back.closed == c.closed and back.degree == c.degree
    u = rng.random(20)
    np.testing.assert_array_equal(back.evaluate(u), c.evaluate(u))


def test_surface_dict_round_trip_is_lossless():
    s = lv_like_surface()
    back = nurbs.NurbsSurface.from_dict(json.loads(json.dumps(s.to_dict())))
    for a in ("knots_u", "knots_v", "control_points", "weights"):
        np.testing.assert_array_equal(getattr(back, a), getattr(s, a))
    assert back.closed_u and back.degree_v == s.degree_v


# ----------------------------------------------------------------- errors
@pytest.mark.parametrize("kwargs, word", [
    (dict(points=[[0, 0], [1, np.nan], [2, 0], [3, 1], [4, 0]]), "points"),
    (dict(points=[[0, 0], [1, np.inf], [2, 0], [3, 1], [4, 0]]), "points"),
    (dict(points=[[0, 0], [1, 1], [2, 0]]), "points"),
    (dict(points=[[1, 1]] * 6), "chord"),
    (dict(points=ellipse_points(20), tol=float("nan")), "tol"),
    (dict(points=ellipse_points(20), tol=-1.0), "tol"),
    (dict(points=ellipse_points(20), n_ctrl=25), "n_ctrl"),
    (dict(points=ellipse_points(20), degree=0), "degree"),
])
def test_fit_curve_rejects_bad_input(kwargs, word):
    with pytest.raises(NurbsInputError, match=word) as info:
        nurbs.fit_curve(**kwargs)
    assert isinstance(info.value, ValueError) and isinstance(info.value, CardioNurbsError)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("args, word", [
    ((3, [0, 0, 0, 0, .6, .4, 1, 1, 1, 1], np.zeros((6, 2))), "knots"),
    ((3, [0, 0, 0, 0, .5, 1, 1, 1, 1], np.zeros((6, 2))), "knots"),
    ((3, [0, 0, 0, 0, 1, 1, 1, 1], np.zeros((4, 2)), [1, 1, 0, 1]), "weights"),
    ((3, [0, 0, 0, 0, 1, 1, 1, 1], np.zeros((4, 2)), [1, 1, -2, 1]), "weights"),
    ((3, [0, 0, 0, 0, 1, 1, 1, 1], [[0, 0], [1, np.nan], [2, 0], [3, 0]]), "control_points"),
    ((3, [0, 0, 0, 1, 1, 1], np.zeros((2, 2))), "control_points"),
])
def test_curve_constructor_rejects_bad_input(args, word):
    with pytest.raises(NurbsInputError, match=word):
        nurbs.NurbsCurve(*args)


def test_other_bad_inputs_name_the_argument():
    c = nurbs.NurbsCurve(3, [0, 0, 0, 0, 1, 1, 1, 1], np.eye(4)[:, :2])
    with pytest.raises(NurbsInputError, match="u"):
        c.evaluate([0.5, 1.5])
    with pytest.raises(NurbsInputError, match="knots"):
        nurbs.insert_knots(c, [0.5, 0.5, 0.5, 0.5])
    with pytest.raises(NurbsInputError, match="sections"):
        nurbs.loft([c])
    with pytest.raises(NurbsInputError, match="nu"):
        nurbs.tessellate(lv_like_surface(), 1, 5)
    with pytest.raises(NurbsInputError, match="points"):
        nurbs.closest_points(c, [[np.nan, 0.0]])
