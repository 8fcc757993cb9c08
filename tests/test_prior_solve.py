"""calib.methods.prior_solve: the camera-prior solve, its companions and its uncertainty."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.errors import InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.evaluation.synthetic import random_efficiency
from calib.methods import prior_solve, responses
from calib.methods.closed_form import normalised_efficiency_sigma
from calib.methods.prior_solve import PriorOptions, estimate_prior, solve_with_prior
from calib.methods.responses import fit_response
from calib.model.bases import CameraBasis, fallback_camera_basis, fourier_basis
from calib.model.forward import PeakFractionNoise, render_observation
from calib.model.linear_model import prepare_lamp

MAPPING = QuadraticMapping(1.5e-5, 0.40, 385.0, pixel_range=(0.0, 849.0))


@pytest.fixture(scope="module")
def basis() -> CameraBasis:
    return fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])


@pytest.fixture(scope="module")
def camera() -> MultiSpectrum:
    return find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity


def _render(
    lamp: str, camera: MultiSpectrum, noise: float, seed: int, kind: str = "led"
) -> LampObservation:
    return render_observation(
        colour_lamp(lamp),
        camera,
        mapping=MAPPING,
        pixel=850,
        grating_efficiency=random_efficiency(np.random.default_rng(5)),
        noise=PeakFractionNoise(noise) if noise else None,
        rng=np.random.default_rng(seed),
        kind=kind,  # type: ignore[arg-type]
    ).observation


def _truth(camera: MultiSpectrum) -> np.ndarray:
    values = np.asarray(camera.resample(DEFAULT_GRID).values)
    return np.asarray(values / values.max())


def test_the_response_fit_reproduces_a_noise_free_profile(basis, camera):
    observation = _render("LED-B3", camera, 0.0, 1)
    estimate = fit_response(prepare_lamp(observation, DEFAULT_GRID), MAPPING)
    assert estimate.used_pixels.sum() > 600
    # The response η·s at the grid nodes; its shape follows the camera times a smooth η.
    assert np.all(np.isfinite(estimate.response))
    assert estimate.covariance.shape == (3, DEFAULT_GRID.size, DEFAULT_GRID.size)


def test_a_companion_lamp_constrains_the_efficiency(basis, camera):
    """The fluorescent lamp's own direct signal adds three equations on η⁻¹: errors go down."""
    led_errors, joint_errors = [], []
    for seed in range(3):
        led = _render("LED-B3", camera, 0.005, seed)
        fluorescent = _render("FL2", camera, 0.005, 100 + seed, kind="fluorescent")
        alone = estimate_prior([led], basis=basis, mapping=MAPPING)
        joint = estimate_prior([led, fluorescent], basis=basis, mapping=MAPPING)
        assert joint.diagnostics["efficiency_lamps"] == ["LED-B3", "FL2"]
        led_errors.append(relative_error(alone.sensitivity, _truth(camera)))
        joint_errors.append(relative_error(joint.sensitivity, _truth(camera)))
    assert np.mean(joint_errors) < np.mean(led_errors)


def test_uncertainty_grows_with_the_noise(basis, camera):
    sigmas = []
    for noise in (0.003, 0.03):
        result = estimate_prior([_render("D65", camera, noise, 2)], basis=basis, mapping=MAPPING)
        assert result.sensitivity_sigma is not None
        assert np.all(np.isfinite(result.sensitivity_sigma)) and np.all(
            result.sensitivity_sigma >= 0
        )
        sigmas.append(float(np.median(result.sensitivity_sigma)))
    assert sigmas[1] > 2 * sigmas[0]


def test_the_direct_measurement_is_required(basis, camera):
    observation = _render("D65", camera, 0.0, 0)
    without = LampObservation(
        observation.name, observation.spectrum, observation.pixel, observation.profile
    )
    with pytest.raises(InputError, match="direct"):
        solve_with_prior(
            prepare_lamp(without, DEFAULT_GRID), MAPPING, basis.prior(), fourier_basis(DEFAULT_GRID)
        )


def test_the_result_honours_the_direct_measurement(basis, camera, monkeypatch):
    """The solve's sensitivity reproduces the measured direct RGB (it is an exact constraint),
    the constraint's null space found once per solve: it is the same on every pass (decision
    0107)."""
    import calib.methods.prior_solve as prior_solve

    factored = []
    null_space = prior_solve._null_space

    def counted(constraint: np.ndarray) -> np.ndarray:
        factored.append(constraint)
        return null_space(constraint)

    monkeypatch.setattr(prior_solve, "_null_space", counted)
    observation = _render("D65", camera, 0.01, 4)
    system = prepare_lamp(observation, DEFAULT_GRID)
    solution = solve_with_prior(system, MAPPING, basis.prior(), fourier_basis(DEFAULT_GRID))
    assert len(factored) == 1
    assert observation.direct_rgb is not None
    np.testing.assert_allclose(
        system.operators.direct_row @ solution.sensitivity, observation.direct_rgb, rtol=1e-9
    )


