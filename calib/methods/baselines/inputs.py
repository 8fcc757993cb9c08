"""What every registered baseline does with its inputs before estimating: sort and check them.

The front function :func:`calib.methods.estimate` hands each method one sequence of observations of
any kind (:data:`calib.core.observations.Observation`) and the camera basis, resolved once. A method
takes the kinds it understands, and says clearly when a kind it cannot use was given or one it needs
is missing.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.core.spectra import WavelengthGrid
from calib.model.bases import CameraBasis


def split_observations(
    observations: Sequence[Any],
    method: str,
    accepted: dict[str, type[Any]],
) -> dict[str, list[Any]]:
    """Group observations by kind; reject kinds the method cannot use.

    Parameters
    ----------
    observations
        What the caller passed to :func:`calib.methods.estimate`.
    method
        The method's registry name (for messages).
    accepted
        Label → observation class, e.g. ``{"charts": ChartObservation}``.

    Returns
    -------
    dict
        Label → the observations of that class (possibly empty lists).
    """
    groups: dict[str, list[Any]] = {label: [] for label in accepted}
    for index, observation in enumerate(observations):
        for label, kind in accepted.items():
            if isinstance(observation, kind):
                groups[label].append(observation)
                break
        else:
            kinds = ", ".join(kind.__name__ for kind in accepted.values())
            name = getattr(observation, "name", f"#{index + 1}")
            raise InputError(
                f"{method} uses {kinds} only; observation {name!r} is a "
                f"{type(observation).__name__}",
                source="observations",
            )
    return groups


def check_basis(basis: CameraBasis, grid: WavelengthGrid, n_vectors: int) -> None:
    """Raise :class:`InputError` unless ``basis`` is on ``grid`` and has ``n_vectors`` (≥ 1) vectors."""
    if basis.grid != grid:
        raise InputError(
            f"the camera basis is on grid {basis.grid}, the estimate on {grid}", source="basis"
        )
    if not 1 <= n_vectors <= basis.n_vectors:
        raise InputError(
            f"n_vectors must be between 1 and the basis' {basis.n_vectors}, got {n_vectors}",
            source="n_vectors",
        )


def check_weight(value: float, name: str) -> None:
    """Raise :class:`InputError` unless a regularisation weight is finite and ``>= 0``."""
    if not (np.isfinite(value) and value >= 0):
        raise InputError(f"{name} must be a finite number >= 0, got {value}", source=name)


def normalised_curves(
    sensitivity: FloatArray, sigma: FloatArray | None, method: str
) -> tuple[FloatArray, FloatArray | None, float]:
    """Curves ``(f, 3)`` divided by their maximum (and σ by the same), with that maximum.

    Raises
    ------
    EstimationError
        When nothing positive was estimated.
    """
    peak = float(np.max(sensitivity))
    if not np.isfinite(peak) or peak <= 0:
        raise EstimationError(
            f"{method} estimated no positive sensitivity; check the observations and their units"
        )
    return sensitivity / peak, None if sigma is None else sigma / peak, peak
