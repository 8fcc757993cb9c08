"""The errors a real rig makes, each a small dataclass of physically motivated ranges.

Every class holds the *ranges* of one error source and draws one scene's (or one lamp's)
realisation from a seeded ``numpy.random.Generator``; :class:`RigErrors` bundles them, and any
source may be switched off (``None``). The defaults and why:

:class:`ExposureTimeError` — a frame's true exposure differs from the time its metadata records
    (mechanical shutters and the camera's own rounding): relative σ 1–3 % per frame. The HDR merge
    divides by the recorded time, so each frame carries a gain error; the direct spot is read from
    the short frames and the band from the long ones, so the direct/profile ratio — which the
    multi-lamp equations rest on — is off by the difference.
:class:`LampDrift` — the lamp changes between the spectrometer's reading and the capture, within
    the warm-up tolerance the rig waits for (``lamps[].warmup.tolerance``, 2 % in ``config.yaml``):
    a gain ``g`` and a tilt ``t`` per 100 nm about 550 nm, ``|g| ≤ tol/2``, ``|t| ≤ tol/3`` (so
    their sum stays within ``tol`` over 400–700 nm).
:class:`SpectrometerError` — the reference spectrum is measured, not known: a wavelength-scale
    offset of ±0.5 nm (a PR-655/CS-2000 class instrument's stated accuracy is ±0.5–2 nm; a
    calibrated one does better than 1 nm), a Gaussian slit function of 2–10 nm FWHM (CS-2000 5 nm,
    PR-655 8 nm, compact CCD spectrometers 2–10 nm), sampling at about half the bandwidth (1, 2 or
    4 nm), and noise of 0.3 % of the value plus 0.05 % of the peak per sample after the rig's three
    averaged readings. The estimator is told the bandwidth (the session records the instrument),
    not the offset.
:class:`StrayLight` — light of the direct spot scattered along the dispersion line (in-plane
    scatter of the grooves and the lens' flare streak): a fraction 0.1–1 % of the 0th order in a
    Lorentzian wing of half-width 100–1000 px centred on the spot. It lies on the band itself, so
    the background strips beside the band do not remove it (a uniform veil would be removed, and
    is not modelled); it matters where the band is dim — the channels' tails.
:class:`PhotonBudget` — shot and read noise of a real sensor behind the rig's HDR policy, not a
    fixed fraction of the peak: full well 8 000–60 000 e⁻ (phone to full-frame pixels, log-uniform),
    read noise 1.5–6 e⁻, the band summed over 20–200 sensor rows (the slit image's length), dark
    frames subtracted (``dark_frames`` per exposure, adding their read noise). The bracket follows
    ``config.yaml``'s ``hdr`` policy: the shortest frame puts the brightest pixel at 25–98 % of the
    clipping level (the policy stops once it is unsaturated, and steps are 2 stops) — the spot's, or
    the band's where a weak 0th order makes the band brighter (the rig's policy looks at the spot
    only, and would leave such a band clipped in every frame), frames
    grow by ``step_stops`` until the band's median SNR reaches ``min_band_snr`` (at most
    ``max_frames``). The frames are rendered as the sensor sees the slit's image, soft edges and
    all, and merged by the rig's own merge (:mod:`calib.image.hdr`; a sample is used below
    ``clip_fraction`` of the clipping level): :mod:`~calib.evaluation.validation.capture`, which
    adds a frame ``step_stops`` shorter where the shortest frame's exposure error lifts a sample
    over that level, as the rig extends a bracket whose shortest frame saturates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import Spectrum
from calib.core.spectrometer_tolerance import WAVELENGTH_SCALE_NM
from calib.image.raw import DEFAULT_SATURATION_FRACTION
from calib.image.sensor_noise import SITES_PER_SAMPLE


def _check_range(name: str, bounds: tuple[float, float], low: float = 0.0) -> None:
    if not (
        math.isfinite(bounds[0]) and math.isfinite(bounds[1]) and low <= bounds[0] <= bounds[1]
    ):
        raise InputError(f"range {bounds} must be finite, ordered and ≥ {low:g}", source=name)


def _log_uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(math.exp(rng.uniform(math.log(bounds[0]), math.log(bounds[1]))))


@dataclass(frozen=True)
class ExposureTimeError:
    """Per-frame shutter error: relative σ drawn per scene from ``sigma_range``."""

    sigma_range: tuple[float, float] = (0.01, 0.03)

    def __post_init__(self) -> None:
        _check_range("exposure.sigma_range", self.sigma_range)

    def draw(self, rng: np.random.Generator, n_frames: int) -> FloatArray:
        """Relative errors ``ε_k`` of ``n_frames`` frames (true time = recorded × (1 + ε_k))."""
        sigma = float(rng.uniform(*self.sigma_range))
        return np.asarray(sigma * rng.standard_normal(n_frames), dtype=np.float64)


@dataclass(frozen=True)
class LampDrift:
    """Drift between the spectrometer's reading and the capture, within the warm-up tolerance."""

    tolerance: float = 0.02

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance) and 0 <= self.tolerance < 0.5):
            raise InputError(
                f"must lie in [0, 0.5), got {self.tolerance}", source="drift.tolerance"
            )

    def draw(self, rng: np.random.Generator) -> tuple[float, float]:
        """``(gain, tilt per 100 nm)``."""
        return (
            float(rng.uniform(-self.tolerance / 2, self.tolerance / 2)),
            float(rng.uniform(-self.tolerance / 3, self.tolerance / 3)),
        )


