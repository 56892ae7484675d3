"""Study edits shared by the tests (tests/test_base_between_slices.py,
tests/test_rv_untraced_basal_slice.py)."""

from __future__ import annotations

from cardionurbs.study import Study


def sa_only(study: Study) -> Study:
    """The study without its tags and long-axis views (their contours, landmarks and images),
    edited in place and returned: an SA-only hand-contoured study."""
    study.tags = []
    study.contours = [c for c in study.contours if c.view == "SA"]
    study.landmarks = [lm for lm in study.landmarks if lm.view == "SA"]
    study.images = [im for im in study.images if im.view == "SA"]
    return study
