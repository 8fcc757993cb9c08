"""Fault injection shared by every emulator (serial, USB, camera).

A :class:`FaultSchedule` decides, command by command, whether the emulator misbehaves and how. The
emulator names each command it handles with a short label (``"M5"``, ``"MEAS,1"``, ``"relay on 0"``,
``"status"``, ``"capture"`` …, documented by each emulator) and asks ``schedule.next_fault(label)``;
rules match labels with a regular expression anchored at the start.

Which faults mean what is generic; how they look on the wire is the emulator's business:

=================  =====================================================================================
``NO_REPLY``       the command is executed but its reply is lost (nothing is sent)
``LATE_REPLY``     the reply is sent ``delay_s`` later than it would have been
``GARBLED_REPLY``  some reply bytes are replaced by line noise (bytes >= 0x80, as framing errors give)
``TRUNCATED_REPLY`` only the first part of the reply is sent (``keep_fraction``), the rest never comes
``ERROR_CODE``     the device answers with an error code (``code``, or the emulator's default for the
                   command) instead of executing it; relays ignore the switch (a stuck contact)
``DISCONNECT``     the device goes away mid-reply: part of the reply, then the link drops
``BUSY``           the device says it is busy (where its protocol has a way to say so)
=================  =====================================================================================

Multi-part replies (the CS-2000 ``MEAS`` sends an acknowledgement and, seconds later, a completion
line) use ``part`` to pick which part the fault hits; earlier parts are sent normally.

Randomness (probabilistic rules, which bytes are garbled) comes only from the schedule's seeded
:class:`numpy.random.Generator`, so a failing run can be repeated exactly.

Examples
--------
The third ``M5`` is never answered, and every ``MEAS`` fails with probability 0.1:

>>> schedule = FaultSchedule(
...     [
...         FaultRule(Fault(FaultKind.NO_REPLY), match="M5", nth=3),
...         FaultRule(Fault(FaultKind.ERROR_CODE, code="ER10"), match="MEAS", probability=0.1),
...     ],
...     seed=7,
... )
>>> [schedule.next_fault("M5") is None for _ in range(4)]
[True, True, False, True]
"""

from __future__ import annotations

import enum
import re
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np


class FaultKind(enum.Enum):
    """The ways a device can misbehave (see the module docstring)."""

    NO_REPLY = "no_reply"
    LATE_REPLY = "late_reply"
    GARBLED_REPLY = "garbled_reply"
    TRUNCATED_REPLY = "truncated_reply"
    ERROR_CODE = "error_code"
    DISCONNECT = "disconnect"
    BUSY = "busy"


@dataclass(frozen=True)
class Fault:
    """One misbehaviour and its parameters.

    Parameters
    ----------
    kind
        What goes wrong.
    delay_s
        Extra delay for ``LATE_REPLY``.
    keep_fraction
        For ``TRUNCATED_REPLY`` and ``DISCONNECT``: the fraction of the reply sent before it stops
        (rounded down; at least one byte is withheld).
    garbled_bytes
        For ``GARBLED_REPLY``: how many bytes are replaced.
    code
        For ``ERROR_CODE``: the device's own error code (``"ER10"``, ``"-8"``); ``None`` lets the
        emulator pick its usual one for the command.
    part
        For multi-part replies: which part (0-based) is hit.
    """

    kind: FaultKind
    delay_s: float = 1.0
    keep_fraction: float = 0.5
    garbled_bytes: int = 3
    code: str | None = None
    part: int = 0

    def __post_init__(self) -> None:
        if self.delay_s < 0:
            raise ValueError(f"fault delay must be >= 0 s, got {self.delay_s}")
        if not 0.0 <= self.keep_fraction < 1.0:
            raise ValueError(f"keep_fraction must be in [0, 1), got {self.keep_fraction}")
        if self.garbled_bytes < 1:
            raise ValueError(f"garbled_bytes must be >= 1, got {self.garbled_bytes}")
        if self.part < 0:
            raise ValueError(f"part must be >= 0, got {self.part}")

    def kept(self, reply: bytes) -> bytes:
        """The leading part of ``reply`` that is still sent (truncation, disconnect)."""
        keep = min(int(len(reply) * self.keep_fraction), max(len(reply) - 1, 0))
        return reply[:keep]

    def garble(self, reply: bytes, rng: np.random.Generator, *, keep: bytes = b"") -> bytes:
        """``reply`` with ``garbled_bytes`` bytes replaced by bytes >= 0x80.

        Bytes whose values are in ``keep`` (a text protocol's line ends and prompts) are never
        replaced, so the receiver sees a complete but corrupted reply rather than a missing one.
        """
        candidates = [index for index, byte in enumerate(reply) if byte not in keep]
        if not candidates:
            return reply
        corrupted = bytearray(reply)
        count = min(self.garbled_bytes, len(candidates))
        for position in rng.choice(candidates, size=count, replace=False):
            corrupted[int(position)] = int(rng.integers(0x80, 0x100))
        return bytes(corrupted)


