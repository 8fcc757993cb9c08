"""AMPAS spectral-data JSON (schema 1.0.0): the camera files rawtoaces reads.

What rawtoaces requires of a camera file, each rule checked before a file is written
(:func:`check_rawtoaces_camera`):

* the document validates against ``schema/spectral_1.0.0.json`` (bundled from rawtoaces-data,
  Apache-2.0): ``schema_version``, ``description``, ``document_creation_date`` (RFC 3339),
  ``document_creator`` and ``license`` non-empty;
* exactly 81 rows at 380–780 nm in 5 nm steps under ``spectral_data.data.main`` (rawtoaces 1.x exits
  on anything else) and no other data set: rawtoaces 2.x reads every set with one running
  wavelength counter, so a second set (e.g. a σ) breaks its step check;
* ``spectral_data.index.main == ["R", "G", "B"]`` (its solver asks for the channels by these names);
* ``header.manufacturer`` / ``header.model`` as LibRaw names the camera (``Nikon`` / ``D5100``),
  after the remaps of rawtoaces-data's ``aliases.json`` (:func:`rawtoaces_names`); the repository
  names the file ``<Make>_<Model>_380_780_5.json`` with spaces as underscores
  (:func:`camera_file_name`).

The 52 cameras of rawtoaces-data (bundled) are the examples of well-formed files
(:func:`reference_cameras`).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from datetime import datetime
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.camera_curves import CHANNEL_LABELS, CameraCurves, channel_order
from calib.core.errors import InputError
from calib.core.formats.json_file import read_json
from calib.core.spectra import WavelengthGrid

#: The bundled copy of rawtoaces-data (LICENSE, NOTICE, SOURCE_COMMIT beside the files).
RAWTOACES_DATA = Path(__file__).resolve().parents[1] / "data" / "rawtoaces-data"
AMPAS_SCHEMA_VERSION = "1.0.0"
SCHEMA_FILE = RAWTOACES_DATA / "schema" / f"spectral_{AMPAS_SCHEMA_VERSION}.json"
ALIASES_FILE = RAWTOACES_DATA / "data" / "aliases.json"
CAMERA_DIR = RAWTOACES_DATA / "data" / "camera"
#: The only wavelength grid rawtoaces accepts for a camera.
RAWTOACES_GRID = WavelengthGrid(380.0, 780.0, 5.0)


class AmpasFormatError(InputError):
    """A document that is not a camera file rawtoaces would read (the message says which rule)."""


@dataclass(frozen=True)
class AmpasHeader:
    """The ``header`` of a camera file (schema 1.0.0 names)."""

    manufacturer: str | None
    model: str | None
    description: str
    document_creator: str
    document_creation_date: str
    license: str
    comments: str | None = None
    measurement_equipment: str | None = None
    laboratory: str | None = None
    unique_identifier: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema_version": AMPAS_SCHEMA_VERSION,
            "manufacturer": self.manufacturer,
            "model": self.model,
            "description": self.description,
            "document_creator": self.document_creator,
            "unique_identifier": self.unique_identifier,
            "measurement_equipment": self.measurement_equipment,
            "laboratory": self.laboratory,
            "document_creation_date": self.document_creation_date,
            "comments": self.comments,
            "license": self.license,
        }


@dataclass(frozen=True)
class AmpasCamera:
    """A camera file read back: its curves and header (``schema_version`` as found)."""

    curves: CameraCurves
    header: dict[str, Any]
    schema_version: str | None


@cache
def _schema() -> dict[str, Any]:
    schema: dict[str, Any] = json.loads(SCHEMA_FILE.read_text(encoding="utf-8"))
    return schema


def _wavelength_key(wavelength_nm: float) -> str:
    return str(round(wavelength_nm)) if float(wavelength_nm).is_integer() else repr(wavelength_nm)


def schema_errors(document: Any) -> list[str]:
    """Every violation of the spectral 1.0.0 schema, as ``path: message`` (empty when valid).

    The ``date-time`` format is checked too (RFC 3339 ``YYYY-MM-DDTHH:MM:SSZ`` or with an offset).
    """
    import jsonschema

    validator = jsonschema.Draft4Validator(_schema())
    problems = [
        f"{'/'.join(str(p) for p in error.absolute_path) or '(document)'}: {error.message}"
        for error in validator.iter_errors(document)
    ]
    header = document.get("header") if isinstance(document, dict) else None
    date = header.get("document_creation_date") if isinstance(header, dict) else None
    if isinstance(date, str) and not _is_rfc3339(date):
        problems.append(f"header/document_creation_date: {date!r} is not an RFC 3339 date-time")
    return problems


def _is_rfc3339(text: str) -> bool:
    if not re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?(Z|[+-]\d\d:\d\d)", text):
        return False
    try:
        datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return False
    return True


def rawtoaces_problems(document: Any) -> list[str]:
    """Where ``document`` breaks rawtoaces' own loading rules for a camera (beyond the schema)."""
    problems: list[str] = []
    try:
        spectral = document["spectral_data"]
        index, data = spectral["index"], spectral["data"]
    except (KeyError, TypeError):
        return ["spectral_data.index / spectral_data.data missing"]
    if set(data) != {"main"} or set(index) != {"main"}:
        problems.append(
            f"data sets {sorted(data)} (index {sorted(index)}): rawtoaces reads one set, 'main'"
        )
    if index.get("main") != list(CHANNEL_LABELS):
        problems.append(f"index.main is {index.get('main')!r}, rawtoaces asks for R, G, B")
    main = data.get("main")
    if not isinstance(main, dict):
        return [*problems, "data.main is not an object of wavelength → [R, G, B]"]
    expected = [_wavelength_key(w) for w in RAWTOACES_GRID.wavelength_nm]
    if list(main) != expected:
        problems.append(
            f"{len(main)} rows from {next(iter(main), '?')} to {list(main)[-1] if main else '?'} "
            "nm: rawtoaces needs exactly 81 rows at 380–780 nm in 5 nm steps"
        )
    bad = [
        key
        for key, row in main.items()
        if not (
            isinstance(row, list)
            and len(row) == 3
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in row)
            and all(math.isfinite(float(v)) for v in row)
        )
    ]
    if bad:
        problems.append(f"rows {', '.join(bad[:3])}: each row must be three finite numbers")
    return problems


