"""calib.methods.multilamp: several lamps jointly, the σ band (calibration, bootstrap), the grating library."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.core.blas import pinv_symmetric_stack
from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.errors import InputError
from calib.core.grating_file import read_grating_file, write_grating_file
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.evaluation.synthetic import (
    LAMP_SETS,
    band_coverage,
    random_efficiency,
    random_mapping,
    render_lamps,
)
from calib.methods import ESTIMATION_METHODS, estimate
from calib.methods.known_grating import estimate_known_grating
from calib.methods.multilamp import (
    PRIOR_WEIGHTS,
    MultilampOptions,
    _efficiency_jacobians,
    _efficiency_terms_solve,
    _nonlinear_efficiency,
    bootstrap_sigma,
    calibrate_lamps,
    choose_prior_weight,
    estimate_multilamp,
    grating_file_from,
    mapping_lamps,
    pooled_efficiency_terms,
    prepare_lamps,
    refine_grating,
    upre_scores,
    weight_score,
)
from calib.methods.prior_solve import PriorOptions, estimate_prior
from calib.model.bases import CameraBasis, fallback_camera_basis
from tests.synthetic_cameras import as_spectrum, exact_basis, gaussian_camera


@pytest.fixture(scope="module")
def basis(tmp_path_factory: pytest.TempPathFactory) -> CameraBasis:
    return exact_basis(tmp_path_factory.mktemp("basis"))[0]


def _scene(
    seed: int, lamp_set: str = "5 lamps", noise: float = 0.01
) -> tuple[
    np.ndarray, QuadraticMapping, tuple[LampObservation, ...], Callable[[np.ndarray], np.ndarray]
]:
    """A smooth camera near (not in) the basis' span, a random grating and mapping, the lamps."""
    rng = np.random.default_rng([99, seed])
    camera = gaussian_camera(
        (rng.uniform(575, 625), rng.uniform(515, 565), rng.uniform(435, 485)),
        (rng.uniform(28, 52), rng.uniform(33, 57), rng.uniform(23, 42)),
    )
    mapping = random_mapping(rng)
    efficiency = random_efficiency(rng)
    observations = render_lamps(
        LAMP_SETS[lamp_set], as_spectrum(camera), mapping, efficiency, rng, noise
    )
    return camera / camera.max(), mapping, observations, efficiency


def test_multilamp_is_registered_and_reachable_through_estimate(basis):
    truth, mapping, observations, _ = _scene(0, noise=0.0)
    assert "multilamp" in ESTIMATION_METHODS
    result = estimate(observations, method="multilamp", basis=basis, mapping=mapping)
    assert result.method == "multilamp"
    assert result.sensitivity_sigma is not None
    assert result.grating_efficiency_sigma is not None
    assert result.diagnostics["prior_weight_rule"] == "UPRE"
    assert result.diagnostics["direct_equations"] == 3 * len(observations)
    assert relative_error(result.sensitivity, truth) < 0.02
    # Five lamps measured directly: the front function's default (auto) chooses multilamp, says so.
    chosen = estimate(observations, basis=basis, mapping=mapping)
    assert (
        chosen.method == "multilamp" and "5 lamps" in chosen.diagnostics["method_choice"]["reason"]
    )
    np.testing.assert_array_equal(chosen.sensitivity, result.sensitivity)


def test_noise_free_lamps_recover_the_efficiency_and_the_camera(basis):
    truth, mapping, observations, efficiency = _scene(1, noise=0.0)
    result = estimate_multilamp(observations, basis=basis, mapping=mapping)
    true_eta = efficiency(DEFAULT_GRID.wavelength_nm)
    assert result.grating_efficiency is not None
    np.testing.assert_allclose(result.grating_efficiency, true_eta / true_eta.max(), atol=0.03)
    assert relative_error(result.sensitivity, truth) < 0.015


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_efficiency_model_fits_a_grating_the_inverse_model_cannot(basis, seed: int):
    """The protocol's η is smooth in η; its inverse over a 3:1 range is not (noise-free lamps)."""
    truth, mapping, observations, efficiency = _scene(seed, noise=0.0)
    true_eta = efficiency(DEFAULT_GRID.wavelength_nm)
    direct = estimate_multilamp(
        observations, basis=basis, mapping=mapping, options=MultilampOptions(uncertainty="none")
    )
    inverse = estimate_multilamp(
        observations,
        basis=basis,
        mapping=mapping,
        options=MultilampOptions(efficiency_model="inverse", uncertainty="none"),
    )
    assert direct.diagnostics["efficiency_model"] == "efficiency"
    assert inverse.diagnostics["efficiency_model"] == "inverse"
    assert direct.grating_efficiency is not None
    np.testing.assert_allclose(direct.grating_efficiency, true_eta / true_eta.max(), atol=0.02)
    direct_re = relative_error(direct.sensitivity, truth)
    assert direct_re < 0.005
    assert relative_error(inverse.sensitivity, truth) > 2 * direct_re


