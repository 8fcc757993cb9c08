"""The ``rig`` command: capture sessions on the rig (or its digital twin) and hand them to calib.

Exit codes: 0 success; 1 a device or internal failure; 2 bad input (configuration, limits, a path
that is not a session); 130/143 when a capture was interrupted by Ctrl-C/SIGTERM. Errors are one line
each on stderr, ``rig: error: …``, never a traceback.
"""

from __future__ import annotations

import json
import os
import signal
import sys
from collections.abc import Sequence
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.table import Table

from calib.cli import data
from calib.cli.command_line import ARGUMENTS, new_app, run_app
from calib.cli.options import (
    DataDirOption,
    EnsembleOption,
    EpochsOption,
    ExcludeCameraOption,
    ForceOption,
    GridOption,
    JobsOption,
    JsonOption,
    MethodOption,
    QuietOption,
    ReportOption,
    SchedulerOption,
    SummaryOption,
    WeightRuleOption,
    checked_grid,
    checked_method,
)
from calib.core.errors import CalibError, InputError
from calib.core.software import current_software
from drivers.base import DeviceError
from rig.errors import OpeningInterrupted, RigError, StationOpenFailed
from rig.interrupts import HaltRequested

if TYPE_CHECKING:
    from calib.pipeline import OfflineOutcome
    from rig.config import RigConfig
    from rig.progress import ProgressReporter
    from rig.runner import RunOutcome

app = new_app("rig", "Capture-rig controller for camera spectral sensitivity measurements.")

DEFAULT_CONFIG = Path("config.yaml")
ConfigOption = Annotated[Path, typer.Option("--config", "-c", help="The rig's configuration file.")]


def _duration(seconds: float) -> str:
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    return f"{minutes} min {secs:02d} s" if minutes else f"{secs} s"


def _capture_progress(config: RigConfig, quiet: bool) -> ProgressReporter:
    """A progress bar timed by the dry-run model of ``config``, or silence with ``--quiet``."""
    from rig.dryrun import StepCostModel
    from rig.progress import RichProgress, SilentProgress

    return SilentProgress() if quiet else RichProgress(StepCostModel(config.dry_run))


@app.command()
def version() -> None:
    """Print the software version."""
    typer.echo(current_software().version)


class SpectrometerKind(StrEnum):
    twin = "twin"
    pr655 = "pr655"
    pr670 = "pr670"
    cs2000 = "cs2000"
    seabreeze = "seabreeze"
    argyll = "argyll"
    files = "files"


class RelayKind(StrEnum):
    twin = "twin"
    hid_usbrelay = "hid_usbrelay"
    lcus = "lcus"
    numato = "numato"


class CameraKind(StrEnum):
    twin = "twin"
    gphoto2 = "gphoto2"


@app.command()
def init(
    twin: Annotated[
        bool,
        typer.Option(
            "--twin",
            help="The digital twin for every device not named (the default when none is named).",
        ),
    ] = False,
    spectrometer: Annotated[
        SpectrometerKind | None, typer.Option("--spectrometer", help="The spectrometer's kind.")
    ] = None,
    relays: Annotated[
        RelayKind | None, typer.Option("--relays", help="The relay board's kind.")
    ] = None,
    camera: Annotated[
        CameraKind | None, typer.Option("--camera", help="The camera's kind.")
    ] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="The file to write.")] = DEFAULT_CONFIG,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing file.")] = False,
) -> None:
    """Write a commented configuration: real instruments (--spectrometer, --relays, --camera; the
    others PR-655, HID relays, gphoto2) or the digital twin (--twin), each device on its own."""
    from rig.init_config import HARDWARE_DEFAULTS, TWIN, write_new_config

    named = {"spectrometer": spectrometer, "relays": relays, "camera": camera}
    everything_twin = twin or all(kind is None for kind in named.values())
    kinds = {
        role: kind.value
        if kind is not None
        else TWIN
        if everything_twin
        else HARDWARE_DEFAULTS[role]
        for role, kind in named.items()
    }
    try:
        write_new_config(out, force=force, **kinds)
    except FileExistsError as exc:
        raise InputError(str(exc), source="--out") from None
    typer.echo(
        f"wrote {out}: spectrometer {kinds['spectrometer']}, relays {kinds['relays']}, "
        f"camera {kinds['camera']}"
    )
    if all(kind == TWIN for kind in kinds.values()):
        typer.echo(f"next: rig demo -c {out}   (capture on the twin, estimate, report)")
    else:
        typer.echo(
            f"next: edit the ports and lamps in {out} (`rig devices` lists what is plugged in), "
            f"then rig dry-run -c {out} and rig capture -c {out}"
        )


