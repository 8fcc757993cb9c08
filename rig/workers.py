"""One worker thread per device: every device call runs there, under a wall-clock deadline.

Why threads: a deadline can then be enforced even on a call that blocks inside a C library
(libgphoto2), the main thread stays free to react to a second Ctrl-C, and a call is never cut in half
by a signal (signals are delivered to the main thread only). Calls to one device are serialised in
its thread, so an abandoned call finishes before the next one starts on the same device.

A call that overruns its deadline raises :class:`rig.errors.StepTimeout`; the device is marked hung
until that call returns, and calls made meanwhile fail at once instead of queueing behind it.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
from typing import Any, TypeVar

from rig.errors import StepTimeout

T = TypeVar("T")

#: Longest uninterrupted wait of the calling thread for a device call, in seconds.
WAKE_UP_S = 0.05


@dataclass
class _Job:
    what: str
    function: Callable[[], Any]
    future: Future[Any]


class DeviceWorker:
    """A daemon thread that runs one device's calls in order.

    Parameters
    ----------
    role
        The device's role in the rig (``"camera"``), used for the thread's name.
    device
        How errors name the device (``"PR-655 on /dev/ttyACM0"``); may be updated after identify.
    """

    def __init__(self, role: str, device: str) -> None:
        self.role = role
        self.device = device
        self._jobs: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._hung: tuple[str, float] | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name=f"rig-{role}", daemon=True)
        self._thread.start()

    def call(self, what: str, function: Callable[[], T], timeout_s: float) -> T:
        """Run ``function`` in the device's thread; wait at most ``timeout_s`` (wall clock) for it.

        Raises
        ------
        StepTimeout
            When the call overruns, or an earlier overrunning call to this device has not returned.
        Exception
            Whatever ``function`` raised.
        """
        with self._lock:
            hung = self._hung
        if hung is not None:
            what_hung, since = hung
            raise StepTimeout(
                self.device,
                f"cannot {what}: the device has not returned from {what_hung} for "
                f"{time.monotonic() - since:.0f} s",
                timeout_s=timeout_s,
            )
        future: Future[T] = Future()
        self._jobs.put(_Job(what, function, future))
        deadline = time.monotonic() + timeout_s
        while True:
            # Wait in short slices: a signal may be delivered to another thread, and the main
            # thread only runs its Python handler when it wakes up.
            remaining = deadline - time.monotonic()
            try:
                return future.result(timeout=max(0.0, min(remaining, WAKE_UP_S)))
            except FutureTimeout:
                if remaining > WAKE_UP_S:
                    continue
            with self._lock:
                if not future.done():
                    self._hung = (what, deadline - timeout_s)
            if future.done():
                return future.result()
            raise StepTimeout(
                self.device, f"{what} did not finish within {timeout_s:g} s", timeout_s=timeout_s
            ) from None

    def _serve(self) -> None:
        while (job := self._jobs.get()) is not None:
            if not job.future.set_running_or_notify_cancel():
                continue
            try:
                result = job.function()
            except BaseException as exc:  # handed to the caller, whatever it is
                job.future.set_exception(exc)
            else:
                job.future.set_result(result)
            finally:
                with self._lock:
                    self._hung = None

    def close(self, timeout_s: float = 1.0) -> None:
        """Stop the thread after the queued calls (waits at most ``timeout_s``)."""
        self._jobs.put(None)
        self._thread.join(timeout_s)
