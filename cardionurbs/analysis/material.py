"""Material points: where three tag surfaces, one per family, meet.

Tag planes are laid down in the tissue at ED and move with it, so the point
where tag surfaces ``sa1 #i``, ``sa2 #j`` and ``la #k`` meet is the same
piece of myocardium at every frame (docs/metrics.md, Tags). For every triple
(i, j, k) and frame we solve

    S1(u1, v1) = S2(u2, v2) = S3(u3, v3)                                  (M1)

for the six surface parameters by damped Newton (Gauss–Newton with a tiny
Levenberg term): residual F = [S1 − S2, S2 − S3] ∈ R⁶, Jacobian
J = [[S1u S1v −S2u −S2v 0 0], [0 0 S2u S2v −S3u −S3v]] (3 × 2 blocks of
surface first derivatives, NURBS Book A3.6/A4.4). All triples iterate
together; each surface is evaluated once per iteration at the parameters of
the triples that use it (:class:`cardionurbs.nurbs.batch.SurfaceBatch`).

Starting values: at ED the three surfaces are close to planes, so the start
is the intersection of the three least-squares planes of the surfaces'
data, projected on a parameter grid of each surface; at any other frame the
start is the ED solution (the same tissue has nearly the same surface
parameters), with the plane start as a fallback. Triples whose ED point
lies outside the LV myocardium (SA contours at ED) or outside a surface's
parameter domain are left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cardionurbs.analysis.tag_surfaces import TagSurface, build_tag_surfaces, resolve_frames
from cardionurbs.anatomy.sections import stacking_direction, study_long_axis
from cardionurbs.geometry import fit_plane
from cardionurbs.nurbs.batch import CurveBatch, SplineData, SurfaceBatch  # noqa: F401 (re-export)
from cardionurbs.study import Study

FAMILIES = ("sa1", "sa2", "la")
#: how far (in surface parameter) Newton may follow a surface's linear extension
EXTENSION = 0.25
NEWTON_TOL_MM = 1e-4
ACCEPT_TOL_MM = 0.05
MAX_ITER = 20
_GRID = 15


def surface_grid(surface, n: int = _GRID) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (n², 2) and points (n², 3) of a uniform n × n grid on a surface.

    Parameters
    ----------
    surface : NurbsSurface
        A surface, scanner mm.
    n : int
        Nodes per parameter direction.

    Returns
    -------
    params : (n², 2) ndarray
        (u, v) of each node.
    points : (n², 3) ndarray
        The surface there, mm.
    """
    t = np.linspace(0.0, 1.0, n)
    pts = np.asarray(surface.evaluate(t, t)).reshape(-1, 3)
    uu, vv = np.meshgrid(t, t, indexing="ij")
    return np.column_stack([uu.ravel(), vv.ravel()]), pts


