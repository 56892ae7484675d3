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
``<subject>_sa.nii.gz`` and ``mnms_info.csv`` (External code, ED, ES);
``mnms2`` — ``<subject>_SA_ED_gt``, ``_SA_ES_gt``, ``_LA_ED_gt``, ``_LA_ES_gt``
(3-D; the LA maps the 4-chamber slice) and the images without ``_gt``.
By default: frame interval in ``pixdim[4]`` (ms), NIfTI world RAS+ (DICOM LPS
with x and y negated), sform and qform codes 1. ``quirks`` (:data:`QUIRKS`,
``phantom --label-quirks``) write the real datasets' headers instead:
``real`` (ACDC: unit-scale sform code 2 with no real orientation, qform 0, the
spacing only in pixdim, slices base first; UK Biobank: ``pixdim[4]`` in seconds
with an unknown time unit), ``lps`` (in-plane array axes reversed, the same world
image), ``apex-first`` / ``base-first`` (SA slice order), ``pv`` (partial-volume
labels, 3 x 3 supersampling); see docs/formats.md.
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
LAYOUT_PRESETS = ("acdc", "ukbb", "mnms", "mnms2")
LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


def tissue_codes(phantom, hp: np.ndarray, f: float) -> np.ndarray:
    """Tissue code (BG, LV, MYO_LV, RV, MYO_RV, LA, RA) of heart-frame points at phase f.

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        The phantom.
    hp : ndarray, shape (n, 3)
        Heart-frame positions at phase f, mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).

    Returns
    -------
    ndarray of uint8, shape (n,)
        The tissue code of each point.
    """
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
    majority of supersample² sub-pixel centres).

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        The phantom.
    plane : cardionurbs.imaging.geometry.ImagePlane
        The image plane (its frame).
    supersample : int, optional
        Sub-pixels per side voted over.
    cache : dict, optional
        Heart-frame pixel positions per (slice, sub-pixel offset), filled and reused.

    Returns
    -------
    ndarray of uint8, shape (columns, rows)
        Tissue codes, first axis the column index.
    """
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
    """Tissue code -> label value of a convention (0 for what it does not label).

    Parameters
    ----------
    preset : str
        A label convention of :data:`cardionurbs.io.labels.PRESETS` (``"acdc"``, ``"ukbb"`` ...).
    atria : bool, optional
        Label the atria too (where the convention has them).

    Returns
    -------
    ndarray of uint8, shape (7,)
        Label value per tissue code.
    """
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
    dark, body grey, lung black; ``blur_px`` > 0 adds Gaussian partial-volume blur.

    Parameters
    ----------
    codes : ndarray of uint8
        A tissue code image, any shape.
    blur_px : float, optional
        Gaussian blur σ, in pixels.

    Returns
    -------
    ndarray of int16
        Intensities in 0..4095, shape of ``codes``.
    """
    val = np.array([BODY, BLOOD, MYO, BLOOD, MYO, BLOOD, BLOOD], float)
    img = val[codes]
    img = np.where(codes == BG, np.where(ndimage.binary_dilation(codes > 0, iterations=15), BODY, LUNG),
                   img)
    if blur_px > 0:
        img = ndimage.gaussian_filter(img, blur_px)
    return np.clip(np.round(img * 3000.0), 0, 4095).astype(np.int16)


def plane_affine_ras(planes: list[ImagePlane]) -> np.ndarray:
    """RAS+ voxel-to-world affine of a stack of parallel planes (k = list order; one plane:
    the third axis is the normal times the slice thickness).

    Parameters
    ----------
    planes : list of cardionurbs.imaging.geometry.ImagePlane
        Parallel planes in stack order.

    Returns
    -------
    ndarray, shape (4, 4)
        Voxel (i, j, k) to RAS+ world mm.

    Raises
    ------
    cardionurbs.errors.PhantomError
        The planes are not evenly spaced (one affine would misplace every plane beyond the
        first step).
    """
    p0 = planes[0]
    steps = np.diff([p.position for p in planes], axis=0)
    if len(steps) > 1 and not np.allclose(steps, steps[0], atol=1e-3):
        raise PhantomError(f"the stack {planes[0].slice}..{planes[-1].slice} is not evenly "
                           "spaced: one NIfTI affine cannot place its slices")
    a = np.eye(4)
    a[:3, 0] = p0.row_cosine * p0.pixel_spacing[1]
    a[:3, 1] = p0.column_cosine * p0.pixel_spacing[0]
    a[:3, 2] = (planes[1].position - p0.position) if len(planes) > 1 else p0.normal * p0.thickness
    a[:3, 3] = p0.position
    return LPS_TO_RAS @ a


