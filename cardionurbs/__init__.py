"""cardionurbs: NURBS models of the heart's ventricles from cardiac MR.

Public API (README.md, "Python API")::

    import cardionurbs as cn
    study = cn.load_study(path)          # native | sunnybrook | gpfile | phantom
    model = cn.reconstruct(study)        # NURBS surfaces per frame, scanner mm
    meshes = model.meshes(frame)         # closed manifold trimesh.Trimesh
    m = cn.measure(model)                # docs/metrics.md column -> float
    table = cn.cohort(paths)             # pandas.DataFrame
"""

from __future__ import annotations

from cardionurbs.errors import (CardioNurbsError, NurbsInputError, PhantomError,
                                ReconstructionError, StudyError, TagError,
                                UnsupportedInputError)
from cardionurbs.io import load_study
from cardionurbs.study import Contour, Landmark, Study, TagLine

__version__ = "0.1.0"

__all__ = [
    "CardioNurbsError", "NurbsInputError", "PhantomError", "ReconstructionError",
    "StudyError", "TagError", "UnsupportedInputError",
    "Study", "Contour", "TagLine", "Landmark",
    "load_study", "reconstruct", "measure", "cohort", "nurbs",
]


def __getattr__(name):  # lazy: keep `import cardionurbs` light and acyclic
    if name == "nurbs":
        import importlib
        return importlib.import_module("cardionurbs.nurbs")
    if name == "reconstruct":
        from cardionurbs.anatomy.model import reconstruct
        return reconstruct
    if name == "measure":
        from cardionurbs.analysis.function import measure
        return measure
    if name == "cohort":
        from cardionurbs.cohort import cohort
        return cohort
    raise AttributeError(f"module 'cardionurbs' has no attribute {name!r}")
