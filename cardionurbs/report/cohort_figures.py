"""Cohort figures from the cohort CSV: distributions by group, measured vs truth, Bland–Altman.

Inputs
------
cohort CSV
    ``cardionurbs cohort`` / ``demo`` output: ``subject``, ``status`` and the
    docs/metrics.md columns, one row per study (rows whose status is not ``ok`` are
    left out of the plots and counted in the caption).
truth (optional, phantoms)
    the demo's ``truth.csv`` (``subject``, ``pathology``, docs/metrics.md columns), a
    folder holding ``<subject>/truth.json`` phantom folders, or a DataFrame.
groups
    ``normal``, ``MR``, ``PHTN``: from a ``group`` or ``pathology`` column of the
    cohort CSV or of the truth table, else an explicit mapping subject -> group;
    without any, every study is in one group ``all``.

Figures (PNG, headless Agg, Okabe–Ito colours per group)
--------------------------------------------------------
``cohort_distributions.png``
    one panel per metric: box plot (median, quartiles, 1.5 IQR whiskers) and
    the individual studies (jittered points) of each group.
``cohort_measured_vs_truth.png``
    one panel per metric: measured against truth with the identity line.
``cohort_bland_altman.png``
    one panel per metric: difference d = measured − truth against the mean
    (measured + truth) / 2, with the bias d̄ and the 95 % limits of agreement
    d̄ ± 1.96 s_d (Bland & Altman 1986, Lancet i:307, eqs. for LoA; s_d the
    sample standard deviation, ddof = 1).

A figure whose input is missing (no truth, no ok rows) is left out with one
line saying why.
"""

from __future__ import annotations

import json
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from cardionurbs.errors import CohortInputError
from cardionurbs.report.figures import DPI, OKABE_ITO, FigureResult, FigureSet, _result

__all__ = ["write_cohort_figures", "bland_altman", "BlandAltman", "read_truth", "cohort_groups",
           "DEFAULT_METRICS", "GROUP_COLOURS", "CohortInputError"]

DEFAULT_METRICS = ("LVEDV (mL)", "LVESV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVESV (mL)",
                   "RVEF (%)", "RVM (g)", "MR RegVol (mL)", "MR RegFrac (%)", "RV/LV EDV ratio",
                   "EI ES", "Twist (deg)", "Torsion (deg/cm)", "CL shear (deg)", "LS (%)")
GROUP_NAMES = {"normal": "normal", "mr": "MR", "phtn": "PHTN"}
GROUP_ORDER = ("normal", "MR", "PHTN")
GROUP_COLOURS = {"normal": OKABE_ITO["blue"], "MR": OKABE_ITO["vermillion"],
                 "PHTN": OKABE_ITO["bluish_green"], "all": OKABE_ITO["black"]}
_EXTRA = (OKABE_ITO["reddish_purple"], OKABE_ITO["orange"], OKABE_ITO["sky_blue"])


@dataclass(frozen=True)
class BlandAltman:
    """Bland–Altman agreement of paired values: bias, SD of differences, 95 % limits.

    Attributes
    ----------
    n : int
        Finite (measured, truth) pairs.
    bias : float
        Mean difference measured − truth, in the metric's unit.
    sd : float
        Sample standard deviation of the differences (ddof = 1), in the metric's unit.
    lower, upper : float
        The 95 % limits of agreement, bias ∓ 1.96 sd.
    """

    n: int
    bias: float
    sd: float
    lower: float
    upper: float


def bland_altman(measured: Sequence[float], truth: Sequence[float]) -> BlandAltman:
    """Bias d̄ = mean(m − t), s_d (ddof = 1), limits d̄ ± 1.96 s_d over finite pairs.

    With one pair s_d is NaN (and so are the limits); with none, everything is NaN.

    Parameters
    ----------
    measured : sequence of float, shape (n,)
        Measured values of one metric, one per subject.
    truth : sequence of float, shape (n,)
        Their reference values, same order and unit.

    Returns
    -------
    BlandAltman
        n, bias, sd and the limits, in the metric's unit (NaN as above).
    """
    m, t = np.asarray(measured, float), np.asarray(truth, float)
    ok = np.isfinite(m) & np.isfinite(t)
    d = m[ok] - t[ok]
    n = int(d.size)
    bias = float(d.mean()) if n else float("nan")
    sd = float(d.std(ddof=1)) if n > 1 else float("nan")
    return BlandAltman(n, bias, sd, bias - 1.96 * sd, bias + 1.96 * sd)


# ----------------------------------------------------------------- inputs
def _read_csv(path: Path, what: str) -> pd.DataFrame:
    try:
        df = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise CohortInputError(f"{path}: cannot read the {what} CSV "
                               f"({' '.join(str(exc).split())})") from None
    if "subject" not in df.columns:
        raise CohortInputError(f"{path}: the {what} CSV has no 'subject' column")
    df["subject"] = df["subject"].astype(str)
    return df


