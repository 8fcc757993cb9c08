"""The open devices a run works with: :class:`Station` (the three devices, their clock, the frame
analyser). Builders that open one are in :mod:`rig.station`; this module is their common ground
(the hardware and the twin builders import it, and :mod:`rig.station` imports them).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from drivers.base import Camera, RelayBoard, Spectrometer, TranscriptSink
from rig.analysis import FrameAnalyzer
from rig.clock import Clock
from rig.config import RigConfig
from rig.frame_stats import frame_exposure_s
from rig.operator import ConsoleOperator, Operator
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
    hardware needs nothing). ``operator`` does the plan's manual actions (:mod:`rig.operator`; a
    person at the terminal by default).
    """

    spectrometer: Spectrometer
    camera: Camera
    relays: RelayBoard
    clock: Clock
    analyzer: FrameAnalyzer
    on_close: list[Callable[[], None]] = field(default_factory=list)
    frame_exposure: Callable[[Path], float | None] | None = frame_exposure_s
    step_hook: Callable[[str], None] | None = None
    operator: Operator = field(default_factory=ConsoleOperator)
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
"""Opens a station from the configuration, each device recording into its transcript."""
