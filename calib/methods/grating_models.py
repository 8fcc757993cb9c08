"""Physical grating models in the multi-lamp solve: one shape parameter, the 0th order included.

The multi-lamp solve (:mod:`calib.methods.multilamp`) reads the grating from each lamp's direct
(0th-order) equations. With the lamp's first-order response ``q̂_l = E_l η₁ s`` fitted from its
profile, the direct signal is

    m_dir,lc = T E_l ∫ e_l η₀ s_c dλ = Σ_λ d_l(λ) q̂_lc(λ) · T η₀(λ) / η₁(λ),

with ``T`` the direct path's throughput relative to the first order's (exposures, the spot's
extraction — unknown, fitted). Two curves enter: ``g = T η₀/η₁`` weights the direct equations and
``h = 1/η₁`` turns the response into the sensitivity (``s = Q ⊙ h``). The free Fourier model takes
``η₀`` flat, so that ``g ∝ h`` (decision 0015); for a real grating ``η₀`` is not flat: a thin
sinusoidal phase sheet has ``η₀ = J₀²(φ₀ λ₀/λ)``, a blazed grating ``sinc²(λ_B/λ)``
(:mod:`calib.model.gratings`), and ignoring it biases the camera by the shape of ``η₀``.

Here ``η₀`` and ``η₁`` come from one physical model with the same parameters
(:data:`calib.model.gratings.PHYSICAL_KINDS`): ``θ = (p, log T)``, ``p`` the sheet's peak phase at
550 nm or the blaze wavelength. ``p`` is found by scanning its range (``T`` in closed form at each
value: the equations are linear in it) and refined by a bounded 1-D minimisation; the rows are
re-whitened at each pass's ``g`` (the response's covariance enters their σ). No camera prior is
needed: two parameters against ``3L`` equations.

σ: the inverse of ``JᵀJ`` of the whitened residuals at the solution, inflated by the reduced χ²
where it exceeds 1 (the model or the rig's errors do not match the stated noise; the inflation is
reported), never below the wavelength scale's share (:data:`WAVELENGTH_SCALE_SIGMA`), and widened
to the leave-one-lamp-out jackknife's σ of ``p`` where that is larger
(each lamp's response carries its own error of the mapping and of its measured spectrum, which the
direct equations' χ² cannot see: on the twin, φ₀ within 0.002 rad of the truth but 6σ of the
equations' own σ), propagated to ``h`` along ``∂h/∂p``.

The model is chosen (``grating_model="auto"``) by the estimated predictive risk of the direct
equations, Mallows' ``C_L`` (what UPRE minimises for the Fourier model's prior weight): ``χ² + 2
k_eff``, with ``k_eff = 2`` for a physical model and ``tr H`` (the effective number of parameters
under the camera prior) for the Fourier model. It is an unbiased estimate of the error in
predicting new direct measurements, and so asymptotically the leave-one-out cross-validation
score (Stone 1977), computed on the lamps' own equations — *provided the noise level is right*.
The rows are whitened by the stated noise (photon noise, the response's covariance, 2 % shared by
a lamp's channels and a 0.1 % floor), and a real rig's direct-to-profile ratios are off by more,
per channel: stray light on the band's tails, the spectrometer's scale and slit, the lamp's tilt
between spectrum and frames. Against the stated noise alone the true physical model then gets a
χ² of tens to hundreds, and the free model, which bends η to follow those errors, wins with a
wrong, flat ``η₀`` (decision 0042: 13 of 32 validation estimates, RE 3.4–12.7 ×10⁻² where the
physical model gave 0.7–2.9). So ``C_L`` is judged at the rig's error level: each equation's σ
floored at :data:`CHOICE_FLOOR` of its signal (as decision 0034 floors the profile's), both the χ²
and — for the Fourier model — its ``tr H`` taken from the fit as made, except the free scale (``T``,
or the Fourier ``η⁻¹``'s overall factor: the direct path's throughput, a nuisance no model
predicts), which is profiled out at the judged weighting. The fit's own ``T`` is the best at the
stated noise, where a few precise equations dominate; judged at the rig's level, that ``T`` left
every equation of the true model off by the same few per cent, and the free model — whose scale
compensates through its shape — won (decision 0048: 7 of 88 validation estimates of the
multi-lamp variants, RE 3.6–18.8 ×10⁻² where the sinusoidal fit gave 0.3–0.9). The fits themselves are
unchanged; the record keeps the rule, both risks (``predictive_risk`` as judged,
``noise_only_predictive_risk``) and the floor. The σ budget's re-solves keep the estimate's
choice (:func:`calib.methods._rerun`). Once a physical model wins, *which* family is chosen at the
stated noise (its quasi-likelihood, :func:`calib.methods.multilamp.family_weights`: two rigid
families cannot bend to the rig's errors, and the precise equations tell them apart), and the
other family's share of the evidence is carried in σ (decision 0053). Each parameter is now
charged ``max(2, log n)`` instead of 2 (Schwarz's criterion, :func:`calib.methods.multilamp.choice_penalty`:
the choice asks which η the sheet has, not how well the direct equations are predicted; decision
0058).

References
----------
Mallows, C. L. (1973). Some comments on C_p. *Technometrics* 15(4), 661–675.
Stone, M. (1977). An asymptotic equivalence of choice of model by cross-validation and Akaike's
criterion. *J. R. Stat. Soc. B* 39(1), 44–47.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import pinv_symmetric
from calib.core.errors import EstimationError, InputError
from calib.methods.responses import MODEL_FLOOR, LampData, direct_rows
from calib.model.gratings import (
    PHYSICAL_KINDS,
    PHYSICAL_PARAMETER_NAMES,
    PHYSICAL_PARAMETER_RANGES,
    BlazedGrating,
    PhysicalKind,
    SinusoidalPhaseGrating,
    physical_efficiencies,
    physical_grating,
)

GratingModelName = Literal["auto", "fourier", "sinusoidal", "blazed"]
#: The estimator's grating models: ``"fourier"`` (free, ``η₀`` flat: decision 0015), the two
#: physical families, or ``"auto"``: chosen among the three at the rig's error level (module
#: docstring).
GRATING_MODELS: tuple[GratingModelName, ...] = ("auto", "fourier", "sinusoidal", "blazed")
DEFAULT_GRATING_MODEL: GratingModelName = "auto"
#: Parameter values scanned before the 1-D refinement.
SCAN_POINTS = 120
#: Values scanned around a known start (:func:`with_jackknife`'s refits).
LOCAL_POINTS = 21
#: Passes: the rows are re-whitened at the previous pass's ``g``.
FIT_PASSES = 3
#: The refinement's tolerance in the parameter (``minimize_scalar``'s ``xatol``); also how far
#: inside a scan's end :func:`fit_physical` looks to see whether the misfit falls away from it.
REFINE_XATOL = 1e-6
#: Relative σ of the wavelength scale the responses are on: 0.5 nm at 550 nm, a spectrometer's
#: stated accuracy (the validation protocol draws ±0.5 nm) and the order of the mapping's error.
#: Both families depend on ``p/λ`` alone (``φ₀·550/λ``, ``λ_B/λ``), so a scale error moves ``p`` by
#: the same fraction; the parameter's σ is never below it. (On the twin, with a consistent direct
#: χ², φ₀ came out 0.11 % low: 6× the equations' own σ.)
WAVELENGTH_SCALE_SIGMA = 0.5 / 550.0
#: Relative floor under each direct equation's σ when the grating model is chosen (``"auto"``):
#: the rig's error level on a direct-to-profile ratio per channel (module docstring). Chosen on the
#: VALIDATION split only (decision 0042: 1 % left one of 32 estimates on the free model, 2 % none,
#: 3 % tipped a 3 lamps + RGB estimate back to it).
CHOICE_FLOOR = 0.02
#: Relative step of the numerical derivative of the efficiencies in the parameter.
DERIVATIVE_STEP = 1e-5


def check_grating_model(name: str, source: str = "grating_model") -> GratingModelName:
    """``name`` as a :data:`GRATING_MODELS` member, or a one-line :class:`InputError`."""
    for model in GRATING_MODELS:
        if name == model:
            return model
    raise InputError(
        f"unknown grating model {name!r}; choose from {', '.join(GRATING_MODELS)}", source=source
    )


def model_curves(
    kind: PhysicalKind, parameter: float, wavelength_nm: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``η₀`` and ``η₁`` of the family at ``parameter``, each ``(f,)``."""
    grating = physical_grating(kind, parameter)
    return grating.efficiency(0, wavelength_nm), grating.efficiency(1, wavelength_nm)


