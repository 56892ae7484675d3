"""Label maps closed and placed as they were labelled (issue 29 items 2, 3, 7): base and
apex of the SA stack from the anatomy, a labelled slice standing for its slab, and the QC
flags that compare the model with the voxel count."""

from __future__ import annotations

import json

import nibabel as nib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import StudyError, load_study
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.analysis.voxels import myocardium_flags, voxel_disagreement
from cardionurbs.cli import main
from cardionurbs.errors import ReconstructionError
from cardionurbs.geometry import polygon_area
from cardionurbs.imaging.stack import base_end_from_anatomy

PX, DZ, N = 1.5, 10.0, 96          # pixel (mm), slice spacing (mm), matrix


def _slice(r_lv: float, wall: float, rv: bool, cap: bool = False) -> np.ndarray:
    """One ACDC-labelled slice (1 RV, 2 myocardium, 3 LV): an LV disc of radius r_lv (mm)
    in a ring ``wall`` thick, an RV crescent beside it; ``cap``: myocardium only."""
    x = (np.arange(N) - N / 2 + 0.5) * PX
    X, Y = np.meshgrid(x, x, indexing="ij")
    r = np.hypot(X, Y)
    out = np.zeros((N, N), np.uint8)
    if cap:
        out[r < r_lv] = 2
        return out
    out[r < r_lv + wall] = 2
    out[r < r_lv] = 3
    if rv:
        crescent = (np.hypot(X - (r_lv + wall), Y) < 1.1 * r_lv) & (r >= r_lv + wall)
        out[crescent] = 1
    return out


