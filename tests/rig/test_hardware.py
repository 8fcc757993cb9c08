"""The hardware station: real drivers from the configuration, and errors that name the missing device.

No hardware: serial devices are the firmware emulators on ptys (or ports that do not exist), the HID
board is the fake pyusb backend, the camera the fake gphoto2 module.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.base import DeviceNotFound, ListTranscript
from mocks.emulators import start_lcus, start_numato, start_pr655
from mocks.emulators.lcus import LcusEmulator
from mocks.fake_gphoto2 import FakeGphoto2, canon_eos_body
from mocks.lamps import LampBank
from mocks.pty_serial import PtySerialDevice
from mocks.usb_relay_backend import EmulatedRelayBoard, FakeUsbBackend
from rig.clock import MonotonicClock
from rig.config import RigConfig
from rig.errors import StationOpenFailed, StationUnavailable
from rig.frame_stats import RawFrameAnalyzer
from rig.hardware import open_hardware_station, open_relays
from rig.runner import StepTimeouts
from tests.rig.fakes import fake_config_data

LAMPS = [{"name": "LED-B3", "channel": 1, "kind": "led"}]


def hardware_config(**devices: dict[str, Any]) -> RigConfig:
    data = fake_config_data()
    data["lamps"] = LAMPS
    data["devices"] = {
        "spectrometer": {"kind": "pr655", "port": "/dev/spectral-rig-no-such-tty0"},
        "relays": {"kind": "lcus", "port": "/dev/spectral-rig-no-such-tty1", "channels": 2},
        "camera": {"kind": "gphoto2"},
    } | devices
    return RigConfig.model_validate(data)


class Transcripts:
    """One in-memory transcript per role."""

    def __init__(self) -> None:
        self.by_role: dict[str, ListTranscript] = {}

    def __call__(self, role: str) -> ListTranscript:
        return self.by_role.setdefault(role, ListTranscript())

    def text(self, role: str) -> str:
        return "\n".join(e.payload.decode(errors="replace") for e in self.by_role[role].entries)


@pytest.fixture
def emulators() -> Iterator[dict[str, PtySerialDevice]]:
    started = {
        "pr655": start_pr655(lambda nm: nm * 0 + 0.01, seed=1, time_scale=1e-3),
        "lcus": start_lcus(2),
        "numato": start_numato(2),
    }
    yield started
    for device in started.values():
        device.stop()


def test_every_device_is_tried_and_every_failure_named_at_once() -> None:
    transcripts = Transcripts()
    with pytest.raises(StationOpenFailed) as failed:
        open_hardware_station(hardware_config(), transcripts)
    assert sorted(failed.value.failures) == ["camera", "relays", "spectrometer"]
    assert all(isinstance(e, DeviceNotFound) for e in failed.value.failures.values())
    message = str(failed.value)
    assert message.startswith("3 devices could not be opened, nothing was recorded: ")
    assert "/dev/spectral-rig-no-such-tty1' does not exist" in message
    assert "/dev/spectral-rig-no-such-tty0' does not exist" in message
    assert "no camera detected" in message
    assert not failed.value.lamps_off  # no relay board opened to switch them off


def test_when_a_device_fails_the_opened_board_switches_every_lamp_off_and_is_released(
    emulators: dict[str, PtySerialDevice],
) -> None:
    relays = {"kind": "lcus", "port": emulators["lcus"].path, "channels": 2}
    config = hardware_config(relays=relays)
    board = emulators["lcus"].emulator
    assert isinstance(board, LcusEmulator)
    board.states[0] = True  # a lamp a killed run left on
    with pytest.raises(StationOpenFailed, match=r"PR-655 on /dev/spectral-rig-no-such-tty0") as e:
        open_hardware_station(config, Transcripts())
    assert sorted(e.value.failures) == ["camera", "spectrometer"]
    assert e.value.lamps_off and board.states == [False, False]
    # The relay board's port was released: it opens again (ports are opened exclusively).
    open_relays(config.devices.relays, ListTranscript()).close()


def test_hid_boards_are_found_by_serial_and_channel_count() -> None:
    bank = LampBank([], n_channels=4)
    backend = FakeUsbBackend([EmulatedRelayBoard("QAAMZ", 2, lamp_bank=bank)])
    with pytest.raises(DeviceNotFound, match=r"no board with serial 'ABCDE'; found 'QAAMZ'"):
        open_relays(
            hardware_config(
                relays={"kind": "hid_usbrelay", "serial": "ABCDE", "channels": 2}
            ).devices.relays,
            ListTranscript(),
            usb_backend=backend,
        )
    with pytest.raises(DeviceNotFound, match=r"has 2 relays.*devices\.relays\.channels = 4"):
        open_relays(
            hardware_config(relays={"kind": "hid_usbrelay", "channels": 4}).devices.relays,
            ListTranscript(),
            usb_backend=backend,
        )
    board = open_relays(
        hardware_config(
            relays={"kind": "hid_usbrelay", "serial": "QAAMZ", "channels": 2}
        ).devices.relays,
        ListTranscript(),
        usb_backend=backend,
    )
    board.close()


def test_a_missing_camera_names_what_was_asked_and_found(
    emulators: dict[str, PtySerialDevice],
) -> None:
    config = hardware_config(
        spectrometer={"kind": "pr655", "port": emulators["pr655"].path},
        relays={"kind": "numato", "port": emulators["numato"].path, "channels": 2},
        camera={"kind": "gphoto2", "model": "Nikon DSC D850"},
    )
    gphoto2 = FakeGphoto2([canon_eos_body()])
    with pytest.raises(
        StationOpenFailed,
        match=r"no camera with model 'Nikon DSC D850'; detected: 'Canon EOS 5D Mark III' on usb:001,004",
    ) as failed:
        open_hardware_station(config, Transcripts(), gphoto2_module=gphoto2)
    assert list(failed.value.failures) == ["camera"] and failed.value.lamps_off
    with pytest.raises(StationOpenFailed, match=r"detected: none \(is it on, in PTP mode"):
        open_hardware_station(config, Transcripts(), gphoto2_module=FakeGphoto2([]))


def test_the_real_drivers_make_a_station(emulators: dict[str, PtySerialDevice]) -> None:
    config = hardware_config(
        spectrometer={"kind": "pr655", "port": emulators["pr655"].path, "timeout_s": 5},
        relays={"kind": "lcus", "port": emulators["lcus"].path, "channels": 2, "baud": 115200},
        camera={"kind": "gphoto2", "model": "Canon EOS 5D Mark III", "port": "usb:001,004"},
    )
    transcripts = Transcripts()
    station = open_hardware_station(
        config, transcripts, gphoto2_module=FakeGphoto2([canon_eos_body()])
    )
    try:
        assert isinstance(station.clock, MonotonicClock)
        assert isinstance(station.analyzer, RawFrameAnalyzer)
        assert station.spectrometer.identify().model == "PR-655"
        assert station.camera.identify().model == "Canon EOS 5D Mark III"
        assert station.relays.channels == 2
        assert "115200 8N1" in transcripts.text("relays")  # the configured line speed
    finally:
        station.close()


def test_twin_devices_are_not_hardware(tmp_path: Path) -> None:
    data = fake_config_data(tmp_path)
    with pytest.raises(StationUnavailable, match=r"devices\.relays\.kind is 'twin'"):
        open_hardware_station(RigConfig.model_validate(data), Transcripts())


@pytest.mark.parametrize(
    ("spectrometer", "driver_worst_s"),
    [
        ({"kind": "pr655", "port": "/dev/ttyACM0", "timeout_s": 10}, 60.0 + 10.0),
        (
            {"kind": "pr670", "port": "/dev/ttyACM0", "timeout_s": 0.5, "measure_timeout_s": 1},
            1.5,
        ),
        ({"kind": "cs2000", "port": "/dev/ttyACM0", "timeout_s": 15}, 15 + 242 + 10 + 75.0),
    ],
)
def test_the_spectrometer_watchdog_outlasts_the_driver_s_own_deadlines(
    spectrometer: dict[str, Any], driver_worst_s: float
) -> None:
    """A silent instrument must end in the driver's retryable timeout, not the runner's watchdog."""
    timeouts = StepTimeouts.from_config(hardware_config(spectrometer=spectrometer))
    assert driver_worst_s < timeouts.spectrometer_s <= driver_worst_s + 1.0


def test_the_twin_spectrometer_watchdog_follows_the_emulated_model() -> None:
    data = fake_config_data()
    data["devices"]["spectrometer"] = {
        "kind": "twin",
        "emulate": "cs2000",
        "timeout_s": 0.5,
        "measure_timeout_s": 1,
    }
    timeouts = StepTimeouts.from_config(RigConfig.model_validate(data))
    assert timeouts.spectrometer_s == pytest.approx(0.5 + 242 + 1 + 5 * 0.5 + 1.0)
