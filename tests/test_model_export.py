"""`analyze` output folder and mesh/model export (STL, PLY, OBJ, GLB by extension; model.json)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from cardionurbs.analysis.function import COLUMNS
from cardionurbs.anatomy.model import BiventricularModel, reconstruct
from cardionurbs.cli import main
from cardionurbs.io.export import ExportError, export_mesh, mesh_format
from cardionurbs.io.native import write_study

from test_model_fixtures import heart, study_from_hearts


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    st = study_from_hearts([heart(1.0), heart(0.8)], subject="ell")
    return write_study(st, tmp_path_factory.mktemp("an") / "ell")


@pytest.fixture(scope="module")
def analysis(study_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "analysis"
    assert main(["analyze", str(study_dir), "--out", str(out), "--no-figures"]) == 0
    return out


def test_metrics_json(analysis):
    d = json.loads((analysis / "metrics.json").read_text())
    assert d["subject"] == "ell" and (d["ed_frame"], d["es_frame"]) == (0, 1)
    assert list(d["metrics"]) == list(COLUMNS)
    assert 80 < d["metrics"]["LVEDV (mL)"] < 90
    assert d["volume_curve"]["frame"] == [0, 1]
    assert d["residuals"]["lv_endo"]["max_px"] < 1.0


def test_meshes_per_frame_and_structure_are_closed(analysis):
    files = sorted((analysis / "meshes").glob("*.ply"))
    assert len(files) == 8
    for f in files:
        tm = trimesh.load(f, force="mesh")
        assert tm.is_watertight and tm.is_volume, f.name


def test_model_json_round_trip(analysis):
    d = json.loads((analysis / "model.json").read_text())
    m = BiventricularModel.from_dict(d)
    tm = trimesh.load(analysis / "meshes" / "frame_00_lv_cavity.ply", force="mesh")
    assert m.volumes[0]["lv_cavity"] == pytest.approx(tm.volume / 1000, rel=1e-4)
    assert (analysis / "residuals.csv").exists()


def test_existing_output_is_replaced_atomically(study_dir, analysis, tmp_path):
    from cardionurbs.io.atomic import MARKER
    out = tmp_path / "again"
    out.mkdir()
    (out / "stale.txt").write_text("old")
    # a folder cardionurbs did not write is never replaced (issue 10) ...
    assert main(["analyze", str(study_dir), "--out", str(out), "--no-figures", "--overwrite"]) == 2
    assert (out / "stale.txt").read_text() == "old"
    # ... nor one whose marker lists no files (what it wrote is unknown) ...
    (out / MARKER).write_text("")
    assert main(["analyze", str(study_dir), "--out", str(out), "--no-figures", "--overwrite"]) == 2
    assert (out / "stale.txt").read_text() == "old"
    # ... an earlier output is, with --overwrite, as a whole
    (out / "stale.txt").unlink()
    (out / MARKER).unlink()
    assert main(["analyze", str(study_dir), "--out", str(out), "--no-figures"]) == 0
    assert main(["analyze", str(study_dir), "--out", str(out), "--no-figures"]) == 2
    assert main(["analyze", str(study_dir), "--out", str(out), "--no-figures", "--overwrite"]) == 0
    assert (out / "metrics.json").exists()


def test_bad_study_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["analyze", str(tmp_path / "nope"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope" in err
    assert not out.exists()


@pytest.fixture(scope="module")
def lv_myocardium():
    m = reconstruct(study_from_hearts([heart(1.0)], rv=False), resolution=(40, 24))
    return m.meshes(0)["lv_myocardium"]


@pytest.mark.parametrize("ext", ["stl", "ply", "obj", "glb"])
def test_export_formats_by_extension(ext, tmp_path, lv_myocardium):
    tm = lv_myocardium
    path = export_mesh(tm, tmp_path / f"lv_myo.{ext}")
    back = trimesh.load(path, force="mesh")
    if ext != "obj":
        back.merge_vertices()
    assert back.volume == pytest.approx(tm.volume, rel=1e-3)
    assert np.allclose(back.bounds, tm.bounds, atol=1e-3)


def test_unsupported_extension():
    with pytest.raises(ExportError, match="vtk"):
        mesh_format("x.vtk")


def test_rhino_3dm_matches_the_surfaces(analysis):
    rhino3dm = pytest.importorskip("rhino3dm", reason="the cad extra (rhino3dm) is not installed")
    m = BiventricularModel.from_dict(json.loads((analysis / "model.json").read_text()))
    f = rhino3dm.File3dm.Read(str(analysis / "model.3dm"))
    names = sorted(o.Attributes.Name for o in f.Objects)
    assert names == sorted(f"{s}_frame{m.ed_frame}" for s in m.surfaces[m.ed_frame])
    for o in f.Objects:
        g = o.Geometry
        s = m.surfaces[m.ed_frame][o.Attributes.Name.split("_frame")[0]]
        d0, d1 = g.Domain(0), g.Domain(1)
        for u, v in ((0.3, 0.6), (0.9, 0.1)):
            p = g.PointAt(d0.T0 + u * (d0.T1 - d0.T0), d1.T0 + v * (d1.T1 - d1.T0))
            assert np.allclose([p.X, p.Y, p.Z], s.evaluate([u], [v])[0, 0], atol=1e-6)
