"""Throughput benchmark (issue 16): analyze timings, study file sizes, cohorts on processes
and on Dask, and the per-subject costs behind reports/scale.md.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_throughput.py [--n 1000] [--repeat 3]
        [--out reports/benchmark-throughput.md] [--json reports/throughput.json]

Every timing is repeated (``--repeat``) and reported as the median, with the CPU time
(user + system of the process and its children) beside the wall time: the machine is
shared, and CPU time is what an idle core would need. Peak memory is the child's
maximum resident set size. The load average is recorded at start and end.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "data"
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")

MIX = """# benchmark mix: ED + ES frames, tagged (the paper12 proportions 5 : 3 : 4)
[cohort]
name = "throughput"
frames = 2
{subjects}
"""


def run(cmd: list[str], **kw) -> dict:
    """Run a command; wall s, CPU s (user + sys of it and its children), peak RSS MB."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, **kw)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    err = p.stderr.read().decode()
    p.stderr.close()
    code = os.waitstatus_to_exitcode(status)
    if code not in (0,):
        raise RuntimeError(f"{' '.join(cmd)} -> exit {code}: {err[-2000:]}")
    return {"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024,
            "stderr": err}


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "cardionurbs.cli", *args]


def median_of(fn, repeat: int) -> dict:
    runs = [fn() for _ in range(repeat)]
    return {k: statistics.median(r[k] for r in runs) for k in ("wall_s", "cpu_s", "rss_mb")} | \
        {"runs": [{k: round(r[k], 3) for k in ("wall_s", "cpu_s", "rss_mb")} for r in runs]}


def du(path: Path) -> int:
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def loadavg() -> str:
    return " / ".join(f"{x:.1f}" for x in os.getloadavg())


def in_process_cost(path: Path, repeat: int, drop_tags: bool = False) -> dict:
    """load_study + analyse_study (what one cohort row costs), in this process, CPU s median;
    ``drop_tags``: the same study without its tag lines (an untagged cine study)."""
    from cardionurbs.io import load_study
    from cardionurbs.pipeline import analyse_study

    def load():
        st = load_study(path)
        if drop_tags:
            st.tags = []
        return st
    analyse_study(load())                    # warm: imports, caches
    walls, cpus = [], []
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        analyse_study(load())
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return {"wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus)}


def native_load(path: Path, repeat: int) -> dict:
    from cardionurbs.io import native
    cpus = []
    for _ in range(repeat):
        c = time.process_time()
        native.read_study(path)
        cpus.append(time.process_time() - c)
    return {"cpu_s": statistics.median(cpus)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000, help="synthetic subjects in the cohort runs")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", default=str(ROOT / "reports" / "throughput.json"))
    ap.add_argument("--md", default=str(ROOT / "reports" / "benchmark-throughput.md"))
    ap.add_argument("--scale", default=str(ROOT / "reports" / "scale.md"))
    ap.add_argument("--render-only", action="store_true",
                    help="only rewrite --md from an existing --json")
    ap.add_argument("--skip-analyze", action="store_true")
    ap.add_argument("--skip-cohort", action="store_true")
    a = ap.parse_args(argv)
    if a.render_only:
        res = json.loads(Path(a.json).read_text())
        Path(a.md).write_text(render(res, a))
        if "phantom50_row_in_process" in res and "cohort_processes_2" in res:
            Path(a.scale).write_text(render_scale(res))
        return 0
    res: dict = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                 "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python "
                            f"{platform.python_version()}",
                 "load_start": loadavg(), "n": a.n, "repeat": a.repeat}
    work = Path(tempfile.mkdtemp(prefix="cn-throughput-"))
    try:
        if not a.skip_analyze:
            res.update(bench_analyze(work, a.repeat))
        if not a.skip_cohort:
            res.update(bench_cohort(work, a.n, a.repeat))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    res["load_end"] = loadavg()
    old = json.loads(Path(a.json).read_text()) if Path(a.json).is_file() else {}
    if a.skip_analyze or a.skip_cohort:          # keep the other half of an earlier run
        res = {**old, **res}
    Path(a.json).write_text(json.dumps(res, indent=1) + "\n")
    Path(a.md).write_text(render(res, a))
    if "phantom50_row_in_process" in res and "cohort_processes_2" in res:
        Path(a.scale).write_text(render_scale(res))
    print(f"wrote {a.json} and {a.md}")
    return 0


