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


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 12))
def test_pair_residuals_of_many_lines_equal_line_by_line(seed, problems):
    """Lines of different lengths in different planes, one batch, against blend_trace and
    signed_distance_to_trace line by line (a pair that misses the plane goes one by one)."""
    from cardionurbs.analysis.tagqc import _pair_residuals_many
    rng = np.random.default_rng(seed)
    u = np.linspace(0, 1, 48)
    pts, Ca, Cb, O, N = [], [], [], [], []
    for k in range(problems):
        normal = rng.normal(0, 0.15, 3) + [0, 0, 1]
        normal /= np.linalg.norm(normal)
        origin = rng.normal(0, 2, 3)
        base = np.column_stack([40 * u - 20, 3 * np.sin(3 * u + k), np.zeros_like(u)]) + origin
        a = base + [0, rng.normal(0, 2), -5 - 5 * rng.random()] + rng.normal(0, 0.2, (48, 3))
        b = base + [0, rng.normal(0, 2), 5 + 5 * rng.random()] + rng.normal(0, 0.2, (48, 3))
        if rng.random() < 0.15:          # a pair whose samples do not all cut the plane
            b[:5] = a[:5]
        n = int(rng.integers(0, 30))
        p = np.column_stack([rng.uniform(-15, 15, n), rng.normal(0, 1, n), np.zeros(n)]) + origin
        pts.append(p), Ca.append(a), Cb.append(b), O.append(origin), N.append(normal)
    got = _pair_residuals_many(pts, Ca, Cb, O, N)
    for g, p, a, b, o, n in zip(got, pts, Ca, Cb, O, N):
        T, tan = blend_trace(a, b, o, n)
        d = signed_distance_to_trace(p, T, tan, n)
        if len(d) == 0 or not np.isfinite(d).all():
            assert g is None
        else:
            assert g == pytest.approx(float(np.median(d)), abs=1e-9)


def _index_trend_reference(values, i, outlier):
    """The tag-index trend as np.polyfit computes it, one problem at a time."""
    if not values:
        return 0.0
    j = np.array([v[0] for v in values], float)
    r = np.array([v[1] for v in values], float)
    keep = np.ones(len(j), bool)
    for _ in range(2):
        n = int(keep.sum())
        if n == 0:
            return 0.0
        if n == 1:
            return float(r[keep][0])
        w = 1.0 / (1.0 + np.abs(j[keep] - i)) ** 2
        c = np.polyfit(j[keep] - i, r[keep], 2 if n >= 4 else 1, w=np.sqrt(w))
        new = np.abs(r - np.polyval(c, j - i)) <= outlier
        if new.sum() < 1 or np.array_equal(new, keep):
            break
        keep = new
    return float(c[-1])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 25))
def test_batched_index_trends_equal_polyfit_one_by_one(seed, problems):
    from cardionurbs.analysis.tagqc import _index_trends
    rng = np.random.default_rng(seed)
    vals, at = [], []
    for _ in range(problems):
        i = int(rng.integers(-6, 7))
        others = [j for j in range(-7, 8) if j != i and rng.random() < 0.6]
        a, b, c = rng.normal(0, [0.5, 0.1, 0.02])
        v = [(j, float(a + b * j + c * j * j + rng.normal(0, 0.05)
                       + (3.0 if rng.random() < 0.15 else 0.0))) for j in others]
        vals.append(v), at.append(i)
    got = _index_trends(vals, at, 1.0)
    for g, v, i in zip(got, vals, at):
        assert g == pytest.approx(_index_trend_reference(v, i, 1.0), rel=1e-9, abs=1e-9)
