"""Validation of the regional analysis against phantom truth; writes reports/validation-regional.md.

Run from the repository root::

    .venv/bin/python benchmarks/validate_regional.py [--seeds 1]

Against ``truth.json`` of freshly generated phantoms (normal seed 1, mr seed 2,
phtn seed 3; with ``--seeds N`` also the next N − 1 seeds of each):

1. noise-free 2-frame phantoms: segmental wall thickness (ED, ES) and
   thickening, Ecc/Ell/Err per segment and global, det F, GLS/GCS surface;
2. the same with 0.5 px contour and tag noise;
3. filling rates at 20, 30 and 40 frames (noise-free), and the rate estimator (natural
   spline) beside other interpolants on two families of analytic volume curves;
4. Sunnybrook (heart failure with infarction): GCS surface beside the published
   heart-failure range;
5. the regional analysis time on a 2-frame tagged phantom (median of 5 after a warm-up).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import statistics
import sys
import time
from pathlib import Path

# single-threaded BLAS, as the speed section reports (set before numpy is imported: a
# multi-threaded BLAS spinning on a loaded machine inflates the CPU time several fold)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs.analysis.rates import RATE_COLUMNS, model_filling_rates  # noqa: E402
from cardionurbs.analysis.regional import regional_metrics  # noqa: E402
from cardionurbs.analysis.tags import tag_metrics  # noqa: E402
from cardionurbs.anatomy.model import reconstruct  # noqa: E402
from cardionurbs.io import atomic  # noqa: E402
from cardionurbs.phantom.faults import add_noise  # noqa: E402
from cardionurbs.phantom.generate import _rng, generate  # noqa: E402

PRESETS = (("normal", 1), ("mr", 2), ("phtn", 3))
SEG = range(1, 17)
HF_GCS = (-6.6, 3.6)   # mid-LV circumferential strain in HFrEF, mean ± SD (see NOTES)


def _num(v):
    return float("nan") if v is None else float(v)


def seg_signed(m, t, fmt):
    """Measured − truth per segment 1–16 (NaN where either is missing: a segment without
    tagged tissue in the truth, e.g. a base above the highest tag level)."""
    return np.array([_num(m[fmt.format(k)]) - _num(t[fmt.format(k)]) for k in SEG])


def seg_err(m, t, fmt):
    e = np.abs(seg_signed(m, t, fmt))
    return float(np.nanmax(e)), float(np.nanmean(e))


def one(pathology, seed, noise, noise_on="both", anatomy="ideal", infarct=None):
    """One phantom's row; ``noise_on="tags"``: the noise on the tag lines only, the contours
    exact (the issue's condition), drawn from the phantom's own noise generator;
    ``anatomy``, ``infarct``: as :func:`cardionurbs.phantom.generate.generate`'s
    ``anatomy_model`` and ``infarct``."""
    kw = dict(frames=2, volume_check=False, anatomy_model=anatomy, infarct=infarct)
    if noise_on == "tags":
        ph = generate(pathology, seed=seed, **kw)
        add_noise(ph.study, noise, _rng(seed, pathology, "noise"), targets=("tags",))
    else:
        ph = generate(pathology, seed=seed, noise_px=noise, **kw)
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    r = regional_metrics(model, tags)
    t = ph.truth["metrics"]
    label = f"{pathology} {seed}" + (f" {anatomy}" if anatomy != "ideal" else "") + (
        f" infarct {infarct}" if infarct else "")
    row = {"subject": label, "noise": noise, "noise on": noise_on}
    for name, fmt in (("WT ED", "WT_AHA_{} (mm)"), ("WT ES", "WT_ES_AHA_{} (mm)"),
                      ("Thickening", "Thickening_AHA_{} (%)"), ("Ecc", "Ecc_AHA_{} (%)"),
                      ("Ell", "Ell_AHA_{} (%)"), ("Err", "Err_AHA_{} (%)")):
        row[name] = seg_err(r, t, fmt)
    row["signed"] = {k: seg_signed(r, t, k + "_AHA_{} (%)") for k in ("Ecc", "Ell", "Err")}
    row["segments"] = int(np.isfinite(row["signed"]["Ecc"]).sum())
    row["near axis"] = r.strain.get("near_axis_excluded", 0)
    for c in ("Ecc_Global (%)", "Ell_Global (%)", "Err_Global (%)", "GLS surface (%)",
              "GCS surface (%)", "WT_Global (mm)", "Thickening_Global (%)"):
        row[c] = (r[c], t[c])
    row["det F"] = r.strain.get("det_F", float("nan"))
    # the incompressibility check independent of the penalty: det F of the unregularised fit
    row["det F0"] = r.strain.get("det_F_unregularised", row["det F"])
    row["det F truth"] = ph.truth["tags"]["det_F_es"]
    row["points"] = r.strain.get("n_points", 0)
    row["tag points"] = r.strain.get("n_tag_points", 0)
    row["noise mm"] = r.strain.get("tag_noise_mm", float("nan"))
    row["residual mm"] = r.strain.get("fit_residual_mm", float("nan"))
    row["penalty"] = r.strain.get("penalty") or []
    se = r.strain.get("segment_se") or {}
    row["se"] = {k: np.array(list(v.values())) for k, v in se.items()}
    row["se by segment"] = {k: np.array([v.get(str(s), np.nan) for s in SEG]) for k, v in se.items()}
    sd = r.strain.get("segment_sd") or {}
    row["sd"] = {k: np.array(list(v.values())) for k, v in sd.items()}
    row["prior sd"] = r.strain.get("volume_prior_sd")
    row["sigma mm"] = r.strain.get("sigma_mm", float("nan"))
    if anatomy == "realistic" and not noise:
        row["exact motion"] = exact_motion_errors(ph, model, tags)
        # the estimator before: the regularisation's σ from the tracking noise alone
        rb = regional_metrics(model, tags, misfit_noise=False)
        row["noise-only sigma"] = {k: float(np.nanmax(np.abs(seg_signed(rb, t, k + "_AHA_{} (%)"))))
                                   for k in ("Ecc", "Ell", "Err")}
    if noise:
        # the same tags fitted by the other estimators (ESTIMATORS) and with other prior spreads
        row["estimators"] = {"tags + contours, volume prior (reported)": row["signed"]}
        for name, kw in ESTIMATORS if noise_on == "both" else ESTIMATORS[:2]:
            rv = regional_metrics(model, tags, **kw)
            row["estimators"][name] = {k: seg_signed(rv, t, k + "_AHA_{} (%)") for k in ("Ecc", "Ell", "Err")}
    return row


def exact_motion_errors(ph, model, tags) -> dict:
    """Max |measured − truth| per kind over the segments when the fitted F is replaced by the
    phantom's exact motion (:meth:`~cardionurbs.phantom.generate.Phantom.deformation_gradient`):
    the error that is left comes from how the strain is sampled and averaged (wall samples,
    tagged range, directions, segments), not from the fit."""
    r = regional_metrics(model, tags, deformation=ph.deformation_gradient)
    t = ph.truth["metrics"]
    return {k: float(np.nanmax(np.abs(seg_signed(r, t, k + "_AHA_{} (%)")))) for k in ("Ecc", "Ell", "Err")}


#: the estimators the reported one (tags and wall contours, the volume prior s = VOLUME_PRIOR_SD)
#: is compared with on the noisy phantoms: the tags alone with the prior (the estimator before
#: the contours joined), and with the contours: the ridge penalties alone, the incompressibility
#: weight chosen by the risk estimate, and the prior with other spreads s
ESTIMATORS = (("tags alone, volume prior (before)", {"boundaries": False}),
              ("ridge only (risk)", {"incompressibility": False}),
              ("κ by risk (before)", {"incompressibility": "risk"}),
              ("volume prior s = 3 %", {"volume_prior_sd": 0.03}),
              ("volume prior s = 7 %", {"volume_prior_sd": 0.07}))


def table(rows):
    out = ["| phantom | WT ED max/mean (mm) | WT ES max/mean (mm) | Thickening max (%) | "
           "Ecc seg max/mean | Ell seg max/mean | Err seg max/mean | GCS (Ecc_Global) err | "
           "GLS (Ell_Global) err | Err_Global err | det F fit / unregularised (truth 1) | GLS surface err | "
           "GCS surface err | tag points / ED-plane noise / fit residual (mm) | penalty λ |",
           "|" + "---|" * 15]
    for r in rows:
        def d(c):
            return r[c][0] - r[c][1]
        out.append(f"| {r['subject']} | {r['WT ED'][0]:.2f} / {r['WT ED'][1]:.2f} | "
                   f"{r['WT ES'][0]:.2f} / {r['WT ES'][1]:.2f} | {r['Thickening'][0]:.2f} | "
                   f"{r['Ecc'][0]:.2f} / {r['Ecc'][1]:.2f} | {r['Ell'][0]:.2f} / {r['Ell'][1]:.2f} | "
                   f"{r['Err'][0]:.1f} / {r['Err'][1]:.1f} | {d('Ecc_Global (%)'):+.2f} | "
                   f"{d('Ell_Global (%)'):+.2f} | {d('Err_Global (%)'):+.1f} | {r['det F']:.3f} / {r['det F0']:.3f} | "
                   f"{d('GLS surface (%)'):+.2f} | {d('GCS surface (%)'):+.2f} | "
                   f"{r['tag points']} / {r['noise mm']:.2f} / {r['residual mm']:.2f} | "
                   f"{', '.join(f'{v:g}' for v in r['penalty']) or '—'} |")
    return out


BOUNDS_NOISY = (("Ecc", 2.0), ("Ell", 3.0), ("Err", 6.0), ("WT ED", 1.0), ("WT ES", 1.0))


def chance_within(se: np.ndarray, bound: float) -> float:
    """Probability that every segment error of an unbiased Gaussian estimate with standard
    errors ``se`` lies within ``bound``: Π_k (2Φ(bound / se_k) − 1)."""
    from scipy.stats import norm
    return float(np.prod(2 * norm.cdf(bound / se) - 1)) if len(se) else float("nan")


def noise_rows(rows):
    """Per noisy phantom: the fit's standard errors (Cramér–Rao bound within the motion model)
    of the segment strains, and the chance an unbiased estimator meets the bound on all 16."""
    out = ["| phantom | Err SE median / max | P(all 16 Err within 6) | Ell SE median / max | "
           "P(all 16 Ell within 3) | Ecc SE max | Err seg error max | regularised Err SD median / max |",
           "|" + "---|" * 8]
    for r in rows:
        se = r["se"]
        if not se:
            continue
        out.append(f"| {r['subject']} | {np.median(se['Err']):.1f} / {se['Err'].max():.1f} | "
                   f"{chance_within(se['Err'], 6.0):.3f} | {np.median(se['Ell']):.1f} / "
                   f"{se['Ell'].max():.1f} | {chance_within(se['Ell'], 3.0):.3f} | "
                   f"{se['Ecc'].max():.2f} | {r['Err'][0]:.1f} | "
                   f"{np.median(r['sd']['Err']):.1f} / {r['sd']['Err'].max():.1f} |")
    return out


def calibration(rows):
    """Over every segment of every noisy phantom: the mean error (the bias), the RMS error,
    and the errors in units of the fit's own standard error, z = error / SE (an unbiased
    estimate with those errors: mean z ≈ 0, RMS z ≈ 1)."""
    out = ["| quantity | segments | mean error | RMS error | mean z | RMS z | apical (13–16) mean error |",
           "|---|---|---|---|---|---|---|"]
    for k in ("Ecc", "Ell", "Err"):
        e = np.concatenate([r["signed"][k] for r in rows if r["se by segment"]])
        se = np.concatenate([r["se by segment"][k] for r in rows if r["se by segment"]])
        apical = np.concatenate([r["signed"][k][12:] for r in rows if r["se by segment"]])
        z = e / se
        ok = np.isfinite(z)
        out.append(f"| {k} | {int(ok.sum())} | {np.mean(e[ok]):+.2f} | {np.sqrt(np.mean(e[ok] ** 2)):.2f} | "
                   f"{np.mean(z[ok]):+.2f} | {np.sqrt(np.mean(z[ok] ** 2)):.2f} | "
                   f"{np.nanmean(apical):+.2f} |")
    return out


def bound_summary(rows):
    """How many noisy phantoms meet each twice-the-noise-free bound on all 16 segments."""
    out = ["| quantity | bound | phantoms within / all | worst segment error |", "|---|---|---|---|"]
    for name, b in BOUNDS_NOISY:
        worst = [r[name][0] for r in rows]
        out.append(f"| {name} | {b:g} | {sum(w <= b for w in worst)} / {len(rows)} | {max(worst):.2f} |")
    for name, b in (("Ecc_Global (%)", 1.0), ("Ell_Global (%)", 1.0)):
        worst = [abs(r[name][0] - r[name][1]) for r in rows]
        out.append(f"| {name} | {b:g} | {sum(w <= b for w in worst)} / {len(rows)} | {max(worst):.2f} |")
    worst = [abs(r["det F0"] - 1.0) for r in rows]
    out.append(f"| det F − 1 (unregularised fit) | 0.1 | {sum(w <= 0.1 for w in worst)} / {len(rows)} | {max(worst):.3f} |")
    return out


def ablation(rows):
    """The estimators of the noisy fit side by side: per quantity, phantoms within the noisy
    bound on all 16 segments, the worst segment error, the RMS and the mean segment error."""
    names = list(rows[0]["estimators"])
    out = ["| quantity | bound | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for k, b in (("Ecc", 2.0), ("Ell", 3.0), ("Err", 6.0)):
        cells = []
        for name in names:
            e = [r["estimators"][name][k] for r in rows]
            worst = [float(np.nanmax(np.abs(x))) for x in e]
            allv = np.concatenate(e)
            cells.append(f"{sum(w <= b for w in worst)} / {len(rows)} / {max(worst):.2f} / "
                         f"{np.sqrt(np.nanmean(allv ** 2)):.2f} / {np.nanmean(allv):+.2f}")
        out.append(f"| {k} | {b:g} | " + " | ".join(cells) + " |")
    return out


def offset_rows(rows):
    """The signed Err error split into each phantom's mean over its segments (an offset shared
    by the whole ventricle) and the segments' spread about it."""
    e = [r["signed"]["Err"] for r in rows]
    means = np.array([np.nanmean(x) for x in e])
    spread = np.concatenate([x - m for x, m in zip(e, means)])
    worst = [r["Err"][0] for r in rows]
    fail = [f"{r['subject']} ({m:+.1f})" for r, m, w in zip(rows, means, worst) if w > 6.0]
    return ["| quantity | value |", "|---|---|",
            f"| SD over phantoms of the per-phantom mean Err error | {np.std(means, ddof=1):.2f} |",
            f"| mean of the per-phantom mean Err error | {np.mean(means):+.2f} |",
            f"| RMS of the segment errors about their phantom's mean | {np.sqrt(np.nanmean(spread ** 2)):.2f} |",
            f"| phantoms over the Err bound (their mean Err error) | {', '.join(fail) or 'none'} |"]


