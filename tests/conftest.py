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


#: the xdist group of the modules that share :func:`phantom20_analysed` (``--dist
#: loadgroup``, pyproject.toml: one worker runs them all, so it is analysed once)
PHANTOM20 = "phantom20"


@pytest.fixture(scope="session")
def phantom20_analysed(tmp_path_factory):
    """A 20-frame tagged 'normal' phantom (no DICOM) analysed once per test process with
    two processes: (study folder, output folder). The output holds metrics.json,
    model.json, model.3dm, residuals.csv and the VTK meshes (a .vtp per frame and mesh, a
    .pvd per mesh). Used by test_model_file.py and test_vtk_outputs.py, whose modules are
    marked ``pytest.mark.xdist_group(PHANTOM20)``."""
    from cardionurbs.cli import main
    root = tmp_path_factory.mktemp("phantom20")
    study, out = root / "study", root / "out"
    assert main(["phantom", "--pathology", "normal", "--frames", "20", "--no-dicom",
                 "--out", str(study)]) == 0
    assert main(["analyze", str(study), "--outputs", "metrics,model,meshes", "--mesh-format",
                 "vtp", "--jobs", "2", "--out", str(out)]) == 0
    return study, out
