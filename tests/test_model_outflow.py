"""Outflow tracts (cardionurbs.anatomy.outflow): the tube against analytic cylinders, and
bivme-patient1's RV against biv-me with and without its outflow evidence."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.anatomy.mesh import Plane, volume_ml
from cardionurbs.anatomy.outflow import (build_tract, endo_signed_depth, offset_tract,
                                         section_circle, tract_solid)
from cardionurbs.geometry import in_plane_basis

AROUND_AREA = 48 * math.sin(2 * math.pi / 48) / (2 * math.pi)   # 48-gon / circle area


def _cylinder_case(radius, length, tilt_deg, outlet_loops):
    """A straight circular RVOT of ``radius`` whose axis leaves the body plane (z = 0,
    apical side z < 0) at ``tilt_deg`` and reaches the pulmonary annulus after ``length``
    mm along the axis; evidence: two LA wall lines in one plane through the axis, or
    SA-like outlet loops (planes z = const, ellipses where the tube is tilted)."""
    t = math.radians(tilt_deg)
    axis_up = np.array([math.sin(t), 0.0, math.cos(t)])    # from the body towards the valve
    body = Plane(np.zeros(3), np.array([0.0, 0.0, -1.0]))
    u, v = in_plane_basis(axis_up)
    top = length * axis_up
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    annulus = top + radius * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
    s = np.linspace(-10.0, length, 60)
    if outlet_loops:
        runs = []
        for z in np.arange(2.0, top[2] - 1.0, 4.0):
            # the tube's cut by the plane z = const: centre on the axis, semi-axes r / cos(t), r
            c = axis_up * (z / axis_up[2])
            w = np.linspace(0, 2 * np.pi, 40, endpoint=False)
            ex = np.array([math.cos(t), 0.0, -math.sin(t)])
            ex = ex - (ex @ np.array([0, 0, 1.0])) * np.array([0, 0, 1.0])
            ex /= np.linalg.norm(ex)
            ey = np.array([0.0, 1.0, 0.0])
            loop = (c + (radius / math.cos(t)) * np.cos(w)[:, None] * ex
                    + radius * np.sin(w)[:, None] * ey)
            runs.append(loop)
    else:
        side = np.cross(axis_up, [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        runs = [np.outer(s, axis_up) + sgn * radius * side for sgn in (1, -1)]
        runs = [r[r[:, 2] > 0] for r in runs]
    return body, annulus, runs, radius, length


@settings(max_examples=12, deadline=None)
@given(radius=st.floats(6.0, 15.0), length=st.floats(12.0, 40.0), tilt=st.floats(0.0, 30.0),
       loops=st.booleans(), two_points=st.booleans())
def test_cylinder_tract_volume_is_analytic(radius, length, tilt, loops, two_points):
    """A straight cylinder cut by the body plane (z = 0) and the annulus plane: its volume
    between them is pi r^2 L (the annulus plane is perpendicular to the axis, the body
    plane is not: the slanted cut leaves the volume unchanged on average)."""
    body, annulus, runs, r, L = _cylinder_case(radius, length, tilt, loops)
    if two_points:
        annulus = annulus[[0, 4]]        # two points, as a CAP LA view gives them
    t = build_tract("rv_endo", annulus, [] if loops else runs, body,
                    np.array([0.0, 0.0, -1.0]), loops=runs if loops else ())
    assert t is not None
    m = tract_solid(t, overlap_mm=0.0)
    truth = math.pi * r * r * L * AROUND_AREA / 1000.0
    assert volume_ml(m) == pytest.approx(truth, rel=0.02)
    # the tube's wall passes through its evidence
    ev = np.concatenate(runs)
    assert np.abs(endo_signed_depth(t, ev)).max() < 0.05 * r + 0.2


def test_epicardial_tube_is_the_lumen_widened_by_the_wall():
    body, annulus, runs, r, L = _cylinder_case(10.0, 30.0, 10.0, False)
    endo = build_tract("rv_endo", annulus, runs, body, np.array([0.0, 0.0, -1.0]))
    epi_runs = [p + 3.0 * (p - np.outer((p - endo.valve.origin) @ endo.axis, endo.axis)
                           - endo.valve.origin) / r for p in runs]
    epi = offset_tract(endo, np.concatenate(epi_runs))
    assert np.allclose(epi.radii - endo.radii, 3.0, atol=0.05)
    assert offset_tract(endo, np.concatenate(runs) * 0 + endo.valve.origin) is None  # inside


def test_section_circle_rules():
    assert section_circle(np.array([[0.0, 0.0]])) is None
    c, r = section_circle(np.array([[-4.0, 0.0], [4.0, 0.0]]))
    assert np.allclose(c, 0) and r == pytest.approx(4.0)
    w = np.linspace(0, 2, 5)
    c, r = section_circle(np.column_stack([3 + 7 * np.cos(w), -2 + 7 * np.sin(w)]))
    assert np.allclose(c, [3, -2]) and r == pytest.approx(7.0)


def test_valve_behind_the_body_plane_builds_no_tract():
    body, annulus, runs, *_ = _cylinder_case(10.0, 20.0, 0.0, False)
    assert build_tract("rv_endo", annulus - [0, 0, 40.0], [], body,
                       np.array([0.0, 0.0, -1.0])) is None


# ----------------------------------------------------------------- bivme-patient1
@pytest.fixture(scope="module")
def bivme_models(bivme_dir_module):
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.io import load_study
    st_ = load_study(bivme_dir_module)
    bare = dataclasses.replace(st_, landmarks=[lm for lm in st_.landmarks
                                               if lm.name not in ("pulmonary", "aortic")])
    return reconstruct(st_, frames=[9, 24]), reconstruct(bare, frames=[9, 24])


@pytest.fixture(scope="module")
def bivme_dir_module():
    from pathlib import Path
    p = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "bivme-patient1"
    if not p.exists():
        pytest.skip(f"real data not available: {p} is absent")
    return p


def test_bivme_rvot_brings_the_rv_to_biv_me(bivme_models):
    """biv-me ED frame 24: RV 167.8 mL, RVM 51.9 g (docs/metrics.md: 1.05 g/mL)."""
    with_rvot, without = bivme_models
    rv, rvm = with_rvot.volumes[24]["rv_cavity"], with_rvot.volumes[24]["rv_myocardium"] * 1.05
    assert rv == pytest.approx(167.8, rel=0.05)
    assert rvm == pytest.approx(51.9, rel=0.15)
    assert set(with_rvot.outflow[24]) >= {"rv_endo", "rv_epi"}
    # the tract only adds: RV body and LV untouched, the RV larger at both frames
    for f in (9, 24):
        assert with_rvot.volumes[f]["rv_cavity"] > without.volumes[f]["rv_cavity"]
        assert with_rvot.volumes[f]["lv_myocardium"] == without.volumes[f]["lv_myocardium"]


def test_bivme_within_the_issue_bounds_of_biv_me(bivme_models):
    """Issue 13, Done when: biv-me's published ED (frame 24) and ES (frame 9) figures, LV and
    RV volumes within 5 %, LVM within 8 %, RVM within 15 % (1.05 g/mL); the frame-9 RV in
    the test below."""
    m, _ = bivme_models
    for (f, k), (ref, rel) in {(24, "lv_cavity"): (179.0, 0.05), (24, "rv_cavity"): (167.8, 0.05),
                               (9, "lv_cavity"): (72.0, 0.05),
                               (24, "lv_myocardium"): (131.3 / 1.05, 0.08),
                               (24, "rv_myocardium"): (51.9 / 1.05, 0.15)}.items():
        assert m.volumes[f][k] == pytest.approx(ref, rel=rel), (f, k)


def test_bivme_frame9_rv_within_5_percent_of_biv_me(bivme_models):
    m, _ = bivme_models
    assert m.volumes[9]["rv_cavity"] == pytest.approx(76.7, rel=0.05)


def test_bivme_rv_loft_does_not_pinch_between_slices(bivme_models):
    """Between two neighbouring SA slices the RV cavity's cross-section (planes parallel to
    the slices) stays above half the smaller slice's contour area: the loft does not
    overshoot between its synthetic sections and the SA slices (with ungraded sections every
    2.5 mm it fell to a quarter, ~440 mm², between sa_02 and sa_03 at frame 9;
    anatomy.surfaces.synthetic_offsets)."""
    m, _ = bivme_models
    for f in (9, 24):
        geo = m.geometry[f]
        n = geo.direction
        B = in_plane_basis(n)
        rv = m.solids(f)["rv_cavity"].transform(np.hstack([np.vstack([B, n]), np.zeros((3, 1))]))
        secs = geo.sections["rv_endo"]
        for a, b in zip(secs[:-2], secs[1:-1]):       # the apical pair's areas vanish
            la, lb = float(a.points.mean(axis=0) @ n), float(b.points.mean(axis=0) @ n)
            cut = [rv.slice(float(h)).area() for h in np.linspace(la, lb, 9)[1:-1]]
            smaller = min(rv.slice(la).area(), rv.slice(lb).area())
            assert min(cut) > 0.5 * smaller, (f, a.slice, b.slice, min(cut), smaller)


def test_bivme_without_outflow_evidence_is_closed_at_the_tricuspid_plane(bivme_models):
    """No pulmonary / aortic landmark and no rv_outlet contour: no tract, the volumes
    those of the RV body alone (150.8 mL at ED, 71.6 mL at frame 9 with volume-corrected
    meshes, the LV epicardium closed through the RV septum, RV sections resampled after
    their septal move and RV synthetic sections graded next to the SA stack; 147.0 and
    65.7 mL before the grading, 146.6 and 61.3 mL on the surfaces' plain tessellation before
    all)."""
    _, without = bivme_models
    assert without.outflow[24] == {} and without.outflow[9] == {}
    assert without.volumes[24]["rv_cavity"] == pytest.approx(150.78, abs=0.05)
    assert without.volumes[9]["rv_cavity"] == pytest.approx(71.65, abs=0.05)


# ----------------------------------------------------------------- lofted outlet loops
def _prism_loops(section_xy, top_z, spacing=4.0):
    """Loops of a vertical prism (axis z, body plane z = 0, apical side z < 0) in the planes
    z = 2, 2 + spacing, ... below ``top_z``."""
    return [np.column_stack([section_xy, np.full(len(section_xy), z)])
            for z in np.arange(2.0, top_z - 0.5, spacing)]


def _crescent_polygon(r_out=22.0, r_in=15.0, shift=9.0, n=80):
    # outer arc of the big circle outside the small one, inner arc of the small circle inside
    # the big one; both circles meet where |x - c| = r: solve for the tips' angle
    x_tip = (r_out ** 2 - r_in ** 2 + shift ** 2) / (2 * shift) - shift   # in small-circle frame
    a_in = math.acos(x_tip / r_in)
    a_out = math.acos((x_tip + shift) / r_out)
    t_out = np.linspace(-a_out, a_out, n)
    outer = np.column_stack([r_out * np.cos(t_out), r_out * np.sin(t_out)])
    t_in = np.linspace(a_in, -a_in, n)
    inner = np.column_stack([-shift + r_in * np.cos(t_in), r_in * np.sin(t_in)])
    return np.vstack([outer, inner[1:-1]])


def _shoelace(p):
    return 0.5 * abs(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


@pytest.mark.parametrize("section", ["ellipse", "crescent"])
def test_lofted_prism_volume_is_analytic(section):
    """A vertical prism between the body plane z = 0 and the plane of its most basal
    outlet loop (no annulus landmark): volume = section area x height, the crescent
    included (a non-convex RV-like section)."""
    from cardionurbs.anatomy.outflow import loft_tract
    if section == "ellipse":
        w = np.linspace(0, 2 * np.pi, 90, endpoint=False)
        xy = np.column_stack([14.0 * np.cos(w), 9.0 * np.sin(w)])
    else:
        xy = _crescent_polygon()
    loops = _prism_loops(xy, 23.0)
    body = Plane(np.zeros(3), np.array([0.0, 0.0, -1.0]))
    t = loft_tract("rv_endo", None, loops, body, np.array([0.0, 0.0, -1.0]),
                   np.array([1.0, 0.0, 0.0]))
    top = max(q[0, 2] for q in loops)
    truth = _shoelace(xy) * top / 1000.0
    assert volume_ml(tract_solid(t, overlap_mm=0.0)) == pytest.approx(truth, rel=0.01)


def test_lofted_prism_with_a_tilted_annulus():
    """A circular prism closed by a tilted annulus plane through 8 ring points above its
    outlet loops: volume = area x height at the axis (a prism cut by a plane)."""
    from cardionurbs.anatomy.outflow import loft_tract
    w = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    xy = np.column_stack([11.0 * np.cos(w), 11.0 * np.sin(w)])
    loops = _prism_loops(xy, 23.0)
    body = Plane(np.zeros(3), np.array([0.0, 0.0, -1.0]))
    H = 30.0
    ring = np.column_stack([xy[::12], H + math.tan(math.radians(15)) * xy[::12, 0]])
    t = loft_tract("rv_endo", ring, loops, body, np.array([0.0, 0.0, -1.0]),
                   np.array([1.0, 0.0, 0.0]))
    truth = _shoelace(xy) * H / 1000.0
    assert volume_ml(tract_solid(t, overlap_mm=0.0)) == pytest.approx(truth, rel=0.01)


# ----------------------------------------------------------------- a phantom given an outlet
@pytest.fixture(scope="module")
def phantom_with_prism_outlet():
    """A noise-free phantom (no outflow tract of its own) given a straight circular RVOT:
    a prism of radius R along the stacking direction over the RV free-wall side, with
    SA-parallel rv_outlet loops, outlet-only RV epicardial loops (wall W), and a ring of
    pulmonary annulus points H mm beyond the tricuspid plane (at the prism axis)."""
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.phantom.generate import generate
    from cardionurbs.study import Contour, Landmark
    ph = generate("normal", seed=0, frames=2, volume_check=False)
    study = ph.study
    study.tags = []
    plain = reconstruct(study)
    R, W, H = 6.0, 3.0, 14.0
    added_c, added_l, heights = [], [], {}
    for f in plain.frames:
        geo = plain.geometry[f]
        n, tri = geo.direction, geo.base_planes["rv"]
        basal = geo.sections["rv_endo"][0].points
        ref = geo.reference
        far = basal[np.argmax(basal @ ref)]
        axis_pt = far - (R + W + 4.0) * ref                 # inside the RV, off the free wall
        axis_pt = axis_pt - (tri.signed_distance(axis_pt[None])[0] / (n @ tri.normal)) * n
        u, v = in_plane_basis(n)
        w = np.linspace(0, 2 * np.pi, 96, endpoint=False)
        circ = np.cos(w)[:, None] * u + np.sin(w)[:, None] * v
        for k, h in enumerate((3.0, 7.0, 11.0)):
            c = axis_pt - h * n
            added_c += [Contour("rv_outlet", "SA", f"outlet_{k}", f, c + R * circ, closed=True),
                        Contour("rv_epi", "SA", f"outlet_{k}", f, c + (R + W) * circ, closed=True)]
        ring = axis_pt - H * n + R * circ[::12]
        added_l += [Landmark("pulmonary", f, p, i) for i, p in enumerate(ring)]
        heights[f] = H
    given = dataclasses.replace(study, contours=study.contours + added_c,
                                landmarks=study.landmarks + added_l)
    return plain, reconstruct(given), R, W, heights


def test_phantom_outlet_adds_the_prism_beyond_the_tricuspid_plane(phantom_with_prism_outlet):
    """The RV cavity gains pi R^2 H (the prism between the tricuspid plane, cut at the axis
    height, and the pulmonary plane: area x axial height for planar cuts), the RV
    myocardium the wall pi ((R+W)^2 - R^2) H; LV volumes and masses are unchanged."""
    plain, given, R, W, heights = phantom_with_prism_outlet
    ring48 = 48 * math.sin(2 * math.pi / 48) / (2 * math.pi)
    for f in plain.frames:
        a, b = plain.volumes[f], given.volumes[f]
        lumen = math.pi * R * R * heights[f] * ring48 / 1000.0
        wall = math.pi * ((R + W) ** 2 - R ** 2) * heights[f] * ring48 / 1000.0
        assert b["rv_cavity"] - a["rv_cavity"] == pytest.approx(lumen, rel=0.01)
        assert b["rv_myocardium"] - a["rv_myocardium"] == pytest.approx(wall, rel=0.02)
        for k in ("lv_cavity", "lv_myocardium"):
            assert b[k] == a[k]


def test_model_file_keeps_the_outflow_tracts(phantom_with_prism_outlet):
    """model.json round trip: the read-back model has the same RV volumes (tracts kept)."""
    import json
    from cardionurbs.anatomy.model import BiventricularModel
    _, given, *_ = phantom_with_prism_outlet
    back = BiventricularModel.from_dict(json.loads(json.dumps(given.to_dict())))
    for f in given.frames:
        assert set(back.outflow[f]) == set(given.outflow[f])
        for k in ("rv_cavity", "rv_myocardium"):
            assert back.volumes[f][k] == pytest.approx(given.volumes[f][k], rel=1e-9)


# ----------------------------------------------------------------- the phantom's own tracts
@pytest.fixture(scope="module")
def outflow_phantom():
    """The realistic phantom with its outflow tracts (issue 17: RVOT to a pulmonary valve,
    LVOT to an aortic valve; truth by the convention of docs/metrics.md), noise-free."""
    from cardionurbs.analysis.function import measure
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.phantom.generate import generate
    ph = generate("normal", seed=1, frames=2, anatomy_model="realistic", outflow=True,
                  volume_check=False)      # the truth by sections; its mesh cross-check is #17's test
    ph.study.tags = []
    m = reconstruct(ph.study)
    return ph, m, measure(m)


def test_outflow_phantom_volumes_within_two_percent(outflow_phantom):
    """Cavity volumes (tracts included) within 2 %, EF within 2 points, RVM (RVOT free
    wall included) within 3 %. RVM reads -1.1 % here (reports/validation-outflow.md); it
    read +3.1 % while the epicardial tube put a wall all round the lumen, where the
    phantom's RVOT has its inner side on the LV epicardium (now widened by the local wall
    thickness of the epicardial contours)."""
    ph, m, got = outflow_phantom
    truth = ph.truth["metrics"]
    for key in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "RVESV (mL)"):
        assert got[key] == pytest.approx(truth[key], rel=0.02), key
    for key in ("LVEF (%)", "RVEF (%)"):
        assert abs(got[key] - truth[key]) < 2.0, key
    assert got["RVM (g)"] == pytest.approx(truth["RVM (g)"], rel=0.03)
    # the tracts are built from the phantom's evidence: the RVOT lofted through rv_outlet
    for f in m.frames:
        assert set(m.outflow[f]) == {"rv_endo", "rv_epi", "lv_endo"}
        assert m.outflow[f]["rv_endo"].rings is not None


def test_outflow_phantom_tract_lumen_at_ed(outflow_phantom):
    """What the reconstruction adds beyond the tricuspid / mitral plane at ED against the
    phantom's tract lumen (truth by sections, independent of the reconstruction)."""
    from cardionurbs.anatomy.mesh import volume_ml
    from cardionurbs.phantom import truth_realistic as trr
    ph, m, _ = outflow_phantom
    truth = trr.ed_outflow_volumes(ph.anatomy)
    ed = m.ed_frame
    assert volume_ml(m._tract_part(ed, "rv_endo")) == pytest.approx(truth["rv_endo"], rel=0.15)
    assert volume_ml(m._tract_part(ed, "lv_endo")) == pytest.approx(truth["lv_endo"], rel=0.2)
