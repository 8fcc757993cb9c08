"""A broadband-only quadratic answer whose valley is narrower than the search's end scans: the ends
are scanned again at the deciding profile's own bin (decision 0145).

With a broadband lamp alone and no 0th order (the paper's protocol: the quadratic family), the
deciding stage (:data:`~calib.wavelength.profile_search.REFINE_BIN_NM` bins, the flexible response)
has minima a few nanometres apart, and it finds them from the scan's basins through an end grid
(:data:`~calib.wavelength.profile_search.LOCAL_SCAN`: ±6 nm in 2 nm steps) and a descent from its
lowest point. When the profile is nearly noiseless the valleys of that landscape are far narrower
than the grid's step: a grid point a nanometre beside the bottom of the truth's valley can cost more
than the whole of a wrong one, so no point of the grid lies in it and the descent lands elsewhere.
On the validation split's paper scenes (the Sony DSC-RX1 predicted curve, seed 0, no noise) the
answer was 4.9 nm off at the red end, unwarned, σ 0.07 nm, while the truth's valley 5.8 nm away
fits the deciding profile four times better (χ² 2 922 against 12 331).

Whether a valley can hide is read off the answer's own valley: the shift of either end (the middle
following by half, as the grids move it) that raises the deciding cost by the search's bar
(:data:`~calib.wavelength.profile_search.AMBIGUITY_DELTA_CHI2`, tempered by the fit's reduced χ²),
from the descent's curvature ``JᵀJ``. Where that half-width is below half the grid's step, a valley as
narrow as the answer's fits between two of its points; there the ends are scanned again over the
same reach at the deciding profile's bin (1 nm: the finest shift that profile resolves), costed on
the same flexible response at the scan refinement's bins (the view the deciding stage ranks its
grid on), and the deciding stage descends from the grid's lowest local minimum outside the answer's
valley, when that minimum is within what a valley as narrow as the answer's and deeper could cost
half a step from its bottom (decision 0145's addendum: ~3 in 4 checks on the validation split's
paper scenes make no descent). The valley found is the answer only where the search, had its scan held it, would have
answered with it unwarned: ahead by the broadband bar
(:data:`~calib.wavelength.profile_search.BROADBAND_AMBIGUITY_DELTA_CHI2`) on the deciding stage and
by :data:`~calib.wavelength.profile_search.AMBIGUITY_DELTA_CHI2` on the final one (decision 0139's
rule for the coarse view's rival). The answer it replaces stays a basin, so the search's own σ and
warning rules weigh it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.wavelength.families import QuadraticFamily
from calib.wavelength.least_squares import Solution

if TYPE_CHECKING:
    from calib.wavelength.profile_search import StageFit

#: At most this many of the fine grid's local minima are descended from.
EXTRA_DESCENTS = 1


def valley_half_width_nm(solution: Solution, delta_chi2: float) -> float:
    """The narrower end's half-width (nm) of ``solution``'s valley: the shift of one end of the
    profile (the middle following by half) that raises the cost by ``delta_chi2`` times the fit's
    reduced χ² (at least 1), by the fit's curvature ``JᵀJ`` (the quadratic family's parameters are
    the wavelengths at the ends and the middle)."""
    dof = max(solution.residual.size - solution.x.size, 1)
    temper = max(solution.cost / dof, 1.0)
    widths = []
    for curvature in _end_curvatures(solution):
        widths.append(math.sqrt(delta_chi2 * temper / curvature) if curvature > 0 else math.inf)
    return min(widths)


def _end_curvatures(solution: Solution) -> tuple[float, float]:
    """The cost's curvature (per nm²) for a shift of either end of the profile, the middle
    following by half, from the fit's ``JᵀJ``."""
    normal = solution.jacobian.T @ solution.jacobian
    blue, red = (
        float(direction @ normal @ direction)
        for direction in (np.array([1.0, 0.5, 0.0]), np.array([0.0, 0.5, 1.0]))
    )
    return blue, red


