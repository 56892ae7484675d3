"""Bad tag input gives one TagError line naming it; a study without tags gives NaN and a note."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cardionurbs.errors import StudyError, TagError
from cardionurbs.study import Study, TagLine
from test_tags_analytic import AnalyticHeart


@pytest.fixture(scope="module")
def study():
    return AnalyticHeart().study()


def _with_tags(study: Study, tags) -> Study:
    return Study(study.subject, images=study.images, contours=study.contours, tags=tags,
                 landmarks=study.landmarks, ed_frame=study.ed_frame, es_frame=study.es_frame)


def _one_line(exc: Exception) -> str:
    msg = str(exc)
    assert "\n" not in msg
    return msg


def test_line_with_fewer_than_two_points(study):
    from cardionurbs.analysis.tags import tag_metrics
    t = study.tags[5]
    bad = TagLine(t.family, t.index, t.view, t.slice, t.frame, t.points[:1], image=t.image)
    with pytest.raises(TagError) as e:
        tag_metrics(_with_tags(study, study.tags[:5] + [bad] + study.tags[6:]), 0, 1)
    msg = _one_line(e.value)
    assert f"{t.family}#{t.index}" in msg and t.slice in msg and "1 point" in msg


def test_index_twice_in_a_slice(study):
    from cardionurbs.analysis.tags import tag_surfaces
    t = study.tags[7]
    with pytest.raises(TagError) as e:
        tag_surfaces(_with_tags(study, study.tags + [t]), t.frame)
    msg = _one_line(e.value)
    assert "twice" in msg and f"{t.family}#{t.index}" in msg and t.slice in msg


def test_unknown_family(study):
    from cardionurbs.analysis.tags import tag_qc
    # the TagLine constructor refuses it ...
    with pytest.raises(StudyError) as e:
        TagLine("sa3", 0, "SA", "sa_00", 0, np.zeros((3, 3)))
    assert "sa3" in _one_line(e.value)
    # ... and a line whose family was changed afterwards is refused by the analysis
    t = TagLine("sa1", 0, "SA", "sa_00", 0, study.tags[0].points)
    t.family = "sa3"
    with pytest.raises(TagError) as e:
        tag_qc(_with_tags(study, study.tags + [t]))
    assert "unknown tag family 'sa3'" in _one_line(e.value)


def test_tags_without_ed_frame(study):
    from cardionurbs.analysis.tags import material_points, tag_metrics
    es_only = [t for t in study.tags if t.frame == 1]
    with pytest.raises(TagError) as e:
        tag_metrics(_with_tags(study, es_only), 0, 1)
    assert "ED frame 0" in _one_line(e.value)
    unlabelled = _with_tags(study, study.tags)
    unlabelled.ed_frame = None
    with pytest.raises(TagError) as e:
        material_points(unlabelled)
    assert "no ED frame" in _one_line(e.value)


def test_family_in_wrong_view(study):
    from cardionurbs.analysis.tags import tag_surfaces
    t = study.tags[0]
    bad = TagLine("la", 99, "SA", t.slice, t.frame, t.points, image=t.image)
    with pytest.raises(TagError) as e:
        tag_surfaces(_with_tags(study, study.tags + [bad]), t.frame)
    assert "la#99" in _one_line(e.value)


def test_study_without_tags_gives_nan_and_one_note(study):
    from cardionurbs.analysis.tags import TAG_COLUMNS, tag_metrics
    res = tag_metrics(_with_tags(study, []), 0, 1)
    assert set(res.columns) == set(TAG_COLUMNS)
    assert all(math.isnan(v) for v in res.columns.values())
    assert len(res.notes) == 1 and "no tag lines" in res.notes[0]
    assert dict(res) == res.columns
