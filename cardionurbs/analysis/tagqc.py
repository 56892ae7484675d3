"""Tag-jump QC: leave-one-out departure of each tag line from its tag surface.

"Tag jumping" (paper §4.2.3, Fig. 8): a 2D tracker assigns a tag line in
one slice to the neighbouring tag plane, so the lofted tag surface gets a
one-spacing step. For every tag (family, index) at every tagged frame, and
every slice (SA families) or view (``la``) showing it, we

1. loft the tag surface through the *other* slices' fitted curves
   (paper §3.2.4; for ``la`` the spoke fan of the other views);
2. cut that surface with the left-out image plane: for each ``u`` the
   ``v*`` where the surface crosses the plane (sign change on a parameter
   grid, one Newton step), or — beyond the first or last remaining slice —
   the linear extension S(u, v_end) + t·∂S/∂v;
3. measure each left-out tag point's in-plane distance from that trace,
   perpendicular to it (tangent ∂S/∂u − (∂S/∂u·n)/(∂S/∂v·n)·∂S/∂v), and
   take the median over the line, divided by the tag spacing.

Lines whose departure exceeds the threshold (0.5 spacing by default) are
flagged one at a time, worst first, and left out of the surface before the
rest are measured again (a jumped line also pulls the loft that predicts
its neighbours, by about half a spacing).

Tag spacing: ``study.meta["tag_spacing_mm"]`` when given, else estimated
per family and frame from neighbouring indices (median over slices of the
distance between consecutive tag lines' centroids across the lines,
divided by their index difference).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cardionurbs import nurbs
from cardionurbs.analysis.tag_surfaces import (TagSection, TagSurface, build_tag_surfaces,
                                               family_direction, fit_tag_curve, pixel_size)
from cardionurbs.study import TAG_FAMILIES, Study

DEFAULT_THRESHOLD = 0.5
_NU, _NV = 48, 64


@dataclass(frozen=True)
class TagFlag:
    """One tag line judged mistracked: departure in tag spacings from the others' surface."""

    family: str
    index: int
    slice: str
    frame: int
    departure: float

    def as_tuple(self) -> tuple:
        return (self.family, self.index, self.slice, self.frame, self.departure)


@dataclass(frozen=True)
class LineDeparture:
    """Leave-one-out departure of one tag line (every line, flagged or not)."""

    family: str
    index: int
    slice: str
    frame: int
    departure: float
    flagged: bool


# ---------------------------------------------------------------- geometry
def plane_trace(surface, origin: np.ndarray, normal: np.ndarray, periodic: bool = False,
                nu: int = _NU, nv: int = _NV) -> tuple[np.ndarray, np.ndarray]:
    """Points (k, 3) and unit tangents (k, 3) where a surface crosses a plane.

    For each of ``nu`` values of u, every sign change of the signed distance
    along a ``nv`` grid in v (wrapping when ``periodic``) is refined by one
    Newton step in v. For u where the surface does not reach the plane, the
    surface is extended linearly beyond its nearer v-boundary.
    """
    u = np.linspace(0.0, 1.0, nu)
    v = np.linspace(0.0, 1.0, nv)
    P = np.asarray(surface.evaluate(u, v))
    d = (P - origin) @ normal                                   # (nu, nv)
    if periodic:
        d_next = np.roll(d, -1, axis=1)
        v_next = np.roll(v, -1) + np.r_[np.zeros(nv - 1), 1.0]
        d, d_next, v0, v1 = d[:, :-1], d_next[:, :-1], v[:-1], v_next[:-1]
    else:
        d_next, v0, v1 = d[:, 1:], v[:-1], v[1:]
        d = d[:, :-1]
    cross = (d == 0) | (np.sign(d) != np.sign(d_next))
    iu, iv = np.nonzero(cross)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(d[iu, iv] != d_next[iu, iv], d[iu, iv] / (d[iu, iv] - d_next[iu, iv]), 0.0)
    uu = u[iu]
    vv = np.mod(v0[iv] + w * (v1[iv] - v0[iv]), 1.0) if periodic else v0[iv] + w * (v1[iv] - v0[iv])
    ext_u = np.empty(0)
    ext_v = np.empty(0)
    if not periodic:
        missing = np.setdiff1d(np.arange(nu), iu)
        if len(missing):
            full = (P - origin) @ normal
            # extend from the boundary nearer the plane
            end = np.where(np.abs(full[missing, 0]) < np.abs(full[missing, -1]), 0.0, 1.0)
            ext_u, ext_v = u[missing], end
    pts, tan = [], []
    if len(uu):
        from cardionurbs.analysis.material import surface_derivatives
        S, Su, Sv = surface_derivatives(surface, uu, vv)
        den = Sv @ normal
        ok = np.abs(den) > 1e-12
        dv = np.where(ok, -((S - origin) @ normal) / np.where(ok, den, 1.0), 0.0)
        vv2 = np.mod(vv + dv, 1.0) if periodic else np.clip(vv + dv, 0.0, 1.0)
        S, Su, Sv = surface_derivatives(surface, uu, vv2)
        pts.append(S - np.outer((S - origin) @ normal, normal))
        tan.append(_in_plane_tangent(Su, Sv, normal))
    if len(ext_u):
        from cardionurbs.analysis.material import surface_derivatives
        S, Su, Sv = surface_derivatives(surface, ext_u, ext_v)
        den = Sv @ normal
        den = np.where(np.abs(den) > 1e-12, den, 1e-12)
        t = -((S - origin) @ normal) / den
        Q = S + t[:, None] * Sv
        pts.append(Q - np.outer((Q - origin) @ normal, normal))
        tan.append(_in_plane_tangent(Su, Sv, normal))
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.vstack(pts), np.vstack(tan)


