"""Decision 0158: a broadband-only answer shifted as a whole by an alias spacing (the response
nodes' 10 nm) has the truth's valley one spacing away; the search shifts the whole leader by
± that spacing, descends, and a valley the deciding and the final stage both prefer leads (the
old leader stays a basin)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from calib.wavelength.families import QuadraticFamily
from calib.wavelength.least_squares import Solution
from calib.wavelength.profile_search import WHOLE_SHIFT_NM, whole_shift_probe

from .landscape import Landscape, solution

PIXELS = (0.0, 799.0)
LEADER = np.array([394.0, 552.0, 720.0])
#: The truth's valley a spacing bluer, a little off the exact shift.
TRUTH = LEADER - WHOLE_SHIFT_NM + np.array([0.4, -0.3, 0.2])


def _probe(
    deciding_truth_cost: float, final_truth_cost: float
) -> tuple[list[tuple[Any, Solution]], int, Landscape, Solution]:
    family = QuadraticFamily(PIXELS)
    # The ranking and the deciding view alike.
    view = Landscape([(TRUTH, deciding_truth_cost), (LEADER, 1000.0)], 5000.0)
    leader = solution(LEADER, 1000.0)
    decided, count = whole_shift_probe(
        [(family, leader)],
        view,  # type: ignore[arg-type]
        view,  # type: ignore[arg-type]
        Landscape([(TRUTH, final_truth_cost), (LEADER, 1000.0)], 5000.0),  # type: ignore[arg-type]
        PIXELS,
    )
    return decided, count, view, leader


def test_the_whole_leader_is_shifted_both_ways_and_the_valley_both_stages_prefer_leads():
    decided, count, view, leader = _probe(900.0, final_truth_cost=900.0)
    assert view.starts[0] == pytest.approx(LEADER - WHOLE_SHIFT_NM)
    assert view.starts[1] == pytest.approx(LEADER + WHOLE_SHIFT_NM)
    assert decided[0][1].x == pytest.approx(TRUTH)
    assert decided[1][1] is leader
    # Two sketches, one costing of 3, the descent, two settles.
    assert count == 2 * 10 + 3 + 3 * 10


def test_a_valley_behind_the_leader_is_left_whatever_the_final_stage_says():
    # Not below the leader where the sketches are ranked: nothing is descended.
    decided, count, _, leader = _probe(1000.5, final_truth_cost=900.0)
    assert [d[1] for d in decided] == [leader]
    assert count == 2 * 10 + 3


def test_a_valley_the_final_stage_does_not_prefer_by_the_bar_stays_behind_the_leader():
    """Decision 0168: the leader stays the answer, the valley (lower on the deciding stage) a
    basin behind it."""
    decided, count, _, leader = _probe(900.0, final_truth_cost=990.0)
    assert decided[0][1] is leader
    assert [d[1].x for d in decided[1:]] == [pytest.approx(TRUTH)]
    assert count == 2 * 10 + 3 + 3 * 10
