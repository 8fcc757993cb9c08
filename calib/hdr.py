"""Merge an exposure bracket of RAW frames into one linear radiance image per channel, with its variance.

Each frame's black-subtracted planes (:mod:`calib.raw`) become rate estimates ``x = (y − dark) / t``
in DN/s. The merged radiance is the inverse-variance weighted mean over the frames whose sample is
usable, and its variance is the inverse of the summed weights. The variance of one sample follows the
sensor's noise model

``Var(y) = (g · μ + σ_read² + 1/12 + Var(dark)) / n``

with ``g`` the conversion gain (DN per electron), ``μ`` the expected raw level above black, ``σ_read``
the read noise per raw pixel and ``n`` the number of raw sites averaged into the plane sample (two for
green).

Weights, exclusions and variances never use a sample's own value: ``μ`` is predicted from the mean of
the sample's neighbours in the same frame (a 5×5 window without its centre). A weighted mean whose
weights or inclusion depend on the noise of the values it averages is biased (low near the clipping
level, high near black), and the profiles average hundreds of pixels, so such a bias would stand far
out of their noise. A sample is excluded when

* it is saturated (:mod:`calib.raw`), or its predicted level is above ``prediction_fraction`` of the
  clipping level (it or its neighbours are close to clipping), or
* its predicted level is near black (below ``near_black_sigma`` read-noise sigmas) while a longer
  exposure of the bracket is predicted to measure it below clipping.

Where no frame has a usable sample the pixel is flagged ``saturated`` and holds the shortest frame's
(clipped, hence lower-bound) rate with infinite variance.

Frames are streamed: one is decoded (in a background thread) while the previous one is merged, so the
peak memory is a few frames' planes plus the float32 accumulators, whatever the bracket's length.
Optional dark frames are matched to the light frames by exposure time (and averaged per exposure).
All frames must come from one camera at one ISO, size and aperture; the first file that differs is
named in the error.

The noise model is given, or estimated: the gain and read noise from the longest frame's two green
sites per 2×2 cell (their difference has variance ``2 (g μ + σ²)``: a photon-transfer fit over the
frame's range of levels), and the read noise per channel from the dark frames when there are any.

Examples
--------
>>> image = merge_bracket(["f_0001.dng", "f_0002.dng"], darks=["d_0001.dng"])  # doctest: +SKIP
>>> image.radiance.shape, image.variance.dtype  # doctest: +SKIP
((3, 2000, 3000), dtype('float32'))
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from calib.errors import EstimationError, InputError
from calib.raw import (
    CHANNELS,
    DEFAULT_SATURATION_FRACTION,
    RawMetadata,
    RawPlanes,
    read_raw,
    read_raw_metadata,
)

Float32Array = NDArray[np.float32]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
PathLike = str | os.PathLike[str]
#: ``progress(frames_done, frames_total, path_just_merged)``
ProgressCallback = Callable[[int, int, Path], None]

#: Raw sites averaged into one plane sample: R, G (two greens), B.
SITES_PER_SAMPLE = np.array([1.0, 2.0, 1.0])
#: Rounding to integer DN adds this variance (DN²).
QUANTISATION_VARIANCE_DN2 = 1.0 / 12.0
#: Side of the neighbourhood (plane samples) whose mean, without the centre, predicts a sample.
PREDICTOR_WINDOW = 5
#: Relative difference within which two exposure times count as the same (dark-frame matching).
EXPOSURE_MATCH_TOLERANCE = 0.02
_MAD_TO_SIGMA = 1.4826


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


@dataclass(frozen=True)
class FrameRecord:
    """One light frame of a merged bracket.

    Parameters
    ----------
    path
        The file.
    exposure_s
        Its exposure time.
    dark_paths
        Dark frames averaged and subtracted from it (empty if none).
    saturated_fraction
        Shape ``(3,)``: fraction of samples per channel flagged saturated.
    """

    path: Path
    exposure_s: float
    dark_paths: tuple[Path, ...]
    saturated_fraction: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class HdrImage:
    """A linear radiance image per colour channel, with per-sample variance.

    Parameters
    ----------
    radiance
        Shape ``(3, h, w)``, float32: R, G, B rates in DN/s above black (dark-subtracted).
    variance
        Shape ``(3, h, w)``, float32: variance of ``radiance`` in (DN/s)²; infinite where
        ``saturated``.
    saturated
        Shape ``(3, h, w)``: no frame had a usable sample (clipped everywhere); ``radiance`` there is
        a lower bound.
    channel_origin_px
        Shape ``(3, 2)``: ``(row, column)`` offset of each channel's samples inside the 2×2 cell; a
        sample ``(i, j)`` of channel ``c`` is at sensor pixel ``(2 i, 2 j) + channel_origin_px[c]``.
    pixel_pitch_px
        Sensor pixels per plane sample (2 for half-resolution Bayer planes).
    cfa_pattern, camera, iso, f_number
        Where the frames came from.
    frames
        The light frames, longest exposure first.
    noise_model
        The model used for weights and variances.
    """

    radiance: Float32Array
    variance: Float32Array
    saturated: BoolArray
    channel_origin_px: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.5, 0.5), (1.0, 1.0))
    pixel_pitch_px: float = 2.0
    cfa_pattern: str = "RGGB"
    camera: str = "unknown camera"
    iso: float | None = None
    f_number: float | None = None
    frames: tuple[FrameRecord, ...] = ()
    noise_model: NoiseModel | None = None
    metadata: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        shape = self.radiance.shape
        if self.radiance.ndim != 3 or shape[0] != 3:
            raise InputError(f"radiance must have shape (3, h, w), got {shape}", source="HDR image")
        if self.variance.shape != shape or self.saturated.shape != shape:
            raise InputError(
                f"variance {self.variance.shape} and saturated {self.saturated.shape} must match "
                f"radiance {shape}",
                source="HDR image",
            )
        if np.shape(self.channel_origin_px) != (3, 2) or self.pixel_pitch_px <= 0:
            raise InputError("channel_origin_px must be (3, 2) and pitch > 0", source="HDR image")

    @property
    def plane_shape(self) -> tuple[int, int]:
        """``(h, w)`` of each channel plane."""
        return (int(self.radiance.shape[1]), int(self.radiance.shape[2]))

    @property
    def sensor_shape_px(self) -> tuple[int, int]:
        """``(height, width)`` of the covered sensor area in sensor pixels."""
        height, width = self.plane_shape
        return (round(height * self.pixel_pitch_px), round(width * self.pixel_pitch_px))


# --------------------------------------------------------------------------------------------------
# Consistency of a bracket


def _same(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=1e-3)


def _check_metadata(reference: RawMetadata, other: RawMetadata, *, check_aperture: bool) -> None:
    """Raise naming ``other`` when it was not taken by the same camera with the same settings."""
    first = f"{reference.path.name} (first frame)"
    if (reference.make, reference.model) != (other.make, other.model):
        raise InputError(
            f"taken with {other.camera}, but {first} with {reference.camera}; "
            "a bracket must come from one camera",
            source=str(other.path),
        )
    if not _same(reference.iso, other.iso):
        raise InputError(
            f"ISO {other.iso} differs from ISO {reference.iso} of {first}; keep the ISO fixed",
            source=str(other.path),
        )
    if check_aperture and not _same(reference.f_number, other.f_number):
        raise InputError(
            f"aperture f/{other.f_number} differs from f/{reference.f_number} of {first}; "
            "keep the aperture fixed",
            source=str(other.path),
        )


@dataclass(frozen=True)
class _PlaneLayout:
    """What every frame of a bracket must share, kept without the first frame's pixels."""

    path: Path
    plane_shape: tuple[int, int]
    sensor_shape_px: tuple[int, int]
    cfa_pattern: str
    channel_origin_px: tuple[tuple[float, float], ...]

    @classmethod
    def of(cls, planes: RawPlanes) -> _PlaneLayout:
        return cls(
            planes.metadata.path,
            planes.plane_shape,
            planes.sensor_shape_px,
            planes.cfa_pattern,
            planes.channel_origin_px,
        )


