"""``rig capture`` in a child process on the digital twin, with a slow capture to interrupt.

Usage: ``python -m tests.rig.twin_process CONFIG SLOW_CAPTURE_S [CALL]``. The twin's second
``CALL`` (default ``capture``; ``file_get`` is the download of a frame from the camera) takes
SLOW_CAPTURE_S of wall time (a ``slow`` camera fault), so a test that sees the first bracket frame
in the log can interrupt the run while a lamp is on. The relays keep their state in the
configuration's ``devices.relays.state_file``.
"""

from __future__ import annotations

import sys

from mocks.bench import TwinFaults
from mocks.fake_gphoto2 import CameraFault
from rig import cli, station
from rig.twin import twin_station_builder


def main() -> None:
    config, slow_capture_s, *call = sys.argv[1:]
    slow = CameraFault(
        "slow", call=call[0] if call else "capture", skip=1, delay_s=float(slow_capture_s)
    )
    station.STATION_BUILDERS["twin"] = twin_station_builder(faults=TwinFaults(camera=[slow]))
    sys.argv = ["rig", "capture", "--config", config, "--quiet"]
    cli.main()


if __name__ == "__main__":
    main()
