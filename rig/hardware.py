"""The hardware station: the real drivers for the devices in the configuration.

:func:`open_hardware_station` opens, in this order, the relay board (first, so the runner's first
step can switch every lamp off as early as possible, e.g. after a crash left one on), the
spectroradiometer and the camera, each recording its exchanges in the session's transcript. Every
device is tried even after one failed; if any failed, the board switches every lamp off, the
opened devices are closed again and :class:`rig.errors.StationOpenFailed` names every failure. Devices that are not
there raise :class:`drivers.base.DeviceNotFound` naming the port, serial number or model that was
asked for and what was found instead.

The clock is the wall clock; frames are measured by the real frame analyser
(:class:`rig.frame_stats.RawFrameAnalyzer`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any, TypeVar

from drivers.base import (
    Camera,
    DeviceError,
    DeviceNotFound,
    RelayBoard,
    Spectrometer,
    TranscriptSink,
)
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
from rig.errors import StationOpenFailed, StationUnavailable
from rig.frame_stats import RawFrameAnalyzer
from rig.runner import StepTimeouts, switch_off_now
from rig.station import Station, TranscriptFactory

DeviceT = TypeVar("DeviceT", Spectrometer, Camera, RelayBoard)
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

    Every device is tried, even after one failed, so a single attempt names every problem. When any
    fails, the relay board (if it opened) switches every lamp off and is read back, and every device
    that opened is closed again.

    ``usb_backend`` and ``gphoto2_module`` replace libusb and python-gphoto2 (for tests).

    Raises
    ------
    rig.errors.StationOpenFailed
        One or more devices are not there or do not answer: each failure (a
        :class:`drivers.base.DeviceNotFound` naming the port, serial or model asked for and what was
        found, or another device error) by role, and whether the lamps are confirmed off.
    StationUnavailable
        A device is configured as ``twin`` (the twin is all or nothing).
    """
    devices = config.devices
    failures: dict[str, DeviceError] = {}
    opened: list[Spectrometer | Camera | RelayBoard] = []

    def attempt(role: str, open_device: Callable[[], DeviceT]) -> DeviceT | None:
        try:
            device = open_device()
        except DeviceError as exc:
            failures[role] = exc
            return None
        opened.append(device)
        return device

    try:
        relays = attempt(
            "relays",
            lambda: open_relays(devices.relays, transcripts("relays"), usb_backend=usb_backend),
        )
        spectrometer = attempt(
            "spectrometer",
            lambda: open_configured_spectrometer(devices.spectrometer, transcripts("spectrometer")),
        )
        camera = attempt(
            "camera",
            lambda: open_configured_camera(
                devices.camera, transcripts("camera"), gphoto2_module=gphoto2_module
            ),
        )
    except BaseException:
        _close_all(opened)
        raise
    if relays is None or spectrometer is None or camera is None:
        timeout_s = StepTimeouts.from_config(config).relays_s
        lamps_off = relays is not None and switch_off_now(relays, timeout_s)
        _close_all(opened)
        raise StationOpenFailed(failures, lamps_off=lamps_off)
    return Station(spectrometer, camera, relays, MonotonicClock(), RawFrameAnalyzer())


def _close_all(opened: list[Spectrometer | Camera | RelayBoard]) -> None:
    for device in reversed(opened):
        with contextlib.suppress(Exception):
            device.close()
