"""Konica Minolta CS-2000 / CS-2000A spectroradiometers over a serial (USB virtual COM) port.

The protocol as the facts sheet (``protocols.md`` §1.2) paraphrases the KM communication
specification (KMSE A0E3-CS.07E), and the choices made where it leaves room (``docs/decisions/0003``):

- the port: 115200 8N1 with RTS/CTS (:data:`SERIAL_SETTINGS`); commands end with LF
  (:data:`COMMAND_TERMINATOR`; CR and CR LF are allowed too) and the instrument answers with the same
  delimiter; replies are ``OK00`` or ``ERxx`` followed by comma-separated parameters;
- ``RMTS,2`` enters remote mode without writing settings to flash, ``RMTS,0`` leaves it;
- ``IDDR`` identity; ``SPMS``/``SPMR`` speed mode (Normal with automatic integration for adaptive
  exposure, Manual with a 9-digit integration time in µs for a fixed one; the internal ND filter
  off/on/auto), read back after every change;
- ``MEAS,1`` answers twice: ``OK00,ttt`` once the pre-measurement is done (``ttt`` = remaining
  seconds), then ``OK00`` when the measurement has finished. The driver blocks on the port for the
  second line with a deadline of ``ttt`` plus a margin, instead of sleeping and polling; if that
  deadline passes it cancels the measurement (``MEAS,0``) before raising;
- ``MEDR,0,0,1`` measurement conditions (the integration time actually used), ``MEDR,1,1,<1–4>`` the
  spectrum in four blocks (380–479, 480–579, 580–679, 680–780 nm at 1 nm: 100, 100, 100, 101
  values), each value 8 hex digits of a big-endian IEEE-754 float32;
- ``ERxx`` codes map to typed errors: ``ER02`` (measurement in progress) is
  :class:`~drivers.base.DeviceBusy`, the rest :class:`~drivers.base.InstrumentError` with the manual's
  meaning.
"""

from __future__ import annotations

import logging
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from drivers.base import (
    DeviceBusy,
    DeviceError,
    DeviceIdentity,
    DeviceNotFound,
    DeviceTimeout,
    InstrumentError,
    ProtocolError,
    SpectrumReading,
    StateMismatch,
    TranscriptSink,
)
from drivers.lifecycle import ClosesOnExit, connect_or_close, farewell_then_close
from drivers.replies import ReplyContext, decode_ascii, parse_int
from drivers.transport import ByteTransport, Deadline, SerialSettings, ask, open_serial

_log = logging.getLogger(__name__)

SERIAL_SETTINGS = SerialSettings(baudrate=115200, rtscts=True)
#: [?] The manual allows CR, LF or CR LF; colour-specio uses LF, and so do we.
COMMAND_TERMINATOR = b"\n"
#: Remote mode without writing settings to flash (firmware >= 3.00.9301; flash wears out).
REMOTE_ON = "RMTS,2"
REMOTE_OFF = "RMTS,0"
#: The manual asks hosts to allow at least 10 s for any command; the pre-measurement alone takes
#: up to 10 s.
DEFAULT_TIMEOUT_S = 15.0
#: Allowance beyond the measurement time the instrument announces.
DEFAULT_COMPLETION_MARGIN_S = 10.0
#: The longest remaining measurement time ``MEAS,1`` can announce (``OK00,ttt``: 002–242 s).
LONGEST_ANNOUNCED_S = 242.0
#: [?] The manual says "spectral irradiance"; the instrument measures radiance.
SPECTRAL_UNITS = "W/(sr·m²·nm)"

#: ``MEDR,1`` blocks: (first wavelength in nm, number of values).
SPECTRAL_BLOCKS: dict[int, tuple[int, int]] = {
    1: (380, 100),
    2: (480, 100),
    3: (580, 100),
    4: (680, 101),
}
#: What the instrument sends (hex format) for a value it could not calculate (≈ −9.999999e10).
CALCULATION_ERROR_HEX = "D1BA43B6"

MODELS = ("CS-2000", "CS-2000A")
InternalNd = Literal["off", "on", "auto"]
INTERNAL_ND_CODES: dict[InternalNd, int] = {"off": 0, "on": 1, "auto": 2}
#: Manual integration time limits, µs.
MANUAL_INTEGRATION_RANGE_US = (5_000, 120_000_000)
SPEED_MODES = {0: "Normal", 1: "Fast", 2: "Multi-integration Normal", 3: "Manual", 4: "Multi Fast"}

