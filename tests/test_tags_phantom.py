"""Tag metrics and tag-jump QC against phantom truth (the issue's acceptance figures).

The full sweeps (20 seeds of tag jumping, several noise seeds) are in
benchmarks/validate_tags.py -> reports/validation-tags.md; here a few cases.
"""

from __future__ import annotations

import numpy as np
import pytest

from cardionurbs.analysis.tagqc import tag_departures, tag_qc
from cardionurbs.analysis.tags import tag_metrics

phantom = pytest.importorskip("cardionurbs.phantom")


def _levels(res, truth):
    return {lv["index"]: lv for lv in res.levels}, {lv["index"]: lv for lv in truth["tags"]["levels"]}


@pytest.fixture(scope="module", params=["normal", "mr", "phtn"])
def clean(request):
    ph = phantom.generate(request.param, seed=0, frames=2, volume_check=False)
    return ph, tag_metrics(ph.study, 0, ph.truth["es_frame"])


def test_noise_free_metrics_match_truth(clean):
    ph, res = clean
    t = ph.truth["metrics"]
    assert res["Twist (deg)"] == pytest.approx(t["Twist (deg)"], abs=0.5)
    assert res["LS (%)"] == pytest.approx(t["LS (%)"], abs=0.5)
    assert res["Torsion (deg/cm)"] == pytest.approx(t["Torsion (deg/cm)"], abs=0.1)
    assert res["CL shear (deg)"] == pytest.approx(t["CL shear (deg)"], rel=0.01)
    assert res["Twist 2D (deg)"] == pytest.approx(t["Twist 2D (deg)"], abs=0.5)
    assert res["Tag QC flags"] == 0


def test_noise_free_levels_match_truth(clean):
    ph, res = clean
    ours, truth = _levels(res, ph.truth)
    assert set(ours) == set(truth)
    for k, lv in truth.items():
        assert ours[k]["rotation_deg"] == pytest.approx(lv["rotation_deg"], abs=0.5)
        assert ours[k]["distance_from_apex_mm"] == pytest.approx(lv["distance_from_apex_mm"], abs=0.5)
        assert ours[k]["in_twist"] == lv["in_twist"]


@pytest.mark.parametrize("pathology, seed", [("phtn", 1)])
def test_half_pixel_noise_within_one_degree_and_point(pathology, seed):
    ph = phantom.generate(pathology, seed=seed, frames=2, noise_px=0.5, volume_check=False)
    res = tag_metrics(ph.study, 0, ph.truth["es_frame"], qc=False)
    t = ph.truth["metrics"]
    assert res["Twist (deg)"] == pytest.approx(t["Twist (deg)"], abs=1.0)
    assert res["LS (%)"] == pytest.approx(t["LS (%)"], abs=1.0)


@pytest.mark.parametrize("pathology, seed", [("normal", 3), ("mr", 4)])
def test_every_tag_jump_is_flagged_and_nothing_else(pathology, seed):
    ph = phantom.generate(pathology, seed=seed, frames=4, tag_jumps=3, volume_check=False)
    found = tag_qc(ph.study)
    flags = {(f.family, f.index, f.slice, f.frame) for f in found}
    jumps = {(j["family"], j["index"], j["slice"], j["frame"]) for j in ph.truth["faults"]["tag_jumps"]}
    assert len(jumps) == 3
    assert flags == jumps
    for f in found:
        assert 0.7 < f.departure < 1.5     # one tag spacing


def test_clean_phantom_has_no_flags_and_small_departures():
    ph = phantom.generate("phtn", seed=5, frames=4, volume_check=False)
    deps = tag_departures(ph.study)
    assert len(deps) > 500
    assert not [d for d in deps if d.flagged]
    assert max(d.departure for d in deps) < 0.45


def test_flagged_lines_are_left_out_of_the_metrics():
    """Jumps at ES corrupt the ES tag surfaces unless the flagged lines are left out."""
    ph = phantom.generate("normal", seed=7, frames=2, tag_jumps=3, volume_check=False)
    t = ph.truth["metrics"]
    res = tag_metrics(ph.study, 0, ph.truth["es_frame"])
    assert res["Tag QC flags"] == 3 == t["Tag QC flags"]
    assert res["Twist (deg)"] == pytest.approx(t["Twist (deg)"], abs=0.5)
    assert res["LS (%)"] == pytest.approx(t["LS (%)"], abs=0.5)
    assert any("left out" in n for n in res.notes)
