import numpy as np
import pytest

from calib.core.mapping import GratingGeometry, QuadraticMapping, mapping_from_dict
from calib.core.spectra import DEFAULT_GRID, Spectrum
from calib.model.bases import camera_basis
from calib.model.forward import render_observation
from calib.wavelength.peaks import Peak, mapping_from_peaks, match_peaks
from tests.synthetic_cameras import as_spectrum, gaussian_camera, spanning_set


def test_quadratic_inverse_and_serialisation():
    mapping = QuadraticMapping(3e-5, 0.4, 390.0, pixel_range=(0.0, 900.0))
    pixels = np.linspace(0, 900, 50)
    np.testing.assert_allclose(mapping.pixel_at(mapping.wavelength_nm(pixels)), pixels, atol=1e-8)
    again = mapping_from_dict(mapping.to_dict())
    assert again == mapping


def test_grating_geometry_exact_and_quadratic():
    geometry = GratingGeometry(grooves_per_mm=500, focal_length_mm=24, pixel_pitch_um=8.0)
    wavelength = np.array([400.0, 550.0, 700.0])
    np.testing.assert_allclose(
        geometry.wavelength_nm(geometry.pixel_at(wavelength)), wavelength, atol=1e-9
    )
    quadratic = geometry.quadratic((400.0, 700.0))
    low, high = geometry.pixel_at(np.array([400.0, 700.0]))
    pixels = np.linspace(float(low), float(high), 100)
    assert np.max(np.abs(quadratic.wavelength_nm(pixels) - geometry.wavelength_nm(pixels))) < 0.5
    assert mapping_from_dict(geometry.to_dict()) == geometry


def test_peak_matching_survives_wrong_and_missing_peaks():
    truth = QuadraticMapping(-3e-5, 0.45, 385.0, pixel_range=(0.0, 800.0))
    lines = [Peak(nm, 1.0, p) for nm, p in ((404.7, 0.3), (435.8, 1.0), (546.1, 0.9), (611.6, 0.6))]
    true_pixels = truth.pixel_at(np.array([435.8, 546.1, 611.6]))  # 404.7 is missing
    peaks = [Peak(float(px), 1.0, 1.0) for px in true_pixels] + [
        Peak(250.0, 1.0, 0.8),
        Peak(700.0, 1.0, 0.5),
    ]
    mapping, matches = match_peaks(
        lines, peaks, pixel_range=(0.0, 800.0), dispersion_range_nm_per_px=(0.3, 0.6)
    )
    assert len(matches) == 3
    pixels = np.linspace(0, 800, 50)
    assert np.max(np.abs(mapping.wavelength_nm(pixels) - truth.wavelength_nm(pixels))) < 0.05


def test_fluorescent_mapping_from_rendered_profile():
    import colour

    lamp = Spectrum.from_colour(colour.SDS_ILLUMINANTS["FL2"], name="FL2")
    truth = QuadraticMapping(-2e-5, 0.42, 385.0, pixel_range=(0.0, 820.0))
    camera = as_spectrum(gaussian_camera((600, 540, 460), (40, 45, 30)))
    rendered = render_observation(lamp, camera, mapping=truth, pixel=821, kind="fluorescent")
    basis = camera_basis(spanning_set(), n_vectors=5, cache=False)
    mapping = mapping_from_peaks(
        lamp, rendered.observation.pixel, rendered.observation.profile, basis.mean
    )
    pixels = truth.pixel_at(np.array([430.0, 560.0]))
    # Peak matching alone is within a few nm where the lines are; the solve's residual refines it.
    assert np.max(np.abs(mapping.wavelength_nm(pixels) - truth.wavelength_nm(pixels))) < 3.0
    assert mapping.method == "fluorescent-peaks"
    assert DEFAULT_GRID.size == 31


def test_grating_rejects_bad_geometry():
    with pytest.raises(ValueError):
        GratingGeometry(grooves_per_mm=-1, focal_length_mm=24, pixel_pitch_um=4)


def test_a_fit_without_covariance_is_the_same_curve():
    """A search's trial fits skip the covariance; the curve and its range are the full fit's."""
    rng = np.random.default_rng(3)
    pixel = np.sort(rng.uniform(0.0, 800.0, 9))
    wavelength = (-2.2e-5 * pixel + 0.43) * pixel + 383.0 + rng.normal(0.0, 0.05, pixel.size)
    for degree in (1, 2):
        full = QuadraticMapping.fit(pixel, wavelength, degree=degree)
        bare = QuadraticMapping.fit(pixel, wavelength, degree=degree, with_covariance=False)
        assert (bare.a, bare.b, bare.c, bare.pixel_range) == (
            full.a,
            full.b,
            full.c,
            full.pixel_range,
        )
        assert full.covariance is not None and bare.covariance is None
