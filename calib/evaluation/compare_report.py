"""Write a method comparison (:mod:`calib.evaluation.compare`) as Markdown, CSV and a grid of plots.

The Markdown is the paper-style table (Makabe et al. 2025, Fig. 7): one table per noise level, a row
per camera (mean over repeats) and a column per method with RE ×10⁻², then the mean over cameras and
the median wall time of one estimate per method. The CSV has one line per estimate. The plots show,
per noise level, each camera (rows) × method (columns): estimated (solid) and true (dotted) R, G, B
curves, normalised to a maximum of 1, with the RE in the panel.

Captured sessions (:func:`sessions_markdown_report`, :func:`plot_panels`) give one table and one grid,
a row per session, and list the columns they cannot feed with the reason.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from calib.core.markdown import table_row, table_rule
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.evaluation.compare import CompareRow, GratingAdapter, SyntheticAdapter

_CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")


def _noise_label(noise: float) -> str:
    return f"{noise * 100:g} %"


def _ordered(values: Sequence[str]) -> list[str]:
    return list(dict.fromkeys(values))


def _mean_re(rows: Sequence[CompareRow]) -> tuple[float, int]:
    """Mean RE over successful rows and the number of failures."""
    good = [row.relative_error for row in rows if row.failure is None]
    failed = len(rows) - len(good)
    return (float(np.mean(good)) if good else float("nan")), failed


def _cell(rows: Sequence[CompareRow]) -> str:
    if not rows:
        return "—"
    value, failed = _mean_re(rows)
    text = "failed" if not math.isfinite(value) else f"{value * 100:.2f}"
    if failed and math.isfinite(value):
        text += f" ({failed} failed)"
    return text


def _time_cell(rows: Sequence[CompareRow]) -> str:
    if not rows:
        return "—"
    median = float(np.median([row.time_s for row in rows]))
    return f"{median:.3f} s" if median < 10 else f"{median:.1f} s"


def _table_lines(
    rows: Sequence[CompareRow], labels: Sequence[str], cameras: Sequence[str]
) -> list[str]:
    """A camera × column table of ``rows`` (one noise level) with the mean and time lines."""
    cells: dict[tuple[str, str], list[CompareRow]] = defaultdict(list)
    for row in rows:
        cells[(row.camera, row.label)].append(row)
    lines = [table_row(["camera", *labels]), table_rule(1 + len(labels), right_aligned_from=1)]
    for camera in cameras:
        lines.append(table_row([camera, *(_cell(cells[(camera, label)]) for label in labels)]))
    by_label = {label: [r for r in rows if r.label == label] for label in labels}
    lines.append(table_row(["**mean**", *(f"**{_cell(by_label[label])}**" for label in labels)]))
    lines.append(table_row(["time / estimate", *(_time_cell(by_label[label]) for label in labels)]))
    return lines


def _heading(title: str, description: str, command: str | None) -> list[str]:
    """The title, what the data are, and the command that reproduces the report."""
    lines = [title, "", description, ""]
    if command:
        lines += ["Reproduce with:", "", f"    {command}", ""]
    return lines


def _legend(
    caption: str,
    rows: Sequence[CompareRow],
    adapters: Sequence[SyntheticAdapter | GratingAdapter],
    where: Callable[[CompareRow], str],
) -> list[str]:
    """What the numbers are, the columns' notes, then every failure (``where`` names its row)."""
    notes = {adapter.label: adapter.note for adapter in adapters}
    lines = [caption, "", "Columns:", ""]
    lines += [
        f"- **{label}**: {notes.get(label, '')}" for label in _ordered([r.label for r in rows])
    ]
    failures = [row for row in rows if row.failure]
    if failures:
        lines += ["", "Failures:", ""]
        lines += [f"- {where(row)}: {row.failure}" for row in failures]
    return lines


def markdown_report(
    rows: Sequence[CompareRow],
    adapters: Sequence[SyntheticAdapter],
    *,
    description: str,
    skipped: Sequence[str] = (),
    command: str | None = None,
) -> str:
    """The comparison as Markdown (see the module docstring)."""
    labels = _ordered([row.label for row in rows])
    cameras = _ordered([row.camera for row in rows])
    noises = sorted({row.noise for row in rows})
    lines = _heading("# Method comparison", description, command)
    for noise in noises:
        lines += [f"## Noise {_noise_label(noise)} of the peak", ""]
        lines += _table_lines([row for row in rows if row.noise == noise], labels, cameras)
        lines.append("")
    lines += _legend(
        "RE ×10⁻² (Makabe et al. 2025, Eq. 16; mean over repeats); time: median wall time of one "
        "estimate call.",
        rows,
        adapters,
        lambda row: f"{row.label}, {row.camera}, noise {_noise_label(row.noise)}",
    )
    if skipped:
        lines += [
            "",
            "Registered but not run (no synthetic adapter): " + ", ".join(skipped) + ".",
        ]
    return "\n".join(lines) + "\n"


