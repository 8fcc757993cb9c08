"""Capture metadata of RAW files: exposure time, ISO, aperture, camera, capture time.

The EXIF / DNG tags are read with exifread, which gives exact rationals (``1/250`` rather than LibRaw's
float32 ``0.004000000189989805``) and the camera's Make and Model, which rawpy does not expose. It
parses TIFF-based RAWs (DNG, CR2, NEF, ARW, ORF, RW2, PEF …) directly; for Fujifilm RAF the EXIF of the
embedded JPEG is read, and for Canon CR3 the TIFF structures in the ``CMT1`` (IFD0) and ``CMT2`` (EXIF)
boxes. What the tags do not give is taken from LibRaw (:func:`build_metadata`).
"""

from __future__ import annotations

import io
import math
import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, BinaryIO, Literal

import exifread

from calib.core.errors import InputError

ExposureSource = Literal["exif", "libraw", "override"]

_EXIF_EXPOSURE_KEYS = ("EXIF ExposureTime", "Image ExposureTime")
_EXIF_FNUMBER_KEYS = ("EXIF FNumber", "Image FNumber")
_EXIF_ISO_KEYS = (
    "EXIF ISOSpeedRatings",
    "EXIF PhotographicSensitivity",
    "EXIF RecommendedExposureIndex",
    "Image ISOSpeedRatings",
)
_EXIF_TIME_KEYS = ("EXIF DateTimeOriginal", "Image DateTimeOriginal", "Image DateTime")
_EXIF_FOCAL_KEYS = ("EXIF FocalLength", "Image FocalLength")
_EXIF_PLANE_RESOLUTION_KEYS = ("EXIF FocalPlaneXResolution", "Image FocalPlaneXResolution")
_EXIF_PLANE_UNIT_KEYS = ("EXIF FocalPlaneResolutionUnit", "Image FocalPlaneResolutionUnit")
#: EXIF FocalPlaneResolutionUnit → micrometres per unit (2 inch, 3 cm, 4 mm, 5 µm).
_PLANE_UNIT_UM = {1: 25400.0, 2: 25400.0, 3: 10000.0, 4: 1000.0, 5: 1.0}
_EXIF_UNIQUE_MODEL_KEYS = ("Image UniqueCameraModel", "Image Tag 0xC614")

#: Canon CR3: the metadata boxes live in this UUID box inside ``moov``.
_CR3_METADATA_UUID = bytes.fromhex("85c0b687820f11e08111f4ce462b6a48")
_RAF_MAGIC = b"FUJIFILMCCD-RAW"


@dataclass(frozen=True)
class RawMetadata:
    """What a RAW file says about its capture.

    Parameters
    ----------
    path
        The file.
    exposure_s
        Exposure time in seconds.
    exposure_source
        Where ``exposure_s`` came from: the EXIF/DNG tags, LibRaw, or the caller's override.
    iso
        ISO speed, or ``None`` when the file does not say.
    f_number
        Aperture (f-number), or ``None``.
    make, model
        Camera maker and model (IFD0 tags; DNG UniqueCameraModel when Make/Model are absent).
    capture_time
        DateTimeOriginal (or DateTime), or ``None``.
    focal_length_mm
        The lens' focal length (EXIF FocalLength), or ``None`` (a manual lens, a scan).
    pixel_pitch_um
        The sensor's photosite pitch from EXIF FocalPlaneXResolution and its unit, or ``None``
        (many bodies do not write it).
    """

    path: Path
    exposure_s: float
    exposure_source: ExposureSource
    iso: float | None
    f_number: float | None
    make: str | None
    model: str | None
    capture_time: datetime | None
    focal_length_mm: float | None = None
    pixel_pitch_um: float | None = None

    @property
    def camera(self) -> str:
        """``"Make Model"`` for messages, ``"unknown camera"`` when neither is known."""
        parts = [part for part in (self.make, self.model) if part]
        return " ".join(parts) if parts else "unknown camera"


def _exif_number(tags: Mapping[str, Any], keys: tuple[str, ...]) -> float | None:
    for key in keys:
        tag = tags.get(key)
        if tag is None:
            continue
        values = getattr(tag, "values", None)
        first: Any = values[0] if isinstance(values, list) and values else values
        try:
            number = float(first)
        except (TypeError, ValueError, ZeroDivisionError):
            continue
        if math.isfinite(number) and number > 0:
            return number
    return None


def _exif_text(tags: Mapping[str, Any], keys: tuple[str, ...]) -> str | None:
    for key in keys:
        tag = tags.get(key)
        if tag is None:
            continue
        values = getattr(tag, "values", tag)
        text = (values if isinstance(values, str) else str(values)).strip().strip("\0").strip()
        if text:
            return text
    return None


