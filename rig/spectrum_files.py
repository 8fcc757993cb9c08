"""Measured spectrum files as the spectrometer of a capture (``devices.spectrometer.kind: files``).

The device is :class:`drivers.spectrometer.files.FilesSpectrometer`; this module gives it its
reader, which lives in the rig because it uses ``calib``'s readers (``drivers`` import nothing of
the project), colour-science's among them (through ``calib.core.colour_data.spectral_file``):

============  ======================================================================================
format        files
============  ======================================================================================
``argyll``    ArgyllCMS CGATS ``.sp`` (``spotread -s``, ``illumread``): :mod:`drivers.spectrometer.cgats`
``csv``       a ``wavelength_nm`` column and a value column (``column``, default the only other one),
              any delimiter; ``# units: …`` and ``# bandwidth_nm: …`` comment lines say what it holds
``ies``       IES TM-27-14 XML (``.spdx``): spectral quantity and bandwidth (FWHM) from its header
``xrite``     X-Rite i1Profiler / ColorPort ``.txt`` exports (``column`` picks a sample)
``sekonic``   Sekonic C-7000/C-800 spectrometer CSV exports
``uprtek``    UPRtek MK350/MF250 exports
``auto``      by the file's suffix: ``.sp`` argyll, ``.spdx``/``.xml`` ies, a ``.txt`` holding
              ``BEGIN_DATA_FORMAT`` xrite, anything else csv
============  ======================================================================================

A file's own units and bandwidth win over the configuration's (``units``, ``bandwidth_nm``), which
stand for files that do not say. Values below zero (a spectrometer's noise in the dark) are set to
zero, as the rig does with every spectrum it records.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from calib.core.colour_data import spectral_file
from calib.core.errors import SpectrumError
from calib.core.spectra import csv_header, read_spectrum_csv
from drivers.base import RelayBoard, SpectrumReading, TranscriptSink
from drivers.spectrometer.cgats import CgatsError, parse_sp, units_of
from drivers.spectrometer.files import FilesSpectrometer, LampFile, SwitchedRelays
from rig.config import FilesSpectrometerConfig, LampConfig
from rig.config import SpectrumFileFormat as FileFormat

__all__ = ["FileFormat", "detect_format", "open_spectrum_files", "read_measured_spectrum"]

KnownFormat = Literal["argyll", "csv", "ies", "xrite", "sekonic", "uprtek"]


def detect_format(path: Path) -> KnownFormat:
    """The format of ``path`` by its suffix (and, for ``.txt``, its content)."""
    suffix = path.suffix.lower()
    if suffix == ".sp":
        return "argyll"
    if suffix in (".spdx", ".xml"):
        return "ies"
    if suffix == ".txt":
        try:
            head = path.read_text(encoding="latin-1")[:20000]
        except OSError:
            return "csv"
        if "BEGIN_DATA_FORMAT" in head:
            return "xrite"
    return "csv"


def _positive(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SpectrumError(f"{what} {text!r} is not a number") from None
    if not value > 0:
        raise SpectrumError(f"{what} must be > 0, got {text}")
    return value


def read_measured_spectrum(
    path: Path,
    *,
    file_format: FileFormat = "auto",
    column: str | None = None,
    units: str = "relative spectral power",
    bandwidth_nm: float | None = None,
) -> SpectrumReading:
    """One measured spectrum file as a reading.

    Raises
    ------
    calib.core.errors.SpectrumError
        Missing, unreadable, not in the format, no such column, bad header values (named).
    """
    chosen: KnownFormat = detect_format(path) if file_format == "auto" else file_format
    if not path.is_file():
        raise SpectrumError("file not found", source=str(path))
    if chosen == "argyll":
        try:
            parsed = parse_sp(path.read_text(encoding="latin-1"), str(path))
        except CgatsError as exc:
            raise SpectrumError(str(exc)) from None
        values = np.clip(parsed.values[-1], 0.0, None)
        file_units = parsed.measurement_type and units_of(parsed.measurement_type)
        return SpectrumReading(
            parsed.wavelength_nm, values, file_units or units, None, {}, bandwidth_nm
        )
    if chosen == "csv":
        header = csv_header(path)
        spectrum = read_spectrum_csv(path, column=column, negative="clip")
        bandwidth = header.get("bandwidth_nm") or header.get("bandwidth")
        return SpectrumReading(
            spectrum.wavelength_nm,
            spectrum.values,
            header.get("units", units),
            None,
            {},
            _positive(bandwidth, f"{path}: # bandwidth_nm") if bandwidth else bandwidth_nm,
        )
    read = spectral_file(path, chosen, column)
    return SpectrumReading(
        read.spectrum.wavelength_nm,
        read.spectrum.values,
        read.quantity or units,
        None,
        {},
        read.bandwidth_nm if read.bandwidth_nm is not None else bandwidth_nm,
    )


def open_spectrum_files(
    config: FilesSpectrometerConfig,
    lamps: list[LampConfig],
    relays: RelayBoard,
    transcript: TranscriptSink | None,
) -> tuple[FilesSpectrometer, SwitchedRelays]:
    """The files device of ``config`` watching ``relays`` (returned wrapped: use that board).

    Raises
    ------
    drivers.base.DeviceNotFound
        A lamp of ``lamps`` has no file, a file names no configured lamp, a file is missing or
        unreadable (every one named).
    """
    channels = {lamp.name: lamp.channel for lamp in lamps}
    switched = relays if isinstance(relays, SwitchedRelays) else SwitchedRelays(relays)
    files = [
        LampFile(name, channels[name], config.directory / file)
        for name, file in config.lamps.items()
        if name in channels
    ]

    def reader(path: Path) -> SpectrumReading:
        return read_measured_spectrum(
            path,
            file_format=config.format,
            column=config.column,
            units=config.units,
            bandwidth_nm=config.bandwidth_nm,
        )

    return FilesSpectrometer(config.directory, files, reader, switched, transcript), switched
