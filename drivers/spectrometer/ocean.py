"""Ocean Optics / Ocean Insight USB spectrometers through python-seabreeze's pure-Python backend.

pyseabreeze speaks the instruments' two USB protocols over pyusb bulk transfers: the OOI opcodes of
the USB2000+/Flame-S family (``0x01`` initialise, ``0x02`` integration time, ``0x05`` EEPROM slot,
``0x09`` spectrum, ``0x6B`` FPGA register, ``0xFE`` status) and the framed OBP messages of the newer
ones (STS, QE Pro: ``0xC0C1`` header, 32-bit message type, ``0xC2C3C4C5`` footer). This driver uses
pyseabreeze's device features for those exchanges and adds what a radiometric measurement needs
and seabreeze leaves to its user:

- **integration time with automatic ranging** against saturation (:func:`range_integration`): a
  ladder of integration times (1-2-5 per decade within the configured and instrument limits), climbed
  from its shortest rung until the peak sits below ``target_fraction`` of full scale; a fixed
  integration time when the configuration gives one;
- **the first scan after a change of integration time is discarded** (seabreeze issues #110, #177:
  the instrument acquires continuously and hands over a scan integrated with the old time);
- **a dark spectrum** per rung, measured by :meth:`OceanSpectrometer.measure_dark` while the rig
  has every lamp off (a plan step), subtracted from every scan at the same integration time;
- **electric-dark correction** (the optically masked pixels' mean, tracking baseline drift between
  the dark and the scan) and **nonlinearity correction** (the EEPROM polynomial), each ``auto``
  (used when the instrument has them), ``on`` (required) or ``off``;
- **averaging** of ``averages`` scans;
- **a relative irradiance calibration** (:class:`IrradianceCalibration`, loaded by the rig from a
  file): the spectrum handed on is counts per ms times the calibration's factor, on the
  calibration's wavelength range. Without one the driver refuses to open unless told
  (``allow_uncalibrated``): raw counts carry the instrument's own spectral response, which would
  enter the camera estimate as if it were the lamp's.

Every bulk transfer is recorded through :class:`drivers.usb_bulk.RecordingBackend`.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from drivers.base import (
    DarkReading,
    DeviceBusy,
    DeviceError,
    DeviceIdentity,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ProtocolError,
    SpectrumReading,
    TranscriptSink,
)
from drivers.libraries import pyseabreeze, pyusb
from drivers.lifecycle import ClosesOnExit
from drivers.usb_bulk import RecordingBackend, recording_backend

__all__ = [
    "DEFAULT_INTEGRATION_RANGE_MS",
    "CorrectionChoice",
    "DarkMissing",
    "DarkReading",
    "IrradianceCalibration",
    "OceanInfo",
    "OceanSettings",
    "OceanSpectrometer",
    "corrected_counts",
    "find_ocean_spectrometers",
    "integration_ladder_ms",
    "open_ocean",
    "range_integration",
]

T = TypeVar("T")
FloatArray = NDArray[np.float64]
CorrectionChoice = Literal["auto", "on", "off"]

#: Integration times the ranging may use unless the configuration narrows them, ms.
DEFAULT_INTEGRATION_RANGE_MS = (1.0, 5000.0)
#: The sync byte that ends an OOI spectrum transfer (pyseabreeze drops it unchecked).
OOI_SYNC_BYTE = 0x69
#: Scans discarded after the integration time changed (the instrument hands over one stale scan).
STALE_SCANS_AFTER_CHANGE = 1
#: Extra USB deadline beyond the integration time of a scan, ms.
DEFAULT_TIMEOUT_MS = 5000

_ERRNO_GONE = frozenset({errno.ENODEV, errno.ENOENT, errno.ESHUTDOWN, errno.EIO})
_ERRNO_BUSY = frozenset({errno.EBUSY, errno.EAGAIN})
_UDEV_HINT = (
    "install Ocean's udev rule (python-seabreeze ships it: `seabreeze_os_setup`) or a rule such as "
    'SUBSYSTEM=="usb", ATTR{idVendor}=="2457", MODE="0666", then replug the spectrometer'
)


class DarkMissing(DeviceError):
    """A measurement was asked for before the dark spectrum at its integration time."""

    reason = "dark_missing"


# ------------------------------------------------------------------------------- calibration


@dataclass(frozen=True, eq=False)
class IrradianceCalibration:
    """Relative spectral irradiance per (count per ms): ``E(λ) = counts_per_ms(λ) × factor(λ)``.

    Parameters
    ----------
    wavelength_nm, factor
        Shape ``(n,)``, increasing wavelengths; factors > 0.
    source
        Where it came from (a file path, or the twin's built-in calibration), for the identity.
    units
        The unit of the calibrated values (relative unless the file says otherwise).
    """

    wavelength_nm: FloatArray
    factor: FloatArray
    source: str
    units: str = "relative spectral irradiance"

    def __post_init__(self) -> None:
        if self.wavelength_nm.shape != self.factor.shape or self.wavelength_nm.ndim != 1:
            raise ValueError(
                f"calibration {self.source}: {self.wavelength_nm.shape} wavelengths, "
                f"{self.factor.shape} factors"
            )
        if self.wavelength_nm.size < 2 or np.any(np.diff(self.wavelength_nm) <= 0):
            raise ValueError(f"calibration {self.source}: wavelengths must increase")
        if not np.all(np.isfinite(self.factor)) or np.any(self.factor <= 0):
            raise ValueError(f"calibration {self.source}: every factor must be finite and > 0")

    @property
    def sha256(self) -> str:
        """A digest of the numbers (what makes two calibrations the same)."""
        digest = hashlib.sha256(np.ascontiguousarray(self.wavelength_nm).tobytes())
        digest.update(np.ascontiguousarray(self.factor).tobytes())
        return digest.hexdigest()

    @property
    def range_nm(self) -> tuple[float, float]:
        return float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])

    def factors_at(self, wavelength_nm: FloatArray) -> FloatArray:
        """Factors interpolated onto ``wavelength_nm`` (inside :attr:`range_nm` only)."""
        return np.interp(wavelength_nm, self.wavelength_nm, self.factor)


# ------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class OceanSettings:
    """How the driver measures.

    Parameters
    ----------
    integration_range_ms
        Shortest and longest integration time the ranging may use (clipped to the instrument's).
    averages
        Scans averaged per spectrum (and per dark).
    target_fraction
        The ranging aims the peak at this fraction of full scale.
    saturation_fraction
        A scan whose active pixels reach this fraction of full scale is saturated.
    min_signal_fraction
        At the longest integration time, a peak below this fraction of full scale is too weak.
    electric_dark, nonlinearity
        ``auto``: used when the instrument has them; ``on``: required; ``off``.
    calibration
        The relative irradiance calibration (``None``: counts per ms, see ``allow_uncalibrated``).
    allow_uncalibrated
        Open without a calibration (spectra in counts per ms, shaped by the instrument's response).
    bandwidth_nm
        The optical resolution (FWHM) of the instrument's slit and grating, when known.
    timeout_ms
        USB deadline of a scan beyond its integration time.
    """

    integration_range_ms: tuple[float, float] = DEFAULT_INTEGRATION_RANGE_MS
    averages: int = 3
    target_fraction: float = 0.75
    saturation_fraction: float = 0.95
    min_signal_fraction: float = 0.02
    electric_dark: CorrectionChoice = "auto"
    nonlinearity: CorrectionChoice = "auto"
    calibration: IrradianceCalibration | None = None
    allow_uncalibrated: bool = False
    bandwidth_nm: float | None = None
    timeout_ms: int = DEFAULT_TIMEOUT_MS

    def __post_init__(self) -> None:
        low, high = self.integration_range_ms
        if not 0 < low < high:
            raise ValueError(f"integration_range_ms must be 0 < low < high, got {low}, {high}")
        if self.averages < 1:
            raise ValueError(f"averages must be >= 1, got {self.averages}")
        if not 0 < self.target_fraction < self.saturation_fraction <= 1:
            raise ValueError("need 0 < target_fraction < saturation_fraction <= 1")


# ------------------------------------------------------------------------------- pure parts


def integration_ladder_ms(low_ms: float, high_ms: float) -> tuple[float, ...]:
    """The integration times ranging chooses from: 1-2-5 per decade within ``[low_ms, high_ms]``.

    The ends are always rungs, so the instrument's shortest and the configured longest are reachable.

    >>> integration_ladder_ms(1.0, 60.0)
    (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 60.0)
    """
    if not 0 < low_ms < high_ms:
        raise ValueError(f"need 0 < low < high, got {low_ms}, {high_ms}")
    rungs = {float(low_ms), float(high_ms)}
    decade = 10.0 ** math.floor(math.log10(low_ms))
    while decade <= high_ms:
        for step in (1.0, 2.0, 5.0):
            value = round(step * decade, 6)
            if low_ms < value < high_ms:
                rungs.add(value)
        decade *= 10.0
    return tuple(sorted(rungs))


def range_integration(
    ladder_ms: Sequence[float],
    peak_counts: Callable[[float], float],
    *,
    saturation_counts: float,
    target_counts: float,
    weak_counts: float,
) -> float:
    """The longest rung whose scan stays below ``target_counts`` (predicted linearly from a scan).

    Climbs from the shortest rung: a scan's peak (signal above dark) predicts the integration time
    reaching ``target_counts``; the next scan is at the longest rung not beyond it. A saturated scan
    marks its rung and every longer one as too long. Deterministic for given scans (a resumed run
    ranges as the original did).

    Raises
    ------
    InstrumentError
        Saturated at the shortest rung (``code="saturated"``), or below ``weak_counts`` at the
        longest (``code="weak_light"``).
    """
    index, too_long = 0, len(ladder_ms)
    while True:
        integration_ms = ladder_ms[index]
        peak = peak_counts(integration_ms)
        if peak >= saturation_counts:
            if index == 0:
                raise InstrumentError(
                    "spectrometer",
                    f"saturated at the shortest integration time {integration_ms:g} ms: attenuate "
                    "the light (neutral density, a longer fibre, a smaller aperture)",
                    code="saturated",
                    command=f"scan at {integration_ms:g} ms",
                )
            too_long = index
            index -= 1
            continue
        wanted_ms = integration_ms * target_counts / peak if peak > 0 else math.inf
        best = index
        while best + 1 < too_long and ladder_ms[best + 1] <= wanted_ms:
            best += 1
        if best == index:
            if index == len(ladder_ms) - 1 and peak < weak_counts:
                raise InstrumentError(
                    "spectrometer",
                    f"weak light: the peak reaches {peak:.0f} counts at the longest integration "
                    f"time {integration_ms:g} ms (needed {weak_counts:.0f}); raise "
                    "devices.spectrometer.integration_max_ms or bring the probe closer",
                    code="weak_light",
                    command=f"scan at {integration_ms:g} ms",
                )
            return integration_ms
        index = best


def corrected_counts(
    raw: FloatArray,
    dark: FloatArray | None,
    dark_pixels: Sequence[int],
    nonlinearity: Sequence[float] | None,
) -> FloatArray:
    """Signal counts of a scan: electric dark, nonlinearity, then the dark spectrum, removed.

    Parameters
    ----------
    raw, dark
        Shape ``(n_pixels,)``: the scan and the dark at the same integration time (``None``: none).
    dark_pixels
        Indices of the optically masked pixels (empty: no electric-dark correction).
    nonlinearity
        Polynomial coefficients ``c0, c1, …`` of the counts' response (seabreeze's convention:
        linear counts = counts / poly(counts)); ``None``: no correction.

    Notes
    -----
    The nonlinearity is a property of the detector's fill, so it is applied to the scan and to the
    dark separately (each above its electric-dark baseline) before they are subtracted.

    >>> corrected_counts(np.array([110.0, 300.0]), np.array([100.0, 100.0]), [], None)
    array([ 10., 200.])
    """

    def linear(counts: FloatArray) -> FloatArray:
        above = counts - float(np.mean(counts[list(dark_pixels)])) if dark_pixels else counts
        if nonlinearity is None:
            return above
        response = np.polynomial.polynomial.polyval(above, np.asarray(nonlinearity, dtype=float))
        return np.asarray(above / response, dtype=np.float64)

    signal = linear(raw)
    if dark is not None:
        signal = signal - linear(dark)
    return np.asarray(signal, dtype=np.float64)


# ------------------------------------------------------------------------------- readings


@dataclass(frozen=True)
class OceanInfo:
    """An Ocean spectrometer found on the bus."""

    model: str
    serial: str
    port: str


# ------------------------------------------------------------------------------- the driver


def _usb_port(pyusb_device: Any) -> str:
    bus, address = getattr(pyusb_device, "bus", None), getattr(pyusb_device, "address", None)
    if bus is None or address is None:
        return "usb"
    return f"usb:{int(bus):03d},{int(address):03d}"


def _typed_error(label: str, what: str, exc: BaseException, timeout_s: float) -> DeviceError:
    """A pyusb or pyseabreeze exception as the rig's typed device error."""
    usb = pyusb()
    code = getattr(exc, "errno", None)
    text = str(getattr(exc, "strerror", None) or exc) or type(exc).__name__
    if isinstance(exc, usb.USBTimeoutError) or code == errno.ETIMEDOUT:
        return DeviceTimeout(
            label, f"no answer within {timeout_s:g} s during {what} ({text})", timeout_s=timeout_s
        )
    if code in _ERRNO_GONE:
        return Disconnected(label, f"the spectrometer went away during {what} ({text})")
    if code in _ERRNO_BUSY or type(exc).__name__ == "USBTransportDeviceInUse":
        return DeviceBusy(
            label, f"the spectrometer is in use by another program during {what} ({text})"
        )
    if code == errno.EACCES:
        return DeviceNotFound(label, f"permission denied on the USB device: {_UDEV_HINT}")
    if code == errno.EPIPE:
        return ProtocolError(label, f"the spectrometer stalled {what}", command=what, reply=None)
    return ProtocolError(
        label, f"{what} failed: {type(exc).__name__}: {text}", command=what, reply=None
    )


#: What pyseabreeze and pyusb raise on a bad or missing answer (struct and assertion errors come
#: from pyseabreeze's own frame checks).
def _device_exceptions() -> tuple[type[BaseException], ...]:
    usb = pyusb()
    sb = pyseabreeze()
    from seabreeze.pyseabreeze.transport import USBTransportDeviceInUse, USBTransportError

    return (
        usb.USBError,
        sb.SeaBreezeError,
        USBTransportError,
        USBTransportDeviceInUse,
        AssertionError,
        struct.error,
        ValueError,
        RuntimeError,
    )


class OceanSpectrometer(ClosesOnExit):
    """An open Ocean spectrometer; implements :class:`drivers.base.Spectrometer` and measures darks.

    Build it with :func:`open_ocean`. Not thread-safe.
    """

    def __init__(
        self,
        device: Any,
        backend: RecordingBackend,
        settings: OceanSettings,
        *,
        port: str,
    ) -> None:
        self._device = device
        self._backend = backend
        self.settings = settings
        self.port = port
        self.model = str(device.model)
        self.serial = str(device.serial_number)
        self.label = f"Ocean {self.model} {self.serial} on {port}"
        backend.label = self.label
        self._closed = False
        feature = self._call("read its configuration", lambda: device.f.spectrometer)
        self._feature = feature
        self.wavelength_nm = np.asarray(
            self._call("read the wavelength calibration", feature.get_wavelengths), dtype=float
        )
        self.max_counts = float(feature.get_maximum_intensity())
        low_us, high_us = feature.get_integration_time_micros_limits()
        self.instrument_range_ms = (low_us / 1000.0, high_us / 1000.0)
        self.dark_pixels = tuple(int(i) for i in feature.get_electric_dark_pixel_indices())
        self.nonlinearity = self._nonlinearity()
        if settings.electric_dark == "on" and not self.dark_pixels:
            raise DeviceNotFound(
                self.label,
                "electric_dark is 'on' but this model has no optically masked pixels; set it to "
                "'auto' or 'off'",
            )
        if settings.electric_dark == "off":
            self.dark_pixels = ()
        low = max(settings.integration_range_ms[0], self.instrument_range_ms[0])
        high = min(settings.integration_range_ms[1], self.instrument_range_ms[1] * 0.999)
        if not low < high:
            raise DeviceNotFound(
                self.label,
                f"the configured integration range {settings.integration_range_ms} ms lies "
                f"outside the instrument's {self.instrument_range_ms} ms",
            )
        self.ladder_ms = integration_ladder_ms(low, high)
        self._fixed_ms: float | None = None
        self._current_us: int | None = None
        self._stale = 0
        self._darks: dict[float, FloatArray] = {}
        calibration = settings.calibration
        if calibration is None and not settings.allow_uncalibrated:
            raise DeviceNotFound(
                self.label,
                "no irradiance calibration: set devices.spectrometer.calibration_file (the "
                "instrument's relative irradiance calibration, or one made against a known lamp); "
                "spectra in raw counts carry the spectrometer's own response into the estimate. "
                "Set allow_uncalibrated: true only to look at raw spectra",
            )
        if calibration is None:
            self._in_range = np.ones(self.wavelength_nm.shape, dtype=bool)
        else:
            low_nm, high_nm = calibration.range_nm
            self._in_range = (self.wavelength_nm >= low_nm) & (self.wavelength_nm <= high_nm)
            if np.count_nonzero(self._in_range) < 2:
                raise DeviceNotFound(
                    self.label,
                    f"the calibration {calibration.source} covers {low_nm:g}–{high_nm:g} nm, "
                    f"the spectrometer {self.wavelength_nm[0]:g}–{self.wavelength_nm[-1]:g} nm",
                )
        active = np.ones(self.wavelength_nm.shape, dtype=bool)
        active[list(self.dark_pixels)] = False
        self._active = active
        self._in_range &= active  # the optically masked pixels are not part of the spectrum

    # ------------------------------------------------------------------------------ plumbing

    def _call(self, what: str, function: Callable[[], T], timeout_ms: int | None = None) -> T:
        if self._closed:
            raise Disconnected(self.label, "the driver was closed; open the spectrometer again")
        try:
            return function()
        except DeviceError:
            raise
        except _device_exceptions() as exc:
            seconds = (timeout_ms or self.settings.timeout_ms) / 1000.0
            raise _typed_error(self.label, what, exc, seconds) from exc

    def _nonlinearity(self) -> tuple[float, ...] | None:
        choice = self.settings.nonlinearity
        feature = getattr(self._device.f, "nonlinearity_coefficients", None)
        coefficients: tuple[float, ...] | None = None
        if feature is not None and choice != "off":
            values = self._call(
                "read the nonlinearity coefficients", feature.get_nonlinearity_coefficients
            )
            coefficients = tuple(float(v) for v in values) or None
        if choice == "on" and coefficients is None:
            raise DeviceNotFound(
                self.label,
                "nonlinearity is 'on' but pyseabreeze reads no nonlinearity coefficients from "
                "this model; set it to 'auto' or 'off'",
            )
        return coefficients

    @property
    def device(self) -> str:
        return self.label

    def identify(self) -> DeviceIdentity:
        settings = self.settings
        calibration = settings.calibration
        extra = {
            "driver": "seabreeze",
            "backend": "pyseabreeze",
            "pixels": str(self.wavelength_nm.size),
            "integration_ladder_ms": ",".join(f"{v:g}" for v in self.ladder_ms),
            "averages": str(settings.averages),
            "electric_dark": "on" if self.dark_pixels else "off",
            "nonlinearity": "on" if self.nonlinearity else "off",
            "calibration": calibration.source if calibration else "none (counts per ms)",
            "timeout_ms": str(settings.timeout_ms),
        }
        if settings.bandwidth_nm is not None:
            extra["bandwidth_nm"] = f"{settings.bandwidth_nm:g}"
        if calibration is not None:
            extra["calibration_sha256"] = calibration.sha256
        return DeviceIdentity(
            kind="spectrometer", model=self.model, serial=self.serial, port=self.port, extra=extra
        )

    # ------------------------------------------------------------------------------ settings

    def set_exposure(self, exposure_ms: float | None) -> None:
        """A fixed integration time in ms, or ``None`` for automatic ranging on the ladder."""
        if exposure_ms is None:
            self._fixed_ms = None
            return
        low, high = self.instrument_range_ms
        if not low <= exposure_ms < high:
            raise ValueError(
                f"{self.label}: integration time must be {low:g}–{high:g} ms, got {exposure_ms!r}"
            )
        self._fixed_ms = float(exposure_ms)

    def _integration_times(self) -> tuple[float, ...]:
        return (self._fixed_ms,) if self._fixed_ms is not None else self.ladder_ms

    def _set_integration(self, integration_ms: float) -> None:
        micros = round(integration_ms * 1000.0)
        if micros == self._current_us:
            return
        self._call(
            f"set the integration time to {integration_ms:g} ms",
            lambda: self._feature.set_integration_time_micros(micros),
        )
        self._current_us = micros
        self._stale = STALE_SCANS_AFTER_CHANGE

    def _scan(self, integration_ms: float) -> FloatArray:
        """One scan's raw counts at ``integration_ms`` (stale scans after a change discarded)."""
        self._set_integration(integration_ms)
        timeout_ms = int(integration_ms) + self.settings.timeout_ms
        while True:
            counts = self._call(
                f"read a spectrum at {integration_ms:g} ms",
                self._feature.get_intensities,
                timeout_ms,
            )
            self._check_frame(integration_ms)
            if self._stale > 0:
                self._stale -= 1
                continue
            return np.asarray(counts, dtype=np.float64)

    def _check_frame(self, integration_ms: float) -> None:
        """An OOI spectrum transfer ends with its sync byte, which pyseabreeze does not check."""
        data = self._backend.last_read
        if len(data) == 2 * self.wavelength_nm.size + 1 and data[-1] != OOI_SYNC_BYTE:
            raise ProtocolError(
                self.label,
                f"spectrum at {integration_ms:g} ms does not end with the sync byte "
                f"0x{OOI_SYNC_BYTE:02x}",
                command=bytes([0x09]),
                reply=data[-16:],
            )

    def _average(self, integration_ms: float) -> FloatArray:
        scans = [self._scan(integration_ms) for _ in range(self.settings.averages)]
        return np.asarray(np.mean(scans, axis=0), dtype=np.float64)

    # ------------------------------------------------------------------------------ measuring

    def measure_dark(self) -> DarkReading:
        """Dark spectra at every integration time the driver may use; the rig has the lamps off."""
        times = self._integration_times()
        counts = np.stack([self._average(t) for t in times])
        self._darks = dict(zip(times, counts, strict=True))
        return DarkReading(self.wavelength_nm.copy(), times, counts)

    def _dark(self, integration_ms: float) -> FloatArray:
        dark = self._darks.get(integration_ms)
        if dark is None:
            raise DarkMissing(
                self.label,
                f"no dark spectrum at {integration_ms:g} ms: measure the dark (lamps off) after "
                "setting the integration time and before measuring",
            )
        return dark

    def _peak(self, integration_ms: float) -> float:
        signal = corrected_counts(
            self._scan(integration_ms), self._dark(integration_ms), self.dark_pixels, None
        )
        return float(np.max(signal[self._active]))

    def _saturated(self, raw: FloatArray) -> bool:
        return bool(
            np.max(raw[self._active]) >= self.settings.saturation_fraction * self.max_counts
        )

    def measure(self) -> SpectrumReading:
        """Range (or take the fixed integration time), average, correct and calibrate a spectrum.

        The spectrum covers the calibration's wavelength range (no optically masked pixels).

        Raises
        ------
        DarkMissing
            :meth:`measure_dark` has not been called since the integration time was chosen.
        InstrumentError
            Saturated at the shortest, or too weak at the longest integration time; or the light
            saturated the averaged scans at a fixed integration time.
        DeviceTimeout, ProtocolError, Disconnected
            USB trouble.
        """
        integration_ms, rate, peak = self._measure_rate()
        settings = self.settings
        calibration = settings.calibration
        wavelength = self.wavelength_nm[self._in_range]
        values = rate[self._in_range]
        units = "counts/ms (uncalibrated)"
        if calibration is not None:
            values = values * calibration.factors_at(wavelength)
            units = calibration.units
        return SpectrumReading(
            wavelength_nm=wavelength,
            values=np.asarray(values, dtype=np.float64),
            units=units,
            exposure_ms=integration_ms,
            bandwidth_nm=settings.bandwidth_nm,
            extra={"averages": str(settings.averages), "peak_counts": f"{peak:.0f}"},
        )

    def measure_counts_per_ms(self) -> SpectrumReading:
        """A spectrum as :meth:`measure` takes it, without the calibration: corrected counts per
        ms on every active pixel (what a calibration against a known lamp divides into)."""
        integration_ms, rate, peak = self._measure_rate()
        return SpectrumReading(
            wavelength_nm=self.wavelength_nm[self._active],
            values=rate[self._active],
            units="counts/ms (uncalibrated)",
            exposure_ms=integration_ms,
            bandwidth_nm=self.settings.bandwidth_nm,
            extra={"averages": str(self.settings.averages), "peak_counts": f"{peak:.0f}"},
        )

    def _measure_rate(self) -> tuple[float, FloatArray, float]:
        """Integration time, corrected counts per ms on every pixel, and the raw peak."""
        settings = self.settings
        if self._fixed_ms is not None:
            integration_ms = self._fixed_ms
        else:
            integration_ms = range_integration(
                self.ladder_ms,
                self._peak,
                saturation_counts=settings.saturation_fraction * self.max_counts,
                target_counts=settings.target_fraction * self.max_counts,
                weak_counts=settings.min_signal_fraction * self.max_counts,
            )
        dark = self._dark(integration_ms)
        raw = self._average(integration_ms)
        if self._saturated(raw):
            raise InstrumentError(
                self.label,
                f"light overload: the averaged scans at {integration_ms:g} ms reach full scale "
                "(the light changed while ranging, or the fixed integration time is too long)",
                code="saturated",
                command=f"scan at {integration_ms:g} ms",
            )
        rate = corrected_counts(raw, dark, self.dark_pixels, self.nonlinearity) / integration_ms
        return integration_ms, rate, float(np.max(raw[self._active]))

    # ------------------------------------------------------------------------------ closing

    def close(self) -> None:
        """Release the USB device (pyseabreeze resets it); never raises for a device that is gone."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(Exception):
            self._device.close()
        self._backend.event("close")
        self._backend.transcript = None  # the session closes its transcripts after this


@dataclass
class _Found:
    info: OceanInfo
    device: Any
    problems: list[str] = field(default_factory=list)


def _open_all(backend: RecordingBackend) -> tuple[list[_Found], list[str]]:
    """Open every Ocean spectrometer pyseabreeze supports on ``backend``; each is left open."""
    usb = pyusb()
    pyseabreeze()
    from seabreeze.pyseabreeze.devices import SeaBreezeDevice
    from seabreeze.pyseabreeze.transport import USBTransport, USBTransportHandle

    supported = USBTransport.vendor_product_ids
    try:
        matches = list(
            usb.find(
                find_all=True,
                backend=backend,
                custom_match=lambda d: (d.idVendor, d.idProduct) in supported,
            )
        )
    except usb.NoBackendError as exc:
        raise DeviceNotFound("Ocean spectrometer", f"no USB backend available: {exc}") from exc
    found: list[_Found] = []
    skipped: list[str] = []
    for pyusb_device in matches:
        port = _usb_port(pyusb_device)
        label = f"Ocean spectrometer on {port}"
        try:
            device = SeaBreezeDevice(USBTransportHandle(pyusb_device))
            device.open()
            info = OceanInfo(str(device.model), str(device.serial_number), port)
        except _device_exceptions() as exc:
            skipped.append(f"{label}: {_typed_error(label, 'opening', exc, 1.0).message}")
            continue
        found.append(_Found(info, device))
    return found, skipped


def find_ocean_spectrometers(
    *, backend: Any = None, transcript: TranscriptSink | None = None
) -> tuple[list[OceanInfo], list[str]]:
    """The Ocean spectrometers on the bus (model, serial, port), and why other matches were skipped.

    Raises
    ------
    drivers.libraries.HardwareLibraryMissing
        pyusb or python-seabreeze is not installed.
    DeviceNotFound
        No USB backend (libusb) on this system.
    """
    found, skipped = _open_all(recording_backend(backend, "Ocean spectrometer", transcript))
    for item in found:
        with contextlib.suppress(Exception):
            item.device.close()
    return [item.info for item in found], skipped


def open_ocean(
    serial: str | None,
    settings: OceanSettings,
    *,
    backend: Any = None,
    transcript: TranscriptSink | None = None,
) -> OceanSpectrometer:
    """Find and open an Ocean spectrometer (by serial number, or the only one present).

    Parameters
    ----------
    serial
        The serial number (``USB2G12345``, ``S01234``); ``None``: the only spectrometer present.
    settings
        How to measure (calibration, ranging, corrections).
    backend
        A pyusb backend (``None``: libusb); every bulk transfer through it is recorded.
    transcript
        Where the transfers go.

    Raises
    ------
    DeviceNotFound
        None found, none with that serial, several and no serial given; no calibration and
        ``allow_uncalibrated`` not set; a correction required that the model lacks.
    """
    recorder = recording_backend(backend, "Ocean spectrometer", transcript)
    found, skipped = _open_all(recorder)
    wanted = [item for item in found if serial is None or item.info.serial == serial]
    chosen = wanted[0] if len(wanted) == 1 else None
    for item in found:
        if item is not chosen:
            with contextlib.suppress(Exception):
                item.device.close()
    if chosen is None:
        listed = ", ".join(f"{f.info.model} {f.info.serial!r} on {f.info.port}" for f in found)
        others = f"; skipped: {'; '.join(skipped)}" if skipped else ""
        if not found:
            message = f"no Ocean Optics spectrometer found on USB{others}"
        elif serial is None:
            message = (
                f"{len(found)} spectrometers found ({listed}); set devices.spectrometer.serial"
            )
        else:
            message = f"no spectrometer with serial {serial!r}; found {listed}{others}"
        raise DeviceNotFound("Ocean spectrometer", message)
    try:
        instrument = OceanSpectrometer(chosen.device, recorder, settings, port=chosen.info.port)
    except BaseException:
        with contextlib.suppress(Exception):
            chosen.device.close()
        raise
    recorder.event("open", model=instrument.model, serial=instrument.serial, port=instrument.port)
    return instrument
