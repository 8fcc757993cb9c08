"""A capture from configuration to finished session: check limits, open the station, run the plan.

This is what ``rig capture`` does, as a function: limits are checked before anything is opened, the
session directory is created before the devices are opened (so the transcripts of a failed opening
are kept), and a station that cannot be opened still leaves a valid log with a start and a stop
record saying why.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from drivers.base import DeviceError
from rig.config import RigConfig
from rig.dryrun import DryRunReport, ModelledBench, check_limits, walk
from rig.errors import LimitsExceeded, RigError
from rig.interrupts import InterruptController
from rig.plan import Plan, StandardCaptureArgs, standard_capture
from rig.progress import ProgressReporter
from rig.records import PlanInfo, StartRecord, StopRecord
from rig.runner import RetryPolicy, Runner, RunOutcome, StepTimeouts, error_info, software_info
from rig.session import SessionWriter
from rig.station import StationBuilder, resolve_builder, station_kind

PLAN_NAME = "standard_capture"


def _record_unopened_station(
    session: SessionWriter, plan: PlanInfo, config: dict[str, object], error: Exception
) -> None:
    """Start and stop records for a session whose devices could not be opened."""
    with contextlib.suppress(RigError):
        session.write(
            StartRecord,
            session_id=session.session_id,
            wall_time=datetime.now(UTC),
            software=software_info(),
            plan=plan,
            config=config,
            devices={},
            clock="none",
        )
        session.close_transcripts()
        info = error_info(error)
        session.write(
            StopRecord,
            exit_status="fail",
            reason=info.reason,
            message=f"the devices could not be opened: {error}",
            wall_time=datetime.now(UTC),
            t_s=0.0,
            error=info,
            lamps_off=False,
        )
    session.close()


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
    interrupts = interrupts or InterruptController()
    session = SessionWriter.create(out_dir or config.output_dir, guard=interrupts.critical)
    return run_on_station(
        config,
        session,
        standard_capture(args),
        plan_info,
        RunOptions(progress, interrupts, retry, builder),
        estimate=estimate,
    )


@dataclass(frozen=True)
class RunOptions:
    """How a run is done: progress, signal handling, retries (``None``: the runner's defaults), and
    the station builder (callers resolve it before they create or touch the session)."""

    progress: ProgressReporter | None
    interrupts: InterruptController | None
    retry: RetryPolicy | None
    builder: StationBuilder


def run_on_station(
    config: RigConfig,
    session: SessionWriter,
    plan: Plan,
    plan_info: PlanInfo,
    options: RunOptions,
    *,
    estimate: DryRunReport | None = None,
    after_start: Callable[[Runner], None] | None = None,
) -> RunOutcome:
    """Open the station recording into ``session``, run ``plan`` on it, and close it.

    A station that cannot be opened still leaves a start and a stop record saying why.
    ``after_start`` is called with the runner right after the run's start record.
    """
    config_snapshot = config.model_dump(mode="json")
    try:
        station = options.builder(config, session.transcript_sink)
    except (DeviceError, RigError) as exc:
        _record_unopened_station(session, plan_info, config_snapshot, exc)
        raise
    try:
        runner = Runner(
            station,
            session,
            timeouts=StepTimeouts.from_config(config),
            retry=options.retry,
            progress=options.progress,
            interrupts=options.interrupts,
        )
        hook = None if after_start is None else functools.partial(after_start, runner)
        return runner.run(plan, plan_info, config_snapshot, estimate, after_start=hook)
    finally:
        station.close()  # the runner has closed it already, unless it failed to start
