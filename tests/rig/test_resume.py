"""``rig resume`` on the fake rig: what is reused, what is done again, what is recorded."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from drivers.base import Disconnected, SpectrumReading
from rig.capture import run_capture
from rig.config import RigConfig
from rig.errors import NotResumable, ResumeConfigRefused
from rig.records import DiscardRecord, ResumeRecord, StartRecord, StepRecord
from rig.resume import run_resume
from rig.runner import RetryPolicy, RunOutcome
from rig.session import SessionWriter, read_session
from tests.rig.fakes import FakeRig, fake_config, fake_config_data, make_fake_rig, write_config
from tests.rig.test_cli import run_cli

NO_BACKOFF = RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)


def user_config(tmp_path: Path) -> RigConfig:
    """The configuration the sessions of these tests were captured with: the user's own."""
    return fake_config(tmp_path / "sessions")


def failed_mid_bracket(tmp_path: Path) -> RunOutcome:
    """A capture whose camera goes away at the second frame of the first lamp's bracket."""
    rig = make_fake_rig()
    rig.camera.io.faults["capture"] = [None, Disconnected("FakeCam", "unplugged")]
    outcome = run_capture(fake_config(tmp_path / "sessions"), builder=rig.builder, retry=NO_BACKOFF)
    assert (outcome.reason, outcome.failed_key) == ("disconnected", "lamp/LED-B3/scene/001")
    return outcome


def step_keys(path: Path, run: int) -> list[str]:
    session = read_session(path)
    return [r.key for r in session.records if isinstance(r, StepRecord) and r.run == run]


def test_a_failed_session_continues_where_it_stopped(tmp_path: Path) -> None:
    failed = failed_mid_bracket(tmp_path)
    rig = make_fake_rig()
    outcome = run_resume(
        failed.session, user_config(tmp_path), builder=rig.builder, retry=NO_BACKOFF
    )
    assert outcome.exit_status == "success", outcome
    session = read_session(failed.session)
    assert session.status == "complete" and session.verify_files() == []
    assert rig.relays.state() == (False, False)
    (resume,) = [r for r in session.records if isinstance(r, ResumeRecord)]
    assert (resume.previous_status, resume.previous_reason) == ("failed", "disconnected")
    assert resume.resume_key == "lamp/LED-B3/scene/001"
    assert "lamp/LED-B3/switch-on" in resume.redo and "lamp/LED-B3/reference/000" in resume.redo
    run2 = step_keys(failed.session, 2)
    # Devices set up again, LED-B3 switched on, warmed up and measured again …
    setup = ["start/all-lamps-off", "start/camera", "start/spectrometer"]
    assert run2[:4] == [*setup, "lamp/LED-B3/switch-on"]
    # … its first frame reused, its exposure for the second frame set again, nothing done twice.
    assert "lamp/LED-B3/scene/000" not in run2
    assert "lamp/LED-B3/scene/001/exposure" in run2
    assert len(run2) == len(set(run2))
    starts = [r for r in session.records if isinstance(r, StartRecord)]
    assert [s.run for s in starts] == [1, 2] and starts[1].schema_version == 2
    assert (failed.session / "transcripts" / "camera.run2.jsonl").exists()


def test_another_camera_body_is_refused_and_the_session_stays_resumable(tmp_path: Path) -> None:
    failed = failed_mid_bracket(tmp_path)
    other = make_fake_rig()
    other.camera.serial = "C2"
    outcome = run_resume(
        failed.session, user_config(tmp_path), builder=other.builder, retry=NO_BACKOFF
    )
    assert (outcome.exit_status, outcome.reason) == ("fail", "resume_mismatch")
    assert "FakeCam (serial C2)" in outcome.message and "serial C1" in outcome.message
    assert outcome.lamps_off and other.relays.state() == (False, False)
    assert other.camera.captured == 0
    session = read_session(failed.session)
    assert session.status == "failed" and not any(
        isinstance(r, ResumeRecord) for r in session.records
    )
    # A replug on another port is the same camera; with the original body it goes on.
    again = make_fake_rig()
    again.camera.port = "fake:usb-2"
    assert run_resume(
        failed.session, user_config(tmp_path), builder=again.builder, retry=NO_BACKOFF
    ).exit_status == ("success")
    starts = [r for r in read_session(failed.session).records if isinstance(r, StartRecord)]
    assert [s.devices["camera"].port for s in starts] == ["fake:usb", "fake:usb", "fake:usb-2"]


def test_a_frame_that_no_longer_verifies_is_discarded_and_taken_again(tmp_path: Path) -> None:
    failed = failed_mid_bracket(tmp_path)
    frame = failed.session / "frames" / "LED-B3" / "scene-000.dng"
    frame.write_bytes(frame.read_bytes() + b"!")
    outcome = run_resume(
        failed.session, user_config(tmp_path), builder=make_fake_rig().builder, retry=NO_BACKOFF
    )
    assert outcome.exit_status == "success", outcome
    session = read_session(failed.session)
    (discarded,) = [r for r in session.records if isinstance(r, DiscardRecord)]
    assert (discarded.path, discarded.reason) == ("frames/LED-B3/scene-000.dng", "unverified")
    assert "lamp/LED-B3/scene/000" in step_keys(failed.session, 2)
    assert session.verify_files() == []  # the discarded file is no longer acknowledged
    result = session.done_steps()["lamp/LED-B3/scene/000"].result
    assert result is not None and result["file"] == "frames/LED-B3/scene-000.2.dng"


