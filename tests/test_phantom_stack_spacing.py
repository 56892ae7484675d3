"""The phantom's SA stack is evenly spaced, outflow slices included, so its NIfTI label maps
place every slice where the phantom imaged it (issue 34, held-out seed 1056).

Before: above the stack's top slice (held 2 mm below a saddle annulus' lowest point, or the
first offset below the base) the outflow slices started only above ``z_base + 1``, so when
the first slot above the top fell below that (a first offset near one spacing; every
realistic 5 mm stack) it was left out; the label map's one affine, taken from the first two
planes, then put every SA slice of a base-first (ukbb) map 10 mm x k off: seed 1056's
LVEDV +171 mL, voxel count and model alike.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from cardionurbs.errors import PhantomError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.phantom.geometry import Acquisition, slice_specs
from cardionurbs.phantom.labelmaps import plane_affine_ras

_generate = importlib.import_module("cardionurbs.phantom.generate")


@pytest.fixture(scope="module")
def realistic_anatomy():
    """Seed 1056's realistic MR anatomy with its outflow tracts (the solved ED geometry only:
    no images, no truth)."""
    draw = _generate.sample_subject(_generate.load_preset("mr"), _generate._rng(1056, "mr", "subject"))
    anatomy = _generate._subject_anatomy(draw, 1056, "mr", "realistic", None, True, None)
    assert anatomy.outflow is not None
    return anatomy


@pytest.mark.parametrize("spacing,offset", [(10.0, 9.26), (10.0, None), (5.0, None), (5.0, 4.8),
                                            (8.0, 0.5)])
def test_sa_stack_with_outflow_slices_is_evenly_spaced(realistic_anatomy, spacing, offset):
    acq = Acquisition(sa_spacing_mm=spacing, sa_first_offset_mm=offset)
    h = np.array([s.height for s in slice_specs(realistic_anatomy, acq) if s.view == "SA"])
    assert h[0] > realistic_anatomy.z_base          # outflow slices above the base
    assert np.allclose(np.diff(h), -spacing, atol=1e-9)


def _plane(k: str, z: float) -> ImagePlane:
    return ImagePlane(id=k, slice=k, frame=0, view="SA", position=np.array([0.0, 0.0, z]),
                      row_cosine=np.array([1.0, 0.0, 0.0]), column_cosine=np.array([0.0, 1.0, 0.0]),
                      pixel_spacing=(1.2, 1.2), rows=64, columns=64, thickness=8.0)


def test_label_map_affine_refuses_an_uneven_stack():
    even = [_plane(f"sa_{k:02d}", -10.0 * k) for k in range(4)]
    assert np.allclose(plane_affine_ras(even)[:3, 2], [0.0, 0.0, -10.0])
    uneven = [_plane("sa_00", 10.0)] + even[1:]       # one slot left out after the first
    with pytest.raises(PhantomError, match="not evenly spaced"):
        plane_affine_ras(uneven)
