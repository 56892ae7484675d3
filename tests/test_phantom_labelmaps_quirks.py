"""Phantom label maps written in the real datasets' conventions (``--label-quirks``) read back
right: spacing, slice positions, frame interval in ms, ED/ES frames, and voxel-count volumes
near the analytic truth (issue 29, item 6). The model's accuracy on them is tested elsewhere."""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import load_study
from cardionurbs.cli import main
from cardionurbs.errors import PhantomError
from cardionurbs.phantom.generate import generate
from cardionurbs.phantom.geometry import Acquisition, sa_heights
from cardionurbs.phantom.labelmaps import parse_quirks, write_labelmaps
from cardionurbs.pipeline import analyse_study

#: (layout, quirks) written and read back
VARIANTS = [("acdc", "real"), ("acdc", "real,pv"), ("ukbb", "real"), ("ukbb", "real,lps,apex-first"),
            ("mnms", "lps"), ("mnms2", "real,base-first"), ("mnms2", "apex-first")]
#: (pathology, SA spacing mm, SA thickness mm): 10 mm with 5 mm gaps, and 5 mm slices
PHANTOMS = [("normal", 10.0, 5.0), ("phtn", 5.0, 4.0)]


@pytest.fixture(scope="module", params=PHANTOMS, ids=lambda p: f"{p[0]}-{p[1]:g}mm")
def phantom(request):
    name, spacing, thickness = request.param
    return generate(name, seed=3, frames=2, matrix=128, sa_spacing_mm=spacing,
                    sa_thickness_mm=thickness, volume_check=False), spacing


def _centre(im) -> np.ndarray:
    """The plane's centre in scanner mm (independent of which corner the array starts at)."""
    return (im.position + 0.5 * (im.columns - 1) * im.pixel_spacing[1] * im.row_cosine
            + 0.5 * (im.rows - 1) * im.pixel_spacing[0] * im.column_cosine)


@pytest.mark.parametrize("layout,quirks", VARIANTS)
def test_every_variant_reads_back_against_the_truth(phantom, layout, quirks, tmp_path):
    ph, spacing = phantom
    write_labelmaps(ph, tmp_path, layout, quirks=quirks, images=False)
    study = load_study(tmp_path)
    assert study.meta["layout"] == layout
    assert (study.ed_frame, study.es_frame) == (0, ph.es_frame)
    ref = [im for im in ph.study.images if im.view == "SA" and im.frame == 0]
    sa = [im for im in study.images if im.view == "SA" and im.frame == 0]
    assert np.allclose([im.pixel_spacing for im in sa], ref[0].pixel_spacing, atol=1e-5)
    depth = np.sort([_centre(im) @ sa[0].normal for im in sa])
    assert np.allclose(np.diff(depth), spacing, atol=1e-3)
    if "real" in quirks and layout == "acdc":          # ACDC's placeholder orientation
        assert all(h["orientation"] == "placeholder" for h in study.meta["headers"].values())
    else:                                              # where the slices are, whatever the order
        got = np.array(sorted(map(tuple, np.round([_centre(im) for im in sa], 3))))
        want = np.array(sorted(map(tuple, np.round([_centre(im) for im in ref
                                                    if im.slice in {s.slice for s in sa}], 3))))
        assert np.allclose(got, want, atol=1e-2)
    if layout == "mnms2":                              # the 4-chamber LA maps, as ukbb's are used
        assert {(c.frame, c.structure) for c in study.contours if c.slice == "la_4ch"} >= {
            (0, "lv_endo"), (ph.es_frame, "lv_endo"), (0, "lv_epi")}
        assert len([lm for lm in study.landmarks if lm.name == "mitral" and lm.frame == 0]) == 2
    if layout == "ukbb":                               # seconds with an unknown unit -> ms
        dt = 60000.0 / ph.study.heart_rate_bpm / len(ph.phases)
        assert study.frame_times_ms[1] == pytest.approx(dt, rel=1e-5)
        assert study.meta["time_axis"]["unit_used"] == "sec"
    truth = ph.truth["metrics"]                       # analytic (truth.json)
    ed, es = (study.meta["voxel_volumes_ml"][f] for f in (0, ph.es_frame))
    got = {"LVEDV (mL)": ed["lv_cavity"], "LVESV (mL)": es["lv_cavity"], "RVEDV (mL)": ed["rv_cavity"],
           "RVESV (mL)": es["rv_cavity"], "LVM (g)": 1.05 * ed["lv_myocardium"]}
    for key, value in got.items():
        assert abs(value / truth[key] - 1) < 0.10, (key, value, truth[key])


