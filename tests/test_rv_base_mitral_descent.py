"""The RV's end-systolic valve plane of a label map whose long-axis views give mitral but no
tricuspid landmarks (M&Ms-2) follows the mitral plane's measured descent from ED to ES
(docs/metrics.md, Cavities and walls; issue 29): before, it stayed at the half-slice rule's
ES slab, and RVESV came out ~10 % high on the normal phantom."""

from __future__ import annotations

import pytest

from cardionurbs import load_study
from cardionurbs.phantom.generate import generate
from cardionurbs.phantom.labelmaps import write_labelmaps
from cardionurbs.pipeline import analyse_study


@pytest.fixture(scope="module")
def mnms2(tmp_path_factory):
    """A normal phantom's M&Ms-2 maps (short- and long-axis)."""
    ph = generate("normal", seed=0, frames=2, matrix=128, volume_check=False)
    full = tmp_path_factory.mktemp("mnms2")
    write_labelmaps(ph, full, "mnms2", quirks="real", images=False)
    return ph.truth["metrics"], full


def test_rv_es_plane_follows_the_mitral_descent(mnms2):
    truth, full = mnms2
    study = load_study(full)
    assert study.landmarks_at(study.es_frame, "mitral")
    assert not study.landmarks_at(study.es_frame, "tricuspid")
    model, m = analyse_study(study)
    g = model.geometry[model.es_frame]
    assert "lv" not in g.base_from_slices and "rv" in g.base_from_slices
    # measured on this 2-frame phantom: RVESV +7.9 % before, -5.0 % after (the 20-frame
    # one: +10.0 %, -3.0 %); RVEF -4.6 points before, +0.8 after
    assert abs(m["RVESV (mL)"] / truth["RVESV (mL)"] - 1) < 0.06
    assert abs(m["RVEF (%)"] - truth["RVEF (%)"]) < 3.0
    assert abs(m["RVEDV (mL)"] / truth["RVEDV (mL)"] - 1) < 0.04         # ED: untouched
    assert model.es_frame in model.rv_base_shift_mm
    assert abs(model.rv_base_shift_mm[model.es_frame]) <= max(g.base_slack, 0.5 * g.thickness)
