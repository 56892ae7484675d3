"""Biventricular reconstruction of an analytic (ellipsoid) heart: volumes against exact
truth, closed meshes, residuals, serialisation, SA-only input, CAP-style RV parts."""

from __future__ import annotations

import json
import math

import manifold3d
import numpy as np
import pytest

from cardionurbs.analysis.function import measure
from cardionurbs.analysis.simpson import disk_volumes
from cardionurbs.anatomy.model import MESHES, BiventricularModel, reconstruct
from cardionurbs.anatomy.sections import join_open_parts, order_closed, order_open
from cardionurbs.errors import ReconstructionError
from cardionurbs.study import Contour, Study

from test_model_fixtures import heart, study_from_hearts, truth_volumes

HEARTS = [heart(1.0), heart(0.8)]


@pytest.fixture(scope="module")
def truth():
    return [truth_volumes(h) for h in HEARTS]


@pytest.fixture(scope="module")
def model():
    return reconstruct(study_from_hearts(HEARTS))


def test_frames_and_ed_es(model):
    assert model.frames == [0, 1]
    assert (model.ed_frame, model.es_frame) == (0, 1)
    assert set(model.surfaces[0]) == {"lv_endo", "lv_epi", "rv_endo", "rv_epi"}


@pytest.mark.parametrize("frame", [0, 1])
def test_volumes_match_exact_truth(model, truth, frame):
    v, t = model.volumes[frame], truth[frame]
    assert v["lv_cavity"] == pytest.approx(t["lv_cavity"], rel=0.01)
    assert v["lv_myocardium"] == pytest.approx(t["lv_myocardium"], rel=0.01)
    assert v["rv_cavity"] == pytest.approx(t["rv_cavity"], rel=0.01)
    assert v["rv_myocardium"] == pytest.approx(t["rv_myocardium"], rel=0.03)


def test_ejection_fraction_within_one_point(model, truth):
    m = measure(model)
    ef = 100 * (1 - truth[1]["lv_cavity"] / truth[0]["lv_cavity"])
    rvef = 100 * (1 - truth[1]["rv_cavity"] / truth[0]["rv_cavity"])
    assert abs(m["LVEF (%)"] - ef) < 1.0
    assert abs(m["RVEF (%)"] - rvef) < 1.0
    assert m["LVM (g)"] == pytest.approx(1.05 * truth[0]["lv_myocardium"], rel=0.03)
    assert 0.5 < m["EI ES"] < 1.5


@pytest.mark.parametrize("frame", [0, 1])
def test_every_mesh_is_closed_manifold_and_outward(model, frame):
    meshes = model.meshes(frame)
    assert set(meshes) == set(MESHES)
    for name, tm in meshes.items():
        assert tm.is_watertight and tm.is_winding_consistent and tm.is_volume, name
        m = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(tm.vertices, np.float32),
                                                tri_verts=np.asarray(tm.faces, np.uint32)))
        assert m.status() == manifold3d.Error.NoError, name
        assert tm.volume > 0, name          # positive signed volume: normals point outward
    assert model.meshes(frame) is meshes    # cached


def test_meshes_lie_on_the_apical_side_of_the_valve_planes(model):
    for f in model.frames:
        for name, tm in model.meshes(f).items():
            plane = model.base_planes[f]["lv" if name.startswith("lv") else "rv"]
            assert plane.signed_distance(tm.vertices).min() > -1e-6, name


def test_residuals_within_one_pixel(model):
    r = model.residuals
    assert set(r.columns) >= {"structure", "frame", "slice", "mean_mm", "max_mm", "mean_px", "max_px"}
    sa = r[r["view"] == "SA"]
    assert len(sa) > 20
    assert sa["max_px"].max() < 1.0
    la = r[(r["view"] == "LA") & r["structure"].str.startswith("lv")]
    assert la["mean_mm"].max() < 1.0


def test_long_axis(model):
    apex, base = model.long_axis()
    assert np.linalg.norm(apex - base) == pytest.approx(70 + 8, abs=0.5)   # epi apex to z_b


