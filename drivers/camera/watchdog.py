"""A hard deadline around blocking library calls that may never return.

libgphoto2 calls can hang (low battery, a body that stops answering, ``wait_for_event`` that ignores
its timeout: gphoto2#393, #511, libgphoto2#611). A Python thread cannot be killed, so each camera
gets one worker thread that runs its library calls in order; the caller waits for the result with a
deadline. When the deadline passes the worker is abandoned (it is a daemon thread, so it cannot keep
the process alive) and the next call starts a fresh worker. The driver then re-initialises the camera
with a new library object before trusting it again.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import TypeVar

__all__ = ["CallTimedOut", "CallWatchdog"]

T = TypeVar("T")
_Job = tuple[Callable[[], object], "Future[object]"]


class CallTimedOut(Exception):
    """A call did not return within its deadline; its worker thread was abandoned."""

    def __init__(self, call: str, timeout_s: float) -> None:
        self.call = call
        self.timeout_s = timeout_s
        super().__init__(f"{call} did not return within {timeout_s:g} s")


class _Worker(threading.Thread):
    def __init__(self, name: str) -> None:
        super().__init__(name=name, daemon=True)
        self.jobs: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()

    def run(self) -> None:
        while True:
            job = self.jobs.get()
            if job is None:
                return
            function, future = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                result = function()
            except BaseException as exc:  # handed to the caller, who decides
                future.set_exception(exc)
            else:
                future.set_result(result)


class CallWatchdog:
    """Run calls one at a time on a worker thread, each with a deadline.

    Parameters
    ----------
    name
        Thread name prefix (shows in debuggers and ``threading.enumerate()``).
    """

    def __init__(self, name: str) -> None:
        self._name = name
        self._lock = threading.Lock()
        self._worker: _Worker | None = None
        self._generation = 0
        self.abandoned = 0
        """How many workers were left behind in a call that never returned."""

    def call(self, function: Callable[[], T], *, timeout_s: float, name: str) -> T:
        """Run ``function()`` on the worker and return its result or raise its exception.

        Raises
        ------
        CallTimedOut
            When it has not finished after ``timeout_s`` seconds. The worker is abandoned.
        """
        if not timeout_s > 0:
            raise ValueError(f"{name}: timeout_s must be positive, got {timeout_s}")
        future: Future[object] = Future()
        with self._lock:
            worker = self._ensure_worker()
            worker.jobs.put((function, future))
        try:
            return future.result(timeout=timeout_s)  # type: ignore[return-value]
        except FutureTimeout:
            future.cancel()
            self._abandon(worker)
            raise CallTimedOut(name, timeout_s) from None

    def close(self) -> None:
        """Let the worker finish its queue and exit (does not wait for a stuck one)."""
        with self._lock:
            if self._worker is not None:
                self._worker.jobs.put(None)
                self._worker = None

    def _ensure_worker(self) -> _Worker:
        if self._worker is None or not self._worker.is_alive():
            self._generation += 1
            self._worker = _Worker(f"{self._name}-{self._generation}")
            self._worker.start()
        return self._worker

    def _abandon(self, worker: _Worker) -> None:
        with self._lock:
            if self._worker is worker:
                worker.jobs.put(None)  # it exits if the stuck call ever returns
                self._worker = None
                self.abandoned += 1
