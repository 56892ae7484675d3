"""Regional ground truth of the analytic phantom (truth.json), independent of any reconstruction.

Filling rates
    The LV volume is V(τ) = V_ED (1 − EF f(τ)) exactly (motion eq. M3), so
    dV/dt = −V_ED EF f'(τ) / RR with f' the exact derivative of the
    piecewise-cubic phase curve (:meth:`VolumeCurve.derivative`). The peaks
    are taken over the windows of the definitions (systole [0, τ_ES], early
    diastole the first two thirds of [τ_ES, 1], atrial the last third) on a 20 000-point grid
    plus the curve's knots (f' is piecewise quadratic, so its maximum over an
    interval is at a knot, an end or a grid point within 1e-5 of the vertex).

Wall thickness
    On a cell-centred (μ, θ) grid of the ED endocardial spheroid (80 × 160
    cells; the segment means change by < 0.002 mm from 240 × 480), each point
    and its surface normal are moved by the exact motion, and the distance
    along the normal to the moved epicardium is bisected on the analytic
    inverse map (:func:`wall_thickness_samples`). Segments come from the
    analytic apex, mitral centre, endocardial apex and RV insertion points
    (:func:`truth_segments`); means are weighted by the moved surface area.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cardionurbs.geometry import averaged_normals
from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.motion import Motion

NAN = float("nan")
#: radius (mm) over which the measurement averages the endocardial normals for the strain
#: directions (its definition, docs/metrics.md; the same value as the analysis' constant)
DIRECTION_SMOOTHING_MM = 10.0
#: the rate columns and the fewest frames they are reported for (as the measurement)
RATE_COLUMNS = ("PER (mL/s)", "PEFR (mL/s)", "PAFR (mL/s)", "E/A ratio")
MIN_FRAMES = 10
SEGMENTS = range(1, 17)


def filling_rate_truth(anatomy: Anatomy, motion: Motion, n_frames: int, es_frame: int,
                       rr_ms: float, dv_df=None) -> dict[str, float]:
    """PER, PEFR, PAFR (mL/s) and E/A ratio of the analytic LV volume curve; NaN below
    MIN_FRAMES frames (the measurement's own rule).

    dV/dt = dV/df · f'(τ) / RR. ``dv_df`` (mL per unit phase, a function of f): by default the
    ideal anatomy's exact −V_ED EF; a realistic anatomy passes the derivative of its numerical
    volume curve (:func:`realistic_regional_truth`).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    n_frames : int
        Frames per cycle.
    es_frame : int
        The ES frame index, 0-based.
    rr_ms : float
        The R-R interval, ms.
    dv_df : callable, optional
        dV/df in mL per unit phase, as a function of f.
    Returns
    -------
    dict of str to float
        ``PER (mL/s)``, ``PEFR (mL/s)``, ``PAFR (mL/s)``, ``E/A ratio``.
    """
    if n_frames < MIN_FRAMES:
        return {c: NAN for c in RATE_COLUMNS}
    if dv_df is None:
        v_ed = anatomy.lv_cavity_volume() / 1000.0                  # mL
        slope = -v_ed * motion.lv_ef

        def dv_df(f):
            return np.full(np.shape(f), slope)
    curve = motion.curve
    e = es_frame / n_frames
    ts, _ = curve.knots()
    out = {}
    windows = {"PER (mL/s)": (0.0, e), "PEFR (mL/s)": (e, e + 2 * (1 - e) / 3),
               "PAFR (mL/s)": (e + 2 * (1 - e) / 3, 1.0)}
    for col, (a, b) in windows.items():
        tau = np.unique(np.r_[np.linspace(a, b, 20001), ts[(ts >= a) & (ts <= b)]])
        tau = np.clip(tau, 0.0, 1.0 - 1e-12)                          # the end of the beat, not τ = 0
        dvdt = dv_df(curve(tau)) * curve.derivative(tau) / rr_ms * 1000.0   # mL/s
        out[col] = float(np.max(-dvdt if col == "PER (mL/s)" else dvdt))
    out["E/A ratio"] = out["PEFR (mL/s)"] / out["PAFR (mL/s)"]
    return out


# ----------------------------------------------------------------- AHA segments
def wrap(angle):
    """Angles wrapped to [−π, π).

    Parameters
    ----------
    angle : float or array_like
        Angles, rad.

    Returns
    -------
    ndarray
        The wrapped angles, rad.
    """
    return (np.asarray(angle, float) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class TruthSegments:
    """The AHA geometry of the phantom at one phase, in the heart frame (apex at the origin,
    z along the axis): axis length, cap height and septal angle θ_s (rad; angles are
    counter-clockwise seen from the apex, i.e. θ = −atan2(y, x)).

    Attributes
    ----------
    length : float
        Axis length, apex to mitral centre, mm.
    cap : float
        Height of the apical cap (segment 17), mm.
    septal_angle : float
        θ_s, rad.
    origin : tuple of float
        The apex in the heart frame, mm.
    basis : tuple of tuple of float
        Rows e1, e2 and the axis e (unit vectors).
    """

    length: float
    cap: float
    septal_angle: float
    origin: tuple = (0.0, 0.0, 0.0)     # the apex; realistic anatomy: the bent apex at the phase
    basis: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))   # rows e1, e2, axis

    def local(self, x: np.ndarray) -> np.ndarray:
        """Heart-frame points in the axis frame (apex origin, z along apex → mitral centre).

        Parameters
        ----------
        x : ndarray, shape (n, 3)
            Heart-frame points, mm.
        Returns
        -------
        ndarray, shape (n, 3)
            Axis-frame coordinates, mm.
        """
        return (np.asarray(x, float).reshape(-1, 3) - np.asarray(self.origin)) @ np.asarray(self.basis).T

    def segments(self, x: np.ndarray) -> np.ndarray:
        """AHA segment 1..17 of heart-frame points (0 beyond the base); the rule of
        docs/metrics.md written out independently of the measurement.

        Parameters
        ----------
        x : ndarray, shape (n, 3)
            Heart-frame points, mm.
        Returns
        -------
        ndarray of int, shape (n,)
            AHA segment 1..17, 0 beyond the base.
        """
        x = self.local(x)
        h = x[:, 2]
        t = np.mod(-np.arctan2(x[:, 1], x[:, 0]) - self.septal_angle, 2 * np.pi)
        third = (self.length - self.cap) / 3.0
        ring = np.floor((h - self.cap) / third)
        six = np.minimum(np.floor(np.mod(t + np.radians(120), 2 * np.pi) / np.radians(60)), 5)
        four = np.minimum(np.floor(np.mod(t + np.radians(135), 2 * np.pi) / np.radians(90)), 3)
        lab = np.where(ring >= 2, 1 + six, np.where(ring == 1, 7 + six, 13 + four))
        lab = np.where(h < self.cap, 17, lab)
        return np.where(h > self.length + 1e-9, 0, lab).astype(int)


def truth_segments(anatomy: Anatomy, motion: Motion, specs, f: float) -> TruthSegments:
    """Segments at phase f from analytic landmarks: the epicardial apex (fixed at the origin),
    the mitral centre at height λ z_b, the endocardial apex at λ z_endo_apex, and θ_s the
    midpoint between the mean angles of the anterior and of the inferior RV insertion points
    (:func:`annotate.rv_insertion_points` on every SA slice at phase f).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    TruthSegments
        The segment geometry at phase f.
    """
    from cardionurbs.phantom import annotate
    lam = float(motion.lam(f))
    pts = [annotate.rv_insertion_points(anatomy, motion, s, f) for s in specs if s.view == "SA"]
    pts = [p for p in pts if p is not None]
    if anatomy.realistic:
        return _realistic_segments(anatomy, motion, pts, f)
    means = []
    for i in (0, 1):
        th = -np.arctan2([p[i, 1] for p in pts], [p[i, 0] for p in pts])
        means.append(float(np.arctan2(np.sin(th).mean(), np.cos(th).mean())))
    septal = float(wrap(means[0] + wrap(means[1] - means[0]) / 2.0))
    return TruthSegments(lam * anatomy.z_base, lam * anatomy.z_endo_apex, septal)


def axis_frame(anatomy: Anatomy, motion: Motion, f: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin, basis rows e1, e2, e) of a realistic heart at phase f, heart frame: the bent
    epicardial apex, e toward the centroid of the (bent) mitral annulus points, e1 the heart x
    axis made perpendicular to e, e2 = e × e1 (the heart frame's handedness).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    origin : ndarray, shape (3,)
        The bent epicardial apex, mm.
    basis : ndarray, shape (3, 3)
        Rows e1, e2, e.
    """
    from cardionurbs.phantom import annotate
    lm = annotate.landmarks(anatomy, motion, f)
    apex = annotate.bend(anatomy, lm["apex"])[0]
    e = annotate.bend(anatomy, lm["mitral"]).mean(axis=0) - apex
    e /= np.linalg.norm(e)
    e1 = np.array([1.0, 0.0, 0.0]) - e[0] * e
    e1 /= np.linalg.norm(e1)
    return apex, np.array([e1, np.cross(e, e1), e])


def _realistic_segments(anatomy: Anatomy, motion: Motion, pts: list, f: float) -> TruthSegments:
    """:func:`truth_segments` of a realistic anatomy, in the axis frame of the phase."""
    from cardionurbs.phantom import annotate
    origin, basis = axis_frame(anatomy, motion, f)
    probe = TruthSegments(1.0, 0.0, 0.0, tuple(origin), tuple(map(tuple, basis)))
    lm = annotate.landmarks(anatomy, motion, f)
    length = float(probe.local(annotate.bend(anatomy, lm["mitral"]).mean(axis=0))[0, 2])
    endo_apex = annotate.bend(anatomy, motion.forward(anatomy, np.array([[0.0, 0.0, anatomy.z_endo_apex]]), f))
    cap = float(probe.local(endo_apex)[0, 2])
    means = []
    for i in (0, 1):
        q = probe.local(annotate.bend(anatomy, np.array([p[i] for p in pts])))
        th = -np.arctan2(q[:, 1], q[:, 0])
        means.append(float(np.arctan2(np.sin(th).mean(), np.cos(th).mean())))
    septal = float(wrap(means[0] + wrap(means[1] - means[0]) / 2.0))
    return TruthSegments(length, cap, septal, tuple(origin), tuple(map(tuple, basis)))


def segment_means(values: np.ndarray, weights: np.ndarray, labels: np.ndarray) -> dict[int, float]:
    """Weighted mean per segment 1..16 (NaN where a segment has no sample).

    Parameters
    ----------
    values : ndarray, shape (n,)
        Sample values.
    weights : ndarray, shape (n,)
        Their weights (e.g. areas, mm²).
    labels : ndarray of int, shape (n,)
        Their AHA segments.
    Returns
    -------
    dict of int to float
        Segment 1..16 -> weighted mean.
    """
    return {k: (float(np.average(values[labels == k], weights=weights[labels == k]))
                if np.any(labels == k) else NAN) for k in SEGMENTS}


def endocardial_grid(anatomy: Anatomy, n_mu: int, n_theta: int):
    """Cell-centred material (μ, θ) grid on the ED LV endocardium below the base: z = z_c − c cos μ
    and, at that height, x = r cos θ, y = r sin θ with r = a sin μ (ideal spheroid) or the
    realistic section's √S_endo(z, θ) (shape modes and an infarct's thinning; heart frame).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    n_mu : int
        Cells along the endocardium (μ).
    n_theta : int
        Cells around it (θ).
    Returns
    -------
    mu, theta : ndarray, shape (n_mu * n_theta,)
        The cell centres, rad.
    dmu, dth : float
        The cell sizes, rad.
    point : callable
        ``point(mu, theta) -> (n, 3)`` material points, mm.
    """
    a, c, zc = anatomy.r_short_endo, anatomy.r_long_endo, anatomy.z_center
    mu_b = float(np.arccos(-(anatomy.z_base - zc) / c))
    dmu, dth = mu_b / n_mu, 2 * np.pi / n_theta
    mu = (np.arange(n_mu) + 0.5) * dmu
    th = (np.arange(n_theta) + 0.5) * dth
    M, T = np.meshgrid(mu, th, indexing="ij")

    def point(m, t):
        z = zc - c * np.cos(m)
        if anatomy.shape is None:
            r = a * np.sin(m)
        else:                                   # the realistic section S(z, θ), infarct included
            r = np.sqrt(np.maximum(anatomy.s_lv_endo(z, t), 0.0))
        return np.stack([r * np.cos(t), r * np.sin(t), z], axis=-1).reshape(-1, 3)
    return M.ravel(), T.ravel(), dmu, dth, point


def placed(anatomy: Anatomy, motion: Motion, x: np.ndarray, f: float) -> np.ndarray:
    """Material heart-frame points -> positions at phase f in the (realistic, bent) heart frame.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    x : ndarray, shape (n, 3)
        Material heart-frame points, mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    ndarray, shape (n, 3)
        Positions at phase f in the bent heart frame, mm.
    """
    from cardionurbs.phantom import annotate
    return annotate.bend(anatomy, x if motion is None else motion.forward(anatomy, x, f))


def wall_thickness_samples(anatomy: Anatomy, motion: Motion, f: float, n_mu: int = 80,
                           n_theta: int = 160, iterations: int = 30):
    """Endocardial points (heart frame, phase f), outward normals, area weights and the
    thickness along the normal to the epicardium, all from the analytic model.

    The endocardium at phase f is the ED spheroid mapped by φ_f; its tangents are central
    differences (step 1e-6 rad) of the mapped (μ, θ) grid, the normal their cross product.
    The epicardium at phase f is {x : s(φ_f⁻¹(x)) = s_epi(z(φ_f⁻¹(x)))} (the material
    epicardium, moved); along each ray the root of s − s_epi (negative on the
    endocardium, increasing outward) is bracketed in [0, 60] mm and bisected (30 halvings: 6e-8 mm).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_mu, n_theta : int, optional
        Grid cells along (μ) and around (θ) the endocardium.
    iterations : int, optional
        Bisection halvings.
    Returns
    -------
    points : ndarray, shape (n, 3)
        Endocardial points at phase f, mm.
    normals : ndarray, shape (n, 3)
        Outward unit normals.
    weights : ndarray, shape (n,)
        Area weights, mm².
    thickness : ndarray, shape (n,)
        Wall thickness along the normal, mm.
    """
    from cardionurbs.phantom import annotate
    M, T, dmu, dth, point = endocardial_grid(anatomy, n_mu, n_theta)
    h = 1e-6
    x = placed(anatomy, motion, point(M, T), f)
    tm = (placed(anatomy, motion, point(M + h, T), f) - placed(anatomy, motion, point(M - h, T), f)) / (2 * h)
    tt = (placed(anatomy, motion, point(M, T + h), f) - placed(anatomy, motion, point(M, T - h), f)) / (2 * h)
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
        s, _, _, _, s2, _ = motion.inverse_cylindrical(anatomy, annotate.unbend(anatomy, x + t[:, None] * n), f)
        return s - s2
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        out = g(mid) > 0
        hi = np.where(out, mid, hi)
        lo = np.where(out, lo, mid)
    return x, n, w, 0.5 * (lo + hi)


def wall_thickness_truth(anatomy: Anatomy, motion: Motion, specs, f_es: float,
                         n_mu: int = 80, n_theta: int = 160) -> dict[str, float]:
    """WT, WT_ES and Thickening columns of the analytic phantom (mm, %), per AHA segment of
    the frame's own geometry (:func:`truth_aha_frame`), area-weighted over the endocardium.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices.
    f_es : float
        The cycle phase of the ES frame.
    n_mu, n_theta : int, optional
        Grid cells along (μ) and around (θ) the endocardium.
    Returns
    -------
    dict of str to float
        ``WT_AHA_k (mm)``, ``WT_ES_AHA_k (mm)``, ``Thickening_AHA_k (%)`` columns and their
        global values.
    """
    per = {}
    for key, f in (("ed", 0.0), ("es", f_es)):
        x, _, w, t = wall_thickness_samples(anatomy, motion, f, n_mu, n_theta)
        per[key] = segment_means(t, w, truth_segments(anatomy, motion, specs, f).segments(x))
    ed, es = per["ed"], per["es"]
    g_ed, g_es = float(np.mean([ed[k] for k in SEGMENTS])), float(np.mean([es[k] for k in SEGMENTS]))
    out = {f"WT_AHA_{k} (mm)": ed[k] for k in SEGMENTS}
    out["WT_Global (mm)"] = g_ed
    out.update({f"WT_ES_AHA_{k} (mm)": es[k] for k in SEGMENTS})
    out["WT_ES_Global (mm)"] = g_es
    out.update({f"Thickening_AHA_{k} (%)": 100.0 * (es[k] - ed[k]) / ed[k] for k in SEGMENTS})
    out["Thickening_Global (%)"] = 100.0 * (g_es - g_ed) / g_ed
    return out


# ----------------------------------------------------------------- strain
def endocardial_normal_field(anatomy: Anatomy, n_mu: int = 200, n_theta: int = 400,
                             with_area: bool = False):
    """Points on the ED endocardium (heart frame) and their outward unit normals: the gradient
    of s / a² + (z − z_c)² / c² on the ideal spheroid, the cross product of the grid's
    tangents on a realistic one (for nearest-point queries); ``with_area`` (realistic only):
    also each grid point's area element |∂x/∂μ × ∂x/∂θ| (the cells are equal in (μ, θ)).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    n_mu, n_theta : int, optional
        Grid cells along (μ) and around (θ) the endocardium.
    with_area : bool, optional
        Also return each point's area element (realistic anatomy).
    Returns
    -------
    points : ndarray, shape (n, 3)
        ED endocardial points, mm.
    normals : ndarray, shape (n, 3)
        Outward unit normals.
    area : ndarray, shape (n,)
        Area elements, mm² per unit (μ, θ) cell (with ``with_area`` only).
    """
    M, T, _, _, point = endocardial_grid(anatomy, n_mu, n_theta)
    p = point(M, T)
    if anatomy.realistic:
        # the bent ED endocardium; normals from the grid's tangents (central differences)
        h = 1e-6
        x = placed(anatomy, None, p, 0.0)
        tm = (placed(anatomy, None, point(M + h, T), 0.0) - placed(anatomy, None, point(M - h, T), 0.0)) / (2 * h)
        tt = (placed(anatomy, None, point(M, T + h), 0.0) - placed(anatomy, None, point(M, T - h), 0.0)) / (2 * h)
        n = np.cross(tm, tt)
        area = np.linalg.norm(n, axis=1)
        n /= area[:, None]
        radial = x.copy()
        radial[:, 2] = 0.0
        n = n if float(np.einsum("ij,ij->", radial, n)) > 0 else -n
        return (x, n, area) if with_area else (x, n)
    a, c = anatomy.r_short_endo, anatomy.r_long_endo
    n = np.column_stack([p[:, 0] / a ** 2, p[:, 1] / a ** 2, (p[:, 2] - anatomy.z_center) / c ** 2])
    return p, n / np.linalg.norm(n, axis=1)[:, None]


def motion_map(anatomy: Anatomy, motion: Motion, X: np.ndarray, f: float) -> np.ndarray:
    """φ_f(X): the exact image (n, 3) at phase f of ED heart-frame points X (n, 3) (for the
    realistic anatomy, ED bent frame → bent frame at f).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    X : ndarray, shape (n, 3)
        ED heart-frame points, mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    ndarray, shape (n, 3)
        Their positions at phase f, mm.
    """
    from cardionurbs.phantom import annotate
    if anatomy.realistic:
        return placed(anatomy, motion, annotate.unbend(anatomy, X), f)
    return motion.forward(anatomy, X, f)


def axis_distance(anatomy: Anatomy, motion: Motion, x: np.ndarray, f: float) -> np.ndarray:
    """Distance (mm) of heart-frame points x (n, 3) at phase f from the LV long axis at f
    (the z axis of the ideal anatomy; :func:`axis_frame` of the realistic one).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    x : ndarray, shape (n, 3)
        Heart-frame points at phase f, mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    ndarray, shape (n,)
        Distance from the long axis, mm.
    """
    x = np.asarray(x, float)
    if not anatomy.realistic:
        return np.hypot(x[:, 0], x[:, 1])
    origin, basis = axis_frame(anatomy, motion, f)
    return np.linalg.norm((x - origin) @ basis[:2].T, axis=1)


def deformation_gradient(anatomy: Anatomy, motion: Motion, X: np.ndarray, f: float,
                         h: float = 1e-3) -> np.ndarray:
    """F = ∂φ_f/∂X (n, 3, 3), heart frame, by central differences of the exact motion
    (step h mm; the map is smooth inside each tissue layer).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    X : ndarray, shape (n, 3)
        ED heart-frame points, mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    h : float, optional
        The difference step, mm.
    Returns
    -------
    ndarray, shape (n, 3, 3)
        F (dimensionless).
    """
    def phi(p):
        return motion_map(anatomy, motion, p, f)

    F = np.empty((len(X), 3, 3))
    for j in range(3):
        dx = np.zeros(3)
        dx[j] = h
        F[:, :, j] = (phi(X + dx) - phi(X - dx)) / (2 * h)
    return F


def strain_truth(anatomy: Anatomy, motion: Motion, specs, levels: list[dict], f: float,
                 spacing_mm: float = 1.0, axis_clearance_mm: float = 10.0) -> dict:
    """Exact Ecc, Ell, Err (%) per AHA segment and global at phase f, and det F.

    The tissue sampled is the ED LV myocardium between the most apical and most basal tag
    levels (the LA tag planes whose material points are tracked from ED to ES, ``levels``:
    :func:`cardionurbs.phantom.truth.strain_levels`; on a
    realistic anatomy, whose long axis is tilted against them, between the lowest point of
    the wall on the lowest plane and the highest on the highest, along the ED axis, as the
    measurement keeps the tissue between its extreme material points): a
    ``spacing_mm`` cubic grid, at least 0.05 mm inside the endo- and epicardium and at least
    ``axis_clearance_mm`` from the long axis both at ED and, moved by the exact motion, at
    phase f (the near-axis rule of docs/metrics.md, which the measurement applies with its
    fitted motion: a volume mean over the region the measurement averages, the tagged
    myocardium away from the apical tip around the axis). Directions
    at each point follow the measurement's definition with the analytic endocardium
    (:func:`endocardial_normal_field`); segments are those of :func:`truth_segments` at ED.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices.
    levels : list of dict
        :func:`cardionurbs.phantom.truth.strain_levels`, apex to base.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    spacing_mm : float, optional
        The sampling grid's spacing, mm.
    axis_clearance_mm : float, optional
        Least distance from the long axis, mm.
    Returns
    -------
    dict
        ``columns`` (``Ecc_AHA_k (%)`` ... and global columns; NaN where no sample) and
        ``det_F`` (mean det F, dimensionless).
    """
    kinds = ("Ecc", "Ell", "Err")
    if not levels:
        return {"columns": {f"{k}_{s} (%)": NAN for k in kinds
                            for s in [*(f"AHA_{j}" for j in SEGMENTS), "Global"]}, "det_F": NAN}
    X = _strain_sample(anatomy, motion, levels, f, spacing_mm, axis_clearance_mm)
    F = deformation_gradient(anatomy, motion, X, f)
    E = 0.5 * (np.einsum("nki,nkj->nij", F, F) - np.eye(3))
    dirs = _strain_directions(anatomy, motion, X)
    vals = 100.0 * np.einsum("nki,nij,nkj->nk", dirs, E, dirs)
    labels = truth_segments(anatomy, motion, specs, 0.0).segments(X)
    cols = {}
    for j, kind in enumerate(kinds):
        seg = segment_means(vals[:, j], np.ones(len(X)), labels)
        cols.update({f"{kind}_AHA_{k} (%)": seg[k] for k in SEGMENTS})
        fin = [v for v in seg.values() if np.isfinite(v)]
        cols[f"{kind}_Global (%)"] = float(np.mean(fin)) if fin else NAN
    return {"columns": cols, "det_F": float(np.linalg.det(F).mean()),
            "counts": {k: int((labels == k).sum()) for k in SEGMENTS}}


def _wall_section(anatomy: Anatomy, gx: np.ndarray, gy: np.ndarray, z: float):
    """The grid points (gx, gy) of the ED LV wall on the plane at height z (heart frame, mm,
    (k, 3)) and their distance from the heart's z axis (the motion frame's, unbent; (k,) mm),
    at least 0.05 mm inside the endo- and epicardium."""
    from cardionurbs.phantom import annotate
    if anatomy.realistic:                     # ED bent frame: the section shifted by d(z)
        q = annotate.unbend(anatomy, np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)]))
        s = q[:, 0] ** 2 + q[:, 1] ** 2
        # the sections only where s can reach the wall: between the least endocardial and the
        # largest epicardial S sampled every degree, widened by 5 % (far more than they vary
        # between the samples); elsewhere S1 = S2 = s fails the test below as the exact ones do
        e1, e2 = anatomy.lv_sections(np.full(360, z), np.linspace(0.0, 2 * np.pi, 360, endpoint=False))
        near = np.flatnonzero((s >= 0.95 * float(e1.min())) & (s <= 1.05 * float(e2.max())))
        s1, s2 = s.copy(), s.copy()
        s1[near], s2[near] = anatomy.lv_sections(np.full(len(near), z),
                                                 np.arctan2(q[near, 1], q[near, 0]))
        s = s.reshape(gx.shape)
        s1, s2 = s1.reshape(gx.shape), s2.reshape(gx.shape)
    else:
        s = gx ** 2 + gy ** 2
        s1, s2 = float(anatomy.s_lv_endo(z)), float(anatomy.s_lv_epi(z))
    r = np.sqrt(s)
    inside = (r > np.sqrt(s1) + 0.05) & (r < np.sqrt(s2) - 0.05)
    return np.column_stack([gx[inside], gy[inside], np.full(inside.sum(), z)]), r[inside]


