"""Joint estimate of camera sensitivity and grating efficiency from lamps seen through a grating.

Makabe et al. (2025): a lamp with a measured spectrum, seen through an uncalibrated grating, gives the
direct (0th-order) RGB and a first-order profile; with the pixel→wavelength mapping known, both are
linear in the camera sensitivity ``s_c`` and the inverse grating efficiency ``η⁻¹``, and the joint
estimate has a closed form. Three solvers share the model (``solver=``):

``"prior"`` (default) — :mod:`calib.methods.prior_solve`: ``s`` free at every grid wavelength with a Gaussian
    camera prior learnt from measured cameras, rows in measured units weighted by their noise.
``"basis"`` — the paper's model (``s_c = B_s,c c_s,c``, 7-vector SVD basis; ``η⁻¹ = B_η c_η``,
    Fourier) with rows in measured-profile units, one per pixel and channel:
    ``m_c(p) · (Ψ c_η)(p) − (K B_s,c c_s,c)(p) = 0``, ``K[p, i] = ∫_pixel e φ_i dλ`` (the *measured*
    lamp at 1 nm over each pixel's wavelength interval). Several lamps may be solved jointly (each
    lamp's brightness by alternation).
``"paper"`` — the paper as printed (Eq. 9–12, Supp. F): ``a_c = diag(e⁻¹) W† m_c`` with ``W`` the
    linear-interpolation weights of Eq. 14, the homogeneous system
    ``diag(a_c) B_η c_η − B_s,c c_s,c = 0`` (``3f`` rows) minimised subject to the direct constraint
    through its Lagrange (KKT) system. Kept to reproduce the paper.

The mapping (§3.2) comes from :func:`calib.wavelength.search.find_mapping` (fluorescent lines or a
broadband search, then a fit of the whole profile), from a given mapping, or — to reproduce the paper
— from its point-to-plane ICP (:func:`calib.core.mapping.icp_mapping`, ``mapping_method="icp"``).

References
----------
Makabe, L., Santo, H., Okura, F., Brown, M. S., Matsushita, Y. (2025). Spectral Sensitivity
Estimation with an Uncalibrated Diffraction Grating. Eq. 4–16, Supp. C–F.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.prior_solve import solve_with_prior
from calib.model.bases import CameraBasis, CameraPrior, FourierConvention, fourier_basis
from calib.model.forward import WavelengthMapping, apply_blur, hat_matrix
from calib.model.linear_model import (
    LampSystem,
    design_matrices,
    prepare_lamp,
    solve_constrained,
    solve_constrained_normal,
)
from calib.model.resolution import camera_kernel, match_spectrometer
from calib.wavelength.search import find_mapping

Solver = Literal["prior", "basis", "paper"]
MappingMethod = Literal["search", "icp"]
SOLVERS: tuple[Solver, ...] = ("prior", "basis", "paper")


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


def _dispersion(mapping: WavelengthMapping, pixel: FloatArray) -> FloatArray:
    """nm per pixel-coordinate unit at each pixel (finite difference: works for any mapping)."""
    return np.asarray(np.gradient(mapping.wavelength_nm(pixel), pixel), dtype=np.float64)


def prepare_matched_lamp(
    observation: LampObservation,
    mapping: WavelengthMapping,
    grid: WavelengthGrid,
    kernel: FloatArray | None,
) -> LampSystem:
    """A lamp prepared for the solvers, its profile matched to the spectrometer's resolution.

    Profiles measured against a broader spectrometer are blurred to its resolution (through the
    mapping's dispersion), then the lamp is prepared with the camera's line spread ``kernel``.
    """
    spacing = float(np.median(np.diff(observation.pixel)))
    dispersion = float(np.median(np.abs(_dispersion(mapping, observation.pixel))))
    matched = match_spectrometer(observation, dispersion * spacing)
    return prepare_lamp(matched, grid, kernel=kernel)


def _choose_solve_lamps(
    observations: Sequence[LampObservation], solve_lamps: Sequence[str] | None
) -> list[LampObservation]:
    by_name = {obs.name: obs for obs in observations}
    if solve_lamps is None:
        chosen = [o for o in observations if o.direct_rgb is not None and o.kind != "fluorescent"]
        chosen = chosen or [o for o in observations if o.direct_rgb is not None]
    else:
        missing = [name for name in solve_lamps if name not in by_name]
        if missing:
            raise InputError(
                f"unknown solve lamps {missing}; lamps are {list(by_name)}", source="solve_lamps"
            )
        chosen = [by_name[name] for name in solve_lamps]
    if not chosen:
        raise InputError(
            "no lamp has a direct (0th-order) measurement to solve with", source="observations"
        )
    return chosen


def _mapping_lamps(
    observations: Sequence[LampObservation], mapping_lamp: str | None
) -> list[LampObservation]:
    """The lamps the mapping is found with: the named one, else every lamp (they share one frame)."""
    if mapping_lamp is None:
        return list(observations)
    chosen = [o for o in observations if o.name == mapping_lamp]
    if not chosen:
        raise InputError(
            f"no lamp named {mapping_lamp!r}; lamps are {[o.name for o in observations]}",
            source="mapping_lamp",
        )
    return chosen


@one_blas_thread
def estimate_makabe2025(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    solver: Solver = "prior",
    mapping_method: MappingMethod = "search",
    prior_shrinkage: float | None = None,
    efficiency_terms: int = 7,
    fourier_convention: FourierConvention = "paired",
    solve_lamps: Sequence[str] | None = None,
    refine_given_mapping: bool = False,
    slit_width_px: float = 0.0,
    psf_sigma_px: float = 0.0,
) -> EstimateResult:
    """Estimate sensitivity, grating efficiency and mapping from lamp observations.

    Parameters
    ----------
    observations
        One or more lamps (direct RGB + first-order profile + measured spectrum), all in one geometry.
    basis
        Camera basis on ``grid``: its vectors (``solver="basis"``/``"paper"``) or its prior (mean ŝ
        and covariance, ``solver="prior"`` and the mapping search).
    grid
        Working grid.
    mapping
        A known mapping (used as is unless ``refine_given_mapping``, then it only seeds the search);
        ``None`` finds it.
    mapping_lamp
        Find the mapping with this lamp only. Default: every lamp jointly (fluorescent lines, if any,
        start the search).
    solver
        ``"prior"``, ``"basis"`` or ``"paper"`` (see the module docstring).
    mapping_method
        ``"search"`` (:func:`calib.wavelength.search.find_mapping`) or ``"icp"`` (the paper's
        point-to-plane ICP from a flat start, for reproduction).
    prior_shrinkage
        Shrinkage of the camera prior's covariance (default: Ledoit–Wolf, see
        :meth:`calib.model.bases.CameraBasis.prior`).
    efficiency_terms, fourier_convention
        The Fourier basis for ``η⁻¹`` (Supp. E).
    solve_lamps
        Names of the lamps that enter the solve. Default: every non-fluorescent lamp with a direct
        measurement (the paper uses the LED only), else every lamp with one.
    refine_given_mapping
        Treat ``mapping`` as a start for the search rather than the answer.
    slit_width_px, psf_sigma_px
        Blur of the profile along dispersion, modelled in the mapping search and the solve.

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
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; choose from {SOLVERS}", source="solver")
    names = [obs.name for obs in observations]
    if len(set(names)) != len(names):
        raise InputError(f"lamp names must be unique, got {names}", source="observations")
    chosen = _choose_solve_lamps(observations, solve_lamps)
    prior: CameraPrior = basis.prior(prior_shrinkage)
    efficiency_basis = fourier_basis(grid, efficiency_terms, convention=fourier_convention)
    kernel = camera_kernel(observations, slit_width_px, psf_sigma_px)
    timings: dict[str, float] = {"prepare_s": time.perf_counter() - started}

    step = time.perf_counter()
    used_mapping: QuadraticMapping | GratingGeometry
    if mapping is not None and not refine_given_mapping:
        used_mapping = mapping
    else:
        lamps = _mapping_lamps(observations, mapping_lamp)
        if mapping_method == "icp":
            from calib.wavelength.peaks import icp_mapping

            used_mapping = icp_mapping(lamps[0], prior.mean, grid)
        elif mapping_method == "search":
            starts = None
            if mapping is not None:
                start = (
                    mapping
                    if isinstance(mapping, QuadraticMapping)
                    else mapping.quadratic((grid.start_nm, grid.stop_nm))
                )
                starts = [start]
            used_mapping = find_mapping(lamps, prior, grid, starts=starts, kernel=kernel)
        else:
            raise InputError(
                f"unknown mapping method {mapping_method!r}; use 'search' or 'icp'",
                source="mapping_method",
            )
    timings["mapping_s"] = time.perf_counter() - step

    step = time.perf_counter()

    def prepared(observation: LampObservation) -> LampSystem:
        return prepare_matched_lamp(observation, used_mapping, grid, kernel)

    systems = [prepared(obs) for obs in chosen]
    sensitivity_sigma: FloatArray | None = None
    if solver == "prior":
        # Every other lamp with a direct measurement constrains η (its brightness cancels).
        companions = [
            prepared(obs)
            for obs in observations
            if obs is not chosen[0] and obs.direct_rgb is not None
        ]
        solution = solve_with_prior(
            systems[0], used_mapping, prior, efficiency_basis, companions=companions
        )
        systems = systems[:1]
        sensitivity, inverse_efficiency = solution.sensitivity, solution.inverse_efficiency
        sensitivity_sigma = solution.sensitivity_sigma
        info: dict[str, Any] = {**solution.info, "lamp_scales": [1.0]}
    elif solver == "paper":
        if len(systems) != 1:
            raise InputError(
                "solver='paper' solves one lamp; pass solve_lamps=[NAME]", source="solver"
            )
        _, sensitivity, inverse_efficiency, info = solve_paper(
            systems[0], used_mapping, basis, efficiency_basis
        )
        info["lamp_scales"] = [1.0]
    else:
        _, sensitivity, inverse_efficiency, info = solve_noise_weighted(
            systems, used_mapping, basis, efficiency_basis
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
        "solver": solver,
        "mapping_method": mapping_method if mapping is None or refine_given_mapping else "given",
        "efficiency_basis": {"terms": efficiency_terms, "convention": fourier_convention},
        "solve_lamps": [s.observation.name for s in systems],
        "negative_efficiency_nodes": int(np.sum(inverse_efficiency <= 0)),
        "sensitivity_scale": peak,
        "reduced_chi2": chi2 / max(count, 1),
        "timings": timings,
        **{key: value for key, value in info.items() if key != "passes"},
    }
    return EstimateResult(
        method="makabe2025",
        wavelength_nm=grid.wavelength_nm,
        sensitivity=sensitivity / peak,
        sensitivity_sigma=None if sensitivity_sigma is None else sensitivity_sigma / peak,
        grating_efficiency=efficiency / efficiency_peak
        if np.isfinite(efficiency_peak)
        else efficiency,
        mapping=used_mapping,
        residuals=residuals,
        diagnostics=diagnostics,
    )
