"""LV wall thickness and thickening per AHA segment (docs/metrics.md, Regional function).

Thickness at an endocardial point p is the distance along the outward unit
normal n of the endocardial NURBS surface to the epicardial NURBS surface:
the smallest t > 0 with p + t n = S_epi(u, v). All rays are solved at once
by Newton's method on (u, v, t) (residual S_epi(u, v) − p − t n, Jacobian
[S_u, S_v, −n]), started from the epicardial grid node nearest each ray on its
outward side (a k-d tree query at a few distances along the ray).

The endocardium is sampled on a regular (u, v) grid below the mitral plane;
each sample carries its surface area |S_u × S_v| Δu Δv, so a segment's
thickness is the area-weighted mean over the endocardial surface in that
segment (segment of the endocardial point, :mod:`cardionurbs.analysis.aha`).
``WT_Global`` is the mean of the 16 segment values; thickening per segment is
100 (WT_ES − WT_ED) / WT_ED and ``Thickening_Global`` the same of the global
values. Rays that miss the epicardium (beyond its rim at the base) are left
out.

The ray direction is the endocardial normal averaged over 6 mm of surface
(area-weighted): a ray tilted by α from the true normal crosses a wall of
thickness T over T / cos α ≈ T (1 + α²/2), so the scatter of the normals of a
surface fitted to noisy contours biases every thickness *up* (by ~0.3 mm at
end-systole with 0.5 px contour noise, where the wall is thickest); the disc is
small against the ≥ 20 mm radii of curvature of the LV wall, so a smooth
surface's normal is unchanged to < 0.1°.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from cardionurbs.analysis.aha import AhaFrame
from cardionurbs.analysis.strain import NORMAL_SMOOTHING_MM, smoothed_normals

NAN = float("nan")
WT_COLUMNS = tuple(f"WT_AHA_{k} (mm)" for k in range(1, 17)) + ("WT_Global (mm)",)
WT_ES_COLUMNS = tuple(f"WT_ES_AHA_{k} (mm)" for k in range(1, 17)) + ("WT_ES_Global (mm)",)
THICKENING_COLUMNS = tuple(f"Thickening_AHA_{k} (%)" for k in range(1, 17)) + ("Thickening_Global (%)",)
THICKNESS_COLUMNS = WT_COLUMNS + WT_ES_COLUMNS + THICKENING_COLUMNS


def surface_samples(surface, n_u: int = 96, n_v: int = 64, v_range=(0.0, 1.0)):
    """Points (k, 3), unit normals (k, 3) and area weights (k,) on a cell-centred (u, v) grid.

    Parameters
    ----------
    surface : NurbsSurface
        A surface, scanner mm.
    n_u, n_v : int
        Grid cells in u and v.
    v_range : (float, float)
        The v interval sampled.

    Returns
    -------
    points : (k, 3) ndarray
        Cell centres, mm.
    normals : (k, 3) ndarray
        Unit normals there.
    weights : (k,) ndarray
        Cell areas, mm².
    """
    du, dv = 1.0 / n_u, (v_range[1] - v_range[0]) / n_v
    u = (np.arange(n_u) + 0.5) * du
    v = v_range[0] + (np.arange(n_v) + 0.5) * dv
    D = surface.derivatives_grid(u, v, 1)                    # (n_u, n_v, 2, 2, 3)
    P, Su, Sv = D[..., 0, 0, :], D[..., 1, 0, :], D[..., 0, 1, :]
    n = np.cross(Su, Sv)
    a = np.linalg.norm(n, axis=-1)
    n = n / np.where(a > 0, a, 1.0)[..., None]
    return P.reshape(-1, 3), n.reshape(-1, 3), (a * du * dv).ravel()


def orient_outward(points: np.ndarray, normals: np.ndarray, apex: np.ndarray,
                   base: np.ndarray) -> np.ndarray:
    """Normals flipped, as a whole, to point away from the long axis on average.

    Parameters
    ----------
    points : (k, 3) ndarray
        Surface points, mm.
    normals : (k, 3) ndarray
        Their unit normals.
    apex, base : (3,) ndarray
        The long axis' ends, mm.

    Returns
    -------
    (k, 3) ndarray
        ``normals`` or ``-normals``.
    """
    e = (base - apex) / np.linalg.norm(base - apex)
    d = points - apex
    radial = d - np.outer(d @ e, e)
    return normals if float(np.einsum("ij,ij->", radial, normals)) >= 0 else -normals


def ray_surface_distance(surface, origins: np.ndarray, directions: np.ndarray,
                         grid: tuple[int, int] = (64, 48), iterations: int = 12,
                         tol_mm: float = 1e-3,
                         probe_mm: tuple[float, ...] = (1.0, 3.0, 6.0, 10.0, 15.0, 22.0)
                         ) -> np.ndarray:
    """Distance t (mm) along each unit ray origin + t·direction to a NURBS surface (the
    intersection nearest the start node on the ray's forward side); NaN where Newton does
    not land on the surface within ``tol_mm`` inside its parameter domain or t <= 0.

    Parameters
    ----------
    surface : NurbsSurface
        The target surface, scanner mm.
    origins : (n, 3) ndarray
        Ray starts, mm.
    directions : (n, 3) ndarray
        Unit ray directions.
    grid : (int, int)
        The (u, v) grid of start nodes.
    iterations : int
        Newton iterations.
    tol_mm : float
        Largest distance from the surface accepted, mm.
    probe_mm : tuple of float
        Distances along each ray where start nodes are looked for, mm.

    Returns
    -------
    (n,) ndarray
        t, mm (NaN where not found).
    """
    o = np.asarray(origins, float)
    d = np.asarray(directions, float)
    nu, nv = grid
    gu, gv = np.linspace(0, 1, nu, endpoint=False), np.linspace(0, 1, nv)
    Q = surface.evaluate(gu, gv).reshape(-1, 3)
    UU, VV = np.meshgrid(gu, gv, indexing="ij")
    uv_grid = np.column_stack([UU.ravel(), VV.ravel()])
    # start: of the grid nodes nearest to points along each ray, the one nearest the ray
    tree = cKDTree(Q)
    probes = np.asarray(probe_mm, float)
    _, idx = tree.query((o[:, None, :] + probes[None, :, None] * d[:, None, :]).reshape(-1, 3))
    idx = idx.reshape(len(o), len(probes))
    rel = Q[idx] - o[:, None, :]
    along = np.einsum("kmi,ki->km", rel, d)
    dist2 = np.einsum("kmi,kmi->km", rel, rel) - along * along
    start = idx[np.arange(len(o)), np.argmin(np.where(along > 0, dist2, np.inf), axis=1)]
    u, v = uv_grid[start, 0].copy(), uv_grid[start, 1].copy()
    t = np.einsum("ki,ki->k", Q[start] - o, d)
    closed = bool(getattr(surface, "closed_u", False))
    for _ in range(iterations):
        D = surface.derivatives(u, v, 1)
        S, Su, Sv = D[:, 0, 0], D[:, 1, 0], D[:, 0, 1]
        F = S - o - t[:, None] * d
        if float(np.abs(F).max(initial=0.0)) < 0.1 * tol_mm:
            break
        J = np.stack([Su, Sv, -d], axis=2)                      # (k, 3, 3)
        with np.errstate(all="ignore"):
            step = np.linalg.solve(J + 1e-12 * np.eye(3), -F[..., None])[..., 0]
        step = np.nan_to_num(step)
        step[:, :2] = np.clip(step[:, :2], -0.1, 0.1)
        u = np.mod(u + step[:, 0], 1.0) if closed else np.clip(u + step[:, 0], 0.0, 1.0)
        v = np.clip(v + step[:, 1], 0.0, 1.0)
        t = t + step[:, 2]
    S = surface.derivatives(u, v, 0)[:, 0, 0]
    res = np.linalg.norm(S - o - t[:, None] * d, axis=1)
    ok = (res < tol_mm) & (t > 0) & (v > 1e-6) & (v < 1 - 1e-6)
    return np.where(ok, t, np.nan)


def segment_means(values: np.ndarray, weights: np.ndarray, labels: np.ndarray,
                  segments=range(1, 17)) -> dict[int, float]:
    """Weighted mean of ``values`` per segment label (NaN values left out; NaN if empty).

    Parameters
    ----------
    values : (k,) ndarray
        Sample values.
    weights : (k,) ndarray
        Their weights (areas, mm²).
    labels : (k,) ndarray of int
        Their segment labels.
    segments : iterable of int
        The segments reported (AHA 1..16).

    Returns
    -------
    dict of int to float
    """
    out = {}
    for k in segments:
        m = (labels == k) & np.isfinite(values)
        out[k] = float(np.average(values[m], weights=weights[m])) if m.any() else NAN
    return out


def thickness_by_segment(endo, epi, aha: AhaFrame, base_plane=None,
                         samples: tuple[int, int] = (48, 36),
                         smoothing_mm: float = NORMAL_SMOOTHING_MM) -> tuple[dict[int, float], dict]:
    """Segment (1..16) -> mean wall thickness (mm) of one frame, and the samples
    (``points``, ``thickness``, ``segment``, ``weight``) for figures.

    ``endo``, ``epi``: NURBS surfaces (scanner mm); ``base_plane``: the mitral valve plane
    (normal apical) — endocardial samples beyond it are left out. The rays follow the
    endocardial normal averaged over ``smoothing_mm`` of surface
    (:func:`cardionurbs.analysis.strain.smoothed_normals`; 0: the raw NURBS normal), and the
    samples' ``normals`` are those averaged normals (``raw_normals``: the outward NURBS
    normals before averaging); ``grid``: ((n_u, n_v), the flat (u, v) grid index of each sample).

    Parameters
    ----------
    endo, epi : NurbsSurface
        The LV endo- and epicardial surfaces of one frame, scanner mm.
    aha : AhaFrame
        The frame's AHA segment frame (:mod:`cardionurbs.analysis.aha`).
    base_plane : Plane or None
        The mitral valve plane (normal apical).
    samples : (int, int)
        The (u, v) sample grid on the endocardium.
    smoothing_mm : float
        The normal-averaging radius, mm (0: the raw NURBS normal).

    Returns
    -------
    thickness : dict of int to float
        Segment -> mean wall thickness, mm (NaN where no ray lands).
    samples : dict
        The per-sample arrays above.
    """
    P, N, W = surface_samples(endo, *samples)
    N = orient_outward(P, N, aha.apex, aha.base)
    keep = np.ones(len(P), bool) if base_plane is None else base_plane.signed_distance(P) >= 0
    P, N, W = P[keep], N[keep], W[keep]
    raw = N
    if smoothing_mm > 0:
        N = smoothed_normals(P, N, W, smoothing_mm)
    t = ray_surface_distance(epi, P, N)
    lab = aha.segments(P)
    return segment_means(t, W, lab), {"points": P, "normals": N, "thickness": t, "segment": lab,
                                      "weight": W, "raw_normals": raw,
                                      "grid": (tuple(samples), np.flatnonzero(keep))}


def thickness_columns(ed: dict[int, float], es: dict[int, float]) -> dict[str, float]:
    """The WT, WT_ES and Thickening columns from per-segment thickness at ED and ES (mm).

    Parameters
    ----------
    ed, es : dict of int to float
        Segment -> mean wall thickness at ED and ES, mm.

    Returns
    -------
    dict of str to float
        docs/metrics.md column -> value (mm, %).
    """
    out: dict[str, float] = {}
    g_ed = float(np.nanmean([ed[k] for k in range(1, 17)])) if any(np.isfinite(list(ed.values()))) else NAN
    g_es = float(np.nanmean([es[k] for k in range(1, 17)])) if any(np.isfinite(list(es.values()))) else NAN
    for k in range(1, 17):
        out[f"WT_AHA_{k} (mm)"] = ed[k]
    out["WT_Global (mm)"] = g_ed
    for k in range(1, 17):
        out[f"WT_ES_AHA_{k} (mm)"] = es[k]
    out["WT_ES_Global (mm)"] = g_es
    for k in range(1, 17):
        out[f"Thickening_AHA_{k} (%)"] = 100.0 * (es[k] - ed[k]) / ed[k] if ed[k] else NAN
    out["Thickening_Global (%)"] = 100.0 * (g_es - g_ed) / g_ed if g_ed else NAN
    return out
