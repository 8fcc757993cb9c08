"""calib.evaluation.validation.capture: the protocol's spot and band as the slit's image, bracketed
with the shutter's errors and merged by the rig's HDR merge (decision 0098)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from calib.evaluation.validation.capture import SlitImage, capture_lamp
from calib.evaluation.validation.rig_errors import PhotonBudget, SensorDraw
from calib.model.forward import blur_kernel

SENSOR = SensorDraw(20000.0, 3.0, 24)
#: A slit 3 px wide through a lens blur of σ 1 px: the spot's soft edges are a few pixels wide.
SLIT = SlitImage.of(blur_kernel(3.0, 1.0), SENSOR.band_rows, 1.0)  # type: ignore[arg-type]


def _band() -> tuple[np.ndarray, np.ndarray]:
    pixel = np.arange(240)
    profile = np.outer(np.exp(-0.5 * ((pixel - 120) / 40.0) ** 2), [1.0, 1.5, 0.5])
    return profile, np.array([60.0, 90.0, 30.0])


def test_the_slit_image_has_soft_edges_and_keeps_the_totals() -> None:
    profile, direct = _band()
    image = SLIT.image(profile, direct)
    spot = image[:, :, : SLIT.along.size]
    np.testing.assert_allclose(spot.sum(axis=(1, 2)), direct)
    np.testing.assert_allclose(image[:, :, -profile.shape[0] :].sum(axis=1), profile.T)
    # the spot's edges are dimmer than its core, along the dispersion and across it
    core = spot[1].max()
    assert 0 < spot[1, SENSOR.band_rows // 2, 1] < 0.5 * core
    assert 0 < spot[1, 1, SLIT.along.size // 2] < 0.5 * core
    assert SLIT.spot_px == pytest.approx(1.0 / (SLIT.along.max() * SLIT.across.max()))


def test_the_bracket_judges_one_cells_snr_as_the_rig_does() -> None:
    budget = PhotonBudget()
    profile, direct = _band()
    gain, factors = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, 0.5)

    def cell_snr(factor: float) -> float:  # rig/frame_stats.py: one 2×2 cell's channel mean
        per_pixel = gain * factor * profile / SENSOR.band_rows
        cell = per_pixel.mean(axis=1)
        bright = per_pixel[cell >= 0.25 * np.percentile(cell, 98)]
        variance = (bright + SENSOR.read_noise_e**2) / np.array([1.0, 2.0, 1.0])
        return float(bright.mean() / math.sqrt(np.median(variance.sum(axis=1) / 9.0)))

    assert len(factors) >= 2
    assert cell_snr(factors[-1]) >= budget.min_band_snr > cell_snr(factors[-2])
    # the profile summed over the slit's rows and channels passes in the shortest frame already
    summed = gain * profile.sum(axis=1)
    assert float(np.median(summed / np.sqrt(summed))) > budget.min_band_snr


def test_the_capture_states_its_noise_honestly() -> None:
    budget = PhotonBudget()
    profile, direct = _band()
    gain, factors = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, 0.5)
    exact = np.zeros(len(factors))
    rng = np.random.default_rng(3)
    draws = [
        capture_lamp(profile, direct, SLIT, budget, SENSOR, gain, factors, exact, rng)
        for _ in range(20)
    ]
    band = profile > 0.01 * profile.max(axis=0)
    z_band = np.stack([(d.profile - profile) / d.profile_sigma for d in draws])[:, band]
    z_spot = np.stack([(d.direct - direct) / d.direct_sigma for d in draws])
    assert abs(float(z_band.mean())) < 0.05 and 0.9 < float(z_band.var()) < 1.1
    assert abs(float(z_spot.mean())) < 0.5 and 0.5 < float(z_spot.var()) < 1.6


def test_a_frame_exposed_longer_reads_high_where_it_is_used_alone() -> None:
    budget = PhotonBudget()
    profile, direct = _band()
    gain, _ = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, 0.5)
    captured = capture_lamp(
        profile, direct, SLIT, budget, SENSOR, gain, [1.0], [0.02], np.random.default_rng(1)
    )
    np.testing.assert_allclose(
        captured.direct / direct, 1.02, atol=5 * float(np.max(captured.direct_sigma / direct))
    )


@pytest.mark.parametrize("merge_gains", [False, True])
def test_the_spots_soft_edges_give_each_channel_its_own_frame_errors_unless_the_merge_estimates_them(
    merge_gains: bool,
) -> None:
    # Decision 0087's failure in 1-D: the spot's core comes from the short frames, its edges from
    # the long ones, in a mix that differs per channel; frames off their recorded times by ±3 %
    # then put the channels' direct-to-band ratios apart by far more than their σ — unless the
    # merge estimates each frame's gain (decision 0089).
    budget = replace(PhotonBudget(), merge_gains=merge_gains)
    profile, direct = _band()
    # a bright spot (the band needs long frames) whose channels lie at different levels
    direct = direct * np.array([10.0, 2.5, 40.0])
    gain, factors = budget.bracket(profile, direct, SENSOR, SLIT.spot_px, 0.9)
    assert len(factors) >= 3
    errors = 0.03 * np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0])[: len(factors)]
    captured = capture_lamp(
        profile, direct, SLIT, budget, SENSOR, gain, factors, errors, np.random.default_rng(5)
    )
    ratio = (captured.direct / direct) / (captured.profile.sum(axis=0) / profile.sum(axis=0))
    sigma = captured.direct_sigma / captured.direct
    spread = float(ratio.max() - ratio.min()) / float(np.sqrt(np.sum(sigma**2)))
    if merge_gains:
        assert spread < 4
        assert any(g != 1.0 for g in captured.frame_gains)
    else:
        assert spread > 10
        assert captured.frame_gains == (1.0,) * len(factors)