def _strain_sample(anatomy: Anatomy, motion: Motion, levels: list[dict], f: float,
                   spacing_mm: float, axis_clearance_mm: float) -> np.ndarray:
    """The ED tissue points (n, 3) heart mm of :func:`strain_truth`: a ``spacing_mm`` grid of
    the LV wall between the tag levels, ``axis_clearance_mm`` off the axis at ED and phase f."""
    reach = anatomy.r_short_epi * 1.2 * (1.3 if anatomy.realistic else 1.0)
    if anatomy.shape is not None:
        reach += float(np.hypot(*anatomy.shape.apex_shift_mm))
    g = np.arange(-reach, reach, spacing_mm) + 0.5 * spacing_mm
    gx, gy = np.meshgrid(g, g, indexing="ij")
    zs = [lv["distance_from_apex_mm"] for lv in levels]
    heights = np.arange(min(zs), max(zs) + 1e-9, spacing_mm)
    if anatomy.realistic:
        # the measurement keeps the tissue between the lowest and highest tracked material point
        # along its (ED) long axis, which is tilted against the tag planes: the tagged range is
        # [lowest point of the wall on the lowest tag plane, highest on the highest] along the
        # ED axis of :func:`axis_frame`, and the planes sampled reach as far as it does
        origin, basis = axis_frame(anatomy, motion, 0.0)
        h_lo = float(np.min((_wall_section(anatomy, gx, gy, min(zs))[0] - origin) @ basis[2]))
        h_hi = float(np.max((_wall_section(anatomy, gx, gy, max(zs))[0] - origin) @ basis[2]))
        tilt = float(np.hypot(basis[2][0], basis[2][1]) / basis[2][2])
        margin = reach * tilt + spacing_mm
        heights = np.arange(min(zs) - margin, max(zs) + margin + 1e-9, spacing_mm)
    pts = []
    for z in heights:
        P, r = _wall_section(anatomy, gx, gy, z)
        P = P[r >= axis_clearance_mm]
        if anatomy.realistic:
            h = (P - origin) @ basis[2]
            P = P[(h >= h_lo) & (h <= h_hi)]
        pts.append(P)
    X = np.concatenate(pts)
    return X[axis_distance(anatomy, motion, motion_map(anatomy, motion, X, f), f) >= axis_clearance_mm]


