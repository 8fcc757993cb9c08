"""Ready-made fake bodies with realistic widget sets (names and choices from libgphoto2's
``camlibs/ptp2/config.c`` as of 2.5.34)."""

from __future__ import annotations

from mocks.fake_gphoto2.body import FakeBody, FrameSource, StorageLayout
from mocks.fake_gphoto2.constants import (
    GP_WIDGET_DATE,
    GP_WIDGET_RADIO,
    GP_WIDGET_TEXT,
    GP_WIDGET_TOGGLE,
)
from mocks.fake_gphoto2.widgets import WidgetSpec
from mocks.lamps import Clock

__all__ = ["canon_eos_body", "minimal_body", "nikon_body"]

CANON_SHUTTER_CHOICES = (
    "bulb", "30", "25", "20", "15", "13", "10", "8", "6", "5", "4", "3.2", "2.5", "2", "1.6",
    "1.3", "1", "0.8", "0.6", "0.5", "0.4", "0.3", "1/4", "1/5", "1/6", "1/8", "1/10", "1/13",
    "1/15", "1/20", "1/25", "1/30", "1/40", "1/50", "1/60", "1/80", "1/100", "1/125", "1/160",
    "1/200", "1/250", "1/320", "1/400", "1/500", "1/640", "1/800", "1/1000", "1/1250", "1/1600",
    "1/2000", "1/2500", "1/3200", "1/4000", "1/5000", "1/6400", "1/8000",
)  # fmt: skip
"""Canon EOS third-stop shutter table, 30 s … 1/8000 s plus bulb."""
CANON_ISO_CHOICES = (
    "Auto", "100", "125", "160", "200", "250", "320", "400", "500", "640", "800", "1000", "1250",
    "1600", "2000", "2500", "3200", "4000", "5000", "6400", "8000", "10000", "12800", "16000",
    "20000", "25600",
)  # fmt: skip
CANON_APERTURE_CHOICES = (
    "2.8", "3.2", "3.5", "4", "4.5", "5", "5.6", "6.3", "7.1", "8", "9", "10", "11", "13", "14",
    "16", "18", "20", "22",
)  # fmt: skip
CANON_IMAGEFORMAT_CHOICES = (
    "Large Fine JPEG", "Large Normal JPEG", "Medium Fine JPEG", "Medium Normal JPEG",
    "Small Fine JPEG", "Small Normal JPEG", "RAW + Large Fine JPEG", "mRAW", "sRAW", "RAW",
)  # fmt: skip
CANON_WHITEBALANCE_CHOICES = (
    "Auto", "AWB White", "Daylight", "Shadow", "Cloudy", "Tungsten", "Fluorescent", "Flash",
    "Manual", "Color Temperature",
)  # fmt: skip
EOS_REMOTE_RELEASE_CHOICES = (
    "None", "Press Half AF", "Press Full AF", "Press Half MF", "Press Full MF", "Release Half",
    "Release Full", "Release",
)  # fmt: skip
"""libgphoto2 2.5.34 names (they changed from ``Press Full`` … in 2.5.33)."""

NIKON_SHUTTER_CHOICES = (
    "0.0001s", "0.0002s", "0.0003s", "0.0004s", "0.0005s", "0.0006s", "0.0008s", "0.0010s",
    "0.0012s", "0.0015s", "0.0020s", "0.0025s", "0.0031s", "0.0040s", "0.0050s", "0.0062s",
    "0.0080s", "0.0100s", "0.0125s", "0.0166s", "0.0200s", "0.0250s", "0.0333s", "0.0400s",
    "0.0500s", "0.0666s", "0.0769s", "0.1000s", "0.1250s", "0.1666s", "0.2000s", "0.2500s",
    "0.3333s", "0.4000s", "0.5000s", "0.6250s", "0.7692s", "1.0000s", "1.3000s", "1.6000s",
    "2.0000s", "2.5000s", "3.0000s", "4.0000s", "5.0000s", "6.0000s", "8.0000s", "10.0000s",
    "13.0000s", "15.0000s", "20.0000s", "25.0000s", "30.0000s", "Bulb", "Time",
)  # fmt: skip
"""Generic PTP ExposureTime strings as libgphoto2 shows them for Nikon, with Bulb and Time."""
NIKON_IMAGEQUALITY_CHOICES = (
    "JPEG Basic", "JPEG Normal", "JPEG Fine", "NEF (Raw)", "NEF+Basic", "NEF+Normal", "NEF+Fine",
)  # fmt: skip
NIKON_FNUMBER_CHOICES = (
    "f/1.8", "f/2", "f/2.2", "f/2.5", "f/2.8", "f/3.2", "f/3.5", "f/4", "f/4.5", "f/5", "f/5.6",
    "f/6.3", "f/7.1", "f/8", "f/9", "f/10", "f/11", "f/13", "f/14", "f/16", "f/18", "f/20", "f/22",
)  # fmt: skip


def _radio(name: str, label: str, section: str, value: str, choices: tuple[str, ...]) -> WidgetSpec:
    return WidgetSpec(name, label, GP_WIDGET_RADIO, section, value, choices)


def _status(name: str, label: str, value: str) -> WidgetSpec:
    return WidgetSpec(name, label, GP_WIDGET_TEXT, "status", value, read_only=True)


