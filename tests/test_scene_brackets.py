"""calib.evaluation.validation.capture: a bracket whose shortest frame the shutter's error lifts over
the merge's ceiling is extended with a shorter frame, as the rig extends it (decision 0182)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.evaluation.validation.capture import SlitImage, capture_lamp
from calib.evaluation.validation.rig_errors import PhotonBudget, SensorDraw
from calib.model.forward import blur_kernel

SENSOR = SensorDraw(20000.0, 3.0, 24)
SLIT = SlitImage.of(blur_kernel(3.0, 1.0), SENSOR.band_rows, 1.0)  # type: ignore[arg-type]
#: The shortest frame's brightest pixel at 98 % of the merge's ceiling (the largest spot fill),
#: exposed 4 % longer than recorded: 1.9 % over the ceiling, where the merge uses no sample.
FILL, LONG_BY = 0.98, 0.04


def _bright_band() -> tuple[np.ndarray, np.ndarray]:
    """A broad band brighter per pixel than a weak direct spot (decision 0182's LED through a
    blazed sheet): its flat top's neighbours stand as high as its peak."""
    pixel = np.arange(240)
    profile = np.outer(np.exp(-0.5 * ((pixel - 120) / 40.0) ** 2), [1.0, 1.5, 0.5])
    direct = np.array([1.0, 1.5, 0.5])
    assert float(direct.max()) / SLIT.spot_px < float(profile.max()) / SENSOR.band_rows
    return profile, direct


def test_a_shortest_frame_exposed_over_the_ceiling_gets_a_shorter_frame() -> None:
    budget = PhotonBudget()
    profile, direct = _bright_band()
    gain, factors = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, FILL)
    errors = np.zeros(budget.max_frames)
    errors[0] = LONG_BY
    brightest = gain * (1 + LONG_BY) * float(profile.max()) / SENSOR.band_rows
    assert brightest > budget.clip_fraction * SENSOR.full_well_e
    captured = capture_lamp(
        profile, direct, SLIT, budget, SENSOR, gain, factors, errors, np.random.default_rng(2)
    )
    step = 2.0**budget.step_stops
    assert captured.factors == (1.0 / step, *factors)
    assert len(captured.frame_gains) == len(factors) + 1
    # the samples the first frame lost are measured by the shorter one, within the frames' error
    assert np.all(np.isfinite(captured.profile_sigma))
    top = profile[:, 1] > 0.9 * profile[:, 1].max()
    np.testing.assert_allclose(captured.profile[top, 1] / profile[top, 1], 1.0, atol=LONG_BY)


def test_a_bracket_within_the_ceiling_is_not_extended() -> None:
    budget = PhotonBudget()
    profile, direct = _bright_band()
    gain, factors = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, FILL)
    errors = np.zeros(budget.max_frames)
    captured = capture_lamp(
        profile, direct, SLIT, budget, SENSOR, gain, factors, errors, np.random.default_rng(2)
    )
    assert captured.factors == tuple(factors)


def test_a_bracket_already_at_max_frames_says_so() -> None:
    budget = replace(PhotonBudget(), max_frames=1)
    profile, direct = _bright_band()
    gain, factors = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, FILL)
    rng = np.random.default_rng(2)
    with pytest.raises(InputError, match=r"saturated in every frame.*max_frames 1"):
        capture_lamp(profile, direct, SLIT, budget, SENSOR, gain, factors, [LONG_BY], rng)
