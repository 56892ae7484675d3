"""The frames' LV cavities on worker processes (``reconstruct(jobs=...)``, issue 16, session
11): the model, its metrics, volume curve and warnings equal the serial loop's bit for bit,
and a frame that fails raises in the parent as it does serially."""

from __future__ import annotations

import math

import pytest
from conftest import shared_data

from cardionurbs.analysis.function import measure, volume_curve
from cardionurbs.anatomy import model as model_module
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.errors import ReconstructionError
from cardionurbs.io import load_study
from cardionurbs.parallel import can_fork

pytestmark = pytest.mark.skipif(not can_fork(), reason="needs fork (Linux, not a daemon)")


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


@pytest.fixture(scope="module")
def bivme_study():
    return load_study(shared_data("bivme-patient1"))


def test_workers_give_the_serial_model(bivme_study, monkeypatch):
    """Six of bivme-patient1's frames (LA contours, an RVOT, warnings): ED and ES, the
    per-frame LV volumes, every metric, the volume curve and the warnings (in order) are
    identical with 1 and 2 processes; the parent holds no frame geometry it did not build."""
    frames = bivme_study.contoured_frames[::4][:6]
    # every frame's geometry and LV endocardial fit warn (what a worker hands back; the
    # parent must not add them again when it builds ED and ES itself)
    real_geometry, real_build = model_module.frame_geometry, model_module.build_surface

    def geometry_that_warns(study, frame):
        geo = real_geometry(study, frame)
        geo.warnings.append(f"frame {frame}: geometry warning")
        return geo

    def build_that_warns(geo, structure, *args, **kwargs):
        fit = real_build(geo, structure, *args, **kwargs)
        fit.warnings.append(f"{structure}: fit warning")
        return fit
    monkeypatch.setattr(model_module, "frame_geometry", geometry_that_warns)
    monkeypatch.setattr(model_module, "build_surface", build_that_warns)
    serial = reconstruct(bivme_study, frames=frames, jobs=1)
    forked = reconstruct(bivme_study, frames=frames, jobs=2)
    assert (serial.ed_frame, serial.es_frame) == (forked.ed_frame, forked.es_frame)
    assert serial.lv_volume_by_frame == forked.lv_volume_by_frame
    # the workers' frames are built again here only when asked (ED and ES, so far)
    assert set(forked.geometry.computed) <= {forked.ed_frame, forked.es_frame}
    ms, mf = measure(serial), measure(forked)
    assert all(_same(ms[k], mf[k]) for k in ms), [k for k in ms if not _same(ms[k], mf[k])]
    assert volume_curve(serial, every_structure=False) == volume_curve(forked, every_structure=False)
    assert serial.warnings == forked.warnings
    assert sum("geometry warning" in w for w in serial.warnings) == len(frames)


def test_a_failing_frame_is_left_out_serial_or_forked(bivme_study, monkeypatch):
    frames = bivme_study.contoured_frames[:4]
    bad = frames[2]
    real = model_module.BiventricularModel.lv_cavity_volume_unrefined

    def fails_on_one(self, frame):
        if frame == bad:
            raise ReconstructionError(f"lv_cavity, frame {frame}: made to fail")
        return real(self, frame)
    monkeypatch.setattr(model_module.BiventricularModel, "lv_cavity_volume_unrefined", fails_on_one)
    for jobs in (1, 2):     # the frame is left out of the model with a warning (issue #30)
        model = reconstruct(bivme_study, frames=frames, jobs=jobs)
        assert model.frames == [f for f in frames if f != bad] and model.curve_frames == frames
        assert any(f"frame {bad}: LV cavity cannot be built" in w and "made to fail" in w
                   for w in model.warnings)

    def fails_always(self, frame):
        raise ReconstructionError(f"lv_cavity, frame {frame}: made to fail")
    monkeypatch.setattr(model_module.BiventricularModel, "lv_cavity_volume_unrefined", fails_always)
    for jobs in (1, 2):     # no frame at all: refused, naming the reason
        with pytest.raises(ReconstructionError, match="made to fail"):
            reconstruct(bivme_study, frames=frames, jobs=jobs)


@pytest.fixture(scope="module")
def tagged_phantom():
    from cardionurbs.phantom import generate
    return generate("normal", seed=4, frames=3, noise_px=0.5).study


def test_tag_metrics_beside_the_volumes_equal_the_serial_ones(tagged_phantom):
    """``analyse(jobs=2)`` measures the tag metrics on a worker while this process measures
    the volumes (pipeline.measure_with_tags), after the frames' LV cavities on workers:
    every metric, the tag and regional results and the warnings equal one process's."""
    import json

    from cardionurbs.pipeline import analyse
    study = tagged_phantom
    assert study.tags
    runs = {}
    for jobs in (1, 2):
        model, metrics, tags = analyse(study, over_time=False, jobs=jobs)
        runs[jobs] = (metrics, list(model.warnings), json.dumps(tags.to_json(), sort_keys=True),
                      json.dumps(model.regional.to_json(), sort_keys=True, default=str))
    (m1, w1, t1, r1), (m2, w2, t2, r2) = runs[1], runs[2]
    assert all(_same(m1[k], m2[k]) for k in m1), [k for k in m1 if not _same(m1[k], m2[k])]
    assert (w1, t1, r1) == (w2, t2, r2)
