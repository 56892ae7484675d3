"""Tag analysis on a small analytic tagged heart with a known motion.

The heart is a thick-walled cylinder (LV wall, endo 22 mm, epi 32 mm) whose
long axis is oblique in the scanner. The ED → ES map in local cylindrical
coordinates (R, Θ, Z), Z from the apex (0) toward the base, is

    Z' = (1 − s) Z                       (longitudinal shortening s, apex fixed)
    Θ' = Θ − φ(Z)                         (φ CCW positive seen from the apex)
    R'² = R² − c                          (radial thickening, c = 22² − 16²)

Tag planes are laid at ED: sa1 x = i·sp, sa2 y = j·sp, la Z = k·sp. The
lines each image shows at ES are the tissue of those planes that the map
brings into the fixed image plane, so through-plane motion is real. Truth:
level rotation φ(Z_k), LS = 100 s, Twist 2D = φ(z_apical/(1−s)) −
φ(z_basal/(1−s)).
"""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.study import Contour, Landmark, Study, TagLine

PX = 1.25               # pixel size, mm
SP = 7 * PX             # tag spacing, mm
R_ENDO, R_EPI = 22.0, 32.0
C_THICK = R_ENDO ** 2 - 16.0 ** 2
SLICES_Z = [80.0 - 9.0 * s for s in range(7)]          # sa_00 (base) ... sa_06 (apex)
VIEWS = {"la_2ch": 0.0, "la_3ch": 60.0, "la_4ch": 120.0}
SA_INDICES = range(-3, 4)
LA_INDICES = range(1, 11)


def phi_deg(Z, a=9.0, b=-0.22, c=0.0006):
    """Rotation ED -> ES (deg, CCW seen from the apex) of tissue at height Z (mm)."""
    Z = np.asarray(Z, float)
    return a + b * Z + c * Z ** 2


def _rotation(alpha=0.5, beta=-0.7, gamma=0.3):
    ca, sa, cb, sb, cg, sg = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta), np.cos(gamma), np.sin(gamma)
    Rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rx = np.array([[1, 0, 0], [0, cg, -sg], [0, sg, cg]])
    return Rz @ Ry @ Rx