def test_the_normalised_efficiency_sigma_matches_its_monte_carlo() -> None:
    """η/max η's σ from η⁻¹'s covariance: the first-order propagation against 20 000 draws."""
    from calib.methods.closed_form import normalised_efficiency_sigma

    rng = np.random.default_rng(3)
    wavelength = DEFAULT_GRID.wavelength_nm
    inverse = 1.0 / (0.6 + 0.4 * np.exp(-(((wavelength - 520.0) / 90.0) ** 2)))
    design = fourier_basis(DEFAULT_GRID)[:, :5]
    coefficient_covariance = np.diag([4e-4, 1e-4, 1e-4, 4e-5, 4e-5])
    covariance = design @ coefficient_covariance @ design.T
    stated = normalised_efficiency_sigma(inverse, covariance)
    draws = inverse + rng.multivariate_normal(np.zeros(inverse.size), covariance, 20_000)
    peak = int(np.argmin(inverse))
    normalised = draws[:, [peak]] / draws
    assert stated[peak] == 0.0
    np.testing.assert_allclose(stated, normalised.std(axis=0), rtol=0.05, atol=1e-6)


@pytest.mark.parametrize("name", ["Canon EOS 5D Mark II", "Nikon 5100 (NPL)"])
def test_eta_states_a_sigma_that_covers_a_known_grating(basis, name):
    """Issue 17: the prior solve (free Fourier η, η₀ flat as it assumes) states η's σ through the
    σ budget; on a known smooth sheet its ±2σ band holds the true η without being far wider than
    the error (the solve's own σ alone covers 6–48 % here: the budget's components carry it)."""
    from calib.evaluation.synthetic import efficiency_coverage
    from calib.methods import estimate
    from calib.model.gratings import SinusoidalPhaseGrating

    camera = find_camera(colour_science_cameras(), name).sensitivity
    sheet = SinusoidalPhaseGrating(1.2)

    def first_order(wavelength_nm: np.ndarray) -> np.ndarray:
        return sheet.efficiency(1, wavelength_nm)

    lamps = [
        render_observation(
            colour_lamp(lamp),
            camera,
            mapping=MAPPING,
            pixel=850,
            grating_efficiency=first_order,
            noise=PeakFractionNoise(0.005),
            rng=np.random.default_rng(7 + index),
            kind=kind,  # type: ignore[arg-type]
        ).observation
        for index, (lamp, kind) in enumerate((("LED-B3", "led"), ("FL2", "fluorescent")))
    ]
    result = estimate(
        lamps,
        method="prior",
        basis=basis,
        mapping=MAPPING,
        options=PriorOptions(grating_model="fourier"),
    )
    assert result.grating_efficiency_sigma is not None
    assert result.diagnostics["method_efficiency_sigma"] is not None
    assert np.all(np.isfinite(result.grating_efficiency_sigma))
    budget = result.quality.uncertainty["grating_efficiency"]
    # (a given mapping states no σ: no mapping component)
    assert set(budget["rms"]) == {
        "statistical",
        "spectrometer scale",
        "spectrometer bandwidth",
        "efficiency model",
    }
    coverage, sigma_over_error = efficiency_coverage(
        result, first_order(DEFAULT_GRID.wavelength_nm)
    )
    assert coverage >= 0.9
    assert 1.0 <= sigma_over_error <= 4.0


def test_the_fourier_solve_after_the_model_choice_reuses_its_fits_to_the_bit(
    basis, camera, monkeypatch
):
    """``auto`` choosing the Fourier model hands its prepared lamps and fitted responses to the
    Fourier solve (decision 0083): each lamp's response fitted once, and the same numbers as the
    Fourier solve asked for directly."""
    lamps = [
        _render("LED-B3", camera, 0.005, 0),
        _render("FL2", camera, 0.005, 100, kind="fluorescent"),
    ]
    fits: list[str] = []

    def counted(system, mapping, **options):
        fits.append(system.observation.name)
        return fit_response(system, mapping, **options)

    with monkeypatch.context() as patch:
        patch.setattr(prior_solve, "fit_response", counted)
        patch.setattr(responses, "fit_response", counted)
        chosen = estimate_prior(lamps, basis=basis, mapping=MAPPING)
    assert chosen.diagnostics["grating_model"]["chosen"] == "fourier"
    assert sorted(fits) == ["FL2", "LED-B3"]
    direct = estimate_prior(
        lamps, basis=basis, mapping=MAPPING, options=PriorOptions(grating_model="fourier")
    )
    assert chosen.sensitivity_sigma is not None and direct.sensitivity_sigma is not None
    assert np.array_equal(chosen.sensitivity, direct.sensitivity)
    assert np.array_equal(chosen.sensitivity_sigma, direct.sensitivity_sigma)


