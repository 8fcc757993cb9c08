"""Serve a firmware emulator on a pseudo-terminal so the real driver opens a real device path.

``os.openpty()`` gives a (master, slave) pair; the driver opens the slave's path (``/dev/pts/N``, or
a symlink such as ``/tmp/ttyPR655``) with pyserial exactly as it would open ``/dev/ttyACM0``, and a
thread on the master feeds the received bytes to the emulator and writes its replies back. Both ends
are put in raw mode so CR and LF cross untouched.

The emulator side of the contract is :class:`SerialEmulator`: it is given a :class:`DeviceLink` to
send bytes (now or after a delay: measurements take time, faults make replies late) and to hang up
(a disconnect, as when a USB cable is pulled). All emulator calls happen on the harness thread.

The harness keeps its own handle on the slave open, so a driver may close and reopen the port as
often as it likes; :meth:`PtySerialDevice.unplug` closes everything and removes the symlink, as the
kernel removes ``/dev/ttyACM0`` when a device goes away.
"""

from __future__ import annotations

import contextlib
import errno
import heapq
import itertools
import logging
import os
import select
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Protocol, Self

_log = logging.getLogger(__name__)

#: Bytes read from the master in one go.
_READ_CHUNK = 4096


class ScheduledOutput:
    """Bytes queued for sending; :meth:`cancel` withdraws them if they have not gone yet."""

    def __init__(self, data: bytes, due_s: float) -> None:
        self.data = data
        self.due_s = due_s
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class DeviceLink(Protocol):
    """What an emulator may do to the wire."""

    def send(self, data: bytes, *, delay_s: float = 0.0) -> ScheduledOutput:
        """Queue ``data`` to be written ``delay_s`` from now (equal times keep their order)."""

    def hang_up(self, *, delay_s: float = 0.0) -> None:
        """Drop the link ``delay_s`` from now (the device disappears)."""


class SerialEmulator(Protocol):
    """A device-side protocol implementation (see :mod:`mocks.emulators`)."""

    @property
    def name(self) -> str: ...

    def attach(self, link: DeviceLink) -> None:
        """Called once by the harness before any byte arrives."""

    def receive(self, data: bytes) -> None:
        """Bytes written by the driver (in arbitrary chunks: one character, or many commands)."""


class EmulatorCrashed(RuntimeError):
    """The emulator raised while handling input; the harness kept serving, this reports it."""


@dataclass(order=True)
class _QueueItem:
    due_s: float
    sequence: int
    output: ScheduledOutput | None = field(compare=False)  # None means hang up


