"""3-D Lagrangian strain from tag material points and the contour-length strains, against
the exact strain of the analytic phantom motion (truth.json, never the reconstruction)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.analysis import strain as S
from cardionurbs.analysis.regional import regional_metrics
from cardionurbs.analysis.surface_strain import curve_length
from cardionurbs.analysis.tags import tag_metrics
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.phantom.generate import generate
from cardionurbs.phantom.regional import deformation_gradient


@pytest.fixture(scope="module")
def normal2():
    ph = generate("normal", seed=1, frames=2, volume_check=False)
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    return ph, model, tags, regional_metrics(model, tags)


def test_fit_of_the_exact_motion_reproduces_F(normal2):
    """The cylindrical fit (S1, S2) on exact material-point motion gives the exact F inside
    the wall (the phantom's wall motion lies in the span of the basis)."""
    ph = normal2[0]
    an, mo = ph.anatomy, ph.motion
    f = float(ph.phases[ph.es_frame])
    rng = np.random.default_rng(0)
    z = rng.uniform(0.35, 0.9, 600) * an.z_base
    th = rng.uniform(-np.pi, np.pi, 600)
    s1, s2 = an.s_lv_endo(z), an.s_lv_epi(z)
    r = np.sqrt(s1 + rng.uniform(0.05, 0.95, 600) * (s2 - s1))
    X = np.column_stack([r * np.cos(th), r * np.sin(th), z])
    x = mo.forward(an, X, f)
    fit = S.CylindricalMotionFit(X, x, (np.zeros(3), np.array([0.0, 0.0, an.z_base])))
    F = fit.gradient(X)
    assert fit.residual_mm < 1e-3
    assert np.abs(F - deformation_gradient(an, mo, X, f)).max() < 1e-3


def test_homogeneous_stretch_gives_its_strain():
    """x = diag(1.1, 0.9, 0.95) X about the axis: E = ½(diag² − 1) everywhere."""
    rng = np.random.default_rng(1)
    th, z = rng.uniform(-np.pi, np.pi, 800), rng.uniform(10, 60, 800)
    r = rng.uniform(20, 30, 800)
    X = np.column_stack([r * np.cos(th), r * np.sin(th), z])
    A = np.diag([1.02, 0.98, 0.95])
    fit = S.CylindricalMotionFit(X, X @ A.T, (np.zeros(3), np.array([0.0, 0.0, 80.0])))
    E = S.green_lagrange(fit.gradient(X))
    assert np.abs(E - 0.5 * (A.T @ A - np.eye(3))).max() < 2e-3


def test_tag_strain_against_the_exact_strain(normal2):
    """The bounds of reports/validation-regional.md (noise-free): segments within 1 (Ecc),
    1.5 (Ell), 3 (Err) strain points, GCS/GLS within 0.5, det F within 5 % of 1."""
    ph, _, _, r = normal2
    t = ph.truth["metrics"]
    assert r.strain["method"] == "tag lines"
    for k in range(1, 17):
        assert abs(r[f"Ecc_AHA_{k} (%)"] - t[f"Ecc_AHA_{k} (%)"]) < 1.0, k
        assert abs(r[f"Ell_AHA_{k} (%)"] - t[f"Ell_AHA_{k} (%)"]) < 1.5, k
        assert abs(r[f"Err_AHA_{k} (%)"] - t[f"Err_AHA_{k} (%)"]) < 3.0, k
    assert abs(r["Ecc_Global (%)"] - t["Ecc_Global (%)"]) < 0.5
    assert abs(r["Ell_Global (%)"] - t["Ell_Global (%)"]) < 0.5
    assert abs(r.strain["det_F"] - 1.0) < 0.05
    assert r.strain["tag_noise_mm"] < 0.01            # noise-free tags lie on their ED planes


def _wall_sampler(an, lo=0.3, hi=0.9):
    def inside(X):
        z, s = X[:, 2], X[:, 0] ** 2 + X[:, 1] ** 2
        return (z > lo * an.z_base) & (z < hi * an.z_base) & (s > an.s_lv_endo(z)) & (s < an.s_lv_epi(z))
    return inside


@pytest.mark.parametrize("sigma", [0.0, 0.5])
def test_orthogonal_distance_fit_to_tag_planes_is_unbiased(normal2, sigma):
    """Tag points on three families of ED planes (6 mm apart) moved by the exact phantom motion,
    with σ mm of isotropic noise; the fit (T2) started from the noisy material points (the
    planes' triple intersections) recovers the radial strain without bias: the mean error
    of Err over the wall within 0.6 strain point (the start: > 1), det F within 1 %."""
    from cardionurbs.analysis.tag_motion import fit_tag_motion
    ph = normal2[0]
    an, mo = ph.anatomy, ph.motion
    f = float(ph.phases[ph.es_frame])
    inside = _wall_sampler(an)
    rng = np.random.default_rng(3)
    R = float(np.sqrt(an.s_lv_epi(0.6 * an.z_base))) + 5.0
    lo, hi = [-R, -R, 0.3 * an.z_base], [R, R, 0.9 * an.z_base]
    c, zc = np.arange(-R, R, 6.0) + 1.0, np.arange(lo[2], hi[2], 6.0) + 1.0
    pts, nrm, off = [], [], []
    for fam, cs in ((0, c), (1, c), (2, zc)):
        for v in cs:
            X = rng.uniform(lo, hi, (800, 3))
            X[:, fam] = v
            X = X[inside(X)]
            pts.append(X)
            nrm.append(np.repeat(np.eye(3)[fam][None], len(X), 0))
            off.append(np.full(len(X), v))
    X, n, d = np.vstack(pts), np.vstack(nrm), np.concatenate(off)
    G = np.array(np.meshgrid(c, c, zc, indexing="ij")).reshape(3, -1).T
    G = G[inside(G)]
    fit = S.CylindricalMotionFit(G, mo.forward(an, G, f) + rng.normal(0, sigma, G.shape),
                                 (np.zeros(3), np.array([0.0, 0.0, an.z_base])))
    Y = rng.uniform([-R, -R, 0.35 * an.z_base], [R, R, 0.85 * an.z_base], (6000, 3))
    Y = Y[inside(Y)]
    th = np.arctan2(Y[:, 1], Y[:, 0])
    radial = np.column_stack([np.cos(th), np.sin(th), 0 * th])
    E_true = S.green_lagrange(deformation_gradient(an, mo, Y, f))

    def err_bias():
        dE = S.green_lagrange(fit.gradient(Y)) - E_true
        return float(np.mean(100 * np.einsum("ni,nij,nj->n", radial, dE, radial)))
    start = err_bias()
    out = fit_tag_motion(fit, mo.forward(an, X, f) + rng.normal(0, sigma, X.shape), n, d)
    assert abs(err_bias()) < 0.6
    assert abs(float(np.linalg.det(fit.gradient(Y)).mean()) - 1.0) < 0.01
    assert out["residual_mm"] < max(1e-3, 1.2 * sigma)
    if sigma:
        assert abs(start) > 1.0


def test_surface_strains_within_a_point(normal2):
    ph, _, _, r = normal2
    t = ph.truth["metrics"]
    assert abs(r["GLS surface (%)"] - t["GLS surface (%)"]) < 1.0
    assert abs(r["GCS surface (%)"] - t["GCS surface (%)"]) < 1.0
    assert r.surface["gcs_slice"] is not None


def test_contour_smoothing_keeps_length_and_removes_noise():
    t = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    ell = np.column_stack([25 * np.cos(t), 18 * np.sin(t), np.zeros_like(t)])
    exact = 4 * 25 * math.pi / 2 * (1 + 0) if False else float(
        np.sum(np.linalg.norm(np.diff(np.vstack([ell, ell[:1]]), axis=0), axis=1)))
    assert curve_length(ell, True) == pytest.approx(exact, rel=0.005)
    noisy = ell + np.random.default_rng(2).normal(0, 0.6, ell.shape) * [1, 1, 0]
    raw = float(np.sum(np.linalg.norm(np.diff(np.vstack([noisy, noisy[:1]]), axis=0), axis=1)))
    assert abs(curve_length(noisy, True) - exact) < 0.3 * abs(raw - exact)


def test_untagged_study_says_why(normal2):
    ph, model, _, _ = normal2
    r = regional_metrics(model, None)
    assert math.isnan(r["Ecc_Global (%)"]) and any("tag" in n for n in r.notes)
    assert not math.isnan(r["GCS surface (%)"])


def test_sunnybrook_gcs_in_heart_failure_range(sunnybrook_dir):
    """Sunnybrook SC-HF-I (heart failure with infarction): GCS surface computed and within the
    heart-failure range of reports/validation-regional.md (mean ± 2 SD of reduced-EF HF,
    −6.6 ± 3.6 %: [−13.8, 0.6] %)."""
    from cardionurbs.io import load_study
    model = reconstruct(load_study(sunnybrook_dir / "SC-HF-I-1"))
    r = regional_metrics(model, None)
    assert -13.8 <= r["GCS surface (%)"] <= 0.6
    assert math.isnan(r["GLS surface (%)"])            # no long-axis views


def test_penalty_chosen_by_risk_shrinks_pure_noise_terms():
    """A linear least-squares problem whose second group of coefficients is truly zero: with
    noise, the weights chosen by the unbiased risk estimate shrink that group and lower the
    error of the quantities; without noise no penalty is applied."""
    from cardionurbs.analysis.tag_motion import choose_penalty
    rng = np.random.default_rng(7)
    A = rng.normal(size=(400, 12))
    A[:, 6:] *= 0.05                                 # weakly informed terms, truly zero
    c_true = np.r_[rng.normal(size=6), np.zeros(6)]
    B = rng.normal(size=(20, 12))
    S = A.T @ A
    groups = [np.r_[np.zeros(6, bool), np.ones(6, bool)]]
    P0, lam0 = choose_penalty(S, c_true, groups, 0.0, B)
    assert lam0 == (0.0,) and not P0.any()
    sigma, gain = 0.5, []
    for _ in range(20):
        y = A @ c_true + rng.normal(0, sigma, 400)
        c = np.linalg.solve(S, A.T @ y)
        P, lam = choose_penalty(S, c, groups, sigma, B)
        c_reg = np.linalg.solve(S + P, S @ c)
        gain.append(np.sum((B @ (c - c_true)) ** 2) - np.sum((B @ (c_reg - c_true)) ** 2))
    assert np.mean(gain) > 0 and np.mean(np.array(gain) >= 0) > 0.7


def _family(rng, normal, spacing, first, indices, n_pts, sigma, shift=None):
    """Points on parallel planes n·X = first + spacing k (k in ``indices``), each plane
    sampled over a 40 mm square with ``sigma`` mm of isotropic noise; ``shift``: {k: mm}
    moves plane k off the grid."""
    from cardionurbs.geometry import in_plane_basis
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    e = in_plane_basis(n)
    pts = {}
    for k in indices:
        d = first + spacing * k + (shift or {}).get(k, 0.0)
        uv = rng.uniform(-20, 20, (n_pts, 2))
        pts[("sa1", k)] = d * n + uv @ e + rng.normal(0, sigma, (n_pts, 3))
    return n, pts


def _separate_planes(pts):
    from cardionurbs.analysis.tag_motion import TagPlanes
    from cardionurbs.geometry import fit_plane
    keys = tuple(sorted(pts))
    fits = [fit_plane(pts[k]) for k in keys]
    return TagPlanes(keys, np.array([f[1] for f in fits]),
                     np.array([float(f[1] @ f[0]) for f in fits]), 0.0)


def _offsets_along(planes, n):
    """Offsets of fitted planes expressed along the true normal n (sign-aligned)."""
    s = np.sign(planes.normals @ n)
    return planes.offsets * s


def test_tag_grid_pools_a_family_of_parallel_equally_spaced_planes():
    """SPAMM planes of one family (parallel, equally spaced; 10 planes of 20 points, random
    normal) with 0.6 mm noise, 12 draws: the grid fit's offsets are nearer the truth than the
    separate planes' in every draw, with a mean squared error at most 0.35 of theirs (about
    2 / 10 expected: two parameters for ten offsets), and its normal within 0.5° of the truth."""
    from cardionurbs.analysis.tag_motion import tag_grid
    idx = range(2, 12)
    truth = np.array([3.0 + 8.2 * k for k in idx])
    e_sep, e_grid = [], []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        n, pts = _family(rng, rng.normal(size=3), 8.2, 3.0, idx, 20, 0.6)
        sep = _separate_planes(pts)
        grid = tag_grid(sep, pts)
        e_sep.append(np.mean((_offsets_along(sep, n) - truth) ** 2))
        e_grid.append(np.mean((_offsets_along(grid, n) - truth) ** 2))
        assert np.degrees(np.arccos(min(1.0, abs(grid.normals[0] @ n)))) < 0.5
        assert np.allclose(np.abs(grid.normals @ grid.normals[0]), 1.0)
    assert all(g < s for g, s in zip(e_grid, e_sep))
    assert np.mean(e_grid) <= 0.35 * np.mean(e_sep)


def test_tag_grid_keeps_planes_that_are_not_one_grid():
    """One plane 1.5 mm off the equal spacing (σ = 0.3 mm, 60 points a plane): the F-test
    rejects the grid and the separately fitted planes are kept; noise-free exact planes are
    returned unchanged."""
    from cardionurbs.analysis.tag_motion import tag_grid
    rng = np.random.default_rng(11)
    _, pts = _family(rng, [0.3, 1.0, 0.2], 8.0, 1.0, range(0, 8), 60, 0.3, shift={4: 1.5})
    sep = _separate_planes(pts)
    out = tag_grid(sep, pts)
    assert np.array_equal(out.offsets, sep.offsets) and np.array_equal(out.normals, sep.normals)
    n, exact = _family(rng, [0.0, 0.0, 1.0], 8.0, 1.0, range(0, 8), 30, 0.0)
    sep = _separate_planes(exact)
    out = tag_grid(sep, exact)
    assert np.allclose(_offsets_along(out, n), 1.0 + 8.0 * np.arange(8), atol=1e-9)


@pytest.fixture(scope="module")
def phtn5_noisy():
    ph = generate("phtn", seed=5, frames=2, volume_check=False, noise_px=0.5)
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    return ph, regional_metrics(model, tags), regional_metrics(model, tags, boundaries=False)


def test_near_axis_rule_keeps_every_segment_finite_and_bounded(phtn5_noisy):
    """The phantom whose fitted end-systolic image of one apical point fell near the long
    axis (Err of segment 16 off by 76 strain points before the rule): with the near-axis
    rule applied to measurement and truth alike, some points are left out and every
    segment's Ecc, Ell, Err is within 20 points of the truth (the noisy bounds of
    reports/validation-regional.md are 2, 3 and 6; this checks that no single point can
    dominate a segment)."""
    ph, r, _ = phtn5_noisy
    t = ph.truth["metrics"]
    assert r.strain["near_axis_excluded"] > 0
    for kind in S.STRAIN_KINDS:
        for k in range(1, 17):
            err = r[f"{kind}_AHA_{k} (%)"] - t[f"{kind}_AHA_{k} (%)"]
            assert abs(err) < 20.0, (kind, k, err)


def test_truth_near_axis_rule_uses_the_frame_radius(normal2):
    """The truth's near-axis rule at ES: the exact images of ED points on the long axis stay
    on it (radius 0), and the 10 mm clearance leaves the segment strains of the mid
    ventricle as they are without it while the apical segments lose volume."""
    from cardionurbs.phantom import regional as R
    ph = normal2[0]
    an, mo = ph.anatomy, ph.motion
    f = float(ph.phases[ph.es_frame])
    axis_pts = np.column_stack([np.zeros(5), np.zeros(5), np.linspace(5, 0.8 * an.z_base, 5)])
    assert np.abs(R.axis_distance(an, mo, R.motion_map(an, mo, axis_pts, f), f)).max() < 1e-9
    specs = ph.slices
    levels = ph.truth["tags"]["levels"]
    a = R.strain_truth(an, mo, specs, levels, f, spacing_mm=2.0, axis_clearance_mm=10.0)
    b = R.strain_truth(an, mo, specs, levels, f, spacing_mm=2.0, axis_clearance_mm=0.0)
    for k in range(7, 13):
        assert a["columns"][f"Ecc_AHA_{k} (%)"] == pytest.approx(b["columns"][f"Ecc_AHA_{k} (%)"], abs=1e-9)
    assert sum(a["counts"][k] for k in range(13, 17)) < sum(b["counts"][k] for k in range(13, 17))


@settings(max_examples=30, deadline=None)
@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(0.2, 1), st.floats(4.0, 12.0),
       st.floats(-30.0, 30.0), st.integers(0, 5), st.integers(3, 9), st.floats(0.0, 0.3))
