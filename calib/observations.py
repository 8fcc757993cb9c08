"""What the estimators consume: per-lamp direct and diffracted measurements plus the lamp spectrum.

These are produced either by :mod:`calib.profiles` (from RAW images), by :mod:`calib.forward` (rendered
synthetic data), or read from a user's 1-D profile CSV. Every estimator in :mod:`calib` takes a
sequence of :class:`LampObservation`.

Units: ``direct_rgb`` and ``profile`` must be in the same linear units (e.g. HDR-merged DN per second)
so that their ratio is meaningful across lamps; each lamp's overall brightness is free (it cancels).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.errors import InputError
from calib.spectra import Spectrum

FloatArray = NDArray[np.float64]
LampKind = Literal["led", "fluorescent", "halogen", "narrowband", "other"]
LAMP_KINDS: tuple[LampKind, ...] = ("led", "fluorescent", "halogen", "narrowband", "other")


def _readonly_float(value: ArrayLike, shape_hint: str, name: str, ndim: int) -> FloatArray:
    array = np.array(value, dtype=np.float64)
    if array.ndim != ndim:
        raise InputError(f"{shape_hint} expected, got shape {array.shape}", source=name)
    if not np.all(np.isfinite(array)):
        raise InputError(f"{shape_hint} contains NaN or infinite values", source=name)
    array.flags.writeable = False
    return array


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
        if self.kind not in LAMP_KINDS:
            raise InputError(f"kind {self.kind!r} is not one of {LAMP_KINDS}", source=label)

    @property
    def n_pixels(self) -> int:
        return int(self.pixel.size)
