"""CAP / biv-me GPFiles: bivme-patient1 loads with every contour type and landmark; written
GPFiles read back equal (byte-identical when unchanged)."""

from __future__ import annotations

import filecmp

import numpy as np
import pandas as pd
import pytest

from broken.corpus import synthetic_study
from cardionurbs import load_study
from cardionurbs.io import detect_format, gpfile, native
from conftest import shared_data

TYPES = {"LV_ENDOCARDIAL": "lv_endo", "LV_EPICARDIAL": "lv_epi", "RV_FREEWALL": "rv_freewall",
         "RV_SEPTUM": "rv_septum", "RV_EPICARDIAL": "rv_epi"}
LANDMARKS = {"MITRAL_VALVE": "mitral", "TRICUSPID_VALVE": "tricuspid", "AORTA_VALVE": "aortic",
             "PULMONARY_VALVE": "pulmonary", "APEX_POINT": "apex", "RV_INSERT": "rv_insert"}


@pytest.fixture(scope="module")
def bivme():
    folder = shared_data("bivme-patient1")
    return folder, load_study(folder)


def _file_table(folder, frame):
    return pd.read_csv(folder / f"GPFile_{frame:03d}.txt", sep="\t")


def _study_points(study, frame):
    """(type name as the file spells it, points) blocks of one frame, in file order."""
    blocks = study.meta["gpfile"]["frames"][str(frame)]["blocks"]
    out = []
    for b in blocks:
        if b[0] == "c":
            out.append((b[2], study.contours[b[1]].points))
        else:
            out.append((b[3], np.array([lm.point for lm in study.landmarks[b[1]:b[1] + b[2]]])))
    return out


def test_all_frames_contour_types_and_landmarks(bivme):
    folder, study = bivme
    assert detect_format(folder) == "gpfile"
    assert study.frames == list(range(25))
    kinds = {(c.structure, c.view) for c in study.contours}
    assert kinds == {(s, v) for s in TYPES.values() for v in ("SA", "LA")}
    assert {lm.name for lm in study.landmarks} == set(LANDMARKS.values())
    for f in study.frames:
        assert {lm.name for lm in study.landmarks_at(f)} == set(LANDMARKS.values())
        assert len(study.landmarks_at(f, "apex")) == 1


def test_points_types_and_order_as_in_the_files(bivme):
    """Every line of every GPFile, read independently with pandas, is in the study in order."""
    folder, study = bivme
    for f in (0, 12, 24):
        t = _file_table(folder, f)
        blocks = _study_points(study, f)
        pts = np.concatenate([p for _, p in blocks])
        names = np.concatenate([[n] * len(p) for n, p in blocks])
        assert np.array_equal(pts, t[["x", "y", "z"]].to_numpy(float))
        assert list(names) == list(t["contour type"])
    for c in study.contours:
        # SA LV traces are loops; an SA RV epicardial trace is closed where it closes on
        # itself (one apical loop of this patient), open otherwise (the CAP free-wall arc)
        assert c.closed == (c.view == "SA" and (c.structure in ("lv_endo", "lv_epi")
                                                or (c.structure == "rv_epi"
                                                    and gpfile.is_loop(c.points))))
        im = study.image(c.image)
        assert (im.slice, im.frame, im.view) == (c.slice, c.frame, c.view)
        assert np.abs(im.distance_to_plane(c.points)).max() < 1e-4  # file has 5 decimals


def test_slices_named_from_slice_info(bivme):
    """SA = the 6 parallel slices, sa_00 at the base (farthest from the apex point), LA = la_<id>."""
    _, study = bivme
    slices = {s["slice"]: s["id"] for s in study.meta["gpfile"]["slices"]}
    assert slices == {**{f"sa_{k:02d}": k + 1 for k in range(6)},
                      **{f"la_{i}": i for i in range(7, 12)}}
    apex = np.mean([lm.point for lm in study.landmarks if lm.name == "apex"], axis=0)
    d = [np.linalg.norm(study.slice_plane(f"sa_{k:02d}", 0).center - apex) for k in range(6)]
    # distance to the apex along the stack normal decreases base -> apex
    n = study.slice_plane("sa_00", 0).normal
    along = [abs((study.slice_plane(f"sa_{k:02d}", 0).position - apex) @ n) for k in range(6)]
    assert np.all(np.diff(along) < 0) and d[0] > d[-1]
    assert study.meta["base_apex_rule"] == "apex landmark"


