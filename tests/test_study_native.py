"""The Study model and the native format: geometry, round trip, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs import Contour, Landmark, Study, StudyError, TagLine, load_study
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import native


def _oblique_plane(slice_id="sa_00", frame=0, offset=0.0):
    a, b = np.deg2rad(30), np.deg2rad(20)
    row = np.array([np.cos(a), np.sin(a), 0.0])
    col = np.array([-np.sin(a) * np.cos(b), np.cos(a) * np.cos(b), np.sin(b)])
    n = np.cross(row, col)
    return ImagePlane(id=f"{slice_id}_f{frame}", slice=slice_id, view="SA", frame=frame,
                      position=np.array([-150.0, -140.0, 30.0]) + offset * n,
                      row_cosine=row, column_cosine=col, pixel_spacing=(1.171875, 1.171875),
                      thickness=8.0)


def _study():
    planes = [_oblique_plane(f"sa_{k:02d}", f, 10.0 * k) for k in range(3) for f in range(2)]
    contours, tags = [], []
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    for im in planes:
        pix = np.column_stack([128 + 20 * np.cos(t), 120 + 25 * np.sin(t)])
        contours.append(Contour("lv_endo", "SA", im.slice, im.frame, im.pixel_to_scanner(pix),
                                image=im.id))
        tags.append(TagLine("sa1", 3, "SA", im.slice, im.frame,
                            im.pixel_to_scanner(np.column_stack([np.full(9, 100.3), np.arange(9) + 110.1])),
                            image=im.id))
    lms = [Landmark("apex", 0, [1.0, 2.0, 3.0]), Landmark("mitral", 0, [4, 5, 6], index=0),
           Landmark("mitral", 0, [7, 8, 9], index=1)]
    return Study("s1", images=planes, contours=contours, tags=tags, landmarks=lms,
                 frame_times_ms={0: 0.0, 1: 350.5}, heart_rate_bpm=62.0, ed_frame=0, es_frame=1)


def test_pixel_scanner_round_trip_and_plane_distance():
    im = _oblique_plane(offset=5.0)
    pix = np.random.default_rng(0).uniform(0, 255, (100, 2))
    xyz = im.pixel_to_scanner(pix)
    assert np.allclose(im.scanner_to_pixel(xyz), pix, atol=1e-9)
    assert np.abs(im.distance_to_plane(xyz)).max() < 1e-9
    # the DICOM convention: column index moves along the row cosine by PixelSpacing[1]
    d = im.pixel_to_scanner([[1, 0]]) - im.pixel_to_scanner([[0, 0]])
    assert np.allclose(d[0], im.row_cosine * im.pixel_spacing[1])


def test_native_round_trip_is_exact_at_the_stated_precision(tmp_path):
    s = _study()
    native.write_study(s, tmp_path / "a")
    r = load_study(tmp_path / "a")
    assert r.subject == "s1" and r.heart_rate_bpm == 62.0 and (r.ed_frame, r.es_frame) == (0, 1)
    assert r.frame_times_ms == {0: 0.0, 1: 350.5}
    assert len(r.contours) == len(s.contours) and len(r.tags) == len(s.tags)
    for a, b in zip(s.contours, r.contours):   # 3 decimals: within half a micrometre
        assert np.abs(a.points - b.points).max() <= 0.5e-3 + 1e-12
        assert a.image == b.image and a.closed == b.closed
    native.write_study(s, tmp_path / "lossless", decimals=None)
    r17 = load_study(tmp_path / "lossless")
    for a, b in zip(s.contours, r17.contours):
        assert np.array_equal(a.points, b.points)
    assert [lm.index for lm in r.landmarks] == [0, 0, 1]
    native.write_study(r, tmp_path / "b")
    for name in ("study.json", "points.csv"):
        a = (tmp_path / "a" / name).read_text().replace(str(tmp_path / "a"), "")
        b = (tmp_path / "b" / name).read_text().replace(str(tmp_path / "b"), "")
        assert a == b


def test_native_pixel_only_rows_map_through_their_image(tmp_path):
    s = _study()
    native.write_study(s, tmp_path)
    csv = (tmp_path / "points.csv").read_text().splitlines()
    head = csv[0].split(",")
    xi = [head.index(c) for c in ("x", "y", "z")]
    out = [csv[0]]
    for line in csv[1:]:
        f = line.split(",")
        if f[0] == "contour":
            for i in xi:
                f[i] = ""
        out.append(",".join(f))
    (tmp_path / "points.csv").write_text("\n".join(out) + "\n")
    r = load_study(tmp_path)
    for a, b in zip(s.contours, r.contours):   # px, py at 1/1000 pixel (1.17 mm pixels)
        assert np.allclose(a.points, b.points, atol=1e-3)


@pytest.mark.parametrize("mutate, needle", [
    (lambda t: t.replace("lv_endo", "lv_endx", 1), "unknown structure"),
    (lambda t: t.replace(",sa_00_f0,", ",nope,", 1), "nope"),
    (lambda t: t.split("\n", 1)[0].replace("frame,", "") + "\n", "missing column"),
])
def test_native_bad_points_name_file_and_line(tmp_path, mutate, needle):
    native.write_study(_study(), tmp_path)
    p = tmp_path / "points.csv"
    p.write_text(mutate(p.read_text()))
    with pytest.raises(StudyError) as ei:
        load_study(tmp_path)
    msg = str(ei.value)
    assert needle in msg and "points.csv" in msg and "\n" not in msg


def test_bad_geometry_is_rejected():
    with pytest.raises(StudyError, match="ImageOrientationPatient"):
        ImagePlane(id="x", slice="s", view="SA", frame=0, position=[0, 0, 0],
                   row_cosine=[1, 0, 0], column_cosine=[1, 0, 0], pixel_spacing=(1, 1))
    with pytest.raises(StudyError, match="PixelSpacing"):
        ImagePlane(id="x", slice="s", view="SA", frame=0, position=[0, 0, 0],
                   row_cosine=[1, 0, 0], column_cosine=[0, 1, 0], pixel_spacing=(0, 1))
    with pytest.raises(StudyError, match="NaN"):
        Contour("lv_endo", "SA", "s", 0, [[0, 0, np.nan]])
