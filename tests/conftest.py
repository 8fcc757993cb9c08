"""Shared fixtures: the optional reference data directory and a seeded random generator."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest


def _find_shared_data() -> Path:
    """``$SPECTRAL_RIG_SHARED_DATA``, else ``shared/data/camera_sensitivities`` beside the checkout
    or beside any folder above it (a worktree may sit a level deeper than the main checkout)."""
    if "SPECTRAL_RIG_SHARED_DATA" in os.environ:
        return Path(os.environ["SPECTRAL_RIG_SHARED_DATA"])
    checkout = Path(__file__).resolve().parents[1]
    for folder in checkout.parents:
        candidate = folder / "shared" / "data" / "camera_sensitivities"
        if candidate.is_dir():
            return candidate
    return checkout.parent / "shared" / "data" / "camera_sensitivities"


#: The measured camera collections, when present (tests that need them skip otherwise).
SHARED_CAMERA_DATA = _find_shared_data()


@pytest.fixture
def shared_camera_data() -> Path:
    """The measured camera collections; skips the test cleanly when they are not present."""
    if not SHARED_CAMERA_DATA.is_dir():
        pytest.skip(f"reference camera data not found at {SHARED_CAMERA_DATA}")
    return SHARED_CAMERA_DATA


#: The real grating captures (third-party validation data), beside the camera collections.
SHARED_REAL_GRATING = SHARED_CAMERA_DATA.parent / "real-grating"


@pytest.fixture
def shared_real_grating() -> Path:
    """The real grating captures; skips the test cleanly when they are not present."""
    if not SHARED_REAL_GRATING.is_dir():
        pytest.skip(f"real grating data not found at {SHARED_REAL_GRATING}")
    return SHARED_REAL_GRATING


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20251121)
