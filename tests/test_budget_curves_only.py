"""The σ budget's re-solves compute only the curves it reads, and the prior solve's stacked
whitening: the same bits as before (decision 0132)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.evaluation.synthetic import random_efficiency
from calib.methods import estimate, prior_solve
from calib.methods.prior_solve import PriorOptions, estimate_prior
from calib.methods.uncertainty import BudgetSettings, curves_only, reading_curves_only
from calib.model.bases import CameraBasis, fallback_camera_basis, whitening, whitening_stack
from calib.model.forward import PeakFractionNoise, render_observation

MAPPING = QuadraticMapping(1.5e-5, 0.40, 385.0, pixel_range=(0.0, 849.0))
FOURIER = PriorOptions(grating_model="fourier")


@pytest.fixture(scope="module")
def basis() -> CameraBasis:
    return fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])


@pytest.fixture(scope="module")
def lamps() -> list[LampObservation]:
    camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    return [
        render_observation(
            colour_lamp(name),
            camera,
            mapping=MAPPING,
            pixel=850,
            grating_efficiency=random_efficiency(np.random.default_rng(5)),
            noise=PeakFractionNoise(0.005),
            rng=np.random.default_rng(seed),
            kind=kind,  # type: ignore[arg-type]
        ).observation
        for name, seed, kind in (("LED-B3", 0, "led"), ("FL2", 100, "fluorescent"))
    ]


def test_the_stacked_whitening_is_whitening_of_each_matrix_to_the_bit():
    rng = np.random.default_rng(3)
    size = 31
    low_rank = rng.standard_normal((size, 4))
    stack = np.stack(
        [
            (lambda a: a @ a.T + 1e-3 * np.eye(size))(rng.standard_normal((size, size))),
            low_rank @ low_rank.T,  # rank 4: the eigenvalue floor decides
            np.diag(rng.uniform(1e-6, 1.0, size)) + 1e-9 * rng.standard_normal((size, size)),
        ]
    )
    stacked = whitening_stack(stack)
    for matrix, factor in zip(stack, stacked, strict=True):
        assert np.array_equal(factor, whitening(matrix))


def test_a_curves_only_re_solve_gives_the_full_solves_curves_and_no_sigma(basis, lamps):
    assert not reading_curves_only()
    full = estimate_prior(lamps, basis=basis, mapping=MAPPING, options=FOURIER)
    with curves_only():
        assert reading_curves_only()
        curves = estimate_prior(lamps, basis=basis, mapping=MAPPING, options=FOURIER)
    assert not reading_curves_only()
    assert np.array_equal(curves.sensitivity, full.sensitivity)
    assert np.array_equal(
        np.asarray(curves.grating_efficiency), np.asarray(full.grating_efficiency)
    )
    assert full.sensitivity_sigma is not None and full.grating_efficiency_sigma is not None
    # What only the σ and the residuals need was left out.
    assert curves.sensitivity_sigma is None and curves.grating_efficiency_sigma is None
    assert curves.residuals == {} and full.residuals


def test_a_curves_only_physical_re_solve_gives_the_full_solves_curves(basis, lamps):
    options = PriorOptions(grating_model="sinusoidal")
    full = estimate_prior(lamps, basis=basis, mapping=MAPPING, options=options)
    with curves_only():
        curves = estimate_prior(lamps, basis=basis, mapping=MAPPING, options=options)
    assert full.diagnostics["grating_model"]["chosen"] == "sinusoidal"
    assert np.array_equal(curves.sensitivity, full.sensitivity)
    assert np.array_equal(
        np.asarray(curves.grating_efficiency), np.asarray(full.grating_efficiency)
    )
    assert full.sensitivity_sigma is not None and curves.sensitivity_sigma is None


def test_the_budget_is_the_same_to_the_bit_with_full_re_solves(basis, lamps, monkeypatch):
    settings = BudgetSettings(record_components=True)
    fast = estimate(lamps, "prior", basis=basis, mapping=MAPPING, options=FOURIER, budget=settings)
    monkeypatch.setattr(prior_solve, "reading_curves_only", lambda: False)
    slow = estimate(lamps, "prior", basis=basis, mapping=MAPPING, options=FOURIER, budget=settings)
    components = fast.diagnostics["budget_components"]
    assert set(components) == set(slow.diagnostics["budget_components"])
    assert {"spectrometer bandwidth", "efficiency model"} <= set(components)
    for name, sigma in components.items():
        assert np.array_equal(sigma, slow.diagnostics["budget_components"][name]), name
    assert np.array_equal(np.asarray(fast.sensitivity_sigma), np.asarray(slow.sensitivity_sigma))
    assert np.array_equal(
        np.asarray(fast.grating_efficiency_sigma), np.asarray(slow.grating_efficiency_sigma)
    )
