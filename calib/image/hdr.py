"""Merge an exposure bracket of RAW frames into one linear radiance image per channel, with its variance.

Each frame's black-subtracted planes (:mod:`calib.image.raw`) become rate estimates ``x = (y − dark) / t``
in DN/s. The merged radiance is the inverse-variance weighted mean over the frames whose sample is
usable, and its variance is the inverse of the summed weights. The variance of one sample follows the
sensor's noise model

``Var(y) = (g · μ + σ_read² + 1/12 + Var(dark)) / n``

with ``g`` the conversion gain (DN per electron), ``μ`` the expected raw level above black, ``σ_read``
the read noise per raw pixel and ``n`` the number of raw sites averaged into the plane sample (two for
green).

Weights, exclusions and variances never use a sample's own value: ``μ`` is predicted from the mean of
the sample's neighbours in the same frame (its 8 neighbours in the 3×3 window). A weighted mean whose
weights or inclusion depend on the noise of the values it averages is biased (low near the clipping
level, high near black), and the profiles average hundreds of pixels, so such a bias would stand far
out of their noise. A sample is excluded when

* it is saturated (:mod:`calib.image.raw`), or its predicted level is above ``prediction_fraction`` of the
  clipping level (it or its neighbours are close to clipping), or
* its predicted level is near black (below ``near_black_sigma`` read-noise sigmas) while a longer
  exposure of the bracket is predicted to measure it below clipping.

Where no frame has a usable sample the pixel is flagged ``saturated`` and holds the shortest frame's
rate (a lower bound where it clipped) with infinite variance.

A shutter does not expose exactly its recorded time (1–3 %: curtain timing, third-stop labels), and
where the frame mix of a region differs per channel (a spot's soft edges) such errors differ per
channel. So each frame's actual gain relative to the frames merged before it is estimated from the
samples both use (usable here by the rules above and above the noise floor, measured before):
``g = Σ w x / Σ w m`` with ``x`` the frame's rate, ``m`` the merge's so far and ``w`` the predicted
level over their summed variance. One gain per frame, shared by its channels and its every sample;
the frame's rates are divided by it before they are added, so the gains chain along the bracket, and
at the end the merge is scaled so that the frames' gains have a geometric mean of 1 (the recorded
times' scale). Where the estimate rests on fewer than :data:`GAIN_MIN_SAMPLES` samples or is poorer
than :data:`GAIN_MAX_SIGMA`, or does not depart from the recorded time by more than
:data:`GAIN_SIGNIFICANCE` of its σ, the recorded time is kept. The gains, their σ and the frames that kept
their recorded time are in :attr:`FrameRecord.gain` and ``metadata["frame_gains"]``. The gain's σ is
not added to the per-sample variance: it is one error shared by all of a frame's samples (a scale, not
noise), and 10⁻⁴–10⁻³ for a real bracket's overlap, far below the shutter error it removes (decision
0098: added to the direct RGB's σ as an upper bound, it moved the validation coverage by < 0.1 point).
A short frame that alone measures the direct spot shares only dim samples with the others, and its
gain's σ is 0.2–0.5 %: still better than its recorded time's 1–3 % (decision 0193).

Frames are streamed: the next ones are decoded (in background threads) while one is merged, so the
peak memory is a few frames' planes plus the float32 accumulators, whatever the bracket's length.
Over a region of interest, DNG frames decode only the tiles that meet it (:mod:`calib.image.dng_tiles`).
Optional dark frames are matched to the light frames by exposure time (and averaged per exposure).
All frames must come from one camera at one ISO, size and aperture; the first file that differs is
named in the error.

The noise model (:mod:`calib.image.sensor_noise`) is given, or estimated: the gain and read noise from the
two green sites per 2×2 cell of the first two decoded frames (their difference has variance
``2 (g μ + σ²)``: a photon-transfer fit over the frames' range of levels), and the read noise per
channel from the dark frames when there are any.

Examples
--------
Not run as a doctest: it needs a bracket of RAW files (``tests/test_hdr.py`` merges written ones).

>>> image = merge_bracket(["f_0001.dng", "f_0002.dng"], darks=["d_0001.dng"])  # doctest: +SKIP
>>> image.radiance.shape, image.variance.dtype  # doctest: +SKIP
((3, 2000, 3000), dtype('float32'))
"""

from __future__ import annotations

import math
import os
import threading
from collections import deque
from collections.abc import Callable, Generator, Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import BoolArray
from calib.core.errors import EstimationError, InputError
from calib.image.raw import (
    CHANNELS,
    DEFAULT_SATURATION_FRACTION,
    PlaneBuffers,
    PlaneRegion,
    RawDecoder,
    RawMetadata,
    RawPlanes,
    UnpackedRaw,
    read_raw,
    read_raw_metadata,
    unpack_raw,
)
from calib.image.sensor_noise import (
    QUANTISATION_VARIANCE_DN2,
    SITES_PER_SAMPLE,
    DarkSpread,
    NoiseModel,
    PairStatistics,
    dark_read_noise,
    fit_noise_model,
    green_pair_statistics,
    leave_one_out_mean,
)

Float32Array = NDArray[np.float32]
PathLike = str | os.PathLike[str]
#: ``progress(frames_done, frames_total, path_just_merged)``
ProgressCallback = Callable[[int, int, Path], None]
#: Chooses the region to merge from the first decoded light frame (full planes), or ``None``.
RegionChooser = Callable[[RawPlanes], PlaneRegion | None]

