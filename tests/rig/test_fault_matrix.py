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

Running the estimator costs about a second and a half per session. In the default suite, the rows
of camera-unplugged, disk-full-on-write and ``kill -9`` run it. The other resumed rows
compare what the estimator reads (pixels, exposures, spectra), which is identical when the
estimate is. ``make test-all`` runs every row again with the estimator (ids ``…+estimate``).
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
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rawpy

import rig.session as session_module
from calib.core.arrays import FloatArray
from calib.core.formats.rgb_csv import read_camera_csv
from drivers.relays.hid_usbrelay import CMD_ALL_OFF
from mocks.bench import TwinFaults
from mocks.fake_gphoto2 import CameraFault
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.usb_relay_backend import UsbFault
from rig.capture import run_capture
from rig.config import RigConfig
from rig.estimate import estimate_session
from rig.frame_stats import frame_exposure_s
from rig.records import DiscardRecord, ResumeRecord, RetryRecord, StepRecord, StopRecord
from rig.replay import replay_session
from rig.resume import run_resume
from rig.runner import RetryPolicy
from rig.session import Session, find_sessions, read_session
from rig.twin import twin_station_builder
from tests.rig.fakes import wait_for, write_config
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


def matrix_config(directory: Path) -> RigConfig:
    """The small twin, its relays persisted in ``directory/relays.state``, short serial timeouts."""
    data = twin_config_data(directory / "sessions")
    data["devices"]["relays"]["state_file"] = str(directory / "relays.state")
    data["devices"]["spectrometer"]["timeout_s"] = 0.5
    data["devices"]["spectrometer"]["measure_timeout_s"] = 1.0
    return RigConfig.model_validate(data)


@dataclass(frozen=True)
class Sensitivity:
    """An estimate's ``sensitivity.csv``: its sha256 and its values ``(n_wavelengths, 3)``."""

    sha256: str
    values: FloatArray

    @classmethod
    def of(cls, session: Path, out: Path) -> Sensitivity:
        estimate_session(session, out)
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


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> Uninterrupted:
    directory = tmp_path_factory.mktemp("uninterrupted")
    outcome = run_capture(matrix_config(directory), retry=NO_BACKOFF)
    assert outcome.exit_status == "success", outcome
    return Uninterrupted(outcome.session, estimate_inputs(read_session(outcome.session)))


def with_estimate(rows: Iterable[str], always: set[str]) -> list[Any]:
    """``(row, estimate)`` parameters: each row once, checked by its estimator inputs, or by
    running ``rig estimate`` for the rows in ``always``; every other row again with the estimate,
    marked slow (``make test-all``)."""
    params = []
    for row in rows:
        params.append(pytest.param(row, row in always, id=row))
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


def capture_then_resume(directory: Path, builder: Any = None) -> tuple[str, Path]:
    """Capture with ``builder`` (faults); resume without faults if it did not complete.

    Returns the first run's stop reason and the session.
    """
    outcome = run_capture(matrix_config(directory), retry=NO_BACKOFF, builder=builder)
    if outcome.exit_status != "success":
        resumed = run_resume(outcome.session, retry=NO_BACKOFF)
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


def _spectrometer(kind: FaultKind, nth: int = 4, **fault: Any) -> TwinFaults:
    rule_fault = Fault(kind, **fault)
    return TwinFaults(spectrometer=FaultSchedule.once(rule_fault, "M5", nth=nth))


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
}


@pytest.mark.parametrize(("row", "estimate"), with_estimate(ROWS, {"camera-unplugged-mid-bracket"}))
def test_fault(row: str, estimate: bool, tmp_path: Path, uninterrupted: Uninterrupted) -> None:
    expected = ROWS[row]
    reason, path = capture_then_resume(tmp_path, twin_station_builder(faults=expected.faults()))
    assert reason == expected.reason
    session = assert_invariants(path, tmp_path, uninterrupted, estimate)
    if row == "stale-frame-after-exposure-change":
        (discarded,) = [r for r in session.records if isinstance(r, DiscardRecord)]
        assert discarded.reason == "stale" and "metadata says" in discarded.message
    if row in ("spectrometer-timeout", "spectrometer-truncated-reply"):
        (retry,) = [r for r in session.records if isinstance(r, RetryRecord)]
        assert retry.error.reason == "timeout" and retry.error.retryable
    if reason != "completed":
        (resume,) = resumes(session)
        assert resume.previous_status == "failed" and resume.previous_reason == reason
    replay = replay_session(path, tmp_path / "replay")  # one run or two: replays identically
    assert replay.identical, replay


@dataclass(frozen=True)
class DiskFull:
    """``ENOSPC`` on the ``nth`` log record: half of it written (``write``), or its ``fdatasync``."""

    call: str
    nth: int


