"""Open the real drivers on the replay stand-ins, one device per recorded transcript.

The rig hands over plain data (:class:`RecordedDevice`: the identity recorded in the session's
start record, the decoded transcript, the configured timeouts) and gets back the opened drivers.
Which driver runs is read from the recorded identity (``PR-655`` → the PR-6xx driver, ``dcttech
USBRelay2`` → the HID relay driver …), and each is opened as its ``open_*`` function opens it, with
the recorded port as its name, so identities and labels come out as recorded.
"""

from __future__ import annotations

import contextlib
import json
import re
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from calib.core.spectra import read_spectrum_csv
from drivers.base import (
    Camera,
    RelayBoard,
    Spectrometer,
    SpectrumReading,
    TranscriptEntry,
    TranscriptSink,
)
from drivers.camera import CameraTimeouts, open_camera
from drivers.lifecycle import connect_or_close
from drivers.relays.hid_usbrelay import open_hid_relay
from drivers.relays.lcus import LcusRelayBoard
from drivers.relays.numato import NumatoRelayBoard
from drivers.spectrometer.argyll import ArgyllSettings, open_argyll
from drivers.spectrometer.cs2000 import Cs2000
from drivers.spectrometer.files import (
    FilesSpectrometer,
    LampFile,
    SwitchedRelays,
    reading_from_json,
)
from drivers.spectrometer.ocean import IrradianceCalibration, OceanSettings, open_ocean
from drivers.spectrometer.pr6xx import MODELS as PR6XX_MODELS
from drivers.spectrometer.pr6xx import Pr6xx
from drivers.transport import SerialTransport
from mocks.bench.station import twin_ocean_settings
from mocks.lamps import SimulatedClock
from mocks.ocean_backend import OCEAN_MODELS
from mocks.replay.gphoto2 import FrameSource, ReplayGphoto2, ReplayUnsupported
from mocks.replay.script import CheckingSink, Mismatches, ReplayMismatch, ReplayScript
from mocks.replay.serial_port import ReplaySerialPort
from mocks.replay.spotread import ReplaySpotreadLauncher
from mocks.replay.usb_backend import ReplayOceanBackend, ReplayUsbBackend

__all__ = [
    "RecordedDevice",
    "RecordingServer",
    "ReplayBench",
    "ReplayUnsupported",
    "open_replay",
]

TranscriptFactory = Callable[[str], TranscriptSink]
_CHANNELS = re.compile(r"(\d+)")


@dataclass(frozen=True)
class RecordedDevice:
    """One device of a recorded session.

    Attributes
    ----------
    identity
        The ``devices.<role>`` fields of the start record (``kind``, ``model``, ``port`` …).
    entries
        Its decoded transcript.
    timeout_s
        The configured per-exchange deadline (``devices.<role>.timeout_s``).
    download_timeout_s
        The camera's download deadline.
    measure_timeout_s
        The spectrometer's measurement allowance (``devices.spectrometer.measure_timeout_s``;
        ``None``: the model's default).
    """

    identity: Mapping[str, Any]
    entries: Sequence[TranscriptEntry]
    timeout_s: float
    download_timeout_s: float = 120.0
    measure_timeout_s: float | None = None


@dataclass(eq=False)
class ReplayBench:
    """The opened drivers, the scripts they consume, and the simulated clock of the run."""

    relays: RelayBoard
    spectrometer: Spectrometer
    camera: Camera
    clock: SimulatedClock
    scripts: dict[str, ReplayScript]
    mismatches: Mismatches
    closers: list[Callable[[], object]] = field(default_factory=list)

    def close(self) -> None:
        """Close what is still open (the runner closes the drivers itself)."""
        for closer in reversed(self.closers):
            with contextlib.suppress(Exception):
                closer()

    def finish(self) -> None:
        """After the run: note, as mismatches, every recorded entry left unused."""
        for script in self.scripts.values():
            script.finish()


def _channels(model: str) -> int:
    found = _CHANNELS.search(model)
    if found is None:
        raise ReplayUnsupported(f"cannot tell the relay count from the recorded model {model!r}")
    return int(found.group(1))


def _serial_transport(
    script: ReplayScript, sink: TranscriptSink, label: str, port: str, released: threading.Event
) -> SerialTransport:
    transport = SerialTransport(
        ReplaySerialPort(script, port, released),
        device=label,
        transcript=CheckingSink(script, sink),
    )
    transport.record_event(f"opened {port} (replay)")
    return transport