@app.command()
def capture(
    config: ConfigOption = DEFAULT_CONFIG,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="Directory to create the session in (default: output_dir)."
        ),
    ] = None,
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="No progress bar; only the result.")
    ] = False,
) -> None:
    """Run the standard capture: every lamp warmed up, measured, bracketed, with dark frames."""
    from rig.capture import run_capture
    from rig.config import load_config

    rig_config = load_config(config)
    outcome = run_capture(rig_config, out_dir=out, progress=_capture_progress(rig_config, quiet))
    _report_run(outcome)


def _report_run(outcome: RunOutcome) -> None:
    """Print how a capture or resume ended and exit with its code."""
    status = {"success": "complete", "abort": "interrupted", "fail": "failed"}[outcome.exit_status]
    typer.echo(f"session: {outcome.session}")
    typer.echo(f"status: {status} ({outcome.reason}): {outcome.message}")
    if not outcome.lamps_off:
        typer.echo("WARNING: the lamps could not be confirmed off; check them by hand", err=True)
    raise typer.Exit(outcome.exit_code)


@app.command()
def resume(
    session: Annotated[Path, typer.Argument(help="The session directory (with log.jsonl).")],
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="No progress bar; only the result.")
    ] = False,
    config: Annotated[
        Path,
        typer.Option(
            "--config",
            "-c",
            help="The rig's configuration: the devices are opened as it says, and the session's "
            "recorded configuration must match it except in how the devices are reached (ports, "
            "serials, timeouts). The session's own snapshot is never used to open anything.",
        ),
    ] = DEFAULT_CONFIG,
) -> None:
    """Continue an interrupted or failed session in a new run: lamps off first, devices set up again,
    every file verified, the lit lamp warmed up and measured again, done steps skipped."""
    from rig.config import load_config
    from rig.resume import run_resume

    rig_config = load_config(config)
    _report_run(run_resume(session, rig_config, progress=_capture_progress(rig_config, quiet)))


@app.command("dry-run")
def dry_run_command(
    config: ConfigOption = DEFAULT_CONFIG,
    steps: Annotated[
        bool, typer.Option("--steps/--summary", help="List every step, or only the summary.")
    ] = True,
) -> None:
    """Walk the capture plan with modelled readings: steps, estimated duration, limit violations."""
    from rig.config import load_config
    from rig.dryrun import dry_run
    from rig.steps import AimSpectrometer, Capture, DarkFrame, MeasureBeam, MeasureSpectrum

    rig_config = load_config(config)
    report = dry_run(rig_config)
    console = Console(highlight=False, soft_wrap=True)
    if steps:
        key_width = max((len(p.step.key) for p in report.steps), default=3)
        console.print(f"{'#':>4}  {'at':>12}  {'takes':>9}  {'key':<{key_width}}  step")
        for number, planned in enumerate(report.steps, start=1):
            console.print(
                f"{number:>4}  {_duration(planned.start_s):>12}  {planned.duration_s:>7.2f} s  "
                f"{planned.step.key:<{key_width}}  {planned.step.describe()}"
            )
    frames = report.frames_per_lamp()
    console.print(
        f"{len(report.steps)} steps for {len(rig_config.lamps)} lamps: "
        f"{report.count(Capture)} bracket frames "
        f"({', '.join(f'{lamp} {n}' for lamp, n in frames.items())}), "
        f"{report.count(DarkFrame)} dark frames, {report.count(MeasureSpectrum)} spectra"
    )
    aims = report.count(AimSpectrometer)
    if aims:
        console.print(
            f"the grating's efficiency: {report.count(MeasureBeam)} spectra in its beams, "
            f"{aims} times a person re-aims the spectrometer (the steps marked OPERATOR; the run "
            "waits at each for Enter in the terminal)"
        )
    console.print(
        f"estimated duration: {_duration(report.duration_s)} (modelled readings from dry_run in {config})"
    )
    if report.failure is not None:
        console.print(
            f"the plan fails with the modelled readings ({report.failure.reason}): {report.failure}"
        )
    if report.violations:
        console.print(f"{len(report.violations)} limit violation(s):")
        for violation in report.violations:
            console.print(f"  {violation}")
    else:
        console.print("limit violations: none")
    if not report.ok:
        raise typer.Exit(2)