def test_tag_grid_recovers_any_exact_grid(nx, ny, nz, spacing, first, k0, count, noise):
    """Exact parallel, equally spaced planes (any normal, spacing, first offset and index
    range; 25 points per plane, in-plane jitter ``noise`` mm that leaves them on their
    planes): the grid is accepted and reproduces every plane to 1e-6 mm."""
    from cardionurbs.analysis.tag_motion import tag_grid
    from cardionurbs.geometry import in_plane_basis
    n = np.array([nx, ny, nz]) / np.linalg.norm([nx, ny, nz])
    e = in_plane_basis(n)
    rng = np.random.default_rng(count)
    idx = range(k0, k0 + count)
    pts = {("la", k): (first + spacing * k) * n + rng.uniform(-20, 20, (25, 2)) @ e
           + rng.normal(0, noise, (25, 2)) @ e for k in idx}
    out = tag_grid(_separate_planes(pts), pts)
    d = _offsets_along(out, n)
    assert np.allclose(d, [first + spacing * k for k in idx], atol=1e-6)
    assert np.allclose(np.abs(out.normals @ n), 1.0, atol=1e-9)


def test_direction_smoothing_keeps_a_smooth_wall_normal():
    """Normals of a prolate spheroid (semi-axes 25 mm and 60 mm, an LV-sized cavity) averaged
    over the strain-direction radius (10 mm), where strain is measured (≥ 10 mm from the
    axis, ≥ 12 mm from the apex): within 1.5° of the exact normal on average (a tilt α
    moves Ecc by about α² (Err − Ecc): < 0.06 strain points at Err − Ecc = 85), and a 5°
    random pointwise tilt brought below 2°."""
    a, c = 25.0, 60.0
    u, v = np.meshgrid(np.linspace(0.05, 0.5 * np.pi, 50), np.linspace(-np.pi, np.pi, 100,
                                                                      endpoint=False), indexing="ij")
    u, v = u.ravel(), v.ravel()
    P = np.column_stack([a * np.sin(u) * np.cos(v), a * np.sin(u) * np.sin(v), -c * np.cos(u)])
    N = np.column_stack([P[:, 0] / a ** 2, P[:, 1] / a ** 2, P[:, 2] / c ** 2])
    N /= np.linalg.norm(N, axis=1)[:, None]
    W = a * np.sin(u) * np.sqrt((a * np.cos(u)) ** 2 + (c * np.sin(u)) ** 2)   # area element
    inner = (P[:, 2] < -12.0) & (np.hypot(P[:, 0], P[:, 1]) >= 10.0)

    def angle(M):
        return np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", M, N), -1, 1)))[inner]
    assert angle(S.smoothed_normals(P, N, W, S.DIRECTION_SMOOTHING_MM)).mean() < 1.5
    rng = np.random.default_rng(5)
    noisy = N + np.radians(5.0) * rng.normal(size=N.shape) / np.sqrt(2)
    noisy /= np.linalg.norm(noisy, axis=1)[:, None]
    assert np.sqrt(np.mean(angle(noisy) ** 2)) > 4.0
    assert np.sqrt(np.mean(angle(S.smoothed_normals(P, noisy, W, S.DIRECTION_SMOOTHING_MM)) ** 2)) < 2.0


