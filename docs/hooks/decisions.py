"""MkDocs hook: the design decisions (``docs/decisions/NNNN-*.md``) become a section of the site.

The decision files stay where they are; this hook lists every one of them in the navigation under
"Design decisions" and generates that section's index page (number and title of each, taken from
its first heading), so a new decision appears on the site without editing ``mkdocs.yml``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

SECTION = "Design decisions"
INDEX = "decisions/index.md"
_NUMBERED = re.compile(r"^(\d{4})-.+\.md$")


def _decisions(docs_dir: Path) -> list[tuple[str, str, str]]:
    """``(number, title, path relative to docs_dir)`` of every decision file, by number."""
    found = []
    for path in sorted((docs_dir / "decisions").glob("*.md")):
        match = _NUMBERED.match(path.name)
        if match is None:
            continue
        lines = path.read_text(encoding="utf-8").splitlines()
        heading = next((line for line in lines if line.startswith("# ")), None)
        if heading is None:
            raise ValueError(f"{path}: a decision starts with a '# title' line")
        found.append((match.group(1), heading[2:].strip(), f"decisions/{path.name}"))
    return found


def on_config(config: MkDocsConfig, **kwargs: Any) -> MkDocsConfig:
    """Expand the ``Design decisions`` entry of the navigation into the index and every decision."""
    entries = [{"Index": INDEX}] + [
        {f"{number} {title.replace('`', '')}": path}
        for number, title, path in _decisions(Path(config.docs_dir))
    ]
    for item in config.nav or []:
        if isinstance(item, dict) and SECTION in item:
            item[SECTION] = entries
    return config


def on_files(files: Files, config: MkDocsConfig, **kwargs: Any) -> Files:
    """Add the generated index page of the decisions."""
    rows = "\n".join(
        f"| {number} | [{title}]({Path(path).name}) |"
        for number, title, path in _decisions(Path(config.docs_dir))
    )
    content = (
        "# Design decisions\n\n"
        "One short file per deliberate design change: its context, the choice made and its "
        "consequences. The files live in `docs/decisions/` of the repository; the next free "
        "number is given to a change by whoever assigns the work.\n\n"
        f"| number | decision |\n|---|---|\n{rows}\n"
    )
    files.append(File.generated(config, INDEX, content=content))
    return files
