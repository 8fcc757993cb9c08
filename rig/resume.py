"""``rig resume``: continue an interrupted or failed session in a new process, never losing a frame.

A session is resumable when it has a start record and did not complete: ``interrupted`` (a signal,
or no stop record at all after a crash, ``kill -9`` or a power loss) or ``failed`` (a device gave
up, e.g. the camera was unplugged). A ``complete`` session is refused (:class:`NotResumable`).

A session may come from anyone, so everything in it is data, checked before anything is opened or
written (:func:`prepare_resume`); any problem is a one-line refusal (exit 2):

* the log is read and validated, and every record the resume will use is rebuilt up front (its
  step from ``action`` and ``params``, its result, the spectra it names): a malformed but
  schema-valid record is a :class:`rig.errors.SessionFormatError` naming its line, never a crash
  half-way through the run;
* the configuration snapshot is compared with the **user's** configuration (``config.yaml`` or
  ``--config``; :func:`config_for_resume`): only how the devices are reached may differ, and the
  devices are opened from the user's configuration only — a port, state file or data directory
  named by the session is never opened;
* the session's directories are checked for anything planted (a symbolic link or special file
  anywhere in ``frames/``, ``spectra/``, ``transcripts/``): refused and named;
* every acknowledged file is verified by size and sha256; a file that fails is recorded as
  ``discard`` (``unverified``) and its step is done again — never silently reused;
* the transcripts of a run that was killed (no file records) are checked to be transcripts.

Then :func:`rig.capture.run_on_station` opens the devices under the signal handlers (a device that
cannot be opened changes nothing in the session) and only then continues the session: temporaries
a killed run left (``.incoming-*``, the camera's ``..incoming-*.partial``, ``.reserve``) and any
frame or spectrum no ``file`` record acknowledges (renamed into place when the run was killed) are
removed, so the log alone decides what the new run stores under which name (it replays so); a
torn last line of the log or of a killed run's transcript is moved aside (``<name>.torn-<n>``); and a new run (``run`` + 1, its own transcripts) begins. The runner reads the
relays and switches every lamp off before anything else, checks that every device is the
instrument the session was captured with (model and serial; another port is fine, another camera
body or spectrometer is refused as ``resume_mismatch``), then writes the start record, the
``resume`` record (what the previous run left: status, reason, relays found on, torn line, steps
reused and redone), a ``discard`` per unverified file, and a ``file`` record acknowledging each
transcript of a killed run (so the session replays run by run).

The plan is rebuilt from the start record (:func:`rig.plan.build_plan`) and walked with the
recorded results (:func:`find_resume_point`): the *resume point* is the first step that is not
``done``, whose file does not verify, or whose parameters differ from the record. It is driven
again (:func:`resumed_plan`): recorded results are sent back into the plan without touching a
device for every reusable step before the resume point, except that the device set-up
(``start/*``) is always done again, and the lamp lit at the resume point is switched on, warmed up
and measured again (its state may have drifted while the rig was down). Reused frames of that
lamp's bracket were taken some time after switch-on: a :class:`rig.steps.KeepLampTimeline` wait lets
that time pass again, so the next frame sees the lamp as old as it would have been. An exposure set
by a reused step is set again before a new frame. When an earlier run had the operator re-aim the
spectrometer (the grating's beams, :class:`rig.steps.AimSpectrometer`), nobody knows where it looks
now: before each spectrum the new run takes, the operator is asked to aim it where that spectrum
needs it (an aim step keyed ``lamp/<name>/resume/<run>/aim-<beam>``), unless this run already did.
From the resume point on, every step is executed. Which steps are set-up, warm-up, exposure, frames
or aims is the vocabulary's business (:class:`ResumeRules`, one answer per step type).

Step keys are idempotent (the same plan with the same readings yields the same keys), and later
records of a key win, so a reader sees each step once, as last done.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from pydantic import ValidationError

from calib.core.arrays import FloatArray
from calib.core.errors import SpectrumError
from calib.core.spectra import read_spectrum_csv
from drivers.base import DeviceIdentity
from rig.capture import RunOptions, run_on_station
from rig.config import RigConfig
from rig.errors import (
    NotResumable,
    PlanProtocolError,
    ResumeConfigRefused,
    ResumeMismatch,
    RigError,
    SessionFormatError,
    first_validation_problem,
)
from rig.interrupts import InterruptController
from rig.plan import Plan, build_plan
from rig.progress import ProgressReporter
from rig.records import (
    DeviceRecord,
    DiscardRecord,
    FileRecord,
    ResumeRecord,
    StartRecord,
    StepRecord,
)
from rig.runner import RetryPolicy, Runner, RunOutcome
from rig.session import (
    FileProblem,
    Session,
    SessionWriter,
    check_before_writing,
    move_tail_aside,
    parse_transcript,
    read_session,
    remove_leftovers,
    transcript_path,
)
from rig.station import StationBuilder, resolve_builder, station_kind
from rig.steps import (
    AimSpectrometer,
    AllLampsOff,
    AnyStep,
    Capture,
    ConfigureCamera,
    ConfigureSpectrometer,
    DarkFrame,
    ExposureSet,
    FrameCaptured,
    KeepLampTimeline,
    MeasureBeam,
    MeasureDark,
    MeasureSpectrum,
    SetExposure,
    SpectrumLoader,
    StepHandlers,
    StepResult,
    SwitchLamp,
    Wait,
    interpret,
    result_from_json,
    step_from_record,
)

#: The device roles whose transcripts a run writes.
ROLES = ("relays", "spectrometer", "camera")


@dataclass(frozen=True)
class StepOnResume:
    """What resume needs to know of a step, answered per step type by :class:`ResumeRules`.

    Attributes
    ----------
    setup
        Every run does it again: a new process must set its devices up.
    warmup_lamp
        The step belongs to this lamp's warm-up (switch-on, warm-up wait, spectrum): done again
        when the lamp is lit at the resume point.
    switches
        ``(lamp, on)`` when the step switches a lamp.
    exposure
        The step itself when it sets the camera's exposure (set again before a new frame).
    frame
        ``"scene"`` or ``"dark"`` when the step takes a frame.
    aims
        The step itself when it aims the spectrometer (an operator's action).
    needs_aim
        Where the spectrometer must look for the step (:func:`rig.steps.beam_target`).
    """

    setup: bool = False
    warmup_lamp: str | None = None
    switches: tuple[str, bool] | None = None
    exposure: SetExposure | None = None
    frame: Literal["scene", "dark"] | None = None
    aims: AimSpectrometer | None = None
    needs_aim: str | None = None


class ResumeRules(StepHandlers[StepOnResume]):
    """The vocabulary as resume reads it (see :class:`StepOnResume`)."""

    def all_lamps_off(self, step: AllLampsOff) -> StepOnResume:
        return StepOnResume(setup=True)

    def configure_camera(self, step: ConfigureCamera) -> StepOnResume:
        return StepOnResume(setup=True)

    def configure_spectrometer(self, step: ConfigureSpectrometer) -> StepOnResume:
        return StepOnResume(setup=True)

    def switch_lamp(self, step: SwitchLamp) -> StepOnResume:
        return StepOnResume(
            warmup_lamp=step.lamp if step.on else None, switches=(step.lamp, step.on)
        )

    def measure_spectrum(self, step: MeasureSpectrum) -> StepOnResume:
        return StepOnResume(warmup_lamp=step.lamp, needs_aim="lamp")

    def measure_dark(self, step: MeasureDark) -> StepOnResume:
        return StepOnResume(setup=True)  # a new process measures its spectrometer's dark again

    def aim_spectrometer(self, step: AimSpectrometer) -> StepOnResume:
        return StepOnResume(aims=step)

    def measure_beam(self, step: MeasureBeam) -> StepOnResume:
        return StepOnResume(needs_aim=step.target)

    def wait(self, step: Wait) -> StepOnResume:
        return StepOnResume(warmup_lamp=step.lamp)

    def keep_lamp_timeline(self, step: KeepLampTimeline) -> StepOnResume:
        return StepOnResume()

    def set_exposure(self, step: SetExposure) -> StepOnResume:
        return StepOnResume(exposure=step)

    def capture(self, step: Capture) -> StepOnResume:
        return StepOnResume(frame="scene")

    def dark_frame(self, step: DarkFrame) -> StepOnResume:
        return StepOnResume(frame="dark")


_RULES = ResumeRules()


def on_resume(step: AnyStep) -> StepOnResume:
    """What resume needs to know of ``step``."""
    return interpret(step, _RULES)


#: Relative difference within which a re-applied exposure matches the recorded one.
EXPOSURE_RTOL = 0.01


@dataclass
class ResumePoint:
    """Where a session continues, found by walking its plan with the recorded results.

    Attributes
    ----------
    reusable
        Done steps whose files verify, by key (the last ``done`` record of each).
    results
        The result of every reusable step, rebuilt from its record (and its files) up front.
    resume_step
        The first step to execute (``None``: every step is done; only the stop was missing).
    lamps_on
        Lamps lit at the resume point: switched on and warmed up again.
    unverified
        Acknowledged files that are missing or differ from their record.
    walked
        The reusable steps before the resume point, in plan order.
    aimed_before
        Where the spectrometer looks when the new run opens: ``"lamp"`` (its usual target), or
        ``None`` (unknown) when an earlier run had it re-aimed — a person may also have moved it
        while the rig was down, so the new run asks the operator before its first spectrum.
    """

    reusable: dict[str, StepRecord]
    results: dict[str, StepResult]
    resume_step: AnyStep | None
    lamps_on: frozenset[str]
    unverified: list[FileProblem]
    walked: list[AnyStep] = field(default_factory=list)
    aimed_before: str | None = "lamp"

    @property
    def resume_key(self) -> str | None:
        return None if self.resume_step is None else self.resume_step.key

    def must_redo(self, step: AnyStep) -> bool:
        """Whether a reusable step is done again: device set-up, or the lit lamp's warm-up."""
        rule = on_resume(step)
        return rule.setup or (rule.warmup_lamp is not None and rule.warmup_lamp in self.lamps_on)

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


def _same_params(step: AnyStep, record: StepRecord) -> bool:
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


def _line(record: StepRecord | StartRecord) -> str:
    return f"line {record.seq + 1}"


def _first_error(exc: ValidationError) -> str:
    return first_validation_problem(exc.errors(), "value")


def recorded_config(session: Session) -> RigConfig:
    """The configuration snapshot of the session's start record, validated (as data: it is only
    ever compared with the user's configuration, never opened).

    Raises
    ------
    SessionFormatError
        The snapshot is not a valid configuration.
    """
    start = start_of(session)
    try:
        return RigConfig.model_validate(start.config)
    except ValidationError as exc:
        raise SessionFormatError(
            f"{session.path}: {_line(start)}: the recorded configuration is invalid: "
            f"{_first_error(exc)}"
        ) from None


def plan_of(session: Session) -> Plan:
    """The session's plan, rebuilt from its start record.

    Raises
    ------
    SessionFormatError
        The recorded plan is unknown or its arguments are invalid.
    """
    start = start_of(session)
    try:
        return build_plan(start.plan.name, start.plan.args)
    except ValidationError as exc:
        problem = f"its arguments are invalid: {_first_error(exc)}"
    except PlanProtocolError as exc:
        problem = str(exc)
    raise SessionFormatError(f"{session.path}: {_line(start)}: the recorded plan: {problem}")


def _rebuilt_result(session: Session, record: StepRecord, load: SpectrumLoader) -> StepResult:
    """A done record's result, rebuilt; any problem with the record is a format error naming it."""
    try:
        step = step_from_record(record.action, record.params)
        if step.key != record.key:
            raise ValueError(f"its action and params make the step {step.key!r}")
        assert record.result is not None  # a done record has one
        return result_from_json(step, record.result, load)
    except (SessionFormatError, SpectrumError) as exc:
        problem = str(exc)
    except (ValueError, TypeError, KeyError, OverflowError, AttributeError) as exc:
        problem = f"{type(exc).__name__}: {exc}"
    raise SessionFormatError(
        f"{session.path}: {_line(record)}: step {record.key}: the recorded step or result cannot "
        f"be read ({problem})"
    )


def find_resume_point(session: Session, unverified: list[FileProblem]) -> ResumePoint:
    """Walk the rebuilt plan with the recorded results up to the first step that must be executed.

    Raises
    ------
    SessionFormatError
        A reusable record cannot be rebuilt, or the recorded results cannot drive the plan.
    """
    reusable = reusable_steps(session, unverified)
    load = spectrum_loader(session)
    results = {key: _rebuilt_result(session, record, load) for key, record in reusable.items()}
    plan = plan_of(session)
    lit: dict[str, bool] = {}
    walked: list[AnyStep] = []
    resume_step: AnyStep | None = None
    step: AnyStep | None = None
    try:
        step = next(plan)
        while True:
            record = reusable.get(step.key)
            if record is None or not _same_params(step, record):
                resume_step = step
                break
            walked.append(step)
            switches = on_resume(step).switches
            if switches is not None:
                lit[switches[0]] = switches[1]
            step = plan.send(results[step.key])
    except StopIteration:
        pass
    except RigError:
        pass  # the recorded readings make the plan fail again; the resumed run fails the same way
    except Exception as exc:  # the plan cannot digest what the log says it read
        where = step.key if step is not None else "the start"
        raise SessionFormatError(
            f"{session.path}: the recorded results cannot drive the plan at {where} "
            f"({type(exc).__name__}: {exc})"
        ) from None
    finally:
        plan.close()
    lamps_on = frozenset(lamp for lamp, on in lit.items() if on)
    re_aimed = any(
        isinstance(record, StepRecord) and record.action == AimSpectrometer.__name__
        for record in session.records
    )
    return ResumePoint(
        reusable,
        results,
        resume_step,
        lamps_on,
        unverified,
        walked,
        aimed_before=None if re_aimed else "lamp",
    )


def resumed_plan(plan: Plan, point: ResumePoint, run: int) -> Plan:
    """``plan`` with the reusable steps before the resume point answered from the log.

    See the module docstring for what is done again. Raises :class:`ResumeMismatch` when an
    exposure set again reads back differently from the record.
    """
    executing = False
    relit: str | None = None
    skipped: list[StepRecord] = []
    pending_exposure: tuple[SetExposure, StepRecord] | None = None
    aimed = point.aimed_before
    aims: dict[str, AimSpectrometer] = {}
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
        rule = on_resume(step)
        if rule.aims is not None:
            aims[rule.aims.target] = rule.aims
        result: StepResult
        if record is not None and not point.must_redo(step):
            result = point.results[step.key]
            skipped.append(record)
            if rule.exposure is not None:
                pending_exposure = (rule.exposure, record)
        else:
            executing = executing or record is None
            reapply = rule.frame is not None and pending_exposure is not None
            if reapply and pending_exposure is not None and pending_exposure[1] in skipped:
                # Set again below: its time is spent then, not in the wait.
                skipped.remove(pending_exposure[1])
            yield from _keep_lamp_timeline(relit, skipped, run)
            skipped = []
            if reapply and pending_exposure is not None:
                exposure_step = pending_exposure[0]
                recorded = point.results[exposure_step.key]
                assert isinstance(recorded, ExposureSet)
                yield from _set_exposure_again(exposure_step, recorded)
            if rule.exposure is not None or rule.frame is not None:
                pending_exposure = None
            if rule.needs_aim is not None and rule.needs_aim != aimed:
                yield from _aim_again(step, rule.needs_aim, aims, run)
            result = yield step
            if rule.aims is not None:
                aimed = rule.aims.target
            elif rule.needs_aim is not None:
                aimed = rule.needs_aim
            if (
                rule.switches is not None
                and rule.switches[1]
                and rule.switches[0] in point.lamps_on
            ):
                relit = rule.switches[0]
        try:
            step = plan.send(result)
        except StopIteration:
            return


def _aim_again(
    step: AnyStep, target: str, aims: Mapping[str, AimSpectrometer], run: int
) -> Generator[AnyStep, StepResult, None]:
    """Ask the operator to aim the spectrometer at ``target`` before ``step``: in a new run the
    spectrometer looks where the last run left it, or where a person put it since."""
    lamp = step.lamp_name
    if lamp is None:
        raise PlanProtocolError(f"{step.key}: a spectrometer step of no lamp")
    plan_aim = aims.get(target)
    if plan_aim is None and target != "lamp":
        raise PlanProtocolError(f"{step.key}: the plan never aimed the spectrometer at {target}")
    aim = AimSpectrometer(lamp, "lamp") if plan_aim is None else plan_aim
    yield dataclasses.replace(aim, lamp=lamp, run=run)


def _keep_lamp_timeline(
    lamp: str | None, skipped: list[StepRecord], run: int
) -> Generator[AnyStep, StepResult, None]:
    """Wait the time the reused steps took, when they follow the re-lit lamp's warm-up."""
    seconds = math.fsum(record.duration_s for record in skipped)
    if lamp is not None and seconds > 0:
        yield KeepLampTimeline(lamp, run, seconds)


def _set_exposure_again(
    step: SetExposure, recorded: ExposureSet
) -> Generator[AnyStep, StepResult, None]:
    """A reused exposure setting, applied again before a new frame (a new process starts unset)."""
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


@dataclass(frozen=True)
class KilledTranscript:
    """A transcript of a run that never acknowledged it (killed): where its whole entries end."""

    role: str
    path: str
    whole_bytes: int
    size: int


def killed_transcripts(session: Session) -> list[KilledTranscript]:
    """The transcripts of earlier runs that no ``file`` record acknowledges (a killed run's),
    each checked to be a transcript up to a possibly torn last line.

    Raises
    ------
    SessionFormatError
        A complete line is not a transcript entry.
    """
    acknowledged = {
        record.path
        for record in session.records
        if isinstance(record, FileRecord) and record.role == "transcript"
    }
    found = []
    for run in range(1, session.records[-1].run + 1):
        for role in ROLES:
            relative = transcript_path(role, run)
            if relative in acknowledged or not (session.path / relative).exists():
                continue
            data = session.file_path(relative).read_bytes()
            whole = data.rfind(b"\n") + 1
            parse_transcript(data[:whole], f"{session.path}: {relative}")
            found.append(KilledTranscript(role, relative, whole, len(data)))
    return found


def _acknowledge_killed_transcripts(
    writer: SessionWriter, session: Session, transcripts: list[KilledTranscript]
) -> None:
    """A ``file`` record for each transcript of a killed run (its torn tail already moved aside)."""
    for transcript in transcripts:
        data = session.file_path(transcript.path).read_bytes()
        writer.write(
            FileRecord,
            key=f"transcripts/{transcript.role}",
            role="transcript",
            path=transcript.path,
            size=len(data),
            sha256=hashlib.sha256(data).hexdigest(),
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
        result = point.results[step.key]
        if on_resume(step).frame == "scene" and step.lamp_name == lamp:
            assert isinstance(result, FrameCaptured)
            runner.station.analyzer.analyse(session.file_path(result.file))


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
    before, after = recorded.model_dump(mode="json"), new.model_dump(mode="json")
    changed = _changed_fields(before, after, prefix="")
    refused = [field for field in changed if not _may_change(field)]
    # Another kind of device: say that, not every field the two kinds do not share.
    for role, device in before["devices"].items():
        kind, new_kind = device["kind"], after["devices"][role]["kind"]
        if kind != new_kind:
            within = f"devices.{role}."
            refused = [field for field in refused if not field.startswith(within)]
            refused.append(f"devices.{role}.kind ({kind} → {new_kind})")
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


@dataclass(frozen=True)
class PreparedResume:
    """A session checked for resuming, before any device is opened or anything written."""

    session: Session
    config: RigConfig
    point: ResumePoint
    leftovers: list[Path]
    killed: list[KilledTranscript]


def prepare_resume(path: Path, config: RigConfig) -> PreparedResume:
    """Check the session at ``path`` for resuming with the user's ``config``; open and write nothing.

    Raises
    ------
    SessionFormatError
        Not a valid session: a malformed record, an invalid configuration snapshot or plan, a
        path planted in its directories, a killed run's transcript that is not one.
    NotResumable
        The session is complete, or has no start record.
    ResumeConfigRefused
        ``config`` differs from the recorded configuration in what is measured.
    """
    session = read_session(path)
    start_of(session)  # NotResumable without a start record
    if not session.resumable:
        raise NotResumable(
            f"{path} is complete; there is nothing to resume (estimate it with rig estimate)"
        )
    config = config_for_resume(recorded_config(session), config)
    leftovers = check_before_writing(session)
    unverified = session.verify_files()
    point = find_resume_point(session, unverified)
    return PreparedResume(session, config, point, leftovers, killed_transcripts(session))


def _continue_session(prepared: PreparedResume, interrupts: InterruptController) -> SessionWriter:
    """The session opened for the new run: leftovers removed, torn tails moved aside."""
    session = prepared.session
    try:
        remove_leftovers(prepared.leftovers)
        for transcript in prepared.killed:
            if transcript.whole_bytes < transcript.size:
                move_tail_aside(session.path / transcript.path, transcript.whole_bytes)
    except OSError as exc:
        raise SessionFormatError(f"{session.path}: cannot tidy the session: {exc}") from None
    return SessionWriter.append(session, guard=interrupts.critical)


def run_resume(
    path: Path,
    config: RigConfig,
    *,
    progress: ProgressReporter | None = None,
    interrupts: InterruptController | None = None,
    retry: RetryPolicy | None = None,
    builder: StationBuilder | None = None,
    on_session: Callable[[SessionWriter], None] | None = None,
) -> RunOutcome:
    """Continue the session at ``path`` in a new run with the user's ``config``; return how the
    run ended.

    ``config`` is what the devices are opened with; it may differ from the recorded configuration
    only in how the devices are reached (:func:`config_for_resume`), and the new run's start record
    keeps what it used. Everything is checked before anything is opened (:func:`prepare_resume`).

    Raises
    ------
    NotResumable, ResumeConfigRefused, rig.errors.SessionFormatError
        See :func:`prepare_resume`; nothing was opened or written.
    rig.errors.StationOpenFailed, rig.errors.OpeningInterrupted
        The devices could not be opened, or a signal came while they were; nothing was written.
    """
    prepared = prepare_resume(path, config)
    builder = builder or resolve_builder(station_kind(prepared.config))
    interrupts = interrupts or InterruptController()
    session, point = prepared.session, prepared.point

    def after_start(runner: Runner) -> None:
        check_same_devices(session, runner.identities)
        runner.frame_digests.update(
            (record.sha256, record.key)
            for record in session.files()
            if record.role in ("frame", "dark")
        )
        runner.spectrometer_aim = point.aimed_before
        _write_resume_records(runner.session, runner, session, point)
        _acknowledge_killed_transcripts(runner.session, session, prepared.killed)
        _reanalyse_reused_frames(runner, session, point)

    return run_on_station(
        prepared.config,
        lambda: _continue_session(prepared, interrupts),
        resumed_plan(plan_of(session), point, session.records[-1].run + 1),
        start_of(session).plan,
        RunOptions(progress, interrupts, retry, builder, on_session),
        after_start=after_start,
    )
