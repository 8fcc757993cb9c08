"""Byte-level firmware emulators of the serial instruments, served on pty pairs.

Each ``start_*`` function returns a started :class:`mocks.pty_serial.PtySerialDevice`: hand
``device.path`` to the real driver (``drivers.spectrometer.open_spectrometer``, ``open_lcus``,
``open_numato``) and call ``device.stop()`` (or use it as a context manager) when done. Spectrometers
look at a radiance source (typically :meth:`mocks.lamps.LampBank.radiance`); relay boards switch the
channels of a :class:`mocks.lamps.LampBank`, so what the spectrometer sees depends on which relay is on.

>>> from mocks.emulators import start_lcus, start_pr655  # doctest: +SKIP
>>> relays = start_lcus(4, bank)  # doctest: +SKIP
>>> spectrometer = start_pr655(bank.radiance, seed=1, time_scale=0.01)  # doctest: +SKIP
"""

from mocks.emulators.cs2000 import Cs2000Emulator, start_cs2000
from mocks.emulators.lcus import LcusEmulator, start_lcus
from mocks.emulators.numato import NumatoEmulator, start_numato
from mocks.emulators.pr6xx import PR655, PR670, Pr6xxEmulator, start_pr655, start_pr670

__all__ = [
    "PR655",
    "PR670",
    "Cs2000Emulator",
    "LcusEmulator",
    "NumatoEmulator",
    "Pr6xxEmulator",
    "start_cs2000",
    "start_lcus",
    "start_numato",
    "start_pr655",
    "start_pr670",
]
