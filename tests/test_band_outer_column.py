"""A scan's batch holds its band's last column apart: the same band values and an exact zero in
every row left out; the normal sums and costs of the full band up to rounding (decision 0157)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.wavelength import response_model
from tests.led_scene import unblurred_led


@pytest.fixture(scope="module")
def scan():
    """The shared unblurred LED scene's model and a batch of 25 trial mappings about an offset
    point, one of them falling (the band's signs)."""
    model, family, edges_px, truth = unblurred_led()
    x = family.parameters(truth) + np.array([0.8, -0.4, 0.6])
    steps = np.linspace(-2.0, 2.0, 5)
    points = [x + np.array([a, b, 0.3 * a]) for a in steps for b in steps]
    points[-1] = x[::-1]
    edges = np.stack([family.wavelengths(edges_px, point) for point in points])
    assert edges[-1, -1] < edges[-1, 0] and edges[0, -1] > edges[0, 0]
    return model, edges


def test_the_last_column_held_apart_is_the_bands_and_zero_where_left_out(scan):
    model, edges = scan
    full = model._band_values(edges)
    apart = model._band_values(edges, outer=True)
    assert full.outer is None and apart.outer is not None
    width = full.values.shape[-1]
    assert width >= 3 and apart.values.shape[-1] == width - 1
    assert np.array_equal(apart.values, full.values[..., :-1])
    assert np.array_equal(apart.first, full.first)
    rows, values = apart.outer
    last = full.values[..., -1].reshape(-1)
    assert 0 < rows.size < last.size // 4  # few rows: the junctions' pixels
    assert np.array_equal(values, last[rows])
    left_out = np.ones(last.size, dtype=bool)
    left_out[rows] = False
    assert np.all(last[left_out] == 0.0)
    # Some left-out pixels' nominal span would have reached the column without the check.
    assert np.any(values != 0.0)


@pytest.mark.parametrize("with_rhs", [True, False])
def test_the_normal_sums_with_the_column_apart_are_the_full_bands_to_rounding(scan, with_rhs):
    model, edges = scan
    full = model._normal_sums(model._band_values(edges), with_rhs=with_rhs)
    apart = model._normal_sums(model._band_values(edges, outer=True), with_rhs=with_rhs)
    assert full[0].shape == apart[0].shape
    np.testing.assert_allclose(apart[0], full[0], rtol=1e-13, atol=1e-13 * np.abs(full[0]).max())
    if with_rhs:
        assert full[1] is not None and apart[1] is not None
        np.testing.assert_allclose(
            apart[1], full[1], rtol=1e-13, atol=1e-13 * np.abs(full[1]).max()
        )


def test_a_scans_costs_take_the_column_apart_from_its_size_on(scan, monkeypatch):
    model, edges = scan
    monkeypatch.setattr(response_model, "OUTER_FROM", edges.size * 2)
    whole = model.costs(edges)
    monkeypatch.setattr(response_model, "OUTER_FROM", 0)
    seen: list[bool] = []
    original = response_model.ResponseModel._normal_sums

    def spy(self, band, *, with_rhs):
        seen.append(band.outer is not None)
        return original(self, band, with_rhs=with_rhs)

    monkeypatch.setattr(response_model.ResponseModel, "_normal_sums", spy)
    held = model.costs(edges)
    assert seen == [True]
    np.testing.assert_allclose(held, whole, rtol=1e-12)
