"""Exact-exchange tests of the Ocean driver: every bulk transfer pyseabreeze makes for it, byte for byte.

The scripts are written from the protocol (OOI opcodes of the USB2000+, OBP frames of the STS), not
from the emulator: a scripted pyusb backend fails on any other write, an unread reply, or a script
line left unused.
"""

from __future__ import annotations

import array
import errno
import struct
from typing import Any

import numpy as np
import pytest
import usb.core

from drivers.base import DeviceTimeout, ProtocolError
from drivers.spectrometer.ocean import OceanSettings, OceanSpectrometer, open_ocean
from mocks.ocean_backend import STS, USB2000PLUS, EmulatedOcean, OceanBackend, OceanModel

Line = tuple[bytes, int | None, bytes | None]
"""(bytes written to endpoint 0x01, IN endpoint of the answer, the answer)."""


class ScriptedBulkBackend(OceanBackend):
    """The emulated model's descriptors; its bulk transfers come from a script and are checked."""

    def __init__(self, model: OceanModel, script: list[Line]) -> None:
        super().__init__([EmulatedOcean(model, lambda wavelength: wavelength * 0.0)])
        self.script = list(script)
        self.position = 0
        self.unread: dict[int, bytearray] = {}

    def bulk_write(self, dev_handle: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        assert not any(self.unread.values()), f"wrote {bytes(data).hex()} with a reply unread"
        assert self.position < len(self.script), f"unscripted write {bytes(data).hex()}"
        sent, endpoint, reply = self.script[self.position]
        self.position += 1
        assert (ep, bytes(data)) == (0x01, sent), f"line {self.position - 1}: {bytes(data).hex()}"
        if endpoint is not None and reply is not None:
            self.unread[endpoint] = bytearray(reply)
        return len(data)

    def bulk_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        pending = self.unread.get(ep)
        assert pending, f"read on 0x{ep:02x} with nothing scripted"
        chunk = bytes(pending[: len(buff)])
        del pending[: len(chunk)]
        buff[: len(chunk)] = array.array("B", chunk)
        return len(chunk)

    def check_complete(self) -> None:
        assert self.position == len(self.script), f"unused: {self.script[self.position :]}"
        assert not any(self.unread.values())


# ------------------------------------------------------------------------------------ USB2000+


def eeprom(slot: int, text: str) -> Line:
    """``05 slot`` answered on 0x81 by ``05 slot`` and 15 bytes of zero-padded ASCII."""
    return bytes([0x05, slot]), 0x81, bytes([0x05, slot]) + text.encode().ljust(15, b"\x00")


USB2000PLUS_OPEN: list[Line] = [
    (b"\x01", None, None),  # initialise
    (b"\x6b\x04", 0x81, b"\x04\x90\x20"),  # FPGA firmware version 2.9.0: a USB2000+
    (b"\xfe", 0x81, bytes(14) + b"\x80\x00"),  # status: high-speed USB
    (b"\x05\x11", 0x81, b"\x05\x11" + bytes(4) + struct.pack("<H", 62000) + bytes(9)),
    eeprom(0, "USB2+F12345"),
    eeprom(1, "3.394000E+02"),
    eeprom(2, "3.806000E-01"),
    eeprom(3, "-1.550000E-05"),
    eeprom(4, "0.000000E+00"),
    eeprom(14, "1"),  # nonlinearity order
    eeprom(6, "1.000000E+00"),
    eeprom(7, "-1.000000E-06"),
]


def usb2000plus_spectrum(counts: int, sync: int = 0x69, masked: int | None = None) -> Line:
    """``09``, answered on 0x82 by 2048 little-endian uint16 and the sync byte (the optically
    masked pixels 6–20 at ``masked`` counts, if given)."""
    values = np.full(2048, counts, dtype="<u2")
    if masked is not None:
        values[6:21] = masked
    return b"\x09", 0x82, values.tobytes() + bytes([sync])


def open_usb2000plus(script: list[Line]) -> tuple[OceanSpectrometer, ScriptedBulkBackend]:
    backend = ScriptedBulkBackend(USB2000PLUS, USB2000PLUS_OPEN + script)
    settings = OceanSettings(allow_uncalibrated=True, averages=1, integration_range_ms=(1, 10))
    return open_ocean("USB2+F12345", settings, backend=backend), backend


def test_usb2000plus_open_reads_serial_wavelengths_nonlinearity_and_saturation() -> None:
    spectrometer, backend = open_usb2000plus([])
    backend.check_complete()
    identity = spectrometer.identify()
    assert (identity.model, identity.serial, identity.port) == (
        "USB2000PLUS",
        "USB2+F12345",
        "usb:001,009",
    )
    assert identity.extra["nonlinearity"] == "on" and identity.extra["electric_dark"] == "on"
    np.testing.assert_allclose(spectrometer.wavelength_nm[:2], [339.4, 339.7806])
    assert spectrometer.nonlinearity == (1.0, -1.0e-6)
    assert spectrometer.ladder_ms == (1.0, 2.0, 5.0, 10.0)


def test_usb2000plus_fixed_integration_dark_then_measure() -> None:
    micros = struct.pack("<I", 5000)
    spectrometer, backend = open_usb2000plus(
        [
            (b"\x02" + micros, None, None),  # 5 ms, in µs
            usb2000plus_spectrum(1000),  # the stale scan after the change, discarded
            usb2000plus_spectrum(1000),  # the dark
            usb2000plus_spectrum(3000, masked=1000),  # the light (same time: no stale scan)
        ]
    )
    spectrometer.set_exposure(5.0)
    dark = spectrometer.measure_dark()
    assert dark.integration_ms == (5.0,)
    reading = spectrometer.measure()
    backend.check_complete()
    assert reading.exposure_ms == 5.0 and reading.units == "counts/ms (uncalibrated)"
    # pyseabreeze scales by 65535 / saturation; the electric dark (masked pixels) is removed from
    # scan and dark, the nonlinearity divides each above its baseline, then per ms.
    above = (3000 - 1000) * 65535 / 62000
    expected = above / (1 - 1e-6 * above) / 5.0
    assert reading.values.shape == (2048 - 15,)  # without the masked pixels
    np.testing.assert_allclose(reading.values, expected, rtol=1e-9)


def test_usb2000plus_a_spectrum_without_its_sync_byte_is_a_protocol_error() -> None:
    spectrometer, _ = open_usb2000plus(
        [(b"\x02" + struct.pack("<I", 5000), None, None), usb2000plus_spectrum(1000, sync=0x00)]
    )
    spectrometer.set_exposure(5.0)
    with pytest.raises(ProtocolError, match="sync byte 0x69"):
        spectrometer.measure_dark()


class SilentBulkBackend(ScriptedBulkBackend):
    """The script, then silence: a read with no answer scripted times out as libusb's does."""

    def bulk_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        if not self.unread.get(ep):
            raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
        return super().bulk_read(dev_handle, ep, intf, buff, timeout)


def test_usb2000plus_a_silent_spectrum_request_is_a_retryable_timeout() -> None:
    """The runner retries a ``DeviceTimeout`` (the fault matrix's PR-655 rows); here the Ocean
    driver's own part: a spectrum request libusb times out on is that error, with its deadline."""
    set_5_ms = (b"\x02" + struct.pack("<I", 5000), None, None)
    script = [*USB2000PLUS_OPEN, set_5_ms, (b"\x09", None, None)]
    backend = SilentBulkBackend(USB2000PLUS, script)
    settings = OceanSettings(allow_uncalibrated=True, averages=1, integration_range_ms=(1, 10))
    spectrometer = open_ocean("USB2+F12345", settings, backend=backend)
    spectrometer.set_exposure(5.0)
    with pytest.raises(DeviceTimeout, match="no answer within") as raised:
        spectrometer.measure_dark()
    assert raised.value.retryable and raised.value.reason == "timeout"
    assert raised.value.timeout_s == pytest.approx((5 + settings.timeout_ms) / 1000.0)
    backend.check_complete()


# ------------------------------------------------------------------------------------ STS (OBP)

OBP_HEADER = struct.Struct("<HHHHLL6sBB16sL")
OBP_FOOTER = b"\x00" * 16 + struct.pack("<L", 0xC2C3C4C5)


def obp(message: int, data: bytes = b"", flags: int = 0) -> bytes:
    """An OBP frame: data up to 16 bytes immediate, longer as a payload."""
    immediate, payload = (data, b"") if len(data) <= 16 else (b"", data)
    header = OBP_HEADER.pack(
        0xC0C1, 0x1100, flags, 0, message, 0, b"", 0, len(immediate), immediate, 20 + len(payload)
    )
    return header + payload + OBP_FOOTER


def query(message: int, answer: bytes, argument: bytes = b"") -> Line:
    """A query (no ACK asked) and the device's response on 0x81."""
    return obp(message, argument), 0x81, obp(message, answer, flags=0x0001)


STS_OPEN: list[Line] = [
    query(0x00000101, b"\x06"),  # serial length
    query(0x00000100, b"S05678"),  # serial
    query(0x00180100, b"\x04"),  # wavelength coefficient count
    *(
        query(0x00180101, struct.pack("<f", value), bytes([index]))
        for index, value in enumerate((349.2, 0.4652, -1.8e-5, 0.0))
    ),
]


def test_sts_open_integration_and_spectrum_frames() -> None:
    counts = np.arange(1024, dtype="<u2") + 1000
    backend = ScriptedBulkBackend(
        STS,
        [
            *STS_OPEN,
            # set the integration time (µs) asking for an ACK
            (obp(0x00110010, struct.pack("<L", 2000), flags=0x0004), 0x81, obp(0x00110010, b"", 3)),
            query(0x00101100, counts.tobytes()),  # stale scan after the change
            query(0x00101100, counts.tobytes()),  # the dark
        ],
    )
    settings = OceanSettings(allow_uncalibrated=True, averages=1, integration_range_ms=(1, 10))
    spectrometer = open_ocean(None, settings, backend=backend)
    assert spectrometer.identify().serial == "S05678"
    assert spectrometer.dark_pixels == () and spectrometer.nonlinearity is None
    spectrometer.set_exposure(2.0)
    dark = spectrometer.measure_dark()
    backend.check_complete()
    np.testing.assert_array_equal(dark.counts[0], counts.astype(float))