@app.command()
def sessions(
    directory: Annotated[
        Path | None,
        typer.Argument(
            help="Directory holding sessions (default: output_dir of the configuration)."
        ),
    ] = None,
    config: ConfigOption = DEFAULT_CONFIG,
) -> None:
    """List the sessions in a directory with their status: complete, interrupted or failed.

    Interrupted and failed sessions can be continued with ``rig resume``."""
    from rig.config import load_config
    from rig.session import find_sessions, summarise

    if directory is not None and not directory.is_dir():
        raise InputError(f"{directory} is not a directory", source="rig sessions")
    if directory is None:
        directory = load_config(config).output_dir if config.exists() else Path("sessions")
    console = Console(highlight=False, soft_wrap=True)
    found = [summarise(path) for path in find_sessions(directory)]
    if not found:
        console.print(f"no sessions in {directory}")
        return
    table = Table(box=None, pad_edge=False)
    # Session names are what the other commands take: never shortened (the reason wraps instead).
    table.add_column("session", no_wrap=True, min_width=max(len(f.path.name) for f in found))
    for heading in ("status", "resumable", "started (UTC)", "frames", "reason"):
        table.add_column(heading)
    for summary in found:
        started = f"{summary.started:%Y-%m-%d %H:%M:%S}" if summary.started else "-"
        table.add_row(
            summary.path.name,
            summary.status,
            "yes" if summary.resumable else "no",
            started,
            str(summary.frames),
            summary.reason,
        )
    console.print(table)


@app.command()
def estimate(
    ctx: typer.Context,
    sessions: Annotated[
        list[Path],
        typer.Argument(
            help="Session directories (with log.jsonl); several are estimated as a batch.",
            show_default=False,
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="Output directory (default: SESSION/estimate); with several sessions, "
            "OUT/<session>/ for each and the summary in OUT.",
        ),
    ] = None,
    method: MethodOption = "auto",
    data_dir: DataDirOption = None,
    weight_rule: WeightRuleOption = None,
    grating: Annotated[
        Path | None,
        typer.Option(
            help="A grating file (rig grating, or grating.json of an earlier estimate): with "
            "--method multilamp the sensitivity comes from it and the profiles, s = q / η."
        ),
    ] = None,
    grid: GridOption = None,
    exclude_camera: ExcludeCameraOption = None,
    quiet: QuietOption = False,
    json_output: JsonOption = False,
    force: ForceOption = False,
    report: ReportOption = True,
    jobs: JobsOption = None,
    scheduler: SchedulerOption = None,
    summary: SummaryOption = None,
) -> None:
    """Estimate the camera from a session (every file verified against the log) and write the
    report; several sessions run as a batch (local workers or a Dask cluster) with a summary."""
    from calib.cli.batch import run_batch_command
    from calib.cli.estimate import summary as json_summary
    from calib.methods.multilamp import weight_rule_option
    from calib.pipeline import RichFrameProgress
    from rig.estimate import SESSION_INPUTS, estimate_session, session_settings

    method = checked_method(method)
    command_line = ("rig", "estimate", *ctx.meta.get(ARGUMENTS, ()))
    settings: dict[str, object] = {
        "method_options": weight_rule_option(method, weight_rule),
        "exclude_cameras": tuple(exclude_camera or ()),
    }
    if grating is not None:
        settings["grating"] = grating
    working_grid = checked_grid(grid)
    if len(sessions) > 1 or scheduler is not None:
        offline = session_settings(
            method=method,
            data_dir=data_dir,
            grid=working_grid,
            command_line=command_line,
            settings=settings,
        )
        code = run_batch_command(
            sessions,
            [SESSION_INPUTS],
            offline,
            program="rig",
            out=out,
            jobs=jobs,
            scheduler=scheduler,
            report=report,
            force=force,
            quiet=quiet,
            summary=summary,
        )
        raise typer.Exit(code)
    session = sessions[0]

    def run(progress: RichFrameProgress | None) -> OfflineOutcome:
        return estimate_session(
            session,
            out,
            method=method,
            data_dir=data_dir,
            grid=working_grid,
            progress=progress,
            command_line=command_line,
            settings=settings,
            force=force,
            report=report,
        )

    if quiet or json_output or not RichFrameProgress.wanted(sys.stderr):
        outcome = run(None)
    else:
        with RichFrameProgress(sys.stderr) as progress:
            outcome = run(progress)
    result = outcome.estimate.result
    for warning in outcome.estimate.warnings:
        typer.echo(f"rig: warning: {warning}", err=True)
    if json_output:
        typer.echo(json.dumps(json_summary(outcome), allow_nan=False))
        return
    if "report" in outcome.files:
        typer.echo(f"report: {outcome.files['report']}")
    typer.echo(f"sensitivity: {outcome.files['sensitivity']}")
    if result.mapping_re_estimate is not None:
        from calib.core.metrics import format_re

        typer.echo(
            f"method: {result.method}, mapping RE estimate {format_re(result.mapping_re_estimate)}"
        )
    else:
        typer.echo(f"method: {result.method}")


