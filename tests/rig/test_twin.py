"""End to end on the digital twin: the real runner, plan and drivers on emulated hardware.

Captures use the small twin of :mod:`tests.rig.twin_setup` (640×320 frames). Determinism: the same
seed gives byte-identical frames and spectra; faults injected into the emulators reach the rig.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from calib.image.raw import read_raw_metadata
from mocks.bench import TwinBench, TwinFaults
from mocks.fake_gphoto2 import CameraFault
from mocks.faults import Fault, FaultKind, FaultRule, FaultSchedule
from mocks.usb_relay_backend import UsbFault
from rig.capture import run_capture
from rig.config import RigConfig
from rig.records import FileRecord, RetryRecord, StepRecord
from rig.runner import RetryPolicy, RunOutcome
from rig.session import Session, read_session
from rig.twin import TwinConfigError, open_twin_bench, twin_station_builder
from tests.rig.twin_setup import twin_config, twin_config_data

FAST_RETRY = RetryPolicy(max_attempts=3, initial_s=0.01, max_s=0.01)


def _capture(directory: Path, **options: Any) -> tuple[RunOutcome, Session]:
    config: RigConfig = options.pop("config", None) or twin_config(directory / "sessions")
    outcome = run_capture(config, retry=FAST_RETRY, **options)
    return outcome, read_session(outcome.session)


def _files(session: Session) -> dict[str, str]:
    """sha256 of every frame and spectrum the session acknowledges, by path."""
    return {
        r.path: r.sha256
        for r in session.records
        if isinstance(r, FileRecord) and r.role != "transcript"
    }


def _done(session: Session, action: str) -> list[StepRecord]:
    return [
        r
        for r in session.records
        if isinstance(r, StepRecord) and r.action == action and r.status == "done"
    ]


@pytest.fixture(scope="module")
def captured(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunOutcome, Session]:
    return _capture(tmp_path_factory.mktemp("twin"))


def test_a_capture_on_the_twin_completes_with_real_dng_frames(
    captured: tuple[RunOutcome, Session],
) -> None:
    outcome, session = captured
    assert outcome.exit_status == "success", outcome
    assert session.status == "complete" and session.verify_files() == []
    start = session.start
    assert start is not None and start.clock == "SimulatedClock"
    assert start.devices["spectrometer"].model == "PR-655"
    assert start.devices["relays"].serial == "TWIN1"
    assert start.devices["camera"].model == "spectral-rig TwinCam"
    stop = session.stop
    assert stop is not None and stop.lamps_off
    config = twin_config()
    for lamp in config.lamps:
        scenes = [r for r in _done(session, "Capture") if r.params["lamp"] == lamp.name]
        assert len(scenes) >= 2  # the start exposure saturates the spot: the bracket extends
        by_exposure = sorted(scenes, key=lambda r: r.params["exposure_s"])
        shortest, longest = by_exposure[0].result, by_exposure[-1].result
        assert shortest is not None and longest is not None
        assert (
            shortest["stats"]["direct_saturated_fraction"]
            <= config.hdr.max_direct_saturated_fraction
        )
        assert longest["stats"]["band_snr"] >= config.hdr.min_band_snr
        for record in scenes:
            assert record.result is not None
            metadata = read_raw_metadata(session.path / record.result["file"])
            assert metadata.exposure_s == pytest.approx(record.params["exposure_s"])
            assert metadata.iso == 100 and metadata.f_number == 8
        darks = [r for r in _done(session, "DarkFrame") if r.params["lamp"] == lamp.name]
        assert len(darks) == len(scenes) * config.dark_frames
        warmup = [
            r.result["time_s"]
            for r in _done(session, "MeasureSpectrum")
            if r.params["lamp"] == lamp.name and r.params["purpose"] == "warmup" and r.result
        ]
        # The warm-up ran on the twin's clock: spectra interval_s apart, however fast the test.
        assert warmup[1] - warmup[0] == pytest.approx(lamp.warmup.interval_s, abs=0.5)
    transcripts = {
        r.path for r in session.records if isinstance(r, FileRecord) and r.role == "transcript"
    }
    assert transcripts == {
        "transcripts/camera.jsonl",
        "transcripts/relays.jsonl",
        "transcripts/spectrometer.jsonl",
    }


def test_the_same_seed_gives_the_same_frames_and_spectra(
    captured: tuple[RunOutcome, Session], tmp_path: Path
) -> None:
    _, first = captured
    _, again = _capture(tmp_path / "again")
    assert _files(again) == _files(first)
    reseeded = twin_config(tmp_path / "other" / "sessions").model_copy(update={"seed": 8})
    _, other = _capture(tmp_path / "other", config=reseeded)
    frames = [path for path in _files(first) if path.startswith("frames/")]
    assert all(_files(other).get(path) != _files(first)[path] for path in frames)


@pytest.mark.usefixtures("fast_camera_recovery")
def test_a_busy_camera_is_recovered_by_its_driver(tmp_path: Path) -> None:
    opened: list[TwinBench] = []
    faults = TwinFaults(camera=[CameraFault("busy", skip=1, times=2)])
    builder = twin_station_builder(faults=faults, on_open=opened.append)
    outcome, session = _capture(tmp_path, builder=builder)
    assert outcome.exit_status == "success", outcome
    body = opened[0].camera_body
    assert body is not None
    frames = len(_done(session, "Capture")) + len(_done(session, "DarkFrame"))
    assert [fault.fired for fault in body.faults] == [2]
    assert body.count("capture") == frames + 2  # two busy answers, retried inside the driver


def test_a_garbled_spectrum_is_retried_by_the_runner(tmp_path: Path) -> None:
    schedule = FaultSchedule([FaultRule(Fault(FaultKind.GARBLED_REPLY), match="M5", nth=2)])
    outcome, session = _capture(
        tmp_path, builder=twin_station_builder(faults=TwinFaults(spectrometer=schedule))
    )
    assert outcome.exit_status == "success", outcome
    retries = [r for r in session.records if isinstance(r, RetryRecord)]
    assert [r.error.reason for r in retries] == ["protocol"]
    assert retries[0].key == "lamp/LED-B3/warmup/001"


def test_a_stuck_relay_stops_the_run_before_any_frame(tmp_path: Path) -> None:
    faults = TwinFaults(usb_relays=[UsbFault("stuck_relay", channel=1, times=None)])
    outcome, session = _capture(tmp_path, builder=twin_station_builder(faults=faults))
    assert outcome.exit_status == "fail" and outcome.reason == "state_mismatch"
    assert outcome.failed_key == "lamp/LED-B3/switch-on" and outcome.lamps_off
    assert not _done(session, "Capture")


def test_a_configuration_the_twin_cannot_simulate_fails_before_any_device(tmp_path: Path) -> None:
    config = twin_config(tmp_path / "sessions", sensitivity="Nikon D9999")
    with pytest.raises(
        TwinConfigError, match=r"devices\.camera\.sensitivity: .*Nikon D9999"
    ) as error:
        run_capture(config)
    assert error.value.exit_code == 2
    assert not (tmp_path / "sessions").exists()  # nothing opened, so no session either


@pytest.mark.parametrize("emulate", ["hid_usbrelay", "numato"])
def test_relays_left_on_by_a_dead_process_are_on_for_the_next(tmp_path: Path, emulate: str) -> None:
    state_file = tmp_path / "relays.state"
    data = twin_config_data(tmp_path / "sessions")
    data["devices"]["relays"] |= {"emulate": emulate, "state_file": str(state_file)}
    config = RigConfig.model_validate(data)
    first = open_twin_bench(config)
    first.relays.set(1, True)
    # The process dies: nothing switches the relay off, the emulators just stop.
    first.close()
    assert state_file.read_text().strip() == "10"
    second: Any = open_twin_bench(config)  # the bench itself (mocks.bench.TwinBench)
    try:
        assert second.relays.state() == (True, False)
        assert [lamp.name for lamp, _ in second.bank.lit()] == ["LED-B3"]
    finally:
        for device in (second.camera, second.spectrometer, second.relays):
            device.close()
        second.close()
    # A capture switches every lamp off first, and leaves them off.
    outcome, _ = _capture(tmp_path, config=config)
    assert outcome.exit_status == "success" and state_file.read_text().strip() == "00"
    state_file.write_text("1x\n")
    with pytest.raises(TwinConfigError, match=r"state_file: .* holds '1x', not one 0/1"):
        open_twin_bench(config)
