"""The mapping when the camera and the grating are known: the rig used as a spectrometer.

With a calibrated camera (sensitivity ``s_c``) and, when known, the grating's first-order efficiency
``η``, the system's response ``c_c = s_c η`` is known (:func:`system_response`), so a fluorescent
lamp's profile pins the mapping by its lines alone (Alvarez et al. 2014 use 546.5 and 611.6 nm):

* with the lamp's measured spectrum, its lines are matched to the profile's peaks
  (:func:`calib.wavelength.peaks.mapping_from_peaks`) and the mapping is refined so the whole
  rendered profile fits (:func:`refine_mapping_on_lamp`);
* without it, the peaks are matched to a reference line list
  (:data:`REFERENCE_FLUORESCENT_LINES_NM`) under the through-origin grating model, since the
  profile's pixel axis starts at the direct spot.

This is the ``"lines"`` strategy of :func:`calib.wavelength.find_mapping`.

References
----------
Alvarez, S., Presa, L., Kunkel, T., Masia, B. (2014). Low Cost Recovery of Spectral Power
Distributions. Spanish Computer Graphics Conference (CEIG), Eurographics.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid
from calib.model.forward import PiecewiseLinearDensity, apply_blur, fine_axis, hat_matrix
from calib.wavelength.peaks import (
    Peak,
    lamp_lines,
    mapping_from_peaks,
    nominal_dispersion,
    profile_peaks,
    refine_mapping,
)

#: Emission lines of white fluorescent lamps (nm) with weights, for a mapping lamp whose spectrum
#: was not measured. Mercury lines are in every fluorescent tube (NIST; the 577/579 nm doublet as
#: one line at its centre, since the first order does not resolve it); the Eu³⁺ (611.6 nm) and
#: Tb³⁺ (487.7 nm) peaks are those of tri-phosphor tubes (Tb³⁺ 542.4 nm is left out: it merges
#: with Hg 546.1 nm). The paper uses 546.5 and 611.6 nm.
REFERENCE_FLUORESCENT_LINES_NM: Mapping[float, float] = {
    404.66: 0.3,
    435.83: 1.0,
    487.7: 0.3,
    546.07: 1.0,
    578.0: 0.3,
    611.6: 0.6,
}


class SpectrometerProfile(Protocol):
    """What the ``"lines"`` strategy reads of a profile (:class:`calib.spd.alvarez2014.DiffractedProfile`).

    ``pixel`` ``(n,)`` increasing in equal steps (distance from the direct spot), ``profile`` and
    ``profile_sigma`` ``(n, 3)``, ``source_kernel`` (odd length, sum 1) or ``None``.
    """

    @property
    def pixel(self) -> FloatArray: ...

    @property
    def profile(self) -> FloatArray: ...

    @property
    def profile_sigma(self) -> FloatArray | None: ...

    @property
    def source_kernel(self) -> FloatArray | None: ...

    @property
    def name(self) -> str: ...

    @property
    def spacing_px(self) -> float: ...


@dataclass(frozen=True, eq=False)
class CalibratedCamera:
    """A camera whose sensitivity is known, seen through a grating of known (or flat) efficiency.

    Attributes
    ----------
    sensitivity
        The camera's R, G, B sensitivity.
    grating_efficiency
        The grating's first-order efficiency, or ``None`` for a flat grating.
    """

    sensitivity: MultiSpectrum
    grating_efficiency: Spectrum | None = None


# ---------------------------------------------------------------------------------------- response


def system_response(
    camera: MultiSpectrum, grating_efficiency: Spectrum | None, wavelength_nm: ArrayLike
) -> FloatArray:
    """``c_c(λ) = s_c(λ) η(λ)`` at the given wavelengths, shape ``(n, 3)``, maximum 1.

    The maximum is taken over the camera's whole range (all channels), so the threshold means the
    same whatever part of the spectrum a profile covers. Zero outside the camera's range.
    """
    if camera.values.shape[1] != 3:
        raise InputError(
            f"the camera needs 3 channels, has {camera.values.shape[1]}", source=camera.name
        )
    dense = fine_axis(camera.range_nm[0], camera.range_nm[1], 0.5)

    def response(wavelength: FloatArray) -> FloatArray:
        values = np.stack(
            [
                np.interp(wavelength, camera.wavelength_nm, camera.values[:, k], 0.0, 0.0)
                for k in range(3)
            ],
            axis=1,
        )
        if grating_efficiency is not None:
            values = values * grating_efficiency.at(wavelength)[:, None]
        return values

    peak = float(np.max(response(dense)))
    if peak <= 0:
        raise InputError(
            "the camera response (sensitivity × efficiency) is zero", source=camera.name
        )
    return response(np.asarray(wavelength_nm, dtype=np.float64)) / peak


# ----------------------------------------------------------------------------------------- mapping


def reference_fluorescent_spectrum(step_nm: float = 0.1, line_fwhm_nm: float = 1.0) -> Spectrum:
    """A stand-in spectrum of a white fluorescent lamp: the reference lines on a weak continuum.

    For finding the mapping when the mapping lamp's spectrum was not measured: only the lines'
    positions matter (their heights only rank them).
    """
    wavelength = np.arange(380.0, 730.0 + step_nm / 2, step_nm)
    sigma = line_fwhm_nm / (2 * math.sqrt(2 * math.log(2)))
    values = np.full(wavelength.shape, 0.01)
    for centre, height in REFERENCE_FLUORESCENT_LINES_NM.items():
        values += height * np.exp(-0.5 * ((wavelength - centre) / sigma) ** 2)
    return Spectrum(wavelength, values, name="reference fluorescent lines")


def _grating_through_origin(
    pixel: FloatArray, wavelength_nm: FloatArray, weights: FloatArray | None = None
) -> tuple[float, float] | None:
    """``(d_nm, f_px)`` of ``λ(p) = d sin(atan(p / f))`` through ``(pixel, λ)`` pairs, or ``None``.

    The profile's pixel axis starts at the direct spot, so the zeroth order is the origin: a
    transmission grating at the lens has ``sin θ = λ/d`` and ``p = f tan θ``. Then
    ``(p/λ)² = p²/d² + f²/d²`` is linear in ``(1/d², f²/d²)``: two lines fix it, with the
    grating's own curvature for extrapolating to the ends of the spectrum. ``None`` when the
    points admit no such grating.
    """
    w = np.ones_like(pixel) if weights is None else weights
    design = np.stack([pixel**2, np.ones_like(pixel)], axis=1) * w[:, None]
    target = (pixel / wavelength_nm) ** 2 * w
    (inverse_d2, ratio), *_ = np.linalg.lstsq(design, target, rcond=None)
    if inverse_d2 <= 0 or ratio <= 0:
        return None
    return float(1.0 / math.sqrt(inverse_d2)), float(math.sqrt(ratio / inverse_d2))


def _through_origin_nm(pixel: FloatArray, grating: tuple[float, float]) -> FloatArray:
    d_nm, f_px = grating
    return np.asarray(d_nm * pixel / np.hypot(pixel, f_px), dtype=np.float64)


def _match_lines_through_origin(
    lines: list[Peak],
    peaks: list[Peak],
    pixel_range: tuple[float, float],
    dispersion_range: tuple[float, float],
    tolerance_nm: float = 1.5,
) -> tuple[tuple[float, float], list[tuple[float, float]]]:
    """Robust line↔peak matching under the through-origin grating model.

    Every pair of the strongest lines against every ordered pair of the strongest peaks proposes
    a grating; those with a plausible dispersion are scored by a soft inlier count (each line by
    its weight times that of the peak landing near it: √prominence and closeness, τ = 2 nm), and
    the best is refitted on its inliers.
    """
    line_nm = np.array([line.position for line in lines])
    line_weight = np.array([line.prominence for line in lines])
    line_weight = line_weight / line_weight.max()
    peak_px = np.array([peak.position for peak in peaks])
    strongest_lines = np.argsort(-line_weight)[:6]
    strongest_peaks = np.argsort(-np.array([peak.prominence for peak in peaks]))[:10]
    middle = np.array([0.5 * (pixel_range[0] + pixel_range[1])])

    peak_weight = np.sqrt(np.array([peak.prominence for peak in peaks]))
    peak_weight = peak_weight / peak_weight.max()

    def score(grating: tuple[float, float]) -> float:
        """Each line counts by its weight × the best nearby peak's (√prominence, closeness)."""
        predicted = _through_origin_nm(peak_px, grating)
        closeness = np.exp(-0.5 * ((predicted[:, None] - line_nm[None, :]) / 2.0) ** 2)
        return float(np.sum(line_weight * np.max(peak_weight[:, None] * closeness, axis=0)))

    best: tuple[float, tuple[float, float]] | None = None
    for first, second in itertools.combinations(
        sorted(strongest_lines, key=lambda i: line_nm[i]), 2
    ):
        for low, high in itertools.combinations(
            sorted(strongest_peaks, key=lambda j: peak_px[j]), 2
        ):
            grating = _grating_through_origin(peak_px[[low, high]], line_nm[[first, second]])
            if grating is None:
                continue
            slope = float(
                np.gradient(_through_origin_nm(middle + np.array([-1.0, 0.0, 1.0]), grating))[1]
            )
            if not dispersion_range[0] <= slope <= dispersion_range[1]:
                continue
            value = score(grating)
            if best is None or value > best[0]:
                best = (value, grating)
    if best is None:
        raise EstimationError(
            "no two reference fluorescent lines fit the profile's peaks as a grating would place "
            "them; is the mapping lamp fluorescent? (give its measured spectrum for a safer match)"
        )
    grating = best[1]
    pairs: list[tuple[float, float]] = []
    for tolerance in (4 * tolerance_nm, 2 * tolerance_nm, tolerance_nm):
        distance = np.abs(_through_origin_nm(peak_px, grating)[:, None] - line_nm[None, :])
        # Each line keeps its closest peak, each peak serves one line.
        candidates = [
            (float(peak_px[j]), float(line_nm[i]))
            for i, j in enumerate(np.argmin(distance, axis=0))
            if distance[j, i] <= tolerance and int(np.argmin(distance[j])) == i
        ]
        if len(candidates) < 2:
            break
        pairs = candidates
        refitted = _grating_through_origin(
            np.array([px for px, _ in pairs]), np.array([nm for _, nm in pairs])
        )
        if refitted is None:
            break
        grating = refitted
    if len(pairs) < 2:
        raise EstimationError("fewer than 2 reference lines agree with one grating mapping")
    return grating, pairs