#: what ``quirks`` of :func:`write_labelmaps` may hold (module docstring, docs/formats.md)
QUIRKS = ("real", "lps", "apex-first", "base-first", "pv")
#: ACDC's sform as distributed: unit scale, the scanner axes (x, y negated), origin 0
ACDC_SFORM = np.diag([-1.0, -1.0, 1.0, 1.0])


def parse_quirks(spec: "str | list[str] | tuple[str, ...] | None") -> tuple[str, ...]:
    """``"real,lps"`` (or a list) -> ("real", "lps"); PhantomError for an unknown quirk or for
    ``apex-first`` with ``base-first``.

    Parameters
    ----------
    spec : str, list of str, tuple of str or None
        Comma-separated quirk names, or a list of them.

    Returns
    -------
    tuple of str
        The quirks, lower case, repeats dropped, in order.

    Raises
    ------
    cardionurbs.errors.PhantomError
        An unknown quirk, or ``apex-first`` with ``base-first``.
    """
    if spec is None:
        return ()
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out = tuple(dict.fromkeys(q.strip().lower() for q in items if q.strip()))
    bad = [q for q in out if q not in QUIRKS]
    if bad:
        raise PhantomError(f"unknown label-map quirk {bad[0]!r}; expected some of {', '.join(QUIRKS)}")
    if "apex-first" in out and "base-first" in out:
        raise PhantomError("label-map quirks apex-first and base-first exclude each other")
    return out


def _save(data: np.ndarray, affine_ras: np.ndarray, dt_ms: float | None, path: Path,
          header: str = "ours") -> Path:
    """Write one map. ``header``: ``ours`` (sform and qform code 1, pixdim[4] in ms, units
    mm/msec); ``acdc`` (ACDC as distributed: the unit-scale :data:`ACDC_SFORM` with code 2,
    qform code 0, the spacing only in pixdim, units unknown); ``ukbb`` (UK Biobank: the real
    affine, pixdim[4] in seconds, time unit unknown)."""
    import nibabel as nib

    spacing = np.linalg.norm(affine_ras[:3, :3], axis=0)
    if header == "acdc":
        img = nib.Nifti1Image(data, ACDC_SFORM)
        img.set_sform(ACDC_SFORM, code=2)
        img.set_qform(None, code=0)
        img.header.set_zooms(tuple(spacing) + tuple(img.header.get_zooms()[3:]))
        img.header["xyzt_units"] = 0
    else:
        img = nib.Nifti1Image(data, affine_ras)
        img.set_sform(affine_ras, code=1)
        img.set_qform(affine_ras, code=1)
        img.header.set_xyzt_units("mm", "msec" if header == "ours" else "unknown")
    zooms = list(img.header.get_zooms())
    if data.ndim == 4 and dt_ms is not None:
        zooms[3] = dt_ms / 1000.0 if header == "ukbb" else dt_ms
        img.header.set_zooms(zooms)
    with atomic.atomic_path(path) as tmp:
        nib.save(img, str(tmp.with_suffix(".nii.gz")))
        tmp.with_suffix(".nii.gz").replace(tmp)
    return path


