"""Shared test fixtures: paths to ../shared/data and small synthetic studies."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


def shared_data(*parts: str) -> Path:
    """Path under ../shared/data; skips the test with a reason when absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real data not available: {p} is absent (../shared/data beside the project root)")
    return p


@pytest.fixture
def sunnybrook_dir():
    return shared_data("sunnybrook")


@pytest.fixture
def bivme_dir():
    return shared_data("bivme-patient1")
