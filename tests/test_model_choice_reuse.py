"""The grating model's choice inside a solve scope (decision 0137): the lamps' content is digested
once for the choice's key and both physical fits', and the jackknife of a fit the σ budget's
η-terms re-solve asks for again is the main solve's — every number the one a fresh solve gives."""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest

import calib.methods.multilamp as multilamp
from calib.methods.grating_models import with_jackknife
from calib.methods.multilamp import EfficiencySettings, prepare_lamps, solve_efficiency
from calib.methods.responses import LampData
from calib.methods.solve_scope import perturbation, solve_scope
from calib.model.bases import CameraBasis
from calib.model.gratings import SinusoidalPhaseGrating
from tests.test_grating_models import MAPPING, _order, _scene
from tests.test_grating_models import basis as basis

# The module itself (the package's attribute of that name is the function).
solve_scope_module = sys.modules["calib.methods.solve_scope"]

# A basis, two prepared lamps and five grating-model solves: several seconds.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lamps(basis: CameraBasis) -> list[LampData]:
    grating = SinusoidalPhaseGrating(1.0)
    _, observations = _scene(
        _order(grating, 1), _order(grating, 0), lamps=("LED-B3", "FL2"), noise=0.01
    )
    return list(prepare_lamps(observations, basis=basis, mapping=MAPPING).lamps)


def _arrays(solution: multilamp.EfficiencySolution) -> list[np.ndarray]:
    return [
        solution.inverse_efficiency,
        solution.coefficients,
        solution.coefficient_covariance,
        solution.noise_covariance,
        solution.inverse_jacobian,
    ]


def test_the_choice_digests_each_lamp_once(
    lamps: list[LampData],
    basis: CameraBasis,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``auto`` in a scope: one digest of the lamps for the choice's key and both physical fits'
    (before: five, one per look-up and store); the answer a solve outside any scope gives."""
    prior = basis.prior()
    fresh = solve_efficiency(lamps, prior)
    digested: list[int] = []
    feed = solve_scope_module._feed

    def counting(digest: object, value: object, scope: object = None) -> bool:
        if isinstance(value, LampData):
            digested.append(id(value))
        return bool(feed(digest, value, scope))

    monkeypatch.setattr(solve_scope_module, "_feed", counting)
    with solve_scope() as scope:
        assert scope is not None
        solved = solve_efficiency(lamps, prior)
        assert sorted(digested) == sorted(id(lamp) for lamp in lamps)
        assert solve_efficiency(lamps, prior) is solved  # the choice's key still finds it
    assert set(solved.info["grating_model"]["predictive_risk"]) == {
        "fourier",
        "sinusoidal",
        "blazed",
    }
    for mine, theirs in zip(_arrays(solved), _arrays(fresh), strict=True):
        assert np.array_equal(mine, theirs)


def test_the_eta_terms_re_solve_shares_the_main_solve_s_jackknife(
    lamps: list[LampData],
    basis: CameraBasis,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The budget's η-terms re-solve keeps ``auto``'s physical choice and changes only the
    Fourier terms: its fit is the main solve's, and so is that fit's leave-one-lamp-out
    jackknife (one refit per lamp, not two). Other lamps jackknife afresh."""
    prior = basis.prior()
    settings = EfficiencySettings(grating_model="sinusoidal")
    fewer = replace(settings, terms=5)
    fresh = solve_efficiency(lamps, prior, fewer)  # no scope: everything computed
    calls: list[int] = []
    jackknife = with_jackknife

    def counted(*args: object, **kwargs: object) -> object:
        calls.append(1)
        return jackknife(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(multilamp, "with_jackknife", counted)
    with solve_scope():
        main = solve_efficiency(lamps, prior, settings)
        with perturbation():
            again = solve_efficiency(lamps, prior, fewer)
        assert len(calls) == 1
        assert again is not main  # its own solve (another key), the jackknife shared
        solve_efficiency([*lamps[:1], replace(lamps[1], direct=lamps[1].direct * 1.01)], prior)
        assert len(calls) == 2
    jackknife_sigma = again.info["grating_model"]["jackknife_sigma"]
    assert jackknife_sigma is not None and jackknife_sigma > 0
    assert jackknife_sigma == fresh.info["grating_model"]["jackknife_sigma"]
    for mine, theirs in zip(_arrays(again), _arrays(fresh), strict=True):
        assert np.array_equal(mine, theirs)
