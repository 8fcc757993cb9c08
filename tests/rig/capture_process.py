"""``rig capture`` in a child process, on the fake rig and the wall clock, for the signal tests.

Usage: ``python -m tests.rig.capture_process CONFIG STATE_FILE MARKER_FILE CAPTURE_DELAY_S
[OPEN_DELAY_S [ctrl-c-in-release]]``. The relay board mirrors its state to STATE_FILE (``"10"``: channel 1 on); the
camera writes MARKER_FILE when a capture begins, and each capture takes CAPTURE_DELAY_S of real
time. With OPEN_DELAY_S, the board starts with channel 1 on (a lamp a killed run left on), and
opening the station takes that long after the board is open (as gphoto2 autodetection or a serial
probe may): MARKER_FILE.opening is written when that wait begins; with ``ctrl-c-in-release`` the
process also sends itself a SIGINT as the board is switched off after that opening (a user pressing
Ctrl-C again meanwhile). MARKER_FILE.signals counts the signals the run has handled
(:mod:`tests.rig.handled_signals`).
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

from rig import cli, station
from rig.clock import MonotonicClock
from rig.config import RigConfig
from tests.rig.fakes import make_fake_rig
from tests.rig.handled_signals import report_handled_signals


def main() -> None:
    config, state_file, marker_file, delay_s, *rest = sys.argv[1:]
    rig = make_fake_rig(clock=MonotonicClock(), state_file=Path(state_file), warmup_tau_s=0.02)
    rig.camera.marker_file = Path(marker_file)
    rig.camera.io.delay_s["capture"] = float(delay_s)
    station.STATION_BUILDERS["twin"] = rig.builder
    report_handled_signals(Path(f"{marker_file}.signals"))
    if rest:
        open_delay_s = float(rest[0])
        ctrl_c_in_release = rest[1:] == ["ctrl-c-in-release"]
        switch_all_off = rig.relays.all_off

        def all_off_with_a_ctrl_c() -> None:
            os.kill(os.getpid(), signal.SIGINT)
            switch_all_off()

        rig.relays.bank.set_channel(1, True)
        rig.relays.set(1, True)  # writes the state file: "10"

        def slow_builder(
            config: RigConfig, transcripts: station.TranscriptFactory
        ) -> station.Station:
            opened = rig.builder(config, transcripts)
            Path(f"{marker_file}.opening").write_text("")
            time.sleep(open_delay_s)
            if ctrl_c_in_release:  # the next switching off is the release of this opening
                setattr(rig.relays, "all_off", all_off_with_a_ctrl_c)  # noqa: B010
            return opened

        station.STATION_BUILDERS["twin"] = slow_builder
    sys.argv = ["rig", "capture", "--config", config, "--quiet"]
    cli.main()


if __name__ == "__main__":
    main()
