"""Shared pieces of the serial driver tests: a small lamp bank and timing constants.

A deadline the test expects to pass is short, so that every such fault ends quickly; a deadline a
reply is due within is long, so that an emulator thread starved on a loaded machine is not taken for a
fault. Emulators run 100× faster than the instruments.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from calib.core.spectra import Spectrum
from drivers.base import DeviceTimeout
from mocks.lamps import LampBank, VirtualLamp

#: Emulated durations are multiplied by this.
TIME_SCALE = 0.01
#: Command deadline where the test is about a reply that never comes (or comes too late).
FAST_TIMEOUT_S = 0.4
#: Command deadline where a reply is due: a reply that comes is read at once, so this costs nothing,
#: and a loaded machine (CI, a parallel suite) can starve an emulator thread for longer than
#: FAST_TIMEOUT_S, which would turn a reply into a spurious timeout.
REPLY_TIMEOUT_S = 5.0
#: Per-test ceiling for tests that inject faults (pytest-timeout): none may hang.
FAULT_TEST_TIMEOUT_S = 15

#: How long an emulator thread may take to act on the last bytes a driver sent before closing.
SETTLE_DEADLINE_S = 10.0

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


def settled(condition: Callable[[], bool], deadline_s: float = SETTLE_DEADLINE_S) -> bool:
    """Whether ``condition`` holds once the emulator's thread has handled what was sent to it.

    A driver's last command (leaving remote mode) is written and the port closed; the emulator reads
    it on its own thread, later on a busy machine. This waits for it, up to ``deadline_s``.
    """
    end = time.monotonic() + deadline_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.005)
    return True


def deadline_for(expected: type[Exception]) -> float:
    """The command deadline for a fault test expecting ``expected``: short only where it is a timeout."""
    return FAST_TIMEOUT_S if issubclass(expected, DeviceTimeout) else REPLY_TIMEOUT_S
