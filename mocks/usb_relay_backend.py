"""A pyusb backend that emulates dcttech USBRelay boards at the control-transfer level.

Pass a :class:`FakeUsbBackend` to ``usb.core.find(backend=...)`` (or to
:func:`drivers.relays.hid_usbrelay.open_hid_relay`): pyusb then enumerates the emulated boards, reads
their descriptors and string descriptors, and sends HID Feature reports to them exactly as it would to
libusb. Each :class:`EmulatedRelayBoard` behaves like the V-USB firmware (``u1f35c/usb-relay-firmware``
documents the device side): SET_REPORT ``FF n``/``FD n``/``FE``/``FC``/``FA id`` switches relays or
stores the ID, GET_REPORT returns the ID in bytes 0–4 and the relay bitmask in byte 7. Any other
request STALLs, as a real device's endpoint 0 does. Relays switch channels on a
:class:`mocks.lamps.LampBank` when one is attached.

Faults (:class:`UsbFault`) raise what libusb raises through pyusb: a timeout is a
``usb.core.USBTimeoutError`` with errno ETIMEDOUT after the transfer's timeout has elapsed, a STALL
errno EPIPE, a vanished device errno ENODEV (and the board disappears from enumeration), a busy
device errno EBUSY. A stuck relay accepts its command but does not move.
"""

from __future__ import annotations

import array
import errno
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Literal

import usb.backend
import usb.core

from mocks.lamps import Clock, LampBank, WallClock

__all__ = [
    "DCTTECH_MANUFACTURER",
    "EmulatedRelayBoard",
    "FakeUsbBackend",
    "UsbFault",
    "UsbFaultKind",
    "device_descriptor",
]

DCTTECH_MANUFACTURER = "www.dcttech.com"
VUSB_VENDOR_ID = 0x16C0
VUSB_HID_PRODUCT_ID = 0x05DF
LANGID_US_ENGLISH = 0x0409
LOW_SPEED = 1  # pyusb's SPEED_LOW
REPORT_LENGTH = 8
STRING_INDEX_MANUFACTURER = 1
STRING_INDEX_PRODUCT = 2

#: libusb error code (negative) and errno for each emulated failure, as the libusb1 backend maps them.
_LIBUSB_ERRORS: dict[str, tuple[int, int, str]] = {
    "timeout": (-7, errno.ETIMEDOUT, "Operation timed out"),
    "stall": (-9, errno.EPIPE, "Pipe error"),
    "disconnect": (-4, errno.ENODEV, "No such device (it may have been disconnected)"),
    "busy": (-6, errno.EBUSY, "Resource busy"),
}

UsbFaultKind = Literal[
    "timeout", "late", "stall", "disconnect", "busy", "short_reply", "garbled_reply", "stuck_relay"
]
UsbRequest = Literal["set_report", "get_report", "string", "open", "any"]


@dataclass
class UsbFault:
    """One injected fault.

    Parameters
    ----------
    kind
        ``timeout`` (no answer: the transfer times out), ``late`` (the answer comes after
        ``delay_s``; a timeout if that exceeds the transfer's timeout), ``stall`` (endpoint 0
        STALL), ``disconnect`` (the board vanishes; this and every later access fail with ENODEV),
        ``busy`` (EBUSY), ``short_reply`` (a GET_REPORT returns only ``short_length`` bytes),
        ``garbled_reply`` (a GET_REPORT with every bit of the report inverted), ``stuck_relay``
        (the command is acknowledged but relay ``channel`` does not move).
    request
        Which requests trigger it: ``set_report``, ``get_report``, ``string`` (descriptor reads),
        ``open`` (opening the device), or ``any``.
    skip
        Let this many matching requests pass first ("the 3rd SET_REPORT": ``skip=2``).
    times
        How many matching requests fail; ``None`` = every one from then on.
    channel
        Relay for ``stuck_relay`` (``None`` = every relay).
    """

    kind: UsbFaultKind
    request: UsbRequest = "any"
    skip: int = 0
    times: int | None = 1
    channel: int | None = None
    short_length: int = 5
    delay_s: float = 0.0
    fired: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        implied: dict[str, UsbRequest] = {
            "stuck_relay": "set_report",
            "short_reply": "get_report",
            "garbled_reply": "get_report",
        }
        if self.request == "any" and self.kind in implied:
            self.request = implied[self.kind]

    def matches(self, request: UsbRequest) -> bool:
        if self.request not in ("any", request):
            return False
        if self.skip > 0:
            self.skip -= 1
            return False
        return self.times is None or self.fired < self.times


