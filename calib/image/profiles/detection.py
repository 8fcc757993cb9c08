"""Automatic detection of the direct spot and the first-order band(s) in an HDR image.

1. The spot is the brightest feature of a block-averaged luminance image; its centre is the
   intensity-weighted centroid of all channels at full resolution, each sample at its sensor position.
2. Bands are the regions outside the spot that rise clearly above the noise; the one with most flux is
   the first order (``side = +1``), and a region on the opposite side with at least 5 % of its flux is
   the other first order (``side = -1``). When the stronger one runs off the frame and the other is
   whole, the other is read as ``side = +1`` and the note says so.
3. An order's direction and across-offset come from a line fitted to its across-centroids; its width is
   the half-maximum width of the across-profile; its extent is where the along-profile exceeds
   ``extent_fraction`` of its maximum, plus a margin, cut at the valley before a 2nd order.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import BoolArray, FloatArray
from calib.core.mapping import OPPOSITE_ORDER_TOLERANCE_DEG
from calib.image.blocks import DETECTION_MAX_SIZE, block_factor, block_mean
from calib.image.hdr import HdrImage
from calib.image.profiles.geometry import (
    DetectionError,
    DiffractionGeometry,
    OrderBand,
    Side,
    image_source,
    rectangle_outside_edge,
    rectangle_window,
    sample_positions,
    to_uv,
)

#: The spot must rise this many noise sigmas above the background.
_MIN_SPOT_SNR = 20.0
#: Band candidates rise this many noise sigmas above the background.
_BAND_SNR = 8.0
#: A band extends where its along-profile exceeds this fraction of its maximum (``detect_geometry``'s
#: default); beyond it the band counts as dark.
EXTENT_FRACTION = 0.01
#: A region on the other side counts as the other first order above this fraction of the flux.
_MIN_ORDER_FLUX_RATIO = 0.05
_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class _Downsampled:
    """Channel-summed radiance, block-averaged for detection, with the sensor position of samples."""

    luminance: FloatArray  # (H, W)
    factor: int  # plane samples per block side
    pitch_px: float  # sensor pixels per block
    offset_px: float  # sensor coordinate of block (0, 0)'s centre
    background: float
    noise: float

    def sensor_xy(self, rows: FloatArray, columns: FloatArray) -> tuple[FloatArray, FloatArray]:
        return columns * self.pitch_px + self.offset_px, rows * self.pitch_px + self.offset_px

    def grid_uv(
        self, centre: tuple[float, float], angle_deg: float
    ) -> tuple[FloatArray, FloatArray]:
        rows = np.arange(self.luminance.shape[0], dtype=np.float64)[:, None]
        columns = np.arange(self.luminance.shape[1], dtype=np.float64)[None, :]
        x, y = self.sensor_xy(rows, columns)
        return to_uv(x, y, centre, angle_deg)


def _downsample(image: HdrImage) -> _Downsampled:
    luminance = image.radiance.sum(axis=0, dtype=np.float64)
    finite = np.isfinite(luminance)
    if not finite.all():
        luminance[~finite] = 0.0
    if image.saturated.any():
        saturated = image.saturated.any(axis=0)
        luminance[saturated] = max(float(luminance.max()), float(luminance[saturated].max()))
    factor = block_factor(luminance.shape, DETECTION_MAX_SIZE)
    small = block_mean(luminance, factor)
    background = float(np.median(small))
    noise = _MAD_TO_SIGMA * float(np.median(np.abs(small - background)))
    peak = float(small.max())
    noise = max(noise, 1e-9 * max(abs(peak), 1.0))
    pitch = image.pixel_pitch_px
    return _Downsampled(
        luminance=small,
        factor=factor,
        pitch_px=factor * pitch,
        offset_px=(factor - 1) / 2.0 * pitch + 0.5,
        background=background,
        noise=noise,
    )


@dataclass(frozen=True)
class _Spot:
    centre_px: tuple[float, float]
    zone: BoolArray  # on the downsampled grid: the spot and its immediate surroundings
    peak: float


def _find_spot(image: HdrImage, small: _Downsampled, source: str) -> _Spot:
    from scipy import ndimage

    smooth = ndimage.gaussian_filter(small.luminance, 1.0)
    peak_index = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
    peak = float(smooth[peak_index])
    height = peak - small.background
    if height < _MIN_SPOT_SNR * small.noise:
        raise DetectionError(
            f"no direct spot: the brightest point is only {height / small.noise:.1f} noise sigmas "
            "above the background; check that the lamp is on and the slit is in the field of view",
            reason="no_spot",
            source=source,
        )
    labels, _ = ndimage.label(smooth > small.background + 0.5 * height)
    core = labels == labels[peak_index]
    rows, columns = np.nonzero(core)
    minor = min(np.ptp(rows), np.ptp(columns)) + 1
    radius = max(2, math.ceil(0.5 * minor)) + 2
    zone = ndimage.binary_dilation(core, iterations=radius)
    blocks_h, blocks_w = smooth.shape
    if (
        rows.min() == 0
        or columns.min() == 0
        or rows.max() == blocks_h - 1
        or columns.max() == blocks_w - 1
    ):
        raise DetectionError(
            "the direct spot touches the edge of the frame, so its centre and total are unknown; "
            "aim the camera so the slit image is fully inside the frame",
            reason="spot_off_frame",
            source=source,
        )
    centre = _spot_centroid(image, small, zone)
    return _Spot(centre_px=centre, zone=zone, peak=peak)


def _spot_centroid(image: HdrImage, small: _Downsampled, zone: BoolArray) -> tuple[float, float]:
    """Intensity-weighted centroid of the spot zone at full plane resolution, all channels."""
    rows, columns = np.nonzero(zone)
    block_rows = slice(int(rows.min()), int(rows.max()) + 1)
    block_columns = slice(int(columns.min()), int(columns.max()) + 1)
    factor = small.factor
    window = (
        slice(block_rows.start * factor, block_rows.stop * factor),
        slice(block_columns.start * factor, block_columns.stop * factor),
    )
    zone_samples = np.kron(zone[block_rows, block_columns], np.ones((factor, factor), dtype=bool))
    background = small.background / 3.0  # per channel, the detection image sums three
    total = sum_x = sum_y = 0.0
    for channel in range(3):
        values = image.radiance[channel][window].astype(np.float64) - background
        values = np.where(zone_samples & np.isfinite(values), np.maximum(values, 0.0), 0.0)
        y, x = sample_positions(image, channel, *window)
        total += float(values.sum())
        sum_x += float((values * x).sum())
        sum_y += float((values * y).sum())
    if total <= 0:
        raise DetectionError("the direct spot has no signal above background", reason="no_spot")
    return (sum_x / total, sum_y / total)


@dataclass(frozen=True)
class _Candidate:
    angle_deg: float
    flux: float
    mask: BoolArray


def _band_candidates(small: _Downsampled, spot: _Spot) -> list[_Candidate]:
    from scipy import ndimage

    smooth = ndimage.gaussian_filter(small.luminance, 1.0)
    significant = (smooth > small.background + _BAND_SNR * small.noise) & ~spot.zone
    labels, count = ndimage.label(significant)
    if count == 0:
        return []
    excess = np.maximum(smooth - small.background, 0.0)
    index = np.arange(1, count + 1)
    flux = ndimage.sum(excess, labels, index)
    sizes = ndimage.sum(np.ones_like(excess), labels, index)
    centroid_rows = ndimage.sum(excess * np.arange(excess.shape[0])[:, None], labels, index) / flux
    centroid_columns = (
        ndimage.sum(excess * np.arange(excess.shape[1])[None, :], labels, index) / flux
    )
    candidates = []
    for label, total, size, row, column in zip(
        index, flux, sizes, centroid_rows, centroid_columns, strict=True
    ):
        if size < 6 or total <= 0:
            continue
        x, y = small.sensor_xy(np.array(row), np.array(column))
        angle = math.degrees(math.atan2(float(y) - spot.centre_px[1], float(x) - spot.centre_px[0]))
        candidates.append(_Candidate(angle, float(total), labels == label))
    return sorted(candidates, key=lambda c: -c.flux)


def _angle_difference(a_deg: float, b_deg: float) -> float:
    return (a_deg - b_deg + 180.0) % 360.0 - 180.0


@dataclass
class _CentroidSums:
    """Per along-bin sums of weight, weight × across and weight × along."""

    weight: FloatArray
    across: FloatArray
    along: FloatArray

    @classmethod
    def zeros(cls, n_bins: int) -> _CentroidSums:
        return cls(np.zeros(n_bins), np.zeros(n_bins), np.zeros(n_bins))

    def add(
        self, bins: NDArray[np.int64], weights: FloatArray, u: FloatArray, v: FloatArray
    ) -> None:
        size = self.weight.size
        self.weight += np.bincount(bins, weights, minlength=size)[:size]
        self.across += np.bincount(bins, weights * v, minlength=size)[:size]
        self.along += np.bincount(bins, weights * u, minlength=size)[:size]

    def line(self) -> tuple[float, float] | None:
        """Tilt (radians) and intercept of the weighted line through the bins' centroids."""
        filled = self.weight > 0.05 * self.weight.max()
        if filled.sum() < 3:
            return None
        along = self.along[filled] / self.weight[filled]
        across = self.across[filled] / self.weight[filled]
        slope, intercept = np.polyfit(along, across, 1, w=np.sqrt(self.weight[filled]))
        return math.atan(slope), float(intercept)


