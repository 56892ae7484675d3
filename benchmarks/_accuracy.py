"""Shared error arithmetic of the validation scripts (run as ``python benchmarks/<script>.py``):
a measured metric against its phantom truth, and the per-subject "model / disks" table."""

from __future__ import annotations

from typing import Callable

import numpy as np

#: units whose metrics are compared by difference (points, degrees), not relative %
ABSOLUTE_UNITS = ("(%)", "(deg)", "(deg/cm)")


def metric_error(column: str, value: float, truth: float) -> float:
    """Error of a measured metric: value − truth for metrics already in % or degrees (EF,
    RegFrac, twist: points or degrees), 100·(value/truth − 1) for volumes and masses (%)."""
    if column.endswith(ABSOLUTE_UNITS):
        return value - truth
    return 100.0 * (value / truth - 1.0)


def subject_error_table(rows: list[dict], cols: tuple[str, ...],
                        flag: Callable[[str, float], bool] | None = None
                        ) -> tuple[list[str], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Markdown table, one row per subject, of the errors of our model / of Simpson's disks
    (``rows``: {"subject", (column, "model" | "disks" | "truth"): value}); a model error for
    which ``flag(column, error)`` holds is marked **!**. Also returns, per column, the absolute
    errors (model, disks) over the subjects, NaN where a value is missing."""
    lines = ["| subject | " + " | ".join(f"{c} model / disks" for c in cols) + " |",
             "|---" * (len(cols) + 1) + "|"]
    errors: dict[str, tuple[list, list]] = {c: ([], []) for c in cols}
    for r in rows:
        cells = []
        for c in cols:
            em = metric_error(c, r[(c, "model")], r[(c, "truth")])
            ed = metric_error(c, r[(c, "disks")], r[(c, "truth")])
            errors[c][0].append(abs(em))
            errors[c][1].append(abs(ed))
            mark = " **!**" if flag is not None and flag(c, em) else ""
            cells.append(f"{em:+.2f}{mark} / {ed:+.2f}")
        lines.append(f"| {r['subject']} | " + " | ".join(cells) + " |")
    return lines, {c: (np.array(m), np.array(d)) for c, (m, d) in errors.items()}
