"""calib.image.raw: RAW files → black-subtracted R, G, B planes, saturation, metadata, clear errors."""

from __future__ import annotations

import io
import struct
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from calib.core.errors import InputError
from calib.image.raw import RawFileError, read_raw, read_raw_metadata
from mocks.dng import CFA_PATTERN_CODES, DngMetadata, write_dng
from mocks.scene import BAYER_SITES

BLACKS_RASTER = (500, 510, 520, 530)  # per 2×2 position, raster order


def _site_blacks(pattern: str) -> dict[tuple[int, int], int]:
    return {(row, column): BLACKS_RASTER[2 * row + column] for row in (0, 1) for column in (0, 1)}


def _write(path: Path, data: np.ndarray, **fields: object) -> Path:
    metadata = DngMetadata(**{"exposure_s": 0.01, "white_level_dn": 4095, **fields})  # type: ignore[arg-type]
    return write_dng(path, data, metadata)


@pytest.mark.parametrize("pattern", sorted(CFA_PATTERN_CODES))
def test_planes_are_the_black_subtracted_cfa_sites(
    tmp_path: Path, rng: np.random.Generator, pattern: str
) -> None:
    data = rng.integers(530, 3000, (48, 64)).astype(np.uint16)
    path = _write(tmp_path / "f.dng", data, cfa_pattern=pattern, black_level_dn=BLACKS_RASTER)
    planes = read_raw(path, keep_green_difference=True)
    sites = BAYER_SITES[pattern]
    blacks = _site_blacks(pattern)

    def site(position: tuple[int, int]) -> np.ndarray:
        return data[position[0] :: 2, position[1] :: 2].astype(np.float64) - blacks[position]

    (red,) = sites["R"]
    (blue,) = sites["B"]
    first, second = sites["G"]
    assert planes.cfa_pattern == pattern
    assert planes.signal_dn.shape == (3, 24, 32)
    assert planes.signal_dn.dtype == np.float32
    np.testing.assert_array_equal(planes.signal_dn[0], site(red))
    np.testing.assert_array_equal(planes.signal_dn[2], site(blue))
    np.testing.assert_allclose(planes.signal_dn[1], (site(first) + site(second)) / 2, atol=1e-3)
    assert planes.green_difference_dn is not None
    np.testing.assert_allclose(planes.green_difference_dn, site(first) - site(second), atol=1e-3)
    assert planes.black_level_dn == (
        float(blacks[red]),
        (blacks[first] + blacks[second]) / 2,
        float(blacks[blue]),
    )
    expected_origin = ((float(red[0]), float(red[1])), (0.5, 0.5), (float(blue[0]), float(blue[1])))
    assert planes.channel_origin_px == expected_origin
    assert planes.clip_level_dn == (
        float(4095 - blacks[red]),
        float(4095 - max(blacks[first], blacks[second])),
        float(4095 - blacks[blue]),
    )
    assert planes.sensor_shape_px == (48, 64)


def test_saturation_mask_marks_sites_near_the_white_level(tmp_path: Path) -> None:
    data = np.full((32, 32), 1000, np.uint16)
    threshold = 64 + 0.97 * (4095 - 64)
    data[0, 0] = 4095  # R clipped
    data[2, 2] = int(np.ceil(threshold))  # R at the threshold
    data[4, 4] = int(np.floor(threshold)) - 1  # R just below
    data[0, 3] = 4095  # first green of cell (0, 1)
    path = _write(tmp_path / "sat.dng", data, cfa_pattern="RGGB", black_level_dn=64)
    planes = read_raw(path)
    assert planes.saturated[0, 0, 0] and planes.saturated[0, 1, 1]
    assert not planes.saturated[0, 2, 2]
    assert planes.saturated[1, 0, 1]  # either green saturates the G sample
    assert planes.saturated.sum() == 3