def test_risk_chooses_a_true_constraint_and_rejects_a_false_one():
    """A linear least-squares problem with a penalty term ½ κ |D c − h|² (as the
    near-incompressibility term, :func:`incompressibility_term`): when the truth satisfies
    the constraint (D c_true = h) the unbiased risk estimate picks a large κ and lowers the
    error of the quantities; when the truth violates it by far more than the noise, κ stays
    small; without noise κ = 0."""
    from cardionurbs.analysis.tag_motion import choose_penalty, incompressibility_term
    rng = np.random.default_rng(11)
    A = rng.normal(size=(300, 10))
    A[:, 5:] *= 0.1                                  # weakly informed directions
    D = rng.normal(size=(4, 10))
    B = rng.normal(size=(12, 10))
    S = A.T @ A
    c_true = rng.normal(size=10)
    w = np.ones(4)
    assert choose_penalty(S, c_true, [], 0.0, B, terms=(incompressibility_term(D, D @ c_true, w, 1.0),))[1] == (0.0,)
    sigma = 0.5
    for h, expect_gain in ((D @ c_true, True), (D @ c_true + 5.0, False)):
        gains, kappas = [], []
        for _ in range(20):
            y = A @ c_true + rng.normal(0, sigma, 300)
            c = np.linalg.solve(S, A.T @ y)
            term = incompressibility_term(D, D @ c - h, w, 1.0)
            P, (kappa,) = choose_penalty(S, c, [], sigma, B, terms=(term,))
            c_reg = c - np.linalg.solve(S + P, kappa * term[1])
            gains.append(np.sum((B @ (c - c_true)) ** 2) - np.sum((B @ (c_reg - c_true)) ** 2))
            kappas.append(kappa)
        if expect_gain:
            assert np.median(kappas) >= 10 and np.mean(gains) > 0
        else:
            assert np.median(kappas) <= 0.1


