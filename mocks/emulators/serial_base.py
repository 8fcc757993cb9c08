"""What every serial firmware emulator shares: reply timing, fault application, line splitting.

An emulator turns each command into a list of :class:`ReplyPart` (bytes and when they go out) and
hands it to :meth:`EmulatorBase.deliver`, which applies the command's scheduled :class:`Fault` (if
any) on the way to the wire. The instrument is sequential: a reply's first part cannot leave before
the previous command's first part has (``busy_until``), so a slow measurement delays what follows it.
Later parts of a multi-part reply (the CS-2000's completion line) are asynchronous notifications.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, TypedDict

import numpy as np

from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.pty_serial import DeviceLink, ScheduledOutput


class SpectrometerOptions(TypedDict, total=False):
    """Keyword options of the spectrometer emulators' ``start_*`` functions."""

    seed: int | np.random.Generator | None
    faults: FaultSchedule | None
    time_scale: float
    symlink: str | Path | None


#: After a DISCONNECT fault's partial reply, the link drops this much later (lets the bytes land).
HANG_UP_AFTER_PARTIAL_S = 0.05


@dataclass(frozen=True)
class ReplyPart:
    """Bytes the device sends ``at_s`` seconds after it starts handling the command."""

    data: bytes
    at_s: float = 0.0


class EmulatorBase:
    """Base of the serial emulators.

    Parameters
    ----------
    name
        Label used in logs and by the harness thread name.
    faults
        Scheduled misbehaviour; kinds outside :attr:`SUPPORTED_FAULTS` are rejected here, so a test
        cannot silently schedule a fault the device has no way to show.
    time_scale
        Multiplies every modelled duration (measurement, pre-measurement); 0.01 makes a 3 s
        measurement take 30 ms, for tests and the digital twin.
    """

    SUPPORTED_FAULTS: ClassVar[frozenset[FaultKind]] = frozenset(FaultKind)
    #: Byte values a garbled reply keeps intact (line ends, prompts): the corruption is detectable
    #: as such instead of turning into a missing terminator.
    STRUCTURAL_BYTES: ClassVar[bytes] = b"\r\n"

    def __init__(
        self, name: str, *, faults: FaultSchedule | None = None, time_scale: float = 1.0
    ) -> None:
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale!r}")
        self._name = name
        self.faults = faults or FaultSchedule()
        unsupported = self.faults.kinds() - self.SUPPORTED_FAULTS
        if unsupported:
            names = ", ".join(sorted(kind.name for kind in unsupported))
            raise ValueError(
                f"the {name} emulator cannot inject {names}: its protocol has no way to show it "
                f"(supported: {', '.join(sorted(k.name for k in self.SUPPORTED_FAULTS))})"
            )
        self.time_scale = float(time_scale)
        self.commands: list[str] = []
        self._link: DeviceLink | None = None
        self._busy_until = 0.0

    @property
    def name(self) -> str:
        return self._name

    def attach(self, link: DeviceLink) -> None:
        self._link = link

    @property
    def link(self) -> DeviceLink:
        if self._link is None:
            raise RuntimeError(f"{self._name} emulator is not attached to a harness")
        return self._link

    def receive(self, data: bytes) -> None:  # pragma: no cover - every emulator overrides
        raise NotImplementedError

    def next_fault(self, label: str) -> Fault | None:
        """Log the command and ask the schedule whether it misbehaves."""
        self.commands.append(label)
        return self.faults.next_fault(label)

    def seconds(self, nominal_s: float) -> float:
        """A modelled duration in wall seconds (after :attr:`time_scale`)."""
        return nominal_s * self.time_scale

    def deliver(self, parts: Sequence[ReplyPart], fault: Fault | None) -> list[ScheduledOutput]:
        """Send ``parts`` with the transport-level effects of ``fault`` applied.

        ``ERROR_CODE`` and ``BUSY`` must already be reflected in ``parts`` (they are protocol
        replies); here they pass through unchanged. Returns the queued outputs, one per part that
        is sent (in part order), so an emulator can withdraw one that has not gone yet.
        """
        sent: list[ScheduledOutput] = []
        now = time.monotonic()
        offset_s = max(0.0, self._busy_until - now)
        if parts:
            self._busy_until = now + offset_s + parts[0].at_s
        transport_fault = (
            fault
            if fault is not None and fault.kind not in (FaultKind.ERROR_CODE, FaultKind.BUSY)
            else None
        )
        if transport_fault is not None and transport_fault.part >= len(parts):
            if transport_fault.kind is FaultKind.DISCONNECT:
                self.link.hang_up(delay_s=offset_s)
            elif transport_fault.kind is FaultKind.LATE_REPLY:
                self._busy_until += transport_fault.delay_s
            transport_fault = None
        extra_s = 0.0
        for index, part in enumerate(parts):
            at_s = offset_s + part.at_s + extra_s
            if transport_fault is None or index != transport_fault.part:
                sent.append(self.link.send(part.data, delay_s=at_s))
                continue
            kind = transport_fault.kind
            if kind is FaultKind.NO_REPLY:
                break
            if kind is FaultKind.LATE_REPLY:
                extra_s = transport_fault.delay_s
                if index == 0:
                    self._busy_until += extra_s
                sent.append(self.link.send(part.data, delay_s=at_s + extra_s))
            elif kind is FaultKind.GARBLED_REPLY:
                garbled = transport_fault.garble(
                    part.data, self.faults.rng, keep=self.STRUCTURAL_BYTES
                )
                sent.append(self.link.send(garbled, delay_s=at_s))
            elif kind is FaultKind.TRUNCATED_REPLY:
                sent.append(self.link.send(transport_fault.kept(part.data), delay_s=at_s))
                break
            elif kind is FaultKind.DISCONNECT:
                sent.append(self.link.send(transport_fault.kept(part.data), delay_s=at_s))
                self.link.hang_up(delay_s=at_s + HANG_UP_AFTER_PARTIAL_S)
                break
        return sent


class LineSplitter:
    """Splits a byte stream into command lines on CR, LF or CR LF.

    Yields ``(line, terminator)``; an LF directly after a CR (even in a later chunk) completes a
    CR LF and does not make an empty line.
    """

    def __init__(self, terminators: bytes = b"\r\n") -> None:
        self._terminators = set(terminators)
        self._buffer = bytearray()
        self._after_cr = False

    @property
    def pending(self) -> bytes:
        """Bytes received since the last complete line."""
        return bytes(self._buffer)

    def clear(self) -> None:
        self._buffer.clear()

    def feed(self, data: bytes) -> Iterator[tuple[bytes, bytes]]:
        index = 0
        while index < len(data):
            byte = data[index]
            if self._after_cr and byte == 0x0A and not self._buffer:
                self._after_cr = False
                index += 1
                continue
            self._after_cr = False
            if byte in self._terminators:
                terminator = bytes([byte])
                if byte == 0x0D and index + 1 < len(data) and data[index + 1] == 0x0A:
                    terminator = b"\r\n"
                    index += 1
                elif byte == 0x0D:
                    self._after_cr = True
                line = bytes(self._buffer)
                self._buffer.clear()
                yield line, terminator
            else:
                self._buffer.append(byte)
            index += 1


def measurement_rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    """A generator from a seed (or the generator itself); ``None`` seeds with 0 for repeatability."""
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(0 if seed is None else seed)
