"""The runner: the only code that touches devices. It executes a plan's steps and records everything.

For each step the runner calls the device in that device's worker thread under a deadline
(:mod:`rig.workers`), retries with bounded exponential backoff when both the step is safe to repeat
and the error says a retry may succeed (``DeviceError.retryable``), stores files and spectra in the
session, writes one log record, and sends the result back into the plan. Whatever happens — success,
a device or plan failure, Ctrl-C, SIGTERM, a second Ctrl-C, a bug — the ``finally`` switches every
lamp off (and reads the board back), closes the devices, acknowledges the transcripts, and writes
the stop record with a machine-readable reason as the run's last record.

Time (timestamps, waits, backoff) comes from the station's clock, so on the digital twin a warm-up
of minutes takes no wall time; device deadlines are wall-clock.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import math
import re
import traceback
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal, TypeVar

import numpy as np

from calib.core.checksums import FileDigest, file_digest
from calib.core.errors import SpectrumError
from calib.core.software import current_software
from calib.core.spectra import MultiSpectrum, Spectrum, read_spectrum_csv, write_csv
from drivers.base import (
    DarkCorrecting,
    DeviceError,
    DeviceIdentity,
    RelayBoard,
    SpectrumReading,
    StateMismatch,
)
from drivers.local_files import NO_SPACE_ERRNOS, UnsafeLocalPath
from drivers.spectrometer import longest_measure_s
from drivers.spectrometer.ocean import integration_ladder_ms
from rig.analysis import FrameStats
from rig.config import RigConfig, SeabreezeSpectrometerConfig
from rig.dryrun import DryRunReport
from rig.errors import (
    FrameAnalysisError,
    InvalidReading,
    LampsNotOff,
    PlanProtocolError,
    RigError,
    SessionWriteError,
    StaleReading,
)
from rig.interrupts import HaltRequested, InterruptController
from rig.operator import ManualAction
from rig.plan import Plan
from rig.progress import ProgressReporter, SilentProgress
from rig.records import (
    FRAMES_DIR,
    DeviceRecord,
    DiscardRecord,
    ErrorInfo,
    ExitStatus,
    FileRecord,
    InterruptionRecord,
    PlanInfo,
    RetryRecord,
    SoftwareInfo,
    StartRecord,
    StepRecord,
    StopRecord,
)
from rig.session import STOP_TEXT_CHARS, SessionWriter
from rig.station_devices import Station
from rig.steps import (
    AimSpectrometer,
    AllLampsOff,
    AnyStep,
    CameraReady,
    Capture,
    ConfigureCamera,
    ConfigureSpectrometer,
    DarkFrame,
    DarkMeasured,
    DeviceRole,
    ExposureSet,
    FrameCaptured,
    KeepLampTimeline,
    MeasureBeam,
    MeasureDark,
    MeasureSpectrum,
    RelayState,
    SetExposure,
    SettingReadBack,
    SpectrometerAimed,
    SpectrometerReady,
    SpectrumMeasured,
    Step,
    StepHandlers,
    StepResult,
    SwitchLamp,
    Wait,
    Waited,
    interpret,
)
from rig.workers import DeviceWorker

T = TypeVar("T")

#: Longest single sleep while waiting, so a stop request ends a wait promptly.
WAIT_SLICE_S = 0.25
#: How long closing a device may wait after a second interrupt (it is queued behind any exchange).
HALT_CLOSE_TIMEOUT_S = 0.2
_SUFFIX = re.compile(r"^\.[A-Za-z0-9]{1,8}$")
DEVICE_ROLES: tuple[DeviceRole, ...] = ("relays", "camera", "spectrometer")
#: ``OSError`` numbers that stop a run as ``session_write``: the disk is full or failing.
SESSION_WRITE_ERRNOS = NO_SPACE_ERRNOS | {errno.EIO, errno.EROFS}
#: Readings a step takes at most while the first reading after a settings change is stale.
STALE_READING_ATTEMPTS = 3
#: Relative difference above which a reading's own exposure shows a setting other than the new one.
STALE_EXPOSURE_RTOL = 0.02


def dark_duration_s(config: RigConfig) -> float:
    """How long the spectrometer's dark takes: every rung of its integration ladder (a fixed
    ``spectrum.exposure_ms`` alone), each averaged, plus the stale scan after each change."""
    spectrometer = config.devices.spectrometer
    if not isinstance(spectrometer, SeabreezeSpectrometerConfig):
        return config.dry_run.spectrum_measure_s
    fixed_ms = config.spectrum.exposure_ms
    rungs = (
        (fixed_ms,)
        if fixed_ms is not None
        else integration_ladder_ms(spectrometer.integration_min_ms, spectrometer.integration_max_ms)
    )
    return math.fsum(rungs) * (spectrometer.averages + 1) / 1000.0


@dataclass(frozen=True)
class RetryPolicy:
    """Bounded exponential backoff: ``initial_s``, ×``factor`` per attempt, at most ``max_s``."""

    max_attempts: int = 3
    initial_s: float = 0.5
    factor: float = 2.0
    max_s: float = 5.0

    def backoff_s(self, attempt: int) -> float:
        """The pause after failed attempt number ``attempt`` (from 1)."""
        return float(min(self.max_s, self.initial_s * self.factor ** (attempt - 1)))


@dataclass(frozen=True)
class StepTimeouts:
    """Wall-clock deadlines (s) of device calls; a capture gets its exposure time on top."""

    relays_s: float
    spectrometer_s: float
    camera_s: float
    capture_extra_s: float
    dark_s: float = 0.0

    @classmethod
    def from_config(cls, config: RigConfig) -> StepTimeouts:
        # A driver enforces its own per-exchange deadline; the runner's covers a whole call, which
        # may be several exchanges (switch + read back), so it allows a few of them plus a margin.
        # A measurement is the spectrometer's longest call: its deadline is the driver's own worst
        # case, so a silent instrument ends in the driver's retryable timeout, not here.
        devices = config.devices
        spectrometer = devices.spectrometer
        model = devices.spectrometer_model
        longest = longest_measure_s(
            model,
            timeout_s=spectrometer.timeout_s,
            measure_timeout_s=spectrometer.measure_timeout_s,
        )
        dark_s = dark_duration_s(config) * 2.0 + 10.0 * spectrometer.timeout_s
        return cls(
            relays_s=4 * devices.relays.timeout_s + 1.0,
            spectrometer_s=max(2 * spectrometer.timeout_s, longest) + 1.0,
            camera_s=2 * devices.camera.timeout_s + 1.0,
            capture_extra_s=devices.camera.download_timeout_s + devices.camera.timeout_s,
            dark_s=max(longest, dark_s) + 1.0,
        )


@dataclass(frozen=True)
class RunOutcome:
    """How a run ended.

    ``exit_code`` follows the ``rig`` command's convention: 0 success, 1 device/internal failure,
    2 a limit or input problem, 128 + signal number when interrupted (130 Ctrl-C, 143 SIGTERM).
    """

    session: Path
    exit_status: ExitStatus
    reason: str
    message: str
    lamps_off: bool
    failed_key: str | None = None
    signal: str | None = None
    error_exit_code: int = 1

    @property
    def exit_code(self) -> int:
        if self.exit_status == "success":
            return 0
        if self.exit_status == "abort":
            return {"SIGINT": 130, "SIGTERM": 143, "SIGHUP": 129}.get(self.signal or "", 130)
        return self.error_exit_code


def _shortened(text: str) -> str:
    """At most :data:`rig.session.STOP_TEXT_CHARS` characters, the end kept (where a traceback
    names the failing line)."""
    if len(text) <= STOP_TEXT_CHARS:
        return text
    return "…" + text[-(STOP_TEXT_CHARS - 1) :]


def _small(error: ErrorInfo) -> ErrorInfo:
    """``error`` with its message and traceback shortened for the stop record, which must fit in
    the room reserved for it on a full disk."""
    traceback_text = None if error.traceback is None else _shortened(error.traceback)
    return error.model_copy(
        update={"message": _shortened(error.message), "traceback": traceback_text}
    )


@dataclass(frozen=True)
class _DeferredStore:
    """A step whose storing runs in the journal thread while the camera takes the next frame
    (:meth:`Runner._settle` waits for it): a frame or a spectrum (sync, rename, file and step
    records), or the step record alone of a step that ran while the journal was still storing."""

    step: Step
    attempts: int
    started_s: float
    future: Future[None]


#: The steps that go on while the journal thread still stores earlier ones: they write nothing
#: to the session before :meth:`Runner._settle` (their own storing and records queue behind).
_OVERLAPPING = (Capture, DarkFrame, SetExposure, SwitchLamp, Wait, MeasureSpectrum)


class _Skipped(Exception):
    """A journal job not done because an earlier one failed (the log ends before it)."""


class StopRequested(Exception):
    """Raised between steps after a first interrupt."""

    def __init__(self, signal_name: str) -> None:
        self.signal_name = signal_name
        super().__init__(f"stopped after the current step ({signal_name})")


def software_info() -> SoftwareInfo:
    """:func:`calib.core.software.current_software` as the start record's ``software``."""
    return SoftwareInfo(**current_software().to_dict())


