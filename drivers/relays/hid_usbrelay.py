"""dcttech "USBRelayN" HID relay boards (V-USB firmware) over pyusb control transfers.

The board is a low-speed USB HID device (VID 0x16C0, PID 0x05DF — the shared V-USB ids, so the
manufacturer string ``www.dcttech.com`` and a product string ``USBRelay<n>`` are checked too). It has
one 8-byte Feature report and no report ID:

- HID SET_REPORT (Feature) writes a command: ``FF n`` switches relay *n* on, ``FD n`` off, ``FE`` all
  on, ``FC`` all off, ``FA`` + 5 ASCII bytes stores a new board ID (serial). Remaining bytes are zero.
- HID GET_REPORT (Feature) returns the 5-character ID in bytes 0–4 and the relay state bitmask in
  byte 7 (bit *n − 1* set = relay *n* on).

Every switch is verified by reading the state back (:func:`drivers.relays.verify_relay_state`). Every
control transfer goes to the transcript: ``tx`` carries the 8-byte setup packet followed by any OUT
payload, ``rx`` the IN payload, ``error`` a UTF-8 JSON description of a failed transfer.

References: the device side is documented by the open replacement firmware ``u1f35c/usb-relay-firmware``
and the host side by ``darrylb123/usbrelay``, ``JPEWdev/pyhid-usb-relay`` and libsigrok's
``dcttech-usbrelay`` driver (see ``shared/research/protocols.md`` §2.1, §3).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import re
import struct
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

from drivers.base import (
    DeviceBusy,
    DeviceError,
    DeviceIdentity,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    ProtocolError,
    StateMismatch,
    TranscriptEntry,
    TranscriptSink,
)
from drivers.libraries import pyusb
from drivers.relays import verify_relay_state

__all__ = [
    "DEFAULT_TIMEOUT_S",
    "MANUFACTURER",
    "PRODUCT_PREFIX",
    "USB_PRODUCT_ID",
    "USB_VENDOR_ID",
    "HidRelayInfo",
    "HidUsbRelay",
    "RequestRecipient",
    "find_hid_relays",
    "open_hid_relay",
]

USB_VENDOR_ID = 0x16C0
"""V-USB shared vendor id (Objective Development / van Ooijen)."""
USB_PRODUCT_ID = 0x05DF
"""V-USB shared "HID class" product id."""
MANUFACTURER = "www.dcttech.com"
"""Manufacturer string that tells a dcttech relay board from other V-USB gadgets."""
PRODUCT_PREFIX = "USBRelay"
"""Product string prefix; the digits after it give the relay count."""
SUPPORTED_CHANNEL_COUNTS = (1, 2, 4, 8)

REPORT_LENGTH = 8
"""Length of the one Feature report, bytes (no report ID)."""
SERIAL_LENGTH = 5
"""Length of the board ID (serial) in the Feature report, ASCII characters."""
STATE_BYTE_INDEX = 7
"""Index of the relay state bitmask in the Feature report."""

CMD_ON = 0xFF
CMD_OFF = 0xFD
CMD_ALL_ON = 0xFE
CMD_ALL_OFF = 0xFC
CMD_SET_SERIAL = 0xFA

HID_GET_REPORT = 0x01
HID_SET_REPORT = 0x09
HID_REPORT_TYPE_FEATURE = 0x03
FEATURE_REPORT_VALUE = HID_REPORT_TYPE_FEATURE << 8  # report ID 0 in the low byte
HID_INTERFACE = 0

USB_GET_DESCRIPTOR = 0x06
USB_DESCRIPTOR_TYPE_STRING = 0x03
USB_REQUEST_TYPE_STANDARD_IN = 0x80
STRING_DESCRIPTOR_MAX_LENGTH = 254  # the longest even length, as pyusb asks
LANGID_US_ENGLISH = 0x0409

RequestRecipient = Literal["device", "interface"]
#: bmRequestType for (SET_REPORT, GET_REPORT) per recipient. The HID spec says "interface"
#: (0x21/0xA1), which makes pyusb claim interface 0 and, on Linux, requires detaching usbhid first.
#: V-USB does not check the recipient, so "device" (0x20/0xA0, as pyhid-usb-relay sends) works
#: without touching the kernel driver. [?] untested on hardware: see docs/decisions/0004.
REQUEST_TYPES: dict[RequestRecipient, tuple[int, int]] = {
    "device": (0x20, 0xA0),
    "interface": (0x21, 0xA1),
}
DEFAULT_RECIPIENT: RequestRecipient = "device"

READBACK_CONFIRMATIONS = 1
"""Extra reads of the state after a mismatching one before :class:`StateMismatch` is raised: the
report has no checksum, so one odd read is confirmed before a run is stopped."""
DEFAULT_TIMEOUT_S = 1.0
"""Control-transfer timeout. The board answers in a few ms; pyusb's own default is 1000 ms."""