def _reference_lines_mapping(
    profile: SpectrometerProfile, response_on_grid: FloatArray, grid: WavelengthGrid
) -> QuadraticMapping:
    """Peaks of the profile matched to :data:`REFERENCE_FLUORESCENT_LINES_NM` (no lamp spectrum).

    Matched under the through-origin grating model (the pixel axis starts at the direct spot),
    which also extrapolates with the grating's curvature; the result is its quadratic
    approximation over the profile.
    """
    if profile.pixel[0] <= 0:
        raise InputError(
            "the reference-line mapping needs the profile's pixel axis to start at the direct "
            "spot (as calib.image.profiles extracts it); give the mapping lamp's spectrum instead",
            source=f"lamp {profile.name!r}",
        )
    total = response_on_grid.sum(axis=1)

    def weight(wavelength: FloatArray) -> FloatArray:
        return np.asarray(np.interp(wavelength, grid.wavelength_nm, total, 0.0, 0.0), float)

    lines = lamp_lines(
        reference_fluorescent_spectrum(), weight, range_nm=(grid.start_nm, grid.stop_nm)
    )
    # The lit extent of a white fluorescent lamp is roughly where the camera responds.
    axis = fine_axis(grid.start_nm, grid.stop_nm, 1.0)
    model = hat_matrix(grid, axis) @ response_on_grid
    dispersion = nominal_dispersion(profile.pixel, profile.profile, axis, model)
    peaks = profile_peaks(profile.pixel, profile.profile, line_width_px=20.0 / dispersion)
    pixel_range = (float(profile.pixel[0]), float(profile.pixel[-1]))
    grating, pairs = _match_lines_through_origin(
        lines, peaks, pixel_range, (0.75 * dispersion, 1.33 * dispersion)
    )
    dense = np.linspace(pixel_range[0], pixel_range[1], 128)
    fitted = QuadraticMapping.fit(
        dense, _through_origin_nm(dense, grating), method="reference-lines"
    )
    return fitted.with_details(
        covariance=None,
        wavelength_rms_nm=None,
        details={
            "matched": [{"pixel": px, "line_nm": nm} for px, nm in pairs],
            "grating_through_origin": {
                "groove_spacing_nm": grating[0],
                "focal_length_px": grating[1],
            },
        },
    )


