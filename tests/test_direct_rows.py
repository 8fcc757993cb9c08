"""Decision 0092: :func:`calib.methods.responses.direct_rows` whitens every lamp at once; each
number is the lamp-by-lamp loop's (main before 0092, kept here as the reference) to the bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib.core.arrays import FloatArray
from calib.core.spectra import DEFAULT_GRID
from calib.methods.responses import DIRECT_GAIN_SIGMA, LampData, ResponseEstimate, direct_rows
from calib.model.forward import LampOperators, PiecewiseLinearDensity


def _per_lamp(
    lamps: list[LampData],
    inverse: FloatArray,
    gain: float,
    zeroth_order: FloatArray | None,
    floor: float,
) -> tuple[FloatArray, FloatArray]:
    """The loop before decision 0092: each lamp's block whitened by its own 3 × 3 Cholesky
    factor, written out (``math.sqrt`` on one system's floats)."""
    rows, targets = [], []
    for lamp in lamps:
        direct_row = lamp.zeroth_order_row(zeroth_order)
        spread = direct_row * inverse
        if spread.ndim == 1:
            propagated = (lamp.response.covariance @ spread) @ spread
        else:
            propagated = np.sum((lamp.response.covariance @ spread.T) * spread.T, axis=1).T
        variances = np.maximum(
            lamp.direct_sigma**2 + propagated + (floor * lamp.direct) ** 2, 1e-300
        )
        block = np.empty((*direct_row.shape[:-1], 3, direct_row.shape[-1] + 1))
        block[..., :-1] = lamp.response.response.T * direct_row[..., None, :]
        block[..., -1] = lamp.direct
        g0, g1, g2 = (gain * lamp.direct).tolist()
        if variances.ndim == 1:
            v0, v1, v2 = variances.tolist()
            l00 = math.sqrt(v0 + g0 * g0)
            l10, l20 = g1 * g0 / l00, g2 * g0 / l00
            l11 = math.sqrt(v1 + g1 * g1 - l10 * l10)
            l21 = (g2 * g1 - l20 * l10) / l11
            l22 = math.sqrt(v2 + g2 * g2 - l20 * l20 - l21 * l21)
            factors = [l00, l10, l20, l11, l21, l22]
        else:
            w0, w1, w2 = variances.T
            m00 = np.sqrt(w0 + g0 * g0)
            m10, m20 = g1 * g0 / m00, g2 * g0 / m00
            m11 = np.sqrt(w1 + g1 * g1 - m10 * m10)
            m21 = (g2 * g1 - m20 * m10) / m11
            m22 = np.sqrt(w2 + g2 * g2 - m20 * m20 - m21 * m21)
            factors = [value[:, None] for value in (m00, m10, m20, m11, m21, m22)]
        a00, a10, a20, a11, a21, a22 = factors
        out = np.empty_like(block)
        out[..., 0, :] = block[..., 0, :] / a00
        out[..., 1, :] = (block[..., 1, :] - a10 * out[..., 0, :]) / a11
        out[..., 2, :] = (block[..., 2, :] - a20 * out[..., 0, :] - a21 * out[..., 1, :]) / a22
        rows.append(out[..., :-1])
        targets.append(out[..., -1])
    return np.concatenate(rows, axis=-2), np.concatenate(targets, axis=-1)


def _lamps(rng: np.random.Generator, count: int, with_operators: bool = True) -> list[LampData]:
    grid = DEFAULT_GRID
    size = grid.size
    axis = np.linspace(grid.start_nm, grid.stop_nm, 301)
    lamps = []
    for index in range(count):
        scale = 10.0 ** rng.uniform(-3, 3)
        density = scale * rng.uniform(0.1, 1.0, (axis.size, size))
        operators = LampOperators(
            grid, PiecewiseLinearDensity.on_axis(axis, density), scale * rng.uniform(1, 5, size)
        )
        response = rng.uniform(0.05, 1.0, (size, 3))
        factor = rng.normal(size=(3, size, size)) * 10.0 ** rng.uniform(-4, -1)
        covariance = factor @ factor.transpose(0, 2, 1)
        direct = operators.direct_row @ response * rng.uniform(0.9, 1.1, 3)
        lamps.append(
            LampData(
                f"lamp {index}",
                operators.direct_row,
                ResponseEstimate(response, covariance, np.ones(size, bool), 1.0),
                direct,
                direct * rng.uniform(0.0, 0.01, 3),
                operators if with_operators else None,
            )
        )
    return lamps


@pytest.mark.parametrize("zeroth", ["none", "one", "scan"])
def test_all_lamps_at_once_are_the_lamp_by_lamp_whitening_to_the_bit(zeroth: str) -> None:
    rng = np.random.default_rng(92)
    for trial in range(6):
        lamps = _lamps(rng, 1 + trial)
        size = DEFAULT_GRID.size
        inverse = rng.uniform(0.5, 3.0, size)
        axis = lamps[0].operators.axis_nm if lamps[0].operators is not None else None
        assert axis is not None
        zeroth_order = {
            "none": None,
            "one": rng.uniform(0.1, 1.0, axis.size),
            "scan": rng.uniform(0.1, 1.0, (17, axis.size)),
        }[zeroth]
        for gain, floor in ((DIRECT_GAIN_SIGMA, 1e-3), (0.0, 0.02)):
            expected = _per_lamp(lamps, inverse, gain, zeroth_order, floor)
            got = direct_rows(
                lamps, inverse, gain_sigma=gain, zeroth_order=zeroth_order, floor=floor
            )
            for value, reference in zip(got, expected, strict=True):
                assert value.shape == reference.shape
                assert value.flags.c_contiguous
                np.testing.assert_array_equal(value, reference)
            # The same lamps again (their stack kept): the same numbers.
            again = direct_rows(
                lamps, inverse, gain_sigma=gain, zeroth_order=zeroth_order, floor=floor
            )
            np.testing.assert_array_equal(again[0], expected[0])


def test_lamps_without_operators_take_their_plain_row_as_before() -> None:
    """A lamp without its fine-axis operators keeps its plain direct row under an ``η₀``; mixed
    with lamps that have them, every row is still the loop's."""
    rng = np.random.default_rng(7)
    lamps = _lamps(rng, 2) + _lamps(rng, 2, with_operators=False)
    inverse = rng.uniform(0.5, 3.0, DEFAULT_GRID.size)
    zeroth_order = rng.uniform(0.1, 1.0, 301)
    expected = _per_lamp(lamps, inverse, DIRECT_GAIN_SIGMA, zeroth_order, 1e-3)
    got = direct_rows(lamps, inverse, zeroth_order=zeroth_order)
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])
    # The lamps' order is the rows' order.
    swapped = direct_rows(lamps[::-1], inverse, zeroth_order=zeroth_order)
    np.testing.assert_array_equal(swapped[0][:3], expected[0][-3:])


