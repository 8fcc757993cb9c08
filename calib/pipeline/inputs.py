"""What the offline estimate is given, per lamp: RAW brackets or a 1-D profile, and a spectrum.

:class:`LampImages` is a lamp seen in RAW files (a bracket, optional dark frames); :class:`LampProfile`
is a lamp whose first-order profile was already extracted by other means (a CSV ``pixel,r,g,b`` or
``wavelength_nm,r,g,b``, optionally with ``r_sigma,g_sigma,b_sigma``, and an optional direct RGB).
Both name the lamp's measured spectrum: a CSV ``wavelength_nm,value`` (several CSVs: their mean,
as the rig averages a lamp's reference spectra; ``# units:`` and ``# bandwidth_nm:`` header lines,
which the rig writes, are read) or a :class:`Spectrum`.

Everything here is checked before any RAW file is decoded, so a typo costs a second, not a minute.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError, SpectrumError
from calib.core.lamp_specs import is_spectrum_file, lamp_from_spec
from calib.core.observations import LAMP_KINDS, LampKind
from calib.core.spectra import (
    Spectrum,
    UnitsKind,
    WavelengthGrid,
    as_spectrum,
    csv_header,
    photon_to_energy,
    read_spectrum_csv,
    read_table,
    spectral_units_kind,
)
from calib.core.spectrometer_tolerance import MAX_BANDWIDTH_NM
from calib.image.profile_files import read_fits_profile, read_rawproc_dat

#: Negative spectrum values (dark-subtraction noise) up to this fraction of the maximum are set to
#: zero with a warning; larger ones mean a broken measurement and are refused.
NEGATIVE_SPECTRUM_TOLERANCE = 0.05

_PIXEL_COLUMNS = ("pixel", "pixels", "px", "position_px", "pixel_px")
_WAVELENGTH_COLUMNS = ("wavelength_nm", "wavelength", "nm", "lambda_nm")
_CHANNEL_COLUMNS = ("r", "g", "b")
_SIGMA_COLUMNS = (("r_sigma", "sigma_r"), ("g_sigma", "sigma_g"), ("b_sigma", "sigma_b"))


#: A lamp's spectrum as given: a CSV, several CSVs of one lamp (averaged), or a spectrum.
SpectrumSource = Path | tuple[Path, ...] | Spectrum


def spectrum_paths(source: SpectrumSource) -> tuple[Path, ...]:
    """The files behind a spectrum source (none for a :class:`Spectrum`)."""
    if isinstance(source, Path):
        return (source,)
    if isinstance(source, tuple):
        return source
    return ()


def spectrum_files(source: SpectrumSource) -> tuple[Path, ...]:
    """The files to read behind a spectrum source: none for a :class:`Spectrum` or a named one
    (a colour-science name, ``builtin:NAME``, ``gauss:CENTRE:FWHM``), which is not a file."""
    paths = spectrum_paths(source)
    if len(paths) == 1 and not is_spectrum_file(paths[0]):
        return ()
    return paths


def describe_spectrum(source: SpectrumSource) -> str:
    """The spectrum source in a record: its path(s) or its name."""
    paths = spectrum_paths(source)
    if paths:
        return ", ".join(str(path) for path in paths)
    assert isinstance(source, Spectrum)
    return source.name


#: Whether a profile's channels keep the raw data's gains (:attr:`LampProfile.channel_gains`).
ChannelGains = Literal["raw", "unknown"]


@dataclass(frozen=True)
class LampImages:
    """A lamp captured as RAW files.

    Parameters
    ----------
    name
        Lamp name (unique among the lamps).
    kind
        ``led``, ``fluorescent``, ``halogen``, ``narrowband`` or ``other``.
    spectrum
        The lamp's measured spectrum: a CSV path, several (averaged) or a :class:`Spectrum`.
    images
        The bracket's RAW files.
    darks
        Dark frames at the bracket's exposure times (optional).
    exposure_s
        Exposure times overriding the files' metadata, one per image (or ``None``).
    dark_exposure_s
        The same for the dark frames.
    spectrum_bandwidth_nm
        FWHM of the spectrometer's slit function that measured ``spectrum`` (see
        :attr:`calib.core.observations.LampObservation.spectrum_bandwidth_nm`), or ``None``: the
        CSV's ``# bandwidth_nm:`` line when it has one.
    """

    name: str
    kind: LampKind
    spectrum: SpectrumSource
    images: tuple[Path, ...]
    darks: tuple[Path, ...] = ()
    exposure_s: tuple[float, ...] | None = None
    dark_exposure_s: tuple[float, ...] | None = None
    spectrum_bandwidth_nm: float | None = None


@dataclass(frozen=True)
class LampProfile:
    """A lamp given as a 1-D first-order profile (no images).

    Parameters
    ----------
    name, kind, spectrum
        As for :class:`LampImages`.
    profile
        CSV ``pixel,r,g,b`` or ``wavelength_nm,r,g,b`` (header required; optional
        ``r_sigma,g_sigma,b_sigma``), a rawproc ``.dat`` export, a FITS cube of the R, G and B
        planes (``.fit``/``.fits``/``.fts``), or those planes as three FITS files, R, G, B: see
        :func:`read_profile_file`.
    direct_rgb
        The direct (0th-order) RGB in the profile's units times pixels, or ``None``.
    spectrum_bandwidth_nm
        As for :class:`LampImages`.
    channel_gains
        ``"raw"``: the profile's channels keep the raw data's gains (a raw export); ``"unknown"``:
        a conversion scaled them (white balance, a demosaicked RGB export), so the estimate takes
        the channel balance from the camera population, with its spread in σ (decision 0050). A
        file that says its gains are not raw (a rawproc ``whitebalance:camera``, an input opened
        without ``rawdata``) is taken as ``"unknown"`` with a warning (decision 0178).
    """

    name: str
    kind: LampKind
    spectrum: SpectrumSource
    profile: Path | tuple[Path, ...]
    direct_rgb: tuple[float, float, float] | None = None
    spectrum_bandwidth_nm: float | None = None
    channel_gains: ChannelGains = "raw"


LampInput = LampImages | LampProfile


def profile_files(profile: Path | tuple[Path, ...]) -> tuple[Path, ...]:
    """The files of a lamp's profile (one, or a FITS export's three planes)."""
    return profile if isinstance(profile, tuple) else (profile,)


def describe_profile(profile: Path | tuple[Path, ...]) -> str:
    """The profile's file(s) in a record."""
    return ", ".join(str(path) for path in profile_files(profile))


