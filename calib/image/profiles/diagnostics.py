"""A diagnostic picture of a detected geometry: what was found where, and the profiles it yields."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.figures import agg_figure, polygon, save_png
from calib.image.blocks import block_factor, block_mean
from calib.image.hdr import HdrImage
from calib.image.profiles.extraction import extract
from calib.image.profiles.geometry import (
    CHANNEL_NAMES,
    DetectionError,
    DiffractionGeometry,
    image_source,
    rectangle_corners,
)

#: The picture shows the image block-averaged to at most this many samples across.
_DISPLAY_MAX_SIZE = 1200
_CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")


def _display_image(image: HdrImage) -> tuple[np.ndarray, float]:
    """Log10 of the channel-summed radiance, block-averaged; and the block size in sensor pixels."""
    luminance = image.radiance.sum(axis=0, dtype=np.float64)
    luminance[~np.isfinite(luminance)] = 0.0
    factor = block_factor(luminance.shape, _DISPLAY_MAX_SIZE)
    small = block_mean(luminance, factor)
    positive = small[small > 0]
    floor = float(np.percentile(positive, 50)) if positive.size else 1.0
    return np.log10(np.maximum(small, floor)), factor * image.pixel_pitch_px


def write_geometry_png(
    path: str | os.PathLike[str], image: HdrImage, geometry: DiffractionGeometry
) -> Path:
    """Draw the image with the spot aperture, the bands, the background strips and the profiles.

    Parameters
    ----------
    path
        The PNG to write (its directory must exist).
    image
        The HDR image the geometry was detected on (or applied to).
    geometry
        The geometry to draw.

    Returns
    -------
    Path
        ``path``.
    """
    return save_png(geometry_figure(image, geometry), path, dpi=GEOMETRY_DPI)


#: The resolution :func:`write_geometry_png` draws :func:`geometry_figure` at.
GEOMETRY_DPI = 110


def geometry_figure(image: HdrImage, geometry: DiffractionGeometry) -> Any:
    """The figure :func:`write_geometry_png` writes (a ``matplotlib.figure.Figure``)."""
    display, block_px = _display_image(image)
    height, width = image.sensor_shape_px
    # fixed margins (a constrained layout costs 40 % of the drawing), room for 4-digit pixel and
    # 6-digit radiance tick labels beside the y labels (larger radiances are scaled by 10ⁿ)
    figure = agg_figure(12, 5.5)
    figure.subplots_adjust(left=0.06, right=0.99, bottom=0.1, top=0.95, wspace=0.18)
    picture, profiles = figure.subplots(1, 2, width_ratios=(1.4, 1))
    picture.imshow(
        display,
        cmap="gray",
        extent=(-0.5, display.shape[1] * block_px - 0.5, display.shape[0] * block_px - 0.5, -0.5),
        interpolation="nearest",
    )
    picture.set_xlim(-0.5, width - 0.5)
    picture.set_ylim(height - 0.5, -0.5)
    centre = geometry.spot_centre_px
    along, across = geometry.spot_half_size_px
    primary_angle = geometry.primary.angle_deg
    picture.add_patch(
        polygon(
            rectangle_corners(centre, primary_angle, (-along, along), (-across, across)),
            fill=False,
            edgecolor="yellow",
            linewidth=1.2,
            label="direct aperture",
        )
    )
    picture.plot(*centre, marker="+", color="yellow", markersize=12)
    for band in geometry.orders:
        colour = "cyan" if band.side == 1 else "magenta"
        offset, half = band.centre_offset_px, band.half_width_px
        picture.add_patch(
            polygon(
                rectangle_corners(
                    centre,
                    band.angle_deg,
                    (band.start_px, band.stop_px),
                    (offset - half, offset + half),
                ),
                fill=False,
                edgecolor=colour,
                linewidth=1.2,
                label=f"order {band.side:+d} ({band.angle_deg:.2f}°)",
            )
        )
        inner = band.band_half_width_px + geometry.background_gap_px
        for low, high in (
            (offset - inner - geometry.background_width_px, offset - inner),
            (offset + inner, offset + inner + geometry.background_width_px),
        ):
            picture.add_patch(
                polygon(
                    rectangle_corners(
                        centre, band.angle_deg, (band.start_px, band.stop_px), (low, high)
                    ),
                    fill=False,
                    edgecolor=colour,
                    linestyle=":",
                    linewidth=0.8,
                )
            )
        dx, dy = band.direction
        picture.annotate(
            f"{band.side:+d}",
            xy=(centre[0] + band.stop_px * dx, centre[1] + band.stop_px * dy),
            xytext=(centre[0] + band.start_px * dx, centre[1] + band.start_px * dy),
            color=colour,
            arrowprops={"arrowstyle": "->", "color": colour},
        )
    picture.legend(loc="upper right", fontsize=7)
    picture.set_title(f"{image_source(image)}: log radiance", fontsize=9, y=1.0)
    picture.set_xlabel("sensor column (px)")
    picture.set_ylabel("sensor row (px)")
    for band in geometry.orders:
        try:
            extraction = extract(image, geometry, side=band.side, allow_saturated_direct=True)
        except DetectionError as exc:
            profiles.text(
                0.02,
                0.95,
                f"order {band.side:+d}: {exc}",
                transform=profiles.transAxes,
                fontsize=7,
                wrap=True,
            )
            continue
        style = "-" if band.side == 1 else "--"
        for channel, name in enumerate(CHANNEL_NAMES):
            profiles.plot(
                extraction.pixel,
                extraction.profile[:, channel],
                style,
                color=_CHANNEL_COLOURS[channel],
                linewidth=1,
                label=f"{name} ({band.side:+d})",
            )
    profiles.set_xlabel("distance from the direct spot (sensor px)")
    profiles.set_ylabel("mean radiance across the band (DN/s)")
    profiles.legend(fontsize=7)
    profiles.set_title("first-order profiles", fontsize=9, y=1.0)
    return figure
