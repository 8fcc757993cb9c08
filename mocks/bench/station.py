"""Open the digital twin: lamps on a simulated clock, emulators on ptys and USB, the real drivers on top.

:func:`open_twin` builds, in order:

1. a :class:`mocks.lamps.SimulatedClock` and a :class:`mocks.lamps.LampBank` with the configured
   lamps (colour-science spectra, warm-up drift) — persistent when the spec names a relay state
   file, so relays left on by a killed process are on again in the next;
2. the relay board: a HID USBRelay board on the fake pyusb backend, or an LCUS/Numato emulator on a
   pty — each switching the bank's channels — opened with the real driver;
3. the spectrometer: the PR-655/670 or CS-2000 firmware emulator on a pty, measuring the bank's
   radiance, opened with the real driver (without the PR-6xx's character pacing, which the real
   instrument's USB link needs and the emulator does not);
4. the camera: a fake gphoto2 body whose frames :class:`mocks.bench.camera.FrameRenderer` renders,
   opened with the real gphoto2 driver (bulb exposures timed on the twin's clock).

Everything random is seeded from the spec's seed. Faults can be injected from the start
(:class:`TwinFaults`) or later through the handles on :class:`TwinBench` (``camera_body.inject``,
``relay_board.inject``, ``spectrometer_port.emulator.faults``).

If any step fails, what was opened so far is closed again before the error propagates.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from drivers.base import Camera, RelayBoard, Spectrometer, TranscriptSink
from drivers.camera import CameraTimeouts, open_camera
from drivers.relays.hid_usbrelay import open_hid_relay
from drivers.relays.lcus import open_lcus
from drivers.relays.numato import open_numato
from drivers.spectrometer import open_spectrometer
from drivers.spectrometer.argyll import ArgyllSettings, open_argyll
from drivers.spectrometer.ocean import IrradianceCalibration, OceanSettings, open_ocean
from drivers.spectrometer.pr6xx import open_pr6xx
from drivers.transport import NO_PACING
from mocks.bench.aim import FIELD_DEG, SpectrometerAim
from mocks.bench.camera import FrameRenderer, twin_body
from mocks.bench.deviation import spectrometer_deviation, spectrometer_truth
from mocks.bench.flaws import camera_flaws
from mocks.bench.lamps import PersistentLampBank, virtual_lamp
from mocks.bench.optics import TwinOptics
from mocks.bench.spec import TwinSpec, TwinSpecError
from mocks.bench.truth import TwinTruth
from mocks.emulators import start_cs2000, start_lcus, start_numato, start_pr655, start_pr670
from mocks.emulators.radiometer import RadianceSource, Radiometer, RadiometerOptics
from mocks.fake_gphoto2 import CameraFault, FakeBody, FakeGphoto2
from mocks.faults import FaultKind, FaultSchedule
from mocks.lamps import LampBank, SimulatedClock
from mocks.ocean_backend import OCEAN_MODELS, EmulatedOcean, OceanBackend, ocean_calibration
from mocks.pty_serial import PtySerialDevice
from mocks.spotread_launcher import FakeSpotreadLauncher
from mocks.usb_relay_backend import EmulatedRelayBoard, FakeUsbBackend, UsbFault

TranscriptFactory = Callable[[str], TranscriptSink]
"""The transcript sink for a device role (``"spectrometer"``, ``"relays"``, ``"camera"``)."""

#: Random stream of the spectrometer's noise, mixed with the seed.
SPECTROMETER_NOISE_STREAM = 1
#: The twin's relay board ID and camera serial number.
TWIN_RELAY_SERIAL = "TWIN1"
TWIN_CAMERA_SERIAL = "TW0000000001"

SPECTROMETER_NAMES = {"pr655": "PR-655", "pr670": "PR-670", "cs2000": "CS-2000"}
#: The lamps' time since switch-on is kept to this resolution (see :class:`mocks.lamps.LampBank`).
LAMP_TIME_RESOLUTION_S = 1e-6


def spectrometer_noise_key(spec: TwinSpec) -> list[int]:
    """Seed entropy of the spectrometer's noise: the twin's seed, the stream, and the draw (a draw
    other than 0 changes the spectrometer's noise and nothing else)."""
    key = [spec.seed, SPECTROMETER_NOISE_STREAM]
    return key if spec.spectrometer_noise_draw == 0 else [*key, spec.spectrometer_noise_draw]


def step_entropy(key: str) -> tuple[int, ...]:
    """A step key as seed entropy: four 32-bit words of its sha256."""
    digest = hashlib.sha256(key.encode("utf-8")).digest()
    return tuple(int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4))


