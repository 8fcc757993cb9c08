"""Plans: generators of steps that describe a capture, and branch on the readings sent back.

A plan never touches a device (and never imports a driver). It yields :mod:`rig.steps` steps; whoever
walks it — the runner with real devices, the dry run with modelled readings, a test with scripted
ones — sends each step's result back with ``plan.send(result)``::

    plan = standard_capture(args)
    step = next(plan)
    while True:
        result = execute(step)
        step = plan.send(result)   # StopIteration when the plan is done

The standard plan: every lamp off, camera and spectrometer set up (and, for a spectrometer that
subtracts its own dark, its dark spectrum measured with the lamps off); then per lamp: switch on; measure spectra every ``interval_s`` until consecutive spectra
differ by less than the tolerance (or fail at the warm-up timeout); measure ``repeats`` reference
spectra; capture an automatically extended HDR bracket of the direct + diffracted scene; switch off;
take dark frames at the bracket's exposures. When ``measure_grating`` is configured, its lamp's
reference spectra are followed by the grating's beams (:func:`measure_grating_beams`): the operator
aims the spectrometer at the slit without the sheet, through it straight on and at the 1st order
band by band, a few spectra in each, then back at its usual target. A plan fails by raising a :class:`rig.errors.PlanFailure`
with a reason a person can act on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from typing import Any, TypeVar

import numpy as np
from pydantic import Field

from rig.analysis import FrameStats
from rig.config import (
    CameraSettings,
    GratingMeasurement,
    HdrPolicy,
    LampConfig,
    RigConfig,
    SpectrumPolicy,
    StrictModel,
)
from rig.errors import (
    BeamNotFound,
    BracketImpossible,
    LampDark,
    LampNotStable,
    LimitsExceeded,
    PlanProtocolError,
    WrongFrameFormat,
)
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
    JsonDict,
    MeasureBeam,
    MeasureDark,
    MeasureSpectrum,
    RelayState,
    SetExposure,
    SpectrometerAimed,
    SpectrometerBeam,
    SpectrometerReady,
    SpectrumMeasured,
    StepResult,
    SwitchLamp,
    Wait,
    Waited,
    format_exposure,
)

Plan = Generator[AnyStep, StepResult, None]
"""A plan: yields steps, receives each step's result, returns nothing."""

ResultT = TypeVar("ResultT", bound=StepResult)

#: Relative tolerance within which two exposure times count as the same camera setting.
SAME_EXPOSURE_RTOL = 0.01

#: Frame suffixes that are not RAW data.
NOT_RAW_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".heic")

#: Safety margin on the exposure predicted to reach the band SNR target.
SNR_PREDICTION_MARGIN = 1.25


def run_step(step: AnyStep, expected: type[ResultT]) -> Generator[AnyStep, StepResult, ResultT]:
    """Yield ``step`` and return its result, checked to be of the ``expected`` type."""
    result = yield step
    if not isinstance(result, expected):
        raise PlanProtocolError(
            f"{step.key}: expected a {expected.__name__} back, got {type(result).__name__}"
        )
    return result


def relative_change(previous: SpectrumMeasured, current: SpectrumMeasured) -> float:
    """Relative L2 change between two spectra, ``‖current − previous‖ / ‖current‖`` (dimensionless).

    ``previous`` is interpolated onto ``current``'s wavelengths when the axes differ; an all-zero
    ``current`` gives ``inf``.
    """
    before = previous.values
    if previous.wavelength_nm.shape != current.wavelength_nm.shape or not np.allclose(
        previous.wavelength_nm, current.wavelength_nm
    ):
        before = np.interp(current.wavelength_nm, previous.wavelength_nm, previous.values)
    norm = float(np.linalg.norm(current.values))
    if norm == 0.0:
        return math.inf
    return float(np.linalg.norm(current.values - before)) / norm


# ----------------------------------------------------------------------------------- plan pieces


def check_relay_channels(lamps: list[LampConfig], state: RelayState) -> None:
    """Raise :class:`LimitsExceeded` when a lamp's channel is not on the board that answered."""
    n_channels = len(state.channels)
    missing = [
        f"{lamp.name} on channel {lamp.channel}" for lamp in lamps if lamp.channel > n_channels
    ]
    if missing:
        raise LimitsExceeded(
            f"the relay board has {n_channels} channels, but {', '.join(missing)}; "
            "fix lamps[].channel or use a larger board",
            key="start/all-lamps-off",
        )


