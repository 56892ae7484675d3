"""Study loading speed: DICOM headers, contour files, GPFiles, native + DICOM cross-check.

Run from the project root::

    .venv/bin/python benchmarks/bench_io.py [--repeat 5] [--out reports/benchmark-io.md]

Measures, side by side in one run (median and best of ``--repeat`` runs, warm file cache):

* a synthetic 300-image Sunnybrook-layout study (15 SA slices x 20 phases, 256 x 256
  16-bit images, LV contours at ED and ES): ``load_study`` and its parts (DICOM headers,
  checks), and the same folder read with pixels;
* the real Sunnybrook SC-HF-I-1 (240 images) and bivme-patient1 (25 GPFiles, ~40k
  points; load and GPFile write) from ../shared/data, when present;
* a phantom written by ``cardionurbs.phantom`` (native study + DICOM) loaded with the
  DICOM geometry cross-check, and with geometry taken from the DICOM headers.

Target (issue 4): a 300-image study loads in under 2 s.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from broken.corpus import SA_COL, SA_NORMAL, SA_ORIGIN, SA_ROW, circle_pixels, write_contour, write_dicom_image  # noqa: E402
from pydicom.uid import generate_uid  # noqa: E402

from cardionurbs import load_study  # noqa: E402
from cardionurbs.imaging.dicom import read_dicom_folder  # noqa: E402
from cardionurbs.io import gpfile  # noqa: E402
from cardionurbs.io.checks import check_study  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"


def make_300_image_study(root: Path, n_slices: int = 15, n_phases: int = 20) -> Path:
    """Sunnybrook layout, 256 x 256 images, instance = slice * 20 + phase + 1."""
    series, rr = generate_uid(), 900.0
    rng = np.random.default_rng(0)
    px = rng.integers(0, 1200, (256, 256))
    for s in range(n_slices):
        pos = SA_ORIGIN + 8.0 * s * SA_NORMAL
        for k in range(n_phases):
            inst = s * n_phases + k + 1
            write_dicom_image(root / "dicom" / f"{inst}.dcm", position=pos, row=SA_ROW, col=SA_COL,
                              spacing=(1.25, 1.25), rows=256, columns=256, pixels=px,
                              trigger_time=k * rr / n_phases + 2.0, instance=inst, series_uid=series,
                              heart_rate=66, nominal_interval=rr, n_phases=n_phases)
        for k, r in ((0, 30.0 - s), (8, 20.0 - 0.7 * s)):
            inst = s * n_phases + k + 1
            write_contour(root / "i-contours" / f"IM-0001-{inst:04d}-icontour-manual.txt",
                          circle_pixels(center=(128, 120), radius=r, n=80))
        write_contour(root / "o-contours" / f"IM-0001-{s * n_phases + 1:04d}-ocontour-manual.txt",
                      circle_pixels(center=(128, 120), radius=40.0 - s, n=80))
    return root


def timed(fn, repeat: int) -> tuple[float, float, object]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times), out


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmark-io.md"))
    args = ap.parse_args(argv)
    rows: list[tuple[str, str, float, float, str]] = []

    def add(case, what, fn, note=lambda r: ""):
        med, best, res = timed(fn, args.repeat)
        rows.append((case, what, med, best, note(res)))
        print(f"{case:34s} {what:42s} {med:7.3f} s (best {best:.3f})", flush=True)
        return res

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        big = make_300_image_study(tmp / "sb300")
        print(f"(wrote the 300-image study in {time.perf_counter() - t0:.1f} s)")
        st = add("synthetic 300 images (Sunnybrook)", "load_study (headers + contours + checks)",
                 lambda: load_study(big), lambda s: s.summary().split(": ", 1)[1])
        add("synthetic 300 images (Sunnybrook)", "read_dicom_folder, headers only",
            lambda: read_dicom_folder(big / "dicom"), lambda s: f"{len(s.images)} images")
        add("synthetic 300 images (Sunnybrook)", "check_study", lambda: check_study(st),
            lambda w: f"{len(w)} warnings")
        add("synthetic 300 images (Sunnybrook)", "read_dicom_folder, pixels=True",
            lambda: read_dicom_folder(big / "dicom", pixels=True), lambda s: f"{len(s.pixels)} arrays")

        if (SHARED / "sunnybrook" / "SC-HF-I-1").is_dir():
            add("Sunnybrook SC-HF-I-1 (real)", "load_study",
                lambda: load_study(SHARED / "sunnybrook" / "SC-HF-I-1"),
                lambda s: s.summary().split(": ", 1)[1])
        if (SHARED / "bivme-patient1").is_dir():
            gp = add("bivme-patient1 GPFiles (real)", "load_study",
                     lambda: load_study(SHARED / "bivme-patient1"),
                     lambda s: s.summary().split(": ", 1)[1])
            add("bivme-patient1 GPFiles (real)", "gpfile.write_study (byte-identical)",
                lambda: gpfile.write_study(gp, tmp / "gp_out"), lambda p: "26 files")

        try:
            from cardionurbs.phantom.generate import generate, write_phantom
            import cardionurbs.phantom.dicom  # noqa: F401
        except ImportError:
            rows.append(("phantom", "not available", float("nan"), float("nan"), ""))
        else:
            t0 = time.perf_counter()
            ph = generate("normal", seed=0, frames=28, volume_check=False)
            out = write_phantom(ph, tmp / "phantom")
            print(f"(wrote a {len(ph.study.images)}-image phantom in {time.perf_counter() - t0:.1f} s)")
            from cardionurbs.io.native import check_dicom_geometry, read_study, read_study_from_dicom
            case = f"phantom, {len(ph.study.images)} images (native+DICOM)"
            pst = add(case, "load_study (+ DICOM geometry cross-check)", lambda: load_study(out),
                      lambda s: s.summary().split(": ", 1)[1])
            add(case, "  part: native.read_study (study.json + points.csv)", lambda: read_study(out),
                lambda s: f"{sum(len(c.points) for c in s.contours) + sum(len(t.points) for t in s.tags)} points")
            add(case, "  part: check_dicom_geometry (headers)", lambda: check_dicom_geometry(pst),
                lambda n: f"{n} headers")
            add(case, "  part: check_study", lambda: check_study(pst), lambda w: f"{len(w)} warnings")
            add(case, "read_study_from_dicom (geometry from headers)", lambda: read_study_from_dicom(out),
                lambda s: f"{len(s.contours)} contours")

    lines = [
        "# Benchmark: study loading (issue 4)",
        "",
        "Command (from the project root):",
        "",
        "```",
        ".venv/bin/python benchmarks/bench_io.py" + (f" --repeat {args.repeat}" if args.repeat != 5 else ""),
        "```",
        "",
        f"- Date: {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}",
        f"- Machine: {os.cpu_count()} cores ({cpu_name()}), shared with other jobs; "
        f"Python {platform.python_version()}, pydicom {__import__('pydicom').__version__}, "
        f"numpy {np.__version__}",
        f"- Load average at the end of the run: {', '.join(f'{v:.1f}' for v in os.getloadavg())} "
        "(other jobs share the 2 cores; times scale with it).",
        f"- Median and best of {args.repeat} runs each, warm file cache, one process.",
        "- Target: a 300-image study loads in under 2 s.",
        "",
        "| study | operation | median (s) | best (s) | result |",
        "|---|---|---:|---:|---|",
    ]
    for case, what, med, best, note in rows:
        lines.append(f"| {case} | {what} | {med:.3f} | {best:.3f} | {note} |")
    target = next(r for r in rows if r[1].startswith("load_study"))
    lines += ["", f"300-image load: median {target[2]:.2f} s -> "
              f"{'meets' if target[2] < 2.0 else 'MISSES'} the 2 s target.", ""]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
