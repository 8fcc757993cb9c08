"""Camera sensitivity from first-order profiles alone, through a grating whose efficiency is known.

Without a direct (0th-order) measurement the closed form of Makabe et al. (2025) cannot separate the
camera from the grating: only their product shows in the profile. With η known (from an earlier
calibration, :mod:`calib.core.grating_file`, or assumed flat) the profile is linear in the camera:

``m_lc(p) = E_l ∫_{g(p−½)}^{g(p+½)} e_l(λ) η(λ) s_c(λ) dλ``,  ``s_c = B_c a_c``,

the same image formation as :mod:`calib.model.forward` (the lamp times η is integrated at 1 nm over each
pixel's wavelength interval, so spiky lamps and the pixel widths are modelled). Each lamp's brightness
``E_l`` is unknown; with several lamps they are found by alternating least squares. Rows are weighted
by the profile's noise (``1/σ``).

The mapping is given (e.g. a profile already in wavelength), or found from a fluorescent lamp's lines
(:func:`calib.core.mapping.mapping_from_peaks`), or by the broadband correlation search
(:func:`calib.core.mapping.coarse_mapping_candidates`); either start is refined by minimising this solve's
weighted residual over the mapping (variable projection, :func:`calib.core.mapping.refine_mapping`), which
also estimates the mapping's error.

The sensitivity's standard deviation combines the weighted least-squares covariance (scaled by the
reduced χ² when it exceeds 1) with what the found mapping's covariance adds (first order, by central
differences); a given efficiency's uncertainty is reported as given, not propagated.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import Spectrum, WavelengthGrid
from calib.model.bases import CameraBasis
from calib.model.forward import LampOperators, fine_axis, lamp_operators, pixel_edges
from calib.wavelength.peaks import (
    coarse_mapping_candidates,
    mapping_from_peaks,
    model_curve_on_fine_axis,
    refine_mapping,
)

#: Registry-style name of this method, recorded in results.
KNOWN_GRATING_METHOD = "known-grating"
#: Alternations between the camera and the lamps' brightness (several lamps).
_SCALE_ITERATIONS = 8


@dataclass(frozen=True, eq=False)
class _LampRows:
    """One lamp prepared for the linear solve: lamp × η operators and the weighted profile."""

    observation: LampObservation
    operators: LampOperators
    edges_px: FloatArray
    weights: FloatArray  # (n, 3): 1/σ

    def design(self, mapping: QuadraticMapping | GratingGeometry) -> FloatArray:
        """``K`` ``(n, f)``: ∫ e η φ_i over each pixel's wavelength interval."""
        return self.operators.pixel_matrix(mapping.wavelength_nm(self.edges_px))


def _lamp_through_grating(
    observation: LampObservation, efficiency: GratingEfficiency | None, grid: WavelengthGrid
) -> Spectrum:
    """``e·η`` on a 1 nm axis over the grid (``e`` when the grating is flat)."""
    spectrum = observation.spectrum
    if not spectrum.covers(grid):
        lo, hi = spectrum.range_nm
        raise InputError(
            f"the spectrum covers {lo:g}–{hi:g} nm, the grid needs {grid.start_nm:g}–"
            f"{grid.stop_nm:g} nm; measure a wider range or choose a narrower --grid",
            source=f"lamp {observation.name!r}",
        )
    if efficiency is None:
        return spectrum
    axis = np.union1d(fine_axis(grid.start_nm, grid.stop_nm, 1.0), spectrum.wavelength_nm)
    axis = axis[(axis >= grid.start_nm - 1e-9) & (axis <= grid.stop_nm + 1e-9)]
    return Spectrum(
        axis, spectrum.at(axis) * efficiency.at(axis), name=f"{spectrum.name} × grating"
    )


def _prepare(
    observation: LampObservation, efficiency: GratingEfficiency | None, grid: WavelengthGrid
) -> _LampRows:
    sigma = observation.profile_sigma
    if sigma is None:
        sigma = np.full(
            observation.profile.shape,
            0.01 * max(float(np.max(np.abs(observation.profile))), 1e-300),
        )
    if np.any(sigma <= 0):
        raise InputError("profile sigma must be > 0", source=f"lamp {observation.name!r}")
    return _LampRows(
        observation=observation,
        operators=lamp_operators(_lamp_through_grating(observation, efficiency, grid), grid),
        edges_px=pixel_edges(observation.pixel),
        weights=1.0 / np.asarray(sigma, dtype=np.float64),
    )


