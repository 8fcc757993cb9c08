import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calib.core.errors import InputError
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, Spectrum
from calib.methods.makabe2025 import Makabe2025Options, estimate_makabe2025
from calib.methods.prior_solve import estimate_prior
from calib.model.forward import render_observation
from tests.synthetic_cameras import as_spectrum, exact_basis

MAPPING = QuadraticMapping(-1.5e-5, 0.47, 382.0, pixel_range=(0.0, 719.0))
LAMP = Spectrum(np.arange(380.0, 781.0, 5.0), 1.2 + np.sin(np.arange(81) / 9.0), name="led")


@pytest.fixture(scope="module")
def basis_and_cameras(tmp_path_factory):
    return exact_basis(tmp_path_factory.mktemp("cache"))


def _observation(camera_values, lamp=LAMP, efficiency=None, **kwargs) -> LampObservation:
    rendered = render_observation(
        lamp,
        as_spectrum(camera_values),
        mapping=MAPPING,
        pixel=720,
        grating_efficiency=efficiency,
        kind="led",
        **kwargs,
    )
    return rendered.observation


def test_camera_in_the_basis_span_is_recovered_to_rounding(basis_and_cameras):
    basis, cameras = basis_and_cameras
    truth = 0.6 * cameras[1] + 0.4 * cameras[4]
    result = estimate_makabe2025(
        [_observation(truth)],
        basis=basis,
        mapping=MAPPING,
        options=Makabe2025Options(formulation="measured"),
    )
    assert relative_error(result.sensitivity, truth) < 1e-8
    assert result.grating_efficiency is not None
    np.testing.assert_allclose(result.grating_efficiency, 1.0, atol=1e-7)


def test_prior_solver_recovers_the_prior_mean_camera_and_a_smooth_grating(basis_and_cameras):
    """With s = α ŝ the prior costs nothing, so only the data speak: near-exact recovery."""
    basis, _ = basis_and_cameras
    truth = 2.5 * basis.mean

    def efficiency(wavelength_nm):
        return 0.8 + 0.2 * np.sin(2 * np.pi * (wavelength_nm - 400) / 300)

    result = estimate_prior(
        [_observation(truth, efficiency=efficiency)], basis=basis, mapping=MAPPING
    )
    assert result.method == "prior"
    assert relative_error(result.sensitivity, truth) < 2e-3
    assert result.sensitivity_sigma is not None
    assert np.all(result.sensitivity_sigma >= 0)


def test_smooth_grating_efficiency_is_recovered(basis_and_cameras):
    basis, cameras = basis_and_cameras
    truth = cameras[3]

    def efficiency(wavelength_nm):
        return 0.7 + 0.3 * np.cos(2 * np.pi * (wavelength_nm - 400) / 300)

    result = estimate_makabe2025(
        [_observation(truth, efficiency=efficiency)],
        basis=basis,
        mapping=MAPPING,
        options=Makabe2025Options(formulation="measured"),
    )
    # Not exact: η varies within each pixel's wavelength interval, which the linear rows ignore.
    assert relative_error(result.sensitivity, truth) < 5e-3
    expected = efficiency(DEFAULT_GRID.wavelength_nm)
    assert result.grating_efficiency is not None
    np.testing.assert_allclose(result.grating_efficiency, expected / expected.max(), atol=0.05)


def test_paper_variant_runs_and_is_close_without_noise(basis_and_cameras):
    basis, cameras = basis_and_cameras
    result = estimate_makabe2025([_observation(cameras[0])], basis=basis, mapping=MAPPING)
    # The paper's point-sampled W and grid-sampled lamp are approximations of the renderer.
    assert relative_error(result.sensitivity, cameras[0]) < 0.06
    assert result.method == "makabe2025" and result.diagnostics["formulation"] == "printed"
    assert result.sensitivity_sigma is None  # the paper gives no uncertainty
    assert result.diagnostics["kkt_condition"] > 1