def test_segment_mean_matrix_averages_by_volume():
    from cardionurbs.analysis.tag_motion import segment_mean_matrix
    labels = np.array([3, 1, 3, 1, 2])
    vol = np.array([1.0, 2.0, 3.0, 2.0, 5.0])
    M, v = segment_mean_matrix(labels, vol)
    vals = np.array([1.0, 4.0, 5.0, 6.0, 7.0])
    assert np.allclose(M @ vals, [5.0, 7.0, 4.0]) and np.allclose(v, [4.0, 5.0, 4.0])


def test_noisy_tags_volume_prior(phtn5_noisy):
    """0.5 px noise on the phantom whose Err the risk-chosen incompressibility weight missed
    by 11.5 strain points (reports/validation-regional.md before the volume prior): with the
    prior J̄_s ~ N(1, s²) of stated s and the ridge weights chosen by the evidence, every
    segment's Err is within the noisy bound (6) and Ecc within 2; Ell within 4 (the fit's
    own standard error of this phantom's worst Ell segment is 3.9 points, so 3 is beyond
    what any unbiased estimate reaches reliably here). Two ridge weights are reported (the
    prior's weight is stated, not chosen), with s, and det F of the unregularised fit — the
    check the prior does not pull to 1 — is within 5 % of 1 (the motion is incompressible).
    The tags alone (``boundaries=False``): the prior's own effect, without the contours. Ecc
    within 2 is asked of the reported estimator (tags and contours): with the tag-line map's
    in-plane harmonics raised to 6 (which no ridge group shrinks) the tags alone read
    segment 15's Ecc 2.07 off here."""
    from cardionurbs.analysis.tag_motion import VOLUME_PRIOR_SD
    ph, both, r = phtn5_noisy
    t = ph.truth["metrics"]
    assert len(r.strain["penalty"]) == 2 and r.strain["volume_prior_sd"] == VOLUME_PRIOR_SD
    assert abs(r.strain["det_F_unregularised"] - 1.0) < 0.05
    assert set(r.strain["segment_sd"]) == set(S.STRAIN_KINDS)
    for k in range(1, 17):
        assert abs(r[f"Err_AHA_{k} (%)"] - t[f"Err_AHA_{k} (%)"]) < 6.0, k
        assert abs(both[f"Ecc_AHA_{k} (%)"] - t[f"Ecc_AHA_{k} (%)"]) < 2.0, k
        assert abs(r[f"Ell_AHA_{k} (%)"] - t[f"Ell_AHA_{k} (%)"]) < 4.0, k


