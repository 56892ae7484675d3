"""Units that fit on a screen: no function of cardionurbs over 100 lines, none as branchy as
radon's grades E and F (cyclomatic complexity > 30), read from the source with ``ast``.

The functions that still break a rule are listed below with their size today: they may shrink
(and leave the list once they fit), never grow, and no new one may join. The aim is an empty
list; an entry whose function now fits fails the test too, so that the list stays true.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "cardionurbs"
MAX_LINES = 100
MAX_COMPLEXITY = 30          # radon: 31-40 is grade E, 41+ grade F

#: "module path::qualified name" -> lines today (functions over MAX_LINES)
LONG = {
}
#: "module path::qualified name" -> complexity today (functions over MAX_COMPLEXITY)
BRANCHY = {
}

_DECISIONS = (ast.If, ast.IfExp, ast.For, ast.AsyncFor, ast.While, ast.ExceptHandler, ast.With,
              ast.AsyncWith, ast.Assert, ast.match_case)
_SCOPES = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)


def _body_nodes(fn: ast.AST):
    """The nodes of a function's own body (nested functions and classes are units of their own)."""
    stack = list(ast.iter_child_nodes(fn))
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, _SCOPES):
            stack.extend(ast.iter_child_nodes(node))


def complexity(fn: ast.AST) -> int:
    """McCabe's cyclomatic complexity as radon counts it: 1 + one per branch point (if, elif,
    conditional expression, loop and its else, except, with, assert, match case, comprehension
    and each of its conditions, each extra operand of ``and``/``or``)."""
    n = 1
    for node in _body_nodes(fn):
        n += isinstance(node, _DECISIONS)
        if isinstance(node, (ast.For, ast.AsyncFor, ast.While, ast.Try)) and node.orelse:
            n += 1
        elif isinstance(node, ast.BoolOp):
            n += len(node.values) - 1
        elif isinstance(node, ast.comprehension):
            n += 1 + len(node.ifs)
    return n


@functools.lru_cache(maxsize=1)
def units(root: Path = ROOT) -> dict[str, tuple[int, int]]:
    """"path::qualname" -> (lines, complexity) of every function and method under ``root``."""
    out: dict[str, tuple[int, int]] = {}

    def visit(node: ast.AST, prefix: str, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                out[f"{where}::{name}"] = (child.end_lineno - child.lineno + 1, complexity(child))
                visit(child, f"{name}.", where)
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.", where)
            else:
                visit(child, prefix, where)

    for path in sorted(root.rglob("*.py")):
        visit(ast.parse(path.read_text(encoding="utf-8")), "", path.relative_to(root).as_posix())
    return out


def _breaches(index: int, limit: int, known: dict[str, int]) -> list[str]:
    found = units()
    bad = []
    for key, sizes in found.items():
        size = sizes[index]
        if size > limit and key not in known:
            bad.append(f"{key}: {size} (> {limit}): split it into named steps")
        elif key in known and size > known[key]:
            bad.append(f"{key}: {size}, was {known[key]}: a listed exception may only shrink")
    for key, size in known.items():
        if key not in found or found[key][index] <= limit:
            bad.append(f"{key}: fits now (or is gone): take it off the list in tests/test_structure.py")
    return bad


def test_no_function_over_100_lines():
    assert _breaches(0, MAX_LINES, LONG) == []


def test_no_function_graded_e_or_f():
    assert _breaches(1, MAX_COMPLEXITY, BRANCHY) == []


@pytest.mark.parametrize("src, expected", [
    ("def f(x):\n    return x\n", 1),
    ("def f(x):\n    if x and x > 1 or x < -1:\n        return 1\n    elif x:\n        return 2\n"
     "    return [y for y in x if y]\n", 1 + 1 + 2 + 1 + 2),
    ("def f(x):\n    for y in x:\n        pass\n    else:\n        pass\n    try:\n        pass\n"
     "    except ValueError:\n        pass\n    def g():\n        if x:\n            pass\n", 1 + 2 + 1),
])
def test_complexity_counts_branches_as_radon(src, expected):
    assert complexity(ast.parse(src).body[0]) == expected
