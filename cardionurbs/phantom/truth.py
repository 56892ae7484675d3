"""Ground truth of the analytic phantom (truth.json), independent of any reconstruction.

Volumes are computed by two independent methods:

* **A — analytic / quadrature.** ED volumes from the closed-form truncated
  spheroid (anatomy eq. A4) and the polar quadrature of the RV crescent
  (eq. A5); at phase f the cavities scale exactly by κ (motion eqs. M3:
  V_LV(f) = (1 − EF_L f) V_LV(ED)), myocardial volumes are constant.
* **B — fine closed meshes.** The ED LV endocardium and epicardium spheroids
  are sampled on a (μ, θ) grid; the RV cavity (RV shell minus LV epicardium) is
  meshed as a closed crescent tube whose rings follow the free wall and the
  septum between the sector edges θ_e(z). Every vertex is mapped forward by the
  motion φ_f, the surfaces are closed by their planar valve-plane caps and
  integrated with the divergence theorem V = Σ a·(b × c)/6. RV wall =
  crescent(epi) − crescent(endo), LV wall = LV epi − LV cavity.

Method A gives the truth values; method B is reported beside it
(``truth["volumes"]``: relative differences ~3e-4 at the default resolution,
O(h²) convergence, see reports/benchmark-phantom.md).

Tags and twist follow docs/metrics.md. The SA slices bounding the
levels are those carrying tag lines at both ED and ES (basal slices above the
descended base at ES have none); a level is an LA tag plane z = z_j with
h_apical < z_j < h_basal and h_apical < λ_ES z_j < h_basal (:func:`tag_levels`).
All material points of a level rotate by ψ(z_j) at ES (motion eq. M2), so its
rotation is exact; LS = 100 (1 − λ_ES). ``Twist 2D`` is measured the slice way
from the analytic tag crossings (:func:`twist_2d`), ``EI ES`` from the analytic
ES contours on the mid-ventricular SA slice (:func:`eccentricity_index`).
"""

from __future__ import annotations

import numpy as np

from cardionurbs.geometry import chord_length, polygon_centroid
from cardionurbs.phantom import annotate
from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.geometry import SliceSpec
from cardionurbs.phantom.motion import Motion

DENSITY_G_PER_ML = 1.05

METRIC_COLUMNS = ("HR (bpm)", "LVEDV (mL)", "LVESV (mL)", "LVSV (mL)", "LVEF (%)", "LVCO (L/min)",
                  "LVM (g)", "RVEDV (mL)", "RVESV (mL)", "RVSV (mL)", "RVEF (%)", "RVM (g)",
                  "MR RegVol (mL)", "MR RegFrac (%)", "LVSV-RVSV (mL)", "RV/LV EDV ratio",
                  "RV/LV mass ratio", "EI ES",
                  "Twist (deg)", "Twist 2D (deg)", "Torsion (deg/cm)", "CL shear (deg)", "LS (%)",
                  "Tag QC flags")


# ----------------------------------------------------------------- method B: meshes
def closed_revolution_volume(grid: np.ndarray, cap_center: np.ndarray) -> float:
    """Volume (mm³) enclosed by a (m+1, n, 3) vertex grid (row 0 a pole, θ periodic) closed by a
    planar fan cap at the last row, by the divergence theorem V = Σ a·(b × c) / 6.

    Parameters
    ----------
    grid : ndarray, shape (m + 1, n, 3)
        Vertex rings, mm (row 0 a pole, θ periodic).
    cap_center : ndarray, shape (3,)
        The fan cap's centre at the last row, mm.
    Returns
    -------
    float
        The volume in mm³.
    """
    p = grid
    a, b, c, d = p[:-1], np.roll(p[:-1], -1, axis=1), np.roll(p[1:], -1, axis=1), p[1:]

    def tri(u, v, w):
        return np.einsum("...i,...i->...", u, np.cross(v, w)).sum()

    vol = tri(a, b, c) + tri(a, c, d)
    rim = p[-1]
    ctr = np.broadcast_to(cap_center, rim.shape)
    vol += tri(ctr, rim, np.roll(rim, -1, axis=0))
    return abs(float(vol)) / 6.0


def _spheroid_grid(a: float, c: float, zc: float, z_top: float, n_mu: int, n_theta: int):
    mu_b = np.arccos(-(z_top - zc) / c)
    mu = np.linspace(0.0, mu_b, n_mu + 1)
    th = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
    M, T = np.meshgrid(mu, th, indexing="ij")
    z = zc - c * np.cos(M)
    return M, T, z


