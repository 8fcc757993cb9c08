"""calib.wavelength.least_squares: the refused step shortened (``shorten``, decision 0096); the
convergence bar in units of the fit's own σ and the stop at a bound (decision 0195)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.wavelength.least_squares import (
    CONVERGED_DELTA_CHI2,
    SHORTEN_FRACTION,
    Evaluation,
    ResidualFunction,
    Solution,
    levenberg_marquardt,
)


def _rosenbrock(x: np.ndarray, with_jacobian: bool) -> Evaluation:
    residual = np.array([1000.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])
    jacobian = np.array([[-2000.0 * x[0], 1000.0], [-1.0, 0.0]])
    return residual, jacobian if with_jacobian else None


def _flattening(x: np.ndarray, with_jacobian: bool) -> Evaluation:
    # A residual that flattens away from its root: the Gauss–Newton step from x = 2 overshoots
    # to x ≈ −3.5, where the cost is higher, and stays that long under a small damping.
    residual = np.array([np.arctan(x[0]), 0.1 * np.arctan(x[0] + 1.0)])
    jacobian = np.array([[1.0 / (1.0 + x[0] ** 2)], [0.1 / (1.0 + (x[0] + 1.0) ** 2)]])
    return residual, jacobian if with_jacobian else None


def _cost(function: ResidualFunction, x: np.ndarray) -> float:
    evaluated = function(x, False)
    assert evaluated is not None
    return float(evaluated[0] @ evaluated[0])


def _trials(
    function: ResidualFunction, start: np.ndarray, *, shorten: bool = False
) -> tuple[Solution, list[float]]:
    """The solution and, for every refused trial, the next trial's scaled step over its own
    (both from the same point; the scale ``diag(JᵀJ)`` there)."""
    points: list[np.ndarray] = []

    def watched(x: np.ndarray, with_jacobian: bool) -> Evaluation:
        points.append(np.array(x, dtype=np.float64))
        return function(x, with_jacobian)

    solution = levenberg_marquardt(
        watched, start, max_iterations=1000, tolerance=1e-14, shorten=shorten
    )
    base = points[0]
    cost = _cost(function, base)
    ratios = []
    refused: np.ndarray | None = None
    for point in points[1:]:
        evaluated = function(base, True)
        assert evaluated is not None
        jacobian = np.asarray(evaluated[1])
        scale = np.sqrt(np.sum(jacobian**2, axis=0))
        if refused is not None:
            moved = np.linalg.norm(scale * (point - base)) / np.linalg.norm(scale * refused)
            ratios.append(float(moved))
        trial = _cost(function, point)
        if trial < cost:
            base, cost, refused = point, trial, None
        else:
            refused = point - base
    return solution, ratios


@pytest.mark.parametrize(
    ("function", "start"),
    [(_rosenbrock, np.array([-1.2, 1.0])), (_flattening, np.array([2.0]))],
)
def test_shorten_halves_every_refused_step_and_needs_fewer_evaluations(
    function: ResidualFunction, start: np.ndarray
) -> None:
    plain, plain_ratios = _trials(function, start)
    cut, ratios = _trials(function, start, shorten=True)
    np.testing.assert_allclose(cut.x, plain.x, atol=1e-5)
    assert ratios and max(ratios) <= 1.1 * SHORTEN_FRACTION
    # ×4 alone does not (the flattening residual's refused step stays nearly as long: the
    # damping is far below 1).
    assert max(plain_ratios) > 1.1 * SHORTEN_FRACTION
    assert cut.evaluations < 0.85 * plain.evaluations


def test_the_step_after_a_cut_is_not_lengthened_at_once() -> None:
    # The accepted step right after a refusal keeps its damping: without that rule (÷5 as after
    # any accepted step) the same valley takes more evaluations than with ×4 alone.
    start = np.array([-3.0, 8.0])
    plain = levenberg_marquardt(_rosenbrock, start, max_iterations=1000, tolerance=1e-14)
    cut = levenberg_marquardt(
        _rosenbrock, start, max_iterations=1000, tolerance=1e-14, shorten=True
    )
    np.testing.assert_allclose(cut.x, [1.0, 1.0], atol=1e-5)
    assert cut.evaluations < 0.85 * plain.evaluations


def test_the_stopping_points_jacobian_is_computed_only_when_read():
    """A deferred Jacobian (a call) at the point where the loop stops is not computed by the loop
    (decision 0153): the solution computes it when first read, once, and it is the Jacobian the
    function gives there — the same numbers as an eager loop's."""
    t = np.linspace(0.0, 4.0, 30)
    observed = 2.0 * np.exp(-0.7 * t) + 0.01 * np.sin(7.0 * t)
    calls: list[int] = []

    def model(x, with_jacobian, *, lazy=True):
        value = x[0] * np.exp(-x[1] * t)
        residual = value - observed

        def jacobian():
            calls.append(1)
            return np.stack([np.exp(-x[1] * t), -t * value], axis=1)

        if not with_jacobian:
            return residual, None
        return residual, (jacobian if lazy else jacobian())

    lazy = levenberg_marquardt(model, np.array([1.0, 0.3]), max_iterations=4)
    # One Jacobian per iteration started (four: the cap), none at the stopping point.
    assert len(calls) == 4
    eager = levenberg_marquardt(
        lambda x, j: model(x, j, lazy=False), np.array([1.0, 0.3]), max_iterations=4
    )
    np.testing.assert_array_equal(lazy.x, eager.x)
    assert lazy.cost == eager.cost and lazy.evaluations == eager.evaluations
    before = len(calls)
    first_read = lazy.jacobian
    assert len(calls) == before + 1  # computed on reading
    assert lazy.jacobian is first_read and len(calls) == before + 1  # and kept
    np.testing.assert_array_equal(first_read, eager.jacobian)
    np.testing.assert_array_equal(lazy.covariance(), eager.covariance())


