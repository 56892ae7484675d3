"""NIfTI label maps: layouts, conventions, RAS -> LPS geometry, masks -> contours, voxel counts."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import StudyError, load_study
from cardionurbs.imaging.dicom import read_header
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import masks, nifti
from cardionurbs.geometry import polygon_area, polygon_centroid
from cardionurbs.io.labels import PRESETS, LabelRoles, infer_roles, parse_labels
from cardionurbs.phantom.generate import generate, write_phantom
from cardionurbs.phantom.labelmaps import convention_lut, plane_codes, write_labelmaps

from conftest import shared_data

MATRIX = 192          # 300 mm field of view: 1.5625 mm pixels


@pytest.fixture(scope="module")
def phantom():
    return generate("normal", seed=1, frames=5, matrix=MATRIX)


@pytest.fixture(scope="module")
def layouts(phantom, tmp_path_factory):
    root = tmp_path_factory.mktemp("labelmaps")
    for conv in ("ukbb", "acdc", "mnms"):
        write_labelmaps(phantom, root / conv, conv, images=conv != "ukbb")
    return root


@pytest.fixture(scope="module")
def dicom_phantom(tmp_path_factory):
    """A 2-frame phantom written as DICOM and as label maps (the same images)."""
    ph = generate("phtn", seed=2, frames=2, matrix=MATRIX)
    out = tmp_path_factory.mktemp("dcm") / "ph"
    write_phantom(ph, out, dicom=True, labels="ukbb")
    return ph, out


def _planes_match(study, phantom, tol=1e-4):
    ref = {(im.slice, im.frame): im for im in phantom.study.images}
    for im in study.images:
        p = ref[(im.slice, im.frame)]
        assert np.abs(im.position - p.position).max() < tol, im.slice
        assert np.abs(im.orientation - p.orientation).max() < 1e-6, im.slice
        assert np.allclose(im.pixel_spacing, p.pixel_spacing, atol=1e-6)


@pytest.mark.parametrize("layout,preset", [("ukbb", "ukbb"), ("acdc", "acdc"), ("mnms", "mnms")])
def test_every_layout_loads_with_its_preset_and_geometry(layouts, phantom, layout, preset):
    assert nifti.detect(layouts / layout) == layout
    study = load_study(layouts / layout)
    assert study.meta["labels"].startswith(preset)
    assert study.meta["layout"] == layout
    _planes_match(study, phantom)
    # sa_00 at the base: slice names agree with the phantom's (base -> apex) whatever the file order
    sa = {c.slice for c in study.contours if c.view == "SA"}
    assert "sa_01" in sa
    # ukbb_cardiac: ED frame 0, ES the smallest LV cavity (the phantom's ES); else the files say
    assert (study.ed_frame, study.es_frame) == (0, phantom.es_frame)
    frames = study.contoured_frames
    if layout == "ukbb":
        assert frames == list(range(5))
        assert {c.slice for c in study.contours if c.view == "LA"} == {"la_2ch", "la_3ch", "la_4ch"}
        assert len([lm for lm in study.landmarks if lm.name == "mitral" and lm.frame == 0]) == 6
    else:
        assert frames == [0, phantom.es_frame]
    kinds = {c.structure for c in study.contours if c.view == "SA"}
    assert {"lv_endo", "lv_epi", "rv_septum", "rv_freewall"} <= kinds


def test_single_file_infers_roles_with_a_warning(layouts):
    study = load_study(layouts / "ukbb" / "seg_sa.nii.gz")
    assert study.meta["layout"] == "file"
    assert any("inferred from topology" in w and "lv=1, myo=2, rv=3" in w for w in study.warnings)
    assert study.frame_times_ms and study.frame_times_ms[1] > 0          # pixdim[4] in ms


@pytest.mark.parametrize("layout,file", [("ukbb", "seg_sa.nii.gz"), ("acdc", None), ("mnms", None)])
def test_topology_inference_finds_each_convention(layouts, layout, file):
    if file is None:
        file = next(p.name for p in (layouts / layout).iterdir() if p.name.endswith("gt.nii.gz"))
    vol = nifti.read_label_volume(layouts / layout / file)
    roles, note = infer_roles(vol.data)
    want = PRESETS[layout]
    assert (roles.lv, roles.myo, roles.rv) == (want.lv, want.myo, want.rv)
    assert layout in note or layout == "ukbb"


def test_la_4ch_with_atria_infers_roles_and_rejects_ambiguity():
    a = np.zeros((40, 40, 1), np.uint8)
    yy, xx = np.mgrid[:40, :40]
    for cx, lv, myo in ((10, 1, 2), (30, 3, 4)):     # two disks each in its own ring: ambiguous
        r = np.hypot(xx - cx, yy - 20)
        a[..., 0][r < 8] = myo
        a[..., 0][r < 5] = lv
    with pytest.raises(StudyError, match="ambiguous"):
        infer_roles(a)


def test_label_mapping_and_presets():
    assert parse_labels("lv=3, myo=2, rv=1").values() == PRESETS["acdc"].values()
    assert parse_labels("ACDC") is PRESETS["acdc"]
    for bad in ("lv=1", "heart=1,myo=2", "xyz", "lv=1,myo=1"):
        with pytest.raises(StudyError):
            parse_labels(bad)


def test_explicit_mapping_overrides_the_layout(layouts):
    study = load_study(layouts / "acdc", labels="lv=3,myo=2,rv=1")
    assert study.meta["labels"].startswith("mapping")
    with pytest.raises(StudyError, match="label 3 is not in the label convention"):
        load_study(layouts / "acdc", labels="lv=1,myo=2")


def test_ras_to_lps_against_the_dicom_series(dicom_phantom):
    """The same phantom as DICOM and as NIfTI: image planes from the DICOM headers equal the
    planes the NIfTI affine gives, and contours extracted from the same pixels agree to 0.01 mm."""
    ph, out = dicom_phantom
    study = load_study(out / "labelmaps")
    nii = {(im.slice, im.frame): im for im in study.images}
    lut = convention_lut("ukbb")
    checked = 0
    for im in ph.study.images:
        if im.frame != 0 or im.view != "SA":
            continue
        h = read_header(out / im.file)
        dcm = ImagePlane(id="d", slice=im.slice, view="SA", frame=0, position=h.position,
                         row_cosine=h.orientation[:3], column_cosine=h.orientation[3:],
                         pixel_spacing=h.pixel_spacing, rows=h.rows, columns=h.columns)
        assert nii[(im.slice, 0)].same_geometry(dcm, tol=1e-4)
        labels = lut[plane_codes(ph, dcm)]
        sc = masks.sa_slice_contours(labels, PRESETS["ukbb"])
        got = {c.structure: c.points for c in study.contours
               if c.slice == im.slice and c.frame == 0 and c.closed}
        for name, pix in sc.closed.items():
            d = np.abs(dcm.pixel_to_scanner(pix) - got[name]).max()
            assert d < 0.01, (im.slice, name, d)
            checked += 1
    assert checked >= 10


def test_voxel_counts_and_model_against_the_analytic_truth(dicom_phantom, tmp_path):
    """metrics.json of a label-map study: model volumes within 3 % of truth (LVM 5 %), voxel
    counts beside them, and RV mass null with its reason."""
    import json

    from cardionurbs.cli import main

    ph, out = dicom_phantom
    rc = main(["analyze", str(out / "labelmaps"), "--format", "nifti", "--labels", "ukbb",
               "--no-figures", "--out", str(tmp_path / "an")])
    assert rc == 0
    d = json.load(open(tmp_path / "an" / "metrics.json"))
    m, t = d["metrics"], ph.truth["metrics"]
    for k, tol in (("LVEDV (mL)", 3), ("LVESV (mL)", 3), ("RVEDV (mL)", 3), ("RVESV (mL)", 3),
                   ("LVM (g)", 5)):
        assert abs(m[k] / t[k] - 1) * 100 < tol, (k, m[k], t[k])
    assert abs(m["LVEF (%)"] - t["LVEF (%)"]) < 2
    for k in ("LVEDV voxel (mL)", "RVEDV voxel (mL)", "LVM voxel (g)"):
        assert abs(m[k] / t[k.replace(" voxel", "")] - 1) < 0.15, k
    assert m["RVM (g)"] is None and "no RV wall" in d["notes"]["RVM (g)"]


def test_voxel_volume_is_count_times_voxel_size(layouts, phantom):
    study = load_study(layouts / "mnms")
    vol = nifti.read_label_volume(next((layouts / "mnms").glob("*_sa_gt.nii.gz")))
    n = int((vol.data[..., 0] == 1).sum())
    spacing = 1.5625 * 1.5625 * phantom.acquisition.sa_spacing_mm
    assert study.meta["voxel_volumes_ml"][0]["lv_cavity"] == pytest.approx(n * spacing / 1000)


def test_real_bivme_segmentation_contours(tmp_path):
    """A real, imperfect segmentation (biv-me convention, identity affine)."""
    path = shared_data("bivme-segmentation", "SAX_3d_1.nii.gz")
    study = load_study(path)
    assert any("identity affine" in w for w in study.warnings)
    assert any("as bivme" in w for w in study.warnings)
    by = {}
    for c in study.contours:
        by.setdefault(c.slice, {})[c.structure] = c
    assert len(by) >= 20
    for sl, d in by.items():
        assert {"lv_endo", "lv_epi"} <= set(d), sl
        a_endo, a_epi = polygon_area(d["lv_endo"].points), polygon_area(d["lv_epi"].points)
        assert 0 < a_endo < a_epi
    vol = nifti.read_label_volume(path)
    lv_px = int((vol.data[:, :, 0, 0] == 1).sum())
    a = polygon_area(by["sa_00"]["lv_endo"].points)
    assert abs(a - lv_px) < 0.1 * lv_px                 # 1 mm pixels: area ~ pixel count


# ------------------------------------------------------------------ masks -> contours
def _disk_labels(n=64, holes=False, island=False, broken=False):
    yy, xx = np.mgrid[:n, :n]
    r = np.hypot(xx - 30.3, yy - 31.7)
    lab = np.zeros((n, n), np.uint8)
    lab[r < 16] = 2
    lab[r < 11] = 1
    lab[(np.hypot(xx - 50, yy - 31.7) < 8) & (r >= 16)] = 3
    if holes:
        lab[(np.hypot(xx - 27, yy - 30) < 2)] = 2           # papillary muscle inside the cavity
    if island:
        lab[2:4, 2:4] = 1
    if broken:
        lab[(r >= 11) & (r < 16) & (yy < 31)] = 0   # ring open over half its length (LVOT)
    return lab


def test_papillary_muscles_are_inside_the_cavity_and_islands_are_dropped():
    roles = PRESETS["mnms"]
    plain = masks.sa_slice_contours(_disk_labels(), roles)
    holed = masks.sa_slice_contours(_disk_labels(holes=True, island=True), roles)
    a0 = abs(masks._area(plain.closed["lv_endo"]))
    assert abs(masks._area(holed.closed["lv_endo"])) == pytest.approx(a0, rel=1e-9)
    assert any("island" in n for n in holed.notes)
    assert set(plain.open) == {"rv_septum", "rv_freewall"}


def test_broken_ring_keeps_the_endocardium_as_an_open_basal_section():
    """A ring open over half its length (the LV outflow / mitral orifice at the base): the
    cavity is contoured, with a note (before issue 29's change it was left out and its slab
    lost; a blob only touching the wall is refused: tests/test_open_basal.py)."""
    sc = masks.sa_slice_contours(_disk_labels(broken=True), PRESETS["mnms"])
    assert "lv_endo" in sc.closed and "lv_epi" in sc.closed and not sc.skipped
    assert any("open basal section" in n for n in sc.notes)


def test_broken_ring_warning_names_slice_and_frame(tmp_path):
    import nibabel as nib

    lab = np.stack([_disk_labels(), _disk_labels(broken=True), _disk_labels(),
                    np.zeros((64, 64), np.uint8)], axis=2)
    nib.save(nib.Nifti1Image(lab, np.diag([1.5, 1.5, 10, 1])), str(tmp_path / "m.nii.gz"))
    study = load_study(tmp_path / "m.nii.gz", labels="mnms")
    assert any("open basal section" in w and "slice sa_" in w and "frame 0" in w
               for w in study.warnings)
    assert any("no labels at any frame" in w for w in study.warnings)


@settings(max_examples=25, deadline=None)
@given(a=st.floats(6, 20), b=st.floats(6, 20), cx=st.floats(28, 36), cy=st.floats(28, 36),
       phi=st.floats(0, np.pi))
def test_boundary_area_matches_the_ellipse(a, b, cx, cy, phi):
    """Sub-pixel boundary of a pixel-centre-sampled ellipse: area within 1.5 pixels per
    unit of perimeter (a quarter-pixel band), area centroid within 0.3 pixel."""
    yy, xx = np.mgrid[:64, :64].astype(float)
    u = (xx - cx) * np.cos(phi) + (yy - cy) * np.sin(phi)
    v = -(xx - cx) * np.sin(phi) + (yy - cy) * np.cos(phi)
    mask = ((u / a) ** 2 + (v / b) ** 2 < 1).T             # first axis = x (c)
    loop = masks.boundary_loop(mask)
    area = abs(masks._area(loop))
    perim = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
    assert abs(area - np.pi * a * b) < 0.25 * perim
    assert np.allclose(polygon_centroid(loop), [cx, cy], atol=0.3)


def test_ukbb_ed_es_files_layout(layouts, phantom, tmp_path):
    """seg_sa_ED + seg_sa_ES (ukbb_cardiac's 3-D maps): frames 0 (ED) and 1 (ES)."""
    import nibabel as nib

    img = nib.load(str(layouts / "ukbb" / "seg_sa.nii.gz"))
    data = np.asarray(img.dataobj)
    for name, t in (("ED", 0), ("ES", phantom.es_frame)):
        nib.save(nib.Nifti1Image(data[..., t], img.affine, img.header), str(tmp_path / f"seg_sa_{name}.nii.gz"))
    study = load_study(tmp_path)
    assert study.meta["layout"] == "ukbb" and (study.ed_frame, study.es_frame) == (0, 1)
    assert study.contoured_frames == [0, 1]
    _planes_match(study, phantom)


def test_phantom_cli_writes_label_maps(tmp_path):
    from cardionurbs.cli import main

    out = tmp_path / "ph"
    assert main(["phantom", "--pathology", "mr", "--frames", "2", "--no-dicom", "--labels", "acdc",
                 "--out", str(out)]) == 0
    names = sorted(p.name for p in (out / "labelmaps").iterdir())
    assert "Info.cfg" in names and "mr_000_frame01_gt.nii.gz" in names and "mr_000_4d.nii.gz" in names
    study = load_study(out / "labelmaps")
    assert study.meta["layout"] == "acdc" and study.contoured_frames == [0, 1]