def crescent_grid(anatomy: Anatomy, epi: bool, n_z: int, n_v: int) -> np.ndarray:
    """Material vertex rings (n_z + 1, 2 n_v, 3) of the closed RV shell-minus-LV crescent.

    Row k is the section z_k = z0 + (z_b − z0) u_k² (u uniform; z0 the crescent onset): the
    free wall θ = v θ_e(z_k), v ∈ [−1, 1] on the RV shell s = g² P(θ), then back along the
    septum on the LV epicardium s = s_epi(z_k). Row 0 collapses to the onset point.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    epi : bool
        The RV epicardial shell (else the endocardial).
    n_z : int
        Rings from the onset to the base.
    n_v : int
        Points per half ring.
    Returns
    -------
    ndarray, shape (n_z + 1, 2 n_v, 3)
        Material (ED) vertex rings, mm.
    """
    z0 = anatomy.rv_onset(epi)
    u = np.linspace(0.0, 1.0, n_z + 1)
    z = z0 + (anatomy.z_base - z0) * u * u
    edge = anatomy.rv_sector_edge(z, epi)
    v = np.linspace(-1.0, 1.0, n_v + 1)
    th_free = edge[:, None] * v[None, :]
    th_sept = edge[:, None] * v[::-1][None, 1:-1]
    zz = np.broadcast_to(z[:, None], th_free.shape)
    s_free = anatomy.s_rv(th_free, zz, epi)
    s_sept = np.broadcast_to(anatomy.s_lv_epi(z)[:, None], th_sept.shape)
    th = np.concatenate([th_free, th_sept], axis=1)
    s = np.concatenate([s_free, s_sept], axis=1)
    r = np.sqrt(s)
    zc = np.broadcast_to(z[:, None], th.shape)
    return np.stack([r * np.cos(th), r * np.sin(th), zc], axis=-1)


def mesh_volumes(anatomy: Anatomy, motion: Motion, f: float, n_mu: int = 160, n_theta: int = 320,
                 n_z_rv: int = 160, n_v_rv: int = 160) -> dict[str, float]:
    """Method B: LV/RV cavity and wall volumes (mL) at phase f from forward-mapped fine meshes.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_mu, n_theta : int, optional
        Grid of the LV spheroids (along and around).
    n_z_rv, n_v_rv : int, optional
        Grid of the RV crescents (rings and half-ring points).
    Returns
    -------
    dict of str to float
        ``lv_cavity``, ``lv_myocardium``, ``rv_cavity``, ``rv_myocardium``, in mL.
    """
    zb = anatomy.z_base
    cap = motion.forward(anatomy, np.array([[0.0, 0.0, zb]]), f)[0]

    def moved(grid):
        return motion.forward(anatomy, grid.reshape(-1, 3), f).reshape(grid.shape)

    def spheroid(a, c):
        M, T, z = _spheroid_grid(a, c, anatomy.z_center, zb, n_mu, n_theta)
        r = a * np.sin(M)
        g = np.stack([r * np.cos(T), r * np.sin(T), z], axis=-1)
        return closed_revolution_volume(moved(g), cap) / 1000.0

    def crescent(epi):
        g = moved(crescent_grid(anatomy, epi, n_z_rv, n_v_rv))
        return closed_revolution_volume(g, g[-1].mean(axis=0)) / 1000.0

    v_endo = spheroid(anatomy.r_short_endo, anatomy.r_long_endo)
    v_epi = spheroid(anatomy.r_short_epi, anatomy.r_long_epi)
    v_c3, v_c4 = crescent(False), crescent(True)
    return {"lv_cavity": v_endo, "lv_myocardium": v_epi - v_endo,
            "rv_cavity": v_c3, "rv_myocardium": v_c4 - v_c3}


def analytic_volumes(anatomy: Anatomy, motion: Motion, f: float) -> dict[str, float]:
    """Method A: the same volumes (mL) from eqs. A4, A5 and the exact κ scaling of eq. M3.

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
    dict of str to float
        ``lv_cavity``, ``lv_myocardium``, ``rv_cavity``, ``rv_myocardium``, in mL.
    """
    return {"lv_cavity": float((1 - motion.lv_ef * f) * anatomy.lv_cavity_volume()) / 1000.0,
            "lv_myocardium": anatomy.lv_myocardial_volume() / 1000.0,
            "rv_cavity": float((1 - motion.rv_ef * f) * anatomy.rv_cavity_volume()) / 1000.0,
            "rv_myocardium": anatomy.rv_myocardial_volume() / 1000.0}


