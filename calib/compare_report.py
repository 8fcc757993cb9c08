"""Write a method comparison (:mod:`calib.compare`) as Markdown, CSV and a grid of plots.

The Markdown is the paper-style table (Makabe et al. 2025, Fig. 7): one table per noise level, a row
per camera (mean over repeats) and a column per method with RE ×10⁻², then the mean over cameras and
the median wall time of one estimate per method. The CSV has one line per estimate. The plots show,
per noise level, each camera (rows) × method (columns): estimated (solid) and true (dotted) R, G, B
curves, normalised to a maximum of 1, with the RE in the panel.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from calib.compare import CompareRow, SyntheticAdapter
from calib.spectra import DEFAULT_GRID, WavelengthGrid

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
    cells: dict[tuple[str, str, float], list[CompareRow]] = defaultdict(list)
    for row in rows:
        cells[(row.camera, row.label, row.noise)].append(row)
    lines = ["# Method comparison", "", description, ""]
    if command:
        lines += ["Reproduce with:", "", f"    {command}", ""]
    for noise in noises:
        lines += [f"## Noise {_noise_label(noise)} of the peak", ""]
        lines.append("| camera | " + " | ".join(labels) + " |")
        lines.append("|---|" + "---:|" * len(labels))
        for camera in cameras:
            lines.append(
                f"| {camera} | "
                + " | ".join(_cell(cells[(camera, label, noise)]) for label in labels)
                + " |"
            )
        by_label = {
            label: [r for r in rows if r.label == label and r.noise == noise] for label in labels
        }
        lines.append(
            "| **mean** | " + " | ".join(f"**{_cell(by_label[label])}**" for label in labels) + " |"
        )
        lines.append(
            "| time / estimate | "
            + " | ".join(_time_cell(by_label[label]) for label in labels)
            + " |"
        )
        lines.append("")
    lines += [
        "RE ×10⁻² (Makabe et al. 2025, Eq. 16; mean over repeats); time: median wall time of one "
        "estimate call.",
        "",
        "Columns:",
        "",
    ]
    notes = {adapter.label: adapter.note for adapter in adapters}
    lines += [f"- **{label}**: {notes.get(label, '')}" for label in labels]
    failures = [row for row in rows if row.failure]
    if failures:
        lines += ["", "Failures:", ""]
        lines += [
            f"- {row.label}, {row.camera}, noise {_noise_label(row.noise)}: {row.failure}"
            for row in failures
        ]
    if skipped:
        lines += [
            "",
            "Registered but not run (no synthetic adapter): " + ", ".join(skipped) + ".",
        ]
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chosen = [row for row in rows if row.noise == noise and row.repeat == 0]
    labels = _ordered([row.label for row in chosen])
    cameras = _ordered([row.camera for row in chosen])
    if not chosen:
        raise ValueError(f"no rows at noise {noise}")
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
    figure.suptitle(
        f"estimated (solid) vs true (dotted), noise {_noise_label(noise)}; RE ×10⁻²", fontsize=9
    )
    figure.supxlabel("wavelength (nm)", fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