def _open_relays(
    device: RecordedDevice, script: ReplayScript, sink: TranscriptSink, released: threading.Event
) -> RelayBoard:
    model = str(device.identity.get("model", ""))
    port = str(device.identity.get("port") or "")
    extra = device.identity.get("extra") or {}
    if model.startswith("dcttech USBRelay"):
        recipient = extra.get("request_recipient", "device")
        if recipient not in ("device", "interface"):
            raise ReplayUnsupported(f"unknown HID request recipient {recipient!r}")
        return open_hid_relay(
            device.identity.get("serial"),
            backend=ReplayUsbBackend(script, port),
            transcript=CheckingSink(script, sink),
            timeout_s=device.timeout_s,
            recipient=recipient,
        )
    channels = _channels(model)
    if model.startswith("LCUS-"):
        transport = _serial_transport(
            script, sink, f"LCUS-{channels} relay board on {port}", port, released
        )
        lcus = LcusRelayBoard(transport, channels, timeout_s=device.timeout_s, port=port)
        return connect_or_close(lcus, lcus.state)
    if model.startswith("Numato "):
        transport = _serial_transport(
            script, sink, f"Numato {channels}-relay module on {port}", port, released
        )
        numato = NumatoRelayBoard(transport, channels, timeout_s=device.timeout_s, port=port)

        def connect() -> None:
            numato.resync()
            numato.identify()
            numato.state()

        return connect_or_close(numato, connect)
    raise ReplayUnsupported(f"no replay for the relay board {model!r}")


def _ocean_settings(device: RecordedDevice) -> OceanSettings:
    """The Ocean driver's settings as the recorded identity says the run used them."""
    extra = device.identity.get("extra") or {}
    model = str(device.identity.get("model", ""))
    source = str(extra.get("calibration", ""))
    timeout_s = int(extra.get("timeout_ms", 5000)) / 1000.0
    if source == f"twin {model}":
        return twin_ocean_settings(model, timeout_s)
    ladder = [float(v) for v in str(extra.get("integration_ladder_ms", "")).split(",") if v]
    if len(ladder) < 2:
        raise ReplayUnsupported(f"the recorded {model} names no integration ladder")
    calibration = None
    if extra.get("calibration_sha256"):
        table = read_spectrum_csv(source, column="factor")
        calibration = IrradianceCalibration(table.wavelength_nm, table.values, source=source)
        if calibration.sha256 != extra["calibration_sha256"]:
            raise ReplayUnsupported(
                f"the calibration file {source} changed since the session was recorded"
            )
    bandwidth = extra.get("bandwidth_nm")
    return OceanSettings(
        integration_range_ms=(ladder[0], ladder[-1]),
        averages=int(extra.get("averages", 1)),
        electric_dark="on" if extra.get("electric_dark") == "on" else "off",
        nonlinearity="on" if extra.get("nonlinearity") == "on" else "off",
        calibration=calibration,
        allow_uncalibrated=calibration is None,
        bandwidth_nm=None if bandwidth is None else float(bandwidth),
        timeout_ms=round(timeout_s * 1000),
    )


def _open_files(
    device: RecordedDevice, script: ReplayScript, sink: TranscriptSink, relays: SwitchedRelays
) -> FilesSpectrometer:
    """The files device as recorded: its reads at open are served from the transcript."""
    extra = device.identity.get("extra") or {}
    directory = Path(str(device.identity.get("port") or "."))
    try:
        listed = json.loads(str(extra.get("lamps")))
        lamps = [
            LampFile(name, int(item["channel"]), directory / str(item["file"]))
            for name, item in listed.items()
        ]
        digests = {name: str(item["sha256"]) for name, item in listed.items()}
    except (ValueError, KeyError, TypeError, AttributeError):
        raise ReplayUnsupported("the recorded spectrum files are not listed readably") from None

    def served(path: Path) -> SpectrumReading:
        answer = script.take(f"the spectrum of {path.name}")
        if answer.entry.direction == "error":
            raise ValueError(json.loads(answer.entry.payload).get("error", "unreadable"))
        return reading_from_json(json.loads(answer.entry.payload))

    return FilesSpectrometer(
        directory, lamps, served, relays, CheckingSink(script, sink), digests=digests
    )