def test_a_new_configuration_may_change_how_devices_are_reached(tmp_path: Path) -> None:
    failed = failed_mid_bracket(tmp_path)
    data = fake_config_data(tmp_path / "sessions")
    data["devices"]["spectrometer"]["timeout_s"] = 7
    data["devices"]["camera"]["download_timeout_s"] = 9
    outcome = run_resume(
        failed.session,
        RigConfig.model_validate(data),
        builder=make_fake_rig().builder,
        retry=NO_BACKOFF,
    )
    assert outcome.exit_status == "success", outcome
    starts = [r for r in read_session(failed.session).records if isinstance(r, StartRecord)]
    assert [s.config["devices"]["spectrometer"]["timeout_s"] for s in starts] == [5, 7]


@pytest.mark.parametrize(
    ("change", "named"),
    [
        (lambda data: data["camera"].update(iso=200), "camera.iso"),
        (lambda data: data["lamps"].pop(), "lamps"),
        (lambda data: data["devices"]["relays"].update(channels=4), "devices.relays.channels"),
    ],
)
def test_a_new_configuration_that_changes_the_measurement_is_refused(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    change: Callable[[dict[str, Any]], object],
    named: str,
) -> None:
    failed = failed_mid_bracket(tmp_path)
    data = fake_config_data(tmp_path / "sessions")
    change(data)
    with pytest.raises(ResumeConfigRefused, match=re.escape(named)):
        run_resume(failed.session, RigConfig.model_validate(data))
    config_file = write_config(tmp_path / "changed.yaml", data)
    args = ["resume", str(failed.session), "--config", str(config_file)]
    assert run_cli(args, monkeypatch) == 2
    assert named in capsys.readouterr().err
    assert read_session(failed.session).status == "failed"  # nothing was written


def test_a_complete_session_is_refused(tmp_path: Path) -> None:
    rig = make_fake_rig()
    outcome = run_capture(fake_config(tmp_path / "sessions"), builder=rig.builder)
    with pytest.raises(NotResumable, match="is complete"):
        run_resume(outcome.session, user_config(tmp_path), builder=make_fake_rig().builder)


def test_sessions_says_which_can_be_resumed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    failed_mid_bracket(tmp_path)
    run_capture(fake_config(tmp_path / "sessions"), builder=make_fake_rig().builder)
    assert run_cli(["sessions", str(tmp_path / "sessions")], monkeypatch) == 0
    out = capsys.readouterr().out
    rows = sorted(line.split()[1:3] for line in out.splitlines() if "Z-" in line)
    assert rows == [["complete", "no"], ["failed", "yes"]]


def test_a_torn_last_line_is_moved_aside_and_nothing_else_changes(tmp_path: Path) -> None:
    failed = failed_mid_bracket(tmp_path)
    log = failed.session / "log.jsonl"
    intact = log.read_bytes()
    log.write_bytes(intact + b'{"seq": 99, "run"')
    writer = SessionWriter.append(read_session(failed.session))
    writer.close()
    assert log.read_bytes() == intact
    assert writer.torn_moved_to == "log.jsonl.torn-1"
    assert (failed.session / "log.jsonl.torn-1").read_bytes() == b'{"seq": 99, "run"'


class LaggingSpectrometer:
    """Wraps the fake spectrometer: the first reading after a new integration time uses the old one."""

    def __init__(self, rig: FakeRig) -> None:
        self.inner = rig.spectrometer
        self.previous_ms: float | None = 50.0
        self.lagging = False

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)

    def set_exposure(self, exposure_ms: float | None) -> None:
        self.inner.set_exposure(exposure_ms)
        self.lagging = True

    def measure(self) -> SpectrumReading:
        reading = self.inner.measure()
        if self.lagging:
            self.lagging = False
            return SpectrumReading(
                reading.wavelength_nm, reading.values, reading.units, self.previous_ms
            )
        return reading


def test_a_stale_spectrum_is_discarded_and_measured_again(tmp_path: Path) -> None:
    data = fake_config_data(tmp_path / "sessions")
    data["spectrum"]["exposure_ms"] = 200
    rig = make_fake_rig()
    lagging = LaggingSpectrometer(rig)
    builder = rig.builder

    def build(config: RigConfig, transcripts: object) -> object:
        station = builder(config, transcripts)  # type: ignore[arg-type]
        station.spectrometer = lagging  # type: ignore[assignment]
        return station

    outcome = run_capture(RigConfig.model_validate(data), builder=build)  # type: ignore[arg-type]
    assert outcome.exit_status == "success", outcome
    session = read_session(outcome.session)
    (discarded,) = [r for r in session.records if isinstance(r, DiscardRecord)]
    assert (discarded.key, discarded.reason) == ("lamp/LED-B3/warmup/000", "stale")
    assert "reports 50 ms of integration, it was set to 200 ms" in discarded.message
    assert session.done_steps()["lamp/LED-B3/warmup/000"].result["file"] != discarded.path  # type: ignore[index]
    assert session.verify_files() == []
