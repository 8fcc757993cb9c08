"""Open the digital twin's station of a configuration and close it again: what a capture pays
before its first step (imports, lamp spectra, camera optics, the lamps' noiseless images, the
emulators and drivers). Time it from outside, whole process:

    python bench/twin_station_open.py [--config config.yaml] [--imports-only]

``--imports-only`` stops after the imports, so the two can be told apart.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from drivers.base import ListTranscript
from rig.config import load_config
from rig.station import open_station


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", type=Path, default=Path("config.yaml"))
    parser.add_argument("--imports-only", action="store_true")
    args = parser.parse_args()
    if args.imports_only:
        return
    transcript = ListTranscript()
    station = open_station(load_config(args.config), lambda role: transcript)
    station.close()


if __name__ == "__main__":
    main()
