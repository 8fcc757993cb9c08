"""The hardware station: the real drivers for the devices in the configuration.

:func:`open_hardware_station` opens, in this order, the relay board (first, so the runner's first
step can switch every lamp off as early as possible, e.g. after a crash left one on), the
spectroradiometer and the camera, each recording its exchanges in the session's transcript; if any
fails to open, those already open are closed again and the error propagates. Devices that are not
there raise :class:`drivers.base.DeviceNotFound` naming the port, serial number or model that was
asked for and what was found instead.

The clock is the wall clock; frames are measured by the real frame analyser
(:class:`rig.frame_stats.RawFrameAnalyzer`).
"""

from __future__ import annotations

import contextlib
from typing import Any

from drivers.base import Camera, DeviceNotFound, RelayBoard, Spectrometer, TranscriptSink
from drivers.camera import CameraTimeouts, open_camera
from drivers.relays.hid_usbrelay import open_hid_relay
from drivers.relays.lcus import open_lcus
from drivers.relays.numato import open_numato
from drivers.spectrometer import open_spectrometer
from rig.clock import MonotonicClock
from rig.config import (
    CameraConfig,
    Gphoto2CameraConfig,
    HidRelayConfig,
    LcusRelayConfig,
    NumatoRelayConfig,
    RelayConfig,
    RigConfig,
    SerialSpectrometerConfig,
    SpectrometerConfig,
)
from rig.errors import StationUnavailable
from rig.frame_stats import RawFrameAnalyzer
from rig.station import Station, TranscriptFactory

SPECTROMETER_MODELS = {"pr655": "PR-655", "pr670": "PR-670", "cs2000": "CS-2000"}


def _not_hardware(role: str, kind: str) -> StationUnavailable:
    return StationUnavailable(
        f"devices.{role}.kind is {kind!r}; the hardware station opens real devices only "
        "(the twin needs all three devices to be 'twin')"
    )


def open_relays(
    config: RelayConfig, transcript: TranscriptSink, *, usb_backend: Any = None
) -> RelayBoard:
    """Open the configured relay board and check it has the configured number of channels.

    ``usb_backend`` is the pyusb backend for HID boards (default: libusb).
    """
    board: RelayBoard
    match config:
        case HidRelayConfig():
            board = open_hid_relay(
                config.serial,
                backend=usb_backend,
                transcript=transcript,
                timeout_s=config.timeout_s,
            )
            if board.channels != config.channels:
                board.close()
                raise DeviceNotFound(
                    f"HID USBRelay {config.serial or ''}".strip(),
                    f"the board has {board.channels} relays, the configuration says "
                    f"devices.relays.channels = {config.channels}",
                )
            return board
        case LcusRelayConfig() | NumatoRelayConfig():
            opener = open_lcus if isinstance(config, LcusRelayConfig) else open_numato
            return opener(
                config.port,
                config.channels,
                timeout_s=config.timeout_s,
                transcript=transcript,
                baud=config.baud,
            )
    raise _not_hardware("relays", config.kind)


def open_configured_spectrometer(
    config: SpectrometerConfig, transcript: TranscriptSink
) -> Spectrometer:
    """Open the configured spectroradiometer on its serial port."""
    if not isinstance(config, SerialSpectrometerConfig):
        raise _not_hardware("spectrometer", config.kind)
    return open_spectrometer(
        SPECTROMETER_MODELS[config.kind],
        config.port,
        timeout_s=config.timeout_s,
        measure_timeout_s=config.measure_timeout_s,
        transcript=transcript,
        baud=config.baud,
    )


def open_configured_camera(
    config: CameraConfig, transcript: TranscriptSink, *, gphoto2_module: Any = None
) -> Camera:
    """Open the camera libgphoto2 finds by the configured model and/or port.

    ``gphoto2_module`` stands in for python-gphoto2 (default: the real one).
    """
    if not isinstance(config, Gphoto2CameraConfig):
        raise _not_hardware("camera", config.kind)
    return open_camera(
        config.model,
        config.port,
        gphoto2_module=gphoto2_module,
        transcript=transcript,
        timeouts=CameraTimeouts(call_s=config.timeout_s, download_s=config.download_timeout_s),
    )


def open_hardware_station(
    config: RigConfig,
    transcripts: TranscriptFactory,
    *,
    usb_backend: Any = None,
    gphoto2_module: Any = None,
) -> Station:
    """Open the real devices of ``config`` (relays, spectrometer, camera) as a station.

    ``usb_backend`` and ``gphoto2_module`` replace libusb and python-gphoto2 (for tests).

    Raises
    ------
    drivers.base.DeviceNotFound
        A port, board serial or camera is not there (the message says which and what was found).
    drivers.base.DeviceError
        A device is there but does not answer as expected.
    StationUnavailable
        A device is configured as ``twin`` (the twin is all or nothing).
    """
    devices = config.devices
    opened: list[Spectrometer | Camera | RelayBoard] = []
    try:
        relays = open_relays(devices.relays, transcripts("relays"), usb_backend=usb_backend)
        opened.append(relays)
        spectrometer = open_configured_spectrometer(
            devices.spectrometer, transcripts("spectrometer")
        )
        opened.append(spectrometer)
        camera = open_configured_camera(
            devices.camera, transcripts("camera"), gphoto2_module=gphoto2_module
        )
    except BaseException:
        for device in reversed(opened):
            with contextlib.suppress(Exception):
                device.close()
        raise
    return Station(
        spectrometer,
        camera,
        relays,
        MonotonicClock(),
        RawFrameAnalyzer(),
    )
