"""One validation paper scene's broadband observation, its camera prior and its true mapping, rendered
as :func:`calib.evaluation.synthetic.run_protocol` renders it (the same seeds), for the slow tests
that search it."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.evaluation.synthetic import run_protocol
from calib.evaluation.synthetic_splits import paper_split_cameras, validation_cameras
from calib.evaluation.validation.splits import PREDICTION
from calib.model.bases import CameraBasis, CameraPrior


def paper_scene(
    data: Path, name: str, lamp: str, seed: int, noise: float, predictions: int = 0
) -> tuple[LampObservation, CameraPrior, QuadraticMapping]:
    """The validation split's scene of camera ``name`` under the broadband ``lamp``; with
    ``predictions``, of that many predicted curves drawn with ``seed`` (``bench/paper_coverage.py
    --predictions``)."""
    basis: CameraBasis | Callable[[str], CameraBasis]
    if predictions:
        cameras, basis, _ = validation_cameras(
            data, predictions=predictions, seed=seed, group=PREDICTION
        )
    else:
        cameras, basis = paper_split_cameras("validation", data)
    scenes: list[Any] = []
    run_protocol(
        cameras,
        basis,
        variants=["true mapping"],
        noise_levels=[0, 0.003, 0.01, 0.03],
        broadband_lamp=lamp,
        seed=seed,
        budget=None,
        on_result=lambda scene, _row, _result: scenes.append(scene),
        only=lambda camera, level: camera == name and level == noise,
    )
    (scene,) = scenes
    assert callable(basis)
    return scene.broadband.observation, basis(name).prior(), scene.mapping


def searched_worst_nm(data: Path, name: str, lamp: str, seed: int, noise: float) -> float:
    """The LED-only search's worst error (nm, over the pixels whose true wavelength is on the
    working grid) on the validation split's scene of camera ``name`` (:func:`paper_scene`)."""
    import numpy as np

    from calib.core.spectra import DEFAULT_GRID
    from calib.wavelength.profile_search import search_profiles

    led, prior, mapping = paper_scene(data, name, lamp, seed, noise)
    found = search_profiles([led], prior, DEFAULT_GRID)
    truth = mapping.wavelength_nm(led.pixel)
    inside = (truth >= DEFAULT_GRID.start_nm) & (truth <= DEFAULT_GRID.stop_nm)
    return float(np.max(np.abs(found.mapping.wavelength_nm(led.pixel) - truth)[inside]))
