"""Photo Research PR-655 / PR-670 SpectraScan spectroradiometers over a serial (USB CDC) port.

The protocol, as the facts sheet (``protocols.md`` §1.1) reconstructs it from PsychoPy, Psychtoolbox
and colour-specio, and the choices made where the sources disagree (``docs/decisions/0003``):

- the port: 9600 8N1, no flow control (:data:`SERIAL_SETTINGS`); commands are written one character
  at a time with a pause (:data:`DEFAULT_PACING`), which the PR-655's USB link needs to be reliable;
- remote mode: the five characters ``PHOTO`` (no terminator, :data:`REMOTE_MODE_COMMAND`) answered
  by ``REMOTE MODE`` CR LF; leave it with a bare ``Q`` (:data:`QUIT_COMMAND`, no reply);
- commands end with CR (:data:`COMMAND_TERMINATOR`); every reply line starts with a signed numeric
  status (``00000`` = OK), data follow after commas, lines end with CR LF;
- ``D110`` serial, ``D111`` model, ``D114`` firmware, ``D120`` spectral report (points, …, start,
  end, step: the grid is read from the instrument, never assumed), ``SE<ms>`` exposure (``SE0`` =
  adaptive), ``SN<n>`` cycles to average, ``M5`` measure and send the spectrum (header line, then
  one ``wavelength,value`` line per grid point), ``D5`` the last spectrum again, ``D13`` the exposure
  the last measurement used;
- status codes map to typed errors: :class:`~drivers.spectrometer.errors.MeasurementConditionError`
  (retryable) for unstable light and sync problems, :class:`~drivers.base.InstrumentError` for the
  rest (each with the manual's meaning).

Every reply parser is a pure ``parse_*`` function that raises only typed device errors.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.base import (
    DeviceIdentity,
    DeviceNotFound,
    InstrumentError,
    SpectrumReading,
    TranscriptSink,
)
from drivers.lifecycle import ClosesOnExit, connect_or_close, farewell_then_close
from drivers.replies import ReplyContext, decode_ascii, parse_float, parse_int
from drivers.spectrometer.errors import MeasurementConditionError
from drivers.transport import (
    ByteTransport,
    Deadline,
    Pacing,
    SerialSettings,
    ask,
    open_serial,
)

SERIAL_SETTINGS = SerialSettings(baudrate=9600, rtscts=False)
#: colour-specio's figures (10 ms per character, 50 ms between commands); Psychtoolbox uses 50 ms
#: per character. [?] The PR-655's USB CDC link is said to need pacing; the PR-670 may not.
DEFAULT_PACING = Pacing(char_delay_s=0.01, command_gap_s=0.05)
#: [?] Psychtoolbox and the manual paraphrase send no terminator after PHOTO; colour-specio adds CR.
REMOTE_MODE_COMMAND = b"PHOTO"
REMOTE_MODE_REPLY = b"REMOTE MODE"
#: [?] A bare Q per the manual paraphrase; colour-specio sends Q CR.
QUIT_COMMAND = b"Q"
#: [?] CR per Psychtoolbox, colour-specio and the manual paraphrase; PsychoPy's LF is unconfirmed.
COMMAND_TERMINATOR = b"\r"
REPLY_TERMINATOR = b"\r\n"
#: Spectral radiance as the PR-6xx reports it in its spectral data (per nm).
SPECTRAL_UNITS = "W/(sr·m²·nm)"

#: Timeout for commands other than measurements (PHOTO gets 10 s in PsychoPy and colour-specio).
DEFAULT_TIMEOUT_S = 10.0
#: Timeout for a whole measurement including its spectral reply (adaptive exposure on a dim source
#: takes many seconds; colour-specio allows 60 s).
DEFAULT_MEASURE_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class ModelLimits:
    """What differs between the PR-6xx models the driver knows."""

    exposure_range_ms: tuple[int, int]


#: Exposure limits in standard mode (the PR-670's extended mode, ``SH1``, is not used).
MODELS: dict[str, ModelLimits] = {
    "PR-655": ModelLimits(exposure_range_ms=(3, 6000)),
    "PR-670": ModelLimits(exposure_range_ms=(6, 6000)),
}

#: Status codes from the PR-655/670 manual (as reproduced by colour-specio and the MATLAB class).
STATUS_MEANINGS: dict[int, str] = {
    -1: "light source not constant",
    -2: "light overload (too bright: shorten the exposure or attenuate the source)",
    -3: "cannot sync to the light source",
    -4: "adaptive-mode error",
    -8: "weak light (too dark to measure: lengthen the exposure or brighten the source)",
    -9: "sync error",
    -10: "cannot auto-sync",
    -12: "adaptive-mode timeout",
    -1000: "illegal command",
    -1001: "too many fields in the command",
    -1008: "bad aperture index",
    -1009: "bad units code",
    -1010: "bad exposure value",
    -1011: "bad gain code",
    -1012: "bad average count",
    -1015: "bad observer",
    -1017: "bad dark mode",
    -1019: "bad sync mode",
    -1023: "bad user sync frequency",
    -1026: "bad sensitivity mode",
    -1035: "parameter not applicable",
    -2000: "invalid data request (no such data code, or no measurement made yet)",
}
#: Codes that depend on the light at the moment: measuring again may succeed.
TRANSIENT_CODES = frozenset({-1, -3, -4, -9, -10, -12})


#: Spectral bandwidth (FWHM of the slit function) by model, from Photo Research's data sheets
#: (PR-655: 8 nm; PR-670: 5 nm with its standard aperture). [?] Confirm on the instrument: the
#: estimator blurs profiles to this resolution before comparing them with the measured spectrum.
BANDWIDTH_NM: dict[str, float] = {"PR-655": 8.0, "PR-670": 5.0}


@dataclass(frozen=True)
class SpectralGrid:
    """The instrument's wavelength sampling, as ``D120`` reports it."""

    points: int
    start_nm: float
    stop_nm: float
    step_nm: float

    @property
    def wavelength_nm(self) -> NDArray[np.float64]:
        """Shape ``(points,)``."""
        return self.start_nm + self.step_nm * np.arange(self.points, dtype=np.float64)


