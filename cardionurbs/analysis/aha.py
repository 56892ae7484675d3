"""AHA 17-segment model of the LV (Cerqueira et al., Circulation 105:539, 2002).

Axis and levels
    The long axis runs from the apex a to the centre b of the mitral valve
    plane (:func:`cardionurbs.geometry.long_axis`, the project's one rule,
    at the frame being segmented). A point's height is h = (x − a)·ê with ê = (b − a)/|b − a|.
    The apical cap (segment 17) is the myocardium beyond the end of the
    cavity, h < h_cap with h_cap the height of the LV endocardial apex; the
    rest, h_cap ≤ h ≤ |b − a|, is cut into three equal thirds perpendicular
    to the axis: apical, mid and basal. Points above the mitral plane get 0.

Angles
    θ is measured about the axis counter-clockwise as seen from the apex
    looking toward the base (right-handed about b → a, the METRICS sign of
    the tag rotations), from the septal centre θ_s. Basal (1–6) and mid
    (7–12) rings have six 60° segments, the apical ring (13–16) four 90°
    segments; in increasing θ::

        basal 1 anterior   [θ_s − 120°, θ_s − 60°)   apical 13 anterior [θ_s − 135°, θ_s − 45°)
              2 anteroseptal   [θ_s − 60°, θ_s)             14 septal   [θ_s − 45°, θ_s + 45°)
              3 inferoseptal   [θ_s, θ_s + 60°)              15 inferior [θ_s + 45°, θ_s + 135°)
              4 inferior       [θ_s + 60°, θ_s + 120°)       16 lateral  [θ_s + 135°, θ_s + 225°)
              5 inferolateral, 6 anterolateral (mid: 7–12 likewise)

    (in the standard short-axis display, seen from the apex with the septum on
    the left, anterior → anteroseptal → inferoseptal runs counter-clockwise).

Angular origin θ_s
    The septal centre: the bisector of the two RV insertion points, the
    anterior and inferior junctions of the RV wall with the LV epicardium.
    From ``rv_insert`` landmarks where the frame has them (the two angular
    clusters of the landmarks, split at their largest gap; θ_s the midpoint
    of the shorter arc between the cluster means); otherwise from the SA
    contours: on each slice with RV (epi-, else endocardial) and LV
    epicardial contours, the RV points on the LV epicardium
    (:func:`cardionurbs.anatomy.sections.septal_mask`) span the septum, and
    its angular midpoint is the slice's bisector; θ_s is the circular mean
    over slices. A frame with neither has no segments:
    :class:`cardionurbs.errors.SegmentError` says why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cardionurbs.anatomy.sections import septal_mask
from cardionurbs.analysis.tag_surfaces import axis_frame
from cardionurbs.errors import SegmentError
from cardionurbs.geometry import long_axis
from cardionurbs.study import Study

#: AHA segment names, 1..17
SEGMENT_NAMES = ("basal anterior", "basal anteroseptal", "basal inferoseptal", "basal inferior",
                 "basal inferolateral", "basal anterolateral",
                 "mid anterior", "mid anteroseptal", "mid inferoseptal", "mid inferior",
                 "mid inferolateral", "mid anterolateral",
                 "apical anterior", "apical septal", "apical inferior", "apical lateral", "apex")
N_SEGMENTS = 17
#: the endocardial apex (h = cap height) belongs to the apical cap, segment 17: its mesh vertex
#: lies at the cap height to rounding (1e-14 mm either side), so the cap is closed by this margin
CAP_TOL_MM = 1e-6


def circular_mean(angles: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Mean direction (rad) of angles (rad).

    Parameters
    ----------
    angles : (n,) ndarray
        Angles, rad.
    weights : (n,) ndarray or None
        Their weights; None: equal.

    Returns
    -------
    float
        The mean direction in (−π, π], rad.
    """
    a = np.asarray(angles, float)
    w = np.ones_like(a) if weights is None else np.asarray(weights, float)
    return float(np.arctan2((w * np.sin(a)).sum(), (w * np.cos(a)).sum()))


