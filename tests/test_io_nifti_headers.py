"""NIfTI headers as the real datasets write them: sform vs qform vs pixdim, the time step and
its unit, ED/ES from the layout, M&Ms-2 names, single-file studies (issue 29, reader side).

Every file is built by the test; what the reader must find is known from how it was built."""

from __future__ import annotations

import json
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

from cardionurbs import load_study
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.cli import main
from cardionurbs.io import nifti

PIXDIM = (1.5, 1.25, 10.0)          # ACDC-like: in-plane 1.25-1.8 mm, 5-10 mm between slices


def _rings(n: int = 40, slices: int = 5, radii=(8.0,)) -> np.ndarray:
    """(n, n, slices, frames) ukbb-convention map: LV cavity disc (1), myocardium ring (2),
    an RV crescent (3) on one side; LV radius per frame from ``radii`` (px)."""
    yy, xx = np.mgrid[:n, :n]
    c = n / 2
    out = np.zeros((n, n, slices, len(radii)), np.uint8)
    for t, r in enumerate(radii):
        d = np.hypot(xx - c, yy - c)
        sl = np.zeros((n, n), np.uint8)
        sl[d < r + 4] = 2
        sl[d < r] = 1
        rv = (np.hypot(xx - c - r - 7, yy - c) < 6) & (sl == 0)
        sl[rv] = 3
        out[..., t] = sl[..., None]
    return out


def _write(data: np.ndarray, path: Path, *, sform=None, scode=1, qform=None, qcode=1,
           zooms=None, units=("mm", "msec"), dt=None) -> Path:
    img = nib.Nifti1Image(data, None)
    if qform is not None:
        img.set_qform(qform, code=qcode)
    else:
        img.set_qform(None, code=0)
    if zooms is not None:
        img.header.set_zooms(tuple(zooms) + ((dt,) if data.ndim == 4 else ()))
    elif data.ndim == 4 and dt is not None:
        z = list(img.header.get_zooms())
        z[3] = dt
        img.header.set_zooms(z)
    if sform is not None:
        img.set_sform(sform, code=scode)
    else:
        img.set_sform(None, code=0)
    img.header.set_xyzt_units(*units) if units else img.header.__setitem__("xyzt_units", 0)
    nib.save(img, str(path))
    return path


