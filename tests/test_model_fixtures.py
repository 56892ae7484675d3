"""An analytic biventricular heart made of truncated ellipsoids, as a Study.

Used by the model / metrics / cohort tests (no phantom module needed):

* LV endocardium and epicardium: prolate ellipsoids about the long axis (z),
  apex at z = −c, cut by the base plane z = z_b (the mitral valve plane).
* RV endocardium: an ellipsoid beside the LV, minus the LV epicardial solid;
  RV epicardium: a larger ellipsoid minus the LV epicardial solid.
* SA slices 10 mm apart; 2- and 4-chamber LA contours; apex, mitral and
  tricuspid landmarks; everything rotated and moved into a scanner frame.

Truth volumes: exact formulas for the LV; the RV from manifold3d booleans of
finely tessellated ellipsoids (independent of the NURBS models).
"""

from __future__ import annotations

from dataclasses import dataclass

import manifold3d
import numpy as np

from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.study import Contour, Landmark, Study

PIXEL = 1.25
ROT = np.array([[0.8, 0.0, 0.6], [0.36, 0.8, -0.48], [-0.48, 0.6, 0.64]])   # orthonormal
OFFSET = np.array([12.0, -30.0, 55.0])


@dataclass
class Ellipsoid:
    centre: tuple[float, float, float]
    radii: tuple[float, float, float]

    def ring(self, z: float, n: int = 720) -> np.ndarray | None:
        """Cross-section at height z: (n, 3) points, or None when z misses it."""
        cx, cy, cz = self.centre
        a, b, c = self.radii
        f = 1 - ((z - cz) / c) ** 2
        if f <= 0:
            return None
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        return np.column_stack([cx + a * np.sqrt(f) * np.cos(t), cy + b * np.sqrt(f) * np.sin(t),
                                np.full(n, z)])

    def inside(self, p: np.ndarray) -> np.ndarray:
        q = (p - np.array(self.centre)) / np.array(self.radii)
        return (q ** 2).sum(axis=1) < 1

    def cut_volume_ml(self, zb: float) -> float:
        """Volume below z = zb (mL), exact for an axis-aligned ellipsoid."""
        a, b, c = self.radii
        lo = -c
        hi = min(zb - self.centre[2], c)
        return float(np.pi * a * b * ((hi - lo) - (hi ** 3 - lo ** 3) / (3 * c * c)) / 1000.0)

    def manifold(self, n: int = 256) -> manifold3d.Manifold:
        return (manifold3d.Manifold.sphere(1.0, n).scale(self.radii).translate(self.centre))


def crescent(outer: np.ndarray, hole: Ellipsoid) -> np.ndarray | None:
    """Boundary of (outer ring's disk) − (hole's disk) at the ring's height, ordered."""
    z = outer[0, 2]
    inner = hole.ring(z, len(outer))
    out_mask = ~hole.inside(outer)
    if out_mask.all():
        return outer
    if not out_mask.any():
        return None
    k = int(np.argmax(~out_mask))         # roll so the outside arc is contiguous
    o = np.roll(outer, -k, axis=0)
    om = np.roll(out_mask, -k)
    arc = o[om]
    in_mask = _inside_ring(inner, outer)
    k2 = int(np.argmax(~in_mask))
    i = np.roll(inner, -k2, axis=0)
    im = np.roll(in_mask, -k2)
    arc2 = i[im]
    # join: outer arc (ccw) then inner arc run backwards
    if np.linalg.norm(arc2[-1] - arc[-1]) < np.linalg.norm(arc2[0] - arc[-1]):
        arc2 = arc2[::-1]
    return np.vstack([arc, arc2])


def _inside_ring(p: np.ndarray, ring: np.ndarray) -> np.ndarray:
    from matplotlib.path import Path
    return Path(ring[:, :2]).contains_points(p[:, :2])


@dataclass
class AnalyticHeart:
    lv_endo: Ellipsoid
    lv_epi: Ellipsoid
    rv_endo: Ellipsoid
    rv_epi: Ellipsoid
    zb: float


def heart(scale: float = 1.0, zb: float = 8.0) -> AnalyticHeart:
    """An analytic heart; ``scale`` < 1 contracts the cavities (systole)."""
    s = scale
    return AnalyticHeart(
        lv_endo=Ellipsoid((0, 0, 0), (25 * s, 22 * s, 62 * (0.85 + 0.15 * s))),
        lv_epi=Ellipsoid((0, 0, 0), (25 * s + 9, 22 * s + 9, 62 * (0.85 + 0.15 * s) + 8)),
        rv_endo=Ellipsoid((30, 0, 0), (28 * s, 36 * s, 58 * (0.85 + 0.15 * s))),
        rv_epi=Ellipsoid((30, 0, 0), (28 * s + 4, 36 * s + 4, 58 * (0.85 + 0.15 * s) + 4)),
        zb=zb)


def truth_volumes(h: AnalyticHeart) -> dict[str, float]:
    """Volumes (mL): LV exact; RV by manifold3d booleans of fine ellipsoids."""
    lv_cav = h.lv_endo.cut_volume_ml(h.zb)
    lv_myo = h.lv_epi.cut_volume_ml(h.zb) - lv_cav
    below = manifold3d.Manifold.cube((400, 400, 400), True).translate((0, 0, h.zb - 200))
    epi = h.lv_epi.manifold()
    rv_cav = ((h.rv_endo.manifold() - epi) ^ below).volume() / 1000.0
    rv_all = ((h.rv_epi.manifold() - epi) ^ below).volume() / 1000.0
    return {"lv_cavity": lv_cav, "lv_myocardium": lv_myo, "rv_cavity": rv_cav,
            "rv_myocardium": rv_all - rv_cav}


