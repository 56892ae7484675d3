"""The analyze speed-ups of issue 16 compute the same numbers as what they replace:
the crossing-number inside test against matplotlib's, the clipped-tessellation volume
against the analytic volume and manifold3d's trimmed solid, the one-query
nearest-neighbour chain against a query per step, and the metrics-only volume curve."""

from __future__ import annotations

import math
from types import SimpleNamespace

import manifold3d
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial import cKDTree

from cardionurbs.analysis.function import volume_curve
from cardionurbs.anatomy.mesh import Plane, clipped_volume, closed_mesh, solid, volume_ml
from cardionurbs.anatomy.sections import _nearest_neighbour_chain
from cardionurbs.geometry import points_in_polygon
from cardionurbs.study import Study


@settings(max_examples=40, deadline=None)
@given(st.integers(3, 40), st.integers(0, 2**31 - 1))
def test_points_in_polygon_matches_matplotlib(n, seed):
    from matplotlib.path import Path
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    poly = np.c_[np.cos(ang), np.sin(ang)] * rng.uniform(5, 30, n)[:, None]
    if seed % 2:
        poly = poly[::-1]                                  # either orientation
    xy = rng.uniform(-35, 35, (300, 2))
    assert np.array_equal(points_in_polygon(xy, poly), Path(poly).contains_points(xy))


def _box(lo, hi):
    m = manifold3d.Manifold.cube(np.subtract(hi, lo)).translate(lo)
    mesh = m.to_mesh64()
    return np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def test_clipped_volume_of_a_box_is_analytic():
    v, f = _box((0, 0, 0), (10, 20, 30))
    assert math.isclose(clipped_volume(v, f, None), 6000.0)
    # the plane z = 12 keeping z >= 12: 10 x 20 x 18
    assert math.isclose(clipped_volume(v, f, Plane([0, 0, 12], [0, 0, 1])), 3600.0)
    # an oblique plane through the centre keeps half of the (centrally symmetric) box
    assert math.isclose(clipped_volume(v, f, Plane([5, 10, 15], [1, 2, 3])), 3000.0)
    assert clipped_volume(v, f, Plane([0, 0, 40], [0, 0, 1])) == 0.0


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.8, 0.8), st.floats(-0.8, 0.8), st.floats(-12, 12))
def test_clipped_volume_equals_manifold_trim(nx, ny, offset):
    """A capped open tube (a ventricle-like surface) clipped by a plane: the same volume as
    manifold3d's trimmed solid."""
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    z = np.linspace(-30, 20, 25)
    r = 25 * np.sqrt(np.clip((z + 31) / 51, 0, 1))
    v = np.c_[np.outer(r, np.cos(t)).ravel(), np.outer(r, np.sin(t)).ravel(), np.repeat(z, 40)]
    i, j = np.meshgrid(np.arange(24), np.arange(40), indexing="ij")
    a, b = i * 40 + j, i * 40 + (j + 1) % 40
    f = np.concatenate([np.c_[a.ravel(), b.ravel(), a.ravel() + 40],
                        np.c_[b.ravel(), b.ravel() + 40, a.ravel() + 40]])
    vc, fc = closed_mesh(v, f)
    plane = Plane([0, 0, offset], [nx, ny, -1.0])
    ref = volume_ml(solid(v, f, plane=plane)) * 1000.0
    assert math.isclose(clipped_volume(vc, fc, plane), ref, rel_tol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 120), st.integers(0, 2**31 - 1))
def test_nearest_neighbour_chain_matches_a_query_per_step(n, seed):
    pts = np.round(np.random.default_rng(seed).normal(size=(n, 2)), 1)   # with ties
    start = seed % n
    tree, visited, order, cur = cKDTree(pts), np.zeros(n, bool), [start], start
    visited[start] = True
    for _ in range(n - 1):
        k = min(n, 8)
        while True:
            idx = np.atleast_1d(tree.query(pts[cur], k=k)[1])
            free = idx[~visited[idx]]
            if free.size or k >= n:
                break
            k = min(n, k * 4)
        cur = int(free[0])
        visited[cur] = True
        order.append(cur)
    assert _nearest_neighbour_chain(pts, start).tolist() == order


