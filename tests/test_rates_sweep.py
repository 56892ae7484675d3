"""Rates of an SA-only volume curve made continuous by the volume between the stack's reach and
the base (issue 29: with one base share for the whole beat PER was -7 to +10 % off on 50-frame
ukbb-layout phantoms, because the share changes with the slice that is most basal), and the
smoothing spline that reads through label-map frame noise. Analytic curves only (fast)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from cardionurbs.analysis.rates import (ES_PLANE_SD_MM, BaseStack, base_motion, base_sweep, filling_rates,
                                        roughness_matrix, smoothed_rate)

RR, N = 1000.0, 50
W = 2 * np.pi
TAU = np.arange(N) / N


def _volume(x):
    return 100 + 30 * np.cos(W * x) + 8 * np.cos(2 * W * x) + 3 * np.sin(2 * W * x)


def _exact_peaks(es: int) -> tuple[float, float]:
    tf = np.linspace(0, 1, 100001)[:-1]
    d = (-30 * W * np.sin(W * tf) - 16 * W * np.sin(2 * W * tf) + 6 * W * np.cos(2 * W * tf)) / RR * 1000
    t_es = TAU[es]
    return -d[tf <= t_es].min(), d[(tf >= t_es) & (tf <= t_es + 2 * (1 - t_es) / 3)].max()


def _stack_curve(first_mm: float, sweep_mm: float, areas, spacing=8.0, reach=4.0, lag=0.0):
    """An SA-only curve: slices every ``spacing`` mm from level 0 down, the base ``first_mm``
    above slice 0 at ED moving ``sweep_mm`` towards the apex in phase with the volume, each
    slice's LV area ``areas[i]`` while it is the most basal one; the curve holds the volume up to
    ``reach`` beyond the most basal section (the model's half-slice closing). The slices held at
    every frame follow the phase q = p − lag p (1 − p) (lag > 0: behind the volume's phase p,
    as fixed planes are where material moves through them). Also returns the base level b."""
    v = _volume(TAU)
    es = int(np.argmin(v))
    phase = (v[0] - v) / (v[0] - v[es])
    b = first_mm - sweep_mm * phase
    top = np.maximum(np.ceil(-b / spacing - 1e-12).astype(int), 0)
    z = -spacing * top
    a = np.asarray(areas, float)[top]
    observed = v - a * (b - z - reach) / 1000.0
    stack = BaseStack(a, z, 5000.0 - 1500.0 * (phase - lag * phase * (1.0 - phase)), reach)
    steps = [(i, (i + 1) % N) for i in range(N) if top[i] != top[(i + 1) % N]]
    return observed, stack, steps, es, b


def _errors(obs, stack, steps, es, **kw) -> tuple[float, float]:
    """(PER, PEFR) relative errors of the completed curve against the exact peaks."""
    per, pefr = _exact_peaks(es)
    got, reason = filling_rates(TAU * RR, obs, 0, es, RR, steps=steps,
                                sweep=base_sweep(stack, list(range(N)), 0, es, **kw))
    assert reason == ""
    return got["PER (mL/s)"] / per - 1, got["PEFR (mL/s)"] / pefr - 1


@pytest.mark.parametrize("first, sweep, areas", [(4.8, 14.0, (2400, 1300, 900)),
                                                 (2.0, 17.0, (2000, 1500, 1000)),
                                                 (6.5, 15.0, (2600, 1200, 800))])
def test_base_sweep_where_the_base_share_changes_with_the_basal_slice(first, sweep, areas):
    """The base passes two slices each way, the most basal slice's area differs between them:
    PER and PEFR within 3.5 % of the exact derivative's peaks (one base share for the beat, the
    previous method, is 5-15 % off on the same curves)."""
    obs, stack, steps, es, _ = _stack_curve(first, sweep, areas)
    assert len(steps) == 4
    per, pefr = _exact_peaks(es)
    sw = base_sweep(stack, list(range(N)), 0, es)
    got, reason = filling_rates(TAU * RR, obs, 0, es, RR, steps=steps, sweep=sw)
    assert reason == ""
    assert got["PER (mL/s)"] == pytest.approx(per, rel=0.035)
    assert got["PEFR (mL/s)"] == pytest.approx(pefr, rel=0.035)
    old, _ = filling_rates(TAU * RR, obs, 0, es, RR, steps=steps)
    assert abs(old["PER (mL/s)"] / per - 1) > 0.05


def test_base_motion_from_the_levels_passed():
    """Two levels passed: b0 and D by least squares (exact on exact crossings); one level: b0 at
    the half-slice rule; a base moving the wrong way: None."""
    phase = np.linspace(0, 1, 10)
    b0, d = base_motion(phase, [(0.25, 0.0), (0.75, -8.0)], 0.0, 4.0)
    assert (b0, d) == pytest.approx((4.0, 16.0))
    b0, d = base_motion(phase, [(0.4, 0.0), (0.4, 0.0)], 0.0, 4.0)
    assert (b0, d) == pytest.approx((4.0, 10.0))
    # one level and the ES end: both guesses on the line b = 4 - 10 p -> that line
    assert base_motion(phase, [(0.4, 0.0)], 0.0, 4.0, es_level=-6.0) == pytest.approx((4.0, 10.0))
    # ... off it: D = (w0 p g0 + w1 (1 - p) g1) / (w0 p^2 + w1 (1 - p)^2), g0 = 4, g1 = 9,
    # w0 = 3 / reach^2 (the base anywhere in the 8 mm gap), w1 = 1 / ES_PLANE_SD_MM^2
    w0, w1 = 3.0 / 16.0, 1.0 / ES_PLANE_SD_MM ** 2
    d = (w0 * 0.4 * 4.0 + w1 * 0.6 * 9.0) / (w0 * 0.16 + w1 * 0.36)
    assert base_motion(phase, [(0.4, 0.0)], 0.0, 4.0, es_level=-9.0) == pytest.approx((0.4 * d, d))
    # the wider the gap, the less the half-slice guess weighs against the ES plane: the ED
    # guess 1 mm short of a base on the line b = 6 - 15 p through the crossing (0.4, 0) and the
    # true ES end (-9): D nearer 15 at 10 mm (reach 5) than with the two guesses weighed alike
    b0_true, d_true = 6.0, 15.0
    fit = base_motion(phase, [(0.4, 0.0)], 0.0, 5.0, es_level=b0_true - d_true)
    alike = (0.4 * 5.0 + 0.6 * 9.0) / (0.16 + 0.36)
    assert abs(fit[1] - d_true) < abs(alike - d_true)
    assert base_motion(phase, [(0.4, 0.0)], 0.0, 0.0, es_level=-9.0) is None   # no gap: ED's
    # two levels: the ES end is not used
    assert base_motion(phase, [(0.25, 0.0), (0.75, -8.0)], 0.0, 4.0, es_level=-30.0) == pytest.approx((4.0, 16.0))
    assert base_motion(phase, [(0.25, -8.0), (0.75, 0.0)], 0.0, 4.0) is None
    assert base_motion(phase, [], 0.0, 4.0) is None


def test_roughness_matrix_is_the_bending_energy():
    """gᵀKg equals ∫ g''² of the natural cubic spline through (t, g) on uneven knots."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(10, 30, 12))
    g = rng.normal(0, 5, 12)
    sp = CubicSpline(t, g, bc_type="natural")
    x = np.linspace(t[0], t[-1], 200001)
    energy = np.trapezoid(sp(x, 2) ** 2, x)
    assert g @ roughness_matrix(t) @ g == pytest.approx(energy, rel=1e-4)


