"""Fit residuals: the distance of every contour point to the surface fitted through it.

The tables of :meth:`BiventricularModel.residual_table`, :meth:`~BiventricularModel.point_residuals`
and their numpy forms (what residuals.csv and the quality checks are made from); the model
keeps the per-point distances it computed (:meth:`BiventricularModel.point_residual_arrays`,
cached) and hands them to the functions here.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from cardionurbs import nurbs
from cardionurbs.anatomy.surfaces import free_wall_points

if TYPE_CHECKING:    # pandas (~0.3 s to import) only where a table is asked for
    import pandas as pd

#: columns of :func:`residual_table` (and residuals.csv)
RESIDUAL_COLUMNS = ("structure", "frame", "slice", "view", "n_points", "mean_mm", "max_mm",
                    "mean_px", "max_px")
#: columns of :func:`point_residuals`
POINT_COLUMNS = ["structure", "frame", "slice", "view", "dist_mm", "dist_px"]


def point_residual_parts(model: Any, frames: tuple[int, ...]) -> list[dict]:
    """Every contour point's distance to its surface at ``frames`` of a
    :class:`~cardionurbs.anatomy.model.BiventricularModel`, one dict per (frame, structure)
    in frame order: ``structure``, ``frame``, and per point ``slice`` (object array),
    ``view``, ``dist_mm`` (mm), ``dist_px`` (pixels of its image).

    SA points are the contour points of each slice (for the RV, the free wall: the
    septal part is the LV epicardium's); LA points are the LA contours. An RV point's
    distance is to the boundary of the RV solids, which the RV surface and the LV
    epicardium make together (RV cavity = RV endo − LV epi): the nearer of the two
    surfaces, so that the septal run of an LA RV contour, which lies on the LV
    epicardium, is measured where it lies; where a surface has an outflow tract, the
    nearer of the surface and the tract's wall.

    Parameters
    ----------
    model : BiventricularModel
        A model with its study's contours.
    frames : tuple of int
        The frames to measure.

    Returns
    -------
    list of dict
        One dict per (frame, structure): ``structure`` (str), ``frame`` (int) and per point
        ``slice`` (object array (P,)), ``view`` (object array (P,)), ``dist_mm`` (float array
        (P,), mm), ``dist_px`` (float array (P,), pixels).
    """
    parts = []
    for f in frames:
        geo = model.geometry[f]
        surfs = model.surfaces[f]
        for s, surf in surfs.items():
            items = [(sec.slice, "SA", free_wall_points(sec, geo.direction), _pixel_mm(sec.plane))
                     for sec in model.sections[f].get(s, []) if sec.source_points is not None]
            items += [(sl, "LA", pts, px) for sl, pts, px in
                      zip(geo.la_slices.get(s, []), geo.la_points.get(s, []),
                          geo.la_pixel_mm.get(s, []))]
            if not items:
                continue
            allp = np.concatenate([it[2] for it in items])
            d = surface_distance(surf, allp)
            if s.startswith("rv") and "lv_epi" in surfs:
                d = np.minimum(d, surface_distance(surfs["lv_epi"], allp))
            tract = model.outflow[f].get(s)
            if tract is not None:     # the outflow tract's wall is the surface there
                d = np.minimum(d, tract.distance(allp))
            n = [len(it[2]) for it in items]
            px = np.repeat([it[3] for it in items], n)
            parts.append({
                "structure": s, "frame": f,
                "slice": np.repeat(np.array([it[0] for it in items], dtype=object), n),
                "view": np.repeat([it[1] for it in items], n), "dist_mm": d,
                "dist_px": d / px})
    return parts


def residual_columns(parts: list[dict]) -> dict[str, np.ndarray]:
    """The columns of :func:`residual_table` as numpy arrays (no pandas), from
    :func:`point_residual_parts`: one row per contour, i.e. per (structure, frame, slice,
    view) in the order the contours come, points without a slice left out (as a pandas
    group-by leaves out a missing key). ``mean_*``: the correctly rounded sum of the
    contour's distances over their count (a pandas group-by mean, whose compensated sum
    can differ from it in the last digit).

    Parameters
    ----------
    parts : list of dict
        What :func:`point_residual_parts` returned.

    Returns
    -------
    dict of str to ndarray
        :data:`RESIDUAL_COLUMNS` -> one array (C,) per column, one entry per contour
        (``mean_mm``/``max_mm`` in mm, ``mean_px``/``max_px`` in pixels).
    """
    cols: dict[str, list] = {c: [] for c in RESIDUAL_COLUMNS}
    for p in parts:
        keys: dict[tuple, int] = {}
        group = np.empty(len(p["dist_mm"]), dtype=np.int64)
        sl, vw = p["slice"], p["view"]
        start = 0
        for stop in [*np.flatnonzero((sl[1:] != sl[:-1]) | (vw[1:] != vw[:-1])) + 1, len(sl)]:
            k = (sl[start], vw[start])         # one run of points of one contour
            group[start:stop] = -1 if k[0] is None else keys.setdefault(k, len(keys))
            start = stop
        if not keys:
            continue
        n = np.bincount(group[group >= 0], minlength=len(keys))
        for c, d in (("mm", p["dist_mm"]), ("px", p["dist_px"])):
            cols[f"mean_{c}"].append(_grouped_fsum(d, group, len(keys)) / n)
            mx = np.full(len(keys), -np.inf)
            np.maximum.at(mx, group[group >= 0], d[group >= 0])
            cols[f"max_{c}"].append(mx)
        cols["structure"].append(np.full(len(keys), p["structure"], dtype=object))
        cols["frame"].append(np.full(len(keys), p["frame"], dtype=np.int64))
        cols["slice"].append(np.array([k[0] for k in keys], dtype=object))
        cols["view"].append(np.array([k[1] for k in keys], dtype=object))
        cols["n_points"].append(n.astype(np.int64))
    empty = {"frame": np.int64, "n_points": np.int64, "structure": object, "slice": object,
             "view": object}
    return {c: (np.concatenate(v) if v else np.array([], dtype=empty.get(c, float)))
            for c, v in cols.items()}


def residual_table(parts: list[dict]) -> pd.DataFrame:
    """:func:`residual_columns` as a DataFrame (columns :data:`RESIDUAL_COLUMNS`).

    Parameters
    ----------
    parts : list of dict
        What :func:`point_residual_parts` returned.

    Returns
    -------
    pandas.DataFrame
        One row per contour, columns :data:`RESIDUAL_COLUMNS`.
    """
    import pandas as pd
    return pd.DataFrame(residual_columns(parts), columns=RESIDUAL_COLUMNS)


def point_residuals(parts: list[dict]) -> pd.DataFrame:
    """:func:`point_residual_parts` as one DataFrame (columns :data:`POINT_COLUMNS`).

    Parameters
    ----------
    parts : list of dict
        What :func:`point_residual_parts` returned.

    Returns
    -------
    pandas.DataFrame
        One row per contour point, columns :data:`POINT_COLUMNS` (distances in mm and pixels).
    """
    import pandas as pd
    if not parts:
        return pd.DataFrame([], columns=POINT_COLUMNS)
    return pd.concat([pd.DataFrame(p) for p in parts], ignore_index=True)[POINT_COLUMNS]


def _grouped_fsum(x: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Per group, the correctly rounded sum of ``x`` (:func:`math.fsum`; ``group`` -1:
    left out)."""
    keep = np.flatnonzero(group >= 0)
    order = keep[np.argsort(group[keep], kind="stable")]
    bounds = np.cumsum(np.bincount(group[keep], minlength=n_groups))[:-1]
    return np.array([math.fsum(part) for part in np.split(np.asarray(x, float)[order], bounds)])


def _pixel_mm(plane) -> float:
    return float(np.mean(plane.pixel_spacing)) if plane is not None else 1.0


def surface_distance(surface, points: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point to a NURBS surface (closest-point projection).

    Parameters
    ----------
    surface : NurbsSurface
        The surface.
    points : ndarray, shape (P, 3)
        Points, scanner mm.

    Returns
    -------
    ndarray, shape (P,)
        Each point's distance to the surface, mm.
    """
    res = nurbs.closest_points(surface, np.asarray(points, float))
    if isinstance(res, tuple):
        res = res[-1]
    res = np.asarray(res, float)
    if res.ndim == 2:  # closest points returned
        return np.linalg.norm(res - points, axis=1)
    return res
