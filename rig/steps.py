"""The vocabulary of plans: small frozen steps, and the typed results the runner sends back.

A plan (:mod:`rig.plan`) yields steps; the runner (:mod:`rig.runner`) executes each on the devices and
sends the result back into the plan, which may branch on it (warm-up, automatic bracketing). A dry
run (:mod:`rig.dryrun`) sends modelled results instead.

Every step has a stable, idempotent :attr:`Step.key` — the same plan with the same readings yields the
same keys — so a resumed session can tell which steps are done. Keys are ``/``-separated, built only
from lamp names (restricted by :data:`rig.config.LAMP_NAME_PATTERN`), fixed words and zero-padded
indices: ``lamp/LED-B3/scene/002``.

Results serialise to JSON for the session log (:meth:`StepResult.to_json`) and come back from it
(``from_json``) with everything the plan needs, so a plan can be re-driven from a log (resume, replay).
Spectrum values live in the session's CSV files, not in the log; ``from_json`` takes a loader for them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Never, Protocol, TypeVar, get_args

import numpy as np

from calib.core.arrays import FloatArray
from rig.analysis import FrameStats
from rig.errors import PlanProtocolError

JsonDict = dict[str, Any]
DeviceRole = Literal["spectrometer", "camera", "relays"]
SpectrumPurpose = Literal["warmup", "reference"]
SpectrometerBeam = Literal["lamp", "direct", "order0", "order1"]
"""Where the spectrometer looks: ``lamp`` its usual target (the lamps' warm-up and reference
spectra); for measuring the grating's efficiency, ``direct`` the slit with the grating sheet out of
its path, ``order0`` the slit straight through the sheet (the 0th-order beam), ``order1`` the
slit's 1st-order image through the sheet at the angle of a chosen wavelength."""
SpectrumLoader = Callable[[str], tuple[FloatArray, FloatArray]]
"""Reads a session-relative spectrum file into ``(wavelength_nm, values)``, both ``(n,)``."""


# --------------------------------------------------------------------------------------- results


@dataclass(frozen=True)
class StepResult:
    """What executing a step produced; sent back into the plan."""

    def to_json(self) -> JsonDict:
        """The result as JSON-able data for the step's log record."""
        return {
            field.name: _jsonable(getattr(self, field.name))
            for field in dataclasses.fields(self)
            if not isinstance(getattr(self, field.name), np.ndarray)
        }


def _jsonable(value: object) -> object:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    return value


@dataclass(frozen=True)
class RelayState(StepResult):
    """The relay board's channels (1..n) as read back after switching, at ``time_s`` (runner clock)."""

    time_s: float
    channels: tuple[bool, ...]

    @classmethod
    def from_json(cls, data: JsonDict) -> RelayState:
        return cls(float(data["time_s"]), tuple(bool(c) for c in data["channels"]))


@dataclass(frozen=True)
class SettingReadBack:
    """A camera setting: what was asked and what the camera reports afterwards."""

    name: str
    requested: str
    read_back: str


@dataclass(frozen=True)
class CameraReady(StepResult):
    """The camera after configuration: settings read back and its exposure range in seconds."""

    settings: tuple[SettingReadBack, ...]
    exposure_range_s: tuple[float, float]

    @classmethod
    def from_json(cls, data: JsonDict) -> CameraReady:
        low, high = data["exposure_range_s"]
        return cls(
            tuple(SettingReadBack(**item) for item in data["settings"]),
            (float(low), float(high)),
        )


@dataclass(frozen=True)
class SpectrometerReady(StepResult):
    """The spectrometer's integration time in ms (``None``: adaptive)."""

    exposure_ms: float | None

    @classmethod
    def from_json(cls, data: JsonDict) -> SpectrometerReady:
        value = data["exposure_ms"]
        return cls(None if value is None else float(value))


