"""Inputs stay inside the study (issue 10): study.json may not name files by absolute path,
with ``..`` or through a symbolic link leading out; a Sunnybrook contour that is a symlink to
a system file is refused without echoing that file; ``allow_outside`` lifts the rule."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from broken.corpus import make_gpfile, make_native, make_sunnybrook, sb_contour
from cardionurbs import StudyError, load_study

ROOT = Path(__file__).resolve().parents[1]
SECRET = "TOP-SECRET-FIRST-LINE of a file outside the study"


@pytest.fixture
def secret(tmp_path) -> Path:
    p = tmp_path / "outside" / "secret.txt"
    p.parent.mkdir()
    p.write_text(SECRET + "\n1 2\n")
    return p


def _manifest(root: Path, fn) -> None:
    m = json.loads((root / "study.json").read_text())
    fn(m)
    (root / "study.json").write_text(json.dumps(m))


def _fails(path, *words, **kw):
    with pytest.raises(StudyError) as info:
        load_study(path, **kw)
    msg = str(info.value)
    assert "\n" not in msg and SECRET not in msg
    for w in words:
        assert w in msg, msg
    return msg


def test_points_by_absolute_path_is_refused_unless_allowed(tmp_path):
    root = make_native(tmp_path / "S")
    moved = tmp_path / "elsewhere.csv"
    shutil.move(root / "points.csv", moved)
    _manifest(root, lambda m: m.update(points=str(moved)))
    _fails(root, "absolute path", "points", "--allow-outside")
    assert load_study(root, allow_outside=True).contours       # the explicit option


def test_points_with_dotdot_is_refused(tmp_path):
    root = make_native(tmp_path / "S")
    shutil.move(root / "points.csv", tmp_path / "p.csv")
    _manifest(root, lambda m: m.update(points="../p.csv"))
    _fails(root, "'..'", "points")


def test_points_symlink_leading_out_is_refused(tmp_path):
    root = make_native(tmp_path / "S")
    shutil.move(root / "points.csv", tmp_path / "p.csv")
    os.symlink(tmp_path / "p.csv", root / "points.csv")
    _fails(root, "symbolic link", "points")


def test_points_symlink_inside_the_study_is_fine(tmp_path):
    root = make_native(tmp_path / "S")
    shutil.move(root / "points.csv", root / "real.csv")
    os.symlink("real.csv", root / "points.csv")
    assert load_study(root).contours


def test_image_file_outside_is_refused(tmp_path, secret):
    root = make_native(tmp_path / "S")
    _manifest(root, lambda m: m["images"][0].update(file=str(secret)))
    _fails(root, "absolute path", "images.file")
    _manifest(root, lambda m: m["images"][0].update(file="../../outside/secret.dcm"))
    _fails(root, "'..'", "images.file")


def test_gpfile_slice_file_names_stay_inside(tmp_path):
    root = make_gpfile(tmp_path / "G")
    info = root / "SliceInfoFile.txt"
    lines = info.read_text().splitlines()
    lines[0] = "/etc/passwd" + lines[0][lines[0].index("\t"):]
    info.write_text("\n".join(lines) + "\n")
    _fails(root, "absolute path", "SliceInfoFile")


def test_gpfile_symlink_leading_out_is_refused(tmp_path):
    root = make_gpfile(tmp_path / "G")
    gp = root / "GPFile_000.txt"
    shutil.move(gp, tmp_path / "gp0.txt")
    os.symlink(tmp_path / "gp0.txt", gp)
    _fails(root, "symbolic link", "GPFile_000.txt")


def test_sunnybrook_contour_symlink_to_a_system_file_is_not_echoed(tmp_path, secret):
    root = make_sunnybrook(tmp_path / "SB")
    c = sb_contour(root)
    c.unlink()
    os.symlink(secret, c)
    msg = _fails(root, "symbolic link", c.name)
    assert "1 2" not in msg
    csv = tmp_path / "cohort.csv"
    r = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "cohort", str(root), "--csv",
                        str(csv)], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 3, r.stderr          # the run finished; its one study failed
    assert SECRET not in csv.read_text() and SECRET not in r.stderr
    assert "symbolic link" in csv.read_text()


def test_sunnybrook_dicom_symlink_leading_out_is_refused(tmp_path):
    root = make_sunnybrook(tmp_path / "SB")
    dcm = sorted((root / "dicom").glob("*.dcm"))[0]
    shutil.move(dcm, tmp_path / "x.dcm")
    os.symlink(tmp_path / "x.dcm", dcm)
    _fails(root, "symbolic link", "DICOM")


def test_long_garbage_is_quoted_as_a_short_excerpt(tmp_path):
    root = make_sunnybrook(tmp_path / "SB")
    sb_contour(root).write_text("1 2\n" + "A" * 100_000 + " 3\n")
    msg = _fails(root)
    assert len(msg) < 600 and "100002 characters" in msg


# ---------------------------------------- links resolved at open time, against the study root
DATA = ROOT.parent / "shared" / "data"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data is not available")




def test_sunnybrook_dicom_folder_linked_elsewhere_is_refused(tmp_path):
    root = make_sunnybrook(tmp_path / "SB")
    shutil.move(root / "dicom", tmp_path / "elsewhere")
    os.symlink(tmp_path / "elsewhere", root / "dicom")
    msg = _fails(root, "symbolic link", "DICOM", "--allow-outside")
    assert "elsewhere" not in msg.split(":")[0] or "dicom" in msg   # names the link, not its target
    assert load_study(root, allow_outside=True).contours


@needs_data
def test_real_sunnybrook_dicom_linked_out_is_refused(tmp_path):
    src = DATA / "sunnybrook" / "SC-HF-I-2"
    root = tmp_path / "SB"
    shutil.copytree(src, root, ignore=shutil.ignore_patterns("dicom"))
    os.symlink(src / "dicom", root / "dicom")
    _fails(root, "symbolic link", "DICOM")


@needs_data
def test_acdc_gt_file_linked_out_is_refused(tmp_path):
    src = DATA / "acdc" / "patient005"
    root = Path(shutil.copytree(src, tmp_path / "patient005"))
    gt = sorted(root.glob("*_gt.nii*"))[0]
    gt.unlink()
    os.symlink(src / gt.name, gt)
    _fails(root, "symbolic link", gt.name)


_OPENED: list = []
sys.addaudithook(lambda event, args: _OPENED.append(os.fsdecode(args[0]))
                 if event == "open" and args and isinstance(args[0], (str, bytes, os.PathLike))
                 else None)


def test_study_json_that_is_a_link_out_is_refused(tmp_path):
    root = make_native(tmp_path / "S")
    shutil.move(root / "study.json", tmp_path / "manifest.json")
    os.symlink(tmp_path / "manifest.json", root / "study.json")
    _OPENED.clear()
    _fails(root, "symbolic link", "study.json")
    assert not [p for p in _OPENED if os.path.realpath(p) == os.path.realpath(tmp_path / "manifest.json")], \
        "the manifest outside the study was opened (format detection included)"
    assert load_study(root, allow_outside=True).contours


def test_a_study_reached_through_a_link_is_read(tmp_path):
    root = make_native(tmp_path / "S")
    os.symlink(root, tmp_path / "alias")
    assert load_study(tmp_path / "alias").contours     # the root itself is resolved once
