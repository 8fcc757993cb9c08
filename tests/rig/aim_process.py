"""``rig capture`` in a child process on the twin, whose operator is slow at one aim (to be killed).

Usage: ``python -m tests.rig.aim_process CONFIG KEY MARKER``. At the ``AimSpectrometer`` step
``KEY`` the twin's hands first create the file MARKER, then take 120 s of wall time (a person who
walked away), so that a test can ``kill -9`` the run while the spectrometer is being re-aimed with
the lamp on. The relays keep their state in the configuration's ``devices.relays.state_file``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from rig import cli, station
from rig.config import RigConfig
from rig.operator import ManualAction, ScriptedOperator
from rig.station_devices import Station, TranscriptFactory
from rig.twin import twin_station_builder


def main() -> None:
    config, key, marker = sys.argv[1:]
    twin = twin_station_builder()

    def build(rig_config: RigConfig, transcripts: TranscriptFactory) -> Station:
        opened = twin(rig_config, transcripts)
        hands = opened.operator
        assert isinstance(hands, ScriptedOperator) and hands.act is not None
        act = hands.act

        def slow(action: ManualAction) -> None:
            if action.key == key:
                Path(marker).touch()
                time.sleep(120.0)
            act(action)

        opened.operator = ScriptedOperator(act=slow)
        return opened

    station.STATION_BUILDERS["twin"] = build
    sys.argv = ["rig", "capture", "--config", config, "--quiet"]
    cli.main()


if __name__ == "__main__":
    main()
