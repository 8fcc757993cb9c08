"""Starts the fake ``spotread`` (:mod:`mocks.fake_spotread`) where the driver would start the real one.

:class:`FakeSpotreadLauncher` is a :class:`drivers.spectrometer.argyll.SpotreadLauncher`: the driver
asks it to run ``spotread -a -s -N -O reading.sp``; it writes the scene of this run (what the
instrument reads, or the fault it shows: ``scene()``) to a JSON file, points the fake at it through
``$FAKE_SPOTREAD_SCENE`` and runs the fake with this Python on a pseudo-terminal, with the driver's
own arguments. The driver's transcript still shows ``spotread`` and its arguments, as on a real rig.
"""

from __future__ import annotations

import json
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from drivers.spectrometer.argyll import PtyLauncher, SpotreadProcess

__all__ = ["FAKE_SPOTREAD", "FakeSpotreadLauncher", "fake_spotread_command"]

FAKE_SPOTREAD = Path(__file__).with_name("fake_spotread.py")
"""The fake executable."""
SCENE_VARIABLE = "FAKE_SPOTREAD_SCENE"


def fake_spotread_command(arguments: Sequence[str]) -> list[str]:
    """The command line running the fake with ``arguments`` (spotread's, without its name)."""
    return [sys.executable, str(FAKE_SPOTREAD), *arguments]


class FakeSpotreadLauncher:
    """Runs the fake spotread on a pseudo-terminal with the scene ``scene()`` returns per run.

    Parameters
    ----------
    scene
        Called once per run: the scene's JSON-able data (see :mod:`mocks.fake_spotread`).
    scratch
        Where the scene files go (default: a temporary directory of its own, removed by
        :meth:`close`).
    """

    def __init__(self, scene: Callable[[], Mapping[str, Any]], scratch: Path | None = None) -> None:
        self.scene = scene
        self._temporary = None if scratch is not None else tempfile.TemporaryDirectory()
        self.scratch = scratch if scratch is not None else Path(self._temporary.name)  # type: ignore[union-attr]
        self.runs: list[list[str]] = []

    def launch(self, argv: Sequence[str], cwd: Path) -> SpotreadProcess:
        path = self.scratch / f"scene-{len(self.runs):04d}.json"
        path.write_text(json.dumps(dict(self.scene())), encoding="utf-8")
        self.runs.append(list(argv))
        launcher = PtyLauncher({SCENE_VARIABLE: str(path)})
        return launcher.launch(fake_spotread_command(argv[1:]), cwd)

    def close(self) -> None:
        """Remove the scene files."""
        if self._temporary is not None:
            self._temporary.cleanup()
