"""Whether a broadband-only quadratic mapping holds on the coarser profile its basins were found on
(decision 0133).

Decision 0118's test (:mod:`calib.wavelength.coarse_check`) for the physical family, applied to the
quadratic family (profiles whose origin is arbitrary, no grating prior: the paper's protocol,
``calib estimate`` with profile CSVs and no spot). There the search scans the profile's end
wavelengths on a 5 nm view, refines the grid's lowest minima on the profile binned to
:data:`~calib.wavelength.profile_search.GLOBAL_BIN_NM` with the stiff response (the coarse view),
decides between them with a flexible response on a finer profile, and refines the answer with the
stiff response on the finest. Two ways to a silent wrong answer were found on the validation split's
paper scenes (LED only, D65, 0.3 % noise; decision 0133):

- *The deciding stage leaves the coarse view's basin.* Nikon D1x (Kawakami), seed 2: the scan's best
  basin was the truth's (0.4 nm off); the deciding stage's local scan moved it 5 nm at the red end
  into a neighbouring minimum (its landscape has minima a few nanometres apart: the broadband
  profile's ripple against a response free to follow it). The coarse view puts that answer Δχ² 34
  behind the truth's basin, 2 nm (RMS) away.
- *The 5 nm scan never holds a point in the true basin.* Canon 5D (Kawakami), seed 3: the truth lies
  inside the scan's end grid, but the grid's points near it cost more than their neighbours on the
  5 nm view, so no minimum there was refined; the coarse view puts the answer (10 nm off at the red
  end) Δχ² 79 behind the truth's basin, 10 nm away.

Here the coarse view's best basin within the scan's own reach of the answer is found afresh — the
scan's end grid (:data:`~calib.wavelength.profile_search.QUADRATIC_SCAN`) about the answer on the
coarse view, one batched call, and a descent from its lowest point — and :func:`~calib.wavelength.
coarse_check.coarse_view` gives the verdict with the search's own bars (Δχ² :data:`~calib.wavelength.
profile_search.AMBIGUITY_DELTA_CHI2` tempered by the basin's reduced χ², beyond :data:`~calib.
wavelength.profile_search.AMBIGUITY_MIN_DISTANCE_NM`). Where the model describes the camera the
coarse view's best basin near the answer is the answer itself (right mappings on the validation
split stood up to Δχ² 53 behind it, but within 0.5 nm); both views are one likelihood at two
binnings with the same stiff response.

A rejected answer's rival is then weighed on the search's final stage (:func:`final_verdict`,
decision 0139): in both scenes above the rival, the truth's basin, fits the full-resolution profile
better by tempered Δχ² 330–340, and :func:`calib.wavelength.locate.locate_mapping` takes it as the
answer when that stage prefers it by the search's bar.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.spectra import WavelengthGrid
from calib.model.bases import CameraPrior
from calib.model.resolution import match_spectrometer
from calib.wavelength.coarse_check import CoarseView, coarse_view
from calib.wavelength.families import QuadraticFamily
from calib.wavelength.least_squares import Solution
from calib.wavelength.profile_search import (
    AMBIGUITY_DELTA_CHI2,
    AMBIGUITY_MIN_DISTANCE_NM,
    COARSE_NODES_NM,
    FINAL_BIN_NM,
    FINE_NODES_NM,
    FLEXIBILITY,
    GLOBAL_BIN_NM,
    GLOBAL_SIGMA_FLOOR,
    QUADRATIC_SCAN,
    StageFit,
    _quadratic_points,
    _spans_grid,
    _stage,
)


def _quadratic_stage(
    lamps: Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    answer: QuadraticMapping,
    *,
    kernel: FloatArray | None,
    bin_nm: float,
    node_step_nm: float,
    flexibility: float,
    sigma_floor: float,
    cut_ramps: bool = False,
) -> tuple[QuadraticFamily, tuple[float, float], StageFit]:
    """The quadratic family on the lead lamp's pixels, and one of the search's stages built as
    the search builds it at ``answer``'s dispersion (the lamps matched to it)."""
    lead = lamps[0]
    pixel_range = (float(lead.pixel[0]), float(lead.pixel[-1]))
    family = QuadraticFamily(pixel_range)
    spacing = float(np.median(np.diff(lead.pixel)))
    nm_per_px = float(np.median(np.abs(answer.dispersion_nm_per_px(lead.pixel)))) * spacing
    matched = [match_spectrometer(lamp, nm_per_px) for lamp in lamps]
    stage = _stage(
        matched,
        family,
        grid,
        prior,
        bin_nm=bin_nm,
        nm_per_px=nm_per_px,
        kernel=kernel,
        node_step_nm=node_step_nm,
        flexibility=flexibility,
        sigma_floor=sigma_floor,
        pixel_range=pixel_range,
        cut_ramps=cut_ramps,
    )
    return family, pixel_range, stage