DISK_FULL = {"write": DiskFull("write", 40), "fsync": DiskFull("fsync", 40)}


@pytest.mark.parametrize(("row", "estimate"), with_estimate(DISK_FULL, {"write"}))
def test_disk_full(
    row: str,
    estimate: bool,
    tmp_path: Path,
    uninterrupted: Uninterrupted,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fault = DISK_FULL[row]
    calls = 0

    def full(real: Callable[..., None]) -> Callable[..., None]:
        def call(fd: int, *data: bytes) -> None:
            nonlocal calls
            is_record = fault.call == "fsync" or data[0].startswith(b'{"seq":')
            calls += is_record
            if is_record and calls == fault.nth:
                if data:
                    os.write(fd, data[0][: len(data[0]) // 2])  # the disk fills mid-line
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            real(fd, *data)

        return call

    name = "_write_all" if fault.call == "write" else "_sync"
    with monkeypatch.context() as patch:
        patch.setattr(session_module, name, full(getattr(session_module, name)))
        outcome = run_capture(matrix_config(tmp_path), retry=NO_BACKOFF)
    assert outcome.reason == "session_write" and outcome.lamps_off
    interrupted = read_session(outcome.session)
    assert interrupted.status == "interrupted" and interrupted.stop is None
    assert (interrupted.torn is not None) == (fault.call == "write")
    resumed = run_resume(outcome.session, retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    session = assert_invariants(outcome.session, tmp_path, uninterrupted, estimate)
    (resume,) = resumes(session)
    assert resume.previous_reason == "no_stop_record"
    assert (resume.torn_line is not None) == (fault.call == "write")


# ----------------------------------------------------------------------------- real processes


def start_twin_capture(directory: Path, slow_capture_s: float) -> subprocess.Popen[str]:
    """``rig capture`` on the twin in a child process, stopped in its second (slow) capture."""
    config = write_config(directory / "rig.yaml", matrix_config(directory).model_dump(mode="json"))
    process = subprocess.Popen(
        [sys.executable, "-m", "tests.rig.twin_process", str(config), str(slow_capture_s)],
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
        return sum('"call": "capture"' in call for call in calls) >= 2

    # The second capture is slow: interrupted there, the run has LED-B3 on and a frame done.
    wait_for(in_second_capture, timeout_s=120, what="the second capture")
    return process


def the_session(directory: Path) -> Path:
    (path,) = find_sessions(directory / "sessions")
    return path


SIGNALS: dict[str, tuple[list[signal.Signals], int, str]] = {
    "sigint-once": ([signal.SIGINT], 130, "interrupted"),
    "sigint-twice": ([signal.SIGINT, signal.SIGINT], 130, "halted"),
    "sigterm": ([signal.SIGTERM], 143, "interrupted"),
}


@pytest.mark.parametrize(("row", "estimate"), with_estimate(SIGNALS, set()))
def test_signals(row: str, estimate: bool, tmp_path: Path, uninterrupted: Uninterrupted) -> None:
    signals, exit_code, reason = SIGNALS[row]
    process = start_twin_capture(tmp_path, slow_capture_s=1.0 if len(signals) == 1 else 30.0)
    for number, signum in enumerate(signals):
        if number:
            time.sleep(0.2)  # let the first be handled (a 30 s capture is still going on)
        process.send_signal(signum)
    code, _, err = finish(process)
    assert code == exit_code, err
    path = the_session(tmp_path)
    stop = read_session(path).stop
    assert stop is not None and (stop.reason, stop.lamps_off) == (reason, True)
    resumed = run_resume(path, retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    session = assert_invariants(path, tmp_path, uninterrupted, estimate)
    (resume,) = resumes(session)
    assert (resume.previous_status, resume.previous_reason) == ("interrupted", reason)


def test_kill_9_then_rig_resume(
    tmp_path: Path, uninterrupted: Uninterrupted, monkeypatch: pytest.MonkeyPatch
) -> None:
    process = start_twin_capture(tmp_path, slow_capture_s=60.0)
    state = tmp_path / "relays.state"
    assert state.read_text().strip() == "10"  # LED-B3 is on for its bracket
    process.kill()
    finish(process)
    assert state.read_text().strip() == "10"  # … and stays on: nobody switched it off
    path = the_session(tmp_path)
    assert read_session(path).stop is None
    monkeypatch.chdir(tmp_path)
    assert run_cli(["resume", str(path), "--quiet"], monkeypatch) == 0
    session = assert_invariants(path, tmp_path, uninterrupted, estimate=True)
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


def test_a_complete_session_is_not_resumed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    outcome = run_capture(matrix_config(tmp_path), retry=NO_BACKOFF)
    assert run_cli(["resume", str(outcome.session)], monkeypatch) == 2
    assert "is complete; there is nothing to resume" in capsys.readouterr().err
