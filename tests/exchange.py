"""Exact-exchange testing of byte-protocol drivers, after PyMeasure's ``expected_protocol``.

A test lists the conversation as ``(bytes the driver must send, bytes the device answers)`` pairs
and runs the real driver on a :class:`ScriptedTransport` (a :class:`drivers.transport.ByteTransport`).
The test fails on

- any write that differs from the next scripted one, or a write when the script is used up;
- a write while scripted reply bytes are still unread, or a driver discarding unread reply bytes;
- script lines left unused, or reply bytes left unread, when the ``with`` block ends.

``(sent, None)`` scripts a command the device does not answer; a read then raises
:class:`drivers.transport.ReplyTimeout` at once (no wall time passes). ``(None, reply)`` scripts
bytes the device sends unprompted (the CS-2000's completion line): they are delivered when the
driver reads and the earlier replies are used up. A reply without its terminator scripts a truncated
answer.

Examples
--------
>>> with expected_exchange([(b"D111\\r", b"00000,PR-655\\r\\n")]) as link:  # doctest: +SKIP
...     assert Pr6xx(link, model="PR-655")._query("D111") == ["PR-655"]
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from drivers.base import Disconnected
from drivers.transport import DEFAULT_MAX_REPLY_BYTES, Deadline, ReplyTimeout

Exchange = tuple[bytes | None, bytes | None]


class ScriptedTransport:
    """A byte transport that plays a scripted device and checks every byte the driver sends."""

    def __init__(self, script: Sequence[Exchange], device: str = "scripted device") -> None:
        for index, (sent, reply) in enumerate(script):
            if sent is None and reply is None:
                raise ValueError(f"script line {index} has neither a command nor a reply")
        self.script = list(script)
        self._device = device
        self._next = 0
        self._unread = bytearray()
        self._last_write: bytes | None = None
        self.closed = False

    @property
    def device(self) -> str:
        return self._device

    def _where(self) -> str:
        return f"after script line {self._next - 1}" if self._next else "at the start"

    def write(self, data: bytes) -> None:
        if self.closed:
            raise Disconnected(self._device, "scripted transport is closed")
        if self._unread:
            raise AssertionError(
                f"driver wrote {data!r} {self._where()} while the reply {bytes(self._unread)!r} "
                "was still unread"
            )
        if self._next >= len(self.script):
            raise AssertionError(f"driver wrote {data!r} but the script is used up")
        sent, reply = self.script[self._next]
        if sent is None:
            raise AssertionError(
                f"driver wrote {data!r} but script line {self._next} has the device send "
                f"{reply!r} unprompted first"
            )
        if data != sent:
            raise AssertionError(
                f"script line {self._next}: expected {sent!r}, driver wrote {data!r}"
            )
        self._next += 1
        self._last_write = data
        if reply:
            self._unread.extend(reply)

    def _pull_unprompted(self) -> bool:
        if self._next < len(self.script) and self.script[self._next][0] is None:
            self._unread.extend(self.script[self._next][1] or b"")
            self._next += 1
            return True
        return False

    def _timeout(self, waiting_for: str, deadline: Deadline) -> ReplyTimeout:
        partial = bytes(self._unread)
        self._unread.clear()
        return ReplyTimeout(
            self._device,
            f"no complete reply (scripted, waiting for {waiting_for})",
            command=self._last_write,
            timeout_s=deadline.timeout_s,
            received=partial,
        )

    def read_until(
        self, terminator: bytes, *, deadline: Deadline, max_bytes: int = DEFAULT_MAX_REPLY_BYTES
    ) -> bytes:
        if self.closed:
            raise Disconnected(self._device, "scripted transport is closed")
        while terminator not in self._unread:
            if not self._pull_unprompted():
                raise self._timeout(repr(terminator), deadline)
        end = self._unread.index(terminator) + len(terminator)
        reply = bytes(self._unread[:end])
        del self._unread[:end]
        return reply

    def read_exact(self, size: int, *, deadline: Deadline) -> bytes:
        if self.closed:
            raise Disconnected(self._device, "scripted transport is closed")
        while len(self._unread) < size:
            if not self._pull_unprompted():
                raise self._timeout(f"{size} bytes", deadline)
        reply = bytes(self._unread[:size])
        del self._unread[:size]
        return reply

    def discard_input(self) -> bytes:
        if self._unread:
            raise AssertionError(
                f"driver discarded the unread reply {bytes(self._unread)!r} {self._where()}"
            )
        return b""

    def close(self) -> None:
        self.closed = True

    def check_complete(self) -> None:
        """Fail if script lines are unused or reply bytes unread."""
        if self._next < len(self.script):
            raise AssertionError(
                f"script lines {self._next}..{len(self.script) - 1} were never used, "
                f"next: {self.script[self._next]!r}"
            )
        if self._unread:
            raise AssertionError(f"the reply {bytes(self._unread)!r} was never read")


@contextmanager
def expected_exchange(
    script: Sequence[Exchange], device: str = "scripted device"
) -> Iterator[ScriptedTransport]:
    """A :class:`ScriptedTransport` whose script must be used completely by the end of the block."""
    transport = ScriptedTransport(script, device)
    yield transport
    transport.check_complete()
