"""The rig's configuration: pydantic models of ``config.yaml``, and a loader whose errors a person can act on.

Every model forbids unknown keys. :func:`load_config` reads YAML with the safe loader only (duplicate
keys are an error, not "last one wins"), validates, and turns every problem into a
:class:`calib.core.validated_yaml.ConfigError` that names the file, the line, the field path (``lamps[1].warmup.interval_s``),
the value found and what is allowed, with the closest valid key suggested for a typo.

Exposure times may be written as seconds (``0.01``), fractions (``"1/125"``) or with a unit
(``"2.5s"``, ``"40ms"``). Relative paths (``output_dir``, the twin's ``data_dir`` and
``state_file``, a spectrometer's ``calibration_file`` and ``directory``) are resolved against the directory of the configuration file, so a rig behaves the
same whatever the working directory.

The device ``kind`` selects a driver: ``pr655``/``pr670``/``cs2000`` spectroradiometers on a serial
port, an Ocean Optics spectrometer through python-seabreeze (``seabreeze``), an X-Rite instrument
through ArgyllCMS's ``spotread`` (``argyll``), measured spectrum files (``files``); ``lcus``/
``numato``/``hid_usbrelay`` relay boards; a ``gphoto2`` camera; or ``twin`` for the simulated bench.
Each device may be twin or real on its own (a real camera with twin lamps and spectrometer), except
that a twin spectrometer or camera sees only the twin's lamps, so it needs twin relays.
:mod:`rig.station` turns a :class:`DevicesConfig` into device objects.
"""

from __future__ import annotations

import re
from fractions import Fraction
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator, model_validator

from calib.core.observations import LampKind
from calib.core.spectrometer_tolerance import MAX_BANDWIDTH_NM
from calib.core.validated_yaml import ConfigError as ConfigError
from calib.core.validated_yaml import ConfigIssue, parse_yaml_model
from calib.model.gratings import REPLICA_SHEET_PEAK_PHASE_RAD

# ---------------------------------------------------------------------------------------- values

_EXPOSURE_PATTERN = re.compile(
    r"^\s*(?P<number>\d+(?:\.\d*)?|\.\d+)(?:\s*/\s*(?P<denominator>\d+(?:\.\d*)?))?\s*(?P<unit>s|ms|us|µs)?\s*$"
)
_UNIT_TO_SECONDS = {None: 1.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}


def parse_exposure_s(value: object) -> object:
    """Exposure in seconds from ``0.01``, ``"1/125"``, ``"2.5s"`` or ``"40ms"``; other input passes through.

    Returning non-strings unchanged lets pydantic report the type error itself.
    """
    if not isinstance(value, str):
        return value
    match = _EXPOSURE_PATTERN.match(value)
    if match is None:
        raise ValueError(
            f"{value!r} is not an exposure time; write seconds like 0.01, a fraction like '1/125' "
            "or a value with a unit like '2.5s' or '40ms'"
        )
    number = Fraction(match["number"])
    if match["denominator"] is not None:
        denominator = Fraction(match["denominator"])
        if denominator == 0:
            raise ValueError(f"{value!r} divides by zero")
        number /= denominator
    return float(number) * _UNIT_TO_SECONDS[match["unit"]]


def _parse_f_number(value: object) -> object:
    """``8``, ``"8"``, ``"f/8"`` or ``"F8"`` → 8.0; other input passes through."""
    if isinstance(value, str):
        text = value.strip().lower().removeprefix("f/").removeprefix("f")
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{value!r} is not an f-number; write it like 8 or 'f/8'") from None
    return value


def _lower(value: object) -> object:
    return value.strip().lower() if isinstance(value, str) else value


ExposureSeconds = Annotated[float, BeforeValidator(parse_exposure_s), Field(gt=0, le=3600)]
"""An exposure time in seconds (> 0, at most an hour)."""

LAMP_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,63}$"
"""Lamp names become parts of step keys and file names: letters, digits, ``._+-``, at most 64."""


