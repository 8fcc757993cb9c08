"""calib.methods.known_grating: the one solver through a grating of known (or flat) efficiency.

It replaced two: ``multilamp.estimate_with_grating`` (a grating file, ``s = q̂ / η``) and the old
``known_grating.estimate_with_known_grating`` (no direct measurement: a file, or a flat grating,
and the mapping from the lamps). Both call paths' behaviours are checked here, and that the options
reach the solve (``prior_shrinkage`` was dropped on the way before).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import mapping_relative_error, relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import band_coverage, random_efficiency, random_mapping
from calib.methods import KnownGratingOptions, MultilampOptions, estimate
from calib.methods.grating_models import (
    assumed_candidates,
    assumed_efficiency,
    candidate_log_evidence,
    check_assumed_families,
)
from calib.methods.known_grating import (
    ONE_LAMP_PRIOR_WEIGHTS,
    estimate_known_grating,
    is_assumed_physical,
    one_lamp_prior_weight,
)
from calib.methods.multilamp import SensitivitySolution
from calib.methods.uncertainty import COVERAGE_SCALE, efficiency_family
from calib.model.bases import CameraBasis, CameraPrior
from calib.model.forward import PeakFractionNoise, render_observation
from calib.model.gratings import BlazedGrating, SinusoidalPhaseGrating
from calib.pipeline import LampProfile, OfflineSettings, estimate_offline
from tests.synthetic_cameras import as_spectrum, exact_basis, gaussian_camera

FLAT = KnownGratingOptions(assumed_grating="flat")
PHYSICAL = KnownGratingOptions(assumed_grating="physical")
CAMERA = gaussian_camera((605, 530, 455), (35, 45, 28))
TRUTH = CAMERA / CAMERA.max()


@pytest.fixture(scope="module")
def basis(tmp_path_factory: pytest.TempPathFactory) -> CameraBasis:
    return exact_basis(tmp_path_factory.mktemp("basis"))[0]


def _scene(seed: int = 4):
    rng = np.random.default_rng([7, seed])
    mapping = random_mapping(rng)
    efficiency = random_efficiency(rng)
    wavelength = np.arange(380.0, 721.0, 2.0)
    grating = GratingEfficiency(wavelength, efficiency(wavelength), source="truth")
    return rng, mapping, efficiency, grating


def _lamp(spec: str, kind, mapping, efficiency, rng, noise: float = 0.003) -> LampObservation:
    observation = render_observation(
        colour_lamp(spec),
        as_spectrum(CAMERA),
        mapping=mapping,
        pixel=round(mapping.pixel_range[1]) + 1,
        grating_efficiency=efficiency,
        noise=PeakFractionNoise(noise) if noise else None,
        rng=rng,
        kind=kind,
    ).observation
    return replace(observation, direct_rgb=None, direct_sigma=None)  # not needed, not given


def test_through_a_grating_file_one_led_without_a_direct_measurement_suffices(basis):
    """The grating-library path (``multilamp.estimate_with_grating`` before): s = q̂ / η."""
    rng, mapping, efficiency, grating = _scene()
    led = _lamp("LED-B3", "led", mapping, efficiency, rng)
    result = estimate_known_grating([led], grating=grating, basis=basis, mapping=mapping)
    assert result.method == "known-grating"
    assert relative_error(result.sensitivity, TRUTH) < 0.04
    assert result.sensitivity_sigma is not None and 0.8 <= band_coverage(result, TRUTH) <= 1.0
    eta = efficiency(DEFAULT_GRID.wavelength_nm)
    assert result.grating_efficiency is not None
    np.testing.assert_allclose(result.grating_efficiency, eta / eta.max(), rtol=1e-9)
    assert result.diagnostics["grating"]["source"] == "truth"
    # The front function reaches the same solver, and refuses to run it without saying η.
    through_front = estimate([led], "known-grating", basis=basis, mapping=mapping, grating=grating)
    np.testing.assert_allclose(through_front.sensitivity, result.sensitivity, atol=1e-12)
    with pytest.raises(InputError, match="needs grating="):
        estimate([led], "known-grating", basis=basis, mapping=mapping)


def test_a_grating_file_with_its_sigma_has_a_judged_band_a_makers_curve_says_it_has_none(basis):
    """A calibration's file (η with σ) is the budget's ``known-grating:file`` key, judged on the
    validation split (decision 0075); a maker's curve (no σ) keeps the largest factor and says so."""
    rng, mapping, efficiency, grating = _scene()
    led = _lamp("LED-B3", "led", mapping, efficiency, rng)
    calibrated = replace(grating, efficiency_sigma=np.full(grating.wavelength_nm.size, 0.005))
    results = {
        name: estimate([led], "known-grating", basis=basis, mapping=mapping, grating=given)
        for name, given in (("file", calibrated), ("maker", grating))
    }
    codes = {name: {flag.code for flag in r.quality.flags} for name, r in results.items()}
    assert efficiency_family(results["file"]) == "file"
    assert (
        results["file"].quality.uncertainty["coverage_scale"]
        == COVERAGE_SCALE["known-grating:file"]
    )
    assert "uncertainty_unvalidated" not in codes["file"]
    assert efficiency_family(results["maker"]) is None
    assert results["maker"].quality.uncertainty["coverage_scale"] == max(COVERAGE_SCALE.values())
    assert {"uncertainty_unvalidated", "grating_sigma_missing"} <= codes["maker"]


