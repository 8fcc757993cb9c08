"""Progress of the offline pipeline: the protocol it reports to, and a rich progress bar."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, TextIO

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn


class OfflineProgress(Protocol):
    """Receives the pipeline's progress (a progress bar, a log, a test)."""

    def start(self, total_frames: int) -> None:
        """The pipeline will merge ``total_frames`` RAW frames (0 for profile input)."""

    def frame_done(self, lamp: str, path: Path) -> None:
        """One frame of ``lamp`` is decoded and merged."""

    def stage(self, description: str) -> None:
        """A new stage begins (``"detecting the geometry on LED-B3"``, ``"estimating"`` …)."""


class NoProgress:
    """An :class:`OfflineProgress` that shows nothing."""

    def start(self, total_frames: int) -> None:
        pass

    def frame_done(self, lamp: str, path: Path) -> None:
        pass

    def stage(self, description: str) -> None:
        pass


class RichFrameProgress:
    """A rich progress bar (on ``stream``, e.g. stderr): frames merged, then the stages.

    Use as a context manager; it implements :class:`OfflineProgress`.
    """

    def __init__(self, stream: TextIO) -> None:
        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=Console(file=stream),
        )
        self._task = self._progress.add_task("checking inputs", total=None)

    def __enter__(self) -> RichFrameProgress:
        self._progress.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        if kind is not None:  # the error message follows; leave no half-filled bar above it
            self._progress.update(self._task, visible=False)
        self._progress.stop()

    @staticmethod
    def wanted(stream: TextIO) -> bool:
        """Whether ``stream`` is a terminal (a progress bar in a log file is only noise)."""
        isatty = getattr(stream, "isatty", None)
        return bool(isatty is not None and isatty())

    def start(self, total_frames: int) -> None:
        self._progress.update(self._task, total=total_frames or None, completed=0)

    def frame_done(self, lamp: str, path: Path) -> None:
        self._progress.update(self._task, advance=1, description=f"{lamp}: merged {path.name}")

    def stage(self, description: str) -> None:
        self._progress.update(self._task, description=description)
