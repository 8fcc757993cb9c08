"""Firmware emulator of the Photo Research PR-655 / PR-670 SpectraScan (device side of the wire).

What it implements (facts sheet §1.1):

- local mode until the five characters ``PHOTO`` arrive (one at a time or at once, with or without a
  CR), answered by ``REMOTE MODE`` CR LF; a bare ``Q`` (CR optional) returns to local mode, silently;
- in remote mode, commands end with CR (LF is accepted too); every reply line starts with a
  five-character signed code (``00000`` OK, ``-1000`` illegal command …) and ends with CR LF;
- ``D110`` serial, ``D111`` model, ``D114`` firmware, ``D120`` spectral report (points, …, start,
  end, step), ``SE<ms>`` exposure (0 = adaptive; out of range → ``-1010``), ``SN<n>`` averaging
  (1–99, else ``-1012``), ``M0`` measure, ``M5`` measure and send the spectrum (header line, then one
  ``wavelength,value`` line per point), ``D5`` the last spectrum again, ``D13`` the exposure used;
  ``D5``/``D13`` before any measurement → ``-2000``; anything else → ``-1000``;
- measurements take the time the radiometer model says (scaled by ``time_scale``); adaptive exposure
  that cannot find enough light → ``-0008`` (weak light), a fixed exposure that saturates →
  ``-0002`` (light overload).

Fault labels are the command texts (``"PHOTO"``, ``"Q"``, ``"M5"``, ``"SE250"`` …). ``BUSY`` is not
supported: the PR-6xx protocol has no busy reply (a busy instrument simply answers late).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import ClassVar, Unpack

import numpy as np
from numpy.typing import NDArray

from mocks.emulators.radiometer import RadianceSource, Radiometer, RadiometerOptics
from mocks.emulators.serial_base import (
    EmulatorBase,
    ReplyPart,
    SpectrometerOptions,
    measurement_rng,
)
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.pty_serial import PtySerialDevice

CRLF = b"\r\n"
REMOTE_MODE_REPLY = b"REMOTE MODE" + CRLF

OK = 0
LIGHT_OVERLOAD = -2
WEAK_LIGHT = -8
ILLEGAL_COMMAND = -1000
BAD_EXPOSURE = -1010
BAD_AVERAGE_COUNT = -1012
INVALID_DATA_REQUEST = -2000

_PLANCK_J_S = 6.62607015e-34
_LIGHT_SPEED_M_S = 2.99792458e8


@dataclass(frozen=True)
class PrModel:
    """One PR-6xx model as the emulator presents it."""

    model: str
    start_nm: int
    stop_nm: int
    step_nm: int
    bandwidth_nm: float
    exposure_range_ms: tuple[int, int]
    serial: str
    firmware: str
    peak_responsivity: float = 2.0e4

    @property
    def points(self) -> int:
        return (self.stop_nm - self.start_nm) // self.step_nm + 1

    @property
    def wavelength_nm(self) -> NDArray[np.float64]:
        return np.arange(self.start_nm, self.stop_nm + 1, self.step_nm, dtype=np.float64)


#: 380–780 nm at 4 nm, 8 nm bandwidth, exposure 3–6000 ms.
PR655 = PrModel("PR-655", 380, 780, 4, 8.0, (3, 6000), "65061234", "1.25")
#: 380–780 nm at 2 nm (the real grid is read from D120; this one is the emulator's choice).
PR670 = PrModel("PR-670", 380, 780, 2, 5.0, (6, 6000), "70071234", "2.10")


def code_line(code: int, *fields: str) -> bytes:
    """One reply line: the five-character signed code, then comma-separated fields, CR LF."""
    return ",".join([f"{code:05d}", *fields]).encode("ascii") + CRLF


@dataclass(frozen=True, eq=False)
class _Measurement:
    radiance: NDArray[np.float64]
    exposure_ms: float


class Pr6xxEmulator(EmulatorBase):
    """A PR-655 or PR-670 measuring ``source``.

    Parameters
    ----------
    model
        :data:`PR655` or :data:`PR670` (or another :class:`PrModel`).
    source
        Spectral radiance the instrument looks at.
    seed
        Seed (or generator) for the measurement noise.
    faults, time_scale
        See :class:`mocks.emulators.serial_base.EmulatorBase`.
    """

    SUPPORTED_FAULTS: ClassVar[frozenset[FaultKind]] = frozenset(FaultKind) - {FaultKind.BUSY}

    def __init__(
        self,
        model: PrModel,
        source: RadianceSource,
        *,
        seed: int | np.random.Generator | None = None,
        faults: FaultSchedule | None = None,
        time_scale: float = 1.0,
    ) -> None:
        super().__init__(model.model, faults=faults, time_scale=time_scale)
        self.model = model
        optics = RadiometerOptics(
            wavelength_nm=model.wavelength_nm,
            bandwidth_nm=model.bandwidth_nm,
            peak_responsivity=model.peak_responsivity,
            exposure_range_ms=(
                float(model.exposure_range_ms[0]),
                float(model.exposure_range_ms[1]),
            ),
        )
        self.radiometer = Radiometer(optics, source, measurement_rng(seed))
        self.remote = False
        self.exposure_ms = 0  # 0 = adaptive
        self.averages = 1
        self.last: _Measurement | None = None
        self._line = bytearray()

    # ------------------------------------------------------------------------------ input

    def receive(self, data: bytes) -> None:
        for byte in data:
            self._receive_byte(byte)

    def _receive_byte(self, byte: int) -> None:
        if not self.remote:
            # Local mode: only the PHOTO handshake means anything; line ends are ignored.
            if byte in b"\r\n":
                return
            self._line.append(byte)
            del self._line[:-5]
            if bytes(self._line) == b"PHOTO":
                self._line.clear()
                self._command("PHOTO")
            return
        if byte in b"\r\n":
            if self._line:
                text = self._line.decode("ascii", errors="replace")
                self._line.clear()
                self._command(text)
            return
        if not self._line and byte == ord("Q"):
            self._command("Q")
            return
        self._line.append(byte)
        if bytes(self._line) == b"PHOTO":
            self._line.clear()
            self._command("PHOTO")

    # ------------------------------------------------------------------------------ commands

    def _command(self, text: str) -> None:
        fault = self.next_fault(text)
        if fault is not None and fault.kind is FaultKind.ERROR_CODE:
            parts = [ReplyPart(code_line(self._error_code(text, fault)))]
        else:
            parts = self._execute(text)
        self.deliver(parts, fault)

    @staticmethod
    def _error_code(text: str, fault: Fault) -> int:
        if fault.code is not None:
            return int(fault.code)
        if text.startswith("M"):
            return WEAK_LIGHT
        if text.startswith("SE"):
            return BAD_EXPOSURE
        return ILLEGAL_COMMAND

    def _execute(self, text: str) -> list[ReplyPart]:
        if text == "PHOTO":
            self.remote = True
            return [ReplyPart(REMOTE_MODE_REPLY)]
        if text == "Q":
            self.remote = False
            return []
        model = self.model
        if text == "D110":
            return [ReplyPart(code_line(OK, model.serial))]
        if text == "D111":
            return [ReplyPart(code_line(OK, model.model))]
        if text == "D114":
            return [ReplyPart(code_line(OK, model.firmware))]
        if text == "D120":
            fields = [str(model.points), "0.00", str(model.start_nm), str(model.stop_nm)]
            fields += [str(model.step_nm), f"{model.bandwidth_nm:.0f}", "1", "0"]
            return [ReplyPart(code_line(OK, *fields))]
        if match := re.fullmatch(r"SE(\d{1,5})", text):
            return [ReplyPart(code_line(self._set_exposure(int(match.group(1)))))]
        if match := re.fullmatch(r"SN(\d{1,2})", text):
            count = int(match.group(1))
            if not 1 <= count <= 99:
                return [ReplyPart(code_line(BAD_AVERAGE_COUNT))]
            self.averages = count
            return [ReplyPart(code_line(OK))]
        if text in ("M0", "M5"):
            return self._measure(send_spectrum=text == "M5")
        if text == "D5":
            if self.last is None:
                return [ReplyPart(code_line(INVALID_DATA_REQUEST))]
            return [ReplyPart(self._spectrum_reply(self.last))]
        if text == "D13":
            if self.last is None:
                return [ReplyPart(code_line(INVALID_DATA_REQUEST))]
            return [ReplyPart(code_line(OK, "Normal", f"{self.last.exposure_ms:.0f} msec"))]
        return [ReplyPart(code_line(ILLEGAL_COMMAND))]

    def _set_exposure(self, exposure_ms: int) -> int:
        low, high = self.model.exposure_range_ms
        if exposure_ms != 0 and not low <= exposure_ms <= high:
            return BAD_EXPOSURE
        self.exposure_ms = exposure_ms
        return OK

    def _measure(self, *, send_spectrum: bool) -> list[ReplyPart]:
        exposure = None if self.exposure_ms == 0 else float(self.exposure_ms)
        observation = self.radiometer.observe(exposure, self.averages)
        at_s = self.seconds(observation.duration_s)
        if observation.status == "overload":
            self.last = None
            return [ReplyPart(code_line(LIGHT_OVERLOAD), at_s)]
        if observation.status == "weak_light" or observation.radiance is None:
            self.last = None
            return [ReplyPart(code_line(WEAK_LIGHT), at_s)]
        self.last = _Measurement(observation.radiance, observation.exposure_ms)
        reply = self._spectrum_reply(self.last) if send_spectrum else code_line(OK)
        return [ReplyPart(reply, at_s)]

    def _spectrum_reply(self, measurement: _Measurement) -> bytes:
        wavelength_nm = self.model.wavelength_nm
        radiance = measurement.radiance
        step_nm = float(self.model.step_nm)
        integrated = float(np.sum(radiance) * step_nm)
        photon_energy_j = _PLANCK_J_S * _LIGHT_SPEED_M_S / (wavelength_nm * 1e-9)
        photons = float(np.sum(radiance / photon_energy_j) * step_nm)
        peak_nm = float(wavelength_nm[int(np.argmax(radiance))])
        header = code_line(OK, "0", f"{peak_nm:.3e}", f"{integrated:.3e}", f"{photons:.3e}")
        lines = [
            f"{wavelength:.0f},{value:.4e}".encode("ascii") + CRLF
            for wavelength, value in zip(wavelength_nm, radiance, strict=True)
        ]
        return header + b"".join(lines)


def start_pr6xx(
    model: PrModel, source: RadianceSource, **options: Unpack[SpectrometerOptions]
) -> PtySerialDevice:
    """Start a PR-6xx emulator on a pty; open ``device.path`` with the real driver, then
    ``device.stop()``.

    ``options``: ``seed`` (noise), ``faults``, ``time_scale`` (see :class:`Pr6xxEmulator`) and
    ``symlink`` (a stable device path, see :class:`mocks.pty_serial.PtySerialDevice`).
    """
    emulator = Pr6xxEmulator(
        model,
        source,
        seed=options.get("seed"),
        faults=options.get("faults"),
        time_scale=options.get("time_scale", 1.0),
    )
    return PtySerialDevice(emulator, symlink=options.get("symlink")).start()


def start_pr655(source: RadianceSource, **options: Unpack[SpectrometerOptions]) -> PtySerialDevice:
    """A PR-655 on a pty (see :func:`start_pr6xx`)."""
    return start_pr6xx(PR655, source, **options)


def start_pr670(source: RadianceSource, **options: Unpack[SpectrometerOptions]) -> PtySerialDevice:
    """A PR-670 on a pty (see :func:`start_pr6xx`)."""
    return start_pr6xx(PR670, source, **options)
