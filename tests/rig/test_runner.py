"""rig.runner with fake devices: end to end, retries, failures, timeouts and interrupts — lamps end off."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from calib.core.spectra import read_spectrum_csv
from drivers.base import DeviceBusy, DeviceTimeout, Disconnected
from rig.capture import run_capture
from rig.clock import MonotonicClock
from rig.config import RigConfig
from rig.errors import LimitsExceeded, SessionWriteError
from rig.interrupts import HaltRequested, InterruptController
from rig.plan import build_plan
from rig.records import InterruptionRecord, RetryRecord, StartRecord, StepRecord
from rig.runner import RetryPolicy, RunOutcome
from rig.session import Session, read_session
from rig.steps import Capture, result_from_json, step_from_record
from tests.rig.fakes import FakeRig, fake_config, fake_config_data, make_fake_rig

FAST_RETRY = RetryPolicy(max_attempts=3, initial_s=0.5, factor=2.0, max_s=5.0)
main_thread_only = pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(),
    reason="signal handlers can only be installed in the main thread",
)


def capture(
    tmp_path: Path,
    rig: FakeRig | None = None,
    config: RigConfig | None = None,
    interrupts: InterruptController | None = None,
) -> tuple[RunOutcome, Session, FakeRig]:
    rig = rig or make_fake_rig()
    outcome = run_capture(
        config or fake_config(tmp_path / "sessions"),
        builder=rig.builder,
        retry=FAST_RETRY,
        interrupts=interrupts,
    )
    return outcome, read_session(outcome.session), rig


def steps_of(session: Session, status: str = "done") -> list[StepRecord]:
    return [r for r in session.records if isinstance(r, StepRecord) and r.status == status]


def assert_lamps_off_and_log_valid(outcome: RunOutcome, session: Session, rig: FakeRig) -> None:
    assert rig.relays.state() == (False, False)
    assert outcome.lamps_off
    assert session.torn is None
    assert session.verify_files() == []
    assert session.stop is not None and session.stop.lamps_off
    assert session.records[-1] == session.stop
    assert rig.closed


@pytest.fixture
def signal_sender() -> Iterator[list[threading.Thread]]:
    threads: list[threading.Thread] = []
    yield threads
    for thread in threads:
        thread.join(timeout=5)


def send_signals_when(
    threads: list[threading.Thread],
    event: threading.Event,
    signals: list[signal.Signals],
    interrupts: InterruptController,
) -> None:
    """Once ``event`` is set, send ``signals`` to this process one at a time.

    Each signal is sent only after ``interrupts`` has registered the previous one: the OS
    coalesces a signal that arrives before the handler of the same signal has run.
    """

    def fire() -> None:
        if not event.wait(10):
            return
        for number, signum in enumerate(signals):
            os.kill(os.getpid(), signum)
            deadline = time.monotonic() + 5
            while len(interrupts.received) <= number and time.monotonic() < deadline:
                time.sleep(0.005)

    thread = threading.Thread(target=fire, daemon=True)
    thread.start()
    threads.append(thread)


class TestEndToEnd:
    def test_a_complete_capture(self, tmp_path: Path) -> None:
        config = fake_config(tmp_path / "sessions")
        outcome, session, rig = capture(tmp_path, config=config)
        assert (outcome.exit_status, outcome.reason, outcome.exit_code) == (
            "success",
            "completed",
            0,
        )
        assert session.status == "complete"
        assert_lamps_off_and_log_valid(outcome, session, rig)

        start = session.start
        assert isinstance(start, StartRecord)
        assert start.config == config.model_dump(mode="json")
        assert start.plan.name == "standard_capture"
        assert start.devices["camera"].model == "FakeCam"
        assert start.clock == "SimulatedClock"

        files = session.files()
        roles = {role: sum(f.role == role for f in files) for role in ("frame", "dark", "spectrum")}
        assert roles["frame"] == rig.camera.captured - roles["dark"]
        assert roles["dark"] == roles["frame"] * config.dark_frames
        assert {f.path for f in files if f.role == "transcript"} == {
            "transcripts/relays.jsonl",
            "transcripts/spectrometer.jsonl",
            "transcripts/camera.jsonl",
        }
        assert session.stop is not None
        assert session.stop.counts["frames"] == roles["frame"]

        # every bracket meets the HDR policy according to the recorded statistics
        for lamp in config.lamps:
            frames = [
                r.result
                for r in steps_of(session)
                if r.action == "Capture" and r.params["lamp"] == lamp.name and r.result
            ]
            by_exposure = sorted(frames, key=lambda f: f["exposure_s"])
            assert by_exposure[0]["stats"]["direct_saturated_fraction"] == 0.0
            assert by_exposure[-1]["stats"]["band_snr"] >= config.hdr.min_band_snr
            assert len(frames) > 1  # the fake scene needs a real bracket

        # frames were exactly what the camera wrote, darks taken with every lamp off
        for record in files:
            if record.role == "dark":
                content = session.file_path(record.path).read_bytes()
                assert b'"lit": []' in content

    def test_the_log_holds_what_the_plan_needs_to_be_re_driven(self, tmp_path: Path) -> None:
        """Resume and replay rebuild the plan from the start record and feed it recorded results."""
        _, session, _ = capture(tmp_path)
        start = session.start
        assert start is not None
        plan = build_plan(start.plan.name, start.plan.args)
        records = steps_of(session)

        def load(relative: str) -> Any:
            stored = read_spectrum_csv(session.file_path(relative))
            return stored.wavelength_nm, stored.values

        step = next(plan)
        for index, record in enumerate(records):
            assert step.key == record.key
            assert step == step_from_record(record.action, record.params)
            assert record.result is not None
            try:
                step = plan.send(result_from_json(step, record.result, load))
            except StopIteration:
                assert index == len(records) - 1
                break
        else:
            pytest.fail("the plan wanted more steps than the log holds")

    def test_transcripts_record_the_exchanges(self, tmp_path: Path) -> None:
        _, session, rig = capture(tmp_path)
        lines = session.file_path("transcripts/camera.jsonl").read_text().splitlines()
        assert len(lines) == 2 * sum(rig.camera.io.calls.values())


class TestRetries:
    def test_a_busy_camera_is_retried_with_backoff(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.camera.io.faults["capture"] = [DeviceBusy("FakeCam", "PTP device busy")]
        outcome, session, rig = capture(tmp_path, rig)
        assert outcome.exit_status == "success"
        (retry,) = [r for r in session.records if isinstance(r, RetryRecord)]
        assert (retry.key, retry.attempt, retry.error.reason) == (
            "lamp/LED-B3/scene/000",
            1,
            "busy",
        )
        assert retry.backoff_s == FAST_RETRY.initial_s
        capture_record = next(r for r in steps_of(session) if r.key == "lamp/LED-B3/scene/000")
        assert capture_record.attempts == 2
        assert not list(session.path.rglob(".incoming*"))
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_retries_are_bounded(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.spectrometer.io.faults["measure"] = [
            DeviceTimeout("FakeSpectro", "no reply", timeout_s=1.0) for _ in range(3)
        ]
        outcome, session, rig = capture(tmp_path, rig)
        assert (outcome.exit_status, outcome.reason, outcome.exit_code) == ("fail", "timeout", 1)
        retries = [r for r in session.records if isinstance(r, RetryRecord)]
        assert [r.backoff_s for r in retries] == [0.5, 1.0]
        (failed,) = steps_of(session, "failed")
        assert failed.attempts == 3 and failed.error is not None
        assert failed.error.reason == "timeout" and failed.error.retryable
        assert session.stop is not None and session.stop.failed_key == failed.key
        assert session.status == "failed"
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_a_non_retryable_error_stops_at_once(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.spectrometer.io.faults["measure"] = [Disconnected("FakeSpectro", "USB device gone")]
        outcome, session, rig = capture(tmp_path, rig)
        assert (outcome.reason, outcome.failed_key) == ("disconnected", "lamp/LED-B3/warmup/000")
        assert not [r for r in session.records if isinstance(r, RetryRecord)]
        assert session.stop is not None and session.stop.error is not None
        assert session.stop.error.device == "FakeSpectro"
        assert "USB device gone" in session.stop.message
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_a_step_that_is_not_safe_to_repeat_is_not_retried(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        monkeypatch.setattr(Capture, "retry_safe", False)
        rig = make_fake_rig()
        rig.camera.io.faults["capture"] = [DeviceBusy("FakeCam", "PTP device busy")]
        outcome, session, rig = capture(tmp_path, rig)
        assert outcome.reason == "busy"
        assert not [r for r in session.records if isinstance(r, RetryRecord)]
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_backoff_is_exponential_and_capped(self) -> None:
        policy = RetryPolicy(max_attempts=10, initial_s=0.5, factor=2.0, max_s=3.0)
        assert [policy.backoff_s(n) for n in range(1, 6)] == [0.5, 1.0, 2.0, 3.0, 3.0]


class TestFailures:
    def test_a_hung_device_call_times_out(self, tmp_path: Path) -> None:
        data = fake_config_data(tmp_path / "sessions")
        data["devices"]["camera"].update(timeout_s=0.05, download_timeout_s=0.1)
        rig = make_fake_rig()
        release = rig.camera.io.hold["capture"] = threading.Event()
        try:
            outcome, session, rig = capture(tmp_path, rig, RigConfig.model_validate(data))
            assert ("end", "camera", "capture") not in rig.events  # it did not wait for the call
        finally:
            release.set()
        assert outcome.reason == "step_timeout"
        assert "did not finish within" in outcome.message
        assert outcome.lamps_off and rig.relays.state() == (False, False)
        assert session.stop is not None and session.torn is None

    def test_a_lamp_that_never_settles(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.spectrometer.flicker["LED-B3"] = 0.05
        outcome, session, rig = capture(tmp_path, rig)
        assert (outcome.reason, outcome.exit_code) == ("lamp_not_stable", 1)
        assert outcome.failed_key is not None and "/warmup/" in outcome.failed_key
        assert "LED-B3 did not settle" in outcome.message
        assert rig.camera.captured == 0
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_limits_read_from_the_camera_stop_before_any_lamp(self, tmp_path: Path) -> None:
        rig = make_fake_rig(exposure_range_s=(1 / 1000, 2.0))
        outcome, session, rig = capture(tmp_path, rig)
        assert (outcome.reason, outcome.exit_code) == ("limits", 2)
        assert ("begin", "relays", "set") not in rig.events
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_static_limits_are_refused_before_anything_is_opened(self, tmp_path: Path) -> None:
        data = fake_config_data(tmp_path / "sessions")
        data["lamps"][1]["channel"] = 1
        rig = make_fake_rig()
        with pytest.raises(LimitsExceeded, match="shares relay channel 1"):
            run_capture(RigConfig.model_validate(data), builder=rig.builder)
        assert not (tmp_path / "sessions").exists()
        assert rig.events == []

    def test_a_lamp_left_on_before_a_dark_frame(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.relays.stuck_on = {2}
        outcome, session, rig = capture(tmp_path, rig)
        assert outcome.reason == "lamps_not_off"
        assert outcome.failed_key == "lamp/LED-B3/dark/000"
        assert "relay channel(s) 2 read as on before a dark frame" in outcome.message
        # the board still reads channel 2 as on: the run says so instead of claiming success
        assert not outcome.lamps_off
        assert session.stop is not None and not session.stop.lamps_off

    def test_a_relay_that_does_not_follow_is_caught_before_any_frame(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.relays.dead = {1}
        outcome, session, rig = capture(tmp_path, rig)
        assert (outcome.reason, outcome.failed_key) == ("state_mismatch", "lamp/LED-B3/switch-on")
        assert (
            "relay channel 1 (LED-B3) did not follow: expected 'on', read back '00'"
            in outcome.message
        )
        assert rig.camera.captured == 0 and rig.spectrometer.io.calls["measure"] == 0
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_cleanup_falls_back_to_switching_each_channel(self, tmp_path: Path) -> None:
        rig = make_fake_rig()
        rig.spectrometer.io.faults["measure"] = [Disconnected("FakeSpectro", "gone")]
        rig.relays.io.faults["all_off"] = [
            None,  # the all-off before anything else
            None,  # the plan's
            DeviceTimeout("FakeRelay", "no reply", timeout_s=1),
        ]
        outcome, session, rig = capture(tmp_path, rig)
        assert outcome.reason == "disconnected"
        assert outcome.lamps_off
        assert rig.relays.io.calls["set"] >= 3  # on, then each channel off
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_the_disk_filling_up_stops_the_run(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        import rig.session as session_module

        real_sync = session_module._sync
        calls = {"n": 0}

        def sync(fd: int) -> None:
            calls["n"] += 1
            if calls["n"] > 30:
                raise OSError(28, "No space left on device")
            real_sync(fd)

        monkeypatch.setattr(session_module, "_sync", sync)
        outcome, session, rig = capture(tmp_path)
        assert (outcome.exit_status, outcome.reason) == ("fail", "session_write")
        assert "No space left on device" in outcome.message
        assert rig.relays.state() == (False, False) and outcome.lamps_off
        # nothing more could be written: the log ends without a stop record, and reads as interrupted
        assert session.stop is None and session.status == "interrupted"
        assert session.verify_files() == []

    def test_a_bug_is_recorded_with_its_traceback(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        def broken(*args: object, **kwargs: object) -> None:
            raise ZeroDivisionError("a bug")

        monkeypatch.setattr("rig.runner.read_spectrum_csv", broken)
        outcome, session, rig = capture(tmp_path)
        assert (outcome.reason, outcome.exit_code) == ("internal", 1)
        assert session.stop is not None and session.stop.error is not None
        assert session.stop.error.traceback is not None
        assert "ZeroDivisionError" in session.stop.error.traceback
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_an_unanalysable_frame(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        rig = make_fake_rig()
        monkeypatch.setattr(rig.analyzer, "analyse", lambda path: 1 / 0)
        outcome, session, rig = capture(tmp_path, rig)
        assert outcome.reason == "frame_analysis"
        assert "ZeroDivisionError" in outcome.message
        # the frame itself is kept and acknowledged
        assert any(f.role == "frame" for f in session.files())
        assert_lamps_off_and_log_valid(outcome, session, rig)


@main_thread_only
class TestInterrupts:
    def test_first_ctrl_c_finishes_the_step_and_stops(
        self, tmp_path: Path, signal_sender: list[threading.Thread]
    ) -> None:
        rig = make_fake_rig()
        rig.camera.io.delay_s["capture"] = 0.3
        interrupts = InterruptController()
        send_signals_when(signal_sender, rig.camera.capture_started, [signal.SIGINT], interrupts)
        outcome, session, rig = capture(tmp_path, rig, interrupts=interrupts)
        assert (outcome.exit_status, outcome.reason, outcome.exit_code) == (
            "abort",
            "interrupted",
            130,
        )
        assert rig.camera.captured == 1
        last_step = steps_of(session)[-1]
        assert last_step.key == "lamp/LED-B3/scene/000"  # the step in progress was finished
        (interruption,) = [r for r in session.records if isinstance(r, InterruptionRecord)]
        assert (interruption.signal, interruption.action) == ("SIGINT", "finish-step")
        assert session.status == "interrupted"
        assert_lamps_off_and_log_valid(outcome, session, rig)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler

    def test_a_wait_is_cut_short(self, tmp_path: Path) -> None:
        """On the wall clock, a stop request during a 5 s warm-up wait cuts it short."""
        rig = make_fake_rig(clock=MonotonicClock())
        interrupts = InterruptController()
        measured, waiting = threading.Event(), threading.Event()
        original_measure, original_sleep = rig.spectrometer.measure, rig.clock.sleep

        def measure() -> Any:
            reading = original_measure()
            measured.set()  # the wait follows the first warm-up spectrum
            return reading

        def sleep(seconds: float) -> None:
            if measured.is_set():
                waiting.set()
            original_sleep(seconds)

        rig.spectrometer.measure = measure  # type: ignore[method-assign]
        rig.clock.sleep = sleep  # type: ignore[method-assign]

        def interrupt_during_the_wait() -> None:
            if waiting.wait(10):
                os.kill(os.getpid(), signal.SIGINT)

        thread = threading.Thread(target=interrupt_during_the_wait, daemon=True)
        thread.start()
        data = fake_config_data(tmp_path / "sessions")
        data["lamps"][0]["warmup"]["interval_s"] = 5
        outcome, session, rig = capture(tmp_path, rig, RigConfig.model_validate(data), interrupts)
        thread.join(5)
        assert outcome.reason == "interrupted"
        wait = steps_of(session)[-1]
        assert wait.key == "lamp/LED-B3/warmup/001/wait" and wait.result is not None
        assert wait.result["completed"] is False
        assert 0.0 < wait.result["waited_s"] < 5.0  # begun, and cut short of its 5 s
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_sigterm_is_a_clean_stop(
        self, tmp_path: Path, signal_sender: list[threading.Thread]
    ) -> None:
        rig = make_fake_rig()
        rig.camera.io.delay_s["capture"] = 0.3
        interrupts = InterruptController()
        send_signals_when(signal_sender, rig.camera.capture_started, [signal.SIGTERM], interrupts)
        outcome, session, rig = capture(tmp_path, rig, interrupts=interrupts)
        assert (outcome.reason, outcome.exit_code) == ("interrupted", 143)
        assert_lamps_off_and_log_valid(outcome, session, rig)

    def test_second_ctrl_c_stops_at_once(
        self, tmp_path: Path, signal_sender: list[threading.Thread]
    ) -> None:
        rig = make_fake_rig()
        release = rig.camera.io.hold["capture"] = threading.Event()
        interrupts = InterruptController()
        twice = [signal.SIGINT, signal.SIGINT]
        send_signals_when(signal_sender, rig.camera.capture_started, twice, interrupts)
        try:
            outcome, session, rig = capture(tmp_path, rig, interrupts=interrupts)
            assert ("end", "camera", "capture") not in rig.events  # did not wait for the capture
        finally:
            release.set()
        assert (outcome.reason, outcome.exit_code) == ("halted", 130)
        actions = [r.action for r in session.records if isinstance(r, InterruptionRecord)]
        assert actions == ["finish-step", "stop-now"]
        assert session.status == "interrupted"
        assert rig.relays.state() == (False, False) and outcome.lamps_off
        assert session.torn is None and session.verify_files() == []

    def test_an_exchange_is_never_cut_in_half(
        self, tmp_path: Path, signal_sender: list[threading.Thread]
    ) -> None:
        """Two Ctrl-C during a slow relay exchange: the cleanup's all-off waits for it to end."""
        rig = make_fake_rig()
        rig.relays.io.delay_s["set"] = 0.5
        started = threading.Event()
        original_set = rig.relays.set

        def set_and_flag(channel: int, on: bool) -> None:
            started.set()
            original_set(channel, on)

        rig.relays.set = set_and_flag  # type: ignore[method-assign]
        interrupts = InterruptController()
        send_signals_when(signal_sender, started, [signal.SIGINT, signal.SIGINT], interrupts)
        outcome, _, rig = capture(tmp_path, rig, interrupts=interrupts)
        assert outcome.reason == "halted"
        relay_events = [(kind, method) for kind, device, method in rig.events if device == "relays"]
        set_end = relay_events.index(("end", "set"))
        cleanup = max(i for i, event in enumerate(relay_events) if event == ("begin", "all_off"))
        assert set_end < cleanup
        assert rig.relays.state() == (False, False)


