"""``cardionurbs phantom``: write one phantom study, or a cohort of them (one folder per subject)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cardionurbs.errors import PhantomError
from cardionurbs.phantom.generate import generate, generate_cohort, write_phantom
from cardionurbs.phantom.presets import load_cohort_spec


def run_phantom(args: argparse.Namespace) -> int:
    """Run the ``phantom`` command (args: pathology, cohort, seed, frames, noise_px, tag_jumps,
    breath_hold_mm, snr, no_dicom, out). Exactly one of --pathology and --cohort is required."""
    if bool(args.pathology) == bool(args.cohort):
        raise PhantomError("phantom: give exactly one of --pathology and --cohort")
    from cardionurbs.io.outputs import check_output_dir
    out = check_output_dir(args.out, inputs=[args.cohort] if args.cohort else [],
                           overwrite=getattr(args, "overwrite", False))
    dicom = not args.no_dicom
    if args.pathology:
        ph = generate(args.pathology, seed=args.seed, frames=args.frames, noise_px=args.noise_px,
                      tag_jumps=args.tag_jumps,
                      breath_hold_mm=getattr(args, "breath_hold_mm", 0.0),
                      snr=getattr(args, "snr", None))
        write_phantom(ph, out, dicom=dicom, labels=getattr(args, "labels", None))
        print(f"{out}: {ph.study.summary()}", file=sys.stdout)
        return 0
    if getattr(args, "labels", None):
        raise PhantomError("phantom: --labels applies to one --pathology subject, not a --cohort")
    from cardionurbs.io.atomic import atomic_dir
    spec = load_cohort_spec(args.cohort)
    extra = {"snr": args.snr} if getattr(args, "snr", None) is not None else {}
    with atomic_dir(out) as tmp:                # the whole cohort, or the previous output
        generate_cohort(spec, tmp, dicom=dicom, noise_px=args.noise_px, tag_jumps=args.tag_jumps,
                        **extra,
                        report=lambda path, ph: print(f"{out / path.name}: {ph.study.summary()}",
                                                      file=sys.stdout))
    return 0
