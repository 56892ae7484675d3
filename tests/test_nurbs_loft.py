"""Lofting (paper §3.2.4): orientation, seam alignment, apex at either end,
open sections, mixed degrees, degree across sections."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs import nurbs


def ring(z: float, r: float, phase: float = 0.0, reverse: bool = False, m: int = 48,
         degree: int = 3, n_ctrl: int = 10) -> nurbs.NurbsCurve:
    t = np.linspace(0, 2 * np.pi, m, endpoint=False) + phase
    if reverse:
        t = t[::-1]
    pts = np.c_[r * np.cos(t) + 0.1 * r * np.cos(2 * t), 0.8 * r * np.sin(t), np.full(m, z)]
    return nurbs.fit_curve(pts, degree=degree, closed=True, n_ctrl=n_ctrl)


def seam_angles(s: nurbs.NurbsSurface, n: int = 9) -> np.ndarray:
    P = s.evaluate([0.0], np.linspace(0, 1, n))[0]
    return np.unwrap(np.arctan2(P[:, 1] / 0.8, P[:, 0]))


def test_seams_aligned_and_orientation_unified():
    rng = np.random.default_rng(0)
    secs = [ring(10.0 * k, 25 - 2 * k, phase=rng.uniform(0, 2 * np.pi), reverse=bool(k % 2))
            for k in range(5)]
    s = nurbs.loft(secs)
    ang = seam_angles(s, 5 * 4 + 1)
    assert np.ptp(ang) < np.deg2rad(3.0)           # the seam runs straight up: no twist
    # all sections counter-clockwise about the loft axis (+z): Su x Sv points outward
    u = np.linspace(0, 1, 12, endpoint=False)
    v = np.linspace(0.05, 0.95, 7)
    n = s.normal(u, v)
    P = s.evaluate(u, v)
    assert np.all(np.einsum("abk,abk->ab", n[..., :2], P[..., :2]) > 0)
    # the surface passes through every section
    for c in secs:
        _, _, d = nurbs.closest_points(s, c.evaluate(np.linspace(0, 1, 30)))
        assert d.max() < 1e-8


def test_shared_uniform_knots_stay_shared():
    rng = np.random.default_rng(1)
    secs = []
    for k in range(5):
        t = np.linspace(0, 2 * np.pi, 48, endpoint=False) + rng.uniform(0, 2 * np.pi)
        if k % 2:
            t = t[::-1]
        pts = np.c_[(20 - 2 * k) * np.cos(t), (16 - 2 * k) * np.sin(t), np.full(48, 8.0 * k)]
        secs.append(nurbs.fit_curve(pts, closed=True, n_ctrl=12, knot_rule="uniform"))
    s = nurbs.loft(secs + [np.array([0.0, 0.0, 50.0])])
    assert s.control_points.shape[:2] == (12, 6)          # no knot merging
    P = s.evaluate([0.0], np.linspace(0, 1, 9))[0][:-1]
    ang = np.unwrap(np.arctan2(P[:, 1] / 0.8, P[:, 0]))
    assert np.ptp(ang) < 2 * np.pi / 12 * 1.5             # within about a knot span
    for c in secs:
        _, _, d = nurbs.closest_points(s, c.evaluate(np.linspace(0, 1, 30)))
        assert d.max() < 1e-8
    # align=False keeps the sections as given (here: mixed orientations -> a twisted surface)
    raw = nurbs.loft(secs, align=False)
    assert raw.control_points.shape[:2] == (12, 5)


def test_apex_first_section():
    secs = [np.array([0.0, 0.0, -20.0])] + [ring(10.0 * k, 10 + 5 * k) for k in range(3)]
    s = nurbs.loft(secs)
    assert s.collapsed_v() == (True, False)
    np.testing.assert_allclose(s.evaluate(np.linspace(0, 1, 5), [0.0])[:, 0],
                               np.tile([0.0, 0.0, -20.0], (5, 1)), atol=1e-12)
    n = s.normal(np.linspace(0, 1, 8, endpoint=False), [0.0, 1e-7])
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(n[:, 0], n[:, 1], atol=1e-5)     # the limit normal
    assert np.all(n[:, 0, 2] < 0)                                  # away from the surface, down
    V, F = nurbs.tessellate(s, 24, 10)
    assert V.shape[0] == 24 * 9 + 1
    assert np.count_nonzero(np.all(np.isclose(V, [0, 0, -20.0]), axis=1)) == 1
    tri = V[F]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert area.min() > 0


def test_apex_at_both_ends_closes_the_surface():
    import trimesh
    secs = ([np.array([0.0, 0.0, -12.0])] + [ring(10.0 * k, 14 - 2 * k) for k in range(3)]
            + [np.array([0.0, 0.0, 32.0])])
    s = nurbs.loft(secs)
    assert s.collapsed_v() == (True, True)
    V, F = nurbs.tessellate(s, 40, 30)
    mesh = trimesh.Trimesh(V, F, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0                      # faces point outward


def test_open_sections_are_paired_end_to_end():
    t = np.linspace(0.2, np.pi - 0.2, 30)
    arcs = []
    for k in range(4):
        pts = np.c_[20 * np.cos(t), 20 * np.sin(t), np.full(t.size, 8.0 * k)]
        arcs.append(nurbs.fit_curve(pts[::-1] if k == 2 else pts, n_ctrl=7))
    s = nurbs.loft(arcs)
    assert not s.closed_u
    start = s.evaluate([0.0], np.linspace(0, 1, 7))[0]
    np.testing.assert_allclose(start[:, :2], np.tile(start[0, :2], (7, 1)), atol=1e-6)


def test_mixed_degrees_are_elevated_and_sections_interpolated():
    secs = [ring(0.0, 20, degree=2, n_ctrl=9), ring(10.0, 18, degree=3), ring(20.0, 15, degree=4)]
    s = nurbs.loft(secs, degree_v=3)
    assert s.degree_u == 4 and s.degree_v == 2             # q = min(degree_v, K) = 2
    for c in secs:
        _, _, d = nurbs.closest_points(s, c.evaluate(np.linspace(0, 1, 25)))
        assert d.max() < 1e-8


def test_two_sections_give_a_ruled_surface():
    s = nurbs.loft([ring(0.0, 20), ring(10.0, 10)])
    assert s.degree_v == 1
    P = s.evaluate([0.3], np.linspace(0, 1, 5))[0]
    # points on a v line are collinear
    d = P - P[0]
    assert np.linalg.matrix_rank(d, tol=1e-9 * np.abs(d).max()) == 1


def test_section_parameters_follow_the_paper_formula():
    from cardionurbs.nurbs.loft import section_parameters
    P = np.zeros((3, 4, 3))
    P[1] += [0, 0, 1.0]
    P[2] += [0, 0, 4.0]
    P[2, 0] += [3.0, 0, 0]          # one column moves further
    d = np.linalg.norm(np.diff(P, axis=0), axis=-1)
    expected = np.concatenate([[0], np.cumsum((d / d.sum(axis=0)).mean(axis=1))])
    np.testing.assert_allclose(section_parameters(P), expected)


@pytest.mark.parametrize("sections, word", [
    ([ring(0, 10), np.zeros(3), ring(5, 10)], "sections"),
    ([ring(0, 10), nurbs.fit_curve(np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)], n_ctrl=4)],
     "open and closed"),
    ([ring(0, 10), ring(0, 10)], "coincide"),
    ([np.zeros(3), np.ones(3)], "curve"),
])
def test_bad_sections(sections, word):
    with pytest.raises(nurbs.NurbsInputError, match=word):
        nurbs.loft(sections)


# ------------------------------------------------ loft_compatible (steps 4-5)
def uniform_rings(weights: bool = False) -> list[nurbs.NurbsCurve]:
    """Closed sections on one uniform periodic knot vector, already aligned."""
    rng = np.random.default_rng(7)
    out = []
    for k in range(4):
        t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
        pts = np.c_[(18 - 3 * k) * np.cos(t), (14 - 2 * k) * np.sin(t), np.full(40, 7.0 * k)]
        c = nurbs.fit_curve(pts, closed=True, n_ctrl=10, knot_rule="uniform")
        if weights:
            c = nurbs.NurbsCurve(c.degree, c.knots, c.control_points,
                                 rng.uniform(0.9, 1.1, c.n_control), closed=True)
        out.append(c)
    return out


@pytest.mark.parametrize("rational", [False, True])
@pytest.mark.parametrize("apex", [None, "end", "both"])
@pytest.mark.parametrize("degree_v", [1, 2, 3])
def test_loft_compatible_equals_loft(rational, apex, degree_v):
    secs = uniform_rings(weights=rational)
    start = np.array([0.0, 0.0, -9.0]) if apex == "both" else None
    end = np.array([0.0, 0.0, 30.0]) if apex else None
    items = ([start] if start is not None else []) + secs + ([end] if end is not None else [])
    ref = nurbs.loft(items, degree_v=degree_v, align=False)
    s = nurbs.loft_compatible(np.stack([c.control_points for c in secs]), secs[0].knots,
                              secs[0].degree, degree_v,
                              weights=np.stack([c.weights for c in secs]) if rational else None,
                              closed_u=True, start_point=start, end_point=end)
    assert s.closed_u and s.degree_v == min(degree_v, len(items) - 1)
    np.testing.assert_allclose(s.knots_v, ref.knots_v, rtol=0, atol=1e-12)
    t = np.linspace(0, 1, 31)
    np.testing.assert_allclose(s.evaluate(t, t), ref.evaluate(t, t), rtol=0, atol=1e-9)
    # the collapsed rows are the points (exactly when non-rational; w P / w when rational)
    tol = 1e-12 if rational else 0.0
    for row, pt in ((-1, end), (0, start)):
        if pt is not None:
            np.testing.assert_allclose(s.control_points[:, row], np.tile(pt, (10, 1)), rtol=0,
                                       atol=tol)


def test_loft_compatible_open_sections_equal_loft():
    t = np.linspace(0.0, 1.0, 25)
    secs = [nurbs.fit_curve(np.c_[30 * t, 5 * np.sin(3 * t + k), np.full(25, 4.0 * k + k * k)],
                            n_ctrl=7, knot_rule="uniform") for k in range(5)]
    ref = nurbs.loft(secs)
    s = nurbs.loft_compatible(np.stack([c.control_points for c in secs]), secs[0].knots)
    assert not s.closed_u and np.array_equal(s.weights, np.ones_like(s.weights))
    g = np.linspace(0, 1, 29)
    np.testing.assert_allclose(s.evaluate(g, g), ref.evaluate(g, g), rtol=0, atol=1e-9)
    for k, c in enumerate(secs):     # interpolates the sections at the section parameters
        _, _, d = nurbs.closest_points(s, c.evaluate(np.linspace(0, 1, 20)))
        assert d.max() < 1e-8


@pytest.mark.parametrize("kwargs, word", [
    (dict(control_points=np.zeros((1, 6, 3))), "at least 2 sections"),
    (dict(control_points=np.zeros((6, 3))), "control_points"),
    (dict(weights=np.ones((3, 5))), "weights"),
    (dict(end_point=np.zeros(2)), "end_point"),
    (dict(degree_v=0), "degree_v"),
])
def test_loft_compatible_bad_input(kwargs, word):
    t = np.linspace(0, 1, 12)
    secs = [nurbs.fit_curve(np.c_[t, np.sin(t + k), np.full(12, float(k))], n_ctrl=6,
                            knot_rule="uniform") for k in range(3)]
    args = dict(control_points=np.stack([c.control_points for c in secs]), knots_u=secs[0].knots)
    args.update(kwargs)
    with pytest.raises(nurbs.NurbsInputError, match=word):
        nurbs.loft_compatible(**args)
