"""The one front function :func:`estimate` and the registry of estimation methods behind it.

In the style of colour-science's ``method=`` front functions: each method is a function
``(observations, *, grid, basis, mapping, mapping_lamp, **options) -> EstimateResult`` registered
under its paper's name with :func:`register_method`. Later methods (``multilamp``, ``jiang2013``,
``toivonen2020``, ``han2012``, ``solomatov2023`` …) register themselves the same way, importing
their module only when called so that ``import calib`` stays cheap.

Examples
--------
>>> from calib import estimate                                       # doctest: +SKIP
>>> result = estimate(observations, method="makabe2025")             # doctest: +SKIP
>>> result.sensitivity.shape                                         # doctest: +SKIP
(31, 3)
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from calib.core.blas import one_blas_thread
from calib.core.datasets import SOLOMATOV, load_collection
from calib.core.errors import InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation, Observation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.model.bases import DEFAULT_N_VECTORS, CameraBasis, camera_basis, fallback_camera_basis


class EstimationMethod(Protocol):
    """Signature every registered method implements."""

    def __call__(
        self,
        observations: Sequence[Any],
        *,
        grid: WavelengthGrid,
        basis: CameraBasis | None,
        mapping: QuadraticMapping | GratingGeometry | None,
        mapping_lamp: str | None,
        **options: Any,
    ) -> EstimateResult: ...


ESTIMATION_METHODS: dict[str, EstimationMethod] = {}


def register_method(
    name: str, function: EstimationMethod | None = None, *, replace: bool = False
) -> Any:
    """Register ``function`` under ``name`` (usable as a decorator: ``@register_method("x")``)."""

    def decorator(func: EstimationMethod) -> EstimationMethod:
        key = name.lower()
        if key in ESTIMATION_METHODS and not replace and ESTIMATION_METHODS[key] is not func:
            raise InputError(f"a method named {name!r} is already registered", source="method")
        ESTIMATION_METHODS[key] = func
        return func

    return decorator(function) if function is not None else decorator


def default_camera_basis(
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    n_vectors: int = DEFAULT_N_VECTORS,
    data_dir: str | Path | None = None,
    exclude: Sequence[str] = (),
) -> CameraBasis:
    """The measured-camera basis when the data is available, else the colour-science fallback.

    Uses every Solomatov/Akkaynak ground truth (49) not matching ``exclude``; when the data directory
    cannot be found, :func:`calib.model.bases.fallback_camera_basis` (offline). The basis' ``source`` says
    which was used.
    """
    try:
        records = load_collection(SOLOMATOV, data_dir)
    except InputError:
        if data_dir is not None:
            raise
        return fallback_camera_basis(grid=grid, n_vectors=n_vectors, exclude=exclude)
    excluded = [token.lower() for token in exclude]
    kept = [r for r in records if not any(token in r.name.lower() for token in excluded)]
    return camera_basis(
        [r.sensitivity for r in kept],
        grid=grid,
        n_vectors=n_vectors,
        source=f"{SOLOMATOV} ground truths ({len(kept)})",
        camera_names=[r.name for r in kept],
    )


@one_blas_thread
def estimate(
    observations: Sequence[Observation],
    method: str = "makabe2025",
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    basis: CameraBasis | None = None,
    mapping: QuadraticMapping | GratingGeometry | None = None,
    mapping_lamp: str | None = None,
    **options: Any,
) -> EstimateResult:
    """Estimate a camera's spectral sensitivity from lamp observations.

    Parameters
    ----------
    observations
        The lamps seen through the grating (see :class:`calib.core.observations.LampObservation`), or
        whatever else the method uses (:data:`calib.core.observations.Observation`: colour charts,
        colour matrices); each method takes the kinds it understands.
    method
        A registered method name (see :data:`ESTIMATION_METHODS`); default ``"makabe2025"``.
    grid
        Working wavelength grid.
    basis
        Camera basis; ``None`` uses :func:`default_camera_basis` (measured data if available, else
        the offline colour-science basis).
    mapping
        A known pixel→wavelength mapping, or ``None`` to estimate it.
    mapping_lamp
        Which lamp to find the mapping with.
    **options
        Method-specific options (e.g. ``weighting="paper"`` for makabe2025).

    Returns
    -------
    EstimateResult
    """
    key = method.lower()
    if key not in ESTIMATION_METHODS:
        raise InputError(
            f"unknown method {method!r}; available: {', '.join(sorted(ESTIMATION_METHODS))}",
            source="method",
        )
    return ESTIMATION_METHODS[key](
        observations, grid=grid, basis=basis, mapping=mapping, mapping_lamp=mapping_lamp, **options
    )


def resolve_basis(
    basis: CameraBasis | None, grid: WavelengthGrid, options: dict[str, Any]
) -> CameraBasis:
    """``basis``, else :func:`default_camera_basis` (popping a ``data_dir`` option to find it)."""
    data_dir = options.pop("data_dir", None)
    return basis if basis is not None else default_camera_basis(grid, data_dir=data_dir)


def _makabe2025(
    observations: Sequence[LampObservation],
    *,
    grid: WavelengthGrid,
    basis: CameraBasis | None,
    mapping: QuadraticMapping | GratingGeometry | None,
    mapping_lamp: str | None,
    **options: Any,
) -> EstimateResult:
    from calib.methods.makabe2025 import estimate_makabe2025

    chosen = resolve_basis(basis, grid, options)
    return estimate_makabe2025(
        observations, basis=chosen, grid=grid, mapping=mapping, mapping_lamp=mapping_lamp, **options
    )


register_method("makabe2025", _makabe2025)


def lazy_method(module: str, function: str) -> EstimationMethod:
    """A registry entry that imports ``module`` only when the method is first used.

    Keeps ``import calib`` cheap: a baseline's module (and whatever it imports) loads on demand.
    """

    def run(observations: Sequence[Any], **arguments: Any) -> EstimateResult:
        implementation = getattr(importlib.import_module(module), function)
        return implementation(observations, **arguments)  # type: ignore[no-any-return]

    run.__name__ = function
    run.__qualname__ = function
    run.__doc__ = f"Lazily imported ``{module}.{function}``."
    return run


#: Baselines behind the front function, imported on first use: name → (module, function).
LAZY_METHODS: dict[str, tuple[str, str]] = {
    "jiang2013": ("calib.methods.baselines.jiang2013", "jiang2013_method"),
    "solomatov2023": ("calib.methods.baselines.solomatov2023", "solomatov2023_method"),
    "toivonen2020": ("calib.methods.baselines.toivonen2020", "toivonen2020_method"),
    "multilamp": ("calib.methods.multilamp", "multilamp_method"),
}

for _name, (_module, _function) in LAZY_METHODS.items():
    register_method(_name, lazy_method(_module, _function))


def _han2012(
    observations: Sequence[LampObservation],
    *,
    grid: WavelengthGrid,
    basis: CameraBasis | None,
    mapping: QuadraticMapping | GratingGeometry | None,
    mapping_lamp: str | None,
    **options: Any,
) -> EstimateResult:
    from calib.methods.baselines.han2012 import FluorescentChart, estimate_han2012

    chart = options.pop("chart", None)
    if not isinstance(chart, FluorescentChart) or observations or mapping or mapping_lamp:
        raise InputError(
            "han2012 works from one image of a fluorescent and a reference chart: call "
            "estimate([], method='han2012', chart=FluorescentChart(...)); it uses no lamp "
            "observations and no mapping",
            source="method",
        )
    return estimate_han2012(chart, grid=grid, basis=basis, **options).to_estimate_result()


register_method("han2012", _han2012)

#: Type of a registered method, for other modules' annotations.
MethodFunction = Callable[..., EstimateResult]
