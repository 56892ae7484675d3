"""The API reference's source: numpydoc sections on every public function and class of
cardionurbs.nurbs (each argument named under Parameters, a Returns section where a value
comes back), and the Examples of the main entry points run as doctests."""

from __future__ import annotations

import doctest
import importlib
import inspect
import pkgutil

import pytest

import cardionurbs.nurbs

NURBS_MODULES = sorted(m.name for m in pkgutil.iter_modules(cardionurbs.nurbs.__path__,
                                                             "cardionurbs.nurbs.")
                       if not m.name.rsplit(".", 1)[1].startswith("_"))
#: modules whose Examples are doctested (the package facade: load_study, reconstruct, measure)
DOCTESTED = ["cardionurbs", *NURBS_MODULES]
#: the entry points that must show an Examples section
EXAMPLES = ["NurbsCurve", "fit_curve", "loft", "tessellate"]


def _public(module):
    """(qualified name, object) of the module's own public functions, classes and methods."""
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
            continue
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj):
            yield name, obj
            for mname, m in vars(obj).items():
                if not mname.startswith("_") and inspect.isfunction(getattr(m, "__func__", m)):
                    yield f"{name}.{mname}", getattr(m, "__func__", m)


def _sections(doc: str) -> dict[str, str]:
    """numpydoc section title -> its text."""
    out, title, lines = {}, None, inspect.cleandoc(doc).splitlines()
    for i, line in enumerate(lines):
        if i + 1 < len(lines) and lines[i + 1].strip() and set(lines[i + 1].strip()) == {"-"} \
                and len(lines[i + 1].strip()) >= len(line.strip()) > 0:
            title = line.strip()
            out[title] = ""
        elif title is not None and not set(line.strip()) == {"-"}:
            out[title] += line + "\n"
    return out


def _documented_names(section: str) -> set[str]:
    names = set()
    for line in section.splitlines():
        if line and not line[0].isspace():              # "name : type" or "a, b : type"
            head = line.split(":")[0]
            names.update(n.strip().lstrip("*") for n in head.split(","))
    return names


@pytest.mark.parametrize("modname", NURBS_MODULES)
def test_every_public_nurbs_callable_has_numpydoc_sections(modname):
    module = importlib.import_module(modname)
    bad = []
    for qual, obj in _public(module):
        doc = inspect.getdoc(obj) or ""
        if not doc:
            bad.append(f"{qual}: no docstring")
            continue
        secs = _sections(doc)
        target = obj.__init__ if inspect.isclass(obj) else obj
        try:
            sig = inspect.signature(target)
        except (TypeError, ValueError):
            continue
        params = [p for p in sig.parameters if p not in ("self", "cls")]
        if inspect.isclass(obj) and issubclass(obj, tuple):          # NamedTuple: its fields
            missing = set(obj._fields) - _documented_names(secs.get("Attributes", ""))
            if missing:
                bad.append(f"{qual}: Attributes misses {sorted(missing)}")
            continue
        if params:
            missing = set(params) - _documented_names(secs.get("Parameters", ""))
            if missing:
                bad.append(f"{qual}: Parameters misses {sorted(missing)}")
        returns = sig.return_annotation
        if not inspect.isclass(obj) and returns not in (None, "None", inspect.Signature.empty) \
                and "Returns" not in secs and "Yields" not in secs:
            bad.append(f"{qual}: no Returns section")
    assert bad == []


@pytest.mark.parametrize("name", EXAMPLES)
def test_entry_points_have_examples(name):
    assert "Examples" in _sections(inspect.getdoc(getattr(cardionurbs.nurbs, name)))


def test_package_facade_has_examples():
    import cardionurbs
    assert "Examples" in _sections(cardionurbs.__doc__)
    assert all(f"cn.{n}(" in cardionurbs.__doc__ for n in ("load_study", "reconstruct", "measure"))


@pytest.mark.parametrize("modname", DOCTESTED)
def test_doctests(modname):
    module = importlib.import_module(modname)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False)
    assert result.failed == 0


