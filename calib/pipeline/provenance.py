"""What produced an estimate: the input files with their sha256, the software, the command line.

Hashing every RAW file of a bracket reads hundreds of MB; :class:`FileHasher` does it in a background
thread (``hashlib`` releases the GIL on large buffers) while the estimate runs, and a file already
hashed elsewhere (a session's verified record) is not read again.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from calib.core.checksums import file_sha256
from calib.core.software import current_software

InputRole = Literal["frame", "dark", "spectrum", "profile", "grating"]


@dataclass(frozen=True)
class InputFile:
    """One file the estimate read.

    Parameters
    ----------
    path
        The file (as given, or its place in a session).
    role
        ``frame``, ``dark``, ``spectrum``, ``profile`` or ``grating``.
    lamp
        The lamp it belongs to (``None`` for a grating file).
    size
        Size in bytes.
    sha256
        Hex digest of its content.
    """

    path: str
    role: InputRole
    lamp: str | None
    size: int
    sha256: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "role": self.role,
            "lamp": self.lamp,
            "size": self.size,
            "sha256": self.sha256,
        }


def repeated_file(paths: Sequence[Path]) -> tuple[Path, Path] | None:
    """The first two of ``paths`` that are one file, or two files with the same bytes; ``None``.

    Only files of equal size are hashed (RAW files of one bracket rarely share a size unless
    uncompressed, and then their content differs).
    """
    seen: dict[Path, Path] = {}
    by_size: dict[int, list[Path]] = {}
    for path in paths:
        resolved = path.resolve()
        if resolved in seen:
            return seen[resolved], path
        seen[resolved] = path
        by_size.setdefault(path.stat().st_size, []).append(path)
    for group in by_size.values():
        if len(group) < 2:
            continue
        digests: dict[str, Path] = {}
        for path in group:
            digest = file_sha256(path)[1]
            if digest in digests:
                return digests[digest], path
            digests[digest] = path
    return None


class FileHasher:
    """Hash files in a background thread; :meth:`results` waits for them.

    Use as a context manager so the thread ends even when the estimate fails. ``paused``: hash
    nothing before :meth:`start` (e.g. while other threads decode: hash during the estimate, which
    leaves a core idle).
    """

    def __init__(self, *, paused: bool = False) -> None:
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sha256")
        self._pending: list[tuple[Path, InputRole, str | None, Future[tuple[int, str]]]] = []
        self._known: list[InputFile] = []
        self._started = threading.Event()
        if not paused:
            self._started.set()

    def __enter__(self) -> FileHasher:
        return self

    def __exit__(self, *exc: object) -> None:
        self._started.set()
        self._executor.shutdown(wait=True, cancel_futures=True)

    def start(self) -> None:
        """Start hashing (when created ``paused``)."""
        self._started.set()

    def _hash(self, path: Path) -> tuple[int, str]:
        self._started.wait()
        return file_sha256(path)

    def add(self, path: Path, role: InputRole, lamp: str | None) -> None:
        """Hash ``path`` in the background."""
        self._pending.append((path, role, lamp, self._executor.submit(self._hash, path)))

    def add_known(self, record: InputFile) -> None:
        """A file whose hash is already known (and verified) elsewhere."""
        self._known.append(record)

    def results(self) -> tuple[InputFile, ...]:
        """Every file, in the order added (known hashes first)."""
        self._started.set()
        hashed = []
        for path, role, lamp, future in self._pending:
            size, digest = future.result()
            hashed.append(InputFile(str(path), role, lamp, size, digest))
        return (*self._known, *hashed)


@dataclass(frozen=True)
class Provenance:
    """Everything recorded about how an estimate was produced.

    Parameters
    ----------
    inputs
        Every file read, with its hash.
    command_line
        The command as typed (``None`` when called from Python).
    lamps
        Per lamp: name, kind, how it was given (images or profile), frames and exposures.
    camera
        Make, model, CFA pattern, ISO, aperture of the RAW files (empty for profile input).
    warnings
        What a user must know about this result (also printed by the command lines).
    notes
        What was decided along the way (region of interest, geometry lamp …).
    created
        When the estimate was made (UTC).
    software
        :func:`calib.core.software.current_software` as a dictionary.
    """

    inputs: tuple[InputFile, ...] = ()
    command_line: tuple[str, ...] | None = None
    lamps: tuple[Mapping[str, Any], ...] = ()
    camera: Mapping[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    created: datetime = field(default_factory=lambda: datetime.now(UTC))
    software: Mapping[str, str] = field(default_factory=lambda: current_software().to_dict())

    def to_dict(self) -> dict[str, Any]:
        return {
            "created": self.created.isoformat(timespec="seconds"),
            "software": dict(self.software),
            "command_line": None if self.command_line is None else list(self.command_line),
            "camera": dict(self.camera),
            "lamps": [dict(lamp) for lamp in self.lamps],
            "inputs": [record.to_dict() for record in self.inputs],
            "warnings": list(self.warnings),
            "notes": list(self.notes),
        }


def input_paths(records: Iterable[InputFile], role: InputRole) -> list[str]:
    """Paths of the inputs with ``role``."""
    return [record.path for record in records if record.role == role]
