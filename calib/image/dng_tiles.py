"""Read a window of a DNG's raw CFA data by decoding only the tiles (or strips) that meet it.

LibRaw always decodes a whole file: about 0.6–0.8 s of CPU for a 24 MP lossless-JPEG DNG. The
estimate needs only the direct spot and the first-order band(s), a few percent of the frame, so once
their region is known (:mod:`calib.pipeline.brackets`) later frames are read here: the raw IFD's tags
and tile offsets through :mod:`tifffile`, the tiles meeting the region through
:func:`imagecodecs.ljpeg_decode` (compression 7, lossless JPEG) or as plain integers (compression
1), nothing else.

What the DNG specification (1.7, chapter 5 "Mapping raw values to linear reference values") says
shapes the pixels is honoured:

* **ActiveArea**: coordinates are those of the active area (LibRaw's ``raw_image_visible``); the
  CFA pattern and the black-level pattern start at its top-left corner.
* **DefaultCrop** does not change coordinates: like LibRaw's raw image, the window is the active
  area's (the crop is for rendering).
* **LinearizationTable** maps stored values (values past its end map to its last entry, as LibRaw
  does); **WhiteLevel** is in linearised DN.
* **BlackLevel** with **BlackLevelRepeatDim** (any repeat, not only per CFA position), plus
  **BlackLevelDeltaV** per active-area row and **BlackLevelDeltaH** per column, all as real numbers:
  :meth:`DngTiles.black_dn`.

Where LibRaw departs from the specification the two differ, and this module follows the
specification: LibRaw truncates a fractional black level to an integer, and replaces the per-row and
per-column deltas by their (rounded) means.

Anything else is refused with a one-line :class:`UnsupportedDng` that says why (callers then decode
with LibRaw): other compressions (lossy JPEG, deflate, JPEG XL), packed bit depths of uncompressed
data other than 8 and 16, several samples per pixel, non-rectangular CFA layouts, CFA patterns other
than 2×2 RGB Bayer, opcode lists that change raw values (LibRaw ignores them; the specification
applies them), masked areas (LibRaw measures black there), an active area starting on an odd row or
column (LibRaw's CFA phase there is not the specification's), a linearisation table without a white
level, and tiles whose decoded size is not the tile size.

Examples
--------
Not run as a doctest: it needs a tiled DNG (``tests/test_dng_tiles.py`` runs the same calls on
written ones).

>>> tiles = open_dng("frame.dng")  # doctest: +SKIP
>>> window = tiles.decode(slice(1000, 1400), slice(2000, 2600))  # doctest: +SKIP
>>> window.shape, tiles.blocks_meeting(slice(1000, 1400), slice(2000, 2600))  # doctest: +SKIP
((400, 600), 12)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from calib.core.errors import InputError

__all__ = ["CorruptDng", "DngTiles", "NotDng", "UnsupportedDng", "open_dng"]

Float64Array = NDArray[np.float64]

_COMPRESSION_NONE = 1
_COMPRESSION_LOSSLESS_JPEG = 7
_COMPRESSION_NAMES = {
    8: "deflate",
    34892: "lossy JPEG",
    52546: "JPEG XL",
    6: "old-style JPEG",
    32773: "PackBits",
}
_PHOTOMETRIC_CFA = 32803
_PHOTOMETRIC_NAMES = {34892: "LinearRaw (demosaiced)", 2: "RGB", 1: "greyscale"}
_DNG_VERSION = 50706
_TAG_CFA_REPEAT = 33421
_TAG_CFA_PATTERN = 33422
_TAG_CFA_PLANE_COLOR = 50710
_TAG_CFA_LAYOUT = 50711
_TAG_LINEARIZATION = 50712
_TAG_BLACK_REPEAT = 50713
_TAG_BLACK = 50714
_TAG_BLACK_DELTA_H = 50715
_TAG_BLACK_DELTA_V = 50716
_TAG_WHITE = 50717
_TAG_DEFAULT_CROP_ORIGIN = 50719
_TAG_DEFAULT_CROP_SIZE = 50720
_TAG_ACTIVE_AREA = 50829
_TAG_MASKED_AREAS = 50830
_TAG_OPCODE_LIST1 = 51008
_TAG_OPCODE_LIST2 = 51009
_LUT_SIZE = 65536


class UnsupportedDng(InputError):
    """The tile decoder does not read this file exactly (the message says why in one line)."""


class CorruptDng(InputError):
    """A tile is truncated or does not decode."""


class NotDng(UnsupportedDng):
    """The file is not a DNG (another RAW format, or no TIFF at all)."""


@dataclass(frozen=True, eq=False)
class DngTiles:
    """Where a DNG's raw CFA data lies and how its values map to linear DN.

    Coordinates are active-area pixels ``(row, column)``, as LibRaw's ``raw_image_visible``.

    Attributes
    ----------
    path
        The file.
    dtype
        The stored samples' type with the file's byte order (uncompressed data).
    raw_shape
        ``(height, width)`` of the raw IFD's image.
    active_area
        ``(top, left, bottom, right)`` of the active area in the raw image.
    block_shape
        ``(rows, columns)`` of one tile; a strip is a tile as wide as the image.
    blocks_across
        Tiles per row of tiles.
    offsets, byte_counts
        File offset and length of every tile (strip), raster order.
    compression
        1 (uncompressed) or 7 (lossless JPEG).
    cfa_colours
        Colour (0 = red, 1 = green, 2 = blue) of each site of the 2×2 cell at the active area's
        top-left corner, ``((top-left, top-right), (bottom-left, bottom-right))``.
    black_pattern_dn
        Shape ``(repeat_rows, repeat_columns)``: BlackLevel from the active area's corner.
    black_delta_v_dn, black_delta_h_dn
        Per active-area row / column (``None`` when absent).
    white_level_dn
        WhiteLevel (linearised DN).
    linearization
        Shape ``(65536,)``: stored value → linear value, or ``None``.
    default_crop
        ``(row, column, height, width)`` of DefaultCrop in active-area pixels (for information:
        it does not move coordinates), or ``None``.
    """

    path: Path
    dtype: np.dtype[Any]
    raw_shape: tuple[int, int]
    active_area: tuple[int, int, int, int]
    block_shape: tuple[int, int]
    blocks_across: int
    offsets: tuple[int, ...]
    byte_counts: tuple[int, ...]
    compression: int
    cfa_colours: tuple[tuple[int, int], tuple[int, int]]
    black_pattern_dn: Float64Array
    black_delta_v_dn: Float64Array | None
    black_delta_h_dn: Float64Array | None
    white_level_dn: float
    linearization: NDArray[np.uint16] | None
    default_crop: tuple[float, float, float, float] | None

    @property
    def visible_shape(self) -> tuple[int, int]:
        """``(height, width)`` of the active area."""
        top, left, bottom, right = self.active_area
        return (bottom - top, right - left)

    @property
    def block_count(self) -> int:
        """Tiles (strips) in the file."""
        return len(self.offsets)

    def _block_ranges(self, rows: slice, columns: slice) -> tuple[range, range]:
        top, left, _, _ = self.active_area
        block_rows, block_columns = self.block_shape
        return (
            range((top + rows.start) // block_rows, (top + rows.stop - 1) // block_rows + 1),
            range(
                (left + columns.start) // block_columns,
                (left + columns.stop - 1) // block_columns + 1,
            ),
        )

    def blocks_meeting(self, rows: slice, columns: slice) -> int:
        """How many tiles (strips) :meth:`decode` reads for this window."""
        tile_rows, tile_columns = self._block_ranges(*self._checked(rows, columns))
        return len(tile_rows) * len(tile_columns)

    def _checked(self, rows: slice, columns: slice) -> tuple[slice, slice]:
        height, width = self.visible_shape
        if not (
            0 <= rows.start < rows.stop <= height and 0 <= columns.start < columns.stop <= width
        ):
            raise ValueError(
                f"window rows {rows.start}:{rows.stop}, columns {columns.start}:{columns.stop} is "
                f"not inside the active area {height}×{width}"
            )
        return rows, columns

    def decode(self, rows: slice, columns: slice) -> NDArray[np.uint16]:
        """Linearised raw values of ``rows × columns`` of the active area (only the tiles that
        meet it are read and decoded).

        Raises
        ------
        UnsupportedDng
            A tile does not decode to the tile's size (the caller decodes with LibRaw).
        CorruptDng
            A tile is truncated or corrupt.
        """
        rows, columns = self._checked(rows, columns)
        top, left, _, _ = self.active_area
        block_rows, block_columns = self.block_shape
        raw_height, raw_width = self.raw_shape
        window = np.empty((rows.stop - rows.start, columns.stop - columns.start), np.uint16)
        row0, column0 = top + rows.start, left + columns.start  # the window's corner, raw pixels
        row1, column1 = top + rows.stop, left + columns.stop
        tile_rows, tile_columns = self._block_ranges(rows, columns)
        descriptor = os.open(self.path, os.O_RDONLY)
        try:
            for tile_row in tile_rows:
                for tile_column in tile_columns:
                    index = tile_row * self.blocks_across + tile_column
                    # rows and columns of this block that hold image data
                    block_top, block_left = tile_row * block_rows, tile_column * block_columns
                    held = (
                        min(block_rows, raw_height - block_top),
                        min(block_columns, raw_width - block_left),
                    )
                    r0, r1 = max(row0, block_top), min(row1, block_top + held[0])
                    c0, c1 = max(column0, block_left), min(column1, block_left + held[1])
                    block = self._block(descriptor, index, held, (r0 - block_top, r1 - block_top))
                    window[r0 - row0 : r1 - row0, c0 - column0 : c1 - column0] = block[
                        :, c0 - block_left : c1 - block_left
                    ]
        finally:
            os.close(descriptor)
        if self.linearization is not None:
            return np.take(self.linearization, window)
        return window

    def _block(
        self, descriptor: int, index: int, held: tuple[int, int], rows: tuple[int, int]
    ) -> NDArray[Any]:
        """Rows ``rows[0]:rows[1]`` of tile (strip) ``index``, which holds image data in its first
        ``held`` rows × columns. Uncompressed rows are read alone; a JPEG tile is decoded whole."""
        block_rows, block_columns = self.block_shape
        count = self.byte_counts[index]
        if self.compression == _COMPRESSION_NONE:
            row_bytes = block_columns * self.dtype.itemsize
            start, length = rows[0] * row_bytes, (rows[1] - rows[0]) * row_bytes
            if start + length > count:
                raise CorruptDng(
                    f"corrupt DNG: tile {index} holds {count} bytes, rows up to {rows[1]} need "
                    f"{start + length}",
                    source=str(self.path),
                )
            data = os.pread(descriptor, length, self.offsets[index] + start)
            if len(data) < length:
                raise CorruptDng(
                    f"truncated DNG: tile {index} ends {length - len(data)} bytes early",
                    source=str(self.path),
                )
            return np.frombuffer(data, self.dtype).reshape(rows[1] - rows[0], block_columns)
        data = os.pread(descriptor, count, self.offsets[index])
        if len(data) < count:
            raise CorruptDng(
                f"truncated DNG: tile {index} holds {len(data)} of {count} bytes",
                source=str(self.path),
            )
        import imagecodecs  # deferred: only lossless-JPEG DNGs need it

        try:
            decoded = imagecodecs.ljpeg_decode(data)
        except Exception as exc:  # imagecodecs raises its own error types per codec
            raise CorruptDng(
                f"corrupt DNG: tile {index} is not valid lossless JPEG ({exc})",
                source=str(self.path),
            ) from exc
        # a tile of n components interleaves them along the row (LibRaw reads it so)
        decoded = np.asarray(decoded).reshape(decoded.shape[0], -1)
        if decoded.shape[0] < held[0] or decoded.shape[1] < held[1]:
            raise UnsupportedDng(
                f"lossless-JPEG tile {index} decodes to {decoded.shape[0]}×{decoded.shape[1]}, "
                f"not the tile's {block_rows}×{block_columns}; LibRaw decodes this file",
                source=str(self.path),
            )
        return decoded[rows[0] : rows[1]]

    def black_dn(self, rows: slice, columns: slice) -> Float64Array:
        """Black level of every pixel of the window ``(rows, columns)``: the BlackLevel pattern
        from the active area's corner plus BlackLevelDeltaV of the row and BlackLevelDeltaH of the
        column (DNG 1.7 §5)."""
        pattern = self.black_pattern_dn
        row_index = np.arange(rows.start, rows.stop, rows.step or 1)
        column_index = np.arange(columns.start, columns.stop, columns.step or 1)
        black = pattern[np.ix_(row_index % pattern.shape[0], column_index % pattern.shape[1])]
        if self.black_delta_v_dn is not None:
            black = black + self.black_delta_v_dn[row_index][:, None]
        if self.black_delta_h_dn is not None:
            black = black + self.black_delta_h_dn[column_index][None, :]
        return np.asarray(black, dtype=np.float64)

    def _site_pattern_dn(self, site: tuple[int, int]) -> Float64Array:
        """The BlackLevel pattern's values at one CFA site (``(row, column)`` in the 2×2 cell),
        over one period of pattern and cell together."""
        repeat_rows, repeat_columns = self.black_pattern_dn.shape
        rows = np.arange(site[0], int(np.lcm(repeat_rows, 2)), 2) % repeat_rows
        columns = np.arange(site[1], int(np.lcm(repeat_columns, 2)), 2) % repeat_columns
        return np.asarray(self.black_pattern_dn[np.ix_(rows, columns)], dtype=np.float64)

    def site_black_dn(self, site: tuple[int, int]) -> float:
        """Mean black level of a CFA site (``(row, column)`` in the 2×2 cell) over the active area."""
        height, width = self.visible_shape
        level = float(self._site_pattern_dn(site).mean())
        if self.black_delta_v_dn is not None:
            level += float(self.black_delta_v_dn[site[0] : height : 2].mean())
        if self.black_delta_h_dn is not None:
            level += float(self.black_delta_h_dn[site[1] : width : 2].mean())
        return level

    def black_varies_within_sites(self) -> bool:
        """Whether the black level of a CFA site changes across the frame (deltas, or a pattern
        that does not repeat with the 2×2 cell)."""
        for site in ((0, 0), (0, 1), (1, 0), (1, 1)):
            if np.ptp(self._site_pattern_dn(site)) > 0:
                return True
        return any(
            delta.size > parity and np.ptp(delta[parity::2]) > 0
            for delta in (self.black_delta_v_dn, self.black_delta_h_dn)
            if delta is not None
            for parity in (0, 1)
        )


def _tag(page: Any, code: int) -> Any:
    tag = page.tags.get(code)
    return None if tag is None else tag.value


def _reals(value: Any, dtype_code: int) -> Float64Array:
    """A tag's numbers as floats (RATIONAL / SRATIONAL come as flat numerator, denominator pairs)."""
    numbers = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if dtype_code in (5, 10):  # RATIONAL, SRATIONAL
        numerators, denominators = numbers[0::2], numbers[1::2]
        if (denominators == 0).any():
            raise ValueError("a rational with denominator 0")
        return np.asarray(numerators / denominators, dtype=np.float64)
    return numbers


