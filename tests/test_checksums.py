"""The one file hasher (calib.core.checksums) and the one software record (calib.core.software)."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from calib.core.checksums import CHUNK_BYTES, file_digest, file_sha256
from calib.core.datasets import PinnedFile, _file_is_valid
from calib.core.software import current_software
from calib.pipeline.provenance import Provenance
from rig.runner import software_info


@pytest.mark.parametrize("size", [0, 1, CHUNK_BYTES, 2 * CHUNK_BYTES + 123])
@pytest.mark.parametrize("sync", [False, True])
def test_file_sha256_is_hashlibs_digest_of_the_whole_file(
    tmp_path: Path, size: int, sync: bool
) -> None:
    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    path = tmp_path / "frame.dng"
    path.write_bytes(data)
    assert file_sha256(path, sync=sync) == (size, hashlib.sha256(data).hexdigest())


@pytest.mark.parametrize("sync", [False, True])
def test_a_known_digest_is_reused_only_while_the_file_is_unchanged(
    tmp_path: Path, sync: bool
) -> None:
    path = tmp_path / "frame.dng"
    path.write_bytes(b"first frame")
    digest = file_digest(path)
    assert (digest.size, digest.sha256) == file_sha256(path)
    # Unchanged: not read again (a digest with other bytes but the file's state comes back as is).
    marked = dataclasses.replace(digest, sha256="0" * 64)
    assert file_digest(path, sync=sync, known=marked) is marked
    # Written since (same size, other bytes; a later modification time): read again.
    path.write_bytes(b"other frame")
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    again = file_digest(path, sync=sync, known=marked)
    assert again.sha256 == hashlib.sha256(b"other frame").hexdigest() != marked.sha256
    # Replaced by another file of the same bytes: another inode, read again.
    replacement = tmp_path / "replacement.dng"
    replacement.write_bytes(b"other frame")
    kept = dataclasses.replace(again, sha256="1" * 64)
    replacement.replace(path)
    assert file_digest(path, known=kept).sha256 == again.sha256


def test_a_missing_file_is_an_os_error_naming_it(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"gone\.dng"):
        file_sha256(tmp_path / "gone.dng")


def test_a_pinned_file_verifies_by_size_and_digest(tmp_path: Path) -> None:
    path = tmp_path / "camera.csv"
    path.write_bytes(b"wavelength,r,g,b\n")
    digest = hashlib.sha256(b"wavelength,r,g,b\n").hexdigest()
    pinned = PinnedFile("c", "owner/repo", "0" * 40, "camera.csv", digest, 17)
    assert _file_is_valid(path, pinned)
    path.write_bytes(b"wavelength,r,g,B\n")  # same size, other bytes
    assert not _file_is_valid(path, pinned)
    assert not _file_is_valid(tmp_path / "absent.csv", pinned)


def test_every_output_records_the_same_software() -> None:
    software = current_software()
    assert software.name == "spectral-rig" and software.version
    assert software.python == sys.version.split()[0]
    assert dict(Provenance().software) == software.to_dict()
    assert software_info().model_dump() == software.to_dict()
