"""The compact model file (issue 33): model.json version 2 (knots, control points and
weights at a stated precision, nothing derivable), model.npz, and version-1 files."""

from __future__ import annotations

import json
import math
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cardionurbs as cn
from cardionurbs.analysis.function import measure
from cardionurbs.analysis.regional import regional_metrics
from cardionurbs.errors import ExportError
from cardionurbs.io import load_study
from cardionurbs.io.modelfile import (TAG_UNIT_MM, UNIT_MM, ZIP_TIME, pack, read_model_file,
                                      unpack, write_model_file)

FRAMES = 20


@pytest.fixture(scope="module")
def analysed(phantom20_analysed):
    """The shared 20-frame phantom's study, output folder and metrics (conftest.py)."""
    study, out = phantom20_analysed
    return study, out, json.loads((out / "metrics.json").read_text())["metrics"]


def test_model_json_of_a_20_frame_tagged_phantom_is_under_500_kB(analysed):
    _, out, _ = analysed
    path = out / "model.json"
    assert path.stat().st_size < 500_000
    d = json.loads(path.read_text())
    assert d["version"] == 2 and "sections" not in d                  # nothing derivable
    assert d["precision"]["control_points_mm"] == UNIT_MM
    back = read_model_file(path)
    assert len(back["surfaces"]) == FRAMES and len(back["tag_surfaces"]["frames"]) == FRAMES
    s = back["surfaces"]["0"]["lv_endo"]
    assert np.asarray(s["control_points"]).shape[-1] == 3 and s["degree_u"] == 3


def test_npz_is_smaller_and_both_forms_read_the_same(analysed, tmp_path):
    _, out, _ = analysed
    d = read_model_file(out / "model.json")
    npz = write_model_file(d, tmp_path / "model.npz")
    again = write_model_file(d, tmp_path / "model.json")
    assert npz.stat().st_size < (out / "model.json").stat().st_size
    assert read_model_file(npz) == d
    # the same bytes every time: no member stamped with the time it was written
    assert {i.date_time for i in zipfile.ZipFile(npz).infolist()} == {ZIP_TIME}
    assert write_model_file(d, tmp_path / "again.npz").read_bytes() == npz.read_bytes()
    # the stated precision is a fixed point: writing a read-back model gives the same file
    assert again.read_bytes() == (out / "model.json").read_bytes()


def tolerance(column: str, ref: float, metrics: dict) -> float:
    """1e-6 of the quantities a column is made of: a volume or mass difference (e.g.
    LVSV-RVSV, near 0) is held to 1e-6 of the LV end-diastolic volume, a percentage to
    1e-6 of 100 %, anything else to 1e-6 of itself."""
    if column.endswith(("(mL)", "(g)")):
        return 1e-6 * max(abs(ref), metrics["LVEDV (mL)"])
    if column.endswith("(%)"):
        return 1e-6 * max(abs(ref), 100.0)
    return 1e-6 * abs(ref) + 1e-12


def test_the_loaded_model_gives_the_metrics_to_1e_6(analysed):
    study_dir, out, metrics = analysed
    model = cn.load_model(out / "model.json")
    got = measure(model)
    compared = 0
    for k, v in got.items():
        ref = metrics.get(k)
        if ref is None or not math.isfinite(v):
            continue
        assert abs(v - ref) <= tolerance(k, ref, metrics), k
        compared += 1
    assert compared >= 12 and "LVEDV (mL)" in got and "RVM (g)" in got
    with_study = cn.load_model(out / "model.json", study=load_study(study_dir))
    regional = regional_metrics(with_study)
    for k in range(1, 17):
        for col in (f"WT_AHA_{k} (mm)", f"WT_ES_AHA_{k} (mm)"):
            assert regional[col] == pytest.approx(metrics[col], rel=1e-6), col


def test_version_1_files_still_load(tmp_path):
    """A version-1 model.json is ``json.dumps(model.to_dict())`` (every float as text,
    the SA sections with it): what analyze wrote before version 2."""
    from cardionurbs.phantom import generate
    ph = generate("normal", seed=2, frames=2, volume_check=False)
    model = cn.reconstruct(ph.study)
    old = model.to_dict()
    assert old["version"] == 1 and old["sections"]
    path = tmp_path / "model.json"
    path.write_text(json.dumps(old))
    back = cn.load_model(path)
    assert back.frames == model.frames and back.sections.keys() == model.sections.keys()
    for f in model.frames:
        for k, v in model.volumes[f].items():
            assert back.volumes[f][k] == pytest.approx(v, rel=1e-12)
    cn.save_model(back, tmp_path / "v2.json")
    v2 = cn.load_model(tmp_path / "v2.json")
    for f in model.frames:
        for k, v in model.volumes[f].items():
            assert v2.volumes[f][k] == pytest.approx(v, rel=1e-6)


def _surface(draw_cp, weights, closed):
    nu, nv = draw_cp.shape[:2]
    p = 3
    if closed:
        knots_u = list(np.arange(-p, nu + p + 1) / nu)
    else:
        knots_u = [0.0] * p + list(np.linspace(0, 1, nu - p + 1)) + [1.0] * p
    knots_v = [0.0] * p + list(np.linspace(0, 1, nv - p + 1)) + [1.0] * p
    return {"type": "NurbsSurface", "format": 1, "degree_u": p, "degree_v": p,
            "closed_u": closed, "knots_u": knots_u, "knots_v": knots_v,
            "control_points": draw_cp.tolist(), "weights": weights.tolist()}


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), nu=st.integers(4, 9), nv=st.integers(4, 8),
       rational=st.booleans(), closed=st.booleans(), scale=st.floats(1.0, 400.0))
def test_pack_unpack_keeps_every_number_within_its_stated_precision(seed, nu, nv, rational,
                                                                    closed, scale):
    rng = np.random.default_rng(seed)
    cp = rng.uniform(-scale, scale, size=(nu, nv, 3))
    w = rng.uniform(0.5, 2.0, size=(nu, nv)) if rational else np.ones((nu, nv))
    d = {"format": "cardionurbs-model", "version": 1, "frames": [0],
         "surfaces": {"0": {"lv_endo": _surface(cp, w, closed)}},
         "sections": {"0": {}},
         "tag_surfaces": {"frames": {"0": {"sa1:0": _surface(cp[::-1], w, False)}}}}
    header, streams = pack(d)
    back = unpack(json.loads(json.dumps(header)), streams)
    assert "sections" not in back and back["version"] == 1
    s, t = back["surfaces"]["0"]["lv_endo"], back["tag_surfaces"]["frames"]["0"]["sa1:0"]
    assert np.abs(np.asarray(s["control_points"]) - cp).max() <= UNIT_MM / 2 * (1 + 1e-6)
    assert np.abs(np.asarray(t["control_points"]) - cp[::-1]).max() <= TAG_UNIT_MM / 2 * (1 + 1e-6)
    assert np.array_equal(np.asarray(s["weights"]), w)
    assert np.allclose(s["knots_u"], d["surfaces"]["0"]["lv_endo"]["knots_u"], atol=1e-9, rtol=0)
    assert np.all(np.diff(s["knots_v"]) >= 0)


def test_an_unreadable_model_file_is_one_clear_error(tmp_path):
    bad = tmp_path / "model.json"
    bad.write_text('{"format": "cardionurbs-model", "version": 2, "arrays": {}}')
    with pytest.raises(ExportError, match="model.json"):
        read_model_file(bad)
    with pytest.raises(ExportError, match=r"\.json or \.npz"):
        write_model_file({"version": 1}, tmp_path / "model.txt")
