"""The response model's faster layouts give the numbers of the plain ones (decision 0070)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calib.wavelength import response_model
from calib.wavelength.response_model import RIDGE, SHARED_EDGES_FROM, ResponseModel
from tests.led_scene import unblurred_led


@pytest.fixture(scope="module")
def unblurred():
    """The shared unblurred LED scene and its model: the band's pixels-last path."""
    model, family, edges_px, truth = unblurred_led()
    x = family.parameters(truth) + np.array([0.8, -0.4, 0.6])
    return model, family, edges_px, x


def _batch(family, edges_px, x):
    """Three mappings: off the truth, further off, and one falling."""
    return np.stack(
        [
            family.wavelengths(edges_px, x),
            family.wavelengths(edges_px, x + np.array([-2.0, 1.5, 0.5])),
            family.wavelengths(edges_px, x[::-1]),
        ]
    )


def test_the_pixels_last_band_is_the_pixel_by_pixel_one_to_the_last_bit(unblurred):
    model, family, edges_px, x = unblurred
    assert model.filter.size <= SHARED_EDGES_FROM
    edges = _batch(family, edges_px, x)
    band = model.band(edges)
    windows, _ = model._windows(edges)
    columns = np.minimum(band.columns, model.n_nodes - 1)
    direct, _ = model.columns.evaluate(windows[..., None, :], columns[..., None])
    signs = np.where(edges[:, -1] >= edges[:, 0], 1.0, -1.0)[:, None, None]
    expected = np.einsum("knwl,l->knw", direct, model.filter) * (band.columns < model.n_nodes)
    np.testing.assert_array_equal(band.values, expected * signs)


def test_small_and_large_batches_form_the_same_normal_matrices(unblurred, monkeypatch):
    """The pair products gathered along the band (one mapping) and pixels last (a scan's batch)
    are the same numbers, summed in the same order."""
    model, family, edges_px, x = unblurred
    band = model.band(_batch(family, edges_px, x))
    monkeypatch.setattr(response_model, "SMALL_BAND", 0)
    pixels_last = model._normal(band)
    monkeypatch.setattr(response_model, "SMALL_BAND", band.values.size)
    along_band = model._normal(band)
    for one, other in zip(pixels_last, along_band, strict=True):
        np.testing.assert_array_equal(one, other)


def test_the_band_layout_is_kept_per_width(unblurred):
    model, family, edges_px, x = unblurred
    band = model.band(_batch(family, edges_px, x))
    width = band.values.shape[-1]
    model._systems(*_normal_and_scale(model, band))
    kept = model._band_layout(width)
    assert model._band_layout(width) is kept
    positions = kept[0]
    assert positions.size == np.unique(positions).size  # each entry written once


def _normal_and_scale(model, band):
    diagonals, _ = model._normal(band)
    return diagonals, model._prior_scale(band), model._penalty_weight(diagonals)


def test_one_mappings_dense_systems_are_the_batchs_up_to_rounding(unblurred):
    """:meth:`ResponseModel.residual_lazy` forms one mapping's normal matrices from its dense
    matrix and the held prior and penalty terms: the fitted response is the batch path's (banded
    normal matrices, systems written diagonal by diagonal) to rounding, and the reference's
    penalty weights are :meth:`_penalty_weight`'s."""
    model, family, edges_px, x = unblurred
    at = family.wavelengths(edges_px, x)
    fixed = model.reference(at)
    band = model.band(at[None])
    diagonals, rhs = model._normal(band)
    assert fixed.penalty_weight is not None
    np.testing.assert_allclose(
        fixed.penalty_weight, model._penalty_weight(diagonals)[0], rtol=1e-13
    )
    for where in (at, family.wavelengths(edges_px, x + np.array([0.3, -0.2, 0.1]))):
        _, _, parts = fixed.residual(where)
        band = model.band(where[None])
        diagonals, rhs = model._normal(band)
        systems, pulls, gamma = fixed._systems(
            diagonals, np.array([fixed.scale]), fixed.penalty_weight[None]
        )
        solved = np.linalg.solve(systems[0], np.stack([rhs[0], pulls[0]], axis=-1))
        free, along = solved[..., 0], solved[..., 1]
        beta = np.sum(pulls[0] * free) / (gamma[0] - np.sum(pulls[0] * along))
        np.testing.assert_allclose(parts["beta"], beta, rtol=1e-10)
        np.testing.assert_allclose(
            parts["response"], free + beta * along, rtol=1e-9, atol=1e-12 * np.abs(free).max()
        )
    # The held terms are the reference's own (a copy with other weights recomputes them).
    other = replace(fixed, penalty_weight=2.0 * fixed.penalty_weight)
    assert not np.array_equal(other._held_systems, fixed._held_systems)
    expected = (
        fixed.precision / fixed.scale**2 + fixed.penalty_weight[:, None, None] * fixed.penalty
    )
    np.testing.assert_array_equal(fixed._held_systems, expected)
    assert RIDGE > 0


