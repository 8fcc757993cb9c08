"""Progress of a run: a rich progress bar (lamp, frame k of ~n, ETA), or silence.

The runner reports to a :class:`ProgressReporter`. :class:`RichProgress` measures progress in
*modelled seconds* (:class:`rig.dryrun.StepCostModel`), so a ten-second warm-up wait advances the bar
more than a relay click and the ETA is meaningful; the plan's modelled walk gives the total, which
grows if the real bracket needs more frames than modelled.
"""

from __future__ import annotations

from typing import Protocol

from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    SpinnerColumn,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from rig.dryrun import DryRunReport, StepCostModel
from rig.steps import AnyStep, Capture, StepResult


class ProgressReporter(Protocol):
    """Receives the runner's progress events."""

    def start(self, estimate: DryRunReport | None) -> None: ...

    def step_started(self, step: AnyStep) -> None: ...

    def step_done(self, step: AnyStep, result: StepResult) -> None: ...

    def message(self, text: str) -> None: ...

    def finish(self, completed: bool) -> None: ...


class SilentProgress:
    """Reports nothing (``--quiet``, tests)."""

    def start(self, estimate: DryRunReport | None) -> None:
        """Nothing."""

    def step_started(self, step: AnyStep) -> None:
        """Nothing."""

    def step_done(self, step: AnyStep, result: StepResult) -> None:
        """Nothing."""

    def message(self, text: str) -> None:
        """Nothing."""

    def finish(self, completed: bool) -> None:
        """Nothing."""


class RichProgress:
    """A progress bar on ``console`` (stderr by default); messages print above it."""

    def __init__(self, cost: StepCostModel, console: Console | None = None) -> None:
        self.cost = cost
        self.console = console or Console(stderr=True)
        self._progress = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.percentage:>3.0f}%"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=self.console,
            transient=False,
        )
        self._task: TaskID | None = None
        self._total_s = 0.0
        self._done_s = 0.0
        self._frames_per_lamp: dict[str, int] = {}

    def start(self, estimate: DryRunReport | None) -> None:
        self._total_s = max(estimate.duration_s if estimate else 0.0, 1e-3)
        self._frames_per_lamp = estimate.frames_per_lamp() if estimate else {}
        self._progress.start()
        self._task = self._progress.add_task("starting", total=self._total_s)

    def _describe(self, step: AnyStep) -> str:
        text = step.describe()
        if isinstance(step, Capture):
            modelled = self._frames_per_lamp.get(step.lamp)
            if modelled and step.index < modelled:
                text = text.replace(
                    f"frame {step.index + 1}", f"frame {step.index + 1} of ~{modelled}"
                )
        return text

    def step_started(self, step: AnyStep) -> None:
        if self._task is not None:
            self._progress.update(self._task, description=self._describe(step))

    def step_done(self, step: AnyStep, result: StepResult) -> None:
        if self._task is None:
            return
        self._done_s += self.cost.duration_s(step)
        if self._done_s > self._total_s:
            self._total_s = self._done_s * 1.05
        self._progress.update(self._task, completed=self._done_s, total=self._total_s)

    def message(self, text: str) -> None:
        self._progress.console.print(text, markup=False, highlight=False)

    def finish(self, completed: bool) -> None:
        """Stop the bar: full when the plan completed, where it stopped otherwise."""
        if self._task is not None:
            if completed:
                self._progress.update(self._task, description="done", completed=self._total_s)
            else:
                self._progress.update(self._task, description="stopped")
        self._progress.stop()
