"""Decision 0141: with a broadband lamp alone, the quadratic deciding stage also descends from the
basin's own point, not only from its local scan's lowest point; decision 0150: once, when that
lowest point is the basin's own."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import QuadraticMapping
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import random_efficiency
from calib.model.bases import fallback_camera_basis
from calib.model.forward import render_observation
from calib.wavelength import profile_search

TRUTH = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))


def _far_corner_scene(
    monkeypatch: Any, at_centre: bool = False
) -> tuple[Any, Any, list[np.ndarray], list[np.ndarray]]:
    """A D65-only scene whose deciding scans' lowest point is forced to their far corner (+6 nm at
    both ends; ``at_centre``: to their centre, the basin's own point), with the scans' grids and
    the descents' starts recorded: (prior, observation, scans, starts)."""
    prior = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"]).prior()
    camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    observation = render_observation(
        colour_lamp("D65"),
        camera,
        mapping=TRUTH,
        pixel=800,
        grating_efficiency=random_efficiency(np.random.default_rng(11)),
        rng=np.random.default_rng(3),
        kind="led",
    ).observation

    scans: list[np.ndarray] = []
    original_points = profile_search._quadratic_points

    def points(*args: Any) -> Any:
        out = original_points(*args)
        if sys._getframe(1).f_code.co_name == "decide":
            scans.append(out[0])
        return out

    original_shortlist = profile_search._shortlisted_costs

    def shortlist(grid: np.ndarray, coarse: Any, fine: Any, keep: int) -> Any:
        costs, count = original_shortlist(grid, coarse, fine, keep)
        if sys._getframe(1).f_code.co_name == "decide":
            costs = np.array(costs, dtype=float)
            # The scan's lowest point: its far corner (or its centre).
            costs[grid.shape[0] // 2 if at_centre else -1] = -np.inf
        return costs, count

    starts: list[np.ndarray] = []
    original_refine = profile_search.StageFit.refine

    def refine(self: Any, x: np.ndarray, *args: Any, **kwargs: Any) -> Any:
        starts.append(np.array(x, copy=True))
        return original_refine(self, x, *args, **kwargs)

    monkeypatch.setattr(profile_search, "_quadratic_points", points)
    monkeypatch.setattr(profile_search, "_shortlisted_costs", shortlist)
    monkeypatch.setattr(profile_search.StageFit, "refine", refine)
    return prior, observation, scans, starts


def test_the_deciding_stage_also_descends_from_the_basins_own_point(monkeypatch):
    """The deciding scan's lowest point is forced to its far corner (+6 nm at both ends): the
    deciding stage descends from it and then from the basin's own point (the scan's centre)."""
    prior, observation, scans, starts = _far_corner_scene(monkeypatch)
    # Every basin, however far behind (decision 0143 skips those hopelessly behind).
    monkeypatch.setattr(profile_search, "HOPELESS_DELTA_CHI2", np.inf)
    found = profile_search.search_profiles([observation], prior, DEFAULT_GRID)
    assert scans
    for grid in scans:
        corner, centre = grid[-1], grid[grid.shape[0] // 2]
        assert not np.allclose(corner, centre, rtol=0.0, atol=1.0)
        (first,) = [i for i, s in enumerate(starts) if np.array_equal(s, corner)]
        # (The scan's centre is the basin's point up to the mapping's round trip.)
        np.testing.assert_allclose(starts[first + 1], centre, rtol=0.0, atol=1e-9)
    pixels = np.arange(800.0)
    error = np.abs(found.mapping.wavelength_nm(pixels) - TRUTH.wavelength_nm(pixels))
    assert float(np.max(error)) < 1.0


def test_a_basin_hopelessly_behind_gets_no_descent_from_its_own_point(monkeypatch):
    """Decision 0143: the own-point descent is skipped for a basin whose descent stands more than
    ``HOPELESS_DELTA_CHI2`` behind the best deciding descent so far (here every later basin: the
    bar below zero); the first basin, with nothing ahead of it, still gets one."""
    prior, observation, scans, starts = _far_corner_scene(monkeypatch)
    monkeypatch.setattr(profile_search, "HOPELESS_DELTA_CHI2", -1.0)
    profile_search.search_profiles([observation], prior, DEFAULT_GRID)
    assert len(scans) >= 2
    own = [
        any(np.allclose(s, grid[grid.shape[0] // 2], rtol=0.0, atol=1e-9) for s in starts)
        for grid in scans
    ]
    assert own == [True] + [False] * (len(scans) - 1)


def test_a_basin_whose_scan_is_lowest_at_its_own_point_descends_once(monkeypatch):
    """Decision 0150: when the deciding scan's lowest point is its centre (the basin's own point up
    to the mapping's round trip), the stage descends from it once, not again from the basin."""
    prior, observation, scans, starts = _far_corner_scene(monkeypatch, at_centre=True)
    monkeypatch.setattr(profile_search, "HOPELESS_DELTA_CHI2", np.inf)
    profile_search.search_profiles([observation], prior, DEFAULT_GRID)
    assert scans
    for grid in scans:
        centre = grid[grid.shape[0] // 2]
        near = [s for s in starts if np.allclose(s, centre, rtol=0.0, atol=1e-9)]
        assert len(near) == 1
        np.testing.assert_array_equal(near[0], centre)