def _in_plane_tangent(Su: np.ndarray, Sv: np.ndarray, normal: np.ndarray) -> np.ndarray:
    den = Sv @ normal
    den = np.where(np.abs(den) > 1e-12, den, 1e-12)
    t = Su - ((Su @ normal) / den)[:, None] * Sv
    t -= np.outer(t @ normal, normal)
    return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)


def distance_to_trace(points: np.ndarray, trace: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point from the nearest trace point, across the trace's tangent."""
    if len(trace) == 0:
        return np.full(len(points), np.inf)
    diff = points[:, None, :] - trace[None]
    j = np.argmin((diff ** 2).sum(-1), axis=1)
    dd = diff[np.arange(len(points)), j]
    t = tangents[j]
    perp = dd - (dd * t).sum(1, keepdims=True) * t
    return np.linalg.norm(perp, axis=1)


# ------------------------------------------------------------------ spacing
def tag_spacing(study: Study, family: str, frame: int,
                sections: dict[int, list[TagSection]] | None = None) -> float:
    """Tag spacing (mm) of one family at one frame (see module docstring); NaN when unknown."""
    given = study.meta.get("tag_spacing_mm") if isinstance(study.meta, dict) else None
    if given:
        return float(given)
    lines = study.tags_at(frame, family)
    by_slice: dict[str, list] = {}
    for t in lines:
        by_slice.setdefault(t.slice, []).append(t)
    if not lines:
        return float("nan")
    d_fam = family_direction([t.points for t in lines])
    est = []
    for slc, ts in by_slice.items():
        if len(ts) < 2:
            continue
        plane = study.slice_plane(slc)
        if family == "la":
            across = d_fam_la = np.cross(plane.normal, family_direction([t.points for t in ts]))
            across = d_fam_la / np.linalg.norm(d_fam_la)
        else:
            across = np.cross(plane.normal, d_fam)
            across /= np.linalg.norm(across)
        idx = np.array([t.index for t in ts])
        pos = np.array([t.points.mean(axis=0) @ across for t in ts])
        order = np.argsort(idx)
        di, dp = np.diff(idx[order]), np.diff(pos[order])
        ok = di > 0
        if ok.any():
            est.append(np.median(np.abs(dp[ok]) / di[ok]))
    return float(np.median(est)) if est else float("nan")


# ----------------------------------------------------------------- LOO core
def _group_by_slice(sections: list[TagSection]) -> dict[str, list[TagSection]]:
    out: dict[str, list[TagSection]] = {}
    for s in sections:
        out.setdefault(s.slice, []).append(s)
    return out


def _raw_line(study: Study, family: str, index: int, slice_: str, frame: int) -> np.ndarray:
    for t in study.tags_at(frame, family):
        if t.index == index and t.slice == slice_:
            return np.asarray(t.points, float)
    return np.zeros((0, 3))


def loo_departures(study: Study, ts: TagSurface, spacing: float, px: float,
                   exclude: set[str] = frozenset()) -> dict[str, float]:
    """Leave-one-out departure (tag spacings) of each slice's line of one tag surface.

    ``exclude``: slices already flagged, left out of every loft. Returns
    {slice: departure}; slices that cannot be judged (too few others) absent.
    """
    groups = _group_by_slice(ts.sections)
    names = [s for s in groups if s not in exclude]
    min_others = 2
    out: dict[str, float] = {}
    if len(names) - 1 < min_others:
        return out
    for s in ts.sections:
        if s.curve is None:
            s.curve = fit_tag_curve(s.points, px)
    for left in names:
        others = [sec for sec in ts.sections if sec.slice != left and sec.slice not in exclude]
        curves = [sec.curve for sec in others]
        if ts.periodic_v:
            if len(curves) < 3:
                continue
            curves = curves + [curves[0]]
        surf = nurbs.loft(curves, degree_v=min(3, len(curves) - 1))
        plane = groups[left][0].plane
        trace, tan = plane_trace(surf, plane.position, plane.normal, periodic=ts.periodic_v)
        pts = _raw_line(study, ts.family, ts.index, left, ts.frame)
        if ts.periodic_v:   # judge the LV part the spokes describe
            pts = np.vstack([sec.points[1:] for sec in groups[left]])
        dist = distance_to_trace(pts, trace, tan)
        out[left] = float(np.median(dist) / spacing)
    return out


def tag_departures(study: Study, threshold: float = DEFAULT_THRESHOLD,
                   frames: list[int] | None = None, long_axis: tuple | None = None,
                   surfaces: dict | None = None) -> list[LineDeparture]:
    """Departure of every judgeable tag line, with the iterative worst-first flagging.

    See the module docstring. ``surfaces``: optional {frame: build_tag_surfaces(...)}.
    """
    frames = study.tagged_frames if frames is None else list(frames)
    px = pixel_size(study)
    out: list[LineDeparture] = []
    for f in frames:
        surfs = (surfaces or {}).get(f)
        if surfs is None:
            fams = TAG_FAMILIES if study.tags_at(f, "la") and _can_axis(study, long_axis) \
                else ("sa1", "sa2")
            surfs = build_tag_surfaces(study, f, long_axis, families=fams)
        spacing = {fam: tag_spacing(study, fam, f) for fam in TAG_FAMILIES}
        for (fam, idx), ts in sorted(surfs.items()):
            sp = spacing[fam]
            if not np.isfinite(sp) or sp <= 0:
                continue
            flagged: dict[str, float] = {}
            last: dict[str, float] = {}
            while True:
                dep = loo_departures(study, ts, sp, px, exclude=set(flagged))
                if not dep:
                    break
                last.update(dep)
                worst = max(dep, key=dep.get)
                if dep[worst] <= threshold:
                    break
                flagged[worst] = dep[worst]
            for slc, d in last.items():
                if slc in flagged:
                    d = flagged[slc]
                out.append(LineDeparture(fam, idx, slc, f, d, slc in flagged))
    return out


def _can_axis(study: Study, long_axis) -> bool:
    if long_axis is not None:
        return True
    return bool([lm for lm in study.landmarks if lm.name == "apex"]) and \
        bool([lm for lm in study.landmarks if lm.name == "mitral"])


def tag_qc(study: Study, threshold: float = DEFAULT_THRESHOLD, frames: list[int] | None = None,
           long_axis: tuple | None = None, surfaces: dict | None = None) -> list[TagFlag]:
    """Flag mistracked tag lines ("tag jumping") by leave-one-out lofting.

    Returns one :class:`TagFlag` (family, index, slice, frame, departure in
    tag spacings) per line whose departure from the surface lofted through
    the other slices of its tag exceeds ``threshold`` spacings, sorted by
    frame, family, index, slice.
    """
    deps = tag_departures(study, threshold, frames, long_axis, surfaces)
    flags = [TagFlag(d.family, d.index, d.slice, d.frame, d.departure) for d in deps if d.flagged]
    return sorted(flags, key=lambda x: (x.frame, x.family, x.index, x.slice))
