"""The ``calib`` command: offline estimation, synthetic benchmarks and tools.

Each sub-command lives in its own module of :mod:`calib.cli` with a ``register(app)`` function;
:func:`build_app` assembles them and :func:`main` (the console script) runs them in the one style of
:mod:`calib.cli.command_line` and maps errors to exit codes: 0 ok, 2 bad input (the reason on one
line), 1 the estimation failed or an internal error (``CALIB_DEBUG=1`` shows the traceback).

A command module may import what its command needs at module level (the pipeline, the methods
registry), so :func:`main` imports only the module of the command named on the command line
(:data:`COMMAND_MODULES`); ``calib``, ``calib -h`` and an unknown command import them all, for the
list. None of them imports scipy, matplotlib or colour-science at import time.
"""

from __future__ import annotations

import importlib
import os
import sys
import traceback
from collections.abc import Iterable, Sequence

import typer

from calib.cli.command_line import error_code_and_line, is_option, new_app, run_app

#: Each sub-command of ``calib`` and the module of :mod:`calib.cli` that registers it.
COMMAND_MODULES: dict[str, str] = {
    "synthetic": "synthetic",
    "data": "data",
    "estimate": "estimate",
    "compare": "compare",
    "spd": "spd",
    "plan-lamps": "plan_lamps",
    "idt": "uses",
    "ccm": "uses",
    "raw-to-raw": "uses",
    "profile": "uses",
    "validate": "validate",
}


def _calib() -> None:
    """Camera spectral sensitivity from an uncalibrated diffraction grating."""


def build_app(commands: Iterable[str] | None = None) -> typer.Typer:
    """The ``calib`` command with ``commands`` registered (default: every sub-command)."""
    app = new_app("calib", "Camera spectral sensitivity from an uncalibrated diffraction grating.")
    # A callback keeps ``calib`` a group when one command is registered (typer would make that
    # command the program itself).
    app.callback()(_calib)
    wanted = COMMAND_MODULES if commands is None else commands
    modules = dict.fromkeys(COMMAND_MODULES[name] for name in wanted)
    for module in modules:
        importlib.import_module(f"calib.cli.{module}").register(app)
    return app


def named_command(argv: Sequence[str]) -> str | None:
    """The sub-command ``argv`` names (its first word that is not an option), if ``calib`` has it."""
    first = next((token for token in argv if not is_option(token)), None)
    return first if first in COMMAND_MODULES else None


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point (``argv``: the arguments, default ``sys.argv[1:]``)."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    command = named_command(arguments)
    try:
        app = build_app(None if command is None else [command])
        code = run_app(app, "calib", arguments)
    except Exception as exc:
        if os.environ.get("CALIB_DEBUG"):
            traceback.print_exc()
        code, line = error_code_and_line(exc)
        print(f"calib: {line}", file=sys.stderr)
    sys.exit(code)
