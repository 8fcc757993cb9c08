"""The real frame analyser on frames rendered by the twin: saturation, band signal and SNR, failures."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from calib.image.hdr import HdrImage
from calib.image.profiles import DiffractionGeometry, detect_geometry
from calib.image.raw import DEFAULT_SATURATION_FRACTION
from mocks.bench import TwinOptics
from mocks.bench.camera import FrameRenderer
from mocks.bench.lamps import virtual_lamp
from mocks.fake_gphoto2 import FrameRequest
from mocks.lamps import LampBank, SimulatedClock
from rig import frame_stats
from rig.errors import FrameAnalysisError
from rig.frame_stats import RawFrameAnalyzer
from tests.rig.twin_setup import twin_spec


class Camera:
    """Renders frames of the small twin into ``frames/<lamp>/`` like a session does."""

    def __init__(self, directory: Path, optics: TwinOptics | None = None) -> None:
        spec = twin_spec()
        self.optics = optics or TwinOptics.build(spec.twin_camera)
        self.clock = SimulatedClock(1e6)  # long after switch-on: settled lamps
        self.bank = LampBank([virtual_lamp(lamp) for lamp in spec.lamps], 2, self.clock)
        self.renderer = FrameRenderer(self.optics, self.bank, self.clock, seed=5, download_s=0)
        self.directory = directory
        self.count = 0

    def frame(self, lamp: str | None, exposure_s: float, folder: str = "LED-B3") -> Path:
        for other in self.bank.lamps:
            self.bank.set_channel(other.channel, other.name == lamp)
        self.count += 1
        request = FrameRequest(
            self.count, exposure_s, {"iso": "100"}, "raw", self.clock.now(), "twin"
        )
        path = self.directory / "frames" / folder / f"scene-{self.count:03d}.dng"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(self.renderer(request))
        return path


@pytest.fixture
def camera(tmp_path: Path) -> Iterator[Camera]:
    rig_camera = Camera(tmp_path)
    yield rig_camera
    rig_camera.renderer.close()


def test_longer_frames_saturate_the_spot_and_raise_the_band(camera: Camera) -> None:
    analyzer = RawFrameAnalyzer()
    # The sheet's direct spot (η₀ 0.2–0.6) saturates at 1/500 s already.
    short = analyzer.analyse(camera.frame("LED-B3", 1 / 2000))
    middle = analyzer.analyse(camera.frame("LED-B3", 1 / 500))
    long_ = analyzer.analyse(camera.frame("LED-B3", 1 / 125))
    assert short.direct_saturated_fraction == 0.0
    assert long_.direct_saturated_fraction > 0.05
    assert short.band_saturated_fraction == middle.band_saturated_fraction == 0.0
    # Linear signal, shot-noise-limited SNR: ×4 exposure → ×4 signal, ×2 SNR.
    assert middle.band_signal_dn / short.band_signal_dn == pytest.approx(4.0, rel=0.05)
    assert middle.band_snr / short.band_snr == pytest.approx(2.0, rel=0.12)
    assert long_.band_snr > middle.band_snr


def test_the_geometry_is_detected_once_per_lamp(
    camera: Camera, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[HdrImage] = []

    def counting(image: HdrImage) -> DiffractionGeometry:
        calls.append(image)
        return detect_geometry(image)

    monkeypatch.setattr(frame_stats, "detect_geometry", counting)
    analyzer = RawFrameAnalyzer()
    for exposure_s in (1 / 250, 1 / 60, 1 / 15):
        analyzer.analyse(camera.frame("LED-B3", exposure_s))
    analyzer.analyse(camera.frame("FL2", 1 / 60, folder="FL2"))
    assert len(calls) == 2 and sorted(analyzer.geometries) == ["FL2", "LED-B3"]
    geometry = analyzer.geometries["LED-B3"]
    x0, y0 = camera.optics.layout.spot_centre_px
    assert geometry.spot_centre_px == pytest.approx((x0, y0), abs=0.5)


def test_a_frame_without_a_visible_band_asks_for_longer(tmp_path: Path) -> None:
    # A grating that sends almost nothing into the first order: only the spot is visible.
    optics = TwinOptics.build(twin_spec().twin_camera)
    dim = dataclasses.replace(optics, efficiency=optics.efficiency.scaled(1e-4))
    camera = Camera(tmp_path, dim)
    try:
        analyzer = RawFrameAnalyzer()
        short = analyzer.analyse(camera.frame("LED-B3", 1 / 8000))
        assert (short.band_snr, short.band_signal_dn, short.direct_saturated_fraction) == (0, 0, 0)
        long_ = analyzer.analyse(camera.frame("LED-B3", 1 / 15))
        assert long_.band_snr == 0.0 and long_.direct_saturated_fraction > 0.5
        assert analyzer.geometries == {}  # nothing cached until a band is seen
    finally:
        camera.renderer.close()


def test_frames_that_cannot_be_measured_say_why(camera: Camera, tmp_path: Path) -> None:
    analyzer = RawFrameAnalyzer()
    with pytest.raises(FrameAnalysisError, match="no direct spot"):
        analyzer.analyse(camera.frame(None, 1 / 60))
    jpeg = tmp_path / "frames" / "LED-B3" / "scene-009.jpg"
    jpeg.write_bytes(b"\xff\xd8\xff\xe0 not a raw file")
    with pytest.raises(FrameAnalysisError, match=r"scene-009\.jpg: cannot be decoded as a RAW"):
        analyzer.analyse(jpeg)


def test_a_band_off_the_frame_is_a_setup_problem(tmp_path: Path) -> None:
    optics = TwinOptics.build(twin_spec().twin_camera)
    shifted = dataclasses.replace(
        optics, layout=dataclasses.replace(optics.layout, spot_centre_px=(330.0, 160.0))
    )
    camera = Camera(tmp_path, shifted)
    try:
        with pytest.raises(FrameAnalysisError, match=r"band runs off the frame"):
            RawFrameAnalyzer().analyse(camera.frame("LED-B3", 1 / 60))
    finally:
        camera.renderer.close()


@pytest.mark.parametrize(
    "shape", [(3, 800, 1200), (3, 401, 603), (3, 2, 2), (3, 7, 2), (3, 180, 3), (3, 4, 9001)]
)
def test_the_detection_binning_is_numpys_block_mean_bit_for_bit(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(sum(shape))
    planes = (rng.standard_normal(shape) * 10 ** rng.uniform(-3, 5)).astype(np.float32)
    saturated = rng.random(shape) < 0.05
    height, width = shape[1] // 2 * 2, shape[2] // 2 * 2
    blocks = (3, height // 2, 2, width // 2, 2)
    expected = planes[:, :height, :width].reshape(blocks).mean(axis=(2, 4), dtype=np.float32)
    binned = frame_stats.binned_mean(planes[:, :height, :width])
    assert binned.dtype == np.float32
    np.testing.assert_array_equal(binned, expected)
    np.testing.assert_array_equal(
        frame_stats.binned_any(saturated[:, :height, :width]),
        np.any(saturated[:, :height, :width].reshape(blocks), axis=(2, 4)),
    )


def test_a_frame_is_detected_on_the_same_binned_image(camera: Camera) -> None:
    frame = camera.frame("LED-B3", 1 / 60)
    small = frame_stats._decode(frame, DEFAULT_SATURATION_FRACTION).image
    # The small twin's frames are within the detection size: tiled to a 961-sample wide frame
    # with odd sides, binned twice.
    image = dataclasses.replace(
        small,
        radiance=np.tile(small.radiance, (1, 4, 4))[:, :481, :961],
        variance=np.broadcast_to(np.float32(1.0), (3, 481, 961)),
        saturated=np.tile(small.saturated, (1, 4, 4))[:, :481, :961],
    )
    binned = frame_stats._detection_image(image)
    radiance, saturated, pitch = image.radiance, image.saturated, image.pixel_pitch_px
    while max(radiance.shape[1:]) > frame_stats.DETECTION_SIZE:
        height, width = (size // 2 * 2 for size in radiance.shape[1:])
        blocks = (3, height // 2, 2, width // 2, 2)
        radiance = radiance[:, :height, :width].reshape(blocks).mean(axis=(2, 4), dtype=np.float32)
        saturated = np.any(saturated[:, :height, :width].reshape(blocks), axis=(2, 4))
        pitch *= 2
    assert pitch > image.pixel_pitch_px  # binned at least once
    np.testing.assert_array_equal(binned.radiance, radiance)
    np.testing.assert_array_equal(binned.saturated, saturated)
    assert binned.pixel_pitch_px == pitch
