"""Synthetic SPAMM-tagged cine MR images of the phantom, written as DICOM with pydicom.

Image model (per pixel, evaluated at the pixel centre of the image plane):

1. Scanner → heart frame (minus the slice's breath-hold shift) → material
   point X = φ_t⁻¹(x) (motion inverse, closed form).
2. Tissue class from X: LV/RV cavity blood, LV/RV myocardium, atrial blood
   above the valve plane (a half-ellipsoid cap), mediastinal tissue inside a
   cylinder around the heart, lung outside it (computed only inside, which
   keeps a subject's 240 images to a few seconds).
   Base signal: blood 1.0, myocardium 0.3, mediastinum 0.14, lung 0.03.
3. SPAMM modulation carried by the tissue (computed in material coordinates,
   so tags move with it): SA images use the two orthogonal SA tag families,
   LA images the LA family; each tag plane darkens a Gaussian band of σ = 0.6
   pixel around it, M = Π_k (1 − a(t) exp(−d_k² / 2σ²)), d_k the distance to
   the nearest plane of family k. The depth a(t) = 0.9 exp(−t / T1),
   T1 = 850 ms, fades through the cycle; in blood it is reduced to 15 %
   (inflow washes tags out).
4. Rician noise on the magnitude image: |I + n_1 + i n_2| with n_1, n_2 ~
   N(0, σ²) i.i.d. (the real and imaginary channel noise of the complex MR
   signal; Gudbjartsson & Patz 1995). ``snr`` = S sets σ = 0.3 / S, i.e. S is
   the untagged myocardial signal over the channel noise; the default σ =
   0.025 is S = 12. Seeded per (seed, frame, slice): the same phantom and S
   give identical pixels.
5. Grey levels (MONOCHROME2, 16 bits allocated, 12 stored): the image is stored
   at a grey-level step matched to its noise, pixel = round(I / Δ) with
   Δ = σ / NOISE_GREY_LEVELS (σ spans 2.2 grey levels; at most SCALE = 3000
   levels per unit signal, so noise-free images keep 0..4095). Rounding adds a
   uniform error of variance Δ²/12 = σ² / (12 · 2.2²), 1.7 % of the noise
   variance (0.9 % of its standard deviation): the SNR is unchanged, and the
   noise, which no lossless coder can compress, is not stored at a finer step
   than it has (at the default σ the blood pool is about 88 grey levels).

The contrast is that of a spoiled-gradient-echo SPAMM cine (e.g. Axel &
Dougherty 1989; Zerhouni et al. 1988): bright inflowing blood, myocardium
about a third of it, darker mediastinum and almost no lung signal; tags
dark and fading with T1 through the cycle (they are ~0 % left at t ≈ 2 T1),
washed out in the blood. Every tag plane's position at every frame is known
in closed form (the tag lines in the native study are those planes' cuts).

DICOM: pixel data JPEG-LS Lossless (transfer syntax 1.2.840.10008.1.2.4.80, ISO/IEC
14495-1, DICOM PS3.5 A.4.3; encoded and decoded by pydicom through the pyjpegls
plugin (CharLS), read by every major DICOM toolkit), or RLE Lossless (``compression="rle"``,
1.2.840.10008.1.2.5, PS3.5 Annex G, decoded by pydicom without plugins), or uncompressed
Explicit VR Little Endian with ``compression=None``. No lossless coder can go below the
entropy of the noise: JPEG-LS (a context-modelled predictor with Golomb coding) stores the
default phantom at about 4 bits per pixel, a quarter of the uncompressed 16 bits; RLE,
which cannot code noise, about 2/3 of them (measured in reports/benchmark-throughput.md).
One MR series per view (``sa`` with all SA slices, ``la_2ch``,
``la_3ch``, ``la_4ch``), file ``dicom/<series>/<slice>_<frame>.dcm``, with
ImagePositionPatient, ImageOrientationPatient, PixelSpacing, SliceThickness,
SliceLocation, TriggerTime, HeartRate, NominalInterval, CardiacNumberOfImages
and deterministic UIDs (SOPInstanceUID = the study's image id), no dates or
times taken from the clock.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.uid import (ExplicitVRLittleEndian, JPEGLSLossless, MRImageStorage, PYDICOM_IMPLEMENTATION_UID,
                        RLELossless, generate_uid)
from pydicom.valuerep import format_number_as_ds

from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.phantom.anatomy import unit_phasor, wrap_angle

BLOOD, MYO, BODY, LUNG = 1.0, 0.3, 0.14, 0.03
ATRIUM_MM = 30.0
TAG_DEPTH, T1_MS, TAG_SIGMA_PX, BLOOD_TAG = 0.9, 850.0, 0.6, 0.15
NOISE = 0.025
SCALE = 3000.0                    # most grey levels per unit signal (blood = 1)
NOISE_GREY_LEVELS = 2.2           # the channel noise σ spans this many grey levels
COMPRESSIONS = ("jpegls", "rle", None)


def noise_sigma(snr: float | None) -> float:
    """Channel noise σ (same units as the signal, myocardium = 0.3) for an SNR; default 0.025.

    Parameters
    ----------
    snr : float or None
        Untagged myocardium signal over the channel noise σ (None: the default σ).

    Returns
    -------
    float
        σ, in signal units (0.3 / snr).
    """
    if snr is None:
        return NOISE
    return MYO / float(snr)


def grey_levels_per_unit(sigma: float) -> float:
    """Grey levels per unit signal (1/Δ) for channel noise σ: NOISE_GREY_LEVELS / σ, at most
    SCALE (noise-free or very high SNR images).

    Parameters
    ----------
    sigma : float
        The channel noise σ, in signal units.

    Returns
    -------
    float
        Grey levels per unit signal.
    """
    if not sigma > 0:
        return SCALE
    return min(SCALE, NOISE_GREY_LEVELS / float(sigma))


def _tag_band(u: np.ndarray, spacing: float, offset: float, sigma: float) -> np.ndarray:
    """exp(−d² / 2σ²), d the signed distance of u to the nearest plane offset + k · spacing."""
    d = u - offset + 0.5 * spacing
    d = d - spacing * np.floor(d / spacing) - 0.5 * spacing
    return np.exp(-0.5 * (d / sigma) ** 2)


PAPILLARY = ((np.radians(130.0), 0.25, 0.65), (np.radians(-130.0), 0.2, 0.6))
PAPILLARY_RADIUS_MM = 3.5
PAPILLARY_DEPTH = 0.78            # muscle axis at this fraction of the endocardial radius
BAND_HEIGHT, BAND_HALF_MM, BAND_HALF_RAD = 0.35, 1.5, 0.07


def material_sections(an, mo, points: np.ndarray, f: float):
    """φ_f⁻¹ of (n, 3) heart-frame positions at phase f with every section value there computed
    once: material (s, θ, z) and S1 = s_endo, S2 = s_epi, S3 = max(S2, S_rv_endo),
    S4 = max(S3, S_rv_epi) at (θ, z) (the values of :meth:`Motion.inverse_cylindrical` and of
    :meth:`Anatomy.s_rv`, each factor shared between the surfaces that need it), and e^{iθ}.

    Parameters
    ----------
    an : cardionurbs.phantom.anatomy.Anatomy
        The anatomy.
    mo : cardionurbs.phantom.motion.Motion
        The motion.
    points : ndarray, shape (n, 3)
        Heart-frame positions at phase f, in mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).

    Returns
    -------
    tuple of ndarray, each shape (n,)
        (s, θ, z, S1, S2, S3, S4, e^{iθ}): the material coordinates (s = r² in mm², θ in rad,
        z in mm) and the section values, in mm².
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    z = p[:, 2] / mo.lam(f)
    th = np.arctan2(p[:, 1], p[:, 0]) + mo.psi(z, f)
    e = unit_phasor(th)
    s1, s2 = an.lv_sections(z, th, e)
    rv_endo, rv_epi = an.s_rv_pair(th, z, s_epi=s2 if an.shape is not None else None)
    s3 = np.maximum(s2, rv_endo)
    knots = mo.knots(an, th, z, f, (s1, s2, s3))
    s = mo.inverse_radial_map(an, p[:, 0] ** 2 + p[:, 1] ** 2, th, z, f, knots=knots)
    return s, th, z, s1, s2, s3, np.maximum(s3, rv_epi), e


