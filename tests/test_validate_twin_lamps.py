"""``bench/validate_twin.py`` renders the lamps the 1-D protocol renders (decision 0126).

The 1-D protocol's fluorescent lamps shine with narrow mercury lines at their true wavelengths
(:func:`calib.evaluation.validation.scenes.true_lamp`); the 2-D bench had rendered (and measured
with its spectrometer) the CIE table's 5 nm bins instead, lines at 545/435 nm, so its rows were
not "the same tasks" and its FL lamp's response was off where the lamp alone carried a range.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

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


def test_the_2d_twin_renders_the_fluorescent_lamp_with_the_1d_protocols_lines(
    shared_camera_data: Path, tmp_path: Path
) -> None:
    bench = _bench()
    splits, _ = load_splits(shared_camera_data)
    variants = tuple(v for v in DEFAULT_VARIANTS if v.label == "LED+FL")
    task = next(
        iter(split_tasks(bench._subset(splits.validation, 1), ProtocolSettings(variants=variants)))
    )
    plan, noise = draw_task_plan(task)
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