def device_descriptor(
    vendor_id: int, product_id: int, *, bus: int, address: int, **overrides: object
) -> SimpleNamespace:
    """A USB device descriptor as pyusb's ``Device`` reads it (every field it copies must exist).

    Defaults are those of a dcttech board: USB 1.1, low speed, 8-byte endpoint 0, manufacturer and
    product strings at indices 1 and 2, no serial-number string (the board ID lives in the
    feature report), one configuration. ``overrides`` replace any field by its USB name.
    """
    fields: dict[str, object] = {
        "bLength": 18,
        "bDescriptorType": 1,
        "bcdUSB": 0x0110,
        "bDeviceClass": 0,
        "bDeviceSubClass": 0,
        "bDeviceProtocol": 0,
        "bMaxPacketSize0": 8,
        "idVendor": vendor_id,
        "idProduct": product_id,
        "bcdDevice": 0x0100,
        "iManufacturer": STRING_INDEX_MANUFACTURER,
        "iProduct": STRING_INDEX_PRODUCT,
        "iSerialNumber": 0,
        "bNumConfigurations": 1,
        "bus": bus,
        "address": address,
        "port_number": None,
        "port_numbers": None,
        "speed": LOW_SPEED,
    }
    unknown = set(overrides) - set(fields)
    if unknown:
        raise ValueError(f"not device descriptor fields: {sorted(unknown)}")
    fields.update(overrides)
    return SimpleNamespace(**fields)


class EmulatedRelayBoard:
    """The firmware of one board.

    Parameters
    ----------
    serial
        The 5-character board ID (``"UNSET"`` is what blank replacement firmware reports).
    channels
        Relay count (1, 2, 4 or 8); the product string becomes ``USBRelay<channels>``.
    lamp_bank
        Lamps on the relay channels; relay *n* switches bank channel *n*.
    address, bus
        Where the board sits on the bus.
    manufacturer, product
        Override the strings, e.g. to emulate another V-USB gadget with the same VID/PID.
    """

    def __init__(
        self,
        serial: str = "QAAMZ",
        channels: int = 2,
        *,
        lamp_bank: LampBank | None = None,
        address: int = 4,
        bus: int = 1,
        manufacturer: str = DCTTECH_MANUFACTURER,
        product: str | None = None,
    ) -> None:
        if len(serial.encode("ascii")) > 5:
            raise ValueError(f"a board ID has at most 5 ASCII characters, got {serial!r}")
        if lamp_bank is not None and lamp_bank.n_channels < channels:
            raise ValueError(
                f"lamp bank has {lamp_bank.n_channels} channels, board has {channels} relays"
            )
        self.serial = serial
        self.channels = channels
        self.lamp_bank = lamp_bank
        self.manufacturer = manufacturer
        self.product = product if product is not None else f"USBRelay{channels}"
        self.descriptor = device_descriptor(
            VUSB_VENDOR_ID, VUSB_HID_PRODUCT_ID, bus=bus, address=address
        )
        self.state_mask = 0
        self.plugged = True
        self.kernel_driver_active = True  # usbhid binds HID interfaces on Linux
        self.faults: list[UsbFault] = []
        self.commands: list[bytes] = []
        """Every SET_REPORT payload the board accepted, in order."""

    def inject(self, fault: UsbFault) -> UsbFault:
        """Arm a fault; returns it so a test can read ``fault.fired``."""
        self.faults.append(fault)
        return fault

    def relay_states(self) -> tuple[bool, ...]:
        return tuple(bool(self.state_mask >> n & 1) for n in range(self.channels))

    # --------------------------------------------------------------------------- firmware

    def feature_report(self) -> bytes:
        ident = self.serial.encode("ascii").ljust(5, b"\x00")
        return ident + b"\x00\x00" + bytes([self.state_mask])

    def apply(self, report: bytes, stuck: set[int]) -> None:
        """Execute a SET_REPORT payload; relays in ``stuck`` ignore it."""
        self.commands.append(bytes(report))
        command, argument = report[0], report[1]
        before = self.state_mask
        if command == 0xFF and 1 <= argument <= self.channels:
            self.state_mask |= 1 << (argument - 1)
        elif command == 0xFD and 1 <= argument <= self.channels:
            self.state_mask &= ~(1 << (argument - 1))
        elif command == 0xFE:
            self.state_mask = (1 << self.channels) - 1
        elif command == 0xFC:
            self.state_mask = 0
        elif command == 0xFA:
            self.serial = bytes(report[1:6]).decode("ascii", errors="replace")
        # Unknown commands and out-of-range relays are ignored, as the firmware does.
        for relay in stuck:
            bit = 1 << (relay - 1)
            self.state_mask = (self.state_mask & ~bit) | (before & bit)
        if self.lamp_bank is not None:
            for relay, on in enumerate(self.relay_states(), start=1):
                self.lamp_bank.set_channel(relay, on)

    def string_descriptor(self, index: int) -> bytes | None:
        if index == 0:
            return bytes([4, 3]) + LANGID_US_ENGLISH.to_bytes(2, "little")
        text = {
            STRING_INDEX_MANUFACTURER: self.manufacturer,
            STRING_INDEX_PRODUCT: self.product,
        }.get(index)
        if text is None:
            return None
        encoded = text.encode("utf-16-le")
        return bytes([2 + len(encoded), 3]) + encoded


