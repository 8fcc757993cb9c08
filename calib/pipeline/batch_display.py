"""Showing a batch: its progress (input sets done, failures named as they happen) and its summary,
one row per input set, on the terminal, in Markdown and in CSV.

The summary's columns: the set (a session's name), its status, the camera its RAW files name, the method, the RE
against the truth when one is known (×10⁻² on the terminal and in Markdown, as every report prints
it; the plain fraction in CSV), the number of warnings, and the wall time in its worker. The
Markdown file lists every failure's reason and every warning under the table; the CSV has them in
columns, with each set's CPU time and the worker (``host:pid``) that estimated it.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol, TextIO

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from calib.core.errors import InputError
from calib.core.markdown import table_row, table_rule
from calib.pipeline.batch_jobs import BatchRow
from calib.pipeline.progress import RichFrameProgress

#: The file formats :func:`write_summary` writes, by suffix.
SUMMARY_SUFFIXES = (".md", ".csv")

_CSV_COLUMNS = (
    "name",
    "status",
    "camera",
    "method",
    "truth_relative_error",
    "warnings",
    "wall_s",
    "cpu_s",
    "worker",
    "out_dir",
    "path",
    "error",
)


def _re(row: BatchRow) -> str:
    value = row.truth_relative_error
    return "—" if value is None else f"{value * 100:.2f}"


def _cells(row: BatchRow) -> list[str]:
    return [
        row.name,
        row.status,
        row.camera or "—",
        row.method or "—",
        _re(row),
        str(len(row.warnings)),
        f"{row.wall_s:.1f}",
    ]


def _headings(label: str) -> list[str]:
    return [label, "status", "camera", "method", "RE ×10⁻² (truth)", "warnings", "time s"]


def summary_table(rows: Sequence[BatchRow], *, label: str = "session") -> Table:
    """The summary as a rich table; a failure's reason follows on the next line."""
    table = Table(box=None, pad_edge=False)
    for heading in _headings(label):
        table.add_column(heading, no_wrap=heading == label, overflow="fold")
    for row in rows:
        table.add_row(*_cells(row))
        if row.error:
            table.add_row("", f"[red]{row.error}[/red]" if row.status == "failed" else row.error)
    return table


def summary_markdown(rows: Sequence[BatchRow], *, label: str = "session") -> str:
    """The summary as a Markdown table, then the failures' reasons and every warning."""

    headings = _headings(label)
    lines = [table_row(headings), table_rule(len(headings))]
    lines.extend(table_row(_cells(row)) for row in rows)
    failed = [row for row in rows if row.error]
    if failed:
        lines += ["", "## Not estimated", ""]
        lines += [f"- **{row.name}** ({row.path}): {row.status}: {row.error}" for row in failed]
    warned = [row for row in rows if row.warnings]
    if warned:
        lines += ["", "## Warnings", ""]
        for row in warned:
            lines.append(f"- **{row.name}**")
            lines += [f"  - {warning}" for warning in row.warnings]
    ok = sum(row.status == "ok" for row in rows)
    lines += ["", f"{ok} of {len(rows)} estimated."]
    return "\n".join(lines) + "\n"


def summary_csv(rows: Sequence[BatchRow]) -> str:
    """The summary as CSV (warnings joined by ``"; "``, RE as a plain fraction)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(_CSV_COLUMNS)
    for row in rows:
        writer.writerow(
            [
                row.name,
                row.status,
                row.camera or "",
                row.method or "",
                "" if row.truth_relative_error is None else repr(row.truth_relative_error),
                "; ".join(row.warnings),
                f"{row.wall_s:.3f}",
                f"{row.cpu_s:.3f}",
                row.worker,
                row.out_dir or "",
                row.path,
                row.error or "",
            ]
        )
    return buffer.getvalue()


def check_summary_path(path: Path) -> None:
    """Refuse a summary file whose format is not known by its suffix (before any work).

    Raises
    ------
    InputError
        Another suffix (named, with the ones known).
    """
    if path.suffix.lower() not in SUMMARY_SUFFIXES:
        raise InputError(
            f"unknown summary format {path.suffix or '(no suffix)'!r}: name the file "
            f"{' or '.join('*' + suffix for suffix in SUMMARY_SUFFIXES)}",
            source=str(path),
        )


def write_summary(path: Path, rows: Sequence[BatchRow], *, label: str = "session") -> Path:
    """Write the summary to ``path`` in the format its suffix names (``.md`` or ``.csv``)."""
    check_summary_path(path)
    text = (
        summary_csv(rows) if path.suffix.lower() == ".csv" else summary_markdown(rows, label=label)
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


class BatchProgress(Protocol):
    """Receives a batch's progress: how many input sets, then each one's row as it finishes."""

    def start(self, total: int) -> None:
        """The batch will estimate ``total`` input sets."""

    def done(self, row: BatchRow) -> None:
        """One input set is finished (``row.status`` says how)."""


class NoBatchProgress:
    """A :class:`BatchProgress` that shows nothing (``--quiet``)."""

    def start(self, total: int) -> None:
        pass

    def done(self, row: BatchRow) -> None:
        pass


class RichBatchProgress:
    """A batch's progress on ``stream``: a bar of input sets on a terminal (with the failures
    named above it as they happen), one line per finished set otherwise (a log file).

    Use as a context manager; it implements :class:`BatchProgress`.
    """

    def __init__(self, stream: TextIO) -> None:
        self._console = Console(file=stream)
        self._live = RichFrameProgress.wanted(stream)
        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[failed]}"),
            TimeElapsedColumn(),
            console=self._console,
        )
        self._task = self._progress.add_task("estimating", total=None, failed="")
        self._finished = 0
        self._failed = 0
        self._total = 0

    def __enter__(self) -> RichBatchProgress:
        if self._live:
            self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live:
            self._progress.stop()

    def start(self, total: int) -> None:
        self._total = total
        self._progress.update(self._task, total=total, completed=0)

    def done(self, row: BatchRow) -> None:
        self._finished += 1
        if row.status == "failed":
            self._failed += 1
        if not self._live:
            what = (
                f"{row.status} {row.wall_s:.1f} s"
                if row.status == "ok"
                else f"{row.status}: {row.error}"
            )
            self._console.print(
                f"[{self._finished}/{self._total}] {row.name}: {what}",
                markup=False,
                highlight=False,
                soft_wrap=True,
            )
            return
        if row.status == "failed":
            self._progress.console.print(
                f"{row.name}: failed: {row.error}", markup=False, highlight=False, soft_wrap=True
            )
        self._progress.update(
            self._task,
            advance=1,
            description=f"estimated {row.name}",
            failed=f"{self._failed} failed" if self._failed else "",
        )
