"""Diffraction profiles + colour patches, fitted by Adam, with ensemble uncertainty (Toivonen & Klami 2020).

Unknowns: the sensitivity ``R_c(λ_i)`` at every grid node (no basis, no smoothness prior) and a
quadratic grating efficiency ``η(λ) = a₀ + a₁x + a₂x²`` in ``x = (λ − λ_first)/(λ_last − λ_first)``
(η is evaluated as ``max(·, 0)``). Data (§3.4, normalised as in the paper):

* *monochromatic data* ``v_jc(λ)``: lamp ``j``'s first-order profile mapped to wavelength and divided
  by its green value at 550 nm, modelled as ``R_c(λ) η(λ) v^S_j(λ)`` with the lamp spectrum ``v^S_j``
  divided by its value at 550 nm;
* *patch data* ``p_Jc``: colour patches of known spectra ``P_J`` (transmissive filters in front of a
  lamp, §3.3), divided by the largest value of all patches and channels, modelled as
  ``Σ_λ R_c(λ) P_J(λ)``. As in Makabe et al. (2025) Supp. G, a lamp's direct (0th-order) light can
  serve as a patch whose spectrum is the lamp's.

Loss (§3.5): ``L = α L_mon + β L_patch + γ Σ_λ Γ_λ`` with the mean squared residuals ``L_mon``
(over lamps, channels, wavelengths) and ``L_patch`` (over patches, channels), and the lower-bound
regulariser ``Γ_λ = |η_λ − t·max η|`` where ``η_λ ≤ t·max η`` (else 0), ``α = β = 1``, ``γ = 0.1``,
``t = 0.2``. Minimised with Adam (written out here in numpy); after every epoch negative ``R`` are set
to zero. Each epoch is one full-batch step (the data are a few hundred numbers). Initialisation:
``R ~ U(0, 0.1)``, ``a₀ = 1``, ``a₁, a₂ ~ U(−1, 0)``.

Uncertainty (§3.6): an ensemble of ``N`` runs from random starts, all advanced together as one
vectorised array; the result is the ensemble mean and ``sensitivity_sigma`` its standard deviation
(the ensemble part of the paper's procedure; the per-member variational widths are not modelled).

The patch spectra's overall scale is a free gauge (it trades against η's scale): they are scaled so
that the grating-only estimate ``v/v^S`` (η ≡ 1) predicts the brightest patch value as 1, so the
optimum has η of order 1, where the paper's initialisation starts.

Seed 000's finding reproduced by :mod:`calib.evaluation.compare` and the tests: with one lamp and its direct light
as the only patch the fit is unstable (the ensemble scatters, the mean is far off); with more than ten
Gaussian transmissive patches it is stable (Makabe et al. 2025, Supp. G, Fig. S6).

References
----------
Toivonen, M. E., Klami, A. (2020). Practical Camera Sensor Spectral Response and Uncertainty
Estimation. J. Imaging 6(8), 79, §3.4–3.6.
Makabe, L. et al. (2025). Spectral Sensitivity Estimation with an Uncalibrated Diffraction Grating,
Supp. G.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import ChartObservation, LampObservation, Observation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.baselines.inputs import normalised_curves, split_observations
from calib.model.bases import CameraBasis
from calib.model.charts import stimulus_rows
from calib.model.forward import hat_matrix, lamp_operators, pixel_edges
from calib.model.resolution import camera_kernel
from calib.wavelength import find_mapping, lamps_named

#: Wavelength at which monochromatic data and lamp spectra are normalised (§3.4).
NORMALISATION_NM = 550.0


@dataclass(frozen=True)
class ToivonenSettings:
    """Hyper-parameters of the fit (defaults from §3.5 where the paper gives them).

    Attributes
    ----------
    monochromatic_weight, patch_weight, regulariser_weight
        ``α``, ``β``, ``γ`` (1, 1, 0.1).
    lower_bound_fraction
        ``t`` of the regulariser (0.2).
    learning_rate
        Adam step size (not given in the paper).
    epochs
        Full-batch Adam steps (not given in the paper).
    ensemble_size
        Runs from independent random starts (the paper trains 2500).
    adam_beta1, adam_beta2, adam_epsilon
        Adam's moment decay rates and denominator guard (Kingma & Ba defaults).
    """

    monochromatic_weight: float = 1.0
    patch_weight: float = 1.0
    regulariser_weight: float = 0.1
    lower_bound_fraction: float = 0.2
    learning_rate: float = 0.02
    epochs: int = 5000
    ensemble_size: int = 16
    adam_beta1: float = 0.9
    adam_beta2: float = 0.999
    adam_epsilon: float = 1e-8

    def __post_init__(self) -> None:
        checks = {
            "monochromatic_weight": self.monochromatic_weight >= 0,
            "patch_weight": self.patch_weight >= 0,
            "regulariser_weight": self.regulariser_weight >= 0,
            "lower_bound_fraction": 0 <= self.lower_bound_fraction < 1,
            "learning_rate": self.learning_rate > 0,
            "epochs": self.epochs >= 1,
            "ensemble_size": self.ensemble_size >= 1,
            "adam_beta1": 0 <= self.adam_beta1 < 1,
            "adam_beta2": 0 <= self.adam_beta2 < 1,
            "adam_epsilon": self.adam_epsilon > 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            values = {name: getattr(self, name) for name in bad}
            raise InputError(f"invalid Toivonen settings {values}", source="toivonen2020")


@dataclass(frozen=True, eq=False)
class ToivonenProblem:
    """The normalised data of one fit.

    Attributes
    ----------
    grid
        Working grid (``f`` nodes).
    position
        Shape ``(f,)``: ``x`` in [0, 1] of each node (the efficiency polynomial's variable).
    monochromatic
        Shape ``(n_lamps, f, 3)``: ``v_jc(λ)``, green at 550 nm = 1.
    monochromatic_mask
        Shape ``(n_lamps, f, 3)``: 1 where the profile covers the node, else 0.
    lamp_spectra
        Shape ``(n_lamps, f)``: ``v^S_j(λ)``, 1 at 550 nm.
    patch_rows
        Shape ``(n_patches, f)``: ``P_J`` (scaled, see the module docstring).
    patch_rgb
        Shape ``(n_patches, 3)``: ``p_Jc``, maximum 1.
    lamp_names, patch_names
        Labels.
    """

    grid: WavelengthGrid
    position: FloatArray
    monochromatic: FloatArray
    monochromatic_mask: FloatArray
    lamp_spectra: FloatArray
    patch_rows: FloatArray
    patch_rgb: FloatArray
    lamp_names: tuple[str, ...]
    patch_names: tuple[str, ...]

    @property
    def n_lamps(self) -> int:
        return int(self.monochromatic.shape[0])

    @cached_property
    def efficiency_powers(self) -> FloatArray:
        """Shape ``(f, 3)``: ``1, x, x²`` at each node (η = powers @ a)."""
        x = self.position
        return np.stack([np.ones_like(x), x, x**2], axis=1)

    @property
    def n_patches(self) -> int:
        return int(self.patch_rows.shape[0])


@dataclass(frozen=True, eq=False)
class EnsembleFit:
    """The ensemble after training.

    Attributes
    ----------
    sensitivity
        Shape ``(n_members, f, 3)``: ``R`` of every member (the problem's normalisation).
    efficiency_coefficients
        Shape ``(n_members, 3)``: ``a₀, a₁, a₂``.
    efficiency
        Shape ``(n_members, f)``: ``max(a₀ + a₁x + a₂x², 0)``.
    losses
        Shape ``(n_members, 4)``: final ``L, L_mon, L_patch, ΣΓ``.
    """

    sensitivity: FloatArray
    efficiency_coefficients: FloatArray
    efficiency: FloatArray
    losses: FloatArray


# ---------------------------------------------------------------------------------- data


def _node_index(grid: WavelengthGrid, wavelength_nm: float) -> int:
    """The grid node nearest ``wavelength_nm`` (550 nm is a node of the usual 10 nm grids)."""
    return int(np.argmin(np.abs(grid.wavelength_nm - wavelength_nm)))


def monochromatic_profile(
    observation: LampObservation,
    mapping: QuadraticMapping | GratingGeometry | None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> tuple[FloatArray, FloatArray]:
    """A first-order profile as spectral density on the grid: ``e·η·s`` per nm at each node.

    Each pixel's value is divided by the wavelength interval it spans (``|g(p+½) − g(p−½)|``) and
    the pixels are averaged with the grid's hat weights at their centre wavelengths (the same
    projection :meth:`calib.core.spectra.Spectrum.resample` ``"integrate"`` applies to lamp spectra).

    Parameters
    ----------
    observation
        The lamp's profile (pixel axis, or ``profile_wavelength_nm`` already mapped).
    mapping
        Pixel→wavelength mapping; unused when the profile is already mapped.
    grid
        Working grid.

    Returns
    -------
    tuple of numpy.ndarray
        Density ``(f, 3)`` and coverage ``(f,)`` (the summed hat weight per node; 0 = no pixel).
    """
    if observation.profile_wavelength_nm is not None:
        centres = np.asarray(observation.profile_wavelength_nm)
        # Pixel edges are midway between centres, so their wavelengths are too (half a step out
        # at both ends).
        edges = np.concatenate(
            [
                [centres[0] - 0.5 * (centres[1] - centres[0])],
                0.5 * (centres[1:] + centres[:-1]),
                [centres[-1] + 0.5 * (centres[-1] - centres[-2])],
            ]
        )
    elif mapping is not None:
        centres = mapping.wavelength_nm(observation.pixel)
        edges = mapping.wavelength_nm(pixel_edges(observation.pixel))
    else:
        raise InputError(
            "toivonen2020 needs the profile's pixel→wavelength mapping (Toivonen & Klami use two "
            "laser lines): pass mapping=..., or a camera basis to estimate_toivonen2020, which "
            "finds it as the grating methods do",
            source=f"lamp {observation.name!r}",
        )
    width_nm = np.abs(np.diff(edges))
    density = observation.profile / np.maximum(width_nm, 1e-12)[:, None]
    weights = hat_matrix(grid, centres)
    coverage = weights.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        values = (weights.T @ density) / coverage[:, None]
    return np.where(coverage[:, None] > 0, values, 0.0), coverage


def build_problem(
    lamps: Sequence[LampObservation],
    charts: Sequence[ChartObservation],
    mapping: QuadraticMapping | GratingGeometry | None,
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    patch_lamps: Sequence[LampObservation] = (),
) -> ToivonenProblem:
    """Normalise the observations into a :class:`ToivonenProblem` (see the module docstring).

    Parameters
    ----------
    lamps
        Lamps seen through the grating whose profiles are the monochromatic data.
    charts
        Colour-patch observations (any kind; each patch's radiance is its ``P_J``).
    mapping
        The profiles' pixel→wavelength mapping.
    grid
        Working grid (the data are normalised at its node nearest 550 nm).
    patch_lamps
        Lamps whose direct (0th-order) RGB is a patch with the lamp's spectrum.
    """
    reference = _node_index(grid, NORMALISATION_NM)
    monochromatic = np.zeros((len(lamps), grid.size, 3))
    mask = np.zeros_like(monochromatic)
    spectra = np.zeros((len(lamps), grid.size))
    for index, lamp in enumerate(lamps):
        values, coverage = monochromatic_profile(lamp, mapping, grid)
        if coverage[reference] <= 0 or values[reference, 1] <= 0:
            raise InputError(
                f"the profile has no green signal at {NORMALISATION_NM:g} nm to normalise by",
                source=f"lamp {lamp.name!r}",
            )
        if np.count_nonzero(coverage > 0) < grid.size // 2:
            raise InputError(
                f"the profile covers only {np.count_nonzero(coverage > 0)} of {grid.size} grid "
                "wavelengths; check the mapping",
                source=f"lamp {lamp.name!r}",
            )
        monochromatic[index] = values / values[reference, 1]
        mask[index] = (coverage > 0)[:, None]
        lamp_on_grid = lamp.spectrum.resample(grid, "integrate").values
        if lamp_on_grid[reference] <= 0:
            raise InputError(
                f"the lamp spectrum is zero at {NORMALISATION_NM:g} nm",
                source=f"lamp {lamp.name!r}",
            )
        spectra[index] = lamp_on_grid / lamp_on_grid[reference]
    rows: list[FloatArray] = []
    rgb: list[FloatArray] = []
    names: list[str] = []
    for lamp in patch_lamps:
        if lamp.direct_rgb is None:
            raise InputError(
                "has no direct (0th-order) RGB to use as a patch", source=f"lamp {lamp.name!r}"
            )
        rows.append(lamp_operators(lamp.spectrum, grid).direct_row[None, :])
        rgb.append(lamp.direct_rgb[None, :])
        names.append(f"{lamp.name} (direct)")
    for chart in charts:
        rows.append(stimulus_rows(chart, grid))
        rgb.append(chart.patch_rgb)
        names.extend(f"{chart.name}: {patch}" for patch in chart.patch_names)
    patch_rows = np.vstack(rows) if rows else np.zeros((0, grid.size))
    patch_rgb = np.vstack(rgb) if rgb else np.zeros((0, 3))
    if patch_rgb.size:
        brightest = float(np.max(patch_rgb))
        if brightest <= 0:
            raise InputError("every patch value is <= 0", source="patches")
        patch_rgb = patch_rgb / brightest
        if lamps:
            lit = spectra[0] > 1e-6  # nodes where the lamp gives light (an LED has none at 400 nm)
            grating_only = np.where(
                lit[:, None], monochromatic[0] / np.where(lit, spectra[0], 1.0)[:, None], 0.0
            )
            predicted = float(np.max(patch_rows @ grating_only))
            if predicted > 0:
                patch_rows = patch_rows / predicted
    if not lamps and not patch_rgb.size:
        raise InputError("toivonen2020 got no lamp profile and no patch", source="observations")
    span = grid.stop_nm - grid.start_nm
    return ToivonenProblem(
        grid=grid,
        position=(grid.wavelength_nm - grid.start_nm) / span,
        monochromatic=monochromatic,
        monochromatic_mask=mask,
        lamp_spectra=spectra,
        patch_rows=patch_rows,
        patch_rgb=patch_rgb,
        lamp_names=tuple(lamp.name for lamp in lamps),
        patch_names=tuple(names),
    )


# ------------------------------------------------------------------------------ the fit


def _loss_and_gradients(
    problem: ToivonenProblem,
    settings: ToivonenSettings,
    sensitivity: FloatArray,
    coefficients: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Loss terms ``(N, 4)`` and the gradients w.r.t. ``R`` ``(N, f, 3)`` and ``a`` ``(N, 3)``."""
    powers = problem.efficiency_powers  # (f, 3)
    polynomial = coefficients @ powers.T  # (N, f)
    efficiency = np.maximum(polynomial, 0.0)
    n_members = sensitivity.shape[0]
    grad_sensitivity = np.zeros_like(sensitivity)
    grad_efficiency = np.zeros_like(efficiency)
    loss_mon = np.zeros(n_members)
    loss_patch = np.zeros(n_members)
    if problem.n_lamps:
        count = float(np.sum(problem.monochromatic_mask))
        carrier = efficiency[:, None, :] * problem.lamp_spectra[None, :, :]  # (N, L, f)
        model = sensitivity[:, None, :, :] * carrier[..., None]  # (N, L, f, 3)
        residual = (problem.monochromatic[None] - model) * problem.monochromatic_mask[None]
        loss_mon = np.sum(residual**2, axis=(1, 2, 3)) / count
        scale = -2.0 * settings.monochromatic_weight / count
        # (Broadcast products and sums rather than einsum: these arrays are tiny and einsum's
        # per-call overhead dominated the fit's run time.)
        grad_sensitivity += scale * np.sum(residual * carrier[..., None], axis=1)
        grad_efficiency += scale * np.sum(
            residual * sensitivity[:, None] * problem.lamp_spectra[None, :, :, None], axis=(1, 3)
        )
    if problem.n_patches:
        count = 3.0 * problem.n_patches
        predicted = problem.patch_rows @ sensitivity  # (N, P, 3)
        residual_patch = problem.patch_rgb[None] - predicted
        loss_patch = np.sum(residual_patch**2, axis=(1, 2)) / count
        grad_sensitivity += (-2.0 * settings.patch_weight / count) * (
            problem.patch_rows.T @ residual_patch
        )
    bound = settings.lower_bound_fraction * efficiency.max(axis=1)  # (N,)
    below = efficiency <= bound[:, None]
    regulariser = np.sum(np.where(below, bound[:, None] - efficiency, 0.0), axis=1)
    grad_regulariser = -below.astype(np.float64)
    peak = np.argmax(efficiency, axis=1)
    grad_regulariser[np.arange(n_members), peak] += settings.lower_bound_fraction * below.sum(
        axis=1
    )
    grad_efficiency += settings.regulariser_weight * grad_regulariser
    grad_coefficients = (grad_efficiency * (polynomial > 0)) @ powers
    total = (
        settings.monochromatic_weight * loss_mon
        + settings.patch_weight * loss_patch
        + settings.regulariser_weight * regulariser
    )
    losses = np.stack([total, loss_mon, loss_patch, regulariser], axis=1)
    return losses, grad_sensitivity, grad_coefficients


def fit_ensemble(
    problem: ToivonenProblem, settings: ToivonenSettings, rng: np.random.Generator
) -> EnsembleFit:
    """Train ``settings.ensemble_size`` members from random starts with Adam (vectorised).

    Parameters
    ----------
    problem
        The normalised data.
    settings
        Hyper-parameters.
    rng
        Seeded generator for the initialisations.

    Returns
    -------
    EnsembleFit
    """
    n_members, f = settings.ensemble_size, problem.grid.size
    sensitivity = rng.uniform(0.0, 0.1, size=(n_members, f, 3))
    coefficients = np.column_stack(
        [np.ones(n_members), rng.uniform(-1.0, 0.0, size=(n_members, 2))]
    )
    parameters = [sensitivity, coefficients]
    first_moments = [np.zeros_like(p) for p in parameters]
    second_moments = [np.zeros_like(p) for p in parameters]
    beta1, beta2 = settings.adam_beta1, settings.adam_beta2
    for epoch in range(1, settings.epochs + 1):
        _, *gradients = _loss_and_gradients(problem, settings, sensitivity, coefficients)
        correction1 = 1.0 - beta1**epoch
        correction2 = 1.0 - beta2**epoch
        for parameter, gradient, m, v in zip(
            parameters, gradients, first_moments, second_moments, strict=True
        ):
            m *= beta1
            m += (1.0 - beta1) * gradient
            v *= beta2
            v += (1.0 - beta2) * gradient**2
            parameter -= (
                settings.learning_rate
                * (m / correction1)
                / (np.sqrt(v / correction2) + settings.adam_epsilon)
            )
        np.maximum(sensitivity, 0.0, out=sensitivity)  # positivity after each epoch (§3.5)
    losses, *_ = _loss_and_gradients(problem, settings, sensitivity, coefficients)
    efficiency = np.maximum(coefficients @ problem.efficiency_powers.T, 0.0)
    return EnsembleFit(sensitivity, coefficients, efficiency, losses)


# ------------------------------------------------------------------------------ estimate


def _mapping_from_lamps(
    lamps: Sequence[LampObservation],
    basis: CameraBasis | None,
    grid: WavelengthGrid,
    mapping_lamp: str | None,
) -> QuadraticMapping:
    """The mapping as Makabe et al. (2025) find it (Supp. G runs Toivonen's fit on their mapping):
    every lamp jointly (or the one named), fluorescent lines first, under the camera prior."""
    if basis is None:
        raise InputError(
            "toivonen2020 needs the profiles' pixel→wavelength mapping: pass mapping=..., or a "
            "camera basis (basis=...) to find it as the grating methods do",
            source="mapping",
        )
    if basis.grid != grid:
        raise InputError(
            f"the camera basis is on grid {basis.grid}, the estimate on {grid}", source="basis"
        )
    searched = list(lamps) if mapping_lamp is None else lamps_named(lamps, mapping_lamp)
    return find_mapping(searched, camera=basis.prior(), grid=grid, kernel=camera_kernel(lamps))


@one_blas_thread
def estimate_toivonen2020(
    observations: Sequence[Observation],
    *,
    basis: CameraBasis | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    settings: ToivonenSettings = ToivonenSettings(),
    seed: int | np.random.Generator = 0,
    direct_as_patch: bool = True,
    lamps_for_profiles: Sequence[str] | None = None,
) -> EstimateResult:
    """Estimate sensitivity and grating efficiency as Toivonen & Klami (2020) do.

    Parameters
    ----------
    observations
        Lamp observations through the grating, all in one geometry, and colour-patch observations
        (transmissive filters, a ColorChecker …).
    basis
        Camera basis on ``grid``, whose prior finds the mapping when it is not given (as Makabe et
        al. 2025, Supp. G, run this method); unused otherwise.
    grid
        Working grid (the data are normalised at its node nearest 550 nm).
    mapping
        The profiles' pixel→wavelength mapping (not needed for profiles already mapped).
    mapping_lamp
        Find the mapping with this lamp only (default: every lamp jointly).
    settings
        Hyper-parameters and ensemble size.
    seed
        Seed (or generator) of the random starts.
    direct_as_patch
        Each lamp's direct RGB (when measured) is one more patch with the lamp's spectrum (the
        single patch of Makabe et al.'s setup).
    lamps_for_profiles
        Lamps whose profiles enter ``L_mon``; default every non-fluorescent lamp (a line spectrum
        binned to the grid does not follow ``R·η·v^S``), or all lamps if all are fluorescent.

    Returns
    -------
    EstimateResult
        Ensemble mean (max 1) with ``sensitivity_sigma`` the ensemble standard deviation, the mean
        efficiency and its σ, diagnostics (losses per member, ensemble spread, timings).
    """
    started = time.perf_counter()
    groups = split_observations(
        observations, "toivonen2020", {"lamps": LampObservation, "charts": ChartObservation}
    )
    lamps: list[LampObservation] = groups["lamps"]
    charts: list[ChartObservation] = groups["charts"]
    mapping_source = "given" if mapping is not None else "profile wavelengths"
    if mapping is None and any(lamp.profile_wavelength_nm is None for lamp in lamps):
        mapping = _mapping_from_lamps(lamps, basis, grid, mapping_lamp)
        mapping_source = "found (calib.wavelength.find_mapping)"
    if lamps_for_profiles is None:
        profiled = [lamp for lamp in lamps if lamp.kind != "fluorescent"] or list(lamps)
    else:
        by_name = {lamp.name: lamp for lamp in lamps}
        missing = [name for name in lamps_for_profiles if name not in by_name]
        if missing:
            raise InputError(
                f"unknown lamps {missing}; lamps are {list(by_name)}", source="lamps_for_profiles"
            )
        profiled = [by_name[name] for name in lamps_for_profiles]
    patch_lamps = [lamp for lamp in lamps if lamp.direct_rgb is not None] if direct_as_patch else []
    problem = build_problem(profiled, charts, mapping, grid, patch_lamps=patch_lamps)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    fit = fit_ensemble(problem, settings, rng)
    mean = fit.sensitivity.mean(axis=0)
    spread = (
        fit.sensitivity.std(axis=0, ddof=1) if settings.ensemble_size > 1 else np.zeros_like(mean)
    )
    curves, curves_sigma, peak = normalised_curves(mean, spread, "toivonen2020")
    efficiency_mean = fit.efficiency.mean(axis=0)
    efficiency_peak = float(np.max(efficiency_mean))
    efficiency_sigma = fit.efficiency.std(axis=0, ddof=1) if settings.ensemble_size > 1 else None
    member_peaks = np.max(fit.sensitivity, axis=(1, 2))
    member_curves = fit.sensitivity / np.where(member_peaks > 0, member_peaks, 1.0)[:, None, None]
    diagnostics = {
        "settings": {
            name: getattr(settings, name) for name in ToivonenSettings.__dataclass_fields__
        },
        "n_lamps_profiled": problem.n_lamps,
        "lamps_profiled": list(problem.lamp_names),
        "n_patches": problem.n_patches,
        "patches": list(problem.patch_names),
        "final_losses": {
            key: fit.losses[:, column].tolist()
            for column, key in enumerate(("total", "monochromatic", "patch", "regulariser"))
        },
        "ensemble_spread": float(
            np.sqrt(np.mean((member_curves - member_curves.mean(axis=0)) ** 2))
        ),
        "collapsed_members": int(np.sum(member_peaks <= 0)),
        "efficiency_coefficients": fit.efficiency_coefficients.tolist(),
        "sensitivity_scale": peak,
        "mapping_source": mapping_source,
        "timings": {"total_s": time.perf_counter() - started},
    }
    return EstimateResult(
        method="toivonen2020",
        wavelength_nm=grid.wavelength_nm,
        sensitivity=curves,
        sensitivity_sigma=curves_sigma,
        grating_efficiency=efficiency_mean / efficiency_peak if efficiency_peak > 0 else None,
        grating_efficiency_sigma=None
        if efficiency_sigma is None or efficiency_peak <= 0
        else efficiency_sigma / efficiency_peak,
        mapping=mapping,
        diagnostics=diagnostics,
    )