@pytest.mark.parametrize("spread", [0.25, 1.0, 4.0])
def test_one_lamps_prior_weight_is_the_evidences(spread: float) -> None:
    """Cameras drawn from the prior with ``spread`` × its covariance (well measured): the evidence
    gives the prior the weight ``1 / spread`` (decision 0080), whatever the data's overall scale."""
    grid = DEFAULT_GRID
    size = grid.size
    rng = np.random.default_rng(3)
    mean = gaussian_camera((605, 530, 455), (35, 45, 28))
    distance = (grid.wavelength_nm[:, None] - grid.wavelength_nm[None, :]) / 30.0
    covariance = np.stack([0.01 * np.exp(-0.5 * distance**2) + 1e-6 * np.eye(size)] * 3)
    prior = CameraPrior(grid, mean, covariance, np.zeros(3))
    noise = np.diag(np.full(3 * size, 1e-8))
    factor = np.linalg.cholesky(spread * covariance[0])
    chosen = []
    for _ in range(5):
        camera = mean + np.stack([factor @ rng.standard_normal(size) for _ in range(3)], axis=1)
        solution = SensitivitySolution(3.0 * camera, 9.0 * noise, np.ones(1))
        chosen.append(one_lamp_prior_weight(solution, prior))
    ratio = np.exp(np.mean(np.log(chosen))) * spread
    assert 0.6 < ratio < 1.6, chosen
    # Without a covariance the prior keeps its natural weight.
    assert one_lamp_prior_weight(SensitivitySolution(mean, None, np.ones(1)), prior) == 1.0


def test_one_lamp_through_a_grating_file_weighs_the_prior_by_the_evidence(basis):
    """Only one lamp through a calibration's file (η with σ, where decision 0080 judged it): the
    assumed-η solves keep the prior at its natural weight, where their σ factors were judged
    (decision 0075), and so does a maker's curve (no σ: unjudged)."""
    rng, mapping, efficiency, grating = _scene()
    led = _lamp("LED-B3", "led", mapping, efficiency, rng)
    calibrated = replace(grating, efficiency_sigma=np.full(grating.wavelength_nm.size, 0.005))
    through_file = estimate_known_grating([led], grating=calibrated, basis=basis, mapping=mapping)
    assert through_file.diagnostics["prior_weight"] in ONE_LAMP_PRIOR_WEIGHTS
    for given in (None, grating):
        other = estimate_known_grating([led], grating=given, basis=basis, mapping=mapping)
        assert other.diagnostics["prior_weight"] == 1.0


def test_without_a_grating_a_flat_one_is_assumed_and_recorded(basis):
    """The no-direct, no-file path (``estimate_with_known_grating(…, None)`` before)."""
    rng, mapping, _, _ = _scene(5)
    led = _lamp("LED-B3", "led", mapping, None, rng)
    result = estimate_known_grating([led], grating=None, basis=basis, mapping=mapping, options=FLAT)
    assert result.diagnostics["grating"] == "flat (assumed)"
    assert result.grating_efficiency is not None
    assert np.all(result.grating_efficiency == 1.0) and result.grating_efficiency_sigma is None
    # A flat grating indeed: the camera comes back.
    assert relative_error(result.sensitivity, TRUTH) < 0.04


