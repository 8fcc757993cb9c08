"""An unblurred D65 profile (200 px, ~1.7 nm a pixel) of the prior's mean camera, a little tilted
so it is not the mean (cheap: no dataset to load), and its response model on 10 nm nodes: the
scene the response-model and search-convergence tests share."""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import QuadraticMapping
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.model.bases import fallback_camera_basis
from calib.model.forward import pixel_edges, render_observation
from calib.wavelength.families import QuadraticFamily
from calib.wavelength.response_model import ResponseModel


def unblurred_led(
    **build: Any,
) -> tuple[ResponseModel, QuadraticFamily, np.ndarray, QuadraticMapping]:
    """``(model, family, pixel edges, true mapping)``; ``build`` goes to :meth:`ResponseModel.build`."""
    prior = fallback_camera_basis().prior()
    tilt = 1.0 + 0.3 * np.linspace(-1.0, 1.0, prior.grid.wavelength_nm.size)[:, None]
    camera = MultiSpectrum(prior.grid.wavelength_nm, np.maximum(prior.mean, 0.0) * tilt)
    truth = QuadraticMapping(-8.8e-5, 1.72, 383.0, pixel_range=(0.0, 199.0))
    observation = render_observation(
        colour_lamp("D65"), camera, mapping=truth, pixel=200
    ).observation
    model = ResponseModel.build(
        observation, DEFAULT_GRID, node_step_nm=10.0, prior=prior, flexibility=0.05, **build
    )
    return model, QuadraticFamily((0.0, 199.0)), pixel_edges(observation.pixel), truth
