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
* **Stack normal and slice spacing** (:func:`cardionurbs.geometry.stack_normal`,
  :func:`cardionurbs.geometry.slice_spacing`): the mean sign-aligned normal; the
  median distance between consecutive slice positions along it, from
  ImagePositionPatient, never from SliceThickness.
"""

from __future__ import annotations

import numpy as np

#: LV base -> apex direction prior in patient LPS coordinates (left, anterior, inferior).
APEX_DIRECTION_LPS = np.array([1.0, -1.0, -1.0]) / np.sqrt(3.0)


def group_parallel(normals: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """Label (n,) groups of mutually parallel normals (sign ignored).

    Greedy: each normal joins the first group whose first member is within
    ``max_angle_deg`` of it (|cos| test), else starts a new group. Labels are
    numbered in order of first appearance.
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
    """Boolean (n,) mask of the slices forming the SA stack (see module docstring)."""
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