def _ok(cond: bool) -> str:
    return "**met**" if cond else "**not met**"


def _extrapolation(r: dict) -> str:
    """The 1,000-subject figures extrapolated (clearly) from a smaller measured run."""
    if "cohort_processes_2" not in r or r.get("cohort_subjects", 0) >= 1000:
        return ""
    per = r["cohort_processes_2"]["cpu_s"] / r["cohort_subjects"]
    return (f" 1,000 subjects were not run (the shared cores would not allow it before the "
            f"deadline): at {per:.2f} CPU-s per subject (2-frame tagged, worker start-up "
            f"included) they would cost about {1000 * per:,.0f} core-seconds, about "
            f"{1000 * per / 2 / 60:.0f} minutes on the 2 cores when idle -- extrapolated from "
            f"the {r['cohort_subjects']}-subject run, not measured.")


def render(r: dict, a) -> str:
    """reports/benchmark-throughput.md from the JSON results."""
    L = ["# Benchmark: throughput (issue 16)", "",
         "Command (from the project root):", "",
         "```",
         "OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_throughput.py --repeat 3 "
         "--skip-cohort        # analyze, files",
         f"OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_throughput.py --n {r.get('n')} "
         "--repeat 1 --skip-analyze   # cohorts",
         "```", "",
         "(results in `reports/throughput.json`; `--render-only` rewrites this file and "
         "`reports/scale.md` from it)", "",
         f"- Date: {r.get('date')}; machine: {r.get('machine')}",
         f"- Load average (1 / 5 / 15 min) at start {r.get('load_start')}, at end "
         f"{r.get('load_end')}: the 2 cores are shared with six other engineers' jobs, so wall "
         "times are inflated by the load; CPU time (user + system of the command and its "
         "worker processes) is what the work costs a core and is the better estimate of an "
         "idle machine's wall time for one process.",
         f"- Medians of {r.get('repeat')} runs (cohorts: one run each); peak memory = maximum "
         "resident set of the command (its largest process). Under this load the CPU times "
         "themselves are inflated (shared caches, hyper-threads): the same 20-frame analysis "
         "measured about 3 s of CPU in-process earlier in the evening at a lower load.", ""]
    if "phantom20_all" in r:
        a_, m_, b_ = r["phantom20_all"], r["phantom20_metrics"], r.get("bivme25_metrics")
        L += ["## analyze", "",
              "`cardionurbs analyze STUDY --outputs LIST --out DIR` (CLI, a fresh process: "
              "includes Python start-up and imports, about 1.3 s of CPU):", "",
              "| study | outputs | wall (s) | CPU (s) | peak memory (MB) | target |",
              "|---|---|---:|---:|---:|---|",
              f"| 20-frame tagged phantom (with DICOM) | all | {a_['wall_s']:.2f} | {a_['cpu_s']:.2f} "
              f"| {a_['rss_mb']:.0f} | < 3 s wall, < 300 MB: {_ok(a_['cpu_s'] < 3)} (CPU), "
              f"{_ok(a_['rss_mb'] < 300)} (memory) |",
              f"| 20-frame tagged phantom | metrics | {m_['wall_s']:.2f} | {m_['cpu_s']:.2f} | "
              f"{m_['rss_mb']:.0f} | < 1 s: {_ok(m_['cpu_s'] < 1)} (CPU) |"]
        if b_:
            L.append(f"| bivme-patient1, 25 frames | metrics | {b_['wall_s']:.2f} | "
                     f"{b_['cpu_s']:.2f} | {b_['rss_mb']:.0f} | < 1.5 s: {_ok(b_['cpu_s'] < 1.5)} (CPU) |")
        L += ["", "The per-study cost inside a running process (`load_study` + `analyse_study`: "
              "what one cohort row costs a worker, no start-up):", "",
              "| study | wall (s) | CPU (s) |", "|---|---:|---:|"]
        for key, label in (("phantom20_row_in_process", "20-frame tagged phantom"),
                           ("bivme25_row_in_process", "bivme-patient1, 25 frames"),
                           ("phantom2_row_in_process", "2-frame (ED + ES) tagged phantom"),
                           ("phantom50_row_in_process", "50-frame tagged phantom")):
            if key in r:
                L.append(f"| {label} | {r[key]['wall_s']:.2f} | {r[key]['cpu_s']:.2f} |")
        b = r["phantom20_bytes"]
        L += ["", "## Study files", "",
              "| 20-frame tagged phantom | bytes |", "|---|---:|",
              f"| whole folder (native + RLE DICOM + truth) | {b['total'] / 1e6:.1f} MB |",
              f"| dicom/ (240 images, RLE Lossless) | {b['dicom'] / 1e6:.1f} MB |",
              f"| points.csv (3 decimals) | {b['points.csv'] / 1e6:.1f} MB |",
              f"| points.parquet sidecar (optional) | {r['phantom20_sidecar_bytes'] / 1e6:.1f} MB |",
              "",
              f"Native load (`native.read_study`, CPU, median): CSV "
              f"{r['native_load_csv']['cpu_s']:.3f} s, with the sidecar "
              f"{r['native_load_sidecar']['cpu_s']:.3f} s (target < 0.2 s: "
              f"{_ok(r['native_load_csv']['cpu_s'] < 0.2)}). Whole folder < 12 MB: "
              f"{_ok(b['total'] < 12e6)} -- see below.", ""]
    if "cohort_processes_1" in r:
        p1, p2, d2 = r["cohort_processes_1"], r["cohort_processes_2"], r["cohort_dask_local_2"]
        n = r["cohort_subjects"]
        L += ["## Cohorts: synthetic subjects, ED + ES frames, tagged, metrics only", "",
              f"{n} subjects generated (`phantom --cohort MIX --n {n} --jobs 2 --no-dicom`, "
              f"{r['cohort_generate_2jobs']['wall_s']:.1f} s wall, "
              f"{r['cohort_generate_2jobs']['cpu_s']:.1f} s CPU) and measured with "
              "`cardionurbs cohort ... --timeout 600` (each finished row fsynced to its file):", "",
              "| executor | wall (s) | CPU (s) | subjects / core-second (CPU) | row file bytes / subject |",
              "|---|---:|---:|---:|---:|"]
        for label, x in (("1 local worker process", p1), ("2 local worker processes", p2),
                         ("Dask LocalCluster, 2 workers on 127.0.0.1 (started by the run)", d2)):
            L.append(f"| {label} | {x['wall_s']:.1f} | {x['cpu_s']:.1f} | "
                     f"{x['subjects_per_core_s']:.2f} | {x['row_files_bytes']:.0f} |")
        L += ["", f"- Scaling 1 -> 2 workers (wall): efficiency {100 * r['scaling_efficiency_1_to_2']:.0f} % "
              f"(target >= 90 %: {_ok(r['scaling_efficiency_1_to_2'] >= 0.9)}).",
              f"- Dask against plain processes (wall, cluster start-up included): "
              f"{100 * r['dask_overhead_vs_processes']:+.0f} % (target <= 10 %: "
              f"{_ok(r['dask_overhead_vs_processes'] <= 0.10)}).",
              f"- The three CSVs are byte-identical: {r['cohort_csvs_identical']}.",
              f"- Native files per subject (2 frames, no DICOM): "
              f"{r['cohort_native_bytes_per_subject'] / 1e3:.0f} kB.", ""]
    L += ["## Before and after, and what is not met", "",
          "- Before this work (commit 13a811b, the same 20-frame tagged phantom, every output, "
          "measured at 21:41 UTC on 2026-11-29 with a load average of 0.9): 18.3 s wall, 682 MB "
          "peak (`/usr/bin/time -v python -m pyinstrument -m cardionurbs.cli analyze STUDY --out "
          "DIR`); the profile put the time in tag QC (2.5 s), meshing every frame (3.6 s), "
          "figures (3.0 s), model.json (1.5 s), residuals (0.8 s). The same metrics before and "
          "after, to 1e-6 relative, on five studies (20-frame tagged phantom, bivme-patient1, an "
          "8-frame MR phantom with tag jumps and breath-hold shifts, a 2-frame PH phantom, "
          "Sunnybrook SC-HF-I-1): `python benchmarks/metrics_regression.py record|compare`.",
          "- Speed-ups: tag-QC residuals batched over predictor pairs and plane normals cached "
          "(tag QC 2.5 -> 1.1 s in the profile), metrics-only runs skip the tag time course and "
          "every mesh, figure and file not asked for (`--outputs`), figures reuse the analysis's "
          "tag surfaces, model.json through the C JSON encoder, each frame's meshes let go once "
          "written (peak memory 598 -> 387 MB in a direct measurement).",
          "- Not met: the 3 s / 1 s targets for a 20-frame tagged study. What remains is spread "
          "thinly: surfaces and closed meshes of 20 frames, tag QC of 20 frames x 2 families "
          "(thousands of small leave-one-out lofts), matplotlib figures; Python start-up and "
          "imports alone are about 1.3 s of CPU and 160 MB. The < 300 MB target is not met "
          "either: imports and the loaded study are about 270 MB before any analysis.",
          "- Not met: < 12 MB for the 20-frame phantom with DICOM. The images carry Rician noise "
          "of sigma = 75 grey levels (the default SNR), whose entropy is about 8.3 bits per "
          "pixel: 240 images x 65,536 pixels cannot be stored losslessly in less than about "
          "16 MB, whatever the codec. RLE Lossless reaches about 2/3 of the uncompressed size; "
          "a higher `--snr` compresses further.",
          "- Cohorts: measured with a load average above 20 on the 2 shared cores, so the "
          "1 -> 2 worker efficiency and the Dask overhead are dominated by the other jobs; the "
          "CPU columns are the reliable ones. Dask's CPU includes its scheduler, nannies and "
          "the cluster start-up (a fixed cost of tens of CPU seconds, amortised over a real "
          "cohort but not over a few dozen subjects)." + _extrapolation(r), ""]
    return "\n".join(L) + "\n"


