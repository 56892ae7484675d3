"""Generate a phantom study (Study + truth) and write it (native study, DICOM, truth.json).

Pipeline of :func:`generate`: preset → seeded draw (presets.sample_subject) →
ED anatomy solved to the draw (presets.solve_anatomy) → imaging planes
(geometry) → frame-aligned volume curve with ED = frame 0 and ES =
round(es_fraction · N) → motion whose twist amplitude is solved so that the
docs/metrics.md twist between the outermost tag levels equals the draw → contours,
landmarks and tag lines on every plane and frame (annotate) → faults → truth.

Everything random is drawn from numpy Generators seeded by (seed, pathology,
purpose), and DICOM UIDs are derived from the same inputs, so one seed gives
byte-identical output.
"""

from __future__ import annotations

import dataclasses
import json
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydicom.uid import generate_uid

from cardionurbs.errors import PhantomError
from cardionurbs.io import atomic
from cardionurbs.io.native import write_study
from cardionurbs.phantom import annotate, faults, regional, truth
from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.geometry import Acquisition, HeartPose, SliceSpec, image_plane, slice_specs
from cardionurbs.phantom.motion import Motion, VolumeCurve
from cardionurbs.phantom.presets import (PATHOLOGIES, SubjectDraw, SubjectSpec, load_preset,
                                         sample_subject, solve_anatomy)
from cardionurbs.phantom.outflow import draw_outflow
from cardionurbs.phantom.shape import (ANATOMIES, TERRITORIES, draw_shape, draw_tricuspid_dip,
                                       infarct_only)
from cardionurbs.study import Contour, Landmark, Study, TagLine

UID_PREFIX = "1.2.826.0.1.3680043.8.498."   # pydicom's registered root for generated UIDs
#: the acquisition faults of ``realism="clinical"``
CLINICAL = {"noise_px": 0.5, "breath_hold_mm": 1.5, "snr": 15.0}
SERIES = {"SA": "sa", "la_2ch": "la_2ch", "la_3ch": "la_3ch", "la_4ch": "la_4ch", "la_rvot": "la_rvot"}


@dataclass
class Phantom:
    """A generated phantom: the study, its truth and the analytic model behind them.

    Attributes
    ----------
    study : cardionurbs.study.Study
        The generated study (images, contours, tag lines, landmarks; scanner mm).
    truth : dict
        The analytic truth written as ``truth.json`` (``metrics`` in docs/metrics.md units,
        faults, tag levels, volumes).
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED geometry (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The analytic motion through the cycle.
    pose : cardionurbs.phantom.geometry.HeartPose
        Heart frame -> scanner frame (rotation and origin in mm).
    acquisition : cardionurbs.phantom.geometry.Acquisition
        Matrix, field of view and SA stack of the images.
    slices : list of cardionurbs.phantom.geometry.SliceSpec
        The SA and LA slices imaged.
    tag_grid : cardionurbs.phantom.annotate.TagGrid
        The SPAMM tag planes at ED.
    phases : ndarray, shape (frames,)
        The cycle phase f (0 at ED, 1 at ES) of every frame.
    es_frame : int
        The ES frame index, 0-based.
    draw : cardionurbs.phantom.presets.SubjectDraw
        The subject's drawn parameters.
    config : dict
        The :func:`generate` arguments that made it.
    shifts : dict of str to ndarray
        SA slice id -> its breath-hold in-plane shift (row, column), in mm.
    frame_times_ms : ndarray, shape (frames,)
        Every frame's time after the R wave, in ms.
    """

    study: Study
    truth: dict
    anatomy: Anatomy
    motion: Motion
    pose: HeartPose
    acquisition: Acquisition
    slices: list[SliceSpec]
    tag_grid: annotate.TagGrid
    phases: np.ndarray
    es_frame: int
    draw: SubjectDraw
    config: dict
    shifts: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def frame_times_ms(self) -> np.ndarray:
        return np.array([self.study.frame_times_ms[k] for k in range(len(self.phases))])

    def deformation_gradient(self, points: np.ndarray, frame: int) -> np.ndarray:
        """F (n, 3, 3) of the exact motion from ED to ``frame`` at ED points (n, 3, scanner mm):
        :func:`cardionurbs.phantom.regional.deformation_gradient` in the heart frame (the
        realistic apex bend is part of its map), turned into the scanner frame, R F Rᵀ.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Material points at ED, in scanner mm.
        frame : int
            The frame index, 0-based.

        Returns
        -------
        ndarray, shape (n, 3, 3)
            The deformation gradient F = ∂x/∂X in scanner axes (dimensionless).
        """
        from cardionurbs.phantom import regional
        R = self.pose.rotation
        X = (np.asarray(points, dtype=float).reshape(-1, 3) - self.pose.origin) @ R
        return R @ regional.deformation_gradient(self.anatomy, self.motion, X,
                                                 float(self.phases[frame])) @ R.T


