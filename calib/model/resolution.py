"""Matching resolutions: the spectrometer that measured the lamp and the camera that saw its rainbow.

The profile model ``m(p) = [∫_pixel e(λ) r(λ) dλ] ⊗ k(p)`` needs the lamp spectrum ``e`` at the
camera's spectral resolution and the camera's line spread ``k`` (the slit's image and the lens' blur,
along the dispersion direction). Neither holds as measured:

- A spectroradiometer reports ``e_meas = e ⊗ B`` with ``B`` its slit function (PR-655: 8 nm, CS-2000:
  5 nm FWHM); a fluorescent lamp's mercury lines are ~1 nm wide, far sharper than ``B``. With the
  response ``r`` smooth on the scale of ``B``, ``m ⊗ B ≈ [∫ e_meas r] ⊗ k``: blurring the *profile* by
  ``B`` (in pixels, through the dispersion) brings it to the spectrometer's resolution, where the
  model with the measured spectrum is right. :func:`match_spectrometer`. (The mapping search,
  whose model has no slit terms, matches a broadband lamp the other way: its profile as measured,
  its spectrum sharpened back to the camera's resolution, :func:`sharpened_spectrum`.)
- ``k`` is the direct spot's cross-section along the dispersion direction (the 0th order is the slit's
  image through the same optics), recorded by :mod:`calib.image.profiles` as
  :attr:`calib.core.observations.LampObservation.line_spread`. :func:`camera_kernel`.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.observations import LampObservation
from calib.core.spectra import Spectrum
from calib.model.forward import apply_blur, blur_kernel

if TYPE_CHECKING:
    from scipy import sparse
    from scipy.interpolate import CubicSpline

#: A Gaussian's FWHM over its σ.
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


def gaussian_kernel(sigma_samples: float) -> FloatArray | None:
    """A normalised Gaussian kernel of ``sigma_samples`` (odd length, ±4σ), or ``None`` below 0.1."""
    if sigma_samples < 0.1:
        return None
    half = max(1, math.ceil(4.0 * sigma_samples))
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (offsets / sigma_samples) ** 2)
    return np.asarray(kernel / kernel.sum(), dtype=np.float64)


#: The common resolution never drops below this FWHM (nm): the solvers sample a lamp at
#: :data:`calib.model.forward.FINE_STEP_NM` (1 nm) and integrate it linearly between samples, which
#: represents a line of 2.5 nm FWHM to a fraction of a per cent and a 1.5 nm line (a USB
#: spectrometer's) only roughly. A spectrum sharper than this is blurred to it (and the profile
#: with it).
RESOLUTION_FLOOR_NM = 2.5
#: Sample step (nm) of a matched spectrum: fine enough for the floor's line shape.
MATCHED_STEP_NM = 0.25


#: A spectrometer slit broader than this (nm FWHM) is flagged: the sensitivity's detail finer than
#: the slit then rests on the slit model's second-order terms and the camera prior. On the twin
#: (``bench/spectrometer_equivalence.py``, validation use) slits of 1.5–8 nm agree within the
#: PR-655's own repeatability; 15 and 25 nm (an i1Pro) differ from it by 1.3–2.5 ×10⁻² RE.
COARSE_SLIT_NM = 10.0


def coarse_slit(observation: LampObservation) -> str | None:
    """What to tell the user when ``observation``'s spectrum was measured through a slit broader
    than :data:`COARSE_SLIT_NM`, or ``None``."""
    bandwidth = observation.spectrum_bandwidth_nm
    if bandwidth is None or bandwidth <= COARSE_SLIT_NM:
        return None
    return f"{observation.name} ({bandwidth:g} nm)"


def common_resolution_nm(bandwidth_nm: float, spectrum_step_nm: float) -> float:
    """The FWHM both the profile and the spectrum are brought to: the spectrometer's bandwidth, but
    at least :data:`RESOLUTION_FLOOR_NM` and two of the spectrum's own samples (a spectrum sampled
    more coarsely than half its bandwidth holds no detail finer than that)."""
    return max(bandwidth_nm, RESOLUTION_FLOOR_NM, 2.0 * spectrum_step_nm)


def _matched_spline(spectrum: Spectrum) -> tuple[FloatArray, CubicSpline]:
    """The :data:`MATCHED_STEP_NM` axis over ``spectrum``'s range and a cubic spline through its
    samples (a slit-limited spectrum is smooth on the scale of its samples; linear interpolation
    would cut a 8 nm line sampled every 4 nm by up to a sixth at its peak)."""
    from scipy.interpolate import CubicSpline  # deferred: scipy.interpolate is slow to import

    low, high = spectrum.range_nm
    axis = np.arange(low, high + MATCHED_STEP_NM / 2, MATCHED_STEP_NM)
    return axis, CubicSpline(spectrum.wavelength_nm, spectrum.values)


def blurred_spectrum(spectrum: Spectrum, bandwidth_nm: float, target_nm: float) -> Spectrum:
    """``spectrum`` (measured through a Gaussian slit of ``bandwidth_nm``) at ``target_nm`` FWHM.

    The samples are interpolated with a cubic spline onto a :data:`MATCHED_STEP_NM` axis
    (:func:`_matched_spline`), then convolved with the difference kernel
    (FWHM ``√(target² − bandwidth²)``). Negative overshoot is clipped.
    """
    axis, spline = _matched_spline(spectrum)
    values = spline(axis)
    extra_nm = math.sqrt(max(target_nm**2 - bandwidth_nm**2, 0.0))
    kernel = gaussian_kernel(extra_nm / FWHM_PER_SIGMA / MATCHED_STEP_NM)
    if kernel is not None:
        # Reflect at the ends: the spectrum's range edge is not a dark edge.
        from scipy.ndimage import convolve1d

        values = convolve1d(values, kernel, mode="nearest")
    return Spectrum(axis, values, name=spectrum.name, negative="clip")


def sharpened_spectrum(spectrum: Spectrum, bandwidth_nm: float) -> Spectrum:
    """``spectrum`` (measured through a Gaussian slit of ``bandwidth_nm``) brought back to the
    camera's resolution, to first order: ``e ≈ e_B − ½ σ² e_B″`` (σ the slit's).

    The samples are interpolated as in :func:`blurred_spectrum` (:func:`_matched_spline`); ``e_B″`` is the spline's second derivative smoothed by a Gaussian of
    ``σ/2``, which keeps the correction exact to second order (the smoothing's own effect,
    ``σ²·(σ/2)²/4 · e⁗``, is of the fourth) and damps the sample noise above the slit's band. The
    series is in ``σ²/w²``, ``w`` the width of the spectrum's sharpest feature: right for a
    broadband lamp (the white LED's blue peak, ``w`` ≈ 8–10 nm) through a slit of up to
    :data:`COARSE_SLIT_NM`, not for a line lamp. Negative overshoot is clipped.
    """
    from scipy.ndimage import convolve1d

    axis, spline = _matched_spline(spectrum)
    sigma_nm = bandwidth_nm / FWHM_PER_SIGMA
    curvature = spline(axis, 2)
    kernel = gaussian_kernel(0.5 * sigma_nm / MATCHED_STEP_NM)
    if kernel is not None:
        curvature = convolve1d(curvature, kernel, mode="nearest")
    values = spline(axis) - 0.5 * sigma_nm**2 * curvature
    return Spectrum(axis, values, name=spectrum.name, negative="clip")


def wavelength_blur(wavelength_nm: FloatArray, fwhm_nm: float) -> sparse.csr_array:
    """The matrix ``W`` ``(n, n)`` that blurs a profile sampled at ``wavelength_nm`` (increasing or
    decreasing, one per profile sample) by a Gaussian of ``fwhm_nm`` *in wavelength*.

    A sample ``q`` holds ``g(λ_q)·J_q`` (the density times the nm it spans, ``J`` the dispersion);
    the blurred density at ``λ_p`` is ``Σ_q B(λ_p − λ_q) g(λ_q) J_q``, and the sample at ``p`` is that
    times ``J_p``: ``W[p, q] = J_p B(λ_p − λ_q)``. Unlike a kernel in samples, the slit keeps its
    width in nm where the dispersion changes along the profile (±8 % over a typical first order).
    Zero beyond the ends, as :func:`calib.model.forward.apply_blur`, and beyond 5σ: a band matrix
    (sparse; a dense one cost 60 ms for a 1500-sample profile, per lamp and solve).

    Kept for the last :data:`BLUR_CACHE_SIZE` ``(wavelengths, FWHM)`` (by content, never by the
    array's identity; the matrix's arrays read-only): an estimate builds the same one per lamp for
    the solve and again for each σ-budget re-solve of an unchanged mapping, ~1 ms each against
    the ~0.1 s estimate (decision 0083; 0047 left it uncached against a 4 s one).
    """
    wavelength = np.asarray(wavelength_nm, dtype=np.float64)
    key = (wavelength.shape, wavelength.tobytes(), float(fwhm_nm))
    matrix = _BLUR_CACHE.get(key)
    if matrix is None:
        matrix = _wavelength_blur(wavelength, float(fwhm_nm))
        for array in (matrix.data, matrix.indices, matrix.indptr):
            array.flags.writeable = False
        _BLUR_CACHE[key] = matrix
        while len(_BLUR_CACHE) > BLUR_CACHE_SIZE:
            _BLUR_CACHE.popitem(last=False)
    else:
        _BLUR_CACHE.move_to_end(key)
    return matrix


#: How many of :func:`wavelength_blur`'s matrices are kept (a few lamps' profiles, each perhaps
#: at two resolutions).
BLUR_CACHE_SIZE = 8
_BLUR_CACHE: OrderedDict[tuple[tuple[int, ...], bytes, float], sparse.csr_array] = OrderedDict()


def _wavelength_blur(wavelength: FloatArray, fwhm_nm: float) -> sparse.csr_array:
    """:func:`wavelength_blur` built."""
    from scipy import sparse  # deferred: the mapping search never needs it

    size = wavelength.size
    spans = np.abs(np.gradient(wavelength))
    sigma = fwhm_nm / FWHM_PER_SIGMA
    reach = 5.0 * sigma
    # The band's half-width in samples: the most samples any 5σ holds along the profile.
    ordered = np.sort(wavelength)
    half = int(np.max(np.searchsorted(ordered, ordered + reach, side="right") - np.arange(size)))
    offsets = np.arange(-half, half + 1)
    rows = np.repeat(np.arange(size), offsets.size)
    columns = (np.arange(size)[:, None] + offsets[None, :]).ravel()
    inside = (columns >= 0) & (columns < size)
    rows, columns = rows[inside], columns[inside]
    distance = (wavelength[rows] - wavelength[columns]) / sigma
    near = np.abs(distance) <= 5.0
    rows, columns, distance = rows[near], columns[near], distance[near]
    weights = spans[rows] * np.exp(-0.5 * distance**2) / (sigma * math.sqrt(2.0 * math.pi))
    return sparse.csr_array((weights, (rows, columns)), shape=(size, size))


def blurred_profile(
    wavelength_nm: FloatArray, fwhm_nm: float, profile: FloatArray, sigma: FloatArray | None
) -> tuple[FloatArray, FloatArray | None]:
    """``profile`` ``(n, 3)`` and its σ blurred in wavelength (:func:`wavelength_blur`):
    ``W profile`` and ``√(W² σ²)`` (``W²`` elementwise; neighbours' correlation ignored).

    Kept for the last :data:`BLUR_CACHE_SIZE` inputs (by content: the wavelengths, FWHM, profile
    and σ as bytes; the arrays read-only): the σ budget's spectrometer-scale re-solve moves only
    the lamp's spectrum, so its profile is blurred by the same matrix to the same numbers; the
    two sparse products cost ~1 ms for a 941-sample profile (decision 0138).
    """
    wavelength = np.asarray(wavelength_nm, dtype=np.float64)
    values = np.asarray(profile, dtype=np.float64)
    spread = None if sigma is None else np.asarray(sigma, dtype=np.float64)
    key = (
        wavelength.shape,
        wavelength.tobytes(),
        float(fwhm_nm),
        values.shape,
        values.tobytes(),
        None if spread is None else (spread.shape, spread.tobytes()),
    )
    with _PROFILE_LOCK:
        found = _PROFILE_CACHE.get(key)
        if found is not None:
            _PROFILE_CACHE.move_to_end(key)
            return found
    matrix = wavelength_blur(wavelength, fwhm_nm)
    blurred = matrix @ values
    blurred_sigma = None if spread is None else np.sqrt(matrix.power(2) @ spread**2)
    for array in (blurred, blurred_sigma):
        if array is not None:
            array.flags.writeable = False
    with _PROFILE_LOCK:
        _PROFILE_CACHE[key] = (blurred, blurred_sigma)
        while len(_PROFILE_CACHE) > BLUR_CACHE_SIZE:
            _PROFILE_CACHE.popitem(last=False)
    return blurred, blurred_sigma


#: Guards :data:`_PROFILE_CACHE` (the solves may run in threads).
_PROFILE_LOCK = threading.Lock()
_PROFILE_CACHE: OrderedDict[tuple[object, ...], tuple[FloatArray, FloatArray | None]] = (
    OrderedDict()
)


def match_spectrometer(
    observation: LampObservation,
    nm_per_sample: float,
    *,
    wavelength_nm: FloatArray | None = None,
) -> LampObservation:
    """The observation with its profile and spectrum at one common resolution (if it has a bandwidth).

    The spectrometer reports ``e ⊗ B``; the camera sees ``e`` at its own (finer) resolution. Both are
    brought to :func:`common_resolution_nm` ``T``: the profile blurred by a Gaussian of ``T``
    (through the dispersion), the spectrum by the difference kernel (:func:`blurred_spectrum`), so
    that ``m ⊗ G_T ≈ [∫ (e ⊗ G_T) r] ⊗ k`` with ``r`` smooth on the scale of ``T``.

    ``wavelength_nm``: the profile samples' wavelengths (a known mapping: the solves); the blur is
    then in wavelength (:func:`wavelength_blur`). σ follows the blur (``σ'² = W² σ²``, neighbours'
    correlation ignored). The result carries no bandwidth (it is matched) and records the
    resolution in its metadata.

    Without it (the mapping search, whose response model works on the measured samples in coarse
    bins), only the profile is blurred, by the stated bandwidth, with a kernel of constant width in
    samples from ``nm_per_sample`` (the dispersion times the sample spacing), as before decision
    0035: the search with a spline-resampled spectrum at the common resolution put the twin's
    i1Pro (25 nm at 10 nm, noise draw 1) 23 nm off at the red end, where this finds it within
    0.2 nm.

    In the search, a lamp that is not a line lamp, measured through a slit of at most
    :data:`COARSE_SLIT_NM`, is matched the other way (decision 0082): its profile is kept as
    measured and its spectrum brought to the camera's resolution (:func:`sharpened_spectrum`).
    Blurring the profile instead leaves the search's model (which has no slit terms) the slit's
    commutation term ``σ² (e_B′ r′ + ½ e_B r″)``: it reads as the spectrum shifted by ``σ² r′/r``
    wherever the response is steep under a spectral peak (the white LED's blue one), a mapping
    bias that follows the camera. The sharpened spectrum needs no ``r``. (The solves keep the
    common resolution and its slit terms: sharpened there too, the LED + FL prior solve lost on
    every validation camera, decision 0082.)
    """
    bandwidth = observation.spectrum_bandwidth_nm
    if bandwidth is None or nm_per_sample <= 0:
        return observation
    if wavelength_nm is None and observation.kind != "fluorescent" and bandwidth <= COARSE_SLIT_NM:
        return replace(
            observation,
            spectrum=sharpened_spectrum(observation.spectrum, bandwidth),
            spectrum_bandwidth_nm=None,
            metadata={**observation.metadata, "spectrum_sharpened_from_nm": bandwidth},
        )
    profile = np.asarray(observation.profile)
    sigma = observation.profile_sigma
    if wavelength_nm is None:
        kernel = gaussian_kernel(bandwidth / FWHM_PER_SIGMA / nm_per_sample)
        if kernel is None:
            return replace(observation, spectrum_bandwidth_nm=None)
        return replace(
            observation,
            profile=apply_blur(profile, kernel),
            profile_sigma=None if sigma is None else np.sqrt(apply_blur(sigma**2, kernel**2)),
            spectrum_bandwidth_nm=None,
            metadata={**observation.metadata, "profile_blurred_in_samples_nm": bandwidth},
        )
    spectrum = observation.spectrum
    step_nm = float(np.median(np.diff(spectrum.wavelength_nm)))
    target = common_resolution_nm(bandwidth, step_nm)
    blurred, blurred_sigma = blurred_profile(wavelength_nm, target, profile, sigma)
    return replace(
        observation,
        spectrum=blurred_spectrum(spectrum, bandwidth, target),
        profile=blurred,
        profile_sigma=blurred_sigma,
        spectrum_bandwidth_nm=None,
        metadata={
            **observation.metadata,
            "profile_blurred_to_bandwidth_nm": target,
            "spectrometer_bandwidth_nm": bandwidth,
        },
    )


def matched_resolution_nm(observation: LampObservation) -> float | None:
    """The FWHM :func:`match_spectrometer` brought ``observation`` to, or ``None`` (not matched)."""
    value = observation.metadata.get("profile_blurred_to_bandwidth_nm")
    return None if value is None else float(value)  # type: ignore[arg-type]


def camera_kernel(
    observations: Sequence[LampObservation], slit_width_px: float = 0.0, psf_sigma_px: float = 0.0
) -> FloatArray | None:
    """The camera's line spread: the first observation's measured one, else a box ⊗ Gaussian model.

    ``slit_width_px`` and ``psf_sigma_px`` (in profile samples) are used only when no observation
    carries a measured :attr:`~calib.core.observations.LampObservation.line_spread`.
    """
    for observation in observations:
        if observation.line_spread is not None:
            return np.asarray(observation.line_spread, dtype=np.float64)
    return blur_kernel(slit_width_px, psf_sigma_px)
