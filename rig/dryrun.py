"""Walk a plan with no devices: modelled readings, an estimated duration, and limit violations.

``rig dry-run`` runs this before any lamp is switched on, in the spirit of Bluesky's
``summarize_plan`` and ``check_limits``. Two kinds of problem are found:

* static limits of the configuration (:func:`check_limits`): the HDR range against the camera's
  declared exposure range, lamp channels against the relay board, two lamps on one channel;
* whatever the plan itself raises when walked with modelled readings (a bracket that cannot be
  completed within ``hdr.max_frames``, for example).

The readings are modelled from ``config.dry_run`` (:class:`ModelledBench`): the lamp spectrum drifts
until ``lamp_settles_s`` after switch-on, the direct spot saturates above ``direct_saturates_at_s``,
and the band's SNR grows as √exposure from ``band_snr_at_direct_saturation`` there; a person
re-aiming the spectrometer takes ``operator_aim_s``. The same
:class:`StepCostModel` gives the runner's progress bar its ETA.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rig.analysis import FrameStats
from rig.config import DryRunModel, RigConfig
from rig.errors import PlanFailure, PlanProtocolError
from rig.plan import Plan, StandardCaptureArgs, standard_capture
from rig.steps import (
    AimSpectrometer,
    AllLampsOff,
    AnyStep,
    CameraReady,
    Capture,
    ConfigureCamera,
    ConfigureSpectrometer,
    DarkFrame,
    DarkMeasured,
    ExposureSet,
    FrameCaptured,
    KeepLampTimeline,
    MeasureBeam,
    MeasureDark,
    MeasureSpectrum,
    RelayState,
    SetExposure,
    SettingReadBack,
    SpectrometerAimed,
    SpectrometerReady,
    SpectrumMeasured,
    Step,
    StepHandlers,
    StepResult,
    SwitchLamp,
    Wait,
    Waited,
    interpret,
)

#: Seconds assumed for applying the camera or spectrometer settings, and for one exposure change.
SETTINGS_S = 0.5
EXPOSURE_CHANGE_S = 0.1
#: Safety bound on the number of steps a walked plan may yield.
MAX_STEPS = 100_000


@dataclass(frozen=True)
class LimitViolation:
    """Something the configuration asks that the hardware cannot do; ``field`` is the config path."""

    field: str
    message: str

    def __str__(self) -> str:
        return f"{self.field}: {self.message}"


def check_limits(config: RigConfig) -> list[LimitViolation]:
    """Static checks of the configuration against the devices' declared limits.

    Checks the HDR exposure range against ``camera.exposure_range_s``, every lamp's relay channel
    against the board's channel count, and that no two lamps share a channel.
    """
    violations = []
    low, high = config.camera.exposure_range_s
    if config.hdr.min_exposure_s < low:
        violations.append(
            LimitViolation(
                "hdr.min_exposure_s",
                f"{config.hdr.min_exposure_s:g} s is shorter than the camera's shortest exposure "
                f"{low:g} s (camera.exposure_range_s)",
            )
        )
    if config.hdr.max_exposure_s > high:
        violations.append(
            LimitViolation(
                "hdr.max_exposure_s",
                f"{config.hdr.max_exposure_s:g} s is longer than the camera's longest exposure "
                f"{high:g} s (camera.exposure_range_s)",
            )
        )
    n_channels = config.devices.relays.channels
    owners: dict[int, str] = {}
    for index, lamp in enumerate(config.lamps):
        if lamp.channel > n_channels:
            violations.append(
                LimitViolation(
                    f"lamps[{index}].channel",
                    f"{lamp.name} is on channel {lamp.channel}, but the relay board has "
                    f"{n_channels} (devices.relays.channels)",
                )
            )
        if lamp.channel in owners:
            violations.append(
                LimitViolation(
                    f"lamps[{index}].channel",
                    f"{lamp.name} shares relay channel {lamp.channel} with {owners[lamp.channel]}: "
                    "both would light together",
                )
            )
        owners.setdefault(lamp.channel, lamp.name)
    return violations


class StepCostModel(StepHandlers[float]):
    """Estimated duration of each step in seconds, from ``config.dry_run`` (the spectrometer's dark
    counts as one spectrum measurement: plans and the dry run know no driver's integration ladder).
    """

    def __init__(self, model: DryRunModel) -> None:
        self.model = model

    def duration_s(self, step: AnyStep) -> float:
        """The step's modelled duration (s)."""
        return interpret(step, self)

    def all_lamps_off(self, step: AllLampsOff) -> float:
        return self.model.relay_switch_s

    def switch_lamp(self, step: SwitchLamp) -> float:
        return self.model.relay_switch_s

    def configure_camera(self, step: ConfigureCamera) -> float:
        return SETTINGS_S

    def configure_spectrometer(self, step: ConfigureSpectrometer) -> float:
        return SETTINGS_S

    def measure_spectrum(self, step: MeasureSpectrum) -> float:
        return self.model.spectrum_measure_s

    def measure_dark(self, step: MeasureDark) -> float:
        return self.model.spectrum_measure_s

    def aim_spectrometer(self, step: AimSpectrometer) -> float:
        return self.model.operator_aim_s

    def measure_beam(self, step: MeasureBeam) -> float:
        return self.model.spectrum_measure_s

    def wait(self, step: Wait) -> float:
        return step.seconds

    def keep_lamp_timeline(self, step: KeepLampTimeline) -> float:
        return step.seconds

    def set_exposure(self, step: SetExposure) -> float:
        return EXPOSURE_CHANGE_S

    def capture(self, step: Capture) -> float:
        return step.exposure_s + self.model.frame_download_s

    def dark_frame(self, step: DarkFrame) -> float:
        return step.exposure_s + self.model.frame_download_s


class ModelledBench(StepHandlers[StepResult]):
    """Modelled readings for every step, on a modelled clock advanced by :class:`StepCostModel`."""

    #: The modelled spectrum's wavelengths (nm) and the relative drift per interval before settling.
    WAVELENGTH_NM = np.arange(380.0, 781.0, 5.0)

    def __init__(self, config: RigConfig) -> None:
        self.config = config
        self.cost = StepCostModel(config.dry_run)
        self.time_s = 0.0
        self._switched_on_s: dict[str, float] = {}
        self._n_channels = config.devices.relays.channels
        self._lit: set[int] = set()

    def respond(self, step: AnyStep) -> StepResult:
        """Advance the modelled clock by the step's duration and return its modelled result."""
        self.time_s += self.cost.duration_s(step)
        return interpret(step, self)

    def _relay_state(self) -> RelayState:
        channels = tuple(c in self._lit for c in range(1, self._n_channels + 1))
        return RelayState(self.time_s, channels)

    def all_lamps_off(self, step: AllLampsOff) -> RelayState:
        self._lit.clear()
        return self._relay_state()

    def switch_lamp(self, step: SwitchLamp) -> RelayState:
        if step.on:
            self._lit.add(step.channel)
            self._switched_on_s[step.lamp] = self.time_s
        else:
            self._lit.discard(step.channel)
        return self._relay_state()

    def configure_camera(self, step: ConfigureCamera) -> CameraReady:
        settings = tuple(SettingReadBack(n, v, v) for n, v in step.settings)
        return CameraReady(settings, self.config.camera.exposure_range_s)

    def configure_spectrometer(self, step: ConfigureSpectrometer) -> SpectrometerReady:
        return SpectrometerReady(step.exposure_ms)

    def aim_spectrometer(self, step: AimSpectrometer) -> SpectrometerAimed:
        return SpectrometerAimed(self.time_s, self.config.dry_run.operator_aim_s)

    def measure_beam(self, step: MeasureBeam) -> SpectrumMeasured:
        # Light only around the aimed wavelength in the 1st order; everywhere in the others.
        wavelength = self.WAVELENGTH_NM
        shape = np.exp(-(((wavelength - 550.0) / 120.0) ** 2))
        if step.centre_nm is not None:
            shape = shape * (np.abs(wavelength - step.centre_nm) < 15.0)
        return SpectrumMeasured(self.time_s, step.file, wavelength, shape, "W/(sr·m²·nm)", None)

    def measure_spectrum(self, step: MeasureSpectrum) -> SpectrumMeasured:
        lamp = self.config.lamp(step.lamp)
        on_for_s = self.time_s - self._switched_on_s.get(step.lamp, self.time_s)
        settle_s = self.config.dry_run.lamp_settles_s
        # Each interval before settling changes the spectrum by twice the tolerance, then nothing.
        drift = (1.0 + 2.0 * lamp.warmup.tolerance) ** (
            min(on_for_s, settle_s) / lamp.warmup.interval_s
        )
        shape = np.exp(-(((self.WAVELENGTH_NM - 550.0) / 120.0) ** 2))
        tilt = 1.0 + (drift - 1.0) * (self.WAVELENGTH_NM - 380.0) / 400.0
        file = f"spectra/{step.lamp}/{step.purpose}-{step.index:03d}.csv"
        return SpectrumMeasured(
            self.time_s, file, self.WAVELENGTH_NM, shape * tilt, "W/(sr·m²·nm)", None
        )

    def measure_dark(self, step: MeasureDark) -> DarkMeasured:
        return DarkMeasured(self.time_s, "spectra/dark.csv", ())

    def wait(self, step: Wait) -> Waited:
        return Waited(self.time_s, step.seconds)

    def keep_lamp_timeline(self, step: KeepLampTimeline) -> Waited:
        return self.wait(step)

    def set_exposure(self, step: SetExposure) -> ExposureSet:
        return ExposureSet(step.exposure_s, step.exposure_s)

    def capture(self, step: Capture) -> FrameCaptured:
        model = self.config.dry_run
        ratio = step.exposure_s / model.direct_saturates_at_s
        saturated = 0.0 if ratio <= 1.0 else min(1.0, 0.5 * (1.0 - 1.0 / ratio))
        snr = model.band_snr_at_direct_saturation * math.sqrt(ratio)
        return self._frame(step, "scene", FrameStats(saturated, snr, 1000.0 * ratio))

    def dark_frame(self, step: DarkFrame) -> FrameCaptured:
        return self._frame(step, "dark", None)

    def _frame(
        self, step: Capture | DarkFrame, stream: str, stats: FrameStats | None
    ) -> FrameCaptured:
        file = f"frames/{step.lamp}/{stream}-{step.index:03d}.raw"
        return FrameCaptured(self.time_s, file, step.exposure_s, step.exposure_s, file, stats)


@dataclass(frozen=True)
class PlannedStep:
    """A step of the walked plan with its modelled start time and duration (s)."""

    step: AnyStep
    start_s: float
    duration_s: float


@dataclass
class DryRunReport:
    """What walking the plan found."""

    steps: list[PlannedStep] = field(default_factory=list)
    violations: list[LimitViolation] = field(default_factory=list)
    failure: PlanFailure | None = None

    @property
    def duration_s(self) -> float:
        """Modelled total duration."""
        return sum(p.duration_s for p in self.steps)

    def count(self, step_type: type[Step]) -> int:
        return sum(isinstance(p.step, step_type) for p in self.steps)

    def frames_per_lamp(self) -> dict[str, int]:
        """Modelled number of bracket frames per lamp."""
        counts: dict[str, int] = {}
        for planned in self.steps:
            if isinstance(planned.step, Capture):
                counts[planned.step.lamp] = counts.get(planned.step.lamp, 0) + 1
        return counts

    @property
    def ok(self) -> bool:
        return not self.violations and self.failure is None


def walk(plan: Plan, bench: ModelledBench) -> DryRunReport:
    """Drive ``plan`` with ``bench``'s modelled readings, recording every step; keys must be unique."""
    report = DryRunReport()
    seen: set[str] = set()
    try:
        step = next(plan)
        while True:
            if step.key in seen:
                raise PlanProtocolError(f"the plan yielded the key {step.key!r} twice")
            if len(seen) >= MAX_STEPS:
                raise PlanProtocolError(f"the plan yielded more than {MAX_STEPS} steps")
            seen.add(step.key)
            start_s = bench.time_s
            result = bench.respond(step)
            report.steps.append(PlannedStep(step, start_s, bench.time_s - start_s))
            step = plan.send(result)
    except StopIteration:
        pass
    except PlanFailure as failure:
        report.failure = failure
    finally:
        plan.close()
    return report


def dry_run(config: RigConfig) -> DryRunReport:
    """Static limits plus the standard plan walked with modelled readings."""
    report = walk(standard_capture(StandardCaptureArgs.from_config(config)), ModelledBench(config))
    report.violations = check_limits(config)
    return report
