"""Tag tracking clipped to the myocardium of NIfTI label maps (the study's segmentation as
label maps on the tagged images' pixel grid), against the phantom's true tag lines."""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest
from scipy import ndimage

from cardionurbs.cli import main
from cardionurbs.errors import TagTrackingError
from cardionurbs.io import load_study
from cardionurbs.io.nifti import read_study
from cardionurbs.phantom import generate, write_phantom
from cardionurbs.phantom.labelmaps import write_labelmaps
from cardionurbs.tracking import track_tags
from cardionurbs.tracking.labelmaps import signed_border_distance

MYO = 2          # ukbb convention: LV myocardium
ERODE_PX = 1


def _polyline_distance(P, Q):
    a, b = Q[:-1], Q[1:]
    ab = b - a
    t = np.clip(((P[:, None] - a[None]) * ab[None]).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12),
                0.0, 1.0)
    return np.linalg.norm(P[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)


def _erode_myocardium(folder, px):
    """Every label map of ``folder`` with its myocardium eroded by ``px`` pixels in-plane (the
    eroded rim becomes background), written back in place."""
    for path in sorted(folder.glob("seg*.nii.gz")):
        img = nib.load(str(path))
        data = np.asarray(img.dataobj)
        myo = data == MYO
        keep = ndimage.binary_erosion(myo, structure=np.ones((3, 3) + (1,) * (data.ndim - 2), bool),
                                      iterations=px)
        data = np.where(myo & ~keep, 0, data).astype(data.dtype)
        nib.save(nib.Nifti1Image(data, img.affine, img.header), str(path))


@pytest.fixture(scope="module")
def phantom(tmp_path_factory):
    root = tmp_path_factory.mktemp("trk_labels")
    ph = generate("normal", seed=0, frames=4, snr=20.0, volume_check=False)
    write_phantom(ph, root / "study")
    write_labelmaps(ph, root / "labels", "ukbb", images=False)
    write_labelmaps(ph, root / "eroded", "ukbb", images=False)
    _erode_myocardium(root / "eroded", ERODE_PX)
    study = load_study(root / "study")
    return root, study


@pytest.fixture(scope="module")
def tracked(phantom):
    root, study = phantom
    return {"contours": track_tags(study), "labels": track_tags(study, labels=root / "labels"),
            "eroded": track_tags(study, labels=read_study(root / "eroded"))}


def _label_masks(folder, study):
    """(slice, frame) -> myocardium pixels (rows, columns), read independently of the tracker:
    each tagged image's label map pixel grid found by its position along the stack normal."""
    out = {}
    for path in sorted(folder.glob("seg*.nii.gz")):
        img = nib.load(str(path))
        data = np.asarray(img.dataobj)
        aff = np.diag([-1.0, -1.0, 1.0, 1.0]) @ img.affine            # RAS -> LPS
        for im in study.images:
            if im.rows != data.shape[1] or im.columns != data.shape[0]:
                continue
            if abs(abs(np.asarray(im.row_cosine) @ aff[:3, 0]) / np.linalg.norm(aff[:3, 0]) - 1) > 1e-4:
                continue
            k = (np.asarray(im.position) - aff[:3, 3]) @ aff[:3, 2] / (aff[:3, 2] @ aff[:3, 2])
            off = np.asarray(im.position) - (aff[:3, 3] + round(k) * aff[:3, 2])
            if abs(k - round(k)) > 1e-3 or np.linalg.norm(off) > 1e-3 or not 0 <= round(k) < data.shape[2]:
                continue
            out[(im.slice, im.frame)] = data[:, :, round(k), im.frame].T == MYO
    return out


def test_lines_clipped_by_label_maps_lie_on_the_true_lines_inside_the_labelled_myocardium(phantom, tracked):
    root, study = phantom
    tr = tracked["labels"]
    assert "label maps" in tr.meta["tag_tracking"]["myocardium"]
    masks = _label_masks(root / "labels", study)
    assert {im.slice for im in study.images} <= {s for s, _ in masks}       # SA and LA grids found
    truth = {(t.family, t.index, t.slice, t.frame): t for t in study.tags}
    views, errs = set(), []
    for line in tr.tags:
        im = tr.image(line.image)
        P = im.scanner_to_pixel(line.points)
        sd = signed_border_distance(masks[(line.slice, line.frame)])
        r, c = np.round(P[:, 1]).astype(int), np.round(P[:, 0]).astype(int)
        assert masks[(line.slice, line.frame)][r, c].all(), line.slice
        assert (sd[r, c] >= 0.5).all()          # the 1 px margin, to the pixel grid
        views.add(line.view)
        t = truth.get((line.family, line.index, line.slice, line.frame))
        assert t is not None, "a tracked index the phantom does not have"
        errs.append(_polyline_distance(P, im.scanner_to_pixel(t.points)))
    e = np.concatenate(errs)
    assert views == {"SA", "LA"}
    assert np.median(e) <= 0.3 and np.percentile(e, 95) <= 1.0
    # the label maps and the contours describe the same myocardium: about as many points
    n_lab = sum(len(t.points) for t in tr.tags)
    n_con = sum(len(t.points) for t in tracked["contours"].tags)
    assert 0.7 < n_lab / n_con < 1.3


def test_clipping_follows_the_label_maps_not_the_contours(phantom, tracked):
    """Label maps whose myocardium is eroded by 1 px: the lines stop inside the eroded
    myocardium, where the contour-clipped lines run on into the removed rim."""
    root, study = phantom
    masks = _label_masks(root / "eroded", study)

    def outside(tr):
        n = tot = 0
        for line in tr.tags:
            P = tr.image(line.image).scanner_to_pixel(line.points)
            r, c = np.round(P[:, 1]).astype(int), np.round(P[:, 0]).astype(int)
            n += int((~masks[(line.slice, line.frame)][r, c]).sum())
            tot += len(P)
        return n, tot

    n_eroded, tot_eroded = outside(tracked["eroded"])
    n_contours, tot_contours = outside(tracked["contours"])
    assert tot_eroded > 0 and n_eroded == 0
    assert n_contours > 0.03 * tot_contours       # ~7 % here
    assert tot_eroded < tot_contours


def test_track_command_takes_label_maps_and_a_label_map_study_alone_is_exit_2(phantom, tmp_path, capsys):
    root, _ = phantom
    out = tmp_path / "tracked"
    assert main(["track", str(root / "study"), "--out", str(out), "--label-maps",
                 str(root / "labels")]) == 0
    assert "label maps" in load_study(out).meta["tag_tracking"]["myocardium"]
    capsys.readouterr()
    # the label maps hold no tagged images
    assert main(["track", str(root / "labels"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "label maps" in err[0]
    with pytest.raises(TagTrackingError, match="pixel grid"):
        other = generate("normal", seed=0, frames=2, volume_check=False, matrix=192)
        write_labelmaps(other, tmp_path / "other", "ukbb", images=False)
        track_tags(load_study(root / "study"), labels=tmp_path / "other")
