"""Names of the regional-function columns (docs/metrics.md, Regional function), in CSV order.

Kept in a module of their own so that the global metrics, the regional
analyses and the phantom truth share one list without importing each other.
"""

from __future__ import annotations

from cardionurbs.analysis.rates import RATE_COLUMNS
from cardionurbs.analysis.strain import STRAIN_COLUMNS
from cardionurbs.analysis.surface_strain import SURFACE_STRAIN_COLUMNS
from cardionurbs.analysis.thickness import THICKNESS_COLUMNS

REGIONAL_COLUMNS: tuple[str, ...] = (RATE_COLUMNS + THICKNESS_COLUMNS + STRAIN_COLUMNS
                                     + SURFACE_STRAIN_COLUMNS)