@dataclass(frozen=True, eq=False)
class SpectrumMeasured(StepResult):
    """One spectrum, stored in the session at ``file``.

    Parameters
    ----------
    time_s
        Runner-clock time at the end of the measurement.
    file
        Session-relative path of the CSV file.
    wavelength_nm, values
        Shape ``(n,)``: the spectrum as stored (negative values clipped to zero, see
        ``negative_clipped``).
    units
        The instrument's unit of ``values``.
    exposure_ms
        Integration time the instrument reports having used, if it says.
    negative_clipped
        How many values were negative (noise below zero) and stored as zero.
    """

    time_s: float
    file: str
    wavelength_nm: FloatArray
    values: FloatArray
    units: str
    exposure_ms: float | None
    negative_clipped: int = 0

    @classmethod
    def from_json(cls, data: JsonDict, load_spectrum: SpectrumLoader) -> SpectrumMeasured:
        wavelength_nm, values = load_spectrum(str(data["file"]))
        exposure = data.get("exposure_ms")
        return cls(
            float(data["time_s"]),
            str(data["file"]),
            wavelength_nm,
            values,
            str(data["units"]),
            None if exposure is None else float(exposure),
            int(data.get("negative_clipped", 0)),
        )


@dataclass(frozen=True)
class DarkMeasured(StepResult):
    """The spectrometer's dark spectra (lamps off), one per integration time, stored at ``file``.

    ``integration_ms`` lists the integration times, in the order of the file's value columns.
    """

    time_s: float
    file: str
    integration_ms: tuple[float, ...]

    @classmethod
    def from_json(cls, data: JsonDict) -> DarkMeasured:
        return cls(
            float(data["time_s"]),
            str(data["file"]),
            tuple(float(value) for value in data["integration_ms"]),
        )


@dataclass(frozen=True)
class SpectrometerAimed(StepResult):
    """The operator aimed the spectrometer (a manual action): confirmed at ``time_s`` after
    ``waited_s`` of waiting for the person (or the twin's hands)."""

    time_s: float
    waited_s: float

    @classmethod
    def from_json(cls, data: JsonDict) -> SpectrometerAimed:
        return cls(float(data["time_s"]), float(data["waited_s"]))


@dataclass(frozen=True)
class Waited(StepResult):
    """A wait that ended at ``time_s``; ``completed`` is false when a stop request cut it short."""

    time_s: float
    waited_s: float
    completed: bool = True

    @classmethod
    def from_json(cls, data: JsonDict) -> Waited:
        return cls(float(data["time_s"]), float(data["waited_s"]), bool(data["completed"]))


@dataclass(frozen=True)
class ExposureSet(StepResult):
    """The camera's exposure: what was asked and the nearest available value it read back (s)."""

    requested_s: float
    actual_s: float

    @classmethod
    def from_json(cls, data: JsonDict) -> ExposureSet:
        return cls(float(data["requested_s"]), float(data["actual_s"]))


@dataclass(frozen=True)
class FrameCaptured(StepResult):
    """A frame stored in the session at ``file``.

    ``exposure_s`` is the exposure the step asked for (as set and read back before the capture);
    ``reported_exposure_s`` is what the camera driver reports for the file. ``stats`` is ``None`` for
    dark frames, which are not analysed.
    """

    time_s: float
    file: str
    exposure_s: float
    reported_exposure_s: float
    camera_path: str
    stats: FrameStats | None = None

    @classmethod
    def from_json(cls, data: JsonDict) -> FrameCaptured:
        stats = data.get("stats")
        return cls(
            float(data["time_s"]),
            str(data["file"]),
            float(data["exposure_s"]),
            float(data["reported_exposure_s"]),
            str(data["camera_path"]),
            None if stats is None else FrameStats(**stats),
        )


# ----------------------------------------------------------------------------------------- steps


