"""The image formation model: render direct and first-order observations of a lamp through a grating.

Physics (Makabe et al. 2025, Eq. 2–3, made continuous): the first order spreads the light so that
wavelength ``λ`` lands at pixel ``p(λ)``; a pixel ``[p − ½, p + ½]`` collects

    m_c(p) = ∫_{g(p−½)}^{g(p+½)} e(λ) η(λ) s_c(λ) dλ,

with ``g`` the pixel→wavelength mapping, ``e`` the lamp, ``η`` the grating efficiency and ``s_c``
the camera. The slit's image (a box ``slit_width_px`` wide) and the lens PSF (a Gaussian) blur the
result along the dispersion direction. The direct (0th-order) signal is ``Σ ∫ e s_c dλ``.

Everything is computed on a fine wavelength axis (1 nm by default): curves are linearly interpolated to
its nodes, the spectral density is integrated with the trapezoid rule into a cumulative integral, and a
pixel's signal is the difference of that cumulative integral at its two edge wavelengths. The solvers
use exactly the same discretisation through :class:`LampOperators` (the density of one hat function of
the working grid times the lamp), so a camera that is linear between grid nodes, seen through a flat
grating, is reproduced to rounding error.

Noise: :class:`PeakFractionNoise` (the paper-style protocol: Gaussian noise of a fraction of the
profile's peak) or :class:`ShotReadNoise` (shot + read noise relative to a full well), both seeded
through an explicit ``numpy.random.Generator``; the per-pixel standard deviations are returned with
the observation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.observations import LampKind, LampObservation
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid

EfficiencyLike = Spectrum | Callable[[FloatArray], FloatArray] | None

#: Internal spectral resolution of rendering and of the solvers' operators.
FINE_STEP_NM = 1.0


class WavelengthMapping(Protocol):
    """Anything that maps pixel coordinates to wavelengths (quadratic or physical grating)."""

    def wavelength_nm(self, pixel: ArrayLike) -> FloatArray:
        """Wavelength in nm at each pixel coordinate."""
        ...


# ----------------------------------------------------------------------------- discretisation


def pixel_edges(pixel: ArrayLike) -> FloatArray:
    """Edges of the pixels, shape ``(n + 1,)``: midpoints between centres, half a spacing beyond ends."""
    centres = np.asarray(pixel, dtype=np.float64)
    if centres.ndim != 1 or centres.size < 2:
        raise InputError(
            f"need at least 2 pixel coordinates, got shape {centres.shape}", source="pixel"
        )
    middle = 0.5 * (centres[1:] + centres[:-1])
    first = centres[0] - 0.5 * (centres[1] - centres[0])
    last = centres[-1] + 0.5 * (centres[-1] - centres[-2])
    return np.concatenate([[first], middle, [last]])


def fine_axis(start_nm: float, stop_nm: float, step_nm: float = FINE_STEP_NM) -> FloatArray:
    """Nodes ``k·step`` (multiples of the step) inside ``[start_nm, stop_nm]``."""
    first = math.ceil(start_nm / step_nm - 1e-9)
    last = math.floor(stop_nm / step_nm + 1e-9)
    if last <= first:
        raise InputError(
            f"the range {start_nm:g}–{stop_nm:g} nm holds fewer than two {step_nm:g} nm nodes",
            source="wavelength range",
        )
    return np.arange(first, last + 1, dtype=np.float64) * step_nm


@dataclass(frozen=True, eq=False)
class PiecewiseLinearDensity:
    """Spectral densities linear between the nodes of a uniform fine axis, integrated exactly.

    The cumulative integral of a piecewise-linear density is piecewise quadratic and continuously
    differentiable in the integration limits, so a pixel's signal varies smoothly with the mapping
    (no kinks where a pixel edge crosses a node — the mapping refinement differentiates it).

    Attributes
    ----------
    axis_nm
        Uniform fine axis, shape ``(n_fine,)``.
    density
        Shape ``(n_fine,)`` or ``(n_fine, k)``: the density at the nodes (per nm).
    cumulative
        Same shape: ``∫_{axis[0]}^{axis[j]} density`` (trapezoid, exact for linear pieces).
    """

    axis_nm: FloatArray
    density: FloatArray
    cumulative: FloatArray

    @classmethod
    def on_axis(cls, axis_nm: FloatArray, density: FloatArray) -> PiecewiseLinearDensity:
        step = float(axis_nm[1] - axis_nm[0])
        cumulative = np.zeros_like(density, dtype=np.float64)
        cumulative[1:] = np.cumsum(0.5 * (density[1:] + density[:-1]) * step, axis=0)
        return cls(axis_nm, np.asarray(density, dtype=np.float64), cumulative)

    @property
    def total(self) -> FloatArray:
        """The integral over the whole axis, shape ``()`` or ``(k,)``."""
        return np.asarray(self.cumulative[-1], dtype=np.float64)

    def cumulative_at(self, wavelength_nm: FloatArray) -> FloatArray:
        """Exact ``∫_{axis[0]}^{λ} density`` at each wavelength (constant beyond the axis)."""
        step = float(self.axis_nm[1] - self.axis_nm[0])
        last = self.axis_nm.size - 1
        position = np.clip((np.asarray(wavelength_nm) - self.axis_nm[0]) / step, 0.0, float(last))
        index = np.minimum(position.astype(np.intp), last - 1)
        fraction = position - index
        shape = (-1,) + (1,) * (self.density.ndim - 1)
        t = fraction.reshape(shape)
        low = self.density[index]
        high = self.density[index + 1]
        return np.asarray(
            self.cumulative[index] + step * t * (low + 0.5 * (high - low) * t), dtype=np.float64
        )

    def integrate_pixels(self, edges_nm: FloatArray) -> FloatArray:
        """Integral between consecutive edge wavelengths ``(n + 1,)``, shape ``(n, ...)``.

        ``±(C(λ_{k+1}) − C(λ_k))``, signed so that decreasing mappings work too (the density itself
        may be negative: a slit correction's terms); no light beyond the axis.
        """
        edges = np.asarray(edges_nm, dtype=np.float64)
        values = self.cumulative_at(edges)
        direction = np.where(np.diff(edges) < 0, -1.0, 1.0)
        shape = (-1,) + (1,) * (values.ndim - 1)
        return np.asarray(np.diff(values, axis=0) * direction.reshape(shape), dtype=np.float64)


def hat_matrix(
    grid: WavelengthGrid, wavelength_nm: ArrayLike, *, clamp: bool = False
) -> FloatArray:
    """Linear-interpolation weights of the grid's nodes at given wavelengths (Makabe et al. Eq. 14).

    Parameters
    ----------
    grid
        The working grid (``f`` nodes).
    wavelength_nm
        Shape ``(n,)``.
    clamp
        Evaluate wavelengths outside the grid at the nearest end (else their rows are zero).

    Returns
    -------
    numpy.ndarray
        Shape ``(n, f)``; rows inside the grid sum to 1.
    """
    wavelength = np.asarray(wavelength_nm, dtype=np.float64)
    position = (wavelength - grid.start_nm) / grid.step_nm
    inside = (position >= -1e-9) & (position <= grid.size - 1 + 1e-9)
    position = np.clip(position, 0.0, grid.size - 1.0)
    index = np.minimum(position.astype(np.intp), grid.size - 2)
    fraction = position - index
    matrix = np.zeros((wavelength.size, grid.size))
    rows = np.arange(wavelength.size)
    matrix[rows, index] = 1.0 - fraction
    matrix[rows, index + 1] += fraction
    if not clamp:
        matrix[~inside] = 0.0
    return matrix


def _values_on(curve: Spectrum | MultiSpectrum, axis_nm: FloatArray) -> FloatArray:
    """Linear interpolation on ``axis_nm``, zero outside the curve's range; shape ``(n,)``/``(n, k)``."""
    if isinstance(curve, Spectrum):
        return curve.at(axis_nm)
    return np.stack(
        [
            np.interp(axis_nm, curve.wavelength_nm, curve.values[:, k], left=0.0, right=0.0)
            for k in range(curve.values.shape[1])
        ],
        axis=1,
    )


def _efficiency_on(efficiency: EfficiencyLike, axis_nm: FloatArray) -> FloatArray:
    if efficiency is None:
        return np.ones_like(axis_nm)
    values = efficiency.at(axis_nm) if isinstance(efficiency, Spectrum) else efficiency(axis_nm)
    values = np.asarray(values, dtype=np.float64)
    if values.shape != axis_nm.shape or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise InputError(
            "grating efficiency must give finite values >= 0, one per wavelength",
            source="grating_efficiency",
        )
    return values


@dataclass(frozen=True, eq=False)
class LampOperators:
    """What one lamp contributes to the linear model on a working grid, independent of the mapping.

    With the camera linear between grid nodes, ``s(λ) = Σ_i φ_i(λ) s_i`` (``φ_i`` the hat functions),
    a pixel sees ``Σ_i s_i ∫_pixel e(λ) φ_i(λ) dλ`` (times η) and the direct signal is
    ``Σ_i s_i ∫ e φ_i dλ``. The hats are cut at the grid's ends (no light is modelled outside).

    Attributes
    ----------
    grid
        Working grid (``f`` nodes).
    densities
        ``e·φ_i`` for each node ``i`` on the fine axis, shape ``(n_fine, f)``.
    direct_row
        Shape ``(f,)``: ``∫ e φ_i dλ`` (the direct signal is ``direct_row @ s``).
    """

    grid: WavelengthGrid
    densities: PiecewiseLinearDensity
    direct_row: FloatArray

    @property
    def axis_nm(self) -> FloatArray:
        return self.densities.axis_nm

    def pixel_matrix(self, edges_nm: ArrayLike) -> FloatArray:
        """``K`` of shape ``(n, f)``: ``K[p, i] = ∫_{pixel p} e φ_i dλ`` for pixel edges ``(n + 1,)``."""
        return self.densities.integrate_pixels(np.asarray(edges_nm, dtype=np.float64))


def lamp_operators(
    lamp: Spectrum,
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    fine_step_nm: float = FINE_STEP_NM,
    slit_fwhm_nm: float | None = None,
) -> LampOperators:
    """Precompute :class:`LampOperators` for a lamp (its native samples interpolated to the fine axis).

    ``slit_fwhm_nm``: the lamp spectrum ``e_G = e ⊗ G`` and the profile were both blurred by a
    Gaussian ``G`` of this FWHM (:func:`calib.model.resolution.match_spectrometer`). The blurred
    profile sees ``G ⊗ (e r)``, not ``r (e ⊗ G)``; with ``r`` expanded to second order over the slit
    (the exact moments of a Gaussian slit),
    ``G ⊗ (e r) = r e_G + σ² r′ e_G′ + ½ r″ (σ⁴ e_G″ + σ² e_G) + O(σ³ r‴)``, and the densities
    carry the two correction terms, ``r′`` and ``r″`` as central differences of the grid values
    (:func:`grid_derivatives`). Without them the error is of order ``σ² r″/(2r)``: a few per cent
    at a 25 nm slit.

    Raises
    ------
    InputError
        When the lamp spectrum does not cover the grid.
    """
    if not lamp.covers(grid):
        lo, hi = lamp.range_nm
        raise InputError(
            f"lamp spectrum covers {lo:g}–{hi:g} nm but the grid needs {grid.start_nm:g}–"
            f"{grid.stop_nm:g} nm; measure a wider range or choose a narrower grid (--grid)",
            source=lamp.name,
        )
    axis = fine_axis(grid.start_nm, grid.stop_nm, fine_step_nm)
    hats = hat_matrix(grid, axis)
    density = lamp.at(axis)[:, None] * hats
    if slit_fwhm_nm is not None and slit_fwhm_nm > 0:
        sigma2 = (slit_fwhm_nm / (2.0 * math.sqrt(2.0 * math.log(2.0)))) ** 2
        first = np.gradient(lamp.values, lamp.wavelength_nm)
        second = np.gradient(first, lamp.wavelength_nm)
        slope = np.interp(axis, lamp.wavelength_nm, first, 0.0, 0.0)
        curvature = np.interp(axis, lamp.wavelength_nm, second, 0.0, 0.0)
        d1, d2 = grid_derivatives(grid)
        smooth = grid_smoothing(grid, math.sqrt(sigma2))
        d1, d2 = d1 @ smooth, d2 @ smooth
        density = (
            density
            + (sigma2 * slope)[:, None] * (hats @ d1)
            + (0.5 * (sigma2**2 * curvature + sigma2 * lamp.at(axis)))[:, None] * (hats @ d2)
        )
    densities = PiecewiseLinearDensity.on_axis(axis, density)
    return LampOperators(grid, densities, densities.total.copy())


def grid_smoothing(grid: WavelengthGrid, sigma_nm: float) -> FloatArray:
    """``S`` ``(f, f)``: a Gaussian of ``sigma_nm`` over the grid's nodes, rows summing to 1.

    The slit correction takes ``r′``, ``r″`` of ``S r``: its response to a component of ``r`` of
    wavenumber ``k`` is then ``1 − ½σ²k² e^{−σ²k²/2}`` — right to second order for smooth ``r``,
    and never above 1 for the fast components, where the bare Taylor term ``1 − ½σ²k²`` would turn
    negative (a 25 nm slit on a 10 nm grid) and the solve would chase them.
    """
    nodes = np.arange(grid.size, dtype=np.float64) * grid.step_nm
    weights = np.exp(-0.5 * ((nodes[:, None] - nodes[None, :]) / max(sigma_nm, 1e-9)) ** 2)
    return np.asarray(weights / weights.sum(axis=1, keepdims=True), dtype=np.float64)


def grid_derivatives(grid: WavelengthGrid) -> tuple[FloatArray, FloatArray]:
    """``D₁``, ``D₂`` ``(f, f)``: first and second derivatives (per nm, per nm²) of a curve from its
    values on ``grid``, as central differences (the end nodes take their neighbour's)."""
    size, step = grid.size, grid.step_nm
    first = np.zeros((size, size))
    second = np.zeros((size, size))
    for node in range(size):
        centre = min(max(node, 1), size - 2)
        first[node, centre - 1] -= 0.5 / step
        first[node, centre + 1] += 0.5 / step
        second[node, centre - 1 : centre + 2] = np.array([1.0, -2.0, 1.0]) / step**2
    return first, second


#: A lamp has light where its spectrum exceeds this fraction of its peak (the 2nd order's onset).
SECOND_ORDER_LIGHT_FRACTION = 0.01
#: A camera's lens and filter stack pass little below this (nm): a lamp's ultraviolet shorter
#: than it reaches the sensor too weakly in its 2nd order to matter.
SHORTEST_SEEN_NM = 380.0


def second_order_onset_nm(lamp: Spectrum) -> float:
    """Where the lamp's 2nd order begins, in 1st-order wavelengths: twice its shortest wavelength
    with light (above :data:`SECOND_ORDER_LIGHT_FRACTION` of its peak), and never below twice
    :data:`SHORTEST_SEEN_NM`.

    The grating equation sends order 2 of ``λ`` to the angle of order 1 of ``2λ``, so a first-order
    pixel at ``λ₁`` also receives ``η₂(λ₁/2) e(λ₁/2) s(λ₁/2)`` wherever the lamp has light at
    ``λ₁/2``. A lamp lit at the first wavelength it was measured at may have light below it: the
    onset is then at most twice that wavelength (a bound, the conservative side for a mask).

    Examples
    --------
    >>> import numpy as np
    >>> axis = np.arange(380.0, 781.0, 5.0)
    >>> second_order_onset_nm(Spectrum(axis, np.where(axis >= 420.0, 1.0, 0.0)))
    840.0
    """
    values = np.asarray(lamp.values, dtype=np.float64)
    peak = float(values.max(initial=0.0))
    if peak <= 0:
        return math.inf
    lit = np.flatnonzero(values > SECOND_ORDER_LIGHT_FRACTION * peak)
    return 2.0 * max(float(lamp.wavelength_nm[lit[0]]), SHORTEST_SEEN_NM)


# ------------------------------------------------------------------------------------ blur


def blur_kernel(slit_width_px: float = 0.0, psf_sigma_px: float = 0.0) -> FloatArray | None:
    """Normalised 1-D kernel: a box ``slit_width_px`` wide (fractional ends) convolved with a Gaussian.

    Returns ``None`` when there is no blur (both ≤ 0).
    """
    if slit_width_px < 0 or psf_sigma_px < 0:
        raise InputError("slit width and PSF sigma must be >= 0 px", source="blur")
    if slit_width_px <= 1e-9 and psf_sigma_px <= 1e-9:
        return None
    half = math.ceil(slit_width_px / 2 + 4 * psf_sigma_px) + 1
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    if slit_width_px > 1e-9:
        # Overlap of each unit pixel with the box [−w/2, w/2].
        lo = np.clip(offsets - 0.5, -slit_width_px / 2, slit_width_px / 2)
        hi = np.clip(offsets + 0.5, -slit_width_px / 2, slit_width_px / 2)
        kernel = hi - lo
    else:
        kernel = (offsets == 0).astype(np.float64)
    if psf_sigma_px > 1e-9:
        gaussian = np.exp(-0.5 * (offsets / psf_sigma_px) ** 2)
        kernel = np.convolve(kernel, gaussian / gaussian.sum(), mode="same")
    return np.asarray(kernel / kernel.sum(), dtype=np.float64)


def apply_blur(values: FloatArray, kernel: FloatArray | None) -> FloatArray:
    """Convolve each column of ``values`` ``(n, ...)`` along axis 0 (zero beyond the ends)."""
    if kernel is None:
        return values
    from scipy.ndimage import convolve1d  # deferred: scipy.ndimage is slow to import

    weights = np.asarray(kernel, dtype=np.float64)
    # numpy's mode="same" keeps the full convolution from index (len - 1) // 2; ndimage centres an
    # even kernel one sample later, hence the origin. One call for every column: the mapping
    # search blurs a model per trial mapping, and a Python loop of np.convolve per column cost it
    # a third of its time.
    origin = -1 if weights.size % 2 == 0 else 0
    blurred: FloatArray = convolve1d(
        np.asarray(values, dtype=np.float64), weights, axis=0, mode="constant", origin=origin
    )
    return blurred


# ------------------------------------------------------------------------------------ noise


@dataclass(frozen=True)
class PeakFractionNoise:
    """Gaussian noise of a fixed fraction of the peak (the paper-style synthetic protocol).

    Attributes
    ----------
    fraction
        σ of every profile sample = ``fraction × max(profile)`` (max over pixels and channels).
    direct_fraction
        σ of each direct channel = ``direct_fraction × max(direct)``; ``None`` = same as ``fraction``.
    """

    fraction: float
    direct_fraction: float | None = None

    def sigmas(self, profile: FloatArray, direct: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Standard deviations of shapes ``(n, 3)`` and ``(3,)``."""
        if self.fraction < 0 or (self.direct_fraction or 0) < 0:
            raise InputError("noise fractions must be >= 0", source="noise")
        direct_fraction = self.fraction if self.direct_fraction is None else self.direct_fraction
        return (
            np.full(profile.shape, self.fraction * float(np.max(profile))),
            np.full(direct.shape, direct_fraction * float(np.max(direct))),
        )


@dataclass(frozen=True)
class ShotReadNoise:
    """Shot + read noise of a sensor, with exposures set relative to its full well.

    Attributes
    ----------
    full_well_electrons
        Electrons at saturation.
    read_noise_electrons
        Read noise per pixel and frame (electrons RMS).
    profile_fill, direct_fill
        The exposure puts the brightest profile sample / direct pixel at this fraction of full well.
    rows_averaged
        Sensor rows averaged across the first-order band (the paper averages ~200).
    direct_pixels
        Pixels summed over the direct spot.
    """

    full_well_electrons: float = 30000.0
    read_noise_electrons: float = 3.0
    profile_fill: float = 0.8
    direct_fill: float = 0.8
    rows_averaged: int = 1
    direct_pixels: int = 100

    def sigmas(self, profile: FloatArray, direct: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Standard deviations of shapes ``(n, 3)`` and ``(3,)`` in the signals' own units."""
        if self.full_well_electrons <= 0 or self.rows_averaged < 1 or self.direct_pixels < 1:
            raise InputError(
                "full well, rows averaged and direct pixels must be positive", source="noise"
            )
        profile_gain = (
            self.profile_fill * self.full_well_electrons / max(float(np.max(profile)), 1e-300)
        )
        electrons = np.clip(profile, 0, None) * profile_gain
        profile_sigma = np.sqrt(electrons + self.read_noise_electrons**2) / profile_gain
        profile_sigma /= math.sqrt(self.rows_averaged)
        # The direct spot's brightest pixel is at direct_fill; the spot sums direct_pixels pixels.
        per_pixel = np.clip(direct, 0, None) / self.direct_pixels
        direct_gain = (
            self.direct_fill * self.full_well_electrons / max(float(np.max(per_pixel)), 1e-300)
        )
        direct_electrons = per_pixel * direct_gain
        direct_sigma = (
            np.sqrt(self.direct_pixels * (direct_electrons + self.read_noise_electrons**2))
            / direct_gain
        )
        return profile_sigma, direct_sigma


NoiseModel = PeakFractionNoise | ShotReadNoise


# ------------------------------------------------------------------------------------ render


@dataclass(frozen=True, eq=False)
class RenderedObservation:
    """A rendered lamp observation with the truth it came from.

    Attributes
    ----------
    observation
        What an estimator sees (noisy when a noise model was given, with its sigmas).
    clean_profile, clean_direct
        Noise-free profile ``(n, 3)`` and direct RGB ``(3,)``.
    unblurred_profile
        Shape ``(n, 3)``: what lands on each pixel before slit/PSF blur.
    spectral_axis_nm, spectral_image
        The first order's spectral signal ``e·η·s`` per nm on the fine axis, shapes ``(n_fine,)`` and
        ``(n_fine, 3)`` (what the twin integrates over each pixel's wavelength interval).
    true_wavelength_nm
        Shape ``(n,)``: the wavelength at each pixel centre.
    """

    observation: LampObservation
    clean_profile: FloatArray
    clean_direct: FloatArray
    unblurred_profile: FloatArray
    spectral_axis_nm: FloatArray
    spectral_image: FloatArray
    true_wavelength_nm: FloatArray


def render_observation(
    lamp: Spectrum,
    camera: MultiSpectrum,
    *,
    mapping: WavelengthMapping,
    pixel: ArrayLike | int,
    grating_efficiency: EfficiencyLike = None,
    slit_width_px: float = 0.0,
    psf_sigma_px: float = 0.0,
    noise: NoiseModel | None = None,
    rng: np.random.Generator | None = None,
    kind: LampKind = "other",
    name: str | None = None,
    fine_step_nm: float = FINE_STEP_NM,
    direct_throughput: float = 1.0,
    zeroth_order_efficiency: EfficiencyLike = None,
) -> RenderedObservation:
    """Render a lamp's direct RGB and first-order profile as the camera records them.

    Parameters
    ----------
    lamp
        Lamp spectral power distribution (any sampling; linearly interpolated to the fine axis).
    camera
        Sensitivity with 3 channels; zero outside its wavelength range.
    mapping
        Pixel→wavelength mapping (:class:`calib.core.mapping.QuadraticMapping` or
        :class:`calib.core.mapping.GratingGeometry`).
    pixel
        Pixel coordinates ``(n,)`` (increasing), or a count ``n`` for ``0 … n−1``.
    grating_efficiency
        First-order efficiency η(λ): a :class:`Spectrum`, a callable of wavelength (nm), or ``None``
        for a flat grating.
    slit_width_px, psf_sigma_px
        Blur along the dispersion direction: the slit's image width (box) and a Gaussian PSF σ.
    noise
        :class:`PeakFractionNoise` or :class:`ShotReadNoise`; ``None`` renders noise-free with no
        sigmas attached.
    rng
        Required with ``noise``: the seeded generator that draws it.
    kind, name
        Stored on the observation (``name`` defaults to the lamp's).
    fine_step_nm
        Internal spectral step.
    direct_throughput
        Ratio of the direct path's throughput to the first order's (the 0th-order efficiency).
    zeroth_order_efficiency
        The 0th order's efficiency η₀(λ) (a :class:`Spectrum`, a callable, or ``None`` for a flat
        one): the direct signal is ``direct_throughput · ∫ e η₀ s_c dλ``.

    Returns
    -------
    RenderedObservation
    """
    pixels = (
        np.arange(pixel, dtype=np.float64)
        if isinstance(pixel, int)
        else np.asarray(pixel, dtype=np.float64)
    )
    if noise is not None and rng is None:
        raise InputError(
            "a noise model needs an explicit seeded numpy Generator (rng=)", source="rng"
        )
    if camera.values.ndim != 2 or camera.values.shape[1] != 3:
        raise InputError(
            f"camera needs 3 channels, has {camera.values.shape[1]}", source=camera.name
        )
    lo = max(lamp.range_nm[0], float(camera.wavelength_nm[0]))
    hi = min(lamp.range_nm[1], float(camera.wavelength_nm[-1]))
    axis = fine_axis(lo, hi, fine_step_nm)
    lamp_values = lamp.at(axis)
    sensitivity = _values_on(camera, axis)
    efficiency = _efficiency_on(grating_efficiency, axis)
    spectral_image = (lamp_values * efficiency)[:, None] * sensitivity
    edges_nm = np.asarray(mapping.wavelength_nm(pixel_edges(pixels)), dtype=np.float64)
    unblurred = PiecewiseLinearDensity.on_axis(axis, spectral_image).integrate_pixels(edges_nm)
    clean_profile = apply_blur(unblurred, blur_kernel(slit_width_px, psf_sigma_px))
    zeroth = _efficiency_on(zeroth_order_efficiency, axis)
    clean_direct = (
        direct_throughput
        * PiecewiseLinearDensity.on_axis(axis, (lamp_values * zeroth)[:, None] * sensitivity).total
    )
    profile, direct = clean_profile, clean_direct
    profile_sigma: FloatArray | None = None
    direct_sigma: FloatArray | None = None
    if noise is not None and rng is not None:
        profile_sigma, direct_sigma = noise.sigmas(clean_profile, clean_direct)
        profile = clean_profile + rng.standard_normal(clean_profile.shape) * profile_sigma
        direct = clean_direct + rng.standard_normal(3) * direct_sigma
    true_wavelength = np.asarray(mapping.wavelength_nm(pixels), dtype=np.float64)
    observation = LampObservation(
        name=name or lamp.name,
        spectrum=lamp,
        pixel=pixels,
        profile=profile,
        direct_rgb=direct,
        profile_sigma=profile_sigma,
        direct_sigma=direct_sigma,
        kind=kind,
        metadata={"rendered": True, "slit_width_px": slit_width_px, "psf_sigma_px": psf_sigma_px},
    )
    return RenderedObservation(
        observation=observation,
        clean_profile=clean_profile,
        clean_direct=clean_direct,
        unblurred_profile=unblurred,
        spectral_axis_nm=axis,
        spectral_image=spectral_image,
        true_wavelength_nm=true_wavelength,
    )
