"""Colour charts for the chart-based methods: patch spectra, the linear model of a patch, rendering.

A patch ``j`` lit by ``e(λ)`` gives the camera ``m_jc = ∫ e(λ) ρ_j(λ) s_c(λ) dλ``. With the camera
linear between the working grid's nodes (``s_c = Σ_i φ_i s_ci``, hat functions ``φ_i``), this is
``m_j = A s`` with the *stimulus rows* ``A[j, i] = ∫ e ρ_j φ_i dλ`` (:func:`stimulus_rows`),
integrated on a 1 nm axis exactly like :mod:`calib.model.forward` integrates lamp spectra — so a camera
given on the grid, rendered with :func:`render_chart`, is reproduced to rounding error.

Charts provided (colour-science's ColorChecker reflectances and CIE test colour samples, used by
the "CC" and "Exif+CC" baselines of Makabe et al. (2025) §4, are
:func:`calib.core.colour_data.colorchecker` and :func:`calib.core.colour_data.cie_test_colour_samples`):

``gaussian_filters`` N transmissive band filters with Gaussian transmittance whose centres tile the
                     range evenly (Makabe et al. 2025, Supp. G / Fig. S6: "shifted Gaussian
                     distributions, ensuring that the visible wavelength range was always fully
                     covered by the N filters"), the synthetic stand-in for Toivonen & Klami's
                     transmissive patches.
"""

from __future__ import annotations

import math

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.observations import ChartKind, ChartObservation
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid
from calib.model.forward import FINE_STEP_NM, fine_axis, hat_matrix

#: FWHM of each Gaussian filter as a multiple of the spacing of the centres (neighbours cross at
#: half maximum, so the sum of the set is flat to a few per cent inside the range).
GAUSSIAN_FWHM_PER_SPACING = 1.0

_FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


def gaussian_filters(
    n_filters: int,
    *,
    range_nm: tuple[float, float] = (DEFAULT_GRID.start_nm, DEFAULT_GRID.stop_nm),
    peak_transmittance: float = 1.0,
    margin_nm: float = 50.0,
    step_nm: float = FINE_STEP_NM,
) -> MultiSpectrum:
    """``n_filters`` Gaussian band-pass transmittances tiling ``range_nm`` (Makabe et al. Supp. G).

    Filter ``k`` is centred at ``λ_lo + (k + ½)·Δ`` with ``Δ = (λ_hi − λ_lo)/n`` and has a FWHM of
    ``Δ`` (:data:`GAUSSIAN_FWHM_PER_SPACING`), so neighbours cross at half maximum and together the
    filters cover the whole range. One filter is a single broad band over the range.

    Parameters
    ----------
    n_filters
        Number of filters (≥ 1).
    range_nm
        ``(λ_lo, λ_hi)`` the filters tile.
    peak_transmittance
        Transmittance at each filter's centre (0 < t ≤ 1).
    margin_nm, step_nm
        The curves are sampled every ``step_nm`` from ``λ_lo − margin`` to ``λ_hi + margin``.

    Returns
    -------
    MultiSpectrum
        Transmittances, channels ``"gauss 1 (425 nm)"`` …
    """
    if n_filters < 1:
        raise InputError(f"need at least one filter, got {n_filters}", source="n_filters")
    low, high = range_nm
    if not high > low:
        raise InputError(f"range {range_nm} must increase", source="range_nm")
    if not 0 < peak_transmittance <= 1:
        raise InputError(
            f"peak transmittance must be in (0, 1], got {peak_transmittance}",
            source="peak_transmittance",
        )
    spacing = (high - low) / n_filters
    centres = low + (np.arange(n_filters) + 0.5) * spacing
    sigma = GAUSSIAN_FWHM_PER_SPACING * spacing / _FWHM_PER_SIGMA
    axis = np.arange(low - margin_nm, high + margin_nm + step_nm / 2, step_nm)
    values = peak_transmittance * np.exp(-0.5 * ((axis[:, None] - centres[None, :]) / sigma) ** 2)
    names = tuple(f"gauss {k + 1} ({centre:.0f} nm)" for k, centre in enumerate(centres))
    return MultiSpectrum(axis, values, channels=names, name=f"{n_filters} Gaussian filters")