@dataclass(frozen=True)
class Step:
    """One thing for the runner to do.

    Class attributes
    ----------------
    device
        The device the step talks to (``None``: no device, e.g. a wait).
    retry_safe
        Whether repeating the step after a *retryable* device error is harmless.
    result_type
        The :class:`StepResult` subclass the runner sends back.
    """

    device: ClassVar[DeviceRole | None] = None
    retry_safe: ClassVar[bool] = True
    result_type: ClassVar[type[StepResult]] = StepResult

    @property
    def key(self) -> str:
        """Stable, idempotent identifier of this step within a plan."""
        raise NotImplementedError

    @property
    def lamp_name(self) -> str | None:
        """The lamp this step belongs to, if any."""
        return getattr(self, "lamp", None)

    def describe(self) -> str:
        """A short human-readable description."""
        raise NotImplementedError

    def params(self) -> JsonDict:
        """The step's fields as JSON-able data for the log."""
        return {f.name: _jsonable(getattr(self, f.name)) for f in dataclasses.fields(self)}


@dataclass(frozen=True)
class AllLampsOff(Step):
    """Switch every relay channel off and read the board back."""

    device = "relays"
    result_type = RelayState
    stage: Literal["start"] = "start"

    @property
    def key(self) -> str:
        return f"{self.stage}/all-lamps-off"

    def describe(self) -> str:
        return "switch every lamp off"


@dataclass(frozen=True)
class ConfigureCamera(Step):
    """Apply camera settings (``(widget, value)`` pairs) and read back the exposure range."""

    device = "camera"
    result_type = CameraReady
    settings: tuple[tuple[str, str], ...] = ()

    @property
    def key(self) -> str:
        return "start/camera"

    def describe(self) -> str:
        shown = ", ".join(f"{name}={value}" for name, value in self.settings)
        return f"configure the camera ({shown or 'no settings'})"


@dataclass(frozen=True)
class ConfigureSpectrometer(Step):
    """Set the spectrometer's integration time (``None``: adaptive)."""

    device = "spectrometer"
    result_type = SpectrometerReady
    exposure_ms: float | None = None

    @property
    def key(self) -> str:
        return "start/spectrometer"

    def describe(self) -> str:
        shown = "adaptive" if self.exposure_ms is None else f"{self.exposure_ms:g} ms"
        return f"configure the spectrometer (integration {shown})"


@dataclass(frozen=True)
class MeasureDark(Step):
    """Measure the spectrometer's dark spectra with every lamp off (the runner checks the board).

    Only for spectrometers that subtract a dark of their own measuring (an Ocean spectrometer);
    set-up: a resumed run measures it again before its first spectrum.
    """

    device = "spectrometer"
    result_type = DarkMeasured

    @property
    def key(self) -> str:
        return "start/spectrometer-dark"

    def describe(self) -> str:
        return "measure the spectrometer's dark spectrum (every lamp off)"


@dataclass(frozen=True)
class SwitchLamp(Step):
    """Switch one lamp's relay channel on or off and read the board back."""

    device = "relays"
    result_type = RelayState
    lamp: str
    channel: int
    on: bool

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/switch-{'on' if self.on else 'off'}"

    def describe(self) -> str:
        return f"switch {self.lamp} {'on' if self.on else 'off'} (relay channel {self.channel})"


@dataclass(frozen=True)
class MeasureSpectrum(Step):
    """Measure the lit lamp's spectrum (during warm-up, or as a reference after it)."""

    device = "spectrometer"
    result_type = SpectrumMeasured
    lamp: str
    purpose: SpectrumPurpose
    index: int

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/{self.purpose}/{self.index:03d}"

    def describe(self) -> str:
        what = "warm-up spectrum" if self.purpose == "warmup" else "reference spectrum"
        return f"{self.lamp}: {what} {self.index + 1}"


def beam_target(beam: SpectrometerBeam, centre_nm: float | None) -> str:
    """The aim as a key word: ``order1-550nm`` for the 1st order at 550 nm, else the beam."""
    if beam == "order1":
        if centre_nm is None:
            raise PlanProtocolError("an order1 aim needs the wavelength at the field's centre")
        return f"order1-{centre_nm:.0f}nm"
    return beam


