"""Regional ground truth of the analytic phantom (truth.json), independent of any reconstruction.

Filling rates
    The LV volume is V(τ) = V_ED (1 − EF f(τ)) exactly (motion eq. M3), so
    dV/dt = −V_ED EF f'(τ) / RR with f' the exact derivative of the
    piecewise-cubic phase curve (:meth:`VolumeCurve.derivative`). The peaks
    are taken over the windows of the definitions
    (:func:`cardionurbs.analysis.rates.rate_windows`) on a 20 000-point grid
    plus the curve's knots (f' is piecewise quadratic, so its maximum over an
    interval is at a knot, an end or a grid point within 1e-5 of the vertex).
"""

from __future__ import annotations

import numpy as np

from cardionurbs.analysis.rates import MIN_FRAMES, RATE_COLUMNS, rate_windows
from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.motion import Motion

NAN = float("nan")


def filling_rate_truth(anatomy: Anatomy, motion: Motion, n_frames: int, es_frame: int,
                       rr_ms: float) -> dict[str, float]:
    """PER, PEFR, PAFR (mL/s) and E/A ratio of the analytic LV volume curve; NaN below
    MIN_FRAMES frames (the measurement's own rule)."""
    if n_frames < MIN_FRAMES:
        return {c: NAN for c in RATE_COLUMNS}
    v_ed = anatomy.lv_cavity_volume() / 1000.0                      # mL
    curve = motion.curve
    e = es_frame / n_frames
    ts, _ = curve.knots()
    out = {}
    for col, (a, b) in rate_windows(0.0, e, 1.0).items():
        tau = np.unique(np.r_[np.linspace(a, b, 20001), ts[(ts >= a) & (ts <= b)]])
        tau = np.clip(tau, 0.0, 1.0 - 1e-12)                          # the end of the beat, not τ = 0
        dvdt = -v_ed * motion.lv_ef * curve.derivative(tau) / rr_ms * 1000.0   # mL/s
        out[col] = float(np.max(-dvdt if col == "PER (mL/s)" else dvdt))
    out["E/A ratio"] = out["PEFR (mL/s)"] / out["PAFR (mL/s)"]
    return out
