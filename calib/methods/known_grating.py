"""Camera sensitivity through a grating whose efficiency is known: ``s_c = q̂_c / η``.

Without a direct (0th-order) measurement, or with the grating calibrated earlier (a grating file,
:mod:`calib.core.grating_file`; ``rig grating`` pools several cameras into one), the joint solve of
Makabe et al. (2025) is not needed: the profile is linear in the response ``q_c = η s_c``
(:func:`calib.methods.responses.fit_response`: the measured lamp at 1 nm over each pixel's
wavelength interval, weighted least squares, nothing divided by a spectrum), and with ``η`` known
the camera follows at every grid wavelength, not confined to a basis' span. One lamp suffices;
several are combined by SNR with their relative brightness fitted
(:func:`calib.methods.multilamp.combine_responses`). Where every lamp is dim the data's σ is large
and the camera prior (natural weight, :func:`calib.methods.multilamp.blend_with_prior`) fills in.

The grating's σ (if the file has one) is propagated node by node. Where a lamp's 2nd order falls
on the grid's red end, it is modelled when the grating file records a physical model (η₂ follows
from its parameters), else its pixels are left out (:func:`calib.methods.responses.fit_response`);
``diagnostics["second_order"]`` says which, per lamp. Without a grating (``None``) a
flat efficiency is assumed: the sensitivity then carries the grating's own spectral efficiency as
an error, which the caller must say (the offline pipeline warns).

The mapping is given (e.g. a profile already in wavelength) or found by the lamps jointly
(:func:`calib.methods.multilamp.find_shared_mapping`), starting from the rig geometry the grating
file stored (its groove spacing always; for the same camera and lens, the whole geometry).

This is the one solver for "estimate through a known grating": it replaced a basis-constrained
least-squares solve that was less accurate and whose σ covered the truth far less often than it
claimed (decision 0020).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.mapping import OPPOSITE_ORDER_TOLERANCE_DEG, GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult, QualityFlag
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.closed_form import GratingMethodOptions, check_lamps, prepare_matched_lamp
from calib.methods.grating_models import (
    DEFAULT_ASSUMED_FAMILIES,
    AssumedEfficiency,
    AssumedFamily,
    AssumedGrating,
    assumed_candidates,
    assumed_efficiency,
    candidate_log_evidence,
    check_assumed_families,
    recorded_physical_grating,
    second_order_ratio,
)
from calib.methods.multilamp import (
    SensitivitySolution,
    blend_with_prior,
    combine_responses,
    mapping_and_lamps,
    multilamp_result,
    pool_responses,
)
from calib.methods.responses import LampData, fit_response
from calib.model.bases import CameraBasis, CameraPrior
from calib.model.resolution import camera_kernel
from calib.wavelength import RigGeometry
from calib.wavelength.rig_prior import optics_from_observation

#: Registry name (and the result's ``method``).
KNOWN_GRATING_METHOD = "known-grating"
#: ``diagnostics["grating"]["source"]`` of an efficiency marginalised over the physical families.
ASSUMED_PHYSICAL_SOURCE = "assumed: physical grating families"
#: ``diagnostics["efficiency_model"]`` of a solve through an assumed-physical η: the σ budget
#: judges its coverage factor apart (:func:`calib.methods.uncertainty.efficiency_family`).
ASSUMED_EFFICIENCY_MODEL = "assumed"
#: ``diagnostics["efficiency_model"]`` of a solve through a grating file that states its η's σ
#: (a calibration's): the σ budget's factor key ``known-grating:file``, judged on the validation
#: split by ``bench/grating_physics.py --judge-factor``. A file without σ (a maker's curve) records
#: none: its band stays the unvalidated largest factor and says so.
FILE_EFFICIENCY_MODEL = "file"
#: ``diagnostics["efficiency_model"]`` of a solve through an assumed flat η: the factor key
#: ``known-grating:flat``, judged on the protocol's variant of that set-up (decision 0075).
FLAT_EFFICIENCY_MODEL = "flat"
#: What stands in for an efficiency nobody measured (decision 0074, amended): a flat η, said
#: (``flat_grating_assumed``). ``"physical"`` (η₁ marginalised over the physical families) is an
#: option: on the validation split it wins only where the truth is drawn from those very families
#: (the protocol's sheets are), and loses on the one grating outside them (the maker's LHires curve).
DEFAULT_ASSUMED_GRATING: AssumedGrating = "flat"
#: The camera prior's weights (its precision's multiplier) one lamp through a grating file chooses
#: among by the evidence (:func:`one_lamp_prior_weight`, decision 0080): a logarithmic grid wide
#: enough that no validation camera's choice sat at either end.
ONE_LAMP_PRIOR_WEIGHTS = np.geomspace(0.03, 30.0, 25)


def one_lamp_prior_weight(
    solution: SensitivitySolution, prior: CameraPrior, weights: FloatArray = ONE_LAMP_PRIOR_WEIGHTS
) -> float:
    """The camera prior's weight ``w`` that maximises the marginal likelihood of one lamp's data
    sensitivity ``ŝ`` (``ŝ ~ N(α m, C + α² Σ / w)``, ``C`` its covariance, ``α`` fitted as
    :func:`calib.methods.multilamp.blend_with_prior` fits it): type-II maximum likelihood, the
    multi-lamp ``"evidence"`` rule (:data:`calib.methods.multilamp.PRIOR_WEIGHT_RULES`) applied to
    the one place the prior enters here. ``1.0`` (the natural weight) without a covariance."""
    if solution.covariance is None:
        return 1.0
    size = prior.grid.size
    data = solution.sensitivity.T.ravel()
    mean = prior.mean.T.ravel()
    scale = float(data @ mean) / max(float(mean @ mean), 1e-300)
    residual = data - scale * mean
    scores = []
    for weight in weights:
        spread = solution.covariance.copy()
        for c in range(3):
            block = slice(c * size, (c + 1) * size)
            spread[block, block] += scale**2 * prior.covariance[c] / weight
        sign, log_det = np.linalg.slogdet(spread)
        scores.append(
            float(residual @ np.linalg.solve(spread, residual)) + log_det if sign > 0 else np.inf
        )
    return float(weights[int(np.argmin(scores))])


def is_assumed_physical(record: object) -> bool:
    """Whether a result's ``diagnostics["grating"]`` records an η marginalised over the physical
    families (no direct measurement, no grating file: decision 0074)."""
    return isinstance(record, Mapping) and record.get("source") == ASSUMED_PHYSICAL_SOURCE


def _budget_family(grating: GratingEfficiency | None, assumed: object) -> str | None:
    """The η model the σ budget keys its factor on (``known-grating:…``, decisions 0074/0075):
    assumed over the physical families, assumed flat, or a file stating its σ; a file without σ
    (a maker's curve) has none, so its band stays the unvalidated largest factor."""
    if grating is None:
        return ASSUMED_EFFICIENCY_MODEL if assumed is not None else FLAT_EFFICIENCY_MODEL
    return FILE_EFFICIENCY_MODEL if grating.efficiency_sigma is not None else None


@dataclass(frozen=True)
class KnownGratingOptions(GratingMethodOptions):
    """Options of :func:`estimate_known_grating`: those of every grating method
    (:class:`calib.methods.closed_form.GratingMethodOptions`); ``prior_shrinkage`` shapes the
    prior that steers the mapping search and fills in where the lamps are dim.
    ``assumed_grating``: what stands in for η without a grating (``grating=None``):
    ``"physical"`` (η₁ marginalised over the physical families,
    :func:`calib.methods.grating_models.assumed_efficiency`) or ``"flat"``.
    ``assumed_families``: the population ``"physical"`` marginalises over
    (:data:`calib.methods.grating_models.ASSUMED_FAMILY_NAMES`; decision 0088 judged each family
    left out of it on the validation split)."""

    assumed_grating: AssumedGrating = DEFAULT_ASSUMED_GRATING
    assumed_families: tuple[AssumedFamily, ...] = DEFAULT_ASSUMED_FAMILIES

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "assumed_families", check_assumed_families(self.assumed_families))


