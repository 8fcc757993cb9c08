"""The byte transport every serial driver talks through, and its pyserial implementation.

Drivers depend on the small :class:`ByteTransport` protocol, never on pyserial: a scripted fake (the
exact-exchange tests), the pyserial port (:class:`SerialTransport`) and, later, a replay of a recorded
transcript all satisfy it. The rules it enforces are the lessons of the pyserial issue tracker:

- every read has an explicit total deadline (:class:`Deadline`), and a reply that is not complete by
  then raises :class:`ReplyTimeout` carrying the bytes that did arrive: a short read never returns
  partial data silently;
- writes have a deadline too (a device holding CTS low must not hang the rig);
- ``SerialException`` / ``OSError`` become :class:`drivers.base.Disconnected`, a port that cannot be
  opened becomes :class:`drivers.base.DeviceNotFound` (or :class:`drivers.base.DeviceBusy` when another
  program holds it);
- every exchange is written to a :class:`drivers.base.TranscriptSink`: ``tx`` (one entry per command,
  whatever the pacing), ``rx`` (one entry per completed read, and the partial bytes of a read that
  timed out), ``event`` (open, close, discarded stale input, timeouts) with :func:`time.monotonic`.
"""

from __future__ import annotations

import dataclasses
import errno
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from drivers.base import (
    DeviceBusy,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    ProtocolError,
    TranscriptDirection,
    TranscriptEntry,
    TranscriptSink,
)
from drivers.libraries import pyserial
from drivers.lifecycle import ClosesOnExit

try:
    import termios
except ImportError:  # Windows
    _OS_PORT_ERRORS: tuple[type[BaseException], ...] = (OSError,)
else:
    # pyserial lets termios.error (not an OSError) escape from flush() on a vanished device.
    _OS_PORT_ERRORS = (OSError, termios.error)


def _port_errors() -> tuple[type[BaseException], ...]:
    """What a failing port raises (pyserial is imported by then: a transport has a port)."""
    return (pyserial().SerialException, *_OS_PORT_ERRORS)


#: A reply longer than this without its terminator is treated as garbage, not waited on.
DEFAULT_MAX_REPLY_BYTES = 1 << 16

#: How long a write may block (flow control held off, USB stalled) before it is a timeout.
DEFAULT_WRITE_TIMEOUT_S = 2.0


