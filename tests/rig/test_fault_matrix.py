"""The fault matrix of issue 6: every fault, injected into the digital twin, ends in a usable session.

One case per row. Each runs ``rig capture`` on the small twin with the fault injected (in this
process, or in a child process for signals and ``kill -9``); when the capture did not complete it
runs ``rig resume`` without the fault. Every case then asserts the four invariants:

1. **lamps off**: the twin's relays (kept in ``devices.relays.state_file``) read all off, and every
   run's stop record says the board read back off;
2. **valid JSONL**: every line of ``log.jsonl`` parses, validates and is in sequence, no torn tail;
3. **files verify**: every file the log acknowledges (and did not discard) has its size and sha256;
4. **completes or resumes to the identical estimate**: the session is complete. A resumed session
   estimates exactly like an uninterrupted capture with the same seed: ``rig estimate`` writes a
   byte-identical ``sensitivity.csv``. A session that absorbed its fault in one run (a retake) comes
   within :data:`SAME_RUN_TOLERANCE` of it.

Running the estimator costs about a second and a half per session. In the default suite, the row
of camera-unplugged and the ``kill -9`` in a capture (PR-655 and Ocean) run it. The other resumed
rows compare what the estimator reads (pixels, exposures, spectra), which is identical when the
estimate is. ``make test-all`` runs every row again with the estimator (ids ``…+estimate``).

The default suite keeps one Ocean row that fails the run (unplugged) and the Argyll row a person
must act on (needs calibration); the Ocean and Argyll rows the runner absorbs by a retry (a USB
timeout, a silent ``spotread``) are ``make test-all``'s: the retry is the runner's, device-blind,
and runs by default on the PR-655 rows, and each driver's own timeout is tested at its level
(``tests/drivers/test_ocean_exchange.py``, ``tests/drivers/test_argyll.py``).

Beyond the four invariants, rows check what their fault must leave: a full disk (a log record, its
sync, a transcript entry, a frame's download) ends as ``session_write`` with the stop record written
and no temporary left; a relay board lost with a lamp on says ``lamps_off: false`` and warns.
Real ``ENOSPC`` on a small tmpfs is ``tests/rig/test_disk_full.py``.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
import rawpy

import drivers.local_files as local_files
import rig.session as session_module
from calib.core.arrays import FloatArray
from calib.core.formats.rgb_csv import read_camera_csv
from drivers.relays.hid_usbrelay import CMD_ALL_OFF
from mocks.bench import TwinFaults
from mocks.fake_gphoto2 import CameraFault
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.usb_relay_backend import UsbFault
from rig import station
from rig.capture import run_capture
from rig.config import RigConfig
from rig.estimate import estimate_session
from rig.frame_stats import frame_exposure_s
from rig.records import DiscardRecord, FileRecord, ResumeRecord, RetryRecord, StepRecord, StopRecord
from rig.replay import replay_session
from rig.resume import run_resume
from rig.runner import RetryPolicy
from rig.session import Session, find_sessions, read_session
from rig.twin import twin_station_builder
from tests.rig.fakes import wait_for, write_config
from tests.rig.handled_signals import send_one_at_a_time
from tests.rig.test_cli import run_cli
from tests.rig.test_signals import finish
from tests.rig.twin_setup import twin_config_data

ROOT = Path(__file__).resolve().parents[2]
#: USB control transfers of the HID relay board, as hex of their setup packets' first bytes.
SET_REPORT, GET_REPORT, GET_DESCRIPTOR = "2009", "a001", "8006"
#: No backoff: a retry then takes no time on the twin's clock, so the lamps' drift is unchanged.
NO_BACKOFF = RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)
#: How close (relative to the peak) a session that absorbed its fault in one run comes to the
#: uninterrupted estimate.
SAME_RUN_TOLERANCE = 0.02
#: The steps whose files the estimator reads (rig.estimate): bracket, dark frames, references.
ESTIMATE_INPUT = re.compile(r"^lamp/[^/]+/(scene|dark|reference)/\d+$")


#: The twin's spectrometers in the matrix: the PR-655 (serial), an Ocean USB2000+ through
#: pyseabreeze, an i1Pro through ArgyllCMS's spotread (the fake, one process per reading).
EMULATED = ("pr655", "seabreeze", "argyll")


def matrix_config(directory: Path, emulate: str = "pr655") -> RigConfig:
    """The small twin, its relays persisted in ``directory/relays.state``, short deadlines.

    A spotread run (a process start) gets 5 s; the serial and USB exchanges 0.5 s.
    """
    data = twin_config_data(directory / "sessions")
    data["devices"]["relays"]["state_file"] = str(directory / "relays.state")
    spectrometer = data["devices"]["spectrometer"]
    spectrometer["emulate"] = emulate
    spectrometer["timeout_s"] = 5.0 if emulate == "argyll" else 0.5
    spectrometer["measure_timeout_s"] = 10.0 if emulate == "argyll" else 1.0
    return RigConfig.model_validate(data)


@dataclass(frozen=True)
class Sensitivity:
    """An estimate's ``sensitivity.csv``: its sha256 and its values ``(n_wavelengths, 3)``."""

    sha256: str
    values: FloatArray

    @classmethod
    def of(cls, session: Path, out: Path) -> Sensitivity:
        estimate_session(session, out, report=False)
        path = out / "sensitivity.csv"
        values = read_camera_csv(path).values
        return cls(hashlib.sha256(path.read_bytes()).hexdigest(), values)

    def relative_difference(self, other: Sensitivity) -> float:
        """Largest difference between the curves, relative to their peak."""
        return float(np.max(np.abs(self.values - other.values)) / np.max(np.abs(other.values)))