def test_one_g_over_a_few_lamps_whitens_on_floats_without_the_stacked_path(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Decision 0116: one ``g`` over up to :data:`FLOAT_LAMPS` lamps (the physical fit's
    refinement) is whitened lamp by lamp on Python floats, never through the stacked
    :func:`_whiten_three`; its numbers are the lamp-by-lamp loop's to the bit."""
    from calib.methods import responses

    rng = np.random.default_rng(116)
    lamps = _lamps(rng, 3)
    inverse = rng.uniform(0.5, 3.0, DEFAULT_GRID.size)
    zeroth_order = rng.uniform(0.1, 1.0, 301)
    expected = _per_lamp(lamps, inverse, DIRECT_GAIN_SIGMA, zeroth_order, 1e-3)

    def stacked(*_: object) -> None:
        raise AssertionError("the stacked whitening was used for one g over three lamps")

    monkeypatch.setattr(responses, "_whiten_three", stacked)
    got = direct_rows(lamps, inverse, zeroth_order=zeroth_order)
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])


def test_a_factor_singular_in_floating_point_gives_the_stacked_paths_numbers() -> None:
    """A lamp whose only error is its direct-to-profile gain (no σ, no covariance, no floor):
    ``v + g² − l₁₀²`` rounds to 0, a factor is 0 and Python's division raises where numpy's gives
    ±inf/NaN. The float path hands such a lamp to the stacked path, whose numbers (and
    non-finite values) it then returns, instead of raising."""
    from calib.methods import responses

    rng = np.random.default_rng(3)
    lamps = _lamps(rng, 2)
    degenerate = [
        LampData(
            lamp.name,
            lamp.direct_row,
            ResponseEstimate(
                lamp.response.response,
                np.zeros_like(lamp.response.covariance),
                lamp.response.used_pixels,
                lamp.response.chi2,
            ),
            lamp.direct,
            np.zeros(3),
            lamp.operators,
        )
        for lamp in lamps
    ]
    inverse = rng.uniform(0.5, 3.0, DEFAULT_GRID.size)
    stack = responses._lamp_stack(degenerate)
    direct = stack.direct
    variances = np.maximum(stack.direct_sigma2 + 0.0 + (0.0 * direct) ** 2, 1e-300)
    block = np.empty((*stack.direct_row.shape[:-1], 3, stack.direct_row.shape[-1] + 1))
    block[..., :-1] = stack.response * stack.direct_row[..., None, :]
    block[..., -1] = direct
    with np.errstate(divide="ignore", invalid="ignore"):
        whitened = responses._whiten_three(variances, DIRECT_GAIN_SIGMA * direct, block)
        rows, targets = direct_rows(degenerate, inverse, floor=0.0)
    assert not np.all(np.isfinite(whitened))  # the case this test is about
    np.testing.assert_array_equal(rows, whitened[..., :-1].reshape(6, -1))
    np.testing.assert_array_equal(targets, whitened[..., -1].reshape(6))
