"""Render what the rig's camera sees: the slit's direct image and its diffraction orders on a Bayer sensor.

The scene is described in sensor pixels. A point at column ``x`` and row ``y`` has the coordinates

``u = (x − x0) cos θ + (y − y0) sin θ``  (along the dispersion, towards the +1 order)
``v = −(x − x0) sin θ + (y − y0) cos θ``  (across)

where ``(x0, y0)`` is the centre of the direct (0th-order) spot and ``θ`` the dispersion angle
(measured from the +x axis towards +y, i.e. clockwise on screen). Radiance is in DN per second that a
pixel of the given colour would collect above black:

* the direct spot is the slit image, a rectangle with soft (raised-cosine) edges, scaled so that its
  sum over all sensor pixels is ``direct_rgb`` (DN/s, per channel);
* the +1 order at ``u > 0`` is ``profile(u) · t(v)`` where ``profile`` is given at sensor-pixel
  distances and ``t`` is a flat top of half-width ``band_half_width_px`` with soft edges (1 inside);
* optionally the −1 order (mirror image at ``u < 0``, scaled) and the 2nd order (``profile(u/2)/2``,
  twice as dispersed, scaled);
* optionally stray light of the direct spot scattered along the dispersion line (in-plane scatter
  of the grooves, the lens' flare streak): a fraction of the spot's light in a Lorentzian wing
  ``(w/π) / (w² + u²)`` along ``u`` on both sides of the spot, with the band's cross-section
  ``t(v)`` — so it lies on the band, where the background strips beside it do not see it (the
  validation protocol's :class:`calib.evaluation.validation.rig_errors.StrayLight`, in 2-D).

A :class:`SceneSignal` gives the first order as per-pixel values at sample positions, which are
interpolated at each pixel's centre. A :class:`PixelIntegratedSignal` gives it as the cumulative
integral of its density along ``u`` instead, and every pixel receives the exact integral of that
density over its own footprint (the unit square, turned by the dispersion angle, projected onto
``u``): the same per-pixel integrals ``calib.model.forward`` computes for its 1-D profiles, at any angle
and sub-pixel spot position.

:func:`render_mosaic_radiance` samples that field at every sensor pixel for the pixel's own colour
(any of RGGB, BGGR, GRBG, GBRG); :func:`expose` turns it into a raw frame: exposure time, dark
current, shot noise (Poisson in electrons), read noise, black level, quantisation and clipping, all
random numbers from the caller's seeded generator. Both are vectorised and work in row blocks, so a
24 MP frame takes a few seconds and a few hundred MB.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.core.arrays import FloatArray
from mocks.dng import DngMetadata, write_dng

Float32Array = NDArray[np.float32]
ShotNoise = Literal["poisson", "gaussian", "none"]

#: Sites of each colour in the 2×2 cell, ``(row, column)``.
BAYER_SITES: dict[str, dict[str, tuple[tuple[int, int], ...]]] = {
    "RGGB": {"R": ((0, 0),), "G": ((0, 1), (1, 0)), "B": ((1, 1),)},
    "BGGR": {"R": ((1, 1),), "G": ((0, 1), (1, 0)), "B": ((0, 0),)},
    "GRBG": {"R": ((0, 1),), "G": ((0, 0), (1, 1)), "B": ((1, 0),)},
    "GBRG": {"R": ((1, 0),), "G": ((0, 0), (1, 1)), "B": ((0, 1),)},
}
_CHANNELS = ("R", "G", "B")
_ROW_BLOCK = 256


@dataclass(frozen=True)
class SensorModel:
    """A Bayer sensor: size, CFA layout, levels and noise.

    Parameters
    ----------
    height_px, width_px
        Sensor size in pixels (even).
    cfa_pattern
        Colours of the top-left 2×2 cell.
    black_level_dn, white_level_dn
        Black offset and clipping level of the raw values (DN).
    gain_dn_per_electron
        Conversion gain: DN per photo-electron.
    read_noise_dn
        Standard deviation of the read noise (DN).
    dark_current_dn_per_s
        Dark signal accumulated per second of exposure (DN/s).
    """

    height_px: int = 4000
    width_px: int = 6000
    cfa_pattern: str = "RGGB"
    black_level_dn: int = 512
    white_level_dn: int = 16383
    gain_dn_per_electron: float = 0.5
    read_noise_dn: float = 2.5
    dark_current_dn_per_s: float = 0.0

    def __post_init__(self) -> None:
        if self.cfa_pattern not in BAYER_SITES:
            raise ValueError(f"cfa_pattern must be one of {sorted(BAYER_SITES)}")
        if self.height_px < 2 or self.width_px < 2 or self.height_px % 2 or self.width_px % 2:
            raise ValueError(
                f"sensor size must be even and ≥ 2, got {self.height_px}×{self.width_px}"
            )
        if not 0 <= self.black_level_dn < self.white_level_dn <= 65535:
            raise ValueError("need 0 ≤ black level < white level ≤ 65535")
        if self.gain_dn_per_electron <= 0 or self.read_noise_dn < 0:
            raise ValueError("gain must be > 0 and read noise ≥ 0")


@dataclass(frozen=True)
class SceneLayout:
    """Where the direct spot and the orders fall on the sensor (all lengths in sensor pixels).

    Parameters
    ----------
    spot_centre_px
        ``(x, y)``: column and row of the direct spot's centre.
    dispersion_angle_deg
        Direction from the spot to the +1 order, from +x towards +y.
    spot_half_size_px
        ``(along, across)`` half-sizes of the slit image (to the middle of its soft edge).
    band_half_width_px
        Half-width of the diffraction band's flat top plus half its edge.
    edge_px
        Width of the raised-cosine edges of the slit image and the band.
    plus_first_strength, minus_first_strength
        Scale of the +1 and −1 orders (the −1 order mirrors the +1 profile).
    second_order_strength
        Scale of the 2nd order along the +1 side (0 = none).
    background_dn_per_s
        Uniform stray light, per channel (R, G, B).
    stray_fraction, stray_wing_px
        Stray light along the band: this fraction of the direct spot's light (per channel) in a
        Lorentzian wing of half-width ``stray_wing_px`` along the dispersion, centred on the spot,
        spread across the band like the first order (0: none).
    """

    spot_centre_px: tuple[float, float]
    dispersion_angle_deg: float = 0.0
    spot_half_size_px: tuple[float, float] = (6.0, 100.0)
    band_half_width_px: float = 100.0
    edge_px: float = 6.0
    plus_first_strength: float = 1.0
    minus_first_strength: float = 0.0
    second_order_strength: float = 0.0
    background_dn_per_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stray_fraction: float = 0.0
    stray_wing_px: float = 0.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.stray_fraction < 1.0) or self.stray_wing_px < 0:
            raise ValueError("need 0 ≤ stray_fraction < 1 and stray_wing_px ≥ 0")
        if self.stray_fraction > 0 and not self.stray_wing_px > 0:
            raise ValueError("stray light needs a wing half-width > 0")

    def stray_wing(self, u: FloatArray) -> FloatArray:
        """The stray light's Lorentzian along ``u`` per pixel of length (integral 1 over all ``u``)."""
        wing = self.stray_wing_px
        return np.asarray((wing / math.pi) / (wing**2 + np.asarray(u) ** 2), dtype=np.float64)

    @property
    def direction(self) -> tuple[float, float]:
        """Unit vector ``(dx, dy)`` from the spot towards the +1 order."""
        angle = np.deg2rad(self.dispersion_angle_deg)
        return (float(np.cos(angle)), float(np.sin(angle)))