@app.command()
def grating(
    sessions: Annotated[
        list[Path],
        typer.Argument(help="Session directories: one or more cameras through the same grating."),
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="The grating file to write (JSON).")],
    data_dir: DataDirOption = None,
    weight_rule: WeightRuleOption = None,
    exclude_camera: ExcludeCameraOption = None,
    description: Annotated[
        str, typer.Option(help="What the grating is (sheet, slit), recorded in the file.")
    ] = "",
    force: Annotated[bool, typer.Option("--force", help="Replace an existing file.")] = False,
) -> None:
    """One grating file from sessions of several cameras through the same grating (η shared).

    The next camera then needs a single LED shot: calib estimate --grating FILE.
    """
    from rig.grating import median_relative_sigma, refine_session_grating

    outcome = refine_session_grating(
        sessions,
        out,
        data_dir=data_dir,
        weight_rule=weight_rule,
        exclude_cameras=exclude_camera or (),
        description=description,
        force=force,
    )
    for warning in outcome.warnings:
        typer.echo(f"rig: warning: {warning}", err=True)
    for camera in outcome.cameras:
        typer.echo(f"{camera.session}: camera {camera.camera}, lamps {', '.join(camera.lamps)}")
    spread = median_relative_sigma(outcome.grating)
    shown = "" if spread is None else f" (median σ {spread:.1%} of η)"
    typer.echo(f"grating: {outcome.path}{shown}")


@app.command()
def compare(
    sessions: Annotated[
        list[Path], typer.Argument(help="Digital-twin session directories (with twin-truth.json).")
    ],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Directory for compare.md, compare.csv, the plot.")
    ] = Path("compare"),
    method: Annotated[
        list[str] | None,
        typer.Option(help="Methods to run (repeatable; default: all): {registered_methods}."),
    ] = None,
    data_dir: DataDirOption = None,
    exclude_camera: ExcludeCameraOption = None,
    ensemble: EnsembleOption = None,
    epochs: EpochsOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Only where the files are.")] = False,
) -> None:
    """Compare every grating method on twin sessions against the twin's true camera (RE table)."""
    import shlex
    from contextlib import nullcontext

    from rich.markdown import Markdown

    from rig.compare import compare_sessions

    toivonen = {
        key: value for key, value in (("ensemble_size", ensemble), ("epochs", epochs)) if value
    }
    status = Console(stderr=True).status("comparing…")
    with nullcontext() if quiet else status:
        comparison = compare_sessions(
            sessions,
            out,
            methods=method,
            data_dir=data_dir,
            exclude_cameras=exclude_camera or (),
            toivonen=toivonen,
            command=" ".join(["rig", *(shlex.quote(arg) for arg in sys.argv[1:])]),
            progress=None if quiet else lambda row: status.update(f"{row.camera} · {row.label}"),
        )
    if not quiet:
        Console().print(Markdown(comparison.report))
    typer.echo("wrote " + ", ".join(str(path) for path in comparison.files.values()))


