"""The ArgyllCMS driver against the fake ``spotread`` on a real pseudo-terminal: the reading, every
error spotread reports mapped to its typed error, the deadline, a missing ArgyllCMS, and the
transcript a replay serves back byte for byte."""

from __future__ import annotations

import json
import os
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.base import (
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ListTranscript,
    ProtocolError,
)
from drivers.spectrometer.argyll import ArgyllSettings, ArgyllSpotread, open_argyll
from drivers.spectrometer.cgats import CgatsError, parse_sp
from drivers.spectrometer.errors import MeasurementConditionError
from mocks.replay.script import CheckingSink, Mismatches, ReplayScript
from mocks.replay.spotread import ReplaySpotreadLauncher
from mocks.spotread_launcher import FAKE_SPOTREAD, FakeSpotreadLauncher

STANDARD_VALUES = [10.0 + k for k in range(36)]
STANDARD = {"start_nm": 380.0, "end_nm": 730.0, "values": STANDARD_VALUES}
HIGH = {"start_nm": 380.0, "end_nm": 730.0, "values": [5.0 + k / 3 for k in range(106)]}


def scene(fault: str | None = None, **extra: object) -> dict[str, object]:
    return {
        "instruments": 1,
        "fault": fault,
        "spectra": {"standard": STANDARD, "high_resolution": HIGH},
        **extra,
    }


def instrument(
    fault: str | None = None, *, timeout_s: float = 10.0, high_resolution: bool = False
) -> tuple[ArgyllSpotread, ListTranscript]:
    transcript = ListTranscript()
    launcher = FakeSpotreadLauncher(lambda: scene(fault))
    settings = ArgyllSettings(timeout_s=timeout_s, high_resolution=high_resolution)
    return open_argyll(settings, launcher=launcher, transcript=transcript, resolve=False), (
        transcript
    )


def test_a_reading_is_the_saved_spectrum_with_its_units_and_bandwidth() -> None:
    device, transcript = instrument()
    reading = device.measure()
    np.testing.assert_allclose(reading.wavelength_nm, np.arange(380.0, 731.0, 10.0))
    np.testing.assert_allclose(reading.values, STANDARD_VALUES, rtol=1e-6)
    assert reading.units == "mW/(m²·nm)"
    assert reading.bandwidth_nm == 25.0
    call = next(entry for entry in transcript.entries if entry.direction == "call")
    assert json.loads(call.payload) == {"argv": ["spotread", "-a", "-s", "-N", "-O", "reading.sp"]}
    last = transcript.entries[-1]
    assert last.direction == "return"
    ended = json.loads(last.payload)
    assert ended["status"] == 0 and ended["file"].startswith("SPECT")
    assert transcript.entries[-2].direction == "rx" and transcript.entries[-2].payload == b""
    output = b"".join(e.payload for e in transcript.entries if e.direction == "rx").decode()
    assert "Place instrument on spot to be measured" in output
    assert "Writing file 'reading.sp' succeeded" in output


def test_high_resolution_runs_with_minus_h_and_reads_the_3_3_nm_bands() -> None:
    assert ArgyllSettings().high_resolution  # the default: a grating rig needs the detail
    device, transcript = instrument(high_resolution=True)
    reading = device.measure()
    assert reading.values.size == 106
    np.testing.assert_allclose(np.diff(reading.wavelength_nm), 350.0 / 105.0)
    assert reading.bandwidth_nm == 15.0 and reading.extra["high_resolution"] == "on"
    call = next(entry for entry in transcript.entries if entry.direction == "call")
    assert "-H" in json.loads(call.payload)["argv"]


def test_a_model_without_high_resolution_bands_reads_its_standard_ones_at_their_bandwidth() -> None:
    """spotread honours -H "if available": the sampling, not the request, sets the bandwidth."""
    transcript = ListTranscript()
    standard_only = {"instruments": 1, "fault": None, "spectra": {"standard": STANDARD}}
    launcher = FakeSpotreadLauncher(lambda: standard_only)
    settings = ArgyllSettings(timeout_s=10.0, high_resolution=True)
    device = open_argyll(settings, launcher=launcher, transcript=transcript, resolve=False)
    reading = device.measure()
    assert reading.values.size == 36
    assert reading.bandwidth_nm == 25.0 and reading.extra["high_resolution"] == "off"
    call = next(entry for entry in transcript.entries if entry.direction == "call")
    assert "-H" in json.loads(call.payload)["argv"]


