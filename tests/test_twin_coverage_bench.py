"""``bench/twin_coverage.py``'s diagnoses of a miss (decision 0111): the truth a grid can hold, and
the max-1 normalisation's part."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest

from tests.benches import load_bench

#: Importing the bench imports the rig (capture, estimate): seconds, so not in the default suite.
pytestmark = pytest.mark.slow


def _bench() -> ModuleType:
    return load_bench("twin_coverage.py")


def test_the_grid_projection_is_off_the_point_samples_by_the_curvature() -> None:
    bench = _bench()
    fine = np.arange(380.0, 781.0, 0.5)  # finer than the projection needs: a smooth truth
    curvature = 1e-4  # s = c (λ − 550)², s'' = 2c
    values = np.stack([curvature * (fine - 550.0) ** 2] * 3, axis=1)
    grid = np.arange(400.0, 701.0, 10.0)
    projected = bench.grid_projection(fine, values, grid)
    points = curvature * (grid - 550.0) ** 2
    # interior nodes: −h² s''/12 (the piecewise-linear least-squares curve lies under a parabola's
    # chords); the end nodes see one side only
    np.testing.assert_allclose(
        projected[2:-2, 1] - points[2:-2], -(10.0**2) * 2 * curvature / 12, rtol=0.02
    )


def test_a_maximum_node_above_its_truth_shows_as_a_common_scale() -> None:
    bench = _bench()
    wavelength = np.arange(400.0, 701.0, 10.0)
    reference = np.stack(
        [np.exp(-0.5 * ((wavelength - centre) / 30.0) ** 2) for centre in (590, 530, 460)], axis=1
    )
    curves = reference.copy()
    curves[19, 0] *= 1.04  # the red node at 590 nm, 4 % above its truth, becomes the maximum
    curves /= curves.max()
    sigma = np.full_like(curves, 0.005)
    found = bench.normalisation_diagnosis(curves, sigma, reference, wavelength)
    assert found["peaks"][0] == ("R", 590.0)
    assert 1.03 < found["common_scale"] < 1.045
    covered = float(np.mean(np.abs(curves - reference) <= 2 * sigma))
    assert covered < 0.8 and found["coverage_at_common_scale"] > 0.95


def test_the_extra_validation_twins_are_other_rawtoaces_bodies_never_a_test_body() -> None:
    bench = _bench()
    drawn = bench.extra_validation_cameras(100)
    names = [name for name, _ in drawn]
    assert {collection for _, collection in drawn} == {"rawtoaces-data"}
    assert len(set(names)) == len(names) > 30
    assert not set(names) & {name for name, _ in bench.VALIDATION}
    # the test cameras' bodies (here and in bench/validate_twin.py) stay on the test side
    assert not set(names) & set(bench.TEST_BODIES)
    assert "Nikon D5100" not in names and "ARRI D21" not in names
    # a fixed draw: the first N of a longer draw, the same on every run
    assert bench.extra_validation_cameras(5) == drawn[:5]


def test_the_physical_parameter_is_scored_against_the_twins_own_sheet() -> None:
    """Decision 0151: η's one parameter, fitted − true, its σ and the direct χ² per degree of
    freedom; nothing where the estimate fitted another family than the twin's sheet."""
    bench = _bench()
    record = {
        "model": "sinusoidal",
        "parameters": {"peak_phase_rad": 1.1987, "peak_phase_rad_sigma": 0.002},
        "direct_chi2": 0.8,
        "direct_equations": 6,
    }
    sheet = {"kind": "sinusoidal", "peak_phase_rad": 1.2, "reference_nm": 550.0}
    error, sigma, chi2 = bench.physical_parameter_scores(record, sheet)
    np.testing.assert_allclose((error, sigma, chi2), (-0.0013, 0.002, 0.2), atol=1e-12)
    blazed = {**record, "model": "blazed"}
    assert np.isnan(bench.physical_parameter_scores(blazed, sheet)).all()
    assert np.isnan(bench.physical_parameter_scores(None, sheet)).all()


def test_the_measured_slit_is_read_from_the_scale_checks_record() -> None:
    """Decision 0159: the slit factor and σ the bandwidth component starts from, as the check's
    record holds them (its ``to_dict`` keys); nothing where the check did not measure the slit."""
    bench = _bench()
    record = {"mean_offset_nm": -0.11, "slit_factor": 0.8856, "slit_factor_sigma": 0.0701}
    assert bench.measured_slit_factor(record) == (0.8856, 0.0701)
    assert bench.measured_slit_factor({**record, "slit_factor": None}) is None
    assert bench.measured_slit_factor({"mean_offset_nm": -0.11}) is None
    assert bench.measured_slit_factor(None) is None


def test_an_estimate_on_a_finer_grid_is_scored_at_the_default_nodes_normalised_there() -> None:
    bench = _bench()
    fine = np.arange(400.0, 701.0, 5.0)
    nodes = np.arange(400.0, 701.0, 10.0)
    values = np.stack([np.exp(-0.5 * ((fine - centre) / 30.0) ** 2) for centre in (600, 535, 455)])
    values = values.T.copy()
    values[fine == 535.0, 1] = 1.25  # the maximum between two 10 nm nodes: not delivered there
    sigma = np.full_like(values, 0.01)
    read, read_sigma = bench.on_nodes(values, sigma, fine, nodes)
    assert read.shape == (nodes.size, 3)
    assert read.max() == pytest.approx(1.0)
    scale = float(values[::2].max())
    np.testing.assert_allclose(read, values[::2] / scale)
    np.testing.assert_allclose(read_sigma, sigma[::2] / scale)
    # the default grid itself: unchanged
    same, same_sigma = bench.on_nodes(values[::2], sigma[::2], nodes, nodes)
    np.testing.assert_array_equal(same, values[::2])
    np.testing.assert_array_equal(same_sigma, sigma[::2])
    # a grid whose nodes miss the default ones cannot be scored there
    with pytest.raises(SystemExit, match="--grid"):
        bench.on_nodes(values[:-1], sigma[:-1], fine[:-1] + 2.5, nodes)