def _closed(v):
    tc = np.r_[TAU * RR, RR]
    return tc, np.r_[v, v[0]]


def test_smoothed_rate_keeps_an_exact_curve():
    """On exact samples GCV leaves the interpolating spline: PER as the plain spline's within 1 %."""
    v = _volume(TAU)
    tc, vc = _closed(v)
    rate = smoothed_rate(tc, vc, np.ones(len(tc)))
    plain = CubicSpline(tc, vc, bc_type="natural")
    x = np.linspace(0, RR, 2001)
    assert np.max(-rate(x)) == pytest.approx(np.max(-plain(x, 1)), rel=0.01)


def test_smoothed_rate_reads_through_frame_noise_and_leaves_out_a_zero_weight_frame():
    """±1 mL of uniform frame noise (what label-map volumes carry) puts the interpolating
    spline's PER 17-41 % off (seeds 0-7), the smoothing spline's within 4.2 %: bound 5 %; a frame
    of weight 0 (+5 mL) changes nothing."""
    v = _volume(TAU)
    es = int(np.argmin(v))
    per, _ = _exact_peaks(es)
    x = np.linspace(0, TAU[es] * RR, 1001)
    for seed in range(4):
        tc, vc = _closed(v + np.random.default_rng(seed).uniform(-1.0, 1.0, N))
        smooth = np.max(-smoothed_rate(tc, vc, np.ones(len(tc)))(x)) * 1000
        plain = np.max(-CubicSpline(tc, vc, bc_type="natural")(x, 1)) * 1000
        assert abs(smooth / per - 1) < 0.05 < 0.15 < abs(plain / per - 1), seed
    wt = np.ones(len(tc))
    wt[es] = 0.0
    blip = vc.copy()
    blip[es] += 5.0
    a = smoothed_rate(tc, vc, wt)(x)
    b = smoothed_rate(tc, blip, wt)(x)
    assert np.allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("first, sweep, areas", [(4.8, 14.0, (2400, 1300, 900)),
                                                 (2.0, 17.0, (2000, 1500, 1000)),
                                                 (6.5, 15.0, (2600, 1200, 800))])
