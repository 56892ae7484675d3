"""Outflow tracts: the RV lumen from the tricuspid plane to the pulmonary valve (RVOT) and
the LV lumen from the mitral plane to the aortic valve (LVOT).

Convention (docs/metrics.md, Cavities and walls): the RV cavity is the RV body (apical
side of the tricuspid plane) united with the RVOT, the lumen on the basal side of the
tricuspid plane up to the pulmonary valve plane; the RV myocardium gains the RVOT free
wall (between the RVOT's endo- and epicardial tubes). The LV cavity gains the LVOT lumen
between the mitral and aortic planes; the LV myocardium is unchanged.

Evidence for a tract at one frame: valve landmarks (``pulmonary`` / ``aortic``, points on
the annulus) or, for the RV, ``rv_outlet`` SA contours. Without either, no tract is built
and every volume is what the ventricle's body gives (the RV closed at the tricuspid plane,
the LV at the mitral plane).

Construction (one tube per surface, scanner mm):

* valve centre ``c`` and radius ``r0``: the annulus points (≥ 3: least-squares circle in
  their plane; 2: their midpoint and half their distance; the most distal ``rv_outlet``
  contour when there is no landmark);
* axis ``a``: the valve plane's normal (through the annulus points, as perpendicular as
  they allow to the direction from ``c`` to the tract's contour points);
* sections: planes ``(x − c)·a = h`` every :data:`STEP_MM`, from the valve (h = 0) until
  the section lies wholly on the apical side of the body's valve plane; on each, the
  crossings of the tract's contours (the LA contour points of that surface on the basal
  side of the body's valve plane that are nearer the outflow valve than the body's valve
  centre, and the ``rv_outlet`` loops) fit a circle (≥ 3 crossings: least squares; 2:
  their midpoint and half distance; 1: the distance to the interpolated centre, but no
  more than the radius interpolated from the sections seen across — one wall seen narrows
  a section, never widens it); centres and radii of sections without crossings are
  interpolated along ``h``;
* the circles are joined into a closed triangulated tube (ruled between sections, so
  its volume is the Cavalieri sum of the section areas), which the model trims to the
  apical side of the outflow valve plane and the basal side of the body's valve plane;
* in a cine of :data:`TIME_PRIOR_MIN_FRAMES` frames or more, the RVOT lumen's radii are,
  section by section, the median of its own and the two adjacent frames' tubes
  (:func:`radii_in_time`): the same section is crossed once at one frame and twice at the
  next, so its radius from one frame's few crossings alone jumps where the tract has
  barely moved.

With SA ``rv_outlet`` contours (planes across the tract) the RVOT is lofted through them
instead (:func:`loft_tract`): from the valve ring (the spline through the annulus points,
the annulus circle with fewer than four; without landmarks the most basal outlet contour
closes the tract) through the outlet contours to the most apical one moved along the
stacking direction past the tricuspid plane (stretched through the tract's LA crossings
on the way), the sections matched point to point by arc length.

The epicardial RVOT tube is the endocardial one widened by the RVOT wall thickness, from
the RV epicardial contour points of the tract (LA runs selected as above, and epicardial
outlet loops): a lofted tube position by position round its rings by the local thickness
those points show (the tract's septal side, on the LV epicardium and aortic root, has no RV
wall), a tube of circles by their median distance outside the lumen; no epicardial
evidence, no RVOT wall.
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cardionurbs.anatomy.mesh import Plane, closed_mesh
from cardionurbs.anatomy.sections import FrameGeometry, valve_plane
from cardionurbs.geometry import fit_plane, in_plane_basis, polygon_area, polyline_crossings
from cardionurbs.study import Study

#: spacing (mm) of the tube's sections along its axis
STEP_MM = 2.0
#: points round each tube section
AROUND = 48
#: the longest tube (mm along its axis) before it must reach the body's valve plane
MAX_LENGTH_MM = 80.0
#: the tube starts this far (mm) beyond its valve plane, so the trim by that plane cuts it
OVERHANG_MM = 1.0
#: annulus points from which a lofted tract's valve section is the spline through them
ANNULUS_SPLINE_MIN = 4
#: a lofted tract's wall thickness at one ring position is taken from the epicardial
#: evidence whose nearest lumen point lies within this many positions of it (of AROUND)
WALL_WINDOW = 2

#: which body valve plane, outflow valve landmark and LA contours each tract uses
TRACTS = {"rv_endo": ("rv", "pulmonary"), "rv_epi": ("rv", "pulmonary"),
          "lv_endo": ("lv", "aortic")}


@dataclass(eq=False)
class OutflowTract:
    """One outflow tube of one frame (scanner mm).

    ``valve``: the outflow valve plane (normal into the ventricle, the kept side);
    ``body_plane``: the ventricle body's valve plane (tricuspid / mitral);
    ``levels`` (k,), ``centres`` (k, 3), ``radii`` (k,): the circular sections at
    distance ``levels`` along ``axis`` from the valve centre; ``evidence``: the contour
    points it was fitted to (m, 3).

    Attributes
    ----------
    structure : str
        ``"rv_endo"``, ``"rv_epi"`` (RVOT lumen and outer wall) or ``"lv_endo"`` (LVOT).
    valve : cardionurbs.anatomy.mesh.Plane
        The outflow valve plane, origin in mm, normal into the ventricle.
    body_plane : cardionurbs.anatomy.mesh.Plane
        The ventricle body's valve plane (tricuspid or mitral).
    axis : ndarray, shape (3,)
        The tube's unit axis, from the valve into the ventricle.
    levels : ndarray, shape (k,)
        Each section's distance along ``axis`` from the valve centre, in mm.
    centres : ndarray, shape (k, 3)
        Section centres, in mm.
    radii : ndarray, shape (k,)
        Section radii, in mm.
    evidence : ndarray, shape (m, 3)
        The contour points the tube was fitted to, in mm.
    rings : ndarray, shape (k, n, 3) or None
        Lofted sections (through outlet loops) in mm, corresponding point to point; None for
        a tube of circles.
    """

    structure: str
    valve: Plane
    body_plane: Plane
    axis: np.ndarray
    levels: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    evidence: np.ndarray
    rings: np.ndarray | None = None     # (k, m, 3) lofted sections (outlet loops), else circles

    def to_dict(self) -> dict:
        """JSON-safe tract (the model file keeps it beside the surfaces).

        Returns
        -------
        dict
            ``structure``, ``valve`` and ``body_plane`` (plane dicts), and ``axis``, ``levels``,
            ``centres``, ``radii``, ``evidence``, ``rings`` as nested lists (mm).
        """
        def arr(a):
            return None if a is None else np.asarray(a, float).tolist()
        return {"structure": self.structure, "valve": self.valve.to_dict(),
                "body_plane": self.body_plane.to_dict(), "axis": arr(self.axis),
                "levels": arr(self.levels), "centres": arr(self.centres),
                "radii": arr(self.radii), "evidence": arr(self.evidence),
                "rings": arr(self.rings)}

    @classmethod
    def from_dict(cls, d: dict) -> "OutflowTract":
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            A :meth:`to_dict` mapping.

        Returns
        -------
        OutflowTract
            The tube.
        """
        def arr(a):
            return None if a is None else np.asarray(a, float)
        return cls(d["structure"], Plane.from_dict(d["valve"]), Plane.from_dict(d["body_plane"]),
                   arr(d["axis"]), arr(d["levels"]), arr(d["centres"]), arr(d["radii"]),
                   arr(d["evidence"]).reshape(-1, 3), rings=arr(d.get("rings")))

    def ring_points(self, around: int = AROUND) -> np.ndarray:
        """(k, m, 3) the tube's sections as point rings, valve end first.

        Parameters
        ----------
        around : int, optional
            Points per circular section (ignored for lofted rings).

        Returns
        -------
        ndarray, shape (k, m, 3)
            The sections' points in mm.
        """
        if self.rings is not None:
            return self.rings
        u, v = in_plane_basis(self.axis)
        t = np.linspace(0.0, 2.0 * np.pi, around, endpoint=False)
        ring = np.cos(t)[:, None] * u + np.sin(t)[:, None] * v          # (m, 3)
        return self.centres[:, None, :] + self.radii[:, None, None] * ring[None]

    def mesh(self, around: int = AROUND) -> tuple[np.ndarray, np.ndarray]:
        """Closed, outward-oriented triangle mesh of the tube (its two ends capped).

        Parameters
        ----------
        around : int, optional
            Points per circular section.

        Returns
        -------
        vertices : ndarray, shape (V, 3)
            In mm.
        faces : ndarray of int, shape (F, 3)
            Triangles, outward-oriented.
        """
        pts = self.ring_points(around)
        k, m = pts.shape[:2]
        idx = np.arange(k * m).reshape(k, m)
        a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
        c, d = idx[1:], np.roll(idx[1:], -1, axis=1)
        faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                                np.stack([a, d, c], -1).reshape(-1, 3)])
        return closed_mesh(pts.reshape(-1, 3), faces)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (mm) of points to the tube's wall within its tract: to the section
        circle at the point's level (the nearest end section beyond the tube's ends);
        infinite for points on the apical side of the body's valve plane, where the
        body's surface bounds the cavity instead.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Points in mm.

        Returns
        -------
        ndarray, shape (n,)
            Distance to the wall in mm (inf on the apical side of the body plane).
        """
        p = np.asarray(points, float)
        if self.rings is not None:        # lofted rings: to the densely sampled wall
            r = self.rings
            w = np.linspace(0.0, 1.0, 5)[:-1]
            dense = np.concatenate([(1 - t) * r[:-1] + t * r[1:] for t in w] + [r[-1:]])
            d = cKDTree(dense.reshape(-1, 3)).query(p)[0]
            return np.where(self.body_plane.signed_distance(p) > 0, np.inf, d)
        h = (p - self.valve.origin) @ self.axis
        hc = np.clip(h, 0.0, self.levels[-1])
        c = np.column_stack([np.interp(hc, self.levels, self.centres[:, i]) for i in range(3)])
        q = p - c
        rho = np.linalg.norm(q - np.outer(q @ self.axis, self.axis), axis=1)
        d = np.hypot(h - hc, rho - np.interp(hc, self.levels, self.radii))
        return np.where(self.body_plane.signed_distance(p) > 0, np.inf, d)


def tract_solid(t: OutflowTract, valve: Plane | None = None, overlap_mm: float = 0.01,
                frame: int | None = None):
    """The tube as a manifold3d solid trimmed to its tract: the apical side of ``valve``
    (default its own valve plane) and the basal side of the body's valve plane moved
    ``overlap_mm`` apically, so that its union with the body has no coplanar faces.
    None when nothing is left.

    Parameters
    ----------
    t : OutflowTract
        The tube.
    valve : cardionurbs.anatomy.mesh.Plane, optional
        The trimming valve plane (default ``t.valve``).
    overlap_mm : float, optional
        How far past the body's valve plane the tube reaches, in mm.
    frame : int or None, optional
        The frame index, for the messages.

    Returns
    -------
    manifold3d.Manifold or None
        The trimmed solid (mm), None when empty.

    Raises
    ------
    cardionurbs.errors.ReconstructionError
        The tube's mesh is not a closed manifold.
    """
    from cardionurbs.anatomy.mesh import to_manifold
    valve = t.valve if valve is None else valve
    m = to_manifold(*t.mesh(), what=f"{t.structure} outflow tract", frame=frame)
    m = m.trim_by_plane(valve.normal, float(valve.origin @ valve.normal))
    b = t.body_plane
    m = m.trim_by_plane(-b.normal, -float(b.origin @ b.normal) - overlap_mm)
    return None if m.is_empty() else m


def circle_fit(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares circle (Kåsa: x² + y² + D x + E y + F = 0) through (k, 2) points,
    k ≥ 3: (centre (2,), radius).

    Parameters
    ----------
    points : ndarray, shape (k, 2)
        In-plane points, in mm, k >= 3.

    Returns
    -------
    centre : ndarray, shape (2,)
        In mm.
    radius : float
        In mm.
    """
    x, y = points[:, 0], points[:, 1]
    A = np.column_stack([x, y, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(A, -(x * x + y * y), rcond=None)
    c = -0.5 * sol[:2]
    return c, float(np.sqrt(max(c @ c - sol[2], 0.0)))


def section_circle(points: np.ndarray, diameter_pair: bool = True
                   ) -> tuple[np.ndarray, float] | None:
    """Centre (2,) and radius of a section from its in-plane points: ≥ 3 points not on one
    line, spanning an arc that pins the circle (radius at most twice their spread):
    least-squares circle; otherwise, when ``diameter_pair`` (crossings of LA planes
    through the tract, which cut it across), the two farthest apart: their midpoint and
    half their distance. None when neither applies.

    Parameters
    ----------
    points : ndarray, shape (k, 2)
        In-plane wall points of one section, in mm.
    diameter_pair : bool, optional
        Fall back to the two farthest points as a diameter.

    Returns
    -------
    tuple of (ndarray, float) or None
        (centre (2,) in mm, radius in mm), or None.
    """
    p = np.asarray(points, float)
    if len(p) < 2:
        return None
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    if len(p) >= 3:
        q = p - p.mean(axis=0)
        s = np.linalg.svd(q, compute_uv=False)
        if s[1] > 0.05 * s[0]:
            c, r = circle_fit(p)
            if r <= 2.0 * d[i, j]:     # an arc of at least ~30 degrees pins the circle
                return c, r
    if not diameter_pair:
        return None
    return 0.5 * (p[i] + p[j]), 0.5 * float(d[i, j])


def _into_ventricle(direction: np.ndarray, body: Plane) -> np.ndarray:
    """A tract's axis points from its valve into the ventricle, i.e. towards the apical side
    of the body's valve plane: ``direction`` when it does, else the body plane's normal
    (contour points beyond the valve, up the great artery, must not turn the tract round)."""
    return direction if float(direction @ body.normal) > 0.1 else body.normal


def _annulus(points: np.ndarray, axis_guess: np.ndarray) -> tuple[Plane, np.ndarray, float]:
    """Valve plane, centre and radius of annulus points."""
    plane = valve_plane(points, axis_guess)
    u, v = in_plane_basis(plane.normal)
    xy = np.column_stack([(points - plane.origin) @ u, (points - plane.origin) @ v])
    circle = section_circle(xy) if len(points) >= 3 else None
    if circle is not None:
        c2, r = circle
        centre = plane.origin + c2[0] * u + c2[1] * v
    else:                       # two points, or points that pin no circle (on one line)
        centre = points.mean(axis=0)
        r = 0.5 * float(np.linalg.norm(points[0] - points[-1]))
    return Plane(centre, plane.normal), centre, r


def outlet_loops(study: Study, frame: int) -> dict[str, list[np.ndarray]]:
    """The RV outlet loops of one frame: ``rv_endo`` the ``rv_outlet`` SA contours,
    ``rv_epi`` the SA RV epicardial contours of slices that have an outlet but no RV
    body (endocardial) contour — each as its (k, 3) points.

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study.
    frame : int
        The frame index, 0-based.

    Returns
    -------
    dict of str to list of ndarray
        ``"rv_endo"`` and ``"rv_epi"`` -> loops, each (k, 3) in mm (k >= 3).
    """
    by_slice: dict = {}
    for c in study.contours_at(frame, view="SA"):
        by_slice.setdefault(c.slice, {}).setdefault(c.structure, []).append(c.points)
    out: dict[str, list[np.ndarray]] = {"rv_endo": [], "rv_epi": []}
    for d in by_slice.values():
        if "rv_outlet" not in d:
            continue
        out["rv_endo"] += [p for p in d["rv_outlet"] if len(p) >= 3]
        if not any(k in d for k in ("rv_endo", "rv_freewall", "rv_septum")):
            out["rv_epi"] += [p for p in d.get("rv_epi", []) if len(p) >= 3]
    return out


def _tract_runs(geo: FrameGeometry, structure: str, body: Plane,
                valve_centre: np.ndarray) -> list[np.ndarray]:
    """The LA contour runs that describe a tract: LA polylines of ``structure`` cut to
    their points on the basal side of the body plane and nearer the outflow valve centre
    than the body plane's centre (consecutive runs of >= 2 points)."""
    runs = []
    for pl in geo.la_points.get(structure, []):
        keep = ((body.signed_distance(pl) < 0)
                & (np.linalg.norm(pl - valve_centre, axis=1)
                   < np.linalg.norm(pl - body.origin, axis=1)))
        if keep.sum() < 2:
            continue
        edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(int), [0]])))
        for s, e in zip(edges[::2], edges[1::2]):
            if e - s >= 2:
                runs.append(pl[s:e])
    return runs


