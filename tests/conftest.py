"""Shared test fixtures: paths to ../shared/data and small synthetic studies."""

from __future__ import annotations

import inspect
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


#: session fixtures of this file that name the xdist group of their tests first
SHARED_FIXTURES = ("phantom20_analysed", "bivme_model")
TESTS = Path(__file__).resolve().parent


def _shared_fixtures(item) -> list[tuple[str, str]]:
    """(scope node, name) of every fixture of tests/ wider than a function that ``item``
    uses, directly or through another fixture, and of its explicit xdist_group marks."""
    defs = getattr(getattr(item, "_fixtureinfo", None), "name2fixturedefs", {})
    keys = [("mark", m.args[0] if m.args else m.kwargs["name"])
            for m in item.iter_markers("xdist_group")]
    for name in getattr(item, "fixturenames", ()):
        fd = (defs.get(name) or [None])[-1]
        if fd is None or fd.scope == "function":
            continue
        try:
            where = Path(inspect.getfile(fd.func))
        except TypeError:                       # not a Python function: not one of ours
            continue
        if not where.is_relative_to(TESTS):
            continue
        if fd.scope == "class":
            node = item.nodeid.rsplit("::", 1)[0]
        elif fd.scope != "module" and where.name == "conftest.py":
            node = "session"                    # one instance for every module that uses it
        else:
            node = item.nodeid.split("::")[0]   # a module's own (module or session) fixture
        keys.append((node, name))
    return keys


def _group_name(keys: set[tuple[str, str]]) -> str:
    """An xdist group's name: its explicit mark, else its session fixture, else its module."""
    for kind in ("mark", "session"):
        named = sorted(n for k, n in keys if k == kind)
        if named:
            return next((n for n in SHARED_FIXTURES if n in named), named[0])
    return Path(min(k for k, _ in keys).split("::")[0]).stem


def _mark_groups(items) -> None:
    """Give the tests connected through fixtures wider than a function (a module's tests
    sharing a module fixture, every module using a session fixture of this file, an explicit
    ``xdist_group`` mark) one ``xdist_group`` mark."""
    parent: dict = {}

    def root(k):
        while parent.setdefault(k, k) != k:
            k = parent[k]
        return k

    used = {id(item): _shared_fixtures(item) for item in items}
    for keys in used.values():
        for k in keys[1:]:
            parent[root(k)] = root(keys[0])
    members: dict = {}
    for keys in used.values():
        for k in keys:
            members.setdefault(root(k), set()).add(k)
    for item in items:
        keys = used[id(item)]
        if keys:
            item.add_marker(pytest.mark.xdist_group(_group_name(members[root(keys[0])])), append=False)


def _group_suffix(item) -> None:
    """The ``@group`` suffix of the node id, by which ``--dist loadgroup`` schedules: what
    pytest-xdist (3.8) writes to ``item._nodeid``, which pytest 9.2 no longer reads (its
    node ids are ``item._id``, a NodeId); without it no test is grouped."""
    names = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                    for m in item.iter_markers("xdist_group")})
    suffix = "@" + "_".join(names)
    if not names or item.nodeid.endswith(suffix):
        return
    from _pytest.nodeid import NodeId
    path, _, rest = (item.nodeid + suffix).partition("::")
    item._id = NodeId(path=path, names=tuple(rest.split("::")))     # "[params]@group" a name


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """One xdist group (``--dist loadgroup``, pyproject.toml) for the tests that share a fixture
    wider than a function, so that it is built once and not once per worker (without it
    ``loadgroup`` hands a module's tests to both workers one by one, and each worker builds
    the module's fixtures): the marks go on before pytest-xdist's own hook reads them, the
    node ids are checked after it."""
    _mark_groups(items)
    result = yield
    if getattr(config.option, "loadgroup", False):          # an xdist worker
        for item in items:
            _group_suffix(item)
    return result


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