def _radiance_on_axis(
    patch_spectra: MultiSpectrum, illuminant: Spectrum | None, axis_nm: FloatArray
) -> FloatArray:
    """``e(λ) ρ_j(λ)`` on ``axis_nm``, shape ``(n_fine, n_patches)`` (zero outside the data)."""
    patches = np.stack(
        [
            np.interp(axis_nm, patch_spectra.wavelength_nm, column, left=0.0, right=0.0)
            for column in patch_spectra.values.T
        ],
        axis=1,
    )
    if illuminant is None:
        return patches
    return np.asarray(illuminant.at(axis_nm)[:, None] * patches, dtype=np.float64)


def _check_coverage(
    patch_spectra: MultiSpectrum, illuminant: Spectrum | None, grid: WavelengthGrid, label: str
) -> None:
    lo, hi = patch_spectra.range_nm
    if lo > grid.start_nm + 1e-6 or hi < grid.stop_nm - 1e-6:
        raise InputError(
            f"patch spectra cover {lo:g}–{hi:g} nm but the grid needs {grid.start_nm:g}–"
            f"{grid.stop_nm:g} nm; give wider data or a narrower grid",
            source=label,
        )
    if illuminant is not None and not illuminant.covers(grid):
        lo, hi = illuminant.range_nm
        raise InputError(
            f"the illuminant {illuminant.name!r} covers {lo:g}–{hi:g} nm but the grid needs "
            f"{grid.start_nm:g}–{grid.stop_nm:g} nm",
            source=label,
        )


def _trapezoid_weights(axis_nm: FloatArray) -> FloatArray:
    step = float(axis_nm[1] - axis_nm[0])
    weights = np.full(axis_nm.size, step)
    weights[[0, -1]] = 0.5 * step
    return weights


def radiance_rows(
    patch_spectra: MultiSpectrum,
    illuminant: Spectrum | None,
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    fine_step_nm: float = FINE_STEP_NM,
    label: str = "chart",
) -> FloatArray:
    """Stimulus rows ``A[j, i] = ∫ e ρ_j φ_i dλ`` for patch spectra under an illuminant.

    Parameters
    ----------
    patch_spectra
        Reflectances/transmittances (or radiances with ``illuminant=None``), one channel per patch.
    illuminant
        The light, or ``None``.
    grid
        Working grid (``f`` nodes); the hats are cut at its ends (no light modelled outside).
    fine_step_nm
        Integration step.

    Returns
    -------
    numpy.ndarray
        Shape ``(n_patches, f)``: ``patch RGB = A @ sensitivity`` for a sensitivity ``(f, 3)``.
    """
    _check_coverage(patch_spectra, illuminant, grid, label)
    axis = fine_axis(grid.start_nm, grid.stop_nm, fine_step_nm)
    radiance = _radiance_on_axis(patch_spectra, illuminant, axis)
    weighted = radiance * _trapezoid_weights(axis)[:, None]
    return np.asarray(weighted.T @ hat_matrix(grid, axis), dtype=np.float64)


def stimulus_rows(
    chart: ChartObservation,
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    fine_step_nm: float = FINE_STEP_NM,
) -> FloatArray:
    """:func:`radiance_rows` of a :class:`ChartObservation`, shape ``(n_patches, f)``."""
    return radiance_rows(
        chart.patch_spectra,
        chart.illuminant,
        grid,
        fine_step_nm=fine_step_nm,
        label=f"chart {chart.name!r}",
    )


def chart_rgb(
    patch_spectra: MultiSpectrum,
    illuminant: Spectrum | None,
    camera: MultiSpectrum,
    *,
    gain: float = 1.0,
    fine_step_nm: float = FINE_STEP_NM,
) -> FloatArray:
    """Noise-free patch RGBs ``gain · ∫ e ρ_j s_c dλ``, shape ``(n_patches, 3)``.

    Integrated (trapezoid, ``fine_step_nm``) over the range the patches, the camera and the
    illuminant all cover; the camera is linear between its samples. With ``illuminant=None`` the
    patch spectra are radiances (e.g. fluorescent emission).

    Raises
    ------
    InputError
        The camera does not have 3 channels.
    """
    if camera.values.ndim != 2 or camera.values.shape[1] != 3:
        raise InputError(
            f"camera needs 3 channels, has {camera.values.shape[1]}", source=camera.name
        )
    lo = max(float(camera.wavelength_nm[0]), patch_spectra.range_nm[0])
    hi = min(float(camera.wavelength_nm[-1]), patch_spectra.range_nm[1])
    if illuminant is not None:
        lo, hi = max(lo, illuminant.range_nm[0]), min(hi, illuminant.range_nm[1])
    axis = fine_axis(lo, hi, fine_step_nm)
    radiance = _radiance_on_axis(patch_spectra, illuminant, axis)
    sensitivity = np.stack(
        [
            np.interp(axis, camera.wavelength_nm, camera.values[:, k], left=0.0, right=0.0)
            for k in range(3)
        ],
        axis=1,
    )
    return np.asarray(
        gain * (radiance * _trapezoid_weights(axis)[:, None]).T @ sensitivity, dtype=np.float64
    )