def _open_spectrometer(
    device: RecordedDevice,
    script: ReplayScript,
    sink: TranscriptSink,
    released: threading.Event,
    relays: RelayBoard,
) -> Spectrometer:
    model = str(device.identity.get("model", ""))
    port = str(device.identity.get("port") or "")
    extra = device.identity.get("extra") or {}
    if extra.get("driver") == "files":
        if not isinstance(relays, SwitchedRelays):
            raise ReplayUnsupported("a files spectrometer needs the switched relays")
        return _open_files(device, script, sink, relays)
    if extra.get("driver") == "seabreeze":
        if model not in OCEAN_MODELS:
            raise ReplayUnsupported(f"no replay for the Ocean spectrometer {model!r}")
        return open_ocean(
            device.identity.get("serial"),
            _ocean_settings(device),
            backend=ReplayOceanBackend(script, model, port),
            transcript=CheckingSink(script, sink),
        )
    if extra.get("driver") == "argyll":
        return open_argyll(
            ArgyllSettings(
                executable=str(extra.get("executable", "spotread")),
                instrument=int(extra.get("instrument", 1)),
                high_resolution=extra.get("high_resolution") == "on",
                timeout_s=float(extra.get("timeout_s", device.timeout_s)),
                bandwidth_nm=float(extra["bandwidth_nm"]) if "bandwidth_nm" in extra else None,
            ),
            launcher=ReplaySpotreadLauncher(script),
            transcript=CheckingSink(script, sink),
            resolve=False,
        )
    transport = _serial_transport(script, sink, f"{model} on {port}", port, released)
    instrument: Pr6xx | Cs2000
    if model in PR6XX_MODELS:
        instrument = Pr6xx(
            transport,
            model=model,
            timeout_s=device.timeout_s,
            measure_timeout_s=device.measure_timeout_s,
            port=port,
        )
    elif model.startswith("CS-2000"):
        instrument = Cs2000(
            transport,
            model=model,
            timeout_s=device.timeout_s,
            completion_margin_s=device.measure_timeout_s,
            port=port,
        )
    else:
        raise ReplayUnsupported(f"no replay for the spectrometer {model!r}")
    return connect_or_close(instrument, instrument.connect)


def open_replay(
    devices: Mapping[str, RecordedDevice],
    transcripts: TranscriptFactory,
    frames: FrameSource,
) -> ReplayBench:
    """Open the relays, the spectrometer and the camera of a recording on their stand-ins.

    Parameters
    ----------
    devices
        ``relays``, ``spectrometer`` and ``camera``.
    transcripts
        The new session's transcript sink per role (everything the replay exchanges is written).
    frames
        Serves the recorded frames to the camera's downloads.

    Raises
    ------
    ReplayUnsupported
        A recorded device has no replay.
    mocks.replay.script.ReplayMismatch
        Opening a driver already sends something the recording did not.
    """
    mismatches = Mismatches()
    scripts = {
        role: ReplayScript(role, device.entries, mismatches) for role, device in devices.items()
    }
    clock = SimulatedClock()
    released = threading.Event()
    opened: list[Callable[[], object]] = [released.set]
    try:
        relays = _open_relays(devices["relays"], scripts["relays"], transcripts("relays"), released)
        opened.append(relays.close)
        spectrometer_extra = devices["spectrometer"].identity.get("extra") or {}
        if spectrometer_extra.get("driver") == "files":
            relays = SwitchedRelays(relays)
        spectrometer = _open_spectrometer(
            devices["spectrometer"],
            scripts["spectrometer"],
            transcripts("spectrometer"),
            released,
            relays,
        )
        opened.append(spectrometer.close)
        camera_device = devices["camera"]
        extra = camera_device.identity.get("extra") or {}
        camera = open_camera(
            str(camera_device.identity.get("model", "")) or None,
            str(camera_device.identity.get("port") or "") or None,
            gphoto2_module=ReplayGphoto2(
                scripts["camera"], frames, str(extra.get("libgphoto2", "unknown"))
            ),
            transcript=CheckingSink(scripts["camera"], transcripts("camera")),
            timeouts=CameraTimeouts(
                call_s=camera_device.timeout_s, download_s=camera_device.download_timeout_s
            ),
            exposure_timer=clock,
        )
    except BaseException:
        for closer in reversed(opened):
            with contextlib.suppress(Exception):
                closer()
        raise
    return ReplayBench(
        relays, spectrometer, camera, clock, scripts, mismatches, closers=[released.set]
    )


class RecordingServer:
    """This package as ``rig replay``'s backend: the ``spectral_rig.replay`` entry point.

    The rig reaches it only through that entry point and its typed protocol
    (:class:`rig.replay.ReplayBackend`), never by importing ``mocks``.
    """

    def open_recording(
        self,
        devices: Mapping[str, Mapping[str, Any]],
        transcripts: TranscriptFactory,
        frames: FrameSource,
    ) -> ReplayBench:
        """:func:`open_replay` of plain data: per role, the :class:`RecordedDevice` fields."""
        return open_replay(
            {role: RecordedDevice(**fields) for role, fields in devices.items()},
            transcripts,
            frames,
        )

    def mismatch_of(self, error: BaseException) -> ReplayMismatch | None:
        """``error`` when it is a replay mismatch (the rig sent what the recording did not)."""
        return error if isinstance(error, ReplayMismatch) else None
