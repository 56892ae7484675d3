"""The one cache mechanism for values derived from an object (docs/architecture.md).

Three forms, one rule (a derived value is computed on first use and kept on the object
it is derived from, in the object's ``__dict__``, never in a module-level table):

* one value of an object: :func:`functools.cached_property`;
* values of an object keyed by arguments (per frame, per structure, per height):
  :class:`memoized` on the method, whose results live in a :class:`Memo` on the instance
  (``model.solids(frame)`` computes once per frame; ``model.solids.forget(frame)`` drops
  one); ``depends=("contours",)`` drops every value when one of the named attributes is
  replaced or changes length (a mutable :class:`cardionurbs.study.Study`'s lists);
  :func:`attached` gives a function of another layer such a memo on an object it does not
  own;
* a read-only mapping of a fixed set of keys whose values are computed on first access
  (a model's per-frame ``surfaces``, ``volumes``): :class:`LazyFrames`.

A pure module-level function of hashable arguments is memoised with
:func:`functools.lru_cache`. A memo's values are plain dicts in the instance's
``__dict__``: an object pickles with them exactly as it did with a hand-made ``_cache``
dict, and a dataclass' field-wise ``==``, ``repr`` and :func:`dataclasses.replace` never
see them. Slotted classes have no ``__dict__`` and cannot use these forms.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping
from typing import Any

__all__ = ["LazyFrames", "Memo", "attached", "memoized"]


def _token(obj: Any, depends: tuple[str, ...]) -> tuple:
    """What the values of a memo depend on: each named attribute and its length."""
    out = []
    for name in depends:
        value = getattr(obj, name)
        out.append((value, len(value)))
    return tuple(out)


def _same(a: tuple, b: tuple) -> bool:
    """Two tokens name the same attribute objects (by identity) of the same lengths."""
    return len(a) == len(b) and all(x is y and m == n for (x, m), (y, n) in zip(a, b))


class Memo:
    """The values of one memoized method on one instance: ``memo(*args)`` computes
    ``method(instance, *args)`` once per argument tuple.

    The values live in a plain dict (``table``) in the instance's ``__dict__``; a Memo
    itself is a light view made on attribute access.

    Parameters
    ----------
    fn : callable
        The method, ``fn(obj, *args)``.
    obj : object
        The instance.
    table : dict
        Argument tuple -> value, kept in the instance's ``__dict__``.
    """

    __slots__ = ("_fn", "_obj", "_table")

    def __init__(self, fn: Callable, obj: Any, table: dict) -> None:
        self._fn, self._obj, self._table = fn, obj, table

    def __call__(self, *args: Hashable) -> Any:
        table = self._table
        if args in table:
            return table[args]
        value = table[args] = self._fn(self._obj, *args)   # an exception keeps nothing
        return value

    def __contains__(self, arg: Hashable) -> bool:
        """``x in memo``: whether the value of the one argument ``x`` exists."""
        return (arg,) in self._table

    def has(self, *args: Hashable) -> bool:
        """Whether the value of these arguments exists (nothing is computed).

        Parameters
        ----------
        *args : hashable
            The arguments.

        Returns
        -------
        bool
        """
        return args in self._table

    def keys(self) -> list[tuple]:
        """The argument tuples whose values exist.

        Returns
        -------
        list of tuple
        """
        return [k for k in self._table if k is not None]

    def get(self, *args: Hashable) -> Any:
        """The value of these arguments if it exists, else None (nothing is computed).

        Parameters
        ----------
        *args : hashable
            The arguments.

        Returns
        -------
        object or None
        """
        return self._table.get(args)

    def provide(self, value: Any, *args: Hashable) -> None:
        """Store a value computed elsewhere (a worker process), unless one exists.

        Parameters
        ----------
        value : object
            The value.
        *args : hashable
            The arguments it is the value of.
        """
        self._table.setdefault(args, value)

    def store(self, value: Any, *args: Hashable) -> None:
        """Store a value computed elsewhere, replacing the one that exists.

        Parameters
        ----------
        value : object
            The value.
        *args : hashable
            The arguments it is the value of.
        """
        self._table[args] = value

    def forget(self, *args: Hashable) -> None:
        """Drop the value of these arguments (nothing when it does not exist).

        Parameters
        ----------
        *args : hashable
            The arguments.
        """
        self._table.pop(args, None)

    def forget_where(self, where: Callable[[tuple], bool]) -> None:
        """Drop every value whose argument tuple satisfies ``where``.

        Parameters
        ----------
        where : callable (tuple) -> bool
            True for an argument tuple whose value is to be dropped.
        """
        for key in [k for k in self.keys() if where(k)]:
            del self._table[key]


class memoized:
    """Method decorator: results kept per instance and per (hashable, positional) argument
    tuple in a :class:`Memo` (see the module docstring).

    Parameters
    ----------
    fn : callable
        The method ``fn(self, *args)``.
    depends : tuple of str
        Attributes of the instance (sized: lists, dicts) the values follow: all values
        are dropped when one of them is replaced by another object or changes length.
    """

    def __init__(self, fn: Callable | None = None, *, depends: Iterable[str] = ()) -> None:
        self.depends = tuple(depends)
        self.fn: Callable | None = None
        self.name = ""
        if fn is not None:
            self._wrap(fn)

    def _wrap(self, fn: Callable) -> "memoized":
        self.fn = fn
        self.name = fn.__name__
        functools.update_wrapper(self, fn)
        return self

    def __call__(self, fn: Callable) -> "memoized":     # @memoized(depends=...)
        return self._wrap(fn)

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None or self.fn is None:
            return self
        return Memo(self.fn, obj, _table(obj, self.name, self.depends))

    def __set__(self, obj: Any, value: Any) -> None:    # a data descriptor: __dict__ holds the table
        raise AttributeError(f"{self.name} is a memoized method, not an attribute")


def _table(obj: Any, name: str, depends: tuple[str, ...]) -> dict:
    """The value table of memo ``name`` on ``obj`` (made, or emptied when its ``depends``
    changed). Depending memos keep their token under the key ``None``."""
    d = obj.__dict__
    table = d.get(name)
    if table is None:
        table = d[name] = {}
    if depends:
        token = _token(obj, depends)
        if not _same(table.get(None, ()), token):
            table.clear()
            table[None] = token
    return table


def attached(obj: Any, name: str, fn: Callable, depends: Iterable[str] = ()) -> Memo:
    """A memo of ``fn(obj, *args)`` kept on ``obj`` under ``name``: for a function of a
    higher layer that caches on an object it does not own (e.g. a study's stacking
    direction per frame, :mod:`cardionurbs.anatomy.sections`). Same rules as
    :class:`memoized`.

    Parameters
    ----------
    obj : object
        The object the memo's table is kept on (in its ``__dict__``).
    name : str
        The table's attribute name.
    fn : callable
        ``fn(obj, *args)``, the value to keep per argument tuple.
    depends : iterable of str
        Attributes of ``obj`` whose replacement (or change of length) drops every value.

    Returns
    -------
    Memo
        Callable as ``memo(*args)``, with ``forget``, ``provide`` and ``in``.
    """
    return Memo(fn, obj, _table(obj, name, tuple(depends)))


class LazyFrames(Mapping):
    """A read-only mapping of fixed keys (frames) whose values are computed on first access.

    Lets a model of many frames build only what is asked for: measuring needs every
    frame's LV cavity (to find ED and ES) but the other surfaces only at ED and ES;
    exporting asks for everything.

    Parameters
    ----------
    frames : iterable
        The keys, in their order.
    compute : callable
        ``compute(frame)`` -> the value of one key.
    """

    def __init__(self, frames: Iterable, compute: Callable[[Any], Any]) -> None:
        self._frames = list(frames)
        self._compute = compute
        self._values: dict = {}

    def __getitem__(self, frame: Any) -> Any:
        if frame not in self._frames:
            raise KeyError(frame)
        if frame not in self._values:
            self._values[frame] = self._compute(frame)
        return self._values[frame]

    def __iter__(self) -> Iterator:
        return iter(self._frames)

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def computed(self) -> list:
        """Frames computed so far."""
        return [f for f in self._frames if f in self._values]

    def provide(self, frame: Any, value: Any) -> None:
        """Store the value of one frame computed elsewhere (a worker process of
        :func:`cardionurbs.parallel.fork_map`), unless this mapping has one.

        Parameters
        ----------
        frame : hashable
            One of the mapping's keys.
        value : object
            Its value.
        """
        if frame not in self._frames:
            raise KeyError(frame)
        self._values.setdefault(frame, value)

    def drop(self, frames: Iterable) -> None:
        """Remove frames from the keys (and their values).

        Parameters
        ----------
        frames : iterable
            Keys to remove.
        """
        gone = set(frames)
        self._frames = [f for f in self._frames if f not in gone]
        for f in gone:
            self._values.pop(f, None)