def test_metrics_only_volume_curve_reports_what_was_measured():
    vols = {0: {"lv_cavity": 150.0, "rv_cavity": 160.0}, 2: {"lv_cavity": 60.0, "rv_cavity": 90.0}}
    model = SimpleNamespace(
        study=Study(subject="s", frame_times_ms={0: 0.0, 1: 100.0, 2: 200.0}),
        frames=[0, 1, 2], ed_frame=0, es_frame=2, volumes=vols,
        lv_cavity_volume=lambda f: {1: 100.0}[f])
    c = volume_curve(model, every_structure=False)
    assert c["lv_cavity (mL)"] == [150.0, 100.0, 60.0]
    assert c["rv_cavity (mL)"][0] == 160.0 and math.isnan(c["rv_cavity (mL)"][1])


def test_metrics_only_analyze_imports_no_mesh_or_figure_library(tmp_path):
    """A metrics-only `analyze` (what every cohort row costs) imports neither trimesh (and
    through it networkx and scipy.ndimage) nor matplotlib: they are loaded where meshes and
    figures are made; nor pydicom for a study that names no DICOM file."""
    import subprocess
    import sys
    from pathlib import Path

    from cardionurbs.phantom import generate, write_phantom
    root = Path(__file__).resolve().parents[1]
    write_phantom(generate("normal", seed=3, frames=2, volume_check=False), tmp_path / "s", dicom=False)
    code = ("import sys; from cardionurbs.cli import main\n"
            f"rc = main(['analyze', {str(tmp_path / 's')!r}, '--outputs', 'metrics', '--out', "
            f"{str(tmp_path / 'o')!r}])\n"
            "print(rc, sorted(m for m in ('trimesh', 'networkx', 'matplotlib', 'pydicom') "
            "if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                       env={**__import__("os").environ, "PYTHONPATH": str(root)}, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "0 []"
    assert (tmp_path / "o" / "metrics.json").is_file()


def _fresh_python(code: str, env: dict) -> str:
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True,
                       env={**env, "PYTHONPATH": str(root)}, timeout=120)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_cli_runs_blas_on_one_thread_unless_the_user_chose():
    """The CLI limits the BLAS libraries to one thread before numpy loads; a user's own
    setting of any thread variable, or numpy already loaded, leaves everything as it is."""
    import os
    from cardionurbs.cli import BLAS_THREAD_VARIABLES
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    code = ("import os{extra}; from cardionurbs.cli import one_blas_thread, BLAS_THREAD_VARIABLES\n"
            "print(one_blas_thread(), [os.environ.get(v) for v in BLAS_THREAD_VARIABLES])")
    assert _fresh_python(code.format(extra=""), clean) == "True ['1', '1', '1']"
    assert _fresh_python(code.format(extra=""), {**clean, "OMP_NUM_THREADS": "3"}) == \
        "False [None, '3', None]"
    assert _fresh_python(code.format(extra="; import numpy"), clean) == \
        "False [None, None, None]"


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.sampled_from(["sa1", "sa2", "la"])),
                min_size=0, max_size=30), st.integers(0, 5))
def test_tags_at_index_equals_a_scan_and_follows_changes(keys, more):
    """Study.tags_at (an index rebuilt when the list is replaced or grows) gives the lines a
    scan of every line gives, in the same order."""
    from cardionurbs.study import TagLine

    def line(frame, fam, k):
        return TagLine(fam, k, "LA" if fam == "la" else "SA", f"s{k % 3}", frame,
                       np.full((3, 3), float(k)))

    def scan(study, f, fam):
        return [t for t in study.tags if t.frame == f and (fam is None or t.family == fam)]

    s = Study(subject="x", images=[], contours=[], tags=[line(f, fam, k)
                                                         for k, (f, fam) in enumerate(keys)])
    for step in range(3):
        for f in range(4):
            for fam in (None, "sa1", "sa2", "la"):
                assert s.tags_at(f, fam) == scan(s, f, fam)
        if step == 0:            # the list grows in place
            s.tags.extend(line(k % 4, "sa1", 100 + k) for k in range(more))
        else:                    # the list is replaced
            s.tags = [t for t in s.tags if t.family != "sa2"]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 12))
def test_principal_directions_equal_one_line_at_a_time(seed, n):
    """principal_directions (one batch) gives _principal_direction of every line, also for a
    line whose ends coincide (the principal axis instead)."""
    from cardionurbs.analysis.tag_surfaces import _principal_direction, principal_directions
    rng = np.random.default_rng(seed)
    lines = [rng.normal(size=(int(rng.integers(2, 9)), 3)) * 20 for _ in range(n)]
    lines[0][-1] = lines[0][0]                       # a closed line: ends coincide
    got = principal_directions(lines)
    want = np.array([_principal_direction(p) for p in lines])
    assert np.allclose(got, want, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ session 8 (issue 16)
def _grid_faces(nx: int, ny: int) -> np.ndarray:
    """Triangles of an nx x ny vertex grid, consistently oriented."""
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = (i * ny + j).ravel()
    b, c, d = a + ny, a + ny + 1, a + 1
    return np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 9), st.integers(2, 9), st.integers(0, 2**31 - 1))