def _flip_in_plane(codes: np.ndarray, affine_ras: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same world image stored with both in-plane array axes reversed (a RAS <-> LPS
    storage flip): index i' = n - 1 - i, so the column is negated and the origin moves to
    the far end. Returns (codes, affine)."""
    a = affine_ras.copy()
    for ax in (0, 1):
        a[:3, 3] += (codes.shape[ax] - 1) * a[:3, ax]
        a[:3, ax] = -a[:3, ax]
    return np.ascontiguousarray(codes[::-1, ::-1]), a


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


class _Writer:
    """Writes the stacks of one phantom in one layout with its quirks (:func:`write_labelmaps`)."""

    def __init__(self, phantom, folder: Path, convention: str, quirks: tuple[str, ...],
                 supersample: int, blur_px: float, images: bool) -> None:
        self.phantom, self.folder, self.convention, self.quirks = phantom, folder, convention, quirks
        self.supersample = 3 if "pv" in quirks and supersample == 1 else int(supersample)
        self.blur_px, self.images = blur_px, images
        self.cache: dict = {}
        self.out: list[Path] = []
        self.header = {"acdc": "acdc", "ukbb": "ukbb"}.get(convention, "ours") \
            if "real" in quirks else "ours"
        self.lut = convention_lut("mnms" if convention == "mnms2" else convention)

    def sa_ids(self, default_apex_first: bool) -> list[str]:
        ids = sorted({im.slice for im in self.phantom.study.images if im.view == "SA"})  # base first
        apex_first = ("apex-first" in self.quirks or default_apex_first) and "base-first" not in self.quirks
        return ids[::-1] if apex_first else ids

    def stack(self, ids: list[str], frames: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Tissue codes (c, r, k, t) and the RAS affine they are stored with (quirk ``lps``)."""
        codes, planes = _stack(self.phantom, ids, frames, self.supersample, self.cache)
        aff = plane_affine_ras(planes)
        if "lps" in self.quirks:
            codes, aff = _flip_in_plane(codes, aff)
        return codes, aff

    def save(self, data, aff, dt, name: str, header: str | None = None) -> None:
        self.out.append(_save(data, aff, dt, self.folder / name, header or self.header))

    def image(self, codes, aff, dt, name: str) -> None:
        if self.images:
            self.save(_cine(codes, self.blur_px), aff, dt, name)

    def text(self, name: str, text: str) -> None:
        self.out.append(atomic.write_text(self.folder / name, text))


def write_labelmaps(phantom, folder: str | Path, convention: str = "ukbb", *,
                    supersample: int = 1, blur_px: float = 0.0, frames: list[int] | None = None,
                    images: bool = True, quirks: "str | list[str] | None" = None) -> list[Path]:
    """Write the phantom's label maps in the layout of ``convention`` (``acdc``, ``ukbb``,
    ``mnms``, ``mnms2``) into ``folder`` with the header ``quirks`` of :data:`QUIRKS`
    (module docstring); returns the files written.

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        The phantom.
    folder : path-like
        The output folder (made).
    convention : str, optional
        ``"acdc"``, ``"ukbb"`` (default), ``"mnms"`` or ``"mnms2"``.
    supersample : int, optional
        Sub-pixels per side of the label vote, >= 1.
    blur_px : float, optional
        Partial-volume blur of the cine images, in pixels.
    frames : list of int or None, optional
        The frames written (default all; 0-based).
    images : bool, optional
        Also write the untagged cine-like image NIfTI.
    quirks : str or list of str, optional
        Header quirks (:data:`QUIRKS`).

    Returns
    -------
    list of pathlib.Path
        The files written.

    Raises
    ------
    cardionurbs.errors.PhantomError
        An unknown convention or quirk, or ``supersample`` < 1.
    """
    if convention not in LAYOUT_PRESETS:
        raise PhantomError(f"unknown label convention {convention!r}; expected one of "
                           f"{', '.join(LAYOUT_PRESETS)}")
    if int(supersample) < 1:
        raise PhantomError(f"supersample must be >= 1, got {supersample!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    w = _Writer(phantom, folder, convention, parse_quirks(quirks), supersample, blur_px, images)
    n = len(phantom.phases)
    fr = list(range(n)) if frames is None else list(frames)
    {"ukbb": _write_ukbb, "acdc": _write_acdc, "mnms": _write_mnms,
     "mnms2": _write_mnms2}[convention](w, fr, n)
    return w.out


def _dt_ms(phantom) -> float:
    return 60000.0 / phantom.study.heart_rate_bpm / len(phantom.phases)


def _write_ukbb(w: _Writer, fr: list[int], n: int) -> None:
    dt = _dt_ms(w.phantom) if fr == list(range(fr[0], fr[0] + len(fr))) else None
    codes, aff = w.stack(w.sa_ids(False), fr)
    w.save(w.lut[codes], aff, dt, "seg_sa.nii.gz")
    w.image(codes, aff, dt, "sa.nii.gz")
    for la in sorted({im.slice for im in w.phantom.study.images if im.view == "LA"}):
        c, a = w.stack([la], fr)
        atria = la == "la_4ch"
        w.save(convention_lut("ukbb", atria)[c], a, dt, f"{'seg4_la_4ch' if atria else 'seg_' + la}.nii.gz")
        w.image(c, a, dt, f"{la}.nii.gz")


def _write_acdc(w: _Writer, fr: list[int], n: int) -> None:
    ph, es = w.phantom, int(w.phantom.es_frame)
    subject = ph.study.subject
    ids = w.sa_ids("real" not in w.quirks)          # ours: apex -> base; as distributed: base first
    for f in (0, es):
        codes, aff = w.stack(ids, [f])
        w.save(w.lut[codes[..., 0]], aff, None, f"{subject}_frame{f + 1:02d}_gt.nii.gz")
    w.text("Info.cfg", f"ED: 1\nES: {es + 1}\nGroup: {ph.config['pathology'].upper()}\n"
                       f"Height: 175.0\nNbFrame: {n}\nWeight: 75.0\n")
    if w.images:
        codes, aff = w.stack(ids, fr)
        w.image(codes, aff, _dt_ms(ph), f"{subject}_4d.nii.gz")


def _write_mnms(w: _Writer, fr: list[int], n: int) -> None:
    """4-D with only ED and ES labelled, and the CSV of ED/ES frames."""
    ph, es = w.phantom, int(w.phantom.es_frame)
    codes, aff = w.stack(w.sa_ids(False), fr)
    lab = w.lut[codes]
    keep = np.zeros(len(fr), bool)
    keep[[i for i, f in enumerate(fr) if f in (0, es)]] = True
    lab[..., ~keep] = 0
    dt = _dt_ms(ph)
    w.save(lab, aff, dt, f"{ph.study.subject}_sa_gt.nii.gz")
    w.image(codes, aff, dt, f"{ph.study.subject}_sa.nii.gz")
    w.text("mnms_info.csv", f"External code,ED,ES\n{ph.study.subject},0,{es}\n")


def _write_mnms2(w: _Writer, fr: list[int], n: int) -> None:
    """M&Ms-2: NNN_SA_ED_gt, NNN_SA_ES_gt (3-D), NNN_LA_ED_gt, NNN_LA_ES_gt (the 4-chamber
    slice), and the images without ``_gt``."""
    ph, es = w.phantom, int(w.phantom.es_frame)
    code = ph.study.subject
    has_4ch = any(im.slice == "la_4ch" for im in ph.study.images)
    for phase, f in (("ED", 0), ("ES", es)):
        for view, ids in (("SA", w.sa_ids(False)), ("LA", ["la_4ch"] if has_4ch else [])):
            if not ids:
                continue
            codes, aff = w.stack(ids, [f])
            w.save(w.lut[codes[..., 0]], aff, None, f"{code}_{view}_{phase}_gt.nii.gz")
            w.image(codes[..., 0], aff, None, f"{code}_{view}_{phase}.nii.gz")


def _cine(codes: np.ndarray, blur_px: float) -> np.ndarray:
    out = np.empty(codes.shape, dtype=np.int16)
    for idx in np.ndindex(*codes.shape[2:]):
        out[(slice(None), slice(None), *idx)] = cine_image(codes[(slice(None), slice(None), *idx)],
                                                           blur_px)
    return out