def read_truth(truth: str | Path | pd.DataFrame | None) -> pd.DataFrame | None:
    """Truth table (subject, [pathology], docs/metrics.md columns) from a CSV, a folder of
    phantom studies (``*/truth.json``), or a DataFrame; None stays None.

    Parameters
    ----------
    truth : str, path-like, pandas.DataFrame or None
        A truth CSV (with a ``subject`` column), a folder of phantom studies, or a table.

    Returns
    -------
    pandas.DataFrame or None
        One row per subject: ``subject``, ``pathology`` (folders) and the metric columns in
        their docs/metrics.md units (NaN where the truth has none); None for None.

    Raises
    ------
    cardionurbs.errors.CohortInputError
        The CSV cannot be read or has no ``subject`` column; a ``truth.json`` is not JSON;
        the folder holds no ``*/truth.json``.
    """
    if truth is None or isinstance(truth, pd.DataFrame):
        return truth
    p = Path(truth)
    if p.is_dir():
        rows = []
        for tj in sorted(p.glob("*/truth.json")):
            try:
                d = json.loads(tj.read_text())
            except (OSError, ValueError):
                raise CohortInputError(f"{tj}: not readable JSON") from None
            row = {"subject": str(d.get("subject", tj.parent.name)), "pathology": d.get("pathology")}
            row.update({k: (np.nan if v is None else v) for k, v in d.get("metrics", {}).items()})
            rows.append(row)
        if not rows:
            raise CohortInputError(f"{p}: no */truth.json phantom folders")
        return pd.DataFrame(rows)
    return _read_csv(p, "truth")


def cohort_groups(cohort: pd.DataFrame, truth: pd.DataFrame | None = None,
                  groups: Mapping[str, str] | None = None) -> pd.Series:
    """Group label per subject (index: subject), see module doc.

    Parameters
    ----------
    cohort : pandas.DataFrame
        The cohort table (``subject``, optionally ``group`` or ``pathology``).
    truth : pandas.DataFrame or None, optional
        The truth table, whose ``group`` or ``pathology`` is used when the cohort has none.
    groups : mapping of str to str, optional
        Subject -> group, taking precedence over both (a missing subject is ``"other"``).

    Returns
    -------
    pandas.Series
        Group name per subject (index: subject); ``"all"`` when nothing names groups.
    """
    subjects = cohort["subject"].astype(str)
    if groups:
        lab = subjects.map(lambda s: groups.get(s, "other"))
    else:
        src = None
        for df in (cohort, truth):
            if df is not None:
                col = next((c for c in ("group", "pathology") if c in df.columns), None)
                if col:
                    src = df.set_index(df["subject"].astype(str))[col]
                    break
        lab = subjects.map(lambda s: src.get(s, "other") if src is not None else "all")
    lab = lab.map(lambda g: GROUP_NAMES.get(str(g).lower(), str(g)))
    return pd.Series(lab.values, index=subjects.values)


def _group_colours(names: Sequence[str]) -> dict[str, str]:
    out, k = {}, 0
    for g in names:
        if g in GROUP_COLOURS:
            out[g] = GROUP_COLOURS[g]
        else:
            out[g] = _EXTRA[k % len(_EXTRA)]
            k += 1
    return out


def _ordered(names) -> list[str]:
    names = list(dict.fromkeys(names))
    return [g for g in GROUP_ORDER if g in names] + sorted(g for g in names if g not in GROUP_ORDER)


# ----------------------------------------------------------------- figures
def _grid(n: int, caption: str, ncols: int = 4):
    from matplotlib.figure import Figure
    nrows = max(1, int(np.ceil(n / ncols)))
    height = 2.45 * nrows + 0.95
    fig = Figure(figsize=(3.1 * ncols, height), dpi=DPI)
    axes = [fig.add_subplot(nrows, ncols, i + 1) for i in range(n)]
    bottom = 0.55 / height
    fig.subplots_adjust(left=0.07, right=0.99, top=1 - 0.7 / height,
                        bottom=bottom + 0.12 / nrows, hspace=0.7, wspace=0.42)
    fig.text(0.01, 0.005, textwrap.fill(caption, int(3.1 * ncols * 16)), fontsize=8, va="bottom")
    return fig, axes


def _legend(fig, colours: Mapping[str, str], marker: str = "o") -> None:
    from matplotlib.lines import Line2D
    fig.legend(handles=[Line2D([], [], ls="none", marker=marker, color=c, label=g)
                        for g, c in colours.items()], loc="upper center", ncol=len(colours),
               fontsize=8, frameon=False)


