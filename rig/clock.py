"""Time for the runner: a protocol, and the wall clock used on a real rig.

The runner takes every timestamp and every wait from a :class:`Clock`. The digital twin passes a
simulated clock (``mocks.lamps.SimulatedClock`` satisfies this protocol structurally) so a lamp
warm-up of minutes takes no wall time while the runner's logic stays the real one. Device deadlines
are enforced in wall time regardless (:mod:`rig.workers`), because a hung device hangs in real time.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """A source of time in seconds; ``sleep`` lets that much time pass (really or virtually)."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """Real time from :func:`time.monotonic`; the default clock of a capture."""

    def now(self) -> float:
        """Seconds since an arbitrary fixed point."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` (nothing for zero or negative values)."""
        if seconds > 0:
            time.sleep(seconds)
