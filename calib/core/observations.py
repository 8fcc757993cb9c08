"""What the estimators consume: per-lamp direct and diffracted measurements plus the lamp spectrum.

These are produced either by :mod:`calib.image.profiles` (from RAW images), by :mod:`calib.model.forward` (rendered
synthetic data), or read from a user's 1-D profile CSV. Every estimator in :mod:`calib` takes a
sequence of :class:`LampObservation`.

Units: ``direct_rgb`` and ``profile`` must be in the same linear units (e.g. HDR-merged DN per second)
so that their ratio is meaningful across lamps; each lamp's overall brightness is free (it cancels).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.lamp_kinds import LAMP_KINDS as LAMP_KINDS  # re-exported
from calib.core.lamp_kinds import LampKind as LampKind
from calib.core.spectra import MultiSpectrum, Spectrum

#: ``LampObservation.metadata[CHANNEL_GAINS_KEY] == "unknown"``: the profile's relative channel gains
#: are not the raw data's (a demosaicked, white-balanced conversion such as the Canon 10D's FITS
#: planes), so the channel balance cannot come from the data.
CHANNEL_GAINS_KEY = "channel_gains"


def _readonly_float(value: ArrayLike, shape_hint: str, name: str, ndim: int) -> FloatArray:
    array = np.array(value, dtype=np.float64)
    if array.ndim != ndim:
        raise InputError(f"{shape_hint} expected, got shape {array.shape}", source=name)
    if not np.all(np.isfinite(array)):
        raise InputError(f"{shape_hint} contains NaN or infinite values", source=name)
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class OrderProfile:
    """The other first order's profile (−1), measured away from the direct spot on its side.

    Attributes
    ----------
    pixel
        Shape ``(n,)``: distance from the direct spot's centre along that order (sensor pixels,
        strictly increasing away from the spot).
    profile, profile_sigma
        Shape ``(n, 3)``: the band's mean radiance (R, G, B) and its standard deviation, in the
        units of the lamp's own profile.
    """

    pixel: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray

    def __post_init__(self) -> None:
        label = "the other first order"
        pixel = _readonly_float(self.pixel, "pixel coordinates (n,)", label, 1)
        profile = _readonly_float(self.profile, "profile (n, 3)", label, 2)
        sigma = _readonly_float(self.profile_sigma, "profile sigma (n, 3)", label, 2)
        if profile.shape != (pixel.size, 3) or sigma.shape != profile.shape:
            raise InputError(
                f"profile {profile.shape} and σ {sigma.shape} must both be ({pixel.size}, 3)",
                source=label,
            )
        if pixel.size > 1 and not np.all(np.diff(pixel) > 0):
            raise InputError("pixel coordinates must be strictly increasing", source=label)
        object.__setattr__(self, "pixel", pixel)
        object.__setattr__(self, "profile", profile)
        object.__setattr__(self, "profile_sigma", sigma)


@dataclass(frozen=True, eq=False)
class LampObservation:
    """One lamp seen through the grating: its spectrum, direct (0th-order) RGB and 1st-order profile.

    Parameters
    ----------
    name
        Lamp name (``"LED-B3"``, ``"fluorescent"``).
    spectrum
        The lamp's measured spectral power distribution, any grid covering the working range.
    pixel
        Shape ``(n_pixels,)``: coordinate of each profile sample along the dispersion direction, in
        pixels, increasing. All lamps captured in one geometry share the same coordinate frame, so a
        mapping found with one lamp applies to the others.
    profile
        Shape ``(n_pixels, 3)``: the first-order diffracted signal (R, G, B) at each pixel.
    direct_rgb
        Shape ``(3,)``: the direct (0th-order) signal, or ``None`` when not measured.
    profile_sigma, direct_sigma
        Standard deviations of the same shapes (noise model), or ``None`` when unknown.
    kind
        What kind of lamp it is; fluorescent lamps are used for the peak-based mapping.
    profile_wavelength_nm
        Shape ``(n_pixels,)`` when the profile is already mapped to wavelength, else ``None``.
    spectrum_bandwidth_nm
        Full width at half maximum of the spectrometer's slit function that measured ``spectrum``
        (PR-655 8 nm, CS-2000 5 nm …), or ``None`` when the spectrum is at least as sharp as the
        profile. A spectrum broader than what the camera resolves blurs every line of the model;
        the estimators then blur the profile to match (:mod:`calib.model.resolution`).
    line_spread
        The camera's line spread along the dispersion direction, sampled at the profile's pixel
        spacing (odd length, centred, sum 1) — the direct spot's cross-section: the slit's image
        and the lens' blur. ``None`` when unknown.
    pixel_origin
        ``"direct_spot"`` when ``pixel`` is the distance from the 0th-order spot along the first
        order (as :mod:`calib.image.profiles` measures it): the 0th order is where λ = 0, which pins the
        mapping's grating physics. ``"arbitrary"`` otherwise.
    other_order
        The other first order (−1) of the same frames, when it was in the frame too (profiles
        measured from the direct spot only): with the first order it measures the lens's focal
        length and the grating's tilt (:mod:`calib.wavelength.other_order`). ``None`` otherwise.
    """

    name: str
    spectrum: Spectrum
    pixel: FloatArray
    profile: FloatArray
    direct_rgb: FloatArray | None = None
    profile_sigma: FloatArray | None = None
    direct_sigma: FloatArray | None = None
    kind: LampKind = "other"
    profile_wavelength_nm: FloatArray | None = None
    metadata: dict[str, object] = field(default_factory=dict)
    spectrum_bandwidth_nm: float | None = None
    line_spread: FloatArray | None = None
    pixel_origin: Literal["arbitrary", "direct_spot"] = "arbitrary"
    other_order: OrderProfile | None = None

    def __post_init__(self) -> None:
        label = f"lamp {self.name!r}"
        pixel = _readonly_float(self.pixel, "pixel coordinates (n_pixels,)", label, 1)
        profile = _readonly_float(self.profile, "profile (n_pixels, 3)", label, 2)
        if profile.shape != (pixel.size, 3):
            raise InputError(
                f"profile has shape {profile.shape}, expected ({pixel.size}, 3) to match the "
                "pixel coordinates",
                source=label,
            )
        if pixel.size > 1 and not np.all(np.diff(pixel) > 0):
            raise InputError("pixel coordinates must be strictly increasing", source=label)
        object.__setattr__(self, "pixel", pixel)
        object.__setattr__(self, "profile", profile)
        if self.direct_rgb is not None:
            direct = _readonly_float(self.direct_rgb, "direct RGB (3,)", label, 1)
            if direct.shape != (3,):
                raise InputError(
                    f"direct RGB has shape {direct.shape}, expected (3,)", source=label
                )
            object.__setattr__(self, "direct_rgb", direct)
        if self.profile_sigma is not None:
            sigma = _readonly_float(self.profile_sigma, "profile sigma (n_pixels, 3)", label, 2)
            if sigma.shape != profile.shape:
                raise InputError(
                    f"profile sigma has shape {sigma.shape}, expected {profile.shape}", source=label
                )
            object.__setattr__(self, "profile_sigma", sigma)
        if self.direct_sigma is not None:
            dsigma = _readonly_float(self.direct_sigma, "direct sigma (3,)", label, 1)
            if dsigma.shape != (3,):
                raise InputError(
                    f"direct sigma has shape {dsigma.shape}, expected (3,)", source=label
                )
            object.__setattr__(self, "direct_sigma", dsigma)
        if self.profile_wavelength_nm is not None:
            mapped = _readonly_float(
                self.profile_wavelength_nm, "wavelengths (n_pixels,)", label, 1
            )
            if mapped.shape != pixel.shape:
                raise InputError(
                    f"profile wavelengths have shape {mapped.shape}, expected {pixel.shape}",
                    source=label,
                )
            object.__setattr__(self, "profile_wavelength_nm", mapped)
        if self.spectrum_bandwidth_nm is not None and not (
            np.isfinite(self.spectrum_bandwidth_nm) and self.spectrum_bandwidth_nm > 0
        ):
            raise InputError(
                f"spectrum bandwidth must be a positive number of nm, got "
                f"{self.spectrum_bandwidth_nm}",
                source=label,
            )
        if self.line_spread is not None:
            spread = _readonly_float(self.line_spread, "line spread (odd length,)", label, 1)
            if spread.size % 2 != 1 or np.any(spread < 0) or float(spread.sum()) <= 0:
                raise InputError(
                    "line spread must have an odd length and non-negative values", source=label
                )
            normalised = spread / float(spread.sum())
            normalised.flags.writeable = False
            object.__setattr__(self, "line_spread", normalised)
        if self.pixel_origin not in ("arbitrary", "direct_spot"):
            raise InputError(
                f"pixel_origin {self.pixel_origin!r} is not 'arbitrary' or 'direct_spot'",
                source=label,
            )
        if self.kind not in LAMP_KINDS:
            raise InputError(f"kind {self.kind!r} is not one of {LAMP_KINDS}", source=label)
        if self.other_order is not None and self.pixel_origin != "direct_spot":
            raise InputError(
                "the other first order needs a profile measured from the direct spot "
                "(pixel_origin 'direct_spot')",
                source=label,
            )

    @property
    def n_pixels(self) -> int:
        return int(self.pixel.size)


# ------------------------------------------------------------------------- colour-patch observations

ChartKind = Literal["reflective", "transmissive", "emissive"]
CHART_KINDS: tuple[ChartKind, ...] = ("reflective", "transmissive", "emissive")


@dataclass(frozen=True, eq=False)
class ChartObservation:
    """Colour patches of known spectra as the camera records them (the colour-chart methods' input).

    A patch ``j`` sends the camera the radiance ``e(λ) ρ_j(λ)``: the illuminant times the patch's
    reflectance (a ColorChecker), transmittance (filters in front of a lamp, Toivonen & Klami 2020
    §3.3) — or, with ``illuminant=None``, ``ρ_j`` is that radiance itself, measured patch by patch.

    Parameters
    ----------
    name
        What was photographed (``"ColorChecker under D65"``).
    patch_rgb
        Shape ``(n_patches, 3)``: linear camera R, G, B of each patch (e.g. the mean of a window of
        black-subtracted RAW samples), all in one unit and exposure.
    patch_spectra
        One column per patch (``n_patches`` channels, named after the patches): reflectance or
        transmittance factors, or radiances when ``illuminant`` is ``None``. Any wavelength axis
        covering the working grid.
    illuminant
        The light on (or through) the chart, or ``None`` (see ``patch_spectra``).
    patch_sigma
        Shape ``(n_patches, 3)``: standard deviation of each value in ``patch_rgb``, or ``None``.
    kind
        ``"reflective"``, ``"transmissive"`` or ``"emissive"`` (radiances given directly).
    metadata
        Free-form provenance (image file, patch centres, chart data source).
    """

    name: str
    patch_rgb: FloatArray
    patch_spectra: MultiSpectrum
    illuminant: Spectrum | None = None
    patch_sigma: FloatArray | None = None
    kind: ChartKind = "reflective"
    metadata: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        label = f"chart {self.name!r}"
        rgb = _readonly_float(self.patch_rgb, "patch RGB (n_patches, 3)", label, 2)
        n_patches = self.patch_spectra.values.shape[1]
        if rgb.shape != (n_patches, 3):
            raise InputError(
                f"patch RGB has shape {rgb.shape}, expected ({n_patches}, 3): one row per patch "
                f"spectrum ({n_patches} given)",
                source=label,
            )
        object.__setattr__(self, "patch_rgb", rgb)
        if self.patch_sigma is not None:
            sigma = _readonly_float(self.patch_sigma, "patch sigma (n_patches, 3)", label, 2)
            if sigma.shape != rgb.shape:
                raise InputError(
                    f"patch sigma has shape {sigma.shape}, expected {rgb.shape}", source=label
                )
            if np.any(sigma <= 0):
                raise InputError("patch sigma must be > 0 everywhere", source=label)
            object.__setattr__(self, "patch_sigma", sigma)
        if self.kind not in CHART_KINDS:
            raise InputError(f"kind {self.kind!r} is not one of {CHART_KINDS}", source=label)
        if self.illuminant is None and self.kind != "emissive":
            raise InputError(
                f"a {self.kind} chart needs the illuminant it was lit with (or kind='emissive' "
                "when the patch spectra are the measured radiances)",
                source=label,
            )

    @property
    def n_patches(self) -> int:
        return int(self.patch_rgb.shape[0])

    @property
    def patch_names(self) -> tuple[str, ...]:
        return self.patch_spectra.channels


@dataclass(frozen=True, eq=False)
class ColorMatrixObservation:
    """A camera's XYZ→camera colour matrices, as its DNG files carry them (ColorMatrix1/2).

    ``camera_rgb ∝ M_k · XYZ`` for a surface lit by calibration illuminant ``k``, each row of ``M_k``
    up to its own scale (the white balance the matrices leave open).

    Parameters
    ----------
    name
        The camera (DNG UniqueCameraModel, or Make + Model).
    matrices
        Shape ``(n_matrices, 3, 3)``: rows R, G, B; columns X, Y, Z. One or two matrices.
    illuminants
        The calibration illuminant of each matrix: a colour-science illuminant name (``"A"``,
        ``"D65"``) or a measured :class:`Spectrum`.
    source
        Where the matrices were read (file and tags, or ``"simulated"``).
    """

    name: str
    matrices: FloatArray
    illuminants: tuple[str | Spectrum, ...]
    source: str = ""

    def __post_init__(self) -> None:
        label = f"colour matrices of {self.name!r}"
        matrices = np.array(self.matrices, dtype=np.float64)
        if matrices.ndim == 2:
            matrices = matrices[None]
        if matrices.ndim != 3 or matrices.shape[1:] != (3, 3) or matrices.shape[0] < 1:
            raise InputError(
                f"expected one or more 3×3 matrices, got shape {np.shape(self.matrices)}",
                source=label,
            )
        if not np.all(np.isfinite(matrices)):
            raise InputError("matrices contain NaN or infinite values", source=label)
        if len(self.illuminants) != matrices.shape[0]:
            raise InputError(
                f"{matrices.shape[0]} matrices but {len(self.illuminants)} illuminants",
                source=label,
            )
        for index, matrix in enumerate(matrices):
            if np.linalg.matrix_rank(matrix) < 3:
                raise InputError(f"matrix {index + 1} is singular: {matrix.tolist()}", source=label)
        matrices.flags.writeable = False
        object.__setattr__(self, "matrices", matrices)
        object.__setattr__(self, "illuminants", tuple(self.illuminants))


#: Everything :func:`calib.methods.estimate` accepts; each method takes the kinds it needs.
Observation = LampObservation | ChartObservation | ColorMatrixObservation


def robust_noise_sigma(profile: FloatArray) -> FloatArray:
    """Per-channel noise σ ``(3,)`` of a profile ``(n, 3)`` from the MAD of its second differences."""
    second = np.diff(profile, n=2, axis=0)
    mad = np.median(np.abs(second - np.median(second, axis=0)), axis=0)
    # A second difference of white noise has variance 6σ²; MAD → σ for a Gaussian is ×1.4826.
    sigma = 1.4826 * mad / np.sqrt(6.0)
    floor = 1e-4 * np.max(np.abs(profile), axis=0) + 1e-300
    return np.asarray(np.maximum(sigma, floor), dtype=np.float64)


def profile_sigma(observation: LampObservation) -> FloatArray:
    """σ per pixel and channel ``(n, 3)``: the observation's own, else a robust estimate.

    The fallback is one σ for every pixel and channel (the largest channel's robust estimate): a
    profile without a noise model is weighted evenly rather than by estimates that, on clean data,
    measure the signal's own curvature.
    """
    if observation.profile_sigma is not None:
        if np.any(observation.profile_sigma <= 0):
            raise InputError(
                "profile sigma must be > 0 everywhere", source=f"lamp {observation.name!r}"
            )
        return np.asarray(observation.profile_sigma, dtype=np.float64)
    sigma = float(np.max(robust_noise_sigma(observation.profile)))
    return np.full(observation.profile.shape, sigma)