def recorded_physical_grating(
    record: Mapping[str, Any] | None,
) -> SinusoidalPhaseGrating | BlazedGrating | None:
    """The physical grating a grating file's (or a solve's) ``model`` record describes, or
    ``None`` (no record, the Fourier model, or a parameter missing)."""
    if not record:
        return None
    kind = record.get("model")
    parameters = record.get("parameters")
    if kind not in PHYSICAL_KINDS or not isinstance(parameters, Mapping):
        return None
    value = parameters.get(PHYSICAL_PARAMETER_NAMES[kind])
    if not isinstance(value, int | float) or not np.isfinite(value):
        return None
    return physical_grating(kind, float(value))


#: The 1st order's efficiency below which the 2nd-to-1st ratio is held (a blazed grating's η₁
#: vanishes far from its blaze).
FIRST_ORDER_FLOOR = 1e-6


def second_order_ratio(
    grating: SinusoidalPhaseGrating | BlazedGrating,
) -> Callable[[FloatArray], FloatArray]:
    """``λ ↦ η₂(λ)/η₁(λ)`` of a physical grating: what turns the 1st-order response
    ``q = η₁ s`` at ``λ`` into the 2nd order's ``η₂ s`` there (the scale of both orders cancels)."""

    def ratio(wavelength_nm: FloatArray) -> FloatArray:
        first = np.maximum(grating.efficiency(1, wavelength_nm), FIRST_ORDER_FLOOR)
        return np.asarray(grating.efficiency(2, wavelength_nm) / first, dtype=np.float64)

    return ratio


