"""calib.methods.solve_scope: the σ budget's re-solves share the estimate's work and say the same.

The shared path (identical sub-solves reused, perturbation re-solves warm-started) is compared with
every re-solve from scratch (``BudgetSettings(reuse_solves=False)``) on noisy scenes through
physical gratings, for the prior solve and multilamp; each comparison also checks that the shared
path was taken (reuses and warm starts counted), so a test cannot pass by running the slow path
twice.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.lamp_specs import lamp_from_spec
from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampKind, LampObservation
from calib.core.spectra import MultiSpectrum
from calib.methods import BudgetSettings, estimate
from calib.methods.multilamp import physical_fit
from calib.methods.responses import lamp_data, prepared_response
from calib.methods.solve_scope import (
    fingerprint,
    perturbation,
    remember_start,
    reuse,
    solve_scope,
    warm_start,
)
from calib.model.bases import CameraBasis, fallback_camera_basis
from calib.model.forward import PeakFractionNoise, render_observation
from calib.model.gratings import BlazedGrating, SinusoidalPhaseGrating
from calib.model.linear_model import prepare_lamp

TRUTH = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
Grating = SinusoidalPhaseGrating | BlazedGrating


@pytest.fixture(scope="module")
def camera() -> MultiSpectrum:
    return find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity


@pytest.fixture(scope="module")
def basis() -> CameraBasis:
    return fallback_camera_basis(exclude=["Canon EOS 5D Mark II"])


def _lamp(
    spec: str,
    camera: MultiSpectrum,
    grating: Grating,
    seed: int,
    kind: LampKind = "other",
    bandwidth_nm: float | None = 4.0,
) -> LampObservation:
    def order(m: int) -> Callable[[np.ndarray], np.ndarray]:
        return lambda wavelength: grating.efficiency(m, wavelength)

    rendered = render_observation(
        lamp_from_spec(spec),
        camera,
        mapping=TRUTH,
        pixel=800,
        grating_efficiency=order(1),
        zeroth_order_efficiency=order(0),
        noise=PeakFractionNoise(0.01, 0.001),
        rng=np.random.default_rng(seed),
        kind=kind,
        name=spec,
    )
    return replace(rendered.observation, spectrum_bandwidth_nm=bandwidth_nm)


SCENES: dict[str, tuple[str, list[tuple[str, LampKind, float | None]], Grating]] = {
    "prior, LED, sinusoidal": ("prior", [("LED-B3", "other", 4.0)], SinusoidalPhaseGrating(1.2)),
    "prior, LED + FL, blazed": (
        "prior",
        [("LED-B3", "other", 4.0), ("FL2", "fluorescent", None)],
        BlazedGrating(500.0),
    ),
    "multilamp, 4 lamps, blazed": (
        "multilamp",
        # A slit of twice the spectra's 5 nm samples (a 4 nm slit at 5 nm is undersampled: the
        # spectra are matched at 10 nm whatever the slit, and its σ component nearly vanishes).
        [
            ("LED-B3", "other", 10.0),
            ("A", "other", 10.0),
            ("D65", "other", 10.0),
            ("FL2", "fluorescent", 10.0),
        ],
        BlazedGrating(450.0),
    ),
}


@pytest.mark.parametrize("scene", list(SCENES))
def test_shared_re_solves_state_the_sigma_of_full_re_solves(
    scene: str, camera: MultiSpectrum, basis: CameraBasis
) -> None:
    method, specs, grating = SCENES[scene]
    lamps = [
        _lamp(spec, camera, grating, seed, kind, bandwidth)
        for seed, (spec, kind, bandwidth) in enumerate(specs)
    ]
    full = estimate(
        lamps, method, basis=basis, mapping=TRUTH, budget=BudgetSettings(reuse_solves=False)
    )
    with solve_scope() as scope:
        fast = estimate(lamps, method, basis=basis, mapping=TRUTH)
    # Shared: the re-solves start from the estimate's solution and answer identical sub-solves
    # once (none left when the kept grating model, decision 0042, is the Fourier one: the η-model
    # perturbation changes its terms).
    assert scope is not None and scope.warm_started > 0
    assert scope.reused > 0 or fast.diagnostics["grating_model"]["chosen"] == "fourier"
    assert full.sensitivity_sigma is not None and fast.sensitivity_sigma is not None
    np.testing.assert_array_equal(fast.sensitivity, full.sensitivity)  # the main solve as before
    full_rms = full.quality.uncertainty["rms"]
    fast_rms = fast.quality.uncertainty["rms"]
    perturbed = ("spectrometer scale", "spectrometer bandwidth")
    assert all(full_rms[name] > 1e-4 for name in perturbed)  # nothing compared at zero
    for name, value in full_rms.items():
        assert fast_rms[name] == pytest.approx(value, rel=0.03, abs=1e-6), name
    difference = fast.sensitivity_sigma - full.sensitivity_sigma
    assert np.sqrt(np.mean(difference**2)) <= 0.02 * np.sqrt(np.mean(full.sensitivity_sigma**2))


def test_a_scope_reuses_only_equal_content() -> None:
    calls: list[int] = []

    def compute() -> int:
        calls.append(1)
        return len(calls)

    values = np.linspace(0.0, 1.0, 5)
    with solve_scope() as scope:
        assert scope is not None
        first = reuse("solve", (values, 1.5), compute)
        assert reuse("solve", (values.copy(), 1.5), compute) == first  # same content: reused
        changed = values.copy()
        changed[2] += 1e-12
        assert reuse("solve", (changed, 1.5), compute) == 2  # one value changed: solved again
        assert reuse("other", (values, 1.5), compute) == 3  # another sub-solve
        assert scope.reused == 1
    assert reuse("solve", (values, 1.5), compute) == 4  # outside a scope nothing is kept
    assert fingerprint(values) != fingerprint(values.astype(np.float32))
    with pytest.raises(TypeError, match="no content digest"):
        fingerprint(object())


def test_warm_starts_only_inside_a_perturbation_and_never_without_sharing() -> None:
    with solve_scope():
        remember_start("fit", 1.0)
        assert warm_start("fit") is None  # the main solve starts from scratch
        with perturbation():
            remember_start("fit", 9.0)  # a re-solve records nothing
            assert warm_start("fit") == 1.0
            with solve_scope(shared=False):
                assert warm_start("fit") is None
        assert warm_start("fit") is None


def test_a_start_in_the_wrong_basin_falls_back_to_the_full_scan(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    grating = SinusoidalPhaseGrating(1.2)
    observation = _lamp("LED-B3", camera, grating, 0)
    lamps = [lamp_data(prepare_lamp(observation, basis.grid), TRUTH)]
    wavelength = basis.grid.wavelength_nm
    full = physical_fit(lamps, "sinusoidal", wavelength, 0.02)
    with solve_scope() as scope:
        assert scope is not None
        remember_start("physical sinusoidal: LED-B3", 0.55)  # far from the truth
        with perturbation():
            warm = physical_fit(lamps, "sinusoidal", wavelength, 0.02)
        assert scope.warm_started == 1
    assert warm.parameter == pytest.approx(full.parameter, rel=1e-5)
    assert warm.parameter == pytest.approx(1.2, rel=0.05)


def test_a_lamp_is_prepared_and_its_response_fitted_once_per_scope(
    camera: MultiSpectrum, basis: CameraBasis
) -> None:
    """Decision 0107: inside a scope, :func:`prepared_response` of the same observation, mapping,
    grid and kernel is the pair already made (the σ budget's η-terms re-solve); another mapping,
    or no scope, makes it afresh — with the same numbers as a fresh pair."""
    observation = _lamp("LED-B3", camera, SinusoidalPhaseGrating(1.2), 0)
    grid = basis.grid
    fresh_system, fresh = prepared_response(observation, TRUTH, grid, None)
    assert prepared_response(observation, TRUTH, grid, None)[1] is not fresh  # no scope
    moved = replace(TRUTH, c=TRUTH.c + 1e-9)
    with solve_scope() as scope:
        assert scope is not None
        system, response = prepared_response(observation, TRUTH, grid, None)
        again_system, again = prepared_response(observation, TRUTH, grid, None)
        assert again is response and again_system is system
        assert scope.reused == 1
        assert prepared_response(observation, moved, grid, None)[1] is not response
        assert scope.reused == 1
    assert np.array_equal(response.response, fresh.response)
    assert np.array_equal(response.covariance, fresh.covariance)
    assert np.array_equal(system.operators.direct_row, fresh_system.operators.direct_row)
    # Metadata no digest reads (a reader's object): made, not shared, never an error.
    odd = replace(observation, metadata={"reader": object()})
    with solve_scope() as scope:
        assert scope is not None
        first = prepared_response(odd, TRUTH, grid, None)[1]
        assert prepared_response(odd, TRUTH, grid, None)[1] is not first
        assert scope.reused == 0
        with pytest.raises(TypeError):
            reuse("strict", (odd,), lambda: None)
    assert np.array_equal(first.response, fresh.response)
