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


@pytest.fixture(scope="session")
def la_spoke_fans():
    """The LA tag QC's spoke fans of every tagged frame of an MR phantom with 4 jumped tag
    lines: ([(sections, their samples)], the study's long axis)."""
    from cardionurbs.analysis.tagqc import _samples, qc_sections
    from cardionurbs.anatomy.sections import study_long_axis
    from cardionurbs.phantom import generate
    study = generate("mr", seed=4, frames=2, tag_jumps=4, volume_check=False).study
    axis = study_long_axis(study)
    fans = [(secs, [_samples(s) for s in secs]) for f in study.tagged_frames
            for (fam, _), secs in qc_sections(study, f, axis).items() if fam == "la"]
    assert fans
    return fans, axis
