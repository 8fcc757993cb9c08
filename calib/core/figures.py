"""The one seam to matplotlib: figures drawn straight to files by the Agg canvas.

matplotlib costs about 0.4 s of CPU to import, so no module of ``calib`` imports it at import time:
plots are made on :func:`agg_figure` (and its patches from :func:`polygon`), which import it on first
use, and written with :func:`save_png`; :func:`import_matplotlib` imports it ahead, e.g. in a thread
while frames decode. Agg figures need no display and no global ``pyplot`` state, so several can be
drawn in threads at once.

What a plot costs is mostly drawing text (tick labels, titles, legends) and encoding the PNG; a
batch draws every report's plots again, so both are kept cheap here: PNGs are compressed at zlib's
fastest level (:data:`PNG_COMPRESS_LEVEL`), and scientific tick labels are plain text
(:func:`scientific_y_ticks`), not mathtext, which parses every label anew.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path
from typing import Any, Literal

from calib.core.arrays import FloatArray


def import_matplotlib() -> None:
    """Import the parts of matplotlib the plots use (figure, Agg canvas, patches)."""
    import matplotlib.backends.backend_agg
    import matplotlib.figure
    import matplotlib.patches  # noqa: F401


def agg_figure(
    width_in: float, height_in: float, *, layout: Literal["constrained"] | None = None
) -> Any:
    """A new ``matplotlib.figure.Figure`` of ``width_in × height_in`` inches on an Agg canvas.

    ``layout="constrained"`` lays the axes out automatically (about twice the drawing time of
    fixed margins set with ``subplots_adjust``). Save with ``figure.savefig(path, dpi=…)``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width_in, height_in), layout=layout)
    FigureCanvasAgg(figure)
    return figure


def polygon(corners: FloatArray, **style: Any) -> Any:
    """A ``matplotlib.patches.Polygon`` through ``corners`` (shape ``(n, 2)``), for ``add_patch``."""
    from matplotlib.patches import Polygon

    return Polygon(corners, **style)


#: zlib level of the PNGs written: 1, zlib's fastest. The plots are large flat areas and lines, so
#: level 1 costs 3–7 % more bytes than Pillow's default 6 and a third of its encoding time (the
#: pixels are the same: PNG is lossless).
PNG_COMPRESS_LEVEL = 1


def save_png(figure: Any, path: str | os.PathLike[str], *, dpi: float) -> Path:
    """Draw ``figure`` and write it to ``path`` as a PNG at ``dpi`` (:data:`PNG_COMPRESS_LEVEL`)."""
    destination = Path(path)
    figure.savefig(destination, dpi=dpi, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    return destination


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


@functools.cache
def _plain_scalar_formatter() -> type[Any]:
    from matplotlib.ticker import ScalarFormatter

    class PlainScalarFormatter(ScalarFormatter):
        """Matplotlib's ``ScalarFormatter`` whose powers of ten read ``×10ⁿ`` in plain text."""

        def format_data(self, value: float) -> str:
            exponent = math.floor(math.log10(abs(value)))
            significand = round(value / 10**exponent, 10)
            shown = ("%d" if significand % 1 == 0 else "%1.10g") % significand
            if exponent == 0:
                return str(self.fix_minus(shown))
            power = "10" + str(exponent).translate(_SUPERSCRIPT)
            return power if significand == 1 else f"{self.fix_minus(shown)}×{power}"

        def get_offset(self) -> str:
            # the attributes' public names are deprecated in Matplotlib 3.11
            locations = getattr(self, "_locs", None)
            order = getattr(self, "_orderOfMagnitude", None)
            if locations is None or order is None:  # before 3.11
                locations, order = self.locs, self.orderOfMagnitude
            if len(locations) == 0 or not (order or self.offset):
                return ""
            power = f"×{self.format_data(10**order)}" if order else ""
            shift = ""
            if self.offset:
                shift = ("+" if self.offset > 0 else "") + self.format_data(self.offset)
            return str(self.fix_minus(power + shift))

    return PlainScalarFormatter


def scientific_y_ticks(axes: Any, limits: tuple[int, int] = (-3, 4)) -> None:
    """Y tick labels scaled by a power of ten outside 10^``limits``, the power shown once above the
    axis as ``×10ⁿ``.

    What ``axes.ticklabel_format(axis="y", style="sci", scilimits=limits, useMathText=True)``
    shows, in plain text: mathtext would parse every tick label (about 1 ms each, a new set for
    every plot).
    """
    formatter = _plain_scalar_formatter()(useMathText=False)
    formatter.set_scientific(True)
    formatter.set_powerlimits(limits)
    axes.yaxis.set_major_formatter(formatter)
