"""The biventricular model: NURBS surfaces per frame, closed meshes, volumes.

``reconstruct(study)`` builds, for every frame with LV endocardial contours,
the surfaces lv_endo, lv_epi, rv_endo, rv_epi (those the contours allow) in
scanner mm (:mod:`cardionurbs.anatomy.surfaces`), their valve planes and apex
points (:mod:`cardionurbs.anatomy.sections`), and finds ED and ES
(docs/metrics.md, Frames). Meshes and volumes follow lazily from the surfaces
(:mod:`cardionurbs.anatomy.mesh`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from functools import cached_property
from typing import TYPE_CHECKING

import manifold3d
import numpy as np

from cardionurbs import nurbs
from cardionurbs.anatomy import handback, serialise
from cardionurbs.anatomy import mesh as meshing
from cardionurbs.anatomy import residuals as fit_residuals
from cardionurbs.anatomy.cycle import (MIN_FRAMES, BasalSupport, CycleCheck, basal_edges,
                                       check_curve, interpolate, is_cyclic, support_basal,
                                       support_rv_basal, support_sections)
from cardionurbs.anatomy.mesh import Plane
from cardionurbs.anatomy.outflow import (TIME_PRIOR_MIN_FRAMES, OutflowTract, outflow_tracts,
                                         tract_solid)
from cardionurbs.anatomy.residuals import RESIDUAL_COLUMNS, surface_distance  # noqa: F401 (re-exported)
from cardionurbs.anatomy.sections import (MYO_CONSERVED_BOUND, SA_APEX_TAPER, SURFACES,
                                          FrameGeometry, frame_geometry,
                                          labelled_beyond_base_ml, labelled_myocardium_ratio,
                                          labels_do_not_conserve, moves_with_lv)
from cardionurbs.anatomy.refine import refine_surface
from cardionurbs.anatomy.surfaces import SurfaceFit, build_surface
from cardionurbs.cache import LazyFrames, memoized
from cardionurbs.errors import CardioNurbsError, ReconstructionError
from cardionurbs.geometry import long_axis, polygon_centroid
from cardionurbs.median import median
from cardionurbs.study import Study

if TYPE_CHECKING:    # trimesh (~0.3 s to import) only where meshes are made, pandas (~0.3 s)
    import pandas as pd    # only where a residual table is asked for
    import trimesh

MESHES = ("lv_cavity", "rv_cavity", "lv_myocardium", "rv_myocardium")
#: default tessellation (around, along) of each surface before the booleans
RESOLUTION = (56, 36)


def ed_es_frames(lv_volumes: dict[int, float], ed_label: int | None = None,
                 es_label: int | None = None) -> tuple[int, int]:
    """ED = frame of maximum, ES = frame of minimum LV cavity volume (docs/metrics.md);
    when exactly two frames are measured and both labels name them, the labels win.

    Parameters
    ----------
    lv_volumes : dict of int to float
        Frame -> LV cavity volume (mL); None or NaN frames are not used.
    ed_label, es_label : int or None
        The study's own ED and ES frames, when it names them.

    Returns
    -------
    (int, int)
        The ED and ES frames.

    Raises
    ------
    ReconstructionError
        No frame has a finite LV cavity volume.
    """
    vols = {f: v for f, v in lv_volumes.items() if v is not None and math.isfinite(v)}
    if not vols:
        raise ReconstructionError("no frame has an LV cavity volume: cannot find ED and ES")
    if (len(vols) == 2 and ed_label in vols and es_label in vols and ed_label != es_label):
        return int(ed_label), int(es_label)
    frames = sorted(vols)
    v = np.array([vols[f] for f in frames])
    return frames[int(np.argmax(v))], frames[int(np.argmin(v))]


def _reference_direction(study: Study, geo: FrameGeometry) -> np.ndarray:
    """In-plane direction from the LV towards the RV (start of every section's
    parameterisation); the first SA image's row direction when there is no RV."""
    n = geo.direction
    lv = geo.sections.get("lv_endo") or geo.sections.get("lv_epi") or []
    rv = geo.sections.get("rv_endo") or geo.sections.get("rv_epi") or []
    if lv and rv:
        d = (np.mean([polygon_centroid(s.points, n) for s in rv], axis=0)
             - np.mean([polygon_centroid(s.points, n) for s in lv], axis=0))
    else:
        sa = [im for im in study.images if im.view == "SA"]
        d = sa[0].row_cosine if sa else np.cross(n, np.eye(3)[np.argmin(np.abs(n))])
    d = d - (d @ n) * n
    return d / np.linalg.norm(d)


