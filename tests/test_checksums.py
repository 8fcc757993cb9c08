"""The one file hasher (calib.core.checksums) and the one software record (calib.core.software)."""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest

from calib.core.checksums import CHUNK_BYTES, file_sha256
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
