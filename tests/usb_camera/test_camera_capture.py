"""Capturing with the gphoto2 driver against the fake module: targets, downloads, RAW+JPEG, bulb."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from drivers.base import DeviceBusy, ListTranscript
from drivers.camera import SettingValueError
from mocks.fake_gphoto2 import FakeGphoto2, FrameRequest, canon_eos_body, nikon_body
from mocks.lamps import SimulatedClock
from tests.usb_camera.conftest import CameraRig, open_on


def frame_metadata(path: Path) -> dict[str, object]:
    """The JSON line the fake's placeholder frame source writes after its header."""
    lines = path.read_bytes().split(b"\n")
    assert lines[0] == b"FAKE-RAW"
    result: dict[str, object] = json.loads(lines[1])
    return result


def test_capture_to_sdram_downloads_and_deletes(canon: CameraRig, tmp_path: Path) -> None:
    canon.camera.set_setting("imageformat", "RAW")
    canon.camera.set_setting("iso", "200")
    assert canon.camera.set_exposure(1 / 250) == pytest.approx(0.004)
    captured = canon.camera.capture(tmp_path / "frames" / "led_0001")
    assert captured.path == tmp_path / "frames" / "led_0001.cr2"
    assert captured.camera_path == "/capt0001.cr2"
    assert captured.exposure_s == pytest.approx(0.004)
    assert captured.settings["shutterspeed"] == "1/250"
    assert captured.settings["iso"] == "200"
    assert captured.settings["imageformat"] == "RAW"
    metadata = frame_metadata(captured.path)
    assert metadata["exposure_s"] == pytest.approx(0.004)
    assert metadata["settings"]["iso"] == "200"  # type: ignore[index]
    assert canon.body.files == {}
    assert sorted(p.name for p in captured.path.parent.iterdir()) == ["led_0001.cr2"]


def test_downloaded_bytes_are_exactly_the_frame(clock: SimulatedClock, tmp_path: Path) -> None:
    requests: list[FrameRequest] = []

    def frame_source(request: FrameRequest) -> bytes:
        requests.append(request)
        return bytes([request.index]) * 1000 + f"{request.exposure_s:.6f}".encode()

    gp = FakeGphoto2([canon_eos_body(clock=clock, frame_source=frame_source)])
    with open_on(gp, clock) as camera:
        camera.set_setting("imageformat", "RAW")
        camera.set_setting("aperture", "8")
        camera.set_exposure(0.5)
        first = camera.capture(tmp_path / "a.cr2")
        second = camera.capture(tmp_path / "b.cr2")
    assert first.path.read_bytes() == b"\x01" * 1000 + b"0.500000"
    assert second.path.read_bytes() == b"\x02" * 1000 + b"0.500000"
    assert [r.settings["aperture"] for r in requests] == ["8", "8"]
    assert [r.file_format for r in requests] == ["raw", "raw"]
    # Two half-second exposures on the body's clock (plus the 1 ms event drains).
    assert clock.now() == pytest.approx(1.0, abs=0.01)


def test_capture_to_card_and_keep_files(clock: SimulatedClock, tmp_path: Path) -> None:
    body = canon_eos_body(clock=clock)
    gp = FakeGphoto2([body])
    with open_on(gp, clock, capture_target="card", delete_after_download=False) as camera:
        camera.set_setting("imageformat", "RAW")
        captured = camera.capture(tmp_path / "card")
    assert captured.camera_path == "/store_00020001/DCIM/100CANON/IMG_0001.CR2"
    assert captured.path.name == "card.cr2"
    assert list(body.files) == [("/store_00020001/DCIM/100CANON", "IMG_0001.CR2")]


def test_raw_plus_jpeg_downloads_the_raw_and_deletes_both(canon: CameraRig, tmp_path: Path) -> None:
    canon.camera.set_setting("imageformat", "RAW + Large Fine JPEG")
    captured = canon.camera.capture(tmp_path / "pair")
    assert captured.path.suffix == ".cr2"
    assert frame_metadata(captured.path)["index"] == 1
    assert canon.body.files == {}
    assert canon.body.count("file_delete") == 2
    assert canon.body.count("file_get") == 1


def test_jpeg_only_camera_format_is_downloaded_as_is(clock: SimulatedClock, tmp_path: Path) -> None:
    with open_on(FakeGphoto2([nikon_body(clock=clock)]), clock) as camera:
        captured = camera.capture(tmp_path / "nikon")
        assert captured.path.name == "nikon.jpg"
        assert captured.path.read_bytes().startswith(b"FAKE-JPEG")
        camera.set_setting("imageformat", "RAW")
        assert camera.capture(tmp_path / "nikon_raw").path.name == "nikon_raw.nef"


def test_a_given_suffix_is_kept_and_existing_files_are_replaced(
    canon: CameraRig, tmp_path: Path
) -> None:
    destination = tmp_path / "frame.raw"
    destination.write_bytes(b"old")
    captured = canon.camera.capture(destination)
    assert captured.path == destination
    assert destination.read_bytes() != b"old"


