"""Replays a recorded spotread run: the driver's command line was checked by the transcript sink;
the terminal serves the recorded output chunk by chunk (an empty chunk ends it, nothing left
before the run's end is silence), and the run ends with the recorded exit status and spectrum
file."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from drivers.spectrometer.argyll import SpotreadProcess
from mocks.replay.script import ReplayScript

__all__ = ["ReplaySpotreadLauncher"]


class _ReplayedRun:
    def __init__(self, script: ReplayScript) -> None:
        self._script = script
        self._file: str | None = None

    def _next(self) -> str | None:
        served = self._script.peek_answer()
        return None if served is None else served.entry.direction

    def read(self, timeout_s: float) -> bytes | None:
        if self._next() != "rx":
            return None  # the recorded run printed nothing more before it was ended
        return self._script.take("spotread's output").entry.payload

    def write(self, data: bytes) -> None:
        """The keys were checked against the recording by the transcript sink."""

    def wait(self, timeout_s: float) -> int | None:
        self._next()
        served = self._script.take("spotread's exit")
        try:
            ended = json.loads(served.entry.payload)
            status, text = ended["status"], ended["file"]
        except (ValueError, KeyError, TypeError):
            raise self._script.fail(
                "the recorded spotread exit is not readable", index=served.line
            ) from None
        self._file = None if text is None else str(text)
        return None if status is None else int(status)

    def kill(self) -> None:
        """Nothing runs."""

    def output(self, cwd: Path) -> str | None:
        return self._file


class ReplaySpotreadLauncher:
    """Starts replayed spotread runs from one spectrometer transcript."""

    def __init__(self, script: ReplayScript) -> None:
        self._script = script

    def launch(self, argv: Sequence[str], cwd: Path) -> SpotreadProcess:
        return _ReplayedRun(self._script)