def estimate_inputs(session: Session) -> dict[str, str]:
    """sha256 of what the estimator reads of each bracket frame, dark frame and reference spectrum.

    For a frame, its pixels and the exposure its metadata records (not the DNG header, which holds
    the capture time on the twin's clock); for a spectrum, the CSV file.
    """
    inputs = {}
    for key, record in session.done_steps().items():
        if ESTIMATE_INPUT.match(key) is None:
            continue
        path = session.file_path(str((record.result or {})["file"]))
        if path.suffix == ".dng":
            with rawpy.imread(str(path)) as raw:
                data = raw.raw_image.tobytes() + repr(frame_exposure_s(path)).encode()
        else:
            data = path.read_bytes()
        inputs[key] = hashlib.sha256(data).hexdigest()
    return inputs


@dataclass
class Uninterrupted:
    """An uninterrupted capture with the same seed: its estimator inputs and (when asked) estimate."""

    session: Path
    inputs: dict[str, str]
    _sensitivity: Sensitivity | None = None

    def sensitivity(self) -> Sensitivity:
        if self._sensitivity is None:
            self._sensitivity = Sensitivity.of(self.session, self.session.parent / "estimate")
        return self._sensitivity


class UninterruptedRuns:
    """Uninterrupted captures with the matrix's seed, one per emulated spectrometer, made once."""

    def __init__(self, factory: pytest.TempPathFactory) -> None:
        self._factory = factory
        self._runs: dict[str, Uninterrupted] = {}

    def __call__(self, emulate: str = "pr655") -> Uninterrupted:
        if emulate not in self._runs:
            directory = self._factory.mktemp(f"uninterrupted-{emulate}")
            outcome = run_capture(matrix_config(directory, emulate), retry=NO_BACKOFF)
            assert outcome.exit_status == "success", outcome
            inputs = estimate_inputs(read_session(outcome.session))
            self._runs[emulate] = Uninterrupted(outcome.session, inputs)
        return self._runs[emulate]


@pytest.fixture(scope="module")
def uninterrupted_runs(tmp_path_factory: pytest.TempPathFactory) -> UninterruptedRuns:
    return UninterruptedRuns(tmp_path_factory)


@pytest.fixture
def uninterrupted(uninterrupted_runs: UninterruptedRuns) -> Uninterrupted:
    return uninterrupted_runs("pr655")