def render_chart(
    patch_spectra: MultiSpectrum,
    illuminant: Spectrum | None,
    camera: MultiSpectrum,
    *,
    name: str | None = None,
    kind: ChartKind = "reflective",
    noise_fraction: float = 0.0,
    rng: np.random.Generator | None = None,
    gain: float = 1.0,
    fine_step_nm: float = FINE_STEP_NM,
) -> ChartObservation:
    """The patch RGBs a camera records of a chart: :func:`chart_rgb` on a 1 nm axis, plus noise.

    Parameters
    ----------
    patch_spectra, illuminant
        As for :func:`radiance_rows`.
    camera
        Sensitivity with 3 channels (linear between its samples, zero outside them).
    name, kind
        Stored on the observation.
    noise_fraction
        Gaussian noise of σ = ``noise_fraction × max(patch RGB)`` on every value (the same
        convention as :class:`calib.model.forward.PeakFractionNoise` for profiles); 0 = noise-free.
    rng
        Required when ``noise_fraction > 0``: the seeded generator that draws the noise.
    gain
        Overall exposure factor.

    Returns
    -------
    ChartObservation
        With ``patch_sigma`` when noise was added; ``metadata["clean_rgb"]`` holds the noise-free
        values.
    """
    check_noise_request(noise_fraction, rng)
    clean = chart_rgb(patch_spectra, illuminant, camera, gain=gain, fine_step_nm=fine_step_nm)
    rgb, sigma = clean, None
    if noise_fraction > 0 and rng is not None:
        sigma = np.full(clean.shape, noise_fraction * float(np.max(clean)))
        rgb = clean + rng.standard_normal(clean.shape) * sigma
    label = name or (
        patch_spectra.name
        if illuminant is None
        else f"{patch_spectra.name} under {illuminant.name}"
    )
    return ChartObservation(
        name=label,
        patch_rgb=rgb,
        patch_spectra=patch_spectra,
        illuminant=illuminant,
        patch_sigma=sigma,
        kind=kind,
        metadata={"rendered": True, "camera": camera.name, "clean_rgb": clean},
    )


def check_noise_request(noise_fraction: float, rng: np.random.Generator | None) -> None:
    """A rendering's noise must be a finite fraction >= 0, drawn from an explicit seeded generator.

    Raises
    ------
    InputError
        A negative or non-finite fraction, or noise without ``rng``.
    """
    if noise_fraction < 0 or not math.isfinite(noise_fraction):
        raise InputError(f"noise fraction must be >= 0, got {noise_fraction}", source="noise")
    if noise_fraction > 0 and rng is None:
        raise InputError("noise needs an explicit seeded numpy Generator (rng=)", source="rng")


def combined(sets: list[MultiSpectrum], grid: WavelengthGrid = DEFAULT_GRID) -> MultiSpectrum:
    """Several patch sets as one, on a 1 nm axis spanning ``grid`` (linear interpolation).

    Raises
    ------
    InputError
        When a set does not cover the grid.
    """
    if not sets:
        raise InputError("no patch sets to combine", source="chart")
    axis = fine_axis(grid.start_nm, grid.stop_nm, FINE_STEP_NM)
    columns: list[FloatArray] = []
    names: list[str] = []
    for patches in sets:
        lo, hi = patches.range_nm
        if lo > grid.start_nm + 1e-6 or hi < grid.stop_nm - 1e-6:
            raise InputError(
                f"covers {lo:g}–{hi:g} nm, the grid needs {grid.start_nm:g}–{grid.stop_nm:g} nm",
                source=patches.name,
            )
        columns.extend(
            np.interp(axis, patches.wavelength_nm, column) for column in patches.values.T
        )
        names.extend(patches.channels)
    return MultiSpectrum(
        axis,
        np.stack(columns, axis=1),
        channels=tuple(names),
        name=" + ".join(patches.name for patches in sets),
    )
