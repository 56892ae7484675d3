"""Regional LV function of a reconstructed model (docs/metrics.md, Regional function).

:func:`regional_metrics` gathers, for one model, the columns of
:data:`cardionurbs.analysis.regional_columns.REGIONAL_COLUMNS` that are not
global-volume based: wall thickness and thickening per AHA segment
(:mod:`cardionurbs.analysis.thickness`, on the AHA geometry of
:mod:`cardionurbs.analysis.aha`), Lagrangian strain from the tag material
points (:mod:`cardionurbs.analysis.strain`; over time when >= 3 frames are
tagged) and the contour-length strains (:mod:`cardionurbs.analysis.surface_strain`).
Each part that cannot be measured leaves its columns NaN and says why in
``notes``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from cardionurbs.analysis.aha import AhaFrame, model_aha_frame
from cardionurbs.analysis.strain import (DIRECTION_SMOOTHING_MM, STRAIN_COLUMNS, STRAIN_KINDS,
                                         cardiac_directions, myocardium_samples, smoothed_normals, tag_strain)
from cardionurbs.analysis.tag_motion import BOUNDARY_SAMPLES, Boundary, ed_tag_planes, frame_tag_points
from cardionurbs.analysis.surface_strain import SURFACE_STRAIN_COLUMNS, surface_strains
from cardionurbs.analysis.thickness import (THICKNESS_COLUMNS, surface_samples, thickness_by_segment,
                                            thickness_columns)
from cardionurbs.analysis.columns import ColumnMapping
from cardionurbs.errors import CardioNurbsError
from cardionurbs.parallel import fork_map

NAN = float("nan")
#: the thickness rays (one per ~3 mm of height) are split this many times along the long axis
#: for the tag strain's wall samples (:func:`~cardionurbs.analysis.strain.myocardium_samples`):
#: a sample per ~0.7 mm of height, so that a segment mean over the tagged height range is a
#: mean over whole slices of the wall
WALL_SUBDIVISION = 4


@dataclass
class RegionalMetrics(ColumnMapping):
    """Regional columns -> float (a read-only mapping), with the segment geometry per frame
    (``aha``: frame -> AhaFrame), the thickness samples per frame (``samples``) and ``notes``.

    Attributes
    ----------
    columns : dict of str to float
        Regional docs/metrics.md column -> value (mm, %, NaN where not measured).
    aha : dict of int to AhaFrame
        Frame -> its segment geometry.
    samples : dict of int to dict
        Frame -> the thickness samples (:func:`~cardionurbs.analysis.thickness.thickness_by_segment`).
    notes : list of str
        Why columns are null.
    strain : dict
        The ES tag strain fit's summary (segment strains, quality), empty without tags.
    over_time : dict of int to dict
        Tagged frame -> its strain summary.
    surface : dict
        The contour-based surface strains' details.
    """

    columns: dict[str, float]
    aha: dict[int, AhaFrame] = field(default_factory=dict)
    samples: dict[int, dict] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    strain: dict = field(default_factory=dict)          # ES fit summary (det F, counts, ...)
    over_time: dict[int, dict] = field(default_factory=dict)
    surface: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """JSON-safe summary for metrics.json (NaN -> None).

        Returns
        -------
        dict
        """
        def num(x):
            return None if x is None or not np.isfinite(x) else float(x)
        def clean(d):
            if isinstance(d, dict):
                return {str(k): clean(v) for k, v in d.items()}
            if isinstance(d, (list, tuple)):
                return [clean(v) for v in d]
            if isinstance(d, (float, np.floating)):
                return num(float(d))
            return d
        peak = {}
        if len(self.over_time) >= 3:
            for kind in STRAIN_KINDS:
                vals = [v["columns"][f"{kind}_Global (%)"] for v in self.over_time.values()]
                vals = [x for x in vals if np.isfinite(x)]
                if vals:
                    peak[f"{kind}_Global (%)"] = max(vals) if kind == "Err" else min(vals)
        return clean({"aha": {str(f): a.to_dict() for f, a in self.aha.items()},
                      "strain": {k: v for k, v in self.strain.items() if k != "columns"},
                      "strain_over_time": {f: {"det_F": v["det_F"],
                                               **{f"{k}_Global (%)": v["columns"][f"{k}_Global (%)"]
                                                  for k in STRAIN_KINDS}}
                                           for f, v in self.over_time.items()},
                      "strain_peak": peak, "surface_strain": self.surface,
                      "notes": list(self.notes)})


def wall_boundaries(model, frame: int, cache: dict | None = None) -> list[Boundary]:
    """The LV endo- and epicardial contours of ``frame`` (every view) with the same surface at
    the model's ED frame, sampled on a (u, v) grid (:data:`~cardionurbs.analysis.tag_motion.BOUNDARY_SAMPLES`)
    for the tag-line fit's boundary term; ``cache``: {structure: (samples, normals, their
    k-d tree)} shared between frames.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        The frame whose contours are taken.
    cache : dict or None
        Shared samples, filled in place.

    Returns
    -------
    list of Boundary
        One per structure that has contours at ``frame``.
    """
    cache = {} if cache is None else cache
    ed = model.surfaces[model.ed_frame]
    out = []
    for structure in ("lv_endo", "lv_epi"):
        pts = [c.points for c in model.study.contours_at(frame, structure)]
        if not pts or structure not in ed:
            continue
        if structure not in cache:
            samples, normals = surface_samples(ed[structure], *BOUNDARY_SAMPLES)[:2]
            cache[structure] = (samples, normals, cKDTree(samples))
        out.append(Boundary(np.vstack(pts), *cache[structure]))
    return out


def regional_metrics(model, tags=None, incompressibility: bool | str = "prior",
                     volume_prior_sd: float | None = None, boundaries: bool = True,
                     deformation=None, misfit_noise: bool = True,
                     jobs: int | None = 1) -> RegionalMetrics:
    """Regional columns of a model (wall thickness, tag and surface strain per AHA segment).

    Parameters
    ----------
    model, tags : BiventricularModel; TagMetrics or None
        The model, and its tag result (material points) when the study is tagged.
    incompressibility, volume_prior_sd : {"prior", "risk"} or bool; float or None
        How the tag-strain fit of noisy tags uses near-incompressibility
        (:func:`~cardionurbs.analysis.strain.tag_strain`): "prior" with the spread
        ``volume_prior_sd`` (None: the stated one); "risk" or False for comparison.
    boundaries, misfit_noise : bool
        The LV contours join the tag-line fit as material boundaries (:func:`wall_boundaries`);
        the fit's σ is the larger of the tracking noise and its misfit (False: comparisons).
    deformation : callable or None
        (points, frame) -> F replacing the fitted F in the strains (validation).
    jobs : int or None
        Processes for the strain over time, one fit per tagged frame (None: the usable CPUs).

    Returns
    -------
    RegionalMetrics
    """
    cols = {c: NAN for c in THICKNESS_COLUMNS + STRAIN_COLUMNS + SURFACE_STRAIN_COLUMNS}
    out = RegionalMetrics(cols)
    ed, es = model.ed_frame, model.es_frame
    try:
        surf_cols, out.surface = surface_strains(model)
        cols.update(surf_cols)
    except CardioNurbsError as exc:
        out.notes.append(f"surface strain not measured: {exc}")
    try:
        out.aha = {f: model_aha_frame(model, f) for f in dict.fromkeys((ed, es))}
    except CardioNurbsError as exc:
        out.notes.append(f"AHA segments not placed: {exc}")
        return out
    per = {}
    for f in dict.fromkeys((ed, es)):
        surf = model.surfaces[f]
        if "lv_endo" not in surf or "lv_epi" not in surf:
            out.notes.append(f"frame {f}: no LV epicardial surface; wall thickness not measured")
            return out
        per[f], out.samples[f] = thickness_by_segment(surf["lv_endo"], surf["lv_epi"], out.aha[f],
                                                      model.base_planes[f].get("lv"))
    cols.update(thickness_columns(per[ed], per[es]))
    material = getattr(tags, "material", None)
    if material is None or not len(material.triples):
        out.notes.append("no tag material points: Ecc, Ell, Err not measured")
        return out
    smp = out.samples[ed]
    P = smp["points"]
    N = smp["normals"]              # averaged over 6 mm by thickness_by_segment: the wall rays
    a = out.aha[ed]
    wall = myocardium_samples(P, N, smp["thickness"], smp["weight"], a.apex, a.base,
                              grid=smp["grid"], subdivide=WALL_SUBDIVISION)
    # the strain directions: the normals averaged over DIRECTION_SMOOTHING_MM; the wall samples'
    # directions and segments are the same at every frame
    N = smoothed_normals(P, smp["raw_normals"], smp["weight"], DIRECTION_SMOOTHING_MM)
    wall = (*wall, cardiac_directions(wall[0], P, N, a.apex, a.base), a.segments(wall[0]))
    frames = [f for f in material.frames if f != material.ed_frame]
    study = model.study
    flagged = {(fl.family, fl.index, fl.slice, fl.frame) for fl in getattr(tags, "flags", [])}
    planes = ed_tag_planes(study, material.ed_frame, flagged)
    ed_samples: dict[str, tuple] = {}
    if boundaries:                  # the ED surface samples' k-d trees, built before any fork
        wall_boundaries(model, es, ed_samples)

    def frame_strain(f: int) -> dict | None:
        ax = (out.aha[f].apex, out.aha[f].base) if f in out.aha else None
        lines = None
        if planes is not None:
            got = frame_tag_points(study, f, planes, flagged)
            if got is not None:
                lines = (got[0], planes.normals[got[1]], planes.offsets[got[1]])
        res = tag_strain(material, f, a.apex, a.base, P, N, a, axis=ax, myocardium=wall,
                         tag_lines=lines, noise_mm=planes.rms_mm if planes is not None else 0.0,
                         incompressibility=incompressibility, volume_prior_sd=volume_prior_sd,
                         boundary=wall_boundaries(model, f, ed_samples) if boundaries else (),
                         deformation=deformation, misfit_noise=misfit_noise)
        if res is not None and planes is not None:
            res["tag_noise_mm"] = planes.rms_mm
        return res

    # one independent fit per tagged frame: ES here, the others on worker processes
    for f, res in zip(frames, fork_map(frame_strain, frames, jobs=jobs, here={es})):
        if res is not None:
            out.over_time[f] = res
    if es in out.over_time:
        out.strain = out.over_time[es]
        cols.update(out.strain["columns"])
    else:
        out.notes.append(f"fewer than the material points needed at ES (frame {es}): "
                         "Ecc, Ell, Err not measured")
    if len(frames) < 2:
        out.over_time = {}
    return out