def check_rawtoaces_camera(document: Any, source: str) -> None:
    """Raise :class:`AmpasFormatError` unless ``document`` validates and rawtoaces would load it."""
    problems = schema_errors(document) + rawtoaces_problems(document)
    if problems:
        raise AmpasFormatError(
            f"not a valid rawtoaces camera file: {problems[0]}"
            + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""),
            source=source,
        )


def camera_document(curves: CameraCurves, header: AmpasHeader) -> dict[str, Any]:
    """The camera file's JSON document (``curves`` must be on 380–780/5 nm; σ is not written)."""
    if not curves.is_on(RAWTOACES_GRID):
        raise AmpasFormatError(
            f"the curves run {curves.range_nm[0]:g}–{curves.range_nm[1]:g} nm on "
            f"{curves.wavelength_nm.size} wavelengths; rawtoaces needs 380–780 nm at 5 nm "
            "(extend them with calib.model.extension first)",
            source=curves.name,
        )
    return {
        "header": header.to_dict(),
        "spectral_data": {
            "units": "relative",
            "reflection_geometry": None,
            "transmission_geometry": None,
            "bandwidth_FWHM": None,
            "bandwidth_corrected": None,
            "index": {"main": list(CHANNEL_LABELS)},
            "data": {
                "main": {
                    _wavelength_key(float(w)): [float(v) for v in row]
                    for w, row in zip(curves.wavelength_nm, curves.values, strict=True)
                }
            },
        },
    }


def write_camera_json(path: Path, curves: CameraCurves, header: AmpasHeader) -> Path:
    """Write :func:`camera_document` after checking it (:func:`check_rawtoaces_camera`)."""
    document = camera_document(curves, header)
    check_rawtoaces_camera(document, str(path))
    path.write_text(json.dumps(document, indent=4, allow_nan=False) + "\n", encoding="utf-8")
    return path


