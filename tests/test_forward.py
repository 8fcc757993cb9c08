import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.mapping import QuadraticMapping
from calib.core.spectra import DEFAULT_GRID, Spectrum
from calib.model.forward import (
    PeakFractionNoise,
    ShotReadNoise,
    apply_blur,
    blur_kernel,
    lamp_operators,
    pixel_edges,
    render_observation,
)
from tests.synthetic_cameras import as_spectrum, gaussian_camera

MAPPING = QuadraticMapping(-2e-5, 0.5, 380.0)
LAMP = Spectrum(np.arange(380.0, 781.0, 5.0), 1.0 + 0.5 * np.sin(np.arange(81) / 7.0), name="lamp")
CAMERA = as_spectrum(gaussian_camera((600, 540, 460), (40, 45, 30)))


def test_profile_sums_to_the_first_order_integral_and_direct_to_the_direct_integral():
    rendered = render_observation(LAMP, CAMERA, mapping=MAPPING, pixel=800)
    axis = rendered.spectral_axis_nm
    total = np.trapezoid(rendered.spectral_image, axis, axis=0)
    np.testing.assert_allclose(rendered.clean_profile.sum(axis=0), total, rtol=1e-9)
    np.testing.assert_allclose(rendered.clean_direct, total, rtol=1e-9)  # flat grating: same light


def test_solver_operators_reproduce_the_renderer_exactly():
    rendered = render_observation(LAMP, CAMERA, mapping=MAPPING, pixel=800)
    operators = lamp_operators(LAMP, DEFAULT_GRID)
    edges = MAPPING.wavelength_nm(pixel_edges(np.arange(800.0)))
    model = operators.pixel_matrix(edges) @ CAMERA.values
    np.testing.assert_allclose(model, rendered.clean_profile, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(
        operators.direct_row @ CAMERA.values, rendered.clean_direct, rtol=1e-12
    )


def test_noise_is_seeded_and_comes_with_sigmas():
    first = render_observation(
        LAMP,
        CAMERA,
        mapping=MAPPING,
        pixel=500,
        noise=PeakFractionNoise(0.01),
        rng=np.random.default_rng(3),
    )
    second = render_observation(
        LAMP,
        CAMERA,
        mapping=MAPPING,
        pixel=500,
        noise=PeakFractionNoise(0.01),
        rng=np.random.default_rng(3),
    )
    np.testing.assert_array_equal(first.observation.profile, second.observation.profile)
    sigma = first.observation.profile_sigma
    assert sigma is not None
    np.testing.assert_allclose(sigma, 0.01 * first.clean_profile.max())
    normalised = (first.observation.profile - first.clean_profile) / sigma
    assert 0.9 < normalised.std() < 1.1


def test_shot_noise_grows_with_signal():
    noise = ShotReadNoise(full_well_electrons=10000, read_noise_electrons=2)
    profile = np.array([[1.0, 0.5, 0.1], [0.01, 0.02, 0.03]])
    sigma, direct_sigma = noise.sigmas(profile, np.array([5.0, 4.0, 3.0]))
    assert sigma[0, 0] > sigma[0, 1] > sigma[0, 2]
    assert np.all(direct_sigma > 0)


def test_noise_needs_a_generator():
    with pytest.raises(InputError, match="Generator"):
        render_observation(LAMP, CAMERA, mapping=MAPPING, pixel=100, noise=PeakFractionNoise(0.01))


def test_blur_kernel_is_normalised_and_conserves_light():
    kernel = blur_kernel(3.5, 1.0)
    assert kernel is not None
    assert kernel.sum() == pytest.approx(1.0)
    sharp = render_observation(LAMP, CAMERA, mapping=MAPPING, pixel=800)
    blurred = render_observation(LAMP, CAMERA, mapping=MAPPING, pixel=800, slit_width_px=6.0)
    np.testing.assert_allclose(
        blurred.clean_profile.sum(axis=0), sharp.clean_profile.sum(axis=0), rtol=1e-6
    )
    assert blur_kernel(0.0, 0.0) is None


@pytest.mark.parametrize("kernel_length", [1, 2, 3, 4, 7, 8])
def test_blur_is_numpys_same_convolution_of_every_column(kernel_length: int) -> None:
    rng = np.random.default_rng(kernel_length)
    values = rng.normal(size=(40, 3, 2))
    kernel = rng.random(kernel_length)
    columns = values.reshape(40, -1)
    expected = np.stack(
        [np.convolve(columns[:, k], kernel, mode="same") for k in range(columns.shape[1])], axis=1
    ).reshape(values.shape)
    np.testing.assert_allclose(apply_blur(values, kernel), expected, rtol=0, atol=1e-12)