@dataclass(frozen=True)
class _Solution:
    coefficients: FloatArray  # (3, k), in units of the first lamp
    covariance: FloatArray  # (3, k, k)
    scales: FloatArray  # (n_lamps,)
    residuals: list[FloatArray]  # per lamp (n, 3), measured − model
    chi2: float
    dof: int


def _solve(
    lamps: Sequence[_LampRows],
    mapping: QuadraticMapping | GratingGeometry,
    basis: CameraBasis,
    designs: Sequence[FloatArray] | None = None,
) -> _Solution:
    """Weighted least squares for the camera coefficients, alternating with the lamp scales."""
    matrices = list(designs) if designs is not None else [lamp.design(mapping) for lamp in lamps]
    k = basis.n_vectors
    scales = np.ones(len(lamps))
    coefficients = np.zeros((3, k))
    covariance = np.zeros((3, k, k))
    iterations = 1 if len(lamps) == 1 else _SCALE_ITERATIONS
    for _ in range(iterations):
        for channel in range(3):
            basis_c = basis.channel(channel)
            normal = np.zeros((k, k))
            right = np.zeros(k)
            for lamp, matrix, scale in zip(lamps, matrices, scales, strict=True):
                weighted = (scale * matrix @ basis_c) * lamp.weights[:, channel, None]
                normal += weighted.T @ weighted
                right += weighted.T @ (
                    lamp.observation.profile[:, channel] * lamp.weights[:, channel]
                )
            inverse = np.linalg.pinv(normal)
            coefficients[channel] = inverse @ right
            covariance[channel] = inverse
        if len(lamps) > 1:
            for index, (lamp, matrix) in enumerate(zip(lamps, matrices, strict=True)):
                model = np.stack(
                    [matrix @ (basis.channel(c) @ coefficients[c]) for c in range(3)], axis=1
                )
                weighted_model = (model * lamp.weights).ravel()
                weighted_data = (lamp.observation.profile * lamp.weights).ravel()
                denominator = float(weighted_model @ weighted_model)
                if denominator > 0:
                    scales[index] = float(weighted_model @ weighted_data) / denominator
            scales /= scales[0] if scales[0] != 0 else 1.0
    residuals = []
    chi2 = 0.0
    count = 0
    for lamp, matrix, scale in zip(lamps, matrices, scales, strict=True):
        model = scale * np.stack(
            [matrix @ (basis.channel(c) @ coefficients[c]) for c in range(3)], axis=1
        )
        difference = lamp.observation.profile - model
        residuals.append(difference)
        chi2 += float(np.sum((difference * lamp.weights) ** 2))
        count += difference.size
    dof = max(count - 3 * k - (len(lamps) - 1), 1)
    return _Solution(coefficients, covariance, scales, residuals, chi2, dof)


def _weighted_residual(lamps: Sequence[_LampRows], basis: CameraBasis) -> Any:
    def residual(mapping: QuadraticMapping) -> FloatArray:
        solution = _solve(lamps, mapping, basis)
        return np.concatenate(
            [
                (difference * lamp.weights).ravel()
                for difference, lamp in zip(solution.residuals, lamps, strict=True)
            ]
        )

    return residual


