"""An SA stack its long-axis contours contradict is a QC flag on every volume it gives
(issue 34, held-out seed 1056: a label map whose affine put the SA slices twice as far apart
as they were imaged gave LVEDV +171 mL, flagged only by generic fit residuals).

The case built here: an ideal phantom's contours with the SA slices moved apart to twice
their spacing (slice k by k spacings along the stack), the LA views left where they were.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cardionurbs import measure, reconstruct
from cardionurbs.analysis.quality import assess
from cardionurbs.anatomy.model import LA_OVERSHOOT_SLACK_MM, la_overshoot_mm
from cardionurbs.phantom import generate
from cardionurbs.study import Study


@pytest.fixture(scope="module")
def phantom_study():
    return generate("normal", seed=3, frames=2, matrix=128, volume_check=False).study


def _stretched(study: Study) -> Study:
    """The study with its SA slices (base first) moved k x spacing further apical."""
    sa = sorted({im.slice for im in study.images if im.view == "SA"})
    im0 = next(im for im in study.images if im.view == "SA")
    n = np.cross(im0.row_cosine, im0.column_cosine)
    pos = {s: next(im.position for im in study.images if im.slice == s) for s in sa}
    if (pos[sa[-1]] - pos[sa[0]]) @ n < 0:
        n = -n                                            # base -> apex
    step = float(np.median(np.diff([pos[s] @ n for s in sa])))
    shift = {s: k * step * n for k, s in enumerate(sa)}
    images = [dataclasses.replace(im, position=im.position + shift[im.slice])
              if im.slice in shift else im for im in study.images]
    contours = [dataclasses.replace(c, points=c.points + shift[c.slice])
                if c.view == "SA" else c for c in study.contours]
    landmarks = [dataclasses.replace(lm, point=lm.point + shift[lm.slice])
                 if lm.view == "SA" and lm.slice in shift else lm for lm in study.landmarks]
    return dataclasses.replace(study, images=images, contours=contours, landmarks=landmarks,
                               tags=[])


def _flags(study: Study) -> dict:
    model = reconstruct(study)
    return assess(model, measure(model)).metrics


def test_consistent_stack_has_no_stack_flag(phantom_study):
    model = reconstruct(dataclasses.replace(phantom_study, tags=[]))
    for f in (model.ed_frame, model.es_frame):
        over = la_overshoot_mm(model.own_geometry[f])
        assert set(over) == {"lv_endo", "lv_epi"} and max(over.values()) < 0
        assert model.stack_flag(f) is None
    q = assess(model, measure(model)).metrics
    assert not any("contradicts the long-axis" in fl for e in q.values() for fl in e["flags"])


def test_stack_the_long_axis_views_contradict_is_flagged(phantom_study):
    study = _stretched(phantom_study)
    model = reconstruct(study)
    ed = model.ed_frame
    geo = model.own_geometry[ed]
    assert la_overshoot_mm(geo)["lv_endo"] > geo.thickness + LA_OVERSHOOT_SLACK_MM
    q = assess(model, measure(model)).metrics
    for col in ("LVEDV (mL)", "LVESV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVEF (%)"):
        assert any("SA stack contradicts the long-axis views" in fl for fl in q[col]["flags"]), col
    assert any("SA stack contradicts" in fl for fl in q["RV/LV EDV ratio"]["flags"])


def test_stack_without_long_axis_views_is_not_judged(phantom_study):
    study = _stretched(phantom_study)
    sa_only = dataclasses.replace(study, contours=[c for c in study.contours if c.view == "SA"],
                                  landmarks=[lm for lm in study.landmarks if lm.view == "SA"])
    model = reconstruct(sa_only)
    assert la_overshoot_mm(model.own_geometry[model.ed_frame]) == {}
    assert model.stack_flag(model.ed_frame) is None