def drifted(lamp: Spectrum, gain: float, tilt_per_100nm: float) -> Spectrum:
    """``lamp × (1 + gain + tilt · (λ − 550 nm) / 100 nm)`` (clipped at zero)."""
    factor = 1.0 + gain + tilt_per_100nm * (lamp.wavelength_nm - 550.0) / 100.0
    return Spectrum(lamp.wavelength_nm, lamp.values * np.clip(factor, 0.0, None), name=lamp.name)


@dataclass(frozen=True)
class SpectrometerReading:
    """One instrument's realised errors."""

    offset_nm: float
    bandwidth_nm: float
    step_nm: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "offset_nm": self.offset_nm,
            "bandwidth_nm": self.bandwidth_nm,
            "step_nm": self.step_nm,
        }


@dataclass(frozen=True)
class SpectrometerError:
    """The reference spectrometer's wavelength offset, slit function, sampling and noise."""

    offset_range_nm: tuple[float, float] = (-WAVELENGTH_SCALE_NM, WAVELENGTH_SCALE_NM)
    bandwidth_range_nm: tuple[float, float] = (2.0, 10.0)
    noise_fraction: float = 0.003
    floor_fraction: float = 5e-4
    range_nm: tuple[float, float] = (380.0, 780.0)

    def __post_init__(self) -> None:
        if not self.offset_range_nm[0] <= self.offset_range_nm[1]:
            raise InputError(f"{self.offset_range_nm} is not ordered", source="spectrometer.offset")
        _check_range("spectrometer.bandwidth_range_nm", self.bandwidth_range_nm, 1e-3)
        if self.noise_fraction < 0 or self.floor_fraction < 0:
            raise InputError("noise fractions must be ≥ 0", source="spectrometer")

    def draw(self, rng: np.random.Generator) -> SpectrometerReading:
        bandwidth = float(rng.uniform(*self.bandwidth_range_nm))
        step = 1.0 if bandwidth < 4 else 2.0 if bandwidth < 8 else 4.0
        return SpectrometerReading(float(rng.uniform(*self.offset_range_nm)), bandwidth, step)

    def measure(
        self, lamp: Spectrum, reading: SpectrometerReading, rng: np.random.Generator
    ) -> Spectrum:
        """What the instrument reports for ``lamp``: blurred by its slit function, read on a
        wavelength scale ``offset_nm`` off (it reports at λ the light of λ + offset), sampled every
        ``step_nm`` over :attr:`range_nm`, with noise."""
        from scipy.ndimage import convolve1d  # deferred: scipy.ndimage is slow to import

        step_fine = 0.1
        lo, hi = lamp.range_nm
        fine = np.arange(lo, hi + step_fine / 2, step_fine)
        sigma_nm = reading.bandwidth_nm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
        offsets = np.arange(
            -math.ceil(4 * sigma_nm / step_fine), math.ceil(4 * sigma_nm / step_fine) + 1
        )
        kernel = np.exp(-0.5 * (offsets * step_fine / sigma_nm) ** 2)
        blurred = convolve1d(lamp.at(fine), kernel / kernel.sum(), mode="nearest")
        samples = np.arange(
            self.range_nm[0], self.range_nm[1] + reading.step_nm / 2, reading.step_nm
        )
        clean = np.interp(samples + reading.offset_nm, fine, blurred)
        sigma = self.noise_fraction * clean + self.floor_fraction * float(clean.max())
        noisy = clean + sigma * rng.standard_normal(clean.shape)
        return Spectrum(samples, noisy, name=lamp.name, negative="clip")