@app.command()
def replay(
    session: Annotated[Path, typer.Argument(help="The recorded session directory.")],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", help="The replay's new session directory (default: SESSION-replay)."
        ),
    ] = None,
) -> None:
    """Run a session's plan again on drivers that serve its recordings; fail on any other command."""
    from rig.replay import ReplayDiverged, replay_session

    outcome = replay_session(session, out)
    run = outcome.run
    status = {"success": "complete", "abort": "interrupted", "fail": "failed"}[run.exit_status]
    typer.echo(f"replay: {run.session}")
    typer.echo(f"status: {status} ({run.reason}): {run.message}")
    if outcome.mismatch is not None:
        raise ReplayDiverged(f"the rig diverged from the recording:\n{outcome.mismatch}")
    if outcome.difference is not None:
        raise ReplayDiverged(f"the replay's log differs from the recording: {outcome.difference}")
    typer.echo("log: identical to the recording (times and ids masked)")


@app.command()
def devices(
    serial: Annotated[bool, typer.Option("--serial/--no-serial", help="List serial ports.")] = True,
    usb: Annotated[
        bool,
        typer.Option(
            "--usb/--no-usb", help="Probe HID relay boards and Ocean spectrometers on the USB bus."
        ),
    ] = True,
    cameras: Annotated[
        bool, typer.Option("--cameras/--no-cameras", help="Autodetect gphoto2 cameras.")
    ] = True,
    timeout_s: Annotated[
        float,
        typer.Option(
            "--timeout", min=0.1, help="Deadline of each USB probe and of autodetection, s."
        ),
    ] = 5.0,
) -> None:
    """List the serial ports, HID relay boards, Ocean spectrometers and cameras present, with
    config snippets for each."""
    from drivers.discovery import list_devices, render_text

    report = list_devices(
        include_serial=serial,
        include_usb_relays=usb,
        include_ocean=usb,
        include_cameras=cameras,
        timeout_s=timeout_s,
    )
    typer.echo(render_text(report), nl=False)


@app.command("calibrate-spectrometer")
def calibrate_spectrometer_command(
    lamp: Annotated[
        str,
        typer.Option(
            "--lamp",
            help="The reference lamp's known spectrum: a colour-science illuminant name (A for a "
            "tungsten-halogen lamp) or a CSV (wavelength_nm, value).",
        ),
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="The calibration file to write.")],
    config: ConfigOption = DEFAULT_CONFIG,
    channel: Annotated[
        int | None,
        typer.Option(
            "--channel", min=1, help="Relay channel of the lamp (default: the lamp of that name)."
        ),
    ] = None,
    warmup_s: Annotated[
        float, typer.Option("--warmup", min=0.0, help="Seconds the lamp burns before measuring.")
    ] = 120.0,
    repeats: Annotated[int, typer.Option("--repeats", min=1, help="Spectra averaged.")] = 3,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing file.")] = False,
) -> None:
    """Make an Ocean spectrometer's relative irradiance calibration against a lamp of known
    spectrum (the file devices.spectrometer.calibration_file loads)."""
    from calib.core.lamp_specs import lamp_from_spec
    from rig.calibrate import calibrate_spectrometer
    from rig.config import load_config

    if out.exists() and not force:
        raise InputError(f"{out} exists; pass --force to replace it", source="--out")
    rig_config = load_config(config)
    known = lamp_from_spec(lamp)
    outcome = calibrate_spectrometer(
        rig_config, known, out, channel=channel, warmup_s=warmup_s, repeats=repeats, source=lamp
    )
    typer.echo(f"calibration: {outcome.path}")
    typer.echo(
        f"range: {outcome.wavelength_nm[0]:g}-{outcome.wavelength_nm[-1]:g} nm, integration "
        f"{outcome.integration_ms:g} ms, spread between spectra {outcome.spread:.2%}"
    )
    typer.echo(f"use it: devices.spectrometer.calibration_file: {outcome.path}")


data.register(app)


