"""A fit's cost is continuous where the working range's hats are cut, and a descent stops within a
tenth of its σ (decision 0124)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.spectra import DEFAULT_GRID
from calib.model.bases import fallback_camera_basis
from calib.wavelength.least_squares import CONVERGED_DELTA_CHI2, levenberg_marquardt
from tests.led_scene import unblurred_led


@pytest.fixture(scope="module")
def led_model():
    """The shared unblurred D65 scene, its band reaching the cut hats' ramps (as the search's
    final fit builds it)."""
    return unblurred_led(cut_ramps=True)


@pytest.mark.parametrize("end", ["start", "stop"])
def test_the_cost_does_not_jump_where_a_pixel_edge_crosses_the_working_ranges_end(led_model, end):
    model, family, edges_px, truth = led_model
    junction = DEFAULT_GRID.start_nm if end == "start" else DEFAULT_GRID.stop_nm
    x = family.parameters(truth)
    edges = family.wavelengths(edges_px, x)
    nearest = int(np.argmin(np.abs(edges - junction)))
    # The whole mapping shifted so that that edge lies a hair below, then a hair above the junction
    # (the lamp's fine axis ramps a cut hat to zero over its next step, 1 nm here).
    below = x + (junction - 1e-7 - edges[nearest])
    above = x + (junction + 1e-7 - edges[nearest])
    batch = np.stack([family.wavelengths(edges_px, below), family.wavelengths(edges_px, above)])
    band = model.band(batch)
    dense = np.zeros((2, band.values.shape[1], model.n_nodes + band.values.shape[2]))
    for k in range(2):
        np.put_along_axis(dense[k], band.columns[k], band.values[k], axis=1)
    # Each entry moves by ~1e-7 × the lamp's density; before, a pixel starting just past the
    # junction dropped the cut hat's ramp (half a fine step's light: ~40 here).
    assert np.max(np.abs(dense[1] - dense[0])) < 1e-3
    costs = model.costs(batch)
    assert abs(costs[1] - costs[0]) < 1e-4 * max(abs(costs[0]), 1.0)


def _decay(x: np.ndarray, with_jacobian: bool):
    """An exponential decay fitted to 20 samples of σ = 0.01 (residuals in units of σ)."""
    t = np.linspace(0.0, 2.0, 20)
    noise = 0.01 * np.sin(7.0 * t)
    model = x[0] * np.exp(-x[1] * t)
    residual = (model - (2.0 * np.exp(-1.3 * t) + noise)) / 0.01
    if not with_jacobian:
        return residual, None
    return residual, np.stack([np.exp(-x[1] * t), -x[0] * t * np.exp(-x[1] * t)], axis=1) / 0.01


def test_a_descent_stops_within_a_tenth_of_its_sigma():
    start = np.array([1.0, 0.4])
    plain = levenberg_marquardt(_decay, start, max_iterations=100, tolerance=1e-14)
    stopped = levenberg_marquardt(
        _decay, start, max_iterations=100, tolerance=1e-14, gain_tolerance=0.01
    )
    assert stopped.evaluations < plain.evaluations
    # Where it stopped the Gauss–Newton model predicts less than 0.01 of χ² to gain, and the
    # fully converged minimum lies within a tenth of a σ (Mahalanobis) of the point.
    jacobian = stopped.jacobian
    gradient = jacobian.T @ stopped.residual
    normal = jacobian.T @ jacobian
    assert float(gradient @ np.linalg.solve(normal, gradient)) < 0.01
    offset = stopped.x - plain.x
    assert float(offset @ normal @ offset) < 0.1**2
    assert stopped.cost - plain.cost < 0.01


@pytest.mark.slow
def test_only_the_search_s_final_fit_reaches_the_ramps_and_stops_at_a_tenth_of_sigma(
    led_model, monkeypatch
):
    from calib.wavelength import profile_search

    model, _, _, _ = led_model
    calls: list[tuple[int, bool, float]] = []
    original = profile_search.StageFit.refine

    def spy(self, x, max_iterations, tolerance=1e-6, rounds=2, gain_tolerance=0.0, **kwargs):
        ramps = {m.cut_ramps for m in self.models}
        assert len(ramps) == 1
        calls.append((self.edges_px.size - 1, ramps.pop(), gain_tolerance))
        return original(self, x, max_iterations, tolerance, rounds, gain_tolerance, **kwargs)

    monkeypatch.setattr(profile_search.StageFit, "refine", spy)
    prior = fallback_camera_basis().prior()
    profile_search.search_profiles(model.observation, prior, DEFAULT_GRID, orientation="rising")
    # The final fit is the search's last descent (no red-end pull-in in the quadratic family).
    *others, final = [(ramps, gain) for _, ramps, gain in calls]
    assert final == (True, CONVERGED_DELTA_CHI2)
    assert others and all(other == (False, 0.0) for other in others)