@dataclass(frozen=True, eq=False)
class PhysicalFit:
    """A physical model fitted to the direct equations (module docstring).

    Attributes
    ----------
    kind, parameter
        The family and its shape parameter (rad at 550 nm, or nm).
    log_throughput
        ``log T``: the direct path's throughput relative to the first order's.
    covariance
        Of ``(parameter, log T)``, ``(2, 2)``, inflated by :attr:`inflation`.
    noise_covariance
        The same before the inflation (the stated noise alone).
    chi2, n_equations
        Of the whitened direct equations at the solution.
    inflation
        ``max(1, χ² / (n − 2))``, times the jackknife's widening (:func:`with_jackknife`).
    wavelength_nm
        The grid ``(f,)``.
    scan
        ``(parameter, χ²)`` over the scan of the last pass (for plots and the record).
    jackknife_sigma
        The leave-one-lamp-out σ of ``p`` (:func:`with_jackknife`), when computed.
    """

    kind: PhysicalKind
    parameter: float
    log_throughput: float
    covariance: FloatArray
    noise_covariance: FloatArray
    chi2: float
    n_equations: int
    inflation: float
    wavelength_nm: FloatArray
    scan: tuple[FloatArray, FloatArray] = field(repr=False, default=(np.zeros(0), np.zeros(0)))
    jackknife_sigma: float | None = None

    @property
    def grating(self) -> SinusoidalPhaseGrating | BlazedGrating:
        return physical_grating(self.kind, self.parameter)

    @property
    def parameter_sigma(self) -> float:
        return float(np.sqrt(max(float(self.covariance[0, 0]), 0.0)))

    @property
    def at_range_bound(self) -> bool:
        """The fit sits within one full-range scan step of its search range's end
        (:data:`PHYSICAL_PARAMETER_RANGES`): its χ² minimum is not inside the range of real
        sheets, so the family explains the direct equations only as a limiting case (decision
        0063)."""
        low, high = PHYSICAL_PARAMETER_RANGES[self.kind]
        step = (high - low) / (SCAN_POINTS - 1)
        return bool(self.parameter <= low + step or self.parameter >= high - step)

    @property
    def predictive_risk(self) -> float:
        """Mallows' ``C_L`` of the direct equations: ``χ² + 2 · 2``."""
        return self.chi2 + 2.0 * 2

    def judged_chi2(
        self, lamps: Sequence[LampData], gain_sigma: float | None, floor: float
    ) -> float:
        """χ² of the direct equations at the fit's parameter with each equation's σ floored at
        ``floor`` of its signal (the model choice's error level, :data:`CHOICE_FLOOR`), the
        throughput ``T`` — a nuisance scale — profiled out at that weighting (module docstring)."""
        wavelength = self.wavelength_nm
        ones = np.ones(wavelength.size)
        shape = physical_equations(lamps, self.kind, self.parameter, ones, None, wavelength)[2]
        throughput = float(np.exp(self.log_throughput))
        values, target, _ = physical_equations(
            lamps, self.kind, self.parameter, throughput * shape, gain_sigma, wavelength, floor
        )
        return profile_throughput(values, target)[1]

    def zeroth_and_first(self) -> tuple[FloatArray, FloatArray]:
        """``η₀``, ``η₁`` on the grid (fractions of the incident light)."""
        return model_curves(self.kind, self.parameter, self.wavelength_nm)

    def derivatives(self) -> tuple[FloatArray, FloatArray]:
        """``∂η₀/∂p`` and ``∂η₁/∂p`` on the grid (central differences)."""
        step = DERIVATIVE_STEP * max(abs(self.parameter), 1e-3)
        zeroth_up, first_up = model_curves(self.kind, self.parameter + step, self.wavelength_nm)
        zeroth_down, first_down = model_curves(self.kind, self.parameter - step, self.wavelength_nm)
        return (zeroth_up - zeroth_down) / (2 * step), (first_up - first_down) / (2 * step)

    def inverse_efficiency(self) -> tuple[FloatArray, FloatArray]:
        """``h = 1/η₁`` ``(f,)`` and ``∂h/∂θ`` ``(f, 2)`` (``h`` does not depend on ``T``)."""
        _, first = self.zeroth_and_first()
        _, first_derivative = self.derivatives()
        inverse = 1.0 / np.maximum(first, 1e-300)
        jacobian = np.zeros((inverse.size, 2))
        jacobian[:, 0] = -first_derivative * inverse**2
        return inverse, jacobian

    def direct_weight(self) -> FloatArray:
        """``T η₀`` ``(f,)``: the direct signal is ``Σ d ⊙ s ⊙ T η₀`` with ``s = Q ⊙ h``."""
        zeroth, _ = self.zeroth_and_first()
        return np.asarray(np.exp(self.log_throughput) * zeroth, dtype=np.float64)

    def efficiency_sigmas(self) -> tuple[FloatArray, FloatArray]:
        """σ of ``η₀`` and ``η₁`` on the grid from the parameter's σ (first order)."""
        zeroth_derivative, first_derivative = self.derivatives()
        sigma = self.parameter_sigma
        return np.abs(zeroth_derivative) * sigma, np.abs(first_derivative) * sigma

    def record(self) -> dict[str, Any]:
        """The fit as plain data (``diagnostics["grating_model"]``'s physical part)."""
        name = PHYSICAL_PARAMETER_NAMES[self.kind]
        zeroth, first = self.zeroth_and_first()
        zeroth_sigma, first_sigma = self.efficiency_sigmas()
        return {
            "model": self.kind,
            "parameters": {
                name: self.parameter,
                f"{name}_sigma": self.parameter_sigma,
                "reference_nm": 550.0 if self.kind == "sinusoidal" else None,
                "direct_throughput": float(np.exp(self.log_throughput)),
            },
            "grating": self.grating.to_dict(),
            "direct_chi2": self.chi2,
            "direct_equations": self.n_equations,
            "sigma_inflation": self.inflation,
            "jackknife_sigma": self.jackknife_sigma,
            "zeroth_order_efficiency": zeroth.tolist(),
            "zeroth_order_efficiency_sigma": zeroth_sigma.tolist(),
            "first_order_efficiency": first.tolist(),
            "first_order_efficiency_sigma": first_sigma.tolist(),
        }


