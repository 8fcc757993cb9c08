"""The ``calib`` command: offline estimation, synthetic benchmarks and tools.

Each sub-command lives in its own module with a ``register(app)`` function; this module assembles
them and maps errors to exit codes: 0 ok, 2 bad input (the reason on one line), 1 internal error.
"""

from __future__ import annotations

import importlib
import sys

import typer

from calib.core.errors import CalibError, InputError

#: Modules that contribute sub-commands, each exposing ``register(app: typer.Typer) -> None``.
COMMAND_MODULES: tuple[str, ...] = (
    "calib.cli.synthetic",
    "calib.cli.data",
    "calib.cli.estimate",
    "calib.cli.compare",
    "calib.cli.spd",
    "calib.cli.plan_lamps",
    "calib.cli.validate",
)

app = typer.Typer(
    name="calib",
    help="Camera spectral sensitivity from an uncalibrated diffraction grating.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def build_app() -> typer.Typer:
    """Register every sub-command module on :data:`app` (idempotent)."""
    if not getattr(app, "_spectral_rig_registered", False):
        for module_name in COMMAND_MODULES:
            importlib.import_module(module_name).register(app)
        app._spectral_rig_registered = True  # type: ignore[attr-defined]
    return app


def main() -> None:
    """Console entry point."""
    if sys.argv[1:2] == ["estimate"]:  # parses its own arguments: skip the other commands' imports
        from calib.cli.estimate import run

        sys.exit(run(sys.argv[2:]))
    try:
        build_app()(standalone_mode=True)
    except InputError as exc:
        print(f"calib: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except CalibError as exc:
        print(f"calib: failed: {exc}", file=sys.stderr)
        sys.exit(1)
