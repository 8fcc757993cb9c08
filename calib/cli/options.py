"""The options several commands declare, one name and one meaning each, in ``calib`` and ``rig`` alike.

``--data-dir``, ``--exclude-camera``, ``--method``, ``--weight-rule``, ``--grid``, ``--quiet``/``-q``,
``--json``, ``--force``, the optics (``--grooves-per-mm``, ``--focal-length-mm``,
``--pixel-pitch-um``). Choices that come from the methods registry are listed in the help through
the placeholders ``{methods}`` and ``{weight_rules}`` (:func:`calib.cli.command_line.help_choices`),
filled only when the help is shown; the commands check the value (:func:`checked_method`,
:func:`checked_grid`).

Kept free of heavy imports: ``rig``'s command line imports it at start-up.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer

from calib.cli.command_line import help_choices
from calib.core.optics_ranges import FOCAL_LENGTH_MM, GROOVES_PER_MM, PIXEL_PITCH_UM

if TYPE_CHECKING:
    from calib.core.spectra import WavelengthGrid


#: The names ``--method`` takes, as :func:`calib.methods.method_names` lists them: kept here so that
#: a command's help lists them without importing the registry (it imports every method, ~0.3 s of
#: CPU); tests/test_command_lines.py checks the two agree. The value is checked against the
#: registry itself (:func:`checked_method`).
METHOD_NAMES: tuple[str, ...] = (
    "auto",
    "prior",
    "makabe2025",
    "multilamp",
    "known-grating",
    "jiang2013",
    "han2012",
    "solomatov2023",
    "toivonen2020",
)
#: :data:`calib.methods.multilamp.PRIOR_WEIGHT_RULES`, for the help (checked likewise).
WEIGHT_RULES: tuple[str, ...] = ("evidence", "typicality", "upre")


@help_choices("methods")
def registered_methods() -> Sequence[str]:
    """``auto`` and the methods registered in :data:`calib.methods.ESTIMATION_METHODS`."""
    return METHOD_NAMES


@help_choices("registered_methods")
def every_method() -> Sequence[str]:
    """The methods registered in :data:`calib.methods.ESTIMATION_METHODS` (not ``auto``)."""
    return METHOD_NAMES[1:]


@help_choices("fetchable_collections")
def fetchable_collections() -> Sequence[str]:
    """The collections ``data fetch`` downloads (:func:`calib.core.datasets.pinned_files`)."""
    from calib.core.datasets import FETCHABLE_COLLECTIONS

    return FETCHABLE_COLLECTIONS


@help_choices("weight_rules")
def weight_rules() -> Sequence[str]:
    """:data:`calib.methods.multilamp.PRIOR_WEIGHT_RULES`."""
    return WEIGHT_RULES


def checked_method(method: str) -> str:
    """``method`` as registered, else :class:`~calib.core.errors.InputError` on ``--method``."""
    from calib.methods import check_method

    return check_method(method, source="--method")


def checked_assumed_grating(text: str | None) -> Literal["flat", "physical"] | None:
    """``--assume-grating flat|physical`` (``None`` when not given), else
    :class:`~calib.core.errors.InputError` naming the option."""
    from calib.core.errors import InputError

    if text is None:
        return None
    if text == "flat":
        return "flat"
    if text == "physical":
        return "physical"
    raise InputError(f"{text!r} is not flat or physical", source="--assume-grating")


def checked_grid(text: str | None) -> WavelengthGrid:
    """``--grid START:STOP:STEP`` (default 400:700:10), else :class:`~calib.core.errors.InputError`."""
    from calib.core.errors import InputError
    from calib.core.spectra import DEFAULT_GRID, WavelengthGrid

    if text is None:
        return DEFAULT_GRID
    try:
        return WavelengthGrid.parse(text)
    except InputError as exc:
        raise InputError(str(exc).removeprefix(f"{exc.source}: "), source="--grid") from None


DataDirOption = Annotated[
    Path | None,
    typer.Option(
        "--data-dir",
        metavar="DIR",
        help="Camera data for the basis: a directory of camera collections (default: "
        "$SPECTRAL_RIG_DATA, else the user cache, else the bundled rawtoaces-data cameras).",
    ),
]
ExcludeCameraOption = Annotated[
    list[str] | None,
    typer.Option(
        "--exclude-camera",
        metavar="PATTERN",
        help="Keep a camera out of the basis, e.g. the camera under test when validating "
        "(repeatable): its make and model names every curve of that body (case, spaces, "
        "punctuation, EOS and Mark/Mk ignored; market names joined), or a shell wildcard such as "
        "'Sony*'.",
    ),
]
MethodOption = Annotated[
    str,
    typer.Option(
        "--method",
        help="Estimation method: {methods}. auto: multilamp when 3 or more lamps have a direct "
        "measurement, else prior.",
    ),
]
WeightRuleOption = Annotated[
    str | None,
    typer.Option(
        "--weight-rule",
        help="How the multilamp solve weights the camera prior: {weight_rules} (default upre). "
        "typicality suits cameras like the basis and fails unusual ones; evidence maximises the "
        "marginal likelihood.",
    ),
]
GridOption = Annotated[
    str | None,
    typer.Option(
        "--grid",
        metavar="START:STOP:STEP",
        help="Working wavelength grid in nm (default 400:700:10).",
    ),
]
QuietOption = Annotated[
    bool,
    typer.Option(
        "--quiet", "-q", help="No progress and no summary (warnings and errors still on stderr)."
    ),
]
JsonOption = Annotated[
    bool, typer.Option("--json", help="Print a JSON summary on stdout (for scripts).")
]
ForceOption = Annotated[
    bool, typer.Option("--force", help="Replace the results of an earlier run in --out.")
]

#: ``--grooves-per-mm``, ``--focal-length-mm``, ``--pixel-pitch-um``: what the rig knows of its
#: optics, the mapping's physical prior (decision 0025; a RAW file's EXIF gives the last two when
#: it records them).
GroovesPerMmOption = Annotated[
    float | None,
    typer.Option(
        "--grooves-per-mm",
        metavar="N",
        min=GROOVES_PER_MM[0],
        max=GROOVES_PER_MM[1],
        help="The grating's nominal line density (lines/mm, taken as ±2 %): the pixel→wavelength "
        "mapping's physics then holds the grating's spacing, which pins its red end beyond the "
        "lamp's last line.",
    ),
]
FocalLengthOption = Annotated[
    float | None,
    typer.Option(
        "--focal-length-mm",
        metavar="MM",
        min=FOCAL_LENGTH_MM[0],
        max=FOCAL_LENGTH_MM[1],
        help="The lens' focal length (mm), when the RAW files do not record it (with the pixel "
        "pitch: the mapping's focal length in pixels). Overrides EXIF.",
    ),
]
PixelPitchOption = Annotated[
    float | None,
    typer.Option(
        "--pixel-pitch-um",
        metavar="UM",
        min=PIXEL_PITCH_UM[0],
        max=PIXEL_PITCH_UM[1],
        help="The sensor's pixel pitch (µm), when the RAW files and the built-in table of bodies "
        "do not give it. Overrides them.",
    ),
]

#: Toivonen et al.'s ensemble size for comparisons.
EnsembleOption = Annotated[
    int | None, typer.Option(min=1, help="Toivonen ensemble size (default 16).")
]
#: Toivonen et al.'s Adam epochs for comparisons.
EpochsOption = Annotated[
    int | None, typer.Option(min=1, help="Toivonen Adam epochs (default 5000).")
]


#: ``--jobs``: local worker processes.
JobsOption = Annotated[
    int | None,
    typer.Option(
        "--jobs",
        "-j",
        min=1,
        help="Worker processes on this machine (default: the CPUs available; 1: in this process).",
    ),
]
#: ``--scheduler``: a Dask cluster instead of local workers.
SchedulerOption = Annotated[
    str | None,
    typer.Option(
        help="Run on the Dask cluster whose scheduler is at this address (tcp://host:8786) "
        "instead of local workers; paths must mean the same files on every worker. Needs "
        "the dask extra (pip install 'spectral-rig\\[dask]').",
    ),
]
#: ``--summary``: where the summary table is written.
SummaryOption = Annotated[
    list[Path] | None,
    typer.Option(
        help="Write the summary table to this file: .md (Markdown) or .csv (repeatable; default "
        "with --out: OUT/summary.md and OUT/summary.csv).",
    ),
]
#: ``--report/--no-report``.
ReportOption = Annotated[
    bool, typer.Option("--report/--no-report", help="Write report.html and its plots.")
]
#: ``--no-report`` alone (the report is the default), for commands whose option column has no room
#: for a second flag name at 80 columns (``calib estimate``); the same name as ``rig estimate``'s.
NoReportOption = Annotated[
    bool, typer.Option("--no-report", help="Do not write report.html and its plots.")
]