@dataclass(frozen=True)
class SpectrumHeader:
    """The first line of a spectral reply."""

    units_code: str
    peak_wavelength_nm: float
    integrated_radiance: float
    integrated_photon_radiance: float


@dataclass(frozen=True, eq=False)
class ParsedSpectrum:
    """A spectral reply: its header and the ``(points,)`` wavelength and value arrays."""

    header: SpectrumHeader
    wavelength_nm: NDArray[np.float64]
    values: NDArray[np.float64]


# ------------------------------------------------------------------------------ reply parsers


def parse_reply_line(line: bytes, context: ReplyContext) -> tuple[int, list[str]]:
    """Split one CR LF line into its status code and its data fields.

    Raises
    ------
    ProtocolError
        The line is not ASCII, not terminated, or does not start with a numeric code.
    """
    text = decode_ascii(line, context)
    if not text.endswith("\r\n"):
        raise context.error("reply line does not end with CR LF", line)
    fields = text[:-2].split(",")
    code_text = fields[0].strip()
    if not re.fullmatch(r"[+-]?\d{1,5}", code_text):
        raise context.error("reply does not start with a numeric status code", line)
    return int(code_text), fields[1:]


def raise_for_status(code: int, context: ReplyContext) -> None:
    """Raise the typed error for a non-zero status code."""
    if code == 0:
        return
    meaning = STATUS_MEANINGS.get(code, "unknown status code (see the instrument manual)")
    error = MeasurementConditionError if code in TRANSIENT_CODES else InstrumentError
    raise error(context.device, meaning, code=str(code), command=context.command)


def parse_status_reply(line: bytes, context: ReplyContext) -> list[str]:
    """The data fields of a reply line whose status must be OK."""
    code, fields = parse_reply_line(line, context)
    raise_for_status(code, context)
    return fields


def parse_grid(fields: Sequence[str], context: ReplyContext, reply: bytes) -> SpectralGrid:
    """The spectral grid from the fields of a ``D120`` reply (points, ?, start, end, step, …)."""
    if len(fields) < 5:
        raise context.error(
            "D120 reply has fewer than 5 fields (points, ?, start, end, step)", reply
        )
    points = parse_int(fields[0], "number of spectral points", context, reply)
    start_nm = parse_float(fields[2], "start wavelength", context, reply)
    stop_nm = parse_float(fields[3], "end wavelength", context, reply)
    step_nm = parse_float(fields[4], "wavelength step", context, reply)
    if points < 2 or step_nm <= 0 or stop_nm <= start_nm:
        raise context.error("D120 reports an impossible spectral grid", reply)
    if abs(start_nm + step_nm * (points - 1) - stop_nm) > 1e-6 * max(1.0, stop_nm):
        raise context.error(
            f"D120 grid is inconsistent: {points} points from {start_nm:g} nm in "
            f"{step_nm:g} nm steps do not end at {stop_nm:g} nm",
            reply,
        )
    return SpectralGrid(points, start_nm, stop_nm, step_nm)


