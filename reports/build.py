"""Regenerate reports/validation.md and reports/benchmark.md (one command).

Usage (from the project root)::

    .venv/bin/python reports/build.py                  # everything (demo cohort included)
    .venv/bin/python reports/build.py --cohort DIR     # reuse a demo output (cohort.csv, truth.csv)
    .venv/bin/python reports/build.py --benchmarks     # also re-run benchmarks/bench_*.py first
    .venv/bin/python reports/build.py --quick          # 5-frame phantom, first 3 CAP frames
    .venv/bin/python reports/build.py --benchmark-only # only reassemble reports/benchmark.md

What it does
------------
1. Analyses three studies end to end with the public pipeline
   (``load_study`` → ``analyse_study`` → ``write_analysis`` with figures and
   report.html): a tagged phantom with two tag jumps (truth known), Sunnybrook
   SC-HF-I-1 and CAP bivme-patient1 (when ../shared/data is present); copies
   their figures to ``reports/figures/validation/<subject>/`` and a headless
   Chromium screenshot of each HTML report beside them.
2. Runs the paper's 12-subject demo cohort (``cardionurbs demo``) unless
   ``--cohort`` gives its output, and draws the cohort figures
   (distributions by group, measured vs truth, Bland–Altman) into
   ``reports/figures/cohort/``.
3. Writes ``reports/validation.md`` embedding all of the above (metrics
   beside truth, captions, the one-line reasons for figures left out, the
   Bland–Altman table), and ``reports/benchmark.md``: every
   ``reports/benchmark-*.md`` in one file behind a table of contents.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
REPORTS = ROOT / "reports"
DATA = ROOT.parent / "shared" / "data"


def _rel(p: Path) -> str:
    return os.path.relpath(p, REPORTS).replace(os.sep, "/")


def _num(x) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.2f}" if isinstance(x, float) else str(x)


def analyse(study_path: Path, work: Path, frames: list[int] | None = None) -> dict:
    """Analyse one study into ``work`` (figures + report.html); return a summary."""
    import cardionurbs as cn
    from cardionurbs.analysis.function import measure
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.pipeline import analyse as analyse_all
    from cardionurbs.pipeline import tag_metrics_hook, write_analysis

    t0 = time.perf_counter()
    study = cn.load_study(study_path)
    if frames:
        model = reconstruct(study, frames=frames)
        metrics = measure(model)
        tags = tag_metrics_hook(model)
        if tags is not None:
            metrics.update({k: float(v) for k, v in dict(tags).items() if k in metrics})
    else:
        model, metrics, tags = analyse_all(study)
    out = work / study.subject
    write_analysis(model, metrics, out, figures=True, tags=tags)
    return {"subject": study.subject, "out": out, "metrics": metrics, "seconds":
            time.perf_counter() - t0, "frames": list(model.frames), "ed": model.ed_frame,
            "es": model.es_frame, "truth": (json.loads((Path(study_path) / "truth.json").read_text())
                                            if (Path(study_path) / "truth.json").is_file() else None)}


def study_section(s: dict, fig_root: Path) -> list[str]:
    """Markdown for one analysed study; copies its figures and a report screenshot."""
    from cardionurbs.report.chromium import find_chromium, open_page
    dst = fig_root / s["subject"]
    dst.mkdir(parents=True, exist_ok=True)
    # only what this section writes: the folder also holds other benchmarks' figures
    # (bench_models.py bivme draws bivme-patient1's residual and outflow figures there)
    for old in [*dst.glob("fig*.png"), dst / "report_screenshot.png"]:
        old.unlink(missing_ok=True)
    idx = json.loads((s["out"] / "figures" / "figures.json").read_text())
    lines = [f"## {s['subject']}", "",
             f"{len(s['frames'])} reconstructed frame(s), ED frame {s['ed']}, ES frame {s['es']}; "
             f"analysis with figures and report.html took {s['seconds']:.1f} s.", ""]
    truth = (s["truth"] or {}).get("metrics")
    lines += ["| metric | measured |" + (" truth |" if truth else ""),
              "|---|---|" + ("---|" if truth else "")]
    for k, v in s["metrics"].items():
        lines.append(f"| {k} | {_num(v)} |" + (f" {_num(truth.get(k))} |" if truth else ""))
    lines.append("")
    for f in idx["figures"]:
        shutil.copy2(s["out"] / "figures" / f["file"], dst / f["file"])
        lines += [f"![{f['name']}]({_rel(dst / f['file'])})", "", f"*{f['caption']}*", ""]
    if idx["skipped"]:
        lines += ["Figures left out:", ""] + [f"- {k}: {v}" for k, v in idx["skipped"].items()] + [""]
    exe = find_chromium()
    if exe:
        run = open_page(s["out"] / "report.html", chromium=exe, timeout=120, ready_js=(
            "document.getElementById('cn-status').getAttribute('data-ok') === '1'"))
        (dst / "report_screenshot.png").write_bytes(run.screenshot)
        size = (s["out"] / "report.html").stat().st_size / 1e6
        lines += [f"![HTML report]({_rel(dst / 'report_screenshot.png')})", "",
                  f"*Interactive report (`report.html`, {size:.1f} MB, self-contained) in headless "
                  f"Chromium: {len(run.errors)} console errors, {len(run.requests)} network "
                  f"requests, rendered: {run.ready}.*", ""]
    else:
        lines += ["(Chromium not installed: no screenshot of the HTML report.)", ""]
    return lines


def cohort_section(cohort_dir: Path, fig_root: Path) -> list[str]:
    import pandas as pd
    from cardionurbs.report.cohort_figures import write_cohort_figures
    dst = fig_root / "cohort"
    shutil.rmtree(dst, ignore_errors=True)
    truth = cohort_dir / "truth.csv"
    fs = write_cohort_figures(cohort_dir / "cohort.csv", dst,
                              truth=truth if truth.is_file() else None)
    lines = ["## Cohort: the paper's 12 phantom subjects (5 normal, 3 MR, 4 PHTN)", ""]
    for f in fs.figures:
        lines += [f"![{f.name}]({_rel(f.path)})", "", f"*{f.caption}*", ""]
    lines += [f"- {k}: {v}" for k, v in fs.skipped.items()]
    agree = dst / "cohort_agreement.csv"
    if agree.is_file():
        t = pd.read_csv(agree)
        lines += ["", "Agreement with the phantom truth (measured − truth):", "",
                  "| metric | n | bias | SD | 95 % limits |", "|---|---|---|---|---|"]
        for _, r in t.iterrows():
            lines.append(f"| {r['metric']} | {int(r['n'])} | {r['bias']:.3g} | {r['sd']:.3g} | "
                         f"[{r['lower']:.3g}, {r['upper']:.3g}] |")
    return lines + [""]


def benchmark_report(run: bool) -> Path:
    """reports/benchmark.md: all reports/benchmark-*.md behind a table of contents."""
    if run:
        for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
            print(f"running {script.name} ...", flush=True)
            subprocess.run([sys.executable, str(script)], cwd=ROOT, check=False)
    parts = sorted(REPORTS.glob("benchmark-*.md"))
    lines = ["# Benchmarks", "",
             "Regenerated by `.venv/bin/python reports/build.py"
             + (" --benchmarks" if run else "") + "` (with `--benchmarks` every "
             "`benchmarks/bench_*.py` is re-run first; each section below names its own command, "
             "date and machine).", "",
             f"Assembled {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC.", ""]
    lines += [f"- [{p.stem}](#{p.stem})" for p in parts] + [""]
    for p in parts:
        body = p.read_text().splitlines()
        lines += [f"<a id=\"{p.stem}\"></a>", ""]
        lines += [("#" + ln) if ln.startswith("#") else ln for ln in body] + [""]
    out = REPORTS / "benchmark.md"
    out.write_text("\n".join(lines) + "\n")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cohort", type=Path, default=None,
                    help="a demo output folder with cohort.csv and truth.csv (else the demo runs)")
    ap.add_argument("--benchmarks", action="store_true", help="re-run benchmarks/bench_*.py first")
    ap.add_argument("--quick", action="store_true", help="5-frame phantom, 3 CAP frames")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--benchmark-only", action="store_true",
                    help="only reassemble reports/benchmark.md from reports/benchmark-*.md")
    args = ap.parse_args(argv)
    if args.benchmark_only:
        print(benchmark_report(args.benchmarks))
        return 0
    from cardionurbs.phantom import generate
    from cardionurbs.phantom.generate import write_phantom

    fig_root = REPORTS / "figures" / "validation"
    fig_root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="cn-reports-"))
    cmd = "`.venv/bin/python reports/build.py" + "".join(
        f" {a}" for a in (argv if argv is not None else sys.argv[1:])) + "`"
    lines = ["# Validation report", "", f"Command: {cmd}", "",
             f"Date: {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC; machine: "
             f"{platform.machine()}, {os.cpu_count()} cores; Python {platform.python_version()}.",
             "", "Every figure below was drawn headless by `cardionurbs analyze` (matplotlib Agg) "
             "in scanner (LPS) millimetres; the screenshots are the self-contained HTML reports "
             "opened in headless Chromium.", "",
             "The detailed validations, each regenerated by the command at its top:", "",
             "- [validation-function.md](validation-function.md): volumes, masses, EF, "
             "regurgitant fraction against phantom truth (noise-free and 0.5 px noise), "
             "beside Simpson's disks from the same contours; Sunnybrook and CAP (biv-me) results.",
             "- [validation-tags.md](validation-tags.md): twist, torsion, CL shear, LS and "
             "per-level rotation against truth; Twist 2D bias; tag-jump QC over 20 seeds.",
             "- [validation-tracking.md](validation-tracking.md): tag lines tracked from the "
             "tagged DICOM (HARP) against the true lines at SNR 20 and 10; tag indices; twist, "
             "torsion, LS from tracked lines (`benchmarks/validate_tracking.py`).",
             "- [validation-labelmaps.md](validation-labelmaps.md): NIfTI label maps of the "
             "phantoms (UK Biobank and ACDC layouts) through mask contours and the model, "
             "beside voxel counting (benchmarks/labelmaps.py validation).",
             "- [fitting.md](fitting.md): control points at 0.5 px on the Sunnybrook contours "
             "(uniform knots, eq. 9 knots, optimised weights).",
             "- [phantoms.md](phantoms.md): the presets, the paper's 12 subjects and their truth.",
             "- [validation-realistic.md](validation-realistic.md): realistic phantom anatomy "
             "(docs/phantoms.md; with its RV and LV outflow tracts and saddle annuli, the "
             "default) beside the ideal one from the same seeds -- volumes, masses, EF, "
             "twist from our model and Simpson's disks, noise-free and with clinical acquisition "
             "faults; the two truth methods and the LA contours over 20 seeds per preset "
             "(`benchmarks/validate_realistic.py`).",
             "- [validation-outflow.md](validation-outflow.md): the reconstruction's outflow "
             "tracts on realistic phantoms with and without them (`benchmarks/validate_outflow.py`).",
             "- [validation-regional.md](validation-regional.md): AHA segments, wall thickness, "
             "tag strain, surface GLS/GCS and filling rates against the phantoms' exact regional "
             "truth, noise-free and with 0.5 px noise (`benchmarks/validate_regional.py`).",
             "- [validation-regional-realistic.md](validation-regional-realistic.md): the same on "
             "realistic anatomy, noise-free (`benchmarks/validate_regional.py --anatomy realistic`): "
             "thickness holds, tag strain does not yet.",
             "- [validation-quality.md](validation-quality.md): the quality flags on the paper's "
             "12 phantoms and on bivme-patient1.",
             ""]
    try:
        nfr = 5 if args.quick else 20
        ph = generate("normal", seed=1, frames=nfr, tag_jumps=2, volume_check=False)
        write_phantom(ph, work / "phantom", dicom=False)
        studies = [(work / "phantom", None)]
        if (DATA / "sunnybrook" / "SC-HF-I-1").is_dir():
            studies.append((DATA / "sunnybrook" / "SC-HF-I-1", None))
        if (DATA / "bivme-patient1").is_dir():
            studies.append((DATA / "bivme-patient1", [0, 1, 2] if args.quick else None))
        for path, frames in studies:
            print(f"analysing {path} ...", flush=True)
            lines += study_section(analyse(path, work / "out", frames), fig_root)
        cohort_dir = args.cohort
        if cohort_dir is None:
            from cardionurbs.demo import run_demo
            cohort_dir = work / "demo"
            print("running the demo cohort ...", flush=True)
            run_demo(argparse.Namespace(out=str(cohort_dir), jobs=args.jobs))
        lines += cohort_section(Path(cohort_dir), fig_root)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    (REPORTS / "validation.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {REPORTS / 'validation.md'}")
    print(f"wrote {benchmark_report(args.benchmarks)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
