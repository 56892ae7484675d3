"""The phantom's shared evaluations (issue 17, generation speed) give the values of the separate
calls they replace, exactly: both RV shells at once, the tract at every point, the motion inverse
with every section value, the tissue masks from them, the landmarks without the valves."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.phantom import annotate
from cardionurbs.phantom import dicom as phantom_dicom
from cardionurbs.phantom import outflow as ofl
from cardionurbs.phantom.anatomy import wrap_angle
from cardionurbs.phantom.generate import generate


@pytest.fixture(scope="module")
def real():
    return generate("normal", seed=7, frames=2, anatomy_model="realistic", volume_check=False)


@pytest.fixture(scope="module")
def ideal():
    return generate("normal", seed=7, frames=2, volume_check=False)


def _points(an, n=4000, seed=0):
    """Material (θ, z) spread over the heart and above the base (the tracts, the atria)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, n), rng.uniform(-5.0, an.z_base + 40.0, n)


@pytest.mark.parametrize("which", ["real", "ideal"])
def test_both_rv_shells_at_once_equal_two_calls(which, request):
    an = request.getfixturevalue(which).anatomy
    th, z = _points(an)
    z = z if an.shape is not None else np.minimum(z, an.z_base)
    endo, epi = an.s_rv_pair(th, z)
    assert np.array_equal(endo, an.s_rv(th, z, False))
    assert np.array_equal(epi, an.s_rv(th, z, True))
    zp = z if an.shape is not None else None
    p0, p1 = an.rv_p_pair(th, zp)
    assert np.array_equal(p0, an.rv_p(th, False, zp)) and np.array_equal(p1, an.rv_p(th, True, zp))


def test_shells_with_the_lv_epicardium_given_equal_the_plain_calls(real):
    an = real.anatomy
    th, z = _points(an, seed=1)
    s2 = an.lv_sections(z, th)[1]
    for epi in (False, True):
        assert np.array_equal(an.s_rv(th, z, epi, s_epi=s2), an.s_rv(th, z, epi))
    assert np.array_equal(np.stack(an.s_rv_pair(th, z, s_epi=s2)), np.stack(an.s_rv_pair(th, z)))
    above = z > an.z_base
    pair = ofl.s_rvot_pair(an, th[above], z[above])
    for k, epi in enumerate((False, True)):
        assert np.array_equal(pair[k], ofl.s_rvot(an, th[above], z[above], epi))


def test_rv_shell_cache_gives_the_tract_and_the_shell_of_the_anatomy(real):
    an = real.anatomy
    th, z = _points(an, seed=2)
    s2 = an.lv_sections(z, th)[1]
    plain = annotate._RvShells(an, th, z, s2)
    via_tract = annotate._RvShells(an, th, z, s2)
    for epi in (False, True):
        via_tract.tract(epi)
        assert np.array_equal(via_tract.s_rv(epi), an.s_rv(th, z, epi))
        assert np.array_equal(plain.s_rv(epi), an.s_rv(th, z, epi))


@pytest.mark.parametrize("which", ["real", "ideal"])
def test_material_sections_equal_the_motion_inverse(which, request):
    ph = request.getfixturevalue(which)
    an, mo = ph.anatomy, ph.motion
    plane = next(im for im in ph.study.images if im.view != "SA")
    hp, _ = phantom_dicom.pixel_heart_points(ph, plane)
    f = float(ph.phases[1])
    s, th, z, s1, s2, s3, s4, e = phantom_dicom.material_sections(an, mo, hp, f)
    assert np.array_equal(e.real, np.cos(th)) and np.array_equal(e.imag, np.sin(th))
    ref = mo.inverse_cylindrical(an, hp, f)
    for a, b in zip((s, th, z, s1, s2, s3), ref):
        assert np.array_equal(a, b)
    assert np.array_equal(s4, np.maximum(s3, an.s_rv(th, z, epi=True)))
    r = np.sqrt(np.maximum(s, 0.0))
    given_all = phantom_dicom.tissue_masks(an, s, th, z, s1, s2, s3, s4, (r * np.cos(th), r * np.sin(th)))
    plain = phantom_dicom.tissue_masks(an, s, th, z, s1, s2, s3)
    assert given_all.keys() == plain.keys()
    assert all(np.array_equal(given_all[k], plain[k]) for k in plain)
    assert plain["lv_cav"].any() and plain["rv_myo"].any()


def test_landmarks_without_the_valves(real):
    an, mo = real.anatomy, real.motion
    full = annotate.landmarks(an, mo, 0.3)
    part = annotate.landmarks(an, mo, 0.3, outflow=False)
    assert set(full) - set(part) == {"pulmonary", "aortic"}
    assert all(np.array_equal(part[k], full[k]) for k in part)


@settings(max_examples=200, deadline=None)
@given(st.floats(-60.0, 60.0, allow_nan=False))
def test_wrap_angle_is_the_principal_angle(x):
    w = float(wrap_angle(x))
    assert -np.pi <= w <= np.pi
    assert abs(np.cos(w) - np.cos(x)) < 1e-12 and abs(np.sin(w) - np.sin(x)) < 1e-12
    if abs(abs(w) - np.pi) > 1e-9:
        assert abs(w - float(np.angle(np.exp(1j * x)))) < 1e-12


def test_la_grid_points_left_out_have_every_region_term_positive(real):
    """The LA sampling grids skip the points where no contour can pass (annotate._outside_heart):
    there every region term is positive, at ED and at the last phase, in every view."""
    an, mo = real.anatomy, real.motion
    names = ("lv_endo", "lv_epi", "rv_endo", "rv_epi")
    skipped = 0
    for spec in (s for s in real.slices if s.view != "SA"):
        w, v, pts = annotate._plane_grid(an, spec, annotate.PLANE_STEP_MM)
        for f in (0.0, float(real.phases[-1])):
            out = annotate._outside_heart(an, mo, pts, f, (len(w), len(v)))
            fields = annotate.material_fields(an, mo, pts[out], f, names)
            for name in names:
                tree = annotate.region_logic(name, len(fields[name]))[0]
                assert np.all(annotate.tree_value(tree, fields[name]) > 0)
                assert all(np.all(t > 0) for t in fields[name][:1])
            skipped += int(out.sum())
            # and the grid's fields equal the full evaluation wherever it computed them
            grid = annotate._grid_fields(an, mo, pts, f, names, (len(w), len(v)))
            full = annotate.material_fields(an, mo, pts, f, names)
            for name in names:
                for a, b in zip(grid[name], full[name]):
                    assert np.array_equal(a[~out], b[~out])
    assert skipped > 0