def test_a_steep_blazed_efficiency_stays_positive_and_beats_the_inverse_model(basis):
    """A grating blazed at 700 nm: sinc² efficiency rising 10:1 across the grid (noise-free)."""

    def blazed(wavelength_nm: np.ndarray) -> np.ndarray:
        return np.asarray(0.01 + np.sinc(700.0 / np.asarray(wavelength_nm) - 1.0) ** 2)

    rng = np.random.default_rng(5)
    camera = gaussian_camera((600, 540, 460), (40, 45, 30))
    mapping = random_mapping(rng)
    observations = render_lamps(
        LAMP_SETS["5 lamps"], as_spectrum(camera), mapping, blazed, rng, 0.0
    )
    truth = camera / camera.max()
    direct = estimate_multilamp(observations, basis=basis, mapping=mapping)
    inverse = estimate_multilamp(
        observations,
        basis=basis,
        mapping=mapping,
        options=MultilampOptions(efficiency_model="inverse"),
    )
    assert direct.grating_efficiency is not None and direct.sensitivity_sigma is not None
    assert np.all(direct.grating_efficiency > 0) and np.all(np.isfinite(direct.sensitivity_sigma))
    assert relative_error(direct.sensitivity, truth) < 0.5 * relative_error(
        inverse.sensitivity, truth
    )


def test_an_unknown_efficiency_model_is_named(basis):
    with pytest.raises(InputError, match="efficiency model"):
        MultilampOptions(efficiency_model="spline")  # type: ignore[arg-type]


def test_the_sigma_band_is_calibrated_pooled_over_scenes(basis):
    """The true curve inside ±2σ at 90–98 % of (wavelength, channel) cells, 1 % noise, 6 scenes."""
    coverage = []
    for seed in range(6):
        truth, mapping, observations, _ = _scene(seed)
        # The paper-style protocol draws no exposure error: the solve is told so.
        options = MultilampOptions(direct_gain_sigma=0.0)
        result = estimate_multilamp(observations, basis=basis, mapping=mapping, options=options)
        coverage.append(band_coverage(result, truth))
    assert 0.90 <= float(np.mean(coverage)) <= 0.98


def test_the_analytic_noise_sigma_agrees_with_a_bootstrap_over_the_noise_model(basis):
    _, mapping, observations, _ = _scene(0)
    # The bootstrap redraws the stated noise only (no exposure error: the solve is told so), and
    # one model throughout (a draw that switched models would not be the same estimator).
    model = MultilampOptions(direct_gain_sigma=0.0, grating_model="fourier")
    analytic = estimate_multilamp(
        observations, basis=basis, mapping=mapping, options=replace(model, uncertainty="noise")
    )
    bootstrap = bootstrap_sigma(
        observations,
        basis=basis,
        mapping=mapping,
        rng=np.random.default_rng(1),
        draws=20,
        options=replace(model, prior_weight=analytic.diagnostics["prior_weight"]),
    )
    assert analytic.sensitivity_sigma is not None
    bright = analytic.sensitivity > 0.05
    ratio = analytic.sensitivity_sigma[bright] / bootstrap[bright]
    assert 0.8 <= float(np.median(ratio)) <= 1.25
    # The posterior also carries the prior's uncertainty: never narrower than the noise alone.
    posterior = estimate_multilamp(observations, basis=basis, mapping=mapping, options=model)
    assert posterior.sensitivity_sigma is not None
    assert np.all(posterior.sensitivity_sigma >= analytic.sensitivity_sigma - 1e-9)


def test_the_prior_weight_falls_as_lamps_are_added(basis):
    _, mapping, observations, _ = _scene(2)
    one = estimate_multilamp(observations[:1], basis=basis, mapping=mapping)
    all_lamps = estimate_multilamp(observations, basis=basis, mapping=mapping)
    assert all_lamps.diagnostics["prior_weight"] < one.diagnostics["prior_weight"]


def test_the_prior_s_share_of_the_posterior_falls_as_lamps_are_added(basis):
    _, mapping, observations, _ = _scene(2)
    one = estimate_multilamp(observations[:1], basis=basis, mapping=mapping)
    all_lamps = estimate_multilamp(observations, basis=basis, mapping=mapping)
    assert 0 < all_lamps.diagnostics["prior_share"] < one.diagnostics["prior_share"] <= 1


@pytest.mark.parametrize("rule", ["typicality", "evidence"])
def test_a_rule_widens_the_prior_of_an_unusual_camera(basis, rule: str):
    """A camera near the training set keeps a strong prior, a Foveon does not: typicality by
    λ_k = d₀ / D²_k, the evidence by how well the prior at each weight explains the camera."""
    assert basis.prior().typical_distance == pytest.approx(basis.typical_distance)
    _, mapping, typical, efficiency = _scene(0)
    foveon = find_camera(colour_science_cameras(), "Sigma SDMerill").sensitivity
    unusual = render_lamps(
        LAMP_SETS["5 lamps"], foveon, mapping, efficiency, np.random.default_rng(5), 0.01
    )
    weights = {}
    for name, observations in (("typical", typical), ("unusual", unusual)):
        result = estimate_multilamp(
            observations,
            basis=basis,
            mapping=mapping,
            options=MultilampOptions(weight_rule=rule),  # type: ignore[arg-type]
        )
        diagnostics = result.diagnostics
        assert diagnostics["prior_weight_rule"] == rule
        assert diagnostics["typical_distance"] == pytest.approx(basis.typical_distance)
        weights[name] = diagnostics["prior_weight"]
    assert weights["unusual"] < 0.1 * weights["typical"]
    with pytest.raises(InputError, match="prior weight rule"):
        MultilampOptions(weight_rule="guess")  # type: ignore[arg-type]