def bench_analyze(work: Path, repeat: int) -> dict:
    out: dict = {}
    ph = work / "ph20"
    g = run(cli("phantom", "--pathology", "normal", "--seed", "1", "--frames", "20", "--out", str(ph)))
    out["phantom20_generate"] = {k: g[k] for k in ("wall_s", "cpu_s", "rss_mb")}
    out["phantom20_bytes"] = {"total": du(ph), "dicom": du(ph / "dicom"),
                              "points.csv": (ph / "points.csv").stat().st_size,
                              "study.json": (ph / "study.json").stat().st_size}
    from cardionurbs.io import native
    sc = work / "ph20_sidecar"
    native.write_study(native.read_study(ph), sc, sidecar=True)
    out["phantom20_sidecar_bytes"] = (sc / "points.parquet").stat().st_size
    out["native_load_csv"] = native_load(ph, max(repeat, 5))
    out["native_load_sidecar"] = native_load(sc, max(repeat, 5))
    cases = {"phantom20_all": ("analyze", str(ph), "--outputs", "all"),
             "phantom20_metrics": ("analyze", str(ph), "--outputs", "metrics")}
    biv = SHARED / "bivme-patient1"
    if biv.is_dir():
        cases["bivme25_metrics"] = ("analyze", str(biv), "--outputs", "metrics")
    for name, args in cases.items():
        dest = work / f"out_{name}"
        out[name] = median_of(lambda: run(cli(*args, "--out", str(dest), "--overwrite")), repeat)
    dest = work / "out_phantom20_all"
    out["phantom20_all_output_bytes"] = {f.name: du(f) if f.is_dir() else f.stat().st_size
                                         for f in dest.iterdir()}
    out["phantom20_row_in_process"] = in_process_cost(ph, repeat)
    if biv.is_dir():
        out["bivme25_row_in_process"] = in_process_cost(biv, repeat)
    # per-subject cost against frames, for the projection (reports/scale.md)
    for frames in (2, 50):
        p = work / f"ph{frames}"
        run(cli("phantom", "--pathology", "normal", "--seed", "7", "--frames", str(frames),
                "--no-dicom", "--out", str(p)))
        out[f"phantom{frames}_row_in_process"] = in_process_cost(p, repeat)
        out[f"phantom{frames}_native_bytes"] = du(p)
    out["phantom50_untagged_row_in_process"] = in_process_cost(work / "ph50", repeat,
                                                               drop_tags=True)
    return out


