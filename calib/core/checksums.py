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
    digest = hashlib.sha256()
    size = 0
    descriptor = os.open(path, os.O_RDONLY)
    try:
        while chunk := os.read(descriptor, CHUNK_BYTES):
            digest.update(chunk)
            size += len(chunk)
        if sync:
            os.fsync(descriptor)
    finally:
        os.close(descriptor)
    return size, digest.hexdigest()
