"""Slice stacks: which slices form the short-axis stack, base-to-apex order, spacing.

Every reader (DICOM, GPFile) gets a set of slice planes and must decide which
ones are the short-axis (SA) stack and which are long-axis (LA) views, and in
which order the SA slices run. The rules here are shared so that a study
reads the same way from every format:

* **SA vs LA** (:func:`split_stack`): slices whose normals are parallel within
  ``stack_angle_deg`` (sign ignored) form a group; the largest group with at
  least two slices is the SA stack, every other slice is LA. A single slice
  alone is SA.
* **Base to apex** (:func:`base_to_apex_direction`): the unit stack normal
  ``u`` signed so that it points from the base towards the apex. When an apex
  landmark is known, ``u`` points towards it from the stack centre; else when
  mitral-valve points are known, ``u`` points away from their centre; else the
  anatomical prior in patient (LPS) coordinates is used: the LV long axis runs
  from base to apex towards the patient's left, anterior and inferior, i.e.
  along ``(+1, -1, -1) / sqrt(3)`` (L = +x, P = +y, S = +z in DICOM), which
  holds for every patient position (HFS, FFS, ...) because LPS is attached to
  the patient, not to the scanner.
* **Base and apex of a labelled stack** (:func:`sa_base_direction`): label maps
  show where each structure is absent, so the base is the end the anatomy says
  (:func:`base_end_from_anatomy`: cavity taper, RV towards the base, the
  myocardium closing over the apex, the LV outflow), never the slice order or
  the header's axes alone (ACDC's carry none); the mitral annulus of long-axis
  maps cross-checks it; conflicting evidence is refused.
* **Stack normal and slice spacing** (:func:`cardionurbs.geometry.stack_normal`,
  :func:`cardionurbs.geometry.slice_spacing`): the mean sign-aligned normal; the
  median distance between consecutive slice positions along it, from
  ImagePositionPatient, never from SliceThickness.
"""

from __future__ import annotations

import numpy as np

from cardionurbs.errors import ReconstructionError

#: LV base -> apex direction prior in patient LPS coordinates (left, anterior, inferior).
APEX_DIRECTION_LPS = np.array([1.0, -1.0, -1.0]) / np.sqrt(3.0)