# ----------------------------------------------------------------- tag truth
def sa_plane_cuts_wall(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float) -> bool:
    """True where an SA plane shows LV myocardium (and hence tag lines) at phase f.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    spec : cardionurbs.phantom.geometry.SliceSpec
        An SA slice.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    bool
        Whether the plane shows LV myocardium.
    """
    z = annotate.sa_material_height(motion, spec, f)
    th = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
    return bool(0.0 < z <= anatomy.z_top_min - annotate.BASE_MARGIN_MM
                and float(np.mean(anatomy.s_lv_epi(z, th))) >= annotate.MIN_RADIUS_MM ** 2)


def tagged_sa_slices(anatomy: Anatomy, motion: Motion, specs: list[SliceSpec], f_es: float) -> list[SliceSpec]:
    """SA slices carrying tag lines both at ED and at ES, base to apex.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices (SA and LA).
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    list of cardionurbs.phantom.geometry.SliceSpec
        The tagged SA slices, base to apex.
    """
    return [s for s in specs if s.view == "SA" and sa_plane_cuts_wall(anatomy, motion, s, 0.0)
            and sa_plane_cuts_wall(anatomy, motion, s, f_es)]


def strain_levels(anatomy: Anatomy, motion: Motion, grid: annotate.TagGrid, specs: list[SliceSpec],
                  f_es: float) -> list[dict]:
    """LA tag planes whose material points the measurement tracks from ED to ES: the plane z_j
    lies between the most apical and most basal SA planes with tag lines at ED, and its image
    λ_ES z_j between those with tag lines at ES (each frame's SA tag surfaces span that frame's
    tagged slices; :meth:`cardionurbs.analysis.material.MaterialPoints.tracked`). Wider than
    :func:`tag_levels`, which asks both of the slices tagged at both frames; the tag strain's
    truth averages over the tissue between these planes, as the measurement averages between
    its extreme tracked points. [{"index", "distance_from_apex_mm"}], apex to base.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : cardionurbs.phantom.annotate.TagGrid
        The SPAMM tag planes at ED.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices (SA and LA).
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    list of dict
        ``{"index", "distance_from_apex_mm"}`` per LA tag plane, apex to base.
    """
    def span(f):
        h = [s.height for s in specs if s.view == "SA" and sa_plane_cuts_wall(anatomy, motion, s, f)]
        return (min(h), max(h)) if len(h) >= 2 else None
    ed, es = span(0.0), span(f_es)
    if ed is None or es is None:
        return []
    lam = float(motion.lam(f_es))
    return [{"index": j, "distance_from_apex_mm": float(zj)}
            for j, zj in enumerate(grid.la_positions(anatomy.z_top_min - annotate.BASE_MARGIN_MM))
            if ed[0] < zj < ed[1] and es[0] < lam * zj < es[1]]


def tag_levels(anatomy: Anatomy, motion: Motion, grid: annotate.TagGrid, specs: list[SliceSpec],
               f_es: float) -> list[dict]:
    """LA tag planes with material points (docs/metrics.md): z_j strictly between the most apical
    and most basal tagged SA planes at ED, and λ_ES z_j also between them at ES.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : cardionurbs.phantom.annotate.TagGrid
        The SPAMM tag planes at ED.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices (SA and LA).
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    list of dict
        One dict per LA tag plane, apex to base: ``index``, ``distance_from_apex_mm``,
        ``rotation_deg`` (ED to ES, CCW seen from the apex), ``epi_radius_mm``, ``in_twist``.
    """
    tagged = tagged_sa_slices(anatomy, motion, specs, f_es)
    if len(tagged) < 2:
        return []
    h_bas, h_ap = max(s.height for s in tagged), min(s.height for s in tagged)
    lam = float(motion.lam(f_es))
    levels = []
    th = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    for j, zj in enumerate(grid.la_positions(anatomy.z_top_min - annotate.BASE_MARGIN_MM)):
        if h_ap < zj < h_bas and h_ap < lam * zj < h_bas:
            # the mean epicardial radius of the level (sqrt of the mean squared radius = the
            # radius of the circle of the same area; exact for the ideal circular sections)
            levels.append({"index": j, "distance_from_apex_mm": float(zj),
                           "rotation_deg": float(np.degrees(motion.psi(zj, f_es))),
                           "epi_radius_mm": float(np.sqrt(np.mean(anatomy.s_lv_epi(zj, th)))),
                           "in_twist": False})
    if levels:
        levels[0]["in_twist"] = levels[-1]["in_twist"] = True
    return levels