def test_responses_given_to_the_solve_are_used_in_the_lamps_order(basis, camera):
    led = prepare_lamp(_render("LED-B3", camera, 0.005, 0), DEFAULT_GRID)
    fluorescent = prepare_lamp(_render("FL2", camera, 0.005, 100, kind="fluorescent"), DEFAULT_GRID)
    fitted = [fit_response(led, MAPPING), fit_response(fluorescent, MAPPING)]
    arguments = (led, MAPPING, basis.prior(), fourier_basis(DEFAULT_GRID))
    fresh = solve_with_prior(*arguments, companions=[fluorescent])
    given = solve_with_prior(*arguments, companions=[fluorescent], responses=fitted)
    assert np.array_equal(given.sensitivity, fresh.sensitivity)
    assert np.array_equal(given.sensitivity_sigma, fresh.sensitivity_sigma)
    swapped = solve_with_prior(*arguments, companions=[fluorescent], responses=fitted[::-1])
    assert not np.allclose(swapped.sensitivity, fresh.sensitivity)
    with pytest.raises(InputError, match="responses"):
        solve_with_prior(*arguments, companions=[fluorescent], responses=fitted[:1])


def _normalised_eta(inverse: np.ndarray) -> np.ndarray:
    eta = 1.0 / inverse
    return np.asarray(eta / eta.max())


def test_the_direct_values_sigma_is_propagated_into_eta_and_the_sensitivity(basis, camera):
    """A 2 % σ of the leading lamp's direct RGB widens η's and s's σ by exactly its first-order
    effect (the solve's own finite-difference derivative in each channel's direct value): the
    direct RGB is a measurement, not an exact constraint. Without the propagation the σ does
    not change with the direct value's σ."""
    observation = _render("D65", camera, 0.003, 4)
    direct = np.asarray(observation.direct_rgb, dtype=np.float64)
    sigma = 0.02 * direct
    prior, efficiency_basis = basis.prior(), fourier_basis(DEFAULT_GRID)
    system = prepare_lamp(replace(observation, direct_sigma=None), DEFAULT_GRID)
    responses = [fit_response(system, MAPPING)]

    def solve(values: np.ndarray, values_sigma: np.ndarray | None) -> prior_solve.PriorSolution:
        changed = replace(system.observation, direct_rgb=values, direct_sigma=values_sigma)
        return solve_with_prior(
            replace(system, observation=changed),
            MAPPING,
            prior,
            efficiency_basis,
            responses=responses,
        )

    exact, measured = solve(direct, None), solve(direct, sigma)
    # The estimate itself is the same; only its σ holds the direct value's.
    np.testing.assert_allclose(measured.sensitivity, exact.sensitivity, rtol=1e-12)
    eta_sigma = [
        normalised_efficiency_sigma(s.inverse_efficiency, s.inverse_efficiency_covariance)
        for s in (exact, measured)
    ]
    added_eta = eta_sigma[1] ** 2 - eta_sigma[0] ** 2
    added_s = measured.sensitivity_sigma**2 - exact.sensitivity_sigma**2
    expected_eta = np.zeros_like(added_eta)
    expected_s = np.zeros_like(added_s)
    step = 1e-4
    for c in range(3):
        moved = direct.copy()
        moved[c] *= 1.0 + step
        shifted = solve(moved, None)
        d_eta = (
            _normalised_eta(shifted.inverse_efficiency) - _normalised_eta(exact.inverse_efficiency)
        ) / (step * direct[c])
        d_s = (shifted.sensitivity - exact.sensitivity) / (step * direct[c])
        expected_eta += (d_eta * sigma[c]) ** 2
        expected_s += (d_s * sigma[c]) ** 2
    assert float(np.sum(expected_eta)) > 0.01 * float(np.sum(eta_sigma[0] ** 2))
    np.testing.assert_allclose(np.sqrt(np.sum(added_eta)), np.sqrt(np.sum(expected_eta)), rtol=0.05)
    np.testing.assert_allclose(
        np.sqrt(np.sum(added_s, axis=0)), np.sqrt(np.sum(expected_s, axis=0)), rtol=0.05
    )
