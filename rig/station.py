"""The one place where configured devices become objects: real drivers, or the digital twin.

A :class:`Station` is what the runner works with: the three devices (any objects satisfying the
``drivers.base`` protocols), the clock their time runs on, and the frame analyser. A *station
builder* makes one from the configuration; :data:`STATION_BUILDERS` names the builder for real
hardware and for the twin (``devices.*.kind: twin``) as ``"module:function"`` strings, imported only
when used, so the rig core never imports ``mocks`` and a missing optional part fails with a clear
message rather than at import time. Tests register their own builders here.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

from drivers.base import Camera, RelayBoard, Spectrometer, TranscriptSink
from rig.analysis import FrameAnalyzer
from rig.clock import Clock
from rig.config import RigConfig
from rig.errors import StationUnavailable
from rig.frame_stats import frame_exposure_s
from rig.steps import DeviceRole

TranscriptFactory = Callable[[DeviceRole], TranscriptSink]
"""Gives the transcript sink for a device role; the session's ``transcripts/<role>.jsonl``."""

DeviceCall = Callable[[DeviceRole, Callable[[], None]], object]
"""Runs a device's method on behalf of the station (the runner passes its deadline-guarded call)."""

CLOSE_ORDER: tuple[DeviceRole, ...] = ("camera", "spectrometer", "relays")


@dataclass
class Station:
    """Open devices, their clock and the frame analyser.

    ``on_close`` callables run after the devices are closed (e.g. the twin stops its emulators).
    ``frame_exposure`` reads the exposure a frame file's own metadata records (``None`` when it
    cannot tell), for the stale-frame check; the default reads RAW metadata
    (:func:`rig.frame_stats.frame_exposure_s`), ``None`` skips the check. ``step_hook`` is told the
    key of every step attempt before it touches a device (the twin keys its noise by it; real
    hardware needs nothing).
    """

    spectrometer: Spectrometer
    camera: Camera
    relays: RelayBoard
    clock: Clock
    analyzer: FrameAnalyzer
    on_close: list[Callable[[], None]] = field(default_factory=list)
    frame_exposure: Callable[[Path], float | None] | None = frame_exposure_s
    step_hook: Callable[[str], None] | None = None
    closed: bool = False

    def device(self, role: DeviceRole) -> Spectrometer | Camera | RelayBoard:
        match role:
            case "spectrometer":
                return self.spectrometer
            case "camera":
                return self.camera
            case "relays":
                return self.relays

    def close(self, call: DeviceCall | None = None) -> None:
        """Close every device (through ``call`` if given), then run the close hooks; once only.

        Errors on the way are suppressed: closing must not stop the others from closing.
        """
        if self.closed:
            return
        self.closed = True
        for role in CLOSE_ORDER:
            close = self.device(role).close
            with contextlib.suppress(Exception):
                if call is None:
                    close()
                else:
                    call(role, close)
        for hook in self.on_close:
            with contextlib.suppress(Exception):
                hook()


StationBuilder = Callable[[RigConfig, TranscriptFactory], Station]

STATION_BUILDERS: dict[str, StationBuilder | str] = {
    "hardware": "rig.hardware:open_hardware_station",
    "twin": "rig.twin:open_twin_station",
}
"""Builders by station kind: a callable, or ``"module:function"`` imported on first use."""


def station_kind(config: RigConfig) -> str:
    """``"twin"`` when the devices are simulated, else ``"hardware"``."""
    return "twin" if config.devices.simulated else "hardware"


def optional_module(name: str, what: str, hint: str = "") -> ModuleType:
    """Import ``name``, an optional part of the installation (the twin, replay).

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
    """The builder registered for ``kind``, importing it if given by name."""
    entry = STATION_BUILDERS.get(kind)
    if entry is None:
        raise StationUnavailable(
            f"no station builder for {kind!r}; known: {sorted(STATION_BUILDERS)}"
        )
    if callable(entry):
        return entry
    module_name, _, function_name = entry.partition(":")
    module = optional_module(module_name, f"the {kind} station ({entry})")
    builder = getattr(module, function_name, None)
    if not callable(builder):
        raise StationUnavailable(f"{module_name} has no station builder {function_name!r}")
    return builder  # type: ignore[no-any-return]


def open_station(config: RigConfig, transcripts: TranscriptFactory) -> Station:
    """Open the configured devices (real or twin), each recording its exchanges to ``transcripts``."""
    return resolve_builder(station_kind(config))(config, transcripts)
