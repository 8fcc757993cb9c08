"""What the closed-form joint solves share: checks, the mapping, the lamps' preparation, the result.

Makabe et al. (2025) solve for the camera sensitivity and the grating efficiency in closed form once
the pixel→wavelength mapping is known. Two solves follow that recipe here: the paper's
(:mod:`calib.methods.makabe2025`) and the project's prior solve (:mod:`calib.methods.prior_solve`).
Both check the lamps the same way, find the mapping the same way (:func:`calib.wavelength.find_mapping`:
the profile-fit search, or the paper's ICP), prepare each lamp matched to the spectrometer's
resolution, and report residuals, timings and diagnostics in one shape (:func:`joint_result`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import WavelengthGrid
from calib.methods.solve_scope import reuse
from calib.model.bases import CameraBasis, CameraPrior, FourierConvention, fourier_basis
from calib.model.forward import WavelengthMapping, apply_blur, hat_matrix
from calib.model.linear_model import LampSystem, prepare_lamp
from calib.model.resolution import camera_kernel, match_spectrometer, matched_resolution_nm
from calib.wavelength import find_mapping, lamps_named

SearchMethod = Literal["search", "icp"]
#: How the closed-form solves find the mapping (strategies of :func:`calib.wavelength.find_mapping`).
SEARCH_METHODS: tuple[SearchMethod, ...] = ("search", "icp")


@dataclass(frozen=True)
class GratingMethodOptions:
    """What every grating method's options hold: how the lamps are read and the mapping found.

    Attributes
    ----------
    prior_shrinkage
        Shrinkage of the camera prior's covariance (``None``: Ledoit–Wolf,
        :meth:`calib.model.bases.CameraBasis.prior`); the prior steers the mapping search, and the
        solves that lean on it.
    refine_given_mapping
        Treat a given mapping as a start for the search rather than the answer.
    slit_width_px, psf_sigma_px
        Blur of the profile along dispersion (when the observations carry no line spread).
    """

    prior_shrinkage: float | None = None
    refine_given_mapping: bool = False
    slit_width_px: float = 0.0
    psf_sigma_px: float = 0.0

    def __post_init__(self) -> None:
        if self.prior_shrinkage is not None and not 0.0 <= self.prior_shrinkage <= 1.0:
            raise InputError(
                f"must be in [0, 1], got {self.prior_shrinkage}", source="prior_shrinkage"
            )
        if self.slit_width_px < 0 or self.psf_sigma_px < 0:
            raise InputError("slit width and PSF sigma must be >= 0 px", source="blur")


@dataclass(frozen=True)
class ClosedFormOptions(GratingMethodOptions):
    """Options every closed-form solve takes (checked on construction), besides
    :class:`GratingMethodOptions`'.

    Attributes
    ----------
    mapping_method
        ``"search"`` (fit the whole profile under the camera prior) or ``"icp"`` (the paper's
        point-to-plane ICP from a flat start, for reproduction).
    efficiency_terms, fourier_convention
        The Fourier basis of ``η⁻¹`` (Supp. E).
    solve_lamps
        Names of the lamps that enter the solve. ``None``: every non-fluorescent lamp with a direct
        measurement (the paper uses the LED only), else every lamp with one.
    """

    mapping_method: SearchMethod = "search"
    efficiency_terms: int = 7
    fourier_convention: FourierConvention = "paired"
    solve_lamps: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.mapping_method not in SEARCH_METHODS:
            raise InputError(
                f"unknown mapping method {self.mapping_method!r}; use 'search' or 'icp'",
                source="mapping_method",
            )
        if self.efficiency_terms < 1:
            raise InputError(
                f"need at least one term, got {self.efficiency_terms}", source="efficiency_terms"
            )
        if self.solve_lamps is not None:
            # A list is welcome (stored as a tuple); a single name would be read letter by letter.
            names: object = self.solve_lamps
            if isinstance(names, str):
                raise InputError("give a sequence of lamp names", source="solve_lamps")
            object.__setattr__(self, "solve_lamps", tuple(self.solve_lamps))


def check_lamps(
    observations: Sequence[LampObservation], basis: CameraBasis, grid: WavelengthGrid
) -> None:
    """Lamps given, names unique, the basis on the working grid; else an :class:`InputError`."""
    if not observations:
        raise InputError("no lamp observations given", source="observations")
    if basis.grid != grid:
        raise InputError(
            f"the camera basis is on grid {basis.grid}, the estimate on {grid}", source="basis"
        )
    names = [obs.name for obs in observations]
    if len(set(names)) != len(names):
        raise InputError(f"lamp names must be unique, got {names}", source="observations")


def choose_solve_lamps(
    observations: Sequence[LampObservation], solve_lamps: Sequence[str] | None
) -> list[LampObservation]:
    """The lamps named, else every non-fluorescent lamp with a direct measurement, else any with one."""
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

    The profile and the spectrum are brought to a common resolution (the profile blurred in
    wavelength through the mapping), then the lamp is prepared with the camera's line spread ``kernel``.
    """
    spacing = float(np.median(np.diff(observation.pixel)))
    dispersion = float(np.median(np.abs(_dispersion(mapping, observation.pixel))))
    matched = match_spectrometer(
        observation, dispersion * spacing, wavelength_nm=mapping.wavelength_nm(observation.pixel)
    )
    slit_fwhm_nm = None if matched is observation else matched_resolution_nm(matched)
    return prepare_lamp(matched, grid, kernel=kernel, slit_fwhm_nm=slit_fwhm_nm)