def read_camera_json(path: str | Path) -> AmpasCamera:
    """Read an AMPAS camera file (schema 0.1.0 or 1.0.0): R, G, B by the index's labels.

    Raises
    ------
    AmpasFormatError
        Not JSON, no ``spectral_data.data.main``, rows that are not three numbers, labels that do
        not name R, G, B (the file is named).
    """
    path = Path(path)
    document = read_json(path, error=AmpasFormatError)
    try:
        main = document["spectral_data"]["data"]["main"]
        labels = document["spectral_data"].get("index", {}).get("main", list(CHANNEL_LABELS))
        items = sorted((float(key), [float(v) for v in row]) for key, row in main.items())
    except (KeyError, TypeError, ValueError, AttributeError):
        raise AmpasFormatError(
            "not an AMPAS camera file: expected spectral_data.data.main = {nm: [R, G, B]}",
            source=str(path),
        ) from None
    header = document.get("header") if isinstance(document.get("header"), dict) else {}
    name = " ".join(str(header.get(k) or "") for k in ("manufacturer", "model")).strip()
    values = np.array([row for _, row in items], dtype=np.float64)
    if values.ndim != 2 or values.shape[1] != 3:
        raise AmpasFormatError(
            f"each wavelength needs 3 values [R, G, B], got shape {values.shape}", source=str(path)
        )
    try:
        order = channel_order([str(label) for label in labels], str(path))
        curves = CameraCurves([nm for nm, _ in items], values[:, order], name=name or path.stem)
    except InputError as exc:
        raise AmpasFormatError(str(exc).removeprefix(f"{exc.source}: "), source=str(path)) from None
    return AmpasCamera(curves, dict(header), header.get("schema_version"))


# ------------------------------------------------------------------------------- names and files


@cache
def _aliases() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(ALIASES_FILE.read_text(encoding="utf-8"))
    camera: dict[str, Any] = data["data"]["camera"]
    return camera


def rawtoaces_names(make: str, model: str) -> tuple[str, str, str | None]:
    """``(make, model, why)`` after rawtoaces-data's ``aliases.json`` (case-insensitive keys).

    ``why`` is the alias' comment when a remap applied (``None`` otherwise): rawtoaces maps a RAW
    file's names this way before looking for a camera file, so a file must carry the mapped names
    to be found.

    Examples
    --------
    >>> rawtoaces_names("Nikon Corporation", "D800")
    ('Nikon', 'D800E', 'different model, same sensor')
    """
    aliases = _aliases()
    why: str | None = None
    makes = {key.lower(): value for key, value in aliases.get("make", {}).items()}
    if make.lower() in makes:
        make = str(makes[make.lower()])
        why = "make alias"
    for alias_make, models in aliases.get("model", {}).items():
        if alias_make.lower() != make.lower():
            continue
        for alias_model, target in models.items():
            if alias_model.lower() == model.lower():
                return str(target["make"]), str(target["model"]), str(target.get("comments", why))
    return make, model, why


def camera_file_name(make: str, model: str) -> str:
    """rawtoaces-data's name for a camera file: ``<Make>_<Model>_380_780_5.json``.

    Examples
    --------
    >>> camera_file_name("Canon", "EOS-1D X Mark II")
    'Canon_EOS-1D_X_Mark_II_380_780_5.json'
    """
    return f"{file_stem(make, model)}_380_780_5.json"


def file_stem(make: str, model: str) -> str:
    """``<Make>_<Model>`` with spaces as underscores and characters unsafe in file names dropped."""
    text = f"{make.strip()} {model.strip()}".strip()
    text = re.sub(r"[^\w.+\-]+", "_", text, flags=re.ASCII).strip("._")
    return text or "camera"


def reference_cameras() -> list[AmpasCamera]:
    """The 52 measured cameras of the bundled rawtoaces-data, sorted by file name."""
    return [read_camera_json(path) for path in sorted(CAMERA_DIR.glob("*.json"))]