def parse_spectrum_header(
    fields: Sequence[str], context: ReplyContext, reply: bytes
) -> SpectrumHeader:
    """The header fields of an ``M5``/``D5`` reply: units, peak λ, radiometric and photon sums."""
    if len(fields) < 4:
        raise context.error("spectral header has fewer than 4 fields after the status", reply)
    return SpectrumHeader(
        units_code=fields[0].strip(),
        peak_wavelength_nm=parse_float(fields[1], "peak wavelength", context, reply),
        integrated_radiance=parse_float(fields[2], "integrated radiance", context, reply),
        integrated_photon_radiance=parse_float(fields[3], "photon radiance", context, reply),
    )


def parse_spectrum(
    header_line: bytes, data_lines: Sequence[bytes], grid: SpectralGrid, context: ReplyContext
) -> ParsedSpectrum:
    """A whole spectral reply: the header line and one ``wavelength,value`` line per grid point.

    The wavelengths must match the grid reported by ``D120``.

    Raises
    ------
    InstrumentError
        The header carries an error status (e.g. weak light).
    ProtocolError
        Anything malformed, or wavelengths off the grid.
    """
    header = parse_spectrum_header(parse_status_reply(header_line, context), context, header_line)
    if len(data_lines) != grid.points:
        raise context.error(f"expected {grid.points} spectral lines, got {len(data_lines)}", None)
    wavelength_nm = np.empty(grid.points)
    values = np.empty(grid.points)
    for index, line in enumerate(data_lines):
        text = decode_ascii(line, context)
        if not text.endswith("\r\n"):
            raise context.error("spectral line does not end with CR LF", line)
        parts = text[:-2].split(",")
        if len(parts) != 2:
            raise context.error("spectral line is not 'wavelength,value'", line)
        wavelength_nm[index] = parse_float(parts[0], "wavelength", context, line)
        values[index] = parse_float(parts[1], "spectral value", context, line)
    expected_nm = grid.wavelength_nm
    if not np.allclose(wavelength_nm, expected_nm, atol=1e-3):
        worst = int(np.argmax(np.abs(wavelength_nm - expected_nm)))
        raise context.error(
            f"spectral line {worst + 1} is at {wavelength_nm[worst]:g} nm, the D120 grid says "
            f"{expected_nm[worst]:g} nm",
            data_lines[worst],
        )
    return ParsedSpectrum(header, expected_nm, values)


def parse_exposure_report(fields: Sequence[str], context: ReplyContext, reply: bytes) -> float:
    """The exposure in ms from the fields of a ``D13`` reply (``Normal,250 msec``).

    Raises
    ------
    ProtocolError
        No ``<n> msec`` field (e.g. a stale reply to another command was read instead).
    """
    for text in reversed(fields):
        match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*msec\s*", text)
        if match:
            return parse_float(match.group(1), "exposure", context, reply)
    raise context.error("D13 reply names no exposure ('<n> msec')", reply)


# --------------------------------------------------------------------------------- the driver