@dataclass
class TwinFaults:
    """Faults armed when the twin opens.

    Attributes
    ----------
    spectrometer
        Schedule of the spectrometer emulator (labels: its commands, ``"M5"``, ``"MEAS,1"`` …).
    serial_relays
        Schedule of an LCUS or Numato emulator.
    usb_relays
        Faults of the HID board (see :class:`mocks.usb_relay_backend.UsbFault`).
    camera
        Faults of the camera body (see :class:`mocks.fake_gphoto2.CameraFault`).
    """

    spectrometer: FaultSchedule | None = None
    serial_relays: FaultSchedule | None = None
    usb_relays: Sequence[UsbFault] = ()
    camera: Sequence[CameraFault] = ()


@dataclass(eq=False)
class TwinBench:
    """The open twin: the drivers the rig uses, and the simulated hardware behind them.

    ``spectrometer`` and ``camera`` (with what stands behind them) are ``None`` when the rig's own
    instrument plays that role; the lamps and relays are always the twin's.
    """

    spec: TwinSpec
    clock: SimulatedClock
    bank: LampBank
    relays: RelayBoard
    optics: TwinOptics | None = None
    renderer: FrameRenderer | None = None
    spectrometer: Spectrometer | None = None
    spectrometer_port: PtySerialDevice | None = None
    ocean: EmulatedOcean | None = None
    spotread: TwinSpotread | None = None
    camera: Camera | None = None
    camera_body: FakeBody | None = None
    gphoto2: FakeGphoto2 | None = None
    relay_port: PtySerialDevice | None = None
    relay_board: EmulatedRelayBoard | None = None
    usb_backend: FakeUsbBackend | None = None
    aim: SpectrometerAim | None = None
    closed: bool = field(default=False, init=False)

    def aim_spectrometer(self, beam: str, angle_deg: float) -> None:
        """Turn the twin's spectrometer to ``beam`` (see :mod:`mocks.bench.aim`): the hands of
        the person a real bench needs for the rig's ``AimSpectrometer`` step."""
        if self.aim is None:
            raise TwinSpecError("the spectrometer is real: the twin cannot aim it")
        self.aim.aim(beam, angle_deg)

    def begin_step(self, key: str) -> None:
        """The rig is about to do step ``key``: its readings draw their noise from it.

        The camera's frames and the spectrometer's spectra are then a function of the seed, the
        step and the light, not of how many readings came before, so a retried step or a step done
        in a resumed process reads the same as in an uninterrupted run.
        """
        entropy = step_entropy(key)
        if self.renderer is not None:
            self.renderer.noise_entropy = entropy
        sequence = np.random.SeedSequence([*spectrometer_noise_key(self.spec), *entropy])
        if self.ocean is not None:
            self.ocean.rng = np.random.default_rng(sequence)
        elif self.spotread is not None:
            self.spotread.key_noise(sequence)
        elif self.spectrometer_port is not None:
            radiometer = self.spectrometer_port.emulator.radiometer  # type: ignore[attr-defined]
            radiometer.rng_per_observation = lambda: np.random.default_rng(sequence)

    @property
    def truth(self) -> TwinTruth:
        """What an estimate from this twin's frames should find (a twin camera's)."""
        if self.optics is None:
            raise TwinSpecError("the camera is real: the twin knows no truth about it")
        return TwinTruth.of(
            self.optics, self.spec.seed, spectrometer_truth(self.spec), camera_flaws(self.spec)
        )

    def radiometers(self) -> list[Radiometer]:
        """The emulated spectrometer's measurement physics (one per resolution for spotread)."""
        if self.ocean is not None:
            return [self.ocean._radiometer]
        if self.spotread is not None:
            return list(self.spotread.radiometers.values())
        if self.spectrometer_port is not None:
            return [self.spectrometer_port.emulator.radiometer]  # type: ignore[attr-defined]
        return []

    def close(self) -> None:
        """Stop the emulators and remove scratch files (the drivers are closed by their owner)."""
        if self.closed:
            return
        self.closed = True
        if self.gphoto2 is not None:
            self.gphoto2.release_hangs()
        for port in (self.spectrometer_port, self.relay_port):
            if port is not None:
                with contextlib.suppress(Exception):
                    port.stop()
        if self.spotread is not None:
            self.spotread.launcher.close()
        if self.renderer is not None:
            self.renderer.close()


