"""Shared pieces of the serial driver tests: a small lamp bank and timing constants.

Timeouts are short so that every fault ends quickly; emulators run 100× faster than the instruments.
"""

from __future__ import annotations

import numpy as np

from calib.core.spectra import Spectrum
from mocks.lamps import LampBank, VirtualLamp

#: Emulated durations are multiplied by this.
TIME_SCALE = 0.01
#: Command deadline used against emulators.
FAST_TIMEOUT_S = 0.4
#: Per-test ceiling for tests that inject faults (pytest-timeout): none may hang.
FAULT_TEST_TIMEOUT_S = 15

BLUE_PEAK_NM = 450.0
RED_PEAK_NM = 630.0


def narrow_band(peak_nm: float, width_nm: float, radiance: float) -> Spectrum:
    """A Gaussian LED-like spectrum, W/(sr·m²·nm), on 300–900 nm."""
    wavelength_nm = np.arange(300.0, 901.0, 1.0)
    values = radiance * np.exp(-0.5 * ((wavelength_nm - peak_nm) / width_nm) ** 2)
    return Spectrum(wavelength_nm, values, name=f"LED {peak_nm:g} nm")


def two_lamp_bank(n_channels: int = 4) -> LampBank:
    """A blue lamp on channel 1 and a red one on channel 2, no warm-up drift."""
    lamps = [
        VirtualLamp("blue", 1, narrow_band(BLUE_PEAK_NM, 12.0, 0.02), warmup_tau_s=0.0),
        VirtualLamp("red", 2, narrow_band(RED_PEAK_NM, 10.0, 0.02), warmup_tau_s=0.0),
    ]
    return LampBank(lamps, n_channels)
