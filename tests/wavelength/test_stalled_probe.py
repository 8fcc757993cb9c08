"""Decision 0158: the scan's best basin whose deciding descent stalled hopelessly behind the
leader (a narrow valley of its own, an end 10 nm too far out) is probed as decision 0152 probes
the leader: an end moved inwards and descended; the valley found leads when the deciding and the
final stage both prefer it, the old leader staying a basin."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calib.wavelength.families import QuadraticFamily
from calib.wavelength.least_squares import Solution
from calib.wavelength.profile_search import HOPELESS_DELTA_CHI2, LOCAL_SCAN, stalled_probe

from .landscape import Landscape, solution

PIXELS = (0.0, 799.0)
#: The deciding leader: an alias 10 nm off in the middle.
LEADER = np.array([382.0, 551.5, 718.0])
#: The scan's best basin where its descent stalled: the blue end 6.5 nm too blue.
STALLED = np.array([377.5, 539.0, 710.0])
#: The truth's valley, the blue end inwards of it (the middle following by half).
TRUTH = STALLED + np.array([6.5, 3.25, 0.0])


def _probe(
    stalled_cost: float, final_truth_cost: float
) -> tuple[list[tuple[Any, Solution]], int, Landscape, Solution]:
    family = QuadraticFamily(PIXELS)
    # The ranking and the deciding view alike; the final stage with its own cost of the truth.
    view = Landscape([(TRUTH, 100.0), (LEADER, 1000.0), (STALLED, stalled_cost)], 500_000.0)
    final = Landscape(
        [(TRUTH, final_truth_cost), (LEADER, 1000.0), (STALLED, stalled_cost)], 500_000.0
    )
    leader = solution(LEADER, 1000.0)
    stalled = solution(STALLED, stalled_cost)
    decided, count = stalled_probe(
        [(family, leader), (family, stalled)],
        stalled,
        view,  # type: ignore[arg-type]
        view,  # type: ignore[arg-type]
        final,  # type: ignore[arg-type]
        PIXELS,
    )
    return decided, count, view, leader


def test_a_stalled_scan_best_is_probed_and_the_valley_both_stages_prefer_leads():
    decided, count, view, leader = _probe(100_000.0, final_truth_cost=500.0)
    half = LOCAL_SCAN[0]
    # From the stalled basin: the blue end up (the middle by half), the red end down; the blue
    # end's sketch falls into the truth's valley.
    assert view.starts[0] == pytest.approx(STALLED + np.array([half, half / 2, 0.0]))
    assert view.starts[1] == pytest.approx(STALLED + np.array([0.0, -half / 2, -half]))
    assert decided[0][1].x == pytest.approx(TRUTH)
    assert decided[1][1] is leader
    # Four sketches (two moves of each end), one costing of 5, the descent, two settles.
    assert count == 4 * 10 + 5 + 3 * 10


def test_a_valley_the_final_stage_does_not_prefer_by_the_bar_stays_behind_the_leader():
    """Decision 0168: the leader stays the answer, the valley (lower on the deciding stage) a
    basin behind it."""
    decided, _, _, leader = _probe(100_000.0, final_truth_cost=990.0)
    assert decided[0][1] is leader
    assert decided[1][1].x == pytest.approx(TRUTH)


def test_a_scan_best_not_hopelessly_behind_is_not_probed():
    decided, count, view, leader = _probe(1000.0 + HOPELESS_DELTA_CHI2, final_truth_cost=500.0)
    assert count == 0
    assert not view.starts
    assert decided[0][1] is leader


@pytest.mark.slow
@pytest.mark.shared_data
def test_the_canon_10d_paper_scene_under_lamp_a_is_found(shared_camera_data: Path) -> None:
    """The validation split's paper scene (lamp A, seed 4, no noise) of the Canon 10D
    (Kawakami): on base 371f8f5 its LED-only mapping was 10.6 nm off, unwarned; the scan's best
    basin was the truth's with its blue end 10 nm too blue, its deciding descent stalled."""
    from .paper_scene import searched_worst_nm

    assert (
        searched_worst_nm(shared_camera_data, "Canon 10D (Kawakami-et-al-2013)", "A", 4, 0.0) < 1.0
    )
