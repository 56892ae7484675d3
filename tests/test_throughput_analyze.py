"""`analyze --outputs` and `--progress`, and the speed-ups behind them keep every number:
metrics-only writes only what was asked for and measures the same columns; the batched
tag-QC residuals equal the pair-by-pair ones; compact JSON reads back equal."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cardionurbs.analysis.tagqc import _pair_residuals, blend_trace, signed_distance_to_trace
from cardionurbs.cli import main
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.io.export import write_json
from cardionurbs.phantom import generate
from cardionurbs.phantom.generate import write_phantom
from cardionurbs.pipeline import OUTPUTS, analyse, parse_outputs


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    ph = generate("normal", seed=5, frames=3, tag_jumps=1, volume_check=False)
    d = tmp_path_factory.mktemp("s") / "study"
    write_phantom(ph, d, dicom=False)
    return d


def test_parse_outputs_orders_completes_and_rejects():
    assert parse_outputs(None) == OUTPUTS == parse_outputs("all")
    assert parse_outputs("figures,metrics") == ("metrics", "figures")
    assert parse_outputs("report") == ("metrics", "model", "report")
    with pytest.raises(ValueError, match="'mesh'"):
        parse_outputs("metrics,mesh")


@pytest.fixture(scope="module")
def full_analysis(study_dir):
    from cardionurbs.io import load_study
    return analyse(load_study(study_dir))        # every output's analysis (time course)


def test_metrics_only_writes_only_metrics_with_the_same_numbers(study_dir, full_analysis,
                                                               tmp_path, capsys):
    assert main(["analyze", str(study_dir), "--outputs", "metrics", "--progress",
                 "--out", str(tmp_path / "m")]) == 0
    assert sorted(p.name for p in (tmp_path / "m").iterdir()
                  if not p.name.startswith(".")) == ["metrics.json"]
    err = capsys.readouterr().err
    for stage in ("load", "reconstruct", "measure", "tags", "metrics"):
        assert f"analyze: {stage} done (" in err
    assert "figures done" not in err and "meshes done" not in err
    got = json.loads((tmp_path / "m" / "metrics.json").read_text())["metrics"]
    _, full, tags = full_analysis
    assert tags.over_time                 # the full run measured the time course ...
    for k, v in full.items():             # ... which changes no column
        if math.isnan(v):
            assert got[k] is None, k
        else:
            assert got[k] == pytest.approx(v, rel=1e-9, abs=1e-12), k


def test_unknown_output_is_a_usage_error(study_dir, tmp_path, capsys):
    assert main(["analyze", str(study_dir), "--outputs", "metrics,nope", "--out",
                 str(tmp_path / "x")]) == 2
    assert "nope" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 4), st.integers(3, 12))
def test_batched_pair_residuals_equal_pair_by_pair(seed, pairs, npts):
    rng = np.random.default_rng(seed)
    u = np.linspace(0, 1, 48)
    base = np.column_stack([40 * u - 20, 3 * np.sin(3 * u), np.zeros_like(u)])
    Ca = [base + [0, rng.normal(0, 2), -5 - rng.random() * 5] + rng.normal(0, 0.2, (48, 3))
          for _ in range(pairs)]
    Cb = [base + [0, rng.normal(0, 2), 5 + rng.random() * 5] + rng.normal(0, 0.2, (48, 3))
          for _ in range(pairs)]
    origin, normal = np.zeros(3), np.array([0.0, 0.0, 1.0])
    pts = np.column_stack([rng.uniform(-15, 15, npts), rng.normal(0, 1, npts), np.zeros(npts)])
    got = _pair_residuals(pts, Ca, Cb, origin, normal)
    for g, a, b in zip(got, Ca, Cb):
        T, tan = blend_trace(a, b, origin, normal)
        want = float(np.median(signed_distance_to_trace(pts, T, tan, normal)))
        assert g == pytest.approx(want, abs=1e-9)


def test_image_plane_normal_is_cached_and_read_only():
    p = ImagePlane("i", "sa_00", "SA", 0, [0, 0, 0], [1, 0, 0], [0, 1, 0], (1.0, 1.0))
    assert p.normal is p.normal
    assert np.array_equal(p.normal, [0, 0, 1])
    with pytest.raises(ValueError):
        p.normal[0] = 1.0


def test_compact_json_reads_back_equal_with_nan_as_null(tmp_path):
    obj = {"a": [1.5, np.float64(2.25), np.arange(3)], "b": {"c": float("nan")}, 3: np.int64(4)}
    write_json(obj, tmp_path / "x.json", indent=None)
    assert json.loads((tmp_path / "x.json").read_text()) == {"a": [1.5, 2.25, [0, 1, 2]],
                                                             "b": {"c": None}, "3": 4}
    write_json({"a": [0.1, 2]}, tmp_path / "y.json", indent=None)
    assert (tmp_path / "y.json").read_text() == '{"a": [0.1, 2]}\n'
