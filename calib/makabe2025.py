"""Closed-form joint estimate of camera sensitivity and grating efficiency (Makabe et al. 2025).

Model (§3.1): ``s_c = B_s,c c_s,c`` per channel and ``η⁻¹ = B_η c_η`` (Fourier), a direct constraint
``m_dir,c = e·s_c`` and a diffracted constraint per pixel. Two ways to write the diffracted constraint:

``weighting="paper"`` — the paper as printed (Eq. 9–12, Supp. F): ``a_c = diag(e⁻¹) W† m_c`` with
    ``W`` the linear-interpolation weights of Eq. 14 at the pixel centres and ``e`` on the grid; the
    homogeneous system ``diag(a_c) B_η c_η − B_s,c c_s,c = 0`` (``3f`` rows) minimised subject to the
    direct constraint through its Lagrange (KKT) system.

``weighting="noise"`` (default) — in measured-profile units, one row per pixel and channel:
    ``m_c(p) · (Ψ c_η)(p) − (K B_s,c c_s,c)(p) = 0`` where ``Ψ`` interpolates ``B_η`` at ``g(p)`` and
    ``K[p, i] = ∫_pixel e φ_i dλ`` integrates the *measured* lamp spectrum at 1 nm over each pixel's
    wavelength interval (so spiky lamps and the pixel's own width are modelled, see
    :class:`calib.forward.LampOperators`). It follows from ``m = K diag(η) s`` with η smooth over a
    pixel. Each row is weighted by ``1/(σ_c(p) · η̂⁻¹(g(p)))`` — the noise of that row — after a first
    pass with ``1/σ``; the direct constraint is exact, or a weighted row set when its σ is known. The
    paper's division by ``e`` amplifies noise where the lamp is dim; these rows do not.

Several lamps may be solved jointly (each lamp's unknown brightness is estimated by alternation).

The mapping (§3.2) comes from a fluorescent lamp's lines (:func:`calib.mapping.mapping_from_peaks`)
or, with broadband lamps only, from a global correlation search; either is then refined by minimising
this solve's own weighted residual over ``(a, b, c)`` (variable projection), which also gives the
mapping's covariance.

References
----------
Makabe, L., Santo, H., Okura, F., Brown, M. S., Matsushita, Y. (2025). Spectral Sensitivity
Estimation with an Uncalibrated Diffraction Grating. Eq. 4–16, Supp. C–F.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from calib.bases import CameraBasis, FourierConvention, fourier_basis
from calib.errors import EstimationError, InputError
from calib.forward import (
    LampOperators,
    WavelengthMapping,
    apply_blur,
    blur_kernel,
    hat_matrix,
    lamp_operators,
    pixel_edges,
)
from calib.mapping import (
    GratingGeometry,
    QuadraticMapping,
    coarse_mapping_candidates,
    mapping_from_peaks,
    model_curve_on_fine_axis,
    refine_mapping,
)
from calib.observations import LampObservation
from calib.result import EstimateResult
from calib.spectra import DEFAULT_GRID, WavelengthGrid

FloatArray = NDArray[np.float64]
Weighting = Literal["noise", "paper"]


@dataclass(frozen=True, eq=False)
class LampSystem:
    """One lamp's data prepared for the solver (everything that does not depend on the mapping)."""

    observation: LampObservation
    operators: LampOperators
    edges_px: FloatArray
    profile_sigma: FloatArray
    kernel: FloatArray | None

    @property
    def profile(self) -> FloatArray:
        return self.observation.profile


def prepare_lamp(
    observation: LampObservation,
    grid: WavelengthGrid,
    *,
    slit_width_px: float = 0.0,
    psf_sigma_px: float = 0.0,
) -> LampSystem:
    """Precompute a lamp's operators; a missing profile σ becomes 1 % of the profile's peak."""
    sigma = observation.profile_sigma
    if sigma is None:
        sigma = np.full(
            observation.profile.shape, 0.01 * max(float(np.max(observation.profile)), 1e-300)
        )
    elif np.any(sigma <= 0):
        raise InputError(
            "profile sigma must be > 0 everywhere", source=f"lamp {observation.name!r}"
        )
    return LampSystem(
        observation=observation,
        operators=lamp_operators(observation.spectrum, grid),
        edges_px=pixel_edges(observation.pixel),
        profile_sigma=np.asarray(sigma, dtype=np.float64),
        kernel=blur_kernel(slit_width_px, psf_sigma_px),
    )


