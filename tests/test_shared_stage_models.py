"""A stage on the same bins and nodes as another reuses its layouts and lamp tables, with the
numbers a new build gives (decision 0135)."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.spectra import WavelengthGrid
from calib.model.bases import fallback_camera_basis
from calib.wavelength import profile_search
from calib.wavelength.response_model import ResponseModel
from tests.led_scene import unblurred_led

KERNEL = np.array([0.2, 0.6, 0.2])


def _equal_models(built: ResponseModel, derived: ResponseModel) -> None:
    for item in fields(ResponseModel):
        a, b = getattr(built, item.name), getattr(derived, item.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), item.name
        elif item.name in ("layout", "columns", "observation"):
            continue  # compared below / the same object
        else:
            assert a == b, item.name


@pytest.mark.parametrize("cut_ramps", [False, True])
def test_a_model_with_another_prior_is_the_build_with_it(cut_ramps: bool) -> None:
    base, family, edges_px, truth = unblurred_led(
        kernel=KERNEL, sigma_floor=0.005, cut_ramps=cut_ramps
    )
    prior = fallback_camera_basis().prior()
    x = family.parameters(truth) + np.array([0.8, -0.4, 0.6])
    batch = np.stack(
        [
            family.wavelengths(edges_px, x),
            family.wavelengths(edges_px, x + np.array([-2.0, 1.5, 0.5])),
            family.wavelengths(edges_px, x[::-1]),
        ]
    )
    edges = batch[0]
    jacobian = family.jacobian(edges_px, x)
    for flexibility, floor in ((2.0, 0.0), (0.05, 0.0), (0.05, 0.005)):
        built = ResponseModel.build(
            base.observation,
            prior.grid,
            node_step_nm=10.0,
            prior=prior,
            flexibility=flexibility,
            kernel=KERNEL,
            sigma_floor=floor,
            cut_ramps=cut_ramps,
        )
        derived = base.with_prior(prior, flexibility=flexibility, sigma_floor=floor)
        assert derived.layout is base.layout and derived.columns is base.columns
        _equal_models(built, derived)
        assert np.array_equal(built.layout.nodes_nm, derived.layout.nodes_nm)
        assert np.array_equal(built.columns.cumulative, derived.columns.cumulative)
        assert np.array_equal(built.costs(batch), derived.costs(batch))
        one, many = built.reference(edges), derived.reference(edges)
        residual, jac, _ = one.residual(edges, jacobian)
        again, jac_again, _ = many.residual(edges, jacobian)
        assert np.array_equal(residual, again)
        assert jac is not None and jac_again is not None and np.array_equal(jac, jac_again)


def test_a_prior_on_another_grid_is_refused() -> None:
    base, _, _, _ = unblurred_led()
    prior = fallback_camera_basis().prior()
    inner = slice(1, -1)  # the same prior on the grid one step inside
    other = replace(
        prior,
        grid=WavelengthGrid(
            prior.grid.start_nm + prior.grid.step_nm,
            prior.grid.stop_nm - prior.grid.step_nm,
            prior.grid.step_nm,
        ),
        mean=prior.mean[inner],
        covariance=prior.covariance[:, inner, inner],
    )
    with pytest.raises(InputError, match="grid"):
        base.with_prior(other, flexibility=2.0, sigma_floor=0.0)


def test_a_stage_like_another_shares_its_tables_and_gives_its_costs() -> None:
    base, family, _, truth = unblurred_led()
    prior = fallback_camera_basis().prior()

    def stage(
        flexibility: float, floor: float, like: profile_search.StageFit | None = None
    ) -> profile_search.StageFit:
        return profile_search._stage(
            [base.observation],
            family,
            prior.grid,
            prior,
            bin_nm=2.5,
            nm_per_px=1.72,
            kernel=KERNEL,
            node_step_nm=10.0,
            flexibility=flexibility,
            sigma_floor=floor,
            pixel_range=(0.0, 199.0),
            like=like,
        )

    first = stage(0.05, 0.005)
    fresh = stage(2.0, 0.0)
    shared = stage(2.0, 0.0, like=first)
    assert shared.models[0].columns is first.models[0].columns
    assert fresh.models[0].columns is not first.models[0].columns
    x = family.parameters(truth)
    points = np.stack([x, x + np.array([0.5, -0.3, 0.2]), x + np.array([-1.0, 0.4, -0.6])])
    assert np.array_equal(shared.costs(points), fresh.costs(points))
    assert not np.array_equal(shared.costs(points), first.costs(points))
