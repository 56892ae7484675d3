"""`analyze --mesh-format vtp`: VTK PolyData per frame and mesh with point data, and a
ParaView .pvd time series per mesh (issue 33), read back with VTK's own readers.

One 20-frame tagged phantom is analysed once for this module and test_model_file.py
(conftest.py's ``phantom20_analysed``: metrics, model and vtp meshes, two processes); every file is read with ``vtkXMLPolyDataReader`` (the .pvd with VTK's
XML parser, ``vtkXMLDataParser``: the VTK wheel has no .pvd reader, ParaView has)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

vtk = pytest.importorskip("vtkmodules", reason="the vtk wheel (test extra) is not installed")
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402
from vtkmodules.vtkIOXML import vtkXMLPolyDataReader  # noqa: E402
from vtkmodules.vtkIOXMLParser import vtkXMLDataParser  # noqa: E402

from cardionurbs.cli import main  # noqa: E402
from cardionurbs.io.vtkfiles import canonical_order, write_pvd, write_vtp  # noqa: E402

MESHES = ("lv_cavity", "lv_myocardium", "rv_cavity", "rv_myocardium")
FRAMES = 20


@pytest.fixture(scope="module")
def analysed(phantom20_analysed):
    """The shared 20-frame phantom (conftest.py): output folder, metrics.json, frame times."""
    study, out = phantom20_analysed
    times = {int(k): v for k, v in json.loads((study / "study.json").read_text())
             ["frame_times_ms"].items()}
    return out, json.loads((out / "metrics.json").read_text()), times


def read_vtp(path: Path) -> dict:
    """Points (V, 3), triangles (F, 3), point data {name: (V,)} and TimeValue of a .vtp."""
    r = vtkXMLPolyDataReader()
    r.SetFileName(str(path))
    r.Update()
    assert r.GetErrorCode() == 0, path
    poly = r.GetOutput()
    polys = poly.GetPolys()
    offsets = vtk_to_numpy(polys.GetOffsetsArray())
    assert np.all(np.diff(offsets) == 3), f"{path.name}: not all triangles"
    pd = poly.GetPointData()
    return {"points": vtk_to_numpy(poly.GetPoints().GetData()),
            "faces": vtk_to_numpy(polys.GetConnectivityArray()).reshape(-1, 3),
            "data": {pd.GetArrayName(i): vtk_to_numpy(pd.GetArray(i))
                     for i in range(pd.GetNumberOfArrays())},
            "time": float(vtk_to_numpy(poly.GetFieldData().GetArray("TimeValue"))[0])}


def read_pvd(path: Path) -> list[tuple[float, str]]:
    """(timestep, file) of every DataSet of a .pvd, through VTK's XML parser."""
    p = vtkXMLDataParser()
    p.SetFileName(str(path))
    assert p.Parse() == 1, path
    root = p.GetRootElement()
    assert root.GetName() == "VTKFile" and root.GetAttribute("type") == "Collection"
    col = root.GetNestedElement(0)
    assert col.GetName() == "Collection"
    return [(float(col.GetNestedElement(i).GetAttribute("timestep")),
             col.GetNestedElement(i).GetAttribute("file"))
            for i in range(col.GetNumberOfNestedElements())]