def test_destination_must_be_a_file_path(canon: CameraRig, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="is a directory"):
        canon.camera.capture(tmp_path)


def test_sdram_fills_when_files_are_not_deleted(clock: SimulatedClock, tmp_path: Path) -> None:
    body = canon_eos_body(clock=clock)
    body.sdram_capacity = 2
    gp = FakeGphoto2([body])
    with open_on(gp, clock, delete_after_download=False) as camera:
        camera.capture(tmp_path / "1")
        camera.capture(tmp_path / "2")
        with pytest.raises(DeviceBusy, match="undownloaded images fill its SDRAM"):
            camera.capture(tmp_path / "3")


# ------------------------------------------------------------------------------------- bulb


def test_bulb_exposure_longer_than_the_longest_choice(canon: CameraRig, tmp_path: Path) -> None:
    canon.camera.set_setting("imageformat", "RAW")
    assert canon.camera.set_exposure(120.0) == 120.0
    assert canon.body.values["shutterspeed"] == "bulb"
    captured = canon.camera.capture(tmp_path / "long")
    assert captured.exposure_s == pytest.approx(120.0)
    assert captured.settings["shutterspeed"] == "bulb"
    assert captured.settings["bulb_requested_s"] == "120"
    assert frame_metadata(captured.path)["exposure_s"] == pytest.approx(120.0)
    assert canon.body.count("capture") == 0
    # Back to a timed exposure: no bulb any more.
    assert canon.camera.set_exposure(1 / 60) == pytest.approx(1 / 60)
    assert canon.camera.capture(tmp_path / "short").exposure_s == pytest.approx(1 / 60)
    assert canon.body.count("capture") == 1


def test_bulb_through_eos_remote_release(clock: SimulatedClock, tmp_path: Path) -> None:
    body = canon_eos_body(clock=clock, bulb_toggle=False)
    transcript = ListTranscript()
    with open_on(FakeGphoto2([body]), clock, transcript=transcript) as camera:
        camera.set_exposure(45.0)
        captured = camera.capture(tmp_path / "eos")
    written = [
        json.loads(e.payload)["args"][0]
        for e in transcript.entries
        if e.direction == "call" and json.loads(e.payload)["call"] == "CameraWidget.set_value"
    ]
    assert captured.exposure_s == pytest.approx(45.0)
    assert "Press Full MF" in written and "Release Full" in written


def test_bulb_needs_an_exposure_time(canon: CameraRig, tmp_path: Path) -> None:
    canon.camera.set_setting("shutterspeed", "bulb")
    with pytest.raises(SettingValueError, match="set_exposure"):
        canon.camera.capture(tmp_path / "x")


def test_bulb_limit(canon: CameraRig) -> None:
    with pytest.raises(SettingValueError, match="bulb limit"):
        canon.camera.set_exposure(7200.0)


# ------------------------------------------------------------------------------- transcript


def test_every_library_call_is_in_the_transcript(canon: CameraRig, tmp_path: Path) -> None:
    start = len(canon.transcript.entries)
    canon.camera.capture(tmp_path / "t")
    entries = canon.transcript.entries[start:]
    decoded = [(e.direction, json.loads(e.payload.decode("utf-8"))) for e in entries]
    calls = [body["call"] for direction, body in decoded if direction == "call"]
    returns = [body["call"] for direction, body in decoded if direction == "return"]
    assert calls == returns
    assert calls[:2] == ["get_single_config", "capture"]
    assert "file_get" in calls and calls[-1] == "file_delete"
    capture_return = next(b for d, b in decoded if d == "return" and b["call"] == "capture")
    assert capture_return["result"] == {"folder": "/", "name": "capt0001.jpg"}
    download = next(b for d, b in decoded if d == "event" and b.get("event") == "downloaded")
    assert download["bytes"] == 4096
    assert {e.device for e in entries} == {"Canon EOS 5D Mark III on usb:001,004"}


# ------------------------------------------------------------------------------- event drain


@pytest.mark.parametrize(
    ("image_format", "signals_complete", "waits"),
    [
        ("RAW", True, 1),  # CAPTURE_COMPLETE with the one file in: stop at once
        ("RAW", False, 1),  # no complete signal: one empty wait
        ("RAW + Large Fine JPEG", True, 2),  # the JPEG's FILE_ADDED, then complete
        ("RAW + Large Fine JPEG", False, 2),  # the JPEG's FILE_ADDED, then one empty wait
    ],
)
def test_events_after_a_capture_are_read_without_idle_waits(
    clock: SimulatedClock, tmp_path: Path, image_format: str, signals_complete: bool, waits: int
) -> None:
    body = canon_eos_body(clock=clock)
    body.signals_capture_complete = signals_complete
    with open_on(FakeGphoto2([body]), clock) as camera:
        camera.set_setting("imageformat", image_format)
        before = body.count("wait_for_event")
        captured = camera.capture(tmp_path / "f")
        assert body.count("wait_for_event") - before == waits
    assert captured.path.suffix == ".cr2"
    assert body.files == {}
