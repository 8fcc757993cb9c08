"""``calib spd``: the rig as a spectrometer — a lamp's SPD from its diffraction image.

Parses the options into a :class:`calib.spd.pipeline.SpdRequest`, runs
:func:`calib.spd.pipeline.measure_spd` (which writes ``spd.csv``, ``spd.json``, ``spd.png`` and
``geometry.png`` into ``--out``) and prints a summary (``--json``: ``spd.json`` on stdout).

Exit codes: 0 ok, 2 bad input (a file, a field, an image that does not show a spot and a band),
1 the estimation failed; the reason is printed on one line.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer
from rich.console import Console
from rich.table import Table

from calib.cli.command_line import ARGUMENTS, list_options_command
from calib.cli.options import ForceOption, JsonOption, QuietOption, checked_grid
from calib.core.errors import InputError

if TYPE_CHECKING:
    from calib.spd.pipeline import SpdMeasurement

# The measurement (calib.spd, the image stages) is imported by the command when it runs: building
# ``calib`` imports this module. The choices its options take are kept here as the types typer
# reads, checked against calib.spd's own by tests/test_cli_startup.py.

#: ``calib.spd.alvarez2014.SourceMode``.
SourceMode = Literal["point", "finite", "auto"]
#: ``calib.spd.alvarez2014.Weighting``.
Weighting = Literal["noise", "paper"]
#: ``calib.spd.light_sources.Metric``.
Metric = Literal["l2", "weighted"]

#: The files of an earlier measurement that ``--force`` allows to overwrite.
SPD_MARKERS = ("spd.json", "spd.csv")
#: The options that take a list of files.
LIST_OPTIONS = ("--images", "--dark", "--mapping-lamp-images", "--mapping-lamp-dark")


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


def register(app: typer.Typer) -> None:
    @app.command("spd", cls=list_options_command(*LIST_OPTIONS))
    def spd(
        ctx: typer.Context,
        images: Annotated[
            list[Path],
            typer.Option(metavar="RAW ...", help="The lamp's bracket (RAW files, any exposures)."),
        ],
        camera: Annotated[
            Path,
            typer.Option(
                metavar="FILE",
                help="The camera's sensitivity: a CSV with columns wavelength_nm,R,G,B by name, a "
                "camera JSON, or an estimate's output directory.",
            ),
        ],
        out: Annotated[
            Path,
            typer.Option(
                "--out", "-o", metavar="DIR", help="Where to write spd.csv, spd.json and the plots."
            ),
        ],
        dark: Annotated[
            list[Path] | None,
            typer.Option(metavar="RAW ...", help="Dark frames matching the lamp's exposures."),
        ] = None,
        grating_efficiency: Annotated[
            Path | None,
            typer.Option(
                metavar="CSV|JSON",
                help="The grating's first-order efficiency: a CSV wavelength_nm,value, or the "
                "grating.json an estimate or rig grating wrote (else assumed flat).",
            ),
        ] = None,
        mapping_lamp_images: Annotated[
            list[Path] | None,
            typer.Option(
                metavar="RAW ...",
                help="A fluorescent lamp's bracket in the same set-up, for the mapping.",
            ),
        ] = None,
        mapping_lamp_dark: Annotated[
            list[Path] | None, typer.Option(metavar="RAW ...", help="Its dark frames.")
        ] = None,
        mapping_lamp_spectrum: Annotated[
            Path | None,
            typer.Option(
                metavar="CSV|NAME",
                help="Its spectrum: a measured CSV, or a name (a colour-science light source such "
                "as FL11, builtin:NAME for a line list such as builtin:cfl-triphosphor). Without "
                "it the lines come from a reference list, a few nm less accurate.",
            ),
        ] = None,
        mapping: Annotated[
            Path | None,
            typer.Option(
                metavar="JSON", help="A known mapping (a mapping record or a result.json with one)."
            ),
        ] = None,
        name: Annotated[
            str, typer.Option(metavar="NAME", help="The lamp's name in the outputs.")
        ] = "lamp",
        source: Annotated[
            SourceMode,
            typer.Option(
                metavar="MODE",
                help="auto, point or finite: finite deconvolves the source's shape (auto: when it "
                "is wider than 1.5 samples).",
            ),
        ] = "auto",
        weighting: Annotated[
            Weighting,
            typer.Option(
                metavar="WEIGHTS", help="noise or paper (the median-distance weights alone)."
            ),
        ] = "noise",
        smoothness: Annotated[
            float,
            typer.Option(min=0.0, metavar="W", help="w_s of the paper (smoothness weight, ≥ 0)."),
        ] = 50.0,
        metric: Annotated[
            Metric,
            typer.Option(
                metavar="DISTANCE", help="Distance for recognising the source: weighted or l2."
            ),
        ] = "weighted",
        grid: Annotated[
            str | None,
            typer.Option(
                metavar="START:STOP:STEP",
                help="Wavelengths of spd.csv in nm (default: 1 nm over the recovered range).",
            ),
        ] = None,
        no_plots: Annotated[
            bool, typer.Option("--no-plots", help="Skip spd.png and geometry.png.")
        ] = False,
        force: ForceOption = False,
        quiet: QuietOption = False,
        json_output: JsonOption = False,
    ) -> None:
        """Measure a lamp's spectral power distribution with a calibrated camera and the
        diffraction grating (Alvarez et al. 2014)."""
        if mapping is not None and mapping_lamp_images:
            raise InputError(
                "give either --mapping or --mapping-lamp-images, not both", source="calib spd"
            )
        from calib.core.result import json_safe
        from calib.pipeline.outputs import check_out_dir
        from calib.spd.pipeline import SpdRequest, measure_spd

        check_out_dir(out, force, markers=SPD_MARKERS, what="an SPD measurement")
        request = SpdRequest(
            images=tuple(images),
            darks=tuple(dark or ()),
            camera=camera,
            out=out,
            grating_efficiency=grating_efficiency,
            mapping_images=tuple(mapping_lamp_images or ()),
            mapping_darks=tuple(mapping_lamp_dark or ()),
            mapping_spectrum=mapping_lamp_spectrum,
            mapping_file=mapping,
            name=name,
            source=source,
            weighting=weighting,
            smoothness=smoothness,
            metric=metric,
            grid=None if grid is None else checked_grid(grid),
            plots=not no_plots,
            command_line=("calib", "spd", *ctx.meta.get(ARGUMENTS, ())),
        )

        def progress(message: str) -> None:
            if not quiet:
                print(f"calib spd: {message}", file=sys.stderr)

        measurement = measure_spd(request, progress)
        if json_output:
            print(json.dumps(json_safe(measurement.summary), indent=2))
        if not quiet:
            _print_summary(measurement, request.out)
