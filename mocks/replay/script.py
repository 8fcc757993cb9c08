"""A device's recorded transcript as a script: what the rig must send, and what to answer.

Replay runs the real drivers against stand-ins of the layer below them (a pyserial port, a pyusb
backend, the ``gphoto2`` module). Every driver already writes each exchange to a transcript sink
*before* it goes to the device, so the check sits in the sink (:class:`CheckingSink`): each entry
the driver sends (``tx`` bytes, a libgphoto2 ``call``) must equal the next one the recording sent,
or the replay stops with :class:`ReplayMismatch`. The stand-ins then serve what the recording
received after it (``rx`` bytes, a ``return`` or ``error``), through :meth:`ReplayScript.take`.

``event`` entries are notes (ports opened, stale bytes dropped): they are neither sent nor
answered, and only a serial timeout among them is served (as silence).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drivers.base import DeviceError, TranscriptEntry, TranscriptSink

__all__ = [
    "INCOMING",
    "OUTGOING",
    "CheckingSink",
    "Mismatches",
    "ReplayMismatch",
    "ReplayScript",
    "comparable",
]

OUTGOING = ("tx", "call")
"""Directions the rig sends: checked against the recording."""
INCOMING = ("rx", "return", "error")
"""Directions the device answers: served from the recording."""


class ReplayMismatch(DeviceError):
    """The rig sent something other than the recording did (or less, or more).

    Attributes
    ----------
    role
        The device role (``relays``, ``spectrometer``, ``camera``).
    index
        Line of the recorded transcript (from 1) the rig was expected to send, or ``None`` when
        the recording has nothing more.
    expected, sent
        The recorded entry and the entry the rig produced (``None`` when there is none).
    """

    reason = "replay_mismatch"
    retryable = False

    def __init__(
        self,
        role: str,
        problem: str,
        *,
        index: int | None,
        expected: TranscriptEntry | None,
        sent: TranscriptEntry | None,
    ) -> None:
        self.role = role
        self.problem = problem
        self.index = index
        self.expected = expected
        self.sent = sent
        where = (
            f"transcripts/{role}.jsonl line {index}" if index is not None else "end of recording"
        )
        super().__init__(
            f"replay of {role}",
            f"{problem} at {where}: expected {self.describe(expected)}; sent {self.describe(sent)}",
        )

    @staticmethod
    def describe(entry: TranscriptEntry | None) -> str:
        """An entry as a person reads it: ``tx 44 31 31 30 0d  b'D110\\r'`` or ``call {...}``."""
        if entry is None:
            return "nothing"
        if entry.direction in ("tx", "rx"):
            return f"{entry.direction} {entry.payload.hex(' ')}  {entry.payload!r}"
        return f"{entry.direction} {entry.payload.decode('utf-8', errors='replace')}"


class Mismatches:
    """The mismatches of one replay, in the order they happened (the first is the one to show).

    Drivers sometimes swallow device errors (a probe that moves on, a close that must not fail), so
    the scripts keep every mismatch here as well as raising it.
    """

    def __init__(self) -> None:
        self.found: list[ReplayMismatch] = []
        self.context: Callable[[], str] = lambda: "(unknown step)"
        """Says where the run is (the rig sets it to give the current step's key)."""
        self._where: list[str] = []
        self._lock = threading.Lock()

    def add(self, mismatch: ReplayMismatch) -> ReplayMismatch:
        where = self.context()
        with self._lock:
            self.found.append(mismatch)
            self._where.append(where)
        return mismatch

    def where(self, mismatch: ReplayMismatch) -> str:
        """What :attr:`context` said when ``mismatch`` was found."""
        with self._lock:
            return next(w for m, w in zip(self.found, self._where, strict=True) if m is mismatch)

    @property
    def first(self) -> ReplayMismatch | None:
        with self._lock:
            return self.found[0] if self.found else None


def comparable(entry: TranscriptEntry) -> object:
    """What must be equal between a recorded and a sent entry.

    Bytes compare as bytes. A libgphoto2 call compares by name and arguments, with opaque handles
    (``{"type": …}``, a port-info ``{"widget": …}``) compared only as handles: they carry no data
    the camera sees, and their class names differ between python-gphoto2 and stand-ins.
    """
    if entry.direction == "tx":
        return entry.payload
    try:
        body = json.loads(entry.payload)
    except ValueError:
        return entry.payload
    return _without_handles(body)


def _without_handles(value: object) -> object:
    if isinstance(value, dict):
        if set(value) in ({"type"}, {"widget"}):
            return "<handle>"
        return {key: _without_handles(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_without_handles(item) for item in value]
    return value


@dataclass(frozen=True)
class Served:
    """A recorded answer handed to a stand-in: the entry and its transcript line (from 1)."""

    entry: TranscriptEntry
    line: int


class ReplayScript:
    """The recorded exchanges of one device, consumed in order. Thread-safe.

    Parameters
    ----------
    role
        Device role, for messages.
    entries
        The recorded transcript, in order.
    mismatches
        Where every mismatch is also kept (shared by the devices of one replay).
    """

    def __init__(
        self, role: str, entries: Sequence[TranscriptEntry], mismatches: Mismatches
    ) -> None:
        self.role = role
        self.entries = list(entries)
        self.mismatches = mismatches
        self._next = 0
        self._last_sent: TranscriptEntry | None = None
        self._sent_index: int | None = None
        self._sent_at: float | None = None
        self._lock = threading.RLock()

    # ----------------------------------------------------------------------------- sending

    def fail(
        self,
        problem: str,
        *,
        index: int | None,
        expected: TranscriptEntry | None = None,
        sent: TranscriptEntry | None = None,
    ) -> ReplayMismatch:
        """Record a mismatch and return it (to raise)."""
        return self.mismatches.add(
            ReplayMismatch(self.role, problem, index=index, expected=expected, sent=sent)
        )

    def expect(self, sent: TranscriptEntry) -> None:
        """Check an entry the rig sends against the next one the recording sent.

        Raises
        ------
        ReplayMismatch
            A different command, or one more than the recording has, or recorded answers to the
            previous command left unread.
        """
        with self._lock:
            unread = self._next_incoming()
            if unread is not None:
                raise self.fail(
                    "a recorded answer was not read before the next command",
                    index=unread.line,
                    expected=unread.entry,
                    sent=sent,
                )
            index = self._find(self._next, OUTGOING)
            if index is None:
                raise self.fail("the rig sent more than the recording has", index=None, sent=sent)
            expected = self.entries[index]
            if expected.direction != sent.direction or comparable(expected) != comparable(sent):
                raise self.fail(
                    "the rig sent a different command",
                    index=index + 1,
                    expected=expected,
                    sent=sent,
                )
            self._next = index + 1
            self._last_sent = sent
            self._sent_index = index
            self._sent_at = time.monotonic()

    # ----------------------------------------------------------------------------- answering

    def peek(self) -> Served | None:
        """The next recorded answer or event before the next command, without taking it."""
        with self._lock:
            if (
                self._next < len(self.entries)
                and self.entries[self._next].direction not in OUTGOING
            ):
                return Served(self.entries[self._next], self._next + 1)
            return None

    def peek_answer(self) -> Served | None:
        """:meth:`peek`, the events before it passed over (they are notes, never answers)."""
        with self._lock:
            served = self.peek()
            while served is not None and served.entry.direction == "event":
                self.skip()
                served = self.peek()
            return served

    def wait_before(self, served: Served) -> float:
        """Seconds to wait now so that ``served`` comes as long after the last command as recorded.

        Recorded times are the transcript's monotonic timestamps; the replay's own send time of
        that command is the reference (0 when nothing was sent yet).
        """
        with self._lock:
            if self._sent_at is None or self._sent_index is None:
                return 0.0
            recorded_s = served.entry.monotonic_s - self.entries[self._sent_index].monotonic_s
            if not math.isfinite(recorded_s):
                return 0.0
            return max(0.0, self._sent_at + recorded_s - time.monotonic())

    def skip(self) -> None:
        """Pass over the entry :meth:`peek` returned."""
        with self._lock:
            self._next += 1

    def take(self, what: str) -> Served:
        """The next recorded answer (``rx``/``return``/``error``) to the last command, events skipped.

        Raises
        ------
        ReplayMismatch
            The recording has no answer there: the rig waits for one the device never gave.
        """
        with self._lock:
            answer = self._next_incoming()
            if answer is None:
                at = self._find(self._next, OUTGOING)
                raise self.fail(
                    f"the rig expects {what}, the recording has none",
                    index=None if at is None else at + 1,
                    expected=None if at is None else self.entries[at],
                    sent=self._last_sent,
                )
            self._next = answer.line
            return answer

    def finish(self) -> ReplayMismatch | None:
        """After the run: every recorded command must have been sent and every answer read.

        Returns the mismatch (also kept in the shared :class:`Mismatches`) for the first recorded
        entry left unused, or ``None``.
        """
        with self._lock:
            index = self._find(self._next, OUTGOING + INCOMING)
            if index is None:
                return None
            entry = self.entries[index]
            problem = (
                "a recorded command was never sent"
                if entry.direction in OUTGOING
                else "a recorded answer was never read"
            )
            return self.fail(problem, index=index + 1, expected=entry)

    # ----------------------------------------------------------------------------- internals

    def _find(self, start: int, directions: tuple[str, ...]) -> int | None:
        for index in range(start, len(self.entries)):
            if self.entries[index].direction in directions:
                return index
        return None

    def _next_incoming(self) -> Served | None:
        """The next answer before the next command (events in between skipped), if any."""
        for index in range(self._next, len(self.entries)):
            direction = self.entries[index].direction
            if direction in OUTGOING:
                return None
            if direction in INCOMING:
                return Served(self.entries[index], index + 1)
        return None


class CheckingSink:
    """A transcript sink that writes every entry to ``inner`` and checks what the rig sends.

    The entry is written first, so the replay's own transcript shows what was actually sent.
    """

    def __init__(self, script: ReplayScript, inner: TranscriptSink | None) -> None:
        self.script = script
        self.inner = inner

    def record(self, entry: TranscriptEntry) -> None:
        if self.inner is not None:
            self.inner.record(entry)
        if entry.direction in OUTGOING:
            self.script.expect(entry)