def exposure_limits(hdr: HdrPolicy, camera: CameraReady) -> tuple[float, float]:
    """The bracket's allowed exposure range, after checking the HDR policy against the camera's range."""
    low, high = camera.exposure_range_s
    problems = []
    if hdr.min_exposure_s < low * (1 - SAME_EXPOSURE_RTOL):
        problems.append(
            f"hdr.min_exposure_s = {format_exposure(hdr.min_exposure_s)} is shorter than the "
            f"camera's shortest {format_exposure(low)}"
        )
    if hdr.max_exposure_s > high * (1 + SAME_EXPOSURE_RTOL):
        problems.append(
            f"hdr.max_exposure_s = {format_exposure(hdr.max_exposure_s)} is longer than the "
            f"camera's longest {format_exposure(high)}"
        )
    if problems:
        raise LimitsExceeded("; ".join(problems), key="start/camera")
    return max(hdr.min_exposure_s, low), min(hdr.max_exposure_s, high)


def wait_until_stable(
    lamp: LampConfig, switched_on_s: float
) -> Generator[AnyStep, StepResult, None]:
    """Measure spectra ``interval_s`` apart until ``stable_pairs`` consecutive changes are below tolerance.

    Raises
    ------
    LampDark
        When the first spectrum is all zeros (the lamp did not light).
    LampNotStable
        When the lamp is not stable ``timeout_s`` after ``switched_on_s``.
    """
    policy = lamp.warmup
    index = 0
    previous = yield from run_step(MeasureSpectrum(lamp.name, "warmup", index), SpectrumMeasured)
    if not np.any(previous.values > 0):
        raise LampDark(
            f"{lamp.name} gives no light after switching relay channel {lamp.channel} on (the "
            "spectrum is all zeros): check the lamp, its power supply and the relay wiring",
            key=MeasureSpectrum(lamp.name, "warmup", index).key,
        )
    stable_in_a_row = 0
    changes: list[float] = []
    while True:
        elapsed_s = previous.time_s - switched_on_s
        if elapsed_s + policy.interval_s > policy.timeout_s:
            shown = ", ".join(f"{c:.2%}" for c in changes[-3:]) or "none measured"
            raise LampNotStable(
                f"{lamp.name} did not settle within warmup.timeout_s = {policy.timeout_s:g} s: "
                f"the last changes between spectra {policy.interval_s:g} s apart were {shown}, "
                f"tolerance {policy.tolerance:.2%} for {policy.stable_pairs} in a row; check the "
                "lamp, or raise lamps[].warmup.timeout_s or .tolerance",
                key=MeasureSpectrum(lamp.name, "warmup", index).key,
            )
        index += 1
        yield from run_step(Wait(lamp.name, index, policy.interval_s), Waited)
        current = yield from run_step(MeasureSpectrum(lamp.name, "warmup", index), SpectrumMeasured)
        change = relative_change(previous, current)
        changes.append(change)
        stable_in_a_row = stable_in_a_row + 1 if change < policy.tolerance else 0
        if stable_in_a_row >= policy.stable_pairs:
            return
        previous = current


def _check_raw(frame: FrameCaptured, camera: CameraSettings, key: str) -> None:
    if camera.require_raw and frame.file.lower().endswith(NOT_RAW_SUFFIXES):
        raise WrongFrameFormat(
            f"the camera delivered {frame.camera_path!r}, not a RAW file: set camera.image_format "
            "to the camera's RAW choice (or camera.require_raw: false to accept it)",
            key=key,
        )