class Deadline:
    """A point in monotonic time by which a reply must be complete.

    One deadline can span several reads (a multi-line reply), so the total wait is bounded no matter
    how the bytes trickle in.

    Parameters
    ----------
    timeout_s
        Seconds from now; must be finite and >= 0.
    clock
        Monotonic time source in seconds (tests may inject one).
    """

    def __init__(self, timeout_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        if not timeout_s >= 0 or timeout_s == float("inf"):
            raise ValueError(f"a deadline needs a finite timeout >= 0 s, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self._clock = clock
        self._expires_at = clock() + self.timeout_s

    def remaining_s(self) -> float:
        """Seconds left (0 once expired)."""
        return max(0.0, self._expires_at - self._clock())

    def expired(self) -> bool:
        return self.remaining_s() <= 0.0


class ReplyTimeout(DeviceTimeout):
    """No complete reply before the deadline; ``received`` holds whatever bytes did arrive."""

    def __init__(
        self,
        device: str,
        message: str,
        *,
        command: bytes | str | None,
        timeout_s: float,
        received: bytes,
    ) -> None:
        self.received = received
        detail = (
            f"; received {received!r} before the deadline" if received else "; nothing received"
        )
        super().__init__(device, message + detail, command=command, timeout_s=timeout_s)


@runtime_checkable
class ByteTransport(Protocol):
    """What a byte-stream driver needs from its link to the instrument.

    Implementations: :class:`SerialTransport` (pyserial), the scripted fake in ``tests/exchange.py``,
    and the replay transport. All reads return complete replies or raise.
    """

    @property
    def device(self) -> str:
        """Who is on the other end, for error messages: ``"PR-655 on /dev/ttyACM0"``."""

    def write(self, data: bytes) -> None:
        """Send one command (the transport applies any character pacing)."""

    def read_until(
        self, terminator: bytes, *, deadline: Deadline, max_bytes: int = DEFAULT_MAX_REPLY_BYTES
    ) -> bytes:
        """Bytes up to and including ``terminator``; :class:`ReplyTimeout` if it does not arrive."""

    def read_exact(self, size: int, *, deadline: Deadline) -> bytes:
        """Exactly ``size`` bytes; :class:`ReplyTimeout` if fewer arrive."""

    def discard_input(self) -> bytes:
        """Drop stale input (late replies of an earlier command); return what was dropped."""

    def close(self) -> None:
        """Release the link; idempotent."""


class SerialPort(Protocol):
    """The part of a pyserial port object the transport uses (``serial.Serial`` and the URL
    handlers' classes all have it)."""

    port: str | None
    timeout: float | None
    write_timeout: float | None

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes, /) -> int | None: ...

    def flush(self) -> None: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class SerialSettings:
    """Line settings passed to pyserial (ignored by USB CDC devices and ptys, honoured by RS-232)."""

    baudrate: int = 9600
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1
    rtscts: bool = False
    xonxoff: bool = False
    write_timeout_s: float = DEFAULT_WRITE_TIMEOUT_S
    exclusive: bool = True

    def with_baud(self, baudrate: int | None) -> SerialSettings:
        """These settings at another line speed (``None``: unchanged)."""
        if baudrate is None:
            return self
        if baudrate <= 0:
            raise ValueError(f"baud rate must be positive, got {baudrate}")
        return dataclasses.replace(self, baudrate=baudrate)

    def describe(self) -> str:
        flow = "rtscts" if self.rtscts else "xonxoff" if self.xonxoff else "no flow control"
        stop = int(self.stopbits) if float(self.stopbits).is_integer() else self.stopbits
        return f"{self.baudrate} {self.bytesize}{self.parity}{stop} {flow}"


@dataclass(frozen=True)
class Pacing:
    """Write pacing for instruments whose input buffer cannot take a whole command at once.

    Parameters
    ----------
    char_delay_s
        Pause after each character (the command is written one byte at a time, flushed each time).
    command_gap_s
        Minimum time between the end of one command and the start of the next.
    """

    char_delay_s: float = 0.0
    command_gap_s: float = 0.0

    def __post_init__(self) -> None:
        if self.char_delay_s < 0 or self.command_gap_s < 0:
            raise ValueError(f"pacing delays must be >= 0 s, got {self}")


NO_PACING = Pacing()


class SerialTransport(ClosesOnExit):
    """A :class:`ByteTransport` over an open pyserial port.

    Use :func:`open_serial` to open one by path or URL. Not thread-safe: one driver, one thread.

    Parameters
    ----------
    port
        An open pyserial port (``serial.Serial``, or any ``serial_for_url`` object; see
        :class:`SerialPort`).
    device
        Label for errors and transcript entries.
    transcript
        Where exchanges are recorded; ``None`` records nothing.
    pacing
        Character pacing on writes.
    clock, sleep
        Monotonic time source and sleep function (injectable for tests).
    """

    def __init__(
        self,
        port: SerialPort,
        *,
        device: str,
        transcript: TranscriptSink | None = None,
        pacing: Pacing = NO_PACING,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self._port = port
        self._device = device
        self._transcript = transcript
        self._pacing = pacing
        self._clock = clock
        self._sleep = sleep
        self._pending = bytearray()
        self._last_command: bytes | None = None
        self._last_write_end: float | None = None
        self._broken: Disconnected | None = None
        self._closed = False

    # ------------------------------------------------------------------------------ properties

    @property
    def device(self) -> str:
        return self._device

    @property
    def port_name(self) -> str:
        return str(self._port.port)

    @property
    def pacing(self) -> Pacing:
        return self._pacing

    # ------------------------------------------------------------------------------ transcript

    def _record(self, direction: TranscriptDirection, payload: bytes) -> None:
        if self._transcript is not None:
            self._transcript.record(
                TranscriptEntry(self._device, direction, payload, self._clock())
            )

    def record_event(self, text: str) -> None:
        """Write a free-text ``event`` entry (open/close/reset notes) to the transcript."""
        self._record("event", text.encode("utf-8"))

    # ---------------------------------------------------------------------------------- errors

    def _check_usable(self) -> None:
        if self._broken is not None:
            raise self._broken
        if self._closed:
            raise Disconnected(self._device, f"serial port {self.port_name} is closed")

    def _disconnected(self, action: str, exc: BaseException) -> Disconnected:
        error = Disconnected(
            self._device,
            f"serial port {self.port_name} failed during {action}: {exc}. "
            "Check the cable and power, then reopen the device.",
        )
        self._broken = error
        self.record_event(f"disconnected during {action}: {exc}")
        return error

    # ----------------------------------------------------------------------------------- write

    def write(self, data: bytes) -> None:
        """Send ``data``, paced, within the port's write timeout.

        Raises
        ------
        DeviceTimeout
            The port would not accept the bytes in time (flow control held off).
        Disconnected
            The port failed.
        """
        self._check_usable()
        if self._pacing.command_gap_s > 0 and self._last_write_end is not None:
            wait_s = self._last_write_end + self._pacing.command_gap_s - self._clock()
            if wait_s > 0:
                self._sleep(wait_s)
        self._last_command = bytes(data)
        self._record("tx", bytes(data))
        try:
            if self._pacing.char_delay_s > 0:
                for index in range(len(data)):
                    self._port.write(data[index : index + 1])
                    self._port.flush()
                    self._sleep(self._pacing.char_delay_s)
            else:
                self._port.write(data)
                self._port.flush()
        except pyserial().SerialTimeoutException as exc:
            self.record_event(f"write timeout: {exc}")
            raise DeviceTimeout(
                self._device,
                f"serial port {self.port_name} did not accept {data!r} within the write timeout "
                "(flow control held off? check the RTS/CTS setting and the cable)",
                command=data,
                timeout_s=float(self._port.write_timeout or 0.0),
            ) from exc
        except _port_errors() as exc:
            raise self._disconnected("write", exc) from exc
        finally:
            self._last_write_end = self._clock()

    # ------------------------------------------------------------------------------------ read

    def _fill(self, wait_s: float) -> None:
        """Block up to ``wait_s`` for at least one byte and append what is there to the buffer."""
        try:
            self._port.timeout = wait_s
            chunk = self._port.read(max(1, self._port.in_waiting))
        except _port_errors() as exc:
            raise self._disconnected("read", exc) from exc
        self._pending.extend(chunk)

    def _timeout(self, waiting_for: str, deadline: Deadline) -> ReplyTimeout:
        partial = bytes(self._pending)
        self._pending.clear()
        if partial:
            self._record("rx", partial)
        self.record_event(f"timeout after {deadline.timeout_s:g} s waiting for {waiting_for}")
        return ReplyTimeout(
            self._device,
            f"no complete reply within {deadline.timeout_s:g} s (waiting for {waiting_for})",
            command=self._last_command,
            timeout_s=deadline.timeout_s,
            received=partial,
        )

    def read_until(
        self, terminator: bytes, *, deadline: Deadline, max_bytes: int = DEFAULT_MAX_REPLY_BYTES
    ) -> bytes:
        """Read up to and including ``terminator``.

        Raises
        ------
        ReplyTimeout
            The terminator did not arrive before ``deadline``; the partial bytes are in the error.
        ProtocolError
            More than ``max_bytes`` arrived without the terminator.
        Disconnected
            The port failed.
        """
        if not terminator:
            raise ValueError("read_until needs a non-empty terminator")
        self._check_usable()
        while True:
            index = self._pending.find(terminator)
            if index >= 0:
                end = index + len(terminator)
                reply = bytes(self._pending[:end])
                del self._pending[:end]
                self._record("rx", reply)
                return reply
            if len(self._pending) > max_bytes:
                garbage = bytes(self._pending)
                self._pending.clear()
                self._record("rx", garbage)
                raise ProtocolError(
                    self._device,
                    f"reply exceeds {max_bytes} bytes without its terminator {terminator!r}",
                    command=self._last_command,
                    reply=garbage[:200],
                )
            remaining_s = deadline.remaining_s()
            if remaining_s <= 0:
                raise self._timeout(repr(terminator), deadline)
            self._fill(remaining_s)

    def read_exact(self, size: int, *, deadline: Deadline) -> bytes:
        """Read exactly ``size`` bytes (binary replies).

        Raises
        ------
        ReplyTimeout
            Fewer than ``size`` bytes arrived before ``deadline``.
        Disconnected
            The port failed.
        """
        if size < 0:
            raise ValueError(f"cannot read {size} bytes")
        self._check_usable()
        while len(self._pending) < size:
            remaining_s = deadline.remaining_s()
            if remaining_s <= 0:
                raise self._timeout(f"{size} bytes", deadline)
            self._fill(remaining_s)
        reply = bytes(self._pending[:size])
        del self._pending[:size]
        self._record("rx", reply)
        return reply

    def discard_input(self) -> bytes:
        """Drop buffered and waiting input; the dropped bytes go to the transcript."""
        self._check_usable()
        stale = bytes(self._pending)
        self._pending.clear()
        try:
            waiting = self._port.in_waiting
            if waiting:
                self._port.timeout = 0
                stale += self._port.read(waiting)
            self._port.reset_input_buffer()
        except _port_errors() as exc:
            raise self._disconnected("input flush", exc) from exc
        if stale:
            self._record("rx", stale)
            self.record_event(f"discarded {len(stale)} stale input bytes")
        return stale

    # ----------------------------------------------------------------------------------- close

    def close(self) -> None:
        """Close the port (idempotent; never raises for a port that is already gone)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._port.close()
        except _port_errors() as exc:
            self.record_event(f"close failed: {exc}")
        self.record_event(f"closed {self.port_name}")


_NOT_FOUND_ERRNOS = {errno.ENOENT, errno.ENODEV, errno.ENXIO}
_PERMISSION_ERRNOS = {errno.EACCES, errno.EPERM}
_IN_USE_ERRNOS = {errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY}


def _open_error(device: str, port: str, exc: BaseException) -> Exception:
    code = getattr(exc, "errno", None)
    if code in _PERMISSION_ERRNOS:
        return DeviceNotFound(
            device,
            f"no permission to open serial port {port!r} ({exc}); on Linux add the user to the "
            "'dialout' group (or install a udev rule) and log in again",
        )
    if code in _IN_USE_ERRNOS:
        return DeviceBusy(
            device, f"serial port {port!r} is in use by another program ({exc}); close it and retry"
        )
    hint = "check the cable and the port in the config; `rig devices` lists the ports present"
    if code in _NOT_FOUND_ERRNOS:
        return DeviceNotFound(device, f"serial port {port!r} does not exist; {hint}")
    return DeviceNotFound(device, f"cannot open serial port {port!r}: {exc}; {hint}")


def open_serial(
    port: str,
    settings: SerialSettings,
    *,
    device: str,
    transcript: TranscriptSink | None = None,
    pacing: Pacing = NO_PACING,
) -> SerialTransport:
    """Open ``port`` (a device path such as ``/dev/ttyACM0`` or a pyserial URL such as
    ``loop://``, ``socket://host:port`` or ``spy:///dev/ttyUSB0``) with explicit settings.

    Raises
    ------
    DeviceNotFound
        The port does not exist, or may not be opened (permissions, bad URL).
    DeviceBusy
        Another program holds the port.
    """
    serial = pyserial()
    try:
        handle = serial.serial_for_url(
            port,
            do_not_open=True,
            baudrate=settings.baudrate,
            bytesize=settings.bytesize,
            parity=settings.parity,
            stopbits=settings.stopbits,
            rtscts=settings.rtscts,
            xonxoff=settings.xonxoff,
            timeout=0,
            write_timeout=settings.write_timeout_s,
        )
        if settings.exclusive and isinstance(handle, serial.Serial):
            handle.exclusive = True
        handle.open()
    except (serial.SerialException, OSError, ValueError) as exc:
        raise _open_error(device, port, exc) from exc
    transport = SerialTransport(handle, device=device, transcript=transcript, pacing=pacing)
    transport.record_event(
        f"opened {port} ({settings.describe()}, pacing {pacing.char_delay_s:g} s/char, "
        f"{pacing.command_gap_s:g} s between commands)"
    )
    return transport


def ask(
    transport: ByteTransport, command: bytes, *, terminator: bytes, deadline: Deadline
) -> bytes:
    """Drop stale input, send ``command`` and return the reply up to and including ``terminator``.

    Stale bytes (a late reply to an earlier command that timed out) are dropped first so they cannot
    be taken for this command's reply; the transport records them in the transcript.
    """
    transport.discard_input()
    transport.write(command)
    return transport.read_until(terminator, deadline=deadline)
