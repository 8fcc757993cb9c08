"""Reading a JSON camera file: one place for the errors every format reports the same way."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from calib.core.errors import InputError

_COMMENT = re.compile(r'"(?:\\.|[^"\\])*"|//[^\n]*')


def strip_comments(text: str) -> str:
    """``//`` comments (dcamprof's) removed, never inside a string."""
    return _COMMENT.sub(lambda m: m.group(0) if m.group(0).startswith('"') else "", text)


def read_json(path: Path, *, comments: bool = False, error: type[InputError] = InputError) -> Any:
    """The JSON document in ``path`` (``//`` comments allowed with ``comments``).

    Raises
    ------
    InputError
        (or ``error``) naming the file: missing, unreadable, or not JSON.
    """
    try:
        text = path.read_text(encoding="utf-8")
        return json.loads(strip_comments(text) if comments else text)
    except FileNotFoundError:
        raise error("file not found", source=str(path)) from None
    except OSError as exc:
        raise error(f"cannot read: {exc.strerror}", source=str(path)) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"not valid JSON ({exc})", source=str(path)) from None
