"""Phantom anatomy and motion: invertibility, exact myocardial volume, prescribed ejection."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cardionurbs.errors import PhantomError
from cardionurbs.phantom import truth
from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.motion import Motion, VolumeCurve

ANAT = Anatomy(27.7, 35.7, 72.0, 78.4, 14.4, 40.0, 50.0, 74.0, 3.5, 0.78).validate()


def motion(ls=0.15, lv_ef=0.63, rv_ef=0.57, eps=0.3, apex=10.0, base=-5.0):
    return Motion(ls, lv_ef, rv_ef, eps, apex, base, ANAT.z_base)


@settings(max_examples=40, deadline=None)
@given(f=st.floats(0.0, 1.0), ls=st.floats(0.0, 0.3), ef=st.floats(0.0, 0.8), eps=st.floats(0.0, 0.4),
       seed=st.integers(0, 2 ** 31))
def test_forward_inverse_roundtrip(f, ls, ef, eps, seed):
    m = motion(ls=ls, lv_ef=ef, rv_ef=ef * 0.8, eps=eps, apex=12.0, base=-6.0)
    p = np.random.default_rng(seed).normal(size=(200, 3)) * [35, 35, 40] + [10, 0, 50]
    q = m.forward(ANAT, p, f)
    np.testing.assert_allclose(m.inverse(ANAT, q, f), p, atol=1e-9)


def _jacobian_det(m, p, f, h=1e-4):
    cols = []
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        cols.append((m.forward(ANAT, p + d, f) - m.forward(ANAT, p - d, f)) / (2 * h))
    J = np.stack(cols, axis=-1)
    return np.linalg.det(J)


def _points_in(region, n, rng):
    out = []
    while sum(len(o) for o in out) < n:
        p = rng.uniform([-90, -90, 1], [110, 90, ANAT.z_base - 1], size=(20000, 3))
        s, th, z = p[:, 0] ** 2 + p[:, 1] ** 2, np.arctan2(p[:, 1], p[:, 0]), p[:, 2]
        s1, s2 = ANAT.s_lv_endo(z), ANAT.s_lv_epi(z)
        s3, s4 = np.maximum(s2, ANAT.s_rv(th, z)), np.maximum(s2, ANAT.s_rv(th, z, epi=True))
        masks = {"lv_wall": (s > s1 * 1.01 + 0.5) & (s < s2 * 0.99 - 0.5),
                 "rv_wall": (s > s3 * 1.01 + 0.5) & (s < s4 * 0.99 - 0.5) & (s3 > s2 + 1),
                 "lv_cavity": s < s1 * 0.98}
        out.append(p[masks[region]])
    return np.concatenate(out)[:n]


@pytest.mark.parametrize("region", ["lv_wall", "rv_wall"])
def test_myocardium_jacobian_is_one(region):
    rng = np.random.default_rng(1)
    p = _points_in(region, 300, rng)
    det = _jacobian_det(motion(), p, 1.0)
    np.testing.assert_allclose(det, 1.0, atol=1e-5)


def test_lv_cavity_jacobian_is_kappa():
    p = _points_in("lv_cavity", 200, np.random.default_rng(2))
    m = motion(eps=0.0)
    np.testing.assert_allclose(_jacobian_det(m, p, 1.0), 1 - m.lv_ef, rtol=1e-5)


def test_myocardial_volume_constant_over_cycle_and_methods_agree():
    m = motion()
    curve = VolumeCurve(es_fraction=0.35)
    phases = curve(np.arange(20) / 20)
    ed = truth.mesh_volumes(ANAT, m, 0.0, n_mu=120, n_theta=240, n_z_rv=120, n_v_rv=120)
    for f in phases[1::3]:
        b = truth.mesh_volumes(ANAT, m, float(f), n_mu=120, n_theta=240, n_z_rv=120, n_v_rv=120)
        a = truth.analytic_volumes(ANAT, m, float(f))
        for key in ("lv_myocardium", "rv_myocardium"):
            assert abs(b[key] - ed[key]) / ed[key] < 0.005
        for key in a:
            assert abs(b[key] - a[key]) / a[key] < 0.002, (key, f)


def test_volume_curve_shape():
    c = VolumeCurve(es_fraction=0.35)
    tau = np.linspace(0, 1, 401)
    f = c(tau)
    assert f[0] == 0 and abs(c(0.35) - 1) < 1e-12 and f.max() <= 1 + 1e-12
    assert np.all(np.diff(f[tau <= 0.35]) >= -1e-12)          # ejection is monotone
    rapid = c(0.35 + 0.35 * 0.65) - c(0.35)                   # rapid filling refills most
    kick = c(0.35 + 0.85 * 0.65) - c(1.0 - 1e-9)              # the atrial kick refills the rest
    assert rapid < -0.5 and kick > 0.1


@pytest.mark.parametrize("kw, word", [
    (dict(r_short_endo=-5.0), "r_short_endo"),
    (dict(r_short_epi=20.0), "wall thickness"),
    (dict(r_long_epi=70.0), "r_long_epi"),
    (dict(rv_offset=1.2), "rv_offset"),
])
def test_bad_anatomy_is_one_line(kw, word):
    base = ANAT.to_dict()
    base.update(kw)
    with pytest.raises(PhantomError) as e:
        Anatomy(**base).validate()
    assert word in str(e.value) and "\n" not in str(e.value)


def test_bad_motion():
    with pytest.raises(PhantomError, match="lv_ef"):
        motion(lv_ef=1.2)
