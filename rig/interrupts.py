"""Ctrl-C and SIGTERM for a running capture: the first finishes the step, the second stops at once.

:class:`InterruptController` replaces the handlers of SIGINT, SIGTERM and SIGHUP while a run is in
progress (main thread only; Python delivers signals there):

* the first signal only *requests* a stop: the runner finishes the current step, records it, and
  stops cleanly (Bluesky's deferred pause, without the in-memory resume);
* a second signal raises :class:`HaltRequested` at once — except inside a :meth:`critical` section
  (a log write, a file rename), where it is held until the section ends so no record is torn;
* once a halt is under way (a second signal raised, or held for a section's end) or cleanup has
  begun (:meth:`enter_cleanup`: switching lamps off, writing the stop record), further signals are
  only noted: the halt's own cleanup must run to the end (a third Ctrl-C raised inside it, while
  the lamps of an interrupted opening were being switched off, left them on and printed a
  traceback).

Device exchanges run in worker threads (:mod:`rig.workers`), which never receive signals, so a
transaction with a device is never cut in half either: an abandoned exchange finishes in its thread,
and the next call to the same device (the lamps-off in cleanup) queues behind it.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from types import FrameType, TracebackType
from typing import Literal

HANDLED_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


class HaltRequested(BaseException):
    """A second interrupt: stop now. A :class:`BaseException` so no ``except Exception`` swallows it."""

    def __init__(self, signal_name: str) -> None:
        self.signal_name = signal_name
        super().__init__(f"stopped at once by a second interrupt ({signal_name})")


@dataclass(frozen=True)
class ReceivedSignal:
    """A signal the run received: its name, :func:`time.monotonic` at receipt, what it triggered."""

    name: str
    monotonic_s: float
    action: Literal["finish-step", "stop-now"]


class _CriticalSection:
    """Counted in the main thread only: signal handlers run there, so another thread (the
    runner's journal) is never cut by one, and its sections must not hold back a second signal
    meant to stop the main thread at once."""

    def __init__(self, controller: InterruptController) -> None:
        self._controller = controller
        self._counted = False

    def __enter__(self) -> None:
        self._counted = threading.current_thread() is threading.main_thread()
        if self._counted:
            self._controller._critical_depth += 1

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if not self._counted:
            return
        controller = self._controller
        controller._critical_depth -= 1
        pending = controller._halt_pending
        if controller._critical_depth == 0 and pending and not controller._cleanup:
            controller._halt_pending = None
            if exc_type is None:
                raise HaltRequested(pending)


class InterruptController:
    """Turns SIGINT/SIGTERM/SIGHUP into a stop request, then into :class:`HaltRequested`."""

    def __init__(self) -> None:
        self.received: list[ReceivedSignal] = []
        self._critical_depth = 0
        self._halt_pending: str | None = None
        self._cleanup = False
        self._previous: dict[signal.Signals, object] = {}
        self._installs = 0

    @property
    def stop_requested(self) -> str | None:
        """The name of the first signal received, or ``None``."""
        return self.received[0].name if self.received else None

    @property
    def halted(self) -> bool:
        """Whether a second signal asked to stop at once."""
        return any(r.action == "stop-now" for r in self.received)

    def install(self) -> bool:
        """Install the handlers; returns ``False`` (and does nothing) outside the main thread.

        Installs nest: a capture installs them before it opens the devices, the runner again when
        the run starts; only the outermost :meth:`uninstall` restores the previous handlers.
        """
        if threading.current_thread() is not threading.main_thread():
            return False
        self._installs += 1
        if self._installs == 1:
            for signum in HANDLED_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return True

    def uninstall(self) -> None:
        """Undo one :meth:`install`; the outermost restores the handlers that were there before."""
        if self._installs == 0:
            return
        self._installs -= 1
        if self._installs > 0:
            return
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)  # type: ignore[arg-type]
        self._previous.clear()

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        """The handlers installed for the ``with`` block."""
        installed = self.install()
        try:
            yield
        finally:
            if installed:
                self.uninstall()

    def critical(self) -> _CriticalSection:
        """A section a second interrupt may not cut (it is raised when the section ends)."""
        return _CriticalSection(self)

    def enter_cleanup(self) -> None:
        """From now on signals are only noted: cleanup must run to the end."""
        self._cleanup = True
        self._halt_pending = None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        # Runs in the main thread between bytecodes: it must not take locks or do I/O.
        name = signal.Signals(signum).name
        if not self.received:
            self.received.append(ReceivedSignal(name, time.monotonic(), "finish-step"))
            return
        # A halt is already under way once an earlier signal was a stop-now one.
        halting = len(self.received) > 1
        self.received.append(ReceivedSignal(name, time.monotonic(), "stop-now"))
        if self._cleanup or halting:
            return
        if self._critical_depth > 0:
            self._halt_pending = name
            return
        raise HaltRequested(name)
