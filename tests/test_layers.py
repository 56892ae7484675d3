"""The layer order of docs/architecture.md, enforced by reading every module's imports.

Every ``import`` statement counts, at module level or inside a function (an
import inside a function must not be a way around the rules). A module may
import a module of a lower layer or of its own package; nothing imports
upwards or sideways, and there is no cycle. ``import cardionurbs.nurbs``
loads nothing of the package outside ``cardionurbs.nurbs`` and
``cardionurbs.errors``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "cardionurbs"

#: docs/architecture.md, "Layer order" (top-level part of the package -> layer).
LAYERS = {
    "errors": 0, "limits": 0, "median": 0, "workers": 0, "cache": 0,
    "safe": 1, "progress": 1, "executor": 1, "heap": 1, "parallel": 1,
    "confine": 2,
    "nurbs": 3, "geometry": 3,
    "imaging": 4,
    "study": 5,
    "io": 6,
    "anatomy": 7, "phantom": 7,
    "analysis": 8,
    "report": 9, "tracking": 9,
    "pipeline": 10,
    "cohort": 11,
    "demo": 12,
    "cli": 13,
    "": 14,          # the package facade, cardionurbs/__init__.py
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(name: str) -> str:
    """The package module an imported dotted name refers to (longest known prefix)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name


def imports_of(module: str) -> set[str]:
    """Package modules imported anywhere in ``module`` (``from P import m`` of a submodule
    counts as importing ``P.m``; relative imports are resolved)."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                     for a in node.names]
        else:
            continue
        out.update(_resolve(n) for n in names if n == "cardionurbs" or n.startswith("cardionurbs."))
    out.discard(module)
    return out


GRAPH = {m: imports_of(m) for m in MODULES}


def _part(module: str) -> str:
    return module.split(".")[1] if "." in module else ""


def test_every_part_has_a_layer():
    assert {_part(m) for m in MODULES} <= set(LAYERS), \
        f"parts without a layer (add them to LAYERS and docs/architecture.md): " \
        f"{sorted({_part(m) for m in MODULES} - set(LAYERS))}"


def test_no_import_goes_up_or_sideways():
    wrong = []
    for m, deps in GRAPH.items():
        for d in deps:
            same_package = _part(m) == _part(d) and _part(m) != ""
            if not same_package and LAYERS[_part(d)] >= LAYERS[_part(m)]:
                wrong.append(f"{m} (layer {LAYERS[_part(m)]}) imports {d} "
                             f"(layer {LAYERS[_part(d)]})")
    assert not wrong, "wrong-way imports:\n" + "\n".join(sorted(wrong))


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    assert _cycles(GRAPH) == []


def test_cycle_detection_finds_a_planted_cycle():
    """The checks above can fail: a planted upward import and cycle are caught."""
    graph = {k: set(v) for k, v in GRAPH.items()}
    graph["cardionurbs.nurbs.curve"].add("cardionurbs.nurbs.fitting")
    assert any("cardionurbs.nurbs.curve" in c for c in _cycles(graph))
    assert "cardionurbs.io.atomic" in imports_of("cardionurbs.io.native")


@pytest.mark.parametrize("layer", ["nurbs", "geometry", "errors"])
def test_importing_a_low_layer_loads_only_that_layer(layer):
    code = (f"import cardionurbs.{layer}, sys; "
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('cardionurbs'))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.split()
    allowed = {"cardionurbs", "cardionurbs.errors"}
    assert [m for m in out if m not in allowed and not m.startswith(f"cardionurbs.{layer}")] == []
    assert f"cardionurbs.{layer}" in out
