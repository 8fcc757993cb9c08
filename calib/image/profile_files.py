"""1-D RGB profiles from the files other tools write: rawproc ``.dat`` exports and FITS planes.

A user who reduced a grating capture elsewhere brings what that tool wrote, not a CSV; these
readers turn it into an :class:`RgbProfile` (pixel axis, R, G, B, and σ where the file allows
one) with no conversion script.

rawproc ``.dat`` (Glenn Butcher's raw processor, "data" export of a cropped image)
    Header lines ``width: N`` and ``height: M``, then the rawproc command that made the image
    (e.g. ``rawproc-0.9.1Dev DSG_4683.NEF:rawdata=crop; demosaic:half rotate:hmirror crop:…``),
    then a row ``x,0,1,…,N−1``, rows ``red,…``, ``green,…``, ``blue,…`` holding the *column means*
    of the ``M`` rows of the crop (linear 0–1), and trailing ``rmax: V rmaxcolumn: C`` lines (also
    ``gmax``, ``bmax``) that are checked against the rows. A ``hmirror`` in the command means the
    columns run mirrored with respect to the sensor; the profile keeps the file's order (where the
    wavelength usually increases with ``x``) unless ``sensor_orientation=True``. The file holds
    means only, so the profile has no σ (the estimators then use a robust noise estimate).
FITS (through astropy, an optional dependency: ``pip install 'spectral-rig[fits]'``)
    One 2-D image per colour plane (three files R, G, B) or one cube with three planes. The
    spectral axis runs along the image's x (``NAXIS1``) by default. The profile is the *sum* over
    the band's cross-dispersion rows (found as the rows whose mean reaches ``band_fraction`` of the
    brightest, or given), less the per-column background of the rows outside the band when there
    are enough of them. σ comes from the rows' scatter about a separable model ``a_row · m_column``
    (the band's cross-section times the spectrum) — shot and read noise alike — and is inflated
    by the correlation between neighbouring rows that a demosaicked plane has (its rows share raw
    samples, so their scatter understates the noise of their sum).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.observations import LampKind, LampObservation
from calib.core.spectra import Spectrum

CHANNELS: tuple[str, str, str] = ("red", "green", "blue")
#: Relative tolerance of the trailing ``rmax:`` lines against the rows' own maxima (the file
#: prints six decimals).
RAWPROC_MAX_TOLERANCE = 5e-6
#: Fewer rows outside the band than this: no background is subtracted.
MIN_BACKGROUND_ROWS = 4
#: Columns over which each column's scatter is averaged (it rests on few rows per column).
SCATTER_SMOOTHING_COLUMNS = 7
#: Columns sharing one fitted cross-section of the band in the σ model.
CROSS_SECTION_BLOCK_COLUMNS = 64
#: Neighbouring-row lags whose correlation inflates the σ of a sum over rows.
CORRELATION_LAGS = 2
FITS_EXTRA_HINT = "reading FITS needs astropy: pip install 'spectral-rig[fits]' (or astropy>=6.0)"


@dataclass(frozen=True, eq=False)
class RgbProfile:
    """A 1-D first-order profile read from a file.

    Attributes
    ----------
    pixel
        Shape ``(n,)``, increasing: the column of each sample (the file's own pixel axis).
    profile
        Shape ``(n, 3)``: R, G, B in the file's linear units.
    profile_sigma
        Shape ``(n, 3)`` standard deviation, or ``None`` when the file does not allow one.
    source
        The file(s) read.
    metadata
        What the file says about how it was made (JSON-safe): the processing command, rows
        averaged or summed, mirroring, header keywords.
    """

    pixel: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray | None
    source: str
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pixel = np.array(self.pixel, dtype=np.float64)
        profile = np.array(self.profile, dtype=np.float64)
        if profile.shape != (pixel.size, 3):
            raise InputError(
                f"profile has shape {profile.shape}, expected ({pixel.size}, 3)", source=self.source
            )
        for array in (pixel, profile):
            array.flags.writeable = False
        object.__setattr__(self, "pixel", pixel)
        object.__setattr__(self, "profile", profile)
        if self.profile_sigma is not None:
            sigma = np.array(self.profile_sigma, dtype=np.float64)
            sigma.flags.writeable = False
            object.__setattr__(self, "profile_sigma", sigma)

    def to_observation(
        self,
        name: str,
        spectrum: Spectrum,
        *,
        kind: LampKind = "other",
        direct_rgb: Sequence[float] | None = None,
        spectrum_bandwidth_nm: float | None = None,
    ) -> LampObservation:
        """The estimators' input: this profile with the lamp's spectrum (pixel origin arbitrary)."""
        return LampObservation(
            name=name,
            spectrum=spectrum,
            pixel=self.pixel,
            profile=self.profile,
            direct_rgb=None if direct_rgb is None else np.asarray(direct_rgb, dtype=np.float64),
            profile_sigma=self.profile_sigma,
            kind=kind,
            metadata={"profile_file": self.source, **dict(self.metadata)},
            spectrum_bandwidth_nm=spectrum_bandwidth_nm,
        )


# ----------------------------------------------------------------------------------- rawproc


def _numbers(fields: list[str], where: str) -> FloatArray:
    try:
        values = np.array([float(text) for text in fields], dtype=np.float64)
    except ValueError:
        bad = next(text for text in fields if not _is_number(text))
        raise InputError(f"{bad!r} is not a number", source=where) from None
    if not np.all(np.isfinite(values)):
        raise InputError("contains NaN or infinite values", source=where)
    return values


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


_MAX_LINE = re.compile(
    r"^(?P<channel>[rgb])max:\s*(?P<value>\S+)(?:\s+\wmaxcolumn:\s*(?P<column>\d+))?"
)


def read_rawproc_dat(path: str | Path, *, sensor_orientation: bool = False) -> RgbProfile:
    """Read a rawproc ``.dat`` export (see the module docstring) into a profile.

    Parameters
    ----------
    path
        The ``.dat`` file.
    sensor_orientation
        Undo a ``hmirror`` of the rawproc command, so that the pixel axis runs as the sensor's
        columns (and the profile's order follows); by default the file's order is kept.

    Raises
    ------
    InputError
        A missing or unreadable file, a missing ``width:``/``x``/``red``/``green``/``blue`` line,
        rows of the wrong length, text or NaN in a row, an ``x`` row that is not ``0 … width−1``,
        or an ``rmax:``-style line that disagrees with its row (the file and line are named).

    Examples
    --------
    Not run as a doctest: it needs a rawproc export (``tests/test_profile_files.py`` reads written
    ones, and the real D7000 files when ``../shared`` is present).

    >>> profile = read_rawproc_dat("D7000_spectrum.dat")  # doctest: +SKIP
    >>> profile.profile.shape, profile.metadata["mirrored"]  # doctest: +SKIP
    ((2474, 3), True)
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", source=str(path)) from None
    header: dict[str, int] = {}
    rows: dict[str, tuple[int, FloatArray]] = {}
    maxima: dict[str, tuple[int, float, int | None]] = {}
    command = ""
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        where = f"{path} line {number}"
        if not line:
            continue
        key = line.split(",", 1)[0].split(":", 1)[0].strip().lower()
        if key in ("width", "height") and ":" in line:
            text = line.split(":", 1)[1].strip()
            if not text.isdigit() or int(text) <= 0:
                raise InputError(f"{key} must be a positive integer, got {text!r}", source=where)
            header[key] = int(text)
        elif key in ("x", *CHANNELS) and "," in line:
            if key in rows:
                raise InputError(f"a second {key!r} row", source=where)
            rows[key] = (number, _numbers(line.split(",")[1:], where))
        elif (match := _MAX_LINE.match(line)) is not None:
            column = match["column"]
            maxima[match["channel"]] = (
                number,
                float(_numbers([match["value"]], where)[0]),
                None if column is None else int(column),
            )
        elif line.lower().startswith("rawproc"):
            command = line
        else:
            raise InputError(
                f"unexpected line {line[:40]!r}; a rawproc .dat has width:, height:, the rawproc "
                "command, x/red/green/blue rows and rmax:/gmax:/bmax: lines",
                source=where,
            )
    missing = [name for name in ("width", "height") if name not in header]
    missing += [name for name in ("x", *CHANNELS) if name not in rows]
    if missing:
        raise InputError(
            f"not a rawproc data export: no {', '.join(missing)} line(s)", source=str(path)
        )
    width = header["width"]
    for name, (number, values) in rows.items():
        if values.size != width:
            raise InputError(
                f"the {name!r} row has {values.size} values, width says {width}",
                source=f"{path} line {number}",
            )
    x_line, x = rows["x"]
    if not np.array_equal(x, np.arange(width, dtype=np.float64)):
        raise InputError(f"the x row must be 0, 1, …, {width - 1}", source=f"{path} line {x_line}")
    profile = np.stack([rows[name][1] for name in CHANNELS], axis=1)
    for letter, (number, value, column) in maxima.items():
        channel = "rgb".index(letter)
        found = float(profile[:, channel].max())
        if abs(found - value) > RAWPROC_MAX_TOLERANCE * max(abs(value), 1.0) + 5e-7:
            raise InputError(
                f"{letter}max {value:g} disagrees with the {CHANNELS[channel]} row's maximum "
                f"{found:g}; the file is damaged or edited",
                source=f"{path} line {number}",
            )
        if column is not None and profile[column, channel] < found - 5e-7:
            raise InputError(
                f"{letter}maxcolumn {column} does not hold the {CHANNELS[channel]} row's maximum",
                source=f"{path} line {number}",
            )
    mirrored = "hmirror" in command
    flipped = sensor_orientation and mirrored
    if flipped:
        profile = profile[::-1]
    metadata: dict[str, Any] = {
        "format": "rawproc data export",
        "command": command,
        "rows_averaged": header["height"],
        "width": width,
        "mirrored": mirrored,
        "pixel_axis": "sensor columns of the crop"
        if flipped or not mirrored
        else "mirrored columns of the crop (rawproc hmirror)",
        "units": "linear, 0-1 (column means)",
    }
    return RgbProfile(np.arange(width, dtype=np.float64), profile, None, str(path), metadata)


# -------------------------------------------------------------------------------------- FITS


@dataclass(frozen=True, eq=False)
class ChannelPlanes:
    """Three colour planes of one image and their FITS headers.

    Attributes
    ----------
    planes
        Shape ``(3, rows, columns)``: R, G, B as stored (BZERO/BSCALE applied), float64.
    headers
        One header per plane, as plain ``{keyword: value}`` data.
    source
        The file(s) read.
    """

    planes: FloatArray
    headers: tuple[Mapping[str, Any], ...]
    source: str


def _fits_module() -> Any:
    try:
        from astropy.io import fits  # deferred: optional dependency, slow to import
    except ImportError:
        raise InputError(FITS_EXTRA_HINT, source="FITS") from None
    return fits


def _read_fits_image(path: Path) -> tuple[FloatArray, dict[str, Any]]:
    fits = _fits_module()
    try:
        with fits.open(path, memmap=False) as hdus:
            for hdu in hdus:
                if getattr(hdu, "data", None) is not None and getattr(hdu, "is_image", False):
                    data = np.asarray(hdu.data, dtype=np.float64)
                    header = {
                        str(k): v
                        for k, v in hdu.header.items()
                        if k and k not in ("COMMENT", "HISTORY")
                    }
                    return data, header
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except OSError as exc:
        raise InputError(f"not a readable FITS file ({exc})", source=str(path)) from None
    raise InputError("the FITS file holds no image data", source=str(path))


def read_fits_planes(paths: str | Path | Sequence[str | Path]) -> ChannelPlanes:
    """R, G, B planes from three 2-D FITS images (in that order) or one cube of three planes.

    Raises
    ------
    InputError
        astropy missing (with the install line), a file that is not FITS or holds no image, planes
        of different shapes, NaN or infinite values, or a cube without exactly three planes.
    """
    files = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
    if len(files) not in (1, 3):
        raise InputError(
            f"give three FITS files (R, G, B) or one cube, got {len(files)}", source="FITS"
        )
    images = [_read_fits_image(path) for path in files]
    source = ", ".join(str(path) for path in files)
    if len(files) == 1:
        data, header = images[0]
        if data.ndim != 3 or 3 not in (data.shape[0], data.shape[-1]):
            raise InputError(
                f"one file must be a cube of 3 colour planes, got shape {data.shape}; or give "
                "the R, G and B planes as three files",
                source=source,
            )
        planes = data if data.shape[0] == 3 else np.moveaxis(data, -1, 0)
        headers: tuple[Mapping[str, Any], ...] = (header,) * 3
    else:
        shapes = {data.shape for data, _ in images}
        if len(shapes) != 1 or next(iter(shapes)).__len__() != 2:
            raise InputError(
                f"the three planes must be 2-D images of one shape, got {sorted(shapes)}",
                source=source,
            )
        planes = np.stack([data for data, _ in images])
        headers = tuple(header for _, header in images)
    if not np.all(np.isfinite(planes)):
        raise InputError("the planes contain NaN or infinite values", source=source)
    planes = np.ascontiguousarray(planes, dtype=np.float64)
    planes.flags.writeable = False
    return ChannelPlanes(planes, headers, source)


def band_rows(planes: FloatArray, band_fraction: float = 0.5) -> tuple[int, int]:
    """``(first, stop)`` rows of the band: the contiguous run around the brightest row whose mean
    (over columns and channels) reaches ``band_fraction`` of the brightest row's.

    The planes are taken as dark-subtracted (a reduced FITS image is): a band that fills the frame
    keeps every row.
    """
    if not 0 < band_fraction < 1:
        raise InputError(f"band_fraction must lie in (0, 1), got {band_fraction}", source="band")
    across = planes.mean(axis=(0, 2))
    peak = int(np.argmax(across))
    inside = across >= band_fraction * float(across[peak])
    first, stop = peak, peak + 1
    while first > 0 and inside[first - 1]:
        first -= 1
    while stop < across.size and inside[stop]:
        stop += 1
    return first, stop


def _separable_residual(rows_signal: FloatArray, source: str) -> FloatArray:
    """``x − a ⊗ m`` for a band ``x`` of shape ``(rows, columns)``: the cross-section ``a`` (fitted
    per block of :data:`CROSS_SECTION_BLOCK_COLUMNS`, so vignetting along the band is not taken
    for noise) times each column's least-squares level ``m``."""
    residual = np.empty_like(rows_signal)
    for start in range(0, rows_signal.shape[1], CROSS_SECTION_BLOCK_COLUMNS):
        block = rows_signal[:, start : start + CROSS_SECTION_BLOCK_COLUMNS]
        cross_section = block.mean(axis=1)
        weight = float(cross_section @ cross_section)
        if weight <= 0:
            raise InputError(
                f"no signal in the band's columns {start}…{start + block.shape[1] - 1}",
                source=source,
            )
        level = cross_section @ block / weight
        residual[:, start : start + block.shape[1]] = block - np.outer(cross_section, level)
    return residual


def _row_correlation_inflation(residual: FloatArray) -> float:
    """``1 + 2 Σ_k (1 − k/n) ρ_k`` over lags ``k ≤ CORRELATION_LAGS`` of the residuals' row
    autocorrelation (pooled over columns), at least 1: the variance of a sum of ``n`` correlated
    rows over that of ``n`` independent ones."""
    n = residual.shape[0]
    variance = float(np.mean(residual**2))
    if n < 3 or variance <= 0:
        return 1.0
    inflation = 1.0
    for lag in range(1, min(CORRELATION_LAGS, n - 1) + 1):
        rho = float(np.mean(residual[lag:] * residual[:-lag])) / variance
        inflation += 2.0 * (1.0 - lag / n) * rho
    return max(inflation, 1.0)


def profile_from_planes(
    planes: ChannelPlanes,
    *,
    rows: tuple[int, int] | None = None,
    dispersion_axis: Literal["x", "y"] = "x",
    band_fraction: float = 0.5,
) -> RgbProfile:
    """Sum the band's cross-dispersion rows of each plane into a profile with σ (module docstring).

    Parameters
    ----------
    planes
        From :func:`read_fits_planes`.
    rows
        ``(first, stop)`` rows of the band (after turning ``dispersion_axis`` to x); default: found
        with :func:`band_rows`.
    dispersion_axis
        ``"x"`` when the spectrum runs along the image's columns (``NAXIS1``), ``"y"`` along rows.
    band_fraction
        Threshold of :func:`band_rows`.

    Raises
    ------
    InputError
        A band of fewer than 2 rows, or rows outside the image.
    """
    if dispersion_axis not in ("x", "y"):
        raise InputError(
            f"dispersion_axis must be 'x' or 'y', got {dispersion_axis!r}", source="FITS"
        )
    data = planes.planes if dispersion_axis == "x" else np.swapaxes(planes.planes, 1, 2)
    n_rows = data.shape[1]
    first, stop = band_rows(data, band_fraction) if rows is None else rows
    if not 0 <= first < stop <= n_rows or stop - first < 2:
        raise InputError(
            f"band rows {first}…{stop - 1} must lie inside 0…{n_rows - 1} and span ≥ 2 rows",
            source=planes.source,
        )
    band = data[:, first:stop, :]
    outside = np.concatenate([data[:, :first, :], data[:, stop:, :]], axis=1)
    background = (
        np.median(outside, axis=1)
        if outside.shape[1] >= MIN_BACKGROUND_ROWS
        else np.zeros((3, data.shape[2]))
    )
    n = band.shape[1]
    signal = band - background[:, None, :]
    profile = signal.sum(axis=1).T
    from scipy.ndimage import uniform_filter1d  # deferred: scipy.ndimage is slow to import

    sigma = np.empty_like(profile)
    inflation: list[float] = []
    for channel in range(3):
        residual = _separable_residual(signal[channel], f"{planes.source} ({CHANNELS[channel]})")
        scatter = np.sum(residual**2, axis=0) / max(n - 2, 1)
        scatter = uniform_filter1d(scatter, SCATTER_SMOOTHING_COLUMNS, mode="nearest")
        factor = _row_correlation_inflation(residual)
        inflation.append(factor)
        sigma[:, channel] = np.sqrt(np.maximum(n * scatter * factor, 0.0))
    positive = sigma[sigma > 0]
    floor = float(positive.min()) if positive.size else 1e-12
    sigma = np.maximum(sigma, floor)
    header = dict(planes.headers[0])
    metadata: dict[str, Any] = {
        "format": "FITS planes",
        "band_rows": [first, stop],
        "rows_summed": n,
        "background": "median of the rows outside the band"
        if outside.shape[1] >= MIN_BACKGROUND_ROWS
        else "none (the band fills the frame)",
        "dispersion_axis": dispersion_axis,
        "row_correlation_inflation": [round(f, 4) for f in inflation],
        "header": {
            key: value
            for key, value in header.items()
            if isinstance(value, str | int | float | bool)
            and key in ("INSTRUME", "EXPTIME", "ISOSPEED", "DATE-OBS", "PROGRAM", "BZERO")
        },
    }
    pixel = np.arange(profile.shape[0], dtype=np.float64)
    return RgbProfile(pixel, profile, sigma, planes.source, metadata)


def read_fits_profile(
    paths: str | Path | Sequence[str | Path],
    *,
    rows: tuple[int, int] | None = None,
    dispersion_axis: Literal["x", "y"] = "x",
    band_fraction: float = 0.5,
) -> RgbProfile:
    """:func:`read_fits_planes` then :func:`profile_from_planes`.

    Examples
    --------
    Not run as a doctest: it needs FITS planes (``tests/test_profile_files.py`` reads written ones,
    and the real Canon 10D planes when ``../shared`` is present).

    >>> planes = [f"Solar Spectrum Canon EOS 10D {c}.fit" for c in "RGB"]  # doctest: +SKIP
    >>> read_fits_profile(planes).profile.shape  # doctest: +SKIP
    (1658, 3)
    """
    return profile_from_planes(
        read_fits_planes(paths),
        rows=rows,
        dispersion_axis=dispersion_axis,
        band_fraction=band_fraction,
    )
