"""``rig calibrate-spectrometer``: an Ocean spectrometer's relative irradiance calibration, made
against a lamp whose spectrum is known.

An Ocean spectrometer counts photo-electrons: its raw spectrum is the light times the response of
its grating, detector and fibre. The calibration file the driver loads
(``devices.spectrometer.calibration_file``, :class:`drivers.spectrometer.ocean.IrradianceCalibration`)
holds the factor that turns counts per ms into relative spectral irradiance. Without the
manufacturer's, it can be made against any lamp whose relative spectrum is known — a tungsten-halogen
lamp is close to CIE illuminant A (a Planckian at 2856 K), a calibrated lamp comes with its table:

1. every lamp off, the dark spectra measured at every integration time the driver may use;
2. the reference lamp on (a relay channel: ``--channel``, or the configured lamp of that name),
   waited ``--warmup`` seconds, then ``--repeats`` spectra in counts per ms (ranged against
   saturation, dark, electric-dark and nonlinearity corrected, averaged) — their spread is reported;
3. every lamp off (whatever happened);
4. ``factor(λ) = known(λ) / counts_per_ms(λ)`` on a 1 nm grid, where both are defined and the
   lamp gives at least ``--min-signal`` of its peak (elsewhere the factor would be noise),
   normalised to a mean of 1 over the grid, and written as ``wavelength_nm,factor`` with a header
   saying what it was made from.

A smooth lamp is the right reference: the spectrometer's slit blurs what it measures (``bandwidth_nm``)
and a known spectrum with lines or steps finer than that would print them into the factor.
"""

from __future__ import annotations

import contextlib
import datetime
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import Spectrum, WavelengthGrid
from drivers.base import ListTranscript, RelayBoard, SpectrumReading
from drivers.spectrometer.ocean import OceanSpectrometer
from rig.clock import Clock, MonotonicClock
from rig.config import RigConfig, SeabreezeSpectrometerConfig, TwinSpectrometerConfig
from rig.errors import RigError
from rig.hardware import open_configured_spectrometer, open_relays
from rig.twin import open_twin_bench

__all__ = [
    "CalibrationOutcome",
    "SpectrometerCalibrationError",
    "calibrate_spectrometer",
    "calibration_factors",
]

#: Below this fraction of the lamp's peak (counts per ms) the factor is left out.
DEFAULT_MIN_SIGNAL = 0.005


class SpectrometerCalibrationError(RigError):
    """The calibration cannot be made (wrong spectrometer, no channel, no usable range)."""

    reason = "calibration"
    exit_code = 2


@dataclass(frozen=True)
class CalibrationOutcome:
    """What was written, and how good the measurement was.

    Attributes
    ----------
    path
        The calibration file.
    wavelength_nm, factor
        Its content, shape ``(n,)``.
    integration_ms
        Integration time the ranging chose.
    spread
        Largest relative standard deviation between the repeated spectra over the range.
    """

    path: Path
    wavelength_nm: FloatArray
    factor: FloatArray
    integration_ms: float | None
    spread: float