def profile_throughput(predicted: FloatArray, target: FloatArray) -> tuple[float, float]:
    """``T`` minimising ``‖T predicted − target‖²`` (closed form) and the χ² there."""
    norm = float(predicted @ predicted)
    if norm <= 0 or not np.isfinite(norm):
        return float("nan"), float("inf")
    throughput = float(predicted @ target) / norm
    if throughput <= 0:
        return float("nan"), float("inf")
    residual = throughput * predicted - target
    return throughput, float(residual @ residual)


def physical_equations(
    lamps: Sequence[LampData],
    kind: PhysicalKind,
    parameter: float,
    weight: FloatArray,
    gain_sigma: float | None,
    wavelength_nm: FloatArray,
    floor: float = MODEL_FLOOR,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The whitened direct equations at ``parameter`` (whitened at the current ``weight``, ``g``
    up to ``T``): their predicted values for ``T = 1``, targets, and ``g/T`` on the grid ``(f,)``.

    When the lamps carry their operators, ``η₀/η₁`` is integrated inside each lamp's row on the
    fine axis, times ``η₁`` at the row's node (``node_factor`` of
    :func:`calib.methods.responses.direct_rows`), and ``g = T/η₁`` at the nodes: the row of node
    ``f`` is ``∫ e (η₀/η₁) φ_f`` (``φ_f`` its hat), because the profile fits the response
    ``r = η₁ s`` linear between the nodes, so that the direct signal ``∫ e η₀ s`` is
    ``∫ e (η₀/η₁) r``; ``s = r/η₁`` linear between the nodes instead put ``η₁``'s curvature into
    the phase (−0.0012 rad on the flaw-free twins, decision 0154). Without operators both are taken
    at the grid's nodes (``g = T η₀/η₁``). ``floor``: the relative floor under each equation's σ
    (:func:`calib.methods.responses.direct_rows`).

    The same numbers as one value of :func:`physical_misfits`' scan (:func:`scan_efficiencies`,
    :func:`_physical_rows`), the rows made on the one-value path of
    :func:`calib.methods.responses.direct_rows`.
    """
    first, second = scan_efficiencies(lamps, kind, np.array([parameter]), wavelength_nm)
    rows, target, shape = _physical_rows(lamps, first[0], second[0], weight, gain_sigma, floor)
    return rows @ shape, target, np.asarray(shape, dtype=np.float64)


def scan_efficiencies(
    lamps: Sequence[LampData], kind: PhysicalKind, parameters: FloatArray, wavelength_nm: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """What the direct equations take of the model at ``parameters`` ``(k,)``: ``η₁`` on
    ``wavelength_nm`` (floored at 1e-300) and ``η₀/η₁`` on the lamps' fine axis when every lamp
    carries its operators (:func:`physical_equations`; else ``η₀`` on ``wavelength_nm``). They
    depend on the values scanned alone, not on the rows' weights: a fit's passes, which re-whiten
    the rows and scan the same values, make them once (decision 0107)."""
    first = np.maximum(physical_efficiencies(kind, parameters, 1, wavelength_nm), 1e-300)
    operators = [lamp.operators for lamp in lamps]
    if all(operator is not None for operator in operators):
        axis = operators[0].axis_nm if operators[0] is not None else wavelength_nm
        zeroth = physical_efficiencies(kind, parameters, 0, axis)
        return first, zeroth / np.maximum(physical_efficiencies(kind, parameters, 1, axis), 1e-300)
    return first, physical_efficiencies(kind, parameters, 0, wavelength_nm)


def _physical_rows(
    lamps: Sequence[LampData],
    first: FloatArray,
    second: FloatArray,
    weight: FloatArray,
    gain_sigma: float | None,
    floor: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The whitened direct rows and targets (:func:`calib.methods.responses.direct_rows`) and the
    factor ``g/T`` they multiply, from :func:`scan_efficiencies`' pair for one value (``(f,)``
    and ``(n,)`` arrays) or a scan's (``(k, ·)``): ``1/η₁`` with η₀/η₁ inside the rows when every
    lamp carries its operators, else ``η₀/η₁`` at the nodes."""
    if all(lamp.operators is not None for lamp in lamps):
        rows, target = direct_rows(
            lamps,
            weight,
            gain_sigma=gain_sigma,
            zeroth_order=second,
            node_factor=first,
            floor=floor,
        )
        return rows, target, 1.0 / first
    rows, target = direct_rows(lamps, weight, gain_sigma=gain_sigma, floor=floor)
    return rows, target, second / first


