"""Array types every module shares, and checked read-only float arrays for the estimators' inputs."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.core.errors import InputError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def checked_array(value: ArrayLike, shape: tuple[int, ...], name: str, source: str) -> FloatArray:
    """``value`` as a read-only float64 array of exactly ``shape``, all finite.

    Raises
    ------
    InputError
        Naming ``name`` (what the array is) and ``source`` (whose it is): the shape found and the
        one expected, or that it holds NaN or infinite values.
    """
    array = np.array(value, dtype=np.float64)
    if array.shape != shape:
        raise InputError(f"{name} has shape {array.shape}, expected {shape}", source=source)
    if not np.all(np.isfinite(array)):
        raise InputError(f"{name} contains NaN or infinite values", source=source)
    array.flags.writeable = False
    return array