class _Opened:
    """What has been opened so far, closed in reverse order if opening the rest fails."""

    def __init__(self) -> None:
        self._closers: list[Callable[[], object]] = []

    def add(self, closer: Callable[[], object]) -> None:
        self._closers.append(closer)

    def close_all(self) -> None:
        for closer in reversed(self._closers):
            with contextlib.suppress(Exception):
                closer()


def open_twin(
    spec: TwinSpec,
    transcripts: TranscriptFactory | None = None,
    *,
    faults: TwinFaults | None = None,
    prepare: bool = True,
) -> TwinBench:
    """Open the simulated bench described by ``spec``.

    Parameters
    ----------
    spec
        The bench.
    transcripts
        Gives each device's transcript sink by role (default: none recorded).
    faults
        Faults armed from the start.
    prepare
        Render every lamp's noiseless image now (otherwise at its first frame).

    Raises
    ------
    mocks.bench.spec.TwinSpecError
        The spec cannot be built (unknown camera or illuminant, a layout that does not fit).
    drivers.base.DeviceError
        A driver fails to open its emulated device (e.g. an injected fault at open).
    """
    faults = faults or TwinFaults()

    def sink(role: str) -> TranscriptSink | None:
        return transcripts(role) if transcripts is not None else None

    clock = SimulatedClock()
    lamps = [virtual_lamp(lamp) for lamp in spec.lamps]
    bank: LampBank
    saved = (False,) * spec.relay_channels
    if spec.relay_state_file is None:
        bank = LampBank(
            lamps,
            n_channels=spec.relay_channels,
            clock=clock,
            time_resolution_s=LAMP_TIME_RESOLUTION_S,
        )
    else:
        bank = PersistentLampBank(
            lamps,
            spec.relay_channels,
            clock,
            spec.relay_state_file,
            time_resolution_s=LAMP_TIME_RESOLUTION_S,
        )
        saved = bank.saved_channels()
    opened = _Opened()
    try:
        bench = _open_relays(spec, bank, clock, saved, faults, sink("relays"), opened)
        _open_spectrometer(bench, faults, sink("spectrometer"), opened)
        _open_camera(bench, faults, sink("camera"), opened, prepare=prepare)
    except BaseException:
        opened.close_all()
        raise
    return bench


def _open_relays(
    spec: TwinSpec,
    bank: LampBank,
    clock: SimulatedClock,
    saved: tuple[bool, ...],
    faults: TwinFaults,
    transcript: TranscriptSink | None,
    opened: _Opened,
) -> TwinBench:
    """The relay board switching ``bank``, opened with the real driver."""
    relay_port: PtySerialDevice | None = None
    relay_board: EmulatedRelayBoard | None = None
    usb_backend: FakeUsbBackend | None = None
    relays: RelayBoard
    if spec.relay_model == "hid_usbrelay":
        relay_board = EmulatedRelayBoard(TWIN_RELAY_SERIAL, spec.relay_channels, lamp_bank=bank)
        relay_board.state_mask = sum(1 << index for index, on in enumerate(saved) if on)
        for usb_fault in faults.usb_relays:
            relay_board.inject(usb_fault)
        usb_backend = FakeUsbBackend([relay_board], clock=clock)
        relays = open_hid_relay(
            TWIN_RELAY_SERIAL,
            backend=usb_backend,
            transcript=transcript,
            timeout_s=spec.relay_timeout_s,
        )
    else:
        start = start_lcus if spec.relay_model == "lcus" else start_numato
        relay_port = start(spec.relay_channels, bank, faults=faults.serial_relays)
        opened.add(relay_port.stop)
        relay_port.emulator.states = list(saved)  # type: ignore[attr-defined]
        opener = open_lcus if spec.relay_model == "lcus" else open_numato
        relays = opener(
            relay_port.path,
            spec.relay_channels,
            timeout_s=spec.relay_timeout_s,
            transcript=transcript,
        )
    opened.add(relays.close)
    # Relays left on by a previous process light their lamps again (warming up from now).
    for channel, on in enumerate(saved, start=1):
        if on:
            bank.set_channel(channel, True)
    return TwinBench(
        spec=spec,
        clock=clock,
        bank=bank,
        relays=relays,
        relay_port=relay_port,
        relay_board=relay_board,
        usb_backend=usb_backend,
    )