def test_written_gpfiles_are_byte_identical(bivme, tmp_path):
    folder, study = bivme
    gpfile.write_study(study, tmp_path)
    names = sorted(p.name for p in folder.glob("*.txt") if p.name.startswith(("GPFile", "Slice")))
    assert sorted(p.name for p in tmp_path.iterdir()) == names
    for name in names:
        assert filecmp.cmp(folder / name, tmp_path / name, shallow=False), name


def _assert_equal_studies(a, b):
    assert a.frames == b.frames and len(a.contours) == len(b.contours)
    for x, y in zip(a.contours, b.contours):
        assert (x.structure, x.view, x.slice, x.frame, x.closed, x.index, x.image) == \
               (y.structure, y.view, y.slice, y.frame, y.closed, y.index, y.image)
        assert np.array_equal(x.points, y.points)
    assert len(a.landmarks) == len(b.landmarks)
    for x, y in zip(a.landmarks, b.landmarks):
        assert (x.name, x.frame, x.index, x.slice, x.image) == (y.name, y.frame, y.index, y.slice, y.image)
        assert np.array_equal(x.point, y.point)
    for x, y in zip(a.images, b.images):
        assert x.id == y.id and x.same_geometry(y, tol=1e-12)


def test_written_gpfiles_read_back_equal_without_provenance(bivme, tmp_path):
    """Without the meta that makes write-back exact, the study still reads back equal."""
    _, study = bivme
    bare = type(study)(subject=study.subject, images=study.images, contours=study.contours,
                       landmarks=study.landmarks)
    gpfile.write_study(bare, tmp_path)
    _assert_equal_studies(study, load_study(tmp_path))


def test_gpfile_to_native_and_back_is_exact(bivme, tmp_path):
    folder, study = bivme
    native.write_study(study, tmp_path / "native", decimals=None)   # lossless (17 digits)
    again = load_study(tmp_path / "native")
    _assert_equal_studies(study, again)
    gpfile.write_study(again, tmp_path / "gp")
    assert filecmp.cmp(folder / "GPFile_007.txt", tmp_path / "gp" / "GPFile_007.txt", shallow=False)


def test_synthetic_study_round_trip(tmp_path):
    s = synthetic_study()
    gpfile.write_study(s, tmp_path)
    r = load_study(tmp_path)
    assert {c.structure for c in r.contours} == {c.structure for c in s.contours}
    assert sorted({im.slice for im in r.images}) == ["la_4ch", "sa_00", "sa_01", "sa_02"]
    for a, b in zip(s.contours, r.contours):
        assert np.array_equal(a.points, b.points) and a.structure == b.structure


def test_rv_endo_written_as_septum_and_free_wall(tmp_path):
    """A closed rv_endo crescent becomes RV_SEPTUM (the run on the LV epicardium) + RV_FREEWALL."""
    s = synthetic_study()
    s.contours = [c for c in s.contours if c.structure not in ("rv_septum", "rv_freewall")]
    from broken.corpus import circle_pixels
    for im in [im for im in s.images if im.view == "SA"]:
        epi = next(c for c in s.contours_at(im.frame, "lv_epi") if c.slice == im.slice)
        r_epi = np.linalg.norm(im.scanner_to_pixel(epi.points)[0] - [16, 15])
        sept = circle_pixels(radius=r_epi, n=24)[[22, 23, 0, 1, 2]]      # on the epicardium
        free = np.array([[16 + r_epi * 0.5 + 9 * np.cos(t), 15 + 9 * np.sin(t) * 1.2]
                         for t in np.linspace(1.2, -1.2, 9)])[::-1]
        s.contours.append(type(epi)("rv_endo", "SA", im.slice, im.frame,
                                    im.pixel_to_scanner(np.r_[sept, free]), image=im.id))
    gpfile.write_study(s, tmp_path)
    r = load_study(tmp_path)
    for c in (c for c in s.contours if c.structure == "rv_endo"):
        parts = [p for p in r.contours if p.slice == c.slice and p.frame == c.frame
                 and p.structure in ("rv_septum", "rv_freewall")]
        assert {p.structure for p in parts} == {"rv_septum", "rv_freewall"}
        sept = next(p for p in parts if p.structure == "rv_septum")
        assert len(sept.points) == 5
        assert np.array_equal(np.sort(np.concatenate([p.points for p in parts]), axis=0),
                              np.sort(c.points, axis=0))