ERROR_MEANINGS: dict[str, str] = {
    "ER00": "command not understood, wrong number of parameters, or not in remote mode",
    "ER02": "measurement in progress",
    "ER05": "no compensation values",
    "ER10": "over range (too bright, or too much flicker): enable the internal ND or attenuate",
    "ER17": "parameter out of range",
    "ER20": "no measurement data",
    "ER30": "internal memory error",
    "ER32": "internal memory error",
    "ER34": "internal memory error",
    "ER51": "temperature abnormal",
    "ER52": "temperature abnormal",
    "ER71": "sync signal out of range (20–200 Hz) or missing",
    "ER81": "shutter fault",
    "ER82": "internal ND filter fault",
    "ER83": "measurement-angle selector abnormal",
    "ER84": "cooling fan fault",
    "ER99": "program abnormality",
}

#: Spectral bandwidth (FWHM) of the CS-2000/2000A: "5 nm or less" in Konica Minolta's specification.
BANDWIDTH_NM = 5.0


@dataclass(frozen=True)
class SpeedSetting:
    """A speed-mode setting as ``SPMS`` takes it and ``SPMR`` reports it."""

    mode: int
    internal_nd: int
    integration_us: int | None = None
    multi_integration_s: int | None = None

    def command(self) -> str:
        if self.mode == 3:
            return f"SPMS,3,{self.integration_us:09d},{self.internal_nd}"
        if self.mode in (2, 4):
            return f"SPMS,{self.mode},{self.multi_integration_s:02d},{self.internal_nd}"
        return f"SPMS,{self.mode},{self.internal_nd}"


@dataclass(frozen=True)
class MeasurementConditions:
    """The first fields of ``MEDR,0,0,1``."""

    speed_mode: int
    sync_mode: int
    integration_us: int
    internal_nd: int


# ------------------------------------------------------------------------------ reply parsers


def parse_reply(line: bytes, context: ReplyContext) -> list[str]:
    """The parameters of an ``OK00`` reply line.

    Raises
    ------
    DeviceBusy
        ``ER02``.
    InstrumentError
        Any other ``ERxx``.
    ProtocolError
        Not ASCII, not terminated, or neither ``OK00`` nor ``ERxx``.
    """
    text = decode_ascii(line, context)
    if not text.endswith(("\n", "\r")):
        raise context.error("reply line is not terminated", line)
    fields = text.rstrip("\r\n").split(",")
    code = fields[0]
    if code == "OK00":
        return fields[1:]
    if re.fullmatch(r"ER\d\d", code):
        meaning = ERROR_MEANINGS.get(code, "unknown error code (see the communication spec)")
        if code == "ER02":
            raise DeviceBusy(context.device, f"{meaning} (code ER02, command {context.command!r})")
        raise InstrumentError(context.device, meaning, code=code, command=context.command)
    raise context.error("reply starts with neither OK00 nor ERxx", line)


def _field_count(
    fields: Sequence[str], count: int, what: str, context: ReplyContext, line: bytes
) -> None:
    if len(fields) != count:
        raise context.error(f"{what} has {len(fields)} parameters, expected {count}", line)


def parse_identity(fields: Sequence[str], context: ReplyContext, line: bytes) -> tuple[str, str]:
    """``(model, serial)`` from ``IDDR`` (product name, variation 1/2, 7-digit serial)."""
    _field_count(fields, 3, "IDDR reply", context, line)
    variation = parse_int(fields[1], "product variation", context, line)
    models = {1: "CS-2000", 2: "CS-2000A"}
    if variation not in models:
        raise context.error(
            f"unknown product variation {variation} (1 = CS-2000, 2 = CS-2000A)", line
        )
    serial = fields[2].strip()
    if not re.fullmatch(r"\d{1,10}", serial):
        raise context.error(f"serial number {serial!r} is not numeric", line)
    return models[variation], serial


def parse_measurement_time(fields: Sequence[str], context: ReplyContext, line: bytes) -> int:
    """The remaining measurement time in seconds from the ``MEAS,1`` acknowledgement."""
    _field_count(fields, 1, "MEAS acknowledgement", context, line)
    if not re.fullmatch(r"\d{1,3}", fields[0]):
        raise context.error(f"measurement time {fields[0]!r} is not 1–3 digits", line)
    seconds = int(fields[0])
    if seconds > LONGEST_ANNOUNCED_S:
        raise context.error(
            f"measurement time {seconds} s is beyond the instrument's {LONGEST_ANNOUNCED_S:g} s",
            line,
        )
    return seconds