def twist_from_levels(levels: list[dict], f_es_lambda: float) -> dict[str, float]:
    """Twist, torsion, CL shear and LS from the most apical and most basal levels (docs/metrics.md).

    Parameters
    ----------
    levels : list of dict
        :func:`tag_levels`, apex to base.
    f_es_lambda : float
        λ at ES (eq. M1).
    Returns
    -------
    dict of str to float
        ``Twist (deg)``, ``Torsion (deg/cm)``, ``CL shear (deg)``, ``LS (%)``; NaN with fewer
        than two levels.
    """
    if len(levels) < 2:
        nan = float("nan")
        return {"Twist (deg)": nan, "Torsion (deg/cm)": nan, "CL shear (deg)": nan, "LS (%)": nan}
    ap, ba = levels[0], levels[-1]
    twist = ap["rotation_deg"] - ba["rotation_deg"]
    d = ba["distance_from_apex_mm"] - ap["distance_from_apex_mm"]
    return {"Twist (deg)": twist, "Torsion (deg/cm)": twist / (d / 10.0),
            "CL shear (deg)": twist * (ap["epi_radius_mm"] + ba["epi_radius_mm"]) / (2.0 * d),
            "LS (%)": 100.0 * (d - f_es_lambda * d) / d}


def _lv_centroid(anatomy, motion, spec, f) -> np.ndarray:
    c = annotate.sa_contours(anatomy, motion, spec, f, n_lv=720)
    poly = c.get("lv_endo", c.get("lv_epi"))
    return polygon_centroid(poly[:, :2])


def slice_rotation_deg(anatomy: Anatomy, motion: Motion, grid: annotate.TagGrid, spec: SliceSpec,
                       f_es: float) -> float:
    """Mean ED→ES rotation (deg, CCW seen from the apex) of the sa1 × sa2 tag crossings in the LV
    wall of one SA slice, each about the slice's LV (cavity) centroid at its frame.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : cardionurbs.phantom.annotate.TagGrid
        The SPAMM tag planes at ED.
    spec : cardionurbs.phantom.geometry.SliceSpec
        An SA slice.
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    float
        The mean rotation in degrees (NaN without tag crossings in the wall).
    """
    n1, n2 = grid.sa_normal("sa1"), grid.sa_normal("sa2")
    c = grid.sa_positions()
    ci, cj = np.meshgrid(c, c, indexing="ij")
    keep = np.ones(ci.size, dtype=bool)
    zs, xys = {}, {}
    for f in (0.0, f_es):
        z = annotate.sa_material_height(motion, spec, f)
        # crossings of the ED tag planes in the material section z (shifted by the apex bend)
        d = (anatomy.shape.apex_shift(z, anatomy.z_base)[0]
             if anatomy.shape is not None and anatomy.shape.bends else np.zeros(2))
        xy = ci.ravel()[:, None] * n1[None, :2] + cj.ravel()[:, None] * n2[None, :2] - d[None, :]
        s, th = (xy ** 2).sum(axis=1), np.arctan2(xy[:, 1], xy[:, 0])
        if anatomy.shape is None:
            keep &= (s >= anatomy.s_lv_endo(z)) & (s <= anatomy.s_lv_epi(z))
        else:
            keep &= (s >= anatomy.s_lv_endo(z, th)) & (s <= anatomy.s_lv_epi(z, th))
        zs[f], xys[f] = z, xy
    if not keep.any():
        return float("nan")
    ang = {}
    for f in (0.0, f_es):
        xy = xys[f][keep]
        mat = np.column_stack([xy, np.full(len(xy), zs[f])])
        p = motion.forward(anatomy, mat, f)[:, :2] - _lv_centroid(anatomy, motion, spec, f)
        ang[f] = np.arctan2(p[:, 1], p[:, 0])
    d = np.angle(np.exp(1j * (ang[f_es] - ang[0.0])))
    return float(np.degrees(-d.mean()))