def _strain_directions(anatomy: Anatomy, motion: Motion, X: np.ndarray) -> np.ndarray:
    """The measurement's (c, l, r) directions at the ED points X: (n, 3, 3), rows unit vectors
    (r: the analytic endocardium's normal; c: circumferential about the long axis, made
    orthogonal to r; l = r x c)."""
    from scipy.spatial import cKDTree
    if anatomy.realistic:
        # the measurement's r: the normal averaged (by area) over DIRECTION_SMOOTHING_MM of
        # endocardium, here on a 60 x 120 grid (~250 samples a disc; the average varies on the
        # 10 mm scale, so the nearest grid point's average serves each X). A realistic wall
        # bends (and an infarct steps) on that scale; on the ideal spheroid the average tilts
        # r by ~1° (< 0.1 strain point) and is not taken.
        ep, en, area = endocardial_normal_field(anatomy, 60, 120, with_area=True)
        en = averaged_normals(ep, en, area, DIRECTION_SMOOTHING_MM)
    else:
        ep, en = endocardial_normal_field(anatomy)
    rdir = en[cKDTree(ep).query(X)[1]]
    if anatomy.realistic:                         # circumferential about the ED long axis
        origin, basis = axis_frame(anatomy, motion, 0.0)
        c = np.cross(basis[2][None, :], X - origin[None, :])
        c /= np.linalg.norm(c, axis=1)[:, None]
    else:
        th = np.arctan2(X[:, 1], X[:, 0])
        c = np.column_stack([-np.sin(th), np.cos(th), np.zeros(len(th))])
    c -= np.einsum("ni,ni->n", c, rdir)[:, None] * rdir
    c /= np.linalg.norm(c, axis=1)[:, None]
    return np.stack([c, np.cross(rdir, c), rdir], axis=1)


