"""The rig as a spectrometer: a lamp's spectral power distribution from one diffraction image.

With a calibrated camera (sensitivity ``s_c(λ)``, and the grating's first-order efficiency ``η(λ)``
when it is known), the first-order profile of a lamp is ``r_c(λ) = c_c(λ) e(λ)`` per nm, where
``c_c = s_c η`` is the system's response (Alvarez et al., Eq. 5). Each channel gives a quotient
``q_c(λ) = r_c(λ) / c_c(λ)``, an estimate of the lamp ``e(λ)``; the estimate ``ê`` minimises

``E = Σ_c Σ_λ (ω_{c,λ} (ê_λ − q_{c,λ}))² + w_s Σ_λ (Δê_λ)²``        (Eq. 6, 7, 11)

where samples whose response is below ``threshold`` (0.02 of the maximum) are left out, ``Δ`` is
the discrete Laplacian ``[1 −2 1]`` and the weights ``ω`` (Eq. 8–10) fall from 1 to 0 as a channel's
quotient, normalised by its maximum ``P_c``, moves away from the median of the three normalised
quotients at that wavelength (``α`` sets the slope: 0.09 for point sources, 2 for finite ones).

Steps, in order:

1. **Mapping** — :func:`calib.wavelength.find_mapping` with the camera known (its ``"lines"``
   strategy, :mod:`calib.wavelength.calibrated`): pixel→wavelength from a fluorescent lamp's peaks
   (the paper uses 546.5 and 611.6 nm), its measured spectrum when there is one, else a reference
   line list.
2. **Finite sources** — :func:`richardson_lucy`: the first order is the spectrum convolved with the
   source's image along the dispersion; the kernel is the direct spot's own profile along that
   direction (:func:`source_kernel_from_image`: crop around the spot, threshold relative to its
   maximum, normalise), as the paper crops and thresholds the source in the image.
3. **Amplitude recovery** — :func:`recover_spd_alvarez2014`, the weighted least squares above, a
   pentadiagonal system solved directly. ``weighting="paper"`` uses the paper's ``ω`` alone;
   ``weighting="noise"`` (default) multiplies ``ω²`` by each quotient's inverse noise variance
   (from the profile's σ divided by the response), the refinement the paper proposes in §7–8.

Deliberate departures, each because the paper's literal choice is wrong for a measurement: the
Laplacian is not circular (a circular kernel ties 400 nm to 700 nm); ``ω`` is clipped to ``[0, 1]``
(Eq. 8 turns negative for ``|v| > 1``, which noise makes possible); ``P_c`` is the maximum of the
median-filtered quotient (a single noisy sample would otherwise set it); ``w_s`` keeps its meaning
in nm whatever the sampling (it is the paper's at 0.333 nm per sample, rescaled by ``(h₀/h)⁴``).

Recognising the source, its CCT and white-balance gains are in :mod:`calib.spd.light_sources`.

References
----------
Alvarez, S., Presa, L., Kunkel, T., Masia, B. (2014). Low Cost Recovery of Spectral Power
Distributions. Spanish Computer Graphics Conference (CEIG), Eurographics.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.core.arrays import FloatArray, checked_array
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.spectra import MultiSpectrum, Spectrum, WavelengthGrid
from calib.image.hdr import HdrImage
from calib.image.profiles import DiffractionGeometry, Extraction
from calib.image.profiles.geometry import rectangle_window, sample_positions, to_uv
from calib.model.forward import WavelengthMapping
from calib.wavelength.calibrated import ProfileRenderer, system_response

SourceMode = Literal["point", "finite", "auto"]
Weighting = Literal["noise", "paper"]

#: Weight of the smoothness term (the paper's ``w_s``, "works well across sources").
DEFAULT_SMOOTHNESS = 50.0
#: The paper's sampling (0.333 nm per pixel), at which ``w_s`` is defined.
PAPER_SAMPLE_NM = 1.0 / 3.0
#: Responses below this fraction of the maximum are left out (the paper's 0.02).
DEFAULT_THRESHOLD = 0.02
#: The paper's ``α``: slope of the median-distance weights, per kind of source.
ALPHA_POINT = 0.09
ALPHA_FINITE = 2.0
#: Richardson–Lucy iterations for finite sources.
DEFAULT_RL_ITERATIONS = 30
#: The spot's profile is cut where it falls below this fraction of its maximum.
DEFAULT_KERNEL_THRESHOLD = 0.05


# ------------------------------------------------------------------------------------------ input


@dataclass(frozen=True, eq=False)
class DiffractedProfile:
    """What the spectrometer reads: one lamp's first-order profile (and its direct spot).

    Parameters
    ----------
    pixel
        Shape ``(n,)``, increasing, uniformly spaced: distance from the direct spot along the order
        in sensor pixels (as :mod:`calib.image.profiles` extracts it).
    profile
        Shape ``(n, 3)``: R, G, B radiance on the band, linear (DN/s).
    profile_sigma
        Shape ``(n, 3)``: its standard deviation, or ``None`` when unknown.
    direct_rgb, direct_sigma
        Shape ``(3,)``: the direct spot's RGB and σ, or ``None``.
    source_kernel
        Shape ``(k,)``, ``k`` odd: the source's image along the dispersion, sampled at the profile's
        spacing and centred (sums to 1), or ``None`` (see :func:`source_kernel_from_image`).
    name
        Lamp name, for messages and outputs.
    metadata
        Provenance (frames, geometry).
    """

    pixel: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray | None = None
    direct_rgb: FloatArray | None = None
    direct_sigma: FloatArray | None = None
    source_kernel: FloatArray | None = None
    name: str = "lamp"
    metadata: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        label = f"lamp {self.name!r}"
        pixel = np.array(self.pixel, dtype=np.float64)
        if pixel.ndim != 1 or pixel.size < 8:
            raise InputError(f"need ≥ 8 profile samples, got shape {pixel.shape}", source=label)
        steps = np.diff(pixel)
        if not np.all(steps > 0) or np.ptp(steps) > 1e-6 * max(float(steps.mean()), 1.0):
            raise InputError("pixel coordinates must increase in equal steps", source=label)
        n = pixel.size
        object.__setattr__(self, "pixel", checked_array(pixel, (n,), "pixel", label))
        object.__setattr__(self, "profile", checked_array(self.profile, (n, 3), "profile", label))
        for name, shape in (
            ("profile_sigma", (n, 3)),
            ("direct_rgb", (3,)),
            ("direct_sigma", (3,)),
        ):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, checked_array(value, shape, name, label))
        if self.source_kernel is not None:
            kernel = np.array(self.source_kernel, dtype=np.float64)
            if kernel.ndim != 1 or kernel.size % 2 == 0 or np.any(kernel < 0) or kernel.sum() <= 0:
                raise InputError(
                    "the source kernel must be 1-D, of odd length, >= 0 and not all zero",
                    source=label,
                )
            object.__setattr__(
                self,
                "source_kernel",
                checked_array(kernel / kernel.sum(), kernel.shape, "source kernel", label),
            )

    @property
    def spacing_px(self) -> float:
        return float(self.pixel[1] - self.pixel[0])

    @classmethod
    def from_extraction(
        cls, extraction: Extraction, *, name: str, source_kernel: FloatArray | None = None
    ) -> DiffractedProfile:
        """From :func:`calib.image.profiles.extract`'s result (and optionally the spot's kernel)."""
        return cls(
            pixel=extraction.pixel,
            profile=extraction.profile,
            profile_sigma=extraction.profile_sigma,
            direct_rgb=extraction.direct_rgb,
            direct_sigma=extraction.direct_sigma,
            source_kernel=source_kernel,
            name=name,
            metadata={"frames": list(extraction.frames), "source": extraction.source},
        )


def widened_geometry(
    geometry: DiffractionGeometry,
    mapping: QuadraticMapping | GratingGeometry,
    range_nm: tuple[float, float],
    *,
    edge_margin_px: float = 4.0,
) -> DiffractionGeometry:
    """The geometry with its ``+1`` order extended to cover ``range_nm`` (as far as the sensor goes).

    Detection sets a band's extent where that lamp is bright; a spectrometer wants every
    wavelength the camera sees. The extent is cut where the band would leave the sensor and kept
    outside the direct spot.
    """
    band = geometry.primary
    wanted = np.sort(np.asarray(mapping.pixel_at(np.array(range_nm)), dtype=np.float64))
    start = max(float(wanted[0]), geometry.spot_half_size_px[0] + 2 * geometry.bin_px)
    stop = float(wanted[1])
    height, width = geometry.sensor_shape_px
    dx, dy = band.direction
    x0, y0 = geometry.spot_centre_px
    for v in (
        band.centre_offset_px - band.half_width_px,
        band.centre_offset_px + band.half_width_px,
    ):
        # Corner at distance u: (x0 + u dx − v dy, y0 + u dy + v dx) must stay inside the sensor.
        for origin, step, size in ((x0 - v * dy, dx, width), (y0 + v * dx, dy, height)):
            if step > 1e-9:
                stop = min(stop, (size - 1 - edge_margin_px - origin) / step)
            elif step < -1e-9:
                stop = min(stop, (edge_margin_px - origin) / step)
    stop -= geometry.bin_px  # extraction reads one bin beyond the end
    if stop - start < 8 * geometry.bin_px:
        raise InputError(
            f"the first order for {range_nm[0]:g}–{range_nm[1]:g} nm does not fit on the sensor",
            source="geometry",
        )
    return replace(
        geometry, orders=(replace(band, start_px=start, stop_px=stop), *geometry.orders[1:])
    )


def _dispersion_nm_per_px(mapping: WavelengthMapping, pixel: FloatArray) -> FloatArray:
    if isinstance(mapping, QuadraticMapping):
        return mapping.dispersion_nm_per_px(pixel)
    step = 0.5
    return np.asarray(
        (mapping.wavelength_nm(pixel + step) - mapping.wavelength_nm(pixel - step)) / (2 * step),
        dtype=np.float64,
    )


# ------------------------------------------------------------------------------- finite sources


def richardson_lucy(
    values: ArrayLike, kernel: ArrayLike, *, iterations: int = DEFAULT_RL_ITERATIONS
) -> FloatArray:
    """Richardson–Lucy deconvolution along axis 0 (Richardson 1972, Lucy 1974).

    Parameters
    ----------
    values
        Shape ``(n,)`` or ``(n, k)``: blurred non-negative signal(s), each column on its own;
        negative values (noise around zero) are set to zero.
    kernel
        Shape ``(m,)``, odd, centred: the blur (normalised here to sum 1).
    iterations
        Number of multiplicative updates (more sharpens more, and amplifies more noise).

    Returns
    -------
    numpy.ndarray
        Same shape as ``values``: deconvolved, ``>= 0``, each column with its input's total.
    """
    observed = np.clip(np.asarray(values, dtype=np.float64), 0.0, None)
    psf = np.asarray(kernel, dtype=np.float64)
    if psf.ndim != 1 or psf.size % 2 == 0 or psf.sum() <= 0 or iterations < 0:
        raise InputError("RL needs an odd, non-negative 1-D kernel and iterations >= 0")
    psf = psf / psf.sum()
    mirrored = psf[::-1]

    def blur(signal: FloatArray, weights: FloatArray) -> FloatArray:
        from scipy import ndimage  # deferred: scipy costs ~0.3 s; calib's CLI imports this module

        return np.asarray(ndimage.convolve1d(signal, weights, axis=0, mode="constant"), float)

    # Edge-normalised: near the ends part of the kernel falls outside; dividing by the covered part
    # keeps flux there instead of darkening the ends.
    coverage = blur(np.ones_like(observed), mirrored)
    estimate = np.empty_like(observed)
    estimate[...] = np.maximum(observed.mean(axis=0), 1e-300)
    tiny = 1e-12 * max(float(observed.max()), 1e-300)
    for _ in range(iterations):
        ratio = observed / np.maximum(blur(estimate, psf), tiny)
        estimate = estimate * blur(ratio, mirrored) / coverage
    totals = estimate.sum(axis=0)
    scale = np.where(totals > 0, observed.sum(axis=0) / np.where(totals > 0, totals, 1.0), 1.0)
    return np.asarray(estimate * scale, dtype=np.float64)


def source_kernel_from_image(
    image: HdrImage,
    geometry: DiffractionGeometry,
    *,
    background_rgb: ArrayLike | None = None,
    threshold: float = DEFAULT_KERNEL_THRESHOLD,
) -> FloatArray:
    """The source's image along the dispersion, from the direct spot (the paper's crop + threshold).

    The spot's radiance (all channels) is summed across the dispersion and binned along it at the
    geometry's ``bin_px``, centred on the spot; bins below ``threshold`` of the maximum are cut.

    Parameters
    ----------
    image
        The lamp's merged bracket (the spot must not be saturated in every frame).
    geometry
        Its geometry (spot centre, size and the first order's direction).
    background_rgb
        Per-channel background to subtract (e.g. :attr:`Extraction.direct_background_rgb`).
    threshold
        Relative cut-off.

    Returns
    -------
    numpy.ndarray
        Shape ``(k,)``, ``k`` odd, sums to 1: sampled at ``geometry.bin_px``.
    """
    centre = geometry.spot_centre_px
    angle = geometry.primary.angle_deg
    along, across = geometry.spot_half_size_px
    step = geometry.bin_px
    # Look well beyond the detected aperture (a wide source's tails): up to half-way to the order.
    reach_px = max(1.5 * along + 2 * step, 0.5 * geometry.primary.start_px)
    half_bins = math.ceil(reach_px / step)
    reach = (half_bins + 0.5) * step
    window = rectangle_window(image, centre, angle, (-reach, reach), (-across, across))
    if window is None:
        raise InputError("the direct spot is outside the image", source="source kernel")
    background = np.zeros(3) if background_rgb is None else np.asarray(background_rgb, float)
    sums = np.zeros(2 * half_bins + 1)
    for channel in range(3):
        y, x = sample_positions(image, channel, *window)
        u, v = to_uv(x, y, centre, angle)
        index = np.rint(u / step).astype(np.int64) + half_bins
        inside = (np.abs(v) <= across) & (index >= 0) & (index < sums.size)
        values = image.radiance[channel][window][inside].astype(np.float64) - background[channel]
        if image.saturated[channel][window][inside].any():
            raise InputError(
                "the direct spot is saturated in every frame; add a shorter exposure to measure "
                "the source's shape",
                source="source kernel",
            )
        sums += np.bincount(index[inside], np.where(np.isfinite(values), values, 0.0), sums.size)
    peak = float(sums.max())
    if peak <= 0:
        raise InputError("the direct spot shows no signal", source="source kernel")
    kernel = np.where(sums >= threshold * peak, sums, 0.0)
    lit = np.flatnonzero(kernel)
    half = max(half_bins - int(lit[0]), int(lit[-1]) - half_bins)
    kernel = kernel[half_bins - half : half_bins + half + 1]
    return np.asarray(kernel / kernel.sum(), dtype=np.float64)


def kernel_fwhm_samples(kernel: ArrayLike) -> float:
    """Full width at half maximum of a kernel, in samples (linear interpolation of the edges)."""
    values = np.asarray(kernel, dtype=np.float64)
    half = 0.5 * float(values.max())
    above = np.flatnonzero(values >= half)
    first, last = int(above[0]), int(above[-1])
    left = float(first)
    if first > 0:
        left = first - (values[first] - half) / (values[first] - values[first - 1])
    right = float(last)
    if last < values.size - 1:
        right = last + (values[last] - half) / (values[last] - values[last + 1])
    return right - left


# -------------------------------------------------------------------------------------- recovery


@dataclass(frozen=True, eq=False)
class SpdRecovery:
    """A recovered spectral power distribution and what it was computed from.

    Attributes
    ----------
    wavelength_nm
        Shape ``(n,)``: the profile samples' wavelengths inside the supported range.
    spd
        Shape ``(n,)``: the estimate ``ê`` (relative units: DN/s per nm per unit response).
    spd_sigma
        Shape ``(n,)``: its standard deviation from the profile noise, or ``None``.
    quotients
        Shape ``(n, 3)``: ``q_c = r_c / c_c`` (NaN where the response is below the threshold).
    weights
        Shape ``(n, 3)``: the paper's ``ω`` (0 where left out).
    response
        Shape ``(n, 3)``: the system response ``c_c`` at the samples (maximum 1 over the camera).
    mapping
        The pixel→wavelength mapping used.
    source
        ``"point"`` or ``"finite"`` (deconvolved).
    settings
        The parameters (smoothness, α, threshold, weighting, iterations).
    notes
        Things a user should know (no σ, flat grating assumed …).
    """

    wavelength_nm: FloatArray
    spd: FloatArray
    spd_sigma: FloatArray | None
    quotients: FloatArray
    weights: FloatArray
    response: FloatArray
    mapping: QuadraticMapping | GratingGeometry
    source: Literal["point", "finite"]
    settings: Mapping[str, Any]
    notes: tuple[str, ...] = ()

    @property
    def range_nm(self) -> tuple[float, float]:
        return float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])

    def spectrum(self, name: str = "recovered SPD") -> Spectrum:
        """The estimate at its native samples, negative noise clipped to zero, maximum 1."""
        values = np.clip(self.spd, 0.0, None)
        peak = float(values.max())
        if peak <= 0:
            raise EstimationError("the recovered SPD is zero everywhere")
        return Spectrum(self.wavelength_nm, values / peak, name=name)

    def sigma_spectrum(self) -> Spectrum | None:
        """σ on the same scale as :meth:`spectrum`, or ``None``."""
        if self.spd_sigma is None:
            return None
        peak = float(np.clip(self.spd, 0.0, None).max())
        return Spectrum(self.wavelength_nm, self.spd_sigma / peak, name="recovered SPD sigma")

    def on_grid(self, grid: WavelengthGrid) -> Spectrum:
        """:meth:`spectrum` on ``grid`` (hat-function projection, exact for spiky spectra)."""
        native = self.spectrum()
        lo, hi = self.range_nm
        if grid.start_nm < lo - 1e-6 or grid.stop_nm > hi + 1e-6:
            raise InputError(
                f"the SPD was recovered over {lo:.1f}–{hi:.1f} nm only (where the camera responds "
                f"and the profile reaches); choose a grid inside it, not {grid}",
                source="grid",
            )
        # Within the range, so end nodes are projected on the covered part of their hat.
        return native.resample(grid, "integrate")


def _second_difference_banded(n: int) -> FloatArray:
    """``DᵀD`` for the second difference ``D`` (``(n − 2) × n``), in upper banded form ``(3, n)``."""
    diagonal = np.full(n, 6.0)
    diagonal[[0, -1]] = 1.0
    if n > 2:
        diagonal[[1, -2]] = 5.0
    first = np.full(n, -4.0)
    first[[1, -1]] = -2.0
    second = np.ones(n)
    banded = np.zeros((3, n))
    banded[2] = diagonal
    banded[1, 1:] = first[1:]
    banded[0, 2:] = second[2:]
    return banded


def _robust_peak(values: FloatArray) -> float:
    from scipy import ndimage  # deferred: scipy costs ~0.3 s; calib's CLI imports this module

    finite = np.where(np.isfinite(values), values, 0.0)
    return float(np.max(ndimage.median_filter(finite, size=5, mode="nearest")))


def median_distance_weights(quotients: FloatArray, alpha: float) -> FloatArray:
    """The paper's ``ω`` (Eq. 8–10) for quotients ``(n, 3)`` (NaN = left out), clipped to [0, 1]."""
    peaks = np.array([_robust_peak(quotients[:, k]) for k in range(3)])
    normalised = quotients / np.where(peaks > 0, peaks, np.nan)[None, :]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: nothing valid there
        median = np.nanmedian(normalised, axis=1, keepdims=True)
    distance = np.nan_to_num(normalised - median, nan=np.inf)
    omega = 1.0 - np.exp(-1.0 / (distance**2 + alpha)) / math.exp(-1.0 / (1.0 + alpha))
    return np.where(np.isfinite(quotients), np.clip(omega, 0.0, 1.0), 0.0)


def _supported_slice(
    valid: NDArray[np.bool_], wavelength: FloatArray, range_nm: tuple[float, float]
) -> slice:
    usable = valid.any(axis=1) & (wavelength >= range_nm[0]) & (wavelength <= range_nm[1])
    indices = np.flatnonzero(usable)
    if indices.size < 8:
        raise EstimationError(
            "fewer than 8 profile samples fall where the camera responds (≥ threshold) inside "
            f"{range_nm[0]:g}–{range_nm[1]:g} nm; check the mapping and the camera file"
        )
    return slice(int(indices[0]), int(indices[-1]) + 1)


def recover_spd_alvarez2014(
    profile: DiffractedProfile,
    camera: MultiSpectrum,
    mapping: QuadraticMapping | GratingGeometry,
    *,
    grating_efficiency: Spectrum | None = None,
    source: SourceMode = "auto",
    smoothness: float = DEFAULT_SMOOTHNESS,
    alpha: float | None = None,
    threshold: float = DEFAULT_THRESHOLD,
    weighting: Weighting = "noise",
    rl_iterations: int = DEFAULT_RL_ITERATIONS,
    range_nm: tuple[float, float] = (380.0, 730.0),
    compute_sigma: bool = True,
) -> SpdRecovery:
    """Recover a lamp's SPD from its first-order profile (Alvarez et al. 2014, Eq. 5–11).

    Parameters
    ----------
    profile
        The lamp's profile (with σ for ``weighting="noise"``, with a source kernel for finite
        sources).
    camera
        The calibrated camera's sensitivity (3 channels).
    mapping
        Pixel→wavelength mapping of the profile's pixel axis (e.g. from :func:`find_mapping`).
    grating_efficiency
        The grating's first-order efficiency η(λ) if known (e.g. from the camera's calibration);
        ``None`` assumes it flat and says so in the notes.
    source
        ``"point"``: no deconvolution, α = 0.09; ``"finite"``: Richardson–Lucy with the profile's
        source kernel, α = 2; ``"auto"``: finite when a kernel is attached and wider (FWHM) than
        1.5 samples.
    smoothness
        ``w_s`` (Eq. 6) as the paper means it, at 0.333 nm per sample; rescaled to the profile's
        sampling so that it smooths the same in nm.
    alpha
        Slope of the weights; ``None``: with ``weighting="paper"`` the paper's value for the source
        kind (0.09 point, 2 finite), else 0.09.
    threshold
        Responses below this fraction of the maximum are left out.
    weighting
        ``"noise"`` (paper's ω × inverse noise variance, needs ``profile_sigma``) or ``"paper"``.
    rl_iterations
        Richardson–Lucy iterations for finite sources.
    range_nm
        Wavelengths considered (further limited to where the camera responds).
    compute_sigma
        Propagate the profile's σ to the SPD (a dense ``n × n`` inverse: skip it when only the
        estimate is needed).

    Returns
    -------
    SpdRecovery

    Raises
    ------
    InputError
        ``source="finite"`` without a kernel; bad parameters.
    EstimationError
        Too few usable samples (mapping or camera do not match the profile).
    """
    if smoothness < 0 or not 0 < threshold < 1 or rl_iterations < 0:
        raise InputError("need smoothness >= 0, 0 < threshold < 1 and rl_iterations >= 0")
    if weighting not in ("noise", "paper"):
        raise InputError(f"weighting must be 'noise' or 'paper', got {weighting!r}")
    notes: list[str] = []
    kernel = profile.source_kernel
    if source == "finite" and kernel is None:
        raise InputError(
            "a finite source needs the source's kernel (the direct spot's profile)",
            source=f"lamp {profile.name!r}",
        )
    finite = source == "finite" or (
        source == "auto" and kernel is not None and kernel_fwhm_samples(kernel) > 1.5
    )
    if alpha is not None:
        alpha_used = alpha
    elif weighting == "paper":
        alpha_used = ALPHA_FINITE if finite else ALPHA_POINT
    else:
        # α = 2 flattens ω to ≈ 0.15, i.e. smooths 40× harder: the paper's answer to the noise of
        # deconvolved bulbs. A slit's image deconvolves cleanly, and the noise weights already
        # handle the noise, so the point-source slope is kept.
        alpha_used = ALPHA_POINT
    signal = profile.profile
    if finite and kernel is not None:
        signal = richardson_lucy(signal, kernel, iterations=rl_iterations)
    sigma = profile.profile_sigma
    if weighting == "noise" and sigma is None:
        notes.append("the profile has no σ: the paper's weights were used alone")
    if grating_efficiency is None:
        notes.append("grating efficiency unknown: assumed flat (the SPD carries η(λ) if it is not)")

    wavelength_all = np.asarray(mapping.wavelength_nm(profile.pixel), dtype=np.float64)
    dispersion = _dispersion_nm_per_px(mapping, profile.pixel)
    if np.any(dispersion <= 0) or np.any(np.diff(wavelength_all) <= 0):
        raise EstimationError(
            "the mapping does not increase over the profile (wavelength must grow away from the "
            "direct spot); check the mapping lamp"
        )
    response_all = system_response(camera, grating_efficiency, wavelength_all)
    valid_all = response_all >= threshold
    keep = _supported_slice(valid_all, wavelength_all, range_nm)
    wavelength = wavelength_all[keep]
    response = response_all[keep]
    valid = valid_all[keep]
    density = signal[keep] / dispersion[keep, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        quotients = np.where(valid, density / response, np.nan)
    omega = median_distance_weights(quotients, alpha_used)
    data_weight = omega**2
    quotient_sigma: FloatArray | None = None
    if sigma is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            quotient_sigma = np.where(
                valid, sigma[keep] / dispersion[keep, None] / response, np.inf
            )
        if weighting == "noise":
            # Channels are weighted against each other by their noise at each wavelength; the
            # best channel keeps the paper's weight, so w_s means what it means in the paper.
            best = np.min(quotient_sigma, axis=1, keepdims=True)
            data_weight = data_weight * (best / quotient_sigma) ** 2
    data_weight = np.where(valid, data_weight, 0.0)
    totals = data_weight.sum(axis=1)
    right = np.sum(data_weight * np.nan_to_num(quotients), axis=1)
    # w_s is the paper's, at its 0.333 nm per sample: a discrete Laplacian of samples h nm apart
    # is h² times the curvature, summed over 1/h samples per nm, against 1/h data terms per nm,
    # so the same smoothing in nm needs w_s (h₀/h)⁴.
    sample_nm = float(np.median(np.diff(wavelength)))
    effective_smoothness = smoothness * (PAPER_SAMPLE_NM / sample_nm) ** 4
    banded = effective_smoothness * _second_difference_banded(wavelength.size)
    banded[2] += totals
    if np.count_nonzero(totals) < 2:
        raise EstimationError("fewer than two wavelengths carry weight; nothing to recover")
    from scipy import linalg  # deferred: scipy costs ~0.3 s; calib's CLI imports this module

    try:
        estimate = linalg.solveh_banded(banded, right)
    except linalg.LinAlgError as exc:
        raise EstimationError(f"the amplitude recovery system is singular ({exc})") from None
    estimate_sigma = None
    if quotient_sigma is not None and compute_sigma:
        # ê = H⁻¹ Σ_c W_c q_c: its covariance is H⁻¹ (Σ_c W_c² σ_c²) H⁻¹ (the weights held fixed).
        inverse = linalg.solveh_banded(banded, np.eye(wavelength.size))
        source_variance = np.sum(
            np.where(valid, data_weight**2 * np.where(valid, quotient_sigma, 0.0) ** 2, 0.0),
            axis=1,
        )
        estimate_sigma = np.sqrt(np.einsum("ij,j,ij->i", inverse, source_variance, inverse))
    return SpdRecovery(
        wavelength_nm=wavelength,
        spd=np.asarray(estimate, dtype=np.float64),
        spd_sigma=estimate_sigma,
        quotients=quotients,
        weights=omega,
        response=response,
        mapping=mapping,
        source="finite" if finite else "point",
        settings={
            "smoothness": smoothness,
            "smoothness_per_sample": effective_smoothness,
            "sample_nm": sample_nm,
            "alpha": alpha_used,
            "threshold": threshold,
            "weighting": weighting if sigma is not None else "paper",
            "rl_iterations": rl_iterations if finite else 0,
            "range_nm": list(range_nm),
            "kernel_fwhm_px": None
            if kernel is None
            else kernel_fwhm_samples(kernel) * profile.spacing_px,
        },
        notes=tuple(notes),
    )


def instrument_view(
    spectrum: Spectrum,
    recovery: SpdRecovery,
    profile: DiffractedProfile,
    camera: MultiSpectrum,
    *,
    grating_efficiency: Spectrum | None = None,
) -> Spectrum:
    """How this spectrometer would report ``spectrum``: rendered in the set-up, then recovered.

    The spectrum's profile on ``profile``'s pixel axis (same mapping, source kernel and response;
    the measured σ pattern weighs the channels) goes through the same recovery as ``recovery``.
    Comparing a measurement with library spectra seen this way leaves out what the instrument
    does to every spectrum alike (finite resolution, smoothing, the ends of the range), so only
    real differences remain.
    """
    render = ProfileRenderer.build(spectrum, profile, camera, grating_efficiency)
    model = render(recovery.mapping)
    if float(model.max()) <= 0:
        raise InputError("the spectrum gives no signal in this set-up", source=spectrum.name)
    synthetic = DiffractedProfile(
        pixel=profile.pixel,
        profile=model,
        profile_sigma=profile.profile_sigma,
        source_kernel=profile.source_kernel,
        name=spectrum.name,
    )
    settings = recovery.settings
    seen = recover_spd_alvarez2014(
        synthetic,
        camera,
        recovery.mapping,
        grating_efficiency=grating_efficiency,
        source=recovery.source,
        smoothness=float(settings["smoothness"]),
        alpha=float(settings["alpha"]),
        threshold=float(settings["threshold"]),
        weighting=settings["weighting"],
        rl_iterations=int(settings["rl_iterations"]) or DEFAULT_RL_ITERATIONS,
        range_nm=(float(settings["range_nm"][0]), float(settings["range_nm"][1])),
        compute_sigma=False,
    )
    return seen.spectrum(name=spectrum.name)


def comparison_grid(
    spectrum: Spectrum, range_nm: tuple[float, float] = (400.0, 700.0), step_nm: float = 5.0
) -> WavelengthGrid:
    """The ``step_nm`` grid over ``range_nm`` whose nodes' hats lie inside the spectrum's range.

    A node ``λ`` of the hat-function projection averages ``[λ − step, λ + step]``; keeping every
    such interval inside the measured range makes a measured spectrum and a reference comparable
    at every node (no half-covered ends).
    """
    lo = math.ceil(max(range_nm[0], spectrum.range_nm[0] + step_nm) / step_nm - 1e-9) * step_nm
    hi = math.floor(min(range_nm[1], spectrum.range_nm[1] - step_nm) / step_nm + 1e-9) * step_nm
    if hi - lo < 2 * step_nm:
        raise InputError(
            f"{spectrum.name} covers {spectrum.range_nm[0]:g}–{spectrum.range_nm[1]:g} nm, too "
            f"little of {range_nm[0]:g}–{range_nm[1]:g} nm to compare",
            source=spectrum.name,
        )
    return WavelengthGrid(lo, hi, step_nm)


def spd_rms_error(
    estimated: Spectrum,
    truth: Spectrum,
    *,
    range_nm: tuple[float, float] = (400.0, 700.0),
    step_nm: float = 5.0,
) -> float:
    """RMS difference of two SPDs' shapes, as a fraction of the true maximum.

    Both are projected (hat functions, fair to line spectra) onto the ``step_nm`` grid over
    ``range_nm`` ∩ the estimate's range (:func:`comparison_grid`) — a spectrometer is judged where
    it measures. The truth
    is divided by its maximum there and the estimate scaled by the least-squares factor onto it,
    so only the shape counts.
    """
    grid = comparison_grid(estimated, range_nm, step_nm)
    estimate = estimated.resample(grid, "integrate").values
    reference = truth.resample(grid, "integrate", out_of_range="zero").values
    reference = reference / float(reference.max())
    denominator = float(estimate @ estimate)
    if denominator <= 0:
        raise InputError("the estimated SPD is zero on the grid", source=estimated.name)
    scale = float(estimate @ reference) / denominator
    return float(np.sqrt(np.mean((scale * estimate - reference) ** 2)))
