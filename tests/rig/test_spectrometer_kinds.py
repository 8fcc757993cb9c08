"""The spectrometers labs already own, through the whole rig: ArgyllCMS (the twin's fake spotread)
and measured spectrum files (a real "device" beside the twin's lamps and camera) — capture, replay
byte for byte, and what their configuration and files refuse."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.core.errors import SpectrumError
from drivers.base import DeviceNotFound, InstrumentError
from drivers.spectrometer.files import FilesSpectrometer, LampFile, SwitchedRelays
from mocks.bench.lamps import virtual_lamp
from mocks.fake_spotread import sp_text
from mocks.lamps import LampBank, SimulatedClock
from rig.capture import run_capture
from rig.config import ConfigError, RigConfig, parse_config
from rig.replay import replay_session
from rig.runner import RetryPolicy
from rig.session import decode_transcript_line, read_session
from rig.spectrum_files import read_measured_spectrum
from tests.rig.fakes import FakeRelayBoard
from tests.rig.twin_setup import twin_config_data, twin_spec

FAST_RETRY = RetryPolicy(max_attempts=3, initial_s=0.01, max_s=0.01)


def _transcript(session: Path, role: str) -> list[tuple[str, bytes]]:
    lines = (session / "transcripts" / f"{role}.jsonl").read_text().splitlines()
    return [(e.direction, e.payload) for e in map(decode_transcript_line, lines)]


def _lamp_files(directory: Path, bandwidth_nm: float = 1.5) -> dict[str, str]:
    """The twin's settled lamp spectra through a ``bandwidth_nm`` slit, as CSV files with a header."""
    directory.mkdir(parents=True, exist_ok=True)
    files = {}
    sigma = bandwidth_nm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    fine = np.arange(370.0, 790.0, 0.1)
    for lamp in twin_spec().lamps:
        wavelength = np.arange(380.0, 781.0, 1.0)
        weights = np.exp(-0.5 * ((wavelength[:, None] - fine[None, :]) / sigma) ** 2)
        values = weights @ virtual_lamp(lamp).spectrum.at(fine) / weights.sum(axis=1)
        path = directory / f"{lamp.name}.csv"
        rows = "".join(f"{w:g},{v:.6e}\n" for w, v in zip(wavelength, values, strict=True))
        path.write_text(
            f"# units: W/(sr·m²·nm)\n# bandwidth_nm: {bandwidth_nm:g}\nwavelength_nm,radiance\n"
            + rows
        )
        files[lamp.name] = path.name
    return files


# --------------------------------------------------------------------------------- argyll


def test_an_argyll_twin_session_captures_and_replays_byte_for_byte(tmp_path: Path) -> None:
    data = twin_config_data(tmp_path / "sessions")
    data["devices"]["spectrometer"] = {"kind": "twin", "emulate": "argyll", "timeout_s": 20}
    outcome = run_capture(RigConfig.model_validate(data), retry=FAST_RETRY)
    assert outcome.exit_status == "success", outcome
    session = read_session(outcome.session)
    spectra = [r for r in session.files() if r.role == "spectrum"]
    # spotread -H by default: the i1Pro's 3.3 nm bands, 15 nm FWHM.
    assert spectra and {r.bandwidth_nm for r in spectra} == {15.0}
    sent = [p for d, p in _transcript(outcome.session, "spectrometer") if d == "call"]
    argv = ["spotread", "-a", "-s", "-N", "-H", "-O", "reading.sp"]
    assert json.loads(sent[0]) == {"argv": argv}
    replay = replay_session(outcome.session, tmp_path / "replay")
    assert replay.identical and replay.run.exit_status == "success", replay
    assert _transcript(replay.run.session, "spectrometer") == _transcript(
        outcome.session, "spectrometer"
    )


# --------------------------------------------------------------------------------- files


def test_a_files_session_beside_the_twin_captures_and_replays(tmp_path: Path) -> None:
    data = twin_config_data(tmp_path / "sessions")
    files = _lamp_files(tmp_path / "measured")
    data["devices"]["spectrometer"] = {
        "kind": "files",
        "directory": str(tmp_path / "measured"),
        "lamps": files,
    }
    outcome = run_capture(RigConfig.model_validate(data), retry=FAST_RETRY)
    assert outcome.exit_status == "success", outcome
    session = read_session(outcome.session)
    identity = session.start.devices["spectrometer"]  # type: ignore[union-attr]
    assert identity.model == "spectrum files" and identity.extra["driver"] == "files"
    records = [r for r in session.files() if r.role == "spectrum"]
    assert {r.bandwidth_nm for r in records} == {1.5}
    assert {r.units for r in records} == {"W/(sr·m²·nm)"}
    replay = replay_session(outcome.session, tmp_path / "replay")
    assert replay.identical and replay.run.exit_status == "success", replay


