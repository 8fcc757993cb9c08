"""``calib estimate``: standalone offline estimation from RAW brackets (or profiles) and lamp spectra.

The lamps come as ``--lamp NAME`` groups (:mod:`calib.cli.lamp_groups`) or from an inputs file
(``--inputs lamps.yaml``, :mod:`calib.pipeline.inputs_file`), or both (the file's lamps first); the
rest are ordinary options. Exit codes: 0 ok, 2 bad input (the reason on one line on stderr, naming the
file, field or option), 1 the estimation failed or an internal error (``CALIB_DEBUG=1`` shows the
traceback). With ``--json`` a summary (or the error) is printed as one JSON object on stdout.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TextIO

import typer

from calib.cli.command_line import (
    ARGUMENTS,
    ClickContext,
    click_command,
    error_code_and_line,
    new_app,
    subcommands,
    typed_on_command_line,
    warn,
)
from calib.cli.lamp_groups import LAMP_GROUPS, LampGroup, LampGroupsCommand, option_names
from calib.cli.options import (
    DataDirOption,
    ExcludeCameraOption,
    FocalLengthOption,
    ForceOption,
    GridOption,
    GroovesPerMmOption,
    JsonOption,
    MethodOption,
    NoReportOption,
    PixelPitchOption,
    QuietOption,
    WeightRuleOption,
    checked_assumed_grating,
    checked_grid,
    checked_method,
)
from calib.core.errors import InputError

if TYPE_CHECKING:
    # The pipeline (numpy, the methods registry) loads when a command runs, not for its help.
    from calib.pipeline.estimate import OfflineSettings
    from calib.pipeline.inputs import LampInput
    from calib.pipeline.run import OfflineOutcome

HELP = (
    "Estimate a camera's RGB spectral sensitivity from RAW brackets (or 1-D profiles) of lamps "
    "seen through a diffraction grating, and each lamp's measured spectrum.\n\n"
    "Give every lamp as a group, --lamp NAME (--images RAW ... | --profile CSV) --spectrum CSV "
    "[--kind KIND] …, repeated for each lamp; or list the lamps in a YAML file (--inputs). For "
    "example: calib estimate --lamp LED --kind led --images led/*.dng --spectrum led.csv --lamp FL "
    "--kind fluorescent --images fl/*.dng --spectrum fl.csv --out result\n\n"
    "Exit codes: 0 ok, 2 bad input (the reason on one line), 1 the estimation failed."
)


@dataclass(frozen=True)
class EstimateRequest:
    """What one ``calib estimate`` command line asks for.

    Attributes
    ----------
    lamps
        The lamps, the inputs file's first, then the ``--lamp`` groups in order.
    out_dir
        ``--out``.
    settings
        How to estimate (method and its options, grid, mapping lamp, data, grating, excluded
        cameras, the command line).
    force, quiet, json_output
        The flags.
    report
        ``--report/--no-report``: write ``report.html`` and its plots (as ``rig estimate``).
    """

    lamps: tuple[LampInput, ...]
    out_dir: Path
    settings: OfflineSettings
    force: bool = False
    quiet: bool = False
    json_output: bool = False
    report: bool = True


def summary(outcome: OfflineOutcome) -> dict[str, Any]:
    """The ``--json`` summary of an :class:`calib.pipeline.OfflineOutcome`."""
    from calib.core.mapping import QuadraticMapping
    from calib.core.result import json_safe

    estimate = outcome.estimate
    result = estimate.result
    mapping = result.mapping
    mapping_record: dict[str, Any] | None = None
    if isinstance(mapping, QuadraticMapping):
        mapping_record = {"a": mapping.a, "b": mapping.b, "c": mapping.c, "method": mapping.method}
    elif mapping is not None:
        mapping_record = dict(mapping.to_dict())
    record: dict[str, Any] = json_safe(
        {
            "status": "ok",
            "method": result.method,
            "method_choice": result.diagnostics.get("method_choice"),
            "out_dir": str(outcome.files["result"].parent),
            "files": {key: str(path) for key, path in outcome.files.items() if ":" not in key},
            "camera": estimate.provenance.camera.get("camera"),
            "lamps": [{"name": obs.name, "kind": obs.kind} for obs in estimate.observations],
            "mapping": mapping_record,
            "mapping_re_estimate": result.mapping_re_estimate,
            "reduced_chi2": result.diagnostics.get("reduced_chi2"),
            "uncertainty": result.sensitivity_sigma is not None,
            "basis": result.diagnostics.get("basis"),
            "warnings": list(estimate.warnings),
            "timings_s": dict(outcome.timings),
        }
    )
    return record


def print_summary(outcome: OfflineOutcome, stream: TextIO) -> None:
    """The few lines ``calib estimate`` prints after an estimate (without ``--json``)."""
    from calib.core.metrics import format_re

    record = summary(outcome)
    lamps = ", ".join(f"{lamp['name']} ({lamp['kind']})" for lamp in record["lamps"])
    print(f"estimate: {record['method']} from {lamps}", file=stream)
    if record["method_choice"]:
        print(
            f"method: auto chose {record['method']}: {record['method_choice']['reason']}",
            file=stream,
        )
    if record["camera"]:
        print(f"camera: {record['camera']}", file=stream)
    mapping = record["mapping"]
    if mapping and "a" in mapping:
        line = (
            f"mapping: λ = {mapping['a']:.4g} p² {mapping['b']:+.5g} p {mapping['c']:+.5g} nm "
            f"({mapping['method']})"
        )
        if record["mapping_re_estimate"] is not None:
            line += f", mapping RE estimate {format_re(record['mapping_re_estimate'])}"
        print(line, file=stream)
    for key in (
        "sensitivity",
        "result",
        "report",
        "camera_json",
        "dcamprof",
        "vkdt",
        "dcp",
        "icc",
        "grating",
    ):
        if key in record["files"]:
            print(f"{key:>11}: {record['files'][key]}", file=stream)


def typed_options(ctx: ClickContext) -> frozenset[str]:
    """The inputs-file ``estimate:`` keys whose option the command line typed (click's parameter
    source): they beat an inputs file's, which beat the defaults (decision 0179)."""
    from calib.pipeline.inputs_file import ESTIMATE_KEYS

    return frozenset(
        key
        for key, (_, option) in ESTIMATE_KEYS.items()
        if typed_on_command_line(ctx, option.removeprefix("--").replace("-", "_"))
    )


