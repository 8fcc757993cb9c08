"""A descent's evaluation with fewer copies and calls gives the same bits (decision 0142)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import lapack

from calib.wavelength import response_model
from calib.wavelength.response_model import (
    _cholesky,
    _scale_of,
    _scale_of_columns,
    _scale_of_one,
)
from tests.led_scene import unblurred_led


def _systems(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rows = rng.normal(size=(3, 40, 12))
    return np.asarray(rows.transpose(0, 2, 1) @ rows + np.eye(12), dtype=np.float64)


def test_the_channels_factors_are_made_in_place_and_are_lapacks_to_the_bit():
    systems = _systems()
    expected = [lapack.dpotrf(channel.copy(), lower=1, clean=1)[0] for channel in systems]
    factors = _cholesky(systems)
    for channel, (factor, plain) in enumerate(zip(factors, expected, strict=True)):
        assert np.shares_memory(factor, systems[channel])  # no copy in or out
        assert factor.flags.f_contiguous  # what the triangular solve reads without a copy
        assert np.array_equal(factor, plain)


def test_a_non_positive_system_still_raises():
    systems = _systems()
    systems[1] = -systems[1]
    with pytest.raises(np.linalg.LinAlgError):
        _cholesky(systems)


@pytest.mark.parametrize("gamma", [20.0, 7.5, math.nan])
def test_one_mappings_scale_on_floats_is_the_arrays_to_the_bit(gamma):
    rng = np.random.default_rng(1)
    pulls, free = rng.normal(size=(3, 9)), rng.normal(size=(3, 9))
    along = np.abs(rng.normal(size=(3, 9)))
    if gamma == 7.5:  # a denominator of exactly zero: β = 0, as np.where's ∞ gives
        gamma = float(np.dot(pulls.reshape(1, -1), along.reshape(-1, 1))[0, 0])
    expected = np.asarray(_scale_of(pulls, gamma, free, along, 0.0))
    found = _scale_of_one(pulls, gamma, free, along)
    assert isinstance(found, float)
    assert np.array_equal(np.float64(found), expected, equal_nan=True)


@pytest.mark.parametrize("gamma", [20.0, 7.5, math.nan])
def test_the_jacobians_scale_columns_on_a_float_denominator_are_the_arrays_to_the_bit(gamma):
    """:func:`_scale_of_columns` (the Jacobian's ``∂β/∂x``) equals :func:`_scale_of` with a zero
    ``r_β``, a zero and a NaN denominator included (decision 0153)."""
    rng = np.random.default_rng(2)
    pulls, free = rng.normal(size=(3, 9)), rng.normal(size=(3, 9, 4))
    free[0, :, 1] = 0.0  # a column whose sum is zero: +0, as 0 + (−0) gives
    along = np.abs(rng.normal(size=(3, 9)))
    if gamma == 7.5:
        gamma = float(np.dot(pulls.reshape(1, -1), along.reshape(-1, 1))[0, 0])
    expected = _scale_of(pulls, gamma, free, along[..., None], np.zeros(4))
    found = _scale_of_columns(pulls, gamma, free, along)
    assert found.shape == (4,)
    assert np.array_equal(found, expected, equal_nan=True)
    assert np.array_equal(np.signbit(found), np.signbit(expected))


def test_a_descents_residual_and_jacobian_are_those_of_the_plain_steps(monkeypatch):
    """The residual and Jacobian with this decision's steps equal, to the bit, those with the
    plain ones they replace (a factor copied out of LAPACK, the scale on arrays)."""
    model, family, edges_px, truth = unblurred_led()
    x = family.parameters(truth) + np.array([0.8, -0.4, 0.6])
    edges = family.wavelengths(edges_px, x)
    jacobian = family.jacobian(edges_px)
    held = model.reference(edges)
    residual, thunk, parts = held.residual_lazy(edges, jacobian)
    assert thunk is not None
    found_jacobian = thunk()

    def copied(systems: np.ndarray) -> list[np.ndarray]:
        return [lapack.dpotrf(channel, lower=1, clean=1)[0] for channel in systems]

    def on_arrays(pulls: np.ndarray, gamma: float, free: np.ndarray, along: np.ndarray) -> float:
        return float(_scale_of(pulls, gamma, free, along, 0.0))

    monkeypatch.setattr(response_model, "_cholesky", copied)
    monkeypatch.setattr(response_model, "_scale_of_one", on_arrays)
    plain_residual, plain_thunk, plain_parts = held.residual_lazy(edges, jacobian)
    assert plain_thunk is not None
    assert np.array_equal(residual, plain_residual)
    assert np.array_equal(found_jacobian, plain_thunk())
    assert parts["beta"] == plain_parts["beta"]


def test_a_descents_model_reads_its_models_tables_instead_of_making_them_again():
    """What :meth:`ResponseModel.reference` does not change is its model's, the same objects
    (and a width one descent lays out is there for the next)."""
    model, family, edges_px, truth = unblurred_led()
    edges = family.wavelengths(edges_px, family.parameters(truth))
    first, second = model.reference(edges), model.reference(edges + 0.5)
    for name in response_model._REFERENCE_SHARED:
        assert getattr(first, name) is getattr(model, name)
        assert getattr(second, name) is getattr(model, name)
    first._normal_weights(4, True)
    assert (4, True) in second._normal_weight_cache


def test_a_rising_bands_skipped_mask_and_signs_give_what_a_mixed_batch_gives():
    """A batch of rising mappings leaves out the all-ones validity mask and signs; a batch with a
    falling mapping applies them: each mapping's band values and derivative are the same bits
    either way."""
    model, family, edges_px, truth = unblurred_led()
    x = family.parameters(truth)
    rising = family.wavelengths(edges_px, x + np.array([0.5, -0.3, 0.2]))
    falling = family.wavelengths(edges_px, x[::-1])
    assert rising[-1] > rising[0] and falling[-1] < falling[0]
    jacobian = np.broadcast_to(family.jacobian(edges_px), (2, *family.jacobian(edges_px).shape))
    mixed_edges = np.stack([rising, falling])
    mixed = model.band(mixed_edges, np.ascontiguousarray(jacobian), slopes=True)
    for row, edges in enumerate((rising, falling)):
        alone = model.band(edges[None], np.ascontiguousarray(jacobian[:1]), slopes=True)
        width = alone.values.shape[-1]
        assert np.array_equal(alone.first[0], mixed.first[row])
        assert np.array_equal(alone.values[0], mixed.values[row, :, :width])
        assert alone.derivative is not None and mixed.derivative is not None
        assert np.array_equal(alone.derivative[0], mixed.derivative[row, :, :width])
    # The falling mapping's light is |ΔC| (its sign applied), the rising one's ΔC.
    assert mixed.values[0].sum() > 0.0 and mixed.values[1].sum() > 0.0


def test_one_points_quadratic_validity_on_floats_is_the_batchs():
    """:meth:`QuadraticFamily.valid` for one point (Python floats) answers as for a batch of one:
    rising, falling, folding, flat, infinite and NaN points (decision 0153)."""
    from calib.wavelength.families import QuadraticFamily

    family = QuadraticFamily((0.0, 600.0))
    points = np.array(
        [
            [400.0, 550.0, 700.0],
            [700.0, 550.0, 400.0],
            [400.0, 720.0, 450.0],
            [500.0, 500.0, 500.0],
            [400.0, math.inf, 700.0],
            [400.0, math.nan, 700.0],
            [400.0, 400.0 + 1e-9, 700.0],
        ]
    )
    # The search never hands the family a non-finite point (StageFit screens them first); here
    # they are given on purpose, and numpy's "invalid value" warnings on them are expected.
    with np.errstate(invalid="ignore"):
        batch = family.valid(points)
        assert batch.tolist() == [True, True, False, False, False, False, False]
        for point, expected in zip(points, batch, strict=True):
            one = family.valid(point)
            assert one.shape == (1,) and one.dtype == np.bool_
            assert bool(one[0]) == bool(expected)
