"""The documentation's examples run as written (issue 33): every code block of the
tutorials (docs/tutorials/*.md) and the README's API example.

A page's blocks run in order, in one namespace, from an empty folder beside a link to
``../shared`` (so ``../shared/data/...`` means what it says in a checkout):

* ```` ```bash ```` blocks: each line is a ``cardionurbs ...`` command, run through
  :func:`cardionurbs.cli.main` (exit status 0 expected); any other shell line fails the
  test (it would not be checked);
* ```` ```python ```` blocks: executed;
* other blocks (```` ```text ````, output, cluster-only commands) are shown, not run; a
  python or bash block preceded by ``<!-- skip: reason -->`` is not run either.

A page that names ``../shared/data`` is skipped, with the reason, when that folder is
absent.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from cardionurbs.cli import main

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
TUTORIALS = sorted((ROOT / "docs" / "tutorials").glob("*.md"))
BLOCK = re.compile(r"(?:<!--\s*skip:\s*(?P<skip>[^>]*?)\s*-->\s*\n)?```(?P<lang>[\w-]*)[^\n]*\n"
                   r"(?P<code>.*?)^```", re.S | re.M)


def code_blocks(text: str) -> list[tuple[str, str, str | None]]:
    """(language, code, skip reason or None) of every fenced block of a Markdown page."""
    return [(m["lang"], m["code"], m["skip"]) for m in BLOCK.finditer(text)]


def run_blocks(text: str, where: Path, monkeypatch) -> int:
    """Run the bash and python blocks of ``text`` in ``where``; returns how many ran."""
    if "../shared/data" in text and not (SHARED / "data").is_dir():
        pytest.skip("../shared/data is absent (the page analyses the shared real data)")
    work = where / "work"
    work.mkdir(parents=True)
    if SHARED.exists():
        (where / "shared").symlink_to(SHARED.resolve(), target_is_directory=True)
    monkeypatch.chdir(work)
    namespace: dict = {"__name__": "__tutorial__"}
    ran = 0
    for lang, code, skip in code_blocks(text):
        if skip is not None:
            assert skip.strip(), "a skipped block must say why"
            continue
        if lang == "bash":
            for line in code.splitlines():
                if not line.strip() or line.lstrip().startswith("#"):
                    continue
                words = shlex.split(line, comments=True)
                assert words[0] == "cardionurbs", f"not a cardionurbs command: {line}"
                assert main(words[1:]) == 0, line
            ran += 1
        elif lang == "python":
            exec(compile(code, f"<{lang} block {ran}>", "exec"), namespace)
            ran += 1
    return ran


@pytest.mark.parametrize("page", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_every_tutorial_block_runs(page, tmp_path, monkeypatch):
    assert run_blocks(page.read_text(), tmp_path, monkeypatch) >= 2


def test_the_tutorials_are_in_the_site_nav():
    nav = (ROOT / "mkdocs.yml").read_text()
    assert len(TUTORIALS) >= 7
    for page in TUTORIALS:
        assert f"tutorials/{page.name}" in nav, page.name


def readme_api_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)


def test_readme_api_example_runs_as_written(tmp_path, monkeypatch):
    code = readme_api_example()
    assert len(code.strip().splitlines()) <= 10
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "<README API example>", "exec"), {"__name__": "__readme__"})
    assert (tmp_path / "model.json").is_file()


def test_the_block_rules(tmp_path, monkeypatch):
    page = ("```bash\ncardionurbs phantom --pathology normal --frames 2 --no-dicom --out p\n```\n"
            "<!-- skip: needs a cluster -->\n```python\nraise SystemExit('not run')\n```\n"
            "```text\nnot run either\n```\n"
            "```python\nimport json\nassert json.load(open('p/truth.json'))['subject']\n```\n")
    assert [b[0] for b in code_blocks(page)] == ["bash", "python", "text", "python"]
    assert run_blocks(page, tmp_path, monkeypatch) == 2
    with pytest.raises(AssertionError, match="not a cardionurbs command"):
        run_blocks("```bash\nrm -rf p\n```\n", tmp_path / "x", monkeypatch)
