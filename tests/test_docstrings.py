"""The API reference's source: numpydoc sections on every public function and class of
cardionurbs.nurbs, cardionurbs.io and cardionurbs.analysis, of the package facade
(``cardionurbs.__all__``) and of every object docs/api.md renders (each argument named under
Parameters, a Returns section where a value comes back), and the Examples of the main entry
points run as doctests."""

from __future__ import annotations

import dataclasses
import doctest
import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest

import cardionurbs
import cardionurbs.analysis
import cardionurbs.io
import cardionurbs.nurbs

ROOT = Path(__file__).resolve().parents[1]


def _modules(package) -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(package.__path__, package.__name__ + ".")
                  if not m.name.rsplit(".", 1)[1].startswith("_"))


NURBS_MODULES = _modules(cardionurbs.nurbs)
#: the package modules whose every public function and class is checked
CHECKED_MODULES = [*NURBS_MODULES, "cardionurbs.io", *_modules(cardionurbs.io),
                   "cardionurbs.analysis", *_modules(cardionurbs.analysis)]
#: modules whose Examples are doctested (the package facade and its entry points)
DOCTESTED = ["cardionurbs", "cardionurbs.io", "cardionurbs.anatomy.model",
             "cardionurbs.analysis.function", "cardionurbs.cohort", *NURBS_MODULES]
#: the entry points that must show an Examples section
EXAMPLES = ["cardionurbs.nurbs.NurbsCurve", "cardionurbs.nurbs.fit_curve", "cardionurbs.nurbs.loft",
            "cardionurbs.nurbs.tessellate", "cardionurbs.load_study", "cardionurbs.reconstruct",
            "cardionurbs.measure", "cardionurbs.cohort"]
def _checked(named) -> list[str]:
    """The problems of (dotted name, object) pairs; a name of :data:`NOT_YET` is a problem
    when it has none (the list may only shrink)."""
    bad = []
    for name, obj in named:
        problems = _problems(name, obj)
        if name in NOT_YET:
            bad += [] if problems else [f"{name}: documented now: take it off NOT_YET"]
        else:
            bad += problems
    return bad


def _public(module):
    """(qualified name, object) of the module's own public functions, classes and methods."""
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
            continue
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj):
            yield name, obj
            yield from ((f"{name}.{m}", f) for m, f in _methods(obj))


def _methods(cls):
    for mname, m in vars(cls).items():
        if not mname.startswith("_") and inspect.isfunction(getattr(m, "__func__", m)):
            yield mname, getattr(m, "__func__", m)


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


def _problems(qual: str, obj) -> list[str]:
    """What the numpydoc sections of ``obj`` miss: a Parameters entry for each argument (a
    class: of its own ``__init__``; a dataclass or NamedTuple: each field, under Parameters
    or Attributes), a Returns (or Yields) section where a function returns a value."""
    doc = inspect.getdoc(obj) or ""
    if not doc:
        return [f"{qual}: no docstring"]
    secs = _sections(doc)
    if inspect.isclass(obj):
        if issubclass(obj, tuple) and hasattr(obj, "_fields"):
            fields = set(obj._fields)
        elif dataclasses.is_dataclass(obj):
            fields = {f.name for f in dataclasses.fields(obj) if f.init and not f.name.startswith("_")}
        elif "__init__" in vars(obj):
            fields = set(_arguments(obj.__init__))
        else:
            return []
        missing = fields - _documented_names(secs.get("Parameters", "") + secs.get("Attributes", ""))
        return [f"{qual}: Parameters/Attributes miss {sorted(missing)}"] if missing else []
    bad = []
    missing = set(_arguments(obj)) - _documented_names(secs.get("Parameters", ""))
    if missing:
        bad.append(f"{qual}: Parameters misses {sorted(missing)}")
    returns = _signature(obj).return_annotation if _signature(obj) else None
    if returns not in (None, "None", inspect.Signature.empty) and "Returns" not in secs \
            and "Yields" not in secs:
        bad.append(f"{qual}: no Returns section")
    return bad


def _signature(obj):
    try:
        return inspect.signature(obj)
    except (TypeError, ValueError):
        return None


def _arguments(func) -> list[str]:
    sig = _signature(func)
    return [] if sig is None else [p for p in sig.parameters if p not in ("self", "cls")]


def _resolve(dotted: str):
    """The object a dotted name names: its parent is the longest importable module prefix
    (then attributes); the last part an attribute of the parent where it has one (so that
    ``cardionurbs.nurbs.loft`` is the function, not the submodule of that name)."""
    *head, last = dotted.split(".")
    for k in range(len(head), 0, -1):
        try:
            parent = importlib.import_module(".".join(head[:k]))
        except ModuleNotFoundError:
            continue
        for part in head[k:]:
            parent = getattr(parent, part)
        break
    else:
        return importlib.import_module(dotted)
    return getattr(parent, last) if hasattr(parent, last) else importlib.import_module(dotted)