def twist_2d(anatomy: Anatomy, motion: Motion, grid: annotate.TagGrid, specs: list[SliceSpec],
             f_es: float) -> tuple[float, dict]:
    """Slice-based twist: rotation of the most apical minus the most basal tagged SA slice.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : cardionurbs.phantom.annotate.TagGrid
        The SPAMM tag planes at ED.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices (SA and LA).
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    twist : float
        Twist 2D in degrees (NaN with fewer than two tagged SA slices).
    detail : dict
        The slices used and their rotations.
    """
    tagged = tagged_sa_slices(anatomy, motion, specs, f_es)
    if len(tagged) < 2:
        return float("nan"), {}
    basal, apical = tagged[0], tagged[-1]
    rb = slice_rotation_deg(anatomy, motion, grid, basal, f_es)
    ra = slice_rotation_deg(anatomy, motion, grid, apical, f_es)
    return ra - rb, {"basal_slice": basal.id, "apical_slice": apical.id,
                     "basal_rotation_deg": rb, "apical_rotation_deg": ra}


def eccentricity_index(anatomy: Anatomy, motion: Motion, specs: list[SliceSpec], f_es: float) -> tuple[float, str]:
    """EI at ES on the mid-ventricular SA slice (docs/metrics.md definition).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices (SA and LA).
    f_es : float
        The cycle phase of the ES frame.
    Returns
    -------
    ei : float
        The eccentricity index at ES (dimensionless; NaN without an SA slice with both cavities).
    slice : str
        The slice used (``""`` without one).
    """
    lam = float(motion.lam(f_es))
    target = lam * 0.5 * (anatomy.z_endo_apex + anatomy.z_base)
    best = None
    for s in specs:
        if s.view != "SA":
            continue
        c = annotate.sa_contours(anatomy, motion, s, f_es, n_lv=1440, n_rv_free=720, n_rv_septum=360)
        if "lv_endo" in c and "rv_endo" in c:
            if best is None or abs(s.height - target) < abs(best[0].height - target):
                best = (s, c)
    if best is None:
        return float("nan"), ""
    spec, c = best
    lv, rv = c["lv_endo"][:, :2], c["rv_endo"][:, :2]
    cl, cr = polygon_centroid(lv), polygon_centroid(rv)
    d = cr - cl
    septum = np.array([-d[1], d[0]])
    return chord_length(lv, cl, septum) / chord_length(lv, cl, d), spec.id


# ----------------------------------------------------------------- all metrics
def compute_metrics(anatomy: Anatomy, motion: Motion, grid: annotate.TagGrid, specs: list[SliceSpec],
                    phases: np.ndarray, es_frame: int, heart_rate: float, n_tag_jumps: int) -> tuple[dict, dict]:
    """docs/metrics.md columns (method A) and the tag-level truth.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : cardionurbs.phantom.annotate.TagGrid
        The SPAMM tag planes at ED.
    specs : list of cardionurbs.phantom.geometry.SliceSpec
        The imaged slices (SA and LA).
    phases : ndarray, shape (frames,)
        The cycle phase of every frame.
    es_frame : int
        The ES frame index, 0-based.
    heart_rate : float
        Heart rate, beats/min.
    n_tag_jumps : int
        Tag jumps injected (the ``Tag QC flags`` truth).
    Returns
    -------
    metrics : dict
        docs/metrics.md column -> value (mL, %, g, deg, deg/cm, bpm).
    tags : dict
        The tag-level truth (levels, slices, EI slice).
    """
    f_es = float(phases[es_frame])
    if anatomy.realistic:
        from cardionurbs.phantom.truth_realistic import section_volumes
        ed, es = section_volumes(anatomy, motion, float(phases[0])), section_volumes(anatomy, motion, f_es)
    else:
        ed, es = analytic_volumes(anatomy, motion, float(phases[0])), analytic_volumes(anatomy, motion, f_es)
    m: dict[str, float] = {"HR (bpm)": heart_rate}
    m["LVEDV (mL)"], m["LVESV (mL)"] = ed["lv_cavity"], es["lv_cavity"]
    m["LVSV (mL)"] = m["LVEDV (mL)"] - m["LVESV (mL)"]
    m["LVEF (%)"] = 100.0 * m["LVSV (mL)"] / m["LVEDV (mL)"]
    m["LVCO (L/min)"] = m["LVSV (mL)"] * heart_rate / 1000.0
    m["LVM (g)"] = DENSITY_G_PER_ML * ed["lv_myocardium"]
    m["RVEDV (mL)"], m["RVESV (mL)"] = ed["rv_cavity"], es["rv_cavity"]
    m["RVSV (mL)"] = m["RVEDV (mL)"] - m["RVESV (mL)"]
    m["RVEF (%)"] = 100.0 * m["RVSV (mL)"] / m["RVEDV (mL)"]
    m["RVM (g)"] = DENSITY_G_PER_ML * ed["rv_myocardium"]
    m["MR RegVol (mL)"] = max(0.0, m["LVSV (mL)"] - m["RVSV (mL)"])
    m["MR RegFrac (%)"] = 100.0 * m["MR RegVol (mL)"] / m["LVSV (mL)"]
    m["LVSV-RVSV (mL)"] = m["LVSV (mL)"] - m["RVSV (mL)"]
    m["RV/LV EDV ratio"] = m["RVEDV (mL)"] / m["LVEDV (mL)"]
    m["RV/LV mass ratio"] = m["RVM (g)"] / m["LVM (g)"]
    ei, ei_slice = eccentricity_index(anatomy, motion, specs, f_es)
    m["EI ES"] = ei
    levels = tag_levels(anatomy, motion, grid, specs, f_es)
    tw = twist_from_levels(levels, float(motion.lam(f_es)))
    t2d, t2d_info = twist_2d(anatomy, motion, grid, specs, f_es)
    m["Twist (deg)"] = tw["Twist (deg)"]
    m["Twist 2D (deg)"] = t2d
    m["Torsion (deg/cm)"] = tw["Torsion (deg/cm)"]
    m["CL shear (deg)"] = tw["CL shear (deg)"]
    m["LS (%)"] = tw["LS (%)"]
    m["Tag QC flags"] = float(n_tag_jumps)
    tags = {"levels": levels, "grid": grid.to_dict(), "twist_2d": t2d_info, "ei_slice": ei_slice,
            "sa_slices_tagged_ed_es": [s.id for s in tagged_sa_slices(anatomy, motion, specs, f_es)]}
    return {k: m[k] for k in METRIC_COLUMNS}, tags


