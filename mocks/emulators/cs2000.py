"""Firmware emulator of the Konica Minolta CS-2000 / CS-2000A (device side of the wire).

What it implements (facts sheet §1.2):

- commands end with CR, LF or CR LF and every reply ends with the delimiter the command used;
  replies are ``OK00`` or ``ERxx``, then comma-separated parameters;
- ``RMTS,0|1|2`` leaves / enters remote mode (``1`` would also save settings to flash); outside
  remote mode every other command gets ``ER00``;
- ``IDDR`` → ``OK00,<product name, 9 chars padded>,<1 = CS-2000, 2 = CS-2000A>,<7-digit serial>``;
- ``SPMS,<mode>,…`` / ``SPMR``: speed mode 0 Normal / 1 Fast (``SPMS,0,<nd>``), 2 / 4
  multi-integration (``SPMS,2,<1–16 s>,<nd>``), 3 Manual (``SPMS,3,<9-digit µs, 5 000–120 000 000>,
  <nd>``); internal ND 0 off / 1 on / 2 auto; a wrong parameter count → ``ER00``, out of range →
  ``ER17``;
- ``MSWE,0|1`` disables / enables the measure key;
- ``MEAS,1``: after the pre-measurement (about 1 s), ``OK00,<ttt>`` with the remaining measurement
  time in whole seconds, then, when done, a second line ``OK00`` — or ``ER10`` when the light is
  over range. While measuring, ``MEAS,0`` cancels (``OK00``), ``MEDR`` gets ``ER02`` and anything
  else ``ER00``;
- ``MEDR,0,0,1`` measurement conditions (speed, sync, integration time in µs as 9 digits, internal
  ND, close-up lens, external ND, angle, calibration channel); ``MEDR,1,<format>,<block>`` spectral
  radiance, blocks 1–3 = 100 values, block 4 = 101 (380–780 nm at 1 nm), format 1 = 8 hex digits
  of a big-endian float32 per value, format 0 = exponential text; ``ER20`` when there is no data.
  With the measure key enabled the data are cleared once all four blocks have been read.

Fault labels are the command texts (``"MEAS,1"``, ``"MEDR,1,1,3"`` …). ``BUSY`` answers ``ER02``.
For ``MEAS,1`` a fault's ``part`` picks the acknowledgement (0) or the completion line (1).
``time_scale`` shrinks the pre-measurement and measurement times; the announced ``ttt`` is the
scaled time rounded up to whole seconds (so it may read ``001`` in a fast test).
"""

from __future__ import annotations

import math
import re
import struct
import time
from dataclasses import dataclass
from typing import ClassVar, Unpack

import numpy as np
from numpy.typing import NDArray

from mocks.emulators.radiometer import RadianceSource, Radiometer, RadiometerOptics
from mocks.emulators.serial_base import (
    EmulatorBase,
    LineSplitter,
    ReplyPart,
    SpectrometerOptions,
    measurement_rng,
)
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.pty_serial import PtySerialDevice, ScheduledOutput

#: Spectral blocks of ``MEDR,1``: (first wavelength, number of values).
SPECTRAL_BLOCKS = {1: (380, 100), 2: (480, 100), 3: (580, 100), 4: (680, 101)}
WAVELENGTH_NM = np.arange(380.0, 781.0, 1.0)

#: Time before the ``OK00,ttt`` acknowledgement (pre-measurement), nominal seconds.
PRE_MEASUREMENT_S = 1.0
#: Integration-time limits of the automatic speed modes, ms.
AUTO_EXPOSURE_RANGE_MS = {0: (5.0, 5_000.0), 1: (5.0, 1_000.0)}
MANUAL_RANGE_US = (5_000, 120_000_000)
#: Internal ND attenuation when it is in the light path.
INTERNAL_ND_FACTOR = 0.01


@dataclass(frozen=True)
class _Data:
    radiance: NDArray[np.float64]
    integration_us: int
    nd_used: bool