def truth_rows(rows):
    out = ["| phantom | Ecc_Global | Ell_Global | Err_Global | WT_Global (mm) | Thickening_Global | "
           "GLS surface | GCS surface |", "|" + "---|" * 8]
    for r in rows:
        out.append(f"| {r['subject']} | " + " | ".join(
            f"{r[c][1]:.2f}" for c in ("Ecc_Global (%)", "Ell_Global (%)", "Err_Global (%)",
                                       "WT_Global (mm)", "Thickening_Global (%)",
                                       "GLS surface (%)", "GCS surface (%)")) + " |")
    return out


def rates(frames):
    out = []
    for pathology, seed in PRESETS:
        ph = generate(pathology, seed=seed, frames=frames, volume_check=False)
        got, _ = model_filling_rates(reconstruct(ph.study))
        t = ph.truth["metrics"]
        out.append((pathology, frames, {c: (got[c], t[c]) for c in RATE_COLUMNS}))
    return out


def curve_families(n_curves=12, seed=0):
    """Two families of analytic volume curves V(τ) = 1 − 0.6 f(τ) (τ = t / RR) with their exact
    dV/dτ: the phantom's piecewise-cubic phase curve (random knot fractions; corners at ED and
    ES) and C∞ curves (1 − cos ejection, Gaussian E and A waves in rate)."""
    from scipy.special import erf
    from cardionurbs.phantom.motion import VolumeCurve
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_curves):
        vc = VolumeCurve(es_fraction=rng.uniform(0.3, 0.42), rapid_filling=rng.uniform(0.5, 0.7),
                         diastasis=rng.uniform(0.05, 0.2))
        out.append(("piecewise cubic", lambda tau, vc=vc: 1 - 0.6 * vc(tau),
                    lambda tau, vc=vc: -0.6 * vc.derivative(tau), vc.es_fraction))
    for _ in range(n_curves):
        e, fa, wa = rng.uniform(0.3, 0.42), rng.uniform(0.15, 0.35), rng.uniform(0.03, 0.05)
        te, we, ta = e + rng.uniform(0.12, 0.18), rng.uniform(0.04, 0.07), 1 - 2.2 * wa

        def f(tau, e=e, fa=fa, wa=wa, ta=ta, te=te, we=we):
            tau = np.asarray(tau, float)
            cdf = lambda x, m, w: 0.5 * (1 + erf((x - m) / (np.sqrt(2) * w)))  # noqa: E731
            fill = (1 - fa) * (cdf(tau, te, we) - cdf(e, te, we)) + fa * (cdf(tau, ta, wa) - cdf(e, ta, wa))
            norm = (1 - fa) * (cdf(1, te, we) - cdf(e, te, we)) + fa * (cdf(1, ta, wa) - cdf(e, ta, wa))
            return np.where(tau <= e, 0.5 * (1 - np.cos(np.pi * np.clip(tau / e, 0, 1))), 1 - fill / norm)
        out.append(("Gaussian waves", lambda tau, f=f: 1 - 0.6 * f(tau),
                    lambda tau, f=f: -0.6 * (f(np.asarray(tau) + 1e-6) - f(np.asarray(tau) - 1e-6)) / 2e-6, e))
    return out