def _too_bright(stats: FrameStats, hdr: HdrPolicy) -> tuple[str, str] | None:
    """What in the shortest frame asks for a shorter one, and its allowance; ``None`` if nothing.

    The direct spot's saturated fraction (``hdr.max_direct_saturated_fraction``), and the spot's
    and the band's pixels the HDR merge cannot use (``hdr.max_unmergeable_fraction``): the
    estimator refuses a spot or a band with a pixel no frame of the bracket gives the merge.
    """
    allowed = hdr.max_unmergeable_fraction
    if stats.direct_saturated_fraction > hdr.max_direct_saturated_fraction:
        return (
            f"{stats.direct_saturated_fraction:.2%} of the direct spot is saturated",
            f"hdr.max_direct_saturated_fraction = {hdr.max_direct_saturated_fraction:.2%}",
        )
    for part, fraction in (
        ("direct spot", stats.direct_unmergeable_fraction),
        ("first-order band", stats.band_unmergeable_fraction),
    ):
        if fraction > allowed:
            return (
                f"{fraction:.2%} of the {part} is saturated or too near clipping for the HDR "
                "merge to use",
                f"hdr.max_unmergeable_fraction = {allowed:.2%}",
            )
    return None


def _next_exposure(
    frames: list[FrameCaptured], hdr: HdrPolicy, limits: tuple[float, float], lamp: str
) -> float | None:
    """The next exposure to extend the bracket with, or ``None`` when the bracket is complete."""
    low, high = limits
    by_exposure = sorted(frames, key=lambda f: f.exposure_s)
    shortest, longest = by_exposure[0], by_exposure[-1]
    assert shortest.stats is not None and longest.stats is not None
    too_bright = _too_bright(shortest.stats, hdr)
    snr = longest.stats.band_snr
    need_shorter = too_bright is not None
    need_longer = snr < hdr.min_band_snr
    if not need_shorter and not need_longer:
        return None
    if len(frames) >= hdr.max_frames:
        state = too_bright[0] if too_bright else "neither spot nor band too bright"
        raise BracketImpossible(
            f"{lamp}: the bracket needs more than hdr.max_frames = {hdr.max_frames} frames "
            f"(shortest {format_exposure(shortest.exposure_s)}: {state}; "
            f"longest {format_exposure(longest.exposure_s)}: band SNR {snr:.3g}); "
            "raise hdr.max_frames or hdr.step_stops"
        )
    step_factor: float = 2.0**hdr.step_stops
    if too_bright is not None:
        if shortest.exposure_s <= low * (1 + SAME_EXPOSURE_RTOL):
            raise BracketImpossible(
                f"{lamp}: {too_bright[0]} even at the shortest allowed exposure "
                f"{format_exposure(low)} (allowed: {too_bright[1]}); dim the lamp, stop the "
                "aperture down, narrow the slit or add a neutral-density filter"
            )
        return max(low, shortest.exposure_s / step_factor)
    if longest.exposure_s >= high * (1 - SAME_EXPOSURE_RTOL):
        raise BracketImpossible(
            f"{lamp}: the first-order band reaches SNR {snr:.3g} at the longest allowed exposure "
            f"{format_exposure(high)}, below hdr.min_band_snr = {hdr.min_band_snr:g}; raise "
            "hdr.max_exposure_s, open the aperture, widen the slit or raise the ISO"
        )
    # SNR grows at least as √exposure (shot-noise limit), so (target/snr)² is enough; never jump
    # more than one bracket step (the HDR merge needs overlapping frames) or less than a quarter step.
    predicted = (hdr.min_band_snr / snr) ** 2 * SNR_PREDICTION_MARGIN if snr > 0 else math.inf
    quarter_step: float = step_factor**0.25
    factor = min(step_factor, max(predicted, quarter_step))
    return min(high, longest.exposure_s * factor)