def as_session_error(exc: Exception) -> Exception:
    """``exc``, or a :class:`SessionWriteError` when it says the disk is full or failing (an
    ``OSError`` with ``ENOSPC``, ``EDQUOT``, ``EFBIG``, ``EIO`` or ``EROFS`` from wherever it came:
    the session writer, a driver storing a download, the twin's state file)."""
    if isinstance(exc, OSError) and exc.errno in SESSION_WRITE_ERRNOS:
        return SessionWriteError(f"cannot write: {exc}")
    return exc


def error_info(exc: BaseException, *, with_traceback: bool = False) -> ErrorInfo:
    """An exception as a log record's error: its ``reason`` (or ``internal``), type and message."""
    reason = getattr(exc, "reason", None)
    if not isinstance(reason, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", reason):
        reason = "internal"
    return ErrorInfo(
        reason=reason,
        type=f"{type(exc).__module__}.{type(exc).__qualname__}",
        message=str(exc),
        device=getattr(exc, "device", None) if isinstance(exc, DeviceError) else None,
        retryable=bool(getattr(exc, "retryable", False)),
        traceback="".join(traceback.format_exception(exc)) if with_traceback else None,
    )


def switch_everything_off(
    relays: RelayBoard, worker: DeviceWorker, timeout_s: float
) -> tuple[bool, str]:
    """Switch every relay channel off (one by one if "all off" fails) and read the board back.

    Every call runs in ``worker`` under ``timeout_s``. Returns whether the board read back all off,
    and what went wrong when it did not.
    """
    problems = []
    try:
        worker.call("switch all off", relays.all_off, timeout_s)
    except Exception as exc:
        problems.append(f"all off failed: {exc}")
        n_channels = 0
        with contextlib.suppress(Exception):
            n_channels = int(relays.channels)
        for channel in range(1, n_channels + 1):
            try:
                worker.call(
                    f"switch channel {channel} off",
                    functools.partial(relays.set, channel, False),
                    timeout_s,
                )
            except Exception as channel_exc:
                problems.append(f"channel {channel}: {channel_exc}")
    try:
        state = worker.call("read state", relays.state, timeout_s)
    except Exception as exc:
        problems.append(f"reading the board back failed: {exc}")
        state = None
    confirmed = state is not None and not any(state)
    if confirmed:
        return True, ""
    return False, "; ".join(problems) if problems else f"board reads {state}"


def switch_off_now(relays: RelayBoard, timeout_s: float) -> bool:
    """:func:`switch_everything_off` outside a run (while the devices open), on a worker of its
    own; ``True`` when the board read back all off. Never raises."""
    worker = DeviceWorker("relays", "relay board")
    try:
        return switch_everything_off(relays, worker, timeout_s)[0]
    finally:
        worker.close(timeout_s=0.1)


class Runner(StepHandlers[StepResult]):
    """Executes plans on a station, recording into a session.

    The runner is the vocabulary's interpreter on devices: one :class:`rig.steps.StepHandlers`
    method per step type, reached through :func:`rig.steps.interpret`.

    Parameters
    ----------
    station
        Open devices, their clock and the frame analyser.
    session
        Where everything is recorded; the runner makes its writes interrupt-safe.
    timeouts
        Deadlines of device calls.
    retry
        Backoff for retryable errors of retry-safe steps.
    progress
        Where progress goes (silent by default).
    interrupts
        The signal handling (a fresh controller by default; installed only in the main thread).
    """

    def __init__(
        self,
        station: Station,
        session: SessionWriter,
        *,
        timeouts: StepTimeouts,
        retry: RetryPolicy | None = None,
        progress: ProgressReporter | None = None,
        interrupts: InterruptController | None = None,
    ) -> None:
        self.station = station
        self.session = session
        self.timeouts = timeouts
        self.retry = retry or RetryPolicy()
        self.progress: ProgressReporter = progress or SilentProgress()
        self.interrupts = interrupts or InterruptController()
        self.session.guard = self.interrupts.critical
        self.clock = station.clock
        self._workers = {role: DeviceWorker(role, role) for role in DEVICE_ROLES}
        #: Stores frames and spectra (sync, rename, records) while the camera takes the next
        #: frame; the journal stays in step order because every other session write waits for it.
        self._journal = ThreadPoolExecutor(1, thread_name_prefix="rig-journal")
        self._pending: list[_DeferredStore] = []
        self._journal_failed = False
        #: The storing a handler left to the journal thread (set last thing before it returns),
        #: and the temporary it stores.
        self._store_later: tuple[Callable[[], None], Path] | None = None
        #: A deferred store that failed: its step key and error (the run's failure).
        self._late: tuple[str, BaseException] | None = None
        self._t0 = self.clock.now()
        self._seen_keys: set[str] = set()
        self._counts = {
            "steps": 0,
            "retries": 0,
            "frames": 0,
            "dark_frames": 0,
            "spectra": 0,
            "discarded": 0,
        }
        self._started = False
        self._identities: dict[str, DeviceIdentity] = {}
        self._plan_info = PlanInfo(name="unknown", args={})
        self._config: dict[str, Any] = {}
        #: Relay channels (from 1) that read as on when the run opened the board.
        self.relays_found_on: tuple[int, ...] = ()
        #: The step of every frame acknowledged so far, by sha256: a copy of another step's frame
        #: is never a new frame (the same step taken again may give the same bytes on the twin).
        self.frame_digests: dict[str, str] = {}
        # The first reading after a settings change is checked against the new setting.
        self._camera_changed = True
        self._spectrometer_exposure_ms: float | None = None
        #: Where the spectrometer looks (an aim target, :func:`rig.steps.beam_target`): at its
        #: usual target until an operator re-aims it. ``None``: unknown (a resumed run whose
        #: session re-aimed it; its plan asks the operator again before measuring).
        self.spectrometer_aim: str | None = "lamp"

    # ------------------------------------------------------------------------------ the run

    def run(
        self,
        plan: Plan,
        plan_info: PlanInfo,
        config: dict[str, Any],
        estimate: DryRunReport | None = None,
        *,
        after_start: Callable[[], None] | None = None,
    ) -> RunOutcome:
        """Run ``plan`` to the end, to a failure or to an interrupt; lamps end off in every case.

        Before anything else the relays are read and switched off (a lamp left on by a killed
        process goes off first). ``after_start`` writes records that follow the start record (the
        resume record).
        """
        installed = self.interrupts.install()
        self._t0 = self.clock.now()
        self._plan_info, self._config = plan_info, config
        status: ExitStatus = "success"
        reason, message = "completed", "the plan completed"
        failure: BaseException | None = None
        failed_key: str | None = None
        signal_name: str | None = None
        current: AnyStep | None = None
        try:
            try:
                self._lamps_off_first()
                self._identify()
                self._write_start()
                if after_start is not None:
                    after_start()
                self.progress.start(estimate)
                current = next(plan, None)
                while current is not None:
                    self._check_stop()
                    result = self._execute(current)
                    try:
                        current = plan.send(result)
                    except StopIteration:
                        current = None
                self._settle()  # what the journal still stores is stored before the run counts as done
            except StopRequested as exc:
                status, reason, message = "abort", "interrupted", str(exc)
                signal_name = exc.signal_name
            except Exception as exc:
                failure = as_session_error(exc)
                status, reason = "fail", error_info(failure).reason
                message = (
                    str(failure)
                    if isinstance(failure, DeviceError | RigError)
                    else f"internal error: {type(failure).__name__}: {failure}"
                )
                if self._late is not None and self._is_late(exc):
                    failed_key = self._late[0]
                else:
                    failed_key = getattr(failure, "key", None) or (current.key if current else None)
        except HaltRequested as exc:  # a second signal, during a step or while handling the first
            status, reason, message = "abort", "halted", str(exc)
            signal_name = self.interrupts.stop_requested or exc.signal_name
        finally:
            self.interrupts.enter_cleanup()
            lamps_off = self._switch_everything_off()
            self._settle_in_cleanup()
            with contextlib.suppress(Exception):
                plan.close()
            self.station.close(self._close_device)
            self._write_stop(status, reason, message, failed_key, failure, lamps_off)
            self.progress.finish(status == "success")
            self._close_workers()
            if installed:
                self.interrupts.uninstall()
        return RunOutcome(
            session=self.session.path,
            exit_status=status,
            reason=reason,
            message=message,
            lamps_off=lamps_off,
            failed_key=failed_key,
            signal=signal_name,
            error_exit_code=getattr(failure, "exit_code", 1),
        )

    def _is_late(self, exc: BaseException) -> bool:
        """Whether ``exc`` is an earlier step's deferred storing failing (not this step's)."""
        return self._late is not None and self._late[1] is exc

    def _settle(self) -> None:
        """Wait for what the journal still stores; a failure is recorded on its own step (a
        ``failed`` step record) and raised here, before anything else is written."""
        pending, self._pending = self._pending, []
        first: tuple[_DeferredStore, Exception] | None = None
        for item in pending:
            try:
                item.future.result()
            except _Skipped:
                pass
            except Exception as exc:
                first = first or (item, exc)
        if first is not None:
            failed, error = first
            self._late = (failed.step.key, error)
            self._record_failure(failed.step, error, failed.attempts, failed.started_s)
            raise error

    def _settle_in_cleanup(self) -> None:
        """:meth:`_settle` when the run is ending anyway (its failure is recorded, not raised),
        then stop the journal thread."""
        with contextlib.suppress(BaseException):  # recorded on its step; the cleanup goes on
            self._settle()
        self._journal.shutdown(wait=True)

    def _check_stop(self) -> None:
        signal_name = self.interrupts.stop_requested
        if signal_name is not None:
            raise StopRequested(signal_name)

    def _now_s(self) -> float:
        return self.clock.now() - self._t0

    def _call(self, role: DeviceRole, what: str, function: Callable[[], T], timeout_s: float) -> T:
        return self._workers[role].call(what, function, timeout_s)

    def _lamps_off_first(self) -> None:
        """Read which relays are on (a lamp a killed run left on), then switch them all off."""
        relays = self.station.relays
        with contextlib.suppress(DeviceError):
            state = self._call("relays", "read state", relays.state, self.timeouts.relays_s)
            self.relays_found_on = tuple(i + 1 for i, on in enumerate(state) if on)
        self._call("relays", "switch all off", relays.all_off, self.timeouts.relays_s)

    def _identify(self) -> None:
        for role in DEVICE_ROLES:
            device = self.station.device(role)
            identity = self._call(role, "identify", device.identify, self._timeout(role))
            self._identities[role] = identity
            self._workers[role].device = identity.describe()

    @property
    def identities(self) -> Mapping[str, DeviceIdentity]:
        """Who each device said it was when this run opened it (filled before the start record)."""
        return MappingProxyType(self._identities)

    def _timeout(self, role: DeviceRole) -> float:
        return {
            "relays": self.timeouts.relays_s,
            "spectrometer": self.timeouts.spectrometer_s,
            "camera": self.timeouts.camera_s,
        }[role]

    def _write_start(self) -> None:
        """The start record: config, software, plan and the devices identified so far."""
        self.session.write(
            StartRecord,
            session_id=self.session.session_id,
            wall_time=datetime.now(UTC),
            software=software_info(),
            plan=self._plan_info,
            config=self._config,
            devices={role: DeviceRecord(**asdict(i)) for role, i in self._identities.items()},
            clock=type(self.clock).__name__,
        )
        self._started = True

    # ------------------------------------------------------------------------------ one step

    def _execute(self, step: AnyStep) -> StepResult:
        key = step.key
        if key in self._seen_keys:
            raise PlanProtocolError(f"the plan yielded the step key {key!r} twice")
        self._seen_keys.add(key)
        if not isinstance(step, _OVERLAPPING):
            # What the journal still stores is waited for first (the journal stays in step order).
            self._settle()
        self.progress.step_started(step)
        started_s = self._now_s()
        attempt = 1
        while True:
            try:
                if self.station.step_hook is not None:
                    self.station.step_hook(key)
                result = interpret(step, self)
                break
            except DeviceError as exc:
                if self._is_late(exc):
                    raise
                if (
                    step.retry_safe
                    and exc.retryable
                    and attempt < self.retry.max_attempts
                    and self.interrupts.stop_requested is None
                ):
                    backoff_s = self.retry.backoff_s(attempt)
                    self._settle()
                    self.session.write(
                        RetryRecord,
                        key=key,
                        attempt=attempt,
                        error=error_info(exc),
                        backoff_s=backoff_s,
                    )
                    self._counts["retries"] += 1
                    self.progress.message(
                        f"{key}: {exc} — attempt {attempt} failed, retrying in {backoff_s:g} s"
                    )
                    self._sleep(backoff_s)
                    attempt += 1
                    continue
                self._record_failure(step, exc, attempt, started_s)
                raise
            except RigError as exc:
                if not self._is_late(exc):
                    self._record_failure(step, exc, attempt, started_s)
                raise
        store, self._store_later = self._store_later, None
        if store is not None and self.session.record_limit is not None:
            # A killed run's replay stops after its recorded records: records and device calls
            # then go in lock-step, so the replay stops before the next step's device calls.
            store[0]()
            store = None
        if store is None and not (self._pending and isinstance(step, _OVERLAPPING)):
            self._write_step(step, attempt, started_s, result=result)
        else:
            self._defer(step, attempt, started_s, result, store)
        self._counts["steps"] += 1
        self.progress.step_done(step, result)
        return result

    def _defer(
        self,
        step: Step,
        attempts: int,
        started_s: float,
        result: StepResult,
        store: tuple[Callable[[], None], Path] | None,
    ) -> None:
        """Queue ``store`` (if any) and the step's record in the journal thread, after what is
        queued already; nothing more is written there once a queued job failed (its temporary is
        removed: only a spectrum's, or a record alone, ever waits behind another job)."""
        ended_s = self._now_s()

        def job() -> None:
            if self._journal_failed:
                if store is not None:
                    with contextlib.suppress(OSError):
                        store[1].unlink()
                raise _Skipped
            try:
                if store is not None:
                    store[0]()
                self._record_step(step, attempts, started_s, ended_s, result=result)
            except BaseException:
                self._journal_failed = True
                raise

        future = self._journal.submit(job)
        self._pending.append(_DeferredStore(step, attempts, started_s, future))

    def _write_step(
        self,
        step: Step,
        attempts: int,
        started_s: float,
        *,
        result: StepResult | None = None,
        error: BaseException | None = None,
    ) -> None:
        """The step's record (``done`` with ``result`` or ``failed`` with ``error``), after what
        the journal still stores."""
        self._settle()
        self._record_step(step, attempts, started_s, self._now_s(), result=result, error=error)

    def _record_step(
        self,
        step: Step,
        attempts: int,
        started_s: float,
        ended_s: float,
        *,
        result: StepResult | None = None,
        error: BaseException | None = None,
    ) -> None:
        """Write the step's record, transcripts synced first (also from the journal thread)."""
        self.session.sync_transcripts()
        self.session.write(
            StepRecord,
            key=step.key,
            action=type(step).__name__,
            params=step.params(),
            status="done" if error is None else "failed",
            attempts=attempts,
            started_s=started_s,
            duration_s=max(0.0, ended_s - started_s),
            result=result.to_json() if result is not None else None,
            error=error_info(error) if error is not None else None,
        )

    def _record_failure(
        self, step: Step, exc: BaseException, attempts: int, started_s: float
    ) -> None:
        """A ``failed`` step record, unless the session itself can no longer be written (what the
        journal still stores, and its failure, come first)."""
        self._settle()
        if self.session.broken is None:
            with contextlib.suppress(SessionWriteError):
                self._write_step(step, attempts, started_s, error=exc)

    # ------------------------------------------------------------ the vocabulary on devices
    # The runner's handlers of rig.steps.StepHandlers: reached through interpret() from _execute,
    # which adds the deadline, retries and records around them.

    def all_lamps_off(self, step: AllLampsOff) -> RelayState:
        self._call("relays", "switch all off", self.station.relays.all_off, self.timeouts.relays_s)
        return self._relay_state()

    def switch_lamp(self, step: SwitchLamp) -> RelayState:
        relays = self.station.relays
        self._call(
            "relays",
            f"switch channel {step.channel} {'on' if step.on else 'off'}",
            functools.partial(relays.set, step.channel, step.on),
            self.timeouts.relays_s,
        )
        state = self._relay_state()
        if not 1 <= step.channel <= len(state.channels) or (
            state.channels[step.channel - 1] != step.on
        ):
            raise StateMismatch(
                self._workers["relays"].device,
                f"relay channel {step.channel} ({step.lamp}) did not follow",
                expected="on" if step.on else "off",
                actual="".join("1" if on else "0" for on in state.channels),
            )
        return state

    def configure_camera(self, step: ConfigureCamera) -> CameraReady:
        self._camera_changed = True
        camera = self.station.camera
        read_back = []
        for name, value in step.settings:
            actual = self._call(
                "camera",
                f"set {name}",
                functools.partial(camera.set_setting, name, value),
                self.timeouts.camera_s,
            )
            read_back.append(SettingReadBack(name, value, str(actual)))
        low, high = self._call(
            "camera", "read exposure range", camera.exposure_range_s, self.timeouts.camera_s
        )
        return CameraReady(tuple(read_back), (float(low), float(high)))

    def configure_spectrometer(self, step: ConfigureSpectrometer) -> SpectrometerReady:
        self._spectrometer_exposure_ms = step.exposure_ms
        self._call(
            "spectrometer",
            "set exposure",
            functools.partial(self.station.spectrometer.set_exposure, step.exposure_ms),
            self.timeouts.spectrometer_s,
        )
        return SpectrometerReady(step.exposure_ms)

    def measure_dark(self, step: MeasureDark) -> DarkMeasured:
        return self._measure_dark(step)

    def measure_spectrum(self, step: MeasureSpectrum) -> SpectrumMeasured:
        self._check_aim(step, "lamp")
        return self._measure(step, f"spectra/{step.lamp}/{step.purpose}-{step.index:03d}.csv")

    def aim_spectrometer(self, step: AimSpectrometer) -> SpectrometerAimed:
        began_s = self._now_s()
        action = ManualAction(
            step.key, step.instruction(), step.beam, step.angle_deg, step.centre_nm
        )
        self.spectrometer_aim = None  # being moved
        interrupts = self.interrupts
        if not self.station.operator.perform(action, lambda: interrupts.stop_requested is not None):
            raise StopRequested(interrupts.stop_requested or "SIGINT")
        self.spectrometer_aim = step.target
        ended_s = self._now_s()
        return SpectrometerAimed(ended_s, ended_s - began_s)

    def measure_beam(self, step: MeasureBeam) -> SpectrumMeasured:
        self._check_aim(step, step.target)
        return self._measure(step, step.file)

    def _check_aim(self, step: MeasureSpectrum | MeasureBeam, target: str) -> None:
        if self.spectrometer_aim != target:
            where = self.spectrometer_aim or "an unknown direction"
            raise PlanProtocolError(
                f"{step.key}: the spectrometer must look at {target}, it was last aimed at {where}"
            )

    def wait(self, step: Wait) -> Waited:
        began_s = self._now_s()
        completed = self._sleep(step.seconds)
        ended_s = self._now_s()
        return Waited(ended_s, ended_s - began_s, completed)

    def keep_lamp_timeline(self, step: KeepLampTimeline) -> Waited:
        return self.wait(step)

    def set_exposure(self, step: SetExposure) -> ExposureSet:
        self._camera_changed = True
        actual = self._call(
            "camera",
            f"set exposure {step.exposure_s:g} s",
            functools.partial(self.station.camera.set_exposure, step.exposure_s),
            self.timeouts.camera_s,
        )
        return ExposureSet(step.exposure_s, float(actual))

    def capture(self, step: Capture) -> FrameCaptured:
        return self._capture(step)

    def dark_frame(self, step: DarkFrame) -> FrameCaptured:
        return self._capture(step)

    def _relay_state(self) -> RelayState:
        state = self._call(
            "relays", "read state", self.station.relays.state, self.timeouts.relays_s
        )
        return RelayState(self._now_s(), tuple(bool(s) for s in state))

    def _discard_stale(self, key: str, path: str, problem: str) -> None:
        """Record that a reading was stale; the step takes it again."""
        self.session.write(DiscardRecord, key=key, path=path, reason="stale", message=problem)
        self._counts["discarded"] += 1
        self.progress.message(f"{key}: discarded {path}: {problem}; taking it again")

    def _still_stale(self, role: DeviceRole, what: str) -> StaleReading:
        return StaleReading(
            self._workers[role].device,
            f"{STALE_READING_ATTEMPTS} readings in a row after a settings change {what}",
        )

    def _measure(self, step: MeasureSpectrum | MeasureBeam, relative: str) -> SpectrumMeasured:
        configured_ms = self._spectrometer_exposure_ms
        for _ in range(STALE_READING_ATTEMPTS):
            reading = self._call(
                "spectrometer",
                "measure",
                self.station.spectrometer.measure,
                self.timeouts.spectrometer_s,
            )
            values = np.asarray(reading.values, dtype=np.float64)
            try:
                spectrum = Spectrum(reading.wavelength_nm, values, name=step.key, negative="clip")
            except SpectrumError as exc:
                raise InvalidReading(
                    self._workers["spectrometer"].device, f"invalid spectrum: {exc}"
                ) from None
            temporary = self.session.stage_spectrum(
                relative, spectrum, units=reading.units, bandwidth_nm=reading.bandwidth_nm
            )
            stale = (
                configured_ms is not None
                and reading.exposure_ms is not None
                and not math.isclose(
                    reading.exposure_ms, configured_ms, rel_tol=STALE_EXPOSURE_RTOL
                )
            )
            if not stale:
                break
            self._settle()
            record = self._commit(step, temporary, relative, "spectrum", reading)
            self._discard_stale(
                step.key,
                record.path,
                f"the spectrometer reports {reading.exposure_ms:g} ms of integration, "
                f"it was set to {configured_ms:g} ms",
            )
        else:
            raise self._still_stale(
                "spectrometer", f"did not use the integration time ({configured_ms:g} ms)"
            )
        # Checked: later readings need no check until the next settings change.
        self._spectrometer_exposure_ms = None
        self._counts["spectra"] += 1
        # The plan gets the spectrum as stored (CSV precision), so a plan re-driven from the session
        # (resume, replay) sees exactly the numbers this run saw and takes the same branches.
        try:
            stored = read_spectrum_csv(temporary)
        except OSError as exc:
            raise SessionWriteError(f"reading back {relative}: {exc}") from exc
        return SpectrumMeasured(
            self._now_s(),
            self._store_later_as(step, temporary, relative, "spectrum", reading),
            stored.wavelength_nm,
            stored.values,
            reading.units,
            reading.exposure_ms,
            int(np.count_nonzero(values < 0)),
        )

    def _check_lamps_off(self, before: str) -> None:
        state = self._relay_state()
        lit = [str(i + 1) for i, on in enumerate(state.channels) if on]
        if lit:
            raise LampsNotOff(
                self._workers["relays"].device,
                f"relay channel(s) {', '.join(lit)} read as on before {before}",
            )

    def _measure_dark(self, step: MeasureDark) -> DarkMeasured:
        """The spectrometer's dark spectra, lamps checked off first, stored as one CSV file
        (``wavelength_nm`` and a ``dark_<t>ms`` column of raw counts per integration time)."""
        spectrometer = self.station.spectrometer
        device = self._workers["spectrometer"].device
        if not isinstance(spectrometer, DarkCorrecting):
            raise PlanProtocolError(f"{step.key}: {device} measures no dark of its own")
        self._check_lamps_off("the spectrometer's dark")
        reading = self._call(
            "spectrometer", "measure the dark", spectrometer.measure_dark, self.timeouts.dark_s
        )
        try:
            darks = MultiSpectrum(
                reading.wavelength_nm,
                np.asarray(reading.counts, dtype=np.float64).T,
                channels=tuple(f"dark_{t:g}ms" for t in reading.integration_ms),
                name=step.key,
                negative="clip",
            )
        except SpectrumError as exc:
            raise InvalidReading(device, f"invalid dark spectrum: {exc}") from None
        temporary = self.session.incoming_path("spectra")
        write_csv(temporary, darks)
        record = self.session.commit_file(
            temporary, "spectra/dark.csv", key=step.key, role="spectrum", units="counts"
        )
        return DarkMeasured(self._now_s(), record.path, tuple(reading.integration_ms))

    def _capture(self, step: Capture | DarkFrame) -> FrameCaptured:
        """A frame, whose storing overlaps the camera's next frame.

        The frame is downloaded next to where it is kept, and checked (not stale: a new digest,
        and after a settings change the exposure its metadata records) and, for a scene frame,
        analysed there; syncing it, renaming it into place and its file and step records are
        left to the journal thread (:meth:`_execute`), which works while the plan's next steps —
        the next exposure and frame — use the camera. What the journal still stores is waited
        for once this frame is downloaded: when it failed, this frame is still stored (a
        ``file`` record; the step is not acknowledged) and the run fails on the earlier step's
        error. A frame that cannot be analysed is stored before the run fails on it.
        """
        dark = isinstance(step, DarkFrame)
        if dark:
            self._check_lamps_off("a dark frame")
        for _ in range(STALE_READING_ATTEMPTS):
            captured, source, relative = self._download(step, dark=dark)
            try:
                self._settle()
            except BaseException:
                with contextlib.suppress(Exception):  # a broken session keeps it as a temporary
                    self._commit(step, source, relative, "dark" if dark else "frame")
                raise
            try:
                # Taken once: storing the frame reuses it unless the file changed since.
                digest = file_digest(source)
            except OSError as exc:
                raise SessionWriteError(f"reading the downloaded frame {source}: {exc}") from exc
            problem = self._stale_frame(step, digest.sha256, source)
            if problem is None:
                break
            record = self._commit(step, source, relative, "dark" if dark else "frame", known=digest)
            self.frame_digests.setdefault(record.sha256, step.key)
            self._discard_stale(step.key, record.path, problem)
        else:
            raise self._still_stale("camera", f"were stale at {step.exposure_s:g} s of exposure")
        self.frame_digests.setdefault(digest.sha256, step.key)
        self._camera_changed = False
        self._counts["dark_frames" if dark else "frames"] += 1
        stats = None if dark else self._analyse(step, source, relative, digest)
        return FrameCaptured(
            self._now_s(),
            self._store_later_as(step, source, relative, "dark" if dark else "frame", known=digest),
            step.exposure_s,
            float(captured.exposure_s),
            captured.camera_path,
            stats,
        )

    def _store_later_as(
        self,
        step: Step,
        temporary: Path,
        relative: str,
        role: Literal["dark", "frame", "spectrum"],
        reading: SpectrumReading | None = None,
        *,
        known: FileDigest | None = None,
    ) -> str:
        """Leave the storing of ``temporary`` under ``relative`` to the journal thread
        (:meth:`_execute` queues it with the step's record); return the name it will have."""
        final = self.session.final_name(relative)

        def store() -> None:
            record = self._commit(step, temporary, relative, role, reading, known=known)
            if record.path != final:
                raise SessionWriteError(
                    f"{self.session.path}: {relative} was stored as {record.path}, not {final}: "
                    "something else writes into the session"
                )

        self._store_later = (store, temporary)
        return final

    def _analyse(
        self, step: Capture | DarkFrame, source: Path, relative: str, digest: FileDigest
    ) -> FrameStats:
        """The statistics of a downloaded scene frame; one that cannot be analysed is stored
        (a ``file`` record) before :class:`FrameAnalysisError` names it."""
        try:
            return self.station.analyzer.analyse(source)
        except Exception as exc:
            record = self._commit(step, source, relative, "frame", known=digest)
            detail = str(exc).removeprefix(f"{source}: ")
            if not isinstance(exc, FrameAnalysisError):
                detail = f"{type(exc).__name__}: {exc}"
            raise FrameAnalysisError(record.path, detail) from exc

    def _commit(
        self,
        step: Step,
        temporary: Path,
        relative: str,
        role: Literal["dark", "frame", "spectrum"],
        reading: SpectrumReading | None = None,
        *,
        known: FileDigest | None = None,
    ) -> FileRecord:
        """Acknowledge a downloaded frame or a staged spectrum under ``relative`` (``known``:
        its digest as the runner took it, :meth:`rig.session.SessionWriter.commit_file`)."""
        return self.session.commit_file(
            temporary,
            relative,
            key=step.key,
            role=role,
            units=None if reading is None else reading.units,
            bandwidth_nm=None if reading is None else reading.bandwidth_nm,
            known=known,
        )

    def _download(self, step: Capture | DarkFrame, *, dark: bool) -> tuple[Any, Path, str]:
        """Capture and download one frame for ``step``: what the driver returned, the
        downloaded file (a temporary in the session) and the name to acknowledge it under."""
        # Next to where it is kept: the analyser knows a lamp's frames by their directory.
        temporary = self.session.incoming_path(f"{FRAMES_DIR}/{step.lamp}")
        camera = self.station.camera
        try:
            captured = self._call(
                "camera",
                f"capture {step.exposure_s:g} s",
                # Unsynced: commit_file syncs it before its record, in the journal thread,
                # while the camera takes the next frame.
                lambda: camera.capture(temporary, sync=False),
                step.exposure_s + self.timeouts.capture_extra_s,
            )
        except BaseException as exc:
            with contextlib.suppress(OSError):
                temporary.unlink(missing_ok=True)
            if isinstance(exc, UnsafeLocalPath):
                raise self.session.refusal(exc) from None
            if isinstance(exc, OSError):  # the driver could not store the download
                raise SessionWriteError(f"storing the frame from the camera: {exc}") from exc
            raise
        source = Path(captured.path)
        if not source.is_file():
            raise InvalidReading(
                self._workers["camera"].device,
                f"the driver reported a download to {source}, but there is no file there",
            )
        suffix = Path(captured.camera_path).suffix.lower()
        stream = "dark" if dark else "scene"
        relative = f"frames/{step.lamp}/{stream}-{step.index:03d}{suffix if _SUFFIX.fullmatch(suffix) else '.raw'}"
        return captured, source, relative

    def _stale_frame(self, step: Capture | DarkFrame, sha256: str, frame: Path) -> str | None:
        """Why a just-acknowledged frame is stale, or ``None``.

        A copy of a frame the session already holds is never a new frame. The first frame after a
        settings change must also show, in its own metadata, the exposure the camera was set to.
        """
        earlier = self.frame_digests.get(sha256, step.key)
        if earlier != step.key:
            return f"it is a byte-for-byte copy of the frame of {earlier}"
        read_exposure = self.station.frame_exposure
        if not self._camera_changed or read_exposure is None:
            return None
        recorded_s = read_exposure(frame)
        if recorded_s is None or math.isclose(
            recorded_s, step.exposure_s, rel_tol=STALE_EXPOSURE_RTOL
        ):
            return None
        return (
            f"its metadata says {recorded_s:g} s of exposure, the camera was set to "
            f"{step.exposure_s:g} s (a frame taken before the new setting)"
        )

    def _sleep(self, seconds: float) -> bool:
        """Let ``seconds`` pass on the clock, in slices; ``False`` if a stop request cut it short."""
        end = self.clock.now() + seconds
        while (remaining := end - self.clock.now()) > 0:
            if self.interrupts.stop_requested is not None:
                return False
            self.clock.sleep(min(remaining, WAIT_SLICE_S))
        return True

    # ------------------------------------------------------------------------------ cleanup

    def _switch_everything_off(self) -> bool:
        """Switch every relay channel off and read the board back; ``True`` when confirmed off."""
        confirmed, problem = switch_everything_off(
            self.station.relays, self._workers["relays"], self.timeouts.relays_s
        )
        if not confirmed:
            self.progress.message(
                f"WARNING: could not confirm that every lamp is off ({problem}): switch them off "
                "by hand"
            )
        return confirmed

    def _write_stop(
        self,
        status: ExitStatus,
        reason: str,
        message: str,
        failed_key: str | None,
        failure: BaseException | None,
        lamps_off: bool,
    ) -> None:
        session = self.session
        # The room reserved for these records is released first: on a full disk they still fit.
        if not session.finish():
            if not session.killed:
                self.progress.message(
                    f"WARNING: the stop record could not be written: {session.broken}"
                )
            session.close()
            return
        try:
            if not self._started:
                self._write_start()
            for received in self.interrupts.received:
                session.write(
                    InterruptionRecord,
                    signal=received.name,
                    t_s=self._now_s(),
                    action=received.action,
                )
            session.close_transcripts()
            internal = failure is not None and not isinstance(failure, DeviceError | RigError)
            error = error_info(failure, with_traceback=internal) if failure else None
            session.write(
                StopRecord,
                exit_status=status,
                reason=reason,
                message=_shortened(message),
                wall_time=datetime.now(UTC),
                t_s=self._now_s(),
                failed_key=failed_key,
                error=None if error is None else _small(error),
                lamps_off=lamps_off,
                counts=dict(self._counts),
            )
        except SessionWriteError as exc:
            self.progress.message(f"WARNING: the stop record could not be written: {exc}")
        finally:
            session.close()

    def _close_device(self, role: DeviceRole, close: Callable[[], None]) -> None:
        # After a second interrupt, do not wait for a device still busy with an abandoned exchange:
        # its close stays queued behind that exchange and runs when it returns.
        timeout_s = HALT_CLOSE_TIMEOUT_S if self.interrupts.halted else self._timeout(role)
        self._call(role, "close", close, timeout_s)

    def _close_workers(self) -> None:
        for worker in self._workers.values():
            worker.close(timeout_s=0.1)
