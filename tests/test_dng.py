"""mocks.dng: DNG files that rawpy, exifread and tifffile read back exactly as written."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime
from pathlib import Path

import exifread
import numpy as np
import pytest
import rawpy
import tifffile
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.dng import CFA_PATTERN_CODES, DngMetadata, DngWriteError, write_dng

#: rawpy's raw_pattern (colour indices 0 R, 1 G, 2 B, 3 second G) for each CFA layout.
RAWPY_PATTERNS = {
    "RGGB": [[0, 1], [3, 2]],
    "BGGR": [[2, 3], [1, 0]],
    "GRBG": [[1, 0], [2, 3]],
    "GBRG": [[3, 2], [0, 1]],
}


def _random_cfa(rng: np.random.Generator, shape: tuple[int, int], white: int) -> np.ndarray:
    return rng.integers(0, white + 1, size=shape).astype(np.uint16)


@pytest.mark.parametrize("pattern", sorted(CFA_PATTERN_CODES))
def test_pixels_and_levels_round_trip_through_rawpy(
    tmp_path: Path, rng: np.random.Generator, pattern: str
) -> None:
    data = _random_cfa(rng, (64, 96), 4095)
    metadata = DngMetadata(
        exposure_s=1 / 250,
        iso=400,
        f_number=8.0,
        cfa_pattern=pattern,
        black_level_dn=(60, 61, 62, 63),
        white_level_dn=4095,
        capture_time=datetime(2025, 3, 4, 5, 6, 7),
    )
    path = write_dng(tmp_path / "frame.dng", data, metadata)
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, data)
        assert raw.raw_pattern.tolist() == RAWPY_PATTERNS[pattern]
        # raster-order black levels come back per colour index
        by_position = {
            (row, column): raw.black_level_per_channel[RAWPY_PATTERNS[pattern][row][column]]
            for row in (0, 1)
            for column in (0, 1)
        }
        assert [
            by_position[(0, 0)],
            by_position[(0, 1)],
            by_position[(1, 0)],
            by_position[(1, 1)],
        ] == [60, 61, 62, 63]
        assert raw.white_level == 4095
        assert raw.other.iso_speed == 400
        assert raw.other.shutter_speed == pytest.approx(1 / 250, rel=1e-6)
        assert raw.other.aperture == pytest.approx(8.0)
        assert raw.other.timestamp == datetime(2025, 3, 4, 5, 6, 7)
        np.testing.assert_allclose(raw.camera_whitebalance[:3], [2.0, 1.0, 1.49993], rtol=1e-4)


def test_exif_ifd_is_readable_by_exifread_and_tifffile(tmp_path: Path) -> None:
    metadata = DngMetadata(
        exposure_s=1 / 8000, iso=3200, f_number=2.8, make="Maker", model="Body 7"
    )
    path = write_dng(tmp_path / "frame.dng", np.full((32, 48), 700, np.uint16), metadata)
    with path.open("rb") as handle:
        tags = exifread.process_file(handle, details=False)
    assert str(tags["Image Make"]) == "Maker"
    assert str(tags["Image Model"]) == "Body 7"
    assert str(tags["EXIF ExposureTime"]) == "1/8000"
    assert str(tags["EXIF ISOSpeedRatings"]) == "3200"
    assert str(tags["EXIF FNumber"]) == "14/5"
    with tifffile.TiffFile(path) as tiff:
        exif = tiff.pages.first.tags["ExifTag"].value
        assert exif["ISOSpeedRatings"] == 3200
        assert exif["ExposureTime"] == (1, 8000)
        assert tiff.pages.first.tags["UniqueCameraModel"].value == "Maker Body 7"


def test_optional_fields_can_be_left_out(tmp_path: Path) -> None:
    metadata = DngMetadata(exposure_s=None, iso=None, f_number=None)
    path = write_dng(tmp_path / "bare.dng", np.full((32, 32), 600, np.uint16), metadata)
    with rawpy.imread(str(path)) as raw:
        assert raw.other.shutter_speed == 0
        assert raw.other.iso_speed == 0
        assert raw.other.aperture == 0


@pytest.mark.parametrize("shape", [(63, 95), (22, 22), (101, 64)])
def test_odd_and_minimal_sizes_round_trip(
    tmp_path: Path, rng: np.random.Generator, shape: tuple[int, int]
) -> None:
    data = _random_cfa(rng, shape, 16383)
    path = write_dng(tmp_path / "odd.dng", data, DngMetadata(exposure_s=0.01))
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, data)


def test_active_area_crops_the_visible_image(tmp_path: Path, rng: np.random.Generator) -> None:
    data = _random_cfa(rng, (40, 60), 4095)
    metadata = DngMetadata(
        exposure_s=0.01, white_level_dn=4095, cfa_pattern="GRBG", active_area=(4, 6, 36, 56)
    )
    path = write_dng(tmp_path / "margins.dng", data, metadata)
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, data[4:36, 6:56])
        assert (raw.sizes.top_margin, raw.sizes.left_margin) == (4, 6)


def test_full_16_bit_range_round_trips(tmp_path: Path, rng: np.random.Generator) -> None:
    data = _random_cfa(rng, (48, 48), 65535)
    data[0, :4] = (0, 1, 65534, 65535)
    path = write_dng(
        tmp_path / "full.dng",
        data,
        DngMetadata(exposure_s=1.0, black_level_dn=0, white_level_dn=65535),
    )
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, data)


@settings(max_examples=20, deadline=None)
@given(
    height=st.integers(22, 70),
    width=st.integers(22, 70),
    pattern=st.sampled_from(sorted(CFA_PATTERN_CODES)),
    seed=st.integers(0, 2**32 - 1),
)
def test_any_array_round_trips(
    tmp_path_factory: pytest.TempPathFactory, height: int, width: int, pattern: str, seed: int
) -> None:
    data = np.random.default_rng(seed).integers(0, 4096, (height, width)).astype(np.uint16)
    path = tmp_path_factory.mktemp("dng") / "any.dng"
    write_dng(path, data, DngMetadata(exposure_s=0.02, cfa_pattern=pattern, white_level_dn=4095))
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, data)


def test_integer_arrays_are_accepted_and_written_as_uint16(tmp_path: Path) -> None:
    data = np.arange(32 * 32, dtype=np.int64).reshape(32, 32) % 4000
    path = write_dng(tmp_path / "int.dng", data, DngMetadata(exposure_s=0.1, white_level_dn=4095))
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, data)


def test_writing_is_atomic_and_replaces(tmp_path: Path) -> None:
    path = tmp_path / "frame.dng"
    path.write_bytes(b"old")
    write_dng(path, np.full((32, 32), 600, np.uint16), DngMetadata(exposure_s=0.1))
    assert path.read_bytes()[:2] in (b"II", b"MM")
    assert [p.name for p in tmp_path.iterdir()] == ["frame.dng"]


@pytest.mark.parametrize(
    ("data", "metadata", "message"),
    [
        (np.zeros((32, 32), np.float32), DngMetadata(exposure_s=0.1), "integers"),
        (np.zeros((10, 32), np.uint16), DngMetadata(exposure_s=0.1), "at least 22"),
        (np.zeros((32,), np.uint16), DngMetadata(exposure_s=0.1), "2-D"),
        (
            np.full((32, 32), 5000, np.uint16),
            DngMetadata(exposure_s=0.1, white_level_dn=4095),
            "exceed",
        ),
        (np.full((32, 32), -1, np.int32), DngMetadata(exposure_s=0.1), "0..65535"),
        (
            np.zeros((40, 40), np.uint16),
            DngMetadata(exposure_s=0.1, active_area=(3, 5, 37, 39)),
            "even",
        ),
        (
            np.zeros((40, 40), np.uint16),
            DngMetadata(exposure_s=0.1, active_area=(0, 0, 50, 40)),
            "does not fit",
        ),
    ],
)
def test_unwritable_input_is_rejected(
    tmp_path: Path, data: np.ndarray, metadata: DngMetadata, message: str
) -> None:
    with pytest.raises(DngWriteError, match=message):
        write_dng(tmp_path / "bad.dng", data, metadata)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"exposure_s": 0.0}, "exposure_s"),
        ({"exposure_s": float("nan")}, "exposure_s"),
        ({"exposure_s": 0.1, "cfa_pattern": "RGBW"}, "cfa_pattern"),
        ({"exposure_s": 0.1, "iso": 0}, "iso"),
        ({"exposure_s": 0.1, "black_level_dn": 5000, "white_level_dn": 4095}, "black"),
        ({"exposure_s": 0.1, "black_level_dn": (1, 2, 3)}, r"rows × columns values"),
        ({"exposure_s": 0.1, "tile_px": (100, 128)}, "multiples of 16"),
        ({"exposure_s": 0.1, "tile_px": (128, 128), "rows_per_strip": 8}, "not both"),
        ({"exposure_s": 0.1, "color_matrix1": ((1.0, 0.0), (0.0, 1.0))}, "3×3"),
    ],
)
def test_invalid_metadata_is_rejected(fields: dict[str, object], message: str) -> None:
    with pytest.raises(DngWriteError, match=message):
        DngMetadata(**fields)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("shape", "white", "active_area"),
    [((300, 520), 16383, None), ((64, 96), 4095, (2, 4, 62, 90)), ((22, 22), 65535, None)],
)
def test_lossless_jpeg_tiles_round_trip_exactly(
    tmp_path: Path,
    rng: np.random.Generator,
    shape: tuple[int, int],
    white: int,
    active_area: tuple[int, int, int, int] | None,
) -> None:
    data = _random_cfa(rng, shape, white)
    metadata = DngMetadata(
        exposure_s=1 / 60, iso=200, white_level_dn=white, black_level_dn=0, active_area=active_area
    )
    path = write_dng(tmp_path / "frame.dng", data, replace(metadata, compression="lossless-jpeg"))
    with tifffile.TiffFile(path) as tiff:
        page = tiff.pages[0]
        assert page.compression == 7
        assert page.is_tiled == (min(shape) >= 256)
    with rawpy.imread(str(path)) as raw:
        top, left, bottom, right = active_area or (0, 0, *shape)
        assert np.array_equal(raw.raw_image_visible, data[top:bottom, left:right])
    with path.open("rb") as handle:
        tags = exifread.process_file(handle, details=False)
    assert str(tags["EXIF ISOSpeedRatings"]) == "200"


def test_lossless_jpeg_is_smaller_for_a_smooth_scene(tmp_path: Path) -> None:
    rows, columns = np.mgrid[0:256, 0:512]
    data = (600 + 2 * columns + rows).astype(np.uint16)
    plain = write_dng(tmp_path / "plain.dng", data, DngMetadata(exposure_s=0.01))
    packed = write_dng(
        tmp_path / "packed.dng", data, DngMetadata(exposure_s=0.01, compression="lossless-jpeg")
    )
    assert packed.stat().st_size < 0.5 * plain.stat().st_size


def test_unknown_compression_is_refused() -> None:
    with pytest.raises(DngWriteError, match="compression 'zip' is not one of"):
        DngMetadata(exposure_s=0.01, compression="zip")
