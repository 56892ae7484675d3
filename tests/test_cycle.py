"""Frames that agree with their neighbours (issue #30, item 2; cardionurbs.anatomy.cycle):
a frame with half its contours removed or 3 mm noise does not make a volume its neighbours
contradict; ES and EF stay with the truth; every supported frame is flagged."""

from __future__ import annotations

import dataclasses
import importlib
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from cardionurbs import reconstruct
from cardionurbs.analysis.function import measure, volume_curve
from cardionurbs.analysis.quality import assess, partial_tracings, section_support_flag
from cardionurbs.anatomy.cycle import (MIN_FRAMES, SUPPORT_BOUND, basal_edges, bracketing_frames, check_curve,
                                       lagrange_weights, partial_sections, section_areas,
                                       support_basal)
from cardionurbs.anatomy.model import BiventricularModel
from cardionurbs.anatomy.sections import frame_geometry

generate = importlib.import_module("cardionurbs.phantom.generate")


def _curve(n: int, es: float, edv: float = 150.0, ef: float = 0.6) -> dict[int, float]:
    """A smooth volume curve (ED at 0, ES at phase ``es``), mL per frame."""
    t = np.arange(n) / n
    phase = np.where(t < es, 0.5 * (1 - np.cos(np.pi * t / es)),
                     0.5 * (1 + np.cos(np.pi * (t - es) / (1 - es))))
    return {k: float(edv * (1 - ef * p)) for k, p in enumerate(phase)}


def test_lagrange_weights_reproduce_cubics():
    x = np.array([-2.0, -1.0, 1.0, 2.0])
    w = lagrange_weights(x, 0.0)
    assert w == pytest.approx([-1 / 6, 4 / 6, 4 / 6, -1 / 6])
    y = 3 * x ** 3 - x ** 2 + 2 * x + 5
    assert w @ y == pytest.approx(5.0)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(MIN_FRAMES, 40), es=st.floats(0.3, 0.45), ef=st.floats(0.2, 0.75),
       noise=st.floats(0.0, 0.005), seed=st.integers(0, 1000))
def test_smooth_curves_need_no_support(n, es, ef, noise, seed):
    v = _curve(n, es, ef=ef)
    rng = np.random.default_rng(seed)
    v = {f: x * (1 + noise * rng.standard_normal()) for f, x in v.items()}
    c = check_curve(v)
    assert c.supported == {} and c.consistent == v


@settings(max_examples=40, deadline=None)
@given(n=st.integers(20, 40), es=st.floats(0.3, 0.45), ef=st.floats(0.3, 0.7),
       where=st.floats(0.05, 0.95), up=st.booleans(), extra=st.floats(0.06, 0.2))
@example(n=20, es=0.3046875, ef=0.625, where=0.0625, up=False, extra=0.125)  # a near-tie
@example(n=22, es=0.3, ef=0.6953125, where=0.25, up=False, extra=0.1)  # a dip beside ES
def test_a_spike_is_supported_and_its_volume_restored(n, es, ef, where, up, extra):
    """A frame beyond both neighbours (by more than they differ and than 4 %)."""
    truth = _curve(n, es, ef=ef)
    bad = int(where * n)
    v = dict(truth)
    a, b = truth[(bad - 1) % n], truth[(bad + 1) % n]
    step = max(abs(a - b), extra * min(a, b)) * 1.2
    v[bad] = max(a, b) + step if up else min(a, b) - step
    c = check_curve(v)
    assert list(c.supported) == [bad]
    assert c.consistent[bad] == pytest.approx(truth[bad], rel=0.03)
    assert c.departure[bad] == pytest.approx(v[bad] / c.consistent[bad] - 1)
    assert f"frame {bad} supported" in c.describe(bad)


def _cusp_curve(n: int, es: float, ef: float, edv: float = 150.0) -> dict[int, float]:
    """The phantom's exact LV curve (:class:`cardionurbs.phantom.motion.VolumeCurve`): ED a
    cusp, the atrial kick before it and the ejection starting from rest after it."""
    from cardionurbs.phantom.motion import VolumeCurve
    phase = VolumeCurve(es_fraction=round(es * n) / n)(np.arange(n) / n)
    return {k: float(edv * (1 - ef * p)) for k, p in enumerate(phase)}