@pytest.mark.parametrize("grating", [SinusoidalPhaseGrating(0.6), BlazedGrating(620.0)])
def test_without_a_grating_the_physical_families_stand_in_for_eta_and_beat_a_flat_one(
    basis, grating
):
    """No direct measurement, no file (decision 0074): η₁ marginalised over the physical
    families, weighed by the camera prior, its spread in σ — not a flat η, which leaves the
    sheet's shape in the camera."""
    rng, mapping, _, _ = _scene(5)

    def efficiency(wavelength):
        return grating.efficiency(1, wavelength)

    halogen = _lamp("A", "halogen", mapping, efficiency, rng)
    flat = estimate_known_grating(
        [halogen], grating=None, basis=basis, mapping=mapping, options=FLAT
    )
    result = estimate_known_grating(
        [halogen], grating=None, basis=basis, mapping=mapping, options=PHYSICAL
    )
    record = result.diagnostics["grating"]
    assert is_assumed_physical(record) and record["weighted_by_camera_prior"]
    assert efficiency_family(result) == "assumed"  # its own σ-budget factor key
    assert result.grating_efficiency_sigma is not None
    assumed_error = relative_error(result.sensitivity, TRUTH)
    assert assumed_error < 0.5 * relative_error(flat.sensitivity, TRUTH)
    assert band_coverage(result, TRUTH) >= 0.8
    # auto says what it assumed: the physical families, not a flat grating.
    quick = estimate(
        [halogen],
        basis=basis,
        mapping=mapping,
        assume_flat_grating=True,
        budget=None,
        options=PHYSICAL,
    )
    codes = {flag.code for flag in quick.quality.flags}
    assert "grating_assumed" in codes and "flat_grating_assumed" not in codes
    # By default (decision 0074, amended) auto assumes a flat grating, and says so.
    default = estimate([halogen], basis=basis, mapping=mapping, assume_flat_grating=True)
    default_codes = {flag.code for flag in default.quality.flags}
    assert "flat_grating_assumed" in default_codes and np.all(default.grating_efficiency == 1.0)
    # … with its band's factor judged on the protocol's variant of this set-up (decision 0075).
    assert efficiency_family(default) == "flat" and "uncertainty_unvalidated" not in default_codes
    assert default.quality.uncertainty["coverage_scale"] == COVERAGE_SCALE["known-grating:flat"]
    # Likewise with a fluorescent lamp nobody measured, for the mapping only (the D7000 pair).
    tube = replace(
        _lamp("FL2", "fluorescent", mapping, efficiency, rng), metadata={"spectrum_known": False}
    )
    paired = estimate(
        [tube, halogen],
        basis=basis,
        mapping=mapping,
        assume_flat_grating=True,
        budget=None,
        options=PHYSICAL,
    )
    assert paired.diagnostics["method_choice"]["mapping_only"] == ["FL2"]
    assert "grating_assumed" in {flag.code for flag in paired.quality.flags}


def test_the_camera_prior_weighs_the_assumed_shapes() -> None:
    """A candidate the evidence singles out is the mean, with no spread left; without evidence the
    families' whole spread stays in the covariance."""
    wavelength = DEFAULT_GRID.wavelength_nm
    stack, weight, labels = assumed_candidates(wavelength)
    assert weight.sum() == pytest.approx(1.0) and len(labels) == stack.shape[0]
    evidence = np.full(stack.shape[0], -1e6)
    evidence[7] = 0.0
    singled = assumed_efficiency(wavelength, log_evidence=evidence)
    np.testing.assert_allclose(singled.inverse, stack[7], rtol=1e-9)
    assert np.max(np.abs(singled.inverse_covariance)) < 1e-12
    assert singled.record["effective_candidates"] == pytest.approx(1.0)
    spread = assumed_efficiency(wavelength, ("sinusoidal", "blazed"))
    assert np.all(spread.efficiency_sigma > 0) and spread.record["effective_candidates"] > 40
    # The evidence prefers the shape the response was made through.
    prior_mean = np.stack([TRUTH[:, c] for c in range(3)], axis=1)
    prior_covariance = np.stack([np.eye(wavelength.size) * 1e-4] * 3)
    response = prior_mean / stack[20][:, None]
    log_evidence = candidate_log_evidence(
        response,
        np.stack([np.eye(wavelength.size) * 1e-6] * 3),
        prior_mean,
        prior_covariance,
        stack,
    )
    assert int(np.argmax(log_evidence)) == 20