def _distributions(df, groups, metrics, colours, out, caption_tail) -> FigureResult:
    order = list(colours)
    caption = ("Cohort distributions by group: box (median, quartiles, whiskers 1.5 IQR) and "
               "individual studies; " + ", ".join(f"{g} n = {(groups == g).sum()}" for g in order)
               + caption_tail)
    fig, axes = _grid(len(metrics), caption)
    rng = np.random.default_rng(0)
    for ax, m in zip(axes, metrics):
        data = [df.loc[(groups == g).values, m].astype(float).dropna().to_numpy() for g in order]
        pos = np.arange(len(order))
        ax.boxplot([d if d.size else [np.nan] for d in data], positions=pos, widths=0.55,
                   showfliers=False, medianprops={"color": "black"}, whis=1.5)
        for i, (g, d) in enumerate(zip(order, data)):
            ax.plot(i + rng.uniform(-0.15, 0.15, d.size), d, "o", ms=3.5, color=colours[g],
                    alpha=0.9)
        ax.set_xticks(pos, order, fontsize=7)
        ax.set_title(m, fontsize=8.5)
        ax.tick_params(labelsize=7)
    _legend(fig, colours)
    return _result("cohort_distributions", fig, out, caption, colours)


def _paired(df, truth, metrics):
    t = truth.set_index(truth["subject"].astype(str))
    pairs = {}
    for m in metrics:
        if m not in t.columns:
            continue
        tv = df["subject"].map(lambda s: t[m].get(s, np.nan)).astype(float).to_numpy()
        mv = df[m].astype(float).to_numpy()
        if (np.isfinite(tv) & np.isfinite(mv)).sum() >= 1:
            pairs[m] = (mv, tv)
    return pairs


def _measured_vs_truth(df, groups, pairs, colours, out, caption_tail) -> FigureResult:
    caption = ("Measured versus phantom truth per metric (dashed: identity), coloured by group"
               + caption_tail)
    fig, axes = _grid(len(pairs), caption)
    for ax, (m, (mv, tv)) in zip(axes, pairs.items()):
        for g, c in colours.items():
            sel = (groups == g).values
            ax.plot(tv[sel], mv[sel], "o", ms=3.5, color=c)
        fin = np.concatenate([mv[np.isfinite(mv)], tv[np.isfinite(tv)]])
        lo, hi = float(fin.min()), float(fin.max())
        pad = 0.05 * (hi - lo) + 1e-9
        ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "--", color="#777777", lw=0.8)
        ax.set_title(m, fontsize=8.5)
        ax.set_xlabel("truth", fontsize=7)
        ax.set_ylabel("measured", fontsize=7)
        ax.tick_params(labelsize=7)
    _legend(fig, colours)
    return _result("cohort_measured_vs_truth", fig, out, caption, colours)


#: differences below this fraction of the values' magnitude are floating-point rounding, not
#: disagreement: such metrics get no Bland-Altman panel (their line in the caption instead)
ROUNDING_LEVEL = 1e-9


def _at_rounding_level(mv, tv) -> bool:
    fin = np.isfinite(mv) & np.isfinite(tv)
    if not fin.any():
        return False
    scale = max(float(np.abs(tv[fin]).max()), float(np.abs(mv[fin]).max()), 1.0)
    return float(np.abs(mv[fin] - tv[fin]).max()) <= ROUNDING_LEVEL * scale


def _unit(metric: str) -> str:
    """The unit in a column name 'LVEDV (mL)' -> ' (mL)'; '' when it has none."""
    return f" ({metric.rsplit('(', 1)[1].rstrip(')')})" if metric.endswith(")") else ""


def _bland_altman_fig(df, groups, pairs, colours, out, caption_tail
                      ) -> tuple[FigureResult | None, dict]:
    stats = {m: bland_altman(mv, tv) for m, (mv, tv) in pairs.items()}
    exact = [m for m, (mv, tv) in pairs.items() if _at_rounding_level(mv, tv)]
    shown = {m: p for m, p in pairs.items() if m not in exact}
    caption = ("Bland–Altman: measured − truth (y) against the mean of measured and truth (x), "
               "in the metric's unit; solid: bias, dashed: 95 % limits of agreement (bias ± "
               "1.96 SD)"
               + (f"; {', '.join(exact)}: measured equals truth to floating-point rounding "
                  f"(|difference| ≤ {ROUNDING_LEVEL:g} of the values), no panel"
                  if exact else "") + caption_tail)
    if not shown:
        return None, stats
    fig, axes = _grid(len(shown), caption)
    for ax, (m, (mv, tv)) in zip(axes, shown.items()):
        ba = stats[m]
        mean, diff = (mv + tv) / 2, mv - tv
        for g, c in colours.items():
            sel = (groups == g).values
            ax.plot(mean[sel], diff[sel], "o", ms=3.5, color=c)
        ax.axhline(ba.bias, color="black", lw=1)
        if np.isfinite(ba.sd):
            for y in (ba.lower, ba.upper):
                ax.axhline(y, color="black", lw=0.8, ls="--")
        ax.set_title(f"{m}\nbias {ba.bias:.3g}, LoA [{ba.lower:.3g}, {ba.upper:.3g}]",
                     fontsize=7.5)
        ax.set_xlabel(f"mean of measured and truth{_unit(m)}", fontsize=7)
        ax.set_ylabel(f"measured − truth{_unit(m)}", fontsize=7)
        ax.tick_params(labelsize=7)
    _legend(fig, colours)
    return _result("cohort_bland_altman", fig, out, caption, colours), stats


