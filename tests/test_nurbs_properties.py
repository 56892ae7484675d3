"""Property tests (hypothesis) of the NURBS core: basis, knot insertion,
degree elevation, reversal, periodic continuity, exact conics."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cardionurbs import nurbs
from cardionurbs.nurbs.basis import basis_matrix
from cardionurbs.nurbs.knots import periodic_knot_vector

SETTINGS = settings(max_examples=30, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


@st.composite
def open_curves(draw, max_degree: int = 5, dim: int = 3, rational: bool = True):
    """Random clamped NURBS curves with (possibly repeated) interior knots."""
    p = draw(st.integers(1, max_degree))
    n_spans = draw(st.integers(1, 6))
    breaks = np.sort(draw(st.lists(st.floats(0.02, 0.98), min_size=n_spans - 1,
                                   max_size=n_spans - 1, unique=True)))
    breaks = breaks[np.concatenate([[True], np.diff(breaks) > 0.01])] if breaks.size else breaks
    mults = [draw(st.integers(1, p)) for _ in breaks]
    inner = np.repeat(breaks, mults)
    U = np.concatenate([np.zeros(p + 1), inner, np.ones(p + 1)])
    n = U.size - p - 1
    seed = draw(st.integers(0, 2 ** 31))
    rng = np.random.default_rng(seed)
    P = rng.uniform(-10, 10, size=(n, dim))
    w = rng.uniform(0.3, 3.0, n) if rational and draw(st.booleans()) else None
    return nurbs.NurbsCurve(p, U, P, w)


@st.composite
def closed_curves(draw, max_degree: int = 4, dim: int = 3):
    """Random periodic NURBS curves (simple or repeated knots below the degree)."""
    p = draw(st.integers(1, max_degree))
    n = draw(st.integers(p + 1, p + 8))
    seed = draw(st.integers(0, 2 ** 31))
    rng = np.random.default_rng(seed)
    gaps = rng.uniform(0.3, 1.0, n)
    B = np.concatenate([[0.0], np.cumsum(gaps) / gaps.sum()])
    if draw(st.booleans()) and p >= 2 and n >= 3:   # one double knot
        k = int(rng.integers(1, n - 1))
        B[k + 1] = B[k]
        B = np.sort(B)
    B[-1] = 1.0
    U = periodic_knot_vector(B, p)
    P = rng.uniform(-10, 10, size=(n, dim))
    w = rng.uniform(0.3, 3.0, n) if draw(st.booleans()) else None
    return nurbs.NurbsCurve(p, U, P, w, closed=True)


def _scale(c: nurbs.NurbsCurve) -> float:
    return float(np.abs(c.control_points).max())


U_SAMPLES = np.linspace(0.0, 1.0, 157)


# ----------------------------------------------------------------- basis
@SETTINGS
@given(open_curves(), st.lists(st.floats(0, 1), min_size=1, max_size=40))
def test_basis_partition_of_unity_and_non_negative(c, us):
    B = basis_matrix(c.knots, c.degree, np.array(us))
    assert np.all(B >= -1e-15)
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-13)


@SETTINGS
@given(closed_curves(), st.lists(st.floats(0, 1), min_size=1, max_size=40))
def test_periodic_basis_partition_of_unity(c, us):
    B = basis_matrix(c.knots, c.degree, np.array(us), n_periodic=c.n_control)
    assert np.all(B >= -1e-15)
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-13)


@SETTINGS
@given(open_curves())
def test_open_curve_interpolates_end_control_points(c):
    np.testing.assert_allclose(c.evaluate([0.0, 1.0]), c.control_points[[0, -1]],
                               atol=1e-12 * _scale(c))


# ----------------------------------------------------- knot insertion
@SETTINGS
@given(open_curves(), st.lists(st.floats(0.001, 0.999), min_size=1, max_size=6))
def test_knot_insertion_keeps_shape_open(c, xs):
    # keep every multiplicity <= degree
    xs = [x for x in xs if np.count_nonzero(np.isclose(c.knots, x, atol=1e-12)) == 0]
    if not xs:
        xs = [0.5 if np.count_nonzero(c.knots == 0.5) < c.degree else 0.123456]
    xs = np.unique(xs)
    k = nurbs.insert_knots(c, xs)
    assert k.n_control == c.n_control + xs.size
    np.testing.assert_allclose(k.evaluate(U_SAMPLES), c.evaluate(U_SAMPLES),
                               atol=1e-9 * _scale(c), rtol=0)


@SETTINGS
@given(closed_curves(), st.lists(st.floats(0.0, 0.999), min_size=1, max_size=5))
def test_knot_insertion_keeps_shape_periodic(c, xs):
    period = c.knots[c.degree:c.knots.size - c.degree - 1]
    xs = np.unique([x for x in xs if not np.any(np.isclose(period, x, atol=1e-9))])
    if xs.size == 0:
        return
    k = nurbs.insert_knots(c, xs)
    assert k.closed and k.n_control == c.n_control + xs.size
    np.testing.assert_allclose(k.evaluate(U_SAMPLES), c.evaluate(U_SAMPLES),
                               atol=1e-9 * _scale(c), rtol=0)


# ---------------------------------------------------- degree elevation
@SETTINGS
@given(open_curves(max_degree=4), st.integers(1, 3))
def test_degree_elevation_keeps_shape_open(c, t):
    e = nurbs.elevate_degree(c, t)
    assert e.degree == c.degree + t
    n_distinct_inner = np.unique(c.knots[c.degree + 1:-c.degree - 1]).size
    assert e.n_control == c.n_control + t * (n_distinct_inner + 1)
    np.testing.assert_allclose(e.evaluate(U_SAMPLES), c.evaluate(U_SAMPLES),
                               atol=1e-9 * _scale(c), rtol=0)
    np.testing.assert_allclose(e.derivative(U_SAMPLES[1:-1:7], 1),
                               c.derivative(U_SAMPLES[1:-1:7], 1),
                               atol=1e-7 * np.abs(c.derivative(U_SAMPLES, 1)).max(), rtol=0)


@SETTINGS
@given(closed_curves(max_degree=3), st.integers(1, 2))
def test_degree_elevation_keeps_shape_periodic(c, t):
    e = nurbs.elevate_degree(c, t)
    assert e.closed and e.degree == c.degree + t
    np.testing.assert_allclose(e.evaluate(U_SAMPLES), c.evaluate(U_SAMPLES),
                               atol=1e-9 * _scale(c), rtol=0)


@SETTINGS
@given(closed_curves())
def test_periodic_curve_seam_continuity(c):
    # C^(p - m) at the seam knot of multiplicity m (C^(p-1) for a simple seam knot)
    m = int(np.count_nonzero(np.abs(c.knots[c.degree:c.knots.size - c.degree - 1]) < 1e-12))
    order = c.degree - m
    if order < 0:
        return
    a = c.derivatives(np.array([0.0]), order)[0]
    b = c.derivatives(np.array([1.0]), order)[0]
    for r in range(order + 1):
        scale = max(np.abs(c.derivatives(U_SAMPLES, order)[:, r]).max(), 1.0)
        np.testing.assert_allclose(a[r], b[r], atol=1e-9 * scale, rtol=0)


@SETTINGS
@given(closed_curves(), st.floats(0.0, 1.0))
def test_seam_rotation_and_clamping_are_exact(c, s):
    r = nurbs.rotate_seam(c, s)
    np.testing.assert_allclose(r.evaluate(U_SAMPLES), c.evaluate((U_SAMPLES + s) % 1.0),
                               atol=1e-9 * _scale(c), rtol=0)
    cl = c.to_clamped()
    np.testing.assert_allclose(cl.evaluate(U_SAMPLES), c.evaluate(U_SAMPLES),
                               atol=1e-9 * _scale(c), rtol=0)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(open_curves(max_degree=4), min_size=2, max_size=4))
def test_make_compatible_gives_one_degree_and_knot_vector(curves):
    out = nurbs.make_compatible(curves)
    assert len({c.degree for c in out}) == 1
    assert out[0].degree == max(c.degree for c in curves)
    for c in out[1:]:
        np.testing.assert_array_equal(c.knots, out[0].knots)
    for a, b in zip(curves, out):
        np.testing.assert_allclose(b.evaluate(U_SAMPLES), a.evaluate(U_SAMPLES),
                                   atol=1e-9 * _scale(a), rtol=0)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(closed_curves(max_degree=3), min_size=2, max_size=3))
def test_make_compatible_periodic(curves):
    out = nurbs.make_compatible(curves)
    for c in out[1:]:
        np.testing.assert_array_equal(c.knots, out[0].knots)
    for a, b in zip(curves, out):
        assert b.closed
        np.testing.assert_allclose(b.evaluate(U_SAMPLES), a.evaluate(U_SAMPLES),
                                   atol=1e-9 * _scale(a), rtol=0)


# ----------------------------------------------------------- fitting
@st.composite
def point_sets(draw, closed: bool):
    m = draw(st.integers(12, 60))
    seed = draw(st.integers(0, 2 ** 31))
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, m, endpoint=not closed)
    if not closed:
        t = t * draw(st.floats(0.3, 0.9))
    r = 20 + rng.normal(scale=0.1, size=m)          # a smooth contour with pixel-like noise
    pts = np.c_[r * np.cos(t), 0.7 * r * np.sin(t), rng.normal(scale=0.1, size=m)]
    return pts


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(point_sets(closed=False), st.integers(2, 4), st.sampled_from([None, 0.3]))
def test_reversed_data_give_reversed_curve_open(pts, p, tol):
    a = nurbs.fit_curve(pts, degree=p, tol=tol, n_ctrl=None if tol else min(8, len(pts)))
    b = nurbs.fit_curve(pts[::-1], degree=p, tol=tol, n_ctrl=None if tol else min(8, len(pts)))
    assert a.n_control == b.n_control
    np.testing.assert_allclose(b.evaluate(U_SAMPLES), a.evaluate(1.0 - U_SAMPLES),
                               atol=1e-9 * np.abs(pts).max(), rtol=0)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(point_sets(closed=True), st.integers(2, 4), st.sampled_from([None, 0.3]))
def test_reversed_data_give_reversed_curve_closed(pts, p, tol):
    rev = np.concatenate([pts[:1], pts[:0:-1]])          # same start point, backwards
    kw = dict(degree=p, closed=True, tol=tol, n_ctrl=None if tol else 9)
    a = nurbs.fit_curve(pts, **kw)
    b = nurbs.fit_curve(rev, **kw)
    assert a.n_control == b.n_control
    np.testing.assert_allclose(b.evaluate(U_SAMPLES), a.evaluate((1.0 - U_SAMPLES) % 1.0),
                               atol=1e-9 * np.abs(pts).max(), rtol=0)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(point_sets(closed=True), st.integers(2, 5))
def test_periodic_fit_is_continuous_across_seam(pts, p):
    c = nurbs.fit_curve(pts, degree=p, closed=True, tol=0.5)
    a = c.derivatives(np.array([0.0]), p - 1)[0]
    b = c.derivatives(np.array([1.0]), p - 1)[0]
    scale = np.abs(c.derivatives(U_SAMPLES, p - 1)).max(axis=0)
    assert np.all(np.abs(a - b) <= 1e-9 * np.maximum(scale, 1.0))
    _, d = nurbs.closest_points(c, pts)
    assert d.max() <= 0.5


# --------------------------------------------------------- exact conics
def rational_circle(radius: float = 1.0, centre=(0.0, 0.0)) -> nurbs.NurbsCurve:
    """The 9-point rational quadratic circle (NURBS Book Ex. 7.2)."""
    s = np.sqrt(0.5)
    P = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [1, 0]],
                 float) * radius + np.asarray(centre)
    w = np.array([1, s, 1, s, 1, s, 1, s, 1])
    U = [0, 0, 0, .25, .25, .5, .5, .75, .75, 1, 1, 1]
    return nurbs.NurbsCurve(2, U, P, w)


@SETTINGS
@given(st.floats(0.01, 1e3), st.floats(-100, 100), st.floats(-100, 100))
def test_rational_quadratic_circle_is_exact(r, cx, cy):
    c = rational_circle(r, (cx, cy))
    u = np.linspace(0, 1, 1001)
    scale = max(r, abs(cx), abs(cy))            # rounding is relative to the coordinates
    d = np.linalg.norm(c.evaluate(u) - [cx, cy], axis=1)
    np.testing.assert_allclose(d, r, rtol=0, atol=1e-12 * scale)
    # still a circle after degree elevation and knot insertion
    e = nurbs.insert_knots(nurbs.elevate_degree(c, 2), [0.1, 0.6])
    np.testing.assert_allclose(np.linalg.norm(e.evaluate(u) - [cx, cy], axis=1), r,
                               rtol=0, atol=1e-12 * scale)
    # tangent is perpendicular to the radius
    t = c.derivative(u[1:-1:10], 1)
    rad = c.evaluate(u[1:-1:10]) - [cx, cy]
    cosang = np.einsum("kd,kd->k", t, rad) / (np.linalg.norm(t, axis=1) * r)
    assert np.abs(cosang).max() < 1e-12 * scale / r
