"""Which lamps to buy: rank lamp subsets by how well they pin the grating efficiency down.

For a set of lamps the multi-lamp solve (:mod:`calib.methods.multilamp`) determines ``η⁻¹ = B_η c_η`` from
the direct equations ``Σ_λ p_lc(λ) η⁻¹(λ) = m_dir,lc``. Before any capture they can be predicted for a
typical camera (the camera prior's mean ``ŝ``) behind a flat grating: ``p_lc = e_l ŝ_c`` (integrated
over the grid's hats), each equation with the noise of the synthetic protocol (a fraction of the
brightest direct channel, plus the model floor). A subset is scored by

* the condition number of its whitened data rows alone (∞ when it has fewer equations than ``c_η``
  has terms: the camera prior must decide the rest),
* the predicted σ of ``η``'s shape (relative, RMS over the grid) from the posterior with the camera prior at
  its natural weight, which is what the estimate's own uncertainty will be for a camera like ``ŝ``;
* the same σ from the direct equations alone (the Cramér–Rao bound: what the lamps pin down by
  themselves, for a camera the prior does not describe; ∞ when they cannot).

Subsets are ranked by the predicted σ; :func:`best_additions` says which extra lamp (e.g. a red,
green or blue LED) lowers it most.

With a physical grating model (``grating_model="sinusoidal"`` or ``"blazed"``,
:mod:`calib.methods.grating_models`; the model the solve would choose, or the one a grating file
recorded) the prediction is for that grating, at ``grating_parameter`` (default
:data:`PLANNING_PARAMETERS`): the Fisher information of ``(p, log T)`` from the direct equations of a
camera like ``ŝ`` through it, η₀ included, each lamp's rows whitened as the solve whitens them.
That solve takes no camera prior, so both σ columns are the same bound, and the relative σ of
``η₁``'s shape follows from ``∂ log η₁ / ∂p``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.spectra import Spectrum
from calib.methods.grating_models import check_grating_model, physical_equations
from calib.methods.multilamp import DEFAULT_EFFICIENCY_TERMS, prior_rows
from calib.methods.responses import LampData, ResponseEstimate, direct_rows
from calib.model.bases import CameraPrior, fourier_basis
from calib.model.forward import lamp_operators
from calib.model.gratings import PHYSICAL_PARAMETER_NAMES, PhysicalKind, physical_grating

#: Direct noise of the prediction (fraction of the brightest channel), as in ``calib synthetic``.
DEFAULT_NOISE_FRACTION = 0.01
#: Most lamps :func:`rank_subsets` enumerates every subset of (2^n − 1 subsets).
MAX_LAMPS = 12
#: Above this condition number the direct equations alone leave a direction of ``η`` open.
MAX_CONDITION = 1e10
#: The grating each physical family is planned for when no parameter is given: a sheet of peak
#: phase 1.2 rad at 550 nm (the middle of what such sheets have), a grating blazed at 500 nm (the
#: usual choice for the visible).
PLANNING_PARAMETERS: dict[PhysicalKind, float] = {"sinusoidal": 1.2, "blazed": 500.0}


@dataclass(frozen=True)
class SubsetScore:
    """One lamp subset's predicted quality.

    Attributes
    ----------
    lamps
        The lamps' names.
    condition
        Condition number of the whitened direct equations alone (``inf`` when underdetermined).
    efficiency_sigma
        Predicted RMS relative σ of ``η`` over the grid (0.01 = 1 %), camera prior included.
    data_sigma
        The same from the direct equations alone (``inf`` when they leave a direction open).
    """

    lamps: tuple[str, ...]
    condition: float
    efficiency_sigma: float
    data_sigma: float = math.inf

    def to_dict(self) -> dict[str, object]:
        return {
            "lamps": list(self.lamps),
            "condition": self.condition if math.isfinite(self.condition) else None,
            "efficiency_sigma": self.efficiency_sigma,
            "data_sigma": self.data_sigma if math.isfinite(self.data_sigma) else None,
        }


@dataclass(frozen=True, eq=False)
class _Planner:
    """What every subset's score shares: the efficiency basis, the prior's rows, the noise."""

    prior: CameraPrior
    efficiency_basis: FloatArray
    penalty: FloatArray
    noise_fraction: float
    grating: tuple[PhysicalKind, float] | None = None

    @classmethod
    def of(
        cls,
        prior: CameraPrior,
        noise_fraction: float,
        efficiency_terms: int,
        grating_model: str = "fourier",
        grating_parameter: float | None = None,
    ) -> _Planner:
        if noise_fraction <= 0 or not math.isfinite(noise_fraction):
            raise InputError(
                f"the noise fraction must be > 0, got {noise_fraction}", source="noise"
            )
        model = check_grating_model(grating_model)
        if model == "auto":
            raise InputError(
                "plan for one model: fourier, sinusoidal or blazed (auto chooses on data)",
                source="grating_model",
            )
        if model != "fourier":
            kind: PhysicalKind = "sinusoidal" if model == "sinusoidal" else "blazed"
            parameter = (
                PLANNING_PARAMETERS[kind] if grating_parameter is None else grating_parameter
            )
            grating = physical_grating(kind, parameter)  # checks the parameter
            wavelength = prior.grid.wavelength_nm
            shape = np.zeros((wavelength.size, 2))
            step = 1e-4 * parameter
            shape[:, 0] = (
                np.log(physical_grating(kind, parameter + step).efficiency(1, wavelength))
                - np.log(physical_grating(kind, parameter - step).efficiency(1, wavelength))
            ) / (2 * step)
            del grating
            return cls(prior, shape, np.zeros((0, 3)), noise_fraction, (kind, parameter))
        efficiency_basis = fourier_basis(prior.grid, efficiency_terms)
        size = prior.grid.size
        flat = np.ones(size)
        typical = ResponseEstimate(prior.mean, np.zeros((3, size, size)), flat, 0)
        penalty = prior_rows(typical, prior, efficiency_basis, flat, 1.0)
        return cls(prior, efficiency_basis, penalty, noise_fraction)

    def rows(self, lamp: Spectrum) -> FloatArray:
        """The lamp's whitened direct equations for a camera like ``ŝ``, weighted as the solve
        weights them (:func:`calib.methods.responses.direct_rows`): on ``c_η`` behind a flat
        grating, ``(3, b)``; or, with a physical model, their Jacobian in ``(p, log T)`` behind
        that grating, ``(3, 2)``."""
        size = self.prior.grid.size
        operators = lamp_operators(lamp, self.prior.grid)
        direct_row = operators.direct_row
        if self.grating is None:
            direct = direct_row @ self.prior.mean
            predicted = LampData(
                lamp.name,
                direct_row,
                ResponseEstimate(
                    self.prior.mean, np.zeros((3, size, size)), np.ones(size, bool), 0
                ),
                direct,
                np.full(3, self.noise_fraction * float(np.max(direct))),
            )
            nodes, _ = direct_rows([predicted], np.ones(size))
            return np.asarray(nodes @ self.efficiency_basis, dtype=np.float64)
        kind, parameter = self.grating
        grating = physical_grating(kind, parameter)
        wavelength = self.prior.grid.wavelength_nm
        first = grating.efficiency(1, wavelength)
        data = LampData(
            lamp.name,
            direct_row,
            ResponseEstimate(
                self.prior.mean * first[:, None],
                np.zeros((3, size, size)),
                np.ones(size, bool),
                0,
            ),
            np.zeros(3),
            np.zeros(3),
            operators,
        )
        direct = data.zeroth_order_row(grating.efficiency(0, operators.axis_nm)) @ self.prior.mean
        data = replace(
            data, direct=direct, direct_sigma=np.full(3, self.noise_fraction * float(direct.max()))
        )
        weight = 1.0 / first
        step = 1e-4 * parameter
        up = physical_equations([data], kind, parameter + step, weight, None, wavelength)[0]
        down = physical_equations([data], kind, parameter - step, weight, None, wavelength)[0]
        values = physical_equations([data], kind, parameter, weight, None, wavelength)[0]
        return np.stack([(up - down) / (2 * step), values], axis=1)

    def score(self, rows: Mapping[str, FloatArray], names: Sequence[str]) -> SubsetScore:
        return score_subset(
            [rows[name] for name in names], names, self.penalty, self.efficiency_basis
        )


def _unique_names(lamps: Sequence[Spectrum]) -> list[str]:
    names = [lamp.name for lamp in lamps]
    if len(set(names)) != len(names):
        raise InputError(f"lamp names must be unique, got {names}", source="lamps")
    return names


def score_subset(
    rows: Sequence[FloatArray],
    names: Sequence[str],
    penalty: FloatArray,
    efficiency_basis: FloatArray,
) -> SubsetScore:
    """Score a subset from its lamps' whitened rows and the prior's rows (see module docstring)."""
    data = np.vstack(rows)
    b_eta = data.shape[1]
    singular = np.linalg.svd(data, compute_uv=False)
    condition = (
        float(singular[0] / max(singular[-1], 1e-300)) if data.shape[0] >= b_eta else math.inf
    )
    padded = np.hstack([data, np.zeros((data.shape[0], 1))])
    posterior = np.linalg.pinv(padded.T @ padded + penalty.T @ penalty, hermitian=True)
    data_sigma = (
        _shape_sigma(np.linalg.inv(data.T @ data), efficiency_basis)
        if condition < MAX_CONDITION
        else math.inf
    )
    return SubsetScore(
        tuple(names),
        condition,
        _shape_sigma(posterior[:b_eta, :b_eta], efficiency_basis),
        data_sigma,
    )


def _shape_sigma(covariance: NDArray[np.floating], efficiency_basis: FloatArray) -> float:
    """RMS σ of ``η``'s shape over the grid from the covariance of ``c_η``.

    η's overall scale does not matter (results are normalised): the σ of its shape, η⁻¹ minus its
    mean. A flat grating has η⁻¹ = 1 in this gauge: the relative σ of η⁻¹ is that of η.
    """
    shape = efficiency_basis - efficiency_basis.mean(axis=0)
    variance = np.einsum("ij,jk,ik->i", shape, covariance, shape)
    return float(np.sqrt(np.mean(np.clip(variance, 0.0, None))))


def rank_subsets(
    lamps: Sequence[Spectrum],
    prior: CameraPrior,
    *,
    noise_fraction: float = DEFAULT_NOISE_FRACTION,
    efficiency_terms: int = DEFAULT_EFFICIENCY_TERMS,
    grating_model: str = "fourier",
    grating_parameter: float | None = None,
) -> list[SubsetScore]:
    """Every subset of ``lamps``, best (smallest predicted σ) first (``grating_model``: the module
    docstring).

    Raises
    ------
    InputError
        No lamps, too many, duplicate names, or a spectrum that does not cover the prior's grid.
    """
    if not lamps:
        raise InputError("no lamps given", source="lamps")
    if len(lamps) > MAX_LAMPS:
        raise InputError(
            f"{len(lamps)} lamps give {2 ** len(lamps) - 1} subsets; give at most {MAX_LAMPS}",
            source="lamps",
        )
    names = _unique_names(lamps)
    planner = _Planner.of(prior, noise_fraction, efficiency_terms, grating_model, grating_parameter)
    rows = {lamp.name: planner.rows(lamp) for lamp in lamps}
    scores = [
        planner.score(rows, subset)
        for size in range(1, len(lamps) + 1)
        for subset in itertools.combinations(names, size)
    ]
    return sorted(scores, key=lambda score: (score.efficiency_sigma, len(score.lamps)))


def best_additions(
    lamps: Sequence[Spectrum],
    candidates: Sequence[Spectrum],
    prior: CameraPrior,
    *,
    noise_fraction: float = DEFAULT_NOISE_FRACTION,
    efficiency_terms: int = DEFAULT_EFFICIENCY_TERMS,
    grating_model: str = "fourier",
    grating_parameter: float | None = None,
) -> list[SubsetScore]:
    """All of ``lamps`` plus each candidate in turn, best first (the first is the one to buy).

    Candidates named like one of ``lamps`` are already there and are not tried again.
    """
    names = _unique_names(lamps)
    planner = _Planner.of(prior, noise_fraction, efficiency_terms, grating_model, grating_parameter)
    rows = {lamp.name: planner.rows(lamp) for lamp in lamps}
    scored = []
    for candidate in (c for c in candidates if c.name not in rows):
        scored.append(
            planner.score(
                {**rows, candidate.name: planner.rows(candidate)}, [*names, candidate.name]
            )
        )
    return sorted(scored, key=lambda score: score.efficiency_sigma)


def recorded_model(grating: GratingEfficiency) -> tuple[str, float | None]:
    """The model and parameter a grating file records (``"fourier"`` when none was fitted)."""
    record = grating.model or {}
    kind = record.get("model")
    if kind not in PLANNING_PARAMETERS:
        return "fourier", None
    parameters = record.get("parameters") or {}
    value = parameters.get(PHYSICAL_PARAMETER_NAMES[kind])
    return str(kind), None if value is None else float(value)
