"""How a model's work done in a worker process comes back to the model in the parent.

Worker processes (:func:`cardionurbs.parallel.fork_map`) are forked with the parent's
:class:`~cardionurbs.anatomy.model.BiventricularModel` and build part of it; the model
itself is never pickled. What they hand back is plain values, which the parent's model
stores as if it had made them itself:

* the ED/ES search (:func:`unrefined_cavity_volumes`): per frame, the unrefined and the
  LA-corrected LV cavity volume, the contour count, the sections interpolated in time
  (:func:`cardionurbs.anatomy.cycle.support_sections`) and the warnings the frame raised;
* the meshes of every frame (:func:`cardionurbs.pipeline.write_meshes`): per frame, the
  values of the :data:`HANDED_BACK` mappings the worker computed (:func:`frame_results`,
  stored by :func:`adopt_frame_results`); solids and meshes stay in the worker;
* the fit residuals at ED and ES (:meth:`BiventricularModel.provide_point_residuals`).
"""

from __future__ import annotations

from functools import partial
from typing import Any

from cardionurbs.cache import LazyFrames
from cardionurbs.errors import CardioNurbsError

#: a :class:`~cardionurbs.anatomy.model.BiventricularModel` (not imported: it imports this module)
BiventricularModel = Any

#: the per-frame mappings a worker process that built one frame's solids hands back
#: (:func:`frame_results`); base planes, apex points and sections follow from geometry
HANDED_BACK = ("geometry", "outflow", "surfaces", "volumes")


def computed(model: BiventricularModel) -> dict[str, set]:
    """Frames whose :data:`HANDED_BACK` values exist, per mapping (see :func:`frame_results`).

    Parameters
    ----------
    model : BiventricularModel
        The model (in a worker process, before it makes a frame).

    Returns
    -------
    dict of str to set of int
        Per handed-back mapping, the frames whose values exist now.
    """
    return {k: set(getattr(model, k).computed) for k in HANDED_BACK
            if isinstance(getattr(model, k), LazyFrames)}


def frame_results(model: BiventricularModel, frame: int, before: dict[str, set]) -> dict:
    """The values of one frame computed since :func:`computed` returned ``before``: what
    a worker process that made the frame's solids returns so that the model in the parent
    process, given them by :func:`adopt_frame_results`, is as if it had made them itself
    (solids and meshes are not handed back: :meth:`BiventricularModel.release` drops them).

    Parameters
    ----------
    model : BiventricularModel
        The model in the worker process.
    frame : int
        The frame the worker made.
    before : dict of str to set of int
        What :func:`computed` returned before the frame was made.

    Returns
    -------
    dict
        Mapping name -> the frame's new value (surfaces, sections, volumes as the model keeps
        them), picklable.
    """
    return {k: getattr(model, k)[frame] for k, done in before.items()
            if frame not in done and frame in getattr(model, k).computed}


def adopt_frame_results(model: BiventricularModel, frame: int, results: dict) -> None:
    """Store the values :func:`frame_results` returned (those the model has are kept).

    Parameters
    ----------
    model : BiventricularModel
        The model in the parent process.
    frame : int
        The frame the values belong to.
    results : dict
        What :func:`frame_results` returned in the worker.
    """
    for k, value in results.items():
        getattr(model, k).provide(frame, value)


def unrefined_cavity_volumes(model: BiventricularModel, jobs: int | None = 1,
                             progress=None) -> dict[int, float]:
    """Every frame's :meth:`BiventricularModel.lv_cavity_volume_unrefined` (mL), which ED and
    ES are found with; ``progress(k, n)`` after each frame.

    With worker processes (``jobs``, :func:`cardionurbs.parallel.fork_map`) each worker
    also makes its frames' LA-corrected LV cavity volume (:meth:`lv_cavity_volume` asks
    for it next: the volume curve and the filling rates) and hands back the two volumes
    and the warnings the frame raised, which are added here in frame order. Nothing else
    comes back: the surfaces this process needs later (ED and ES) are built here again,
    from the study, so that they are the serial loop's to the last bit (a section's
    points unpickled are contiguous copies of what were views, and numpy sums those in
    another order), and their warnings, already recorded, are not added twice. A frame
    whose corrected volume fails leaves it to be made (and fail) where the serial order
    makes it.

    Parameters
    ----------
    model : BiventricularModel
        The model whose frames are measured.
    jobs : int or None
        Worker processes (:func:`cardionurbs.parallel.worker_count`: 1 serial, None every CPU).
    progress : callable (int, int) -> None, optional
        Called with (frames done, frames in all) after each frame.

    Returns
    -------
    dict of int to float
        Frame -> unrefined LV cavity volume (mL); NaN where the cavity cannot be built.
    """
    from cardionurbs.parallel import fork_map, worker_count
    n = len(model.frames)
    if worker_count(jobs, n) == 0:
        lv = {}
        for k, f in enumerate(model.frames):
            lv[f] = model._unrefined_or_nan(f)
            if progress is not None:
                progress(k + 1, n)
        return lv
    done = [0]

    def told(i: int, result: dict) -> None:
        done[0] += 1
        if progress is not None:
            progress(done[0], n)
    results = fork_map(partial(_frame_volumes, model), model.frames, jobs=jobs, on_result=told)
    lv = {}
    for f, r in zip(model.frames, results):
        lv[f] = r["unrefined"]
        if "refined" in r:
            model._clipped_lv_ml.provide(r["refined"], f)
        if "contours" in r:
            model._lv_contour_count.provide(r["contours"], f)
        model._in_time[f] = r.get("in_time", {})
        model.warnings += r["warnings"]
        model._warned |= {(f, "geometry"), (f, "lv_endo", False)}
    return lv


def _frame_volumes(model: BiventricularModel, f: int) -> dict[str, Any]:
    """What a worker of :func:`unrefined_cavity_volumes` hands back for one frame."""
    n_warnings = len(model.warnings)
    out: dict[str, Any] = {"unrefined": model._unrefined_or_nan(f)}
    if f in model.geometry.computed:
        out["contours"] = model._lv_contour_count(f)
        out["in_time"] = model.geometry[f].in_time
    try:
        out["refined"] = model._clipped_lv_ml(f)
    except CardioNurbsError:
        pass
    out["warnings"] = model.warnings[n_warnings:]
    return out
