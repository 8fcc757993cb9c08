"""For the child-process signal tests: the run's interrupt controller says when it has handled a
signal, so a test sends the next only then.

The OS keeps one pending signal of a kind: a second Ctrl-C sent before the process has handled the
first (a loaded machine may not run it for a while) merges into it, and the test would see one.
:func:`report_handled_signals` makes every capture in this process use a controller that writes
the number of signals it has handled to a file after each; :func:`send_one_at_a_time` sends a list
of signals, each after the previous one was handled.
"""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path
from types import FrameType

from rig import capture
from rig.interrupts import InterruptController
from tests.rig.fakes import wait_for


class ReportingInterruptController(InterruptController):
    """The rig's controller, writing how many signals it has handled to ``report`` after each."""

    def __init__(self, report: Path) -> None:
        super().__init__()
        self._report = report

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        try:
            super()._handle(signum, frame)
        finally:
            self._report.write_text(str(len(self.received)))


def report_handled_signals(report: Path) -> None:
    """Every capture (and resume) this process runs reports its handled signals to ``report``."""
    setattr(capture, "InterruptController", lambda: ReportingInterruptController(report))  # noqa: B010


def handled(report: Path) -> int:
    """How many signals the child has handled so far."""
    text = report.read_text() if report.exists() else ""
    return int(text) if text else 0


def send_one_at_a_time(
    process: subprocess.Popen[str], signals: list[signal.Signals], report: Path
) -> None:
    """Send ``signals`` to ``process``, each once the child has handled the ones before it (or
    has ended: the test then sees how)."""
    already = handled(report)
    for number, signum in enumerate(signals):
        if number:
            wait_for(
                lambda number=number: (
                    handled(report) >= already + number or process.poll() is not None
                ),
                timeout_s=60,
                what=f"the child to handle signal {number}",
            )
        process.send_signal(signum)
