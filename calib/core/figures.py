"""The one seam to matplotlib: figures drawn straight to files by the Agg canvas.

matplotlib costs about 0.4 s of CPU to import, so no module of ``calib`` imports it at import time:
plots are made on :func:`agg_figure` (and its patches from :func:`polygon`), which import it on first
use; :func:`import_matplotlib` imports it ahead, e.g. in a thread while frames decode. Agg figures
need no display and no global ``pyplot`` state, so several can be drawn in threads at once.
"""

from __future__ import annotations

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