def test_the_files_device_reads_the_lit_lamp_only(tmp_path: Path) -> None:
    files = _lamp_files(tmp_path)
    spec = twin_spec()
    bank = LampBank([virtual_lamp(lamp) for lamp in spec.lamps], 2, SimulatedClock())
    relays = SwitchedRelays(FakeRelayBoard(bank, []))
    lamps = [LampFile(lamp.name, lamp.channel, tmp_path / files[lamp.name]) for lamp in spec.lamps]
    device = FilesSpectrometer(tmp_path, lamps, read_measured_spectrum, relays)
    with pytest.raises(InstrumentError, match="no lamp on") as raised:
        device.measure()
    assert raised.value.code == "no_lamp"
    relays.set(2, True)
    assert device.measure() is device.readings["FL2"]
    relays.set(1, True)
    with pytest.raises(InstrumentError, match="LED-B3, FL2 on"):
        device.measure()
    relays.all_off()
    assert relays.on_channels() == frozenset()
    (tmp_path / files["FL2"]).write_text("wavelength_nm,radiance\n400,abc\n")
    with pytest.raises(DeviceNotFound, match=r"lamp 'FL2'.*FL2\.csv"):
        FilesSpectrometer(tmp_path, lamps, read_measured_spectrum, relays)


def test_measured_files_of_every_format_read_with_their_units_and_bandwidth(
    tmp_path: Path,
) -> None:
    values = [float(v) for v in np.linspace(1.0, 2.0, 36)]
    (tmp_path / "a.sp").write_text(sp_text(380.0, 730.0, values))
    reading = read_measured_spectrum(tmp_path / "a.sp", bandwidth_nm=10.0)
    np.testing.assert_allclose(reading.values, values, rtol=1e-5)  # 6 digits written
    assert (reading.units, reading.bandwidth_nm) == ("mW/(m²·nm)", 10.0)

    (tmp_path / "b.csv").write_text(
        "# measured with a borrowed CS-2000\n# units: W/(sr·m²·nm)\n# bandwidth_nm: 5\n"
        "wavelength_nm,lamp1,lamp2\n400,1,3\n500,2,-0.01\n600,3,1\n"
    )
    reading = read_measured_spectrum(tmp_path / "b.csv", column="lamp2")
    assert reading.values.tolist() == [3.0, 0.0, 1.0]  # noise below zero set to zero
    assert (reading.units, reading.bandwidth_nm) == ("W/(sr·m²·nm)", 5.0)
    with pytest.raises(SpectrumError, match="choose one"):
        read_measured_spectrum(tmp_path / "b.csv")

    colour = pytest.importorskip("colour")
    distribution = colour.SpectralDistribution(
        dict(zip(range(400, 701, 10), np.linspace(0.5, 1.5, 31), strict=True))
    )
    ies = colour.SpectralDistribution_IESTM2714(
        str(tmp_path / "c.spdx"),
        data=distribution.values,
        domain=distribution.wavelengths,
        spectral_quantity="radiance",
        bandwidth_FWHM=2.5,
    )
    ies.header.manufacturer = "test"
    ies.write()
    reading = read_measured_spectrum(tmp_path / "c.spdx")
    assert (reading.units, reading.bandwidth_nm) == ("radiance", 2.5)
    np.testing.assert_allclose(reading.values, distribution.values, rtol=1e-6)

    with pytest.raises(SpectrumError, match="file not found"):
        read_measured_spectrum(tmp_path / "missing.csv")
    (tmp_path / "d.csv").write_text("# bandwidth_nm: wide\nwavelength_nm,v\n400,1\n500,2\n")
    with pytest.raises(SpectrumError, match="bandwidth_nm 'wide' is not a number"):
        read_measured_spectrum(tmp_path / "d.csv")


@pytest.mark.parametrize(
    ("spectrometer", "spectrum", "says"),
    [
        (
            {"kind": "files", "directory": "m", "lamps": {"LED-B3": "a.csv", "A": "b.csv"}},
            {},
            "no file for 'FL2'; 'A' is not a lamp",
        ),
        ({"kind": "argyll"}, {"exposure_ms": 100}, "spotread chooses its own integration"),
        (
            {"kind": "files", "directory": "m", "lamps": {"LED-B3": "a", "FL2": "b"}},
            {"exposure_ms": 100},
            "files have no integration time",
        ),
    ],
)
def test_the_configuration_refuses_what_cannot_work(
    spectrometer: dict[str, object], spectrum: dict[str, object], says: str
) -> None:
    data = twin_config_data()
    data["devices"]["spectrometer"] = spectrometer
    data["spectrum"] = {**data.get("spectrum", {}), **spectrum}
    import yaml

    with pytest.raises(ConfigError, match=says):
        parse_config(yaml.safe_dump(data), "config.yaml")
