"""A camera's R, G, B sensitivities as they travel between files: :class:`CameraCurves`.

The one type every camera file is read into and written from (CSV by column name, AMPAS/rawtoaces
JSON, dcamprof SSF JSON, vkdt text, ``result.json``; :mod:`calib.core.camera_files`), with the
per-sample standard deviation when known and which samples were measured (an estimate extended
beyond its measured range says where, :mod:`calib.model.extension`).

:func:`as_camera` is the adapter that lets any camera-like object stand where a camera is
expected: a :class:`CameraCurves`, a :class:`~calib.core.spectra.MultiSpectrum` with R, G, B
channels, or a colour-science ``RGB_CameraSensitivities`` / ``MultiSpectralDistributions`` (read
through its ``wavelengths``, ``values`` and ``labels``: colour itself is not imported here).

Channels are always in the order R, G, B. Files written by spectral-rig label them ``R``, ``G``,
``B`` (:data:`CHANNEL_LABELS`); readers accept ``r``/``red``/``R`` … by name.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import BoolArray, FloatArray
from calib.core.colour_data import rgb_camera_sensitivities
from calib.core.errors import InputError
from calib.core.spectra import CHANNEL_COLUMNS, MultiSpectrum, WavelengthGrid, column_key

#: How spectral-rig labels the channels in every file it writes.
CHANNEL_LABELS: tuple[str, str, str] = ("R", "G", "B")


def _frozen(array: Any, dtype: type = np.float64) -> Any:
    out: Any = np.array(array, dtype=dtype)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False, init=False)
class CameraCurves:
    """R, G, B sensitivities on one increasing wavelength axis.

    Parameters
    ----------
    wavelength_nm
        Shape ``(f,)``, strictly increasing, finite.
    values
        Shape ``(f, 3)``: R, G, B (any common scale; finite).
    sigma
        Shape ``(f, 3)`` standard deviation on the same scale (``NaN`` where unknown), or ``None``.
    measured
        Shape ``(f,)``: ``True`` where the values were measured or estimated, ``False`` where they
        extend the curves beyond that (default: all measured).
    name
        What the curves are (camera, file), used in messages.
    """

    wavelength_nm: FloatArray
    values: FloatArray
    sigma: FloatArray | None
    measured: BoolArray
    name: str

    def __init__(
        self,
        wavelength_nm: ArrayLike,
        values: ArrayLike,
        sigma: ArrayLike | None = None,
        measured: ArrayLike | None = None,
        name: str = "camera",
    ) -> None:
        axis = np.asarray(wavelength_nm, dtype=np.float64)
        curves = np.asarray(values, dtype=np.float64)
        if axis.ndim != 1 or axis.size < 2:
            raise InputError(f"need at least 2 wavelengths, got shape {axis.shape}", source=name)
        if not np.all(np.isfinite(axis)) or not np.all(np.diff(axis) > 0):
            raise InputError("wavelengths must be finite and strictly increasing", source=name)
        if curves.shape != (axis.size, 3):
            raise InputError(
                f"values have shape {curves.shape}, expected ({axis.size}, 3) for R, G, B",
                source=name,
            )
        if not np.all(np.isfinite(curves)):
            raise InputError("sensitivities contain NaN or infinite values", source=name)
        if sigma is not None:
            sigma = np.asarray(sigma, dtype=np.float64)
            if sigma.shape != curves.shape:
                raise InputError(
                    f"sigma has shape {sigma.shape}, expected {curves.shape}", source=name
                )
            if np.any(sigma < 0):
                raise InputError("sigma must be >= 0 (NaN where unknown)", source=name)
        mask = np.ones(axis.size, dtype=bool) if measured is None else np.asarray(measured, bool)
        if mask.shape != axis.shape:
            raise InputError(f"measured has shape {mask.shape}, expected {axis.shape}", source=name)
        object.__setattr__(self, "wavelength_nm", _frozen(axis))
        object.__setattr__(self, "values", _frozen(curves))
        object.__setattr__(self, "sigma", None if sigma is None else _frozen(sigma))
        object.__setattr__(self, "measured", _frozen(mask, bool))
        object.__setattr__(self, "name", name)

    @property
    def range_nm(self) -> tuple[float, float]:
        return float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])

    @property
    def measured_range_nm(self) -> tuple[float, float] | None:
        """First and last measured wavelength (``None`` when nothing is)."""
        inside = self.wavelength_nm[self.measured]
        return (float(inside[0]), float(inside[-1])) if inside.size else None

    def is_on(self, grid: WavelengthGrid) -> bool:
        """Whether the wavelengths are exactly ``grid``'s."""
        return self.wavelength_nm.size == grid.size and bool(
            np.allclose(self.wavelength_nm, grid.wavelength_nm, rtol=0, atol=1e-9)
        )

    def normalised(self) -> CameraCurves:
        """Divided by the maximum over all channels (σ too): the paper's convention."""
        peak = float(np.max(self.values))
        if peak <= 0:
            raise InputError("the sensitivities are zero everywhere", source=self.name)
        return CameraCurves(
            self.wavelength_nm,
            self.values / peak,
            None if self.sigma is None else self.sigma / peak,
            self.measured,
            self.name,
        )

    def clipped(self) -> tuple[CameraCurves, int]:
        """Negative values set to zero, and how many there were (σ kept: it covers the change)."""
        negative = int(np.count_nonzero(self.values < 0))
        if not negative:
            return self, 0
        return (
            CameraCurves(
                self.wavelength_nm,
                np.clip(self.values, 0.0, None),
                self.sigma,
                self.measured,
                self.name,
            ),
            negative,
        )

    def at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """Linear interpolation at ``wavelength_nm`` ``(n,)`` → ``(n, 3)`` (zero outside)."""
        points = np.asarray(wavelength_nm, dtype=np.float64)
        return np.stack(
            [
                np.interp(points, self.wavelength_nm, self.values[:, k], left=0.0, right=0.0)
                for k in range(3)
            ],
            axis=1,
        )

    def to_multispectrum(self) -> MultiSpectrum:
        """As a :class:`MultiSpectrum` with channels ``r, g, b`` (negative values set to zero)."""
        return MultiSpectrum(
            self.wavelength_nm, self.values, ("r", "g", "b"), name=self.name, negative="clip"
        )

    def to_colour(self) -> Any:
        """A colour-science ``RGB_CameraSensitivities`` (σ dropped; colour labels the channels
        ``red, green, blue`` whatever it is given)."""

        return rgb_camera_sensitivities(self.wavelength_nm, self.values, self.name)


