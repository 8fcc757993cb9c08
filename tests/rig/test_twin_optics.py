"""The twin's physics: lamps, per-pixel integration consistent with calib.model.forward, frames, emulated models."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calib.core.spectra import Spectrum
from calib.image.raw import read_raw, read_raw_metadata
from calib.model.forward import render_observation
from mocks.bench import TwinOptics, TwinSpec, TwinSpecError, open_twin
from mocks.bench.camera import ExposureSettings, FrameRenderer
from mocks.bench.lamps import drift_coefficients, spectral_components, virtual_lamp
from mocks.bench.optics import SPECTRAL_STEP_NM
from mocks.bench.spec import RelayModel, SpectrometerModel
from mocks.fake_gphoto2 import FrameRequest
from mocks.lamps import LampBank, SimulatedClock, VirtualLamp
from mocks.scene import (
    BAYER_SITES,
    PixelFootprint,
    PixelIntegratedSignal,
    SceneSignal,
    render_mosaic_radiance,
)
from tests.rig.twin_setup import twin_spec


@pytest.fixture(scope="module")
def spec() -> TwinSpec:
    return twin_spec()


@pytest.fixture(scope="module")
def fluorescent(spec: TwinSpec) -> VirtualLamp:
    return virtual_lamp(spec.lamps[1])


def _forward_per_pixel(optics: TwinOptics, lamp: Spectrum, pixel: np.ndarray) -> np.ndarray:
    """calib.model.forward's unblurred per-pixel integrals, scaled as the twin scales the band."""
    rendered = render_observation(
        lamp,
        optics.sensitivity,
        mapping=optics.mapping,
        pixel=pixel,
        grating_efficiency=optics.efficiency,
        zeroth_order_efficiency=optics.zeroth_order_efficiency,
        fine_step_nm=SPECTRAL_STEP_NM,
    )
    scale = optics.throughput_e_per_s * optics.sensor.gain_dn_per_electron
    return rendered.clean_profile * scale / optics.slit_length_px


def test_axis_aligned_pixels_receive_forwards_per_pixel_integrals(
    spec: TwinSpec, fluorescent: VirtualLamp
) -> None:
    optics = TwinOptics.build(spec.twin_camera)
    signal = optics.first_order(fluorescent.spectrum, blur=False).signal
    # Pixel centres at a sub-pixel offset from the spot, over the whole band (sharp mercury lines).
    pixel = np.arange(200.37, 420.0, 1.0)
    expected = _forward_per_pixel(optics, fluorescent.spectrum, pixel)
    np.testing.assert_allclose(
        signal.per_pixel(pixel), expected, rtol=0, atol=2e-4 * expected.max()
    )


def test_the_2d_frame_along_the_band_is_forwards_profile(
    spec: TwinSpec, fluorescent: VirtualLamp
) -> None:
    level = dataclasses.replace(spec.twin_camera.grating, dispersion_angle_deg=0.0)
    camera = dataclasses.replace(
        spec.twin_camera,
        grating=level,
        optics=dataclasses.replace(spec.twin_camera.optics, spot_position_px=(101.3, 160.6)),
    )
    optics = TwinOptics.build(camera)
    signal = optics.first_order(fluorescent.spectrum, blur=False).signal
    mosaic = render_mosaic_radiance(optics.layout, signal, optics.sensor)
    x0, y0 = optics.layout.spot_centre_px
    row = round(y0)
    columns = np.arange(300, 520)
    expected = _forward_per_pixel(optics, fluorescent.spectrum, columns - x0)
    sites = BAYER_SITES[optics.sensor.cfa_pattern]
    for channel, name in enumerate("RGB"):
        for site_row, site_column in sites[name]:
            if row % 2 != site_row:
                continue
            chosen = columns % 2 == site_column
            np.testing.assert_allclose(
                mosaic[row, columns[chosen]],
                expected[chosen, channel],
                rtol=1e-5,
                atol=1e-4 * expected.max(),
            )


