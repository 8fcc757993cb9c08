"""The ``calib`` command: offline estimation, synthetic benchmarks and tools.

Each sub-command lives in its own module of :mod:`calib.cli` with a ``register(app)`` function;
:func:`build_app` assembles them and :func:`main` (the console script) runs them in the one style of
:mod:`calib.cli.command_line` and maps errors to exit codes: 0 ok, 2 bad input (the reason on one
line), 1 the estimation failed or an internal error (``CALIB_DEBUG=1`` shows the traceback). The
command modules import no heavy library at import time (scipy, matplotlib and colour-science load
when a command needs them), so ``calib --help`` and the start of ``calib estimate`` stay fast.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Sequence

import typer

from calib.cli import compare, data, estimate, plan_lamps, spd, synthetic, uses, validate
from calib.cli.command_line import error_code_and_line, new_app, run_app


def build_app() -> typer.Typer:
    """The ``calib`` command with every sub-command registered."""
    app = new_app("calib", "Camera spectral sensitivity from an uncalibrated diffraction grating.")
    for command in (synthetic, data, estimate, compare, spd, plan_lamps, uses, validate):
        command.register(app)
    return app


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point (``argv``: the arguments, default ``sys.argv[1:]``)."""
    try:
        code = run_app(build_app(), "calib", argv)
    except Exception as exc:
        if os.environ.get("CALIB_DEBUG"):
            traceback.print_exc()
        code, line = error_code_and_line(exc)
        print(f"calib: {line}", file=sys.stderr)
    sys.exit(code)