def _find_mapping(
    mapping_lamp: _LampRows,
    all_lamps: Sequence[_LampRows],
    basis: CameraBasis,
    grid: WavelengthGrid,
    efficiency: GratingEfficiency | None,
) -> QuadraticMapping:
    """Starts from the mapping lamp (its lines, or the broadband search), refined on every lamp.

    With η known, every lamp — fluorescent ones included — follows the same linear model, so the
    refinement minimises the joint weighted residual of all lamps (each with its own brightness);
    the lowest cost over all starts wins (the residual has local minima a few nm apart).
    """
    observation = mapping_lamp.observation
    pixel, profile = observation.pixel, observation.profile
    pixel_range = (float(pixel[0]), float(pixel[-1]))
    through_grating = _lamp_through_grating(observation, efficiency, grid)
    starts: list[QuadraticMapping] = []
    method = "broadband-search+refined"
    if observation.kind == "fluorescent":
        starts.append(mapping_from_peaks(through_grating, pixel, profile, basis.mean, grid=grid))
        method = "fluorescent-peaks+refined"
    broadband = next((lamp for lamp in all_lamps if lamp.observation.kind != "fluorescent"), None)
    search = broadband or mapping_lamp
    model_nm, model = model_curve_on_fine_axis(
        _lamp_through_grating(search.observation, efficiency, grid), basis.mean, grid
    )
    try:
        starts.extend(
            coarse_mapping_candidates(
                search.observation.pixel, search.observation.profile, model_nm, model, grid=grid
            )
        )
    except EstimationError:
        if not starts:
            raise
    residual = _weighted_residual(all_lamps, basis)
    best: tuple[float, QuadraticMapping, int] | None = None
    for index, start in enumerate(starts):
        refined, cost = refine_mapping(start, residual, pixel_range=pixel_range, method=method)
        if best is None or cost < best[0]:
            best = (cost, refined, index)
    if best is None:
        raise EstimationError(f"no mapping found with lamp {observation.name!r}")
    cost, found, index = best
    if observation.kind == "fluorescent" and index > 0:
        found = found.with_details(method="broadband-search+refined")
    return found.with_details(
        details={
            **dict(found.details),
            "mapping_lamp": observation.name,
            "n_starts": len(starts),
            "refined_with": [lamp.observation.name for lamp in all_lamps],
        }
    )


def _mapping_variance(
    lamps: Sequence[_LampRows], mapping: QuadraticMapping, basis: CameraBasis
) -> FloatArray:
    """Variance ``(f, 3)`` the mapping's covariance adds to the sensitivity (first order).

    ``∂s/∂θ`` by central differences over the mapping's three anchor wavelengths (0.05 nm).
    """
    if mapping.covariance is None or mapping.pixel_range is None:
        return np.zeros((basis.grid.size, 3))
    low, high = mapping.pixel_range
    anchors = np.array([low, 0.5 * (low + high), high])
    to_coefficients = np.linalg.inv(np.stack([anchors**2, anchors, np.ones(3)], axis=1))
    covariance = np.asarray(mapping.covariance, dtype=np.float64)
    # covariance of the anchor wavelengths from that of (a, b, c)
    design = np.stack([anchors**2, anchors, np.ones(3)], axis=1)
    anchor_covariance = design @ covariance @ design.T
    step = 0.05
    base = mapping.wavelength_nm(anchors)
    derivatives = []
    for k in range(3):
        curves = []
        for sign in (1.0, -1.0):
            moved = base.copy()
            moved[k] += sign * step
            a, b, c = to_coefficients @ moved
            solution = _solve(lamps, QuadraticMapping(float(a), float(b), float(c)), basis)
            curves.append(_sensitivity(solution, basis))
        derivatives.append((curves[0] - curves[1]) / (2 * step))
    jacobian = np.stack(derivatives, axis=-1)  # (f, 3, 3 anchors)
    return np.asarray(np.einsum("fca,ab,fcb->fc", jacobian, anchor_covariance, jacobian))


def _sensitivity(solution: _Solution, basis: CameraBasis) -> FloatArray:
    return np.stack([basis.channel(c) @ solution.coefficients[c] for c in range(3)], axis=1)


