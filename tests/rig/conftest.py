"""Fixtures of the rig tests: temporary directories in memory where the machine has a tmpfs, and
the camera driver's recovery waits shortened for tests whose twin camera answers busy or unplugs.

Sessions sync every record (fdatasync) and every file (fsync); on a disk that costs milliseconds
each and dominates the suite's run time. The same code runs on tmpfs, where a sync is nearly free;
durability itself cannot be tested in a unit test anyway.
"""

from __future__ import annotations

import functools
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.camera import gphoto

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


#: The camera driver's waits in these tests: after a busy answer (0.5 s by default, doubled on each
#: further attempt) and before re-initialising after an unplug (1 s). They are real sleeps, not
#: the twin's clock, and the twin's body answers busy or comes back by its count of calls, never
#: by time: the retries take the same path and leave the same records and transcripts.
FAST_CAMERA_RECOVERY_S = 0.01


@pytest.fixture
def fast_camera_recovery(monkeypatch: pytest.MonkeyPatch) -> None:
    """The camera driver (``drivers.camera.gphoto``) built with short recovery waits.

    For tests whose twin camera answers busy or unplugs in this process (child processes keep
    the defaults). The driver's own tests (``tests/usb_camera``) run it with a short policy too.
    """
    fast = functools.partial(
        gphoto.RecoveryPolicy,
        busy_backoff_s=FAST_CAMERA_RECOVERY_S,
        reinit_backoff_s=FAST_CAMERA_RECOVERY_S,
    )
    monkeypatch.setattr(gphoto, "RecoveryPolicy", fast)
