"""Ground-truth volumes of a realistic phantom by two independent numerical methods.

A realistic anatomy (:mod:`cardionurbs.phantom.shape`) has no closed-form
volumes once its mitral annulus is a saddle and the cavity is closed, as
docs/metrics.md defines it, at the best-fit plane of the annulus points. The
truth is therefore computed twice, by methods that share nothing but the
analytic model:

* **A — sections.** The heart is cut by planes z' = const of the deformed
  (and bent) heart every ``dz`` mm. Each cut of a cavity or wall is an explicit
  polar curve (the section functions S(θ, z) pushed through the radial map of
  the motion, eq. M3), clipped by the valve half-plane; its area by the shoelace
  formula is integrated over z' by the trapezoid rule.
* **B — closed meshes.** Each region is sampled as a closed triangle mesh in
  material coordinates (a (μ, θ) grid of the LV surfaces with a cap above the
  annulus; rings of the RV crescent), every vertex mapped forward by the motion
  and the apex bend, and its volume taken by the divergence theorem over the
  triangles clipped by the same valve plane.

The valve planes come from the annulus landmarks the study carries (least
squares; :func:`cardionurbs.geometry.fit_plane`). The material myocardium (LV
wall up to the saddle annulus, RV free wall) is also meshed at every requested
phase: its volume must not change, which checks that the motion is
incompressible.
"""

from __future__ import annotations

import functools

import numpy as np

from cardionurbs.errors import PhantomError
from cardionurbs.geometry import fit_plane
from cardionurbs.phantom import annotate
from cardionurbs.phantom import outflow as ofl
from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.motion import Motion


def valve_planes(anatomy: Anatomy, motion: Motion, f: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(centroid, unit normal toward the base) of the mitral and tricuspid annulus points at
    phase f, realistic heart frame (mm).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    Returns
    -------
    dict of str to tuple of (ndarray, ndarray)
        ``"mitral"`` and ``"tricuspid"`` -> (centroid (3,) in mm, unit normal (3,)).
    """
    lm = annotate.landmarks(anatomy, motion, f)
    out = {}
    keys = ("mitral", "tricuspid") + (("pulmonary", "aortic") if anatomy.outflow is not None else ())
    for key in keys:
        # an outflow view that misses its annulus at f gives no landmark: the ring itself
        pts = (annotate.bend(anatomy, lm[key]) if key in lm
               else annotate.annulus_ring(anatomy, motion, f, key))
        c, n = fit_plane(pts)
        out[key] = (c, n if n[2] > 0 else -n)
    return out


def clipped_areas(poly: np.ndarray, zp: np.ndarray, plane: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Areas (mm²) of the parts of closed polygons (L, n, 2), each in its level z' = zp[l], below a
    plane, all levels at once.

    Shoelace over the clipped boundary: each edge contributes its inside part, P × Q; the closing
    segments run along the cut line X = o + t u, where P × Q = (o × u)(t_Q − t_P) is linear in t,
    so together they contribute (o × u)(Σ t_entry − Σ t_exit) whatever their pairing.

    Parameters
    ----------
    poly : ndarray, shape (L, n, 2)
        Closed polygons (x', y'), one per level, mm.
    zp : ndarray, shape (L,)
        Their levels z', mm.
    plane : tuple of (ndarray, ndarray)
        (point (3,) in mm, unit normal (3,) toward the side cut off).
    Returns
    -------
    ndarray, shape (L,)
        The areas below the plane, mm².
    """
    c, n = plane
    nxy = n[:2]
    if float(nxy @ nxy) < 1e-20:                                  # a horizontal plane: cut or not
        full = 0.5 * np.abs((poly[..., 0] * np.roll(poly[..., 1], -1, axis=1)
                             - poly[..., 1] * np.roll(poly[..., 0], -1, axis=1)).sum(axis=1))
        return np.where(zp <= c[2], full, 0.0)
    k = float(c @ n) - n[2] * zp                                   # n_xy · X = k on the cut line
    d = poly @ nxy - k[:, None]                                   # > 0 above the plane
    P, Q = poly, np.roll(poly, -1, axis=1)
    dP, dQ = d, np.roll(d, -1, axis=1)
    inP, inQ = dP <= 0, dQ <= 0
    denom = np.where(dP != dQ, dP - dQ, 1.0)
    X = P + (dP / denom)[..., None] * (Q - P)

    def cross(a, b):
        return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]

    contrib = np.where(inP & inQ, cross(P, Q), 0.0)
    contrib += np.where(inP & ~inQ, cross(P, X), 0.0)
    contrib += np.where(~inP & inQ, cross(X, Q), 0.0)
    nn = float(nxy @ nxy)
    u = np.array([-nxy[1], nxy[0]]) / np.sqrt(nn)
    o = k[:, None] * nxy[None, :] / nn
    t = (X - o[:, None, :]) @ u
    closing = (np.where(~inP & inQ, t, 0.0) - np.where(inP & ~inQ, t, 0.0)).sum(axis=1)
    o_cross_u = o[:, 0] * u[1] - o[:, 1] * u[0]
    return 0.5 * np.abs(contrib.sum(axis=1) + o_cross_u * closing)


