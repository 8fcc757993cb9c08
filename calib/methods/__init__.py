"""The one front function :func:`estimate` and the registry of estimation methods behind it.

In colour-science's manner (``colour.recovery``'s ``METHODS`` tables with ``filter_kwargs``):
:data:`ESTIMATION_METHODS` maps each method's name to its algorithm function, and :func:`estimate`
routes each function only the keyword arguments it declares. An option the chosen method does not
declare is refused with an :class:`~calib.core.errors.InputError` naming it and the method, unless
the caller asks for filtering (``filter_options=True``, e.g. one option set for many methods).

The front function resolves the camera basis once (:func:`calib.model.bases.default_camera_basis`,
measured cameras when the data is found, else colour-science's) for a method that takes one;
methods receive their basis and never call back here. The grating methods take their options as one
typed object (:class:`PriorOptions`, :class:`Makabe2025Options`, :class:`MultilampOptions`,
:class:`KnownGratingOptions`, …, checked on construction), built once by whoever parsed them.

``method="auto"`` (the default) chooses by :func:`choose_method` and records the choice and its
reason in the result's ``diagnostics["method_choice"]``.

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
>>> led = render_observation(colour_lamp("LED-B3"), camera, mapping=truth, pixel=800).observation
>>> result = estimate([led], basis=basis, mapping=truth)
>>> result.method, result.diagnostics["method_choice"]["method"]
('prior', 'prior')
>>> estimate([led], "prior", basis=basis, mapping=truth, weight_rule="upre")
Traceback (most recent call last):
...
calib.core.errors.InputError: weight_rule: method 'prior' takes no option 'weight_rule' (it takes basis, grid, mapping, mapping_lamp, options)
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.blas import one_blas_thread
from calib.core.errors import InputError
from calib.core.line_lists import is_builtin
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult, QualityFlag, mapping_flags
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.core.spectrometer_scale import ScaleCheckOutcome, checked_observations
from calib.methods.baselines.han2012 import Han2012Options, estimate_han2012
from calib.methods.baselines.jiang2013 import estimate_jiang2013
from calib.methods.baselines.solomatov2023 import estimate_solomatov2023
from calib.methods.baselines.toivonen2020 import estimate_toivonen2020
from calib.methods.known_grating import (
    KNOWN_GRATING_METHOD,
    KnownGratingOptions,
    estimate_known_grating,
)
from calib.methods.makabe2025 import MAKABE2025_METHOD, Makabe2025Options, estimate_makabe2025
from calib.methods.multilamp import (
    MULTILAMP_METHOD,
    MultilampOptions,
    estimate_multilamp,
    family_flag,
)
from calib.methods.prior_solve import PRIOR_METHOD, PriorOptions, estimate_prior
from calib.methods.solve_scope import perturbation, solve_scope
from calib.methods.uncertainty import (
    DEFAULT_BUDGET,
    BudgetSettings,
    assumed_grating_flag,
    channel_gains_unknown,
    check_grid_within_basis,
    curves_only,
    uncertainty_budget,
    with_budget,
    with_prior_channel_balance,
)
from calib.model.bases import CameraBasis, default_camera_basis, is_fallback_basis

__all__ = [
    "AUTO",
    "ESTIMATION_METHODS",
    "BudgetSettings",
    "Han2012Options",
    "KnownGratingOptions",
    "Makabe2025Options",
    "MethodChoice",
    "MethodOptions",
    "MultilampOptions",
    "PriorOptions",
    "check_method",
    "choose_method",
    "coarse_line_spectrum",
    "estimate",
    "method_names",
    "unmeasured_line_spectrum",
]

#: Type of a registered method: ``(observations, **declared keywords) -> EstimateResult``.
MethodFunction = Callable[..., EstimateResult]

#: Registry name → the algorithm function.
ESTIMATION_METHODS: dict[str, MethodFunction] = {
    PRIOR_METHOD: estimate_prior,
    MAKABE2025_METHOD: estimate_makabe2025,
    MULTILAMP_METHOD: estimate_multilamp,
    KNOWN_GRATING_METHOD: estimate_known_grating,
    "jiang2013": estimate_jiang2013,
    "han2012": estimate_han2012,
    "solomatov2023": estimate_solomatov2023,
    "toivonen2020": estimate_toivonen2020,
}

#: The front function's default: :func:`choose_method` decides.
AUTO = "auto"


def method_names() -> tuple[str, ...]:
    """Every name :func:`estimate` takes: ``"auto"`` and the registered methods."""
    return (AUTO, *ESTIMATION_METHODS)


#: The typed options of the grating methods (what a command line builds and a pipeline carries).
MethodOptions = PriorOptions | Makabe2025Options | MultilampOptions | KnownGratingOptions

#: Lamps with a direct measurement from which ``auto`` chooses ``multilamp``: each lamp adds three
#: equations on η alone, and three spectrally different lamps determine it without leaning on the
#: camera prior (decision 0015).
AUTO_MULTILAMP_LAMPS = 3


#: A line lamp (fluorescent, narrowband) whose spectrum is sampled more coarsely than this (nm)
#: cannot place its lines: ``auto`` uses it for the mapping only. Spectroradiometers sample at
#: 1–5 nm (tabulated CIE F-series too). Unless the spectrum states a slit at least twice its
#: sample step (an i1Pro through ``spotread``: 25 nm at 10 nm): such a spectrum is slit-limited
#: and well sampled, the solve models the slit (:mod:`calib.model.resolution`), and the lamp's
#: direct measurement constrains η (decision 0035).
COARSE_LINE_SPECTRUM_NM = 5.0
LINE_LAMP_KINDS = ("fluorescent", "narrowband")


def unmeasured_line_spectrum(observation: LampObservation) -> str | None:
    """Why a line lamp's spectrum is not a measurement of it, or ``None``: its lamp's
    ``metadata["spectrum_known"]`` is ``False`` (a nominal spectrum standing in for one nobody
    measured), or it is a built-in line list (``builtin:NAME``: where the lines are, not how bright
    the lamp is between them)."""
    if observation.kind not in LINE_LAMP_KINDS:
        return None
    if observation.metadata.get("spectrum_known") is False:
        return f"lamp {observation.name!r}: its spectrum was not measured"
    if is_builtin(observation.spectrum.name or ""):
        return (
            f"lamp {observation.name!r}: its spectrum is the line list {observation.spectrum.name} "
            "(where its lines are, not a measurement of the lamp)"
        )
    return None


def coarse_line_spectrum(observation: LampObservation) -> str | None:
    """Why a line lamp's spectrum cannot be used in the solve (not a measurement,
    :func:`unmeasured_line_spectrum`, or too coarse), or ``None``."""
    if observation.kind not in LINE_LAMP_KINDS:
        return None
    unmeasured = unmeasured_line_spectrum(observation)
    if unmeasured is not None:
        return unmeasured
    wavelength = np.asarray(observation.spectrum.wavelength_nm, dtype=np.float64)
    step = float(np.median(np.diff(wavelength))) if wavelength.size > 1 else math.inf
    bandwidth = observation.spectrum_bandwidth_nm
    slit_limited = bandwidth is not None and bandwidth >= 2.0 * step
    if step > COARSE_LINE_SPECTRUM_NM and not slit_limited:
        return (
            f"lamp {observation.name!r}: its spectrum is sampled every {step:g} nm, too coarse for "
            f"its emission lines (≤ {COARSE_LINE_SPECTRUM_NM:g} nm needed, or a stated "
            f"spectrometer bandwidth of at least {2.0 * step:g} nm)"
        )
    return None


@dataclass(frozen=True)
class MethodChoice:
    """What ``method="auto"`` chose, and why (recorded in ``diagnostics["method_choice"]``).

    ``mapping_only`` names the lamps used to find the mapping but kept out of the solve.
    """

    method: str
    reason: str
    mapping_only: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "requested": AUTO,
            "method": self.method,
            "reason": self.reason,
            "mapping_only": list(self.mapping_only),
        }


def choose_method(
    observations: Sequence[object], *, grating: object = None, assume_flat_grating: bool = False
) -> MethodChoice:
    """The method ``auto`` stands for.

    1. A line lamp with an unknown or coarse spectrum (:func:`coarse_line_spectrum`) helps the
       mapping only: its lines place the wavelengths, but its spectrum would put wrong lines into
       the solve.
    2. A grating file given: ``known-grating`` (its η and σ, measured or a maker's curve).
    3. ``multilamp`` when at least :data:`AUTO_MULTILAMP_LAMPS` of the other lamps have a direct
       measurement, else the prior solve.
    4. No direct measurement and no grating file: ``known-grating`` through a flat grating when
       ``assume_flat_grating`` (the caller warns), else an error.

    Raises
    ------
    InputError
        No lamp observation, or no lamp with a direct measurement, no grating file and no flat
        grating allowed (then the grating's efficiency must come from elsewhere).
    """
    lamps = [item for item in observations if isinstance(item, LampObservation)]
    if len(lamps) != len(observations) or not lamps:
        raise InputError(
            "method 'auto' chooses among the grating methods and needs lamp observations only; "
            "name the method for charts or colour matrices (e.g. method='jiang2013')",
            source="method",
        )
    reasons = {lamp.name: why for lamp in lamps if (why := coarse_line_spectrum(lamp))}
    mapping_only = tuple(name for name in reasons if len(reasons) < len(lamps))
    prefix = "".join(f"{reasons[name]}: used for the mapping only; " for name in mapping_only)
    if grating is not None:
        source = getattr(grating, "source", "the grating file")
        stated = getattr(grating, "efficiency_sigma", None) is not None
        return MethodChoice(
            KNOWN_GRATING_METHOD,
            prefix
            + f"a grating efficiency was given ({source}): the known-grating solve uses it "
            + ("with its σ" if stated else "(it states no σ)"),
            mapping_only,
        )
    direct = [
        lamp.name for lamp in lamps if lamp.direct_rgb is not None and lamp.name not in mapping_only
    ]
    if len(direct) >= AUTO_MULTILAMP_LAMPS:
        return MethodChoice(
            MULTILAMP_METHOD,
            prefix + f"{len(direct)} lamps have a direct measurement ({', '.join(direct)}): their "
            "direct equations determine the grating efficiency",
            mapping_only,
        )
    if direct:
        return MethodChoice(
            PRIOR_METHOD,
            prefix + f"{len(direct)} lamp(s) with a direct measurement ({', '.join(direct)}); "
            f"multilamp needs at least {AUTO_MULTILAMP_LAMPS}",
            mapping_only,
        )
    if assume_flat_grating:
        return MethodChoice(
            KNOWN_GRATING_METHOD,
            prefix + "no direct measurement and no grating file: the known-grating solve through "
            "an assumed grating efficiency (flat unless told otherwise; the quality flags say "
            "which, and the sensitivity carries this grating's departure from it)",
            mapping_only,
        )
    raise InputError(
        "no lamp has a direct (0th-order) measurement, so no method can estimate the grating "
        "efficiency; give a grating file (method='known-grating', grating=...) or measure the "
        "direct spot",
        source="observations",
    )


def check_method(method: str, *, source: str = "method") -> str:
    """``method`` as registered (lower case), else an :class:`InputError` listing the names."""
    key = method.lower()
    if key != AUTO and key not in ESTIMATION_METHODS:
        raise InputError(
            f"unknown method {method!r}; available: {', '.join(method_names())}", source=source
        )
    return key


def _route(
    name: str,
    function: MethodFunction,
    options: Mapping[str, Any],
    *,
    filter_options: bool,
) -> dict[str, Any]:
    """The options ``function`` declares (after its first, positional parameter)."""
    declared = list(inspect.signature(function).parameters.values())[1:]
    if any(parameter.kind is inspect.Parameter.VAR_KEYWORD for parameter in declared):
        return dict(options)  # a function taking **options routes them itself
    names = [parameter.name for parameter in declared]
    routed = {key: value for key, value in options.items() if key in names}
    refused = [key for key in options if key not in names]
    if refused and not filter_options:
        raise InputError(
            f"method {name!r} takes no option {refused[0]!r} (it takes {', '.join(names)})",
            source=refused[0],
        )
    return routed


@one_blas_thread
def estimate(
    observations: Sequence[Any],
    method: str = AUTO,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    basis: CameraBasis | None = None,
    data_dir: str | Path | None = None,
    filter_options: bool = False,
    budget: BudgetSettings | None = DEFAULT_BUDGET,
    assume_flat_grating: bool = False,
    check_spectrometer_scale: bool = True,
    **options: Any,
) -> EstimateResult:
    """Estimate a camera's spectral sensitivity by the method named.

    Parameters
    ----------
    observations
        The lamps seen through the grating (:class:`calib.core.observations.LampObservation`), or
        whatever else the method uses (:data:`calib.core.observations.Observation`: colour charts,
        colour matrices; han2012's fluorescent chart); each method takes the kinds it understands.
    method
        ``"auto"`` (:func:`choose_method`) or a name of :data:`ESTIMATION_METHODS`.
    grid
        Working grid.
    basis
        The camera basis; ``None``: :func:`calib.model.bases.default_camera_basis` on ``grid``, for
        a method that takes one.
    data_dir
        Where that default basis' camera data is (default ``$SPECTRAL_RIG_DATA``, the user cache).
    filter_options
        Drop the options the method does not declare instead of refusing them.
    budget
        How the stated σ is made (:mod:`calib.methods.uncertainty`: the method's own σ, the basis'
        misfit, the mapping's σ, the spectrometer and η-model perturbations, the validation-judged
        factor); ``None`` keeps the method's own σ (and no quality flags of the budget).
    assume_flat_grating
        With ``"auto"``: lamps without a direct measurement and no grating file go through the
        known-grating solve with a flat grating instead of an error (the caller warns).
    check_spectrometer_scale
        Check the spectrometer's wavelength scale against the Hg lines of a fluorescent lamp it
        measured and correct every spectrum of that instrument
        (:func:`calib.core.spectrometer_scale.checked_observations`, decision 0069): the mapping
        and the σ budget then carry the check's σ instead of the scale tolerance; the result
        records it in ``diagnostics["spectrometer_scale_check"]``. Off: the spectra as given.
    **options
        The method's own keywords, as its function declares them: ``mapping``, ``mapping_lamp``,
        ``options`` (its typed options object), ``grating`` (known-grating), ``seed`` (toivonen2020) …

    Returns
    -------
    EstimateResult
        With ``diagnostics["method_choice"]`` when ``method="auto"``, the budget's σ and its
        ``quality`` flags.

    Raises
    ------
    InputError
        An unknown method; an option it does not declare (named); options of another method's type;
        a missing required input; a grid beyond the basis' camera data; or whatever the method
        refuses.
    """
    key = check_method(method)
    scale_check: ScaleCheckOutcome | None = None
    if check_spectrometer_scale:
        observations, scale_check = checked_observations(
            observations, range_nm=(grid.start_nm, grid.stop_nm)
        )
        if scale_check.check is None and not scale_check.notes:
            scale_check = None
    choice: MethodChoice | None = None
    if key == AUTO:
        choice = choose_method(
            observations,
            grating=options.get("grating"),
            assume_flat_grating=assume_flat_grating,
        )
        key = choice.method
        if choice.mapping_only:
            return with_scale_check(
                _mapping_only_estimate(
                    observations,
                    choice,
                    grid=grid,
                    basis=basis,
                    data_dir=data_dir,
                    filter_options=filter_options,
                    budget=budget,
                    options=options,
                ),
                scale_check,
            )
        if key == KNOWN_GRATING_METHOD:
            options = {"grating": None, **options}
        else:
            options = {name: value for name, value in options.items() if name != "grating"}
    function = ESTIMATION_METHODS[key]
    routed = _route(key, function, options, filter_options=filter_options)
    parameters = inspect.signature(function).parameters
    if "grid" in parameters:
        routed["grid"] = grid
    if "basis" in parameters:
        # A basis the method cannot do without; an optional one (toivonen2020: only to find a
        # mapping not given; han2012: its Fourier basis by default) is passed only when given.
        if basis is None and parameters["basis"].default is inspect.Parameter.empty:
            basis = default_camera_basis(grid, data_dir=data_dir)
            data_dir = None
        if basis is not None:
            routed["basis"] = basis
    elif basis is not None and any(
        parameter.kind is inspect.Parameter.VAR_KEYWORD for parameter in parameters.values()
    ):
        routed["basis"] = basis
    elif basis is not None and not filter_options:
        raise InputError(f"method {key!r} takes no camera basis", source="basis")
    if data_dir is not None and not filter_options:
        raise InputError(
            f"method {key!r} reads no camera data here (a basis was given, or it takes none)",
            source="data_dir",
        )
    if "options" in routed and "options" in parameters:
        expected = type(parameters["options"].default)
        if not isinstance(routed["options"], expected):
            raise InputError(
                f"method {key!r} takes {expected.__name__}, got {type(routed['options']).__name__}",
                source="options",
            )
    missing = [
        name
        for name, parameter in list(parameters.items())[1:]
        if parameter.default is inspect.Parameter.empty
        and parameter.kind is inspect.Parameter.KEYWORD_ONLY
        and name not in routed
    ]
    if missing:
        raise InputError(
            f"method {key!r} needs {', '.join(f'{name}=' for name in missing)}", source=missing[0]
        )
    used_basis = routed.get("basis")
    if isinstance(used_basis, CameraBasis):
        check_grid_within_basis(used_basis)
    # The method and its budget's re-solves share identical sub-solves and warm starts.
    with solve_scope(shared=budget is None or budget.reuse_solves):
        return with_scale_check(
            _estimate_in_scope(
                observations, key, function, routed, parameters, choice, used_basis, budget
            ),
            scale_check,
        )


def _flag_assumed_grating(result: EstimateResult) -> EstimateResult:
    flag = assumed_grating_flag(result)
    return result if flag is None else result.with_quality(flag)


def with_scale_check(result: EstimateResult, outcome: ScaleCheckOutcome | None) -> EstimateResult:
    """``result`` recording the spectrometer-scale check (``diagnostics["spectrometer_scale_check"]``),
    flagged ``spectrometer_out_of_spec`` when the lines put the scale beyond its tolerance."""
    if outcome is None or not isinstance(result, EstimateResult):
        return result
    result = replace(
        result,
        diagnostics={**result.diagnostics, "spectrometer_scale_check": outcome.to_dict()},
    )
    check = outcome.check
    if check is not None and check.out_of_spec:
        result = result.with_quality(
            QualityFlag(
                "spectrometer_out_of_spec",
                f"the Hg lines of {check.lamp} put the spectrometer's wavelength scale "
                f"{check.mean_offset_nm:+.2f} ± {check.sigma_nm:.2f} nm off, beyond its "
                f"±{check.tolerance_nm:g} nm tolerance: the spectra were corrected by the lines, "
                "but the instrument is out of its specification (recalibrate it)",
            )
        )
    return result


def _estimate_in_scope(
    observations: Sequence[Any],
    key: str,
    function: MethodFunction,
    routed: dict[str, Any],
    parameters: Mapping[str, inspect.Parameter],
    choice: MethodChoice | None,
    used_basis: object,
    budget: BudgetSettings | None,
) -> EstimateResult:
    """:func:`estimate` once the method and its options are settled: the method, its quality
    flags and the σ budget."""
    returned: object = function(observations, **routed)
    if not isinstance(returned, EstimateResult):  # a registered stand-in (tests) returns as is
        return returned  # type: ignore[return-value]
    # What the mapping stage warned of (competing basins, lines against the fit, extrapolation)
    # reaches the quality block whoever calls: the command lines and the Python API alike.
    result = returned.with_quality(*mapping_flags(returned.mapping))
    # Likewise the grating model's choice, for every method that judged the physical families
    # from the direct equations (the prior solve and multilamp alike, decision 0063).
    family = family_flag(returned.diagnostics.get("grating_model"))
    if family is not None:
        result = result.with_quality(family)
    if choice is not None:
        result = replace(
            result, diagnostics={**result.diagnostics, "method_choice": choice.to_dict()}
        )
    if choice is not None and key == KNOWN_GRATING_METHOD and routed.get("grating") is None:
        result = _flag_assumed_grating(result)
    if isinstance(used_basis, CameraBasis) and is_fallback_basis(used_basis):
        result = result.with_quality(
            QualityFlag(
                "fallback_basis",
                "no measured camera data found: the prior is the built-in fallback (CIE-derived "
                "curves, not cameras); fetch the data (rig data fetch) or give --data-dir",
            )
        )
    if isinstance(used_basis, CameraBasis) and channel_gains_unknown(observations):
        balance: Callable[[EstimateResult], EstimateResult] = partial(
            with_prior_channel_balance, basis=used_basis
        )
    else:
        balance = _unchanged
    if budget is None or getattr(routed.get("options"), "uncertainty", None) == "none":
        return balance(result)
    return balance(
        with_budget(
            result,
            uncertainty_budget(
                result,
                observations,
                rerun=_rerun(function, routed, result),
                basis=used_basis if isinstance(used_basis, CameraBasis) else None,
                options=routed.get("options", parameters["options"].default)
                if "options" in parameters
                else None,
                settings=budget,
            ),
            record_components=budget.record_components,
        )
    )


def _unchanged(result: EstimateResult) -> EstimateResult:
    return result


def _mapping_only_estimate(
    observations: Sequence[LampObservation],
    choice: MethodChoice,
    *,
    grid: WavelengthGrid,
    basis: CameraBasis | None,
    data_dir: str | Path | None,
    filter_options: bool,
    budget: BudgetSettings | None,
    options: Mapping[str, Any],
) -> EstimateResult:
    """``auto`` with lamps for the mapping only: the mapping from every lamp (those lamps' direct
    measurements set aside), then the chosen method on the other lamps through that mapping."""
    kept = [
        replace(obs, direct_rgb=None, direct_sigma=None) if obs.name in choice.mapping_only else obs
        for obs in observations
    ]
    if basis is None:
        basis = default_camera_basis(grid, data_dir=data_dir)
    method_options = {
        name: value
        for name, value in options.items()
        if name != "grating" or choice.method == KNOWN_GRATING_METHOD
    }
    if choice.method == KNOWN_GRATING_METHOD:
        method_options.setdefault("grating", None)
    mapping = method_options.pop("mapping", None)
    if mapping is None:
        mapping = estimate(
            kept,
            choice.method,
            grid=grid,
            basis=basis,
            filter_options=True,
            budget=None,
            check_spectrometer_scale=False,
            **method_options,
        ).mapping
    method_options.pop("mapping_lamp", None)
    solve = [obs for obs in kept if obs.name not in choice.mapping_only]
    result = estimate(
        solve,
        choice.method,
        grid=grid,
        basis=basis,
        filter_options=filter_options,
        budget=budget,
        mapping=mapping,
        check_spectrometer_scale=False,
        **method_options,
    )
    if choice.method == KNOWN_GRATING_METHOD and method_options.get("grating") is None:
        # The inner solve was called by name: say what it assumed for η here.
        result = _flag_assumed_grating(result)
    return replace(result, diagnostics={**result.diagnostics, "method_choice": choice.to_dict()})


def _rerun(
    function: MethodFunction, routed: Mapping[str, Any], result: EstimateResult
) -> Callable[..., EstimateResult] | None:
    """The method again with its mapping fixed (only the solve re-runs), for the budget's
    perturbations; ``None`` for a method that takes no mapping."""
    if result.mapping is None or "mapping" not in inspect.signature(function).parameters:
        return None
    fixed = {**routed, "mapping": result.mapping}
    if "mapping_lamp" in fixed:
        fixed["mapping_lamp"] = None
    # The grating model ``auto`` chose is kept (decision 0042): a perturbation measures how the
    # chosen model's answer moves, not a switch to another model.
    record = result.diagnostics.get("grating_model")
    chosen = record.get("chosen") if isinstance(record, Mapping) else None
    default_options = inspect.signature(function).parameters.get("options")

    def rerun(observations: Sequence[Any], **changes: Any) -> EstimateResult:
        arguments = {**fixed, **changes}
        options = arguments.get("options")
        if options is None and default_options is not None:
            options = default_options.default
            if options is inspect.Parameter.empty:
                options = None
        if options is not None and getattr(options, "refine_given_mapping", False):
            arguments["options"] = options = replace(options, refine_given_mapping=False)
        if (
            options is not None
            and isinstance(chosen, str)
            and getattr(options, "grating_model", None) == "auto"
        ):
            arguments["options"] = replace(options, grating_model=chosen)
        # The budget reads only the re-solve's curves and η (never its σ or residuals).
        with perturbation(), curves_only():
            return function(observations, **arguments)

    return rerun
