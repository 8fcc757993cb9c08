"""Write real DNG files of a Bayer sensor that rawpy/LibRaw read back with exact pixel values.

The digital twin's camera and the tests use this writer: a ``uint16`` CFA array goes into IFD0 of a
TIFF written by :mod:`tifffile` with the DNG tag set that LibRaw needs (CFA pattern, black and white
levels, colour matrix, as-shot neutral; see ``shared/research/protocols.md`` §6.3).

ISO speed lives in an EXIF sub-IFD, the place LibRaw, exifread and tifffile look for it (LibRaw
ignores ISOSpeedRatings in IFD0). tifffile refuses to write the ExifIFD pointer (tag 34665) itself,
so the writer reserves the IFD0 entry under a placeholder tag that sorts at the same position
(34664), appends the EXIF IFD after the image data and rewrites that one entry into a pointer to it.
The file is written under a temporary name and renamed, so a reader never sees half a file.

Examples
--------
>>> import numpy as np, tempfile, pathlib
>>> cfa = np.full((24, 32), 600, dtype=np.uint16)
>>> path = pathlib.Path(tempfile.mkdtemp()) / "frame.dng"
>>> write_dng(path, cfa, DngMetadata(exposure_s=1 / 250, iso=200)).name
'frame.dng'
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from fractions import Fraction
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import ArrayLike, NDArray

#: CFAPattern tag values (raster order over the 2×2 cell; 0 = red, 1 = green, 2 = blue).
CFA_PATTERN_CODES: dict[str, tuple[int, int, int, int]] = {
    "RGGB": (0, 1, 1, 2),
    "BGGR": (2, 1, 1, 0),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
}

#: An XYZ→camera matrix of plausible shape (rows R, G, B) for ColorMatrix1 under D65.
DEFAULT_COLOR_MATRIX1: tuple[tuple[float, float, float], ...] = (
    (0.6722, -0.0635, -0.0963),
    (-0.4287, 1.2460, 0.2028),
    (-0.0908, 0.2162, 0.5668),
)

#: How :func:`write_dng` can store the raw data (see :class:`DngMetadata`).
DNG_COMPRESSIONS = ("none", "lossless-jpeg")
#: TIFF tile sides must be multiples of this.
TILE_MULTIPLE_PX = 16
#: Tile side of lossless-JPEG DNGs (Adobe's DNG Converter writes 256 × 256 tiles).
LOSSLESS_JPEG_TILE_PX = 256

#: LibRaw refuses images with a side shorter than this.
MIN_SIDE_PX = 22

_PLACEHOLDER_TAG = 34664  # sorts directly before ExifIFD (34665), unknown to readers
_EXIF_IFD_TAG = 34665
_TIFF_TYPE_CODES = {"BYTE": 1, "ASCII": 2, "SHORT": 3, "LONG": 4, "RATIONAL": 5, "UNDEFINED": 7}
_RATIONAL_DENOMINATOR_LIMIT = 1_000_000
_ILLUMINANT_D65 = 21
_SENSITIVITY_TYPE_ISO_SPEED = 3


class DngWriteError(ValueError):
    """The array or the metadata cannot be written as a DNG that LibRaw reads back exactly."""


@dataclass(frozen=True)
class DngMetadata:
    """What a DNG frame says about its capture.

    Parameters
    ----------
    exposure_s
        Exposure time in seconds (ExposureTime, IFD0 and EXIF IFD), or ``None`` to leave it out
        (to test readers on files without one).
    iso
        ISO speed (ISOSpeedRatings in the EXIF IFD), or ``None`` to leave it out.
    f_number
        Aperture (FNumber, IFD0 and EXIF IFD), or ``None`` to leave it out.
    make, model
        Camera maker and model (IFD0). Naming a camera LibRaw knows makes it use its built-in matrix.
    unique_camera_model
        DNG UniqueCameraModel; ``"{make} {model}"`` when ``None``.
    cfa_pattern
        ``"RGGB"``, ``"BGGR"``, ``"GRBG"`` or ``"GBRG"``: colours of the top-left 2×2 cell.
    black_level_dn
        One black level, four in raster order over the 2×2 cell, or ``rows × columns`` of
        ``black_repeat`` in raster order (DN; integers are written as LONG, fractions as RATIONAL).
    black_repeat
        BlackLevelRepeatDim ``(rows, columns)``; ``None``: (2, 2) for four values, else (1, 1).
    black_delta_v_dn, black_delta_h_dn
        BlackLevelDeltaV (one per active-area row) and BlackLevelDeltaH (one per active-area
        column), written as SRATIONAL, or ``None``.
    linearization_table
        LinearizationTable: the CFA values written are indices into it, ``None`` for none.
    white_level_dn
        The clipping level in DN (after linearisation).
    as_shot_neutral
        Camera-space neutral (R, G, B), e.g. ``(0.5, 1, 0.6667)``.
    color_matrix1
        XYZ→camera 3×3 matrix for CalibrationIlluminant1 = D65.
    capture_time
        DateTime (IFD0) and DateTimeOriginal (EXIF), or ``None``.
    active_area
        ``(top, left, bottom, right)`` of the visible area inside the array (DNG ActiveArea), or
        ``None`` for all of it; the rest is masked border that readers drop.
    default_crop
        DefaultCropOrigin and DefaultCropSize ``(x, y, width, height)`` in active-area pixels, or
        ``None``.
    compression
        ``"none"``: one uncompressed strip (fast to write; LibRaw copies it). ``"lossless-jpeg"``:
        256 × 256 tiles of lossless JPEG (Compression 7, predictor 1; one strip for frames smaller
        than a tile), as cameras and Adobe's DNG Converter store raw data: the same pixels, about
        40 % smaller, and as costly to decode as a camera's own files.
    tile_px
        ``(rows, columns)`` of the tiles instead (multiples of 16; either compression), or ``None``.
    rows_per_strip
        Strips of this many rows instead (either compression), or ``None``.
    extra_tags
        Further IFD0 tags ``(code, tifffile type, count, value)`` written as given: DNG features
        this writer does not model (opcode lists, masked areas, odd active areas), to test
        readers on them.
    jpeg_components
        Components of each lossless-JPEG tile: 1, or 2 as Adobe's DNG Converter writes them
        (a tile ``w`` wide is a JPEG ``w / 2`` wide whose two components interleave along the row).
    """

    exposure_s: float | None
    iso: int | None = 100
    f_number: float | None = 5.6
    make: str = "spectral-rig"
    model: str = "SimCam"
    unique_camera_model: str | None = None
    cfa_pattern: str = "RGGB"
    black_level_dn: float | tuple[float, ...] = 512
    black_repeat: tuple[int, int] | None = None
    black_delta_v_dn: tuple[float, ...] | None = None
    black_delta_h_dn: tuple[float, ...] | None = None
    linearization_table: tuple[int, ...] | None = None
    white_level_dn: int = 16383
    as_shot_neutral: tuple[float, float, float] = (0.5, 1.0, 0.6667)
    color_matrix1: tuple[tuple[float, float, float], ...] = field(default=DEFAULT_COLOR_MATRIX1)
    capture_time: datetime | None = None
    active_area: tuple[int, int, int, int] | None = None
    default_crop: tuple[int, int, int, int] | None = None
    compression: str = "none"
    tile_px: tuple[int, int] | None = None
    rows_per_strip: int | None = None
    jpeg_components: int = 1
    extra_tags: tuple[tuple[int, str, int, object], ...] = ()

    def __post_init__(self) -> None:
        if self.compression not in DNG_COMPRESSIONS:
            raise DngWriteError(
                f"compression {self.compression!r} is not one of {sorted(DNG_COMPRESSIONS)}"
            )
        if self.exposure_s is not None and not (
            np.isfinite(self.exposure_s) and self.exposure_s > 0
        ):
            raise DngWriteError(f"exposure_s must be a positive number, got {self.exposure_s}")
        if self.cfa_pattern not in CFA_PATTERN_CODES:
            raise DngWriteError(
                f"cfa_pattern {self.cfa_pattern!r} is not one of {sorted(CFA_PATTERN_CODES)}"
            )
        if self.iso is not None and not 0 < self.iso <= 65535:
            raise DngWriteError(f"iso must be in 1..65535, got {self.iso}")
        if self.f_number is not None and not self.f_number > 0:
            raise DngWriteError(f"f_number must be > 0, got {self.f_number}")
        if not 0 < self.white_level_dn <= 65535:
            raise DngWriteError(f"white_level_dn must be in 1..65535, got {self.white_level_dn}")
        blacks = self.black_pattern_dn
        if any(not 0 <= b < self.white_level_dn for b in blacks.ravel()):
            raise DngWriteError(
                f"black levels {blacks.ravel().tolist()} must lie in 0..white level "
                f"({self.white_level_dn})"
            )
        if self.tile_px is not None and self.rows_per_strip is not None:
            raise DngWriteError("give tile_px or rows_per_strip, not both")
        if self.tile_px is not None and (
            len(self.tile_px) != 2
            or any(side <= 0 or side % TILE_MULTIPLE_PX for side in self.tile_px)
        ):
            raise DngWriteError(
                f"tile_px {self.tile_px} must be two multiples of {TILE_MULTIPLE_PX}"
            )
        if self.jpeg_components not in (1, 2):
            raise DngWriteError(f"jpeg_components must be 1 or 2, got {self.jpeg_components}")
        if self.rows_per_strip is not None and self.rows_per_strip < 1:
            raise DngWriteError(f"rows_per_strip must be ≥ 1, got {self.rows_per_strip}")
        if self.linearization_table is not None and (
            not self.linearization_table
            or max(self.linearization_table) > self.white_level_dn
            or min(self.linearization_table) < 0
        ):
            raise DngWriteError("linearization_table must map into 0..white level")
        if np.shape(self.color_matrix1) != (3, 3):
            raise DngWriteError(f"color_matrix1 must be 3×3, got {np.shape(self.color_matrix1)}")

    @property
    def black_pattern_dn(self) -> NDArray[np.float64]:
        """BlackLevel as a ``black_repeat`` array (rows, columns from the active area's corner)."""
        value = self.black_level_dn
        levels = np.atleast_1d(np.asarray(value, dtype=np.float64))
        repeat = self.black_repeat or ((2, 2) if levels.size == 4 else (1, 1))
        if len(repeat) != 2 or min(repeat) < 1 or levels.size != repeat[0] * repeat[1]:
            raise DngWriteError(
                f"black_level_dn needs {repeat} = rows × columns values, got {value!r}"
            )
        return levels.reshape(repeat)


def _rational(value: float) -> tuple[int, int]:
    fraction = Fraction(value).limit_denominator(_RATIONAL_DENOMINATOR_LIMIT)
    if fraction.numerator > 0xFFFFFFFF:
        raise DngWriteError(f"{value} does not fit a TIFF RATIONAL")
    return fraction.numerator, fraction.denominator


def _srational(value: float) -> tuple[int, int]:
    return round(value * 10_000), 10_000


def _tiff_datetime(moment: datetime) -> str:
    return moment.strftime("%Y:%m:%d %H:%M:%S")


@dataclass(frozen=True)
class _IfdEntry:
    tag: int
    type_name: str
    count: int
    payload: bytes


def _encode_ifd(entries: Sequence[_IfdEntry], ifd_offset: int, byteorder: str) -> bytes:
    """A classic-TIFF IFD at file offset ``ifd_offset``: entries, next-IFD = 0, then long values."""
    entries = sorted(entries, key=lambda entry: entry.tag)
    header_size = 2 + 12 * len(entries) + 4
    directory = [struct.pack(byteorder + "H", len(entries))]
    values = b""
    for entry in entries:
        head = struct.pack(
            byteorder + "HHI", entry.tag, _TIFF_TYPE_CODES[entry.type_name], entry.count
        )
        if len(entry.payload) <= 4:
            directory.append(head + entry.payload.ljust(4, b"\0"))
        else:
            offset = ifd_offset + header_size + len(values)
            directory.append(head + struct.pack(byteorder + "I", offset))
            values += entry.payload + b"\0" * (len(entry.payload) % 2)
    directory.append(struct.pack(byteorder + "I", 0))
    return b"".join(directory) + values


def _exif_entries(metadata: DngMetadata, byteorder: str) -> list[_IfdEntry]:
    def rational(value: float) -> bytes:
        return struct.pack(byteorder + "II", *_rational(value))

    def short(value: int) -> bytes:
        return struct.pack(byteorder + "H", value)

    entries = [_IfdEntry(36864, "UNDEFINED", 4, b"0231")]
    if metadata.exposure_s is not None:
        entries.append(_IfdEntry(33434, "RATIONAL", 1, rational(metadata.exposure_s)))
    if metadata.f_number is not None:
        entries.append(_IfdEntry(33437, "RATIONAL", 1, rational(metadata.f_number)))
    if metadata.iso is not None:
        entries.append(_IfdEntry(34855, "SHORT", 1, short(metadata.iso)))
        entries.append(_IfdEntry(34864, "SHORT", 1, short(_SENSITIVITY_TYPE_ISO_SPEED)))
    if metadata.capture_time is not None:
        text = _tiff_datetime(metadata.capture_time).encode("ascii") + b"\0"
        entries.append(_IfdEntry(36867, "ASCII", len(text), text))
    return entries


def _reals_tag(
    code: int, values: NDArray[np.float64], signed: bool
) -> tuple[int, str, int, object, bool]:
    """LONG when every value is a whole number (and none is negative), else (S)RATIONAL."""
    flat = values.ravel()
    if not signed and np.all(flat == np.round(flat)):
        return (code, "I", flat.size, tuple(int(v) for v in flat), True)
    parts = [part for v in flat for part in (_srational(v) if signed else _rational(v))]
    return (code, "2i" if signed else "2I", flat.size, parts, True)


def _ifd0_extratags(metadata: DngMetadata) -> list[tuple[int, str, int, object, bool]]:
    blacks = metadata.black_pattern_dn
    unique = metadata.unique_camera_model or f"{metadata.make} {metadata.model}"
    matrix = [part for value in np.ravel(metadata.color_matrix1) for part in _srational(value)]
    neutral = [part for value in metadata.as_shot_neutral for part in _rational(value)]
    tags: list[tuple[int, str, int, object, bool]] = [
        (271, "s", 0, metadata.make, True),
        (272, "s", 0, metadata.model, True),
        (33421, "H", 2, (2, 2), True),
        (33422, "B", 4, CFA_PATTERN_CODES[metadata.cfa_pattern], True),
        (_PLACEHOLDER_TAG, "I", 1, 0, True),
        (50706, "B", 4, (1, 4, 0, 0), True),
        (50707, "B", 4, (1, 1, 0, 0), True),
        (50708, "s", 0, unique, True),
        (50710, "B", 3, (0, 1, 2), True),
        (50711, "H", 1, 1, True),
        (50713, "H", 2, blacks.shape, True),
        _reals_tag(50714, blacks, signed=False),
        (50717, "I", 1, metadata.white_level_dn, True),
        (50721, "2i", 9, matrix, True),
        (50728, "2I", 3, neutral, True),
        (50778, "H", 1, _ILLUMINANT_D65, True),
    ]
    if metadata.exposure_s is not None:
        tags.append((33434, "2I", 1, _rational(metadata.exposure_s), True))
    if metadata.f_number is not None:
        tags.append((33437, "2I", 1, _rational(metadata.f_number), True))
    if metadata.capture_time is not None:
        tags.append((306, "s", 0, _tiff_datetime(metadata.capture_time), True))
    if metadata.active_area is not None:
        tags.append((50829, "I", 4, metadata.active_area, True))
    if metadata.black_delta_h_dn is not None:
        tags.append(_reals_tag(50715, np.asarray(metadata.black_delta_h_dn, float), signed=True))
    if metadata.black_delta_v_dn is not None:
        tags.append(_reals_tag(50716, np.asarray(metadata.black_delta_v_dn, float), signed=True))
    if metadata.linearization_table is not None:
        table = metadata.linearization_table
        tags.append((50712, "H", len(table), tuple(table), True))
    if metadata.default_crop is not None:
        x, y, width, height = metadata.default_crop
        tags.append((50719, "I", 2, (x, y), True))
        tags.append((50720, "I", 2, (width, height), True))
    tags.extend(
        (code, kind, count, value, True) for code, kind, count, value in metadata.extra_tags
    )
    return tags


def _as_cfa_array(cfa: ArrayLike) -> NDArray[np.uint16]:
    array = np.asarray(cfa)
    if array.ndim != 2 or min(array.shape) < MIN_SIDE_PX:
        raise DngWriteError(
            f"CFA data must be a 2-D array of at least {MIN_SIDE_PX}×{MIN_SIDE_PX} (LibRaw rejects "
            f"smaller images), got shape {array.shape}"
        )
    if array.dtype == np.uint16:
        return np.ascontiguousarray(array)
    if not np.issubdtype(array.dtype, np.integer):
        raise DngWriteError(
            f"CFA data must be integers (LibRaw rescales float DNGs), got {array.dtype}"
        )
    if array.size and (array.min() < 0 or array.max() > 65535):
        raise DngWriteError("CFA values must lie in 0..65535")
    return np.ascontiguousarray(array, dtype=np.uint16)


def write_dng(path: str | os.PathLike[str], cfa: ArrayLike, metadata: DngMetadata) -> Path:
    """Write ``cfa`` as a DNG with the capture ``metadata`` (uncompressed or lossless JPEG).

    Parameters
    ----------
    path
        Destination file; its directory must exist. Replaced atomically if present.
    cfa
        Shape ``(height, width)``: raw sensor values in DN (``uint16``, or integers in 0..65535).
    metadata
        Exposure, ISO, aperture, camera, CFA layout, black and white levels.

    Returns
    -------
    Path
        ``path``.
    """
    data = _as_cfa_array(cfa)
    table = metadata.linearization_table
    if table is None and (data > metadata.white_level_dn).any():
        raise DngWriteError(
            f"CFA values exceed the white level {metadata.white_level_dn}; clip before writing"
        )
    if table is not None and data.size and int(data.max()) >= len(table):
        raise DngWriteError(f"CFA values index past the linearization table ({len(table)} entries)")
    if metadata.active_area is not None:
        top, left, bottom, right = metadata.active_area
        if not (0 <= top < bottom <= data.shape[0] and 0 <= left < right <= data.shape[1]):
            raise DngWriteError(
                f"active_area {metadata.active_area} does not fit the array of shape {data.shape}"
            )
        if top % 2 or left % 2:
            # The DNG CFA pattern is relative to the active area; LibRaw 0.22 then re-phases the
            # black levels inconsistently, so odd origins would not read back as written.
            raise DngWriteError(
                f"active_area must start on an even row and column, got {top, left}"
            )
    destination = Path(path)
    temporary = destination.with_name(f".{destination.name}.{os.getpid()}.part")
    try:
        common: dict[str, object] = {
            "photometric": 32803,
            "planarconfig": 1,
            "subfiletype": 0,
            "metadata": None,
            "software": False,
            "extratags": _ifd0_extratags(metadata),
        }
        height, width = data.shape
        if metadata.tile_px is not None:
            block = metadata.tile_px
        elif metadata.rows_per_strip is not None:
            block = (min(metadata.rows_per_strip, height), width)
        elif metadata.compression == "lossless-jpeg" and min(data.shape) >= LOSSLESS_JPEG_TILE_PX:
            block = (LOSSLESS_JPEG_TILE_PX, LOSSLESS_JPEG_TILE_PX)
        else:
            # LibRaw reads a single tile larger than the image wrongly: small frames get one strip
            block = (height, width)
        strips = block[1] == width and metadata.tile_px is None
        layout: dict[str, object] = {"rowsperstrip": block[0]} if strips else {"tile": block}
        if metadata.compression == "lossless-jpeg":
            bits = max(
                int(metadata.white_level_dn if table is None else data.max()).bit_length(), 2
            )
            tifffile.imwrite(
                temporary,
                data=iter(
                    _lossless_jpeg_blocks(data, bits, block, strips, metadata.jpeg_components)
                ),
                shape=data.shape,
                dtype=np.uint16,
                compression=7,
                bitspersample=bits,
                **layout,
                **common,
            )
        else:
            tifffile.imwrite(temporary, data, compression=None, **layout, **common)
        _attach_exif_ifd(temporary, metadata)
        temporary.replace(destination)
    finally:
        temporary.unlink(missing_ok=True)
    return destination


def _lossless_jpeg_blocks(
    data: NDArray[np.uint16], bits: int, block: tuple[int, int], strips: bool, components: int
) -> list[bytes]:
    """``data`` as lossless JPEG blocks in raster order: tiles of ``block`` with the edge tiles
    padded with zeros (DNG 1.4 §6), or strips of ``block[0]`` rows (the last one shorter); with
    2 components, each row's pairs of samples are one pixel of a JPEG half as wide."""
    import imagecodecs  # deferred: only lossless-JPEG frames need it

    height, width = data.shape
    rows, columns = block
    encoded = []
    for top in range(0, height, rows):
        for left in range(0, width, columns):
            part = data[top : top + rows, left : left + columns]
            if not strips:
                tile = np.zeros((rows, columns), dtype=np.uint16)
                tile[: part.shape[0], : part.shape[1]] = part
                part = tile
            encoded.append(
                bytes(imagecodecs.ljpeg_encode(np.ascontiguousarray(part), bitspersample=bits))
            )
    return encoded


def _attach_exif_ifd(path: Path, metadata: DngMetadata) -> None:
    """Append the EXIF IFD and turn the placeholder IFD0 entry into the ExifIFD pointer."""
    with tifffile.TiffFile(path) as tiff:
        if tiff.is_bigtiff:  # pragma: no cover - tifffile writes classic TIFF for these sizes
            raise DngWriteError("BigTIFF output is not supported by the DNG writer")
        byteorder = tiff.byteorder
        entry_offset = tiff.pages.first.tags[_PLACEHOLDER_TAG].offset
    with path.open("r+b") as handle:
        end = handle.seek(0, os.SEEK_END)
        ifd_offset = end + (end % 2)
        handle.write(b"\0" * (ifd_offset - end))
        handle.write(_encode_ifd(_exif_entries(metadata, byteorder), ifd_offset, byteorder))
        handle.seek(entry_offset)
        handle.write(
            struct.pack(byteorder + "HHII", _EXIF_IFD_TAG, _TIFF_TYPE_CODES["LONG"], 1, ifd_offset)
        )