def _api_md_objects() -> list[tuple[str, object]]:
    """Every object docs/api.md renders (``::: name``, with its ``members: [...]``)."""
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    out = []
    for m in re.finditer(r"^::: (\S+)((?:\n    .*)*)", text, flags=re.M):
        name, options = m.group(1), m.group(2)
        obj = _resolve(name)
        if not inspect.ismodule(obj):
            out.append((name, obj))
        members = re.search(r"members:\s*\[([^\]]*)\]", options)
        for member in (members.group(1).replace("\n", " ").split(",") if members else []):
            out.append((f"{name}.{member.strip()}", getattr(obj, member.strip())))
    return out


def _facade_objects() -> list[tuple[str, object]]:
    """Every public name of ``import cardionurbs as cn`` and the public methods of its classes."""
    out = []
    for name in cardionurbs.__all__:
        obj = getattr(cardionurbs, name)
        if inspect.ismodule(obj):
            continue
        out.append((f"cardionurbs.{name}", obj))
        if inspect.isclass(obj) and not issubclass(obj, BaseException):
            out += [(f"cardionurbs.{name}.{m}", f) for m, f in _methods(obj)]
    return out


@pytest.mark.parametrize("modname", CHECKED_MODULES)
def test_every_public_callable_has_numpydoc_sections(modname):
    module = importlib.import_module(modname)
    assert _checked((f"{modname}.{qual}", obj) for qual, obj in _public(module)) == []


def test_the_facade_has_numpydoc_sections():
    assert _checked(_facade_objects()) == []


def test_every_api_md_object_has_numpydoc_sections():
    objects = _api_md_objects()
    assert len(objects) > 20                          # the parse found the page's objects
    assert _checked(objects) == []


def test_the_check_finds_what_is_missing():
    def undocumented(a: int, b: float = 1.0) -> float:
        """Sum.

        Parameters
        ----------
        a : int
            One.
        """
        return a + b
    assert _problems("f", undocumented) == ["f: Parameters misses ['b']", "f: no Returns section"]


@pytest.mark.parametrize("name", EXAMPLES)
def test_entry_points_have_examples(name):
    assert "Examples" in _sections(inspect.getdoc(_resolve(name)))


def test_package_facade_has_examples():
    assert "Examples" in _sections(cardionurbs.__doc__)
    assert all(f"cn.{n}(" in cardionurbs.__doc__ for n in ("load_study", "reconstruct", "measure"))


def test_facade_cohort_stays_the_function():
    """Importing the submodule cardionurbs.cohort names it on the package: ``cn.cohort``
    must still be the function, the second time too."""
    importlib.import_module("cardionurbs.cohort")
    from cardionurbs.cohort import cohort
    assert cardionurbs.cohort is cohort and cardionurbs.cohort is cohort


@pytest.mark.parametrize("modname", DOCTESTED)
def test_doctests(modname):
    module = importlib.import_module(modname)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False)
    assert result.failed == 0


#: public names whose numpydoc sections are still to be written (#35 item 4); empty now. The
#: list may only shrink -- a name here that passes fails the test (:func:`_checked`).
NOT_YET: set[str] = set()


# ----------------------------------------------------- the rest of the package (#35 item 4)
#: modules outside nurbs/, io/ and analysis/ whose every public
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
    "cardionurbs.anatomy.model", "cardionurbs.anatomy.handback", "cardionurbs.anatomy.residuals",
    "cardionurbs.anatomy.serialise", "cardionurbs.cache", "cardionurbs.cli", "cardionurbs.study",
    "cardionurbs.errors",
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
REST_ELSEWHERE: set[str] = set()


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
    REST_MODULES, and every REST_ELSEWHERE name exists there."""
    import cardionurbs.anatomy
    import cardionurbs.imaging
    import cardionurbs.phantom
    import cardionurbs.report
    import cardionurbs.tracking
    packages = (cardionurbs.imaging, cardionurbs.tracking, cardionurbs.report,
                cardionurbs.anatomy, cardionurbs.phantom)
    wanted = {m.name for p in packages for m in pkgutil.iter_modules(p.__path__, p.__name__ + ".")
              if not m.name.rsplit(".", 1)[1].startswith("_")}
    assert wanted - set(REST_MODULES) == set()
    names = {f"{m}.{q}" for m in REST_MODULES for q, _ in _public(importlib.import_module(m))}
    assert REST_ELSEWHERE - names == set()
