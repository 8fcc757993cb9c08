"""The ``rig`` console command's entry point: a Ctrl-C at any moment ends in one line, not a traceback.

Starting ``rig`` imports its libraries first (typer, rich, numpy …: a few tenths of a second). A
Ctrl-C in that moment is only noted while the import runs — raised there, it could land inside a
C extension's callback (pydantic-core builds its validators in one), where Python prints it as an
"exception ignored" traceback and goes on — and then ends the command with ``rig: interrupted``
and exit code 130 like a Ctrl-C later on (:func:`rig.cli.main`).

The noting handler is installed as this module is imported, which is the console script's first
act, through the interpreter's built-in ``_signal`` (the module :mod:`signal` wraps, loaded before
any script runs) rather than :mod:`signal`, whose import builds three enums: half a millisecond of
Python in which a Ctrl-C used to print a traceback. So rig's own code before the handler is a few
bytecodes, and the lines a console script runs between its import and :func:`main` (pip's wrapper
compiles a regular expression there) are covered too. Earlier, the Ctrl-C is CPython's: before
the interpreter sets its own handler the process simply ends by SIGINT (a shell reports 130 for
that too); while it imports ``site`` it reports ``Fatal Python error: init_import_site``; and on
the console script's own import line it prints a ``KeyboardInterrupt`` traceback of the script
and importlib, with no frame of rig. Nothing else imports this module; importing it elsewhere
would leave SIGINT noted, not raised, until :func:`main` runs.
"""

from __future__ import annotations

# Already loaded when the interpreter starts: importing either runs no Python code.
import _signal  # type: ignore[import-not-found]  # no stub; the C half of :mod:`signal`
import sys

INTERRUPTED_EXIT_CODE = 130

_received: list[int] = []


def _note(signum: int, frame: object) -> None:
    _received.append(signum)


_previous_handler = _signal.signal(_signal.SIGINT, _note)


def main() -> None:
    """Import the command and run it; a Ctrl-C before the command handles its own exits quietly
    with 130."""
    try:
        try:
            # Imported here, not at the top: the import itself is what a Ctrl-C may interrupt.
            from rig import cli
        finally:
            _signal.signal(_signal.SIGINT, _previous_handler)
        if not _received:
            cli.main()  # exits itself: with the command's code, or 130 for a Ctrl-C it caught
            return
    except KeyboardInterrupt:
        # In the moment between restoring Python's handler and rig.cli.main's own ``try``, or
        # while it reported an error: interrupted all the same.
        pass
    print("rig: interrupted", file=sys.stderr)
    sys.exit(INTERRUPTED_EXIT_CODE)
