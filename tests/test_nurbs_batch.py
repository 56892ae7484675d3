"""Many splines at once: per-row knot vectors in A2.1/A2.3 and the batched
curve/surface evaluators of :mod:`cardionurbs.nurbs.batch`."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import nurbs
from cardionurbs.nurbs.basis import basis_function_derivatives, find_spans


def random_knots(rng: np.random.Generator, p: int, n: int, lo: float = 0.0,
                 hi: float = 1.0) -> np.ndarray:
    inner = np.sort(rng.uniform(lo, hi, n - p - 1))
    return np.r_[np.full(p + 1, lo), inner, np.full(p + 1, hi)]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), p=st.integers(1, 5), nd=st.integers(0, 4))
def test_per_row_knots_equal_one_knot_vector_per_row(seed, p, nd):
    """(k, m) knots give, row by row, exactly the 1-d result for that row's vector,
    also for vectors padded by repeating their last knot."""
    rng = np.random.default_rng(seed)
    vecs = [random_knots(rng, p, int(rng.integers(p + 1, p + 8))) for _ in range(6)]
    m = max(len(U) for U in vecs)
    rows = rng.integers(0, len(vecs), 40)
    u = np.r_[rng.uniform(-0.05, 1.05, 34), 0.0, 1.0, vecs[rows[36]][p + 1:p + 2], 0.5, 0.25, 1.0]
    K = np.array([np.r_[vecs[r], np.full(m - len(vecs[r]), vecs[r][-1])] for r in rows])
    spans = find_spans(K, p, u)
    D = basis_function_derivatives(spans, u, p, K, nd)
    for i, r in enumerate(rows):
        s1 = find_spans(vecs[r], p, u[i:i + 1])
        assert spans[i] == s1[0]
        np.testing.assert_array_equal(D[i], basis_function_derivatives(s1, u[i:i + 1], p,
                                                                       vecs[r], nd)[0])


def test_per_row_knots_need_one_row_per_parameter():
    K = np.tile([0, 0, 1, 1.0], (3, 1))
    with pytest.raises(nurbs.NurbsInputError, match="knots"):
        basis_function_derivatives(np.ones(2, int), np.zeros(2), 1, K, 1)


def random_surfaces(rng: np.random.Generator) -> list[nurbs.NurbsSurface]:
    out = []
    for i in range(7):
        p, q = (3, 3) if i < 4 else (2, int(rng.integers(1, 4)))
        nu, nv = int(rng.integers(p + 1, p + 5)), int(rng.integers(q + 1, q + 4))
        lo, hi = (0.0, 1.0) if i % 3 else (-2.0, 5.0)           # also other domains
        P = rng.normal(size=(nu, nv, 3)) * 10
        w = rng.uniform(0.5, 2.0, (nu, nv)) if i % 2 else None
        out.append(nurbs.NurbsSurface(p, q, random_knots(rng, p, nu, lo, hi),
                                      random_knots(rng, q, nv), P, w))
    return out


def test_surface_batch_equals_nurbs_surface_derivatives():
    rng = np.random.default_rng(3)
    surfs = random_surfaces(rng)
    sid = rng.integers(0, len(surfs), 500)
    u = np.array([rng.uniform(*surfs[k].domain_u) for k in sid])
    v = rng.uniform(0, 1, 500)
    S, Su, Sv = nurbs.SurfaceBatch(surfs).derivatives(sid, u, v)
    for k, s in enumerate(surfs):
        m = sid == k
        D = s.derivatives(u[m], v[m], 1)
        np.testing.assert_allclose(S[m], D[:, 0, 0], rtol=0, atol=1e-10)
        np.testing.assert_allclose(Su[m], D[:, 1, 0], rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(Sv[m], D[:, 0, 1], rtol=1e-10, atol=1e-9)


def test_surface_batch_extends_linearly_outside_the_domain():
    rng = np.random.default_rng(4)
    surfs = random_surfaces(rng)
    k = np.arange(len(surfs))
    lo = np.array([s.domain_u[0] for s in surfs])
    hi = np.array([s.domain_u[1] for s in surfs])
    batch = nurbs.SurfaceBatch(surfs)
    S0, Su0, Sv0 = batch.derivatives(k, hi, np.zeros(len(k)))
    S, Su, Sv = batch.derivatives(k, hi + 0.1, np.full(len(k), -0.2))
    np.testing.assert_allclose(S, S0 + 0.1 * Su0 - 0.2 * Sv0, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(Su, Su0)
    S1, _, _ = batch.derivatives(k, lo - 0.3, np.full(len(k), 0.5))
    Sl, Sul, _ = batch.derivatives(k, lo, np.full(len(k), 0.5))
    np.testing.assert_allclose(S1, Sl - 0.3 * Sul, rtol=0, atol=1e-10)


def test_curve_batch_equals_nurbs_curve_derivatives():
    rng = np.random.default_rng(5)
    curves = []
    for i in range(6):
        p = 3 if i < 3 else 2
        n = int(rng.integers(p + 1, p + 7))
        w = rng.uniform(0.5, 2.0, n) if i % 2 else None
        curves.append(nurbs.NurbsCurve(p, random_knots(rng, p, n), rng.normal(size=(n, 3)), w))
    data = [nurbs.SplineData(c.degree, c.knots, c.control_points, c.weights) for c in curves]
    cid = rng.integers(0, len(curves), 300)
    u = rng.uniform(0, 1, 300)
    C, dC = nurbs.CurveBatch(curves).derivatives(cid, u)
    C2, dC2 = nurbs.CurveBatch(data).derivatives(cid, u)
    np.testing.assert_array_equal(C, C2)
    np.testing.assert_array_equal(dC, dC2)
    for k, c in enumerate(curves):
        m = cid == k
        D = c.derivatives(u[m], 1)
        np.testing.assert_allclose(C[m], D[:, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(dC[m], D[:, 1], rtol=1e-10, atol=1e-10)


def test_batches_reject_closed_splines():
    t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    ring = nurbs.fit_curve(np.c_[np.cos(t), np.sin(t), 0 * t], closed=True, n_ctrl=8)
    with pytest.raises(nurbs.NurbsInputError, match="open"):
        nurbs.CurveBatch([ring])
    s = nurbs.loft([ring, nurbs.fit_curve(np.c_[np.cos(t), np.sin(t), 0 * t + 1], closed=True,
                                          n_ctrl=8)])
    with pytest.raises(nurbs.NurbsInputError, match="open"):
        nurbs.SurfaceBatch([s])
