"""A small Levenberg–Marquardt for a handful of parameters with an analytic Jacobian.

The mapping families have 2–4 parameters and the response models give their exact Jacobian, so a
plain damped Gauss–Newton loop (Marquardt 1963, diagonal scaling) converges in a few iterations;
scipy's general solver costs more in set-up per call than the model itself at these sizes. A trial
point outside the family's valid region (a mapping that folds back, a grating angle past 90°) is a
rejected step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack

from calib.core.arrays import FloatArray

_gesv = lapack.dgesv

#: What a residual function gives at a point: ``(residual, jacobian)`` — the Jacobian an array, a
#: call that computes it (evaluated only if the point is accepted: a rejected trial costs only its
#: residual), or ``None`` when not asked for — or ``None`` outside the valid region.
Evaluation = tuple[FloatArray, FloatArray | Callable[[], FloatArray] | None] | None
#: The geodesic step's probe, as a fraction of the step (the finite difference's ``h``).
GEODESIC_PROBE = 0.1
#: Largest ``2‖a‖/‖v‖`` (acceleration over velocity, scaled norm) a geodesic step may have.
GEODESIC_RATIO = 0.75
#: With ``shorten``: how long (scaled norm) the step after a refused one may be, as a fraction of
#: the refused step: halved, as Armijo's (1966) backtracking halves a refused line-search step.
#: Cutting by the quadratic interpolation of the cost along the straight refused step instead
#: (clipped to 0.1–0.5, Dennis & Schnabel's trust-radius update) cut further than a curved valley
#: allows: Rosenbrock's took 1013 evaluations against 597 with ×4 alone and 469 halved (decision
#: 0096).
SHORTEN_FRACTION = 0.5
#: A fit has converged once the Gauss–Newton step's predicted decrease of χ² is below this
#: (``gain_tolerance``): with residuals in units of their σ, that decrease is the squared distance
#: (in σ) of the local model's minimum from where the fit stands, and 0.01 puts it within a tenth
#: of the fit's own σ (a statistical bar, not a tuned one; decision 0124). Where the residuals
#: are larger than their σ say, the fit's own σ is wider by √(reduced χ²), and so is the bar
#: (``tempered``; decision 0195).
CONVERGED_DELTA_CHI2 = 0.01
#: ``function(x, with_jacobian)`` → :data:`Evaluation`.
ResidualFunction = Callable[[FloatArray, bool], Evaluation]


@dataclass(frozen=True)
class Solution:
    """Where the loop stopped: parameters, residual, Jacobian, cost ``‖r‖²``, evaluations.

    The Jacobian may be given as the call that computes it (:data:`Evaluation`'s): it is then
    computed when first read — a search's descents mostly never read their end's (decision
    0153) — and kept; the same call gives the same numbers whenever it runs.
    """

    x: FloatArray
    residual: FloatArray
    _jacobian: FloatArray | Callable[[], FloatArray] = field(repr=False)
    cost: float
    evaluations: int

    @property
    def jacobian(self) -> FloatArray:
        """``∂r/∂x`` at :attr:`x` ``(rows, P)``."""
        if callable(self._jacobian):
            object.__setattr__(self, "_jacobian", self._jacobian())
        assert not callable(self._jacobian)
        return self._jacobian

    @property
    def dof(self) -> int:
        """Residual rows less parameters (at least 1): what the fit's χ² is reduced by."""
        return max(self.residual.size - self.x.size, 1)

    @property
    def temper(self) -> float:
        """The reduced χ² ``cost / dof``, at least 1: what a Δχ² against this fit is divided by
        where its residuals are larger than their σ say (the mapping search's tempering)."""
        return max(self.cost / self.dof, 1.0)

    def covariance(self, *, scale_by_fit: bool = True) -> FloatArray:
        """``(JᵀJ)⁻¹``, times the residual variance ``cost / (rows − P)`` when ``scale_by_fit``."""
        normal = self.jacobian.T @ self.jacobian
        covariance = np.linalg.pinv(normal)
        if scale_by_fit:
            covariance = covariance * self.cost / self.dof
        return np.asarray(covariance, dtype=np.float64)


def levenberg_marquardt(
    function: ResidualFunction,
    x0: FloatArray,
    *,
    max_iterations: int = 30,
    tolerance: float = 1e-8,
    geodesic: bool = False,
    step_tolerance: float = 0.0,
    shorten: bool = False,
    gain_tolerance: float = 0.0,
    tempered: bool = False,
    stop_at_bound: bool = False,
    give_up_above: float = math.inf,
) -> Solution:
    """Minimise ``‖r(x)‖²`` from ``x0`` (which must be valid).

    Stops when an accepted step lowers the cost by less than ``tolerance`` relative (or by less
    than ``tolerance`` absolutely, for a zero-residual problem), or after ``max_iterations``
    Jacobian evaluations. With ``step_tolerance``, also when an accepted step moves no residual
    by more than that (the residuals in units of their σ: the fit no longer moves what it fits).
    With ``gain_tolerance``, also before a step when the Gauss–Newton model's whole predicted
    decrease, ``gᵀ(JᵀJ)⁻¹g``, is below it: for residuals in units of their σ that decrease is the
    squared Mahalanobis distance of the model's minimum from ``x``, so 0.01 stops a fit within a
    tenth of its own σ of where it would go (without the trials, mostly refused, that the cost's
    roughness at that scale costs; decision 0124). With ``tempered`` that bar is in units of the
    fit's own σ: scaled by the reduced χ² ``cost / (rows − P)`` where it exceeds 1, the factor a
    fit's covariance is scaled by (decision 0195). With ``stop_at_bound``, an accepted step that
    lowers the cost by less than that bar also stops the fit: where the model's minimum lies
    beyond a bound of the valid region, its predicted gain never falls, and the fit crawls along
    the bound by ever smaller steps (a line fit whose width or shift presses on its limits). Not
    for a fit along a flat valley that a soft prior settles: there many such steps add up to a
    move its σ tells (decision 0195). With ``give_up_above``, also before a step when
    the Gauss–Newton model's minimum, ``‖r‖² − gᵀ(JᵀJ)⁻¹g``, is above it: the descent's own model
    says it ends there (a start hopelessly behind a leader; decision 0165).

    With ``geodesic``, once a plain step has been refused, each step carries its geodesic
    acceleration (Transtrum & Sethna 2012): the residual's second derivative along the step, by
    one extra residual evaluation a tenth of the way along it, bends the step to follow a curved
    valley; a step whose bend exceeds
    :data:`GEODESIC_RATIO` of its length (in the scaled norm) is treated as rejected. A fit that
    crawls along a narrow curved valley (Marquardt's damping cycling once up and once down per
    accepted step) goes there in tens of steps instead of hundreds.

    With ``shorten``, a refused step raises the damping (at least ×4, as without it) until the
    damped step is at most :data:`SHORTEN_FRACTION` as long as the refused one in the scaled norm,
    and the step then accepted keeps that damping instead of the usual ÷5 (the step that was just
    cut is not lengthened at once, straight back into the refused one). With Marquardt's scaling
    by ``diag(JᵀJ)`` a damping far below 1 leaves the step nearly the Gauss–Newton one, so ×4
    alone refused the same long step many times over (one scan refinement nine times in a row,
    decision 0084). The length a damping gives is read off one eigendecomposition of the scaled
    normal matrix; no residual is evaluated for it (decision 0096).

    Examples
    --------
    >>> def line(x, with_jacobian):
    ...     t = np.arange(5.0)
    ...     r = x[0] + x[1] * t - (1 + 2 * t)
    ...     return r, np.stack([np.ones(5), t], axis=1) if with_jacobian else None
    >>> levenberg_marquardt(line, np.zeros(2)).x.round(6)
    array([1., 2.])
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    first = function(x, True)
    if first is None:
        raise ValueError("the starting point is outside the family's valid region")
    residual, first_jacobian = first
    if first_jacobian is None:
        raise ValueError("the residual function gave no Jacobian")
    # The accepted point's Jacobian as the function gave it: computed at the next iteration's
    # start, or by the solution's reader — not when the loop stops there (decision 0153).
    pending: FloatArray | Callable[[], FloatArray] = first_jacobian
    cost = float(residual @ residual)
    evaluations = 1
    damping = 1e-3
    dof = max(residual.size - x.size, 1)

    def bar(at_cost: float) -> float:
        """``gain_tolerance``, in units of the fit's own σ when ``tempered``."""
        return gain_tolerance * (max(at_cost / dof, 1.0) if tempered else 1.0)

    stride = x.size + 1
    # Steps bend only once a plain step has been refused: a fit that converges with every step
    # accepted costs no probes.
    bending = False
    for _ in range(max_iterations):
        jacobian = _concrete(pending)
        pending = jacobian
        gradient = -(jacobian.T @ residual)
        normal = jacobian.T @ jacobian
        scale = np.maximum(normal.diagonal(), 1e-30)
        if gain_tolerance > 0.0 or give_up_above < math.inf:
            gain = _newton_gain(normal, gradient)
            if gain < bar(cost) or cost - gain > give_up_above:
                break
        improved = False
        refused = False
        while damping < 1e12:
            system = normal.copy()
            # The diagonal as a strided view of the fresh copy (a fancy-indexed add cost more
            # than the solve).
            system.reshape(-1)[::stride] += damping * scale
            # LAPACK's gesv itself (what np.linalg.solve calls), without its per-call set-up:
            # these systems are 2–10 wide and solved thousands of times per mapping.
            _, _, step, info = _gesv(system, gradient)
            if info != 0:
                damping *= 10.0
                continue
            if bending:
                bent = _geodesic_step(function, x, residual, jacobian, system, step, scale)
                evaluations += 1
                if bent is None:
                    damping *= 4.0
                    continue
                step = bent
            trial = x + step
            # The Jacobian comes with the trial (near convergence most steps are accepted), as
            # a call when the function defers it: computed only if the trial is accepted.
            outcome = function(trial, True)
            evaluations += 1
            if outcome is not None and outcome[1] is not None:
                trial_cost = float(outcome[0] @ outcome[0])
                if math.isfinite(trial_cost) and trial_cost < cost:
                    decrease = cost - trial_cost
                    moved = float(np.max(np.abs(outcome[0] - residual))) if step_tolerance else 1.0
                    x = trial
                    residual, pending = outcome[0], outcome[1]
                    cost = trial_cost
                    if not (shorten and refused):
                        # (A step just cut to the length the cost allows is not lengthened at
                        # once: straight back into the refused one.)
                        damping = max(damping / 5.0, 1e-9)
                    improved = True
                    crawled = stop_at_bound and decrease < bar(cost)
                    if decrease <= tolerance * max(cost, 1.0) or moved < step_tolerance or crawled:
                        return Solution(x, residual, pending, cost, evaluations)
                    break
            refused = True
            if shorten:
                damping = _shortened(normal, scale, gradient, step, damping)
            else:
                damping *= 4.0
            bending = geodesic
        if not improved:
            break
    return Solution(x, residual, pending, cost, evaluations)


def _newton_gain(normal: FloatArray, gradient: FloatArray) -> float:
    """``gᵀ(JᵀJ)⁻¹g``: the decrease of ``‖r‖²`` the Gauss–Newton step predicts (``inf`` when the
    normal matrix is singular: no prediction, no stop)."""
    _, _, newton, info = _gesv(normal, gradient)
    if info != 0:
        return math.inf
    gain = float(gradient @ newton)
    return gain if math.isfinite(gain) and gain >= 0.0 else math.inf


def _shortened(
    normal: FloatArray, scale: FloatArray, gradient: FloatArray, step: FloatArray, damping: float
) -> float:
    """The damping after ``step`` (solved at ``damping``) was refused: at least four times
    ``damping``, and large enough that the damped step's scaled length ``‖D s‖`` (``D² = scale``)
    is at most :data:`SHORTEN_FRACTION` of ``step``'s."""
    least = 4.0 * damping
    root = np.sqrt(scale)
    scaled = normal / np.outer(root, root)
    if not np.all(np.isfinite(scaled)):
        return least
    # The scaled step is (Λ + λ)⁻¹ b in the eigenbasis of D⁻¹(JᵀJ)D⁻¹ = QΛQᵀ, b = Qᵀ D⁻¹ g.
    eigenvalues, vectors = np.linalg.eigh(scaled)
    along = vectors.T @ (gradient / root)
    target = SHORTEN_FRACTION * math.sqrt(float(step**2 @ scale))
    # ‖D s(λ)‖ falls with λ and 1/‖D s(λ)‖ is concave and rising: Newton's iteration on it from
    # the left stays left of the root (Moré & Sorensen 1983); within 10 % is close enough.
    lam = max(least, -float(eigenvalues[0]) + 1e-12 * least)
    for _ in range(20):
        shifted = along / (eigenvalues + lam)
        length = math.sqrt(float(shifted @ shifted))
        if not length > 1.1 * target:
            break
        # d‖s‖/dλ = −Σ b²/(Λ+λ)³ / ‖s‖; Newton on ψ(λ) = 1/‖s‖ − 1/target.
        derivative = -float(shifted @ (shifted / (eigenvalues + lam))) / length
        lam += (1.0 / target - 1.0 / length) * length**2 / -derivative
    return lam if math.isfinite(lam) else least


def _geodesic_step(
    function: ResidualFunction,
    x: FloatArray,
    residual: FloatArray,
    jacobian: FloatArray,
    system: FloatArray,
    step: FloatArray,
    scale: FloatArray,
) -> FloatArray | None:
    """``v + a/2``: the step ``v`` with its geodesic acceleration ``a`` (``system`` is the damped
    normal matrix ``v`` was solved with, ``scale`` the norm's diagonal), or ``None`` when the
    probe is outside the valid region or the bend is too large."""
    probe = function(x + GEODESIC_PROBE * step, False)
    if probe is None:
        return None
    second = (2.0 / GEODESIC_PROBE) * ((probe[0] - residual) / GEODESIC_PROBE - jacobian @ step)
    _, _, acceleration, info = _gesv(system, -(jacobian.T @ second))
    if info != 0:
        return None
    bend = float(acceleration**2 @ scale) / max(float(step**2 @ scale), 1e-300)
    if not math.isfinite(bend) or 2.0 * math.sqrt(bend) > GEODESIC_RATIO:
        return None
    return np.asarray(step + 0.5 * acceleration, dtype=np.float64)


def _concrete(jacobian: FloatArray | Callable[[], FloatArray]) -> FloatArray:
    return jacobian() if callable(jacobian) else jacobian
