"""The documentation's examples run: every ``>>>`` example in docs/*.md, as a doctest per page;
and every Markdown table in the README and docs/ keeps its columns.

Each page runs in its own empty working directory (examples may write files). The pages named in
``PAGES_WITH_EXAMPLES`` must keep examples, so that moving or deleting them fails here rather than
leaving the docs untested.
"""

from __future__ import annotations

import doctest
import re
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


#: A cell boundary: a ``|`` not escaped as ``\\|`` (GitHub's tables split on it even inside code).
_CELL_BOUNDARY = re.compile(r"(?<!\\)\|")


def _tables(text: str) -> list[tuple[int, list[str]]]:
    """Each table outside code blocks: its first line's number and its lines."""
    tables: list[tuple[int, list[str]]] = []
    fenced = False
    current: list[str] = []
    start = 0
    for number, line in enumerate([*text.splitlines(), ""], start=1):
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("|"):
            if not current:
                start = number
            current.append(line.rstrip())
            continue
        if len(current) >= 2:
            tables.append((start, current))
        current = []
    return tables


def test_every_markdown_table_row_has_its_headings_cells() -> None:
    """A cell's own ``|`` (``|Δλ|``) must be escaped, or every column after it moves."""
    pages = [DOCS.parent / "README.md", *sorted(DOCS.rglob("*.md"))]
    uneven = [
        f"{page.relative_to(DOCS.parent)}:{start}"
        for page in pages
        for start, lines in _tables(page.read_text("utf-8"))
        if len({len(_CELL_BOUNDARY.split(line)) for line in lines}) > 1
    ]
    assert not uneven, uneven
    assert _tables("| a | b |\n|---|---|\n| x \\|y\\| | 2 |\n")  # the reader finds a table