def test_a_clipping_plateau_below_the_white_level_counts_as_saturated(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    data = rng.integers(1000, 3000, (64, 64)).astype(np.uint16)
    data[:20, :20] = 3800  # many sites stuck at one value well below white (4095)
    path = _write(tmp_path / "plateau.dng", data, black_level_dn=64)
    planes = read_raw(path)
    assert planes.saturated[:, :10, :10].all()
    assert not planes.saturated[:, 10:, 10:].any()


def test_visible_area_and_odd_sizes(tmp_path: Path, rng: np.random.Generator) -> None:
    data = rng.integers(600, 3000, (41, 63)).astype(np.uint16)
    planes = read_raw(_write(tmp_path / "odd.dng", data, black_level_dn=64))
    assert planes.signal_dn.shape == (3, 20, 31)
    margins = rng.integers(600, 3000, (44, 64)).astype(np.uint16)
    path = _write(tmp_path / "margins.dng", margins, black_level_dn=64, active_area=(4, 2, 40, 62))
    cropped = read_raw(path)
    np.testing.assert_array_equal(cropped.signal_dn[0], margins[4:40:2, 2:62:2] - 64.0)


def test_metadata_comes_from_the_exif_tags(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "m.dng",
        np.full((32, 32), 700, np.uint16),
        exposure_s=1 / 3,
        iso=800,
        f_number=11.0,
        make="Maker",
        model="Body",
        capture_time=datetime(2024, 12, 31, 23, 59, 58),
    )
    for metadata in (read_raw(path).metadata, read_raw_metadata(path)):
        assert metadata.exposure_s == 1 / 3  # exact rational, not LibRaw's float32
        assert metadata.exposure_source == "exif"
        assert metadata.iso == 800
        assert metadata.f_number == 11.0
        assert (metadata.make, metadata.model, metadata.camera) == ("Maker", "Body", "Maker Body")
        assert metadata.capture_time == datetime(2024, 12, 31, 23, 59, 58)


def test_exposure_override_wins_and_missing_exposure_names_the_file(tmp_path: Path) -> None:
    path = _write(tmp_path / "no_exposure.dng", np.full((32, 32), 700, np.uint16), exposure_s=None)
    with pytest.raises(InputError, match=r"no_exposure\.dng.*no exposure time.*exposure_s"):
        read_raw(path)
    with pytest.raises(InputError, match=r"no_exposure\.dng"):
        read_raw_metadata(path)
    planes = read_raw(path, exposure_s=2.5)
    assert (planes.metadata.exposure_s, planes.metadata.exposure_source) == (2.5, "override")
    timed = _write(tmp_path / "timed.dng", np.full((32, 32), 700, np.uint16), exposure_s=0.01)
    assert read_raw_metadata(timed, exposure_s=0.02).exposure_s == 0.02
    with pytest.raises(InputError, match="exposure override"):
        read_raw(timed, exposure_s=-1.0)


def _truncated(tmp_path: Path) -> Path:
    good = _write(tmp_path / "good.dng", np.full((64, 64), 700, np.uint16))
    content = good.read_bytes()
    path = tmp_path / "truncated.dng"
    path.write_bytes(content[: len(content) // 2])
    return path


def _not_raw_tiff(tmp_path: Path) -> Path:
    path = tmp_path / "photo.tif"
    tifffile.imwrite(path, np.zeros((32, 32, 3), np.uint8))
    return path


def _text(tmp_path: Path) -> Path:
    path = tmp_path / "notes.dng"
    path.write_text("these are not pixels\n" * 20)
    return path


def _empty(tmp_path: Path) -> Path:
    path = tmp_path / "empty.dng"
    path.write_bytes(b"")
    return path


def _no_cfa_pattern(tmp_path: Path) -> Path:
    path = tmp_path / "mono.dng"
    tifffile.imwrite(
        path,
        np.full((32, 32), 700, np.uint16),
        photometric=32803,
        metadata=None,
        extratags=[(50706, "B", 4, (1, 4, 0, 0), True), (33434, "2I", 1, (1, 100), True)],
    )
    return path


@pytest.mark.parametrize(
    ("make_file", "message"),
    [
        (_truncated, "corrupt or truncated"),
        (_not_raw_tiff, "not a RAW file"),
        (_text, "not a RAW file"),
        (_empty, "empty"),
        (_no_cfa_pattern, "colour filter"),
        (lambda tmp: tmp / "missing.dng", "not found"),
        (lambda tmp: tmp, "directory"),
    ],
)
def test_unreadable_files_are_rejected_naming_the_file(
    tmp_path: Path, make_file: object, message: str
) -> None:
    path = make_file(tmp_path)  # type: ignore[operator]
    with pytest.raises(RawFileError, match=message) as caught:
        read_raw(path)
    assert str(path) in str(caught.value)
    assert caught.value.source == str(path)


def test_saturation_fraction_is_validated(tmp_path: Path) -> None:
    path = _write(tmp_path / "f.dng", np.full((32, 32), 700, np.uint16))
    with pytest.raises(ValueError, match="saturation_fraction"):
        read_raw(path, saturation_fraction=1.5)


# --------------------------------------------------------------------------------------------------
# Metadata of containers exifread does not open by itself (built to the formats' layout)


def _tiff_with_tags(tags: list[tuple[int, str, int, object, bool]]) -> bytes:
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, np.zeros((1, 1), np.uint8), metadata=None, extratags=tags)
    return buffer.getvalue()


def _box(kind: bytes, payload: bytes) -> bytes:
    return struct.pack(">I4s", 8 + len(payload), kind) + payload


def test_cr3_metadata_comes_from_its_cmt_boxes(tmp_path: Path) -> None:
    ifd0 = _tiff_with_tags([(271, "s", 0, "Canon", True), (272, "s", 0, "Canon EOS R5", True)])
    exif = _tiff_with_tags(
        [
            (33434, "2I", 1, (1, 60), True),
            (33437, "2I", 1, (4, 1), True),
            (34855, "H", 1, 200, True),
        ]
    )
    uuid = bytes.fromhex("85c0b687820f11e08111f4ce462b6a48")
    metadata_box = _box(
        b"uuid",
        uuid
        + _box(b"CNCV", b"CanonCR3_001/00.10.00/00.00.00")
        + _box(b"CMT1", ifd0)
        + _box(b"CMT2", exif),
    )
    content = (
        _box(b"ftyp", b"crx \x00\x00\x00\x01crx isom")
        + _box(b"moov", metadata_box)
        + _box(b"mdat", b"\0" * 64)
    )
    path = tmp_path / "IMG_0001.CR3"
    path.write_bytes(content)
    metadata = read_raw_metadata(path)
    assert (metadata.make, metadata.model) == ("Canon", "Canon EOS R5")
    assert (metadata.exposure_s, metadata.iso, metadata.f_number) == (1 / 60, 200, 4.0)
    assert metadata.exposure_source == "exif"


def test_raf_metadata_comes_from_its_jpeg_preview(tmp_path: Path) -> None:
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = "FUJIFILM", "X-T3"
    sub_ifd = exif.get_ifd(0x8769)
    sub_ifd[0x829A], sub_ifd[0x829D], sub_ifd[0x8827] = (
        IFDRational(1, 125),
        IFDRational(28, 10),
        640,
    )
    preview = io.BytesIO()
    Image.new("RGB", (8, 8)).save(preview, "JPEG", exif=exif.tobytes())
    jpeg = preview.getvalue()
    header = b"FUJIFILMCCD-RAW 0201FF383501".ljust(84, b"\0") + struct.pack(">II", 100, len(jpeg))
    path = tmp_path / "DSCF0001.RAF"
    path.write_bytes(header.ljust(100, b"\0") + jpeg)
    metadata = read_raw_metadata(path)
    assert (metadata.make, metadata.model) == ("FUJIFILM", "X-T3")
    assert (metadata.exposure_s, metadata.iso, metadata.f_number) == (1 / 125, 640, 2.8)


def test_unknown_containers_fall_back_to_libraw(tmp_path: Path) -> None:
    path = tmp_path / "strange.raw"
    path.write_bytes(b"\x00\x01" * 200)
    with pytest.raises(RawFileError, match="not a RAW file"):
        read_raw_metadata(path)
