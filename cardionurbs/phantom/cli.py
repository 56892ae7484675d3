"""``cardionurbs phantom``: write one phantom study, or a cohort of them (one folder per subject)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from cardionurbs.errors import PhantomError
from cardionurbs.phantom.generate import generate, generate_cohort, write_phantom
from cardionurbs.phantom.presets import SubjectSpec, load_cohort_spec


def run_phantom(args: argparse.Namespace) -> int:
    """Run the ``phantom`` command (args: pathology, cohort, seed, frames, noise_px, tag_jumps,
    breath_hold_mm, snr, no_dicom, out). Exactly one of --pathology and --cohort is required.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``phantom`` command line.

    Returns
    -------
    int
        The exit code: 0, or 3 when a subject of a ``--cohort --n`` mix failed.

    Raises
    ------
    cardionurbs.errors.PhantomError
        Conflicting or incomplete options (checked before anything is written).
    cardionurbs.errors.OutputError
        ``--out`` may not be written.
    """
    if bool(args.pathology) == bool(args.cohort):
        raise PhantomError("phantom: give exactly one of --pathology and --cohort")
    if getattr(args, "label_quirks", None):
        from cardionurbs.phantom.labelmaps import parse_quirks
        parse_quirks(args.label_quirks)               # refused before anything is written
        if not getattr(args, "labels", None):
            raise PhantomError("phantom: --label-quirks needs --labels LAYOUT")
    n = getattr(args, "n", None)
    if n is not None and not args.cohort:
        raise PhantomError("phantom: --n needs --cohort SPEC (the mix to draw from)")
    if getattr(args, "resume", False) and n is None:
        raise PhantomError("phantom: --resume goes with --cohort SPEC --n N")
    from cardionurbs.io.outputs import STUDY_MARKER, check_output_dir
    out = check_output_dir(args.out, inputs=[args.cohort] if args.cohort else [],
                           marker=STUDY_MARKER,
                           overwrite=getattr(args, "overwrite", False)
                           or (n is not None and getattr(args, "resume", False)))
    dicom = not args.no_dicom
    shape = anatomy_options(args)
    if args.pathology:
        ph = generate(args.pathology, seed=args.seed, frames=args.frames, noise_px=args.noise_px,
                      tag_jumps=args.tag_jumps,
                      breath_hold_mm=getattr(args, "breath_hold_mm", 0.0),
                      snr=getattr(args, "snr", None), **shape)
        write_phantom(ph, out, dicom=dicom, labels=getattr(args, "labels", None),
                      label_quirks=getattr(args, "label_quirks", None))
        print(f"{out}: {ph.study.summary()}", file=sys.stdout)
        return 0
    if getattr(args, "labels", None) or getattr(args, "label_quirks", None):
        raise PhantomError("phantom: --labels applies to one --pathology subject, not a --cohort")
    from cardionurbs.io.atomic import atomic_dir
    spec = load_cohort_spec(args.cohort)
    extra = {"snr": args.snr} if getattr(args, "snr", None) is not None else {}
    extra.update(shape)
    if getattr(args, "n", None) is not None:
        return _run_mix(args, spec, out, dicom, extra)
    with atomic_dir(out, STUDY_MARKER) as tmp:  # the whole cohort, or the previous output
        generate_cohort(spec, tmp, dicom=dicom, noise_px=args.noise_px, tag_jumps=args.tag_jumps,
                        **extra,
                        report=lambda path, ph: print(f"{out / path.name}: {ph.study.summary()}",
                                                      file=sys.stdout))
    return 0


def anatomy_options(args: argparse.Namespace) -> dict:
    """generate() keywords of --anatomy, --infarct, --realism and --[no-]outflow (only those
    given, so that older callers' phantoms stay byte-identical; generate() decides the tracts'
    default from the anatomy).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``phantom`` command line.

    Returns
    -------
    dict
        :func:`~cardionurbs.phantom.generate.generate` keywords: ``anatomy_model``,
        ``infarct``, ``realism``, ``outflow``, ``sa_spacing_mm``, ``sa_thickness_mm`` (mm).
    """
    out = {}
    if getattr(args, "anatomy", "ideal") not in (None, "ideal"):
        out["anatomy_model"] = args.anatomy
    if getattr(args, "infarct", None):
        out["infarct"] = args.infarct
    if getattr(args, "realism", None):
        out["realism"] = args.realism
    if getattr(args, "outflow", None) is not None:
        out["outflow"] = bool(args.outflow)
    for opt, kw in (("sa_spacing", "sa_spacing_mm"), ("sa_thickness", "sa_thickness_mm")):
        if getattr(args, opt, None) is not None:
            out[kw] = float(getattr(args, opt))
    return out


# ------------------------------------------------------------------ --n: a mix at scale
#: seed step between rounds of a cohort mix (subject k uses its template's seed + round * step)
SEED_STEP = 100_000


def mix_subjects(spec: list[SubjectSpec], n: int) -> list[SubjectSpec]:
    """``n`` subjects drawn from a cohort spec used as a mix: subject k takes the spec's
    subject k mod m (m subjects) as its template -- pathology, frames, faults -- with seed
    template.seed + (k div m) * SEED_STEP and id ``<template id>`` in the first round,
    ``<template id>_r<round>`` after it. Subject k is the same whatever ``n``, and the
    first m subjects are the spec's own.

    Parameters
    ----------
    spec : list of cardionurbs.phantom.presets.SubjectSpec
        The mix's template subjects.
    n : int
        Subjects wanted, >= 1.

    Returns
    -------
    list of cardionurbs.phantom.presets.SubjectSpec
        The ``n`` subjects.

    Raises
    ------
    cardionurbs.errors.PhantomError
        ``n`` < 1.
    """
    if n < 1:
        raise PhantomError(f"--n must be >= 1, got {n}")
    m = len(spec)
    out = []
    for k in range(n):
        t, r = spec[k % m], k // m
        out.append(dataclasses.replace(t, seed=t.seed + r * SEED_STEP,
                                       id=t.id if r == 0 else f"{t.id}_r{r}"))
    return out


def generate_subject(subject: SubjectSpec, out_dir: str, dicom: bool, noise_px: float,
                     tag_jumps: int, extra: dict) -> dict:
    """Generate and write one subject into ``out_dir/<id>`` (a worker task): a summary row.

    Parameters
    ----------
    subject : cardionurbs.phantom.presets.SubjectSpec
        The subject (its own noise and tag jumps win over the command's).
    out_dir : str
        The cohort folder.
    dicom : bool
        Write synthetic DICOM images too.
    noise_px : float
        Contour and tag noise σ, in pixels.
    tag_jumps : int
        Tag jumps injected.
    extra : dict
        Further :func:`~cardionurbs.phantom.generate.generate` keywords (``snr``, anatomy).

    Returns
    -------
    dict
        ``subject``, ``status`` (``"ok"``), ``path`` and ``summary``.
    """
    ph = generate(subject.pathology, seed=subject.seed, frames=subject.frames,
                  noise_px=subject.noise_px or noise_px, tag_jumps=subject.tag_jumps or tag_jumps,
                  breath_hold_mm=subject.breath_hold_mm, subject=subject.id, **extra)
    path = write_phantom(ph, Path(out_dir) / subject.id, dicom=dicom)
    return {"subject": subject.id, "status": "ok", "path": str(path), "summary": ph.study.summary()}


def _run_mix(args: argparse.Namespace, spec: list[SubjectSpec], out: Path, dicom: bool,
             extra: dict) -> int:
    """``phantom --cohort SPEC --n N [--jobs J] [--dask ...] [--resume]``: N subjects of the
    spec's mix, generated on local worker processes or Dask, each subject's folder written
    atomically as it is done (a killed run keeps the finished ones; ``--resume`` skips them)."""
    import shutil

    from cardionurbs.executor import TaskFailure, run_tasks
    from cardionurbs.io.atomic import STUDY_MARKER, write_marker

    subjects = mix_subjects(spec, int(args.n))
    resume = getattr(args, "resume", False)
    if out.is_dir() and any(out.iterdir()) and not resume:
        shutil.rmtree(out)                  # an earlier output, allowed by --overwrite
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out, STUDY_MARKER, trees=[s.id for s in subjects])   # the subjects it owns
    todo = [s for s in subjects if not (resume and (out / s.id / "study.json").is_file())]
    failed: list[str] = []

    def done(k: int, result) -> None:
        if isinstance(result, TaskFailure):
            failed.append(f"{todo[k].id}: {result}")
            print(f"{out / todo[k].id}: error: {result}", file=sys.stderr)
        else:
            print(f"{result['path']}: {result['summary']}", file=sys.stdout)

    run_tasks(generate_subject, [(s, str(out), dicom, args.noise_px, args.tag_jumps, extra)
                                 for s in todo], done, jobs=getattr(args, "jobs", 1) or 1,
              dask=getattr(args, "dask", None))
    print(f"phantom: {len(subjects) - len(failed)} of {len(subjects)} subjects in {out} "
          f"({len(subjects) - len(todo)} kept from before), {len(failed)} failed", file=sys.stderr)
    return 3 if failed else 0