def _rot(deg: float) -> np.ndarray:
    a = np.radians(deg)
    r = np.eye(4)
    r[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return r


def _scanner_affine(zooms=PIXDIM, deg=30.0, origin=(12.0, -40.0, 7.0)) -> np.ndarray:
    a = _rot(deg) @ np.diag([*zooms, 1.0])
    a[:3, 3] = origin
    return a


# ------------------------------------------------------------------ item 1: geometry
def test_acdc_unit_sform_measures_with_pixdim_and_says_so(tmp_path):
    """ACDC as distributed: sform code 2 with unit scale, qform code 0, the spacing in pixdim."""
    p = _write(_rings()[..., 0], tmp_path / "patient001_frame01_gt.nii.gz", sform=np.diag([-1, -1, 1, 1.0]),
               scode=2, zooms=PIXDIM, units=None)
    vol = nifti.read_label_volume(p)
    assert np.allclose(np.linalg.norm(vol.affine[:3, :3], axis=0), PIXDIM)
    assert vol.voxel_ml == pytest.approx(np.prod(PIXDIM) / 1000)
    (w,) = [w for w in vol.warnings if "pixdim" in w]
    assert str(p) in w and "1 x 1 x 1 mm" in w and "1.5 x 1.25 x 10 mm" in w
    assert vol.header["orientation"] == "placeholder" and vol.header["sform_code"] == 2
    study = load_study(p, labels="ukbb")
    sa = sorted((im for im in study.images if im.frame == 0), key=lambda im: im.slice)
    assert np.allclose(sa[0].pixel_spacing, (1.25, 1.5))
    gaps = np.diff(sorted(im.position[2] for im in sa))
    assert np.allclose(gaps, 10.0)
    lv = study.meta["voxel_volumes_ml"][0]["lv_cavity"]
    assert lv == pytest.approx((_rings()[..., 0, 0] == 1).sum() * 5 * np.prod(PIXDIM) / 1000)


def test_qform_only_file_has_the_geometry_of_the_same_sform_file(tmp_path):
    aff = _scanner_affine()
    a = nifti.read_label_volume(_write(_rings()[..., 0], tmp_path / "q.nii.gz", qform=aff, qcode=1))
    b = nifti.read_label_volume(_write(_rings()[..., 0], tmp_path / "s.nii.gz", sform=aff, qform=aff))
    assert np.allclose(a.affine, b.affine, atol=1e-4)
    assert np.allclose(a.affine[:3, 3], [-12.0, 40.0, 7.0], atol=1e-4)     # RAS -> LPS
    assert not [w for w in a.warnings + b.warnings if "disagree" in w]


@pytest.mark.parametrize("deg,shift", [(90.0, 0.0), (0.0, 25.0)])
def test_sform_and_qform_disagreeing_give_one_warning_and_the_sform(tmp_path, deg, shift):
    s = _scanner_affine()
    q = _scanner_affine(deg=30.0 + deg, origin=(12.0 + shift, -40.0, 7.0))
    p = _write(_rings()[..., 0], tmp_path / "x.nii.gz", sform=s, qform=q)
    vol = nifti.read_label_volume(p)
    assert np.allclose(vol.affine, nifti.RAS_TO_LPS @ s, atol=1e-4)
    (w,) = [w for w in vol.warnings if "disagree" in w]
    assert str(p) in w and "sform" in w and "qform" in w


def test_unit_voxels_everywhere_are_named(tmp_path):
    aff = _scanner_affine(zooms=(1.0, 1.0, 1.0))
    vol = nifti.read_label_volume(_write(_rings()[..., 0], tmp_path / "u.nii.gz", sform=aff, qform=aff))
    assert any("1 x 1 x 1 mm" in w and "no real spacing" in w for w in vol.warnings)


# ------------------------------------------------------------------ item 1: time step
@pytest.mark.parametrize("units,pixdim4,frames,dt_ms,says", [
    (("mm", "sec"), 0.02, 40, 20.0, None),
    (("mm", "msec"), 20.0, 40, 20.0, None),
    (("mm", "usec"), 20000.0, 40, 20.0, None),
    (None, 0.0173, 50, 17.3, "read as sec"),              # UK Biobank: seconds, unit unknown
    (None, 17.3, 50, 17.3, "read as msec"),
    (("mm", "msec"), 0.0173, 50, 0.0173, "implausible time axis"),   # declared unit honoured
    (None, 1e-5, 50, None, "implausible time axis"),
    (("mm", "msec"), 0.0, 10, None, "no frame interval"),
])
def test_time_step_honours_the_unit_or_finds_a_cardiac_cycle(tmp_path, units, pixdim4, frames,
                                                               dt_ms, says):
    data = _rings(n=24, slices=2, radii=np.linspace(6, 8, frames))
    p = _write(data, tmp_path / "t.nii.gz", sform=_scanner_affine(), qform=_scanner_affine(),
               units=units, dt=pixdim4)
    vol = nifti.read_label_volume(p)
    if dt_ms is None:
        assert vol.dt_ms is None
    else:
        assert vol.dt_ms == pytest.approx(dt_ms, rel=1e-5)
    said = [w for w in vol.warnings if "frame interval" in w or "time axis" in w]
    if says is None:
        assert not said
    else:
        assert len(said) == 1 and says in said[0] and str(p) in said[0]
    assert vol.header["time"]["plausible"] is (says is None or "read as" in says)


def test_implausible_time_axis_reaches_metrics_json_and_qc(tmp_path, monkeypatch):
    data = _rings(n=40, slices=5, radii=[10, 9.5, 8.5, 7.5, 7, 7.5, 8.5, 9, 9.5, 9.8])
    p = _write(data, tmp_path / "seg.nii.gz", sform=_scanner_affine(zooms=(1.5, 1.5, 8.0)),
               qform=_scanner_affine(zooms=(1.5, 1.5, 8.0)), units=("mm", "msec"), dt=0.02)
    monkeypatch.chdir(tmp_path)
    assert main(["analyze", "seg.nii.gz", "--out", "results", "--outputs", "metrics",
                 "--labels", "ukbb"]) == 0                      # --out beside the file: allowed
    m = json.loads((tmp_path / "results" / "metrics.json").read_text())
    assert "implausible time axis" in m["QC"]
    assert "implausible time axis" in m["quality"]["metrics"]["PER (mL/s)"]["flags"]
    assert "implausible time axis (seg.nii.gz: 0.02 per frame, unit msec)" in m["notes"]["PER (mL/s)"]
    assert m["metrics"]["LVEDV (mL)"] > 0


# ------------------------------------------------------------------ item 2: ED/ES of the layout
def test_ukbb_ed_is_frame_0_and_es_the_smallest_cavity_whatever_the_volumes(tmp_path):
    """ukbb_cardiac's definition wins even where another frame is larger than frame 0."""
    radii = [8.0, 9.0, 10.0, 7.0, 6.0, 6.5, 7.5]              # largest at 2, smallest at 4
    folder = tmp_path / "ukbb"
    folder.mkdir()
    _write(_rings(slices=5, radii=radii), folder / "seg_sa.nii.gz",
           sform=_scanner_affine(zooms=(1.5, 1.5, 8.0)), qform=_scanner_affine(zooms=(1.5, 1.5, 8.0)),
           units=None, dt=0.12)
    study = load_study(folder)
    assert (study.ed_frame, study.es_frame) == (0, 4)
    assert "smallest LV cavity" in study.meta["ed_es_source"]
    assert study.frame_times_ms[1] == pytest.approx(120.0)
    model = reconstruct(study)
    assert (model.ed_frame, model.es_frame) == (0, 4)
    given = load_study(folder, ed_frame=1)            # one frame given: the other from the layout
    assert (given.ed_frame, given.es_frame) == (1, 4)


def test_acdc_info_cfg_is_honoured_over_the_volumes(tmp_path):
    folder = tmp_path / "patient001"
    folder.mkdir()
    aff = np.diag([-1, -1, 1, 1.0])
    for f, r in ((1, 6.0), (5, 9.0), (9, 7.0)):          # the largest cavity is not ED
        _write(_rings(radii=[r])[..., 0], folder / f"patient001_frame{f:02d}_gt.nii.gz",
               sform=aff, scode=2, zooms=PIXDIM, units=None)
    (folder / "Info.cfg").write_text("ED: 1\nES: 9\nGroup: NOR\nHeight: 170\nWeight: 70\n")
    study = load_study(folder, labels="lv=1,myo=2,rv=3")
    assert (study.ed_frame, study.es_frame) == (0, 8)
    assert study.meta["ed_es_source"].startswith("ACDC Info.cfg")
    assert (reconstruct(study).ed_frame, reconstruct(study).es_frame) == (0, 8)


# ------------------------------------------------------------------ items 4-5: M&Ms-2, single files
def _mnms2(folder: Path, code: str = "001", la: bool = True) -> Path:
    folder.mkdir(parents=True)
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    for phase, r in (("ED", 9.0), ("ES", 6.0)):
        data = _rings(slices=5, radii=[r])[..., 0]
        _write(data, folder / f"{code}_SA_{phase}_gt.nii.gz", sform=aff, qform=aff)
        _write(data, folder / f"{code}_SA_{phase}.nii.gz", sform=aff, qform=aff)
        if la:
            la_aff = aff.copy()                     # the SA stack's y axis is the LA normal
            la_aff[:3, 1], la_aff[:3, 2] = aff[:3, 2] * 1.5 / 8.0, aff[:3, 1] * 8.0 / 1.5
            _write(data[:, :, 2:3], folder / f"{code}_LA_{phase}_gt.nii.gz", sform=la_aff, qform=la_aff)
    return folder


def test_mnms2_layout_reads_sa_ed_es_with_its_preset(tmp_path):
    folder = _mnms2(tmp_path / "001")
    assert nifti.detect(folder) == "mnms2"
    study = load_study(folder)
    assert study.meta["layout"] == "mnms2" and study.meta["labels"].startswith("mnms (lv=1, myo=2, rv=3")
    assert (study.ed_frame, study.es_frame) == (0, 1)
    assert sorted(study.meta["image_files"]) == ["001_SA_ED.nii.gz", "001_SA_ES.nii.gz"]
    assert "001_LA_ED_gt.nii.gz" in study.meta["label_files"]
    v = study.meta["voxel_volumes_ml"]
    one = 1.5 * 1.5 * 8.0 / 1000
    assert v[0]["lv_cavity"] == pytest.approx((_rings(radii=[9.0])[..., 0, 0] == 1).sum() * 5 * one)
    assert v[1]["lv_cavity"] == pytest.approx((_rings(radii=[6.0])[..., 0, 0] == 1).sum() * 5 * one)


def test_mnms2_refuses_two_subjects_in_one_folder(tmp_path, capsys):
    folder = _mnms2(tmp_path / "x", "001", la=False)
    for ph in ("ED", "ES"):
        (folder / f"002_SA_{ph}_gt.nii.gz").write_bytes((folder / f"001_SA_{ph}_gt.nii.gz").read_bytes())
    assert main(["analyze", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "one subject" in err[0] and "001, 002" in err[0]
    assert not (tmp_path / "o").exists()


def test_single_file_with_ed_es_frames_is_read_like_its_layout(tmp_path):
    """An M&Ms 4-D map alone with --ed-frame/--es-frame = the same map in its folder + CSV."""
    folder = tmp_path / "A1B2"
    folder.mkdir()
    radii = [9.0, 0, 0, 6.0, 0]
    data = _rings(slices=4, radii=[r or 5 for r in radii])
    data[..., [1, 2, 4]] = 0
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    _write(data, folder / "A1B2_sa_gt.nii.gz", sform=aff, qform=aff, dt=30.0)
    (folder / "info.csv").write_text("External code,ED,ES\nA1B2,0,3\n")
    a = load_study(folder)
    b = load_study(folder / "A1B2_sa_gt.nii.gz", labels="mnms", ed_frame=0, es_frame=3)
    assert (a.ed_frame, a.es_frame) == (b.ed_frame, b.es_frame) == (0, 3)
    assert a.meta["voxel_volumes_ml"] == b.meta["voxel_volumes_ml"]
    assert len(a.contours) == len(b.contours)
    assert a.frame_times_ms == b.frame_times_ms == {0: 0.0, 3: 90.0}


def test_single_3d_map_gives_null_ef_with_the_reason(tmp_path, monkeypatch):
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    _write(_rings(slices=5)[..., 0], tmp_path / "seg.nii.gz", sform=aff, qform=aff)
    monkeypatch.chdir(tmp_path)
    for extra, out in (([], "alone"), (["--ed-frame", "0", "--es-frame", "0"], "given")):
        assert main(["analyze", "seg.nii.gz", "--out", out, "--outputs", "metrics",
                     "--labels", "ukbb", *extra]) == 0
        m = json.loads((tmp_path / out / "metrics.json").read_text())
        for col in ("LVSV (mL)", "LVEF (%)", "RVEF (%)"):
            assert m["metrics"][col] is None, (out, col)
        assert m["metrics"]["LVEDV (mL)"] > 0
        assert any("ED = ES" in str(w) for w in m["warnings"])       # the model says why


@pytest.mark.parametrize("out", ["seg.nii.gz", ".", ".."])
def test_single_file_study_still_refuses_an_output_that_is_or_holds_it(tmp_path, monkeypatch,
                                                                        capsys, out):
    aff = _scanner_affine(zooms=(1.5, 1.5, 8.0))
    (tmp_path / "d").mkdir()
    seg = _write(_rings(slices=5)[..., 0], tmp_path / "d" / "seg.nii.gz", sform=aff, qform=aff)
    before = seg.read_bytes()
    monkeypatch.chdir(tmp_path / "d")
    assert main(["analyze", "seg.nii.gz", "--out", out, "--outputs", "metrics"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]
    assert seg.read_bytes() == before and sorted(q.name for q in (tmp_path / "d").iterdir()) == ["seg.nii.gz"]