def _check_planes(reference: _PlaneLayout, other: RawPlanes) -> None:
    first = f"{reference.path.name} (first frame)"
    if other.plane_shape != reference.plane_shape:
        raise InputError(
            f"sensor area {other.sensor_shape_px} differs from {reference.sensor_shape_px} of "
            f"{first}; frames must have the same size",
            source=str(other.metadata.path),
        )
    if other.cfa_pattern != reference.cfa_pattern:
        raise InputError(
            f"colour filter layout {other.cfa_pattern} differs from {reference.cfa_pattern} of "
            f"{first}",
            source=str(other.metadata.path),
        )


# --------------------------------------------------------------------------------------------------
# Noise model estimation


def _robust_variance(values: FloatArray, clip_sigma: float = 5.0) -> float:
    """Variance of the bulk of ``values``, ignoring outliers beyond ``clip_sigma`` robust sigmas.

    The median absolute deviation only seeds the clipping: on integer DN values it moves in whole
    steps, which biases it by tens of per cent at read-noise levels; the variance of the clipped set
    does not (a 5-sigma clip removes 6e-7 of a normal distribution's samples).
    """
    centre = float(np.median(values))
    spread = _MAD_TO_SIGMA * float(np.median(np.abs(values - centre)))
    if spread <= 0:
        spread = float(np.std(values))
    if spread <= 0:
        return 0.0
    kept = values[np.abs(values - centre) <= clip_sigma * max(spread, 1.0)]
    return float(np.var(kept))