#: The i1Pro's bands in ArgyllCMS's standard (10 nm) and high-resolution (3.3 nm) modes, 380–730 nm.
I1PRO_BANDS = {"standard": 36, "high_resolution": 106}
#: Its optical resolution (FWHM) in each mode (see :data:`drivers.spectrometer.argyll.I1PRO_BANDWIDTH_NM`).
I1PRO_FWHM_NM = {"standard": 25.0, "high_resolution": 15.0}
#: Radiance (W/(sr·m²·nm)) to the ambient reading spotread reports (mW/(m²·nm)) of a uniform field.
AMBIENT_MW_PER_RADIANCE = 1000.0 * np.pi
#: How the twin's spectrometer faults look on spotread (label ``"spotread"``); ``ERROR_CODE``
#: takes the fake's fault name from its code (default ``misread``).
SPOTREAD_FAULTS = {
    FaultKind.NO_REPLY: "hang",
    FaultKind.DISCONNECT: "no_instrument",
    FaultKind.BUSY: "comms",
    FaultKind.GARBLED_REPLY: "garbled_file",
    FaultKind.TRUNCATED_REPLY: "garbled_file",
}


class TwinSpotread:
    """What the fake spotread reads on the twin: an i1Pro-like instrument looking at the lamps.

    Each run's scene holds the reading in both resolutions (each through its own slit function
    and noise), or the fault the schedule injects (label ``"spotread"``).
    """

    def __init__(
        self,
        radiance: RadianceSource,
        noise: np.random.Generator,
        faults: FaultSchedule | None,
        time_scale: float,
    ) -> None:
        self.faults = faults or FaultSchedule()
        self.time_scale = time_scale
        self.radiometers = {
            mode: Radiometer(
                RadiometerOptics(
                    wavelength_nm=np.linspace(380.0, 730.0, bands),
                    bandwidth_nm=I1PRO_FWHM_NM[mode],
                    peak_responsivity=5.0e3,
                    exposure_range_ms=(2.0, 8000.0),
                    read_noise_counts=8.0,
                    overhead_s=1.5,
                ),
                radiance,
                noise,
            )
            for mode, bands in I1PRO_BANDS.items()
        }
        self.launcher = FakeSpotreadLauncher(self.scene)

    def key_noise(self, sequence: np.random.SeedSequence) -> None:
        """Draw the next readings' noise from ``sequence`` (one stream per resolution)."""
        for index, radiometer in enumerate(self.radiometers.values()):
            child = np.random.SeedSequence(sequence.entropy, spawn_key=(index,))
            radiometer.rng_per_observation = lambda child=child: np.random.default_rng(child)

    def scene(self) -> dict[str, object]:
        """The fake spotread's scene of the next run."""
        fault = self.faults.next_fault("spotread")
        name: str | None = None
        delay_s = 0.0
        if fault is not None:
            if fault.kind is FaultKind.ERROR_CODE:
                name = fault.code or "misread"
            elif fault.kind is FaultKind.LATE_REPLY:
                delay_s = fault.delay_s
            else:
                name = SPOTREAD_FAULTS[fault.kind]
        spectra: dict[str, object] = {}
        for mode, radiometer in self.radiometers.items():
            observation = radiometer.observe(None)
            if observation.radiance is None:
                name = name or "misread"
                continue
            delay_s = max(delay_s, observation.duration_s * self.time_scale)
            grid = radiometer.optics.wavelength_nm
            spectra[mode] = {
                "start_nm": float(grid[0]),
                "end_nm": float(grid[-1]),
                "values": [float(v) for v in observation.radiance * AMBIENT_MW_PER_RADIANCE],
            }
        return {"instruments": 1, "fault": name, "delay_s": delay_s, "spectra": spectra}


def twin_ocean_settings(model: str, timeout_s: float) -> OceanSettings:
    """The Ocean driver's settings on the twin: the emulated model's exact calibration."""
    emulated = OCEAN_MODELS[model]
    wavelength_nm, factor = ocean_calibration(emulated)
    calibration = IrradianceCalibration(wavelength_nm, factor, source=f"twin {model}")
    return OceanSettings(
        calibration=calibration,
        bandwidth_nm=emulated.bandwidth_nm,
        timeout_ms=max(1, round(timeout_s * 1000)),
    )