@settings(max_examples=60, deadline=None)
@given(n=st.integers(MIN_FRAMES, 24), es=st.floats(0.3, 0.45), ef=st.floats(0.45, 0.7),
       before=st.floats(0.0, 0.02), after=st.floats(-0.02, 0.0), up=st.floats(0.001, 0.02))
@example(n=20, es=0.35, ef=0.62, before=0.015, after=-0.016, up=0.002)  # phantom seed 8
def test_an_ed_cusp_is_not_supported_a_spike_as_large_is(n, es, ef, before, after, up):
    """Noise of up to 2 % (1 px contour noise: 0.9 % rms, at most 1.9 % about ED on 24
    phantoms) lifting the frame before ED and lowering the one after, and ED just above
    both by more than the bound and than they differ (a spike by its neighbours): at the
    phantom's exact cusp, which the cubic through its neighbours under-reaches (by 3.5 to
    5.1 % on 30 phantoms), it stays its own (below the ejection limb's extrapolation); the same lift of a
    diastasis frame over its neighbours is a spike and is supported, and so is an ED above
    both limbs' extrapolations (issue #30; phantom seed 8 at 1 px noise: ED 146.6 mL
    between 132.5 and 139.3, truth 145.6, was supported at 139.9 mL, EF -2.55 points;
    reports/validation-quality.md). Up to 24 frames: in a finer cine the ejection limb's
    first frames are closer to ED, and 2 % noise against it on all three frames (3 % up
    to 22 frames) can lift ED above its extrapolation."""
    m = n // 2                            # ED mid-cine (a cine need not start at ED): a
    truth = {(k + m) % n: x for k, x in _cusp_curve(n, es, ef).items()}   # spike there
    v = {**truth, m - 1: truth[m - 1] * (1 + before), m + 1: truth[m + 1] * (1 + after)}
    near, gap = max(v[m - 1], v[m + 1]), abs(v[m + 1] - v[m - 1])    # leaves it cyclic
    v[m] = (near + max(gap, SUPPORT_BOUND * near)) * (1 + up)
    assume(abs(v[m] / truth[m] - 1) <= 0.02)       # ED itself off by noise only
    assert check_curve(v).supported == {}
    k = (m + round(0.8 * n)) % n          # in diastasis: the same lift is a spike
    d = {**truth, k: max(truth[k - 1], truth[k + 1]) * v[m] / near}
    assert list(check_curve(d).supported) == [k]
    limbs = max(2 * v[m - 1] - v[m - 2], 2 * v[m + 1] - v[m + 2])   # extrapolated to ED
    c = check_curve({**v, m: limbs * (1 + SUPPORT_BOUND) * 1.01})
    assert list(c.supported) == [m] and c.consistent[m] < limbs


def test_a_frame_that_cannot_be_built_is_interpolated():
    truth = _curve(20, 0.4)
    v = {**truth, 7: math.nan}
    c = check_curve(v)
    assert list(c.supported) == [7] and c.consistent[7] == pytest.approx(truth[7], rel=0.01)
    assert "cannot be built" in c.describe(7)


def test_coarse_cines_are_not_checked():
    v = _curve(MIN_FRAMES - 1, 0.4)
    v[3] *= 0.8
    assert check_curve(v).supported == {}