@dataclass(frozen=True, eq=False)
class SceneSignal:
    """The light of one lamp: direct spot total and first-order profile.

    Parameters
    ----------
    direct_rgb
        Shape ``(3,)``: the direct spot's radiance summed over all sensor pixels (DN/s).
    pixel
        Shape ``(n,)``: distances from the spot centre along the dispersion (sensor pixels),
        increasing.
    profile
        Shape ``(n, 3)``: first-order radiance on the band's centre line at ``pixel`` (DN/s per
        pixel); zero outside the given range.
    """

    direct_rgb: FloatArray
    pixel: FloatArray
    profile: FloatArray

    def __post_init__(self) -> None:
        direct = np.asarray(self.direct_rgb, dtype=np.float64)
        pixel = np.asarray(self.pixel, dtype=np.float64)
        profile = np.asarray(self.profile, dtype=np.float64)
        if direct.shape != (3,) or profile.shape != (pixel.size, 3) or pixel.size < 2:
            raise ValueError("need direct_rgb (3,), pixel (n ≥ 2,) and profile (n, 3)")
        if not np.all(np.diff(pixel) > 0):
            raise ValueError("pixel distances must increase")
        if (direct < 0).any() or (profile < 0).any():
            raise ValueError("radiance must be non-negative")
        object.__setattr__(self, "direct_rgb", direct)
        object.__setattr__(self, "pixel", pixel)
        object.__setattr__(self, "profile", profile)

    @property
    def reach_px(self) -> float:
        """Distance from the spot beyond which the first order is dark."""
        return float(self.pixel[-1])

    def first_order(
        self, channel: int, u: FloatArray, footprint: PixelFootprint, stretch: float = 1.0
    ) -> FloatArray:
        """Per-pixel radiance of the order at distances ``u`` (the pixel centres), DN/s.

        The profile is interpolated at ``u / stretch`` and divided by ``stretch`` (a 2nd order is the
        first order stretched twice as far); ``footprint`` is not used (point sampling).
        """
        values = np.interp(u / stretch, self.pixel, self.profile[:, channel], left=0.0, right=0.0)
        return np.asarray(values / stretch, dtype=np.float64)