_ERRNO_TIMEOUT = errno.ETIMEDOUT
_ERRNO_GONE = frozenset({errno.ENODEV, errno.ENOENT, errno.ESHUTDOWN})
_ERRNO_BUSY = frozenset({errno.EBUSY, errno.EAGAIN})
_ERRNO_STALL = errno.EPIPE
_ERRNO_ACCESS = errno.EACCES
_UDEV_HINT = (
    'add a udev rule such as SUBSYSTEM=="usb", ATTR{idVendor}=="16c0", ATTR{idProduct}=="05df", '
    'MODE="0666" (as usbrelay ships) and replug the board'
)


def setup_packet(request_type: int, request: int, value: int, index: int, length: int) -> bytes:
    """The 8-byte USB SETUP packet of a control transfer (little-endian words), as on the wire."""
    return struct.pack("<BBHHH", request_type, request, value, index, length)


def command_report(command: int, argument: bytes = b"") -> bytes:
    """An 8-byte Feature report: the command byte, its argument, zero padding."""
    report = bytes([command]) + argument
    if len(report) > REPORT_LENGTH:
        raise ValueError(f"command report {report.hex(' ')} is longer than {REPORT_LENGTH} bytes")
    return report.ljust(REPORT_LENGTH, b"\x00")


def decode_string_descriptor(descriptor: bytes) -> str:
    """Text of a USB string descriptor (bLength, bDescriptorType=3, UTF-16LE)."""
    if len(descriptor) < 2 or descriptor[1] != USB_DESCRIPTOR_TYPE_STRING:
        raise ValueError(f"not a string descriptor: {descriptor.hex(' ')}")
    length = min(descriptor[0], len(descriptor)) & 0xFE
    return descriptor[2:length].decode("utf-16-le", errors="replace")


def channel_count_from_product(product: str) -> int:
    """Relay count from a product string such as ``USBRelay4``; raises ValueError otherwise."""
    match = re.fullmatch(re.escape(PRODUCT_PREFIX) + r"(\d+)", product.strip())
    if match is None or int(match.group(1)) not in SUPPORTED_CHANNEL_COUNTS:
        raise ValueError(
            f"product string {product!r} is not {PRODUCT_PREFIX}<n> with n in "
            f"{SUPPORTED_CHANNEL_COUNTS}"
        )
    return int(match.group(1))


@dataclasses.dataclass(frozen=True)
class FeatureReport:
    """The decoded 8-byte Feature report: board ID and relay bitmask."""

    serial: str
    state_mask: int

    @classmethod
    def decode(cls, report: bytes) -> FeatureReport:
        if len(report) != REPORT_LENGTH:
            raise ValueError(f"feature report has {len(report)} bytes, expected {REPORT_LENGTH}")
        serial = report[:SERIAL_LENGTH].rstrip(b"\x00").decode("ascii", errors="replace")
        return cls(serial=serial, state_mask=report[STATE_BYTE_INDEX])

    def channel_states(self, channels: int) -> tuple[bool, ...]:
        return tuple(bool(self.state_mask >> (n - 1) & 1) for n in range(1, channels + 1))


@dataclasses.dataclass(frozen=True)
class HidRelayInfo:
    """A dcttech board as found on the bus (discovery and selection by serial)."""

    serial: str
    product: str
    channels: int
    bus: int | None
    address: int | None
    state_mask: int = 0
    """Relay bitmask when the board was probed (bit n-1 = relay n)."""

    @property
    def port(self) -> str:
        """``usb:BBB,AAA`` (bus, address), the notation libgphoto2 also uses."""
        if self.bus is None or self.address is None:
            return "usb"
        return f"usb:{self.bus:03d},{self.address:03d}"


