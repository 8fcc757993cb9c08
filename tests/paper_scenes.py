"""A leave-one-camera-out paper scene (profiles without the 0th order: the quadratic family) under
D65 and FL2, mapped through :func:`calib.wavelength.locate.locate_mapping` as ``calib estimate``
maps it (decisions 0121 and 0122; ``bench/wavelength_loco.py --with-fl`` runs the whole split)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class MappedScene:
    """The scene, its lamps and what the mapping found."""

    scene: Any
    lamps: list[Any]
    found: Any

    def error_nm(self, inside_grid: bool = False) -> np.ndarray:
        """The found mapping minus the truth at the profile's pixels (only where the truth lies on
        the working grid with ``inside_grid``)."""
        from calib.core.spectra import DEFAULT_GRID

        pixel = self.lamps[0].pixel
        truth = self.scene.mapping.wavelength_nm(pixel)
        if inside_grid:
            keep = (truth >= DEFAULT_GRID.start_nm) & (truth <= DEFAULT_GRID.stop_nm)
            pixel, truth = pixel[keep], truth[keep]
        return np.asarray(self.found.exact.wavelength_nm(pixel) - truth, dtype=np.float64)


def mapped_fl_paper_scene(
    data_dir: Path, camera_prefix: str, seed: int, noise_fraction: float = 0.01
) -> MappedScene:
    """The training camera whose name starts with ``camera_prefix``, held out of the basis, rendered
    with the bench's seed ``[seed, index]`` (noise ``noise_fraction`` of the peak) and mapped from
    its D65 and FL2 profiles."""
    from calib.core.datasets import makabe2025_split
    from calib.core.lamp_specs import lamp_from_spec
    from calib.core.spectra import DEFAULT_GRID
    from calib.evaluation.synthetic import render_scene
    from calib.model.bases import camera_basis
    from calib.wavelength.locate import locate_mapping

    train, _ = makabe2025_split(str(data_dir))
    index = next(i for i, r in enumerate(train) if r.name.startswith(camera_prefix))
    prior = camera_basis(
        [r.sensitivity for i, r in enumerate(train) if i != index], grid=DEFAULT_GRID
    ).prior()
    scene = render_scene(
        train[index].name,
        train[index].sensitivity,
        np.random.default_rng([seed, index]),
        broadband_lamp=lamp_from_spec("D65"),
        fluorescent_lamp=lamp_from_spec("FL2"),
        noise_fraction=noise_fraction,
    )
    lamps = [scene.broadband.observation, scene.fluorescent.observation]
    return MappedScene(scene, lamps, locate_mapping(lamps, prior, DEFAULT_GRID))
