"""``rig resume``: continue an interrupted or failed session in a new process, never losing a frame.

A session is resumable when it has a start record and did not complete: ``interrupted`` (a signal,
or no stop record at all after a crash, ``kill -9`` or a power loss) or ``failed`` (a device gave
up, e.g. the camera was unplugged). A ``complete`` session is refused (:class:`NotResumable`).

Resuming

1. reads the log (a torn last line is moved aside to ``log.torn-<n>``) and verifies every
   acknowledged file by size and sha256; a file that fails is recorded as ``discard``
   (``unverified``) and its step is done again — never silently reused;
2. rebuilds the plan from the start record (:func:`rig.plan.build_plan`) and walks it with the
   recorded results (:func:`find_resume_point`): the *resume point* is the first step that is not
   ``done``, whose file does not verify, or whose parameters differ from the record;
3. opens the devices in a new run (``run`` + 1, its own transcripts): the runner reads the relays
   and switches every lamp off before anything else, checks that every device is the instrument
   the session was captured with (model and serial; another port is fine, another camera body or
   spectrometer is refused as ``resume_mismatch``), then writes the start record and a
   ``resume`` record (what the previous run left: status, reason, relays found on, torn line,
   steps reused and redone);
4. drives the plan again (:func:`resumed_plan`): recorded results are sent back into the plan
   without touching a device for every reusable step before the resume point, except that the
   device set-up (``start/*``) is always done again, and the lamp lit at the resume point is
   switched on, warmed up and measured again (its state may have drifted while the rig was down).
   Reused frames of that lamp's bracket were taken some time after switch-on: a
   :class:`rig.steps.KeepLampTimeline` wait lets that time pass again, so the next frame sees the
   lamp as old as it would have been. An exposure set by a reused step is set again before a new
   frame. From the resume point on, every step is executed.

Step keys are idempotent (the same plan with the same readings yields the same keys), and later
records of a key win, so a reader sees each step once, as last done.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Generator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from calib.core.arrays import FloatArray
from calib.core.spectra import read_spectrum_csv
from drivers.base import DeviceIdentity
from rig.capture import RunOptions, run_on_station
from rig.config import RigConfig
from rig.errors import NotResumable, ResumeConfigRefused, ResumeMismatch, RigError
from rig.interrupts import InterruptController
from rig.plan import Plan, build_plan
from rig.progress import ProgressReporter
from rig.records import DeviceRecord, DiscardRecord, ResumeRecord, StartRecord, StepRecord
from rig.runner import RetryPolicy, Runner, RunOutcome
from rig.session import FileProblem, Session, SessionWriter, read_session
from rig.station import StationBuilder, resolve_builder, station_kind
from rig.steps import (
    AllLampsOff,
    Capture,
    ConfigureCamera,
    ConfigureSpectrometer,
    DarkFrame,
    ExposureSet,
    KeepLampTimeline,
    MeasureDark,
    MeasureSpectrum,
    SetExposure,
    SpectrumLoader,
    Step,
    StepResult,
    SwitchLamp,
    Wait,
    result_from_json,
)

#: The set-up steps every run does again: a new process must re-initialise its devices.
SETUP_STEPS = (AllLampsOff, ConfigureCamera, ConfigureSpectrometer, MeasureDark)
#: Relative difference within which a re-applied exposure matches the recorded one.
EXPOSURE_RTOL = 0.01


@dataclass
class ResumePoint:
    """Where a session continues, found by walking its plan with the recorded results.

    Attributes
    ----------
    reusable
        Done steps whose files verify, by key (the last ``done`` record of each).
    resume_step
        The first step to execute (``None``: every step is done; only the stop was missing).
    lamps_on
        Lamps lit at the resume point: switched on and warmed up again.
    unverified
        Acknowledged files that are missing or differ from their record.
    walked
        The reusable steps before the resume point, in plan order.
    """

    reusable: dict[str, StepRecord]
    resume_step: Step | None
    lamps_on: frozenset[str]
    unverified: list[FileProblem]
    walked: list[Step] = field(default_factory=list)

    @property
    def resume_key(self) -> str | None:
        return None if self.resume_step is None else self.resume_step.key

    def must_redo(self, step: Step) -> bool:
        """Whether a reusable step is done again: device set-up, or the lit lamp's warm-up."""
        if isinstance(step, SETUP_STEPS):
            return True
        if step.lamp_name not in self.lamps_on:
            return False
        is_warmup_wait = type(step) is Wait
        is_switch_on = isinstance(step, SwitchLamp) and step.on
        return is_switch_on or is_warmup_wait or isinstance(step, MeasureSpectrum)

    @property
    def redo(self) -> list[str]:
        """Keys of the reusable steps done again."""
        return [step.key for step in self.walked if self.must_redo(step)]


