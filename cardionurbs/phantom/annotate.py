"""Contours, landmarks and tag lines of the analytic phantom on its imaging planes.

Everything is computed in the heart frame at cycle phase f and returned as
(n, 3) heart-frame points on the plane; :mod:`cardionurbs.phantom.generate`
maps them to scanner mm.

Because the SA planes are perpendicular to the long axis and the motion keeps
z-planes planar (z' = λz), the tissue seen in SA plane z' = h at phase f is the
material section z = h/λ, and every surface cut is an explicit polar curve
s'(θ') = G(S(θ, z); θ, z) with θ = θ' + ψ(z) (motion eq. M3). LA planes
contain the axis, so the material angle of a point at height z' on the ray α is
θ = α + ψ(z'/λ) and again the cut is explicit in a surface parameter (the
spheroid angle μ for the LV, z for the RV). No root finding is needed except
the RV sector edges and apex, solved by bisection.

Tag lines (docs/metrics.md): ``sa1``/``sa2`` are the tissue planes n_k · x = c_i
(n_1 ⟂ n_2 ⟂ e_z) laid at ED with spacing d = 7 pixels; in an SA plane at
phase f they are the images of the material lines {n_k·x = c_i, z = h/λ},
clipped to the LV myocardium (gap over the cavity). ``la`` are the tissue
planes z = z_j, seen in LA views at z' = λ z_j, clipped to the LV myocardium.
Points are sampled about one per pixel of material length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from cardionurbs.cache import attached, memoized
from cardionurbs.geometry import polyline_crossings
from cardionurbs.phantom.anatomy import Anatomy, spheroid_s_unclamped, unit_phasor, wrap_angle
from cardionurbs.phantom.geometry import SliceSpec
from cardionurbs.phantom.motion import Motion

MIN_RADIUS_MM = 2.0      # sections smaller than this are not contoured
MIN_RV_WIDTH_MM = 1.5    # RV crescents thinner than this (at θ = 0) are not contoured
BASE_MARGIN_MM = 1.0     # SA planes must cut tissue at least this far below the base


@dataclass(frozen=True)
class TagGrid:
    """The ED tag pattern: spacing (mm), SA family angles (rad, about e_z), first plane offsets.

    Attributes
    ----------
    spacing : float
        The tag spacing d, mm.
    sa_angle : float
        Angle of the sa1 plane normal from e_x, rad (sa2 is +90°).
    n_half : int
        SA tag indices run 0 .. 2 n_half, index n_half nearest the axis.
    sa_offset : float
        c_i = (i − n_half) d + sa_offset, mm.
    la_offset : float
        z_j = la_offset + j d, mm.
    """

    spacing: float
    sa_angle: float          # angle of the sa1 plane normal from e_x; sa2 is +90°
    n_half: int              # SA tag indices run 0 .. 2 n_half, index n_half nearest the axis
    sa_offset: float         # c_i = (i − n_half) d + sa_offset
    la_offset: float         # z_j = la_offset + j d

    def sa_normal(self, family: str) -> np.ndarray:
        """Unit normal of an SA family's planes.

        Parameters
        ----------
        family : str
            ``"sa1"`` or ``"sa2"``.

        Returns
        -------
        ndarray, shape (3,)
            The normal, heart frame (in the xy-plane).
        """
        a = self.sa_angle + (0.0 if family == "sa1" else 0.5 * np.pi)
        return np.array([np.cos(a), np.sin(a), 0.0])

    def sa_positions(self) -> np.ndarray:
        """Offsets c_i of the SA tag planes along their normal.

        Returns
        -------
        ndarray, shape (2 n_half + 1,)
            c_i for i = 0 .. 2 n_half, mm.
        """
        return (np.arange(2 * self.n_half + 1) - self.n_half) * self.spacing + self.sa_offset

    def la_positions(self, z_max: float) -> np.ndarray:
        """Heights z_j of the LA tag planes up to ``z_max``.

        Parameters
        ----------
        z_max : float
            The highest height, mm.

        Returns
        -------
        ndarray
            z_j = la_offset + j d <= z_max, mm.
        """
        n = int(np.floor((z_max - self.la_offset) / self.spacing)) + 1
        return self.la_offset + self.spacing * np.arange(max(n, 0))

    def to_dict(self) -> dict:
        """JSON-safe tag pattern (truth.json).

        Returns
        -------
        dict
            ``spacing_mm``, ``sa1_normal_angle_deg``, ``sa_first_index_position_mm``,
            ``n_sa_tags``, ``la_first_plane_mm``.
        """
        return {"spacing_mm": self.spacing, "sa1_normal_angle_deg": float(np.degrees(self.sa_angle)),
                "sa_first_index_position_mm": float(self.sa_positions()[0]),
                "n_sa_tags": int(2 * self.n_half + 1), "la_first_plane_mm": self.la_offset}


def make_tag_grid(anatomy: Anatomy, spacing: float, sa_angle_deg: float = 45.0) -> TagGrid:
    """Tag planes covering the heart: SA indices symmetric about the axis, LA from the apex.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    spacing : float
        The tag spacing, mm.
    sa_angle_deg : float, optional
        Angle of the sa1 plane normal from e_x, degrees.
    Returns
    -------
    TagGrid
        The tag planes at ED.
    """
    reach = np.sqrt(anatomy.r_short_epi ** 2 * (1 + (anatomy.base_height / anatomy.r_long_epi) ** 2))
    reach = max(reach, anatomy.r_free_endo * (1 + anatomy.rv_offset) + anatomy.rv_wall)
    n_half = int(np.ceil(reach / spacing)) + 1
    return TagGrid(spacing=spacing, sa_angle=np.radians(sa_angle_deg), n_half=n_half,
                   sa_offset=0.37 * spacing, la_offset=0.5 * spacing)


def _polar(sp: np.ndarray, thp: np.ndarray, zp) -> np.ndarray:
    r = np.sqrt(np.maximum(sp, 0.0))
    zp = np.broadcast_to(np.asarray(zp, dtype=float), r.shape)
    return np.column_stack([r * np.cos(thp), r * np.sin(thp), zp])


def sa_material_height(motion: Motion, spec: SliceSpec, f: float) -> float:
    """The material (ED) height z = z' / λ(f) that an SA plane cuts at phase f.

    Parameters
    ----------
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    spec : cardionurbs.phantom.geometry.SliceSpec
        An SA slice (its height z', mm).
    f : float
        The cycle phase.

    Returns
    -------
    float
        z, mm.
    """
    return float(spec.height / motion.lam(f))


def sa_contours(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float,
                n_lv: int = 60, n_rv_free: int = 32, n_rv_septum: int = 16) -> dict[str, np.ndarray]:
    """Closed SA contours (heart frame at phase f) of one SA plane: lv_endo, lv_epi, rv_endo, rv_epi.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    spec : cardionurbs.phantom.geometry.SliceSpec
        The slice.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_lv : int, optional
        Points per LV contour.
    n_rv_free, n_rv_septum : int, optional
        Points on the RV free wall and septum.
    Returns
    -------
    dict of str to ndarray
        Structure -> closed contour (k, 3), heart frame, mm (RV ones where the plane cuts the RV).
    """
    z = sa_material_height(motion, spec, f)
    out: dict[str, np.ndarray] = {}
    if anatomy.realistic:
        return _sa_contours_realistic(anatomy, motion, spec, f, z, n_lv, n_rv_free, n_rv_septum)
    if not (0.0 < z <= anatomy.z_base - BASE_MARGIN_MM):
        return out
    psi = float(motion.psi(z, f))
    s1, s2 = float(anatomy.s_lv_endo(z)), float(anatomy.s_lv_epi(z))
    th = np.linspace(0.0, 2 * np.pi, n_lv, endpoint=False)
    if s2 < MIN_RADIUS_MM ** 2:
        return out
    if s1 >= MIN_RADIUS_MM ** 2:
        out["lv_endo"] = _polar(motion.radial_map(anatomy, s1, th, z, f), th - psi, spec.height)
    out["lv_epi"] = _polar(motion.radial_map(anatomy, s2, th, z, f), th - psi, spec.height)
    for name, epi in (("rv_endo", False), ("rv_epi", True)):
        if np.sqrt(float(anatomy.s_rv(0.0, z, epi))) - np.sqrt(s2) < MIN_RV_WIDTH_MM:
            continue
        edge = float(anatomy.rv_sector_edge(z, epi)[0])
        tf = np.linspace(-edge, edge, n_rv_free)
        ts = np.linspace(edge, -edge, n_rv_septum + 2)[1:-1]
        free = motion.radial_map(anatomy, anatomy.s_rv(tf, z, epi), tf, z, f)
        sept = motion.radial_map(anatomy, s2, ts, z, f)
        out[name] = _polar(np.r_[free, sept], np.r_[tf, ts] - psi, spec.height)
    return out


def _sa_contours_realistic(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float, z: float,
                           n_lv: int, n_rv_free: int, n_rv_septum: int) -> dict[str, np.ndarray]:
    """:func:`sa_contours` for a realistic anatomy: the same explicit polar curves with the
    angle-dependent sections S(θ, z) and the asymmetric RV sector [θ_lo, θ_hi]."""
    out: dict[str, np.ndarray] = {}
    if anatomy.outflow is not None and z > anatomy.z_base + BASE_MARGIN_MM:
        return _sa_outlet(anatomy, motion, spec, f, z, n_rv_free, n_rv_septum)
    # the LV is contoured below the lowest point of the saddle annulus (a plane through the saddle
    # shows part wall, part atrium); the RV likewise below the lowest point of its annulus
    if not (0.0 < z <= anatomy.z_base - BASE_MARGIN_MM):
        return out
    psi = float(motion.psi(z, f))
    th = np.linspace(0.0, 2 * np.pi, n_lv, endpoint=False)
    s1, s2 = anatomy.lv_sections(np.full(n_lv, z), th)
    if s2.mean() < MIN_RADIUS_MM ** 2:
        return out
    if z <= anatomy.z_top_min - BASE_MARGIN_MM:
        layers = (s1, s2, np.maximum(s2, anatomy.s_rv(th, np.full(n_lv, z))))   # evaluated once
        if s1.mean() >= MIN_RADIUS_MM ** 2:
            out["lv_endo"] = _polar(motion.radial_map(anatomy, s1, th, z, f, layers=layers), th - psi,
                                    spec.height)
        out["lv_epi"] = _polar(motion.radial_map(anatomy, s2, th, z, f, layers=layers), th - psi,
                               spec.height)
    for name, epi in (("rv_endo", False), ("rv_epi", True)):
        sector = _contoured_crescent(anatomy, z, epi) if z <= anatomy.z_top_rv_min - BASE_MARGIN_MM else None
        if sector is None:
            continue
        lo, hi = sector
        tf = np.linspace(lo, hi, n_rv_free)
        ts = np.linspace(hi, lo, n_rv_septum + 2)[1:-1]
        free = motion.radial_map(anatomy, anatomy.s_rv(tf, z, epi), tf, z, f)
        sept = motion.radial_map(anatomy, anatomy.s_lv_epi(z, ts), ts, z, f)
        out[name] = _polar(np.r_[free, sept], np.r_[tf, ts] - psi, spec.height)
    return out


def _sa_outlet(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float, z: float, n_free: int,
               n_septum: int) -> dict[str, np.ndarray]:
    """SA contours of the RV outflow tract above the tricuspid plane (material height z): the
    ``rv_outlet`` endocardial crescent and, when its wall is cut too, the ``rv_epi`` of the outlet;
    each only when the whole section lies below the pulmonary valve plane and is at least
    MIN_RV_WIDTH_MM wide."""
    from cardionurbs.phantom import outflow as ofl
    fr = ofl.rvot_frame(anatomy)
    psi = float(motion.psi(z, f))
    out: dict[str, np.ndarray] = {}
    for name, epi in (("rv_outlet", False), ("rv_epi", True)):
        lo, hi = (float(v) for v in fr.window(z, epi))
        tf = np.linspace(lo, hi, n_free)
        ts = np.linspace(hi, lo, n_septum + 2)[1:-1]
        s_f = ofl.s_rvot(anatomy, tf, np.full(n_free, z), epi)
        s_s = anatomy.s_lv_epi(np.full(len(ts), z), ts)
        th = np.r_[tf, ts]
        r = np.sqrt(np.maximum(np.r_[s_f, s_s], 0.0))
        below = np.all(ofl.rvot_top_term(anatomy, r * np.cos(th), r * np.sin(th), z) < 0)
        mid = n_free // 2
        width = np.sqrt(s_f[mid]) - np.sqrt(float(anatomy.s_lv_epi(np.array([z]), tf[mid:mid + 1])[0]))
        if not below or width < MIN_RV_WIDTH_MM or (epi and "rv_outlet" not in out):
            continue
        sp = motion.radial_map(anatomy, np.r_[s_f, s_s], th, np.full(len(th), z), f)
        out[name] = _polar(sp, th - psi, spec.height)
    return out


def _contoured_crescent(anatomy: Anatomy, z: float, epi: bool) -> tuple[float, float] | None:
    """(θ_lo, θ_hi) of a realistic RV crescent at material height z, or None where there is none or
    it is thinner than MIN_RV_WIDTH_MM at its middle angle (not contoured)."""
    lo, hi = (float(v[0]) for v in anatomy.rv_sector(z, epi))
    mid = 0.5 * (lo + hi)
    width = np.sqrt(float(anatomy.s_rv(mid, z, epi))) - np.sqrt(float(anatomy.s_lv_epi(z, mid)))
    return None if hi - lo <= 0 or width < MIN_RV_WIDTH_MM else (lo, hi)


# ----------------------------------------------------------------- realistic LA planes
PLANE_STEP_MM = 1.0      # sampling of an LA plane for the realistic contours (marching squares),
                         # each vertex then refined on its grid edge to the exact boundary


def unbend(anatomy: Anatomy, points: np.ndarray) -> np.ndarray:
    """Realistic heart-frame points -> the motion frame (the apex bend undone; a copy).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    points : ndarray, shape (n, 3)
        Realistic heart-frame points, mm.
    Returns
    -------
    ndarray, shape (n, 3)
        The points in the motion frame, mm.
    """
    if anatomy.shape is None:
        return np.array(points, dtype=float).reshape(-1, 3)
    return anatomy.shape.displace(points, anatomy.z_base, -1.0)


def bend(anatomy: Anatomy, points: np.ndarray) -> np.ndarray:
    """The motion frame -> realistic heart-frame points (the apex bend; a copy).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    points : ndarray, shape (n, 3)
        Motion-frame points, mm.
    Returns
    -------
    ndarray, shape (n, 3)
        The points in the realistic heart frame, mm.
    """
    if anatomy.shape is None:
        return np.array(points, dtype=float).reshape(-1, 3)
    return anatomy.shape.displace(points, anatomy.z_base, 1.0)


def material_fields(anatomy: Anatomy, motion: Motion, points: np.ndarray, f: float,
                    regions=None) -> dict[str, np.ndarray]:
    """Signed region functions (negative inside) of realistic heart-frame points at phase f for
    the four contoured regions — LV cavity, LV epicardium, RV cavity, RV epicardium — each as
    a tuple of terms (inside where all are negative): the wall terms (the RV has two, free wall
    and septum), then the top (valve closure) term, so that contour points on the closure can be
    told from points on the wall and the corners between the parts found.

    The wall terms compare the point's deformed squared radius s' with the deformed boundary's,
    G(S_k(θ, z)) (motion eq. M3) at the point's material angle and height: smooth across the
    boundary (the material s has a kink there, where the radial map changes slope). Beyond each
    LV apex the spheroid's S (negative there) continues the section, so the field stays positive
    below the apex instead of touching zero along the axis. Scaled by 1/50 mm to read roughly as
    mm. Also returned: ``s`` (= s'), ``s1``, ``s2`` (the deformed LV boundaries), ``theta``, ``z``.
    ``regions``: only these regions' terms (all four by default).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    points : ndarray, shape (n, 3)
        Realistic heart-frame points at phase f, mm.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    regions : iterable of str, optional
        The regions wanted (default all four).
    Returns
    -------
    dict
        Region -> tuple of its terms, each (n,) (≈ mm, negative inside), and ``s``, ``s1``,
        ``s2`` (mm²), ``theta`` (rad), ``z`` (mm), each (n,).
    """
    x = unbend(anatomy, points)
    z = x[:, 2] / float(motion.lam(f))
    th = np.arctan2(x[:, 1], x[:, 0]) + motion.psi(z, f)
    sp = x[:, 0] ** 2 + x[:, 1] ** 2
    e = unit_phasor(th)
    s1, s2 = anatomy.lv_sections(z, th, e)
    shells = _RvShells(anatomy, th, z, s2)
    regions = set(regions or ("lv_endo", "lv_epi", "rv_endo", "rv_epi"))
    if anatomy.outflow is not None:
        for name, epi in (("rv_endo", False), ("rv_epi", True)):
            if name in regions:     # the tract's terms need it at every point: the shell takes it
                shells.tract(epi)
    rv = shells.s_rv(False)
    layers = (s1, s2, np.maximum(s2, rv))
    s1 = s1 + np.minimum(spheroid_s_unclamped(z, anatomy.r_short_endo, anatomy.r_long_endo,
                                              anatomy.z_center), 0.0)
    s2 = s2 + np.minimum(spheroid_s_unclamped(z, anatomy.r_short_epi, anatomy.r_long_epi,
                                              anatomy.z_center), 0.0)
    # the RV free-wall boundaries as such (not max'ed with the LV epicardium), so that the free
    # wall and septum terms stay independent where they meet at the crescent's tip
    want = {"b1": "lv_endo" in regions, "b2": True, "b3": "rv_endo" in regions,
            "b4": "rv_epi" in regions}
    src = {"b1": lambda: s1, "b2": lambda: s2, "b3": lambda: rv,
           "b4": lambda: shells.s_rv(True)}
    knots = motion.knots(anatomy, th, z, f, layers)      # shared by every boundary's map
    b = {k: motion.radial_map(anatomy, src[k](), th, z, f, knots=knots) for k, on in want.items() if on}
    scale = 1.0 / 50.0
    out = {"s": sp, "theta": th, "z": z, "s1": b.get("b1"), "s2": b["b2"]}
    lv_top = z - anatomy.z_top(th)
    rv_top = z - anatomy.z_top_rv(th)     # the tricuspid annulus (z_b where it is planar)
    if "lv_endo" in regions:
        out["lv_endo"] = ((sp - b["b1"]) * scale, lv_top)
    if "lv_epi" in regions:
        out["lv_epi"] = ((sp - b["b2"]) * scale, lv_top)
    if "rv_endo" in regions:
        out["rv_endo"] = ((sp - b["b3"]) * scale, (b["b2"] - sp) * scale, rv_top)
    if "rv_epi" in regions:
        out["rv_epi"] = ((sp - b["b4"]) * scale, (b["b2"] - sp) * scale, rv_top)
    if anatomy.outflow is not None:
        _outflow_terms(anatomy, motion, out, regions, sp, th, z, f, layers, scale, knots, shells, e)
    return out


class _RvShells:
    """The RV shells' squared radii at one set of material (θ, z), each evaluated once: the body
    (:meth:`Anatomy.s_rv_body`), the tract's base radius and the whole shell (:meth:`Anatomy.s_rv`)."""

    def __init__(self, anatomy: Anatomy, th: np.ndarray, z: np.ndarray, s_epi=None) -> None:
        """``s_epi``: the LV epicardial S at (θ, z) when the caller has it (the tract's inner side)."""
        self.anatomy, self.th, self.z, self.s_epi = anatomy, th, z, s_epi

    @memoized
    def body(self, epi: bool) -> np.ndarray:
        return self.anatomy.s_rv_body(self.th, self.z, epi)

    @memoized
    def base_radius(self, epi: bool):
        if self.anatomy.outflow is None:
            return None
        from cardionurbs.phantom.outflow import rvot_base_radius
        return rvot_base_radius(self.anatomy, self.th, epi)

    @memoized
    def tract(self, epi: bool) -> np.ndarray:
        """The RVOT shell's S (:func:`cardionurbs.phantom.outflow.s_rvot`) at every point."""
        from cardionurbs.phantom.outflow import s_rvot
        return s_rvot(self.anatomy, self.th, self.z, epi, s_epi=self.s_epi, r_b=self.base_radius(epi))

    @memoized
    def s_rv(self, epi: bool) -> np.ndarray:
        """:meth:`Anatomy.s_rv`: the body, and above the tricuspid plane the tract (taken from
        :meth:`tract` when that has been asked for: the same values)."""
        if epi in self.tract:
            return np.where(self.z > self.anatomy.z_base, self.tract(epi), self.body(epi))
        return self.anatomy.s_rv(self.th, self.z, epi, body=self.body(epi),
                                 r_b=self.base_radius(epi), s_epi=self.s_epi)


def _outflow_terms(anatomy: Anatomy, motion: Motion, out: dict, regions, sp, th, z, f, layers,
                   scale: float, knots=None, shells: "_RvShells | None" = None, e=None) -> None:
    """Append the outflow tracts' terms to the region functions (see :func:`region_logic`):
    LV endocardium + (LVOT cylinder, aortic valve plane); RV endo/epicardium + (tract free wall,
    pulmonary valve plane, tract bottom 1 mm below the tricuspid plane, where the tract lies
    inside the body). The valve planes and the cylinder are material: the point's material radius
    comes from the inverse radial map. ``e``: e^{iθ} when the caller has it."""
    from cardionurbs.phantom import outflow as ofl
    r = np.sqrt(np.maximum(motion.inverse_radial_map(anatomy, sp, th, z, f, layers=layers,
                                                     knots=knots), 0.0))
    e = unit_phasor(th) if e is None else e
    x, y = r * e.real, r * e.imag          # r cos θ, r sin θ
    if "lv_endo" in regions:
        # (2- and 4-chamber views never reach the cylinder: the terms only keep the tree's shape)
        out["lv_endo"] = out["lv_endo"] + (ofl.lvot_cylinder_term(anatomy, x, y),
                                           ofl.lvot_top_term(anatomy, x, y, z))
    if not {"rv_endo", "rv_epi"} & set(regions):
        return
    pulmonary = ofl.rvot_top_term(anatomy, x, y, z)
    bottom = (anatomy.z_base - 1.0) - z
    for name, epi in (("rv_endo", False), ("rv_epi", True)):
        if name not in regions:
            continue
        shells = shells or _RvShells(anatomy, th, z, layers[1])
        s_ot = shells.tract(epi)
        s_ot = np.where(z > anatomy.z_base, s_ot, np.minimum(s_ot, shells.body(epi)))
        wall = (sp - motion.radial_map(anatomy, s_ot, th, z, f, layers=layers, knots=knots)) * scale
        out[name] = out[name] + (wall, pulmonary, bottom)


def region_logic(name: str, n_terms: int) -> tuple[tuple, set, dict]:
    """How a region's terms (:func:`material_fields`) combine: (tree, closure terms, wall parts).

    The tree nests ``("max", …)`` (inside all) and ``("min", …)`` (inside any) over term
    indices; closure terms are valve planes and the LVOT's aorto-mitral curtain (not contoured);
    wall parts group the wall terms that continue one another (the RV body's and the outflow
    tract's free wall), between which no corner is solved.

    Parameters
    ----------
    name : str
        The region (``"lv_endo"``, ``"lv_epi"``, ``"rv_endo"``, ``"rv_epi"``).
    n_terms : int
        Its number of terms.
    Returns
    -------
    tree : tuple
        The min/max tree.
    closure : set of int
        The closure terms.
    parts : dict of int to int
        Wall term index -> its wall part.
    """
    if name.startswith("lv"):
        if n_terms == 4:        # LV endocardium with the LVOT: wall ∧ (mitral ∨ (cylinder ∧ aortic))
            return ("max", 0, ("min", 1, ("max", 2, 3))), {1, 2, 3}, {0: 0}
        return ("max", 0, 1), {1}, {0: 0}
    if n_terms == 6:    # RV with the RVOT: septum ∧ ((body ∧ tricuspid) ∨ (tract ∧ pulmonary ∧ bottom))
        return ("max", 1, ("min", ("max", 0, 2), ("max", 3, 4, 5))), {2, 4, 5}, {0: 0, 3: 0, 1: 1}
    return ("max", 0, 1, 2), {2}, {0: 0, 1: 1}


def tree_value(tree, terms) -> np.ndarray:
    """The value of a min/max tree over arrays of terms (:func:`tree_eval` without the index).

    Parameters
    ----------
    tree : tuple or int
        A ``("max", ...)`` / ``("min", ...)`` tree over term indices (:func:`region_logic`).
    terms : sequence of ndarray
        The terms, each shape (n,).
    Returns
    -------
    ndarray, shape (n,)
        The tree's value.
    """
    if isinstance(tree, int):
        return terms[tree]
    op, *kids = tree
    return (np.maximum if op == "max" else np.minimum).reduce([tree_value(k, terms) for k in kids])


def tree_eval(tree, terms) -> tuple[np.ndarray, np.ndarray]:
    """(value, index of the term that gives it) of a min/max tree over arrays of terms.

    Parameters
    ----------
    tree : tuple or int
        A ``("max", ...)`` / ``("min", ...)`` tree over term indices (:func:`region_logic`).
    terms : sequence of ndarray
        The terms, each shape (n,).
    Returns
    -------
    value : ndarray, shape (n,)
        The tree's value.
    index : ndarray of int, shape (n,)
        The term giving it.
    """
    if isinstance(tree, int):
        return terms[tree], np.full(np.shape(terms[tree]), tree)
    op, *kids = tree
    vals, acts = zip(*(tree_eval(k, terms) for k in kids))
    v, a = np.stack(vals), np.stack(acts)
    i = (np.argmax if op == "max" else np.argmin)(v, axis=0)[None]
    return np.take_along_axis(v, i, 0)[0], np.take_along_axis(a, i, 0)[0]


def _plane_grid(anatomy: Anatomy, spec: SliceSpec, step: float):
    """(w, v) sample grid of a realistic LA plane covering the heart, and its 3-D points."""
    reach = max(anatomy.r_short_epi, anatomy.r_free_endo * (1 + anatomy.rv_offset) + anatomy.rv_wall)
    reach = 1.35 * reach + 12.0
    z_hi = anatomy.z_base + (anatomy.shape.saddle_mm if anatomy.shape is not None else 0.0) + 6.0
    if anatomy.outflow is not None and spec.id in ("la_3ch", "la_rvot"):
        # the views that cut a tract (the 2- and 4-chamber views pass beside both)
        from cardionurbs.phantom import outflow as ofl
        ring = ofl.aortic_ring(anatomy) if spec.id == "la_3ch" else ofl.pulmonary_ring(anatomy)
        z_hi = max(z_hi, float(ring[:, 2].max()) + 8.0)
    col = spec.column
    v_a, v_b = (z_hi - spec.center[2]) / col[2], (-6.0 - spec.center[2]) / col[2]
    v = np.arange(min(v_a, v_b), max(v_a, v_b) + step, step)
    w = np.arange(-reach, reach + step, step)
    W, V = np.meshgrid(w, v, indexing="ij")
    pts = spec.center[None, :] + W.reshape(-1, 1) * spec.row[None, :] + V.reshape(-1, 1) * col[None, :]
    return w, v, pts


def _refine_on_edges(loop: np.ndarray, grid: np.ndarray, iters: int = 3):
    """Move marching-squares vertices (fractional grid indices (k, 2)) to the zero of the exact
    field along their grid edge: regula falsi iterations. A generator (see :func:`_open_contour`):
    it yields the (k, 2) fractional indices where it needs the exact field, is sent the field's
    values there, and returns the refined vertices."""
    loop = loop.copy()
    along_w = np.abs(loop[:, 0] - np.round(loop[:, 0])) > 1e-9
    a = np.where(along_w[:, None], np.column_stack([np.floor(loop[:, 0]), loop[:, 1]]),
                 np.column_stack([loop[:, 0], np.floor(loop[:, 1])]))
    b = a + np.where(along_w[:, None], [1.0, 0.0], [0.0, 1.0])
    ia, ib = np.round(a).astype(int), np.round(b).astype(int)
    ia = np.clip(ia, 0, np.array(grid.shape) - 1)
    ib = np.clip(ib, 0, np.array(grid.shape) - 1)
    fa, fb = grid[ia[:, 0], ia[:, 1]], grid[ib[:, 0], ib[:, 1]]
    ta, tb = np.zeros(len(loop)), np.ones(len(loop))
    ok = np.sign(fa) != np.sign(fb)
    for _ in range(iters):
        tm = np.where(ok, ta - fa * (tb - ta) / np.where(fb != fa, fb - fa, 1.0), 0.5 * (ta + tb))
        fm = yield a + tm[:, None] * (b - a)
        left = np.sign(fm) == np.sign(fa)
        ta, fa = np.where(left, tm, ta), np.where(left, fm, fa)
        tb, fb = np.where(left, tb, tm), np.where(left, fb, fm)
    t = np.where(np.abs(fa) < np.abs(fb), ta, tb)
    return np.where(ok[:, None], a + t[:, None] * (b - a), loop)


def _corners(w: np.ndarray, v: np.ndarray, iters: int = 4, h: float = 1e-3):
    """Solve wall(w, v) = top(w, v) = 0 near each start point by Newton's method with a
    central-difference Jacobian (plane coordinates, mm): (k, 2) corner points. A generator (see
    :func:`_open_contour`): the five evaluations of a step are yielded at once as plane
    coordinates (w, v) and the pair (wall, top) is sent back."""
    p = np.column_stack([w, v]).astype(float)
    k = len(p)
    offs = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    for _ in range(iters):
        q = (p[None, :, :] + offs[:, None, :]).reshape(-1, 2)
        val = np.column_stack((yield q[:, 0], q[:, 1])).reshape(5, k, 2)
        jac = np.stack([(val[1] - val[2]) / (2 * h), (val[3] - val[4]) / (2 * h)], axis=-1)
        step = np.linalg.pinv(jac) @ val[0][..., None]
        step = step[..., 0]
        p -= np.clip(step, -2.0, 2.0)
    return p


def _annulus_corner(solved: np.ndarray, start: np.ndarray, value: np.ndarray, wall: np.ndarray,
                    top: np.ndarray, tol: float = 1e-4) -> np.ndarray:
    """The annulus end of a wall run among its candidate corners ``solved`` (k, 2), each solved
    by Newton from ``start`` against one closure term (the first: the closure the sampling
    grid saw next to the wall): the nearest one where the wall term, its closure term and the
    region's function (``value``, the min/max tree) all vanish to ``tol``; the first candidate
    when none does."""
    ok = (np.abs(value) < tol) & (np.abs(wall) < tol) & (np.abs(top) < tol)
    if not ok.any():
        return solved[0]
    d = np.where(ok, np.hypot(*(solved - start).T), np.inf)
    return solved[int(np.argmin(d))]


def _open_contour(name: str, fields: dict, shape, w, v, spec: SliceSpec,
                  n: int, start_positive: bool = True):
    """The open contour (wall part) of one region on a sampled plane, or None.

    A generator: wherever it needs the exact region terms it yields plane coordinates
    ``(w, v)`` and is sent the region's terms there (:func:`material_fields`), so that
    :func:`_run_contours` can evaluate the requests of every region and view of a frame in one
    call; it returns the contour.

    Marching squares on the max of the region's terms; each vertex refined to the exact boundary
    on its grid edge; the vertices where the top (closure) term is active dropped, and with them
    any wall run that closures cut off from the longest one; the exact
    corners inserted where the active term changes (the annulus ends, the RV apex where free
    wall meets septum, by Newton's method on the two terms); a cubic spline in arc length through
    each smooth piece; resampled to n points by arc length, starting at the annulus end with the
    larger w when ``start_positive``."""
    wall = _region_loop(name, fields, shape)
    if wall is None:
        return None
    loop, field, tree, closures, parts = wall

    def plane_uv(idx):
        return np.interp(idx[:, 0], np.arange(len(w)), w), np.interp(idx[:, 1], np.arange(len(v)), v)

    loop = yield from _relay(_refine_on_edges(loop, field), plane_uv, lambda t: tree_value(tree, t))
    ww, vv = plane_uv(loop)
    active = tree_eval(tree, (yield ww, vv))[1]
    run = _wall_run(active, closures)
    if run is None:
        return None
    keep, ends = run
    ww, vv, act = ww[keep], vv[keep], active[keep]
    corners = yield from _solve_corners(ww, vv, act, tree, closures, parts, ends)
    pieces = _wall_pieces(ww, vv, act, parts, corners, bool(ends))
    if start_positive and pieces[0][0, 0] < pieces[-1][-1, 0]:
        pieces = [p[::-1] for p in pieces[::-1]]
    uv = _resample_pieces(pieces, n)
    return spec.center[None, :] + uv[:, :1] * spec.row[None, :] + uv[:, 1:] * spec.column[None, :]


def _relay(inner, ask, answer):
    """Drive the generator ``inner`` from within a generator (``yield from _relay(...)``): each
    request of ``inner`` is passed on as ``ask(request)``, the reply sent back to ``inner`` as
    ``answer(reply)``; returns ``inner``'s result."""
    try:
        request = next(inner)
        while True:
            request = inner.send(answer((yield ask(request))))
    except StopIteration as done:
        return done.value


def _region_loop(name: str, fields: dict, shape):
    """Marching squares on the max/min tree of one region's sampled terms: the longest loop
    ((k, 2) fractional grid indices, not repeating its first vertex), the sampled field, the
    region's (tree, closures, parts); None without a loop of 8 vertices."""
    from skimage.measure import find_contours

    terms = [a.reshape(shape) for a in fields[name]]
    tree, closures, parts = region_logic(name, len(terms))
    field = tree_value(tree, terms)
    loops = find_contours(field, 0.0)
    if not loops:
        return None
    loop = max(loops, key=len)
    if len(loop) < 8:
        return None
    if np.allclose(loop[0], loop[-1]):
        loop = loop[:-1]
    return loop, field, tree, closures, parts


def _wall_run(active: np.ndarray, closures: set):
    """The loop vertices of the wall (``active``: the active term per vertex): their indices
    in order and the closure terms next to the run's two ends (``[]`` when the whole loop is
    wall); None when the longest wall run has fewer than 4 vertices."""
    on_wall = ~np.isin(active, list(closures))
    if on_wall.all():
        return np.arange(len(active)), []
    order = np.roll(np.arange(len(active)), -int(np.flatnonzero(~on_wall)[0]))
    # the wall's runs between closures: the ventricle's wall is the longest; a shorter one
    # (the LVOT's septal wall between the cylinder and the aortic plane) is cut off from it
    # by closure terms and is not joined to it across them
    edges = np.flatnonzero(np.diff(np.r_[0, on_wall[order].astype(int), 0]))
    starts, ends = edges[::2], edges[1::2]
    j = int(np.argmax(ends - starts))
    if ends[j] - starts[j] < 4:
        return None
    # the closure terms next to the wall's two ends (the valve planes the annulus corners are on)
    top_first = int(active[order[starts[j] - 1]])
    top_last = int(active[order[ends[j] % len(order)]])
    return order[starts[j]:ends[j]], [top_first, top_last]


def _solve_corners(ww, vv, act, tree, closures: set, parts, ends: list):
    """The corners of a wall run (plane coordinates ``ww``, ``vv`` with active terms ``act``):
    the annulus ends against the closure terms ``ends`` (none when empty) and the changes of
    wall part (the RV apex), all solved in one vectorised Newton iteration (:func:`_corners`).
    A generator like :func:`_open_contour`; returns corner number -> (w, v), in run order."""
    turns = [k for k in range(1, len(ww)) if parts[int(act[k])] != parts[int(act[k - 1])]]
    req = [(0.5 * (ww[k] + ww[k - 1]), 0.5 * (vv[k] + vv[k - 1]), act[k - 1], act[k]) for k in turns]
    # an annulus end is solved against every closure term: the grid vertex after the wall run can
    # show a closure that only binds a grid step further on (the LVOT cylinder 0.3 mm inside the
    # septal wall past the mitral corner, whose own corner with the wall is 8 mm up the tract);
    # the end is the nearest solution that lies on the region's boundary (_annulus_corner)
    cands = [[t] + sorted(closures - {t}) for t in ends]
    if ends:
        req = ([(ww[0], vv[0], act[0], t) for t in cands[0]] + req
               + [(ww[-1], vv[-1], act[-1], t) for t in cands[1]])
    if not req:
        return {}
    ci = np.array([r[2] for r in req], dtype=int)
    cj = np.array([r[3] for r in req], dtype=int)

    def term_pair(terms):
        e = np.stack(terms)
        cols = np.arange(e.shape[1])
        return e[np.tile(ci, 5), cols], e[np.tile(cj, 5), cols]

    newton = _corners(np.array([r[0] for r in req]), np.array([r[1] for r in req]))
    solved = yield from _relay(newton, lambda q: q, term_pair)
    if ends:
        e = np.stack((yield solved[:, 0], solved[:, 1]))
        cols = np.arange(len(req))
        n0, n1 = len(cands[0]), len(cands[1])
        start = np.array([r[:2] for r in req], dtype=float)
        pick = [_annulus_corner(solved[sl], start[sl], tree_value(tree, list(e[:, sl])),
                                e[ci[sl], cols[sl]], e[cj[sl], cols[sl]])
                for sl in (slice(0, n0), slice(len(req) - n1, len(req)))]
        solved = np.r_[pick[0][None], solved[n0:len(req) - n1], pick[1][None]]
    return {i: tuple(c) for i, c in enumerate(solved)}


def _wall_pieces(ww, vv, act, parts, corners: dict, has_ends: bool) -> list[np.ndarray]:
    """The wall run cut at its part changes into smooth pieces ((k, 2) plane mm each), the
    corners inserted at the cuts and, with ``has_ends``, the annulus corners at both ends."""
    pieces, cur = [], [(ww[0], vv[0])]
    if has_ends:
        cur = [corners[0], (ww[0], vv[0])]
    n_turn = 0
    for k in range(1, len(ww)):
        if parts[int(act[k])] != parts[int(act[k - 1])]:
            c = corners[n_turn + (1 if has_ends else 0)]
            n_turn += 1
            pieces.append(np.array(cur + [c]))
            cur = [c]
        cur.append((ww[k], vv[k]))
    if has_ends:
        cur.append(corners[len(corners) - 1])
    pieces.append(np.array(cur))
    return pieces


def _resample_pieces(pieces: list[np.ndarray], n: int) -> np.ndarray:
    """``n`` points evenly spaced in arc length along the pieces in order: (n, 2) plane mm."""
    # arc length per piece; a cubic spline through each smooth piece (chords of the ~1 mm vertex
    # spacing would cut the apex by up to 0.05 mm), linear where a piece has < 4 points
    curves, starts, total = [], [], 0.0
    for p in pieces:
        seg = np.hypot(*np.diff(p, axis=0).T)
        p = p[np.r_[True, seg > 1e-9]]
        arc = np.r_[0.0, np.cumsum(seg[seg > 1e-9])]
        if len(p) >= 4:
            cs = CubicSpline(arc, p)
            curves.append(lambda s, cs=cs: cs(s))
        else:
            curves.append(lambda s, a=arc, q=p: np.column_stack([np.interp(s, a, q[:, 0]),
                                                                 np.interp(s, a, q[:, 1])]))
        starts.append(total)
        total += arc[-1]
    s_all = np.linspace(0.0, total, n)
    which = np.clip(np.searchsorted(starts, s_all, side="right") - 1, 0, len(curves) - 1)
    uv = np.empty((n, 2))
    for k, cfun in enumerate(curves):
        m = which == k
        if m.any():
            uv[m] = cfun(s_all[m] - starts[k])
    return uv


def _la_contours_realistic(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float, n_side: int,
                           with_rv: bool, step: float = PLANE_STEP_MM,
                           with_lv: bool = True) -> dict[str, np.ndarray]:
    """LA contours of a realistic anatomy: the plane is sampled every ``step`` mm, each region's
    signed function (:func:`material_fields`) is contoured by marching squares, the valve
    closure is dropped and the open wall contour is returned in the motion frame."""
    return la_contours_realistic_views(anatomy, motion, [(spec, with_rv, with_lv)], f, n_side,
                                       step)[spec.id]


#: margins of the bound on the heart's outer squared radius (:func:`_outside_heart`): relative, mm²
OUTER_MARGIN, OUTER_MARGIN_MM2 = 0.1, 25.0


def _outer_s_table(anatomy: Anatomy, n: int = 720, n_z: int = 160) -> tuple:
    """S_out(θ) on n bins of θ ∈ [−π, π): an upper bound, over the heights (z_lo, z_hi) also
    returned, of the squared radius of every boundary the region terms compare with (LV
    epicardium, RV endo- and epicardium, RVOT shells), each bin's maximum over itself and two
    bins either side (mm²; per anatomy). Sampled at two angles per bin and n_z heights (every
    ~0.8 mm; with the heights where the surfaces have kinks or jumps: the LV equator, the base, the
    tract's top): the smooth maxima between samples exceed the samples by far less than the
    margins of :func:`_beyond_every_boundary`."""
    return attached(anatomy, "_outer_s_table", _make_outer_s_table)(n, n_z)


def _make_outer_s_table(anatomy: Anatomy, n: int, n_z: int) -> tuple:
    """:func:`_outer_s_table` made (once per anatomy and sampling)."""
    th = -np.pi + (np.arange(2 * n) + 0.5) * (2 * np.pi / (2 * n))
    top = anatomy.z_base + 80.0
    marks = [anatomy.z_center, anatomy.z_base, np.nextafter(anatomy.z_base, np.inf)]
    if anatomy.outflow is not None:
        from cardionurbs.phantom import outflow as ofl
        top = max(top, float(ofl.pulmonary_ring(anatomy)[:, 2].max()) + 20.0)
        marks.append(anatomy.z_base + ofl.rvot_frame(anatomy).height)
    z = np.unique(np.r_[np.linspace(-10.0, top, n_z), marks])[:, None]
    T = np.broadcast_to(th[None, :], (len(z), len(th)))
    Z = np.broadcast_to(z, T.shape)
    parts = [anatomy.s_lv_epi(Z, T), anatomy.s_rv(T, Z, False), anatomy.s_rv(T, Z, True)]
    if anatomy.outflow is not None:
        from cardionurbs.phantom import outflow as ofl
        parts += list(ofl.s_rvot_pair(anatomy, T, Z))
    per = np.max([p.max(axis=0) for p in parts], axis=0).reshape(n, 2).max(axis=1)
    return np.max([np.roll(per, k) for k in range(-2, 3)], axis=0), (-10.0, top)


def _outside_heart(anatomy: Anatomy, motion: Motion, points: np.ndarray, f: float,
                   grid_shape: tuple[int, int]) -> np.ndarray:
    """Points of a (w, v) sampling grid where every region term's value is surely positive
    (:func:`_beyond_every_boundary`) with their eight neighbours, so that no marching-squares cell
    they are a corner of is crossed by a contour."""
    from scipy.ndimage import binary_erosion

    far = _beyond_every_boundary(anatomy, motion, points, f).reshape(grid_shape)
    return binary_erosion(far, np.ones((3, 3), dtype=bool), border_value=1).ravel()


def _beyond_every_boundary(anatomy: Anatomy, motion: Motion, points: np.ndarray, f: float) -> np.ndarray:
    """Heart-frame points at phase f whose deformed squared radius s' exceeds the bound on every
    region boundary's image, so that every wall term of :func:`material_fields` is positive there.
    The boundaries' images are G(S) ≤ max(κ_L, κ_R, 1) S / λ ≤ (1 + ε) S / λ (motion eq. M3: the
    map's slopes are κ_L ≤ 1 + ε, κ_R ≤ 1 and 1) with S ≤ S_out(θ) at the point's material
    angle (:func:`_outer_s_table`), widened by OUTER_MARGIN and OUTER_MARGIN_MM2."""
    tab, (z_lo, z_hi) = _outer_s_table(anatomy)
    lam = float(motion.lam(f))
    x = unbend(anatomy, points)
    z = x[:, 2] / lam
    th = wrap_angle(np.arctan2(x[:, 1], x[:, 0]) + motion.psi(z, f))
    k = np.clip(((th + np.pi) / (2 * np.pi) * len(tab)).astype(int), 0, len(tab) - 1)
    bound = (1.0 + OUTER_MARGIN) * (1.0 + motion.septal_flattening) * tab[k] / lam + OUTER_MARGIN_MM2
    return (x[:, 0] ** 2 + x[:, 1] ** 2 > bound) & (z > z_lo) & (z < z_hi)


def _grid_fields(anatomy: Anatomy, motion: Motion, pts: np.ndarray, f: float, names,
                 grid_shape: tuple[int, int]) -> dict[str, tuple]:
    """The region terms of ``names`` on a sampling grid (:func:`material_fields`), computed where a
    contour can pass; where :func:`_outside_heart` shows every term positive, each term is set to
    a positive stand-in (the marching squares and the edge refinement read the field only at the
    corners of the cells a contour crosses: the same contours)."""
    out = np.flatnonzero(~_outside_heart(anatomy, motion, pts, f, grid_shape))
    fields = material_fields(anatomy, motion, pts[out], f, names)
    full = {}
    for name in names:
        terms = []
        for t in fields[name]:
            a = np.full(len(pts), 1.0e3)
            a[out] = t
            terms.append(a)
        full[name] = tuple(terms)
    return full


def la_contours_realistic_views(anatomy: Anatomy, motion: Motion, views, f: float, n_side: int = 30,
                                step: float = PLANE_STEP_MM) -> dict[str, dict[str, np.ndarray]]:
    """:func:`la_contours` of a realistic anatomy for several LA views at one phase f: ``views`` is
    a list of (spec, with_rv, with_lv); returns spec id -> contours. The exact region terms every
    view's contours ask for are evaluated together, in one :func:`material_fields` call per step
    (the same values as one view at a time: every term is computed point by point).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    views : list of tuple
        (spec, with_rv, with_lv) per LA view.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_side : int, optional
        Points per side of a contour.
    step : float, optional
        The marching step, mm.
    Returns
    -------
    dict of str to dict of str to ndarray
        Slice id -> structure -> open contour (k, 3), mm.
    """
    runs, out = [], {}
    for spec, with_rv, with_lv in views:
        w, v, pts = _plane_grid(anatomy, spec, step)
        names = (("lv_endo", "lv_epi") if with_lv else ()) + (("rv_endo", "rv_epi") if with_rv else ())
        fields = _grid_fields(anatomy, motion, pts, f, names, (len(w), len(v)))
        out[spec.id] = {}
        for name in names:
            gen = _open_contour(name, fields, (len(w), len(v)), w, v, spec, 2 * n_side - 1)
            runs.append((spec, name, gen))
    for (spec, name, _), c in zip(runs, _run_contours(anatomy, motion, f, runs)):
        if c is not None:
            out[spec.id][name] = unbend(anatomy, c)
    return {spec.id: out[spec.id] for spec, _, _ in views}


def _run_contours(anatomy: Anatomy, motion: Motion, f: float, runs) -> list:
    """Run :func:`_open_contour` generators ``runs`` ((spec, region, generator), ...) side by side:
    each round, the plane coordinates every running generator asks for are mapped to heart-frame
    points of its view, the region terms of all of them are computed in one
    :func:`material_fields` call and each generator is sent its own. Returns the contours."""
    result = [None] * len(runs)
    asks = {}
    for i, (_, _, gen) in enumerate(runs):
        try:
            asks[i] = next(gen)
        except StopIteration as done:
            result[i] = done.value
    while asks:
        order = list(asks)
        pts = [runs[i][0].center[None, :] + asks[i][0][:, None] * runs[i][0].row[None, :]
               + asks[i][1][:, None] * runs[i][0].column[None, :] for i in order]
        fields = material_fields(anatomy, motion, np.concatenate(pts), f, {runs[i][1] for i in order})
        ends = np.cumsum([len(p) for p in pts])
        nxt = {}
        starts = ends - np.array([len(p) for p in pts])
        for i, lo, hi in zip(order, starts, ends):
            terms = tuple(t[lo:hi] for t in fields[runs[i][1]])
            try:
                nxt[i] = runs[i][2].send(terms)
            except StopIteration as done:
                result[i] = done.value
        asks = nxt
    return result


def _la_tag_lines_realistic(anatomy: Anatomy, motion: Motion, grid: TagGrid, spec: SliceSpec, f: float,
                            step: float) -> list[tuple[str, int, np.ndarray]]:
    """LA tag lines of a realistic anatomy: the material planes z = z_j are at z' = λ z_j at phase f
    (the bend keeps z), a line of the LA plane; it is sampled every step/8 and clipped to the LV
    myocardium, and each run is resampled about once per ``step``."""
    lam = float(motion.lam(f))
    reach = 1.3 * max(anatomy.r_short_epi, 20.0) + 10.0
    w = np.arange(-reach, reach, step / 8.0)
    out = []
    row, col, c = spec.row, spec.column, spec.center
    levels = grid.la_positions(anatomy.z_top_min - BASE_MARGIN_MM)
    if not len(levels):
        return out
    v_all = (lam * levels[:, None] - c[2] - w[None, :] * row[2]) / col[2]          # every level at once
    pts = (c[None, None, :] + w[None, :, None] * row[None, None, :]
           + v_all[:, :, None] * col[None, None, :]).reshape(-1, 3)
    # the wall only where it can be: beyond every boundary the point is not inside the LV epicardium
    near = np.flatnonzero(~_beyond_every_boundary(anatomy, motion, pts, f))
    fl = material_fields(anatomy, motion, pts[near], f, ("lv_endo",))
    inside_all = np.zeros(len(pts), dtype=bool)
    inside_all[near] = (fl["s"] >= fl["s1"]) & (fl["s"] <= fl["s2"]) & (fl["lv_endo"][1] <= 0)
    inside_all = inside_all.reshape(len(levels), len(w))
    for j, zj in enumerate(levels):
        segs = _inside_runs(inside_all[j], w)
        if not segs:
            continue
        wj = _sample_segments(segs, step)
        vj = (lam * zj - c[2] - wj * row[2]) / col[2]
        p = c[None, :] + wj[:, None] * row[None, :] + vj[:, None] * col[None, :]
        out.append(("la", j, unbend(anatomy, p)))
    return out


def _la_side(motion: Motion, alpha: float, z: np.ndarray, f: float):
    """Material angle of the ray α at material heights z (LA plane) at phase f."""
    return alpha + motion.psi(z, f)


def la_contours(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float, n_side: int = 30,
                with_rv: bool = False, with_lv: bool = True) -> dict[str, np.ndarray]:
    """Open LA contours (annulus → apex → annulus) in an LA plane at phase f (heart frame); a
    realistic anatomy's ``la_rvot`` view has RV contours only (``with_lv=False``).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    spec : cardionurbs.phantom.geometry.SliceSpec
        The slice.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_side : int, optional
        Points per side (annulus to apex).
    with_rv : bool, optional
        Also the RV contours.
    with_lv : bool, optional
        The LV contours.
    Returns
    -------
    dict of str to ndarray
        Structure -> open contour (k, 3), heart frame, mm.
    """
    if anatomy.realistic:
        return _la_contours_realistic(anatomy, motion, spec, f, n_side, with_rv, with_lv=with_lv)
    out: dict[str, np.ndarray] = {}
    lam = float(motion.lam(f))
    u = np.array([np.cos(spec.azimuth), np.sin(spec.azimuth), 0.0])
    for name, a, c, zc in (("lv_endo", anatomy.r_short_endo, anatomy.r_long_endo, anatomy.z_center),
                           ("lv_epi", anatomy.r_short_epi, anatomy.r_long_epi, anatomy.z_center)):
        mu_b = np.arccos(-(anatomy.z_base - zc) / c)
        mu = np.linspace(0.0, mu_b, n_side)
        z = zc - c * np.cos(mu)
        s = (a * np.sin(mu)) ** 2
        w_pos = np.sqrt(motion.radial_map(anatomy, s, _la_side(motion, spec.azimuth, z, f), z, f))
        w_neg = -np.sqrt(motion.radial_map(anatomy, s, _la_side(motion, spec.azimuth + np.pi, z, f), z, f))
        w = np.r_[w_pos[::-1], w_neg[1:]]
        zz = lam * np.r_[z[::-1], z[1:]]
        out[name] = w[:, None] * u[None, :] + zz[:, None] * np.array([0.0, 0.0, 1.0])
    if with_rv:
        for name, epi in (("rv_endo", False), ("rv_epi", True)):
            pts = _la_rv(anatomy, motion, spec.azimuth, f, epi, n_side)
            if pts is not None:
                out[name] = pts
    return out


def _la_rv(anatomy: Anatomy, motion: Motion, alpha: float, f: float, epi: bool, n_side: int):
    """Open RV contour in an LA plane: free wall from the annulus to the RV apex, back along the septum."""
    lam = float(motion.lam(f))
    z_top = anatomy.z_base
    c = anatomy.r_long_rv_endo + (anatomy.rv_wall if epi else 0.0)

    def width(z):
        th = _la_side(motion, alpha, z, f)
        return anatomy.s_rv(th, z, epi) - anatomy.s_lv_epi(z)

    if float(width(np.array(z_top))) <= MIN_RV_WIDTH_MM ** 2:
        return None
    lo, hi = z_top - c, z_top
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if float(width(np.array(mid))) > 0:
            hi = mid
        else:
            lo = mid
    z = np.linspace(z_top, hi, n_side)
    th = _la_side(motion, alpha, z, f)
    free = np.sqrt(motion.radial_map(anatomy, anatomy.s_rv(th, z, epi), th, z, f))
    zs = z[::-1][1:]
    ths = _la_side(motion, alpha, zs, f)
    sept = np.sqrt(motion.radial_map(anatomy, anatomy.s_lv_epi(zs), ths, zs, f))
    w = np.r_[free, sept]
    zz = lam * np.r_[z, zs]
    u = np.array([np.cos(alpha), np.sin(alpha), 0.0])
    return w[:, None] * u[None, :] + zz[:, None] * np.array([0.0, 0.0, 1.0])


# ----------------------------------------------------------------- landmarks
def landmarks(anatomy: Anatomy, motion: Motion, f: float, n_mitral: int = 6,
              outflow: bool = True) -> dict[str, np.ndarray]:
    """Apex (LV epicardial apex), mitral annulus (on the LV endocardium in the base plane) and
    tricuspid annulus points (4 on the RV free wall, 2 on the septum; realistic: at the annulus
    height of each angle, :meth:`Anatomy.z_top_rv`) at phase f, heart frame; with outflow tracts
    also their valves' (:func:`outflow_landmarks`) unless ``outflow`` is False.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_mitral : int, optional
        Mitral annulus points.
    outflow : bool, optional
        Add the outflow valves' points.
    Returns
    -------
    dict of str to ndarray
        ``apex`` (1, 3), ``mitral``, ``tricuspid`` (and ``pulmonary``, ``aortic``) points (k, 3), mm.
    """
    zb = anatomy.z_base
    th = np.linspace(0.0, 2 * np.pi, n_mitral, endpoint=False)
    if anatomy.realistic:
        # the saddle annulus: twelve points, on the endocardium at the annulus height of each angle
        th = np.linspace(0.0, 2 * np.pi, 2 * n_mitral, endpoint=False)
        zt = anatomy.z_top(th)
        lo, hi = (float(v[0]) for v in anatomy.rv_sector(zb))
        tf = lo + (hi - lo) * np.array([0.2, 0.4, 0.6, 0.8])
        ts = lo + (hi - lo) * np.array([0.65, 0.35])
        if anatomy.outflow is not None:
            # the tricuspid orifice is the part of the base crescent outside the RVOT window
            from cardionurbs.phantom.outflow import rvot_frame
            hi = float(rvot_frame(anatomy).window(zb)[0])
            tf = lo + (hi - lo) * np.array([0.15, 0.4, 0.65, 0.9])
            ts = lo + (hi - lo) * np.array([0.7, 0.3])
        # on the annulus: the top of the RV walls at each angle (z_b where it is planar)
        zf, zs = anatomy.z_top_rv(tf), anatomy.z_top_rv(ts)
        tri = np.r_[_polar(anatomy.s_rv(tf, zf), tf, zf), _polar(anatomy.s_lv_epi(zs, ts), ts, zs)]
        mitral = np.column_stack([_polar(anatomy.s_lv_endo(zt, th), th, 0.0)[:, :2], zt])
        out = {"apex": motion.forward(anatomy, np.zeros((1, 3)), f),
               "mitral": motion.forward(anatomy, mitral, f),
               "tricuspid": motion.forward(anatomy, tri, f)}
        if anatomy.outflow is not None and outflow:
            out.update(outflow_landmarks(anatomy, motion, f))
        return out
    mitral_mat = _polar(np.full(n_mitral, float(anatomy.s_lv_endo(zb))), th, zb)
    edge = float(anatomy.rv_sector_edge(zb)[0])
    tf = edge * np.array([-0.6, -0.2, 0.2, 0.6])
    ts = edge * np.array([0.3, -0.3])
    tri_mat = np.r_[_polar(anatomy.s_rv(tf, zb), tf, zb), _polar(np.full(2, float(anatomy.s_lv_epi(zb))), ts, zb)]
    return {"apex": motion.forward(anatomy, np.zeros((1, 3)), f),
            "mitral": motion.forward(anatomy, mitral_mat, f),
            "tricuspid": motion.forward(anatomy, tri_mat, f)}


def outflow_landmarks(anatomy: Anatomy, motion: Motion, f: float, n_ring: int = 6) -> dict[str, np.ndarray]:
    """``pulmonary`` and ``aortic`` annulus points at phase f (motion frame): first the two points
    where the RVOT view (``la_rvot``), resp. the 3-chamber view, cuts the annulus, then ``n_ring``
    points evenly spaced around it (docs/phantoms.md). A view planned at ED can miss its annulus
    at another phase (the annulus moved out of the fixed plane, e.g. with a large basal
    rotation at ES): an annotator sees no valve there, so that annulus has no landmark at f.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    n_ring : int, optional
        Points evenly spaced around each annulus.

    Returns
    -------
    dict of str to ndarray
        ``pulmonary`` and ``aortic`` -> points (2 + n_ring, 3), mm; an annulus its view does
        not cut twice at f is left out.
    """
    from cardionurbs.phantom.geometry import la_plane
    out = {}
    for name, view in (("pulmonary", "la_rvot"), ("aortic", "la_3ch")):
        spec = la_plane(anatomy, view)
        ring = annulus_ring(anatomy, motion, f, name)
        cut = polyline_crossings(ring, spec.normal, float(spec.center @ spec.normal), closed=True)
        if len(cut) != 2:       # the view misses the annulus at this phase: no valve to click
            continue
        idx = np.round(np.linspace(0, len(ring), n_ring, endpoint=False)).astype(int)
        out[name] = unbend(anatomy, np.r_[cut, ring[idx]])
    return out


def annulus_ring(anatomy: Anatomy, motion: Motion, f: float, name: str) -> np.ndarray:
    """The pulmonary or aortic annulus at phase f as a closed polyline, bent heart frame.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        A realistic anatomy with outflow tracts (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    name : str
        ``"pulmonary"`` (97 points) or ``"aortic"`` (192 points).

    Returns
    -------
    ndarray
        (n, 3) points, mm, in the bent frame (:func:`bend`).
    """
    from cardionurbs.phantom import outflow as ofl
    ring_mat = (ofl.pulmonary_ring(anatomy, 97) if name == "pulmonary"
                else ofl.aortic_ring(anatomy, 192))
    return bend(anatomy, motion.forward(anatomy, ring_mat, f))


def rv_insertion_points(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float):
    """The two RV insertion points (RV epicardium meets LV epicardium) on an SA plane, or None.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    spec : cardionurbs.phantom.geometry.SliceSpec
        The slice.
    f : float
        The cycle phase (0 at ED, 1 at ES).

    Returns
    -------
    ndarray, shape (2, 3) or None
        The two insertion points, heart frame at phase f, mm; None where
        the plane shows no RV.
    """
    z = sa_material_height(motion, spec, f)
    if anatomy.realistic:
        if not (0.0 < z <= anatomy.z_top_rv_min - BASE_MARGIN_MM):
            return None
        sector = _contoured_crescent(anatomy, z, epi=True)
        if sector is None:
            return None
        th = np.array(sector[::-1])
        return motion.forward(anatomy, _polar(anatomy.s_lv_epi(np.full(2, z), th), th, z), f)
    if not (0.0 < z <= anatomy.z_base - BASE_MARGIN_MM):
        return None
    if np.sqrt(float(anatomy.s_rv(0.0, z, True))) - np.sqrt(float(anatomy.s_lv_epi(z))) < MIN_RV_WIDTH_MM:
        return None
    edge = float(anatomy.rv_sector_edge(z, epi=True)[0])
    th = np.array([edge, -edge])
    mat = _polar(np.full(2, float(anatomy.s_lv_epi(z))), th, z)
    return motion.forward(anatomy, mat, f)


# ----------------------------------------------------------------- tags
def _segments(c: float, s_in: float, s_out: float) -> list[tuple[float, float]]:
    """w-intervals of the line {c n + w n⊥} inside the annulus s_in ≤ s ≤ s_out."""
    if s_out <= c * c:
        return []
    wo = np.sqrt(s_out - c * c)
    if s_in <= c * c:
        return [(-wo, wo)]
    wi = np.sqrt(s_in - c * c)
    return [(-wo, -wi), (wi, wo)]


def _sample_segments(segs, step: float) -> np.ndarray:
    parts = []
    for a, b in segs:
        n = max(int(np.ceil((b - a) / step)) + 1, 2)
        parts.append(np.linspace(a, b, n))
    return np.concatenate(parts) if parts else np.empty(0)


def _inside_runs(inside: np.ndarray, w: np.ndarray) -> list[tuple[float, float]]:
    """(w_start, w_end) of each run of at least two consecutive True samples."""
    idx = np.flatnonzero(inside)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if len(idx) else []
    return [(w[r[0]], w[r[-1]]) for r in runs if len(r) >= 2]


def _move_lines(anatomy: Anatomy, motion: Motion, keys: list, mats: list, f: float) -> list:
    """(family, index, points at phase f) of material tag lines, moved in one call."""
    if not mats:
        return []
    moved = motion.forward(anatomy, np.concatenate(mats), f)
    cuts = np.cumsum([len(m) for m in mats])[:-1]
    return [(fam, i, pts) for (fam, i), pts in zip(keys, np.split(moved, cuts))]


def _sa_line(c: float, n: np.ndarray, segs, step: float, z: float) -> np.ndarray:
    """Material points of the tag line {c n + w n⊥} in section z over the w-intervals ``segs``."""
    w = _sample_segments(segs, step)
    mat = c * n[None, :] + w[:, None] * np.array([-n[1], n[0], 0.0])[None, :]
    mat[:, 2] = z
    return mat


def sa_tag_lines(anatomy: Anatomy, motion: Motion, grid: TagGrid, spec: SliceSpec, f: float,
                 step: float) -> list[tuple[str, int, np.ndarray]]:
    """(family, index, points) of the SA tag lines on one SA plane at phase f, clipped to the LV wall.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : TagGrid
        The tag pattern at ED.
    spec : cardionurbs.phantom.geometry.SliceSpec
        The slice.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    step : float
        Point spacing along the lines, mm.
    Returns
    -------
    list of tuple of (str, int, ndarray)
        (``"sa1"`` | ``"sa2"``, tag index, points (k, 3) in mm) per line piece.
    """
    z = sa_material_height(motion, spec, f)
    if anatomy.realistic:
        return _sa_tag_lines_realistic(anatomy, motion, grid, spec, f, z, step)
    if not (0.0 < z <= anatomy.z_base - BASE_MARGIN_MM):
        return []
    s1, s2 = float(anatomy.s_lv_endo(z)), float(anatomy.s_lv_epi(z))
    if s2 < MIN_RADIUS_MM ** 2:
        return []
    keys, mats = [], []
    for fam in ("sa1", "sa2"):
        n = grid.sa_normal(fam)
        for i, c in enumerate(grid.sa_positions()):
            segs = _segments(float(c), s1, s2)
            if segs:
                keys.append((fam, i))
                mats.append(_sa_line(float(c), n, segs, step, z))
    return _move_lines(anatomy, motion, keys, mats, f)


def _sa_tag_lines_realistic(anatomy: Anatomy, motion: Motion, grid: TagGrid, spec: SliceSpec, f: float,
                            z: float, step: float) -> list[tuple[str, int, np.ndarray]]:
    """SA tag lines of a realistic anatomy. The tag planes are planes of the (bent) ED heart,
    n · X = c; with the bend X = x + d(z) the material line in section z is n · x = c − n · d(z).
    Each line is sampled every step/8, clipped to S_endo(θ) ≤ s ≤ S_epi(θ), and each run is
    resampled about once per ``step``."""
    if not (0.0 < z <= anatomy.z_top_min - BASE_MARGIN_MM):
        return []
    th_all = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    s1_all, s2_all = anatomy.lv_sections(np.full(len(th_all), z), th_all)
    s2max = float(s2_all.max())
    if s2_all.mean() < MIN_RADIUS_MM ** 2:
        return []
    reach = np.sqrt(s2max) + 1.0
    wf = np.arange(-reach, reach + step / 8.0, step / 8.0)
    d = anatomy.shape.apex_shift(z, anatomy.z_base)[0] if anatomy.shape.bends else np.zeros(2)
    lines = [(fam, i, float(c) - float(grid.sa_normal(fam)[:2] @ d))
             for fam in ("sa1", "sa2") for i, c in enumerate(grid.sa_positions())]
    nrm = np.array([grid.sa_normal(fam) for fam, _, _ in lines])
    ce = np.array([c for _, _, c in lines])[:, None]
    x = ce * nrm[:, :1] - wf[None, :] * nrm[:, 1:2]
    y = ce * nrm[:, 1:2] + wf[None, :] * nrm[:, :1]
    s, th = x * x + y * y, np.arctan2(y, x)
    # the wall only where s can reach it: between the section's least endocardial and largest
    # epicardial S sampled every degree, widened by 5 % (their variation between the samples is
    # far below that), the exact test there
    near = np.flatnonzero(((s >= 0.95 * float(s1_all.min())) & (s <= 1.05 * s2max)).ravel())
    s_endo, s_epi = anatomy.lv_sections(np.full(len(near), z), th.ravel()[near])
    inside = np.zeros(s.shape, dtype=bool)
    inside.ravel()[near] = (s.ravel()[near] >= s_endo) & (s.ravel()[near] <= s_epi)
    keys, mats = [], []
    for k in np.flatnonzero(inside.sum(axis=1) >= 2):
        fam, i, c = lines[k]
        segs = _inside_runs(inside[k], wf)
        if segs:
            keys.append((fam, i))
            mats.append(_sa_line(c, grid.sa_normal(fam), segs, step, z))
    return _move_lines(anatomy, motion, keys, mats, f)


def la_tag_lines(anatomy: Anatomy, motion: Motion, grid: TagGrid, spec: SliceSpec, f: float,
                 step: float) -> list[tuple[str, int, np.ndarray]]:
    """(``"la"``, index, points) of the LA tag lines on one LA plane at phase f, clipped to the LV wall.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy (heart frame, mm).
    motion : cardionurbs.phantom.motion.Motion
        The motion.
    grid : TagGrid
        The tag pattern at ED.
    spec : cardionurbs.phantom.geometry.SliceSpec
        The slice.
    f : float
        The cycle phase (0 at ED, 1 at ES).
    step : float
        Point spacing along the lines, mm.
    Returns
    -------
    list of tuple of (str, int, ndarray)
        (``"la"``, tag index, points (k, 3) in mm) per line piece.
    """
    if anatomy.realistic:
        return _la_tag_lines_realistic(anatomy, motion, grid, spec, f, step)
    alpha = spec.azimuth
    u = np.array([np.cos(alpha), np.sin(alpha), 0.0])
    rs, ths, zs, signs, owners = [], [], [], [], []
    levels = grid.la_positions(anatomy.z_base - BASE_MARGIN_MM)
    psi = motion.psi(levels, f)
    s1_all, s2_all = anatomy.s_lv_endo(levels), anatomy.s_lv_epi(levels)
    for j, zj in enumerate(levels):
        s1, s2 = float(s1_all[j]), float(s2_all[j])
        if s2 < MIN_RADIUS_MM ** 2:
            continue
        for side, sign in ((alpha + np.pi, -1.0), (alpha, 1.0)):
            segs = [(np.sqrt(s1), np.sqrt(s2))] if s1 > 0 else [(0.0, np.sqrt(s2))]
            r = _sample_segments(segs, step)
            if s1 <= 0 and sign < 0:
                r = r[r > 0]
            r = r[::-1] if sign < 0 else r          # order along the line: −epi → −endo, endo → epi
            rs.append(r)
            ths.append(np.full(len(r), side + float(psi[j])))
            zs.append(np.full(len(r), zj))
            signs.append(np.full(len(r), sign))
            owners.append(np.full(len(r), j))
    if not rs:
        return []
    r, th, z, sign, owner = map(np.concatenate, (rs, ths, zs, signs, owners))
    w = sign * np.sqrt(motion.radial_map(anatomy, r * r, th, z, f))
    pts = w[:, None] * u[None, :]
    pts[:, 2] = motion.lam(f) * z
    cuts = np.flatnonzero(np.diff(owner)) + 1
    return [("la", int(o[0]), p) for o, p in zip(np.split(owner, cuts), np.split(pts, cuts))]
