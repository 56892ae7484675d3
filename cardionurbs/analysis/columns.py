"""A table of metric columns that reads as a mapping (column name -> value)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping


class ColumnMapping(Mapping):
    """Read-only ``Mapping`` view of ``self.columns`` (docs/metrics.md name -> value).

    Result dataclasses (tag metrics, regional metrics) keep their columns in a
    ``columns`` dict beside richer detail; subclassing this makes ``result[name]``,
    ``dict(result)`` and ``len(result)`` read the columns alone.
    """

    columns: dict[str, float]

    def __getitem__(self, key: str) -> float:
        return self.columns[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)