@dataclass(frozen=True)
class PixelFootprint:
    """A unit pixel projected onto the dispersion axis: the sum of two centred uniform widths.

    A pixel turned by ``θ`` against the dispersion covers ``u`` with the density of
    ``U₁ + U₂``, ``U₁`` uniform over ``|cos θ|`` and ``U₂`` over ``|sin θ|`` (a trapezoid).
    """

    wide_px: float
    narrow_px: float

    @classmethod
    def at_angle(cls, angle_deg: float) -> PixelFootprint:
        cos, sin = abs(math.cos(math.radians(angle_deg))), abs(math.sin(math.radians(angle_deg)))
        return cls(max(cos, sin), min(cos, sin))


#: Gauss–Legendre nodes and weights on [−½, ½] for averaging over the footprint's narrow side.
_NARROW_NODES, _NARROW_WEIGHTS = (array / 2.0 for array in np.polynomial.legendre.leggauss(4))
#: Below this narrow width (pixels) the footprint is a plain box.
_BOX_FOOTPRINT_PX = 1e-6


@dataclass(frozen=True, eq=False)
class PixelIntegratedSignal:
    """The light of one lamp as a cumulative integral along the dispersion, integrated per pixel.

    Parameters
    ----------
    direct_rgb
        Shape ``(3,)``: the direct spot's radiance summed over all sensor pixels (DN/s).
    position_px
        Shape ``(m,)``: distances from the spot centre along the dispersion (sensor pixels),
        increasing; finely spaced (a tenth of a pixel or less), since the density is taken as
        constant between them.
    cumulative
        Shape ``(m, 3)``: ``C(u) = ∫_{position[0]}^{u} f(x) dx`` of the first order's density
        ``f`` on the band's centre line (DN/s per pixel area), non-decreasing; the order is dark
        before ``position[0]`` and beyond ``position[-1]``.

    Notes
    -----
    A pixel whose centre lies at ``u`` receives the mean of ``f`` over its footprint
    (:class:`PixelFootprint`): ``E[C(u + U₂ + a/2) − C(u + U₂ − a/2)] / a``, exact in ``U₁`` and
    a four-node Gauss–Legendre mean over the narrow side ``U₂``. Along the axis (``θ = 0``) that is
    ``C(u + ½) − C(u − ½)``: the per-pixel integral of ``calib.model.forward``.
    """

    direct_rgb: FloatArray
    position_px: FloatArray
    cumulative: FloatArray

    def __post_init__(self) -> None:
        direct = np.asarray(self.direct_rgb, dtype=np.float64)
        position = np.asarray(self.position_px, dtype=np.float64)
        cumulative = np.asarray(self.cumulative, dtype=np.float64)
        if direct.shape != (3,) or cumulative.shape != (position.size, 3) or position.size < 2:
            raise ValueError("need direct_rgb (3,), position_px (m ≥ 2,) and cumulative (m, 3)")
        if not np.all(np.diff(position) > 0):
            raise ValueError("positions must increase")
        if (direct < 0).any() or (np.diff(cumulative, axis=0) < 0).any():
            raise ValueError("radiance must be non-negative (cumulative non-decreasing)")
        object.__setattr__(self, "direct_rgb", direct)
        object.__setattr__(self, "position_px", position)
        object.__setattr__(self, "cumulative", cumulative - cumulative[0])

    @property
    def reach_px(self) -> float:
        return float(self.position_px[-1])

    def per_pixel(self, pixel: ArrayLike) -> FloatArray:
        """Shape ``(n, 3)``: the per-pixel integrals of axis-aligned pixels centred at ``pixel``."""
        centres = np.asarray(pixel, dtype=np.float64)
        footprint = PixelFootprint(1.0, 0.0)
        return np.stack([self.first_order(c, centres, footprint) for c in range(3)], axis=1)

    def first_order(
        self, channel: int, u: FloatArray, footprint: PixelFootprint, stretch: float = 1.0
    ) -> FloatArray:
        """Mean density of the order over each pixel's footprint centred at ``u``, DN/s.

        ``stretch`` spreads the order ``stretch`` times as far (``C(u / stretch)``), keeping its
        total.
        """
        column = self.cumulative[:, channel]
        last = float(column[-1])

        def cumulative_at(x: FloatArray) -> FloatArray:
            return np.interp(x / stretch, self.position_px, column, left=0.0, right=last)

        half = footprint.wide_px / 2.0
        if footprint.narrow_px < _BOX_FOOTPRINT_PX:
            nodes, weights = np.zeros(1), np.ones(1)
        else:
            nodes, weights = _NARROW_NODES * footprint.narrow_px, _NARROW_WEIGHTS
        total = np.zeros(np.shape(u), dtype=np.float64)
        for node, weight in zip(nodes, weights, strict=True):
            total += weight * (cumulative_at(u + node + half) - cumulative_at(u + node - half))
        return total / footprint.wide_px