def with_estimate(
    rows: Iterable[str], always: set[str], slow: frozenset[str] = frozenset()
) -> list[Any]:
    """``(row, estimate)`` parameters: each row once, checked by its estimator inputs, or by
    running ``rig estimate`` for the rows in ``always``; every other row again with the estimate,
    marked slow (``make test-all``), as are the rows in ``slow`` themselves."""
    params = []
    for row in rows:
        marks = [pytest.mark.slow] if row in slow else []
        params.append(pytest.param(row, row in always, id=row, marks=marks))
        if row not in always:
            params.append(pytest.param(row, True, id=f"{row}+estimate", marks=pytest.mark.slow))
    return params


# ----------------------------------------------------------------------------- the invariants


def assert_invariants(
    session_path: Path, directory: Path, uninterrupted: Uninterrupted, estimate: bool
) -> Session:
    """The four invariants of the module docstring; returns the session.

    Without ``estimate``, a resumed session is compared by what the estimator reads (identical
    inputs to the deterministic estimator give the identical estimate), and a session that
    completed in one run only by completing.
    """
    assert (directory / "relays.state").read_text().strip() == "00"  # 1. lamps off
    log = (session_path / "log.jsonl").read_bytes()
    assert log.endswith(b"\n")
    for line in log.splitlines():  # 2. valid JSONL (and valid records, in sequence)
        json.loads(line)
    session = read_session(session_path)
    assert session.torn is None
    stops = [r for r in session.records if isinstance(r, StopRecord)]
    assert stops and all(stop.lamps_off for stop in stops)
    assert session.verify_files() == []  # 3. files verify
    assert session.status == "complete", session.stop  # 4. completes …
    resumed = bool(resumes(session))
    if resumed and not estimate:
        assert estimate_inputs(session) == uninterrupted.inputs
    if not estimate:
        return session
    sensitivity = Sensitivity.of(session_path, directory / "estimate")
    if resumed:
        # … resumed: to the estimate of an uninterrupted run with the same seed, to the byte;
        assert sensitivity.sha256 == uninterrupted.sensitivity().sha256
    else:
        # … in one run: a retaken reading costs time on the twin's clock, during which the lamp
        # drifts, so the frames after it are other (equally valid) frames; the estimate is close.
        difference = sensitivity.relative_difference(uninterrupted.sensitivity())
        assert difference < SAME_RUN_TOLERANCE
    return session


def capture_then_resume(
    directory: Path, builder: Any = None, emulate: str = "pr655"
) -> tuple[str, Path]:
    """Capture with ``builder`` (faults); resume without faults if it did not complete.

    Returns the first run's stop reason and the session.
    """
    outcome = run_capture(matrix_config(directory, emulate), retry=NO_BACKOFF, builder=builder)
    if outcome.exit_status != "success":
        resumed = run_resume(outcome.session, matrix_config(directory, emulate), retry=NO_BACKOFF)
        assert resumed.exit_status == "success", resumed
    return outcome.reason, outcome.session


def resumes(session: Session) -> list[ResumeRecord]:
    return [r for r in session.records if isinstance(r, ResumeRecord)]


# ----------------------------------------------------------------------------- in-process rows


@dataclass(frozen=True)
class Row:
    """A fault injected at open, and the first run's stop reason it leads to.

    ``faults`` makes a fresh set per test: schedules and injected faults count down as they fire,
    so one set shared by two tests (a row and its ``+estimate`` twin) would fire only once.
    """

    faults: Callable[[], TwinFaults]
    reason: str
    emulate: str = "pr655"


def _spectrometer(kind: FaultKind, nth: int = 4, match: str = "M5", **fault: Any) -> TwinFaults:
    rule_fault = Fault(kind, **fault)
    return TwinFaults(spectrometer=FaultSchedule.once(rule_fault, match, nth=nth))


def _ocean(kind: FaultKind) -> TwinFaults:
    """A fault on the 12th spectrum transfer of the emulated USB2000+ (inside the warm-up)."""
    return _spectrometer(kind, nth=12, match="spectrum")