def spectrum_loader(session: Session) -> SpectrumLoader:
    """Reads a session's spectrum CSV (through the symlink-refusing path check)."""

    def load(relative: str) -> tuple[FloatArray, FloatArray]:
        spectrum = read_spectrum_csv(session.file_path(relative))
        return spectrum.wavelength_nm, spectrum.values

    return load


def _same_params(step: Step, record: StepRecord) -> bool:
    return bool(json.loads(json.dumps(step.params())) == record.params)


def reusable_steps(session: Session, unverified: list[FileProblem]) -> dict[str, StepRecord]:
    """The last ``done`` record of every key whose file (if any) is acknowledged and verifies."""
    bad = {problem.path for problem in unverified}
    acknowledged = {record.path for record in session.files()}
    reusable = {}
    for key, record in session.done_steps().items():
        file = (record.result or {}).get("file")
        if isinstance(file, str) and (file in bad or file not in acknowledged):
            continue
        reusable[key] = record
    return reusable


def start_of(session: Session) -> StartRecord:
    """The session's first start record (:class:`NotResumable` when there is none)."""
    if session.start is None:
        raise NotResumable(f"{session.path}: the log has no start record; nothing to resume")
    return session.start


def plan_of(session: Session) -> Plan:
    """The session's plan, rebuilt from its start record."""
    start = start_of(session)
    return build_plan(start.plan.name, start.plan.args)


def find_resume_point(session: Session, unverified: list[FileProblem]) -> ResumePoint:
    """Walk the rebuilt plan with the recorded results up to the first step that must be executed."""
    reusable = reusable_steps(session, unverified)
    load = spectrum_loader(session)
    plan = plan_of(session)
    lit: dict[str, bool] = {}
    walked: list[Step] = []
    resume_step: Step | None = None
    try:
        step = next(plan)
        while True:
            record = reusable.get(step.key)
            if record is None or not _same_params(step, record):
                resume_step = step
                break
            walked.append(step)
            if isinstance(step, SwitchLamp):
                lit[step.lamp] = step.on
            assert record.result is not None  # a done record has one
            step = plan.send(result_from_json(step, record.result, load))
    except StopIteration:
        pass
    except RigError:
        pass  # the recorded readings make the plan fail again; the resumed run fails the same way
    finally:
        plan.close()
    lamps_on = frozenset(lamp for lamp, on in lit.items() if on)
    return ResumePoint(reusable, resume_step, lamps_on, unverified, walked)


def resumed_plan(plan: Plan, point: ResumePoint, session: Session, run: int) -> Plan:
    """``plan`` with the reusable steps before the resume point answered from the log.

    See the module docstring for what is done again. Raises :class:`ResumeMismatch` when an
    exposure set again reads back differently from the record.
    """
    load = spectrum_loader(session)
    executing = False
    relit: str | None = None
    skipped: list[StepRecord] = []
    pending_exposure: tuple[SetExposure, StepRecord] | None = None
    try:
        step = next(plan)
    except StopIteration:
        return
    while True:
        record = None
        if not executing and step.key != point.resume_key:
            record = point.reusable.get(step.key)
            if record is not None and not _same_params(step, record):
                record = None  # the plan took another branch than the recorded run
        result: StepResult
        if record is not None and not point.must_redo(step):
            assert record.result is not None
            result = result_from_json(step, record.result, load)
            skipped.append(record)
            if isinstance(step, SetExposure):
                pending_exposure = (step, record)
        else:
            executing = executing or record is None
            reapply = isinstance(step, Capture | DarkFrame) and pending_exposure is not None
            if reapply and pending_exposure is not None and pending_exposure[1] in skipped:
                # Set again below: its time is spent then, not in the wait.
                skipped.remove(pending_exposure[1])
            yield from _keep_lamp_timeline(relit, skipped, run)
            skipped = []
            if reapply and pending_exposure is not None:
                yield from _set_exposure_again(*pending_exposure)
            if isinstance(step, SetExposure | Capture | DarkFrame):
                pending_exposure = None
            result = yield step
            if isinstance(step, SwitchLamp) and step.on and step.lamp in point.lamps_on:
                relit = step.lamp
        try:
            step = plan.send(result)
        except StopIteration:
            return


