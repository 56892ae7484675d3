"""SA-only label maps: the apex from the taper of the section areas, and ED/ES frames named
by the user (load_study ed_frame/es_frame, analyze --ed-frame/--es-frame)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import StudyError, load_study
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.anatomy.sections import Section, apical_taper
from cardionurbs.anatomy.surfaces import crescent_scale, septal_anchor
from cardionurbs.analysis.function import measure
from cardionurbs.cli import main
from cardionurbs.geometry import points_in_polygon, polygon_area
from cardionurbs.phantom.generate import generate
from cardionurbs.phantom.labelmaps import write_labelmaps


# ------------------------------------------------------------------ the taper rule
def _spheroid_areas(levels, a, c, h_apex):
    """Section areas of a prolate spheroid (semi-axes a, c) whose tip is at level h_apex,
    the axis along increasing level."""
    x = h_apex - np.asarray(levels)                 # distance from the tip
    return np.pi * a * a * (2 * x / c - (x / c) ** 2)


@settings(max_examples=60, deadline=None)
@given(a=st.floats(10, 40), c=st.floats(40, 110), gap=st.floats(0.5, 30), step=st.floats(5, 12))
def test_taper_finds_the_tip_of_a_spheroid(a, c, gap, step):
    """Three sections of a spheroid above its tip: the apex is its tip (to rounding)."""
    h_apex = 100.0
    levels = h_apex - gap - step * np.arange(4)[::-1]
    if (h_apex - levels[0]) > c:                    # sections beyond the equator: not a taper
        return
    tp = apical_taper(levels, _spheroid_areas(levels, a, c, h_apex))
    assert tp is not None
    span = levels[-1] - levels[0]
    assert tp.apex == pytest.approx(min(h_apex, levels[-1] + span), abs=1e-6)
    assert tp.area_ratio(levels[-1]) == pytest.approx(1.0)
    assert tp.area_ratio(tp.apex) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(k=st.floats(0.5, 5), gap=st.floats(1, 20), step=st.floats(5, 12))
def test_taper_of_a_cone_never_overshoots_its_tip(k, gap, step):
    """A cone's areas are convex in the level: the straight line through the last two areas
    ends at or before the tip (never beyond it)."""
    h_apex = 80.0
    levels = h_apex - gap - step * np.arange(3)[::-1]
    tp = apical_taper(levels, k * (h_apex - levels) ** 2)
    assert tp is not None
    assert levels[-1] < tp.apex <= h_apex + 1e-9


def test_taper_respects_an_empty_slice_and_refuses_a_widening_end():
    levels = np.array([0.0, 10.0, 20.0])
    areas = _spheroid_areas(levels, 25.0, 60.0, 35.0)
    assert apical_taper(levels, areas).apex == pytest.approx(35.0)
    held = apical_taper(levels, areas, limit=28.0)
    assert held.apex == pytest.approx(28.0)
    assert held.area_ratio(28.0) == pytest.approx(0.0, abs=1e-9)    # still closes at the apex
    assert apical_taper(levels, areas[::-1]) is None                 # widening: no taper
    assert apical_taper(levels[:2], areas[:2]) is None               # two sections: no taper


# ------------------------------------------------------------------ on a phantom
@pytest.fixture(scope="module")
def acdc_phantom(tmp_path_factory):
    ph = generate("mr", seed=3, frames=6, matrix=176, volume_check=False)
    out = tmp_path_factory.mktemp("acdc") / "mr3"
    write_labelmaps(ph, out, "acdc", images=True)     # labels at ED and ES, the image 4-D
    return ph, out


def test_sa_only_label_maps_meet_the_targets_the_half_slice_rule_misses(acdc_phantom):
    """ACDC layout (no long-axis maps): with the taper apex LVEDV is within 3 % and LVM
    within 5 % of the analytic truth; the half-slice apex (what hand-drawn SA contours
    get) misses LVM by more, on the same contours."""
    ph, out = acdc_phantom
    t = ph.truth["metrics"]
    study = load_study(out)
    assert study.meta["sa_apex"] == "taper"
    model = reconstruct(study)
    m = measure(model)
    assert abs(m["LVEDV (mL)"] / t["LVEDV (mL)"] - 1) < 0.03
    lvm_err = abs(m["LVM (g)"] / t["LVM (g)"] - 1)
    assert lvm_err < 0.05
    assert abs(m["LVEF (%)"] - t["LVEF (%)"]) < 2
    for k in ("RVEDV (mL)", "RVESV (mL)"):
        assert abs(m[k] / t[k] - 1) < 0.03, k
    # the ES valve plane keeps the myocardial volume of ED, within the slab the stack allows
    ed, es = (model.volumes[f]["lv_myocardium"] for f in (model.ed_frame, model.es_frame))
    shift = model.base_shift_mm[model.es_frame]
    assert abs(shift) < 0.5 * model.geometry[model.es_frame].thickness
    assert es == pytest.approx(ed, rel=0.01)
    del study.meta["sa_apex"]
    half = measure(reconstruct(study))
    assert abs(half["LVM (g)"] / t["LVM (g)"] - 1) > lvm_err + 0.01


# ------------------------------------------------------------------ ED/ES given by the user
@pytest.fixture(scope="module")
def cine_map(tmp_path_factory):
    """A 4-D SA label map of 5 frames (no long-axis maps): a single file."""
    ph = generate("normal", seed=4, frames=5, matrix=128, volume_check=False)
    out = tmp_path_factory.mktemp("cine")
    write_labelmaps(ph, out, "ukbb", images=False)
    return out / "seg_sa.nii.gz"


def test_given_ed_es_frames_are_used_as_given(cine_map, tmp_path):
    study = load_study(cine_map, labels="ukbb", ed_frame=1, es_frame=3)
    assert study.meta["ed_es_given"] == ["ED", "ES"]
    model = reconstruct(study)
    assert (model.ed_frame, model.es_frame) == (1, 3)
    rc = main(["analyze", str(cine_map), "--labels", "ukbb", "--ed-frame", "1", "--es-frame", "3",
               "--outputs", "metrics", "--out", str(tmp_path / "an")])
    assert rc == 0
    d = json.load(open(tmp_path / "an" / "metrics.json"))
    assert (d["ed_frame"], d["es_frame"]) == (1, 3)


@pytest.mark.parametrize("opts,expect", [
    (["--ed-frame", "7", "--es-frame", "2"], "ED frame 7 is not a labelled frame"),
    (["--es-frame", "-1"], "--es-frame"),
    (["--ed-frame", "x"], "--ed-frame"),
])
def test_bad_ed_es_frames_exit_2_with_one_line(cine_map, tmp_path, capsys, opts, expect):
    rc = main(["analyze", str(cine_map), "--labels", "ukbb", *opts, "--outputs", "metrics",
               "--out", str(tmp_path / "an")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and expect in err, err
    assert not (tmp_path / "an").exists()


def test_ed_es_frames_are_refused_for_contour_formats(tmp_path):
    from cardionurbs.phantom.generate import write_phantom
    ph = generate("normal", seed=0, frames=2, matrix=96, volume_check=False)
    write_phantom(ph, tmp_path / "ph")
    with pytest.raises(StudyError, match="NIfTI label maps"):
        load_study(tmp_path / "ph", ed_frame=0)


# ------------------------------------------------------------------ the image beside the labels
def test_contours_sit_on_the_image_beside_the_labels(acdc_phantom, tmp_path):
    """The cine image NIfTI (its own file and header) under the contours from the labels:
    blood is bright inside the LV endocardium, the myocardium between the LV contours dark,
    and the figure is drawn for ED and ES."""
    from matplotlib.path import Path as MplPath

    from cardionurbs.report.figures import render_figures
    from cardionurbs.report.overlay import sa_overlay

    ph, out = acdc_phantom
    study = load_study(out)
    ov = sa_overlay(study, study.ed_frame)
    assert not isinstance(ov, str), ov
    cc, rr = np.meshgrid(np.arange(ov.image.shape[0]), np.arange(ov.image.shape[1]),
                         indexing="ij")
    pix = np.column_stack([cc.ravel(), rr.ravel()])
    inside = {k: MplPath(ov.contours[k][0]).contains_points(pix).reshape(ov.image.shape)
              for k in ("lv_endo", "lv_epi")}
    blood = ov.image[inside["lv_endo"]].mean()
    wall = ov.image[inside["lv_epi"] & ~inside["lv_endo"]]
    assert blood > 2 * np.median(wall)
    fs = render_figures(reconstruct(study), tmp_path / "fig", only=["fig18_labelmap_overlay"])
    assert [f.name for f in fs.figures] == ["fig18_labelmap_overlay"], fs.skipped
    no_image = load_study(out)
    no_image.meta.pop("image_files")
    assert "no short-axis image" in sa_overlay(no_image, no_image.ed_frame)


# ------------------------------------------------------------------ the RV crescent's taper
def _crescent(r_lv, width, half_angle, n=120):
    """An RV crescent on a circular LV epicardium (centre 0, radius r_lv) in the z = 0 plane:
    the septal arc on the circle, the free wall ``width`` mm outside it, over ±half_angle."""
    a = np.linspace(-half_angle, half_angle, n)
    bulge = r_lv + width * np.sqrt(np.clip(np.sin(np.pi * (a + half_angle) / (2 * half_angle)), 0, 1))
    outer = np.stack([bulge * np.cos(a), bulge * np.sin(a), 0 * a], axis=1)
    inner = np.stack([r_lv * np.cos(a[::-1]), r_lv * np.sin(a[::-1]), 0 * a], axis=1)
    return np.concatenate([outer, inner[1:-1]])


@settings(max_examples=25, deadline=None)
@given(r_lv=st.floats(15, 35), width=st.floats(6, 20), half=st.floats(0.6, 1.4),
       ratio=st.floats(0.05, 0.9))
def test_crescent_scale_gives_the_tapered_area_outside_the_lv(r_lv, width, half, ratio):
    """The scaled crescent's part outside the LV epicardium has the target area (checked on a
    grid 2.5x finer than the one the scale was solved on), where scaling by sqrt(ratio) alone
    leaves less, part of it sunk into the LV."""
    n = np.array([0.0, 0.0, 1.0])
    t = _crescent(r_lv, width, half)
    phi = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    lv = np.stack([r_lv * np.cos(phi), r_lv * np.sin(phi), 0 * phi], axis=1)
    anchor = septal_anchor(Section("rv_endo", 0, t, septum_of=lv), n)
    assert anchor is not None and abs(np.hypot(*anchor[:2]) - r_lv) < 0.2 * r_lv
    target = ratio * polygon_area(t, n)
    s = crescent_scale(t, anchor, target, lv, n)

    def outside(scale, step):
        p = anchor + scale * (t - anchor)
        lo, hi = p[:, :2].min(0), p[:, :2].max(0)
        g = np.stack(np.meshgrid(np.arange(lo[0], hi[0], step), np.arange(lo[1], hi[1], step)),
                     -1).reshape(-1, 2) + step / 2
        g = g[points_in_polygon(g, p[:, :2])]
        return step * step * np.count_nonzero(np.hypot(g[:, 0], g[:, 1]) > r_lv)

    fine = (np.ptp(t[:, :2], axis=0).max() * s) / 150
    assert outside(s, fine) == pytest.approx(target, rel=0.06, abs=2.0)
    assert outside(np.sqrt(ratio), fine) <= outside(s, fine) + 1.0