def auto_bracket(
    lamp: LampConfig, hdr: HdrPolicy, limits: tuple[float, float], camera: CameraSettings
) -> Generator[AnyStep, StepResult, list[FrameCaptured]]:
    """Capture frames until the bracket satisfies the HDR policy; return them by increasing exposure.

    Starts at ``hdr.start_exposure_s`` (default: the geometric mean of ``limits``). While the shortest
    frame saturates the direct spot beyond ``hdr.max_direct_saturated_fraction``, or leaves more than
    ``hdr.max_unmergeable_fraction`` of the spot or the band unusable to the HDR merge, it adds a frame
    ``hdr.step_stops`` shorter; then, while the longest frame's band SNR is below
    ``hdr.min_band_snr``, a longer one (the exposure predicted to reach the target, at most one step
    longer). Bounded by ``limits`` (s) and ``hdr.max_frames``.

    Raises
    ------
    BracketImpossible
        When a limit or the frame budget is reached first, or the camera cannot set an exposure
        beyond the bracket's current end.
    """
    low, high = limits
    start = hdr.start_exposure_s if hdr.start_exposure_s is not None else math.sqrt(low * high)
    request: float | None = min(high, max(low, start))
    frames: list[FrameCaptured] = []
    while request is not None:
        index = len(frames)
        exposure = yield from run_step(SetExposure(lamp.name, "scene", index, request), ExposureSet)
        actual = exposure.actual_s
        repeated = [
            f for f in frames if math.isclose(f.exposure_s, actual, rel_tol=SAME_EXPOSURE_RTOL)
        ]
        if repeated:
            raise BracketImpossible(
                f"{lamp.name}: asked the camera for {format_exposure(request)} to extend the "
                f"bracket, but it set {format_exposure(actual)}, which the bracket already has; "
                "the camera offers no exposure between them: raise hdr.step_stops"
            )
        capture = Capture(lamp.name, index, actual)
        frame = yield from run_step(capture, FrameCaptured)
        _check_raw(frame, camera, capture.key)
        if frame.stats is None:
            raise PlanProtocolError(f"{capture.key}: a scene frame came back without statistics")
        frames.append(frame)
        request = _next_exposure(frames, hdr, limits, lamp.name)
    return sorted(frames, key=lambda f: f.exposure_s)


def dark_frames(
    lamp: LampConfig, exposures_s: list[float], per_exposure: int
) -> Generator[AnyStep, StepResult, None]:
    """``per_exposure`` dark frames at each exposure of the bracket (lamps off), shortest first."""
    count = len(exposures_s) * per_exposure
    index = 0
    for exposure_s in exposures_s:
        actual = exposure_s
        for repeat in range(per_exposure):
            if repeat == 0:
                exposure = yield from run_step(
                    SetExposure(lamp.name, "dark", index, exposure_s), ExposureSet
                )
                actual = exposure.actual_s
            yield from run_step(DarkFrame(lamp.name, index, count, actual), FrameCaptured)
            index += 1


#: The 1st-order aims step by this fraction of the band the spectrometer's field sees: a band's
#: edges are blurred by the spectrometer's bandwidth (PR-655: 8 nm) and by the aim's error, so only
#: its core is used, and the cores of neighbouring aims overlap.
AIM_STEP_FRACTION = 0.5


def first_order_aims(measure: GratingMeasurement) -> list[tuple[float, float]]:
    """``(centre_nm, angle_deg)`` of each 1st-order aim covering ``measure.range_nm``.

    At normal incidence the 1st order of ``λ`` leaves at ``θ = asin(λ/d)``; a field of ``F``
    radians sees ``d cos θ · F`` nm around it. Aims start half a step inside the range and step
    by :data:`AIM_STEP_FRACTION` of that band until the range's end is inside one.
    """
    spacing_nm = 1e6 / measure.grooves_per_mm
    field_rad = math.radians(measure.field_deg)
    low, high = measure.range_nm

    def step_nm(centre_nm: float) -> float:
        cos_theta = math.sqrt(1.0 - (centre_nm / spacing_nm) ** 2)
        return spacing_nm * cos_theta * field_rad * AIM_STEP_FRACTION

    aims = []
    centre = low + step_nm(low) / 2.0
    while True:
        centre = round(min(centre, high), 1)
        aims.append((centre, math.degrees(math.asin(centre / spacing_nm))))
        if centre + step_nm(centre) / 2.0 >= high:
            return aims
        centre += step_nm(centre)


def _beam_spectra(
    lamp: LampConfig,
    aim: AimSpectrometer,
    repeats: int,
) -> Generator[AnyStep, StepResult, None]:
    """Aim, then ``repeats`` spectra in that beam; no light at all is a :class:`BeamNotFound`."""
    yield from run_step(aim, SpectrometerAimed)
    for index in range(repeats):
        step = MeasureBeam(lamp.name, aim.beam, aim.centre_nm, index)
        spectrum = yield from run_step(step, SpectrumMeasured)
        if index == 0 and not np.any(spectrum.values > 0):
            raise BeamNotFound(
                f"{lamp.name}: the spectrometer saw no light in the {step.target} beam; check "
                f"that it is aimed as asked ({aim.instruction()}), that the lamp is on, and "
                "that measure_grating.grooves_per_mm is the sheet's",
                key=step.key,
            )