def _iterate_axis(
    angle_deg: float,
    offset_px: float,
    sums_for: Callable[[float, float], _CentroidSums | None],
    *,
    iterations: int = 3,
    tolerance_rad: float = 1e-6,
) -> tuple[float, float]:
    """Rotate the axis by the tilt of the centroids' line until it lies along the band."""
    for _ in range(iterations):
        sums = sums_for(angle_deg, offset_px)
        fitted = sums.line() if sums is not None else None
        if fitted is None:
            break
        tilt, intercept = fitted
        angle_deg += math.degrees(tilt)
        offset_px = intercept * math.cos(tilt)
        if abs(tilt) < tolerance_rad:
            break
    return angle_deg, offset_px


def _refine_axis(
    small: _Downsampled, centre: tuple[float, float], candidate: _Candidate
) -> tuple[float, float]:
    """Angle and across-offset of the band's centre line from its across-centroids along it."""
    from scipy import ndimage

    excess = np.maximum(small.luminance - small.background, 0.0)
    region = ndimage.binary_dilation(candidate.mask, iterations=2) & (excess > 0)
    if region.sum() < 10:
        return candidate.angle_deg, 0.0

    def sums_for(angle_deg: float, _offset_px: float) -> _CentroidSums:
        u, v = small.grid_uv(centre, angle_deg)
        bins = np.floor(u[region] / small.pitch_px).astype(np.int64)
        bins -= bins.min()
        sums = _CentroidSums.zeros(int(bins.max()) + 1)
        sums.add(bins, excess[region], u[region], v[region])
        return sums

    return _iterate_axis(candidate.angle_deg, 0.0, sums_for)


