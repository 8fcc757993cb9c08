"""What is plugged in, for ``rig devices``: serial ports, HID relay boards, Ocean Optics
spectrometers (python-seabreeze) and gphoto2 cameras.

Each device comes with the YAML snippet of a ``devices:`` entry that uses it (``kind`` plus the
port, serial or model that selects it). Every source is optional and failure-proof: a missing USB
backend (no libusb), a missing python-gphoto2 or an error while probing becomes a note in the report
rather than an exception, so the command always prints what it could find. Nothing here can block:
HID probes use control-transfer timeouts and camera autodetection runs under a watchdog.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

import yaml

from drivers.base import DeviceError
from drivers.camera.detect import GphotoModule, list_cameras, load_gphoto2
from drivers.relays.hid_usbrelay import find_hid_relays
from drivers.spectrometer.ocean import find_ocean_spectrometers

__all__ = [
    "SERIAL_KIND_HINTS",
    "DiscoveredDevice",
    "DiscoveryReport",
    "list_devices",
    "render_text",
]

DeviceKind = Literal["serial_port", "hid_relay", "ocean_spectrometer", "camera"]

SERIAL_KIND_HINTS: dict[tuple[int, int | None], tuple[str, str]] = {
    (0x1A86, 0x7523): ("lcus", "CH340 USB-serial: LCUS relay boards use it (so do many adapters)"),
    (0x2A19, None): ("numato", "Numato Lab USB relay module"),
    (0x132B, None): ("cs2000", "Konica Minolta instrument (CS-2000/2000A?)"),
}
"""(VID, PID or None for any) → (suggested driver kind, why). [?] The Konica Minolta vendor id is
from USB id lists, not checked on a CS-2000; Photo Research's PR-655/670 CDC port has no confirmed
id and gets no suggestion."""
SERIAL_KINDS = ("pr655", "pr670", "cs2000", "lcus", "numato")


@dataclass(frozen=True)
class DiscoveredDevice:
    """One device found.

    Attributes
    ----------
    kind
        ``serial_port``, ``hid_relay``, ``ocean_spectrometer`` or ``camera``.
    name
        What it is, as far as the bus tells (model, product, description).
    address
        What selects it: a serial port path, a relay board serial, a camera port.
    details
        Everything else known (VID/PID as ``0x1a86``, manufacturer, channels …).
    config_snippet
        YAML for a ``devices:`` entry using it.
    """

    kind: DeviceKind
    name: str
    address: str
    details: dict[str, str] = field(default_factory=dict)
    config_snippet: str = ""


@dataclass(frozen=True)
class DiscoveryReport:
    """The devices found and, per source, anything that prevented a complete search."""

    devices: tuple[DiscoveredDevice, ...]
    notes: tuple[str, ...] = ()

    def of_kind(self, kind: DeviceKind) -> list[DiscoveredDevice]:
        return [d for d in self.devices if d.kind == kind]


def _snippet(entry: dict[str, object], comment: str) -> str:
    text = yaml.safe_dump(entry, sort_keys=False, default_flow_style=False, allow_unicode=True)
    return f"# {comment}\n{text}"


def _hex(value: int | None) -> str | None:
    return None if value is None else f"0x{value:04x}"


def _serial_devices(ports: Iterable[Any]) -> list[DiscoveredDevice]:
    devices: list[DiscoveredDevice] = []
    for port in sorted(ports, key=lambda p: str(p.device)):
        vid, pid = getattr(port, "vid", None), getattr(port, "pid", None)
        details = {
            key: str(value)
            for key, value in {
                "vendor_id": _hex(vid),
                "product_id": _hex(pid),
                "serial_number": getattr(port, "serial_number", None),
                "manufacturer": getattr(port, "manufacturer", None),
                "product": getattr(port, "product", None),
                "hwid": getattr(port, "hwid", None),
            }.items()
            if value not in (None, "", "n/a")
        }
        hint = SERIAL_KIND_HINTS.get((vid, pid)) or SERIAL_KIND_HINTS.get((vid, None))  # type: ignore[arg-type]
        description = str(getattr(port, "description", "") or "serial port")
        ids = f" [{vid:04x}:{pid:04x}]" if vid is not None and pid is not None else ""
        if hint is not None:
            kind, why = hint
            details["suggested_kind"] = kind
            comment = f"{port.device}: {description}{ids} — looks like: {why}"
        else:
            kind = "pr655"
            comment = (
                f"{port.device}: {description}{ids} — set kind to the instrument on this port "
                f"({', '.join(SERIAL_KINDS)})"
            )
        devices.append(
            DiscoveredDevice(
                kind="serial_port",
                name=description,
                address=str(port.device),
                details=details,
                config_snippet=_snippet({"kind": kind, "port": str(port.device)}, comment),
            )
        )
    return devices


def _relay_devices(backend: Any, timeout_s: float) -> tuple[list[DiscoveredDevice], list[str]]:
    boards, skipped = find_hid_relays(backend=backend, timeout_s=timeout_s)
    devices = []
    for board in boards:
        on = [str(n) for n in range(1, board.channels + 1) if board.state_mask >> (n - 1) & 1]
        devices.append(
            DiscoveredDevice(
                kind="hid_relay",
                name=f"dcttech {board.product}",
                address=board.serial,
                details={
                    "channels": str(board.channels),
                    "port": board.port,
                    "relays_on": ",".join(on) or "none",
                    "vendor_id": "0x16c0",
                    "product_id": "0x05df",
                },
                config_snippet=_snippet(
                    {"kind": "hid_usbrelay", "serial": board.serial},
                    f"dcttech {board.product} ({board.channels} relays) on {board.port}",
                ),
            )
        )
    return devices, [f"skipped USB device: {reason}" for reason in skipped]


def _ocean_devices(backend: Any) -> tuple[list[DiscoveredDevice], list[str]]:
    found, skipped = find_ocean_spectrometers(backend=backend)
    devices = [
        DiscoveredDevice(
            kind="ocean_spectrometer",
            name=f"Ocean {info.model}",
            address=info.serial,
            details={"port": info.port, "vendor_id": "0x2457"},
            config_snippet=_snippet(
                {
                    "kind": "seabreeze",
                    "serial": info.serial,
                    "calibration_file": f"calibration-{info.serial}.csv",
                },
                f"Ocean {info.model} on {info.port}; its relative irradiance calibration: the "
                "instrument's, or `rig calibrate-spectrometer --lamp A` against a known lamp",
            ),
        )
        for info in found
    ]
    return devices, [f"skipped Ocean spectrometer: {reason}" for reason in skipped]


def _camera_devices(gp: GphotoModule, timeout_s: float) -> list[DiscoveredDevice]:
    return [
        DiscoveredDevice(
            kind="camera",
            name=model,
            address=port,
            details={"port": port},
            config_snippet=_snippet(
                {"kind": "gphoto2", "model": model, "port": port}, f"{model} on {port}"
            ),
        )
        for model, port in list_cameras(gp, timeout_s=timeout_s)
    ]


def _default_serial_ports() -> list[Any]:
    from serial.tools import list_ports

    return list(list_ports.comports())


def list_devices(
    *,
    serial_ports: Callable[[], Iterable[Any]] | None = None,
    usb_backend: Any = None,
    gphoto2_module: GphotoModule | None = None,
    include_serial: bool = True,
    include_usb_relays: bool = True,
    include_ocean: bool = True,
    include_cameras: bool = True,
    timeout_s: float = 5.0,
) -> DiscoveryReport:
    """Find the serial ports, HID relay boards, Ocean spectrometers and cameras present.

    Parameters
    ----------
    serial_ports
        Returns pyserial ``ListPortInfo``-like objects (default ``list_ports.comports``).
    usb_backend
        pyusb backend for the relay and Ocean searches (default: pyusb's choice, i.e. libusb).
    gphoto2_module
        The ``gphoto2`` module (default: import python-gphoto2).
    include_serial, include_usb_relays, include_ocean, include_cameras
        Which sources to search.
    timeout_s
        Deadline of each USB control transfer and of camera autodetection.
    """
    devices: list[DiscoveredDevice] = []
    notes: list[str] = []
    if include_serial:
        try:
            devices += _serial_devices((serial_ports or _default_serial_ports)())
        except (OSError, ImportError) as exc:
            notes.append(f"serial ports: could not list them ({exc})")
    usb_problems: dict[str, list[str]] = {}
    if include_usb_relays:
        try:
            relays, skipped = _relay_devices(usb_backend, timeout_s)
            devices += relays
            notes += skipped
        except DeviceError as exc:
            usb_problems.setdefault(exc.message, []).append("HID relay boards")
    if include_ocean:
        try:
            spectrometers, skipped = _ocean_devices(usb_backend)
            devices += spectrometers
            notes += skipped
        except DeviceError as exc:
            usb_problems.setdefault(exc.message, []).append("Ocean spectrometers")
    notes += [f"{' and '.join(sources)}: {problem}" for problem, sources in usb_problems.items()]
    if include_cameras:
        try:
            gp = gphoto2_module if gphoto2_module is not None else load_gphoto2()
            devices += _camera_devices(gp, timeout_s)
        except DeviceError as exc:
            notes.append(f"gphoto2 cameras: {exc.message}")
        except Exception as exc:  # a GPhoto2Error from autodetect: report it, keep the rest
            notes.append(f"gphoto2 cameras: autodetection failed ({exc})")
    return DiscoveryReport(tuple(devices), tuple(notes))


def render_text(report: DiscoveryReport) -> str:
    """The report as text: one section per kind, each device with its snippet, then the notes."""
    titles: dict[DeviceKind, str] = {
        "serial_port": "Serial ports",
        "hid_relay": "HID relay boards",
        "ocean_spectrometer": "Ocean spectrometers (seabreeze)",
        "camera": "Cameras (gphoto2)",
    }
    lines: list[str] = []
    for kind, title in titles.items():
        found = report.of_kind(kind)
        lines.append(f"{title}: {len(found) or 'none found'}")
        for device in found:
            extras = ", ".join(f"{k}={v}" for k, v in device.details.items())
            lines.append(f"  {device.address} — {device.name}" + (f" ({extras})" if extras else ""))
            lines.extend(f"    {line}" for line in device.config_snippet.rstrip().splitlines())
        lines.append("")
    if report.notes:
        lines.append("Notes:")
        lines.extend(f"  - {note}" for note in report.notes)
    return "\n".join(lines).rstrip() + "\n"