def test_real_headers_are_the_datasets_own(phantom, tmp_path):
    ph, spacing = phantom
    write_labelmaps(ph, tmp_path / "acdc", "acdc", quirks="real", images=False)
    write_labelmaps(ph, tmp_path / "ukbb", "ukbb", quirks="real", images=False)
    h = nib.load(str(next((tmp_path / "acdc").glob("*_frame01_gt.nii.gz")))).header
    assert (int(h["sform_code"]), int(h["qform_code"]), int(h["xyzt_units"])) == (2, 0, 0)
    assert np.allclose(np.linalg.norm(h.get_sform()[:3, :3], axis=0), 1.0)
    assert h.get_zooms()[2] == pytest.approx(spacing)
    a = np.asanyarray(nib.load(str(next((tmp_path / "acdc").glob("*_frame01_gt.nii.gz")))).dataobj)
    lv = [(a[..., k] == 3).sum() for k in range(a.shape[2])]
    assert lv[0] > 0 and lv[-1] < max(lv)           # base first: the large cavity at k = 0 side
    u = nib.load(str(tmp_path / "ukbb" / "seg_sa.nii.gz")).header
    assert u.get_xyzt_units()[1] == "unknown"
    assert u.get_zooms()[3] == pytest.approx(60.0 / ph.study.heart_rate_bpm / len(ph.phases), rel=1e-5)


def test_quirks_are_checked():
    assert parse_quirks("real, lps") == ("real", "lps")
    with pytest.raises(PhantomError, match="unknown label-map quirk 'rasx'"):
        parse_quirks("real,rasx")
    with pytest.raises(PhantomError, match="exclude each other"):
        parse_quirks("apex-first,base-first")


def test_phantom_cli_writes_real_quirks_and_refuses_bad_ones(tmp_path, capsys):
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom", "--labels",
                 "mnms2", "--label-quirks", "real", "--sa-spacing", "10", "--sa-thickness", "5",
                 "--out", str(tmp_path / "p")]) == 0
    names = sorted(q.name for q in (tmp_path / "p" / "labelmaps").iterdir())
    assert {n.split("_", 2)[-1] for n in names} >= {"SA_ED_gt.nii.gz", "SA_ES_gt.nii.gz",
                                                    "LA_ED_gt.nii.gz", "LA_ES_gt.nii.gz"}
    capsys.readouterr()
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--labels", "acdc",
                 "--label-quirks", "sideways", "--out", str(tmp_path / "q")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sideways" in err[0]
    assert not (tmp_path / "q").exists()


@settings(max_examples=25, deadline=None)
@given(spacing=st.floats(4.0, 15.0))
def test_first_sa_slice_lies_within_one_spacing_of_the_base(phantom, spacing):
    """The first SA slice follows the spacing (0.6 of it below the ED base, as a planner puts
    it within one gap of the valve plane), so no basal slab is left out of a fine stack; a
    given offset is kept."""
    anatomy = phantom[0].anatomy
    h = sa_heights(anatomy, Acquisition(sa_spacing_mm=spacing, n_sa=3))
    assert anatomy.z_base - spacing < h[0] < anatomy.z_base
    assert h[0] == pytest.approx(min(anatomy.z_base - 0.6 * spacing, anatomy.z_top_min - 2.0))
    fixed = sa_heights(anatomy, Acquisition(sa_spacing_mm=spacing, n_sa=3, sa_first_offset_mm=6.0))
    assert fixed[0] == pytest.approx(min(anatomy.z_base - 6.0, anatomy.z_top_min - 2.0))
    with pytest.raises(PhantomError, match="sa_first_offset_mm"):
        Acquisition(sa_first_offset_mm=-1.0)


def test_five_mm_acdc_as_distributed_meets_the_truth(phantom, tmp_path):
    """With 5 mm slices the model from the maps as ACDC ships them is within 3 % (volumes) and
    5 % (LVM) of the analytic truth (issue 29: the basal slab was missing, -5..-9 %)."""
    ph, spacing = phantom
    if spacing != 5.0:
        pytest.skip("the 5 mm phantom only")
    write_labelmaps(ph, tmp_path, "acdc", quirks="real", images=False)
    _, m = analyse_study(load_study(tmp_path))
    t = ph.truth["metrics"]
    for key, bound in (("LVEDV (mL)", 0.03), ("RVEDV (mL)", 0.03), ("LVESV (mL)", 0.03),
                       ("LVM (g)", 0.05)):
        assert abs(m[key] / t[key] - 1) < bound, (key, m[key], t[key])
