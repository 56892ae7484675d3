"""The same bytes every run (issue 31, finding 7): two ``analyze`` runs of one study with
every output (metrics, model with model.3dm, meshes, figures, report), ``--jobs 1`` and
``--jobs 2``, each in its own process with its own string-hash seed, write byte-identical
folders; mesh files are canonical (vertices sorted, faces rotated to their smallest index
and sorted: cardionurbs.io.export.canonical_order). The subject name is not ASCII
(finding 5): the runs print their one result line and nothing on stderr, and no figure
draws an empty box for a character its font lacks."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from cardionurbs.cli import main
from cardionurbs.io.export import canonical_order

SUBJECT = "Müller-Ærø_株"
#: (jobs, PYTHONHASHSEED) of the two runs: string hashing (set and dict order of names)
#: differs between them, as between any two runs of the command
RUNS = {"a": ("1", "1"), "b": ("2", "2")}


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("repro")
    study = root / "S"
    assert main(["phantom", "--pathology", "normal", "--frames", "2", "--no-dicom",
                 "--out", str(study)]) == 0
    meta = json.loads((study / "study.json").read_text())
    meta["subject"] = SUBJECT
    (study / "study.json").write_text(json.dumps(meta, ensure_ascii=False), encoding="utf-8")
    out = {}
    for name, (jobs, seed) in RUNS.items():
        env = dict(os.environ, PYTHONHASHSEED=seed, PYTHONIOENCODING="utf-8")
        r = subprocess.run([sys.executable, "-m", "cardionurbs.cli", "analyze", str(study),
                            "--out", str(root / name), "--jobs", jobs], env=env,
                           capture_output=True, text=True, encoding="utf-8")
        out[name] = (r, root / name)
    return out


def test_two_runs_and_two_job_counts_give_the_same_bytes(runs):
    snaps = {k: _snapshot(folder) for k, (r, folder) in runs.items()}
    a, b = snaps["a"], snaps["b"]
    for part in ("model.3dm", "model.json", "metrics.json", "report.html", ".cardionurbs-output"):
        assert part in a, part
    assert any(k.endswith(".ply") for k in a) and any(k.endswith(".png") for k in a)
    differ = sorted(k for k in a if a[k] != b.get(k))
    assert differ == [] and a.keys() == b.keys(), differ


def test_a_non_ascii_subject_prints_one_line_and_no_glyph_warning(runs):
    for r, folder in runs.values():
        assert r.returncode == 0 and r.stderr == "", r.stderr
        assert re.fullmatch(rf"{re.escape(SUBJECT)}: ED frame 0, ES frame 1; LVEDV [0-9.]+ mL, "
                            rf"LVEF [0-9.]+ %; wrote {re.escape(str(folder))}\n", r.stdout), r.stdout
    captions = json.loads((folder / "figures" / "figures.json").read_text(encoding="utf-8"))
    assert SUBJECT in json.dumps(captions, ensure_ascii=False)     # the name itself, kept


def test_figure_text_has_no_glyph_the_font_lacks():
    """plain_text writes a character no figure font has as [U+XXXX]: matplotlib then draws
    the whole name and warns of no missing glyph (the raw name does warn: the check bites)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from cardionurbs.safe import _drawable, plain_text

    def glyph_warnings(text: str) -> list[str]:
        fig = Figure()
        FigureCanvasAgg(fig)
        fig.text(0.1, 0.5, text)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fig.canvas.draw()
        return [str(w.message) for w in caught if "Glyph" in str(w.message)]

    lacks = 0x682A not in (_drawable() or ())        # 株: not in DejaVu Sans (matplotlib's)
    shown = plain_text(SUBJECT)
    assert shown == ("Müller-Ærø_[U+682A]" if lacks else SUBJECT) and glyph_warnings(shown) == []
    assert bool(glyph_warnings(SUBJECT)) == lacks
    assert plain_text("cost $5\nnext") == "cost \\$5\nnext"


def test_the_3dm_objects_have_ids_of_their_geometry(runs, tmp_path):
    rhino3dm = pytest.importorskip("rhino3dm", reason="rhino3dm (the 'cad' extra) is not installed")
    from cardionurbs import load_model
    from cardionurbs.nurbs.rhino import geometry_id, write_3dm
    _, folder = runs["a"]
    f = rhino3dm.File3dm.Read(str(folder / "model.3dm"))
    ids = [o.Attributes.Id for o in f.Objects]
    assert len(ids) == 4 and len(set(ids)) == 4 and {i.version for i in ids} == {5}
    assert len(f.Layers) == 1 and f.Layers[0].Id.version == 5
    model = load_model(folder / "model.json")
    s = model.surfaces[model.ed_frame]
    lv, epi = s["lv_endo"], s["lv_epi"]
    # another geometry or another name, another id
    assert len({geometry_id(lv, "x"), geometry_id(epi, "x"), geometry_id(lv, "y")}) == 3
    one, two = (write_3dm(tmp_path / n, [lv, epi], names=["lv", "epi"]) for n in ("1.3dm", "2.3dm"))
    back = rhino3dm.File3dm.Read(str(one))
    assert [o.Attributes.Id for o in back.Objects] == [geometry_id(lv, "lv"), geometry_id(epi, "epi")]
    assert one.read_bytes() == two.read_bytes() and "1.3dm".encode("utf-16-le") not in one.read_bytes()


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
