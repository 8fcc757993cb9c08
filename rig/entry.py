"""The ``rig`` console command's entry point: a Ctrl-C at any moment ends in one line, not a traceback.

Starting ``rig`` imports its libraries first (typer, rich, numpy …: a few tenths of a second). A
Ctrl-C in that moment interrupts an import; it is caught here, around the import, and ends the
command with ``rig: interrupted`` and exit code 130 like a Ctrl-C later on (:func:`rig.cli.main`).
"""

from __future__ import annotations

import sys

INTERRUPTED_EXIT_CODE = 130


def main() -> None:
    """Import the command and run it; a Ctrl-C while importing exits quietly with 130."""
    try:
        # Imported here, not at the top: the import itself is what a Ctrl-C may interrupt.
        from rig import cli
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        sys.exit(INTERRUPTED_EXIT_CODE)
    cli.main()
