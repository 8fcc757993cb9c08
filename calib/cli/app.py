"""The ``calib`` command: offline estimation, synthetic benchmarks and tools.

Each sub-command lives in its own module of :mod:`calib.cli` with a ``register(app)`` function;
:func:`build_app` assembles them and :func:`main` (the console script) runs them in the one style of
:mod:`calib.cli.command_line` and maps errors to exit codes: 0 ok, 2 bad input (the reason on one
line), 1 the estimation failed or an internal error (``CALIB_DEBUG=1`` shows the traceback).

The command modules are imported for real (the import graph is what tools and
``tests/test_layering.py`` see); none of them imports scipy, matplotlib or colour-science at import
time, each of those loads at its one seam when a command needs it.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Sequence

import typer

from calib.cli import batch, compare, data, estimate, plan_lamps, spd, synthetic, uses, validate
from calib.cli.command_line import error_code_and_line, new_app, run_app


def _calib() -> None:
    """Camera spectral sensitivity from an uncalibrated diffraction grating."""


def build_app() -> typer.Typer:
    """The ``calib`` command with every sub-command registered."""
    app = new_app("calib", "Camera spectral sensitivity from an uncalibrated diffraction grating.")
    app.callback()(_calib)
    for command in (synthetic, data, estimate, batch, compare, spd, plan_lamps, uses, validate):
        command.register(app)
    return app


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point (``argv``: the arguments, default ``sys.argv[1:]``)."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    try:
        code = run_app(build_app(), "calib", arguments)
    except Exception as exc:
        if os.environ.get("CALIB_DEBUG"):
            traceback.print_exc()
        code, line = error_code_and_line(exc)
        print(f"calib: {line}", file=sys.stderr)
    sys.exit(code)