def channel_order(labels: Sequence[str], source: str) -> list[int]:
    """Positions of R, G, B in ``labels`` (matched by name), or an error naming the labels."""
    keys = [column_key(str(label)) for label in labels]
    order: list[int] = []
    for names in CHANNEL_COLUMNS:
        found = [index for index, key in enumerate(keys) if key in names]
        if len(found) != 1:
            raise InputError(
                f"channels {tuple(labels)} do not name R, G and B once each (expected "
                "r/red, g/green, b/blue)",
                source=source,
            )
        order.append(found[0])
    return order


def as_camera(camera: Any, name: str | None = None) -> CameraCurves:
    """Any camera-like object as :class:`CameraCurves` (R, G, B by channel name).

    Accepts :class:`CameraCurves`, a :class:`~calib.core.spectra.MultiSpectrum` whose channels name
    R, G, B, and colour-science ``MultiSpectralDistributions``/``RGB_CameraSensitivities`` (its
    ``labels`` must name R, G, B: ``red, green, blue`` as colour's cameras do).

    Raises
    ------
    InputError
        Not a camera, or channels that do not name R, G and B.

    Examples
    --------
    >>> spectra = MultiSpectrum([400, 500, 600], [[0, 1, 2], [1, 2, 0], [2, 0, 1]],
    ...                         channels=("blue", "green", "red"))
    >>> as_camera(spectra).values[:, 0]  # R is the file's third column
    array([2., 0., 1.])
    """
    if isinstance(camera, CameraCurves):
        return camera
    if isinstance(camera, MultiSpectrum):
        order = channel_order(camera.channels, name or camera.name)
        return CameraCurves(camera.wavelength_nm, camera.values[:, order], name=name or camera.name)
    wavelengths = getattr(camera, "wavelengths", None)
    labels = getattr(camera, "labels", None)
    if wavelengths is None or labels is None:
        raise InputError(
            f"{type(camera).__name__} is not a camera: expected CameraCurves, a MultiSpectrum or "
            "colour's RGB_CameraSensitivities / MultiSpectralDistributions",
            source=name or "camera",
        )
    label = name or str(getattr(camera, "name", "camera"))
    values = np.asarray(camera.values, dtype=np.float64)
    order = channel_order([str(item) for item in labels], label)
    return CameraCurves(np.asarray(wavelengths, dtype=np.float64), values[:, order], name=label)