def _real_tag(page: Any, code: int) -> Float64Array | None:
    tag = page.tags.get(code)
    return None if tag is None else _reals(tag.value, int(tag.dtype))


def _raw_page(tiff: Any, path: Path) -> Any:
    """The IFD holding the raw CFA data: NewSubFileType 0 in IFD0 or its SubIFDs."""
    first = tiff.pages.first
    if first.tags.get(_DNG_VERSION) is None:
        raise NotDng("not a DNG (no DNGVersion tag); LibRaw decodes it", source=str(path))
    candidates = [first]
    for sub in getattr(first, "pages", None) or ():
        candidates.append(sub)
    main = [page for page in candidates if not int(_tag(page, 254) or 0) & 1]
    if len(main) != 1:
        raise UnsupportedDng(
            f"{len(main)} full-resolution images in the DNG (expected one); LibRaw decodes it",
            source=str(path),
        )
    return main[0]


def open_dng(path: str | os.PathLike[str]) -> DngTiles:
    """Read a DNG's raw-image tags and tile offsets (a few kB of I/O, no pixels).

    Raises
    ------
    UnsupportedDng
        Not a DNG, or a layout this module does not read exactly (the message says which).
    """
    file = Path(path)
    source = str(file)
    with file.open("rb") as handle:
        if handle.read(4) not in (b"II*\0", b"MM\0*"):
            raise NotDng("not a TIFF-based file; LibRaw decodes it", source=source)

    def refuse(reason: str) -> UnsupportedDng:
        return UnsupportedDng(f"{reason}; LibRaw decodes it", source=source)

    try:
        with tifffile.TiffFile(file) as tiff:
            page = _raw_page(tiff, file)
            byteorder = tiff.byteorder
            return _layout(page, file, byteorder, refuse)
    except UnsupportedDng:
        raise
    except (tifffile.TiffFileError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise refuse(f"DNG tags not readable ({exc})") from exc


def _layout(page: Any, file: Path, byteorder: str, refuse: Any) -> DngTiles:
    photometric = int(_tag(page, 262) or 0)
    if photometric != _PHOTOMETRIC_CFA:
        name = _PHOTOMETRIC_NAMES.get(photometric, str(photometric))
        raise refuse(f"raw image is {name}, not colour filter array data")
    compression = int(_tag(page, 259) or 1)
    if compression not in (_COMPRESSION_NONE, _COMPRESSION_LOSSLESS_JPEG):
        name = _COMPRESSION_NAMES.get(compression, "unknown")
        raise refuse(f"compression {compression} ({name}) is not read by the tile decoder")
    samples = int(_tag(page, 277) or 1)
    if samples != 1:
        raise refuse(f"{samples} samples per pixel (the tile decoder reads one)")
    bits = np.atleast_1d(np.asarray(_tag(page, 258) or 1))
    bits_per_sample = int(bits[0])
    if compression == _COMPRESSION_NONE and bits_per_sample not in (8, 16):
        raise refuse(f"uncompressed {bits_per_sample}-bit packed samples")
    if bits_per_sample > 16:
        raise refuse(f"{bits_per_sample}-bit samples")
    if int(_tag(page, 339) or 1) != 1:  # SampleFormat: unsigned integers only
        raise refuse("floating-point or signed samples")
    if int(_tag(page, 284) or 1) != 1:
        raise refuse("planar configuration 2")
    for code, name in ((_TAG_OPCODE_LIST1, "OpcodeList1"), (_TAG_OPCODE_LIST2, "OpcodeList2")):
        if page.tags.get(code) is not None:
            raise refuse(f"{name} present (opcodes that change raw values are not applied)")
    if page.tags.get(_TAG_MASKED_AREAS) is not None:
        raise refuse("MaskedAreas present (LibRaw measures black there)")
    if int(_tag(page, _TAG_CFA_LAYOUT) or 1) != 1:
        raise refuse("CFALayout is not rectangular")
    width, height = int(_tag(page, 256)), int(_tag(page, 257))
    tiled = page.tags.get(322) is not None
    if tiled:
        block = (int(_tag(page, 323)), int(_tag(page, 322)))
        offsets, counts = _tag(page, 324), _tag(page, 325)
    else:
        block = (min(int(_tag(page, 278) or height), height), width)
        offsets, counts = _tag(page, 273), _tag(page, 279)
    offsets = tuple(int(v) for v in np.atleast_1d(offsets))
    counts = tuple(int(v) for v in np.atleast_1d(counts))
    across = -(-width // block[1])
    if len(offsets) != across * -(-height // block[0]) or len(counts) != len(offsets):
        raise refuse(f"{len(offsets)} tile offsets for a {width}×{height} image of {block} tiles")
    area = _tag(page, _TAG_ACTIVE_AREA)
    top, left, bottom, right = (0, 0, height, width) if area is None else map(int, area)
    if not (0 <= top < bottom <= height and 0 <= left < right <= width):
        raise refuse(f"ActiveArea {area} outside the {height}×{width} image")
    if top % 2 or left % 2:
        raise refuse(f"ActiveArea starts at an odd row or column ({top}, {left})")
    repeat = tuple(int(v) for v in np.atleast_1d(_tag(page, _TAG_CFA_REPEAT) or (2, 2)))
    pattern = np.atleast_1d(np.frombuffer(bytes(_tag(page, _TAG_CFA_PATTERN) or b""), np.uint8))
    planes = bytes(_tag(page, _TAG_CFA_PLANE_COLOR) or b"\x00\x01\x02")
    if repeat != (2, 2) or pattern.size != 4:
        raise refuse(f"CFA repeat {repeat} is not a 2×2 Bayer cell")
    if any(int(index) >= len(planes) for index in pattern):
        raise refuse(f"CFAPattern {pattern.tolist()} names planes beyond CFAPlaneColor")
    colours = [planes[int(index)] for index in pattern]
    if sorted(colours) != [0, 1, 1, 2]:
        raise refuse(f"CFA colours {colours} are not one red, two green and one blue")
    cfa = ((colours[0], colours[1]), (colours[2], colours[3]))
    black_repeat = tuple(int(v) for v in np.atleast_1d(_tag(page, _TAG_BLACK_REPEAT) or (1, 1)))
    black = _real_tag(page, _TAG_BLACK)
    black = np.zeros(1) if black is None else black
    if (
        len(black_repeat) != 2
        or min(black_repeat) < 1
        or black.size != black_repeat[0] * black_repeat[1]
    ):
        raise refuse(f"{black.size} BlackLevel values for a {black_repeat} repeat")
    visible = (bottom - top, right - left)
    deltas: list[Float64Array | None] = []
    for code, length, name in (
        (_TAG_BLACK_DELTA_V, visible[0], "BlackLevelDeltaV"),
        (_TAG_BLACK_DELTA_H, visible[1], "BlackLevelDeltaH"),
    ):
        delta = _real_tag(page, code)
        if delta is not None and delta.size != length:
            raise refuse(f"{name} has {delta.size} values for {length} active-area lines")
        deltas.append(delta)
    table = _tag(page, _TAG_LINEARIZATION)
    white = _tag(page, _TAG_WHITE)
    linearization: NDArray[np.uint16] | None = None
    if table is not None:
        if white is None:
            raise refuse("LinearizationTable without WhiteLevel")
        values = np.atleast_1d(np.asarray(table, dtype=np.uint16))[:_LUT_SIZE]
        linearization = np.empty(_LUT_SIZE, np.uint16)
        linearization[: values.size] = values
        linearization[values.size :] = values[-1]
    white_level = (
        float(np.atleast_1d(white)[0]) if white is not None else float(2**bits_per_sample - 1)
    )
    crop: tuple[float, float, float, float] | None = None
    origin, size = (
        _real_tag(page, _TAG_DEFAULT_CROP_ORIGIN),
        _real_tag(page, _TAG_DEFAULT_CROP_SIZE),
    )
    if origin is not None and size is not None:
        crop = (float(origin[1]), float(origin[0]), float(size[1]), float(size[0]))
    dtype = np.dtype(np.uint8 if bits_per_sample == 8 else np.uint16).newbyteorder(
        "<" if byteorder == "<" else ">"
    )
    return DngTiles(
        path=file,
        dtype=dtype,
        raw_shape=(height, width),
        active_area=(top, left, bottom, right),
        block_shape=block,
        blocks_across=across,
        offsets=offsets,
        byte_counts=counts,
        compression=compression,
        cfa_colours=cfa,
        black_pattern_dn=black.reshape(black_repeat),
        black_delta_v_dn=deltas[0],
        black_delta_h_dn=deltas[1],
        white_level_dn=white_level,
        linearization=linearization,
        default_crop=crop,
    )