def other_order_flag(
    grating: GratingEfficiency | None, observations: Sequence[LampObservation]
) -> QualityFlag | None:
    """``grating_other_order`` when this capture's first order runs opposite, on the sensor, to
    the one the grating file's efficiency was measured on (the file's rig record). Either the
    camera was turned round, or this is the other first order, whose efficiency a blazed grating
    makes different (detection reads the other order where the stronger leaves the frame,
    decision 0196); nothing in the images tells the two apart."""
    if grating is None or grating.rig is None or not observations:
        return None
    stored = RigGeometry.from_dict(grating.rig).optics.order_angle_deg
    new = optics_from_observation(observations[0]).order_angle_deg
    if stored is None or new is None:
        return None
    turn = abs((new - stored + 180.0) % 360.0 - 180.0)
    if turn < 180.0 - OPPOSITE_ORDER_TOLERANCE_DEG:
        return None
    return QualityFlag(
        "grating_other_order",
        f"this capture's first order runs at {new:.0f}° on the sensor, opposite to the {stored:.0f}° "
        f"of the order the grating file {grating.source!r} was measured on: either the camera was "
        "turned round, or this is the other first order, whose efficiency differs for a blazed "
        "grating (a thin sinusoidal sheet's two orders are alike); measure this order with the "
        "rig, or keep the order the file was measured on in the frame",
    )