def to_scanner(p: np.ndarray) -> np.ndarray:
    return p @ ROT.T + OFFSET


def la_curve(e: Ellipsoid, axis: int, zb: float, hole: Ellipsoid | None = None,
             n: int = 400) -> np.ndarray:
    """Open LA contour of an ellipsoid in the plane through the z axis along
    ``axis`` (0: x, 4-chamber; 1: y, 2-chamber), from base over the apex to base."""
    a = e.radii[axis]
    c = e.radii[2]
    t0 = np.arcsin(np.clip((zb - e.centre[2]) / c, -1, 1))
    ang = np.linspace(t0, -np.pi - t0, n)      # from one base point over the apex
    p = np.zeros((n, 3))
    p[:, axis] = e.centre[axis] + a * np.cos(ang)
    p[:, 2] = e.centre[2] + c * np.sin(ang)
    if hole is not None:
        p = p[~hole.inside(p)]
    return p


def study_from_hearts(hearts: list[AnalyticHeart], *, spacing: float = 10.0, la: bool = True,
                      rv: bool = True, landmarks: bool = True, noise_px: float = 0.0,
                      seed: int = 0, subject: str = "ellipsoids") -> Study:
    """A Study with SA (and LA) contours of the analytic hearts, one frame each."""
    rng = np.random.default_rng(seed)
    st = Study(subject=subject, heart_rate_bpm=60.0)
    h0 = hearts[0]
    levels = np.arange(h0.zb - 4.0, -h0.lv_epi.radii[2] + 4.0, -spacing)
    e_x, e_y, e_z = ROT[:, 0], ROT[:, 1], ROT[:, 2]
    for fr, h in enumerate(hearts):
        st.frame_times_ms[fr] = 400.0 * fr
        for k, z in enumerate(levels):
            sl = f"sa_{k:02d}"
            pos = to_scanner(np.array([-160.0, -160.0, z]))
            im = ImagePlane(id=f"{sl}_f{fr}", slice=sl, view="SA", frame=fr, position=pos,
                            row_cosine=e_x, column_cosine=e_y, pixel_spacing=(PIXEL, PIXEL),
                            thickness=8.0)
            st.images.append(im)
            rings = {"lv_endo": h.lv_endo.ring(z, 160), "lv_epi": h.lv_epi.ring(z, 160)}
            if rv:
                rv_r = h.rv_endo.ring(z, 720)
                rvp_r = h.rv_epi.ring(z, 720)
                rings["rv_endo"] = crescent(rv_r, h.lv_epi) if rv_r is not None else None
                rings["rv_epi"] = crescent(rvp_r, h.lv_epi) if rvp_r is not None else None
                for s in ("rv_endo", "rv_epi"):
                    if rings[s] is not None:
                        rings[s] = rings[s][:: max(1, len(rings[s]) // 160)]
            for s, r in rings.items():
                if r is None or len(r) < 8:
                    continue
                if noise_px:
                    r = r + np.column_stack([rng.normal(0, noise_px * PIXEL, (len(r), 2)),
                                             np.zeros(len(r))])
                st.contours.append(Contour(s, "SA", sl, fr, to_scanner(r), image=im.id))
        if la:
            for sl, axis, ori in (("la_4ch", 0, (e_x, -e_z)), ("la_2ch", 1, (e_y, -e_z))):
                pos = to_scanner(np.array([0.0, 0.0, 0.0]) - 150 * (axis == 0) * np.array([1, 0, 0])
                                 - 150 * (axis == 1) * np.array([0, 1, 0]) + np.array([0, 0, 60.0]))
                im = ImagePlane(id=f"{sl}_f{fr}", slice=sl, view="LA", frame=fr, position=pos,
                                row_cosine=ori[0], column_cosine=ori[1], pixel_spacing=(PIXEL, PIXEL),
                                thickness=8.0)
                st.images.append(im)
                curves = {"lv_endo": la_curve(h.lv_endo, axis, h.zb),
                          "lv_epi": la_curve(h.lv_epi, axis, h.zb)}
                if rv and axis == 0:
                    rve = la_curve(h.rv_endo, axis, h.zb, hole=h.lv_epi)
                    curves["rv_endo"] = rve[rve[:, 0] > 0]
                    rvp = la_curve(h.rv_epi, axis, h.zb, hole=h.lv_epi)
                    curves["rv_epi"] = rvp[rvp[:, 0] > 0]
                for s, cpts in curves.items():
                    if noise_px:
                        cpts = cpts + rng.normal(0, noise_px * PIXEL, cpts.shape) * \
                            np.array([axis == 0, axis == 1, 1.0])
                    st.contours.append(Contour(s, "LA", sl, fr, to_scanner(cpts), image=im.id,
                                               closed=False))
        if landmarks:
            st.landmarks.append(Landmark("apex", fr, to_scanner(np.array([0, 0, -h.lv_epi.radii[2]]))))
            ring = h.lv_endo.ring(h.zb, 6)
            for i, p in enumerate(ring):
                st.landmarks.append(Landmark("mitral", fr, to_scanner(p), index=i))
            if rv:
                rr = h.rv_endo.ring(h.zb, 12)
                rr = rr[~h.lv_epi.inside(rr)]
                for i, p in enumerate(rr):
                    st.landmarks.append(Landmark("tricuspid", fr, to_scanner(p), index=i))
    return st