def estimator_comparison():
    """Worst relative error (%) of PER / PEFR / PAFR over each curve family, per interpolant
    and frame count (the peaks of each interpolant's derivative by the same windows as
    ``analysis.rates``; exact peaks on a 20 001-point grid of the exact derivative)."""
    from scipy.interpolate import Akima1DInterpolator, CubicSpline, PchipInterpolator
    from cardionurbs.analysis.rates import peak_rates

    def interpolant(kind, tc, vc):
        if kind in ("natural", "not-a-knot", "periodic"):
            sp = CubicSpline(tc, vc, bc_type=kind)
            return lambda x: sp(x, 1)
        if kind == "pchip":
            return PchipInterpolator(tc, vc).derivative()
        return Akima1DInterpolator(tc, vc, method="makima").derivative()
    kinds = ("natural", "not-a-knot", "periodic", "pchip", "makima")
    rr, rows = 1000.0, []
    curves = curve_families()
    for fam in ("piecewise cubic", "Gaussian waves"):
        for n in (20, 30, 40):
            worst = {k: np.zeros(3) for k in kinds}
            for name, V, dV, e in curves:
                if name != fam:
                    continue
                es = int(round(e * n))
                ee, t = es / n, np.arange(n) * rr / n
                exact = {}
                for col, (a, b) in {"PER (mL/s)": (0, ee), "PEFR (mL/s)": (ee, ee + 2 * (1 - ee) / 3),
                                    "PAFR (mL/s)": (ee + 2 * (1 - ee) / 3, 1)}.items():
                    d = dV(np.linspace(a, b - 1e-9, 20001)) / rr * 1000.0
                    exact[col] = float(np.max(-d if col.startswith("PER") else d))
                tc, vc = np.r_[t, rr], np.r_[V(t / rr), V(0.0)]
                for k in kinds:
                    got = peak_rates(interpolant(k, tc, vc), 0.0, t[es], rr, knots=tc)
                    err = [abs(100 * (got[c] / exact[c] - 1)) for c in RATE_COLUMNS[:3]]
                    worst[k] = np.maximum(worst[k], err)
            rows.append((fam, n, worst))
    return kinds, rows


