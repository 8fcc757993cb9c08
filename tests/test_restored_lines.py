"""A tabulated fluorescent spectrum's mercury lines restored without shoulders (decision 0072)."""

from __future__ import annotations

import numpy as np

from calib.core.line_lists import TABULATED_MERCURY_NM, table_bandpass, with_narrow_lines
from calib.core.spectra import Spectrum


def _tabulated(continuum: np.ndarray, axis: np.ndarray, powers: dict[float, float]) -> Spectrum:
    """A lamp as the CIE FL tables hold it: measured through a triangular bandpass as wide as the
    5 nm step, so a line between two steps adds to both."""
    values = continuum.copy()
    for line, power in powers.items():
        values += power * table_bandpass(axis - line, 5.0)
    return Spectrum(axis, values)


def test_a_tabulated_line_is_restored_whole_and_its_neighbouring_step_is_the_continuum():
    axis = np.arange(380.0, 781.0, 5.0)
    continuum = 1.0 + 0.01 * (axis - 380.0)
    powers = {TABULATED_MERCURY_NM[1]: 120.0, TABULATED_MERCURY_NM[2]: 80.0}  # 435.8, 546.1
    restored = with_narrow_lines(_tabulated(continuum, axis, powers))
    # No shoulder one step to the red of each line (440 and 550 nm): the continuum there, not the
    # 17–21 % of the line's table value the bandpass put in that step.
    for step in (440.0, 550.0):
        value = float(restored.at(np.array([step]))[0])
        assert abs(value - float(np.interp(step, axis, continuum))) < 1e-6
    # Each line carries all its power (both steps' excess), at its own wavelength.
    for line, power in powers.items():
        near = np.abs(restored.wavelength_nm - line) < 3.0
        excess = restored.values[near] - np.interp(restored.wavelength_nm[near], axis, continuum)
        assert abs(float(np.trapezoid(excess, restored.wavelength_nm[near])) - power) < 0.01 * power
        assert abs(restored.wavelength_nm[near][np.argmax(excess)] - line) < 0.15
