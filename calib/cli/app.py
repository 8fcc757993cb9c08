"""The ``calib`` command: offline estimation, synthetic benchmarks and tools.

Each sub-command lives in its own module of :mod:`calib.cli` with a ``register(app)`` function;
:func:`build_app` assembles them and :func:`main` (the console script) maps errors to exit codes: 0 ok, 2 bad input (the reason on one
line), 1 internal error. The command modules import no heavy library at import time (scipy,
matplotlib and colour-science load when a command needs them), so ``calib --help`` and the start of
``calib estimate`` stay fast.
"""

from __future__ import annotations

import sys

import typer

from calib.cli import compare, data, estimate, plan_lamps, spd, synthetic, uses, validate
from calib.cli.exits import say_interrupted
from calib.core.errors import CalibError, InputError


def build_app() -> typer.Typer:
    """The ``calib`` command with every sub-command registered."""
    app = typer.Typer(
        name="calib",
        help="Camera spectral sensitivity from an uncalibrated diffraction grating.",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
    )
    for command in (synthetic, data, estimate, compare, spd, plan_lamps, uses, validate):
        command.register(app)
    return app


def main() -> None:
    """Console entry point."""
    try:
        build_app()(standalone_mode=True)
    except SystemExit as exit_:
        say_interrupted(exit_, "calib")
        raise
    except InputError as exc:
        print(f"calib: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except CalibError as exc:
        print(f"calib: failed: {exc}", file=sys.stderr)
        sys.exit(1)