def test_the_assumed_population_is_chosen_by_family_the_flat_one_a_family_of_one() -> None:
    """Decision 0088: the population ``"physical"`` marginalises over is named by family (each
    family equal weight, uniform inside it); ``"flat"`` is one candidate, η = 1."""
    wavelength = DEFAULT_GRID.wavelength_nm
    both, both_weight, _ = assumed_candidates(wavelength, ("sinusoidal", "blazed"))
    stack, weight, labels = assumed_candidates(wavelength)  # the default adds the flat one
    assert stack.shape[0] == both.shape[0] + 1 and labels[-1] == ("flat", 0.0)
    np.testing.assert_array_equal(stack[-1], np.ones(wavelength.size))
    np.testing.assert_allclose(stack[:-1], both)  # the families' shapes as before
    np.testing.assert_allclose(weight[-1], 1 / 3)
    np.testing.assert_allclose(weight[:-1], both_weight * 2 / 3)
    sinusoidal = assumed_candidates(wavelength, ("sinusoidal",))[2]
    assert {kind for kind, _ in sinusoidal} == {"sinusoidal"}
    flat = assumed_efficiency(wavelength, ("flat",))
    np.testing.assert_allclose(flat.inverse, 1.0)
    assert np.max(np.abs(flat.inverse_covariance)) == 0.0
    assert flat.record["most_likely"] == {"model": "flat"} and flat.record["ranges"] == {}
    assert check_assumed_families(("flat", "sinusoidal")) == ("sinusoidal", "flat")
    for wrong in [(), ("prism",), ("blazed", "blazed")]:
        with pytest.raises(InputError, match="assumed families"):
            KnownGratingOptions(assumed_families=wrong)  # type: ignore[arg-type]


def test_the_assumed_families_reach_the_solve(basis):
    """``assumed_families`` is the population the solve marginalises over and records."""
    rng, mapping, _, _ = _scene(5)
    grating = SinusoidalPhaseGrating(0.6)

    def efficiency(wavelength):
        return grating.efficiency(1, wavelength)

    halogen = _lamp("A", "halogen", mapping, efficiency, rng)
    only = KnownGratingOptions(assumed_grating="physical", assumed_families=("blazed",))
    result = estimate_known_grating(
        [halogen], grating=None, basis=basis, mapping=mapping, options=only
    )
    record = result.diagnostics["grating"]
    assert record["families"] == ["blazed"]
    assert record["family_weights"] == {"blazed": pytest.approx(1.0)}
    assert record["most_likely"]["model"] == "blazed"


def test_the_mapping_is_found_from_the_lamps_when_not_given(basis):
    """No mapping given: the lamps' fluorescent lines and profiles find it, as the joint solves do."""
    rng, mapping, efficiency, grating = _scene(6)
    led = _lamp("LED-B3", "led", mapping, efficiency, rng)
    tube = _lamp("FL2", "fluorescent", mapping, efficiency, rng)
    result = estimate_known_grating([led, tube], grating=grating, basis=basis)
    assert result.mapping is not None
    pixels = led.pixel
    true_nm = mapping.wavelength_nm(pixels)
    inside = (true_nm >= 400) & (true_nm <= 700)
    found_nm = result.mapping.wavelength_nm(pixels[inside])
    assert mapping_relative_error(found_nm, true_nm[inside]) < 2e-3
    assert result.diagnostics["solve_lamps"] == ["LED-B3", "FL2"]
    assert relative_error(result.sensitivity, TRUTH) < 0.04


def test_a_grating_that_does_not_cover_the_grid_is_named(basis):
    rng, mapping, efficiency, grating = _scene()
    led = _lamp("LED-B3", "led", mapping, efficiency, rng)
    short = GratingEfficiency(
        grating.wavelength_nm[:100], grating.efficiency[:100], source="short.json"
    )
    with pytest.raises(InputError, match=r"short.json: the grating efficiency covers 380–578 nm"):
        estimate_known_grating([led], grating=short, basis=basis, mapping=mapping)


