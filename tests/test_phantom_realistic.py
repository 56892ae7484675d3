"""Realistic phantom anatomy: not a toy, exact where it claims to be, and measured within bounds.

Checks against the analytic model only (never against the reconstruction), except the last
tests, which measure the reconstruction against the truth as the issue's bounds ask.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.measure import EllipseModel

from cardionurbs.geometry import fit_plane
from cardionurbs.phantom import annotate
from cardionurbs.phantom import truth_realistic as trr
from cardionurbs.phantom.generate import generate, write_phantom
from cardionurbs.phantom.geometry import Acquisition, slice_specs
from cardionurbs.phantom.motion import Motion
from cardionurbs.phantom.presets import load_preset, sample_subject, solve_anatomy
from cardionurbs.phantom.shape import ShapeModes, draw_shape


@pytest.fixture(scope="module")
def real():
    return generate("normal", seed=7, frames=2, anatomy_model="realistic")


def _motion(an):
    return Motion(ls=0.15, lv_ef=0.62, rv_ef=0.57, septal_flattening=0.05, apex_rotation_deg=8.0,
                  base_rotation_deg=-4.0, z_base=an.z_base)


@pytest.fixture(scope="module")
def ideal_pair():
    """The same ideal anatomy twice: without shape (explicit formulas) and with empty shape modes
    (the general, realistic code paths)."""
    a = solve_anatomy(sample_subject(load_preset("normal"), np.random.default_rng(3)))
    return a, dataclasses.replace(a, shape=ShapeModes()), _motion(a)


# ----------------------------------------------------------------- not a toy
def test_mid_ventricular_section_is_not_an_ellipse(real):
    specs = [s for s in real.slices if s.view == "SA"]
    mid = min(specs, key=lambda s: abs(s.height - 0.5 * real.anatomy.z_base))
    c = annotate.sa_contours(real.anatomy, real.motion, mid, 0.0, n_lv=360)["lv_endo"][:, :2]
    model = EllipseModel.from_estimate(c)
    rms = float(np.sqrt(np.mean(model.residuals(c) ** 2)))
    assert rms >= 1.0, rms


def test_mitral_annulus_is_a_saddle(real):
    lm = annotate.bend(real.anatomy, annotate.landmarks(real.anatomy, real.motion, 0.0)["mitral"])
    c, n = fit_plane(lm)
    assert np.abs((lm - c) @ n).max() >= 2.0


def test_apex_off_the_long_axis_and_wall_thicker_at_the_septum(real):
    an = real.anatomy
    assert np.hypot(*an.shape.apex_shift_mm) >= 4.0
    z = 0.5 * an.z_base
    th = np.array([0.0, np.pi])                       # septum (toward the RV), lateral wall
    s1, s2 = an.lv_sections(np.full(2, z), th)
    wall = np.sqrt(s2) - np.sqrt(s1)
    assert wall[0] > wall[1] + 1.0


def test_shape_is_deterministic_per_seed():
    a = draw_shape(np.random.default_rng(11))
    b = draw_shape(np.random.default_rng(11))
    c = draw_shape(np.random.default_rng(12))
    assert a == b and a != c


# ----------------------------------------------------------------- truth
def test_two_truth_methods_agree_and_myocardium_is_incompressible(real):
    vols = real.truth["volumes"]
    assert vols["max_relative_difference"] < 0.002
    myo = list(vols["lv_myocardium_material_mL"].values())
    assert max(myo) - min(myo) < 1e-3 * np.mean(myo)


def test_ideal_truth_is_recovered_by_the_numerical_methods(ideal_pair):
    """With empty shape modes the numerical methods must give the closed forms of the ideal."""
    from cardionurbs.phantom.truth import analytic_volumes
    a, b, mo = ideal_pair
    for f in (0.0, 1.0):
        exact = analytic_volumes(a, mo, f)
        for got in (trr.section_volumes(b, mo, f), trr.mesh_volumes(b, mo, f)):
            for key in exact:
                assert got[key] == pytest.approx(exact[key], rel=1.5e-3), (f, key)


def test_section_modes_keep_the_ideal_section_areas(ideal_pair):
    a, _, _ = ideal_pair
    b = dataclasses.replace(a, shape=dataclasses.replace(draw_shape(np.random.default_rng(2)),
                                                         septal_thickening=0.1))
    assert b.lv_cavity_volume() == pytest.approx(a.lv_cavity_volume(), rel=1e-9)
    assert b.lv_myocardial_volume() == pytest.approx(a.lv_myocardial_volume(), rel=1e-9)


# ----------------------------------------------------------------- contours
def test_general_la_contours_match_the_explicit_ideal_ones(ideal_pair):
    """The marching-squares LA path on the ideal anatomy lies on the ideal surfaces: each point's
    distance to the dense explicit contour is below 0.05 mm, and the annulus ends coincide."""
    from scipy.spatial import cKDTree
    a, b, mo = ideal_pair
    for spec in (s for s in slice_specs(a, Acquisition()) if s.view == "LA"):
        for f in (0.0, 1.0):
            ref = annotate.la_contours(a, mo, spec, f, n_side=3000, with_rv=spec.id == "la_4ch")
            got = annotate.la_contours(b, mo, spec, f, with_rv=spec.id == "la_4ch")
            assert set(got) == set(ref)
            for key in ref:
                d, _ = cKDTree(ref[key]).query(got[key])
                assert d.max() < 0.05, (spec.id, f, key, d.max())
                assert np.linalg.norm(got[key][0] - ref[key][0]) < 0.01
                assert np.linalg.norm(got[key][-1] - ref[key][-1]) < 0.01


def test_realistic_contours_lie_on_their_planes_and_surfaces(real):
    st_ = real.study
    planes = {im.id: im for im in st_.images}
    for c in st_.contours:
        pl = planes[c.image]
        n = np.cross(pl.row_cosine, pl.column_cosine)
        assert np.abs((c.points - pl.position) @ n).max() < 1e-6
    an, mo = real.anatomy, real.motion
    for spec in (s for s in real.slices if s.view == "LA"):
        cont = annotate.la_contours(an, mo, spec, 0.0)
        for key in ("lv_endo", "lv_epi"):
            fl = annotate.material_fields(an, mo, annotate.bend(an, cont[key]), 0.0)
            # the wall term is (s' − G(S)) / 50 mm: a radial distance of 50 |term| / (2 r')
            tree = annotate.region_logic(key, len(fl[key]))[0]     # (with the LVOT's terms too)
            dist = 50.0 * np.abs(annotate.tree_value(tree, list(fl[key]))) / (2.0 * np.sqrt(fl["s"]) + 1e-9)
            # within 0.1 mm (a tenth of a pixel): mostly < 0.01 mm, but near the epicardial apex
            # up to 0.067 mm on this subject's 4-chamber view, depending on where the 1 mm grid
            # falls (it moved when the tricuspid saddle re-solved the RV size)
            assert dist.max() < 0.1, (spec.id, key, dist.max())


@functools.cache
def _ideal_normal():
    return solve_anatomy(sample_subject(load_preset("normal"), np.random.default_rng(1)))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), x=st.floats(-40, 40), y=st.floats(-40, 40), z=st.floats(2, 80),
       f=st.floats(0, 1))
def test_realistic_motion_and_bend_are_invertible(seed, x, y, z, f):
    an = dataclasses.replace(_ideal_normal(), shape=draw_shape(np.random.default_rng(seed), "lad"))
    mo = _motion(an)
    p = np.array([[x, y, z]])
    q = annotate.bend(an, mo.forward(an, p, f))
    back = mo.inverse(an, annotate.unbend(an, q), f)
    assert np.allclose(back, p, atol=1e-7)


# ----------------------------------------------------------------- infarct
def test_infarct_territory_is_thinner_and_hypokinetic():
    ph = generate("normal", seed=2, frames=2, anatomy_model="realistic", infarct="lad")
    an, mo = ph.anatomy, ph.motion
    z = 0.45 * an.z_base
    inf, rem = np.radians(25.0), np.radians(180.0)        # LAD centre; lateral (remote) wall
    th = np.array([inf, rem])
    zz = np.full(2, z)
    healthy = dataclasses.replace(an, shape=dataclasses.replace(an.shape, infarct=None))
    wall = np.sqrt(an.s_lv_epi(zz, th)) - np.sqrt(an.s_lv_endo(zz, th))
    wall0 = np.sqrt(healthy.s_lv_epi(zz, th)) - np.sqrt(healthy.s_lv_endo(zz, th))
    assert wall[0] < 0.7 * wall0[0]                          # thinned inside the territory
    assert wall[1] == pytest.approx(wall0[1], abs=1e-9)      # untouched remote wall
    assert np.allclose(an.s_lv_epi(zz, th), healthy.s_lv_epi(zz, th))   # the RV side is kept
    k = mo.kappa_lv(th, 1.0, np.full(2, z), an)
    assert 1 - k[0] < 0.4 * (1 - k[1])                      # the territory barely ejects


def test_thickness_truth_sees_the_infarct():
    """The regional truth measures the wall the infarct thinned (its endocardial grid is the
    realistic section, infarct included): the mid and apical anterior and anteroseptal segments,
    inside the LAD territory (25° ± 70°, apex to 3/4 of the base height), are > 1 mm thinner at
    ED than the healthy twin's, the inferior and lateral segments outside it are unchanged, and
    the reconstruction's ED segment thickness agrees with that truth within the noise-free
    bound (0.5 mm). (At ES the infarct phantoms' segments next to the territory's edge read up
    to ~1.7 mm thinner than the truth: reports/validation-regional-realistic.md.)"""
    from cardionurbs.analysis.regional import regional_metrics
    from cardionurbs.anatomy.model import reconstruct
    sick = generate("normal", seed=4, frames=2, volume_check=False, anatomy_model="realistic",
                    infarct="lad")
    well = generate("normal", seed=4, frames=2, volume_check=False, anatomy_model="realistic")
    t, t0 = sick.truth["metrics"], well.truth["metrics"]
    lad, remote = (7, 8, 13, 14), (4, 5, 6, 10, 11, 12, 16)
    for k in lad:
        assert t[f"WT_AHA_{k} (mm)"] < t0[f"WT_AHA_{k} (mm)"] - 1.0, k
    for k in remote:
        assert t[f"WT_AHA_{k} (mm)"] == pytest.approx(t0[f"WT_AHA_{k} (mm)"], abs=0.05), k
    r = regional_metrics(reconstruct(sick.study))
    for k in range(1, 17):
        assert abs(r[f"WT_AHA_{k} (mm)"] - t[f"WT_AHA_{k} (mm)"]) < 0.5, k


# ----------------------------------------------------------------- CLI
def test_cli_writes_a_realistic_clinical_infarct_phantom(tmp_path):
    out = tmp_path / "p"
    r = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "phantom", "--pathology", "mr",
                        "--seed", "3", "--frames", "2", "--anatomy", "realistic", "--infarct", "rca",
                        "--realism", "clinical", "--no-dicom", "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    tr = json.loads((out / "truth.json").read_text())
    assert tr["anatomy"]["model"] == "realistic" and tr["anatomy"]["shape"]["infarct"] == "rca"
    assert tr["faults"]["noise_px"] == 0.5 and tr["faults"]["breath_hold_mm"] == 1.5
    bad = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "phantom", "--pathology", "mr",
                          "--anatomy", "spherical", "--out", str(tmp_path / "q")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "q").exists()


# ----------------------------------------------------------------- measured
def test_reconstruction_within_bounds_on_a_realistic_phantom(real, tmp_path):
    import cardionurbs as cn
    from cardionurbs.pipeline import analyse_study
    write_phantom(real, tmp_path / "p", dicom=False)
    _, got = analyse_study(cn.load_study(tmp_path / "p"))
    m = real.truth["metrics"]
    for key in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "RVESV (mL)"):
        assert got[key] == pytest.approx(m[key], rel=0.02), key
    assert got["LVM (g)"] == pytest.approx(m["LVM (g)"], rel=0.04)
    assert got["RVM (g)"] == pytest.approx(m["RVM (g)"], rel=0.08)
    assert abs(got["LVEF (%)"] - m["LVEF (%)"]) < 2.0 and abs(got["RVEF (%)"] - m["RVEF (%)"]) < 2.0
    assert abs(got["Twist (deg)"] - m["Twist (deg)"]) < 1.0
