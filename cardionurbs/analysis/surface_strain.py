"""Global strain without tags, from endocardial curve lengths (docs/metrics.md, Regional function).

``GLS surface (%)``
    100 (L_ES − L_ED) / L_ED of the LV endocardial contour length in each
    long-axis view (annulus → apex → annulus), averaged over the views that
    have the contour at both ED and ES.
``GCS surface (%)``
    The same for the LV endocardial circumference of the mid-ventricular SA
    slice: the slice whose ED contour centroid lies nearest, along the long
    axis, to the midpoint of the axis (apex → mitral centre at ED); the same
    slice at ES.

Named apart from the tag strains (``Ecc``/``Ell``): these are lengths of the
traced boundary, not of the same tissue (the boundary slides along the wall
and through the slice), so they work for cine-only and label-map studies.

Each contour is smoothed before its length is taken, so that tracing noise
does not lengthen it: every coordinate, as a function of the chord-length
parameter, by a cubic smoothing spline whose smoothing is chosen by
generalised cross-validation (:func:`scipy.interpolate.make_smoothing_spline`;
noise-free points are then followed closely, noisy ones smoothed); closed
contours are wrapped by a third of their points at each end so the seam is
smoothed like the rest. The length is that of the smoothed curve sampled 8
times more finely than the points.
"""

from __future__ import annotations

import numpy as np

from scipy.interpolate import make_smoothing_spline

from cardionurbs.study import Study

SURFACE_STRAIN_COLUMNS = ("GLS surface (%)", "GCS surface (%)")
NAN = float("nan")


def curve_length(points: np.ndarray, closed: bool, tol_mm: float | None = None) -> float:
    """Length (mm) of ordered contour points after GCV smoothing (module docstring)."""
    p = np.asarray(points, float)
    n = len(p)
    if closed:
        k = max(n // 3, 4)
        q = np.vstack([p[-k:], p, p[:k + 1]])
    else:
        k = 0
        q = p
    t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))]
    keep = np.r_[True, np.diff(t) > 1e-9]
    q, t = q[keep], t[keep]
    splines = [make_smoothing_spline(t, q[:, j]) for j in range(q.shape[1])]
    lo, hi = (t[k], t[k + n]) if closed else (t[0], t[-1])
    u = np.linspace(lo, hi, 8 * n + 1)
    s = np.column_stack([sp(u) for sp in splines])
    return float(np.linalg.norm(np.diff(s, axis=0), axis=1).sum())


def _tol(study: Study, contour) -> float:
    try:
        plane = study.slice_plane(contour.slice, contour.frame)
        return float(np.mean(plane.pixel_spacing))
    except Exception:  # noqa: BLE001 - a contour without its image: 1 mm
        return 1.0


def gls_surface(study: Study, ed: int, es: int) -> tuple[float, dict]:
    """GLS surface (%) and the per-view strains {view: %}."""
    views = {}
    la_ed = {c.slice: c for c in study.contours_at(ed, "lv_endo", view="LA")}
    for c in study.contours_at(es, "lv_endo", view="LA"):
        if c.slice in la_ed:
            l0 = curve_length(la_ed[c.slice].points, False, _tol(study, la_ed[c.slice]))
            l1 = curve_length(c.points, False, _tol(study, c))
            views[c.slice] = 100.0 * (l1 - l0) / l0
    return (float(np.mean(list(views.values()))) if views else NAN), views


def mid_sa_slice(study: Study, ed: int, apex: np.ndarray, base: np.ndarray) -> str | None:
    """The SA slice whose ED ``lv_endo`` centroid is nearest the axis midpoint, along the axis."""
    e = (base - apex) / np.linalg.norm(base - apex)
    mid = 0.5 * float((base - apex) @ e)
    best, gap = None, np.inf
    for c in study.contours_at(ed, "lv_endo", view="SA"):
        h = float((c.points.mean(axis=0) - apex) @ e)
        if abs(h - mid) < gap:
            best, gap = c.slice, abs(h - mid)
    return best


def gcs_surface(study: Study, ed: int, es: int, apex: np.ndarray, base: np.ndarray) -> tuple[float, str | None]:
    """GCS surface (%) and the mid slice it was measured on."""
    s = mid_sa_slice(study, ed, np.asarray(apex, float), np.asarray(base, float))
    if s is None:
        return NAN, None
    c0 = [c for c in study.contours_at(ed, "lv_endo", view="SA") if c.slice == s]
    c1 = [c for c in study.contours_at(es, "lv_endo", view="SA") if c.slice == s]
    if not c0 or not c1:
        return NAN, s
    l0 = curve_length(c0[0].points, True, _tol(study, c0[0]))
    l1 = curve_length(c1[0].points, True, _tol(study, c1[0]))
    return 100.0 * (l1 - l0) / l0, s


def surface_strains(model) -> tuple[dict[str, float], dict]:
    """Both columns of a model (its study, ED/ES and ED long axis), with details."""
    study, ed, es = model.study, model.ed_frame, model.es_frame
    gls, views = gls_surface(study, ed, es)
    apex, base = model.long_axis()
    gcs, sl = gcs_surface(study, ed, es, apex, base)
    return {"GLS surface (%)": gls, "GCS surface (%)": gcs}, {"gls_views": views, "gcs_slice": sl}