def test_base_phase_from_the_completed_volume_where_fixed_slices_lag(first, sweep, areas):
    """The slices held at every frame lag the volume's phase (lag 0.3): with their phase PER is
    up to 5.7 % off (2.6-5.7 %), with the completed volume's phase (iterated) the errors are
    those of an unlagged stack (PER and PEFR within 2.5 %) whatever the lag."""
    obs, stack, steps, es, _ = _stack_curve(first, sweep, areas, lag=0.3)
    fixed = _errors(obs, stack, steps, es)
    own = _errors(obs, stack, steps, es, volumes=obs)
    unlagged = _errors(*_stack_curve(first, sweep, areas)[:4], volumes=obs)
    assert abs(fixed[0]) > 0.02
    assert own == pytest.approx(unlagged, abs=1e-6)
    assert max(abs(own[0]), abs(own[1])) < 0.03


@pytest.mark.parametrize("first, sweep", [(7.0, 11.0), (3.0, 9.0), (8.0, 14.0), (5.0, 9.0)])
def test_one_level_passed_the_es_end_narrows_the_base_guess(first, sweep):
    """10 mm slices, the base passes slice 0 only: where the ED base is not at the half-slice
    guess (5 mm) PER is 11-16 % off with that guess alone; the ES end (here its true level) as a
    second guess brings every case closer (1-11 %, weighted by the inverse variances of
    base_motion), and where both guesses are right the rates
    are within 2 %."""
    obs, stack, steps, es, b = _stack_curve(first, sweep, (2400, 1300, 900), spacing=10.0, reach=5.0)
    assert len(steps) == 2
    alone = _errors(obs, stack, steps, es, volumes=obs)
    both = _errors(obs, stack, steps, es, volumes=obs, es_level=float(b[es]))
    assert abs(both[0]) < abs(alone[0]) or abs(alone[0]) < 0.02
    if (first, sweep) == (5.0, 9.0):
        assert max(abs(both[0]), abs(both[1])) < 0.02
    else:
        assert abs(alone[0]) > 0.1 and abs(both[0]) < 0.115


def test_smoothed_rate_has_a_least_smoothing():
    """The least λ (MIN_SMOOTHING h³) leaves an exact 50-frame curve's PER and PEFR within
    0.2 % of the interpolating spline's."""
    v = _volume(TAU)
    es = int(np.argmin(v))
    tc, vc = _closed(v)
    plain = CubicSpline(tc, vc, bc_type="natural")
    x = np.linspace(0, TAU[es] * RR, 1001)
    y = np.linspace(TAU[es] * RR, RR, 1001)
    rate = smoothed_rate(tc, vc, np.ones(len(tc)))
    assert np.max(-rate(x)) == pytest.approx(np.max(-plain(x, 1)), rel=0.002)
    assert np.max(rate(y)) == pytest.approx(np.max(plain(y, 1)), rel=0.002)


def test_voxel_curve_of_a_label_map_study():
    """The voxel-count LV cavity volumes of the curve's frames and the SA spacing (the voxel's
    depth: its slabs reach half of it); None where a frame has none or no meta (a contour study)."""
    from types import SimpleNamespace

    from cardionurbs.analysis.rates import _voxel_curve
    normal = np.array([0.0, 0.6, 0.8])
    images = [SimpleNamespace(view="SA", normal=normal, position=np.array([1.0, 2.0, 3.0]) + normal * 8.0 * k)
              for k in range(4) for _ in range(2)] + [SimpleNamespace(view="2CH", normal=np.array([1.0, 0, 0]),
                                                                      position=np.zeros(3))]
    meta = {"voxel_volumes_ml": {0: {"lv_cavity": 150.0}, "1": {"lv_cavity": 120.5}}}
    study = SimpleNamespace(meta=meta, images=images)
    vols, spacing = _voxel_curve(study, [0, 1])
    assert vols == [150.0, 120.5] and spacing == pytest.approx(8.0)
    assert _voxel_curve(study, [0, 1, 2]) is None
    assert _voxel_curve(SimpleNamespace(meta={}, images=images), [0, 1]) is None
