"""The twin spectrometer's in-spec wavelength-scale error and slit deviation (decision 0038)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from calib.core.spectrometer_tolerance import BANDWIDTH_TOLERANCE, WAVELENGTH_SCALE_NM
from mocks.bench import TwinSpec
from mocks.bench.deviation import (
    deviation_from_record,
    draw_deviation,
    spectrometer_deviation,
)
from mocks.bench.spec import TwinSpecError
from mocks.bench.station import open_twin
from mocks.bench.truth import TwinTruth
from mocks.emulators.radiometer import InstrumentDeviation, Radiometer, RadiometerOptics
from rig.config import RigConfig
from rig.twin import read_twin_truth, write_twin_truth
from tests.rig.twin_setup import twin_config_data

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


#: The test line's own σ (nm): resolved by the radiometer's fine grid (0.25 nm for a 2 nm slit).
LINE_SIGMA_NM = 0.4


def _line(centre_nm: float, width_nm: float = LINE_SIGMA_NM) -> object:
    def radiance(wavelength_nm: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.exp(-0.5 * ((np.asarray(wavelength_nm) - centre_nm) / width_nm) ** 2)

    return radiance


def _radiometer(source: object, deviation: InstrumentDeviation | None = None) -> Radiometer:
    optics = RadiometerOptics(
        wavelength_nm=np.arange(480.0, 620.0 + 0.25, 0.25),
        bandwidth_nm=2.0,
        peak_responsivity=1e3,
        exposure_range_ms=(1.0, 1000.0),
    )
    return Radiometer(optics, source, np.random.default_rng(0), deviation)  # type: ignore[arg-type]


def _centre_and_fwhm(radiometer: Radiometer) -> tuple[float, float]:
    grid = radiometer.optics.wavelength_nm
    reading = radiometer.band_radiance()
    centre = float(np.sum(grid * reading) / np.sum(reading))
    variance = float(np.sum((grid - centre) ** 2 * reading) / np.sum(reading))
    # the slit's own FWHM: the line's width taken out of the reading's
    return centre, FWHM_PER_SIGMA * math.sqrt(variance - LINE_SIGMA_NM**2)


def test_the_twin_draws_the_sizes_the_sigma_budget_assumes() -> None:
    draws = [draw_deviation(seed) for seed in range(200)]
    ends = np.array([d.true_wavelength_nm(np.array([380.0, 780.0])) - [380, 780] for d in draws])
    factors = np.array([d.bandwidth_factor for d in draws])
    assert np.abs(ends).max() <= WAVELENGTH_SCALE_NM
    assert np.abs(factors - 1).max() <= BANDWIDTH_TOLERANCE
    # in spec, not at zero: the draws fill the tolerance
    assert np.abs(ends).max() > 0.9 * WAVELENGTH_SCALE_NM
    assert np.abs(factors - 1).max() > 0.9 * BANDWIDTH_TOLERANCE
    assert draw_deviation(7) == draw_deviation(7) != draw_deviation(8)


def test_a_line_is_read_at_its_true_wavelength_minus_the_drawn_scale_error() -> None:
    deviation = InstrumentDeviation(offset_nm=0.4, slope=1e-3, bandwidth_factor=1.2)
    for true_nm in (520.0, 546.1, 580.0):
        exact_centre, exact_fwhm = _centre_and_fwhm(_radiometer(_line(true_nm)))
        centre, fwhm = _centre_and_fwhm(_radiometer(_line(true_nm), deviation))
        assert exact_centre == pytest.approx(true_nm, abs=0.01)
        assert exact_fwhm == pytest.approx(2.0, rel=0.02)
        # the pixel stated as λ sees λ + δ(λ): the line lands at λ_true − δ(λ_true) (to first order)
        shift = 0.4 + 1e-3 * (true_nm - 580.0)
        assert centre == pytest.approx(true_nm - shift / (1 + 1e-3), abs=0.01)
        assert fwhm == pytest.approx(2.0 * 1.2 / (1 + 1e-3), rel=0.02)


def test_without_a_deviation_the_slit_is_the_one_before_it_existed() -> None:
    """No deviation (the switch off) weighs the light exactly as the radiometer always did."""
    radiometer = _radiometer(_line(546.1), None)
    optics = radiometer.optics
    grid = optics.wavelength_nm
    sigma_nm = optics.bandwidth_nm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    step_nm = min(0.5, optics.bandwidth_nm / 8.0)
    reach_nm = 4.0 * sigma_nm
    fine = np.arange(grid[0] - reach_nm, grid[-1] + reach_nm + step_nm / 2, step_nm)
    weights = np.exp(-0.5 * ((grid[:, None] - fine[None, :]) / sigma_nm) ** 2)
    weights = weights / weights.sum(axis=1, keepdims=True)
    reference = weights @ np.asarray(radiometer.source(fine))
    assert radiometer.band_radiance().tobytes() == reference.tobytes()
    # a zero deviation is the same instrument, and setting it back to None restores it exactly
    radiometer.deviation = InstrumentDeviation()
    assert radiometer.band_radiance().tobytes() == reference.tobytes()
    radiometer.deviation = InstrumentDeviation(offset_nm=0.3)
    assert radiometer.band_radiance().tobytes() != reference.tobytes()
    radiometer.deviation = None
    assert radiometer.band_radiance().tobytes() == reference.tobytes()


def _spec(emulate: str, *, in_spec_error: bool | None = None, seed: int = 11) -> TwinSpec:
    data = twin_config_data()
    data["seed"] = seed
    data["devices"]["spectrometer"]["emulate"] = emulate
    if in_spec_error is not None:
        data["devices"]["spectrometer"]["in_spec_error"] = in_spec_error
    return TwinSpec.from_config_data(RigConfig.model_validate(data).model_dump(mode="json"))


@pytest.mark.parametrize("emulate", ["pr655", "cs2000", "seabreeze", "argyll"])
def test_every_emulated_instrument_gets_the_seed_s_draw(emulate: str) -> None:
    spec = _spec(emulate)
    bench = open_twin(spec, prepare=False)
    try:
        radiometers = bench.radiometers()
        assert radiometers, emulate
        for radiometer in radiometers:
            assert radiometer.deviation == draw_deviation(11)
    finally:
        bench.close()
    off = open_twin(_spec(emulate, in_spec_error=False), prepare=False)
    try:
        assert [r.deviation for r in off.radiometers()] == [None] * len(radiometers)
    finally:
        off.close()


def test_the_switch_is_on_by_default_and_only_true_or_false() -> None:
    assert _spec("pr655").spectrometer_in_spec_error
    assert spectrometer_deviation(_spec("pr655", in_spec_error=False)) is None
    data = RigConfig.model_validate(twin_config_data()).model_dump(mode="json")
    data["devices"]["spectrometer"]["in_spec_error"] = "maybe"
    with pytest.raises(TwinSpecError, match=r"devices\.spectrometer\.in_spec_error"):
        TwinSpec.from_config_data(data)
    config = twin_config_data()
    config["devices"]["spectrometer"]["in_spec_error"] = "maybe"
    with pytest.raises(ValueError, match="in_spec_error"):
        RigConfig.model_validate(config)


def test_the_truth_records_the_draw_and_reads_it_back(tmp_path: Path) -> None:
    data = twin_config_data()
    data["seed"] = 11
    config = RigConfig.model_validate(data)
    path = write_twin_truth(config, tmp_path)
    record = read_twin_truth(path).spectrometer
    assert record is not None and record["emulate"] == "pr655" and record["in_spec_error"]
    assert deviation_from_record(record) == draw_deviation(11)
    assert record["wavelength_error_at_380_nm"] == pytest.approx(
        float(draw_deviation(11).true_wavelength_nm(np.array([380.0]))[0] - 380.0)
    )
    data["devices"]["spectrometer"]["in_spec_error"] = False
    (tmp_path / "off").mkdir()
    off = read_twin_truth(write_twin_truth(RigConfig.model_validate(data), tmp_path / "off"))
    assert off.spectrometer == {"emulate": "pr655", "in_spec_error": False}
    # a truth file written before the twin had these errors still reads
    truth = TwinTruth.read(path)
    document = truth.to_dict()
    del document["spectrometer"]
    (tmp_path / "old").mkdir()
    old = tmp_path / "old" / "twin-truth.json"
    old.write_text(json.dumps(document), encoding="utf-8")
    assert TwinTruth.read(old).spectrometer is None