FirstOrderSignal = SceneSignal | PixelIntegratedSignal
"""Either form of a lamp's light (both have ``direct_rgb``, ``reach_px`` and ``first_order``)."""


def soft_box(distance: FloatArray, half_size: float, edge: float) -> FloatArray:
    """1 inside ``|d| ≤ half − edge/2``, 0 beyond ``half + edge/2``, raised cosine between.

    The shape of the slit's image along and across (its integral over ``d`` is ``2 · half_size``).
    """
    if edge <= 0:
        return (np.abs(distance) <= half_size).astype(np.float64)
    ramp = np.clip((np.abs(distance) - (half_size - edge / 2.0)) / edge, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * ramp))


def _site_coordinates(
    layout: SceneLayout, rows: FloatArray, columns: FloatArray
) -> tuple[FloatArray, FloatArray]:
    dx, dy = layout.direction
    x = columns[None, :] - layout.spot_centre_px[0]
    y = rows[:, None] - layout.spot_centre_px[1]
    return x * dx + y * dy, -x * dy + y * dx


def _spot_normaliser(layout: SceneLayout, sensor: SensorModel) -> float:
    """Sum of the spot shape over every sensor pixel (so the spot sums to ``direct_rgb``)."""
    rows, columns = _bounding_rows_columns(layout, sensor, spot_only=True)
    if rows.size == 0 or columns.size == 0:
        return 0.0
    u, v = _site_coordinates(layout, rows, columns)
    along, across = layout.spot_half_size_px
    return float((soft_box(u, along, layout.edge_px) * soft_box(v, across, layout.edge_px)).sum())