def _spotread(kind: FaultKind, code: str | None = None) -> TwinFaults:
    """A fault on the 3rd spotread run (the fake's scene: ``mocks.bench.station.SPOTREAD_FAULTS``)."""
    return _spectrometer(kind, nth=3, match="spotread", code=code)


ROWS: dict[str, Row] = {
    "camera-unplugged-mid-bracket": Row(
        lambda: TwinFaults(camera=[CameraFault("unplug", skip=1)]), "disconnected"
    ),
    "ptp-busy-on-capture": Row(
        lambda: TwinFaults(camera=[CameraFault("busy", times=2)]), "completed"
    ),
    "same-file-returned-twice": Row(
        lambda: TwinFaults(camera=[CameraFault("same_file", skip=1)]), "completed"
    ),
    "stale-frame-after-exposure-change": Row(
        lambda: TwinFaults(camera=[CameraFault("stale_frame", skip=1)]), "completed"
    ),
    # The driver's own deadline ends a silent or cut-off measurement (a retryable timeout, retried
    # in the same run), before the runner's watchdog, which covers the driver's worst case.
    "spectrometer-timeout": Row(lambda: _spectrometer(FaultKind.NO_REPLY), "completed"),
    "spectrometer-garbled-reply": Row(lambda: _spectrometer(FaultKind.GARBLED_REPLY), "completed"),
    "spectrometer-truncated-reply": Row(
        lambda: _spectrometer(FaultKind.TRUNCATED_REPLY), "completed"
    ),
    "spectrometer-error-code": Row(lambda: _spectrometer(FaultKind.ERROR_CODE), "instrument_error"),
    "relay-read-back-mismatch": Row(
        lambda: TwinFaults(
            usb_relays=[UsbFault("stuck_relay", request="set_report", skip=2, channel=1)]
        ),
        "state_mismatch",
    ),
    # Ocean (pyseabreeze on the emulated USB bus): a lost transfer is a USB timeout, a stall and
    # a spectrum without its sync byte protocol errors, all retried; an unplugged spectrometer
    # fails the run, and the resume (it is back) completes it.
    "seabreeze-usb-timeout": Row(lambda: _ocean(FaultKind.NO_REPLY), "completed", "seabreeze"),
    "seabreeze-stall": Row(lambda: _ocean(FaultKind.ERROR_CODE), "completed", "seabreeze"),
    "seabreeze-bad-sync-byte": Row(
        lambda: _ocean(FaultKind.GARBLED_REPLY), "completed", "seabreeze"
    ),
    "seabreeze-busy": Row(lambda: _ocean(FaultKind.BUSY), "completed", "seabreeze"),
    "seabreeze-unplugged": Row(lambda: _ocean(FaultKind.DISCONNECT), "disconnected", "seabreeze"),
    # ArgyllCMS (the fake spotread): a silent run is killed at its deadline and a misread retried;
    # a calibration the instrument needs, or an instrument gone, fails the run for a person.
    "argyll-silent": Row(lambda: _spotread(FaultKind.NO_REPLY), "completed", "argyll"),
    "argyll-misread": Row(
        lambda: _spotread(FaultKind.ERROR_CODE, "misread"), "completed", "argyll"
    ),
    "argyll-garbled-file": Row(lambda: _spotread(FaultKind.GARBLED_REPLY), "completed", "argyll"),
    "argyll-needs-calibration": Row(
        lambda: _spotread(FaultKind.ERROR_CODE, "needs_calibration"), "instrument_error", "argyll"
    ),
    "argyll-instrument-gone": Row(lambda: _spotread(FaultKind.DISCONNECT), "not_found", "argyll"),
}
#: Rows of the default suite (the others run in ``make test-all``); those in :data:`ALWAYS`
#: run the estimator there too.
DEFAULT_ROWS = {
    *(row for row, spec in ROWS.items() if spec.emulate == "pr655"),
    "seabreeze-unplugged",
    "argyll-needs-calibration",
}
#: None: the PR-655 kill -9 row runs the estimator on a resumed session in the default suite (the
#: seabreeze and argyll rows compare the estimator's inputs there); every fault row's estimate runs
#: in ``make test-all``.
ALWAYS: set[str] = set()