# --------------------------------------------------------------- myocardium
def _polygon_signed_distance(pts2: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Signed distance (positive inside) of (n, 2) points to a closed (m, 2) polygon: the
    distance to the nearest edge, its sign by the crossing-number test. Vectorised over
    points × edges in blocks of about 64 k pairs (x and y kept apart: the temporaries stay in
    cache)."""
    ax, ay = poly[:, 0], poly[:, 1]
    bx, by = np.roll(ax, -1), np.roll(ay, -1)
    abx, aby = bx - ax, by - ay
    inv = 1.0 / np.maximum(abx * abx + aby * aby, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = abx / aby                               # x per unit y along each edge
    out = np.empty(len(pts2))
    rows = max(1, 65536 // max(len(poly), 1))
    for i in range(0, len(pts2), rows):
        px, py = pts2[i:i + rows, :1], pts2[i:i + rows, 1:2]
        apx, apy = px - ax, py - ay
        t = np.clip((apx * abx + apy * aby) * inv, 0.0, 1.0)
        dx, dy = apx - t * abx, apy - t * aby
        d = np.sqrt((dx * dx + dy * dy).min(axis=1))
        # crossing-number point-in-polygon test: edges straddling the point's y, crossed on its right
        with np.errstate(invalid="ignore"):
            crossed = ((ay > py) != (by > py)) & (px < ax + apy * slope)
        out[i:i + rows] = np.where(np.count_nonzero(crossed, axis=1) % 2 == 1, d, -d)
    return out


def myocardium_margin(study: Study, frame: int, points: np.ndarray) -> np.ndarray | None:
    """Signed distance (mm, positive inside) of points to the LV myocardium, or None.

    Built from the closed SA ``lv_endo`` / ``lv_epi`` contours of ``frame``:
    in each slice the margin is min(distance inside the epicardium, distance
    outside the endocardium); between slices it is interpolated linearly
    along the stack normal; beyond the first or last contoured slice it is
    negative. None when the frame has no such contour pair.

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame whose contours are used.
    points : (n, 3) ndarray
        Scanner points, mm.

    Returns
    -------
    (n,) ndarray or None
        The signed margin, mm.
    """
    rings: dict[str, dict[str, np.ndarray]] = {}
    for c in study.contours_at(frame, ("lv_endo", "lv_epi"), view="SA"):
        if c.closed:
            rings.setdefault(c.slice, {})[c.structure] = c.points
    rings = {s: r for s, r in rings.items() if len(r) == 2}
    if not rings:
        return None
    n = stacking_direction(study)[0]
    pts = np.asarray(points, float).reshape(-1, 3)
    slices = sorted(rings, key=lambda s: float(rings[s]["lv_epi"].mean(axis=0) @ n))
    keys = np.array([float(rings[s]["lv_epi"].mean(axis=0) @ n) for s in slices])
    h = pts @ n
    out = np.full(len(pts), -np.inf)
    if len(slices) == 1:
        keys = np.r_[keys, keys + 1e-9]
    j = np.clip(np.searchsorted(keys, h) - 1, 0, len(keys) - 2)
    w = (h - keys[j]) / (keys[j + 1] - keys[j])
    ok = (w >= -1e-9) & (w <= 1 + 1e-9)
    acc = np.zeros(len(pts))
    for m, s in enumerate(slices):
        rows = np.flatnonzero(ok & ((j == m) | (j + 1 == m)))
        if len(rows) == 0:
            continue
        plane = study.slice_plane(s, frame) if any(im.slice == s and im.frame == frame
                                                  for im in study.images) else study.slice_plane(s)
        e1, e2, o = plane.row_cosine, plane.column_cosine, plane.position
        to2 = lambda p: np.column_stack([(p - o) @ e1, (p - o) @ e2])  # noqa: E731
        q = to2(pts[rows])
        margin = np.minimum(_polygon_signed_distance(q, to2(rings[s]["lv_epi"])),
                            -_polygon_signed_distance(q, to2(rings[s]["lv_endo"])))
        weight = np.where(j[rows] == m, 1 - w[rows], w[rows])
        acc[rows] += weight * margin
    out[ok] = acc[ok]
    return out


# ------------------------------------------------------------------- Newton
class _Surfaces:
    """The three families' surfaces of one frame, indexed by tag index, batched per family."""

    def __init__(self, by_family: dict[str, dict[int, TagSurface]]) -> None:
        self.by_family = by_family
        self.batch = {}
        self.lookup = {}
        for f, d in by_family.items():
            keys = sorted(d)
            self.batch[f] = SurfaceBatch([d[k].surface for k in keys])
            lut = np.full(max(keys) - min(keys) + 1 if keys else 0, -1)
            for pos, k in enumerate(keys):
                lut[k - min(keys)] = pos
            self.lookup[f] = (min(keys) if keys else 0, lut)

    def evaluate(self, fam: str, idx: np.ndarray, uv: np.ndarray):
        lo, lut = self.lookup[fam]
        return self.batch[fam].derivatives(lut[np.asarray(idx) - lo], uv[:, 0], uv[:, 1])


def _wrap_or_clip(params: np.ndarray, periodic: tuple[bool, bool, bool]) -> np.ndarray:
    p = params.copy()
    lo, hi = -EXTENSION, 1.0 + EXTENSION
    for f in range(3):
        p[:, 2 * f] = np.clip(p[:, 2 * f], lo, hi)
        if periodic[f]:
            p[:, 2 * f + 1] = np.mod(p[:, 2 * f + 1], 1.0)
        else:
            p[:, 2 * f + 1] = np.clip(p[:, 2 * f + 1], lo, hi)
    return p


def in_domain(params: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Rows whose six surface parameters all lie in [0, 1] (not on a surface's extension).

    Parameters
    ----------
    params : (n, 6) ndarray
        The (u, v) of each point on the three surfaces.
    tol : float
        Tolerance on [0, 1].

    Returns
    -------
    (n,) ndarray of bool
    """
    with np.errstate(invalid="ignore"):
        return np.all((params >= -tol) & (params <= 1 + tol), axis=1)


def intersect_three_surfaces(surfs: _Surfaces, triples: np.ndarray, params: np.ndarray,
                             max_iter: int = MAX_ITER) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve (M1) for every triple from starting parameters (n, 6).

    Returns (points (n, 3), params (n, 6), residual (n,) mm). The step is a
    Gauss–Newton step with Levenberg damping λ = 1e-10·tr(JᵀJ), limited to
    0.2 in any parameter; non-periodic parameters are clipped to [0, 1], the
    angular parameter of the closed LA fan wraps.

    Parameters
    ----------
    surfs : _Surfaces
        One frame's tag surfaces by family.
    triples : (n, 3) ndarray of int
        Tag indices (sa1, sa2, la).
    params : (n, 6) ndarray
        Starting (u, v) on each of the three surfaces.
    max_iter : int
        Gauss–Newton iterations.

    Returns
    -------
    points : (n, 3) ndarray
        The intersections, mm.
    params : (n, 6) ndarray
        Their parameters.
    residual : (n,) ndarray
        The largest point-to-surface distance, mm.
    """
    sa1, sa2, la = (bool(next(iter(surfs.by_family[f].values())).periodic_v)
                    if surfs.by_family[f] else False for f in FAMILIES)
    periodic = (sa1, sa2, la)
    p = _wrap_or_clip(np.asarray(params, float), periodic)
    n = len(triples)
    active = np.ones(n, bool)
    res = np.full(n, np.inf)
    X = np.full((n, 3), np.nan)
    for _ in range(max_iter + 1):
        rows = np.flatnonzero(active)
        if len(rows) == 0:
            break
        ev = [surfs.evaluate(f, triples[rows, c], p[rows, 2 * c:2 * c + 2])
              for c, f in enumerate(FAMILIES)]
        (S1, S1u, S1v), (S2, S2u, S2v), (S3, S3u, S3v) = ev
        F = np.concatenate([S1 - S2, S2 - S3], axis=1)
        r = np.linalg.norm(F, axis=1)
        res[rows] = r
        X[rows] = (S1 + S2 + S3) / 3.0
        done = r < NEWTON_TOL_MM
        active[rows[done]] = False
        rows, F = rows[~done], F[~done]
        if len(rows) == 0:
            break
        k = ~done
        J = np.zeros((len(rows), 6, 6))
        J[:, 0:3, 0], J[:, 0:3, 1] = S1u[k], S1v[k]
        J[:, 0:3, 2], J[:, 0:3, 3] = -S2u[k], -S2v[k]
        J[:, 3:6, 2], J[:, 3:6, 3] = S2u[k], S2v[k]
        J[:, 3:6, 4], J[:, 3:6, 5] = -S3u[k], -S3v[k]
        JtJ = np.einsum("nij,nik->njk", J, J)
        lam = 1e-10 * np.trace(JtJ, axis1=1, axis2=2)[:, None, None] * np.eye(6)
        step = -np.linalg.solve(JtJ + lam + 1e-12 * np.eye(6), np.einsum("nij,ni->nj", J, F)[..., None])[..., 0]
        big = np.abs(step).max(axis=1, keepdims=True)
        step *= np.minimum(1.0, 0.2 / np.maximum(big, 1e-300))
        new = _wrap_or_clip(p[rows] + step, periodic)
        moved = np.abs(new - p[rows]).max(axis=1)
        p[rows] = new
        # stuck against a domain boundary, or hopeless: stop iterating those rows
        active[rows[moved < 1e-12]] = False
    return X, p, res


def start_from_planes(surfs: _Surfaces,
                      triples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starting points and parameters (n, 3), (n, 6) from the three least-squares planes.

    The planes' intersection point is projected on each surface by the
    nearest node of a 25 × 25 parameter grid. Also returns, as the third
    item of the tuple, the largest point-to-grid distance (mm) per triple, a
    cheap test of whether the point is inside all three surfaces' domains.

    Parameters
    ----------
    surfs : _Surfaces
        One frame's tag surfaces by family.
    triples : (n, 3) ndarray of int
        Tag indices (sa1, sa2, la).

    Returns
    -------
    points : (n, 3) ndarray
        The planes' intersections, mm.
    params : (n, 6) ndarray
        The nearest grid nodes' parameters.
    gap : (n,) ndarray
        The largest point-to-grid distance, mm.
    """
    planes = {}
    grids = {}
    for f in FAMILIES:
        for k, ts in surfs.by_family[f].items():
            pts = np.vstack([s.points for s in ts.sections])
            planes[(f, k)] = fit_plane(pts)
            grids[(f, k)] = surface_grid(ts.surface)
    A = np.empty((len(triples), 3, 3))
    b = np.empty((len(triples), 3))
    for c, f in enumerate(FAMILIES):
        for k in np.unique(triples[:, c]):
            rows = triples[:, c] == k
            cen, nrm = planes[(f, int(k))]
            A[rows, c] = nrm
            b[rows, c] = nrm @ cen
    X0 = np.linalg.solve(A + 1e-12 * np.eye(3), b[..., None])[..., 0]
    params = np.empty((len(triples), 6))
    gap = np.zeros(len(triples))
    for c, f in enumerate(FAMILIES):
        for k in np.unique(triples[:, c]):
            rows = np.flatnonzero(triples[:, c] == k)
            uv, g = grids[(f, int(k))]
            d2 = ((X0[rows, None, :] - g[None]) ** 2).sum(-1)
            j = np.argmin(d2, axis=1)
            params[rows, 2 * c:2 * c + 2] = uv[j]
            gap[rows] = np.maximum(gap[rows], np.sqrt(d2[np.arange(len(rows)), j]))
    return X0, params, gap


# ------------------------------------------------------------------ results
@dataclass
class MaterialPoints:
    """Material points of a study: one row per tag triple (sa1 i, sa2 j, la k).

    Attributes
    ----------
    triples : (n, 3) int
        Tag indices (sa1, sa2, la).
    positions : dict frame -> (n, 3)
        Scanner mm at each tracked frame; NaN where the three surfaces do not
        meet inside their domains at that frame.
    ed_frame, es_frame : int
    dropped : int
        Triples left out at ED (outside the myocardium or the surfaces).
    notes : list of str
        Why triples or frames are missing.
    params : dict frame -> (n, 6)
        The three surfaces' (u, v) parameters of each point at each frame.
    extended : dict frame -> (n, 3)
        Scanner mm also where the surfaces meet only on their linear extensions
        (:meth:`found`).
    """

    triples: np.ndarray
    positions: dict[int, np.ndarray]
    ed_frame: int
    es_frame: int
    dropped: int = 0
    notes: list[str] = field(default_factory=list)
    params: dict[int, np.ndarray] = field(default_factory=dict)
    extended: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def frames(self) -> list[int]:
        return sorted(self.positions)

    def tracked(self, *frames: int) -> np.ndarray:
        """Triples found inside all three surfaces' domains at every one of ``frames``.

        Parameters
        ----------
        *frames : int
            Frames.

        Returns
        -------
        (n,) ndarray of bool
        """
        m = np.ones(len(self.triples), bool)
        for f in frames:
            m &= np.all(np.isfinite(self.positions[f]), axis=1)
            if f in self.extended:
                m &= ~self.extended[f]
        return m

    def found(self, *frames: int) -> np.ndarray:
        """Triples found at every one of ``frames``, also on the surfaces' linear extensions
        (up to ``EXTENSION`` in parameter beyond the data: used to place a level that
        leaves the SA stack).

        Parameters
        ----------
        *frames : int
            Frames.

        Returns
        -------
        (n,) ndarray of bool
        """
        m = np.ones(len(self.triples), bool)
        for f in frames:
            m &= np.all(np.isfinite(self.positions[f]), axis=1)
        return m

    def displacement(self, f0: int | None = None, f1: int | None = None) -> np.ndarray:
        """(n, 3) displacement, mm, from frame f0 (ED) to f1 (ES).

        Parameters
        ----------
        f0, f1 : int or None
            The frames; None: ED and ES.

        Returns
        -------
        (n, 3) ndarray
            mm (NaN where a point is not found at either frame).
        """
        f0 = self.ed_frame if f0 is None else f0
        f1 = self.es_frame if f1 is None else f1
        return self.positions[f1] - self.positions[f0]


def _complete(surfaces: dict) -> _Surfaces | None:
    by = {f: {k[1]: ts for k, ts in surfaces.items() if k[0] == f} for f in FAMILIES}
    return _Surfaces(by) if all(by[f] for f in FAMILIES) else None


def material_points(study: Study, ed_frame: int | None = None, es_frame: int | None = None,
                    frames: list[int] | None = None, long_axis: tuple | None = None,
                    surfaces: dict | None = None, margin_mm: float = 0.5) -> MaterialPoints:
    """Material points (tag-surface triple intersections) at ED, ES and ``frames``.

    Parameters
    ----------
    study : Study
        With tag lines of all three families at ED.
    ed_frame, es_frame : int or None
        Default to the study's labels.
    frames : list of int or None
        The frames tracked; None: every tagged frame (ED first).
    long_axis : (apex, base centre) at ED, mm
        For lofting the LA family; from the landmarks when omitted.
    surfaces : dict frame -> {(family, index): TagSurface}, optional
        Pre-built surfaces (:func:`build_tag_surfaces`), to share work.
    margin_mm : float
        A point is kept when its ED signed distance inside the LV
        myocardium is >= -margin_mm (mm): half a millimetre of tolerance,
        the order of contour tracing noise (no test without ED contours).

    Returns
    -------
    MaterialPoints
    """
    ed_frame, es_frame = resolve_frames(study, ed_frame, es_frame)
    if frames is None:
        frames = [f for f in study.tagged_frames]
    frames = [ed_frame] + [f for f in dict.fromkeys([es_frame, *frames]) if f != ed_frame]
    if long_axis is None:
        long_axis = study_long_axis(study, ed_frame)
    surfaces = dict(surfaces or {})
    notes: list[str] = []
    for f in frames:
        if f not in surfaces:
            surfaces[f] = build_tag_surfaces(study, f, long_axis)
    ed = _complete(surfaces[ed_frame])
    empty = MaterialPoints(np.zeros((0, 3), int), {f: np.zeros((0, 3)) for f in frames},
                           ed_frame, es_frame, 0, notes)
    if ed is None:
        notes.append(f"frame {ed_frame}: tag surfaces of all three families are needed for "
                     "material points")
        return empty
    grid = np.array(np.meshgrid(sorted(ed.by_family["sa1"]), sorted(ed.by_family["sa2"]),
                                sorted(ed.by_family["la"]), indexing="ij")).reshape(3, -1).T
    X0, p0, gap = start_from_planes(ed, grid)
    keep = gap < 8.0
    margin0 = myocardium_margin(study, ed_frame, X0)
    if margin0 is not None:
        keep &= margin0 > -(margin_mm + 4.0)
    else:
        notes.append(f"frame {ed_frame}: no SA myocardial contours; material points not "
                     "restricted to the myocardium")
    triples, p0 = grid[keep], p0[keep]
    X, p, res = intersect_three_surfaces(ed, triples, p0)
    ok = (res < ACCEPT_TOL_MM) & in_domain(p)
    margin = myocardium_margin(study, ed_frame, X)
    if margin is not None:
        ok &= margin >= -margin_mm
    dropped = len(grid) - int(ok.sum())
    triples, X, p = triples[ok], X[ok], p[ok]
    positions = {ed_frame: X}
    params = {ed_frame: p}
    extended = {ed_frame: np.zeros(len(X), bool)}
    for f in frames[1:]:
        sf = _complete(surfaces[f])
        if sf is None:
            positions[f] = np.full_like(X, np.nan)
            notes.append(f"frame {f}: not all three tag families; no material points")
            continue
        has = np.array([all(int(t[c]) in sf.by_family[fam] for c, fam in enumerate(FAMILIES))
                        for t in triples], bool) if len(triples) else np.zeros(0, bool)
        Xf = np.full_like(X, np.nan)
        pf = np.full_like(p, np.nan)
        if has.any():
            rows = np.flatnonzero(has)
            x1, p1, r1 = intersect_three_surfaces(sf, triples[rows], p[rows])
            bad = r1 >= ACCEPT_TOL_MM
            if bad.any():
                _, pb, _ = start_from_planes(sf, triples[rows[bad]])
                x2, p2, r2 = intersect_three_surfaces(sf, triples[rows[bad]], pb)
                better = r2 < r1[bad]
                idx = np.flatnonzero(bad)[better]
                x1[idx], p1[idx], r1[idx] = x2[better], p2[better], r2[better]
            good = r1 < ACCEPT_TOL_MM
            Xf[rows[good]] = x1[good]
            pf[rows[good]] = p1[good]
        positions[f] = Xf
        params[f] = pf
        extended[f] = np.isfinite(Xf[:, 0]) & ~in_domain(pf)
    return MaterialPoints(triples, positions, ed_frame, es_frame, dropped, notes, params, extended)
