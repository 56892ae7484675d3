"""Snapshot every metric of a fixed set of studies, to compare two versions of the code.

Run from the project root of each version, then compare::

    python benchmarks/metrics_snapshot.py snapshot OUT.json [--phantoms DIR]
    python benchmarks/metrics_snapshot.py compare BEFORE.json AFTER.json

The studies: the paper's 12-subject phantom cohort (20 frames, generated once
into ``--phantoms``, default /tmp/cardionurbs-snapshot-phantoms, and reused so
both versions measure the same files), three 2-frame phantoms with 0.5 px
contour noise and one tag jump, ../shared/data/bivme-patient1 and the
Sunnybrook studies. For each: ``cardionurbs.pipeline.analyse`` (every column of
docs/metrics.md, tag columns included), Simpson's-disk volumes, the ED/ES
frames and the control-point grid of every surface at ED and ES. A study that
fails records its one-line error. ``compare`` prints, per column, in how many
studies it changed and the largest relative change.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = ROOT.parent / "shared" / "data"


def _clean(v):
    return None if isinstance(v, float) and math.isnan(v) else v


def snapshot(out: Path, phantoms: Path) -> None:
    from cardionurbs.analysis.simpson import simpson_metrics
    from cardionurbs.io import load_study
    from cardionurbs.pipeline import analyse
    if not phantoms.exists():
        from cardionurbs.phantom import generate, generate_cohort, load_cohort_spec, write_phantom
        from cardionurbs.phantom.presets import data_path
        generate_cohort(load_cohort_spec(data_path("paper12.toml")), phantoms, dicom=False)
        for p in ("normal", "mr", "phtn"):
            write_phantom(generate(p, seed=2, frames=2, noise_px=0.5, tag_jumps=1),
                          phantoms / f"noisy_{p}", dicom=False)
    studies = sorted(phantoms.iterdir()) + [DATA / "bivme-patient1"] + \
        sorted((DATA / "sunnybrook").glob("SC-*"))
    rows = {}
    for path in studies:
        try:
            study = load_study(path)
            model, metrics, _ = analyse(study)
        except Exception as exc:  # recorded, the snapshot goes on
            rows[path.name] = {"error": " ".join(str(exc).split())}
            continue
        row = {k: _clean(v) for k, v in metrics.items()}
        sm = simpson_metrics(study, model.ed_frame, model.es_frame)
        row.update({f"simpson {k}": _clean(v) for k, v in sm.items()})
        row["ed_es"] = [model.ed_frame, model.es_frame]
        row["n_ctrl"] = {f"{fr}/{name}": list(s.control_points.shape[:2])
                         for fr in (model.ed_frame, model.es_frame)
                         for name, s in model.surfaces[fr].items()}
        rows[path.name] = row
        print(path.name, "ok", flush=True)
    out.write_text(json.dumps(rows, indent=1, sort_keys=True))


def compare(before: Path, after: Path) -> None:
    a, b = json.loads(before.read_text()), json.loads(after.read_text())
    worst: dict[str, list] = {}
    for subj in sorted(set(a) | set(b)):
        ra, rb = a.get(subj, {}), b.get(subj, {})
        for k in sorted(set(ra) | set(rb)):
            va, vb = ra.get(k), rb.get(k)
            if isinstance(va, (int, float)) and isinstance(vb, (int, float)):
                if va != vb:
                    worst.setdefault(k, []).append((abs(va - vb) / max(abs(va), 1e-12),
                                                    abs(va - vb), subj, va, vb))
            elif va != vb:
                print(f"{subj}: {k}: {va} -> {vb}")
    for k, changes in sorted(worst.items()):
        rel, d, subj, va, vb = max(changes)
        print(f"{k:28s} changed in {len(changes):2d} studies; max relative change {rel:.2e} "
              f"(abs {d:.3g}; {subj}: {va:.6g} -> {vb:.6g})")
    if not worst:
        print("no numeric column changed")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("snapshot")
    s.add_argument("out", type=Path)
    s.add_argument("--phantoms", type=Path, default=Path("/tmp/cardionurbs-snapshot-phantoms"))
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = ap.parse_args()
    if args.cmd == "snapshot":
        snapshot(args.out, args.phantoms)
    else:
        compare(args.before, args.after)


if __name__ == "__main__":
    main()
