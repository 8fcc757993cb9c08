"""A descent whose own Gauss–Newton model ends hopelessly behind a leader stops there
(``give_up_above``, :func:`calib.wavelength.profile_search.hopeless_bar`; decision 0165)."""

from __future__ import annotations

import math

import numpy as np

from calib.wavelength.families import QuadraticFamily
from calib.wavelength.least_squares import Evaluation, levenberg_marquardt
from calib.wavelength.profile_search import HOPELESS_DELTA_CHI2, _probed_valley, hopeless_bar

from .landscape import Landscape, solution

PIXELS = (0.0, 1000.0)


def _offset_line(x: np.ndarray, with_jacobian: bool) -> Evaluation:
    # A straight line through five points that no line fits exactly: the minimum's cost is
    # FLOOR, and the Gauss–Newton model of a linear residual is exact.
    t = np.arange(5.0)
    data = 1.0 + 2.0 * t + np.array([1.0, -1.0, 1.0, -1.0, 1.0])
    residual = x[0] + x[1] * t - data
    return residual, np.stack([np.ones(5), t], axis=1) if with_jacobian else None


FLOOR = float(np.sum(_offset_line(np.array([1.2, 2.0]), False)[0] ** 2))  # type: ignore[index]


def test_the_floor_is_the_lines_minimum() -> None:
    assert math.isclose(levenberg_marquardt(_offset_line, np.zeros(2)).cost, FLOOR, rel_tol=1e-9)


def test_a_descent_whose_model_ends_above_the_bar_stops_at_its_start() -> None:
    start = np.array([10.0, -3.0])
    stopped = levenberg_marquardt(_offset_line, start, give_up_above=FLOOR - 0.1)
    assert stopped.evaluations == 1
    np.testing.assert_array_equal(stopped.x, start)


def test_a_descent_whose_model_reaches_below_the_bar_goes_on_as_without_one() -> None:
    start = np.array([10.0, -3.0])
    plain = levenberg_marquardt(_offset_line, start)
    barred = levenberg_marquardt(_offset_line, start, give_up_above=FLOOR + 0.1)
    np.testing.assert_array_equal(barred.x, plain.x)
    assert barred.evaluations == plain.evaluations > 1


def test_the_bar_is_the_hopeless_delta_chi2_tempered_by_the_leaders_reduced_chi2() -> None:
    # (:func:`solution`'s fits have 1 000 rows and 3 parameters: 997 degrees of freedom.)
    assert hopeless_bar(solution(np.zeros(3), 500.0)) == 500.0 + HOPELESS_DELTA_CHI2  # below 1
    assert hopeless_bar(solution(np.zeros(3), 3988.0)) == 3988.0 + 4.0 * HOPELESS_DELTA_CHI2


def test_the_probes_sketches_run_their_whole_round() -> None:
    """Decision 0165, addendum: a probe's sketches are given no bar (stopping them moved
    predicted-curve mappings from right to 6–7 nm off)."""
    basin = np.array([400.0, 550.0, 700.0])
    view = Landscape([(basin, 2000.0)], floor=9000.0)
    valley, count = _probed_valley(
        QuadraticFamily(PIXELS),
        solution(basin, 2000.0),
        solution(basin, 2000.0),
        view,  # type: ignore[arg-type]
        view,  # type: ignore[arg-type]
        PIXELS,
    )
    assert valley is None
    # Four sketches of 10 evaluations and one batch of five costs, all uphill, then the two moves
    # twice as far (decision 0169) and one batch of their two costs (the basin's own cost is
    # reused, decision 0172); no bar passed on.
    assert view.bars == [math.inf] * 6
    assert count == 4 * 10 + 5 + 2 * 10 + 2