def test_volume_prior_is_the_gaussian_posterior():
    """The stated prior D c ~ N(h, s² I) beside data c ~ N(c_true, σ² S⁻¹) (S = AᵀA of a
    linear model with noise σ): the regularised optimum c − (S + P)⁻¹ ρ with P, ρ from
    :func:`incompressibility_term` at weight k σ² / s² (k constraints, equal weights) is the
    closed-form posterior mean (AᵀA / σ² + DᵀD / s²)⁻¹ (Aᵀy / σ² + Dᵀh / s²); choose_penalty
    keeps that term at weight 1 whatever ridge it picks, and without noise adds nothing."""
    from cardionurbs.analysis.tag_motion import (choose_penalty, incompressibility_term,
                                                 volume_prior_weight)
    rng = np.random.default_rng(3)
    A = rng.normal(size=(200, 8))
    D = rng.normal(size=(3, 8))
    c_true, sigma, sd = rng.normal(size=8), 0.4, 0.05
    h = D @ c_true + rng.normal(0, sd, 3)
    y = A @ c_true + rng.normal(0, sigma, 200)
    S = A.T @ A
    c = np.linalg.solve(S, A.T @ y)
    Q, r = incompressibility_term(D, D @ c - h, np.ones(3), 3 * volume_prior_weight(sigma, sd))
    post = np.linalg.solve(S / sigma ** 2 + D.T @ D / sd ** 2, A.T @ y / sigma ** 2 + D.T @ h / sd ** 2)
    assert np.allclose(c - np.linalg.solve(S + Q, r), post, atol=1e-9)
    P, lams = choose_penalty(S, c, [np.arange(8) >= 6], sigma, np.eye(8), fixed=((Q, r),),
                             criterion="evidence")
    assert len(lams) == 1 and lams[0] > 0
    assert np.allclose(P - lams[0] * np.diag(np.where(np.arange(8) >= 6, np.diag(S), 0.0)), Q)
    assert not choose_penalty(S, c, [], 0.0, np.eye(8), fixed=((Q, r),))[0].any()
    with pytest.raises(ValueError):
        choose_penalty(S, c, [], sigma, np.eye(8), terms=((Q, r),), criterion="evidence")


