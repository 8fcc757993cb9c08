"""Read camera RAW files into linear, black-subtracted colour planes at half resolution.

Any file LibRaw decodes (DNG, CR2, CR3, NEF, ARW, RAF, ORF, RW2 …) with a 2×2 Bayer colour filter
array is split into three planes without demosaicing: R, G (the mean of the two green sites of each
2×2 cell) and B, each of shape ``(height // 2, width // 2)``. Per-colour black levels are subtracted
(LibRaw's ``black_level_per_channel`` is indexed by colour index, not raster position), and a
saturation mask marks samples at or near the clipping level.

DNGs whose layout the tile decoder (:mod:`calib.image.dng_tiles`) reads exactly are decoded there,
and only the tiles that meet a requested region are decoded; LibRaw decodes every other file (and a
DNG the tile decoder refuses, saying why in :attr:`RawPlanes.decoding`). See :data:`RawDecoder`.

Coordinates stay in the sensor's frame (LibRaw's ``flip`` is not applied). A plane sample ``(i, j)``
of channel ``c`` sits at sensor pixel ``(2 i + dy_c, 2 j + dx_c)`` (row, column), where ``(dy_c, dx_c)``
is that colour's place in the 2×2 cell (``channel_origin_px``; green is the mean of its two sites,
``(0.5, 0.5)``).

Metadata (exposure time, ISO, aperture, make, model, capture time) comes from the EXIF / DNG tags
(:mod:`calib.image.raw_metadata`), falling back to what LibRaw reports. An ``exposure_s`` override wins over
both; a file without an exposure time and no override is rejected with its name.

Examples
--------
Not run as a doctest: it needs a RAW file (``tests/test_raw.py`` reads written DNGs).

>>> planes = read_raw("frame_0001.dng")  # doctest: +SKIP
>>> planes.signal_dn.shape, planes.metadata.exposure_s  # doctest: +SKIP
((3, 2000, 3000), 0.004)
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import rawpy
from numpy.typing import NDArray

from calib.core.arrays import BoolArray
from calib.core.errors import InputError
from calib.image.dng_tiles import CorruptDng, DngTiles, NotDng, UnsupportedDng, open_dng
from calib.image.raw_metadata import (
    ExposureSource,
    RawMetadata,
    build_metadata,
    exif_exposure_s,
    exif_tags,
)

__all__ = [
    "CHANNELS",
    "DEFAULT_SATURATION_FRACTION",
    "ExposureSource",
    "PlaneBuffers",
    "PlaneRegion",
    "RawDecoder",
    "RawFileError",
    "RawMetadata",
    "RawPlanes",
    "UnpackedRaw",
    "read_raw",
    "read_raw_metadata",
    "unpack_raw",
]

Float32Array = NDArray[np.float32]
#: A window of plane samples, ``(rows, columns)`` with explicit integer ``start``/``stop``.
PlaneRegion = tuple[slice, slice]

#: Which decoder reads the pixels: ``"auto"`` reads DNGs through the tile decoder
#: (:mod:`calib.image.dng_tiles`: only the tiles that meet the region) when it reads them exactly,
#: everything else through LibRaw; ``"libraw"`` always LibRaw; ``"tiles"`` the tile decoder or
#: :class:`~calib.image.dng_tiles.UnsupportedDng`.
RawDecoder = Literal["auto", "libraw", "tiles"]
RAW_DECODERS: tuple[str, ...] = ("auto", "libraw", "tiles")

#: Names of the three planes, in order.
CHANNELS: tuple[str, str, str] = ("R", "G", "B")

#: A sample counts as saturated from this fraction of the way from black to the clipping level:
#: sensors leave the linear range a little below the nominal white level.
DEFAULT_SATURATION_FRACTION = 0.97

#: Samples at exactly the frame's maximum, this many or more, are taken as a clipping plateau
#: below the nominal white level (cameras whose real clip point is lower than the metadata says).
_PLATEAU_MIN_COUNT = 16
#: …and only when that plateau lies above this fraction of the black-to-white range.
_PLATEAU_MIN_FRACTION = 0.8


class RawFileError(InputError):
    """A file is missing, not a RAW file, corrupt or truncated, or has an unsupported sensor layout."""


@dataclass(frozen=True, eq=False)
class RawPlanes:
    """A decoded RAW frame: linear R, G, B planes at half resolution, black level subtracted.

    Parameters
    ----------
    metadata
        Exposure, ISO, aperture, camera.
    signal_dn
        Shape ``(3, h, w)``, float32: signal above black in DN (R, mean of the two G, B).
    saturated
        Shape ``(3, h, w)``: the sample (for G: either green site) is at or near clipping.
    cfa_pattern
        Colours of the top-left 2×2 cell of the visible area, e.g. ``"RGGB"``.
    black_level_dn
        Shape ``(3,)``: black level subtracted per channel (G: mean of the two greens).
    clip_level_dn
        Shape ``(3,)``: the clipping level above black per channel (lowest of the two greens).
    channel_origin_px
        Shape ``(3, 2)``: ``(row, column)`` of each channel's sample inside the 2×2 cell.
    green_difference_dn
        Shape ``(h, w)``: first green minus second green (DN), for noise estimation; ``None``
        unless requested.
    green_sites_px
        ``(row, column)`` of the first and the second green site inside the 2×2 cell.
    region_origin
        ``(row, column)`` of the planes' first sample in the full planes (``(0, 0)`` unless only a
        region was read); sensor pixel = ``2 · (origin + index) + channel_origin_px``.
    full_plane_shape
        ``(h, w)`` of the full planes (the planes' own shape unless only a region was read).
    decoding
        How the pixels were decoded: ``"LibRaw"``, ``"LibRaw (<why not the tile decoder>)"`` for a
        DNG the tile decoder refused, or ``"tiles: n of m"``.
    """

    metadata: RawMetadata
    signal_dn: Float32Array
    saturated: BoolArray
    cfa_pattern: str
    black_level_dn: tuple[float, float, float]
    clip_level_dn: tuple[float, float, float]
    channel_origin_px: tuple[tuple[float, float], ...]
    green_difference_dn: Float32Array | None = None
    green_sites_px: tuple[tuple[int, int], tuple[int, int]] = ((0, 1), (1, 0))
    region_origin: tuple[int, int] = (0, 0)
    full_plane_shape: tuple[int, int] | None = None
    decoding: str = "LibRaw"

    @property
    def plane_shape(self) -> tuple[int, int]:
        """``(h, w)`` of each plane."""
        return (int(self.signal_dn.shape[1]), int(self.signal_dn.shape[2]))

    @property
    def full_shape(self) -> tuple[int, int]:
        """``(h, w)`` of the full planes of the frame (whatever region was read)."""
        return self.full_plane_shape or self.plane_shape

    def cropped(self, region: PlaneRegion) -> RawPlanes:
        """The planes inside ``region`` (indices of the full planes), as views of these arrays.

        Raises
        ------
        ValueError
            When these planes do not cover the region.
        """
        rows, columns = region
        row0, column0 = self.region_origin
        local = (
            slice(rows.start - row0, rows.stop - row0),
            slice(columns.start - column0, columns.stop - column0),
        )
        height, width = self.plane_shape
        if not (0 <= local[0].start < local[0].stop <= height) or not (
            0 <= local[1].start < local[1].stop <= width
        ):
            raise ValueError(
                f"region {region} is not inside these planes (origin {self.region_origin})"
            )
        return RawPlanes(
            metadata=self.metadata,
            signal_dn=self.signal_dn[:, local[0], local[1]],
            saturated=self.saturated[:, local[0], local[1]],
            cfa_pattern=self.cfa_pattern,
            black_level_dn=self.black_level_dn,
            clip_level_dn=self.clip_level_dn,
            channel_origin_px=self.channel_origin_px,
            green_difference_dn=None
            if self.green_difference_dn is None
            else self.green_difference_dn[local[0], local[1]],
            green_sites_px=self.green_sites_px,
            region_origin=(rows.start, columns.start),
            full_plane_shape=self.full_shape,
            decoding=self.decoding,
        )

    @property
    def sensor_shape_px(self) -> tuple[int, int]:
        """``(height, width)`` in sensor pixels of the area the planes cover."""
        height, width = self.plane_shape
        return (2 * height, 2 * width)


@dataclass(frozen=True, eq=False)
class PlaneBuffers:
    """Arrays :func:`read_raw` may fill instead of allocating (a stream of frames reuses them).

    Parameters
    ----------
    signal_dn
        Shape ``(3, h, w)``, float32.
    saturated
        Shape ``(3, h, w)``, bool.
    """

    signal_dn: Float32Array
    saturated: BoolArray


@dataclass(frozen=True)
class _CfaLayout:
    """Where each colour sits in the 2×2 cell: ``(row, column)`` per site."""

    pattern: str
    red: tuple[int, int]
    greens: tuple[tuple[int, int], tuple[int, int]]
    blue: tuple[int, int]

    @property
    def channel_origin_px(self) -> tuple[tuple[float, float], ...]:
        (g1y, g1x), (g2y, g2x) = self.greens
        return (
            (float(self.red[0]), float(self.red[1])),
            ((g1y + g2y) / 2.0, (g1x + g2x) / 2.0),
            (float(self.blue[0]), float(self.blue[1])),
        )


def _check_file(path: Path) -> None:
    if not path.exists():
        raise RawFileError("file not found", source=str(path))
    if path.is_dir():
        raise RawFileError("is a directory, expected a RAW file", source=str(path))
    if path.stat().st_size == 0:
        raise RawFileError("file is empty (0 bytes): not a RAW file", source=str(path))


def _open_raw(path: Path) -> Any:
    try:
        return rawpy.imread(str(path))
    except rawpy.LibRawFileUnsupportedError as exc:
        raise RawFileError(
            "not a RAW file LibRaw can decode (unsupported format, or not a camera RAW)",
            source=str(path),
        ) from exc
    except rawpy.LibRawError as exc:
        raise RawFileError(
            f"corrupt or truncated RAW file (LibRaw: {_libraw_message(exc)})", source=str(path)
        ) from exc


def _libraw_message(exc: BaseException) -> str:
    text = exc.args[0] if exc.args else exc
    return text.decode(errors="replace") if isinstance(text, bytes) else str(text)


def read_raw_metadata(
    path: str | os.PathLike[str], *, exposure_s: float | None = None
) -> RawMetadata:
    """Read a RAW file's capture metadata without decoding its pixels where possible.

    The EXIF / DNG tags are read with exifread (a few kB of I/O). Only when they lack the exposure
    time is the file decoded by LibRaw to use its values.

    Parameters
    ----------
    path
        The RAW file.
    exposure_s
        Exposure time in seconds that overrides the file's.

    Returns
    -------
    RawMetadata

    Raises
    ------
    RawFileError
        The file is missing, empty, not a RAW file, corrupt or truncated.
    InputError
        The file has no exposure time and no override is given.
    """
    file = Path(path)
    _check_file(file)
    exif = exif_tags(file)
    if exposure_s is not None or exif_exposure_s(exif) is not None:
        return build_metadata(file, exif, None, exposure_s)
    with _open_raw(file) as raw:
        other = _unpacked(raw, file, lambda r: r.other)
    return build_metadata(file, exif, other, exposure_s)


def _unpacked(raw: Any, path: Path, read: Any) -> Any:
    """``read(raw)``, translating LibRaw's decoding errors (raised on first data access)."""
    try:
        return read(raw)
    except rawpy.LibRawError as exc:
        raise RawFileError(
            f"corrupt or truncated RAW file (LibRaw: {_libraw_message(exc)})", source=str(path)
        ) from exc


@dataclass(eq=False)
class UnpackedRaw:
    """A RAW file opened for decoding, with its EXIF tags: :func:`read_raw` then cuts it into planes
    (of a region chosen meanwhile).

    Either LibRaw has unpacked it (``raw``, ``visible``: most of the decoding, and LibRaw releases
    the GIL while it runs; LibRaw's copy of the pixels is held until closed), or it is a DNG the tile
    decoder reads (``tiles``: only its tags and tile offsets are read until :func:`read_raw` decodes
    the tiles of the region). ``fallback`` says why a DNG went to LibRaw; ``strict``: the tile
    decoder was asked for (``decoder="tiles"``), so its refusal is an error, not a fallback.
    """

    path: Path
    exif: Mapping[str, Any]
    raw: Any | None = None
    visible: NDArray[np.uint16] | None = None
    tiles: DngTiles | None = None
    fallback: str | None = None
    strict: bool = False

    def close(self) -> None:
        if self.raw is not None:
            self.raw.close()

    def __enter__(self) -> UnpackedRaw:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: exifread's names of the DNGVersion tag (older versions know it only by number).
_DNG_VERSION_KEYS = ("Image DNGVersion", "Image Tag 0xC612")


def _may_be_dng(exif: Mapping[str, Any]) -> bool:
    """A DNG, or a file exifread could not parse (tifffile then decides): other TIFF-based RAWs
    (NEF, CR2, ARW …) are not parsed twice."""
    return not exif or any(key in exif for key in _DNG_VERSION_KEYS)


def unpack_raw(path: str | os.PathLike[str], decoder: RawDecoder = "auto") -> UnpackedRaw:
    """Open ``path`` for :func:`read_raw`: a DNG the tile decoder reads is only opened (tags and
    tile offsets), anything else is unpacked by LibRaw (see :data:`RawDecoder` and, for the errors,
    :func:`read_raw`).

    Raises
    ------
    UnsupportedDng
        ``decoder="tiles"`` and the tile decoder does not read the file exactly.
    """
    if decoder not in RAW_DECODERS:
        raise ValueError(f"decoder must be one of {RAW_DECODERS}, got {decoder!r}")
    file = Path(path)
    _check_file(file)
    exif = exif_tags(file)
    fallback: str | None = None
    if decoder == "tiles" or (decoder == "auto" and _may_be_dng(exif)):
        try:
            return UnpackedRaw(file, exif, tiles=open_dng(file), strict=decoder == "tiles")
        except NotDng:
            if decoder == "tiles":
                raise
        except UnsupportedDng as exc:
            if decoder == "tiles":
                raise
            fallback = str(exc).removeprefix(f"{file}: ")
    raw = _open_raw(file)
    try:
        visible = _unpacked(raw, file, lambda r: r.raw_image_visible)
    except BaseException:
        raw.close()
        raise
    return UnpackedRaw(file, exif, raw=raw, visible=visible, fallback=fallback)


def _visible_colour_indices(raw: Any) -> NDArray[np.int64]:
    """Colour indices of the top-left 2×2 cell of the visible area (without rawpy's full map)."""
    sizes = raw.sizes
    return np.array(
        [
            [raw.raw_color(sizes.top_margin + row, sizes.left_margin + column) for column in (0, 1)]
            for row in (0, 1)
        ]
    )


def _cfa_layout(raw: Any, path: Path) -> _CfaLayout:
    if raw.raw_type != rawpy.RawType.Flat:
        raise RawFileError(
            "not a mosaiced (colour filter array) RAW: LibRaw reports a stacked/linear image "
            "(sRAW, Foveon or linear DNG); calib needs the undemosaiced sensor data",
            source=str(path),
        )
    description = raw.color_desc.decode("ascii", errors="replace")
    full_pattern = raw.raw_pattern
    if full_pattern is None or full_pattern.shape != (2, 2):
        shape = None if full_pattern is None else full_pattern.shape
        raise RawFileError(
            f"unsupported colour filter array (pattern shape {shape}, colours {description!r}): "
            "only 2×2 Bayer sensors (RGGB, BGGR, GRBG, GBRG) are supported, not X-Trans or CMYG",
            source=str(path),
        )
    pattern = _visible_colour_indices(raw)
    return _bayer_layout(pattern.tolist(), description, path)


def _bayer_layout(pattern: list[list[int]], description: str, path: Path) -> _CfaLayout:
    """The layout of a 2×2 cell of colour indices into ``description`` (e.g. ``"RGBG"``)."""
    sites: dict[str, list[tuple[int, int]]] = {"R": [], "G": [], "B": []}
    for row in range(2):
        for column in range(2):
            index = int(pattern[row][column])
            colour = description[index] if index < len(description) else "?"
            if colour not in sites:
                raise RawFileError(
                    f"unsupported colour filter colours {description!r}: only RGB Bayer sensors",
                    source=str(path),
                )
            sites[colour].append((row, column))
    if [len(sites[c]) for c in CHANNELS] != [1, 2, 1]:
        raise RawFileError(
            f"colour filter cell {pattern} ({description!r}) is not a Bayer cell with "
            "one red, two green and one blue site",
            source=str(path),
        )
    order = {site: colour for colour, places in sites.items() for site in places}
    name = "".join(order[(row, column)] for row in range(2) for column in range(2))
    return _CfaLayout(
        pattern=name,
        red=sites["R"][0],
        greens=(sites["G"][0], sites["G"][1]),
        blue=sites["B"][0],
    )


def _saturation_threshold(
    site: NDArray[np.uint16], black: float, white: float, fraction: float
) -> np.uint16:
    """Raw DN from which a site counts as saturated, lowered to a clipping plateau if one shows.

    Raw values are integers, so the threshold is rounded up and compared in the raw's own type.
    """
    threshold = black + fraction * (white - black)
    peak = float(site.max()) if site.size else 0.0
    if black + _PLATEAU_MIN_FRACTION * (white - black) < peak < threshold:
        at_peak = int(np.count_nonzero(site == peak))
        if at_peak >= _PLATEAU_MIN_COUNT:
            threshold = black + fraction * (peak - black)
    return np.uint16(min(math.ceil(threshold), 65535))


def read_raw(
    path: str | os.PathLike[str],
    *,
    exposure_s: float | None = None,
    saturation_fraction: float = DEFAULT_SATURATION_FRACTION,
    keep_green_difference: bool = False,
    buffers: PlaneBuffers | None = None,
    region: PlaneRegion | None = None,
    unpacked: UnpackedRaw | None = None,
    decoder: RawDecoder = "auto",
) -> RawPlanes:
    """Decode a RAW file into black-subtracted R, G, B planes at half resolution.

    Parameters
    ----------
    path
        Any RAW file LibRaw reads, with a 2×2 Bayer filter.
    exposure_s
        Exposure time in seconds that overrides the file's metadata.
    saturation_fraction
        A site is saturated from ``black + saturation_fraction · (white − black)`` DN, or from that
        fraction of a clipping plateau found below the nominal white level.
    keep_green_difference
        Also return the difference of the two green sites (for noise estimation).
    buffers
        Arrays to fill instead of allocating new ones (used when their shape fits).
    region
        Only these plane samples (rows, columns of the full planes; clipped to them). A DNG read by
        the tile decoder decodes only the tiles that meet the region; LibRaw unpacks the whole file,
        and then black subtraction and saturation flags cost only the region. A clipping plateau is
        looked for inside the region.
    unpacked
        ``path`` already opened (:func:`unpack_raw`); closed by this call.
    decoder
        See :data:`RawDecoder` (ignored when ``unpacked`` is given).

    Returns
    -------
    RawPlanes
        Planes of shape ``(3, height // 2, width // 2)`` of the visible sensor area (the DNG's
        ActiveArea; an odd last row or column is dropped), or of the region. The tile decoder
        subtracts the DNG's black level pixel by pixel (BlackLevel pattern and deltas, see
        :mod:`calib.image.dng_tiles`); ``black_level_dn`` then holds each site's mean.

    Raises
    ------
    RawFileError
        Missing, empty, non-RAW, corrupt or truncated file; unsupported sensor layout.
    UnsupportedDng
        ``decoder="tiles"`` and the tile decoder does not read the file exactly.
    InputError
        No exposure time in the metadata and no override.
    """
    if not 0.0 < saturation_fraction <= 1.0:
        raise ValueError(f"saturation_fraction must be in (0, 1], got {saturation_fraction}")
    source = unpacked if unpacked is not None else unpack_raw(path, decoder)
    options = (exposure_s, saturation_fraction, keep_green_difference, buffers, region)
    try:
        return _read_planes(source, *options)
    except UnsupportedDng as exc:  # a tile the decoder cannot place: LibRaw reads the file
        if source.tiles is None or source.strict:
            raise
        reason = str(exc).removeprefix(f"{source.path}: ")
    fallback = unpack_raw(source.path, "libraw")
    fallback.fallback = reason
    return _read_planes(fallback, *options)


def _read_planes(
    source: UnpackedRaw,
    exposure_s: float | None,
    saturation_fraction: float,
    keep_green_difference: bool,
    buffers: PlaneBuffers | None,
    region: PlaneRegion | None,
) -> RawPlanes:
    with source:
        pixels = _pixel_source(source, exposure_s)
        file = source.path
        visible_height, visible_width = pixels.visible_shape
        height, width = (visible_height // 2) * 2, (visible_width // 2) * 2
        if height < 2 or width < 2:
            raise RawFileError(
                f"visible sensor area {pixels.visible_shape} is too small", source=str(file)
            )
        full_plane_shape = (height // 2, width // 2)
        row0, row1, column0, column1 = 0, height // 2, 0, width // 2
        if region is not None:
            row0, row1 = max(region[0].start, 0), min(region[0].stop, row1)
            column0, column1 = max(region[1].start, 0), min(region[1].stop, column1)
            if row1 <= row0 or column1 <= column0:
                raise ValueError(f"region {region} is outside the planes {full_plane_shape}")
        window = pixels.window(slice(2 * row0, 2 * row1), slice(2 * column0, 2 * column1))
        layout = pixels.layout

        def site_view(site: tuple[int, int]) -> NDArray[np.uint16]:
            return window.values[site[0] :: 2, site[1] :: 2]

        plane_shape = (row1 - row0, column1 - column0)
        if buffers is not None and buffers.signal_dn.shape == (3, *plane_shape):
            signal, saturated = buffers.signal_dn, buffers.saturated
        else:
            signal = np.empty((3, *plane_shape), dtype=np.float32)
            saturated = np.empty((3, *plane_shape), dtype=np.bool_)
        blacks: list[float] = []
        clips: list[float] = []
        for channel, site in ((0, layout.red), (2, layout.blue)):
            view = site_view(site)
            black, white = pixels.levels(site)
            np.subtract(view, np.float32(black), out=signal[channel], dtype=np.float32)
            offset = window.black_offset(site)
            if offset is not None:
                signal[channel] -= offset
            threshold = _saturation_threshold(view, black, white, saturation_fraction)
            np.greater_equal(view, threshold, out=saturated[channel])
            blacks.append(black)
            clips.append(white - black)
        first, second = (site_view(site) for site in layout.greens)
        (black_1, white_1), (black_2, white_2) = (pixels.levels(site) for site in layout.greens)
        offset_1, offset_2 = (window.black_offset(site) for site in layout.greens)
        green = signal[1]
        np.add(first, second, out=green, dtype=np.float32)
        green -= np.float32(black_1 + black_2)
        for offset in (offset_1, offset_2):
            if offset is not None:
                green -= offset
        green *= np.float32(0.5)
        np.greater_equal(
            first,
            _saturation_threshold(first, black_1, white_1, saturation_fraction),
            out=saturated[1],
        )
        saturated[1] |= second >= _saturation_threshold(
            second, black_2, white_2, saturation_fraction
        )
        green_difference: Float32Array | None = None
        if keep_green_difference:
            green_difference = np.subtract(first, second, dtype=np.float32)
            green_difference -= np.float32(black_1 - black_2)
            if offset_1 is not None and offset_2 is not None:
                green_difference -= offset_1 - offset_2
    return RawPlanes(
        metadata=pixels.metadata,
        signal_dn=signal,
        saturated=saturated,
        cfa_pattern=layout.pattern,
        black_level_dn=(blacks[0], (black_1 + black_2) / 2.0, blacks[1]),
        clip_level_dn=(clips[0], min(white_1 - black_1, white_2 - black_2), clips[1]),
        channel_origin_px=layout.channel_origin_px,
        green_difference_dn=green_difference,
        green_sites_px=layout.greens,
        region_origin=(row0, column0),
        full_plane_shape=full_plane_shape,
        decoding=window.decoding,
    )


@dataclass(frozen=True, eq=False)
class _Window:
    """Raw values of a window of the visible area and what black to subtract beyond each site's."""

    values: NDArray[np.uint16]
    decoding: str
    tiles: DngTiles | None = None
    rows: slice | None = None
    columns: slice | None = None

    def black_offset(self, site: tuple[int, int]) -> Float32Array | None:
        """Per-sample black of ``site`` minus the site's mean black (``None`` where it is 0)."""
        if self.tiles is None or self.rows is None or self.columns is None:
            return None
        if not self.tiles.black_varies_within_sites():
            return None
        rows = slice(self.rows.start + site[0], self.rows.stop, 2)
        columns = slice(self.columns.start + site[1], self.columns.stop, 2)
        black = self.tiles.black_dn(rows, columns) - self.tiles.site_black_dn(site)
        return black.astype(np.float32)


@dataclass(frozen=True, eq=False)
class _PixelSource:
    """What :func:`read_raw` needs of a decoder: layout, levels per site, windows of raw values."""

    metadata: RawMetadata
    layout: _CfaLayout
    visible_shape: tuple[int, int]
    site_levels: dict[tuple[int, int], tuple[float, float]]
    window: Callable[[slice, slice], _Window]

    def levels(self, site: tuple[int, int]) -> tuple[float, float]:
        """``(black, white)`` of a site of the 2×2 cell, DN."""
        return self.site_levels[site]


_SITES = ((0, 0), (0, 1), (1, 0), (1, 1))


def _pixel_source(source: UnpackedRaw, exposure_s: float | None) -> _PixelSource:
    file, exif, tiles = source.path, source.exif, source.tiles
    if tiles is not None:
        other = None
        if exposure_s is None and exif_exposure_s(exif) is None:  # LibRaw's fallback values
            with _open_raw(file) as raw:
                other = _unpacked(raw, file, lambda r: r.other)
        tiles_of = tiles

        def tile_window(rows: slice, columns: slice) -> _Window:
            read = tiles_of.blocks_meeting(rows, columns)
            try:
                values = tiles_of.decode(rows, columns)
            except CorruptDng as exc:
                message = str(exc).removeprefix(f"{file}: ")
                raise RawFileError(
                    f"corrupt or truncated RAW file ({message})", source=str(file)
                ) from exc
            return _Window(
                values,
                f"tiles: {read} of {tiles_of.block_count}",
                tiles_of,
                rows,
                columns,
            )

        return _PixelSource(
            metadata=build_metadata(file, exif, other, exposure_s),
            layout=_bayer_layout([list(row) for row in tiles.cfa_colours], "RGB", file),
            visible_shape=tiles.visible_shape,
            site_levels={
                site: (tiles.site_black_dn(site), tiles.white_level_dn) for site in _SITES
            },
            window=tile_window,
        )
    raw, visible = source.raw, source.visible
    assert raw is not None and visible is not None
    layout = _cfa_layout(raw, file)
    colour_index = _visible_colour_indices(raw)
    black_per_colour = [float(b) for b in raw.black_level_per_channel]
    white_per_colour = raw.camera_white_level_per_channel
    white_default = float(raw.white_level)

    def levels(site: tuple[int, int]) -> tuple[float, float]:
        index = int(colour_index[site])
        white = white_default
        if white_per_colour is not None and white_per_colour[index] > 0:
            white = float(white_per_colour[index])
        return black_per_colour[index], white

    decoding = "LibRaw" if source.fallback is None else f"LibRaw ({source.fallback})"

    def libraw_window(rows: slice, columns: slice) -> _Window:
        return _Window(visible[rows, columns], decoding)

    return _PixelSource(
        metadata=build_metadata(file, exif, raw.other, exposure_s),
        layout=layout,
        visible_shape=(int(visible.shape[0]), int(visible.shape[1])),
        site_levels={site: levels(site) for site in _SITES},
        window=libraw_window,
    )
