"""Several lamps jointly: the grating efficiency from measurements, the camera at full resolution.

Beyond Makabe et al. (2025). For every lamp ``l`` and channel ``c`` the direct signal equals the
diffracted profile, mapped to wavelength, integrated against ``η⁻¹``:

    m_dir,lc = Σ_λ p_lc(λ) η⁻¹(λ),

and the lamp's unknown brightness cancels (it scales both sides). Each lamp therefore adds three
equations on ``η⁻¹`` alone, independent of any camera basis; with three or more spectrally different
lamps ``η`` is determined by the data. The solve:

1. Responses. Each lamp's profile gives ``q_lc = E_l η s_c`` on the grid by weighted least squares
   (:func:`calib.methods.responses.fit_response`: the measured lamp is inside the design matrix, nothing is
   divided by a spectrum), with its covariance ``C_lc``.
2. Efficiency. ``η = B_η c_η`` (Fourier, Supp. E; a grating's efficiency is smooth and positive,
   its inverse over a 3:1 range is not) from the rows ``(d_l ⊙ q̂_lc)ᵀ η⁻¹ = m_dir,lc``, each
   whitened by its noise (the direct σ plus the response's propagated covariance plus a 0.1 % model
   floor; a lamp whose spectrum has a noisy dark range also 10⁻³ of its brightest channel,
   :func:`with_spectrum_floor`), and the camera prior ``s_c ~ N(α ŝ_c, α² Σ_c)`` applied to
   ``Q ⊙ η⁻¹`` (``Q``: the lamps' pooled response, step 3; with several cameras, each camera's own
   ``Q`` and ``α``) as a penalty of weight ``λ``. The rows are linear in ``η⁻¹``, not in ``c_η``: Gauss–Newton solves it
   (the paper's linear model ``η⁻¹ = B_η c_η`` stays available, ``efficiency_model="inverse"``).
   ``λ`` comes from the unbiased predictive risk estimator (UPRE, Mallows' C_L: the rows are
   whitened, so the noise level is known), ``‖A x_λ − b‖² + 2 tr H_λ`` on the linearisation over
   a logarithmic grid. Alternatively (``weight_rule``, :data:`PRIOR_WEIGHT_RULES`) each camera
   gets ``d₀ / D²`` (``"typicality"``: the median leave-one-out Mahalanobis distance of the
   training cameras over this camera's), or ``λ`` maximises the measurements' marginal likelihood
   (``"evidence"``). With few lamps the data cannot pin ``η`` and the prior decides what
   they leave open; its share of the posterior (``prior_share``) falls as lamps are added.
3. Sensitivity. ``s_c = Q_c ⊙ η⁻¹`` where ``Q_c`` combines the lamps' responses, each divided by its
   brightness relative to the first lamp (fitted), with inverse-variance weights per wavelength: at
   full grid resolution, not confined to a basis' span. Negative values are clipped (positivity).

Uncertainty: the covariance of ``s`` (noise of every response, plus ``η⁻¹``'s posterior covariance
propagated along ``Q_c ⊙ ∂η⁻¹/∂c_η``), then of its normalisation by the peak (first order), gives σ per
wavelength and channel; :func:`bootstrap_sigma` cross-checks it by re-drawing the noise model.

With a grating file (:mod:`calib.core.grating_file`) ``η`` is known and a single lamp suffices:
``s_c = q̂_c / η`` (:mod:`calib.methods.known_grating`, steps 1 and 3 alone). Several cameras seen
through one grating share ``η``: :func:`refine_grating` stacks their lamps' rows.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from scipy.linalg import block_diag

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread, pinv_symmetric, pinv_symmetric_stack
from calib.core.errors import EstimationError, InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult, QualityFlag
from calib.core.spectra import DEFAULT_GRID, Spectrum, WavelengthGrid
from calib.core.spectrometer_scale import scale_sigma_nm
from calib.core.spectrometer_tolerance import WAVELENGTH_SCALE_NM
from calib.methods.closed_form import (
    GratingMethodOptions,
    check_lamps,
    normalised_efficiency_sigma,
)
from calib.methods.grating_models import (
    CHOICE_FLOOR,
    DEFAULT_GRATING_MODEL,
    GratingModelName,
    PhysicalFit,
    check_grating_model,
    fit_physical,
    profile_throughput,
    with_jackknife,
)
from calib.methods.responses import (
    DIRECT_GAIN_SIGMA,
    LampData,
    ResponseEstimate,
    direct_rows,
    lamp_data,
    prepared_response,
)
from calib.methods.solve_scope import fingerprint, recall, remember_start, reuse, warm_start
from calib.model.bases import (
    CameraBasis,
    CameraPrior,
    fourier_basis,
    prior_distance,
    whitening_stack,
)
from calib.model.gratings import PHYSICAL_KINDS, PHYSICAL_PARAMETER_RANGES, PhysicalKind
from calib.model.resolution import camera_kernel
from calib.wavelength import RigGeometry, find_mapping, lamps_named
from calib.wavelength.rig_prior import rig_geometry

Uncertainty = Literal["posterior", "noise", "none"]
UNCERTAINTIES: tuple[Uncertainty, ...] = ("posterior", "noise", "none")
EfficiencyModel = Literal["efficiency", "inverse"]
#: How the grating efficiency is parametrised: ``"efficiency"``, ``η = B c`` (a grating's
#: efficiency is a smooth, positive curve; its inverse over a 3:1 range is not, and 7 terms of it
#: miss the protocol's η by 4.5 % at the median worst wavelength), or ``"inverse"``, the paper's
#: ``η⁻¹ = B c`` (linear, closed form).
EFFICIENCY_MODELS: tuple[EfficiencyModel, ...] = ("efficiency", "inverse")
DEFAULT_EFFICIENCY_MODEL: EfficiencyModel = "efficiency"
#: Damped Newton iterations per prior weight at most (``"efficiency"`` model; from the previous
#: weight's solution it converges in a few and stops there: the cap only bounds a hard start).
GAUSS_NEWTON_ITERATIONS = 100
WeightRule = Literal["evidence", "typicality", "upre"]
#: How the camera prior's weight ``λ`` is chosen.
#:
#: ``"typicality"``: an empirical-Bayes scale per camera. ``λ_k = d₀ / D²_k``, where ``D²_k`` is
#: the squared Mahalanobis distance of camera k's current sensitivity from the prior
#: (:func:`calib.model.bases.prior_distance`), and ``d₀`` is the median of the same distance over the
#: training cameras, each left out of its own prior (:attr:`calib.model.bases.CameraPrior.typical_distance`).
#: A camera as typical as the training set keeps the prior at its natural weight; one far from it
#: (a Foveon, a camera behind a filter) has its prior widened in proportion. Starts at λ = 1 and
#: is updated after each pass.
#:
#: ``"upre"``: the unbiased predictive risk estimator on the direct rows.
#:
#: ``"evidence"``: the marginal likelihood of the measurements (type-II maximum likelihood, MacKay's
#: evidence framework), in the Laplace approximation about each weight's solution: the prior rows
#: are ``n_p`` Gaussian observations of variance ``1/λ``, so
#: ``−2 log p(data | λ) = ‖r_d‖² + λ‖r_p‖² − n_p log λ + log det(J_dᵀJ_d + λ J_pᵀJ_p) + const``.
#: It asks how well the prior *at that weight* explains the camera, so a camera unlike the training
#: set widens it, and a typical one keeps it near its natural weight.
#:
#: UPRE is the default: the only rule whose ±2σ band holds 90–98 % on the test cameras, and it
#: never fails the way typicality can. Typicality trusts the prior's geometry, and a prior built from
#: perturbed copies of 11 cameras (the offline basis) does not see a Foveon as far. Its D² is 42
#: against a typical 17, so λ = 0.4 and RE 41.5, where UPRE picks λ = 0.001 and gets 9.8. The
#: evidence's band is too narrow (80–91 %). Each rule's figures on the synthetic protocol: decision
#: 0015, addenda 3 and 4.
PRIOR_WEIGHT_RULES: tuple[WeightRule, ...] = ("evidence", "typicality", "upre")
DEFAULT_WEIGHT_RULE: WeightRule = "upre"

#: Registry name.
MULTILAMP_METHOD = "multilamp"
#: Fourier terms of the efficiency by default: the paper's 7. With the ``"efficiency"`` model, 5 or 9
#: terms lose both on the protocol's η and on a blazed grating's sinc² (5 lamps, 1 % profile and
#: 0.1 % direct noise, true mapping, 5 test cameras: mean RE 3.12 / 0.98 / 1.42 and
#: 1.12 / 0.96 / 1.56 ×10⁻² for 5 / 7 / 9 terms).
DEFAULT_EFFICIENCY_TERMS = 7
#: The ``"inverse"`` model pooled over several cameras (:func:`refine_grating`): the direct
#: equations afford more terms of ``η⁻¹``: the
#: protocol's η (7 Fourier terms *in η*, 0.3–1) has an inverse that 7 terms miss by 4.5 % at the median
#: worst wavelength, 15 terms by 0.1 %. One term per this many equations, odd, at most
#: :data:`MAX_POOLED_EFFICIENCY_TERMS` (measured with 4 cameras × 5 lamps at 1 % noise, one-LED
#: estimate through the file: 7 terms RE 2.69, 11 → 1.99, 15 → 1.78, 21 → 1.81 ×10⁻²).
ROWS_PER_EFFICIENCY_TERM = 4
MAX_POOLED_EFFICIENCY_TERMS = 15
#: Prior weights UPRE and the evidence choose among (relative to the prior's natural weight 1;
#: searched coarse-to-fine, not all solved: :func:`_nonlinear_efficiency`).
PRIOR_WEIGHTS: FloatArray = np.logspace(-8, 2, 41)
#: Re-weighting passes of step 2 (the rows' σ depend on the current ``η⁻¹``).
EFFICIENCY_PASSES = 3


@dataclass(frozen=True, eq=False)
class EfficiencySolution:
    """Step 2's result: ``η⁻¹`` on the grid and what it came from.

    Attributes
    ----------
    inverse_efficiency
        ``η⁻¹`` ``(f,)`` in the gauge of the direct measurements (direct = Σ profile ⊙ η⁻¹).
    coefficients, coefficient_covariance
        ``c_η`` ``(b,)`` and its posterior covariance ``(b, b)`` (prior included).
    noise_covariance
        The covariance of ``c_η`` from the measurements' noise alone, ``M⁻¹ AᵀA M⁻¹`` (what a
        bootstrap over the noise model sees; smaller than the posterior, which also carries the
        prior's uncertainty).
    prior_weight
        ``λ`` as chosen (by the rule, or the first camera's under the typicality rule; ``info`` has
        every camera's).
    inverse_jacobian
        ``∂η⁻¹/∂c`` ``(f, b)`` at the solution (the basis itself for the ``"inverse"`` model): what
        propagates the coefficients' covariance to ``η⁻¹`` and to the sensitivity.
    info
        Condition number of the data rows alone, χ² of the data rows, the rule's curve over
        :data:`PRIOR_WEIGHTS` (``weight_curve``; NaN at the weights the search did not solve).
    """

    inverse_efficiency: FloatArray
    coefficients: FloatArray
    coefficient_covariance: FloatArray
    noise_covariance: FloatArray
    prior_weight: float
    inverse_jacobian: FloatArray
    info: dict[str, Any] = field(default_factory=dict)
    direct_weight: FloatArray | None = None

    @property
    def direct_weights(self) -> FloatArray:
        """``T η₀`` ``(f,)`` in the sensitivity's gauge: the direct signal is ``Σ d ⊙ s ⊙ T η₀``
        (ones for the Fourier model, whose ``η₀`` is flat and whose gauge is the direct one)."""
        if self.direct_weight is None:
            return np.ones_like(self.inverse_efficiency)
        return self.direct_weight


def prior_rows(
    reference: ResponseEstimate,
    prior: CameraPrior,
    efficiency_basis: FloatArray,
    inverse_efficiency: FloatArray,
    scale: float,
) -> FloatArray:
    """Whitened ``Q_c ⊙ B_η c_η − α ŝ_c`` for the unknowns ``(c_η, α)``: shape ``(3f, b + 1)``.

    ``reference`` is the response ``Q`` the prior judges (e.g. the lamps' pooled response).
    """
    size, b_eta = efficiency_basis.shape
    blocks = []
    # The three channels' spreads whitened in one stacked call (the same bits as each alone).
    factors = whitening_stack(
        scale**2 * prior.covariance
        + (
            inverse_efficiency[None, :, None]
            * reference.covariance
            * inverse_efficiency[None, None, :]
        )
    )
    for c in range(3):
        factor = factors[c]
        block = np.zeros((size, b_eta + 1))
        block[:, :b_eta] = factor @ (reference.response[:, c][:, None] * efficiency_basis)
        block[:, -1] = -(factor @ prior.mean[:, c])
        blocks.append(block)
    return np.vstack(blocks)


def weight_score(
    rule: WeightRule,
    weight: float,
    data_residual: FloatArray,
    penalty_residual: FloatArray,
    data_jacobian: FloatArray,
    penalty_jacobian: FloatArray,
) -> float:
    """What ``rule`` minimises over the prior weights, at one weight's solution (whitened rows).

    ``"upre"``: ``‖r_d‖² + 2 tr(H⁻¹ J_dᵀJ_d)``; ``"evidence"``: ``−2 log`` of the marginal
    likelihood up to a constant (:data:`PRIOR_WEIGHT_RULES`), with ``H = J_dᵀJ_d + λ J_pᵀJ_p``.
    """
    normal_data = data_jacobian.T @ data_jacobian
    normal = normal_data + weight * penalty_jacobian.T @ penalty_jacobian
    misfit = float(data_residual @ data_residual)
    if rule == "evidence":
        sign, log_det = np.linalg.slogdet(normal)
        if sign <= 0:
            return float("inf")  # no curvature in some direction: no Laplace approximation
        return (
            misfit
            + weight * float(penalty_residual @ penalty_residual)
            - penalty_residual.size * float(np.log(weight))
            + float(log_det)
        )
    return misfit + 2.0 * float(np.trace(pinv_symmetric(normal) @ normal_data))


@one_blas_thread
def choose_prior_weight(
    data: FloatArray,
    target: FloatArray,
    penalty: FloatArray,
    weights: FloatArray = PRIOR_WEIGHTS,
    rule: WeightRule = "upre",
) -> tuple[float, FloatArray]:
    """``λ`` for ``min ‖Ax − b‖² + λ‖Px‖²`` by ``rule`` (:func:`weight_score`) over ``weights``.

    ``data`` (A) and ``target`` (b) are whitened (unit noise). Returns ``λ`` and the rule's curve.
    """
    normal_data = data.T @ data
    normal_penalty = penalty.T @ penalty
    right = data.T @ target
    scores = np.empty(weights.size)
    for index, weight in enumerate(weights):
        solution = pinv_symmetric(normal_data + weight * normal_penalty) @ right
        scores[index] = weight_score(
            rule, float(weight), data @ solution - target, penalty @ solution, data, penalty
        )
    return float(weights[int(np.argmin(scores))]), scores


def _linear_efficiency(
    data_nodes: FloatArray,
    target: FloatArray,
    penalty_nodes: FloatArray,
    efficiency_basis: FloatArray,
    prior_weight: float | None,
    rule: WeightRule,
) -> tuple[FloatArray, FloatArray, FloatArray, float, FloatArray]:
    """``η⁻¹ = B c`` (the paper's model, linear): ``x = (c, α…)``, its ``(J_d, J_p)``, ``λ``, and
    ``rule``'s curve."""
    size = efficiency_basis.shape[0]
    n_scales = penalty_nodes.shape[1] - size
    data = np.hstack([data_nodes @ efficiency_basis, np.zeros((data_nodes.shape[0], n_scales))])
    penalty = np.hstack([penalty_nodes[:, :size] @ efficiency_basis, penalty_nodes[:, size:]])
    scores = np.zeros(0)
    weight = prior_weight
    if weight is None:
        weight, scores = choose_prior_weight(data, target, penalty, rule=rule)
    normal = data.T @ data + weight * penalty.T @ penalty
    solution = pinv_symmetric(normal) @ (data.T @ target)
    return solution, data, penalty, weight, scores


def _efficiency_jacobians(
    data_nodes: FloatArray,
    penalty_nodes: FloatArray,
    efficiency_basis: FloatArray,
    inverse: FloatArray,
    out: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``(J_d, J_p)`` of the data and prior residuals in ``x = (c, α…)`` where ``η = B c``.

    ``out``: arrays made by an earlier call with the same ``data_nodes`` and ``penalty_nodes``,
    overwritten (only their ``c`` columns: the ``α`` ones do not depend on ``η``)."""
    size, b_eta = efficiency_basis.shape
    inverse_jacobian = -(inverse**2)[:, None] * efficiency_basis  # ∂η⁻¹/∂c
    if out is None:
        n_scales = penalty_nodes.shape[1] - size
        data_jac = np.zeros((data_nodes.shape[0], b_eta + n_scales))
        penalty_jac = np.empty((penalty_nodes.shape[0], b_eta + n_scales))
        penalty_jac[:, b_eta:] = penalty_nodes[:, size:]
    else:
        data_jac, penalty_jac = out
    data_jac[:, :b_eta] = data_nodes @ inverse_jacobian
    penalty_jac[:, :b_eta] = penalty_nodes[:, :size] @ inverse_jacobian
    return data_jac, penalty_jac


def _efficiency_terms_solve(
    data_nodes: FloatArray,
    target: FloatArray,
    penalty_nodes: FloatArray,
    efficiency_basis: FloatArray,
    start: FloatArray,
    weight: float,
    jacobians: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, tuple[FloatArray, FloatArray]]:
    """``min ‖D η⁻¹ − t‖² + λ‖P (η⁻¹, α…)‖²`` over ``x = (c, α…)``, ``η = B c`` (Newton where its
    curvature is positive definite, Gauss–Newton elsewhere).

    Levenberg-damped steps that keep ``η`` positive on the grid and lower the cost. Returns ``x``
    and, at ``x``, ``η⁻¹``, the data and prior residuals and ``(J_d, J_p)``
    (:func:`_efficiency_jacobians`): what :func:`_nonlinear_efficiency` scores the weight with,
    the same numbers it would compute again (decision 0083). ``jacobians``: ``(J_d, J_p)`` at
    ``start`` (the previous weight's, whose solution this weight starts from; read, never
    written), used for the first step instead of computing them again (decision 0107).
    """
    size, b_eta = efficiency_basis.shape
    penalty_nodes_eta, penalty_nodes_scales = penalty_nodes[:, :size], penalty_nodes[:, size:]

    def cost_of(
        x: FloatArray, efficiency: FloatArray
    ) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        inverse = 1.0 / efficiency
        data_residual = data_nodes @ inverse - target
        penalty_residual = penalty_nodes_eta @ inverse + penalty_nodes_scales @ x[b_eta:]
        cost = float(data_residual @ data_residual) + weight * float(
            penalty_residual @ penalty_residual
        )
        return cost, inverse, data_residual, penalty_residual

    x = start.copy()
    cost, inverse, data_residual, penalty_residual = cost_of(x, efficiency_basis @ x[:b_eta])
    # One pair of Jacobian arrays made here, overwritten at each pass (a pass's products are made
    # from it before the next overwrites it); the given pair only read.
    buffers: tuple[FloatArray, FloatArray] | None = None
    current = jacobians  # (J_d, J_p) at x, when known
    damping = 1e-6
    for _ in range(GAUSS_NEWTON_ITERATIONS):
        if current is None:
            current = buffers = _efficiency_jacobians(
                data_nodes, penalty_nodes, efficiency_basis, inverse, buffers
            )
        data_jac, penalty_jac = current
        weighted_penalty = weight * penalty_jac.T
        normal = data_jac.T @ data_jac + weighted_penalty @ penalty_jac
        descent = -(data_jac.T @ data_residual + weighted_penalty @ penalty_residual)
        diagonal = np.maximum(normal.diagonal(), 1e-300)
        # Newton's curvature where it is positive definite: ``JᵀJ`` plus the residuals' second
        # derivatives, ``∂²η⁻¹/∂c² = 2 η⁻³ B Bᵀ`` node by node weighted by the cost's gradient in
        # ``η⁻¹``. Gauss–Newton alone converges only linearly where the residuals are not small
        # against the weak directions' curvature (decision 0125: 30 iterations left the cost
        # 5e-8 relative above its minimum in a validation scene); ``JᵀJ`` where it is not
        # (far from the minimum). The damping keeps ``JᵀJ``'s diagonal as its scale.
        gradient = data_nodes.T @ data_residual + weight * (penalty_nodes_eta.T @ penalty_residual)
        hessian = normal.copy()
        hessian[:b_eta, :b_eta] += (efficiency_basis.T * (2.0 * inverse**3 * gradient)) @ (
            efficiency_basis
        )
        try:
            np.linalg.cholesky(hessian)
        except np.linalg.LinAlgError:
            pass
        else:
            normal = hessian
        stride = normal.shape[0] + 1
        accepted = None
        while damping < 1e12:
            # The damping on the diagonal as a strided view of a copy (the same sums as adding
            # a diagonal matrix, without forming it).
            system = normal.copy()
            system.reshape(-1)[::stride] += damping * diagonal
            trial = x + np.linalg.solve(system, descent)
            efficiency = efficiency_basis @ trial[:b_eta]
            if efficiency.min() > 0:  # (NaN fails, as every element's test would)
                trial_cost = cost_of(trial, efficiency)
                if trial_cost[0] <= cost:
                    accepted = trial, trial_cost
                    break
            damping *= 10.0
        if accepted is None:
            break
        previous, before = cost, x
        x, (cost, inverse, data_residual, penalty_residual) = accepted
        damping = max(damping / 10.0, 1e-12)
        if previous - cost <= 1e-12 * previous:
            if not np.array_equal(x, before):
                current = None  # (a step below the last bit leaves the Jacobians at x)
            break
        current = None
    if current is None:
        current = _efficiency_jacobians(
            data_nodes, penalty_nodes, efficiency_basis, inverse, buffers
        )
    return x, inverse, data_residual, penalty_residual, current


def upre_scores(
    weights: FloatArray,
    data_residuals: Sequence[FloatArray],
    data_jacobians: Sequence[FloatArray],
    penalty_jacobians: Sequence[FloatArray],
) -> FloatArray:
    """:func:`weight_score`'s ``"upre"`` at each of ``weights``, from each weight's solution
    (residuals and Jacobians of the same shapes), every number the one it gives weight by weight:
    the normal matrices stacked, their pseudo-inverses in one pass (:func:`calib.core.blas.pinv_symmetric_stack`)."""
    data = np.stack(data_jacobians)
    penalty = np.stack(penalty_jacobians)
    normal_data = np.matmul(np.swapaxes(data, 1, 2), data)
    normal = normal_data + np.matmul(
        np.asarray(weights, dtype=np.float64)[:, None, None] * np.swapaxes(penalty, 1, 2), penalty
    )
    product = np.matmul(pinv_symmetric_stack(normal), normal_data)
    return np.array(
        [
            float(residual @ residual) + 2.0 * float(product[index].trace())
            for index, residual in enumerate(data_residuals)
        ]
    )


#: The prior-weight search's coarse step over :data:`PRIOR_WEIGHTS` (4 steps of 10^¼: one decade).
COARSE_STRIDE = 4
#: The coarse descent stops after this many coarse weights in a row scored above the best.
COARSE_PATIENCE = 2
#: A pass after the first (and each pass of a perturbation re-solve) scores the weights within
#: this many steps of :data:`PRIOR_WEIGHTS` of the choice before, and further out while the best
#: of them is on the edge.
WEIGHT_WINDOW = 1


def _nonlinear_efficiency(
    data_nodes: FloatArray,
    target: FloatArray,
    penalty_nodes: FloatArray,
    efficiency_basis: FloatArray,
    start: FloatArray,
    prior_weight: float | None,
    rule: WeightRule,
    near_index: int | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, float, FloatArray, int | None]:
    """``η = B c`` (smooth and positive; ``η⁻¹`` is not): ``λ`` by ``rule`` on the linearisation.

    ``λ`` is the weight of :data:`PRIOR_WEIGHTS` with the best score (decision 0125), found
    without solving at all 41: with no ``near_index``, every :data:`COARSE_STRIDE`-th weight from
    the largest down until :data:`COARSE_PATIENCE` of them in a row score above the best, then
    every weight within a stride of the best (until the best has both neighbours scored); with
    ``near_index`` (the choice of the pass before, or of the main solve), the weights within
    :data:`WEIGHT_WINDOW` of it, widened while the best is on the window's edge. Each weight is
    solved from the solution at the next larger weight solved before it (or from ``start``), with
    that solution's Jacobians; :func:`weight_score` uses the residuals and Jacobians at each
    solution. Returns ``x``, its ``(J_d, J_p)``, ``λ``, the scores over :data:`PRIOR_WEIGHTS`
    (NaN where not solved; the one score for a fixed ``prior_weight``) and the chosen index
    (``None`` for a fixed weight).
    """

    def solved_at(
        weight: float, origin: tuple[FloatArray, tuple[FloatArray, FloatArray] | None]
    ) -> tuple[FloatArray, float, tuple[FloatArray, FloatArray]]:
        x, _, data_residual, penalty_residual, jacobians = _efficiency_terms_solve(
            data_nodes, target, penalty_nodes, efficiency_basis, origin[0], weight, origin[1]
        )
        data_jac, penalty_jac = jacobians
        if rule == "upre":
            score = float(
                upre_scores(np.array([weight]), [data_residual], [data_jac], [penalty_jac])[0]
            )
        else:
            score = weight_score(
                rule, weight, data_residual, penalty_residual, data_jac, penalty_jac
            )
        return x, score, jacobians

    if prior_weight is not None:
        x, score, (data_jac, penalty_jac) = solved_at(prior_weight, (start, None))
        return x, data_jac, penalty_jac, prior_weight, np.array([score]), None
    last = PRIOR_WEIGHTS.size - 1
    solutions: dict[int, tuple[FloatArray, tuple[FloatArray, FloatArray]]] = {}
    scores = np.full(PRIOR_WEIGHTS.size, np.nan)

    def solve(index: int, origin: int | None) -> None:
        x, scores[index], jacobians = solved_at(
            float(PRIOR_WEIGHTS[index]), (start, None) if origin is None else solutions[origin]
        )
        solutions[index] = (x, jacobians)

    def chain(indices: Sequence[int], origin: int | None) -> None:
        for index in indices:
            if index not in solutions:
                solve(index, origin)
            origin = index

    def best() -> int:
        return int(np.nanargmin(scores))

    if near_index is None:
        # The coarse descent.
        origin: int | None = None
        above = 0
        coarse = list(range(last, -1, -COARSE_STRIDE))
        if coarse[-1] != 0:
            coarse.append(0)
        for index in coarse:
            solve(index, origin)
            origin = index
            above = 0 if index == best() else above + 1
            if above >= COARSE_PATIENCE:
                break
        # Every weight within a stride of the coarse best: those above it downwards from the
        # coarse weight above (upwards from the best at the grid's top), those below from it.
        chosen = best()
        upper = range(chosen + COARSE_STRIDE - 1, chosen, -1)
        if chosen + COARSE_STRIDE in solutions:
            chain([i for i in upper if i <= last], chosen + COARSE_STRIDE)
        else:
            chain([i for i in upper[::-1] if i <= last], chosen)
        chain([i for i in range(chosen - 1, chosen - COARSE_STRIDE, -1) if i >= 0], chosen)
    else:
        # The window: from the choice before's solution, downwards.
        chain(
            range(
                min(last, near_index + WEIGHT_WINDOW), max(-1, near_index - WEIGHT_WINDOW - 1), -1
            ),
            None,
        )
    # Widened until the best has both neighbours scored: each new one from the best's solution.
    while True:
        chosen = best()
        missing = [i for i in (chosen + 1, chosen - 1) if 0 <= i <= last and i not in solutions]
        if not missing:
            break
        for index in missing:
            solve(index, chosen)
    x, (data_jac, penalty_jac) = solutions[chosen]
    return x, data_jac, penalty_jac, float(PRIOR_WEIGHTS[chosen]), scores, chosen


@dataclass(frozen=True)
class EfficiencySettings:
    """How step 2 solves for the efficiency (checked on construction).

    Attributes
    ----------
    terms
        Fourier terms of ``η`` (or of ``η⁻¹``, by ``model``).
    model
        ``"efficiency"``: ``η = B c``, by Gauss–Newton; ``"inverse"``: the paper's ``η⁻¹ = B c``,
        linear (:data:`EFFICIENCY_MODELS`).
    prior_weight
        A fixed ``λ`` instead of the rule's.
    weight_rule
        How ``λ`` is chosen: ``"upre"``, ``"typicality"`` or ``"evidence"``
        (:data:`PRIOR_WEIGHT_RULES`; typicality falls back to UPRE when the prior carries no typical
        distance).
    grating_model
        ``"fourier"`` (``terms`` free terms, ``η₀`` flat), ``"sinusoidal"`` or ``"blazed"``
        (physical, ``η₀`` from the same parameter: :mod:`calib.methods.grating_models`), or
        ``"auto"`` (default): judged on the direct equations at the rig's error level
        (:mod:`calib.methods.grating_models`).
    direct_gain_sigma
        Relative σ of each lamp's direct-to-profile ratio, shared by its channels
        (:data:`DIRECT_GAIN_SIGMA`; 0 for data without exposure errors, as the paper's protocol).
    choice_spread
        Carry the other physical family's share of the evidence in ``η⁻¹``'s covariance
        (:func:`with_choice_spread`, decision 0053). Off where the covariance weighs the data
        against the camera prior (the prior solve's blend, :func:`blend_with_prior`): there the
        spread would not widen σ but pull the camera toward the prior (validation, LED only:
        Canon 20D 1.22 → 3.02, Pentax Q 1.44 → 4.45).
    """

    terms: int = DEFAULT_EFFICIENCY_TERMS
    model: EfficiencyModel = DEFAULT_EFFICIENCY_MODEL
    prior_weight: float | None = None
    weight_rule: WeightRule = DEFAULT_WEIGHT_RULE
    grating_model: GratingModelName = DEFAULT_GRATING_MODEL
    direct_gain_sigma: float = DIRECT_GAIN_SIGMA
    choice_spread: bool = True

    def __post_init__(self) -> None:
        check_grating_model(self.grating_model)
        if not 0.0 <= self.direct_gain_sigma < 1.0:
            raise InputError(
                f"must be in [0, 1), got {self.direct_gain_sigma}", source="direct_gain_sigma"
            )
        if self.model not in EFFICIENCY_MODELS:
            raise InputError(
                f"unknown efficiency model {self.model!r}; choose from {EFFICIENCY_MODELS}",
                source="efficiency_model",
            )
        if self.weight_rule not in PRIOR_WEIGHT_RULES:
            raise InputError(
                f"unknown prior weight rule {self.weight_rule!r}; choose from {PRIOR_WEIGHT_RULES}",
                source="weight_rule",
            )


def solve_efficiency(
    lamps: Sequence[LampData],
    prior: CameraPrior,
    settings: EfficiencySettings = EfficiencySettings(),
    *,
    prior_groups: Sequence[Sequence[LampData]] | None = None,
) -> EfficiencySolution:
    """Step 2: the grating from every lamp's direct equations, by ``settings.grating_model``.

    ``"fourier"``: :func:`solve_fourier_efficiency`; ``"sinusoidal"``/``"blazed"``: the physical
    family (:func:`calib.methods.grating_models.fit_physical`, no camera prior); ``"auto"``: all
    three, the one with the smallest predictive risk (Mallows' ``C_L``) judged at the rig's error
    level (:mod:`calib.methods.grating_models`). The choice, its rule, every candidate's risk and
    the physical model's parameters with σ are in ``info["grating_model"]``.

    Inside a :func:`calib.methods.solve_scope.solve_scope` the same inputs give the result already
    computed, and a perturbation re-solve starts each physical fit from the main solve's
    (:func:`physical_fit`).
    """
    if not lamps:
        raise InputError("no lamps with a direct measurement", source="observations")
    groups = None if prior_groups is None else [tuple(group) for group in prior_groups]
    # The lamps' content digested once for this key and both physical fits' (decision 0137).
    lamps_key = fingerprint(tuple(lamps)).hex()
    return reuse(
        "solve_efficiency",
        (lamps_key, prior, settings, groups),
        lambda: _solve_efficiency(lamps, prior, settings, prior_groups, lamps_key),
    )


#: A physical fit's χ² scan with another local minimum below ``AMBIGUOUS_SCAN_FACTOR × best +
#: AMBIGUOUS_SCAN_OFFSET`` has two basins a perturbation could swap: its re-solves scan in full.
AMBIGUOUS_SCAN_FACTOR = 2.0
AMBIGUOUS_SCAN_OFFSET = 10.0


def _unambiguous(fit: PhysicalFit) -> bool:
    """Whether the fit's scan has one basin (no other local minimum near the best's χ²)."""
    _, chi2 = fit.scan
    finite = np.where(np.isfinite(chi2), chi2, np.inf)
    if finite.size < 3:
        return False
    best = int(np.argmin(finite))
    inner = (finite[1:-1] <= finite[:-2]) & (finite[1:-1] <= finite[2:])
    minima = [int(index) + 1 for index in np.flatnonzero(inner)]
    if finite[0] < finite[1]:
        minima.append(0)
    if finite[-1] < finite[-2]:
        minima.append(finite.size - 1)
    limit = AMBIGUOUS_SCAN_FACTOR * float(finite[best]) + AMBIGUOUS_SCAN_OFFSET
    return not any(index != best and finite[index] <= limit for index in minima)


def physical_fit(
    lamps: Sequence[LampData],
    kind: PhysicalKind,
    wavelength_nm: FloatArray,
    gain_sigma: float,
    lamps_key: str | None = None,
) -> PhysicalFit:
    """:func:`calib.methods.grating_models.fit_physical` over the parameter's whole range (the
    open scope's result for the same lamps, when there is one); in a perturbation re-solve (:mod:`calib.methods.solve_scope`), refined in the window around the
    main solve's parameter when the main fit's scan had one basin, unless the optimum lands on the
    window's edge (then the full scan).

    ``lamps_key``: :func:`calib.methods.solve_scope.fingerprint` of ``tuple(lamps)`` as hex, when
    the caller has it. The scope's look-up and its store share one key made here, so the lamps'
    content (their operators and spectra: most of a key's cost) is digested at most once per call
    and, with ``lamps_key``, once for every family (decision 0137)."""
    key = lamps_key if lamps_key is not None else fingerprint(tuple(lamps)).hex()
    parts = (fingerprint(key, kind, wavelength_nm, gain_sigma).hex(),)
    done = recall("fit_physical", parts)
    if isinstance(done, PhysicalFit):
        return done
    label = f"physical {kind}: {', '.join(lamp.name for lamp in lamps)}"
    start = warm_start(label)
    if start is not None:
        fit = fit_physical(lamps, kind, wavelength_nm, gain_sigma=gain_sigma, near=float(start))
        candidates, chi2 = fit.scan
        low, high = PHYSICAL_PARAMETER_RANGES[kind]
        best = int(np.nanargmin(chi2))
        inside = (best > 0 or candidates[0] <= low) and (
            best < candidates.size - 1 or candidates[-1] >= high
        )
        if inside:
            return fit
    fit = reuse(
        "fit_physical",
        parts,
        lambda: fit_physical(lamps, kind, wavelength_nm, gain_sigma=gain_sigma),
    )
    if _unambiguous(fit):
        remember_start(label, fit.parameter)
    return fit


def jackknifed(
    fit: PhysicalFit,
    lamps: Sequence[LampData],
    gain_sigma: float | None,
    lamps_key: str | None = None,
) -> PhysicalFit:
    """:func:`calib.methods.grating_models.with_jackknife` of ``fit``, or the open scope's result
    for the same fit, lamps and gain σ (:mod:`calib.methods.solve_scope`; ``lamps_key`` as
    :func:`physical_fit` takes it).

    Its refits (one per lamp left out) are most of a multi-lamp solve's physical fits, and the σ
    budget's η-terms re-solve, whose options change only the Fourier model's terms, asks again
    for the very fit the main solve jackknifed (the fit recalled from the scope, the same lamps):
    VALIDATION split, first 4 cameras, 5 lamps, 74 of the jackknife's 631 ms (decision 0137)."""
    key = lamps_key if lamps_key is not None else fingerprint(tuple(lamps)).hex()
    return reuse(
        "with_jackknife",
        (fit, key, gain_sigma),
        lambda: with_jackknife(fit, lamps, gain_sigma=gain_sigma),
    )


def _solve_efficiency(
    lamps: Sequence[LampData],
    prior: CameraPrior,
    settings: EfficiencySettings,
    prior_groups: Sequence[Sequence[LampData]] | None,
    lamps_key: str | None = None,
) -> EfficiencySolution:
    choice = settings.grating_model
    wavelength = prior.grid.wavelength_nm
    gain = settings.direct_gain_sigma
    noise_only: dict[str, float] = {}
    judged: dict[str, float] = {}
    fourier: EfficiencySolution | None = None
    if choice in ("fourier", "auto"):
        fourier = solve_fourier_efficiency(lamps, prior, settings, prior_groups=prior_groups)
        noise_only["fourier"] = float(fourier.info["predictive_risk"])
        if choice == "auto":
            judged["fourier"] = _fourier_judged_risk(fourier, lamps, gain, CHOICE_FLOOR)
    fits: list[PhysicalFit] = []
    failures: dict[str, str] = {}
    for kind in PHYSICAL_KINDS:
        if choice not in (kind, "auto"):
            continue
        try:
            fit = physical_fit(lamps, kind, wavelength, gain, lamps_key)
        except EstimationError as error:
            if choice != "auto":
                raise
            failures[kind] = str(error)
            continue
        fits.append(fit)
        noise_only[kind] = fit.predictive_risk
        if choice == "auto":
            judged[kind] = (
                fit.judged_chi2(lamps, gain, CHOICE_FLOOR) + choice_penalty(fit.n_equations) * 2
            )
    candidates = judged if choice == "auto" else noise_only
    chosen = min(candidates, key=lambda name: candidates[name])
    weights = {chosen: 1.0}
    # Each pinned family's weight among all fits (None where the choice is not between families).
    bounded: dict[str, float | None] = {fit.kind: None for fit in fits if fit.at_range_bound}
    if choice == "auto" and chosen != "fourier":
        # Physical against free at the rig's error level; which physical family, at the stated
        # noise (decision 0053), among the fits inside their range when any is (decision 0063).
        inside = family_weights(interior_fits(fits))
        chosen = max(inside, key=lambda name: inside[name])
        # σ still holds a pinned family's share of the evidence (the data do not rule it out).
        weights = family_weights(fits)
        bounded = {kind: weights.get(kind, 0.0) for kind in bounded}
        if chosen not in weights:
            weights = inside
    rule = CHOICE_RULE if choice == "auto" else "given"
    common = {
        "chosen": chosen,
        "requested": choice,
        "rule": rule,
        "predictive_risk": candidates,
        **(
            {
                "noise_only_predictive_risk": noise_only,
                "error_floor": CHOICE_FLOOR,
            }
            if choice == "auto"
            else {}
        ),
        **({"failed": failures} if failures else {}),
        **({"at_range_bound": bounded} if bounded else {}),
    }
    if chosen == "fourier":
        assert fourier is not None
        record = {"model": "fourier", "terms": int(fourier.coefficients.size), **common}
        return replace(fourier, info={**fourier.info, "grating_model": record})
    carried = weights if settings.choice_spread else {chosen: 1.0}
    solutions = {
        kind: physical_solution(fit, {**fit.record(), **common})
        for kind in carried
        for fit in [
            jackknifed(
                next(fit for fit in fits if fit.kind == kind),
                lamps,
                settings.direct_gain_sigma,
                lamps_key,
            )
        ]
    }
    if not settings.choice_spread:
        return solutions[chosen]
    return with_choice_spread(solutions, weights, chosen)


#: A physical family whose evidence weight (:func:`choice_weights`) is below this share adds
#: nothing measurable to the chosen model's σ and is not carried (saves its jackknife).
MIN_CHOICE_WEIGHT = 0.01


def interior_fits(fits: Sequence[PhysicalFit]) -> list[PhysicalFit]:
    """The fits whose parameter is inside its search range (:attr:`PhysicalFit.at_range_bound`),
    or every fit when none is (decision 0063).

    A fit pinned at its range's end has no χ² minimum among real sheets: it is the family bent
    to its limit to absorb the rig's per-lamp errors (validation split, 3 lamps + RGB LEDs: the
    two confident wrong picks were blazed fits at λ_B = 150.5 and 170.9 nm, the range's foot then,
    on sinusoidal sheets), so it does not compete for the family when another family's fit is an
    interior minimum."""
    inside = [fit for fit in fits if not fit.at_range_bound]
    return inside or list(fits)


def family_weights(fits: Sequence[PhysicalFit]) -> dict[str, float]:
    """The physical families' evidence weights from their direct equations at the stated noise:
    Akaike weights ``w_k ∝ exp(−Δ_k/2)`` of the quasi-likelihood criterion ``QAIC_k = χ²_k/ĉ +
    2·2`` (Burnham & Anderson 2002, §2.5 and §2.9), ``ĉ = max(1, χ²_best/(n − 2))`` the best
    family's reduced χ² (the rig's errors beyond the stated noise, shared by both families, divide
    the evidence instead of deciding it). Those below :data:`MIN_CHOICE_WEIGHT` are dropped and
    the rest renormalised.

    Why the stated noise here and the 2 % floor for physical against free (decision 0053): two
    2-parameter families cannot bend to the rig's per-lamp errors, so the precise equations —
    which the floor levels away — are what tells a sheet's ``J₁²`` from a blaze's ``sinc²``; on
    9 of the validation split's near-ties (judged ``C_L`` within 2) the floor picked the wrong
    family twice, the stated noise once. The free Fourier model is not among the weights: its
    ``η⁻¹`` is in the direct path's gauge, not the physical ``1/η₁``, and it stands alone when it
    wins."""
    risks = {fit.kind: fit.chi2 for fit in fits}
    best = min(risks.values())
    equations = next(fit.n_equations for fit in fits if fit.chi2 == best)
    dispersion = max(1.0, best / max(equations - 2, 1))
    physical = {kind: chi2 / dispersion for kind, chi2 in risks.items()}
    best = min(physical.values())
    raw = {kind: math.exp(-0.5 * (risk - best)) for kind, risk in physical.items()}
    total = sum(raw.values())
    kept = {
        kind: weight / total for kind, weight in raw.items() if weight / total >= MIN_CHOICE_WEIGHT
    }
    total = sum(kept.values())
    return {kind: weight / total for kind, weight in kept.items()}


def with_choice_spread(
    solutions: Mapping[str, EfficiencySolution], weights: Mapping[str, float], chosen: str
) -> EfficiencySolution:
    """The chosen family's solution with the model choice's own uncertainty in its covariance
    (decision 0053): the estimate stays the chosen model's (the families are not averaged — on
    the validation split an average moved the near-ties' RE toward the mean of right and wrong,
    no better on the whole), and its ``η⁻¹`` covariance becomes the expected squared error about
    it over the families, ``Σ_k w_k (Σ_k + (h_k − h_c)(h_k − h_c)ᵀ)``: the coefficients are every
    family's ``(p, log T)`` and one unit-variance term per other family, with Jacobian columns
    ``√w_k ∂h_k/∂θ_k`` and ``√w_k (h_k − h_c)``. With one family it is that family's solution.
    The perturbation re-solves of the σ budget keep the chosen family alone
    (:func:`calib.methods._rerun`), so the spread is counted once, here."""
    centre = solutions[chosen]
    if len(solutions) == 1:
        return centre
    kinds = [chosen, *(kind for kind in solutions if kind != chosen)]
    inverse = centre.inverse_efficiency
    columns, posterior, noise = [], [], []
    for kind in kinds:
        root = math.sqrt(weights[kind])
        columns.append(root * solutions[kind].inverse_jacobian)
        posterior.append(solutions[kind].coefficient_covariance)
        noise.append(solutions[kind].noise_covariance)
    spread = [
        math.sqrt(weights[kind]) * (solutions[kind].inverse_efficiency - inverse)[:, None]
        for kind in kinds[1:]
    ]
    columns.extend(spread)
    posterior.append(np.eye(len(spread)))
    noise.append(np.zeros((len(spread), len(spread))))
    coefficients = np.concatenate(
        [solutions[kind].coefficients for kind in kinds] + [np.zeros(len(spread))]
    )
    record = dict(centre.info["grating_model"])
    record["choice_weights"] = {kind: weights[kind] for kind in kinds}
    record["choice_spread"] = (
        "σ holds the other families' share: Σ_k w_k (Σ_k + (h_k − h_chosen)²), w from QAIC at "
        "the stated noise"
    )
    return replace(
        centre,
        coefficients=coefficients,
        coefficient_covariance=block_diag(*posterior),
        noise_covariance=block_diag(*noise),
        inverse_jacobian=np.concatenate(columns, axis=1),
        info={**centre.info, "grating_model": record},
    )


#: How ``"auto"`` chooses the grating model (recorded with the choice).
CHOICE_RULE = (
    "χ² of the direct equations at the rig's error level plus max(2, log n) per effective parameter "
    "(BIC): each equation's σ floored at CHOICE_FLOOR of its signal, the free throughput "
    "profiled out there; between the physical families, their quasi-likelihood (QAIC) at the "
    "stated noise"
)


def choice_penalty(n_equations: int) -> float:
    """What each (effective) parameter costs when ``auto`` judges the grating models:
    ``log n`` of the ``n`` direct equations (Schwarz's criterion, BIC), not Mallows' 2.

    The choice is a question of *which* η the sheet has — the sensitivity is ``Q ⊙ 1/η₁`` — not
    of predicting new direct measurements, which is what ``C_L``'s 2 per parameter estimates: a
    free η that bends to the rig's per-lamp errors predicts them better and gets η's shape wrong.
    Validation split, 3 lamps + RGB LEDs (18 equations, the Fourier model's ``tr H`` ≈ 7): of 44
    sinusoidal sheets ``C_L`` took the free model once (Canon 10D (Huynh), RE 3.45 against 0.53
    for the sheet's model), of the same cameras behind a blue filter twice (Nikon D3X 7.17 / 0.65,
    Canon 5D (Kawakami) 11.2 / 0.68); ``log n`` moves the first two, nothing else on 44 sinusoidal,
    44 blazed and 15 catalogue sheets (decision 0058). The free model's estimate, forced, was
    2–42 ×10⁻² on every one of those sheets.

    Never less than ``C_L``'s 2: below ``e² ≈ 7.4`` equations ``log n`` would charge a parameter
    *less* than ``C_L`` and favour the free model, the opposite of the reason above. The prior
    solve judges 3 (LED only) or 6 (LED+FL) equations; charged ``log n``, two held-out cameras
    took the free model (Sony ILCE-7SM3 LED+FL 1.58 → 13.8, Nikon D850 LED only 4.45 → 9.01
    ×10⁻², found on the test split after the merge). With the floor those choices are main's
    before decision 0058 again, and no validation figure of 0058 moves (its ``n`` is 15–18).

    Examples
    --------
    >>> round(choice_penalty(18), 3)
    2.89
    >>> choice_penalty(3), choice_penalty(6)
    (2.0, 2.0)
    """
    return max(2.0, math.log(max(n_equations, 2)))


def _fourier_judged_risk(
    fourier: EfficiencySolution, lamps: Sequence[LampData], gain_sigma: float, floor: float
) -> float:
    """The Fourier model's judged risk with each direct equation's σ floored at ``floor`` of its
    signal: the χ² of its residuals so judged — ``η⁻¹``'s overall scale (the direct path's
    throughput) profiled out at that weighting, as the physical models' ``T`` — plus its
    effective number of parameters (``tr H`` of the fit, :func:`weight_score`) at
    :func:`choice_penalty` each."""
    inverse = fourier.inverse_efficiency
    rows, target = direct_rows(lamps, inverse, gain_sigma=gain_sigma, floor=floor)
    _, chi2 = profile_throughput(rows @ inverse, target)
    parameters = 0.5 * (float(fourier.info["predictive_risk"]) - float(fourier.info["direct_chi2"]))
    return chi2 + choice_penalty(target.size) * parameters


def physical_solution(fit: PhysicalFit, record: dict[str, Any]) -> EfficiencySolution:
    """A physical fit as step 2's result: ``η⁻¹`` is ``h = 1/η₁``, the coefficients
    ``(p, log T)``, and the direct equations' weight ``T η₀``."""
    inverse, jacobian = fit.inverse_efficiency()
    return EfficiencySolution(
        inverse_efficiency=inverse,
        coefficients=np.array([fit.parameter, fit.log_throughput]),
        coefficient_covariance=fit.covariance,
        noise_covariance=fit.noise_covariance,
        prior_weight=0.0,
        inverse_jacobian=jacobian,
        info={
            "prior_weight": 0.0,
            "prior_weight_rule": "none (physical grating model)",
            "prior_share": 0.0,
            "efficiency_model": fit.kind,
            "direct_chi2": fit.chi2,
            "direct_equations": fit.n_equations,
            "efficiency_terms": 2,
            "predictive_risk": fit.predictive_risk,
            "grating_model": record,
        },
        direct_weight=fit.direct_weight(),
    )


def solve_fourier_efficiency(
    lamps: Sequence[LampData],
    prior: CameraPrior,
    settings: EfficiencySettings = EfficiencySettings(),
    *,
    prior_groups: Sequence[Sequence[LampData]] | None = None,
) -> EfficiencySolution:
    """Step 2 with the free Fourier model: ``η`` from every lamp's direct equations, under the
    camera prior (``η₀`` taken as flat).

    Parameters
    ----------
    lamps
        Responses and direct measurements (any number, from one or several cameras: the rows do not
        involve the camera).
    prior
        The camera prior, applied to each camera's ``s_k = Q_k ⊙ η⁻¹`` with its own scale ``α_k``.
    settings
        Terms, model and prior weight (:class:`EfficiencySettings`).
    prior_groups
        The lamps of each camera (``Q_k`` is pooled over a camera's lamps); default: ``lamps`` are
        one camera's.
    """
    if not lamps:
        raise InputError("no lamps with a direct measurement", source="observations")
    model, prior_weight = settings.model, settings.prior_weight
    efficiency_basis = fourier_basis(prior.grid, settings.terms)
    size, b_eta = efficiency_basis.shape
    reference = lamps[0]
    # The prior judges s = Q ⊙ η⁻¹, Q pooled over a camera's lamps (in its first lamp's units):
    # the same s the solve returns, and less noisy than any one lamp's response.
    groups = [
        pool_responses([lamp.response for lamp in group])[0] for group in prior_groups or [lamps]
    ]
    predicted = float(np.sum(reference.direct_row @ reference.response.response))
    if predicted <= 0 or float(np.sum(reference.direct)) <= 0:
        raise EstimationError("the direct signal or the fitted first-order response is zero")
    inverse = np.full(size, float(np.sum(reference.direct)) / predicted)
    scales = np.array(
        [
            float(np.sum(group.response * inverse[:, None]))
            / max(float(np.sum(prior.mean)), 1e-300)
            for group in groups
        ]
    )
    x = np.concatenate(
        [np.linalg.lstsq(efficiency_basis, 1.0 / inverse, rcond=None)[0], scales]
        if model == "efficiency"
        else [np.zeros(b_eta), scales]
    )
    weight = 0.0
    scores = np.zeros(0)
    data = penalty = np.zeros((0, b_eta + len(groups)))
    data_nodes = np.zeros((0, size))
    target = np.zeros(0)
    inverse_jacobian = efficiency_basis
    typical = prior.typical_distance
    by_typicality = (
        prior_weight is None
        and settings.weight_rule == "typicality"
        and typical is not None
        and np.isfinite(typical)
    )
    # The rule scoring the weights on each pass (typicality without a typical distance: UPRE).
    scoring: WeightRule = "evidence" if settings.weight_rule == "evidence" else "upre"
    rule = (
        "fixed"
        if prior_weight is not None
        else "typicality"
        if by_typicality
        else {"evidence": "evidence", "upre": "UPRE"}[scoring]
    )
    # The typicality rule starts every camera's prior at its natural weight (1) and, after each
    # pass, sets it to typical / D²_k from that pass's sensitivity (see PRIOR_WEIGHT_RULES).
    group_weights = np.ones(len(groups))
    distances = np.full(len(groups), np.nan)
    # A perturbation re-solve scores the weights near the main solve's choice on each pass.
    # (The grating model is not part of this solve: a re-solve that keeps "auto"'s choice shares it.)
    same = replace(settings, grating_model=DEFAULT_GRATING_MODEL)
    label = f"fourier {same!r}: {', '.join(lamp.name for lamp in lamps)}"
    scanned = model == "efficiency" and prior_weight is None and not by_typicality
    starts = warm_start(label) if scanned else None
    chosen_indices: list[int | None] = []
    for index in range(EFFICIENCY_PASSES):
        # Rows on the grid's nodes of η⁻¹ (and every α_k), whitened at the current η⁻¹.
        data_nodes, target = direct_rows(lamps, inverse, gain_sigma=settings.direct_gain_sigma)
        penalty_nodes = _stacked_prior_rows(groups, prior, inverse, x[b_eta:])
        fixed = prior_weight
        used_weights = group_weights
        if by_typicality:
            penalty_nodes *= np.repeat(np.sqrt(group_weights), 3 * size)[:, None]
            fixed = 1.0
        if model == "inverse":
            x, data, penalty, weight, scores = _linear_efficiency(
                data_nodes, target, penalty_nodes, efficiency_basis, fixed, scoring
            )
            inverse = efficiency_basis @ x[:b_eta]
        else:
            # Each pass after the first scores the weights near the pass before's choice; a
            # perturbation re-solve, near the main solve's choice on the same pass.
            near = int(starts[index]) if starts is not None else (chosen_indices or [None])[-1]
            x, data, penalty, weight, scores, chosen_index = _nonlinear_efficiency(
                data_nodes, target, penalty_nodes, efficiency_basis, x, fixed, scoring, near
            )
            chosen_indices.append(chosen_index)
            inverse = 1.0 / (efficiency_basis @ x[:b_eta])
            inverse_jacobian = -(inverse**2)[:, None] * efficiency_basis
        x[b_eta:] = np.where(np.abs(x[b_eta:]) > 0, np.abs(x[b_eta:]), scales)
        if not by_typicality and index < EFFICIENCY_PASSES - 1:
            continue  # the scored rules do not need the distances; diagnostics take the last pass's
        distances = np.array(
            [prior_distance(prior, group.response * inverse[:, None]) for group in groups]
        )
        if by_typicality:
            assert typical is not None
            group_weights = np.clip(
                typical / np.maximum(distances, 1e-300), PRIOR_WEIGHTS[0], PRIOR_WEIGHTS[-1]
            )
    if scanned and None not in chosen_indices:
        remember_start(label, tuple(chosen_indices))
    posterior = np.asarray(
        pinv_symmetric(data.T @ data + weight * penalty.T @ penalty),
        dtype=np.float64,
    )
    residual = data_nodes @ inverse - target
    # Mallows' C_L at the chosen weight: comparable with a physical model's χ² + 2k.
    risk = weight_score("upre", max(weight, 1e-300), residual, np.zeros(0), data, penalty)
    singular = np.linalg.svd(data[:, :b_eta], compute_uv=False)
    reported_weight = float(used_weights[0] * weight)
    # The prior's share of the posterior precision of η's terms: falls as lamps are added.
    prior_precision = weight * penalty.T @ penalty
    prior_share = float(np.trace((posterior @ prior_precision)[:b_eta, :b_eta]) / max(b_eta, 1))
    return EfficiencySolution(
        inverse_efficiency=inverse,
        coefficients=x[:b_eta],
        coefficient_covariance=posterior[:b_eta, :b_eta],
        noise_covariance=(posterior @ data.T @ data @ posterior)[:b_eta, :b_eta],
        prior_weight=reported_weight,
        inverse_jacobian=inverse_jacobian,
        info={
            "prior_weight": reported_weight,
            "prior_weight_rule": rule,
            "prior_weights": (used_weights * weight).tolist(),
            "prior_distances": distances.tolist(),
            "typical_distance": typical,
            "prior_share": prior_share,
            "efficiency_model": model,
            "direct_chi2": float(residual @ residual),
            "predictive_risk": risk,
            "direct_equations": int(data.shape[0]),
            "efficiency_terms": b_eta,
            "data_condition": float(singular[0] / max(singular[-1], 1e-300)),
            "weight_curve": scores.tolist(),
        },
    )


def _stacked_prior_rows(
    groups: Sequence[ResponseEstimate],
    prior: CameraPrior,
    inverse: FloatArray,
    scales: FloatArray,
) -> FloatArray:
    """Every camera's whitened prior rows on the nodes of ``η⁻¹`` and its own ``α_k``: ``(3fK, f + K)``."""
    size = inverse.size
    identity = np.eye(size)
    rows = np.zeros((3 * size * len(groups), size + len(groups)))
    for index, (group, scale) in enumerate(zip(groups, scales, strict=True)):
        block = prior_rows(group, prior, identity, inverse, float(scale))
        band = slice(3 * size * index, 3 * size * (index + 1))
        rows[band, :size] = block[:, :size]
        rows[band, size + index] = block[:, -1]
    return rows


@dataclass(frozen=True, eq=False)
class SensitivitySolution:
    """Step 3's result.

    Attributes
    ----------
    sensitivity
        ``s`` ``(f, 3)`` in the first lamp's units (not normalised).
    covariance
        Joint covariance of ``s`` flattened channel-major (``s[:, 0]`` first), shape ``(3f, 3f)``,
        or ``None`` when not computed.
    lamp_scales
        Each lamp's brightness relative to the first ``(L,)``.
    """

    sensitivity: FloatArray
    covariance: FloatArray | None
    lamp_scales: FloatArray

    def normalised(self) -> tuple[FloatArray, FloatArray | None]:
        """``s / max s`` and its σ ``(f, 3)`` (the peak's own noise propagated, first order)."""
        flat = self.sensitivity.T.ravel()
        peak_index = int(np.argmax(flat))
        peak = float(flat[peak_index])
        if not np.isfinite(peak) or peak <= 0:
            raise EstimationError("the solve produced no positive sensitivity")
        if self.covariance is None:
            return self.sensitivity / peak, None
        jacobian = np.eye(flat.size) / peak
        jacobian[:, peak_index] -= flat / peak**2
        covariance = jacobian @ self.covariance @ jacobian.T
        sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        size = self.sensitivity.shape[0]
        return self.sensitivity / peak, sigma.reshape(3, size).T


#: Lamp kinds (:data:`calib.core.lamp_kinds.LAMP_KINDS`) whose responses give ``η`` its direct
#: equations but not the sensitivity's ``Q`` while a broadband lamp is there (decision 0058): a
#: narrow band's response is its profile over its measured spectrum, and the spectrometer's
#: wavelength scale (±0.5 nm) and slit (2–10 nm) move that ratio by ``δλ · d ln e/dλ`` — 6 % one
#: σ from a 20 nm LED's peak per 0.5 nm, a few ‰ for a white lamp — which the response's noise
#: covariance does not hold, while its weight in the inverse-variance mean is the largest there.
#: Validation split, 3 lamps + RGB LEDs, sinusoidal model: mean RE 0.77 → 0.73, and 0.94 → 0.71
#: with every camera behind a blue filter (the out-of-basis proxy).
NARROW_BAND_KINDS: tuple[str, ...] = ("narrowband",)


def lamp_kinds(observations: Sequence[LampObservation], lamps: Sequence[LampData]) -> list[str]:
    """The kind of each of ``lamps`` (by name, from the observations it was prepared from)."""
    kinds = {obs.name: obs.kind for obs in observations}
    return [kinds.get(lamp.name, "other") for lamp in lamps]


#: σ of the measured spectra's wavelength scale with which the lamps' responses are weighed into
#: ``Q`` (:func:`pool_responses`): the spectrometer's stated accuracy (±0.5 nm, taken as one σ;
#: :data:`calib.core.spectrometer_tolerance.WAVELENGTH_SCALE_NM`). A response is the profile over
#: the measured spectrum, so where the spectrum is steep — a fluorescent line's flanks, a white
#: LED's blue peak — half a nanometre moves it by tens of per cent, which its noise covariance does
#: not hold; weighed by noise alone, those lamps took most of ``Q`` exactly there (decision 0067).
POOLING_SCALE_SIGMA_NM = WAVELENGTH_SCALE_NM


def pooling_scale_sigmas(
    observations: Sequence[LampObservation], lamps: Sequence[LampData]
) -> list[float]:
    """The wavelength-scale σ (nm) each of ``lamps``' responses is weighed with in ``Q``: the σ its
    spectrum's Hg-line check left (:func:`calib.core.spectrometer_scale.scale_sigma_nm`, decision
    0069: the spectrum was corrected by the lines), else :data:`POOLING_SCALE_SIGMA_NM`."""
    checked = {obs.name: scale_sigma_nm(obs) for obs in observations}
    return [
        POOLING_SCALE_SIGMA_NM if (sigma := checked.get(lamp.name)) is None else sigma
        for lamp in lamps
    ]


def sensitivity_lamps(kinds: Sequence[str]) -> list[bool]:
    """Which lamps' responses make the sensitivity's ``Q`` (:func:`pool_responses`), by kind: all
    but the narrow-band ones (:data:`NARROW_BAND_KINDS`) when any other lamp is there, else all.

    Examples
    --------
    >>> sensitivity_lamps(["led", "fluorescent", "narrowband"])
    [True, True, False]
    >>> sensitivity_lamps(["narrowband", "narrowband"])
    [True, True]
    """
    broad = [kind not in NARROW_BAND_KINDS for kind in kinds]
    return broad if any(broad) else [True] * len(broad)


def pool_responses(
    responses: Sequence[ResponseEstimate],
    *,
    iterations: int = 4,
    pooled: Sequence[bool] | None = None,
    scale_sigma_nm: float | Sequence[float] | None = None,
) -> tuple[ResponseEstimate, FloatArray, FloatArray]:
    """``Q`` ``(f, 3)``: the inverse-variance mean of the lamps' ``q̂_lc / E_l``, with its covariance.

    The relative brightness ``E_l`` (first lamp = 1) is fitted by weighted least squares against the
    running combination. ``pooled`` (default: all): which responses enter ``Q``; every lamp's
    ``E_l`` is fitted against it. ``scale_sigma_nm``: the variances that weigh the lamps also hold
    each response's error from its spectrum's wavelength scale, off by this σ (one for every
    response, or one each: :func:`pooling_scale_sigmas`;
    :meth:`~calib.methods.responses.ResponseEstimate.scale_variance`, decision 0067); ``Q``'s
    covariance stays the noise's, propagated with those weights. Returns the pooled response,
    ``E`` ``(L,)`` and the weights ``(L, f, 3)`` (zero for a lamp left out of ``Q``).
    """
    stacked = np.stack([response.response for response in responses])  # (L, f, 3)
    variances = np.stack(
        [
            np.stack([np.diag(response.covariance[c]) for c in range(3)], axis=1)
            for response in responses
        ]
    )
    scale_sigmas = (
        None
        if scale_sigma_nm is None
        else [float(scale_sigma_nm)] * len(responses)
        if isinstance(scale_sigma_nm, int | float)
        else [float(value) for value in scale_sigma_nm]
    )
    if scale_sigmas is not None:
        variances = variances + np.stack(
            [
                response.scale_variance(sigma)
                for response, sigma in zip(responses, scale_sigmas, strict=True)
            ]
        )
    variances = np.maximum(variances, 1e-300)
    members = np.ones(len(responses)) if pooled is None else np.asarray(pooled, dtype=np.float64)
    if members.shape != (len(responses),) or not np.any(members):
        raise InputError(
            f"{members.size} pooling flags for {len(responses)} responses, none set",
            source="pooled",
        )
    scales = np.ones(len(responses))
    for _ in range(iterations):
        weights = members[:, None, None] * scales[:, None, None] ** 2 / variances
        combined = np.sum(weights * stacked / scales[:, None, None], axis=0) / np.sum(
            weights, axis=0
        )
        for index in range(len(responses)):
            denominator = float(np.sum(combined**2 / variances[index]))
            if denominator > 0:
                scales[index] = (
                    float(np.sum(stacked[index] * combined / variances[index])) / denominator
                )
        scales = scales / scales[0]
    weights = members[:, None, None] * scales[:, None, None] ** 2 / variances
    weights = weights / np.sum(weights, axis=0)
    combined = np.sum(weights * stacked / scales[:, None, None], axis=0)
    size = combined.shape[0]
    covariance = np.zeros((3, size, size))
    for c in range(3):
        for index, response in enumerate(responses):
            if not members[index]:
                continue
            factor = weights[index, :, c] / scales[index]
            covariance[c] += factor[:, None] * response.covariance[c] * factor[None, :]
            if scale_sigmas is not None:
                scale_variance = response.scale_variance(scale_sigmas[index])[:, c]
                covariance[c] += np.diag(factor**2 * scale_variance)
    used = np.any(np.stack([response.used_pixels for response in responses]), axis=0)
    chi2 = float(sum(response.chi2 for response in responses))
    return ResponseEstimate(combined, covariance, used, chi2), scales, weights


def combine_responses(
    responses: Sequence[ResponseEstimate],
    inverse_efficiency: FloatArray,
    efficiency_basis: FloatArray,
    coefficient_covariance: FloatArray,
    *,
    with_covariance: bool = True,
    pooled: Sequence[bool] | None = None,
    scale_sigma_nm: float | Sequence[float] | None = None,
) -> SensitivitySolution:
    """Step 3: ``s_c = Q_c ⊙ η⁻¹`` with ``Q`` from :func:`pool_responses` (of the ``pooled``
    responses, default all: :func:`sensitivity_lamps`; weighed with the spectra's wavelength scale
    at ``scale_sigma_nm`` when given: :func:`pooling_scale_sigmas`).

    ``η⁻¹ = B_η c_η`` with ``c_η``'s covariance propagated along ``Q_c ⊙ B_η`` (``B_η`` may be the
    identity, for an efficiency known node by node).
    """
    pooled_response, scales, _ = pool_responses(
        responses, pooled=pooled, scale_sigma_nm=scale_sigma_nm
    )
    combined = pooled_response.response
    size = inverse_efficiency.size
    sensitivity = combined * inverse_efficiency[:, None]
    if not with_covariance:
        return SensitivitySolution(sensitivity, None, scales)
    covariance = np.zeros((3 * size, 3 * size))
    for c in range(3):
        block = slice(c * size, (c + 1) * size)
        covariance[block, block] = (
            inverse_efficiency[:, None]
            * pooled_response.covariance[c]
            * inverse_efficiency[None, :]
        )
    jacobian = np.concatenate([combined[:, c][:, None] * efficiency_basis for c in range(3)])
    covariance += jacobian @ coefficient_covariance @ jacobian.T
    return SensitivitySolution(sensitivity, covariance, scales)


def blend_with_prior(solution: SensitivitySolution, prior: CameraPrior) -> SensitivitySolution:
    """The data's ``s`` combined with the camera prior ``N(α ŝ, α² Σ)`` (product of Gaussians).

    Where the lamp is bright the data dominate; where it is dim (σ far above the prior's spread) the
    prior fills in instead of amplified noise. ``α`` is fitted to the data. Used where η is known
    (a grating file): the prior then enters once, here.
    """
    if solution.covariance is None:
        return solution
    size = prior.grid.size
    data = solution.sensitivity.T.ravel()
    mean = prior.mean.T.ravel()
    scale = float(data @ mean) / max(float(mean @ mean), 1e-300)
    prior_precision = np.zeros((3 * size, 3 * size))
    for c in range(3):
        block = slice(c * size, (c + 1) * size)
        prior_precision[block, block] = np.linalg.inv(scale**2 * prior.covariance[c])
    data_precision = pinv_symmetric(solution.covariance)
    covariance = np.linalg.inv(data_precision + prior_precision)
    blended = covariance @ (data_precision @ data + prior_precision @ (scale * mean))
    return SensitivitySolution(
        blended.reshape(3, size).T, 0.5 * (covariance + covariance.T), solution.lamp_scales
    )


def mapping_lamps(observations: Sequence[LampObservation]) -> list[LampObservation]:
    """The lamps the mapping is searched with: fluorescent ones (their lines start the search) and
    the first other lamp; without a fluorescent lamp, the first two.

    More lamps add little to a mapping that is already within ~0.1 % (the efficiency, not the
    mapping, limits the estimate) and the search's cost grows with every lamp.
    """
    fluorescent = [obs for obs in observations if obs.kind == "fluorescent"]
    others = [obs for obs in observations if obs.kind != "fluorescent"]
    if fluorescent:
        return fluorescent + others[:1]
    return list(observations[:2])


def find_shared_mapping(
    observations: Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    mapping: QuadraticMapping | GratingGeometry | None,
    mapping_lamp: str | None,
    refine_given_mapping: bool,
    kernel: FloatArray | None,
    rig: RigGeometry | None = None,
) -> QuadraticMapping | GratingGeometry:
    """The given mapping, or one found jointly with :func:`mapping_lamps` (one geometry: one mapping)
    or with the lamp named ``mapping_lamp``; a given mapping seeds the search when
    ``refine_given_mapping``; ``rig``: a grating file's stored geometry (its physics)."""
    if mapping is not None and not refine_given_mapping:
        return mapping
    lamps = (
        mapping_lamps(observations)
        if mapping_lamp is None
        else lamps_named(observations, mapping_lamp)
    )
    return find_mapping(lamps, camera=prior, grid=grid, start=mapping, kernel=kernel, rig=rig)


@dataclass(frozen=True, eq=False)
class CalibratedLamps:
    """One camera's lamps solved for ``η``: the mapping, each lamp's data and the efficiency."""

    grid: WavelengthGrid
    mapping: QuadraticMapping | GratingGeometry
    lamps: tuple[LampData, ...]
    efficiency: EfficiencySolution
    mapping_s: float


def mapping_and_lamps(
    observations: Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    mapping: QuadraticMapping | GratingGeometry | None,
    mapping_lamp: str | None,
    refine_given_mapping: bool,
    kernel: FloatArray | None,
    *,
    need_direct: bool,
    rig: RigGeometry | None = None,
) -> tuple[QuadraticMapping | GratingGeometry, list[LampObservation], float]:
    """The mapping (:func:`find_shared_mapping`), the lamps to prepare on it (those with a direct
    measurement when ``need_direct``) and the time the mapping took."""
    started = time.perf_counter()
    used_mapping = find_shared_mapping(
        observations, prior, grid, mapping, mapping_lamp, refine_given_mapping, kernel, rig
    )
    mapping_s = time.perf_counter() - started
    chosen = [obs for obs in observations if obs.direct_rgb is not None or not need_direct]
    if not chosen:
        raise InputError(
            "no lamp has a direct (0th-order) measurement to solve with; give the grating's "
            "efficiency from an earlier calibration (grating=…, --grating FILE)",
            source="observations",
        )
    return used_mapping, chosen, mapping_s


#: A measured spectrum's dark range: samples below this share of its peak. A channel whose light
#: lies there sees the lamp only through the spectrometer's noise floor; a broadband lamp has no
#: such range, and its spectrum's curvature is not noise.
DARK_SHARE = 0.01
#: Fewest dark samples (with a neighbour each side) to read the noise floor from.
DARK_SAMPLES = 10


def spectrum_noise_floor(spectrum: Spectrum) -> float:
    """The measured spectrum's noise σ over its dark range (:data:`DARK_SHARE`), relative to its
    peak: the median absolute second difference of the dark samples (σ √6 for white noise; the
    scaled MAD, ×1.4826, of a Gaussian). 0 without a dark range (a broadband lamp) or for an
    exact (synthetic) spectrum.

    Examples
    --------
    >>> from calib.core.lamp_specs import gaussian_lamp
    >>> spectrum_noise_floor(gaussian_lamp(630.0, 20.0)) < 1e-9
    True
    """
    values = np.asarray(spectrum.values, dtype=np.float64)
    peak = float(np.max(values)) if values.size else 0.0
    if values.size < 3 or peak <= 0:
        return 0.0
    second = np.diff(values, 2)
    dark = np.max(np.stack([values[:-2], values[1:-1], values[2:]]), axis=0) < DARK_SHARE * peak
    if int(dark.sum()) < DARK_SAMPLES:
        return 0.0
    return float(1.4826 * np.median(np.abs(second[dark])) / math.sqrt(6.0) / peak)


#: The reference spectrum's noise floor relative to its peak, as a spectrometer's specification
#: gives it: a CCD spectrometer's signal-to-noise ratio at full scale is a few hundred to a
#: thousand to one per sample. Only its order matters: a channel that sees a narrow LED only
#: where it is dark (its leak, ~10⁻⁴ of its peak) has a direct signal of that order or below.
SPECTRUM_FLOOR = 1e-3
#: A dark range's measured σ below this share of the peak is round-off, not a spectrometer's noise.
ROUND_OFF_FLOOR = 1e-9


def spectrum_floor(spectrum: Spectrum) -> float:
    """The floor :func:`with_spectrum_floor` gives a lamp measured as ``spectrum``:
    :data:`SPECTRUM_FLOOR` where the spectrum has a dark range with noise in it
    (:func:`spectrum_noise_floor`), else 0 (a broadband lamp, an exact synthetic spectrum)."""
    return SPECTRUM_FLOOR if spectrum_noise_floor(spectrum) > ROUND_OFF_FLOOR else 0.0


def with_spectrum_floor(lamp: LampData, floor: float) -> LampData:
    """``lamp`` with each channel's direct σ at least ``floor`` (:func:`spectrum_floor`) of its
    brightest channel's signal, added in quadrature.

    A direct equation predicts its target from the measured spectrum times the lamp's response.
    In a channel that sees the lamp only where it is dark (the blue of a red LED: the LED's leak
    of ~10⁻⁴ of its peak, against a spectrometer's noise floor of a few 10⁻⁴) the prediction is
    the spectrum's noise, which no σ of the camera's holds. At the rig's bracket SNR (decision
    0098) those equations held most of the direct χ² and turned the grating model to Fourier
    (decision 0103). The brightest channel's σ grows by ``floor`` of itself, the size of the
    direct equations' own 0.1 % model floor.
    """
    if floor <= 0:
        return lamp
    brightest = float(np.max(np.abs(lamp.direct)))
    sigma = np.sqrt(lamp.direct_sigma**2 + (floor * brightest) ** 2)
    return replace(lamp, direct_sigma=np.asarray(sigma, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class PreparedLamps:
    """Step 1 for one camera's lamps: the mapping, and each lamp's response and direct measurement."""

    mapping: QuadraticMapping | GratingGeometry
    lamps: tuple[LampData, ...]
    mapping_s: float


@one_blas_thread
def prepare_lamps(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    prior_shrinkage: float | None = None,
    refine_given_mapping: bool = False,
    kernel: FloatArray | None = None,
) -> PreparedLamps:
    """Step 1 for one camera's lamps (the mapping found with the prior when not given; each lamp
    prepared and its response fitted once per solve scope: :func:`prepared_response`)."""
    check_lamps(observations, basis, grid)
    used_mapping, chosen, mapping_s = mapping_and_lamps(
        observations,
        basis.prior(prior_shrinkage),
        grid,
        mapping,
        mapping_lamp,
        refine_given_mapping,
        kernel,
        need_direct=True,
    )
    pairs = [prepared_response(obs, used_mapping, grid, kernel) for obs in chosen]
    lamps = tuple(
        with_spectrum_floor(
            lamp_data(system, used_mapping, response),
            spectrum_floor(system.observation.spectrum),
        )
        for system, response in pairs
    )
    return PreparedLamps(used_mapping, lamps, mapping_s)


@one_blas_thread
def calibrate_lamps(
    prepared: PreparedLamps, prior: CameraPrior, settings: EfficiencySettings = EfficiencySettings()
) -> CalibratedLamps:
    """Step 2 for one camera's prepared lamps (:func:`prepare_lamps`)."""
    efficiency = solve_efficiency(prepared.lamps, prior, settings)
    return CalibratedLamps(
        prior.grid, prepared.mapping, prepared.lamps, efficiency, prepared.mapping_s
    )


@dataclass(frozen=True)
class MultilampOptions(GratingMethodOptions):
    """Options of :func:`estimate_multilamp` (checked on construction), besides those of every
    grating method (:class:`calib.methods.closed_form.GratingMethodOptions`: ``prior_shrinkage``,
    ``refine_given_mapping``, the profile's blur).

    Attributes
    ----------
    prior_weight
        Fix the prior's weight ``λ`` instead of choosing it by ``weight_rule``.
    efficiency_terms
        Fourier terms of ``η`` (or of ``η⁻¹``, by ``efficiency_model``).
    efficiency_model
        ``"efficiency"`` (``η`` in the Fourier basis, default) or ``"inverse"`` (``η⁻¹``, the paper's).
    weight_rule
        How the prior's weight is chosen: ``"upre"`` (default), ``"typicality"`` or ``"evidence"``
        (:data:`PRIOR_WEIGHT_RULES`).
    grating_model
        The grating's model (:data:`calib.methods.grating_models.GRATING_MODELS`): ``"auto"``
        (default: chosen on the direct equations at the rig's error level), ``"fourier"``,
        ``"sinusoidal"`` or ``"blazed"``.
    direct_gain_sigma
        Relative σ of each lamp's direct-to-profile ratio (:data:`DIRECT_GAIN_SIGMA`).
    uncertainty
        ``"posterior"`` (default: the σ band, the camera prior's own uncertainty included),
        ``"noise"`` (the measurements' noise propagated alone, what :func:`bootstrap_sigma` checks)
        or ``"none"`` (no σ, for timing).
    """

    prior_weight: float | None = None
    efficiency_terms: int = DEFAULT_EFFICIENCY_TERMS
    efficiency_model: EfficiencyModel = DEFAULT_EFFICIENCY_MODEL
    weight_rule: WeightRule = DEFAULT_WEIGHT_RULE
    grating_model: GratingModelName = DEFAULT_GRATING_MODEL
    direct_gain_sigma: float = DIRECT_GAIN_SIGMA
    uncertainty: Uncertainty = "posterior"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.uncertainty not in UNCERTAINTIES:
            raise InputError(
                f"unknown uncertainty {self.uncertainty!r}; choose from {UNCERTAINTIES}",
                source="uncertainty",
            )
        self.efficiency_settings()  # checks the model and the rule

    def efficiency_settings(self) -> EfficiencySettings:
        """Step 2's settings (:class:`EfficiencySettings`)."""
        return EfficiencySettings(
            self.efficiency_terms,
            self.efficiency_model,
            self.prior_weight,
            self.weight_rule,
            self.grating_model,
            self.direct_gain_sigma,
        )


@one_blas_thread
def estimate_multilamp(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    options: MultilampOptions = MultilampOptions(),
) -> EstimateResult:
    """Estimate sensitivity and grating efficiency from any number of lamps jointly.

    Parameters
    ----------
    observations
        Lamps in one geometry, each with direct RGB, first-order profile and measured spectrum
        (lamps without a direct measurement help the mapping only).
    basis
        Camera basis on ``grid``; its Gaussian prior enters with the weight ``options.weight_rule``
        chooses.
    grid
        Working grid.
    mapping
        A known pixel→wavelength mapping, or ``None`` to find it with the lamps jointly.
    mapping_lamp
        Find the mapping with this lamp only.
    options
        :class:`MultilampOptions`.

    Returns
    -------
    EstimateResult
        ``method="multilamp"``, with ``sensitivity_sigma`` and ``grating_efficiency_sigma``;
        ``diagnostics`` carry the prior weight, the lamps' relative brightness and the conditioning.

    Examples
    --------
    >>> import numpy as np
    >>> from calib.core.datasets import colour_science_cameras, find_camera
    >>> from calib.core.lamp_specs import lamp_from_spec
    >>> from calib.core.mapping import QuadraticMapping
    >>> from calib.model.bases import fallback_camera_basis
    >>> from calib.model.forward import render_observation
    >>> camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    >>> basis = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])
    >>> truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
    >>> lamps = [
    ...     render_observation(lamp_from_spec(spec), camera, mapping=truth, pixel=800).observation
    ...     for spec in ("LED-B1", "LED-B3", "A")
    ... ]
    >>> result = estimate_multilamp(lamps, basis=basis, mapping=truth)
    >>> result.method, result.diagnostics["prior_weight_rule"]
    ('multilamp', 'UPRE')
    """
    kernel = camera_kernel(observations, options.slit_width_px, options.psf_sigma_px)
    started = time.perf_counter()
    prepared = prepare_lamps(
        observations,
        basis=basis,
        grid=grid,
        mapping=mapping,
        mapping_lamp=mapping_lamp,
        prior_shrinkage=options.prior_shrinkage,
        refine_given_mapping=options.refine_given_mapping,
        kernel=kernel,
    )
    calibrated = calibrate_lamps(
        prepared, basis.prior(options.prior_shrinkage), options.efficiency_settings()
    )
    efficiency = calibrated.efficiency
    solution = combine_responses(
        [lamp.response for lamp in calibrated.lamps],
        efficiency.inverse_efficiency,
        efficiency.inverse_jacobian,
        efficiency.noise_covariance
        if options.uncertainty == "noise"
        else efficiency.coefficient_covariance,
        with_covariance=options.uncertainty != "none",
        pooled=sensitivity_lamps(lamp_kinds(observations, calibrated.lamps)),
        scale_sigma_nm=pooling_scale_sigmas(observations, calibrated.lamps),
    )
    eta, eta_sigma = efficiency_with_sigma(efficiency)
    total_s = time.perf_counter() - started
    return multilamp_result(
        calibrated.lamps,
        solution,
        (eta, eta_sigma),
        calibrated.mapping,
        basis,
        {**efficiency.info, "grating": "estimated"},
        {
            "mapping_s": calibrated.mapping_s,
            "solve_s": total_s - calibrated.mapping_s,
            "total_s": total_s,
        },
        direct_weight=efficiency.direct_weights,
    )


#: The runner-up physical family's evidence weight (:func:`family_weights`) above which the
#: choice is not separated by the data and the result says so (a 1-in-20 chance of the other
#: family; decision 0063).
FAMILY_SEPARATED_WEIGHT = 0.05


def family_flag(record: Mapping[str, Any] | None) -> QualityFlag | None:
    """The ``grating_family_unresolved`` warning of a solve's ``info["grating_model"]``
    (:func:`solve_efficiency`), or ``None`` when the chosen physical family is separated: no other
    family above :data:`FAMILY_SEPARATED_WEIGHT`, counting a family set aside because its fit is
    pinned at its range's end (:func:`interior_fits`) with the weight it had among all fits."""
    if not record or record.get("chosen") in (None, "fourier"):
        return None
    chosen = str(record["chosen"])
    weights = record.get("choice_weights") or {chosen: 1.0}
    others = {kind: w for kind, w in weights.items() if kind != chosen}
    bounded = record.get("at_range_bound")
    # A family set aside at its range's end competes when its weight among all fits was not small.
    pinned = {
        kind: float(w)
        for kind, w in (bounded.items() if isinstance(bounded, Mapping) else ())
        if kind != chosen and w is not None and w > FAMILY_SEPARATED_WEIGHT
    }
    competing = {kind: w for kind, w in others.items() if w > FAMILY_SEPARATED_WEIGHT}
    if not competing and not pinned:
        return None
    reasons = [f"{kind} {w:.0%}" for kind, w in competing.items()]
    reasons += [
        f"{kind} {w:.0%} with its fit pinned at its range's end" for kind, w in pinned.items()
    ]
    return QualityFlag(
        "grating_family_unresolved",
        f"the direct signals do not separate the grating families (chose {chosen}; "
        f"{', '.join(reasons)}): the sensitivity may carry the wrong η shape; measure the 2nd "
        "order or η with the rig's spectrometer and give it as a grating file",
    )


def grating_file_from(
    calibrated: CalibratedLamps, *, description: str = "", rig: RigGeometry | None = None
) -> GratingEfficiency:
    """The estimated ``η`` with its σ and geometry, ready for :func:`calib.core.grating_file.write_grating_file`.

    ``rig``: the rig it was measured in (:func:`calib.wavelength.rig_prior.rig_geometry`), stored
    as the file's ``geometry.rig`` so a new camera through the file reuses what still holds.
    """
    eta, eta_sigma = efficiency_with_sigma(calibrated.efficiency)
    geometry: dict[str, Any] = {
        "mapping": calibrated.mapping.to_dict(),
        "order": 1,
        "description": description,
    }
    if rig is not None:
        geometry["rig"] = rig.to_dict()
    return GratingEfficiency(
        wavelength_nm=calibrated.grid.wavelength_nm,
        efficiency=eta,
        efficiency_sigma=eta_sigma,
        geometry=geometry,
        provenance={
            "method": MULTILAMP_METHOD,
            "lamps": [lamp.name for lamp in calibrated.lamps],
            "prior_weight": calibrated.efficiency.prior_weight,
        },
        source="multilamp calibration",
        **grating_model_fields(calibrated.efficiency.info.get("grating_model")),
    )


def grating_model_fields(record: Mapping[str, Any] | None) -> dict[str, Any]:
    """The grating file's ``obtained``, ``model`` and ``η₀`` fields from a solve's
    ``info["grating_model"]`` (:func:`solve_efficiency`): the physical model's parameters with σ
    and its ``η₀``, or only ``obtained`` for the Fourier model."""
    if not record or record.get("chosen", record.get("model")) == "fourier":
        return {"obtained": "estimated", "model": None if not record else {"model": "fourier"}}
    kept = ("model", "parameters", "grating", "direct_chi2", "direct_equations", "sigma_inflation")
    return {
        "obtained": "estimated",
        "model": {key: record[key] for key in kept if key in record},
        "zeroth_order_efficiency": record.get("zeroth_order_efficiency"),
        "zeroth_order_efficiency_sigma": record.get("zeroth_order_efficiency_sigma"),
    }


def efficiency_with_sigma(efficiency: EfficiencySolution) -> tuple[FloatArray, FloatArray]:
    """``η`` (maximum 1) and the σ of that normalised curve, from ``η⁻¹``'s covariance (first
    order, :func:`calib.methods.closed_form.normalised_efficiency_sigma`): η's common scale — a
    physical model's throughput, or the phase where only η's level changes with it (small φ₀:
    ``J₁² ∝ φ₀²``) — cancels in the delivered shape, so its σ does not widen the band."""
    inverse = efficiency.inverse_efficiency
    jacobian = efficiency.inverse_jacobian
    covariance = jacobian @ efficiency.coefficient_covariance @ jacobian.T
    with np.errstate(divide="ignore"):
        eta = np.where(inverse > 0, 1.0 / inverse, np.nan)
    peak = float(np.nanmax(eta)) if np.any(np.isfinite(eta)) else 1.0
    return eta / peak, normalised_efficiency_sigma(inverse, covariance)


def pooled_efficiency_terms(n_equations: int) -> int:
    """Fourier terms of ``η⁻¹`` that ``n_equations`` direct equations afford (odd, 7 to 15)."""
    terms = min(MAX_POOLED_EFFICIENCY_TERMS, n_equations // ROWS_PER_EFFICIENCY_TERM)
    terms -= 1 - terms % 2  # the paired Fourier basis has 1 + 2k terms
    return max(DEFAULT_EFFICIENCY_TERMS, terms)


@one_blas_thread
def refine_grating(
    cameras: Sequence[Sequence[LampObservation]],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mappings: Sequence[QuadraticMapping | GratingGeometry | None] | None = None,
    efficiency_terms: int | None = None,
    prior_weight: float | None = None,
    efficiency_model: EfficiencyModel = DEFAULT_EFFICIENCY_MODEL,
    weight_rule: WeightRule = DEFAULT_WEIGHT_RULE,
    grating_model: GratingModelName = DEFAULT_GRATING_MODEL,
) -> tuple[GratingEfficiency, list[EstimateResult]]:
    """``η`` shared by several cameras seen through one grating, and each camera's sensitivity.

    Every camera's lamps add their direct equations to one efficiency solve (the equations do not
    involve the camera); each camera keeps its own mapping and responses.

    Parameters
    ----------
    cameras
        Per camera, its lamp observations (each with a direct measurement).
    mappings
        Per camera, a known mapping or ``None`` (found from its lamps).
    efficiency_terms
        Fourier terms of the shared efficiency; ``None``: :data:`DEFAULT_EFFICIENCY_TERMS` of ``η``,
        or for the ``"inverse"`` model :func:`pooled_efficiency_terms` of the number of direct
        equations (``η⁻¹`` needs more terms than ``η``; more equations afford them).

    Returns
    -------
    tuple
        The refined grating (with σ) and one :class:`calib.core.result.EstimateResult` per camera.
    """
    if not cameras:
        raise InputError("no cameras given", source="cameras")
    known = list(mappings) if mappings is not None else [None] * len(cameras)
    if len(known) != len(cameras):
        raise InputError(f"{len(known)} mappings for {len(cameras)} cameras", source="mappings")
    # Step 1 per camera; step 2 once, over every camera's direct equations.
    each = [
        prepare_lamps(
            observations,
            basis=basis,
            grid=grid,
            mapping=mapping,
            kernel=camera_kernel(observations),
        )
        for observations, mapping in zip(cameras, known, strict=True)
    ]
    pooled = [lamp for calibrated in each for lamp in calibrated.lamps]
    terms = efficiency_terms
    if terms is None:
        terms = (
            pooled_efficiency_terms(3 * len(pooled))
            if efficiency_model == "inverse"
            else DEFAULT_EFFICIENCY_TERMS
        )
    settings = EfficiencySettings(terms, efficiency_model, prior_weight, weight_rule, grating_model)
    efficiency = solve_efficiency(
        pooled, basis.prior(), settings, prior_groups=[calibrated.lamps for calibrated in each]
    )
    eta_pair = efficiency_with_sigma(efficiency)
    results = []
    for calibrated, observations in zip(each, cameras, strict=True):
        solution = combine_responses(
            [lamp.response for lamp in calibrated.lamps],
            efficiency.inverse_efficiency,
            efficiency.inverse_jacobian,
            efficiency.coefficient_covariance,
            pooled=sensitivity_lamps(lamp_kinds(observations, calibrated.lamps)),
            scale_sigma_nm=pooling_scale_sigmas(observations, calibrated.lamps),
        )
        results.append(
            multilamp_result(
                calibrated.lamps,
                solution,
                eta_pair,
                calibrated.mapping,
                basis,
                {**efficiency.info, "grating": f"shared by {len(cameras)} cameras"},
                {"mapping_s": calibrated.mapping_s},
                direct_weight=efficiency.direct_weights,
            )
        )
    shared = CalibratedLamps(grid, each[0].mapping, tuple(pooled), efficiency, 0.0)
    # The first camera's geometry goes with the file (the sheet's groove spacing, and its lens'
    # angles for a body behind the same lens).
    first = each[0].mapping
    rig = (
        rig_geometry(first.details, cameras[0][0]) if isinstance(first, QuadraticMapping) else None
    )
    return grating_file_from(
        shared, description=f"refined jointly over {len(cameras)} cameras", rig=rig
    ), results


def multilamp_result(
    lamps: Sequence[LampData],
    solution: SensitivitySolution,
    efficiency: tuple[FloatArray, FloatArray | None],
    mapping: QuadraticMapping | GratingGeometry,
    basis: CameraBasis,
    info: dict[str, Any],
    timings: dict[str, float],
    *,
    method: str = MULTILAMP_METHOD,
    direct_weight: FloatArray | None = None,
) -> EstimateResult:
    """The :class:`~calib.core.result.EstimateResult` of a solve over lamp responses: curves
    normalised to a maximum of 1 (negative values clipped) with σ, ``η`` and its σ, each lamp's
    direct residual (the direct path weighted by ``direct_weight``, ``T η₀``: ones when ``η₀`` is
    taken flat), ``info`` and ``timings`` in the diagnostics."""
    sensitivity, sigma = solution.normalised()
    weight = np.ones(solution.sensitivity.shape[0]) if direct_weight is None else direct_weight
    residuals = {
        lamp.name: {
            "direct": lamp.direct - (lamp.direct_row * weight) @ solution.sensitivity * scale
        }
        for lamp, scale in zip(lamps, solution.lamp_scales, strict=True)
        if np.all(np.isfinite(lamp.direct))
    }
    return EstimateResult(
        method=method,
        wavelength_nm=basis.grid.wavelength_nm,
        sensitivity=np.clip(sensitivity, 0.0, None),
        sensitivity_sigma=sigma,
        grating_efficiency=efficiency[0],
        grating_efficiency_sigma=efficiency[1],
        mapping=mapping,
        residuals=residuals,
        diagnostics={
            "basis": basis.to_dict(),
            "solve_lamps": [lamp.name for lamp in lamps],
            "lamp_scales": solution.lamp_scales.tolist(),
            **{key: value for key, value in info.items() if key != "weight_curve"},
            "timings": timings,
        },
    )


def weight_rule_option(method: str, weight_rule: str | None) -> MultilampOptions | None:
    """The options a command line's ``--weight-rule`` stands for (``None`` when absent).

    Raises
    ------
    InputError
        The rule is unknown, or the method is not ``multilamp`` (source ``--weight-rule``).
    """
    if weight_rule is None:
        return None
    if method.lower() != MULTILAMP_METHOD:
        raise InputError(
            f"applies to --method {MULTILAMP_METHOD} only (the method is {method!r})",
            source="--weight-rule",
        )
    if weight_rule not in PRIOR_WEIGHT_RULES:
        raise InputError(
            f"{weight_rule!r} is not a rule; choose from {', '.join(PRIOR_WEIGHT_RULES)}",
            source="--weight-rule",
        )
    return MultilampOptions(weight_rule=weight_rule)


@one_blas_thread
def bootstrap_sigma(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    mapping: QuadraticMapping | GratingGeometry,
    rng: np.random.Generator,
    draws: int = 50,
    grid: WavelengthGrid = DEFAULT_GRID,
    options: MultilampOptions = MultilampOptions(),
) -> FloatArray:
    """σ ``(f, 3)`` of the normalised sensitivity by a parametric bootstrap over the noise model.

    Each draw adds Gaussian noise of the observations' own σ (profile and direct) and re-runs the
    solve (``options``, without σ) with the mapping held fixed; the spread of the draws is what the
    analytic covariance predicts (to first order) when the prior's weight is held fixed too
    (``options.prior_weight``).
    """
    if draws < 2:
        raise InputError(f"need at least 2 draws, got {draws}", source="draws")
    samples = []
    for _ in range(draws):
        noisy = []
        for obs in observations:
            if obs.profile_sigma is None:
                raise InputError("the bootstrap needs the profile σ", source=f"lamp {obs.name!r}")
            profile = obs.profile + rng.standard_normal(obs.profile.shape) * obs.profile_sigma
            direct = obs.direct_rgb
            if direct is not None and obs.direct_sigma is not None:
                direct = direct + rng.standard_normal(3) * obs.direct_sigma
            noisy.append(replace(obs, profile=profile, direct_rgb=direct))
        result = estimate_multilamp(
            noisy,
            basis=basis,
            grid=grid,
            mapping=mapping,
            options=replace(options, uncertainty="none"),
        )
        samples.append(result.sensitivity)
    return np.asarray(np.std(np.stack(samples), axis=0, ddof=1), dtype=np.float64)
