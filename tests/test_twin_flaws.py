"""The twin camera's stray light along the band and its shutter error (mocks.bench.flaws, decision 0087)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from calib.evaluation.validation.rig_errors import ExposureTimeError, StrayLight
from calib.image.raw import read_raw
from mocks.bench import TwinOptics, TwinSpec
from mocks.bench.camera import FrameRenderer
from mocks.bench.flaws import (
    PROTOCOL_BAND_PX,
    CameraFlaws,
    camera_flaws,
    draw_camera_flaws,
)
from mocks.bench.lamps import virtual_lamp
from mocks.bench.optics import visible_band_px
from mocks.bench.spec import TwinSpecError
from mocks.fake_gphoto2 import FrameRequest
from mocks.lamps import LampBank, SimulatedClock
from mocks.scene import SceneLayout, SensorModel, render_mosaic_radiance, smooth_signal
from rig.config import RigConfig
from rig.twin import read_twin_truth, write_twin_truth
from tests.rig.twin_setup import twin_config_data, twin_spec


def test_the_stray_light_lies_on_the_band_in_a_lorentzian_wing() -> None:
    sensor = SensorModel(height_px=200, width_px=1000, read_noise_dn=0.0)
    clean = SceneLayout(spot_centre_px=(60.0, 100.0), band_half_width_px=40.0)
    stray = SceneLayout(
        spot_centre_px=(60.0, 100.0),
        band_half_width_px=40.0,
        stray_fraction=0.005,
        stray_wing_px=300,
    )
    signal = smooth_signal(start_px=300.0, stop_px=900.0)
    added = render_mosaic_radiance(stray, signal, sensor) - render_mosaic_radiance(
        clean, signal, sensor
    ).astype(np.float64)
    # A red site on the band's centre row, between the spot and the first order (dark without it).
    row, column = 100, 200
    u = column - 60.0
    expected = 0.005 * signal.direct_rgb[0] / 80.0 * (300 / math.pi) / (300**2 + u**2)
    assert added[row, column] == pytest.approx(expected, rel=1e-4)
    # Beside the band (where the background strips are) there is none; on the −1 side there is.
    assert np.all(added[:50] == 0) and np.all(added[150:] == 0)
    assert added[row, 20] > 0
    # The wing holds the fraction of the spot's light: its integral along u is 1.
    u_axis = np.linspace(-1e6, 1e6, 2_000_001)
    assert np.trapezoid(stray.stray_wing(u_axis), u_axis) == pytest.approx(1.0, rel=1e-3)
    with pytest.raises(ValueError, match="half-width"):
        SceneLayout(spot_centre_px=(0.0, 0.0), stray_fraction=0.01)


def test_the_draw_is_the_protocols_and_the_seed_s() -> None:
    flaws = [draw_camera_flaws(seed) for seed in range(200)]
    assert draw_camera_flaws(7) == flaws[7]
    low, high = StrayLight().fraction_range
    assert all(low <= f.stray_fraction <= high for f in flaws)
    wing_low, wing_high = StrayLight().wing_range_px
    assert all(
        wing_low <= f.stray_wing_band * PROTOCOL_BAND_PX <= wing_high * (1 + 1e-12) for f in flaws
    )
    sigma_low, sigma_high = ExposureTimeError().sigma_range
    assert all(sigma_low <= f.exposure_sigma <= sigma_high for f in flaws)
    # Each frame's error is a function of the seed and its key, of σ exposure_sigma.
    one = CameraFlaws(0.0, 0.0, 0.02)
    assert one.frame_exposure_error(5, (1, 2)) == one.frame_exposure_error(5, (1, 2))
    errors = np.array([one.frame_exposure_error(5, (k,)) for k in range(2000)])
    assert np.std(errors) == pytest.approx(0.02, rel=0.1)


def test_the_switches_are_on_by_default_and_each_turns_one_off() -> None:
    spec = twin_spec()
    drawn = draw_camera_flaws(spec.seed)
    assert camera_flaws(spec) == drawn
    no_stray = camera_flaws(twin_spec(stray_light=False))
    assert no_stray == CameraFlaws(0.0, 0.0, drawn.exposure_sigma)
    exact = camera_flaws(twin_spec(shutter_error=False))
    assert exact == CameraFlaws(drawn.stray_fraction, drawn.stray_wing_band, 0.0)
    assert camera_flaws(twin_spec(stray_light=False, shutter_error=False)) is None
    with pytest.raises(ValueError, match="stray_light"):
        RigConfig.model_validate(twin_config_data(stray_light="maybe"))
    data = RigConfig.model_validate(twin_config_data()).model_dump(mode="json")
    data["devices"]["camera"]["shutter_error"] = "maybe"
    with pytest.raises(TwinSpecError, match=r"devices\.camera\.shutter_error"):
        TwinSpec.from_config_data(data)


def _frames(tmp_path: Path, flaws: CameraFlaws) -> tuple[TwinOptics, np.ndarray, np.ndarray]:
    """The LED's frame (1/50 s, frame 4, seed 3) of a clean camera and of one with ``flaws``:
    RGB planes above black."""
    spec = twin_spec()
    clock = SimulatedClock()
    lamp = virtual_lamp(spec.lamps[0])
    planes: list[np.ndarray] = []
    optics = TwinOptics.build(spec.twin_camera, flaws)
    for flawed in (None, flaws):
        renderer = FrameRenderer(
            TwinOptics.build(spec.twin_camera, flawed),
            LampBank([lamp], n_channels=2, clock=clock),
            clock,
            seed=3,
            download_s=0.0,
            flaws=flawed,
        )
        try:
            renderer.bank.set_channel(lamp.channel, True)
            request = FrameRequest(4, 1 / 50, {"iso": "100", "aperture": "8"}, "raw", 0.0, "twin")
            path = tmp_path / f"frame-{len(planes)}.dng"
            path.write_bytes(renderer(request))
            planes.append(read_raw(path).signal_dn.astype(np.float64))
        finally:
            renderer.close()
    return optics, planes[0], planes[1]


def test_the_twin_s_frames_show_the_wing_on_the_band(tmp_path: Path) -> None:
    flaws = CameraFlaws(0.006, 0.5, 0.0)
    optics, clean, flawed = _frames(tmp_path, flaws)
    assert optics.layout.stray_wing_px == pytest.approx(0.5 * visible_band_px(optics.mapping))
    # Between the spot and the first order, on the band's rows: the wing, far above the noise.
    x0, y0 = optics.layout.spot_centre_px
    start = optics.band_range_px[0]
    gap = slice(int(x0 + 0.3 * start) // 2, int(x0 + 0.7 * start) // 2)
    rows = slice(int(y0 - 50) // 2, int(y0 + 50) // 2)
    noise = clean[:, rows, gap].std() / math.sqrt(clean[:, rows, gap].size)
    assert flawed[:, rows, gap].mean() - clean[:, rows, gap].mean() > 20 * noise
    # Beside the band (the background strips' rows): none.
    beside = slice(0, int(y0 - optics.slit_length_px) // 2)
    assert abs(flawed[:, beside, gap].mean() - clean[:, beside, gap].mean()) < 3 * noise


def test_the_twin_s_frames_are_exposed_with_the_shutter_s_error(tmp_path: Path) -> None:
    flaws = CameraFlaws(0.0, 0.0, 0.03)
    optics, clean, flawed = _frames(tmp_path, flaws)
    epsilon = flaws.frame_exposure_error(3, (4,))
    assert abs(epsilon) > 5e-3  # this draw is told from an exact shutter
    x0, y0 = optics.layout.spot_centre_px
    rows = slice(int(y0 - 100) // 2, int(y0 + 100) // 2)
    band = slice(int(x0 + optics.band_range_px[0]) // 2, None)
    ratio = flawed[:, rows, band].sum() / clean[:, rows, band].sum()
    assert ratio == pytest.approx(1.0 + epsilon, abs=2e-3)


def test_the_truth_records_the_draw(tmp_path: Path) -> None:
    data = twin_config_data()
    data["seed"] = 11
    path = write_twin_truth(RigConfig.model_validate(data), tmp_path)
    record = read_twin_truth(path).camera_flaws
    drawn = draw_camera_flaws(11)
    assert record is not None
    assert record["stray_fraction"] == drawn.stray_fraction
    assert record["exposure_sigma"] == drawn.exposure_sigma
    assert record["stray_wing_px"] > 0
    data["devices"]["camera"].update(stray_light=False, shutter_error=False)
    (tmp_path / "off").mkdir()
    off = read_twin_truth(write_twin_truth(RigConfig.model_validate(data), tmp_path / "off"))
    assert off.camera_flaws is None
