"""Matching resolutions: the spectrometer that measured the lamp and the camera that saw its rainbow.

The profile model ``m(p) = [∫_pixel e(λ) r(λ) dλ] ⊗ k(p)`` needs the lamp spectrum ``e`` at the
camera's spectral resolution and the camera's line spread ``k`` (the slit's image and the lens' blur,
along the dispersion direction). Neither holds as measured:

- A spectroradiometer reports ``e_meas = e ⊗ B`` with ``B`` its slit function (PR-655: 8 nm, CS-2000:
  5 nm FWHM); a fluorescent lamp's mercury lines are ~1 nm wide, far sharper than ``B``. With the
  response ``r`` smooth on the scale of ``B``, ``m ⊗ B ≈ [∫ e_meas r] ⊗ k``: blurring the *profile* by
  ``B`` (in pixels, through the dispersion) brings it to the spectrometer's resolution, where the
  model with the measured spectrum is right. :func:`match_spectrometer`.
- ``k`` is the direct spot's cross-section along the dispersion direction (the 0th order is the slit's
  image through the same optics), recorded by :mod:`calib.image.profiles` as
  :attr:`calib.core.observations.LampObservation.line_spread`. :func:`camera_kernel`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.observations import LampObservation
from calib.model.forward import apply_blur, blur_kernel

_FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


def gaussian_kernel(sigma_samples: float) -> FloatArray | None:
    """A normalised Gaussian kernel of ``sigma_samples`` (odd length, ±4σ), or ``None`` below 0.1."""
    if sigma_samples < 0.1:
        return None
    half = max(1, math.ceil(4.0 * sigma_samples))
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (offsets / sigma_samples) ** 2)
    return np.asarray(kernel / kernel.sum(), dtype=np.float64)


def match_spectrometer(observation: LampObservation, nm_per_sample: float) -> LampObservation:
    """The observation with its profile blurred to the spectrometer's bandwidth (if it has one).

    ``nm_per_sample``: the dispersion times the profile's sample spacing (a typical value over the
    profile; the bandwidth is a few samples, so its variation along the profile does not matter).
    σ follows the blur (``σ'² = σ² ⊗ k²``, neighbours' correlation ignored). The result carries no
    bandwidth (it is matched) and records the blur in its metadata.
    """
    bandwidth = observation.spectrum_bandwidth_nm
    if bandwidth is None or nm_per_sample <= 0:
        return observation
    kernel = gaussian_kernel(bandwidth / _FWHM_PER_SIGMA / nm_per_sample)
    if kernel is None:
        return replace(observation, spectrum_bandwidth_nm=None)
    sigma = observation.profile_sigma
    blurred_sigma = None if sigma is None else np.sqrt(apply_blur(sigma**2, kernel**2))
    return replace(
        observation,
        profile=apply_blur(np.asarray(observation.profile), kernel),
        profile_sigma=blurred_sigma,
        spectrum_bandwidth_nm=None,
        metadata={**observation.metadata, "profile_blurred_to_bandwidth_nm": bandwidth},
    )


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