def test_a_frame_between_its_neighbours_is_not_given_a_trough_they_do_not_show():
    """An incomplete frame beside ES whose cubic (through a steep side) undershoots both
    neighbours: it lies between them, so the interpolant is held within their range and it
    is not supported (a phantom at 1 px noise, normal seed 1: supporting it at 55.1 mL made
    it ES and the EF 1.8 points high; reports/validation-quality.md)."""
    raw = [156.0, 150.15, 129.23, 102.83, 85.46, 70.45, 61.41, 57.35, 58.06, 62.46, 87.15,
           114.71, 121.94, 126.40, 128.18, 131.72, 133.02, 131.27, 133.82, 141.13]
    v = dict(enumerate(raw))
    counts = {f: 10 for f in v} | {8: 9}             # one section fewer than both neighbours
    c = check_curve(v, contours=counts)
    assert c.supported == {} and c.consistent == v
    v[8] = 50.0                                      # beyond both: a spike, supported
    c = check_curve(v, contours=counts)
    assert list(c.supported) == [8] and c.consistent[8] < 57.35


def test_an_incomplete_es_trough_is_not_supported_by_the_cubic_across_a_gap():
    """The frame before ES not built (3 mm noise), ES one section fewer than both its
    neighbours (the apical cavity closing): the cubic through frames 5, 6, 9, 10 overshoots
    the trough (49.0 mL, truth 50.7; its own 51.3), and ES, lying above both one-sided
    extrapolations, stays its own; 20 % lower it lies below both and is supported (phantom
    normal seed 9 at 1 px noise, corrupted: supporting it made the EF 1.25 points high;
    reports/validation-quality.md)."""
    raw = [148.2, 143.9, 130.4, 106.9, 86.8, 73.0, 58.9, math.nan, 51.3, 51.8, 58.8, 87.5,
           112.0, 118.0, 120.4, 124.0, 125.4, 126.9, 125.9, 130.5]
    v = dict(enumerate(raw))
    counts = {f: 11 for f in v} | {k: 9 for k in (4, 5, 6, 9, 10)} | {8: 8, 11: -6}
    del counts[7]
    c = check_curve(v, contours=counts)
    assert sorted(c.supported) == [7] and c.consistent[8] == 51.3
    v[8] = 0.8 * 51.3
    c = check_curve(v, contours=counts)
    assert sorted(c.supported) == [7, 8]


# ------------------------------------------------------------------ the basal region
def _stacks(n: int, gone: range) -> dict[int, list[str]]:
    """Five-slice stacks whose basal slice sa_01 is not traced at the frames ``gone``."""
    full = [f"sa_0{k}" for k in range(1, 6)]
    return {f: full[1:] if f in gone else list(full) for f in range(n)}


def test_basal_edges_are_the_frames_beside_a_change_of_the_basal_stack():
    ref, edges = basal_edges(_stacks(25, range(7, 13)), list(range(25)), cyclic=True)
    assert ref == "sa_02" and sorted(edges) == [6, 7, 12, 13]
    assert "sa_01" in edges[6] and "frame 7's (none)" in edges[6]
    assert basal_edges(_stacks(25, range(0)), list(range(25)), cyclic=True) == ("sa_01", {})
    # the change across the cycle's end counts only when the frames wrap
    s = _stacks(20, range(15, 20))
    assert sorted(basal_edges(s, list(range(20)), cyclic=True)[1]) == [0, 14, 15, 19]
    assert sorted(basal_edges(s, list(range(20)), cyclic=False)[1]) == [14, 15]
    assert basal_edges({0: ["sa_01"], 1: ["sa_02"], 2: ["sa_03"]}, [0, 1, 2], False) == (None, {})


def test_a_partial_basal_region_is_supported_by_its_neighbours():
    """An edge frame whose basal region lacks 12 mL: it keeps its own apical part and takes
    the cubic's basal region (within 2 % of the truth); an edge frame on the curve is left
    alone; the check then reports its own volume as raw and names the basal region."""
    n = 25
    total, basal = _curve(n, 0.4), _curve(n, 0.4, edv=70.0, ef=0.7)
    v = dict(total)
    v[14] -= 12.0
    own_basal = {f: basal[f] - (12.0 if f == 14 else 0.0) for f in range(n)}
    asked = []

    def basal_ml(f):
        asked.append(f)
        return own_basal[f]

    edges = {13: "edge", 14: "edge", 7: "edge"}
    got = support_basal(v, edges, "sa_02", basal_ml)
    assert list(got) == [14] and set(asked) <= {5, 6, 8, 9, 7, 11, 12, 13, 14, 15, 16}
    b = got[14]
    assert b.sources == [11, 12, 15, 16] and b.total == pytest.approx(total[14], rel=0.02)
    assert b.own == v[14] and b.basal == own_basal[14]
    c = check_curve(v, basal=got)
    assert c.raw[14] == v[14] and c.consistent[14] == pytest.approx(b.total)
    assert c.supported == {14: [11, 12, 15, 16]}
    assert c.departure[14] == pytest.approx(v[14] / b.total - 1)
    assert "supported by its neighbours' basal region" in c.describe(14)
    assert support_basal(dict(list(v.items())[:MIN_FRAMES - 1]), edges, "sa_02", basal_ml) == {}


