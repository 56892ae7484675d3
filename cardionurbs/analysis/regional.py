"""Regional LV function of a reconstructed model (docs/metrics.md, Regional function).

:func:`regional_metrics` gathers, for one model, the columns of
:data:`cardionurbs.analysis.regional_columns.REGIONAL_COLUMNS` that are not
global-volume based: wall thickness and thickening per AHA segment
(:mod:`cardionurbs.analysis.thickness`, on the AHA geometry of
:mod:`cardionurbs.analysis.aha`). Each part that cannot be measured leaves
its columns NaN and says why in ``notes``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from cardionurbs.analysis.aha import AhaFrame, model_aha_frame
from cardionurbs.analysis.thickness import THICKNESS_COLUMNS, thickness_by_segment, thickness_columns
from cardionurbs.errors import CardioNurbsError

NAN = float("nan")


@dataclass
class RegionalMetrics(Mapping):
    """Regional columns -> float (a read-only mapping), with the segment geometry per frame
    (``aha``: frame -> AhaFrame), the thickness samples per frame (``samples``) and ``notes``."""

    columns: dict[str, float]
    aha: dict[int, AhaFrame] = field(default_factory=dict)
    samples: dict[int, dict] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def __getitem__(self, key: str) -> float:
        return self.columns[key]

    def __iter__(self):
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    def to_json(self) -> dict:
        """JSON-safe summary for metrics.json (NaN -> None)."""
        def num(x):
            return None if x is None or not np.isfinite(x) else float(x)
        return {"aha": {str(f): a.to_dict() for f, a in self.aha.items()},
                "notes": list(self.notes)}


def regional_metrics(model) -> RegionalMetrics:
    """Wall thickness (ED, ES) and thickening per AHA segment of a model."""
    cols = {c: NAN for c in THICKNESS_COLUMNS}
    out = RegionalMetrics(cols)
    ed, es = model.ed_frame, model.es_frame
    try:
        out.aha = {f: model_aha_frame(model, f) for f in dict.fromkeys((ed, es))}
    except CardioNurbsError as exc:
        out.notes.append(f"AHA segments not placed: {exc}")
        return out
    per = {}
    for f in dict.fromkeys((ed, es)):
        surf = model.surfaces[f]
        if "lv_endo" not in surf or "lv_epi" not in surf:
            out.notes.append(f"frame {f}: no LV epicardial surface; wall thickness not measured")
            return out
        per[f], out.samples[f] = thickness_by_segment(surf["lv_endo"], surf["lv_epi"], out.aha[f],
                                                      model.base_planes[f].get("lv"))
    cols.update(thickness_columns(per[ed], per[es]))
    return out
