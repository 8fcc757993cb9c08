"""How a command line ends on Ctrl-C: one line, not typer's silent exit.

typer (≥ 0.16) turns a ``KeyboardInterrupt`` inside a command into ``typer.Exit(130)`` and exits
without a word, so a Ctrl-C while a command is still importing its modules looked like a silent
failure. :func:`interrupted` recognises that exit so ``calib`` and ``rig`` can say what happened.
"""

from __future__ import annotations

import sys

import typer

#: The exit code of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED_EXIT_CODE = 130


def interrupted(exit_: SystemExit) -> bool:
    """Whether ``exit_`` is typer's exit for a ``KeyboardInterrupt`` raised inside a command."""
    context = exit_.__context__
    return isinstance(context, typer.Exit) and isinstance(context.__cause__, KeyboardInterrupt)


def say_interrupted(exit_: SystemExit, program: str) -> None:
    """Print ``<program>: interrupted`` on stderr when ``exit_`` ends a Ctrl-C (see :func:`interrupted`)."""
    if interrupted(exit_):
        print(f"{program}: interrupted", file=sys.stderr)