# ----------------------------------------------------- the rest of the package (#35 item 4)
#: modules outside nurbs/, io/ and analysis/ (and anatomy/model.py) whose every public
#: function, class and method is checked
REST_MODULES = [
    "cardionurbs.cohort", "cardionurbs.confine", "cardionurbs.demo", "cardionurbs.executor",
    "cardionurbs.geometry", "cardionurbs.heap", "cardionurbs.limits", "cardionurbs.median",
    "cardionurbs.parallel", "cardionurbs.pipeline", "cardionurbs.progress", "cardionurbs.safe",
    "cardionurbs.workers",
    "cardionurbs.imaging.dicom", "cardionurbs.imaging.geometry", "cardionurbs.imaging.phases",
    "cardionurbs.imaging.stack",
    "cardionurbs.report.bullseye", "cardionurbs.report.chromium", "cardionurbs.report.cohort_figures",
    "cardionurbs.report.figures", "cardionurbs.report.html", "cardionurbs.report.overlay",
    "cardionurbs.tracking.harp", "cardionurbs.tracking.labelmaps", "cardionurbs.tracking.spectral",
    "cardionurbs.tracking.track",
    "cardionurbs.anatomy.cycle", "cardionurbs.anatomy.mesh", "cardionurbs.anatomy.outflow",
    "cardionurbs.anatomy.refine", "cardionurbs.anatomy.sections", "cardionurbs.anatomy.surfaces",
    "cardionurbs.phantom.anatomy", "cardionurbs.phantom.annotate", "cardionurbs.phantom.cli",
    "cardionurbs.phantom.dicom", "cardionurbs.phantom.faults", "cardionurbs.phantom.figures",
    "cardionurbs.phantom.generate", "cardionurbs.phantom.geometry", "cardionurbs.phantom.labelmaps",
    "cardionurbs.phantom.motion", "cardionurbs.phantom.outflow", "cardionurbs.phantom.presets",
    "cardionurbs.phantom.regional", "cardionurbs.phantom.shape", "cardionurbs.phantom.truth",
    "cardionurbs.phantom.truth_realistic",
]
#: names of those modules whose docstrings other branches of this session write (the facade
#: and docs/api.md objects: `types`; lines the `caches` branch rewrites); a name
#: here is skipped while undocumented and fails once documented, so the set may only shrink:
#: empty it as those branches land
REST_ELSEWHERE = {
    "cardionurbs.cohort.cohort", "cardionurbs.pipeline.analyse",
    "cardionurbs.pipeline.write_analysis", "cardionurbs.tracking.track.track_tags",
    "cardionurbs.phantom.anatomy.gauss_legendre",
}


def _rest_problems(qual: str, obj) -> list[str]:
    """Each argument named under Parameters (a class: its ``__init__``'s, a dataclass's or
    NamedTuple's fields, under Parameters or Attributes) and a Returns or Yields section
    where a function's annotation says it returns a value."""
    import dataclasses
    doc = inspect.getdoc(obj) or ""
    if not doc:
        return [f"{qual}: no docstring"]
    secs = _sections(doc)
    if inspect.isclass(obj):
        if issubclass(obj, tuple) and hasattr(obj, "_fields"):
            args = set(obj._fields)
        elif dataclasses.is_dataclass(obj):
            args = {f.name for f in dataclasses.fields(obj) if f.init and not f.name.startswith("_")}
        elif "__init__" in vars(obj):
            args = set(inspect.signature(obj.__init__).parameters) - {"self"}
        else:
            return []
        missing = args - _documented_names(secs.get("Parameters", "") + secs.get("Attributes", ""))
        return [f"{qual}: Parameters/Attributes miss {sorted(missing)}"] if missing else []
    sig = inspect.signature(obj)
    bad = []
    missing = set(sig.parameters) - {"self", "cls"} - _documented_names(secs.get("Parameters", ""))
    if missing:
        bad.append(f"{qual}: Parameters misses {sorted(missing)}")
    if sig.return_annotation not in (None, "None", inspect.Signature.empty) \
            and "Returns" not in secs and "Yields" not in secs:
        bad.append(f"{qual}: no Returns section")
    return bad


@pytest.mark.parametrize("modname", REST_MODULES)
def test_rest_of_the_package_has_numpydoc_sections(modname):
    module = importlib.import_module(modname)
    bad = []
    for qual, obj in _public(module):
        name = f"{modname}.{qual}"
        problems = _rest_problems(name, obj)
        if name in REST_ELSEWHERE:
            bad += [] if problems else [f"{name}: documented now: take it off REST_ELSEWHERE"]
        else:
            bad += problems
    assert bad == []


def test_rest_check_finds_what_is_missing():
    def f(a: int, *, b: float = 1.0) -> float:
        """Sum.

        Parameters
        ----------
        a : int
            One.
        """
        return a + b

    class C:
        """A class.

        Parameters
        ----------
        x : float
            In mm.
        """

        def __init__(self, x: float, y: float) -> None:
            self.x, self.y = x, y
    assert _rest_problems("f", f) == ["f: Parameters misses ['b']", "f: no Returns section"]
    assert _rest_problems("C", C) == ["C: Parameters/Attributes miss ['y']"]


def test_rest_lists_every_module_and_only_real_names():
    """Every public module of imaging/, tracking/, report/, anatomy/ and phantom/ is in
    REST_MODULES (but anatomy/model.py and the modules the `caches` branch splits out of it,
    documented there), and every REST_ELSEWHERE name exists there."""
    import cardionurbs.anatomy
    import cardionurbs.imaging
    import cardionurbs.phantom
    import cardionurbs.report
    import cardionurbs.tracking
    packages = (cardionurbs.imaging, cardionurbs.tracking, cardionurbs.report,
                cardionurbs.anatomy, cardionurbs.phantom)
    wanted = {m.name for p in packages for m in pkgutil.iter_modules(p.__path__, p.__name__ + ".")
              if not m.name.rsplit(".", 1)[1].startswith("_")}
    wanted -= {f"cardionurbs.anatomy.{m}" for m in ("model", "handback", "residuals", "serialise")}
    assert wanted - set(REST_MODULES) == set()
    names = {f"{m}.{q}" for m in REST_MODULES for q, _ in _public(importlib.import_module(m))}
    assert REST_ELSEWHERE - names == set()