def sessions_markdown_report(
    rows: Sequence[CompareRow],
    adapters: Sequence[GratingAdapter],
    *,
    description: str,
    skipped: Sequence[tuple[str, str]] = (),
    session_notes: Sequence[str] = (),
    command: str | None = None,
) -> str:
    """A comparison on captured sessions as Markdown: one table, a row per session.

    Parameters
    ----------
    rows
        :func:`calib.evaluation.compare.run_grating_comparison`'s rows.
    adapters
        The columns run (for their notes).
    description
        What the data are.
    skipped
        ``(column or method, reason)`` of everything not run.
    session_notes
        Per-session lines (the pipeline's warnings …), listed under the table.
    command
        The command that reproduces the report.
    """
    labels = _ordered([row.label for row in rows])
    cameras = _ordered([row.camera for row in rows])
    lines = _heading("# Method comparison on captured sessions", description, command)
    lines += _table_lines(rows, labels, cameras)
    lines.append("")
    lines += _legend(
        "RE ×10⁻² (Makabe et al. 2025, Eq. 16) against the twin's true camera; time: median wall "
        "time of one estimate call.",
        rows,
        adapters,
        lambda row: f"{row.label}, {row.camera}",
    )
    if skipped:
        lines += ["", "Skipped (need data a grating session does not hold):", ""]
        lines += [f"- **{label}**: {reason}" for label, reason in skipped]
    if session_notes:
        lines += ["", "Sessions:", ""]
        lines += [f"- {note}" for note in session_notes]
    return "\n".join(lines) + "\n"


def write_csv(path: Path, rows: Sequence[CompareRow]) -> Path:
    """One line per estimate: camera, column, method, noise, repeat, RE, time, failure."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "camera",
                "column",
                "method",
                "noise_fraction",
                "repeat",
                "relative_error",
                "time_s",
                "failure",
            ]
        )
        for row in rows:
            writer.writerow(
                [
                    row.camera,
                    row.label,
                    row.method,
                    row.noise,
                    row.repeat,
                    "" if row.failure else f"{row.relative_error:.6g}",
                    f"{row.time_s:.6f}",
                    row.failure or "",
                ]
            )
    return path


def plot_grid(
    path: Path,
    rows: Sequence[CompareRow],
    noise: float,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> Path:
    """Cameras × methods panels of estimated (solid) vs true (dotted) curves at one noise level."""
    chosen = [row for row in rows if row.noise == noise and row.repeat == 0]
    if not chosen:
        raise ValueError(f"no rows at noise {noise}")
    title = f"estimated (solid) vs true (dotted), noise {_noise_label(noise)}; RE ×10⁻²"
    return plot_panels(path, chosen, title, grid=grid)


def plot_panels(
    path: Path,
    rows: Sequence[CompareRow],
    title: str,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> Path:
    """Cameras × columns panels of estimated (solid) vs true (dotted) curves, one row each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chosen = list(rows)
    labels = _ordered([row.label for row in chosen])
    cameras = _ordered([row.camera for row in chosen])
    by_key = {(row.camera, row.label): row for row in chosen}
    wavelength = grid.wavelength_nm
    figure, axes = plt.subplots(
        len(cameras),
        len(labels),
        figsize=(2.3 * len(labels) + 0.8, 1.9 * len(cameras) + 0.8),
        sharex=True,
        sharey=True,
        squeeze=False,
    )
    for i, camera in enumerate(cameras):
        for j, label in enumerate(labels):
            axis = axes[i][j]
            row = by_key.get((camera, label))
            if row is not None and row.truth is not None:
                for channel, colour in enumerate(_CHANNEL_COLOURS):
                    axis.plot(wavelength, row.truth[:, channel], ":", color=colour, lw=1.2)
                    if row.estimate is not None:
                        axis.plot(wavelength, row.estimate[:, channel], "-", color=colour, lw=1.0)
                text = "failed" if row.failure else f"RE {row.relative_error * 100:.2f}"
                axis.text(
                    0.97, 0.93, text, transform=axis.transAxes, ha="right", va="top", fontsize=7
                )
            axis.set_ylim(-0.05, 1.1)
            axis.tick_params(labelsize=6)
            if i == 0:
                axis.set_title(label, fontsize=7)
            if j == 0:
                axis.set_ylabel(camera, fontsize=7)
    figure.suptitle(title, fontsize=9)
    figure.supxlabel("wavelength (nm)", fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
