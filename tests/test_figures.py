"""The matplotlib seam's cheap paths show what matplotlib's own would (calib.core.figures)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calib.core.figures import agg_figure, save_png, scientific_y_ticks


def _profile_axes(peak: float, offset: float = 0.0) -> tuple[Any, Any]:
    figure = agg_figure(7.0, 3.0)
    axes = figure.subplots()
    x = np.linspace(400.0, 900.0, 200)
    axes.plot(x, offset + peak * np.exp(-(((x - 650.0) / 60.0) ** 2)))
    return figure, axes


def _mathtext_plain(label: str) -> str:
    """A mathtext label as it reads: ``$\\times\\mathdefault{10^{5}}$`` → ``×10⁵``."""
    superscript = str.maketrans("-−0123456789", "⁻⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
    label = re.sub(r"\^\{([^}]*)\}", lambda m: m.group(1).translate(superscript), label)
    label = label.replace(r"\times", "×").replace(r"\mathdefault", "")
    return re.sub(r"[${}\s]", "", label)


@pytest.mark.parametrize(
    ("peak", "offset"), [(2.0e5, 0.0), (3.7e-4, 0.0), (123.0, 0.0), (4.0e6, -1.0e5), (1.0, 1e4)]
)
def test_scientific_ticks_read_as_mathtext_ones(peak: float, offset: float) -> None:
    shown: list[list[str]] = []
    for plain_text in (False, True):
        figure, axes = _profile_axes(peak, offset)
        if plain_text:
            scientific_y_ticks(axes, (-3, 4))
        else:
            axes.ticklabel_format(axis="y", style="sci", scilimits=(-3, 4), useMathText=True)
        figure.canvas.draw()
        yaxis = axes.yaxis
        labels = [text.get_text() for text in axes.get_yticklabels()]
        shown.append([*labels, yaxis.offsetText.get_text()])
    mathtext, plain = shown
    assert [_mathtext_plain(label) for label in mathtext] == plain
    assert not any("$" in label for label in plain)


def test_scientific_ticks_show_the_power_once_when_large() -> None:
    figure, axes = _profile_axes(2.0e5)
    scientific_y_ticks(axes)
    figure.canvas.draw()
    assert axes.yaxis.offsetText.get_text() == "×10⁵"


def test_the_fast_png_holds_the_same_pixels(tmp_path: Path) -> None:
    from PIL import Image

    figure, _ = _profile_axes(2.0e5)
    default = tmp_path / "default.png"
    figure.savefig(default, dpi=100)
    fast = save_png(figure, tmp_path / "fast.png", dpi=100)
    with Image.open(default) as first, Image.open(fast) as second:
        assert first.size == second.size == (700, 300)
        assert np.array_equal(np.asarray(first), np.asarray(second))
