"""`cardionurbs analyze`: one study in, its model, meshes, metrics and figures out.

Output folder (written atomically: complete or absent)::

    DIR/metrics.json        {"subject", "metrics": {docs/metrics.md column: value},
                             "ed_frame", "es_frame", "volume_curve", "residuals",
                             "quality": {per metric: flags, surfaces, frames; per
                             surface and frame: fit residual median/p95/max in mm
                             and px; contours left out}, "QC", "notes", "warnings"}
                             (notes: metric -> why it is null)
    DIR/model.json          the NURBS model, compact (cardionurbs.io.modelfile: knots, control
                            points and weights at a stated precision)
    DIR/model.3dm           the ED surfaces as Rhino NURBS (with the ``cad`` extra)
    DIR/residuals.csv       contour-point-to-surface distances per slice, at ED and ES
    DIR/meshes/frame_NN_<mesh>.ply   closed meshes per frame and structure (binary PLY,
                                     the manifold3d result with float32 vertices; or
                                     --mesh-format stl|obj|glb|vtp)
    DIR/meshes/<mesh>.pvd            with --mesh-format vtp: VTK PolyData per frame with
                                     point data, and a ParaView time series per mesh
                                     (cardionurbs.analysis.mesh_fields)
    DIR/figures/...         PNG figures + figures.json (cardionurbs.report.figures.write_figures;
                            skipped with --no-figures)
    DIR/report.html         self-contained offline viewer (cardionurbs.report.html)

``--outputs`` chooses what is computed and written (default: all): ``metrics``
(metrics.json), ``model`` (model.json, model.3dm, residuals.csv), ``meshes``,
``figures``, ``report`` (needs metrics and model, which it then also writes).
Nothing that was not asked for is computed: metrics alone reconstruct every frame's
LV cavity (to find ED and ES) and the other surfaces at ED and ES only, and measure
the tags at ED and ES (twist and LS over time only for figures and report).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
from pathlib import Path

from cardionurbs.analysis.function import explain_nulls, measure, volume_curve
from cardionurbs.analysis.notes import collect_warnings, notes_of
from cardionurbs.analysis.uncertainty import intervals
from cardionurbs.anatomy import handback
from cardionurbs.anatomy.model import BiventricularModel, reconstruct
from cardionurbs.errors import UsageError
from cardionurbs.heap import acyclic, long_lived
from cardionurbs.io import atomic, load_study
from cardionurbs.io.export import export_mesh, export_model_3dm, table_csv, write_json, write_ply
from cardionurbs.io.modelfile import read_model_file, write_model_file
from cardionurbs.progress import Progress
from cardionurbs.study import Study

#: what ``analyze`` can write (``--outputs``), in the order it is produced
OUTPUTS = ("metrics", "model", "meshes", "figures", "report")


def parse_outputs(text: str | None) -> tuple[str, ...]:
    """``"metrics,figures"`` -> the outputs to write, in :data:`OUTPUTS` order (None or
    ``"all"``: everything). ``report`` brings ``metrics`` and ``model`` (its inputs).
    Raises ValueError naming an unknown output.

    Parameters
    ----------
    text : str or None
        The ``--outputs`` value: comma-separated names of :data:`OUTPUTS`, or ``"all"``.

    Returns
    -------
    tuple of str
        The outputs to write, in :data:`OUTPUTS` order.

    Raises
    ------
    ValueError
        An unknown output, or none named.
    """
    if text is None or text.strip() == "all":
        return OUTPUTS
    want = {t.strip() for t in text.split(",") if t.strip()}
    unknown = sorted(want - set(OUTPUTS))
    if unknown or not want:
        raise ValueError(f"--outputs: unknown output {unknown[0]!r}; choose from "
                         f"{', '.join(OUTPUTS)} (comma-separated) or all" if unknown else
                         "--outputs: name at least one output")
    if "report" in want:
        want |= {"metrics", "model"}
    return tuple(o for o in OUTPUTS if o in want)


def tag_metrics_hook(model: BiventricularModel, over_time: bool = True):
    """Tag metrics (Twist, Twist 2D, Torsion, CL shear, LS, QC flags) from
    ``cardionurbs.analysis.tags.tag_metrics(model)`` -- a mapping docs/metrics.md column ->
    float, with the level table, QC flags and tag surfaces as attributes -- when the
    study has tag lines; None otherwise (the columns then stay NaN). Twist and LS over
    time are included when three or more frames are tagged, so this one result serves
    the metrics, metrics.json, model.json and the figures. ``over_time=False`` (metrics
    only) measures at ED and ES alone: the same columns, without the time course.

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model of a study.
    over_time : bool, optional
        Also measure twist and LS at every tagged frame (when three or more are tagged).

    Returns
    -------
    cardionurbs.analysis.tags.TagMetrics or None
        Column -> value (deg, deg/cm, %) with the level table, QC flags and tag surfaces;
        None when the study has no tag lines.
    """
    if not model.study.tags:
        return None
    from cardionurbs.analysis.tags import tag_metrics
    return tag_metrics(model, over_time=over_time and len(model.study.tagged_frames) >= 3)


def analyse(study: Study, *, heart_rate_bpm: float | None = None, over_time: bool = True,
            progress: Progress | None = None, jobs: int | None = 1, on_measured=None):
    """Reconstruct and measure one loaded study: (model, docs/metrics.md dict, tag result or None).

    Parameters
    ----------
    study : Study
        A study read by :func:`cardionurbs.io.load_study`.
    heart_rate_bpm : float or None
        Heart rate (bpm) when the study carries none.
    over_time : bool
        Also twist and LS at every tagged frame (for figures and metrics.json); the
        docs/metrics.md columns are the same without it.
    progress : Progress or None
        Stages on stderr.
    jobs : int or None
        Processes for the per-frame work -- the frames' LV cavities (``reconstruct``), the
        tag metrics beside the volumes (:func:`measure_with_tags`) and the tag strain over
        time (one fit per tagged frame, :func:`cardionurbs.analysis.regional.regional_metrics`);
        1 (the default: a library call forks nothing unless asked): this process only; None:
        the usable CPUs (``cardionurbs analyze``'s default). The results are the same either way.
    on_measured : callable or None
        ``on_measured(model)`` is called once ED and ES are known and the volumes measured,
        before the tag results are awaited (``analyze`` starts the meshes' workers there).

    Returns
    -------
    model : BiventricularModel
        The reconstruction.
    metrics : dict
        docs/metrics.md column -> float in its unit (NaN, with its reason, where the study
        cannot give one), the tag, regional and voxel-count columns included.
    tags : TagMetrics or None
        The tag result (None without tag lines).
    """
    progress = progress or Progress(False)
    progress.stage("reconstruct")
    model = reconstruct(study, progress=progress.step, jobs=jobs)
    metrics, tags = measure_with_tags(model, heart_rate_bpm=heart_rate_bpm, over_time=over_time,
                                      jobs=jobs, progress=progress, on_measured=on_measured)
    if tags is not None:
        metrics.update({k: float(v) for k, v in dict(tags).items() if k in metrics})
    model.tag_result = tags                       # the tag intervals read it (analysis/tag_uncertainty)
    from cardionurbs.analysis.regional import regional_metrics
    regional = regional_metrics(model, tags, jobs=jobs)
    metrics.update({k: float(v) for k, v in regional.items() if k in metrics})
    model.regional = regional                     # kept for metrics.json and the figures
    voxels = study.meta.get("voxel_volumes_ml") if isinstance(study.meta, dict) else None
    if voxels:                              # label maps: voxel counting beside the model
        from cardionurbs.analysis.voxels import voxel_metrics
        metrics.update(voxel_metrics(voxels, model.ed_frame, model.es_frame))
    explain_nulls(model, metrics)           # the tag and regional columns are in now
    return model, metrics, tags


def analysis_warnings(model: BiventricularModel, metrics: dict, tags=None) -> list[dict]:
    """Every warning of one analysis, ``[{"source": load|reconstruct|measure, "message"}]``
    (:func:`cardionurbs.analysis.notes.collect_warnings`): the study's, the model's, the
    metrics', the tag and regional notes.

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model (its study's and its own warnings).
    metrics : dict
        Its docs/metrics.md dict (the notes of its null values).
    tags : cardionurbs.analysis.tags.TagMetrics or None, optional
        The tag metrics, whose notes are added.

    Returns
    -------
    list of dict
        One ``{"source": "load" | "reconstruct" | "measure", "message": str}`` per warning.
    """
    regional = getattr(model, "regional", None)
    extra = list(getattr(tags, "notes", None) or []) + list(getattr(regional, "notes", None) or [])
    return collect_warnings(model.study, model, metrics, measure_notes=extra)


def body_json(study: Study) -> dict:
    """Height (cm), weight (kg), age (y), sex and where each came from (metrics.json ``body``).

    Parameters
    ----------
    study : cardionurbs.study.Study
        The loaded study (its ``meta["body"]``).

    Returns
    -------
    dict
        ``height_cm`` (cm), ``weight_kg`` (kg), ``age_y`` (years), ``sex`` and ``source``; None
        for each one the study does not give.
    """
    body = dict(study.meta.get("body") or {}) if isinstance(study.meta, dict) else {}
    return {k: body.get(k) for k in ("height_cm", "weight_kg", "age_y", "sex", "source")}


def range_flags_json(metrics: dict, study: Study) -> dict:
    """metrics.json ``ranges``: the citation and, per metric with a reference range, its
    flag (below / normal / above or None), limits and table
    (:func:`cardionurbs.analysis.ranges.range_flags`).

    Parameters
    ----------
    metrics : dict
        The docs/metrics.md dict of one study.
    study : cardionurbs.study.Study
        The study, whose sex and age choose the reference table.

    Returns
    -------
    dict
        ``citation``, ``url``, ``limits`` and ``flags`` (metric -> flag, limits and table).
    """
    from cardionurbs.analysis.ranges import load_ranges, range_flags
    body, table = body_json(study), load_ranges()
    return {"citation": table["citation"], "url": table.get("url"), "limits": table.get("limits"),
            "flags": range_flags(metrics, body.get("sex"), body.get("age_y"))}


def measure_with_tags(model: BiventricularModel, *, heart_rate_bpm: float | None = None,
                      over_time: bool = True, jobs: int | None = 1,
                      progress: Progress | None = None, on_measured=None):
    """(docs/metrics.md dict of :func:`measure`, :func:`tag_metrics_hook` result or None).

    With worker processes (``jobs`` not 1; :func:`cardionurbs.parallel.fork_map`) this
    process measures the volumes, masses and rates while a worker measures the tag
    metrics (which need the study and the model's ED long axis alone; this process then
    makes the fit residuals at ED and ES, which the quality check of the metrics asks for
    next) or, without tag lines, those fit residuals (from the ED and ES surfaces, which
    the worker builds as this process does). Results are pickled back: the same as one
    process's. Neither changes the model except for warnings: the tag metrics' are added
    after the volumes' (the serial order); the residual worker's repeat this process's
    (the same surfaces) and are dropped. ``on_measured(model)`` is called in this process
    right after the volumes are measured (:func:`analyse`).

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model.
    heart_rate_bpm : float or None, optional
        Heart rate in beats/min for the rate metrics (None: the study's own).
    over_time : bool, optional
        Also measure twist and LS over time (see :func:`tag_metrics_hook`).
    jobs : int or None, optional
        Worker processes (1, the default: all in this process; None: the usable CPUs).
    progress : cardionurbs.progress.Progress or None, optional
        Where the stages are shown (None: nowhere).
    on_measured : callable, optional
        ``on_measured(model)``, called right after the volumes are measured.

    Returns
    -------
    metrics : dict
        docs/metrics.md column -> value (mL, %, g, mL/s ...; NaN where not measured).
    tags : cardionurbs.analysis.tags.TagMetrics or None
        The tag metrics, None without tag lines.
    """
    from cardionurbs.parallel import fork_map
    progress = progress or Progress(False)
    tagged = bool(model.study.tags)
    if jobs == 1 or not (tagged or model.study.contours):
        progress.stage("measure")
        metrics = measure(model, heart_rate_bpm=heart_rate_bpm)
        if on_measured is not None:
            on_measured(model)
        if tagged:
            progress.stage("tags")
        return metrics, tag_metrics_hook(model, over_time=over_time)

    def part(name: str):
        n_warnings = len(model.warnings)
        if name == "measure":
            metrics = measure(model, heart_rate_bpm=heart_rate_bpm)
            if on_measured is not None:
                on_measured(model)
            if tagged:                  # the tags are the longer part: residuals here meanwhile
                model.point_residual_arrays()
                progress.stage("tags")                 # what is left: the worker's tags
            return metrics
        if name == "residuals":
            return model.point_residual_arrays()
        tags = tag_metrics_hook(model, over_time=over_time)
        warnings = model.warnings[n_warnings:]
        del model.warnings[n_warnings:]             # added back below, after the volumes'
        return tags, warnings
    progress.stage("measure")
    metrics, other = fork_map(part, ["measure", "tags" if tagged else "residuals"], jobs=jobs,
                              here={"measure"})
    if not tagged:
        model.provide_point_residuals(other)
        return metrics, None
    tags, warnings = other
    model.warnings += warnings
    return metrics, tags


def analyse_study(study: Study, *, heart_rate_bpm: float | None = None
                  ) -> tuple[BiventricularModel, dict[str, float]]:
    """Reconstruct and measure one loaded study: (model, docs/metrics.md dict) -- the metrics
    only (what a cohort row needs: no tag time course), in this process (a cohort runs one
    study per core).

    Parameters
    ----------
    study : cardionurbs.study.Study
        A loaded study.
    heart_rate_bpm : float or None, optional
        Heart rate in beats/min for the rate metrics (None: the study's own).

    Returns
    -------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model.
    metrics : dict of str to float
        docs/metrics.md column -> value (NaN where not measured).
    """
    model, metrics, _ = analyse(study, heart_rate_bpm=heart_rate_bpm, over_time=False, jobs=1)
    return model, metrics


def write_analysis(model: BiventricularModel, metrics: dict, out: str | Path, *,
                   figures: bool = True, mesh_ext: str = "ply", tags=None,
                   outputs: tuple[str, ...] | None = None,
                   progress: Progress | None = None, jobs: int | None = 1,
                   early_meshes: "EarlyMeshes | None" = None, uncertainty: bool = True) -> Path:
    """Write the chosen ``outputs`` to ``out``, atomically (complete or untouched).

    Parameters
    ----------
    model, metrics, tags, out : BiventricularModel; dict; TagMetrics or None; path-like
        The results of :func:`analyse`; the output folder (docs/outputs.md).
    figures, mesh_ext, outputs, uncertainty : bool; str; tuple of str or None; bool
        False drops figures and report; the mesh format (``ply``, ``stl``, ``obj``, ``glb``);
        the outputs (:data:`OUTPUTS`; None: all); the 95 % intervals in metrics.json.
    progress, jobs, early_meshes : Progress or None; int or None; EarlyMeshes or None
        Stages on stderr; worker processes for the meshes and figures (1: none; None: the
        usable CPUs); the meshes already started (:class:`EarlyMeshes`).

    Returns
    -------
    pathlib.Path
    """
    outputs = OUTPUTS if outputs is None else tuple(outputs)
    if not figures:
        outputs = tuple(o for o in outputs if o not in ("figures", "report"))
    progress = progress or Progress(False)
    # the study, the model and the libraries are exempt from the garbage collector's passes
    # while the outputs are made (cardionurbs.heap)
    with long_lived(), atomic.atomic_dir(out) as tmp:
        if "meshes" in outputs:
            progress.stage("meshes")
            if early_meshes is not None and early_meshes.writer is not None:
                early_meshes.finish_into(tmp / "meshes", progress)
            else:
                write_meshes(model, tmp / "meshes", mesh_ext, jobs=jobs, progress=progress)

        def model_and_metrics() -> None:
            if "model" in outputs:
                progress.stage("model")
                with acyclic():                         # plain lists and dicts
                    save_model(model, tmp / "model.json", tags=tags)
                try:                                   # the cad extra: Rhino .3dm of the ED surfaces
                    import rhino3dm  # noqa: F401
                except ImportError:
                    pass
                else:
                    export_model_3dm(model, tmp / "model.3dm")
                # ED and ES (every frame: model.residuals); the table's CSV without pandas
                atomic.write_text(tmp / "residuals.csv", table_csv(model.residual_columns()))
            if "metrics" in outputs:
                progress.stage("metrics")
                from cardionurbs.analysis.quality import assess, residual_summary
                quality = assess(model, metrics)
                summary = residual_summary(model)      # ED and ES, per surface (no pandas)
                write_json({"subject": model.study.subject,
                            "metrics": {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                        for k, v in metrics.items()},
                            "ed_frame": model.ed_frame, "es_frame": model.es_frame,
                            "volume_curve": volume_curve(model, every_structure=bool(
                                {"meshes", "figures", "report"} & set(outputs))),
                            "residuals": summary,
                            "residual_frames": sorted({model.ed_frame, model.es_frame}),
                            "tags": None if tags is None else tags.to_json(),
                            "quality": quality.to_json(), "QC": "; ".join(quality.flags),
                            "regional": (None if getattr(model, "regional", None) is None
                                         else model.regional.to_json()),
                            "notes": {**dict(model.study.meta.get("metric_notes") or {}),
                                      **notes_of(metrics)},
                            "body": body_json(model.study),
                            "ranges": range_flags_json(metrics, model.study),
                            "uncertainty": intervals(model, metrics) if uncertainty else None,
                            "warnings": analysis_warnings(model, metrics, tags)},
                           tmp / "metrics.json")

        fig_set = None
        if "figures" in outputs:
            # the figures' workers draw while this process writes the model and the metrics
            # (the figures read the model as it is now: every volume is known once the meshes
            # are written; without them the metrics' volume curve computes them first)
            overlap = "meshes" in outputs or len(model.volumes.computed) == len(model.frames)
            if not overlap:
                model_and_metrics()
            progress.stage("figures")

            def then_figures() -> None:
                model_and_metrics()
                progress.stage("figures")

            fig_set = _figures(model, metrics, tmp, tags=tags, jobs=jobs,
                               meanwhile=then_figures if overlap else None)
        else:
            model_and_metrics()
        if "report" in outputs:
            progress.stage("report")
            # the tag surfaces just written, from memory; the model as model.json saved it
            # (its stated precision: `cardionurbs report` on the folder makes the same page)
            _report(tmp, model=load_model(tmp / "model.json") if "model" in outputs else None,
                    tag_data=getattr(fig_set, "report_tags", None))
        progress.done()
    return Path(out)


def save_model(model: BiventricularModel, path: str | Path, tags=None) -> Path:
    """Write the model file (``model.json``, or ``model.npz`` by the suffix), compact
    (:mod:`cardionurbs.io.modelfile`), atomically.

    Parameters
    ----------
    model : BiventricularModel
        The model (its surfaces in scanner mm, ED/ES, valve planes, sections).
    path : str or Path
        ``.json`` or ``.npz``.
    tags : TagMetrics, optional
        The tag result of :func:`analyse`: its tag surfaces are saved with the model.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ExportError
        A suffix other than ``.json`` or ``.npz``.
    """
    model_dict = model.to_dict()
    if tags is not None:                       # tag surfaces are saved with the model
        from cardionurbs.analysis.tags import tag_surfaces_dict
        model_dict["tag_surfaces"] = tag_surfaces_dict(
            model.study, long_axis=model.long_axis(), surfaces=tags.surfaces)
    return write_model_file(model_dict, path)


def load_model(path: str | Path, study: Study | None = None) -> BiventricularModel:
    """Read a model file (``model.json`` of any version, or ``model.npz``).

    Parameters
    ----------
    path : str or Path
        A model file written by :func:`save_model`.
    study : Study, optional
        The study the model was reconstructed from (default: one reduced to subject,
        heart rate, ED/ES and the long-axis landmarks, which every volume, mass and
        wall-thickness metric needs).

    Returns
    -------
    BiventricularModel

    Raises
    ------
    ExportError
        The file cannot be read or is not a cardionurbs model file.
    """
    return BiventricularModel.from_dict(read_model_file(path), study=study)


def write_meshes(model: BiventricularModel, mesh_dir: Path, mesh_ext: str = "ply", *,
                 jobs: int | None = 1, progress: Progress | None = None) -> None:
    """Every frame's closed meshes into ``mesh_dir`` (``frame_NN_<mesh>.<mesh_ext>``), with
    every frame's volumes kept in ``model.volumes`` (the volume curve of metrics.json and
    the figures); ``jobs`` worker processes (:class:`MeshWriter`; 1, the default: all here;
    None: the usable CPUs).

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model (``model.volumes`` filled for every frame).
    mesh_dir : pathlib.Path
        The folder the meshes go to (made when missing).
    mesh_ext : str, optional
        The mesh format: ``"ply"`` (default), ``"vtp"`` (with point data and a ``.pvd``
        series) or any extension trimesh exports (``"stl"``, ``"obj"``).
    jobs : int or None, optional
        Worker processes (1, the default: all here; None: the usable CPUs).
    progress : cardionurbs.progress.Progress or None, optional
        Where the frames meshed are counted.
    """
    MeshWriter(model, mesh_dir, mesh_ext, jobs=jobs).finish(progress)


class MeshWriter:
    """Every frame's meshes written into ``mesh_dir``, started when made and finished by
    :meth:`finish` (or stopped by :meth:`cancel`).

    ED and ES are meshed in this process (their solids stay cached) by :meth:`finish`; the
    other frames by ``jobs`` worker processes forked when this is made
    (:class:`cardionurbs.parallel.ForkMap`; None: the usable CPUs, 1: every frame here, in
    :meth:`finish`), which work while this process goes on (``analyze`` starts them once
    ED and ES are known, before the tags are measured). Each worker writes its frames'
    files and hands back what a frame added to the model (surfaces, volumes:
    :func:`cardionurbs.anatomy.handback.frame_results`) and its warnings, added in frame order: the
    model ends as a serial loop leaves it, less the other frames' solids (released after
    writing, as that loop does).

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model (ED and ES frames chosen).
    mesh_dir : pathlib.Path
        The folder the meshes go to (made now when missing).
    mesh_ext : str, optional
        The mesh format (see :func:`write_meshes`).
    jobs : int or None, optional
        Worker processes (None, the default: the usable CPUs; 1: every frame in :meth:`finish`).
    """

    def __init__(self, model: BiventricularModel, mesh_dir: Path, mesh_ext: str = "ply", *,
                 jobs: int | None = None) -> None:
        from cardionurbs.parallel import ForkMap
        self.model = model
        keep = {model.ed_frame, model.es_frame}
        before = handback.computed(model)
        Path(mesh_dir).mkdir(parents=True, exist_ok=True)

        def frame_meshes(f: int) -> tuple[dict, list[str]]:
            n_warnings = len(model.warnings)
            model.volumes[f]
            if mesh_ext == "ply":                   # straight from the manifold3d arrays
                for name, (v, fc) in model.mesh_arrays(f).items():
                    write_ply(v, fc, Path(mesh_dir) / f"frame_{f:02d}_{name}.ply")
            elif mesh_ext == "vtp":                 # VTK PolyData with point data
                from cardionurbs.analysis.mesh_fields import write_frame_vtp
                write_frame_vtp(model, f, mesh_dir)
            else:                                   # other formats: trimesh's exporters
                for name, m in model.meshes(f).items():
                    export_mesh(m, Path(mesh_dir) / f"frame_{f:02d}_{name}.{mesh_ext}")
            warnings = model.warnings[n_warnings:]
            del model.warnings[n_warnings:]         # added back by finish, in frame order
            results = handback.frame_results(model, f, before)
            if f not in keep:                       # the meshes written and let go
                model.release(f)
            return results, warnings

        self.mesh_dir, self.mesh_ext = Path(mesh_dir), mesh_ext
        self.work = ForkMap(frame_meshes, model.frames, jobs=jobs, here=keep)

    @property
    def forked(self) -> bool:
        """True when worker processes are meshing (else :meth:`finish` does every frame)."""
        return self.work.workers > 0

    def finish(self, progress: Progress | None = None) -> None:
        """Mesh ED and ES here, collect the workers' frames, update the model.

        Parameters
        ----------
        progress : cardionurbs.progress.Progress or None, optional
            Where the frames meshed are counted.
        """
        progress = progress or Progress(False)
        model, done = self.model, [0]

        def step(i, result) -> None:
            done[0] += 1
            progress.step(done[0], len(model.frames))

        # (a worker's values and warnings are what its frame added after the fork; nothing
        # this process does between the fork and here -- the tags -- builds surfaces or
        # solids of frames other than ED and ES, so the warnings are not added twice)
        for f, (results, warnings) in zip(model.frames, self.work.results(on_result=step)):
            handback.adopt_frame_results(model, f, results)
            model.warnings += warnings
        if self.mesh_ext == "vtp":                  # the time series ParaView plays
            from cardionurbs.analysis.mesh_fields import write_pvd_series
            write_pvd_series(model, self.mesh_dir)

    def cancel(self) -> None:
        """Stop the workers (nothing once finished)."""
        self.work.cancel()


class EarlyMeshes:
    """The meshes of ``analyze`` started as soon as ED and ES are known (:meth:`start`, the
    ``on_measured`` hook of :func:`analyse`), in a marked temporary folder beside the
    output (:func:`cardionurbs.io.atomic.sibling_temporary_dir`) that
    :func:`write_analysis` moves into its own; :meth:`close` stops the workers and removes
    that folder when the analysis did not get that far.

    Parameters
    ----------
    out : path-like
        The output folder of ``analyze`` (the temporary folder is made beside it).
    mesh_ext : str, optional
        The mesh format (see :func:`write_meshes`).
    jobs : int or None, optional
        Worker processes (None: the usable CPUs; 1: nothing is started early).
    """

    def __init__(self, out: str | Path, mesh_ext: str = "ply", jobs: int | None = None) -> None:
        self.out, self.mesh_ext, self.jobs = Path(out), mesh_ext, jobs
        self.writer: MeshWriter | None = None
        self.folder: Path | None = None

    def start(self, model: BiventricularModel) -> None:
        """Fork the mesh workers for the frames other than ED and ES (nothing when only one
        process would work: :func:`write_analysis` meshes every frame then).

        Parameters
        ----------
        model : cardionurbs.anatomy.model.BiventricularModel
            The model, its ED and ES frames chosen.
        """
        from cardionurbs.parallel import worker_count
        n_other = len(set(model.frames) - {model.ed_frame, model.es_frame})
        if worker_count(self.jobs, n_other, 1) == 0:
            return                                 # one process: write_analysis meshes later
        self.folder = atomic.sibling_temporary_dir(self.out)
        self.writer = MeshWriter(model, self.folder / "meshes", self.mesh_ext, jobs=self.jobs)

    def finish_into(self, mesh_dir: Path, progress: Progress | None = None) -> None:
        """Finish the meshes and move them to ``mesh_dir``.

        Parameters
        ----------
        mesh_dir : pathlib.Path
            The final meshes folder (must not exist yet).
        progress : cardionurbs.progress.Progress or None, optional
            Where the frames meshed are counted.
        """
        assert self.writer is not None and self.folder is not None, "start() wrote no meshes"
        self.writer.finish(progress)
        os.replace(self.folder / "meshes", mesh_dir)

    def close(self) -> None:
        """Stop the workers and remove the temporary folder (nothing once moved)."""
        if self.writer is not None:
            self.writer.cancel()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
        self.writer = self.folder = None


def _figures(model: BiventricularModel, metrics: dict, out_dir: Path, tags=None,
             jobs: int | None = None, meanwhile=None):
    """The figures into ``out_dir/figures`` (a cardionurbs.report.figures.FigureSet), drawn by
    ``jobs`` processes while this one runs ``meanwhile``; None without the report module
    (``meanwhile`` is then run alone)."""
    try:
        from cardionurbs.report.figures import render_figures
    except ImportError:
        if meanwhile is not None:
            meanwhile()
        return None
    return render_figures(model, Path(out_dir) / "figures", metrics=metrics, tags=tags,
                          jobs=jobs, meanwhile=meanwhile)


def _report(out_dir: Path, model: BiventricularModel | None = None,
            tag_data: dict | None = None) -> Path | None:
    try:
        from cardionurbs.report.html import write_report
    except ImportError:
        return None
    return write_report(out_dir, Path(out_dir) / "report.html", model=model, tag_data=tag_data)


def _label_option(args: argparse.Namespace) -> dict:
    """``labels=``, ``ed_frame=``, ``es_frame=`` for load_study when ``--labels``,
    ``--ed-frame``, ``--es-frame`` were given (NIfTI label maps)."""
    opts = {k: getattr(args, k, None) for k in ("labels", "ed_frame", "es_frame")}
    return {k: v for k, v in opts.items() if v is not None}


def study_folder(path: str | Path) -> Path:
    """The folder of a study given as a folder or as a file in it (its study.json); a
    single-file study (a NIfTI label map) is the file itself, whose reader reads nothing
    else, so an output folder beside it is allowed.

    Parameters
    ----------
    path : path-like
        A study folder, a file in it, or a NIfTI label map.

    Returns
    -------
    pathlib.Path
        The folder the study's files lie in (the NIfTI file itself for a single-file study).
    """
    p = Path(path)
    if p.is_file() and p.name.lower().endswith((".nii", ".nii.gz")):
        return p
    return p if p.is_dir() or not p.exists() else p.parent


def run_analyze(args: argparse.Namespace) -> int:
    """Load, reconstruct, measure and write one study (outputs: docs/formats.md); ``--out`` is
    checked (cardionurbs.io.outputs) before anything is read; ``--outputs`` chooses what is
    written, ``--progress`` (or a terminal on stderr) shows the stages.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``analyze`` command line (``study``, ``out``, ``format``, ``outputs`` ...).

    Returns
    -------
    int
        The exit code, 0.

    Raises
    ------
    cardionurbs.errors.UsageError
        An unknown ``--outputs`` name.
    cardionurbs.errors.ExportError
        ``--mesh-format vtp`` without the vtk extra (before any work).
    cardionurbs.errors.OutputError
        ``--out`` may not be written (checked before anything is read).
    cardionurbs.errors.StudyError
        The study cannot be read.
    """
    from cardionurbs.io.outputs import check_output_dir
    try:
        outputs = parse_outputs(getattr(args, "outputs", None))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if getattr(args, "no_figures", False):
        outputs = tuple(o for o in outputs if o not in ("figures", "report"))
    check_output_dir(args.out, inputs=[study_folder(args.study)],
                     overwrite=getattr(args, "overwrite", False))
    if getattr(args, "mesh_format", None) == "vtp" and "meshes" in outputs:
        from cardionurbs.io.vtkfiles import require_vtk
        require_vtk()                            # before any work: the vtk extra is there
    progress = Progress(True if getattr(args, "progress", False) else None, prefix="analyze")
    progress.stage("load")
    study = load_study(args.study, format=args.format,
                       allow_outside=getattr(args, "allow_outside", False), **_label_option(args))
    if getattr(args, "pathology", None):      # the stated question (MR RegVol, docs/metrics.md)
        study.meta = dict(study.meta, pathology=str(args.pathology))
    if getattr(args, "track_tags", False):
        from cardionurbs.tracking import track_tags
        study = track_tags(study)
    given = {k: getattr(args, a, None) for k, a in (("height_cm", "height_cm"),
                                                     ("weight_kg", "weight_kg"),
                                                     ("age_y", "age"), ("sex", "sex"))}
    if any(v is not None for v in given.values()):
        from cardionurbs.io.body import attach_body
        attach_body(study, given)
    jobs = getattr(args, "jobs", None)
    # the meshes need only the model: their workers start once ED and ES are known and work
    # while this process measures the tags
    mesh_ext = getattr(args, "mesh_format", None) or "ply"
    # (.vtp carries the regional results on the meshes: written once they are measured)
    early = EarlyMeshes(args.out, mesh_ext, jobs=jobs) \
        if "meshes" in outputs and mesh_ext != "vtp" else None
    try:
        model, metrics, tags = analyse(study, heart_rate_bpm=getattr(args, "heart_rate", None),
                                       over_time=bool({"figures", "report"} & set(outputs))
                                       or ("meshes" in outputs and mesh_ext == "vtp"),
                                       progress=progress, jobs=jobs,
                                       on_measured=None if early is None else early.start)
        write_analysis(model, metrics, args.out, outputs=outputs, tags=tags, progress=progress,
                       jobs=jobs, early_meshes=early, mesh_ext=mesh_ext,
                       uncertainty=getattr(args, "uncertainty", "on") == "on")
    finally:
        if early is not None:
            early.close()
    print(summary_line(study.subject, model, metrics, args.out))
    qc = json.loads((Path(args.out) / "metrics.json").read_text()).get("QC") \
        if "metrics" in outputs else None
    if qc:
        print(f"QC: {qc}")
    report_warnings(analysis_warnings(model, metrics, tags), verbose=getattr(args, "verbose", False))
    return 0


def _value(metrics: dict, column: str, unit: str) -> str:
    v = metrics.get(column)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        why = notes_of(metrics).get(column)
        return f"— ({why})" if why else "—"
    return f"{v:.1f} {unit}"


def summary_line(subject: str, model: BiventricularModel, metrics: dict, out) -> str:
    """``analyze``'s line on stdout: ED/ES, LVEDV and LVEF (a null one with its reason).

    Parameters
    ----------
    subject : str
        The study's subject.
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model (its ED and ES frame indices, 0-based).
    metrics : dict
        Its docs/metrics.md dict.
    out : path-like
        The output folder written.

    Returns
    -------
    str
        One line: ED and ES frames, LVEDV in mL and LVEF in %, the output folder.
    """
    return (f"{subject}: ED frame {model.ed_frame}, ES frame {model.es_frame}; "
            f"LVEDV {_value(metrics, 'LVEDV (mL)', 'mL')}, LVEF {_value(metrics, 'LVEF (%)', '%')}; "
            f"wrote {out}")


#: how many warnings ``analyze`` prints without --verbose
SHOWN_WARNINGS = 3


def report_warnings(warnings: list[dict], *, verbose: bool = False, file=None) -> None:
    """On stderr: ``N warnings (load 2, reconstruct 1; all in metrics.json)`` and the first
    :data:`SHOWN_WARNINGS` of them, load warnings first (every one with ``verbose``).

    Parameters
    ----------
    warnings : list of dict
        ``{"source", "message"}`` per warning (:func:`analysis_warnings`).
    verbose : bool, optional
        Print every warning, not the first :data:`SHOWN_WARNINGS`.
    file : text stream, optional
        Where to print (default :data:`sys.stderr`).
    """
    import sys
    file = file or sys.stderr
    if not warnings:
        return
    counts = {s: sum(w["source"] == s for w in warnings) for s in ("load", "reconstruct", "measure")}
    parts = ", ".join(f"{s} {n}" for s, n in counts.items() if n)
    shown = warnings if verbose else warnings[:SHOWN_WARNINGS]
    more = "" if verbose or len(warnings) <= SHOWN_WARNINGS else "; --verbose shows all"
    print(f"{len(warnings)} warning{'s' if len(warnings) != 1 else ''} ({parts}; "
          f"all in metrics.json{more})", file=file)
    for w in shown:
        print(f"  {w['source']}: {w['message']}", file=file)
