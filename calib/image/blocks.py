"""Block averaging: the reduced images that detection works on and that the diagnostics draw.

An image of ``H × W`` samples is cut into ``b × b`` blocks, ``b`` the smallest integer that makes
it at most ``max_size`` blocks across (:func:`block_factor`); the last partial rows and columns are
dropped. Detection (:mod:`calib.image.profiles.detection`) works at most :data:`DETECTION_MAX_SIZE`
blocks across, and the first, coarse detection on a single large frame
(:func:`calib.pipeline.brackets.coarse_image`) reduces the frame to that very size, so detection
runs on it block for block (decision 0021).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import BoolArray, FloatArray

#: Detection's working image is at most this many blocks across. At 800, a 24 MP frame
#: (3000 × 2000 plane samples) is cut into blocks of 4 plane samples (8 sensor pixels), so a band
#: 40 pixels across still spans 5 blocks; the rig's captures up to 1600 plane samples across (the
#: twin's, the tests') are detected at full resolution or in blocks of 2. A coarser image (512
#: across was used for the first detection on large frames) saves ~25 ms on a 24 MP frame and
#: changes nothing found there; one size for both keeps one detection.
DETECTION_MAX_SIZE = 800


def block_factor(shape: tuple[int, ...], max_size: int) -> int:
    """The block side ``b ≥ 1`` that makes the last two axes of ``shape`` at most ``max_size`` across.

    Examples
    --------
    >>> block_factor((2000, 3000), 800), block_factor((400, 600), 800)
    (4, 1)
    """
    return max(1, math.ceil(max(shape[-2], shape[-1]) / max_size))


def block_mean(values: NDArray[np.generic], factor: int) -> FloatArray:
    """Means of ``factor × factor`` blocks over the last two axes (float64), partial blocks dropped.

    ``values`` has shape ``(..., H, W)``; the result ``(..., H // factor, W // factor)``.

    Examples
    --------
    >>> block_mean(np.arange(16.0).reshape(4, 4), 2).tolist()
    [[2.5, 4.5], [10.5, 12.5]]
    """
    rows, columns = values.shape[-2] // factor, values.shape[-1] // factor
    blocks = values[..., : rows * factor, : columns * factor].reshape(
        *values.shape[:-2], rows, factor, columns, factor
    )
    return np.asarray(blocks.mean(axis=(-3, -1), dtype=np.float64), dtype=np.float64)


def block_any(flags: BoolArray, factor: int) -> BoolArray:
    """Whether any sample of each ``factor × factor`` block is set (shapes as :func:`block_mean`)."""
    rows, columns = flags.shape[-2] // factor, flags.shape[-1] // factor
    blocks = flags[..., : rows * factor, : columns * factor].reshape(
        *flags.shape[:-2], rows, factor, columns, factor
    )
    return np.asarray(blocks.any(axis=(-3, -1)), dtype=np.bool_)