def quadratic_coarse_view(
    lamps: Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    answer: QuadraticMapping,
    *,
    kernel: FloatArray | None,
    scan: tuple[float, float] = QUADRATIC_SCAN,
) -> tuple[CoarseView | None, int]:
    """The coarse view's basin about ``answer`` and its verdict on it (see the module docstring).

    Parameters
    ----------
    lamps
        The broadband lamps the search mapped with (one pixel frame).
    prior
        The camera prior the search used.
    grid
        The working grid.
    answer
        The search's answer (quadratic family).
    kernel
        The camera's line spread in profile samples, as the search used it.
    scan
        Half width and step (nm) of the end grid about the answer.

    Returns
    -------
    tuple
        The verdict (``None`` when the coarse view costs nothing finite there) and the coarse
        view's evaluations made.
    """
    family, pixel_range, view = _quadratic_stage(
        lamps,
        prior,
        grid,
        answer,
        kernel=kernel,
        bin_nm=GLOBAL_BIN_NM,
        node_step_nm=COARSE_NODES_NM,
        flexibility=FLEXIBILITY,
        sigma_floor=GLOBAL_SIGMA_FLOOR,
    )
    x = family.parameters(answer)
    points, _ = _quadratic_points(answer, family, scan)
    costs = view.costs(points)
    if not np.any(np.isfinite(costs)):
        return None, points.shape[0]
    basin = view.sketch(points[int(np.argmin(costs))])
    evaluations = points.shape[0] + basin.evaluations + 2
    probe = np.linspace(pixel_range[0], pixel_range[1], 64)
    answer_nm = answer.wavelength_nm(probe)

    def distance(other: FloatArray) -> float:
        return float(np.sqrt(np.mean((family.wavelengths(probe, other) - answer_nm) ** 2)))

    verdict = coarse_view(
        view.costs,
        x,
        [(basin.x, basin.dof)],
        distance,
        min_distance_nm=AMBIGUITY_MIN_DISTANCE_NM,
        threshold=AMBIGUITY_DELTA_CHI2,
    )
    return verdict, evaluations


@dataclass(frozen=True)
class FinalVerdict:
    """The final stage's word on the coarse view's rival (decision 0139).

    Attributes
    ----------
    rival
        The final stage's descent from the coarse view's basin (as the search's final fit: its
        covariance is the search's).
    rival_cost, answer_cost
        The rival's and the search's answer's costs on that stage, each at its own prior scale.
    temper
        The leader's reduced χ² on that stage (at least 1).
    delta_chi2
        How far behind the rival the answer stands there, tempered (negative: the answer leads).
    adopts
        The rival fits better by more than the search's bar
        (:data:`~calib.wavelength.profile_search.AMBIGUITY_DELTA_CHI2`) and spans the grid.
    evaluations
        The final stage's evaluations made.
    """

    rival: Solution
    rival_cost: float
    answer_cost: float
    temper: float
    delta_chi2: float
    adopts: bool
    evaluations: int


def final_verdict(
    lamps: Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    answer: QuadraticMapping,
    rival: FloatArray,
    *,
    kernel: FloatArray | None,
) -> FinalVerdict | None:
    """The coarse view's rival (``rival``, quadratic family parameters) refined on the search's
    final stage — the profile at :data:`~calib.wavelength.profile_search.FINAL_BIN_NM`, the stiff
    response on :data:`~calib.wavelength.profile_search.FINE_NODES_NM` nodes, the search's own
    descent and stop — and weighed against ``answer`` there (decision 0139). Both views are one
    likelihood; the final one is the finest, the one the search's answer was refined on. The rival
    is adopted when the answer stands more than the search's bar behind it (tempered by the
    leader's reduced χ², at least 1) and it spans the grid (the search's rule for an answer).
    ``None`` when the rival's descent fails."""
    family, pixel_range, final = _quadratic_stage(
        lamps,
        prior,
        grid,
        answer,
        kernel=kernel,
        bin_nm=FINAL_BIN_NM,
        node_step_nm=FINE_NODES_NM,
        flexibility=FLEXIBILITY,
        sigma_floor=0.0,
        cut_ramps=True,
    )
    solution = final.settle(rival)
    costs = final.costs(np.vstack([solution.x, family.parameters(answer)]))
    evaluations = solution.evaluations + 2
    rival_cost, answer_cost = float(costs[0]), float(costs[1])
    if not (math.isfinite(rival_cost) and math.isfinite(answer_cost)):
        return None
    temper = max(min(rival_cost, answer_cost) / solution.dof, 1.0)
    delta = (answer_cost - rival_cost) / temper
    adopts = delta > AMBIGUITY_DELTA_CHI2 and _spans_grid(
        family.mapping(solution.x), pixel_range, grid
    )
    return FinalVerdict(solution, rival_cost, answer_cost, temper, delta, adopts, evaluations)


__all__ = ["FinalVerdict", "final_verdict", "quadratic_coarse_view"]