@pytest.mark.parametrize("rule", ["evidence", "upre"])
def test_a_rule_recovers_the_prior_weight_of_a_well_specified_linear_model(rule: str) -> None:
    """x ~ N(0, I/λ), b = A x + unit noise: both rules find λ = 4 on the grid (within a factor 1.6)."""
    chosen = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        # 160 equations, 80 unknowns: as decisive as 300 × 150 on these seeds, at a fifth of the cost.
        design = 0.3 * rng.standard_normal((160, 80))
        truth = rng.standard_normal(80) / 2.0
        target = design @ truth + rng.standard_normal(160)
        weight, curve = choose_prior_weight(
            design,
            target,
            np.eye(80),
            np.logspace(-3, 3, 61),
            rule=rule,  # type: ignore[arg-type]
        )
        assert curve.shape == (61,) and weight == np.logspace(-3, 3, 61)[np.argmin(curve)]
        chosen.append(weight)
    assert min(chosen) > 4.0 / 1.6 and max(chosen) < 4.0 * 1.6


def test_more_lamps_beat_the_single_lamp_prior_solve_on_a_camera_outside_the_basis():
    """Sigma SDMerill (Foveon) against a basis of the other colour-science cameras."""
    prior_basis = fallback_camera_basis(exclude=["Sigma SDMerill"])
    camera = find_camera(colour_science_cameras(), "Sigma SDMerill").sensitivity
    rng = np.random.default_rng(3)
    mapping = random_mapping(rng)
    observations = render_lamps(
        LAMP_SETS["3 lamps + RGB LEDs"], camera, mapping, random_efficiency(rng), rng, 0.01
    )
    truth = camera.resample(DEFAULT_GRID, "interpolate", out_of_range="zero").values
    truth = truth / truth.max()
    multi = estimate_multilamp(observations, basis=prior_basis, mapping=mapping)
    single = estimate_prior(
        observations,
        basis=prior_basis,
        mapping=mapping,
        options=PriorOptions(solve_lamps=(observations[0].name,)),
    )
    assert relative_error(multi.sensitivity, truth) < 0.75 * relative_error(
        single.sensitivity, truth
    )


def test_a_grating_file_lets_one_led_shot_estimate_a_new_camera(basis, tmp_path: Path):
    _, mapping, observations, efficiency = _scene(4, noise=0.003)
    calibrated = calibrate_lamps(
        prepare_lamps(observations, basis=basis, mapping=mapping), basis.prior()
    )
    path = write_grating_file(
        tmp_path / "grating.json", grating_file_from(calibrated, description="bench A")
    )
    grating = read_grating_file(path)
    assert grating.efficiency_sigma is not None
    assert grating.geometry["description"] == "bench A"
    assert json.loads(path.read_text())["provenance"]["method"] == "multilamp"
    # Another camera behind the same grating, one LED, no direct measurement needed.
    rng = np.random.default_rng(11)
    other = gaussian_camera((605, 530, 455), (35, 45, 28))
    (led,) = render_lamps(("LED-B3",), as_spectrum(other), mapping, efficiency, rng, 0.003)
    led = LampObservation(
        name=led.name,
        spectrum=led.spectrum,
        pixel=led.pixel,
        profile=led.profile,
        profile_sigma=led.profile_sigma,
        kind="led",
    )
    result = estimate_known_grating([led], grating=grating, basis=basis, mapping=mapping)
    assert result.sensitivity_sigma is not None
    assert relative_error(result.sensitivity, other / other.max()) < 0.04


def test_cameras_through_one_grating_share_and_refine_it(basis):
    scenes = [_scene(seed) for seed in (5, 6)]
    # One grating for both: re-render the second camera through the first scene's.
    _, mapping, first, efficiency = scenes[0]
    rng = np.random.default_rng(12)
    second = render_lamps(
        LAMP_SETS["5 lamps"],
        as_spectrum(gaussian_camera((610, 545, 450), (40, 40, 30))),
        mapping,
        efficiency,
        rng,
        0.01,
    )
    alone = calibrate_lamps(prepare_lamps(first, basis=basis, mapping=mapping), basis.prior())
    grating, results = refine_grating([first, second], basis=basis, mappings=[mapping, mapping])
    assert len(results) == 2
    assert grating.efficiency_sigma is not None
    alone_sigma = grating_file_from(alone).efficiency_sigma
    assert alone_sigma is not None
    assert float(np.mean(grating.efficiency_sigma)) < float(np.mean(alone_sigma))