def parse_conditions(
    fields: Sequence[str], context: ReplyContext, line: bytes
) -> MeasurementConditions:
    """The measurement conditions of ``MEDR,0,0,1``."""
    if len(fields) < 4:
        raise context.error("measurement conditions have fewer than 4 parameters", line)
    return MeasurementConditions(
        speed_mode=parse_int(fields[0], "speed mode", context, line),
        sync_mode=parse_int(fields[1], "sync mode", context, line),
        integration_us=parse_int(fields[2], "integration time", context, line),
        internal_nd=parse_int(fields[3], "internal ND", context, line),
    )


def parse_speed_setting(fields: Sequence[str], context: ReplyContext, line: bytes) -> SpeedSetting:
    """The speed mode reported by ``SPMR``."""
    if not fields:
        raise context.error("SPMR reply has no parameters", line)
    mode = parse_int(fields[0], "speed mode", context, line)
    if mode in (0, 1):
        _field_count(fields, 2, "SPMR reply", context, line)
        return SpeedSetting(mode, parse_int(fields[1], "internal ND", context, line))
    if mode in (2, 3, 4):
        _field_count(fields, 3, "SPMR reply", context, line)
        value = parse_int(fields[1], "integration time", context, line)
        nd = parse_int(fields[2], "internal ND", context, line)
        if mode == 3:
            return SpeedSetting(mode, nd, integration_us=value)
        return SpeedSetting(mode, nd, multi_integration_s=value)
    raise context.error(f"unknown speed mode {mode}", line)


def parse_spectral_block(
    fields: Sequence[str], block: int, context: ReplyContext, line: bytes
) -> NDArray[np.float64]:
    """The values of one ``MEDR,1,1,<block>`` reply (big-endian float32 in 8 hex digits each).

    Raises
    ------
    InstrumentError
        The instrument flags a value it could not calculate.
    ProtocolError
        Wrong count, bad hex, or a non-finite value.
    """
    start_nm, count = SPECTRAL_BLOCKS[block]
    _field_count(fields, count, f"spectral block {block}", context, line)
    values = np.empty(count)
    failed: list[int] = []
    for index, text in enumerate(fields):
        if not re.fullmatch(r"[0-9A-Fa-f]{8}", text):
            raise context.error(f"value {index + 1} of block {block} is not 8 hex digits", line)
        if text.upper() == CALCULATION_ERROR_HEX:
            failed.append(start_nm + index)
            continue
        (value,) = struct.unpack(">f", bytes.fromhex(text))
        if not np.isfinite(value):
            raise context.error(f"value {index + 1} of block {block} is not finite", line)
        values[index] = value
    if failed:
        raise InstrumentError(
            context.device,
            f"the instrument could not calculate the spectral value at {len(failed)} "
            f"wavelength(s), first at {failed[0]} nm",
            code=CALCULATION_ERROR_HEX,
            command=context.command,
        )
    return values


# --------------------------------------------------------------------------------- the driver


def _check_options(model: str, internal_nd: str) -> None:
    if model not in MODELS:
        raise ValueError(f"unknown Konica Minolta model {model!r}; known: {', '.join(MODELS)}")
    if internal_nd not in INTERNAL_ND_CODES:
        raise ValueError(f"internal_nd is 'off', 'on' or 'auto', got {internal_nd!r}")