def wrap(angle) -> np.ndarray:
    """Angle(s) wrapped to [−π, π).

    Parameters
    ----------
    angle : float or ndarray
        Angle(s), rad.

    Returns
    -------
    ndarray
        The same shape, in [−π, π).
    """
    return (np.asarray(angle, float) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class AhaFrame:
    """The geometry the 17 segments are cut with at one frame (scanner mm, radians).

    Attributes
    ----------
    apex, base : (3,) ndarray
        The ends of the long axis (apex, mitral centre), mm.
    cap_height : float
        h of the LV endocardial apex (mm from the apex along the axis).
    septal_angle : float
        θ_s (rad) in the axis frame :func:`axis_frame` (apex, base).
    source : str
        How θ_s was found (``"rv_insert landmarks"`` or ``"RV contours"``).
    """

    apex: np.ndarray
    base: np.ndarray
    cap_height: float
    septal_angle: float
    source: str = ""

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.base - self.apex))

    def cylindrical(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(h mm along apex → base, θ rad from the septal centre in [−π, π), r mm from the axis).

        Parameters
        ----------
        points : (n, 3) ndarray
            Scanner points, mm.

        Returns
        -------
        h, theta, r : (n,) ndarray
            Height (mm), angle (rad), radius (mm).
        """
        e1, e2, e = axis_frame(self.apex, self.base)
        d = np.asarray(points, float).reshape(-1, 3) - self.apex
        h = -(d @ e)
        th = wrap(np.arctan2(d @ e2, d @ e1) - self.septal_angle)
        r = np.linalg.norm(d - np.outer(d @ e, e), axis=1)
        return h, th, r

    def segments(self, points: np.ndarray) -> np.ndarray:
        """AHA segment (1..17) of each (n, 3) point; 0 above the mitral plane.

        Parameters
        ----------
        points : (n, 3) ndarray
            Scanner points, mm.

        Returns
        -------
        (n,) ndarray of int
            The segment of each point (17: the apical cap).
        """
        h, th, _ = self.cylindrical(points)
        return segment_labels(h, th, self.cap_height, self.length)

    def to_dict(self) -> dict:
        """JSON-safe: apex and base (mm), ``cap_height_mm``, ``septal_angle_deg``, ``source``.

        Returns
        -------
        dict
        """
        return {"apex": [float(x) for x in self.apex], "base": [float(x) for x in self.base],
                "cap_height_mm": float(self.cap_height),
                "septal_angle_deg": float(np.degrees(self.septal_angle)), "source": self.source}


def segment_labels(h: np.ndarray, theta: np.ndarray, cap_height: float, length: float) -> np.ndarray:
    """AHA segments from height h (mm from the apex) and angle θ (rad from the septal centre,
    CCW seen from the apex); 0 beyond the base (h > length).

    Parameters
    ----------
    h : (n,) ndarray
        Height from the apex along the axis, mm.
    theta : (n,) ndarray
        Angle from the septal centre, rad.
    cap_height : float
        Height of the apical cap (segment 17), mm.
    length : float
        Axis length apex -> base, mm.

    Returns
    -------
    (n,) ndarray of int
        Segments 1..17 (17 where h <= cap_height, to :data:`CAP_TOL_MM`), 0 beyond the base.
    """
    h = np.asarray(h, float)
    t = np.mod(np.asarray(theta, float), 2 * np.pi)
    third = (length - cap_height) / 3.0
    ring = np.floor((h - cap_height) / third).astype(int)            # 0 apical, 1 mid, 2 basal
    six = np.floor(np.mod(t + np.radians(120.0), 2 * np.pi) / np.radians(60.0)).astype(int)   # 0 = seg 1
    four = np.floor(np.mod(t + np.radians(135.0), 2 * np.pi) / np.radians(90.0)).astype(int)  # 0 = seg 13
    out = np.where(ring >= 2, 1 + np.minimum(six, 5), np.where(ring == 1, 7 + np.minimum(six, 5),
                                                              13 + np.minimum(four, 3)))
    out = np.where(h < cap_height + CAP_TOL_MM, 17, out)     # the endocardial apex itself is in the cap
    return np.where(h > length + 1e-9, 0, out).astype(int)


def insertion_bisector(angles: np.ndarray) -> float:
    """θ_s (rad) from the angles of RV insertion points: the two clusters split at the largest
    angular gaps, θ_s the midpoint of the shorter arc between their circular means.

    Parameters
    ----------
    angles : (n,) ndarray
        Angles of the RV insertion points in the axis frame, rad (n >= 2).

    Returns
    -------
    float
        θ_s, rad.
    """
    a = np.sort(np.mod(np.asarray(angles, float), 2 * np.pi))
    if len(a) < 2:
        raise SegmentError("one RV insertion point: two (anterior and inferior) are needed")
    gaps = np.diff(np.r_[a, a[0] + 2 * np.pi])
    g1, g2 = np.argsort(gaps)[-2:]                     # the two largest gaps separate the clusters
    lo, hi = sorted((int(g1), int(g2)))
    c1 = a[lo + 1:hi + 1]
    c2 = np.r_[a[hi + 1:], a[:lo + 1]]
    if len(c1) == 0 or len(c2) == 0:
        raise SegmentError("the RV insertion points form one cluster: anterior and inferior "
                           "cannot be told apart")
    m1, m2 = circular_mean(c1), circular_mean(c2)
    d = float(wrap(m2 - m1))
    return float(wrap(m1 + d / 2.0))


def septal_angle_from_landmarks(study: Study, frame: int, apex, base) -> float | None:
    """θ_s from the frame's ``rv_insert`` landmarks, None without two of them.

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    apex, base : (3,) ndarray
        The long axis' ends, mm.

    Returns
    -------
    float or None
        θ_s, rad.
    """
    pts = [lm.point for lm in study.landmarks_at(frame, "rv_insert")]
    if len(pts) < 2:
        return None
    e1, e2, e = axis_frame(apex, base)
    d = np.asarray(pts, float) - apex
    return insertion_bisector(np.arctan2(d @ e2, d @ e1))


def septal_angle_from_contours(study: Study, frame: int, apex, base) -> float | None:
    """θ_s from the SA RV and LV epicardial contours of the frame (module docstring), None
    when no slice has both.

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    apex, base : (3,) ndarray
        The long axis' ends, mm.

    Returns
    -------
    float or None
        θ_s, rad.
    """
    e1, e2, e = axis_frame(apex, base)
    epi = {c.slice: c.points for c in study.contours_at(frame, "lv_epi", view="SA") if c.closed}
    rv: dict = {}
    for name in ("rv_endo", "rv_epi"):              # rv_epi wins: it meets the LV at the insertion
        for c in study.contours_at(frame, name, view="SA"):
            if c.slice in epi:
                rv[c.slice] = c.points
    mids, weights = [], []
    for s, pts in rv.items():
        nrm = np.linalg.svd(epi[s] - epi[s].mean(axis=0), full_matrices=False)[2][2]
        near = septal_mask(pts, epi[s], nrm, near_mm=1.0)
        if near.sum() < 2 or near.all():
            continue
        d = pts[near] - apex
        ang = np.arctan2(d @ e2, d @ e1)
        centre = circular_mean(ang)
        rel = wrap(ang - centre)
        mids.append(centre + 0.5 * (rel.min() + rel.max()))
        weights.append(1.0)
    if not mids:
        return None
    return circular_mean(np.asarray(mids), np.asarray(weights))


def aha_frame(study: Study, frame: int, apex: np.ndarray, base: np.ndarray,
              cap_height: float) -> AhaFrame:
    """The segment geometry of one frame; SegmentError when the frame has no RV data.

    Parameters
    ----------
    study : Study
        The study.
    frame : int
        The frame.
    apex, base : (3,) ndarray
        The long axis' ends, mm.
    cap_height : float
        Height of the LV endocardial apex above ``apex``, mm.

    Returns
    -------
    AhaFrame

    Raises
    ------
    SegmentError
        No ``rv_insert`` landmarks and no slice with RV and LV epicardial contours.
    """
    apex, base = np.asarray(apex, float), np.asarray(base, float)
    th = septal_angle_from_landmarks(study, frame, apex, base)
    source = "rv_insert landmarks"
    if th is None:
        th = septal_angle_from_contours(study, frame, apex, base)
        source = "RV contours"
    if th is None:
        raise SegmentError("no RV insertion landmarks and no SA RV contours "
                           "beside LV epicardial ones, so the AHA segments cannot be oriented",
                           frame=frame, field="rv_insert")
    return AhaFrame(apex, base, float(cap_height), float(th), source)


def model_aha_frame(model, frame: int) -> AhaFrame:
    """:func:`aha_frame` of a reconstructed model at ``frame``: the long axis of
    :func:`cardionurbs.geometry.long_axis` with that frame's landmarks and model apex and
    valve plane (at ED the model's own :meth:`long_axis`), the cap at the model's LV
    endocardial apex.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        The frame.

    Returns
    -------
    AhaFrame

    Raises
    ------
    SegmentError
        The frame has no RV data to place the septum.
    """
    if frame == model.ed_frame:
        apex, base = model.long_axis()
    else:
        ap = model.apex_points.get(frame, {})
        valve = model.base_planes.get(frame, {}).get("lv")
        apex, base = long_axis([lm.point for lm in model.study.landmarks_at(frame, "apex")],
                               [lm.point for lm in model.study.landmarks_at(frame, "mitral")],
                               model_apex=ap.get("lv_epi", ap.get("lv_endo")),
                               valve_origin=None if valve is None else valve.origin,
                               where=f"frame {frame}")
    endo_apex = model.apex_points[frame].get("lv_endo")
    ehat = (base - apex) / np.linalg.norm(base - apex)
    cap = max(float((np.asarray(endo_apex) - apex) @ ehat), 0.0) if endo_apex is not None else 0.0
    return aha_frame(model.study, frame, apex, base, cap)
