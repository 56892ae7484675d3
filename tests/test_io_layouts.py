"""Other datasets' layouts as they are distributed (issues 29 and 30, "real data we keep aside";
reports/layouts.md, benchmarks/layouts_matrix.py): each test builds the files and fails on the
reader as it was before the fix named in its docstring."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cardionurbs import load_study
from test_io_nifti_headers import PIXDIM, _rings, _scanner_affine, _write


def _la_affine(aff: np.ndarray, zooms=(1.5, 1.5, 8.0)) -> np.ndarray:
    """A long-axis plane through the SA stack of ``aff``: its y axis is the LA normal."""
    la = aff.copy()
    la[:3, 1], la[:3, 2] = aff[:3, 2] * zooms[1] / zooms[2], aff[:3, 1] * zooms[2] / zooms[1]
    return la


def _u_la(n: int = 40, heights=(12, 9)) -> np.ndarray:
    """(n, n, 1, frames) 4-chamber-like map: an LV cavity (1) with myocardium (2) on three
    sides, open towards the atrium; cavity length per frame from ``heights`` (px)."""
    out = np.zeros((n, n, 1, len(heights)), np.uint8)
    for t, h in enumerate(heights):
        out[10:30, 5:9 + h, 0, t] = 2
        out[14:26, 5:5 + h, 0, t] = 1
    return out


# ------------------------------------------------------------------ ACDC Info.cfg
def test_acdc_info_cfg_with_a_byte_order_mark_keeps_its_first_key(tmp_path):
    """Info.cfg saved with a UTF-8 BOM (Windows editors): ED was lost (the key read as
    '\\ufeffED'), silently replaced by the volume rule."""
    folder = tmp_path / "patient101"
    folder.mkdir()
    aff = np.diag([-1, -1, 1, 1.0])
    for f, r in ((1, 6.0), (5, 9.0), (9, 7.0)):          # the largest cavity is not ED
        _write(_rings(radii=[r])[..., 0], folder / f"patient101_frame{f:02d}_gt.nii.gz",
               sform=aff, scode=2, zooms=PIXDIM, units=None)
    (folder / "Info.cfg").write_bytes("\ufeffED: 1\r\nES: 9\r\nHeight: 170\r\nNbFrame: 9\r\n"
                                      "Weight: 70\r\n".encode())
    study = load_study(folder, labels="lv=1,myo=2,rv=3")
    assert (study.ed_frame, study.es_frame) == (0, 8)
    assert study.meta["ed_es_source"].startswith("ACDC Info.cfg")


# ------------------------------------------------------------------ UK Biobank long axis
def _ukbb_sa(folder: Path, *, pair: bool) -> np.ndarray:
    folder.mkdir(parents=True)
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    sa = _rings(slices=5, radii=[9.0, 6.0])
    if pair:
        _write(sa[..., 0], folder / "seg_sa_ED.nii.gz", sform=aff, qform=aff)
        _write(sa[..., 1], folder / "seg_sa_ES.nii.gz", sform=aff, qform=aff)
    else:
        _write(sa, folder / "seg_sa.nii.gz", sform=aff, qform=aff, units=None, dt=0.4)
    return aff


def test_ukbb_atrial_seg_la_4ch_is_left_out_not_read_as_ventricles(tmp_path):
    """ukbb_cardiac's seg_la_4ch labels 1 LA and 2 RA: those values are the ukbb preset's LV
    cavity and myocardium, and the atria were read as a ventricle."""
    folder = tmp_path / "ukbb"
    aff = _ukbb_sa(folder, pair=False)
    n = 40
    la = np.zeros((n, n, 1, 2), np.uint8)
    la[8:20, 10:30] = 1                                 # left atrium
    la[21:34, 10:30] = 2                                # right atrium, touching along one side
    la_aff = _la_affine(aff)
    la_aff[:3, 3] += aff[:3, 0] * 3.0                   # not through a slice centre
    _write(la, folder / "seg_la_4ch.nii.gz", sform=la_aff, qform=la_aff, units=None, dt=0.4)
    study = load_study(folder)
    assert not [c for c in study.contours if c.view == "LA"]
    left = [w for w in study.warnings if "seg_la_4ch" in w and "left out" in w]
    assert len(left) == 1 and "borders label 1" in left[0], study.warnings


def test_ukbb_ed_es_long_axis_pairs_are_used_beside_seg_sa_ed_es(tmp_path):
    """ukbb_cardiac writes seg4_la_4ch_ED/_ES beside seg_sa_ED/_ES: they were ignored."""
    folder = tmp_path / "ukbb"
    aff = _ukbb_sa(folder, pair=True)
    la, la_aff = _u_la(), _la_affine(aff)
    for t, ph in enumerate(("ED", "ES")):
        _write(la[..., t], folder / f"seg4_la_4ch_{ph}.nii.gz", sform=la_aff, qform=la_aff)
    study = load_study(folder)
    assert {"seg4_la_4ch_ED.nii.gz", "seg4_la_4ch_ES.nii.gz"} <= set(study.meta["label_files"])
    assert {c.frame for c in study.contours if c.view == "LA"} == {0, 1}


def test_ukbb_ed_es_long_axis_pairs_beside_a_cine_seg_sa_are_named(tmp_path):
    """Beside a 4-D seg_sa, LA maps only as _ED/_ES pairs (frames unnamed) were dropped silently."""
    folder = tmp_path / "ukbb"
    aff = _ukbb_sa(folder, pair=False)
    for t, ph in enumerate(("ED", "ES")):
        _write(_u_la()[..., t], folder / f"seg4_la_4ch_{ph}.nii.gz", sform=_la_affine(aff),
               qform=_la_affine(aff))
    study = load_study(folder)
    assert any("seg4_la_4ch_ED/_ES" in w and "left out" in w for w in study.warnings)


# ------------------------------------------------------------------ M&Ms-1 dataset table
def _mnms1(root: Path, code: str = "A1B2C3") -> Path:
    """OpenDataset/Training/Labeled/<code>/<code>_sa_gt.nii.gz, 6 frames, ED 1 and ES 4
    labelled, the dataset table at the dataset root, as the challenge ships it."""
    subj = root / "OpenDataset" / "Training" / "Labeled" / code
    subj.mkdir(parents=True)
    data = np.zeros((40, 40, 5, 6), np.uint8)
    data[..., 1] = _rings(slices=5, radii=[6.0])[..., 0]     # ED labelled smaller than ES:
    data[..., 4] = _rings(slices=5, radii=[9.0])[..., 0]     # only the table says which is which
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    _write(data, subj / f"{code}_sa_gt.nii.gz", sform=aff, qform=aff, dt=30.0)
    (root / "OpenDataset" / "211230_M&Ms_Dataset_information_diagnosis_opendataset.csv").write_text(
        ",External code,VendorName,Vendor,Centre,ED,ES,Age,Pathology,Sex,Height,Weight\n"
        f"0,ZZZZZZ,Siemens,A,1,0,9,50,NOR,M,170,70\n1,{code},Philips,B,2,1,4,61,HCM,F,165,60\n")
    return subj


def test_mnms1_dataset_table_at_the_dataset_root_is_read_with_allow_outside(tmp_path):
    """The table lies three folders above the subject: it was looked for one folder up only."""
    subj = _mnms1(tmp_path)
    study = load_study(subj, allow_outside=True)
    assert (study.ed_frame, study.es_frame) == (1, 4)
    assert study.meta["ed_es_source"].startswith("M&Ms CSV")


def test_mnms1_without_its_table_says_where_ed_and_es_come_from(tmp_path):
    """Without --allow-outside the table is not read: ED/ES came from the volumes, unsaid."""
    study = load_study(_mnms1(tmp_path))
    said = [w for w in study.warnings if "M&Ms dataset table" in w]
    assert len(said) == 1 and "--allow-outside" in said[0] and "frames 1, 4" in said[0]


@pytest.mark.parametrize("bom", [False, True])
def test_mnms1_table_beside_the_subject_with_or_without_a_byte_order_mark(tmp_path, bom):
    subj = _mnms1(tmp_path)
    table = (tmp_path / "OpenDataset").glob("*.csv").__next__()
    text = table.read_text().replace(",External code", "External code").replace("\n0,", "\n")
    text = text.replace("\n1,", "\n")
    (subj / "info.csv").write_bytes(("\ufeff" if bom else "").encode() + text.encode())
    table.unlink()
    study = load_study(subj)
    assert (study.ed_frame, study.es_frame) == (1, 4)


# ------------------------------------------------------------------ CAP / biv-me exports
def _cap_copy(dest: Path, frames=(0, 1), order=None) -> Path:
    """Two frames of bivme-patient1, the GPFile columns in ``order`` (named by the header)."""
    from conftest import shared_data
    src = shared_data("bivme-patient1")
    dest.mkdir()
    (dest / "SliceInfoFile.txt").write_bytes((src / "SliceInfoFile.txt").read_bytes())
    cols = ["x", "y", "z", "contour type", "frameID", "weight", "time frame"]
    for f in frames:
        lines = (src / f"GPFile_{f:03d}.txt").read_text().splitlines()
        rows = [ln.split("\t") for ln in lines[1:]]
        if order:
            rows = [[r[cols.index(c.replace("sliceID", "frameID"))] for c in order] for r in rows]
        head = "\t".join(order) if order else lines[0]
        (dest / f"GPFile_{f:03d}.txt").write_text("\n".join([head, *map("\t".join, rows)]) + "\n")
    return dest


def test_gpfile_columns_in_another_order_are_read_by_their_header_names(tmp_path):
    """biv-me reads the GPFile columns by name; another order was refused ("x is not a number")."""
    from cardionurbs.io import gpfile
    ref = load_study(_cap_copy(tmp_path / "ref"))
    order = ["contour type", "sliceID", "x", "y", "z", "weight", "time frame"]
    got = load_study(_cap_copy(tmp_path / "perm", order=order))
    assert len(got.contours) == len(ref.contours) and len(got.landmarks) == len(ref.landmarks)
    for a, b in zip(got.contours, ref.contours):
        assert (a.structure, a.view, a.slice, a.frame) == (b.structure, b.view, b.slice, b.frame)
        np.testing.assert_array_equal(a.points, b.points)
    gpfile.write_study(got, tmp_path / "back")          # written back in the order it was read
    for f in ("GPFile_000.txt", "GPFile_001.txt"):
        assert (tmp_path / "back" / f).read_bytes() == (tmp_path / "perm" / f).read_bytes()


# ------------------------------------------------------------------ a dataset's tree
def _acdc_patient(folder: Path, labels: bool = True) -> Path:
    folder.mkdir(parents=True)
    aff = np.diag([-1, -1, 1, 1.0])
    for f, r in ((1, 9.0), (5, 6.0)):
        data = _rings(radii=[r])[..., 0]
        if labels:
            _write(data, folder / f"{folder.name}_frame{f:02d}_gt.nii.gz", sform=aff, scode=2,
                   zooms=PIXDIM, units=None)
        _write(data.astype(np.int16) * 300, folder / f"{folder.name}_frame{f:02d}.nii.gz",
               sform=aff, scode=2, zooms=PIXDIM, units=None)
    (folder / "Info.cfg").write_text("ED: 1\nES: 5\nGroup: NOR\nHeight: 170\nNbFrame: 9\n"
                                     "Weight: 70\n")
    return folder


def test_cohort_over_a_dataset_tree_measures_the_patients_in_it(tmp_path):
    """`cardionurbs cohort database` (ACDC's training/ and testing/ trees) was one failed row,
    "cannot tell the study format"."""
    from cardionurbs.cohort import expand_folders
    from cardionurbs.io import studies_in
    db = tmp_path / "database"
    for split, name in (("training", "patient001"), ("training", "patient002"),
                        ("testing", "patient101")):
        _acdc_patient(db / split / name)
    _acdc_patient(db / "testing" / "patient102", labels=False)      # images only: not a study
    found = [p.name for p in studies_in(db)]
    assert found == ["patient101", "patient001", "patient002"]
    assert expand_folders([str(db / "training"), str(tmp_path / "nothing")]) == [
        str(db / "training" / "patient001"), str(db / "training" / "patient002"),
        str(tmp_path / "nothing")]


def test_a_folder_of_studies_or_of_images_only_is_refused_with_what_it_is(tmp_path, capsys):
    from cardionurbs.cli import main
    db = tmp_path / "training"
    _acdc_patient(db / "patient001")
    _acdc_patient(db / "patient002")
    _acdc_patient(tmp_path / "patient103", labels=False)
    assert main(["analyze", str(db), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a folder of 2 studies: patient001, patient002" in err[0]
    assert "cardionurbs cohort" in err[0]
    assert main(["analyze", str(tmp_path / "patient103"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ACDC patient folder without its label maps" in err[0]


def test_a_stray_label_value_is_refused_with_the_values_and_a_mapping_to_give(tmp_path):
    from cardionurbs import StudyError
    folder = _acdc_patient(tmp_path / "patient001")
    f = folder / "patient001_frame01_gt.nii.gz"
    data = _rings(radii=[9.0])[..., 0]
    data[0, 0, 0] = 4
    _write(data, f, sform=np.diag([-1, -1, 1, 1.0]), scode=2, zooms=PIXDIM, units=None)
    with pytest.raises(StudyError, match=r"label 4 is not in .*\(values present: 1, 2, 3, 4; .*"
                                         r"--labels, e\.g\. lv=3,myo=2,rv=1,ROLE=4 with ROLE one of rv_myo, la, ra"):
        load_study(folder)


@pytest.mark.parametrize("named", [".nii.gz", ".nii"])
def test_a_map_whose_name_and_compression_disagree_is_read_by_its_content(tmp_path, named):
    """A .nii.gz that is not gzipped (or a gzipped .nii) was refused ("not a gzip file")."""
    data = _rings(slices=5, radii=[9.0])[..., 0]
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    right = _write(data, tmp_path / ("right" + (".nii" if named == ".nii.gz" else ".nii.gz")),
                   sform=aff, qform=aff)
    wrong = tmp_path / ("seg" + named)
    wrong.write_bytes(right.read_bytes())               # the other form's bytes under this name
    a, b = load_study(right, labels="ukbb"), load_study(wrong, labels="ukbb")
    assert a.meta["voxel_volumes_ml"] == b.meta["voxel_volumes_ml"]
    assert [w for w in b.warnings if "gzip-compressed" in w and "read by its content" in w]


def test_seg_sa_alone_has_ukbb_cardiacs_ed_and_es_as_in_its_folder(tmp_path):
    """`analyze seg_sa.nii.gz` took ED from the volumes (frame 2 here), its folder frame 0."""
    radii = [8.0, 9.0, 10.0, 7.0, 6.0, 6.5, 7.5]              # largest at 2, smallest at 4
    folder = tmp_path / "ukbb"
    folder.mkdir()
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    _write(_rings(slices=5, radii=radii), folder / "seg_sa.nii.gz", sform=aff, qform=aff,
           units=None, dt=0.12)
    a, b = load_study(folder), load_study(folder / "seg_sa.nii.gz")
    assert (a.ed_frame, a.es_frame) == (b.ed_frame, b.es_frame) == (0, 4)
    assert b.meta["ed_es_given"] == ["ED", "ES"] and "ukbb_cardiac" in b.meta["ed_es_source"]
    assert a.meta["voxel_volumes_ml"] == b.meta["voxel_volumes_ml"]


def test_a_frame_missing_from_a_gpfile_series_is_named(tmp_path):
    """GPFile_001 absent between _000 and _002: the gap went unsaid."""
    folder = _cap_copy(tmp_path / "gap", frames=(0, 2, 3))
    study = load_study(folder)
    said = [w for w in study.warnings if "no GPFile for frame 1 " in w]
    assert len(said) == 1 and "GPFile_000.txt and GPFile_003.txt" in said[0]
    assert not [w for w in load_study(_cap_copy(tmp_path / "whole", frames=(0, 1, 2))).warnings
                if "no GPFile for" in w]


def test_an_export_without_valve_or_apex_points_says_how_base_and_apex_are_placed(tmp_path):
    """Without APEX_POINT/MITRAL_VALVE/TRICUSPID_VALVE the stack order came from the LPS
    prior and the bases from the slices, unsaid (LVEDV -15 % on bivme-patient1)."""
    folder = _cap_copy(tmp_path / "nolm", frames=(0, 1))
    for f in folder.glob("GPFile_*.txt"):
        lines = f.read_text().splitlines()
        f.write_text("\n".join([lines[0]] + [ln for ln in lines[1:]
                                             if ln.split("\t")[3].startswith(("SAX_", "LAX_"))]) + "\n")
    said = [w for w in load_study(folder).warnings if "guide points" in w]
    assert len(said) == 3 and "LPS prior" in said[0]
    assert "MITRAL_VALVE" in said[1] and "TRICUSPID_VALVE" in said[2]
    assert not [w for w in load_study(_cap_copy(tmp_path / "all")).warnings if "guide points" in w]
