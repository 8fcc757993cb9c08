"""Spectra: a small immutable spectrum type, working grids, resampling and CSV input/output.

A :class:`Spectrum` is one curve (a lamp's spectral power distribution, a grating efficiency); a
:class:`MultiSpectrum` is several curves on one wavelength axis (a camera's R, G, B sensitivities).
Both validate on construction: wavelengths strictly monotonic and finite, values finite and
non-negative. Arrays are copied and made read-only.

Resampling to a :class:`WavelengthGrid` has two meanings, and the caller chooses:

``"interpolate"``
    point samples of a smooth curve (sensitivities, efficiencies): linear interpolation.
``"integrate"``
    the projection of a possibly spiky spectrum onto the grid's linear "hat" functions: node ``i``
    receives ``∫ e(λ) φ_i(λ) dλ / ∫ φ_i(λ) dλ`` where ``φ_i`` is the triangle of half-width one grid
    step centred on node ``i``. If a sensitivity ``s`` is linear between grid nodes, then
    ``Σ_i e_i s_i · step = ∫ e s dλ`` exactly, which is why lamp spectra are integrated rather than
    point-sampled before they enter the image formation sums. Computed exactly (Simpson's rule on
    each piece of the piecewise-quadratic product).

References
----------
Makabe, L., Santo, H., Okura, F., Brown, M. S., Matsushita, Y. (2025). Spectral Sensitivity
Estimation with an Uncalibrated Diffraction Grating. (Working grid 400–700 nm at 10 nm, f = 31.)
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import SpectrumError

ResampleMethod = Literal["interpolate", "integrate"]
OutOfRange = Literal["error", "zero"]
NegativePolicy = Literal["error", "clip"]

#: Wavelengths outside this interval are taken as a sign that the column is not in nanometres.
PLAUSIBLE_WAVELENGTH_NM = (100.0, 3000.0)

_COVERAGE_TOLERANCE_NM = 1e-6


def _readonly(array: FloatArray) -> FloatArray:
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class WavelengthGrid:
    """A uniform wavelength grid ``start_nm, start_nm + step_nm, …, stop_nm`` (both ends included).

    Examples
    --------
    >>> WavelengthGrid.parse("400:700:10").size
    31
    """

    start_nm: float = 400.0
    stop_nm: float = 700.0
    step_nm: float = 10.0

    def __post_init__(self) -> None:
        values = (self.start_nm, self.stop_nm, self.step_nm)
        if not all(math.isfinite(v) for v in values):
            raise SpectrumError(f"grid values must be finite numbers, got {values}", source="grid")
        if self.step_nm <= 0:
            raise SpectrumError(f"step must be > 0 nm, got {self.step_nm}", source="grid")
        if self.stop_nm <= self.start_nm:
            raise SpectrumError(
                f"stop ({self.stop_nm} nm) must be greater than start ({self.start_nm} nm)",
                source="grid",
            )
        n_steps = (self.stop_nm - self.start_nm) / self.step_nm
        if not math.isfinite(n_steps):
            raise SpectrumError(
                f"{self.start_nm:g}:{self.stop_nm:g}:{self.step_nm:g} nm has no countable number "
                "of steps",
                source="grid",
            )
        if abs(n_steps - round(n_steps)) > 1e-6:
            raise SpectrumError(
                f"{self.stop_nm} - {self.start_nm} nm is not a whole number of {self.step_nm} nm steps",
                source="grid",
            )

    @classmethod
    def parse(cls, text: str) -> WavelengthGrid:
        """Parse ``"START:STOP:STEP"`` in nanometres, e.g. ``"400:700:10"``."""
        parts = text.strip().split(":")
        if len(parts) != 3:
            raise SpectrumError(
                f"expected START:STOP:STEP in nm (e.g. 400:700:10), got {text!r}", source="grid"
            )
        try:
            start, stop, step = (float(p) for p in parts)
        except ValueError:
            raise SpectrumError(
                f"expected three numbers START:STOP:STEP (e.g. 400:700:10), got {text!r}",
                source="grid",
            ) from None
        n_steps = (stop - start) / step if step > 0 else 0.0
        if math.isfinite(n_steps) and n_steps + 1 > MAX_GRID_SIZE:
            raise SpectrumError(
                f"{text.strip()} has {n_steps + 1:,.0f} wavelengths; at most {MAX_GRID_SIZE} "
                "(a camera's sensitivity is smooth: 5 or 10 nm steps suffice, e.g. 400:700:10)",
                source="grid",
            )
        return cls(start, stop, step)

    @property
    def size(self) -> int:
        """Number of wavelengths ``f``."""
        return round((self.stop_nm - self.start_nm) / self.step_nm) + 1

    @property
    def wavelength_nm(self) -> FloatArray:
        """The wavelengths, shape ``(f,)``."""
        return _readonly(self.start_nm + self.step_nm * np.arange(self.size, dtype=np.float64))

    def __str__(self) -> str:
        return f"{self.start_nm:g}:{self.stop_nm:g}:{self.step_nm:g}"


DEFAULT_GRID = WavelengthGrid(400.0, 700.0, 10.0)
MAX_GRID_SIZE = 1001
"""Most wavelengths a grid given as input may have (:meth:`WavelengthGrid.parse`): the solve grows
as its cube (0.1 nm steps over 400–700 nm ran for minutes, 0.01 nm ran out of memory)."""


def _validate_axis(wavelength_nm: ArrayLike, name: str) -> tuple[FloatArray, bool]:
    """Return the axis as increasing float64 and whether it had to be reversed."""
    axis = np.array(wavelength_nm, dtype=np.float64)
    if axis.ndim != 1:
        raise SpectrumError(f"wavelengths must be 1-D, got shape {axis.shape}", source=name)
    if axis.size < 2:
        raise SpectrumError(f"need at least 2 wavelengths, got {axis.size}", source=name)
    if not np.all(np.isfinite(axis)):
        index = int(np.flatnonzero(~np.isfinite(axis))[0])
        raise SpectrumError(f"wavelength #{index} is {axis[index]} (not finite)", source=name)
    steps = np.diff(axis)
    reversed_axis = bool(np.all(steps < 0))
    if reversed_axis:
        axis = axis[::-1].copy()
        steps = -steps[::-1]
    if not np.all(steps > 0):
        index = int(np.flatnonzero(steps <= 0)[0])
        raise SpectrumError(
            f"wavelengths are not strictly monotonic: {axis[index]:g} nm is followed by "
            f"{axis[index + 1]:g} nm; sort the rows and remove duplicates",
            source=name,
        )
    low, high = PLAUSIBLE_WAVELENGTH_NM
    if axis[0] < low or axis[-1] > high:
        raise SpectrumError(
            f"wavelengths run from {axis[0]:g} to {axis[-1]:g}, outside {low:g}–{high:g} nm: "
            "is the first column in nanometres?",
            source=name,
        )
    return axis, reversed_axis


def _validate_values(
    values: FloatArray, name: str, negative: NegativePolicy, wavelength_nm: FloatArray
) -> FloatArray:
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise SpectrumError(
            f"value at {wavelength_nm[row]:g} nm is {values.flat[np.flatnonzero(bad)[0]]} "
            "(NaN or infinite); fill or remove that row",
            source=name,
        )
    if (values < 0).any():
        if negative == "clip":
            return np.clip(values, 0.0, None)
        row = int(np.argwhere(values < 0)[0][0])
        raise SpectrumError(
            f"negative value {values.flat[np.flatnonzero(values < 0)[0]]:g} at "
            f"{wavelength_nm[row]:g} nm; spectra must be >= 0 (subtract the dark level properly, "
            "or read with negative='clip' to zero small negative noise)",
            source=name,
        )
    return values


@lru_cache(maxsize=64)
def _hat_projection(source_nm: bytes, grid: WavelengthGrid, out_of_range: OutOfRange) -> FloatArray:
    """Matrix ``(f, n_source)`` mapping source samples to hat-function projections on ``grid``."""
    source = np.frombuffer(source_nm, dtype=np.float64)
    nodes = grid.wavelength_nm
    step = grid.step_nm
    lo, hi = nodes[0] - step, nodes[-1] + step
    breaks = np.union1d(source, np.concatenate([nodes, [lo, hi]]))
    if out_of_range == "error":
        breaks = breaks[(breaks >= max(lo, source[0])) & (breaks <= min(hi, source[-1]))]
    else:
        breaks = breaks[(breaks >= lo) & (breaks <= hi)]
    mids = 0.5 * (breaks[:-1] + breaks[1:])
    points = np.concatenate([breaks, mids])
    widths = np.diff(breaks)
    # Simpson weights: h/6 at both ends of a segment, 4h/6 at its midpoint.
    weights = np.zeros(points.size)
    np.add.at(weights, np.arange(breaks.size - 1), widths / 6)
    np.add.at(weights, np.arange(1, breaks.size), widths / 6)
    weights[breaks.size :] = 4 * widths / 6
    # Linear interpolation of the source (zero outside it) as a matrix acting on sample values.
    interp = np.zeros((points.size, source.size))
    inside = (points >= source[0]) & (points <= source[-1])
    idx = np.clip(np.searchsorted(source, points[inside], side="right") - 1, 0, source.size - 2)
    frac = (points[inside] - source[idx]) / (source[idx + 1] - source[idx])
    rows = np.flatnonzero(inside)
    interp[rows, idx] = 1 - frac
    interp[rows, idx + 1] += frac
    hats = np.clip(1 - np.abs(points[None, :] - nodes[:, None]) / step, 0.0, None)
    covered = hats * (inside if out_of_range == "error" else np.ones_like(inside))[None, :]
    norm = (covered * weights).sum(axis=1, keepdims=True)
    return _readonly(((hats * weights) @ interp) / norm)


def _check_coverage(
    axis: FloatArray, grid: WavelengthGrid, out_of_range: OutOfRange, name: str
) -> None:
    if out_of_range == "zero":
        return
    if (
        axis[0] > grid.start_nm + _COVERAGE_TOLERANCE_NM
        or axis[-1] < grid.stop_nm - _COVERAGE_TOLERANCE_NM
    ):
        raise SpectrumError(
            f"spectrum covers {axis[0]:g}–{axis[-1]:g} nm but the grid needs "
            f"{grid.start_nm:g}–{grid.stop_nm:g} nm; measure a wider range or choose a narrower "
            "grid (--grid)",
            source=name,
        )


def _resample_columns(
    axis: FloatArray,
    values: FloatArray,
    grid: WavelengthGrid,
    method: ResampleMethod,
    out_of_range: OutOfRange,
    name: str,
) -> FloatArray:
    """Resample ``values`` of shape ``(n, k)`` on ``axis`` to ``(f, k)`` on ``grid``."""
    _check_coverage(axis, grid, out_of_range, name)
    nodes = grid.wavelength_nm
    if method == "interpolate":
        columns = [
            np.interp(nodes, axis, values[:, k], left=0.0, right=0.0)
            for k in range(values.shape[1])
        ]
        return np.stack(columns, axis=1)
    if method == "integrate":
        matrix = _hat_projection(axis.tobytes(), grid, out_of_range)
        return matrix @ values
    raise SpectrumError(f"unknown resampling method {method!r}; use 'interpolate' or 'integrate'")


@dataclass(frozen=True, eq=False, init=False)
class Spectrum:
    """One spectral curve.

    Parameters
    ----------
    wavelength_nm
        Shape ``(n,)``, strictly monotonic (a decreasing axis is reversed), in nanometres.
    values
        Shape ``(n,)``, finite and >= 0 (see ``negative``).
    name
        What the curve is (lamp name, file name); used in error messages.
    negative
        ``"error"`` (default) rejects negative values, ``"clip"`` sets them to zero.

    Examples
    --------
    >>> s = Spectrum([400, 500, 600, 700], [1.0, 2.0, 2.0, 1.0], name="lamp")
    >>> s.resample(WavelengthGrid(400, 700, 50)).values
    array([1. , 1.5, 2. , 2. , 2. , 1.5, 1. ])
    """

    wavelength_nm: FloatArray
    values: FloatArray
    name: str = "spectrum"

    def __init__(
        self,
        wavelength_nm: ArrayLike,
        values: ArrayLike,
        name: str = "spectrum",
        negative: NegativePolicy = "error",
    ) -> None:
        object.__setattr__(self, "name", name)
        axis, reversed_axis = _validate_axis(wavelength_nm, self.name)
        values = np.array(values, dtype=np.float64)
        if values.shape != (axis.size,):
            raise SpectrumError(
                f"values have shape {values.shape}, expected ({axis.size},) to match the wavelengths",
                source=self.name,
            )
        if reversed_axis:
            values = values[::-1].copy()
        values = _validate_values(values, self.name, negative, axis)
        object.__setattr__(self, "wavelength_nm", _readonly(axis))
        object.__setattr__(self, "values", _readonly(values))

    @classmethod
    def from_colour(cls, sd: object, name: str | None = None) -> Spectrum:
        """Build from a ``colour.SpectralDistribution``."""
        wavelengths = np.asarray(sd.wavelengths, dtype=np.float64)  # type: ignore[attr-defined]
        values = np.asarray(sd.values, dtype=np.float64)  # type: ignore[attr-defined]
        return cls(wavelengths, values, name=name or str(sd.name))  # type: ignore[attr-defined]

    @property
    def range_nm(self) -> tuple[float, float]:
        return float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])

    def covers(self, grid: WavelengthGrid) -> bool:
        """Whether the spectrum spans the whole grid."""
        lo, hi = self.range_nm
        return (
            lo <= grid.start_nm + _COVERAGE_TOLERANCE_NM
            and hi >= grid.stop_nm - _COVERAGE_TOLERANCE_NM
        )

    def resample(
        self,
        grid: WavelengthGrid = DEFAULT_GRID,
        method: ResampleMethod = "interpolate",
        out_of_range: OutOfRange = "error",
    ) -> Spectrum:
        """This spectrum on ``grid`` (see the module docstring for the two methods).

        ``out_of_range="error"`` raises :class:`SpectrumError` when the spectrum does not cover
        the grid; ``"zero"`` treats it as zero outside its range.
        """
        values = _resample_columns(
            self.wavelength_nm, self.values[:, None], grid, method, out_of_range, self.name
        )
        return Spectrum(grid.wavelength_nm, values[:, 0], name=self.name, negative="clip")

    def scaled(self, factor: float) -> Spectrum:
        return Spectrum(self.wavelength_nm, self.values * factor, name=self.name)

    def normalised(self, how: Literal["max", "sum", "l2"] = "max") -> Spectrum:
        """Divided by its maximum, sum or Euclidean norm."""
        if how == "max":
            norm = float(np.max(self.values))
        elif how == "sum":
            norm = float(np.sum(self.values))
        else:
            norm = float(np.linalg.norm(self.values))
        if norm <= 0:
            raise SpectrumError("cannot normalise an all-zero spectrum", source=self.name)
        return self.scaled(1.0 / norm)

    def at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """Linear interpolation at arbitrary wavelengths (zero outside the range)."""
        return np.interp(
            np.asarray(wavelength_nm, dtype=np.float64), self.wavelength_nm, self.values, 0.0, 0.0
        )


def as_spectrum(spectrum: object, name: str | None = None) -> Spectrum:
    """Any spectrum-like object as a :class:`Spectrum`: a :class:`Spectrum`, or a colour-science
    ``SpectralDistribution`` (read through its ``wavelengths`` and ``values``; colour itself is
    not imported).

    Raises
    ------
    SpectrumError
        Not a spectrum (names what was given), or invalid values.
    """
    if isinstance(spectrum, Spectrum):
        return spectrum
    values = getattr(spectrum, "values", None)
    if getattr(spectrum, "wavelengths", None) is None or values is None or np.ndim(values) != 1:
        raise SpectrumError(
            f"{type(spectrum).__name__} is not a spectrum: expected a Spectrum or colour's "
            "SpectralDistribution",
            source=name or "spectrum",
        )
    return Spectrum.from_colour(spectrum, name=name)


@dataclass(frozen=True, eq=False, init=False)
class MultiSpectrum:
    """Several curves on one wavelength axis, e.g. a camera's R, G, B sensitivities.

    Parameters
    ----------
    wavelength_nm
        Shape ``(n,)``.
    values
        Shape ``(n, k)`` with one column per channel.
    channels
        ``k`` channel names, e.g. ``("r", "g", "b")``.
    """

    wavelength_nm: FloatArray
    values: FloatArray
    channels: tuple[str, ...] = ("r", "g", "b")
    name: str = "spectra"

    def __init__(
        self,
        wavelength_nm: ArrayLike,
        values: ArrayLike,
        channels: Sequence[str] = ("r", "g", "b"),
        name: str = "spectra",
        negative: NegativePolicy = "error",
    ) -> None:
        object.__setattr__(self, "name", name)
        object.__setattr__(self, "channels", tuple(channels))
        axis, reversed_axis = _validate_axis(wavelength_nm, self.name)
        values = np.array(values, dtype=np.float64)
        if values.ndim != 2 or values.shape[0] != axis.size:
            raise SpectrumError(
                f"values have shape {values.shape}, expected ({axis.size}, n_channels)",
                source=self.name,
            )
        if values.shape[1] != len(self.channels):
            raise SpectrumError(
                f"{values.shape[1]} value columns but {len(self.channels)} channel names "
                f"{self.channels}",
                source=self.name,
            )
        if reversed_axis:
            values = values[::-1].copy()
        values = _validate_values(values, self.name, negative, axis)
        object.__setattr__(self, "wavelength_nm", _readonly(axis))
        object.__setattr__(self, "values", _readonly(values))

    @classmethod
    def from_colour(cls, msds: object, name: str | None = None) -> MultiSpectrum:
        """Build from a ``colour.MultiSpectralDistributions`` (channel names lower-cased)."""
        wavelengths = np.asarray(msds.wavelengths, dtype=np.float64)  # type: ignore[attr-defined]
        values = np.asarray(msds.values, dtype=np.float64)  # type: ignore[attr-defined]
        labels = tuple(str(label).lower() for label in msds.labels)  # type: ignore[attr-defined]
        return cls(wavelengths, values, channels=labels, name=name or str(msds.name))  # type: ignore[attr-defined]

    @property
    def range_nm(self) -> tuple[float, float]:
        return float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])

    def channel(self, name: str) -> Spectrum:
        """One channel as a :class:`Spectrum`."""
        try:
            index = self.channels.index(name)
        except ValueError:
            raise SpectrumError(
                f"no channel {name!r}; channels are {self.channels}", source=self.name
            ) from None
        return Spectrum(self.wavelength_nm, self.values[:, index], name=f"{self.name}[{name}]")

    def resample(
        self,
        grid: WavelengthGrid = DEFAULT_GRID,
        method: ResampleMethod = "interpolate",
        out_of_range: OutOfRange = "error",
    ) -> MultiSpectrum:
        """All channels on ``grid`` (see :meth:`Spectrum.resample`)."""
        values = _resample_columns(
            self.wavelength_nm, self.values, grid, method, out_of_range, self.name
        )
        return MultiSpectrum(grid.wavelength_nm, values, self.channels, self.name, negative="clip")

    def scaled(self, factor: float) -> MultiSpectrum:
        return MultiSpectrum(self.wavelength_nm, self.values * factor, self.channels, self.name)

    def normalised(self) -> MultiSpectrum:
        """Divided by the maximum over all channels (the paper's convention for sensitivities)."""
        peak = float(np.max(self.values))
        if peak <= 0:
            raise SpectrumError("cannot normalise all-zero curves", source=self.name)
        return self.scaled(1.0 / peak)


# --------------------------------------------------------------------------------------------- CSV

_NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return [part.strip() for part in line.split(delimiter)]


def _strip_trailing_empty(fields: list[str], delimiter: str | None) -> list[str]:
    """Drop the empty field a trailing delimiter leaves (``400,1.0,``)."""
    if delimiter is not None and len(fields) > 1 and fields[-1] == "":
        return fields[:-1]
    return fields


def _guess_delimiter(line: str) -> str | None:
    for candidate in ("\t", ";", ","):
        if candidate in line:
            return candidate
    return None


def _to_float(text: str, delimiter: str | None, where: str) -> float:
    cleaned = text.strip().strip('"').strip("'")
    if delimiter != "," and _NUMBER.match(cleaned):
        cleaned = cleaned.replace(",", ".")  # decimal comma, as written by some European locales
    try:
        return float(cleaned)
    except ValueError:
        raise SpectrumError(f"{cleaned!r} is not a number", source=where) from None


#: A wavelength column's name only when no :data:`WAVELENGTH_COLUMNS` name is there.
FALLBACK_WAVELENGTH_COLUMNS: tuple[str, ...] = ("w",)
#: Header names that mean the wavelength column (compared after :func:`column_key`).
WAVELENGTH_COLUMNS: tuple[str, ...] = (
    "wavelength_nm",
    "wavelength",
    "wavelengths",
    "wl",
    "wl_nm",
    "nm",
    "lambda",
    "lambda_nm",
    "λ",
    "λ_nm",
)
#: Header names of each camera channel, in the order R, G, B.
CHANNEL_COLUMNS: tuple[tuple[str, ...], ...] = (("r", "red"), ("g", "green"), ("b", "blue"))
#: How a channel's standard-deviation column is named (``{channel}`` is any of its names).
SIGMA_COLUMN_PATTERNS: tuple[str, ...] = (
    "{channel}_sigma",
    "sigma_{channel}",
    "{channel}_σ",
    "σ_{channel}",
    "{channel}_std",
)

_UNIT_SUFFIX = re.compile(r"\s*[\(\[]\s*(nm|nanometres?|nanometers?)\s*[\)\]]\s*$")


def column_key(header: str) -> str:
    """A header cell as compared with the known names: lower case, a trailing ``(nm)``/``[nm]`` unit
    removed, spaces and hyphens as ``_`` (``"Wavelength (nm)"`` → ``"wavelength"``)."""
    key = header.strip().strip('"').strip("'").lower()
    key = _UNIT_SUFFIX.sub("", key)
    return re.sub(r"[\s\-]+", "_", key.strip())


def sigma_column_names(channel: int) -> tuple[str, ...]:
    """Every header name of channel ``channel``'s (0 = R) standard-deviation column."""
    return tuple(
        pattern.format(channel=name)
        for name in CHANNEL_COLUMNS[channel]
        for pattern in SIGMA_COLUMN_PATTERNS
    )


MAX_TABLE_BYTES = 32 * 1024 * 1024
"""Largest CSV file read as a spectrum or profile (a spectrometer's 0.1 nm export is < 1 MiB)."""
MAX_TABLE_ROWS = 200_000
"""Most data rows read from one CSV file."""
VALUE_MAGNITUDE_RANGE = (1e-30, 1e30)
"""Where the largest magnitude of a table's value columns must lie (when not all zero): beyond it
the arithmetic of resampling and solving overflows or underflows, and no measurement lies there."""


@dataclass(frozen=True)
class CsvTable:
    """A numeric table read from a CSV file: a header (possibly synthesised) and rows.

    Columns are found by name (:meth:`find`, :meth:`wavelength_index`, :meth:`rgb_indices`); a
    table without a header line has the wavelength in its first column and nothing else known.
    """

    columns: tuple[str, ...]
    rows: FloatArray
    path: Path
    had_header: bool

    def find(self, names: Sequence[str], what: str) -> int | None:
        """The one column whose name is in ``names``; ``None`` when none is.

        Raises
        ------
        SpectrumError
            When two columns both name ``what`` (an ambiguous table).
        """
        keys = [column_key(column) for column in self.columns]
        wanted = {column_key(name) for name in names}
        found = [index for index, key in enumerate(keys) if key in wanted]
        if len(found) > 1:
            clash = " and ".join(repr(self.columns[i]) for i in found)
            raise SpectrumError(
                f"columns {clash} both name the {what}; the table is ambiguous (columns "
                f"{', '.join(self.columns)})",
                source=str(self.path),
            )
        return found[0] if found else None

    def wavelength_index(self) -> int:
        """The wavelength column: by name (:data:`WAVELENGTH_COLUMNS`), the first without a header.

        Raises
        ------
        SpectrumError
            A header that names no wavelength column, or two.
        """
        if not self.had_header:
            return 0
        index = self.find(WAVELENGTH_COLUMNS, "wavelength")
        if index is None:
            # R's data frames name it "w" (the LHires III curve, Wehrli's table); never over a
            # proper name, as "W" is also a unit of the values (nm, W).
            index = self.find(FALLBACK_WAVELENGTH_COLUMNS, "wavelength")
        if index is None:
            raise SpectrumError(
                f"no wavelength column among {', '.join(self.columns)}; name it wavelength_nm "
                "(or wavelength, wl, nm, lambda)",
                source=str(self.path),
            )
        return index

    def rgb_indices(self) -> tuple[tuple[int, int, int], tuple[int, int, int] | None]:
        """The R, G, B columns and their σ columns (``None`` when there are none), by name.

        Raises
        ------
        SpectrumError
            No header (which column is which cannot be known), a channel missing or named twice,
            σ columns for some channels only, or a column that is none of these.
        """
        if not self.had_header:
            raise SpectrumError(
                f"no header line, so which of the {len(self.columns) - 1} value columns is R, G or "
                "B cannot be known; add a header such as wavelength_nm,R,G,B",
                source=str(self.path),
            )
        wavelength = self.wavelength_index()
        found = [self.find(names, f"{names[1]} channel") for names in CHANNEL_COLUMNS]
        sigmas = [
            self.find(sigma_column_names(k), f"σ of {CHANNEL_COLUMNS[k][1]}") for k in range(3)
        ]
        missing = [CHANNEL_COLUMNS[k][1] for k, index in enumerate(found) if index is None]
        if missing:
            raise SpectrumError(
                f"no column for {', '.join(missing)} among {', '.join(self.columns)}; name the "
                "channels R, G, B (or red, green, blue)",
                source=str(self.path),
            )
        if any(index is None for index in sigmas) and any(index is not None for index in sigmas):
            raise SpectrumError(
                "give a σ column for every channel (R_sigma, G_sigma, B_sigma) or for none; "
                f"columns are {', '.join(self.columns)}",
                source=str(self.path),
            )
        known = {wavelength, *found, *sigmas}
        extra = [self.columns[i] for i in range(len(self.columns)) if i not in known]
        if extra:
            raise SpectrumError(
                f"unknown column(s) {', '.join(extra)}: a camera table has wavelength_nm, R, G, B "
                "and optionally R_sigma, G_sigma, B_sigma",
                source=str(self.path),
            )
        channels = (found[0], found[1], found[2])
        assert None not in channels
        if sigmas[0] is None:
            return channels, None  # type: ignore[return-value]
        return channels, (sigmas[0], sigmas[1], sigmas[2])  # type: ignore[return-value]


def read_table(path: str | Path) -> CsvTable:
    """Read a numeric CSV/TSV/whitespace table with an optional header line and ``#`` comments.

    Raises :class:`SpectrumError` naming the file and line on text in a data row, ragged rows, an
    empty file or a missing file.
    """
    path = Path(path)
    try:
        with path.open("rb") as stream:
            raw = stream.read(MAX_TABLE_BYTES + 1)
    except FileNotFoundError:
        raise SpectrumError("file not found", source=str(path)) from None
    except OSError as exc:
        raise SpectrumError(f"cannot read: {exc.strerror}", source=str(path)) from None
    if len(raw) > MAX_TABLE_BYTES:
        raise SpectrumError(
            f"more than {MAX_TABLE_BYTES // (1024 * 1024)} MiB: not a spectrum or profile table "
            "(give the measurement itself, at most a few hundred thousand rows)",
            source=str(path),
        )
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    lines = [
        (number, line.strip())
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith(("#", "//", ";"))
    ]
    if not lines:
        raise SpectrumError("no data rows (empty file?)", source=str(path))
    delimiter = _guess_delimiter(lines[-1][1]) if len(lines) > 1 else _guess_delimiter(lines[0][1])
    header_delimiter = delimiter
    if delimiter is None or delimiter not in lines[0][1]:
        header_delimiter = _guess_delimiter(lines[0][1])
    first_fields = _strip_trailing_empty(_split(lines[0][1], header_delimiter), header_delimiter)
    had_header = not _NUMBER.match(first_fields[0].strip().strip('"').strip("'"))
    if had_header:
        columns = tuple(f.strip().strip('"').strip("'").lower() for f in first_fields)
        data_lines = lines[1:]
    else:
        columns = ("wavelength_nm", *(f"c{k}" for k in range(1, len(first_fields))))
        data_lines = lines
    if not data_lines:
        raise SpectrumError("a header but no data rows", source=str(path))
    if len(data_lines) > MAX_TABLE_ROWS:
        raise SpectrumError(
            f"{len(data_lines)} data rows; at most {MAX_TABLE_ROWS} are read", source=str(path)
        )
    rows: list[list[float]] = []
    for number, line in data_lines:
        fields = _strip_trailing_empty(_split(line, delimiter), delimiter)
        where = f"{path} line {number}"
        if len(fields) != len(columns):
            raise SpectrumError(
                f"{len(fields)} fields but {len(columns)} columns {columns}", source=where
            )
        rows.append([_to_float(f, delimiter, where) for f in fields])
    if len(columns) < 2:
        raise SpectrumError(
            "need at least two columns: wavelength_nm and a value", source=str(path)
        )
    table = np.array(rows, dtype=np.float64)
    values = np.abs(table[:, 1:][np.isfinite(table[:, 1:])])
    peak = float(values.max()) if values.size else 0.0
    low, high = VALUE_MAGNITUDE_RANGE
    if peak > high or 0.0 < peak < low:
        raise SpectrumError(
            f"values reach {peak:g} at most: outside {low:g} … {high:g}, where no measurement "
            "lies; is the column in the right unit?",
            source=str(path),
        )
    return CsvTable(columns, table, path, had_header)


def read_spectrum_csv(
    path: str | Path,
    column: str | int | None = None,
    *,
    name: str | None = None,
    negative: NegativePolicy = "error",
) -> Spectrum:
    """Read a ``wavelength_nm,value`` CSV (header optional, any spacing).

    With a header the wavelength column is found by name (:data:`WAVELENGTH_COLUMNS`); without
    one it is the first column.

    Parameters
    ----------
    path
        The file.
    column
        Which value column to use when there are several: a header name or a 1-based index
        (column 0 is the wavelength). Required when the file has more than one value column.
    name
        Name of the spectrum (defaults to the file name).
    negative
        ``"error"`` or ``"clip"`` (see :class:`Spectrum`).
    """
    table = read_table(path)
    label = name or table.path.name
    wavelength = table.wavelength_index()
    if column is None:
        values = [i for i in range(len(table.columns)) if i != wavelength]
        if len(values) != 1:
            raise SpectrumError(
                f"{len(values)} value columns {tuple(table.columns[i] for i in values)}; choose "
                "one with column=NAME or use read_multispectrum_csv",
                source=str(table.path),
            )
        index = values[0]
    elif isinstance(column, int):
        if not 1 <= column < len(table.columns) or column == wavelength:
            raise SpectrumError(
                f"column index {column} out of range 1..{len(table.columns) - 1} (or the "
                "wavelength column)",
                source=str(table.path),
            )
        index = column
    else:
        found = table.find((column,), f"column {column!r}")
        if found is None:
            raise SpectrumError(
                f"no column {column!r}; columns are {table.columns}", source=str(table.path)
            )
        index = found
    try:
        return Spectrum(
            table.rows[:, wavelength], table.rows[:, index], name=label, negative=negative
        )
    except SpectrumError as exc:
        raise SpectrumError(str(exc).removeprefix(f"{label}: "), source=str(table.path)) from None


def read_multispectrum_csv(
    path: str | Path,
    channels: Sequence[str] | None = None,
    *,
    name: str | None = None,
    negative: NegativePolicy = "error",
) -> MultiSpectrum:
    """Read a ``wavelength_nm,c1,c2,…`` CSV: the wavelength column by name, every other column a
    channel named by its header, in the file's order.

    ``channels`` overrides the names from the header (required count = number of value columns).
    A camera's R, G, B (in that order whatever the file's, with σ) is
    :func:`calib.core.camera_curves.read_camera_csv`.
    """
    table = read_table(path)
    label = name or table.path.name
    wavelength = table.wavelength_index()
    value_columns = [i for i in range(len(table.columns)) if i != wavelength]
    names = (
        tuple(channels) if channels is not None else tuple(table.columns[i] for i in value_columns)
    )
    if len(names) != len(value_columns):
        raise SpectrumError(
            f"{len(value_columns)} value columns but {len(names)} channel names {names}",
            source=str(table.path),
        )
    try:
        return MultiSpectrum(
            table.rows[:, wavelength],
            table.rows[:, value_columns],
            channels=names,
            name=label,
            negative=negative,
        )
    except SpectrumError as exc:
        raise SpectrumError(str(exc).removeprefix(f"{label}: "), source=str(table.path)) from None


#: What a spectrum's ``# units:`` says of its quantity (:func:`spectral_units_kind`).
UnitsKind = Literal["energy", "photon", "counts", "ratio", "relative", "unknown"]

#: Words that mark each kind, tried in this order on the lower-cased text ("photon counts
#: (uncalibrated)" is counts: an uncalibrated instrument's response is the graver fault).
_UNITS_WORDS: tuple[tuple[UnitsKind, re.Pattern[str]], ...] = (
    ("counts", re.compile(r"uncalibrated|\braw\b")),
    ("photon", re.compile(r"photon|quant[au]|\b[µμu]?mol\b|einstein")),
    ("counts", re.compile(r"\bcounts?\b|\badu\b|\bdn\b|\bdigital numbers?\b")),
    ("ratio", re.compile(r"reflectan|transmittan|absorp?tan|\b[rt]-factor")),
    # units, or the quantity a format names (IES TM-27-14: flux, irradiance, radiance …)
    (
        "energy",
        re.compile(
            r"\b[fpnµμumk]?w\b|watt|\b[mµμu]?j\b|joule|\berg|flux|irradiance|radiance|"
            r"intensity|exitance|power"
        ),
    ),
    ("relative", re.compile(r"relative|arbitrary|a\.\s?u\.|\bau\b|normali[sz]ed|unitless")),
)


def spectral_units_kind(units: str) -> UnitsKind:
    """What a spectrum's units (``# units:`` of its CSV, or a format's spectral quantity) measure:
    ``"energy"`` (power or energy per nm: W, mW/(sr m² nm), J, erg, an irradiance), ``"photon"`` (photons or moles of them per nm: what a PAR
    meter or a quantum-calibrated spectrometer gives), ``"counts"`` (a spectrometer's raw counts,
    or anything marked uncalibrated: its own spectral response is still in them), ``"ratio"`` (a
    reflectance or transmittance: a sample's, not a lamp's emission), ``"relative"`` (no unit:
    taken as energy), else ``"unknown"``.

    >>> spectral_units_kind("W/(sr m² nm)"), spectral_units_kind("µmol/m²/s/nm")
    ('energy', 'photon')
    >>> spectral_units_kind("counts/ms (uncalibrated)"), spectral_units_kind("furlongs")
    ('counts', 'unknown')
    """
    text = units.strip().lower()
    for kind, words in _UNITS_WORDS:
        if words.search(text):
            return kind
    return "unknown"


def photon_to_energy(spectrum: Spectrum, reference_nm: float = 555.0) -> Spectrum:
    """A spectrum in photons per nm as relative power per nm: each photon carries ``hc/λ``, so the
    values are divided by ``λ`` (scaled by ``reference_nm`` so that the magnitude stays near the
    original's; the scale is arbitrary to the estimate)."""
    wavelength = spectrum.wavelength_nm
    return Spectrum(wavelength, spectrum.values * (reference_nm / wavelength), name=spectrum.name)


def csv_header(path: str | Path) -> dict[str, str]:
    """The ``# key: value`` comment lines before a CSV's data (keys lower-cased), e.g. a spectrum's
    ``# units: W/(sr m² nm)`` and ``# bandwidth_nm: 8`` (what :func:`write_csv` writes)."""
    found: dict[str, str] = {}
    with Path(path).open(encoding="utf-8-sig", errors="replace") as handle:
        for line in handle:
            stripped = line.strip()
            if not stripped:
                continue
            if not stripped.startswith("#"):
                break
            key, separator, value = stripped.lstrip("#").partition(":")
            if separator:
                found[key.strip().lower()] = value.strip()
    return found


def write_csv(
    path: str | Path,
    spectrum: Spectrum | MultiSpectrum,
    *,
    header: Mapping[str, object] | None = None,
) -> Path:
    """Write ``wavelength_nm,value`` (or ``wavelength_nm,<channels>``) with a header line, after
    ``# key: value`` comment lines for ``header``'s entries that are not ``None`` (units,
    bandwidth_nm …; :func:`csv_header` reads them back)."""
    path = Path(path)
    if isinstance(spectrum, Spectrum):
        columns: Iterable[str] = ("wavelength_nm", "value")
        body = np.column_stack([spectrum.wavelength_nm, spectrum.values])
    else:
        columns = ("wavelength_nm", *spectrum.channels)
        body = np.column_stack([spectrum.wavelength_nm, spectrum.values])
    lines = [f"# {key}: {value}" for key, value in (header or {}).items() if value is not None]
    lines.append(",".join(columns))
    lines.extend(",".join(f"{v:.10g}" for v in row) for row in body)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