def measure_grating_beams(
    lamp: LampConfig, measure: GratingMeasurement
) -> Generator[AnyStep, StepResult, None]:
    """The grating's beams with ``lamp`` lit: direct, 0th order, the 1st order band by band, then
    the spectrometer back at its usual target (see :class:`rig.config.GratingMeasurement`)."""
    beams: list[tuple[SpectrometerBeam, float | None, float]] = [
        ("direct", None, 0.0),
        ("order0", None, 0.0),
        *(("order1", centre, angle) for centre, angle in first_order_aims(measure)),
    ]
    for beam, centre_nm, angle_deg in beams:
        aim = AimSpectrometer(lamp.name, beam, centre_nm, round(angle_deg, 3))
        yield from _beam_spectra(lamp, aim, measure.repeats)
    yield from run_step(AimSpectrometer(lamp.name, "lamp"), SpectrometerAimed)


# ---------------------------------------------------------------------------------- standard plan


class StandardCaptureArgs(StrictModel):
    """The arguments of :func:`standard_capture`, recorded in the session's start record."""

    lamps: list[LampConfig] = Field(min_length=1)
    camera: CameraSettings
    spectrum: SpectrumPolicy
    hdr: HdrPolicy
    dark_frames: int = Field(ge=0)
    spectrometer_dark: bool = False
    measure_grating: GratingMeasurement | None = None

    @classmethod
    def from_config(cls, config: RigConfig) -> StandardCaptureArgs:
        return cls(
            lamps=config.lamps,
            camera=config.camera,
            spectrum=config.spectrum,
            hdr=config.hdr,
            dark_frames=config.dark_frames,
            spectrometer_dark=config.devices.spectrometer_takes_dark,
            measure_grating=config.measure_grating,
        )


def standard_capture(args: StandardCaptureArgs) -> Plan:
    """The standard measurement: every lamp in turn, warmed up, measured and bracketed, then darks.

    Raises
    ------
    LimitsExceeded
        Before any lamp is switched on, when a lamp's relay channel is not on the board or the HDR
        range exceeds the camera's.
    LampDark, LampNotStable, BracketImpossible, WrongFrameFormat, BeamNotFound
        When the readings show the measurement cannot succeed.
    """
    relays = yield from run_step(AllLampsOff(), RelayState)
    check_relay_channels(args.lamps, relays)
    camera = yield from run_step(ConfigureCamera(args.camera.setting_items()), CameraReady)
    limits = exposure_limits(args.hdr, camera)
    yield from run_step(ConfigureSpectrometer(args.spectrum.exposure_ms), SpectrometerReady)
    if args.spectrometer_dark:
        yield from run_step(MeasureDark(), DarkMeasured)
    for lamp in args.lamps:
        switched = yield from run_step(SwitchLamp(lamp.name, lamp.channel, True), RelayState)
        yield from wait_until_stable(lamp, switched.time_s)
        for repeat in range(args.spectrum.repeats):
            yield from run_step(MeasureSpectrum(lamp.name, "reference", repeat), SpectrumMeasured)
        if args.measure_grating is not None and args.measure_grating.lamp == lamp.name:
            yield from measure_grating_beams(lamp, args.measure_grating)
        bracket = yield from auto_bracket(lamp, args.hdr, limits, args.camera)
        yield from run_step(SwitchLamp(lamp.name, lamp.channel, False), RelayState)
        yield from dark_frames(lamp, [f.exposure_s for f in bracket], args.dark_frames)


PlanFactory = Callable[[JsonDict], Plan]


def _standard_capture_from_json(args: JsonDict) -> Plan:
    return standard_capture(StandardCaptureArgs.model_validate(args))


PLANS: dict[str, PlanFactory] = {"standard_capture": _standard_capture_from_json}
"""Plans by the name recorded in a session's start record; each rebuilds from its recorded args."""


def build_plan(name: str, args: dict[str, Any]) -> Plan:
    """Rebuild a recorded plan from its name and JSON arguments (resume, replay)."""
    factory = PLANS.get(name)
    if factory is None:
        raise PlanProtocolError(f"unknown plan {name!r}; known plans: {', '.join(sorted(PLANS))}")
    return factory(args)