class AnalyticHeart:
    def __init__(self, shortening=0.15, origin=(12.0, -40.0, 25.0)):
        self.s = shortening
        self.R = _rotation()
        self.O = np.asarray(origin, float)

    # local <-> scanner
    def to_scanner(self, p):
        return np.asarray(p, float) @ self.R.T + self.O

    def forward(self, X):
        """ED local points (n, 3) -> ES local points."""
        x, y, Z = X[:, 0], X[:, 1], X[:, 2]
        R = np.hypot(x, y)
        th = np.arctan2(y, x) - np.radians(phi_deg(Z))
        R2 = np.sqrt(np.maximum(R ** 2 - C_THICK, 0.0))
        return np.column_stack([R2 * np.cos(th), R2 * np.sin(th), (1 - self.s) * Z])

    # ---------------------------------------------------------------- lines
    def sa_line(self, family, index, z_slice, frame):
        """Local points of an SA tag line in the slice z_slice at frame 0 (ED) or 1 (ES)."""
        c = index * SP
        Z = z_slice if frame == 0 else z_slice / (1 - self.s)
        t = np.arange(-R_EPI, R_EPI + 1e-9, PX * 0.9)
        r = np.hypot(c, t)
        t = t[(r >= R_ENDO) & (r <= R_EPI)]
        X = np.column_stack([np.full_like(t, c), t, np.full_like(t, Z)]) if family == "sa1" else \
            np.column_stack([t, np.full_like(t, c), np.full_like(t, Z)])
        return X if frame == 0 else self.forward(X)

    def la_line(self, index, psi_deg, frame):
        Z = index * SP
        r_in, r_out = (R_ENDO, R_EPI) if frame == 0 else (np.sqrt(R_ENDO ** 2 - C_THICK),
                                                          np.sqrt(R_EPI ** 2 - C_THICK))
        Zf = Z if frame == 0 else (1 - self.s) * Z
        r = np.arange(r_in, r_out + 1e-9, PX * 0.9)
        t = np.concatenate([-r[::-1], r])
        ps = np.radians(psi_deg)
        return np.column_stack([t * np.cos(ps), t * np.sin(ps), np.full_like(t, Zf)])

    # ---------------------------------------------------------------- study
    def study(self, noise_px=0.0, jumps=(), seed=0, frames=(0, 1), with_la=True,
              with_landmarks=True, with_contours=True) -> Study:
        rng = np.random.default_rng(seed)
        ex, ey, ez = self.R[:, 0], self.R[:, 1], self.R[:, 2]
        images, tags, contours, landmarks = [], [], [], []
        jumps = set(jumps)
        for f in frames:
            for s, z in enumerate(SLICES_Z):
                sid = f"sa_{s:02d}"
                pos = self.to_scanner([-128 * PX, -128 * PX, z])
                im = ImagePlane(f"{sid}_f{f}", sid, "SA", f, pos, ex, ey, (PX, PX))
                images.append(im)
                for fam in ("sa1", "sa2"):
                    for i in SA_INDICES:
                        j = i + 1 if (fam, i, sid, f) in jumps else i
                        P = self.to_scanner(self.sa_line(fam, j, z, f))
                        P = P + noise_px * PX * (rng.standard_normal((len(P), 1)) * ex
                                                 + rng.standard_normal((len(P), 1)) * ey)
                        tags.append(TagLine(fam, i, "SA", sid, f, P, image=im.id))
                if with_contours:
                    th = np.linspace(0, 2 * np.pi, 60, endpoint=False)
                    for name, r in (("lv_endo", R_ENDO), ("lv_epi", R_EPI)):
                        rr = r if f == 0 else np.sqrt(r ** 2 - C_THICK)
                        loc = np.column_stack([rr * np.cos(th), rr * np.sin(th), np.full_like(th, z)])
                        contours.append(Contour(name, "SA", sid, f, self.to_scanner(loc), image=im.id))
            if with_la:
                for vid, psi in VIEWS.items():
                    ps = np.radians(psi)
                    row = np.cos(ps) * ex + np.sin(ps) * ey
                    col = -ez
                    pos = self.to_scanner([0, 0, 110.0]) - 128 * PX * row
                    im = ImagePlane(f"{vid}_f{f}", vid, "LA", f, pos, row, col, (PX, PX))
                    images.append(im)
                    for k in LA_INDICES:
                        kk = k + 1 if ("la", k, vid, f) in jumps else k
                        P = self.to_scanner(self.la_line(kk, psi, f))
                        P = P + noise_px * PX * (rng.standard_normal((len(P), 1)) * row
                                                 + rng.standard_normal((len(P), 1)) * col)
                        tags.append(TagLine("la", k, "LA", vid, f, P, image=im.id))
            if with_landmarks:
                landmarks.append(Landmark("apex", f, self.to_scanner([0, 0, 0])))
                zb = 90.0 if f == 0 else 90.0 * (1 - self.s)
                for m, a in enumerate(np.linspace(0, 2 * np.pi, 6, endpoint=False)):
                    landmarks.append(Landmark("mitral", f, self.to_scanner(
                        [R_ENDO * np.cos(a), R_ENDO * np.sin(a), zb]), index=m))
        return Study("analytic", images=images, contours=contours, tags=tags,
                     landmarks=landmarks, ed_frame=0, es_frame=1)

    # ---------------------------------------------------------------- truth
    def levels(self):
        """LA indices whose plane lies strictly inside the SA stack at ED and ES."""
        zmin, zmax = min(SLICES_Z), max(SLICES_Z)
        out = []
        for k in LA_INDICES:
            Z = k * SP
            if zmin < Z < zmax and zmin < (1 - self.s) * Z < zmax:
                out.append(k)
        return out

    def truth(self):
        lv = self.levels()
        za, zb = lv[0] * SP, lv[-1] * SP
        twist = float(phi_deg(za) - phi_deg(zb))
        D = zb - za
        return {
            "levels": {k: float(phi_deg(k * SP)) for k in lv},
            "Twist (deg)": twist,
            "Torsion (deg/cm)": twist / (D / 10),
            "CL shear (deg)": twist * (2 * R_EPI) / (2 * D),
            "LS (%)": 100 * self.s,
            "Twist 2D (deg)": float(phi_deg(min(SLICES_Z) / (1 - self.s))
                                    - phi_deg(max(SLICES_Z) / (1 - self.s))),
            "distance": {k: k * SP for k in lv},
        }


