"""The digital twin as a station: the simulated bench of ``mocks.bench`` behind the rig's real logic.

``rig`` never imports ``mocks`` statically (the twin is optional, and the layering keeps test doubles
out of the rig); this module loads ``mocks.bench`` when the twin is asked for, hands it the
configuration as plain data (``RigConfig.model_dump(mode="json")``) and wraps the open bench into a
:class:`rig.station.Station` with the real frame analyser, exactly as the hardware station does.
The bench's emulators stop when the station closes.

Tests reach the bench's fault injection through :func:`twin_station_builder` (faults armed at
open, and a callback that receives the open bench for later injections).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from rig.config import RigConfig
from rig.errors import StationUnavailable
from rig.frame_stats import RawFrameAnalyzer
from rig.hardware import open_configured_camera, open_configured_spectrometer, watched_relays
from rig.station import Station, StationBuilder, TranscriptFactory, optional_module

BENCH_MODULE = "mocks.bench"


def bench_module() -> ModuleType:
    """``mocks.bench``, imported now.

    Raises
    ------
    StationUnavailable
        When this installation has no ``mocks`` package.
    """
    return optional_module(
        BENCH_MODULE,
        f"the digital twin ({BENCH_MODULE})",
        "; configure real devices instead of kind: twin",
    )


def twin_spec(config: RigConfig) -> Any:
    """The ``mocks.bench.TwinSpec`` of a configuration whose devices are ``twin``.

    Raises
    ------
    TwinConfigError
        When the configuration cannot be simulated (unknown camera or illuminant, a layout that
        does not fit the sensor); the message names the field.
    """
    bench = bench_module()
    try:
        return bench.TwinSpec.from_config_data(config.model_dump(mode="json"))
    except bench.TwinSpecError as exc:
        raise _config_error(exc) from None


class TwinConfigError(StationUnavailable):
    """The configuration cannot be simulated (unknown camera or illuminant, a layout that does not
    fit the sensor): the user must change a field, named in the message."""

    reason = "twin_config"
    exit_code = 2


def _config_error(exc: Exception) -> TwinConfigError:
    return TwinConfigError(f"the digital twin cannot be built: {exc}")


def open_twin_bench(
    config: RigConfig, transcripts: TranscriptFactory | None = None, *, faults: Any = None
) -> Any:
    """Open the simulated bench (a ``mocks.bench.TwinBench``) of ``config``."""
    bench = bench_module()
    spec = twin_spec(config)
    try:
        return bench.open_twin(spec, transcripts, faults=faults)
    except bench.TwinSpecError as exc:
        raise _config_error(exc) from None


def station_of(twin: Any, config: RigConfig, transcripts: TranscriptFactory) -> Station:
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
    return Station(
        spectrometer,
        camera,
        relays,
        twin.clock,
        RawFrameAnalyzer(),
        on_close=[twin.close],
        step_hook=twin.begin_step,
    )


def open_twin_station(config: RigConfig, transcripts: TranscriptFactory) -> Station:
    """The station builder for a configuration with twin devices (see
    :data:`rig.station.STATION_BUILDERS`): the twin's lamps, and its spectrometer and camera
    where the configuration says ``twin``."""
    return station_of(open_twin_bench(config, transcripts), config, transcripts)


def twin_station_builder(
    *, faults: Any = None, on_open: Callable[[Any], None] | None = None
) -> StationBuilder:
    """A station builder for tests: faults armed at open (``mocks.bench.TwinFaults``), and
    ``on_open`` called with the open ``TwinBench`` (to inject faults later or inspect it)."""

    def build(config: RigConfig, transcripts: TranscriptFactory) -> Station:
        twin = open_twin_bench(config, transcripts, faults=faults)
        if on_open is not None:
            on_open(twin)
        return station_of(twin, config, transcripts)

    return build


def write_twin_truth(config: RigConfig, directory: Path) -> Path:
    """Write the twin's ``twin-truth.json`` for ``config`` into ``directory``; return its path."""
    bench = bench_module()
    spec = twin_spec(config)
    try:
        optics = bench.TwinOptics.build(spec.camera)
    except bench.TwinSpecError as exc:
        raise _config_error(exc) from None
    path: Path = bench.TwinTruth.of(optics, spec.seed).write(directory)
    return path
