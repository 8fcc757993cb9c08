"""The digital twin as a station: the simulated bench behind the rig's real logic, through a typed seam.

The rig never imports ``mocks`` (the twin is optional, and the layering keeps test doubles out of
the rig). What it needs of the simulated bench is the :class:`DigitalTwin` protocol; the
implementation is found through the ``spectral_rig.twin`` entry point that the package declares
(``mocks.bench.seam:BENCH``), so the dependency is written down in ``pyproject.toml`` and checked by
mypy here, not hidden in a module-name string. The rig hands the bench its configuration as plain
data (``RigConfig.model_dump(mode="json")``) and wraps the open bench into a
:class:`rig.station_devices.Station` with the real frame analyser, as the hardware station does;
the bench's emulators stop when the station closes.

Tests reach the bench's fault injection through :func:`twin_station_builder` (faults armed at
open, and a callback that receives the open bench for later injections).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Mapping
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol

from calib.core.mapping import GratingGeometry
from calib.core.spectra import MultiSpectrum, Spectrum
from drivers.base import Camera, RelayBoard, Spectrometer
from rig.clock import Clock
from rig.config import RigConfig
from rig.errors import StationUnavailable
from rig.frame_stats import RawFrameAnalyzer
from rig.hardware import open_configured_camera, open_configured_spectrometer, watched_relays
from rig.operator import ScriptedOperator
from rig.station_devices import Station, StationBuilder, TranscriptFactory

__all__ = [
    "TWIN_ENTRY_POINT",
    "DigitalTwin",
    "TwinBenchHandle",
    "TwinConfigError",
    "TwinTruthRecord",
    "digital_twin",
    "open_twin_bench",
    "open_twin_station",
    "read_twin_truth",
    "station_of",
    "twin_station_builder",
    "write_twin_truth",
]

TWIN_ENTRY_POINT = ("spectral_rig.twin", "bench")
"""Entry-point group and name of the :class:`DigitalTwin` implementation."""


class TwinBenchHandle(Protocol):
    """An open simulated bench: the drivers the rig uses, on the bench's clock.

    ``spectrometer`` and ``camera`` are ``None`` where the rig's own instrument plays the role.
    """

    @property
    def relays(self) -> RelayBoard: ...

    @property
    def spectrometer(self) -> Spectrometer | None: ...

    @property
    def camera(self) -> Camera | None: ...

    @property
    def clock(self) -> Clock: ...

    def begin_step(self, key: str) -> None:
        """The rig is about to do step ``key`` (the bench keys its noise by it)."""

    def aim_spectrometer(self, beam: str, angle_deg: float) -> None:
        """Turn the twin's spectrometer to ``beam`` (``lamp``, ``direct``, ``order0``, ``order1``
        ``angle_deg`` from the 0th order): what a person does on a real bench."""

    def close(self) -> None:
        """Stop the emulators (the drivers are closed by the station)."""


class TwinTruthRecord(Protocol):
    """What the twin knows about its camera: what an estimate is judged against."""

    @property
    def camera(self) -> str: ...

    @property
    def seed(self) -> int: ...

    @property
    def sensitivity(self) -> MultiSpectrum: ...

    @property
    def grating_efficiency(self) -> Spectrum: ...

    @property
    def zeroth_order_efficiency(self) -> Spectrum: ...

    @property
    def mapping(self) -> GratingGeometry: ...

    @property
    def spectrometer(self) -> Mapping[str, Any] | None:
        """The emulated spectrometer and its in-spec scale/slit errors (``None``: real)."""

    @property
    def camera_flaws(self) -> Mapping[str, Any] | None:
        """The twin camera's stray light along the band and shutter error (``None``: none)."""


class DigitalTwin(Protocol):
    """What the rig needs of the simulated bench.

    Attributes
    ----------
    config_error
        Raised by :meth:`open` and :meth:`write_truth` for configuration data the twin cannot
        build (the message names the field).
    truth_error
        Raised by :meth:`read_truth` for a file that is not a truth record.
    truth_file_name
        The name of the truth file next to a session's log (``twin-truth.json``).
    """

    config_error: type[Exception]
    truth_error: type[Exception]
    truth_file_name: str

    def open(
        self,
        config_data: Mapping[str, Any],
        transcripts: Callable[[str], Any] | None,
        *,
        faults: Any = None,
        prepare: bool = True,
    ) -> TwinBenchHandle:
        """Open the bench of the configuration; ``prepare`` renders the lamps' images now."""

    def write_truth(self, config_data: Mapping[str, Any], directory: Path) -> Path:
        """Write the truth of the configuration's twin camera into ``directory``."""

    def read_truth(self, path: Path) -> TwinTruthRecord:
        """Read a truth file."""


