"""Sunnybrook SC-HF-I-1, I-2, I-4 from ../shared/data: contours in scanner mm on their planes,
volumes checked against an independent computation straight from the files."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pydicom
import pytest

from cardionurbs import load_study
from cardionurbs.io import detect_format
from cardionurbs.geometry import polygon_area
from conftest import shared_data

pytestmark = pytest.mark.filterwarnings("ignore:Invalid value for VR UI")
SUBJECTS = ["SC-HF-I-1", "SC-HF-I-2", "SC-HF-I-4"]
NAME = re.compile(r"IM-\d+-(\d+)-([io])contour-manual\.txt")


@pytest.fixture(scope="module", params=SUBJECTS)
def loaded(request):
    folder = shared_data("sunnybrook", request.param)
    return folder, load_study(folder)


def _headers(folder: Path) -> dict[int, pydicom.Dataset]:
    out = {}
    for f in (folder / "dicom").glob("*.dcm"):
        ds = pydicom.dcmread(f, stop_before_pixels=True)
        out[int(ds.InstanceNumber)] = ds
    return out


def test_detected_as_sunnybrook(loaded):
    folder, study = loaded
    assert detect_format(folder) == "sunnybrook"
    assert study.meta["format"] == "sunnybrook"


def test_every_contour_point_on_its_image_plane(loaded):
    folder, study = loaded
    files = sorted(folder.glob("?-contours/*.txt"))
    assert len(study.contours) == len(files) > 0
    for c in study.contours:
        im = study.image(c.image)
        assert im.slice == c.slice and im.frame == c.frame and c.closed and c.view == "SA"
        assert np.abs(im.distance_to_plane(c.points)).max() < 1e-6


def test_points_are_the_file_pixels_mapped_by_the_dicom_header(loaded):
    """Independent of the package's geometry code: P = S + x*dc*X + y*dr*Y from pydicom."""
    folder, study = loaded
    headers = _headers(folder)
    by_key = {}
    for c in study.contours:
        by_key[(c.structure, study.image(c.image).meta["instance_number"])] = c
    for f in sorted(folder.glob("?-contours/*.txt")):
        inst, kind = NAME.match(f.name).groups()
        ds = headers[int(inst)]
        pix = np.loadtxt(f)
        S = np.array(ds.ImagePositionPatient, float)
        X, Y = np.array(ds.ImageOrientationPatient[:3], float), np.array(ds.ImageOrientationPatient[3:], float)
        X, Y = X / np.linalg.norm(X), Y / np.linalg.norm(Y)  # direction cosines are unit vectors
        dr, dc = (float(v) for v in ds.PixelSpacing)
        expected = S + pix[:, :1] * dc * X + pix[:, 1:] * dr * Y
        c = by_key[("lv_endo" if kind == "i" else "lv_epi", int(inst))]
        assert np.abs(c.points - expected).max() < 1e-6
        assert c.image == ds.SOPInstanceUID


def test_frames_follow_the_cardiac_phase(loaded):
    """Sunnybrook numbers images slice by slice, 20 phases each: frame = (InstanceNumber-1) % 20,
    whether the folder holds the whole cine (I-1) or only the contoured images (I-2, I-4)."""
    _, study = loaded
    for im in study.images:
        assert im.frame == (im.meta["instance_number"] - 1) % 20
    times = [study.frame_times_ms[f] for f in sorted(study.frame_times_ms)]
    assert np.all(np.diff(times) > 0)


def test_ed_es_labels_and_heart_rate(loaded):
    folder, study = loaded
    headers = _headers(folder)
    o_inst = [int(NAME.match(f.name).group(1)) for f in folder.glob("o-contours/*.txt")]
    i_inst = [int(NAME.match(f.name).group(1)) for f in folder.glob("i-contours/*.txt")]
    ed = {(n - 1) % 20 for n in o_inst}
    assert ed == {study.ed_frame}
    assert {(n - 1) % 20 for n in i_inst} == {study.ed_frame, study.es_frame}
    hr = np.mean([float(ds.HeartRate) for ds in headers.values()])
    assert study.heart_rate_bpm == pytest.approx(hr)
    assert any("lv_epi" in w and "ES" in w for w in study.warnings)  # o-contours at ED only


def test_slices_numbered_base_to_apex(loaded):
    """sa_00 is basal: the epicardial area shrinks towards the apex (last contoured slice)."""
    _, study = loaded
    epi = sorted((c.slice, polygon_area(c.points)) for c in study.contours
                 if c.structure == "lv_epi")
    assert epi[-1][1] < 0.5 * epi[0][1]


def test_edv_esv_match_independent_shoelace(loaded):
    """EDV/ESV by disk summation computed straight from the txt files and pydicom headers
    (shoelace area in pixels x pixel area x slice spacing) equal the study's contour areas
    x the reader's slice spacing (header values carry 6-7 digits: agreement to 1e-6)."""
    folder, study = loaded
    headers = _headers(folder)
    # independent slice spacing: distance between consecutive slice positions
    pos = np.unique([np.array(ds.ImagePositionPatient, float) for ds in headers.values()], axis=0)
    normal = np.cross(*np.array(next(iter(headers.values())).ImageOrientationPatient, float).reshape(2, 3))
    normal /= np.linalg.norm(normal)
    depth = np.sort(pos @ normal)
    spacing = float(np.median(np.diff(depth)))
    vols = {}
    for f in folder.glob("i-contours/*.txt"):
        inst = int(NAME.match(f.name).group(1))
        x, y = np.loadtxt(f).T
        area_px = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
        dr, dc = (float(v) for v in headers[inst].PixelSpacing)
        frame = (inst - 1) % 20
        vols[frame] = vols.get(frame, 0.0) + area_px * dr * dc * spacing / 1000.0
    ours = {}
    for c in study.contours:
        if c.structure == "lv_endo":
            ours[c.frame] = ours.get(c.frame, 0.0) + polygon_area(c.points) \
                * study.meta["slice_spacing_mm"] / 1000.0
    assert study.meta["slice_spacing_mm"] == pytest.approx(spacing, abs=1e-6)
    assert set(vols) == set(ours) == {study.ed_frame, study.es_frame}
    for f in vols:
        assert ours[f] == pytest.approx(vols[f], rel=1e-6)
    edv, esv = vols[study.ed_frame], vols[study.es_frame]
    assert 50 < esv < edv < 500  # mL, heart failure with infarction