def physical_misfits(
    lamps: Sequence[LampData],
    kind: PhysicalKind,
    parameters: FloatArray,
    weight: FloatArray,
    gain_sigma: float | None,
    wavelength_nm: FloatArray,
    floor: float = MODEL_FLOOR,
    *,
    efficiencies: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """:func:`profile_throughput`'s χ² of :func:`physical_equations` at each of ``parameters``
    ``(k,)``, all in one pass: the efficiencies as ``(k, ·)`` arrays, the direct rows of every
    value at once (:func:`calib.methods.responses.direct_rows`) — the fit's scans. Equal to the
    value-by-value χ² within rounding (``inf`` where the throughput is not positive).
    ``efficiencies``: :func:`scan_efficiencies` of the same lamps, kind, values and grid, already
    made."""
    first, second = (
        scan_efficiencies(lamps, kind, parameters, wavelength_nm)
        if efficiencies is None
        else efficiencies
    )
    rows, target, shape = _physical_rows(lamps, first, second, weight, gain_sigma, floor)
    if rows.ndim == 3:  # one set of rows per value
        values = np.matmul(rows, shape[:, :, None])[:, :, 0]
    else:
        values = shape @ rows.T
        target = np.broadcast_to(target, values.shape)
    norm = np.sum(values * values, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        throughput = np.sum(values * target, axis=1) / norm
    residual = throughput[:, None] * values - target
    chi2 = np.sum(residual * residual, axis=1)
    chi2[(norm <= 0) | ~np.isfinite(norm) | (throughput <= 0)] = np.inf
    return np.asarray(chi2, dtype=np.float64)


def fit_physical(
    lamps: Sequence[LampData],
    kind: PhysicalKind,
    wavelength_nm: FloatArray,
    *,
    gain_sigma: float | None = None,
    near: float | None = None,
) -> PhysicalFit:
    """Fit ``θ = (p, log T)`` of ``kind`` to the lamps' direct equations (module docstring);
    ``gain_sigma`` as :func:`calib.methods.responses.direct_rows` takes it. ``near``: scan only a
    tenth of the range around this value (the jackknife's refits start from the full fit).

    Raises
    ------
    InputError
        No lamps or an unknown family.
    EstimationError
        No parameter value gives a positive throughput (the direct signals contradict the model).
    """
    from scipy.optimize import minimize_scalar  # deferred: scipy.optimize is slow to import

    if not lamps:
        raise InputError("no lamps with a direct measurement", source="observations")
    if kind not in PHYSICAL_KINDS:
        raise InputError(f"unknown physical grating {kind!r}", source="grating_model")
    low, high = PHYSICAL_PARAMETER_RANGES[kind]
    if near is None:
        candidates = np.linspace(low, high, SCAN_POINTS)
    else:
        reach = 0.05 * (high - low)
        candidates = np.linspace(max(low, near - reach), min(high, near + reach), LOCAL_POINTS)
    reference = lamps[0]
    predicted = float(np.sum(reference.direct_row @ reference.response.response))
    weight = np.full(wavelength_nm.size, float(np.sum(reference.direct)) / max(predicted, 1e-300))
    parameter = float("nan")
    throughput = float("nan")
    chi2_scan = np.zeros(0)

    def equations(value: float, weight: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        return physical_equations(lamps, kind, value, weight, gain_sigma, wavelength_nm)

    # The equations the pass's refinement evaluated, by parameter value (its weight is the
    # pass's): the refinement returns one of them, which the pass then reads again.
    evaluated: dict[float, tuple[FloatArray, FloatArray, FloatArray]] = {}

    def misfit(value: float, weight: FloatArray) -> float:
        evaluated[value] = made = equations(value, weight)
        return profile_throughput(made[0], made[1])[1]

    scanned = scan_efficiencies(lamps, kind, candidates, wavelength_nm)
    for _ in range(FIT_PASSES):
        evaluated.clear()
        chi2_scan = physical_misfits(
            lamps, kind, candidates, weight, gain_sigma, wavelength_nm, efficiencies=scanned
        )
        if not np.any(np.isfinite(chi2_scan)):
            raise EstimationError(
                f"the direct signals fit no {kind} grating (no positive throughput anywhere)"
            )
        best = int(np.nanargmin(chi2_scan))
        end = best in (0, candidates.size - 1)
        inside = float(candidates[best]) + (REFINE_XATOL if best == 0 else -REFINE_XATOL)
        if end and misfit(inside, weight) >= chi2_scan[best]:
            # The scan's best is its end and the misfit rises from there inwards: the bounded
            # refinement would crawl towards the end by golden sections (29 evaluations where
            # 8-9 refine an inner minimum), never evaluate it, and lose to the scan's value
            # there, which is the answer (decision 0125).
            parameter = float(candidates[best])
        else:
            refined = minimize_scalar(
                lambda value, weight=weight: misfit(float(value), weight),
                bounds=(
                    float(candidates[max(best - 1, 0)]),
                    float(candidates[min(best + 1, candidates.size - 1)]),
                ),
                method="bounded",
                options={"xatol": REFINE_XATOL},
            )
            parameter = (
                float(refined.x) if refined.fun <= chi2_scan[best] else float(candidates[best])
            )
        values, target, shape = evaluated.get(parameter) or equations(parameter, weight)
        throughput, _ = profile_throughput(values, target)
        weight = throughput * shape
    values, target, _ = equations(parameter, weight)
    chi2 = profile_throughput(values, target)[1]
    step = DERIVATIVE_STEP * max(abs(parameter), 1e-3)
    up = equations(parameter + step, weight)[0]
    down = equations(parameter - step, weight)[0]
    jacobian = np.stack([throughput * (up - down) / (2 * step), throughput * values], 1)
    noise_covariance = np.asarray(pinv_symmetric(jacobian.T @ jacobian), dtype=np.float64)
    dof = max(target.size - 2, 1)
    inflation = max(1.0, chi2 / dof)
    return PhysicalFit(
        kind=kind,
        parameter=parameter,
        log_throughput=float(np.log(throughput)),
        covariance=noise_covariance * inflation,
        noise_covariance=noise_covariance,
        chi2=chi2,
        n_equations=int(target.size),
        inflation=inflation,
        wavelength_nm=np.asarray(wavelength_nm, dtype=np.float64),
        scan=(candidates, chi2_scan),
    )


def _with_scale_floor(fit: PhysicalFit) -> PhysicalFit:
    """``fit`` with ``σ_p ≥ p · WAVELENGTH_SCALE_SIGMA`` (both families depend on ``p/λ``)."""
    floor = (fit.parameter * WAVELENGTH_SCALE_SIGMA) ** 2
    stated = float(fit.covariance[0, 0])
    if stated >= floor or stated <= 0:
        return fit
    factor = floor / stated
    return replace(fit, covariance=fit.covariance * factor, inflation=fit.inflation * factor)


def with_jackknife(
    fit: PhysicalFit,
    lamps: Sequence[LampData],
    *,
    gain_sigma: float | None = None,
) -> PhysicalFit:
    """``fit`` with its covariance widened to the leave-one-lamp-out jackknife's variance of ``p``
    where that is larger (module docstring); unchanged with one lamp, or where a lamp's removal
    leaves too few equations.

    The jackknife variance is ``(L − 1)/L Σ_l (p_(−l) − p̄)²`` over the fits without lamp ``l``.
    """
    fit = _with_scale_floor(fit)
    if len(lamps) < 2:
        return fit
    values = []
    for left_out in range(len(lamps)):
        kept = [lamp for index, lamp in enumerate(lamps) if index != left_out]
        try:
            values.append(
                fit_physical(
                    kept, fit.kind, fit.wavelength_nm, gain_sigma=gain_sigma, near=fit.parameter
                ).parameter
            )
        except EstimationError:
            return fit
    spread = np.asarray(values)
    variance = (spread.size - 1) / spread.size * float(np.sum((spread - spread.mean()) ** 2))
    stated = float(fit.covariance[0, 0])
    if not np.isfinite(variance) or variance <= stated or stated <= 0:
        return replace(fit, jackknife_sigma=float(np.sqrt(max(variance, 0.0))))
    factor = variance / stated
    return replace(
        fit,
        covariance=fit.covariance * factor,
        inflation=fit.inflation * factor,
        jackknife_sigma=float(np.sqrt(variance)),
    )


#: Shape parameters per family over which an assumed grating is marginalised
#: (:func:`assumed_efficiency`): the families' draw ranges (what sheets sold for this work span,
#: :attr:`calib.model.gratings.SinusoidalPhaseGrating.PHASE_RANGE_RAD`,
#: :attr:`calib.model.gratings.BlazedGrating.BLAZE_RANGE_NM`), sampled evenly.
ASSUMED_POINTS = 41
#: The efficiency's assumption when neither a direct measurement nor a grating file gives it:
#: ``"flat"`` (η = 1, the grating's shape left in the sensitivity) or ``"physical"`` (η
#: marginalised over the physical families, :func:`assumed_efficiency`).
AssumedGrating = Literal["flat", "physical"]
#: The families' parameter ranges an assumed grating spans: what sheets sold for the visible span.
ASSUMED_RANGES: dict[PhysicalKind, tuple[float, float]] = {
    "sinusoidal": SinusoidalPhaseGrating.PHASE_RANGE_RAD,
    "blazed": BlazedGrating.BLAZE_RANGE_NM,
}
ASSUMED_GRATINGS: tuple[AssumedGrating, ...] = ("flat", "physical")
#: A family an assumed η may be marginalised over: a physical one (its range,
#: :data:`ASSUMED_RANGES`) or ``"flat"`` — one candidate, η = 1 (a sheet whose first order does not
#: change over the grid: the limit no scalar family reaches exactly).
AssumedFamily = Literal["sinusoidal", "blazed", "flat"]
ASSUMED_FAMILY_NAMES: tuple[AssumedFamily, ...] = ("sinusoidal", "blazed", "flat")
#: The population ``assumed_grating="physical"`` marginalises over: the two physical families
#: (decision 0074) and the flat candidate, equal weight each (decision 0088: a sheet nearly flat
#: over the grid, like a maker's ruled grating, is a real case no scalar family holds; on the
#: validation split the flat candidate helped the one such curve, 2.87 → 2.68 ×10⁻², and left
#: the families' own scenes as they were).
DEFAULT_ASSUMED_FAMILIES: tuple[AssumedFamily, ...] = ("sinusoidal", "blazed", "flat")


def check_assumed_families(
    families: Sequence[str], source: str = "assumed_families"
) -> tuple[AssumedFamily, ...]:
    """``families`` as :data:`ASSUMED_FAMILY_NAMES` members (none repeated, at least one), or a
    one-line :class:`InputError`."""
    chosen = tuple(name for name in families if name in ASSUMED_FAMILY_NAMES)
    if not chosen or len(chosen) != len(families) or len(set(chosen)) != len(chosen):
        raise InputError(
            f"assumed families {list(families)}: give one or more of "
            f"{', '.join(ASSUMED_FAMILY_NAMES)}, each once",
            source=source,
        )
    return tuple(family for family in ASSUMED_FAMILY_NAMES if family in chosen)


@dataclass(frozen=True, eq=False)
class AssumedEfficiency:
    """A first-order efficiency nobody measured, marginalised over the physical families.

    Attributes
    ----------
    inverse, inverse_covariance
        Mean of ``1/η₁`` ``(f,)`` over the families' range (each candidate scaled to a geometric
        mean of 1 on the grid: the sensitivity's scale is free) and its covariance ``(f, f)``
        over the candidates (the shapes' spread: smooth, correlated across the grid).
    record
        What was assumed (``diagnostics["grating"]``).
    """

    inverse: FloatArray
    inverse_covariance: FloatArray
    record: dict[str, Any]

    @property
    def efficiency(self) -> FloatArray:
        return np.asarray(1.0 / self.inverse, dtype=np.float64)

    @property
    def efficiency_sigma(self) -> FloatArray:
        """σ of ``η₁`` node by node (first order from ``1/η₁``'s)."""
        sigma = np.sqrt(np.clip(np.diag(self.inverse_covariance), 0.0, None))
        return np.asarray(sigma / self.inverse**2, dtype=np.float64)


def assumed_candidates(
    wavelength_nm: FloatArray,
    kinds: Sequence[AssumedFamily] = DEFAULT_ASSUMED_FAMILIES,
    points: int = ASSUMED_POINTS,
) -> tuple[FloatArray, FloatArray, list[tuple[AssumedFamily, float]]]:
    """The families' ``1/η₁`` over their draw ranges ``(K, f)`` (each scaled to a geometric mean
    of 1 on the grid: the sensitivity's scale is free; ``"flat"`` one row of ones), their prior
    weights ``(K,)`` (equal per family, uniform in each range) and ``(kind, parameter)`` of each
    (``0.0`` for the flat one)."""
    wavelength = np.asarray(wavelength_nm, dtype=np.float64)
    candidates: list[FloatArray] = []
    labels: list[tuple[AssumedFamily, float]] = []
    weights: list[float] = []
    for kind in kinds:
        if kind == "flat":
            candidates.append(np.ones(wavelength.size))
            labels.append((kind, 0.0))
            weights.append(1.0)
            continue
        low, high = ASSUMED_RANGES[kind]
        for value in np.linspace(low, high, points):
            first = physical_grating(kind, float(value)).efficiency(1, wavelength)
            log_inverse = -np.log(np.maximum(first, 1e-300))
            candidates.append(np.exp(log_inverse - log_inverse.mean()))
            labels.append((kind, float(value)))
            weights.append(1.0 / points)
    share = np.asarray(weights)
    return np.asarray(candidates), share / share.sum(), labels


def candidate_log_evidence(
    response: FloatArray,
    response_covariance: FloatArray,
    prior_mean: FloatArray,
    prior_covariance: FloatArray,
    inverse_candidates: FloatArray,
) -> FloatArray:
    """``log p(Q | η_k)`` of each candidate ``(K,)`` under the camera prior.

    The first-order response ``Q_c = η ⊙ s_c`` (``(f, 3)``, covariance ``(3, f, f)``) with
    ``s_c ~ N(α μ_c, α² Σ_c)``: ``Q_c ~ N(α η⊙μ_c, α² D_η Σ_c D_η + C_c)``, ``α`` the
    least-squares scale of the prior's mean to the data (as
    :func:`calib.methods.multilamp.blend_with_prior` takes it)."""
    values = np.zeros(inverse_candidates.shape[0])
    for k, inverse in enumerate(inverse_candidates):
        eta = 1.0 / inverse
        predicted = eta[:, None] * prior_mean
        scale = float(np.sum(predicted * response)) / max(float(np.sum(predicted**2)), 1e-300)
        total = 0.0
        for c in range(3):
            covariance = scale**2 * (eta[:, None] * prior_covariance[c] * eta[None, :])
            covariance = covariance + response_covariance[c]
            covariance = 0.5 * (covariance + covariance.T)
            jitter = 1e-12 * float(np.trace(covariance)) / covariance.shape[0]
            covariance[np.diag_indices_from(covariance)] += jitter
            residual = response[:, c] - scale * predicted[:, c]
            sign, logdet = np.linalg.slogdet(covariance)
            if sign <= 0:
                total = -np.inf
                break
            total -= 0.5 * (float(residual @ np.linalg.solve(covariance, residual)) + logdet)
        values[k] = total
    return values


def assumed_efficiency(
    wavelength_nm: FloatArray,
    kinds: Sequence[AssumedFamily] = DEFAULT_ASSUMED_FAMILIES,
    points: int = ASSUMED_POINTS,
    log_evidence: FloatArray | None = None,
) -> AssumedEfficiency:
    """``1/η₁`` marginalised over ``kinds`` (:func:`assumed_candidates`), weighted by
    ``log_evidence`` (:func:`candidate_log_evidence`) when given: its mean and covariance on
    ``wavelength_nm``.

    Without a direct measurement the first order's profile gives ``q = η₁ s`` only; η₁'s shape
    is not in the data. A flat η leaves it in the sensitivity as an error no σ holds. Here the
    error is the spread of the shapes real sheets have (a thin sinusoidal phase sheet
    ``J₁²(φ₀ λ₀/λ)``, a blazed grating ``sinc²(λ_B/λ − 1)``, each over the range sold for the
    visible), carried as a correlated covariance: the camera prior
    (:func:`calib.methods.multilamp.blend_with_prior`) then settles what of that shape the
    camera family allows, and σ holds the rest.
    """
    stack, weight, labels = assumed_candidates(wavelength_nm, kinds, points)
    if log_evidence is not None:
        finite = np.where(np.isfinite(log_evidence), log_evidence, -np.inf)
        weight = weight * np.exp(finite - finite.max())
        weight = weight / weight.sum()
    mean = weight @ stack
    centred = stack - mean
    covariance = (centred * weight[:, None]).T @ centred
    best = int(np.argmax(weight))
    record = {
        "assumed": "physical",
        "families": list(kinds),
        "ranges": {kind: list(ASSUMED_RANGES[kind]) for kind in kinds if kind != "flat"},
        "weighted_by_camera_prior": log_evidence is not None,
        "family_weights": {
            kind: float(sum(w for w, (k, _) in zip(weight, labels, strict=True) if k == kind))
            for kind in kinds
        },
        "most_likely": _candidate_record(*labels[best]),
        "effective_candidates": float(1.0 / np.sum(weight**2)),
        "note": "no direct measurement and no grating file: η₁ marginalised over the physical "
        "families' ranges, its spread carried in σ",
    }
    return AssumedEfficiency(
        np.asarray(mean, dtype=np.float64), 0.5 * (covariance + covariance.T), record
    )


def _candidate_record(kind: AssumedFamily, value: float) -> dict[str, Any]:
    """One candidate as plain data: its family and shape parameter (none for the flat one)."""
    if kind == "flat":
        return {"model": kind}
    return {"model": kind, PHYSICAL_PARAMETER_NAMES[kind]: value}
