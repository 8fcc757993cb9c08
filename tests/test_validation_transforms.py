"""calib.evaluation.validation.transforms: validation cameras changed physically (decision 0094)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.spectra import MultiSpectrum
from calib.evaluation.validation.splits import (
    LEAVE_ONE_OUT,
    TRANSFORMED,
    SplitCamera,
    transformed_cameras,
)
from calib.evaluation.validation.transforms import (
    EDGE_FRACTION,
    TRANSFORM_KINDS,
    filtered,
    move_edge,
    shift_dyes,
    transform_camera,
)


def _camera() -> MultiSpectrum:
    axis = np.arange(400.0, 701.0, 10.0)
    curves = [
        np.exp(-0.5 * ((axis - peak) / width) ** 2)
        for peak, width in ((600, 30), (530, 35), (460, 25))
    ]
    return MultiSpectrum(axis, np.stack(curves, axis=1), name="test camera")


def _edges(values: np.ndarray) -> tuple[float, float]:
    axis = np.arange(400.0, 701.0)
    total = values.sum(axis=1)
    above = np.flatnonzero(total >= EDGE_FRACTION * total.max())
    return float(axis[above[0]]), float(axis[above[-1]])


@pytest.mark.parametrize("shift", [-30.0, -20.0, 15.0])
def test_the_ir_cut_edge_moves_by_the_shift_and_the_rest_stays(shift):
    camera = _camera()
    before = _edges(move_edge(camera, 0.0, "red"))
    moved = move_edge(camera, shift, "red")
    after = _edges(moved)
    assert after[1] - before[1] == pytest.approx(shift, abs=1.5)
    assert after[0] == before[0]
    # Below the red channel's peak nothing changes.
    fine = np.arange(400.0, 701.0)
    below = fine <= 600.0
    np.testing.assert_allclose(moved[below], move_edge(camera, 0.0, "red")[below])


def test_the_blue_edge_moves_and_the_red_stays():
    camera = _camera()
    before = _edges(move_edge(camera, 0.0, "blue"))
    after = _edges(move_edge(camera, 15.0, "blue"))
    assert after[0] - before[0] == pytest.approx(15.0, abs=1.5)
    assert after[1] == before[1]


def test_dyes_shift_each_channel_and_filters_cut_their_side():
    camera = _camera()
    fine = np.arange(400.0, 701.0)
    shifted = shift_dyes(camera, [5.0, -3.0, 0.0])
    peaks = fine[np.argmax(shifted, axis=0)]
    np.testing.assert_allclose(peaks, [605.0, 527.0, 460.0])
    blue = filtered(camera, "blue", 560.0)
    yellow = filtered(camera, "yellow", 450.0)
    assert blue[fine == 650.0, 0] < 0.2 * shifted[fine == 650.0, 0]
    assert yellow[fine == 420.0, 2] < 0.2 * move_edge(camera, 0.0, "red")[fine == 420.0, 2]


def test_transformed_cameras_keep_their_body_and_are_drawn_from_the_seed():
    base = [
        SplitCamera(f"camera {k}", f"body{k}", "solomatov", LEAVE_ONE_OUT, _camera())
        for k in range(3)
    ]
    added = transformed_cameras(base, 7, seed=5)
    assert len(added) == 7
    assert [c.name for c in added] == [c.name for c in transformed_cameras(base, 7, seed=5)]
    assert {c.group for c in added} == {TRANSFORMED}
    for camera in added:
        (source,) = [b for b in base if camera.name.startswith(b.name + " · ")]
        assert camera.body == source.body  # its basis leaves the same body out
        assert float(np.max(camera.sensitivity.values)) == pytest.approx(1.0)
    kinds = [
        transform_camera(_camera(), kind, np.random.default_rng(1))[1] for kind in TRANSFORM_KINDS
    ]
    assert len(set(kinds)) == len(TRANSFORM_KINDS)
    assert transformed_cameras(base, 0, seed=5) == []
