"""Smooth synthetic cameras and a basis that spans them exactly (shared by the estimator tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.model.bases import CameraBasis, camera_basis


def gaussian_camera(
    centres_nm: tuple[float, float, float], widths_nm: tuple[float, float, float]
) -> np.ndarray:
    wavelength = DEFAULT_GRID.wavelength_nm
    return np.stack(
        [
            np.exp(-0.5 * ((wavelength - c) / w) ** 2)
            for c, w in zip(centres_nm, widths_nm, strict=True)
        ],
        axis=1,
    )


def spanning_set() -> np.ndarray:
    """Seven smooth cameras, shape (7, f, 3)."""
    rng = np.random.default_rng(7)
    cameras = []
    for _ in range(7):
        centres = (rng.uniform(580, 620), rng.uniform(520, 560), rng.uniform(440, 480))
        widths = (rng.uniform(30, 50), rng.uniform(35, 55), rng.uniform(25, 40))
        cameras.append(gaussian_camera(centres, widths))
    return np.stack(cameras)


def exact_basis(cache_dir: Path) -> tuple[CameraBasis, np.ndarray]:
    """A 7-vector basis whose span holds every camera of :func:`spanning_set` exactly."""
    cameras = spanning_set()
    basis = camera_basis(cameras, n_vectors=7, source="synthetic exact", cache_dir=cache_dir)
    return basis, cameras


def as_spectrum(values: np.ndarray, name: str = "camera") -> MultiSpectrum:
    return MultiSpectrum(DEFAULT_GRID.wavelength_nm, values, name=name)


def small_data_dir(root: Path, training: int) -> Path:
    """A camera data directory under ``root``: the paper's 5 test files (Solomatov & Akkaynak's
    layout) and ``training`` other Gaussian cameras, each a little shifted from the last."""
    from calib.core.datasets import MAKABE2025_TEST_FILES

    folder = root / "data" / "solomatov-akkaynak-2023" / "data" / "ground-truths"
    folder.mkdir(parents=True)
    grid = DEFAULT_GRID.wavelength_nm
    names = [*MAKABE2025_TEST_FILES, *(f"Camera_{k}_Someone-2020.csv" for k in range(training))]
    for index, name in enumerate(names):
        centres = (590.0 + 3 * index, 535.0 + 2 * index, 455.0 + index)
        values = gaussian_camera(centres, (40.0, 45.0, 30.0))
        lines = "\n".join(
            f"{w:g},{r:.6f},{g:.6f},{b:.6f}" for w, (r, g, b) in zip(grid, values, strict=True)
        )
        (folder / name).write_text("wavelength,red,green,blue\n" + lines + "\n")
    return root / "data"