class PtySerialDevice:
    """An emulator served on a pty pair.

    Parameters
    ----------
    emulator
        The device-side protocol.
    symlink
        Optional stable path (e.g. ``tmp_path / "ttyPR655"``) pointing at the pty; an existing
        symlink there is replaced, any other file is an error.

    Examples
    --------
    >>> from mocks.emulators.numato import NumatoEmulator  # doctest: +SKIP
    >>> with PtySerialDevice(NumatoEmulator(channels=8)) as device:  # doctest: +SKIP
    ...     board = open_numato(device.path, 8)
    """

    def __init__(self, emulator: SerialEmulator, *, symlink: str | Path | None = None) -> None:
        self.emulator = emulator
        self.symlink = Path(symlink) if symlink is not None else None
        self.errors: list[BaseException] = []
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_path: str | None = None
        self._wake_read: int | None = None
        self._wake_write: int | None = None
        self._queue: list[_QueueItem] = []
        self._sequence = itertools.count()
        self._outgoing = bytearray()
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._unplugged = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------------------ lifecycle

    @property
    def path(self) -> str:
        """The path a driver opens (the symlink if one was asked for)."""
        if self._slave_path is None:
            raise RuntimeError(f"{self.emulator.name} emulator is not started")
        return str(self.symlink) if self.symlink is not None else self._slave_path

    @property
    def unplugged(self) -> bool:
        return self._unplugged.is_set()

    def start(self) -> Self:
        """Open the pty pair and start serving."""
        if self._thread is not None:
            raise RuntimeError(f"{self.emulator.name} emulator already started")
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._slave_path = os.ttyname(slave)
        if self.symlink is not None:
            if self.symlink.is_symlink():
                self.symlink.unlink()
            elif self.symlink.exists():
                self._close_fds()
                raise FileExistsError(
                    f"cannot put the {self.emulator.name} emulator at {self.symlink}: "
                    "a file that is not a symlink is already there"
                )
            self.symlink.symlink_to(self._slave_path)
        self._wake_read, self._wake_write = os.pipe()
        self.emulator.attach(self)
        self._thread = threading.Thread(
            target=self._serve, name=f"pty-{self.emulator.name}", daemon=True
        )
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop serving and release the pty.

        Raises
        ------
        EmulatorCrashed
            The emulator raised while handling input (the first error is chained).
        """
        if self._thread is not None:
            self._stopping.set()
            self._wake()
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise RuntimeError(f"{self.emulator.name} emulator thread did not stop")
            self._thread = None
        self._close_fds()
        for fd in (self._wake_read, self._wake_write):
            if fd is not None:
                os.close(fd)
        self._wake_read = self._wake_write = None
        if self.errors:
            raise EmulatorCrashed(
                f"{self.emulator.name} emulator raised {len(self.errors)} error(s)"
            ) from self.errors[0]

    def unplug(self) -> None:
        """Disconnect now, as if the USB cable were pulled."""
        self.hang_up()

    def __enter__(self) -> Self:
        """Start if not started yet (the ``start_*`` helpers return started devices)."""
        return self if self._thread is not None else self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop()

    # ------------------------------------------------------------------------------ the link

    def send(self, data: bytes, *, delay_s: float = 0.0) -> ScheduledOutput:
        output = ScheduledOutput(bytes(data), time.monotonic() + max(0.0, delay_s))
        self._enqueue(output.due_s, output)
        return output

    def hang_up(self, *, delay_s: float = 0.0) -> None:
        self._enqueue(time.monotonic() + max(0.0, delay_s), None)

    def _enqueue(self, due_s: float, output: ScheduledOutput | None) -> None:
        with self._lock:
            heapq.heappush(self._queue, _QueueItem(due_s, next(self._sequence), output))
        self._wake()

    def _wake(self) -> None:
        if self._wake_write is not None:
            with contextlib.suppress(OSError):  # a full pipe means the thread is awake anyway
                os.write(self._wake_write, b"\0")

    # ------------------------------------------------------------------------------ the thread

    def _serve(self) -> None:
        while not self._stopping.is_set():
            timeout_s = self._release_due()
            master = None if self.unplugged else self._master
            wake = self._wake_read
            if wake is None:
                return
            readers = [wake] + ([master] if master is not None else [])
            writers = [master] if master is not None and self._outgoing else []
            try:
                readable, writable, _ = select.select(readers, writers, [], timeout_s)
            except (OSError, ValueError):  # fds closed under us during stop
                return
            if wake in readable:
                os.read(wake, 4096)
            if master is not None and master in readable:
                self._read_master(master)
            if master is not None and master in writable:
                self._write_master(master)

    def _release_due(self) -> float | None:
        """Move due output to the write buffer; return how long until the next item is due."""
        now = time.monotonic()
        with self._lock:
            while self._queue and self._queue[0].due_s <= now:
                item = heapq.heappop(self._queue)
                if item.output is None:
                    self._queue.clear()
                    self._do_hang_up()
                    return None
                if not item.output.cancelled:
                    self._outgoing.extend(item.output.data)
            if self._queue:
                return max(0.0, self._queue[0].due_s - now)
        return None

    def _read_master(self, master: int) -> None:
        try:
            data = os.read(master, _READ_CHUNK)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # the slave side went away; treat as unplugged
                self._do_hang_up()
                return
            raise
        if not data:
            return
        try:
            self.emulator.receive(data)
        except Exception as exc:  # keep serving; stop() reports it
            _log.exception("%s emulator failed on input %r", self.emulator.name, data)
            self.errors.append(exc)

    def _write_master(self, master: int) -> None:
        try:
            written = os.write(master, bytes(self._outgoing))
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._do_hang_up()
                return
            raise
        del self._outgoing[:written]

    def _do_hang_up(self) -> None:
        if self._unplugged.is_set():
            return
        self._unplugged.set()
        self._outgoing.clear()
        self._close_fds()

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        if self.symlink is not None and self.symlink.is_symlink():
            self.symlink.unlink()
