"""Block averaging (calib.image.blocks): one reduction for detection, the coarse first detection and the picture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.image.blocks import DETECTION_MAX_SIZE, block_any, block_factor, block_mean
from calib.image.raw import RawPlanes
from calib.image.raw_metadata import RawMetadata
from calib.pipeline.brackets import coarse_image


@pytest.mark.parametrize(
    ("shape", "factor"),
    [((400, 600), 1), ((800, 800), 1), ((801, 10), 2), ((2000, 3000), 4), ((3, 2752, 4128), 6)],
)
def test_the_factor_is_the_smallest_that_fits(shape: tuple[int, ...], factor: int) -> None:
    assert block_factor(shape, DETECTION_MAX_SIZE) == factor
    assert max(shape[-2:]) // factor <= DETECTION_MAX_SIZE
    assert factor == 1 or max(shape[-2:]) / (factor - 1) > DETECTION_MAX_SIZE


def test_blocks_average_each_channel_and_drop_partial_edges() -> None:
    values = np.random.default_rng(1).normal(size=(3, 7, 9)).astype(np.float32)
    reduced = block_mean(values, 3)
    assert reduced.shape == (3, 2, 3) and reduced.dtype == np.float64
    np.testing.assert_allclose(reduced[2, 1, 2], values[2, 3:6, 6:9].mean(dtype=np.float64))
    flags = np.zeros((3, 7, 9), dtype=bool)
    flags[1, 4, 8] = True  # inside block (1, 2) of channel 1
    flags[0, 6, 0] = True  # in the dropped last row
    assert block_any(flags, 3).nonzero() == (np.array([1]), np.array([1]), np.array([2]))


def test_the_coarse_image_is_at_detections_working_size() -> None:
    # A 24 MP frame's planes: the first detection must run on them block for block, so detection
    # does not reduce the coarse image again.
    rng = np.random.default_rng(2)
    signal = rng.uniform(0.0, 100.0, size=(3, 2000, 3000)).astype(np.float32)
    saturated = np.zeros(signal.shape, dtype=bool)
    saturated[0, 5, 7] = True
    metadata = RawMetadata(Path("frame.dng"), 0.01, "exif", 100.0, 8.0, "Make", "Model", None)
    planes = RawPlanes(
        metadata=metadata,
        signal_dn=signal,
        saturated=saturated,
        cfa_pattern="RGGB",
        black_level_dn=(0.0, 0.0, 0.0),
        clip_level_dn=(1000.0, 1000.0, 1000.0),
        channel_origin_px=((0.0, 0.0), (0.5, 0.5), (1.0, 1.0)),
    )
    coarse = coarse_image(planes)
    assert coarse.radiance.shape == (3, 500, 750)
    assert block_factor(coarse.radiance.shape, DETECTION_MAX_SIZE) == 1
    assert coarse.pixel_pitch_px == 8.0
    np.testing.assert_allclose(coarse.radiance, block_mean(signal, 4) / 0.01, rtol=1e-6)
    assert coarse.saturated[0, 1, 1] and coarse.saturated.sum() == 1