def lines_mapping(
    profile: SpectrometerProfile,
    camera: MultiSpectrum,
    *,
    grating_efficiency: Spectrum | None = None,
    lamp_spectrum: Spectrum | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
    initial: QuadraticMapping | None = None,
) -> QuadraticMapping:
    """Pixel→wavelength mapping from a fluorescent lamp's first-order profile, the camera and grating known.

    The profile's line peaks are matched to the lamp's lines (the paper's spectral calibration):
    those of its measured spectrum, or the reference list when it was not measured. With a
    measured spectrum the mapping is then refined on the whole profile
    (:func:`refine_mapping_on_lamp`), since camera, grating and lamp are all known.

    Parameters
    ----------
    profile
        The fluorescent lamp's profile, in the same geometry as the lamp to be measured.
    camera, grating_efficiency
        The calibrated system (η ``None`` = flat).
    lamp_spectrum
        The mapping lamp's measured spectrum; ``None`` uses the reference line list.
    grid
        Wavelength range searched for lines.
    initial
        Skip the peak matching and refine this mapping (e.g. the one found on a shorter profile).

    Returns
    -------
    QuadraticMapping
        ``details["lines"]`` says which line list was used.
    """
    response_on_grid = system_response(camera, grating_efficiency, grid.wavelength_nm)
    if initial is not None:
        mapping = initial
    elif lamp_spectrum is not None:
        mapping = mapping_from_peaks(
            lamp_spectrum, profile.pixel, profile.profile, response_on_grid, grid=grid
        )
    else:
        mapping = _reference_lines_mapping(profile, response_on_grid, grid)
    if lamp_spectrum is not None:
        mapping = refine_mapping_on_lamp(
            profile, mapping, lamp_spectrum, camera, grating_efficiency=grating_efficiency
        )
    lines = "measured spectrum" if lamp_spectrum is not None else "reference line list"
    return mapping.with_details(details={**dict(mapping.details), "lines": lines})


