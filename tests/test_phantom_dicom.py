"""Synthetic tagged DICOM of the phantom: readable, geometry exact, tags fade, reproducible."""

from __future__ import annotations

import numpy as np
import pydicom
import pytest

from cardionurbs.io.native import read_study
from cardionurbs.phantom import generate, write_phantom


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("ph") / "phtn_003"
    ph = generate("phtn", seed=3, frames=3, volume_check=False)
    write_phantom(ph, out, dicom=True)
    return ph, out


def _plane_from_dicom(ds):
    ipp = np.array(ds.ImagePositionPatient, float)
    iop = np.array(ds.ImageOrientationPatient, float)
    ps = np.array(ds.PixelSpacing, float)
    return ipp, iop[:3], iop[3:], ps


def test_every_dicom_reads_back_with_exact_geometry(written):
    ph, out = written
    st = read_study(out)
    files = sorted((out / "dicom").rglob("*.dcm"))
    assert len(files) == len(st.images)
    series = {}
    by_id = {im.id: im for im in st.images}
    dsets = {}
    for f in files:
        ds = pydicom.dcmread(f)
        assert ds.PhotometricInterpretation == "MONOCHROME2" and ds.BitsAllocated == 16
        assert ds.pixel_array.shape == (256, 256) and ds.pixel_array.dtype == np.uint16
        assert float(ds.SliceThickness) == 8.0 and int(ds.CardiacNumberOfImages) == 3
        assert float(ds.HeartRate) > 0 and float(ds.NominalInterval) > 0
        im = by_id[ds.SOPInstanceUID]
        assert (out / im.file).resolve() == f.resolve()
        assert float(ds.TriggerTime) == pytest.approx(im.trigger_time, abs=1e-6)
        series.setdefault(ds.SeriesInstanceUID, set()).add(im.slice[:3] if im.view == "SA" else im.slice)
        dsets[im.id] = ds
    assert sorted(map(sorted, series.values())) == [["la_2ch"], ["la_3ch"], ["la_4ch"], ["sa_"]]
    # each contour point lies on the plane of the DICOM it references, and the DICOM
    # pixel -> scanner mapping reproduces it
    for c in [*st.contours, *st.tags]:
        ipp, row, col, ps = _plane_from_dicom(dsets[c.image])
        n = np.cross(row, col)
        assert np.abs((c.points - ipp) @ n).max() < 1e-6
        pix = np.column_stack([(c.points - ipp) @ row / ps[1], (c.points - ipp) @ col / ps[0]])
        back = ipp + pix[:, :1] * ps[1] * row + pix[:, 1:] * ps[0] * col
        assert np.abs(back - c.points).max() < 1e-6


def test_image_contrast_and_tag_fading(written):
    ph, out = written
    st = read_study(out)
    ed = [im for im in st.images if im.slice == "sa_03" and im.frame == 0][0]
    late = [im for im in st.images if im.slice == "sa_03" and im.frame == 2][0]
    a0 = pydicom.dcmread(out / ed.file).pixel_array.astype(float)
    a2 = pydicom.dcmread(out / late.file).pixel_array.astype(float)
    endo = [c for c in st.contours_at(0, "lv_endo") if c.slice == "sa_03"][0]
    cen = np.round(ed.scanner_to_pixel(endo.points.mean(axis=0))[0]).astype(int)
    blood = a0[cen[1] - 2:cen[1] + 3, cen[0] - 2:cen[0] + 3].mean()
    assert blood > 2.0 * np.median(a0)          # bright blood pool
    # tag modulation: dark tag lines across the LV wall at ED, fading later in the cycle
    from matplotlib.path import Path as MplPath

    def wall_pixels(img, im, frame):
        cs = {c.structure: c for c in st.contours_at(frame, view="SA") if c.slice == "sa_03"}
        cc, rr = np.meshgrid(np.arange(256), np.arange(256))
        xy = np.column_stack([cc.ravel(), rr.ravel()])
        inside = MplPath(im.scanner_to_pixel(cs["lv_epi"].points)).contains_points(xy, radius=-1.5)
        cavity = MplPath(im.scanner_to_pixel(cs["lv_endo"].points)).contains_points(xy, radius=1.5)
        return img.ravel()[inside & ~cavity]

    w0, w2 = wall_pixels(a0, ed, 0), wall_pixels(a2, late, 2)
    assert np.percentile(w0, 10) < 0.5 * np.percentile(w0, 90)      # deep tag lines at ED
    assert w0.std() / w0.mean() > 1.3 * (w2.std() / w2.mean())       # faded later


def test_dicom_output_is_byte_identical(tmp_path, written):
    ph, out = written
    write_phantom(generate("phtn", seed=3, frames=3, volume_check=False), tmp_path / "again", dicom=True)
    a = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    b = sorted(p.relative_to(tmp_path / "again") for p in (tmp_path / "again").rglob("*") if p.is_file())
    assert a == b
    for rel in a:
        assert (out / rel).read_bytes() == (tmp_path / "again" / rel).read_bytes(), rel


def test_snr_sets_rician_noise_deterministically():
    """--snr S: channel noise σ = 0.3 / S on the magnitude image (Rician), seeded; the truth
    records it and the expected tag planes are in the study."""
    from cardionurbs.phantom.dicom import LUNG, MYO, render_image
    ph = generate("normal", seed=1, frames=2, volume_check=False, snr=10.0)
    assert ph.truth["imaging"]["snr"] == 10.0
    assert ph.truth["imaging"]["noise_sigma"] == pytest.approx(MYO / 10.0)
    im = [p for p in ph.study.images if p.slice == "sa_02" and p.frame == 0][0]
    clean = render_image(ph, im)
    a = render_image(ph, im, np.random.default_rng(5))
    b = render_image(ph, im, np.random.default_rng(5))
    assert np.array_equal(a, b)
    lung = clean == LUNG                 # untagged lung background, signal A = 0.03
    assert lung.sum() > 10000
    bg = a[lung]
    sigma = MYO / 10.0
    assert bg.min() >= 0
    # second moment of a Rician variable: A^2 + 2 sigma^2
    assert np.mean(bg ** 2) == pytest.approx(LUNG ** 2 + 2 * sigma ** 2, rel=0.05)
    planes = ph.study.meta["tag_planes"]
    assert set(planes) == {"sa1", "sa2", "la"}
    n1, n2 = np.array(planes["sa1"]["normal"]), np.array(planes["sa2"]["normal"])
    assert abs(n1 @ n2) < 1e-12 and planes["la"]["spacing_mm"] == pytest.approx(7 * 300 / 256)
    # every true tag line lies on its plane: normal . x = index0 + index * spacing at ED
    for t in ph.study.tags_at(0):
        p = planes[t.family]
        pos = t.points @ np.array(p["normal"])
        assert np.abs(pos - p["index0_mm"] - t.index * p["spacing_mm"]).max() < 1e-6


def test_snr_must_be_positive():
    from cardionurbs.errors import PhantomError
    with pytest.raises(PhantomError, match="snr"):
        generate("normal", frames=2, snr=0.0, volume_check=False)
