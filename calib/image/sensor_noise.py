"""The noise of raw sensor values, and how to estimate it from the images themselves.

One raw pixel at an expected level ``μ`` DN above black has the variance ``g μ + σ² + 1/12`` DN²: shot
noise through the conversion gain ``g`` (DN per electron), read noise ``σ`` and integer rounding. A
plane sample that averages ``n`` raw sites (two greens) has ``1/n`` of it.

The gain and read noise are estimated from the two green sites of each 2×2 cell (a photon-transfer
fit of ``Var(G1 − G2) / 2`` against the level, see :func:`fit_noise_model`), and the read noise per
channel from dark frames (:func:`dark_read_noise`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.image.raw import RawPlanes

Float32Array = NDArray[np.float32]
#: Per-sample level, slope-corrected green difference and local slope (see green_pair_statistics).
PairStatistics = tuple[
    NDArray[np.floating[Any]], NDArray[np.floating[Any]], NDArray[np.floating[Any]]
]

#: Raw sites averaged into one plane sample: R, G (two greens), B.
SITES_PER_SAMPLE = np.array([1.0, 2.0, 1.0])
#: Rounding to integer DN adds this variance (DN²).
QUANTISATION_VARIANCE_DN2 = 1.0 / 12.0
#: Side of the window (plane samples) that smooths the green plane for the photon-transfer fit.
SMOOTHING_WINDOW = 5
_MAD_TO_SIGMA = 1.4826
#: Level bins of the photon-transfer fit are thinned to about this many green pairs.
_MAX_BIN_SAMPLES = 200_000


@dataclass(frozen=True)
class NoiseModel:
    """Noise of one raw pixel: shot noise through the conversion gain plus read noise.

    Parameters
    ----------
    gain_dn_per_electron
        Conversion gain ``g``: a signal of ``μ`` DN has shot-noise variance ``g · μ`` DN².
    read_noise_dn
        Shape ``(3,)``: read-noise standard deviation per raw pixel (R, G, B), DN.
    source
        How the values were obtained (``"given"``, ``"green pairs of <file>"``, ``"dark frames"``).
    """

    gain_dn_per_electron: float
    read_noise_dn: tuple[float, float, float]
    source: str = "given"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain_dn_per_electron) and self.gain_dn_per_electron > 0):
            raise InputError(
                f"gain must be > 0 DN/electron, got {self.gain_dn_per_electron}",
                source="noise model",
            )
        if len(self.read_noise_dn) != 3 or not all(
            math.isfinite(s) and s >= 0 for s in self.read_noise_dn
        ):
            raise InputError(
                f"read noise must be three values ≥ 0 DN, got {self.read_noise_dn}",
                source="noise model",
            )

    def sample_variance_dn2(self, channel: int, level_dn: FloatArray | float) -> FloatArray:
        """Variance (DN²) of one plane sample of ``channel`` at expected level ``level_dn``."""
        read = self.read_noise_dn[channel] ** 2 + QUANTISATION_VARIANCE_DN2
        level = np.maximum(np.asarray(level_dn, dtype=np.float64), 0.0)
        return (self.gain_dn_per_electron * level + read) / SITES_PER_SAMPLE[channel]  # type: ignore[no-any-return]


def leave_one_out_mean(
    signal: Float32Array, *, out: Float32Array, scratch: Float32Array | None = None
) -> Float32Array:
    """Mean of each sample's 3×3 neighbourhood without the sample itself (the 8 neighbours).

    Parameters
    ----------
    signal
        Shape ``(..., h, w)``: planes (float32), each smoothed on its own.
    out
        Same shape: receives the result.
    scratch
        Same shape, reused between calls to avoid fresh allocations (optional).

    Returns
    -------
    numpy.ndarray
        ``out``. Edge samples average the neighbours that exist.
    """
    rows = scratch if scratch is not None else np.empty_like(signal)
    # separable 3×3 box sum (zero padding) by shifted additions: fewer passes than a filter
    np.add(signal[..., :-2, :], signal[..., 1:-1, :], out=rows[..., 1:-1, :])
    rows[..., 1:-1, :] += signal[..., 2:, :]
    np.add(signal[..., 0, :], signal[..., 1, :], out=rows[..., 0, :])
    np.add(signal[..., -2, :], signal[..., -1, :], out=rows[..., -1, :])
    np.add(rows[..., :, :-2], rows[..., :, 1:-1], out=out[..., :, 1:-1])
    out[..., :, 1:-1] += rows[..., :, 2:]
    np.add(rows[..., :, 0], rows[..., :, 1], out=out[..., :, 0])
    np.add(rows[..., :, -2], rows[..., :, -1], out=out[..., :, -1])
    out -= signal
    out *= np.float32(1.0 / 8.0)
    # edges have fewer neighbours: 5 along a side, 3 in a corner
    height, width = signal.shape[-2:]
    count_rows = np.full(height, 3.0)
    count_rows[[0, -1]] = 2.0
    count_columns = np.full(width, 3.0)
    count_columns[[0, -1]] = 2.0
    for edge in (0, -1):
        out[..., edge, :] *= (8.0 / (count_rows[edge] * count_columns - 1.0)).astype(np.float32)
        out[..., 1:-1, edge] *= np.float32(8.0 / (count_columns[edge] * 3.0 - 1.0))
    return out


def robust_variance(values: FloatArray, clip_sigma: float = 5.0) -> float:
    """Variance of the bulk of ``values``, ignoring outliers beyond ``clip_sigma`` robust sigmas.

    The median absolute deviation only seeds the clipping: on integer DN values it moves in whole
    steps, which biases it by tens of per cent at read-noise levels; the variance of the clipped set
    does not (a 5-sigma clip removes 6e-7 of a normal distribution's samples).
    """
    return robust_level_and_variance(values, clip_sigma)[1]


#: Raw values on a grid of 1/_LATTICE DN (integers, a green pair's half-integers) take the exact
#: counting path of :func:`robust_level_and_variance` when they span at most _MAX_LATTICE_BINS steps.
_LATTICE = 8
_MAX_LATTICE_BINS = 1 << 20


def _lattice_level_and_variance(
    values: FloatArray, clip_sigma: float
) -> tuple[float, float] | None:
    """:func:`robust_level_and_variance` of values on a grid of ``1/_LATTICE`` by counting: the same
    numbers, bit for bit, or ``None`` (not on the grid, or too wide: the general path).

    Both medians are order statistics read from one histogram of the values (the deviations'
    histogram is the values' folded about the centre), where ``np.median`` partitions the values
    and then their deviations. Every value, the centre (a mean of two) and every deviation is then
    an exact multiple of ``1/(2 _LATTICE)``, so the medians are the same floats; when no value is
    clipped, the variance is taken of the same array in the same order.
    """
    if values.ndim != 1 or values.size == 0 or not values.flags.c_contiguous:
        return None
    scaled = values * float(_LATTICE)  # exact: a power of two
    with np.errstate(invalid="ignore"):  # NaN or ±inf cast to garbage: caught just below
        keys = scaled.astype(np.int64)
    if not np.array_equal(keys, scaled):  # off the grid, or NaN
        return None
    low, high = int(keys.min()), int(keys.max())
    if high - low >= _MAX_LATTICE_BINS:
        return None
    counts = np.bincount(keys - low)
    cumulative = np.cumsum(counts)
    size = values.size

    def order_statistic(cumulative: NDArray[np.int64], index: int) -> int:
        return int(np.searchsorted(cumulative, index, side="right"))

    half = size // 2
    # the centre in steps of 1/(2 _LATTICE): twice the middle key, or the sum of the two middle keys
    upper = order_statistic(cumulative, half) + low
    lower = upper if size % 2 else order_statistic(cumulative, half - 1) + low
    centre = _mean_of(lower / _LATTICE, upper / _LATTICE, size)
    doubled_centre = lower + upper
    # deviations |2 k − (k_lower + k_upper)| in steps of 1/(2 _LATTICE)
    distance = np.abs(2 * (np.arange(counts.size) + low) - doubled_centre)
    folded = np.bincount(distance, weights=counts)
    folded_cumulative = np.cumsum(folded.astype(np.int64))
    step = 2 * _LATTICE
    deviation_upper = order_statistic(folded_cumulative, half)
    deviation_lower = deviation_upper if size % 2 else order_statistic(folded_cumulative, half - 1)
    spread = _MAD_TO_SIGMA * _mean_of(deviation_lower / step, deviation_upper / step, size)
    if spread <= 0:
        return None
    widest = max(abs(2 * low - doubled_centre), abs(2 * high - doubled_centre)) / step
    if widest > clip_sigma * max(spread, 1.0):
        deviation = np.abs(values - centre)
        return centre, float(np.var(values[deviation <= clip_sigma * max(spread, 1.0)]))
    return centre, float(np.var(values))


def _mean_of(lower: float, upper: float, size: int) -> float:
    """The median of ``size`` values from its middle one (odd) or two (even), as ``np.median``."""
    return lower if size % 2 else float(np.mean(np.array([lower, upper])))


def robust_level_and_variance(values: FloatArray, clip_sigma: float = 5.0) -> tuple[float, float]:
    """The median of ``values`` and :func:`robust_variance`, which starts from it."""
    counted = _lattice_level_and_variance(values, clip_sigma)
    if counted is not None:
        return counted
    centre = float(np.median(values))
    deviation = np.abs(values - centre)  # once, for the spread and the clip
    spread = _MAD_TO_SIGMA * float(np.median(deviation))
    if spread <= 0:
        spread = float(np.std(values))
    if spread <= 0:
        return centre, 0.0
    kept = values[deviation <= clip_sigma * max(spread, 1.0)]
    return centre, float(np.var(kept))


def green_pair_statistics(planes: RawPlanes, max_samples: int = 1_000_000) -> PairStatistics:
    """Predicted level, slope-corrected green difference and local slope of usable green pairs.

    The two greens of a cell sit one pixel apart diagonally, so a slope in the scene shifts their
    difference by the slope times that offset; it is removed with the slope of the smoothed green
    plane (the curvature terms cancel between the two symmetric sites).
    """
    from scipy import ndimage

    difference = planes.green_difference_dn
    if difference is None:
        raise ValueError("read the frame with keep_green_difference=True")
    green = planes.signal_dn[1]
    window = SMOOTHING_WINDOW
    smooth = ndimage.uniform_filter(green, size=window, mode="reflect")
    slope_rows, slope_columns = np.gradient(smooth)
    (first_row, first_column), (second_row, second_column) = planes.green_sites_px
    # site offset in plane samples (2 sensor pixels each)
    offset_rows, offset_columns = (
        (first_row - second_row) / 2.0,
        (first_column - second_column) / 2.0,
    )
    corrected = difference - (offset_rows * slope_rows + offset_columns * slope_columns)
    predicted = (smooth * np.float32(window * window) - green) / np.float32(window * window - 1)
    near_clip = ndimage.maximum_filter(planes.saturated[1], size=window)
    step = max(1, math.ceil(green.size / max_samples))  # every step-th row
    usable = ~near_clip[::step]
    return (
        predicted[::step][usable],
        corrected[::step][usable],
        np.hypot(slope_rows[::step], slope_columns[::step])[usable],
    )


def fit_noise_model(
    statistics: Sequence[PairStatistics],
    clip_level_dn: float,
    source: str,
    *,
    min_bin_samples: int = 200,
) -> NoiseModel:
    """Fit ``Var(G1 − G2) / 2 = g μ + σ²`` over the levels of one or more frames (photon transfer).

    Samples are binned by their level predicted from the neighbours (not by their own value, which
    would select on the noise); in each bin the flatter half of the samples (smallest local slope)
    is used, as edges inflate the difference beyond the noise. Bins that still sit far above the
    fitted line are dropped and the line refitted. Frames of one bracket (same ISO) can be pooled.

    Parameters
    ----------
    statistics
        :func:`green_pair_statistics` of each frame.
    clip_level_dn
        Green clipping level above black, for the level bins.
    source
        The frame(s) the statistics come from (file names), for the description and errors.
    min_bin_samples
        Level bins with fewer (flat) pairs are ignored.

    Returns
    -------
    NoiseModel
        Gain and read noise (the same read noise for R, G and B).

    Raises
    ------
    EstimationError
        Too little signal range for a fit, or a non-physical result.
    """
    level = np.concatenate([frame[0] for frame in statistics]).astype(np.float64)
    difference = np.concatenate([frame[1] for frame in statistics]).astype(np.float64)
    slope = np.concatenate([frame[2] for frame in statistics])
    edges = np.concatenate(
        [[-np.inf], np.geomspace(max(clip_level_dn * 1e-4, 1.0), clip_level_dn, 40)]
    )
    bin_of = np.digitize(level, edges) - 1
    # every bin's members in increasing order, from one stable (radix) sort of the small bin numbers
    by_bin = np.argsort(bin_of.astype(np.uint8), kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(bin_of, minlength=edges.size))])
    means: list[float] = []
    variances: list[float] = []
    counts: list[int] = []
    for bin_index in range(edges.size):
        members = by_bin[bounds[bin_index] : bounds[bin_index + 1]]
        if members.size < 2 * min_bin_samples:
            continue
        members = members[:: max(1, members.size // _MAX_BIN_SAMPLES)]
        half = members.size // 2
        flattest = members[np.argpartition(slope[members], half)[:half]]
        means.append(float(level[flattest].mean()))
        variances.append(robust_variance(difference[flattest]) / 2.0)
        counts.append(int(flattest.size))
    if len(means) < 3 or max(means) < 50 * max(min(means), 1.0):
        raise EstimationError(
            f"cannot estimate the noise model from {source}: too narrow a range of signal levels; "
            "give a NoiseModel (gain, read noise) explicitly"
        )
    gain, read_variance = _fit_photon_transfer(
        np.array(means), np.array(variances), np.array(counts, dtype=np.float64)
    )
    if not (gain > 0 and math.isfinite(gain)):
        raise EstimationError(
            f"photon-transfer fit on {source} gave a gain of {gain:.3g} DN/electron; "
            "give a NoiseModel explicitly"
        )
    read_noise = math.sqrt(max(read_variance - QUANTISATION_VARIANCE_DN2, 0.0))
    return NoiseModel(gain, (read_noise, read_noise, read_noise), source=f"green pairs of {source}")


def estimate_noise_from_green_pairs(planes: RawPlanes) -> NoiseModel:
    """:func:`fit_noise_model` on one frame read with ``keep_green_difference=True``."""
    return fit_noise_model(
        [green_pair_statistics(planes)], planes.clip_level_dn[1], planes.metadata.path.name
    )


def _fit_photon_transfer(
    level: FloatArray, variance: FloatArray, count: FloatArray, *, iterations: int = 6
) -> tuple[float, float]:
    """Weighted line ``variance = gain · level + read_variance``, dropping bins far above it.

    Contamination (edges, hot pixels) only ever adds variance, so bins more than 3 standard errors
    above the line are outliers while bins below it are kept.
    """
    keep = np.ones(level.size, dtype=bool)
    expected = variance.copy()
    gain, read_variance = 0.0, float(np.min(variance))
    for _ in range(iterations):
        weights = np.sqrt(count[keep] / 2.0) / np.maximum(expected[keep], 1e-9)
        design = np.stack([level[keep], np.ones(int(keep.sum()))], axis=1) * weights[:, None]
        solution, *_ = np.linalg.lstsq(design, variance[keep] * weights, rcond=None)
        gain, read_variance = float(solution[0]), float(solution[1])
        expected = np.maximum(gain * level + read_variance, 1e-9)
        standard_error = expected * np.sqrt(2.0 / count)
        new_keep = (variance - expected) < 3.0 * standard_error
        if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return gain, read_variance


@dataclass(frozen=True)
class DarkSpread:
    """Robust spread and level of one dark frame, per channel (plane samples, DN², DN)."""

    variance_dn2: tuple[float, float, float]
    level_dn: tuple[float, float, float]

    @classmethod
    def of(cls, dark: RawPlanes) -> DarkSpread:
        variances, levels = [], []
        for channel in range(3):
            plane = dark.signal_dn[channel]
            sample = plane[:: max(1, plane.shape[0] // 512)].ravel().astype(np.float64)
            level, variance = robust_level_and_variance(sample)
            variances.append(variance)
            levels.append(level)
        return cls((variances[0], variances[1], variances[2]), (levels[0], levels[1], levels[2]))


def dark_read_noise(spreads: Sequence[DarkSpread], gain: float) -> tuple[float, float, float]:
    """Per-channel read noise per raw pixel from single dark frames (dark shot noise removed)."""
    estimates = np.empty((len(spreads), 3))
    for row, spread in enumerate(spreads):
        for channel in range(3):
            per_pixel = spread.variance_dn2[channel] * SITES_PER_SAMPLE[channel]
            shot = gain * max(spread.level_dn[channel], 0.0)
            estimates[row, channel] = math.sqrt(
                max(per_pixel - shot - QUANTISATION_VARIANCE_DN2, 0.0)
            )
    median = np.median(estimates, axis=0)
    return (float(median[0]), float(median[1]), float(median[2]))
