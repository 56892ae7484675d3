"""Regional ground truth of the analytic phantom (truth.json), independent of any reconstruction.

Filling rates
    The LV volume is V(τ) = V_ED (1 − EF f(τ)) exactly (motion eq. M3), so
    dV/dt = −V_ED EF f'(τ) / RR with f' the exact derivative of the
    piecewise-cubic phase curve (:meth:`VolumeCurve.derivative`). The peaks
    are taken over the windows of the definitions
    (:func:`cardionurbs.analysis.rates.rate_windows`) on a 20 000-point grid
    plus the curve's knots (f' is piecewise quadratic, so its maximum over an
    interval is at a knot, an end or a grid point within 1e-5 of the vertex).

Wall thickness
    On a cell-centred (μ, θ) grid of the ED endocardial spheroid (80 × 160
    cells; the segment means change by < 0.002 mm from 240 × 480), each point
    and its surface normal are moved by the exact motion, and the distance
    along the normal to the moved epicardium is bisected on the analytic
    inverse map (:func:`wall_thickness_samples`). Segments come from the
    analytic apex, mitral centre, endocardial apex and RV insertion points
    (:func:`truth_aha_frame`); means are weighted by the moved surface area.
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


# ----------------------------------------------------------------- AHA segments
def truth_aha_frame(anatomy: Anatomy, motion: Motion, pose, specs, f: float):
    """The AHA geometry of the phantom at phase f in scanner mm, from analytic landmarks:
    apex = the epicardial apex, base = the mitral centre (0, 0, z_b) moved to phase f, cap at
    the endocardial apex λ z_endo_apex, θ_s from the analytic RV insertion points of every
    SA slice at phase f (the rule of :mod:`cardionurbs.analysis.aha`)."""
    from cardionurbs.analysis.aha import AhaFrame, insertion_bisector
    from cardionurbs.analysis.tag_surfaces import axis_frame
    from cardionurbs.phantom import annotate
    ends = motion.forward(anatomy, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, anatomy.z_base]]), f)
    apex, base = pose.to_scanner(ends)
    ins = [annotate.rv_insertion_points(anatomy, motion, s, f) for s in specs if s.view == "SA"]
    ins = np.concatenate([p for p in ins if p is not None])
    e1, e2, _ = axis_frame(apex, base)
    d = pose.to_scanner(ins) - apex
    th = insertion_bisector(np.arctan2(d @ e2, d @ e1))
    return AhaFrame(apex, base, float(motion.lam(f)) * anatomy.z_endo_apex, th, "analytic")


def endocardial_grid(anatomy: Anatomy, n_mu: int, n_theta: int):
    """Cell-centred material (μ, θ) grid on the ED LV endocardial spheroid below the base:
    x = a sin μ cos θ, y = a sin μ sin θ, z = z_c − c cos μ (heart frame)."""
    a, c, zc = anatomy.r_short_endo, anatomy.r_long_endo, anatomy.z_center
    mu_b = float(np.arccos(-(anatomy.z_base - zc) / c))
    dmu, dth = mu_b / n_mu, 2 * np.pi / n_theta
    mu = (np.arange(n_mu) + 0.5) * dmu
    th = (np.arange(n_theta) + 0.5) * dth
    M, T = np.meshgrid(mu, th, indexing="ij")

    def point(m, t):
        return np.stack([a * np.sin(m) * np.cos(t), a * np.sin(m) * np.sin(t), zc - c * np.cos(m)],
                        axis=-1).reshape(-1, 3)
    return M.ravel(), T.ravel(), dmu, dth, point


def wall_thickness_samples(anatomy: Anatomy, motion: Motion, f: float, n_mu: int = 80,
                           n_theta: int = 160, iterations: int = 30):
    """Endocardial points (heart frame, phase f), outward normals, area weights and the
    thickness along the normal to the epicardium, all from the analytic model.

    The endocardium at phase f is the ED spheroid mapped by φ_f; its tangents are central
    differences (step 1e-6 rad) of the mapped (μ, θ) grid, the normal their cross product.
    The epicardium at phase f is {x : s(φ_f⁻¹(x)) = s_epi(z(φ_f⁻¹(x)))} (the material
    epicardium, moved); along each ray the root of s − s_epi (negative on the
    endocardium, increasing outward) is bracketed in [0, 60] mm and bisected (30 halvings: 6e-8 mm).
    """
    M, T, dmu, dth, point = endocardial_grid(anatomy, n_mu, n_theta)
    h = 1e-6
    x = motion.forward(anatomy, point(M, T), f)
    tm = (motion.forward(anatomy, point(M + h, T), f) - motion.forward(anatomy, point(M - h, T), f)) / (2 * h)
    tt = (motion.forward(anatomy, point(M, T + h), f) - motion.forward(anatomy, point(M, T - h), f)) / (2 * h)
    n = np.cross(tm, tt)
    area = np.linalg.norm(n, axis=1)
    n /= area[:, None]
    radial = x.copy()
    radial[:, 2] = 0.0
    if float(np.einsum("ij,ij->", radial, n)) < 0:
        n = -n
    w = area * dmu * dth
    lo, hi = np.zeros(len(x)), np.full(len(x), 60.0)

    def g(t):
        s, _, _, _, s2, _ = motion.inverse_cylindrical(anatomy, x + t[:, None] * n, f)
        return s - s2
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        out = g(mid) > 0
        hi = np.where(out, mid, hi)
        lo = np.where(out, lo, mid)
    return x, n, w, 0.5 * (lo + hi)


def wall_thickness_truth(anatomy: Anatomy, motion: Motion, pose, specs, f_es: float,
                         n_mu: int = 80, n_theta: int = 160) -> dict[str, float]:
    """WT, WT_ES and Thickening columns of the analytic phantom (mm, %), per AHA segment of
    the frame's own geometry (:func:`truth_aha_frame`), area-weighted over the endocardium."""
    from cardionurbs.analysis.thickness import segment_means, thickness_columns
    per = {}
    for key, f in (("ed", 0.0), ("es", f_es)):
        x, _, w, t = wall_thickness_samples(anatomy, motion, f, n_mu, n_theta)
        aha = truth_aha_frame(anatomy, motion, pose, specs, f)
        per[key] = segment_means(t, w, aha.segments(pose.to_scanner(x)))
    return thickness_columns(per["ed"], per["es"])