class BiventricularModel:
    """NURBS surfaces of the ventricles per frame, with meshes, volumes and residuals.

    Per-frame attributes are mappings frame -> value, computed on first access
    (:class:`cardionurbs.cache.LazyFrames`) when the model is reconstructed from a study;
    solids, meshes and the fit residuals are memoized methods (:mod:`cardionurbs.cache`).
    The residual tables are made by :mod:`cardionurbs.anatomy.residuals`, the dict form by
    :mod:`cardionurbs.anatomy.serialise`, and what worker processes build for the model
    comes back through :mod:`cardionurbs.anatomy.handback`.

    Attributes
    ----------
    study : Study
    frames : list of int
        Reconstructed frames (those with LV endocardial contours).
    surfaces : frame -> dict structure -> NurbsSurface
        structures ``lv_endo``, ``lv_epi``, ``rv_endo``, ``rv_epi`` (those present).
    sections : frame -> dict structure -> list of Section
        The SA sections (contours as ordered loops), base -> apex.
    apex_points : frame -> dict structure -> (3,) apex (collapsed end), mm.
    base_planes : frame -> {'lv': Plane, 'rv': Plane} valve planes (normal apical).
    volumes : frame -> dict mesh -> mL
    ed_frame, es_frame : int
    warnings : list of str

    Parameters
    ----------
    study : Study
        The study the model is of (scanner mm).
    frames : list of int
        The frames to model (each with LV endocardial contours).
    surfaces, base_planes, apex_points, outflow, sections : mapping or None
        Frame -> the per-frame values above (and the outflow tracts), given when the model
        is read back (:meth:`from_dict`); None: built from the study on first access.
    tol_px : float
        Curve-fit tolerance, pixels (paper §4.2.1).
    refine : bool
        Correct the LV surfaces towards the LA contour points (:mod:`cardionurbs.anatomy.refine`).
    anchor_weight : float
        Weight of the SA contour points against the LA points in that correction.
    ed_es : (int, int) or None
        The ED and ES frames of a model read back; None: chosen by the model's rule
        (:func:`ed_es_frames`).
    warnings : list of str or None
        Warnings carried over (a model read back).
    resolution : (int, int)
        Tessellation samples (around, along) of each surface's mesh.
    progress : callable or None
        Told ``(k, n)`` after each frame's LV cavity is built.
    jobs : int or None
        Processes for the frames' LV cavities (1: this one; None: the usable CPUs).
    """

    def __init__(self, study: Study, frames: list[int], *, surfaces: Mapping | None = None,
                 base_planes: Mapping | None = None, apex_points: Mapping | None = None,
                 outflow: Mapping | None = None,
                 sections: Mapping | None = None, tol_px: float = 1.0,
                 refine: bool = True, anchor_weight: float = 10.0,
                 ed_es: tuple[int, int] | None = None, warnings: list[str] | None = None,
                 resolution: tuple[int, int] = RESOLUTION, progress=None,
                 jobs: int | None = 1) -> None:
        self.study = study
        self.frames = list(frames)
        #: the frames of the volume curve: :attr:`frames` and those whose LV cavity could not
        #: be built (their volumes come from their neighbours, :mod:`cardionurbs.anatomy.cycle`)
        self.curve_frames = list(frames)
        self.tol_px = float(tol_px)
        self.refine, self.anchor_weight = bool(refine), float(anchor_weight)
        self.warnings = list(warnings or [])
        self.resolution = tuple(resolution)
        self._in_time: dict[int, dict] = {}         # a worker's frames' sections interpolated in time
        self._warned: set[tuple] = set()    # (frame, what) whose warnings a worker process gave
        #: each frame's geometry from its own contours; :attr:`geometry` adds the sections
        #: it lacks, interpolated in time (:func:`cardionurbs.anatomy.cycle.support_sections`)
        self.own_geometry = LazyFrames(self.frames, self._own_geometry)
        self.geometry = LazyFrames(self.frames, self._frame_geometry)
        if surfaces is None:          # reconstruct lazily from the study
            self.surfaces = LazyFrames(self.frames, self._all_surfaces)
            self.base_planes = LazyFrames(self.frames, lambda f: self.geometry[f].base_planes)
            self.apex_points = LazyFrames(self.frames, lambda f: {
                s: self.geometry[f].apex[s] for s in self._structures(f)})
            self.sections = LazyFrames(self.frames, lambda f: {
                s: self.geometry[f].sections[s] for s in self._structures(f)})
        else:                         # a deserialised model
            self.surfaces, self.base_planes = surfaces, base_planes
            self.apex_points, self.sections = apex_points, sections or {}
        #: frame -> {'rv_endo'|'rv_epi'|'lv_endo': OutflowTract} (anatomy.outflow); {} read back
        self.outflow = LazyFrames(self.frames, self._outflow) if surfaces is None else \
            LazyFrames(self.frames, lambda f: dict((outflow or {}).get(f, {})))
        self.volumes = LazyFrames(self.frames, lambda f: {
            k: meshing.volume_ml(m) + self._beyond_base_ml(f, k) for k, m in self.solids(f).items()})
        ed, es = self._choose_ed_es(study, ed_es, jobs, progress)
        self.ed_frame, self.es_frame = ed, es
        for f in getattr(self, "cycle", CycleCheck({}, {})).supported:
            self.warnings.append(self.cycle.describe(f))
        if ed == es:
            self.warnings.append(f"only one frame ({ed}) has LV contours: ED = ES, so SV, EF and the "
                                 "other ED-to-ES metrics are null")
        self.base_shift_mm: dict[int, float] = {}
        #: ES frame -> how far (mm, basally) the RV's half-slice plane followed the mitral
        #: landmarks' descent (:meth:`_follow_mitral_descent`)
        self.rv_base_shift_mm: dict[int, float] = {}
        if surfaces is None and ed != es:
            self._conserve_myocardium(ed, es)

    # ------------------------------------------------------------- ED and ES
    def _choose_ed_es(self, study: Study, ed_es: tuple[int, int] | None, jobs: int | None,
                      progress) -> tuple[int, int]:
        """ED and ES frames (docs/metrics.md, Frames): given, labelled, or from the volume curve.

        Parameters
        ----------
        study : Study
        ed_es : (int, int) or None
            Frames known beforehand (a deserialised model), used as they are.
        jobs, progress
            As for the constructor: the per-frame LV cavities of the ED/ES search.

        Returns
        -------
        (int, int)
            The ED and ES frame indices. Sets :attr:`lv_volume_by_frame` and :attr:`cycle`
            (:mod:`cardionurbs.anatomy.cycle`) when the volume curve was searched.
        """
        labels = (study.ed_frame, study.es_frame)
        if ed_es is None and len(self.frames) == 2 and set(labels) == set(self.frames):
            ed_es = labels                # docs/metrics.md: two contoured frames, the labels win
        given = set(study.meta.get("ed_es_given") or ())
        if ed_es is None and given == {"ED", "ES"} and set(labels) <= set(self.frames):
            ed_es = labels                # docs/metrics.md: frames the user names are used as given
        if ed_es is not None:            # known (labels, or a deserialised model)
            ed, es = int(ed_es[0]), int(ed_es[1])
        else:
            if isinstance(self.surfaces, LazyFrames):
                lv = self._corrected_cavity_volumes(
                    handback.unrefined_cavity_volumes(self, jobs, progress))
            else:
                lv = {f: meshing.volume_ml(self.lv_cavity_solid(f)) for f in self.frames}
            self.lv_volume_by_frame = lv      # the per-frame LV cavity volumes (mL), raw
            self.cycle = check_curve(lv, contours=self._lv_contour_counts(lv),
                                     basal=self._basal_support(lv))
            failed = [f for f, v in lv.items() if not math.isfinite(v)]
            if failed:
                self._drop_frames(failed)
            ed, es = ed_es_frames({f: self.cycle.consistent[f] for f in self.frames},
                                  study.ed_frame, study.es_frame)
            if "ED" in given and study.ed_frame in lv:      # one frame named by the user
                ed = int(study.ed_frame)
            if "ES" in given and study.es_frame in lv:
                es = int(study.es_frame)
        return ed, es

    def _basal_support(self, lv: dict[int, float]) -> dict[int, BasalSupport]:
        """The frames at an edge of a basal slice's run whose basal region their neighbours
        support (:func:`cardionurbs.anatomy.cycle.support_basal`); {} for a model read back."""
        if not isinstance(self.surfaces, LazyFrames) or len(lv) < MIN_FRAMES:
            return {}
        stacks = {}
        for f, v in lv.items():
            if math.isfinite(v):
                geo = self.geometry[f]
                stacks[f] = [sec.slice for sec in geo.sections.get("lv_endo") or []
                             if sec.slice is not None]
        finite = np.array([v for v in lv.values() if math.isfinite(v)])
        ref, edges = basal_edges(stacks, sorted(lv), is_cyclic(finite))
        if ref is None or not edges:
            return {}
        return support_basal(lv, edges, ref, lambda f: lv[f] - self._lv_apical_ml(f, ref))

    def _lv_apical_ml(self, frame: int, slice_id: str) -> float:
        """One frame's LV cavity (mL) on the apical side of an SA slice's plane (NaN when
        the frame has no section of its LV endocardium there)."""
        geo = self.geometry[frame]
        sec = next((x for x in geo.sections.get("lv_endo") or [] if x.slice == slice_id), None)
        if sec is None:
            return math.nan
        v, f = self._capped_tessellation(self._surface(frame, "lv_endo"))
        return meshing.clipped_volume(v, f, Plane(sec.points.mean(axis=0), geo.direction)) / 1000.0

    def _unrefined_or_nan(self, frame: int) -> float:
        """:meth:`lv_cavity_volume_unrefined`, NaN with a warning when the frame's LV
        endocardium cannot be built (its neighbours then support it, :mod:`.cycle`)."""
        try:
            return self.lv_cavity_volume_unrefined(frame)
        except ReconstructionError as exc:
            self.warnings.append(f"frame {frame}: LV cavity cannot be built ({exc}); the frame "
                                 "is left out of the model")
            return math.nan

    def _lv_contour_counts(self, lv: dict[int, float]) -> dict[int, int]:
        """Per built frame, the SA sections and LA contours its LV endocardium comes from
        (the evidence of an incomplete frame, :func:`cardionurbs.anatomy.cycle.check_curve`)."""
        return {f: self._lv_contour_count(f) for f, v in lv.items() if math.isfinite(v)}

    @memoized
    def _lv_contour_count(self, frame: int) -> int:
        """SA sections + LA contours of one frame's LV endocardium, negative when a contour
        of it was left out (a partial tracing): such a frame counts as incomplete."""
        geo = self.geometry[frame]
        n = len(geo.sections.get("lv_endo") or []) + len(geo.la_points.get("lv_endo") or [])
        n -= sum(s == "lv_endo" for s, _ in geo.in_time)      # interpolated in time: not its own
        lacks = any(s == "lv_endo" for s, _, _ in geo.left_out) or any(s == "lv_endo" for s, _ in geo.in_time)
        return -n if lacks else n

    def _drop_frames(self, frames: list[int]) -> None:
        """Leave out of the model the frames whose LV cavity cannot be built (they stay on
        the volume curve, :attr:`curve_frames`, supported by their neighbours)."""
        if len(frames) == len(self.frames):
            raise ReconstructionError(f"study {self.study.subject}: no frame's LV cavity can be "
                                      f"built ({self.warnings[-1] if self.warnings else ''})")
        self.frames = [f for f in self.frames if f not in frames]
        for lazy in vars(self).values():
            if isinstance(lazy, LazyFrames):
                lazy.drop(frames)

    def _corrected_cavity_volumes(self, unrefined: dict[int, float]) -> dict[int, float]:
        """Every frame's LA-corrected LV cavity volume (mL; what the volume curve reports,
        :meth:`lv_cavity_volume`), the unrefined one where the correction fails."""
        lv = {}
        for f in self.frames:
            if not math.isfinite(unrefined[f]):
                lv[f] = unrefined[f]
                continue
            try:
                lv[f] = self._clipped_lv_ml(f)
            except CardioNurbsError:
                lv[f] = unrefined[f]
        return lv

    @property
    def supported(self) -> dict[int, list[int]]:
        """Frames whose volumes come from their neighbours (:mod:`cardionurbs.anatomy.cycle`):
        frame -> the frames they are interpolated from; {} for a model read back."""
        cycle = getattr(self, "cycle", None)
        return dict(cycle.supported) if cycle is not None else {}

    @property
    def sections_in_time(self) -> dict[int, dict[tuple[str, str], tuple[int, int]]]:
        """Frames with sections interpolated in time (:func:`.cycle.support_sections`):
        frame -> {(surface, slice): (frame before, frame after)}."""
        geo = getattr(self, "geometry", None)
        out = {f: d for f, d in self._in_time.items() if d} if hasattr(self, "_in_time") else {}
        for f in (geo.computed if isinstance(geo, LazyFrames) else []):
            if geo[f].in_time:
                out[f] = geo[f].in_time
        return dict(sorted(out.items()))

    def consistent_volumes(self, frame: int) -> dict[str, float]:
        """The volumes (mL, keyed like :attr:`volumes`) the metrics use at one frame: its own
        (the RV cavity with its basal region from its neighbours where
        :meth:`rv_basal_support` says so), or for a supported frame those of its nearest
        trusted neighbour on each side interpolated linearly to it
        (:func:`cardionurbs.anatomy.cycle.interpolate`: two frames' solids, not four), the
        LV cavity from the checked curve (the cubic).

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        dict of str to float
            Volume name (as :attr:`volumes`) -> mL.
        """
        src = self.supported.get(frame)
        if src is None:
            if frame not in self.frames:
                return {}
            out = dict(self.volumes[frame])
            rv = self.rv_basal_support(frame)
            if rv is not None:
                out["rv_cavity"] = rv.total
            return out
        near = src[1:3]             # the nearest trusted frame on each side: linear in time
        keys = set().union(*(self.volumes[g] for g in near))
        curve = self.curve_frames
        out = {k: interpolate({g: self.volumes[g].get(k, math.nan) for g in near}, curve,
                              near, frame, self.cycle.cyclic) for k in sorted(keys)}
        out["lv_cavity"] = self.cycle.consistent[frame]
        return {k: v for k, v in out.items() if math.isfinite(v)}

    @memoized
    def rv_basal_support(self, frame: int) -> BasalSupport | None:
        """How one frame's RV cavity basal to the RV's reference slice is supported by its
        neighbours (:func:`cardionurbs.anatomy.cycle.support_rv_basal`; None when it keeps
        its own, and for a model read back). A supported frame adds one warning.

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        BasalSupport or None
            ``total`` the RV cavity volume used (mL).
        """
        edges = self._rv_basal_edges()
        if edges is None or frame not in edges[1] or frame not in self.frames:
            return None
        ref, edge = edges
        vol = self.volumes[frame].get("rv_cavity", math.nan)
        cycle = getattr(self, "cycle", None)
        out = support_rv_basal(frame, self.frames, edge, ref, vol,
                               lambda g: self._rv_basal_ml(g, ref),
                               cyclic=bool(cycle is not None and cycle.cyclic))
        if out is not None:
            self.warnings.append(
                f"frame {frame} RV supported by its neighbours' basal region: {out.why}; its RV "
                f"cavity basal to slice {ref} {out.basal:.1f} mL departs "
                f"{out.basal - out.used:+.1f} mL from frames {', '.join(map(str, out.sources))} "
                f"({out.used:.1f} mL), so {out.total:.1f} mL used instead of {out.own:.1f}")
        return out

    @memoized
    def _rv_basal_edges(self) -> tuple[str, dict[int, str]] | None:
        """(reference slice, frame -> why) of the RV endocardial stacks
        (:func:`cardionurbs.anatomy.cycle.basal_edges`); None for a model read back, a cine
        of fewer than :data:`MIN_FRAMES` frames, or no edge (cached)."""
        if not isinstance(self.surfaces, LazyFrames) or len(self.frames) < MIN_FRAMES:
            return None
        stacks = {f: [sec.slice for sec in self.geometry[f].sections.get("rv_endo") or []
                      if sec.slice is not None] for f in self.frames}
        if not all(stacks.values()):
            return None
        cycle = getattr(self, "cycle", None)
        ref, edges = basal_edges(stacks, self.frames, bool(cycle is not None and cycle.cyclic))
        return None if ref is None or not edges else (ref, edges)

    def _rv_basal_ml(self, frame: int, slice_id: str) -> float:
        """One frame's RV cavity (mL) on the basal side of an SA slice's plane (NaN when
        the frame has no RV cavity or no RV endocardial section there)."""
        geo = self.geometry[frame]
        sec = next((x for x in geo.sections.get("rv_endo") or [] if x.slice == slice_id), None)
        cav = self.solids(frame).get("rv_cavity") if frame in self.frames else None
        if sec is None or cav is None:
            return math.nan
        n = np.asarray(geo.direction, float)
        apical = cav.trim_by_plane(n, float(sec.points.mean(axis=0) @ n))
        return (cav.volume() - apical.volume()) / 1000.0

    def own_lv_cavity_volume(self, frame: int) -> float:
        """:meth:`lv_cavity_volume` from the frame's own contours, without the sections
        interpolated in time (:attr:`sections_in_time`); NaN when those cannot be built.

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        float
            LV cavity volume, mL (NaN when it cannot be built).
        """
        if frame not in self.sections_in_time:
            return self.lv_cavity_volume(frame)
        geo = self.own_geometry[frame]
        try:
            surface = build_surface(geo, "lv_endo", geo.reference, tol_px=self.tol_px).surface
            return self._clipped_cavity_ml(frame, self._refined(geo, "lv_endo", surface)
                                           if self.refine else surface)
        except CardioNurbsError:
            return math.nan

    def consistent_lv_cavity_volume(self, frame: int) -> float:
        """:meth:`lv_cavity_volume`, or the checked curve's value at a supported frame (mL).

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        float
            LV cavity volume, mL.
        """
        if frame in self.supported:
            return self.cycle.consistent[frame]
        return self.lv_cavity_volume(frame) if frame in self.frames else math.nan

    # ------------------------------------------------------------- lazy construction
    def _own_geometry(self, frame: int) -> FrameGeometry:
        geo = frame_geometry(self.study, frame)
        geo.reference = _reference_direction(self.study, geo)
        if geo.base_from_slices and self.study.meta.get("sa_apex") != SA_APEX_TAPER:
            base_between_slices(self.study, geo)          # hand contours (label maps: their slab)
        return geo

    def _frame_geometry(self, frame: int) -> FrameGeometry:
        geo = support_sections(frame, self.own_geometry, self.curve_frames)
        if (frame, "geometry") not in self._warned:
            self.warnings += geo.warnings
        return geo

    def _outflow(self, frame: int) -> dict[str, OutflowTract]:
        return outflow_tracts(self.study, self.geometry[frame],
                              [self._own_tracts(g).get("rv_endo") for g in self._rv_neighbours(frame)])

    @memoized
    def _own_tracts(self, frame: int) -> dict[str, OutflowTract]:
        """One frame's outflow tubes from its own evidence alone (no neighbours; cached)."""
        return outflow_tracts(self.study, self.geometry[frame])

    def _rv_neighbours(self, frame: int) -> list[int]:
        """The frames before and after ``frame`` whose RVOT tubes smooth its own in time
        (:func:`cardionurbs.anatomy.outflow.radii_in_time`): both adjacent frames of a cine of
        :data:`~cardionurbs.anatomy.outflow.TIME_PRIOR_MIN_FRAMES` frames or more, when the
        model has both; [] otherwise (the ends of the cine, a coarser one)."""
        frames = self.frames
        if len(self.curve_frames) < TIME_PRIOR_MIN_FRAMES or frame not in frames:
            return []
        i = frames.index(frame)
        if i == 0 or i == len(frames) - 1 or frames[i + 1] - frames[i - 1] != 2:
            return []
        return [frames[i - 1], frames[i + 1]]

    @memoized
    def _tract_part(self, frame: int, structure: str):
        """The outflow tube of one surface trimmed to its tract (cached; None without one):
        the apical side of the outflow valve plane (the RV epicardial tube: of the
        pulmonary plane of the endocardial one) and the basal side of the body's valve
        plane, overlapping the body by 0.01 mm so that the union has no coplanar faces
        (docs/metrics.md, Cavities and walls)."""
        tracts = self.outflow[frame]
        t = tracts.get(structure)
        if t is None:
            return None
        valve = tracts.get("rv_endo", t).valve if structure == "rv_epi" else t.valve
        return tract_solid(t, valve, frame=frame)

    def _structures(self, frame: int) -> list[str]:
        """Surfaces that frame's contours allow (SA contours on >= 2 slices)."""
        geo = self.geometry[frame]
        return [s for s in SURFACES if len(geo.sections.get(s) or []) >= 2]

    def fit(self, frame: int, structure: str, refined: bool = True) -> SurfaceFit:
        """The lofted surface of one structure at one frame, with its sections (cached);
        ``refined``: corrected towards the LA contours (LV surfaces, when enabled).

        Parameters
        ----------
        frame : int
            A frame of the model.
        structure : str
            ``lv_endo``, ``lv_epi``, ``rv_endo`` or ``rv_epi``.
        refined : bool
            Corrected towards the LA contours (True) or the loft through the SA sections alone.

        Returns
        -------
        SurfaceFit
            The surface (NURBS, scanner mm) and the sections it was lofted through.
        """
        refined = refined and self.refine and structure in ("lv_endo", "lv_epi") \
            and bool(self.geometry[frame].la_points.get(structure))
        return self._fit(frame, structure, refined)

    @memoized
    def _fit(self, frame: int, structure: str, refined: bool) -> SurfaceFit:
        """:meth:`fit` once ``refined`` says whether the refinement applies."""
        if refined:
            base = self._fit(frame, structure, False)
            return dataclasses.replace(base, surface=self._refined(self.geometry[frame], structure,
                                                                   base.surface), warnings=[])
        geo = self.geometry[frame]
        f = build_surface(geo, structure, geo.reference, tol_px=self.tol_px)
        if (frame, structure, refined) not in self._warned:
            self.warnings += f.warnings
        return f

    def lv_cavity_volume_unrefined(self, frame: int) -> float:
        """LV cavity volume (mL) of the loft through the SA contours alone: what ED and
        ES are found with (cheap for every frame; the LA correction is applied only
        to the frames that are reported).

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        float
            LV cavity volume, mL.
        """
        return self._clipped_cavity_ml(frame, self.fit(frame, "lv_endo", refined=False).surface)

    def _capped_tessellation(self, surface) -> tuple[np.ndarray, np.ndarray]:
        """A cavity surface tessellated at the model's resolution (volume-corrected) and
        capped closed: (V, 3) vertices in scanner mm and (F, 3) triangles."""
        return meshing.closed_mesh(*nurbs.tessellate(surface, *self.resolution,
                                                     volume_corrected=True))

    def _clipped_cavity_ml(self, frame: int, surface) -> float:
        """LV cavity volume (mL) inside one frame's LV endocardial ``surface``: its capped
        tessellation clipped by the mitral plane
        (:func:`cardionurbs.anatomy.mesh.clipped_volume`: the divergence theorem, no
        manifold solid built)."""
        v, f = self._capped_tessellation(surface)
        vol = meshing.clipped_volume(v, f, self.base_planes[frame].get("lv")) / 1000.0
        lvot = self._tract_part(frame, "lv_endo")
        if lvot is not None:      # the LVOT lies beyond the mitral plane: the volumes add
            vol += meshing.volume_ml(lvot)
        vol += self._beyond_base_ml(frame)
        if not vol > 0:
            raise ReconstructionError(f"lv_cavity, frame {frame}: nothing lies on the apical "
                                      "side of the valve plane")
        return vol

    def lv_cavity_volume(self, frame: int) -> float:
        """The LV cavity volume (mL) of one frame, as :meth:`volumes` has it: at ED and ES
        (and any frame whose solids exist) from the checked manifold solid; at the other
        frames (the volume curve, filling rates) from the clipped tessellation of the same
        surface, which gives the same volume to rounding without building the solid.

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        float
            LV cavity volume, mL.
        """
        if frame in (self.ed_frame, self.es_frame) or frame in self.lv_cavity_solid:
            return meshing.volume_ml(self.lv_cavity_solid(frame)) + self._beyond_base_ml(frame)
        return self._clipped_lv_ml(frame)           # the filling rates and the volume curve ask

    def _beyond_base_ml(self, frame: int, what: str = "lv_cavity") -> float:
        """The label map's LV cavity (``what``: or myocardium) on SA slices basal to the
        surface's half-slice valve plane, each slice its slab
        (:func:`cardionurbs.anatomy.sections.labelled_beyond_base_ml`; 0 for other studies,
        other volumes and a model read back from its file, whose volumes are its meshes'), mL."""
        meta = getattr(self.study, "meta", None)
        if what not in ("lv_cavity", "lv_myocardium") or not isinstance(self.surfaces, LazyFrames) \
                or not (isinstance(meta, dict) and meta.get("lv_slice_ml")):
            return 0.0
        return labelled_beyond_base_ml(self.study, self.geometry[frame], what)

    @memoized
    def _clipped_lv_ml(self, frame: int) -> float:
        """The LV cavity volume (mL) of a frame without solids (:meth:`_clipped_cavity_ml` of
        its LV endocardium; cached, or given by a worker process)."""
        return self._clipped_cavity_ml(frame, self._surface(frame, "lv_endo"))

    def _refined(self, geo: FrameGeometry, structure: str, surface):
        """The surface corrected towards the LA contour points on the apical side of the
        valve plane (:func:`cardionurbs.anatomy.refine.refine_surface`)."""
        la = geo.la_points.get(structure) or []
        if not la:
            return surface
        targets = np.concatenate(la)
        wl = geo.la_weights.get(structure) or []
        weights = np.concatenate(wl) if len(wl) == len(la) else np.ones(len(targets))
        plane = geo.base_planes.get("lv")
        if plane is not None:
            keep = plane.signed_distance(targets) >= 0
            targets, weights = targets[keep], weights[keep]
        # the SA points every ~2 mm along each contour suffice to hold the surface
        anchors = np.concatenate([_every(sec.source_points, 2.0) for sec in geo.sections[structure]
                                  if sec.source_points is not None])     # not those interpolated
        every = _every_index(targets, 2.0)
        return refine_surface(surface, anchors, targets[every], anchor_weight=self.anchor_weight,
                              target_weights=weights[every], passes=2)

    def _all_surfaces(self, frame: int) -> dict:
        geo = self.geometry[frame]
        for s in SURFACES:
            if len(geo.sections.get(s) or []) == 1:
                self.warnings.append(f"{s}, frame {frame}: contours on one slice only; "
                                     "surface skipped")
        return {s: self.fit(frame, s).surface for s in self._structures(frame)}

    def _surface(self, frame: int, structure: str):
        if isinstance(self.surfaces, LazyFrames) and frame not in self.surfaces.computed:
            return self.fit(frame, structure).surface
        return self.surfaces[frame][structure]

    def _conserve_myocardium(self, ed: int, es: int, samples: int = 9) -> None:
        """The ES valve planes of a short-axis-only label map (docs/metrics.md, Cavities
        and walls): the half-slice plane at ES is moved along its normal, within the slab
        the stack allows (from the most basal section to the next slice), to where the
        LV myocardial volume at ES equals that at ED — the myocardium is nearly
        incompressible — and the RV plane by the same amount (the atrioventricular
        plane moves as one). Only when both frames' LV valve planes come from the
        half-slice rule and both have LV endo- and epicardial surfaces."""
        g_ed, g_es = self.geometry[ed], self.geometry[es]
        if not ("lv" in g_es.base_from_slices or "lv" in g_ed.base_from_slices):
            self._follow_mitral_descent(g_ed, g_es)
            return
        if not (g_es.base_slack > 0 and "lv" in g_es.base_from_slices
                and "lv" in g_ed.base_from_slices):
            return
        need = ("lv_endo", "lv_epi")
        if not all(s in self._structures(f) for f in (ed, es) for s in need):
            return
        self._stationary_epicardial_apex(g_ed, g_es)
        ratio = labelled_myocardium_ratio(self.study, ed, es)
        if ratio is not None and abs(ratio - 1) > MYO_CONSERVED_BOUND:
            self.warnings.append(labels_do_not_conserve(ratio, es))
            self.base_shift_mm[es] = 0.0
            return                        # the labels' own slab at ES (docs/metrics.md)
        target = self.volumes[ed]["lv_myocardium"] - self._beyond_base_ml(es, "lv_myocardium")
        myo = self._solid(es, "lv_epi") - self._solid(es, "lv_endo")
        plane = g_es.base_planes["lv"]
        shifts = np.linspace(-0.5 * g_es.thickness, g_es.base_slack, samples)
        level = float(plane.origin @ plane.normal)
        vols = np.array([meshing.volume_ml(myo.trim_by_plane(plane.normal, level - d))
                         for d in shifts])
        vols = np.maximum.accumulate(vols)            # more basal plane, never less wall
        shift = float(np.interp(target, vols, shifts))
        self._move_es_planes(g_es, self._moving_with_lv(g_es), shift)
        self.base_shift_mm[es] = shift

    def _moving_with_lv(self, g_es: FrameGeometry) -> list[str]:
        """:func:`moves_with_lv`, and the RV's plane too when :func:`base_between_slices`
        closed the RV beyond an untraced plane on which the LV's most basal section lies
        (the two valve planes are then one; hand contours only)."""
        sides = moves_with_lv(g_es)
        if ("rv" in sides or "rv" not in g_es.base_from_slices or "lv" not in sides
                or self.study.meta.get("sa_apex") == SA_APEX_TAPER):
            return sides                  # label maps keep their own RV slab
        n, planes = g_es.direction, g_es.base_planes
        one = abs(float((planes["rv"].origin - planes["lv"].origin) @ n)) < 0.05
        if one and rv_untraced_basal_level(self.study, g_es) is not None:
            sides.append("rv")
        return sides

    def _move_es_planes(self, g_es: FrameGeometry, sides: list[str], shift: float) -> None:
        """Move the ES valve planes ``sides`` ``shift`` mm basally along their normals and
        forget what was built on them."""
        for side in sides:
            p = g_es.base_planes[side]
            g_es.base_planes[side] = Plane(p.origin - shift * p.normal, p.normal)
        es = g_es.frame
        for memo in (self.lv_cavity_solid, self.solids, self._tract_part):
            memo.forget_where(lambda k: k[0] == es)
        self.meshes.forget(es)

    def _follow_mitral_descent(self, g_ed: FrameGeometry, g_es: FrameGeometry) -> None:
        """The RV's ES half-slice valve plane when both frames' mitral planes come from
        landmarks but the RV's from the half-slice rule (docs/metrics.md, Cavities and
        walls): it is put where the RV's ED plane lies plus the mitral plane's measured
        descent from ED to ES along the stacking direction (the atrioventricular plane
        moves as one), within the slab the stack allows at ES (from the most basal RV
        section's centre to ``base_slack`` beyond the half-slice plane)."""
        if not ("rv" in g_es.base_from_slices and "rv" in g_ed.base_from_slices
                and "lv" in g_ed.base_planes and "lv" in g_es.base_planes):
            return
        n = g_es.direction
        m_ed, m_es = g_ed.base_planes["lv"], g_es.base_planes["lv"]
        p_ed, p_es = g_ed.base_planes["rv"], g_es.base_planes["rv"]
        k, km = float(p_es.normal @ n), float(m_es.normal @ n)
        if min(k, km) < 0.05:
            return
        # along n from the ED mitral centre to the ES mitral plane (not the landmarks' means:
        # another subset of annulus points at ES would shift the mean along a tilted annulus)
        descent = float((m_es.origin - m_ed.origin) @ m_es.normal) / km
        shift = (float((p_es.origin - p_ed.origin) @ n) - descent) / k
        shift = float(np.clip(shift, -0.5 * g_es.thickness, max(g_es.base_slack, 0.0)))
        self.rv_base_shift_mm[g_es.frame] = shift
        if shift:
            self._move_es_planes(g_es, ["rv"], shift)

    def _stationary_epicardial_apex(self, g_ed: FrameGeometry, g_es: FrameGeometry) -> None:
        """The LV epicardial apex of a taper-closed surface at ES is put at the level found
        at ED (docs/metrics.md): the apex hardly moves over the cycle, the base moves
        towards it, and the ellipsoidal taper describes the relaxed ventricle at ED
        better than the thickened apical wall at ES (never short of the ES endocardial
        apex)."""
        a, b = g_ed.taper.get("lv_epi"), g_es.taper.get("lv_epi")
        if a is None or b is None:
            return
        n = g_es.direction
        level = float(g_ed.apex["lv_epi"] @ n)
        endo = g_es.taper.get("lv_endo")
        level = max(level, endo.apex if endo is not None else b.level)
        if level <= b.level:
            return
        g_es.taper["lv_epi"] = dataclasses.replace(b, apex=level)
        c = polygon_centroid(g_es.sections["lv_epi"][-1].points, n)
        g_es.apex["lv_epi"] = c + (level - float(c @ n)) * n
        es = g_es.frame
        self._fit.forget_where(lambda k: k[:2] == (es, "lv_epi"))
        self._solid.forget(es, "lv_epi")
        self.solids.forget(es)

    # ------------------------------------------------------------- geometry
    def long_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """The LV long axis at ED, (apex (3,), base centre (3,)) in mm, by the one rule of
        :func:`cardionurbs.geometry.long_axis` (docs/metrics.md): the apex landmark, else
        the model's LV epicardial (else endocardial) apex; the mean of the mitral
        landmarks, else the LV valve plane's origin.

        Returns
        -------
        apex, base : (3,) ndarray
            Scanner mm.
        """
        fr = self.ed_frame
        ap = self.apex_points.get(fr, {})
        valve = self.base_planes.get(fr, {}).get("lv")
        return long_axis([lm.point for lm in self.study.landmarks_at(fr, "apex")],
                         [lm.point for lm in self.study.landmarks_at(fr, "mitral")],
                         model_apex=ap.get("lv_epi", ap.get("lv_endo")),
                         valve_origin=None if valve is None else valve.origin,
                         where=f"frame {fr}")

    @memoized
    def _solid(self, frame: int, structure: str):
        """manifold3d solid bounded by one surface, capped beyond its valve plane but not
        yet trimmed by it (cached)."""
        v, f = nurbs.tessellate(self._surface(frame, structure), *self.resolution,
                                volume_corrected=True)
        return meshing.solid(v, f, what=structure, frame=frame)

    def _trim(self, m, frame: int, side: str, shift_mm: float = 0.0, what: str = ""):
        """Keep the apical side of a valve plane (moved ``shift_mm`` towards the base)."""
        plane = self.base_planes[frame].get(side)
        if plane is None:
            return m
        out = m.trim_by_plane(plane.normal, float(plane.origin @ plane.normal) - shift_mm)
        if out.is_empty():
            raise ReconstructionError(f"{what}, frame {frame}: nothing lies on the apical side "
                                      "of the valve plane")
        return out

    @memoized
    def lv_cavity_solid(self, frame: int):
        """The LV cavity of one frame: LV endocardial solid trimmed by the mitral plane,
        united with the LVOT lumen where the frame has one (:meth:`_tract_part`; cached)."""
        m = self._trim(self._solid(frame, "lv_endo"), frame, "lv", what="lv_cavity")
        lvot = self._tract_part(frame, "lv_endo")
        return m if lvot is None else m + lvot

    @memoized
    def solids(self, frame: int) -> dict:
        """manifold3d solids of one frame keyed like :meth:`meshes` (cached)::

            lv_cavity     = LV endo ∩ H_lv
            lv_myocardium = (LV epi − LV endo) ∩ H_lv
            rv_cavity     = (RV endo − L) ∩ H_rv
            rv_myocardium = (RV epi − RV endo − L) ∩ H_rv,   L = LV epi ∩ H_lv

        H = the apical half-space of the valve plane (docs/metrics.md). The booleans act
        on the untrimmed solids and the trim comes last, so no two faces of a
        boolean are coplanar (which would pinch the result); L is trimmed 0.01 mm
        beyond the mitral plane for the same reason when the two valve planes
        coincide (SA-only input).
        """
        if frame not in self.surfaces:
            raise ReconstructionError(f"frame {frame} is not reconstructed "
                                      f"(reconstructed: {self.frames})")
        have = set(self.surfaces[frame])
        sol = {s: self._solid(frame, s) for s in have}
        out: dict = {}
        if "lv_endo" in sol:
            out["lv_cavity"] = self.lv_cavity_solid(frame)
            if "lv_epi" in sol:
                out["lv_myocardium"] = self._trim(sol["lv_epi"] - sol["lv_endo"], frame, "lv",
                                                  what="lv_myocardium")
        lv_epi = self._trim(sol["lv_epi"], frame, "lv", 0.01, "lv_epi") if "lv_epi" in sol else None
        if "rv_endo" in sol:
            rc = sol["rv_endo"] if lv_epi is None else sol["rv_endo"] - lv_epi
            out["rv_cavity"] = self._trim(rc, frame, "rv", what="rv_cavity")
            rvot = self._tract_part(frame, "rv_endo")
            if rvot is not None:          # the RVOT lumen (docs/metrics.md)
                out["rv_cavity"] = out["rv_cavity"] + (rvot if lv_epi is None else rvot - lv_epi)
            if "rv_epi" in sol:
                rm = sol["rv_epi"] - sol["rv_endo"]
                if lv_epi is not None:
                    rm = rm - lv_epi
                out["rv_myocardium"] = self._trim(rm, frame, "rv", what="rv_myocardium")
                wall = self._tract_part(frame, "rv_epi")
                if rvot is not None and wall is not None:   # the RVOT free wall
                    wall = wall - rvot
                    if lv_epi is not None:
                        wall = wall - lv_epi
                    out["rv_myocardium"] = (out["rv_myocardium"] + wall) - out["rv_cavity"]
        for k, m in out.items():
            if m.status() != manifold3d.Error.NoError or m.is_empty():
                raise ReconstructionError(f"{k}, frame {frame}: boolean result is empty or not "
                                          f"manifold ({m.status().name})")
        return out

    @memoized
    def meshes(self, frame: int) -> dict[str, trimesh.Trimesh]:
        """Closed manifold meshes (scanner mm) of one frame, keyed lv_cavity,
        rv_cavity, lv_myocardium, rv_myocardium (those the surfaces allow); cached.

        See :meth:`solids` for the booleans. Each mesh is checked watertight with
        consistent outward winding; ReconstructionError names the mesh and frame
        on failure.

        Parameters
        ----------
        frame : int
            A reconstructed frame.

        Returns
        -------
        dict of str to trimesh.Trimesh
            Mesh name -> closed manifold mesh, scanner mm.

        Raises
        ------
        ReconstructionError
            A mesh that is not watertight with outward winding (naming the mesh and frame).
        """
        return {k: meshing.to_trimesh(m, what=k, frame=frame)
                for k, m in self.solids(frame).items()}

    def mesh_arrays(self, frame: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The closed meshes of :meth:`meshes` as plain (vertices (V, 3) mm, faces (F, 3))
        arrays, checked closed and outward (:func:`cardionurbs.anatomy.mesh.mesh_arrays`),
        without trimesh: what is written to files (not cached).

        Parameters
        ----------
        frame : int
            A reconstructed frame.

        Returns
        -------
        dict of str to (vertices (V, 3) ndarray of float, faces (F, 3) ndarray of int64)
            Mesh name -> its arrays, mm.
        """
        if frame in self.meshes:
            return {k: (np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64))
                    for k, tm in self.meshes(frame).items()}
        return {k: meshing.mesh_arrays(m, what=k, frame=frame)
                for k, m in self.solids(frame).items()}

    def release(self, frame: int) -> None:
        """Forget the cached solids and meshes of one frame (its volumes and surfaces are
        kept): exporting every frame's meshes then holds one frame's at a time.

        Parameters
        ----------
        frame : int
            A frame of the model.
        """
        self.meshes.forget(frame)
        for memo in (self._solid, self.lv_cavity_solid, self.solids, self._tract_part):
            memo.forget_where(lambda k: k[0] == frame)

    def stack_flag(self, frame: int) -> str | None:
        """The QC flag of an SA stack its long-axis contours contradict at ``frame``: an LV
        surface's most apical SA section more than one slice thickness plus
        :data:`LA_OVERSHOOT_SLACK_MM` beyond the LA apex (:func:`la_overshoot_mm`; e.g. a
        label map whose slice spacing is not where the slices were imaged). None: consistent,
        no LA contours, or a model read back without its study.

        Parameters
        ----------
        frame : int
            A frame of the model.

        Returns
        -------
        str or None
            The flag, naming the surface, the distance and the bound in mm.
        """
        if frame not in self.frames or not self.study.contours:
            return None
        geo = self.own_geometry[frame]
        bound = geo.thickness + LA_OVERSHOOT_SLACK_MM
        over = {s: d for s, d in la_overshoot_mm(geo).items() if d > bound}
        if not over:
            return None
        s = max(over, key=over.__getitem__)
        return (f"SA stack contradicts the long-axis views at frame {frame}: the "
                f"{'LV endo' if s == 'lv_endo' else 'LV epi'} SA sections reach {over[s]:.1f} mm beyond the apex of the "
                f"LA contours (bound {bound:.1f} mm); the SA slice positions (spacing) or the "
                f"LA planes are wrong, so the volumes are not measured honestly")

    # ------------------------------------------------------------- residuals (anatomy.residuals)
    @cached_property
    def residuals(self) -> pd.DataFrame:
        """Distance of every contour point to its surface, every frame (see
        :meth:`residual_table`)."""
        return self.residual_table(self.frames)

    def residual_table(self, frames=None) -> pd.DataFrame:
        """Distance of every contour point to its surface (closest-point projection,
        :func:`cardionurbs.nurbs.closest_points`), per (structure, frame, slice, view):
        columns structure, frame, slice, view, n_points, mean_mm, max_mm, mean_px,
        max_px, for the given frames (default ED and ES); see :meth:`point_residuals`
        for which points and which distance. Empty for a model read back without its
        study's contours. The same numbers without pandas: :meth:`residual_columns`
        (:func:`cardionurbs.anatomy.residuals.residual_table`).

        Parameters
        ----------
        frames : iterable of int or None
            The frames; None: ED and ES.

        Returns
        -------
        pandas.DataFrame
            One row per contour; distances in mm and pixels.
        """
        return fit_residuals.residual_table(self.point_residual_arrays(frames))

    def residual_columns(self, frames=None) -> dict[str, np.ndarray]:
        """The columns of :meth:`residual_table` as numpy arrays, no pandas
        (:func:`cardionurbs.anatomy.residuals.residual_columns`).

        Parameters
        ----------
        frames : iterable of int or None
            The frames; None: ED and ES.

        Returns
        -------
        dict of str to ndarray
            Column name -> array (C,), one entry per contour (mm and pixels).
        """
        return fit_residuals.residual_columns(self.point_residual_arrays(frames))

    def point_residuals(self, frames=None) -> pd.DataFrame:
        """Every contour point's distance to the surface it was fitted by (mm and pixels of
        its image), at the given frames (default ED and ES): columns structure, frame,
        slice, view, dist_mm, dist_px (:func:`cardionurbs.anatomy.residuals.point_residual_parts`
        says which points and which distance). The same numbers without pandas:
        :meth:`point_residual_arrays`.

        Parameters
        ----------
        frames : iterable of int or None
            The frames; None: ED and ES.

        Returns
        -------
        pandas.DataFrame
            One row per contour point.
        """
        return fit_residuals.point_residuals(self.point_residual_arrays(frames))

    def point_residual_arrays(self, frames=None) -> list[dict]:
        """:meth:`point_residuals` as numpy arrays (cached), one dict per (frame, structure)
        in frame order: ``structure``, ``frame``, and per point ``slice`` (object array),
        ``view``, ``dist_mm``, ``dist_px``; [] without the study's contours.

        Parameters
        ----------
        frames : iterable of int or None
            The frames; None: ED and ES.

        Returns
        -------
        list of dict
            One dict per (frame, structure), as
            :func:`cardionurbs.anatomy.residuals.point_residual_parts`.
        """
        if not self.study.contours:
            return []
        return [dict(p) for p in self._point_residuals(self._residual_frames(frames))]

    def _residual_frames(self, frames=None) -> tuple[int, ...]:
        """The frames of :meth:`point_residual_arrays` (default ED and ES), as its key."""
        return tuple(sorted({self.ed_frame, self.es_frame}) if frames is None else frames)

    def provide_point_residuals(self, parts: list[dict], frames=None) -> None:
        """Store :meth:`point_residual_arrays` computed elsewhere (a worker process of
        :func:`cardionurbs.parallel.fork_map`), unless this model has them.

        Parameters
        ----------
        parts : list of dict
            What :meth:`point_residual_arrays` returned in the worker.
        frames : iterable of int or None
            The frames they are of; None: ED and ES.
        """
        self._point_residuals.provide([dict(p) for p in parts], self._residual_frames(frames))

    @memoized
    def _point_residuals(self, frames: tuple[int, ...]) -> list[dict]:
        return fit_residuals.point_residual_parts(self, frames)

    # ------------------------------------------------------------- (de)serialise (anatomy.serialise)
    def to_dict(self) -> dict:
        """JSON-safe model: surfaces (NURBS), valve planes, apex points, SA sections, outflow
        tracts (frames that have them), ED/ES (:func:`cardionurbs.anatomy.serialise.encode`).

        Returns
        -------
        dict
            The version-1 model dict (:mod:`cardionurbs.io.modelfile` writes it compactly).
        """
        return serialise.encode(self)

    @classmethod
    def from_dict(cls, d: dict, study: Study | None = None) -> "BiventricularModel":
        """Inverse of :meth:`to_dict` (the Study is reduced to subject, heart rate,
        ED/ES labels and the apex/mitral landmarks unless ``study`` is given); also reads
        the compact version-2 dict of a model.json (:mod:`cardionurbs.io.modelfile`;
        :func:`cardionurbs.anatomy.serialise.decode`).

        Parameters
        ----------
        d : dict
            A model dict (version 1, or the compact version 2 of a model.json).
        study : Study or None
            The study the model was reconstructed from; None: a reduced one.

        Returns
        -------
        BiventricularModel
        """
        return cls(**serialise.decode(d, study))


def base_between_slices(study: Study, geo: FrameGeometry) -> None:
    """Hand-drawn SA contours without valve landmarks: each valve plane the half-slice rule
    placed is moved to half-way between its most basal section and the next imaged SA plane
    on the basal side (when the slices are farther apart than they are thick: the valve
    lies anywhere in that gap, not only in the section's own slab), and the ES plane may
    then move up to that next plane (``geo.base_slack``), where the LV myocardial volume
    equals ED's (:meth:`BiventricularModel._conserve_myocardium`).

    The RV's plane goes further when that next plane carries an LV section but no RV one
    (:func:`rv_untraced_basal_level`): the plane cuts the tricuspid annulus, part ventricle
    and part atrium, so the RV reaches into it and is closed half-way beyond it, as if it
    had a section there (docs/metrics.md, Cavities and walls).

    Parameters
    ----------
    study : Study
        The study (its SA image planes at ``geo.frame``).
    geo : FrameGeometry
        One frame's geometry; its ``base_planes`` and ``base_slack`` are changed in place.
    """
    n = geo.direction
    levels = _sa_levels(study, geo)
    slack = 0.5 * geo.thickness
    for side, surf in (("lv", "lv_endo"), ("rv", "rv_endo")):
        secs = geo.sections.get(surf) or []
        if side not in geo.base_from_slices or not secs:
            continue
        level = float(secs[0].points.mean(axis=0) @ n)
        above = levels[levels < level - 0.5]
        if not len(above):
            continue
        half_gap = 0.5 * (level - float(above.max()))
        extra = half_gap - 0.5 * geo.thickness
        untraced = rv_untraced_basal_level(study, geo) if side == "rv" else None
        if untraced is not None:          # closed half-way beyond the untraced plane
            beyond = levels[levels < untraced - 0.5]
            reach = 0.5 * (untraced - float(beyond.max())) if len(beyond) else 0.0
            extra = (level - untraced) + max(reach, 0.5 * geo.thickness) - 0.5 * geo.thickness
        if extra > 0:
            p = geo.base_planes[side]
            geo.base_planes[side] = Plane(p.origin - extra * p.normal, p.normal)
        if side == "lv":
            slack = max(half_gap, slack)
    if "lv" in geo.base_from_slices:
        geo.base_slack = slack


def _sa_levels(study: Study, geo: FrameGeometry) -> np.ndarray:
    """The levels along ``geo.direction`` of the frame's SA image planes, mm, shape (k,)."""
    n = geo.direction
    return np.array([float(im.position @ n) for im in study.images
                     if im.view == "SA" and im.frame == geo.frame])


def rv_untraced_basal_level(study: Study, geo: FrameGeometry) -> float | None:
    """The level of the SA plane next to the RV's most basal section on the basal side
    when that plane carries an LV section but no RV one, else None.

    A tracer leaves out a ventricle on a slice that cuts its valve annulus (part wall,
    part atrium). The LV traced on that plane says the atrioventricular plane lies in or
    beyond it; the RV not traced there says its annulus dips into it: the RV reaches
    into that slice, not only into the gap before it (an SA-only stack of hand contours
    whose RV half-slice plane was put in the gap made RVEDV 30-38 mL low on realistic
    phantoms, reports/rv-sa-only.md). Only for an RV valve plane from the half-slice rule.

    Parameters
    ----------
    study : Study
        The study (its SA image planes at ``geo.frame``).
    geo : FrameGeometry
        One frame's geometry (sections, stacking direction).

    Returns
    -------
    float or None
        The plane's level along ``geo.direction``, mm (SA image position · direction).
    """
    if "rv" not in geo.base_from_slices:
        return None
    rv = geo.sections.get("rv_endo") or []
    if not rv:
        return None
    n = geo.direction
    level = float(rv[0].points.mean(axis=0) @ n)
    levels = _sa_levels(study, geo)
    above = levels[levels < level - 0.5]
    if not len(above):
        return None
    nxt = float(above.max())

    def on_plane(structure: str) -> bool:
        return any(abs(float(s.points.mean(axis=0) @ n) - nxt) < 0.5
                   for s in geo.sections.get(structure) or [])
    if not (on_plane("lv_endo") or on_plane("lv_epi")) or on_plane("rv_epi"):
        return None
    return nxt


#: how far beyond one slice thickness the most apical SA section of an LV surface may lie
#: beyond the apex of its long-axis contours before the two views contradict each other
#: (breath-hold misregistration between the SA and LA acquisitions is a few mm), mm
LA_OVERSHOOT_SLACK_MM = 10.0


def la_overshoot_mm(geo: FrameGeometry) -> dict[str, float]:
    """How far the most apical SA section of each LV surface lies beyond the apex its LA
    contours show, along the stacking direction.

    The centroid of the most apical SA contour lies on the base side of the LA contours'
    apex in a consistent study (the slice cuts the cavity, the LA contour turns beyond it);
    a positive value is SA cavity where the long-axis views have none.

    Parameters
    ----------
    geo : FrameGeometry
        One frame's sections and LA polylines (:func:`cardionurbs.anatomy.sections.frame_geometry`).

    Returns
    -------
    dict
        ``lv_endo`` / ``lv_epi`` (those with SA sections and LA contours) -> the distance,
        mm (negative: the LA apex lies beyond the SA stack, as it should).
    """
    n, out = geo.direction, {}
    for s in ("lv_endo", "lv_epi"):
        secs, la = geo.sections.get(s) or [], geo.la_points.get(s) or []
        if secs and la:
            la_apex = float((np.concatenate(la) @ n).max())
            out[s] = float(secs[-1].points.mean(axis=0) @ n) - la_apex
    return out


def _every(points: np.ndarray, spacing_mm: float) -> np.ndarray:
    """A subsample of ordered contour points about ``spacing_mm`` apart."""
    return points[_every_index(points, spacing_mm)]


def _every_index(points: np.ndarray, spacing_mm: float) -> slice:
    """The slice of ordered contour points that keeps them about ``spacing_mm`` apart."""
    if len(points) < 3:
        return slice(None)
    step = median(np.linalg.norm(np.diff(points, axis=0), axis=1)) or spacing_mm
    return slice(None, None, max(1, int(round(spacing_mm / step))))


def reconstruct(study: Study, *, frames: list[int] | None = None, tol_px: float = 1.0,
                refine: bool = True, resolution: tuple[int, int] = RESOLUTION,
                progress=None, jobs: int | None = 1) -> BiventricularModel:
    """Biventricular NURBS model of a study (paper §4.2): one set of lofted
    surfaces per frame with LV endocardial contours (or the given ``frames``).

    The LV endocardium of every frame is built at once (its cavity volume finds
    ED and ES); the other surfaces are built when first asked for (measuring
    asks only at ED and ES).

    Parameters
    ----------
    study : Study
        A study read by :func:`cardionurbs.io.load_study` (scanner mm).
    frames : list of int or None
        The frames to model; None: every frame with LV endocardial contours.
    tol_px : float
        Curve-fit tolerance, pixels (paper §4.2.1: < 1 px).
    refine : bool
        Correct the LV surfaces towards the LA contour points
        (:mod:`cardionurbs.anatomy.refine`), where the study has LA contours.
    resolution : (int, int)
        Tessellation samples (around, along) of each surface's mesh.
    progress : callable or None
        Told ``(k, n)`` after each frame's LV cavity is built.
    jobs : int or None
        Processes for the frames' LV cavities (1: this one; None: the usable CPUs;
        :func:`cardionurbs.parallel.fork_map`): the same model either way.

    Returns
    -------
    BiventricularModel
        The surfaces per frame (scanner mm), ED and ES, volumes (mL) on demand.

    Raises
    ------
    ReconstructionError
        A frame without LV endocardial contours, or a surface that cannot be built (naming
        the structure and frame).

    Examples
    --------
    A two-frame phantom, reconstructed (its other surfaces and meshes are built when first
    asked for):

    >>> import pathlib, tempfile
    >>> import cardionurbs as cn
    >>> from cardionurbs.phantom import generate, write_phantom
    >>> phantom = generate("normal", seed=1, frames=2, n_sa=6, matrix=128, volume_check=False)
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = write_phantom(phantom, pathlib.Path(tmp.name) / "p1", dicom=False)
    >>> model = cn.reconstruct(cn.load_study(folder))
    >>> model.frames, model.ed_frame, model.es_frame
    ([0, 1], 0, 1)
    >>> sorted(model.surfaces[0])
    ['lv_endo', 'lv_epi', 'rv_endo', 'rv_epi']
    >>> tmp.cleanup()
    """
    avail = study.contoured_frames
    if frames is None:
        frames = avail
    missing = [f for f in frames if f not in avail]
    if missing:
        raise ReconstructionError(f"frame(s) {missing} have no LV endocardial contours")
    if not frames:
        raise ReconstructionError(f"study {study.subject}: no LV endocardial contours")
    return BiventricularModel(study, frames, tol_px=tol_px, refine=refine, resolution=resolution,
                              progress=progress, jobs=jobs)