def _exif_time(tags: Mapping[str, Any]) -> datetime | None:
    text = _exif_text(tags, _EXIF_TIME_KEYS)
    if text is None:
        return None
    try:
        return datetime.strptime(text[:19], "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None


def _positive(value: float) -> float | None:
    return float(value) if math.isfinite(value) and value > 0 else None


def _libraw_time(value: datetime | None) -> datetime | None:
    if value is None or value.year <= 1970:  # LibRaw reports the epoch when the tag is absent
        return None
    return value


def build_metadata(
    path: Path,
    exif: Mapping[str, Any],
    libraw_other: Any | None,
    exposure_s: float | None,
) -> RawMetadata:
    if exposure_s is not None and not (math.isfinite(exposure_s) and exposure_s > 0):
        raise InputError(f"exposure override must be > 0 s, got {exposure_s}", source=str(path))
    exif_exposure = _exif_number(exif, _EXIF_EXPOSURE_KEYS)
    libraw_exposure = _positive(libraw_other.shutter_speed) if libraw_other is not None else None
    source: ExposureSource
    if exposure_s is not None:
        exposure, source = float(exposure_s), "override"
    elif exif_exposure is not None:
        exposure, source = exif_exposure, "exif"
    elif libraw_exposure is not None:
        exposure, source = libraw_exposure, "libraw"
    else:
        raise InputError(
            "no exposure time in the file's metadata (EXIF ExposureTime, LibRaw shutter speed); "
            "give it explicitly (exposure_s=…, or --exposure on the command line)",
            source=str(path),
        )
    iso = _exif_number(exif, _EXIF_ISO_KEYS)
    f_number = _exif_number(exif, _EXIF_FNUMBER_KEYS)
    capture_time = _exif_time(exif)
    if libraw_other is not None:
        iso = iso if iso is not None else _positive(libraw_other.iso_speed)
        f_number = f_number if f_number is not None else _positive(libraw_other.aperture)
        capture_time = capture_time or _libraw_time(libraw_other.timestamp)
    make = _exif_text(exif, ("Image Make",))
    model = _exif_text(exif, ("Image Model",))
    if make is None and model is None:
        model = _exif_text(exif, _EXIF_UNIQUE_MODEL_KEYS)
    return RawMetadata(
        path=path,
        exposure_s=exposure,
        exposure_source=source,
        iso=iso,
        f_number=f_number,
        make=make,
        model=model,
        capture_time=capture_time,
        focal_length_mm=_exif_number(exif, _EXIF_FOCAL_KEYS),
        pixel_pitch_um=_plane_pitch_um(exif),
    )


def _plane_pitch_um(tags: Mapping[str, Any]) -> float | None:
    """Photosite pitch from FocalPlaneXResolution (pixels per unit) and its unit, or ``None``."""
    resolution = _exif_number(tags, _EXIF_PLANE_RESOLUTION_KEYS)
    unit = _exif_number(tags, _EXIF_PLANE_UNIT_KEYS) or 2.0  # the tag's default is inches
    per_unit = _PLANE_UNIT_UM.get(int(unit))
    if resolution is None or per_unit is None:
        return None
    pitch = per_unit / resolution
    # A pitch outside 0.5–30 µm is a tag describing something else (a thumbnail's plane).
    return pitch if 0.5 <= pitch <= 30.0 else None


def exif_exposure_s(tags: Mapping[str, Any]) -> float | None:
    """The exposure time in the tags (EXIF IFD first, then IFD0), or ``None``."""
    return _exif_number(tags, _EXIF_EXPOSURE_KEYS)


def _process(handle: BinaryIO) -> dict[str, Any]:
    try:
        return dict(exifread.process_file(handle, details=False, extract_thumbnail=False))
    except Exception:  # exifread raises many kinds on odd files; LibRaw has the final word
        return {}


def _boxes(data: bytes, start: int = 0, end: int | None = None) -> Iterator[tuple[bytes, int, int]]:
    """ISO base-media boxes in ``data[start:end]``: ``(type, payload start, payload end)``."""
    position, limit = start, len(data) if end is None else end
    while position + 8 <= limit:
        size, kind = struct.unpack(">I4s", data[position : position + 8])
        header = 8
        if size == 1 and position + 16 <= limit:
            (size,) = struct.unpack(">Q", data[position + 8 : position + 16])
            header = 16
        elif size == 0:
            size = limit - position
        if size < header or position + size > limit:
            return
        yield kind, position + header, position + size
        position += size


def _cr3_tags(path: Path) -> dict[str, Any]:
    """EXIF tags of a Canon CR3 from its CMT1 (IFD0) and CMT2 (EXIF IFD) boxes."""
    data = path.read_bytes()[: 4 << 20]  # the metadata sits at the front of the file
    tags: dict[str, Any] = {}
    for kind, start, end in _boxes(data):
        if kind != b"moov":
            continue
        for inner, inner_start, inner_end in _boxes(data, start, end):
            if inner != b"uuid" or data[inner_start : inner_start + 16] != _CR3_METADATA_UUID:
                continue
            for box, box_start, box_end in _boxes(data, inner_start + 16, inner_end):
                parsed = _process(io.BytesIO(data[box_start:box_end]))
                if box == b"CMT1":
                    tags.update(parsed)
                elif box == b"CMT2":  # an EXIF IFD stored as a TIFF of its own
                    tags.update(
                        {key.replace("Image ", "EXIF ", 1): value for key, value in parsed.items()}
                    )
    return tags


def _raf_tags(path: Path) -> dict[str, Any]:
    """EXIF tags of a Fujifilm RAF, from the JPEG preview its header points to."""
    with path.open("rb") as handle:
        header = handle.read(92)
        if len(header) < 92:
            return {}
        offset, length = struct.unpack(">II", header[84:92])
        handle.seek(offset)
        return _process(io.BytesIO(handle.read(length)))


def exif_tags(path: Path) -> dict[str, Any]:
    """exifread's tags of a RAW file (empty for formats it cannot reach)."""
    with path.open("rb") as handle:
        magic = handle.read(16)
        if magic[:2] in (b"II", b"MM"):
            return _process(handle)
    if magic.startswith(_RAF_MAGIC):
        return _raf_tags(path)
    if magic[4:8] == b"ftyp" and magic[8:12] == b"crx ":
        return _cr3_tags(path)
    return {}