# ----------------------------------------------------------------- surface strain
def _polyline_length(p: np.ndarray, closed: bool) -> float:
    q = np.vstack([p, p[:1]]) if closed else p
    return float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum())


def surface_strain_truth(anatomy: Anatomy, motion: Motion, specs, f_es: float) -> dict[str, float]:
    """GLS surface and GCS surface (%) of the analytic contours, finely sampled (the LA
    endocardial curves with 600 points a side, the mid SA circumference with 2880 points);
    the mid SA slice is the one nearest z_b / 2 at ED (the measurement's rule, with the
    analytic apex and mitral centre).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices.
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    dict of str to float
        ``GLS surface (%)`` and ``GCS surface (%)``.
    """
    from cardionurbs.phantom import annotate
    gls = []
    for s in specs:
        if s.view != "LA":
            continue
        c0 = annotate.la_contours(anatomy, motion, s, 0.0, n_side=600).get("lv_endo")
        c1 = annotate.la_contours(anatomy, motion, s, f_es, n_side=600).get("lv_endo")
        if c0 is not None and c1 is not None:
            # lengths in the (bent) heart, where the LA planes are planes; the bend is the
            # identity for the ideal anatomy
            l0 = _polyline_length(annotate.bend(anatomy, c0), False)
            l1 = _polyline_length(annotate.bend(anatomy, c1), False)
            gls.append(100.0 * (l1 - l0) / l0)
    sa = [s for s in specs if s.view == "SA"]
    mid = min(sa, key=lambda s: abs(s.height - 0.5 * anatomy.z_base))
    c0 = annotate.sa_contours(anatomy, motion, mid, 0.0, n_lv=2880).get("lv_endo")
    c1 = annotate.sa_contours(anatomy, motion, mid, f_es, n_lv=2880).get("lv_endo")
    gcs = NAN
    if c0 is not None and c1 is not None:
        l0, l1 = _polyline_length(c0, True), _polyline_length(c1, True)
        gcs = 100.0 * (l1 - l0) / l0
    return {"GLS surface (%)": float(np.mean(gls)) if gls else NAN, "GCS surface (%)": gcs}


