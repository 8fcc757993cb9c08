"""``drivers.discovery.list_devices``: serial ports, HID relay boards and cameras, with snippets."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest
import usb.core
import yaml

from drivers import discovery
from drivers.base import DeviceNotFound
from drivers.discovery import list_devices, render_text
from mocks.fake_gphoto2 import FakeGphoto2, canon_eos_body, nikon_body
from mocks.usb_relay_backend import EmulatedRelayBoard, FakeUsbBackend


def port(device: str, vid: int | None, pid: int | None, description: str) -> SimpleNamespace:
    return SimpleNamespace(
        device=device,
        vid=vid,
        pid=pid,
        serial_number="A1" if vid else None,
        manufacturer="QinHeng" if vid == 0x1A86 else None,
        product=None,
        description=description,
        hwid="USB VID:PID" if vid else "n/a",
    )


SERIAL_PORTS = [
    port("/dev/ttyUSB0", 0x1A86, 0x7523, "USB Serial"),
    port("/dev/ttyACM1", 0x2A19, 0x0C05, "Numato Lab 1 Channel USB Powered Relay Module"),
    port("/dev/ttyACM0", 0x0483, 0x5740, "PR-655 SpectraScan"),
    port("/dev/ttyS0", None, None, "ttyS0"),
]


def test_everything_found_with_a_snippet_each() -> None:
    board = EmulatedRelayBoard("LAMPS", 4, address=7)
    board.state_mask = 0b0101
    report = list_devices(
        serial_ports=lambda: SERIAL_PORTS,
        usb_backend=FakeUsbBackend([board]),
        gphoto2_module=FakeGphoto2([canon_eos_body(), nikon_body()]),
    )
    assert report.notes == ()
    serial = {d.address: d for d in report.of_kind("serial_port")}
    assert list(serial) == ["/dev/ttyACM0", "/dev/ttyACM1", "/dev/ttyS0", "/dev/ttyUSB0"]
    assert yaml.safe_load(serial["/dev/ttyUSB0"].config_snippet) == {
        "kind": "lcus",
        "port": "/dev/ttyUSB0",
    }
    assert serial["/dev/ttyUSB0"].details["vendor_id"] == "0x1a86"
    assert serial["/dev/ttyUSB0"].details["product_id"] == "0x7523"
    assert yaml.safe_load(serial["/dev/ttyACM1"].config_snippet)["kind"] == "numato"
    # No known id: the snippet says which kinds to choose from.
    assert "(pr655, pr670, cs2000, lcus, numato)" in serial["/dev/ttyACM0"].config_snippet
    assert "hwid" not in serial["/dev/ttyS0"].details
    (relay,) = report.of_kind("hid_relay")
    assert relay.address == "LAMPS" and relay.details["relays_on"] == "1,3"
    assert yaml.safe_load(relay.config_snippet) == {"kind": "hid_usbrelay", "serial": "LAMPS"}
    cameras = report.of_kind("camera")
    assert [yaml.safe_load(c.config_snippet) for c in cameras] == [
        {"kind": "gphoto2", "model": "Canon EOS 5D Mark III", "port": "usb:001,004"},
        {"kind": "gphoto2", "model": "Nikon DSC D750", "port": "usb:001,005"},
    ]
    text = render_text(report)
    assert "Serial ports: 4" in text and "HID relay boards: 1" in text
    assert "Cameras (gphoto2): 2" in text and "kind: hid_usbrelay" in text


def test_no_usb_backend_is_a_note_not_a_failure(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_backend(**kwargs: object) -> None:
        raise usb.core.NoBackendError("No backend available")

    monkeypatch.setattr(usb.core, "find", no_backend)
    report = list_devices(serial_ports=list, gphoto2_module=FakeGphoto2([canon_eos_body()]))
    assert len(report.of_kind("camera")) == 1
    assert report.notes == (
        "HID relay boards and Ocean spectrometers: no USB backend available (libusb-1.0 not found): install it "
        "(apt install libusb-1.0-0, brew install libusb) or `pip install libusb-package`",
    )
    assert "Notes:" in render_text(report)


def test_other_vusb_gadgets_are_noted(monkeypatch: pytest.MonkeyPatch) -> None:
    gadget = EmulatedRelayBoard("KEYS0", 2, manufacturer="obdev.at", product="HIDKeys")
    report = list_devices(
        serial_ports=list,
        usb_backend=FakeUsbBackend([gadget]),
        include_cameras=False,
    )
    assert report.devices == ()
    assert "obdev.at" in report.notes[0]


def test_missing_gphoto2_and_failing_sources(monkeypatch: pytest.MonkeyPatch) -> None:
    def missing() -> None:
        raise DeviceNotFound("gphoto2", "python-gphoto2 is not importable (no module)")

    def broken_ports() -> list[object]:
        raise OSError("sysfs unreadable")

    monkeypatch.setattr(discovery, "load_gphoto2", missing)
    report = list_devices(serial_ports=broken_ports, usb_backend=FakeUsbBackend([]))
    assert report.devices == ()
    assert report.notes == (
        "serial ports: could not list them (sysfs unreadable)",
        "gphoto2 cameras: python-gphoto2 is not importable (no module)",
    )
    assert "none found" in render_text(report)


def test_camera_autodetection_that_fails_or_hangs() -> None:
    gp = FakeGphoto2([canon_eos_body()])

    def failing() -> None:
        raise gp.GPhoto2Error(-7)

    gp.Camera.autodetect = staticmethod(failing)  # type: ignore[method-assign,assignment]
    report = list_devices(
        include_serial=False, include_usb_relays=False, include_ocean=False, gphoto2_module=gp
    )
    assert report.notes == ("gphoto2 cameras: autodetection failed ([-7] I/O problem)",)

    release = threading.Event()
    gp.Camera.autodetect = staticmethod(lambda: release.wait(10))  # type: ignore[method-assign,assignment]
    try:
        report = list_devices(
            include_serial=False,
            include_usb_relays=False,
            include_ocean=False,
            gphoto2_module=gp,
            timeout_s=0.1,
        )
    finally:
        release.set()
    assert report.notes == ("gphoto2 cameras: camera autodetection did not return within 0.1 s",)


def test_ocean_spectrometers_on_the_bus_with_a_snippet_each() -> None:
    from mocks.ocean_backend import STS, USB2000PLUS, EmulatedOcean, OceanBackend

    dark = lambda wavelength: wavelength * 0.0  # noqa: E731
    bus = OceanBackend(
        [EmulatedOcean(USB2000PLUS, dark, address=9), EmulatedOcean(STS, dark, address=12)]
    )
    report = list_devices(serial_ports=list, usb_backend=bus, include_cameras=False)
    assert report.notes == ()
    found = {d.address: d for d in report.of_kind("ocean_spectrometer")}
    assert set(found) == {USB2000PLUS.serial, STS.serial}
    usb2000 = found[USB2000PLUS.serial]
    assert usb2000.name == "Ocean USB2000PLUS" and usb2000.details["port"] == "usb:001,009"
    assert yaml.safe_load(usb2000.config_snippet) == {
        "kind": "seabreeze",
        "serial": USB2000PLUS.serial,
        "calibration_file": f"calibration-{USB2000PLUS.serial}.csv",
    }
    assert "rig calibrate-spectrometer" in usb2000.config_snippet
    assert "Ocean spectrometers (seabreeze): 2" in render_text(report)
    # Found means opened and closed again: the rig can open it right after.
    assert all(device.configured for device in bus.devices)


def test_a_missing_seabreeze_is_a_note(monkeypatch: pytest.MonkeyPatch) -> None:
    from drivers import libraries

    def missing() -> None:
        raise libraries.HardwareLibraryMissing(
            "python-seabreeze", "seabreeze", ImportError("No module named 'seabreeze'")
        )

    monkeypatch.setattr(discovery, "find_ocean_spectrometers", lambda **_: missing())
    report = list_devices(serial_ports=list, include_usb_relays=False, include_cameras=False)
    (note,) = report.notes
    assert note.startswith("Ocean spectrometers: seabreeze is not installed")
    assert "spectral-rig[rig]" in note
