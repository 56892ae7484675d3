"""Validation of the HARP tag tracker against phantom truth; writes reports/validation-tracking.md.

Run from the repository root::

    .venv/bin/python benchmarks/validate_tracking.py [--frames 20] [--seed 0] [--quick]

For each preset (normal, mr, phtn) and image SNR (20, 10) a phantom with tagged DICOM is
generated, its tag lines are tracked from the images (:func:`cardionurbs.track_tags`) and
compared with the phantom's own (true) tag lines:

* tracking error: distance (px) of every tracked point to the true line of its family,
  index, slice and frame, over the frames whose tag contrast exp(-t / T1) is above 20 % of
  the first frame's;
* tag indices: a tracked line's index is right when the true line nearest to it (median
  distance) has that index; every wrong one is looked up in the tag QC flags;
* Twist, Torsion and LS (docs/metrics.md) from the tracked lines, beside the truth and beside
  the same measures from the phantom's own lines;
* speed: one 9 SA + 3 LA slice study x ``--frames`` frames, tracked end to end (DICOM read,
  spectra, harmonic phase, tracking, lines), best of 3.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs.analysis.tags import tag_metrics  # noqa: E402
from cardionurbs.io import atomic, load_study  # noqa: E402
from cardionurbs.phantom import generate, write_phantom  # noqa: E402
from cardionurbs.phantom.dicom import T1_MS  # noqa: E402
from cardionurbs.tracking import track_tags  # noqa: E402

PRESETS = ("normal", "mr", "phtn")
SNRS = (20.0, 10.0)
COLUMNS = ("Twist (deg)", "Torsion (deg/cm)", "LS (%)")


def polyline_distance(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Distance of points P (n, 2) to the polyline Q (m, 2) (px)."""
    if len(Q) == 1:
        return np.linalg.norm(P - Q[0], axis=1)
    a, b = Q[:-1], Q[1:]
    ab = b - a
    t = np.clip(((P[:, None] - a[None]) * ab[None]).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12),
                0.0, 1.0)
    return np.linalg.norm(P[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)


def compare(truth, tracked, frames_ok: set[int]):
    """Point errors (px) by view, and the list of (line key, right?)."""
    by_image: dict = {}
    for t in truth.tags:
        by_image.setdefault((t.family, t.slice, t.frame), {})[t.index] = t
    errs = {"SA": [], "LA": []}
    verdicts = []
    for line in tracked.tags:
        cands = by_image.get((line.family, line.slice, line.frame))
        if not cands:
            continue
        im = tracked.image(line.image)
        P = im.scanner_to_pixel(line.points)
        d = {i: polyline_distance(P, im.scanner_to_pixel(t.points)) for i, t in cands.items()}
        nearest = min(d, key=lambda i: float(np.median(d[i])))
        key = (line.family, line.index, line.slice, line.frame)
        verdicts.append((key, nearest == line.index))
        if line.index in d and line.frame in frames_ok:
            errs[line.view].append(d[line.index])
    return {v: np.concatenate(e) if e else np.zeros(0) for v, e in errs.items()}, verdicts


def run_case(pathology: str, snr: float, frames: int, seed: int, tmp: Path) -> dict:
    ph = generate(pathology, seed=seed, frames=frames, snr=snr, volume_check=False)
    folder = tmp / f"{pathology}_{int(snr)}_{seed}"
    write_phantom(ph, folder)
    study = load_study(folder)
    t0, c0 = time.perf_counter(), time.process_time()
    tracked = track_tags(study)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    times = study.frame_times_ms
    frames_ok = {k for k, t in times.items() if np.exp(-t / T1_MS) > 0.2}
    errs, verdicts = compare(study, tracked, frames_ok)
    own = tag_metrics(study)
    trk = tag_metrics(tracked)
    flagged = {(f.family, f.index, f.slice, f.frame) for f in trk.flags}
    wrong = [k for k, ok in verdicts if not ok]
    return {"pathology": pathology, "snr": snr, "seed": seed, "seconds": seconds,
            "cpu": cpu, "images": len(study.images),
            "errs": errs, "n_lines": len(verdicts), "wrong": wrong,
            "wrong_flagged": sum(k in flagged for k in wrong), "n_flags": len(trk.flags),
            "frames_ok": len(frames_ok), "frames": len(times),
            "truth": {c: ph.truth["metrics"][c] for c in COLUMNS},
            "own": {c: float(own[c]) for c in COLUMNS}, "tracked": {c: float(trk[c]) for c in COLUMNS},
            "notes": tracked.meta["tag_tracking"]["notes"]}


def speed(frames: int, seed: int, tmp: Path, repeat: int = 3) -> dict:
    """9 SA + 3 LA slices x frames, tracked end to end; best of ``repeat``."""
    for spacing in (10.0, 9.0, 8.0):
        try:
            ph = generate("normal", seed=seed, frames=frames, n_sa=9, sa_spacing_mm=spacing,
                          snr=20.0, volume_check=False)
            break
        except Exception:  # noqa: BLE001 - a smaller heart needs a finer stack
            continue
    folder = tmp / "speed"
    write_phantom(ph, folder)
    study = load_study(folder)
    best, cpu = np.inf, np.inf
    load_before = os.getloadavg()
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        tracked = track_tags(study)
        best = min(best, time.perf_counter() - w)
        cpu = min(cpu, time.process_time() - c)
    n_sa = len({im.slice for im in study.images if im.view == "SA"})
    n_la = len({im.slice for im in study.images if im.view == "LA"})
    return {"seconds": best, "cpu": cpu, "images": len(study.images), "n_sa": n_sa, "n_la": n_la,
            "lines": len(tracked.tags), "sa_spacing_mm": spacing,
            "load": (load_before, os.getloadavg())}


def fmt(x, nd=2):
    return "—" if x is None or not np.isfinite(x) else f"{x:.{nd}f}"


def report(cases: list[dict], sp: dict, args, elapsed: float) -> str:
    cmd = "python benchmarks/validate_tracking.py" + (" --quick" if args.quick else "") + \
        (f" --frames {args.frames}" if args.frames != 20 else "") + (f" --seed {args.seed}" if args.seed else "") + (" --no-speed" if args.no_speed else "")
    lines = [
        "# Validation: tag tracking from tagged images (HARP)", "",
        f"Command: `.venv/bin/python {cmd.split('python ', 1)[1]}` (from the repository root; "
        f"{elapsed:.0f} s here).", "",
        f"Generated {_dt.date.today().isoformat()} on {platform.machine()}, {os.cpu_count()} cores "
        f"(shared), Python {platform.python_version()}, numpy {np.__version__}.", "",
        f"Each phantom (seeds {args.seed} and {args.seed + 1}; {args.frames} frames) is written with its tagged DICOM at the given SNR "
        "(untagged myocardium over the Rician channel noise; `cardionurbs phantom --snr`); "
        "`cn.track_tags` finds the tag lines in the images alone (the study's contours clip them "
        "to the myocardium, its `meta.tag_planes` give the expected spacing and the index labels). "
        "Errors are distances of every tracked point to the phantom's true tag line of the same "
        "family, index, slice and frame, in pixels, over the frames whose tag contrast "
        "exp(−t/T1) is above 20 % of the first frame's.", "",
        "## Tracking error and tag indices", "",
        "| phantom | seed | SNR | frames used | SA median px | SA p95 px | LA median px | LA p95 px | "
        "all median px | all p95 px | lines | wrong index | wrong ones flagged by QC | "
        "QC flags (all lines) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        allp = np.concatenate([c["errs"]["SA"], c["errs"]["LA"]])
        nw = len(c["wrong"])
        lines.append(
            f"| {c['pathology']} | {c['seed']} | {c['snr']:g} | {c['frames_ok']}/{c['frames']} | "
            f"{fmt(np.median(c['errs']['SA']))} | {fmt(np.percentile(c['errs']['SA'], 95))} | "
            f"{fmt(np.median(c['errs']['LA']))} | {fmt(np.percentile(c['errs']['LA'], 95))} | "
            f"**{fmt(np.median(allp))}** | **{fmt(np.percentile(allp, 95))}** | {c['n_lines']} | "
            f"{nw} ({100 * nw / max(c['n_lines'], 1):.1f} %) | {c['wrong_flagged']}/{nw} | "
            f"{c['n_flags']} |")
    lines += ["", "## Tag metrics from the tracked lines", "",
              "Truth: the phantom's analytic value (truth.json). *Own lines*: the same tag analysis "
              "on the phantom's own (true) tag lines. *Tracked*: on the lines tracked from the "
              "images (flagged lines left out, as in `analyze`).", "",
              "| phantom | seed | SNR | metric | truth | own lines | tracked | tracked − truth | "
              "tracked − own |", "|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        for m in COLUMNS:
            t, o, k = c["truth"][m], c["own"][m], c["tracked"][m]
            lines.append(f"| {c['pathology']} | {c['seed']} | {c['snr']:g} | {m} | {fmt(t)} | {fmt(o)} | {fmt(k)} | "
                         f"{fmt(k - t)} | {fmt(k - o)} |")
    lines += ["", "## Speed", "",
              f"One study of {sp['n_sa']} SA + {sp['n_la']} LA slices × {args.frames} frames "
              f"({sp['images']} images, 256 × 256, SA spacing {sp['sa_spacing_mm']:g} mm), "
              f"`track_tags` end to end (DICOM read, spectra, harmonic phase, tracking, lines), best "
              f"of 3: **{sp['seconds']:.2f} s** wall ({sp['cpu']:.2f} s CPU; load average "
              f"{sp['load'][0][0]:.1f} before, {sp['load'][1][0]:.1f} after"
              + ("; the last `--speed-only` run" if sp.get("speed_only") else "") + "), "
              f"**{1000 * sp['seconds'] / sp['images']:.1f} ms per image**; {sp['lines']} tag lines.", "",
              "Per-study tracking times of the cases above (one run each, machine shared; wall / "
              "CPU): " +
              ", ".join(f"{c['pathology']} seed {c['seed']} SNR {c['snr']:g}: {c['seconds']:.1f} / "
                        f"{c['cpu']:.1f} s" for c in cases) + ".", ""]
    notes = sorted({n for c in cases for n in c["notes"]})
    if notes:
        lines += ["Tracker notes:", ""] + [f"- {n}" for n in notes] + [""]
    lines += [NOTES]
    return "\n".join(lines)


NOTES = """## Method and notes

- **Geometry.** The first frame's spectrum (Hann window, local-contrast peak picking, harmonic
  check) gives each family's wave vector; the SA stack shares one median wave vector (a small
  apical section, or one locked on a harmonic, takes it), checked against `meta.tag_planes`
  (spacing within 20 %, direction within 15°).
- **Myocardial window.** Before the band-pass, every frame's pixels outside the myocardium of
  the study's contours at that frame are set to the myocardium's mean intensity. The Gaussian
  band-pass (σ = 0.25 |k|) reaches a few pixels: without the window the bright blood pool's
  edge adds its own spectrum at the tag frequency and biases the phase near the endocardium by
  up to half a spacing, a bias that moves with the wall, so that phase-invariant tracking
  followed it. That was the cause of the earlier MR-phantom errors (p95 1.73 px, 35 wrong
  indices at SNR 20, concentrated at end systole within ~2 px of the border of the thin-walled
  slices next to the RV blood). The tag trough refinement runs on the same windowed frames
  (the dark lung beyond the epicardium is no tag).
- **Phase and tracking.** The harmonic images are stored demodulated so that bilinear
  interpolation and finite differences of the phase are accurate. Material points (the first
  frame's tag line points) are followed by Newton iterations on the wrapped phase of both
  families (one along the tag normal in LA views), started from the previous position moved
  by the study's contours' motion; a point whose displacement departs by more than 0.35
  spacing from its neighbours' is restarted from theirs.
- **Lines.** SA: the tracked material points of each line; LA: the iso-phase lines φ = π,
  labelled by the lines predicted from the previous frame; both moved onto the tag trough
  (a parabola through the image minimum along the phase gradient, ±0.45 spacing, median
  filtered along the line) and clipped to the myocardium of the study's contours at that
  frame, 1 px in from its borders (0.5 px gives more wrong indices from grazing pieces, 0 px
  a larger p95). At the first frame a piece more than 0.12 spacing from its tag plane (a
  plane grazing the border) is no tag line.
- **Basal slices that leave the ventricle.** A slice without contours at a frame the study
  contours elsewhere has left the ventricle (its tissue was above the base at ED, so no LV
  tag runs through it; docs/metrics.md, Levels): it gets no tag lines from that frame on.
  Earlier, a basal slice contoured at exactly half the frames borrowed its neighbours'
  contours and kept tag lines through end systole; the twist levels then spanned one extra
  basal level (index 10 of the normal phantom) and Twist was 2.49° off. Now the SA slices
  tagged at ED and ES, and so the levels, are the phantom's own.
- **Confidence and QC.** Each line carries its median harmonic magnitude (relative to the
  first frame) and the RMS phase residual of the tracked points it is made of; the tag QC
  flags lines below 0.15 or above 0.6 rad as "low confidence", beside the leave-one-out
  tag-jump test. "QC flags (all lines)" counts every flag raised on the tracked study (false
  alarms included), "wrong ones flagged" those on a wrong index.
- **Short-axis line model (Twist bias).** The tracked SA lines after the first frame are moved
  onto one least-squares quadratic of their offset along k against their position along the
  tag (`tag_curve`, across both wall pieces of a line). Before, every phantom's Twist and
  Torsion from tracked lines came out too large (Twist +0.36 to +0.97 deg, Torsion +0.09 to
  +0.17 deg/cm, MR above the 0.15 bound), although each line's own rotation was within a
  few tenths of a degree. What was looked at, on MR seed 0 (levels, common material points,
  hybrids of own and tracked lines): the LA lines are not the cause (own SA + tracked LA
  lines: Twist within 0.03 deg); the 1 px clipping is not (own lines cut to the tracked
  lines' extent: within 0.1 deg); the missing material points are not (the bias is the
  same on the points both have). The tracked SA lines at end systole carry a
  point-to-point jitter of ~0.2 px from the trough search, and the lofted tag surfaces and
  their three-way intersections amplify it into material-point errors of 0.5–1 mm, whose
  level means come out biased. The quadratic removes it (five phantoms, SNR 20: mean Twist
  error +0.66 → +0.29 deg, Torsion +0.130 → +0.056 deg/cm; seed 0 in the table above: Twist
  +0.71 / +0.97 / +0.36 deg and Torsion +0.14 / +0.17 / +0.09 deg/cm in this report's
  previous version, +0.23 / +0.55 / +0.20 and +0.05 / +0.09 / +0.05 now). A fit per wall
  piece does not help, nor do a re-centred (unbiased) trough search, a wider median along
  the line, a wider band-pass or band-limited extrapolation of the tags past the
  myocardium (tried on the MR and normal seed-0 phantoms, not kept). On the phantoms' own
  lines the model changes Twist by < 0.02 deg; it is not exact for them at end systole
  (points moved by up to ~0.5 px at the ends), which is why the SA p95 of PHTN rose from
  0.20 to 0.34 px while those of normal and MR fell. The Twist error left at SNR 20 is
  +0.20 to +0.55 deg in five cases of six (−0.03 in the sixth): a smaller positive bias
  whose cause is not found.
- **Label maps.** `track_tags(study, labels=...)` / `cardionurbs track --label-maps PATH` clip
  the lines to the myocardium pixels of NIfTI label maps on the tagged images' pixel grid
  (tests/test_tracking_labelmaps.py: on the phantom's ukbb maps the lines lie on the true
  lines inside the labelled myocardium; with the maps eroded by 1 px no point is in the
  removed rim, where ~7 % of the contour-clipped points are).
"""


def benchmark_md(sp: dict, cases: list[dict], args) -> str:
    """reports/benchmark-tracking.md: the speed part (assembled into reports/benchmark.md)."""
    return "\n".join([
        "# Benchmark: tag tracking from tagged DICOM (issue 15)", "",
        "Command (from the project root):", "", "```",
        ".venv/bin/python benchmarks/validate_tracking.py"
        + (" --speed-only" if sp.get("speed_only") else ""), "```", "",
        f"- Date: {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- Machine: {os.cpu_count()} cores, shared with other jobs; Python "
        f"{platform.python_version()}, numpy {np.__version__}",
        "- Load average (1, 5, 15 min) just before / after the timed runs: "
        f"{', '.join(f'{x:.1f}' for x in sp['load'][0])} / "
        f"{', '.join(f'{x:.1f}' for x in sp['load'][1])} (2 cores: a load of L leaves this job "
        "about 2 / L of a core, so the wall time is about CPU x L / 2 when L > 2; the CPU time "
        "is what an idle machine's wall time would be, the tracker being single-threaded).",
        "- Target: one study, 9 SA + 3 LA slices x 20 frames, tracked in < 10 s.", "",
        "| study | images | `track_tags` wall (s, best of 3) | CPU (s) | per image, wall (ms) | "
        "per image, CPU (ms) | tag lines |",
        "|---|---|---|---|---|---|---|",
        f"| normal phantom, {sp['n_sa']} SA + {sp['n_la']} LA x {args.frames} frames, 256 x 256, SNR 20 | "
        f"{sp['images']} | **{sp['seconds']:.2f}** | {sp['cpu']:.2f} | "
        f"{1000 * sp['seconds'] / sp['images']:.1f} | **{1000 * sp['cpu'] / sp['images']:.1f}** | "
        f"{sp['lines']} |", "",
        "Where the time goes (pyinstrument on the normal phantom, seed 0, 240 images): per-line "
        "work at every frame — iso-phase lines, the trough search, the myocardium test with its "
        "1 px border margin, the robust quadratic that drops slipped points, phase sampling and "
        "the SA line model (`tag_curve`, 3 %) — about half; HARP Newton tracking with its "
        "contour prior about 11 %; DICOM reading (RLE) about 8 %; rasterising the myocardium "
        "5 %; FFTs 5 %. The contour prior's cyclic contour matching runs by FFT instead of "
        "trying every shift. Nothing further was cut: the target is met, and the largest items "
        "(the exact polygon distance of the 1 px margin, the robust line fit) set the validated "
        "clipping and slip rejection.", "",
        "End to end: DICOM pixel reading (pydicom), first-frame spectra, harmonic images of every "
        "frame (scipy.fft on a crop around the contours), Newton tracking of every tag point, "
        "iso-phase lines, trough refinement, indices. Accuracy: "
        "[validation-tracking.md](validation-tracking.md).", ""])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="normal only, SNR 20")
    ap.add_argument("--out", default=str(ROOT / "reports" / "validation-tracking.md"))
    ap.add_argument("--no-speed", action="store_true",
                    help="keep the last run's speed figures (a quiet-machine --speed-only run)")
    ap.add_argument("--speed-only", action="store_true",
                    help="only the speed study; rewrites reports/benchmark-tracking.md")
    ap.add_argument("--from-cache", action="store_true",
                    help="re-render benchmark-tracking.md from the last run's cached results")
    args = ap.parse_args()
    t0 = time.perf_counter()
    import pickle
    cache = Path(tempfile.gettempdir()) / "validate_tracking_cases.pkl"
    speed_cache = Path(tempfile.gettempdir()) / "validate_tracking_speed.pkl"
    if args.from_cache:   # re-render both reports (notes edited) from the last run's results
        cases, sp, elapsed = pickle.loads(cache.read_bytes())
        if speed_cache.is_file():     # a dedicated --speed-only run, when there is one
            sp = pickle.loads(speed_cache.read_bytes())
        atomic.write_text(args.out, report(cases, sp, args, elapsed))
        atomic.write_text(Path(args.out).with_name("benchmark-tracking.md"), benchmark_md(sp, cases, args))
        return 0
    if args.speed_only:
        with tempfile.TemporaryDirectory() as d:
            sp = dict(speed(args.frames, args.seed, Path(d)), speed_only=True)
        speed_cache.write_bytes(pickle.dumps(sp))
        print(f"speed: {sp['seconds']:.2f} s wall, {sp['cpu']:.2f} s CPU for {sp['images']} images; "
              f"load {sp['load']}", flush=True)
        atomic.write_text(Path(args.out).with_name("benchmark-tracking.md"), benchmark_md(sp, [], args))
        return 0
    cases = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        runs = [(p, s, args.seed) for p in (PRESETS[:1] if args.quick else PRESETS)
                for s in (SNRS[:1] if args.quick else SNRS)]
        if not args.quick:   # a second subject per phantom at both SNRs: metric biases seen twice,
            runs += [(p, s, args.seed + 1) for p in PRESETS for s in SNRS]   # more wrong-index chances
        for p, s, seed in runs:
                c = run_case(p, s, args.frames, seed, tmp)
                allp = np.concatenate([c["errs"]["SA"], c["errs"]["LA"]])
                print(f"{p} seed {seed} SNR {s:g}: median {np.median(allp):.3f} px, p95 "
                      f"{np.percentile(allp, 95):.3f} px, wrong {len(c['wrong'])}/{c['n_lines']} "
                      f"({c['wrong_flagged']} flagged); {c['seconds']:.1f} s", flush=True)
                cases.append(c)
        if args.no_speed and speed_cache.is_file():
            sp = pickle.loads(speed_cache.read_bytes())
        else:
            sp = speed(args.frames, args.seed, tmp)
        print(f"speed: {sp['seconds']:.2f} s for {sp['images']} images", flush=True)
    elapsed = time.perf_counter() - t0
    cache.write_bytes(pickle.dumps((cases, sp, elapsed)))
    text = report(cases, sp, args, elapsed)
    atomic.write_text(args.out, text)
    if not args.no_speed:
        atomic.write_text(Path(args.out).with_name("benchmark-tracking.md"), benchmark_md(sp, cases, args))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