class Cs2000(ClosesOnExit):
    """A CS-2000 or CS-2000A in remote mode; implements :class:`drivers.base.Spectrometer`.

    Build it with :func:`open_cs2000` (or :func:`drivers.spectrometer.open_spectrometer`). Not
    thread-safe.

    Parameters
    ----------
    transport
        The byte link to the instrument.
    model
        ``"CS-2000"`` or ``"CS-2000A"``; the instrument must report the same variation.
    timeout_s
        Deadline of each command (and of the ``MEAS`` acknowledgement, which follows the
        pre-measurement); ``None``: :data:`DEFAULT_TIMEOUT_S`.
    completion_margin_s
        Allowance beyond the announced measurement time for the completion line; ``None``:
        :data:`DEFAULT_COMPLETION_MARGIN_S`.
    internal_nd
        Internal ND filter for every measurement: ``"off"``, ``"on"`` or ``"auto"``.
    port
        Where the instrument is connected (reported in its identity).
    """

    def __init__(
        self,
        transport: ByteTransport,
        *,
        model: str = "CS-2000",
        timeout_s: float | None = None,
        completion_margin_s: float | None = None,
        internal_nd: InternalNd = "auto",
        port: str | None = None,
    ) -> None:
        _check_options(model, internal_nd)
        self._transport = transport
        self.model = model
        self.port = port
        self.timeout_s = DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s
        self.completion_margin_s = (
            DEFAULT_COMPLETION_MARGIN_S if completion_margin_s is None else completion_margin_s
        )
        self.internal_nd = internal_nd
        self._remote = False
        self._identity: DeviceIdentity | None = None

    @property
    def device(self) -> str:
        return self._transport.device

    # ------------------------------------------------------------------------------ exchanges

    def _context(self, command: str) -> ReplyContext:
        return ReplyContext(self.device, command)

    def _send(self, command: str, deadline: Deadline) -> bytes:
        return ask(
            self._transport,
            command.encode("ascii") + COMMAND_TERMINATOR,
            terminator=COMMAND_TERMINATOR,
            deadline=deadline,
        )

    def _query(self, command: str) -> tuple[list[str], bytes]:
        """Send ``command``; the parameters of its ``OK00`` reply, and the reply line."""
        line = self._send(command, Deadline(self.timeout_s))
        return parse_reply(line, self._context(command)), line

    # ------------------------------------------------------------------------------ session

    def connect(self) -> None:
        """Enter remote mode (``RMTS,2``) and identify the instrument.

        Raises
        ------
        DeviceNotFound
            The instrument on the port is the other variation.
        """
        try:
            self._query(REMOTE_ON)
        except InstrumentError as exc:
            raise InstrumentError(
                self.device,
                f"the instrument refused {REMOTE_ON} ({exc.message}); remote mode without flash "
                "writes needs firmware 3.00.9301 or later",
                code=exc.code,
                command=REMOTE_ON,
            ) from exc
        self._remote = True
        identity = self.identify()
        if identity.model != self.model:
            raise DeviceNotFound(
                self.device,
                f"the instrument on this port is a {identity.model}, the config says "
                f"{self.model}; fix the spectrometer model in the config",
            )

    def identify(self) -> DeviceIdentity:
        """Model and serial number from ``IDDR``; cached."""
        if self._identity is None:
            fields, line = self._query("IDDR")
            model, serial = parse_identity(fields, self._context("IDDR"), line)
            self._identity = DeviceIdentity(
                kind="spectrometer", model=model, serial=serial, port=self.port
            )
        return self._identity

    # ------------------------------------------------------------------------------ settings

    def speed_setting(self) -> SpeedSetting:
        """The speed mode as the instrument reports it (``SPMR``)."""
        fields, line = self._query("SPMR")
        return parse_speed_setting(fields, self._context("SPMR"), line)

    def set_exposure(self, exposure_ms: float | None) -> None:
        """Manual integration time in ms (5–120 000, to the µs), or ``None`` for Normal mode
        (automatic integration); read back with ``SPMR``.

        Raises
        ------
        ValueError
            Outside the instrument's range.
        StateMismatch
            The setting read back differs.
        """
        nd = INTERNAL_ND_CODES[self.internal_nd]
        if exposure_ms is None:
            wanted = SpeedSetting(mode=0, internal_nd=nd)
        else:
            integration_us = round(exposure_ms * 1000)
            low, high = MANUAL_INTEGRATION_RANGE_US
            if not low <= integration_us <= high:
                raise ValueError(
                    f"{self.model} manual integration must be {low / 1000:g}–{high / 1000:g} ms "
                    f"(or None for automatic), got {exposure_ms!r} ms"
                )
            wanted = SpeedSetting(mode=3, internal_nd=nd, integration_us=integration_us)
        self._query(wanted.command())
        actual = self.speed_setting()
        if actual != wanted:
            raise StateMismatch(
                self.device,
                "speed mode read back after SPMS differs",
                expected=wanted,
                actual=actual,
            )

    # ------------------------------------------------------------------------------ measuring

    def _cancel_measurement(self) -> None:
        """Best effort ``MEAS,0`` after a lost completion line, so the next command is accepted."""
        try:
            self._query("MEAS,0")
        except DeviceError as exc:
            _log.warning("%s: could not cancel the measurement: %s", self.device, exc)

    def measure(self) -> SpectrumReading:
        """Measure (``MEAS,1``), wait for completion, read conditions and the four blocks.

        Raises
        ------
        InstrumentError
            ``ER10`` over range and other instrument errors.
        DeviceBusy
            The instrument is still busy with another measurement.
        DeviceTimeout
            No acknowledgement within ``timeout_s``, or no completion within the announced time
            plus ``completion_margin_s`` (the measurement is then cancelled).
        """
        command = "MEAS,1"
        context = self._context(command)
        ack, ack_line = self._query(command)
        try:
            measurement_s = parse_measurement_time(ack, context, ack_line)
        except ProtocolError:
            self._cancel_measurement()  # whatever it announced, it may be measuring
            raise
        completion = Deadline(measurement_s + self.completion_margin_s)
        try:
            done = self._transport.read_until(COMMAND_TERMINATOR, deadline=completion)
        except DeviceTimeout:
            self._cancel_measurement()
            raise
        parse_reply(done, self._context("MEAS,1 (completion)"))

        fields, line = self._query("MEDR,0,0,1")
        conditions = parse_conditions(fields, self._context("MEDR,0,0,1"), line)
        blocks = []
        for block in SPECTRAL_BLOCKS:
            block_command = f"MEDR,1,1,{block}"
            fields, line = self._query(block_command)
            blocks.append(parse_spectral_block(fields, block, self._context(block_command), line))
        return SpectrumReading(
            wavelength_nm=np.arange(380.0, 781.0, 1.0),
            values=np.concatenate(blocks),
            units=SPECTRAL_UNITS,
            exposure_ms=conditions.integration_us / 1000.0,
            bandwidth_nm=BANDWIDTH_NM,
            extra={
                "speed_mode": SPEED_MODES.get(conditions.speed_mode, str(conditions.speed_mode)),
                "internal_nd": str(conditions.internal_nd),
                "announced_measurement_s": str(measurement_s),
            },
        )

    # ------------------------------------------------------------------------------ closing

    def close(self) -> None:
        """Leave remote mode (``RMTS,0``) and close the port; never raises for a device gone."""
        farewell = (lambda: self._query(REMOTE_OFF)) if self._remote else None
        self._remote = False
        farewell_then_close(self.device, farewell, self._transport)


