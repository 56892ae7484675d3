"""Phantom study content: planes, contours, landmarks, tags, faults, native output, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cardionurbs.cli import main
from cardionurbs.errors import PhantomError
from cardionurbs.io.native import read_study
from cardionurbs.phantom import generate, write_phantom


@pytest.fixture(scope="module")
def ph():
    return generate("normal", seed=5, frames=8)


def test_study_layout(ph):
    st = ph.study
    sa = sorted({im.slice for im in st.images if im.view == "SA"})
    la = sorted({im.slice for im in st.images if im.view == "LA"})
    assert la == ["la_2ch", "la_3ch", "la_4ch"] and 8 <= len(sa) <= 11 and sa[0] == "sa_00"
    assert st.ed_frame == 0 and 0 < st.es_frame < 8 and st.heart_rate_bpm > 0
    assert len(st.images) == 8 * (len(sa) + 3) and len({im.id for im in st.images}) == len(st.images)
    for im in st.images:
        assert im.rows == im.columns == 256 and im.pixel_spacing == (300 / 256, 300 / 256)
        assert np.all(np.abs(im.normal) < 0.99)            # oblique, not axis-aligned
    # SA planes perpendicular to the long axis (apex -> mitral centre) and 10 mm apart
    apex = st.landmarks_at(0, "apex")[0].point
    mitral = np.mean([lm.point for lm in st.landmarks_at(0, "mitral")], axis=0)
    axis = (mitral - apex) / np.linalg.norm(mitral - apex)
    planes = [st.slice_plane(s, 0) for s in sa]
    for p in planes:
        assert abs(abs(p.normal @ axis) - 1) < 1e-9
    heights = [(p.position - apex) @ axis for p in planes]
    np.testing.assert_allclose(np.diff(heights), -10.0, atol=1e-9)
    assert heights[0] < np.linalg.norm(mitral - apex)


def test_contours_lie_on_their_planes(ph):
    st = ph.study
    for c in st.contours:
        im = st.image(c.image)
        assert np.abs(im.distance_to_plane(c.points)).max() < 1e-9
        assert c.closed == (c.view == "SA") and len(c.points) >= 10
    for t in st.tags:
        assert np.abs(st.image(t.image).distance_to_plane(t.points)).max() < 1e-9
    ed = st.contours_at(0, view="SA")
    assert {c.structure for c in ed} == {"lv_endo", "lv_epi", "rv_endo", "rv_epi"}
    la4 = [c.structure for c in st.contours_at(0, view="LA") if c.slice == "la_4ch"]
    assert sorted(la4) == ["lv_endo", "lv_epi", "rv_endo", "rv_epi"]


def test_endo_inside_epi_and_cavity_shrinks(ph):
    st = ph.study

    def area(p, im):
        q = im.scanner_to_pixel(p) * im.pixel_spacing[0]
        return 0.5 * abs(np.dot(q[:, 0], np.roll(q[:, 1], -1)) - np.dot(q[:, 1], np.roll(q[:, 0], -1)))

    mid = "sa_04"
    for fr in (0, st.es_frame):
        cs = {c.structure: c for c in st.contours_at(fr, view="SA") if c.slice == mid}
        im = st.image(cs["lv_endo"].image)
        assert area(cs["lv_endo"].points, im) < area(cs["lv_epi"].points, im)
    a_ed = area([c for c in st.contours_at(0, "lv_endo") if c.slice == mid][0].points, st.slice_plane(mid, 0))
    a_es = area([c for c in st.contours_at(st.es_frame, "lv_endo") if c.slice == mid][0].points,
                st.slice_plane(mid, 0))
    assert a_es < 0.7 * a_ed


def test_landmarks(ph):
    st = ph.study
    for fr in range(8):
        assert len(st.landmarks_at(fr, "apex")) == 1
        m = np.array([lm.point for lm in st.landmarks_at(fr, "mitral")])
        t = np.array([lm.point for lm in st.landmarks_at(fr, "tricuspid")])
        assert len(m) == 6 and len(t) == 6
        # the annulus points are coplanar (valve plane)
        for pts in (m, np.r_[m, t]):
            sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
            assert sv[-1] < 1e-9 * sv[0]
    np.testing.assert_allclose(st.landmarks_at(0, "apex")[0].point,
                               st.landmarks_at(st.es_frame, "apex")[0].point, atol=1e-9)
    ins = [lm for lm in st.landmarks_at(0, "rv_insert")]
    assert len(ins) >= 2 * 5 and all(lm.slice.startswith("sa_") for lm in ins)


def test_ed_tag_lines_parallel_and_seven_pixels_apart(ph):
    st = ph.study
    for fam in ("sa1", "sa2"):
        lines = sorted((t for t in st.tags_at(0, fam) if t.slice == "sa_03"), key=lambda t: t.index)
        assert len(lines) >= 5
        im = st.image(lines[0].image)
        dirs, offs = [], []
        for t in lines:
            q = im.scanner_to_pixel(t.points)
            c = q.mean(axis=0)
            _, sv, vt = np.linalg.svd(q - c)
            assert sv[-1] < 1e-8 * sv[0]                       # straight at ED
            d = vt[0] * np.sign(vt[0][0] + 1e-12 * vt[0][1])
            dirs.append(d)
            offs.append(c @ np.array([-d[1], d[0]]))
        dirs = np.array(dirs)
        cross = dirs[:, None, 0] * dirs[None, :, 1] - dirs[:, None, 1] * dirs[None, :, 0]
        assert np.abs(cross).max() < 1e-8                      # parallel
        idx = np.array([t.index for t in lines])
        gaps = np.abs(np.diff(offs)) / np.diff(idx)
        np.testing.assert_allclose(gaps, 7.0, atol=1e-8)
    a = [t for t in st.tags_at(0, "sa1") if t.slice == "sa_03"][0]
    b = [t for t in st.tags_at(0, "sa2") if t.slice == "sa_03"][0]
    da, db = a.points[-1] - a.points[0], b.points[-1] - b.points[0]
    assert abs(da @ db) / np.linalg.norm(da) / np.linalg.norm(db) < 1e-9   # families orthogonal
    # LA tags: perpendicular to the long axis, 7 px apart
    la = sorted((t for t in st.tags_at(0, "la") if t.slice == "la_4ch"), key=lambda t: t.index)
    im = st.image(la[0].image)
    rows = [im.scanner_to_pixel(t.points)[:, 1] for t in la]
    assert max(np.ptp(r) for r in rows) < 1e-8
    np.testing.assert_allclose(np.abs(np.diff([r[0] for r in rows])), 7.0, atol=1e-8)


def test_tags_move_with_tissue(ph):
    st = ph.study
    ed = {(t.family, t.index): t for t in st.tags_at(0) if t.slice == "sa_05"}
    es = {(t.family, t.index): t for t in st.tags_at(st.es_frame) if t.slice == "sa_05"}
    common = set(ed) & set(es)
    assert common
    moved = max(np.linalg.norm(es[k].points.mean(0) - ed[k].points.mean(0)) for k in common)
    assert moved > 1.0


def test_truth_file_content(ph):
    tr = ph.truth
    from cardionurbs.analysis.regional_columns import REGIONAL_COLUMNS
    from cardionurbs.phantom.truth import METRIC_COLUMNS
    assert tuple(tr["metrics"]) == METRIC_COLUMNS + REGIONAL_COLUMNS
    assert tr["volumes"]["max_relative_difference"] < 0.002
    lv = tr["tags"]["levels"]
    assert len(lv) >= 2 and lv[0]["in_twist"] and lv[-1]["in_twist"]
    assert lv[0]["rotation_deg"] > 0 > lv[-1]["rotation_deg"]            # apex CCW, base CW
    assert tr["metrics"]["Twist (deg)"] == pytest.approx(lv[0]["rotation_deg"] - lv[-1]["rotation_deg"])
    d = lv[-1]["distance_from_apex_mm"] - lv[0]["distance_from_apex_mm"]
    assert tr["metrics"]["Torsion (deg/cm)"] == pytest.approx(tr["metrics"]["Twist (deg)"] / (d / 10))
    assert tr["faults"] == {"noise_px": 0.0, "tag_jumps": [], "breath_hold_mm": 0.0,
                            "breath_hold_shifts_mm": {}}


def test_tag_jumps_and_noise_are_recorded():
    clean = generate("phtn", seed=2, frames=4, volume_check=False)
    bad = generate("phtn", seed=2, frames=4, tag_jumps=3, noise_px=0.5, volume_check=False)
    jumps = bad.truth["faults"]["tag_jumps"]
    assert len(jumps) == 3 and bad.truth["metrics"]["Tag QC flags"] == 3
    assert len({(j["slice"], j["frame"]) for j in jumps}) == 3 and all(j["frame"] != 0 for j in jumps)
    for j in jumps:
        assert abs(j["replaced_by_index"] - j["index"]) == 1
        line = [t for t in bad.study.tags_at(j["frame"], j["family"])
                if t.slice == j["slice"] and t.index == j["index"]][0]
        true_nb = [t for t in clean.study.tags_at(j["frame"], j["family"])
                   if t.slice == j["slice"] and t.index == j["replaced_by_index"]][0]
        im = bad.study.image(line.image)
        err = im.scanner_to_pixel(line.points) - im.scanner_to_pixel(true_nb.points)
        assert np.abs(err).max() < 5.0                        # neighbour's line (+ noise)
    c0, c1 = clean.study.contours[0], bad.study.contours[0]
    assert 0 < np.abs(c1.points - c0.points).max() < 10
    assert bad.truth["metrics"]["LVEDV (mL)"] == clean.truth["metrics"]["LVEDV (mL)"]
    with pytest.raises(PhantomError, match="tag_jumps"):
        generate("normal", seed=0, frames=2, tag_jumps=10 ** 4)


@pytest.mark.parametrize("targets", [("tags",), ("contours",)])
def test_noise_on_chosen_annotations_only(targets):
    """add_noise(targets=...) moves the chosen annotations by about sigma pixels and leaves
    the others exactly where they were."""
    from cardionurbs.phantom.faults import add_noise
    clean = generate("normal", seed=3, frames=2, volume_check=False)
    noisy = generate("normal", seed=3, frames=2, volume_check=False)
    add_noise(noisy.study, 0.5, np.random.default_rng(0), targets=targets)
    for kind in ("contours", "tags"):
        px = []
        for a, b in zip(getattr(clean.study, kind), getattr(noisy.study, kind)):
            im = clean.study.image(a.image)
            px.append(im.scanner_to_pixel(b.points) - im.scanner_to_pixel(a.points))
        d = np.concatenate(px)
        if kind in targets:
            assert 0.45 < d.std() < 0.55
        else:
            assert np.array_equal(d, np.zeros_like(d))
    with pytest.raises(ValueError, match="targets"):
        add_noise(noisy.study, 0.5, np.random.default_rng(0), targets=("images",))


def test_breath_hold_shift_moves_slices():
    a = generate("normal", seed=4, frames=2, volume_check=False)
    b = generate("normal", seed=4, frames=2, breath_hold_mm=2.0, volume_check=False)
    sh = b.truth["faults"]["breath_hold_shifts_mm"]
    assert set(sh) == {im.slice for im in a.study.images if im.view == "SA"}
    ca = [c for c in a.study.contours if c.slice == "sa_02" and c.frame == 0][0]
    cb = [c for c in b.study.contours if c.slice == "sa_02" and c.frame == 0][0]
    im = a.study.image(ca.image)
    d = (cb.points - ca.points) @ np.c_[im.row_cosine, im.column_cosine]
    np.testing.assert_allclose(d, np.tile(sh["sa_02"], (len(d), 1)), atol=1e-9)


def test_native_output_reads_back_and_is_reproducible(tmp_path):
    ph = generate("mr", seed=7, frames=2)
    write_phantom(ph, tmp_path / "a", dicom=False)
    write_phantom(generate("mr", seed=7, frames=2), tmp_path / "b", dicom=False)
    for name in ("study.json", "points.csv", "truth.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    st = read_study(tmp_path / "a")
    assert st.summary() == ph.study.summary()
    assert all(im.file is None for im in st.images)
    tr = json.loads((tmp_path / "a" / "truth.json").read_text())
    assert tr["metrics"]["LVEDV (mL)"] == ph.truth["metrics"]["LVEDV (mL)"]
    write_phantom(generate("mr", seed=8, frames=2, volume_check=False), tmp_path / "c", dicom=False)
    assert (tmp_path / "a" / "truth.json").read_bytes() != (tmp_path / "c" / "truth.json").read_bytes()


def test_cli_single_and_cohort(tmp_path, capsys):
    assert main(["phantom", "--pathology", "phtn", "--seed", "1", "--frames", "2", "--no-dicom",
                 "--tag-jumps", "1", "--out", str(tmp_path / "one")]) == 0
    tr = json.loads((tmp_path / "one" / "truth.json").read_text())
    assert tr["pathology"] == "phtn" and tr["metrics"]["Tag QC flags"] == 1
    spec = tmp_path / "c.toml"
    spec.write_text("[cohort]\nframes = 2\n[[subject]]\nid = 'n1'\npathology = 'normal'\nseed = 1\n"
                    "[[subject]]\nid = 'p1'\npathology = 'phtn'\nseed = 1\n")
    assert main(["phantom", "--cohort", str(spec), "--no-dicom", "--out", str(tmp_path / "co")]) == 0
    assert sorted(p.name for p in (tmp_path / "co").iterdir()) == [".cardionurbs-study", "n1",
                                                                   "p1"]
    assert read_study(tmp_path / "co" / "n1").subject == "n1"
    capsys.readouterr()
    assert main(["phantom", "--cohort", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.toml" in err and not (tmp_path / "x").exists()
    assert main(["phantom", "--out", str(tmp_path / "y")]) == 2
