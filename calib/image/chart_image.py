"""Patch RGBs from an image of a colour chart: corner patches → every patch centre → a window mean.

The input is the linear image as :func:`calib.image.raw.read_raw` gives it: planes ``(3, h, w)`` (R, G, B at
half the sensor resolution, black subtracted) and, optionally, its saturation mask. The chart is
located by four points, the **centres of its four corner patches** in the order

    top-left (patch 1, "dark skin" on a ColorChecker), top-right, bottom-right, bottom-left,

each ``(x, y)`` = (column, row) in plane pixels (sensor pixels / 2). A projective map (homography)
from the chart's patch lattice to these points gives every patch centre, so a chart photographed at
an angle is sampled correctly. Each patch is sampled by a square window centred on it, of side
``window_fraction`` × the distance between neighbouring centres (the default 0.4 stays clear of the
black gaps between patches); its mean is the patch value and the standard error of the mean its σ.

Patches are numbered in reading order (left to right, top to bottom), the order of
``colour.SDS_COLOURCHECKERS`` and of :func:`calib.model.charts.colorchecker`.

Errors name the patch (number and name), where its window is, and what to do: corners that do not
form a convex quadrilateral in the stated order, windows off the frame, clipped samples, windows too
small to average.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.observations import ChartKind, ChartObservation
from calib.core.spectra import MultiSpectrum, Spectrum

#: Fewest samples per window and channel for a mean and a standard error.
MIN_WINDOW_SAMPLES = 4


@dataclass(frozen=True)
class ChartLayout:
    """The patch lattice of a chart and how much of each patch to average.

    Attributes
    ----------
    rows, columns
        Patches per column and per row (ColorChecker Classic: 4 × 6).
    window_fraction
        Side of the square sampling window as a fraction of the centre-to-centre distance
        (0 < f ≤ 1).
    """

    rows: int = 4
    columns: int = 6
    window_fraction: float = 0.4

    def __post_init__(self) -> None:
        if self.rows < 2 or self.columns < 2:
            raise InputError(
                f"a chart needs at least 2 × 2 patches to be located by its corner patches, got "
                f"{self.rows} × {self.columns}",
                source="chart layout",
            )
        if not 0 < self.window_fraction <= 1:
            raise InputError(
                f"window_fraction must be in (0, 1], got {self.window_fraction}",
                source="chart layout",
            )

    @property
    def n_patches(self) -> int:
        return self.rows * self.columns


@dataclass(frozen=True, eq=False)
class PatchSamples:
    """Patch values sampled from an image.

    Attributes
    ----------
    rgb
        Shape ``(n_patches, 3)``: mean of each window per channel.
    sigma
        Shape ``(n_patches, 3)``: standard error of that mean.
    centres_px
        Shape ``(n_patches, 2)``: ``(x, y)`` of each patch centre in plane pixels.
    window_px
        Side of the square windows in plane pixels.
    """

    rgb: FloatArray
    sigma: FloatArray
    centres_px: FloatArray
    window_px: int


def _homography(corners_px: FloatArray, layout: ChartLayout) -> FloatArray:
    """3×3 map from lattice coordinates (column, row) to image ``(x, y)`` through the 4 corners."""
    lattice = np.array(
        [[0.0, 0.0], [layout.columns - 1.0, 0.0], [layout.columns - 1.0, layout.rows - 1.0],
         [0.0, layout.rows - 1.0]]
    )  # fmt: skip
    system = []
    target = []
    for (u, v), (x, y) in zip(lattice, corners_px, strict=True):
        system.append([u, v, 1.0, 0.0, 0.0, 0.0, -u * x, -v * x])
        system.append([0.0, 0.0, 0.0, u, v, 1.0, -u * y, -v * y])
        target.extend([x, y])
    solution = np.linalg.solve(np.array(system), np.array(target))
    return np.append(solution, 1.0).reshape(3, 3)


def _validated_corners(corners_px: ArrayLike) -> FloatArray:
    corners = np.asarray(corners_px, dtype=np.float64)
    if corners.shape != (4, 2) or not np.all(np.isfinite(corners)):
        raise InputError(
            f"expected 4 finite (x, y) points, got shape {np.shape(corners_px)}",
            source="chart corners",
        )
    edges = np.roll(corners, -1, axis=0) - corners
    turns = (
        edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1]
        - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    )
    if not (np.all(turns > 0) or np.all(turns < 0)):
        raise InputError(
            "the 4 points must be the centres of the corner patches in the order top-left, "
            f"top-right, bottom-right, bottom-left, forming a convex quadrilateral; got "
            f"{corners.tolist()}",
            source="chart corners",
        )
    return corners


def patch_centres(corners_px: ArrayLike, layout: ChartLayout = ChartLayout()) -> FloatArray:
    """Every patch centre from the centres of the four corner patches.

    Parameters
    ----------
    corners_px
        Shape ``(4, 2)``: ``(x, y)`` of the top-left, top-right, bottom-right and bottom-left
        patch centres, in plane pixels.
    layout
        Rows and columns of the chart.

    Returns
    -------
    numpy.ndarray
        Shape ``(rows · columns, 2)``: ``(x, y)`` of each patch in reading order.

    Examples
    --------
    >>> patch_centres([[0, 0], [50, 0], [50, 30], [0, 30]])[[0, 1, 6, 23]]
    array([[ 0.,  0.],
           [10.,  0.],
           [ 0., 10.],
           [50., 30.]])
    """
    corners = _validated_corners(corners_px)
    homography = _homography(corners, layout)
    rows, columns = np.meshgrid(
        np.arange(layout.rows, dtype=np.float64),
        np.arange(layout.columns, dtype=np.float64),
        indexing="ij",
    )
    lattice = np.stack([columns.ravel(), rows.ravel(), np.ones(layout.n_patches)], axis=0)
    mapped = homography @ lattice
    return np.asarray((mapped[:2] / mapped[2]).T, dtype=np.float64)


def _patch_label(index: int, names: Sequence[str] | None) -> str:
    name = f" ({names[index]!r})" if names is not None and index < len(names) else ""
    return f"patch {index + 1}{name}"


def sample_patches(
    planes: ArrayLike,
    corners_px: ArrayLike,
    layout: ChartLayout = ChartLayout(),
    *,
    saturated: ArrayLike | None = None,
    patch_names: Sequence[str] | None = None,
    source: str = "chart image",
) -> PatchSamples:
    """Mean R, G, B of a window at every patch centre (see the module docstring).

    Parameters
    ----------
    planes
        Shape ``(3, h, w)``: linear, black-subtracted R, G, B planes.
    corners_px
        Shape ``(4, 2)``: the corner patch centres (see :func:`patch_centres`).
    layout
        Chart lattice and window size.
    saturated
        Shape ``(3, h, w)`` boolean: clipped samples (``RawPlanes.saturated``), or ``None``.
    patch_names
        Names for error messages (e.g. the chart data's channel names).
    source
        The image file or what it is, for error messages.

    Returns
    -------
    PatchSamples

    Raises
    ------
    InputError
        Bad corners, a window off the frame or too small, clipped samples in a window.
    """
    image = np.asarray(planes, dtype=np.float64)
    if image.ndim != 3 or image.shape[0] != 3:
        raise InputError(f"expected planes of shape (3, h, w), got {image.shape}", source=source)
    height, width = image.shape[1:]
    mask = None
    if saturated is not None:
        mask = np.asarray(saturated, dtype=bool)
        if mask.shape != image.shape:
            raise InputError(
                f"saturation mask has shape {mask.shape}, planes {image.shape}", source=source
            )
    centres = patch_centres(corners_px, layout)
    grid_centres = centres.reshape(layout.rows, layout.columns, 2)
    pitch = min(
        float(np.min(np.linalg.norm(np.diff(grid_centres, axis=0), axis=-1))),
        float(np.min(np.linalg.norm(np.diff(grid_centres, axis=1), axis=-1))),
    )
    window = int(np.floor(layout.window_fraction * pitch))
    if window * window < MIN_WINDOW_SAMPLES:
        raise InputError(
            f"patch centres are only {pitch:.1f} px apart, so the sampling window is {window} px "
            f"wide (< {MIN_WINDOW_SAMPLES} samples); photograph the chart larger or raise "
            "window_fraction",
            source=source,
        )
    rgb = np.empty((layout.n_patches, 3))
    sigma = np.empty((layout.n_patches, 3))
    for index, (x, y) in enumerate(centres):
        left = int(np.floor(x - window / 2 + 0.5))
        top = int(np.floor(y - window / 2 + 0.5))
        right, bottom = left + window, top + window
        if left < 0 or top < 0 or right > width or bottom > height:
            raise InputError(
                f"{_patch_label(index, patch_names)} at (x={x:.1f}, y={y:.1f}) needs the window "
                f"x {left}…{right - 1}, y {top}…{bottom - 1}, outside the {width}×{height} frame; "
                "check the corner points (order top-left, top-right, bottom-right, bottom-left; "
                "plane pixels) and that the whole chart is in the picture",
                source=source,
            )
        if mask is not None:
            clipped = mask[:, top:bottom, left:right].reshape(3, -1).sum(axis=1)
            if np.any(clipped > 0):
                channel = "RGB"[int(np.argmax(clipped))]
                raise InputError(
                    f"{_patch_label(index, patch_names)} has {int(clipped.max())} clipped "
                    f"samples in channel {channel}; lower the exposure and take the chart again",
                    source=source,
                )
        samples = image[:, top:bottom, left:right].reshape(3, -1)
        rgb[index] = samples.mean(axis=1)
        spread = samples.std(axis=1, ddof=1) / np.sqrt(samples.shape[1])
        # A perfectly flat (synthetic) window still gets a tiny positive σ: estimators divide by it.
        sigma[index] = np.maximum(spread, 1e-12 * max(float(np.abs(rgb[index]).max()), 1.0))
    return PatchSamples(rgb=rgb, sigma=sigma, centres_px=centres, window_px=window)


def chart_observation_from_planes(
    planes: ArrayLike,
    corners_px: ArrayLike,
    patch_spectra: MultiSpectrum,
    illuminant: Spectrum | None,
    *,
    layout: ChartLayout = ChartLayout(),
    saturated: ArrayLike | None = None,
    name: str = "chart",
    kind: ChartKind = "reflective",
    source: str = "chart image",
) -> ChartObservation:
    """A :class:`ChartObservation` from an image of a chart and its patch data.

    Parameters
    ----------
    planes, corners_px, layout, saturated
        As for :func:`sample_patches`.
    patch_spectra
        One channel per patch in reading order (``rows · columns`` of them), e.g.
        :func:`calib.model.charts.colorchecker`.
    illuminant
        The light on the chart (``None`` for emissive patches).
    name, kind, source
        Stored on the observation / used in messages.
    """
    n_spectra = patch_spectra.values.shape[1]
    if n_spectra != layout.n_patches:
        raise InputError(
            f"the chart data has {n_spectra} patches but the layout {layout.rows} × "
            f"{layout.columns} has {layout.n_patches}",
            source=source,
        )
    samples = sample_patches(
        planes,
        corners_px,
        layout,
        saturated=saturated,
        patch_names=patch_spectra.channels,
        source=source,
    )
    return ChartObservation(
        name=name,
        patch_rgb=samples.rgb,
        patch_spectra=patch_spectra,
        illuminant=illuminant,
        patch_sigma=samples.sigma,
        kind=kind,
        metadata={
            "source": source,
            "patch_centres_px": samples.centres_px.tolist(),
            "window_px": samples.window_px,
        },
    )