def longest_measure_s(
    timeout_s: float | None = None, completion_margin_s: float | None = None
) -> float:
    """The longest :meth:`Cs2000.measure` may take: ``MEAS,1``'s acknowledgement (one command, the
    1–10 s pre-measurement inside it), the longest time the instrument can announce
    (:data:`LONGEST_ANNOUNCED_S`) plus the margin, then ``MEDR`` for the conditions and the four
    spectral blocks (five commands). Timeouts as for :class:`Cs2000` (``None``: the defaults).
    """
    command = DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s
    margin = DEFAULT_COMPLETION_MARGIN_S if completion_margin_s is None else completion_margin_s
    return command + LONGEST_ANNOUNCED_S + margin + 5 * command


def open_cs2000(
    port: str,
    *,
    model: str = "CS-2000",
    timeout_s: float | None = None,
    completion_margin_s: float | None = None,
    internal_nd: InternalNd = "auto",
    transcript: TranscriptSink | None = None,
    baud: int | None = None,
) -> Cs2000:
    """Open a CS-2000/CS-2000A on ``port`` (path or pyserial URL), enter remote mode, identify it.

    ``baud`` overrides the line speed of :data:`SERIAL_SETTINGS`; the timeouts are as for
    :class:`Cs2000` (``None``: the defaults).

    Raises
    ------
    DeviceNotFound
        No port, or the other variation on it.
    DeviceTimeout
        The instrument does not answer.
    """
    _check_options(model, internal_nd)
    transport = open_serial(
        port, SERIAL_SETTINGS.with_baud(baud), device=f"{model} on {port}", transcript=transcript
    )
    instrument = Cs2000(
        transport,
        model=model,
        timeout_s=timeout_s,
        completion_margin_s=completion_margin_s,
        internal_nd=internal_nd,
        port=port,
    )
    return connect_or_close(instrument, instrument.connect)
