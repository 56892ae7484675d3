"""Open basal short-axis slices of label maps (issue 29): where the myocardium opens to the
LV outflow tract or the mitral orifice, the LV cavity the labels hold is kept as the basal
section (it was left out, losing its slab); a blob that only touches the wall is still
refused."""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest

from cardionurbs import load_study
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.io import masks
from cardionurbs.io.labels import PRESETS

ACDC = PRESETS["acdc"]                       # 1 RV, 2 myocardium, 3 LV
PX, DZ, N = 1.5, 10.0, 96                    # pixel (mm), slice spacing (mm), matrix


def _grid() -> tuple[np.ndarray, np.ndarray]:
    x = (np.arange(N) - N / 2 + 0.5) * PX
    return np.meshgrid(x, x, indexing="ij")


def _slice(r_lv: float, wall: float = 7.0, open_side: bool = False) -> np.ndarray:
    """An LV disc of radius r_lv (mm) in a myocardial ring ``wall`` thick; ``open_side``:
    the ring removed over the half x > 0 (the wall open to the outflow / atrium)."""
    X, Y = _grid()
    r = np.hypot(X, Y)
    out = np.zeros((N, N), np.uint8)
    out[r < r_lv + wall] = 2
    out[r < r_lv] = 3
    if open_side:
        out[(out == 2) & (X > 0)] = 0
    return out


def _touching_blob() -> np.ndarray:
    """A solid disc of myocardium with an LV-labelled disc just touching it from outside."""
    X, Y = _grid()
    out = np.zeros((N, N), np.uint8)
    out[np.hypot(X, Y) < 20] = 2
    out[(np.hypot(X - 31.5, Y) < 12) & (out == 0)] = 3
    return out


def test_an_open_basal_cavity_is_kept_with_its_labelled_area():
    """A cavity ringed over half its border: contoured, with a note, its contour's area the
    label's pixel area (within a quarter-pixel band along its perimeter)."""
    lab = _slice(20.0, open_side=True)
    sc = masks.sa_slice_contours(lab, ACDC)
    assert "lv_endo" in sc.closed and "lv_epi" in sc.closed and not sc.skipped
    assert any("open basal section" in n for n in sc.notes)
    area = abs(masks._area(sc.closed["lv_endo"]))
    n_px = int((lab == 3).sum())
    assert area == pytest.approx(n_px, abs=0.25 * len(sc.closed["lv_endo"]))


def test_a_blob_only_touching_the_wall_is_refused():
    """LV label outside the myocardium, touching it over under MIN_OPEN_RING_FRACTION of
    its border: not the LV's cavity, left out with the reason."""
    sc = masks.sa_slice_contours(_touching_blob(), ACDC)
    assert "lv_endo" not in sc.closed
    assert any("not ringed" in s for s in sc.skipped)


def test_a_ringed_cavity_carries_no_open_note():
    sc = masks.sa_slice_contours(_slice(20.0), ACDC)
    assert "lv_endo" in sc.closed and not sc.notes and not sc.skipped


def test_the_open_basal_slab_is_in_the_model(tmp_path):
    """A tapering LV whose basal slice is open over half its wall: the model's cavity holds
    the voxel count within 3 % (leaving the basal section out, as before issue 29's change, lost its slab: -24 %)."""
    k = np.arange(6)
    radii = 24.0 * np.sqrt(np.clip(1 - ((k + 0.5) / 6.3) ** 2, 0.02, None))
    data = np.stack([_slice(r, open_side=i == 0) for i, r in enumerate(radii)], axis=2)
    aff = np.diag([PX, PX, DZ, 1.0])
    img = nib.Nifti1Image(data, aff)
    img.set_sform(aff, code=2)
    nib.save(img, str(tmp_path / "seg.nii.gz"))
    study = load_study(tmp_path / "seg.nii.gz", labels="acdc")
    assert any("open basal section" in w and "slice sa_00" in w for w in study.warnings)
    model = reconstruct(study)
    vox = study.meta["voxel_volumes_ml"][model.ed_frame]["lv_cavity"]
    assert model.volumes[model.ed_frame]["lv_cavity"] == pytest.approx(vox, rel=0.03)


def _save(tmp_path, data: np.ndarray):
    aff = np.diag([PX, PX, DZ, 1.0])
    img = nib.Nifti1Image(data, aff)
    img.set_sform(aff, code=2)
    nib.save(img, str(tmp_path / "seg.nii.gz"))
    return load_study(tmp_path / "seg.nii.gz", labels="acdc")


def test_a_small_open_basal_section_stays_in_the_surface(tmp_path):
    """An open basal slice whose cavity is under MIN_BASAL_AREA_RATIO of the next slice's
    (the slice across the annulus' saddle): a label map's section is the labelled cavity,
    not a partial tracing, so it stays the basal section and its slab is in the ED volume
    (dropped as a partial tracing, the model lost it: issue 29, seed 210 at 10 mm)."""
    from cardionurbs.anatomy.sections import MIN_BASAL_AREA_RATIO
    radii = [10.0, 24.0, 23.0, 21.0, 17.0, 10.0]
    assert (radii[0] / radii[1]) ** 2 < MIN_BASAL_AREA_RATIO
    study = _save(tmp_path, np.stack([_slice(r, open_side=i == 0) for i, r in enumerate(radii)],
                                     axis=2))
    model = reconstruct(study)
    geo = model.geometry[model.ed_frame]
    assert geo.sections["lv_endo"][0].slice == "sa_00" and not geo.left_out
    vox = study.meta["voxel_volumes_ml"][model.ed_frame]["lv_cavity"]
    assert model.volumes[model.ed_frame]["lv_cavity"] == pytest.approx(vox, rel=0.03)