def bench_cohort(work: Path, n: int, repeat: int) -> dict:
    out: dict = {}
    mix = work / "mix.toml"
    subjects = [("normal", 5), ("mr", 3), ("phtn", 4)]
    entries, k = [], 0
    for path, count in subjects:
        for _ in range(count):
            entries.append(f'[[subject]]\nid = "{path}{k:02d}"\npathology = "{path}"\nseed = {k}\n')
            k += 1
    mix.write_text(MIX.format(subjects="\n".join(entries)))
    gen = work / "cohort"
    out["cohort_generate_2jobs"] = {k_: v for k_, v in run(cli(
        "phantom", "--cohort", str(mix), "--n", str(n), "--jobs", "2", "--no-dicom",
        "--out", str(gen))).items() if k_ != "stderr"}
    studies = sorted(str(p) for p in gen.iterdir() if p.is_dir())
    out["cohort_native_bytes_per_subject"] = du(gen) / len(studies)
    configs = {"processes_1": ["--jobs", "1", "--timeout", "600", "--allow-failures"],
               "processes_2": ["--jobs", "2", "--timeout", "600", "--allow-failures"],
               "dask_local_2": ["--jobs", "2", "--dask", "local", "--timeout", "600", "--allow-failures"]}
    csvs = {}
    for name, extra in configs.items():
        csv = work / f"{name}.csv"

        def once(csv=csv, extra=extra):
            return run(cli("cohort", *studies, "--csv", str(csv), *extra))
        out[f"cohort_{name}"] = median_of(once, repeat)
        out[f"cohort_{name}"]["subjects_per_core_s"] = (
            len(studies) / out[f"cohort_{name}"]["cpu_s"])
        csvs[name] = csv.read_bytes()
        out[f"cohort_{name}"]["row_files_bytes"] = du(Path(str(csv) + ".rows")) / len(studies)
    out["cohort_csvs_identical"] = len(set(csvs.values())) == 1
    t1, t2 = out["cohort_processes_1"]["wall_s"], out["cohort_processes_2"]["wall_s"]
    out["scaling_efficiency_1_to_2"] = t1 / (2 * t2)
    out["dask_overhead_vs_processes"] = out["cohort_dask_local_2"]["wall_s"] / t2 - 1
    out["cohort_subjects"] = len(studies)
    return out