def test_evidence_shrinks_a_pure_noise_group_and_keeps_a_real_one():
    """Ridge weights by the marginal likelihood: a group of coefficients that are zero in
    the truth (pure noise in the fit) gets a large weight and the error of the fitted
    coefficients falls; a group carrying a real signal far above the noise gets a small one."""
    from cardionurbs.analysis.tag_motion import choose_penalty
    rng = np.random.default_rng(7)
    A = rng.normal(size=(300, 10))
    A[:, 5:] *= 0.1                                    # weakly informed directions
    S = A.T @ A
    group = np.arange(10) >= 5
    sigma = 0.5
    for scale, strong in ((0.0, True), (20.0, False)):
        c_true = np.where(group, scale, 1.0) * rng.normal(size=10)
        lams, gains = [], []
        for _ in range(20):
            c = np.linalg.solve(S, A.T @ (A @ c_true + rng.normal(0, sigma, 300)))
            P, (lam,) = choose_penalty(S, c, [group], sigma, np.eye(10), criterion="evidence")
            c_reg = np.linalg.solve(S + P, S @ c)
            lams.append(lam)
            gains.append(np.sum((c - c_true) ** 2) - np.sum((c_reg - c_true) ** 2))
        if strong:
            assert np.median(lams) >= 10 and np.mean(gains) > 0
        else:
            assert np.median(lams) <= 0.1


def test_wall_boundaries_fix_the_transmural_offset():
    """0.5 px noise on the tags only, contours exact (the issue's condition): with the tags
    alone the noisy fit leaves the whole ventricle's Err off by a common offset of up to ~4
    strain points (the one or two tag lines across the wall hardly inform it); with the
    endo- and epicardial contours as material boundaries (term (T3)) every segment is within
    the noisy bounds (Ecc 2, Ell 3, Err 6), the boundary points sit on the moved ED surfaces
    to within the contours' exactness, and the segments' Err is closer to the truth than the
    tags alone make it (RMS over the 16 segments)."""
    from cardionurbs.phantom.faults import add_noise
    ph = generate("mr", seed=21, frames=2, volume_check=False)
    add_noise(ph.study, 0.5, np.random.default_rng(21), targets=("tags",))
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    t = ph.truth["metrics"]

    def errors(r, kind):
        return np.array([r[f"{kind}_AHA_{k} (%)"] - t[f"{kind}_AHA_{k} (%)"] for k in range(1, 17)])
    both = regional_metrics(model, tags)
    alone = regional_metrics(model, tags, boundaries=False)
    assert both.strain["boundary_points"] > 500 and "boundary_points" not in alone.strain
    assert both.strain["boundary_residual_mm"] < 0.1 < both.strain["boundary_noise_mm"]
    for kind, bound in (("Ecc", 2.0), ("Ell", 3.0), ("Err", 6.0)):
        assert np.abs(errors(both, kind)).max() < bound, kind
    rms = [float(np.sqrt(np.mean(errors(r, "Err") ** 2))) for r in (both, alone)]
    assert rms[0] < rms[1], rms


def test_truth_and_measurement_average_directions_over_one_radius():
    """The phantom's strain truth takes r as the measurement defines it: the endocardial normal
    averaged over the same radius, by the same function."""
    from cardionurbs.phantom import regional as R
    assert R.DIRECTION_SMOOTHING_MM == S.DIRECTION_SMOOTHING_MM
    assert R.averaged_normals is S.averaged_normals


def test_expanded_basis_keeps_the_map():
    """A fit moved onto a larger basis (the tag-line fit's) is the same map: the same images
    and deformation gradients; the ζ' component keeps its harmonics (only the long-axis tags
    measure it)."""
    rng = np.random.default_rng(4)
    X = rng.uniform([-30, -30, 10], [30, 30, 70], (600, 3))
    X = X[np.hypot(X[:, 0], X[:, 1]) > 15]
    th = 0.1 * X[:, 2] / 70
    c, s = np.cos(th), np.sin(th)
    x = np.column_stack([0.9 * (c * X[:, 0] - s * X[:, 1]), 0.9 * (s * X[:, 0] + c * X[:, 1]) + 0.05 * X[:, 0] ** 2 / 30,
                         0.85 * X[:, 2]])
    axis = (np.zeros(3), np.array([0.0, 0.0, 80.0]))
    fit = S.CylindricalMotionFit(X, x, axis)
    big = fit.expanded(S.TAG_LINE_ORDERS, S.TRANSMURAL_ORDERS, S.AXIAL_HARMONICS)
    Y = X[::7]
    assert np.allclose(big.position(Y), fit.position(Y), atol=1e-9)
    assert np.allclose(big.gradient(Y), fit.gradient(Y), atol=1e-12)
    assert len(big.params) > len(fit.params) == fit.coef.size
    a, b, m = big._index
    axial = big.free.reshape(3, -1)[2]
    assert axial.sum() < big.free.reshape(3, -1)[0].sum() and m[axial].max() == 2 * S.AXIAL_HARMONICS
    with pytest.raises(ValueError):
        big.expanded(S.ORDERS, S.TRANSMURAL_ORDERS)