def _bounding_rows_columns(
    layout: SceneLayout, sensor: SensorModel, *, spot_only: bool, reach_px: float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Sensor rows and columns of the box that holds the spot (and the orders out to ``reach``)."""
    dx, dy = layout.direction
    along, across = layout.spot_half_size_px
    margin = layout.edge_px
    corners_uv = [(s * (along + margin), t * (across + margin)) for s in (-1, 1) for t in (-1, 1)]
    if not spot_only:
        half = layout.band_half_width_px + margin
        corners_uv += [(s * reach_px, t * half) for s in (-1, 1) for t in (-1, 1)]
    x0, y0 = layout.spot_centre_px
    xs = [x0 + u * dx - v * dy for u, v in corners_uv]
    ys = [y0 + u * dy + v * dx for u, v in corners_uv]
    column_lo = max(int(np.floor(min(xs))) - 1, 0)
    column_hi = min(int(np.ceil(max(xs))) + 2, sensor.width_px)
    row_lo = max(int(np.floor(min(ys))) - 1, 0)
    row_hi = min(int(np.ceil(max(ys))) + 2, sensor.height_px)
    return (
        np.arange(row_lo, max(row_hi, row_lo), dtype=np.float64),
        np.arange(column_lo, max(column_hi, column_lo), dtype=np.float64),
    )


def _field(
    layout: SceneLayout,
    signal: FirstOrderSignal,
    channel: int,
    u: FloatArray,
    v: FloatArray,
    spot_scale: float,
) -> FloatArray:
    """Radiance of one channel at coordinates ``(u, v)`` (no uniform background)."""
    along, across = layout.spot_half_size_px
    value = spot_scale * soft_box(u, along, layout.edge_px) * soft_box(v, across, layout.edge_px)
    band = soft_box(v, layout.band_half_width_px, layout.edge_px)
    footprint = PixelFootprint.at_angle(layout.dispersion_angle_deg)
    orders = np.zeros_like(u)
    if layout.plus_first_strength:
        orders += layout.plus_first_strength * signal.first_order(channel, u, footprint)
    if layout.minus_first_strength:
        orders += layout.minus_first_strength * signal.first_order(channel, -u, footprint)
    if layout.second_order_strength:
        orders += layout.second_order_strength * signal.first_order(channel, u, footprint, 2.0)
    if layout.stray_fraction:
        # The spot's light per row of the band (the band's cross-section integrates to twice its
        # half-width), spread along u by the wing; sampled at the pixel centre (the wing is ≥ 100×
        # wider than a pixel).
        per_row = float(signal.direct_rgb[channel]) / (2.0 * layout.band_half_width_px)
        orders += layout.stray_fraction * per_row * layout.stray_wing(u)
    return value + orders * band


def render_mosaic_radiance(
    layout: SceneLayout, signal: FirstOrderSignal, sensor: SensorModel
) -> Float32Array:
    """Radiance each sensor pixel sees through its own colour filter.

    Parameters
    ----------
    layout
        Spot position, dispersion angle, band width, which orders are present.
    signal
        The lamp's direct total and first-order profile (point-sampled or pixel-integrated).
    sensor
        Size and CFA layout.

    Returns
    -------
    numpy.ndarray
        Shape ``(height_px, width_px)``, float32, DN/s.
    """
    reach = signal.reach_px * (2.0 if layout.second_order_strength else 1.0) + 1.0
    if layout.stray_fraction:
        reach = max(reach, math.hypot(sensor.width_px, sensor.height_px))  # the wing's whole length
    rows, columns = _bounding_rows_columns(layout, sensor, spot_only=False, reach_px=reach)
    normaliser = _spot_normaliser(layout, sensor)
    mosaic = np.empty((sensor.height_px, sensor.width_px), dtype=np.float32)
    sites = BAYER_SITES[sensor.cfa_pattern]
    for channel, name in enumerate(_CHANNELS):
        spot_scale = signal.direct_rgb[channel] / normaliser if normaliser > 0 else 0.0
        for site_row, site_column in sites[name]:
            target = mosaic[site_row::2, site_column::2]
            target[...] = layout.background_dn_per_s[channel]
            site_rows = rows[(rows % 2) == site_row]
            site_columns = columns[(columns % 2) == site_column]
            if site_rows.size == 0 or site_columns.size == 0:
                continue
            u, v = _site_coordinates(layout, site_rows, site_columns)
            block = _field(layout, signal, channel, u, v, spot_scale)
            first_row, first_column = int(site_rows[0]) // 2, int(site_columns[0]) // 2
            target[
                first_row : first_row + site_rows.size,
                first_column : first_column + site_columns.size,
            ] += block.astype(np.float32)
    return mosaic


def _row_blocks(height: int) -> Iterator[slice]:
    for start in range(0, height, _ROW_BLOCK):
        yield slice(start, min(start + _ROW_BLOCK, height))


def expose(
    mosaic_radiance: ArrayLike,
    exposure_s: float,
    sensor: SensorModel,
    rng: np.random.Generator,
    *,
    shot_noise: ShotNoise = "poisson",
) -> NDArray[np.uint16]:
    """Simulate one raw frame of the scene.

    Parameters
    ----------
    mosaic_radiance
        Shape ``(height_px, width_px)``: per-pixel radiance in DN/s (from
        :func:`render_mosaic_radiance`).
    exposure_s
        Exposure time in seconds.
    sensor
        Gain, read noise, dark current, black and white levels.
    rng
        Seeded generator for every random number.
    shot_noise
        ``"poisson"`` (photo-electrons), ``"gaussian"`` (same variance, faster) or ``"none"``.

    Returns
    -------
    numpy.ndarray
        Shape ``(height_px, width_px)``, uint16 raw values: black + signal + noise, rounded and
        clipped to ``[0, white_level_dn]``.
    """
    radiance = np.asarray(mosaic_radiance)
    if radiance.shape != (sensor.height_px, sensor.width_px):
        raise ValueError(f"radiance shape {radiance.shape} does not match the sensor")
    if not exposure_s > 0:
        raise ValueError(f"exposure_s must be > 0, got {exposure_s}")
    raw = np.empty(radiance.shape, dtype=np.uint16)
    gain = sensor.gain_dn_per_electron
    for rows in _row_blocks(sensor.height_px):
        mean_dn = np.maximum(
            radiance[rows].astype(np.float64) * exposure_s
            + sensor.dark_current_dn_per_s * exposure_s,
            0.0,
        )
        if shot_noise == "poisson":
            signal_dn = rng.poisson(mean_dn / gain) * gain
        elif shot_noise == "gaussian":
            signal_dn = mean_dn + rng.standard_normal(mean_dn.shape) * np.sqrt(gain * mean_dn)
        else:
            signal_dn = mean_dn
        if sensor.read_noise_dn:
            signal_dn = signal_dn + rng.standard_normal(mean_dn.shape) * sensor.read_noise_dn
        np.clip(np.rint(signal_dn + sensor.black_level_dn), 0, sensor.white_level_dn, out=signal_dn)
        raw[rows] = signal_dn
    return raw


def smooth_signal(
    *,
    start_px: float = 150.0,
    stop_px: float = 800.0,
    peak_dn_per_s: tuple[float, float, float] = (2000.0, 2000.0, 2000.0),
    direct_rgb: tuple[float, float, float] = (3.0e7, 5.0e7, 2.0e7),
    step_px: float = 0.5,
) -> SceneSignal:
    """A smooth stand-in for a broadband lamp seen through a grating (until ``calib.model.forward``).

    Three Gaussian channel responses along a linear wavelength axis (400 nm at ``start_px + 50``,
    0.5 nm per pixel when the band spans 650 px), tapered to zero at both ends.

    Parameters
    ----------
    start_px, stop_px
        Where the first-order profile is defined (zero outside), sensor pixels from the spot.
    peak_dn_per_s
        Peak radiance of each channel on the band's centre line.
    direct_rgb
        The direct spot's total per channel (DN/s summed over pixels).
    step_px
        Sampling of the returned profile.
    """
    pixel = np.arange(start_px, stop_px + step_px / 2, step_px)
    fraction = (pixel - start_px) / (stop_px - start_px)
    wavelength_nm = 375.0 + 350.0 * fraction
    taper = np.sin(np.pi * fraction) ** 2
    centres_nm, widths_nm = (600.0, 530.0, 460.0), (40.0, 40.0, 30.0)
    profile = np.stack(
        [
            peak * np.exp(-0.5 * ((wavelength_nm - centre) / width) ** 2) * taper
            for peak, centre, width in zip(peak_dn_per_s, centres_nm, widths_nm, strict=True)
        ],
        axis=1,
    )
    return SceneSignal(direct_rgb=np.array(direct_rgb), pixel=pixel, profile=profile)


def dng_metadata(sensor: SensorModel, exposure_s: float | None, **fields: object) -> DngMetadata:
    """DNG metadata of a frame from ``sensor`` (CFA layout, levels), with extra ``fields``."""
    template = DngMetadata(
        exposure_s=exposure_s,
        cfa_pattern=sensor.cfa_pattern,
        black_level_dn=sensor.black_level_dn,
        white_level_dn=sensor.white_level_dn,
    )
    return replace(template, **fields)  # type: ignore[arg-type]


def write_bracket(
    directory: str | os.PathLike[str],
    mosaic_radiance: ArrayLike,
    sensor: SensorModel,
    exposures_s: Sequence[float],
    rng: np.random.Generator,
    *,
    prefix: str = "frame",
    shot_noise: ShotNoise = "poisson",
    **fields: object,
) -> list[Path]:
    """Expose the scene at each exposure time and write the frames as DNG files.

    Parameters
    ----------
    directory
        Existing directory for the files ``{prefix}_{index:04d}.dng``.
    mosaic_radiance
        Shape ``(height_px, width_px)``: from :func:`render_mosaic_radiance` (zeros for darks).
    sensor
        The sensor (noise, levels, CFA).
    exposures_s
        One frame per exposure time.
    rng
        Seeded generator.
    prefix
        File name prefix.
    shot_noise
        See :func:`expose`.
    **fields
        Extra :class:`mocks.dng.DngMetadata` fields (``iso``, ``model`` …).

    Returns
    -------
    list of Path
        The files, in the order of ``exposures_s``.
    """
    folder = Path(directory)
    paths = []
    for index, exposure in enumerate(exposures_s):
        raw = expose(mosaic_radiance, exposure, sensor, rng, shot_noise=shot_noise)
        paths.append(
            write_dng(
                folder / f"{prefix}_{index:04d}.dng", raw, dng_metadata(sensor, exposure, **fields)
            )
        )
    return paths


def channel_planes(mosaic: ArrayLike, cfa_pattern: str) -> FloatArray:
    """The R, G (mean of both greens), B planes of a mosaic, as :func:`calib.image.raw.read_raw` lays them out.

    Parameters
    ----------
    mosaic
        Shape ``(height_px, width_px)`` (even), e.g. the noiseless radiance of
        :func:`render_mosaic_radiance`.
    cfa_pattern
        Colours of the top-left 2×2 cell.

    Returns
    -------
    numpy.ndarray
        Shape ``(3, height_px // 2, width_px // 2)``, float64.
    """
    array = np.asarray(mosaic, dtype=np.float64)
    sites = BAYER_SITES[cfa_pattern]

    def plane(site: tuple[int, int]) -> FloatArray:
        return array[site[0] :: 2, site[1] :: 2]

    (red,) = sites["R"]
    (blue,) = sites["B"]
    first, second = sites["G"]
    return np.stack([plane(red), 0.5 * (plane(first) + plane(second)), plane(blue)])


def channel_origins(cfa_pattern: str) -> tuple[tuple[float, float], ...]:
    """``(row, column)`` of R, G (mean of both greens) and B inside the 2×2 cell, as in calib.image.raw."""
    sites = BAYER_SITES[cfa_pattern]
    (red,) = sites["R"]
    (blue,) = sites["B"]
    first, second = sites["G"]
    return (
        (float(red[0]), float(red[1])),
        ((first[0] + second[0]) / 2.0, (first[1] + second[1]) / 2.0),
        (float(blue[0]), float(blue[1])),
    )