def render_scale(r: dict) -> str:
    """reports/scale.md: UK Biobank (100,000 subjects x 50 frames) from the measured costs."""
    N, NODES = 100_000, 100
    t50 = r["phantom50_row_in_process"]["cpu_s"]
    u50 = r["phantom50_untagged_row_in_process"]["cpu_s"]
    t2 = r["phantom2_row_in_process"]["cpu_s"]
    # worker overhead: what a cohort run costs per subject beyond the in-process analysis
    # (process start, imports, loading, fsync of the row), measured on the 2-frame cohort
    p2 = r["cohort_processes_2"]
    per_subject_cohort = p2["cpu_s"] / r["cohort_subjects"]
    overhead = max(per_subject_cohort - t2, 0.0)
    eff = min(r["scaling_efficiency_1_to_2"], 1.0)
    dask_over = max(r["dask_overhead_vs_processes"], 0.0)
    row_bytes = p2["row_files_bytes"]
    out20 = sum(r.get("phantom20_all_output_bytes", {}).values())
    L = ["# Scale: UK Biobank on paper", "",
         "Generated with the throughput benchmark (numbers from `reports/throughput.json`):", "",
         "```",
         "OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_throughput.py --repeat 3 --skip-cohort",
         f"OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_throughput.py --n {r.get('n')} "
         "--repeat 1 --skip-analyze",
         "```", "",
         f"Measured {r.get('date')} on {r.get('machine')} (load average {r.get('load_start')} "
         f"at start, {r.get('load_end')} at end: the cores were shared, so CPU time, not wall "
         "time, is used below).", "",
         "## Per-subject cost (measured)", "",
         "| study | CPU s per subject (metrics only, in a running worker) |", "|---|---:|",
         f"| 50-frame tagged phantom (9 SA + 3 LA slices, SA and LA tags) | {t50:.2f} |",
         f"| the same 50 frames without tag lines (a cine study, as most of UK Biobank) | {u50:.2f} |",
         f"| 2-frame (ED + ES) tagged phantom | {t2:.2f} |",
         f"| worker overhead per subject in a cohort run (process, imports, row fsync) | {overhead:.2f} |",
         "", f"(Worker overhead = a cohort run's CPU per subject, {per_subject_cohort:.2f} s, "
         f"minus the in-process 2-frame cost, {t2:.2f} s, measured at another moment; a value "
         "of 0 means the overhead is within the measurement noise.)",
         "", "## UK Biobank: 100,000 subjects x 50 frames, metrics only", ""]
    rows = []
    for label, c in (("cine (untagged)", u50), ("tagged (upper bound)", t50)):
        core_s = N * (c + overhead)
        core_h = core_s / 3600
        single = core_s / (NODES * eff) * (1 + dask_over) / 3600
        rows.append((label, core_h, single, core_h / (NODES * 32) / eff * (1 + dask_over)))
    L += ["| subjects | core-hours | 100-node Dask cluster, 1 core per node (h) | "
          "100 nodes x 32 cores (h) |", "|---|---:|---:|---:|"]
    for label, ch, h1, h32 in rows:
        L.append(f"| {label} | {ch:,.0f} | {h1:.1f} | {h32:.2f} |")
    L += ["", "Assumptions, stated so they can be checked:", "",
          "- core-hours = 100,000 x (per-subject CPU + worker overhead); the per-subject CPU "
          "is the measured 50-frame phantom (9 SA + 3 LA slices: a UK Biobank stack has about "
          "10 SA slices, so within ~10 %).",
          f"- cluster time = core-hours / (workers x parallel efficiency {100 * eff:.0f} %, the "
          f"measured 1 -> 2 worker efficiency) x (1 + Dask overhead {100 * dask_over:.0f} %, "
          "measured against plain processes, cluster start-up included); one single-threaded "
          "worker process per core. Scheduling 100,000 tasks is far below what one Dask "
          "scheduler handles (a few thousand tasks per second), so the scheduler is not the limit.",
          "- Input reading is included for native studies; reading the DICOM headers of UK "
          "Biobank's own files adds the header-read cost measured in "
          "`reports/benchmark-io.md` (about 1 ms per image).", "",
          "## Bytes written per subject", "",
          "| what | bytes per subject | 100,000 subjects |", "|---|---:|---:|",
          f"| cohort, metrics only: the durable row file (JSON) | {row_bytes:.0f} | "
          f"{N * row_bytes / 1e6:.0f} MB |",
          f"| cohort CSV row (docs/metrics.md columns, %.6g) | ~400 | ~{N * 400 / 1e6:.0f} MB |"]
    if out20:
        est50 = out20 * 50 / 20
        L.append(f"| `analyze` with every output (meshes, model, figures, report): 20 frames "
                 f"measured {out20 / 1e6:.1f} MB, 50 frames scaled by frames | "
                 f"~{est50 / 1e6:.0f} MB | ~{N * est50 / 1e12:.1f} TB |")
    L += ["", "Metrics only is what a cohort writes: about a kilobyte per subject, so "
          "100,000 subjects fit in about 0.1 GB; every output of `analyze` for every subject "
          "would be terabytes (mostly meshes and the HTML report) and is meant for the "
          "subjects someone looks at.", ""]
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    sys.exit(main())
