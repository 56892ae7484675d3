"""Rates of a volume curve that steps by a slab where the SA-only stack's extent changes
(issue 29: the basal slice leaving the LV made PER 2.5 x the truth). Against the exact
derivative of an analytic curve and the analytic truth of a 50-frame ukbb-layout phantom."""

from __future__ import annotations

from pathlib import Path

import nibabel as nib
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cardionurbs import load_study
from cardionurbs.analysis.rates import extent_steps, filling_rates
from cardionurbs.io.nifti import read_label_volume
from cardionurbs.phantom.generate import generate
from cardionurbs.phantom.labelmaps import write_labelmaps
from cardionurbs.pipeline import analyse_study


def _quantised(v_true, spacing_mm, sweep_mm, share, first_mm):
    """A slab-quantised curve: the base follows the volume (sweeping ``sweep_mm`` over the
    stroke volume and ``share`` of it), slices every ``spacing_mm`` from ``first_mm`` below the
    ED base; the model closes half a slice beyond the highest slice below the base."""
    sv = v_true.max() - v_true.min()
    b = -sweep_mm * (v_true.max() - v_true) / sv          # base height, 0 at ED
    area = share * sv / sweep_mm                          # mL per mm of base motion
    top = -first_mm - spacing_mm * np.ceil((-first_mm - b) / spacing_mm - 1e-12)
    return v_true + area * (top + 0.5 * spacing_mm - b), top


@settings(max_examples=20, deadline=None)
@given(first=st.floats(0.5, 7.5), sweep=st.floats(10.0, 18.0), share=st.floats(0.2, 0.4))
@example(first=6.015625, sweep=14.03125, share=0.25)   # the second slice passed for one frame
def test_slab_steps_do_not_make_a_rate(first, sweep, share):
    """Where the base passes two slices each way, the stepped curve's PER and PEFR are within
    5 % of the exact derivative's peaks (the spline through the steps gave 2-3 x); where it
    passes one, the base's sweep is known only within a slice (docs/metrics.md): within 20 %.
    The example passes the second slice for one frame at ES: its two steps are neighbours, and
    each step's size must come from step-free intervals (PER was +11 % with the other step in
    the cubic prediction)."""
    rr, n = 1000.0, 50
    tau = np.arange(n) / n
    w = 2 * np.pi
    v_true = 100 + 30 * np.cos(w * tau) + 8 * np.cos(2 * w * tau) + 3 * np.sin(2 * w * tau)
    obs, top = _quantised(v_true, 8.0, sweep, share, first)
    steps = [(i, (i + 1) % n) for i in range(n) if top[i] != top[(i + 1) % n]]
    es = int(np.argmin(v_true))
    got, reason = filling_rates(tau * rr, obs, 0, es, rr, steps=steps)
    assert reason == ""
    plain, _ = filling_rates(tau * rr, obs, 0, es, rr)
    tf = np.linspace(0, 1, 100001)[:-1]
    d = (-30 * w * np.sin(w * tf) - 16 * w * np.sin(2 * w * tf) + 6 * w * np.cos(2 * w * tf)) / rr * 1000
    t_es = tau[es]
    per = -d[tf <= t_es].min()
    pefr = d[(tf >= t_es) & (tf <= t_es + 2 * (1 - t_es) / 3)].max()
    bound = 0.05 if len(steps) >= 4 else 0.20
    assert got["PER (mL/s)"] == pytest.approx(per, rel=bound)
    assert got["PEFR (mL/s)"] == pytest.approx(pefr, rel=bound)
    if steps:
        assert plain["PER (mL/s)"] > 1.2 * per          # what the steps did to the spline


@pytest.fixture(scope="module")
def ukbb50(tmp_path_factory):
    """A normal 50-frame phantom in the ukbb_cardiac layout, SA stack only (8 mm slices,
    1.8 mm pixels), with the header's time unit as UK Biobank writes it (unknown)."""
    ph = generate("normal", seed=0, frames=50, matrix=160, fov_mm=288.0, n_sa=10,
                  sa_spacing_mm=8.0, volume_check=False)
    folder = tmp_path_factory.mktemp("ukbb50")
    write_labelmaps(ph, folder, "ukbb", quirks="real", images=False)
    for q in folder.glob("seg*la*"):
        q.unlink()
    return ph, folder


def _with_unit(folder: Path, dest: Path, unit: str, scale: float) -> Path:
    """The map again with the time step in ``unit`` (the same interval)."""
    img = nib.load(str(folder / "seg_sa.nii.gz"))
    h = img.header.copy()
    h.set_xyzt_units("mm", unit)
    z = list(h.get_zooms())
    z[3] = z[3] * scale
    h.set_zooms(z)
    dest.mkdir()
    nib.save(nib.Nifti1Image(np.asanyarray(img.dataobj), img.affine, h), str(dest / "seg_sa.nii.gz"))
    return dest


def test_ukbb_50_frames_per_ed_es_whatever_the_time_unit(ukbb50, tmp_path):
    """ED 0 and ES the smallest LV cavity (ukbb_cardiac's definitions), the same frame times
    with seconds, milliseconds or an unknown unit, and PER within 5 % of the truth."""
    ph, folder = ukbb50
    dt = 60000.0 / ph.study.heart_rate_bpm / len(ph.phases)
    for unit, scale in (("sec", 1.0), ("msec", 1000.0)):     # the header alone decides the step
        path = _with_unit(folder, tmp_path / unit, unit, scale) / "seg_sa.nii.gz"
        assert read_label_volume(path).dt_ms == pytest.approx(dt, rel=1e-4), unit
    study = load_study(folder)                                  # unit unknown, as UK Biobank's
    assert study.frame_times_ms[1] == pytest.approx(dt, rel=1e-4)
    assert (study.ed_frame, study.es_frame) == (0, ph.es_frame)
    vox = study.meta["voxel_volumes_ml"]
    assert ph.es_frame == min(vox, key=lambda f: vox[f]["lv_cavity"])
    model, m = analyse_study(study)
    frames = list(model.curve_frames)
    assert extent_steps(model.study, frames, [model.study.frame_times_ms[f] for f in frames])
    assert m["PER (mL/s)"] == pytest.approx(ph.truth["metrics"]["PER (mL/s)"], rel=0.05)
