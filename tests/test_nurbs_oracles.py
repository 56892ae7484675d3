"""Cross-checks against geomdl and splipy (test-only oracles, never imported
by the package): evaluation, derivatives, knot insertion, lofting, and the
case where geomdl's degree elevation is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs import nurbs

geomdl = pytest.importorskip("geomdl")
splipy = pytest.importorskip("splipy")
from geomdl import NURBS as GNURBS  # noqa: E402
from geomdl import operations as gops  # noqa: E402

TOL = 1e-9


def random_curve(seed: int, p: int = 3, dim: int = 3, rational: bool = True) -> nurbs.NurbsCurve:
    rng = np.random.default_rng(seed)
    inner = np.sort(rng.uniform(0.05, 0.95, 5))
    inner = np.concatenate([inner[:2], [inner[2]] * min(2, p), inner[3:]])   # a double knot
    U = np.concatenate([np.zeros(p + 1), inner, np.ones(p + 1)])
    n = U.size - p - 1
    P = rng.uniform(-10, 10, (n, dim))
    w = rng.uniform(0.4, 2.5, n) if rational else None
    return nurbs.NurbsCurve(p, U, P, w)


def random_surface(seed: int, p: int = 3, q: int = 2) -> nurbs.NurbsSurface:
    rng = np.random.default_rng(seed)
    Ku = np.concatenate([np.zeros(p + 1), np.sort(rng.uniform(0.1, 0.9, 4)), np.ones(p + 1)])
    Kv = np.concatenate([np.zeros(q + 1), np.sort(rng.uniform(0.1, 0.9, 3)), np.ones(q + 1)])
    nu, nv = Ku.size - p - 1, Kv.size - q - 1
    return nurbs.NurbsSurface(p, q, Ku, Kv, rng.uniform(-5, 5, (nu, nv, 3)),
                              rng.uniform(0.5, 2.0, (nu, nv)))


def geomdl_curve(c: nurbs.NurbsCurve) -> "GNURBS.Curve":
    g = GNURBS.Curve()
    g.degree = c.degree
    g.ctrlpts = c.control_points.tolist()
    g.weights = c.weights.tolist()
    g.knotvector = c.knots.tolist()
    return g


def splipy_curve(c: nurbs.NurbsCurve) -> "splipy.Curve":
    basis = splipy.BSplineBasis(c.degree + 1, c.knots)
    cp = np.column_stack([c.control_points * c.weights[:, None], c.weights])
    return splipy.Curve(basis, cp, rational=True)


def scale_of(x: np.ndarray) -> float:
    return max(float(np.abs(x).max()), 1.0)


@pytest.mark.parametrize("seed", range(4))
def test_curve_evaluation_and_derivatives_match_geomdl(seed):
    c = random_curve(seed, p=2 + seed % 3)
    g = geomdl_curve(c)
    u = np.linspace(0, 1, 41)
    ref = np.array(g.evaluate_list(u.tolist()))
    np.testing.assert_allclose(c.evaluate(u), ref, atol=TOL * scale_of(ref), rtol=0)
    ours = c.derivatives(u, 2)
    for k, uk in enumerate(u):
        d = np.array(g.derivatives(float(uk), order=2))
        np.testing.assert_allclose(ours[k], d, atol=TOL * scale_of(d), rtol=0)


@pytest.mark.parametrize("seed", range(4))
def test_curve_evaluation_and_derivatives_match_splipy(seed):
    c = random_curve(seed, p=2 + seed % 3)
    s = splipy_curve(c)
    u = np.linspace(0, 1, 41)
    ref = s(u)
    np.testing.assert_allclose(c.evaluate(u), ref, atol=TOL * scale_of(ref), rtol=0)
    for order in (1, 2):
        ref_d = s.derivative(u, d=order)
        np.testing.assert_allclose(c.derivative(u, order), ref_d, atol=TOL * scale_of(ref_d), rtol=0)


@pytest.mark.parametrize("seed", range(3))
def test_knot_insertion_matches_geomdl_and_splipy(seed):
    c = random_curve(seed)
    xs = [0.3, 0.61, 0.61]
    ours = nurbs.insert_knots(c, xs)
    g = geomdl_curve(c)
    gops.insert_knot(g, [0.3], [1])
    gops.insert_knot(g, [0.61], [2])
    np.testing.assert_allclose(ours.knots, g.knotvector, atol=1e-15)
    np.testing.assert_allclose(ours.control_points, np.array(g.ctrlpts), atol=TOL * 10, rtol=0)
    np.testing.assert_allclose(ours.weights, g.weights, atol=TOL, rtol=0)
    s = splipy_curve(c)
    for x in xs:
        s.insert_knot(x)
    sp = np.asarray(s.controlpoints)
    np.testing.assert_allclose(ours.knots, s.knots(0, with_multiplicities=True), atol=1e-15)
    np.testing.assert_allclose(ours.weights, sp[:, -1], atol=TOL, rtol=0)
    np.testing.assert_allclose(ours.control_points, sp[:, :-1] / sp[:, -1:], atol=TOL * 10, rtol=0)


@pytest.mark.parametrize("seed", range(3))
def test_surface_evaluation_and_derivatives_match_geomdl_and_splipy(seed):
    srf = random_surface(seed)
    nu, nv = srf.control_points.shape[:2]
    g = GNURBS.Surface()
    g.degree_u, g.degree_v = srf.degree_u, srf.degree_v
    g.ctrlpts_size_u, g.ctrlpts_size_v = nu, nv
    g.ctrlpts = srf.control_points.reshape(-1, 3).tolist()       # v varies fastest
    g.weights = srf.weights.ravel().tolist()
    g.knotvector_u, g.knotvector_v = srf.knots_u.tolist(), srf.knots_v.tolist()
    u = np.linspace(0, 1, 9)
    v = np.linspace(0, 1, 7)
    grid = srf.evaluate(u, v)
    ref = np.array(g.evaluate_list([(a, b) for a in u for b in v])).reshape(9, 7, 3)
    np.testing.assert_allclose(grid, ref, atol=TOL * scale_of(ref), rtol=0)
    uu, vv = np.repeat(u, 7), np.tile(v, 9)
    D = srf.derivatives(uu, vv, 2)
    for k in range(0, uu.size, 5):
        d = np.array(g.derivatives(float(uu[k]), float(vv[k]), order=2))    # d[a][b]
        for a in range(3):
            for b in range(3 - a):
                np.testing.assert_allclose(D[k, a, b], d[a, b], atol=TOL * scale_of(d[a, b]), rtol=0)
    bu = splipy.BSplineBasis(srf.degree_u + 1, srf.knots_u)
    bv = splipy.BSplineBasis(srf.degree_v + 1, srf.knots_v)
    cp = np.concatenate([srf.control_points * srf.weights[..., None], srf.weights[..., None]], -1)
    s = splipy.Surface(bu, bv, cp.transpose(1, 0, 2).reshape(-1, 4), rational=True)
    np.testing.assert_allclose(grid, s(u, v), atol=TOL * scale_of(ref), rtol=0)
    for (a, b) in ((1, 0), (0, 1)):
        ref_d = s.derivative(u, v, d=(a, b))
        ours = srf.derivatives_grid(u, v, 1)[:, :, a, b]
        np.testing.assert_allclose(ours, ref_d, atol=TOL * scale_of(ref_d), rtol=0)


def test_loft_matches_splipy_on_matching_inputs():
    """4 translated copies of one section: the paper's v parameters equal
    splipy's centre-distance parameters and both use one cubic Bezier span in v."""
    base = random_curve(11, p=3, rational=True)
    offsets = np.array([[0, 0, 0], [1.0, 0.5, 7.0], [1.5, 0.7, 16.0], [3.0, 1.0, 21.0]])
    sections = [nurbs.NurbsCurve(3, base.knots, base.control_points + o, base.weights)
                for o in offsets]
    ours = nurbs.loft(sections, degree_v=3)
    sp = [splipy_curve(c) for c in sections]
    from splipy import surface_factory
    ref = surface_factory.loft(sp)
    L = float(ref.end("v"))
    u = np.linspace(0, 1, 13)
    v = np.linspace(0, 1, 11)
    ref_grid = ref(u, v * L)
    np.testing.assert_allclose(ours.evaluate(u, v), ref_grid, atol=TOL * scale_of(ref_grid), rtol=0)


def test_geomdl_degree_elevation_is_wrong_with_interior_knots_and_ours_is_right():
    rng = np.random.default_rng(5)
    U = [0, 0, 0, 0, 0.3, 0.6, 1, 1, 1, 1]          # cubic with two interior knots
    P = rng.uniform(-5, 5, (6, 2))
    c = nurbs.NurbsCurve(3, U, P)
    u = np.linspace(0, 1, 201)
    g = GNURBS.Curve()
    g.degree, g.ctrlpts, g.weights, g.knotvector = 3, P.tolist(), [1.0] * 6, U
    gops.degree_operations(g, [1])
    g_err = np.abs(np.array(g.evaluate_list(u.tolist())) - c.evaluate(u)).max()
    ours = nurbs.elevate_degree(c, 1)
    our_err = np.abs(ours.evaluate(u) - c.evaluate(u)).max()
    assert g_err > 1e-3             # geomdl changes the shape
    assert our_err < 1e-12          # ours does not
    assert ours.degree == 4 and ours.n_control == 6 + 3
    # every interior knot gains one multiplicity: still C^2 there
    np.testing.assert_allclose(ours.knots, [0] * 5 + [0.3] * 2 + [0.6] * 2 + [1] * 5)