def hidden_valleys(
    decided: Sequence[tuple[Any, Solution]],
    ranking: StageFit,
    deciding: StageFit,
    final: StageFit,
    pixel_range: tuple[float, float],
) -> tuple[list[tuple[Any, Solution]], int]:
    """The deciding stage's basins (``decided``, lowest first) with a valley the end grid stepped
    over found about the leader, and the evaluations made (see the module docstring).

    ``ranking``, ``deciding`` and ``final`` are the search's
    :class:`~calib.wavelength.profile_search.StageFit` for the flexible response at the scan
    refinement's bins, on the deciding profile, and its final stage. Returns the basins as given
    when the leader's valley is wide enough for the grid, or when no valley found leads it by the
    search's bar on both the deciding and the final stage; else every basin, the new leader first
    (distinct, > 1 nm apart).
    """
    from calib.wavelength.profile_search import (
        AMBIGUITY_DELTA_CHI2,
        AMBIGUITY_MIN_DISTANCE_NM,
        BROADBAND_AMBIGUITY_DELTA_CHI2,
        LOCAL_SCAN,
        MAX_BASINS,
        REFINE_BIN_NM,
        _behind,
        _distinct,
        _local_minima,
        _quadratic_points,
    )

    family, leader = decided[0]
    assert isinstance(family, QuadraticFamily)
    if valley_half_width_nm(leader, AMBIGUITY_DELTA_CHI2) >= 0.5 * LOCAL_SCAN[1]:
        return list(decided), 0
    points, shape = _quadratic_points(
        family.mapping(leader.x), family, (LOCAL_SCAN[0], REFINE_BIN_NM)
    )
    costs = ranking.costs(points)
    count = points.shape[0]
    # The grid is centred on the leader: its middle point is the leader's own cost on this view.
    own = float(costs[points.shape[0] // 2])
    # A valley as narrow as the leader's and deeper has a grid point at most half a step from its
    # bottom in each end, which costs at most (√a + √b)²·h² ≤ 4·max(a, b)·h² above that bottom
    # (a, b the ends' curvatures): a start that costs more than the leader's own point by that
    # reach cannot be in one (decision 0145, addendum).
    reach = 4.0 * max(_end_curvatures(leader)) * (0.5 * REFINE_BIN_NM) ** 2
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)
    seen: list[FloatArray] = [family.wavelengths(probe, leader.x)]
    starts: list[FloatArray] = []
    for index in _local_minima(costs, shape):
        point = points[index]
        placed = family.wavelengths(probe, point)
        # Outside the leader's valley and apart from the starts taken (> 1 nm somewhere).
        if any(np.max(np.abs(placed - other)) <= AMBIGUITY_MIN_DISTANCE_NM for other in seen):
            continue
        seen.append(placed)
        # The minima are lowest first: none after one beyond the reach is within it.
        if not costs[index] < own + reach:
            break
        starts.append(point)
        if len(starts) == EXTRA_DESCENTS:
            break
    found: list[tuple[Any, Solution]] = []
    for start in starts:
        outcome = deciding.descend(start)
        count += outcome.evaluations
        # Taken only where the search, had its scan held the valley, would have answered with it
        # unwarned: ahead by the broadband bar (below it two basins are an ambiguity, decision
        # 0104), on the deciding stage and on the final one (the finest view of the same
        # likelihood, the stiff response; decision 0139's rule for the coarse view's rival, whose
        # bar is the search's 25). On the validation split a valley 305 ahead on the deciding
        # stage and ahead on the final one was 10 nm off (Canon 5D, Kawakami, seed 2, no noise:
        # the search's answer, right and warned, would have become wrong and warned).
        if not (
            math.isfinite(outcome.cost)
            and _behind(leader, outcome) > BROADBAND_AMBIGUITY_DELTA_CHI2
        ):
            continue
        settled = final.settle(outcome.x)
        held = final.settle(leader.x)
        count += settled.evaluations + held.evaluations
        if _behind(held, settled) > AMBIGUITY_DELTA_CHI2:
            found.append((family, outcome))
    if not found:
        return list(decided), count
    return _distinct([*found, *decided], pixel_range, MAX_BASINS + len(found)), count


__all__ = ["EXTRA_DESCENTS", "hidden_valleys", "valley_half_width_nm"]
