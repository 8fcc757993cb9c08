"""calib.image.dng_tiles through read_raw: a region of a DNG decoded tile by tile equals LibRaw.

LibRaw is the reference. Where its black-level model is the DNG specification's (integer BlackLevel
per CFA position or single, constant integer deltas) the planes are bit-identical to LibRaw's
black-subtracted planes; where LibRaw departs from the specification (it truncates fractional black
levels, averages the per-row and per-column deltas, and keeps only what a 2×2 cell holds of a larger
BlackLevel pattern) the tile decoder follows the specification, and the reference is LibRaw's pixel
values minus the specification's black, computed here from the values written.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import imagecodecs
import numpy as np
import pytest
import rawpy
import tifffile

from calib.image.dng_tiles import NotDng, UnsupportedDng, open_dng
from calib.image.raw import RawFileError, RawPlanes, read_raw
from mocks.dng import DngMetadata, write_dng
from mocks.scene import BAYER_SITES

SHAPE = (300, 520)
WHITE = 4095
#: A window of the planes (150 × 260) that meets a few tiles of every layout below.
REGION = (slice(37, 101), slice(50, 171))


def _data(
    rng: np.random.Generator, shape: tuple[int, int] = SHAPE, high: int = WHITE
) -> np.ndarray:
    data = rng.integers(400, high - 200, shape).astype(np.uint16)
    data[40:60, 120:160] = high  # clipped sites, so saturation flags are compared too
    return data


def _write(path: Path, data: np.ndarray, **fields: Any) -> Path:
    metadata = DngMetadata(exposure_s=0.01, white_level_dn=WHITE, **fields)
    return write_dng(path, data, metadata)


def _assert_identical(tiles: RawPlanes, libraw: RawPlanes) -> None:
    np.testing.assert_array_equal(tiles.signal_dn, libraw.signal_dn)
    np.testing.assert_array_equal(tiles.saturated, libraw.saturated)
    assert tiles.green_difference_dn is not None and libraw.green_difference_dn is not None
    np.testing.assert_array_equal(tiles.green_difference_dn, libraw.green_difference_dn)
    for field in (
        "cfa_pattern",
        "black_level_dn",
        "clip_level_dn",
        "channel_origin_px",
        "green_sites_px",
        "region_origin",
        "full_shape",
        "metadata",
    ):
        assert getattr(tiles, field) == getattr(libraw, field), field


def _both(path: Path, region: tuple[slice, slice] | None) -> tuple[RawPlanes, RawPlanes]:
    options: dict[str, Any] = {"region": region, "keep_green_difference": True}
    return (
        read_raw(path, decoder="tiles", **options),
        read_raw(path, decoder="libraw", **options),
    )


#: DNG layouts whose black level LibRaw models as the specification does: bit-identical.
EXACT_VARIANTS: dict[str, dict[str, Any]] = {
    "lossless-jpeg 256² tiles": {
        "compression": "lossless-jpeg",
        "black_level_dn": (500, 510, 520, 530),
    },
    "lossless-jpeg 64×96 tiles, BGGR": {
        "compression": "lossless-jpeg",
        "tile_px": (64, 96),
        "cfa_pattern": "BGGR",
    },
    "lossless-jpeg 2-component tiles (Adobe)": {
        "compression": "lossless-jpeg",
        "tile_px": (128, 128),
        "jpeg_components": 2,
        "cfa_pattern": "GRBG",
    },
    "uncompressed 48×80 tiles, GBRG": {"tile_px": (48, 80), "cfa_pattern": "GBRG"},
    "uncompressed strips of 37 rows": {"rows_per_strip": 37},
    "uncompressed single strip": {},
    "active area inside the tiles": {
        "compression": "lossless-jpeg",
        "tile_px": (64, 64),
        "active_area": (6, 10, 290, 500),
        "black_level_dn": (500, 510, 520, 530),
    },
    "default crop (coordinates stay the active area's)": {
        "compression": "lossless-jpeg",
        "tile_px": (64, 64),
        "default_crop": (8, 6, 480, 280),
    },
    "single black level": {
        "compression": "lossless-jpeg",
        "tile_px": (64, 64),
        "black_level_dn": 300,
    },
    "constant integer black deltas": {
        "compression": "lossless-jpeg",
        "tile_px": (64, 64),
        "black_level_dn": (256, 258, 260, 262),
        "black_delta_v_dn": (2.0,) * SHAPE[0],
        "black_delta_h_dn": (3.0,) * SHAPE[1],
    },
}


@pytest.mark.parametrize("variant", sorted(EXACT_VARIANTS))
def test_region_planes_equal_libraw_bit_for_bit(
    tmp_path: Path, rng: np.random.Generator, variant: str
) -> None:
    path = _write(tmp_path / "frame.dng", _data(rng), **EXACT_VARIANTS[variant])
    for region in (REGION, None):
        tiles, libraw = _both(path, region)
        _assert_identical(tiles, libraw)
        assert libraw.decoding == "LibRaw"
        read, total = (int(part) for part in tiles.decoding.removeprefix("tiles: ").split(" of "))
        if region is not None and total > 2:
            assert read < total


def test_lossless_jpeg_strips_are_read_whole(tmp_path: Path, rng: np.random.Generator) -> None:
    """LibRaw 0.22 reads only the first strip of a lossless-JPEG DNG in several strips (the rest
    comes back 0); the tile decoder reads every strip, so the reference is the data written."""
    data = _data(rng)
    path = _write(
        tmp_path / "strips.dng",
        data,
        compression="lossless-jpeg",
        rows_per_strip=48,
        black_level_dn=0,
    )
    planes = read_raw(path, decoder="tiles", region=REGION)
    assert planes.decoding == "tiles: 4 of 7"  # plane rows 37–100: sensor rows 74–201
    np.testing.assert_array_equal(planes.signal_dn[0], data[74:202:2, 100:342:2])
    np.testing.assert_array_equal(planes.signal_dn[2], data[75:202:2, 101:342:2])


def test_odd_sizes_and_a_linearization_table(tmp_path: Path, rng: np.random.Generator) -> None:
    table = tuple(int(v) for v in np.round(np.linspace(0, 1, 1024) ** 1.6 * WHITE))
    stored = rng.integers(0, 1024, (301, 523)).astype(np.uint16)
    stored[10:20, 10:40] = 1023
    path = _write(
        tmp_path / "linear.dng",
        stored,
        compression="lossless-jpeg",
        tile_px=(64, 80),
        linearization_table=table,
        black_level_dn=64,
    )
    tiles, libraw = _both(path, (slice(3, 150), slice(200, 261)))
    _assert_identical(tiles, libraw)
    assert tiles.full_shape == (150, 261)  # the odd last row and column are dropped
    tiles, libraw = _both(path, None)
    _assert_identical(tiles, libraw)
    np.testing.assert_array_equal(
        tiles.signal_dn[0], np.asarray(table)[stored[0:300:2, 0:522:2]] - 64.0
    )


def _spec_black(metadata: DngMetadata, shape: tuple[int, int]) -> np.ndarray:
    """Black of every active-area pixel by DNG 1.7 §5, from the values written."""
    pattern = metadata.black_pattern_dn
    rows, columns = np.indices(shape)
    black = pattern[rows % pattern.shape[0], columns % pattern.shape[1]]
    if metadata.black_delta_v_dn is not None:
        black = black + np.asarray(metadata.black_delta_v_dn)[:, None]
    if metadata.black_delta_h_dn is not None:
        black = black + np.asarray(metadata.black_delta_h_dn)[None, :]
    return np.asarray(black, dtype=np.float64)


#: Black-level layouts LibRaw reads differently from the specification, and how far its planes
#: may then lie from the specification's (DN).
SPEC_VARIANTS: dict[str, tuple[dict[str, Any], float | None]] = {
    "fractional black levels (LibRaw truncates)": (
        {"black_level_dn": (511.5, 512.25, 512.75, 513.0)},
        1.0,
    ),
    "fractional single black level": ({"black_level_dn": 300.5}, 1.0),
    "varying black deltas (LibRaw adds their means)": (
        {
            "black_level_dn": (500, 500, 500, 500),
            "black_delta_v_dn": tuple(np.linspace(-3.0, 3.0, SHAPE[0])),
            "black_delta_h_dn": tuple(4.0 * np.sin(np.arange(SHAPE[1]) / 7.0)),
        },
        None,
    ),
    "4×4 black pattern (LibRaw keeps a 2×2 part)": (
        {"black_level_dn": tuple(500.0 + np.arange(16)), "black_repeat": (4, 4)},
        None,
    ),
    "1×2 black pattern": ({"black_level_dn": (500, 507), "black_repeat": (1, 2)}, 0.0),
}


@pytest.mark.parametrize("variant", sorted(SPEC_VARIANTS))
def test_black_level_follows_the_dng_specification(
    tmp_path: Path, rng: np.random.Generator, variant: str
) -> None:
    fields, libraw_tolerance = SPEC_VARIANTS[variant]
    path = _write(
        tmp_path / "black.dng", _data(rng), compression="lossless-jpeg", tile_px=(64, 64), **fields
    )
    metadata = DngMetadata(exposure_s=0.01, white_level_dn=WHITE, **fields)
    with rawpy.imread(str(path)) as raw:
        pixels = np.asarray(raw.raw_image_visible, dtype=np.float64)
    reference: np.ndarray = pixels - _spec_black(metadata, (pixels.shape[0], pixels.shape[1]))
    sites = BAYER_SITES[metadata.cfa_pattern]
    rows, columns = REGION

    def site(position: tuple[int, int]) -> np.ndarray:
        return reference[
            2 * rows.start + position[0] : 2 * rows.stop : 2,
            2 * columns.start + position[1] : 2 * columns.stop : 2,
        ]

    tiles, libraw = _both(path, REGION)
    (red,), (blue,), (first, second) = sites["R"], sites["B"], sites["G"]
    np.testing.assert_allclose(tiles.signal_dn[0], site(red), atol=1e-3)
    np.testing.assert_allclose(tiles.signal_dn[2], site(blue), atol=1e-3)
    np.testing.assert_allclose(tiles.signal_dn[1], (site(first) + site(second)) / 2, atol=1e-3)
    assert tiles.green_difference_dn is not None
    np.testing.assert_allclose(tiles.green_difference_dn, site(first) - site(second), atol=1e-3)
    if libraw_tolerance is not None:  # LibRaw subtracts a truncated black: never more
        difference = libraw.signal_dn - tiles.signal_dn
        assert difference.min() >= -1e-3 and difference.max() <= libraw_tolerance
    else:  # LibRaw's model is coarser: the difference is the specification's detail
        assert np.abs(libraw.signal_dn - tiles.signal_dn).max() > 1.0


#: DNGs LibRaw reads but the tile decoder does not read exactly, and the reason it gives.
UNSUPPORTED: dict[str, tuple[dict[str, Any], str]] = {
    "opcode list 2": (
        {"extra_tags": ((51009, "B", 4, (0, 0, 0, 0)),)},
        "OpcodeList2 present",
    ),
    "masked areas": (
        {"active_area": (8, 0, 300, 520), "extra_tags": ((50830, "I", 4, (0, 0, 8, 520)),)},
        "MaskedAreas present",
    ),
    "odd active-area origin": (
        {"extra_tags": ((50829, "I", 4, (1, 0, 299, 520)),)},
        r"ActiveArea starts at an odd row or column \(1, 0\)",
    ),
}


@pytest.mark.parametrize("variant", sorted(UNSUPPORTED))
def test_unsupported_dngs_fall_back_to_libraw_saying_why(
    tmp_path: Path, rng: np.random.Generator, variant: str
) -> None:
    fields, reason = UNSUPPORTED[variant]
    path = _write(tmp_path / "odd.dng", _data(rng), tile_px=(64, 64), **fields)
    with pytest.raises(UnsupportedDng, match=reason) as refused:
        read_raw(path, decoder="tiles")
    message = str(refused.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    assert message.endswith("LibRaw decodes it")
    auto = read_raw(path, region=REGION, keep_green_difference=True)
    libraw = read_raw(path, decoder="libraw", region=REGION, keep_green_difference=True)
    assert auto.decoding.startswith("LibRaw (") and reason.split(" ")[0] in auto.decoding
    np.testing.assert_array_equal(auto.signal_dn, libraw.signal_dn)


def test_a_tile_that_does_not_decode_to_the_tile_size_falls_back(
    tmp_path: Path, rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _write(tmp_path / "f.dng", _data(rng), compression="lossless-jpeg", tile_px=(64, 64))
    decode = imagecodecs.ljpeg_decode
    monkeypatch.setattr(imagecodecs, "ljpeg_decode", lambda data: decode(data)[:32])
    planes = read_raw(path, region=REGION)
    assert planes.decoding.startswith("LibRaw (lossless-JPEG tile")
    assert "decodes to 32×64, not the tile's 64×64" in planes.decoding
    with pytest.raises(UnsupportedDng, match="decodes to 32×64"):
        read_raw(path, region=REGION, decoder="tiles")
    monkeypatch.undo()
    np.testing.assert_array_equal(planes.signal_dn, read_raw(path, region=REGION).signal_dn)


def test_other_files_are_not_dngs(tmp_path: Path) -> None:
    plain = tmp_path / "photo.tif"
    tifffile.imwrite(plain, np.zeros((32, 32), np.uint16))
    text = tmp_path / "notes.dng"
    text.write_text("not a raw file\n" * 10)
    for path, reason in ((plain, "no DNGVersion"), (text, "not a TIFF-based file")):
        with pytest.raises(NotDng, match=reason):
            open_dng(path)


def test_a_corrupt_or_truncated_tile_names_the_file(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    path = _write(tmp_path / "f.dng", _data(rng), compression="lossless-jpeg", tile_px=(64, 64))
    start = open_dng(path).offsets[3] + 10
    content = path.read_bytes()
    path.write_bytes(content[:start] + b"\0" * (len(content) - start))  # tile 3 zeroed
    with pytest.raises(RawFileError, match=r"corrupt or truncated RAW file .*tile 3") as caught:
        read_raw(path, decoder="tiles")
    assert str(caught.value).startswith(f"{path}: ")
    strip = _write(tmp_path / "strip.dng", _data(rng))
    tiles = open_dng(strip)
    strip.write_bytes(strip.read_bytes()[: tiles.offsets[0] + tiles.byte_counts[0] // 2])
    with pytest.raises(RawFileError, match=r"corrupt or truncated RAW file") as caught:
        read_raw(strip, decoder="tiles", exposure_s=0.01)
    assert str(caught.value).startswith(f"{strip}: ")


def test_only_the_tiles_meeting_the_window_are_read(
    tmp_path: Path, rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _write(tmp_path / "f.dng", _data(rng), compression="lossless-jpeg", tile_px=(64, 64))
    tiles = open_dng(path)
    assert (tiles.block_shape, tiles.blocks_across, tiles.block_count) == ((64, 64), 9, 45)
    decoded: list[int] = []
    decode = imagecodecs.ljpeg_decode

    def counting(data: bytes) -> np.ndarray:
        decoded.append(len(data))
        return np.asarray(decode(data))

    monkeypatch.setattr(imagecodecs, "ljpeg_decode", counting)
    window = tiles.decode(slice(60, 130), slice(120, 200))  # rows 60–129: tiles 0–2; columns 1–3
    assert len(decoded) == tiles.blocks_meeting(slice(60, 130), slice(120, 200)) == 9
    with rawpy.imread(str(path)) as raw:
        np.testing.assert_array_equal(window, raw.raw_image_visible[60:130, 120:200])


def test_the_writer_variants_are_what_they_say(tmp_path: Path, rng: np.random.Generator) -> None:
    path = _write(
        tmp_path / "f.dng",
        _data(rng),
        compression="lossless-jpeg",
        tile_px=(64, 96),
        black_level_dn=(500.5, 501, 502, 503),
        black_delta_v_dn=(1.5,) * SHAPE[0],
        default_crop=(8, 6, 480, 280),
    )
    tiles = open_dng(path)
    assert tiles.compression == 7 and tiles.block_shape == (64, 96)
    np.testing.assert_array_equal(tiles.black_pattern_dn, [[500.5, 501], [502, 503]])
    assert tiles.black_delta_v_dn is not None and np.all(tiles.black_delta_v_dn == 1.5)
    assert tiles.default_crop == (6.0, 8.0, 280.0, 480.0)
    assert replace(DngMetadata(exposure_s=1.0), black_level_dn=7).black_pattern_dn.shape == (1, 1)