def matrix_rows() -> list[Any]:
    return [
        param
        if param.id.removesuffix("+estimate") in DEFAULT_ROWS
        else pytest.param(*param.values, id=param.id, marks=pytest.mark.slow)
        for param in with_estimate(ROWS, ALWAYS)
    ]


@pytest.mark.usefixtures("fast_camera_recovery")
@pytest.mark.parametrize(("row", "estimate"), matrix_rows())
def test_fault(
    row: str, estimate: bool, tmp_path: Path, uninterrupted_runs: UninterruptedRuns
) -> None:
    expected = ROWS[row]
    builder = twin_station_builder(faults=expected.faults())
    reason, path = capture_then_resume(tmp_path, builder, expected.emulate)
    assert reason == expected.reason
    uninterrupted = uninterrupted_runs(expected.emulate)
    session = assert_invariants(path, tmp_path, uninterrupted, estimate)
    if row == "stale-frame-after-exposure-change":
        (discarded,) = [r for r in session.records if isinstance(r, DiscardRecord)]
        assert discarded.reason == "stale" and "metadata says" in discarded.message
    if row in (
        "spectrometer-timeout",
        "spectrometer-truncated-reply",
        "seabreeze-usb-timeout",
        "argyll-silent",
    ):
        (retry,) = [r for r in session.records if isinstance(r, RetryRecord)]
        assert retry.error.reason == "timeout" and retry.error.retryable
    if reason != "completed":
        (resume,) = resumes(session)
        assert resume.previous_status == "failed" and resume.previous_reason == reason
    replay = replay_session(path, tmp_path / "replay")  # one run or two: replays identically
    assert replay.identical, replay


@dataclass(frozen=True)
class DiskFull:
    """``ENOSPC`` on the ``nth`` write of a kind: half of it written first (``write``), or on its
    ``fdatasync`` (``fsync``). ``target`` is what is written: a log record, a transcript entry, or
    the frame the camera driver stores."""

    target: Literal["log", "transcript", "frame"]
    call: Literal["write", "fsync"]
    nth: int


DISK_FULL = {
    "log-write": DiskFull("log", "write", 40),
    "log-fsync": DiskFull("log", "fsync", 40),
    "transcript-append": DiskFull("transcript", "write", 60),
    "frame-download": DiskFull("frame", "write", 2),
}


def leftovers(session: Path) -> list[str]:
    """Temporaries left in a session (downloads, spectra, the camera's, the reserved room)."""
    return sorted(
        str(path.relative_to(session))
        for path in session.rglob("*")
        if path.name.startswith((".incoming-", "..incoming-", ".reserve"))
    )


