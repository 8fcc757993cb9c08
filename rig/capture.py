"""A capture from configuration to finished session: check limits, open the station, run the plan.

This is what ``rig capture`` does, as a function. Limits are checked before anything is opened.
The signal handlers are installed next, so a Ctrl-C or SIGTERM at any later moment ends in a clean
stop; then every device is opened (all of them are tried, and every failure is named at once), and
only when they all are is the session directory created: a device that cannot be opened, or a signal
while they are being opened, leaves no session behind — the relays that did open are switched off
and read back, and the error says whether the lamps are confirmed off. What the devices exchanged
while opening is written to the session's transcripts once it exists
(:class:`rig.session.PendingTranscripts`). ``rig resume`` continues a session the same way
(:func:`run_on_station`), touching it only once its devices are open.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drivers.base import DeviceError
from rig.config import RigConfig
from rig.dryrun import DryRunReport, ModelledBench, check_limits, walk
from rig.errors import LimitsExceeded, OpeningInterrupted, StationOpenFailed
from rig.interrupts import HaltRequested, InterruptController
from rig.plan import Plan, StandardCaptureArgs, standard_capture
from rig.progress import ProgressReporter
from rig.records import PlanInfo
from rig.runner import RetryPolicy, Runner, RunOutcome, StepTimeouts, switch_off_now
from rig.session import PendingTranscripts, SessionWriter
from rig.station import Station, StationBuilder, resolve_builder, station_kind

PLAN_NAME = "standard_capture"

SessionOpener = Callable[[], SessionWriter]
"""Creates (a capture) or continues (a resume) the session, once the devices are open."""


@dataclass(frozen=True)
class RunOptions:
    """How a run is done: progress, signal handling, retries (``None``: the runner's defaults), and
    the station builder (callers resolve it before they create or touch the session).
    ``on_session`` is called with the session writer as soon as it exists (replay ends a killed
    run's replay where the recording ends)."""

    progress: ProgressReporter | None
    interrupts: InterruptController | None
    retry: RetryPolicy | None
    builder: StationBuilder
    on_session: Callable[[SessionWriter], None] | None = None


def run_capture(
    config: RigConfig,
    *,
    out_dir: Path | None = None,
    progress: ProgressReporter | None = None,
    interrupts: InterruptController | None = None,
    retry: RetryPolicy | None = None,
    builder: StationBuilder | None = None,
) -> RunOutcome:
    """Run the standard capture plan; return how it ended (the session path is in the outcome).

    Parameters
    ----------
    config
        The validated configuration.
    out_dir
        Where to create the session directory (default ``config.output_dir``).
    progress, interrupts, retry
        Passed to the :class:`rig.runner.Runner`.
    builder
        Opens the station (default: the builder registered for the configured device kinds).

    Raises
    ------
    LimitsExceeded
        Before anything is opened, when the configuration violates the declared limits.
    rig.errors.StationOpenFailed, rig.errors.OpeningInterrupted
        The devices could not be opened, or a signal came while they were; no session exists.
    rig.errors.SessionWriteError
        When the session directory cannot be created.
    """
    violations = check_limits(config)
    if violations:
        raise LimitsExceeded("; ".join(str(v) for v in violations))
    args = StandardCaptureArgs.from_config(config)
    plan_info = PlanInfo(name=PLAN_NAME, args=args.model_dump(mode="json"))
    estimate = walk(standard_capture(args), ModelledBench(config))
    builder = builder or resolve_builder(station_kind(config))  # before anything is created
    parent = out_dir or config.output_dir
    return run_on_station(
        config,
        functools.partial(SessionWriter.create, parent),
        standard_capture(args),
        plan_info,
        RunOptions(progress, interrupts, retry, builder),
        estimate=estimate,
    )


def run_on_station(
    config: RigConfig,
    open_session: SessionOpener,
    plan: Plan,
    plan_info: PlanInfo,
    options: RunOptions,
    *,
    estimate: DryRunReport | None = None,
    after_start: Callable[[Runner], None] | None = None,
) -> RunOutcome:
    """Open the station under the signal handlers, then the session, run ``plan``, close.

    ``after_start`` is called with the runner right after the run's start record.

    Raises
    ------
    rig.errors.StationOpenFailed, rig.errors.OpeningInterrupted
        Opening failed or was interrupted; ``open_session`` was not called.
    rig.errors.SessionWriteError, rig.errors.SessionFormatError
        ``open_session`` failed; the devices were switched off and closed.
    """
    interrupts = options.interrupts or InterruptController()
    with interrupts.installed():
        transcripts = PendingTranscripts()
        station = open_station(config, options.builder, transcripts, interrupts)
        try:
            session = open_session()
            session.guard = interrupts.critical
            transcripts.attach(session)
        except BaseException:
            release_station(station, config, interrupts)
            raise
        if options.on_session is not None:
            options.on_session(session)
        try:
            runner = Runner(
                station,
                session,
                timeouts=StepTimeouts.from_config(config),
                retry=options.retry,
                progress=options.progress,
                interrupts=interrupts,
            )
            hook = None if after_start is None else functools.partial(after_start, runner)
            return runner.run(
                plan, plan_info, config.model_dump(mode="json"), estimate, after_start=hook
            )
        finally:
            station.close()  # the runner has closed it already, unless it failed to start


def open_station(
    config: RigConfig,
    builder: StationBuilder,
    transcripts: PendingTranscripts,
    interrupts: InterruptController,
) -> Station:
    """Open every device with ``builder``, under the signal handlers.

    A second signal is held until the builder returns (the devices it opened are then switched
    off and closed, which a builder cut short could not do); after the first, the opened station
    is switched off and closed at once.

    Raises
    ------
    rig.errors.StationOpenFailed
        A device could not be opened (a builder that names its failures raises it itself).
    rig.errors.OpeningInterrupted
        A signal arrived while the devices were being opened.
    """
    station: Station | None = None
    try:
        with interrupts.critical():
            station = builder(config, transcripts)
    except HaltRequested as exc:
        lamps_off = release_station(station, config, interrupts)
        raise OpeningInterrupted(
            interrupts.stop_requested or exc.signal_name, lamps_off=lamps_off
        ) from None
    except DeviceError as exc:
        signal_name = interrupts.stop_requested
        if signal_name is not None:
            raise OpeningInterrupted(signal_name, lamps_off=False) from None
        raise StationOpenFailed({"station": exc}, lamps_off=False) from exc
    except StationOpenFailed as exc:
        signal_name = interrupts.stop_requested
        if signal_name is not None:
            raise OpeningInterrupted(signal_name, lamps_off=exc.lamps_off) from None
        raise
    signal_name = interrupts.stop_requested
    if signal_name is not None:
        lamps_off = release_station(station, config, interrupts)
        raise OpeningInterrupted(signal_name, lamps_off=lamps_off)
    return station


def release_station(
    station: Station | None, config: RigConfig, interrupts: InterruptController
) -> bool:
    """Switch every lamp of an opened station off, read the board back, close the station;
    return whether the lamps are confirmed off (``False`` with no station). Nothing of it may
    raise, and from its start signals are only noted: a second one may not cut the switching off."""
    interrupts.enter_cleanup()
    if station is None:
        return False
    try:
        return switch_off_now(station.relays, StepTimeouts.from_config(config).relays_s)
    finally:
        with contextlib.suppress(Exception):
            station.close()
