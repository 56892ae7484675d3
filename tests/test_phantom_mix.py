"""`phantom --cohort SPEC --n N`: N subjects from the spec's mix, deterministic per subject
(the same files whatever N, jobs or executor), written subject by subject; --resume keeps
the finished ones."""

from __future__ import annotations

import filecmp

import pytest

from cardionurbs.cli import main
from cardionurbs.errors import PhantomError
from cardionurbs.phantom.cli import SEED_STEP, mix_subjects
from cardionurbs.phantom.presets import SubjectSpec

SPEC = """[cohort]
frames = 2
[[subject]]
id = "a"
pathology = "normal"
seed = 3
[[subject]]
id = "b"
pathology = "phtn"
seed = 4
tag_jumps = 1
"""


def test_mix_cycles_the_spec_with_its_own_seeds_first():
    spec = [SubjectSpec("a", "normal", 3, frames=2), SubjectSpec("b", "phtn", 4, tag_jumps=1)]
    five = mix_subjects(spec, 5)
    assert [s.id for s in five] == ["a", "b", "a_r1", "b_r1", "a_r2"]
    assert [s.seed for s in five] == [3, 4, 3 + SEED_STEP, 4 + SEED_STEP, 3 + 2 * SEED_STEP]
    assert five[3].pathology == "phtn" and five[3].tag_jumps == 1 and five[2].frames == 2
    assert mix_subjects(spec, 3) == five[:3]          # subject k does not depend on N
    with pytest.raises(PhantomError):
        mix_subjects(spec, 0)


def test_cli_generates_the_mix_in_parallel_identically_and_resumes(tmp_path, capsys):
    (tmp_path / "mix.toml").write_text(SPEC)
    par, seq = tmp_path / "par", tmp_path / "seq"
    common = ["phantom", "--cohort", str(tmp_path / "mix.toml"), "--no-dicom"]
    assert main(common + ["--n", "3", "--jobs", "2", "--out", str(par)]) == 0
    assert main(common + ["--n", "2", "--out", str(seq)]) == 0
    assert sorted(p.name for p in par.iterdir() if not p.name.startswith(".")) == ["a", "a_r1", "b"]
    for sub in ("a", "b"):                             # same subject, other N and jobs: same files
        for name in ("points.csv", "study.json", "truth.json"):
            assert filecmp.cmp(par / sub / name, seq / sub / name, shallow=False), (sub, name)
    before = (par / "a" / "points.csv").stat().st_mtime_ns
    capsys.readouterr()
    assert main(common + ["--n", "4", "--resume", "--out", str(par)]) == 0
    assert (par / "a" / "points.csv").stat().st_mtime_ns == before   # kept, not regenerated
    assert (par / "b_r1" / "study.json").is_file()
    assert "4 of 4 subjects" in capsys.readouterr().err.splitlines()[-1]
    assert main(common + ["--n", "2", "--resume", "--out", str(tmp_path / "x"), "--pathology",
                          "normal"]) == 2
