"""What the digital twin is made of, as plain typed values, and how it is read from configuration data.

``mocks`` never imports ``rig`` (the layering), so the twin is configured with plain data: the rig's
configuration dumped to JSON-able values (``RigConfig.model_dump(mode="json")``). The rig validates
that data against its own schema (``rig.config``: the ``twin`` device models, with their defaults
and error messages); :meth:`TwinSpec.from_config_data` only maps it onto the types below and
refuses what does not fit with a message naming the field. Tests build :class:`TwinSpec` directly.

Lamp defaults per kind (:data:`LAMP_KIND_DEFAULTS`): an LED starts a few percent bright and bluish
and settles within a minute or two as its junction warms; a fluorescent tube starts dim and
greenish and takes minutes; a halogen lamp settles in seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from calib.model.gratings import REPLICA_SHEET_PEAK_PHASE_RAD
from mocks.scene import SensorModel

SpectrometerModel = Literal["pr655", "pr670", "cs2000", "seabreeze", "argyll"]
RelayModel = Literal["hid_usbrelay", "lcus", "numato"]

SPECTROMETER_MODELS: tuple[SpectrometerModel, ...] = (
    "pr655",
    "pr670",
    "cs2000",
    "seabreeze",
    "argyll",
)
OCEAN_MODELS = ("USB2000PLUS", "STS")
RELAY_MODELS: tuple[RelayModel, ...] = ("hid_usbrelay", "lcus", "numato")


@dataclass(frozen=True)
class WarmupDrift:
    """How a lamp drifts after switch-on (see :class:`mocks.lamps.VirtualLamp`)."""

    tau_s: float
    gain: float
    tilt: float


#: Warm-up drift by lamp kind: time constant, output excess and tilt per 100 nm at switch-on.
LAMP_KIND_DEFAULTS: dict[str, WarmupDrift] = {
    "led": WarmupDrift(tau_s=30.0, gain=0.04, tilt=-0.02),
    "fluorescent": WarmupDrift(tau_s=60.0, gain=-0.15, tilt=0.03),
    "halogen": WarmupDrift(tau_s=8.0, gain=-0.05, tilt=-0.05),
    "other": WarmupDrift(tau_s=20.0, gain=0.02, tilt=0.0),
}


#: Mean settled radiance over 400–700 nm of a lamp whose configuration does not say.
DEFAULT_RADIANCE_W_SR_M2_NM = 0.01


class TwinSpecError(ValueError):
    """Configuration data the twin cannot be built from; the message names the field."""


@dataclass(frozen=True)
class LampSpec:
    """A simulated lamp on a relay channel.

    Parameters
    ----------
    name, channel, kind
        As in the rig's ``lamps[]``.
    spd
        colour-science illuminant whose spectral distribution the lamp has (``LED-B3``, ``FL2`` …).
    radiance_w_sr_m2_nm
        Mean settled spectral radiance over 400–700 nm, W/(sr·m²·nm).
    drift
        Warm-up drift.
    """

    name: str
    channel: int
    kind: str
    spd: str
    radiance_w_sr_m2_nm: float
    drift: WarmupDrift


@dataclass(frozen=True)
class GratingSpec:
    """The transmission grating: line density, physical model, direction (``rig.config.TwinGratingConfig``).

    Attributes
    ----------
    model
        ``"sinusoidal"`` (``peak_phase_rad``) or ``"blazed"`` (``blaze_nm``, scaled by
        ``first_order_peak_efficiency``): :mod:`calib.model.gratings`.
    zeroth_order_efficiency
        A flat η₀ instead of the model's, or ``None``.
    """

    grooves_per_mm: float
    blaze_nm: float
    first_order_peak_efficiency: float
    zeroth_order_efficiency: float | None
    dispersion_angle_deg: float
    model: str = "sinusoidal"
    peak_phase_rad: float = REPLICA_SHEET_PEAK_PHASE_RAD


@dataclass(frozen=True)
class OpticsSpec:
    """Lens, slit image and light level (see ``rig.config.TwinOpticsConfig``)."""

    focal_length_mm: float
    slit_width_px: float
    slit_length_px: float
    edge_px: float
    spot_position_px: tuple[float, float] | None
    throughput_e_per_s: float


@dataclass(frozen=True)
class CameraSpec:
    """The twin camera: whose sensitivity it has, its sensor, grating, optics and timing.

    Parameters
    ----------
    sensitivity, sensitivity_collection, data_dir
        The true camera: a name in a ``calib.core.datasets`` collection.
    sensor
        Size, CFA, levels and noise (at ISO 100).
    pixel_pitch_um
        Photosite pitch (sets the dispersion in pixels with the focal length).
    grating, optics
        See :class:`GratingSpec`, :class:`OpticsSpec`.
    download_s
        Simulated time to download one frame.
    realtime
        Exposures and downloads also pass in wall time.
    timeout_s, download_timeout_s
        The driver's deadlines for a call and for a download.
    stray_light, shutter_error
        Stray light along the band and a per-frame shutter error as a real rig has them, drawn
        from the seed (:mod:`mocks.bench.flaws`); ``False``: none.
    """

    sensitivity: str
    sensitivity_collection: str
    data_dir: Path | None
    sensor: SensorModel
    pixel_pitch_um: float
    grating: GratingSpec
    optics: OpticsSpec
    download_s: float
    realtime: bool
    timeout_s: float
    download_timeout_s: float
    stray_light: bool = True
    shutter_error: bool = True


@dataclass(frozen=True)
class TwinSpec:
    """The whole simulated bench.

    Parameters
    ----------
    seed
        Seeds every random number of the twin (spectrometer and camera noise).
    lamps
        The lamps, on distinct relay channels within ``1..relay_channels``.
    camera
        The camera (``None``: the rig's camera is real, the twin only lights its lamps).
    spectrometer_model, spectrometer_time_scale, spectrometer_timeout_s
        Which emulator serves the spectrometer (``None``: the rig's spectrometer is real), the
        fraction of its measuring time that passes in wall time, and the driver's command
        deadline.
    ocean_model
        The Ocean spectrometer emulated for ``seabreeze`` (``USB2000PLUS`` or ``STS``).
    spectrometer_noise_draw
        Which draw of the spectrometer's noise (0: the seed's own; others leave the rest alone).
    spectrometer_high_resolution
        ``argyll``: spotread runs with ``-H`` (3.3 nm bands).
    spectrometer_in_spec_error
        The emulated instrument's wavelength scale and slit are off within specification, drawn
        from ``seed`` (:mod:`mocks.bench.deviation`); ``False``: exactly as stated.
    spectrometer_measure_timeout_s
        The driver's measurement allowance (``None``: the model's default).
    relay_model, relay_channels, relay_timeout_s
        Which relay board is emulated, its size and the driver's deadline.
    relay_state_file
        Where the relays' state survives the process (``None``: every twin starts all off).
    """

    seed: int
    lamps: tuple[LampSpec, ...]
    camera: CameraSpec | None
    spectrometer_model: SpectrometerModel | None
    spectrometer_time_scale: float
    spectrometer_timeout_s: float
    relay_model: RelayModel
    relay_channels: int
    relay_timeout_s: float
    relay_state_file: Path | None = None
    spectrometer_measure_timeout_s: float | None = None
    ocean_model: str = "USB2000PLUS"
    spectrometer_noise_draw: int = 0
    spectrometer_high_resolution: bool = True
    spectrometer_in_spec_error: bool = True

    def __post_init__(self) -> None:
        if self.ocean_model not in OCEAN_MODELS:
            raise TwinSpecError(
                f"devices.spectrometer.ocean_model: {self.ocean_model!r} is not one of "
                f"{', '.join(OCEAN_MODELS)}"
            )
        if (
            self.spectrometer_model is not None
            and self.spectrometer_model not in SPECTROMETER_MODELS
        ):
            raise TwinSpecError(
                f"devices.spectrometer.emulate: {self.spectrometer_model!r} is not one of "
                f"{', '.join(SPECTROMETER_MODELS)}"
            )
        if self.relay_model not in RELAY_MODELS:
            raise TwinSpecError(
                f"devices.relays.emulate: {self.relay_model!r} is not one of "
                f"{', '.join(RELAY_MODELS)}"
            )
        channels = [lamp.channel for lamp in self.lamps]
        if len(set(channels)) != len(channels):
            raise TwinSpecError(f"lamps[].channel: two lamps share a relay channel ({channels})")
        outside = [
            f"{lamp.name} on {lamp.channel}"
            for lamp in self.lamps
            if not 1 <= lamp.channel <= self.relay_channels
        ]
        if outside:
            raise TwinSpecError(
                f"lamps[].channel: {', '.join(outside)} is not on the twin's "
                f"{self.relay_channels}-channel relay board; raise devices.relays.channels"
            )

    @property
    def twin_camera(self) -> CameraSpec:
        """The twin camera (:class:`TwinSpecError` when the rig's camera is real)."""
        if self.camera is None:
            raise TwinSpecError("devices.camera is real: the twin has no camera")
        return self.camera

    # ------------------------------------------------------------------------ from config data

    @classmethod
    def from_config_data(cls, data: Mapping[str, Any]) -> TwinSpec:
        """Build the spec from the rig's configuration as JSON-able data (validated by the rig).

        Every field must be present (the rig's dump carries its defaults); the twin keeps no
        defaults of its own. The relays must be ``twin`` (the lamps are the twin's); a real
        spectrometer or camera is left to the rig (``spectrometer_model`` / ``camera`` ``None``).

        Raises
        ------
        TwinSpecError
            A field is missing or does not fit (named as a path, ``devices.camera.sensor.width_px``).
        """
        root = _Reader(data, "")
        devices = root.section("devices")
        spectrometer = devices.section("spectrometer")
        relays = devices.section("relays")
        camera = devices.section("camera")
        if relays.text("kind") != "twin":
            raise TwinSpecError(
                f"{relays.where('kind')} is {relays.text('kind')!r}; the twin's lamps need 'twin'"
            )
        twin_spectrometer = spectrometer.text("kind") == "twin"
        twin_camera = camera.text("kind") == "twin"
        overrides = relays.section("lamps")
        lamps = root.items("lamps")
        names = [lamp.text("name") for lamp in lamps]
        unknown = sorted(set(overrides.keys()) - set(names))
        if unknown:
            raise TwinSpecError(
                f"devices.relays.lamps: {', '.join(map(repr, unknown))} is not a lamp of lamps[] "
                f"({', '.join(names)})"
            )
        spectrometer_model = spectrometer.text("emulate") if twin_spectrometer else None
        state_file = relays.value("state_file")
        relay_model = relays.text("emulate")
        return cls(
            seed=root.integer("seed"),
            lamps=tuple(
                _lamp_spec(lamp, overrides.section(name) if name in overrides else None)
                for lamp, name in zip(lamps, names, strict=True)
            ),
            camera=_camera_spec(camera) if twin_camera else None,
            spectrometer_model=spectrometer_model,  # type: ignore[arg-type]  # checked on init
            spectrometer_time_scale=spectrometer.number("time_scale") if twin_spectrometer else 1.0,
            spectrometer_timeout_s=spectrometer.number("timeout_s"),
            ocean_model=str(spectrometer.optional("ocean_model") or "USB2000PLUS"),
            spectrometer_noise_draw=int(spectrometer.optional("noise_draw") or 0),
            spectrometer_high_resolution=_switch(spectrometer, "high_resolution", default=True),
            spectrometer_in_spec_error=_switch(spectrometer, "in_spec_error", default=True),
            spectrometer_measure_timeout_s=(
                None
                if spectrometer.optional("measure_timeout_s") is None
                else spectrometer.number("measure_timeout_s")
            ),
            relay_model=relay_model,  # type: ignore[arg-type]  # checked on init
            relay_channels=relays.integer("channels"),
            relay_timeout_s=relays.number("timeout_s"),
            relay_state_file=None if state_file is None else Path(str(state_file)),
        )


class _Reader:
    """Reads nested configuration data, naming the path of whatever is missing or malformed."""

    def __init__(self, data: object, path: str) -> None:
        if not isinstance(data, Mapping):
            raise TwinSpecError(f"{path or 'configuration'}: expected a mapping, got {data!r}")
        self.data: Mapping[str, Any] = data
        self.path = path

    def where(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def keys(self) -> list[str]:
        return [str(key) for key in self.data]

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def value(self, key: str) -> Any:
        if key not in self.data:
            raise TwinSpecError(f"{self.where(key)}: missing")
        return self.data[key]

    def optional(self, key: str) -> Any:
        return self.data.get(key)

    def section(self, key: str) -> _Reader:
        return _Reader(self.value(key), self.where(key))

    def items(self, key: str) -> list[_Reader]:
        values = self.value(key)
        if not isinstance(values, Sequence) or isinstance(values, str):
            raise TwinSpecError(f"{self.where(key)}: expected a list, got {values!r}")
        return [_Reader(value, f"{self.where(key)}[{index}]") for index, value in enumerate(values)]

    def text(self, key: str) -> str:
        value = self.value(key)
        if not isinstance(value, str):
            raise TwinSpecError(f"{self.where(key)}: {value!r} is not text")
        return value

    def number(self, key: str, default: float | None = None) -> float:
        value = self.optional(key) if default is not None else self.value(key)
        if value is None:
            value = default
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise TwinSpecError(f"{self.where(key)}: {value!r} is not a number")
        if not math.isfinite(value):
            raise TwinSpecError(f"{self.where(key)}: {value!r} is not finite")
        return float(value)

    def integer(self, key: str) -> int:
        value = self.value(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise TwinSpecError(f"{self.where(key)}: {value!r} is not an integer")
        return value


def _switch(section: _Reader, key: str, *, default: bool) -> bool:
    """An optional true/false field (``default`` when absent)."""
    value = section.optional(key)
    if value is None:
        return default
    if not isinstance(value, bool):
        raise TwinSpecError(f"{section.where(key)}: {value!r} is not true or false")
    return value


def _lamp_spec(lamp: _Reader, override: _Reader | None) -> LampSpec:
    """A lamp from ``lamps[i]`` and its optional ``devices.relays.lamps.<name>`` entry."""
    name = lamp.text("name")
    kind = lamp.text("kind")
    base = LAMP_KIND_DEFAULTS.get(kind, LAMP_KIND_DEFAULTS["other"])
    extra = override or _Reader({}, f"devices.relays.lamps.{name}")
    spd = extra.optional("spd")
    return LampSpec(
        name=name,
        channel=lamp.integer("channel"),
        kind=kind,
        spd=name if spd is None else str(spd),
        radiance_w_sr_m2_nm=extra.number("radiance_w_sr_m2_nm", DEFAULT_RADIANCE_W_SR_M2_NM),
        drift=WarmupDrift(
            tau_s=extra.number("warmup_tau_s", base.tau_s),
            gain=extra.number("warmup_gain", base.gain),
            tilt=extra.number("warmup_tilt", base.tilt),
        ),
    )


def _grating_spec(grating: _Reader) -> GratingSpec:
    model = grating.optional("model") or "sinusoidal"
    if model not in ("sinusoidal", "blazed"):
        raise TwinSpecError(f"{grating.where('model')}: {model!r} is not sinusoidal or blazed")
    zeroth = grating.optional("zeroth_order_efficiency")
    return GratingSpec(
        grooves_per_mm=grating.number("grooves_per_mm"),
        blaze_nm=grating.number("blaze_nm"),
        first_order_peak_efficiency=grating.number("first_order_peak_efficiency"),
        zeroth_order_efficiency=None
        if zeroth is None
        else grating.number("zeroth_order_efficiency"),
        dispersion_angle_deg=grating.number("dispersion_angle_deg"),
        model=str(model),
        peak_phase_rad=grating.number("peak_phase_rad", REPLICA_SHEET_PEAK_PHASE_RAD),
    )


def _camera_spec(camera: _Reader) -> CameraSpec:
    sensor = camera.section("sensor")
    grating = camera.section("grating")
    optics = camera.section("optics")
    try:
        sensor_model = SensorModel(
            height_px=sensor.integer("height_px"),
            width_px=sensor.integer("width_px"),
            cfa_pattern=sensor.text("cfa_pattern"),
            black_level_dn=sensor.integer("black_level_dn"),
            white_level_dn=sensor.integer("white_level_dn"),
            gain_dn_per_electron=sensor.number("gain_dn_per_electron"),
            read_noise_dn=sensor.number("read_noise_dn"),
            dark_current_dn_per_s=sensor.number("dark_current_dn_per_s"),
        )
    except ValueError as exc:
        raise TwinSpecError(f"{sensor.path}: {exc}") from None
    spot = optics.value("spot_position_px")
    data_dir = camera.value("data_dir")
    return CameraSpec(
        sensitivity=camera.text("sensitivity"),
        sensitivity_collection=camera.text("sensitivity_collection"),
        data_dir=None if data_dir is None else Path(str(data_dir)),
        sensor=sensor_model,
        pixel_pitch_um=sensor.number("pixel_pitch_um"),
        grating=_grating_spec(grating),
        optics=OpticsSpec(
            focal_length_mm=optics.number("focal_length_mm"),
            slit_width_px=optics.number("slit_width_px"),
            slit_length_px=optics.number("slit_length_px"),
            edge_px=optics.number("edge_px"),
            spot_position_px=None if spot is None else (float(spot[0]), float(spot[1])),
            throughput_e_per_s=optics.number("throughput_e_per_s"),
        ),
        download_s=camera.number("download_s"),
        realtime=bool(camera.value("realtime")),
        timeout_s=camera.number("timeout_s"),
        download_timeout_s=camera.number("download_timeout_s"),
        stray_light=_switch(camera, "stray_light", default=True),
        shutter_error=_switch(camera, "shutter_error", default=True),
    )
