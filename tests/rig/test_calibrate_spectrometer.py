"""``rig calibrate-spectrometer`` on the twin's emulated USB2000+: the calibration it writes against
a halogen lamp (CIE A) recovers the emulator's true response, and the driver measures with it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calib.core.lamp_specs import colour_lamp
from calib.core.spectra import Spectrum
from drivers.base import ListTranscript
from mocks.ocean_backend import USB2000PLUS, EmulatedOcean, OceanBackend, ocean_calibration
from rig.calibrate import SpectrometerCalibrationError, calibration_factors
from rig.config import RigConfig
from rig.hardware import load_irradiance_calibration, open_configured_spectrometer
from tests.rig.fakes import write_config
from tests.rig.test_cli import run_cli
from tests.rig.twin_setup import twin_config_data


def _config_data(directory: Path, emulate: str = "seabreeze") -> dict[str, Any]:
    data = twin_config_data(directory / "sessions")
    # The calibration is later used on an emulator built as stated (no in-spec scale/slit error):
    # the twin's instrument must be that same one for the response to transfer.
    data["devices"]["spectrometer"] = {
        "kind": "twin",
        "emulate": emulate,
        "timeout_s": 5,
        "in_spec_error": False,
    }
    data["devices"]["relays"]["channels"] = 4
    data["lamps"].append(
        {
            "name": "A",
            "channel": 3,
            "kind": "halogen",
            "warmup": {"tolerance": 0.02, "interval_s": 10, "timeout_s": 300},
        }
    )
    return data


@pytest.fixture(scope="module")
def calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("calibrate")
    config = write_config(directory / "rig.yaml", _config_data(directory))
    monkeypatch = pytest.MonkeyPatch()
    try:
        code = run_cli(
            [
                "calibrate-spectrometer", "--config", str(config), "--lamp", "A",
                "--out", str(directory / "cal.csv"),
            ],
            monkeypatch,
        )  # fmt: skip
    finally:
        monkeypatch.undo()
    assert code == 0
    return directory / "cal.csv"


def test_the_calibration_recovers_the_spectrometers_response(calibration: Path) -> None:
    loaded = load_irradiance_calibration(calibration)
    wavelength, exact = ocean_calibration(USB2000PLUS)
    inside = (loaded.wavelength_nm >= 400.0) & (loaded.wavelength_nm <= 700.0)
    ratio = loaded.factor[inside] / np.interp(loaded.wavelength_nm[inside], wavelength, exact)
    ratio /= np.mean(ratio)
    assert np.sqrt(np.mean((ratio - 1.0) ** 2)) < 0.005  # shot noise of 3 × 3 scans at 2 ms
    assert np.max(np.abs(ratio - 1.0)) < 0.03
    # The slit's reach at the end of CIE A's table (780 nm) is left out, not divided into.
    assert loaded.range_nm[1] <= 780.0 - USB2000PLUS.bandwidth_nm
    header = calibration.read_text().splitlines()[:4]
    assert "USB2000PLUS (serial USB2+F12345)" in header[0]
    assert "against A" in header[1] and "relay channel 3" in header[1]


def test_the_driver_measures_with_the_calibration_made(calibration: Path) -> None:
    """A real ``kind: seabreeze`` configuration naming the file, on an emulated bus showing lamp A:
    the spectrum the driver hands on is A's relative spectrum."""
    lamp_a = colour_lamp("A").scaled(1e-4)  # about the twin's lamps' radiance, W/(sr·m²·nm)
    data = _config_data(calibration.parent)
    data["devices"]["spectrometer"] = {
        "kind": "seabreeze",
        "calibration_file": str(calibration),
        "bandwidth_nm": 1.5,
    }
    config = RigConfig.model_validate(data)
    lit = False

    def lamp(wavelength_nm: np.ndarray) -> np.ndarray:
        return lamp_a.at(wavelength_nm) if lit else np.zeros_like(wavelength_nm)

    ocean = EmulatedOcean(USB2000PLUS, lamp, seed=3, time_scale=0.0)
    spectrometer = open_configured_spectrometer(
        config.devices.spectrometer, ListTranscript(), usb_backend=OceanBackend([ocean])
    )
    try:
        spectrometer.set_exposure(None)
        spectrometer.measure_dark()  # type: ignore[attr-defined]
        lit = True
        reading = spectrometer.measure()
    finally:
        spectrometer.close()
    measured = Spectrum(reading.wavelength_nm, reading.values)
    inside = (reading.wavelength_nm >= 420.0) & (reading.wavelength_nm <= 700.0)
    ratio = reading.values[inside] / lamp_a.at(reading.wavelength_nm[inside])
    ratio /= np.mean(ratio)
    assert np.max(np.abs(ratio - 1.0)) < 0.05  # single pixels at a short integration
    assert measured.range_nm[1] <= 780.0


def test_what_cannot_be_calibrated_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config = write_config(tmp_path / "rig.yaml", _config_data(tmp_path, emulate="pr655"))
    out = str(tmp_path / "cal.csv")
    arguments = ["calibrate-spectrometer", "--config", str(config), "--lamp", "A", "--out", out]
    assert run_cli(arguments, monkeypatch) == 2
    assert "calibrates Ocean spectrometers (kind: seabreeze)" in capsys.readouterr().err
    config = write_config(tmp_path / "rig.yaml", _config_data(tmp_path))
    arguments[4] = "D65"
    assert run_cli(arguments, monkeypatch) == 2
    assert "give --channel N" in capsys.readouterr().err
    axis = np.arange(400.0, 701.0, 1.0)
    narrow = Spectrum(axis, np.exp(-0.5 * ((axis - 550.0) / 1.0) ** 2))
    with pytest.raises(SpectrometerCalibrationError, match="broadband lamp"):
        calibration_factors(narrow, Spectrum(axis, np.ones_like(axis)))
