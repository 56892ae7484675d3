"""The all-outputs `analyze` path without pandas and with one bull's-eye figure (issue 16):
residuals.csv is the pandas table's CSV (same rows, counts and maxima; means to the last
digit), written by a formatter that writes what pandas writes; the bull's-eyes drawn on one
shared figure are the PNGs a fresh figure gives; a fresh all-outputs run imports no pandas."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.io.export import table_csv
from cardionurbs.phantom import generate
from cardionurbs.phantom.generate import write_phantom
from cardionurbs.report.bullseye import QUANTITIES, BullseyeCanvas, bullseye_figure
from cardionurbs.safe import csv_safe_table

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ["structure", "frame", "slice", "view", "n_points", "mean_mm", "max_mm", "mean_px",
           "max_px"]


@pytest.fixture(scope="module")
def phantom():
    return generate("normal", seed=3, frames=2, volume_check=False)


@pytest.fixture(scope="module")
def model(phantom):
    from cardionurbs.anatomy.model import reconstruct
    return reconstruct(phantom.study)


def _pandas_table(points: pd.DataFrame) -> pd.DataFrame:
    """The per-contour table as pandas groups it (the code residual_columns replaces)."""
    g = points.groupby(["structure", "frame", "slice", "view"], sort=False)
    return g.agg(n_points=("dist_mm", "size"), mean_mm=("dist_mm", "mean"),
                 max_mm=("dist_mm", "max"), mean_px=("dist_px", "mean"),
                 max_px=("dist_px", "max")).reset_index()[COLUMNS]


def _same_table(new: dict, old: pd.DataFrame, rtol: float = 0.0) -> None:
    """Same rows, keys and counts; means to 4 ulp (fsum / n against pandas' compensated
    sum / n), maxima exactly (both to ``rtol`` when given)."""
    assert list(new) == COLUMNS and len(new["frame"]) == len(old) > 0
    for c in COLUMNS:
        if c.startswith(("mean", "max")):
            assert np.allclose(new[c], old[c].to_numpy(), atol=0,
                               rtol=rtol or (4 * np.finfo(float).eps if c[:4] == "mean" else 0))
        else:
            assert new[c].tolist() == old[c].tolist(), c


@pytest.mark.parametrize("every_frame", [False, True])
def test_residual_columns_are_the_pandas_groups(model, every_frame):
    frames = model.frames if every_frame else None
    _same_table(model.residual_columns(frames), _pandas_table(model.point_residuals(frames)))


def test_points_without_a_slice_are_left_out_and_runs_of_one_contour_merge(model):
    parts = model.point_residual_arrays()
    p = parts[0]
    n = len(p["dist_mm"])
    sl = p["slice"].copy()
    sl[: n // 4] = None                                 # no slice: not a contour of the table
    sl[n // 2: n // 2 + 3] = sl[-1]                      # the last contour also appears earlier
    model._point_residuals(model._residual_frames())[0] = {**p, "slice": sl}
    try:
        new = model.residual_columns()
        pts = model.point_residuals()
        assert pts["slice"].isna().sum() == n // 4
        _same_table(new, _pandas_table(pts))
    finally:
        model._point_residuals(model._residual_frames())[0] = p


def test_residual_table_keeps_its_columns_and_empty_form(model):
    t = model.residual_table()
    assert list(t.columns) == COLUMNS and len(t) == len(model.residual_columns()["frame"])
    from cardionurbs.anatomy.model import BiventricularModel
    back = BiventricularModel.from_dict(model.to_dict())      # no contours: no rows
    assert back.residual_table().empty and list(back.residual_table().columns) == COLUMNS


_text = st.one_of(st.sampled_from(["sa_01", "a,b", 'say "hi"', "=1+2", "+x", "-", "@a", "\tt",
                                   "line\nbreak", "", " lead", "é"]), st.none())
_float = st.one_of(st.floats(allow_nan=True, allow_infinity=False, width=64),
                   st.sampled_from([1e-5, 0.1, 1e16, 123456789.0, -0.0, 5e-324]))


@settings(max_examples=60, deadline=None)
@given(rows=st.lists(st.tuples(_text, st.integers(-10**12, 10**12), _float), min_size=1,
                     max_size=8))
def test_table_csv_writes_what_pandas_writes(rows):
    cols = {"name": np.array([r[0] for r in rows], dtype=object),
            "n": np.array([r[1] for r in rows], dtype=np.int64),
            "x": np.array([r[2] for r in rows], dtype=float)}
    assert table_csv(cols) == csv_safe_table(pd.DataFrame(cols)).to_csv(index=False)


def _values(seed: int, holes: int) -> dict[int, float]:
    rng = np.random.default_rng(seed)
    v = {k: float(x) for k, x in zip(range(1, 17), rng.normal(0.0, 10.0, 16))}
    for k in rng.choice(np.arange(1, 17), holes, replace=False):
        v[int(k)] = math.nan
    return v


def test_bullseyes_on_one_shared_figure_are_the_fresh_figures_pngs(tmp_path):
    canvas = BullseyeCanvas()
    # every kind of quantity, segments without values, one with none at all but one
    cases = [(q, _values(i, holes)) for i, (q, holes) in
             enumerate(zip(QUANTITIES + QUANTITIES[::-1], [0, 3, 0, 15, 1, 2, 0, 5, 16, 0]))]
    for i, (q, vals) in enumerate(cases):
        name, _, title, unit, cmap, diverging = q
        kw = dict(cmap=cmap, diverging=diverging, caption=f"case {i}: {title}", label=name)
        shared = bullseye_figure(vals, title, unit, tmp_path / f"s{i}.png", canvas=canvas, **kw)
        fresh = bullseye_figure(vals, title, unit, tmp_path / f"f{i}.png", **kw)
        assert shared.read_bytes() == fresh.read_bytes(), (i, name)


def test_fresh_all_outputs_analysis_imports_no_pandas(phantom, tmp_path):
    from cardionurbs.io import native
    d = tmp_path / "s"
    write_phantom(phantom, d, dicom=False)
    native.write_study(native.read_study(d), d, points="parquet")   # as `phantom` writes it
    out = tmp_path / "out"
    code = ("import sys, json; from cardionurbs.cli import main; "
            f"rc = main(['analyze', {str(d)!r}, '--out', {str(out)!r}]); "
            "print(json.dumps([rc, 'pandas' in sys.modules]))")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout.strip().splitlines()[-1]) == [0, False], run.stderr
    from cardionurbs.io import load_study
    from cardionurbs.pipeline import analyse
    text = (out / "residuals.csv").read_text()
    table = pd.read_csv(out / "residuals.csv", keep_default_na=False)
    assert text.splitlines()[0] == ",".join(COLUMNS) and len(table) > 0
    # another process's model: the CLI runs BLAS on one thread, this process may not, and
    # the least-squares fits then differ in their last digits (residuals ~1e-13 relative)
    _same_table({c: table[c].to_numpy() for c in COLUMNS},
                _pandas_table(analyse(load_study(d))[0].point_residuals()), rtol=1e-9)