#: What the operator is asked to do for each beam (``{angle}`` and ``{centre}`` filled in).
AIM_INSTRUCTIONS: dict[SpectrometerBeam, str] = {
    "lamp": "aim the spectrometer back at its usual target, where it measured the lamps' "
    "reference spectra, and focus it there",
    "direct": "aim the spectrometer at the slit with the grating sheet OUT of its path (slide the "
    "sheet aside or look past its edge), focused on the slit, the slit's image in the middle of "
    "the measuring field",
    "order0": "put the same grating sheet back in front of the spectrometer, in the same "
    "orientation, and aim straight at the slit through it (the 0th-order beam), focused on the "
    "slit, its image in the middle of the measuring field",
    "order1": "turn the spectrometer by {angle:.2f}° from the 0th-order beam towards the side "
    "where the camera sees the first-order spectrum, about the sheet (do not move the sheet), so "
    "that the slit's 1st-order image at {centre:.0f} nm lies in the middle of the measuring field",
}


@dataclass(frozen=True)
class AimSpectrometer(Step):
    """A manual action: the operator aims the spectrometer at a beam and confirms.

    The rig has no rotation stage among its drivers, so a person re-aims the spectrometer; the
    runner asks the station's operator (:mod:`rig.operator`) and waits. ``angle_deg`` is the
    turn from the 0th-order beam (order1 only), computed from the sheet's line density.
    ``run`` is 0 in a plan; a resumed run that must aim again before a measurement numbers its
    own aim steps with the run (the spectrometer may have been moved while the rig was down).
    """

    result_type = SpectrometerAimed
    lamp: str
    beam: SpectrometerBeam
    centre_nm: float | None = None
    angle_deg: float = 0.0
    run: int = 0

    @property
    def target(self) -> str:
        return beam_target(self.beam, self.centre_nm)

    @property
    def key(self) -> str:
        if self.run:
            return f"lamp/{self.lamp}/resume/{self.run:03d}/aim-{self.target}"
        return f"lamp/{self.lamp}/grating/aim-{self.target}"

    def instruction(self) -> str:
        """What the operator is asked to do, in words."""
        return AIM_INSTRUCTIONS[self.beam].format(
            angle=self.angle_deg, centre=self.centre_nm or 0.0
        )

    def describe(self) -> str:
        where = {
            "lamp": "its usual target",
            "direct": "the slit without the sheet",
            "order0": "the 0th-order beam",
            "order1": f"the 1st-order beam at {self.centre_nm or 0.0:.0f} nm "
            f"({self.angle_deg:.2f}° from the 0th order)",
        }[self.beam]
        return f"{self.lamp}: OPERATOR aims the spectrometer at {where}"


@dataclass(frozen=True)
class MeasureBeam(Step):
    """Measure the lit lamp's spectrum in one beam through the grating sheet (repeat ``index``).

    The spectrometer must have been aimed there (:class:`AimSpectrometer`); the spectrum is stored
    like any other, and the step's record says which beam it measured.
    """

    device = "spectrometer"
    result_type = SpectrumMeasured
    lamp: str
    beam: SpectrometerBeam
    centre_nm: float | None
    index: int

    @property
    def target(self) -> str:
        return beam_target(self.beam, self.centre_nm)

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/grating/{self.target}/{self.index:03d}"

    @property
    def file(self) -> str:
        """Where its spectrum is stored, relative to the session."""
        return f"spectra/{self.lamp}/grating-{self.target}-{self.index:03d}.csv"

    def describe(self) -> str:
        return f"{self.lamp}: spectrum in the {self.target} beam {self.index + 1}"


@dataclass(frozen=True)
class Wait(Step):
    """Let ``seconds`` pass before the warm-up spectrum with the same index."""

    result_type = Waited
    lamp: str
    index: int
    seconds: float

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/warmup/{self.index:03d}/wait"

    def describe(self) -> str:
        return f"{self.lamp}: wait {self.seconds:g} s for the lamp to settle"