class StrictModel(BaseModel):
    """Base of every configuration model: unknown keys are errors and values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True, str_strip_whitespace=True)


# --------------------------------------------------------------------------------------- devices

SpectrometerModel = Literal["pr655", "pr670", "cs2000"]
EmulatedSpectrometer = Literal["pr655", "pr670", "cs2000", "seabreeze", "argyll"]
OceanModel = Literal["USB2000PLUS", "STS"]
RelayModel = Literal["hid_usbrelay", "lcus", "numato"]
CorrectionChoice = Literal["auto", "on", "off"]


MEASURE_TIMEOUT_HELP = (
    "measurement allowance: PR-6xx the whole measurement (default 60 s), CS-2000 the margin "
    "beyond the time the instrument announces (default 10 s)"
)


class SerialSpectrometerConfig(StrictModel):
    """A spectroradiometer on a serial (USB CDC) port."""

    kind: SpectrometerModel
    port: str = Field(min_length=1, description="serial device, e.g. /dev/ttyACM0 or COM3")
    baud: int | None = Field(
        None, gt=0, description="line speed; default: the instrument's own (9600 PR, 115200 CS)"
    )
    timeout_s: float = Field(35.0, gt=0, le=600, description="deadline for one command")
    measure_timeout_s: float | None = Field(None, gt=0, le=600, description=MEASURE_TIMEOUT_HELP)


class SeabreezeSpectrometerConfig(StrictModel):
    """An Ocean Optics / Ocean Insight USB spectrometer through python-seabreeze (pyseabreeze).

    ``calibration_file`` is its relative irradiance calibration: a CSV with a ``wavelength_nm``
    column and a ``factor`` column (relative irradiance per count per ms), e.g. the instrument's
    calibration or one made against a lamp of known spectrum. Without it the rig refuses to measure
    unless ``allow_uncalibrated`` is set (raw counts carry the spectrometer's own spectral response
    into the estimate). The integration time is ranged automatically between
    ``integration_min_ms`` and ``integration_max_ms`` (``spectrum.exposure_ms`` fixes it instead); a
    dark spectrum is measured with every lamp off before the first lamp.
    """

    kind: Literal["seabreeze"]
    serial: str | None = Field(None, min_length=1, description="serial number; null: the only one")
    calibration_file: Path | None = None
    allow_uncalibrated: bool = False
    integration_min_ms: float = Field(1.0, gt=0, le=60000)
    integration_max_ms: float = Field(5000.0, gt=0, le=600000)
    averages: int = Field(3, ge=1, le=1000, description="scans averaged per spectrum and dark")
    electric_dark: CorrectionChoice = "auto"
    nonlinearity: CorrectionChoice = "auto"
    bandwidth_nm: float | None = Field(
        None,
        gt=0,
        le=MAX_BANDWIDTH_NM,
        description="optical resolution (FWHM) of the slit and grating",
    )
    timeout_s: float = Field(5.0, gt=0, le=600, description="USB deadline beyond a scan's time")
    measure_timeout_s: float | None = Field(None, gt=0, le=3600, description=MEASURE_TIMEOUT_HELP)

    @model_validator(mode="after")
    def _calibrated_and_ordered(self) -> SeabreezeSpectrometerConfig:
        if self.integration_min_ms >= self.integration_max_ms:
            raise ValueError(
                f"integration_min_ms = {self.integration_min_ms:g} is not below "
                f"integration_max_ms = {self.integration_max_ms:g}"
            )
        if self.calibration_file is None and not self.allow_uncalibrated:
            raise ValueError(
                "calibration_file is missing: give the spectrometer's relative irradiance "
                "calibration (CSV: wavelength_nm, factor), or set allow_uncalibrated: true to "
                "record raw counts (not fit for estimating a camera)"
            )
        return self


class ArgyllSpectrometerConfig(StrictModel):
    """An instrument ArgyllCMS drives (X-Rite i1Pro, i1Studio, ColorMunki …) through ``spotread``
    in ambient spectral mode (``spotread -a -s -N -O reading.sp``).

    ``instrument`` is spotread's ``-c`` number (``spotread -?`` lists them); the instrument must
    have been calibrated (``spotread -a -O``) with its ambient diffuser in place.
    """

    kind: Literal["argyll"]
    executable: str = Field("spotread", min_length=1, description="spotread, or its full path")
    instrument: int = Field(1, ge=1, le=32, description="spotread -c: which instrument")
    high_resolution: bool = Field(
        True,
        description="spotread -H: 3.3 nm bands (15 nm FWHM) where the model has them, else its "
        "10 nm ones (25 nm FWHM); the reading's sampling says which",
    )
    bandwidth_nm: float | None = Field(
        None,
        gt=0,
        le=MAX_BANDWIDTH_NM,
        description="optical resolution (FWHM); null: an i1Pro's, 25 nm (15 with -H)",
    )
    timeout_s: float = Field(60.0, gt=0, le=600, description="deadline of one spotread run")
    measure_timeout_s: float | None = Field(None, gt=0, le=600, description=MEASURE_TIMEOUT_HELP)


SpectrumFileFormat = Literal["auto", "argyll", "csv", "ies", "xrite", "sekonic", "uprtek"]


class FilesSpectrometerConfig(StrictModel):
    """Spectra measured once, elsewhere: one file per lamp in ``directory``.

    ``lamps`` maps every lamp name to its file: an ArgyllCMS CGATS ``.sp``, a CSV with a
    ``wavelength_nm`` column and the values in the column ``column`` (default: the only other one;
    ``# units:`` and ``# bandwidth_nm:`` comment lines say what it holds), an IES TM-27-14 ``.spdx``,
    or an X-Rite, Sekonic or UPRtek export (``format``; ``auto`` goes by the suffix). ``units`` and
    ``bandwidth_nm`` stand for files that do not say. A "measurement" returns the file of the lamp
    that is lit (see :mod:`rig.spectrum_files`).
    """

    kind: Literal["files"]
    directory: Path
    lamps: dict[str, str] = Field(min_length=1)
    format: SpectrumFileFormat = "auto"
    column: str | None = Field(None, min_length=1)
    units: str = Field("relative spectral power", min_length=1)
    bandwidth_nm: float | None = Field(None, gt=0, le=MAX_BANDWIDTH_NM)
    timeout_s: float = Field(5.0, gt=0, le=600)
    measure_timeout_s: float | None = Field(None, gt=0, le=600)


class TwinSpectrometerConfig(StrictModel):
    """The simulated bench's spectrometer: the real driver talking to an emulator.

    ``emulate`` picks the instrument: the PR-655/670 or CS-2000 firmware on a pty, an Ocean
    spectrometer on an emulated USB bus (``seabreeze``; ``ocean_model`` USB2000+ or STS), or a fake
    ``spotread`` (``argyll``). ``time_scale`` is the fraction of the instrument's modelled measuring
    time that passes in wall time; the twin's clock does not wait for it. Sessions that differ only
    in ``noise_draw`` differ only in the spectrometer's noise (its repeatability, measured).
    ``in_spec_error`` (default on) gives the instrument the errors a real one has within its
    specification — a wavelength-scale error and a slit wider or narrower than stated, drawn from
    ``seed`` alone (the same whichever instrument is emulated; ``mocks.bench.deviation``).
    """

    kind: Literal["twin"]
    emulate: EmulatedSpectrometer = "pr655"
    ocean_model: OceanModel = "USB2000PLUS"
    timeout_s: float = Field(35.0, gt=0, le=600)
    measure_timeout_s: float | None = Field(None, gt=0, le=600, description=MEASURE_TIMEOUT_HELP)
    time_scale: float = Field(0.001, gt=0, le=1)
    noise_draw: int = Field(
        0,
        ge=0,
        description="which draw of the spectrometer's noise (the rest of the twin unchanged)",
    )
    high_resolution: bool = Field(True, description="argyll: spotread -H (3.3 nm bands)")
    in_spec_error: bool = Field(
        True,
        description="the emulated instrument's wavelength scale (±0.5 nm) and slit width (±25 %) "
        "are off within specification, drawn from the seed and recorded in twin-truth.json; "
        "false: exactly as its data sheet states",
    )


class LcusRelayConfig(StrictModel):
    """An LCUS/CH340 serial relay board (binary frames)."""

    kind: Literal["lcus"]
    port: str = Field(min_length=1)
    channels: Literal[1, 2, 4, 8]
    baud: int = Field(9600, gt=0)
    timeout_s: float = Field(2.0, gt=0, le=60)


class NumatoRelayConfig(StrictModel):
    """A Numato Lab USB relay module (ASCII commands over CDC-ACM)."""

    kind: Literal["numato"]
    port: str = Field(min_length=1)
    channels: Literal[1, 2, 4, 8, 16, 32]
    baud: int = Field(19200, gt=0)
    timeout_s: float = Field(2.0, gt=0, le=60)


class HidRelayConfig(StrictModel):
    """A dcttech "USBRelayN" HID board over pyusb; ``serial`` picks one when several are plugged in."""

    kind: Literal["hid_usbrelay"]
    serial: str | None = Field(None, min_length=1, max_length=5)
    channels: Literal[1, 2, 4, 8]
    timeout_s: float = Field(2.0, gt=0, le=60)


class TwinLampConfig(StrictModel):
    """A simulated lamp behind the twin's relay board (every field has a default per lamp kind).

    ``spd`` names a colour-science illuminant (``LED-B3``, ``FL2``, ``A``, ``D65`` …; default: the
    lamp's own name). The settled spectrum is scaled so that its mean over 400–700 nm is
    ``radiance_w_sr_m2_nm`` (default 0.01). After switch-on the output and the spectral tilt drift
    exponentially (time constant ``warmup_tau_s``) from ``1 + warmup_gain`` and ``warmup_tilt`` per
    100 nm to their settled values.
    """

    spd: str | None = Field(None, min_length=1)
    radiance_w_sr_m2_nm: float | None = Field(None, gt=0, le=1e4)
    warmup_tau_s: float | None = Field(None, ge=0, le=86400)
    warmup_gain: float | None = Field(None, gt=-1, lt=10)
    warmup_tilt: float | None = Field(None, gt=-0.5, lt=0.5)


class TwinRelayConfig(StrictModel):
    """The simulated bench's relay board: the real driver talking to the emulator.

    ``lamps`` describes the simulated lamps by their ``lamps[].name``; lamps not listed get the
    defaults of their kind. With ``state_file`` the simulated relays keep their state between
    processes, as a real board does when the rig dies (a capture killed with a lamp on leaves it
    on for the next one); without it every twin starts with its relays off.
    """

    kind: Literal["twin"]
    emulate: RelayModel = "hid_usbrelay"
    channels: Literal[1, 2, 4, 8] = 2
    timeout_s: float = Field(2.0, gt=0, le=60)
    lamps: dict[str, TwinLampConfig] = Field(default_factory=dict)
    state_file: Path | None = None


class Gphoto2CameraConfig(StrictModel):
    """A camera tethered through libgphoto2; ``port`` (``usb:001,004``) and ``model`` pick one."""

    kind: Literal["gphoto2"]
    port: str | None = Field(None, min_length=1)
    model: str | None = Field(None, min_length=1)
    timeout_s: float = Field(10.0, gt=0, le=600, description="deadline for a settings call")
    download_timeout_s: float = Field(
        60.0, gt=0, le=3600, description="deadline for capture + download, added to the exposure"
    )


CfaPattern = Literal["RGGB", "BGGR", "GRBG", "GBRG"]


class TwinSensorConfig(StrictModel):
    """The twin camera's Bayer sensor (levels and noise at ISO 100; the gain scales with ISO)."""

    width_px: int = Field(1200, ge=64, le=12000, description="sensor width (even)")
    height_px: int = Field(800, ge=64, le=8000, description="sensor height (even)")
    pixel_pitch_um: float = Field(4.8, gt=0, le=50)
    cfa_pattern: CfaPattern = "RGGB"
    black_level_dn: int = Field(512, ge=0, le=60000)
    white_level_dn: int = Field(16383, ge=1, le=65535)
    gain_dn_per_electron: float = Field(0.5, gt=0, le=100, description="at ISO 100")
    read_noise_dn: float = Field(2.5, ge=0, le=1000)
    dark_current_dn_per_s: float = Field(0.5, ge=0, le=1e5)

    @model_validator(mode="after")
    def _even_and_ordered(self) -> TwinSensorConfig:
        odd = [
            f"{name} = {value}"
            for name, value in (("width_px", self.width_px), ("height_px", self.height_px))
            if value % 2
        ]
        if odd:
            raise ValueError(f"{' and '.join(odd)}: a Bayer sensor has even sides")
        if self.black_level_dn >= self.white_level_dn:
            raise ValueError(
                f"black_level_dn = {self.black_level_dn} is not below white_level_dn = "
                f"{self.white_level_dn}"
            )
        return self


class TwinGratingConfig(StrictModel):
    """The twin's transmission grating in front of the lens (``calib.model.gratings``).

    ``model`` ``sinusoidal`` (default): a thin sinusoidal phase sheet, ``η_m = J_m²(φ₀·550/λ)``
    with ``peak_phase_rad`` φ₀; ``blazed``: ``η_m = first_order_peak_efficiency ·
    sinc²(blaze_nm/λ − m)``. Orders 0, 1 and 2 follow from the same parameters: the direct spot
    through η₀(λ), the first order through η₁, the second order on top of the first's red end.

    The default sheet is a cheap embossed replica film (the rainbow sheets sold for classrooms):
    a sinusoidal surface relief about 0.36 µm deep in a polymer of index ≈ 1.58 (PET/PVC) gives a
    peak phase ``φ₀ = π (n − 1) h / λ`` ≈ 1.2 rad at 550 nm (decision 0040). Such a sheet sends
    25 % of the light at 550 nm into each first order (33 % at 400 nm, 18 % at 700 nm) and keeps
    a bright direct spot (η₀ = J₀² from 0.18 at 400 nm to 0.62 at 700 nm), as these sheets
    visibly do; 1.84 rad (the first order's ceiling of 33.8 %) would need a relief tuned for
    efficiency, not a display film's.

    ``zeroth_order_efficiency`` replaces the model's η₀ by a flat one (a number), e.g. to mimic the
    twin before physical gratings; ``null`` (default) gives the model's own η₀(λ).
    """

    grooves_per_mm: float = Field(500.0, gt=0, le=3000)
    model: Literal["sinusoidal", "blazed"] = "sinusoidal"
    peak_phase_rad: float = Field(REPLICA_SHEET_PEAK_PHASE_RAD, gt=0, le=2.6)
    blaze_nm: float = Field(500.0, ge=200, le=2000)
    first_order_peak_efficiency: float = Field(0.3, gt=0, le=1)
    zeroth_order_efficiency: float | None = Field(None, gt=0, le=1)
    dispersion_angle_deg: float = Field(
        0.8, ge=-180, le=180, description="direction of the first order on the sensor, from +x"
    )


class TwinOpticsConfig(StrictModel):
    """Lens, slit and light level of the twin.

    The slit's image on the sensor is ``slit_width_px`` along the dispersion and
    ``slit_length_px`` across, with raised-cosine edges ``edge_px`` wide (the lens blur).
    ``spot_position_px`` places the direct spot (default: left of centre so the first order from
    380 to 780 nm fits). ``throughput_e_per_s`` converts radiance (W/(sr·m²·nm)) times a sensitivity
    that peaks at 1, integrated over wavelength (nm), into photo-electrons per second at f/8.
    """

    focal_length_mm: float = Field(12.0, gt=0, le=2000)
    slit_width_px: float = Field(4.0, gt=0, le=500)
    slit_length_px: float = Field(300.0, gt=0, le=8000)
    edge_px: float = Field(2.0, ge=0, le=100)
    spot_position_px: tuple[float, float] | None = None
    throughput_e_per_s: float = Field(3.0e10, gt=0, le=1e16)


class TwinCameraConfig(StrictModel):
    """The simulated bench's camera: the real gphoto2 driver on a fake body writing real DNG files.

    ``sensitivity`` names the camera whose spectral sensitivity the twin has: one of
    colour-science's cameras (``sensitivity_collection: colour-science``, the default), or a camera
    of a downloaded collection (``rig data fetch``; ``data_dir`` as for calib). Each frame costs
    its exposure plus ``download_s`` on the twin's clock; with ``realtime: true`` they also pass in
    wall time (to measure the rig's own overhead). ``stray_light`` and ``shutter_error`` (default
    on) give the camera the errors a real rig's camera has: stray light of the direct spot along
    the band and a per-frame shutter error, drawn from ``seed`` (``mocks.bench.flaws``).
    """

    kind: Literal["twin"]
    timeout_s: float = Field(10.0, gt=0, le=600)
    download_timeout_s: float = Field(60.0, gt=0, le=3600)
    sensitivity: str = Field("Nikon 5100 (NPL)", min_length=1)
    sensitivity_collection: str = Field("colour-science", min_length=1)
    data_dir: Path | None = None
    sensor: TwinSensorConfig = TwinSensorConfig()
    grating: TwinGratingConfig = TwinGratingConfig()
    optics: TwinOpticsConfig = TwinOpticsConfig()
    download_s: float = Field(0.5, ge=0, le=600, description="simulated download time per frame")
    realtime: bool = False
    stray_light: bool = Field(
        True,
        description="stray light of the direct spot along the band (0.1–1 % of it in a Lorentzian "
        "wing), drawn from the seed and recorded in twin-truth.json; false: none",
    )
    shutter_error: bool = Field(
        True,
        description="each frame exposed its recorded time × (1 + ε), ε of σ 1–3 % drawn from the "
        "seed and recorded in twin-truth.json; false: an exact shutter",
    )


SpectrometerConfig = Annotated[
    SerialSpectrometerConfig
    | SeabreezeSpectrometerConfig
    | ArgyllSpectrometerConfig
    | FilesSpectrometerConfig
    | TwinSpectrometerConfig,
    Field(discriminator="kind"),
]
RelayConfig = Annotated[
    LcusRelayConfig | NumatoRelayConfig | HidRelayConfig | TwinRelayConfig,
    Field(discriminator="kind"),
]
CameraConfig = Annotated[Gphoto2CameraConfig | TwinCameraConfig, Field(discriminator="kind")]


class DevicesConfig(StrictModel):
    """The three instruments of the rig."""

    spectrometer: SpectrometerConfig
    relays: RelayConfig
    camera: CameraConfig

    @model_validator(mode="after")
    def _twins_see_twin_lamps(self) -> DevicesConfig:
        if self.relays.kind == "twin":
            return self
        blind = [
            role
            for role, kind in (
                ("spectrometer", self.spectrometer.kind),
                ("camera", self.camera.kind),
            )
            if kind == "twin"
        ]
        if blind:
            raise ValueError(
                f"devices.{' and devices.'.join(blind)} {'is' if len(blind) == 1 else 'are'} "
                f"'twin' but devices.relays is {self.relays.kind!r}: a twin spectrometer or camera "
                "sees only the twin's lamps, so the relays must be 'twin' too (or make them real)"
            )
        return self

    def twin_roles(self) -> tuple[str, ...]:
        """The roles the digital twin plays (``()``: all real hardware)."""
        return tuple(
            role
            for role, kind in (
                ("spectrometer", self.spectrometer.kind),
                ("relays", self.relays.kind),
                ("camera", self.camera.kind),
            )
            if kind == "twin"
        )

    @property
    def simulated(self) -> bool:
        """Whether any device is the digital twin."""
        return bool(self.twin_roles())

    @property
    def spectrometer_model(self) -> str:
        """The instrument the spectrometer is or emulates (``pr655``, ``seabreeze`` …)."""
        spectrometer = self.spectrometer
        if isinstance(spectrometer, TwinSpectrometerConfig):
            return spectrometer.emulate
        return spectrometer.kind

    @property
    def spectrometer_takes_dark(self) -> bool:
        """Whether the spectrometer needs a dark spectrum measured with the lamps off."""
        return self.spectrometer_model == "seabreeze"


# ----------------------------------------------------------------------------------------- lamps


class WarmupPolicy(StrictModel):
    """When a lamp counts as warmed up.

    The lamp is stable once ``stable_pairs`` consecutive pairs of spectra, measured ``interval_s``
    apart, differ by less than ``tolerance`` (relative L2 change). It fails when that has not
    happened ``timeout_s`` after switch-on.
    """

    tolerance: float = Field(0.005, gt=0, lt=1, description="relative change between spectra")
    interval_s: float = Field(10.0, gt=0, le=3600)
    timeout_s: float = Field(600.0, gt=0, le=86400)
    stable_pairs: int = Field(2, ge=1, le=20)

    @model_validator(mode="after")
    def _timeout_allows_enough_spectra(self) -> WarmupPolicy:
        needed_s = self.interval_s * self.stable_pairs
        if self.timeout_s < needed_s:
            raise ValueError(
                f"timeout_s = {self.timeout_s:g} is shorter than stable_pairs × interval_s = "
                f"{needed_s:g} s, so no lamp could ever count as stable"
            )
        return self


class LampConfig(StrictModel):
    """A lamp on a relay channel."""

    name: str = Field(pattern=LAMP_NAME_PATTERN)
    channel: int = Field(ge=1, le=32, description="relay channel, numbered from 1 as on the board")
    kind: Annotated[LampKind, BeforeValidator(_lower)]
    warmup: WarmupPolicy = WarmupPolicy()


# ------------------------------------------------------------------------------- capture policy


class CameraSettings(StrictModel):
    """Settings applied to the camera before the first frame.

    ``exposure_range_s`` is what the camera is declared to support; ``rig dry-run`` checks the HDR
    policy against it, and a capture reads the camera's own range instead.
    """

    iso: int | None = Field(100, ge=25, le=409600)
    aperture: Annotated[float | None, BeforeValidator(_parse_f_number)] = Field(8.0, ge=0.5, le=128)
    image_format: str = Field("RAW", min_length=1)
    require_raw: bool = Field(True, description="refuse frames that arrive as JPEG")
    widgets: dict[str, str] = Field(
        default_factory=dict, description="further camera widgets by their gphoto2 name"
    )
    exposure_range_s: tuple[ExposureSeconds, ExposureSeconds] = (1 / 8000, 30.0)

    @field_validator("exposure_range_s")
    @classmethod
    def _range_is_ordered(cls, value: tuple[float, float]) -> tuple[float, float]:
        if value[0] >= value[1]:
            raise ValueError(
                f"shortest exposure {value[0]:g} s is not below longest {value[1]:g} s"
            )
        return value

    def setting_items(self) -> tuple[tuple[str, str], ...]:
        """The widgets to set, in order, as ``(name, value)`` strings."""
        items: list[tuple[str, str]] = [("imageformat", self.image_format)]
        if self.iso is not None:
            items.append(("iso", str(self.iso)))
        if self.aperture is not None:
            items.append(("aperture", f"{self.aperture:g}"))
        items.extend(sorted(self.widgets.items()))
        return tuple(items)


class HdrPolicy(StrictModel):
    """Automatic bracketing: how far the bracket may extend and when it is good enough.

    The bracket starts at ``start_exposure_s`` (default: the geometric mean of the allowed range)
    and grows by at most ``step_stops`` at a time until its shortest frame leaves at most
    ``max_direct_saturated_fraction`` of the direct spot saturated and at most
    ``max_unmergeable_fraction`` of the direct spot's and of the first-order band's pixels
    unmergeable, and its longest frame reaches ``min_band_snr`` on the first-order band.

    Unmergeable is the HDR merge's own rule (``calib.image.hdr.merge_bracket``): a pixel saturated,
    or whose neighbours average above 90 % of the clipping level, is not taken from that frame. The
    estimator refuses a lamp whose spot or band has a pixel that no frame of the bracket gives the
    merge ("saturated in every frame"), so the default 0 asks for a shorter frame while any such
    pixel remains in the shortest one (decision 0186).
    """

    min_exposure_s: ExposureSeconds = 1 / 4000
    max_exposure_s: ExposureSeconds = 8.0
    start_exposure_s: ExposureSeconds | None = None
    step_stops: float = Field(2.0, gt=0, le=6)
    max_direct_saturated_fraction: float = Field(0.001, ge=0, lt=1)
    max_unmergeable_fraction: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="of the shortest frame's direct-spot and first-order-band pixels, the fraction "
        "the HDR merge may not be able to use (saturated or near clipping); 0: none",
    )
    min_band_snr: float = Field(50.0, gt=0, le=100000)
    max_frames: int = Field(8, ge=1, le=30)

    @model_validator(mode="after")
    def _range_is_consistent(self) -> HdrPolicy:
        if self.min_exposure_s >= self.max_exposure_s:
            raise ValueError(
                f"min_exposure_s = {self.min_exposure_s:g} s is not below max_exposure_s = "
                f"{self.max_exposure_s:g} s"
            )
        start = self.start_exposure_s
        if start is not None and not self.min_exposure_s <= start <= self.max_exposure_s:
            raise ValueError(
                f"start_exposure_s = {start:g} s lies outside min_exposure_s..max_exposure_s = "
                f"{self.min_exposure_s:g}..{self.max_exposure_s:g} s"
            )
        return self


class SpectrumPolicy(StrictModel):
    """Reference spectra per lamp, after warm-up."""

    repeats: int = Field(3, ge=1, le=100)
    exposure_ms: float | None = Field(
        None, gt=0, le=60000, description="integration time; null = the instrument's adaptive mode"
    )


class GratingMeasurement(StrictModel):
    """Measure the grating sheet's efficiency with the spectrometer (issue 17, decision 0032).

    While ``lamp`` is lit and settled (after its reference spectra), the operator aims the
    spectrometer at the slit without the sheet (``direct``), then through the sheet straight on
    (``order0``), then at the slit's 1st-order image at a series of angles, each putting another
    wavelength band in the middle of the measuring field, and finally back at its usual target.
    ``repeats`` spectra are taken in each beam. ``η₁ = order1 / direct`` and
    ``η₀ = order0 / direct`` follow wherever the slit's image lies wholly inside the field.

    A spot spectroradiometer (PR-655/670, CS-2000) sees the 1st order of a narrow slit over a band
    ``(λ-spacing) · cos θ · field`` wide (500 lines/mm, 1° field: ≈ 33 nm at 550 nm); the aims step
    by half of that (:data:`rig.plan.AIM_STEP_FRACTION`) so that the cores of neighbouring bands,
    clear of the spectrometer's bandwidth at their edges, overlap. ``grooves_per_mm`` is the
    sheet's nominal line density (the turn angles come from it); ``field_deg`` the spectrometer's
    measuring field (PR-655 with its standard lens: 1°); ``range_nm`` the 1st-order wavelengths
    to cover; ``lamp`` a broadband lamp (a halogen is best; a fluorescent lamp's gaps give no
    ratio there).
    """

    lamp: str = Field(pattern=LAMP_NAME_PATTERN)
    grooves_per_mm: float = Field(gt=0, le=3000)
    field_deg: float = Field(1.0, gt=0, le=10)
    range_nm: tuple[float, float] = (400.0, 700.0)
    repeats: int = Field(2, ge=1, le=20)

    @model_validator(mode="after")
    def _first_order_exists(self) -> GratingMeasurement:
        low, high = self.range_nm
        if not 200.0 <= low < high <= 1100.0:
            raise ValueError(
                f"range_nm = [{low:g}, {high:g}] must be increasing within 200–1100 nm"
            )
        spacing_nm = 1e6 / self.grooves_per_mm
        if high >= spacing_nm:
            raise ValueError(
                f"range_nm reaches {high:g} nm, but a sheet of {self.grooves_per_mm:g} lines/mm "
                f"(spacing {spacing_nm:.0f} nm) has no 1st order beyond {spacing_nm:.0f} nm"
            )
        return self


class DryRunModel(StrictModel):
    """What ``rig dry-run`` assumes about the bench, to model readings and durations."""

    direct_saturates_at_s: ExposureSeconds = 0.02
    band_snr_at_direct_saturation: float = Field(8.0, gt=0)
    lamp_settles_s: float = Field(60.0, ge=0)
    spectrum_measure_s: float = Field(5.0, ge=0)
    frame_download_s: float = Field(1.0, ge=0)
    relay_switch_s: float = Field(0.05, ge=0)
    operator_aim_s: float = Field(
        60.0, ge=0, description="a person re-aiming the spectrometer (measure_grating)"
    )


class RigConfig(StrictModel):
    """The whole ``config.yaml``."""

    schema_version: Literal[1] = 1
    seed: int = Field(0, ge=0, description="seeds the twin's noise and any randomised choice")
    output_dir: Path = Field(Path("sessions"), description="sessions are created inside it")
    devices: DevicesConfig
    camera: CameraSettings = CameraSettings()
    lamps: list[LampConfig] = Field(min_length=1, max_length=32)
    spectrum: SpectrumPolicy = SpectrumPolicy()
    hdr: HdrPolicy = HdrPolicy()
    dark_frames: int = Field(2, ge=0, le=50, description="dark frames per bracket exposure")
    dry_run: DryRunModel = DryRunModel()
    measure_grating: GratingMeasurement | None = Field(
        None, description="measure the grating's efficiency with the spectrometer (null: do not)"
    )

    @model_validator(mode="after")
    def _grating_lamp_is_a_lamp(self) -> RigConfig:
        measure = self.measure_grating
        if measure is None:
            return self
        names = [lamp.name for lamp in self.lamps]
        if measure.lamp not in names:
            raise ValueError(
                f"measure_grating.lamp {measure.lamp!r} is not a lamp of lamps[] "
                f"({', '.join(names)})"
            )
        if self.devices.spectrometer_model == "files":
            raise ValueError(
                "measure_grating: a files spectrometer cannot be aimed at the grating's beams; "
                "set measure_grating to null"
            )
        return self

    @model_validator(mode="after")
    def _every_lamp_has_its_file(self) -> RigConfig:
        spectrometer = self.devices.spectrometer
        if not isinstance(spectrometer, FilesSpectrometerConfig):
            return self
        names = [lamp.name for lamp in self.lamps]
        missing = [name for name in names if name not in spectrometer.lamps]
        unknown = [name for name in spectrometer.lamps if name not in names]
        if missing or unknown:
            parts = [f"no file for {', '.join(map(repr, missing))}"] if missing else []
            if unknown:
                parts.append(f"{', '.join(map(repr, unknown))} is not a lamp of lamps[]")
            raise ValueError(
                f"devices.spectrometer.lamps: {'; '.join(parts)} (lamps: {', '.join(names)})"
            )
        return self

    @model_validator(mode="after")
    def _exposure_is_the_spectrometers_to_choose(self) -> RigConfig:
        model = self.devices.spectrometer_model
        if model in ("argyll", "files") and self.spectrum.exposure_ms is not None:
            who = "spotread chooses its own" if model == "argyll" else "files have no"
            raise ValueError(
                f"spectrum.exposure_ms = {self.spectrum.exposure_ms:g}: {who} integration "
                f"time (devices.spectrometer is {model!r}); set it to null"
            )
        return self

    @field_validator("lamps")
    @classmethod
    def _lamp_names_are_unique(cls, lamps: list[LampConfig]) -> list[LampConfig]:
        seen: dict[str, int] = {}
        for index, lamp in enumerate(lamps):
            folded = lamp.name.casefold()
            if folded in seen:
                raise ValueError(
                    f"lamps[{index}].name {lamp.name!r} repeats lamps[{seen[folded]}].name; "
                    "lamp names must be unique (ignoring case)"
                )
            seen[folded] = index
        return lamps

    def lamp(self, name: str) -> LampConfig:
        """The lamp called ``name``."""
        for lamp in self.lamps:
            if lamp.name == name:
                return lamp
        raise KeyError(name)


def parse_config(text: str, source: str = "<config>", base_dir: Path | None = None) -> RigConfig:
    """Validate YAML ``text`` as a :class:`RigConfig`; relative paths resolve against ``base_dir``.

    Raises
    ------
    ConfigError
        For YAML syntax errors, duplicate keys, or any validation problem (all reported at once).
    """
    config = parse_yaml_model(text, RigConfig, source)
    if base_dir is None:
        return config
    if not config.output_dir.is_absolute():
        config = config.model_copy(update={"output_dir": base_dir / config.output_dir})
    devices = config.devices
    camera, relays = devices.camera, devices.relays
    if isinstance(camera, TwinCameraConfig) and camera.data_dir is not None:
        camera = camera.model_copy(update={"data_dir": base_dir / camera.data_dir})
    if isinstance(relays, TwinRelayConfig) and relays.state_file is not None:
        relays = relays.model_copy(update={"state_file": base_dir / relays.state_file})
    spectrometer = devices.spectrometer
    if isinstance(spectrometer, SeabreezeSpectrometerConfig) and spectrometer.calibration_file:
        spectrometer = spectrometer.model_copy(
            update={"calibration_file": base_dir / spectrometer.calibration_file}
        )
    if isinstance(spectrometer, FilesSpectrometerConfig):
        spectrometer = spectrometer.model_copy(
            update={"directory": base_dir / spectrometer.directory}
        )
    devices = devices.model_copy(
        update={"camera": camera, "relays": relays, "spectrometer": spectrometer}
    )
    return config.model_copy(update={"devices": devices})


def load_config(path: str | Path) -> RigConfig:
    """Read and validate a configuration file (see :func:`parse_config`)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(
            str(path),
            [
                ConfigIssue(
                    "",
                    "file not found; pass --config PATH, or write one with `rig init` "
                    "(`rig init --twin` for the digital twin)",
                )
            ],
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), [ConfigIssue("", f"cannot read the file: {exc}")]) from None
    return parse_config(text, source=str(path), base_dir=path.resolve().parent)
