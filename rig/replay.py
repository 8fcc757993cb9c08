"""``rig replay``: run a recorded session's plan again, on drivers that serve its own recordings.

The recorded plan (:func:`rig.plan.build_plan` from the start record) runs on the real runner,
session writer and drivers. Only the layer below the drivers is replaced (:mod:`mocks.replay`): a
pyserial port, a pyusb backend and a ``gphoto2`` module that check each command against the
session's transcripts and answer with what the devices answered, and serve the session's frames to
the camera's downloads. Waits take no time: the clock is simulated and follows the recorded
timeline, so branches that depend on time (a warm-up timeout) go as they went.

A resumed session replays run by run: run 1 as above, then each later run as ``rig resume`` of
the replay itself (:func:`rig.resume.run_resume`, a fresh interrupt controller as a new process
has), on a station serving that run's transcripts. The resume decides from the replay's own log
what to reuse, as it decided from the original's. Each step takes its recorded time on the
simulated clock (the station's step hook moves the clock from the step's recorded start to its
end), because a resume waits out the reused steps' durations.

A run that was killed (no stop record; ``rig resume`` acknowledged its transcripts) is replayed up
to its last record: the replay's session writer then stops as the killed process did
(:meth:`rig.session.SessionWriter.kill`), and what the rig does after that point — the step the
recording was cut in, the cleanup the killed process never did — is not checked. A run that
stopped because the session could not be written (``session_write``) is refused: its recording
ends where the disk filled, not where the rig stopped.

The replay drivers come from the ``spectral_rig.replay`` entry point (``mocks.replay``'s
:class:`~mocks.replay.station.RecordingServer`), through the typed :class:`ReplayBackend`
protocol; the rig never imports ``mocks``.

The result is a new session directory. The replay fails with :class:`ReplayDiverged` — naming the
step, the device, the transcript line, and the expected and sent bytes or call — when the rig sends
anything else, or leaves a recorded exchange unused; otherwise its log is compared with the
original's with times and ids masked (:func:`compare_logs`).

The session is untrusted input: it is read with :func:`rig.session.read_session` (validated records,
safe relative paths, no symlinks), every acknowledged file is verified against its sha256 before
anything runs, the configuration snapshot is validated by pydantic (never executed), the plan is
rebuilt by name from a registry, and nothing is written outside the new session directory.
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol, TypedDict

from pydantic import ValidationError

from drivers.base import Camera, DeviceError, RelayBoard, Spectrometer, TranscriptEntry
from rig.capture import RunOptions, run_on_station
from rig.clock import Clock
from rig.config import RigConfig
from rig.dryrun import DryRunReport
from rig.errors import (
    PlanProtocolError,
    RigError,
    SessionFormatError,
    StationUnavailable,
    first_validation_problem,
)
from rig.frame_stats import RawFrameAnalyzer
from rig.interrupts import InterruptController, ReceivedSignal
from rig.operator import OperatorDeclined, ScriptedOperator
from rig.plan import build_plan
from rig.progress import ProgressReporter, SilentProgress
from rig.records import FileRecord, InterruptionRecord, Record, StartRecord, StepRecord, StopRecord
from rig.resume import run_resume
from rig.runner import RetryPolicy, RunOutcome
from rig.session import (
    Session,
    SessionWriter,
    parse_transcript,
    read_session,
    transcript_path,
)
from rig.station_devices import Station, TranscriptFactory
from rig.steps import AnyStep, DeviceRole, StepResult, Wait

#: The entry-point group naming the replay backend (``mocks.replay``'s ``RecordingServer``).
REPLAY_ENTRY_POINTS = "spectral_rig.replay"
ROLES: tuple[DeviceRole, ...] = ("relays", "spectrometer", "camera")
#: Keys masked wherever they occur when logs are compared: times, ids and wall clocks.
MASKED_KEYS = frozenset(
    {
        "session_id",
        "wall_time",
        "software",
        "clock",
        "t_s",
        "time_s",
        "started_s",
        "duration_s",
        "waited_s",
        "backoff_s",
        "traceback",
    }
)
MASK = "<masked>"
#: The rig's retries, without their backoff: the timeline moves the clock to each step's recorded
#: end (:meth:`_Timeline.step_hook`), which already holds the backoffs the recording waited out;
#: waiting them again would put every later step that much later than recorded (a retry's
#: ``backoff_s`` is masked when the logs are compared).
REPLAY_RETRY = RetryPolicy(initial_s=0.0, max_s=0.0)


class ReplayRefused(RigError):
    """The session cannot be replayed as it is (invalid, tampered, unsafe, or not supported)."""

    reason = "replay_refused"
    exit_code = 2


class ReplayDiverged(RigError):
    """The rig sent something other than the recording, or left a recorded exchange unused."""

    reason = "replay_mismatch"


class RecordedDeviceData(TypedDict):
    """One recorded device, as plain data for the backend (``mocks.replay.RecordedDevice``)."""

    identity: dict[str, Any]
    entries: list[TranscriptEntry]
    timeout_s: float
    download_timeout_s: float
    measure_timeout_s: float | None


class SteppedClock(Clock, Protocol):
    """The replay's simulated clock: the timeline moves it to the recorded times."""

    def advance(self, seconds: float) -> None: ...