def sunnybrook():
    from cardionurbs.io import load_study
    base = ROOT.parent / "shared" / "data" / "sunnybrook"
    rows = []
    for p in sorted(base.glob("SC-*")):
        model = reconstruct(load_study(p))
        r = regional_metrics(model, None)
        rows.append((p.name, r["GCS surface (%)"], r.surface.get("gcs_slice")))
    return rows


def timing(noise_px: float = 0.0):
    """Wall and CPU time (s) of ``regional_metrics`` on a 2-frame tagged normal phantom (with
    ``noise_px`` contour and tag noise: the regularised fit every real study gets): medians
    of 5 runs after a warm-up. CPU time (``time.process_time``, single-threaded BLAS) is the
    work done, independent of how many other jobs share the machine."""
    ph = generate("normal", seed=1, frames=2, volume_check=False, noise_px=noise_px)
    model = reconstruct(ph.study)
    tags = tag_metrics(model)
    regional_metrics(model, tags)                       # warm-up: surfaces, axes built
    wall, cpu = [], []
    for _ in range(5):
        t0, c0 = time.perf_counter(), time.process_time()
        regional_metrics(model, tags)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def run_all(jobs: list[tuple], n_jobs: int) -> list[dict]:
    """:func:`one` for every job (its arguments), in ``n_jobs`` processes when > 1, in order."""
    if n_jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(n_jobs) as pool:
            return list(pool.map(one, *zip(*jobs)))
    return [one(*j) for j in jobs]


