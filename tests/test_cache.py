"""The one cache mechanism (cardionurbs/cache.py, docs/architecture.md "Derived values")."""

from __future__ import annotations

import ast
import dataclasses
import pickle
from pathlib import Path

import numpy as np
import pytest

from cardionurbs.cache import LazyFrames, attached, memoized
from cardionurbs.study import Contour, Study

PACKAGE = Path(__file__).resolve().parents[1] / "cardionurbs"


class Counter:
    def __init__(self, items: list) -> None:
        self.items = items
        self.calls: list = []

    @memoized
    def square(self, x: int) -> int:
        self.calls.append(x)
        return x * x

    @memoized(depends=("items",))
    def total(self) -> int:
        self.calls.append("total")
        return sum(self.items)


def test_memoized_computes_once_per_argument_and_per_instance():
    a, b = Counter([]), Counter([])
    assert a.square(3) == 9 and a.square(3) == 9 and a.square(4) == 16
    assert a.calls == [3, 4] and b.square(3) == 9 and b.calls == [3]
    assert 3 in a.square and a.square.has(4) and 5 not in a.square
    a.square.forget(3)
    assert 3 not in a.square and a.square(3) == 9 and a.calls == [3, 4, 3]
    a.square.forget_where(lambda k: k[0] > 3)
    assert sorted(a.square.keys()) == [(3,)]
    with pytest.raises(AttributeError):
        a.square = 1


def test_an_exception_is_not_kept():
    class Flaky:
        n = 0

        @memoized
        def value(self) -> int:
            self.n += 1
            if self.n == 1:
                raise ValueError("first")
            return self.n
    f = Flaky()
    with pytest.raises(ValueError):
        f.value()
    assert f.value() == 2 and f.value() == 2


def test_depends_drops_values_when_the_list_is_replaced_or_grows():
    c = Counter([1, 2])
    assert c.total() == 3 and c.total() == 3 and c.calls == ["total"]
    c.items.append(4)                     # longer: made again
    assert c.total() == 7 and c.calls == ["total"] * 2
    c.items = [5, 2, 1]                   # another list of the same length: made again
    assert c.total() == 8 and c.calls == ["total"] * 3


def test_provide_and_store():
    c = Counter([])
    c.square.provide(10, 3)
    c.square.provide(11, 3)               # kept: the first one given
    assert c.square(3) == 10 and c.calls == []
    c.square.store(12, 3)                 # replaced
    assert c.square(3) == 12 and c.square.get(4) is None and c.calls == []


def test_a_frozen_dataclass_keeps_its_memo_outside_its_fields():
    @dataclasses.dataclass(frozen=True)
    class Point:
        x: float

        @memoized
        def scaled(self, k: float) -> float:
            return self.x * k
    p = Point(2.0)
    assert p.scaled(3.0) == 6.0
    q = dataclasses.replace(p)
    assert p == q and hash(p) == hash(q) and "scaled" not in q.__dict__
    assert repr(p) == "test_a_frozen_dataclass_keeps_its_memo_outside_its_fields.<locals>.Point(x=2.0)"


def test_a_study_pickles_with_its_indices_and_they_stay_right():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    study = Study(subject="s", contours=[Contour("lv_endo", "SA", "sa_1", 0, pts),
                                         Contour("lv_endo", "SA", "sa_1", 1, pts)])
    assert len(study.contours_at(0)) == 1
    back = pickle.loads(pickle.dumps(study))
    assert len(back.contours_at(1)) == 1
    back.contours.append(Contour("lv_epi", "SA", "sa_1", 1, pts))
    assert len(back.contours_at(1)) == 2 and len(study.contours_at(1)) == 1
    study.contours = []
    assert study.contours_at(0) == []


def test_attached_memo_on_an_object_it_does_not_own():
    c = Counter([1])
    calls = []

    def doubled(obj, k):
        calls.append(k)
        return 2 * sum(obj.items) * k
    assert attached(c, "_doubled", doubled, depends=("items",))(1) == 2
    assert attached(c, "_doubled", doubled, depends=("items",))(1) == 2 and calls == [1]
    c.items.append(1)
    assert attached(c, "_doubled", doubled, depends=("items",))(1) == 4 and calls == [1, 1]


def test_lazy_frames():
    made = []
    m = LazyFrames([3, 1, 2], lambda f: made.append(f) or f * 10)
    assert list(m) == [3, 1, 2] and len(m) == 3 and m.computed == []
    assert m[1] == 10 and m[1] == 10 and made == [1] and m.computed == [1]
    m.provide(2, 99)
    m.provide(1, 99)                      # kept
    assert m[2] == 99 and m[1] == 10 and made == [1]
    with pytest.raises(KeyError):
        m[7]
    m.drop([1])
    assert list(m) == [3, 2] and 1 not in m


def _hand_made_caches(path: Path) -> list[str]:
    """`object.__setattr__(...)` calls and `x.__dict__[...]` / `x.__dict__.get|setdefault|pop`
    uses in one module."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Attribute) and node.attr == "__setattr__" \
                and isinstance(node.value, ast.Name) and node.value.id == "object":
            out.append(f"{path.name}:{node.lineno} object.__setattr__")
        if isinstance(node, ast.Attribute) and node.attr == "__dict__":
            out.append(f"{path.name}:{node.lineno} __dict__")
    return out


def test_no_hand_made_caches_outside_the_cache_module():
    found = [hit for p in sorted(PACKAGE.rglob("*.py")) if p.name != "cache.py"
             for hit in _hand_made_caches(p)]
    assert found == []


def test_an_error_raised_while_computing_has_no_cache_miss_in_its_context():
    class Bad:
        @memoized
        def value(self, k: int) -> int:
            raise RuntimeError(f"cannot make {k}")
    with pytest.raises(RuntimeError) as info:
        Bad().value(1)
    assert info.value.__context__ is None
