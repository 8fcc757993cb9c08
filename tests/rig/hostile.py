"""Watching what the rig touches outside a session: a directory snapshot and a Python audit hook.

:class:`OutsideWatch` snapshots a directory that stands for "the rest of the user's disk" (every
entry's type, size, content hash and link target) before and after an operation on a hostile
session, and records, through :func:`sys.addaudithook`, every file the process opens, renames,
removes or truncates there and every socket it connects. An audit hook cannot be removed: it is
installed once per process and does nothing while no watch is active.
"""

from __future__ import annotations

import hashlib
import os
import stat
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

_active: list[OutsideWatch] = []
_inside_hook = threading.local()
_installed = False

#: Audit events whose first argument is a path the process opens or changes.
_PATH_EVENTS = {
    "open",
    "os.remove",
    "os.rename",
    "os.truncate",
    "os.mkdir",
    "os.symlink",
    "os.link",
    "shutil.copyfile",
    "shutil.rmtree",
}


@dataclass(frozen=True)
class Touch:
    """One thing the process did outside: the audit event and the path (or address)."""

    event: str
    target: str


@dataclass
class OutsideWatch:
    """What happened to ``directory`` while the watch was active."""

    directory: Path
    touches: list[Touch] = field(default_factory=list)
    connections: list[str] = field(default_factory=list)

    def snapshot(self) -> dict[str, tuple[str, ...]]:
        """Every entry below the directory (links not followed): type, size, sha256, target."""
        entries: dict[str, tuple[str, ...]] = {}
        for path in sorted(self.directory.rglob("*")):
            mode = path.lstat().st_mode
            name = str(path.relative_to(self.directory))
            if stat.S_ISLNK(mode):
                entries[name] = ("link", str(path.readlink()))
            elif stat.S_ISREG(mode):
                data = path.read_bytes()
                entries[name] = ("file", str(len(data)), hashlib.sha256(data).hexdigest())
            else:
                entries[name] = ("dir" if stat.S_ISDIR(mode) else "other",)
        return entries

    def note(self, event: str, target: Any) -> None:
        if event == "socket.connect":
            self.connections.append(repr(target))
            return
        if not isinstance(target, str | bytes | os.PathLike):
            return
        path = Path(os.fsdecode(target))
        if not path.is_absolute():
            path = Path.cwd() / path
        # Through every link on the way: a write through a planted link lands here.
        resolved = Path(os.path.realpath(path))
        if resolved.is_relative_to(self.directory):
            self.touches.append(Touch(event, str(path)))


def _hook(event: str, args: tuple[Any, ...]) -> None:
    if not _active or getattr(_inside_hook, "busy", False):
        return
    if event not in _PATH_EVENTS and event != "socket.connect":
        return
    _inside_hook.busy = True
    try:
        target = args[1] if event == "socket.connect" else args[0]
        for watch in _active:
            watch.note(event, target)
            if event in ("os.rename", "shutil.copyfile", "os.symlink", "os.link"):
                watch.note(event, args[1])
    finally:
        _inside_hook.busy = False


@contextmanager
def watching(directory: Path) -> Iterator[OutsideWatch]:
    """Watch ``directory`` (and sockets) during the block; fail if anything there changed."""
    global _installed
    if not _installed:
        sys.addaudithook(_hook)
        _installed = True
    watch = OutsideWatch(directory.resolve())
    before = watch.snapshot()
    _active.append(watch)
    try:
        yield watch
    finally:
        _active.remove(watch)
    assert watch.snapshot() == before, "something outside the session changed"