@dataclass(frozen=True)
class StrayDraw:
    """One scene's stray light: the fraction of the 0th order and its wing's half-width."""

    fraction: float
    wing_px: float

    def to_dict(self) -> dict[str, Any]:
        return {"fraction": self.fraction, "wing_px": self.wing_px}

    def added(self, profile: FloatArray, direct: FloatArray, pixel: FloatArray) -> FloatArray:
        """``profile + fraction · direct_c · L(p)``, ``L`` the Lorentzian wing per pixel of
        distance ``p`` from the spot (``pixel`` measured from the spot)."""
        wing = (self.wing_px / math.pi) / (self.wing_px**2 + np.asarray(pixel) ** 2)
        return np.asarray(
            profile + self.fraction * wing[:, None] * direct[None, :], dtype=np.float64
        )


@dataclass(frozen=True)
class StrayLight:
    """Light of the direct spot scattered along the band (module docstring)."""

    fraction_range: tuple[float, float] = (1e-3, 1e-2)
    wing_range_px: tuple[float, float] = (100.0, 1000.0)

    def __post_init__(self) -> None:
        _check_range("stray.fraction_range", self.fraction_range)
        _check_range("stray.wing_range_px", self.wing_range_px, 1e-3)

    def draw(self, rng: np.random.Generator) -> StrayDraw:
        return StrayDraw(
            float(rng.uniform(*self.fraction_range)), _log_uniform(rng, self.wing_range_px)
        )


@dataclass(frozen=True)
class SensorDraw:
    """One scene's sensor."""

    full_well_e: float
    read_noise_e: float
    band_rows: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "full_well_e": self.full_well_e,
            "read_noise_e": self.read_noise_e,
            "band_rows": self.band_rows,
        }


