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


#: session fixtures that xdist keeps in one worker: every test using one of them (directly
#: or through another fixture) gets the xdist_group of its name (``--dist loadgroup``,
#: pyproject.toml), so the fixture is built once, not once per worker
SHARED_FIXTURES = ("phantom20_analysed", "bivme_model")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    for item in items:
        used = [n for n in SHARED_FIXTURES if n in getattr(item, "fixturenames", ())]
        if used:
            item.add_marker(pytest.mark.xdist_group(used[0]))


@pytest.fixture(scope="session")
def bivme_model():
    """bivme-patient1 (CAP) loaded and reconstructed, all 25 frames: (study, model).
    Shared by test_cycle.py, test_quality.py and test_model_realdata.py (a model is
    read, never changed, by them; what they compute on it is cached on it)."""
    from cardionurbs import load_study, reconstruct
    study = load_study(shared_data("bivme-patient1"))
    return study, reconstruct(study)


@pytest.fixture(scope="session")
def phantom20_analysed(tmp_path_factory):
    """A 20-frame tagged 'normal' phantom (no DICOM) analysed once per test process with
    two processes: (study folder, output folder). The output holds metrics.json,
    model.json, model.3dm, residuals.csv and the VTK meshes (a .vtp per frame and mesh, a
    .pvd per mesh). Used by test_model_file.py and test_vtk_outputs.py."""
    from cardionurbs.cli import main
    root = tmp_path_factory.mktemp("phantom20")
    study, out = root / "study", root / "out"
    assert main(["phantom", "--pathology", "normal", "--frames", "20", "--no-dicom",
                 "--out", str(study)]) == 0
    assert main(["analyze", str(study), "--outputs", "metrics,model,meshes", "--mesh-format",
                 "vtp", "--jobs", "2", "--out", str(out)]) == 0
    return study, out
