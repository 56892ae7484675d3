"""The newcomer's list (issue 10): a two-command quickstart that CI runs word for word,
and a demo that cleans up its temporary folder unless asked to keep it."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import pytest

from cardionurbs.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _quickstart_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, flags=re.S).group(1)
    return [ln for ln in block.splitlines() if ln.strip()]


def _extras(line: str) -> set[str]:
    """The extras of a ``pip install ".[a,b]"`` line (empty if none)."""
    m = re.search(r'"\.\[([^\]]*)\]"', line)
    return {e.strip() for e in m.group(1).split(",")} if m else set()


def test_quickstart_is_two_commands_with_every_extra_and_the_demo():
    first, second = _quickstart_commands()
    assert '".[test,cad]"' in first and first.rstrip().endswith("cardionurbs demo")
    assert second == "python -m pytest -n 2"
    assert "chromium" in (ROOT / "README.md").read_text().lower()


def test_ci_runs_the_readme_test_command_word_for_word():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    _, second = _quickstart_commands()
    assert second in [ln.strip() for ln in ci]
    first, _ = _quickstart_commands()
    wanted = _extras(first)
    assert wanted >= {"test", "cad"}
    assert any(_extras(ln) >= wanted for ln in ci if "pip install" in ln)   # every extra, or more
    assert any("apt-get install" in ln and "chromium" in ln for ln in ci)


@pytest.fixture
def tiny_cohort(monkeypatch, tmp_path):
    """The demo's folder handling with the cohort work replaced by writing one file
    (the cohort itself is tested in tests/test_demo.py)."""
    import cardionurbs.demo as demo

    def fake(args, out, shown, load):
        (out / "cohort.csv").write_text("subject\n")
    monkeypatch.setattr(demo, "_demo", fake)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    return tmp_path


def test_demo_removes_its_temporary_folder(tiny_cohort, capsys):
    assert main(["demo", "--jobs", "1"]) == 0
    assert list(tiny_cohort.iterdir()) == []
    said = capsys.readouterr()
    assert "temporary folder" in said.out + said.err and "removed" in said.out + said.err


def test_demo_keep_keeps_it(tiny_cohort):
    assert main(["demo", "--jobs", "1", "--keep"]) == 0
    kept = list(tiny_cohort.iterdir())
    assert len(kept) == 1 and (kept[0] / "cohort.csv").is_file()