def build_tract(structure: str, annulus: np.ndarray | None, runs: list[np.ndarray],
                body: Plane, fallback_axis: np.ndarray, loops: Sequence[np.ndarray] = (),
                wall_mm: float = 0.0) -> OutflowTract | None:
    """One outflow tube (module docstring) from annulus points (None: the most distal
    outlet loop is the annulus), the tract's open contour runs (LA: their crossings with
    each section), its outlet loops (SA: their points within half a step of each section,
    projected along the axis), and the body's valve plane. ``wall_mm`` is added to the
    annulus radius.

    Parameters
    ----------
    structure : str
        ``"rv_endo"`` or ``"lv_endo"``.
    annulus : ndarray, shape (a, 3) or None
        Valve annulus landmarks, in mm.
    runs : list of ndarray, shape (n, 3)
        The tract's LA contour runs, in mm.
    body : cardionurbs.anatomy.mesh.Plane
        The ventricle body's valve plane.
    fallback_axis : ndarray, shape (3,)
        The axis guess without evidence (the stacking direction).
    loops : list of ndarray, shape (n, 3), optional
        SA outlet loops, in mm.
    wall_mm : float, optional
        Added to the annulus radius, in mm.

    Returns
    -------
    OutflowTract or None
        The tube of circles (every :data:`STEP_MM` mm), None when the evidence allows none.
    """
    loops = [np.asarray(q, float) for q in loops]
    if annulus is None or len(annulus) == 0:
        if not loops:
            return None
        annulus = min(loops, key=lambda r: float(body.signed_distance(r).mean()))
    annulus = np.atleast_2d(np.asarray(annulus, float))
    centre0 = annulus.mean(axis=0)
    ev = np.concatenate(list(runs) + loops) if (len(runs) or loops) else np.empty((0, 3))
    guess = (ev.mean(axis=0) - centre0) if len(ev) else fallback_axis
    if np.linalg.norm(guess) < 1e-6:
        guess = fallback_axis
    guess = _into_ventricle(guess / np.linalg.norm(guess), body)
    valve, c0, r0 = _annulus(annulus, guess)
    a = valve.normal
    if body.signed_distance(c0[None])[0] >= 0:
        return None                     # the outflow valve is not beyond the body's valve plane
    u, v = in_plane_basis(a)
    levels = [-OVERHANG_MM, 0.0]
    fits: dict[int, tuple] = {0: (c0, r0 + wall_mm)}
    single: dict[int, np.ndarray] = {}
    h = 0.0
    while True:
        h += STEP_MM
        k = len(levels)
        levels.append(h)
        la = [polyline_crossings(r, a, float(c0 @ a) + h) for r in runs]
        near = [q[np.abs((q - c0) @ a - h) <= 0.5 * STEP_MM] for q in loops]
        near = [q for q in near if len(q)]
        pts = np.concatenate(la + near) if (la or near) else np.empty((0, 3))
        if len(pts):
            pts = pts[body.signed_distance(pts) < 0]
        o = c0 + h * a
        xy = np.column_stack([(pts - o) @ u, (pts - o) @ v])   # projected along the axis
        fit = section_circle(xy, diameter_pair=not near)
        if fit is not None:
            fits[k] = (o + fit[0][0] * u + fit[0][1] * v, fit[1])
        elif len(xy) == 1 and not near:
            single[k] = pts[0]
        # stop once a section around the axis, as wide as the widest so far, is wholly apical
        rmax = max(f[1] for f in fits.values())
        tilt = np.sqrt(max(0.0, 1.0 - float(a @ body.normal) ** 2))
        if body.signed_distance(o[None])[0] - rmax * tilt > 0 or h >= MAX_LENGTH_MM:
            break
    lv = np.asarray(levels)
    ks = sorted(fits)
    kh = lv[ks]
    cs = np.array([fits[k][0] for k in ks])
    # centres: offsets from the axis interpolated along h (held beyond the last fit)
    off = cs - c0 - np.outer(kh, a)
    off_all = np.column_stack([np.interp(lv, kh, off[:, i]) for i in range(3)])
    centres = c0 + np.outer(lv, a) + off_all
    rs = {k: fits[k][1] for k in ks}
    across = np.interp(lv, kh, [fits[k][1] for k in ks])
    for k, p in single.items():
        # one wall seen: it narrows the section, never widens it (the other wall is unseen)
        rs[k] = min(float(np.linalg.norm((p - centres[k]) - ((p - centres[k]) @ a) * a)),
                    float(across[k]))
    kr = np.array(sorted(rs))
    radii = np.interp(lv, lv[kr], [rs[k] for k in kr])
    radii[0] = radii[1]
    centres[0] = centres[1] - OVERHANG_MM * a
    return OutflowTract(structure, valve, body, a, lv, centres, np.maximum(radii, 0.5), ev)


