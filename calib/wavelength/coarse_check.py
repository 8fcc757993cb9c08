"""Whether the search's answer holds on the coarser profile it was found from (decision 0118).

An LED-only search (:func:`calib.wavelength.profile_search.search_profiles`, physical family) finds
its basins on the profile binned to :data:`~calib.wavelength.profile_search.GLOBAL_BIN_NM` and
decides between them on a finer one (:data:`~calib.wavelength.profile_search.REFINE_BIN_NM`), with
the same response model and camera prior. Both are views of one likelihood: where the model
describes the camera, the finer view's answer is also near the coarser view's minimum (it is the
same truth, better measured), a few χ² behind it at most. Where the camera prior's shape does not
describe the camera, the finer view's extra rows can pull the answer into a valley the coarser
view rejects — and the basins' Δχ² in the finer view, the only test the search had, then ranks
nothing that tells.

On the validation split (decision 0118) two predicted cameras' LED-only mappings were 5–6 nm off
at the red end with no warning: the Samsung Galaxy-S7-Edge prediction (no EXIF; its true basin
was the coarse view's best, and the finer view slid it to an incidence of −19° where the truth
is −4.7°, the truth's own point there 414 behind) and the Fujifilm X-A1 prediction (with EXIF:
the coarse view's best basin 17.6 nm from the answer, the truth between them). The coarse view put
both answers Δχ² 38 behind its best basin; of the right mappings whose coarse best basin lay more
than 1 nm away, none stood more than 13 behind it. (The X-A1 without EXIF, 5.7 behind, is caught by
the incidence's conflict with the rig prior instead: :func:`calib.wavelength.locate.locate_mapping`.)

This module states that test; the search carries the coarse view's best basin as a candidate, warns
(``mapping_ambiguous``) and widens σ to reach it when the test fails.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from calib.core.arrays import FloatArray

#: The coarser view's Δχ² (tempered by its best basin's reduced χ², at least 1) beyond which it
#: rejects the finer view's answer: 25, the search's own bar for a likelihood that describes the
#: data (:data:`calib.wavelength.profile_search.AMBIGUITY_DELTA_CHI2`, five σ for one parameter),
#: not a value tuned here. On the validation split (decision 0118: the LED-only scenes of the 44
#: leave-one-body-out cameras and 100 predicted ones, with and without EXIF, and 25 predicted ones
#: without) any value from 14 to 37 warns the same scenes: the right mappings (mean |Δλ| < 1 nm)
#: whose coarse best basin lies over 1 nm away stood at most 13 behind it, the two silent wrong ones
#: 38.


@dataclass(frozen=True)
class CoarseView:
    """The coarser view's best basin and how it rates the answer.

    Attributes
    ----------
    x
        The best basin's parameters (in the answer's family).
    delta_chi2
        How far behind that basin the coarser view puts the answer (tempered by the basin's reduced
        χ², at least 1).
    distance_nm
        RMS distance between the two mappings over the profile.
    rejects
        Whether the coarser view rejects the answer: ``delta_chi2`` above the threshold and the
        basin further than the minimum distance (else it is the same answer).
    """

    x: FloatArray
    delta_chi2: float
    distance_nm: float
    rejects: bool


def coarse_view(
    costs: Callable[[FloatArray], FloatArray],
    answer: FloatArray,
    basins: Sequence[tuple[FloatArray, int]],
    distance_nm: Callable[[FloatArray], float],
    *,
    min_distance_nm: float,
    threshold: float,
) -> CoarseView | None:
    """The coarser view's best basin and its verdict on ``answer`` (see the module docstring);
    ``None`` when no basin (or the answer) has a finite cost there.

    Parameters
    ----------
    costs
        The coarser view's cost of a batch of parameter vectors ``(K, P)`` (each at its own prior
        scale), ``inf`` where invalid.
    answer
        The search's answer ``(P,)``.
    basins
        The coarser view's basins: parameters and residual degrees of freedom (rows less
        parameters) of each.
    distance_nm
        RMS distance (nm) of a parameter vector's mapping from the answer's.
    min_distance_nm
        A basin closer than this is the same answer.
    threshold
        The Δχ² behind the best basin beyond which the coarser view rejects the answer: the
        search's own bar for a competing basin
        (:data:`calib.wavelength.profile_search.AMBIGUITY_DELTA_CHI2`).
    """
    if not basins:
        return None
    points = np.stack([np.asarray(answer, dtype=np.float64), *(x for x, _ in basins)])
    values = np.asarray(costs(points), dtype=np.float64)
    answer_cost, basin_costs = float(values[0]), values[1:]
    if not np.any(np.isfinite(basin_costs)) or not np.isfinite(answer_cost):
        return None
    best = int(np.argmin(basin_costs))
    best_cost = float(basin_costs[best])
    x, dof = basins[best]
    temper = max(best_cost / max(dof, 1), 1.0)
    delta = (answer_cost - best_cost) / temper
    apart = float(distance_nm(x))
    return CoarseView(
        np.asarray(x, dtype=np.float64),
        float(delta),
        apart,
        bool(delta > threshold and apart > min_distance_nm),
    )


__all__ = ["CoarseView", "coarse_view"]
