"""`cardionurbs analyze`: one study in, its model, meshes, metrics and figures out."""

from __future__ import annotations

import argparse

from cardionurbs.io import load_study


def run_analyze(args: argparse.Namespace) -> int:
    """Load, reconstruct, measure and write one study (see API.md)."""
    study = load_study(args.study, format=args.format)
    from cardionurbs.anatomy.model import reconstruct  # noqa: F401  (built by the models work)

    raise NotImplementedError(f"analysis of {study.subject} is not built yet")
