"""Repository-wide pytest set-up: the doctests in ``calib/`` and the tests in ``tests/`` share it."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest


@pytest.fixture(autouse=True)
def _numpy_prints_as_documented() -> Iterator[None]:
    """NumPy's current print style for every test and docstring example.

    Importing colour-science directly (some tests do) switches NumPy's global print options to the
    1.13 legacy style; the examples in the docstrings show today's style.
    """
    with np.printoptions(legacy=False):
        yield