@dataclass(frozen=True, eq=False)
class ProfileTable:
    """A profile read from CSV.

    Parameters
    ----------
    axis
        Shape ``(n,)``, increasing: pixel positions, or wavelengths when ``in_wavelength``.
    profile, profile_sigma
        Shape ``(n, 3)``; ``profile_sigma`` is ``None`` when the file has no sigma columns.
    in_wavelength
        The first column was ``wavelength_nm``: the profile is already mapped.
    channel_gains_unknown
        Why the file says its channels are not at the raw data's gains (a rawproc
        ``whitebalance:camera``), or ``None``: see :attr:`RgbProfile.channel_gains_unknown`.
    image_planes
        Read from an RGB image's colour planes (FITS), whose channel gains a conversion may
        have changed: see :attr:`RgbProfile.image_planes`.
    metadata, warnings, notes
        What the file's reader recorded, warned and noted (:class:`RgbProfile`); empty for a CSV.
    """

    axis: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray | None
    in_wavelength: bool
    channel_gains_unknown: str | None = None
    image_planes: bool = False
    metadata: Mapping[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


@dataclass
class LoadedSpectrum:
    """A lamp spectrum and what was done to it on reading.

    ``bandwidth_nm`` and ``units`` are the files' ``# bandwidth_nm:``/``# units:`` header lines
    (the largest bandwidth when averaged files differ; the units also from a value column named
    ``counts``, ``photons`` …), ``None`` when they have none; ``units_kind`` is what the units
    measure (:func:`calib.core.spectra.spectral_units_kind`). A spectrum in photons is converted
    to power per nm.
    """

    spectrum: Spectrum
    warnings: list[str] = field(default_factory=list)
    bandwidth_nm: float | None = None
    units: str | None = None
    units_kind: UnitsKind | None = None


def check_kind(kind: str, source: str) -> LampKind:
    """``kind`` lower-cased if it is a known lamp kind, else :class:`InputError`."""
    lowered = kind.lower()
    if lowered not in LAMP_KINDS:
        raise InputError(
            f"unknown lamp kind {kind!r}; use one of {', '.join(LAMP_KINDS)}", source=source
        )
    return lowered


def check_bandwidth(value: float, *, given_as: str, source: str) -> float:
    """``value`` (a spectrometer's bandwidth, nm) when it is one: above 0 and at most
    :data:`MAX_BANDWIDTH_NM`.

    Raises
    ------
    SpectrumError
        Otherwise, naming ``given_as`` (``"--bandwidth 500"``), ``source`` and the range.
    """
    if not (math.isfinite(value) and 0 < value <= MAX_BANDWIDTH_NM):
        raise SpectrumError(
            f"{given_as} is not a spectrometer's bandwidth (the FWHM of its slit function, nm): "
            f"give one above 0 and at most {MAX_BANDWIDTH_NM:g} nm (an i1Pro's is 25 nm, a "
            "PR-655's 8 nm)",
            source=source,
        )
    return value


def _header_bandwidth(path: Path, header: dict[str, str]) -> float | None:
    text = header.get("bandwidth_nm") or header.get("bandwidth")
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    return check_bandwidth(value, given_as=f"'# bandwidth_nm: {text}'", source=str(path))


def _read_one(path: Path, lamp: str, warnings: list[str]) -> tuple[Spectrum, str]:
    """The spectrum in ``path`` and its value column's name."""
    table = read_table(path)
    if len(table.columns) != 2:
        raise SpectrumError(
            f"expected two columns wavelength_nm,value, found {len(table.columns)} "
            f"({', '.join(table.columns)})",
            source=str(path),
        )
    values = table.rows[:, 1]
    finite = values[np.isfinite(values)]
    peak = float(finite.max()) if finite.size else 0.0
    negative = values < 0
    if negative.any() and np.all(values[negative] >= -NEGATIVE_SPECTRUM_TOLERANCE * peak):
        warnings.append(f"{path.name}: {int(negative.sum())} small negative value(s) set to zero")
        return read_spectrum_csv(path, name=lamp, negative="clip"), table.columns[1]
    return read_spectrum_csv(path, name=lamp), table.columns[1]


def load_spectrum(source: SpectrumSource, lamp: str, grid: WavelengthGrid) -> LoadedSpectrum:
    """Read a lamp spectrum (several files: each must cover ``grid``, and their mean is taken on
    the first one's wavelengths where every file measured) and check that it covers ``grid``.

    Small negative values (noise after dark subtraction, at most
    :data:`NEGATIVE_SPECTRUM_TOLERANCE` of the maximum) are set to zero with a warning.

    ``source`` may also name a spectrum instead of a file (a colour-science illuminant or light
    source, ``builtin:NAME``, ``gauss:CENTRE:FWHM``; :func:`calib.core.lamp_specs.lamp_from_spec`).

    Raises
    ------
    SpectrumError
        Missing file, text in a data row, NaN, non-monotonic wavelengths, large negative values,
        an all-zero spectrum, a range that does not cover the grid, a bad ``# bandwidth_nm:``
        line, or averaged files in different units (the file is named).
    InputError
        A name that is neither a file nor a known spectrum.
    """
    warnings: list[str] = []
    bandwidth: float | None = None
    units: str | None = None
    named, paths = spectrum_paths(source), spectrum_files(source)
    if not named:  # a Spectrum, or colour's SpectralDistribution
        spectrum, where = as_spectrum(source, lamp), f"spectrum of lamp {lamp!r}"
    elif not paths:
        # A colour-science name, builtin:NAME or gauss:… — resolved where every lamp spec is.
        name = str(named[0])
        spectrum, where = lamp_from_spec(name), f"spectrum {name!r} of lamp {lamp!r}"
    else:
        where = ", ".join(str(path) for path in paths)
        read = [_read_one(path, lamp, warnings) for path in paths]
        spectra = [spectrum for spectrum, _ in read]
        headers = [csv_header(path) for path in paths]
        widths = [_header_bandwidth(p, h) for p, h in zip(paths, headers, strict=True)]
        known = [w for w in widths if w is not None]
        bandwidth = max(known) if known else None
        unit_set = {h["units"] for h in headers if "units" in h}
        if len(unit_set) > 1:
            raise SpectrumError(
                f"the spectra of lamp {lamp!r} are in different units ({', '.join(sorted(unit_set))})"
                "; give spectra of one kind",
                source=where,
            )
        units = unit_set.pop() if unit_set else _column_units(read[0][1])
        if len(spectra) == 1:
            spectrum = spectra[0]
        else:
            # Each file must cover the grid (named if not), and the mean is taken where every
            # file measured: np.interp would hold a narrower file's end value constant beyond it.
            for path, one in zip(paths, spectra, strict=True):
                _check_covers(one, grid, str(path))
            low = max(one.range_nm[0] for one in spectra)
            high = min(one.range_nm[1] for one in spectra)
            axis = spectra[0].wavelength_nm
            axis = axis[(axis >= low) & (axis <= high)]
            values = np.mean([np.interp(axis, s.wavelength_nm, s.values) for s in spectra], axis=0)
            spectrum = Spectrum(axis, values, name=f"{lamp} (mean of {len(spectra)} spectra)")
    if not np.any(spectrum.values > 0):
        raise SpectrumError("the spectrum is zero everywhere", source=where)
    _check_covers(spectrum, grid, where)
    kind = None if units is None else spectral_units_kind(units)
    if kind == "photon":
        # The estimate's sensitivity is per unit power (as the camera databases' curves are).
        spectrum = photon_to_energy(spectrum)
        warnings.append(
            f"lamp {lamp!r}: its spectrum is in {units!r} (photons): converted to power per nm "
            "(× 1/λ) for the estimate"
        )
    elif kind == "unknown":
        warnings.append(
            f"lamp {lamp!r}: its spectrum's units {units!r} are not recognised: taken as power per "
            "nm; if they count photons, say so in its '# units:' line (e.g. photons/s/nm)"
        )
    return LoadedSpectrum(spectrum, warnings, bandwidth, units, kind)


#: Value-column names that say what a spectrum without a ``# units:`` line measures.
_COLUMN_UNIT_KINDS = ("photon", "counts", "ratio")


def _column_units(column: str) -> str | None:
    """A value column's name as the spectrum's units where it says photons, raw counts or a
    ratio (``wavelength_nm,counts``); else ``None`` (``value``, ``irradiance``: no unit said)."""
    return column if spectral_units_kind(column) in _COLUMN_UNIT_KINDS else None


def _check_covers(spectrum: Spectrum, grid: WavelengthGrid, where: str) -> None:
    """A :class:`SpectrumError` naming ``where`` unless ``spectrum`` spans ``grid``."""
    if not spectrum.covers(grid):
        lo, hi = spectrum.range_nm
        raise SpectrumError(
            f"covers {lo:g}–{hi:g} nm, too narrow for the working grid {grid.start_nm:g}–"
            f"{grid.stop_nm:g} nm; measure a wider range or choose a narrower --grid",
            source=where,
        )


def _column(columns: tuple[str, ...], names: tuple[str, ...]) -> int | None:
    for name in names:
        if name in columns:
            return columns.index(name)
    return None


def read_profile_csv(path: Path) -> ProfileTable:
    """Read a 1-D profile ``pixel,r,g,b`` or ``wavelength_nm,r,g,b`` (+ optional sigma columns).

    Rows may come in any order (they are sorted); the axis must not repeat a value.

    Raises
    ------
    InputError
        Missing file or header, unknown columns, text or NaN in a row, repeated positions,
        non-positive sigma, too few rows (the file and line or column are named).
    """
    try:
        table = read_table(path)
    except SpectrumError as exc:
        raise InputError(str(exc).removeprefix(f"{exc.source}: "), source=exc.source) from None
    where = str(path)
    if not table.had_header:
        raise InputError(
            "the profile CSV needs a header: pixel,r,g,b (positions in pixels) or "
            "wavelength_nm,r,g,b (already mapped)",
            source=where,
        )
    columns = table.columns
    pixel_index = _column(columns[:1], _PIXEL_COLUMNS)
    wavelength_index = _column(columns[:1], _WAVELENGTH_COLUMNS)
    if pixel_index is None and wavelength_index is None:
        raise InputError(
            f"first column is {columns[0]!r}; expected 'pixel' or 'wavelength_nm'", source=where
        )
    channel_indices = [_column(columns, (name,)) for name in _CHANNEL_COLUMNS]
    if any(index is None for index in channel_indices):
        missing = [n for n, i in zip(_CHANNEL_COLUMNS, channel_indices, strict=True) if i is None]
        raise InputError(
            f"missing column(s) {', '.join(missing)}; the header must name r, g and b "
            f"(found {', '.join(columns)})",
            source=where,
        )
    sigma_indices = [_column(columns, names) for names in _SIGMA_COLUMNS]
    if any(i is not None for i in sigma_indices) and any(i is None for i in sigma_indices):
        raise InputError(
            "give sigma columns for all three channels (r_sigma,g_sigma,b_sigma) or none",
            source=where,
        )
    known = {0, *[i for i in channel_indices if i is not None]}
    known |= {i for i in sigma_indices if i is not None}
    extra = [columns[i] for i in range(len(columns)) if i not in known]
    if extra:
        raise InputError(
            f"unknown column(s) {', '.join(extra)}; allowed: pixel|wavelength_nm, r, g, b, "
            "r_sigma, g_sigma, b_sigma",
            source=where,
        )
    rows = table.rows
    bad = ~np.isfinite(rows)
    if bad.any():
        row, column = (int(v) for v in np.argwhere(bad)[0])
        raise InputError(
            f"row {row + 1} column {columns[column]!r} is not a finite number (NaN or infinite)",
            source=where,
        )
    if rows.shape[0] < 8:
        raise InputError(f"only {rows.shape[0]} rows; a profile needs at least 8", source=where)
    order = np.argsort(rows[:, 0], kind="stable")
    rows = rows[order]
    axis = rows[:, 0]
    if not np.all(np.diff(axis) > 0):
        repeated = float(axis[np.flatnonzero(np.diff(axis) <= 0)[0]])
        raise InputError(f"position {repeated:g} appears twice in {columns[0]!r}", source=where)
    profile = rows[:, [i for i in channel_indices if i is not None]]
    sigma = None
    if sigma_indices[0] is not None:
        sigma = rows[:, [i for i in sigma_indices if i is not None]]
        if np.any(sigma <= 0):
            raise InputError("sigma columns must be > 0 everywhere", source=where)
    in_wavelength = wavelength_index is not None
    if in_wavelength and (axis[0] < 100 or axis[-1] > 3000):
        raise InputError(
            f"wavelengths run from {axis[0]:g} to {axis[-1]:g}: is the first column in nm?",
            source=where,
        )
    return ProfileTable(axis, profile, sigma, in_wavelength)


#: Profile file suffixes of the other readers than the CSV one: what a file that cannot be opened
#: is taken for (the reader then says why); a readable file is known by its first bytes.
RAWPROC_SUFFIXES = (".dat",)
FITS_SUFFIXES = (".fit", ".fits", ".fts")
ProfileFormat = Literal["csv", "rawproc", "fits"]


def profile_format(path: Path) -> ProfileFormat:
    """Which reader a profile file needs, from what it holds: FITS when its first card is
    ``SIMPLE  =`` (the standard's), a rawproc export when its first line is ``width:`` or it is
    named ``.dat``, else CSV. A file that cannot be opened goes by its suffix."""
    suffix = path.suffix.lower()
    try:
        with path.open("rb") as stream:
            head = stream.read(80)
    except OSError:
        if suffix in FITS_SUFFIXES:
            return "fits"
        return "rawproc" if suffix in RAWPROC_SUFFIXES else "csv"
    if head.startswith(b"SIMPLE  ="):
        return "fits"
    if suffix in RAWPROC_SUFFIXES or head.lstrip().lower().startswith(b"width:"):
        return "rawproc"
    return "csv"


def read_profile_file(profile: Path | tuple[Path, ...]) -> ProfileTable:
    """A lamp's 1-D profile from the file(s) a user has: CSV, rawproc ``.dat``, a FITS cube, or
    the R, G and B planes as three FITS files, each known by what it holds
    (:func:`profile_format`), whatever its name.

    The CSV is read by :func:`read_profile_csv`; a rawproc export by
    :func:`calib.image.profile_files.read_rawproc_dat` (its own pixel axis in the file's column
    order; its command read: non-linear or channel-mixing operations refused, stated white-balance
    multipliers divided out, unstated ones reported in ``channel_gains_unknown``);
    FITS planes by :func:`calib.image.profile_files.read_fits_profile` (the spectrum's band found
    in the planes, dispersion along x; ``image_planes`` set). The result is in pixels, with the σ
    the reader could give.

    Raises
    ------
    InputError
        What the reader of that format refuses (the file and the line or keyword named); several
        files that are not three FITS planes; a profile with no value above zero (a blank export:
        the solve has nothing to fit).
    """
    files = profile_files(profile)
    where = describe_profile(profile)
    formats = [profile_format(Path(path)) for path in files]
    if len(files) > 1 and (len(files) != 3 or set(formats) != {"fits"}):
        not_fits = [str(path) for path, kind in zip(files, formats, strict=True) if kind != "fits"]
        raise InputError(
            f"{len(files)} files: a profile is one file (CSV, rawproc .dat, a FITS cube), or "
            "the R, G and B planes of a FITS export as three files, in that order"
            + (f" ({', '.join(not_fits)}: not FITS)" if len(files) == 3 else ""),
            source=where,
        )
    if formats[0] == "csv":
        table = read_profile_csv(files[0])
    else:
        read = read_rawproc_dat(files[0]) if formats[0] == "rawproc" else read_fits_profile(files)
        table = ProfileTable(
            read.pixel,
            read.profile,
            read.profile_sigma,
            in_wavelength=False,
            channel_gains_unknown=read.channel_gains_unknown,
            image_planes=read.image_planes,
            metadata=read.metadata,
            warnings=read.warnings,
            notes=read.notes,
        )
    if not np.any(table.profile > 0):
        raise InputError(
            "no value above zero in r, g or b: the profile holds no light; export it from the "
            "frames where the first-order band is lit (lamp on, band inside the crop)",
            source=where,
        )
    return table


def parse_direct(text: str, source: str = "--direct") -> tuple[float, float, float]:
    """``"R,G,B"`` → three finite numbers ≥ 0, not all zero."""
    parts = [part.strip() for part in text.split(",")]
    try:
        values = tuple(float(part) for part in parts)
    except ValueError:
        raise InputError(f"expected three numbers R,G,B, got {text!r}", source=source) from None
    if len(values) != 3:
        raise InputError(f"expected three numbers R,G,B, got {len(values)}", source=source)
    if not all(math.isfinite(v) and v >= 0 for v in values) or not any(values):
        raise InputError(
            f"direct RGB must be finite, ≥ 0 and not all zero, got {text!r}", source=source
        )
    return (values[0], values[1], values[2])