class _ControlChannel:
    """Control transfers on endpoint 0 of one device, each logged and mapped to typed errors."""

    def __init__(
        self,
        usb_device: Any,
        label: str,
        transcript: TranscriptSink | None,
        timeout_s: float,
        recipient: RequestRecipient,
        monotonic: Callable[[], float],
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self.usb_device = usb_device
        self.label = label
        self.transcript = transcript
        self.timeout_s = timeout_s
        self.recipient = recipient
        self.set_report_type, self.get_report_type = REQUEST_TYPES[recipient]
        self._monotonic = monotonic
        self._detached_kernel_driver = False

    def take_interface(self) -> None:
        """For interface-recipient requests, detach the kernel's usbhid from interface 0 (Linux).

        pyusb claims the interface before such a request, which fails with EBUSY while usbhid holds
        it. Device-recipient requests need nothing.
        """
        if self.recipient != "interface":
            return
        try:
            active = self.usb_device.is_kernel_driver_active(HID_INTERFACE)
            if active:
                self.usb_device.detach_kernel_driver(HID_INTERFACE)
                self._detached_kernel_driver = True
                self.event("detach_kernel_driver", interface=HID_INTERFACE)
        except NotImplementedError:
            pass  # macOS / Windows backends have no kernel-driver notion
        except pyusb().USBError as exc:
            raise self._typed_error(exc, b"") from exc

    def release(self) -> None:
        """Free the device handle and give the interface back to usbhid if it was detached."""
        if self._detached_kernel_driver:
            self._detached_kernel_driver = False
            # Best effort: the board may already be gone.
            with contextlib.suppress(pyusb().USBError, NotImplementedError):
                self.usb_device.attach_kernel_driver(HID_INTERFACE)
        with contextlib.suppress(pyusb().USBError, NotImplementedError):
            pyusb().util.dispose_resources(self.usb_device)

    def read_report(self) -> FeatureReport:
        """HID GET_REPORT (Feature): the board ID and relay bitmask."""
        raw = self.control_in(
            self.get_report_type,
            HID_GET_REPORT,
            FEATURE_REPORT_VALUE,
            HID_INTERFACE,
            REPORT_LENGTH,
        )
        try:
            return FeatureReport.decode(raw)
        except ValueError as exc:
            raise ProtocolError(
                self.label, f"short feature report: {exc}", command="GET_REPORT", reply=raw
            ) from exc

    def write_report(self, report: bytes) -> None:
        """HID SET_REPORT (Feature) with an 8-byte command report."""
        self.control_out(
            self.set_report_type, HID_SET_REPORT, FEATURE_REPORT_VALUE, HID_INTERFACE, report
        )

    def _record(self, direction: Literal["tx", "rx", "error", "event"], payload: bytes) -> None:
        if self.transcript is not None:
            self.transcript.record(
                TranscriptEntry(self.label, direction, payload, self._monotonic())
            )

    def event(self, what: str, **details: object) -> None:
        self._record("event", json.dumps({"event": what, **details}).encode("utf-8"))

    def control_out(
        self, request_type: int, request: int, value: int, index: int, data: bytes
    ) -> None:
        packet = setup_packet(request_type, request, value, index, len(data))
        self._record("tx", packet + data)
        written = self._transfer(packet, request_type, request, value, index, data)
        if written != len(data):
            raise ProtocolError(
                self.label,
                f"control OUT wrote {written} of {len(data)} bytes",
                command=packet + data,
                reply=None,
            )

    def control_in(
        self, request_type: int, request: int, value: int, index: int, length: int
    ) -> bytes:
        packet = setup_packet(request_type, request, value, index, length)
        self._record("tx", packet)
        reply = bytes(self._transfer(packet, request_type, request, value, index, length))
        self._record("rx", reply)
        return reply

    def _transfer(
        self, packet: bytes, request_type: int, request: int, value: int, index: int, data: Any
    ) -> Any:
        timeout_ms = max(1, round(self.timeout_s * 1000))
        try:
            return self.usb_device.ctrl_transfer(
                request_type, request, value, index, data, timeout_ms
            )
        except pyusb().USBError as exc:
            self._record(
                "error",
                json.dumps(
                    {"setup": packet.hex(), "errno": exc.errno, "message": str(exc.strerror or exc)}
                ).encode("utf-8"),
            )
            raise self._typed_error(exc, packet) from exc

    def _typed_error(self, exc: Any, packet: bytes) -> DeviceError:
        code = exc.errno
        text = str(exc.strerror or exc)
        if isinstance(exc, pyusb().USBTimeoutError) or code == _ERRNO_TIMEOUT:
            return DeviceTimeout(
                self.label,
                f"no answer to control transfer within {self.timeout_s:g} s ({text})",
                command=packet,
                timeout_s=self.timeout_s,
            )
        if code in _ERRNO_GONE:
            return Disconnected(self.label, f"board went away during a control transfer ({text})")
        if code in _ERRNO_BUSY:
            return DeviceBusy(
                self.label,
                f"USB device or interface busy ({text}); another program (usbrelay, hidraw "
                "user) may hold it",
            )
        if code == _ERRNO_STALL:
            return ProtocolError(
                self.label, "board stalled the control request (STALL)", command=packet, reply=None
            )
        if code == _ERRNO_ACCESS:
            return DeviceError(self.label, f"permission denied on the USB device: {_UDEV_HINT}")
        return ProtocolError(
            self.label,
            f"control transfer failed: {text} (errno {code})",
            command=packet,
            reply=None,
        )

    def read_string(self, descriptor_index: int, langid: int) -> str:
        raw = self.control_in(
            USB_REQUEST_TYPE_STANDARD_IN,
            USB_GET_DESCRIPTOR,
            (USB_DESCRIPTOR_TYPE_STRING << 8) | descriptor_index,
            langid,
            STRING_DESCRIPTOR_MAX_LENGTH,
        )
        try:
            return decode_string_descriptor(raw)
        except ValueError as exc:
            raise ProtocolError(
                self.label, str(exc), command=f"string descriptor {descriptor_index}", reply=raw
            ) from exc

    def first_langid(self) -> int:
        raw = self.control_in(
            USB_REQUEST_TYPE_STANDARD_IN,
            USB_GET_DESCRIPTOR,
            USB_DESCRIPTOR_TYPE_STRING << 8,
            0,
            STRING_DESCRIPTOR_MAX_LENGTH,
        )
        if len(raw) < 4 or raw[1] != USB_DESCRIPTOR_TYPE_STRING:
            raise ProtocolError(
                self.label, "device has no language IDs", command="string descriptor 0", reply=raw
            )
        return int.from_bytes(raw[2:4], "little")


def _device_label(usb_device: Any, serial: str | None = None) -> str:
    where = _usb_port(usb_device)
    return f"HID USBRelay {serial} on {where}" if serial else f"HID USBRelay on {where}"


def _usb_port(usb_device: Any) -> str:
    bus, address = getattr(usb_device, "bus", None), getattr(usb_device, "address", None)
    if bus is None or address is None:
        return "usb"
    return f"usb:{int(bus):03d},{int(address):03d}"


def _probe(
    usb_device: Any,
    transcript: TranscriptSink | None,
    timeout_s: float,
    recipient: RequestRecipient,
    monotonic: Callable[[], float],
) -> tuple[HidRelayInfo, _ControlChannel] | str:
    """Identify one VID/PID match; return its info, or why it is not a dcttech relay board."""
    channel = _ControlChannel(
        usb_device, _device_label(usb_device), transcript, timeout_s, recipient, monotonic
    )
    try:
        langid = channel.first_langid()
        manufacturer = channel.read_string(usb_device.iManufacturer, langid)
        if manufacturer != MANUFACTURER:
            return f"{channel.label}: manufacturer {manufacturer!r} is not {MANUFACTURER!r}"
        product = channel.read_string(usb_device.iProduct, langid)
    except DeviceError as exc:
        return f"{channel.label}: cannot read its strings ({exc.message})"
    try:
        channels = channel_count_from_product(product)
    except ValueError as exc:
        return f"{channel.label}: {exc}"
    try:
        channel.take_interface()
        report = channel.read_report()
    except DeviceError as exc:
        channel.release()
        return f"{channel.label}: cannot read its feature report ({exc.message})"
    info = HidRelayInfo(
        serial=report.serial,
        product=product,
        channels=channels,
        bus=getattr(usb_device, "bus", None),
        address=getattr(usb_device, "address", None),
        state_mask=report.state_mask,
    )
    channel.label = _device_label(usb_device, info.serial)
    return info, channel


def _find_matches(backend: Any) -> list[Any]:
    try:
        return list(
            pyusb().find(
                find_all=True, idVendor=USB_VENDOR_ID, idProduct=USB_PRODUCT_ID, backend=backend
            )
        )
    except pyusb().NoBackendError as exc:
        raise DeviceNotFound(
            "HID USBRelay",
            "no USB backend available (libusb-1.0 not found): install it "
            "(apt install libusb-1.0-0, brew install libusb) or `pip install libusb-package`",
        ) from exc


def _probe_all(
    backend: Any,
    transcript: TranscriptSink | None,
    timeout_s: float,
    recipient: RequestRecipient,
) -> tuple[list[tuple[HidRelayInfo, _ControlChannel]], list[str]]:
    boards: list[tuple[HidRelayInfo, _ControlChannel]] = []
    skipped: list[str] = []
    for usb_device in _find_matches(backend):
        probed = _probe(usb_device, transcript, timeout_s, recipient, time.monotonic)
        if isinstance(probed, str):
            skipped.append(probed)
            with contextlib.suppress(pyusb().USBError, NotImplementedError):
                pyusb().util.dispose_resources(usb_device)
        else:
            boards.append(probed)
    return boards, skipped


def find_hid_relays(
    *,
    backend: Any = None,
    transcript: TranscriptSink | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    recipient: RequestRecipient = DEFAULT_RECIPIENT,
) -> tuple[list[HidRelayInfo], list[str]]:
    """List the dcttech relay boards on the bus without keeping them open.

    Returns
    -------
    boards, skipped
        The boards found, and one line per VID/PID match that is not a usable relay board (other
        V-USB gadgets, boards whose strings cannot be read) saying why.

    Raises
    ------
    DeviceNotFound
        When pyusb has no backend (libusb missing).
    """
    boards, skipped = _probe_all(backend, transcript, timeout_s, recipient)
    for _, channel in boards:
        channel.release()
    return [info for info, _ in boards], skipped


class HidUsbRelay:
    """A dcttech USBRelay board; implements :class:`drivers.base.RelayBoard`.

    Use :func:`open_hid_relay` to find and open one. Channels are numbered from 1.

    Notes
    -----
    After every switch the driver reads the Feature report back and raises
    :class:`~drivers.base.StateMismatch` unless the whole bitmask equals what it expects (the last
    state read back, with the commanded change); a mismatching read is confirmed by one more read
    first (:data:`READBACK_CONFIRMATIONS`). Each control transfer has the timeout given at
    open; libusb enforces it, so no call here blocks longer.
    """

    def __init__(self, info: HidRelayInfo, channel: _ControlChannel) -> None:
        self._info = info
        self._io = channel
        self._closed = False
        self._known_state = FeatureReport(info.serial, info.state_mask).channel_states(
            info.channels
        )
        self._io.event("open", serial=info.serial, product=info.product, port=info.port)

    # ----------------------------------------------------------------------------- identity

    @property
    def channels(self) -> int:
        return self._info.channels

    @property
    def serial(self) -> str:
        return self._info.serial

    @property
    def device(self) -> str:
        """Label used in errors and transcripts, e.g. ``HID USBRelay QAAMZ on usb:001,004``."""
        return self._io.label

    def identify(self) -> DeviceIdentity:
        return DeviceIdentity(
            kind="relay",
            model=f"dcttech {self._info.product}",
            serial=self._info.serial,
            port=self._info.port,
            extra={
                "vendor_id": f"0x{USB_VENDOR_ID:04x}",
                "product_id": f"0x{USB_PRODUCT_ID:04x}",
                "request_recipient": self._io.recipient,
                "timeout_s": f"{self._io.timeout_s:g}",
            },
        )

    # ----------------------------------------------------------------------------- switching

    def set(self, channel: int, on: bool) -> None:
        """Switch relay ``channel`` (1-based) on or off, then verify by reading the state back."""
        self._check_channel(channel)
        expected = list(self._known_state)
        expected[channel - 1] = on
        self._command(command_report(CMD_ON if on else CMD_OFF, bytes([channel])), expected)

    def all_on(self) -> None:
        """Switch every relay on (one command) and verify."""
        self._command(command_report(CMD_ALL_ON), [True] * self.channels)

    def all_off(self) -> None:
        """Switch every relay off (one command) and verify."""
        self._command(command_report(CMD_ALL_OFF), [False] * self.channels)

    def state(self) -> tuple[bool, ...]:
        """Relays 1..n as the board reports them."""
        self._check_open()
        states = self._io.read_report().channel_states(self.channels)
        self._known_state = states
        return states

    def set_serial(self, new_serial: str) -> None:
        """Store a new 5-character board ID in the board's EEPROM and verify it.

        Boards often ship with identical IDs; give each a distinct one so that a rig with several
        boards can select them by serial.
        """
        if len(new_serial) != SERIAL_LENGTH or not new_serial.isascii() or not new_serial.isalnum():
            raise ValueError(
                f"a board ID must be {SERIAL_LENGTH} ASCII letters or digits, got {new_serial!r}"
            )
        self._check_open()
        self._io.write_report(command_report(CMD_SET_SERIAL, new_serial.encode("ascii")))
        report = self._io.read_report()
        if report.serial != new_serial:
            raise StateMismatch(
                self.device,
                "board ID read back after writing it",
                expected=new_serial,
                actual=report.serial,
            )
        self._info = dataclasses.replace(self._info, serial=new_serial)
        self._io.label = _device_label(self._io.usb_device, new_serial)

    def close(self) -> None:
        """Release the USB device (and give the interface back to usbhid if it was detached)."""
        if self._closed:
            return
        self._closed = True
        self._io.event("close")
        self._io.release()

    def __enter__(self) -> HidUsbRelay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------------------- internals

    def _command(self, report: bytes, expected: Sequence[bool]) -> None:
        self._check_open()
        self._io.write_report(report)
        actual = self.state()
        for _ in range(READBACK_CONFIRMATIONS):
            if actual == tuple(expected):
                break
            self._io.event("state_reread", expected=list(expected), actual=list(actual))
            actual = self.state()
        verify_relay_state(self.device, expected, actual)

    def _check_channel(self, channel: int) -> None:
        if isinstance(channel, bool) or not isinstance(channel, int):
            raise TypeError(f"{self.device}: channel must be an int, got {channel!r}")
        if not 1 <= channel <= self.channels:
            raise ValueError(
                f"{self.device}: channel {channel} does not exist; this board has channels "
                f"1..{self.channels}"
            )

    def _check_open(self) -> None:
        if self._closed:
            raise Disconnected(self.device, "the driver was closed; open the board again")


def open_hid_relay(
    serial: str | None,
    *,
    backend: Any = None,
    transcript: TranscriptSink | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    recipient: RequestRecipient = DEFAULT_RECIPIENT,
) -> HidUsbRelay:
    """Find and open a dcttech USBRelay board.

    Parameters
    ----------
    serial
        The board's 5-character ID. ``None`` opens the only board present (an error if there are
        several, listing their IDs).
    backend
        A pyusb backend (``usb.backend.IBackend``); ``None`` lets pyusb pick libusb.
    transcript
        Where every control transfer is recorded.
    timeout_s
        Timeout of each control transfer, seconds.
    recipient
        bmRequestType recipient of the HID class requests (see :data:`REQUEST_TYPES`).

    Raises
    ------
    DeviceNotFound
        No backend, no board, no board with that serial, several boards and no serial given, or two
        boards sharing the requested serial.
    """
    candidates, skipped = _probe_all(backend, transcript, timeout_s, recipient)
    wanted = [c for c in candidates if serial is None or c[0].serial == serial]
    chosen = wanted[0] if len(wanted) == 1 else None
    for candidate in candidates:
        if candidate is not chosen:
            candidate[1].release()
    if chosen is not None:
        return HidUsbRelay(*chosen)

    found = ", ".join(f"{info.serial!r} ({info.product} on {info.port})" for info, _ in candidates)
    not_relays = f"; other devices with VID/PID 16c0:05df: {'; '.join(skipped)}" if skipped else ""
    if not candidates:
        raise DeviceNotFound(
            "HID USBRelay", f"no dcttech USBRelay board found (VID 16c0, PID 05df){not_relays}"
        )
    if serial is None:
        raise DeviceNotFound(
            "HID USBRelay",
            f"{len(candidates)} boards found: {found}; set the serial of the one to use",
        )
    if not wanted:
        raise DeviceNotFound("HID USBRelay", f"no board with serial {serial!r}; found {found}")
    raise DeviceNotFound(
        "HID USBRelay",
        f"{len(wanted)} boards share serial {serial!r} ({found}); give each a distinct ID with "
        "HidUsbRelay.set_serial while only one is plugged in",
    )
