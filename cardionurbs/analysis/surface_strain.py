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
does not lengthen it: a Whittaker smoother (penalised least squares,
minimise |z − y|² + λ |D² z|², D² second differences; cyclic for closed
contours) with λ = (2 sin(π Δ / L_c))⁻⁴, Δ the mean point spacing and
L_c = :data:`CUTOFF_MM`: its frequency response 1 / (1 + λ (2 sin(π Δ / L))⁴)
is one half at wavelength L_c, ~1 for the shape of a ventricle (wavelengths
of tens of mm) and small at the pixel scale of tracing noise (Eilers,
*Anal. Chem.* 75:3631, 2003). The length is that of the smoothed polyline.
"""

from __future__ import annotations

import numpy as np

from scipy import sparse
from scipy.sparse.linalg import spsolve

from cardionurbs.study import Study

SURFACE_STRAIN_COLUMNS = ("GLS surface (%)", "GCS surface (%)")
#: wavelength (mm) at which the contour smoother halves an undulation
CUTOFF_MM = 15.0
NAN = float("nan")


def whittaker_smooth(points: np.ndarray, closed: bool, cutoff_mm: float | None = None) -> np.ndarray:
    """Points (n, d) smoothed by the Whittaker smoother of the module docstring.

    Parameters
    ----------
    points : (n, d) ndarray
        Ordered points, mm.
    closed : bool
        Whether they form a loop.
    cutoff_mm : float or None
        The smoother's cut-off wavelength, mm; None: :data:`CUTOFF_MM`.

    Returns
    -------
    (n, d) ndarray
    """
    p = np.asarray(points, float)
    n = len(p)
    cutoff_mm = CUTOFF_MM if cutoff_mm is None else cutoff_mm
    seg = np.linalg.norm(np.diff(np.vstack([p, p[:1]]) if closed else p, axis=0), axis=1)
    step = float(seg.mean()) if len(seg) else 1.0
    if n < 5 or step <= 0 or step >= cutoff_mm / 2:
        return p
    lam = (2.0 * np.sin(np.pi * step / cutoff_mm)) ** -4
    eye = sparse.identity(n, format="csr")
    if closed:
        D = (sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n, n + 2)).tolil())
        D = D[:, :n] + sparse.hstack([sparse.csr_matrix((n, n - 2)), D[:, n:]]).tocsr()
    else:
        D = sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n))
    A = (eye + lam * (D.T @ D)).tocsc()
    return np.column_stack([spsolve(A, p[:, j]) for j in range(p.shape[1])])


def curve_length(points: np.ndarray, closed: bool, tol_mm: float | None = None) -> float:
    """Length (mm) of ordered contour points after smoothing (module docstring).

    Parameters
    ----------
    points : (n, 3) ndarray
        Ordered contour points, mm.
    closed : bool
        Whether they form a loop.
    tol_mm : float or None
        The contour's pixel tolerance, mm; not used by the smoothed length (the smoother's
        cut-off is fixed), kept for the callers that pass it.

    Returns
    -------
    float
        mm.
    """
    s = whittaker_smooth(points, closed)
    if closed:
        s = np.vstack([s, s[:1]])
    return float(np.linalg.norm(np.diff(s, axis=0), axis=1).sum())


def _tol(study: Study, contour) -> float:
    try:
        plane = study.slice_plane(contour.slice, contour.frame)
        return float(np.mean(plane.pixel_spacing))
    except Exception:  # noqa: BLE001 - a contour without its image: 1 mm
        return 1.0


def gls_surface(study: Study, ed: int, es: int) -> tuple[float, dict]:
    """GLS surface (%) and the per-view strains {view: %}.

    Parameters
    ----------
    study : Study
        The study.
    ed, es : int
        The ED and ES frames.

    Returns
    -------
    gls : float
        %, NaN without an LA view contoured at both frames.
    per_view : dict of str to float
        LA view -> its strain, %.
    """
    views = {}
    la_ed = {c.slice: c for c in study.contours_at(ed, "lv_endo", view="LA")}
    for c in study.contours_at(es, "lv_endo", view="LA"):
        if c.slice in la_ed:
            l0 = curve_length(la_ed[c.slice].points, False, _tol(study, la_ed[c.slice]))
            l1 = curve_length(c.points, False, _tol(study, c))
            views[c.slice] = 100.0 * (l1 - l0) / l0
    return (float(np.mean(list(views.values()))) if views else NAN), views


def mid_sa_slice(study: Study, ed: int, apex: np.ndarray, base: np.ndarray) -> str | None:
    """The SA slice whose ED ``lv_endo`` centroid is nearest the axis midpoint, along the axis.

    Parameters
    ----------
    study : Study
        The study.
    ed : int
        The ED frame.
    apex, base : (3,) ndarray
        The long axis' ends, mm.

    Returns
    -------
    str or None
        The slice id; None without SA lv_endo contours.
    """
    e = (base - apex) / np.linalg.norm(base - apex)
    mid = 0.5 * float((base - apex) @ e)
    best, gap = None, np.inf
    for c in study.contours_at(ed, "lv_endo", view="SA"):
        h = float((c.points.mean(axis=0) - apex) @ e)
        if abs(h - mid) < gap:
            best, gap = c.slice, abs(h - mid)
    return best


def gcs_surface(study: Study, ed: int, es: int, apex: np.ndarray, base: np.ndarray) -> tuple[float, str | None]:
    """GCS surface (%) and the mid slice it was measured on.

    Parameters
    ----------
    study : Study
        The study.
    ed, es : int
        The ED and ES frames.
    apex, base : (3,) ndarray
        The long axis' ends, mm.

    Returns
    -------
    gcs : float
        %, NaN without the mid slice at both frames.
    slice : str or None
        The mid slice.
    """
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
    """Both columns of a model (its study, ED/ES and ED long axis), with details.

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    columns : dict of str to float
        ``GLS surface (%)``, ``GCS surface (%)``.
    details : dict
        Per-view strains and the mid slice.
    """
    study, ed, es = model.study, model.ed_frame, model.es_frame
    gls, views = gls_surface(study, ed, es)
    apex, base = model.long_axis()
    gcs, sl = gcs_surface(study, ed, es, apex, base)
    return {"GLS surface (%)": gls, "GCS surface (%)": gcs}, {"gls_views": views, "gcs_slice": sl}
