"""cardionurbs.geometry: planes, polygons, stacks and the one long-axis rule."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.errors import ReconstructionError
from cardionurbs.geometry import (centroid_line_axis, chord_length, fit_plane, in_plane_basis,
                                  long_axis, polygon_area, polygon_centroid, slice_spacing,
                                  stack_normal)

ROOT = Path(__file__).resolve().parents[1]


def _rotation(a: float, b: float, c: float) -> np.ndarray:
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rx = np.array([[1, 0, 0], [0, cc, -sc], [0, sc, cc]])
    return rz @ ry @ rx


def _ellipse(n: int, a: float, b: float, centre=(0.0, 0.0)) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([centre[0] + a * np.cos(t), centre[1] + b * np.sin(t)])


def test_square_area_centroid_and_chord():
    sq = np.array([[0, 0], [4, 0], [4, 2], [0, 2.0]])
    assert polygon_area(sq) == pytest.approx(8.0)
    assert polygon_area(sq, signed=True) == pytest.approx(8.0)
    assert polygon_area(sq[::-1], signed=True) == pytest.approx(-8.0)
    assert np.allclose(polygon_centroid(sq), [2, 1])
    assert chord_length(sq, np.array([2.0, 1.0]), np.array([1.0, 0.0])) == pytest.approx(4.0)
    assert polygon_area(sq[:2]) == 0.0


@settings(max_examples=40, deadline=None)
@given(st.floats(0, 6.3), st.floats(0, 6.3), st.floats(0, 6.3),
       st.floats(5, 40), st.floats(5, 40), st.integers(8, 200),
       st.tuples(st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100)))
def test_planar_loop_in_3d_matches_its_2d_polygon(a, b, c, ra, rb, n, shift):
    """A 2-D polygon placed anywhere in space keeps its area and centroid, with or
    without the normal given; the signed area follows the normal's side."""
    xy = _ellipse(n, ra, rb, centre=(3.0, -2.0))
    R = _rotation(a, b, c)
    p3 = np.column_stack([xy, np.zeros(n)]) @ R.T + np.array(shift)
    normal = R[:, 2]
    area2 = polygon_area(xy)
    assert polygon_area(p3) == pytest.approx(area2, rel=1e-9)
    assert polygon_area(p3, normal) == pytest.approx(area2, rel=1e-9)
    assert polygon_area(p3, normal, signed=True) == pytest.approx(area2, rel=1e-9)
    assert polygon_area(p3, -normal, signed=True) == pytest.approx(-area2, rel=1e-9)
    c2 = polygon_centroid(xy)
    expect = np.array([c2[0], c2[1], 0.0]) @ R.T + np.array(shift)
    assert np.allclose(polygon_centroid(p3), expect, atol=1e-8)
    assert np.allclose(polygon_centroid(p3, normal), expect, atol=1e-8)
    assert np.allclose(c2, [3.0, -2.0], atol=1e-9)   # an ellipse's area centroid is its centre


def test_degenerate_polygon_centroid_is_the_mean():
    line = np.array([[0, 0], [1, 1], [2, 2.0]])
    assert np.allclose(polygon_centroid(line), [1, 1])


@settings(max_examples=30, deadline=None)
@given(st.floats(0, 6.3), st.floats(0, 6.3), st.floats(0, 6.3))
def test_fit_plane_and_basis(a, b, c):
    R = _rotation(a, b, c)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.normal(size=(50, 2)) * 10, np.zeros(50)]) @ R.T
    centre, n = fit_plane(pts)
    assert abs(abs(n @ R[:, 2]) - 1) < 1e-9
    B = in_plane_basis(n)
    assert np.allclose(B @ B.T, np.eye(2), atol=1e-12)
    assert np.allclose(B @ n, 0, atol=1e-12)
    assert np.allclose(np.cross(B[0], B[1]), n / np.linalg.norm(n), atol=1e-12)


def test_stack_normal_aligns_signs_and_spacing_is_the_median_gap():
    n = np.array([0.0, 0.0, 1.0])
    normals = np.array([n, -n, n, -n])
    assert np.allclose(stack_normal(normals), n)
    assert np.allclose(stack_normal(-normals), -n)
    assert slice_spacing([0, 10, 20.0, 30, 30.0000001]) == pytest.approx(10.0)
    assert slice_spacing([5.0, 12.0, 19.0, 40.0]) == pytest.approx(7.0)
    assert np.isnan(slice_spacing([3.0]))


def test_long_axis_fallback_order():
    apex_lm, mitral = np.array([[0, 0, -80.0]]), np.array([[10, 0, 0.0], [-10, 0, 0.0]])
    model_apex, valve = np.array([1.0, 1, -70]), np.array([0.0, 0, 5])
    cents = np.array([[0, 0, -10.0 * k] for k in range(6)])
    down = np.array([0.0, 0, -1])
    # 1. landmarks win over everything
    a, b = long_axis(apex_lm, mitral, model_apex=model_apex, valve_origin=valve,
                     sa_centroids=cents, stack_direction=down)
    assert np.allclose(a, [0, 0, -80]) and np.allclose(b, [0, 0, 0])
    # 2. the model's apex and valve plane without landmarks
    a, b = long_axis([], [], model_apex=model_apex, valve_origin=valve, sa_centroids=cents,
                     stack_direction=down)
    assert np.allclose(a, model_apex) and np.allclose(b, valve)
    # 3. the SA centroid line: base at the most basal centre, apex half a gap beyond
    a, b = long_axis(None, None, sa_centroids=cents, stack_direction=down)
    assert np.allclose(a, [0, 0, -55]) and np.allclose(b, [0, 0, 0])
    # each end falls back on its own
    a, b = long_axis(apex_lm, None, sa_centroids=cents, stack_direction=down)
    assert np.allclose(a, [0, 0, -80]) and np.allclose(b, [0, 0, 0])
    with pytest.raises(ReconstructionError, match="frame 3: no LV apex"):
        long_axis(None, mitral, where="frame 3")


def test_centroid_line_axis_is_signed_by_the_stack_direction():
    cents = np.array([[0, 0, 10.0 * k] for k in range(4)])
    a, b = centroid_line_axis(cents, np.array([0, 0, 1.0]))
    assert np.allclose(a, [0, 0, 35]) and np.allclose(b, [0, 0, 0])
    a, b = centroid_line_axis(cents, np.array([0, 0, -1.0]))
    assert np.allclose(a, [0, 0, -5]) and np.allclose(b, [0, 0, 30])


SHARED = ("long_axis", "stack_normal", "slice_spacing", "polygon_area", "polygon_centroid",
          "fit_plane", "in_plane_basis", "chord_length")


def test_each_shared_concept_is_defined_once():
    """grep-able promise of docs/architecture.md: the shared geometry has one home.
    (``BiventricularModel.long_axis`` is the model's accessor: it calls
    :func:`cardionurbs.geometry.long_axis`.)"""
    homes: dict[str, list[str]] = {name: [] for name in SHARED}
    for path in sorted((ROOT / "cardionurbs").rglob("*.py")):
        if "nurbs" in path.relative_to(ROOT / "cardionurbs").parts[:1]:
            continue
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and node.name.lstrip("_") in SHARED:
                homes[node.name.lstrip("_")].append(str(path.relative_to(ROOT)))
    assert homes == {name: ["cardionurbs/geometry.py"] for name in SHARED}