@dataclass(frozen=True, eq=False)
class JointSetup:
    """What a closed-form solve starts from, once the lamps are checked and the mapping is known.

    Attributes
    ----------
    solve_lamps
        The lamps that enter the solve (:func:`choose_solve_lamps`).
    prior
        The camera prior (shrinkage as asked).
    efficiency_basis
        ``B_η`` ``(f, b_η)``.
    kernel
        The camera's line spread in profile samples, or ``None``.
    mapping
        The mapping used (given, or found).
    mapping_given
        Whether ``mapping`` was used as given.
    timings
        ``prepare_s`` and ``mapping_s``.
    started
        :func:`time.perf_counter` at the start.
    """

    solve_lamps: tuple[LampObservation, ...]
    prior: CameraPrior
    efficiency_basis: FloatArray
    kernel: FloatArray | None
    mapping: QuadraticMapping | GratingGeometry
    mapping_given: bool
    timings: dict[str, float] = field(default_factory=dict)
    started: float = 0.0

    def prepared(self, observation: LampObservation, grid: WavelengthGrid) -> LampSystem:
        """``observation`` prepared on the setup's mapping (:func:`prepare_matched_lamp`)."""
        return prepare_matched_lamp(observation, self.mapping, grid, self.kernel)


def _read_only(array: FloatArray) -> FloatArray:
    """``array``, made read-only (a result shared by a solve scope's callers)."""
    array.flags.writeable = False
    return array


