"""A given profile's clipped band (``calib.pipeline.estimate.clipped_band``): exact repeats of a
channel's maximum mean clipping in a float export; in a quantised (8-bit) one a flat top repeats
its maximum by chance, so there the band's shoulders must point above the run."""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.lamp_specs import lamp_from_spec
from calib.core.observations import LampObservation
from calib.pipeline.estimate import clipped_band

PIXEL = np.arange(800.0)


def _observation(profile: np.ndarray) -> LampObservation:
    return LampObservation(
        name="L", spectrum=lamp_from_spec("D65"), pixel=PIXEL, profile=profile, direct_rgb=None
    )


def _bands(width_px: float) -> np.ndarray:
    return np.stack([np.exp(-0.5 * ((PIXEL - c) / width_px) ** 2) for c in (500, 400, 300)], 1)


@pytest.mark.parametrize("width_px", [30.0, 70.0, 150.0])
def test_an_unclipped_8_bit_export_is_not_called_clipped(width_px: float) -> None:
    """Before, 13–50 of 60 such profiles at 0.5–1 count of noise were a SERIOUS warning."""
    rng = np.random.default_rng(11)
    fired = 0
    for _ in range(40):
        top = rng.uniform(60.0, 230.0)
        noisy = _bands(width_px) * top + rng.normal(0.0, 0.5, (PIXEL.size, 3))
        fired += clipped_band(_observation(np.round(noisy))) is not None
    assert fired == 0


@pytest.mark.parametrize("width_px", [30.0, 70.0, 150.0])
def test_an_8_bit_export_clipped_at_full_scale_is_found(width_px: float) -> None:
    rng = np.random.default_rng(12)
    for over in (1.1, 1.3, 2.0):
        noisy = _bands(width_px) * 255.0 * over + rng.normal(0.0, 1.0, (PIXEL.size, 3))
        found = clipped_band(_observation(np.minimum(np.round(noisy), 255.0)))
        assert found is not None and found.startswith("L (r 255 at px "), found


def test_a_float_export_repeating_its_maximum_is_clipped_whatever_its_shoulders() -> None:
    """Column means do not repeat a value by chance: the exact-repeat rule stands there."""
    profile = _bands(70.0) * 0.8
    profile[495:506, 0] = profile[500, 0]
    assert clipped_band(_observation(profile)) == "L (r 0.8 at px 495–505)"


def test_an_8_bit_band_clipped_beside_another_band_of_its_channel_is_found() -> None:
    """The shoulders are the clipped band's own: a second band of the channel above 60 % of the
    clip level (a CFL's lines, an LED's two humps) once joined the parabola's fit, which then
    missed every one of these clipped profiles."""
    rng = np.random.default_rng(13)
    for _ in range(10):
        channel = 255.0 * (
            1.3 * np.exp(-0.5 * ((PIXEL - 300) / 40) ** 2)
            + 0.75 * np.exp(-0.5 * ((PIXEL - 600) / 15) ** 2)
        )
        profile = np.stack([channel, 0.3 * channel, 0.2 * channel], 1)
        noisy = np.minimum(np.round(profile + rng.normal(0.0, 1.0, profile.shape)), 255.0)
        found = clipped_band(_observation(noisy))
        assert found is not None and found.startswith("L (r 255 at px "), found
