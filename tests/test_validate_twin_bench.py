"""``bench/validate_twin.py`` renders the 1-D protocol's tasks: the same brackets, the same lamps.

Decision 0098 made the 1-D protocol bracket each lamp as the rig's HDR policy does
(:meth:`calib.evaluation.validation.rig_errors.PhotonBudget.bracket`); decision 0111 made the 2-D twin
bench take the same rule instead of its own (frames until the band peak reached a quarter of the
clipping level), so both render the same scene with the same frames. Decision 0126: its fluorescent
lamp shines with the 1-D protocol's narrow mercury lines at their true wavelengths
(:func:`calib.evaluation.validation.scenes.true_lamp`), not the CIE table's 5 nm bins (lines at
545/435 nm), so its rows are the same tasks.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

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


LED_FL = next(v for v in DEFAULT_VARIANTS if v.label == "LED+FL")


def _bench() -> ModuleType:
    return load_bench("validate_twin.py")


def _first_led_fl_task(shared_camera_data: Path) -> tuple[ModuleType, Any, Any, Any]:
    """The bench module and the first validation camera's LED+FL task, its plan and noise."""
    bench = _bench()
    splits, _ = load_splits(shared_camera_data)
    settings = ProtocolSettings(seed=0, variants=(LED_FL,))
    task = next(iter(split_tasks(bench._subset(splits.validation, 1), settings)))
    plan, noise = draw_task_plan(task)
    return bench, task, plan, noise


def test_the_2d_twin_brackets_each_lamp_as_the_1d_protocol_does(
    shared_camera_data: Path, tmp_path: Path
) -> None:
    bench, task, plan, noise = _first_led_fl_task(shared_camera_data)
    frames = []
    for spec in LED_FL.lamps:
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


def test_the_2d_twin_renders_the_fluorescent_lamp_with_the_1d_protocols_lines(
    shared_camera_data: Path, tmp_path: Path
) -> None:
    bench, task, plan, noise = _first_led_fl_task(shared_camera_data)
    pixel = np.asarray(plan.geometry.pixel, dtype=np.float64)
    wavelength = np.asarray(plan.geometry.mapping.wavelength_nm(pixel), dtype=np.float64)
    draw = plan.lamps["FL2"]
    seen = drifted(true_lamp("FL2"), draw.drift_gain, draw.drift_tilt_per_100nm)
    profile, direct = clean_signals(plan, seen, task.camera.sensitivity)
    lamp = bench._lamp_images(tmp_path, plan, task, "FL2", noise)
    rendered = lamp.true_direct()
    # the spot's colour as the 1-D scene has it (the CIE table's bins: 0.1–0.2 % off)
    np.testing.assert_allclose(
        rendered / rendered.sum(), direct / direct.sum(), rtol=2e-4, atol=0.0
    )
    # the brightest line of the first order where the 1-D scene has it: Hg 546.1 nm, not 545
    first_order = lamp.true_profile(pixel)[:, 1]
    assert abs(wavelength[np.argmax(first_order)] - wavelength[np.argmax(profile[:, 1])]) < 0.5
