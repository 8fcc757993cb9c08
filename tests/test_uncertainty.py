"""calib.methods.uncertainty: the σ budget, the quality flags it raises, and auto's choices."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from calib.core.arrays import FloatArray
from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.lamp_specs import colour_lamp, lamp_from_spec
from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult, Quality, QualityFlag
from calib.core.spectra import MultiSpectrum, Spectrum, WavelengthGrid
from calib.core.spectrometer_tolerance import IN_SPEC_TOLERANCE_SIGMA
from calib.evaluation.validation.budget import (
    EstimateRecord,
    component_shares,
    coverage_at,
    fit_scale,
    load_records,
    ratios_by_method,
    save_records,
    without_components,
)
from calib.methods import choose_method, estimate
from calib.methods.uncertainty import (
    COMPONENTS,
    DEFAULT_BUDGET,
    NORMALISATION_SHARE,
    PROFILE_ROWS_KEY,
    TOLERANCE_SIGMA,
    BudgetSettings,
    basis_misfit_sigma,
    basis_sigma,
    basis_support_nm,
    check_grid_within_basis,
    data_open_share,
    efficiency_family,
    floored_reduced_chi2,
    lamp_spread_sigma,
    misfit_flag,
    normalisation_sigma,
    prior_sigma_at_scale,
    reduced_chi2,
    uncertainty_budget,
    with_stray_light,
)
from calib.model.bases import CameraBasis, camera_basis, fallback_camera_basis
from calib.model.forward import render_observation

TRUTH = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))


@pytest.fixture(scope="module")
def camera() -> MultiSpectrum:
    return find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity


@pytest.fixture(scope="module")
def basis() -> CameraBasis:
    return fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])


def _lamp(spec: str, camera: MultiSpectrum, bandwidth_nm: float | None = 4.0) -> LampObservation:
    observation = render_observation(lamp_from_spec(spec), camera, mapping=TRUTH, pixel=800)
    return replace(observation.observation, spectrum_bandwidth_nm=bandwidth_nm)


def test_the_budget_names_its_components_and_states_their_sum(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    lamps = [_lamp("LED-B3", camera)]
    own = estimate(lamps, "prior", basis=basis, mapping=TRUTH, budget=None)
    factor = 1.7
    result = estimate(
        lamps,
        "prior",
        basis=basis,
        mapping=TRUTH,
        budget=BudgetSettings(coverage_scale={"prior": factor}),
    )
    summary = result.quality.uncertainty
    # every component evaluated for the prior solve; lamp spread and stray light are multilamp's
    # (decision 0109)
    assert set(summary["rms"]) == set(COMPONENTS) - {"lamp spread", "stray light"}
    assert summary["coverage_scale"] == factor
    assert sum(summary["share_of_variance"].values()) == pytest.approx(1.0)
    assert summary["share_of_variance"]["unexplained"] == pytest.approx(1 - 1 / factor**2)
    assert own.sensitivity_sigma is not None and result.sensitivity_sigma is not None
    np.testing.assert_allclose(result.diagnostics["method_sigma"], own.sensitivity_sigma)
    # the band holds the method's own σ (inflated by χ² where > 1) and more
    assert np.all(result.sensitivity_sigma >= own.sensitivity_sigma * (1 - 1e-9))
    np.testing.assert_allclose(result.sensitivity, own.sensitivity)
    assert result.to_dict()["quality"]["uncertainty"]["total_rms"] > 0


def test_a_budget_without_perturbations_keeps_the_analytic_components(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    result = estimate(
        [_lamp("LED-B3", camera)],
        "prior",
        basis=basis,
        mapping=TRUTH,
        budget=BudgetSettings(perturb=False, coverage_scale={}),
    )
    assert set(result.quality.uncertainty["rms"]) == {
        "statistical",
        "basis",
        "mapping",
        "normalisation",
    }


def test_the_spectrometer_perturbation_moves_with_the_stated_scale(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    lamps = [_lamp("LED-B3", camera)]
    result = estimate(lamps, "prior", basis=basis, mapping=TRUTH, budget=None)

    def rerun(observations: list[LampObservation], **changes: Any) -> EstimateResult:
        return estimate(observations, "prior", basis=basis, mapping=TRUTH, budget=None, **changes)

    small, large = (
        uncertainty_budget(
            result, lamps, rerun=rerun, settings=BudgetSettings(wavelength_scale_nm=shift)
        ).components["spectrometer scale"]
        for shift in (0.2, 2.0)
    )
    assert np.sqrt(np.mean(large**2)) > 3 * np.sqrt(np.mean(small**2)) > 0


def test_a_stated_tolerance_is_a_bound_not_one_sigma(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Decision 0038: an instrument in spec is anywhere within ±tolerance (σ = tolerance/√3);
    a bandwidth assumed because none was given keeps the whole perturbation."""
    stated = [_lamp("LED-B3", camera)]
    unstated = [_lamp("LED-B3", camera, None)]

    def components(lamps: list[LampObservation], tolerance_sigma: float) -> dict[str, Any]:
        result = estimate(lamps, "prior", basis=basis, mapping=TRUTH, budget=None)

        def rerun(observations: list[LampObservation], **changes: Any) -> EstimateResult:
            return estimate(
                observations, "prior", basis=basis, mapping=TRUTH, budget=None, **changes
            )

        settings = BudgetSettings(tolerance_sigma=tolerance_sigma)
        return dict(uncertainty_budget(result, lamps, rerun=rerun, settings=settings).components)

    # decision 0044: the bound is the default
    assert TOLERANCE_SIGMA == IN_SPEC_TOLERANCE_SIGMA
    assert math.isclose(IN_SPEC_TOLERANCE_SIGMA * math.sqrt(3), 1.0)
    bound, in_spec = components(stated, 1.0), components(stated, IN_SPEC_TOLERANCE_SIGMA)
    for name in ("spectrometer scale", "spectrometer bandwidth"):
        assert np.sqrt(np.mean(bound[name] ** 2)) > 0
        np.testing.assert_allclose(in_spec[name], IN_SPEC_TOLERANCE_SIGMA * bound[name], rtol=1e-9)
    assumed = components(unstated, IN_SPEC_TOLERANCE_SIGMA)["spectrometer bandwidth"]
    np.testing.assert_allclose(assumed, components(unstated, 1.0)["spectrometer bandwidth"])