def _green_pair_statistics(
    planes: RawPlanes, max_samples: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Predicted level, slope-corrected green difference and local slope of usable samples.

    The two greens of a cell sit one pixel apart diagonally, so a slope in the scene shifts their
    difference by the slope times that offset; it is removed with the slope of the smoothed green
    plane (the curvature terms cancel between the two symmetric sites).
    """
    difference = planes.green_difference_dn
    if difference is None:
        raise ValueError("read the frame with keep_green_difference=True")
    green = planes.signal_dn[1]
    window = PREDICTOR_WINDOW
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
    step = max(1, int(green.size // max_samples))
    usable = ~near_clip[::step]
    return (
        predicted[::step][usable].astype(np.float64),
        corrected[::step][usable].astype(np.float64),
        np.hypot(slope_rows[::step], slope_columns[::step])[usable].astype(np.float64),
    )


def estimate_noise_from_green_pairs(
    planes: RawPlanes, *, max_samples: int = 4_000_000, min_bin_samples: int = 200
) -> NoiseModel:
    """Fit ``Var(G1 − G2) / 2 = g μ + σ²`` over the levels of one frame (photon transfer).

    Samples are binned by their level predicted from the neighbours (not by their own value, which
    would select on the noise); in each bin the flatter half of the samples (smallest local slope)
    is used, as edges inflate the difference beyond the noise. Bins that still sit far above the
    fitted line are dropped and the line refitted.

    Parameters
    ----------
    planes
        A frame read with ``keep_green_difference=True``; it needs a range of levels (a lit scene).
    max_samples
        Rows are subsampled to about this many green pairs.
    min_bin_samples
        Level bins with fewer pairs are ignored.

    Returns
    -------
    NoiseModel
        Gain and read noise (the same read noise for R, G and B).

    Raises
    ------
    EstimationError
        Too little signal range for a fit, or a non-physical result.
    """
    level, difference, slope = _green_pair_statistics(planes, max_samples)
    clip = planes.clip_level_dn[1]
    edges = np.concatenate([[-np.inf], np.geomspace(max(clip * 1e-4, 1.0), clip, 40)])
    bin_of = np.digitize(level, edges) - 1
    means: list[float] = []
    variances: list[float] = []
    counts: list[int] = []
    for bin_index in range(edges.size):
        members = np.flatnonzero(bin_of == bin_index)
        if members.size < 2 * min_bin_samples:
            continue
        flattest = members[np.argsort(slope[members])[: members.size // 2]]
        means.append(float(level[flattest].mean()))
        variances.append(_robust_variance(difference[flattest]) / 2.0)
        counts.append(int(flattest.size))
    path = planes.metadata.path
    if len(means) < 3 or max(means) < 50 * max(min(means), 1.0):
        raise EstimationError(
            f"cannot estimate the noise model from {path}: too narrow a range of signal levels; "
            "give a NoiseModel (gain, read noise) explicitly"
        )
    gain, read_variance = _fit_photon_transfer(
        np.array(means), np.array(variances), np.array(counts, dtype=np.float64)
    )
    if not (gain > 0 and math.isfinite(gain)):
        raise EstimationError(
            f"photon-transfer fit on {path} gave a gain of {gain:.3g} DN/electron; "
            "give a NoiseModel explicitly"
        )
    read_noise = math.sqrt(max(read_variance - QUANTISATION_VARIANCE_DN2, 0.0))
    return NoiseModel(
        gain, (read_noise, read_noise, read_noise), source=f"green pairs of {path.name}"
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
class _DarkSpread:
    """Robust spread and level of one dark frame, per channel (plane samples, DN², DN)."""

    variance_dn2: tuple[float, float, float]
    level_dn: tuple[float, float, float]

    @classmethod
    def of(cls, dark: RawPlanes) -> _DarkSpread:
        variances, levels = [], []
        for channel in range(3):
            plane = dark.signal_dn[channel]
            sample = plane[:: max(1, plane.shape[0] // 512)].ravel().astype(np.float64)
            variances.append(_robust_variance(sample))
            levels.append(float(np.median(sample)))
        return cls((variances[0], variances[1], variances[2]), (levels[0], levels[1], levels[2]))


def _dark_read_noise(spreads: Sequence[_DarkSpread], gain: float) -> tuple[float, float, float]:
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


# --------------------------------------------------------------------------------------------------
# Dark frames


@dataclass
class _DarkGroup:
    exposure_s: float
    metadata: list[RawMetadata]

    @property
    def paths(self) -> tuple[Path, ...]:
        return tuple(meta.path for meta in self.metadata)


def _group_darks(darks: Sequence[RawMetadata]) -> list[_DarkGroup]:
    groups: list[_DarkGroup] = []
    for meta in sorted(darks, key=lambda m: m.exposure_s):
        if groups and math.isclose(
            groups[-1].exposure_s, meta.exposure_s, rel_tol=EXPOSURE_MATCH_TOLERANCE
        ):
            groups[-1].metadata.append(meta)
        else:
            groups.append(_DarkGroup(meta.exposure_s, [meta]))
    return groups


def _matching_dark(groups: Sequence[_DarkGroup], frame: RawMetadata) -> _DarkGroup:
    for group in groups:
        if math.isclose(group.exposure_s, frame.exposure_s, rel_tol=EXPOSURE_MATCH_TOLERANCE):
            return group
    available = ", ".join(f"{g.exposure_s:.6g} s" for g in groups)
    raise InputError(
        f"no dark frame with its exposure time {frame.exposure_s:.6g} s (dark frames have: "
        f"{available}); capture a dark frame per exposure time, or merge without dark frames",
        source=str(frame.path),
    )


@dataclass
class _MasterDark:
    """The mean of the dark frames of one exposure time."""

    signal_dn: Float32Array  # (3, h, w)
    count: int
    paths: tuple[Path, ...]

    def level_dn(self, channel: int) -> float:
        plane = self.signal_dn[channel]
        return float(np.median(plane[:: max(1, plane.shape[0] // 256)]))


# --------------------------------------------------------------------------------------------------
# The merge


def _predicted_level(signal: Float32Array, out: Float32Array) -> Float32Array:
    """Mean of each sample's 5×5 neighbourhood without the sample itself (per channel)."""
    window = PREDICTOR_WINDOW
    for channel in range(signal.shape[0]):
        ndimage.uniform_filter(signal[channel], size=window, output=out[channel], mode="reflect")
    out *= np.float32(window * window)
    out -= signal
    out *= np.float32(1.0 / (window * window - 1))
    return out


@dataclass
class _Accumulator:
    """Running sums of the merge, float32 ``(3, h, w)`` each."""

    weight: Float32Array
    weighted_rate: Float32Array
    shortest_rate: Float32Array

    @classmethod
    def zeros(cls, shape: tuple[int, ...]) -> _Accumulator:
        return cls(
            np.zeros(shape, np.float32), np.zeros(shape, np.float32), np.zeros(shape, np.float32)
        )


@dataclass(frozen=True)
class _MergeSettings:
    prediction_fraction: float
    near_black_sigma: float
    exposures_s: tuple[float, ...]

    def next_longer(self, exposure_s: float) -> float | None:
        longer = [t for t in self.exposures_s if t > exposure_s * (1 + EXPOSURE_MATCH_TOLERANCE)]
        return min(longer) if longer else None


def _merge_frame(
    planes: RawPlanes,
    dark: _MasterDark | None,
    noise: NoiseModel,
    settings: _MergeSettings,
    state: _Accumulator,
    scratch: Float32Array,
    *,
    is_shortest: bool,
) -> None:
    """Add one frame's usable samples to the running sums (``planes`` is consumed)."""
    exposure = planes.metadata.exposure_s
    predicted = _predicted_level(planes.signal_dn, scratch)
    next_longer = settings.next_longer(exposure)
    gain = noise.gain_dn_per_electron
    for channel in range(3):
        level = predicted[channel]
        ceiling = np.float32(settings.prediction_fraction * planes.clip_level_dn[channel])
        read_variance = noise.read_noise_dn[channel] ** 2 + QUANTISATION_VARIANCE_DN2
        dark_variance = 0.0
        if dark is not None:
            dark_variance = (gain * max(dark.level_dn(channel), 0.0) + read_variance) / dark.count
        # Var(rate) = (g·μ + σ² + Var(dark)) / (n t²), with μ predicted from the neighbours only
        variance = np.maximum(level, np.float32(0.0))
        variance *= np.float32(gain)
        variance += np.float32(read_variance + dark_variance)
        variance *= np.float32(1.0 / (exposure * exposure * SITES_PER_SAMPLE[channel]))
        usable = ~planes.saturated[channel]
        usable &= level <= ceiling
        if next_longer is not None:
            near_black = level < np.float32(settings.near_black_sigma * math.sqrt(read_variance))
            near_black &= level <= ceiling * np.float32(exposure / next_longer)
            usable &= ~near_black
        rate = planes.signal_dn[channel]
        if dark is not None:
            rate -= dark.signal_dn[channel]
        rate *= np.float32(1.0 / exposure)
        if is_shortest:
            state.shortest_rate[channel] = rate
        weight = np.divide(np.float32(1.0), variance, out=variance)
        weight *= usable
        state.weight[channel] += weight
        weight *= rate
        state.weighted_rate[channel] += weight


def _prefetch(
    paths_and_overrides: Sequence[tuple[Path, float, bool]], saturation_fraction: float
) -> Iterator[RawPlanes]:
    """Decode the frames in order, one ahead of the consumer (LibRaw releases the GIL)."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="raw-decode") as pool:

        def submit(item: tuple[Path, float, bool]) -> Future[RawPlanes]:
            path, exposure, keep_difference = item
            return pool.submit(
                read_raw,
                path,
                exposure_s=exposure,
                saturation_fraction=saturation_fraction,
                keep_green_difference=keep_difference,
            )

        pending: Future[RawPlanes] | None = (
            submit(paths_and_overrides[0]) if paths_and_overrides else None
        )
        for position in range(len(paths_and_overrides)):
            assert pending is not None
            current = pending.result()
            following = position + 1
            pending = (
                submit(paths_and_overrides[following])
                if following < len(paths_and_overrides)
                else None
            )
            yield current


def _overrides(
    paths: Sequence[Path], exposure_s: Sequence[float] | None, what: str
) -> list[float | None]:
    if exposure_s is None:
        return [None] * len(paths)
    if len(exposure_s) != len(paths):
        raise InputError(
            f"{len(exposure_s)} exposure times given for {len(paths)} {what}", source="exposure_s"
        )
    return [float(t) for t in exposure_s]


def merge_bracket(
    frames: Sequence[PathLike],
    *,
    darks: Sequence[PathLike] = (),
    exposure_s: Sequence[float] | None = None,
    dark_exposure_s: Sequence[float] | None = None,
    noise_model: NoiseModel | None = None,
    saturation_fraction: float = DEFAULT_SATURATION_FRACTION,
    prediction_fraction: float = 0.9,
    near_black_sigma: float = 3.0,
    progress: ProgressCallback | None = None,
) -> HdrImage:
    """Merge RAW frames of one scene at different exposure times into an :class:`HdrImage`.

    Parameters
    ----------
    frames
        The bracket's RAW files (any order, any LibRaw format with a Bayer filter).
    darks
        Dark frames (lens capped / lamp off) with the same exposure times as the light frames;
        averaged per exposure time and subtracted. Every light frame needs a matching dark when
        any are given.
    exposure_s, dark_exposure_s
        Exposure times overriding the files' metadata, one per frame / dark.
    noise_model
        Gain and read noise; estimated from the bracket (and darks) when ``None``.
    saturation_fraction
        Passed to :func:`calib.raw.read_raw`.
    prediction_fraction
        A sample whose predicted level exceeds this fraction of the clipping level is excluded.
    near_black_sigma
        A sample predicted below this many read-noise sigmas is excluded where a longer exposure
        covers it.
    progress
        Called after each merged frame with ``(done, total, path)``.

    Returns
    -------
    HdrImage
        Radiance and variance in DN/s, per channel at half resolution.

    Raises
    ------
    InputError
        No frames; unreadable files; frames from different cameras, ISO, aperture or size (the
        offending file is named); a light frame without a matching dark.
    EstimationError
        The noise model cannot be estimated from the data (give one).
    """
    if not frames:
        raise InputError("no frames to merge", source="bracket")
    if not 0.0 < prediction_fraction <= 1.0:
        raise ValueError(f"prediction_fraction must be in (0, 1], got {prediction_fraction}")
    light_paths = [Path(p) for p in frames]
    dark_paths = [Path(p) for p in darks]
    light_meta = [
        read_raw_metadata(path, exposure_s=override)
        for path, override in zip(
            light_paths, _overrides(light_paths, exposure_s, "frames"), strict=True
        )
    ]
    dark_meta = [
        read_raw_metadata(path, exposure_s=override)
        for path, override in zip(
            dark_paths, _overrides(dark_paths, dark_exposure_s, "dark frames"), strict=True
        )
    ]
    reference = light_meta[0]
    for meta in light_meta[1:]:
        _check_metadata(reference, meta, check_aperture=True)
    for meta in dark_meta:
        _check_metadata(reference, meta, check_aperture=False)
    dark_groups = _group_darks(dark_meta)
    ordered = sorted(light_meta, key=lambda m: -m.exposure_s)
    matched = [_matching_dark(dark_groups, meta) for meta in ordered] if dark_groups else []

    # Decode order, longest exposure first: a dark group's frames right before its first light
    # frame, so only one master dark is held at a time.
    schedule: list[tuple[Path, float, bool]] = []
    roles: list[tuple[str, int]] = []  # ("dark", group index) or ("light", index in `ordered`)
    for position, meta in enumerate(ordered):
        if matched and (position == 0 or matched[position] is not matched[position - 1]):
            group_index = dark_groups.index(matched[position])
            for dark_meta_item in matched[position].metadata:
                schedule.append((dark_meta_item.path, dark_meta_item.exposure_s, False))
                roles.append(("dark", group_index))
        schedule.append((meta.path, meta.exposure_s, position == 0 and noise_model is None))
        roles.append(("light", position))

    settings = _MergeSettings(
        prediction_fraction=prediction_fraction,
        near_black_sigma=near_black_sigma,
        exposures_s=tuple(m.exposure_s for m in ordered),
    )
    state: _Accumulator | None = None
    scratch: Float32Array | None = None
    reference_planes: _PlaneLayout | None = None
    master: _MasterDark | None = None
    dark_sum: Float32Array | None = None
    dark_count = 0
    dark_spreads: list[_DarkSpread] = []
    records: list[FrameRecord] = []
    noise = noise_model
    for planes, (role, index) in zip(_prefetch(schedule, saturation_fraction), roles, strict=True):
        if reference_planes is None:
            reference_planes = _PlaneLayout.of(planes)
        _check_planes(reference_planes, planes)
        if role == "dark":
            group = dark_groups[index]
            if dark_count == 0:
                master, dark_sum = None, planes.signal_dn  # reuse the first dark's buffer
            else:
                assert dark_sum is not None
                dark_sum += planes.signal_dn
            dark_count += 1
            dark_spreads.append(_DarkSpread.of(planes))
            if dark_count == len(group.metadata):
                assert dark_sum is not None
                dark_sum *= np.float32(1.0 / dark_count)
                master = _MasterDark(dark_sum, dark_count, group.paths)
                dark_sum, dark_count = None, 0
            continue
        meta = ordered[index]
        if noise is None:
            noise = estimate_noise_from_green_pairs(planes)
            if dark_spreads:
                noise = NoiseModel(
                    noise.gain_dn_per_electron,
                    _dark_read_noise(dark_spreads, noise.gain_dn_per_electron),
                    source=f"{noise.source}; read noise from {len(dark_spreads)} dark frame(s)",
                )
        if state is None:
            state = _Accumulator.zeros(planes.signal_dn.shape)
            scratch = np.empty_like(planes.signal_dn)
        assert scratch is not None
        saturated_fraction = planes.saturated.mean(axis=(1, 2))
        _merge_frame(
            planes, master, noise, settings, state, scratch, is_shortest=index == len(ordered) - 1
        )
        records.append(
            FrameRecord(
                path=meta.path,
                exposure_s=meta.exposure_s,
                dark_paths=master.paths if master is not None else (),
                saturated_fraction=(
                    float(saturated_fraction[0]),
                    float(saturated_fraction[1]),
                    float(saturated_fraction[2]),
                ),
            )
        )
        del planes
        if progress is not None:
            progress(len(records), len(ordered), meta.path)
    assert state is not None and noise is not None and reference_planes is not None
    return _finish(state, noise, reference_planes, reference, tuple(records))


def _finish(
    state: _Accumulator,
    noise: NoiseModel,
    reference_planes: _PlaneLayout,
    reference: RawMetadata,
    records: tuple[FrameRecord, ...],
) -> HdrImage:
    saturated = state.weight <= 0
    radiance = state.weighted_rate
    np.divide(radiance, state.weight, out=radiance, where=~saturated)
    np.copyto(radiance, state.shortest_rate, where=saturated)
    variance = state.weight
    np.divide(np.float32(1.0), variance, out=variance, where=~saturated)
    variance[saturated] = np.inf
    return HdrImage(
        radiance=radiance,
        variance=variance,
        saturated=saturated,
        channel_origin_px=reference_planes.channel_origin_px,
        pixel_pitch_px=2.0,
        cfa_pattern=reference_planes.cfa_pattern,
        camera=reference.camera,
        iso=reference.iso,
        f_number=reference.f_number,
        frames=records,
        noise_model=noise,
        metadata={"channels": CHANNELS},
    )