def test_a_large_mappings_banded_normal_matrices_are_the_dense_ones(unblurred, monkeypatch):
    """Above :data:`response_model.DENSE_NORMAL` entries one mapping's normal matrices come from
    its band (:meth:`ResponseModel._banded_normal`): the same ``AᵀW²A`` as the dense product, so
    the same residual, Jacobian and fitted response up to rounding."""
    model, family, edges_px, x = unblurred
    fixed = model.reference(family.wavelengths(edges_px, x))
    where = family.wavelengths(edges_px, x + np.array([0.3, -0.2, 0.1]))
    jacobian = family.jacobian(edges_px, x)
    band = fixed.band(where[None])
    size = fixed.n_nodes
    columns = np.minimum(band.columns[0], size - 1)
    flat = (np.arange(band.values.shape[1])[:, None] * size + columns).ravel()
    rows = band.values.shape[1]
    matrix = np.bincount(flat, weights=band.values[0].ravel(), minlength=rows * size)
    matrix = matrix.reshape(rows, size)
    weighted = fixed.weights.T[:, :, None] * matrix
    dense = np.matmul(weighted.transpose(0, 2, 1), weighted)
    normal = fixed._banded_normal(band)
    np.testing.assert_allclose(normal, dense, rtol=0, atol=1e-13 * np.abs(dense).max())
    outputs = []
    for limit in (10**9, 0):  # the dense product, then the band's
        monkeypatch.setattr(response_model, "DENSE_NORMAL", limit)
        residual, derivative, parts = fixed.residual(where, jacobian)
        outputs.append((residual, derivative, parts["response"]))
    for dense_one, banded_one in zip(*outputs, strict=True):
        scale = np.abs(dense_one).max()
        np.testing.assert_allclose(banded_one, dense_one, rtol=0, atol=1e-11 * scale)


def test_a_batchs_prior_scale_from_its_normal_equations_is_the_gathered_one(unblurred):
    """:meth:`ResponseModel.costs` reads ``β̂`` off the normal equations it formed (``μ·AᵀW²y``
    over the band's quadratic form in ``μ``): the scale :meth:`_prior_scale` gathers from the
    band, to rounding, for rising and falling mappings alike (decision 0106)."""
    model, family, edges_px, x = unblurred
    band = model.band(_batch(family, edges_px, x))
    diagonals, rhs = model._normal(band)
    gathered = model._prior_scale(band)
    from_normal = model._prior_scale_from_normal(diagonals, rhs)
    assert np.all(gathered > 0) and not np.allclose(gathered, 1.0)
    np.testing.assert_allclose(from_normal, gathered, rtol=1e-12)
    # The quadratic form's weights are kept per band width.
    width = diagonals.shape[-1]
    assert model._mean_pairs(width) is model._mean_pairs(width)


def test_the_bands_kept_densities_give_the_located_derivative(unblurred):
    """A band asked for its edge densities (``slopes``) keeps :meth:`LampColumns.density_at`'s
    numbers, and :meth:`band_derivative` read from them (pixels last) is the one that locates
    the edges again (batched matmul) up to rounding (decision 0106)."""
    model, family, edges_px, x = unblurred
    edges = _batch(family, edges_px, x)
    moving = np.stack([family.jacobian(edges_px, x)] * edges.shape[0])
    kept = model.band(edges, slopes=True)
    plain = model.band(edges)
    assert kept.slope is not None and plain.slope is None
    np.testing.assert_array_equal(kept.values, plain.values)
    size = model.n_nodes
    column = np.minimum(kept.first + np.arange(kept.values.shape[-1])[:, None, None], size - 1)
    windows, _ = model._windows(edges)
    located = model.columns.density_at(np.moveaxis(windows, -1, 0)[None], column[:, None])
    np.testing.assert_array_equal(kept.slope, located)
    from_kept = model.band_derivative(edges, moving, kept)
    relocated = model.band_derivative(edges, moving, plain)
    assert np.abs(relocated).max() > 0
    np.testing.assert_allclose(from_kept, relocated, rtol=0, atol=1e-14 * np.abs(relocated).max())


def test_the_residuals_jacobian_from_kept_densities_is_the_relocated_one(unblurred, monkeypatch):
    """:meth:`residual_lazy` keeps the band's edge densities for its Jacobian: the same residual
    and, up to rounding, the same Jacobian as a band that locates the edges again."""
    model, family, edges_px, x = unblurred
    fixed = model.reference(family.wavelengths(edges_px, x))
    where = family.wavelengths(edges_px, x + np.array([0.3, -0.2, 0.1]))
    moving = family.jacobian(edges_px, x)
    residual, jacobian, _ = fixed.residual(where, moving)
    plain_band = ResponseModel.band

    def without_densities(self, edges_nm, edge_jacobian=None, *, slopes=False):
        return plain_band(self, edges_nm, edge_jacobian)

    monkeypatch.setattr(ResponseModel, "band", without_densities)
    again, relocated, _ = fixed.residual(where, moving)
    np.testing.assert_array_equal(residual, again)
    assert jacobian is not None and relocated is not None
    np.testing.assert_allclose(jacobian, relocated, rtol=0, atol=1e-12 * np.abs(relocated).max())