def test_bivme_basal_slice_at_the_edge_of_its_run_is_supported(bivme_model):
    """bivme-patient1: sa_01 (not traced at frames 7-12) is a partial tracing at frame 14,
    where the base re-enters it; the LV cavity basal to sa_02 of frame 14 is supported by
    its neighbours, and no frame of the LV cavity curve departs more than 5 % from the mean
    of its two neighbours (issue #30; 6.3 % at frame 14 without it). ED, ES, and frame 10's
    support are unchanged."""
    study, model = bivme_model
    c = model.cycle
    assert 14 in c.basal and c.basal[14].slice == "sa_02" and c.basal[14].sources == [11, 12, 15, 16]
    assert c.consistent[14] > c.raw[14] + 8.0            # 102.1 -> 114.9 mL
    y = np.array([c.consistent[f] for f in sorted(c.consistent)])
    dep = y[1:-1] / ((y[:-2] + y[2:]) / 2) - 1
    assert np.abs(dep).max() < 0.05, np.round(dep, 3)
    assert (model.ed_frame, model.es_frame) == (24, 10) and 10 in model.supported
    q = assess(model, measure(model))
    assert any(x.startswith("frame 14 supported by its neighbours' basal region") for x in q.flags)


# ------------------------------------------------------------------ corrupted studies
def _corrupt(study, frame: int, how: str, seed: int = 0):
    """The study with one frame's contours halved (every other contour of each structure
    and view left out) or with 3 mm in-plane noise on every point
    (``benchmarks/corrupted_frames.py``'s ``corrupt``, which measures the same on more seeds)."""
    import importlib.util
    import sys

    mod = sys.modules.get("corrupted_frames")
    if mod is None:
        path = Path(__file__).resolve().parents[1] / "benchmarks" / "corrupted_frames.py"
        spec = importlib.util.spec_from_file_location("corrupted_frames", path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules["corrupted_frames"] = mod
        spec.loader.exec_module(mod)
    return mod.corrupt(study, frame, how, seed)


def _lv_curve(study):
    model = reconstruct(study)
    return model, np.array(volume_curve(model, every_structure=False)["lv_cavity (mL)"])


@pytest.fixture(scope="module")
def bivme(bivme_model):
    study, model = bivme_model                    # conftest.py: reconstructed once per session
    curve = np.array(volume_curve(model, every_structure=False)["lv_cavity (mL)"])
    return study, curve, model.sections_in_time


@pytest.mark.parametrize("frame,how", [(4, "half"), (17, "noise")])
def test_bivme_corrupted_frame_keeps_the_curve(bivme, frame, how):
    study, untouched, own = bivme
    model, curve = _lv_curve(_corrupt(study, frame, how))
    assert np.all(np.abs(curve / untouched - 1) < 0.05), np.round(curve / untouched - 1, 3)
    q = assess(model, measure(model))
    assert all(any(f"frame {f} supported" in x for x in q.flags) for f in model.supported)
    if how == "half":           # its missing sections are made from its neighbours'
        assert set(model.sections_in_time) - set(own) == {frame}
        assert any(x.startswith(f"frame {frame} supported by its neighbours' sections")
                   for x in q.flags)


def _without_slice(study, slice_id: str, frames: set[int]):
    """The study with every SA contour of one slice removed at ``frames``."""
    out = [c for c in study.contours if not (c.slice == slice_id and c.frame in frames)]
    return dataclasses.replace(study, contours=out, warnings=list(study.warnings))


def test_bivme_slice_missing_in_some_frames_is_supported_in_time(bivme):
    """A mid-ventricular SA slice removed (every surface) in three frames: the three are
    supported by sections interpolated in time, flagged by name, and the curve stays within
    5 % of the untouched study's."""
    study, untouched, own = bivme
    model, curve = _lv_curve(_without_slice(study, "sa_03", {15, 16, 17}))
    assert np.all(np.abs(curve / untouched - 1) < 0.05), np.round(curve / untouched - 1, 3)
    assert set(model.sections_in_time) - set(own) == {15, 16, 17}
    assert {sl for s, sl in model.sections_in_time[16]} == {"sa_03"}
    assert model.sections_in_time[16][("lv_endo", "sa_03")] == (14, 18)
    vc = volume_curve(model, every_structure=False)    # raw: the frames' own contours
    raw, used = (np.array(vc[k])[15:18] for k in ("lv_cavity raw (mL)", "lv_cavity (mL)"))
    assert raw == pytest.approx([model.own_lv_cavity_volume(f) for f in (15, 16, 17)])
    assert np.all(np.isfinite(raw)) and np.abs(raw - used).max() > 1.0, (raw, used)
    q = assess(model, measure(model))
    for f in (15, 16, 17):
        assert sum(x.startswith(f"frame {f} supported by its neighbours' sections") and
                   "lv_endo sa_03" in x for x in q.flags) == 1


@given(n=st.integers(MIN_FRAMES, 30), data=st.data())
@settings(max_examples=40, deadline=None)
def test_bracketing_frames_are_the_nearest_traced_on_each_side(n, data):
    frames = list(range(n))
    traced = set(data.draw(st.lists(st.sampled_from(frames), min_size=1, max_size=n - 1)))
    f = data.draw(st.sampled_from(sorted(set(frames) - traced)))
    a, b, w = bracketing_frames(f, frames, traced, cyclic=True)
    da, db = (f - a) % n or n, (b - f) % n or n
    assert a in traced and b in traced
    assert not any(0 < (f - k) % n < da or 0 < (k - f) % n < db for k in traced)
    assert w == pytest.approx(da / (da + db))
    flat = bracketing_frames(f, frames, traced, cyclic=False)
    if min(traced) < f < max(traced):
        assert flat is not None and flat[0] < f < flat[1]
    else:
        assert flat is None


@pytest.fixture(scope="module")
def noisy_phantom():
    return generate.generate("normal", seed=4, frames=20, noise_px=1.0, volume_check=False)


def test_phantom_corrupted_frames_keep_es_and_ef(noisy_phantom):
    """3 mm noise on the frame before ES (it cannot be built) and half the contours of a
    filling frame: the same ES and EF as the untouched phantom (0.2 point), ES within one
    frame and EF within 1 point of the truth (issue #30; this seed 0.85 point, seeds 0-2
    in reports/validation-quality.md), the curve within 5 % of the untouched one, the half
    frame's missing sections interpolated in time, every supported frame flagged."""
    ph = noisy_phantom
    truth = ph.truth
    es = truth["es_frame"]
    base = reconstruct(ph.study)
    ref = measure(base)
    study = _corrupt(_corrupt(ph.study, es - 1, "noise"), es + 3, "half")
    model = reconstruct(study)
    m = measure(model)
    assert model.es_frame == base.es_frame and abs(model.es_frame - es) <= 1
    assert abs(m["LVEF (%)"] - ref["LVEF (%)"]) < 0.2
    assert abs(m["LVEF (%)"] - truth["metrics"]["LVEF (%)"]) < 1.0
    assert es - 1 in model.supported and not base.supported    # the half frame: if needed
    curve = volume_curve(model, every_structure=False)
    assert curve["frame"] == ph.study.contoured_frames
    assert math.isnan(curve["lv_cavity raw (mL)"][es - 1])
    untouched = np.array(volume_curve(base, every_structure=False)["lv_cavity (mL)"])
    assert np.all(np.abs(np.array(curve["lv_cavity (mL)"]) / untouched - 1) < 0.05)
    q = assess(model, m)
    assert all(any(f"frame {f} supported" in x for x in q.flags) for f in model.supported)
    assert es + 3 in model.sections_in_time and not base.sections_in_time
    assert all(any(x.startswith(f"frame {f} supported by its neighbours' sections")
                   for x in q.flags) for f in model.sections_in_time)


def test_an_incomplete_frame_off_the_cubic_is_supported():
    """Within its neighbours' range but off the smooth curve: supported only when its
    contours say it is incomplete (fewer than both neighbours', or one left out)."""
    truth = _curve(24, 0.4)
    v = dict(truth)
    v[4] = truth[4] * 1.06                        # on the steep systolic slope
    assert check_curve(v).supported == {}
    full = {f: 8 for f in v}
    assert check_curve(v, contours=full).supported == {}
    assert list(check_curve(v, contours={**full, 4: 5}).supported) == [4]
    assert list(check_curve(v, contours={**full, 4: -8}).supported) == [4]
    c = check_curve(v, contours={**full, 4: 5})
    assert c.consistent[4] == pytest.approx(truth[4], rel=0.01)


def _shrunk(study, frame: int, slice_id: str, structure: str, fraction: float):
    """The study with one SA contour scaled about its centroid to ``fraction`` of its area."""
    out = []
    for c in study.contours:
        if c.frame == frame and c.slice == slice_id and c.structure == structure:
            m = c.points.mean(axis=0)
            c = dataclasses.replace(c, points=m + (c.points - m) * math.sqrt(fraction))
        out.append(c)
    return dataclasses.replace(study, contours=out, warnings=list(study.warnings))


def _one_frame(study, frame: int) -> BiventricularModel:
    """A lazy model of the whole cine whose curve is not searched (ED = ES = ``frame``):
    one frame's cavity without building the other nineteen."""
    return BiventricularModel(study, study.contoured_frames, ed_es=(frame, frame))


def test_a_partial_tracing_is_replaced_from_its_neighbouring_frames(noisy_phantom):
    """One mid-ventricular LV endocardial contour shrunk to 60 % of its area in one frame
    (a partial tracing): it alone is found, against the same slice in the neighbouring
    frames, replaced by the section interpolated in time, warned and flagged by name; the
    frame's LV cavity is back within 2 % of the untouched one. The untouched phantom (1 px
    noise) has none."""
    study, frame, sl = noisy_phantom.study, 12, "sa_04"
    frames = study.contoured_frames
    clean = {f: section_areas(frame_geometry(study, f)) for f in frames}
    assert not any(partial_sections(f, clean, frames) for f in frames)
    shrunk = _shrunk(study, frame, sl, "lv_endo", 0.6)
    areas = {**clean, frame: section_areas(frame_geometry(shrunk, frame))}
    assert {f: set(partial_sections(f, areas, frames)) for f in frames
            if partial_sections(f, areas, frames)} == {frame: {("lv_endo", sl)}}
    untouched, model = _one_frame(study, frame), _one_frame(shrunk, frame)
    assert model.geometry[frame].in_time == {("lv_endo", sl): (frame - 1, frame + 1)}
    assert model.own_lv_cavity_volume(frame) < 0.97 * untouched.own_lv_cavity_volume(frame)
    assert model.lv_cavity_volume(frame) == pytest.approx(untouched.lv_cavity_volume(frame),
                                                          rel=0.02)
    assert any(f"frame {frame}: slice {sl}: lv_endo contour encloses" in w and "partial" in w
               for w in model.warnings)
    flag = section_support_flag(frame, model.sections_in_time[frame],
                                partial_tracings(model, frame))
    assert f"lv_endo {sl} (a partial tracing, from frames {frame - 1} and {frame + 1})" in flag
    assert not untouched.sections_in_time and not partial_tracings(untouched, frame)