@pytest.fixture(scope="module")
def heart():
    return AnalyticHeart()


@pytest.fixture(scope="module")
def clean_result(heart):
    from cardionurbs.analysis.tags import tag_metrics
    return tag_metrics(heart.study(), 0, 1)


# ------------------------------------------------------------------- tests
def test_tag_surfaces_cover_every_tag(heart):
    from cardionurbs.analysis.tags import tag_surfaces
    st = heart.study()
    surfs = tag_surfaces(st, 0)
    assert {k for k in surfs if k[0] == "sa1"} == {("sa1", i) for i in SA_INDICES}
    assert {k for k in surfs if k[0] == "la"} == {("la", k) for k in LA_INDICES}


def test_ed_tag_surfaces_are_the_tag_planes(heart):
    """At ED every tag surface lies in its tag plane (lofting coplanar curves stays in the plane)."""
    from cardionurbs.analysis.tags import tag_surfaces
    surfs = tag_surfaces(heart.study(), 0)
    t = np.linspace(0, 1, 15)
    inv = lambda P: (P - heart.O) @ heart.R  # noqa: E731  scanner -> local
    for (fam, idx), s in surfs.items():
        P = inv(np.asarray(s.evaluate(t, t)).reshape(-1, 3))
        coord = {"sa1": P[:, 0], "sa2": P[:, 1], "la": P[:, 2]}[fam]
        assert np.max(np.abs(coord - idx * SP)) < 0.05, (fam, idx)


def test_es_sa_surface_passes_through_tracked_tissue(heart):
    """An ES sa1 surface contains the ES image of tag-plane tissue between the slices."""
    from cardionurbs.analysis.tags import tag_surfaces
    from scipy.spatial import cKDTree
    surfs = tag_surfaces(heart.study(), 1)
    rng = np.random.default_rng(1)
    i = 1
    n = 200
    Z = rng.uniform(35, 88, n)
    rng.uniform(0, 2 * np.pi, n)                  # (keeps the draws that follow)
    y = rng.uniform(-30, 30, n)
    X = np.column_stack([np.full(n, i * SP), y, Z])
    R = np.hypot(X[:, 0], X[:, 1])
    X = X[(R > R_ENDO + 1) & (R < R_EPI - 1)]
    x_es = heart.to_scanner(heart.forward(X))
    inside = ((1 - heart.s) * X[:, 2] > min(SLICES_Z) + 1) & ((1 - heart.s) * X[:, 2] < max(SLICES_Z) - 1)
    t = np.linspace(0, 1, 400)
    grid = np.asarray(surfs[("sa1", i)].evaluate(t, t)).reshape(-1, 3)
    d, _ = cKDTree(grid).query(x_es[inside])
    assert np.median(d) < 0.15 and np.max(d) < 0.6


def test_material_points_track_the_same_tissue(heart):
    """ES material points = the analytic map applied to the ED material points."""
    from cardionurbs.analysis.tags import material_points
    mp = material_points(heart.study(), 0, 1)
    ok = mp.tracked(0, 1)
    assert ok.sum() > 80   # 6 levels x 16 grid nodes not within a pixel of the epicardium
    inv = lambda P: (P - heart.O) @ heart.R  # noqa: E731
    X0 = inv(mp.positions[0][ok])
    # ED points are the tag-plane grid nodes
    assert np.allclose(X0[:, 0], mp.triples[ok, 0] * SP, atol=0.05)
    assert np.allclose(X0[:, 1], mp.triples[ok, 1] * SP, atol=0.05)
    assert np.allclose(X0[:, 2], mp.triples[ok, 2] * SP, atol=0.05)
    X1 = inv(mp.positions[1][ok])
    err = np.linalg.norm(X1 - heart.forward(X0), axis=1)
    assert np.median(err) < 0.1 and err.max() < 0.5
    # inside the myocardium at ED
    R = np.hypot(X0[:, 0], X0[:, 1])
    assert np.all((R > R_ENDO - 1e-6) & (R < R_EPI + 1e-6))


