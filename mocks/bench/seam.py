"""The digital twin as the rig sees it: :data:`BENCH` implements ``rig.twin.DigitalTwin``.

The package declares it as the ``spectral_rig.twin`` entry point (``pyproject.toml``), which is
how the rig finds the twin without importing ``mocks``. Everything crosses as plain data: the rig's
configuration dumped to JSON-able values, a transcript factory, paths.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from drivers.base import TranscriptSink
from mocks.bench.deviation import spectrometer_truth
from mocks.bench.flaws import camera_flaws
from mocks.bench.optics import TwinOptics
from mocks.bench.spec import TwinSpec, TwinSpecError
from mocks.bench.station import TwinBench, TwinFaults, open_twin
from mocks.bench.truth import TRUTH_FILE_NAME, TruthFormatError, TwinTruth

__all__ = ["BENCH", "BenchSeam"]


class BenchSeam:
    """Opens :class:`mocks.bench.station.TwinBench` benches and reads and writes their truth."""

    config_error: type[Exception] = TwinSpecError
    truth_error: type[Exception] = TruthFormatError
    truth_file_name: str = TRUTH_FILE_NAME

    def open(
        self,
        config_data: Mapping[str, Any],
        transcripts: Callable[[str], TranscriptSink] | None,
        *,
        faults: TwinFaults | None = None,
        prepare: bool = True,
    ) -> TwinBench:
        return open_twin(
            TwinSpec.from_config_data(config_data), transcripts, faults=faults, prepare=prepare
        )

    def write_truth(self, config_data: Mapping[str, Any], directory: Path) -> Path:
        spec = TwinSpec.from_config_data(config_data)
        flaws = camera_flaws(spec)
        optics = TwinOptics.build(spec.twin_camera, flaws)
        return TwinTruth.of(optics, spec.seed, spectrometer_truth(spec), flaws).write(directory)

    def read_truth(self, path: Path) -> TwinTruth:
        return TwinTruth.read(path)


BENCH = BenchSeam()
"""The twin the rig opens (entry point ``spectral_rig.twin``: ``bench``)."""
