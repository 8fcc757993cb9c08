"""Step 1 of the grating solves: each lamp's first-order response and its direct equations.

:func:`fit_response` fits ``q_c = η s_c`` on the grid from one lamp's profile (weighted least
squares, the measured lamp inside the design matrix: nothing is divided by a spectrum), with its
covariance. :class:`LampData` holds it with the lamp's direct (0th-order) measurement, and
:func:`direct_rows` turns a set of lamps into the whitened equations
``(d_l ⊙ q̂_lc)ᵀ g = m_dir,lc`` that every grating model is solved from
(:mod:`calib.methods.multilamp`, :mod:`calib.methods.grating_models`, :mod:`calib.methods.prior_solve`).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import pinv_symmetric_stack
from calib.core.errors import EstimationError, InputError
from calib.core.observations import LampObservation
from calib.core.spectra import WavelengthGrid
from calib.core.spectrometer_tolerance import WAVELENGTH_SCALE_NM
from calib.methods.closed_form import prepare_matched_lamp
from calib.methods.solve_scope import reuse
from calib.model.forward import (
    LampOperators,
    PiecewiseLinearDensity,
    WavelengthMapping,
    apply_blur,
    hat_matrix,
    second_order_onset_nm,
)
from calib.model.linear_model import LampSystem

#: Second-difference penalty of the response fit, relative to the data's scale (stabilises grid
#: nodes that few pixels see without shaping the curve).
RESPONSE_SMOOTHNESS = 1e-4
#: Relative floor on each direct equation's σ: lamp spectra and the model hold to ~0.1 %, not better.
MODEL_FLOOR = 1e-3
#: Relative σ of one lamp's direct-to-profile ratio, shared by its three channels: the spot and the
#: band come from different exposures (a shutter's time is good to 1–3 %) and the lamp may drift
#: between them. Without it the direct equations' reduced χ² on the validation split is 2–900.
DIRECT_GAIN_SIGMA = 0.02


def pixels_inside(edges_nm: FloatArray, start_nm: float, stop_nm: float) -> FloatArray:
    """Pixels whose whole wavelength interval lies in ``[start_nm, stop_nm]``: mask ``(n,)``."""
    low = np.minimum(edges_nm[:-1], edges_nm[1:])
    high = np.maximum(edges_nm[:-1], edges_nm[1:])
    return np.asarray((low >= start_nm - 1e-9) & (high <= stop_nm + 1e-9))


def _second_differences(size: int) -> FloatArray:
    matrix = np.zeros((size - 2, size))
    for row in range(size - 2):
        matrix[row, row : row + 3] = (1.0, -2.0, 1.0)
    return matrix


@dataclass(frozen=True, eq=False)
class ResponseEstimate:
    """Step 1: ``q̂`` ``(f, 3)``, its covariance ``(3, f, f)`` and the pixels used ``(n,)``;
    ``second_order_nm`` the lamp's 2nd-order onset where it falls on the grid, else ``None``, and
    ``second_order`` how its light was treated there (``"modelled"`` or ``"masked"``);
    ``log_slope_squared`` ``(f,)``: :func:`log_slope_squared` of the lamp's spectrum (``None``:
    not known, no wavelength-scale share in :meth:`scale_variance`)."""

    response: FloatArray
    covariance: FloatArray
    used_pixels: FloatArray
    chi2: float
    second_order_nm: float | None = None
    second_order: Literal["modelled", "masked"] | None = None
    log_slope_squared: FloatArray | None = None

    def scale_variance(self, scale_sigma_nm: float = WAVELENGTH_SCALE_NM) -> FloatArray:
        """``(f, 3)``: the variance of ``q̂`` from the measured spectrum's wavelength scale, off by
        ``scale_sigma_nm`` (one σ; default the spectrometer's stated accuracy,
        :data:`~calib.core.spectrometer_tolerance.WAVELENGTH_SCALE_NM`). The profile is divided by
        the spectrum read at ``λ`` for the light of ``λ + δ``, so ``q̂`` is off by ``δ · d ln e/dλ``
        of itself: ``(q̂ · σ_δ)² · (d ln e/dλ)²``. Not in :attr:`covariance` (the noise's alone):
        a few ‰ for a tungsten lamp, tens of per cent on a fluorescent line's or a narrow LED's
        flanks (decision 0067)."""
        if self.log_slope_squared is None:
            return np.zeros_like(self.response)
        return np.asarray(
            (self.response * scale_sigma_nm) ** 2 * self.log_slope_squared[:, None],
            dtype=np.float64,
        )


def log_slope_squared(operators: LampOperators) -> FloatArray:
    """``(f,)``: the mean of ``(d ln e/dλ)²`` (nm⁻²) over each grid node's hat, weighted by the
    light ``e φ_i`` it receives there — ``e`` the lamp's spectrum as the response is fitted with
    (at the matched resolution, :func:`calib.model.resolution.match_spectrometer`). The mean square,
    not the square of the mean: within a node a fluorescent line's two flanks do not cancel in the
    least-squares fit of the profile's pixels."""
    axis = operators.densities.axis_nm
    # The nodes' densities sum to ``e`` (the slit's correction terms are derivatives of the
    # hats' sum, a constant); the weights are ``e φ_i`` without them (never negative).
    spectrum = np.maximum(operators.densities.density.sum(axis=1), 0.0)
    light = spectrum[:, None] * hat_matrix(operators.grid, axis)
    floor = 1e-12 * max(float(spectrum.max()), 1e-300)
    slope = np.gradient(np.log(np.maximum(spectrum, floor)), axis)
    total = np.maximum(light.sum(axis=0), 1e-300)
    return np.asarray((light * (slope**2)[:, None]).sum(axis=0) / total, dtype=np.float64)


def fit_response(
    system: LampSystem,
    mapping: WavelengthMapping,
    *,
    second_order: Callable[[FloatArray], FloatArray] | None = None,
) -> ResponseEstimate:
    """Step 1: weighted least squares for ``q_c = η s_c`` on the grid from the profile.

    The lamp's 2nd order lands on the 1st order's red end, from twice its shortest wavelength with
    light (:func:`calib.model.forward.second_order_onset_nm`): a 1st-order pixel at ``λ`` also
    receives ``e η₂ s`` at ``λ/2``. With ``second_order`` (``λ ↦ η₂/η₁``, known from a physical
    grating model) that light is modelled: ``q`` at ``λ/2`` times the ratio, added to the pixel's
    row, every pixel kept. Without it, the pixels beyond the onset are left out (where enough
    remain), so that no 2nd-order light is fitted as 1st-order signal (decision 0032).
    """
    grid = system.operators.grid
    size = grid.size
    edges_nm = mapping.wavelength_nm(system.edges_px)
    inside = pixels_inside(edges_nm, grid.start_nm, grid.stop_nm)
    if int(inside.sum()) < size:
        raise EstimationError(
            f"only {int(inside.sum())} profile pixels map inside {grid.start_nm:g}–{grid.stop_nm:g} "
            f"nm; need at least {size} (one per grid wavelength)"
        )
    # The lamp's 2nd order lands on the 1st order's red end (from twice its shortest wavelength
    # with light): those pixels are not first-order signal, so they are left out, the grid's
    # nodes there kept by the fit's smoothness and their σ (decision 0032). Only where enough
    # pixels remain: a grid that lies wholly in the 2nd order cannot be fitted either way.
    onset_nm = second_order_onset_nm(system.observation.spectrum)
    treated: Literal["modelled", "masked"] | None = None
    matrix = system.operators.pixel_matrix(edges_nm)
    if onset_nm < grid.stop_nm:
        # Modelled where λ/2 is on the grid (the camera is known there only); masked between
        # the onset and twice the grid's start, where it comes from wavelengths below the grid.
        modelled_from_nm = 2.0 * grid.start_nm if second_order is not None else np.inf
        if second_order is not None and modelled_from_nm < grid.stop_nm:
            densities = system.operators.densities
            ratio = second_order(densities.axis_nm)
            halves = PiecewiseLinearDensity.on_axis(
                densities.axis_nm, densities.density * ratio[:, None]
            )
            matrix = matrix + halves.integrate_pixels(edges_nm / 2.0)
            treated = "modelled"
        clean = inside & np.logical_or(
            pixels_inside(edges_nm, -np.inf, onset_nm),
            pixels_inside(edges_nm, max(modelled_from_nm, onset_nm), np.inf),
        )
        if not np.array_equal(clean, inside) and int(clean.sum()) >= size:
            inside, treated = clean, treated or "masked"
    pixel_matrix = apply_blur(matrix, system.kernel)[inside]
    profile = system.observation.profile[inside]
    weights = 1.0 / system.profile_sigma[inside]
    difference = _second_differences(size)
    penalty = difference.T @ difference
    responses = np.empty((size, 3))
    normals = np.empty((3, size, size))
    weighted_rows = []
    for c in range(3):
        weighted = pixel_matrix * weights[:, c][:, None]
        normal = weighted.T @ weighted
        normals[c] = normal + RESPONSE_SMOOTHNESS * float(np.trace(normal)) / size * penalty
        weighted_rows.append(weighted)
    # The three channels' pseudo-inverses in one stacked call (each ``pinv_symmetric``'s bits).
    covariances = pinv_symmetric_stack(normals)
    chi2 = 0.0
    for c, weighted in enumerate(weighted_rows):
        responses[:, c] = covariances[c] @ (weighted.T @ (weights[:, c] * profile[:, c]))
        chi2 += float(np.sum((weights[:, c] * profile[:, c] - weighted @ responses[:, c]) ** 2))
    return ResponseEstimate(
        responses,
        covariances,
        inside,
        chi2,
        onset_nm if treated else None,
        treated,
        log_slope_squared(system.operators),
    )


@dataclass(frozen=True, eq=False)
class LampData:
    """One lamp prepared for the efficiency rows: its response and its direct measurement."""

    name: str
    direct_row: FloatArray  # (f,): ∫ e φ_i dλ
    response: ResponseEstimate
    direct: FloatArray  # (3,)
    direct_sigma: FloatArray  # (3,)
    operators: LampOperators | None = None  # e φ_i on the fine axis, for an η₀ inside the row

    def zeroth_order_row(self, zeroth_order: FloatArray | None) -> FloatArray:
        """``∫ e φ_i η₀ dλ`` ``(f,)`` (``(k, f)`` for ``k`` rows of ``η₀``) with ``η₀`` given on the fine axis (``None``: flat, the
        plain direct row). Integrated at 1 nm: ``η₀`` may vary within a grid step (a blazed
        grating's vanishes at its blaze)."""
        if zeroth_order is None or self.operators is None:
            return self.direct_row
        return np.asarray(zeroth_order @ self._trapezoid_densities, dtype=np.float64)

    @cached_property
    def _trapezoid_densities(self) -> FloatArray:
        """``e φ_i`` on the fine axis times the trapezoid rule's weights ``(n_fine, f)``: the
        integral of a density linear between the axis' nodes (what
        :class:`~calib.model.forward.PiecewiseLinearDensity` integrates), as one product with
        ``η₀`` — the physical grating fit evaluates it hundreds of times per lamp."""
        assert self.operators is not None
        densities = self.operators.densities
        axis = densities.axis_nm
        weights = np.full(axis.size, float(axis[1] - axis[0]))
        weights[[0, -1]] *= 0.5
        return np.asarray(densities.density * weights[:, None], dtype=np.float64)


def prepared_response(
    observation: LampObservation,
    mapping: WavelengthMapping,
    grid: WavelengthGrid,
    kernel: FloatArray | None,
) -> tuple[LampSystem, ResponseEstimate]:
    """``observation`` prepared on ``mapping`` (:func:`calib.methods.closed_form.prepare_matched_lamp`
    with the camera's line spread ``kernel``) and its response fitted there (:func:`fit_response`).

    Inside a :func:`calib.methods.solve_scope.solve_scope`, the pair made once for the same inputs
    (by content): the σ budget's η-terms re-solve changes only the solve's options, so it reads
    the estimate's lamps and responses instead of making them again (decision 0107)."""

    def made() -> tuple[LampSystem, ResponseEstimate]:
        system = prepare_matched_lamp(observation, mapping, grid, kernel)
        return system, fit_response(system, mapping)

    # Not strict: an observation's metadata may hold objects no digest reads (not shared then).
    return reuse("prepared response", (observation, mapping, grid, kernel), made, strict=False)


def lamp_data(
    system: LampSystem, mapping: WavelengthMapping, response: ResponseEstimate | None = None
) -> LampData:
    """Step 1 for one lamp with a direct measurement (``response``: :func:`fit_response` of the
    system on ``mapping``, already made)."""
    observation = system.observation
    if observation.direct_rgb is None:
        raise InputError(
            "every lamp of the multi-lamp solve needs a direct (0th-order) measurement",
            source=f"lamp {observation.name!r}",
        )
    direct = np.asarray(observation.direct_rgb, dtype=np.float64)
    sigma = (
        np.zeros(3)
        if observation.direct_sigma is None
        else np.asarray(observation.direct_sigma, dtype=np.float64)
    )
    return LampData(
        observation.name,
        system.operators.direct_row,
        fit_response(system, mapping) if response is None else response,
        direct,
        sigma,
        system.operators,
    )


def direct_rows(
    lamps: Sequence[LampData],
    inverse_efficiency: FloatArray,
    *,
    gain_sigma: float | None = None,
    zeroth_order: FloatArray | None = None,
    node_factor: FloatArray | None = None,
    floor: float = MODEL_FLOOR,
) -> tuple[FloatArray, FloatArray]:
    """The whitened equations ``(d_l ⊙ q̂_lc)ᵀ g = m_dir,lc`` on the grid's nodes of ``g`` (``η⁻¹``
    for the Fourier model, ``T/η₁`` for a physical one, whose ``η₀`` enters ``d_l`` on the fine
    axis: ``zeroth_order``, :meth:`LampData.zeroth_order_row`): rows ``(3L, f)``, targets ``(3L,)``;
    with ``zeroth_order`` ``(k, n_fine)`` (a scan over η₀'s parameter), ``(k, 3L, f)`` and
    ``(k, 3L)``, each ``k`` the same numbers as its own call within rounding. ``node_factor``
    ``(f,)`` or ``(k, f)``: multiplies the rows made from ``zeroth_order`` node by node (a physical
    fit's ``η₁`` at the nodes, where ``zeroth_order`` is ``η₀/η₁``; decision 0154).

    Each equation's variance is the direct measurement's, the response's covariance propagated
    through the current ``g`` and the model floor; a lamp's three equations also share the error of
    its direct-to-profile ratio (``gain_sigma``, default :data:`DIRECT_GAIN_SIGMA`: exposure times
    and the lamp between the frames), a rank-one covariance ``σ_g² m mᵀ`` — so each lamp's block
    is whitened by the Cholesky factor of its 3 × 3 covariance. ``floor``: the relative floor under
    each equation's σ (:data:`MODEL_FLOOR` for the fit; the grating model's choice judges at the
    rig's error level, :data:`calib.methods.grating_models.CHOICE_FLOOR`).

    All lamps at once, on their arrays stacked (:func:`_lamp_stack`): every number is the one a
    lamp-by-lamp loop gives, to the bit (the same products per lamp, the same elementwise
    expressions; decision 0092) — the physical fits call this thousands of times per estimate.
    """
    gain = DIRECT_GAIN_SIGMA if gain_sigma is None else gain_sigma
    stack = _lamp_stack(lamps)
    if zeroth_order is None:
        row = stack.direct_row  # (L, f)
    elif stack.densities is not None:
        row = np.asarray(zeroth_order @ stack.densities, dtype=np.float64)  # (L, [k,] f)
    else:
        row = np.stack([lamp.zeroth_order_row(zeroth_order) for lamp in lamps])
    if zeroth_order is not None and node_factor is not None:
        row = row * node_factor
    spread = row * inverse_efficiency
    if spread.ndim == 2:
        propagated = ((stack.covariance @ spread[:, None, :, None])[..., 0] @ spread[:, :, None])[
            ..., 0
        ]  # (L, 3)
        response, direct, sigma2 = stack.response, stack.direct, stack.direct_sigma2
    else:  # (L, k, f): one σ per value of η₀ (a scan), (L, k, 3)
        columns = spread.swapaxes(-1, -2)[:, None]  # (L, 1, f, k)
        propagated = np.sum((stack.covariance @ columns) * columns, axis=2).swapaxes(-1, -2)
        response = stack.response[:, None]
        direct, sigma2 = stack.direct[:, None], stack.direct_sigma2[:, None]
    if spread.ndim == 2 and len(lamps) <= FLOAT_LAMPS:
        made = _few_lamps_whitened(row, response, direct, sigma2, propagated, floor, gain)
        if made is not None:
            return made
    variances = np.maximum(sigma2 + propagated + (floor * direct) ** 2, 1e-300)
    block = np.empty((*row.shape[:-1], 3, row.shape[-1] + 1))
    # Written in place (a scan's (k, 3, f) product, formed apart and copied in, was a third of
    # the call): the same products.
    np.multiply(response, row[..., None, :], out=block[..., :-1])
    block[..., -1] = direct
    whitened = _whiten_three(variances, gain * direct, block)  # (L, [k,] 3, f + 1)
    if whitened.ndim == 4:
        whitened = whitened.swapaxes(0, 1)  # (k, L, 3, f + 1): the lamps' rows in turn
    lead = whitened.shape[:-3]
    count = whitened.shape[-3] * 3
    return (
        np.ascontiguousarray(whitened[..., :-1].reshape(*lead, count, row.shape[-1])),
        np.ascontiguousarray(whitened[..., -1].reshape(*lead, count)),
    )


@dataclass(frozen=True, eq=False)
class _LampStack:
    """The arrays of a set of lamps that :func:`direct_rows` needs, stacked along a first axis
    ``L`` (read-only): ``direct_row`` ``(L, f)``, ``response`` ``(L, 3, f)`` (each ``q̂ᵀ``),
    ``covariance`` ``(L, 3, f, f)``, ``direct`` and ``direct_sigma2`` ``(L, 3)``, and
    ``densities`` ``(L, n_fine, f)`` (:attr:`LampData._trapezoid_densities`; ``None`` unless
    every lamp carries its operators on one fine axis)."""

    lamps: tuple[LampData, ...]
    direct_row: FloatArray
    response: FloatArray
    covariance: FloatArray
    direct: FloatArray
    direct_sigma2: FloatArray
    densities: FloatArray | None


#: How many lamp sets' stacks :func:`_lamp_stack` keeps (an estimate solves from one set; its
#: σ budget's re-solves and the grating model's choice from the same lamp objects, or a few).
STACK_CACHE_SIZE = 8
_STACKS: OrderedDict[tuple[int, ...], _LampStack] = OrderedDict()
_STACKS_LOCK = threading.Lock()


def _lamp_stack(lamps: Sequence[LampData]) -> _LampStack:
    """The lamps' arrays stacked (:class:`_LampStack`), kept for the last :data:`STACK_CACHE_SIZE`
    sets by the lamps' identity: a kept stack holds its lamps, so no other object can take their
    ids while it is kept (a :class:`LampData` is frozen; its arrays are never written)."""
    key = tuple(id(lamp) for lamp in lamps)
    with _STACKS_LOCK:
        stack = _STACKS.get(key)
        if stack is not None:
            _STACKS.move_to_end(key)
            return stack
    if not lamps:
        raise InputError("no lamps with a direct measurement", source="observations")
    axes = [None if lamp.operators is None else lamp.operators.densities.axis_nm for lamp in lamps]
    first_axis = axes[0]
    same_axis = first_axis is not None and all(
        axis is not None and np.array_equal(axis, first_axis) for axis in axes
    )
    stack = _LampStack(
        tuple(lamps),
        np.stack([np.asarray(lamp.direct_row, dtype=np.float64) for lamp in lamps]),
        np.stack([lamp.response.response.T for lamp in lamps]),
        np.stack([lamp.response.covariance for lamp in lamps]),
        np.stack([np.asarray(lamp.direct, dtype=np.float64) for lamp in lamps]),
        np.stack([lamp.direct_sigma**2 for lamp in lamps]),
        np.stack([lamp._trapezoid_densities for lamp in lamps]) if same_axis else None,
    )
    for array in (
        stack.direct_row,
        stack.response,
        stack.covariance,
        stack.direct,
        stack.direct_sigma2,
        stack.densities,
    ):
        if array is not None:
            array.flags.writeable = False
    with _STACKS_LOCK:
        _STACKS[key] = stack
        while len(_STACKS) > STACK_CACHE_SIZE:
            _STACKS.popitem(last=False)
    return stack


#: Up to this many lamps, :func:`direct_rows` of one ``g`` whitens lamp by lamp on Python floats
#: (:func:`_few_lamps_whitened`).
FLOAT_LAMPS = 8


def _few_lamps_whitened(
    row: FloatArray,
    response: FloatArray,
    direct: FloatArray,
    sigma2: FloatArray,
    propagated: FloatArray,
    floor: float,
    gain: float,
) -> tuple[FloatArray, FloatArray] | None:
    """:func:`direct_rows`' rows ``(3L, f)`` and targets ``(3L,)`` for one ``g`` (``row``
    ``(L, f)``, ``response`` ``(L, 3, f)``, ``direct``, ``sigma2`` and ``propagated`` ``(L, 3)``):
    the same numbers to the bit as the stacked path (:func:`_whiten_three` on the block
    ``[q̂ ⊙ d | m]``), with each lamp's variances, 3 × 3 factor and targets computed on Python
    floats (IEEE doubles: the same operations in the same order) and only the rows' substitution
    on arrays, in place. The physical grating fit's refinement calls this ~170 times per estimate
    with one or a few lamps, where the stacked path's ~40 numpy calls on 1–5 numbers were most of
    the time (decision 0116). ``None`` where a lamp's factor is not positive definite in floating
    point (a square root of a negative number, a division by zero): the stacked path carries
    those on as NaN or ±inf."""
    rows = np.multiply(response, row[:, None, :], out=np.empty(response.shape))  # (L, 3, f)
    factors: list[tuple[float, ...]] = []
    targets: list[float] = []
    try:
        for (d0, d1, d2), (s0, s1, s2), (p0, p1, p2) in zip(
            direct.tolist(), sigma2.tolist(), propagated.tolist(), strict=True
        ):
            v0 = max(s0 + p0 + (floor * d0) * (floor * d0), 1e-300)
            v1 = max(s1 + p1 + (floor * d1) * (floor * d1), 1e-300)
            v2 = max(s2 + p2 + (floor * d2) * (floor * d2), 1e-300)
            g0, g1, g2 = gain * d0, gain * d1, gain * d2
            l00 = math.sqrt(v0 + g0 * g0)
            l10 = g1 * g0 / l00
            l20 = g2 * g0 / l00
            l11 = math.sqrt(v1 + g1 * g1 - l10 * l10)
            l21 = (g2 * g1 - l20 * l10) / l11
            l22 = math.sqrt(v2 + g2 * g2 - l20 * l20 - l21 * l21)
            factors.append((l00, l10, l20, l11, l21, l22))
            t0 = d0 / l00
            t1 = (d1 - l10 * t0) / l11
            t2 = (d2 - l20 * t0 - l21 * t1) / l22
            targets.extend((t0, t1, t2))
    except (ValueError, ZeroDivisionError):
        return None
    # The substitution on every lamp's rows at once, in place: each lamp's factor a (L, 1)
    # column, or for one lamp the floats themselves (numpy's scalar operand is the cheaper call).
    columns: Sequence[float | FloatArray]
    if len(factors) == 1:
        columns = factors[0]
    else:
        table = np.array(factors, dtype=np.float64)
        columns = [table[:, index, None] for index in range(6)]
    a00, a10, a20, a11, a21, a22 = columns
    first, second, third = rows[:, 0], rows[:, 1], rows[:, 2]
    first /= a00
    second -= a10 * first
    second /= a11
    third -= a20 * first
    third -= a21 * second
    third /= a22
    return rows.reshape(-1, row.shape[-1]), np.array(targets, dtype=np.float64)


def _whiten_three(variances: FloatArray, shared: FloatArray, block: FloatArray) -> FloatArray:
    """``L⁻¹ block`` with ``L`` the Cholesky factor of ``diag(variances) + shared sharedᵀ`` (3 × 3),
    written out: the direct equations are whitened hundreds of times per physical grating fit, and
    LAPACK's call overhead on a 3 × 3 matrix is most of that time. ``variances`` ``(…, 3)`` with
    ``shared`` broadcasting against it and ``block`` ``(…, 3, m)``: every system at once (the
    elementwise expressions of one system's, so each its own numbers to the bit)."""
    v0, v1, v2 = (variances[..., i] for i in range(3))
    g0, g1, g2 = (shared[..., i] for i in range(3))
    l00 = np.sqrt(v0 + g0 * g0)
    l10 = g1 * g0 / l00
    l20 = g2 * g0 / l00
    l11 = np.sqrt(v1 + g1 * g1 - l10 * l10)
    l21 = (g2 * g1 - l20 * l10) / l11
    l22 = np.sqrt(v2 + g2 * g2 - l20 * l20 - l21 * l21)
    l00, l10, l20, l11, l21, l22 = (value[..., None] for value in (l00, l10, l20, l11, l21, l22))
    out = np.empty_like(block)
    out[..., 0, :] = block[..., 0, :] / l00
    out[..., 1, :] = (block[..., 1, :] - l10 * out[..., 0, :]) / l11
    out[..., 2, :] = (block[..., 2, :] - l20 * out[..., 0, :] - l21 * out[..., 1, :]) / l22
    return out