class ReplayMismatchView(Protocol):
    """What the rig sent against what the recording has (``mocks.replay.ReplayMismatch``)."""

    role: str
    problem: str
    index: int | None
    expected: TranscriptEntry | None
    sent: TranscriptEntry | None

    def describe(self, entry: TranscriptEntry | None) -> str: ...


class MismatchLog(Protocol):
    """Every mismatch of one replay in order (``mocks.replay.Mismatches``)."""

    context: Callable[[], str]

    @property
    def found(self) -> Sequence[ReplayMismatchView]: ...

    def where(self, mismatch: Any) -> str: ...


class ReplayStation(Protocol):
    """The recorded devices opened on their stand-ins (``mocks.replay.ReplayBench``)."""

    @property
    def relays(self) -> RelayBoard: ...

    @property
    def spectrometer(self) -> Spectrometer: ...

    @property
    def camera(self) -> Camera: ...

    @property
    def clock(self) -> SteppedClock: ...

    @property
    def mismatches(self) -> MismatchLog: ...

    def finish(self) -> None: ...

    def close(self) -> None: ...


class ReplayBackend(Protocol):
    """What ``rig replay`` needs of the package that serves a recording to the real drivers."""

    def open_recording(
        self,
        devices: Mapping[str, RecordedDeviceData],
        transcripts: TranscriptFactory,
        frames: Callable[[int, int, str | None], bytes],
    ) -> ReplayStation: ...

    def mismatch_of(self, error: BaseException) -> ReplayMismatchView | None: ...


def replay_backend() -> ReplayBackend:
    """The backend registered under :data:`REPLAY_ENTRY_POINTS`.

    Raises
    ------
    StationUnavailable
        This installation has none (replay needs the ``mocks`` package of spectral-rig).
    """
    found = sorted(entry_points(group=REPLAY_ENTRY_POINTS), key=lambda entry: entry.name)
    if not found:
        raise StationUnavailable(
            f"session replay is not part of this installation (no {REPLAY_ENTRY_POINTS!r} entry "
            "point: install spectral-rig with its mocks package)"
        )
    backend: ReplayBackend = found[0].load()()
    return backend


@dataclass(frozen=True)
class RecordedRun:
    """One run of a session (a capture, or a resume of it): its start, records and transcripts."""

    number: int
    start: StartRecord
    config: RigConfig
    records: list[Record]
    transcripts: dict[DeviceRole, list[TranscriptEntry]]
    frames: list[FileRecord]
    killed: bool = False
    """The run has no stop record: it was killed, and is replayed up to its last record."""


@dataclass(frozen=True)
class Recording:
    """A verified session, ready to replay: its runs in order (more than one once resumed)."""

    session: Session
    runs: list[RecordedRun]


@dataclass(frozen=True)
class ReplayOutcome:
    """How a replay went.

    ``mismatch`` is the diff when the rig diverged from the recording (``None`` when it did not);
    ``difference`` the first record where the logs differ after masking (``None``: identical).
    """

    source: Path
    run: RunOutcome
    mismatch: str | None
    difference: str | None

    @property
    def identical(self) -> bool:
        return self.mismatch is None and self.difference is None


