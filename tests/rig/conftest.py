"""Fixtures of the rig tests: temporary directories in memory where the machine has a tmpfs.

Sessions sync every record (fdatasync) and every file (fsync); on a disk that costs milliseconds
each and dominates the suite's run time. The same code runs on tmpfs, where a sync is nearly free;
durability itself cannot be tested in a unit test anyway.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

MEMORY_FILESYSTEM = Path("/dev/shm")


@pytest.fixture
def tmp_path(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A fresh directory on ``/dev/shm`` when it exists, else pytest's usual temporary directory."""
    if not MEMORY_FILESYSTEM.is_dir():
        yield tmp_path_factory.mktemp("rig")
        return
    path = Path(tempfile.mkdtemp(prefix="spectral-rig-test-", dir=MEMORY_FILESYSTEM))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)
