"""A broadband-only quadratic answer whose valley is narrower than the search's end scans: the ends
are scanned again at the deciding profile's own bin (decision 0145). This module sizes the answer's
valley; :func:`calib.wavelength.profile_search.hidden_valleys` scans and descends.

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

import numpy as np

from calib.wavelength.least_squares import Solution

#: At most this many of the fine grid's local minima are descended from.
EXTRA_DESCENTS = 1


def valley_half_width_nm(solution: Solution, delta_chi2: float) -> float:
    """The narrower end's half-width (nm) of ``solution``'s valley: the shift of one end of the
    profile (the middle following by half) that raises the cost by ``delta_chi2`` times the fit's
    reduced χ² (at least 1), by the fit's curvature ``JᵀJ`` (the quadratic family's parameters are
    the wavelengths at the ends and the middle)."""
    temper = solution.temper
    widths = []
    for curvature in end_curvatures(solution):
        widths.append(math.sqrt(delta_chi2 * temper / curvature) if curvature > 0 else math.inf)
    return min(widths)


def end_curvatures(solution: Solution) -> tuple[float, float]:
    """The cost's curvature (per nm²) for a shift of either end of the profile, the middle
    following by half, from the fit's ``JᵀJ``."""
    normal = solution.jacobian.T @ solution.jacobian
    blue, red = (
        float(direction @ normal @ direction)
        for direction in (np.array([1.0, 0.5, 0.0]), np.array([0.0, 0.5, 1.0]))
    )
    return blue, red


__all__ = ["EXTRA_DESCENTS", "end_curvatures", "valley_half_width_nm"]
