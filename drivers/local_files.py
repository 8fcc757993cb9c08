"""Writing on this computer's disk without following anything planted in the way.

The write-side twin of the session reader's path checks (:meth:`rig.session.Session.file_path`):
a session directory may come from anyone, and a symbolic link planted where the rig writes (a lamp
directory, a temporary name, a final name) would carry the write outside it. Every writer of the
rig — the session writer, the camera's download, resume, the estimate's output directory — goes
through these functions:

* :func:`checked_directory` walks a directory path below a root one component at a time
  (``lstat``, never following), refusing a symbolic link or anything that is not a directory, and
  creates what is missing;
* :func:`create_new_file` opens a file that must not exist yet (``O_CREAT | O_EXCL | O_NOFOLLOW``):
  a leftover or a planted entry under a temporary name is refused, never written through;
* :func:`entries_below` walks a directory without following links, to find what was planted;
* :func:`write_atomically` writes a file's bytes to a new temporary name in the same directory
  (opened relative to the directory's own descriptor, itself opened with ``O_NOFOLLOW``), syncs and
  renames it into place; a failure removes the temporary.

Renaming onto a final name never follows a link there (``rename`` replaces the link itself).
Refusals raise :class:`UnsafeLocalPath`, naming the path and what was found there.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterator
from pathlib import Path

__all__ = [
    "NO_SPACE_ERRNOS",
    "UnsafeLocalPath",
    "checked_directory",
    "create_new_file",
    "describe_entry",
    "entries_below",
    "is_plain",
    "write_all",
    "write_atomically",
]

NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
"""``OSError.errno`` values that mean the disk (or the user's quota) is full."""

_DIRECTORY_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_NEW_FILE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


class UnsafeLocalPath(OSError):
    """A path the rig was about to write through is not what the rig made there: a symbolic
    link, a special file, a file where a directory belongs, or an entry under a temporary name
    that must not exist yet. Nothing was written through it.

    Attributes
    ----------
    path
        The offending path.
    problem
        What was found there (``"a symbolic link to /etc/passwd"``).
    """

    def __init__(self, path: Path, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(errno.EEXIST, f"{path} is {problem}; refused (nothing was written)")

    def __str__(self) -> str:
        return f"{self.path} is {self.problem}; refused (nothing was written)"


def describe_entry(path: Path) -> str:
    """What ``path`` is, as :class:`UnsafeLocalPath` says it (without following it)."""
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return "missing"
    if stat.S_ISLNK(mode):
        try:
            return f"a symbolic link to {path.readlink()}"
        except OSError:
            return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISREG(mode):
        return "a file that is already there"
    return "a special file (FIFO, socket or device)"


def entries_below(directory: Path) -> Iterator[os.DirEntry[str]]:
    """Every entry below ``directory``, never following a link: a link (or a special file) is
    yielded as itself and never entered, so a planted link cannot lead the walk elsewhere."""
    pending = [directory]
    while pending:
        with os.scandir(pending.pop()) as entries:
            for entry in entries:
                yield entry
                if entry.is_dir(follow_symlinks=False):
                    pending.append(Path(entry.path))


def is_plain(entry: os.DirEntry[str]) -> bool:
    """A real directory or a regular file: not a link, FIFO, socket or device."""
    return entry.is_dir(follow_symlinks=False) or entry.is_file(follow_symlinks=False)


def checked_directory(root: Path, relative: str, *, create: bool = True) -> Path:
    """``root / relative`` once every component below ``root`` is a real directory.

    Components are checked with ``lstat`` one by one from ``root`` (which is trusted: the user
    named it); a missing one is created (mode 0o755) when ``create`` is true.

    Raises
    ------
    UnsafeLocalPath
        A component is a symbolic link or not a directory.
    FileNotFoundError
        A component is missing and ``create`` is false.
    OSError
        A directory cannot be created (permissions, a full disk).
    """
    current = root
    for part in Path(relative).parts:
        if part in ("", ".", "..") or "/" in part:
            raise UnsafeLocalPath(current / part, "not a plain directory name")
        current = current / part
        try:
            mode = current.lstat().st_mode
        except FileNotFoundError:
            if not create:
                raise
            with contextlib.suppress(FileExistsError):  # made meanwhile: checked below
                current.mkdir(mode=0o755)
            mode = current.lstat().st_mode
        if not stat.S_ISDIR(mode):
            raise UnsafeLocalPath(current, describe_entry(current))
    return current


def create_new_file(
    path: Path, mode: int = 0o644, *, dir_fd: int | None = None, shown_as: Path | None = None
) -> int:
    """Open ``path`` as a new, empty file for writing; return its descriptor.

    With ``dir_fd``, ``path`` is a plain name inside that open directory, and ``shown_as`` is how
    messages name it.

    Raises
    ------
    UnsafeLocalPath
        Something is already there (a leftover, or a planted link: never followed).
    """
    shown = shown_as or path
    try:
        return os.open(path, _NEW_FILE_FLAGS, mode, dir_fd=dir_fd)
    except FileExistsError:
        raise UnsafeLocalPath(shown, describe_entry(shown)) from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:  # O_NOFOLLOW met a link (some systems say so, not EEXIST)
            raise UnsafeLocalPath(shown, describe_entry(shown)) from None
        raise


def write_all(fd: int, data: bytes) -> None:
    """Write every byte of ``data`` to ``fd`` (``os.write`` may write less than asked)."""
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]


def write_atomically(path: Path, data: bytes, *, sync: bool = True) -> None:
    """Write ``data`` to ``path`` via ``.<name>.partial`` in the same directory, fsync, rename.

    The directory is created if missing, and must be a real directory (not a link); everything
    happens relative to its own descriptor, so the file lands in that directory whatever is renamed meanwhile. A crash
    leaves either no file or the complete file under ``path`` (plus at most the temporary), never
    a truncated file under the final name; a failure (a full disk) removes the temporary.
    ``sync=False`` leaves out both fsyncs, for a caller that syncs the file and its directory itself
    before it relies on it (a session's ``commit_file``): after a power cut the file may then be
    empty or missing, so it must not be acknowledged anywhere before that caller's sync.

    Raises
    ------
    UnsafeLocalPath
        The directory is a link, or the temporary name is taken (a leftover or a planted link).
    OSError
        The write failed (``errno`` in :data:`NO_SPACE_ERRNOS` for a full disk).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        directory = os.open(path.parent, _DIRECTORY_FLAGS)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENOTDIR):
            raise UnsafeLocalPath(path.parent, describe_entry(path.parent)) from None
        raise
    try:
        temporary = f".{path.name}.partial"
        fd = create_new_file(Path(temporary), dir_fd=directory, shown_as=path.parent / temporary)
        try:
            write_all(fd, data)
            if sync:
                os.fsync(fd)
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(temporary, dir_fd=directory)
            raise
        os.close(fd)
        os.replace(temporary, path.name, src_dir_fd=directory, dst_dir_fd=directory)
        if sync:
            os.fsync(directory)
    finally:
        os.close(directory)