@dataclass(frozen=True, eq=False)
class ProfileRenderer:
    """The profile a known spectrum gives in a set-up, as a function of the mapping.

    Sample ``p`` is ``∫_{g(p−½h)}^{g(p+½h)} e(λ) c_c(λ) dλ`` (``h`` the sample spacing; exact for
    ``e·c`` linear between 0.25 nm nodes), blurred by the source kernel when there is one. The
    overall scale is arbitrary.
    """

    density: PiecewiseLinearDensity
    edges_px: FloatArray
    kernel: FloatArray | None

    @classmethod
    def build(
        cls,
        spectrum: Spectrum,
        like: SpectrometerProfile,
        camera: MultiSpectrum,
        grating_efficiency: Spectrum | None = None,
    ) -> ProfileRenderer:
        """For ``spectrum`` seen on the pixel axis (and with the source kernel) of ``like``."""
        axis = fine_axis(*spectrum.range_nm, 0.25)
        response = system_response(camera, grating_efficiency, axis)
        density = PiecewiseLinearDensity.on_axis(axis, spectrum.at(axis)[:, None] * response)
        half = like.spacing_px / 2
        edges = np.concatenate([like.pixel - half, [like.pixel[-1] + half]])
        return cls(density, edges, like.source_kernel)

    def __call__(self, mapping: QuadraticMapping | GratingGeometry) -> FloatArray:
        """Shape ``(n, 3)``."""
        model = self.density.integrate_pixels(mapping.wavelength_nm(self.edges_px))
        return apply_blur(model, self.kernel) if self.kernel is not None else model


#: Extra blur (nm) of profile and model in the coarse-to-fine stages of the mapping refinement.
REFINE_BLUR_NM = (6.0, 2.0, 0.0)


def refine_mapping_on_lamp(
    profile: SpectrometerProfile,
    mapping: QuadraticMapping,
    lamp_spectrum: Spectrum,
    camera: MultiSpectrum,
    *,
    grating_efficiency: Spectrum | None = None,
) -> QuadraticMapping:
    """Refine a mapping so the whole profile of a known lamp matches its rendering.

    Each sample ``p`` of the model is ``k ∫_{g(p−½h)}^{g(p+½h)} e(λ) c_c(λ) dλ`` (``h`` the
    sample spacing), blurred by the source kernel when there is one; the common scale ``k`` is
    solved in closed form, the residual is weighted by the profile's σ. Coarse to fine: both are
    first blurred by :data:`REFINE_BLUR_NM` so the sharp lines have wide basins.
    """
    from scipy import ndimage  # deferred: scipy.ndimage is slow to import

    render = ProfileRenderer.build(lamp_spectrum, profile, camera, grating_efficiency)
    sigma = profile.profile_sigma
    if sigma is None:
        sigma = np.full(profile.profile.shape, 1e-3 * float(np.abs(profile.profile).max()))
    pixel_range = (float(profile.pixel[0]), float(profile.pixel[-1]))
    dispersion = float(np.median(mapping.dispersion_nm_per_px(profile.pixel)))

    def stage(blur_nm: float) -> Callable[[QuadraticMapping], FloatArray]:
        blur_samples = blur_nm / abs(dispersion) / profile.spacing_px
        observed = profile.profile
        if blur_samples > 0:
            observed = ndimage.gaussian_filter1d(observed, blur_samples, axis=0, mode="nearest")

        def residual(candidate: QuadraticMapping) -> FloatArray:
            model = render(candidate)
            if blur_samples > 0:
                model = ndimage.gaussian_filter1d(model, blur_samples, axis=0, mode="nearest")
            weights = 1.0 / sigma**2
            scale = float(np.sum(weights * model * observed)) / max(
                float(np.sum(weights * model**2)), 1e-300
            )
            return np.asarray(((observed - scale * model) / sigma).ravel(), dtype=np.float64)

        return residual

    method = mapping.method if mapping.method.endswith("+refined") else f"{mapping.method}+refined"
    refined = mapping
    for blur_nm in REFINE_BLUR_NM:
        refined, cost = refine_mapping(
            refined, stage(blur_nm), pixel_range=pixel_range, method=method
        )
    n_residuals = profile.profile.size
    return refined.with_details(
        details={
            **dict(refined.details),
            "reduced_chi2": cost / max(n_residuals - 4, 1),
            "start": list(mapping.coefficients),
        }
    )