# ------------------------------------------------------------------------------------ reading


def _first_validation_error(exc: ValidationError) -> str:
    return first_validation_problem(exc.errors(), "config")


def load_recording(path: Path) -> Recording:
    """Read, validate and verify a session for replay.

    Raises
    ------
    SessionFormatError
        The directory is not a valid session (bad record, unsafe path).
    ReplayRefused
        A file differs from its record, the configuration or plan is invalid, or a run's
        transcript is missing or unreadable.
    """
    try:
        session = read_session(path)
    except UnicodeDecodeError:
        raise SessionFormatError(f"{path}: the log is not UTF-8") from None
    start = session.start
    if start is None:
        raise ReplayRefused(f"{path}: the log has no start record")
    if any(
        isinstance(record, InterruptionRecord) and record.action == "stop-now"
        for record in session.records
    ):
        raise ReplayRefused(
            f"{path}: a second signal stopped the run in the middle of a step; such a run cannot "
            "be reproduced exchange by exchange"
        )
    problems = session.verify_files()
    if problems:
        raise ReplayRefused(f"{path}: {problems[0]} ({len(problems)} file problem(s))")
    try:
        build_plan(start.plan.name, start.plan.args).close()
    except ValidationError as exc:
        raise ReplayRefused(
            f"{path}: the recorded configuration or plan is invalid: {_first_validation_error(exc)}"
        ) from None
    except PlanProtocolError as exc:
        raise ReplayRefused(f"{path}: the recorded plan: {exc}") from None
    numbers = sorted({record.run for record in session.records})
    known = {transcript_path(role, number) for role in ROLES for number in numbers}
    for record in session.files():
        if record.role == "transcript" and record.path not in known:
            raise ReplayRefused(f"{path}: unexpected transcript {record.path}")
    runs = [_recorded_run(path, session, number) for number in numbers]
    return Recording(session, runs)


def _recorded_run(path: Path, session: Session, number: int) -> RecordedRun:
    """Run ``number``'s start, records, transcripts and frames (:class:`ReplayRefused` if any is
    missing: a run whose devices never opened, or a crashed run, cannot be replayed)."""
    records = [record for record in session.records if record.run == number]
    start = records[0] if records else None
    if not isinstance(start, StartRecord):
        raise ReplayRefused(f"{path}: run {number} has no start record")
    try:
        config = RigConfig.model_validate(start.config)
    except ValidationError as exc:
        raise ReplayRefused(
            f"{path}: the recorded configuration or plan is invalid: {_first_validation_error(exc)}"
        ) from None
    missing = [role for role in ROLES if role not in start.devices]
    if missing:
        raise ReplayRefused(
            f"{path}: run {number}'s start record identifies no {', '.join(missing)} (the devices "
            "never opened); there is nothing to replay"
        )
    stops = [record for record in records if isinstance(record, StopRecord)]
    if stops and stops[-1].reason == "session_write":
        raise ReplayRefused(
            f"{path}: run {number} stopped because the session could not be written "
            f"({stops[-1].message}); its recording ends where the disk failed, so it cannot be "
            "reproduced exchange by exchange"
        )
    # A run's transcripts are acknowledged by the run itself, or by the resume after it was killed.
    names = {transcript_path(role, number): role for role in ROLES}
    transcripts: dict[DeviceRole, list[TranscriptEntry]] = {}
    for record in session.files():
        role = names.get(record.path)
        if record.role == "transcript" and role is not None:
            data = session.file_path(record.path).read_bytes()
            transcripts[role] = parse_transcript(data, f"{path}: {record.path}")
    absent = [role for role in ROLES if role not in transcripts]
    if absent:
        raise ReplayRefused(
            f"{path}: no acknowledged transcript of run {number} for {', '.join(absent)} (a killed "
            "run's transcripts are acknowledged when the session is resumed: rig resume it "
            "first); cannot replay"
        )
    # Every frame the run downloaded, discarded ones too (a stale frame was downloaded before
    # the rig saw it was stale); each is checked against its sha256 when it is served.
    frames = [
        record
        for record in records
        if isinstance(record, FileRecord) and record.role in ("frame", "dark")
    ]
    return RecordedRun(number, start, config, records, transcripts, frames, killed=not stops)


