"""Every injected camera fault ends in recovery or the right typed error, within its deadline."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from drivers.base import (
    DeviceBusy,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ListTranscript,
    ProtocolError,
)
from drivers.camera import CameraTimeouts, classify_gphoto_error
from mocks.fake_gphoto2 import CameraFault, FakeBody, FakeGphoto2, canon_eos_body
from mocks.lamps import SimulatedClock
from tests.usb_camera.conftest import FAST_TIMEOUTS, CameraRig, open_on

#: How long a test waits for something the fake's threads are due to do (a loaded machine is slow).
SETTLE_DEADLINE_S = 10.0


def events(transcript: ListTranscript, name: str) -> list[dict[str, object]]:
    decoded = [json.loads(e.payload) for e in transcript.entries if e.direction == "event"]
    return [body for body in decoded if body.get("event") == name]


class CallsInside:
    """Counts the library calls named ``call`` that are inside the fake body, not yet returned.

    A hang holds its call until the test releases it, so a deadline shown to pass while the hung
    call is still inside was not waited out by waiting for the call (a wall-clock bound on the
    whole operation would say the same only on an idle machine).
    """

    def __init__(self, monkeypatch: pytest.MonkeyPatch, body: FakeBody, call: str) -> None:
        self.inside = 0
        self.returned = threading.Event()
        self._lock = threading.Lock()
        enter = body.enter

        def counting_enter(name: str, widget: str | None = None) -> CameraFault | None:
            if name != call:
                return enter(name, widget)
            with self._lock:
                self.inside += 1
            try:
                return enter(name, widget)
            finally:
                with self._lock:
                    self.inside -= 1
                self.returned.set()

        monkeypatch.setattr(body, "enter", counting_enter)


# ----------------------------------------------------------------------------------- busy


def test_ptp_busy_on_capture_is_retried(canon: CameraRig, tmp_path: Path) -> None:
    fault = canon.body.inject(CameraFault("busy", call="capture"))
    captured = canon.camera.capture(tmp_path / "f")
    assert fault.fired == 1
    assert canon.body.count("capture") == 2
    assert captured.path.exists()
    retries = events(canon.transcript, "retry")
    assert retries == [{"event": "retry", "operation": "capture", "attempt": 1, "code": -110}]


def test_io_in_progress_on_download_is_retried(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("busy", call="file_get", times=2))
    captured = canon.camera.capture(tmp_path / "f")
    assert captured.path.read_bytes().startswith(b"FAKE-JPEG")
    assert canon.body.count("file_get") == 3
    assert canon.body.count("capture") == 1


def test_persistent_busy_ends_in_device_busy(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("busy", call="capture", times=None))
    with pytest.raises(DeviceBusy, match=r"-110 \(I/O in progress\) after 3 attempts") as caught:
        canon.camera.capture(tmp_path / "f")
    assert caught.value.retryable
    assert "MF" in str(caught.value)
    assert canon.body.count("capture") == 3


# ----------------------------------------------------------------------------- same file


def test_same_file_returned_twice_is_retaken(canon: CameraRig, tmp_path: Path) -> None:
    first = canon.camera.capture(tmp_path / "1")
    canon.body.inject(CameraFault("same_file"))
    second = canon.camera.capture(tmp_path / "2")
    assert second.camera_path != first.camera_path
    assert canon.body.count("capture") == 3  # first, the repeat, the retake
    assert len(events(canon.transcript, "same_file_returned")) == 1


def test_same_file_with_the_new_file_announced_by_an_event(
    canon: CameraRig, tmp_path: Path
) -> None:
    first = canon.camera.capture(tmp_path / "1")
    canon.body.inject(CameraFault("same_file", new_file_event=True))
    second = canon.camera.capture(tmp_path / "2")
    assert second.camera_path not in (first.camera_path, "")
    assert canon.body.count("capture") == 2  # no retake needed
    assert len(canon.body.frames) == 2


def test_same_file_forever_is_a_protocol_error(canon: CameraRig, tmp_path: Path) -> None:
    canon.camera.capture(tmp_path / "1")
    canon.body.inject(CameraFault("same_file", times=None))
    with pytest.raises(ProtocolError, match="3 captures in a row produced no new file") as caught:
        canon.camera.capture(tmp_path / "2")
    assert caught.value.reply == "//capt0001.jpg"


# ------------------------------------------------------------------------- claim and I/O


def test_claim_error_at_open_is_retried(clock: SimulatedClock) -> None:
    body = canon_eos_body(clock=clock)
    body.inject(CameraFault("claim", times=2))
    with open_on(FakeGphoto2([body]), clock) as camera:
        assert camera.identify().model == "Canon EOS 5D Mark III"
    assert body.count("init") == 3


def test_claim_error_that_persists_names_the_usual_culprit(clock: SimulatedClock) -> None:
    body = canon_eos_body(clock=clock)
    body.inject(CameraFault("claim", times=None))
    with pytest.raises(DeviceBusy, match="gvfs-gphoto2-volume-monitor"):
        open_on(FakeGphoto2([body]), clock)


def test_io_error_reinitialises_with_a_new_camera_and_reapplies_settings(
    canon: CameraRig, tmp_path: Path
) -> None:
    canon.camera.set_setting("capturetarget", "card")
    canon.camera.set_setting("iso", "400")
    generation = canon.body.session_generation
    canon.body.inject(CameraFault("io_error", call="capture"))
    captured = canon.camera.capture(tmp_path / "f")
    assert canon.body.session_generation == generation + 1
    # capturetarget resets on a new session; the driver put it back before retrying.
    assert canon.body.values["capturetarget"] == "Memory card"
    assert captured.camera_path.startswith("/store_00020001/DCIM/100CANON/")
    assert canon.camera.identify().extra["reinitialisations"] == "1"
    assert canon.gp.calls_after_exit == []


def test_file_lost_in_a_reinit_is_retaken(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("io_error", call="file_get"))
    captured = canon.camera.capture(tmp_path / "f")
    assert canon.body.count("capture") == 2  # SDRAM was cleared by the new session
    assert len(events(canon.transcript, "file_vanished")) == 1
    assert captured.path.exists()


def test_timeout_code_that_persists_is_a_device_timeout(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("timeout", call="capture", times=None))
    with pytest.raises(DeviceTimeout, match="-10"):
        canon.camera.capture(tmp_path / "f")


def test_camera_error_is_an_instrument_error(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("camera_error", call="capture", times=None))
    with pytest.raises(InstrumentError) as caught:
        canon.camera.capture(tmp_path / "f")
    assert caught.value.code == "-113"


# ------------------------------------------------------------------------------- unplug


def test_unplug_mid_bracket_is_a_disconnect(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("unplug", skip=2))
    canon.camera.capture(tmp_path / "1")
    canon.camera.capture(tmp_path / "2")
    with pytest.raises(Disconnected, match="no longer detected") as caught:
        canon.camera.capture(tmp_path / "3")
    assert not caught.value.retryable
    # It gives up at once: the capture is not retried and the camera is looked for once (after the
    # one look at opening), not waited for.
    assert canon.body.count("capture") == 3
    assert canon.gp.calls.count("autodetect") == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["1.jpg", "2.jpg"]


def test_replug_on_another_port_is_followed(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("unplug", call="capture"))
    with pytest.raises(Disconnected):
        canon.camera.capture(tmp_path / "1")
    canon.body.replug(port="usb:001,011")
    canon.camera.reinitialise()
    assert canon.camera.identify().port == "usb:001,011"
    assert canon.camera.capture(tmp_path / "2").path.exists()
    assert events(canon.transcript, "port_changed")[0]["new"] == "usb:001,011"


# --------------------------------------------------------------------------------- hangs


def test_capture_that_never_returns_times_out(
    clock: SimulatedClock, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    body = canon_eos_body(clock=clock)
    gp = FakeGphoto2([body])
    captures = CallsInside(monkeypatch, body, "capture")
    timeouts = CameraTimeouts(
        call_s=1.0, init_s=1.0, capture_overhead_s=0.2, download_s=1.0, drain_ms=1
    )
    camera = open_on(gp, clock, timeouts=timeouts)
    try:
        camera.set_exposure(1 / 100)
        body.inject(CameraFault("hang", call="capture"))
        with pytest.raises(DeviceTimeout, match=r"capture did not return within 0\.21 s"):
            camera.capture(tmp_path / "hung")
        assert captures.inside == 1  # the hung call is still held: its deadline ended the wait
        # The stuck session is abandoned (never exited); the next call opens a new one.
        generation = body.session_generation
        assert camera.capture(tmp_path / "after").path.exists()
        assert body.session_generation == generation + 1
        assert body.count("exit") == 0
    finally:
        gp.release_hangs()
        camera.close()
    assert gp.calls_after_exit == []


def test_late_answer_within_the_deadline_is_accepted(canon: CameraRig, tmp_path: Path) -> None:
    canon.body.inject(CameraFault("slow", call="file_get", delay_s=0.2))
    assert canon.camera.capture(tmp_path / "late").path.exists()
    assert canon.camera.identify().extra["reinitialisations"] == "0"


def test_answer_after_the_deadline_is_dropped_and_the_session_replaced(
    canon_fast: CameraRig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The answer is held until the deadline has passed, then let through (a fixed delay longer
    # than the deadline could come first on a loaded machine, which starves the waiting thread).
    answer_due = threading.Event()
    enter = canon_fast.body.enter

    def late_enter(name: str, widget: str | None = None) -> CameraFault | None:
        fault = enter(name, widget)
        if name == "get_single_config" and not answer_due.is_set():
            answer_due.wait(SETTLE_DEADLINE_S)
        return fault

    monkeypatch.setattr(canon_fast.body, "enter", late_enter)
    reads = CallsInside(monkeypatch, canon_fast.body, "get_single_config")
    with pytest.raises(DeviceTimeout):
        canon_fast.camera.get_setting("iso")
    answer_due.set()
    # The late answer arrives into the abandoned call and is dropped.
    assert reads.returned.wait(SETTLE_DEADLINE_S) and reads.inside == 0
    assert canon_fast.camera.get_setting("iso") == "Auto"
    assert canon_fast.camera.capture(tmp_path / "after").path.exists()
    assert canon_fast.camera.identify().extra["reinitialisations"] == "1"


def test_settings_read_that_hangs_times_out(
    canon_fast: CameraRig, monkeypatch: pytest.MonkeyPatch
) -> None:
    reads = CallsInside(monkeypatch, canon_fast.body, "get_single_config")
    canon_fast.body.inject(CameraFault("hang", call="get_single_config"))
    with pytest.raises(DeviceTimeout, match=r"get_single_config did not return within 0\.5 s"):
        canon_fast.camera.get_setting("iso")
    assert reads.inside == 1  # the hung call is still held: its deadline ended the wait
    assert canon_fast.camera.get_setting("iso") == "Auto"


def test_bulb_event_wait_that_hangs_times_out(canon_fast: CameraRig, tmp_path: Path) -> None:
    canon_fast.camera.set_exposure(60.0)
    canon_fast.body.inject(CameraFault("hang", call="wait_for_event"))
    with pytest.raises(DeviceTimeout, match="wait_for_event"):
        canon_fast.camera.capture(tmp_path / "bulb")
    # The shutter was released before waiting for the file.
    assert canon_fast.body.count("set_single_config") >= 3


def test_open_that_hangs_in_init_times_out(clock: SimulatedClock) -> None:
    body = canon_eos_body(clock=clock)
    gp = FakeGphoto2([body])
    body.inject(CameraFault("hang", call="init"))
    try:
        with pytest.raises(DeviceTimeout, match="init did not return"):
            open_on(gp, clock, timeouts=FAST_TIMEOUTS)
    finally:
        gp.release_hangs()


def test_claim_after_a_stuck_session_points_at_the_stuck_call(
    canon_fast: CameraRig, tmp_path: Path
) -> None:
    canon_fast.body.inject(CameraFault("hang", call="capture"))
    with pytest.raises(DeviceTimeout):
        canon_fast.camera.capture(tmp_path / "1")
    canon_fast.body.inject(CameraFault("claim", times=None))
    with pytest.raises(DeviceBusy, match="still stuck in an earlier session"):
        canon_fast.camera.capture(tmp_path / "2")


def test_closed_camera_refuses_calls(canon: CameraRig, tmp_path: Path) -> None:
    canon.camera.close()
    canon.camera.close()
    with pytest.raises(Disconnected, match="closed"):
        canon.camera.capture(tmp_path / "x")
    assert canon.body.count("exit") == 1


def test_error_classes() -> None:
    assert classify_gphoto_error(-110) == "busy"
    assert classify_gphoto_error(-53) == "claim"
    assert classify_gphoto_error(-7) == "io"
    assert classify_gphoto_error(-10) == "timeout"
    assert classify_gphoto_error(-52) == "gone"
    assert classify_gphoto_error(-108) == "not_found"
    assert classify_gphoto_error(-2) == "fatal"
