"""The linear image-formation model on a working grid, shared by the solvers.

One lamp's first-order profile ``m_c(p)`` and the camera ``s_c`` (linear between grid nodes) are related,
for a grating efficiency smooth over a pixel, by ``m_c(p) · η⁻¹(g(p)) = (K s_c)(p)`` with
``K[p, i] = ∫_pixel e(λ) φ_i(λ) dλ`` (:class:`calib.model.forward.LampOperators`); the direct signal is
``d · s_c``. :class:`LampSystem` holds what does not depend on the mapping, :func:`design_matrices`
evaluates ``K`` and ``Ψ`` (η⁻¹'s basis at the pixels) for a mapping, and :func:`solve_constrained`
solves the equality-constrained least squares problems the solvers reduce to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.observations import LampObservation, profile_sigma
from calib.core.spectra import WavelengthGrid
from calib.model.forward import (
    LampOperators,
    WavelengthMapping,
    apply_blur,
    blur_kernel,
    hat_matrix,
    lamp_operators,
    pixel_edges,
)


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
    kernel: FloatArray | None = None,
    slit_fwhm_nm: float | None = None,
) -> LampSystem:
    """Precompute a lamp's operators; a missing profile σ is estimated from the profile itself.

    ``kernel`` is the camera's line spread in profile samples (see :mod:`calib.model.resolution`); without
    it, a box of ``slit_width_px`` convolved with a Gaussian of ``psf_sigma_px`` is used.
    ``slit_fwhm_nm``: the Gaussian both the profile and the spectrum were blurred by (the operators
    then carry the slit's second-order correction, :func:`calib.model.forward.lamp_operators`).
    """
    sigma = profile_sigma(observation)
    return LampSystem(
        observation=observation,
        operators=lamp_operators(observation.spectrum, grid, slit_fwhm_nm=slit_fwhm_nm),
        edges_px=pixel_edges(observation.pixel),
        profile_sigma=np.asarray(sigma, dtype=np.float64),
        kernel=kernel if kernel is not None else blur_kernel(slit_width_px, psf_sigma_px),
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
