"""A pyusb backend wrapper that writes every bulk transfer to a transcript: the wire log of USB
instruments whose driver stack we do not own (python-seabreeze talks to pyusb itself).

:class:`RecordingBackend` sits between pyusb and the real backend (libusb, or a stand-in: the
twin's emulated spectrometer, the replay of a recording, the exact-exchange tests). Every
``bulk_write`` is a ``tx`` entry and every ``bulk_read`` an ``rx`` entry, each payload led by the
endpoint address (``01 …`` out on endpoint 1, ``82 …`` in on endpoint 0x82); a failed transfer is an
``error`` entry (UTF-8 JSON: operation, endpoint, errno, message), and opening, configuring and
resetting the device are ``event`` entries. The transcript is what ``rig replay`` serves back.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

from drivers.base import DeviceNotFound, TranscriptDirection, TranscriptEntry, TranscriptSink
from drivers.libraries import pyusb

__all__ = ["RecordingBackend", "bulk_payload", "recording_backend"]


def bulk_payload(endpoint: int, data: bytes) -> bytes:
    """A bulk transfer as the transcript writes it: the endpoint address, then the bytes."""
    return bytes([endpoint & 0xFF]) + bytes(data)


def recording_backend(
    inner: Any, label: str, transcript: TranscriptSink | None
) -> RecordingBackend:
    """Wrap ``inner`` (``None``: pyusb's libusb 1.0 backend) in a :class:`RecordingBackend`.

    Raises
    ------
    drivers.libraries.HardwareLibraryMissing
        pyusb is not installed.
    drivers.base.DeviceNotFound
        No libusb on this system.
    """
    pyusb()
    if inner is None:
        import usb.backend.libusb1

        inner = usb.backend.libusb1.get_backend()
        if inner is None:
            raise DeviceNotFound(
                label,
                "no USB backend available (libusb-1.0 not found): install it (apt install "
                "libusb-1.0-0, brew install libusb) or `pip install libusb-package`",
            )
    return RecordingBackend(inner, label, transcript)


class RecordingBackend:
    """A pyusb ``IBackend`` that delegates to ``inner`` and records bulk transfers.

    Parameters
    ----------
    inner
        The backend doing the work.
    label
        Device label of the transcript entries (``"Ocean USB2000PLUS"``).
    transcript
        Where entries go (``None``: nowhere).
    monotonic
        Time source of the entries.

    Notes
    -----
    pyusb checks backends with ``isinstance(backend, IBackend)`` nowhere; it only calls the methods,
    so this class implements them all by delegation rather than subclassing (which would inherit
    ``NotImplementedError`` stubs).
    """

    def __init__(
        self,
        inner: Any,
        label: str,
        transcript: TranscriptSink | None,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.inner = inner
        self.label = label
        self.transcript = transcript
        self._monotonic = monotonic
        #: The last bytes read from an IN endpoint (a driver checks framing pyseabreeze skips).
        self.last_read = b""

    # ------------------------------------------------------------------------------ recording

    def _record(self, direction: TranscriptDirection, payload: bytes) -> None:
        if self.transcript is not None:
            self.transcript.record(
                TranscriptEntry(self.label, direction, payload, self._monotonic())
            )

    def event(self, what: str, **details: object) -> None:
        """Write an ``event`` entry (UTF-8 JSON)."""
        self._record("event", json.dumps({"event": what, **details}).encode("utf-8"))

    def _failed(self, operation: str, endpoint: int | None, exc: BaseException) -> None:
        self._record(
            "error",
            json.dumps(
                {
                    "op": operation,
                    "endpoint": endpoint,
                    "errno": getattr(exc, "errno", None),
                    "message": str(getattr(exc, "strerror", None) or exc),
                }
            ).encode("utf-8"),
        )

    # ------------------------------------------------------------------------------ transfers

    def bulk_write(self, dev_handle: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        self._record("tx", bulk_payload(ep, bytes(data)))
        try:
            return int(self.inner.bulk_write(dev_handle, ep, intf, data, timeout))
        except Exception as exc:
            self._failed("bulk_write", ep, exc)
            raise

    def bulk_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        try:
            count = int(self.inner.bulk_read(dev_handle, ep, intf, buff, timeout))
        except Exception as exc:
            self._failed("bulk_read", ep, exc)
            raise
        data = bytes(buff[:count])
        self.last_read = data
        self._record("rx", bulk_payload(ep, data))
        return count

    def intr_write(self, dev_handle: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        return int(self.inner.intr_write(dev_handle, ep, intf, data, timeout))

    def intr_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        return int(self.inner.intr_read(dev_handle, ep, intf, buff, timeout))

    def iso_write(self, dev_handle: Any, ep: int, intf: int, data: Any, timeout: int) -> int:
        return int(self.inner.iso_write(dev_handle, ep, intf, data, timeout))

    def iso_read(self, dev_handle: Any, ep: int, intf: int, buff: Any, timeout: int) -> int:
        return int(self.inner.iso_read(dev_handle, ep, intf, buff, timeout))

    # ------------------------------------------------------------------------------ the rest

    def enumerate_devices(self) -> Any:
        return self.inner.enumerate_devices()

    def get_device_descriptor(self, dev: Any) -> Any:
        return self.inner.get_device_descriptor(dev)

    def get_configuration_descriptor(self, dev: Any, config: int) -> Any:
        return self.inner.get_configuration_descriptor(dev, config)

    def get_interface_descriptor(self, dev: Any, intf: int, alt: int, config: int) -> Any:
        return self.inner.get_interface_descriptor(dev, intf, alt, config)

    def get_endpoint_descriptor(self, dev: Any, ep: int, intf: int, alt: int, config: int) -> Any:
        return self.inner.get_endpoint_descriptor(dev, ep, intf, alt, config)

    def get_parent(self, dev: Any) -> Any:
        return self.inner.get_parent(dev)

    def open_device(self, dev: Any) -> Any:
        try:
            return self.inner.open_device(dev)
        except Exception as exc:
            self._failed("open", None, exc)
            raise

    def close_device(self, dev_handle: Any) -> None:
        self.inner.close_device(dev_handle)

    def set_configuration(self, dev_handle: Any, config_value: int) -> None:
        self.event("set_configuration", value=config_value)
        try:
            self.inner.set_configuration(dev_handle, config_value)
        except Exception as exc:
            self._failed("set_configuration", None, exc)
            raise

    def get_configuration(self, dev_handle: Any) -> int:
        return int(self.inner.get_configuration(dev_handle))

    def set_interface_altsetting(self, dev_handle: Any, intf: int, altsetting: int) -> None:
        self.inner.set_interface_altsetting(dev_handle, intf, altsetting)

    def claim_interface(self, dev_handle: Any, intf: int) -> None:
        try:
            self.inner.claim_interface(dev_handle, intf)
        except Exception as exc:
            self._failed("claim_interface", None, exc)
            raise

    def release_interface(self, dev_handle: Any, intf: int) -> None:
        self.inner.release_interface(dev_handle, intf)

    def ctrl_transfer(
        self,
        dev_handle: Any,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: Any,
        timeout: int,
    ) -> int:
        return int(
            self.inner.ctrl_transfer(
                dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout
            )
        )

    def clear_halt(self, dev_handle: Any, ep: int) -> None:
        self.event("clear_halt", endpoint=ep)
        self.inner.clear_halt(dev_handle, ep)

    def reset_device(self, dev_handle: Any) -> None:
        # Not recorded: pyseabreeze also resets a device when its handle is garbage-collected,
        # at no fixed point of the exchange.
        self.inner.reset_device(dev_handle)

    def is_kernel_driver_active(self, dev_handle: Any, intf: int) -> bool:
        return bool(self.inner.is_kernel_driver_active(dev_handle, intf))

    def detach_kernel_driver(self, dev_handle: Any, intf: int) -> None:
        self.inner.detach_kernel_driver(dev_handle, intf)

    def attach_kernel_driver(self, dev_handle: Any, intf: int) -> None:
        self.inner.attach_kernel_driver(dev_handle, intf)