# ----------------------------------------------------------------- realistic anatomy
def realistic_regional_truth(anatomy: Anatomy, motion: Motion, specs, n_frames: int, es_frame: int,
                             rr_ms: float) -> dict[str, float]:
    """Regional truth of a realistic anatomy (:mod:`cardionurbs.phantom.shape`).

    Filling rates come from the method-A volume curve V(f) (quadratic in the phase f,
    :func:`cardionurbs.phantom.truth_realistic.volume_polynomials`): dV/dt = V'(f) f'(τ) / RR,
    by :func:`filling_rate_truth`. (Wall thickness, tag strain and surface strain:
    :func:`wall_thickness_truth`, :func:`strain_truth` and :func:`surface_strain_truth`, which
    handle both anatomies.)

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices.
    n_frames : int
        Frames per cycle.
    es_frame : int
        The ES frame index, 0-based.
    rr_ms : float
        The R-R interval, ms.
    Returns
    -------
    dict of str to float
        The filling-rate columns (mL/s) and ``E/A ratio``.
    """
    from cardionurbs.phantom.truth_realistic import volume_polynomials

    f_es = float(motion.curve(es_frame / n_frames))
    dv_df = volume_polynomials(anatomy, motion, f_es)["lv_cavity"].deriv()
    return filling_rate_truth(anatomy, motion, n_frames, es_frame, rr_ms, dv_df=dv_df)