def design_matrices(
    system: LampSystem, mapping: WavelengthMapping, efficiency_basis: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``K`` ``(n, f)`` (lamp × hat integrated per pixel, blurred) and ``Ψ`` ``(n, b_η)``."""
    grid = system.operators.grid
    edges_nm = mapping.wavelength_nm(system.edges_px)
    pixel_matrix = apply_blur(system.operators.pixel_matrix(edges_nm), system.kernel)
    centres_nm = mapping.wavelength_nm(system.observation.pixel)
    psi = hat_matrix(grid, centres_nm, clamp=True) @ efficiency_basis
    # Pixels mapped off the grid are predicted dark: their residual is m·(constant term of η⁻¹), a
    # fixed cost for light the model cannot explain (not η⁻¹ at the edge, which the fit could zero).
    outside = (centres_nm < grid.start_nm) | (centres_nm > grid.stop_nm)
    psi[outside] = 0.0
    psi[outside, 0] = 1.0
    return pixel_matrix, psi


def _diffracted_rows(
    system: LampSystem,
    pixel_matrix: FloatArray,
    psi: FloatArray,
    basis: CameraBasis,
    weights: FloatArray,
    lamp_scale: float = 1.0,
) -> FloatArray:
    """Weighted rows ``w (m Ψ c_η − E K B_c c_c)``: shape ``(3n, b_η + 3k)``."""
    n, b_eta = psi.shape
    k = basis.n_vectors
    rows = np.zeros((3 * n, b_eta + 3 * k))
    for channel in range(3):
        block = slice(channel * n, (channel + 1) * n)
        w = weights[:, channel][:, None]
        rows[block, :b_eta] = w * system.profile[:, channel][:, None] * psi
        rows[block, b_eta + channel * k : b_eta + (channel + 1) * k] = (
            -lamp_scale * w * (pixel_matrix @ basis.channel(channel))
        )
    return rows


def _direct_rows(
    system: LampSystem, basis: CameraBasis, b_eta: int, lamp_scale: float = 1.0
) -> FloatArray:
    """``E d B_c`` for each channel: shape ``(3, b_η + 3k)``."""
    k = basis.n_vectors
    rows = np.zeros((3, b_eta + 3 * k))
    for channel in range(3):
        rows[channel, b_eta + channel * k : b_eta + (channel + 1) * k] = lamp_scale * (
            system.operators.direct_row @ basis.channel(channel)
        )
    return rows


def solve_constrained(
    rows: FloatArray,
    constraint: FloatArray,
    target: FloatArray,
    constraint_sigma: FloatArray | None = None,
) -> tuple[FloatArray, dict[str, float]]:
    """``argmin ‖rows x‖²`` s.t. ``constraint x = target`` (or weighted rows when σ is given).

    The equality case uses the null space of the constraint (numerically stabler than the KKT system,
    same solution). Returns the solution and condition numbers.
    """
    if constraint_sigma is not None:
        stacked = np.vstack([rows, constraint / constraint_sigma[:, None]])
        rhs = np.concatenate([np.zeros(rows.shape[0]), target / constraint_sigma])
        solution, *_ = np.linalg.lstsq(stacked, rhs, rcond=None)
        return solution, {"condition": float(np.linalg.cond(stacked))}
    particular, *_ = np.linalg.lstsq(constraint, target, rcond=None)
    _, singular, vt = np.linalg.svd(constraint)
    rank = int(np.sum(singular > singular[0] * 1e-12))
    null_space = vt[rank:].T
    reduced = rows @ null_space
    coefficients, *_ = np.linalg.lstsq(reduced, -rows @ particular, rcond=None)
    return particular + null_space @ coefficients, {
        "condition": float(np.linalg.cond(reduced)),
        "constraint_condition": float(singular[0] / singular[rank - 1]),
    }


def solve_constrained_normal(
    normal: FloatArray,
    constraint: FloatArray,
    target: FloatArray,
    constraint_sigma: FloatArray | None = None,
) -> tuple[FloatArray, dict[str, float]]:
    """As :func:`solve_constrained` for the quadratic form ``xᵀ N x`` given by its matrix ``N``."""
    if constraint_sigma is not None:
        weighted = constraint / constraint_sigma[:, None]
        system = normal + weighted.T @ weighted
        solution = np.asarray(
            np.linalg.solve(system, weighted.T @ (target / constraint_sigma)), dtype=np.float64
        )
        return solution, {"condition": float(np.linalg.cond(system))}
    particular, *_ = np.linalg.lstsq(constraint, target, rcond=None)
    _, singular, vt = np.linalg.svd(constraint)
    rank = int(np.sum(singular > singular[0] * 1e-12))
    null_space = vt[rank:].T
    reduced = null_space.T @ normal @ null_space
    coefficients = np.linalg.solve(reduced, -null_space.T @ (normal @ particular))
    return particular + null_space @ coefficients, {
        "condition": float(np.sqrt(max(np.linalg.cond(reduced), 1.0))),
        "constraint_condition": float(singular[0] / singular[rank - 1]),
    }


def _split(
    solution: FloatArray, basis: CameraBasis, efficiency_basis: FloatArray
) -> tuple[FloatArray, FloatArray]:
    b_eta = efficiency_basis.shape[1]
    k = basis.n_vectors
    inverse_efficiency = efficiency_basis @ solution[:b_eta]
    sensitivity = np.stack(
        [basis.channel(c) @ solution[b_eta + c * k : b_eta + (c + 1) * k] for c in range(3)], axis=1
    )
    return sensitivity, inverse_efficiency


def mapping_residual(system: LampSystem, basis: CameraBasis, efficiency_basis: FloatArray) -> Any:
    """The closed-form solve's weighted residual as a function of the mapping (for refinement).

    The gauge is fixed by the constant term of ``η⁻¹`` (= 1), so no direct measurement is needed
    and the fluorescent lamp can be used too. Pixels mapped outside the grid are predicted dark, so
    pushing signal out of the grid costs residual; a mapping whose pixels do not cover the whole grid
    is penalised (the profile must hold the whole first order), otherwise the flexible η⁻¹ could
    explain away a region of the grid that no pixel sees.
    """
    weights = 1.0 / system.profile_sigma
    grid = system.operators.grid
    ends_px = system.observation.pixel[[0, -1]]
    # The penalty for a mapping that leaves part of the grid outside the profile: as many residual
    # units per nm as the whole profile's signal-to-noise, so that no fit can pay for it.
    coverage_weight = float(np.sqrt(np.sum((system.profile * weights) ** 2)))

    def residual(mapping: QuadraticMapping) -> FloatArray:
        ends_nm = mapping.wavelength_nm(ends_px)
        shortfall = np.array(
            [max(ends_nm.min() - grid.start_nm, 0.0), max(grid.stop_nm - ends_nm.max(), 0.0)]
        )
        pixel_matrix, psi = design_matrices(system, mapping, efficiency_basis)
        rows = _diffracted_rows(system, pixel_matrix, psi, basis, weights)
        fixed, free = rows[:, 0], rows[:, 1:]
        normal = free.T @ free
        scale = np.sqrt(np.clip(np.diag(normal), 1e-300, None))
        try:
            z = np.linalg.solve(normal / np.outer(scale, scale), -(free.T @ fixed) / scale) / scale
        except np.linalg.LinAlgError:
            z = np.asarray(np.linalg.lstsq(free, -fixed, rcond=None)[0], dtype=np.float64)
        return np.concatenate([fixed + free @ z, coverage_weight * shortfall])

    return residual


#: Gaussian blurs (σ in nm) of the coarse-to-fine mapping refinement, before the unblurred stage.
COARSE_TO_FINE_BLUR_NM: tuple[float, ...] = (6.0, 2.0)


def _blurred(system: LampSystem, sigma_px: float) -> LampSystem:
    """The same lamp with profile and model both blurred by a Gaussian of ``sigma_px``."""
    extra = blur_kernel(0.0, sigma_px)
    if extra is None:
        return system
    kernel = extra if system.kernel is None else np.convolve(system.kernel, extra)
    observation = replace(system.observation, profile=apply_blur(system.observation.profile, extra))
    return replace(system, observation=observation, kernel=kernel)


def estimate_mapping(
    mapping_system: LampSystem,
    basis: CameraBasis,
    efficiency_basis: FloatArray,
    *,
    use_peaks: bool,
    initial: QuadraticMapping | None = None,
    n_candidates: int = 4,
    refine_system: LampSystem | None = None,
) -> QuadraticMapping:
    """Find the pixel→wavelength mapping from one lamp (see the module docstring).

    ``refine_system`` (default: the mapping lamp) is the lamp whose solve residual refines the
    start: a broadband lamp gives a smooth objective, a line lamp a rough one whose basins are only
    as wide as its lines, so the peak-matched start of a fluorescent lamp is refined with the LED.
    """
    observation = mapping_system.observation
    grid = mapping_system.operators.grid
    pixel_range = (float(observation.pixel[0]), float(observation.pixel[-1]))
    refine_with = refine_system or mapping_system
    residual = mapping_residual(refine_with, basis, efficiency_basis)
    if initial is not None:
        starts = [initial]
        method = f"{initial.method}+refined"
    elif use_peaks:
        starts = [
            mapping_from_peaks(
                observation.spectrum, observation.pixel, observation.profile, basis.mean, grid=grid
            )
        ]
        method = "fluorescent-peaks+refined"
    else:
        axis, model = model_curve_on_fine_axis(observation.spectrum, basis.mean, grid)
        starts = coarse_mapping_candidates(
            observation.pixel,
            observation.profile,
            axis,
            model,
            grid=grid,
            n_candidates=n_candidates,
        )
        method = "led-search+refined"
    # Coarse to fine: first match blurred versions of profile and model (wide basins around sharp
    # lines), then sharpen. The last stage is the unblurred residual.
    dispersion = float(np.median(np.abs(starts[0].dispersion_nm_per_px(observation.pixel))))
    spacing = float(np.median(np.diff(observation.pixel)))
    stages = [
        mapping_residual(
            _blurred(refine_with, blur_nm / dispersion / spacing), basis, efficiency_basis
        )
        for blur_nm in COARSE_TO_FINE_BLUR_NM
    ] + [residual]
    best: tuple[float, QuadraticMapping] | None = None
    for start in starts:
        refined = start
        for stage in stages:
            refined, cost = refine_mapping(refined, stage, pixel_range=pixel_range, method=method)
        if best is None or cost < best[0]:
            best = (cost, refined)
    assert best is not None
    cost, mapping = best
    return mapping.with_details(
        details={
            **dict(mapping.details),
            "mapping_lamp": observation.name,
            "refined_with": refine_with.observation.name,
            "n_starts": len(starts),
            "start": starts[0].to_dict() if len(starts) == 1 else [s.coefficients for s in starts],
        }
    )


def _noise_scale(inverse_efficiency: FloatArray) -> FloatArray:
    """``|η̂⁻¹|`` at the pixels, bounded below so that a near-zero estimate cannot blow up a weight."""
    magnitude = np.abs(inverse_efficiency)
    floor = 0.05 * float(np.median(magnitude)) if magnitude.size else 0.0
    return np.maximum(magnitude, max(floor, 1e-300))


def solve_noise_weighted(
    systems: Sequence[LampSystem],
    mapping: WavelengthMapping,
    basis: CameraBasis,
    efficiency_basis: FloatArray,
    *,
    reweight: bool = False,
    direct_constraint: Literal["exact", "weighted"] = "exact",
    scale_iterations: int = 6,
) -> tuple[FloatArray, FloatArray, FloatArray, dict[str, Any]]:
    """Solve for ``c_η`` and ``c_s`` over one or more lamps in measured units (see module docstring).

    ``reweight`` adds a second pass weighted by ``1/(σ η̂⁻¹)`` (the rows' exact noise);
    ``direct_constraint`` chooses an exact direct constraint (default, as the paper) or weighted rows with
    observations' ``direct_sigma``. On the synthetic protocol the basis gap of real cameras, not the
    noise, dominates the residual, and the defaults (one pass, exact direct) are the most accurate.

    Returns
    -------
    (solution, sensitivity, inverse_efficiency, info)
        ``sensitivity`` ``(f, 3)`` in absolute units of the first lamp, ``η⁻¹`` ``(f,)``.
    """
    b_eta = efficiency_basis.shape[1]
    designs = [design_matrices(system, mapping, efficiency_basis) for system in systems]
    scales = np.ones(len(systems))
    inverse_at_pixels = [np.ones(system.observation.n_pixels) for system in systems]
    info: dict[str, Any] = {}
    solution = np.zeros(b_eta + 3 * basis.n_vectors)
    passes = 2 if reweight else 1
    noise_known = all(system.observation.profile_sigma is not None for system in systems)
    for iteration in range(passes + (scale_iterations if len(systems) > 1 else 0)):
        rows, constraints, targets, sigmas = [], [], [], []
        for index, (system, (pixel_matrix, psi)) in enumerate(zip(systems, designs, strict=True)):
            weights = 1.0 / (system.profile_sigma * _noise_scale(inverse_at_pixels[index])[:, None])
            rows.append(_diffracted_rows(system, pixel_matrix, psi, basis, weights, scales[index]))
            direct = system.observation.direct_rgb
            if direct is None:
                raise InputError(
                    "the solve needs the direct (0th-order) RGB of every solve lamp",
                    source=f"lamp {system.observation.name!r}",
                )
            constraints.append(_direct_rows(system, basis, b_eta, scales[index]))
            targets.append(direct)
            sigmas.append(
                system.observation.direct_sigma if direct_constraint == "weighted" else None
            )
        if len(systems) > 1:
            # Several lamps: every direct measurement is a weighted row set (0.1 % when σ is unknown).
            sigmas = [
                s if s is not None else 1e-3 * np.abs(t) + 1e-300
                for s, t in zip(sigmas, targets, strict=True)
            ]
        known_sigmas = [s for s in sigmas if s is not None]
        constraint_sigma: FloatArray | None = (
            np.concatenate(known_sigmas) if len(known_sigmas) == len(sigmas) else None
        )
        if noise_known:
            # Errors-in-variables correction: the measured profile multiplies η⁻¹ in every row, so
            # E‖rows x‖² carries + Σ (wσ)² (Ψ c_η)²; subtracting it removes the pull of η⁻¹ to zero.
            stacked = np.vstack(rows)
            normal = stacked.T @ stacked
            for index, (_, psi) in enumerate(designs):
                noise_weight = 1.0 / _noise_scale(inverse_at_pixels[index]) ** 2
                normal[:b_eta, :b_eta] -= 3 * psi.T @ (psi * noise_weight[:, None])
            solution, info = solve_constrained_normal(
                normal, np.vstack(constraints), np.concatenate(targets), constraint_sigma
            )
        else:
            solution, info = solve_constrained(
                np.vstack(rows), np.vstack(constraints), np.concatenate(targets), constraint_sigma
            )
        inverse_at_pixels = [psi @ solution[:b_eta] for _, psi in designs]
        if len(systems) > 1 and iteration >= 1:
            scales = _update_scales(systems, designs, basis, solution, b_eta, scales)
    sensitivity, inverse_efficiency = _split(solution, basis, efficiency_basis)
    info["lamp_scales"] = scales.tolist()
    info["passes"] = passes
    return solution, sensitivity, inverse_efficiency, info


def _update_scales(
    systems: Sequence[LampSystem],
    designs: Sequence[tuple[FloatArray, FloatArray]],
    basis: CameraBasis,
    solution: FloatArray,
    b_eta: int,
    scales: FloatArray,
) -> FloatArray:
    """Per-lamp brightness ``E_l`` by 1-D least squares on that lamp's rows (lamp 0 stays 1)."""
    sensitivity, _ = _split(solution, basis, np.eye(b_eta))
    updated = scales.copy()
    for index in range(1, len(systems)):
        system = systems[index]
        pixel_matrix, psi = designs[index]
        inverse = psi @ solution[:b_eta]
        weights = 1.0 / (system.profile_sigma * _noise_scale(inverse)[:, None])
        left = (system.profile * inverse[:, None] * weights).ravel()
        right = ((pixel_matrix @ sensitivity) * weights).ravel()
        direct = system.observation.direct_rgb
        direct_sigma = system.observation.direct_sigma
        model_direct = system.operators.direct_row @ sensitivity
        if direct is not None:
            dsig = direct_sigma if direct_sigma is not None else 1e-3 * np.abs(direct) + 1e-300
            left = np.concatenate([left, direct / dsig])
            right = np.concatenate([right, model_direct / dsig])
        updated[index] = float(left @ right) / max(float(right @ right), 1e-300)
    return updated


def solve_paper(
    system: LampSystem,
    mapping: WavelengthMapping,
    basis: CameraBasis,
    efficiency_basis: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, dict[str, Any]]:
    """The paper's solve as printed (Eq. 9–12 with W from Eq. 14 and the KKT system of Supp. F)."""
    grid = system.operators.grid
    observation = system.observation
    if observation.direct_rgb is None:
        raise InputError(
            "the solve needs the direct (0th-order) RGB", source=f"lamp {observation.name!r}"
        )
    lamp_grid = observation.spectrum.resample(grid, "integrate").values
    if np.any(lamp_grid <= 0):
        raise EstimationError(
            f"lamp {observation.name!r} is zero at some grid wavelength; the paper's a = e⁻¹W†m is "
            "undefined there (use weighting='noise')"
        )
    weight_matrix = hat_matrix(grid, mapping.wavelength_nm(observation.pixel))
    pseudo_inverse = np.linalg.pinv(weight_matrix)
    b_eta = efficiency_basis.shape[1]
    k = basis.n_vectors
    f = grid.size
    a_dif = np.zeros((3 * f, b_eta + 3 * k))
    a_dir = np.zeros((3, b_eta + 3 * k))
    for channel in range(3):
        a_vector = (pseudo_inverse @ observation.profile[:, channel]) / lamp_grid
        block = slice(channel * f, (channel + 1) * f)
        a_dif[block, :b_eta] = a_vector[:, None] * efficiency_basis
        a_dif[block, b_eta + channel * k : b_eta + (channel + 1) * k] = -basis.channel(channel)
        a_dir[channel, b_eta + channel * k : b_eta + (channel + 1) * k] = lamp_grid @ basis.channel(
            channel
        )
    size = b_eta + 3 * k
    kkt = np.zeros((size + 3, size + 3))
    kkt[:size, :size] = 2 * a_dif.T @ a_dif
    kkt[:size, size:] = a_dir.T
    kkt[size:, :size] = a_dir
    rhs = np.concatenate([np.zeros(size), observation.direct_rgb])
    try:
        solution = np.linalg.solve(kkt, rhs)[:size]
    except np.linalg.LinAlgError as exc:
        raise EstimationError(
            f"the KKT system is singular ({exc}); is W full column rank?"
        ) from None
    sensitivity, inverse_efficiency = _split(solution, basis, efficiency_basis)
    return (
        solution,
        sensitivity,
        inverse_efficiency,
        {
            "kkt_condition": float(np.linalg.cond(kkt)),
            "weight_matrix_rank": int(np.linalg.matrix_rank(weight_matrix)),
        },
    )


def _profile_model(
    system: LampSystem,
    mapping: WavelengthMapping,
    sensitivity: FloatArray,
    inverse_efficiency: FloatArray,
    scale: float,
) -> FloatArray:
    """Predicted profile ``(n, 3)``: ``E K s / η⁻¹(g(p))``."""
    grid = system.operators.grid
    edges_nm = mapping.wavelength_nm(system.edges_px)
    pixel_matrix = apply_blur(system.operators.pixel_matrix(edges_nm), system.kernel)
    inverse = (
        hat_matrix(grid, mapping.wavelength_nm(system.observation.pixel), clamp=True)
        @ inverse_efficiency
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        model = scale * (pixel_matrix @ sensitivity) / inverse[:, None]
    return np.where(np.isfinite(model), model, 0.0)


def estimate_makabe2025(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    weighting: Weighting = "noise",
    efficiency_terms: int = 7,
    fourier_convention: FourierConvention = "paired",
    solve_lamps: Sequence[str] | None = None,
    refine_given_mapping: bool = False,
    slit_width_px: float = 0.0,
    psf_sigma_px: float = 0.0,
    n_candidates: int = 4,
) -> EstimateResult:
    """Estimate sensitivity, grating efficiency and mapping from lamp observations.

    Parameters
    ----------
    observations
        One or more lamps (direct RGB + first-order profile + measured spectrum), all in one geometry.
    basis
        Camera basis on ``grid`` (``k`` vectors per channel).
    grid
        Working grid.
    mapping
        A known mapping (used as is unless ``refine_given_mapping``); ``None`` estimates it.
    mapping_lamp
        Name of the observation to find the mapping with. Default: the first fluorescent lamp (peak
        matching, "LED+Flu"), else the first solve lamp (broadband search, "LED only").
    weighting
        ``"noise"`` (measured units, noise-weighted) or ``"paper"`` (Eq. 9–12 as printed).
    efficiency_terms, fourier_convention
        The Fourier basis for ``η⁻¹`` (Supp. E).
    solve_lamps
        Names of the lamps that enter the solve. Default: every non-fluorescent lamp with a direct
        measurement (the paper uses the LED only), else every lamp with one.
    refine_given_mapping
        Refine a given mapping by the solve's residual.
    slit_width_px, psf_sigma_px
        Blur of the profile along dispersion, modelled in the solve (``"noise"`` weighting).
    n_candidates
        Starting points kept from the broadband search.

    Returns
    -------
    EstimateResult
    """
    started = time.perf_counter()
    if not observations:
        raise InputError("no lamp observations given", source="observations")
    if basis.grid != grid:
        raise InputError(
            f"the camera basis is on grid {basis.grid}, the estimate on {grid}", source="basis"
        )
    names = [obs.name for obs in observations]
    if len(set(names)) != len(names):
        raise InputError(f"lamp names must be unique, got {names}", source="observations")
    by_name = {obs.name: obs for obs in observations}
    if solve_lamps is None:
        chosen = [o for o in observations if o.direct_rgb is not None and o.kind != "fluorescent"]
        chosen = chosen or [o for o in observations if o.direct_rgb is not None]
    else:
        missing = [name for name in solve_lamps if name not in by_name]
        if missing:
            raise InputError(
                f"unknown solve lamps {missing}; lamps are {names}", source="solve_lamps"
            )
        chosen = [by_name[name] for name in solve_lamps]
    if not chosen:
        raise InputError(
            "no lamp has a direct (0th-order) measurement to solve with", source="observations"
        )
    efficiency_basis = fourier_basis(grid, efficiency_terms, convention=fourier_convention)
    blur = {"slit_width_px": slit_width_px, "psf_sigma_px": psf_sigma_px}
    systems = [prepare_lamp(obs, grid, **blur) for obs in chosen]
    timings: dict[str, float] = {"prepare_s": time.perf_counter() - started}

    step = time.perf_counter()
    used_mapping: QuadraticMapping | GratingGeometry
    if mapping is not None and not refine_given_mapping:
        used_mapping = mapping
    else:
        if mapping_lamp is not None:
            if mapping_lamp not in by_name:
                raise InputError(
                    f"no lamp named {mapping_lamp!r}; lamps are {names}", source="mapping_lamp"
                )
            mapping_observation = by_name[mapping_lamp]
        else:
            fluorescent = [o for o in observations if o.kind == "fluorescent"]
            mapping_observation = fluorescent[0] if fluorescent else chosen[0]
        mapping_system = next(
            (s for s in systems if s.observation is mapping_observation), None
        ) or prepare_lamp(mapping_observation, grid, **blur)
        initial = None
        if mapping is not None:
            initial = (
                mapping
                if isinstance(mapping, QuadraticMapping)
                else mapping.quadratic((grid.start_nm, grid.stop_nm))
            )
        used_mapping = estimate_mapping(
            mapping_system,
            basis,
            efficiency_basis,
            use_peaks=mapping_observation.kind == "fluorescent",
            initial=initial,
            n_candidates=n_candidates,
            refine_system=systems[0] if mapping_observation.kind == "fluorescent" else None,
        )
    timings["mapping_s"] = time.perf_counter() - step

    step = time.perf_counter()
    if weighting == "paper":
        if len(systems) != 1:
            raise InputError(
                "weighting='paper' solves one lamp; pass solve_lamps=[NAME]", source="weighting"
            )
        _, sensitivity, inverse_efficiency, info = solve_paper(
            systems[0], used_mapping, basis, efficiency_basis
        )
        info["lamp_scales"] = [1.0]
    elif weighting == "noise":
        _, sensitivity, inverse_efficiency, info = solve_noise_weighted(
            systems, used_mapping, basis, efficiency_basis
        )
    else:
        raise InputError(
            f"unknown weighting {weighting!r}; use 'noise' or 'paper'", source="weighting"
        )
    timings["solve_s"] = time.perf_counter() - step

    peak = float(np.max(sensitivity))
    if not np.isfinite(peak) or peak <= 0:
        raise EstimationError(
            "the solve produced no positive sensitivity; check the inputs and mapping"
        )
    with np.errstate(divide="ignore"):
        efficiency = np.where(inverse_efficiency > 0, 1.0 / inverse_efficiency, np.nan)
    efficiency_peak = (
        float(np.nanmax(efficiency)) if np.any(np.isfinite(efficiency)) else float("nan")
    )
    residuals: dict[str, Any] = {}
    chi2 = 0.0
    count = 0
    for index, system in enumerate(systems):
        model = _profile_model(
            system, used_mapping, sensitivity, inverse_efficiency, info["lamp_scales"][index]
        )
        difference = system.profile - model
        residuals[system.observation.name] = {
            "profile": difference,
            "profile_normalised": difference / system.profile_sigma,
            "direct": None
            if system.observation.direct_rgb is None
            else system.observation.direct_rgb
            - info["lamp_scales"][index] * (system.operators.direct_row @ sensitivity),
        }
        chi2 += float(np.sum((difference / system.profile_sigma) ** 2))
        count += difference.size
    timings["total_s"] = time.perf_counter() - started
    diagnostics = {
        "basis": basis.to_dict(),
        "efficiency_basis": {"terms": efficiency_terms, "convention": fourier_convention},
        "weighting": weighting,
        "solve_lamps": [s.observation.name for s in systems],
        "negative_efficiency_nodes": int(np.sum(inverse_efficiency <= 0)),
        "sensitivity_scale": peak,
        "reduced_chi2": chi2 / max(count - efficiency_basis.shape[1] - 3 * basis.n_vectors, 1),
        "timings": timings,
        **{key: value for key, value in info.items() if key != "passes"},
    }
    return EstimateResult(
        method="makabe2025",
        wavelength_nm=grid.wavelength_nm,
        sensitivity=sensitivity / peak,
        grating_efficiency=efficiency / efficiency_peak
        if np.isfinite(efficiency_peak)
        else efficiency,
        mapping=used_mapping,
        residuals=residuals,
        diagnostics=diagnostics,
    )
