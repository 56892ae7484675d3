"""Per-frame work of one analysis on forked worker processes (cardionurbs.parallel, issue 16):
the same outputs as one process, worker exceptions raised in the parent with their type and
message, serial inside daemonic processes (cohort and Dask workers), no output on failure."""

from __future__ import annotations

import json
import multiprocessing as mp
import os

import numpy as np
import pytest

from cardionurbs import cli
from cardionurbs.errors import ReconstructionError, StudyError, TagError
from cardionurbs.parallel import WorkerDied, can_fork, fork_map, worker_count

needs_fork = pytest.mark.skipif(not can_fork(), reason="no fork start method here")


# ------------------------------------------------------------------ fork_map itself
def _pid_of(x):
    return x, os.getpid()


@needs_fork
def test_results_in_order_here_items_run_here():
    seen = []

    def fn(x):
        seen.append(x)                          # visible here only for this process's items
        return x * x, os.getpid()

    out = fork_map(fn, range(7), jobs=2, here={0, 3})
    assert [r[0] for r in out] == [x * x for x in range(7)]
    pids = {x: p for x, (_, p) in enumerate(out)}
    assert pids[0] == pids[3] == os.getpid()
    assert all(pids[x] != os.getpid() for x in (1, 2, 4, 5, 6))
    assert sorted(seen) == [0, 3]


def test_serial_when_one_job_or_one_process_would_work():
    assert [p for _, p in fork_map(_pid_of, range(4), jobs=1)] == [os.getpid()] * 4
    assert [p for _, p in fork_map(_pid_of, [0], jobs=4)] == [os.getpid()]
    assert [p for _, p in fork_map(_pid_of, [0, 1], jobs=4, here={0, 1})] == [os.getpid()] * 2
    assert worker_count(1, 10) == 0 and worker_count(8, 1) == 0 and worker_count(8, 0, 3) == 0
    if can_fork():                  # one worker beside this process's own items: two at work
        assert worker_count(8, 1, 1) == 1 and worker_count(2, 5, 1) == 2
    with pytest.raises(ValueError, match="jobs"):
        worker_count(0, 3)


@needs_fork
def test_worker_exception_reaches_the_parent_as_itself():
    def fn(x):
        if x in (4, 6):
            raise StudyError("no tag points", file="study.json", frame=x)
        return x

    with pytest.raises(StudyError) as info:
        fork_map(fn, range(8), jobs=2, here={0})
    assert str(info.value) == "study.json: frame 4: no tag points"   # the first in item order
    assert info.value.frame == 4
    assert "in a worker process" in str(info.value.__cause__)

    class Unpicklable(Exception):                # a local class: cannot be pickled
        pass

    def bad(x):
        if x == 2:
            raise Unpicklable("lost type")
        return x

    with pytest.raises(RuntimeError, match="Unpicklable: lost type"):
        fork_map(bad, range(4), jobs=2)


@needs_fork
def test_a_worker_that_dies_is_reported():
    def fn(x):
        if x == 3:
            os._exit(7)
        return x

    with pytest.raises(WorkerDied, match=r"died \(exit code 7\) before reporting item \d"):
        fork_map(fn, range(6), jobs=2)


def _in_daemon(conn):
    conn.send(fork_map(_pid_of, range(5), jobs=4))
    conn.close()


@needs_fork
def test_serial_in_a_daemonic_process():
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_in_daemon, args=(child,), daemon=True)
    p.start()
    child.close()
    out = parent.recv()
    p.join()
    assert {pid for _, pid in out} == {p.pid}      # every item in the daemonic process


# ------------------------------------------------------------------ analyze with --jobs
@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    from cardionurbs.phantom import generate
    from cardionurbs.phantom.generate import write_phantom
    ph = generate("normal", seed=2, frames=5, volume_check=False)
    return write_phantom(ph, tmp_path_factory.mktemp("par") / "ph5", dicom=False)


@pytest.fixture(scope="module")
def runs(study_dir, tmp_path_factory):
    out = {}
    for jobs in ("1", "2"):
        d = tmp_path_factory.mktemp(f"jobs{jobs}") / "out"
        assert cli.main(["analyze", str(study_dir), "--out", str(d), "--jobs", jobs,
                         "--outputs", "all"]) == 0
        out[jobs] = d
    return out


@needs_fork
def test_parallel_outputs_equal_serial(runs):
    one, two = runs["1"], runs["2"]
    for name in ("metrics.json", "model.json", "residuals.csv", "report.html"):
        assert (one / name).read_bytes() == (two / name).read_bytes(), name
    figures = sorted(p.name for p in (one / "figures").iterdir())
    assert figures == sorted(p.name for p in (two / "figures").iterdir())
    assert sum(name.endswith(".png") for name in figures) >= 10
    for name in figures:                   # PNGs drawn by workers, figures.json, report_tags.json
        assert (one / "figures" / name).read_bytes() == (two / "figures" / name).read_bytes(), name
    meshes = sorted(p.name for p in (one / "meshes").iterdir())
    assert meshes == sorted(p.name for p in (two / "meshes").iterdir()) and len(meshes) == 20
    for name in meshes:       # manifold3d's threaded booleans may order a mesh's vertices
        assert _triangles(one / "meshes" / name) == _triangles(two / "meshes" / name), name
    m = json.loads((two / "metrics.json").read_text())
    assert all(np.isfinite(m["volume_curve"]["rv_myocardium (mL)"]))   # every frame meshed
    assert len(m["volume_curve"]["frame"]) == 5
    assert len(m["regional"]["strain_over_time"]) == 4          # frames 1-4 against ED


