"""``rig capture`` in a child process, on the fake rig and the wall clock, for the signal tests.

Usage: ``python -m tests.rig.capture_process CONFIG STATE_FILE MARKER_FILE CAPTURE_DELAY_S``.
The relay board mirrors its state to STATE_FILE (``"10"``: channel 1 on); the camera writes
MARKER_FILE when a capture begins, and each capture takes CAPTURE_DELAY_S of real time.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rig import cli, station
from rig.clock import MonotonicClock
from tests.rig.fakes import make_fake_rig


def main() -> None:
    config, state_file, marker_file, delay_s = sys.argv[1:5]
    rig = make_fake_rig(clock=MonotonicClock(), state_file=Path(state_file), warmup_tau_s=0.02)
    rig.camera.marker_file = Path(marker_file)
    rig.camera.io.delay_s["capture"] = float(delay_s)
    station.STATION_BUILDERS["twin"] = rig.builder
    sys.argv = ["rig", "capture", "--config", config, "--quiet"]
    cli.main()


if __name__ == "__main__":
    main()
