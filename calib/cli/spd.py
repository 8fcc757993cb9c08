"""``calib spd``: the rig as a spectrometer — a lamp's SPD from its diffraction image.

Parses the options into a :class:`calib.spd.pipeline.SpdRequest`, runs
:func:`calib.spd.pipeline.measure_spd` (which writes ``spd.csv``, ``spd.json``, ``spd.png`` and
``geometry.png`` into ``--out``) and prints a summary (``--json``: ``spd.json`` on stdout).

Exit codes: 0 ok, 2 bad input (a file, a field, an image that does not show a spot and a band),
1 the estimation failed; the reason is printed on one line.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import typer
from rich.console import Console
from rich.table import Table

from calib.core.errors import CalibError, InputError
from calib.core.result import json_safe
from calib.core.spectra import WavelengthGrid
from calib.spd.pipeline import SpdMeasurement, SpdRequest, measure_spd

# ------------------------------------------------------------------------------------ command


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are :class:`InputError` (one line, exit code 2 via ``main``)."""

    def error(self, message: str) -> NoReturn:
        raise InputError(message, source="calib spd")


def _grid(text: str) -> WavelengthGrid:
    try:
        return WavelengthGrid.parse(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="calib spd",
        description="Measure a lamp's spectral power distribution with a calibrated camera and "
        "the diffraction grating (Alvarez et al. 2014).",
    )
    parser.add_argument(
        "--images",
        nargs="+",
        type=Path,
        required=True,
        metavar="RAW",
        help="the lamp's bracket (RAW files, any exposures)",
    )
    parser.add_argument(
        "--dark",
        nargs="+",
        type=Path,
        default=[],
        metavar="RAW",
        help="dark frames matching the lamp's exposures",
    )
    parser.add_argument(
        "--camera",
        type=Path,
        required=True,
        metavar="CSV",
        help="the camera's sensitivity: a CSV with columns wavelength_nm,R,G,B by name, a camera JSON, or an estimate's output directory",
    )
    parser.add_argument(
        "--grating-efficiency",
        type=Path,
        metavar="CSV",
        help="the grating's first-order efficiency: wavelength_nm,value (else assumed flat)",
    )
    parser.add_argument(
        "--mapping-lamp-images",
        nargs="+",
        type=Path,
        default=[],
        metavar="RAW",
        help="a fluorescent lamp's bracket in the same set-up, for the mapping",
    )
    parser.add_argument(
        "--mapping-lamp-dark",
        nargs="+",
        type=Path,
        default=[],
        metavar="RAW",
        help="its dark frames",
    )
    parser.add_argument(
        "--mapping-lamp-spectrum",
        type=Path,
        metavar="CSV",
        help="its measured spectrum (else its lines are taken from a reference "
        "list: a few nm less accurate)",
    )
    parser.add_argument(
        "--mapping",
        type=Path,
        metavar="JSON",
        help="a known mapping (a mapping record or a result.json with one)",
    )
    parser.add_argument("--name", default="lamp", help="the lamp's name in the outputs")
    parser.add_argument(
        "--source",
        choices=("auto", "point", "finite"),
        default="auto",
        help="finite: deconvolve the source's shape (auto: when it is wider than 1.5 samples)",
    )
    parser.add_argument(
        "--weighting",
        choices=("noise", "paper"),
        default="noise",
        help="paper: the median-distance weights alone",
    )
    parser.add_argument("--smoothness", type=float, default=50.0, help="w_s of the paper")
    parser.add_argument(
        "--metric",
        choices=("weighted", "l2"),
        default="weighted",
        help="distance for recognising the source",
    )
    parser.add_argument(
        "--grid",
        type=_grid,
        metavar="START:STOP:STEP",
        help="wavelengths of spd.csv in nm (default: 1 nm over the recovered range)",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--no-plots", action="store_true", help="skip spd.png and geometry.png")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("--json", action="store_true", help="print spd.json to stdout")
    return parser


def request_from_args(arguments: Sequence[str]) -> tuple[SpdRequest, argparse.Namespace]:
    options = build_parser().parse_args(list(arguments))
    if options.mapping is not None and options.mapping_lamp_images:
        raise InputError(
            "give either --mapping or --mapping-lamp-images, not both", source="calib spd"
        )
    if options.smoothness < 0:
        raise InputError(f"must be >= 0, got {options.smoothness}", source="--smoothness")
    request = SpdRequest(
        images=tuple(options.images),
        darks=tuple(options.dark),
        camera=options.camera,
        out=options.out,
        grating_efficiency=options.grating_efficiency,
        mapping_images=tuple(options.mapping_lamp_images),
        mapping_darks=tuple(options.mapping_lamp_dark),
        mapping_spectrum=options.mapping_lamp_spectrum,
        mapping_file=options.mapping,
        name=options.name,
        source=options.source,
        weighting=options.weighting,
        smoothness=options.smoothness,
        metric=options.metric,
        grid=options.grid,
        plots=not options.no_plots,
        command_line=("calib", "spd", *arguments),
    )
    return request, options


def _print_summary(measurement: SpdMeasurement, out: Path) -> None:
    summary = measurement.summary
    recognition = measurement.recognition
    table = Table(title=f"SPD of {summary['name']}", show_header=False)
    table.add_row("recovered range", "{:.0f}–{:.0f} nm".format(*measurement.recovery.range_nm))
    names = ", ".join(recognition.names)
    table.add_row(
        "library match",
        f"{names} (distance {recognition.distance:.4f}, margin {recognition.margin:.4f})",
    )
    cct = summary["cct"]["recovered (completed with the match)"]
    table.add_row("CCT", ", ".join(f"{k}: {v:.0f} K" for k, v in cct["cct_k"].items()))
    table.add_row("Duv", f"{cct['duv']:+.4f}")
    gains = summary["white_balance"]["camera_raw_gains"]["recovered"]
    table.add_row("camera WB gains", "R {:.3f}  G {:.3f}  B {:.3f}".format(*gains))
    for note in measurement.recovery.notes:
        table.add_row("note", note)
    table.add_row("outputs", str(out))
    Console(stderr=True).print(table)


def run(arguments: Sequence[str]) -> SpdMeasurement:
    """Parse, measure, report (used by the typer command; raises :class:`CalibError`)."""
    request, options = request_from_args(arguments)

    def progress(message: str) -> None:
        if not options.quiet:
            print(f"calib spd: {message}", file=sys.stderr)

    measurement = measure_spd(request, progress)
    if options.json:
        print(json.dumps(json_safe(measurement.summary), indent=2))
    if not options.quiet:
        _print_summary(measurement, request.out)
    return measurement


def register(app: typer.Typer) -> None:
    @app.command(
        "spd",
        context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
        add_help_option=False,
        help="Measure a lamp's SPD with a calibrated camera (see calib spd --help).",
    )
    def spd(context: typer.Context) -> None:
        """Measure a lamp's spectral power distribution (calib spd --help for the options)."""
        try:
            run(context.args)
        except CalibError:
            raise
        except OSError as exc:
            raise InputError(f"{exc.strerror or exc}", source=str(exc.filename or "")) from None