@app.command()
def demo(
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Directory for the session, estimate and report.")
    ] = Path("demo-output"),
    config: ConfigOption = DEFAULT_CONFIG,
    quiet: Annotated[
        bool, typer.Option("--quiet", "-q", help="No progress bar; only the result.")
    ] = False,
) -> None:
    """Capture on the digital twin, estimate, and report the error against the twin's true camera."""
    from rig.config import load_config
    from rig.demo import run_demo

    rig_config = load_config(config)
    result = run_demo(rig_config, out, progress=_capture_progress(rig_config, quiet))
    capture = result.capture
    typer.echo(f"session: {capture.session} (capture {result.capture_s:.1f} s)")
    if capture.exit_status != "success":
        typer.echo(f"the capture did not complete ({capture.reason}): {capture.message}", err=True)
        raise typer.Exit(capture.exit_code)
    typer.echo(f"twin truth: {result.truth}")
    typer.echo(f"estimate: {result.estimate_dir} ({result.estimate_s:.1f} s)")
    if result.report is not None:
        typer.echo(f"report: {result.report}")
    if result.relative_error is None:
        typer.echo("the estimate wrote no sensitivity.csv: no error to report", err=True)
        raise typer.Exit(1)
    from calib.core.metrics import format_re

    typer.echo(
        f"RE against the twin's camera: {format_re(result.relative_error)} "
        "(Makabe et al. 2025 Eq. 16, curves normalised to their maximum)"
    )
    for illuminant, (mean, worst) in result.colour_error.items():
        typer.echo(
            f"ΔE2000 against the twin's camera under {illuminant} (ColorChecker, developed with "
            f"the estimate's matrix vs the truth's): mean {mean:.2f}, max {worst:.2f}"
        )


def _fail(message: str, code: int) -> None:
    for line in message.splitlines() or [""]:
        print(f"rig: error: {line}", file=sys.stderr)
    sys.exit(code)


def _warn_lamps(exc: BaseException) -> None:
    """After an opening that failed or was interrupted: say when the lamps are not confirmed off."""
    if isinstance(exc, StationOpenFailed | OpeningInterrupted) and not exc.lamps_off:
        print(
            "rig: warning: the lamps could not be confirmed off (the relay board did not open or "
            "answer): check them by hand",
            file=sys.stderr,
        )


def _interrupt_inside(exc: BaseException) -> bool:
    """Whether ``exc`` is a Ctrl-C a library turned into its own error: a ``KeyboardInterrupt`` in
    its chain, or pydantic-core's ``SchemaError``, which keeps only the interrupt's name in its text
    when one arrives while it builds a validator."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, KeyboardInterrupt):
            return True
        if type(current).__name__ == "SchemaError" and "KeyboardInterrupt" in str(current):
            return True
        current = current.__cause__ or current.__context__
    return False


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point: errors become one line each on stderr and an exit code."""
    try:
        code = run_app(app, "rig", argv)
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        code = 130
    except HaltRequested as exc:
        # A second signal in the instant between the first one's stop and the cleanup's start
        # (from there on every further one is only noted): the cleanup did not run.
        _fail(
            f"{exc}, before the cleanup began: the lamps may still be on, check them by hand "
            "[halted]",
            128 + int(signal.Signals[exc.signal_name]),
        )
    except InputError as exc:
        _fail(str(exc), 2)
    except OpeningInterrupted as exc:
        _warn_lamps(exc)
        _fail(f"{exc} [{exc.reason}]", exc.signal_exit_code)
    except RigError as exc:
        _warn_lamps(exc)
        _fail(f"{exc} [{exc.reason}]", exc.exit_code)
    except DeviceError as exc:
        _fail(f"{exc} [{exc.reason}]", 1)
    except CalibError as exc:
        _fail(str(exc), 1)
    except OSError as exc:
        if os.environ.get("RIG_DEBUG"):
            raise
        _fail(f"cannot read or write a file: {exc}", 1)
    except Exception as exc:
        if _interrupt_inside(exc):
            print("rig: interrupted", file=sys.stderr)
            sys.exit(130)
        if os.environ.get("RIG_DEBUG"):
            raise
        _fail(f"internal error: {type(exc).__name__}: {exc} (set RIG_DEBUG=1 for the traceback)", 1)
    sys.exit(code)
