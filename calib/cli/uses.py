"""``calib idt``, ``calib ccm``, ``calib raw-to-raw``, ``calib profile``: what the curves are for.

Each takes an estimate's output directory (its camera JSON) or any camera file spectral-rig reads
(:func:`calib.core.formats.read_camera`: AMPAS/rawtoaces JSON, dcamprof SSF JSON, vkdt text, CSV
with named columns, ``result.json``); the work is :mod:`calib.use`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from calib.cli.command_line import help_choices
from calib.core.errors import InputError

CameraArgument = Annotated[
    Path, typer.Argument(help="an estimate's output directory, or a camera file")
]


@help_choices("use_illuminants")
def use_illuminants() -> Sequence[str]:
    """The scene illuminants ``--illuminant`` takes (:data:`calib.core.colour_data.USE_ILLUMINANTS`:
    read when the help is shown, so that building ``calib`` does not import numpy)."""
    from calib.core.colour_data import USE_ILLUMINANTS

    return USE_ILLUMINANTS


IlluminantOption = Annotated[str, typer.Option(help="scene illuminant: {use_illuminants}")]
JsonOption = Annotated[bool, typer.Option("--json", help="print JSON instead of text")]


def _matrix_lines(matrix: Any) -> list[str]:
    return ["  " + "  ".join(f"{value:+.6f}" for value in row) for row in matrix]


def _balanced_matrix(origin: str, heading: str, matrix: Any, white_balance: Any) -> list[str]:
    """The lines of a matrix applied to white-balanced camera RGB, and the white balance."""
    return [
        f"camera: {origin}",
        heading,
        *_matrix_lines(matrix),
        "white balance R, G, B: " + ", ".join(f"{v:.6f}" for v in white_balance),
    ]


def _print(record: dict[str, Any], lines: list[str], as_json: bool) -> None:
    if as_json:
        typer.echo(json.dumps(record, indent=1, ensure_ascii=False))
    else:
        typer.echo("\n".join(lines))


def register(app: typer.Typer) -> None:
    @app.command("idt")
    def idt(
        camera: CameraArgument, illuminant: IlluminantOption = "D65", as_json: JsonOption = False
    ) -> None:
        """The ACES IDT matrix (colour.matrix_idt, rawtoaces' method) under an illuminant."""
        from calib.use import camera_for_uses
        from calib.use.idt import aces_idt

        curves, origin = camera_for_uses(camera)
        result = aces_idt(curves, illuminant)
        heading = f"ACES IDT under {illuminant} (white-balanced camera RGB → ACES2065-1):"
        lines = _balanced_matrix(origin, heading, result.matrix, result.white_balance)
        _print({"camera": origin, **result.to_dict()}, lines, as_json)

    @app.command("ccm")
    def ccm(
        camera: CameraArgument, illuminant: IlluminantOption = "D65", as_json: JsonOption = False
    ) -> None:
        """A colour-correction matrix (camera RGB → XYZ) and the ColorChecker ΔE2000 it predicts."""
        from calib.use import camera_for_uses
        from calib.use.colour_correction import fit_colour_correction

        curves, origin = camera_for_uses(camera)
        result = fit_colour_correction(curves, illuminant)
        heading = (
            f"colour-correction matrix under {illuminant} (white-balanced camera RGB → CIE XYZ):"
        )
        lines = [
            *_balanced_matrix(origin, heading, result.matrix, result.white_balance),
            f"ColorChecker ΔE2000: mean {result.delta_e.mean:.2f}, max {result.delta_e.max:.2f} "
            f"({result.delta_e.worst})",
        ]
        _print({"camera": origin, **result.to_dict()}, lines, as_json)

    @app.command("raw-to-raw")
    def raw_to_raw_command(
        source: Annotated[Path, typer.Argument(help="the camera whose raw RGB is converted")],
        target: Annotated[Path, typer.Argument(help="the camera it is converted to")],
        illuminant: IlluminantOption = "D65",
        as_json: JsonOption = False,
    ) -> None:
        """A 3×3 matrix from one camera's raw RGB to another's (fitted on 190 reflectances)."""
        from calib.use import camera_for_uses
        from calib.use.raw_to_raw import raw_to_raw

        first, first_origin = camera_for_uses(source)
        second, second_origin = camera_for_uses(target)
        result = raw_to_raw(first, second, illuminant)
        lines = [
            f"from: {first_origin}",
            f"to:   {second_origin}",
            f"raw-to-raw matrix under {illuminant} (each camera's white at G = 1):",
            *_matrix_lines(result.matrix),
            f"residual over {result.n_reflectances} reflectances: median "
            f"{100 * result.relative_residual_median:.2f} %, max "
            f"{100 * result.relative_residual_max:.2f} % of the target's RGB",
        ]
        _print(result.to_dict(), lines, as_json)

    @app.command("profile")
    def profile(
        camera: CameraArgument,
        out: Annotated[
            Path | None,
            typer.Option(help="where to write (default: <CAMERA dir>/dcamprof, or ./dcamprof)"),
        ] = None,
        name: Annotated[
            str | None,
            typer.Option(help="the raw converters' make and model (default: the camera file's)"),
        ] = None,
        dcamprof: Annotated[
            Path | None, typer.Option(help="the dcamprof program (default: dcamprof on PATH)")
        ] = None,
    ) -> None:
        """DCP and ICC profiles through dcamprof (installed separately; GPL-3)."""
        from calib.core.formats.dcamprof import write_ssf_json
        from calib.use import camera_for_uses
        from calib.use.dcamprof import find_dcamprof, make_profiles

        if name is None and not (camera.is_dir() or camera.suffix.lower() == ".json"):
            raise InputError(
                "this file does not name the camera: give --name 'MAKE MODEL' as the raw "
                "converters name it",
                source=str(camera),
            )
        program = find_dcamprof(dcamprof)
        if program is None:
            raise InputError(
                "dcamprof is not installed (not on PATH): install it, or give --dcamprof PATH",
                source="dcamprof",
            )
        curves, origin = camera_for_uses(camera)
        destination = out or (camera if camera.is_dir() else Path.cwd()) / "dcamprof"
        destination.mkdir(parents=True, exist_ok=True)
        camera_name = name or curves.name
        ssf = write_ssf_json(destination / "ssf.json", curves, camera_name)
        made = make_profiles(ssf, camera_name, destination, executable=program)
        typer.echo(f"camera: {origin}")
        typer.echo(f"DCP: {made.dcp}")
        typer.echo(f"ICC: {made.icc}")
