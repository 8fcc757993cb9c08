"""Input sets for the batch tests that misbehave in their worker (imported by spawned workers, so
kept light)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from calib.pipeline.input_sets import InputSet
from calib.pipeline.inputs import LampImages


class CrashingReader:
    """Input sets named ``crash*`` kill their worker; the others fail at once (a missing frame)."""

    kind = "test"
    description = "a test set"

    def recognises(self, path: Path) -> bool:
        return True

    def default_out_name(self, path: Path) -> str:
        return path.name

    def read(self, path: Path, out_dir: Path | None, *, force: bool) -> InputSet:
        if path.name.startswith("crash"):
            os._exit(3)
        lamp = LampImages("LED", "led", path / "led.csv", (path / "missing.dng",))
        return InputSet(path.name, (lamp,), out_dir or path / "out")


CRASHING_READER = CrashingReader()


class KillsOnArrival:
    """Kills the process that unpickles it: a worker that dies before any job starts."""

    def __reduce__(self) -> tuple[Any, tuple[int]]:
        return os._exit, (4,)