def test_the_prior_shrinkage_reaches_the_solve(basis):
    rng, mapping, efficiency, grating = _scene()
    led = _lamp("LED-B3", "led", mapping, efficiency, rng, noise=0.03)
    default = estimate_known_grating([led], grating=grating, basis=basis, mapping=mapping)
    shrunk = estimate_known_grating(
        [led],
        grating=grating,
        basis=basis,
        mapping=mapping,
        options=KnownGratingOptions(prior_shrinkage=0.9),
    )
    assert shrunk.diagnostics["prior_shrinkage"] == [0.9, 0.9, 0.9]
    assert default.diagnostics["prior_shrinkage"] != [0.9, 0.9, 0.9]
    assert not np.allclose(shrunk.sensitivity, default.sensitivity)


def test_the_pipeline_keeps_the_multilamp_options_it_can_use_through_a_grating_file(
    basis, tmp_path: Path
):
    """``--method multilamp --grating FILE``: the solve is the known-grating one; before, the
    multi-lamp options' ``prior_shrinkage`` was dropped on the way (typer → dict → ``**options``)."""
    rng, mapping, efficiency, grating = _scene()
    led = _lamp("LED-B3", "led", mapping, efficiency, rng, noise=0.03)
    assert led.profile_sigma is not None
    profile = tmp_path / "led.csv"
    np.savetxt(
        profile,
        np.column_stack([led.pixel, led.profile, led.profile_sigma]),
        delimiter=",",
        header="pixel,r,g,b,r_sigma,g_sigma,b_sigma",
        comments="",
    )
    lamps = [LampProfile("LED-B3", "led", led.spectrum, profile)]
    options = MultilampOptions(prior_shrinkage=0.9, weight_rule="typicality")
    settings = OfflineSettings(
        method="multilamp", method_options=options, basis=basis, grating=grating
    )
    outcome = estimate_offline(lamps, settings)
    assert outcome.result.method == "known-grating"
    assert outcome.result.diagnostics["prior_shrinkage"] == [0.9, 0.9, 0.9]
    assert any("--weight-rule has no effect with a grating file" in w for w in outcome.warnings)
    direct = estimate_known_grating(
        [outcome.observations[0]],
        grating=grating,
        basis=basis,
        mapping=outcome.result.mapping,
        options=KnownGratingOptions(prior_shrinkage=0.9),
    )
    np.testing.assert_allclose(outcome.result.sensitivity, direct.sensitivity, atol=1e-12)


def test_a_first_order_opposite_to_the_grating_files_is_flagged(basis):
    """A grating file measured on an order running at 3° on the sensor, a capture whose order runs
    at 183°: the camera was turned round or this is the other first order (read where the
    stronger one leaves the frame, decision 0196), whose efficiency a blazed grating makes
    different. The result says so; an order in the file's direction says nothing."""
    from calib.core.mapping import TiltedGrating
    from calib.wavelength import RigGeometry
    from calib.wavelength.rig_prior import RigOptics

    _, mapping, efficiency, grating = _scene()
    rig = RigGeometry(TiltedGrating(0.5, 3000.0), RigOptics(order_angle_deg=3.0)).to_dict()
    grating = replace(grating, geometry={"rig": rig})

    def led_at(angle_deg: float) -> LampObservation:
        order = {"side": 1, "angle_deg": angle_deg, "start_px": 400.0, "stop_px": 900.0}
        geometry = {"sensor_shape_px": (1000, 3000), "spot_centre_px": (1500.0, 500.0)}
        led = _lamp("LED-B3", "led", mapping, efficiency, np.random.default_rng(3))
        return replace(led, metadata={"geometry": {**geometry, "orders": [order]}})

    flags = {
        angle: {
            flag.code: flag.message
            for flag in estimate(
                [led_at(angle)], "known-grating", basis=basis, mapping=mapping, grating=grating
            ).quality.flags
        }
        for angle in (3.5, 183.0)
    }
    assert "grating_other_order" not in flags[3.5]
    message = flags[183.0]["grating_other_order"]
    assert "183°" in message and "turned round" in message
