"""A pyserial port stand-in that plays a recorded serial transcript back.

The real :class:`drivers.transport.SerialTransport` and the real driver run on top of it. What the
transport writes was already checked by the transcript sink (:class:`mocks.replay.script.CheckingSink`);
the port answers with the recorded ``rx`` entries, one recorded read at a time, so replies arrive in
the pieces the driver saw. Recorded failures come back as pyserial raised them: a read that timed
out waits out its deadline and returns nothing, a write timeout raises ``SerialTimeoutException``,
a vanished port ``SerialException`` (as long after the last command as it was recorded, or when the
replay's bench closes, whichever comes first).
"""

from __future__ import annotations

import threading
import time

import serial

from mocks.replay.script import ReplayScript, Served

__all__ = ["ReplaySerialPort"]

#: After the recorded moment of a port failure (see ``_raise_recorded_failure``).
_FAILURE_MARGIN_S = 0.1
#: Past the transport's deadline, so a recorded timeout is a timeout again (and no later bytes leak).
_TIMEOUT_MARGIN_S = 0.01


class ReplaySerialPort:
    """Satisfies :class:`drivers.transport.SerialPort`; ``port`` is the recorded device path."""

    def __init__(
        self, script: ReplayScript, port: str, released: threading.Event | None = None
    ) -> None:
        self._script = script
        self._released = released or threading.Event()
        self.port: str | None = port
        self.timeout: float | None = 0.0
        self.write_timeout: float | None = None
        self._buffer = bytearray()

    def _recorded_event(self, prefix: bytes) -> Served | None:
        """Take the next entry if it is an event starting with ``prefix``."""
        served = self._script.peek()
        if (
            served is not None
            and served.entry.direction == "event"
            and served.entry.payload.startswith(prefix)
        ):
            self._script.skip()
            return served
        return None

    def _raise_recorded_failure(self, action: str) -> None:
        served = self._recorded_event(f"disconnected during {action}".encode())
        if served is not None:
            # The port fails as long after the last command as it did then (a read that hung
            # until the rig gave up and the device was closed), unless the bench closes first.
            # The margin keeps the order of a failure that followed the runner's own deadline:
            # the runner notices a deadline up to one wait slice (50 ms) late.
            self._released.wait(self._script.wait_before(served) + _FAILURE_MARGIN_S)
            raise serial.SerialException(f"replayed: the port failed during {action}")

    def _refill(self) -> bool:
        """Move the next recorded reply into the buffer; ``True`` when a recorded timeout is next."""
        while not self._buffer:
            served = self._script.peek()
            if served is None:
                return False
            if served.entry.direction == "rx":
                self._buffer.extend(self._script.take("a reply").entry.payload)
                return False
            if served.entry.direction == "event" and served.entry.payload.startswith(b"timeout"):
                return True
            if served.entry.direction == "event" and served.entry.payload.startswith(
                b"disconnected"
            ):
                return False
            self._script.skip()
        return False

    @property
    def in_waiting(self) -> int:
        self._raise_recorded_failure("read")
        self._refill()
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        self._raise_recorded_failure("read")
        timed_out = self._refill()
        if self._buffer:
            chunk = bytes(self._buffer[:size])
            del self._buffer[:size]
            return chunk
        if timed_out:
            self._script.skip()
            time.sleep((self.timeout or 0.0) + _TIMEOUT_MARGIN_S)
            return b""
        raise self._script.fail("the rig waits for a reply the recording does not have", index=None)

    def write(self, data: bytes, /) -> int:
        if self._recorded_event(b"write timeout"):
            raise serial.SerialTimeoutException("replayed: write timeout")
        self._raise_recorded_failure("write")
        return len(data)

    def flush(self) -> None:
        """Nothing to flush."""

    def reset_input_buffer(self) -> None:
        self._raise_recorded_failure("input flush")
        self._buffer.clear()

    def close(self) -> None:
        """Nothing to release."""