def test_boundary_edges_are_those_whose_reverse_no_face_has(nx, ny, seed):
    """boundary_loops finds the boundary with one sort: its loops run exactly the directed
    edges whose reverse belongs to no face (checked against a set of every edge)."""
    from cardionurbs.anatomy.mesh import boundary_loops
    from cardionurbs.errors import ReconstructionError
    faces = _grid_faces(nx, ny)
    faces = faces[np.random.default_rng(seed).permutation(len(faces))]
    edges = {(int(f[k]), int(f[(k + 1) % 3])) for f in faces for k in range(3)}
    expect = {e for e in edges if (e[1], e[0]) not in edges}
    loops = boundary_loops(faces)
    got = {(int(lp[k]), int(lp[(k + 1) % len(lp)])) for lp in loops for k in range(len(lp))}
    assert got == expect and sum(len(lp) for lp in loops) == len(expect)
    with pytest.raises(ReconstructionError, match="directed edge used twice"):
        boundary_loops(np.concatenate([faces, faces[:1]]))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 30), min_size=1, max_size=8), st.integers(0, 2**31 - 1))
def test_polyline_lengths_equal_one_line_at_a_time(sizes, seed):
    from cardionurbs.analysis.tag_surfaces import control_count, polyline_lengths
    rng = np.random.default_rng(seed)
    lines = [rng.normal(scale=20.0, size=(n, 3)) for n in sizes]
    one = np.array([np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in lines])
    assert np.allclose(polyline_lengths(lines), one, rtol=1e-12, atol=0)
    assert control_count(lines) == int(np.clip(round(float(np.median(one)) / 12.0) + 3, 4, 8))


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 6), st.floats(0.0, 3.0), st.floats(0.05, 1.0))
def test_compatible_fit_fits_each_section_at_the_chosen_count(k, wobble, tol):
    """fit_compatible_curves fits a section at a count only when the search asks for it;
    the curves it returns are each section's own least-squares fit at the chosen count
    (the same as a fit offered that count alone), not another section's."""
    from cardionurbs import nurbs
    t = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    secs = [np.column_stack([(30 - 2 * s) * np.cos(t), (20 - s) * np.sin(t)
                             + wobble * np.sin((5 + s) * t), np.full(t.size, 8.0 * s)])
            for s in range(k)]
    fit = nurbs.fit_compatible_curves(secs, closed=True, tol=tol)
    alone = nurbs.fit_compatible_curves(secs, closed=True, tol=tol, counts=[fit.n_ctrl])
    for a, b in zip(fit.curves, alone.curves):
        assert np.array_equal(a.knots, b.knots)
        assert np.array_equal(a.control_points, b.control_points)


def test_la_departures_with_shared_spoke_profiles_equal_spoke_by_spoke(la_spoke_fans):
    """loo_departures of the LA spoke fan computes every spoke's profile once, in a batch;
    every departure equals the median of spoke_height_departure taken spoke by spoke
    (so no profile is attached to the wrong spoke), at every frame of a phantom with
    jumped tag lines."""
    from cardionurbs.analysis.tagqc import _neighbours_cyclic, loo_departures, spoke_height_departure
    fans, axis = la_spoke_fans
    checked = 0
    for secs, samples in fans:
        got = loo_departures(secs, samples, 1.0, True, axis=axis)
        for left, value in got.items():
            keep = [k for k, s in enumerate(secs) if s.slice != left]
            keys = np.array([secs[k].key for k in keep])
            dist = []
            for k in (k for k, s in enumerate(secs) if s.slice == left):
                a, b = _neighbours_cyclic(keys, secs[k].key)
                dist.append(spoke_height_departure(secs[k].points[1:], samples[keep[a]],
                                                   samples[keep[b]], axis))
            # the profiles are batched (masked circular means): equal to rounding
            assert value == pytest.approx(float(np.median(np.concatenate(dist))),
                                          rel=1e-9, abs=1e-12)
            checked += 1
    assert checked > 0
