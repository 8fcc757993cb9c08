"""The direct spot's colour from the Bayer interleaving under a tilted slit (decision 0134)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib.image.profiles import extraction as module
from calib.image.profiles.extraction import extract
from tests.test_profiles import _slit_image


def _colour_error_over_sigma(angle_deg: float) -> list[float]:
    """|error| / σ of R/G and B/G over five sub-pixel offsets: a noiseless slit image 4 px wide with
    raised-cosine edges 2 px wide (decision 0123's spot) and 80 px long, read by the interleaving
    (which decision 0140 no longer picks on this spot, two pitches wide: it is made to here)."""
    ratios = []
    for shift_px in (0.0, 0.35, 0.7, 1.1, 1.5):
        image, geometry, truth = _slit_image(2.0, 2.0, shift_px, angle_deg, raised_cosine_edge=True)
        extraction = extract(image, geometry, subtract_background=False)
        direct, sigma = extraction.direct_rgb, extraction.direct_sigma
        assert direct is not None and sigma is not None
        relative = sigma / direct
        for channel in (0, 2):
            error = abs((direct[channel] / direct[1]) / (truth[channel] / truth[1]) - 1)
            ratios.append(error / math.hypot(relative[channel], relative[1]))
    return ratios


@pytest.mark.parametrize("angle_deg", [0.8, -0.8])
def test_a_tilted_slits_interleaved_colour_stays_within_its_sigma(
    angle_deg: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Decision 0123: at ±0.8° the interleaving reads the slit's tilt as colour (up to 0.6 % here,
    its noise σ a tenth of that). Decision 0134 states the tilt term's effect as a bound in the σ:
    every colour within 2σ; without it, misses of more than 3σ."""
    monkeypatch.setattr(module, "_aliasing", lambda *_: 1.0)
    assert max(_colour_error_over_sigma(angle_deg)) < 2.0
    with monkeypatch.context() as patch:
        patch.setattr(module, "_slit_tilt", lambda *_: 0.0)
        assert max(_colour_error_over_sigma(angle_deg)) > 3.0


def test_an_untilted_slit_adds_no_tilt_bound() -> None:
    """Along the sensor's axes the greens see the slit where R and B do: no bound is added."""
    red, green, blue = (np.array([1.0, 4.0, 3.0, 0.5]) * level for level in (1.0, 2.0, 0.5))
    bias = module._tilt_bias(red, green + 0.01, blue, np.ones(4), 1.0, "RGGB", axis=0, tilt=0.0)
    assert bias is not None
    np.testing.assert_array_equal(bias, np.zeros(3))


def test_the_slits_tilt_is_measured_against_the_axis_the_dispersion_runs_nearest() -> None:
    slope = math.tan(math.radians(0.8))
    assert module._slit_tilt(0.8, 0) == pytest.approx(slope)
    assert abs(module._slit_tilt(90.8, 1)) == pytest.approx(slope)
    assert abs(module._slit_tilt(-89.2, 1)) == pytest.approx(slope)
