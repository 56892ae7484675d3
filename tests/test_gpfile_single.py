"""biv-me's single-file layout: one GPFile.txt holding every frame (the time frame column
says which) beside SliceInfoFile.txt reads as the same Study as the per-frame layout
(GPFile_NNN.txt); bad time frames, mixed frame numbering and confinement are refused with
one clear StudyError line."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from cardionurbs import load_study
from cardionurbs.errors import StudyError
from cardionurbs.io import detect_format, gpfile, studies_in
from conftest import shared_data

FRAMES = (0, 1, 2)


def _per_frame(dst, frames=FRAMES, name="GPFile_{:03d}.txt"):
    """A per-frame copy of bivme-patient1 with only ``frames`` (the files as they are)."""
    src = shared_data("bivme-patient1")
    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / "SliceInfoFile.txt", dst / "SliceInfoFile.txt")
    for f in frames:
        shutil.copy(src / f"GPFile_{f:03d}.txt", dst / name.format(f))
    return dst


def _single(dst, frames=FRAMES, time=lambda f, row: str(f)):
    """The same frames in biv-me's single-file style: one header, then every frame's lines,
    the time frame column set to the frame (``time`` may spoil it)."""
    src = shared_data("bivme-patient1")
    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / "SliceInfoFile.txt", dst / "SliceInfoFile.txt")
    header, body = None, []
    for f in frames:
        lines = (src / f"GPFile_{f:03d}.txt").read_text().splitlines()
        header = lines[0]
        for k, ln in enumerate(lines[1:]):
            tok = ln.split("\t")
            tok[6] = time(f, k)
            body.append("\t".join(tok))
    (dst / "GPFile.txt").write_text("\n".join([header, *body]) + "\n")
    return dst


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("single")
    a = load_study(_per_frame(root / "perframe"))
    b = load_study(_single(root / "single"))
    return root, a, b


def _assert_same_study(a, b):
    assert a.frames == b.frames == list(FRAMES)
    assert len(a.contours) == len(b.contours) > 0
    for x, y in zip(a.contours, b.contours):
        assert (x.structure, x.view, x.slice, x.frame, x.closed, x.index, x.image) == \
               (y.structure, y.view, y.slice, y.frame, y.closed, y.index, y.image)
        assert np.array_equal(x.points, y.points) and np.array_equal(x.weights, y.weights)
    assert [(m.name, m.frame, m.index, m.slice) for m in a.landmarks] == \
           [(m.name, m.frame, m.index, m.slice) for m in b.landmarks]
    assert np.array_equal([m.point for m in a.landmarks], [m.point for m in b.landmarks])
    assert [im.id for im in a.images] == [im.id for im in b.images]
    assert all(x.same_geometry(y, tol=1e-12) for x, y in zip(a.images, b.images))


def test_single_file_reads_as_the_per_frame_study(pair):
    root, a, b = pair
    _assert_same_study(a, b)
    assert detect_format(root / "single") == "gpfile"
    told = [w for w in b.warnings if "time frame column" in w]
    assert len(told) == 1 and "GPFile.txt" in told[0] and "3 frames (0-2)" in told[0]
    assert not any("time frame column" in w for w in a.warnings)


def test_the_file_itself_as_the_path(pair):
    root, a, _ = pair
    _assert_same_study(a, load_study(root / "single" / "GPFile.txt"))


def test_same_metrics_both_layouts(pair):
    """Equal studies give equal metrics (ED/ES among frames 0-2), in a plausible range."""
    from cardionurbs.pipeline import analyse_study
    _, a, b = pair
    ma, mb = analyse_study(a)[1], analyse_study(b)[1]
    assert ma.keys() == mb.keys()
    assert all(ma[k] == mb[k] or (ma[k] != ma[k] and mb[k] != mb[k]) for k in ma)
    assert 100 < ma["LVEDV (mL)"] < 300 and 80 < ma["LVM (g)"] < 200
    assert 100 < ma["RVEDV (mL)"] < 300


def test_gap_warning_names_the_single_file(tmp_path):
    s = load_study(_single(tmp_path, frames=(0, 2)))
    gap = [w for w in s.warnings if "no GPFile for frame 1" in w]
    assert len(gap) == 1 and "frames 0 and 2 of GPFile.txt" in gap[0]


def test_write_back_keeps_one_file(pair, tmp_path):
    root, _, b = pair
    gpfile.write_study(b, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["GPFile.txt", "SliceInfoFile.txt"]
    assert (tmp_path / "GPFile.txt").read_bytes() == (root / "single" / "GPFile.txt").read_bytes()
    _assert_same_study(b, load_study(tmp_path))


@pytest.mark.parametrize("bad, said", [("", "time frame is nothing"),
                                       ("1.5", "time frame is '1.5'"),
                                       ("x", "time frame is 'x'"),
                                       ("-1", "time frame is '-1'")])
def test_bad_time_frame_one_clear_line(tmp_path, bad, said):
    _single(tmp_path, frames=(0, 1), time=lambda f, k: bad if (f, k) == (1, 5) else str(f))
    n0 = len((shared_data("bivme-patient1") / "GPFile_000.txt").read_text().splitlines())
    with pytest.raises(StudyError) as e:
        load_study(tmp_path)
    msg = str(e.value)
    assert said in msg and f"line {n0 + 6}" in msg and "GPFile.txt" in msg and "\n" not in msg


def test_missing_time_frame_column_one_clear_line(tmp_path):
    _single(tmp_path, frames=(0, 1))
    gp = tmp_path / "GPFile.txt"
    rows = [ln.rsplit("\t", 1)[0] for ln in gp.read_text().splitlines()]
    gp.write_text("\n".join(rows) + "\n")
    with pytest.raises(StudyError) as e:
        load_study(tmp_path)
    msg = str(e.value)
    assert "GPFile.txt" in msg and "line 2" in msg and "time_frame" in msg and "\n" not in msg


def test_time_frames_the_slice_info_does_not_list(tmp_path):
    """A CAP SliceInfoFile with timeFrame numbers: a frame of the column it does not list
    is refused, naming the frame's first line."""
    _single(tmp_path, frames=(0, 1))
    info = tmp_path / "SliceInfoFile.txt"
    lines = info.read_text().splitlines()
    info.write_text("\n".join(ln.replace("sliceID:", "frameID:").replace(
        "\tImagePositionPatient", "\ttimeFrame\t0\tImagePositionPatient") for ln in lines) + "\n")
    n0 = len((shared_data("bivme-patient1") / "GPFile_000.txt").read_text().splitlines())
    with pytest.raises(StudyError) as e:
        load_study(tmp_path)
    msg = str(e.value)
    assert f"line {n0 + 1}" in msg and "no line of SliceInfoFile.txt lists this frame" in msg
    assert "GPFile.txt" in msg


