"""A pyusb backend that plays a recorded HID relay transcript back, control transfer by transfer.

The real :mod:`drivers.relays.hid_usbrelay` driver enumerates one board through it, with the bus
address of the recorded identity and the string-descriptor indices the recording asked for. Each
control transfer's setup packet (and OUT data) was already checked by the transcript sink; an IN
transfer gets the recorded ``rx`` bytes, and a transfer recorded as failed raises the recorded errno
as a ``usb.core.USBError``.
"""

from __future__ import annotations

import array
import errno
import json
import re
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

import usb.backend
import usb.core

from drivers.base import TranscriptEntry
from mocks.ocean_backend import OCEAN_MODELS, EmulatedOcean, OceanBackend
from mocks.replay.script import ReplayScript
from mocks.usb_relay_backend import device_descriptor

__all__ = ["ReplayOceanBackend", "ReplayUsbBackend", "string_indices"]

_VENDOR_ID = 0x16C0
_PRODUCT_ID = 0x05DF
_GET_STRING = (0x80, 0x06)
_PORT = re.compile(r"^usb:(\d{1,3}),(\d{1,3})$")


def string_indices(entries: Sequence[TranscriptEntry]) -> tuple[int, int]:
    """The manufacturer and product string indices the recording read (default 1 and 2)."""
    indices = [
        entry.payload[2]
        for entry in entries
        if entry.direction == "tx"
        and len(entry.payload) == 8
        and tuple(entry.payload[:2]) == _GET_STRING
        and entry.payload[3] == 0x03
        and entry.payload[2] != 0
    ]
    return (indices[0], indices[1]) if len(indices) >= 2 else (1, 2)


class ReplayUsbBackend(usb.backend.IBackend):  # type: ignore[misc]
    """One recorded dcttech board on a pyusb backend.

    Parameters
    ----------
    script
        The relay transcript.
    port
        The recorded ``usb:BBB,AAA`` (bus, address) of the board.
    """

    def __init__(self, script: ReplayScript, port: str | None) -> None:
        match = _PORT.match(port or "")
        bus, address = (int(match.group(1)), int(match.group(2))) if match else (1, 1)
        manufacturer, product = string_indices(script.entries)
        self._script = script
        self._descriptor = device_descriptor(
            _VENDOR_ID,
            _PRODUCT_ID,
            bus=bus,
            address=address,
            iManufacturer=manufacturer,
            iProduct=product,
        )
        self._device = SimpleNamespace(name="replayed board")

    def enumerate_devices(self) -> list[Any]:
        return [self._device]

    def get_device_descriptor(self, dev: Any) -> SimpleNamespace:
        return self._descriptor

    def open_device(self, dev: Any) -> Any:
        return dev

    def close_device(self, dev_handle: Any) -> None:
        """Nothing to release."""

    def claim_interface(self, dev_handle: Any, intf: int) -> None:
        """Interfaces are not the recording's business."""

    def release_interface(self, dev_handle: Any, intf: int) -> None:
        """Nothing to release."""

    def is_kernel_driver_active(self, dev_handle: Any, intf: int) -> bool:
        return False

    def detach_kernel_driver(self, dev_handle: Any, intf: int) -> None:
        """Nothing attached."""

    def attach_kernel_driver(self, dev_handle: Any, intf: int) -> None:
        """Nothing to attach."""

    def ctrl_transfer(
        self,
        dev_handle: Any,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: array.array[int],
        timeout: int,
    ) -> int:
        served = self._script.peek_answer()
        if served is not None and served.entry.direction == "error":
            self._script.take("an error")
            raise _recorded_error(served.entry.payload)
        if bmRequestType & 0x80 == 0:
            return len(data)
        reply = self._script.take("a control transfer reply").entry.payload
        count = min(len(data), len(reply))
        data[:count] = array.array("B", reply[:count])
        return count


def _recorded_error(payload: bytes) -> usb.core.USBError:
    try:
        detail = json.loads(payload)
        code = int(detail["errno"])
        message = str(detail.get("message", "replayed USB error"))
    except (ValueError, KeyError, TypeError):
        code, message = errno.EIO, "replayed USB error"
    if code == errno.ETIMEDOUT:
        return usb.core.USBTimeoutError(message, None, code)
    return usb.core.USBError(message, None, code)


class ReplayOceanBackend(OceanBackend):
    """One recorded Ocean spectrometer on a pyusb backend: its descriptors are the emulated
    model's, its bulk OUT transfers were checked by the transcript sink, and each bulk IN
    transfer returns the recorded ``rx`` bytes (after their endpoint byte) or raises the recorded
    error.

    Parameters
    ----------
    script
        The spectrometer transcript.
    model
        The recorded model (``USB2000PLUS``, ``STS``).
    port
        The recorded ``usb:BBB,AAA``.
    """

    def __init__(self, script: ReplayScript, model: str, port: str | None) -> None:
        match = _PORT.match(port or "")
        bus, address = (int(match.group(1)), int(match.group(2))) if match else (1, 1)
        device = EmulatedOcean(
            OCEAN_MODELS[model], lambda wavelength: wavelength * 0.0, bus=bus, address=address
        )
        super().__init__([device])
        self._script = script

    def bulk_write(self, dev_handle: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        return len(data)

    def bulk_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        served = self._script.peek_answer()
        if served is not None and served.entry.direction == "error":
            self._script.take("an error")
            raise _recorded_error(served.entry.payload)
        reply = self._script.take("a bulk transfer").entry.payload[1:]
        count = min(len(buff), len(reply))
        buff[:count] = array.array("B", reply[:count])
        return count