def _lamps(file_lamps: tuple[LampInput, ...], groups: Sequence[LampGroup]) -> tuple[LampInput, ...]:
    # Deferred: pydantic and PyYAML, which `calib --help` need not load.
    from calib.pipeline.inputs_file import lamp_from_options

    lamps = file_lamps + tuple(lamp_from_options(group.entry(), option_names()) for group in groups)
    if not lamps:
        raise InputError(
            "no lamps; give --lamp NAME --images RAW ... --spectrum CSV for every lamp, or "
            "--inputs FILE",
            source="--lamp",
        )
    return lamps


def estimate_request(
    ctx: ClickContext,
    *,
    out: Path,
    inputs: Path | None = None,
    method: str = "auto",
    weight_rule: str | None = None,
    mapping_lamp: str | None = None,
    grid: str | None = None,
    data_dir: Path | None = None,
    grating: Path | None = None,
    assume_grating: str | None = None,
    exclude_camera: Sequence[str] | None = None,
    grooves_per_mm: float | None = None,
    focal_length_mm: float | None = None,
    pixel_pitch_um: float | None = None,
    force: bool = False,
    quiet: bool = False,
    json_output: bool = False,
    no_report: bool = False,
) -> EstimateRequest:
    """The request of a parsed ``calib estimate`` (its options, and the lamp groups in ``ctx``):
    an inputs file's ``estimate:`` settings where no option was typed
    (:func:`calib.pipeline.inputs_file.own_settings_over`)."""
    from calib.methods.multilamp import weight_rule_option
    from calib.pipeline.estimate import OfflineSettings, StatedOptics
    from calib.pipeline.inputs_file import (
        InputsFileContents,
        own_settings_over,
        read_estimate_inputs,
    )

    method = checked_method(method)
    typed = typed_options(ctx)
    contents = (
        read_estimate_inputs(inputs)
        if inputs is not None
        else InputsFileContents(lamps=(), settings={}, notes=())
    )
    # --weight-rule goes with the method the estimate will use: the file's, unless typed.
    chosen_method = method if "method" in typed else contents.settings.get("method", method)
    settings = OfflineSettings(
        method=method,
        method_options=weight_rule_option(chosen_method, weight_rule),
        grid=checked_grid(grid),
        mapping_lamp=mapping_lamp,
        data_dir=data_dir,
        grating=grating,
        assumed_grating=checked_assumed_grating(assume_grating),
        exclude_cameras=tuple(exclude_camera or ()),
        optics=StatedOptics(grooves_per_mm, focal_length_mm, pixel_pitch_um),
        command_line=("calib", "estimate", *ctx.meta.get(ARGUMENTS, ())),
        typed_options=typed,
        notes=contents.notes,
    )
    settings = own_settings_over(settings, contents.settings, str(inputs))
    return EstimateRequest(
        lamps=_lamps(contents.lamps, ctx.meta.get(LAMP_GROUPS, [])),
        out_dir=out,
        settings=settings,
        force=force,
        quiet=quiet,
        json_output=json_output,
        report=not no_report,
    )