def write_cohort_figures(cohort_csv: str | Path | pd.DataFrame, out_dir: str | Path,
                         truth: str | Path | pd.DataFrame | None = None,
                         groups: Mapping[str, str] | None = None,
                         metrics: Sequence[str] | None = None) -> FigureSet:
    """Write the cohort figures (see module doc) into ``out_dir``; return the FigureSet.

    Also writes ``cohort_agreement.csv`` (metric, n, bias, sd, lower, upper) when truth is
    given, and ``skipped.txt`` (one line per figure left out).

    Parameters
    ----------
    cohort_csv : str, path-like or pandas.DataFrame
        The cohort table (``subject``, ``status`` and metric columns) or its CSV.
    out_dir : path-like
        The folder the PNGs, ``cohort_agreement.csv`` and ``skipped.txt`` go to (made).
    truth : str, path-like, pandas.DataFrame or None, optional
        The truth (see :func:`read_truth`); without it only the distributions are drawn.
    groups : mapping of str to str, optional
        Subject -> group (see :func:`cohort_groups`).
    metrics : sequence of str, optional
        The metric columns drawn (default :data:`DEFAULT_METRICS`).

    Returns
    -------
    cardionurbs.report.figures.FigureSet
        The figures written (paths and captions) and, per figure left out, why.

    Raises
    ------
    cardionurbs.errors.CohortInputError
        The cohort or truth CSV cannot be read or lacks a ``subject`` column.
    """
    from cardionurbs.io import atomic
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    df = cohort_csv.copy() if isinstance(cohort_csv, pd.DataFrame) else _read_csv(Path(cohort_csv), "cohort")
    tdf = read_truth(truth)
    fs = FigureSet()
    status = df["status"].astype(str) if "status" in df.columns else pd.Series(["ok"] * len(df))
    ok = df[(status == "ok").values].reset_index(drop=True)
    n_err = int(len(df) - len(ok))
    tail = f" ({n_err} stud{'y' if n_err == 1 else 'ies'} with errors left out)." if n_err else "."
    if ok.empty:
        reason = "no study with status ok in the cohort CSV"
        for n in ("cohort_distributions", "cohort_measured_vs_truth", "cohort_bland_altman"):
            fs.skipped[n] = reason
    else:
        want = [m for m in (metrics or DEFAULT_METRICS) if m in ok.columns
                and np.isfinite(ok[m].astype(float)).any()]
        grp = cohort_groups(ok, tdf, groups)
        colours = _group_colours(_ordered(grp.unique()))
        if want:
            fs.figures.append(_distributions(ok, grp, want, colours, out, tail))
        else:
            fs.skipped["cohort_distributions"] = "no metric with finite values"
        if tdf is None:
            why = "no truth given (phantom truth.csv or study folders with truth.json)"
            fs.skipped["cohort_measured_vs_truth"] = why
            fs.skipped["cohort_bland_altman"] = why
        else:
            pairs = _paired(ok, tdf, want)
            if not pairs:
                why = "no subject of the cohort has truth values for the plotted metrics"
                fs.skipped["cohort_measured_vs_truth"] = why
                fs.skipped["cohort_bland_altman"] = why
            else:
                fs.figures.append(_measured_vs_truth(ok, grp, pairs, colours, out, tail))
                res, stats = _bland_altman_fig(ok, grp, pairs, colours, out, tail)
                if res is None:
                    fs.skipped["cohort_bland_altman"] = ("every metric equals its truth to "
                                                         "floating-point rounding")
                else:
                    fs.figures.append(res)
                table = pd.DataFrame([{"metric": m, "n": s.n, "bias": s.bias, "sd": s.sd,
                                       "lower": s.lower, "upper": s.upper}
                                      for m, s in stats.items()])
                atomic.write_text(out / "cohort_agreement.csv", table.to_csv(index=False))
    atomic.write_text(out / "skipped.txt", "".join(f"{k}: {v}\n" for k, v in fs.skipped.items()))
    return fs
