"""A grating's first-order efficiency η(λ) as a small JSON file, to reuse a calibration later.

An estimate with a direct (0th-order) measurement finds η along with the camera; a later estimate of a
camera seen through the same grating, but with no direct measurement (a 1-D profile from a DIY
spectroscope, a line-scan tool), needs η given. ``calib estimate`` writes ``grating.json`` next to its
results, and reads one with ``--grating FILE``.

Format (``format_version`` 2; version 1 files — without ``geometry.rig`` — are read as before)::

    {
      "schema": "spectral-rig/grating-efficiency",
      "format_version": 2,
      "wavelength_nm": [400.0, 410.0, …],          strictly increasing, nm
      "efficiency": [0.81, 0.84, …],               relative (maximum 1), finite, ≥ 0
      "efficiency_sigma": [0.01, …] | null,        standard deviation on the same scale
      "geometry": {                                how it was measured (all optional)
        "mapping": {…} | null,                     pixel → wavelength (calib.core.mapping to_dict)
        "diffraction": {…} | null,                 spot/band geometry (calib.image.profiles to_dict)
        "order": 1,                                the diffraction order
        "description": "…",                        free text (incidence angle, sheet, …)
        "rig": {                                   the rig it was measured in (version 2, optional)
          "grating": {…},                          the fitted grating through the lens
                                                   (calib.core.mapping.TiltedGrating to_dict)
          "optics": {"camera", "focal_length_mm", "pixel_pitch_um", "axis_offset_px",
                     "order_angle_deg", "band_distance_px", "side", …},
          "grooves_per_mm": 600 | null             the sheet's nominal density, when configured
        } | null
      },
      "provenance": {"created": "…", "software": "…", "method": "…", "source": "…", …},
      "obtained": "estimated",                     how η was obtained (OBTAINED_KINDS)
      "model": {"model": "sinusoidal",             the grating model, when a physical one was
                "parameters": {…}, …} | null,      fitted (its parameters with σ)
      "zeroth_order_efficiency": [0.62, …] | null, η₀ on the same wavelengths (absolute fraction)
      "zeroth_order_efficiency_sigma": [...] | null
    }

``obtained`` says what the curve is worth: ``"estimated"`` (from lamps' direct measurements),
``"measured"`` (the spectrometer in the 0th- and 1st-order beams, ``rig``'s ``measure-grating``
step), ``"maker's curve"`` (a catalogue), ``"assumed flat"`` (no information at all: an
estimate without a direct measurement saves the flat curve it assumed) or ``"assumed physical"``
(the same estimate through η marginalised over the physical families, decision 0074). Reusing an
assumed file warns (:func:`reuse_warnings`); a file without the key (written before it existed) counts as
``"estimated"`` and says so.

Unknown keys are kept in ``provenance``/``geometry`` and otherwise ignored, so later versions can add
fields without breaking readers; a larger ``format_version`` is refused.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import Spectrum, WavelengthGrid, read_spectrum_csv

GRATING_SCHEMA = "spectral-rig/grating-efficiency"
GRATING_FORMAT_VERSION = 2

__all__ = [
    "GRATING_FORMAT_VERSION",
    "GRATING_SCHEMA",
    "MAKER_CURVE_SUFFIXES",
    "OBTAINED_KINDS",
    "GratingEfficiency",
    "GratingFileError",
    "read_grating_file",
    "read_maker_curve",
    "reuse_warnings",
    "write_grating_file",
]


#: How a grating file's η was obtained (the file's ``obtained``).
OBTAINED_KINDS: tuple[str, ...] = (
    "estimated",
    "measured",
    "maker's curve",
    "assumed flat",
    "assumed physical",
)


class GratingFileError(InputError):
    """A grating file is missing, not JSON, or does not follow the schema (the field is named)."""


def _array(values: Any, field_name: str, source: str) -> FloatArray:
    try:
        array = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise GratingFileError(
            f"{field_name} must be a list of numbers", source=f"{source}: {field_name}"
        ) from None
    if array.ndim != 1:
        raise GratingFileError(
            f"{field_name} must be a flat list of numbers, got shape {array.shape}",
            source=f"{source}: {field_name}",
        )
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise GratingFileError(
            f"entry {bad} is not a finite number (NaN, infinity or null)",
            source=f"{source}: {field_name}",
        )
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class GratingEfficiency:
    """Relative first-order efficiency of a grating, with its uncertainty and provenance.

    Parameters
    ----------
    wavelength_nm
        Shape ``(n,)``, strictly increasing (nm), ``n ≥ 2``.
    efficiency
        Shape ``(n,)``: relative efficiency, finite and ≥ 0 (any scale; only its shape matters).
    efficiency_sigma
        Shape ``(n,)``: standard deviation on the same scale, or ``None``.
    geometry
        How it was measured (see the module docstring); JSON data.
    provenance
        Who made it, when, from what; JSON data.
    source
        Where it was read from (for messages).
    obtained
        How η was obtained (:data:`OBTAINED_KINDS`).
    model
        The grating model's record when a physical one was fitted (``model``, ``parameters``
        with σ), else ``None``.
    zeroth_order_efficiency, zeroth_order_efficiency_sigma
        ``η₀`` and its σ on ``wavelength_nm`` (absolute fractions), when known.
    """

    wavelength_nm: FloatArray
    efficiency: FloatArray
    efficiency_sigma: FloatArray | None = None
    geometry: Mapping[str, Any] = field(default_factory=dict)
    provenance: Mapping[str, Any] = field(default_factory=dict)
    source: str = "grating efficiency"
    obtained: str = "estimated"
    model: Mapping[str, Any] | None = None
    zeroth_order_efficiency: FloatArray | None = None
    zeroth_order_efficiency_sigma: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.obtained not in OBTAINED_KINDS:
            raise GratingFileError(
                f"{self.obtained!r} is not one of {', '.join(OBTAINED_KINDS)}",
                source=f"{self.source}: obtained",
            )
        wavelength = _array(self.wavelength_nm, "wavelength_nm", self.source)
        efficiency = _array(self.efficiency, "efficiency", self.source)
        if wavelength.size < 2:
            raise GratingFileError(
                "needs at least two wavelengths", source=f"{self.source}: wavelength_nm"
            )
        if not np.all(np.diff(wavelength) > 0):
            raise GratingFileError(
                "wavelengths must be strictly increasing", source=f"{self.source}: wavelength_nm"
            )
        if efficiency.shape != wavelength.shape:
            raise GratingFileError(
                f"{efficiency.size} values for {wavelength.size} wavelengths",
                source=f"{self.source}: efficiency",
            )
        if np.any(efficiency < 0) or not np.any(efficiency > 0):
            raise GratingFileError(
                "efficiencies must be ≥ 0 and not all zero", source=f"{self.source}: efficiency"
            )
        object.__setattr__(self, "wavelength_nm", wavelength)
        object.__setattr__(self, "efficiency", efficiency)
        if self.efficiency_sigma is not None:
            sigma = _array(self.efficiency_sigma, "efficiency_sigma", self.source)
            if sigma.shape != wavelength.shape or np.any(sigma < 0):
                raise GratingFileError(
                    f"needs {wavelength.size} values ≥ 0, one per wavelength",
                    source=f"{self.source}: efficiency_sigma",
                )
            object.__setattr__(self, "efficiency_sigma", sigma)
        for name in ("zeroth_order_efficiency", "zeroth_order_efficiency_sigma"):
            values = getattr(self, name)
            if values is None:
                continue
            array = _array(values, name, self.source)
            if array.shape != wavelength.shape or np.any(array < 0):
                raise GratingFileError(
                    f"needs {wavelength.size} values ≥ 0, one per wavelength",
                    source=f"{self.source}: {name}",
                )
            object.__setattr__(self, name, array)

    @property
    def rig(self) -> Mapping[str, Any] | None:
        """The rig it was measured in (``geometry.rig``, format version 2), or ``None``."""
        rig = self.geometry.get("rig")
        return rig if isinstance(rig, Mapping) else None

    @property
    def range_nm(self) -> tuple[float, float]:
        return float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])

    def covers(self, grid: WavelengthGrid) -> bool:
        """Whether the efficiency is known over the whole working grid."""
        lo, hi = self.range_nm
        return lo <= grid.start_nm + 1e-6 and hi >= grid.stop_nm - 1e-6

    def at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """Linear interpolation at ``wavelength_nm`` (the end values beyond the range)."""
        return np.interp(
            np.asarray(wavelength_nm, dtype=np.float64), self.wavelength_nm, self.efficiency
        )

    def sigma_at(self, wavelength_nm: ArrayLike) -> FloatArray | None:
        """Linear interpolation of the standard deviation, or ``None`` when unknown."""
        if self.efficiency_sigma is None:
            return None
        return np.interp(
            np.asarray(wavelength_nm, dtype=np.float64), self.wavelength_nm, self.efficiency_sigma
        )

    def spectrum(self) -> Spectrum:
        """The efficiency as a :class:`calib.core.spectra.Spectrum` (maximum 1)."""
        return Spectrum(
            self.wavelength_nm, self.efficiency / float(self.efficiency.max()), name=self.source
        )

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (see the module docstring)."""
        peak = float(self.efficiency.max())
        return {
            "schema": GRATING_SCHEMA,
            "format_version": GRATING_FORMAT_VERSION,
            "wavelength_nm": self.wavelength_nm.tolist(),
            "efficiency": (self.efficiency / peak).tolist(),
            "efficiency_sigma": None
            if self.efficiency_sigma is None
            else (self.efficiency_sigma / peak).tolist(),
            "geometry": dict(self.geometry),
            "provenance": dict(self.provenance),
            "obtained": self.obtained,
            "model": None if self.model is None else dict(self.model),
            "zeroth_order_efficiency": _listed(self.zeroth_order_efficiency),
            "zeroth_order_efficiency_sigma": _listed(self.zeroth_order_efficiency_sigma),
        }

    @classmethod
    def from_dict(cls, data: Any, *, source: str = "grating file") -> GratingEfficiency:
        """Validate a parsed document.

        Raises
        ------
        GratingFileError
            Not an object, a different schema, a newer format version, or a missing or malformed
            field (named in the message).
        """
        if not isinstance(data, Mapping):
            raise GratingFileError(
                f"expected a JSON object, got {type(data).__name__}", source=source
            )
        schema = data.get("schema")
        if schema != GRATING_SCHEMA:
            raise GratingFileError(
                f"schema is {schema!r}, expected {GRATING_SCHEMA!r} (is this a grating file "
                "written by calib estimate?)",
                source=f"{source}: schema",
            )
        version = data.get("format_version")
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise GratingFileError(
                f"format_version must be a positive integer, got {version!r}",
                source=f"{source}: format_version",
            )
        if version > GRATING_FORMAT_VERSION:
            raise GratingFileError(
                f"format version {version} is newer than this software reads "
                f"({GRATING_FORMAT_VERSION}); update spectral-rig",
                source=f"{source}: format_version",
            )
        for required in ("wavelength_nm", "efficiency"):
            if required not in data:
                raise GratingFileError("missing", source=f"{source}: {required}")
        for optional in ("geometry", "provenance", "model"):
            value = data.get(optional)
            if value is not None and not isinstance(value, Mapping):
                raise GratingFileError(
                    f"must be an object, got {type(value).__name__}", source=f"{source}: {optional}"
                )
        rig = (data.get("geometry") or {}).get("rig")
        if rig is not None:
            _check_rig(rig, f"{source}: geometry.rig")
        return cls(
            wavelength_nm=data["wavelength_nm"],
            efficiency=data["efficiency"],
            efficiency_sigma=data.get("efficiency_sigma"),
            geometry=dict(data.get("geometry") or {}),
            provenance=dict(data.get("provenance") or {}),
            source=source,
            obtained=str(data.get("obtained", "estimated")),
            model=None if data.get("model") is None else dict(data["model"]),
            zeroth_order_efficiency=data.get("zeroth_order_efficiency"),
            zeroth_order_efficiency_sigma=data.get("zeroth_order_efficiency_sigma"),
        )

    def reuse_warnings(self) -> list[str]:
        """:func:`reuse_warnings` of this file."""
        return reuse_warnings(self)


