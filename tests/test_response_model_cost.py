"""What a model's build and a scan's evaluation no longer redo give the plain numbers (decision 0131)."""

from __future__ import annotations

import gc
from dataclasses import replace

import numpy as np
import pytest

from calib.core.lamp_specs import colour_lamp
from calib.core.spectra import DEFAULT_GRID, Spectrum, WavelengthGrid
from calib.model.bases import fallback_camera_basis
from calib.wavelength import response_model
from calib.wavelength.response_model import (
    LampColumns,
    NodeLayout,
    ResponseModel,
    hat_averages,
    response_prior,
    shared_response_prior,
)
from tests.led_scene import unblurred_led


@pytest.fixture(scope="module")
def scene():
    model, family, edges_px, truth = unblurred_led()
    x = family.parameters(truth) + np.array([0.8, -0.4, 0.6])
    edges = np.stack(
        [
            family.wavelengths(edges_px, x),
            family.wavelengths(edges_px, x + np.array([-2.0, 1.5, 0.5])),
            family.wavelengths(edges_px, x[::-1]),  # falling
        ]
    )
    return model, edges


def _dense_columns(
    lamp: Spectrum, layout: NodeLayout, fine_step_nm: float
) -> tuple[np.ndarray, np.ndarray]:
    """The lamp's column table as it was built before: every node's hat on the whole fine axis."""
    lo = float(layout.piece_bounds[:, 0].min())
    hi = float(layout.piece_bounds[:, 1].max())
    count = round((hi - lo) / fine_step_nm) + 1
    axis = lo + fine_step_nm * np.arange(count, dtype=np.float64)
    lamp_fine = hat_averages(lamp, lo, fine_step_nm, count)
    nodes = layout.nodes_nm
    hats = np.clip(1.0 - np.abs(axis[:, None] - nodes[None, :]) / layout.step_nm, 0.0, None)
    outside = (axis[:, None] < layout.piece_bounds[None, :, 0] - 1e-9) | (
        axis[:, None] > layout.piece_bounds[None, :, 1] + 1e-9
    )
    hats[outside] = 0.0
    density = lamp_fine[:, None] * hats
    cumulative = np.zeros_like(density)
    cumulative[1:] = np.cumsum(0.5 * (density[1:] + density[:-1]) * fine_step_nm, axis=0)
    return density, cumulative


@pytest.mark.parametrize(
    ("grid", "margin_nm", "node_step_nm", "fine_step_nm"),
    [
        (DEFAULT_GRID, 30.0, 10.0, 1.0),
        (DEFAULT_GRID, 30.0, 5.0, 0.1),
        (DEFAULT_GRID, 13.0, 10.0, 0.25),  # margins shorter than a node step: cut hats
        (WavelengthGrid(420.0, 680.0, 5.0), 47.0, 20.0, 0.2),
        (WavelengthGrid(420.0, 680.0, 5.0), 0.0, 10.0, 0.5),  # no margins at all
    ],
)
def test_the_lamps_column_table_from_each_hats_block_is_the_dense_one_to_the_bit(
    grid, margin_nm, node_step_nm, fine_step_nm
):
    """Each column's density and cumulative integral computed over its hat's block of fine nodes
    only: the whole table equal to the dense build's, bit for bit (a comb lamp: zeros inside the
    supports, a line between fine nodes)."""
    wavelength = np.arange(350.0, 800.05, 0.1)
    values = 1.0 + np.sin(wavelength / 7.0) ** 2
    values[(wavelength > 500.0) & (wavelength < 520.0)] = 0.0
    values[np.abs(wavelength - 546.07) < 0.06] = 50.0
    lamp = Spectrum(wavelength, values, name="comb")
    lo = max(grid.start_nm - margin_nm, lamp.range_nm[0])
    hi = min(grid.stop_nm + margin_nm, lamp.range_nm[1])
    layout = NodeLayout.build(grid, (lo, hi), node_step_nm)
    columns = LampColumns.build(lamp, layout, fine_step_nm)
    density, cumulative = _dense_columns(lamp, layout, fine_step_nm)
    assert np.array_equal(columns.density, density)
    assert np.array_equal(columns.cumulative, cumulative)


def test_the_column_table_never_forms_the_whole_axis_by_nodes_hats(monkeypatch):
    """The block build's cumulative sums run over a hat's few fine nodes, not the whole axis."""
    lamp = Spectrum(np.arange(350.0, 800.05, 0.5), np.ones(901), name="flat")
    layout = NodeLayout.build(DEFAULT_GRID, (370.0, 760.0), 5.0)
    summed: list[tuple[int, ...]] = []
    cumsum = np.cumsum

    def counting(array, *args, **kwargs):
        summed.append(np.shape(array))
        return cumsum(array, *args, **kwargs)

    monkeypatch.setattr(np, "cumsum", counting)
    columns = LampColumns.build(lamp, layout, 0.1)
    rows = columns.density.shape[0]
    assert rows > 3000
    assert summed and all(shape[0] < 110 for shape in summed if len(shape) == 2)