def _heart(n: int = 8, scale: float = 1.0, wall: float = 7.0, cap: bool = True) -> np.ndarray:
    """(x, y, n) labels of a spheroidal LV, base at k = 0: radii taper to the apex, the RV
    on the basal two thirds, the last slice a myocardial cap."""
    k = np.arange(n)
    radii = scale * 26.0 * np.sqrt(np.clip(1 - ((k + 0.5) / (n + 0.3)) ** 2, 0.02, None))
    sl = [_slice(r, wall, rv=i < 2 * n // 3, cap=cap and i == n - 1) for i, r in enumerate(radii)]
    return np.stack(sl, axis=2)


def _save(data: np.ndarray, path, flip_z: bool = False):
    """Written as ACDC writes it: unit-free identity directions, the spacing in pixdim."""
    aff = np.diag([PX, PX, DZ, 1.0])
    img = nib.Nifti1Image(data[:, :, ::-1] if flip_z else data, aff)
    img.set_sform(aff, code=2)
    img.set_qform(aff, code=1)
    nib.save(img, str(path))
    return path


def _sa_areas(study, frame=0):
    """LV endocardial contour area (mm²) per SA slice name, base (sa_00) first."""
    out = {}
    for c in study.contours_at(frame, "lv_endo", view="SA"):
        n = np.cross(*[np.asarray(v, float) for v in
                       (study.images[0].row_cosine, study.images[0].column_cosine)])
        out[c.slice] = polygon_area(c.points, n)
    return [out[k] for k in sorted(out)]


# ------------------------------------------------------------------ base and apex
@pytest.mark.parametrize("flip", [False, True], ids=["base first", "apex first"])
def test_base_and_apex_come_from_the_anatomy_not_the_slice_order(tmp_path, flip):
    """The same heart written base-first and apex-first: sa_00 is the widest (basal) slice
    either way, and the myocardial cap is the last slice."""
    study = load_study(_save(_heart(), tmp_path / "seg.nii.gz", flip_z=flip))
    assert study.meta["sa_orientation"].startswith("anatomy")
    areas = _sa_areas(study)
    assert areas[0] == max(areas) and areas == sorted(areas, reverse=True)
    last = max(im.slice for im in study.images if im.view == "SA")
    assert not study.contours_at(0, "lv_endo", view="SA") or \
        last not in {c.slice for c in study.contours_at(0, "lv_endo", view="SA")}
    assert not any("partial tracing" in w for w in reconstruct(study).warnings)


def _open_ring(r_lv: float, wall: float) -> np.ndarray:
    """An LV cavity the myocardium rings over one half of its border only (an outflow)."""
    out = _slice(r_lv, wall, rv=False)
    x = (np.arange(N) - N / 2 + 0.5) * PX
    X, _ = np.meshgrid(x, x, indexing="ij")
    out[(out == 2) & (X > 0)] = 0
    return out


def test_conflicting_anatomy_is_refused_with_one_line(tmp_path, capsys):
    """The narrow end shows an LV cavity open to one side (an outflow, the base's sign)
    while the cavity and the RV taper towards it: refused, exit 2, one stderr line naming
    the file and the cues."""
    data = _heart(cap=False)
    data[:, :, -1] = _open_ring(8.0, 6.0)
    (tmp_path / "in").mkdir()
    path = _save(data, tmp_path / "in" / "seg.nii.gz")
    with pytest.raises(StudyError, match="base and apex cannot be told apart"):
        load_study(path)
    assert main(["analyze", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seg.nii.gz" in err[0] and "LV outflow: base at the last" in err[0]
    assert not (tmp_path / "out").exists()


def test_a_wide_ring_of_myocardium_at_the_base_is_no_cap(tmp_path):
    """A basal slice through the annulus showing myocardium alone, as a wide ring (ES maps
    can): not taken for the wall closing over the apex, the stack still reads base first."""
    data = _heart()
    ring = _slice(24.0, 8.0, rv=False)
    ring[ring == 3] = 0
    data[:, :, 0] = ring
    study = load_study(_save(data, tmp_path / "seg.nii.gz", flip_z=True))
    assert study.meta["sa_orientation"].startswith("anatomy")
    # the file runs apex first: the cap at its first slice says "base at the last", and the
    # basal ring (its last slice) is no second cap that would cancel it
    assert "myocardial cap: base at the last slice" in study.meta["sa_orientation"]
    areas = _sa_areas(study)
    assert areas[0] == max(areas)


def test_a_stack_without_anatomical_cues_says_so_in_one_warning(tmp_path):
    """A straight tube (no taper, no RV, no cap): the order falls back on the header's
    patient axes, with one warning naming the file."""
    data = np.stack([_slice(20.0, 6.0, rv=False)] * 6, axis=2)
    study = load_study(_save(data, tmp_path / "tube.nii.gz"))
    assert study.meta["sa_orientation"].startswith("LPS prior")
    warn = [w for w in study.warnings if "header's patient axes" in w]
    assert len(warn) == 1 and "tube.nii.gz" in warn[0]


@settings(max_examples=40, deadline=None)
@given(n=st.integers(3, 14), a0=st.floats(200, 2000), drop=st.floats(0.4, 0.95),
       rv=st.booleans(), cap=st.booleans())
def test_the_anatomical_vote_turns_with_the_stack(n, a0, drop, rv, cap):
    """A tapering profile (with or without an RV and a cap) says base-first; the same
    profile reversed says base-last: the vote depends on the anatomy, not on the order."""
    lv = a0 * (1 - drop * (np.arange(n) / (n - 1)) ** 2)
    myo = 0.4 * lv
    rvp = np.where(np.arange(n) < 2 * n // 3, lv, 0.0) if rv else None
    end, votes = base_end_from_anatomy(lv, myo, rvp, cap=(False, cap))
    back, _ = base_end_from_anatomy(lv[::-1], myo[::-1], None if rvp is None else rvp[::-1],
                                    cap=(cap, False))
    assert end == 1 and back == -1 and votes["cavity taper"] == 1


def test_the_mitral_annulus_cross_checks_the_anatomy():
    from cardionurbs.imaging.stack import sa_base_direction
    from cardionurbs.io.masks import StackAnatomy
    lv = np.array([900.0, 800, 600, 300])
    anat = StackAnatomy(lv, 0.4 * lv, None, (False, True), (False, False))
    centres = np.outer(np.arange(4), [0, 0, 10.0])
    u, rule = sa_base_direction([0, 0, 1.0], centres, anat)
    assert u @ [0, 0, 1] > 0 and rule.startswith("anatomy")
    u, rule = sa_base_direction([0, 0, 1.0], centres, anat, mitral=np.array([[0, 0, -8.0]]))
    assert u @ [0, 0, 1] > 0 and rule.startswith("mitral")
    with pytest.raises(ReconstructionError, match="mitral annulus lies at the end"):
        sa_base_direction([0, 0, 1.0], centres, anat, mitral=np.array([[0, 0, 40.0]]))


# ------------------------------------------------------------------ the slab rule
@pytest.fixture(scope="module")
def two_frames(tmp_path_factory):
    """ED and ES of one heart in a 4-D map written apex first, ES with 25 % more labelled
    myocardium than ED (as ACDC's ES maps have): the labels do not conserve it."""
    ed = _heart(n=8, scale=1.0, wall=7.0)
    es = _heart(n=8, scale=0.75, wall=10.5)
    path = tmp_path_factory.mktemp("slab") / "in" / "seg.nii.gz"
    path.parent.mkdir()
    aff = np.diag([PX, PX, DZ, 1.0])
    img = nib.Nifti1Image(np.stack([ed, es], axis=3)[:, :, ::-1], aff)
    img.set_sform(aff, code=2)
    img.header.set_xyzt_units("mm", "msec")
    img.header["pixdim"][4] = 400.0
    nib.save(img, str(path))
    return path, ed, es


def test_each_labelled_slice_stands_for_its_slab(two_frames):
    """Between the planes half-way to the neighbouring slices, the model holds the label
    area times the spacing (within 3 %, the sub-pixel boundary of a 1.5 mm grid), at ED and
    at ES; the ES valve plane stays at the labels' slab (their myocardium is not conserved)
    with a warning; the cavities agree with the voxel count within 3 %."""
    path, ed, es = two_frames
    study = load_study(path)
    model = reconstruct(study)
    assert (model.ed_frame, model.es_frame) == (0, 1)
    assert model.base_shift_mm[model.es_frame] == 0.0
    assert any("not moved to conserve the myocardium" in w for w in model.warnings)
    vox = study.meta["voxel_volumes_ml"]
    for f, data in ((0, ed), (1, es)):
        geo = model.geometry[f]
        n = geo.direction
        cav = model.solids(f)["lv_cavity"]
        lev = np.sort([float(im.position @ n) for im in study.images
                       if im.view == "SA" and im.frame == f])
        edges = np.r_[lev[0] - DZ / 2, (lev[1:] + lev[:-1]) / 2, lev[-1] + DZ / 2]
        above = np.array([cav.trim_by_plane(list(n), float(e)).volume() / 1000 for e in edges])
        model_slabs = above[:-1] - above[1:]
        label_slabs = (data == 3).sum(axis=(0, 1)) * PX * PX * DZ / 1000    # base first
        keep = label_slabs > 5.0                   # the cap and tip slabs are mm-thin shells
        np.testing.assert_allclose(model_slabs[keep], label_slabs[keep], rtol=0.03)
        assert model.volumes[f]["lv_cavity"] == pytest.approx(vox[f]["lv_cavity"], rel=0.03)


# ------------------------------------------------------------------ QC
def test_model_voxel_disagreement_is_flagged_beyond_its_bound():
    m = {"LVEDV (mL)": 130.0, "LVEDV voxel (mL)": 100.0, "LVESV (mL)": 45.0,
         "LVESV voxel (mL)": 42.0, "LVEF (%)": 65.0, "LVEF voxel (%)": 58.0,
         "RVEDV (mL)": float("nan"), "RVEDV voxel (mL)": 100.0}
    flags = voxel_disagreement(m)
    assert set(flags) == {"LVEDV (mL)", "LVEF (%)"}
    assert "+30.0 %" in flags["LVEDV (mL)"][0] and "+7.0 points" in flags["LVEF (%)"][0]


def test_myocardium_flags_fire_on_a_built_disagreement():
    vox = {f: {"lv_myocardium": v} for f, v in enumerate([100, 101, 99, 60, 98, 100])}
    # the labels' ES frame loses 40 % of the myocardium; a model that follows them within
    # 5 points is not flagged for it, one that loses 60 % is
    flags = myocardium_flags(vox, 0, 3, model_myo=(100.0, 55.0))
    assert not any("model" in f for f in flags)
    flags = myocardium_flags(vox, 0, 3, model_myo=(100.0, 40.0))
    assert any("model -60 % vs labels -40 %" in f for f in flags)
    assert any("ES frame 3" in f and "off its neighbours'" in f for f in flags)
    steady = {f: {"lv_myocardium": v} for f, v in enumerate([100, 101, 99, 98, 100])}
    assert myocardium_flags(steady, 0, 2, model_myo=(100.0, 99.0)) == []


def test_qc_names_the_label_map_flags_in_metrics_json(two_frames, tmp_path, monkeypatch):
    """A built disagreement reaches metrics.json's QC: the voxel count of ED made 40 %
    smaller than the map holds (as a map read with the wrong spacing would give)."""
    from cardionurbs.io import nifti
    real = nifti.voxel_volumes

    def shrunk(*a, **k):
        out = real(*a, **k)
        out[0] = {key: 0.6 * v for key, v in out[0].items()}
        return out
    monkeypatch.setattr(nifti, "voxel_volumes", shrunk)
    path, _, _ = two_frames
    assert main(["analyze", str(path), "--out", str(tmp_path / "o"), "--outputs", "metrics"]) == 0
    doc = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert "LVEDV model" in doc["QC"] and "beyond 6 %" in doc["QC"]
    assert doc["quality"]["metrics"]["LVEDV (mL)"]["flags"]


# ------------------------------------------------------------------ a phantom as ACDC ships it
def _as_distributed(folder):
    """The phantom's ACDC maps rewritten as ACDC distributes them: base first, a unit-scale
    RAS sform of code 2 (no orientation), no qform, the spacing in pixdim only."""
    for f in sorted(folder.glob("*_gt.nii.gz")):
        img = nib.load(str(f))
        zooms = img.header.get_zooms()[:3]
        unit = np.diag([-1.0, -1.0, 1.0, 1.0])
        out = nib.Nifti1Image(np.asanyarray(img.dataobj)[:, :, ::-1], unit)
        out.set_sform(unit, code=2)
        out.set_qform(None, code=0)
        out.header["pixdim"][1:4] = zooms
        nib.save(out, str(f))


def test_a_phantom_written_as_acdc_ships_it_meets_the_truth(tmp_path):
    """No orientation in the header, the stack base first: the anatomy finds the base, and
    the model is within 3 % (volumes) and 5 % (LVM) of the analytic truth, nearer it than
    voxel counting on LVM (which partial volume at the wall's two borders costs 2-10 %)."""
    from cardionurbs.analysis.function import measure
    from cardionurbs.analysis.voxels import voxel_metrics
    from cardionurbs.phantom.generate import generate
    from cardionurbs.phantom.labelmaps import write_labelmaps
    # the validation's grid (1.44 mm pixels); the RV volume is the closest to its bound:
    # the phantom's first slice lies 6 mm below the base, the slab reaches 5 mm, and the RV
    # holds 2.4 % of its volume per mm there (RVEDV -2.2 .. -3.0 % at 10 mm slices)
    ph = generate("mr", seed=1, frames=6, matrix=208, volume_check=False)
    write_labelmaps(ph, tmp_path, "acdc", frames=[0, ph.es_frame], images=False)
    _as_distributed(tmp_path)
    study = load_study(tmp_path)
    assert study.meta["sa_orientation"].startswith("anatomy")
    model = reconstruct(study)
    m = measure(model)
    vox = voxel_metrics(study.meta["voxel_volumes_ml"], model.ed_frame, model.es_frame)
    t = ph.truth["metrics"]
    for k in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "RVESV (mL)"):
        assert abs(m[k] / t[k] - 1) < 0.03, k
    assert abs(m["LVM (g)"] / t["LVM (g)"] - 1) < 0.05
    assert abs(m["LVM (g)"] / t["LVM (g)"] - 1) < abs(vox["LVM voxel (g)"] / t["LVM (g)"] - 1)
