"""The ``rig`` command: capture sessions on the rig (or its digital twin) and hand them to calib."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="rig",
    help="Capture-rig controller for camera spectral sensitivity measurements.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.command()
def version() -> None:
    """Print the software version."""
    from importlib.metadata import version as dist_version

    typer.echo(dist_version("spectral-rig"))


def main() -> None:
    """Console entry point."""
    app()