def header(title: str, options: str) -> list[str]:
    """A report's title, its command (this script with ``options``) and where and when it ran;
    the caller's text continues the last line."""
    return [f"# {title}", "", "Command: `.venv/bin/python benchmarks/validate_regional.py"
            + (" " + options.strip() if options.strip() else "") + "`", "",
            f"Generated {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC on {platform.node()} "
            f"({os.cpu_count()} cores, Python {platform.python_version()})."]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--noise-seeds", type=int, default=4,
                    help="noisy phantoms per preset (seeds s, s + 1, ...: each its own noise draw)")
    ap.add_argument("--jobs", type=int, default=1, help="phantoms fitted in parallel processes")
    ap.add_argument("--out", default=str(ROOT / "reports" / "validation-regional.md"))
    ap.add_argument("--bench-out", default=str(ROOT / "reports" / "benchmark-regional.md"),
                    help="the speed section for reports/benchmark.md ('' to skip)")
    ap.add_argument("--anatomy", choices=("ideal", "realistic"), default="ideal",
                    help="realistic: only the noise-free tag strain on realistic phantoms, "
                         "into reports/validation-regional-realistic.md")
    ap.add_argument("--speed-only", action="store_true",
                    help="re-measure section 5 (speed) alone into --out and --bench-out")
    a = ap.parse_args(argv)
    if a.speed_only:
        return speed_only(a)
    if a.anatomy == "realistic":
        return realistic_report(a)
    presets = [(p, s + k) for p, s in PRESETS for k in range(a.seeds)]
    noisy_seeds = [(p, s + k) for p, s in PRESETS for k in range(max(a.seeds, a.noise_seeds))]
    jobs = ([(p, s, 0.0, "both") for p, s in presets] + [(p, s, 0.5, "both") for p, s in noisy_seeds]
            + [(p, s, 0.5, "tags") for p, s in noisy_seeds])
    rows = run_all(jobs, a.jobs)
    clean = rows[:len(presets)]
    noisy = [r for r in rows[len(presets):] if r["noise on"] == "both"]
    tag_noisy = [r for r in rows[len(presets):] if r["noise on"] == "tags"]
    rr = [x for n in (20, 30, 40) for x in rates(n)]
    kinds, comparison = estimator_comparison()
    sb = sunnybrook()
    med, cpu = timing()
    noisy = timing(0.5)
    L = header("Validation: regional function (AHA segments, wall thickness, strain, rates)",
               (f" --seeds {a.seeds}" if a.seeds != 1 else "")
               + (f" --noise-seeds {a.noise_seeds}" if a.noise_seeds != 4 else "")
               + (f" --jobs {a.jobs}" if a.jobs != 1 else "")) + [
         "Truth: `truth.json` of each phantom, computed from the analytic model "
         "(`cardionurbs.phantom.regional`), "
         "never from the reconstruction. Errors are measured − truth; strains in strain points "
         "(%), segment errors over AHA segments 1–16.", "",
         "## 1. Noise-free phantoms (2 frames: ED, ES)", ""]
    L += table(clean)
    L += ["", "Truth values of the global columns:", ""] + truth_rows(clean)
    L += ["", "## 2. With 0.5 px contour and tag noise", "",
          f"{max(a.seeds, a.noise_seeds)} phantoms per preset (seeds s, s + 1, …; each phantom "
          "its own noise draw), all reported.", ""] + table(noisy)
    L += ["", "Twice the noise-free bounds (the issue's target with 0.5 px tag noise; here the contours "
          "are noisy too), over these "
          "phantoms:", ""] + bound_summary(noisy)
    partial = [f"{r['subject']} ({r['segments']})" for r in noisy + clean if r["segments"] < 16]
    if partial:
        L += ["", "Segments with tagged tissue in the truth fewer than 16 (the others are "
              "compared): " + ", ".join(partial) + "."]
    L += ["", "Bias and calibration of the segment strains over all these noisy phantoms "
          "(error = measured − truth; z = error / the fit's standard error below):", ""]
    L += calibration(noisy)
    L += ["", "Estimators of the noisy fit side by side, on the same tags (each cell: phantoms "
          "within the bound on all 16 segments / all, worst segment error, RMS and mean segment "
          "error, strain points). Reported: the tag lines and the frame's LV endo- and "
          "epicardial contours fitted together (the contours as material boundaries, term (T3) "
          "of `analysis.tag_motion`), the volume prior J̄_s ~ N(1, s²) with s = 5 % stated a "
          "priori, ridge weights by the evidence. Compared: the same prior on the tags alone "
          "(the estimator before the contours joined); with the contours, the ridge penalties "
          "alone and the incompressibility weight κ chosen with them by the unbiased risk "
          "estimate; and the prior with s = 3 % and 7 %, to show how much the result depends "
          "on the stated spread:", ""] + ablation(noisy)
    L += ["", "What the data can tell: the standard error of each segment strain of the "
          "unregularised fit (tag lines and contours), σ √diag(B S⁻¹ Bᵀ) (σ the fit's noise: the ED-plane noise, or the frame's misfit if larger; S the fit's "
          "reduced Gauss–Newton matrix, B the derivative of the segment means with respect to "
          "the coefficients) — the Cramér–Rao bound of any unbiased estimate within the motion "
          "model (S1) — and the chance that an unbiased estimator with those errors puts all 16 "
          "segments within the bound, Π (2Φ(b / SE) − 1):", ""] + noise_rows(noisy)
    L += ["", "## 2b. With 0.5 px tag noise only (the issue's condition), contours exact", "",
          "The issue asks for twice the noise-free bounds \"with 0.5 px tag noise\". Section 2 adds "
          "the noise to the contours as well, which also moves the surfaces the strain directions, "
          "the AHA segments and the wall samples come from. Here the same phantoms get 0.5 px "
          "noise on the tag points only (`phantom.faults.add_noise(..., targets=(\"tags\",))`, "
          "drawn from each phantom's own noise generator), the contours stay exact; same "
          "estimator (tags and contours, the volume prior s = 5 %).", ""] + table(tag_noisy)
    L += ["", "Twice the noise-free bounds over these phantoms:", ""] + bound_summary(tag_noisy)
    L += ["", "Bias and calibration over these phantoms:", ""] + calibration(tag_noisy)
    L += ["", "The same tags fitted without the contours (the estimator before they joined), and "
          "the ridge alone with the contours:", ""] + ablation(tag_noisy)
    L += ["", "Where the remaining Err error is: the mean over the 16 segments of each phantom's "
          "signed Err error (a whole-ventricle offset, shared by every segment) against the spread "
          "of the errors about that mean:", ""] + offset_rows(tag_noisy)
    L += ["", "## 3. Filling and ejection rates (noise-free, relative error %)", "",
          "| phantom | frames | PER | PEFR | PAFR | E/A | truth PER / PEFR / PAFR (mL/s) |",
          "|---|---|---|---|---|---|---|"]
    for p, n, d in rr:
        e = {c: 100 * (d[c][0] / d[c][1] - 1) for c in d}
        L.append(f"| {p} | {n} | {e['PER (mL/s)']:+.1f} | {e['PEFR (mL/s)']:+.1f} | "
                 f"{e['PAFR (mL/s)']:+.1f} | {e['E/A ratio']:+.1f} | "
                 f"{d['PER (mL/s)'][1]:.0f} / {d['PEFR (mL/s)'][1]:.0f} / {d['PAFR (mL/s)'][1]:.0f} |")
    L += ["", "Rate estimator: worst error (%) of PER / PEFR / PAFR over 12 analytic curves of "
          "each family (`estimator_comparison`; the package uses the natural spline):", "",
          "| curves | frames | " + " | ".join(kinds) + " |", "|---|---|" + "---|" * len(kinds)]
    for fam, n, worst in comparison:
        L.append(f"| {fam} | {n} | " + " | ".join("/".join(f"{x:.1f}" for x in worst[k]) for k in kinds)
                 + " |")
    lo, hi = HF_GCS[0] - 2 * HF_GCS[1], HF_GCS[0] + 2 * HF_GCS[1]
    L += ["", "## 4. Sunnybrook (heart failure with infarction): GCS surface", "",
          "| study | GCS surface (%) | mid SA slice | within HF range |", "|---|---|---|---|"]
    for name, g, s in sb:
        L.append(f"| {name} | {g:.1f} | {s} | {'yes' if lo <= g <= hi else 'no'} |")
    L += ["", f"Published range for heart failure with reduced EF: mid-LV circumferential strain "
          f"{HF_GCS[0]} ± {HF_GCS[1]} % (mean ± SD; normal controls −14.6 ± 3.4 %), cine feature "
          "tracking, 1.5 T (Comparisons of myocardial strain and strain rate in patients with "
          "heart failure with preserved and reduced ejection fraction using Feature Tracking of "
          "cine MR images, *J Cardiovasc Magn Reson* 16(Suppl 1):P300, 2014, "
          "https://jcmr-online.biomedcentral.com/articles/10.1186/1532-429X-16-S1-P300). "
          f"Range used: mean ± 2 SD = [{lo:.1f}, {hi:.1f}] %. Sunnybrook has no long-axis "
          "views, so GLS surface is empty there.", "",
          "## 5. Speed", ""] + speed_lines(med, cpu, noisy)
    L += NOTES.splitlines()
    atomic.write_text(a.out, "\n".join(L) + "\n")
    if a.bench_out:
        write_benchmark(a.bench_out, med, cpu, noisy)
    print("\n".join(L))
    return 0


def speed_lines(med: float, cpu: float, noisy: tuple[float, float] | None = None) -> list[str]:
    """Section 5 of the report: the median wall and CPU time (s) of :func:`timing`, and of
    ``timing(0.5)`` (``noisy``) when given."""
    out = [f"`regional_metrics` (AHA segments at ED and ES, thickness by ray casting, tag strain "
           f"with its fit, surface strains) on a 2-frame tagged normal phantom after the analysis "
           f"has built its surfaces: median **{cpu * 1000:.0f} ms CPU** ({med * 1000:.0f} ms wall; "
           f"5 runs, single-threaded BLAS, load average {os.getloadavg()[0]:.1f} on the shared "
           "2-core machine, so the wall time is inflated by the other jobs)."]
    if noisy is not None:
        out.append(f"The same phantom with 0.5 px contour and tag noise, whose fit is regularised (the "
                   f"evidence search, the volume prior and the strains' derivatives with respect to "
                   f"the map's coefficients): median **{noisy[1] * 1000:.0f} ms CPU** "
                   f"({noisy[0] * 1000:.0f} ms wall).")
    return [" ".join(out), ""]


