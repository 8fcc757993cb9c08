"""Colour-checker baseline: sensitivities from patch RGBs under a known light (Jiang et al. 2013).

Each channel is written in the leading ``k`` vectors of the per-channel camera basis,
``s_c = B_c x_c`` (Jiang et al. found two vectors per channel enough; Makabe et al. 2025 §4 use two,
"which yielded the best results"), and a chart of known patch spectra under a known illuminant gives
``m_jc = Σ_i A_ji s_ci`` (:func:`calib.model.charts.stimulus_rows`). So each channel is a small linear
least-squares problem ``min ‖A B_c x_c − m_c‖`` — solved per channel, weighted by the patch σ when
known. This is the estimator as in colour-science's ``RGB_to_msds_camera_sensitivities_Jiang2013``
(plain least squares in the basis), with two optional extensions that are off by default: a ridge
term and non-negativity of ``s_c`` at every wavelength (:mod:`calib.model.inequality_lstsq`).

Input: one or more :class:`calib.core.observations.ChartObservation` (several charts, or one chart under
several lights, are stacked). For an image, build the observation with
:func:`calib.image.chart_image.chart_observation_from_planes` (corner patch centres → every patch).

The σ of the result is the least-squares covariance propagated through the basis: from the patch σ
when every chart has one, else from the residual scatter. It does not include the error of the basis
itself, which dominates on noise-free data.

References
----------
Jiang, J., Liu, D., Gu, J., Süsstrunk, S. (2013). What is the space of spectral sensitivity
functions for digital color cameras? IEEE WACV, 168–179.
Makabe, L. et al. (2025). Spectral Sensitivity Estimation with an Uncalibrated Diffraction
Grating, §4 ("CC").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import InputError
from calib.core.observations import ChartObservation, Observation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.baselines.inputs import (
    check_basis,
    check_weight,
    normalised_curves,
    split_observations,
)
from calib.model.bases import CameraBasis
from calib.model.charts import stimulus_rows
from calib.model.inequality_lstsq import lstsq_inequality

#: Basis vectors per channel (Jiang et al. 2013; Makabe et al. 2025 §4).
JIANG2013_N_VECTORS = 2


def _stacked_system(
    charts: Sequence[ChartObservation], grid: WavelengthGrid
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Rows ``(n, f)``, RGB ``(n, 3)`` and σ ``(n, 3)`` (``None`` unless every chart has σ)."""
    rows = np.vstack([stimulus_rows(chart, grid) for chart in charts])
    rgb = np.vstack([chart.patch_rgb for chart in charts])
    sigmas = [chart.patch_sigma for chart in charts]
    sigma = None if any(s is None for s in sigmas) else np.vstack(sigmas)  # type: ignore[arg-type]
    return rows, rgb, sigma


@one_blas_thread
def estimate_jiang2013(
    observations: Sequence[Observation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_vectors: int = JIANG2013_N_VECTORS,
    ridge: float = 0.0,
    nonnegative: bool = False,
) -> EstimateResult:
    """Estimate camera sensitivity from colour-chart observations (see the module docstring).

    Parameters
    ----------
    observations
        Chart observations (patch RGB + patch spectra + illuminant), at least ``n_vectors``
        patches in all; any other kind is refused.
    basis
        Per-channel camera basis on ``grid``; its leading ``n_vectors`` vectors are used.
    grid
        Working grid.
    n_vectors
        Basis vectors per channel ``k`` (2 in the paper).
    ridge
        Tikhonov weight on the coefficients, relative to the mean diagonal of the normal matrix
        (0 = the paper's plain least squares).
    nonnegative
        Constrain ``s_c(λ_i) ≥ 0`` at every grid node.

    Returns
    -------
    EstimateResult
        ``sensitivity`` (max 1), ``sensitivity_sigma``, residuals per chart (``"patch_rgb"``,
        measured − model, in the charts' units), diagnostics (condition numbers, basis, timing).
    """
    started = time.perf_counter()
    charts: list[ChartObservation] = split_observations(
        observations, "jiang2013", {"charts": ChartObservation}
    )["charts"]
    if not charts:
        raise InputError("jiang2013 needs at least one colour-chart observation", source="charts")
    check_basis(basis, grid, n_vectors)
    check_weight(ridge, "ridge")
    rows, rgb, sigma = _stacked_system(charts, grid)
    n_patches = rows.shape[0]
    if n_patches < n_vectors:
        raise InputError(
            f"{n_patches} patches cannot determine {n_vectors} basis coefficients per channel",
            source="charts",
        )
    sensitivity = np.empty((grid.size, 3))
    sensitivity_var = np.empty((grid.size, 3))
    conditions: list[float] = []
    chi2_per_channel: list[float] = []
    for channel in range(3):
        vectors = basis.channel(channel)[:, :n_vectors]
        design = rows @ vectors
        weights = np.ones(n_patches) if sigma is None else 1.0 / sigma[:, channel]
        weighted = design * weights[:, None]
        target = rgb[:, channel] * weights
        normal = weighted.T @ weighted
        penalty = ridge * float(np.trace(normal)) / n_vectors
        if penalty > 0:
            augmented = np.vstack([weighted, np.sqrt(penalty) * np.eye(n_vectors)])
            augmented_target = np.concatenate([target, np.zeros(n_vectors)])
        else:
            augmented, augmented_target = weighted, target
        if nonnegative:
            coefficients = lstsq_inequality(
                augmented, augmented_target, vectors, np.zeros(grid.size)
            )
        else:
            coefficients = np.linalg.lstsq(augmented, augmented_target, rcond=None)[0]
        conditions.append(float(np.linalg.cond(weighted)))
        residual = target - weighted @ coefficients
        dof = max(n_patches - n_vectors, 1)
        chi2 = float(residual @ residual)
        chi2_per_channel.append(chi2 / dof)
        scale = 1.0 if sigma is not None else chi2 / dof
        covariance = np.linalg.pinv(normal + penalty * np.eye(n_vectors)) * scale
        sensitivity[:, channel] = vectors @ coefficients
        sensitivity_var[:, channel] = np.einsum("ik,kl,il->i", vectors, covariance, vectors)
    curves, curves_sigma, peak = normalised_curves(
        sensitivity, np.sqrt(np.clip(sensitivity_var, 0, None)), "jiang2013"
    )
    residuals: dict[str, Any] = {}
    offset = 0
    for chart in charts:
        chunk = slice(offset, offset + chart.n_patches)
        residuals[chart.name] = {"patch_rgb": rgb[chunk] - rows[chunk] @ sensitivity}
        offset += chart.n_patches
    diagnostics = {
        "basis": basis.to_dict(),
        "n_vectors": n_vectors,
        "ridge": ridge,
        "nonnegative": nonnegative,
        "n_patches": n_patches,
        "weighted": sigma is not None,
        "condition_numbers": conditions,
        "reduced_chi2": chi2_per_channel,
        "sensitivity_scale": peak,
        "timings": {"total_s": time.perf_counter() - started},
    }
    return EstimateResult(
        method="jiang2013",
        wavelength_nm=grid.wavelength_nm,
        sensitivity=curves,
        sensitivity_sigma=curves_sigma,
        residuals=residuals,
        diagnostics=diagnostics,
    )
