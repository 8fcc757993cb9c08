"""The ``rig`` console command's entry point: a Ctrl-C at any moment ends in one line, not a traceback.

Starting ``rig`` imports its libraries first (typer, rich, numpy …: a few tenths of a second). A
Ctrl-C in that moment interrupts an import; it is caught here, around the import, and ends the
command with ``rig: interrupted`` and exit code 130 like a Ctrl-C later on (:func:`rig.cli.main`).

A library may catch the ``KeyboardInterrupt`` and raise its own error instead (pydantic-core turns
one raised while it builds a validator into a ``SchemaError``); the Ctrl-C is therefore also noted
when it arrives (:func:`interrupt_seen`), so the command still ends as interrupted, not as an
internal error.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType

INTERRUPTED_EXIT_CODE = 130

_seen: list[int] = []


def interrupt_seen() -> bool:
    """Whether a Ctrl-C reached this process through the handler :func:`main` installs."""
    return bool(_seen)


def _note_and_interrupt(signum: int, frame: FrameType | None) -> None:
    _seen.append(signum)
    signal.default_int_handler(signum, frame)


def main() -> None:
    """Import the command and run it; a Ctrl-C while importing exits quietly with 130."""
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _note_and_interrupt)
    try:
        # Imported here, not at the top: the import itself is what a Ctrl-C may interrupt.
        from rig import cli
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        sys.exit(INTERRUPTED_EXIT_CODE)
    cli.main()