def _usb_error(kind: str) -> usb.core.USBError:
    code, errno_value, text = _LIBUSB_ERRORS[kind]
    if kind == "timeout":
        return usb.core.USBTimeoutError(text, code, errno_value)
    return usb.core.USBError(text, code, errno_value)


@dataclass
class _Handle:
    board: EmulatedRelayBoard
    claimed: set[int] = field(default_factory=set)


class FakeUsbBackend(usb.backend.IBackend):  # type: ignore[misc]
    """A pyusb backend serving :class:`EmulatedRelayBoard` s (and nothing else).

    Parameters
    ----------
    boards
        The boards plugged in.
    clock
        Time source for timeouts (a timed-out transfer sleeps its timeout on this clock).
    """

    def __init__(self, boards: Sequence[EmulatedRelayBoard], clock: Clock | None = None) -> None:
        self.boards = list(boards)
        addresses = [(b.descriptor.bus, b.descriptor.address) for b in self.boards]
        if len(set(addresses)) != len(addresses):
            raise ValueError(f"two boards share a bus address: {addresses}")
        self.clock: Clock = clock or WallClock()
        self._lock = threading.RLock()
        self.transfers: list[tuple[int, int, int, int, bytes]] = []
        """Every control transfer's (bmRequestType, bRequest, wValue, wIndex, OUT data)."""

    # ------------------------------------------------------------------------ hot plug

    def unplug(self, board: EmulatedRelayBoard) -> None:
        with self._lock:
            board.plugged = False

    def replug(self, board: EmulatedRelayBoard, address: int | None = None) -> None:
        """Plug a board back in; like a real replug, it may get a new address."""
        with self._lock:
            board.plugged = True
            board.state_mask = 0  # relays drop when power goes
            if address is not None:
                board.descriptor.address = address

    # ------------------------------------------------------------------------ IBackend

    def enumerate_devices(self) -> list[EmulatedRelayBoard]:
        with self._lock:
            return [board for board in self.boards if board.plugged]

    def get_device_descriptor(self, dev: EmulatedRelayBoard) -> SimpleNamespace:
        return dev.descriptor

    def open_device(self, dev: EmulatedRelayBoard) -> _Handle:
        with self._lock:
            self._fire(dev, "open", None)
            return _Handle(dev)

    def close_device(self, dev_handle: _Handle) -> None:
        dev_handle.claimed.clear()

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        with self._lock:
            board = dev_handle.board
            self._check_plugged(board)
            if board.kernel_driver_active:
                raise _usb_error("busy")  # libusb: LIBUSB_ERROR_BUSY while usbhid holds it
            dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        dev_handle.claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle: _Handle, intf: int) -> bool:
        self._check_plugged(dev_handle.board)
        return dev_handle.board.kernel_driver_active

    def detach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        self._check_plugged(dev_handle.board)
        dev_handle.board.kernel_driver_active = False

    def attach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        self._check_plugged(dev_handle.board)
        dev_handle.board.kernel_driver_active = True

    def ctrl_transfer(
        self,
        dev_handle: _Handle,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: array.array[int],
        timeout: int,
    ) -> int:
        board = dev_handle.board
        with self._lock:
            self.transfers.append((bmRequestType, bRequest, wValue, wIndex, bytes(data)))
            recipient = bmRequestType & 0x1F
            kind = bmRequestType & 0x60
            if recipient == 1 and kind == 0x20 and wIndex not in dev_handle.claimed:
                # pyusb claims the interface before interface-recipient class requests.
                raise _usb_error("stall")
            request = self._classify(bmRequestType, bRequest, wValue)
            fault = self._fire(board, request, timeout)
            if request == "string":
                return self._reply(data, board.string_descriptor(wValue & 0xFF))
            if request == "get_report":
                report = board.feature_report()
                if fault is not None and fault.kind == "short_reply":
                    report = report[: fault.short_length]
                elif fault is not None and fault.kind == "garbled_reply":
                    report = bytes(b ^ 0xFF for b in report)
                return self._reply(data, report)
            if request == "set_report":
                if len(data) != REPORT_LENGTH:
                    raise _usb_error("stall")
                stuck = self._stuck_relays(board, fault)
                board.apply(bytes(data), stuck)
                return len(data)
            raise _usb_error("stall")

    # ------------------------------------------------------------------------ internals

    @staticmethod
    def _classify(request_type: int, request: int, value: int) -> UsbRequest | None:
        if request_type == 0x80 and request == 0x06 and value >> 8 == 0x03:
            return "string"
        if request_type in (0x21, 0x20) and request == 0x09 and value == 0x0300:
            return "set_report"
        if request_type in (0xA1, 0xA0) and request == 0x01 and value == 0x0300:
            return "get_report"
        return None

    @staticmethod
    def _reply(buffer: array.array[int], payload: bytes | None) -> int:
        if payload is None:
            raise _usb_error("stall")
        count = min(len(buffer), len(payload))
        buffer[:count] = array.array("B", payload[:count])
        return count

    @staticmethod
    def _stuck_relays(board: EmulatedRelayBoard, fault: UsbFault | None) -> set[int]:
        if fault is None or fault.kind != "stuck_relay":
            return set()
        if fault.channel is None:
            return set(range(1, board.channels + 1))
        return {fault.channel}

    def _check_plugged(self, board: EmulatedRelayBoard) -> None:
        if not board.plugged:
            raise _usb_error("disconnect")

    def _fire(
        self, board: EmulatedRelayBoard, request: UsbRequest | None, timeout_ms: int | None
    ) -> UsbFault | None:
        """Raise or return the fault armed for this request (after checking the board is there)."""
        self._check_plugged(board)
        if request is None:
            return None
        for fault in board.faults:
            if not fault.matches(request):
                continue
            fault.fired += 1
            if fault.kind == "disconnect":
                board.plugged = False
                raise _usb_error("disconnect")
            timeout_s = (timeout_ms or 1000) / 1000.0
            if fault.kind == "timeout" or (fault.kind == "late" and fault.delay_s >= timeout_s):
                self.clock.sleep(timeout_s)
                raise _usb_error("timeout")
            if fault.kind == "late":
                self.clock.sleep(fault.delay_s)
                return None
            if fault.kind in ("stall", "busy"):
                raise _usb_error(fault.kind)
            return fault
        return None
