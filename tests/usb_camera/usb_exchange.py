"""Exact-exchange testing for USB control transfers (PyMeasure's ``expected_protocol``, for pyusb).

A test lists every control transfer the driver must make, in order: the SETUP fields, the OUT payload
or IN length, and the reply. :class:`ScriptedUsbBackend` serves that script as a pyusb backend and
fails on any difference; :func:`expected_transfers` also fails when a scripted transfer was never made.
"""

from __future__ import annotations

import array
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from types import SimpleNamespace

import usb.backend
import usb.core

from mocks.usb_relay_backend import device_descriptor


@dataclass(frozen=True)
class Transfer:
    """One scripted control transfer.

    For OUT transfers give ``data`` (the exact payload); for IN transfers give ``length`` (wLength)
    and ``reply`` (bytes the device returns, at most ``length``). ``error`` is raised instead of
    completing the transfer (a ``usb.core.USBError``).
    """

    request_type: int
    request: int
    value: int
    index: int
    data: bytes = b""
    length: int = 0
    reply: bytes = b""
    error: usb.core.USBError | None = None

    @property
    def is_in(self) -> bool:
        return bool(self.request_type & 0x80)

    def describe(self) -> str:
        head = f"{self.request_type:02x} {self.request:02x} {self.value:04x} {self.index:04x}"
        return f"{head} IN len {self.length}" if self.is_in else f"{head} OUT {self.data.hex(' ')}"


def string_descriptor(text: str) -> bytes:
    encoded = text.encode("utf-16-le")
    return bytes([2 + len(encoded), 3]) + encoded


class ScriptedUsbBackend(usb.backend.IBackend):  # type: ignore[misc]
    """A pyusb backend with one device that answers from a script and asserts every request."""

    def __init__(self, script: Sequence[Transfer], descriptor: SimpleNamespace) -> None:
        self.script = list(script)
        self.position = 0
        self.descriptor = descriptor

    def enumerate_devices(self) -> list[str]:
        return ["scripted"]

    def get_device_descriptor(self, dev: str) -> SimpleNamespace:
        return self.descriptor

    def open_device(self, dev: str) -> str:
        return "handle"

    def close_device(self, dev_handle: str) -> None:
        pass

    def claim_interface(self, dev_handle: str, intf: int) -> None:
        pass

    def release_interface(self, dev_handle: str, intf: int) -> None:
        pass

    def is_kernel_driver_active(self, dev_handle: str, intf: int) -> bool:
        return False

    def ctrl_transfer(
        self,
        dev_handle: str,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: array.array[int],
        timeout: int,
    ) -> int:
        is_in = bool(bmRequestType & 0x80)
        actual = Transfer(
            bmRequestType,
            bRequest,
            wValue,
            wIndex,
            data=b"" if is_in else bytes(data),
            length=len(data) if is_in else 0,
        )
        if self.position >= len(self.script):
            raise AssertionError(f"unscripted control transfer {actual.describe()}")
        expected = self.script[self.position]
        self.position += 1
        if (
            expected.request_type,
            expected.request,
            expected.value,
            expected.index,
            expected.data,
            expected.length,
        ) != (
            actual.request_type,
            actual.request,
            actual.value,
            actual.index,
            actual.data,
            actual.length,
        ):
            raise AssertionError(
                f"transfer {self.position}: expected {expected.describe()}, got {actual.describe()}"
            )
        if expected.error is not None:
            raise expected.error
        if is_in:
            if len(expected.reply) > len(data):
                raise AssertionError(f"scripted reply longer than wLength {len(data)}")
            data[: len(expected.reply)] = array.array("B", expected.reply)
            return len(expected.reply)
        return len(data)

    def assert_finished(self) -> None:
        unused = self.script[self.position :]
        if unused:
            raise AssertionError(
                "scripted transfers never made: " + "; ".join(t.describe() for t in unused)
            )


@contextmanager
def expected_transfers(
    script: Sequence[Transfer], descriptor: SimpleNamespace | None = None
) -> Iterator[ScriptedUsbBackend]:
    """Yield a backend serving ``script``; on exit assert that every transfer was made."""
    backend = ScriptedUsbBackend(
        script, descriptor or device_descriptor(0x16C0, 0x05DF, bus=1, address=7)
    )
    yield backend
    backend.assert_finished()