class Pr6xx(ClosesOnExit):
    """A PR-655 or PR-670 in remote mode; implements :class:`drivers.base.Spectrometer`.

    Build it with :func:`open_pr6xx` (or :func:`drivers.spectrometer.open_spectrometer`), which opens
    the port and calls :meth:`connect`. Not thread-safe.

    Parameters
    ----------
    transport
        The byte link to the instrument.
    model
        ``"PR-655"`` or ``"PR-670"``; the instrument must say the same in ``D111``.
    timeout_s
        Deadline of each command other than a measurement; ``None``: :data:`DEFAULT_TIMEOUT_S`.
    measure_timeout_s
        Deadline of a whole measurement, spectral reply included; ``None``:
        :data:`DEFAULT_MEASURE_TIMEOUT_S`.
    port
        Where the instrument is connected (reported in its identity).
    """

    def __init__(
        self,
        transport: ByteTransport,
        *,
        model: str,
        timeout_s: float | None = None,
        measure_timeout_s: float | None = None,
        port: str | None = None,
    ) -> None:
        if model not in MODELS:
            raise ValueError(f"unknown Photo Research model {model!r}; known: {sorted(MODELS)}")
        self._transport = transport
        self.model = model
        self.port = port
        self.limits = MODELS[model]
        self.timeout_s = DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s
        self.measure_timeout_s = (
            DEFAULT_MEASURE_TIMEOUT_S if measure_timeout_s is None else measure_timeout_s
        )
        self.averages = 1
        self._remote = False
        self._identity: DeviceIdentity | None = None
        self._grid: SpectralGrid | None = None

    @property
    def device(self) -> str:
        return self._transport.device

    # ------------------------------------------------------------------------------ exchanges

    def _context(self, command: bytes | str) -> ReplyContext:
        return ReplyContext(self.device, command)

    def _ask_line(self, command: str, deadline: Deadline) -> bytes:
        return ask(
            self._transport,
            command.encode("ascii") + COMMAND_TERMINATOR,
            terminator=REPLY_TERMINATOR,
            deadline=deadline,
        )

    def _query(self, command: str) -> list[str]:
        """Send ``command`` and return the data fields of its (OK) one-line reply."""
        line = self._ask_line(command, Deadline(self.timeout_s))
        return parse_status_reply(line, self._context(command))

    # ------------------------------------------------------------------------------ session

    def connect(self) -> None:
        """Enter remote mode, read the identity and the spectral grid, check the model.

        Raises
        ------
        DeviceNotFound
            The instrument on the port is a different model.
        """
        self.enter_remote_mode()
        identity = self.identify()
        if identity.model != self.model:
            raise DeviceNotFound(
                self.device,
                f"the instrument on this port reports model {identity.model!r}, the config says "
                f"{self.model!r}; fix the spectrometer model in the config",
            )
        self.spectral_grid()

    def enter_remote_mode(self) -> None:
        """Send ``PHOTO`` and wait for ``REMOTE MODE``."""
        reply = ask(
            self._transport,
            REMOTE_MODE_COMMAND,
            terminator=REPLY_TERMINATOR,
            deadline=Deadline(self.timeout_s),
        )
        if REMOTE_MODE_REPLY not in reply:
            raise self._context(REMOTE_MODE_COMMAND).error(
                "the instrument did not confirm remote mode", reply
            )
        self._remote = True

    def identify(self) -> DeviceIdentity:
        """Serial number (``D110``), model (``D111``) and firmware (``D114``); cached."""
        if self._identity is None:
            serial = ",".join(self._query("D110")).strip()
            model = ",".join(self._query("D111")).strip()
            firmware = ",".join(self._query("D114")).strip()
            self._identity = DeviceIdentity(
                kind="spectrometer", model=model, serial=serial, firmware=firmware, port=self.port
            )
        return self._identity

    def spectral_grid(self) -> SpectralGrid:
        """The wavelength grid from ``D120``; cached."""
        if self._grid is None:
            line = self._ask_line("D120", Deadline(self.timeout_s))
            context = self._context("D120")
            self._grid = parse_grid(parse_status_reply(line, context), context, line)
        return self._grid

    # ------------------------------------------------------------------------------ settings

    def set_exposure(self, exposure_ms: float | None) -> None:
        """Fixed integration time in ms (rounded to whole ms), or ``None`` for adaptive (``SE0``).

        Raises
        ------
        ValueError
            Outside the model's range.
        InstrumentError
            The instrument refused the value (code -1010).
        """
        if exposure_ms is None:
            setting = 0
        else:
            setting = round(exposure_ms)
            low, high = self.limits.exposure_range_ms
            if not low <= setting <= high:
                raise ValueError(
                    f"{self.model} exposure must be {low}–{high} ms (or None for adaptive), "
                    f"got {exposure_ms!r} ms"
                )
        self._query(f"SE{setting}")

    def set_averages(self, count: int) -> None:
        """Number of measurement cycles the instrument averages (``SN``, 1–99)."""
        if not 1 <= count <= 99:
            raise ValueError(f"{self.model} averages 1–99 cycles, got {count}")
        self._query(f"SN{count}")
        self.averages = count

    # ------------------------------------------------------------------------------ measuring

    def _read_spectrum(self, command: str) -> ParsedSpectrum:
        grid = self.spectral_grid()
        deadline = Deadline(self.measure_timeout_s if command.startswith("M") else self.timeout_s)
        header = self._ask_line(command, deadline)
        context = self._context(command)
        # An error status comes alone, without data lines: check it before waiting for them.
        raise_for_status(parse_reply_line(header, context)[0], context)
        lines = [
            self._transport.read_until(REPLY_TERMINATOR, deadline=deadline)
            for _ in range(grid.points)
        ]
        return parse_spectrum(header, lines, grid, context)

    def _reading(self, spectrum: ParsedSpectrum, command: str) -> SpectrumReading:
        exposure_ms = self.last_exposure_ms()
        header = spectrum.header
        return SpectrumReading(
            wavelength_nm=spectrum.wavelength_nm,
            values=spectrum.values,
            units=SPECTRAL_UNITS,
            exposure_ms=exposure_ms,
            bandwidth_nm=BANDWIDTH_NM.get(self.model),
            extra={
                "command": command,
                "units_code": header.units_code,
                "peak_wavelength_nm": f"{header.peak_wavelength_nm:g}",
                "integrated_radiance": f"{header.integrated_radiance:g}",
                "averages": str(self.averages),
            },
        )

    def measure(self) -> SpectrumReading:
        """Measure (``M5``) and return the spectrum, with the exposure used (``D13``).

        Raises
        ------
        MeasurementConditionError
            Unstable light or sync trouble (retryable).
        InstrumentError
            Too dark, overload and other instrument errors.
        DeviceTimeout
            No complete reply within ``measure_timeout_s``.
        """
        return self._reading(self._read_spectrum("M5"), "M5")

    def last_spectrum(self) -> SpectrumReading:
        """The last measurement's spectrum again (``D5``), without measuring."""
        return self._reading(self._read_spectrum("D5"), "D5")

    def last_exposure_ms(self) -> float:
        """The integration time the last measurement used (``D13``), ms."""
        line = self._ask_line("D13", Deadline(self.timeout_s))
        context = self._context("D13")
        return parse_exposure_report(parse_status_reply(line, context), context, line)

    # ------------------------------------------------------------------------------ closing

    def close(self) -> None:
        """Leave remote mode (``Q``) and close the port; never raises for a device that is gone."""
        farewell = self._leave_remote_mode if self._remote else None
        self._remote = False
        farewell_then_close(self.device, farewell, self._transport)

    def _leave_remote_mode(self) -> None:
        self._transport.discard_input()
        self._transport.write(QUIT_COMMAND)


