"""A real camera with the twin's lamps and spectrometer: ``devices.camera.kind: gphoto2`` beside twin
relays and a twin spectrometer. The camera is opened by the real driver through python-gphoto2's
seam (:func:`drivers.camera.detect.load_gphoto2`), here the fake gphoto2 module with a Canon body that
photographs the twin's own lamps — so the capture, the estimate and the replay run end to end."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from drivers.camera import detect
from mocks.bench.camera import FrameRenderer
from mocks.bench.optics import TwinOptics
from mocks.bench.spec import TwinSpec
from mocks.fake_gphoto2 import FakeGphoto2, canon_eos_body
from rig.capture import run_capture
from rig.config import RigConfig
from rig.estimate import estimate_session
from rig.replay import replay_session
from rig.session import read_session
from rig.station_devices import Station, TranscriptFactory
from rig.twin import open_twin_bench, station_of
from tests.rig.twin_setup import twin_config, twin_config_data


def test_a_real_camera_photographs_the_twins_lamps(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = twin_config_data(tmp_path / "sessions")
    data["devices"]["camera"] = {"kind": "gphoto2", "model": "Canon EOS 5D Mark III"}
    config = RigConfig.model_validate(data)
    assert config.devices.twin_roles() == ("spectrometer", "relays")
    # What the body "sees": the small twin's camera, optics and grating, lit by the bench's lamps.
    camera_spec = TwinSpec.from_config_data(twin_config().model_dump(mode="json")).twin_camera

    def builder(rig_config: RigConfig, transcripts: TranscriptFactory) -> Station:
        bench: Any = open_twin_bench(rig_config, transcripts)
        assert bench.camera is None  # the twin leaves the camera to the rig
        renderer = FrameRenderer(
            TwinOptics.build(camera_spec), bench.bank, bench.clock, seed=7, download_s=0.0
        )
        body = canon_eos_body(frame_source=renderer, clock=bench.clock)
        # python-gphoto2 as the drivers import it (drivers.libraries.gphoto2, through detect).
        monkeypatch.setattr(detect, "gphoto2", lambda: FakeGphoto2([body]))
        return station_of(bench, rig_config, transcripts)

    outcome = run_capture(config, builder=builder)
    assert outcome.exit_status == "success", outcome
    session = read_session(outcome.session)
    start = session.start
    assert start is not None
    assert start.devices["camera"].model == "Canon EOS 5D Mark III"
    assert start.devices["spectrometer"].model == "PR-655"
    frames = [r for r in session.files() if r.role == "frame"]
    assert frames and all(r.size > 10_000 for r in frames)  # the body's renders, as DNG
    result = estimate_session(outcome.session, tmp_path / "estimate", report=False).estimate.result
    assert np.all(np.isfinite(result.sensitivity))
    # The replay needs no camera of its own: it serves the recorded downloads.
    replay = replay_session(outcome.session, tmp_path / "replay")
    assert replay.identical, replay