def _refine_axis_exact(
    image: HdrImage,
    centre: tuple[float, float],
    angle_deg: float,
    offset_px: float,
    half_width_px: float,
    u_range: tuple[float, float],
) -> tuple[float, float]:
    """Refit the band's centre line on the full-resolution planes, every sample at its position.

    The block-averaged detection image puts R, G and B of a cell at one place although they sit up
    to a pixel apart; as the band's colour changes along it, that would tilt the fitted line. Here
    each channel's samples keep their own sensor coordinates, in a window symmetric about the line.
    """
    bin_px = max(8.0, (u_range[1] - u_range[0]) / 64.0)
    n_bins = max(int((u_range[1] - u_range[0]) / bin_px), 1)

    def sums_for(angle: float, offset: float) -> _CentroidSums | None:
        window = rectangle_window(
            image, centre, angle, u_range, (offset - half_width_px, offset + half_width_px)
        )
        if window is None:
            return None
        sums = _CentroidSums.zeros(n_bins)
        for channel in range(3):
            y, x = sample_positions(image, channel, *window)
            u, v = to_uv(x, y, centre, angle)
            values = image.radiance[channel][window].astype(np.float64)
            bins = np.floor((u - u_range[0]) / bin_px).astype(np.int64)
            inside = (np.abs(v - offset) <= half_width_px) & (bins >= 0) & (bins < n_bins)
            inside &= np.isfinite(values)
            sums.add(bins[inside], values[inside], u[inside], v[inside])
        return sums

    return _iterate_axis(angle_deg, offset_px, sums_for)