@dataclass(frozen=True)
class KeepLampTimeline(Wait):
    """On resume: let the time of the reused steps pass, so the re-lit lamp is as old as it was.

    ``index`` is the run number. The lamp was switched on and warmed up again; the reused frames of
    its bracket were taken that much later after switch-on, and the next frame must be too.
    """

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/resume/{self.index:03d}/wait"

    def describe(self) -> str:
        return f"{self.lamp}: wait {self.seconds:g} s, the time the reused frames took"


@dataclass(frozen=True)
class SetExposure(Step):
    """Set the camera's exposure before frame ``index`` of a scene bracket or of the dark frames."""

    device = "camera"
    result_type = ExposureSet
    lamp: str
    stream: Literal["scene", "dark"]
    index: int
    exposure_s: float

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/{self.stream}/{self.index:03d}/exposure"

    def describe(self) -> str:
        return f"{self.lamp}: set exposure {format_exposure(self.exposure_s)}"


@dataclass(frozen=True)
class Capture(Step):
    """Capture frame ``index`` of a lamp's HDR bracket (direct spot + first-order band) and analyse it."""

    device = "camera"
    result_type = FrameCaptured
    lamp: str
    index: int
    exposure_s: float

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/scene/{self.index:03d}"

    def describe(self) -> str:
        return f"{self.lamp}: bracket frame {self.index + 1} at {format_exposure(self.exposure_s)}"


@dataclass(frozen=True)
class DarkFrame(Step):
    """Capture dark frame ``index`` of ``count`` for a lamp's bracket, after checking every lamp is off."""

    device = "camera"
    result_type = FrameCaptured
    lamp: str
    index: int
    count: int
    exposure_s: float

    @property
    def key(self) -> str:
        return f"lamp/{self.lamp}/dark/{self.index:03d}"

    def describe(self) -> str:
        return (
            f"{self.lamp}: dark frame {self.index + 1} of {self.count} at "
            f"{format_exposure(self.exposure_s)}"
        )


AnyStep = (
    AllLampsOff
    | ConfigureCamera
    | ConfigureSpectrometer
    | SwitchLamp
    | MeasureSpectrum
    | MeasureDark
    | AimSpectrometer
    | MeasureBeam
    | Wait
    | KeepLampTimeline
    | SetExposure
    | Capture
    | DarkFrame
)
"""Every step of the vocabulary: what a plan may yield. A new step type is added here, to
:class:`StepHandlers` and to :func:`interpret`; mypy then names every interpreter that lacks it."""

STEP_TYPES: dict[str, type[AnyStep]] = {cls.__name__: cls for cls in get_args(AnyStep)}
"""Every step type by its class name, as written in the log's ``action`` field."""


# ---------------------------------------------------------------------------------- interpreting

ResultT_co = TypeVar("ResultT_co", covariant=True)


class StepHandlers(Protocol[ResultT_co]):
    """An interpreter of the vocabulary: one method per step type.

    The runner executes steps on the devices (:class:`rig.runner.Runner`), the dry run models
    their duration and readings (:class:`rig.dryrun.StepCostModel`, :class:`rig.dryrun.ModelledBench`)
    and resume decides what a new run must do again (:class:`rig.resume.ResumeRules`). Each
    derives from this protocol, so mypy refuses to instantiate one that lacks a step type; every
    step reaches its handler through :func:`interpret`, the one dispatch (Bluesky's RunEngine
    command table).
    """

    def all_lamps_off(self, step: AllLampsOff) -> ResultT_co: ...

    def configure_camera(self, step: ConfigureCamera) -> ResultT_co: ...

    def configure_spectrometer(self, step: ConfigureSpectrometer) -> ResultT_co: ...

    def switch_lamp(self, step: SwitchLamp) -> ResultT_co: ...

    def measure_spectrum(self, step: MeasureSpectrum) -> ResultT_co: ...

    def measure_dark(self, step: MeasureDark) -> ResultT_co: ...

    def aim_spectrometer(self, step: AimSpectrometer) -> ResultT_co: ...

    def measure_beam(self, step: MeasureBeam) -> ResultT_co: ...

    def wait(self, step: Wait) -> ResultT_co: ...

    def keep_lamp_timeline(self, step: KeepLampTimeline) -> ResultT_co: ...

    def set_exposure(self, step: SetExposure) -> ResultT_co: ...

    def capture(self, step: Capture) -> ResultT_co: ...

    def dark_frame(self, step: DarkFrame) -> ResultT_co: ...