def tissue_masks(an, s: np.ndarray, th: np.ndarray, z: np.ndarray, s1: np.ndarray, s2: np.ndarray,
                 s3: np.ndarray, s4: np.ndarray | None = None,
                 xy: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Boolean masks of the tissues at material points (s, θ, z) with their section values
    (motion inverse): ``lv_cav``, ``lv_myo``, ``rv_cav``, ``rv_myo``, the atria ``la``, ``ra``
    (half-ellipsoid caps above the base), and, for a realistic anatomy, ``papillary`` and
    ``band`` (papillary muscles and the RV trabecular band: muscle inside the cavities, which
    the metric definitions count as cavity — drawn in images, labelled as cavity in label maps).
    ``s4`` = max(S3, S_rv_epi) and ``xy`` = the material (x, y) when the caller has them.

    Parameters
    ----------
    an : cardionurbs.phantom.anatomy.Anatomy
        The anatomy.
    s, th, z : ndarray, shape (n,)
        Material coordinates: s = r² (mm²), θ (rad), z (mm).
    s1, s2, s3 : ndarray, shape (n,)
        S1 = s_endo, S2 = s_epi, S3 = max(S2, S_rv_endo) at (θ, z), in mm².
    s4 : ndarray, shape (n,), optional
        S4 = max(S3, S_rv_epi), in mm².
    xy : tuple of (ndarray, ndarray), optional
        The material (x, y), in mm.

    Returns
    -------
    dict of str to ndarray of bool
        Tissue name -> mask (n,).
    """
    if s4 is None:
        s4 = np.maximum(s3, an.s_rv(th, z, epi=True))
    real = an.shape is not None
    lv_top = an.z_top(th) if real else an.z_base
    lv_heart = (z >= 0) & (z <= lv_top)
    rv_top = an.z_top_rv(th) if real else an.z_base
    rv_heart = (z >= 0) & (z <= rv_top)
    out = {"lv_cav": lv_heart & (s < s1), "lv_myo": lv_heart & (s >= s1) & (s <= s2),
           "rv_cav": rv_heart & (s > s2) & (s < s3),
           "rv_myo": rv_heart & (s >= s3) & (s <= s4) & (s4 > s2)}
    if real and an.shape.outflow is not None:
        _add_outflow(an, out, s, th, z, s1, s2, s3, s4, xy)
    u = (z - lv_top) / ATRIUM_MM
    cap = np.clip(1.0 - u * u, 0.0, None)
    out["la"] = np.zeros(len(z), dtype=bool)
    out["ra"] = np.zeros(len(z), dtype=bool)
    above = np.flatnonzero(z > (min(an.z_top_min, an.z_top_rv_min) if real else an.z_base))  # atria
    if len(above):
        th_a, zb = th[above], np.full(len(above), an.z_base)
        s_a = s[above]
        s_mitral, s2b = an.lv_sections(zb, th_a) if real else (float(an.s_lv_endo(an.z_base)),
                                                               float(an.s_lv_epi(an.z_base)))
        out["la"][above] = (u[above] > 0) & (s_a < s_mitral * cap[above])
        ur = (z[above] - an.z_base) / ATRIUM_MM
        cap_r = np.clip(1.0 - ur * ur, 0.0, None)
        out["ra"][above] = ((ur > 0) & ~out["la"][above] & (s_a > s2b)
                            & (s_a < an.s_rv(th_a, zb) * cap_r))
        if real:    # below a dipping tricuspid annulus: the RV body's lumen there is atrium
            out["ra"][above] |= ((z[above] > rv_top[above]) & (z[above] <= an.z_base)
                                 & (s_a > s2[above]) & (s_a < s3[above]))
        if real and an.shape.outflow is not None:       # the atria end where the tracts begin
            tracts = out["lv_cav"] | out["rv_cav"] | out["rv_myo"]
            out["la"] &= ~tracts
            out["ra"] &= ~tracts
    if real:
        out["papillary"] = np.zeros(len(z), dtype=bool)
        for tp, lo, hi in PAPILLARY:
            idx = np.flatnonzero(out["lv_cav"] & (z >= lo * an.z_base) & (z <= hi * an.z_base))
            if xy is None:
                r = np.sqrt(np.maximum(s[idx], 0.0))
                x, y = r * np.cos(th[idx]), r * np.sin(th[idx])
            else:
                x, y = xy[0][idx], xy[1][idx]
            rc = PAPILLARY_DEPTH * np.sqrt(np.maximum(an.s_lv_endo(z[idx], np.full(len(idx), tp)), 0.0))
            d2 = (x - rc * np.cos(tp)) ** 2 + (y - rc * np.sin(tp)) ** 2
            out["papillary"][idx[d2 < PAPILLARY_RADIUS_MM ** 2]] = True
        out["band"] = out["rv_cav"] & (np.abs(z - BAND_HEIGHT * an.z_base) < BAND_HALF_MM) & (
            np.abs(wrap_angle(th)) < BAND_HALF_RAD)
    return out


def _add_outflow(an, out: dict, s, th, z, s1, s2, s3, s4, xy=None) -> None:
    """Add the outflow tracts (phantom/outflow.py) to the cavity and wall masks: the RVOT lumen and
    free wall above the tricuspid plane and below the pulmonary valve plane, the LVOT lumen (inside
    the LV endocardium and the LVOT cylinder, below the aortic valve plane)."""
    from cardionurbs.phantom import outflow as ofl
    if xy is None:
        r = np.sqrt(np.maximum(s, 0.0))
        x, y = r * np.cos(th), r * np.sin(th)
    else:
        x, y = xy
    tract = (z > an.z_base) & (ofl.rvot_top_term(an, x, y, z) < 0)
    out["rv_cav"] |= tract & (s > s2) & (s < s3)
    out["rv_myo"] |= tract & (s >= s3) & (s <= s4) & (s4 > s2)
    out["lv_cav"] |= ((z >= 0) & (s < s1) & (ofl.lvot_cylinder_term(an, x, y) < 0)
                      & (ofl.lvot_top_term(an, x, y, z) < 0))


def pixel_heart_points(phantom, plane: ImagePlane) -> tuple[np.ndarray, np.ndarray]:
    """Heart-frame positions of the pixel centres inside the heart region of interest, and its mask.

    The same for every frame of a slice (planes are static); includes the slice's breath-hold shift.

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        The phantom.
    plane : cardionurbs.imaging.geometry.ImagePlane
        The image plane.

    Returns
    -------
    points : ndarray, shape (k, 3)
        Heart-frame positions of the pixels inside the region, in mm.
    mask : ndarray of bool, shape (rows * columns,)
        Which pixels (row-major) are inside.
    """
    an, pose = phantom.anatomy, phantom.pose
    cc, rr = np.meshgrid(np.arange(plane.columns, dtype=float), np.arange(plane.rows, dtype=float))
    pts = plane.pixel_to_scanner(np.column_stack([cc.ravel(), rr.ravel()]))
    if plane.slice in phantom.shifts:
        sh = phantom.shifts[plane.slice]
        pts = pts - sh[0] * plane.row_cosine - sh[1] * plane.column_cosine
    hp = pose.to_heart(pts)
    roi_r = max(an.r_short_epi, an.r_free_endo * (1 + an.rv_offset) + an.rv_wall) + 25.0
    roi = (hp[:, 0] ** 2 + hp[:, 1] ** 2 < roi_r ** 2) & (hp[:, 2] > -25.0) & (hp[:, 2] < an.z_base + 45.0)
    return hp[roi], roi


def render_image(phantom, plane: ImagePlane, rng: np.random.Generator | None = None,
                 roi_points: tuple[np.ndarray, np.ndarray] | None = None,
                 sigma: float | None = None, tag_depth: float | None = None) -> np.ndarray:
    """Float image (rows, columns) of one plane at its frame, before 16-bit scaling.

    ``rng`` adds Rician noise of channel standard deviation ``sigma`` (default
    from the phantom's ``snr``); ``tag_depth`` the SPAMM depth at t = 0 (default
    the phantom's, 0.9; 0 gives an untagged image).

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        The phantom.
    plane : cardionurbs.imaging.geometry.ImagePlane
        The image plane (its frame).
    rng : numpy.random.Generator or None, optional
        The noise generator (None: no noise).
    roi_points : tuple of (ndarray, ndarray), optional
        :func:`pixel_heart_points` of the plane, when already computed.
    sigma : float or None, optional
        The channel noise σ, in signal units.
    tag_depth : float or None, optional
        SPAMM tag depth at t = 0, in [0, 1].

    Returns
    -------
    ndarray of float, shape (rows, columns)
        Signal (myocardium about 0.3).
    """
    an, mo, grid = phantom.anatomy, phantom.motion, phantom.tag_grid
    f = float(phantom.phases[plane.frame])
    hp, roi = roi_points if roi_points is not None else pixel_heart_points(phantom, plane)
    s, th, z, s1, s2, s3, s4, e = material_sections(an, mo, hp, f)
    r = np.sqrt(np.maximum(s, 0.0))
    x, y = r * e.real, r * e.imag          # r cos θ, r sin θ
    tm = tissue_masks(an, s, th, z, s1, s2, s3, s4, (x, y))
    if an.shape is None:
        # the ideal phantom's images as before: one atrial cap (30 mm) over the LV only
        u = (z - an.z_base) / 30.0
        atria = (u > 0) & (s < float(an.s_lv_endo(an.z_base)) * (1.0 - u * u))
    else:
        atria = tm["la"] | tm["ra"]
    blood = tm["lv_cav"] | tm["rv_cav"] | atria
    muscle = tm["lv_myo"] | tm["rv_myo"]
    if "papillary" in tm:
        blood &= ~(tm["papillary"] | tm["band"])
        muscle |= tm["papillary"] | tm["band"]
    img = np.full(len(z), BODY)
    img = np.where(muscle, MYO, img)
    img = np.where(blood, BLOOD, img)
    if an.shape is not None and an.shape.bends:
        # the tag planes are planes of the bent ED heart: n · (x + d(z)) (see annotate)
        dz = an.shape.apex_shift(z, an.z_base)
        x, y = x + dz[:, 0], y + dz[:, 1]
    # SPAMM modulation in material coordinates
    t_ms = plane.trigger_time or 0.0
    if tag_depth is None:
        tag_depth = float(phantom.config.get("tag_depth", TAG_DEPTH))
    depth = tag_depth * np.exp(-t_ms / T1_MS)
    sig = TAG_SIGMA_PX * plane.pixel_spacing[0]
    if plane.view == "SA":
        mod = np.ones_like(img)
        first = grid.sa_positions()[0]
        for fam in ("sa1", "sa2"):
            n = grid.sa_normal(fam)
            mod *= 1.0 - depth * _tag_band(x * n[0] + y * n[1], grid.spacing, first, sig)
    else:
        mod = 1.0 - depth * _tag_band(z, grid.spacing, grid.la_offset, sig)
    mod = np.where(blood, 1.0 - BLOOD_TAG * (1.0 - mod), mod)
    full = np.full(plane.rows * plane.columns, LUNG)
    full[roi] = img * mod
    img = full
    if rng is not None:
        if sigma is None:
            sigma = noise_sigma(phantom.config.get("snr"))
        # the real then the imaginary channel's noise (one draw of 2n standard normals: the same
        # numbers as two draws of n), and the magnitude |I + n_1 + i n_2|
        noise = rng.standard_normal(2 * img.size)
        noise *= sigma
        re = img + noise[:img.size]
        im = noise[img.size:]
        img = np.sqrt(re * re + im * im)
    return img.reshape(plane.rows, plane.columns)


def _ds(v: float) -> str:
    return format_number_as_ds(float(v))


def _rle_plugin() -> str:
    """The RLE encoder: pylibjpeg-rle (compiled, a dependency; ~30x faster) when importable, else
    pydicom's own pure-Python one. Both write the same bytes (PS3.5 Annex G is deterministic)."""
    from pydicom.pixels.encoders import RLELosslessEncoder
    return "pylibjpeg" if "pylibjpeg" in RLELosslessEncoder.available_plugins else "pydicom"


def _series_header(phantom, series: str, series_uid: str, series_number: int, levels: float) -> Dataset:
    """The data elements every image of one series has in common (patient, study, series,
    sequence, pixel format, display window), set once per series."""
    study, cfg = phantom.study, phantom.config
    rr = 60000.0 / study.heart_rate_bpm
    ds = Dataset()
    ds.SpecificCharacterSet = "ISO_IR 100"
    ds.ImageType = ["ORIGINAL", "PRIMARY", "M", "ND"]
    ds.SOPClassUID = MRImageStorage
    ds.StudyDate = ds.SeriesDate = ds.ContentDate = "20000101"
    ds.StudyTime = ds.SeriesTime = ds.ContentTime = "120000"
    ds.Modality = "MR"
    ds.Manufacturer = "cardionurbs phantom"
    ds.InstitutionName = "synthetic"
    ds.StudyDescription = f"cardionurbs phantom {cfg['pathology']}"
    ds.SeriesDescription = f"tagged cine {series}"
    ds.PatientName = study.subject
    ds.PatientID = study.subject
    ds.PatientSex = "O"
    ds.BodyPartExamined = "HEART"
    ds.ScanningSequence = "GR"
    ds.SequenceVariant = "SP"
    ds.ScanOptions = "CG"
    ds.MRAcquisitionType = "2D"
    ds.RepetitionTime = "5.2"
    ds.EchoTime = "1.82"
    ds.MagneticFieldStrength = "1.5"
    ds.FlipAngle = "45"
    ds.NominalInterval = str(int(round(rr)))
    ds.HeartRate = str(int(round(study.heart_rate_bpm)))
    ds.CardiacNumberOfImages = str(len(phantom.phases))
    ds.StudyInstanceUID = study.meta["study_uid"]
    ds.SeriesInstanceUID = series_uid
    ds.StudyID = "1"
    ds.SeriesNumber = str(series_number)
    ds.FrameOfReferenceUID = study.meta["frame_of_reference_uid"]
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated = 16
    ds.BitsStored = 12
    ds.HighBit = 11
    ds.PixelRepresentation = 0
    ds.WindowCenter = _ds(round(0.4 * levels, 1))       # myocardium to blood
    ds.WindowWidth = _ds(round(0.8 * levels, 1))
    return ds


def write_dicom(phantom, folder: str | Path, compression: str | None = "jpegls") -> list[Path]:
    """Write every image of the phantom's study under ``folder`` (paths = ImagePlane.file);
    ``compression``: ``"jpegls"`` (JPEG-LS Lossless, default), ``"rle"`` (RLE Lossless) or
    None (uncompressed). The grey-level step is matched to the noise (module docstring, 5).

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        The phantom.
    folder : path-like
        The study folder (files at ``ImagePlane.file``).
    compression : str or None, optional
        ``"jpegls"``, ``"rle"`` or None.

    Returns
    -------
    list of pathlib.Path
        The DICOM files written.
    """
    if compression not in COMPRESSIONS:
        raise ValueError(f"compression must be 'jpegls', 'rle' or None, got {compression!r}")
    folder = Path(folder)
    study = phantom.study
    cfg = phantom.config
    base = f"{cfg['pathology']}|{cfg['seed']}|{cfg['subject']}|{cfg['frames']}"
    series_uid: dict[str, str] = {}
    series_num = {"sa": 1, "la_2ch": 2, "la_3ch": 3, "la_4ch": 4}
    out = []
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    headers: dict[str, Dataset] = {}
    sigma = noise_sigma(cfg.get("snr"))
    levels = grey_levels_per_unit(sigma)
    for plane in study.images:
        series = Path(plane.file).parent.name
        if series not in series_uid:
            series_uid[series] = generate_uid(entropy_srcs=[study.meta["study_uid"], "series", series])
        rng = np.random.default_rng(np.random.SeedSequence(
            [cfg["seed"], plane.frame, int.from_bytes(plane.slice.encode()[:6].ljust(6, b"_"), "little")]))
        if plane.slice not in cache:
            cache[plane.slice] = pixel_heart_points(phantom, plane)
        img = render_image(phantom, plane, rng, cache[plane.slice], sigma=sigma)
        pix = np.clip(np.round(img * levels), 0, 4095).astype(np.uint16)
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = MRImageStorage
        meta.MediaStorageSOPInstanceUID = plane.id
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        meta.ImplementationClassUID = PYDICOM_IMPLEMENTATION_UID
        if series not in headers:
            headers[series] = _series_header(phantom, series, series_uid[series],
                                             series_num.get(series, 9), levels)
        # the series header's elements are shared by its images, never changed: every element
        # set below is new to the header
        ds = Dataset()
        ds.update(headers[series])
        ds.file_meta = meta
        ds.SOPInstanceUID = plane.id
        ds.SliceThickness = _ds(plane.thickness)
        ds.TriggerTime = _ds(plane.trigger_time or 0.0)
        ds.InstanceNumber = str(plane.frame + 1 + 100 * int(plane.slice[3:]) if plane.view == "SA"
                                else plane.frame + 1)
        ds.ImagePositionPatient = [_ds(v) for v in plane.position]
        ds.ImageOrientationPatient = [_ds(v) for v in plane.orientation]
        ds.SliceLocation = _ds(float(np.dot(plane.position, plane.normal)))
        ds.ImageComments = (f"slice {plane.slice} frame {plane.frame}; SPAMM tag spacing "
                            f"{cfg['tag_spacing_px']:g} px; {base}")
        ds.Rows, ds.Columns = plane.rows, plane.columns
        ds.PixelSpacing = [_ds(plane.pixel_spacing[0]), _ds(plane.pixel_spacing[1])]
        ds.PixelData = pix.tobytes()
        if compression == "jpegls":
            ds.compress(JPEGLSLossless, pix, encoding_plugin="pyjpegls", generate_instance_uid=False)
        elif compression == "rle":
            ds.compress(RLELossless, pix, encoding_plugin=_rle_plugin(), generate_instance_uid=False)
        path = folder / plane.file
        path.parent.mkdir(parents=True, exist_ok=True)
        ds.save_as(path, enforce_file_format=True)
        out.append(path)
    return out