# ------------------------------------------------------------------------------------ running


class _Timeline:
    """Keeps the replay on the recorded timeline, step by step: its clock and its interruption.

    When a step starts, the clock jumps to where the recording says the step *ended* (a wait: where
    it started; the wait itself advances it), so every time a plan sees (a spectrum's, a switch's)
    is as recorded and time-dependent branches go the same way. The clock never goes back.

    A run that was stopped by a signal (one Ctrl-C: finish the step, then stop) receives the same
    signal during its last recorded step: after it, or at its start when it was a wait that the
    signal cut short.
    """

    def __init__(
        self, inner: ProgressReporter, records: Sequence[Record], interrupts: InterruptController
    ) -> None:
        self.inner = inner
        self.clock: Any = None  # the station's, once it is opened (attach)
        self.current_key = "(opening the devices)"
        self._t0 = 0.0
        self._current: AnyStep | None = None
        self._steps = {r.key: r for r in records if isinstance(r, StepRecord)}
        self._interrupts = interrupts
        signals = [r.signal for r in records if isinstance(r, InterruptionRecord)]
        self._signal = signals[0] if signals else None
        last = next((r for r in reversed(records) if isinstance(r, StepRecord)), None)
        self._last_key = last.key if last is not None else None
        self._cut_short = last is not None and (last.result or {}).get("completed") is False

    def attach(self, clock: Any) -> None:
        """The clock of the station, opened after this timeline was made."""
        self.clock = clock
        self._t0 = clock.now()

    def _receive_signal(self) -> None:
        assert self._signal is not None
        self._interrupts.received.append(
            ReceivedSignal(self._signal, time.monotonic(), "finish-step")
        )

    def start(self, estimate: DryRunReport | None) -> None:
        self.current_key = "(identifying the devices)"
        if self._signal is not None and self._last_key is None:
            self._receive_signal()
        self.inner.start(estimate)

    def step_started(self, step: AnyStep) -> None:
        self.current_key = step.key
        self._current = step
        recorded = self._steps.get(step.key)
        if recorded is not None:  # the runner reads the step's start after this
            self._advance_to(self._t0 + recorded.started_s)
        if self._signal is not None and step.key == self._last_key and self._cut_short:
            self._receive_signal()
        self.inner.step_started(step)

    def step_hook(self, key: str) -> None:
        """The station's hook, called once the runner has the step's start: on to its recorded end
        (a wait advances the clock itself), so the step takes its recorded time and the devices
        answer at the times they did. The next run's resume reads those durations."""
        recorded = self._steps.get(key)
        if recorded is not None and not isinstance(self._current, Wait):
            self._advance_to(self._t0 + recorded.started_s + recorded.duration_s)

    def _advance_to(self, target: float) -> None:
        ahead_s = target - self.clock.now()
        if ahead_s > 0:
            self.clock.advance(ahead_s)

    def step_done(self, step: AnyStep, result: StepResult) -> None:
        if self._signal is not None and step.key == self._last_key and not self._cut_short:
            self._receive_signal()
        self.inner.step_done(step, result)

    def message(self, text: str) -> None:
        self.inner.message(text)

    def finish(self, completed: bool) -> None:
        self.current_key = "(closing the devices)"
        self.inner.finish(completed)


def _frame_source(
    recording: Recording, run: RecordedRun
) -> Callable[[int, int, str | None], bytes]:
    """Serves the run's n-th download from the session's frame files (by sha256 when recorded)."""
    by_sha256 = {record.sha256: record for each in recording.runs for record in each.frames}

    def frame(number: int, size: int, sha256: str | None) -> bytes:
        if sha256 is not None:
            record = by_sha256.get(sha256)
        else:
            record = run.frames[number] if number < len(run.frames) else None
        if record is None or record.size != size:
            raise ReplayDiverged(
                f"download {number + 1} of the camera ({size} bytes, sha256 {sha256}) is not a "
                "frame the session acknowledges"
            )
        data = recording.session.file_path(record.path).read_bytes()
        if hashlib.sha256(data).hexdigest() != record.sha256:
            raise ReplayRefused(f"{record.path} changed while it was replayed")
        return data

    return frame