def _listed(values: FloatArray | None) -> list[float] | None:
    return None if values is None else np.asarray(values, dtype=np.float64).tolist()


def reuse_warnings(grating: GratingEfficiency) -> list[str]:
    """What a user reusing ``grating`` as a calibration must hear (empty when nothing).

    An assumed-flat file carries no information about the grating: an estimate through it carries
    the grating's own spectral efficiency as an error.
    """
    if grating.obtained in ("assumed flat", "assumed physical"):
        what = (
            "a flat efficiency"
            if grating.obtained == "assumed flat"
            else ("an efficiency averaged over the physical grating families")
        )
        return [
            f"{grating.source}: this grating file holds {what} that was assumed, not "
            "measured; an estimate through it carries the grating's own efficiency as an error. "
            "Calibrate the grating with lamps measured directly (≥ 3 lamps, --method multilamp) "
            "or with the spectrometer (rig plan measure-grating)"
        ]
    return []


def _check_rig(rig: Any, where: str) -> None:
    """``geometry.rig`` must hold a grating record the mapping types read."""
    from calib.core.mapping import TiltedGrating

    if not isinstance(rig, Mapping):
        raise GratingFileError(f"must be an object, got {type(rig).__name__}", source=where)
    if "grating" not in rig:
        raise GratingFileError("missing", source=f"{where}.grating")
    try:
        TiltedGrating.from_dict(rig["grating"])
    except InputError as exc:
        raise GratingFileError(str(exc), source=f"{where}.grating") from None
    optics = rig.get("optics")
    if optics is not None and not isinstance(optics, Mapping):
        raise GratingFileError("must be an object", source=f"{where}.optics")