def _fill_the_disk(fault: DiskFull, patch: pytest.MonkeyPatch) -> None:
    calls = 0

    def counts(data: bytes) -> bool:
        if fault.target == "log":
            return data.startswith(b'{"seq":')
        if fault.target == "transcript":
            return data.startswith(b'{"t_s":')
        return True

    def full(real: Callable[..., None]) -> Callable[..., None]:
        def call(fd: int, *data: bytes) -> None:
            nonlocal calls
            hit = fault.call == "fsync" or counts(data[0])
            calls += hit
            if hit and calls == fault.nth:
                if data:
                    os.write(fd, data[0][: len(data[0]) // 2])  # the disk fills mid-write
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            real(fd, *data)

        return call

    module: Any = local_files if fault.target == "frame" else session_module
    name = "_sync" if fault.call == "fsync" else "write_all"
    patch.setattr(module, name, full(getattr(module, name)))


@pytest.mark.parametrize(("row", "estimate"), with_estimate(DISK_FULL, set()))
def test_disk_full(
    row: str,
    estimate: bool,
    tmp_path: Path,
    uninterrupted: Uninterrupted,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fault = DISK_FULL[row]
    with monkeypatch.context() as patch:
        _fill_the_disk(fault, patch)
        outcome = run_capture(matrix_config(tmp_path), retry=NO_BACKOFF)
    assert (outcome.reason, outcome.lamps_off) == ("session_write", True)
    failed = read_session(outcome.session)
    # The log says why and that the lamps are off: its last records fit in the reserved room.
    assert failed.torn is None and failed.status == "failed"
    assert failed.stop is not None and failed.stop.reason == "session_write"
    assert failed.stop.lamps_off and "No space left on device" in failed.stop.message
    assert failed.verify_files() == []  # a transcript cut at a whole entry still verifies
    assert leftovers(outcome.session) == []
    resumed = run_resume(outcome.session, matrix_config(tmp_path), retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    session = assert_invariants(outcome.session, tmp_path, uninterrupted, estimate)
    (resume,) = resumes(session)
    assert (resume.previous_status, resume.previous_reason) == ("failed", "session_write")


# ----------------------------------------------------------------------------- real processes


def start_twin_capture(
    directory: Path,
    slow_capture_s: float,
    call: str = "capture",
    emulate: str = "pr655",
    lag: str | None = None,
) -> subprocess.Popen[str]:
    """``rig capture`` on the twin (its spectrometer emulating ``emulate``) in a child process,
    stopped in its second (slow) capture, or in the second download of a frame from the camera
    (``call="file_get"``); ``lag`` holds the first frame's storing there (``tests.rig.twin_process``)."""
    config = write_config(
        directory / "rig.yaml", matrix_config(directory, emulate).model_dump(mode="json")
    )
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.rig.twin_process",
            str(config),
            str(slow_capture_s),
            call,
            *([lag] if lag else []),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    def in_second_capture() -> bool:
        if process.poll() is not None:
            raise AssertionError(f"the capture ended early: {process.communicate()}")
        transcripts = list((directory / "sessions").glob("*/transcripts/camera.jsonl"))
        if not transcripts:
            return False
        lines = transcripts[0].read_text().splitlines()
        calls = [json.loads(line)["data"] for line in lines if '"dir": "call"' in line]
        return sum(f'"call": "{call}"' in entry for entry in calls) >= 2

    # The second capture is slow: interrupted there, the run has LED-B3 on and a frame done.
    wait_for(in_second_capture, timeout_s=120, what=f"the second {call}")
    return process


def the_session(directory: Path) -> Path:
    (path,) = find_sessions(directory / "sessions")
    return path


SIGNALS: dict[str, tuple[list[signal.Signals], int, str]] = {
    "sigint-once": ([signal.SIGINT], 130, "interrupted"),
    "sigint-twice": ([signal.SIGINT, signal.SIGINT], 130, "halted"),
    "sigterm": ([signal.SIGTERM], 143, "interrupted"),
}


#: One Ctrl-C takes the SIGTERM row's path (finish the step, stop interrupted, resume), so its row
#: runs in ``make test-all``; the default suite checks its exit 130 and finished step in
#: ``tests/rig/test_signals.py``.
SLOW_SIGNALS = frozenset({"sigint-once"})


@pytest.mark.parametrize(("row", "estimate"), with_estimate(SIGNALS, set(), SLOW_SIGNALS))
def test_signals(row: str, estimate: bool, tmp_path: Path, uninterrupted: Uninterrupted) -> None:
    signals, exit_code, reason = SIGNALS[row]
    process = start_twin_capture(tmp_path, slow_capture_s=1.0 if len(signals) == 1 else 30.0)
    send_one_at_a_time(process, signals, tmp_path / "rig.yaml.signals")
    code, _, err = finish(process)
    assert code == exit_code, err
    path = the_session(tmp_path)
    stop = read_session(path).stop
    assert stop is not None and (stop.reason, stop.lamps_off) == (reason, True)
    resumed = run_resume(path, matrix_config(tmp_path), retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    session = assert_invariants(path, tmp_path, uninterrupted, estimate)
    (resume,) = resumes(session)
    assert (resume.previous_status, resume.previous_reason) == ("interrupted", reason)


#: The hang guard of a kill -9 row (pytest-timeout; not a speed check): it runs two captures (one
#: in a child process), a resume, up to two estimates and a replay, which on a machine loaded 10×
#: its cores takes longer than the suite's 120 s although nothing hangs.
KILL_TEST_TIMEOUT_S = 360


@pytest.mark.timeout(KILL_TEST_TIMEOUT_S)
@pytest.mark.parametrize(
    ("emulate", "during", "estimate", "lag"),
    [
        # A retry after the rig's own backoff before the lamp goes on (a timeout under load):
        # the whole run is later on the twin's clock, and its replay must be so only once.
        pytest.param("pr655", "capture", True, "start-timeout", id="in-a-capture"),
        # The first frame's storing (the journal thread) held as a loaded machine holds it: the
        # kill lands before the frame was renamed into place (a temporary), or after it was but
        # before its ``file`` record. Either way the resume takes it again under the name the
        # log alone decides, as the replay of the killed run does (which stops at its last record).
        pytest.param("pr655", "file_get", False, "before-rename", id="in-a-download"),
        # Checked by what the estimator reads (identical inputs, identical estimate); the
        # estimate itself runs in ``make test-all``.
        pytest.param("seabreeze", "capture", False, None, id="seabreeze", marks=pytest.mark.slow),
        pytest.param(
            "seabreeze", "capture", True, None, id="seabreeze+estimate", marks=pytest.mark.slow
        ),
        # issue 20's done-when (kill -9, resume, estimate, replay): the in-a-capture row runs the
        # estimator on the default suite; this row compares its inputs, the estimate in test-all.
        pytest.param("argyll", "capture", False, "before-record", id="argyll"),
        pytest.param(
            "argyll", "capture", True, "before-record", id="argyll+estimate", marks=pytest.mark.slow
        ),
    ],
)
def test_kill_9_then_rig_resume(
    emulate: str,
    during: str,
    estimate: bool,
    lag: str | None,
    tmp_path: Path,
    uninterrupted_runs: UninterruptedRuns,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    uninterrupted = uninterrupted_runs(emulate)
    process = start_twin_capture(
        tmp_path, slow_capture_s=60.0, call=during, emulate=emulate, lag=lag
    )
    state = tmp_path / "relays.state"
    assert state.read_text().strip() == "10"  # LED-B3 is on for its bracket
    process.kill()
    finish(process)
    assert state.read_text().strip() == "10"  # … and stays on: nobody switched it off
    path = the_session(tmp_path)
    killed = read_session(path)
    assert killed.stop is None
    if lag in ("before-rename", "before-record"):  # the kill landed in the held store
        renamed = (path / "frames" / "LED-B3" / "scene-000.dng").exists()
        assert renamed == (lag == "before-record")
        assert not [r for r in killed.records if isinstance(r, FileRecord) and r.role == "frame"]
    monkeypatch.chdir(tmp_path)
    assert run_cli(["resume", str(path), "--quiet", "--config", "rig.yaml"], monkeypatch) == 0
    # Some kills run the estimator; the others compare what it reads (identical inputs).
    session = assert_invariants(path, tmp_path, uninterrupted, estimate=estimate)
    (resume,) = resumes(session)
    assert resume.previous_reason == "no_stop_record"
    assert resume.relays_found_on == [1]  # the lamp the killed run left on was seen on …
    run2 = [r for r in session.records if r.run == 2 and isinstance(r, StepRecord)]
    assert run2[0].key == "start/all-lamps-off"
    # … and the first command the resumed run sent the board (after reads) switched all off.
    relays = (path / "transcripts" / "relays.run2.jsonl").read_text().splitlines()
    sent = [json.loads(line)["data"] for line in relays if json.loads(line)["dir"] == "tx"]
    first_set = next(i for i, data in enumerate(sent) if data.startswith(SET_REPORT))
    assert sent[first_set][16:18] == f"{CMD_ALL_OFF:02x}"
    assert all(data.startswith((GET_DESCRIPTOR, GET_REPORT)) for data in sent[:first_set])
    # The resume acknowledged the killed run's transcripts: the session replays run by run.
    acknowledged = {r.path: r.run for r in session.files() if r.role == "transcript"}
    assert acknowledged["transcripts/camera.jsonl"] == 2
    assert leftovers(path) == []
    # The first frame is stored under its own name, never beside a copy the killed run renamed.
    first = session.done_steps()["lamp/LED-B3/scene/000"].result or {}
    assert first["file"] == "frames/LED-B3/scene-000.dng"
    replay = replay_session(path, tmp_path / "replay")
    assert replay.identical, replay


def test_a_complete_session_is_not_resumed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config = matrix_config(tmp_path)
    outcome = run_capture(config, retry=NO_BACKOFF)
    config_file = write_config(tmp_path / "rig.yaml", config.model_dump(mode="json"))
    assert run_cli(["resume", str(outcome.session), "-c", str(config_file)], monkeypatch) == 2
    assert "is complete; there is nothing to resume" in capsys.readouterr().err


# ------------------------------------------------------------------ lamps that cannot be switched


def test_a_board_lost_with_a_lamp_on_says_so_and_the_resume_switches_it_off(
    tmp_path: Path,
    uninterrupted: Uninterrupted,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The relay board vanishes as LED-B3 is to go off: the stop record says ``lamps_off: false``
    and the command warns to switch them off by hand; the resume finds the lamp on, switches it
    off first, and completes."""
    lost = TwinFaults(usb_relays=[UsbFault("disconnect", request="set_report", skip=3, times=None)])
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", twin_station_builder(faults=lost))
    config = matrix_config(tmp_path)
    config_file = write_config(tmp_path / "rig.yaml", config.model_dump(mode="json"))
    assert run_cli(["capture", "-c", str(config_file), "-q"], monkeypatch) == 1
    captured = capsys.readouterr()
    assert "WARNING: the lamps could not be confirmed off; check them by hand" in captured.err
    assert (tmp_path / "relays.state").read_text().strip() == "10"  # LED-B3 is still on
    path = the_session(tmp_path)
    failed = read_session(path)
    assert failed.stop is not None and not failed.stop.lamps_off
    assert (failed.stop.reason, failed.stop.failed_key) == (
        "disconnected",
        "lamp/LED-B3/switch-off",
    )
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", twin_station_builder())
    assert run_cli(["resume", str(path), "-q", "-c", str(config_file)], monkeypatch) == 0
    assert "WARNING" not in capsys.readouterr().err
    session = read_session(path)
    (resume,) = resumes(session)
    assert resume.relays_found_on == [1]
    stops = [r for r in session.records if isinstance(r, StopRecord)]
    assert [stop.lamps_off for stop in stops] == [False, True]
    assert (tmp_path / "relays.state").read_text().strip() == "00"
    assert session.status == "complete" and session.verify_files() == []
    assert estimate_inputs(session) == uninterrupted.inputs


def test_a_board_missing_at_opening_with_a_lamp_on_warns_and_leaves_no_session(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "relays.state").write_text("10\n")  # a lamp a killed run left on
    missing = TwinFaults(usb_relays=[UsbFault("disconnect", request="open", times=None)])
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", twin_station_builder(faults=missing))
    config_file = write_config(
        tmp_path / "rig.yaml", matrix_config(tmp_path).model_dump(mode="json")
    )
    assert run_cli(["capture", "-c", str(config_file), "-q"], monkeypatch) == 1
    err = capsys.readouterr().err
    assert (
        "rig: warning: the lamps could not be confirmed off" in err and "check them by hand" in err
    )
    assert "could not be opened, nothing was recorded" in err
    assert not (tmp_path / "sessions").exists()  # no session that could never be resumed
    assert (tmp_path / "relays.state").read_text().strip() == "10"