def _recorded_devices(run: RecordedRun) -> dict[str, RecordedDeviceData]:
    devices = run.config.devices
    timeouts = {
        "relays": devices.relays.timeout_s,
        "spectrometer": devices.spectrometer.timeout_s,
        "camera": devices.camera.timeout_s,
    }
    return {
        role: RecordedDeviceData(
            identity=run.start.devices[role].model_dump(),
            entries=run.transcripts[role],
            timeout_s=timeouts[role],
            download_timeout_s=devices.camera.download_timeout_s,
            measure_timeout_s=(
                devices.spectrometer.measure_timeout_s if role == "spectrometer" else None
            ),
        )
        for role in ROLES
    }


def _mismatch_text(mismatch: ReplayMismatchView, step_key: str, run: int) -> str:
    return "\n".join(
        [
            f"step {step_key}: {mismatch.role}: {mismatch.problem}",
            f"  at {transcript_path(mismatch.role, run)} line {mismatch.index}"
            if mismatch.index is not None
            else "  after the last recorded entry",
            f"  expected: {mismatch.describe(mismatch.expected)}",
            f"  sent:     {mismatch.describe(mismatch.sent)}",
        ]
    )


def default_replay_dir(source: Path) -> Path:
    """``<session>-replay`` next to the session."""
    resolved = source.resolve()
    return resolved.parent / f"{resolved.name}-replay"


def replay_session(
    source: Path,
    out: Path | None = None,
    *,
    progress: ProgressReporter | None = None,
    interrupts: InterruptController | None = None,
) -> ReplayOutcome:
    """Replay the session at ``source`` into the new session directory ``out``.

    Parameters
    ----------
    source
        The recorded session.
    out
        The replay's session directory (must not exist; default :func:`default_replay_dir`).
    progress, interrupts
        Passed to the runner.

    Raises
    ------
    SessionFormatError, ReplayRefused
        The session cannot be replayed (see :func:`load_recording`); nothing is written.
    rig.errors.SessionWriteError
        ``out`` exists or cannot be created.
    """
    recording = load_recording(source)
    target = out if out is not None else default_replay_dir(source)
    if target.resolve().is_relative_to(source.resolve()):
        raise ReplayRefused(
            f"{target} lies inside the recorded session {source}; replay never writes there"
        )
    backend = replay_backend()
    interrupts = interrupts or InterruptController()
    progress = progress or SilentProgress()
    first, *resumed = recording.runs
    run, mismatch = _replay_run(recording, first, target, backend, progress, interrupts)
    for later in resumed:
        if mismatch is not None:
            break
        # A resume is a new process: a signal the previous run received is not its own.
        fresh = InterruptController()
        run, mismatch = _replay_run(recording, later, target, backend, progress, fresh)
    difference = None
    if mismatch is None:
        difference = compare_logs(recording.session, read_session(run.session))
    return ReplayOutcome(source, run, mismatch, difference)


def _declined(run: RecordedRun) -> frozenset[str]:
    """The manual actions the run's operator declined (their steps failed so)."""
    return frozenset(
        record.key
        for record in run.records
        if isinstance(record, StepRecord)
        and record.status == "failed"
        and record.error is not None
        and record.error.reason == OperatorDeclined.reason
    )


def _station(bench: ReplayStation, timeline: _Timeline, declined: frozenset[str]) -> Station:
    return Station(
        bench.spectrometer,
        bench.camera,
        bench.relays,
        bench.clock,
        RawFrameAnalyzer(),
        on_close=[bench.close],
        step_hook=timeline.step_hook,
        # The recording's aims were done (or declined) by a person; replaying them asks nobody
        # (the log comparison checks that the replay aimed where the recording did).
        operator=ScriptedOperator(decline=declined),
    )