@dataclass(frozen=True)
class PhotonBudget:
    """Shot + read noise of a sensor behind the rig's HDR policy (module docstring)."""

    full_well_range_e: tuple[float, float] = (8000.0, 60000.0)
    read_noise_range_e: tuple[float, float] = (1.5, 6.0)
    band_rows_range: tuple[int, int] = (20, 200)
    spot_fill_range: tuple[float, float] = (0.25, 0.98)
    step_stops: float = 2.0
    min_band_snr: float = 50.0
    max_frames: int = 8
    dark_frames: int = 2
    clip_fraction: float = 0.9
    #: The band's bright part for the SNR check: cells at least this share of its 98th percentile
    #: (the rig's frame analyser's ``BRIGHT_FRACTION``, ``rig/frame_stats.py``).
    bright_fraction: float = 0.25
    #: The merge estimates each frame's gain from the samples it shares with the frames merged
    #: before it, as the rig's merge does (decision 0089); ``False`` trusts the recorded times
    #: (what the merge did before: shows what the estimate removes).
    merge_gains: bool = True

    def __post_init__(self) -> None:
        _check_range("photons.full_well_range_e", self.full_well_range_e, 1.0)
        _check_range("photons.read_noise_range_e", self.read_noise_range_e)
        _check_range(
            "photons.band_rows_range",
            (float(self.band_rows_range[0]), float(self.band_rows_range[1])),
            1.0,
        )
        _check_range("photons.spot_fill_range", self.spot_fill_range, 1e-6)
        if self.spot_fill_range[1] > 1.0 or self.max_frames < 1 or self.dark_frames < 1:
            raise InputError(
                "spot fill ≤ 1, max_frames ≥ 1 and dark_frames ≥ 1 are required", source="photons"
            )

    def draw(self, rng: np.random.Generator) -> SensorDraw:
        return SensorDraw(
            _log_uniform(rng, self.full_well_range_e),
            float(rng.uniform(*self.read_noise_range_e)),
            int(rng.integers(self.band_rows_range[0], self.band_rows_range[1] + 1)),
        )

    def draw_spot_fill(self, rng: np.random.Generator) -> float:
        """The direct spot's brightest pixel in the shortest frame, a fraction of the clipping level."""
        return _log_uniform(rng, self.spot_fill_range)

    def bracket(
        self,
        profile: FloatArray,
        direct: FloatArray,
        sensor: SensorDraw,
        spot_px: float,
        spot_fill: float,
    ) -> tuple[float, list[float]]:
        """Electrons per signal unit of the shortest frame and the frames' nominal exposure factors.

        The shortest frame puts the brightest pixel (spot or band) at ``spot_fill`` of the clipping
        level; frames ``× 2^step_stops`` are added while the last one's band SNR is below
        ``min_band_snr``. The SNR is the one the rig's frame analyser judges the bracket by
        (``rig/frame_stats.py``): the band's mean signal per 2×2 cell (the channels' mean) over its
        bright part (cells at least :attr:`bright_fraction` of the band's 98th percentile), over the
        noise of one such cell (unsaturated cells; their median noise) — one cell's SNR, not the
        SNR of the profile summed over the slit's rows.
        """
        # The brightest pixel is the spot's, or the band's where a weak 0th order makes the band
        # brighter (a narrow LED through a sheet near its optimum phase).
        peak_per_pixel = max(
            float(np.max(direct)) / spot_px, float(np.max(profile)) / sensor.band_rows
        )
        if peak_per_pixel <= 0:
            raise InputError("the direct spot and the band are dark", source="photon budget")
        gain = spot_fill * self.clip_fraction * sensor.full_well_e / peak_per_pixel
        per_pixel = np.clip(profile, 0.0, None) / sensor.band_rows  # the band's flat top
        cell = per_pixel.mean(axis=1)
        bright = cell >= self.bright_fraction * float(np.percentile(cell, 98))
        saturation = DEFAULT_SATURATION_FRACTION * sensor.full_well_e
        sites = np.asarray(SITES_PER_SAMPLE, dtype=np.float64)
        factors: list[float] = []
        for frame in range(self.max_frames):
            factor = (2.0**self.step_stops) ** frame
            factors.append(factor)
            electrons = gain * factor * per_pixel[bright]
            unsaturated = np.all(electrons < saturation, axis=1)
            if not unsaturated.any():
                break
            signal = float(np.minimum(electrons, sensor.full_well_e).mean())
            cell_variance = ((electrons[unsaturated] + sensor.read_noise_e**2) / sites).sum(
                axis=1
            ) / 9.0
            if signal / math.sqrt(float(np.median(cell_variance))) >= self.min_band_snr:
                break
        return gain, factors

    def read_variance_e2(self, sensor: SensorDraw) -> float:
        """Read variance of one dark-subtracted pixel (e⁻²)."""
        return sensor.read_noise_e**2 * (1.0 + 1.0 / self.dark_frames)


@dataclass(frozen=True)
class RigErrors:
    """Every error source of a scene; ``None`` switches one off (the photon budget stays: noise)."""

    exposure: ExposureTimeError | None = ExposureTimeError()
    drift: LampDrift | None = LampDrift()
    spectrometer: SpectrometerError | None = SpectrometerError()
    stray: StrayLight | None = StrayLight()
    photons: PhotonBudget = PhotonBudget()

    @classmethod
    def noise_only(cls, photons: PhotonBudget | None = None) -> RigErrors:
        """Shot and read noise only: no systematic error (for checks and comparisons)."""
        return cls(None, None, None, None, photons or PhotonBudget())

    def to_dict(self) -> dict[str, Any]:
        from dataclasses import asdict

        return {
            name: None if value is None else asdict(value)
            for name, value in (
                ("exposure", self.exposure),
                ("drift", self.drift),
                ("spectrometer", self.spectrometer),
                ("stray", self.stray),
                ("photons", self.photons),
            )
        }
