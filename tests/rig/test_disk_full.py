"""A disk that really fills up: ``rig capture`` on the twin into a small tmpfs, then ``rig resume``.

The capture runs in a child process in its own mount namespace (:mod:`tests.rig.disk_full_process`,
``unshare --mount``), on a 16 MiB tmpfs that it fills to the last page once a chosen step is done:
the next write that needs room fails with a real ``ENOSPC`` from the kernel — a log record, a
transcript entry, a spectrum or the camera's download, whichever comes first. Whatever it is, the
run must end as ``session_write`` with its stop record written (the room reserved for it), the
lamps confirmed off, every acknowledged file verifying, no temporary left behind — and the session
must resume to completion once there is room again.

Skipped where the machine does not allow a mount namespace (neither as root nor as a user).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rig.records import StopRecord
from rig.resume import run_resume
from rig.runner import RetryPolicy
from rig.session import read_session
from tests.rig.fakes import write_config
from tests.rig.test_fault_matrix import leftovers, matrix_config

ROOT = Path(__file__).resolve().parents[2]
NO_BACKOFF = RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)
NAMESPACES = (
    ["unshare", "--mount", "--propagation", "private"],
    ["unshare", "--mount", "--map-root-user", "--propagation", "private"],
)


def _namespace(probe: Path) -> list[str] | None:
    """The ``unshare`` command that may mount a tmpfs here, or ``None``."""
    if shutil.which("unshare") is None or shutil.which("mount") is None:
        return None
    probe.mkdir()
    for command in NAMESPACES:
        mount = ["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(probe)]
        done = subprocess.run([*command, *mount], capture_output=True, timeout=30, check=False)
        if done.returncode == 0:
            return command
    return None


@pytest.fixture(scope="module")
def namespace(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    command = _namespace(tmp_path_factory.mktemp("probe") / "mnt")
    if command is None:
        pytest.skip("this machine allows no mount namespace for a small tmpfs (unshare --mount)")
    return command


@pytest.mark.parametrize(
    "fill_after",
    [
        # What fails first is the next write that needs a new page (measured: a transcript
        # entry, a warm-up spectrum, the camera's download of a frame).
        "start/all-lamps-off",
        "start/spectrometer",
        "lamp/LED-B3/scene/000/exposure",
    ],
)
def test_a_full_disk_ends_as_session_write_and_resumes(
    namespace: list[str], tmp_path: Path, fill_after: str
) -> None:
    mount = tmp_path / "disk"
    mount.mkdir()
    config = matrix_config(tmp_path)  # relays' state file here, outside the small disk
    data = config.model_dump(mode="json") | {"output_dir": str(mount / "sessions")}
    config_file = write_config(tmp_path / "rig.yaml", data)
    copies, result = tmp_path / "copies", tmp_path / "result.json"
    copies.mkdir()
    arguments = [str(config_file), str(mount), fill_after, str(copies), str(result)]
    child = subprocess.run(
        [*namespace, sys.executable, "-m", "tests.rig.disk_full_process", *arguments],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert child.returncode == 0, child.stderr
    outcome = json.loads(result.read_text())
    assert outcome["filled_bytes"] > 0
    assert (outcome["reason"], outcome["lamps_off"]) == ("session_write", True), outcome
    assert "No space left on device" in outcome["message"]
    assert (tmp_path / "relays.state").read_text().strip() == "00"
    session_path = copies / outcome["session"]
    session = read_session(session_path)
    assert session.torn is None and session.status == "failed"
    stop = session.records[-1]
    assert isinstance(stop, StopRecord) and stop.reason == "session_write" and stop.lamps_off
    assert session.verify_files() == []
    assert leftovers(session_path) == []
    # Room again (the copy is on an ordinary disk): the session resumes to completion.
    resumed = run_resume(session_path, config, retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    completed = read_session(session_path)
    assert completed.status == "complete" and completed.verify_files() == []
