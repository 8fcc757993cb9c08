"""The one place where configured devices become objects: real drivers, or the digital twin.

A :class:`Station` (defined in :mod:`rig.station_devices`) is what the runner works with: the three
devices (any objects satisfying the ``drivers.base`` protocols), the clock their time runs on, and
the frame analyser. A *station builder* makes one from the configuration; :data:`STATION_BUILDERS`
holds the builder for real hardware (:func:`rig.hardware.open_hardware_station`) and for a
configuration with twin devices (:func:`rig.twin.open_twin_station`, which reaches the simulated
bench through its typed seam, never by importing ``mocks``). Tests register their own builders here.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from rig.config import RigConfig
from rig.errors import StationUnavailable
from rig.hardware import open_hardware_station
from rig.station_devices import (
    CLOSE_ORDER,
    DeviceCall,
    Station,
    StationBuilder,
    TranscriptFactory,
)
from rig.twin import digital_twin, open_twin_station

__all__ = [
    "CLOSE_ORDER",
    "STATION_BUILDERS",
    "DeviceCall",
    "Station",
    "StationBuilder",
    "TranscriptFactory",
    "open_station",
    "optional_module",
    "resolve_builder",
    "station_kind",
]

STATION_BUILDERS: dict[str, StationBuilder] = {
    "hardware": open_hardware_station,
    "twin": open_twin_station,
}
"""Builders by station kind."""


def station_kind(config: RigConfig) -> str:
    """``"twin"`` when any device is simulated, else ``"hardware"``."""
    return "twin" if config.devices.simulated else "hardware"


def optional_module(name: str, what: str, hint: str = "") -> ModuleType:
    """Import ``name``, an optional part of the installation (session replay).

    Raises
    ------
    StationUnavailable
        When the module (or its package) is not installed: "<what> is not part of this
        installation<hint>". An import error inside it propagates.
    """
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and name.startswith(exc.name):
            raise StationUnavailable(f"{what} is not part of this installation{hint}") from None
        raise


def resolve_builder(kind: str) -> StationBuilder:
    """The builder registered for ``kind``; for the twin's, the twin is looked up now, so that an
    installation without it says so before a session is created.

    Raises
    ------
    StationUnavailable
        No builder for ``kind``, or the digital twin is not installed.
    """
    builder = STATION_BUILDERS.get(kind)
    if builder is None:
        raise StationUnavailable(
            f"no station builder for {kind!r}; known: {sorted(STATION_BUILDERS)}"
        )
    if builder is open_twin_station:
        digital_twin()
    return builder


def open_station(config: RigConfig, transcripts: TranscriptFactory) -> Station:
    """Open the configured devices (real or twin), each recording its exchanges to ``transcripts``."""
    return resolve_builder(station_kind(config))(config, transcripts)
