"""``rig replay``: a twin session replayed on its own transcripts; divergence, tampering, hostility.

The twin records real transcripts (real drivers on emulators), so a twin session is a faithful
recording to replay. Replays run the real runner, plan and drivers on the stand-ins of
:mod:`mocks.replay`.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from drivers.relays import hid_usbrelay
from drivers.spectrometer import pr6xx
from mocks.bench import TwinFaults
from mocks.fake_gphoto2 import CameraFault
from mocks.faults import Fault, FaultKind, FaultRule, FaultSchedule
from mocks.replay.script import comparable
from mocks.usb_relay_backend import UsbFault
from rig.capture import run_capture
from rig.config import RigConfig
from rig.interrupts import InterruptController, ReceivedSignal
from rig.progress import SilentProgress
from rig.records import StartRecord
from rig.replay import (
    ReplayDiverged,
    ReplayRefused,
    compare_logs,
    load_recording,
    replay_session,
)
from rig.resume import run_resume
from rig.runner import RetryPolicy
from rig.session import decode_transcript_line, read_session
from rig.steps import Step, StepResult
from rig.twin import twin_station_builder
from tests.rig.hostile import watching
from tests.rig.test_cli import run_cli
from tests.rig.twin_setup import twin_config, twin_config_data

FAST_RETRY = RetryPolicy(max_attempts=3, initial_s=0.01, max_s=0.01)


def _twin_session(directory: Path, **options: object) -> Path:
    outcome = run_capture(twin_config(directory), retry=FAST_RETRY, **options)  # type: ignore[arg-type]
    assert outcome.exit_status == "success", outcome
    return outcome.session


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _twin_session(tmp_path_factory.mktemp("recorded"))


@pytest.fixture
def session_copy(recorded: Path, tmp_path: Path) -> Path:
    """A copy of the recorded session that a test may tamper with."""
    copy = tmp_path / "copy" / recorded.name
    shutil.copytree(recorded, copy, symlinks=True)
    return copy


def _data_files(session: Path) -> dict[str, str]:
    return {
        path.relative_to(session).as_posix(): hashlib.sha256(path.read_bytes()).hexdigest()
        for directory in ("frames", "spectra")
        for path in sorted((session / directory).rglob("*"))
        if path.is_file()
    }


def _sent(session: Path, role: str) -> list[object]:
    """What the rig sent to a device, as replay compares it (opaque handles as handles)."""
    lines = (session / "transcripts" / f"{role}.jsonl").read_text().splitlines()
    entries = [decode_transcript_line(line) for line in lines]
    return [comparable(e) for e in entries if e.direction in ("tx", "call")]


def _rewrite_log(session: Path, edit: object) -> None:
    """Apply ``edit(record_dict)`` to every log record (a forged but self-consistent log)."""
    log = session / "log.jsonl"
    records = [json.loads(line) for line in log.read_text().splitlines()]
    log.write_text("".join(json.dumps(edit(r)) + "\n" for r in records))  # type: ignore[operator]


def _acknowledge(session: Path, relative: str) -> None:
    """Make the log's record of ``relative`` match the file as it now is (a consistent forgery)."""
    data = (session / relative).read_bytes()

    def edit(record: dict[str, object]) -> dict[str, object]:
        if record.get("path") == relative:
            record |= {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        return record

    _rewrite_log(session, edit)


# ------------------------------------------------------------------------------- faithful


def test_a_twin_session_replays_identically(recorded: Path, tmp_path: Path) -> None:
    outcome = replay_session(recorded, tmp_path / "replay")
    assert outcome.mismatch is None and outcome.difference is None, outcome
    assert outcome.identical and outcome.run.exit_status == "success"
    replay = outcome.run.session
    assert _data_files(replay) == _data_files(recorded)  # frames as served, spectra re-parsed
    for role in ("relays", "spectrometer", "camera"):
        assert _sent(replay, role) == _sent(recorded, role)
    assert read_session(replay).verify_files() == []


def test_the_comparison_finds_a_changed_record(recorded: Path, tmp_path: Path) -> None:
    replay = replay_session(recorded, tmp_path / "replay").run.session

    def bump(record: dict[str, object]) -> dict[str, object]:
        if record.get("key") == "start/camera" and record.get("type") == "step":
            record["attempts"] = 2
        return record

    _rewrite_log(replay, bump)
    difference = compare_logs(read_session(recorded), read_session(replay))
    assert difference is not None and '"attempts": 2' in difference


@pytest.mark.parametrize(
    ("spectrometer", "relays"),
    [
        # Both families replay through the same record/replay layer: one in the default suite.
        pytest.param("cs2000", "lcus", marks=pytest.mark.slow),
        ("pr670", "numato"),
    ],
)
def test_every_driver_family_replays_identically(
    tmp_path: Path, spectrometer: str, relays: str
) -> None:
    data = twin_config_data(tmp_path / "sessions")
    data["devices"]["spectrometer"]["emulate"] = spectrometer
    data["devices"]["relays"]["emulate"] = relays
    config = RigConfig.model_validate(data)
    source = run_capture(config, retry=FAST_RETRY).session
    outcome = replay_session(source, tmp_path / "replay")
    assert outcome.identical and outcome.run.exit_status == "success", outcome


GARBLED_SPECTRUM = FaultRule(Fault(FaultKind.GARBLED_REPLY), match="M5", nth=2)
HUNG_SPECTROMETER = FaultRule(Fault(FaultKind.NO_REPLY), match="M5", nth=3)
FAULTS = {
    "garbled spectrum, retried by the runner": TwinFaults(
        spectrometer=FaultSchedule([GARBLED_SPECTRUM])
    ),
    "relay board stalls, retried": TwinFaults(usb_relays=[UsbFault("stall", "get_report", 3)]),
    "relay state garbled: the run fails": TwinFaults(
        usb_relays=[UsbFault("garbled_reply", skip=4)]
    ),
    "camera unplugged and found again": TwinFaults(camera=[CameraFault("unplug", skip=40)]),
    "camera busy, recovered by its driver": TwinFaults(
        camera=[CameraFault("busy", skip=1, times=2)]
    ),
    # The driver's measurement deadline (1 s here, as in the fault matrix: the twin measures in
    # ms) ends it, before the runner's watchdog; the runner retries. The replay waits the
    # recorded deadline out again.
    "spectrometer silent: the driver times out, retried": TwinFaults(
        spectrometer=FaultSchedule([HUNG_SPECTROMETER])
    ),
}


#: The spectrometer's measurement deadline of the fault rows (the small twin's is 2 s): a silent
#: spectrometer waits it out twice, in the capture and in the replay; how long does not matter.
FAULT_MEASURE_TIMEOUT_S = 1.0


def _replays_identically(tmp_path: Path, faults: TwinFaults) -> None:
    data = twin_config_data(tmp_path / "faulty")
    data["devices"]["spectrometer"]["measure_timeout_s"] = FAULT_MEASURE_TIMEOUT_S
    source = run_capture(
        RigConfig.model_validate(data),
        retry=FAST_RETRY,
        builder=twin_station_builder(faults=faults),
    ).session
    outcome = replay_session(source, tmp_path / "replay")
    assert outcome.identical, outcome


@pytest.mark.usefixtures("fast_camera_recovery")
@pytest.mark.parametrize("faults", FAULTS.values(), ids=FAULTS.keys())
def test_a_session_with_faults_replays_identically(tmp_path: Path, faults: TwinFaults) -> None:
    _replays_identically(tmp_path, faults)


class _SignalAt(SilentProgress):
    """Delivers one Ctrl-C (as the signal handler notes it) when a step starts or ends."""

    def __init__(self, interrupts: InterruptController, key: str, when: str) -> None:
        self.interrupts, self.key, self.when = interrupts, key, when

    def _deliver(self, step: Step, when: str) -> None:
        if step.key == self.key and when == self.when:
            self.interrupts.received.append(ReceivedSignal("SIGINT", 0.0, "finish-step"))

    def step_started(self, step: Step) -> None:
        self._deliver(step, "start")

    def step_done(self, step: Step, result: StepResult) -> None:
        self._deliver(step, "done")


@pytest.mark.parametrize(
    ("key", "when"),
    [("lamp/LED-B3/reference/000", "done"), ("lamp/LED-B3/warmup/001/wait", "start")],
)
def test_an_interrupted_session_replays_identically(tmp_path: Path, key: str, when: str) -> None:
    interrupts = InterruptController()
    outcome = run_capture(
        twin_config(tmp_path / "sessions"),
        retry=FAST_RETRY,
        interrupts=interrupts,
        progress=_SignalAt(interrupts, key, when),
    )
    assert outcome.exit_status == "abort" and outcome.signal == "SIGINT", outcome
    replay = replay_session(outcome.session, tmp_path / "replay")
    assert replay.identical, replay
    assert replay.run.exit_status == "abort" and replay.run.exit_code == 130


def test_rig_replay_command(
    recorded: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "replayed"
    assert run_cli(["replay", str(recorded), "--out", str(out)], monkeypatch) == 0
    printed = capsys.readouterr().out
    assert f"replay: {out}" in printed
    assert "log: identical to the recording (times and ids masked)" in printed


def test_the_default_output_is_next_to_the_session(
    session_copy: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_cli(["replay", str(session_copy)], monkeypatch) == 0
    assert (session_copy.parent / f"{session_copy.name}-replay" / "log.jsonl").is_file()
    assert sorted(p.name for p in session_copy.parent.iterdir()) == [
        session_copy.name,
        f"{session_copy.name}-replay",
    ]


# ------------------------------------------------------------------------------- divergence


def test_a_different_command_fails_with_a_diff(
    recorded: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The rig of today switches everything off with another command than the recording's.
    monkeypatch.setattr(hid_usbrelay, "CMD_ALL_OFF", 0xFE)
    out = tmp_path / "replayed"
    assert run_cli(["replay", str(recorded), "--out", str(out)], monkeypatch) == 1
    err = capsys.readouterr().err
    assert "the rig diverged from the recording" in err
    # Every run switches the lamps off while opening the devices, before the plan starts.
    assert "step (opening the devices): relays: the rig sent a different command" in err
    assert "at transcripts/relays.jsonl line" in err
    assert "expected: tx 20 09 00 03 00 00 08 00 fc" in err
    assert "sent:     tx 20 09 00 03 00 00 08 00 fe" in err
    assert all(line.startswith("rig: error: ") for line in err.splitlines())


def test_a_different_command_while_opening_fails_with_a_diff(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(pr6xx, "REMOTE_MODE_COMMAND", b"PHOTO\r")
    with pytest.raises(ReplayDiverged) as diverged:
        replay_session(recorded, tmp_path / "replay")
    message = str(diverged.value)
    assert message.startswith("step (opening the devices): spectrometer: the rig sent a different")
    assert "expected: tx 50 48 4f 54 4f  b'PHOTO'" in message
    assert "sent:     tx 50 48 4f 54 4f 0d  b'PHOTO\\r'" in message
    assert not (tmp_path / "replay").exists()  # devices that do not open leave no session


def test_a_recorded_command_left_unused_fails(session_copy: Path, tmp_path: Path) -> None:
    transcript = session_copy / "transcripts" / "spectrometer.jsonl"
    lines = transcript.read_text().splitlines()
    extra = json.loads(next(line for line in reversed(lines) if '"dir": "tx"' in line))
    transcript.write_text("\n".join([*lines, json.dumps(extra)]) + "\n")
    _acknowledge(session_copy, "transcripts/spectrometer.jsonl")
    outcome = replay_session(session_copy, tmp_path / "replay")
    assert outcome.mismatch is not None
    assert "spectrometer: a recorded command was never sent" in outcome.mismatch
    assert f"line {len(lines) + 1}" in outcome.mismatch


def test_an_edited_reply_changes_the_log(session_copy: Path, tmp_path: Path) -> None:
    # A consistent forgery of the relay board's answer: the replay reads what the forger wrote.
    transcript = session_copy / "transcripts" / "relays.jsonl"
    lines = transcript.read_text().splitlines()
    index = max(i for i, line in enumerate(lines) if '"dir": "rx"' in line)
    forged = json.loads(lines[index])
    forged["data"] = forged["data"][:-2] + "01"  # relay 1 reads as on at the end
    lines[index] = json.dumps(forged)
    transcript.write_text("\n".join(lines) + "\n")
    _acknowledge(session_copy, "transcripts/relays.jsonl")
    outcome = replay_session(session_copy, tmp_path / "replay")
    assert not outcome.identical
    assert outcome.difference is not None and '"lamps_off"' in outcome.difference


# ------------------------------------------------------------------------------- untrusted input


@pytest.fixture
def refuse(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> Callable[[Path], str]:
    """``rig replay`` of a session that must be refused: exit 2, one line, nothing written."""

    def replay(session: Path) -> str:
        out = tmp_path / "replayed"
        before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
        assert run_cli(["replay", str(session), "--out", str(out)], monkeypatch) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and err.startswith("rig: error: ")
        assert not out.exists()
        assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
        return err

    return replay


def test_a_transcript_path_leaving_the_session_is_refused(
    session_copy: Path,
    refuse: Callable[[Path], str],
) -> None:
    def escape(record: dict[str, object]) -> dict[str, object]:
        if record.get("path") == "transcripts/relays.jsonl":
            record["path"] = "../../etc/passwd"
        return record

    _rewrite_log(session_copy, escape)
    err = refuse(session_copy)
    assert "../../etc/passwd" in err and "[session_format]" in err


def test_a_symlinked_frame_is_refused(
    session_copy: Path, tmp_path: Path, refuse: Callable[[Path], str]
) -> None:
    frame = next((session_copy / "frames").rglob("scene-000.dng"))
    outside = tmp_path / "outside.dng"
    frame.rename(outside)
    frame.symlink_to(outside)
    err = refuse(session_copy)
    assert "symlink" in err and "[replay_refused]" in err


def test_a_tampered_transcript_is_refused(
    session_copy: Path,
    refuse: Callable[[Path], str],
) -> None:
    transcript = session_copy / "transcripts" / "spectrometer.jsonl"
    transcript.write_text(transcript.read_text().replace("50484f544f", "50484f544e", 1))
    err = refuse(session_copy)
    assert "transcripts/spectrometer.jsonl: sha256 differs from the log" in err


def test_a_missing_transcript_is_refused(
    session_copy: Path,
    refuse: Callable[[Path], str],
) -> None:
    (session_copy / "transcripts" / "camera.jsonl").unlink()
    err = refuse(session_copy)
    # the path once ("camera.jsonl: transcripts/camera.jsonl does not exist" before)
    assert f"{session_copy}: transcripts/camera.jsonl: does not exist (1 file problem(s))" in err


@pytest.mark.parametrize(
    ("field", "value", "shown"),
    [
        ("payload", "!!python/object/apply:os.system ['touch /tmp/pwned']", "config.payload"),
        ("seed", {"__reduce__": "os.system"}, "config.seed"),
    ],
)
def test_a_hostile_configuration_is_refused(
    session_copy: Path,
    refuse: Callable[[Path], str],
    field: str,
    value: object,
    shown: str,
) -> None:
    def poison(record: dict[str, object]) -> dict[str, object]:
        if record.get("type") == "start":
            record["config"][field] = value  # type: ignore[index]
        return record

    _rewrite_log(session_copy, poison)
    err = refuse(session_copy)
    assert "the recorded configuration or plan is invalid" in err and shown.split(".")[1] in err


def test_a_replay_into_the_recorded_session_is_refused(
    session_copy: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = session_copy / "frames" / "replay"
    assert run_cli(["replay", str(session_copy), "--out", str(out)], monkeypatch) == 2
    assert "replay never writes there [replay_refused]" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.usefixtures("fast_camera_recovery")
@pytest.mark.parametrize("first_run", ["camera unplugged", "interrupted by a signal"])
def test_a_resumed_session_replays_run_by_run(tmp_path: Path, first_run: str) -> None:
    """Run 1 on its transcripts, then `rig resume` of the replay on run 2's: one identical log."""
    config = twin_config(tmp_path / "sessions")
    if first_run == "camera unplugged":
        builder = twin_station_builder(faults=TwinFaults(camera=[CameraFault("unplug", skip=1)]))
        first = run_capture(config, retry=FAST_RETRY, builder=builder)
        assert first.reason == "disconnected", first
    else:
        interrupts = InterruptController()
        progress = _SignalAt(interrupts, "lamp/LED-B3/reference/000", "done")
        first = run_capture(config, retry=FAST_RETRY, interrupts=interrupts, progress=progress)
        assert first.exit_status == "abort", first
    assert run_resume(first.session, config, retry=FAST_RETRY).exit_status == "success"
    starts = [r for r in read_session(first.session).records if isinstance(r, StartRecord)]
    assert [s.run for s in starts] == [1, 2]
    replay = replay_session(first.session, tmp_path / "replay")
    assert replay.identical, replay
    assert replay.run.exit_status == "success"
    replayed = read_session(tmp_path / "replay")
    assert [r.run for r in replayed.records if isinstance(r, StartRecord)] == [1, 2]
    assert (tmp_path / "replay" / "transcripts" / "camera.run2.jsonl").exists()


def test_a_resumed_run_without_its_transcripts_is_refused(session_copy: Path) -> None:
    log = session_copy / "log.jsonl"
    lines = log.read_text().splitlines()
    second = json.loads(lines[0]) | {"seq": len(lines), "run": 2}
    log.write_text("\n".join([*lines, json.dumps(second)]) + "\n")
    with pytest.raises(ReplayRefused, match="no acknowledged transcript of run 2"):
        load_recording(session_copy)


@pytest.mark.slow
def test_rig_estimate_of_the_replay_gives_the_identical_result(
    recorded: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    replay = tmp_path / "replayed"
    assert run_cli(["replay", str(recorded), "--out", str(replay)], monkeypatch) == 0
    sensitivities = []
    for session in (recorded, replay):
        out = tmp_path / f"estimate-{session.name}"
        assert run_cli(["estimate", str(session), "--out", str(out), "--quiet"], monkeypatch) == 0
        sensitivities.append((out / "sensitivity.csv").read_bytes())
    assert sensitivities[0] == sensitivities[1]


def test_ports_and_files_the_snapshot_names_are_never_opened_by_a_replay(
    session_copy: Path, tmp_path: Path
) -> None:
    """Replay drives stand-ins: the recorded configuration's ports and state file are data."""
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "victim").write_bytes(b"the user's own file")
    url = f"spy://loop://?file={outside / 'victim'}"

    def hostile(record: dict[str, object]) -> dict[str, object]:
        if record.get("type") == "start":
            devices = record["config"]["devices"]  # type: ignore[index]
            devices["spectrometer"] = {"kind": "pr655", "port": url}
            devices["relays"] = {"kind": "lcus", "port": "socket://127.0.0.1:9", "channels": 2}
            devices["camera"] = {"kind": "gphoto2", "port": "usb:001,002"}
        return record

    _rewrite_log(session_copy, hostile)
    with watching(outside) as watch:
        outcome = replay_session(session_copy, tmp_path / "replay")
    assert watch.touches == [] and watch.connections == []
    assert outcome.mismatch is None  # the recorded exchanges, as recorded