@functools.cache
def digital_twin() -> DigitalTwin:
    """The installed digital twin (the ``spectral_rig.twin`` entry point), loaded once.

    Raises
    ------
    StationUnavailable
        This installation has no twin.
    """
    group, name = TWIN_ENTRY_POINT
    found = [point for point in entry_points(group=group) if point.name == name]
    if not found:
        raise StationUnavailable(
            f"the digital twin is not part of this installation (no {group!r} entry point "
            f"{name!r}: install the package with `pip install 'spectral-rig[sim]'`), or "
            "configure real devices instead of kind: twin"
        )
    try:
        twin: DigitalTwin = found[0].load()
    except ImportError as exc:
        raise StationUnavailable(
            f"the digital twin needs the simulation extra: `pip install 'spectral-rig[sim]'` ({exc})"
        ) from None
    return twin


class TwinConfigError(StationUnavailable):
    """The configuration cannot be simulated (unknown camera or illuminant, a layout that does not
    fit the sensor): the user must change a field, named in the message."""

    reason = "twin_config"
    exit_code = 2


def _config_error(exc: Exception) -> TwinConfigError:
    return TwinConfigError(f"the digital twin cannot be built: {exc}")


def open_twin_bench(
    config: RigConfig,
    transcripts: TranscriptFactory | None = None,
    *,
    faults: Any = None,
    prepare: bool = True,
) -> TwinBenchHandle:
    """Open the simulated bench of ``config`` (``prepare``: render the lamps' images now).

    Raises
    ------
    TwinConfigError
        The configuration cannot be simulated.
    """
    twin = digital_twin()
    try:
        return twin.open(
            config.model_dump(mode="json"),
            transcripts,  # type: ignore[arg-type]  # roles are the twin's strings
            faults=faults,
            prepare=prepare,
        )
    except twin.config_error as exc:
        raise _config_error(exc) from None


def station_of(twin: TwinBenchHandle, config: RigConfig, transcripts: TranscriptFactory) -> Station:
    """Wrap an open bench into a station with the real frame analyser; the roles the twin does
    not play (a real camera, a real spectrometer) are opened on their hardware
    (:mod:`rig.hardware`). If one fails to open, the bench and what was opened are closed."""
    opened: list[Any] = []
    relays = watched_relays(config, twin.relays)
    try:
        spectrometer = twin.spectrometer
        if spectrometer is None:
            spectrometer = open_configured_spectrometer(
                config.devices.spectrometer,
                transcripts("spectrometer"),
                relays=relays,
                lamps=config.lamps,
            )
            opened.append(spectrometer)
        camera = twin.camera
        if camera is None:
            camera = open_configured_camera(config.devices.camera, transcripts("camera"))
    except BaseException:
        for device in (*opened, twin.relays):
            with contextlib.suppress(Exception):
                device.close()
        twin.close()
        raise
    station = Station(
        spectrometer,
        camera,
        relays,
        twin.clock,
        RawFrameAnalyzer(),
        on_close=[twin.close],
        step_hook=twin.begin_step,
    )
    if twin.spectrometer is not None:
        # The twin's own spectrometer is aimed by the twin's hands; a real one by a person.
        station.operator = ScriptedOperator(
            act=lambda action: twin.aim_spectrometer(action.beam, action.angle_deg)
        )
    return station


def open_twin_station(config: RigConfig, transcripts: TranscriptFactory) -> Station:
    """The station builder for a configuration with twin devices (see
    :data:`rig.station.STATION_BUILDERS`): the twin's lamps, and its spectrometer and camera
    where the configuration says ``twin``."""
    return station_of(open_twin_bench(config, transcripts), config, transcripts)


def twin_station_builder(
    *, faults: Any = None, on_open: Callable[[Any], None] | None = None
) -> StationBuilder:
    """A station builder for tests: faults armed at open (``mocks.bench.TwinFaults``), and
    ``on_open`` called with the open bench (to inject faults later or inspect it)."""

    def build(config: RigConfig, transcripts: TranscriptFactory) -> Station:
        twin = open_twin_bench(config, transcripts, faults=faults)
        if on_open is not None:
            on_open(twin)
        return station_of(twin, config, transcripts)

    return build


def write_twin_truth(config: RigConfig, directory: Path) -> Path:
    """Write the twin's ``twin-truth.json`` for ``config`` into ``directory``; return its path."""
    twin = digital_twin()
    try:
        return twin.write_truth(config.model_dump(mode="json"), directory)
    except twin.config_error as exc:
        raise _config_error(exc) from None


def read_twin_truth(path: Path) -> TwinTruthRecord:
    """A twin truth file (``twin.truth_error`` when it is not one)."""
    return digital_twin().read_truth(path)