def test_twist_torsion_ls_match_truth(heart, clean_result):
    cols = clean_result.columns
    tr = heart.truth()
    assert cols["Twist (deg)"] == pytest.approx(tr["Twist (deg)"], abs=0.3)
    assert cols["Torsion (deg/cm)"] == pytest.approx(tr["Torsion (deg/cm)"], abs=0.05)
    assert cols["CL shear (deg)"] == pytest.approx(tr["CL shear (deg)"], abs=0.3)
    assert cols["LS (%)"] == pytest.approx(tr["LS (%)"], abs=0.3)
    assert cols["Tag QC flags"] == 0


def test_level_table_matches_truth(heart, clean_result):
    tr = heart.truth()
    got = {lv["index"]: lv for lv in clean_result.levels}
    assert set(got) == set(tr["levels"])
    for k, phi in tr["levels"].items():
        assert got[k]["rotation_deg"] == pytest.approx(phi, abs=0.3)
        assert got[k]["distance_from_apex_mm"] == pytest.approx(tr["distance"][k], abs=0.1)
    assert [lv["in_twist"] for lv in clean_result.levels].count(True) == 2


def test_twist_2d_sees_through_plane_motion(heart, clean_result):
    tr = heart.truth()
    assert clean_result.columns["Twist 2D (deg)"] == pytest.approx(tr["Twist 2D (deg)"], abs=0.3)
    # and it differs from the 3D twist, which follows the tissue
    assert abs(tr["Twist 2D (deg)"] - tr["Twist (deg)"]) > 2


def test_rotation_sign_is_ccw_from_apex():
    """Positive rotation is CCW seen from the apex looking toward the base."""
    from cardionurbs.analysis.tags import rotation_deg
    apex, base = np.zeros(3), np.array([0.0, 0.0, 10.0])
    # seen from the apex (below, z < 0) looking up +z, CCW is clockwise about +z
    x0 = np.array([[1.0, 0.0, 5.0]])
    x1 = np.array([[np.cos(-0.1), np.sin(-0.1), 5.0]])
    assert rotation_deg(x0, x1, apex, base)[0] == pytest.approx(np.degrees(0.1))


def test_noise_half_pixel_within_one_degree(heart):
    from cardionurbs.analysis.tags import tag_metrics
    tr = heart.truth()
    cols = tag_metrics(heart.study(noise_px=0.5, seed=3), 0, 1, qc=False).columns
    assert cols["Twist (deg)"] == pytest.approx(tr["Twist (deg)"], abs=1.0)
    assert cols["LS (%)"] == pytest.approx(tr["LS (%)"], abs=1.0)


def test_long_axis_argument_is_used(heart):
    from cardionurbs.analysis.tags import tag_metrics
    from cardionurbs.anatomy.sections import study_long_axis
    st = heart.study()
    axis = study_long_axis(st, 0)
    a = tag_metrics(st, 0, 1, long_axis=axis, qc=False).columns
    # without landmarks the axis must come from the argument
    st2 = heart.study(with_landmarks=False)
    b = tag_metrics(st2, 0, 1, long_axis=axis, qc=False).columns
    assert a["Twist (deg)"] == pytest.approx(b["Twist (deg)"], abs=1e-9)


def test_compatible_loft_equals_nurbs_loft(heart):
    """The fast loft of sections on one knot vector is the NURBS module's loft."""
    from cardionurbs import nurbs
    from cardionurbs.analysis.tag_surfaces import fit_sections, sa_sections
    secs = sa_sections(heart.study(noise_px=0.3), "sa2", 1)[1]
    fit_sections(secs)
    fast = nurbs.loft_compatible(np.array([s.ctrl for s in secs]), secs[0].knots)
    ref = nurbs.loft([s.curve for s in secs], degree_v=3)
    t = np.linspace(0, 1, 23)
    assert np.allclose(fast.evaluate(t, t), ref.evaluate(t, t), atol=1e-9)