def test_each_camera_of_a_pooled_solve_has_its_own_prior_scale(basis):
    from calib.methods.multilamp import _stacked_prior_rows, pool_responses

    groups = []
    for seed in (5, 6):
        _, mapping, observations, _ = _scene(seed)
        lamps = prepare_lamps(observations, basis=basis, mapping=mapping).lamps
        groups.append(pool_responses([lamp.response for lamp in lamps])[0])
    size = DEFAULT_GRID.size
    rows = _stacked_prior_rows(groups, basis.prior(), np.ones(size), np.array([1.0, 2.0]))
    assert rows.shape == (2 * 3 * size, size + 2)
    first, second = rows[: 3 * size], rows[3 * size :]
    assert np.all(first[:, size + 1] == 0) and np.any(first[:, size] != 0)
    assert np.all(second[:, size] == 0) and np.any(second[:, size + 1] != 0)
    # Each block judges its own camera's pooled response.
    assert not np.allclose(first[:, :size], second[:, :size])


def test_the_mapping_is_searched_with_the_fluorescent_lamp_and_one_other():
    _, _, observations, _ = _scene(0, noise=0.0)
    fluorescent = [o for o in observations if o.kind == "fluorescent"]
    chosen = mapping_lamps(observations)
    assert chosen[: len(fluorescent)] == fluorescent
    assert len(chosen) == len(fluorescent) + 1


def test_bad_inputs_are_named(basis):
    _, mapping, observations, _ = _scene(0, noise=0.0)
    with pytest.raises(InputError, match="unique"):
        estimate_multilamp([observations[0], observations[0]], basis=basis, mapping=mapping)
    with pytest.raises(InputError, match="uncertainty"):
        MultilampOptions(uncertainty="maybe")  # type: ignore[arg-type]
    no_direct = LampObservation(
        name="bare",
        spectrum=observations[0].spectrum,
        pixel=observations[0].pixel,
        profile=observations[0].profile,
    )
    with pytest.raises(InputError, match="direct"):
        estimate_multilamp([no_direct], basis=basis, mapping=mapping)


def test_a_camera_behind_a_filter_is_a_different_camera():
    from calib.evaluation.synthetic import behind_filter, colour_filter

    camera = MultiSpectrum(DEFAULT_GRID.wavelength_nm, np.ones((DEFAULT_GRID.size, 3)))
    filtered = behind_filter(camera, colour_filter())
    assert filtered.values[0, 0] > 0.8 and filtered.values[-1, 0] < 0.15


@pytest.mark.parametrize(
    ("equations", "terms"), [(3, 7), (15, 7), (30, 7), (44, 11), (45, 11), (60, 15), (600, 15)]
)
def test_pooled_equations_afford_more_efficiency_terms(equations: int, terms: int) -> None:
    assert pooled_efficiency_terms(equations) == terms


def test_a_pooled_grating_file_carries_the_rig_geometry_it_was_measured_in(basis):
    # A mapping fitted as a grating from the direct spot: the file stores that rig (its groove
    # spacing, focal length and incidence), so a new camera through it reuses what still holds.
    from calib.core.mapping import TiltedGrating
    from calib.wavelength import RigGeometry

    _, mapping, first, _ = _scene(5)
    grating = TiltedGrating(
        dispersion_nm_per_px=0.43, focal_length_px=2400.0, incidence_deg=3.0, zero_order_px=0.0
    )
    fitted = mapping.with_details(details={"grating": grating.to_dict()})
    spot = [replace(obs, pixel_origin="direct_spot") for obs in first]
    written, _ = refine_grating([spot], basis=basis, mappings=[fitted])
    assert written.rig is not None
    stored = RigGeometry.from_dict(written.rig)
    assert stored.grating.incidence_deg == pytest.approx(3.0)
    assert stored.grating.focal_length_px == pytest.approx(2400.0)


def test_a_response_left_out_of_the_pool_keeps_its_scale_and_moves_nothing() -> None:
    from calib.methods.multilamp import pool_responses
    from calib.methods.responses import ResponseEstimate

    rng = np.random.default_rng(5)
    size = 12
    shape = rng.uniform(0.2, 1.0, (size, 3))
    covariance = np.stack([np.eye(size) * 1e-4] * 3)
    used = np.ones(20, dtype=bool)
    clean = [ResponseEstimate(scale * shape, covariance, used, 0.0) for scale in (1.0, 2.0)]
    # A third lamp, three times as bright, whose response is off by 30 % at a few nodes (a narrow
    # band over a spectrum measured on a slightly wrong wavelength scale), with a small σ.
    biased = 3.0 * shape
    biased[4:7] *= 1.3
    third = ResponseEstimate(biased, covariance / 100.0, used, 0.0)
    alone, _, _ = pool_responses(clean)
    pooled, scales, weights = pool_responses([*clean, third], pooled=[True, True, False])
    np.testing.assert_allclose(pooled.response, alone.response, rtol=1e-12)
    np.testing.assert_allclose(scales[:2], [1.0, 2.0], rtol=1e-9)
    assert scales[2] == pytest.approx(3.0, rel=0.15)
    assert np.all(weights[2] == 0.0)
    everything, _, _ = pool_responses([*clean, third])
    assert np.max(np.abs(everything.response / shape - 1.0)) > 0.1
    with pytest.raises(InputError, match="pooling flags"):
        pool_responses(clean, pooled=[False, False])


