"""NIfTI label maps (and an untagged cine-like image) of the analytic phantom.

Each pixel of every image plane (SA stack and LA views, at the acquisition's
pixel size) is labelled by the tissue at its centre in the analytic anatomy
at that frame: the pixel centre is mapped to the heart frame and back through
the motion to its material point (:meth:`Motion.inverse_cylindrical`), then

* LV cavity ``s < S1``, LV myocardium ``S1 ≤ s ≤ S2``, RV cavity
  ``S2 < s < S3`` and RV myocardium ``S3 ≤ s ≤ S4`` for ``0 ≤ z ≤ z_b``
  (anatomy eqs. A1–A3; S4 the RV epicardial shell);
* left / right atrium above the base plane: the cap
  ``s < S1(z_b)(1 − u²)`` over the LV and the crescent ``S2(z_b) < s <
  S3(z_b)(1 − u²)`` over the RV, ``u = (z − z_b) / 30 mm``.

``supersample`` > 1 labels each pixel by the majority of s × s sub-pixel
centres (partial-volume assignment) instead. The label values follow a
convention of :mod:`cardionurbs.io.labels` (``acdc``, ``ukbb``, ``mnms``); the
RV myocardium is not labelled (these conventions have no RV wall) and the
atria only in the ukbb 4-chamber map (``seg4_la_4ch``). The truth of a label
map study stays the analytic ``truth.json``.

Layouts written by :func:`write_labelmaps` (see :mod:`cardionurbs.io.nifti`):
``ukbb`` — ``seg_sa.nii.gz`` (4-D, slices base → apex), ``seg4_la_4ch``,
``seg_la_2ch``, ``seg_la_3ch`` and images ``sa``, ``la_*``; ``acdc`` —
``<subject>_frameMM_gt.nii.gz`` at ED and ES (slices apex → base, as a
reader must not assume an order), ``Info.cfg`` and ``<subject>_4d.nii.gz``;
``mnms`` — ``<subject>_sa_gt.nii.gz`` (4-D, only ED and ES labelled),
``<subject>_sa.nii.gz`` and ``mnms_info.csv`` (External code, ED, ES).
Frame interval in ``pixdim[4]`` (ms), NIfTI world RAS+ (DICOM LPS with x and
y negated), sform and qform codes 1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from cardionurbs.errors import PhantomError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io import atomic
from cardionurbs.io.labels import PRESETS
from cardionurbs.phantom.dicom import ATRIUM_MM, BLOOD, BODY, LUNG, MYO, pixel_heart_points, tissue_masks

#: tissue codes of :func:`tissue_codes`
BG, LV, MYO_LV, RV, MYO_RV, LA, RA = range(7)
LAYOUT_PRESETS = ("acdc", "ukbb", "mnms")
LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


def tissue_codes(phantom, hp: np.ndarray, f: float) -> np.ndarray:
    """Tissue code (BG, LV, MYO_LV, RV, MYO_RV, LA, RA) of heart-frame points at phase f."""
    an, mo = phantom.anatomy, phantom.motion
    s, th, z, s1, s2, s3 = mo.inverse_cylindrical(an, hp, f)
    tm = tissue_masks(an, s, th, z, s1, s2, s3)
    code = np.full(len(z), BG, dtype=np.uint8)
    code[tm["rv_myo"]] = MYO_RV
    code[tm["rv_cav"]] = RV
    code[tm["lv_myo"]] = MYO_LV
    code[tm["lv_cav"]] = LV
    code[tm["la"]] = LA
    code[tm["ra"] & ~tm["la"]] = RA
    return code


def plane_codes(phantom, plane: ImagePlane, supersample: int = 1,
                cache: dict | None = None) -> np.ndarray:
    """(columns, rows) tissue codes of one image plane at its frame (pixel centre, or the
    majority of supersample² sub-pixel centres)."""
    f = float(phantom.phases[plane.frame])
    s = int(supersample)
    votes = []
    offsets = [(0.0, 0.0)] if s <= 1 else [((i + 0.5) / s - 0.5, (j + 0.5) / s - 0.5)
                                          for i in range(s) for j in range(s)]
    for dc, dr in offsets:
        key = (plane.slice, dc, dr)
        if cache is not None and key in cache:
            hp, roi = cache[key]
        else:
            shifted = plane
            if dc or dr:
                shifted = ImagePlane(id=plane.id, slice=plane.slice, view=plane.view, frame=plane.frame,
                                     position=plane.position + dc * plane.pixel_spacing[1] * plane.row_cosine
                                     + dr * plane.pixel_spacing[0] * plane.column_cosine,
                                     row_cosine=plane.row_cosine, column_cosine=plane.column_cosine,
                                     pixel_spacing=plane.pixel_spacing, rows=plane.rows,
                                     columns=plane.columns, thickness=plane.thickness)
            hp, roi = pixel_heart_points(phantom, shifted)
            if cache is not None:
                cache[key] = (hp, roi)
        full = np.zeros(plane.rows * plane.columns, dtype=np.uint8)
        full[roi] = tissue_codes(phantom, hp, f)
        votes.append(full)
    if len(votes) == 1:
        code = votes[0]
    else:
        counts = np.stack([(np.stack(votes) == c).sum(axis=0) for c in range(7)])
        code = counts.argmax(axis=0).astype(np.uint8)
    return code.reshape(plane.rows, plane.columns).T          # (c, r): first axis = column index


def convention_lut(preset: str, atria: bool = False) -> np.ndarray:
    """Tissue code -> label value of a convention (0 for what it does not label)."""
    roles = PRESETS[preset]
    lut = np.zeros(7, dtype=np.uint8)
    lut[LV], lut[MYO_LV] = roles.lv, roles.myo
    if roles.rv is not None:
        lut[RV] = roles.rv
    if atria and roles.la is not None:
        lut[LA], lut[RA] = roles.la, roles.ra
    return lut


def cine_image(codes: np.ndarray, blur_px: float = 0.0) -> np.ndarray:
    """Untagged cine-like intensities (0..4095) of a code image: blood bright, myocardium
    dark, body grey, lung black; ``blur_px`` > 0 adds Gaussian partial-volume blur."""
    val = np.array([BODY, BLOOD, MYO, BLOOD, MYO, BLOOD, BLOOD], float)
    img = val[codes]
    img = np.where(codes == BG, np.where(ndimage.binary_dilation(codes > 0, iterations=15), BODY, LUNG),
                   img)
    if blur_px > 0:
        img = ndimage.gaussian_filter(img, blur_px)
    return np.clip(np.round(img * 3000.0), 0, 4095).astype(np.int16)


def plane_affine_ras(planes: list[ImagePlane]) -> np.ndarray:
    """RAS+ voxel-to-world affine of a stack of parallel planes (k = list order; one plane:
    the third axis is the normal times the slice thickness)."""
    p0 = planes[0]
    a = np.eye(4)
    a[:3, 0] = p0.row_cosine * p0.pixel_spacing[1]
    a[:3, 1] = p0.column_cosine * p0.pixel_spacing[0]
    a[:3, 2] = (planes[1].position - p0.position) if len(planes) > 1 else p0.normal * p0.thickness
    a[:3, 3] = p0.position
    return LPS_TO_RAS @ a


def _save(data: np.ndarray, affine_ras: np.ndarray, dt_ms: float | None, path: Path) -> Path:
    import nibabel as nib

    img = nib.Nifti1Image(data, affine_ras)
    img.set_sform(affine_ras, code=1)
    img.set_qform(affine_ras, code=1)
    zooms = list(img.header.get_zooms())
    if data.ndim == 4 and dt_ms is not None:
        zooms[3] = dt_ms
        img.header.set_zooms(zooms)
    img.header.set_xyzt_units("mm", "msec")
    with atomic.atomic_path(path) as tmp:
        nib.save(img, str(tmp.with_suffix(".nii.gz")))
        tmp.with_suffix(".nii.gz").replace(tmp)
    return path


def _stack(phantom, slice_ids: list[str], frames: list[int], supersample: int, cache: dict):
    """(columns, rows, len(slice_ids), len(frames)) codes and the planes of frame frames[0]."""
    by_key = {(im.slice, im.frame): im for im in phantom.study.images}
    planes = [by_key[(s, frames[0])] for s in slice_ids]
    p0 = planes[0]
    codes = np.zeros((p0.columns, p0.rows, len(slice_ids), len(frames)), dtype=np.uint8)
    for j, fr in enumerate(frames):
        for i, s in enumerate(slice_ids):
            codes[:, :, i, j] = plane_codes(phantom, by_key[(s, fr)], supersample, cache)
    return codes, planes


def write_labelmaps(phantom, folder: str | Path, convention: str = "ukbb", *,
                    supersample: int = 1, blur_px: float = 0.0, frames: list[int] | None = None,
                    images: bool = True) -> list[Path]:
    """Write the phantom's label maps in the layout of ``convention`` into ``folder``
    (see the module docstring); returns the files written."""
    if convention not in LAYOUT_PRESETS:
        raise PhantomError(f"unknown label convention {convention!r}; expected one of "
                           f"{', '.join(LAYOUT_PRESETS)}")
    if int(supersample) < 1:
        raise PhantomError(f"supersample must be >= 1, got {supersample!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    study = phantom.study
    n = len(phantom.phases)
    es = int(phantom.es_frame)
    dt = 60000.0 / study.heart_rate_bpm / n
    sa_ids = sorted({im.slice for im in study.images if im.view == "SA"})
    la_ids = sorted({im.slice for im in study.images if im.view == "LA"})
    subject = study.subject
    out: list[Path] = []
    cache: dict = {}
    lut = convention_lut(convention)
    if convention == "ukbb":
        fr = list(range(n)) if frames is None else list(frames)
        if fr != list(range(fr[0], fr[0] + len(fr))):
            dt = None                          # a subset of frames has no constant interval
        codes, planes = _stack(phantom, sa_ids, fr, supersample, cache)
        aff = plane_affine_ras(planes)
        out.append(_save(lut[codes], aff, dt, folder / "seg_sa.nii.gz"))
        if images:
            out.append(_save(_cine(codes, blur_px), aff, dt, folder / "sa.nii.gz"))
        for la in la_ids:
            c, pl = _stack(phantom, [la], fr, supersample, cache)
            atria = la == "la_4ch"
            name = "seg4_la_4ch" if atria else f"seg_{la}"
            out.append(_save(convention_lut(convention, atria)[c], plane_affine_ras(pl), dt,
                             folder / f"{name}.nii.gz"))
            if images:
                out.append(_save(_cine(c, blur_px), plane_affine_ras(pl), dt, folder / f"{la}.nii.gz"))
        return out
    fr = list(range(n)) if frames is None else list(frames)
    if convention == "acdc":
        ids = sa_ids[::-1]                                  # apex -> base
        for f in (0, es):
            codes, planes = _stack(phantom, ids, [f], supersample, cache)
            out.append(_save(lut[codes[..., 0]], plane_affine_ras(planes), None,
                             folder / f"{subject}_frame{f + 1:02d}_gt.nii.gz"))
        info = (f"ED: 1\nES: {es + 1}\nGroup: {phantom.config['pathology'].upper()}\n"
                f"Height: 175.0\nNbFrame: {n}\nWeight: 75.0\n")
        out.append(atomic.write_text(folder / "Info.cfg", info))
        if images:
            codes, planes = _stack(phantom, ids, fr, supersample, cache)
            out.append(_save(_cine(codes, blur_px), plane_affine_ras(planes), dt,
                             folder / f"{subject}_4d.nii.gz"))
        return out
    # mnms: 4-D with only ED and ES labelled
    codes, planes = _stack(phantom, sa_ids, fr, supersample, cache)
    lab = lut[codes]
    keep = np.zeros(len(fr), bool)
    keep[[i for i, f in enumerate(fr) if f in (0, es)]] = True
    lab[..., ~keep] = 0
    aff = plane_affine_ras(planes)
    out.append(_save(lab, aff, dt, folder / f"{subject}_sa_gt.nii.gz"))
    if images:
        out.append(_save(_cine(codes, blur_px), aff, dt, folder / f"{subject}_sa.nii.gz"))
    out.append(atomic.write_text(folder / "mnms_info.csv",
                                 f"External code,ED,ES\n{subject},0,{es}\n"))
    return out


def _cine(codes: np.ndarray, blur_px: float) -> np.ndarray:
    out = np.empty(codes.shape, dtype=np.int16)
    for idx in np.ndindex(*codes.shape[2:]):
        out[(slice(None), slice(None), *idx)] = cine_image(codes[(slice(None), slice(None), *idx)],
                                                           blur_px)
    return out