def test_turned_pixels_integrate_their_whole_footprint() -> None:
    # A line 0.6 px wide: how a pixel turned by 25° samples it is all in the footprint.
    position = np.arange(-20.0, 20.0, 1 / 64)
    density = np.exp(-0.5 * (position / 0.6) ** 2)[:, None] * np.array([1.0, 0.5, 0.25])
    trapezoids = (density[1:] + density[:-1]) / 2 / 64
    cumulative = np.concatenate([np.zeros((1, 3)), np.cumsum(trapezoids, axis=0)])
    signal = PixelIntegratedSignal(np.zeros(3), position, cumulative)
    angle = np.radians(25.0)
    footprint = PixelFootprint.at_angle(25.0)
    centres = np.linspace(-2.0, 2.0, 41)
    # Brute force: the mean density over a 200×200 grid of points in each turned pixel.
    grid = (np.arange(200) + 0.5) / 200 - 0.5
    s, t = np.meshgrid(grid, grid)
    offsets = (s * np.cos(angle) + t * np.sin(angle)).ravel()
    brute = np.array([np.interp(c + offsets, position, density[:, 0]).mean() for c in centres])
    integrated = signal.first_order(0, centres, footprint)
    np.testing.assert_allclose(integrated, brute, atol=1e-4 * brute.max())
    # Interpolating per-pixel values given at whole pixels instead misses by far more between them.
    nodes = np.arange(-20.0, 21.0)
    sampled = SceneSignal(np.zeros(3), nodes, signal.per_pixel(nodes)).first_order(
        0, centres, footprint
    )
    assert np.max(np.abs(sampled - brute)) > 0.05 * brute.max()


def test_the_slit_blur_keeps_the_light(spec: TwinSpec, fluorescent: VirtualLamp) -> None:
    optics = TwinOptics.build(spec.twin_camera)
    sharp = optics.first_order(fluorescent.spectrum, blur=False).signal
    blurred = optics.first_order(fluorescent.spectrum).signal
    np.testing.assert_allclose(blurred.cumulative[-1], sharp.cumulative[-1], rtol=1e-9)
    np.testing.assert_allclose(blurred.direct_rgb, sharp.direct_rgb)
    _, weights = optics.slit_profile()
    assert weights.sum() == pytest.approx(1.0)
    pixel = np.arange(200.0, 420.0)
    # The blur lowers the sharp lines' peaks.
    assert blurred.per_pixel(pixel).max() < sharp.per_pixel(pixel).max()


@pytest.mark.parametrize("lamp_index", [0, 1])
def test_two_components_mix_into_the_drifting_lamp(spec: TwinSpec, lamp_index: int) -> None:
    lamp = virtual_lamp(spec.lamps[lamp_index])
    components = spectral_components(lamp)
    axis = lamp.spectrum.wavelength_nm
    for seconds_on in (0.0, 7.5, 40.0, 1e4):
        weights = drift_coefficients(lamp, components, seconds_on)
        assert weights is not None
        mixed = sum(w * c.at(axis) for w, c in zip(weights, components, strict=True))
        np.testing.assert_allclose(mixed, lamp.radiance(axis, seconds_on), rtol=1e-9, atol=1e-15)


def test_a_drift_the_components_cannot_span_is_rendered_directly(spec: TwinSpec) -> None:
    steep = dataclasses.replace(
        spec.lamps[0], drift=dataclasses.replace(spec.lamps[0].drift, tilt=-0.49)
    )
    lamp = virtual_lamp(steep)
    # At switch-on the tilt drives the red end below zero, where the lamp's radiance is clipped.
    assert drift_coefficients(lamp, spectral_components(lamp), 0.0) is None
    optics = TwinOptics.build(spec.twin_camera)
    clock = SimulatedClock()
    bank = LampBank([lamp], n_channels=2, clock=clock)
    renderer = FrameRenderer(optics, bank, clock, seed=1, download_s=0.0)
    try:
        bank.set_channel(lamp.channel, True)
        settings = ExposureSettings(100.0, 8.0)
        direct = render_mosaic_radiance(
            optics.layout,
            optics.first_order(
                Spectrum(
                    lamp.spectrum.wavelength_nm, lamp.radiance(lamp.spectrum.wavelength_nm, 0.0)
                )
            ).signal,
            optics.sensor,
        )
        np.testing.assert_allclose(renderer.noiseless(settings), direct, rtol=1e-5)
    finally:
        renderer.close()


