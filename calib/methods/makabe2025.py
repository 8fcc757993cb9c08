"""The paper's joint estimate of camera sensitivity and grating efficiency (Makabe et al. 2025).

A lamp with a measured spectrum, seen through an uncalibrated grating, gives the direct (0th-order)
RGB and a first-order profile; with the pixel→wavelength mapping known, both are linear in the
camera's basis coefficients ``c_s,c`` (``s_c = B_s,c c_s,c``, the 7-vector SVD basis of measured
cameras) and those of the inverse grating efficiency ``η⁻¹ = B_η c_η`` (Fourier, Supp. E), and the
joint estimate has a closed form. Two formulations (``Makabe2025Options.formulation``):

``"printed"`` (default) — the paper as printed (Eq. 9–12, Supp. F): ``a_c = diag(e⁻¹) W† m_c`` with
    ``W`` the linear-interpolation weights of Eq. 14, the homogeneous system
    ``diag(a_c) B_η c_η − B_s,c c_s,c = 0`` (``3f`` rows) minimised subject to the direct constraint
    through its Lagrange (KKT) system. One lamp.
``"measured"`` — the same model with rows in measured-profile units, one per pixel and channel:
    ``m_c(p) · (Ψ c_η)(p) − (K B_s,c c_s,c)(p) = 0``, ``K[p, i] = ∫_pixel e φ_i dλ`` (the *measured*
    lamp at 1 nm over each pixel's wavelength interval), weighted by the profile's noise. Several
    lamps may be solved jointly (each lamp's brightness by alternation).

The mapping (§3.2) comes from :func:`calib.wavelength.find_mapping` (fluorescent lines or a
broadband search, then a fit of the whole profile), from a given mapping, or — as the paper finds it
— from its point-to-plane ICP (``mapping_method="icp"``). The project's own solve, with the camera
free at every grid wavelength under a Gaussian prior, is :mod:`calib.methods.prior_solve`
(registered as ``"prior"``).

References
----------
Makabe, L., Santo, H., Okura, F., Brown, M. S., Matsushita, Y. (2025). Spectral Sensitivity
Estimation with an Uncalibrated Diffraction Grating. Eq. 4–16, Supp. C–F.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.closed_form import ClosedFormOptions, joint_result, joint_setup
from calib.model.bases import CameraBasis
from calib.model.forward import WavelengthMapping, hat_matrix
from calib.model.linear_model import (
    LampSystem,
    design_matrices,
    solve_constrained,
    solve_constrained_normal,
)

#: Registry name (and the result's ``method``).
MAKABE2025_METHOD = "makabe2025"
Formulation = Literal["printed", "measured"]
#: The paper's rows as printed, or the same model in measured-profile units (module docstring).
FORMULATIONS: tuple[Formulation, ...] = ("printed", "measured")


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


@dataclass(frozen=True)
class Makabe2025Options(ClosedFormOptions):
    """Options of :func:`estimate_makabe2025`: those of every closed-form solve, and the formulation.

    Attributes
    ----------
    formulation
        ``"printed"`` (the paper's Eq. 12 and KKT system, one lamp) or ``"measured"`` (the same
        model in measured-profile units, several lamps); see the module docstring.
    """

    formulation: Formulation = "printed"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.formulation not in FORMULATIONS:
            raise InputError(
                f"unknown formulation {self.formulation!r}; choose from {FORMULATIONS}",
                source="formulation",
            )


@one_blas_thread
def estimate_makabe2025(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    options: Makabe2025Options = Makabe2025Options(),
) -> EstimateResult:
    """Estimate sensitivity, grating efficiency and mapping as Makabe et al. (2025) do.

    Parameters
    ----------
    observations
        One or more lamps (direct RGB + first-order profile + measured spectrum), all in one geometry.
    basis
        Camera basis on ``grid``: its vectors span the sensitivity; its prior (mean ŝ and
        covariance) steers the mapping search.
    grid
        Working grid.
    mapping
        A known mapping (used as is unless ``options.refine_given_mapping``, then it only seeds the
        search); ``None`` finds it.
    mapping_lamp
        Find the mapping with this lamp only. Default: every lamp jointly (fluorescent lines, if any,
        start the search).
    options
        :class:`Makabe2025Options`.

    Returns
    -------
    EstimateResult
        ``method="makabe2025"``; no σ (the paper gives none).

    Raises
    ------
    InputError
        No lamps, duplicate names, a basis on another grid, no lamp with a direct measurement, or
        several solve lamps for the printed formulation.
    EstimationError
        No mapping found, a singular system, or no positive sensitivity.

    Examples
    --------
    >>> from calib.core.datasets import colour_science_cameras, find_camera
    >>> from calib.core.lamp_specs import colour_lamp
    >>> from calib.core.mapping import QuadraticMapping
    >>> from calib.model.bases import fallback_camera_basis
    >>> from calib.model.forward import render_observation
    >>> camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    >>> basis = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])
    >>> truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
    >>> led = render_observation(colour_lamp("LED-B3"), camera, mapping=truth, pixel=800)
    >>> result = estimate_makabe2025([led.observation], basis=basis, mapping=truth)
    >>> result.method, result.sensitivity.shape
    ('makabe2025', (31, 3))
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
    systems = [setup.prepared(obs, grid) for obs in setup.solve_lamps]
    if options.formulation == "printed":
        if len(systems) != 1:
            raise InputError(
                "the printed formulation solves one lamp; pass solve_lamps=(NAME,) or "
                "formulation='measured'",
                source="solve_lamps",
            )
        _, sensitivity, inverse_efficiency, info = solve_paper(
            systems[0], setup.mapping, basis, setup.efficiency_basis
        )
        info["lamp_scales"] = [1.0]
    else:
        _, sensitivity, inverse_efficiency, info = solve_noise_weighted(
            systems, setup.mapping, basis, setup.efficiency_basis
        )
    setup.timings["solve_s"] = time.perf_counter() - step
    return joint_result(
        MAKABE2025_METHOD,
        setup,
        systems,
        basis=basis,
        grid=grid,
        options=options,
        sensitivity=sensitivity,
        inverse_efficiency=inverse_efficiency,
        sensitivity_sigma=None,
        info=info,
        diagnostics={"formulation": options.formulation},
    )
