"""The measurement physics behind the spectroradiometer emulators.

A spectroradiometer sees the source through a slit of finite bandwidth (a Gaussian of the stated
FWHM), converts light to counts with a wavelength-dependent responsivity, chooses an integration time
(adaptive exposure aims the brightest pixel at a fraction of full scale), subtracts a dark frame and
divides by its calibration. Noise is shot noise on the signal plus read noise on the light and the
dark frame, averaged over the requested cycles; the result therefore has realistic, wavelength-
dependent signal-to-noise (poor in the deep blue, where silicon and the grating are weak), and can dip
below zero where there is no light. All randomness comes from the seeded generator passed in.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

#: Radiance source: spectral radiance (W/(sr·m²·nm)) at the given wavelengths (nm), shape ``(n,)``.
RadianceSource = Callable[[NDArray[np.float64]], NDArray[np.float64]]

ObservationStatus = Literal["ok", "overload", "weak_light"]


@dataclass(frozen=True)
class RadiometerOptics:
    """What an instrument model is made of.

    Parameters
    ----------
    wavelength_nm
        The instrument's sampling grid, shape ``(n,)``.
    bandwidth_nm
        Full width at half maximum of the (Gaussian) slit function.
    peak_responsivity
        Counts per ms per W/(sr·m²·nm) at the most sensitive wavelength.
    exposure_range_ms
        Shortest and longest integration time.
    full_scale_counts
        Counts at which the detector saturates.
    read_noise_counts
        Standard deviation of one read.
    adaptive_target
        Fraction of full scale the adaptive exposure aims the peak at.
    weak_light_counts
        Peak counts below which adaptive exposure gives up ("weak light").
    overhead_s
        Fixed time per measurement (shutter, dark frame set-up, readout).
    """

    wavelength_nm: NDArray[np.float64]
    bandwidth_nm: float
    peak_responsivity: float
    exposure_range_ms: tuple[float, float]
    full_scale_counts: float = 60_000.0
    read_noise_counts: float = 6.0
    adaptive_target: float = 0.7
    weak_light_counts: float = 300.0
    overhead_s: float = 0.4

    def responsivity(self) -> NDArray[np.float64]:
        """Counts per ms per unit radiance on the sampling grid, shape ``(n,)``."""
        shape = 0.12 + 0.88 * np.exp(-0.5 * ((self.wavelength_nm - 610.0) / 140.0) ** 2)
        return np.asarray(self.peak_responsivity * shape, dtype=np.float64)


@dataclass(frozen=True)
class InstrumentDeviation:
    """How a real instrument differs, within its specification, from what it states.

    Attributes
    ----------
    offset_nm
        Wavelength-scale error at ``reference_nm``: the pixel the instrument reports as ``λ``
        sees light of ``λ + offset_nm + slope · (λ − reference_nm)``.
    slope
        Linear term of the scale error (nm per nm).
    bandwidth_factor
        The slit function's true FWHM over the stated one.
    reference_nm
        Where ``offset_nm`` applies.
    """

    offset_nm: float = 0.0
    slope: float = 0.0
    bandwidth_factor: float = 1.0
    reference_nm: float = 580.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.bandwidth_factor) and self.bandwidth_factor > 0):
            raise ValueError(f"bandwidth_factor must be > 0, got {self.bandwidth_factor}")

    def true_wavelength_nm(self, stated_nm: NDArray[np.float64]) -> NDArray[np.float64]:
        """The wavelength each stated one really sees, shape of ``stated_nm``."""
        shift = self.offset_nm + self.slope * (stated_nm - self.reference_nm)
        return np.asarray(stated_nm + shift, dtype=np.float64)


@dataclass(frozen=True)
class Observation:
    """The outcome of one measurement.

    ``radiance`` (shape ``(n,)``, W/(sr·m²·nm)) is ``None`` unless ``status == "ok"``;
    ``duration_s`` is the nominal time the instrument took (before any time scaling).
    """

    status: ObservationStatus
    exposure_ms: float
    duration_s: float
    radiance: NDArray[np.float64] | None = None
    peak_counts: float = 0.0


class Radiometer:
    """Measures a radiance source through :class:`RadiometerOptics`.

    Parameters
    ----------
    optics
        The instrument model.
    source
        Where the light comes from (e.g. :meth:`mocks.lamps.LampBank.radiance`).
    rng
        Seeded generator for the noise.
    deviation
        How the instrument differs from its stated scale and slit (``None``: not at all);
        settable later (:attr:`deviation`).
    """

    def __init__(
        self,
        optics: RadiometerOptics,
        source: RadianceSource,
        rng: np.random.Generator,
        deviation: InstrumentDeviation | None = None,
    ) -> None:
        self.optics = optics
        self.source = source
        self.rng = rng
        #: When set, every observation draws its noise from a fresh generator it returns (the twin
        #: keys the noise by the rig's step, so a repeated or resumed step measures the same).
        self.rng_per_observation: Callable[[], np.random.Generator] | None = None
        self.deviation = deviation
        self._responsivity = optics.responsivity()

    @property
    def deviation(self) -> InstrumentDeviation | None:
        """The instrument's true scale and slit against its stated ones (``None``: as stated)."""
        return self._deviation

    @deviation.setter
    def deviation(self, deviation: InstrumentDeviation | None) -> None:
        # The one place where the instrument's slit meets the light: every emulator's reading is
        # made of these weights, so a scale or slit error set here reaches all of them.
        self._deviation = deviation
        optics = self.optics
        centre_nm = optics.wavelength_nm
        bandwidth_nm = optics.bandwidth_nm
        if deviation is not None:
            centre_nm = deviation.true_wavelength_nm(centre_nm)
            bandwidth_nm = bandwidth_nm * deviation.bandwidth_factor
        sigma_nm = bandwidth_nm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
        step_nm = min(0.5, bandwidth_nm / 8.0)
        reach_nm = 4.0 * sigma_nm
        low_nm, high_nm = float(np.min(centre_nm)), float(np.max(centre_nm))
        self._fine_nm = np.arange(low_nm - reach_nm, high_nm + reach_nm + step_nm / 2, step_nm)
        weights = np.exp(-0.5 * ((centre_nm[:, None] - self._fine_nm[None, :]) / sigma_nm) ** 2)
        self._weights = weights / weights.sum(axis=1, keepdims=True)

    def band_radiance(self) -> NDArray[np.float64]:
        """Noise-free radiance as the instrument's slit sees it, on its grid, shape ``(n,)``."""
        fine = np.asarray(self.source(self._fine_nm), dtype=np.float64)
        return np.asarray(self._weights @ fine, dtype=np.float64)

    def observe(
        self, exposure_ms: float | None, averages: int = 1, *, attenuation: float = 1.0
    ) -> Observation:
        """Take one measurement; ``exposure_ms=None`` chooses the exposure adaptively.

        ``attenuation`` is a neutral-density filter in the light path (the detector sees
        ``attenuation`` times the light; the reported radiance is corrected for it).
        """
        optics = self.optics
        low_ms, high_ms = optics.exposure_range_ms
        radiance = self.band_radiance() * attenuation
        rate = radiance * self._responsivity  # counts per ms
        peak_rate = float(np.max(rate, initial=0.0))
        adaptive = exposure_ms is None
        if exposure_ms is None:
            wanted_ms = (
                optics.adaptive_target * optics.full_scale_counts / peak_rate
                if peak_rate > 0
                else high_ms
            )
            exposure_ms = float(np.clip(np.round(wanted_ms), low_ms, high_ms))
        duration_s = optics.overhead_s + 2.0 * exposure_ms * averages / 1000.0
        if adaptive:
            duration_s += optics.overhead_s + min(exposure_ms, 1000.0) / 1000.0
        signal = rate * exposure_ms
        peak_counts = float(np.max(signal, initial=0.0))
        if peak_counts > optics.full_scale_counts:
            return Observation("overload", exposure_ms, duration_s, peak_counts=peak_counts)
        if adaptive and peak_counts < optics.weak_light_counts:
            return Observation("weak_light", exposure_ms, duration_s, peak_counts=peak_counts)
        variance = np.clip(signal, 0.0, None) + 2.0 * optics.read_noise_counts**2
        rng = self.rng if self.rng_per_observation is None else self.rng_per_observation()
        noise = rng.standard_normal(signal.shape) * np.sqrt(variance / averages)
        measured = (signal + noise) / (self._responsivity * exposure_ms * attenuation)
        return Observation("ok", exposure_ms, duration_s, measured, peak_counts)