def test_to_dict_round_trip(model):
    d = json.loads(json.dumps(model.to_dict()))
    m2 = BiventricularModel.from_dict(d)
    assert m2.frames == model.frames and (m2.ed_frame, m2.es_frame) == (model.ed_frame, model.es_frame)
    for f in model.frames:
        for k, v in model.volumes[f].items():
            assert m2.volumes[f][k] == pytest.approx(v, rel=1e-9)
    assert measure(m2)["EI ES"] == pytest.approx(measure(model)["EI ES"])


def test_noisy_contours_volumes_within_two_percent(truth):
    m = reconstruct(study_from_hearts(HEARTS[:1], noise_px=0.5, seed=3), tol_px=1.5)
    for k in ("lv_cavity", "rv_cavity"):
        assert m.volumes[0][k] == pytest.approx(truth[0][k], rel=0.02)


def test_short_axis_only_input_extends_half_a_slice():
    st = study_from_hearts(HEARTS[:1], la=False, landmarks=False, rv=False)
    m = reconstruct(st)
    assert set(m.surfaces[0]) == {"lv_endo", "lv_epi"}
    assert set(m.meshes(0)) == {"lv_cavity", "lv_myocardium"}
    v = m.volumes[0]["lv_cavity"]
    disks = disk_volumes(st, 0)["lv_cavity"]
    assert v == pytest.approx(disks, rel=0.05)
    # the base plane is half a slice thickness above the most basal contour
    plane = m.base_planes[0]["lv"]
    first = m.sections[0]["lv_endo"][0].points
    assert np.abs(plane.signed_distance(first) - 4.0).max() < 1e-6


def _split_rv_into_cap_parts(st: Study) -> Study:
    """Replace closed SA rv_endo by open rv_freewall + rv_septum parts (as CAP gives
    them), in scrambled file order, and rv_epi by its open free-wall part."""
    out = []
    for c in st.contours:
        if c.view == "SA" and c.structure in ("rv_endo", "rv_epi"):
            p = c.points
            n = len(p)
            k = n // 2
            if c.structure == "rv_endo":
                fw, sp = p[: k], p[k:]
                out.append(Contour("rv_freewall", "SA", c.slice, c.frame, np.roll(fw, 7, axis=0),
                                   image=c.image, closed=False))
                out.append(Contour("rv_septum", "SA", c.slice, c.frame, sp[::-1], image=c.image,
                                   closed=False))
            else:
                out.append(Contour("rv_epi", "SA", c.slice, c.frame, p[: k], image=c.image,
                                   closed=False))
        else:
            out.append(c)
    st.contours = out
    return st


def test_open_rv_parts_are_assembled():
    st = _split_rv_into_cap_parts(study_from_hearts(HEARTS[:1]))
    assert not [c for c in st.contours if c.view == "SA" and c.structure == "rv_endo"]
    m = reconstruct(st)
    ref = reconstruct(study_from_hearts(HEARTS[:1]))
    assert m.volumes[0]["rv_cavity"] == pytest.approx(ref.volumes[0]["rv_cavity"], rel=0.03)
    for tm in m.meshes(0).values():
        assert tm.is_watertight and tm.is_volume


def test_point_ordering_helpers():
    t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    ring = np.column_stack([10 * np.cos(t), 5 * np.sin(t), np.zeros(60)])
    rng = np.random.default_rng(0)
    shuffled = ring[rng.permutation(60)]
    o = order_closed(shuffled)
    steps = np.linalg.norm(np.diff(np.vstack([o, o[:1]]), axis=0), axis=1)
    assert steps.max() < 2.0
    arc = ring[:30]
    o2 = order_open(np.roll(arc, 11, axis=0))
    assert np.allclose(o2[[0, -1]], arc[[0, -1]]) or np.allclose(o2[[0, -1]], arc[[-1, 0]])
    loop = join_open_parts([ring[:25], ring[25:][::-1]])
    assert len(loop) == 60 and np.linalg.norm(np.diff(loop, axis=0), axis=1).max() < 2.0


def test_missing_lv_contours_is_a_reconstruction_error():
    st = study_from_hearts(HEARTS[:1])
    st.contours = [c for c in st.contours if c.structure != "lv_endo" or c.slice != "sa_00"
                   and c.view == "LA"]
    with pytest.raises(ReconstructionError, match="lv_endo"):
        reconstruct(st)
    with pytest.raises(ReconstructionError, match="frame"):
        reconstruct(study_from_hearts(HEARTS[:1]), frames=[5])
    assert math.isfinite(1.0)