def longest_measure_s(
    timeout_s: float | None = None, measure_timeout_s: float | None = None
) -> float:
    """The longest :meth:`Pr6xx.measure` may take: ``M5`` (the measurement allowance), then ``D13``
    (one ordinary command). Timeouts as for :class:`Pr6xx` (``None``: the defaults).
    """
    command = DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s
    allowance = DEFAULT_MEASURE_TIMEOUT_S if measure_timeout_s is None else measure_timeout_s
    return allowance + command


def open_pr6xx(
    model: str,
    port: str,
    *,
    timeout_s: float | None = None,
    measure_timeout_s: float | None = None,
    transcript: TranscriptSink | None = None,
    pacing: Pacing = DEFAULT_PACING,
    baud: int | None = None,
) -> Pr6xx:
    """Open a PR-655/PR-670 on ``port`` (path or pyserial URL), enter remote mode and identify it.

    ``baud`` overrides the line speed of :data:`SERIAL_SETTINGS` (the legacy RS-232 port); the
    timeouts are as for :class:`Pr6xx` (``None``: the defaults).

    Raises
    ------
    DeviceNotFound
        No port, or another model on it.
    DeviceTimeout
        The instrument does not answer ``PHOTO`` (off, or not in a state to accept remote mode).
    """
    if model not in MODELS:
        raise ValueError(f"unknown Photo Research model {model!r}; known: {sorted(MODELS)}")
    transport = open_serial(
        port,
        SERIAL_SETTINGS.with_baud(baud),
        device=f"{model} on {port}",
        transcript=transcript,
        pacing=pacing,
    )
    instrument = Pr6xx(
        transport,
        model=model,
        timeout_s=timeout_s,
        measure_timeout_s=measure_timeout_s,
        port=port,
    )
    return connect_or_close(instrument, instrument.connect)
