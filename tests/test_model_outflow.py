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


def test_bivme_without_outflow_evidence_is_closed_at_the_tricuspid_plane(bivme_models):
    """No pulmonary / aortic landmark and no rv_outlet contour: no tract, the volumes
    those of the RV body alone (reports/validation-function.md before the RVOT:
    146.6 mL at ED, 61.3 mL at frame 9)."""
    _, without = bivme_models
    assert without.outflow[24] == {} and without.outflow[9] == {}
    assert without.volumes[24]["rv_cavity"] == pytest.approx(146.6, abs=0.05)
    assert without.volumes[9]["rv_cavity"] == pytest.approx(61.3, abs=0.05)
