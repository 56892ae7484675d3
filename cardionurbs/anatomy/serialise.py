"""A model as a JSON-safe dict and back (:meth:`BiventricularModel.to_dict` / ``from_dict``).

:func:`encode` gives the version-1 dict (surfaces as NURBS, valve planes, apex points, SA
sections, outflow tracts, ED/ES, the apex and mitral landmarks, warnings);
:func:`decode` reads it, or the compact version-2 dict of a model.json
(:mod:`cardionurbs.io.modelfile`), into the arguments of the model's constructor. Cached
values (solids, meshes, volumes, residuals) are never written: a model read back makes
them again from its surfaces.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cardionurbs import nurbs
from cardionurbs.anatomy.mesh import Plane
from cardionurbs.anatomy.outflow import OutflowTract
from cardionurbs.anatomy.sections import Section
from cardionurbs.io.modelfile import unpack
from cardionurbs.study import Landmark, Study


def _arr(a) -> list:
    return np.asarray(a, float).tolist()


def encode(model: Any) -> dict:
    """JSON-safe dict of a :class:`~cardionurbs.anatomy.model.BiventricularModel`: surfaces
    (NURBS), valve planes, apex points, SA sections, outflow tracts (frames that have them),
    ED/ES (``"format": "cardionurbs-model", "version": 1``).

    Parameters
    ----------
    model : BiventricularModel
        The model.

    Returns
    -------
    dict
        The version-1 model dict (JSON-safe: lists and numbers; coordinates in scanner mm).
    """
    return {
        "format": "cardionurbs-model", "version": 1,
        "subject": model.study.subject, "frames": model.frames,
        "ed_frame": model.ed_frame, "es_frame": model.es_frame,
        "heart_rate_bpm": model.study.heart_rate_bpm,
        "resolution": list(model.resolution),
        "surfaces": {str(f): {s: surf.to_dict() for s, surf in d.items()}
                     for f, d in model.surfaces.items()},
        "base_planes": {str(f): {k: p.to_dict() for k, p in d.items()}
                        for f, d in model.base_planes.items()},
        "apex_points": {str(f): {k: _arr(p) for k, p in d.items()}
                        for f, d in model.apex_points.items()},
        "sections": {str(f): {s: [{"slice": sec.slice, "points": _arr(sec.points)} for sec in secs]
                              for s, secs in d.items()} for f, d in model.sections.items()},
        "outflow": {str(f): {s: t.to_dict() for s, t in model.outflow[f].items()}
                    for f in model.frames if model.outflow[f]},
        "landmarks": [{"name": lm.name, "frame": lm.frame, "index": lm.index,
                       "point": _arr(lm.point)} for lm in model.study.landmarks
                      if lm.name in ("apex", "mitral")],
        "warnings": model.warnings,
    }


def decode(d: dict, study: Study | None = None) -> dict[str, Any]:
    """The keyword arguments of ``BiventricularModel(**kwargs)`` for a dict of
    :func:`encode` (or a model.json's version 2). The Study is reduced to subject, heart
    rate, ED/ES labels and the apex/mitral landmarks unless ``study`` is given.

    Parameters
    ----------
    d : dict
        A dict of :func:`encode`, or a model.json's compact version 2.
    study : Study or None
        The study the model was reconstructed from; None: a reduced one.

    Returns
    -------
    dict of str to object
        The keyword arguments of ``BiventricularModel(**kwargs)``.
    """
    d = unpack(d)
    if study is None:
        study = Study(subject=d["subject"], heart_rate_bpm=d.get("heart_rate_bpm"),
                      ed_frame=d.get("ed_frame"), es_frame=d.get("es_frame"),
                      landmarks=[Landmark(lm["name"], lm["frame"], lm["point"], lm["index"])
                                 for lm in d.get("landmarks", [])])
    surfaces = {int(f): {s: nurbs.NurbsSurface.from_dict(sd) for s, sd in dd.items()}
                for f, dd in d["surfaces"].items()}
    planes = {int(f): {k: Plane.from_dict(p) for k, p in dd.items()}
              for f, dd in d["base_planes"].items()}
    apex = {int(f): {k: np.asarray(p, float) for k, p in dd.items()}
            for f, dd in d["apex_points"].items()}
    sections = {int(f): {s: [Section(s, int(f), np.asarray(x["points"], float), slice=x["slice"])
                             for x in secs] for s, secs in dd.items()}
                for f, dd in d.get("sections", {}).items()}
    ed_es = (d["ed_frame"], d["es_frame"]) if "ed_frame" in d and "es_frame" in d else None
    outflow = {int(f): {s: OutflowTract.from_dict(td) for s, td in dd.items()}
               for f, dd in d.get("outflow", {}).items()}
    kwargs = {"study": study, "frames": d["frames"], "surfaces": surfaces, "base_planes": planes,
              "apex_points": apex, "outflow": outflow, "sections": sections,
              "warnings": d.get("warnings"), "ed_es": ed_es}
    if "resolution" in d:
        kwargs["resolution"] = tuple(d["resolution"])
    return kwargs