@dataclass
class FaultRule:
    """When to inject a fault.

    Parameters
    ----------
    fault
        What to inject.
    match
        Regular expression matched at the start of the command label; ``None`` matches every
        command.
    nth
        Fire only on the n-th matching command (1-based). ``None``: every matching command.
    probability
        Fire on a matching command with this probability (drawn from the schedule's generator).
        Combined with ``nth``, the n-th command fires with this probability.
    limit
        Stop after firing this many times (``None``: no limit).
    """

    fault: Fault
    match: str | None = None
    nth: int | None = None
    probability: float | None = None
    limit: int | None = None
    seen: int = field(default=0, init=False)
    fired: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.nth is not None and self.nth < 1:
            raise ValueError(f"nth counts from 1, got {self.nth}")
        if self.probability is not None and not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {self.probability}")
        if self.limit is not None and self.limit < 0:
            raise ValueError(f"limit must be >= 0, got {self.limit}")
        self._pattern = re.compile(self.match) if self.match is not None else None

    def matches(self, label: str) -> bool:
        return self._pattern is None or self._pattern.match(label) is not None


@dataclass(frozen=True)
class InjectedFault:
    """A fault that was injected: which command (by label and its ordinal) and what."""

    label: str
    command_index: int
    fault: Fault


class FaultSchedule:
    """An ordered list of rules; the first rule that fires on a command wins.

    Thread-safe: the emulator thread asks, a test thread may inspect :attr:`injected`.

    Parameters
    ----------
    rules
        The rules, in priority order.
    seed
        Seed of the generator used for probabilities and garbling (ignored if ``rng`` is given).
    rng
        An explicit generator.
    """

    def __init__(
        self,
        rules: Iterable[FaultRule] = (),
        *,
        seed: int = 0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.rules = list(rules)
        self.rng = rng if rng is not None else np.random.default_rng(seed)
        self.injected: list[InjectedFault] = []
        self._commands_seen = 0
        self._lock = threading.Lock()

    @classmethod
    def once(cls, fault: Fault, match: str | None = None, *, nth: int = 1) -> FaultSchedule:
        """A schedule with a single rule that fires on the ``nth`` matching command."""
        return cls([FaultRule(fault, match=match, nth=nth)])

    def kinds(self) -> set[FaultKind]:
        """The fault kinds this schedule can inject (emulators reject kinds they cannot produce)."""
        return {rule.fault.kind for rule in self.rules}

    def next_fault(self, label: str) -> Fault | None:
        """The fault to inject for the command ``label``, or ``None``; every call counts."""
        with self._lock:
            self._commands_seen += 1
            chosen: Fault | None = None
            for rule in self.rules:
                if not rule.matches(label):
                    continue
                rule.seen += 1
                if chosen is not None:
                    continue
                if rule.limit is not None and rule.fired >= rule.limit:
                    continue
                if rule.nth is not None and rule.seen != rule.nth:
                    continue
                if rule.probability is not None and self.rng.random() >= rule.probability:
                    continue
                rule.fired += 1
                chosen = rule.fault
            if chosen is not None:
                self.injected.append(InjectedFault(label, self._commands_seen, chosen))
            return chosen