#: Suffixes of a grating file read as a maker's curve table rather than JSON.
MAKER_CURVE_SUFFIXES = (".csv", ".tsv", ".txt")


def read_maker_curve(path: str | os.PathLike[str]) -> GratingEfficiency:
    """A maker's published efficiency curve as a table ``wavelength_nm,efficiency`` (any scale,
    e.g. per cent; header optional, as a spectrum CSV; small negative values of a measured curve
    set to zero): ``obtained = "maker's curve"``, no σ (the estimate then says the grating's
    error is not in σ, ``grating_sigma_missing``).

    Raises
    ------
    InputError
        What the table reader refuses (file and line named); a curve with no value above zero.
    """
    file = Path(path)
    curve = read_spectrum_csv(file, name=file.name, negative="clip")
    peak = float(np.max(curve.values))
    if not peak > 0:
        raise GratingFileError("no efficiency above zero in the maker's curve", source=str(file))
    return GratingEfficiency(
        curve.wavelength_nm,
        curve.values / peak,
        provenance={"source": str(file), "method": "maker's curve"},
        source=str(file),
        obtained="maker's curve",
    )


def read_grating_file(path: str | os.PathLike[str]) -> GratingEfficiency:
    """Read and validate a grating efficiency file: the JSON an estimate writes, or a maker's
    curve as a table (:func:`read_maker_curve`, by its suffix: :data:`MAKER_CURVE_SUFFIXES`).

    Raises
    ------
    GratingFileError
        Missing or unreadable file, invalid JSON (with the line), or a schema violation.
    """
    file = Path(path)
    if file.suffix.lower() in MAKER_CURVE_SUFFIXES:
        return read_maker_curve(file)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GratingFileError("file not found", source=str(file)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GratingFileError(f"cannot read: {exc}", source=str(file)) from None
    try:
        data = json.loads(text, parse_constant=lambda name: math.nan)
    except json.JSONDecodeError as exc:
        raise GratingFileError(
            f"not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})", source=str(file)
        ) from None
    return GratingEfficiency.from_dict(data, source=str(file))


def write_grating_file(path: str | os.PathLike[str], grating: GratingEfficiency) -> Path:
    """Write ``grating`` as JSON (efficiency normalised to a maximum of 1); returns the path.

    Written to a temporary file beside ``path`` and renamed over it: a reader never sees half a
    file, and an interrupted write leaves an earlier file as it was.
    """
    file = Path(path)
    text = json.dumps(grating.to_dict(), indent=2, allow_nan=False) + "\n"
    temporary = file.with_name(f".{file.name}.{os.getpid()}.tmp")
    try:
        temporary.write_text(text)
        temporary.replace(file)
    finally:
        temporary.unlink(missing_ok=True)
    return file
