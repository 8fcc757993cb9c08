"""Small in-memory fake devices for the rig's tests, with fault injection.

The fakes share one :class:`mocks.lamps.LampBank`: the relay board switches its channels, the
spectrometer reads its radiance (with warm-up drift), and the camera writes a tiny "RAW" file
recording the exposure and which lamps were lit; :class:`FakeAnalyzer` turns that file into
:class:`rig.analysis.FrameStats` with a simple sensor model (white level, shot and read noise), so
automatic bracketing sees realistic saturation and SNR.

Faults: every fake has ``faults[method]``, a list of exceptions raised (first to last) by the next
calls of that method (``None`` in the list lets one call through); ``delay_s[method]``, a real sleep
inside the call (to test deadlines and interrupts); and ``hold[method]``, an event the call waits
for (at most :data:`HOLD_LIMIT_S`): a call that hangs until the test lets it go, so a test shows
that the rig did not wait for it without timing anything. ``events`` records
``("begin"|"end", device, method)`` in order across all fakes.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.spectra import Spectrum
from drivers.base import (
    CapturedFile,
    DeviceIdentity,
    SettingInfo,
    SpectrumReading,
    TranscriptEntry,
    TranscriptSink,
)
from mocks.lamps import Clock, LampBank, SimulatedClock, VirtualLamp
from rig.analysis import FrameStats
from rig.config import RigConfig
from rig.errors import FrameAnalysisError
from rig.station_devices import Station, TranscriptFactory

RAW_MAGIC = b"FAKERAW1\n"
WHITE_LEVEL_DN = 4000.0
READ_NOISE_DN = 4.0
WAVELENGTH_NM = np.arange(380.0, 781.0, 4.0)
#: Longest a held call waits for its test to let it go (tests never hang).
HOLD_LIMIT_S = 60.0


@dataclass(frozen=True)
class FakeLampOptics:
    """How bright a lamp looks to the camera: DN per second on the direct spot and the band."""

    direct_dn_per_s: float
    band_dn_per_s: float


class FaultInjector:
    """Per-method queued exceptions and delays, and a shared event log."""

    def __init__(self, name: str, events: list[tuple[str, str, str]]) -> None:
        self.name = name
        self.faults: dict[str, list[BaseException | None]] = defaultdict(list)
        self.delay_s: dict[str, float] = {}
        self.hold: dict[str, threading.Event] = {}
        self.calls: dict[str, int] = defaultdict(int)
        self.events = events
        self.transcript: TranscriptSink | None = None

    def enter(self, method: str) -> None:
        self.calls[method] += 1
        self.events.append(("begin", self.name, method))
        self._record("tx", method)
        delay = self.delay_s.get(method, 0.0)
        if delay:
            time.sleep(delay)
        held = self.hold.get(method)
        if held is not None:
            held.wait(HOLD_LIMIT_S)
        error = self.faults[method].pop(0) if self.faults[method] else None
        if error is not None:
            self.events.append(("end", self.name, method))
            self._record("error", f"{method}: {error}")
            raise error

    def leave(self, method: str, reply: str = "ok") -> None:
        self._record("rx", reply)
        self.events.append(("end", self.name, method))

    def _record(self, direction: str, text: str) -> None:
        if self.transcript is not None:
            payload = text.encode()
            self.transcript.record(
                TranscriptEntry(self.name, direction, payload, time.monotonic())  # type: ignore[arg-type]
            )


class FakeRelayBoard:
    """A relay board on the lamp bank; optionally mirrors its state to ``state_file`` (``"0100"``).

    Channels in ``stuck_on`` always read as on; channels in ``dead`` ignore commands (and, unlike a
    real driver, the fake does not verify: the runner's own read-back must catch it).
    """

    def __init__(
        self, bank: LampBank, events: list[tuple[str, str, str]], state_file: Path | None = None
    ) -> None:
        self.bank = bank
        self.io = FaultInjector("relays", events)
        self.state_file = state_file
        self.stuck_on: set[int] = set()
        self.dead: set[int] = set()
        self._write_state()

    @property
    def channels(self) -> int:
        return self.bank.n_channels

    def identify(self) -> DeviceIdentity:
        self.io.enter("identify")
        self.io.leave("identify")
        return DeviceIdentity("relay", "FakeRelay", serial="R1", port="fake:relays")

    def _write_state(self) -> None:
        if self.state_file is None:
            return
        text = "".join("1" if on else "0" for on in self.state())
        temporary = self.state_file.with_suffix(".tmp")
        temporary.write_text(text)
        temporary.replace(self.state_file)

    def set(self, channel: int, on: bool) -> None:
        self.io.enter("set")
        if channel not in self.dead:
            self.bank.set_channel(channel, on)
        self._write_state()
        self.io.leave("set")

    def state(self) -> tuple[bool, ...]:
        states = self.bank.channel_states()
        return tuple(on or (i + 1) in self.stuck_on for i, on in enumerate(states))

    def all_off(self) -> None:
        self.io.enter("all_off")
        for channel in range(1, self.bank.n_channels + 1):
            self.bank.set_channel(channel, False)
        self._write_state()
        self.io.leave("all_off")

    def close(self) -> None:
        self.io.events.append(("close", "relays", "close"))


class FakeSpectrometer:
    """Measures the lamp bank's radiance; lamps named in ``flicker`` never settle."""

    def __init__(self, bank: LampBank, events: list[tuple[str, str, str]]) -> None:
        self.bank = bank
        self.io = FaultInjector("spectrometer", events)
        self.flicker: dict[str, float] = {}
        self.exposure_ms: float | None = None

    def identify(self) -> DeviceIdentity:
        self.io.enter("identify")
        self.io.leave("identify")
        return DeviceIdentity("spectrometer", "FakeSpectro", serial="S1", port="fake:spectro")

    def set_exposure(self, exposure_ms: float | None) -> None:
        self.io.enter("set_exposure")
        self.exposure_ms = exposure_ms
        self.io.leave("set_exposure")

    def measure(self) -> SpectrumReading:
        self.io.enter("measure")
        values = self.bank.radiance(WAVELENGTH_NM)
        for lamp, seconds_on in self.bank.lit():
            amplitude = self.flicker.get(lamp.name)
            if amplitude:
                values = values * (1.0 + amplitude * math.sin(seconds_on / 3.0))
        self.io.leave("measure", f"{values.sum():.6g}")
        return SpectrumReading(WAVELENGTH_NM.copy(), values, "W/(sr·m²·nm)", self.exposure_ms)

    def close(self) -> None:
        self.io.events.append(("close", "spectrometer", "close"))


class FakeCamera:
    """Writes a small JSON "RAW" file per capture; exposures snap to ``choices_s`` when given."""

    def __init__(
        self,
        bank: LampBank,
        optics: dict[str, FakeLampOptics],
        events: list[tuple[str, str, str]],
        *,
        exposure_range_s: tuple[float, float] = (1 / 8000, 30.0),
        choices_s: Iterable[float] | None = None,
        suffix: str = ".dng",
    ) -> None:
        self.bank = bank
        self.optics = optics
        self.io = FaultInjector("camera", events)
        self.range_s = exposure_range_s
        self.choices_s = sorted(choices_s) if choices_s is not None else None
        self.suffix = suffix
        self.exposure_s = 1 / 100
        self.settings: dict[str, str] = {}
        self.captured = 0
        self.capture_started = threading.Event()
        self.marker_file: Path | None = None
        #: When set, each capture takes exposure + this many seconds of real time (a download).
        self.real_time_download_s: float | None = None
        #: The serial number the body reports (another body: another serial).
        self.serial = "C1"
        #: Where the body reports it is connected (a replug elsewhere: another port).
        self.port = "fake:usb"

    def identify(self) -> DeviceIdentity:
        self.io.enter("identify")
        self.io.leave("identify")
        return DeviceIdentity("camera", "FakeCam", serial=self.serial, port=self.port)

    def list_settings(self) -> dict[str, SettingInfo]:
        return {name: SettingInfo(name, value) for name, value in self.settings.items()}

    def get_setting(self, name: str) -> str:
        return self.settings[name]

    def set_setting(self, name: str, value: str) -> str:
        self.io.enter("set_setting")
        self.settings[name] = value
        self.io.leave("set_setting", value)
        return value

    def exposure_range_s(self) -> tuple[float, float]:
        return self.range_s

    def set_exposure(self, exposure_s: float) -> float:
        self.io.enter("set_exposure")
        low, high = self.range_s
        target = min(high, max(low, exposure_s))
        if self.choices_s is not None:
            target = min(self.choices_s, key=lambda c: abs(math.log(c / target)))
        self.exposure_s = target
        self.io.leave("set_exposure", f"{target:g}")
        return target

    def capture(self, destination: Path, *, sync: bool = True) -> CapturedFile:
        self.capture_started.set()
        if self.marker_file is not None:
            self.marker_file.write_text(str(self.captured + 1))
        self.io.enter("capture")
        if self.real_time_download_s is not None:
            time.sleep(self.exposure_s + self.real_time_download_s)
        self.captured += 1
        lit = self.bank.lit()
        frame = {
            "exposure_s": self.exposure_s,
            "direct_dn_per_s": sum(self.optics[lamp.name].direct_dn_per_s for lamp, _ in lit),
            "band_dn_per_s": sum(self.optics[lamp.name].band_dn_per_s for lamp, _ in lit),
            "lit": [lamp.name for lamp, _ in lit],
            "number": self.captured,
        }
        destination.write_bytes(RAW_MAGIC + json.dumps(frame).encode())
        self.io.leave("capture", destination.name)
        return CapturedFile(
            destination, f"/store/DCIM/IMG_{self.captured:04d}{self.suffix}", self.exposure_s
        )

    def close(self) -> None:
        self.io.events.append(("close", "camera", "close"))


class FakeAnalyzer:
    """Frame statistics from a :class:`FakeCamera` file: saturation at the white level, shot + read noise."""

    def __init__(self) -> None:
        self.analysed: list[Path] = []

    def analyse(self, frame: Path) -> FrameStats:
        data = frame.read_bytes()
        if not data.startswith(RAW_MAGIC):
            raise FrameAnalysisError(str(frame), "not a fake RAW file")
        self.analysed.append(frame)
        content: dict[str, Any] = json.loads(data[len(RAW_MAGIC) :])
        exposure_s = float(content["exposure_s"])
        direct = float(content["direct_dn_per_s"]) * exposure_s
        band = min(float(content["band_dn_per_s"]) * exposure_s, WHITE_LEVEL_DN)
        # The spot has a Gaussian profile: the fraction of its pixels above the white level grows
        # with the peak level.
        saturated = (
            0.0 if direct <= WHITE_LEVEL_DN else min(1.0, math.log(direct / WHITE_LEVEL_DN) / 3)
        )
        noise = math.sqrt(band + READ_NOISE_DN**2)
        return FrameStats(
            direct_saturated_fraction=saturated,
            band_snr=band / noise,
            band_signal_dn=band,
            band_saturated_fraction=1.0 if band >= WHITE_LEVEL_DN else 0.0,
        )


def _gaussian_spectrum(name: str, centre_nm: float, width_nm: float) -> Spectrum:
    wavelength = np.arange(360.0, 831.0, 1.0)
    values = 0.02 + np.exp(-(((wavelength - centre_nm) / width_nm) ** 2))
    return Spectrum(wavelength, values, name=name)


@dataclass
class FakeRig:
    """A complete fake station: lamp bank, the three devices, analyser and clock.

    ``builder`` has the :data:`rig.station.StationBuilder` signature and hands out these devices
    (attaching the session's transcript sinks).
    """

    clock: Clock
    bank: LampBank
    relays: FakeRelayBoard
    spectrometer: FakeSpectrometer
    camera: FakeCamera
    analyzer: FakeAnalyzer
    events: list[tuple[str, str, str]] = field(default_factory=list)
    closed: bool = False

    def builder(self, config: RigConfig, transcripts: TranscriptFactory) -> Station:
        self.relays.io.transcript = transcripts("relays")
        self.spectrometer.io.transcript = transcripts("spectrometer")
        self.camera.io.transcript = transcripts("camera")
        return Station(
            self.spectrometer,
            self.camera,
            self.relays,
            self.clock,
            self.analyzer,
            on_close=[self._mark_closed],
        )

    def _mark_closed(self) -> None:
        self.closed = True


DEFAULT_OPTICS = {
    "LED-B3": FakeLampOptics(direct_dn_per_s=200_000.0, band_dn_per_s=2_000.0),
    "FL2": FakeLampOptics(direct_dn_per_s=80_000.0, band_dn_per_s=800.0),
}


def make_fake_rig(
    *,
    clock: Clock | None = None,
    n_channels: int = 2,
    optics: dict[str, FakeLampOptics] | None = None,
    state_file: Path | None = None,
    warmup_tau_s: float = 20.0,
    **camera_options: Any,
) -> FakeRig:
    """Two lamps (LED-B3 on channel 1, FL2 on channel 2) on a simulated clock by default."""
    clock = clock or SimulatedClock()
    lamps = [
        VirtualLamp("LED-B3", 1, _gaussian_spectrum("LED-B3", 460.0, 30.0), "led", warmup_tau_s),
        VirtualLamp(
            "FL2", 2, _gaussian_spectrum("FL2", 580.0, 80.0), "fluorescent", warmup_tau_s, -0.2
        ),
    ]
    bank = LampBank(lamps, n_channels=n_channels, clock=clock)
    events: list[tuple[str, str, str]] = []
    return FakeRig(
        clock=clock,
        bank=bank,
        relays=FakeRelayBoard(bank, events, state_file),
        spectrometer=FakeSpectrometer(bank, events),
        camera=FakeCamera(bank, optics or DEFAULT_OPTICS, events, **camera_options),
        analyzer=FakeAnalyzer(),
        events=events,
    )


def fake_config_data(output_dir: Path | str = "sessions") -> dict[str, Any]:
    """A valid configuration (twin kinds, two lamps) as plain data, for tests to modify."""
    return {
        "seed": 7,
        "output_dir": str(output_dir),
        "devices": {
            "spectrometer": {"kind": "twin", "timeout_s": 5},
            "relays": {"kind": "twin", "channels": 2, "timeout_s": 1},
            "camera": {"kind": "twin", "timeout_s": 2, "download_timeout_s": 5},
        },
        "camera": {"iso": 100, "aperture": 8, "exposure_range_s": ["1/8000", 30]},
        "lamps": [
            {
                "name": "LED-B3",
                "channel": 1,
                "kind": "led",
                "warmup": {"tolerance": 0.002, "interval_s": 10, "timeout_s": 300},
            },
            {
                "name": "FL2",
                "channel": 2,
                "kind": "fluorescent",
                "warmup": {"tolerance": 0.002, "interval_s": 10, "timeout_s": 300},
            },
        ],
        "spectrum": {"repeats": 2},
        "hdr": {
            "min_exposure_s": "1/4000",
            "max_exposure_s": 8,
            "start_exposure_s": "1/60",
            "step_stops": 2,
            "max_direct_saturated_fraction": 0.0,
            "min_band_snr": 30,
            "max_frames": 8,
        },
        "dark_frames": 1,
    }


def fake_config(output_dir: Path | str = "sessions", **overrides: Any) -> RigConfig:
    """:func:`fake_config_data` validated, with top-level keys replaced by ``overrides``."""
    data = fake_config_data(output_dir)
    data.update(overrides)
    return RigConfig.model_validate(data)


def write_config(path: Path, data: dict[str, Any]) -> Path:
    """Write configuration data as YAML (JSON is valid YAML)."""
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
    return path


def wait_for(condition: Any, timeout_s: float = 10.0, what: str = "condition") -> None:
    """Poll ``condition()`` until true; fail after ``timeout_s`` (tests never hang)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.01)


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