def parse_estimate_command(argv: Sequence[str]) -> EstimateRequest:
    """What ``calib estimate ARGV`` asks for, without running it (for scripts and tests).

    Raises
    ------
    InputError, typer's click.UsageError
        The mistakes the command itself would report.
    """
    app = new_app("calib", "")
    register(app)
    command = click_command(app)
    command = subcommands(command).get("estimate", command)
    with command.make_context("calib estimate", list(argv)) as ctx:
        params = dict(ctx.params)
        return estimate_request(ctx, json_output=params.pop("json_output"), **params)


def run_request(request: EstimateRequest) -> OfflineOutcome:
    """Estimate and write the outputs; print warnings and the summary as the flags say."""
    from calib.pipeline.outputs import check_out_dir
    from calib.pipeline.progress import RichFrameProgress
    from calib.pipeline.run import run_offline

    check_out_dir(request.out_dir, request.force)
    if request.quiet or not RichFrameProgress.wanted(sys.stderr):
        outcome = run_offline(
            request.lamps, request.out_dir, request.settings, report=request.report
        )
    else:
        with RichFrameProgress(sys.stderr) as progress:
            outcome = run_offline(
                request.lamps,
                request.out_dir,
                request.settings,
                progress=progress,
                report=request.report,
            )
    for warning in outcome.estimate.warnings:
        warn("calib", warning)
    if request.json_output:
        print(json.dumps(summary(outcome), allow_nan=False))
    elif not request.quiet:
        print_summary(outcome, sys.stdout)
    return outcome


def _json_error(exc: Exception) -> None:
    code, line = error_code_and_line(exc)
    record = {
        "status": "error",
        "exit_code": code,
        "error": line.split(": ", 1)[1],
        "source": getattr(exc, "source", None),
    }
    print(json.dumps(record))


def register(app: typer.Typer) -> None:
    """Add ``calib estimate`` to the ``calib`` app."""

    @app.command("estimate", cls=LampGroupsCommand, help=HELP)
    def estimate_command(
        ctx: typer.Context,
        out: Annotated[
            Path,
            typer.Option(
                "--out",
                "-o",
                metavar="DIR",
                help="Where to write sensitivity.csv, result.json, report.html, the camera files "
                "and grating.json (created if missing).",
            ),
        ],
        inputs: Annotated[
            Path | None,
            typer.Option(
                "--inputs",
                metavar="YAML",
                help="The lamps as a YAML file (lamps: a list of name, kind, images or profile, "
                "spectrum …; paths relative to the file), instead of or before --lamp groups; its "
                "optional estimate: block sets options (method, grid, optics …) that a typed "
                "option overrides.",
            ),
        ] = None,
        method: MethodOption = "auto",
        weight_rule: WeightRuleOption = None,
        mapping_lamp: Annotated[
            str | None,
            typer.Option(
                "--mapping-lamp",
                metavar="NAME",
                help="The lamp that gives the pixel→wavelength mapping (default: the "
                "estimator's choice).",
            ),
        ] = None,
        grid: GridOption = None,
        data_dir: DataDirOption = None,
        grating: Annotated[
            Path | None,
            typer.Option(
                "--grating",
                metavar="FILE",
                help="Grating efficiency (grating.json of an earlier estimate) for lamps with no "
                "direct measurement; without it a flat grating is assumed, with a warning.",
            ),
        ] = None,
        assume_grating: Annotated[
            str | None,
            typer.Option(
                "--assume-grating",
                metavar="flat|physical",
                help="With no direct measurement and no --grating: what stands in for the "
                "grating's efficiency, flat (default) or physical (η₁ averaged over thin "
                "sinusoidal sheets and blazed gratings, weighed by the camera prior: better when "
                "the sheet is one of them, worse when not; decision 0074).",
            ),
        ] = None,
        exclude_camera: ExcludeCameraOption = None,
        grooves_per_mm: GroovesPerMmOption = None,
        focal_length_mm: FocalLengthOption = None,
        pixel_pitch_um: PixelPitchOption = None,
        force: ForceOption = False,
        quiet: QuietOption = False,
        json_output: JsonOption = False,
        no_report: NoReportOption = False,
    ) -> None:
        try:
            request = estimate_request(
                ctx,
                out=out,
                inputs=inputs,
                method=method,
                weight_rule=weight_rule,
                mapping_lamp=mapping_lamp,
                grid=grid,
                data_dir=data_dir,
                grating=grating,
                assume_grating=assume_grating,
                exclude_camera=exclude_camera,
                grooves_per_mm=grooves_per_mm,
                focal_length_mm=focal_length_mm,
                pixel_pitch_um=pixel_pitch_um,
                force=force,
                quiet=quiet,
                json_output=json_output,
                no_report=no_report,
            )
            run_request(request)
        except Exception as exc:
            if json_output:
                _json_error(exc)
            raise
