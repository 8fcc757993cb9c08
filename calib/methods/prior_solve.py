"""The joint estimate of sensitivity and grating efficiency with a Gaussian camera prior (closed form).

Makabe et al. (2025) write each channel's sensitivity in a 7-vector basis learnt from measured cameras
and the inverse grating efficiency ``η⁻¹ = B_η c_η`` in a Fourier basis (Eq. 12). A camera outside the
basis' span cannot be represented, and the fit bends η to compensate. Here the profile decides the
sensitivity's shape at every grid wavelength, and the measured cameras enter as a Gaussian prior
``s_c ~ N(α ŝ_c, α² Σ_c)`` (:class:`calib.model.bases.CameraPrior`) that settles only what one lamp cannot:
the smooth factor shared by ``η`` and ``s``.

1. Response. The profile is linear in the response ``q_c = η s_c`` on the grid: ``m_c = K q_c`` with
   ``K[p, i] = ∫_pixel e φ_i dλ`` (the measured lamp at 1 nm; pixels wholly inside the grid). Weighted
   least squares with a slight second-difference penalty gives ``q̂_c`` and its covariance ``C_c``.
2. Efficiency. ``s_c = q_c ⊙ η⁻¹``: ``c_η`` and the scale ``α`` minimise
   ``Σ_c ‖V_c^{-1/2} (diag(q̂_c) B_η c_η − α ŝ_c)‖²`` subject to the direct measurement
   ``d · (q̂_c ⊙ B_η c_η) = m_dir,c``, with ``V_c = α̂² Σ_c + diag(η̂⁻¹) C_c diag(η̂⁻¹)`` (prior spread
   plus the response's noise); two passes refine ``α̂, η̂⁻¹``. A linear problem: closed form.
3. Sensitivity. With ``η⁻¹`` fixed, the data's ``s_c ~ N(η̂⁻¹ ⊙ q̂_c, diag(η̂⁻¹) C_c diag(η̂⁻¹))`` and the
   prior are combined (product of Gaussians) and conditioned on the direct measurement; the posterior
   covariance, plus the propagated uncertainty of ``c_η``, gives the sensitivity's σ.

The direct measurement is used as exact in steps 2 and 3, but it is measured: its variance (its
``direct_sigma`` and a 0.1 % floor, as a companion's, :func:`direct_variance`) is carried to first
order into ``c_η``'s covariance (``J Σ_dir Jᵀ``, ``J = ∂c_η/∂m_dir`` of step 2's constrained solution)
and into the sensitivity's σ (through ``η⁻¹`` and step 3's conditioning together), so η's and s's σ
hold it (decision 0126).

Noise is handled where it enters: in step 1 the measured profile is only ever on the right-hand side
(no errors-in-variables bias), and the paper's division by ``e`` never happens (``K`` carries the lamp).

:func:`estimate_prior` is the registered method (``"prior"``): the lamps checked, the mapping found
and the result reported as for the paper's solve (:mod:`calib.methods.closed_form`), this solve in
between.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread, pinv_symmetric_stack
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.closed_form import ClosedFormOptions, JointSetup, joint_result, joint_setup
from calib.methods.grating_models import (
    DEFAULT_GRATING_MODEL,
    GratingModelName,
    check_grating_model,
)
from calib.methods.responses import (
    LampData,
    ResponseEstimate,
    fit_response,
    lamp_data,
    prepared_response,
)
from calib.methods.uncertainty import reading_curves_only
from calib.model.bases import CameraBasis, CameraPrior, whitening_stack
from calib.model.forward import WavelengthMapping
from calib.model.linear_model import LampSystem

#: Passes of step 2 (re-weighting by the previous η̂⁻¹ and α̂).
EFFICIENCY_PASSES = 3
#: Registry name (and the result's ``method``).
PRIOR_METHOD = "prior"


@dataclass(frozen=True, eq=False)
class PriorSolution:
    """The solve's results.

    Attributes
    ----------
    sensitivity, sensitivity_sigma
        Shape ``(f, 3)`` in the direct measurement's units (not normalised), and its posterior σ.
    inverse_efficiency, inverse_efficiency_sigma
        ``η⁻¹`` on the grid ``(f,)`` (same gauge) and its σ.
    inverse_efficiency_covariance
        ``(f, f)``: the covariance of ``η⁻¹`` on the grid (``B_η C_η B_ηᵀ``, the prior's spread and
        the responses' noise as step 2 weighs them).
    response
        ``q̂`` ``(f, 3)``: the fitted ``η s_c``.
    scale
        ``α``: the camera's scale relative to the prior mean.
    used_pixels
        Boolean mask ``(n,)`` of the profile pixels that entered.
    info
        Condition numbers, χ² values, passes.
    """

    sensitivity: FloatArray
    sensitivity_sigma: FloatArray
    inverse_efficiency: FloatArray
    inverse_efficiency_sigma: FloatArray
    inverse_efficiency_covariance: FloatArray
    response: FloatArray
    scale: float
    used_pixels: FloatArray
    info: dict[str, Any]


def solve_with_prior(
    system: LampSystem,
    mapping: WavelengthMapping,
    prior: CameraPrior,
    efficiency_basis: FloatArray,
    *,
    companions: Sequence[LampSystem] = (),
    responses: Sequence[ResponseEstimate] | None = None,
    with_sigma: bool = True,
) -> PriorSolution:
    """MAP estimate of sensitivity and η⁻¹ (see the module docstring).

    Parameters
    ----------
    system
        The reference lamp (profile, σ, spectrum operators, blur), with a direct measurement: the
        sensitivity's shape comes from its response.
    mapping
        Pixel→wavelength mapping (shared by every lamp: one geometry).
    prior
        Camera prior on the system's grid.
    efficiency_basis
        ``B_η`` of shape ``(f, b_η)``.
    companions
        Other lamps with a direct measurement (e.g. the fluorescent lamp used for the mapping). Each
        adds three equations on ``η⁻¹`` alone, ``d_l · (q̂_l ⊙ η⁻¹) = m_dir,l`` — its own response
        against its own direct signal, so its brightness cancels.
    responses
        Step 1 already made (:func:`calib.methods.responses.fit_response` of ``system`` and then
        of each companion, on ``mapping``), e.g. by the grating model's choice; ``None``: fitted
        here.
    with_sigma
        Off: the curves only (a σ budget's re-solve, whose σ nobody reads:
        :func:`calib.methods.uncertainty.curves_only`): the same sensitivity and ``η⁻¹`` to the
        bit, without what only their σ needs (the constrained solution's gain and covariance, the
        step-3 σ terms, the rows' singular values); the σ fields, the covariance and the
        condition number are then NaN.

    Raises
    ------
    InputError
        Without a direct measurement, or a prior on another grid.
    EstimationError
        When too few pixels fall inside the grid or the data are degenerate.
    """
    observation = system.observation
    grid = system.operators.grid
    if prior.grid != grid:
        raise InputError(f"the camera prior is on grid {prior.grid}, not {grid}", source="prior")
    if observation.direct_rgb is None:
        raise InputError(
            "the solve needs the direct (0th-order) RGB", source=f"lamp {observation.name!r}"
        )
    direct = np.asarray(observation.direct_rgb, dtype=np.float64)
    direct_row = system.operators.direct_row
    mean = prior.mean
    size = grid.size
    b_eta = efficiency_basis.shape[1]
    if responses is not None and len(responses) != 1 + len(companions):
        raise InputError(
            f"{len(responses)} fitted responses for {1 + len(companions)} lamps", source="responses"
        )
    estimate = fit_response(system, mapping) if responses is None else responses[0]
    response, response_cov = estimate.response, estimate.covariance

    # Step 2: c_η and α under the prior, constrained by the direct measurement.
    predicted = float(np.sum(direct_row @ response))
    if predicted <= 0 or float(np.sum(direct)) <= 0:
        raise EstimationError("the direct signal or the fitted first-order response is zero")
    inverse_hat = np.full(size, float(np.sum(direct)) / predicted)
    scale_hat = float(np.sum(direct)) / max(float(np.sum(direct_row @ mean)), 1e-300)
    n_unknowns = b_eta + 1
    constraint = np.zeros((3, n_unknowns))
    for c in range(3):
        constraint[c, :b_eta] = (direct_row * response[:, c]) @ efficiency_basis
    # Companions' equations are rows weighted by their own noise (their responses are noisy where
    # their lamp is dim — between a fluorescent lamp's lines — so they must not be exact).
    companion_terms = []
    for index, companion in enumerate(companions, start=1):
        if companion.observation.direct_rgb is None:
            raise InputError(
                "a companion lamp needs a direct measurement",
                source=f"lamp {companion.observation.name!r}",
            )
        fitted = fit_response(companion, mapping) if responses is None else responses[index]
        companion_terms.append(
            (
                companion.operators.direct_row,
                fitted,
                np.asarray(companion.observation.direct_rgb, dtype=np.float64),
                companion.observation.direct_sigma,
            )
        )
    solution = np.zeros(n_unknowns)
    rows = np.zeros((0, n_unknowns))
    # The constraint is the same on every pass: its null space and particular solution once.
    null_space = _null_space(constraint)
    particular = np.asarray(np.linalg.lstsq(constraint, direct, rcond=None)[0], dtype=np.float64)
    for _ in range(EFFICIENCY_PASSES):
        blocks = []
        # The three channels' spreads whitened in one stacked call (the same bits as each alone).
        whitening_factors = whitening_stack(
            scale_hat**2 * prior.covariance
            + (inverse_hat[None, :, None] * response_cov * inverse_hat[None, None, :])
        )
        for c in range(3):
            whitening_factor = whitening_factors[c]
            block = np.zeros((size, n_unknowns))
            block[:, :b_eta] = whitening_factor @ (response[:, c][:, None] * efficiency_basis)
            block[:, -1] = -(whitening_factor @ mean[:, c])
            blocks.append(block)
        companion_targets = []
        for companion_row, fitted, companion_direct, companion_sigma in companion_terms:
            spread = companion_row * inverse_hat
            variances = direct_variance(companion_direct, companion_sigma)
            for c in range(3):
                weighted = companion_row * fitted.response[:, c]
                variances[c] += float(spread @ fitted.covariance[c] @ spread)
                block = np.zeros((1, n_unknowns))
                block[0, :b_eta] = (weighted @ efficiency_basis) / np.sqrt(variances[c])
                blocks.append(block)
            companion_targets.append(companion_direct / np.sqrt(variances))
        target_rows = np.concatenate([np.zeros(3 * size), *companion_targets])
        rows = np.vstack(blocks)
        solution = _constrained_lstsq(rows, particular, null_space, target_rows)
        inverse_hat = efficiency_basis @ solution[:b_eta]
        scale_hat = abs(float(solution[-1])) or scale_hat
    inverse_efficiency = efficiency_basis @ solution[:b_eta]
    if with_sigma:
        # The leading lamp's direct RGB is measured, not exact: its variance moves the constrained
        # solution along ``∂x/∂m_dir`` (first order; the rows' noise is independent of it).
        leading_variance = direct_variance(direct, observation.direct_sigma)
        direct_gain = _constrained_gain(rows, constraint, null_space)[:b_eta]
        noise_cov = _constrained_covariance(rows, null_space)[:b_eta, :b_eta]
        c_eta_cov = noise_cov + (direct_gain * leading_variance) @ direct_gain.T
        inverse_covariance = efficiency_basis @ c_eta_cov @ efficiency_basis.T
        inverse_sigma = np.sqrt(np.clip(np.diag(inverse_covariance), 0, None))
    else:
        inverse_covariance = np.full((size, size), np.nan)
        inverse_sigma = np.full(size, np.nan)

    # Step 3: combine the data's s = η⁻¹ ⊙ q̂ with the prior, conditioned on the direct signal.
    sensitivity = np.empty((size, 3))
    sensitivity_sigma = np.full((size, 3), np.nan)
    # The channels' inverses in stacked calls: LAPACK on each matrix in turn, the same bits.
    data_precisions = pinv_symmetric_stack(
        inverse_efficiency[None, :, None] * response_cov * inverse_efficiency[None, None, :]
    )
    prior_precisions = np.linalg.inv(scale_hat**2 * prior.covariance)
    posterior_covs = np.linalg.inv(data_precisions + prior_precisions)
    for c in range(3):
        data_mean = inverse_efficiency * response[:, c]
        prior_mean = scale_hat * mean[:, c]
        data_precision = data_precisions[c]
        prior_precision = prior_precisions[c]
        posterior_cov = posterior_covs[c]
        posterior_mean = posterior_cov @ (data_precision @ data_mean + prior_precision @ prior_mean)
        gain = posterior_cov @ direct_row / float(direct_row @ posterior_cov @ direct_row)
        sensitivity[:, c] = posterior_mean + gain * (direct[c] - float(direct_row @ posterior_mean))
        if not with_sigma:
            continue
        conditioned = posterior_cov - np.outer(gain, direct_row @ posterior_cov)
        # η's own uncertainty moves s_c along q̂_c ⊙ B_η (a smooth common factor).
        jacobian = response[:, c][:, None] * efficiency_basis
        total = conditioned + jacobian @ noise_cov @ jacobian.T
        # The leading lamp's measured direct RGB moves s_c through η⁻¹ (step 2) and through this
        # step's conditioning on m_dir,c, together (one draw of m_dir): ∂s_c/∂m_dir, first order.
        moved = (posterior_cov @ data_precision) @ (jacobian @ direct_gain)
        moved -= np.outer(gain, direct_row @ moved)
        moved[:, c] += gain
        total += (moved * leading_variance) @ moved.T
        sensitivity_sigma[:, c] = np.sqrt(np.clip(np.diag(total), 0.0, None))

    condition = float("nan")
    if with_sigma:
        singular = np.linalg.svd(rows, compute_uv=False)
        condition = float(singular[0] / max(singular[-1], 1e-300))
    return PriorSolution(
        sensitivity=sensitivity,
        sensitivity_sigma=sensitivity_sigma,
        inverse_efficiency=inverse_efficiency,
        inverse_efficiency_sigma=inverse_sigma,
        inverse_efficiency_covariance=inverse_covariance,
        response=response,
        scale=float(solution[-1]),
        used_pixels=estimate.used_pixels,
        info={
            "pixels_used": int(estimate.used_pixels.sum()),
            "response_chi2": estimate.chi2,
            "prior_chi2": float(np.sum((rows @ solution) ** 2)),
            "efficiency_condition": condition,
            "prior_shrinkage": prior.shrinkage.tolist(),
            "camera_scale": float(solution[-1]),
            "efficiency_lamps": [system.observation.name]
            + [companion.observation.name for companion in companions],
        },
    )


def _null_space(constraint: FloatArray) -> FloatArray:
    _, singular, vt = np.linalg.svd(constraint)
    rank = int(np.sum(singular > singular[0] * 1e-12))
    return np.asarray(vt[rank:].T, dtype=np.float64)


def _constrained_lstsq(
    rows: FloatArray,
    particular: FloatArray,
    null_space: FloatArray,
    row_target: FloatArray | None = None,
) -> FloatArray:
    """``argmin ‖rows x − row_target‖²`` s.t. ``constraint x = target``, through the constraint's
    ``particular`` solution (``lstsq``) and its ``null_space`` (:func:`_null_space`)."""
    offset = rows @ particular - (0.0 if row_target is None else row_target)
    coefficients, *_ = np.linalg.lstsq(rows @ null_space, -offset, rcond=None)
    return np.asarray(particular + null_space @ coefficients, dtype=np.float64)


def direct_variance(direct: FloatArray, sigma: FloatArray | None) -> FloatArray:
    """The variance ``(3,)`` of a lamp's direct equations ``d · (q̂ ⊙ η⁻¹) = m_dir``: the direct
    value's own (``sigma``, e.g. the Bayer interleaving's 0.3–3 %: decision 0119) and a floor of
    0.1 % of it, to which the lamp's spectrum and the model are known."""
    variance = (1e-3 * np.asarray(direct, dtype=np.float64)) ** 2
    if sigma is not None:
        variance = variance + np.asarray(sigma, dtype=np.float64) ** 2
    return np.asarray(variance, dtype=np.float64)


def _constrained_gain(
    rows: FloatArray, constraint: FloatArray, null_space: FloatArray
) -> FloatArray:
    """``∂x/∂target`` ``(n, 3)`` of :func:`_constrained_lstsq`'s solution: the particular solution
    ``constraint⁺ target`` less what the rows then pull back along the null space."""
    particular = np.linalg.pinv(constraint)
    reduced = rows @ null_space
    pulled = null_space @ np.linalg.lstsq(reduced, rows @ particular, rcond=None)[0]
    return np.asarray(particular - pulled, dtype=np.float64)


def _constrained_covariance(rows: FloatArray, null_space: FloatArray) -> FloatArray:
    """Covariance of that solution for unit-variance rows and an exact constraint (its
    ``null_space``)."""
    reduced = rows @ null_space
    return np.asarray(
        null_space @ np.linalg.pinv(reduced.T @ reduced) @ null_space.T, dtype=np.float64
    )


@dataclass(frozen=True)
class PriorOptions(ClosedFormOptions):
    """Options of :func:`estimate_prior` (those of every closed-form solve,
    :class:`calib.methods.closed_form.ClosedFormOptions`); ``prior_shrinkage`` also shapes the
    prior this solve leans on.

    Attributes
    ----------
    grating_model
        ``"fourier"``: this module's solve (``η⁻¹`` in ``efficiency_terms`` Fourier terms, ``η₀``
        flat); ``"sinusoidal"``/``"blazed"``: the physical grating fitted to the lamps' direct
        equations (:mod:`calib.methods.grating_models`), then the camera through it with the prior
        where the lamps are dim; ``"auto"`` (default): chosen on the direct equations at the rig's
        error level (:func:`calib.methods.multilamp.solve_efficiency`).
    """

    grating_model: GratingModelName = DEFAULT_GRATING_MODEL

    def __post_init__(self) -> None:
        super().__post_init__()
        check_grating_model(self.grating_model)


@one_blas_thread
def estimate_prior(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    options: PriorOptions = PriorOptions(),
) -> EstimateResult:
    """Estimate sensitivity (with σ), grating efficiency and mapping under a Gaussian camera prior.

    The first solve lamp (:func:`calib.methods.closed_form.choose_solve_lamps`) gives the
    sensitivity's shape; every other lamp with a direct measurement constrains ``η`` (its own
    response against its own direct signal, so its brightness cancels).

    Parameters
    ----------
    observations
        Lamps (direct RGB + first-order profile + measured spectrum), all in one geometry.
    basis
        Camera basis on ``grid``: its Gaussian prior (mean ŝ, covariance) is used.
    grid
        Working grid.
    mapping
        A known mapping (used as is unless ``options.refine_given_mapping``); ``None`` finds it.
    mapping_lamp
        Find the mapping with this lamp only (default: every lamp jointly).
    options
        :class:`PriorOptions`.

    Returns
    -------
    EstimateResult
        ``method="prior"``, with ``sensitivity_sigma``.

    Raises
    ------
    InputError
        No lamps, duplicate names, a basis on another grid, no lamp with a direct measurement.
    EstimationError
        No mapping found, too few pixels inside the grid, or no positive sensitivity.

    Examples
    --------
    >>> from calib.core.datasets import colour_science_cameras, find_camera
    >>> from calib.core.lamp_specs import colour_lamp
    >>> from calib.core.mapping import QuadraticMapping
    >>> from calib.core.metrics import relative_error
    >>> from calib.model.bases import fallback_camera_basis
    >>> from calib.model.forward import render_observation
    >>> camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    >>> basis = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])
    >>> truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
    >>> led = render_observation(colour_lamp("LED-B3"), camera, mapping=truth, pixel=800)
    >>> result = estimate_prior([led.observation], basis=basis, mapping=truth)
    >>> result.method, result.sensitivity_sigma is not None
    ('prior', True)
    """
    setup = joint_setup(
        observations,
        basis=basis,
        grid=grid,
        mapping=mapping,
        mapping_lamp=mapping_lamp,
        options=options,
    )
    step = time.perf_counter()
    record: dict[str, Any] = {"model": "fourier", "chosen": "fourier", "requested": "fourier"}
    # Each lamp prepared and its response fitted once: the grating model's choice made both for
    # the lamps with a direct measurement, on the same mapping (decision 0083).
    prepared: dict[int, tuple[LampSystem, ResponseEstimate]] = {}
    if options.grating_model != "fourier":
        physical, record, made = _physical_estimate(observations, setup, basis, grid, options)
        if physical is not None:
            return physical
        record = {**record, "model": "fourier", "terms": int(setup.efficiency_basis.shape[1])}
        prepared = {id(obs): pair for obs, pair in made}
    reference = setup.solve_lamps[0]
    solved = [reference] + [
        obs for obs in observations if obs is not reference and obs.direct_rgb is not None
    ]
    # Made here or found in the open scope (the σ budget's η-terms re-solve: decision 0107).
    pairs = [
        prepared[id(obs)]
        if id(obs) in prepared
        else prepared_response(obs, setup.mapping, grid, setup.kernel)
        for obs in solved
    ]
    systems = [system for system, _ in pairs]
    fitted = [response for _, response in pairs]
    system = systems[0]
    # A σ budget's re-solve: its curves are read, never its σ or residuals (decision 0132).
    full = not reading_curves_only()
    solution = solve_with_prior(
        system,
        setup.mapping,
        setup.prior,
        setup.efficiency_basis,
        companions=systems[1:],
        responses=fitted,
        with_sigma=full,
    )
    setup.timings["solve_s"] = time.perf_counter() - step
    return joint_result(
        PRIOR_METHOD,
        setup,
        [system] if full else [],
        basis=basis,
        grid=grid,
        options=options,
        sensitivity=solution.sensitivity,
        inverse_efficiency=solution.inverse_efficiency,
        sensitivity_sigma=solution.sensitivity_sigma if full else None,
        info={**solution.info, "lamp_scales": [1.0]},
        diagnostics={"grating_model": record},
        inverse_efficiency_covariance=solution.inverse_efficiency_covariance if full else None,
    )


def _physical_estimate(
    observations: Sequence[LampObservation],
    setup: JointSetup,
    basis: CameraBasis,
    grid: WavelengthGrid,
    options: PriorOptions,
) -> tuple[
    EstimateResult | None,
    dict[str, Any],
    list[tuple[LampObservation, tuple[LampSystem, ResponseEstimate]]],
]:
    """The estimate through a physical grating fitted to the direct equations, when
    ``options.grating_model`` asks for one or ``"auto"`` prefers one (else ``None``: the Fourier
    solve above runs), the model choice's record, and each lamp with a direct measurement with
    its prepared system and fitted response (for the Fourier solve). The camera is ``q̂ / η₁``
    pooled over the lamps, with the prior where they are dim
    (:func:`calib.methods.multilamp.blend_with_prior`: the prior enters once, here)."""
    # Deferred: multilamp builds on this module's response fit.
    from calib.methods.multilamp import (
        EfficiencySettings,
        blend_with_prior,
        combine_responses,
        efficiency_with_sigma,
        multilamp_result,
        solve_efficiency,
    )

    started = time.perf_counter()
    with_direct = [obs for obs in observations if obs.direct_rgb is not None]
    pairs = [prepared_response(obs, setup.mapping, grid, setup.kernel) for obs in with_direct]
    lamps: list[LampData] = [
        lamp_data(system, setup.mapping, response) for system, response in pairs
    ]
    made = list(zip(with_direct, pairs, strict=True))
    efficiency = solve_efficiency(
        lamps,
        setup.prior,
        # The covariance weighs the data against the prior below: no choice spread (0053).
        EfficiencySettings(grating_model=options.grating_model, choice_spread=False),
    )
    record: dict[str, Any] = efficiency.info["grating_model"]
    if record["chosen"] == "fourier":
        return None, record, made
    solution = combine_responses(
        [lamp.response for lamp in lamps],
        efficiency.inverse_efficiency,
        efficiency.inverse_jacobian,
        efficiency.coefficient_covariance,
    )
    solution = blend_with_prior(solution, setup.prior)
    if reading_curves_only():
        # A σ budget's re-solve: the curves are read, not their σ (the normalised covariance's
        # products left out; decision 0132).
        solution = replace(solution, covariance=None)
    setup.timings["solve_s"] = time.perf_counter() - started
    setup.timings["total_s"] = time.perf_counter() - setup.started
    return (
        multilamp_result(
            lamps,
            solution,
            efficiency_with_sigma(efficiency),
            setup.mapping,
            basis,
            {**efficiency.info, "grating": "estimated", "mapping_given": setup.mapping_given},
            setup.timings,
            method=PRIOR_METHOD,
            direct_weight=efficiency.direct_weights,
        ),
        record,
        made,
    )