#: Frames whose green pairs are pooled for the noise model (each is held until the fit is done).
NOISE_POOL_FRAMES = 2
#: Frames decoded ahead of the merge (each holds its planes until merged).
PREFETCH_FRAMES = 2
#: Threads decoding them: LibRaw releases the GIL while it unpacks, so two files decode at once
#: (10 uncompressed 24 MP DNGs: 1.0 s → 0.7 s on two cores).
DECODE_THREADS = max(1, min(PREFETCH_FRAMES, os.cpu_count() or 1))
#: Relative difference within which two exposure times count as the same (dark-frame matching).
EXPOSURE_MATCH_TOLERANCE = 0.02
#: A frame's gain is estimated from at least this many plane samples that it and the frames merged
#: before it both measure (fewer: its recorded exposure time is kept).
GAIN_MIN_SAMPLES = 100
#: ... and only when the estimate's σ is at most this: a shutter's actual exposure is off its
#: recorded time by ~1–3 % (focal-plane curtain timing, third-stop labels rounding 2^(n/3) by up to
#: 3 %; decision 0087), so an estimate better than 1 % improves on the recorded time; a poorer one
#: could make the merge worse than the label it replaces. (At 0.2 % the bracket's shortest frame,
#: which alone measures the direct spot and shares with the others only the spot's edges and the
#: band's brightest part, kept its recorded time on a third of the validation twins' lamps, with
#: estimates of σ 0.3 % that were right to 0.1 %: the spot's level then carried that frame's 1–4 %
#: against the band's; decision 0193.)
GAIN_MAX_SIGMA = 0.01
#: ... and only when it departs from the recorded time by more than this many of its σ: the gain is
#: one error shared by all of a frame's samples, which the per-sample variance does not carry, so a
#: gain the data cannot tell from 1 would add its own σ (10⁻⁴-size, the size of a wide band's
#: profile σ) as an unstated bias. Five σ: a detection threshold that exact times pass about once
#: in 10⁶ frames (at three, one 16-seed test bracket of exact times moved its profile by 0.4 of its
#: σ), where a real shutter's 1–3 % is 15–100 σ.
GAIN_SIGNIFICANCE = 5.0
#: A sample is taken from a frame only when its neighbours average at most this fraction of the
#: clipping level (the default ``prediction_fraction``): nearer to clipping, the pixel's own
#: response is no longer linear enough to merge. The rig brackets until every spot and band pixel
#: passes it in the shortest frame (:mod:`rig.frame_stats`, decision 0186).
PREDICTION_FRACTION = 0.9


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
    decoding
        How its pixels were decoded (:attr:`calib.image.raw.RawPlanes.decoding`).
    gain
        The frame's actual exposure relative to ``exposure_s`` as the merge estimated it (its rates
        were divided by it), anchored so that the bracket's gains have a geometric mean of 1; 1
        when it was not estimated.
    gain_sigma
        The estimate's σ (relative), ``None`` when the recorded time was kept.
    gain_samples
        Plane samples the gain was estimated from (shared with the frames merged before it).
    """

    path: Path
    exposure_s: float
    dark_paths: tuple[Path, ...]
    saturated_fraction: tuple[float, float, float]
    decoding: str = "LibRaw"
    gain: float = 1.0
    gain_sigma: float | None = None
    gain_samples: int = 0


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
    region_origin_px
        ``(row, column)`` in sensor pixels of the covered area's first 2×2 cell: ``(0, 0)`` for a
        whole frame, else where the merged region starts (add it to positions in this image to
        get positions on the sensor).
    full_sensor_shape_px
        ``(height, width)`` of the whole sensor area of the frames (``None``: the image's own).
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
    region_origin_px: tuple[int, int] = (0, 0)
    full_sensor_shape_px: tuple[int, int] | None = None

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


def _differ(a: object, b: object) -> bool:
    """Both known and different (an unknown value is no evidence of a different setting)."""
    if a is None or b is None:
        return False
    if isinstance(a, float) and isinstance(b, float):
        return not math.isclose(a, b, rel_tol=1e-3)
    return a != b


def _check_metadata(reference: RawMetadata, other: RawMetadata, *, check_aperture: bool) -> None:
    """Raise naming ``other`` when it was not taken by the same camera with the same settings."""
    first = f"{reference.path.name} (reference frame)"
    if _differ(reference.make, other.make) or _differ(reference.model, other.model):
        raise InputError(
            f"taken with {other.camera}, but {first} with {reference.camera}; "
            "a bracket must come from one camera",
            source=str(other.path),
        )
    if _differ(reference.iso, other.iso):
        raise InputError(
            f"ISO {other.iso:g} differs from ISO {reference.iso:g} of {first}; keep the ISO fixed",
            source=str(other.path),
        )
    if check_aperture and _differ(reference.f_number, other.f_number):
        raise InputError(
            f"aperture f/{other.f_number:g} differs from f/{reference.f_number:g} of {first}; "
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
        height, width = planes.full_shape
        return cls(
            planes.metadata.path,
            planes.full_shape,
            (2 * height, 2 * width),
            planes.cfa_pattern,
            planes.channel_origin_px,
        )


def _check_planes(reference: _PlaneLayout, other: RawPlanes) -> None:
    first = f"{reference.path.name} (first decoded frame)"
    if other.full_shape != reference.plane_shape:
        height, width = other.full_shape
        raise InputError(
            f"sensor area {(2 * height, 2 * width)} differs from {reference.sensor_shape_px} of "
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
    """The mean of the dark frames of one exposure time (in the first dark's buffers)."""

    buffers: PlaneBuffers
    count: int
    paths: tuple[Path, ...]

    region_origin: tuple[int, int] = (0, 0)

    @property
    def signal_dn(self) -> Float32Array:
        return self.buffers.signal_dn

    def level_dn(self, channel: int) -> float:
        plane = self.signal_dn[channel]
        return float(np.median(plane[:: max(1, plane.shape[0] // 256)]))

    def matching(self, planes: RawPlanes) -> _MasterDark:
        """This master dark over the same samples as ``planes`` (a view when it covers more)."""
        if self.region_origin == planes.region_origin and self.signal_dn.shape[1:] == (
            planes.plane_shape
        ):
            return self
        row0 = planes.region_origin[0] - self.region_origin[0]
        column0 = planes.region_origin[1] - self.region_origin[1]
        height, width = planes.plane_shape
        window = (slice(None), slice(row0, row0 + height), slice(column0, column0 + width))
        return _MasterDark(
            PlaneBuffers(self.buffers.signal_dn[window], self.buffers.saturated[window]),
            self.count,
            self.paths,
            planes.region_origin,
        )


# --------------------------------------------------------------------------------------------------
# The merge


@dataclass
class _Accumulator:
    """Running sums of the merge (float32 ``(3, h, w)``) and per-plane work buffers (``(h, w)``).

    The buffers are allocated once: fresh arrays of this size cost page faults every frame.
    """

    weight: Float32Array
    weighted_rate: Float32Array
    shortest_rate: Float32Array
    frame_weight: Float32Array
    level: Float32Array
    work: Float32Array
    scratch: Float32Array
    usable: BoolArray
    condition: BoolArray
    overlap: BoolArray

    @classmethod
    def zeros(cls, shape: tuple[int, int, int]) -> _Accumulator:
        plane = shape[1:]
        return cls(
            weight=np.zeros(shape, np.float32),
            weighted_rate=np.zeros(shape, np.float32),
            shortest_rate=np.zeros(shape, np.float32),
            frame_weight=np.empty(shape, np.float32),
            level=np.empty(plane, np.float32),
            work=np.empty(plane, np.float32),
            scratch=np.empty(plane, np.float32),
            usable=np.empty(plane, np.bool_),
            condition=np.empty(plane, np.bool_),
            overlap=np.empty(plane, np.bool_),
        )


@dataclass(frozen=True)
class _MergeSettings:
    prediction_fraction: float
    near_black_sigma: float
    exposures_s: tuple[float, ...]
    estimate_gains: bool = True

    def next_longer(self, exposure_s: float) -> float | None:
        longer = [t for t in self.exposures_s if t > exposure_s * (1 + EXPOSURE_MATCH_TOLERANCE)]
        return min(longer) if longer else None


@dataclass(frozen=True)
class _FrameGain:
    """A frame's exposure relative to its recorded time and the frames merged before it."""

    gain: float = 1.0
    sigma: float | None = None  # None: the recorded time was kept
    samples: int = 0


@dataclass
class _GainSums:
    """Sums over the samples a frame and the running merge both measure, for the frame's gain
    ``g = Σ w x / Σ w m`` (``x`` the frame's rate, ``m`` the merge's so far, ``w`` their level over
    their summed variance: the ratio estimator's best weights, taken from the predicted level)."""

    frame: float = 0.0
    merged: float = 0.0
    frame_variance: float = 0.0
    merged_variance: float = 0.0
    samples: int = 0

    def add(
        self,
        rate: Float32Array,
        frame_weight: Float32Array,
        level: Float32Array,
        exposure_s: float,
        state: _Accumulator,
        channel: int,
        overlap: BoolArray,
    ) -> None:
        at = np.flatnonzero(overlap)
        if not at.size:
            return
        merged_weight = state.weight[channel].ravel().take(at).astype(np.float64)
        merged = state.weighted_rate[channel].ravel().take(at) / merged_weight
        frame_variance = 1.0 / frame_weight.ravel().take(at).astype(np.float64)
        merged_variance = 1.0 / merged_weight
        w = level.ravel().take(at) / (exposure_s * (frame_variance + merged_variance))
        # elementwise sums, not np.dot: BLAS threads cost more than these vectors on busy cores
        self.frame += float((w * rate.ravel().take(at)).sum())
        self.merged += float((w * merged).sum())
        w *= w
        self.frame_variance += float((w * frame_variance).sum())
        self.merged_variance += float((w * merged_variance).sum())
        self.samples += int(at.size)

    def gain(self) -> _FrameGain:
        if self.samples < GAIN_MIN_SAMPLES or self.merged <= 0.0 or self.frame <= 0.0:
            return _FrameGain(samples=self.samples)
        gain = self.frame / self.merged
        sigma = math.sqrt(self.frame_variance + gain * gain * self.merged_variance) / self.merged
        if sigma > GAIN_MAX_SIGMA:
            return _FrameGain(samples=self.samples)
        if abs(gain - 1.0) <= GAIN_SIGNIFICANCE * sigma:
            # measured and consistent with the recorded time: the time stands (σ recorded)
            return _FrameGain(1.0, sigma, self.samples)
        return _FrameGain(gain, sigma, self.samples)


def _merge_frame(
    planes: RawPlanes,
    dark: _MasterDark | None,
    noise: NoiseModel,
    settings: _MergeSettings,
    state: _Accumulator,
    *,
    is_shortest: bool,
    is_first: bool,
) -> _FrameGain:
    """Add one frame's usable samples to the running sums (``planes`` is consumed); returns the
    frame's gain relative to the frames merged before it, by which its rates were divided.

    The gain is one per frame, shared by its channels and all its samples (the direct spot and the
    band alike): a shutter's error scales the whole frame. It is estimated from the samples this
    frame and the merge so far both use (not saturated, not near clipping, above the noise floor in
    this frame), so the gains chain along the bracket from the first merged frame (gain 1).
    """
    exposure = planes.metadata.exposure_s
    next_longer = settings.next_longer(exposure)
    gain = noise.gain_dn_per_electron
    level, usable, condition = state.level, state.usable, state.condition
    sums = _GainSums()
    for channel in range(3):
        weight = state.frame_weight[channel]
        signal = planes.signal_dn[channel]
        leave_one_out_mean(signal, out=level, scratch=state.scratch)
        ceiling = settings.prediction_fraction * planes.clip_level_dn[channel]
        read_variance = noise.read_noise_dn[channel] ** 2 + QUANTISATION_VARIANCE_DN2
        dark_variance = 0.0
        if dark is not None:
            dark_variance = (gain * max(dark.level_dn(channel), 0.0) + read_variance) / dark.count
        # weight = 1 / Var(rate) = n t² / (g·μ + σ² + Var(dark)), μ predicted from the neighbours
        scale = 1.0 / (exposure * exposure * SITES_PER_SAMPLE[channel])
        np.maximum(level, np.float32(0.0), out=weight)
        weight *= np.float32(gain * scale)
        weight += np.float32((read_variance + dark_variance) * scale)
        np.reciprocal(weight, out=weight)
        # usable: not saturated, predicted at most `ceiling`, and not near black where a longer
        # exposure will measure it (both conditions on the predicted level reduce to one range)
        np.logical_not(planes.saturated[channel], out=usable)
        np.less_equal(level, np.float32(ceiling), out=condition)
        usable &= condition
        near_black = settings.near_black_sigma * math.sqrt(read_variance)
        if next_longer is not None:
            lowest = min(near_black, ceiling * exposure / next_longer)
            np.greater_equal(level, np.float32(lowest), out=condition)
            usable &= condition
        rate = signal
        if dark is not None:
            rate -= dark.signal_dn[channel]
        rate *= np.float32(1.0 / exposure)
        if settings.estimate_gains and not is_first:
            # the overlap: usable here, above the noise floor here, and measured before
            np.greater_equal(level, np.float32(near_black), out=condition)
            condition &= usable
            np.greater(state.weight[channel], np.float32(0.0), out=state.overlap)
            condition &= state.overlap
            sums.add(rate, weight, level, exposure, state, channel, condition)
        weight *= usable
    frame_gain = sums.gain()
    for channel in range(3):
        rate = planes.signal_dn[channel]
        weight = state.frame_weight[channel]
        if frame_gain.gain != 1.0:
            rate *= np.float32(1.0 / frame_gain.gain)
            weight *= np.float32(frame_gain.gain * frame_gain.gain)
        if is_shortest:
            state.shortest_rate[channel] = rate
        state.weight[channel] += weight
        weight *= rate
        state.weighted_rate[channel] += weight
    return frame_gain


class _BufferPool:
    """Plane arrays handed back after a frame is merged, for the next decode (thread-safe)."""

    def __init__(self) -> None:
        self._free: list[PlaneBuffers] = []
        self._lock = threading.Lock()

    def take(self) -> PlaneBuffers | None:
        with self._lock:
            return self._free.pop() if self._free else None

    def give(self, signal_dn: Float32Array, saturated: BoolArray) -> None:
        with self._lock:
            self._free.append(PlaneBuffers(signal_dn, saturated))


@dataclass
class _RegionHolder:
    """The region to decode, once chosen (read by the decoding threads at each frame).

    ``chosen`` is set once the chooser has seen the first light frame (at once without a chooser):
    later frames are unpacked meanwhile, but cut into planes of the region only.
    """

    region: PlaneRegion | None = None
    chooser: RegionChooser | None = None
    chosen: threading.Event = field(default_factory=threading.Event)

    def __post_init__(self) -> None:
        if self.chooser is None:
            self.chosen.set()


class Unpacker:
    """Unpacks RAW files (:func:`calib.image.raw.unpack_raw`) in a given order, ``ahead`` files ahead of
    the files taken, on :data:`DECODE_THREADS` threads; each file is handed out once. A DNG the
    tile decoder reads is only opened here (its tiles are decoded with the region, in
    :func:`calib.image.raw.read_raw`); ``decoder``: see :data:`calib.image.raw.RawDecoder`.

    One unpacker shared by several brackets (the lamps of a capture) keeps LibRaw busy across
    their boundaries. A file taken out of order, or again, is unpacked when taken. Use as a context
    manager: files never taken are closed at the end.
    """

    def __init__(
        self, paths: Sequence[PathLike], ahead: int = PREFETCH_FRAMES, decoder: RawDecoder = "auto"
    ) -> None:
        self._order = deque(Path(p) for p in paths)
        self._ahead = ahead
        self._decoder = decoder
        self._executor = ThreadPoolExecutor(
            max_workers=DECODE_THREADS, thread_name_prefix="raw-unpack"
        )
        self._scheduled: dict[Path, Future[UnpackedRaw]] = {}
        self._lock = threading.Lock()
        self._closed = False
        with self._lock:
            self._schedule_locked()

    def _schedule_locked(self) -> None:
        while self._order and len(self._scheduled) < self._ahead and not self._closed:
            path = self._order.popleft()
            if path not in self._scheduled:
                self._scheduled[path] = self._executor.submit(unpack_raw, path, self._decoder)

    def take(self, path: PathLike) -> UnpackedRaw:
        """``path`` unpacked (waits for it, or unpacks it now); the caller closes it."""
        file = Path(path)
        with self._lock:
            future = self._scheduled.pop(file, None)
            if future is None and file in self._order:
                self._order.remove(file)
            self._schedule_locked()
        return future.result() if future is not None else unpack_raw(file, self._decoder)

    def __enter__(self) -> Unpacker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop unpacking; close the files unpacked but never taken."""
        with self._lock:
            self._closed = True
            left = list(self._scheduled.values())
            self._scheduled.clear()
        self._executor.shutdown(wait=True, cancel_futures=True)
        for future in left:
            if not future.cancelled() and future.exception() is None:
                future.result().close()


def _prefetch(
    schedule: Sequence[tuple[Path, float, bool]],
    first_light: int,
    saturation_fraction: float,
    pool: _BufferPool,
    holder: _RegionHolder,
    unpacker: Unpacker,
) -> Generator[RawPlanes, None, None]:
    """Decode the frames in order, :data:`PREFETCH_FRAMES` ahead of the consumer, on
    :data:`DECODE_THREADS` threads (LibRaw releases the GIL), so the decoders keep going while a
    frame takes the merge longer than usual. Frames after ``first_light`` (the schedule's first
    light frame, which chooses the region) wait for the region before they are cut into planes."""

    def decode(position: int) -> RawPlanes:
        path, exposure, keep_difference = schedule[position]
        unpacked = unpacker.take(path)
        if position > first_light:
            holder.chosen.wait()
        return read_raw(
            path,
            exposure_s=exposure,
            saturation_fraction=saturation_fraction,
            keep_green_difference=keep_difference,
            buffers=pool.take(),
            region=holder.region,
            unpacked=unpacked,
        )

    with ThreadPoolExecutor(
        max_workers=DECODE_THREADS, thread_name_prefix="raw-decode"
    ) as executor:
        try:
            pending: deque[Future[RawPlanes]] = deque(
                executor.submit(decode, position)
                for position in range(min(PREFETCH_FRAMES, len(schedule)))
            )
            for position in range(len(schedule)):
                current = pending.popleft().result()
                following = position + PREFETCH_FRAMES
                if following < len(schedule):
                    pending.append(executor.submit(decode, following))
                yield current
        finally:  # the merge failed or stopped early: no frame may wait for the region any more
            holder.chosen.set()


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
    prediction_fraction: float = PREDICTION_FRACTION,
    near_black_sigma: float = 3.0,
    progress: ProgressCallback | None = None,
    region: PlaneRegion | RegionChooser | None = None,
    unpacker: Unpacker | None = None,
    plan: DecodePlan | None = None,
    decoder: RawDecoder = "auto",
    estimate_gains: bool = True,
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
        Passed to :func:`calib.image.raw.read_raw`.
    prediction_fraction
        A sample whose predicted level exceeds this fraction of the clipping level is excluded.
    near_black_sigma
        A sample predicted below this many read-noise sigmas is excluded where a longer exposure
        covers it.
    progress
        Called after each merged frame with ``(done, total, path)``.
    region
        Merge only these plane samples (``(rows, columns)`` of the full planes), or a function
        that chooses them from the first decoded light frame (full planes; ``None`` = all). The
        merge then costs the region, not the frame, and so does decoding the DNGs the tile
        decoder reads (LibRaw unpacks other files whole); the image records where the region lies
        (``region_origin_px``, ``full_sensor_shape_px``).
    unpacker
        Unpacks the files ahead, shared with other brackets (the :attr:`DecodePlan.paths` of
        :func:`decode_order` are this bracket's order); by default one of the bracket's own.
    plan
        These files' metadata and decode order from :func:`decode_order` (called with the same
        files and exposure times), so that the metadata is not read again; read here when ``None``.
    decoder
        Which decoder reads the pixels (:data:`calib.image.raw.RawDecoder`), when the bracket
        unpacks its own files (``unpacker`` is ``None``).
    estimate_gains
        Estimate each frame's actual exposure relative to its recorded time from the samples it
        shares with the frames merged before it (decision 0089); ``False`` trusts the recorded
        times.

    Notes
    -----
    Frames are decoded longest exposure first, except that without a ``noise_model`` the
    second-longest frame comes first: the green pairs of the first two decoded frames estimate the
    noise model (the longest frame often clips much of the band). Should they not span enough
    levels, further frames are held and pooled until the fit succeeds.

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
    estimate_noise = noise_model is None
    if plan is None:
        plan = decode_order(
            frames,
            darks=darks,
            exposure_s=exposure_s,
            dark_exposure_s=dark_exposure_s,
            estimate_noise=estimate_noise,
        )
    elif [m.path for m in plan.frames] != [Path(p) for p in frames] or [
        m.path for m in plan.darks
    ] != [Path(p) for p in darks]:
        raise ValueError("the decode plan was made for other files than these frames and darks")
    plan = plan.replanned(estimate_noise=estimate_noise)
    reference = plan.frames[0]
    ordered = plan.ordered
    settings = _MergeSettings(
        prediction_fraction=prediction_fraction,
        near_black_sigma=near_black_sigma,
        exposures_s=tuple(m.exposure_s for m in ordered),
        estimate_gains=estimate_gains,
    )
    pool = _BufferPool()
    holder = (
        _RegionHolder(chooser=region)
        if callable(region)
        else _RegionHolder(region=_checked_region(region))
    )
    merger = _Merger(ordered, plan, settings, noise_model, progress, pool, holder)
    source = unpacker or Unpacker(plan.paths, decoder=decoder)
    decoded = _prefetch(plan.schedule, plan.first_light, saturation_fraction, pool, holder, source)
    try:
        return _merge_decoded(merger, plan, decoded, reference)
    finally:  # stop the decoders, then the unpacker if it is ours
        decoded.close()
        if source is not unpacker:
            source.close()


def _merge_decoded(
    merger: _Merger, plan: DecodePlan, decoded: Iterable[RawPlanes], reference: RawMetadata
) -> HdrImage:
    """Feed the frames, decoded in the plan's order, to the merge; its result."""
    for planes, (role, index) in zip(decoded, plan.roles, strict=True):
        if role == "dark":
            merger.add_dark(planes, index)
        else:
            merger.add_light(planes, index)
    return merger.finish(reference)


def merge_planes(
    frames: Sequence[RawPlanes],
    *,
    darks: Sequence[RawPlanes] = (),
    noise_model: NoiseModel | None = None,
    prediction_fraction: float = PREDICTION_FRACTION,
    near_black_sigma: float = 3.0,
    estimate_gains: bool = True,
) -> HdrImage:
    """:func:`merge_bracket`'s merge of frames already decoded (or rendered) in memory.

    The frames (and darks) are consumed: their planes become the merge's work buffers. Each needs
    its own ``metadata.path`` (it names the frame in the records); the other arguments are
    :func:`merge_bracket`'s. The validation protocol merges its rendered brackets through it
    (:mod:`calib.evaluation.validation.capture`), so they meet the merge a capture meets.

    Examples
    --------
    >>> from calib.image.raw import RawPlanes
    >>> from calib.image.raw_metadata import RawMetadata
    >>> def frame(name, exposure_s, level_dn):
    ...     meta = RawMetadata(Path(name), exposure_s, "override", 100.0, None, None, None, None)
    ...     signal = np.full((3, 8, 8), level_dn, np.float32)
    ...     signal[:, 0, 0] += 1.0  # not blank
    ...     return RawPlanes(meta, signal, np.zeros((3, 8, 8), bool), "RGGB", (0.0,) * 3,
    ...                      (4000.0,) * 3, ((0.0, 0.0), (0.5, 0.5), (1.0, 1.0)))
    >>> noise = NoiseModel(1.0, (2.0, 2.0, 2.0))
    >>> image = merge_planes([frame("a", 0.01, 100.0), frame("b", 0.04, 400.0)], noise_model=noise)
    >>> round(float(image.radiance[1, 4, 4]))
    10000
    """
    if not frames:
        raise InputError("no frames to merge", source="bracket")
    if not 0.0 < prediction_fraction <= 1.0:
        raise ValueError(f"prediction_fraction must be in (0, 1], got {prediction_fraction}")
    by_path = {planes.metadata.path: planes for planes in (*frames, *darks)}
    if len(by_path) != len(frames) + len(darks):
        raise ValueError("every frame and dark needs its own metadata.path")
    plan = DecodePlan.build(
        [planes.metadata for planes in frames],
        [planes.metadata for planes in darks],
        estimate_noise=noise_model is None,
    )
    settings = _MergeSettings(
        prediction_fraction=prediction_fraction,
        near_black_sigma=near_black_sigma,
        exposures_s=tuple(m.exposure_s for m in plan.ordered),
        estimate_gains=estimate_gains,
    )
    merger = _Merger(
        plan.ordered, plan, settings, noise_model, None, _BufferPool(), _RegionHolder()
    )
    decoded = (by_path[path] for path, _, _ in plan.schedule)
    return _merge_decoded(merger, plan, decoded, plan.frames[0])


def decode_order(
    frames: Sequence[PathLike],
    *,
    darks: Sequence[PathLike] = (),
    exposure_s: Sequence[float] | None = None,
    dark_exposure_s: Sequence[float] | None = None,
    estimate_noise: bool = True,
) -> DecodePlan:
    """The order in which :func:`merge_bracket` decodes these files (to unpack them ahead), with
    their metadata: pass it to :func:`merge_bracket` (``plan=``) so that it is read once.

    ``estimate_noise``: no noise model will be given. The arguments are those of
    :func:`merge_bracket`.
    """
    return DecodePlan.build(
        _scan(frames, exposure_s, "frames"),
        _scan(darks, dark_exposure_s, "dark frames"),
        estimate_noise=estimate_noise,
    )


def _check_not_blank(planes: RawPlanes) -> None:
    """A light frame whose every sample has one value (all zero, or flat black) shows nothing: a
    corrupt file, or a capture without the lamp. Merged, it would pass as a very short exposure."""
    signal = planes.signal_dn
    if signal.size and float(signal.max()) == float(signal.min()):
        raise InputError(
            f"the frame is blank (every sample {float(signal.flat[0]):g} DN above black): a "
            "bracket frame must show the direct spot and the band; remove it or capture it again",
            source=str(planes.metadata.path),
        )


def _checked_region(region: PlaneRegion | None) -> PlaneRegion | None:
    if region is None:
        return None
    rows, columns = region
    for part in (rows.start, rows.stop, columns.start, columns.stop):
        if not isinstance(part, int | np.integer):
            raise ValueError(f"a region needs integer start and stop, got {region}")
    if (
        rows.stop <= rows.start
        or columns.stop <= columns.start
        or min(rows.start, columns.start) < 0
    ):
        raise ValueError(f"empty or negative region {region}")
    return (slice(int(rows.start), int(rows.stop)), slice(int(columns.start), int(columns.stop)))


def _scan(
    paths: Sequence[PathLike], exposure_s: Sequence[float] | None, what: str
) -> list[RawMetadata]:
    files = [Path(p) for p in paths]
    return [
        read_raw_metadata(path, exposure_s=override)
        for path, override in zip(files, _overrides(files, exposure_s, what), strict=True)
    ]


@dataclass(frozen=True)
class DecodePlan:
    """A bracket's files with their metadata (read once), and in which order
    :func:`merge_bracket` decodes them: longest exposure first (the second-longest first when the
    noise model is estimated), each dark group right before its first light frame.

    Attributes
    ----------
    frames, darks
        The light and dark frames' metadata, in the order given.
    estimate_noise
        Whether the merge estimates the noise model (keeps the green pairs' difference).
    """

    frames: tuple[RawMetadata, ...]
    darks: tuple[RawMetadata, ...]
    estimate_noise: bool
    ordered: tuple[RawMetadata, ...]  # the light frames, longest exposure first
    schedule: tuple[tuple[Path, float, bool], ...]  # (path, exposure, keep green difference)
    roles: tuple[tuple[str, int], ...]  # ("dark", group) or ("light", index into ordered)
    groups: tuple[_DarkGroup, ...]
    group_of_light: tuple[int | None, ...]  # per index into ordered

    @classmethod
    def build(
        cls, frames: Sequence[RawMetadata], darks: Sequence[RawMetadata], *, estimate_noise: bool
    ) -> DecodePlan:
        """The plan of these files; raises :class:`InputError` as :func:`merge_bracket` does
        when they are not from one camera with the same settings or a dark frame is missing."""
        for meta in frames[1:]:
            _check_metadata(frames[0], meta, check_aperture=True)
        for meta in darks if frames else ():
            _check_metadata(frames[0], meta, check_aperture=False)
        ordered = sorted(frames, key=lambda m: -m.exposure_s)
        groups = _group_darks(darks)
        group_of_light = tuple(
            groups.index(_matching_dark(groups, meta)) if groups else None for meta in ordered
        )
        order = list(range(len(ordered)))
        if estimate_noise and len(order) > 1:
            order.insert(0, order.pop(1))
        schedule: list[tuple[Path, float, bool]] = []
        roles: list[tuple[str, int]] = []
        scheduled_groups: set[int] = set()
        for index in order:
            group = group_of_light[index]
            if group is not None and group not in scheduled_groups:
                scheduled_groups.add(group)
                for dark in groups[group].metadata:
                    schedule.append((dark.path, dark.exposure_s, False))
                    roles.append(("dark", group))
            schedule.append((ordered[index].path, ordered[index].exposure_s, estimate_noise))
            roles.append(("light", index))
        return cls(
            tuple(frames),
            tuple(darks),
            estimate_noise,
            tuple(ordered),
            tuple(schedule),
            tuple(roles),
            tuple(groups),
            group_of_light,
        )

    def replanned(self, *, estimate_noise: bool) -> DecodePlan:
        """The plan of the same files for a merge that estimates the noise model, or not."""
        if estimate_noise == self.estimate_noise:
            return self
        return DecodePlan.build(self.frames, self.darks, estimate_noise=estimate_noise)

    @property
    def paths(self) -> list[Path]:
        """Every file in decode order (for an :class:`Unpacker`)."""
        return [path for path, _, _ in self.schedule]

    @property
    def first_light(self) -> int:
        """Position in the schedule of the first light frame (the one that chooses the region)."""
        return next(i for i, (role, _) in enumerate(self.roles) if role == "light")


class _Merger:
    """The merge's state while frames arrive in the plan's order."""

    def __init__(
        self,
        ordered: Sequence[RawMetadata],
        plan: DecodePlan,
        settings: _MergeSettings,
        noise_model: NoiseModel | None,
        progress: ProgressCallback | None,
        pool: _BufferPool,
        holder: _RegionHolder,
    ) -> None:
        self.pool = pool
        self.holder = holder
        self.ordered = ordered
        self.plan = plan
        self.settings = settings
        self.noise = noise_model
        self.progress = progress
        self.layout: _PlaneLayout | None = None
        self.reference: RawMetadata | None = None
        self.state: _Accumulator | None = None
        self.masters: dict[int, _MasterDark] = {}
        self.building: dict[int, _MasterDark] = {}
        self.remaining = {
            group: plan.group_of_light.count(group) for group in set(plan.group_of_light)
        }
        self.dark_spreads: list[DarkSpread] = []
        self.held: list[tuple[RawPlanes, int]] = []
        self.pair_statistics: list[PairStatistics] = []
        self.records: dict[int, FrameRecord] = {}

    def _check(self, planes: RawPlanes, *, light: bool) -> None:
        if light:
            _check_not_blank(planes)
        if self.layout is None:
            self.layout = _PlaneLayout.of(planes)
        _check_planes(self.layout, planes)
        if light and self.reference is None:
            self.reference = planes.metadata
        elif self.reference is not None:
            _check_metadata(self.reference, planes.metadata, check_aperture=light)

    def _in_region(self, planes: RawPlanes) -> RawPlanes:
        region = self.holder.region
        if region is None or (
            planes.region_origin == (region[0].start, region[1].start)
            and planes.plane_shape
            == (region[0].stop - region[0].start, region[1].stop - region[1].start)
        ):
            return planes
        return planes.cropped(region)

    def add_dark(self, planes: RawPlanes, group: int) -> None:
        self._check(planes, light=False)
        planes = self._in_region(planes)
        self.dark_spreads.append(DarkSpread.of(planes))
        if group in self.building:
            # the running sum may predate the region's choice: use its view of the region
            total = self.building[group].matching(planes)
            np.add(total.signal_dn, planes.signal_dn, out=total.signal_dn)
            self.pool.give(planes.signal_dn, planes.saturated)
        else:  # the group's first dark frame holds the running sum
            total = _MasterDark(
                PlaneBuffers(planes.signal_dn, planes.saturated),
                0,
                self.plan.groups[group].paths,
                planes.region_origin,
            )
        total.count += 1
        if total.count < len(self.plan.groups[group].metadata):
            self.building[group] = total
            return
        self.building.pop(group, None)
        np.multiply(total.signal_dn, np.float32(1.0 / total.count), out=total.signal_dn)
        self.masters[group] = total

    def add_light(self, planes: RawPlanes, index: int) -> None:
        self._check(planes, light=True)
        if self.holder.chooser is not None:
            chooser, self.holder.chooser = self.holder.chooser, None
            chosen = _checked_region(chooser(planes))
            if chosen is not None:
                height, width = planes.full_shape
                rows = slice(min(chosen[0].start, height), min(chosen[0].stop, height))
                columns = slice(min(chosen[1].start, width), min(chosen[1].stop, width))
                self.holder.region = _checked_region((rows, columns))
            self.holder.chosen.set()
        planes = self._in_region(planes)
        if self.noise is not None:
            self._merge(planes, index)
            return
        self.held.append((planes, index))
        self.pair_statistics.append(green_pair_statistics(planes))
        if len(self.held) < min(NOISE_POOL_FRAMES, len(self.ordered)):
            return
        try:
            noise = fit_noise_model(
                self.pair_statistics,
                planes.clip_level_dn[1],
                ", ".join(held.metadata.path.name for held, _ in self.held),
            )
        except EstimationError:
            if len(self.held) + len(self.records) < len(self.ordered):
                return  # pool with the next frame
            raise
        if self.dark_spreads:
            noise = NoiseModel(
                noise.gain_dn_per_electron,
                dark_read_noise(self.dark_spreads, noise.gain_dn_per_electron),
                source=f"{noise.source}; read noise from {len(self.dark_spreads)} dark frame(s)",
            )
        self.noise = noise
        self.pair_statistics.clear()
        held, self.held = self.held, []
        for held_planes, held_index in held:
            self._merge(held_planes, held_index)

    def _merge(self, planes: RawPlanes, index: int) -> None:
        assert self.noise is not None
        if self.state is None:
            self.state = _Accumulator.zeros(planes.signal_dn.shape)
        group = self.plan.group_of_light[index]
        master = self.masters[group].matching(planes) if group is not None else None
        saturated_fraction = planes.saturated.mean(axis=(1, 2))
        meta = self.ordered[index]
        frame_gain = _merge_frame(
            planes,
            master,
            self.noise,
            self.settings,
            self.state,
            is_shortest=index == len(self.ordered) - 1,
            is_first=not self.records,
        )
        self.pool.give(planes.signal_dn, planes.saturated)
        self.records[index] = FrameRecord(
            path=meta.path,
            exposure_s=meta.exposure_s,
            dark_paths=master.paths if master is not None else (),
            saturated_fraction=(
                float(saturated_fraction[0]),
                float(saturated_fraction[1]),
                float(saturated_fraction[2]),
            ),
            decoding=planes.decoding,
            gain=frame_gain.gain,
            gain_sigma=frame_gain.sigma if self.records else 0.0,
            gain_samples=frame_gain.samples,
        )
        if group is not None:
            self.remaining[group] -= 1
            if self.remaining[group] == 0:  # no later frame needs this master dark
                done = self.masters.pop(group)
                self.pool.give(done.buffers.signal_dn, done.buffers.saturated)
        if self.progress is not None:
            self.progress(len(self.records), len(self.ordered), meta.path)

    def finish(self, reference: RawMetadata) -> HdrImage:
        assert self.state is not None and self.noise is not None and self.layout is not None
        records = tuple(self.records[index] for index in sorted(self.records))
        region = self.holder.region
        origin = (0, 0) if region is None else (2 * region[0].start, 2 * region[1].start)
        return _finish(
            self.state,
            self.noise,
            self.layout,
            self.reference or reference,
            records,
            origin,
            gains_estimated=self.settings.estimate_gains,
        )


def _finish(
    state: _Accumulator,
    noise: NoiseModel,
    reference_planes: _PlaneLayout,
    reference: RawMetadata,
    records: tuple[FrameRecord, ...],
    region_origin_px: tuple[int, int] = (0, 0),
    gains_estimated: bool = True,
) -> HdrImage:
    # The gains chain from the first merged frame; anchored so that their geometric mean is 1
    # (the bracket's recorded times are right on average), the merge's scale is the recorded times'.
    anchor = math.exp(sum(math.log(record.gain) for record in records) / max(len(records), 1))
    saturated = state.weight <= 0
    radiance = state.weighted_rate
    np.divide(radiance, state.weight, out=radiance, where=~saturated)
    np.copyto(radiance, state.shortest_rate, where=saturated)
    variance = state.weight
    np.divide(np.float32(1.0), variance, out=variance, where=~saturated)
    variance[saturated] = np.inf
    if anchor != 1.0:
        radiance *= np.float32(anchor)
        variance *= np.float32(anchor * anchor)
        records = tuple(replace(record, gain=record.gain / anchor) for record in records)
    metadata: dict[str, object] = {"channels": CHANNELS}
    if gains_estimated:
        metadata["frame_gains"] = {
            "anchor": "geometric mean of the frames' gains = 1",
            "gains": [record.gain for record in records],
            "sigmas": [record.gain_sigma for record in records],
            "samples": [record.gain_samples for record in records],
            "kept_recorded_time": [
                record.path.name for record in records if record.gain_sigma is None
            ],
        }
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
        metadata=metadata,
        region_origin_px=region_origin_px,
        full_sensor_shape_px=reference_planes.sensor_shape_px,
    )
