"""The realistic phantom's saddle-shaped tricuspid annulus (docs/phantoms.md): landmarks, contours,
tissue masks and truth all end the RV at the same annulus z_tri(θ), the RV is closed at the
best-fit plane of its annulus points, the presets keep their targets, the ideal stays planar."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs.geometry import fit_plane
from cardionurbs.phantom import annotate, dicom
from cardionurbs.phantom import truth_realistic as trr
from cardionurbs.phantom.generate import generate


@pytest.fixture(scope="module", params=[False, True], ids=["body", "outflow"])
def ph(request):
    # the realistic default has the outflow tracts; ``outflow=False`` leaves them out
    return generate("mr", seed=2, frames=3, anatomy_model="realistic",
                    **({} if request.param else {"outflow": False}))


def test_annulus_points_are_a_saddle_on_the_rv_walls(ph):
    an = ph.anatomy
    assert 3.0 <= an.tricuspid_dip <= 5.0
    tri = annotate.landmarks(an, ph.motion, 0.0)["tricuspid"]          # material at ED
    th = np.arctan2(tri[:, 1], tri[:, 0])
    assert np.allclose(tri[:, 2], an.z_top_rv(th), atol=1e-9)         # on the annulus height
    s = tri[:, 0] ** 2 + tri[:, 1] ** 2
    assert np.allclose(s[:4], an.s_rv(th[:4], tri[:4, 2]), rtol=1e-12)   # free wall
    assert np.allclose(s[4:], an.s_lv_epi(tri[4:, 2], th[4:]), rtol=1e-12)   # septum
    bent = annotate.bend(an, tri)
    c, n = fit_plane(bent)
    dev = np.abs((bent - c) @ n)
    assert np.ptp(tri[:, 2]) > 1.0 and dev.max() > 0.5, dev       # not planar
    # the crescent's tips stay at the base plane; with a tract its whole window does
    lo, hi = an.tricuspid_span()
    assert an.z_top_rv(np.array([lo, hi]))[0] == pytest.approx(an.z_base)
    assert an.z_top_rv(np.array([0.5 * (lo + hi)]))[0] == pytest.approx(an.z_base - an.tricuspid_dip)
    if an.outflow is not None:
        from cardionurbs.phantom.outflow import rvot_frame
        w = np.linspace(*rvot_frame(an).window(an.z_base, epi=True), 9)
        assert np.all(an.z_top_rv(w) == an.z_base)


def test_tissue_masks_end_the_rv_at_the_annulus(ph):
    """Just below z_tri(θ) the RV cavity and wall, just above it atrium (cavity) and not RV."""
    an, mo = ph.anatomy, ph.motion
    lo, hi = an.tricuspid_span()
    th = np.linspace(lo, hi, 41)[1:-1]
    zt = an.z_top_rv(th)
    s2 = an.s_lv_epi(zt, th)
    s3, s4 = an.s_rv(th, zt), an.s_rv(th, zt, epi=True)
    for s, cav in ((0.5 * (s2 + s3), True), (0.5 * (s3 + s4), False)):
        for dz, inside in ((-0.05, True), (0.05, False)):
            z = zt + dz
            p = np.column_stack([np.sqrt(s) * np.cos(th), np.sqrt(s) * np.sin(th), z])
            si, t, zz, a1, a2, a3 = mo.inverse_cylindrical(an, p, 0.0)
            tm = dicom.tissue_masks(an, si, t, zz, a1, a2, a3)
            key = "rv_cav" if cav else "rv_myo"
            dipped = zt < an.z_base - 0.1       # where the annulus is below the base plane
            assert np.all(tm[key][dipped] == inside), (key, dz)
            if cav and not inside:
                assert np.all(tm["ra"][dipped])


def test_la_contours_end_on_the_annulus(ph):
    """The 4-chamber RV contours' annulus ends are where the RV walls meet z_tri(θ)."""
    an, mo = ph.anatomy, ph.motion
    spec = next(s for s in ph.slices if s.id == "la_4ch")
    cont = annotate.la_contours(an, mo, spec, 0.0, with_rv=True)
    for name in ("rv_endo", "rv_epi"):
        ends = np.array([cont[name][0], cont[name][-1]])
        th = np.arctan2(ends[:, 1], ends[:, 0])
        assert np.allclose(ends[:, 2], an.z_top_rv(th), atol=0.02), (name, ends[:, 2], an.z_top_rv(th))


def test_truth_closes_the_rv_at_the_best_fit_plane(ph):
    vol = ph.truth["volumes"]
    assert vol["max_relative_difference"] < 2e-3, vol["max_relative_difference"]
    m, pm = ph.truth["metrics"], ph.draw.predicted_metrics()
    assert m["RVEDV (mL)"] == pytest.approx(pm["RVEDV (mL)"], rel=1e-3)
    assert m["RVM (g)"] == pytest.approx(pm["RVM (g)"], rel=1e-3)
    # the plane closure: the body up to the base plane is more than the RV cavity below the plane
    an = ph.anatomy
    caps = trr.tricuspid_cap_volumes(an, ph.motion, 0.0, trr.valve_planes(an, ph.motion, 0.0)["tricuspid"])
    assert caps["rv_endo"][0] > 0.5                                    # mL above the plane
    if an.outflow is not None:
        assert 0.0 < caps["rv_endo"][1] < caps["rv_endo"][0]          # the tract's part of it


def test_realistic_default_has_the_tracts_and_the_tricuspid_saddle(ph):
    """The realistic default (``outflow`` not given) has both outflow tracts and the saddle
    tricuspid annulus: the six annulus points depart from their best-fit plane; with
    ``outflow=False`` the saddle stays and the tracts, their view and landmarks are left out."""
    tri = np.array([l.point for l in ph.study.landmarks if l.name == "tricuspid" and l.frame == 0])
    c, n = fit_plane(tri)
    assert np.abs((tri - c) @ n).max() > 0.5
    names = {l.name for l in ph.study.landmarks}
    views = {c.slice for c in ph.study.contours}
    structures = {c.structure for c in ph.study.contours}
    if ph.anatomy.outflow is not None:
        assert ph.config["outflow"] is True
        assert {"pulmonary", "aortic"} <= names and "la_rvot" in views and "rv_outlet" in structures
    else:
        assert "outflow" not in ph.config and "outflow" not in ph.truth["anatomy"]["shape"]
        assert not {"pulmonary", "aortic"} & names and "la_rvot" not in views
        assert "rv_outlet" not in structures


def test_ideal_tricuspid_annulus_stays_planar():
    ph = generate("normal", seed=1, frames=2)
    tri = np.array([l.point for l in ph.study.landmarks if l.name == "tricuspid" and l.frame == 0])
    c, n = fit_plane(tri)
    assert np.abs((tri - c) @ n).max() < 1e-9
    assert "tricuspid_dip_mm" not in (ph.truth["anatomy"].get("shape") or {})