def test_frames_follow_exposure_iso_and_aperture(spec: TwinSpec, tmp_path: Path) -> None:
    optics = TwinOptics.build(spec.twin_camera)
    clock = SimulatedClock()
    lamps = [virtual_lamp(lamp) for lamp in spec.lamps]
    bank = LampBank(lamps, n_channels=2, clock=clock)
    renderer = FrameRenderer(optics, bank, clock, seed=3, download_s=0.75)
    try:
        bank.set_channel(1, True)
        base = renderer.noiseless(ExposureSettings(100.0, 8.0))
        np.testing.assert_allclose(
            renderer.noiseless(ExposureSettings(200.0, 8.0)), 2 * base, rtol=1e-6
        )
        np.testing.assert_allclose(
            renderer.noiseless(ExposureSettings(100.0, 4.0)), 4 * base, rtol=1e-6
        )

        def frame(index: int, exposure_s: float, iso: str = "100") -> Path:
            request = FrameRequest(
                index, exposure_s, {"iso": iso, "aperture": "8"}, "raw", clock.now(), "twin"
            )
            path = tmp_path / f"frame-{index}.dng"
            path.write_bytes(renderer(request))
            return path

        short, long_ = frame(1, 1 / 500), frame(2, 2.0)
        assert clock.now() == pytest.approx(1.5)  # two downloads on the twin's clock
        metadata = read_raw_metadata(short)
        assert (metadata.exposure_s, metadata.iso, metadata.f_number) == (1 / 500, 100.0, 8.0)
        assert metadata.model == "TwinCam"
        planes = read_raw(long_)
        assert planes.saturated.any()  # the direct spot clips at 2 s
        sensor = optics.sensor
        assert planes.signal_dn.max() <= sensor.white_level_dn - sensor.black_level_dn
        # Same seed and frame number: the same bytes; another frame number: other noise.
        assert frame(1, 1 / 500).read_bytes() == short.read_bytes()
        bank.set_channel(1, False)
        dark = read_raw(frame(3, 1 / 500))
        assert abs(float(dark.signal_dn.mean())) < 1.0  # black level subtracted, no light
    finally:
        renderer.close()


def test_specs_that_cannot_be_simulated_say_which_field() -> None:
    with pytest.raises(TwinSpecError, match=r"devices\.camera\.sensitivity: .*Nikon 5100"):
        TwinOptics.build(twin_spec(sensitivity="No Such Camera").twin_camera)
    with pytest.raises(TwinSpecError, match=r"beyond the 400×320 sensor"):
        TwinOptics.build(twin_spec(sensor={"width_px": 400, "height_px": 320}).twin_camera)
    with pytest.raises(TwinSpecError, match=r"grooves_per_mm = 1300.*fewer grooves"):
        TwinOptics.build(twin_spec(grating={"grooves_per_mm": 1300}).twin_camera)
    with pytest.raises(TwinSpecError, match=r"edge_px = 6 is wider than slit_width_px = 4"):
        TwinOptics.build(
            twin_spec(
                optics={"focal_length_mm": 4.8, "slit_length_px": 120, "edge_px": 6}
            ).twin_camera
        )
    lamp = dataclasses.replace(twin_spec().lamps[0], spd="LED-Z9")
    with pytest.raises(TwinSpecError, match=r"devices\.relays\.lamps\.LED-B3\.spd: 'LED-Z9'.*FL2"):
        virtual_lamp(lamp)


@pytest.mark.parametrize(
    ("spectrometer", "relays"), [("pr670", "lcus"), ("cs2000", "numato"), ("pr655", "hid_usbrelay")]
)
def test_every_emulated_model_serves_the_real_driver(
    spectrometer: SpectrometerModel, relays: RelayModel
) -> None:
    spec = dataclasses.replace(
        twin_spec(),
        spectrometer_model=spectrometer,
        relay_model=relays,
        spectrometer_time_scale=1e-3,
    )
    bench = open_twin(spec, prepare=False)
    try:
        assert bench.relays.state() == (False, False)
        bench.relays.set(2, True)
        assert bench.relays.state() == (False, True)
        assert [lamp.name for lamp, _ in bench.bank.lit()] == ["FL2"]
        assert bench.spectrometer is not None and bench.spectrometer_port is not None
        reading = bench.spectrometer.measure()
        # What the instrument's slit lets through: the lamp seen at its bandwidth, noise-free.
        emulator: Any = bench.spectrometer_port.emulator
        seen = emulator.radiometer.band_radiance()
        assert np.corrcoef(reading.values, seen)[0, 1] > 0.99
        bench.relays.all_off()
        assert bench.bank.lit() == []
    finally:
        for device in (bench.camera, bench.spectrometer, bench.relays):
            assert device is not None
            device.close()
        bench.close()