def write_benchmark(path, med: float, cpu: float, noisy: tuple[float, float] | None = None) -> None:
    """reports/benchmark-regional.md (the speed section for reports/benchmark.md)."""
    atomic.write_text(path, "\n".join([
        "# Regional analysis (issue 14)", "",
        "Command: `.venv/bin/python benchmarks/validate_regional.py` (section 5 of "
        "reports/validation-regional.md; `--speed-only` re-measures that section alone)", "",
        f"Measured {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC on {platform.node()} "
        f"({os.cpu_count()} cores, Python {platform.python_version()}, load average "
        f"{os.getloadavg()[0]:.1f}).", "",
        "`regional_metrics` — AHA segments at ED and ES, wall thickness by NURBS ray casting, "
        "tag strain (material-point fit refined on the tag lines, F, segment volume means) and "
        f"surface strains — adds a median **{cpu * 1000:.0f} ms of CPU time** "
        f"({med * 1000:.0f} ms wall on the shared machine; 5 runs, single-threaded BLAS) to a "
        "2-frame tagged normal phantom study after its surfaces are built. Target: < 0.5 s."
        + ("" if noisy is None else
           f" With 0.5 px contour and tag noise (the regularised fit every real study gets): "
           f"**{noisy[1] * 1000:.0f} ms of CPU time** ({noisy[0] * 1000:.0f} ms wall)."),
        ""]) + "\n")


def speed_only(a) -> int:
    """Re-measure section 5 alone: rewrite it in ``--out`` (the rest of the report kept) and
    ``--bench-out``, e.g. when the full run's timing fell in a busy moment of the machine."""
    med, cpu = timing()
    noisy = timing(0.5)
    text = Path(a.out).read_text()
    head, rest = text.split("## 5. Speed\n\n", 1)
    tail = rest[rest.index("## Notes"):]
    lines = speed_lines(med, cpu, noisy)
    atomic.write_text(a.out, head + "## 5. Speed\n\n" + "\n".join(lines) + "\n" + tail)
    if a.bench_out:
        write_benchmark(a.bench_out, med, cpu, noisy)
    print("\n".join(lines))
    return 0


REALISTIC_INFARCTS = (("normal", 1, "lad"), ("mr", 2, "rca"), ("phtn", 3, "lcx"))


def realistic_report(a) -> int:
    """Noise-free regional rows on realistic anatomy (section 1's table, the same estimator),
    written to reports/validation-regional-realistic.md unless ``--out`` says otherwise."""
    out = (ROOT / "reports" / "validation-regional-realistic.md"
           if a.out == str(ROOT / "reports" / "validation-regional.md") else Path(a.out))
    jobs = ([(p, s + k, 0.0, "both", "realistic", None) for p, s in PRESETS for k in range(a.seeds)]
            + [(p, s, 0.0, "both", "realistic", inf) for p, s, inf in REALISTIC_INFARCTS])
    rows = run_all(jobs, a.jobs)
    L = header("Validation: regional function on realistic anatomy (noise-free)",
               "--anatomy realistic" + (f" --seeds {a.seeds}" if a.seeds != 1 else "")
               + (f" --jobs {a.jobs}" if a.jobs != 1 else "")) + [
         "Realistic phantoms "
         "(`--anatomy realistic`: shape modes, segmental wall thickness, apex off the axis, saddle "
         "annuli, outflow tracts; docs/phantoms.md), 2 frames, no noise, against their `truth.json`; "
         "the columns are those of section 1 of reports/validation-regional.md (bounds there: "
         "thickness 0.5 mm, Ecc 1, Ell 1.5, Err 3 strain points, GCS/GLS 0.5).", ""]
    L += table(rows)
    L += ["", "Truth values of the global columns:", ""] + truth_rows(rows)
    L += ["", "## Reading", "",
          "- **Wall thickness, thickening and surface GLS/GCS** are measured from the NURBS "
          "surfaces and hold on realistic anatomy without an infarct as on the ideal one. With "
          "an infarct, the ED thickness holds too (the truth's endocardial grid now follows the "
          "infarct's thinning; before, it ignored it and the truth kept the healthy wall); at ES "
          "segments next to the territory read up to 1.2 mm thinner than the truth (up to "
          "1.7 mm on other seeds), "
          "probably because the thickness changes steeply there (a thin, hypokinetic territory "
          "beside a wall thickening by half) and the measured and the analytic ES segment "
          "boundaries (the ES long axis and RV insertion points) differ slightly: a segment "
          "mean across a steep edge moves with its boundary. Not resolved; the ES thickness "
          "and thickening of infarct phantoms are not validated.",
          "- **The strain truth's directions.** On realistic anatomy they follow the measurement's "
          "definition: the ED endocardial normal averaged over 10 mm (until now the truth took "
          "the raw normal, and on an infarct phantom that of the healthy wall; the averaged normal "
          "moves an infarct segment's Ecc truth by up to ~5 points, a non-infarct one's by less).",
          "- **Tag strain.** The tag-line fit's map carries 6 harmonics in the terms of r'² and "
          "θ' − θ that are constant across the wall (2 in the material-point start, in ζ' and in "
          "the transmural terms): with 2, as before, it left 0.4–0.7 mm of misfit on these exact "
          "tags, which its transmural terms absorbed (Err off by up to ~60 points); now the "
          "misfit is ~0.02–0.04 mm (column \"fit residual\"). Two differences between what was "
          "measured and what the truth averaged were fixed with it: the wall samples are rays "
          "split four times along the axis (one every ~0.7 mm of height, so a segment partly "
          "inside the tagged range is a mean over whole slices of the wall), and the truth "
          "averages over the tagged range the measurement uses (the LA tag planes tracked from "
          "ED to ES, along the tilted ED axis; before, the planes tagged at both frames, which "
          "left the basal segments with slivers or nothing). The table below splits the error: "
          "the same measurement with the exact motion in place of the fitted map (what the "
          "sampling and averaging leave) beside the fitted map. Where the two differ, the fit "
          "is short. The wall moves across its thickness with more regional detail than the "
          "map carries; fitted unregularised (the tags are exact), the map bent its weakly "
          "determined transmural terms to absorb that misfit, which Err — the least determined "
          "of the three — showed first (up to ~6 points off). The regularisation's σ is now the "
          "larger of the ED-plane tracking noise and the frame's own misfit "
          "(`analysis.tag_motion`, \"the misfit as noise\"; column σ): the misfit of 0.02–0.04 mm "
          "is treated as noise, and the volume prior and the evidence-chosen ridges tie the "
          "transmural terms to what the data determine. The last column is the estimator before "
          "(σ from the tracking noise alone, here unregularised). Without an infarct, Ecc, Ell, "
          "GCS, GLS and det F are within their bounds; Err is within 3 on most phantoms and a "
          "little over on some (table). With an infarct the tag strain is not within its bounds: the territory's "
          "hypokinesis ends at a sharp edge, which no smooth global map follows (fit residual "
          "0.2–0.3 mm on exact tags, the strains off by tens of points in and beside the "
          "territory, while the exact motion at the same samples reads within 3 points, the "
          "rest of it from segment means across the territory's steep edge). A map with regional support (finite elements or B-splines in "
          "prolate coordinates, as model-based tag analyses use) with a smoothness prior is "
          "what these need; not built. `regional.strain.fit_residual_mm` well above the tags' "
          "noise `tag_noise_mm` in metrics.json flags such a fit.",
          "", "| phantom | fit residual (mm) | σ (mm) | Ecc / Ell / Err max, fitted map | "
          "Ecc / Ell / Err max, exact motion | Ecc / Ell / Err max, σ = tracking noise (before) |",
          "|---|---|---|---|---|---|"]
    L += [f"| {r['subject']} | {r['residual mm']:.3f} | {r['sigma mm']:.3f} | {r['Ecc'][0]:.2f} / "
          f"{r['Ell'][0]:.2f} / {r['Err'][0]:.1f} | {r['exact motion']['Ecc']:.2f} / "
          f"{r['exact motion']['Ell']:.2f} / {r['exact motion']['Err']:.1f} | "
          f"{r['noise-only sigma']['Ecc']:.2f} / {r['noise-only sigma']['Ell']:.2f} / "
          f"{r['noise-only sigma']['Err']:.1f} |" for r in rows]
    atomic.write_text(out, "\n".join(L) + "\n")
    print("\n".join(L))
    return 0


