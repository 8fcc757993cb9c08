"""Shared fixtures: the optional reference data directory and a seeded random generator."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

#: ``../shared/data/camera_sensitivities`` next to the checkout, or ``$SPECTRAL_RIG_SHARED_DATA``.
SHARED_CAMERA_DATA = Path(
    os.environ.get(
        "SPECTRAL_RIG_SHARED_DATA",
        Path(__file__).resolve().parents[2] / "shared" / "data" / "camera_sensitivities",
    )
)


@pytest.fixture
def shared_camera_data() -> Path:
    """The measured camera collections; skips the test cleanly when they are not present."""
    if not SHARED_CAMERA_DATA.is_dir():
        pytest.skip(f"reference camera data not found at {SHARED_CAMERA_DATA}")
    return SHARED_CAMERA_DATA


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20251121)
