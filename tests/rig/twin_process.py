"""``rig capture`` in a child process on the digital twin, with a slow capture to interrupt.

Usage: ``python -m tests.rig.twin_process CONFIG SLOW_CAPTURE_S [CALL [LAG]]``. The twin's second
``CALL`` (default ``capture``; ``file_get`` is the download of a frame from the camera) takes
SLOW_CAPTURE_S of wall time (a ``slow`` camera fault), so a test that sees the first bracket frame
in the log can interrupt the run while a lamp is on. The relays keep their state in the
configuration's ``devices.relays.state_file``.

``LAG`` holds the journal thread (which stores a frame while the camera takes the next) as a
loaded machine can, so that a kill in the second ``CALL`` lands at a known point of the first
frame's storing: ``before-rename`` (the frame is still a temporary) or ``before-record`` (renamed
into place, no ``file`` record yet). ``LAG`` ``start-timeout`` instead makes the spectrometer's
first exposure setting (``SE``, before any lamp is on) time out as a loaded machine can: the rig
retries it after its backoff (0.5 s on the twin's clock), so every later step is that much later.
CONFIG.signals counts the signals the run has handled (:mod:`tests.rig.handled_signals`).
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import rig.session
from mocks.bench import TwinFaults
from mocks.fake_gphoto2 import CameraFault
from mocks.faults import Fault, FaultKind, FaultSchedule
from rig import cli, station
from rig.twin import twin_station_builder
from tests.rig.handled_signals import report_handled_signals

#: Longer than any wait for the kill: the held store never finishes.
HELD_S = 600.0


def hold_frame_stores(lag: str) -> None:
    """Hold every frame's storing at ``lag`` (see the module docstring) in the journal thread."""
    name = {"before-rename": "file_digest", "before-record": "_sync_directory"}[lag]
    real = getattr(rig.session, name)

    def held(path: Path, *args: object, **kwargs: object) -> object:
        if "frames" in Path(path).parts and threading.current_thread().name.startswith(
            "rig-journal"
        ):
            threading.Event().wait(HELD_S)
        return real(path, *args, **kwargs)

    setattr(rig.session, name, held)


def main() -> None:
    config, slow_capture_s, *rest = sys.argv[1:]
    call = rest[0] if rest else "capture"
    lag = rest[1] if len(rest) > 1 else None
    spectrometer = None
    if lag == "start-timeout":
        spectrometer = FaultSchedule.once(Fault(FaultKind.NO_REPLY), "SE", nth=1)
    elif lag is not None:
        hold_frame_stores(lag)
    slow = CameraFault("slow", call=call, skip=1, delay_s=float(slow_capture_s))
    faults = TwinFaults(camera=[slow], spectrometer=spectrometer)
    station.STATION_BUILDERS["twin"] = twin_station_builder(faults=faults)
    report_handled_signals(Path(f"{config}.signals"))
    sys.argv = ["rig", "capture", "--config", config, "--quiet"]
    cli.main()


if __name__ == "__main__":
    main()
