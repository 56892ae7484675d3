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

from cardionurbs.phantom.anatomy import Anatomy
from cardionurbs.phantom.geometry import SliceSpec
from cardionurbs.phantom.motion import Motion

MIN_RADIUS_MM = 2.0      # sections smaller than this are not contoured
MIN_RV_WIDTH_MM = 1.5    # RV crescents thinner than this (at θ = 0) are not contoured
BASE_MARGIN_MM = 1.0     # SA planes must cut tissue at least this far below the base


@dataclass(frozen=True)
class TagGrid:
    """The ED tag pattern: spacing (mm), SA family angles (rad, about e_z), first plane offsets."""

    spacing: float
    sa_angle: float          # angle of the sa1 plane normal from e_x; sa2 is +90°
    n_half: int              # SA tag indices run 0 .. 2 n_half, index n_half nearest the axis
    sa_offset: float         # c_i = (i − n_half) d + sa_offset
    la_offset: float         # z_j = la_offset + j d

    def sa_normal(self, family: str) -> np.ndarray:
        a = self.sa_angle + (0.0 if family == "sa1" else 0.5 * np.pi)
        return np.array([np.cos(a), np.sin(a), 0.0])

    def sa_positions(self) -> np.ndarray:
        return (np.arange(2 * self.n_half + 1) - self.n_half) * self.spacing + self.sa_offset

    def la_positions(self, z_max: float) -> np.ndarray:
        n = int(np.floor((z_max - self.la_offset) / self.spacing)) + 1
        return self.la_offset + self.spacing * np.arange(max(n, 0))

    def to_dict(self) -> dict:
        return {"spacing_mm": self.spacing, "sa1_normal_angle_deg": float(np.degrees(self.sa_angle)),
                "sa_first_index_position_mm": float(self.sa_positions()[0]),
                "n_sa_tags": int(2 * self.n_half + 1), "la_first_plane_mm": self.la_offset}


def make_tag_grid(anatomy: Anatomy, spacing: float, sa_angle_deg: float = 45.0) -> TagGrid:
    """Tag planes covering the heart: SA indices symmetric about the axis, LA from the apex."""
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
    return float(spec.height / motion.lam(f))


def sa_contours(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float,
                n_lv: int = 60, n_rv_free: int = 32, n_rv_septum: int = 16) -> dict[str, np.ndarray]:
    """Closed SA contours (heart frame at phase f) of one SA plane: lv_endo, lv_epi, rv_endo, rv_epi."""
    z = sa_material_height(motion, spec, f)
    out: dict[str, np.ndarray] = {}
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


def _la_side(motion: Motion, alpha: float, z: np.ndarray, f: float):
    """Material angle of the ray α at material heights z (LA plane) at phase f."""
    return alpha + motion.psi(z, f)


def la_contours(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float, n_side: int = 30,
                with_rv: bool = False) -> dict[str, np.ndarray]:
    """Open LA contours (annulus → apex → annulus) in an LA plane at phase f (heart frame)."""
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
def landmarks(anatomy: Anatomy, motion: Motion, f: float, n_mitral: int = 6) -> dict[str, np.ndarray]:
    """Apex (LV epicardial apex), mitral annulus (on the LV endocardium in the base plane) and
    tricuspid annulus points (4 on the RV free wall, 2 on the septum) at phase f, heart frame."""
    zb = anatomy.z_base
    th = np.linspace(0.0, 2 * np.pi, n_mitral, endpoint=False)
    mitral_mat = _polar(np.full(n_mitral, float(anatomy.s_lv_endo(zb))), th, zb)
    edge = float(anatomy.rv_sector_edge(zb)[0])
    tf = edge * np.array([-0.6, -0.2, 0.2, 0.6])
    ts = edge * np.array([0.3, -0.3])
    tri_mat = np.r_[_polar(anatomy.s_rv(tf, zb), tf, zb), _polar(np.full(2, float(anatomy.s_lv_epi(zb))), ts, zb)]
    return {"apex": motion.forward(anatomy, np.zeros((1, 3)), f),
            "mitral": motion.forward(anatomy, mitral_mat, f),
            "tricuspid": motion.forward(anatomy, tri_mat, f)}


def rv_insertion_points(anatomy: Anatomy, motion: Motion, spec: SliceSpec, f: float):
    """The two RV insertion points (RV epicardium meets LV epicardium) on an SA plane, or None."""
    z = sa_material_height(motion, spec, f)
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


def sa_tag_lines(anatomy: Anatomy, motion: Motion, grid: TagGrid, spec: SliceSpec, f: float,
                 step: float) -> list[tuple[str, int, np.ndarray]]:
    """(family, index, points) of the SA tag lines on one SA plane at phase f, clipped to the LV wall."""
    z = sa_material_height(motion, spec, f)
    if not (0.0 < z <= anatomy.z_base - BASE_MARGIN_MM):
        return []
    s1, s2 = float(anatomy.s_lv_endo(z)), float(anatomy.s_lv_epi(z))
    if s2 < MIN_RADIUS_MM ** 2:
        return []
    keys, mats = [], []
    for fam in ("sa1", "sa2"):
        n = grid.sa_normal(fam)
        t = np.array([-n[1], n[0], 0.0])
        for i, c in enumerate(grid.sa_positions()):
            segs = _segments(float(c), s1, s2)
            if not segs:
                continue
            w = _sample_segments(segs, step)
            mat = c * n[None, :] + w[:, None] * t[None, :]
            mat[:, 2] = z
            keys.append((fam, i))
            mats.append(mat)
    if not mats:
        return []
    moved = motion.forward(anatomy, np.concatenate(mats), f)
    cuts = np.cumsum([len(m) for m in mats])[:-1]
    return [(fam, i, pts) for (fam, i), pts in zip(keys, np.split(moved, cuts))]


def la_tag_lines(anatomy: Anatomy, motion: Motion, grid: TagGrid, spec: SliceSpec, f: float,
                 step: float) -> list[tuple[str, int, np.ndarray]]:
    """(``"la"``, index, points) of the LA tag lines on one LA plane at phase f, clipped to the LV wall."""
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
