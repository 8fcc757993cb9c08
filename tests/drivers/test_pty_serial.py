"""The pty harness: a real device path, timed replies, clean stop, unplug, crash reporting."""

from __future__ import annotations

from pathlib import Path

import pytest
import serial

from mocks.pty_serial import DeviceLink, EmulatorCrashed, PtySerialDevice
from tests.drivers.serial_rig import REPLY_TIMEOUT_S, settled


class Echo:
    """Echoes every chunk; ``b"later"`` is answered twice, 50 ms apart, the first withdrawn."""

    name = "echo"

    def __init__(self) -> None:
        self.received = bytearray()

    def attach(self, link: DeviceLink) -> None:
        self.link = link

    def receive(self, data: bytes) -> None:
        self.received.extend(data)
        if data == b"later":
            withdrawn = self.link.send(b"never", delay_s=0.02)
            self.link.send(b"second", delay_s=0.05)
            self.link.send(b"first", delay_s=0.0)
            withdrawn.cancel()
            return
        self.link.send(data)


class Broken:
    name = "broken"

    def attach(self, link: DeviceLink) -> None:
        pass

    def receive(self, data: bytes) -> None:
        raise RuntimeError("emulator bug")


def open_port(path: str) -> serial.Serial:
    """A port whose reads wait for replies that come (a loaded machine may starve the emulator)."""
    return serial.Serial(path, 9600, timeout=REPLY_TIMEOUT_S)


def test_a_driver_opens_the_device_path_and_talks_through_it() -> None:
    emulator = Echo()
    with PtySerialDevice(emulator) as device:
        assert device.path.startswith("/dev/")
        port = open_port(device.path)
        port.write(b"PHOTO\r\n\x00\xff")
        assert port.read(9) == b"PHOTO\r\n\x00\xff"  # raw mode: CR, LF and binary unchanged
        port.close()
    assert bytes(emulator.received) == b"PHOTO\r\n\x00\xff"


def test_timed_replies_leave_in_time_order_and_cancelled_ones_never() -> None:
    with PtySerialDevice(Echo()) as device:
        port = open_port(device.path)
        port.write(b"later")
        assert port.read(11) == b"firstsecond"
        port.timeout = 0.05
        assert port.read(5) == b""
        port.close()


def test_the_port_can_be_closed_and_reopened() -> None:
    with PtySerialDevice(Echo()) as device:
        for attempt in (b"one", b"two"):
            port = open_port(device.path)
            port.write(attempt)
            assert port.read(3) == attempt
            port.close()


def test_a_symlink_gives_a_stable_path_and_is_removed_on_stop(tmp_path: Path) -> None:
    link = tmp_path / "ttyFAKE0"
    device = PtySerialDevice(Echo(), symlink=link).start()
    try:
        assert device.path == str(link)
        assert link.is_symlink() and str(link.readlink()).startswith("/dev/")
        port = open_port(device.path)
        port.write(b"hi")
        assert port.read(2) == b"hi"
        port.close()
    finally:
        device.stop()
    assert not link.exists()


def test_a_stale_symlink_is_replaced_but_a_file_is_not(tmp_path: Path) -> None:
    link = tmp_path / "ttyFAKE0"
    link.symlink_to(tmp_path / "gone")
    with PtySerialDevice(Echo(), symlink=link) as device:
        assert str(Path(device.path).readlink()).startswith("/dev/")
    occupied = tmp_path / "ttyFILE"
    occupied.write_text("not a tty")
    with pytest.raises(FileExistsError, match="not a symlink"):
        PtySerialDevice(Echo(), symlink=occupied).start()
    assert occupied.read_text() == "not a tty"


def test_unplug_drops_the_link_and_the_path(tmp_path: Path) -> None:
    link = tmp_path / "ttyFAKE1"
    with PtySerialDevice(Echo(), symlink=link) as device:
        port = open_port(device.path)
        device.unplug()
        assert settled(lambda: device.unplugged)
        assert not link.exists()
        with pytest.raises(serial.SerialException):
            port.read(1)
        port.close()


def test_an_emulator_that_raises_is_reported_at_stop() -> None:
    device = PtySerialDevice(Broken()).start()
    port = open_port(device.path)
    port.write(b"x")
    assert settled(lambda: bool(device.errors))
    port.close()
    with pytest.raises(EmulatorCrashed, match="broken emulator raised 1 error") as caught:
        device.stop()
    assert isinstance(caught.value.__cause__, RuntimeError)


def test_path_before_start_and_double_start_are_errors() -> None:
    device = PtySerialDevice(Echo())
    with pytest.raises(RuntimeError, match="not started"):
        _ = device.path
    device.start()
    try:
        with pytest.raises(RuntimeError, match="already started"):
            device.start()
    finally:
        device.stop()