def test_a_missing_bandwidth_is_flagged_and_assumed(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    given = estimate([_lamp("LED-B3", camera)], "prior", basis=basis, mapping=TRUTH)
    missing = estimate([_lamp("LED-B3", camera, None)], "prior", basis=basis, mapping=TRUTH)
    assert "no_spectrometer_bandwidth" not in {f.code for f in given.quality.flags}
    flag = next(f for f in missing.quality.flags if f.code == "no_spectrometer_bandwidth")
    assert "LED-B3" in flag.message and "--bandwidth" in flag.message
    assert missing.quality.verdict != "ok"


def test_the_fallback_basis_is_flagged(camera: MultiSpectrum, basis: CameraBasis) -> None:
    result = estimate([_lamp("LED-B3", camera)], "prior", basis=basis, mapping=TRUTH)
    assert "fallback_basis" in {flag.code for flag in result.quality.flags}


def test_reduced_chi2_inflates_and_warns() -> None:
    result = EstimateResult(
        "prior",
        np.array([400.0, 500.0, 600.0]),
        np.array([[0, 0.2, 1], [0.1, 1, 0.2], [1, 0.1, 0]]),
        sensitivity_sigma=np.full((3, 3), 0.01),
        diagnostics={"reduced_chi2": 25.0},
    )
    budget = uncertainty_budget(result, [])
    np.testing.assert_allclose(budget.components["statistical"], 0.05)
    assert budget.reduced_chi2 == 25.0
    assert [flag.code for flag in budget.flags] == ["model_misfit"]
    assert misfit_flag(2.0) is None
    assert misfit_flag(500.0).severity == "serious"  # type: ignore[union-attr]
    multilamp = replace(result, diagnostics={"direct_chi2": 30.0, "direct_equations": 15})
    assert reduced_chi2(multilamp) == 2.0


def test_a_physical_fits_chi2_is_not_counted_twice() -> None:
    """Decision 0050: a physical η fit inflates its covariance by the direct equations' χ²/dof
    (:func:`calib.methods.grating_models.fit_physical`); the budget does not inflate the method's σ
    by that χ² again, but still judges and flags it. The Fourier model's posterior is not
    inflated by it, so the budget does."""
    direct = {"direct_chi2": 150.0, "direct_equations": 6}
    result = EstimateResult(
        "multilamp",
        np.array([400.0, 500.0, 600.0]),
        np.array([[0, 0.2, 1], [0.1, 1, 0.2], [1, 0.1, 0]]),
        sensitivity_sigma=np.full((3, 3), 0.01),
        diagnostics={**direct, "efficiency_model": "sinusoidal"},
    )
    physical = uncertainty_budget(result, [])
    np.testing.assert_allclose(physical.components["statistical"], 0.01)
    assert physical.reduced_chi2 == 25.0
    assert [flag.code for flag in physical.flags] == ["model_misfit"]
    assert any("not inflated again" in note for note in physical.notes)
    fourier = replace(result, diagnostics={**direct, "efficiency_model": "fourier-7"})
    np.testing.assert_allclose(uncertainty_budget(fourier, []).components["statistical"], 0.05)


def test_misfit_is_judged_above_the_lamp_spectrums_precision() -> None:
    """A profile far sharper than its lamp spectrum is known (photon noise 0.03 % of the signal,
    residuals 0.8 % of it) is neither called a misfit nor inflated 30×; residuals of 20 % are."""
    rng = np.random.default_rng(5)
    profile = np.outer(np.hanning(200) + 0.05, [0.5, 1.0, 0.3]) * 1e4
    lamp = LampObservation("led", Spectrum([380.0, 780.0], [1.0, 1.0]), np.arange(200.0), profile)
    sigma = 3e-4 * profile
    for relative, flagged in ((0.008, False), (0.2, True)):
        difference = relative * profile * rng.choice([-1.0, 1.0], size=profile.shape)
        result = EstimateResult(
            "prior",
            np.array([400.0, 550.0, 700.0]),
            np.array([[0, 0.2, 1], [0.1, 1, 0.2], [1, 0.1, 0]]),
            sensitivity_sigma=np.full((3, 3), 0.01),
            residuals={"led": {"profile": difference, "profile_normalised": difference / sigma}},
            diagnostics={"reduced_chi2": float(np.mean((difference / sigma) ** 2))},
        )
        budget = uncertainty_budget(result, [lamp])
        assert budget.noise_only_reduced_chi2 == pytest.approx((relative / 3e-4) ** 2)
        expected = relative**2 / (3e-4**2 + BudgetSettings().model_floor ** 2)
        assert budget.reduced_chi2 == pytest.approx(expected)
        assert floored_reduced_chi2(result, [lamp], 0.0) == budget.noise_only_reduced_chi2
        assert ([flag.code for flag in budget.flags] == ["model_misfit"]) is flagged
        inflation = float(budget.components["statistical"][0, 0] / 0.01)
        assert inflation == pytest.approx(max(1.0, math.sqrt(expected)))


def test_a_grid_beyond_the_basis_is_refused_with_the_range() -> None:
    grid = WavelengthGrid(390, 720, 10)
    rng = np.random.default_rng(0)
    curves = rng.uniform(0.1, 1.0, size=(12, grid.size, 3))
    curves[:, grid.wavelength_nm < 400] = 0.0
    curves[:, grid.wavelength_nm > 700] = 0.0
    basis = camera_basis(curves, grid=grid, n_vectors=3, cache=False)
    assert basis_support_nm(basis) == (400.0, 700.0)
    with pytest.raises(InputError, match=r"beyond the camera data.*400–700 nm.*--grid 400:700:10"):
        check_grid_within_basis(basis)
    lamp = LampObservation(
        "LED",
        Spectrum([380, 740], [1.0, 1.0]),
        np.arange(10.0),
        np.ones((10, 3)),
        direct_rgb=np.ones(3),
    )
    with pytest.raises(InputError, match="beyond the camera data"):
        estimate([lamp], "prior", grid=grid, basis=basis, mapping=TRUTH)


def test_quality_keeps_one_flag_per_code_and_grades() -> None:
    quality = Quality().with_flags(QualityFlag("a", "first", "info"))
    assert quality.verdict == "ok" and quality.warnings() == []
    quality = quality.with_flags(QualityFlag("a", "second"), QualityFlag("b", "bad", "serious"))
    assert [flag.message for flag in quality.flags] == ["second", "bad"]
    assert quality.verdict == "doubtful"
    assert quality.to_dict()["flags"][1] == {"code": "b", "severity": "serious", "message": "bad"}


def test_auto_keeps_a_coarse_fluorescent_lamp_for_the_mapping(camera: MultiSpectrum) -> None:
    led = _lamp("LED-B3", camera)
    fluorescent = render_observation(colour_lamp("FL2"), camera, mapping=TRUTH, pixel=800)
    fl = replace(fluorescent.observation, kind="fluorescent")
    fine = replace(fl, spectrum=fl.spectrum.resample(WavelengthGrid(380, 780, 1)))
    assert choose_method([led, fine]).mapping_only == ()
    coarse = replace(fl, spectrum=fl.spectrum.resample(WavelengthGrid(380, 780, 10)))
    choice = choose_method([led, coarse])
    assert choice.method == "prior" and choice.mapping_only == ("FL2",)
    assert "too coarse" in choice.reason and "mapping only" in choice.reason
    unknown = replace(fine, metadata={"spectrum_known": False})
    assert choose_method([led, unknown]).mapping_only == ("FL2",)
    # the lamps alone cannot be all mapping-only
    assert choose_method([coarse]).mapping_only == ()
    # a slit-limited spectrum, well sampled (a 25 nm slit every 10 nm), enters the solve; a slit
    # narrower than two samples does not
    slit = replace(coarse, spectrum_bandwidth_nm=25.0)
    assert choose_method([led, slit]).mapping_only == ()
    narrow = replace(coarse, spectrum_bandwidth_nm=12.0)
    assert choose_method([led, narrow]).mapping_only == ("FL2",)


def test_auto_uses_a_grating_file_when_given(camera: MultiSpectrum) -> None:
    led = _lamp("LED-B3", camera)
    grating = GratingEfficiency(
        np.array([380.0, 780.0]), np.array([1.0, 1.0]), source="grating.json"
    )
    choice = choose_method([led], grating=grating)
    assert choice.method == "known-grating" and "grating.json" in choice.reason
    assert choose_method([led]).method == "prior"


def test_auto_through_a_mapping_only_lamp_records_it(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    led = _lamp("LED-B3", camera)
    fluorescent = render_observation(colour_lamp("FL2"), camera, mapping=TRUTH, pixel=800)
    coarse = replace(
        fluorescent.observation,
        kind="fluorescent",
        spectrum=fluorescent.observation.spectrum.resample(WavelengthGrid(380, 780, 10)),
    )
    result = estimate([led, coarse], basis=basis, mapping=TRUTH)
    choice = result.diagnostics["method_choice"]
    assert choice["mapping_only"] == ["FL2"]
    assert result.diagnostics["solve_lamps"] == ["LED-B3"]


def test_the_coverage_factor_reaches_its_target() -> None:
    rng = np.random.default_rng(1)
    ratios = [np.abs(rng.standard_normal(200)) * scale for scale in (0.5, 2.0, 4.0)]
    factor = fit_scale(ratios, 0.9)
    assert coverage_at(ratios, factor) >= 0.9 > coverage_at(ratios, factor * 0.97)
    assert fit_scale([np.full(10, 0.1)], 0.95) == 1.0  # never shrinks a band


def test_a_mapping_placed_by_the_spectra_carries_their_scale_once(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Decision 0044: when the mapping was placed by the measured spectra (its σ holds their
    scale), a scale error moves mapping and spectra together; the budget's mapping component
    states it and no fixed-mapping re-solve counts it again."""
    lamps = [_lamp("LED-B3", camera)]
    carried = TRUTH.with_details(
        wavelength_rms_nm=0.3, details={"spectrometer_scale_sigma_nm": 0.29}
    )

    def budget(mapping: QuadraticMapping) -> Any:
        result = estimate(lamps, "prior", basis=basis, mapping=mapping, budget=None)

        def rerun(observations: list[LampObservation], **changes: Any) -> EstimateResult:
            return estimate(
                observations, "prior", basis=basis, mapping=mapping, budget=None, **changes
            )

        return uncertainty_budget(result, lamps, rerun=rerun, settings=BudgetSettings())

    separate, once = budget(TRUTH), budget(carried)
    assert "spectrometer scale" in separate.components
    assert "spectrometer scale" not in once.components
    assert any("in the mapping's σ" in note for note in once.notes)
    assert np.sqrt(np.mean(once.components["mapping"] ** 2)) > 0
    np.testing.assert_allclose(
        once.components["spectrometer bandwidth"], separate.components["spectrometer bandwidth"]
    )


def test_a_method_never_validated_says_so(camera: MultiSpectrum, basis: CameraBasis) -> None:
    lamps = [_lamp("LED-B3", camera)]

    def codes(table: dict[str, float]) -> set[str]:
        settings = BudgetSettings(perturb=False, coverage_scale=table)
        result = estimate(lamps, "prior", basis=basis, mapping=TRUTH, budget=settings)
        return {flag.code for flag in result.quality.flags}

    assert "uncertainty_unvalidated" in codes({"multilamp": 1.0, "makabe2025": 3.0})
    assert "uncertainty_unvalidated" not in codes({"prior": 1.5})
    assert "uncertainty_unvalidated" not in codes({})  # the validation run itself


def test_a_given_grating_without_sigma_is_flagged() -> None:
    def codes(grating: object, sigma: list[float] | None, model: str | None = None) -> set[str]:
        result = EstimateResult(
            "known-grating",
            np.array([400.0, 500.0, 600.0]),
            np.array([[0, 0.2, 1], [0.1, 1, 0.2], [1, 0.1, 0]]),
            grating_efficiency=np.array([0.5, 1.0, 0.8]),
            grating_efficiency_sigma=None if sigma is None else np.array(sigma),
            diagnostics={"grating": grating, **({"efficiency_model": model} if model else {})},
        )
        budget = uncertainty_budget(result, [], settings=BudgetSettings(perturb=False))
        return {flag.code for flag in budget.flags}

    assert "grating_sigma_missing" in codes({"source": "maker's curve"}, None)
    assert "grating_sigma_missing" not in codes({"source": "measured"}, [0.01, 0.01, 0.01])
    # What was assumed is read from the η family the solve records (known_grating's keys).
    assert "flat_grating_assumed" in codes("flat (assumed)", None, "flat")
    assumed = codes({"source": "assumed"}, [0.01, 0.01, 0.01], "assumed")
    assert "grating_assumed" in assumed and "flat_grating_assumed" not in assumed
    assert not {"grating_sigma_missing", "flat_grating_assumed", "grating_assumed"} & codes(
        None, None
    )


def test_validation_records_judge_any_tolerance_sigma() -> None:
    """One validation run judges both readings of a tolerance: the spectrometer components scale
    with it, an assumed bandwidth (no tolerance) does not."""
    error = np.array([0.0, 0.3, 0.4, 1.0])
    components = {
        "basis": np.array([0.1, 0.1, 0.3, 0.0]),
        "spectrometer scale": np.array([0.0, 0.4, 0.4, 1.0]),
        "spectrometer bandwidth": np.array([0.0, 0.0, 0.0, 1.0]),
    }
    stated = EstimateRecord("prior", "LED+FL", error, components)
    assumed = EstimateRecord("prior", "LED+FL", error, components, assumed_bandwidth=True)
    np.testing.assert_allclose(stated.named(1.0) ** 2, [0.01, 0.17, 0.25, 2.0])
    np.testing.assert_allclose(stated.named(0.5) ** 2, [0.01, 0.05, 0.13, 0.5])
    np.testing.assert_allclose(assumed.named(0.5) ** 2, [0.01, 0.05, 0.13, 1.25])
    assert stated.ratio(1.0)[0] == 0.0  # no error, σ > 0
    ratios = ratios_by_method([stated, assumed], 0.5)
    assert list(ratios) == ["prior"] and len(ratios["prior"]) == 2
    shares = component_shares([stated], 1.0)
    assert sum(v for k, v in shares.items() if k != "sigma/error (median)") == pytest.approx(1.0)


def test_saved_validation_records_judge_offline_as_the_run_does(tmp_path: Any) -> None:
    """``budget --save`` keeps what a record's named σ depends on (decision 0078): a record whose
    spectra's scale was checked keeps its scale component whatever the tolerance σ, and one with
    an assumed bandwidth its bandwidth component; read back, every record judges as before."""
    error = np.array([0.0, 0.3, 0.4, 1.0])
    components = {
        "basis": np.array([0.1, 0.1, 0.3, 0.0]),
        "spectrometer scale": np.array([0.0, 0.4, 0.4, 1.0]),
        "spectrometer bandwidth": np.array([0.0, 0.0, 0.0, 1.0]),
    }
    records = [
        EstimateRecord("prior", "LED+FL", error, components, family="physical"),
        EstimateRecord(
            "multilamp",
            "3 lamps + RGB LEDs",
            error,
            components,
            assumed_bandwidth=True,
            scale_checked=True,
            outside_basis=np.full(4, 0.2),
            prior_sigma=np.full(4, 0.5),
        ),
    ]
    path = str(tmp_path / "records.npz")
    save_records(records, path)
    loaded = load_records(path)
    assert [(r.key, r.variant, r.assumed_bandwidth, r.scale_checked) for r in loaded] == [
        ("prior:physical", "LED+FL", False, False),
        ("multilamp", "3 lamps + RGB LEDs", True, True),
    ]
    for before, after in zip(records, loaded, strict=True):
        np.testing.assert_allclose(
            after.ratio(IN_SPEC_TOLERANCE_SIGMA), before.ratio(IN_SPEC_TOLERANCE_SIGMA)
        )
    assert loaded[1].outside_basis is not None
    np.testing.assert_allclose(loaded[1].outside_basis, 0.2)
    assert loaded[0].outside_basis is None


def test_a_measured_slits_bandwidth_component_is_not_a_tolerance(
    tmp_path: Any, capsys: Any
) -> None:
    """Decision 0099: where the scale check measured the slit, the record's bandwidth component is
    that slit's one σ and does not scale with the tolerance σ; the flag survives ``--save``, and
    ``--load`` judges saved sets together, each set's coverage printed."""
    from calib.evaluation.validation.budget import main

    error = np.array([0.0, 0.3, 0.4, 1.0])
    components = {
        "basis": np.array([0.1, 0.1, 0.3, 0.0]),
        "spectrometer bandwidth": np.array([0.0, 0.0, 0.0, 1.0]),
    }
    tolerance = EstimateRecord("prior", "LED+FL", error, components)
    measured = EstimateRecord("prior", "LED+FL", error, components, slit_measured=True)
    np.testing.assert_allclose(tolerance.named(0.5) ** 2, [0.01, 0.01, 0.09, 0.25])
    np.testing.assert_allclose(measured.named(0.5) ** 2, [0.01, 0.01, 0.09, 1.0])
    paths = [str(tmp_path / "a.npz"), str(tmp_path / "b.npz")]
    save_records([tolerance], paths[0])
    save_records([measured], paths[1])
    assert [r.slit_measured for p in paths for r in load_records(p)] == [False, True]
    assert main(["--load", paths[0], "--load", paths[1], "--tolerance-sigma", "0.5"]) == 0
    printed = capsys.readouterr().out
    assert f"{paths[0]}: 1 estimates" in printed and f"{paths[1]}: 1 estimates" in printed


def test_the_factor_is_judged_per_eta_family() -> None:
    """Decision 0044: a physical η and a Fourier fallback leave different shares unexplained; the
    factor is looked up as ``method:family``, then ``method``, then the largest."""
    table = {"prior": 1.8, "prior:physical": 1.0, "prior:fourier": 2.8, "makabe2025": 4.5}
    settings = BudgetSettings(coverage_scale=table)
    assert settings.scale_for("prior", "physical") == 1.0
    assert settings.scale_for("prior", "fourier") == 2.8
    assert settings.scale_for("prior", None) == 1.8
    assert settings.scale_for("multilamp", "physical") == 4.5  # never validated: the largest
    assert settings.validated("prior", "physical") and not settings.validated("multilamp", None)

    def family(model: object) -> str | None:
        result = EstimateResult(
            "prior",
            np.array([400.0, 500.0]),
            np.ones((2, 3)),
            diagnostics={"efficiency_model": model},
        )
        return efficiency_family(result)

    assert [family(m) for m in ("sinusoidal", "blazed", "fourier", "inverse", None)] == [
        "physical",
        "physical",
        "fourier",
        "fourier",
        None,
    ]
    record = EstimateRecord("prior", "LED+FL", np.zeros(2), {}, family="physical")
    assert record.key == "prior:physical"
    assert set(ratios_by_method([record], 1.0)) == {"prior", "prior:physical"}


def test_unknown_channel_gains_take_the_populations_balance_with_its_spread(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Decision 0050: a profile from a white-balanced conversion (the Canon 10D's planes) has
    channel gains that are not the raw data's; the delivered balance is the basis mean's, the
    population's spread of it is in σ, and the result says so."""
    lamps = [_lamp("LED-B3", camera)]
    plain = estimate(lamps, "prior", basis=basis, mapping=TRUTH, budget=None)
    balanced_gains = [replace(lamps[0], metadata={"channel_gains": "unknown"})]
    skewed = [replace(balanced_gains[0], profile=balanced_gains[0].profile * [2.5, 1.0, 1.6])]
    result = estimate(skewed, "prior", basis=basis, mapping=TRUTH, budget=None)
    record = result.diagnostics["channel_balance"]
    areas = np.clip(result.sensitivity, 0.0, None).sum(axis=0)
    mean_areas = basis.mean.sum(axis=0)
    reference = "RGB".index(record["reference_channel"])
    np.testing.assert_allclose(areas / areas[reference], mean_areas / mean_areas[reference])
    assert record["relative_sigma"][reference] == 0.0
    assert all(value > 0.0 for i, value in enumerate(record["relative_sigma"]) if i != reference)
    assert result.sensitivity_sigma is not None and plain.sensitivity_sigma is not None
    assert np.all(result.sensitivity_sigma >= 0.0)
    assert "channel_gains_unknown" in {flag.code for flag in result.quality.flags}
    assert "channel_balance" not in plain.diagnostics


def test_the_basis_sigma_is_the_estimates_own_out_of_span_part(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Decision 0050: a curve off the basis span gets its own out-of-span part as the basis σ
    (so an out-of-basis camera widens its band); a curve its method holds to the span gets the
    population's."""
    curves = camera.resample(basis.grid, "interpolate").values
    curves = curves / curves.max()
    off_span = np.clip(curves + 0.1 * np.sin(basis.grid.wavelength_nm / 7.0)[:, None], 0, None)
    result = EstimateResult("prior", basis.grid.wavelength_nm, 2.0 * off_span)
    sigma, source = basis_sigma(result, basis)
    assert source == "estimate"
    scaled = off_span / off_span.max()
    np.testing.assert_allclose(sigma, np.abs(scaled - basis.project(scaled)))
    inside, source = basis_sigma(replace(result, sensitivity=basis.project(curves)), basis)
    assert source == "population"
    np.testing.assert_allclose(inside, basis_misfit_sigma(basis))


def test_the_prior_sigma_follows_the_estimates_scale(basis: CameraBasis) -> None:
    """``α √diag Σ_c`` with ``α`` the curves' least-squares scale against the basis mean."""
    spread = np.stack([np.sqrt(np.diag(basis.covariance[c])) for c in range(3)], axis=1)
    np.testing.assert_allclose(prior_sigma_at_scale(0.5 * basis.mean, basis), 0.5 * spread)


def test_the_basis_sigma_shrinks_where_the_data_pin_the_curve(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Decision 0060: with a shrink power the estimate's out-of-span part is multiplied by the
    share of the prior's spread the data leave open (σ_stat / σ_prior, at most 1): a curve pinned
    by its data (tiny σ) keeps almost none of it, one the data leave open keeps all of it; the
    multilamp method shrinks by default, the prior solve does not."""
    curves = camera.resample(basis.grid, "interpolate").values
    curves = curves / curves.max()
    off_span = np.clip(curves + 0.1 * np.sin(basis.grid.wavelength_nm / 7.0)[:, None], 0, None)
    result = EstimateResult("multilamp", basis.grid.wavelength_nm, off_span / off_span.max())
    whole, source = basis_sigma(result, basis)
    assert source == "estimate"
    prior = prior_sigma_at_scale(result.sensitivity, basis)
    pinned, source = basis_sigma(result, basis, 0.01 * prior, 1.0)
    assert source == "estimate, shrunk"
    np.testing.assert_allclose(pinned, 0.01 * whole, atol=1e-12)
    open_, _ = basis_sigma(result, basis, 3.0 * prior, 1.0)
    np.testing.assert_allclose(open_, whole)
    assert data_open_share(result, basis, 0.01 * prior) == pytest.approx(0.01)
    assert DEFAULT_BUDGET.shrink_power_for("multilamp") == 1.0
    assert DEFAULT_BUDGET.shrink_power_for("prior") == 0.0
    assert BudgetSettings(basis_shrink_power={}).shrink_power_for("multilamp") == 0.0


def test_the_multilamp_budget_shrinks_its_basis_component(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Through :func:`uncertainty_budget`: the multilamp result's basis component is the shrunk
    one by default and decision 0050's whole out-of-span part with ``basis_shrink_power={}``."""
    curves = camera.resample(basis.grid, "interpolate").values
    off_span = np.clip(curves + 0.1 * np.sin(basis.grid.wavelength_nm / 7.0)[:, None], 0, None)
    result = EstimateResult(
        "multilamp",
        basis.grid.wavelength_nm,
        off_span,
        sensitivity_sigma=np.full_like(off_span, 1e-4 * off_span.max()),
    )
    shrunk = uncertainty_budget(result, [], basis=basis)
    whole = uncertainty_budget(
        result, [], basis=basis, settings=BudgetSettings(basis_shrink_power={})
    )
    assert float(np.max(shrunk.components["basis"])) < 0.1 * float(
        np.max(whole.components["basis"])
    )
    assert any("leave open" in note for note in shrunk.notes)


def _pooled(values: FloatArray, method: str = "multilamp") -> EstimateResult:
    wavelength = np.linspace(400.0, 700.0, 4)
    curves = np.tile(values[:, None], (1, 3))
    return EstimateResult(
        method=method,
        wavelength_nm=wavelength,
        sensitivity=curves,
        sensitivity_sigma=np.full_like(curves, 1e-4),
        grating_efficiency=np.ones(4),
        grating_efficiency_sigma=np.full(4, 1e-4),
        mapping=TRUTH,
    )


def _named_lamps(count: int, direct: int) -> list[LampObservation]:
    spectrum = Spectrum([400.0, 700.0], [1.0, 1.0])
    return [
        LampObservation(
            f"lamp{i}",
            spectrum,
            np.arange(4.0),
            np.ones((4, 3)),
            direct_rgb=np.ones(3) if i < direct else None,
            spectrum_bandwidth_nm=2.0,
        )
        for i in range(count)
    ]


def _leave_one_out_rerun(offsets: dict[str, float], fail: str = "") -> Any:
    """Each lamp pulls the pooled curve by its offset (the curve's peak stays 1): without it, the
    others' mean pull."""

    def rerun(observations: list[LampObservation], **changes: Any) -> EstimateResult:
        names = {lamp.name for lamp in observations}
        missing = sorted(set(offsets) - names)
        if missing == [fail]:
            raise RuntimeError("too few lamps")
        pull = np.mean([offsets[name] for name in names if name in offsets])
        return _pooled(np.array([0.5 + pull, 1.0, 0.5, 0.2]))

    return rerun


def test_the_lamp_spread_is_the_lamps_leave_one_out_jackknife() -> None:
    """Decision 0109: the jackknife over the lamps with a direct measurement, the mapping-only lamp
    left in; a lamp whose re-solve fails is left out, fewer than three lamps give none."""
    offsets = {"lamp0": 0.0, "lamp1": 0.01, "lamp2": 0.05, "lamp3": -0.03}
    lamps = _named_lamps(5, 4)  # lamp4 has no direct measurement
    result = _pooled(np.array([0.5, 1.0, 0.5, 0.2]))
    spread = lamp_spread_sigma(result, lamps, _leave_one_out_rerun(offsets))
    assert spread is not None
    sigma, eta_sigma, note = spread
    pulls = np.array([np.mean([v for k, v in offsets.items() if k != left]) for left in offsets])
    expected = math.sqrt(3 / 4 * np.sum((pulls - pulls.mean()) ** 2))
    np.testing.assert_allclose(sigma[0], expected)
    np.testing.assert_allclose(sigma[1:], 0.0, atol=1e-12)
    assert eta_sigma is not None and np.allclose(eta_sigma, 0.0)
    assert "4 of 4 lamps" in note
    failed = lamp_spread_sigma(result, lamps, _leave_one_out_rerun(offsets, fail="lamp2"))
    assert failed is not None and "3 of 4" in failed[2]
    assert failed[0][0, 0] < sigma[0, 0]  # the lamp that disagrees most is the one left in
    assert lamp_spread_sigma(result, _named_lamps(3, 2), _leave_one_out_rerun(offsets)) is None


def test_the_multilamp_budget_names_its_lamps_spread() -> None:
    """The component enters multilamp's budget (and its η's), not another method's, and the
    setting turns it off."""
    offsets = {"lamp0": 0.0, "lamp1": 0.01, "lamp2": 0.05, "lamp3": -0.03}
    lamps = _named_lamps(4, 4)
    rerun = _leave_one_out_rerun(offsets)
    values = np.array([0.5, 1.0, 0.5, 0.2])
    settings = BudgetSettings(coverage_scale={})
    budget = uncertainty_budget(_pooled(values), lamps, rerun=rerun, settings=settings)
    assert budget.components["lamp spread"][0, 0] > 0.01
    assert "lamp spread" in budget.efficiency_components
    assert "lamp spread" in budget.summary()["rms"]
    other = uncertainty_budget(_pooled(values, "prior"), lamps, rerun=rerun, settings=settings)
    assert "lamp spread" not in other.components
    off = replace(settings, lamp_spread=False)
    assert (
        "lamp spread"
        not in uncertainty_budget(_pooled(values), lamps, rerun=rerun, settings=off).components
    )


def test_the_stray_light_perturbation_lies_on_the_band_about_the_spot() -> None:
    """Decision 0109: the direct signal's fraction in a Lorentzian wing, on pixels measured from
    the spot; lamps without a direct measurement are left as they are, and without a spot-measured
    lamp there is nothing to place it by."""
    lamps = [replace(lamp, pixel_origin="direct_spot") for lamp in _named_lamps(2, 1)]
    stray = with_stray_light(lamps, fraction=0.01, wing_px=2.0)
    assert stray is not None
    added = stray[0].profile - lamps[0].profile
    wing = (2.0 / math.pi) / (4.0 + np.arange(4.0) ** 2)
    np.testing.assert_allclose(added, 0.01 * wing[:, None] * np.ones(3)[None, :])
    np.testing.assert_array_equal(stray[1].profile, lamps[1].profile)
    assert with_stray_light(_named_lamps(2, 2)) is None  # arbitrary pixel origin


def test_the_stray_light_on_a_per_row_profile_is_the_spots_light_per_row() -> None:
    """Decision 0119: an image extraction's profile is the band's mean across its rows while its
    direct RGB is the whole spot's; each row of the slit scatters its own light, so the wing is the
    direct signal over the rows (the 2-D twins' band was otherwise widened by the rows, ×50–200)."""
    lamps = [replace(lamp, pixel_origin="direct_spot") for lamp in _named_lamps(2, 1)]
    per_row = [replace(lamp, metadata={PROFILE_ROWS_KEY: 40.0}) for lamp in lamps]
    column_total = with_stray_light(lamps, fraction=0.01, wing_px=2.0)
    mean_of_rows = with_stray_light(per_row, fraction=0.01, wing_px=2.0)
    assert column_total is not None and mean_of_rows is not None
    np.testing.assert_allclose(
        mean_of_rows[0].profile - lamps[0].profile,
        (column_total[0].profile - lamps[0].profile) / 40.0,
    )


def test_saved_records_are_judged_without_a_component() -> None:
    record = EstimateRecord(
        "multilamp",
        "5 lamps",
        np.full(3, 0.1),
        {"mapping": np.full(3, 0.1), "lamp spread": np.full(3, 0.1)},
    )
    (left,) = without_components([record], ["lamp spread"])
    assert set(left.components) == {"mapping"}
    np.testing.assert_allclose(left.named(), 0.1)
    np.testing.assert_allclose(record.named(), 0.1 * math.sqrt(2))


def test_the_mappings_share_of_eta_is_the_change_of_the_curve_stated_at_maximum_1() -> None:
    """Decision 0144: η is stated at its maximum 1, so a wavelength error under it moves the
    normalising node too. For a sinusoidal sheet (first order largest at 400 nm, the twins' own)
    the mapping's component is the change of η(λ + δ)/η(λ_m + δ) — nil at the normalising node —
    not δ·η'(λ), which is ≈ 0.0013/nm there and overstated the rest."""
    from calib.model.gratings import physical_grating

    wavelength = np.arange(400.0, 701.0, 10.0)
    grating = physical_grating("sinusoidal", 1.2)
    eta = grating.efficiency(1, wavelength)
    rms = 0.3
    mapping = replace(TRUTH, wavelength_rms_nm=rms)
    result = EstimateResult(
        "prior",
        wavelength,
        np.ones((wavelength.size, 3)),
        grating_efficiency=eta / eta.max(),
        grating_efficiency_sigma=np.full(wavelength.size, 1e-3),
        mapping=mapping,
    )
    stated = uncertainty_budget(result, []).efficiency_components["mapping"]
    shifted = grating.efficiency(1, wavelength + rms)
    actual = np.abs(shifted / shifted.max() - eta / eta.max())
    assert stated[0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(stated[1:], actual[1:], rtol=0.1)
    assert np.all(np.abs(np.gradient(eta / eta.max(), wavelength)) * rms > 2 * stated)


def test_the_normalisation_component_follows_the_peak_node_s_bend() -> None:
    """The maximum node's discretisation moves every cell in proportion (decision 0181): a curve
    that bends sharply at its peak gets a wider band than one that bends gently, by the ratio of
    their second differences there; a peak at the grid's end, where there is no second
    difference, gets none. The delivered curves' scale does not matter."""
    wavelength = np.arange(400.0, 701.0, 10.0)

    def result(width_nm: float, centre_nm: float = 550.0, scale: float = 1.0) -> EstimateResult:
        curve = scale * np.exp(-0.5 * ((wavelength - centre_nm) / width_nm) ** 2)
        return EstimateResult("test", wavelength, np.stack([curve, 0.5 * curve, 0.2 * curve], 1))

    sharp, gentle = normalisation_sigma(result(12.0)), normalisation_sigma(result(60.0))
    peak = int(np.argmax(result(12.0).sensitivity[:, 0]))
    curve = result(12.0).sensitivity[:, 0]
    bend = abs(curve[peak - 1] - 2 * curve[peak] + curve[peak + 1])
    np.testing.assert_allclose(sharp[:, 0], curve * NORMALISATION_SHARE * bend / 12.0)
    np.testing.assert_allclose(sharp[:, 1], 0.5 * sharp[:, 0])  # every cell, in proportion
    assert sharp.max() > 10 * gentle.max() > 0
    np.testing.assert_allclose(normalisation_sigma(result(12.0, scale=7.0)), sharp)
    assert not normalisation_sigma(result(30.0, centre_nm=700.0)).any()
