"""``rig capture`` on the digital twin into a small tmpfs that really fills up (``ENOSPC``).

Usage: ``unshare --mount --propagation private python -m tests.rig.disk_full_process CONFIG MOUNT
FILL_AFTER_KEY COPY_TO RESULT``. Run in its own mount namespace, the process mounts a 16 MiB tmpfs on
MOUNT (the configuration's ``output_dir`` lies in it), runs the capture, and once the step
FILL_AFTER_KEY is done fills the tmpfs to its last page with a file of its own, so the very next
write that needs room fails as on a full disk. As the run ends it fills the disk again (whatever
the failed write freed, a partial download removed, is taken as another process would take it): the
run's last records then have only the room the session reserved. The session is then copied to
COPY_TO (the tmpfs disappears with the namespace) and the outcome written to RESULT as JSON.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from rig.capture import run_capture
from rig.config import load_config
from rig.dryrun import DryRunReport
from rig.progress import SilentProgress
from rig.runner import RetryPolicy
from rig.session import SessionWriter
from rig.steps import AnyStep, StepResult

TMPFS_SIZE = "16m"


class FillAfter(SilentProgress):
    """Fills the disk once the step ``key`` is done."""

    def __init__(self, key: str, filler: Path) -> None:
        self.key = key
        self.filler = filler
        self.filled_bytes = 0

    def step_done(self, step: AnyStep, result: StepResult) -> None:
        if step.key == self.key:
            self.fill()

    def fill(self) -> None:
        """Write to the filler until the disk is full."""
        fd = os.open(self.filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        chunk = b"\0" * 4096
        try:
            while True:
                self.filled_bytes += os.write(fd, chunk)
        except OSError as exc:
            if exc.errno != errno.ENOSPC:
                raise
        finally:
            os.close(fd)

    def start(self, estimate: DryRunReport | None) -> None:
        """Nothing."""


def main() -> None:
    config_path, mount, key, copy_to, result = sys.argv[1:6]
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={TMPFS_SIZE}", "tmpfs", mount], check=True)
    config = load_config(config_path)
    progress = FillAfter(key, Path(mount) / "filler")
    release_room = SessionWriter.finish

    def finish_on_a_disk_still_full(self: SessionWriter) -> bool:
        if progress.filled_bytes:
            progress.fill()
        return release_room(self)

    SessionWriter.finish = finish_on_a_disk_still_full  # type: ignore[method-assign]
    outcome = run_capture(
        config, progress=progress, retry=RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)
    )
    shutil.copytree(outcome.session, Path(copy_to) / outcome.session.name, symlinks=True)
    with contextlib.suppress(OSError):
        (Path(mount) / "filler").unlink()
    Path(result).write_text(
        json.dumps(
            {
                "session": outcome.session.name,
                "reason": outcome.reason,
                "message": outcome.message,
                "lamps_off": outcome.lamps_off,
                "filled_bytes": progress.filled_bytes,
            }
        )
    )


if __name__ == "__main__":
    main()