def test_a_sinusoidal_sheet_sends_each_order_its_own_efficiency(
    spec: TwinSpec, fluorescent: VirtualLamp
) -> None:
    """η₀(λ) = J₀² in the direct spot, and the second order only where the first has ≥ 2 × 380 nm."""
    from calib.model.gratings import SinusoidalPhaseGrating

    camera = spec.twin_camera
    grating = dataclasses.replace(
        camera.grating, model="sinusoidal", peak_phase_rad=1.4, zeroth_order_efficiency=None
    )
    optics = TwinOptics.build(dataclasses.replace(camera, grating=grating))
    sheet = SinusoidalPhaseGrating(1.4)
    axis = np.arange(400.0, 701.0, 10.0)
    for order, curve in enumerate(
        (optics.zeroth_order_efficiency, optics.efficiency, optics.second_order_efficiency)
    ):
        np.testing.assert_allclose(curve.at(axis), sheet.efficiency(order, axis), atol=1e-9)
    rendering = optics.first_order(fluorescent.spectrum, blur=False)
    expected = render_observation(
        fluorescent.spectrum,
        optics.sensitivity,
        mapping=optics.mapping,
        pixel=np.array([100.0, 200.0]),
        grating_efficiency=optics.efficiency,
        zeroth_order_efficiency=optics.zeroth_order_efficiency,
        fine_step_nm=SPECTRAL_STEP_NM,
    ).clean_direct
    np.testing.assert_allclose(rendering.signal.direct_rgb, expected * rendering.scale_dn_per_s)
    # Without the second order the band's red end holds less light; below 760 nm nothing changes.
    first_only = dataclasses.replace(
        optics, second_order_efficiency=optics.second_order_efficiency.scaled(0.0)
    )
    alone = first_only.first_order(fluorescent.spectrum, blur=False).signal
    red = float(optics.mapping.pixel_at(np.array([770.0]))[0])
    blue = float(optics.mapping.pixel_at(np.array([700.0]))[0])
    both = rendering.signal
    assert np.all(both.per_pixel(np.array([red]))[0] > alone.per_pixel(np.array([red]))[0])
    np.testing.assert_allclose(
        both.per_pixel(np.array([blue])), alone.per_pixel(np.array([blue])), rtol=1e-12
    )


def test_the_default_grating_is_a_sinusoidal_replica_sheet_with_its_own_zeroth_order(
    spec: TwinSpec,
) -> None:
    """Issue 17 item 4: the twin's default grating is physical — a thin sinusoidal sheet at the
    replica sheet's peak phase, every order (the direct spot's η₀ included) from its model."""
    from calib.model.gratings import REPLICA_SHEET_PEAK_PHASE_RAD, SinusoidalPhaseGrating
    from rig.config import TwinGratingConfig

    default = TwinGratingConfig()
    assert (default.model, default.peak_phase_rad, default.zeroth_order_efficiency) == (
        "sinusoidal",
        REPLICA_SHEET_PEAK_PHASE_RAD,
        None,
    )
    assert spec.twin_camera.grating.model == "sinusoidal"
    optics = TwinOptics.build(spec.twin_camera)
    sheet = SinusoidalPhaseGrating(REPLICA_SHEET_PEAK_PHASE_RAD)
    axis = np.arange(400.0, 701.0, 10.0)
    np.testing.assert_allclose(optics.zeroth_order_efficiency.at(axis), sheet.efficiency(0, axis))
    np.testing.assert_allclose(optics.efficiency.at(axis), sheet.efficiency(1, axis))
    # A replica sheet keeps a bright, reddish direct spot: η₀ rises 3× from 400 to 700 nm.
    assert (
        3.0
        < optics.zeroth_order_efficiency.at([700.0])[0]
        / optics.zeroth_order_efficiency.at([400.0])[0]
        < 4.0
    )