def canon_eos_body(
    *,
    port: str = "usb:001,004",
    model: str = "Canon EOS 5D Mark III",
    serial: str = "082024001234",
    bulb_toggle: bool = True,
    frame_source: FrameSource | None = None,
    clock: Clock | None = None,
) -> FakeBody:
    """A Canon EOS body: ``shutterspeed`` 30…1/8000 + bulb, ``aperture``, ``iso``, ``imageformat``
    with RAW, ``whitebalance``, ``capturetarget``, ``bulb`` toggle (optional) and
    ``eosremoterelease``."""
    widgets = [
        WidgetSpec("datetime", "Camera Date and Time", GP_WIDGET_DATE, "settings", 1_763_700_000),
        _radio("capturetarget", "Capture Target", "settings", "Internal RAM",
               ("Internal RAM", "Memory card")),
        _status("serialnumber", "Serial Number", serial),
        _status("manufacturer", "Camera Manufacturer", "Canon Inc."),
        _status("cameramodel", "Camera Model", model),
        _status("deviceversion", "Device Version", "3-1.3.7"),
        _status("batterylevel", "Battery Level", "100%"),
        _radio("imageformat", "Image Format", "imgsettings", "Large Fine JPEG",
               CANON_IMAGEFORMAT_CHOICES),
        _radio("iso", "ISO Speed", "imgsettings", "Auto", CANON_ISO_CHOICES),
        _radio("whitebalance", "WhiteBalance", "imgsettings", "Auto", CANON_WHITEBALANCE_CHOICES),
        _radio("shutterspeed", "Shutter Speed", "capturesettings", "1/125", CANON_SHUTTER_CHOICES),
        _radio("aperture", "Aperture", "capturesettings", "5.6", CANON_APERTURE_CHOICES),
        _status("autoexposuremode", "Canon Auto Exposure Mode", "Manual"),
        _radio("eosremoterelease", "Canon EOS Remote Release", "actions", "None",
               EOS_REMOTE_RELEASE_CHOICES),
    ]  # fmt: skip
    if bulb_toggle:
        widgets.append(WidgetSpec("bulb", "Bulb Mode", GP_WIDGET_TOGGLE, "actions", 0))
    return FakeBody(
        model,
        port,
        widgets,
        layout=StorageLayout(card_folder="/store_00020001/DCIM/100CANON", raw_extension=".CR2"),
        frame_source=frame_source,
        clock=clock,
        reset_on_init=("capturetarget",),
    )


def nikon_body(
    *,
    port: str = "usb:001,005",
    model: str = "Nikon DSC D750",
    frame_source: FrameSource | None = None,
    clock: Clock | None = None,
) -> FakeBody:
    """A Nikon body: generic-PTP ``shutterspeed`` strings (``0.0100s`` … ``30.0000s``, ``Bulb``,
    ``Time``), ``f-number``, ``iso``, ``imagequality`` with ``NEF (Raw)``, ``bulb`` toggle."""
    widgets = [
        _radio("capturetarget", "Capture Target", "settings", "Internal RAM",
               ("Internal RAM", "Memory card")),
        _status("serialnumber", "Serial Number", "3012345"),
        _status("manufacturer", "Camera Manufacturer", "Nikon Corporation"),
        _status("deviceversion", "Device Version", "V1.10"),
        _radio("imagequality", "Image Quality", "imgsettings", "JPEG Fine",
               NIKON_IMAGEQUALITY_CHOICES),
        _radio("iso", "ISO Speed", "imgsettings", "100",
               ("100", "200", "400", "800", "1600", "3200", "6400", "12800")),
        _radio("whitebalance", "WhiteBalance", "imgsettings", "Automatic",
               ("Automatic", "Daylight", "Fluorescent", "Tungsten", "Flash", "Cloudy", "Shade")),
        _radio("shutterspeed", "Shutter Speed", "capturesettings", "0.0080s",
               NIKON_SHUTTER_CHOICES),
        _radio("f-number", "F-Number", "capturesettings", "f/5.6", NIKON_FNUMBER_CHOICES),
        WidgetSpec("bulb", "Bulb Mode", GP_WIDGET_TOGGLE, "actions", 0),
    ]  # fmt: skip
    return FakeBody(
        model,
        port,
        widgets,
        layout=StorageLayout(
            card_folder="/store_00010001/DCIM/100D750",
            card_name="DSC_{index:04d}",
            raw_extension=".NEF",
        ),
        frame_source=frame_source,
        clock=clock,
    )


def minimal_body(
    *,
    port: str = "usb:002,003",
    model: str = "GP VC",
    frame_source: FrameSource | None = None,
    clock: Clock | None = None,
) -> FakeBody:
    """A body like the wheel's virtual camera: few shutter speeds, ``f-number``, no ISO, white
    balance, image format, bulb or serial number; JPEG only."""
    widgets = [
        _radio("capturetarget", "Capture Target", "settings", "Internal RAM",
               ("Internal RAM", "Memory card")),
        _radio("shutterspeed", "Shutter Speed", "capturesettings", "0.0100s",
               ("1.0000s", "0.1000s", "0.0500s", "0.0200s", "0.0100s", "0.0050s", "0.0025s")),
        _radio("f-number", "F-Number", "capturesettings", "f/2.8",
               ("f/2.8", "f/4", "f/5.6", "f/8", "f/11")),
    ]  # fmt: skip
    return FakeBody(
        model,
        port,
        widgets,
        layout=StorageLayout(
            card_folder="/store_00010001/DCIM/100GPHOT",
            card_name="GPH_{index:04d}",
            raw_extension=".DNG",
        ),
        frame_source=frame_source,
        clock=clock,
    )