def _keep_lamp_timeline(
    lamp: str | None, skipped: list[StepRecord], run: int
) -> Generator[Step, StepResult, None]:
    """Wait the time the reused steps took, when they follow the re-lit lamp's warm-up."""
    seconds = math.fsum(record.duration_s for record in skipped)
    if lamp is not None and seconds > 0:
        yield KeepLampTimeline(lamp, run, seconds)


def _set_exposure_again(step: SetExposure, record: StepRecord) -> Generator[Step, StepResult, None]:
    """A reused exposure setting, applied again before a new frame (a new process starts unset)."""
    assert record.result is not None
    recorded = ExposureSet.from_json(record.result)
    again = yield step
    if not isinstance(again, ExposureSet) or not math.isclose(
        again.actual_s, recorded.actual_s, rel_tol=EXPOSURE_RTOL
    ):
        shown = again.actual_s if isinstance(again, ExposureSet) else again
        raise ResumeMismatch(
            f"{step.key}: the camera set {shown} s where the recorded run had "
            f"{recorded.actual_s:g} s; the reused frames and new ones would not form one bracket"
        )


def check_same_devices(session: Session, identities: Mapping[str, DeviceIdentity]) -> None:
    """The devices this run opened must be the instruments earlier runs recorded.

    Model and serial number are compared (the port may change: a device replugged elsewhere is the
    same device). Frames of two cameras, or spectra of two spectrometers, in one session would be
    estimated as one instrument's.

    Raises
    ------
    ResumeMismatch
        A device answers as another model or serial number than the first run recorded for its role.
    """
    recorded: dict[str, DeviceRecord] = {}
    for record in session.records:  # the first run to record a role decides (a refused run too
        if isinstance(record, StartRecord):  # writes a start record, with the wrong instrument)
            recorded = record.devices | recorded
    for role, identity in identities.items():
        before = recorded.get(role)
        if before is None:
            continue
        other_model = identity.model != before.model
        other_serial = (
            None not in (identity.serial, before.serial) and identity.serial != before.serial
        )
        if other_model or other_serial:
            raise ResumeMismatch(
                f"the {role} is {identity.describe()}, but the session was captured with "
                f"{before.describe()}: connect "
                "that instrument again and resume, or start a new session with rig capture"
            )


def _write_resume_records(
    writer: SessionWriter, runner: Runner, session: Session, point: ResumePoint
) -> None:
    """Write the ``resume`` record and a ``discard`` record per unverified file (after the start)."""
    stop = session.stop
    redo = point.redo
    writer.write(
        ResumeRecord,
        previous_status="failed" if session.status == "failed" else "interrupted",
        previous_reason=stop.reason if stop is not None else "no_stop_record",
        previous_run=session.records[-1].run,
        relays_found_on=list(runner.relays_found_on),
        torn_line=writer.torn_moved_to,
        skipped=len(point.walked) - len(redo),
        redo=redo,
        resume_key=point.resume_key,
    )
    keys = {record.path: record.key for record in session.files()}
    for problem in point.unverified:
        writer.write(
            DiscardRecord,
            key=keys[problem.path],
            path=problem.path,
            reason="unverified",
            message=problem.problem,
        )


def _reanalyse_reused_frames(runner: Runner, session: Session, point: ResumePoint) -> None:
    """Show the frame analyser the reused frames of the lamp whose bracket goes on, in order.

    The analyser keeps per-lamp state (the spot and band found in the lamp's first frame); a new
    process must build it from the same frames, or the new frames are measured differently.
    """
    lamp = point.resume_step.lamp_name if point.resume_step is not None else None
    for step in point.walked:
        if isinstance(step, Capture) and step.lamp == lamp:
            result = point.reusable[step.key].result or {}
            runner.station.analyzer.analyse(session.file_path(str(result["file"])))