def test_the_response_prior_is_whitened_once_per_prior_nodes_and_flexibility():
    prior = fallback_camera_basis().prior()
    nodes = DEFAULT_GRID.start_nm + 10.0 * np.arange(31.0)
    mean, factors = shared_response_prior(prior, nodes, 0.05)
    plain_mean, plain_factors = response_prior(prior, nodes, 0.05)
    assert np.array_equal(mean, plain_mean) and np.array_equal(factors, plain_factors)
    again = shared_response_prior(prior, nodes.copy(), 0.05)
    assert again[0] is mean and again[1] is factors
    assert not (mean.flags.writeable or factors.flags.writeable)
    other = shared_response_prior(prior, nodes, 2.0)
    assert other[1] is not factors
    assert np.array_equal(other[1], response_prior(prior, nodes, 2.0)[1])


def test_the_shared_prior_goes_with_its_prior():
    prior = fallback_camera_basis().prior()
    shared_response_prior(prior, DEFAULT_GRID.start_nm + 10.0 * np.arange(31.0), 0.05)
    assert prior in response_model._PRIOR_CACHE
    count = len(response_model._PRIOR_CACHE)
    del prior
    gc.collect()
    assert len(response_model._PRIOR_CACHE) == count - 1


def test_two_lamps_models_under_one_prior_whiten_it_once():
    """A stage's LED and fluorescent models (the same nodes and flexibility) share the prior's
    terms: one entry for the prior, and each model's working block is that entry's."""
    model, _, _, _ = unblurred_led()
    prior = fallback_camera_basis().prior()
    built = [
        ResponseModel.build(
            replace(model.observation, spectrum=colour_lamp(name)),
            DEFAULT_GRID,
            node_step_nm=10.0,
            prior=prior,
            flexibility=0.05,
        )
        for name in ("D65", "FL2")
    ]
    assert len(response_model._PRIOR_CACHE[prior]) == 1
    ((_, factors),) = response_model._PRIOR_CACHE[prior].values()
    for one in built:
        assert np.array_equal(one.prior_factor[:, :, one.layout.working], factors)


def test_a_scans_normal_sums_in_one_bincount_per_channel_are_the_separate_ones_to_the_bit(
    scene, monkeypatch
):
    """The diagonals and right-hand sides from one ``bincount`` per channel: the same bits as
    the pair products' and the band values' own ``bincount`` each, on both layouts (a batch's
    pixels-last products and one mapping's gathered ones)."""
    model, edges = scene
    calls: list[int] = []
    bincount = np.bincount

    def counting(*args, **kwargs):
        calls.append(1)
        return bincount(*args, **kwargs)

    for small_band in (response_model.SMALL_BAND, 0):
        monkeypatch.setattr(response_model, "SMALL_BAND", small_band)
        band = model.band(edges)
        values, first = band.values, band.first
        batch, _, width = values.shape
        size = model.n_nodes
        lows, offsets = response_model._band_pairs(width)
        products = values[..., lows] * values[..., lows + offsets]
        place = (
            (np.arange(batch) * (size * width))[:, None, None]
            + first[:, :, None] * width
            + (lows * width + offsets)
        ).ravel()
        entries = (
            first[:, :, None] + np.arange(width) + (np.arange(batch) * size)[:, None, None]
        ).ravel()
        squared = model.weights**2
        weighted_target = model.weights * model.target
        expected_diagonals = np.stack(
            [
                np.bincount(
                    place,
                    weights=(products * squared[None, :, c, None]).ravel(),
                    minlength=batch * size * width,
                ).reshape(batch, size, width)
                for c in range(3)
            ],
            axis=1,
        )
        expected_rhs = np.stack(
            [
                np.bincount(
                    entries,
                    weights=(values * weighted_target[None, :, c, None]).ravel(),
                    minlength=batch * size,
                ).reshape(batch, size)
                for c in range(3)
            ],
            axis=1,
        )
        calls.clear()
        monkeypatch.setattr(np, "bincount", counting)
        diagonals, rhs = model._normal(band)
        monkeypatch.setattr(np, "bincount", bincount)
        assert len(calls) == 3
        assert np.array_equal(diagonals, expected_diagonals)
        assert np.array_equal(rhs, expected_rhs)
        assert np.array_equal(model._normal_diagonals(band), expected_diagonals)


def test_the_bordered_systems_from_the_padded_precision_are_the_plain_ones(scene):
    model, edges = scene
    band = model.band(edges)
    diagonals, rhs = model._normal(band)
    scale = model._prior_scale_from_normal(diagonals, rhs)
    weight = model._penalty_weight(diagonals)
    bordered, pulls, gamma = model._systems(diagonals, scale, weight, rhs)
    plain, plain_pulls, plain_gamma = model._systems(diagonals, scale, weight)
    size = model.n_nodes
    assert np.array_equal(bordered[..., :size, :size], plain)
    assert np.array_equal(bordered[..., :size, size], rhs)
    assert np.array_equal(bordered[..., size + 1, :size], pulls)
    assert np.all(bordered[..., size, size + 1] == 0.0)
    assert np.all(bordered[..., size + 1, size] == 0.0)
    assert np.array_equal(pulls, plain_pulls) and np.array_equal(gamma, plain_gamma)


def test_a_model_built_twice_costs_the_same(scene):
    """A second build (its prior terms from the cache) gives the same costs to the bit."""
    model, edges = scene
    again = ResponseModel.build(
        model.observation,
        DEFAULT_GRID,
        node_step_nm=10.0,
        prior=fallback_camera_basis().prior(),
        flexibility=0.05,
    )
    assert np.array_equal(again.costs(edges), model.costs(edges))
