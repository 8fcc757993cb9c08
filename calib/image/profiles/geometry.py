"""The geometry of a rig set-up: where the direct spot and the first orders fall on the sensor.

Coordinates are sensor pixels of the visible raw area: ``x`` is the column, ``y`` the row, angles run
from +x towards +y. Relative to the spot's centre and an order's direction, a point has ``u`` (distance
along the order) and ``v`` (distance across, positive to the right of the direction of travel on
screen). A geometry is plain data (:meth:`DiffractionGeometry.to_dict` / ``from_dict``), so one found on
the brightest lamp can be stored and applied to every other lamp of the capture.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.image.hdr import HdrImage

Side = Literal[1, -1]
DetectionReason = Literal[
    "no_spot", "spot_off_frame", "no_band", "band_off_frame", "saturated", "mismatch"
]

GEOMETRY_FORMAT_VERSION = 1
#: Names of the three channels, for messages.
CHANNEL_NAMES = ("R", "G", "B")


class DetectionError(InputError):
    """The image does not show what extraction needs (a spot, a band inside the frame …).

    Parameters
    ----------
    message
        What was found, and what to change at the rig.
    reason
        Machine-readable: ``no_spot``, ``spot_off_frame``, ``no_band``, ``band_off_frame``,
        ``saturated`` or ``mismatch``.
    source
        The image (file names) the problem is in.
    """

    def __init__(self, message: str, *, reason: DetectionReason, source: str | None = None):
        self.reason = reason
        super().__init__(message, source=source)


# --------------------------------------------------------------------------------------------------
# Geometry


@dataclass(frozen=True)
class OrderBand:
    """Where one first order lies, relative to the direct spot (sensor pixels).

    Parameters
    ----------
    side
        ``+1`` for the stronger first order, ``-1`` for the one on the opposite side.
    angle_deg
        Direction from the spot centre along this order, from +x towards +y.
    start_px, stop_px
        Extraction range along the direction: distances from the spot centre, margins included.
    centre_offset_px
        Offset of the band's centre line across the direction (``v``) from the spot centre.
    half_width_px
        Half-width across that is averaged into the profile.
    band_half_width_px
        The band's measured half-width at half maximum.
    relative_flux
        The order's flux relative to the ``+1`` order.
    """

    side: Side
    angle_deg: float
    start_px: float
    stop_px: float
    centre_offset_px: float
    half_width_px: float
    band_half_width_px: float
    relative_flux: float = 1.0

    @property
    def direction(self) -> tuple[float, float]:
        """Unit vector ``(dx, dy)`` along the order."""
        angle = math.radians(self.angle_deg)
        return (math.cos(angle), math.sin(angle))


@dataclass(frozen=True)
class DiffractionGeometry:
    """The direct spot and the first order(s) of one rig set-up, in sensor pixels.

    Parameters
    ----------
    sensor_shape_px
        ``(height, width)`` of the sensor area it was detected on.
    spot_centre_px
        ``(x, y)`` of the direct spot's centre.
    spot_half_size_px
        ``(along, across)`` half-sizes of the rectangle (aligned with the ``+1`` order) over which
        the direct signal is integrated.
    orders
        The first orders found, the ``+1`` (stronger) first.
    bin_px
        Width of a profile sample along the dispersion.
    background_gap_px, background_width_px
        Background strips lie this far beyond the band's (or spot's) half-maximum edge, this wide.
    notes
        What detection noticed but did not fail on (e.g. an other first order that leaves the
        frame and was left out).
    """

    sensor_shape_px: tuple[int, int]
    spot_centre_px: tuple[float, float]
    spot_half_size_px: tuple[float, float]
    orders: tuple[OrderBand, ...]
    bin_px: float = 2.0
    background_gap_px: float = 20.0
    background_width_px: float = 30.0
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.orders:
            raise InputError("a geometry needs at least one order", source="geometry")
        if self.bin_px <= 0:
            raise InputError(f"bin_px must be > 0, got {self.bin_px}", source="geometry")

    @property
    def primary(self) -> OrderBand:
        """The ``+1`` (stronger) first order."""
        return self.orders[0]

    def order(self, side: Side = 1) -> OrderBand:
        """The order on ``side``; :class:`DetectionError` when it was not found."""
        for band in self.orders:
            if band.side == side:
                return band
        raise DetectionError(
            f"no first order on side {side:+d} in this geometry (found: "
            f"{', '.join(f'{b.side:+d}' for b in self.orders)})",
            reason="no_band",
            source="geometry",
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable description (see :meth:`from_dict`)."""
        data = asdict(self)
        data["format_version"] = GEOMETRY_FORMAT_VERSION
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DiffractionGeometry:
        """Rebuild a geometry from :meth:`to_dict` output.

        Raises
        ------
        InputError
            Missing or malformed fields (named), or an unknown format version.
        """
        version = data.get("format_version", GEOMETRY_FORMAT_VERSION)
        if version != GEOMETRY_FORMAT_VERSION:
            raise InputError(
                f"geometry format version {version} is not supported (expected "
                f"{GEOMETRY_FORMAT_VERSION})",
                source="geometry",
            )
        try:
            orders = tuple(
                OrderBand(
                    side=1 if int(order["side"]) > 0 else -1,
                    angle_deg=float(order["angle_deg"]),
                    start_px=float(order["start_px"]),
                    stop_px=float(order["stop_px"]),
                    centre_offset_px=float(order["centre_offset_px"]),
                    half_width_px=float(order["half_width_px"]),
                    band_half_width_px=float(order["band_half_width_px"]),
                    relative_flux=float(order.get("relative_flux", 1.0)),
                )
                for order in data["orders"]
            )
            height, width = data["sensor_shape_px"]
            x, y = data["spot_centre_px"]
            along, across = data["spot_half_size_px"]
            return cls(
                sensor_shape_px=(int(height), int(width)),
                spot_centre_px=(float(x), float(y)),
                spot_half_size_px=(float(along), float(across)),
                orders=orders,
                bin_px=float(data.get("bin_px", 2.0)),
                background_gap_px=float(data.get("background_gap_px", 20.0)),
                background_width_px=float(data.get("background_width_px", 30.0)),
                notes=tuple(str(note) for note in data.get("notes", ())),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed geometry: {exc!r}", source="geometry") from exc


# --------------------------------------------------------------------------------------------------
# Coordinates


def image_source(image: HdrImage) -> str:
    names = [record.path.name for record in image.frames]
    if not names:
        return "image"
    return names[0] if len(names) == 1 else f"{names[0]} … {names[-1]} ({len(names)} frames)"


def sample_positions(
    image: HdrImage, channel: int, rows: slice, columns: slice
) -> tuple[FloatArray, FloatArray]:
    """Sensor ``(y, x)`` of the channel's plane samples in a window, as broadcastable arrays."""
    pitch = image.pixel_pitch_px
    origin_row, origin_column = image.channel_origin_px[channel]
    start_row, stop_row = rows.start or 0, rows.stop
    start_column, stop_column = columns.start or 0, columns.stop
    y = np.arange(start_row, stop_row, dtype=np.float64) * pitch + origin_row
    x = np.arange(start_column, stop_column, dtype=np.float64) * pitch + origin_column
    return y[:, None], x[None, :]


def to_uv(
    x: FloatArray, y: FloatArray, centre: tuple[float, float], angle_deg: float
) -> tuple[FloatArray, FloatArray]:
    angle = math.radians(angle_deg)
    dx, dy = math.cos(angle), math.sin(angle)
    relative_x, relative_y = x - centre[0], y - centre[1]
    return relative_x * dx + relative_y * dy, -relative_x * dy + relative_y * dx


def rectangle_corners(
    centre: tuple[float, float],
    angle_deg: float,
    u_range: tuple[float, float],
    v_range: tuple[float, float],
) -> FloatArray:
    """Shape ``(4, 2)``: sensor ``(x, y)`` of the ``(u, v)`` rectangle's corners, in drawing order."""
    angle = math.radians(angle_deg)
    dx, dy = math.cos(angle), math.sin(angle)
    corners = [
        (u_range[0], v_range[0]),
        (u_range[1], v_range[0]),
        (u_range[1], v_range[1]),
        (u_range[0], v_range[1]),
    ]
    return np.array(
        [(centre[0] + u * dx - v * dy, centre[1] + u * dy + v * dx) for u, v in corners]
    )


def rectangle_window(
    image: HdrImage,
    centre: tuple[float, float],
    angle_deg: float,
    u_range: tuple[float, float],
    v_range: tuple[float, float],
) -> tuple[slice, slice] | None:
    """Plane-sample window holding the ``(u, v)`` rectangle (clipped to the image), or ``None``."""
    corners = rectangle_corners(centre, angle_deg, u_range, v_range)
    pitch = image.pixel_pitch_px
    height, width = image.plane_shape
    row_lo = max(math.floor(corners[:, 1].min() / pitch) - 1, 0)
    row_hi = min(math.ceil(corners[:, 1].max() / pitch) + 2, height)
    column_lo = max(math.floor(corners[:, 0].min() / pitch) - 1, 0)
    column_hi = min(math.ceil(corners[:, 0].max() / pitch) + 2, width)
    if row_hi <= row_lo or column_hi <= column_lo:
        return None
    return slice(row_lo, row_hi), slice(column_lo, column_hi)


def rectangle_outside_edge(
    shape_px: tuple[int, int],
    centre: tuple[float, float],
    angle_deg: float,
    u_range: tuple[float, float],
    v_range: tuple[float, float],
) -> str | None:
    """The sensor edge the ``(u, v)`` rectangle crosses, or ``None`` when it lies inside."""
    height, width = shape_px
    for x, y in rectangle_corners(centre, angle_deg, u_range, v_range):
        if x < -0.5:
            return "left"
        if x > width - 0.5:
            return "right"
        if y < -0.5:
            return "top"
        if y > height - 0.5:
            return "bottom"
    return None
