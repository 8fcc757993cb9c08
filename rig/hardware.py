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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from calib.core.errors import SpectrumError
from calib.core.spectra import read_spectrum_csv, read_table
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
from drivers.spectrometer.argyll import ArgyllSettings, open_argyll
from drivers.spectrometer.files import SwitchedRelays
from drivers.spectrometer.ocean import IrradianceCalibration, OceanSettings, open_ocean
from rig.clock import MonotonicClock
from rig.config import (
    ArgyllSpectrometerConfig,
    CameraConfig,
    FilesSpectrometerConfig,
    Gphoto2CameraConfig,
    HidRelayConfig,
    LampConfig,
    LcusRelayConfig,
    NumatoRelayConfig,
    RelayConfig,
    RigConfig,
    SeabreezeSpectrometerConfig,
    SerialSpectrometerConfig,
    SpectrometerConfig,
)
from rig.errors import StationOpenFailed, StationUnavailable
from rig.frame_stats import RawFrameAnalyzer
from rig.runner import StepTimeouts, switch_off_now
from rig.spectrum_files import open_spectrum_files
from rig.station_devices import Station, TranscriptFactory

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


def load_irradiance_calibration(path: Path) -> IrradianceCalibration:
    """An Ocean spectrometer's relative irradiance calibration from a CSV file (``wavelength_nm``,
    ``factor``; a two-column file without a header is read as those).

    Raises
    ------
    calib.errors.SpectrumError
        The file is missing, unreadable, or its values are not a calibration (names the file).
    """
    table = read_table(path)
    column = "factor" if "factor" in table.columns else None
    spectrum = read_spectrum_csv(path, column=column)
    try:
        return IrradianceCalibration(spectrum.wavelength_nm, spectrum.values, source=str(path))
    except ValueError as exc:
        raise SpectrumError(str(exc), source=str(path)) from None


def ocean_settings(
    config: SeabreezeSpectrometerConfig, calibration: IrradianceCalibration | None
) -> OceanSettings:
    """The Ocean driver's settings from the configuration."""
    return OceanSettings(
        integration_range_ms=(config.integration_min_ms, config.integration_max_ms),
        averages=config.averages,
        electric_dark=config.electric_dark,
        nonlinearity=config.nonlinearity,
        calibration=calibration,
        allow_uncalibrated=config.allow_uncalibrated,
        bandwidth_nm=config.bandwidth_nm,
        timeout_ms=round(config.timeout_s * 1000),
    )


def watched_relays(config: RigConfig, relays: RelayBoard) -> RelayBoard:
    """The relay board as the station hands it to the runner: watched when the spectrometer is
    measured files (they stand for whichever lamp the rig switched on)."""
    if isinstance(config.devices.spectrometer, FilesSpectrometerConfig):
        return SwitchedRelays(relays)
    return relays


def open_configured_spectrometer(
    config: SpectrometerConfig,
    transcript: TranscriptSink,
    *,
    usb_backend: Any = None,
    relays: RelayBoard | None = None,
    lamps: Sequence[LampConfig] = (),
) -> Spectrometer:
    """Open the configured spectrometer: on its serial port, on USB (Ocean), through spotread, or
    measured files.

    ``usb_backend`` is the pyusb backend for an Ocean spectrometer (default: libusb); ``relays``
    (from :func:`watched_relays`) and ``lamps`` are what a files device watches.
    """
    if isinstance(config, FilesSpectrometerConfig):
        if not isinstance(relays, SwitchedRelays):
            raise StationUnavailable("a files spectrometer needs the relays from watched_relays()")
        return open_spectrum_files(config, list(lamps), relays, transcript)[0]
    if isinstance(config, SeabreezeSpectrometerConfig):
        calibration = (
            None
            if config.calibration_file is None
            else load_irradiance_calibration(config.calibration_file)
        )
        return open_ocean(
            config.serial,
            ocean_settings(config, calibration),
            backend=usb_backend,
            transcript=transcript,
        )
    if isinstance(config, ArgyllSpectrometerConfig):
        return open_argyll(
            ArgyllSettings(
                executable=config.executable,
                instrument=config.instrument,
                high_resolution=config.high_resolution,
                timeout_s=config.timeout_s,
                bandwidth_nm=config.bandwidth_nm,
            ),
            transcript=transcript,
        )
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
        if relays is not None:
            relays = watched_relays(config, relays)
        spectrometer = attempt(
            "spectrometer",
            lambda: open_configured_spectrometer(
                devices.spectrometer,
                transcripts("spectrometer"),
                usb_backend=usb_backend,
                relays=relays,
                lamps=config.lamps,
            ),
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
