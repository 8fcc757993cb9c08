"""``bench/validate_twin.py`` brackets a lamp by the rig's rule, as ``calib validate`` does.

Decision 0098 made the 1-D protocol bracket each lamp as the rig's HDR policy does
(:meth:`calib.evaluation.validation.rig_errors.PhotonBudget.bracket`); decision 0111 made the 2-D twin
bench take the same rule instead of its own (frames until the band peak reached a quarter of the
clipping level), so both render the same scene with the same frames.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from calib.evaluation.validation.capture import SHORTEST_S, SlitImage
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    draw_task_plan,
    split_tasks,
)
from calib.evaluation.validation.rig_errors import drifted
from calib.evaluation.validation.scenes import clean_signals, true_lamp
from calib.evaluation.validation.splits import load_splits
from tests.benches import load_bench

pytestmark = [pytest.mark.shared_data, pytest.mark.slow]


def _bench() -> ModuleType:
    return load_bench("validate_twin.py")


def test_the_2d_twin_brackets_each_lamp_as_the_1d_protocol_does(
    shared_camera_data: Path, tmp_path: Path
) -> None:
    bench = _bench()
    splits, _ = load_splits(shared_camera_data)
    variants = tuple(v for v in DEFAULT_VARIANTS if v.label == "LED+FL")
    settings = ProtocolSettings(seed=0, variants=variants)
    task = next(iter(split_tasks(bench._subset(splits.validation, 1), settings)))
    plan, noise = draw_task_plan(task)
    frames = []
    for spec in variants[0].lamps:
        lamp = bench._lamp_images(tmp_path, plan, task, spec, noise)
        draw = plan.lamps[spec]
        seen = drifted(true_lamp(spec), draw.drift_gain, draw.drift_tilt_per_100nm)
        profile, direct = clean_signals(plan, seen, task.camera.sensitivity)
        shape = plan.geometry
        slit = SlitImage.of(shape.line_spread, plan.sensor.band_rows, shape.psf_sigma_px)
        _, factors = plan.errors.photons.bracket(
            profile, direct, plan.sensor, slit.spot_px, draw.spot_fill
        )
        np.testing.assert_allclose(lamp.images.exposure_s, SHORTEST_S * np.asarray(factors))
        frames.append(len(factors))
    # the scene's lamps need more than one frame each: the test judges a bracket, not a single shot
    assert min(frames) > 1