def test_the_batchs_systems_written_diagonal_by_diagonal_are_the_scattered_ones(unblurred):
    """:meth:`ResponseModel._systems` adds the band and the penalty diagonal by diagonal through
    strided views: the same systems, to the last bit, as scattering the same sums at
    :meth:`_band_layout`'s places (decision 0106)."""
    model, family, edges_px, x = unblurred
    band = model.band(_batch(family, edges_px, x))
    diagonals, scale, weight = _normal_and_scale(model, band)
    systems, _, _ = model._systems(diagonals, scale, weight)
    batch, _, size, width = diagonals.shape
    positions, source, penalty_values = model._band_layout(width)
    expected = (1.0 / scale**2)[:, None, None, None] * model.precision
    flat = expected.reshape(batch, 3, size * size)
    padded = np.concatenate(
        [diagonals.reshape(batch, 3, size * width), np.zeros((batch, 3, 1))], axis=-1
    )
    flat[..., positions] += padded[..., source] + weight[..., None] * penalty_values
    diagonal = np.einsum("kcii->kc", expected)
    flat[..., :: size + 1] += (RIDGE * np.maximum(diagonal / size, 1e-300))[..., None]
    assert model._penalty_reach > 0 and np.any(weight > 0)
    np.testing.assert_array_equal(systems, expected)


def _lu_costs(model, edges):
    """:meth:`ResponseModel.costs` as before decision 0116: the systems solved by numpy's batched
    LU for ``[rhs, g]``, then β and the explained part from the solutions."""
    band = model.band(edges)
    diagonals, rhs = model._normal(band)
    scale = model._prior_scale_from_normal(diagonals, rhs)
    systems, pulls, gamma = model._systems(diagonals, scale, model._penalty_weight(diagonals))
    solved = np.linalg.solve(systems, np.stack([rhs, pulls], axis=-1))
    free, along = solved[..., 0], solved[..., 1]
    beta = np.einsum("kci,kci->k", pulls, free) / (gamma - np.einsum("kci,kci->k", pulls, along))
    explained = np.einsum("kci,kci->k", rhs, free + beta[:, None, None] * along)
    return float(np.sum(model.target**2)) - explained


def test_a_batchs_costs_from_the_bordered_cholesky_are_the_lu_solves(unblurred):
    """Decision 0116: a scan's χ² from one Cholesky factor of the bordered systems (their last
    rows ``L⁻¹r``, ``L⁻¹g``) equal the LU solve's to rounding, and the bordered systems hold
    :meth:`ResponseModel._systems`' ``H`` to the bit."""
    model, family, edges_px, x = unblurred
    edges = np.concatenate(
        [_batch(family, edges_px, x), _batch(family, edges_px, x + np.array([1.0, -0.5, 0.2]))]
    )
    expected = _lu_costs(model, edges)
    got = model.costs(edges)
    np.testing.assert_allclose(got, expected, rtol=1e-10)
    assert int(np.argmin(got)) == int(np.argmin(expected))
    band = model.band(edges)
    diagonals, rhs = model._normal(band)
    scale = model._prior_scale_from_normal(diagonals, rhs)
    weight = model._penalty_weight(diagonals)
    plain, pulls, _ = model._systems(diagonals, scale, weight)
    bordered, bordered_pulls, _ = model._systems(diagonals, scale, weight, rhs)
    size = model.n_nodes
    np.testing.assert_array_equal(bordered[..., :size, :size], plain)
    np.testing.assert_array_equal(bordered[..., :size, size], rhs)
    np.testing.assert_array_equal(bordered[..., size + 1, :size], pulls)
    np.testing.assert_array_equal(bordered_pulls, pulls)


def test_bordered_forms_are_the_quadratic_forms_and_refuse_an_indefinite_system():
    rng = np.random.default_rng(116)
    size = 12
    factor = rng.normal(size=(4, 3, size, size + 5))
    systems = factor @ factor.transpose(0, 1, 3, 2) + 0.1 * np.eye(size)
    right = rng.normal(size=(4, 3, size))
    pulls = rng.normal(size=(4, 3, size))
    bordered = np.zeros((4, 3, size + 2, size + 2))
    bordered[..., :size, :size] = systems
    for column, vector in ((size, right), (size + 1, pulls)):
        bordered[..., :size, column] = vector
        bordered[..., column, :size] = vector
        bordered[..., column, column] = 1e6
    forms = response_model._bordered_forms(bordered)
    assert forms is not None
    free = np.linalg.solve(systems, right[..., None])[..., 0]
    along = np.linalg.solve(systems, pulls[..., None])[..., 0]
    for got, expected in zip(
        forms,
        (
            np.einsum("kci,kci->k", right, free),
            np.einsum("kci,kci->k", pulls, free),
            np.einsum("kci,kci->k", pulls, along),
        ),
        strict=True,
    ):
        np.testing.assert_allclose(got, expected, rtol=1e-10)
    bordered[1, 2, 3, 3] = -1.0  # one system indefinite: the batch falls back to the LU solve
    assert response_model._bordered_forms(bordered) is None
