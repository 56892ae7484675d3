"""The same bytes every run (issue 31, finding 7): two ``analyze`` runs of one study, and
``--jobs 1`` against ``--jobs 2``, write byte-identical mesh files (vertices sorted, faces
rotated to their smallest index and sorted: cardionurbs.io.export.canonical_order), model
and metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from cardionurbs.cli import main
from cardionurbs.io.export import canonical_order

OUTPUTS = "meshes,model,metrics"


def _snapshot(folder: Path, skip=("model.3dm",)) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in skip}


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    s = tmp_path_factory.mktemp("repro") / "S"
    assert main(["phantom", "--pathology", "normal", "--frames", "3", "--no-dicom",
                 "--out", str(s)]) == 0
    return s


def test_two_runs_and_two_job_counts_give_the_same_bytes(study, tmp_path):
    runs = {}
    for name, jobs in (("a", "1"), ("b", "1"), ("c", "2")):
        assert main(["analyze", str(study), "--out", str(tmp_path / name), "--outputs", OUTPUTS,
                     "--jobs", jobs]) == 0
        runs[name] = _snapshot(tmp_path / name)
    assert any(k.endswith(".ply") for k in runs["a"])
    for other in ("b", "c"):
        differ = sorted(k for k in runs["a"] if runs["a"][k] != runs[other].get(k))
        assert differ == [] and runs["a"].keys() == runs[other].keys(), (other, differ)


def test_canonical_order_keeps_the_mesh_and_forgets_the_build_order():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(3)
    perm = rng.permutation(len(mesh.vertices))
    inv = np.argsort(perm)
    shuffled_v = mesh.vertices[perm]
    shuffled_f = np.roll(inv[mesh.faces][rng.permutation(len(mesh.faces))], 1, axis=1)
    v1, f1 = canonical_order(mesh.vertices, mesh.faces)
    v2, f2 = canonical_order(shuffled_v, shuffled_f)
    assert np.array_equal(v1, v2) and np.array_equal(f1, f2)
    again = trimesh.Trimesh(v1, f1, process=False)
    assert again.is_watertight and again.volume == pytest.approx(mesh.volume)   # orientation kept
