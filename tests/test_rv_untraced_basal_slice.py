"""SA-only hand contours whose most basal LV slice carries no RV contour (the slice cuts the
tricuspid annulus): the RV is closed half-way beyond that slice, as the LV is, not in the
gap before it (issue 34: realistic MR phantoms, SA-only contours, RVEDV 30-38 mL low and
RVEF 10-13 points low; reports/rv-sa-only.md)."""

from __future__ import annotations

import pytest

import cardionurbs.anatomy.model as model_mod
from cardionurbs import measure, reconstruct
from cardionurbs.phantom import generate
from cardionurbs.study import Study
from studies import sa_only as drop_long_axis


def _without_rv_on_top_slice(study: Study, frames: tuple[int, ...]) -> Study:
    """The study with the RV contours (and RV insertion points) of each frame's most basal
    RV slice left out, the LV ones kept: as a tracer leaves out an RV whose annulus the
    slice cuts."""
    drop = {(f, min(c.slice for c in study.contours if c.frame == f and c.structure == "rv_endo"))
            for f in frames}
    return Study(subject=study.subject, images=list(study.images),
                 contours=[c for c in study.contours
                           if not ((c.frame, c.slice) in drop and c.structure.startswith("rv"))],
                 landmarks=[lm for lm in study.landmarks if (lm.frame, lm.slice) not in drop],
                 ed_frame=study.ed_frame, es_frame=study.es_frame)


@pytest.fixture(scope="module")
def sa_only():
    ph = generate("mr", seed=5, frames=2, matrix=128, volume_check=False)
    study = drop_long_axis(ph.study)
    return ph, study, measure(reconstruct(study))


def test_rv_closed_beyond_the_untraced_slice_at_ed(sa_only):
    ph, study, full = sa_only
    cut = _without_rv_on_top_slice(study, (0,))
    model = reconstruct(cut)
    geo = model.own_geometry[0]
    n = geo.direction
    lv_top = float(geo.sections["lv_endo"][0].points.mean(axis=0) @ n)
    assert model_mod.rv_untraced_basal_level(cut, geo) == pytest.approx(lv_top, abs=0.05)
    # the RV's valve plane is the LV's: half-way beyond the slice both reach into
    rv, lv = geo.base_planes["rv"], geo.base_planes["lv"]
    assert float(rv.origin @ n) == pytest.approx(float(lv.origin @ n), abs=0.05)
    m = measure(model)
    # the RV traced on that slice (the full study) and left out give the same RV:
    # before, 129.8 mL against 169.6 (truth 179.1), RVEF 25.3 % against 42.8
    assert m["RVEDV (mL)"] == pytest.approx(full["RVEDV (mL)"], abs=3.0)
    assert m["RVEF (%)"] == pytest.approx(full["RVEF (%)"], abs=1.5)
    assert abs(m["RVEF (%)"] - ph.truth["metrics"]["RVEF (%)"]) < 2.0
    assert m["LVEDV (mL)"] == pytest.approx(full["LVEDV (mL)"], abs=1e-6)   # the LV untouched


def test_es_rv_plane_moves_with_the_lv_when_they_are_one(sa_only):
    """At ES too: the RV's plane, put at the LV's, moves with it where the myocardium
    places the ES base."""
    ph, study, full = sa_only
    es = study.es_frame
    cut = _without_rv_on_top_slice(study, (es,))
    model = reconstruct(cut)
    g = model.geometry[es]
    n = g.direction
    assert model_mod.rv_untraced_basal_level(cut, g) is not None
    assert float(g.base_planes["rv"].origin @ n) == pytest.approx(
        float(g.base_planes["lv"].origin @ n), abs=0.05)
    m = measure(model)
    assert m["RVESV (mL)"] == pytest.approx(full["RVESV (mL)"], abs=3.0)
    assert m["RVEF (%)"] == pytest.approx(full["RVEF (%)"], abs=2.0)


def test_rule_inert_where_the_rv_is_traced_or_the_slice_is_empty(sa_only):
    """The full study (the RV traced on every slice the LV is) is unchanged; so is an RV
    whose next basal plane carries no LV section either."""
    _, study, _ = sa_only
    geo = reconstruct(study).own_geometry[0]
    assert model_mod.rv_untraced_basal_level(study, geo) is None
    top = min(c.slice for c in study.contours if c.frame == 0)
    bare = Study(subject=study.subject, images=list(study.images),
                 contours=[c for c in study.contours if not (c.frame == 0 and c.slice == top)],
                 landmarks=[lm for lm in study.landmarks if not (lm.frame == 0 and lm.slice == top)],
                 ed_frame=study.ed_frame, es_frame=study.es_frame)
    g = reconstruct(bare).own_geometry[0]
    assert model_mod.rv_untraced_basal_level(bare, g) is None
