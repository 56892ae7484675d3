"""Model file size (issue 33): model.json version 1 (every float as text, with the SA
sections) against version 2 (knots, control points and weights at a stated precision,
nothing derivable) and model.npz, per surface and frame beside the contour points the
surfaces replace.

    .venv/bin/python benchmarks/bench_model_size.py     # -> reports/benchmark-model-size.md

A 20-frame tagged normal phantom (seed 0, no DICOM) is reconstructed and measured
(:func:`cardionurbs.pipeline.analyse`); the three files are written from the same model.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs.analysis.tags import tag_surfaces_dict  # noqa: E402
from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.cli import main as cli  # noqa: E402
from cardionurbs.io.modelfile import TAG_UNIT_MM, UNIT_MM, write_model_file  # noqa: E402
from cardionurbs.pipeline import analyse  # noqa: E402

COMMAND = ".venv/bin/python benchmarks/bench_model_size.py"
FRAMES = 20


def _sizes(model_dict: dict, folder: Path, name: str) -> dict[str, int]:
    """Bytes of the version-1 JSON (as analyze wrote it), version-2 JSON and .npz."""
    v1 = folder / f"{name}-v1.json"
    v1.write_text(json.dumps(model_dict) + "\n")
    return {"v1": v1.stat().st_size,
            "v2": write_model_file(model_dict, folder / f"{name}.json").stat().st_size,
            "npz": write_model_file(model_dict, folder / f"{name}.npz").stat().st_size}


def main() -> Path:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        assert cli(["phantom", "--pathology", "normal", "--seed", "0", "--frames", str(FRAMES),
                    "--no-dicom", "--out", str(tmp / "study")]) == 0
        study = load_study(tmp / "study")
        csv = next(p for p in (tmp / "study").glob("points.*") if p.suffix != ".json")
        model, _, tags = analyse(study, over_time=False)
        heart = model.to_dict()
        full = dict(heart, tag_surfaces=tag_surfaces_dict(study, long_axis=model.long_axis(),
                                                          surfaces=tags.surfaces))
        sizes_full = _sizes(full, tmp, "model")
        sizes_heart = _sizes(heart, tmp, "heart")
        n_surf = sum(len(d) for d in heart["surfaces"].values())
        n_ctrl = sum(np.asarray(s["control_points"]).shape[0] * np.asarray(s["control_points"]).shape[1]
                     for d in heart["surfaces"].values() for s in d.values())
        n_tag = sum(len(d) for d in full["tag_surfaces"]["frames"].values())
        n_contours, n_points = len(study.contours), sum(len(c.points) for c in study.contours)
        csv_bytes = csv.stat().st_size
        rows = json.loads((tmp / "study" / "study.json").read_text())["points_rows"]
        tag_points = sum(len(t.points) for t in study.tags)
    load = os.getloadavg()
    per = n_surf
    lines = [
        "# Benchmark: model file size (issue 33)", "", "Command (from the project root):", "",
        "```", COMMAND, "```", "",
        f"- Date: {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M UTC}",
        f"- Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"numpy {np.__version__}; load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}",
        f"- Study: `normal` phantom, seed 0, {FRAMES} frames, tagged; {per} heart surfaces "
        f"({per // FRAMES} per frame), {n_tag} tag surfaces.",
        f"- Stated precision of version 2: control points {UNIT_MM:g} mm (tag surfaces "
        f"{TAG_UNIT_MM:g} mm), knots 1e-9, weights float64 (left out when all 1); the SA "
        "sections (the study's contours) are not stored.", "",
        "## Whole file (heart surfaces + tag surfaces)", "",
        "| form | bytes | vs version 1 |", "|---|---:|---:|",
        *[f"| {label} | {sizes_full[k]:,} | {sizes_full[k] / sizes_full['v1']:.1%} |"
          for k, label in (("v1", "model.json version 1"), ("v2", "model.json version 2"),
                           ("npz", "model.npz"))],
        "", "## Per surface and frame (heart surfaces only), beside the contour points they replace",
        "",
        "| | per surface and frame |", "|---|---:|",
        f"| control points | {n_ctrl / per:.0f} |",
        f"| model.json version 1 (bytes) | {sizes_heart['v1'] / per:,.0f} |",
        f"| model.json version 2 (bytes) | {sizes_heart['v2'] / per:,.0f} |",
        f"| model.npz (bytes) | {sizes_heart['npz'] / per:,.0f} |",
        f"| contour points they replace | {n_points / per:.0f} |",
        f"| those points in the study's {csv.name} (bytes, {csv_bytes / max(rows, 1):.0f} per row) "
        f"| {n_points * csv_bytes / max(rows, 1) / per:,.0f} |",
        f"| those points as float64 x, y, z (bytes) | {n_points * 24 / per:,.0f} |", "",
        f"The study holds {n_contours} contours ({n_points:,} points) and {len(study.tags)} tag "
        f"lines ({tag_points:,} points); {csv.name} (every point of the study, tag lines "
        f"included) is {csv_bytes:,} bytes.", ""]
    out = ROOT / "reports" / "benchmark-model-size.md"
    out.write_text("\n".join(lines))
    return out


if __name__ == "__main__":
    print(main())
