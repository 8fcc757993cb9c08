"""The pixel→wavelength mapping search as it was before issue 16 — the benchmarks' "before" column.

Kept only as the baseline that ``bench/wavelength_loco.py``, ``bench/wavelength_speed.py`` and
``bench/tune_mapping.py`` measure the product against; **not part of the product**: calib finds
mappings with :func:`calib.wavelength.locate.locate_mapping` (whole profiles:
:func:`calib.wavelength.profile_search.search_profiles`). It imports the pieces it shares with that
engine (the response prior, pixel binning, fluorescent starts and the stage constants) from calib,
so the baseline moves with them.

As it was documented:


Makabe et al. (2025, §3.2) match peaks for a fluorescent lamp and run point-to-plane ICP between the
normalised profile and ``ŝ ⊙ e`` for an LED (Eq. 15, 500 iterations from a flat start). Both compare
the profile with the *mean* camera, so a camera unlike the mean biases the mapping (the paper reports
2.1–2.3 % mapping RE with an LED). Here every stage fits the profile itself with a model

    m_c(p) = ∫_pixel e(λ) r_c(λ) dλ,

the lamp ``e`` (its measured spectrum, at 1 nm) times a per-channel response ``r_c = η s_c`` that is
linear between nodes and found by (penalised) least squares for every trial mapping — variable
projection over the mapping ``(a, b, c)``. What differs between stages is how much the response may
bend:

1. Starts: a fluorescent lamp's lines, found in its measured spectrum, matched to the profile's peaks
   (several hypotheses); a broadband lamp's normalised cross-correlation with ``ŝ ⊙ e`` over linear
   mappings; or starts given by the caller (e.g. from the grating's geometry).
2. Global: the response follows a Gaussian camera prior (:class:`calib.model.bases.CameraPrior`, widened by
   a smooth grating efficiency and a small smooth deviation); on a binned profile, the wavelengths at
   both ends are scanned on a grid around each start and the best grid points refined. The prior
   gives the cost a clear global minimum where a free response would absorb a wrong mapping.
3. Local: on the full profile, 10 nm nodes and a response whose smooth deviation from the prior has
   a σ of twice the channel's peak (:data:`LOCAL_FLEXIBILITY`): the global stage's distinct
   minima are refined and the lowest cost wins, so a camera outside the prior's span does not pick
   the basin; the lamp's fine structure (lines, the blue LED peak, D65's absorption features) pins
   the mapping. Then 5 nm nodes (with the global stage's prior) refine it. All three channels share
   one mapping.

A broadband lamp's profile has aliases (see :data:`LOCAL_FLEXIBILITY`): when the local costs of
competing basins are close, the mapping's error estimate includes their spread
(:func:`basin_spread_nm`) as well as the final fit's covariance.

The response lives on the working range plus margins beyond it that are separate pieces (a camera known
only on 400–700 nm is zero beyond; a real one is not: both are representable).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import (
    GratingGeometry,
    QuadraticMapping,
    TiltedGrating,
    wavelength_rms_from_covariance,
)
from calib.core.observations import LampObservation, profile_sigma
from calib.core.spectra import WavelengthGrid
from calib.model.bases import CameraPrior
from calib.model.forward import (
    PiecewiseLinearDensity,
    apply_blur,
    fine_axis,
    pixel_edges,
)
from calib.model.resolution import camera_kernel, match_spectrometer
from calib.wavelength.peaks import (
    coarse_mapping_candidates,
    fluorescent_starts,
    model_curve_on_fine_axis,
    refine_mapping,
)
from calib.wavelength.profile_search import (
    COARSE_NODES_NM,
    FINE_NODES_NM,
    FLEXIBILITY,
    GLOBAL_BIN_NM,
    GLOBAL_SIGMA_FLOOR,
    LOCAL_FLEXIBILITY,
    bin_pixels,
    binned_kernel,
)
from calib.wavelength.response_model import MARGIN_SMOOTHNESS, MODEL_ERROR, response_prior

Mapping = QuadraticMapping | GratingGeometry | TiltedGrating
AnyMapping = TypeVar("AnyMapping", QuadraticMapping, TiltedGrating)

#: Light is modelled this far beyond the working range (where the lamp spectrum reaches).
MARGIN_NM = 30.0
#: (half width, step) in nm of the scan of the ends' wavelengths, per kind of start.
SCAN_BROADBAND = (20.0, 4.0)
SCAN_LINES = (9.0, 3.0)
#: NCC candidates scanned, and grid points refined at the global stage.
SCANNED_STARTS = 2
FLUORESCENT_STARTS = 3
REFINED_POINTS = 3
#: Least-squares tolerances of the intermediate stages and of the final one.
INTERMEDIATE_TOLERANCE = 1e-6
FINAL_TOLERANCE = 1e-9
#: Distinct global minima carried into the local stages.
LOCAL_FINALISTS = 2


def _segment_hats(axis_nm: FloatArray, nodes_nm: FloatArray) -> FloatArray:
    """Hat functions of ``nodes`` on ``axis``, cut at the first and last node: ``(n_axis, n_nodes)``."""
    step = float(nodes_nm[1] - nodes_nm[0]) if nodes_nm.size > 1 else 1.0
    hats = np.clip(1.0 - np.abs(axis_nm[:, None] - nodes_nm[None, :]) / step, 0.0, None)
    outside = (axis_nm < nodes_nm[0] - 1e-9) | (axis_nm > nodes_nm[-1] + 1e-9)
    hats[outside] = 0.0
    return hats


def _second_differences(size: int) -> FloatArray:
    matrix = np.zeros((max(size - 2, 0), size))
    for row in range(size - 2):
        matrix[row, row : row + 3] = (1.0, -2.0, 1.0)
    return matrix


def _block_diagonal(blocks: Sequence[FloatArray], widths: Sequence[int]) -> FloatArray:
    """Place ``blocks`` (rows × width) along the diagonal of a ``(Σ rows, Σ widths)`` matrix."""
    out = np.zeros((sum(b.shape[0] for b in blocks), sum(widths)))
    row = col = 0
    for block, width in zip(blocks, widths, strict=True):
        out[row : row + block.shape[0], col : col + width] = block
        row += block.shape[0]
        col += width
    return out


@dataclass(frozen=True, eq=False)
class ResponseFit:
    """The profile explained by the lamp times a per-channel response (see the module docstring).

    Attributes
    ----------
    observation
        The (possibly binned) lamp observation whose profile is fitted.
    densities
        Per piece, ``e·φ_j`` for its nodes ``j`` on a 1 nm axis spanning the piece.
    nodes_nm
        Node wavelengths ``(N,)``: margin pieces and the working range.
    working
        Indices of the working range's nodes.
    difference
        Second differences of the margin pieces, ``(rows, N)``.
    smoothness
        Weight of ``difference`` relative to the data's own scale.
    prior_mean, prior_factor
        The response's Gaussian prior on the working nodes (``(n_w, 3)`` and ``(3, n_w, n_w)``, see
        :func:`response_prior`).
    sigma
        Profile σ ``(n, 3)``.
    kernel
        Blur along the pixels (slit image, PSF), or ``None``.
    edges_px
        Pixel edges ``(n + 1,)``.
    """

    observation: LampObservation
    densities: tuple[PiecewiseLinearDensity, ...]
    nodes_nm: FloatArray
    working: NDArray[np.intp]
    difference: FloatArray
    smoothness: float
    prior_mean: FloatArray
    prior_factor: FloatArray
    sigma: FloatArray
    kernel: FloatArray | None
    edges_px: FloatArray

    @classmethod
    def build(
        cls,
        observation: LampObservation,
        grid: WavelengthGrid,
        *,
        node_step_nm: float,
        prior: CameraPrior,
        flexibility: float = 0.0,
        smoothness: float = MARGIN_SMOOTHNESS,
        kernel: FloatArray | None = None,
        margin_nm: float = MARGIN_NM,
        sigma_floor: float = 0.0,
    ) -> ResponseFit:
        """The fit of one lamp's profile with a camera-prior response on ``node_step_nm`` nodes.

        The working range's response follows :func:`response_prior` (with ``flexibility``); the
        margins' by a second-difference penalty of weight ``smoothness``. ``sigma_floor``
        (a fraction of the profile's peak) tempers the weights: the global search looks for the
        right basin, which very precise data make too narrow to find on a grid.
        """
        lamp = observation.spectrum
        lo = max(grid.start_nm - margin_nm, lamp.range_nm[0])
        hi = min(grid.stop_nm + margin_nm, lamp.range_nm[1])
        if lo > grid.start_nm or hi < grid.stop_nm:
            raise InputError(
                f"lamp spectrum covers {lamp.range_nm[0]:g}–{lamp.range_nm[1]:g} nm but the grid "
                f"needs {grid.start_nm:g}–{grid.stop_nm:g} nm",
                source=lamp.name,
            )
        if prior.grid != grid:
            raise InputError(
                f"the camera prior is on grid {prior.grid}, not {grid}", source="prior"
            )
        count = round((grid.stop_nm - grid.start_nm) / node_step_nm)
        working_nodes = grid.start_nm + node_step_nm * np.arange(count + 1.0)
        pieces: list[FloatArray] = []
        if grid.start_nm - lo >= node_step_nm:
            n_left = int((grid.start_nm - lo) // node_step_nm)
            pieces.append(grid.start_nm - node_step_nm * np.arange(n_left, -1, -1.0))
        first_working = sum(piece.size for piece in pieces)
        pieces.append(working_nodes)
        if hi - grid.stop_nm >= node_step_nm:
            n_right = int((hi - grid.stop_nm) // node_step_nm)
            pieces.append(grid.stop_nm + node_step_nm * np.arange(0, n_right + 1.0))
        # One density per piece on its own axis, so each piece ends sharply at its boundary (a
        # shared 1 nm axis would ramp a cut hat over the last nanometre).
        densities = tuple(
            PiecewiseLinearDensity.on_axis(
                axis, lamp.at(axis)[:, None] * _segment_hats(axis, piece)
            )
            for piece in pieces
            for axis in (fine_axis(piece[0], piece[-1]),)
        )
        smooth_blocks = [
            np.zeros((0, piece.size)) if piece is working_nodes else _second_differences(piece.size)
            for piece in pieces
        ]
        prior_mean, prior_factor = response_prior(prior, working_nodes, flexibility)
        return cls(
            observation=observation,
            densities=densities,
            nodes_nm=np.concatenate(pieces),
            working=np.arange(first_working, first_working + working_nodes.size),
            difference=_block_diagonal(smooth_blocks, [piece.size for piece in pieces]),
            smoothness=smoothness,
            prior_mean=prior_mean,
            prior_factor=prior_factor,
            sigma=np.maximum(
                np.hypot(profile_sigma(observation), MODEL_ERROR * np.abs(observation.profile)),
                sigma_floor * float(np.max(observation.profile)),
            ),
            kernel=kernel,
            edges_px=pixel_edges(observation.pixel),
        )

    def _pixel_matrix(self, mapping: Mapping) -> FloatArray:
        edges_nm = mapping.wavelength_nm(self.edges_px)
        matrix = np.hstack([piece.integrate_pixels(edges_nm) for piece in self.densities])
        return apply_blur(matrix, self.kernel)

    def residual(self, mapping: Mapping) -> FloatArray:
        """Weighted data residual, penalty rows and prior rows, flattened (least squares over the mapping)."""
        weights = 1.0 / self.sigma
        pixel_matrix = self._pixel_matrix(mapping)
        weighted = pixel_matrix[None, :, :] * weights.T[:, :, None]  # (3, n, N)
        target = (weights * self.observation.profile).T  # (3, n)
        transposed = weighted.transpose(0, 2, 1)
        normal = transposed @ weighted
        rhs = (transposed @ target[:, :, None])[..., 0]
        size = self.nodes_nm.size
        scale = np.maximum(np.trace(normal, axis1=1, axis2=2) / size, 1e-300)
        lambdas = self.smoothness * scale
        normal = normal + lambdas[:, None, None] * (self.difference.T @ self.difference)[None]
        response, prior_rows = self._solve_with_prior(weighted, target, normal, rhs)
        fitted = (weighted @ response[:, :, None])[..., 0]
        penalty_rows = np.sqrt(lambdas)[:, None] * (response @ self.difference.T)
        return np.concatenate([(target - fitted).ravel(), penalty_rows.ravel(), prior_rows.ravel()])

    def _solve_with_prior(
        self, weighted: FloatArray, target: FloatArray, normal: FloatArray, rhs: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Response ``(3, N)`` and prior rows ``(3, n_w)`` with the camera scale ``β`` eliminated."""
        working = self.working
        size = self.nodes_nm.size
        mean = np.zeros((3, size))
        mean[:, working] = self.prior_mean.T
        # β̂: the scale of the mean camera that best explains the profile; it sets the prior's width.
        predicted = (weighted @ mean[:, :, None])[..., 0]
        scale_hat = float(np.sum(predicted * target)) / max(float(np.sum(predicted**2)), 1e-300)
        if not np.isfinite(scale_hat) or scale_hat <= 0:
            scale_hat = 1.0
        factor = np.zeros((3, working.size, size))
        factor[:, :, working] = self.prior_factor / scale_hat
        precision = factor.transpose(0, 2, 1) @ factor
        system = normal + precision
        pulled = (precision @ mean[:, :, None])[..., 0]
        solved = _solve_batched(system, np.stack([rhs, pulled], axis=2))
        free, along = solved[..., 0], solved[..., 1]
        denominator = float(np.sum(mean * pulled) - np.sum(pulled * along))
        beta = float(np.sum(pulled * free)) / denominator if abs(denominator) > 1e-300 else 0.0
        response = free + beta * along
        prior_rows = (factor @ (response - beta * mean)[:, :, None])[..., 0]
        return response, prior_rows

    def cost(self, mapping: Mapping) -> float:
        return float(np.sum(self.residual(mapping) ** 2))


@dataclass(frozen=True, eq=False)
class JointFit:
    """Several lamps seen in one geometry: their fits' residuals concatenated (one shared mapping).

    Each lamp keeps its own response (they differ by the lamp's brightness and its spectrum's reach);
    what they share is where each wavelength lands.
    """

    fits: tuple[ResponseFit, ...]

    def residual(self, mapping: Mapping) -> FloatArray:
        return np.concatenate([fit.residual(mapping) for fit in self.fits])

    def cost(self, mapping: Mapping) -> float:
        return float(sum(fit.cost(mapping) for fit in self.fits))


def _solve_batched(systems: FloatArray, rhs: FloatArray) -> FloatArray:
    try:
        return np.asarray(np.linalg.solve(systems, rhs), dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.stack(
            [np.linalg.lstsq(systems[c], rhs[c], rcond=None)[0] for c in range(systems.shape[0])]
        )


def _anchors(pixel_range: tuple[float, float]) -> FloatArray:
    return np.array([pixel_range[0], 0.5 * (pixel_range[0] + pixel_range[1]), pixel_range[1]])


def scan_ends(
    start: QuadraticMapping,
    fit: JointFit,
    pixel_range: tuple[float, float],
    *,
    half_width_nm: float,
    step_nm: float,
) -> list[tuple[float, QuadraticMapping]]:
    """Costs of a grid of shifts of the wavelengths at both ends of ``pixel_range`` (middle follows).

    Returns the grid's local minima as ``(cost, mapping)``, lowest first.
    """
    anchors = _anchors(pixel_range)
    design = np.stack([anchors**2, anchors, np.ones(3)], axis=1)
    base = start.wavelength_nm(anchors)
    shifts = np.arange(-half_width_nm, half_width_nm + 0.5 * step_nm, step_nm)
    costs = np.full((shifts.size, shifts.size), np.inf)
    trials: dict[tuple[int, int], QuadraticMapping] = {}
    for i, left in enumerate(shifts):
        for j, right in enumerate(shifts):
            a, b, c = np.linalg.solve(design, base + np.array([left, 0.5 * (left + right), right]))
            trial = QuadraticMapping(float(a), float(b), float(c), pixel_range=pixel_range)
            if np.any(trial.dispersion_nm_per_px(anchors) <= 0):
                continue
            costs[i, j] = fit.cost(trial)
            trials[(i, j)] = trial
    minima: list[tuple[float, QuadraticMapping]] = []
    for (i, j), trial in trials.items():
        window = costs[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2]
        if costs[i, j] <= window.min():
            minima.append((float(costs[i, j]), trial))
    minima.sort(key=lambda item: item[0])
    return minima


def broadband_starts(
    observation: LampObservation,
    mean_sensitivity: FloatArray,
    grid: WavelengthGrid,
    n_candidates: int,
) -> list[QuadraticMapping]:
    """Linear starting mappings of a broadband lamp from the correlation search (best first)."""
    axis, model = model_curve_on_fine_axis(observation.spectrum, mean_sensitivity, grid)
    return coarse_mapping_candidates(
        observation.pixel,
        observation.profile,
        axis,
        model,
        grid=grid,
        n_candidates=n_candidates,
        n_dispersions=96,
    )


def _first_broadband(lamps: Sequence[LampObservation]) -> LampObservation:
    return next((lamp for lamp in lamps if lamp.kind != "fluorescent"), lamps[0])


def _line_starts_or_none(
    lamp: LampObservation, prior: CameraPrior, grid: WavelengthGrid
) -> list[QuadraticMapping]:
    try:
        return fluorescent_starts(lamp, prior.mean, grid, FLUORESCENT_STARTS)
    except EstimationError:
        return []


def _refine(
    start: QuadraticMapping,
    fit: JointFit,
    pixel_range: tuple[float, float],
    method: str,
    max_evaluations: int,
    *,
    final: bool = False,
) -> tuple[QuadraticMapping, float]:
    return refine_mapping(
        start,
        fit.residual,
        pixel_range=pixel_range,
        method=method,
        max_evaluations=max_evaluations,
        step_nm=1e-3,
        tolerance=FINAL_TOLERANCE if final else INTERMEDIATE_TOLERANCE,
    )


@one_blas_thread
def search_mapping(
    observations: LampObservation | Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    *,
    starts: Sequence[QuadraticMapping] | None = None,
    kernel: FloatArray | None = None,
    local_flexibility: float = LOCAL_FLEXIBILITY,
) -> QuadraticMapping:
    """The pixel→wavelength mapping shared by one or more lamps' profiles (see the module docstring).

    Parameters
    ----------
    observations
        The lamps, all in one geometry (one pixel frame). Starts come from the first fluorescent
        lamp's lines if there is one, else from the first lamp's correlation search; every lamp's
        profile enters the fits.
    prior
        The camera prior (mean ŝ and covariance) on ``grid``.
    grid
        Working grid; the mapping must cover it.
    starts
        Starting mappings to use instead of the first stage (e.g. from the grating's geometry).
    kernel
        The camera's line spread in profile samples, modelled in every fit; default: the lamps'
        measured one (:func:`calib.model.resolution.camera_kernel`). Profiles measured with a spectrometer
        broader than the camera are blurred to match (:func:`calib.model.resolution.match_spectrometer`).
    local_flexibility
        The first local stage's response flexibility (:data:`LOCAL_FLEXIBILITY`;
        ``bench/tune_mapping.py`` compares values).

    Returns
    -------
    QuadraticMapping
        With ``covariance``/``wavelength_rms_nm`` from the final fit and the search in ``details``.
    """
    lamps = [observations] if isinstance(observations, LampObservation) else list(observations)
    if not lamps:
        raise InputError("no lamp observations to find the mapping with", source="observations")
    frames = {(lamp.pixel[0], lamp.pixel[-1], lamp.n_pixels) for lamp in lamps}
    if len(frames) != 1:
        raise InputError(
            "the lamps' profiles are on different pixel axes; extract them with one geometry",
            source="observations",
        )
    lead = next((lamp for lamp in lamps if lamp.kind == "fluorescent"), lamps[0])
    pixel_range = (float(lead.pixel[0]), float(lead.pixel[-1]))
    if starts:
        candidates = list(starts)
        origin = "given start"
    elif lead.kind == "fluorescent":
        # Line matching can fail at low signal; a broadband lamp's correlation search is a second
        # opinion, and the joint fit decides.
        candidates = _line_starts_or_none(lead, prior, grid)
        broadband = _first_broadband(lamps)
        if broadband.kind != "fluorescent":
            candidates += broadband_starts(broadband, prior.mean, grid, 1)
        origin = f"lines of {lead.name}"
    else:
        candidates = broadband_starts(lead, prior.mean, grid, SCANNED_STARTS)
        origin = f"correlation search on {lead.name}"
    if not candidates:
        raise EstimationError(f"no starting mapping for lamp {lead.name!r}")
    method = f"{origin}+profile fit"

    def joint_fit(
        factor: int,
        node_step_nm: float,
        stage_kernel: FloatArray | None,
        sigma_floor: float = 0.0,
        flexibility: float = FLEXIBILITY,
    ) -> JointFit:
        return JointFit(
            tuple(
                ResponseFit.build(
                    bin_pixels(lamp, factor),
                    grid,
                    node_step_nm=node_step_nm,
                    prior=prior,
                    flexibility=flexibility,
                    kernel=stage_kernel,
                    sigma_floor=sigma_floor,
                )
                for lamp in lamps
            )
        )

    # Global stage: binned profiles, a grid of the ends' wavelengths around every start. Profiles
    # are first brought to their spectrometer's resolution (through the starts' dispersion).
    spacing = float(np.median(np.diff(lead.pixel)))
    dispersion = float(np.median(np.abs(candidates[0].dispersion_nm_per_px(lead.pixel))))
    if kernel is None:
        kernel = camera_kernel(lamps)
    lamps = [match_spectrometer(lamp, dispersion * spacing) for lamp in lamps]
    lead = next((lamp for lamp in lamps if lamp.kind == "fluorescent"), lamps[0])
    factor = max(1, int(GLOBAL_BIN_NM / max(dispersion * spacing, 1e-9)))
    global_fit = joint_fit(
        factor,
        COARSE_NODES_NM,
        None if kernel is None else binned_kernel(kernel, factor),
        GLOBAL_SIGMA_FLOOR,
    )
    if lead.pixel_origin == "direct_spot" and not starts:
        return _physical_search(
            lamps, candidates, global_fit, joint_fit, kernel, pixel_range, grid, origin
        )
    # The scan looks at each start's own lamp only (half the cost with two lamps); the refinement
    # of its best points uses every lamp.
    points: list[tuple[float, QuadraticMapping]] = []
    for candidate in candidates:
        from_lines = candidate.method == "fluorescent-peaks" or bool(starts)
        half_width, step = SCAN_LINES if from_lines else SCAN_BROADBAND
        scan_lamp = lead if from_lines or len(lamps) == 1 else _first_broadband(lamps)
        scan_fit = JointFit((global_fit.fits[lamps.index(scan_lamp)],))
        start = QuadraticMapping(candidate.a, candidate.b, candidate.c, pixel_range=pixel_range)
        for _, point in scan_ends(
            start, scan_fit, pixel_range, half_width_nm=half_width, step_nm=step
        )[:REFINED_POINTS]:
            points.append((global_fit.cost(point), point))
    points.sort(key=lambda item: item[0])
    refined = [
        _refine(point, global_fit, pixel_range, method, max_evaluations=40)
        for _, point in points[:REFINED_POINTS]
    ]
    refined.sort(key=lambda item: item[1])
    global_cost = refined[0][1]
    finalists = _distinct([mapping for mapping, _ in refined], pixel_range, LOCAL_FINALISTS)

    # Local stages on the full profiles: 10 nm nodes and a flexible response choose between the
    # finalists, 5 nm nodes remove the coarse representation's bias.
    coarse_fit = joint_fit(1, COARSE_NODES_NM, kernel, flexibility=local_flexibility)
    outcomes = [
        _refine(finalist, coarse_fit, pixel_range, method, max_evaluations=100)
        for finalist in finalists
    ]
    best, _ = min(outcomes, key=lambda item: item[1])
    best, cost = _refine(
        best,
        joint_fit(1, FINE_NODES_NM, kernel),
        pixel_range,
        method,
        100,
        final=True,
    )
    spread_nm = basin_spread_nm(best, outcomes, pixel_range)
    covers = best.wavelength_nm(np.array(pixel_range))
    tolerance = (
        0.5 * grid.step_nm
    )  # an end node half a step outside is still constrained by its neighbours
    if covers.min() > grid.start_nm + tolerance or covers.max() < grid.stop_nm - tolerance:
        raise EstimationError(
            f"the best mapping puts the profile at {covers.min():.0f}–{covers.max():.0f} nm, not "
            f"covering the grid {grid.start_nm:g}–{grid.stop_nm:g} nm: does the profile hold the "
            "whole first order?"
        )
    return best.with_details(
        details={
            **dict(best.details),
            "mapping_lamps": [lamp.name for lamp in lamps],
            "origin": origin,
            "n_starts": len(candidates),
            "global_bin": factor,
            "global_cost": global_cost,
            "final_cost": cost,
            "finalist_costs": [c for _, c in outcomes],
            "basin_spread_nm": spread_nm,
            "flexibility": FLEXIBILITY,
            "local_flexibility": local_flexibility,
        },
        wavelength_rms_nm=None
        if best.wavelength_rms_nm is None
        else math.hypot(best.wavelength_rms_nm, spread_nm),
    )


def _distinct(
    mappings: Sequence[AnyMapping], pixel_range: tuple[float, float], count: int
) -> list[AnyMapping]:
    """The first ``count`` of ``mappings`` that differ from every earlier one by > 1 nm somewhere."""
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)
    chosen: list[AnyMapping] = []
    for mapping in mappings:
        if all(
            np.max(np.abs(mapping.wavelength_nm(probe) - other.wavelength_nm(probe))) > 1.0
            for other in chosen
        ):
            chosen.append(mapping)
        if len(chosen) == count:
            break
    return chosen


def basin_spread_nm(
    best: QuadraticMapping,
    outcomes: Sequence[tuple[QuadraticMapping, float]],
    pixel_range: tuple[float, float],
) -> float:
    """RMS wavelength distance (nm) of ``best`` from competing basins, weighted by their evidence.

    ``outcomes`` are the local stage's ``(mapping, cost)``; the cost is a χ², so a basin whose cost
    exceeds the lowest by ``Δ`` carries a relative weight ``exp(−Δ/2)``. The weighted mean squared
    distance of ``g(p)`` from ``best`` over ``pixel_range`` is the error that a choice between
    near-equal basins adds to the covariance's local one: near zero when one basin is clearly
    best, the basins' separation when the profile cannot tell them apart.
    """
    if not outcomes:
        return 0.0
    costs = np.array([cost for _, cost in outcomes])
    weights = np.exp(-0.5 * (costs - costs.min()))
    pixels = np.linspace(pixel_range[0], pixel_range[1], 64)
    squared = np.array(
        [np.mean((m.wavelength_nm(pixels) - best.wavelength_nm(pixels)) ** 2) for m, _ in outcomes]
    )
    return float(np.sqrt(np.sum(weights * squared) / np.sum(weights)))


# ------------------------------------------------------------------------- grating physics


#: Relative range and number of the dispersions scanned around the start's, and the focal lengths
#: (pixels: wide-angle to telephoto at typical pitches) that set the physical curvature.
PHYSICAL_DISPERSION_RANGE = (0.75, 1.33)
PHYSICAL_DISPERSION_STEPS = 57
PHYSICAL_FOCAL_LENGTHS_PX = (1500.0, 4000.0, 15000.0)
#: Bound on the angle of incidence on the grating, and the spread of its (Gaussian) prior, degrees:
#: set-ups align the grating sheet roughly parallel to the sensor (Makabe et al. 2025, §4.2).
MAX_INCIDENCE_DEG = 40.0
INCIDENCE_SIGMA_DEG = 5.0


def _physical(parameters: FloatArray) -> TiltedGrating:
    log_dispersion, log_focal, incidence = parameters
    return TiltedGrating(float(np.exp(log_dispersion)), float(np.exp(log_focal)), float(incidence))


def _refine_physical(
    start: TiltedGrating, fit: JointFit, max_evaluations: int, *, final: bool = False
) -> tuple[TiltedGrating, float, FloatArray | None]:
    """Least squares over ``(log d/F, log F, θ)``; returns the grating, the cost and ``cov(θ)``."""
    from scipy import optimize

    x0 = np.array(
        [math.log(start.dispersion_nm_per_px), math.log(start.focal_length_px), start.incidence_deg]
    )
    tolerance = FINAL_TOLERANCE if final else INTERMEDIATE_TOLERANCE
    solution = optimize.least_squares(
        # A soft prior on the angle of incidence: rigs align the grating roughly square to the lens.
        lambda x: np.append(fit.residual(_physical(x)), x[2] / INCIDENCE_SIGMA_DEG),
        x0,
        diff_step=np.array([1e-6, 1e-4, 1e-4]),
        bounds=(
            [-np.inf, math.log(200.0), -MAX_INCIDENCE_DEG],
            [np.inf, math.log(1e6), MAX_INCIDENCE_DEG],
        ),
        max_nfev=max_evaluations,
        ftol=tolerance,
        xtol=tolerance,
        gtol=tolerance,
    )
    cost = float(np.sum(solution.fun**2))
    covariance = None
    if final:
        dof = max(solution.fun.size - 3, 1)
        covariance = np.linalg.pinv(solution.jac.T @ solution.jac) * cost / dof
    return _physical(solution.x), cost, covariance


def _physical_search(
    lamps: Sequence[LampObservation],
    candidates: Sequence[QuadraticMapping],
    global_fit: JointFit,
    joint_fit: Any,
    kernel: FloatArray | None,
    pixel_range: tuple[float, float],
    grid: WavelengthGrid,
    origin: str,
) -> QuadraticMapping:
    """The mapping within the grating's physical family, for pixels measured from the 0th order.

    ``λ(p) = d [sin(θ + atan(p/F)) − sin θ]`` (:class:`calib.core.mapping.TiltedGrating`) has ``λ(0) = 0``:
    only the dispersion and a small curvature are free, so a shift of the whole rainbow — which a
    camera unlike the prior can otherwise trade against the response's shape — is ruled out.
    A scan over the dispersion (and a few focal lengths) on binned profiles, refinement of the best
    points, then the local stages, all in that family; the result is returned as its quadratic over
    the profile (the difference is a small fraction of a nanometre).
    """
    middle = 0.5 * (pixel_range[0] + pixel_range[1])
    nominal = float(
        np.median([c.wavelength_nm(np.array([middle]))[0] / middle for c in candidates])
    )
    scale = nominal * np.geomspace(*PHYSICAL_DISPERSION_RANGE, PHYSICAL_DISPERSION_STEPS)
    points: list[tuple[float, TiltedGrating]] = []
    for focal in PHYSICAL_FOCAL_LENGTHS_PX:
        costs = []
        for dispersion in scale:
            # At this focal length, the dispersion that puts the profile's middle where the
            # small-angle guess does (so the scan is over wavelengths, whatever the curvature).
            trial = TiltedGrating(float(dispersion), focal)
            correction = (
                dispersion * middle / max(float(trial.wavelength_nm(np.array([middle]))[0]), 1e-9)
            )
            trial = TiltedGrating(float(dispersion * correction), focal)
            costs.append((global_fit.cost(trial), trial))
        values = np.array([c for c, _ in costs])
        for index in range(values.size):
            window = values[max(index - 1, 0) : index + 2]
            if values[index] <= window.min():
                points.append(costs[index])
    points.sort(key=lambda item: item[0])
    refined = [
        _refine_physical(point, global_fit, max_evaluations=40)[:2]
        for _, point in points[:REFINED_POINTS]
    ]
    refined.sort(key=lambda item: item[1])
    finalists = _distinct([mapping for mapping, _ in refined], pixel_range, LOCAL_FINALISTS)
    coarse_fit = joint_fit(1, COARSE_NODES_NM, kernel)
    outcomes = [_refine_physical(finalist, coarse_fit, 100)[:2] for finalist in finalists]
    best, _ = min(outcomes, key=lambda item: item[1])
    best, cost, covariance = _refine_physical(
        best, joint_fit(1, FINE_NODES_NM, kernel), 100, final=True
    )
    pixels = np.linspace(pixel_range[0], pixel_range[1], 256)
    fitted = QuadraticMapping.fit(
        pixels, best.wavelength_nm(pixels), method=f"{origin}+grating fit"
    )
    rms = None
    coefficient_covariance = None
    if covariance is not None:
        # λ at the fitted pixels is linear in the physical parameters near the optimum, and the
        # quadratic's coefficients are linear in λ: propagate the fit's covariance through both.
        x = np.array(
            [
                math.log(best.dispersion_nm_per_px),
                math.log(best.focal_length_px),
                best.incidence_deg,
            ]
        )
        steps = np.array([1e-6, 1e-4, 1e-3])
        jacobian = np.stack(
            [
                (_physical(x + step * unit).wavelength_nm(pixels) - best.wavelength_nm(pixels))
                / step
                for step, unit in zip(steps, np.eye(3), strict=True)
            ],
            axis=1,
        )
        design = np.stack([pixels**2, pixels, np.ones_like(pixels)], axis=1)
        projection = np.linalg.pinv(design)
        coefficient_covariance = projection @ jacobian @ covariance @ jacobian.T @ projection.T
        rms = wavelength_rms_from_covariance(coefficient_covariance, pixel_range)
    covers = best.wavelength_nm(np.array(pixel_range))
    tolerance = 0.5 * grid.step_nm
    if covers.min() > grid.start_nm + tolerance or covers.max() < grid.stop_nm - tolerance:
        raise EstimationError(
            f"the best mapping puts the profile at {covers.min():.0f}–{covers.max():.0f} nm, not "
            f"covering the grid {grid.start_nm:g}–{grid.stop_nm:g} nm: does the profile hold the "
            "whole first order?"
        )
    return QuadraticMapping(
        fitted.a,
        fitted.b,
        fitted.c,
        method=f"{origin}+grating fit",
        pixel_range=pixel_range,
        covariance=None
        if coefficient_covariance is None
        else tuple((float(r[0]), float(r[1]), float(r[2])) for r in coefficient_covariance),
        wavelength_rms_nm=rms,
        details={
            "mapping_lamps": [lamp.name for lamp in lamps],
            "origin": origin,
            "family": "tilted grating (pixels from the 0th order)",
            "grating": best.to_dict(),
            "quadratic_max_error_nm": float(
                np.max(np.abs(fitted.wavelength_nm(pixels) - best.wavelength_nm(pixels)))
            ),
            "final_cost": cost,
            "flexibility": FLEXIBILITY,
        },
    )