def test_factored_schur_step_is_the_gauss_newton_step():
    """The Schur step on the factored Jacobian (∂x/∂coef[j, c] = T[:, :, c] D[:, j]) equals the
    Gauss–Newton step of the whole problem — the coefficients in use and every point's two
    unknowns — solved densely."""
    from cardionurbs.analysis.tag_motion import _schur_step
    rng = np.random.default_rng(5)
    n, b = 40, 6
    T, D = rng.normal(size=(n, 3, 3)), rng.normal(size=(n, b))
    J_pt, res = rng.normal(size=(n, 3, 2)), rng.normal(size=(n, 3))
    free = np.ones(3 * b, bool)
    free[[2 * b + 4, 2 * b + 5]] = False
    J_coef = (T[:, :, :, None] * D[:, None, None, :]).reshape(n, 3, -1)[:, :, free]
    p = int(free.sum())
    J = np.zeros((3 * n, p + 2 * n))
    J[:, :p] = J_coef.reshape(3 * n, p)
    for i in range(n):
        J[3 * i:3 * i + 3, p + 2 * i:p + 2 * i + 2] = J_pt[i]
    step = -np.linalg.solve(J.T @ J, J.T @ res.ravel())
    d_coef, d_pt, S_data = _schur_step(T, D, free, J_pt, res, ridge=0.0)
    assert np.allclose(d_coef, step[:p], rtol=1e-8, atol=1e-10)
    assert np.allclose(d_pt.ravel(), step[p:], rtol=1e-8, atol=1e-10)
    H = J.T @ J
    assert np.allclose(S_data, H[:p, :p] - H[:p, p:] @ np.linalg.solve(H[p:, p:], H[p:, :p]))


@functools.lru_cache(maxsize=2)
def _tagged(pathology, seed, anatomy):
    """(phantom, model, tag metrics) of a noise-free 2-frame phantom, shared by the tests."""
    ph = generate(pathology, seed=seed, frames=2, volume_check=False, anatomy_model=anatomy)
    model = reconstruct(ph.study)
    return ph, model, tag_metrics(model)


def _segment_errors(r, truth):
    """measured − truth per segment 1–16, by kind."""
    return {k: np.array([r[f"{k}_AHA_{s} (%)"] - truth[f"{k}_AHA_{s} (%)"] for s in range(1, 17)])
            for k in S.STRAIN_KINDS}


def _exact_motion_strains(pathology, seed, anatomy):
    """The segment strains the measurement reports with the phantom's exact F in place of the
    fitted one (``deformation=``): what is left of the error is how the strain is sampled and
    averaged (wall samples, tagged range, directions, segments), not the fit. Returns
    measured − truth per segment, by kind."""
    ph, model, tags = _tagged(pathology, seed, anatomy)
    r = regional_metrics(model, tags, deformation=ph.deformation_gradient)
    return _segment_errors(r, ph.truth["metrics"])


@pytest.mark.parametrize("pathology,seed,anatomy,bounds", [
    ("mr", 1, "ideal", {"Ecc": 0.5, "Ell": 0.5, "Err": 1.0}),
    ("mr", 2, "realistic", {"Ecc": 1.0, "Ell": 1.0, "Err": 3.0})])
def test_exact_motion_gives_the_truth_where_the_measurement_samples(pathology, seed, anatomy, bounds):
    """With the exact motion in place of the fitted one, every tagged segment's strain is the
    truth's to within the noise-free bounds (tighter on the ideal anatomy): the wall samples
    cover thin slices of the wall (rays split along the axis: a segment partly inside the
    tagged range kept the inner layers of some rays and the outer of others, +4 points of
    apical Err on mr seed 1), and the truth averages over the tagged range the measurement
    uses (the LA tag planes tracked from ED to ES, along the tilted axis of a realistic heart;
    with the planes tagged at both frames only, basal segments read 10–28 points apart)."""
    err = _exact_motion_strains(pathology, seed, anatomy)
    for kind, bound in bounds.items():
        e = err[kind][np.isfinite(err[kind])]
        assert len(e) >= 12 and np.abs(e).max() < bound, (kind, err[kind])


def test_misfit_as_noise_bounds_realistic_radial_strain():
    """Exact tags on a realistic heart (shape modes, bent apex): the map (S1) cannot follow
    all of the wall's motion (misfit ~0.02 mm, above the noise floor while the ED-plane noise
    is ~0), and fitted unregularised it bent its transmural terms to absorb that (worst
    segment Err 5.9 points off on this phantom). With the misfit as the regularisation's σ
    every tagged segment is within the noise-free bounds; the σ used is reported."""
    from cardionurbs.analysis.tag_motion import NOISE_FLOOR_MM
    ph, model, tags = _tagged("mr", 2, "realistic")
    r = regional_metrics(model, tags)
    assert r.strain["sigma_mm"] > NOISE_FLOOR_MM > r.strain.get("tag_noise_mm", 0.0)
    assert len(r.strain["penalty"]) == 2                          # the fit was regularised
    err = _segment_errors(r, ph.truth["metrics"])
    for kind, bound in {"Ecc": 1.0, "Ell": 1.5, "Err": 3.0}.items():
        e = err[kind][np.isfinite(err[kind])]
        assert len(e) >= 12 and np.abs(e).max() < bound, (kind, err[kind])