def _triangles(path) -> set:
    """A PLY mesh as the set of its triangles (vertex coordinates, rotated to start at the
    smallest vertex, orientation kept): equal whatever the vertex and face order."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode().split("\n")
    nv, nf = (int(next(h for h in head if h.startswith(f"element {e}")).split()[-1])
              for e in ("vertex", "face"))
    v = np.frombuffer(data, "<f4", nv * 3, end).reshape(-1, 3)
    f = np.frombuffer(data, [("n", "u1"), ("i", "<i4", (3,))], nf, end + nv * 12)["i"]
    out = set()
    for tri in v[f]:
        corners = [tuple(c) for c in tri.tolist()]
        k = corners.index(min(corners))
        out.add(tuple(corners[k:] + corners[:k]))
    assert len(out) == nf
    return out


@pytest.fixture(scope="module")
def tagged_model(study_dir):
    from cardionurbs.analysis.tags import tag_metrics
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.io import load_study
    model = reconstruct(load_study(study_dir))
    return model, tag_metrics(model, over_time=True)


@needs_fork
def test_strain_over_time_parallel_equals_serial(tagged_model):
    from cardionurbs.analysis.regional import regional_metrics
    serial = regional_metrics(*tagged_model, jobs=1)
    parallel = regional_metrics(*tagged_model, jobs=2)
    assert list(serial.over_time) == list(parallel.over_time) == [1, 2, 3, 4]
    assert _same(serial.over_time, parallel.over_time)
    assert _same(dict(serial), dict(parallel)) and _same(serial.strain, parallel.strain)


def _same(a, b) -> bool:
    """Equal to the bit: same keys, types and values (NaN where NaN), arrays included."""
    if isinstance(a, dict):
        return (isinstance(b, dict) and list(a) == list(b)
                and all(_same(a[k], b[k]) for k in a))
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, (np.ndarray, np.generic, float)):
        return (type(a) is type(b) and np.shape(a) == np.shape(b)
                and np.asarray(a).tobytes() == np.asarray(b).tobytes())
    return type(a) is type(b) and a == b


@needs_fork
def test_worker_failure_in_meshes_no_output(study_dir, tmp_path, monkeypatch, capsys):
    from cardionurbs.anatomy.model import BiventricularModel
    real = BiventricularModel.mesh_arrays

    def failing(self, frame):
        if frame == 3:                                  # a frame meshed by a worker
            raise ReconstructionError(f"rv_cavity, frame {frame}: boolean result is empty")
        return real(self, frame)

    monkeypatch.setattr(BiventricularModel, "mesh_arrays", failing)
    out = tmp_path / "out"
    assert cli.main(["analyze", str(study_dir), "--out", str(out), "--jobs", "2",
                     "--outputs", "metrics,meshes"]) == 2
    assert "rv_cavity, frame 3: boolean result is empty" in capsys.readouterr().err
    assert not out.exists() and list(tmp_path.iterdir()) == []      # nothing left behind


@needs_fork
def test_worker_failure_in_tag_strain(tagged_model, monkeypatch):
    from cardionurbs.analysis import regional
    real = regional.tag_strain

    def failing(material, frame, *a, **k):
        if frame == 4:                                  # ES is 2: frame 4 is a worker's
            raise TagError("tag line 2 has no points", slice="sa_03", frame=frame)
        return real(material, frame, *a, **k)

    monkeypatch.setattr(regional, "tag_strain", failing)
    with pytest.raises(TagError, match="slice sa_03, frame 4: tag line 2 has no points") as info:
        regional.regional_metrics(*tagged_model, jobs=2)
    assert "in a worker process" in str(info.value.__cause__)


@needs_fork
def test_failure_after_the_meshes_started_leaves_nothing(study_dir, tmp_path, monkeypatch,
                                                         capsys):
    """analyze starts the meshes' workers once ED and ES are known; a failure in the tag
    analysis after that stops them and removes their temporary folder."""
    from cardionurbs.analysis import regional

    def failing(*a, **k):
        raise TagError("no tag planes at ED", frame=0)

    from cardionurbs.io import atomic
    made = []

    def spy(path):
        made.append(real(path))
        return made[-1]

    real = atomic.sibling_temporary_dir
    monkeypatch.setattr(atomic, "sibling_temporary_dir", spy)
    monkeypatch.setattr(regional, "regional_metrics", failing)
    out = tmp_path / "out"
    assert cli.main(["analyze", str(study_dir), "--out", str(out), "--jobs", "2"]) == 2
    assert "frame 0: no tag planes at ED" in capsys.readouterr().err
    assert len(made) == 1 and made[0].parent == tmp_path        # the meshes had started
    assert list(tmp_path.iterdir()) == [] and not mp.active_children()
