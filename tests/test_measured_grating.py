"""The grating's efficiency from spectra measured in its beams (calib.methods.measured_grating)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import WavelengthGrid
from calib.methods.measured_grating import (
    BeamSpectra,
    band_core,
    first_order_points,
    grating_from_beams,
)
from calib.model.gratings import SinusoidalPhaseGrating

AXIS = np.arange(380.0, 781.0, 4.0)
GRID = WavelengthGrid(380.0, 780.0, 5.0)


def smooth_band(centre_nm: float, half_width_nm: float, edge_nm: float = 6.0) -> FloatArray:
    """A band with soft edges (what a field seen through the instrument's bandwidth gives)."""
    return np.asarray(
        np.clip((half_width_nm - np.abs(AXIS - centre_nm)) / edge_nm + 0.5, 0.0, 1.0),
        dtype=np.float64,
    )


def sheet_beams(
    phase_rad: float, rng: np.random.Generator, noise: float = 0.003, repeats: int = 3
) -> BeamSpectra:
    sheet = SinusoidalPhaseGrating(phase_rad)
    lamp = 1.0 + 0.5 * np.sin(AXIS / 40.0)

    def measured(curve: FloatArray) -> FloatArray:
        clean = lamp * curve
        return np.asarray(clean * (1 + noise * rng.standard_normal((repeats, AXIS.size))))

    eta0, eta1 = sheet.efficiency(0, AXIS), sheet.efficiency(1, AXIS)
    bands = [(c, measured(0.92 * eta1 * smooth_band(c, 17.0))) for c in range(410, 700, 17)]
    return BeamSpectra(
        AXIS, measured(np.ones_like(AXIS)), measured(0.92 * eta0), bands, bandwidth_nm=8.0
    )


@pytest.mark.parametrize("phase_rad", [0.6, 1.2, 1.8])
def test_a_sinusoidal_sheet_is_recovered_with_its_scale(phase_rad: float) -> None:
    rng = np.random.default_rng(3)
    grating = grating_from_beams(sheet_beams(phase_rad, rng), GRID)
    assert grating.obtained == "measured"
    assert grating.model is not None and grating.model["model"] == "sinusoidal"
    phase = grating.model["parameters"]["peak_phase_rad"]
    sigma = grating.model["parameter_sigma"]["peak_phase_rad"]
    assert abs(phase - phase_rad) < 3 * sigma + 1e-3
    # A weak sheet (J₁² ≈ φ²/4) determines only scale·φ²: the two σ say so, and cover the truth.
    scale_sigma = grating.model["parameter_sigma"]["scale"]
    assert abs(grating.model["parameters"]["scale"] - 0.92) < 3 * scale_sigma + 1e-3
    truth = 0.92 * SinusoidalPhaseGrating(phase_rad).efficiency(1, GRID.wavelength_nm)
    assert grating.efficiency_sigma is not None
    assert np.all(np.abs(grating.efficiency - truth) <= 3 * grating.efficiency_sigma)
    eta0 = 0.92 * SinusoidalPhaseGrating(phase_rad).efficiency(0, GRID.wavelength_nm)
    assert grating.zeroth_order_efficiency is not None
    np.testing.assert_allclose(grating.zeroth_order_efficiency, eta0, atol=0.01)


def test_the_band_core_leaves_the_soft_edges_out() -> None:
    ratio = 0.3 * smooth_band(550.0, 17.0)
    core = band_core(AXIS, ratio, np.ones(AXIS.size, dtype=bool), bandwidth_nm=8.0)
    used = AXIS[core]
    assert used.min() >= 550 - 17 + 8 and used.max() <= 550 + 17 - 8
    assert np.all(ratio[core] == pytest.approx(0.3))


def test_a_measurement_no_model_fits_is_not_a_silent_answer() -> None:
    rng = np.random.default_rng(4)
    beams = sheet_beams(1.2, rng)
    # Every other band dimmed by a third (aims that clipped the slit's image): no model fits.
    dimmed = [(c, r * (1.0 if i % 2 else 0.67)) for i, (c, r) in enumerate(beams.order1)]
    grating = grating_from_beams(
        BeamSpectra(AXIS, beams.direct, beams.order0, dimmed, bandwidth_nm=8.0), GRID
    )
    assert grating.model is not None and grating.model["reduced_chi2"] > 4
    assert "follows neither physical model" in grating.model["warning"]
    narrow = [(c, r * (np.abs(AXIS - c) < 2.0)) for c, r in beams.order1]
    with pytest.raises(InputError, match="no band wide enough"):
        first_order_points(BeamSpectra(AXIS, beams.direct, beams.order0, narrow, 8.0))