def test_narrow_band_lamps_pin_the_grating_but_not_the_sensitivity(basis):
    # The narrow-band LEDs' spectra read 1 nm off (the spectrometer's wavelength scale): their
    # responses are wrong on the LEDs' flanks by far more than their noise σ. Left out of the
    # pooled response (decision 0058), they still give η its direct equations.
    from calib.methods.multilamp import (
        EfficiencySettings,
        combine_responses,
        lamp_kinds,
        sensitivity_lamps,
    )

    truth, mapping, observations, _ = _scene(0, "3 lamps + RGB LEDs", noise=0.0)
    shifted = [
        replace(
            obs,
            spectrum=replace(obs.spectrum, wavelength_nm=obs.spectrum.wavelength_nm + 1.0),
        )
        if obs.kind == "narrowband"
        else obs
        for obs in observations
    ]
    prepared = prepare_lamps(shifted, basis=basis, mapping=mapping)
    calibrated = calibrate_lamps(
        prepared, basis.prior(), EfficiencySettings(grating_model="fourier")
    )
    rule = sensitivity_lamps(lamp_kinds(shifted, calibrated.lamps))
    assert rule == [obs.kind != "narrowband" for obs in shifted]
    errors = []
    for pooled in (rule, None):
        solution = combine_responses(
            [lamp.response for lamp in calibrated.lamps],
            calibrated.efficiency.inverse_efficiency,
            calibrated.efficiency.inverse_jacobian,
            calibrated.efficiency.coefficient_covariance,
            with_covariance=False,
            pooled=pooled,
        )
        errors.append(relative_error(solution.normalised()[0], truth))
    assert errors[0] < 0.007
    assert errors[1] > 1.5 * errors[0]


def test_steep_spectra_on_a_wrong_wavelength_scale_are_weighed_down_in_the_pool(basis):
    # Every measured spectrum reads 0.5 nm off (the spectrometer's stated scale accuracy): the
    # fluorescent lines' and the white LED's steep flanks put their responses off by tens of per
    # cent there, far beyond their noise σ. Weighed with that share (decision 0067), the pooled
    # response follows the smooth lamps there; weighed by noise alone it follows the steep ones.
    from calib.methods.multilamp import (
        POOLING_SCALE_SIGMA_NM,
        combine_responses,
        lamp_kinds,
        sensitivity_lamps,
    )

    truth, mapping, observations, efficiency = _scene(0, "3 lamps + RGB LEDs")
    shifted = [
        replace(obs, spectrum=replace(obs.spectrum, wavelength_nm=obs.spectrum.wavelength_nm + 0.5))
        for obs in observations
    ]
    prepared = prepare_lamps(shifted, basis=basis, mapping=mapping)
    inverse = 1.0 / efficiency(DEFAULT_GRID.wavelength_nm)
    errors = []
    for scale_sigma in (POOLING_SCALE_SIGMA_NM, None):
        solution = combine_responses(
            [lamp.response for lamp in prepared.lamps],
            inverse,
            np.eye(inverse.size),
            np.zeros((inverse.size, inverse.size)),
            with_covariance=False,
            pooled=sensitivity_lamps(lamp_kinds(shifted, prepared.lamps)),
            scale_sigma_nm=scale_sigma,
        )
        errors.append(relative_error(solution.normalised()[0], truth))
    assert errors[0] < 0.007
    assert errors[1] > 1.8 * errors[0]


def test_a_lamps_wavelength_scale_share_follows_its_spectrums_log_slope() -> None:
    from calib.core.spectra import Spectrum
    from calib.methods.responses import ResponseEstimate, log_slope_squared
    from calib.model.forward import lamp_operators

    wavelength = np.arange(380.0, 781.0)
    # A Gaussian line (σ 15 nm): d ln e/dλ = −(λ − 550)/15², so 0.5 nm moves e by 11 % at 600 nm.
    line = Spectrum(wavelength, np.exp(-0.5 * ((wavelength - 550.0) / 15.0) ** 2), name="line")
    slope2 = log_slope_squared(lamp_operators(line, DEFAULT_GRID))
    nodes = DEFAULT_GRID.wavelength_nm
    # The light-weighted mean over each node's hat, integrated finely: Σ e φ (d ln e/dλ)² / Σ e φ.
    fine = np.linspace(nodes[0], nodes[-1], 30001)
    light = np.exp(-0.5 * ((fine - 550.0) / 15.0) ** 2)
    hats = np.clip(1.0 - np.abs(fine[:, None] - nodes[None, :]) / DEFAULT_GRID.step_nm, 0, None)
    weights = light[:, None] * hats
    expected = (weights * (((fine - 550.0) / 15.0**2) ** 2)[:, None]).sum(0) / weights.sum(0)
    # Where the line has light (below 1e-12 of its peak, ln e is floored: no slope).
    lit = np.abs(nodes - 550.0) <= 100.0
    np.testing.assert_allclose(slope2[lit], expected[lit], rtol=0.02, atol=1e-4)
    flat = Spectrum(wavelength, np.full(wavelength.size, 2.0), name="flat")
    np.testing.assert_allclose(
        log_slope_squared(lamp_operators(flat, DEFAULT_GRID)), 0.0, atol=1e-12
    )
    size = nodes.size
    response = ResponseEstimate(
        np.full((size, 3), 2.0),
        np.stack([np.eye(size)] * 3),
        np.ones(5, dtype=bool),
        0.0,
        log_slope_squared=slope2,
    )
    share = response.scale_variance(0.5)
    np.testing.assert_allclose(share[:, 1], (2.0 * 0.5) ** 2 * slope2)
    assert (
        ResponseEstimate(response.response, response.covariance, response.used_pixels, 0.0)
        .scale_variance()
        .max()
        == 0.0
    )