def group_parallel(normals: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """Label (n,) groups of mutually parallel normals (sign ignored).

    Greedy: each normal joins the first group whose first member is within
    ``max_angle_deg`` of it (|cos| test), else starts a new group. Labels are
    numbered in order of first appearance.

    Parameters
    ----------
    normals : ndarray, shape (n, 3)
        Unit slice-plane normals.
    max_angle_deg : float
        Largest angle between parallel normals, in degrees.

    Returns
    -------
    ndarray of int, shape (n,)
        Group label of each normal, 0, 1, ... in order of first appearance.
    """
    normals = np.asarray(normals, float).reshape(-1, 3)
    cos_tol = np.cos(np.deg2rad(max_angle_deg))
    reps: list[np.ndarray] = []
    labels = np.empty(len(normals), dtype=int)
    for i, n in enumerate(normals):
        for g, r in enumerate(reps):
            if abs(float(n @ r)) >= cos_tol:
                labels[i] = g
                break
        else:
            labels[i] = len(reps)
            reps.append(n)
    return labels


def split_stack(normals: np.ndarray, stack_angle_deg: float = 20.0) -> np.ndarray:
    """Boolean (n,) mask of the slices forming the SA stack (see module docstring).

    Parameters
    ----------
    normals : ndarray, shape (n, 3)
        Unit slice-plane normals, one per slice.
    stack_angle_deg : float, optional
        Largest angle between the normals of one stack, in degrees (default 20).

    Returns
    -------
    ndarray of bool, shape (n,)
        True for the SA slices (all False when no two slices are parallel).
    """
    normals = np.asarray(normals, float).reshape(-1, 3)
    if len(normals) == 0:
        return np.zeros(0, dtype=bool)
    labels = group_parallel(normals, stack_angle_deg)
    counts = np.bincount(labels)
    best = int(np.argmax(counts))  # first of the largest groups
    if counts[best] < 2 and len(normals) > 1:
        return np.zeros(len(normals), dtype=bool)
    return labels == best


def base_to_apex_direction(normal: np.ndarray, centers: np.ndarray, *,
                           apex: np.ndarray | None = None,
                           mitral: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The stack normal signed from base to apex, and the rule that decided it.

    Returns ``(u, rule)`` with ``rule`` one of ``"apex landmark"``,
    ``"mitral landmarks"``, ``"LPS prior"`` (see module docstring).

    Parameters
    ----------
    normal : ndarray, shape (3,)
        The stack normal (either sign, any length but 0).
    centers : ndarray, shape (k, 3)
        The SA slice centres, in mm (scanner coordinates).
    apex : ndarray, shape (3,), optional
        An LV apex landmark, in mm.
    mitral : ndarray, shape (m, 3), optional
        Mitral valve landmarks, in mm.

    Returns
    -------
    u : ndarray, shape (3,)
        The unit stack normal pointing from base to apex.
    rule : str
        ``"apex landmark"``, ``"mitral landmarks"`` or ``"LPS prior"``.
    """
    u = np.asarray(normal, float) / np.linalg.norm(normal)
    centre = np.asarray(centers, float).reshape(-1, 3).mean(axis=0)
    if apex is not None and np.all(np.isfinite(apex)):
        d, rule = float((np.asarray(apex, float).reshape(3) - centre) @ u), "apex landmark"
    elif mitral is not None and len(np.asarray(mitral).reshape(-1, 3)):
        mc = np.asarray(mitral, float).reshape(-1, 3).mean(axis=0)
        d, rule = float((centre - mc) @ u), "mitral landmarks"
    else:
        d, rule = float(APEX_DIRECTION_LPS @ u), "LPS prior"
    return (u if d >= 0 else -u), rule



# --------------------------------------------------------------- base and apex from anatomy
#: a taper cue votes when its two halves differ by more than this share of their sum
TAPER_MIN_SHARE = 0.05
#: weights of the anatomical cues (:func:`base_end_from_anatomy`)
CUE_WEIGHTS = {"cavity taper": 1, "RV towards the base": 1, "myocardial cap": 2,
               "LV outflow": 2}
#: strong evidence on both sides (this much weight each way) is a conflict
CONFLICT_WEIGHT = 2


def _half_taper(area: np.ndarray) -> int:
    """+1 when the first half of a per-slice area profile holds clearly more area than the
    last half (the first end is the wider, basal one), -1 for the reverse, 0 when the two
    differ by less than ``TAPER_MIN_SHARE`` of their sum (the middle slice of an odd count
    is left out)."""
    a = np.asarray(area, float)
    h = len(a) // 2
    first, last = float(a[:h].sum()), float(a[len(a) - h:].sum())
    if h == 0 or first + last <= 0 or abs(first - last) <= TAPER_MIN_SHARE * (first + last):
        return 0
    return 1 if first > last else -1


def _end_vote(first: bool, last: bool, first_is: int) -> int:
    """The vote of a cue seen at the first and/or last end: ``first_is`` (+1: seen at the
    base, -1: seen at the apex) signed by which end shows it; 0 when both or neither."""
    if first == last:
        return 0
    return first_is if first else -first_is


def base_end_from_anatomy(lv: np.ndarray, myo: np.ndarray, rv: np.ndarray | None = None, *,
                          cap: tuple[bool, bool] = (False, False),
                          outflow: tuple[bool, bool] = (False, False)
                          ) -> tuple[int, dict[str, int]]:
    """Which end of a short-axis stack is the base, from what the labels show.

    Parameters
    ----------
    lv, myo : (k,) array
        LV cavity and LV myocardium area (any unit, summed over the labelled frames) of the
        k slices holding the LV, in stack order.
    rv : (k,) array or None
        RV cavity area of the same slices (None: no RV labelled).
    cap : (bool, bool)
        Whether the (first, last) labelled slice of some frame shows myocardium without
        cavity — the wall closing over the apex (a myocardial cap).
    outflow : (bool, bool)
        Whether the (first, last) labelled slice of some frame shows an LV cavity that the
        myocardium does not ring — the LV outflow tract or the cavity open to the atrium,
        which only the base shows.

    Returns
    -------
    end : int
        +1 when the first slice is the base, -1 when the last one is, 0 when the cues give
        no majority.
    votes : dict
        Each cue's vote (+1, -1, 0): "cavity taper" (the LV, cavity and wall, narrows
        towards the apex), "RV towards the base" (the RV cavity ends before the LV apex),
        "myocardial cap", "LV outflow"; weighted by ``CUE_WEIGHTS``.

    Raises
    ------
    ReconstructionError
        When ``CONFLICT_WEIGHT`` or more of the weighted evidence points each way.
    """
    votes = {"cavity taper": _half_taper(np.asarray(lv, float) + np.asarray(myo, float)),
             "RV towards the base": _half_taper(rv) if rv is not None else 0,
             "myocardial cap": _end_vote(*cap, first_is=-1),
             "LV outflow": _end_vote(*outflow, first_is=1)}
    pos = sum(CUE_WEIGHTS[k] for k, v in votes.items() if v > 0)
    neg = sum(CUE_WEIGHTS[k] for k, v in votes.items() if v < 0)
    if pos >= CONFLICT_WEIGHT and neg >= CONFLICT_WEIGHT:
        raise ReconstructionError("the short-axis stack's base and apex cannot be told apart: "
                                  + describe_votes(votes))
    return (1 if pos > neg else -1 if neg > pos else 0), votes


def describe_votes(votes: dict[str, int]) -> str:
    """One line naming which end each anatomical cue puts the base at.

    Parameters
    ----------
    votes : dict of str to int
        Cue -> vote (+1, -1, 0), as :func:`base_end_from_anatomy` returns them.

    Returns
    -------
    str
        ``"<cue>: base at the first slice; ..."``.
    """
    where = {1: "base at the first slice", -1: "base at the last slice", 0: "no say"}
    return "; ".join(f"{k}: {where[v]}" for k, v in votes.items())


def sa_base_direction(normal: np.ndarray, centers: np.ndarray, anatomy, *,
                      mitral: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The stack normal of a labelled SA stack signed from base to apex, and why.

    Parameters
    ----------
    normal : (3,) array
        The slices' plane normal (either sign).
    centers : (k, 3) array
        Slice centres (mm), in stack order.
    anatomy : StackAnatomy
        Per-slice label areas and end cues (:func:`cardionurbs.io.masks.stack_anatomy`).
    mitral : (m, 3) array or None
        Mitral annulus points from long-axis maps.

    Returns
    -------
    u : (3,) array
        Unit normal pointing from the base towards the apex.
    rule : str
        ``"anatomy (...)"``, ``"mitral landmarks"`` or ``"LPS prior"`` with the cues.

    Raises
    ------
    ReconstructionError
        When the cues conflict (:func:`base_end_from_anatomy`), or when they are decided
        and the mitral annulus of the long-axis maps lies at the other end.
    """
    u = np.asarray(normal, float) / np.linalg.norm(normal)
    centers = np.asarray(centers, float).reshape(-1, 3)
    held = np.flatnonzero((anatomy.lv + anatomy.myo) > 0)
    votes: dict[str, int] = {}
    end = 0
    if len(held) >= 2:
        rv = anatomy.rv[held] if anatomy.rv is not None else None
        end, votes = base_end_from_anatomy(anatomy.lv[held], anatomy.myo[held], rv,
                                           cap=anatomy.cap, outflow=anatomy.outflow)
        first, last = centers[held[0]], centers[held[-1]]
        if (last - first) @ u < 0:
            u = -u                                  # u now runs from the first labelled slice
    cues = describe_votes(votes) if votes else "fewer than two labelled slices"
    if mitral is not None and len(np.asarray(mitral).reshape(-1, 3)):
        um, _ = base_to_apex_direction(u, centers, mitral=mitral)
        if end and float(um @ u) * end < 0:
            raise ReconstructionError("the long-axis maps' mitral annulus lies at the end of "
                                      "the short-axis stack that its anatomy calls the apex ("
                                      + cues + ")")
        return um, f"mitral landmarks ({cues})"
    if end:
        return (u if end > 0 else -u), f"anatomy ({cues})"
    return base_to_apex_direction(u, centers)[0], f"LPS prior ({cues})"