T = np.arange(1.0, 11.0)


def _beyond_the_bound(x: np.ndarray, with_jacobian: bool) -> Evaluation:
    """A slope the data put at 2 in a family valid up to 1 only: the minimum lies beyond the bound."""
    if x[0] > 1.0:
        return None
    return (x[0] - 2.0) * T / 0.1, (T[:, None] / 0.1) if with_jacobian else None


def test_a_fit_pressing_on_a_bound_stops_once_its_steps_no_longer_tell():
    """Its Gauss–Newton gain never falls (the model's minimum is beyond the bound): without
    ``stop_at_bound`` the fit crawls to the bound by ever smaller steps; with it, it stops within a
    small part of its own σ of the bound, in a fraction of the evaluations."""

    def fit(gain: float = 0.0, at_bound: bool = False) -> Solution:
        return levenberg_marquardt(
            _beyond_the_bound,
            np.zeros(1),
            max_iterations=200,
            tolerance=1e-12,
            gain_tolerance=gain,
            tempered=True,
            stop_at_bound=at_bound,
        )

    crawled = fit()
    tempered = fit(CONVERGED_DELTA_CHI2)
    stopped = fit(CONVERGED_DELTA_CHI2, at_bound=True)
    assert crawled.x[0] == pytest.approx(1.0, abs=1e-6)
    assert tempered.evaluations == crawled.evaluations  # the gain alone never stops it
    assert stopped.evaluations <= crawled.evaluations / 3
    own_sigma = float(np.sqrt(stopped.covariance()[0, 0]))
    assert 0.0 < 1.0 - stopped.x[0] < 0.1 * own_sigma


def test_the_tempered_bar_is_a_tenth_of_the_fits_own_sigma():
    """A model that cannot pass through its data (reduced χ² ~ 10³): the tempered bar stops the fit
    sooner than the bar in stated σ, and still within a tenth of its own σ of the minimum."""
    data = np.exp(-0.3 * T) + 0.05 * np.sin(T)

    def decay(x: np.ndarray, with_jacobian: bool) -> Evaluation:
        falling = np.exp(-x[1] * T)
        residual = (x[0] * falling - data) / 1e-3
        jacobian = np.stack([falling, -x[0] * T * falling], axis=1) / 1e-3
        return residual, jacobian if with_jacobian else None

    start = np.array([2.0, 1.0])
    best = levenberg_marquardt(decay, start, max_iterations=500, tolerance=0.0)
    assert best.temper > 100.0
    stated = levenberg_marquardt(
        decay, start, max_iterations=500, tolerance=0.0, gain_tolerance=CONVERGED_DELTA_CHI2
    )
    own = levenberg_marquardt(
        decay,
        start,
        max_iterations=500,
        tolerance=0.0,
        gain_tolerance=CONVERGED_DELTA_CHI2,
        tempered=True,
    )
    assert own.evaluations < stated.evaluations < best.evaluations
    apart = own.x - best.x
    assert 0.0 < float(np.sqrt(apart @ np.linalg.solve(best.covariance(), apart))) < 0.1