def joint_setup(
    observations: Sequence[LampObservation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid,
    mapping: QuadraticMapping | GratingGeometry | None,
    mapping_lamp: str | None,
    options: ClosedFormOptions,
) -> JointSetup:
    """Check the lamps, build the prior and the efficiency basis, and find the mapping if needed.

    The mapping is found with the lamp named ``mapping_lamp``, else with every lamp jointly (one
    geometry: one mapping; fluorescent lines, if any, start the search). Inside a
    :func:`calib.methods.solve_scope.solve_scope` the prior and the efficiency basis are built once
    for the same basis, grid and options (the σ budget's re-solves take the estimate's).
    """
    started = time.perf_counter()
    check_lamps(observations, basis, grid)
    chosen = choose_solve_lamps(observations, options.solve_lamps)
    # The prior and the η basis depend on the basis and the options only: inside a solve scope
    # the σ budget's re-solves read the estimate's instead of building them again.
    prior = reuse(
        "camera prior",
        (basis, options.prior_shrinkage),
        lambda: basis.prior(options.prior_shrinkage),
    )
    efficiency_basis = reuse(
        "efficiency basis",
        (grid, options.efficiency_terms, options.fourier_convention),
        lambda: _read_only(
            fourier_basis(grid, options.efficiency_terms, convention=options.fourier_convention)
        ),
    )
    kernel = camera_kernel(observations, options.slit_width_px, options.psf_sigma_px)
    timings = {"prepare_s": time.perf_counter() - started}
    step = time.perf_counter()
    given = mapping is not None and not options.refine_given_mapping
    if mapping is not None and given:
        used: QuadraticMapping | GratingGeometry = mapping
    else:
        lamps = (
            list(observations) if mapping_lamp is None else lamps_named(observations, mapping_lamp)
        )
        used = find_mapping(
            lamps,
            camera=prior,
            grid=grid,
            method=options.mapping_method,
            start=mapping,
            kernel=None if options.mapping_method == "icp" else kernel,
        )
    timings["mapping_s"] = time.perf_counter() - step
    return JointSetup(tuple(chosen), prior, efficiency_basis, kernel, used, given, timings, started)


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


def normalised_efficiency_sigma(inverse: FloatArray, covariance: FloatArray) -> FloatArray:
    """σ ``(f,)`` of ``η / max η`` from the covariance ``(f, f)`` of ``η⁻¹`` (first order).

    With ``p`` the node of the maximum, ``n_i = η⁻¹_p / η⁻¹_i`` and ``δ = dη⁻¹ / η⁻¹``:
    ``dn_i = n_i (δ_p − δ_i)``. The common scale of ``η`` cancels (only its shape is delivered),
    so σ is 0 at the maximum and grows with the distance in shape from it. Nodes where ``η⁻¹ ≤ 0``
    (no efficiency) get NaN.

    Examples
    --------
    >>> inverse = np.array([2.0, 1.0, 4.0])
    >>> normalised_efficiency_sigma(inverse, np.diag([0.0, 0.01, 0.0]))  # the peak's own error
    array([0.05 , 0.   , 0.025])
    >>> normalised_efficiency_sigma(inverse, 0.01 * np.outer(inverse, inverse))  # a common scale
    array([0., 0., 0.])
    """
    inverse = np.asarray(inverse, dtype=np.float64)
    covariance = np.asarray(covariance, dtype=np.float64)
    positive = inverse > 0
    if not np.any(positive):
        return np.full(inverse.shape, np.nan)
    peak = int(np.argmin(np.where(positive, inverse, np.inf)))
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.where(positive, 1.0 / inverse, np.nan)
        normalised = inverse[peak] * relative
        variance = (
            covariance[peak, peak] / inverse[peak] ** 2
            + np.diag(covariance) * relative**2
            - 2.0 * covariance[peak] * relative / inverse[peak]
        )
    return np.asarray(normalised * np.sqrt(np.clip(variance, 0.0, None)), dtype=np.float64)


def joint_result(
    method: str,
    setup: JointSetup,
    systems: Sequence[LampSystem],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid,
    options: ClosedFormOptions,
    sensitivity: FloatArray,
    inverse_efficiency: FloatArray,
    sensitivity_sigma: FloatArray | None,
    info: dict[str, Any],
    diagnostics: dict[str, Any],
    inverse_efficiency_covariance: FloatArray | None = None,
) -> EstimateResult:
    """The solve's :class:`~calib.core.result.EstimateResult`: curves normalised to a maximum of 1,
    each solve lamp's residuals, the reduced χ², timings and ``diagnostics`` (the solve's own).

    ``info["lamp_scales"]`` holds each system's brightness relative to the first. With
    ``inverse_efficiency_covariance`` ``(f, f)`` (of ``η⁻¹`` on the grid) the result states η's σ
    (:func:`normalised_efficiency_sigma`).
    """
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
        scale = info["lamp_scales"][index]
        model = _profile_model(system, setup.mapping, sensitivity, inverse_efficiency, scale)
        difference = system.profile - model
        residuals[system.observation.name] = {
            "profile": difference,
            "profile_normalised": difference / system.profile_sigma,
            "direct": None
            if system.observation.direct_rgb is None
            else system.observation.direct_rgb
            - scale * (system.operators.direct_row @ sensitivity),
        }
        chi2 += float(np.sum((difference / system.profile_sigma) ** 2))
        count += difference.size
    timings = {**setup.timings, "total_s": time.perf_counter() - setup.started}
    return EstimateResult(
        method=method,
        wavelength_nm=grid.wavelength_nm,
        sensitivity=sensitivity / peak,
        sensitivity_sigma=None if sensitivity_sigma is None else sensitivity_sigma / peak,
        grating_efficiency=efficiency / efficiency_peak
        if np.isfinite(efficiency_peak)
        else efficiency,
        grating_efficiency_sigma=None
        if inverse_efficiency_covariance is None
        else normalised_efficiency_sigma(inverse_efficiency, inverse_efficiency_covariance),
        mapping=setup.mapping,
        residuals=residuals,
        diagnostics={
            "basis": basis.to_dict(),
            **diagnostics,
            "mapping_method": "given" if setup.mapping_given else options.mapping_method,
            "efficiency_basis": {
                "terms": options.efficiency_terms,
                "convention": options.fourier_convention,
            },
            "solve_lamps": [s.observation.name for s in systems],
            "negative_efficiency_nodes": int(np.sum(inverse_efficiency <= 0)),
            "sensitivity_scale": peak,
            "reduced_chi2": chi2 / max(count, 1),
            "timings": timings,
            **{key: value for key, value in info.items() if key != "passes"},
        },
    )