@settings(max_examples=40, deadline=None)
@given(st.integers(3, 40), st.integers(0, 2 ** 31 - 1))
def test_polygon_signed_distance_is_the_nearest_edge_distance(m, seed):
    """The blocked, vectorised signed distance that keeps tag points inside the myocardium
    equals an edge-by-edge reference: distance to the nearest edge, positive inside by
    matplotlib's point-in-polygon test (points within 1e-6 mm of an edge: no sign asked)."""
    from matplotlib.path import Path

    from cardionurbs.analysis.material import _polygon_signed_distance
    rng = np.random.default_rng(seed)
    th = np.sort(rng.uniform(0, 2 * np.pi, m))
    rad = rng.uniform(10, 30, m)
    poly = np.column_stack([rad * np.cos(th), rad * np.sin(th)])
    pts = rng.uniform(-35, 35, (3000, 2))
    got = _polygon_signed_distance(pts, poly)
    ref = np.full(len(pts), np.inf)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        t = np.clip((pts - a) @ (b - a) / max((b - a) @ (b - a), 1e-12), 0.0, 1.0)
        ref = np.minimum(ref, np.linalg.norm(pts - a - t[:, None] * (b - a), axis=1))
    assert np.allclose(np.abs(got), ref, rtol=0, atol=1e-9)
    inside = Path(poly).contains_points(pts)
    clear = ref > 1e-6
    assert np.array_equal((got > 0)[clear], inside[clear])


def test_batched_coefficient_differences_equal_the_one_at_a_time_ones():
    """quantity_jacobian of PointQuantities (every perturbed F in one batch, by the map's
    linearity in its coefficients) equals the same central differences taken one coefficient
    at a time through the fit, for segment strains and volume ratios at shared points."""
    from cardionurbs.analysis.tag_motion import PointQuantities, quantity_jacobian
    rng = np.random.default_rng(3)
    th, z = rng.uniform(-np.pi, np.pi, 400), rng.uniform(10, 60, 400)
    r = rng.uniform(20, 30, 400)
    X = np.column_stack([r * np.cos(th), r * np.sin(th), z])
    x = X @ np.diag([0.9, 0.95, 0.97]).T + 0.02 * r[:, None] * np.sin(3 * th)[:, None]
    fit = S.CylindricalMotionFit(X, x, (np.zeros(3), np.array([0.0, 0.0, 80.0])))
    fit = fit.expanded(S.TAG_LINE_ORDERS, S.TRANSMURAL_ORDERS, S.AXIAL_HARMONICS)
    fit.params = fit.params + 1e-3 * rng.standard_normal(len(fit.params))
    labels = rng.integers(1, 17, 400)
    dirs = S.cardiac_directions(X, X, np.column_stack([np.cos(th), np.sin(th), 0 * th]),
                                np.zeros(3), np.array([0.0, 0.0, 80.0]))
    batched = S.segment_strain_quantities(X, dirs, labels, np.ones(400)) + PointQuantities(
        ((X.copy(), lambda F: np.linalg.det(F)[:, :5]),))
    coef = fit.params.copy()
    scale = np.full(len(coef), 0.01)
    J = quantity_jacobian(fit, batched, coef, scale)
    J1 = quantity_jacobian(fit, lambda f: batched(f), coef, scale)
    assert J.shape == (16 * 3 + 5, len(coef))
    assert np.allclose(J, J1, rtol=1e-6, atol=1e-8 * np.abs(J1).max())
    assert np.array_equal(fit.params, coef)


def test_strain_over_time_and_peaks_against_the_exact_strain():
    """The strain curves (every tagged frame) and their peaks in metrics.json, against the
    exact strain of the phantom's motion at each frame over the tissue tracked to that frame
    (cardionurbs.phantom.regional.strain_truth with that frame's tracked LA levels): every
    frame's segments within the noise-free bounds (Ecc 1, Ell 1.5, Err 3), the global values
    within GCS/GLS's 0.5 (Err 1.5), det F within 1 %, and the peaks (the most negative Ecc,
    Ell and the largest Err over the curve) within the same."""
    from cardionurbs.phantom import regional as PR
    from cardionurbs.phantom import truth as PT
    ph = generate("mr", seed=1, frames=6, volume_check=False)
    model = reconstruct(ph.study)
    r = regional_metrics(model, tag_metrics(model, over_time=True))
    assert sorted(r.over_time) == [1, 2, 3, 4, 5]
    bounds = {"Ecc": (1.0, 0.5), "Ell": (1.5, 0.5), "Err": (3.0, 1.5)}
    curves = {k: [] for k in bounds}
    for f, got in sorted(r.over_time.items()):
        phase = float(ph.phases[f])
        levels = PT.strain_levels(ph.anatomy, ph.motion, ph.tag_grid, ph.slices, phase)
        exact = PR.strain_truth(ph.anatomy, ph.motion, ph.slices, levels, phase)
        assert abs(got["det_F"] - exact["det_F"]) < 0.01
        for kind, (seg_bound, global_bound) in bounds.items():
            seg = np.array([got["columns"][f"{kind}_AHA_{s} (%)"] - exact["columns"][f"{kind}_AHA_{s} (%)"]
                            for s in range(1, 17)])
            assert np.isfinite(seg).sum() >= 12 and np.nanmax(np.abs(seg)) < seg_bound, (f, kind, seg)
            g, t = got["columns"][f"{kind}_Global (%)"], exact["columns"][f"{kind}_Global (%)"]
            assert abs(g - t) < global_bound, (f, kind, g, t)
            curves[kind].append(t)
    peak = r.to_json()["strain_peak"]
    for kind, (_, global_bound) in bounds.items():
        want = max(curves[kind]) if kind == "Err" else min(curves[kind])
        assert abs(peak[f"{kind}_Global (%)"] - want) < global_bound, (kind, peak, want)
