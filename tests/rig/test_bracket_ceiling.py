"""The bracket ends only when the HDR merge can use every pixel of the spot and the band (decision 0186).

The estimator's extraction refuses a lamp whose direct spot or first-order band has a pixel that no
frame of the bracket gives the merge ("saturated in every frame"): saturated, or whose neighbours
average above the merge's ``prediction_fraction`` of the clipping level. The rig's bracket must
apply the same rule to its shortest frame, to the band as well as to the spot.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from calib.image.hdr import PREDICTION_FRACTION
from calib.image.raw import DEFAULT_SATURATION_FRACTION, read_raw
from calib.image.sensor_noise import leave_one_out_mean
from mocks.bench import TwinOptics
from rig.analysis import FrameStats
from rig.config import HdrPolicy
from rig.errors import BracketImpossible
from rig.frame_stats import RawFrameAnalyzer
from rig.plan import _next_exposure
from rig.session import read_session
from rig.steps import FrameCaptured
from tests.rig.fakes import write_config
from tests.rig.test_cli import run_cli
from tests.rig.test_frame_stats import Camera
from tests.rig.twin_setup import twin_config_data, twin_spec

LIMITS_S = (1 / 4000, 8.0)
#: A blazed sheet with a weak 0th order: the band is brighter per pixel than the direct spot.
BAND_BRIGHTER = {
    "model": "blazed",
    "first_order_peak_efficiency": 0.6,
    "zeroth_order_efficiency": 0.05,
}
#: A blazed sheet whose band clips over a wide stretch at 1/60 s while the spot is weaker.
CLIPPED_BAND = {
    "model": "blazed",
    "first_order_peak_efficiency": 0.6,
    "zeroth_order_efficiency": 0.15,
}


def frame(exposure_s: float, **stats: float) -> FrameCaptured:
    fields = {"direct_saturated_fraction": 0.0, "band_snr": 500.0, "band_signal_dn": 1e4} | stats
    return FrameCaptured(0.0, "f.dng", exposure_s, exposure_s, "/f", FrameStats(**fields))


class TestPlan:
    def test_an_unmergeable_band_asks_for_a_shorter_frame(self) -> None:
        # The band at 93 % of clipping: none of it saturated, all of it beyond the merge's 90 %.
        hdr = HdrPolicy()
        shortest = frame(1 / 250, band_unmergeable_fraction=0.4)
        assert _next_exposure([shortest, frame(1 / 60)], hdr, LIMITS_S, "LED-B3") == (
            pytest.approx(1 / 1000)
        )

    def test_only_the_band_bright_still_extends(self) -> None:
        # Spot clean (neither saturated nor near clipping), a single band pixel unmergeable.
        hdr = HdrPolicy()
        shortest = frame(1 / 250, band_unmergeable_fraction=0.0005)
        assert _next_exposure([shortest], hdr, LIMITS_S, "LED-B3") == pytest.approx(1 / 1000)
        clean = frame(1 / 1000)
        assert _next_exposure([clean, shortest], hdr, LIMITS_S, "LED-B3") is None

    def test_a_spot_below_the_saturated_allowance_but_unmergeable_extends(self) -> None:
        hdr = HdrPolicy()
        shortest = frame(
            1 / 250, direct_saturated_fraction=0.0005, direct_unmergeable_fraction=0.0008
        )
        assert _next_exposure([shortest], hdr, LIMITS_S, "LED-B3") == pytest.approx(1 / 1000)
        tolerant = HdrPolicy(max_unmergeable_fraction=0.001)
        assert _next_exposure([shortest], tolerant, LIMITS_S, "LED-B3") is None

    def test_at_the_shortest_exposure_it_names_the_lamp_the_band_and_the_remedy(self) -> None:
        shortest = frame(LIMITS_S[0], band_unmergeable_fraction=0.02)
        with pytest.raises(BracketImpossible) as caught:
            _next_exposure([shortest], HdrPolicy(), LIMITS_S, "FL2")
        message = str(caught.value)
        assert message.startswith("FL2: 2.00% of the first-order band is saturated or too near")
        assert (
            "even at the shortest allowed exposure 1/4000 s (allowed: hdr.max_unmergeable"
            in message
        )
        assert "neutral-density filter" in message


@pytest.fixture
def band_brighter(tmp_path: Path) -> Iterator[Camera]:
    camera = Camera(tmp_path, TwinOptics.build(twin_spec(grating=BAND_BRIGHTER).twin_camera))
    yield camera
    camera.renderer.close()


def test_a_band_at_93_percent_of_clipping_is_unmergeable(band_brighter: Camera) -> None:
    analyzer = RawFrameAnalyzer()
    probe_s = 1 / 1000
    probe = band_brighter.frame("LED-B3", probe_s)
    assert analyzer.analyse(probe).band_unmergeable_fraction == 0.0
    planes = read_raw(probe)
    level = leave_one_out_mean(planes.signal_dn, out=np.empty_like(planes.signal_dn))
    clip = np.asarray(planes.clip_level_dn, dtype=np.float32)[:, None, None]
    peak = float((level / clip).max())  # the band's peak: brighter than the spot on this sheet
    # The exposure that puts the band's peak at 93 % of clipping (the sensor is linear).
    exposure_s = float(probe_s * 0.93 / peak)
    stats = analyzer.analyse(band_brighter.frame("LED-B3", exposure_s))
    # The old criterion (the spot's saturated cells only) called this frame short enough ...
    assert stats.direct_saturated_fraction == 0.0
    assert stats.direct_unmergeable_fraction == 0.0
    # ... but the merge cannot use the band's brightest stretch from it.
    assert 0.0 < stats.band_unmergeable_fraction < 0.2
    assert stats.band_unmergeable_fraction > stats.band_saturated_fraction
    assert PREDICTION_FRACTION < 0.93 < DEFAULT_SATURATION_FRACTION  # the case's premise


def test_a_shorter_frame_redetects_a_geometry_found_on_a_clipped_frame(tmp_path: Path) -> None:
    optics = TwinOptics.build(twin_spec(grating=CLIPPED_BAND).twin_camera)
    camera = Camera(tmp_path, optics)
    try:
        analyzer = RawFrameAnalyzer()
        analyzer.analyse(camera.frame("LED-B3", 1 / 60))  # the band clips widely
        shorter = analyzer.analyse(camera.frame("LED-B3", 1 / 250))
        x0, y0 = optics.layout.spot_centre_px
        assert analyzer.geometries["LED-B3"].spot_centre_px == pytest.approx((x0, y0), abs=1.0)
        # The spot still clips at 1/250 s: the bracket must go shorter.
        assert shorter.direct_saturated_fraction > 0.05
        assert shorter.direct_unmergeable_fraction > 0.05
    finally:
        camera.renderer.close()


@pytest.mark.slow
def test_a_clipped_band_twin_session_brackets_until_the_estimate_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before decision 0186 this bracket ended at 1/60 + 1/250 s and the estimate failed with
    "the direct spot is saturated in every frame"."""
    pytest.importorskip("rig.estimate")
    data = twin_config_data(tmp_path / "sessions", grating=CLIPPED_BAND)
    data["lamps"] = [lamp for lamp in data["lamps"] if lamp["name"] == "LED-B3"]
    config = write_config(tmp_path / "rig.yaml", data)
    assert run_cli(["capture", "-c", str(config), "-q"], monkeypatch) == 0
    (session,) = (tmp_path / "sessions").iterdir()
    assert read_session(session).status == "complete"
    exposures = sorted(
        entry["params"]["exposure_s"]
        for entry in map(json.loads, (session / "log.jsonl").read_text().splitlines())
        if entry.get("action") == "Capture" and entry.get("status") == "done"
    )
    assert exposures == pytest.approx([1 / 1000, 1 / 250, 1 / 60])
    capsys.readouterr()
    assert run_cli(["estimate", str(session), "-q"], monkeypatch) == 0
    assert (session / "estimate" / "sensitivity.csv").is_file()