ResultT = TypeVar("ResultT")


def interpret(step: AnyStep, handlers: StepHandlers[ResultT]) -> ResultT:
    """Hand ``step`` to the ``handlers`` method of its type: the vocabulary's one dispatch.

    Raises
    ------
    rig.errors.PlanProtocolError
        ``step`` is not of a type of the vocabulary (a plan yielded something else).
    """
    match step:
        case AllLampsOff():
            return handlers.all_lamps_off(step)
        case ConfigureCamera():
            return handlers.configure_camera(step)
        case ConfigureSpectrometer():
            return handlers.configure_spectrometer(step)
        case SwitchLamp():
            return handlers.switch_lamp(step)
        case MeasureSpectrum():
            return handlers.measure_spectrum(step)
        case MeasureDark():
            return handlers.measure_dark(step)
        case AimSpectrometer():
            return handlers.aim_spectrometer(step)
        case MeasureBeam():
            return handlers.measure_beam(step)
        case KeepLampTimeline():  # before Wait, its base class
            return handlers.keep_lamp_timeline(step)
        case Wait():
            return handlers.wait(step)
        case SetExposure():
            return handlers.set_exposure(step)
        case Capture():
            return handlers.capture(step)
        case DarkFrame():
            return handlers.dark_frame(step)
        case _:
            raise _not_in_vocabulary(step)


def _not_in_vocabulary(step: Never) -> PlanProtocolError:
    """The error for a step of no known type. Typed ``Never``: mypy refuses the call unless every
    member of :data:`AnyStep` was matched before it (at run time, a plan bug)."""
    return PlanProtocolError(
        f"{type(step).__name__} is not a step of the vocabulary "
        f"(known: {', '.join(sorted(STEP_TYPES))})"
    )


def step_from_record(action: str, params: JsonDict) -> AnyStep:
    """Rebuild a step from its log record's ``action`` and ``params``."""
    step_type = STEP_TYPES.get(action)
    if step_type is None:
        raise ValueError(f"unknown step action {action!r}; known: {', '.join(sorted(STEP_TYPES))}")
    values: dict[str, Any] = {
        key: tuple(tuple(v) if isinstance(v, list) else v for v in value)
        if isinstance(value, list)
        else value
        for key, value in params.items()
    }
    return step_type(**values)


def result_from_json(
    step: Step, data: JsonDict, load_spectrum: SpectrumLoader | None = None
) -> StepResult:
    """Rebuild the result of ``step`` from its log record (``load_spectrum`` reads spectrum files)."""
    result_type = step.result_type
    if result_type is SpectrumMeasured:
        if load_spectrum is None:
            raise ValueError(f"{step.key}: a spectrum loader is needed to rebuild its result")
        return SpectrumMeasured.from_json(data, load_spectrum)
    from_json: Callable[[JsonDict], StepResult] = getattr(result_type, "from_json")  # noqa: B009
    return from_json(data)


def format_exposure(exposure_s: float) -> str:
    """``1/125 s`` below a tenth of a second, ``0.25 s`` or ``2.5 s`` above."""
    if exposure_s < 0.1:
        return f"1/{1 / exposure_s:.4g} s"
    return f"{exposure_s:.4g} s"
