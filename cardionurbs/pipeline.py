"""`cardionurbs analyze`: one study in, its model, meshes, metrics and figures out.

Output folder (written atomically: complete or absent)::

    DIR/metrics.json        {"subject", "metrics": {docs/metrics.md column: value},
                             "ed_frame", "es_frame", "volume_curve", "residuals",
                             "quality": {per metric: flags, surfaces, frames; per
                             surface and frame: fit residual median/p95/max in mm
                             and px; contours left out}, "QC", "notes", "warnings"}
                             (notes: metric -> why it is null)
    DIR/model.json          the NURBS model (BiventricularModel.to_dict)
    DIR/model.3dm           the ED surfaces as Rhino NURBS (with the ``cad`` extra)
    DIR/residuals.csv       contour-point-to-surface distances per slice, at ED and ES
    DIR/meshes/frame_NN_<mesh>.ply   closed meshes per frame and structure (binary PLY,
                                     float64 vertices: exactly the manifold3d result)
    DIR/figures/...         PNG figures + figures.json (cardionurbs.report.figures, via
                            :func:`figures_hook`; skipped with --no-figures)
    DIR/report.html         self-contained offline viewer (cardionurbs.report.html)
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from cardionurbs.analysis.function import measure, volume_curve
from cardionurbs.anatomy.model import BiventricularModel, reconstruct
from cardionurbs.io import atomic, load_study
from cardionurbs.safe import csv_safe_table
from cardionurbs.io.export import export_mesh, export_model_3dm, write_json
from cardionurbs.study import Study


def tag_metrics_hook(model: BiventricularModel):
    """Tag metrics (Twist, Twist 2D, Torsion, CL shear, LS, QC flags) from
    ``cardionurbs.analysis.tags.tag_metrics(model)`` -- a mapping docs/metrics.md column ->
    float, with the level table, QC flags and tag surfaces as attributes -- when the
    study has tag lines; None otherwise (the columns then stay NaN). Twist and LS over
    time are included when three or more frames are tagged, so this one result serves
    the metrics, metrics.json, model.json and the figures."""
    if not model.study.tags:
        return None
    from cardionurbs.analysis.tags import tag_metrics
    return tag_metrics(model, over_time=len(model.study.tagged_frames) >= 3)


def figures_hook(model: BiventricularModel, metrics: dict, out_dir: Path, tags=None) -> list[Path]:
    """Figures of an analysis into ``out_dir/figures``:
    ``cardionurbs.report.figures.write_figures(model, out_dir, metrics=, tags=)``, then the
    self-contained HTML viewer ``out_dir/report.html``
    (``cardionurbs.report.html.write_report``), when the report module provides them;
    [] otherwise."""
    try:
        from cardionurbs.report.figures import write_figures
        from cardionurbs.report.html import write_report
    except ImportError:
        return []
    paths = list(write_figures(model, Path(out_dir) / "figures", metrics=metrics, tags=tags) or [])
    return paths + [write_report(out_dir, Path(out_dir) / "report.html")]


def analyse(study: Study, *, heart_rate_bpm: float | None = None):
    """Reconstruct and measure one loaded study: (model, docs/metrics.md dict, tag result or None)."""
    model = reconstruct(study)
    metrics = measure(model, heart_rate_bpm=heart_rate_bpm)
    tags = tag_metrics_hook(model)
    if tags is not None:
        metrics.update({k: float(v) for k, v in dict(tags).items() if k in metrics})
    from cardionurbs.analysis.regional import regional_metrics
    regional = regional_metrics(model, tags)
    metrics.update({k: float(v) for k, v in regional.items() if k in metrics})
    model.regional = regional                     # kept for metrics.json and the figures
    voxels = study.meta.get("voxel_volumes_ml") if isinstance(study.meta, dict) else None
    if voxels:                              # label maps: voxel counting beside the model
        from cardionurbs.analysis.voxels import voxel_metrics
        metrics.update(voxel_metrics(voxels, model.ed_frame, model.es_frame))
    return model, metrics, tags


def analyse_study(study: Study, *, heart_rate_bpm: float | None = None
                  ) -> tuple[BiventricularModel, dict[str, float]]:
    """Reconstruct and measure one loaded study: (model, docs/metrics.md dict)."""
    model, metrics, _ = analyse(study, heart_rate_bpm=heart_rate_bpm)
    return model, metrics


def write_analysis(model: BiventricularModel, metrics: dict, out: str | Path, *,
                   figures: bool = True, mesh_ext: str = "ply", tags=None) -> Path:
    """Write metrics.json, model.json, residuals.csv, meshes (and figures) to ``out``,
    atomically (the folder is complete or untouched)."""
    with atomic.atomic_dir(out) as tmp:
        mesh_dir = tmp / "meshes"
        for f in model.frames:
            for name, m in model.meshes(f).items():
                export_mesh(m, mesh_dir / f"frame_{f:02d}_{name}.{mesh_ext}")
        model_dict = model.to_dict()
        if tags is not None:                   # tag surfaces are saved with the model
            from cardionurbs.analysis.tags import tag_surfaces_dict
            model_dict["tag_surfaces"] = tag_surfaces_dict(
                model.study, long_axis=model.long_axis(), surfaces=tags.surfaces)
        write_json(model_dict, tmp / "model.json")
        try:                                   # the cad extra: Rhino .3dm of the ED surfaces
            import rhino3dm  # noqa: F401
        except ImportError:
            pass
        else:
            export_model_3dm(model, tmp / "model.3dm")
        res = model.residual_table()            # ED and ES (every frame: model.residuals)
        from cardionurbs.analysis.quality import assess
        quality = assess(model, metrics)
        atomic.write_text(tmp / "residuals.csv", csv_safe_table(res).to_csv(index=False))
        summary = {}
        for s, g in res.groupby("structure"):
            summary[s] = {"mean_mm": float(g["mean_mm"].mean()), "max_mm": float(g["max_mm"].max()),
                          "max_px": float(g["max_px"].max())}
        write_json({"subject": model.study.subject,
                    "metrics": {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                for k, v in metrics.items()},
                    "ed_frame": model.ed_frame, "es_frame": model.es_frame,
                    "volume_curve": volume_curve(model), "residuals": summary,
                    "residual_frames": sorted({model.ed_frame, model.es_frame}),
                    "tags": None if tags is None else tags.to_json(),
                    "quality": quality.to_json(), "QC": "; ".join(quality.flags),
                    "regional": (None if getattr(model, "regional", None) is None
                                 else model.regional.to_json()),
                    "notes": dict(model.study.meta.get("metric_notes") or {}),
                    "warnings": model.warnings}, tmp / "metrics.json")
        if figures:
            figures_hook(model, metrics, tmp, tags=tags)
    return Path(out)


def _label_option(args: argparse.Namespace) -> dict:
    """``labels=`` for load_study when ``--labels`` was given (NIfTI label maps)."""
    labels = getattr(args, "labels", None)
    return {} if labels is None else {"labels": labels}


def study_folder(path: str | Path) -> Path:
    """The folder of a study given as a folder or as a file in it (its study.json)."""
    p = Path(path)
    return p if p.is_dir() or not p.exists() else p.parent


def run_analyze(args: argparse.Namespace) -> int:
    """Load, reconstruct, measure and write one study (outputs: docs/formats.md); ``--out`` is checked
    (cardionurbs.io.outputs) before anything is read."""
    from cardionurbs.io.outputs import check_output_dir
    check_output_dir(args.out, inputs=[study_folder(args.study)],
                     overwrite=getattr(args, "overwrite", False))
    study = load_study(args.study, format=args.format,
                       allow_outside=getattr(args, "allow_outside", False), **_label_option(args))
    if getattr(args, "track_tags", False):
        from cardionurbs.tracking import track_tags
        study = track_tags(study)
    model, metrics, tags = analyse(study, heart_rate_bpm=getattr(args, "heart_rate", None))
    write_analysis(model, metrics, args.out, figures=not getattr(args, "no_figures", False),
                   tags=tags)
    print(f"{study.subject}: ED frame {model.ed_frame}, ES frame {model.es_frame}; "
          f"LVEDV {metrics['LVEDV (mL)']:.1f} mL, LVEF {metrics['LVEF (%)']:.1f} %; "
          f"wrote {args.out}")
    qc = json.loads((Path(args.out) / "metrics.json").read_text()).get("QC")
    if qc:
        print(f"QC: {qc}")
    return 0
