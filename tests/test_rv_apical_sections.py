"""RV sections near the apex: the septal run moved into the LV wall must not leave a loop whose
uniform parameters jump (docs/metrics.md, Cavities and walls; anatomy.surfaces.embed_septa)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs.anatomy.sections import Section
from cardionurbs.anatomy.surfaces import embed_septa, resample_loop
from cardionurbs.geometry import polygon_area


def _crescent(width_deg: float, reach_mm: float, r_lv: float = 20.0, m: int = 120) -> np.ndarray:
    """An RV crescent in the plane z = 0 against an LV epicardial circle of radius r_lv: the free
    wall an arc reach_mm beyond it, the septal run on the circle (mm)."""
    half = np.radians(width_deg) / 2
    t = np.linspace(-half, half, m // 2)
    free = np.stack([(r_lv + reach_mm * np.cos(np.pi * t / (2 * half))) * np.cos(t),
                     (r_lv + reach_mm * np.cos(np.pi * t / (2 * half))) * np.sin(t), 0 * t], 1)
    sept = np.stack([r_lv * np.cos(t[::-1]), r_lv * np.sin(t[::-1]), 0 * t], 1)[1:-1]
    return np.concatenate([free, sept])


@settings(max_examples=15, deadline=None)
@given(st.floats(30.0, 120.0), st.floats(1.5, 12.0))
def test_embedded_loops_stay_uniform_in_arc_length(width_deg, reach_mm):
    n, ref = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    phi = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    lv = np.stack([20.0 * np.cos(phi), 20.0 * np.sin(phi), 0 * phi], 1)
    loop = resample_loop(_crescent(width_deg, reach_mm), n, ref)
    sec = Section("rv_endo", 0, loop.copy(), slice="sa_01", septum_of=lv, source_points=loop.copy())
    before = Section("rv_endo", 0, loop.copy(), slice="sa_01", septum_of=lv, source_points=loop.copy())
    embed_septa([before], [], n, 0.5)
    embed_septa([sec], [], n, 0.5, ref)

    def steps(p):
        return np.linalg.norm(np.diff(np.vstack([p, p[:1]]), axis=0), axis=1)

    assert steps(before.points).max() > 4.0 * steps(before.points).mean()   # the moved run's step
    assert steps(sec.points).max() < 1.05 * steps(sec.points).mean()        # uniform again
    # the same loop: resampled points within 1 mm of the moved polygon (a spline rounds its
    # corners, which lie inside the LV wall), the same area within 2 %
    q = before.points
    e = np.roll(q, -1, axis=0) - q
    rel = sec.points[:, None] - q[None]
    t = np.clip(np.einsum("ijk,jk->ij", rel, e) / np.maximum((e * e).sum(1), 1e-18), 0, 1)
    assert np.linalg.norm(rel - t[..., None] * e[None], axis=2).min(axis=1).max() < 1.0
    assert polygon_area(sec.points, n) == pytest.approx(polygon_area(q, n), rel=0.02)
    # septal points were moved inside the LV circle
    assert (np.linalg.norm(sec.points[:, :2], axis=1) < 19.0).any()


@pytest.fixture(scope="module")
def mr2():
    """Realistic MR seed 2 with outflow tracts: its end-systolic RV ends 1 mm beyond the last SA
    section, a 30 mm² crescent (RVESV was -2.8 %: the loft folded through that section)."""
    from cardionurbs.analysis.function import measure
    from cardionurbs.anatomy.model import reconstruct
    from cardionurbs.phantom.generate import generate
    ph = generate("mr", seed=2, frames=2, anatomy_model="realistic", outflow=True, volume_check=False)
    ph.study.tags = []
    m = reconstruct(ph.study)
    return ph, m, measure(m)


def test_apical_sliver_section_does_not_fold_the_rv(mr2):
    ph, m, got = mr2
    t = ph.truth["metrics"]
    for c in ("RVEDV (mL)", "RVESV (mL)"):
        assert abs(got[c] / t[c] - 1) < 0.02, (c, got[c], t[c])
    es = m.es_frame
    fit = m.fit(es, "rv_endo")
    pts = np.concatenate([s.points for s in fit.sections])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    cp = fit.surface.control_points.reshape(-1, 3)
    # the control net stays near its sections (the fold had a control point 300 mm out)
    assert np.all(cp > lo - 15.0) and np.all(cp < hi + 15.0)
