"""The ES valve plane of an SA-only label map moves to conserve the myocardium only where a
plane within its slab can (issue 29, ACDC patient025): where the labels' ES walls hold more
myocardium than any basal plane position offsets, the plane stays at the labels' slab."""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cardionurbs import load_study
from cardionurbs.anatomy.model import (MYO_PLANE_MISS_BOUND, conservation_miss,
                                       plane_cannot_conserve, reconstruct)
from test_labelmap_geometry import DZ, PX, _heart, _slice


@settings(max_examples=60, deadline=None)
@given(lo=st.floats(10, 200), span=st.floats(0, 50), t=st.floats(1, 400))
def test_the_miss_is_zero_inside_the_range_and_signed_outside(lo, span, t):
    vols = np.linspace(lo, lo + span, 9)
    miss = conservation_miss(t, vols)
    if lo <= t <= lo + span:
        assert miss == 0.0
    elif t < lo:                      # the ES wall exceeds ED's at every plane position
        assert miss == pytest.approx(lo / t - 1) and miss > 0
    else:
        assert miss == pytest.approx((lo + span) / t - 1) and miss < 0


def test_the_warning_names_frame_miss_and_bound():
    w = plane_cannot_conserve(0.12, 8)
    assert w.startswith("frame 8:") and "+12 %" in w and f"±{100 * MYO_PLANE_MISS_BOUND:.0f} %" in w


@pytest.fixture(scope="module")
def thick_es_walls(tmp_path_factory):
    """ED and ES of one heart (base first, ACDC header), the ES walls labelled thick (+7 %
    myocardium, within what partial volume explains) but the basal ES ring thin (3 mm), as on
    patient025: half the basal slab cannot offset the excess."""
    ed = _heart(n=8, scale=1.0, wall=7.0)
    es = _heart(n=8, scale=0.75, wall=10.2)
    es[..., 0] = _slice(0.75 * 26.0 * np.sqrt(1 - (0.5 / 8.3) ** 2), 3.0, rv=True)
    path = tmp_path_factory.mktemp("esplane") / "seg.nii.gz"
    aff = np.diag([PX, PX, DZ, 1.0])
    img = nib.Nifti1Image(np.stack([ed, es], axis=3), aff)
    img.set_sform(aff, code=2)
    img.header.set_xyzt_units("mm", "msec")
    img.header["pixdim"][4] = 400.0
    nib.save(img, str(path))
    return path, ed, es


def test_an_unreachable_conservation_keeps_the_labels_slab(thick_es_walls):
    """The labels' myocardial ratio is inside MYO_CONSERVED_BOUND, so the plane would have
    been moved to the apical end of its range (LVESV 8.7 % below the voxel count before this
    rule); now it stays at the labels' slab with one warning, LVESV within 2 % of the voxel
    count."""
    path, ed, es = thick_es_walls
    ratio = (es == 2).sum() / (ed == 2).sum()
    assert 1.03 < ratio < 1.12
    study = load_study(path)
    model = reconstruct(study)
    es_f = model.es_frame
    assert model.base_shift_mm[es_f] == 0.0
    assert sum("no ES valve plane within the basal slab" in w for w in model.warnings) == 1
    vox = study.meta["voxel_volumes_ml"][es_f]["lv_cavity"]
    assert model.volumes[es_f]["lv_cavity"] == pytest.approx(vox, rel=0.02)