def test_mapping_is_found_from_the_broadband_lamp_alone(basis_and_cameras):
    basis, cameras = basis_and_cameras
    truth = cameras[2]
    result = estimate_prior([_observation(truth)], basis=basis)
    assert isinstance(result.mapping, QuadraticMapping)
    pixels = np.arange(720.0)
    inside = (MAPPING.wavelength_nm(pixels) >= 400) & (MAPPING.wavelength_nm(pixels) <= 700)
    error = result.mapping.wavelength_nm(pixels[inside]) - MAPPING.wavelength_nm(pixels[inside])
    assert np.sqrt(np.mean(error**2)) < 1.5
    assert relative_error(result.sensitivity, truth) < 0.02
    assert result.to_dict()["mapping"]["method"] == "correlation search on led+profile fit"


def test_missing_direct_is_a_clear_error(basis_and_cameras):
    basis, cameras = basis_and_cameras
    observation = _observation(cameras[0])
    without = LampObservation(
        observation.name, observation.spectrum, observation.pixel, observation.profile
    )
    with pytest.raises(InputError, match="direct"):
        estimate_makabe2025([without], basis=basis, mapping=MAPPING)
    with pytest.raises(InputError, match="direct"):
        estimate_prior([without], basis=basis, mapping=MAPPING)


@settings(max_examples=8, deadline=None)
@given(lamp_scale=st.floats(1e-3, 1e3), sensitivity_scale=st.floats(1e-3, 1e3))
def test_invariant_to_lamp_scale_and_equivariant_to_sensitivity_scale(
    basis_and_cameras, lamp_scale, sensitivity_scale
):
    basis, cameras = basis_and_cameras
    truth = 0.5 * cameras[5] + 0.5 * cameras[6]
    reference = estimate_prior([_observation(truth)], basis=basis, mapping=MAPPING)
    observation = _observation(truth)
    # The lamp spectrum as given to the solver is rescaled: the estimate must not change shape.
    rescaled_lamp = LampObservation(
        observation.name,
        observation.spectrum.scaled(lamp_scale),
        observation.pixel,
        observation.profile,
        observation.direct_rgb,
        kind="led",
    )
    result = estimate_prior([rescaled_lamp], basis=basis, mapping=MAPPING)
    np.testing.assert_allclose(result.sensitivity, reference.sensitivity, atol=1e-9)
    assert result.diagnostics["sensitivity_scale"] == pytest.approx(
        reference.diagnostics["sensitivity_scale"] / lamp_scale, rel=1e-7
    )
    # A camera k times as sensitive gives k times the signals and k times the absolute estimate.
    brighter = _observation(sensitivity_scale * truth)
    scaled = estimate_prior([brighter], basis=basis, mapping=MAPPING)
    np.testing.assert_allclose(scaled.sensitivity, reference.sensitivity, atol=1e-9)
    assert scaled.diagnostics["sensitivity_scale"] == pytest.approx(
        sensitivity_scale * reference.diagnostics["sensitivity_scale"], rel=1e-7
    )


def test_the_printed_formulation_solves_one_lamp_and_says_so(basis_and_cameras):
    basis, cameras = basis_and_cameras
    first = _observation(cameras[0])
    second = LampObservation(
        "led 2", first.spectrum, first.pixel, first.profile, first.direct_rgb, kind="led"
    )
    with pytest.raises(InputError, match="printed formulation solves one lamp"):
        estimate_makabe2025([first, second], basis=basis, mapping=MAPPING)
    measured = estimate_makabe2025(
        [first, second],
        basis=basis,
        mapping=MAPPING,
        options=Makabe2025Options(formulation="measured"),
    )
    assert measured.diagnostics["solve_lamps"] == ["led", "led 2"]
    with pytest.raises(InputError, match="formulation"):
        Makabe2025Options(formulation="as printed")  # type: ignore[arg-type]
