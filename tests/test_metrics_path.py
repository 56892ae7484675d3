"""The lean metrics-only path of issue 16 (what `cohort` and `analyze --outputs metrics` run)
gives the same numbers as the pandas path it replaces: a Parquet points file read straight
into numpy gives the same Study (nulls, pixel-only rows, a broken file's messages), the
numpy point residuals give the quality stats and the metrics.json residual summary of the
per-contour table, and a fresh metrics-only process imports neither pandas nor pydicom."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cardionurbs.errors import StudyError
from cardionurbs.io import native
from cardionurbs.phantom import generate
from cardionurbs.phantom.generate import write_phantom

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def phantom():
    return generate("normal", seed=3, frames=2, volume_check=False)


def _dump(study) -> list:
    """Everything a loaded study holds of its points, with the exact bytes and layout."""
    out = []
    for c in study.contours:
        out.append(("c", c.structure, c.view, c.slice, c.frame, c.image, c.closed, c.index,
                    c.points.tobytes(), c.points.flags.f_contiguous))
    for t in study.tags:
        out.append(("t", t.family, t.index, t.view, t.slice, t.frame, t.image, t.points.tobytes()))
    for lm in study.landmarks:
        out.append(("l", lm.name, lm.frame, lm.index, lm.slice, lm.view, lm.image,
                    lm.point.tobytes()))
    return out


def _read_both(folder: Path, monkeypatch) -> tuple[list, list]:
    fast = _dump(native.read_study(folder))
    with monkeypatch.context() as m:            # the pandas path: no numpy fast path
        m.setattr(native, "_parquet_columns", lambda path: None)
        slow = _dump(native.read_study(folder))
    return fast, slow


def test_parquet_points_read_without_pandas_equal_the_pandas_path(phantom, tmp_path,
                                                                  monkeypatch):
    d = tmp_path / "p"
    native.write_study(phantom.study, d, points="parquet")
    fast, slow = _read_both(d, monkeypatch)
    assert len(fast) > 100 and fast == slow
    # pixel-only rows (x, y, z empty) are mapped through their image the same way, and a
    # null string (an empty image id) reads as empty on both paths
    import pyarrow as pa
    import pyarrow.parquet as pq
    t = pq.read_table(d / native.POINTS_PARQUET)
    n = t.num_rows
    rows = np.zeros(n, bool)
    rows[::7] = True
    rows &= np.array([bool(v) for v in t.column("image").to_pylist()])    # rows with an image
    cols = {}
    for name in t.column_names:
        col = t.column(name).to_pylist()
        if name in ("x", "y", "z"):
            col = [None if r else v for v, r in zip(col, rows)]
        if name == "closed":
            col = [None if v == "" else v for v in col]
        cols[name] = col
    pq.write_table(pa.table(cols, schema=t.schema), d / native.POINTS_PARQUET)
    fast, slow = _read_both(d, monkeypatch)
    assert fast == slow


def test_parquet_of_another_schema_falls_back_and_bad_rows_name_their_line(phantom, tmp_path,
                                                                           monkeypatch):
    import pyarrow as pa
    import pyarrow.parquet as pq
    d = tmp_path / "s"
    native.write_study(phantom.study, d, points="parquet")
    path = d / native.POINTS_PARQUET
    t = pq.read_table(path)
    # text in a number column: the pandas path reads and judges it (same Study when it parses)
    x = pa.array([repr(v) for v in t.column("x").to_pylist()])
    pq.write_table(t.set_column(t.column_names.index("x"), "x", x), path)
    assert native._parquet_columns(path) is None
    assert len(native.read_study(d).contours) > 0
    # a fractional frame is refused naming its line, on both paths alike
    fr = t.column("frame").to_numpy().astype(float)
    fr[5] += 0.5
    pq.write_table(t.set_column(t.column_names.index("frame"), "frame", pa.array(fr)), path)
    with pytest.raises(StudyError, match="line 7: frame is not a number") as fast:
        native.read_study(d)
    with monkeypatch.context() as m:
        m.setattr(native, "_parquet_columns", lambda p: None)
        with pytest.raises(StudyError, match="line 7: frame is not a number") as slow:
            native.read_study(d)
    assert str(fast.value) == str(slow.value)


@pytest.fixture(scope="module")
def model_of(phantom):
    from cardionurbs.anatomy.model import reconstruct
    return reconstruct(phantom.study)


def test_numpy_residuals_give_the_table_s_quality_stats_and_summary(model_of):
    from cardionurbs.analysis.function import measure
    from cardionurbs.analysis.quality import assess, residual_stats, residual_summary
    model = model_of
    frames = sorted({model.ed_frame, model.es_frame})
    pts = model.point_residuals(frames)                  # the pandas table
    q = assess(model, measure(model))
    for (s, f), g in pts.groupby(["structure", "frame"]):
        assert q.surfaces[int(f)][s] == residual_stats(g["dist_mm"].to_numpy(),
                                                       g["dist_px"].to_numpy())
    for s, g in pts.groupby("structure"):
        assert q._pooled[s] == residual_stats(g["dist_mm"].to_numpy(), g["dist_px"].to_numpy())
    res = model.residual_table()
    summary = residual_summary(model)
    assert sorted(summary) == sorted(res["structure"].unique())
    for s, g in res.groupby("structure"):
        assert summary[s]["mean_mm"] == pytest.approx(float(g["mean_mm"].mean()), rel=1e-12)
        assert summary[s]["max_mm"] == float(g["max_mm"].max())
        assert summary[s]["max_px"] == float(g["max_px"].max())


@pytest.mark.parametrize("kind", ["native", "gpfile"])
def test_fresh_metrics_only_analysis_imports_neither_pandas_nor_pydicom(phantom, tmp_path, kind):
    d = tmp_path / "m"
    if kind == "native":
        write_phantom(phantom, d, dicom=False)
        native.write_study(native.read_study(d), d, points="parquet")
    else:
        from cardionurbs.io import gpfile
        gpfile.write_study(phantom.study, d)
    code = ("import sys, json; from cardionurbs.cli import main; "
            f"rc = main(['analyze', {str(d)!r}, '--outputs', 'metrics', '--out', "
            f"{str(tmp_path / 'out')!r}]); "
            "print(json.dumps([rc, sorted(m for m in ('pandas', 'pydicom', 'scipy.ndimage', "
            "'trimesh', 'matplotlib') if m in sys.modules)]))")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout.strip().splitlines()[-1]) == [0, []], run.stderr
    assert (tmp_path / "out" / "metrics.json").is_file()


BIVME = ROOT / ".." / "shared" / "data" / "bivme-patient1"


def _gp_dump(study) -> list:
    out = [("c", c.structure, c.view, c.slice, c.frame, c.image, c.closed, c.index,
            c.points.tobytes(), c.points.flags.f_contiguous,
            None if c.weights is None else c.weights.tobytes()) for c in study.contours]
    out += [("l", lm.name, lm.frame, lm.index, lm.slice, lm.view, lm.image, lm.point.tobytes())
            for lm in study.landmarks]
    return [out, study.meta, study.warnings, [im.to_dict() for im in study.images]]


@pytest.mark.skipif(not BIVME.is_dir(), reason="needs ../shared/data/bivme-patient1")
def test_plain_gpfiles_read_without_pandas_equal_the_pandas_reader(tmp_path, monkeypatch):
    import shutil
    from cardionurbs.io import gpfile
    d = tmp_path / "b"
    shutil.copytree(BIVME, d)
    gp = sorted(d.glob("GPFile_*.txt"))
    # frame 1 is not plain (a space-separated line): it alone goes through pandas
    lines = gp[1].read_text().splitlines()
    lines[5] = " ".join(lines[5].split("\t"))
    gp[1].write_text("\n".join(lines) + "\n")
    calls = []
    plain = gpfile._plain_rows
    monkeypatch.setattr(gpfile, "_plain_rows", lambda *a: calls.append(plain(*a)) or calls[-1])
    fast = _gp_dump(gpfile.read_study(d))
    assert sum(c is None for c in calls) == 1 and len(calls) == len(gp)
    monkeypatch.setattr(gpfile, "_plain_rows", lambda *a: None)
    assert fast == _gp_dump(gpfile.read_study(d))


@pytest.mark.parametrize("token, message", [("1_5", "x is not a number"),
                                            ("nan", "x is NaN or infinite"),
                                            ("１.5", "x is not a number")])
def test_odd_numbers_in_a_gpfile_are_told_as_before(tmp_path, token, message):
    from cardionurbs.io import gpfile
    if not BIVME.is_dir():
        pytest.skip("needs ../shared/data/bivme-patient1")
    import shutil
    d = tmp_path / "b"
    shutil.copytree(BIVME, d)
    path = sorted(d.glob("GPFile_*.txt"))[0]
    lines = path.read_text().splitlines()
    f = lines[3].split("\t")
    f[0] = token
    lines[3] = "\t".join(f)
    path.write_text("\n".join(lines) + "\n")
    assert gpfile._plain_rows(path.read_text(), path.read_text().splitlines(), 1) is None
    with pytest.raises(StudyError, match=f"line 4: {message}"):
        gpfile.read_study(d)


def test_spoke_profiles_kept_between_passes_give_each_pass_s_departures(la_spoke_fans):
    """The worst-first passes of the LA QC share one profile cache: every pass, whatever
    it excludes, gives the departures a fresh call gives."""
    from cardionurbs.analysis.tagqc import loo_departures
    fans, axis = la_spoke_fans
    for secs, samples in fans:
        shared: dict = {}
        names = list(dict.fromkeys(s.slice for s in secs))
        for exclude in (set(), set(names[:1]), set(names[:2]), set(names[1:2])):
            got = loo_departures(secs, samples, 1.0, True, exclude=exclude, axis=axis,
                                 profiles=shared)
            assert got == loo_departures(secs, samples, 1.0, True, exclude=exclude, axis=axis)


def test_compatible_fit_judges_each_count_and_section_once(monkeypatch):
    """fit_compatible_curves asks the (costly) tolerance test once per (count, section): the
    final all-sections check reuses the search's answers; the fit is unchanged."""
    from cardionurbs import nurbs
    from cardionurbs.nurbs import fitting
    t = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    secs = [np.column_stack([(30 - 2 * s) * np.cos(t), (20 - s) * np.sin(t)
                             + 0.8 * np.sin((5 + s) * t), np.full(t.size, 8.0 * s)])
            for s in range(5)]
    asked = []
    judge = fitting._error_within

    def counted(curve, points, params, tol):
        asked.append((len(curve.control_points), round(float(points[0, 2]), 6)))
        return judge(curve, points, params, tol)

    monkeypatch.setattr(fitting, "_error_within", counted)
    fit = nurbs.fit_compatible_curves(secs, closed=True, tol=0.3)
    assert fit.met and len(asked) == len(set(asked)) > len(secs)
    monkeypatch.setattr(fitting, "_error_within", judge)
    again = nurbs.fit_compatible_curves(secs, closed=True, tol=0.3, counts=[fit.n_ctrl])
    for a, b in zip(fit.curves, again.curves):
        assert np.array_equal(a.control_points, b.control_points)