def estimate_with_known_grating(
    observations: Sequence[LampObservation],
    efficiency: GratingEfficiency | None,
    *,
    basis: CameraBasis,
    grid: WavelengthGrid,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
) -> EstimateResult:
    """Estimate the camera from first-order profiles through a grating of known efficiency.

    Parameters
    ----------
    observations
        Lamps with profiles (a direct RGB, if any, is not used), all in one pixel frame.
    efficiency
        The grating's relative efficiency, or ``None`` for a flat grating.
    basis
        Camera basis on ``grid``.
    grid
        Working grid.
    mapping
        A known pixel→wavelength mapping, or ``None`` to find it.
    mapping_lamp
        The lamp to find the mapping with (default: the first fluorescent lamp, else the first).

    Returns
    -------
    EstimateResult
        ``method = "known-grating"``; ``sensitivity_sigma`` from the fit's covariance;
        ``grating_efficiency`` the given (or flat) efficiency on the grid.

    Raises
    ------
    InputError
        No observations, duplicate names, an unknown mapping lamp, a spectrum or an efficiency that
        does not cover the grid.
    EstimationError
        The mapping cannot be found, or the fit gives no positive sensitivity.
    """
    started = time.perf_counter()
    if not observations:
        raise InputError("no lamp observations given", source="observations")
    names = [obs.name for obs in observations]
    if len(set(names)) != len(names):
        raise InputError(f"lamp names must be unique, got {names}", source="observations")
    if basis.grid != grid:
        raise InputError(
            f"the camera basis is on grid {basis.grid}, the estimate on {grid}", source="basis"
        )
    if efficiency is not None and not efficiency.covers(grid):
        lo, hi = efficiency.range_nm
        raise InputError(
            f"the grating efficiency covers {lo:g}–{hi:g} nm, the grid needs {grid.start_nm:g}–"
            f"{grid.stop_nm:g} nm",
            source=efficiency.source,
        )
    prepared = {obs.name: _prepare(obs, efficiency, grid) for obs in observations}
    solve = [prepared[o.name] for o in observations if o.kind != "fluorescent"] or list(
        prepared.values()
    )
    if mapping_lamp is not None and mapping_lamp not in prepared:
        raise InputError(
            f"no lamp named {mapping_lamp!r}; lamps are {names}", source="mapping_lamp"
        )
    timings: dict[str, float] = {}
    step = time.perf_counter()
    used_mapping: QuadraticMapping | GratingGeometry
    if mapping is not None:
        used_mapping = mapping
    else:
        if mapping_lamp is None:
            fluorescent = [o.name for o in observations if o.kind == "fluorescent"]
            mapping_lamp = fluorescent[0] if fluorescent else solve[0].observation.name
        used_mapping = _find_mapping(
            prepared[mapping_lamp], list(prepared.values()), basis, grid, efficiency
        )
    timings["mapping_s"] = time.perf_counter() - step
    step = time.perf_counter()
    solution = _solve(solve, used_mapping, basis)
    timings["solve_s"] = time.perf_counter() - step
    sensitivity = _sensitivity(solution, basis)
    reduced_chi2 = solution.chi2 / solution.dof
    variance = np.stack(
        [
            np.einsum("ij,jk,ik->i", basis.channel(c), solution.covariance[c], basis.channel(c))
            for c in range(3)
        ],
        axis=1,
    ) * max(reduced_chi2, 1.0)
    if mapping is None and isinstance(used_mapping, QuadraticMapping):
        variance = variance + _mapping_variance(solve, used_mapping, basis)
    peak = float(np.max(sensitivity))
    if not np.isfinite(peak) or peak <= 0:
        raise EstimationError(
            "the fit gives no positive sensitivity; check the profile, spectrum and mapping"
        )
    wavelength = grid.wavelength_nm
    if efficiency is None:
        eta = np.ones_like(wavelength)
        eta_sigma: FloatArray | None = None
    else:
        eta = efficiency.at(wavelength)
        eta_sigma = efficiency.sigma_at(wavelength)
        eta_peak = float(eta.max())
        eta = eta / eta_peak
        eta_sigma = None if eta_sigma is None else eta_sigma / eta_peak
    residuals = {
        lamp.observation.name: {
            "profile": difference,
            "profile_normalised": difference * lamp.weights,
            "direct": None,
        }
        for lamp, difference in zip(solve, solution.residuals, strict=True)
    }
    timings["total_s"] = time.perf_counter() - started
    return EstimateResult(
        method=KNOWN_GRATING_METHOD,
        wavelength_nm=wavelength,
        sensitivity=sensitivity / peak,
        sensitivity_sigma=np.sqrt(np.clip(variance, 0.0, None)) / peak,
        grating_efficiency=eta,
        grating_efficiency_sigma=eta_sigma,
        mapping=used_mapping,
        residuals=residuals,
        diagnostics={
            "basis": basis.to_dict(),
            "grating": "flat (assumed)"
            if efficiency is None
            else {"source": efficiency.source, "provenance": dict(efficiency.provenance)},
            "solve_lamps": [lamp.observation.name for lamp in solve],
            "lamp_scales": solution.scales.tolist(),
            "reduced_chi2": reduced_chi2,
            "sensitivity_scale": peak,
            "timings": timings,
        },
    )