@one_blas_thread
def estimate_known_grating(
    observations: Sequence[LampObservation],
    *,
    grating: GratingEfficiency | None,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    options: KnownGratingOptions = KnownGratingOptions(),
) -> EstimateResult:
    """Estimate the camera from first-order profiles through a grating of known efficiency.

    Parameters
    ----------
    observations
        Lamps with profiles and measured spectra, all in one pixel frame (a direct RGB, if any, is
        not needed).
    grating
        The grating's efficiency, or ``None`` to assume a flat one (say so to the user).
    basis
        Camera basis on ``grid``: its prior steers the mapping and fills in where lamps are dim.
    grid
        Working grid.
    mapping
        A known pixel→wavelength mapping, or ``None`` to find it.
    mapping_lamp
        Find the mapping with this lamp only (default: fluorescent lamps and one other, jointly).
    options
        :class:`KnownGratingOptions`.

    Returns
    -------
    EstimateResult
        ``method="known-grating"``, with ``sensitivity_sigma``; ``grating_efficiency`` the given
        (or flat) one, maximum 1; ``diagnostics["grating"]`` says which.

    Raises
    ------
    InputError
        No observations, duplicate names, an unknown mapping lamp, a grating that does not cover
        the grid or is zero inside it.
    EstimationError
        The mapping cannot be found, or no positive sensitivity.

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
    >>> result = estimate_known_grating(
    ...     [led.observation], grating=None, basis=basis, mapping=truth
    ... )
    >>> result.method, result.diagnostics["grating"]
    ('known-grating', 'flat (assumed)')
    """
    started = time.perf_counter()
    check_lamps(observations, basis, grid)
    wavelength = grid.wavelength_nm
    eta_sigma: FloatArray | None = None
    assumed: AssumedEfficiency | None = None
    record: Any
    if grating is None:
        # Placeholders until the responses are fitted (the assumed-physical η is weighed by them).
        eta = np.ones_like(wavelength)
        record = "flat (assumed)"
    else:
        if not grating.covers(grid):
            lo, hi = grating.range_nm
            raise InputError(
                f"the grating efficiency covers {lo:g}–{hi:g} nm, the grid needs "
                f"{grid.start_nm:g}–{grid.stop_nm:g} nm",
                source=grating.source,
            )
        eta = grating.at(wavelength)
        if np.any(eta <= 0):
            raise InputError(
                "the grating efficiency is zero inside the grid", source=grating.source
            )
        eta_sigma = grating.sigma_at(wavelength)
        record = {"source": grating.source, "provenance": dict(grating.provenance)}
    prior = basis.prior(options.prior_shrinkage)
    kernel = camera_kernel(observations, options.slit_width_px, options.psf_sigma_px)
    used_mapping, chosen, mapping_s = mapping_and_lamps(
        observations,
        prior,
        grid,
        mapping,
        mapping_lamp,
        options.refine_given_mapping,
        kernel,
        need_direct=False,
        rig=None if grating is None or grating.rig is None else RigGeometry.from_dict(grating.rig),
    )
    systems = [prepare_matched_lamp(obs, used_mapping, grid, kernel) for obs in chosen]
    # The 2nd order on the 1st order's red end: modelled when the grating's physical model gives
    # η₂/η₁, else its pixels left out (fit_response; decision 0032).
    physical = None if grating is None else recorded_physical_grating(grating.model)
    ratio = None if physical is None else second_order_ratio(physical)
    responses = [fit_response(system, used_mapping, second_order=ratio) for system in systems]
    second_order = {
        system.observation.name: {
            "from_nm": response.second_order_nm,
            "treated": response.second_order,
        }
        for system, response in zip(systems, responses, strict=True)
        if response.second_order is not None
    }
    if grating is None and options.assumed_grating == "physical":
        # Each physical shape weighed by how well the camera prior explains the response through
        # it (decision 0074: on the validation split the weighing beat the families' prior alone).
        pooled = pool_responses(responses)[0]
        log_evidence = candidate_log_evidence(
            pooled.response,
            pooled.covariance,
            prior.mean,
            prior.covariance,
            assumed_candidates(wavelength, options.assumed_families)[0],
        )
        assumed = assumed_efficiency(
            wavelength, options.assumed_families, log_evidence=log_evidence
        )
        eta, eta_sigma = assumed.efficiency, assumed.efficiency_sigma
        record = {"source": ASSUMED_PHYSICAL_SOURCE, **assumed.record}
        # The shapes' spread is smooth and shared by the channels: its full covariance, so that
        # the camera prior can settle the part of it the camera family does not allow.
        inverse, inverse_covariance = assumed.inverse, assumed.inverse_covariance
    else:
        inverse = 1.0 / eta
        inverse_sigma = np.zeros_like(inverse) if eta_sigma is None else eta_sigma / eta**2
        inverse_covariance = np.diag(inverse_sigma**2)
    solution = combine_responses(responses, inverse, np.eye(inverse.size), inverse_covariance)
    # The profile of one lamp says little where the lamp is dim: the camera prior fills in there
    # (η is known, so the prior enters only here). One lamp through a calibration's grating file
    # (η with σ) weighs it by the evidence (decision 0080, judged there); elsewhere at its natural
    # weight (the assumed η's σ factors were judged so, decision 0075; a maker's curve is unjudged).
    prior_weight = (
        one_lamp_prior_weight(solution, prior)
        if _budget_family(grating, assumed) == FILE_EFFICIENCY_MODEL and len(responses) == 1
        else 1.0
    )
    solution = blend_with_prior(
        solution, replace(prior, covariance=prior.covariance / prior_weight)
    )
    lamps = tuple(
        LampData(
            system.observation.name,
            system.operators.direct_row,
            response,
            np.full(3, np.nan),
            np.zeros(3),
        )
        for system, response in zip(systems, responses, strict=True)
    )
    peak = float(eta.max())
    total_s = time.perf_counter() - started
    result = multilamp_result(
        lamps,
        solution,
        (eta / peak, None if eta_sigma is None else eta_sigma / peak),
        used_mapping,
        basis,
        {
            "grating": record,
            **({"efficiency_model": model} if (model := _budget_family(grating, assumed)) else {}),
            "prior_shrinkage": prior.shrinkage.tolist(),
            "prior_weight": prior_weight,
            **({"second_order": second_order} if second_order else {}),
        },
        {"mapping_s": mapping_s, "solve_s": total_s - mapping_s, "total_s": total_s},
        method=KNOWN_GRATING_METHOD,
    )
    flag = other_order_flag(grating, observations)
    return result if flag is None else result.with_quality(flag)