def ring_from(points: np.ndarray, normal: np.ndarray, ref: np.ndarray, m: int = AROUND
              ) -> np.ndarray:
    """``m`` points uniformly spaced in arc length round a closed loop, counter-clockwise
    about ``normal``, starting at the loop's point farthest along ``ref`` (so that the
    sections of one tract correspond point to point).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        A closed loop (first point not repeated), in mm.
    normal : ndarray, shape (3,)
        The direction the loop runs counter-clockwise about.
    ref : ndarray, shape (3,)
        The direction whose farthest point starts the ring.
    m : int, optional
        Points of the ring.

    Returns
    -------
    ndarray, shape (m, 3)
        The ring, in mm.
    """
    p = np.asarray(points, float)
    if polygon_area(p, normal, signed=True) < 0:
        p = p[::-1]
    p = np.roll(p, -int(np.argmax(p @ ref)), axis=0)
    closed = np.vstack([p, p[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    t = arc[-1] * np.arange(m) / m
    return np.column_stack([np.interp(t, arc, closed[:, i]) for i in range(3)])


def annulus_ring(valve: Plane, centre: np.ndarray, radius: float, normal: np.ndarray,
                 ref: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
    """The valve section as a ring in the valve plane. With at least
    :data:`ANNULUS_SPLINE_MIN` annulus ``points``: the closed cubic spline (chord length)
    through them, projected on the plane, in angular order about their centroid, so that
    the section passes through every annulus point whatever the annulus shape (a crescent
    RVOT annulus is not round: its least-squares circle missed the points by up to 4.5 mm);
    fewer points: the annulus circle (centre and radius from the points, :func:`_annulus`).
    Joined as a polygon, a few ring points would cut the area (8 points: by 10 %).

    Parameters
    ----------
    valve : cardionurbs.anatomy.mesh.Plane
        The valve plane.
    centre : ndarray, shape (3,)
        The annulus centre, in mm.
    radius : float
        The annulus radius, in mm.
    normal : ndarray, shape (3,)
        The direction the ring runs counter-clockwise about.
    ref : ndarray, shape (3,)
        The direction whose farthest point starts the ring.
    points : ndarray, shape (a, 3), optional
        The annulus landmarks, in mm.

    Returns
    -------
    ndarray, shape (AROUND, 3)
        The valve ring, in mm.
    """
    u, v = in_plane_basis(valve.normal)
    if points is not None and len(points) >= ANNULUS_SPLINE_MIN:
        from cardionurbs.anatomy.surfaces import periodic_spline
        p = np.asarray(points, float)
        p = p - np.outer(valve.signed_distance(p), valve.normal)
        q = p - p.mean(axis=0)
        p = p[np.argsort(np.arctan2(q @ v, q @ u))]
        keep = np.r_[True, np.linalg.norm(np.diff(p, axis=0), axis=1) > 0.5]
        keep[-1] &= bool(np.linalg.norm(p[-1] - p[0]) > 0.5)
        if keep.sum() >= ANNULUS_SPLINE_MIN:
            spline, length = periodic_spline(p[keep])
            return ring_from(spline(np.linspace(0.0, length, 8 * AROUND, endpoint=False)),
                             normal, ref)
    t = np.linspace(0.0, 2.0 * np.pi, 8 * AROUND, endpoint=False)
    circle = centre + radius * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
    return ring_from(circle, normal, ref)


def ring_through_crossings(ring: np.ndarray, normal: np.ndarray, crossings: np.ndarray,
                           limits: tuple[float, float] = (0.5, 2.5)) -> np.ndarray:
    """A section ring stretched in its plane (normal ``normal``) about its centroid so that
    it passes through wall points seen on that plane (``crossings``, e.g. the LA contours'
    crossings of the section plane).

    Each crossing at polar angle φ_i about the centroid, at distance ρ_i, gives the radial
    scale s_i = ρ_i / r(φ_i), r(φ) the ring's own distance at that angle (piecewise linear
    in φ between its vertices); each ring vertex is scaled by s(φ), the periodic linear
    interpolation of the s_i in φ. One crossing seen scales its side only (s = 1 at the
    opposite angle). The scales are kept within ``limits``. Points off the section plane
    are used as projected along ``normal``.

    Parameters
    ----------
    ring : ndarray, shape (m, 3)
        A section ring, in mm.
    normal : ndarray, shape (3,)
        Its plane's normal.
    crossings : ndarray, shape (c, 3)
        Wall points seen on the plane, in mm.
    limits : tuple of (float, float), optional
        The least and largest radial scale.

    Returns
    -------
    ndarray, shape (m, 3)
        The stretched ring, in mm (``ring`` itself without crossings).
    """
    ring = np.asarray(ring, float)
    x = np.asarray(crossings, float).reshape(-1, 3)
    if not len(x):
        return ring
    n = normal / np.linalg.norm(normal)
    u, v = in_plane_basis(n)
    c = ring.mean(axis=0)
    q, p = ring - c, x - c
    phi_r, r_r = np.arctan2(q @ v, q @ u), np.hypot(q @ u, q @ v)
    phi_x, rho_x = np.arctan2(p @ v, p @ u), np.hypot(p @ u, p @ v)
    o = np.argsort(phi_r)
    r_at = np.interp(phi_x, phi_r[o], r_r[o], period=2.0 * np.pi)
    s = np.clip(rho_x / np.maximum(r_at, 1e-9), *limits)
    if len(s) == 1:
        phi_x, s = np.r_[phi_x, phi_x + np.pi], np.r_[s, 1.0]
    scale = np.interp(phi_r, phi_x, s, period=2.0 * np.pi)
    return c + q * scale[:, None]


def loft_tract(structure: str, annulus: np.ndarray | None, loops: list[np.ndarray],
               body: Plane, direction: np.ndarray, ref: np.ndarray,
               runs: Sequence[np.ndarray] = ()) -> OutflowTract | None:
    """An outflow tube lofted through its outlet loops (SA ``rv_outlet`` contours, planes
    across the tract): from the valve ring (:func:`annulus_ring`; without annulus points
    the most basal loop closes the tract) through the loops in stacking order to the
    most apical loop moved along the stacking ``direction`` until it lies wholly on the
    apical side of the body's valve plane. Sections correspond by arc length from their
    point farthest along ``ref`` (the LV → RV direction).

    Between the most apical loop and the body's valve plane no SA contour shows the tract;
    where its LA contour ``runs`` (:func:`_tract_runs`) do, the section is moved on every
    :data:`STEP_MM` and stretched through their crossings of each section plane
    (:func:`ring_through_crossings`), each from the one before, so that a wall no longer
    seen keeps where it was last seen: the tract widens there into the ventricle's body,
    which the moved loop alone would miss.

    Parameters
    ----------
    structure : str
        ``"rv_endo"`` (the RVOT lumen).
    annulus : ndarray, shape (a, 3) or None
        Valve annulus landmarks, in mm.
    loops : list of ndarray, shape (n, 3)
        SA outlet loops, in mm.
    body : cardionurbs.anatomy.mesh.Plane
        The ventricle body's valve plane.
    direction : ndarray, shape (3,)
        The stacking direction, base to apex.
    ref : ndarray, shape (3,)
        The LV → RV direction (ring correspondence).
    runs : list of ndarray, shape (n, 3), optional
        The tract's LA contour runs, in mm.

    Returns
    -------
    OutflowTract or None
        The lofted tube (``rings`` set), None without loops or when the valve is not basal.
    """
    loops = [np.asarray(q, float) for q in loops if len(q) >= 3]
    if not loops:
        return None
    n = direction / np.linalg.norm(direction)
    ref = ref - (ref @ n) * n
    loops.sort(key=lambda q: float(q.mean(axis=0) @ n))
    ev = np.concatenate(loops)
    if annulus is None or len(annulus) == 0:
        annulus, loops = loops[0], loops[1:]
        c0, nrm = fit_plane(annulus)
        valve = Plane(c0, nrm if nrm @ n > 0 else -nrm)
        top = ring_from(annulus, n, ref)
    else:
        annulus = np.atleast_2d(np.asarray(annulus, float))
        guess = ev.mean(axis=0) - annulus.mean(axis=0)
        valve, c0, r0 = _annulus(annulus, _into_ventricle(guess / np.linalg.norm(guess), body))
        top = annulus_ring(valve, c0, r0, n, ref, points=annulus)
    if body.signed_distance(valve.origin[None])[0] >= 0:
        return None
    loops = [q for q in loops if valve.signed_distance(q).mean() > 0]
    rings = [top - OVERHANG_MM * valve.normal, top] + [ring_from(q, n, ref) for q in loops]
    last = rings[-1]
    # the most apical section, moved along the stacking direction past the body's plane
    depth = -body.signed_distance(last).min() / max(float(n @ body.normal), 0.2) + 1.0
    if depth > 0:
        depth = min(depth, MAX_LENGTH_MM)
        runs = [np.asarray(r, float) for r in runs if len(r) >= 2]
        prev, h_prev = last, 0.0
        for h in np.arange(STEP_MM, depth, STEP_MM) if runs else ():
            ring = prev + (h - h_prev) * n
            level = float(ring.mean(axis=0) @ n)
            cut = np.concatenate([polyline_crossings(r, n, level) for r in runs])
            if len(cut):
                # the previous section stretched on: a wall no longer seen keeps its place
                prev, h_prev = ring_through_crossings(ring, n, cut), h
                rings.append(prev)
        # the end ring as the last stretched one (no crossings past the body's plane)
        rings.append(prev + (depth - h_prev) * n)
    stack = np.asarray(rings)
    centres = stack.mean(axis=1)
    levels = (centres - valve.origin) @ valve.normal
    radii = np.linalg.norm(stack - centres[:, None], axis=2).mean(axis=1)
    return OutflowTract(structure, valve, body, valve.normal, levels, centres, radii, ev,
                        rings=stack)


def offset_tract(endo: OutflowTract, epi_points: np.ndarray, structure: str = "rv_epi"
                 ) -> OutflowTract | None:
    """The epicardial tube of a tract: the endocardial tube's sections widened by the wall
    thickness (None when the epicardial points do not lie outside the lumen: their median
    distance outside it is not positive).

    A lofted tube (rings) is widened position by position round its rings by the local wall
    thickness the epicardial points give (:func:`ring_wall_thickness`): the RVOT has a free
    wall, but on its septal side the RV epicardial contours run on the lumen's wall (the LV
    epicardium, the aortic root), where a uniform widening would add a wall no contour
    shows. A tube of circles is widened by the median distance outside it.

    Parameters
    ----------
    endo : OutflowTract
        The lumen's tube.
    epi_points : ndarray, shape (n, 3)
        Epicardial contour points of the tract, in mm.
    structure : str, optional
        The new tube's structure.

    Returns
    -------
    OutflowTract or None
        The widened tube, None as above.
    """
    if endo.rings is not None:
        d = endo.distance(epi_points)
        d = d[np.isfinite(d)]
    else:
        d = -endo_signed_depth(endo, epi_points)
    wall = float(np.median(d)) if len(d) else 0.0
    if not wall > 0:
        return None
    rings = None
    if endo.rings is not None:
        local = ring_wall_thickness(endo.rings, np.asarray(epi_points, float))
        rings = offset_rings(endo.rings, local)
        wall = float(local.mean())
    return OutflowTract(structure, endo.valve, endo.body_plane, endo.axis, endo.levels,
                        endo.centres, endo.radii + wall, np.asarray(epi_points, float),
                        rings=rings)


def ring_normals(r: np.ndarray) -> np.ndarray:
    """(m, 3) unit outward normals, in its own plane, of a counter-clockwise ring's vertices.

    Parameters
    ----------
    r : ndarray, shape (m, 3)
        A closed planar ring, in mm.

    Returns
    -------
    ndarray, shape (m, 3)
        Unit outward normals.
    """
    nrm = fit_plane(r)[1]
    if polygon_area(r, nrm, signed=True) < 0:
        nrm = -nrm
    o = np.cross(np.roll(r, -1, axis=0) - np.roll(r, 1, axis=0), nrm)
    return o / np.maximum(np.linalg.norm(o, axis=1, keepdims=True), 1e-12)


def ring_wall_thickness(rings: np.ndarray, points: np.ndarray, window: int = WALL_WINDOW
                        ) -> np.ndarray:
    """(m,) wall thickness (mm) at each position round the rings (k, m, 3) of a lofted
    lumen, from epicardial points: each point's signed distance outside the lumen (to the
    nearest point of the rings, densely interpolated between them, along its outward
    normal; inside counts 0) is assigned to that point's ring position j; the thickness at
    j is the median over the points at positions within ``window`` of j (round the ring),
    and positions without points take the periodic linear interpolation of the others.
    The rings correspond position to position (:func:`ring_from`), so position j is one
    side of the tract along its length.

    Parameters
    ----------
    rings : ndarray, shape (k, m, 3)
        The lumen's lofted rings, in mm.
    points : ndarray, shape (n, 3)
        Epicardial points, in mm.
    window : int, optional
        Ring positions either side pooled for each median.

    Returns
    -------
    ndarray, shape (m,)
        Wall thickness at each ring position, in mm.
    """
    k, m = rings.shape[:2]
    w = np.linspace(0.0, 1.0, 5)[:-1]
    dense = np.concatenate([(1 - t) * rings[:-1] + t * rings[1:] for t in w] + [rings[-1:]])
    normals = np.stack([ring_normals(r) for r in dense])
    _, idx = cKDTree(dense.reshape(-1, 3)).query(points)
    near, out = dense.reshape(-1, 3)[idx], normals.reshape(-1, 3)[idx]
    depth = np.maximum(np.einsum("ij,ij->i", points - near, out), 0.0)
    pos = idx % m
    wall = np.full(m, np.nan)
    for j in range(m):
        sel = np.abs((pos - j + m // 2) % m - m // 2) <= window
        if sel.any():
            wall[j] = float(np.median(depth[sel]))
    have = np.flatnonzero(np.isfinite(wall))
    return np.interp(np.arange(m), have, wall[have], period=m)


def offset_rings(rings: np.ndarray, by) -> np.ndarray:
    """Each ring moved ``by`` mm outward in its own plane (vertex normals of the
    counter-clockwise ring); ``by`` a number or one value per ring position (m,).

    Parameters
    ----------
    rings : ndarray, shape (k, m, 3)
        Closed planar rings, in mm.
    by : float or ndarray, shape (m,)
        The outward offset, in mm.

    Returns
    -------
    ndarray, shape (k, m, 3)
        The moved rings, in mm.
    """
    by = np.broadcast_to(np.asarray(by, float), (rings.shape[1],))[:, None]
    return np.asarray([r + by * ring_normals(r) for r in rings])


def endo_signed_depth(t: OutflowTract, points: np.ndarray) -> np.ndarray:
    """Signed distance (mm) of points inside the tube from its wall, section by section
    (positive inside): the section radius at the point's level minus its distance from the
    section centre; points beyond the tube's ends are measured at the end sections.

    Parameters
    ----------
    t : OutflowTract
        A tube of circles.
    points : ndarray, shape (n, 3)
        Points in mm.

    Returns
    -------
    ndarray, shape (n,)
        Signed depth in mm (> 0 inside).
    """
    p = np.asarray(points, float)
    h = (p - t.valve.origin) @ t.axis
    c = np.column_stack([np.interp(h, t.levels, t.centres[:, i]) for i in range(3)])
    r = np.interp(h, t.levels, t.radii)
    q = p - c
    q = q - np.outer(q @ t.axis, t.axis)
    return r - np.linalg.norm(q, axis=1)


def outflow_tracts(study: Study, geo: FrameGeometry,
                   rv_neighbours: Sequence[OutflowTract | None] = ()
                   ) -> dict[str, OutflowTract]:
    """The outflow tubes one frame's evidence allows: ``rv_endo`` / ``rv_epi`` (RVOT lumen
    and outer wall) and ``lv_endo`` (LVOT lumen); {} without evidence (module docstring).

    Parameters
    ----------
    study : cardionurbs.study.Study
        The study (valve landmarks, outlet contours).
    geo : cardionurbs.anatomy.sections.FrameGeometry
        The frame's sections, valve planes and LA points.
    rv_neighbours : sequence of OutflowTract or None, optional
        The RVOT lumen tubes of the neighbouring frames, built without this argument: the
        lumen's radii are their median with this frame's (:func:`radii_in_time`), before
        its epicardial tube is widened from it.

    Returns
    -------
    dict of str to OutflowTract
        Structure -> tube, for the tracts the frame's evidence gives.
    """
    frame = geo.frame
    loops = outlet_loops(study, frame)
    out: dict[str, OutflowTract] = {}
    for s, (side, landmark) in TRACTS.items():
        body = geo.base_planes.get(side)
        if body is None or not geo.sections.get(s):
            continue
        annulus = np.array([lm.point for lm in study.landmarks_at(frame, landmark)])
        tract_loops = loops.get(s, []) if side == "rv" else []
        if len(annulus) == 0 and not loops.get("rv_endo" if side == "rv" else "none"):
            continue
        if s == "rv_epi":
            endo = out.get("rv_endo")
            if endo is None:
                continue
            ev = _tract_runs(geo, s, body, endo.valve.origin) + tract_loops
            if not ev:
                continue                # no epicardial evidence: no RVOT wall
            t = offset_tract(endo, np.concatenate(ev), s)
        elif tract_loops:               # SA outlet contours: loft through them
            ref = geo.reference if geo.reference is not None else in_plane_basis(geo.direction)[0]
            centre = annulus.mean(axis=0) if len(annulus) else \
                min(tract_loops, key=lambda r: float(body.signed_distance(r).mean())).mean(axis=0)
            t = loft_tract(s, annulus if len(annulus) else None, tract_loops, body,
                           geo.direction, ref, runs=_tract_runs(geo, s, body, centre))
        else:                           # valve landmarks and LA contour crossings
            runs = _tract_runs(geo, s, body, annulus.mean(axis=0))
            t = build_tract(s, annulus, runs, body, geo.direction)
            if t is not None and s == "rv_endo":
                t = radii_in_time(t, rv_neighbours)
        if t is not None:
            out[s] = t
    return out


#: fewest frames whose RVOT tubes are smoothed in time (:func:`radii_in_time`): a coarser
#: cine's neighbouring frames are too far apart (as the volume curve's check,
#: :data:`cardionurbs.anatomy.cycle.MIN_FRAMES`)
TIME_PRIOR_MIN_FRAMES = 16


def radii_in_time(own: OutflowTract, neighbours: Sequence[OutflowTract | None]
                  ) -> OutflowTract:
    """A tube of circles whose section radii are the median, level by level, of its own and
    its neighbouring frames' tubes (the same structure at the frames before and after).

    The tube's sections come from a few LA contour crossings and two or three valve
    landmarks, so from one frame to the next the same section may be crossed once or
    twice, and seen across or not: its radius jumps (8 vs 17 mm on bivme-patient1) where
    the tract has barely moved. The median of three frames keeps a radius two of them
    agree on; the tube's own axis, centres and length (its valve and the body's valve
    plane at this frame) are kept. The sections lie at the same levels along every
    tube's axis (every :data:`STEP_MM` from the valve); a shorter tube's last radius is
    held beyond its end, as its own interpolation does. Lofted tubes (``rings``, through
    SA outlet contours) and neighbours that are missing or lofted are left as they are.

    Parameters
    ----------
    own : OutflowTract
        This frame's tube.
    neighbours : sequence of OutflowTract or None
        The same structure's tubes at the neighbouring frames (None: none there).

    Returns
    -------
    OutflowTract
        ``own`` with the median radii (``own`` itself when nothing applies).
    """
    others = [t for t in neighbours if t is not None and t.rings is None]
    if own.rings is not None or len(others) < 2:
        return own
    k = len(own.levels)
    stack = [own.radii] + [np.interp(own.levels, t.levels, t.radii) for t in others]
    radii = np.median(np.asarray(stack)[:, :k], axis=0)
    return dataclasses.replace(own, radii=radii)