def test_batched_surface_evaluation_matches_nurbs(heart):
    """SurfaceBatch (per-row knots, A2.3 vectorised) equals NurbsSurface.derivatives."""
    from cardionurbs.nurbs import SurfaceBatch
    from cardionurbs.analysis.tags import tag_surfaces
    surfs = list(tag_surfaces(heart.study(), 1).values())
    rng = np.random.default_rng(0)
    sid = rng.integers(0, len(surfs), 300)
    u, v = rng.uniform(0, 1, 300), rng.uniform(0, 1, 300)
    S, Su, Sv = SurfaceBatch(surfs).derivatives(sid, u, v)
    for k in range(0, 300, 7):
        d = surfs[sid[k]].derivatives(u[k:k + 1], v[k:k + 1], order=1)[0]
        assert np.allclose(S[k], d[0, 0], atol=1e-9)
        assert np.allclose(Su[k], d[1, 0], atol=1e-7)
        assert np.allclose(Sv[k], d[0, 1], atol=1e-7)


def test_figure_data_marks_the_flagged_line(heart):
    from cardionurbs.analysis.tags import tag_figure_data
    st = heart.study(jumps=[("sa1", 1, "sa_03", 1)])
    figs = tag_figure_data(st, 1)
    bad = [f for f in figs if f["flagged"]]
    assert [(f["family"], f["index"], f["flagged_slices"]) for f in bad] == [("sa1", 1, ["sa_03"])]
    f = bad[0]
    assert f["vertices"].shape[1] == 3 and f["faces"].max() < len(f["vertices"])
    assert [ln["slice"] for ln in f["lines"] if ln["flagged"]] == ["sa_03"]
    assert {(g["family"]) for g in figs} == {"sa1", "sa2", "la"}


def test_over_time_and_json(heart):
    import json
    from cardionurbs.analysis.tags import tag_metrics
    res = tag_metrics(heart.study(), 0, 1, over_time=True, qc=False)
    assert res.over_time[0]["Twist (deg)"] == pytest.approx(0.0, abs=1e-6)
    assert res.over_time[1]["Twist (deg)"] == pytest.approx(res["Twist (deg)"])
    doc = json.loads(json.dumps(res.to_json()))
    assert doc["columns"]["Tag QC flags"] is None        # QC not run
    assert [lv["index"] for lv in doc["levels"]] == [lv["index"] for lv in res.levels]


def test_flagged_lines_do_not_reach_the_material_points(heart):
    """Two jumped ES lines in a mid slice: left out, the levels are exact again."""
    from cardionurbs.analysis.tags import tag_metrics
    tr = heart.truth()
    st = heart.study(jumps=[("sa1", 2, "sa_03", 1), ("sa2", -2, "sa_03", 1)])

    def worst(res):
        return max(abs(lv["rotation_deg"] - tr["levels"][lv["index"]]) for lv in res.levels)

    kept = tag_metrics(st, 0, 1, exclude_flagged=False)
    left_out = tag_metrics(st, 0, 1)
    assert kept["Tag QC flags"] == left_out["Tag QC flags"] == 2
    assert worst(kept) > 0.05
    assert worst(left_out) < 0.01


def test_tag_surfaces_round_trip_through_json(heart):
    import json
    from cardionurbs.analysis.tags import tag_surfaces, tag_surfaces_dict
    from cardionurbs.nurbs import NurbsSurface
    st = heart.study()
    doc = json.loads(json.dumps(tag_surfaces_dict(st, frames=[1])))
    surfs = tag_surfaces(st, 1)
    t = np.linspace(0, 1, 9)
    for (fam, idx), s in surfs.items():
        back = NurbsSurface.from_dict(doc["frames"]["1"][f"{fam}:{idx}"])
        assert np.allclose(back.evaluate(t, t), s.evaluate(t, t))