def calibration_factors(
    counts_per_ms: Spectrum,
    known: Spectrum,
    *,
    min_signal: float = DEFAULT_MIN_SIGNAL,
    bandwidth_nm: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """``known / counts_per_ms`` on a 1 nm grid where both exist and the signal is enough.

    Returns ``(wavelength_nm, factor)``, the factor normalised to a mean of 1. Within
    ``bandwidth_nm`` (the spectrometer's slit) of an end of the known spectrum that the spectrometer
    reaches beyond, the measurement holds light the known table does not describe: left out.

    Raises
    ------
    SpectrometerCalibrationError
        The two spectra share less than 10 nm with enough signal.

    Examples
    --------
    >>> axis = np.arange(400.0, 701.0, 1.0)
    >>> counts = Spectrum(axis, 2.0 + (axis - 400.0) / 100.0)
    >>> wavelength, factor = calibration_factors(counts, Spectrum(axis, np.ones_like(axis)))
    >>> round(float(factor[0] / factor[-1]), 3)  # the response rose 2.5×: the factor falls 2.5×
    2.5
    """
    known_low, known_high = known.range_nm
    if counts_per_ms.range_nm[0] < known_low:
        known_low += bandwidth_nm
    if counts_per_ms.range_nm[1] > known_high:
        known_high -= bandwidth_nm
    low = math.ceil(max(counts_per_ms.range_nm[0], known_low))
    high = math.floor(min(counts_per_ms.range_nm[1], known_high))
    if high - low < 10:
        raise SpectrometerCalibrationError(
            f"the spectrometer ({counts_per_ms.range_nm[0]:g}–{counts_per_ms.range_nm[1]:g} nm) "
            f"and the known spectrum ({known.range_nm[0]:g}–{known.range_nm[1]:g} nm) overlap by "
            "less than 10 nm"
        )
    grid = WavelengthGrid(float(low), float(high), 1.0)
    rate = counts_per_ms.resample(grid, "integrate").values
    expected = known.resample(grid, "interpolate").values
    usable = (rate >= min_signal * float(np.max(rate))) & (expected > 0)
    peak = int(np.argmax(rate))
    start, stop = peak, peak
    while start > 0 and usable[start - 1]:
        start -= 1
    while stop < usable.size - 1 and usable[stop + 1]:
        stop += 1
    if stop - start < 10:
        raise SpectrometerCalibrationError(
            f"the lamp gives at least {min_signal:.1%} of its peak over less than 10 nm; use a "
            "broadband lamp (tungsten halogen)"
        )
    wavelength = grid.wavelength_nm[start : stop + 1]
    factor = expected[start : stop + 1] / rate[start : stop + 1]
    return np.asarray(wavelength), np.asarray(factor / np.mean(factor))


@dataclass
class _Devices:
    spectrometer: OceanSpectrometer
    relays: RelayBoard
    clock: Clock
    close: Callable[[], None]


def _open(config: RigConfig) -> _Devices:
    """The relay board and the Ocean spectrometer of ``config`` (the twin's, or the real ones)."""
    spectrometer_config = config.devices.spectrometer
    ocean = isinstance(spectrometer_config, SeabreezeSpectrometerConfig) or (
        isinstance(spectrometer_config, TwinSpectrometerConfig)
        and spectrometer_config.emulate == "seabreeze"
    )
    if not ocean:
        raise SpectrometerCalibrationError(
            f"devices.spectrometer is {config.devices.spectrometer_model!r}: this command "
            "calibrates Ocean spectrometers (kind: seabreeze); spectroradiometers (PR-655/670, "
            "CS-2000) and ArgyllCMS instruments report calibrated spectra themselves"
        )
    transcript = ListTranscript()
    if config.devices.relays.kind == "twin":
        bench = open_twin_bench(config, lambda role: transcript, prepare=False)
        spectrometer = bench.spectrometer
        relays: RelayBoard = bench.relays
        closers: list[Callable[[], object]] = [bench.close]
        if spectrometer is None:
            spectrometer = open_configured_spectrometer(spectrometer_config, transcript)
        clock: Clock = bench.clock
    else:
        relays = open_relays(config.devices.relays, transcript)
        closers = []
        try:
            spectrometer = open_configured_spectrometer(spectrometer_config, transcript)
        except BaseException:
            relays.close()
            raise
        clock = MonotonicClock()
    closers = [spectrometer.close, relays.close, *closers]

    def close() -> None:
        for closer in closers:
            with contextlib.suppress(Exception):
                closer()

    if not isinstance(spectrometer, OceanSpectrometer):
        close()
        raise SpectrometerCalibrationError("the configured spectrometer is not an Ocean one")
    return _Devices(spectrometer, relays, clock, close)


def _uncalibrated(config: RigConfig) -> RigConfig:
    """``config`` with its Ocean spectrometer allowed to open without a calibration file."""
    spectrometer = config.devices.spectrometer
    if not isinstance(spectrometer, SeabreezeSpectrometerConfig):
        return config
    spectrometer = spectrometer.model_copy(update={"allow_uncalibrated": True})
    devices = config.devices.model_copy(update={"spectrometer": spectrometer})
    return config.model_copy(update={"devices": devices})


def _channel(config: RigConfig, known: Spectrum, channel: int | None) -> int:
    if channel is not None:
        if not 1 <= channel <= config.devices.relays.channels:
            raise SpectrometerCalibrationError(
                f"--channel {channel}: the relay board has {config.devices.relays.channels} channels"
            )
        return channel
    for lamp in config.lamps:
        if lamp.name == known.name:
            return lamp.channel
    raise SpectrometerCalibrationError(
        f"which relay channel lights {known.name!r}? give --channel N (no lamp of the "
        "configuration has that name)"
    )


def _write(
    path: Path,
    wavelength: FloatArray,
    factor: FloatArray,
    header: list[str],
) -> None:
    lines = [f"# {line}" for line in header]
    lines.append("wavelength_nm,factor")
    lines += [f"{w:g},{f:.6e}" for w, f in zip(wavelength, factor, strict=True)]
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")
    temporary.replace(path)


def calibrate_spectrometer(
    config: RigConfig,
    known: Spectrum,
    out: Path,
    *,
    channel: int | None = None,
    warmup_s: float = 120.0,
    repeats: int = 3,
    min_signal: float = DEFAULT_MIN_SIGNAL,
    source: str | None = None,
) -> CalibrationOutcome:
    """Measure the lamp of spectrum ``known`` and write the calibration to ``out``.

    Parameters
    ----------
    config
        The rig (its relays and its Ocean spectrometer; the twin's when they are ``twin``).
    known
        The lamp's relative spectrum.
    out
        The calibration file to write (replaced atomically).
    channel
        Relay channel of the lamp (default: the configured lamp named like ``known``).
    warmup_s
        Time the lamp burns before it is measured.
    repeats
        Spectra averaged (their spread is reported).
    min_signal
        Fraction of the peak below which wavelengths are left out.
    source
        How the known spectrum was given (for the file's header).

    Raises
    ------
    SpectrometerCalibrationError
        Not an Ocean spectrometer, no channel, not enough signal.
    drivers.base.DeviceError
        The devices did not answer as they should (the lamp is switched off all the same).
    """
    if repeats < 1 or warmup_s < 0:
        raise InputError("repeats must be >= 1 and warmup >= 0 s", source="calibrate-spectrometer")
    lamp_channel = _channel(config, known, channel)
    devices = _open(_uncalibrated(config))
    spectrometer, relays = devices.spectrometer, devices.relays
    readings: list[SpectrumReading] = []
    try:
        relays.all_off()
        spectrometer.set_exposure(None)
        spectrometer.measure_dark()
        relays.set(lamp_channel, True)
        devices.clock.sleep(warmup_s)
        readings = [spectrometer.measure_counts_per_ms() for _ in range(repeats)]
    finally:
        with contextlib.suppress(Exception):
            relays.all_off()
        identity = spectrometer.identify()
        devices.close()
    stack = np.stack([reading.values for reading in readings])
    mean = np.mean(stack, axis=0)
    counts = Spectrum(readings[0].wavelength_nm, np.clip(mean, 0.0, None), name="counts per ms")
    wavelength, factor = calibration_factors(
        counts, known, min_signal=min_signal, bandwidth_nm=spectrometer.settings.bandwidth_nm or 2.0
    )
    inside = (readings[0].wavelength_nm >= wavelength[0]) & (
        readings[0].wavelength_nm <= wavelength[-1]
    )
    spread = 0.0
    if repeats > 1:
        relative = np.std(stack[:, inside], axis=0, ddof=1) / np.maximum(mean[inside], 1e-12)
        spread = float(np.median(relative))
    integration_ms = readings[0].exposure_ms
    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    header = [
        f"relative irradiance calibration of Ocean {identity.describe()}",
        f"made by rig calibrate-spectrometer at {now} against {known.name} "
        f"({source or 'given spectrum'}) on relay channel {lamp_channel}, after {warmup_s:g} s",
        f"integration {integration_ms:g} ms, {spectrometer.settings.averages} scans x "
        f"{repeats} spectra averaged, dark subtracted; median spread between spectra "
        f"{spread:.2%}",
        f"valid {wavelength[0]:g}-{wavelength[-1]:g} nm (signal >= {min_signal:.1%} of peak); "
        "factor normalised to a mean of 1: counts per ms x factor = relative irradiance",
    ]
    _write(out, wavelength, factor, header)
    return CalibrationOutcome(out, wavelength, factor, integration_ms, spread)