def _sections(anatomy: Anatomy, motion: Motion, f: float, zp: np.ndarray, region: str, n: int) -> np.ndarray:
    """Polygons (L, m, 2) of one region's cuts by the deformed levels z' (realistic frame); a
    level without the region gives a degenerate polygon of zero area."""
    lam = float(motion.lam(f))
    z = zp / lam
    psi = motion.psi(z, f)[:, None]
    shift = (anatomy.shape.apex_shift(zp, anatomy.z_base) if anatomy.shape.bends
             else np.zeros((len(zp), 2)))
    zz = z[:, None]
    if region in ("lv_endo", "lv_epi"):
        th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)[None, :]
        # the LV sections at (θ, z) once (θ a row, z a column: the angular factors are computed
        # per angle, not per point): the cut's own S and the knots of the radial map (M3) (on
        # the LV boundaries G needs S1 and S2 only, so S3 = S2 stands in for the RV's)
        s1, s2 = anatomy.lv_sections(zz, th)
        s = np.maximum(s1 if region == "lv_endo" else s2, 0.0)
        sp = motion.radial_map(anatomy, s, th, zz, f, knots=motion.knots(anatomy, th, zz, f, (s1, s2, s2)))
    else:
        epi = region == "rv_epi"
        lo, hi = anatomy.rv_sector(np.minimum(z, anatomy.z_base), epi)
        lo, hi = np.where(z <= anatomy.z_base, lo, 0.0), np.where(z <= anatomy.z_base, hi, 0.0)
        v = np.linspace(0.0, 1.0, n)
        tf = lo[:, None] + (hi - lo)[:, None] * v[None, :]
        ts = lo[:, None] + (hi - lo)[:, None] * np.linspace(1.0, 0.0, n // 2 + 2)[None, 1:-1]
        th = np.concatenate([tf, ts], axis=1)
        # the levels with a crescent (elsewhere s = 0, a degenerate polygon, whatever the map);
        # every section value once there: the free wall's S_rv (endo for the knot S3; epi too for
        # the epicardial cut), S1 and S2 everywhere (on the septum the cut is S2 itself, where G
        # needs S1 and S2 only: S3 = S2 stands in)
        act = np.flatnonzero(hi > lo)
        sp = np.zeros(th.shape)
        if len(act):
            tfa, tha, za = tf[act], th[act], zz[act]
            zf = np.broadcast_to(za, tfa.shape)
            rv_endo = anatomy.s_rv(tfa, zf, False)
            s1, s2 = anatomy.lv_sections(np.broadcast_to(za, tha.shape), tha)
            nf = tf.shape[1]
            s = np.concatenate([anatomy.s_rv(tfa, zf, True) if epi else rv_endo, s2[:, nf:]], axis=1)
            s3 = np.concatenate([np.maximum(s2[:, :nf], rv_endo), s2[:, nf:]], axis=1)
            sp[act] = motion.radial_map(anatomy, np.maximum(s, 0.0), tha, np.broadcast_to(za, tha.shape),
                                        f, layers=(s1, s2, s3))
    r = np.sqrt(np.maximum(sp, 0.0))
    return np.stack([r * np.cos(th - psi), r * np.sin(th - psi)], axis=-1) + shift[:, None, :]


def _levels(top: float, planes, reach: float, dz: float, dz_fine: float) -> np.ndarray:
    """Integration levels: every dz mm, and every dz_fine mm where a valve plane crosses the heart
    (the section area changes fast, or jumps, there)."""
    parts = [np.arange(0.0, top + dz, dz)]
    for c, n in planes:
        tilt = np.hypot(n[0], n[1]) / abs(n[2])
        lo, hi = c[2] - tilt * reach - 0.5, c[2] + tilt * reach + 0.5
        parts.append(np.arange(lo, hi, dz_fine))
    return np.unique(np.concatenate(parts))


def section_volumes(anatomy: Anatomy, motion: Motion, f: float, dz: float = 0.25, dz_fine: float = 0.02,
                    n: int = 360) -> dict[str, float]:
    """Method A: LV cavity, LV myocardium, RV cavity, RV myocardium (mL) at phase f.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    dz : float, optional
        Level spacing of the section integral, mm.
    dz_fine : float, optional
        Level spacing near the valve planes, mm.
    n : int, optional
        Points per section polygon.
    Returns
    -------
    dict of str to float
        ``lv_cavity``, ``lv_myocardium``, ``rv_cavity``, ``rv_myocardium``, in mL.
    """
    return dict(_section_volumes(anatomy, motion, float(f), dz, dz_fine, n))


@functools.lru_cache(maxsize=16)
def _section_volumes(anatomy: Anatomy, motion: Motion, f: float, dz: float, dz_fine: float,
                     n: int) -> dict[str, float]:
    planes = valve_planes(anatomy, motion, f)
    lam = float(motion.lam(f))
    top = lam * (anatomy.z_base + anatomy.shape.saddle_mm) + 8.0
    reach = 1.5 * max(anatomy.r_short_epi, anatomy.r_free_endo + anatomy.rv_wall) + 10.0
    vol = {}
    for key in ("lv_endo", "lv_epi", "rv_endo", "rv_epi"):
        plane = planes["mitral" if key.startswith("lv") else "tricuspid"]
        zs = _levels(top, [plane], reach, dz, dz_fine)
        zs = zs[(zs > 0) & (zs < top)]
        area = clipped_areas(_sections(anatomy, motion, f, zs, key, n), zs, plane)
        vol[key] = float(np.trapezoid(area, zs)) / 1000.0
    lv_myocardium = vol["lv_epi"] - vol["lv_endo"]       # the LVOT adds lumen, no wall
    if anatomy.outflow is not None:
        for key, v in _outflow_section_volumes(anatomy, motion, f, planes, n).items():
            vol[key] += v
        if anatomy.tricuspid_dip > 0:
            for key, (_, window) in tricuspid_cap_volumes(anatomy, motion, f, planes["tricuspid"],
                                                          n, dz_fine=0.1, body=False).items():
                vol[key] += window
    return {"lv_cavity": vol["lv_endo"], "lv_myocardium": lv_myocardium,
            "rv_cavity": vol["rv_endo"], "rv_myocardium": vol["rv_epi"] - vol["rv_endo"]}


# ----------------------------------------------------------------- tricuspid annulus
def _cap_levels(anatomy: Anatomy) -> tuple[float, float]:
    """Material heights between which a dipping tricuspid annulus' best-fit plane can cut the RV
    body: from well below its lowest point to the base plane, mm."""
    return anatomy.z_base - 2.0 * anatomy.tricuspid_dip - 6.0, anatomy.z_base


def _window_material(anatomy: Anatomy, z: np.ndarray, epi: bool, n: int, n_back: int | None = None) -> np.ndarray:
    """Material (s, θ) polygons (L, n + n_back, 2) of the RV body's part inside the outflow tract's
    base window (:meth:`RvotFrame.window` at z_b) at heights z ≤ z_b: the free wall over the window
    ∩ the crescent, back along the LV epicardium (``n_back`` interior points, n − 2 at the free
    wall's angles); a degenerate polygon where the window misses the crescent."""
    n_back = n // 2 if n_back is None else n_back
    w_lo, w_hi = (float(v) for v in ofl.rvot_frame(anatomy).window(anatomy.z_base, epi))
    lo, hi = anatomy.rv_sector(z, epi)
    a, b = np.maximum(lo, w_lo), np.minimum(hi, w_hi)
    b = np.maximum(a, b)
    v = np.linspace(0.0, 1.0, n)
    tf = a[:, None] + (b - a)[:, None] * v[None, :]
    ts = a[:, None] + (b - a)[:, None] * np.linspace(1.0, 0.0, n_back + 2)[None, 1:-1]
    zz = z[:, None]
    s = np.concatenate([anatomy.s_rv_body(tf, np.broadcast_to(zz, tf.shape), epi),
                        anatomy.s_lv_epi(np.broadcast_to(zz, ts.shape), ts)], axis=1)
    s = np.where((b > a)[:, None], np.maximum(s, 0.0), 0.0)
    return np.stack([s, np.concatenate([tf, ts], axis=1)], axis=-1)


def _polygon_areas(poly: np.ndarray) -> np.ndarray:
    """Shoelace areas (mm²) of closed polygons (L, m, 2)."""
    return 0.5 * np.abs((poly[..., 0] * np.roll(poly[..., 1], -1, axis=1)
                         - poly[..., 1] * np.roll(poly[..., 0], -1, axis=1)).sum(axis=1))


def tricuspid_cap_volumes(anatomy: Anatomy, motion: Motion, f: float, plane, n: int = 360,
                          dz_fine: float = 0.1, body: bool = True) -> dict[str, tuple[float, float]]:
    """Method A, for a dipping tricuspid annulus: per RV surface (``rv_endo``, ``rv_epi``) the
    volumes (mL) at phase f, on the basal side of the tricuspid ``plane`` and below z' = λ z_b, of
    (1) the whole RV body and (2) its part in the outflow tract's base window (0 without tracts).

    The RV cavity (docs/metrics.md) is the body closed at the tricuspid plane united with the
    tract's lumen above that plane: below z_b the tract is the body's window part, so with
    tracts (2) is added to the body below the plane; (1) is what the body's volume up to z_b
    (the preset solver's) overcounts (``body=False``: not computed, 0).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    plane : tuple of (ndarray, ndarray)
        The tricuspid plane (centroid (3,) mm, unit normal toward the base).
    n : int, optional
        Points per section.
    dz_fine : float, optional
        Level spacing, mm.
    body : bool, optional
        Compute (1) as well.
    Returns
    -------
    dict of str to tuple of (float, float)
        ``rv_endo``, ``rv_epi`` -> ((1), (2)) in mL.
    """
    lam = float(motion.lam(f))
    z_lo, z_hi = _cap_levels(anatomy)
    zs = _outflow_levels(lam * z_lo, lam * z_hi, dz_fine)
    out = {}
    for key, epi in (("rv_endo", False), ("rv_epi", True)):
        whole = 0.0
        if body:
            poly = _sections(anatomy, motion, f, zs, key, n)
            whole = float(np.trapezoid(_polygon_areas(poly) - clipped_areas(poly, zs, plane), zs)) / 1000.0
        window = 0.0
        if anatomy.outflow is not None:
            wpoly = _deform_polar(anatomy, motion, f, _window_material(anatomy, zs / lam, epi, n), zs / lam)
            window = float(np.trapezoid(_polygon_areas(wpoly) - clipped_areas(wpoly, zs, plane), zs)) / 1000.0
        out[key] = (whole, window)
    return out


def ed_tricuspid_correction(anatomy: Anatomy, n: int = 64, dz_fine: float = 0.25) -> dict[str, float]:
    """What the tricuspid closure changes at end-diastole (mm³; ``rv_endo``, ``rv_epi``) against the
    RV body up to the base plane (the preset solver's volumes): minus the body on the basal side of
    the best-fit tricuspid plane, plus, with tracts, the window's part there (the tract's lumen
    starting at the plane). 0 for a planar annulus.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy.
    n : int, optional
        Points per section.
    dz_fine : float, optional
        Level spacing, mm.
    Returns
    -------
    dict of str to float
        ``rv_endo``, ``rv_epi`` -> the change in mm³.
    """
    if anatomy.tricuspid_dip == 0.0:
        return {"rv_endo": 0.0, "rv_epi": 0.0}
    still = Motion(ls=0.0, lv_ef=0.0, rv_ef=0.0, septal_flattening=0.0, apex_rotation_deg=0.0,
                   base_rotation_deg=0.0, z_base=anatomy.z_base)
    lm = annotate.landmarks(anatomy, still, 0.0, outflow=False)["tricuspid"]
    c, nrm = fit_plane(annotate.bend(anatomy, lm))
    caps = tricuspid_cap_volumes(anatomy, still, 0.0, (c, nrm if nrm[2] > 0 else -nrm), n, dz_fine)
    return {k: (w - b) * 1000.0 for k, (b, w) in caps.items()}


# ----------------------------------------------------------------- outflow tracts
def _rvot_material(anatomy: Anatomy, z: np.ndarray, epi: bool, n: int, n_back: int | None = None) -> np.ndarray:
    """Material (s, θ) of the RVOT section polygons at heights z (> z_b): the free wall over the
    window θ_lo → θ_hi (n points), back along the LV epicardium (``n_back`` interior points, n//2
    by default; n − 2 puts them at the free wall's angles); (L, n + n_back, 2)."""
    n_back = n // 2 if n_back is None else n_back
    fr = ofl.rvot_frame(anatomy)
    lo, hi = fr.window(z, epi)
    v = np.linspace(0.0, 1.0, n)
    tf = lo[:, None] + (hi - lo)[:, None] * v[None, :]
    ts = lo[:, None] + (hi - lo)[:, None] * np.linspace(1.0, 0.0, n_back + 2)[None, 1:-1]
    zz = z[:, None]
    s = np.concatenate([ofl.s_rvot(anatomy, tf, np.broadcast_to(zz, tf.shape), epi),
                        anatomy.s_lv_epi(np.broadcast_to(zz, ts.shape), ts)], axis=1)
    return np.stack([np.maximum(s, 0.0), np.concatenate([tf, ts], axis=1)], axis=-1)


def _lvot_material(anatomy: Anatomy, z: np.ndarray, n: int) -> np.ndarray:
    """Material (s, θ) of the LVOT section polygons at heights z: (L, n, 2)."""
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    xy = ofl.lvot_boundary(anatomy, phi[None, :], z[:, None])
    return np.stack([xy[..., 0] ** 2 + xy[..., 1] ** 2, np.arctan2(xy[..., 1], xy[..., 0])], axis=-1)


def _deform_polar(anatomy: Anatomy, motion: Motion, f: float, st: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Material section polygons (s, θ) at heights z -> deformed, bent (x, y) at phase f."""
    s, th = st[..., 0], st[..., 1]
    zz = np.broadcast_to(z[:, None], s.shape)
    sp = motion.radial_map(anatomy, s, th, zz, f)
    r = np.sqrt(np.maximum(sp, 0.0))
    a = th - motion.psi(zz, f)
    xy = np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
    if anatomy.shape.bends:
        xy = xy + anatomy.shape.apex_shift(float(motion.lam(f)) * z, anatomy.z_base)[:, None, :]
    return xy


def _outflow_levels(lo: float, hi: float, dz: float) -> np.ndarray:
    return np.linspace(lo, hi, max(int(np.ceil((hi - lo) / dz)), 2) + 1)


def ed_outflow_volumes(anatomy: Anatomy, parts=("rv", "lv"), dz: float = 0.25, n: int = 96,
                       exact_planes: bool = True) -> dict[str, float]:
    """Method A at end-diastole for the outflow tracts alone (mL; ``rv_endo``, ``rv_epi``,
    ``lv_endo`` as in :func:`section_volumes`): what the preset solver adds to the body volumes.
    ``exact_planes=False`` (the solver): the material valve planes, the mitral one fitted to the
    unbent annulus (the apex bend moves it by ~0.01 mm at the base).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy.
    parts : tuple of str, optional
        ``"rv"`` and/or ``"lv"``.
    dz : float, optional
        Level spacing, mm.
    n : int, optional
        Points per section.
    exact_planes : bool, optional
        The valve planes at ED (else the material ones, as the solver uses).
    Returns
    -------
    dict of str to float
        ``rv_endo``, ``rv_epi``, ``lv_endo`` -> the tract's volume in mL.
    """
    still = Motion(ls=0.0, lv_ef=0.0, rv_ef=0.0, septal_flattening=0.0, apex_rotation_deg=0.0,
                   base_rotation_deg=0.0, z_base=anatomy.z_base)
    if exact_planes:
        planes = valve_planes(anatomy, still, 0.0)
    else:
        planes = {}
        if "rv" in parts:
            fr = ofl.rvot_frame(anatomy)
            planes["pulmonary"] = (np.asarray(fr.plane_point), np.asarray(fr.plane_normal))
        if "lv" in parts:
            fl = ofl.lvot_frame(anatomy)
            planes["aortic"] = (np.asarray(fl.plane_point), np.asarray(fl.plane_normal))
            th = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
            zt = anatomy.z_top(th)
            r = np.sqrt(anatomy.s_lv_endo(zt, th))
            c, nrm = fit_plane(np.column_stack([r * np.cos(th), r * np.sin(th), zt]))
            planes["mitral"] = (c, nrm if nrm[2] > 0 else -nrm)
    return _outflow_section_volumes(anatomy, still, 0.0, planes, n, dz, parts)


def _outflow_section_volumes(anatomy: Anatomy, motion: Motion, f: float, planes: dict, n: int,
                             dz: float = 0.25, parts=("rv", "lv")) -> dict[str, float]:
    """Method A for the outflow tracts, added to the body volumes (mm³ -> mL): the RVOT lumen and
    wall above the tricuspid plane z' = λ z_b and below the pulmonary valve plane; the LVOT as
    |D ∩ aortic⁻| − |D ∩ mitral⁻| (the LVOT lumen above the mitral plane, D below the aortic plane
    wherever it is below the mitral one). The section areas are continuous in z' (tilted planes,
    the tract starting at z_b), so the trapezoid rule needs no refinement at the planes."""
    lam = float(motion.lam(f))
    out = {}
    zb = anatomy.z_base
    top = lam * (float(ofl.pulmonary_ring(anatomy)[:, 2].max()) + 6.0)
    zs = _outflow_levels(lam * zb, top, dz)
    for key, epi in (("rv_endo", False), ("rv_epi", True)) if "rv" in parts else ():
        poly = _deform_polar(anatomy, motion, f, _rvot_material(anatomy, zs / lam, epi, n), zs / lam)
        out[key] = float(np.trapezoid(clipped_areas(poly, zs, planes["pulmonary"]), zs)) / 1000.0
    if "lv" not in parts:
        return out
    lo = lam * (anatomy.z_top_min - 4.0)
    hi = lam * (float(ofl.aortic_ring(anatomy)[:, 2].max()) + 4.0)
    zs = _outflow_levels(lo, hi, dz)
    poly = _deform_polar(anatomy, motion, f, _lvot_material(anatomy, zs / lam, n), zs / lam)
    above_mitral = clipped_areas(poly, zs, planes["aortic"]) - clipped_areas(poly, zs, planes["mitral"])
    out["lv_endo"] = float(np.trapezoid(above_mitral, zs)) / 1000.0
    return out


def _lvot_check(anatomy: Anatomy, motion: Motion, f: float, planes: dict) -> None:
    """The LVOT formula needs the aortic plane above the mitral one over the LVOT: checked on the
    aortic annulus points."""
    ring = annotate.bend(anatomy, motion.forward(anatomy, np.asarray(ofl.aortic_ring(anatomy)), f))
    c, nrm = planes["mitral"]
    if np.any((ring - c) @ nrm <= 0):
        raise PhantomError("the aortic annulus dips below the mitral valve plane")


# ----------------------------------------------------------------- method B: meshes
def _grid_faces(n_rows: int, n_cols: int, offset: int = 0) -> np.ndarray:
    """Quads of a (n_rows, n_cols) vertex grid, periodic in the columns, as triangles."""
    i, j = np.meshgrid(np.arange(n_rows - 1), np.arange(n_cols), indexing="ij")
    a = i * n_cols + j
    b = i * n_cols + (j + 1) % n_cols
    c = (i + 1) * n_cols + (j + 1) % n_cols
    d = (i + 1) * n_cols + j
    return offset + np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                                    np.stack([a, c, d], -1).reshape(-1, 3)])


def _closed_tube(rings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed mesh from (m, n, 3) rings: the first row collapsed to a pole, the last capped by a fan
    about its centroid."""
    m, n, _ = rings.shape
    body = rings[1:].reshape(-1, 3)
    pole = rings[0].mean(axis=0)
    cap = rings[-1].mean(axis=0)
    v = np.vstack([body, pole, cap])
    ip, ic = len(body), len(body) + 1
    f = [_grid_faces(m - 1, n)]
    j = np.arange(n)
    f.append(np.column_stack([np.full(n, ip), (j + 1) % n, j]))
    last = (m - 2) * n
    f.append(np.column_stack([np.full(n, ic), last + j, last + (j + 1) % n]))
    faces = np.concatenate(f)
    # orient outward
    t = v[faces]
    if np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() < 0:
        faces = faces[:, ::-1]
    return v, faces


def _closed_sphere(rings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed mesh from (m, n, 3) rings whose first and last rows are each collapsed to a pole."""
    m, n, _ = rings.shape
    body = rings[1:-1].reshape(-1, 3)
    v = np.vstack([body, rings[0].mean(axis=0), rings[-1].mean(axis=0)])
    i0, i1 = len(body), len(body) + 1
    j = np.arange(n)
    last = (m - 3) * n
    faces = np.concatenate([_grid_faces(m - 2, n),
                            np.column_stack([np.full(n, i0), (j + 1) % n, j]),
                            np.column_stack([np.full(n, i1), last + j, last + (j + 1) % n])])
    t = v[faces]
    if np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() < 0:
        faces = faces[:, ::-1]
    return v, faces


def myocardium_rings(anatomy: Anatomy, n_mu: int, n_theta: int, n_strip: int = 8) -> np.ndarray:
    """Material rings of the closed LV myocardium: the epicardium from its apex up to the saddle
    annulus, the annulus strip from epicardium to endocardium, the endocardium back down to its
    apex.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy.
    n_mu : int
        Rings along each surface.
    n_theta : int
        Points per ring.
    n_strip : int, optional
        Rings across the annulus strip.
    Returns
    -------
    ndarray, shape (k, n_theta, 3)
        Material rings, mm (apex to apex, through the annulus).
    """
    th = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
    zt = anatomy.z_top(th)
    epi = _lv_rings(anatomy, "lv_epi", zt, n_mu, n_theta)
    endo = _lv_rings(anatomy, "lv_endo", zt, n_mu, n_theta)
    r2 = np.sqrt(anatomy.s_lv_epi(zt, th))
    r1 = np.sqrt(anatomy.s_lv_endo(zt, th))
    a = np.linspace(0.0, 1.0, n_strip + 2)[1:-1, None]
    r = r2[None, :] + a * (r1 - r2)[None, :]
    strip = np.stack([r * np.cos(th), r * np.sin(th), np.broadcast_to(zt, r.shape)], axis=-1)
    return np.concatenate([epi, strip, endo[::-1]], axis=0)


def _volume(v: np.ndarray, faces: np.ndarray, plane=None) -> float:
    """Volume (mL) of a closed, outward mesh by the divergence theorem, V = Σ det(p0, p1, p2) / 6;
    with a ``plane`` (point c, unit normal n) only its part on the apical side n·(x − c) ≤ 0.

    The trimmed solid is bounded by the clipped triangles and a cap in the plane. With the origin
    moved to c the cap's tetrahedra are flat, so the volume is the sum over the clipped triangles
    alone: each triangle keeps all of itself (no vertex above), a quadrilateral (one above), a
    triangle (two above) or nothing, cut where the edges cross the plane. The mesh must be closed
    and consistently oriented (checked: every edge is used once in each direction)."""
    _check_closed(faces)
    if plane is None:
        tri = v[faces]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6000.0
    c, n = (np.asarray(a, dtype=float) for a in plane)
    q = v - c[None, :]
    d = q @ n
    tri, dt = q[faces], d[faces]
    above = dt > 0.0
    k = above.sum(axis=1)

    def det(a, b, e):
        return np.einsum("ij,ij->i", a, np.cross(b, e))

    def cut(a, b, da, db):
        return a + (b - a) * (da / (da - db))[:, None]

    total = det(*(tri[k == 0].transpose(1, 0, 2))).sum()
    for n_above in (1, 2):
        m = k == n_above
        if not m.any():
            continue
        t, dd, ab = tri[m], dt[m], above[m]
        # roll each triangle (keeping its orientation) so that the odd vertex out comes first:
        # the one above (one above) or the one below (two above)
        lone = np.argmax(ab if n_above == 1 else ~ab, axis=1)
        idx = (lone[:, None] + np.arange(3)[None, :]) % 3
        t = np.take_along_axis(t, idx[:, :, None], axis=1)
        dd = np.take_along_axis(dd, idx, axis=1)
        p0, p1, p2 = t[:, 0], t[:, 1], t[:, 2]
        x01 = cut(p0, p1, dd[:, 0], dd[:, 1])
        x20 = cut(p2, p0, dd[:, 2], dd[:, 0])
        if n_above == 1:        # kept: x01, p1, p2, x20
            total += (det(x01, p1, p2) + det(x01, p2, x20)).sum()
        else:                   # kept: p0, x01, x20
            total += det(p0, x01, x20).sum()
    return float(total) / 6000.0


def _check_closed(faces: np.ndarray) -> None:
    """PhantomError unless every directed edge of ``faces`` occurs once and its reverse once (a
    closed, consistently oriented triangle mesh)."""
    f = np.asarray(faces, dtype=np.int64)
    n = int(f.max()) + 1
    a = f.ravel()
    b = np.roll(f, -1, axis=1).ravel()
    fwd, bwd = np.sort(a * n + b), np.sort(b * n + a)
    if np.any(fwd[1:] == fwd[:-1]) or not np.array_equal(fwd, bwd):
        raise PhantomError("phantom truth mesh is not closed and consistently oriented")


def _lv_rings(anatomy: Anatomy, which: str, z_cap, n_mu: int, n_theta: int) -> np.ndarray:
    """Material (μ, θ) vertex rings of an LV surface from its apex up to height z_cap(θ)."""
    endo = which == "lv_endo"
    c = anatomy.r_long_endo if endo else anatomy.r_long_epi
    zc = anatomy.z_center
    th = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
    zcap = np.broadcast_to(np.asarray(z_cap, dtype=float), th.shape)
    mu_cap = np.arccos(np.clip(-(zcap - zc) / c, -1.0, 1.0))
    t = np.linspace(0.0, 1.0, n_mu + 1)[:, None]
    mu = t * mu_cap[None, :]
    z = zc - c * np.cos(mu)
    T = np.broadcast_to(th[None, :], z.shape)
    s = anatomy.s_lv_endo(z, T) if endo else anatomy.s_lv_epi(z, T)
    r = np.sqrt(np.maximum(s, 0.0))
    return np.stack([r * np.cos(T), r * np.sin(T), z], axis=-1)


def _rv_rings(anatomy: Anatomy, epi: bool, n_z: int, n_v: int) -> np.ndarray:
    """Material rings of the RV crescent (free wall lo → hi, back along the septum), onset → base."""
    z0 = anatomy.rv_onset(epi)
    u = np.linspace(0.0, 1.0, n_z + 1)
    z = np.minimum(z0 + (anatomy.z_base - z0) * u * u, anatomy.z_base)   # no rounding past the base
    lo, hi = anatomy.rv_sector(z, epi)
    v = np.linspace(0.0, 1.0, n_v + 1)
    th_free = lo[:, None] + (hi - lo)[:, None] * v[None, :]
    th_sept = lo[:, None] + (hi - lo)[:, None] * v[::-1][None, 1:-1]
    zz_f = np.broadcast_to(z[:, None], th_free.shape)
    zz_s = np.broadcast_to(z[:, None], th_sept.shape)
    s = np.concatenate([anatomy.s_rv(th_free, zz_f, epi), anatomy.s_lv_epi(zz_s, th_sept)], axis=1)
    th = np.concatenate([th_free, th_sept], axis=1)
    r = np.sqrt(np.maximum(s, 0.0))
    zc = np.broadcast_to(z[:, None], th.shape)
    return np.stack([r * np.cos(th), r * np.sin(th), zc], axis=-1)


def _moved(anatomy: Anatomy, motion: Motion, rings: np.ndarray, f: float) -> np.ndarray:
    p = motion.forward(anatomy, rings.reshape(-1, 3), f)
    return annotate.bend(anatomy, p).reshape(rings.shape)


def mesh_volumes(anatomy: Anatomy, motion: Motion, f: float, n_mu: int = 120, n_theta: int = 240,
                 n_z_rv: int = 120, n_v_rv: int = 120) -> dict[str, float]:
    """Method B: the same four volumes (mL) from closed meshes trimmed by the valve planes, and the
    material myocardial volumes (LV wall up to the saddle annulus, RV free wall).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_mu, n_theta : int, optional
        Grid of the LV surfaces (rings and points per ring).
    n_z_rv, n_v_rv : int, optional
        Grid of the RV crescents.
    Returns
    -------
    dict of str to float
        The four volumes of :func:`section_volumes` and ``lv_myocardium_material`` (the LV
        wall up to the saddle annulus), in mL.
    """
    planes = valve_planes(anatomy, motion, f)
    cap = anatomy.z_base + anatomy.shape.saddle_mm + 6.0
    vols = {}
    if anatomy.outflow is not None:
        _lvot_check(anatomy, motion, f, planes)
    for key in ("lv_endo", "lv_epi"):
        rings = _moved(anatomy, motion, _lv_rings(anatomy, key, cap, n_mu, n_theta), f)
        vols[key] = _volume(*_closed_tube(rings), plane=planes["mitral"])
    myo = _moved(anatomy, motion, myocardium_rings(anatomy, n_mu, n_theta), f)
    vols["lv_myocardium_material"] = _volume(*_closed_sphere(myo))
    for key, epi in (("rv_endo", False), ("rv_epi", True)):
        rings = _moved(anatomy, motion, _rv_rings(anatomy, epi, n_z_rv, n_v_rv), f)
        # (a planar tricuspid annulus is the top ring itself: no trim)
        vols[key] = _volume(*_closed_tube(rings),
                            plane=planes["tricuspid"] if anatomy.tricuspid_dip > 0 else None)
    lv_myocardium = vols["lv_epi"] - vols["lv_endo"]     # the LVOT adds lumen, no wall
    if anatomy.outflow is not None:
        for key, v in _outflow_mesh_volumes(anatomy, motion, f, planes, n_z_rv, n_v_rv).items():
            vols[key] += v
        if anatomy.tricuspid_dip > 0:
            # the tract's lumen above the tricuspid plane and below z_b: the body's window part
            z_lo, z_hi = _cap_levels(anatomy)
            z = np.linspace(z_lo, z_hi, n_z_rv + 1)
            for key, epi in (("rv_endo", False), ("rv_epi", True)):
                mesh = _crescent_tube(_rings_3d(anatomy, motion, f,
                                                _window_material(anatomy, z, epi, n_v_rv + 1, n_v_rv - 1), z))
                vols[key] += _volume(*mesh) - _volume(*mesh, plane=planes["tricuspid"])
    return {"lv_cavity": vols["lv_endo"], "lv_myocardium": lv_myocardium,
            "rv_cavity": vols["rv_endo"], "rv_myocardium": vols["rv_epi"] - vols["rv_endo"],
            "lv_myocardium_material": vols["lv_myocardium_material"]}


def _ladder_cap(n: int, offset: int, flip: bool) -> np.ndarray:
    """Triangles closing a crescent ring (free wall 0 … n−1, then the inner wall back, 2n − 2
    vertices, tips shared) by rungs between the points of equal angle on the two walls."""
    m = 2 * n - 2
    i = np.arange(n - 1)
    f0, f1 = i, i + 1
    s0, s1 = (2 * n - 2 - i) % m, (2 * n - 3 - i) % m
    t1 = np.column_stack([f0, f1, s1])[: n - 2]            # the last one is degenerate (tip)
    t2 = np.column_stack([f0, s1, s0])[1:]                 # the first one is degenerate (tip)
    tri = np.concatenate([t1, t2]) + offset
    return tri[:, ::-1] if flip else tri


def _crescent_tube(rings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed mesh of a tube of crescent rings (L, 2n − 2, 3), capped at both ends by rungs."""
    L, m, _ = rings.shape
    n = (m + 2) // 2
    v = rings.reshape(-1, 3)
    faces = np.concatenate([_grid_faces(L, m), _ladder_cap(n, 0, True), _ladder_cap(n, (L - 1) * m, False)])
    t = v[faces]
    if np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() < 0:
        faces = faces[:, ::-1]
    return v, faces


def _outflow_mesh_volumes(anatomy: Anatomy, motion: Motion, f: float, planes: dict, n_z: int,
                          n_v: int) -> dict[str, float]:
    """Method B for the outflow tracts: closed material meshes of the RVOT (from the tricuspid
    plane up past the pulmonary valve) and of the LVOT cylinder-in-endocardium D, every vertex
    moved, trimmed by the valve planes (mL)."""
    zb = anatomy.z_base
    out = {}
    z_top = float(ofl.pulmonary_ring(anatomy)[:, 2].max()) + 6.0
    z = zb + (z_top - zb) * np.linspace(0.0, 1.0, n_z + 1)
    for key, epi in (("rv_endo", False), ("rv_epi", True)):
        st = _rvot_material(anatomy, z, epi, n_v + 1, n_v - 1)
        rings = _rings_3d(anatomy, motion, f, st, z)
        out[key] = _volume(*_crescent_tube(rings), plane=planes["pulmonary"])
    fr = ofl.lvot_frame(anatomy)
    z = np.linspace(anatomy.z_top_min - 4.0, float(ofl.aortic_ring(anatomy)[:, 2].max()) + 4.0, n_z + 1)
    st = _lvot_material(anatomy, z, 2 * n_v)
    rings = _rings_3d(anatomy, motion, f, st, z)
    pole = _moved(anatomy, motion, np.array([[[fr.center[0], fr.center[1], z[0]]]]), f)
    mesh = _closed_tube(np.concatenate([np.broadcast_to(pole, (1,) + rings.shape[1:]), rings], axis=0))
    out["lv_endo"] = _volume(*mesh, plane=planes["aortic"]) - _volume(*mesh, plane=planes["mitral"])
    return out


def _rings_3d(anatomy: Anatomy, motion: Motion, f: float, st: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Material (s, θ) rings at heights z -> moved, bent 3-D rings (L, m, 3)."""
    r = np.sqrt(st[..., 0])
    th = st[..., 1]
    mat = np.stack([r * np.cos(th), r * np.sin(th), np.broadcast_to(z[:, None], r.shape)], axis=-1)
    return _moved(anatomy, motion, mat, f)


def volume_polynomials(anatomy: Anatomy, motion: Motion, f_max: float) -> dict[str, np.poly1d]:
    """V(f) per volume (mL) as the quadratic in the phase f through method A at f = 0, f_max / 2
    and f_max (the cavity scalings κ of the motion are quadratic in f; the valve planes move
    smoothly).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f_max : float
        The largest phase of the cycle (that of ES).
    Returns
    -------
    dict of str to numpy.poly1d
        Volume name -> V(f) in mL.
    """
    fs = np.array([0.0, 0.5 * f_max, f_max])
    vals = [section_volumes(anatomy, motion, float(f)) for f in fs]
    return {k: np.poly1d(np.polyfit(fs, [v[k] for v in vals], 2)) for k in vals[0]}


def volume_curve(anatomy: Anatomy, motion: Motion, f_max: float):
    """V(f) for every phase, from :func:`volume_polynomials`: a callable f -> dict of mL.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved realistic anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f_max : float
        The largest phase of the cycle.
    Returns
    -------
    callable
        ``curve(f) -> dict`` of the four volumes in mL.
    """
    poly = volume_polynomials(anatomy, motion, f_max)
    return lambda f: {k: float(p(f)) for k, p in poly.items()}