NOTES = """## Notes

- **Thickness** is measured along the outward endocardial normal of the NURBS surface to the
  epicardial NURBS (Newton on (u, v, t) per ray, 48 × 36 rays); the truth bisects the same
  distance on the exact moved surfaces (80 × 160 cells). Both weight by endocardial area.
- **Ecc and Ell** are the volume means of the fitted strain over the tagged myocardium of each
  segment; the truth is the exact strain (central differences of the analytic motion) on a
  1 mm grid of the same region (between the outermost LA tag planes whose material points are
  tracked from ED to ES, as the measurement's extreme tracked points bound it).
- **Strain fit.** The map ED → ES is fitted to the material points (tag-surface triple
  intersections) and then refined on the tag points themselves by orthogonal-distance
  regression to the moved ED tag planes (`analysis.tag_motion`). The material points alone
  under-stated thickening (Err up to 42 points low, det F 0.90–0.955 noise-free): they come
  from tag surfaces lofted from tag curves with one control point per ~12 mm, which cannot
  follow an ES tag line's bend across a thickening wall, and there are one or two of them
  across the wall. The tag lines have a point every ~1 mm. The twist path (material points,
  `analysis.tags`) is unchanged, so reports/validation-tags.md stands.
- **ED-plane noise** is the RMS distance of the ED tag points to their tag's least-squares
  plane: an estimate of the tracking noise normal to the tags (0.5 px ≈ 0.6 mm here).
- **Directions.** r is the endocardial normal averaged over 10 mm of surface: with 0.5 px
  contour noise the raw NURBS normals tilt enough to bias Ecc by +1.7 and Err by −1.6 points
  (a tilt α moves Ecc by ≈ α² (Err − Ecc), upward whatever the tilt's sign). Averaged over
  6 mm (as the thickness rays still are) the residual tilt left a mean segment Ecc error of
  +0.25 points over these 24 noisy phantoms (mean z +0.88; normal 2's apical segment 14 at
  +2.08, over the bound); the table above gives it over 10 mm. Noise-free, the segment
  strains stay within 0.2 points of the 6 mm values. With exact tags and noisy contours
  alone, normal 1's mean Ecc error was +0.17 with 6 mm and +0.02 with 10 mm.
- **Near the axis.** Segment means (and the truth) leave out the myocardium within 10 mm of
  the ED long axis, and the myocardium whose image at the frame lies within 10 mm of that
  frame's long axis (the measurement with its fitted map, the truth with the exact motion;
  count in `regional.strain.near_axis_excluded`): the cylindrical map is singular on the
  axis (the radial stretch involves 1 / r'). Before the second condition, one point of
  phtn 5 whose fitted end-systolic r'² fell to the 1 mm² floor put segment 16's Err 75.7
  points off.
- **ED tag planes as one grid per family.** SPAMM lays a family's tags down as parallel,
  equally spaced planes, so each family is fitted as one grid (common normal, offsets
  a + b k), every plane estimated from all the family's ED points (an F-test at 0.999 keeps
  separate planes when the grid does not fit). A separately fitted plane has an offset
  error σ / √n_k (20–60 points for an LA tag), up to 0.3 mm here, which the fit reads as
  stretch between neighbouring tags; it is not in the fit's standard errors, and it was the
  main excess of the Ell errors over them (12 phantoms: Ell within 3 on 7 → 10, RMS 1.21 →
  1.04 points).
- **Tag points kept up to 3σ outside the contours** (σ the ED-plane noise; at least
  0.5 mm). The noise moves a point along its tag line too; a cut at 0.5 mm dropped the
  points near the endo- and epicardium that the noise pushed out of the wall and kept those
  it pushed in, which for lines crossing the wall obliquely shifts the kept points across
  the tag, in opposite directions at the two surfaces: segment Err was biased low (mean
  error −1.9 points over the 12 phantoms, −5 on normal 1). With the wider margin the mean
  error of Err is within its standard error and the errors match the fit's own standard
  errors (RMS z below 1).
- **With 0.5 px noise** the fit is regularised, as a Bayesian estimate: a ridge (a zero-mean
  Gaussian prior) on the terms that let the transmural gradient vary with height and angle,
  and on the highest order in height, with weights (λ, column "penalty") chosen by the
  marginal likelihood of the data (the evidence) from the ED-plane noise; and the prior
  that the volume mean J̄_s of det F over each AHA segment is N(1, s²) with s = 5 %, stated
  a priori (next note). Noise-free (noise below 0.01 mm) nothing changes: the prior's
  weight against the data is σ² / s². σ is the larger of the ED-plane noise and the frame
  fit's own misfit (degrees-of-freedom corrected): with noisy tags the two nearly agree (on
  the tag-noise phantoms of section 2b no segment moved by 0.01 points); with exact tags on a
  realistic heart the misfit is what the map cannot follow, and treating it as noise keeps
  the transmural terms from bending to absorb it (reports/validation-regional-realistic.md).
- **Near-incompressibility as a prior.** Myocardium keeps its volume within a few per cent,
  and det F ties the transmural stretch (measured worst) to the in-plane ones: at typical
  end-systolic strains dErr/dEcc ≈ −3.7 and dErr/dEll ≈ −3.2 at fixed det F. The spread is
  taken from the literature, not from these phantoms: in the canine LV the largest
  systolic volume loss was 4.1, 6.8 and 10.3 % at the subepicardium, midwall and
  subendocardium (Ashikaga et al., *Am J Physiol Heart Circ Physiol* 295:H610–H618, 2008);
  a zero-mean prior with s = 5 % puts the wall average at 1.4 s. The phantoms' truth is
  incompressible, so the prior's mean is exact for them; a real segment that loses 7 % is
  pulled towards 1 by the fraction SE² / (SE² + s²) of the difference, SE the data's own
  standard error of J̄_s (1.3–2.5 % on mr 7), i.e. by ≤ 1.5 % of volume, ~2–3 Err points
  upward. Because of the prior, the det F of the final fit is no independent check: the
  table reports the det F of the unregularised fit beside it (the check of the bounds
  table). The estimator before this one chose the prior's weight κ with the ridge weights
  by Stein's unbiased risk estimate of the segment strains' error; those weights swung
  from 0 to 1000 between phantoms of one kind, and Err met its bound on 10 of the first 24
  noisy phantoms. With the stated prior but the ridge weights still by the risk estimate,
  Err met it on 12 of those 24 (worst 14.7 points): the risk estimate itself, minimised over
  a grid of weights, is noisy; the evidence, which reads the ridge as a prior too (MacKay
  1992; Wahba 1985), is steadier and took it to 20 (worst 7.8). The cost, in the comparison
  table: on some phantoms the evidence's strong transmural ridge moves an apical Ecc by
  1–2 points (mr 5, segment 15), and the prior at 5 % holds det F less tightly than a large
  κ did on an exactly incompressible phantom, so a few Ell segments of phtn phantoms
  exceed 3 (their Ell standard errors reach 3.6–3.9 points). Tried before settling on
  segment means: det F penalised at 600 wall samples (pointwise), which did no better.
  Tried with the prior: keeping the evidence's ridge from moving any segment's Ecc or Ell
  by more than 2 of its standard errors (linearised) changed nothing (the apical Ecc shift
  is not in the linearisation). Wall thickening from the NURBS surfaces as a second Err
  source: (WT_ES / WT_ED)² mapped to Err missed the truth by up to 19 points with noise
  (RMS 7.8 on mr 7) and by 5–7.5 points noise-free (thickness along the ES normal of
  the ES segment is not the Lagrangian radial stretch), so it has no precision to add.
- **Seeds not looked at while choosing the estimator.** The estimator was chosen on the first
  24 noisy phantoms (8 seeds per preset); on the 12 of the next four seeds of each preset,
  Err is within 6 on all 16 segments on 9 (the risk-chosen κ before it: 7), Ecc within 2 on
  12 (before: 12) and Ell within 3 on 11 (before: 11).
- **Also tried, not kept:** removing the second-order bias of the strains (E is quadratic in
  F, so noise in the fitted field raises its mean by ½ tr(∇²E Cov); computed from the fit's
  covariance by symmetric sigma points) changed segment strains by ≤ 0.02 points; the fit
  without any penalty (λ = 0) left the Ell errors as they were, so the regularisation is not
  the source of the Ell errors either. Of the Ecc bias left with 6 mm directions (+0.25
  points on average, up to +2 in apical segments) about half came from the contour noise
  (with exact tags) and half from the tag noise at the apex; the 10 mm directions (below)
  remove most of the first half.
- **Radial strain is noise-limited.** The table of standard errors above is the fit's own
  covariance: with one or two tag lines across a 1 cm wall the transmural gradient is what
  the tags measure least well. With the tags alone the standard error of a segment's Err was
  a median of 3–6 strain points at σ ≈ 0.6 mm (up to 25 in an apical segment, where few tag
  lines cross the wall, obliquely), against at most 0.2–1.3 for Ecc, and an unbiased
  estimator put all 16 segments within 6 points with a probability of 0.001–0.22 per
  phantom. With the contours in the fit it is 2–3 points (the table above), and the
  regularised fit's own standard deviations (last column) about 1 point. That table
  treats every contour point's noise as independent; the ED surface the points slide on
  carries the ED contours' noise into all of them at once, so with contour noise it
  over-states what the contours add (the Err errors of section 2 exceed those standard
  errors on a few phantoms), while with exact contours (section 2b) the errors are within
  them. With the tags alone, most of the Err error was one offset shared by the whole
  ventricle (section 2b: the per-phantom mean Err error), which the contours measure (next
  note).
- **Contours as material boundaries** (reported estimator). The frame's LV endo- and
  epicardial contour points join the tag-line fit as images of points of the same ED
  surface (term (T3) of `analysis.tag_motion`: each slides on the tangent plane of its
  nearest ED NURBS sample), weighted by σ / σ_c, σ_c their RMS distance from the ED
  surfaces moved by the tag-only fit; only points between the lowest and highest tag point.
  They measure how far each boundary moved along its normal — the wall's thickening — so
  they fix the transmural offset the tags leave open. An earlier attempt in another form
  (the reconstructed ED and ES surfaces both as point-to-surface residuals, weighted by
  their own residual variance) biased Err low and did not help on the normal phantom; here
  the contour points themselves are the data and only the ED surface is reconstructed.
  Nothing was adjusted after the sweeps in this report (the sample grid, the two joint
  Gauss–Newton steps and the weighting were set before). With contour noise the ED surface
  carries the ED contours' noise into the term, which leaves Err biased low by about a
  point on average (calibration table of section 2).
- **Thickness with contour noise.** The rays follow the endocardial normal averaged over 6 mm
  (as the strain directions do): a ray tilted by α crosses a wall of thickness T over
  T / cos α, so the raw normals of a surface fitted to noisy contours over-stated the
  end-systolic thickness by ~0.3 mm on average and up to 1.4 mm per segment.
- **Speed** is given as CPU time (single-threaded BLAS) because the shared 2-core machine ran
  other engineers' test suites (load average up to ~20), which inflates wall time several
  fold; the tag-line fit (a few Gauss–Newton steps on ~3000 points, noise-free: no
  regularisation search) and the thickness rays (2 frames) dominate it.
- **Filling rates** need ≥ 10 frames. The curve is interpolated by the natural cubic spline
  (V'' = 0 on either side of ED). The not-a-knot spline used before overshot PAFR by
  15–23 % at 20 frames: the phantom's atrial kick lasts ~0.1 RR (two frame intervals) and its
  steepest rate is at the ED corner, where not-a-knot extends the cubic of the last two
  intervals. The estimator table above compares interpolants on curves that are not the
  phantom's (Gaussian E and A waves) as well as on the phantom's family.
"""


if __name__ == "__main__":
    sys.exit(main())
