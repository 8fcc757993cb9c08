"""The documentation's examples run: every ``>>>`` example in docs/*.md, as a doctest per page.

Each page runs in its own empty working directory (examples may write files). The pages named in
``PAGES_WITH_EXAMPLES`` must keep examples, so that moving or deleting them fails here rather than
leaving the docs untested.
"""

from __future__ import annotations

import doctest
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parent.parent / "docs"
PAGES_WITH_EXAMPLES = ("python-api.md", "measure-your-camera.md")
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _pages() -> list[Path]:
    return sorted(path for path in DOCS.rglob("*.md") if ">>> " in path.read_text("utf-8"))


def test_the_pages_that_must_have_examples_have_them() -> None:
    found = {path.name for path in _pages()}
    missing = [name for name in PAGES_WITH_EXAMPLES if name not in found]
    assert not missing, f"no >>> examples left in {missing}"


@pytest.mark.parametrize("page", _pages(), ids=lambda path: path.name)
def test_page_examples(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    text = page.read_text("utf-8")
    test = doctest.DocTestParser().get_doctest(text, {}, page.name, str(page), 0)
    assert test.examples, page
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    report: list[str] = []
    runner.run(test, out=report.append)
    failed, attempted = runner.summarize(verbose=False)
    assert failed == 0, f"{page.name}: {failed} of {attempted} examples failed\n" + "".join(report)