class Cs2000Emulator(EmulatorBase):
    """A CS-2000 (``variation=1``) or CS-2000A (``variation=2``) measuring ``source``.

    Parameters
    ----------
    source
        Spectral radiance the instrument looks at.
    variation
        1 = CS-2000, 2 = CS-2000A (as ``IDDR`` reports it).
    serial
        Seven-digit serial number.
    seed, faults, time_scale
        See :class:`mocks.emulators.serial_base.EmulatorBase`.
    """

    SUPPORTED_FAULTS: ClassVar[frozenset[FaultKind]] = frozenset(FaultKind)

    def __init__(
        self,
        source: RadianceSource,
        *,
        variation: int = 1,
        serial: str = "1000123",
        seed: int | np.random.Generator | None = None,
        faults: FaultSchedule | None = None,
        time_scale: float = 1.0,
        peak_responsivity: float = 5.0e4,
    ) -> None:
        if variation not in (1, 2):
            raise ValueError(f"variation is 1 (CS-2000) or 2 (CS-2000A), got {variation}")
        if not re.fullmatch(r"\d{7}", serial):
            raise ValueError(f"the CS-2000 serial is 7 digits, got {serial!r}")
        super().__init__(
            "CS-2000A" if variation == 2 else "CS-2000", faults=faults, time_scale=time_scale
        )
        self.variation = variation
        self.serial = serial
        optics = RadiometerOptics(
            wavelength_nm=WAVELENGTH_NM,
            bandwidth_nm=5.0,
            peak_responsivity=peak_responsivity,
            exposure_range_ms=AUTO_EXPOSURE_RANGE_MS[0],
            overhead_s=0.5,
            weak_light_counts=0.0,  # the CS-2000 has no "too dark" error: it reports the noise
        )
        self.radiometer = Radiometer(optics, source, measurement_rng(seed))
        self.remote = False
        self.measure_key_enabled = True
        self.speed_mode = 0
        self.multi_integration_s = 2
        self.manual_integration_us = 100_000
        self.internal_nd = 2
        self.data: _Data | None = None
        self.blocks_read: set[int] = set()
        self.measuring_until = 0.0
        self._pending_completion: ScheduledOutput | None = None
        self._splitter = LineSplitter()

    # ------------------------------------------------------------------------------ input

    def receive(self, data: bytes) -> None:
        for line, terminator in self._splitter.feed(data):
            self._command(line, terminator)

    def _measuring(self) -> bool:
        return time.monotonic() < self.measuring_until

    def _command(self, line: bytes, terminator: bytes) -> None:
        text = line.decode("ascii", errors="replace")
        fault = self.next_fault(text)
        if fault is not None and fault.kind is FaultKind.BUSY:
            replies = [(b"ER02", 0.0)]
        elif fault is not None and fault.kind is FaultKind.ERROR_CODE:
            replies = self._error_replies(text, fault)
        else:
            replies = self._execute(text)
        parts = [ReplyPart(reply + terminator, at_s) for reply, at_s in replies]
        sent = self.deliver(parts, fault)
        if text == "MEAS,1" and len(replies) == 2 and len(sent) == 2:
            self._pending_completion = sent[1]

    def _error_replies(self, text: str, fault: Fault) -> list[tuple[bytes, float]]:
        code = (fault.code or ("ER10" if text == "MEAS,1" else "ER00")).encode("ascii")
        if text == "MEAS,1" and fault.part == 1:
            # The measurement runs, then fails: the acknowledgement, then the error as completion.
            (ack, ack_s), (_, done_s) = self._start_measurement()
            self.data = None
            return [(ack, ack_s), (code, done_s)]
        return [(code, 0.0)]

    # ------------------------------------------------------------------------------ commands

    def _execute(self, text: str) -> list[tuple[bytes, float]]:
        if not re.fullmatch(r"[0-9A-Za-z ,]*", text):
            return [(b"ER00", 0.0)]
        fields = text.split(",")
        name, params = fields[0], fields[1:]
        if name == "RMTS":
            return [(self._remote(params), 0.0)]
        if not self.remote:
            return [(b"ER00", 0.0)]
        if self._measuring():
            if name == "MEAS" and params == ["0"]:
                self._cancel_measurement()
                return [(b"OK00", 0.0)]
            return [(b"ER02" if name == "MEDR" else b"ER00", 0.0)]
        if name == "IDDR" and not params:
            product = ("CS-2000A" if self.variation == 2 else "CS-2000").ljust(9)
            return [(f"OK00,{product},{self.variation},{self.serial}".encode("ascii"), 0.0)]
        if name == "MSWE" and params in (["0"], ["1"]):
            self.measure_key_enabled = params == ["1"]
            return [(b"OK00", 0.0)]
        if name == "SPMS":
            return [(self._set_speed(params), 0.0)]
        if name == "SPMR" and not params:
            return [(b"OK00," + self._speed_fields().encode("ascii"), 0.0)]
        if name == "MEAS" and params == ["1"]:
            return self._start_measurement()
        if name == "MEAS" and params == ["0"]:
            return [(b"OK00", 0.0)]
        if name == "MEDR" and len(params) == 3:
            return [(self._read_data(params), 0.0)]
        return [(b"ER00", 0.0)]

    def _remote(self, params: list[str]) -> bytes:
        if len(params) != 1:
            return b"ER00"
        if params[0] not in ("0", "1", "2"):
            return b"ER17"
        self.remote = params[0] != "0"
        return b"OK00"

    def _set_speed(self, params: list[str]) -> bytes:
        if not params or not all(p.isdigit() for p in params):
            return b"ER00"
        mode = int(params[0])
        if mode in (0, 1):
            if len(params) != 2:
                return b"ER00"
            nd = int(params[1])
        elif mode in (2, 3, 4):
            if len(params) != 3:
                return b"ER00"
            value, nd = int(params[1]), int(params[2])
            if mode == 3 and not (
                len(params[1]) == 9 and MANUAL_RANGE_US[0] <= value <= MANUAL_RANGE_US[1]
            ):
                return b"ER17"
            if mode in (2, 4) and not 1 <= value <= 16:
                return b"ER17"
        else:
            return b"ER17"
        if nd not in (0, 1, 2):
            return b"ER17"
        self.speed_mode, self.internal_nd = mode, nd
        if mode == 3:
            self.manual_integration_us = value
        elif mode in (2, 4):
            self.multi_integration_s = value
        return b"OK00"

    def _speed_fields(self) -> str:
        if self.speed_mode == 3:
            return f"3,{self.manual_integration_us:09d},{self.internal_nd}"
        if self.speed_mode in (2, 4):
            return f"{self.speed_mode},{self.multi_integration_s:02d},{self.internal_nd}"
        return f"{self.speed_mode},{self.internal_nd}"

    def _start_measurement(self) -> list[tuple[bytes, float]]:
        """Measure now; the data become readable when the completion line is due."""
        if self.speed_mode == 3:
            exposure_ms: float | None = self.manual_integration_us / 1000.0
        else:
            exposure_ms = None  # Normal, Fast and multi-integration choose their own
        nd_used = self.internal_nd == 1
        attenuation = INTERNAL_ND_FACTOR if nd_used else 1.0
        observation = self.radiometer.observe(exposure_ms, attenuation=attenuation)
        if observation.status == "overload" and self.internal_nd == 2:
            nd_used = True
            observation = self.radiometer.observe(exposure_ms, attenuation=INTERNAL_ND_FACTOR)
        duration_s = observation.duration_s
        if self.speed_mode in (2, 4):
            duration_s += self.multi_integration_s
        pre_s = self.seconds(PRE_MEASUREMENT_S)
        measure_s = self.seconds(duration_s)
        self.measuring_until = time.monotonic() + pre_s + measure_s
        self.blocks_read.clear()
        if observation.status == "overload" or observation.radiance is None:
            self.data = None
            completion = b"ER10"
        else:
            integration_us = round(observation.exposure_ms * 1000)
            self.data = _Data(observation.radiance, integration_us, nd_used)
            completion = b"OK00"
        announced_s = min(max(math.ceil(measure_s), 1), 999)
        ack = f"OK00,{announced_s:03d}".encode("ascii")
        return [(ack, pre_s), (completion, pre_s + measure_s)]

    def _cancel_measurement(self) -> None:
        if self._pending_completion is not None:
            self._pending_completion.cancel()
            self._pending_completion = None
        self.measuring_until = 0.0
        self.data = None

    def _read_data(self, params: list[str]) -> bytes:
        mode, data_format, block = params
        if self.data is None:
            return b"ER20"
        if mode == "0" and block == "1" and data_format in ("0", "1"):
            data = self.data
            fields = ["3" if self.speed_mode == 3 else str(self.speed_mode), "0"]
            fields += [f"{data.integration_us:09d}", "1" if data.nd_used else "0", "0", "0"]
            fields += ["0", "0"]
            return ("OK00," + ",".join(fields)).encode("ascii")
        if mode != "1" or data_format not in ("0", "1") or not block.isdigit():
            return b"ER00"
        if int(block) not in SPECTRAL_BLOCKS:
            return b"ER17"
        start_nm, count = SPECTRAL_BLOCKS[int(block)]
        first = start_nm - 380
        values = self.data.radiance[first : first + count]
        if data_format == "1":
            encoded = [struct.pack(">f", float(v)).hex().upper() for v in values]
        else:
            encoded = [f"{float(v):.4E}".replace("E-0", "E-").replace("E+0", "E+") for v in values]
        self.blocks_read.add(int(block))
        if self.measure_key_enabled and self.blocks_read == set(SPECTRAL_BLOCKS):
            self.data = None
        return ("OK00," + ",".join(encoded)).encode("ascii")


def start_cs2000(
    source: RadianceSource, *, variation: int = 1, **options: Unpack[SpectrometerOptions]
) -> PtySerialDevice:
    """Start a CS-2000 (``variation=1``) or CS-2000A (``2``) emulator on a pty; open
    ``device.path`` with the real driver, then ``device.stop()``.

    ``options``: ``seed``, ``faults``, ``time_scale`` (see :class:`Cs2000Emulator`) and ``symlink``.
    """
    emulator = Cs2000Emulator(
        source,
        variation=variation,
        seed=options.get("seed"),
        faults=options.get("faults"),
        time_scale=options.get("time_scale", 1.0),
    )
    return PtySerialDevice(emulator, symlink=options.get("symlink")).start()
