"""Volumes by summation of disks (the clinical "Simpson's" method), for comparison.

    V = d · Σ_i A_i

with A_i the area enclosed by the contour on SA slice i (shoelace formula in
the slice plane, mm²) and d the slice spacing (median distance between
neighbouring slice planes along their normal, mm). Myocardial volume is
d · Σ (A_epi − A_endo). This is what the models are compared with: its error
depends on where the slices fall relative to base and apex.
"""

from __future__ import annotations

import numpy as np

from cardionurbs.analysis.function import COLUMNS, NAN, mass_g, regurgitation, ventricular_function
from cardionurbs.anatomy.sections import _sa_loops, stacking_direction
from cardionurbs.geometry import polygon_area, slice_spacing
from cardionurbs.study import Study


def disk_areas(study: Study, frame: int) -> dict[str, dict[str, float]]:
    """Area (mm²) of each surface's SA contour per slice at one frame
    (CAP open RV parts closed as in the models).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.

    Returns
    -------
    dict of str to dict of str to float
        Surface (``lv_endo`` ...) -> slice -> area, mm².
    """
    n, _ = stacking_direction(study, frame)
    out: dict[str, dict[str, float]] = {}
    for s, loops in _sa_loops(study, frame).items():
        out[s] = {sl: polygon_area(pts, n) for sl, pts, _ in loops}
    return out


def disk_volumes(study: Study, frame: int, spacing: float | None = None) -> dict[str, float]:
    """Volumes (mL) by disk summation at one frame: lv_cavity, lv_myocardium,
    rv_cavity, rv_myocardium (NaN where contours are missing).

    RV cavity area = area(rv_endo); RV wall area = area(rv_epi) − area(rv_endo)
    (docs/metrics.md: rv_epi encloses the RV cavity and free wall).

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    spacing : float or None
        The disk thickness, mm; None: the median SA slice gap.

    Returns
    -------
    dict of str to float
        Solid -> volume, mL.
    """
    n, _ = stacking_direction(study, frame)
    if spacing is None:
        levels = [im.position @ n for im in study.images if im.view == "SA" and im.frame == frame]
        if len(levels) < 2:
            levels = [im.position @ n for im in study.images if im.view == "SA"]
        spacing = slice_spacing(np.asarray(levels))
    a = disk_areas(study, frame)

    def total(s: str) -> float:
        return sum(a.get(s, {}).values()) if a.get(s) else NAN

    def wall(outer: str, inner: str) -> float:
        o, i = a.get(outer, {}), a.get(inner, {})
        both = [sl for sl in o if sl in i]
        return sum(o[sl] - i[sl] for sl in both) if both else NAN

    return {"lv_cavity": spacing * total("lv_endo") / 1000.0,
            "lv_myocardium": spacing * wall("lv_epi", "lv_endo") / 1000.0,
            "rv_cavity": spacing * total("rv_endo") / 1000.0,
            "rv_myocardium": spacing * wall("rv_epi", "rv_endo") / 1000.0}


def simpson_metrics(study: Study, ed_frame: int, es_frame: int,
                    heart_rate_bpm: float | None = None) -> dict[str, float]:
    """The volume columns of docs/metrics.md by disk summation at the given ED/ES frames.

    Parameters
    ----------
    study : Study
        The study.
    ed_frame, es_frame : int
        The ED and ES frames.
    heart_rate_bpm : float or None
        For the cardiac output columns; None: the study's.

    Returns
    -------
    dict of str to float
        docs/metrics.md column -> value (mL, %, g, L/min).
    """
    hr = study.heart_rate_bpm if study.heart_rate_bpm is not None else heart_rate_bpm
    hr = float(hr) if hr is not None else NAN
    ed, es = disk_volumes(study, ed_frame), disk_volumes(study, es_frame)
    out = {c: NAN for c in COLUMNS}
    out["HR (bpm)"] = hr
    for side, cav, myo in (("LV", "lv_cavity", "lv_myocardium"), ("RV", "rv_cavity", "rv_myocardium")):
        f = ventricular_function(ed[cav], es[cav], hr)
        out[f"{side}EDV (mL)"], out[f"{side}ESV (mL)"] = ed[cav], es[cav]
        out[f"{side}SV (mL)"], out[f"{side}EF (%)"] = f["SV"], f["EF"]
        if side == "LV":
            out["LVCO (L/min)"] = f["CO"]
        out[f"{side}M (g)"] = mass_g(ed[myo])
    out["MR RegVol (mL)"], out["MR RegFrac (%)"] = regurgitation(out["LVSV (mL)"], out["RVSV (mL)"])
    return out
