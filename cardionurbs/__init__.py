"""cardionurbs: NURBS models of the heart's ventricles from cardiac MR.

Public API (README.md, "Python API")::

    import cardionurbs as cn
    study = cn.load_study(path)          # native | sunnybrook | gpfile | phantom
    model = cn.reconstruct(study)        # NURBS surfaces per frame, scanner mm
    meshes = model.meshes(frame)         # closed manifold trimesh.Trimesh
    m = cn.measure(model)                # docs/metrics.md column -> float
    table = cn.cohort(paths)             # pandas.DataFrame
    tracked = cn.track_tags(study)       # tag lines tracked from the tagged DICOM (HARP)
    cn.save_model(model, "model.json")   # compact model file (.json or .npz)
    model = cn.load_model("model.json")

``load_study(path)`` (:func:`cardionurbs.io.load_study`) reads a study folder or file
into a :class:`Study` in scanner mm; ``reconstruct(study)``
(:func:`cardionurbs.anatomy.model.reconstruct`) gives the ``BiventricularModel``;
``measure(model)`` (:func:`cardionurbs.analysis.function.measure`) the metrics of
docs/metrics.md, a dict column -> float (mL, g, %, ms; NaN where the study cannot give one).

Examples
--------
A phantom heart whose volumes are known in closed form, written as a study folder, read,
reconstructed and measured (the LV end-diastolic volume within 1 % of the truth):

>>> import pathlib, tempfile
>>> import cardionurbs as cn
>>> from cardionurbs.phantom import generate, write_phantom
>>> phantom = generate("normal", seed=1, frames=2, volume_check=False)
>>> tmp = tempfile.TemporaryDirectory()
>>> folder = write_phantom(phantom, pathlib.Path(tmp.name) / "normal_001", dicom=False)
>>> study = cn.load_study(folder)
>>> study.subject, sorted(study.frames)
('normal_001', [0, 1])
>>> model = cn.reconstruct(study)
>>> m = cn.measure(model)
>>> truth = phantom.truth["metrics"]["LVEDV (mL)"]
>>> bool(abs(m["LVEDV (mL)"] - truth) < 0.01 * truth)
True
>>> tmp.cleanup()
"""

from __future__ import annotations

import importlib
import sys
import types

from cardionurbs.errors import (CardioNurbsError, NurbsInputError, PhantomError,
                                ReconstructionError, StudyError, TagError,
                                UnsupportedInputError)

__version__ = "0.1.0"

__all__ = [
    "CardioNurbsError", "NurbsInputError", "PhantomError", "ReconstructionError",
    "StudyError", "TagError", "UnsupportedInputError",
    "Study", "Contour", "TagLine", "Landmark",
    "load_study", "reconstruct", "measure", "cohort", "nurbs", "track_tags",
    "save_model", "load_model",
]

#: public name -> (module, attribute): resolved on first use, so that importing one layer
#: (e.g. ``import cardionurbs.nurbs``) does not load the others (docs/architecture.md).
_LAZY = {
    "nurbs": ("cardionurbs.nurbs", None),
    "Study": ("cardionurbs.study", "Study"), "Contour": ("cardionurbs.study", "Contour"),
    "TagLine": ("cardionurbs.study", "TagLine"), "Landmark": ("cardionurbs.study", "Landmark"),
    "load_study": ("cardionurbs.io", "load_study"),
    "reconstruct": ("cardionurbs.anatomy.model", "reconstruct"),
    "measure": ("cardionurbs.analysis.function", "measure"),
    "cohort": ("cardionurbs.cohort", "cohort"),
    "track_tags": ("cardionurbs.tracking", "track_tags"),
    "save_model": ("cardionurbs.pipeline", "save_model"),
    "load_model": ("cardionurbs.pipeline", "load_model"),
}


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'cardionurbs' has no attribute {name!r}")
    module, attr = _LAZY[name]
    mod = importlib.import_module(module)
    return mod if attr is None else getattr(mod, attr)


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


class _Facade(types.ModuleType):
    """The package's module type: ``cn.cohort`` stays the function, though importing the
    submodule :mod:`cardionurbs.cohort` names it on the package (the import system's setattr
    is ignored here; the submodule stays in ``sys.modules``, where ``from cardionurbs.cohort
    import ...`` finds it)."""

    @property
    def cohort(self):
        from cardionurbs.cohort import cohort
        return cohort

    @cohort.setter
    def cohort(self, value) -> None:
        pass


sys.modules[__name__].__class__ = _Facade
