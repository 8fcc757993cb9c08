"""The SHA-256 of a file: the one file hasher of calib and rig.

Every file the project records or checks is hashed here: a session's frames, spectra and transcripts
when they are stored and whenever they are verified (:mod:`rig.session`, :mod:`rig.estimate`), an
estimate's inputs (:mod:`calib.pipeline.provenance`, ``calib spd``) and the pinned camera data
(:func:`calib.core.datasets.fetch_datasets`). The file is read once, in :data:`CHUNK_BYTES` pieces, so
a 100 MB RAW file never sits in memory whole (``hashlib`` releases the GIL on each piece, so hashing
threads run beside decoding).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

#: Bytes read per call while hashing.
CHUNK_BYTES = 1 << 20


def file_sha256(path: str | Path, *, sync: bool = False) -> tuple[int, str]:
    """``(size in bytes, sha256 hex digest)`` of a file, read once.

    Parameters
    ----------
    path
        The file.
    sync
        Also ``fsync`` the file through the descriptor it was read with, before it is closed: what a
        writer does before renaming a finished file into place, so the bytes hashed are the bytes
        made durable.

    Raises
    ------
    OSError
        The file cannot be opened, read or synced (the caller names what it was for).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = Path(folder) / "a.txt"
    ...     _ = path.write_bytes(b"abc")
    ...     file_sha256(path)
    (3, 'ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad')
    """
    digest = file_digest(path, sync=sync)
    return digest.size, digest.sha256


@dataclass(frozen=True)
class FileDigest:
    """A file's size and sha256, with the state of the file they were read from.

    ``state`` is the file's device, inode, size and modification and change times (ns) as its
    descriptor showed them once the file was read: a later :func:`file_digest` given this
    digest as ``known`` reads the file again only when its state differs (it was replaced or
    written since).
    """

    size: int
    sha256: str
    state: tuple[int, int, int, int, int]


def _state(descriptor: int) -> tuple[int, int, int, int, int]:
    info = os.fstat(descriptor)
    return info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, info.st_ctime_ns


def file_digest(
    path: str | Path, *, sync: bool = False, known: FileDigest | None = None
) -> FileDigest:
    """The :class:`FileDigest` of a file, read once (:func:`file_sha256` is its size and sha256).

    Parameters
    ----------
    path
        The file.
    sync
        As for :func:`file_sha256`.
    known
        A digest of the same file taken earlier: when the opened file's state is still
        ``known.state`` it is not read again (only synced when ``sync``) and ``known`` is
        returned; otherwise it is read and hashed as without it.

    Raises
    ------
    OSError
        The file cannot be opened, read or synced (the caller names what it was for).
    """
    descriptor = os.open(path, os.O_RDONLY)
    try:
        if known is not None and _state(descriptor) == known.state:
            digest = known
        else:
            hasher = hashlib.sha256()
            size = 0
            while chunk := os.read(descriptor, CHUNK_BYTES):
                hasher.update(chunk)
                size += len(chunk)
            digest = FileDigest(size, hasher.hexdigest(), _state(descriptor))
        if sync:
            os.fsync(descriptor)
    finally:
        os.close(descriptor)
    return digest