def test_a_spectrum_its_hg_lines_checked_is_weighed_with_the_checks_sigma(basis):
    # A fluorescent spectrum corrected by its own Hg lines (decision 0069) is off by the check's σ,
    # not by the spectrometer's tolerance: its response takes its due share of Q again.
    from calib.core.spectrometer_scale import SCALE_SIGMA_KEY
    from calib.methods.multilamp import (
        POOLING_SCALE_SIGMA_NM,
        pool_responses,
        pooling_scale_sigmas,
    )

    _, mapping, observations, _ = _scene(0, "3 lamps + RGB LEDs")
    checked = [
        replace(obs, metadata={**obs.metadata, SCALE_SIGMA_KEY: 0.05})
        if obs.kind == "fluorescent"
        else obs
        for obs in observations
    ]
    prepared = prepare_lamps(checked, basis=basis, mapping=mapping)
    sigmas = pooling_scale_sigmas(checked, prepared.lamps)
    kinds = {obs.name: obs.kind for obs in checked}
    assert sigmas == [
        0.05 if kinds[lamp.name] == "fluorescent" else POOLING_SCALE_SIGMA_NM
        for lamp in prepared.lamps
    ]
    responses = [lamp.response for lamp in prepared.lamps]
    fluorescent = next(
        i for i, lamp in enumerate(prepared.lamps) if kinds[lamp.name] == "fluorescent"
    )
    _, _, tolerance_weights = pool_responses(responses, scale_sigma_nm=POOLING_SCALE_SIGMA_NM)
    _, _, checked_weights = pool_responses(responses, scale_sigma_nm=sigmas)
    gain = checked_weights[fluorescent].sum() / tolerance_weights[fluorescent].sum()
    assert gain > 1.2, gain
    # The same σ for every lamp, given either way, pools the same.
    same, _, _ = pool_responses(responses, scale_sigma_nm=[0.3] * len(responses))
    scalar, _, _ = pool_responses(responses, scale_sigma_nm=0.3)
    np.testing.assert_array_equal(same.response, scalar.response)