@dataclass
class _RunCheck:
    """The replayed run's bench, and where a killed run's recording ended (the mismatches found
    by then are the only ones that count)."""

    bench: ReplayStation | None = None
    cut: int | None = None

    def kill_point(self) -> None:
        if self.bench is not None:
            self.cut = len(self.bench.mismatches.found)

    def mismatch(self, run: RecordedRun) -> str | None:
        bench = self.bench
        if bench is None:
            return None
        if not run.killed:
            bench.finish()  # unused recorded entries count as mismatches too
        found = list(bench.mismatches.found)
        counted = found if self.cut is None else found[: self.cut]
        if not counted:
            return None
        first = counted[0]
        return _mismatch_text(first, bench.mismatches.where(first), run.number)


def _replay_run(
    recording: Recording,
    run: RecordedRun,
    target: Path,
    backend: ReplayBackend,
    progress: ProgressReporter,
    interrupts: InterruptController,
) -> tuple[RunOutcome, str | None]:
    """One run on a station serving that run's transcripts, into the new session ``target``.

    Run 1 drives the recorded plan (:func:`rig.capture.run_on_station`); a later run is
    ``rig resume`` of the replay (:func:`rig.resume.run_resume`), which decides from the replay's
    own log what to reuse, as it decided from the original's. A killed run's writer stops after
    as many records as the recording has.
    """
    check = _RunCheck()
    timeline = _Timeline(progress, run.records, interrupts)

    def builder(config: RigConfig, transcripts: TranscriptFactory) -> Station:
        try:
            bench = backend.open_recording(
                _recorded_devices(run), transcripts, _frame_source(recording, run)
            )
        except (DeviceError, ValueError) as exc:
            mismatch = backend.mismatch_of(exc)
            if mismatch is not None:
                raise ReplayDiverged(
                    _mismatch_text(mismatch, "(opening the devices)", run.number)
                ) from None
            raise ReplayRefused(
                f"the recorded devices cannot be opened for replay: {exc}"
            ) from None
        check.bench = bench
        timeline.attach(bench.clock)
        bench.mismatches.context = lambda: timeline.current_key
        return _station(bench, timeline, _declined(run))

    def on_session(writer: SessionWriter) -> None:
        if run.killed:
            writer.record_limit = len(run.records)
            writer.on_kill = check.kill_point

    options = RunOptions(timeline, interrupts, REPLAY_RETRY, builder, on_session)
    if run.number == 1:
        outcome = run_on_station(
            run.config,
            functools.partial(SessionWriter, target),
            build_plan(run.start.plan.name, run.start.plan.args),
            run.start.plan,
            options,
        )
    else:
        outcome = run_resume(
            target,
            run.config,
            progress=timeline,
            interrupts=interrupts,
            retry=REPLAY_RETRY,
            builder=builder,
            on_session=on_session,
        )
    return outcome, check.mismatch(run)


# ------------------------------------------------------------------------------------ comparing


def _masked(value: object, paths: tuple[str, ...]) -> object:
    if isinstance(value, dict):
        return {
            key: MASK if key in MASKED_KEYS else _masked(item, paths) for key, item in value.items()
        }
    if isinstance(value, list):
        return [_masked(item, paths) for item in value]
    if isinstance(value, str):
        for path in paths:
            value = value.replace(path, "<session>")
    return value


def masked_record(record: Record, session_path: Path) -> dict[str, Any]:
    """A record as compared: times, ids, wall clocks and the session's own path masked.

    A transcript's size and sha256 are masked too: its entries carry wall-clock timestamps.
    """
    data = json.loads(record.model_dump_json())
    if isinstance(record, FileRecord) and record.role == "transcript":
        data["size"] = data["sha256"] = MASK
    paths = (str(session_path.resolve()), str(session_path))
    masked = _masked(data, paths)
    assert isinstance(masked, dict)
    return masked


def compare_logs(original: Session, replay: Session) -> str | None:
    """The first record where the two logs differ after masking, described; ``None`` if identical."""
    for index in range(max(len(original.records), len(replay.records))):
        left = (
            masked_record(original.records[index], original.path)
            if index < len(original.records)
            else None
        )
        right = (
            masked_record(replay.records[index], replay.path)
            if index < len(replay.records)
            else None
        )
        if left != right:
            return "\n".join(
                [
                    f"record {index} (line {index + 1}) differs:",
                    f"  original: {json.dumps(left, sort_keys=True)}",
                    f"  replay:   {json.dumps(right, sort_keys=True)}",
                ]
            )
    return None