def test_per_frame_files_win_over_a_stray_single_file(pair, tmp_path):
    root, a, _ = pair
    folder = _per_frame(tmp_path / "both")
    shutil.copy(root / "single" / "GPFile.txt", folder / "GPFile.txt")
    s = load_study(folder)
    _assert_same_study(a, s)
    assert not any("time frame column" in w for w in s.warnings)


def test_two_digit_frame_numbers(pair, tmp_path):
    """biv-me's example/guidepoints/patient1 mixes GPFile_000.txt with GPFile_03.txt: both
    numberings read as one series; two files for one frame are refused naming both."""
    _, a, _ = pair
    _assert_same_study(a, load_study(_per_frame(tmp_path / "two", name="GPFile_{:02d}.txt")))
    mixed = _per_frame(tmp_path / "mixed")
    (mixed / "GPFile_001.txt").rename(mixed / "GPFile_01.txt")
    _assert_same_study(a, load_study(mixed))
    shutil.copy(mixed / "GPFile_01.txt", mixed / "GPFile_001.txt")
    with pytest.raises(StudyError, match=r"two GPFiles for frame 1 \(GPFile_001.txt and "
                                         r"GPFile_01.txt\)"):
        load_study(mixed)


def test_empty_folder_message(tmp_path):
    shutil.copy(shared_data("bivme-patient1") / "SliceInfoFile.txt", tmp_path)
    with pytest.raises(StudyError, match="no GPFile_NNN.txt files and no GPFile.txt"):
        gpfile.read_study(tmp_path)


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="no symbolic links")
def test_single_file_link_outside_refused(pair, tmp_path):
    root, _, _ = pair
    folder = tmp_path / "linked"
    folder.mkdir()
    shutil.copy(root / "single" / "SliceInfoFile.txt", folder)
    os.symlink(root / "single" / "GPFile.txt", folder / "GPFile.txt")
    with pytest.raises(StudyError, match="GPFile"):
        gpfile.read_study(folder)


def test_cohort_discovery_finds_single_file_studies(pair):
    root, _, _ = pair
    assert sorted(p.name for p in studies_in(root)) == ["perframe", "single"]


def test_same_geometry_slice_numbers_merged(tmp_path):
    """biv-me's test_data style: a ``slice`` header column, a SliceInfoFile of ``frameID:``
    lines, one number per image (each frame's image of a slice numbered apart, the same
    geometry): one slice per geometry, told in one warning."""
    _single(tmp_path, frames=(0, 1))
    info = tmp_path / "SliceInfoFile.txt"
    lines = [ln.replace("sliceID:", "frameID:") for ln in info.read_text().splitlines()]
    ids = [int(ln.split("\t")[2]) for ln in lines]
    shift = 100
    extra = [ln.replace(f"\t{i}\t", f"\t{i + shift}\t", 1) for ln, i in zip(lines, ids)]
    info.write_text("\n".join(lines + extra) + "\n")
    gp = tmp_path / "GPFile.txt"
    rows = gp.read_text().splitlines()
    out = ["x\ty\tz\tcontour type\tslice\tweight\ttime frame"]
    for ln in rows[1:]:           # frame 1 refers to the second set of numbers
        tok = ln.split("\t")
        if tok[6] == "1":
            tok[4] = str(int(tok[4]) + shift)
        out.append("\t".join(tok))
    gp.write_text("\n".join(out) + "\n")
    s = load_study(tmp_path)
    ref = load_study(_single(tmp_path / "ref", frames=(0, 1)))
    assert [im.id for im in s.images] == [im.id for im in ref.images]
    assert [(c.structure, c.slice, c.frame) for c in s.contours] == \
           [(c.structure, c.slice, c.frame) for c in ref.contours]
    told = [w for w in s.warnings if "merged into" in w]
    assert len(told) == 1 and f"{len(lines)} slice number(s)" in told[0]
    assert f"merged into {len(lines)} slice(s)" in told[0]
