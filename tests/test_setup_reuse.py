"""Decision 0138: what a solve scope keeps of one estimate's set-up — digests of objects that cannot
change, read once; the camera prior and the η basis built once; a blurred profile made once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, Spectrum
from calib.methods.closed_form import ClosedFormOptions, joint_setup
from calib.methods.solve_scope import fingerprint, reuse, solve_scope
from calib.model import resolution
from calib.model.bases import fallback_camera_basis

MAPPING = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 99.0))


def _frozen(values: np.ndarray) -> np.ndarray:
    values.flags.writeable = False
    return values


@dataclass(frozen=True)
class _Pair:
    left: np.ndarray
    right: float


def test_digests_are_kept_only_for_what_cannot_change(monkeypatch: pytest.MonkeyPatch) -> None:
    owned = _frozen(np.array(np.linspace(0.0, 1.0, 7)))  # owns its copy
    writeable = np.linspace(0.0, 1.0, 7)
    base = np.linspace(0.0, 1.0, 7)
    view = _frozen(base[:])  # read-only, but its memory is a writeable array's
    outside = [fingerprint(value) for value in (owned, writeable, view)]
    read: list[int] = []
    scope_module = __import__("sys").modules["calib.methods.solve_scope"]
    original = scope_module._array_digest

    def counted(value: np.ndarray) -> bytes:
        read.append(value.size)
        return bytes(original(value))

    monkeypatch.setattr(scope_module, "_array_digest", counted)
    with solve_scope() as scope:
        assert scope is not None
        inside = [fingerprint(value) for value in (owned, writeable, view)]
        assert inside == outside  # the same digests as without a scope
        read.clear()
        fingerprint(owned, _Pair(owned, 1.0))
        assert read == []  # kept: neither the array nor the frozen pair of it read again
        fingerprint(writeable)
        fingerprint(view)
        assert read == [7, 7]  # read each time
        writeable[3] += 1.0
        base[3] += 1.0
        assert fingerprint(writeable) != outside[1]
        assert fingerprint(view) != outside[2]


def test_a_results_parts_are_known_by_where_they_came_from() -> None:
    """What a reuse computed is digested by its place in the result (never read again), while an
    input it passes through keeps its content digest: the same inputs still find the result."""
    given = np.linspace(0.0, 1.0, 5)  # writeable: digested by content
    calls: list[int] = []

    def compute() -> tuple[np.ndarray, np.ndarray]:
        calls.append(1)
        return given, np.full(4, float(len(calls)))

    with solve_scope() as scope:
        assert scope is not None
        passed, made = reuse("make", (given,), compute)
        assert passed is given
        assert id(made) in scope.digests and id(given) not in scope.digests
        assert reuse("make", (given.copy(),), compute)[1] is made  # same content: found
        assert reuse("make", (given,), compute)[1] is made
        after = reuse("use", (made,), lambda: float(made.sum()))
        assert reuse("use", (made,), lambda: -1.0) == after
        assert reuse("use", (made.copy(),), lambda: -1.0) == -1.0  # content, not place: new
        assert calls == [1]


def test_the_prior_and_the_efficiency_basis_are_built_once_per_scope() -> None:
    basis = fallback_camera_basis()
    rng = np.random.default_rng(0)
    observation = LampObservation(
        "LED",
        Spectrum(np.arange(380.0, 781.0, 5.0), np.ones(81)),
        np.arange(100.0),
        rng.uniform(0.1, 1.0, (100, 3)),
        direct_rgb=np.ones(3),
    )
    arguments = {
        "basis": basis,
        "grid": DEFAULT_GRID,
        "mapping": MAPPING,
        "mapping_lamp": None,
        "options": ClosedFormOptions(),
    }
    alone = joint_setup([observation], **arguments)  # type: ignore[arg-type]
    with solve_scope():
        first = joint_setup([observation], **arguments)  # type: ignore[arg-type]
        again = joint_setup([observation], **arguments)  # type: ignore[arg-type]
        fewer = joint_setup(
            [observation],
            **{**arguments, "options": ClosedFormOptions(efficiency_terms=5)},  # type: ignore[arg-type]
        )
    assert again.prior is first.prior and again.efficiency_basis is first.efficiency_basis
    assert fewer.prior is first.prior and fewer.efficiency_basis.shape[1] == 5
    assert not first.efficiency_basis.flags.writeable
    assert np.array_equal(first.prior.covariance, alone.prior.covariance)
    assert np.array_equal(first.efficiency_basis, alone.efficiency_basis)
    assert joint_setup([observation], **arguments).prior is not alone.prior  # type: ignore[arg-type]


def test_a_blurred_profile_is_made_once_for_the_same_inputs() -> None:
    rng = np.random.default_rng(1)
    wavelength = np.linspace(420.0, 680.0, 300)
    profile = rng.uniform(0.0, 1.0, (300, 3))
    sigma = rng.uniform(0.01, 0.02, (300, 3))
    matrix = resolution._wavelength_blur(wavelength, 5.0)
    fresh = matrix @ profile, np.sqrt(matrix.power(2) @ sigma**2)
    first = resolution.blurred_profile(wavelength, 5.0, profile, sigma)
    again = resolution.blurred_profile(wavelength.copy(), 5.0, profile.copy(), sigma.copy())
    assert again[0] is first[0] and again[1] is first[1]
    assert first[1] is not None
    assert np.array_equal(first[0], fresh[0]) and np.array_equal(first[1], fresh[1])
    moved = profile.copy()
    moved[10, 1] += 1e-9
    other = resolution.blurred_profile(wavelength, 5.0, moved, sigma)
    assert other[0] is not first[0] and not np.array_equal(other[0], first[0])
    assert resolution.blurred_profile(wavelength, 5.0, profile, None)[1] is None