def vertex_areas(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A third of the area of the triangles around each vertex (mm²)."""
    a = 0.5 * np.linalg.norm(np.cross(points[faces[:, 1]] - points[faces[:, 0]],
                                      points[faces[:, 2]] - points[faces[:, 0]]), axis=1)
    out = np.zeros(len(points))
    np.add.at(out, faces.ravel(), np.repeat(a / 3, 3))
    return out


def test_every_vtp_is_a_closed_mesh_with_its_frame_time(analysed):
    out, metrics, times = analysed
    files = sorted((out / "meshes").glob("*.vtp"))
    assert len(files) == FRAMES * len(MESHES)
    for f in files:
        frame = int(f.name.split("_")[1])
        m = read_vtp(f)
        assert len(m["points"]) > 100 and m["faces"].max() < len(m["points"])
        edges = np.sort(m["faces"][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        assert np.all(counts == 2), f"{f.name}: not closed"
        assert m["time"] == pytest.approx(times[frame])
        assert np.all(m["data"]["time (ms)"] == pytest.approx(times[frame]))


def test_the_meshes_enclose_the_measured_volumes(analysed):
    out, metrics, _ = analysed
    curve = metrics["volume_curve"]
    for k, frame in enumerate(curve["frame"]):
        for mesh in ("lv_cavity", "rv_cavity"):
            m = read_vtp(out / "meshes" / f"frame_{frame:02d}_{mesh}.vtp")
            p, f = m["points"], m["faces"]
            vol = np.einsum("ij,ij->i", p[f[:, 0]], np.cross(p[f[:, 1]], p[f[:, 2]])).sum() / 6e3
            assert vol == pytest.approx(curve[f"{mesh} (mL)"][k], rel=1e-6), (mesh, frame)


def test_every_pvd_plays_the_cycle_at_the_study_times(analysed):
    out, _, times = analysed
    for mesh in MESHES:
        rows = read_pvd(out / "meshes" / f"{mesh}.pvd")
        assert [t for t, _ in rows] == pytest.approx([times[f] for f in range(FRAMES)])
        for t, name in rows:
            assert name == f"frame_{int(name.split('_')[1]):02d}_{mesh}.vtp"
            assert read_vtp(out / "meshes" / name)["time"] == pytest.approx(t)


@pytest.mark.parametrize("when", ["ED", "ES"])
def test_wall_thickness_on_the_mesh_matches_the_segment_means(analysed, when):
    out, metrics, _ = analysed
    frame = metrics["ed_frame" if when == "ED" else "es_frame"]
    m = read_vtp(out / "meshes" / f"frame_{frame:02d}_lv_myocardium.vtp")
    t, seg = m["data"]["wall thickness (mm)"], m["data"]["AHA segment"]
    assert np.isfinite(t).mean() > 0.95 and np.nanmin(t) > 2 and np.nanmax(t) < 25
    w = vertex_areas(m["points"], m["faces"])
    column = "WT_AHA_{} (mm)" if when == "ED" else "WT_ES_AHA_{} (mm)"
    for k in range(1, 17):
        sel = (seg == k) & np.isfinite(t)
        assert sel.sum() > 10, k
        mesh_mean = np.average(t[sel], weights=w[sel])
        assert mesh_mean == pytest.approx(metrics["metrics"][column.format(k)], abs=0.2), k


def test_endocardium_has_segments_and_the_tag_strain(analysed):
    out, metrics, _ = analysed
    ed, es = metrics["ed_frame"], metrics["es_frame"]
    m = read_vtp(out / "meshes" / f"frame_{es:02d}_lv_cavity.vtp")
    seg = m["data"]["AHA segment"]
    assert set(np.unique(seg)) >= set(range(1, 18))
    for kind in ("Err", "Ecc", "Ell"):
        values = m["data"][f"{kind} (%)"]
        for k in range(1, 17):
            expected = metrics["metrics"][f"{kind}_AHA_{k} (%)"]
            assert np.allclose(values[seg == k], expected), (kind, k)
        assert np.isnan(values[seg == 17]).all() and np.isnan(values[seg == 0]).all()
    assert np.nanmean(m["data"]["Ecc (%)"]) < -5 and np.nanmean(m["data"]["Err (%)"]) > 5
    at_ed = read_vtp(out / "meshes" / f"frame_{ed:02d}_lv_cavity.vtp")["data"]
    inside = (at_ed["AHA segment"] >= 1) & (at_ed["AHA segment"] <= 16)
    assert np.all(at_ed["Ecc (%)"][inside] == 0.0)
    rv = read_vtp(out / "meshes" / f"frame_{es:02d}_rv_cavity.vtp")["data"]
    assert set(rv) == {"time (ms)"}


def test_vtp_bytes_depend_on_the_mesh_not_its_order(tmp_path):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(6, 3))
    f = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 0], [1, 3, 5]])
    data = {"value": np.arange(6.0), "label": np.arange(6)}
    perm = rng.permutation(6)
    inverse = np.argsort(perm)
    a = write_vtp(tmp_path / "a.vtp", v, f, data, time_ms=12.5)
    b = write_vtp(tmp_path / "b.vtp", v[perm], np.roll(inverse[f], 1, axis=1)[::-1],
                  {k: x[perm] for k, x in data.items()}, time_ms=12.5)
    assert a.read_bytes() == b.read_bytes()
    back = read_vtp(a)
    cv, cf, cd = canonical_order(v, f, data)
    assert np.array_equal(back["points"], cv) and np.array_equal(back["faces"], cf)
    assert back["data"]["label"].dtype.kind == "i" and back["time"] == 12.5
    assert np.array_equal(back["data"]["value"], cd["value"])
    pvd = write_pvd(tmp_path / "s.pvd", [(20.0, "b.vtp"), (10.0, "a.vtp")])
    assert read_pvd(pvd) == [(10.0, "a.vtp"), (20.0, "b.vtp")]


def test_vtp_without_vtk_exits_2_before_any_work(tmp_path, monkeypatch, capsys):
    import cardionurbs.io.vtkfiles as vf
    from cardionurbs.errors import ExportError

    def missing():
        raise ExportError(vf.VTK_MISSING)
    monkeypatch.setattr(vf, "_vtk", missing)
    out = tmp_path / "out"
    assert main(["analyze", str(tmp_path / "nowhere"), "--mesh-format", "vtp",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cardionurbs[vtk]" in err and not out.exists()


def test_mesh_format_option_writes_the_other_formats(tmp_path):
    study = tmp_path / "study"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom",
                 "--out", str(study)]) == 0
    assert main(["analyze", str(study), "--outputs", "meshes", "--mesh-format", "stl",
                 "--jobs", "1", "--out", str(tmp_path / "out")]) == 0
    files = sorted((tmp_path / "out" / "meshes").iterdir())
    assert len(files) == 2 * len(MESHES) and all(f.suffix == ".stl" for f in files)