def _remove_incoming(session: Session) -> None:
    """Delete downloads a killed run left half-done (never acknowledged, named ``.incoming-*``)."""
    for directory in ("frames", "spectra"):
        for leftover in (session.path / directory).glob(".incoming-*.part"):
            with contextlib.suppress(OSError):
                leftover.unlink()


def recorded_config(path: Path) -> RigConfig:
    """The configuration a session was captured with (its start record's snapshot)."""
    return RigConfig.model_validate(start_of(read_session(path)).config)


#: What a configuration given to ``rig resume --config`` may change: how each device is reached
#: (``devices.<role>.<field>``), never what is measured or with which kind of device.
CONNECTION_FIELDS = frozenset(
    {"port", "serial", "model", "baud", "timeout_s", "measure_timeout_s", "download_timeout_s"}
)


def config_for_resume(recorded: RigConfig, new: RigConfig) -> RigConfig:
    """``new`` when it differs from ``recorded`` only in :data:`CONNECTION_FIELDS` (and where new
    sessions go, ``output_dir``): e.g. a spectrometer that came back on another serial port.

    Raises
    ------
    ResumeConfigRefused
        ``new`` changes anything else (lamps, plan, camera settings, a device's kind …), named.
    """
    changed = _changed_fields(
        recorded.model_dump(mode="json"), new.model_dump(mode="json"), prefix=""
    )
    refused = [field for field in changed if not _may_change(field)]
    if refused:
        raise ResumeConfigRefused(
            f"the configuration changes {', '.join(refused)}; a resumed session measures as it "
            "was recorded, so only how the devices are reached may change (devices.<role>."
            f"{{{', '.join(sorted(CONNECTION_FIELDS))}}}): start a new session with rig capture "
            "for the rest"
        )
    return new


def _may_change(field: str) -> bool:
    parts = field.split(".")
    return field == "output_dir" or (
        len(parts) == 3 and parts[0] == "devices" and parts[2] in CONNECTION_FIELDS
    )


def _changed_fields(before: object, after: object, *, prefix: str) -> list[str]:
    """Dotted paths where two JSON documents differ (lists compared whole)."""
    if isinstance(before, dict) and isinstance(after, dict):
        changed = []
        for key in sorted(set(before) | set(after), key=str):
            path = f"{prefix}{key}"
            if key not in before or key not in after:
                changed.append(path)
            else:
                changed.extend(_changed_fields(before[key], after[key], prefix=f"{path}."))
        return changed
    return [] if before == after else [prefix.rstrip(".")]


def run_resume(
    path: Path,
    *,
    progress: ProgressReporter | None = None,
    interrupts: InterruptController | None = None,
    retry: RetryPolicy | None = None,
    builder: StationBuilder | None = None,
    config: RigConfig | None = None,
) -> RunOutcome:
    """Continue the session at ``path`` in a new run; return how the run ended.

    ``config`` replaces the recorded configuration for this run where :func:`config_for_resume`
    allows it (how the devices are reached); the new run's start record keeps what it used.

    Raises
    ------
    NotResumable
        The session is complete, or has no start record.
    ResumeConfigRefused
        ``config`` changes what the session measures.
    rig.errors.SessionFormatError
        ``path`` is not a valid session.
    """
    session = read_session(path)
    start = start_of(session)  # NotResumable without a start record
    if not session.resumable:
        raise NotResumable(
            f"{path} is complete; there is nothing to resume (estimate it with rig estimate)"
        )
    recorded = RigConfig.model_validate(start.config)
    config = recorded if config is None else config_for_resume(recorded, config)
    unverified = session.verify_files()
    point = find_resume_point(session, unverified)
    builder = builder or resolve_builder(station_kind(config))  # before the log is touched
    interrupts = interrupts or InterruptController()
    writer = SessionWriter.append(session, guard=interrupts.critical)
    _remove_incoming(session)

    def after_start(runner: Runner) -> None:
        check_same_devices(session, runner.identities)
        runner.frame_digests.update(
            (record.sha256, record.key)
            for record in session.files()
            if record.role in ("frame", "dark")
        )
        _write_resume_records(writer, runner, session, point)
        _reanalyse_reused_frames(runner, session, point)

    return run_on_station(
        config,
        writer,
        resumed_plan(plan_of(session), point, session, writer.run),
        start.plan,
        RunOptions(progress, interrupts, retry, builder),
        after_start=after_start,
    )
