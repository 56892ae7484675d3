"""nurbs.fit_compatible_curves: sections on one knot vector, within a tolerance (paper §3.2.4)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cardionurbs import nurbs
from cardionurbs.errors import NurbsInputError
from cardionurbs.nurbs.fitting import max_distance


def _sections(k: int, m: int = 120, wobble: float = 0.0) -> list[np.ndarray]:
    t = np.linspace(0, 2 * np.pi, m, endpoint=False)
    return [np.column_stack([(30 - 2 * s) * np.cos(t), (20 - s) * np.sin(t) + wobble * np.sin(5 * t),
                             np.full(m, 8.0 * s)]) for s in range(k)]


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 6), st.floats(0.0, 3.0), st.floats(0.05, 1.0))
@example(6, 1.0, 0.1211)    # the first section passed at a count a later section raised past it
def test_shared_knots_and_tolerance_hold(k, wobble, tol):
    secs = _sections(k, wobble=wobble)
    fit = nurbs.fit_compatible_curves(secs, closed=True, tol=tol)
    assert fit.met
    U = fit.curves[0].knots
    for c, q in zip(fit.curves, secs):
        assert np.array_equal(c.knots, U) and c.n_control == fit.n_ctrl and c.closed
        assert max_distance(c, q) <= tol + 1e-12
    assert fit.max_error <= tol
    # the fewest control points: one fewer misses the tolerance on some section
    if fit.n_ctrl > 4:
        fewer = nurbs.fit_compatible_curves(secs, closed=True, tol=tol,
                                            counts=[fit.n_ctrl - 1])
        assert not fewer.met


def test_sections_loft_on_their_shared_knots():
    """Compatible as they come: the loft needs no knot merging, and its end sections
    are the first and last curves."""
    secs = _sections(4, wobble=1.0)
    fit = nurbs.fit_compatible_curves(secs, closed=True, tol=0.1)
    c0 = fit.curves[0]
    surf = nurbs.loft_compatible(np.stack([c.control_points for c in fit.curves]), c0.knots,
                                 3, 3, closed_u=True)
    u = np.linspace(*c0.domain, 50, endpoint=False)
    lo, hi = surf.knots_v[0], surf.knots_v[-1]
    assert np.allclose(surf.evaluate(u, np.array([lo]))[:, 0], c0.evaluate(u), atol=1e-9)
    assert np.allclose(surf.evaluate(u, np.array([hi]))[:, 0], fit.curves[-1].evaluate(u), atol=1e-9)


def test_error_points_and_unjudged_sections():
    secs = _sections(3, wobble=2.0)
    noisy = [q + np.random.default_rng(1).normal(scale=0.05, size=q.shape) for q in secs]
    fit = nurbs.fit_compatible_curves(secs, closed=True, tol=[0.5, 0.5, 1e-9],
                                      error_points=[noisy[0], noisy[1], None], counts=(8, 12, 16))
    assert fit.met and fit.n_ctrl in (8, 12, 16)
    fit = nurbs.fit_compatible_curves(secs, closed=True, tol=1e-6, counts=(8, 12))
    assert not fit.met and fit.n_ctrl == 12 and fit.max_error > 1e-6


def test_open_sections_keep_their_ends():
    x = np.linspace(0, 10, 40)
    secs = [np.column_stack([x, np.sin(x) * (1 + s), np.full_like(x, s)]) for s in range(3)]
    fit = nurbs.fit_compatible_curves(secs, closed=False, tol=0.05)
    for c, q in zip(fit.curves, secs):
        assert np.allclose(c.control_points[0], q[0]) and np.allclose(c.control_points[-1], q[-1])


@pytest.mark.parametrize("kwargs, word", [
    (dict(point_sets=[np.zeros((10, 3)), np.zeros((11, 3))]), "same number of points"),
    (dict(point_sets=[]), "at least one section"),
    (dict(point_sets=[np.random.default_rng(0).normal(size=(10, 2))], tol=-1), "tol"),
    (dict(point_sets=[np.random.default_rng(0).normal(size=(10, 2))], counts=[2]), "counts"),
    (dict(point_sets=[np.random.default_rng(0).normal(size=(10, 2))], knot_rule="x"), "knot_rule"),
])
def test_bad_input_is_one_line(kwargs, word):
    with pytest.raises(NurbsInputError, match=word):
        nurbs.fit_compatible_curves(**kwargs)