def volume_table(anatomy: Anatomy, motion: Motion, phases: np.ndarray, mesh_frames: list[int],
                 **mesh_kw) -> dict:
    """Per-frame method-A volumes and method-B mesh volumes on ``mesh_frames`` with relative gaps.

    A realistic anatomy has no closed form: method A (:func:`truth_realistic.section_volumes`)
    runs on the mesh frames, and the other frames take the quadratic in the phase f through
    method A at f = 0, f_max / 2 and f_max (:func:`truth_realistic.volume_curve`).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved ED anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    phases : ndarray, shape (frames,)
        The cycle phase of every frame.
    mesh_frames : list of int
        Frames whose method-B mesh volumes are computed.
    **mesh_kw
        Grid sizes for :func:`mesh_volumes`.
    Returns
    -------
    dict
        ``analytic_mL`` (frame -> volumes in mL), ``mesh_check`` (frame -> mesh volumes and
        relative differences), ``max_relative_difference``.
    """
    if anatomy.realistic:
        from cardionurbs.phantom import truth_realistic as trr
        curve = trr.volume_curve(anatomy, motion, float(np.max(phases)))
        per_frame = [curve(float(f)) for f in phases]
        check, worst = {}, 0.0
        for k in mesh_frames:
            a = trr.section_volumes(anatomy, motion, float(phases[k]))
            b = trr.mesh_volumes(anatomy, motion, float(phases[k]))
            per_frame[k] = a
            rel = {key: abs(b[key] - a[key]) / a[key] for key in a}
            worst = max(worst, max(rel.values()))
            check[str(k)] = {"mesh_mL": b, "relative_difference": rel}
        return {"analytic_mL": {str(k): v for k, v in enumerate(per_frame)}, "mesh_check": check,
                "max_relative_difference": worst, "method_a": "sections (truth_realistic)",
                "lv_myocardium_material_mL": {k: v["mesh_mL"]["lv_myocardium_material"]
                                              for k, v in check.items()}}
    per_frame = [analytic_volumes(anatomy, motion, float(f)) for f in phases]
    check = {}
    worst = 0.0
    for k in mesh_frames:
        b = mesh_volumes(anatomy, motion, float(phases[k]), **mesh_kw)
        a = per_frame[k]
        rel = {key: abs(b[key] - a[key]) / a[key] for key in a}
        worst = max(worst, max(rel.values()))
        check[str(k)] = {"mesh_mL": b, "relative_difference": rel}
    return {"analytic_mL": {str(k): v for k, v in enumerate(per_frame)}, "mesh_check": check,
            "max_relative_difference": worst}