class TestInterruptController:
    def test_a_second_signal_inside_a_critical_section_waits_for_its_end(self) -> None:
        controller = InterruptController()
        controller._handle(signal.SIGINT, None)
        assert controller.stop_requested == "SIGINT"
        with pytest.raises(HaltRequested), controller.critical():
            controller._handle(signal.SIGINT, None)  # held: no exception here
            completed = True
        assert completed

    def test_outside_a_critical_section_the_second_signal_raises(self) -> None:
        controller = InterruptController()
        controller._handle(signal.SIGTERM, None)
        with pytest.raises(HaltRequested, match="SIGINT"):
            controller._handle(signal.SIGINT, None)
        assert controller.halted

    def test_during_cleanup_signals_are_only_noted(self) -> None:
        controller = InterruptController()
        controller._handle(signal.SIGINT, None)
        controller.enter_cleanup()
        controller._handle(signal.SIGINT, None)
        with controller.critical():
            controller._handle(signal.SIGINT, None)
        assert [r.action for r in controller.received] == ["finish-step", "stop-now", "stop-now"]

    def test_once_a_halt_is_under_way_further_signals_are_only_noted(self) -> None:
        """A third Ctrl-C must not cut the cleanup the second one began (before it reaches
        :meth:`enter_cleanup`): one ``HaltRequested``, raised at once or at the section's end."""
        controller = InterruptController()
        controller._handle(signal.SIGINT, None)
        with pytest.raises(HaltRequested):
            controller._handle(signal.SIGINT, None)
        controller._handle(signal.SIGINT, None)  # noted, not raised
        held = InterruptController()
        held._handle(signal.SIGINT, None)
        with pytest.raises(HaltRequested), held.critical():
            held._handle(signal.SIGINT, None)
            held._handle(signal.SIGTERM, None)
        held._handle(signal.SIGINT, None)
        assert [r.action for r in controller.received] == ["finish-step", "stop-now", "stop-now"]
        assert [r.name for r in held.received] == ["SIGINT", "SIGINT", "SIGTERM", "SIGINT"]

    def test_handlers_are_not_installed_outside_the_main_thread(self) -> None:
        results: list[bool] = []
        thread = threading.Thread(target=lambda: results.append(InterruptController().install()))
        thread.start()
        thread.join(5)
        assert results == [False]


def test_a_session_write_error_is_not_retried(tmp_path: Path) -> None:
    rig = make_fake_rig()
    rig.camera.io.faults["capture"] = [SessionWriteError("transcript: disk full")]
    outcome, session, rig = capture(tmp_path, rig)
    assert outcome.reason == "session_write"
    assert not [r for r in session.records if isinstance(r, RetryRecord)]
    assert rig.relays.state() == (False, False)
    (failed,) = steps_of(session, "failed")
    assert failed.error is not None and failed.error.reason == "session_write"