def _open_spectrometer(
    bench: TwinBench, faults: TwinFaults, transcript: TranscriptSink | None, opened: _Opened
) -> None:
    """The emulated spectrometer measuring the bank, opened with the real driver."""
    spec = bench.spec
    model = spec.spectrometer_model
    if model is None:
        return
    noise = np.random.default_rng(np.random.SeedSequence(spectrometer_noise_key(spec)))
    aim = SpectrometerAim(bench.bank.radiance, spec.camera, FIELD_DEG[model])
    bench.aim = aim
    if model == "seabreeze":
        ocean = EmulatedOcean(
            OCEAN_MODELS[spec.ocean_model],
            aim.radiance,
            seed=noise,
            faults=faults.spectrometer,
            time_scale=spec.spectrometer_time_scale,
        )
        bench.ocean = ocean
        _deviate(bench)
        bench.spectrometer = open_ocean(
            None,
            twin_ocean_settings(spec.ocean_model, spec.spectrometer_timeout_s),
            backend=OceanBackend([ocean]),
            transcript=transcript,
        )
        opened.add(bench.spectrometer.close)
        return
    if model == "argyll":
        spotread = TwinSpotread(
            aim.radiance, noise, faults.spectrometer, spec.spectrometer_time_scale
        )
        bench.spotread = spotread
        _deviate(bench)
        opened.add(spotread.launcher.close)
        bench.spectrometer = open_argyll(
            ArgyllSettings(
                timeout_s=spec.spectrometer_timeout_s,
                high_resolution=spec.spectrometer_high_resolution,
            ),
            launcher=spotread.launcher,
            transcript=transcript,
            resolve=False,
        )
        opened.add(bench.spectrometer.close)
        return
    starter = {"pr655": start_pr655, "pr670": start_pr670, "cs2000": start_cs2000}
    port = starter[model](
        aim.radiance,
        seed=noise,
        faults=faults.spectrometer,
        time_scale=spec.spectrometer_time_scale,
    )
    bench.spectrometer_port = port
    _deviate(bench)
    opened.add(port.stop)
    spectrometer: Spectrometer
    if model == "cs2000":
        spectrometer = open_spectrometer(
            "CS-2000",
            port.path,
            timeout_s=spec.spectrometer_timeout_s,
            measure_timeout_s=spec.spectrometer_measure_timeout_s,
            transcript=transcript,
        )
    else:
        # The PR-6xx driver paces characters for the real instrument's USB link; the emulator
        # takes whole commands, so the twin drops the pauses (same bytes, no waiting).
        spectrometer = open_pr6xx(
            SPECTROMETER_NAMES[model],
            port.path,
            timeout_s=spec.spectrometer_timeout_s,
            measure_timeout_s=spec.spectrometer_measure_timeout_s,
            transcript=transcript,
            pacing=NO_PACING,
        )
    bench.spectrometer = spectrometer
    opened.add(spectrometer.close)


def _deviate(bench: TwinBench) -> None:
    """Give the emulated instrument its in-spec scale and slit errors (the one place: each
    emulator's :class:`~mocks.emulators.radiometer.Radiometer`)."""
    deviation = spectrometer_deviation(bench.spec)
    if deviation is None:
        return
    for radiometer in bench.radiometers():
        radiometer.deviation = deviation


def _open_camera(
    bench: TwinBench,
    faults: TwinFaults,
    transcript: TranscriptSink | None,
    opened: _Opened,
    *,
    prepare: bool,
) -> None:
    """The fake camera body rendering the scene, opened with the real gphoto2 driver."""
    camera_spec = bench.spec.camera
    if camera_spec is None:
        return
    flaws = camera_flaws(bench.spec)
    optics = TwinOptics.build(camera_spec, flaws)
    renderer = FrameRenderer(
        optics,
        bench.bank,
        bench.clock,
        seed=bench.spec.seed,
        download_s=camera_spec.download_s,
        realtime=camera_spec.realtime,
        flaws=flaws,
    )
    opened.add(renderer.close)
    bench.optics, bench.renderer = optics, renderer
    if prepare:
        renderer.prepare()
    body = twin_body(renderer, bench.clock, TWIN_CAMERA_SERIAL)
    for camera_fault in faults.camera:
        body.inject(camera_fault)
    gphoto2 = FakeGphoto2([body])
    opened.add(gphoto2.release_hangs)
    bench.camera_body, bench.gphoto2 = body, gphoto2
    bench.camera = open_camera(
        gphoto2_module=gphoto2,
        transcript=transcript,
        timeouts=CameraTimeouts(
            call_s=camera_spec.timeout_s, download_s=camera_spec.download_timeout_s
        ),
        exposure_timer=bench.clock,
    )