def _bin_means(sums: NDArray[Any], counts: NDArray[Any]) -> FloatArray:
    """``sums / counts`` per bin, NaN for empty bins."""
    means = np.full(sums.shape, np.nan)
    filled = counts > 0
    means[filled] = sums[filled] / counts[filled]
    return means


def _strip_profiles(
    small: _Downsampled,
    centre: tuple[float, float],
    angle_deg: float,
    offset_px: float,
    half_width_px: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Mean excess along the centre strip ``|v − offset| ≤ half_width`` in bins of one block."""
    u, v = small.grid_uv(centre, angle_deg)
    excess = small.luminance - small.background
    inside = (np.abs(v - offset_px) <= half_width_px) & (u > 0)
    bin_width = small.pitch_px
    bins = np.floor(u[inside] / bin_width).astype(np.int64)
    height, width = small.luminance.shape
    reach = math.hypot(height, width) * bin_width
    n_bins = int(reach / bin_width) + 2
    keep = bins < n_bins
    counts = np.bincount(bins[keep], minlength=n_bins).astype(np.float64)
    sums = np.bincount(bins[keep], excess[inside][keep], minlength=n_bins)
    expected = max(2.0 * half_width_px / bin_width, 1.0)
    coverage = counts / expected
    centres = (np.arange(n_bins, dtype=np.float64) + 0.5) * bin_width
    return centres, _bin_means(sums, counts), coverage


def _across_profile(
    small: _Downsampled,
    centre: tuple[float, float],
    angle_deg: float,
    u_range: tuple[float, float],
) -> tuple[FloatArray, FloatArray]:
    u, v = small.grid_uv(centre, angle_deg)
    excess = small.luminance - small.background
    inside = (u >= u_range[0]) & (u <= u_range[1])
    bin_width = small.pitch_px
    v_inside = v[inside]
    lowest = float(np.floor(v_inside.min() / bin_width)) * bin_width
    bins = np.floor((v_inside - lowest) / bin_width).astype(np.int64)
    counts = np.bincount(bins).astype(np.float64)
    sums = np.bincount(bins, excess[inside])
    centres = lowest + (np.arange(counts.size, dtype=np.float64) + 0.5) * bin_width
    return centres, _bin_means(sums, counts)


def _crossing(
    centres: FloatArray, values: FloatArray, inside: int, outside: int, level: float
) -> float:
    """Linear interpolation of where ``values`` crosses ``level`` between two neighbouring bins."""
    if not np.isfinite(values[outside]):
        return float(centres[outside])
    fraction = (values[inside] - level) / (values[inside] - values[outside])
    return float(centres[inside] + fraction * (centres[outside] - centres[inside]))


def _half_maximum_edges(
    centres: FloatArray, values: FloatArray, near: float
) -> tuple[float, float] | None:
    """Where ``values`` falls to half its maximum on each side of the maximum nearest ``near``.

    ``None`` when a side does not come down to half maximum inside the data.
    """
    finite = np.isfinite(values)
    if finite.sum() < 3:
        return None
    step = float(centres[1] - centres[0])
    local = finite & (np.abs(centres - near) <= max(3 * step, 0.25 * float(np.ptp(centres))))
    if not local.any():
        return None
    peak = int(np.argmax(np.where(local, values, -np.inf)))
    half = 0.5 * float(values[peak])
    below = ~(np.where(finite, values, -np.inf) > half)
    left = np.flatnonzero(below[:peak])
    right = np.flatnonzero(below[peak:])
    if left.size == 0 or right.size == 0:
        return None
    lo_out, hi_out = int(left[-1]), peak + int(right[0])
    if not (np.isfinite(values[lo_out]) and np.isfinite(values[hi_out])):
        return None  # the band reaches the frame's edge before falling to half maximum
    return (
        _crossing(centres, values, lo_out + 1, lo_out, half),
        _crossing(centres, values, hi_out - 1, hi_out, half),
    )


@dataclass(frozen=True)
class _Settings:
    across_fraction: float
    extent_fraction: float
    margin_fraction: float
    source: str


def _measure_order(
    image: HdrImage,
    small: _Downsampled,
    spot: _Spot,
    candidate: _Candidate,
    side: Side,
    settings: _Settings,
) -> OrderBand:
    source = settings.source
    centre = spot.centre_px
    angle, offset = _refine_axis(small, centre, candidate)
    # first guess of the width from the candidate region's spread across the axis
    u, v = small.grid_uv(centre, angle)
    region_v = v[candidate.mask]
    half_width_guess = max(float(np.ptp(region_v)) / 2.0, small.pitch_px)
    region_u = u[candidate.mask]
    u_range = (float(region_u.min()), float(region_u.max()))
    across_centres, across = _across_profile(small, centre, angle, u_range)
    edges = _half_maximum_edges(across_centres, across, offset)
    if edges is None:
        raise DetectionError(
            "the first-order band's edges across the dispersion are not inside the frame; "
            "the band runs off the frame sideways",
            reason="band_off_frame",
            source=source,
        )
    offset = 0.5 * (edges[0] + edges[1])
    band_half_width = 0.5 * (edges[1] - edges[0])
    if not band_half_width > 0:
        band_half_width = half_width_guess
    strip = max(0.5 * band_half_width, small.pitch_px)
    along_centres, along, coverage = _strip_profiles(small, centre, angle, offset, strip)
    start, stop = _along_extent(
        along_centres, along, coverage, spot, small, centre, angle, settings.extent_fraction, source
    )
    angle, offset = _refine_axis_exact(
        image, centre, angle, offset, band_half_width + small.pitch_px, (start, stop)
    )
    margin = settings.margin_fraction * (stop - start)
    spot_edge = _zone_reach(small, spot.zone, centre, angle)
    start = max(start - margin, spot_edge)
    stop_limit = _last_covered(along_centres, coverage, small.pitch_px)
    stop = min(stop + margin, stop_limit)
    half_width = settings.across_fraction * band_half_width
    edge = rectangle_outside_edge(
        image.sensor_shape_px,
        centre,
        angle,
        (start, stop),
        (offset - half_width, offset + half_width),
    )
    if edge is not None:
        raise DetectionError(
            f"the first-order band (side {side:+d}) runs off the {edge} edge of the frame; "
            "move or rotate the camera so the whole band is in view",
            reason="band_off_frame",
            source=source,
        )
    return OrderBand(
        side=side,
        angle_deg=angle,
        start_px=start,
        stop_px=stop,
        centre_offset_px=offset,
        half_width_px=half_width,
        band_half_width_px=band_half_width,
    )


def _zone_reach(
    small: _Downsampled, zone: BoolArray, centre: tuple[float, float], angle_deg: float
) -> float:
    """Farthest extent of the spot zone along the direction (sensor pixels)."""
    u, _ = small.grid_uv(centre, angle_deg)
    return float(u[zone].max()) + small.pitch_px / 2.0


def _last_covered(centres: FloatArray, coverage: FloatArray, pitch: float) -> float:
    covered = np.flatnonzero(coverage >= 0.9)
    return float(centres[covered[-1]] + pitch / 2.0) if covered.size else float(centres[-1])


def _along_extent(
    centres: FloatArray,
    along: FloatArray,
    coverage: FloatArray,
    spot: _Spot,
    small: _Downsampled,
    centre: tuple[float, float],
    angle_deg: float,
    extent_fraction: float,
    source: str,
) -> tuple[float, float]:
    """Start and stop (along distance) of the run above ``extent_fraction`` of the band maximum."""
    from scipy import ndimage

    spot_edge = _zone_reach(small, spot.zone, centre, angle_deg)
    usable = (centres > spot_edge) & np.isfinite(along) & (coverage >= 0.5)
    values = np.where(usable, along, -np.inf)
    if not np.isfinite(values).any() or values.max() <= 0:
        raise DetectionError(
            "no first-order band along the detected direction", reason="no_band", source=source
        )
    peak_index = int(np.argmax(values))
    threshold = extent_fraction * values[peak_index]
    above = values > threshold
    first = peak_index
    while first > 0 and above[first - 1]:
        first -= 1
    last = peak_index
    while last + 1 < values.size and above[last + 1]:
        last += 1
    start, stop = float(centres[first]), float(centres[last])
    # a 2nd order begins near twice the first order's start: cut at the valley between them
    if stop > 1.8 * start > 0:
        window = (centres >= 1.5 * start) & (centres <= min(stop, 2.2 * start)) & above
        if window.any():
            smoothed = ndimage.uniform_filter1d(np.where(np.isfinite(values), values, 0.0), 3)
            candidates = np.flatnonzero(window)
            valley = candidates[int(np.argmin(smoothed[candidates]))]
            if smoothed[valley] < 0.3 * values[peak_index] and valley > peak_index:
                last = valley
                stop = float(centres[valley])
    after = last + 1
    if after >= values.size or coverage[after] < 0.9 or not np.isfinite(along[after]):
        raise DetectionError(
            f"the first-order band runs off the frame: its signal is still "
            f"{100 * values[last] / values[peak_index]:.0f}% of its maximum at the frame's edge, "
            f"{stop:.0f} px from the spot; move or rotate the camera (or shorten the distance)",
            reason="band_off_frame",
            source=source,
        )
    return start, stop


#: The other first order's light lies, on average, at least this fraction of the stronger one's
#: in-frame light's distance from the spot. The two are the same grating's orders, so whole they
#: lie equally far (the incidence moves them by a few %); the stronger one, cut by the frame, lies
#: nearer. Stray light around the spot (a Lorentzian wing on both sides) lies much nearer still.
_MIRROR_DISTANCE_FRACTION = 0.7
#: A first order over 400–700 nm ends about 1.75× as far from the spot as it starts; a region
#: shorter than this fraction of its start is no first order.
_MIN_ORDER_LENGTH_FRACTION = 0.3


def _mirrors(
    small: _Downsampled, spot: _Spot, stronger: _Candidate, other: _Candidate, measured: OrderBand
) -> bool:
    """Whether ``other`` (measured as ``measured``) can be the other first order of ``stronger``:
    opposite to it as measured, its light about as far from the spot, and as long as a first order
    is for where it starts. Stray light or a reflection that only happens to lie on the other
    side is not read in the stronger order's place."""
    if abs(_angle_difference(measured.angle_deg, stronger.angle_deg + 180.0)) > (
        OPPOSITE_ORDER_TOLERANCE_DEG
    ):
        return False
    distances = []
    for candidate in (stronger, other):
        u, _ = small.grid_uv(spot.centre_px, candidate.angle_deg)
        light = np.clip(small.luminance[candidate.mask] - small.background, 0.0, None)
        total = float(light.sum())
        if not total > 0:
            return False
        distances.append(float(np.sum(light * u[candidate.mask])) / total)
    if distances[1] < _MIRROR_DISTANCE_FRACTION * distances[0]:
        return False
    return measured.stop_px - measured.start_px >= _MIN_ORDER_LENGTH_FRACTION * measured.start_px


def _spot_half_size(small: _Downsampled, spot: _Spot, primary: OrderBand) -> tuple[float, float]:
    u, v = small.grid_uv(spot.centre_px, primary.angle_deg)
    pitch = small.pitch_px
    along = float(np.abs(u[spot.zone]).max()) + pitch
    across = float(np.abs(v[spot.zone]).max()) + pitch
    along = min(along, 0.8 * primary.start_px)
    return along, across


def detect_geometry(
    image: HdrImage,
    *,
    across_fraction: float = 0.8,
    extent_fraction: float = EXTENT_FRACTION,
    margin_fraction: float = 0.05,
    bin_px: float = 2.0,
) -> DiffractionGeometry:
    """Find the direct spot and the first order(s) in an HDR image.

    Parameters
    ----------
    image
        The merged bracket of a bright, broadband lamp.
    across_fraction
        Fraction of the band's half-maximum half-width that is averaged into the profile (the
        band's soft edges are left out).
    extent_fraction
        The band extends where its along-profile exceeds this fraction of its maximum.
    margin_fraction
        Margin added at both ends of the band, as a fraction of its length.
    bin_px
        Profile sample width along the dispersion, sensor pixels.

    Returns
    -------
    DiffractionGeometry

    Raises
    ------
    DetectionError
        No spot, spot on the frame's edge, no band, or a band that runs off the frame.
    """
    source = image_source(image)
    if not 0 < across_fraction <= 1:
        raise ValueError(f"across_fraction must be in (0, 1], got {across_fraction}")
    small = _downsample(image)
    spot = _find_spot(image, small, source)
    candidates = _band_candidates(small, spot)
    if not candidates:
        raise DetectionError(
            "no first-order band: nothing but the direct spot rises above the noise; check the "
            "grating and that the band is in the field of view (a longer exposure may help)",
            reason="no_band",
            source=source,
        )
    primary_candidate = candidates[0]
    opposite = [
        c
        for c in candidates[1:]
        if abs(_angle_difference(c.angle_deg, primary_candidate.angle_deg + 180.0))
        <= OPPOSITE_ORDER_TOLERANCE_DEG
        and c.flux >= _MIN_ORDER_FLUX_RATIO * primary_candidate.flux
    ]
    settings = _Settings(across_fraction, extent_fraction, margin_fraction, source)
    notes: list[str] = []
    try:
        primary = _measure_order(image, small, spot, primary_candidate, 1, settings)
    except DetectionError as exc:
        # The stronger first order leaves the frame; the other one, whole, is the same grating
        # seen at the opposite angles: it is read instead, and the band left out is named.
        if exc.reason != "band_off_frame" or not opposite:
            raise
        ratio = opposite[0].flux / primary_candidate.flux
        try:
            primary = _measure_order(image, small, spot, opposite[0], 1, settings)
        except DetectionError:
            raise exc from None
        if not _mirrors(small, spot, primary_candidate, opposite[0], primary):
            raise exc from None
        notes.append(
            f"the stronger first order was left out: {exc} — the profiles are read from the other "
            f"first order ({ratio:.0%} of its flux in the frame), which is whole"
        )
        opposite = []
    orders = [primary]
    if opposite:
        try:
            other = _measure_order(image, small, spot, opposite[0], -1, settings)
        except DetectionError as exc:
            notes.append(f"the other first order (side -1) was left out: {exc}")
        else:
            ratio = opposite[0].flux / primary_candidate.flux
            orders.append(replace(other, relative_flux=ratio))
            notes.append(
                f"the other first order (side -1, {ratio:.0%} of the +1 order's flux) is in the "
                "frame too; the profiles are read from the +1 order alone, the other one "
                "measures the lens's focal length and the grating's tilt (the mapping's "
                "other_order)"
            )
    along, across = _spot_half_size(small, spot, primary)
    gap = max(0.25 * primary.band_half_width_px, 2 * small.pitch_px, 10.0)
    return DiffractionGeometry(
        sensor_shape_px=image.sensor_shape_px,
        spot_centre_px=spot.centre_px,
        spot_half_size_px=(along, across),
        orders=tuple(orders),
        bin_px=bin_px,
        background_gap_px=gap,
        background_width_px=max(gap, 20.0),
        notes=tuple(notes),
    )