def _rng(seed: int, pathology: str, purpose: str) -> np.random.Generator:
    entropy = [int(seed), PATHOLOGIES.index(pathology) if pathology in PATHOLOGIES else 9,
               zlib.crc32(purpose.encode())]
    return np.random.default_rng(np.random.SeedSequence(entropy))


def _check_args(pathology, seed, frames, noise_px, tag_jumps, breath_hold_mm) -> None:
    if not isinstance(pathology, str) or pathology not in PATHOLOGIES:
        raise PhantomError(f"unknown pathology {pathology!r}; expected one of {', '.join(PATHOLOGIES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise PhantomError(f"seed must be a whole number >= 0, got {seed!r}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise PhantomError(f"frames must be a whole number >= 2 (ED and ES), got {frames!r}")
    if not (np.isfinite(noise_px) and noise_px >= 0):
        raise PhantomError(f"noise_px must be a finite number >= 0, got {noise_px!r}")
    if isinstance(tag_jumps, bool) or not isinstance(tag_jumps, (int, np.integer)) or tag_jumps < 0:
        raise PhantomError(f"tag_jumps must be a whole number >= 0, got {tag_jumps!r}")
    if not (np.isfinite(breath_hold_mm) and breath_hold_mm >= 0):
        raise PhantomError(f"breath_hold_mm must be a finite number >= 0, got {breath_hold_mm!r}")


def _realistic_anatomy(draw: SubjectDraw, rng: np.random.Generator, infarct: str | None,
                       tries: int = 20, outflow=None, tricuspid_dip: float = 0.0):
    """A realistic anatomy for the draw: shape modes drawn from ``rng`` until the solved anatomy
    passes its validation (one RV crescent per section, nested walls) -- deterministic per seed,
    as the draws come from the subject's own generator. ``outflow``: OutflowTracts to add (the
    sizes are then solved with the tracts' lumen and wall counted)."""
    last = None
    for _ in range(tries):
        shape = dataclasses.replace(draw_shape(rng, infarct), tricuspid_dip_mm=tricuspid_dip)
        if outflow is not None:
            shape = dataclasses.replace(shape, outflow=outflow)
        try:
            return solve_anatomy(draw, shape), shape
        except PhantomError as exc:
            last = exc
    raise PhantomError(f"no valid realistic anatomy in {tries} draws ({last})")


def _twist_motion(anatomy: Anatomy, draw: SubjectDraw, curve: VolumeCurve, specs, grid, f_es) -> Motion:
    """Motion whose level-based twist at ES equals the drawn twist (linear ψ(z), eq. M2)."""
    v = draw.values
    pm = draw.predicted_metrics()
    eps = (v["ei_es"] ** 2 - 1.0) / (v["ei_es"] ** 2 + 1.0)
    kw = dict(ls=v["ls_pct"] / 100.0, lv_ef=v["lvef_pct"] / 100.0, rv_ef=pm["RVEF (%)"] / 100.0,
              septal_flattening=eps, z_base=anatomy.z_base, curve=curve)
    if anatomy.outflow is not None:
        # the tracts rise above the LV walls: they turn with the highest point of the annulus
        kw["z_twist_max"] = anatomy.z_base + anatomy.shape.saddle_mm
    probe = Motion(apex_rotation_deg=0.0, base_rotation_deg=0.0, **kw)
    levels = truth.tag_levels(anatomy, probe, grid, specs, f_es)
    if len(levels) < 2:
        raise PhantomError("fewer than two LA tag levels lie between the tagged SA slices; "
                           "use more SA slices or a smaller sa_spacing_mm")
    span = (levels[-1]["distance_from_apex_mm"] - levels[0]["distance_from_apex_mm"]) / anatomy.z_base
    total = v["twist_deg"] / (f_es * span)
    share = v["base_rotation_share"]
    return Motion(apex_rotation_deg=(1 - share) * total, base_rotation_deg=-share * total, **kw)


def generate(pathology: str = "normal", seed: int = 0, frames: int = 20, noise_px: float = 0.0,
             tag_jumps: int = 0, sa_spacing_mm: float = 10.0, sa_thickness_mm: float = 8.0,
             n_sa: int | None = None, breath_hold_mm: float = 0.0, subject: str | None = None,
             tag_spacing_px: float = 7.0, fov_mm: float = 300.0, matrix: int = 256,
             volume_check: bool = True, anatomy: dict | None = None, snr: float | None = None,
             tag_depth: float | None = None, anatomy_model: str = "ideal", infarct: str | None = None,
             realism: str | None = None, outflow: bool | None = None) -> Phantom:
    """Generate one phantom subject (a bad argument: :class:`~cardionurbs.errors.PhantomError`).

    Parameters
    ----------
    pathology : ``"normal"``, ``"mr"`` or ``"phtn"`` (packaged preset, ``cardionurbs/data/<name>.toml``).
    seed : subject variability and fault seed (same seed → identical output).
    frames : cardiac phases N >= 2 over one RR interval; frame 0 = ED.
    noise_px, tag_jumps, breath_hold_mm : faults (see :mod:`cardionurbs.phantom.faults`).
    sa_spacing_mm, sa_thickness_mm, n_sa : SA stack (n_sa None = cover base to apex).
    tag_spacing_px, fov_mm, matrix : SPAMM tag spacing (px; 7 in the paper), field of view (mm), px a side.
    subject : the study's subject id (default ``<pathology>_<seed, 3 digits>``).
    volume_check : also compute the method-B mesh volumes at ED and ES into the truth.
    snr : image SNR of the tagged DICOM (myocardium over the Rician channel noise σ; default 12).
    tag_depth : SPAMM tag depth at t = 0 in (0, 1] (default 0.9; 0 writes untagged images).
    anatomy : overrides of the solved ED geometry (Anatomy field -> mm, e.g. ``{"r_short_endo": 30.0}``);
        the truth follows them (the preset's target ranges then no longer apply).
    anatomy_model : ``"ideal"`` (spheroids) or ``"realistic"`` (shape modes, segmental walls, varying RV,
        saddle annuli, bent apex, outflow tracts; drawn from the seed, :mod:`cardionurbs.phantom.shape`).
    infarct : ``"lad"``, ``"rca"`` or ``"lcx"``: that coronary territory thinner and hypokinetic.
    realism : ``"clinical"``: 0.5 px contour noise, 1.5 mm breath-hold shifts, image SNR 15 at once
        (each unless given explicitly); the truth is unchanged.
    outflow : RV and LV outflow tracts to pulmonary and aortic valves (:mod:`cardionurbs.phantom.outflow`),
        their ``la_rvot`` view, ``rv_outlet`` contours, landmarks and truth; ``None``: on for the
        realistic anatomy only; ``True`` with the ideal anatomy is an error.

    Returns
    -------
    Phantom
        The study, its truth and the analytic model.
    """
    _check_args(pathology, seed, frames, noise_px, tag_jumps, breath_hold_mm)
    outflow = _check_options(snr, tag_depth, anatomy_model, infarct, outflow, realism)
    if realism == "clinical":
        noise_px = noise_px or CLINICAL["noise_px"]
        breath_hold_mm = breath_hold_mm or CLINICAL["breath_hold_mm"]
        snr = snr if snr is not None else CLINICAL["snr"]
    frames, seed, tag_jumps = int(frames), int(seed), int(tag_jumps)
    draw = sample_subject(load_preset(pathology), _rng(seed, pathology, "subject"))
    overrides = anatomy                                 # the argument: Anatomy field -> mm
    solved = _subject_anatomy(draw, seed, pathology, anatomy_model, infarct, outflow, overrides)
    acq = Acquisition(rows=matrix, columns=matrix, fov_mm=fov_mm, sa_spacing_mm=sa_spacing_mm,
                      sa_thickness_mm=sa_thickness_mm, n_sa=n_sa)
    if not (np.isfinite(tag_spacing_px) and tag_spacing_px > 0):
        raise PhantomError(f"tag_spacing_px must be positive, got {tag_spacing_px!r}")
    specs = slice_specs(solved, acq)
    es_frame = int(min(max(round(draw.values["es_fraction"] * frames), 1), frames - 1))
    curve = VolumeCurve(es_fraction=es_frame / frames)
    phases = curve(np.arange(frames) / frames)
    f_es = float(phases[es_frame])
    grid = annotate.make_tag_grid(solved, tag_spacing_px * acq.pixel_mm)
    motion = _twist_motion(solved, draw, curve, specs, grid, f_es)
    pose = HeartPose.default(solved.z_base, bend=solved.shape if solved.shape is not None and solved.shape.bends
                             else None)
    hr = float(round(draw.values["heart_rate_bpm"]))   # integer bpm, as DICOM HeartRate (IS)
    rr = 60000.0 / hr
    times = {k: round(k * rr / frames, 3) for k in range(frames)}
    subject = subject or f"{pathology}_{seed:03d}"
    config = dict(pathology=pathology, seed=seed, frames=frames, noise_px=float(noise_px),
                  anatomy_overrides=dict(sorted((overrides or {}).items())),
                  tag_jumps=tag_jumps, sa_spacing_mm=float(sa_spacing_mm),
                  sa_thickness_mm=float(sa_thickness_mm), n_sa=n_sa, breath_hold_mm=float(breath_hold_mm),
                  tag_spacing_px=float(tag_spacing_px), fov_mm=float(fov_mm), matrix=int(matrix),
                  subject=subject)
    config.update(_image_options(snr, anatomy_model, infarct, realism, outflow, tag_depth))
    uid = _uid_maker(json.dumps(config, sort_keys=True))
    shifts = faults.breath_hold_offsets([s.id for s in specs if s.view == "SA"], breath_hold_mm,
                                        _rng(seed, pathology, "breath-hold"))
    study = Study(subject=subject, frame_times_ms={k: float(t) for k, t in times.items()},
                  heart_rate_bpm=float(hr), ed_frame=0, es_frame=es_frame, source=None,
                  meta={"generator": "cardionurbs.phantom", "pathology": pathology, "seed": seed,
                        "study_uid": uid("study"), "frame_of_reference_uid": uid("for")})
    scene = _Scene(solved, motion, grid, pose, acq, phases, times, shifts, uid)
    _annotate(study, scene, specs)
    jumps = faults.inject_tag_jumps(study, tag_jumps, _rng(seed, pathology, "tag-jumps"))
    dropped = faults.add_noise(study, float(noise_px), _rng(seed, pathology, "noise"))
    metrics, tag_truth = _truth_metrics(solved, motion, grid, specs, phases, es_frame, hr, len(jumps))
    faults_done = {"noise_px": float(noise_px), "tag_jumps": jumps,
                   **({"contours_left_out": dropped} if dropped else {}),
                   "breath_hold_mm": float(breath_hold_mm),
                   "breath_hold_shifts_mm": ({k: [float(x) for x in v] for k, v in shifts.items()}
                                             if breath_hold_mm > 0 else {})}
    tr = _truth_record({"format": "cardionurbs-phantom-truth", "version": 1, "subject": subject,
                        "pathology": pathology, "seed": seed, "ed_frame": 0, "es_frame": es_frame,
                        "metrics": metrics, "tags": tag_truth}, scene, specs, anatomy_model,
                       draw, faults_done)
    if volume_check:
        tr["volumes"] = truth.volume_table(solved, motion, phases, [0, es_frame])
    study.meta["truth"] = "truth.json"
    study.meta["tag_planes"] = tag_planes_scanner(grid, pose, solved)
    tr["imaging"] = _imaging_record(config)
    return Phantom(study=study, truth=_json_safe(tr), anatomy=solved, motion=motion, pose=pose,
                   acquisition=acq, slices=specs, tag_grid=grid, phases=phases, es_frame=es_frame,
                   draw=draw, config=config, shifts=shifts)


def _check_options(snr: float | None, tag_depth: float | None, anatomy_model: str,
                   infarct: str | None, outflow: bool | None, realism: str | None) -> bool:
    """Check :func:`generate`'s image and anatomy options (:class:`PhantomError` naming the
    option); returns ``outflow`` resolved (None: on for the realistic anatomy only)."""
    if snr is not None and not (isinstance(snr, (int, float, np.floating)) and np.isfinite(snr)
                                and snr > 0):
        raise PhantomError(f"snr must be a finite number > 0, got {snr!r}")
    if tag_depth is not None and not (isinstance(tag_depth, (int, float, np.floating))
                                      and 0.0 <= tag_depth <= 1.0):
        raise PhantomError(f"tag_depth must be a number in [0, 1], got {tag_depth!r}")
    if anatomy_model not in ANATOMIES:
        raise PhantomError(f"unknown anatomy {anatomy_model!r}; expected one of {', '.join(ANATOMIES)}")
    if infarct is not None and infarct not in TERRITORIES:
        raise PhantomError(f"unknown infarct territory {infarct!r}; expected one of {', '.join(TERRITORIES)}")
    if outflow is None:
        outflow = anatomy_model == "realistic"
    if outflow and anatomy_model != "realistic":
        raise PhantomError("outflow tracts need the realistic anatomy (anatomy_model='realistic')")
    if realism not in (None, "clinical"):
        raise PhantomError(f"unknown realism {realism!r}; expected 'clinical'")
    return bool(outflow)


def _subject_anatomy(draw: SubjectDraw, seed: int, pathology: str, anatomy_model: str,
                     infarct: str | None, outflow: bool, overrides: dict | None) -> Anatomy:
    """The subject's ED anatomy: solved to the draw (ideal), or with its shape modes, tracts
    and tricuspid saddle drawn from their own generators (realistic); then ``overrides``
    (Anatomy field -> mm) applied."""
    shape = None
    if anatomy_model == "realistic":
        tracts = draw_outflow(_rng(seed, pathology, "outflow")) if outflow else None
        # the saddle-shaped tricuspid annulus, from its own generator (with or without the tracts)
        dip = draw_tricuspid_dip(_rng(seed, pathology, "tricuspid"))
        anatomy, shape = _realistic_anatomy(draw, _rng(seed, pathology, "shape"), infarct, outflow=tracts,
                                            tricuspid_dip=dip)
    else:
        if infarct is not None:
            shape = infarct_only(infarct)
        anatomy = solve_anatomy(draw, shape)
    if overrides:
        unknown = sorted(set(overrides) - set(Anatomy.__dataclass_fields__))
        if unknown:
            raise PhantomError(f"unknown anatomy parameter {unknown[0]!r}; expected one of "
                               f"{', '.join(Anatomy.__dataclass_fields__)}")
        try:
            fields = {**anatomy.to_dict(), **{k: float(v) for k, v in overrides.items()}}
        except (TypeError, ValueError):
            raise PhantomError("anatomy parameters must be numbers (mm)") from None
        anatomy = Anatomy(**fields, shape=shape).validate()
    return anatomy


def _image_options(snr: float | None, anatomy_model: str, infarct: str | None,
                   realism: str | None, outflow: bool, tag_depth: float | None) -> dict:
    """The options that enter the config (and so the UIDs) only when set, so that phantoms
    written before they existed keep their UIDs."""
    out: dict = {}
    if snr is not None:
        out["snr"] = float(snr)
    if anatomy_model != "ideal":
        out["anatomy_model"] = anatomy_model
    if infarct is not None:
        out["infarct"] = infarct
    if realism is not None:
        out["realism"] = realism
    if outflow:
        out["outflow"] = True
    if tag_depth is not None:
        out["tag_depth"] = float(tag_depth)
    return out


def _uid_maker(uid_base: str) -> Callable[..., str]:
    """The DICOM UID of (config, *parts): the same inputs give the same UID."""
    def uid(*parts) -> str:
        return generate_uid(prefix=UID_PREFIX, entropy_srcs=[uid_base, *map(str, parts)])
    return uid


@dataclass
class _Scene:
    """What annotating every plane and frame needs: the analytic heart, its pose and imaging."""

    anatomy: Anatomy
    motion: Motion
    grid: annotate.TagGrid
    pose: HeartPose
    acq: Acquisition
    phases: np.ndarray          #: (frames,) cardiac phase per frame
    times: dict                 #: frame -> trigger time, ms
    shifts: dict                #: SA slice id -> breath-hold in-plane shift, mm
    uid: Callable[..., str]     #: (*parts) -> DICOM UID


def _annotate(study: Study, scene: _Scene, specs: list[SliceSpec]) -> None:
    """Image planes, contours, tag lines and landmarks of every plane and frame, into ``study``."""
    anatomy, motion, phases = scene.anatomy, scene.motion, scene.phases
    frames = len(phases)
    # every SA plane's material height at every frame: the RV sectors there in one call
    anatomy.prime_rv_sectors([annotate.sa_material_height(motion, s, float(f))
                              for s in specs if s.view == "SA" for f in phases])
    # the realistic LA contours of every view at once per frame (their exact refinements share
    # one evaluation of the region functions per step; the same contours as view by view)
    la_views = [(s, s.id in ("la_4ch", "la_rvot"), s.id != "la_rvot") for s in specs if s.view != "SA"]
    la_done = {}
    if anatomy.realistic and la_views:
        for k in range(frames):
            for sid, cont in annotate.la_contours_realistic_views(anatomy, motion, la_views,
                                                                  float(phases[k])).items():
                la_done[sid, k] = cont
    for spec in specs:
        for k in range(frames):
            _annotate_plane(study, scene, spec, k, la_done.get((spec.id, k)))
    for k in range(frames):
        for name, pts in annotate.landmarks(anatomy, motion, float(phases[k])).items():
            for i, p in enumerate(scene.pose.to_scanner(pts)):
                study.landmarks.append(Landmark(name, k, p, index=i))


def _annotate_plane(study: Study, scene: _Scene, spec: SliceSpec, k: int, la_cont: dict | None) -> None:
    """The image plane of ``spec`` at frame ``k`` with its contours, tag lines and (SA) RV
    insertion points, into ``study``; ``la_cont``: the LA contours when already made."""
    anatomy, motion, grid, pose = scene.anatomy, scene.motion, scene.grid, scene.pose
    series = SERIES["SA"] if spec.view == "SA" else SERIES[spec.id]
    f = float(scene.phases[k])
    plane = image_plane(spec, pose, scene.acq, k, scene.uid("image", spec.id, k), scene.times[k],
                        file=f"dicom/{series}/{spec.id}_{k:02d}.dcm")
    study.images.append(plane)
    shift = np.zeros(3)
    if spec.id in scene.shifts:
        shift = scene.shifts[spec.id][0] * plane.row_cosine + scene.shifts[spec.id][1] * plane.column_cosine

    def scan(p):
        return pose.to_scanner(p) + shift

    step = scene.acq.pixel_mm
    if spec.view == "SA":
        cont = annotate.sa_contours(anatomy, motion, spec, f)
        for name in ("lv_endo", "lv_epi", "rv_endo", "rv_epi", "rv_outlet"):
            if name in cont:
                study.contours.append(Contour(name, "SA", spec.id, k, scan(cont[name]),
                                              image=plane.id, closed=True))
        tags = annotate.sa_tag_lines(anatomy, motion, grid, spec, f, step)
        ins = annotate.rv_insertion_points(anatomy, motion, spec, f)
        if ins is not None:
            for i, p in enumerate(scan(ins)):
                study.landmarks.append(Landmark("rv_insert", k, p, index=i, slice=spec.id,
                                                view="SA", image=plane.id))
    else:
        cont = la_cont if la_cont is not None else annotate.la_contours(
            anatomy, motion, spec, f, with_rv=spec.id in ("la_4ch", "la_rvot"),
            with_lv=spec.id != "la_rvot")
        for name in ("lv_endo", "lv_epi", "rv_endo", "rv_epi"):
            if name in cont:
                study.contours.append(Contour(name, "LA", spec.id, k, scan(cont[name]),
                                              image=plane.id, closed=False))
        # the RVOT view carries RV contours only (no LV tag lines)
        tags = ([] if spec.id == "la_rvot"
                else annotate.la_tag_lines(anatomy, motion, grid, spec, f, step))
    for fam, idx, pts in tags:
        study.tags.append(TagLine(fam, idx, spec.view, spec.id, k, scan(pts), image=plane.id))


def _truth_metrics(anatomy: Anatomy, motion: Motion, grid: annotate.TagGrid, specs: list[SliceSpec],
                   phases: np.ndarray, es_frame: int, hr: float, n_jumps: int) -> tuple[dict, dict]:
    """The truth's metrics (global, filling rates, wall thickness, strain, surface strain) and
    its tag record, all from the analytic model."""
    frames = len(phases)
    f_es = float(phases[es_frame])
    rr = 60000.0 / hr
    metrics, tag_truth = truth.compute_metrics(anatomy, motion, grid, specs, phases, es_frame, float(hr),
                                               n_jumps)
    if anatomy.realistic:
        # filling rates from the numerical volume curve (and surface strain, both anatomies' way)
        metrics.update(regional.realistic_regional_truth(anatomy, motion, specs, frames, es_frame, rr))
    else:
        metrics.update(regional.filling_rate_truth(anatomy, motion, frames, es_frame, rr))
    metrics.update(regional.wall_thickness_truth(anatomy, motion, specs, f_es))
    strain = regional.strain_truth(anatomy, motion, specs,
                                   truth.strain_levels(anatomy, motion, grid, specs, f_es), f_es)
    metrics.update(strain["columns"])
    surface = regional.surface_strain_truth(anatomy, motion, specs, f_es)
    metrics.update(surface)
    tag_truth["det_F_es"] = strain["det_F"]
    return metrics, tag_truth


def _truth_record(head: dict, scene: _Scene, specs: list[SliceSpec], anatomy_model: str,
                  draw: SubjectDraw, faults_done: dict) -> dict:
    """The truth record: ``head`` (format, subject, ED/ES, metrics, tags), then the analytic
    model — motion (with phase and λ per frame), anatomy, pose —, the draw, acquisition,
    faults and the slices (SA height, LA azimuth), in the order truth.json keeps."""
    anatomy, motion, phases = scene.anatomy, scene.motion, scene.phases
    return {**head,
            "motion": {**motion.to_dict(), "phase_per_frame": [float(x) for x in phases],
                       "lambda_per_frame": [float(x) for x in motion.lam(phases)]},
            "anatomy": ({**anatomy.to_dict(), "model": anatomy_model, "shape": anatomy.shape_dict()}
                        if anatomy.shape is not None else anatomy.to_dict()),
            "pose": scene.pose.to_dict(), "draw": draw.values,
            "acquisition": dataclasses.asdict(scene.acq), "faults": faults_done,
            "slices": {s.id: ({"height_mm": s.height} if s.view == "SA"
                              else {"azimuth_deg": float(np.degrees(s.azimuth))}) for s in specs}}


def tag_planes_scanner(grid: annotate.TagGrid, pose: HeartPose, anatomy: Anatomy) -> dict:
    """The SPAMM tag planes at ED in scanner mm, per family: unit ``normal``, ``spacing_mm``
    and ``index0_mm`` — plane ``i`` of the family is {X : normal · X = index0_mm + i spacing_mm}.

    This is what the scanner protocol knows (spacing, orientation, where the grid starts);
    the tag tracker cross-checks the images against it and takes its index labels from it.

    Parameters
    ----------
    grid : cardionurbs.phantom.annotate.TagGrid
        The tag grid (heart frame).
    pose : cardionurbs.phantom.geometry.HeartPose
        Heart frame -> scanner frame.
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy.

    Returns
    -------
    dict
        Family (``"sa1"``, ``"sa2"``, ``"la"``) -> ``{"normal": 3 numbers, "spacing_mm",
        "index0_mm"}`` (mm).
    """
    out = {}
    for fam in ("sa1", "sa2", "la"):
        n_heart = grid.sa_normal(fam) if fam != "la" else np.array([0.0, 0.0, 1.0])
        first = float(grid.sa_positions()[0]) if fam != "la" else float(grid.la_offset)
        n = pose.direction_to_scanner(n_heart)
        out[fam] = {"normal": [float(v) for v in n], "spacing_mm": float(grid.spacing),
                    "index0_mm": float(first + n @ pose.origin)}
    return out


def _imaging_record(config: dict) -> dict:
    from cardionurbs.phantom import dicom as _d
    return {"snr": config.get("snr", _d.MYO / _d.NOISE), "noise_sigma": _d.noise_sigma(config.get("snr")),
            "tag_depth": config.get("tag_depth", _d.TAG_DEPTH), "tag_t1_ms": _d.T1_MS,
            "signal": {"blood": _d.BLOOD, "myocardium": _d.MYO, "mediastinum": _d.BODY,
                       "lung": _d.LUNG}}


def _json_safe(obj):
    """Floats as Python floats, NaN/inf as None, numpy scalars/arrays converted."""
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def write_phantom(phantom: Phantom, out_dir: str | Path, dicom: bool = True,
                  labels: str | None = None, label_quirks: str | None = None) -> Path:
    """Write the native study (study.json + points.csv, or points.parquet for a large study),
    dicom/ and truth.json into ``out_dir``;
    with ``labels`` (``acdc``, ``ukbb``, ``mnms``, ``mnms2``) also NIfTI label maps in that
    layout in ``out_dir/labelmaps``, with the header ``label_quirks`` (e.g. ``"real"``,
    :mod:`cardionurbs.phantom.labelmaps`).

    The folder is replaced atomically; the same phantom gives byte-identical files.

    Parameters
    ----------
    phantom : Phantom
        The phantom.
    out_dir : path-like
        The study folder (replaced atomically).
    dicom : bool, optional
        Write the synthetic DICOM images.
    labels : str or None, optional
        A label-map layout: ``"acdc"``, ``"ukbb"``, ``"mnms"``, ``"mnms2"``.
    label_quirks : str or None, optional
        Header quirks of the label maps (:func:`cardionurbs.phantom.labelmaps.parse_quirks`).

    Returns
    -------
    pathlib.Path
        ``out_dir``.
    """
    out_dir = Path(out_dir)
    study = phantom.study
    if not dicom:
        study = dataclasses.replace(study, images=[dataclasses.replace(im, file=None)
                                                   for im in study.images])
    with atomic.atomic_dir(out_dir, marker=atomic.STUDY_MARKER) as tmp:   # a study, not an output
        write_study(study, tmp)
        atomic.write_text(tmp / "truth.json", json.dumps(phantom.truth, indent=1, allow_nan=False) + "\n")
        if dicom:
            from cardionurbs.phantom.dicom import write_dicom
            write_dicom(phantom, tmp)
        if labels is not None:
            from cardionurbs.phantom.labelmaps import write_labelmaps
            write_labelmaps(phantom, tmp / "labelmaps", labels, quirks=label_quirks)
    return out_dir


def generate_cohort(subjects: list[SubjectSpec], out_dir: str | Path, dicom: bool = True,
                    noise_px: float = 0.0, tag_jumps: int = 0, report=None, **kw) -> list[Path]:
    """Generate and write every subject of a cohort spec into ``out_dir/<id>``.

    ``noise_px`` and ``tag_jumps`` apply to subjects whose spec sets none; ``report`` (optional
    callable) receives (path, phantom) after each subject is written.

    Parameters
    ----------
    subjects : list of cardionurbs.phantom.presets.SubjectSpec
        The cohort spec's subjects.
    out_dir : path-like
        The cohort folder.
    dicom : bool, optional
        Write the synthetic DICOM images.
    noise_px : float, optional
        Contour and tag noise σ in pixels, for subjects that set none.
    tag_jumps : int, optional
        Tag jumps, for subjects that set none.
    report : callable, optional
        ``report(path, phantom)``, after each subject is written.
    **kw
        Further :func:`generate` keywords.

    Returns
    -------
    list of pathlib.Path
        The subject folders written.
    """
    out_dir = Path(out_dir)
    paths = []
    for s in subjects:
        ph = generate(s.pathology, seed=s.seed, frames=s.frames, noise_px=s.noise_px or noise_px,
                      tag_jumps=s.tag_jumps or tag_jumps, breath_hold_mm=s.breath_hold_mm,
                      subject=s.id, **kw)
        paths.append(write_phantom(ph, out_dir / s.id, dicom=dicom))
        if report is not None:
            report(paths[-1], ph)
    return paths