def test_an_outflow_slice_without_wall_counts_as_its_slab(tmp_path):
    """A basal slice holding LV cavity but no myocardium (the LV outflow tract below the
    aortic valve): no section, but the labels' cavity there stands for its slab, so the
    model's LV cavity holds the voxel count (without it, short by that slab)."""
    from cardionurbs.anatomy.sections import labelled_beyond_base_ml
    X, Y = _grid()
    tract = np.where(np.hypot(X - 8.0, Y) < 12.0, 3, 0).astype(np.uint8)
    radii = [24.0, 23.0, 21.0, 17.0, 10.0]
    study = _save(tmp_path, np.stack([tract] + [_slice(r) for r in radii], axis=2))
    assert any("without myocardium" in w and "slice sa_00" in w for w in study.warnings)
    model = reconstruct(study)
    ed = model.ed_frame
    slab = float((tract == 3).sum()) * PX * PX * DZ / 1000.0
    beyond = labelled_beyond_base_ml(study, model.geometry[ed])
    assert beyond == pytest.approx(slab, rel=0.02)      # the half-slice plane lies in its own slab
    vox = study.meta["voxel_volumes_ml"][ed]["lv_cavity"]
    assert model.volumes[ed]["lv_cavity"] == pytest.approx(vox, rel=0.03)
    assert vox - (model.volumes[ed]["lv_cavity"] - beyond) > 0.5 * slab   # the surface alone


def test_no_labelled_slab_beyond_the_base_of_contours():
    """Hand contours (no ``lv_slice_ml``) gain nothing beyond their base."""
    from cardionurbs.anatomy.sections import FrameGeometry, labelled_beyond_base_ml
    from cardionurbs.study import Study
    geo = FrameGeometry(frame=0, direction=np.array([0.0, 0.0, 1.0]), thickness=8.0)
    assert labelled_beyond_base_ml(Study(subject="x", source="x"), geo) == 0.0


def _planes_study(levels, per):
    """A study of SA planes at ``levels`` (mm along z) and the reader's per-slice counts."""
    from cardionurbs.imaging.geometry import ImagePlane
    from cardionurbs.study import Study
    study = Study(subject="x", source="x")
    for i, z in enumerate(levels):
        study.images.append(ImagePlane(f"sa_{i:02d}_f000", f"sa_{i:02d}", "SA", 0,
                                       np.array([0.0, 0.0, z]), np.array([1.0, 0.0, 0.0]),
                                       np.array([0.0, 1.0, 0.0]), (1.0, 1.0)))
    study.meta = {"lv_slice_ml": {0: per}}
    return study


def _geometry(plane, base_slice="sa_02"):
    from cardionurbs.anatomy.mesh import Plane
    from cardionurbs.anatomy.sections import FrameGeometry, Section
    n = np.array([0.0, 0.0, 1.0])
    geo = FrameGeometry(frame=0, direction=n, thickness=10.0)
    ring = np.c_[np.cos(np.linspace(0, 6, 12)), np.sin(np.linspace(0, 6, 12)), np.full(12, 20.0)]
    geo.sections["lv_endo"] = [Section("lv_endo", 0, 20.0 * ring * [1, 1, 0.05], slice=base_slice)]
    geo.base_planes["lv"] = Plane(*plane)
    return geo


def test_the_slab_beyond_a_half_slice_and_a_landmark_plane():
    """Slices at z = 0, 10 (basal) and the base section at 20 mm (n = +z, base to apex): with
    the half-slice plane at 15 mm the two basal slabs count whole; with a mitral plane tilted
    so that it lies at z = 8 under the outflow slice's cavity (centroid x = 10) and at 12
    elsewhere, sa_01's slab [5, 15] counts over [5, 8] only, sa_00's whole; aortic landmarks
    (an LVOT tube) count nothing."""
    from cardionurbs.anatomy.sections import labelled_beyond_base_ml
    from cardionurbs.study import Landmark
    per = {"sa_00": {"lv_cavity": 1.0, "centroid": [10.0, 0.0, 0.0]},
           "sa_01": {"lv_cavity": 2.0, "lv_myocardium": 0.5, "centroid": [10.0, 0.0, 10.0]},
           "sa_02": {"lv_cavity": 9.0, "centroid": [0.0, 0.0, 20.0]}}
    study = _planes_study([0.0, 10.0, 20.0], per)
    half = _geometry((np.array([0.0, 0.0, 15.0]), np.array([0.0, 0.0, 1.0])))
    assert labelled_beyond_base_ml(study, half) == pytest.approx(3.0)
    assert labelled_beyond_base_ml(study, half, "lv_myocardium") == pytest.approx(0.5)
    m = np.array([0.4, 0.0, 1.0]) / np.linalg.norm([0.4, 0.0, 1.0])   # z = 12 - 0.4 x
    tilted = _geometry((np.array([0.0, 0.0, 12.0]), m))
    assert labelled_beyond_base_ml(study, tilted) == pytest.approx(1.0 + 2.0 * 3.0 / 10.0)
    study.landmarks.append(Landmark("aortic", 0, np.array([10.0, 0.0, 5.0])))
    assert labelled_beyond_base_ml(study, tilted) == 0.0