def _gauss_newton_problem(
    seed: int = 7,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A small ``η = B c`` problem: data nodes, target, prior rows, Fourier-like basis, a start."""
    rng = np.random.default_rng(seed)
    size, terms, scales = 31, 7, 1
    wavelength = np.linspace(400.0, 700.0, size)
    basis = np.cos(np.pi * np.outer((wavelength - 400.0) / 300.0, np.arange(terms)))
    data_nodes = rng.uniform(0.0, 1.0, (6, size))
    truth = 1.0 / (0.5 + 0.2 * np.sin(wavelength / 60.0))
    target = data_nodes @ truth + 0.01 * rng.normal(size=6)
    penalty_nodes = np.hstack(
        [rng.normal(size=(3 * size, size)) * 0.1, rng.normal(size=(3 * size, scales))]
    )
    start = np.concatenate([np.linalg.lstsq(basis, 1.0 / truth, rcond=None)[0], np.ones(scales)])
    return data_nodes, target, penalty_nodes, basis, start


def test_the_gauss_newton_state_it_returns_is_the_one_at_its_solution() -> None:
    """:func:`_efficiency_terms_solve` hands its last ``η⁻¹``, residuals and Jacobians to the
    weight's score (decisions 0083, 0107): each must be what ``x`` gives afresh, after steps and
    from the optimum; and Jacobians handed in for the start give the same solve to the bit."""
    data_nodes, target, penalty_nodes, basis, start = _gauss_newton_problem()
    size, terms = basis.shape
    for weight in (1e-3, 1.0):
        first = _efficiency_terms_solve(
            data_nodes, target, penalty_nodes, basis, start * 1.1, weight
        )
        x = first[0]
        assert not np.allclose(x, start * 1.1)  # steps were taken
        second = _efficiency_terms_solve(data_nodes, target, penalty_nodes, basis, x, weight)
        for solution, inverse, data_residual, penalty_residual, jacobians in (first, second):
            fresh = 1.0 / (basis @ solution[:terms])
            assert np.array_equal(inverse, fresh)
            assert np.array_equal(data_residual, data_nodes @ fresh - target)
            assert np.array_equal(
                penalty_residual,
                penalty_nodes[:, :size] @ fresh + penalty_nodes[:, size:] @ solution[terms:],
            )
            for made, afresh in zip(
                jacobians,
                _efficiency_jacobians(data_nodes, penalty_nodes, basis, fresh),
                strict=True,
            ):
                assert np.array_equal(made, afresh)
        # The start's Jacobians handed in: the same solve, and the handed arrays left as they were.
        handed = _efficiency_jacobians(data_nodes, penalty_nodes, basis, 1.0 / (basis @ x[:terms]))
        copies = [array.copy() for array in handed]
        warm = _efficiency_terms_solve(data_nodes, target, penalty_nodes, basis, x, weight, handed)
        for made, expected in zip(warm[:4], second[:4], strict=True):
            assert np.array_equal(made, expected)
        for array, copy in zip(handed, copies, strict=True):
            assert np.array_equal(array, copy)


def test_the_weights_are_scored_at_once_as_one_by_one() -> None:
    """Decision 0107: UPRE's scores over the weights in one pass equal :func:`weight_score` weight
    by weight to the bit (the stacked pseudo-inverse is ``pinv_symmetric``'s, also for singular
    and indefinite matrices)."""
    from calib.core.blas import pinv_symmetric

    rng = np.random.default_rng(3)
    matrices = rng.normal(size=(30, 8, 8))
    matrices = matrices @ matrices.transpose(0, 2, 1) * np.logspace(-6, 6, 30)[:, None, None]
    matrices[::3, 0, :] = matrices[::3, :, 0] = 0.0  # singular
    matrices[1::3] -= 2.0 * np.eye(8) * np.abs(matrices[1::3]).max()  # indefinite
    stacked = pinv_symmetric_stack(matrices)
    for matrix, inverse in zip(matrices, stacked, strict=True):
        assert np.array_equal(inverse, pinv_symmetric(matrix))


def _full_weight_chain(
    problem: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> np.ndarray:
    """UPRE at every weight of :data:`PRIOR_WEIGHTS`, each solved from the next larger one's
    solution (the search before decision 0125)."""
    data_nodes, target, penalty_nodes, basis, state = problem
    scores = []
    for candidate in PRIOR_WEIGHTS[::-1].tolist():
        state, _, data_residual, penalty_residual, (solved_data, solved_penalty) = (
            _efficiency_terms_solve(data_nodes, target, penalty_nodes, basis, state, candidate)
        )
        scores.append(
            weight_score(
                "upre", candidate, data_residual, penalty_residual, solved_data, solved_penalty
            )
        )
    return np.array(scores)[::-1]


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_the_weight_search_finds_the_full_grids_best_from_a_few_weights(
    monkeypatch: pytest.MonkeyPatch, seed: int
) -> None:
    """Decision 0125: the coarse-to-fine search over the prior weights chooses the weight the
    full chain over all 41 chooses, the scores the same to 1e-7, from fewer than half of them
    (each scored afresh at its solution), computing the Jacobians once per solution; a later pass
    from that choice (``near_index``) scores three and keeps it."""
    import calib.methods.multilamp as multilamp

    problem = _gauss_newton_problem(seed=seed)
    data_nodes, target, penalty_nodes, basis, start = problem
    full = _full_weight_chain(problem)
    seen: list[bytes] = []
    jacobians = multilamp._efficiency_jacobians

    def counted(
        data: np.ndarray,
        penalty: np.ndarray,
        efficiency_basis: np.ndarray,
        inverse: np.ndarray,
        out: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        seen.append(inverse.tobytes())
        return jacobians(data, penalty, efficiency_basis, inverse, out)

    monkeypatch.setattr(multilamp, "_efficiency_jacobians", counted)
    x, data_jac, penalty_jac, weight, scores, chosen = _nonlinear_efficiency(
        data_nodes, target, penalty_nodes, basis, start, None, "upre"
    )
    assert len(set(seen)) == len(seen)  # never twice at one η⁻¹
    solved = np.isfinite(scores)
    assert solved.sum() < PRIOR_WEIGHTS.size // 2
    assert chosen == int(np.argmin(full)) == int(np.nanargmin(scores))
    assert weight == PRIOR_WEIGHTS[chosen]
    np.testing.assert_allclose(scores[solved], full[solved], rtol=1e-7)
    # The returned state is the chosen weight's solution: its score afresh is the curve's.
    inverse = 1.0 / (basis @ x[:7])
    afresh = upre_scores(
        np.array([weight]), [data_nodes @ inverse - target], [data_jac], [penalty_jac]
    )
    assert afresh[0] == scores[chosen]
    again = _nonlinear_efficiency(
        data_nodes, target, penalty_nodes, basis, x, None, "upre", near_index=chosen
    )
    assert again[5] == chosen
    assert np.isfinite(again[4]).sum() == 3


def test_a_weights_solve_reaches_its_minimum_where_gauss_newton_crawls() -> None:
    """Decision 0125: with residuals that are not small (a target far off the model), Gauss–
    Newton's ``JᵀJ`` misses the curvature the residuals add and crawls (30 iterations left the
    cost 0.29 relative above its minimum here); the Newton steps land on the minimum: the
    gradient vanishes and a solve from there does not lower the cost."""
    rng = np.random.default_rng(1)
    data_nodes, target, penalty_nodes, basis, start = _gauss_newton_problem(seed=1)
    target = target + rng.normal(size=target.size)  # residuals at the noise's scale, σ = 1
    weight = 0.01
    x, _, data_residual, penalty_residual, (data_jac, penalty_jac) = _efficiency_terms_solve(
        data_nodes, target, penalty_nodes, basis, start, weight
    )
    cost = data_residual @ data_residual + weight * penalty_residual @ penalty_residual
    gradient = data_jac.T @ data_residual + weight * penalty_jac.T @ penalty_residual
    scale = np.sqrt(np.diag(data_jac.T @ data_jac + weight * penalty_jac.T @ penalty_jac))
    assert np.abs(gradient / scale).max() < 1e-6 * np.sqrt(cost)
    polished = _efficiency_terms_solve(data_nodes, target, penalty_nodes, basis, x, weight)
    polished_cost = polished[2] @ polished[2] + weight * polished[3] @ polished[3]
    assert polished_cost >= cost * (1 - 1e-12)


def test_a_channel_darker_than_the_spectrums_floor_gets_its_share_of_sigma() -> None:
    """Each channel's direct σ is at least :data:`SPECTRUM_FLOOR` of the lamp's brightest: the
    blue of a red LED (10⁻⁴ of its red) is left to the spectrometer's noise, the red itself
    barely moves."""
    from calib.methods.multilamp import SPECTRUM_FLOOR, with_spectrum_floor
    from calib.methods.responses import LampData

    lamp = LampData(
        "gauss:630:20",
        np.ones(4),
        None,  # type: ignore[arg-type]  # the floor reads only the direct measurement
        np.array([9.0, 0.2, 9e-4]),
        np.array([2e-3, 6e-5, 2e-5]),
    )
    floored = with_spectrum_floor(lamp, SPECTRUM_FLOOR)
    assert floored.direct_sigma[2] == pytest.approx(SPECTRUM_FLOOR * 9.0, rel=1e-3)
    assert floored.direct_sigma[2] > floored.direct[2]  # the blue equation no longer decides
    assert floored.direct_sigma[0] < 5 * lamp.direct_sigma[0]
    assert np.all(floored.direct_sigma >= lamp.direct_sigma)


@pytest.mark.slow
def test_rgb_leds_under_a_noisy_spectrometer_at_the_rigs_snr(shared_camera_data: Path) -> None:
    """The validation split's Canon 5D scene, 3 lamps + RGB LEDs (decision 0103): at the rig's
    bracket SNR the red LED's blue and the blue LED's red direct equations are predicted from
    the reference spectrum's noise floor; without :func:`with_spectrum_floor` the grating model
    turns Fourier and RE is 0.14, with it 0.0045."""
    from calib.evaluation.validation.protocol import (
        DEFAULT_VARIANTS,
        ProtocolSettings,
        evaluate_task,
        split_tasks,
    )
    from calib.evaluation.validation.splits import load_splits

    splits, _ = load_splits(shared_camera_data)
    variant = next(v for v in DEFAULT_VARIANTS if v.label == "3 lamps + RGB LEDs")
    settings = ProtocolSettings(variants=(variant,))
    task = next(
        t
        for t in split_tasks(splits.validation, settings)
        if t.camera.name.startswith("Canon 5D (Kawakami")
    )
    (row,) = evaluate_task(task)
    assert row.failure is None
    assert row.relative_error < 0.02


def test_only_a_measured_spectrum_with_a_noisy_dark_range_gets_the_floor() -> None:
    """A narrow LED read with a spectrometer's noise floor (clipped at 0, as a file is read) gets
    :data:`SPECTRUM_FLOOR`; the exact LED and a noisy broadband lamp (no dark range) get none."""
    from calib.core.lamp_specs import gaussian_lamp, lamp_from_spec
    from calib.core.spectra import Spectrum
    from calib.methods.multilamp import SPECTRUM_FLOOR, spectrum_floor

    rng = np.random.default_rng(3)
    led = gaussian_lamp(630.0, 20.0)
    noisy = led.values + 5e-4 * rng.standard_normal(led.values.size)
    assert spectrum_floor(led) == 0.0
    assert spectrum_floor(Spectrum(led.wavelength_nm, noisy, negative="clip")) == SPECTRUM_FLOOR
    tungsten = lamp_from_spec("A")
    grainy = tungsten.values * (1 + 3e-3 * rng.standard_normal(tungsten.values.size))
    assert spectrum_floor(Spectrum(tungsten.wavelength_nm, grainy)) == 0.0
