"""The ``rig`` console command's entry point: a Ctrl-C at any moment ends in one line, not a traceback.

Starting ``rig`` imports its libraries first (typer, rich, numpy …: a few tenths of a second). A
Ctrl-C in that moment is only noted while the import runs — raised there, it could land inside a
C extension's callback (pydantic-core builds its validators in one), where Python prints it as an
"exception ignored" traceback and goes on — and then ends the command with ``rig: interrupted``
and exit code 130 like a Ctrl-C later on (:func:`rig.cli.main`).
"""

from __future__ import annotations

import signal
import sys
from types import FrameType

INTERRUPTED_EXIT_CODE = 130


def main() -> None:
    """Import the command and run it; a Ctrl-C while importing exits quietly with 130."""
    received: list[int] = []

    def note(signum: int, frame: FrameType | None) -> None:
        received.append(signum)

    previous = signal.signal(signal.SIGINT, note)
    try:
        # Imported here, not at the top: the import itself is what a Ctrl-C may interrupt.
        from rig import cli
    except KeyboardInterrupt:  # a Ctrl-C before the handler above was set
        received.append(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, previous)
    if received:
        print("rig: interrupted", file=sys.stderr)
        sys.exit(INTERRUPTED_EXIT_CODE)
    cli.main()
