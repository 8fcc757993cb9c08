"""ArgyllCMS spectrum files (``.sp``): CGATS text whose file type is ``SPECT``.

What ``spotread -O reading.sp`` writes (``xicc/xspect.c`` ``write_xspect``), and what ArgyllCMS reads
as a custom illuminant: a first line naming the type (``SPECT``), keyword lines (``KEYWORD "NAME"``
declares one, ``NAME "value"`` sets it), the band layout in ``SPECTRAL_BANDS``,
``SPECTRAL_START_NM``, ``SPECTRAL_END_NM`` (bands evenly spaced, both ends included) and
``SPECTRAL_NORM`` (the value of 1.0), a ``BEGIN_DATA_FORMAT`` … ``END_DATA_FORMAT`` block naming the
fields (``SPEC_380`` …, the nearest whole nanometre of each band) and one ``BEGIN_DATA`` …
``END_DATA`` block with one line per spectrum. ``MEAS_TYPE`` says what was measured (``AMBIENT``:
irradiance in mW/(m²·nm), ``EMISSION``: radiance in mW/(m²·sr·nm)).

The parser is strict: a file that does not say ``SPECT``, lacks a band keyword, names a field count
other than the band count or holds a value that is not a number is refused with a message naming
the line.
"""

from __future__ import annotations

import math
import re
import shlex
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["CgatsError", "SpectrumFile", "parse_sp", "units_of"]

_SPEC_FIELD = re.compile(r"^SPEC_(\d+)$")
_UNITS = {
    "AMBIENT": "mW/(m²·nm)",
    "AMBIENT_FLASH": "mW·s/(m²·nm)",
    "EMISSION": "mW/(m²·sr·nm)",
    "EMISSION_FLASH": "mW·s/(m²·sr·nm)",
    "REFLECTIVE": "reflectance",
    "TRANSMISSIVE": "transmittance",
}


class CgatsError(ValueError):
    """Not a spectrum file ArgyllCMS writes; the message names the line and what is wrong."""


@dataclass(frozen=True, eq=False)
class SpectrumFile:
    """The spectra of a ``.sp`` file.

    Attributes
    ----------
    wavelength_nm
        Shape ``(n_bands,)``, the band centres.
    values
        Shape ``(n_spectra, n_bands)``, divided by ``SPECTRAL_NORM``.
    keywords
        Every keyword and its value (``MEAS_TYPE``, ``CREATED`` …).
    """

    wavelength_nm: NDArray[np.float64]
    values: NDArray[np.float64]
    keywords: dict[str, str] = field(default_factory=dict)

    @property
    def measurement_type(self) -> str | None:
        """``AMBIENT``, ``EMISSION`` … (``None`` when the file does not say)."""
        return self.keywords.get("MEAS_TYPE")

    @property
    def step_nm(self) -> float:
        """The band spacing."""
        return float(self.wavelength_nm[1] - self.wavelength_nm[0])


def units_of(measurement_type: str | None) -> str:
    """The unit of a ``.sp`` file's values by its ``MEAS_TYPE`` (``relative`` when unknown).

    >>> units_of("AMBIENT")
    'mW/(m²·nm)'
    """
    return _UNITS.get(measurement_type or "", "relative spectral power")


def _number(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CgatsError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise CgatsError(f"{where}: {text!r} is not a finite number")
    return value


def parse_sp(text: str, source: str = "<spectrum file>") -> SpectrumFile:
    """Parse the text of an ArgyllCMS ``.sp`` file.

    Raises
    ------
    CgatsError
        Not a ``SPECT`` file, a missing or inconsistent band layout, no data, a bad number.

    Examples
    --------
    >>> text = '''SPECT
    ... KEYWORD "SPECTRAL_BANDS"
    ... SPECTRAL_BANDS "3"
    ... KEYWORD "SPECTRAL_START_NM"
    ... SPECTRAL_START_NM "400.000000"
    ... KEYWORD "SPECTRAL_END_NM"
    ... SPECTRAL_END_NM "420.000000"
    ... KEYWORD "SPECTRAL_NORM"
    ... SPECTRAL_NORM "1.000000"
    ... NUMBER_OF_FIELDS 3
    ... BEGIN_DATA_FORMAT
    ... SPEC_400 SPEC_410 SPEC_420
    ... END_DATA_FORMAT
    ... NUMBER_OF_SETS 1
    ... BEGIN_DATA
    ... 1.5 2.5 3.5
    ... END_DATA
    ... '''
    >>> spectrum = parse_sp(text)
    >>> spectrum.wavelength_nm.tolist(), spectrum.values.tolist()
    ([400.0, 410.0, 420.0], [[1.5, 2.5, 3.5]])
    """
    lines = [
        (number, line.strip())
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines or lines[0][1].split()[0] not in ("SPECT", "CMF"):
        raise CgatsError(f"{source}: not an ArgyllCMS spectrum file (the first line is not SPECT)")
    keywords: dict[str, str] = {}
    fields: list[str] = []
    rows: list[list[float]] = []
    block: str | None = None
    for number, line in lines[1:]:
        where = f"{source} line {number}"
        if line in ("BEGIN_DATA_FORMAT", "BEGIN_DATA"):
            block = line
            continue
        if line in ("END_DATA_FORMAT", "END_DATA"):
            block = None
            continue
        if block == "BEGIN_DATA_FORMAT":
            fields.extend(line.split())
            continue
        if block == "BEGIN_DATA":
            rows.append([_number(value, where) for value in line.split()])
            continue
        try:
            parts = shlex.split(line)
        except ValueError as exc:
            raise CgatsError(f"{where}: {exc}") from None
        if len(parts) >= 2 and parts[0] != "KEYWORD":
            keywords[parts[0]] = " ".join(parts[1:])
    layout = {}
    for name in ("SPECTRAL_BANDS", "SPECTRAL_START_NM", "SPECTRAL_END_NM"):
        if name not in keywords:
            raise CgatsError(f"{source}: no {name} keyword")
        layout[name] = _number(keywords[name], f"{source} {name}")
    bands = int(layout["SPECTRAL_BANDS"])
    start, end = layout["SPECTRAL_START_NM"], layout["SPECTRAL_END_NM"]
    if bands < 2 or not end > start:
        raise CgatsError(f"{source}: {bands} bands from {start:g} to {end:g} nm is not a spectrum")
    norm = _number(keywords.get("SPECTRAL_NORM", "1"), f"{source} SPECTRAL_NORM")
    if norm <= 0:
        raise CgatsError(f"{source}: SPECTRAL_NORM must be > 0, got {norm:g}")
    spectral = [name for name in fields if _SPEC_FIELD.match(name)]
    if len(spectral) != bands:
        raise CgatsError(f"{source}: {len(spectral)} SPEC_ fields but SPECTRAL_BANDS is {bands}")
    if not rows:
        raise CgatsError(f"{source}: no data (BEGIN_DATA … END_DATA is empty or missing)")
    columns = [fields.index(name) for name in spectral]
    width = len(fields)
    for index, row in enumerate(rows, start=1):
        if len(row) != width:
            raise CgatsError(
                f"{source}: data row {index} has {len(row)} values, the format names {width}"
            )
    values = np.array([[row[k] for k in columns] for row in rows], dtype=np.float64) / norm
    wavelength = np.linspace(start, end, bands)
    return SpectrumFile(wavelength, values, keywords)