@pytest.mark.parametrize(
    ("fault", "error", "retryable", "says"),
    [
        ("no_instrument", DeviceNotFound, False, "no instrument at port 1"),
        ("comms", Disconnected, False, "cannot talk to the instrument"),
        ("init", InstrumentError, False, "failed to initialise"),
        ("no_ambient", InstrumentError, False, "does not measure ambient light"),
        ("needs_calibration", InstrumentError, False, "spotread -a -O"),
        ("misread", MeasurementConditionError, True, "misread the light"),
        ("comms_problem", ProtocolError, True, "lost the instrument's communication"),
        ("wrong_position", InstrumentError, False, "wrong position"),
        ("not_spectral", InstrumentError, False, "colorimeter"),
        ("fatal", InstrumentError, False, "Lamp failure"),
        ("garbled_file", ProtocolError, True, "not a number"),
    ],
)
def test_what_spotread_reports_becomes_a_typed_error(
    fault: str, error: type[DeviceError], retryable: bool, says: str
) -> None:
    device, transcript = instrument(fault)
    with pytest.raises(error, match=says) as raised:
        device.measure()
    assert type(raised.value) is error
    assert raised.value.retryable is retryable
    # Every prompt that waited for a key got "q", and the run's end was recorded.
    assert transcript.entries[-1].direction == "return"
    keys = [entry.payload for entry in transcript.entries if entry.direction == "tx"]
    assert set(keys) <= {b"q"}
    if fault in ("needs_calibration", "misread", "comms_problem"):
        assert keys == [b"q"]


def test_a_silent_spotread_is_killed_at_the_deadline() -> None:
    device, transcript = instrument("hang", timeout_s=0.5)
    with pytest.raises(DeviceTimeout, match=r"did not finish within 0\.5 s") as raised:
        device.measure()
    assert raised.value.retryable
    ended = json.loads(transcript.entries[-1].payload)
    assert ended["file"] is None and ended["status"] == -9


def test_a_missing_argyll_says_how_to_install_it(tmp_path: Path) -> None:
    with pytest.raises(DeviceNotFound, match="apt-get install argyll"):
        open_argyll(ArgyllSettings(executable=str(tmp_path / "spotread")))
    with pytest.raises(DeviceNotFound, match="apt-get install argyll"):
        open_argyll(ArgyllSettings(executable="no-such-spotread-here"))


def test_the_executable_on_path_runs_on_a_terminal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The real launcher: a ``spotread`` found on PATH (here a wrapper around the fake)."""
    wrapper = tmp_path / "spotread"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{FAKE_SPOTREAD}" "$@"\n')
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR)
    scene_file = tmp_path / "scene.json"
    scene_file.write_text(json.dumps(scene()))
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}")
    monkeypatch.setenv("FAKE_SPOTREAD_SCENE", str(scene_file))
    device = open_argyll(ArgyllSettings(instrument=1, timeout_s=10.0))
    assert device.executable == str(wrapper)
    assert device.identify().extra["executable"] == str(wrapper)
    assert device.measure().values.size == 106  # -H by default: the 3.3 nm bands


def test_spotread_chooses_its_own_integration_time() -> None:
    device, _ = instrument()
    device.set_exposure(None)
    with pytest.raises(ValueError, match="exposure_ms to null"):
        device.set_exposure(100.0)


@pytest.mark.parametrize("fault", [None, "misread", "hang"])
def test_a_recorded_run_replays_byte_for_byte(fault: str | None) -> None:
    device, recorded = instrument(fault, timeout_s=0.5)
    outcome: list[object] = []
    for attempt in (1, 2):
        try:
            outcome.append(device.measure().values.tolist())
        except DeviceError as exc:
            outcome.append(type(exc))
        del attempt
    script = ReplayScript("spectrometer", recorded.entries, Mismatches())
    replayed = ListTranscript()
    replay = open_argyll(
        ArgyllSettings(timeout_s=0.5, high_resolution=False),
        launcher=ReplaySpotreadLauncher(script),
        transcript=CheckingSink(script, replayed),
        resolve=False,
    )
    again: list[object] = []
    for _ in (1, 2):
        try:
            again.append(replay.measure().values.tolist())
        except DeviceError as exc:
            again.append(type(exc))
    assert again == outcome
    assert [(e.direction, e.payload) for e in replayed.entries] == [
        (e.direction, e.payload) for e in recorded.entries
    ]
    assert script.finish() is None


def test_argylls_own_spectrum_files_parse(tmp_path: Path) -> None:
    reference = Path("/usr/share/color/argyll/ref/CIE_C.sp")
    if reference.is_file():
        spectrum = parse_sp(reference.read_text(encoding="latin-1"), str(reference))
        assert spectrum.values.shape == (1, 93)
        assert spectrum.wavelength_nm[0] == 320.0 and spectrum.wavelength_nm[-1] == 780.0
        assert spectrum.values.max() == pytest.approx(1.2409)  # 124.09, SPECTRAL_NORM 100
    with pytest.raises(CgatsError, match="not an ArgyllCMS spectrum file"):
        parse_sp("CGATS.17\n", "x.sp")
    with pytest.raises(CgatsError, match="no SPECTRAL_START_NM"):
        parse_sp('SPECT\nSPECTRAL_BANDS "2"\n', "x.sp")
