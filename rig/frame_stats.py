"""The real frame analyser: what a RAW frame shows of the direct spot and the first-order band.

Automatic bracketing needs, after every scene frame, how much of the direct spot is saturated and how
much signal the first-order band has (:class:`rig.analysis.FrameStats`). :class:`RawFrameAnalyzer`
decodes the frame with :func:`calib.image.raw.read_raw` (black-subtracted R, G, B planes at half
resolution, with a saturation mask) and measures in the geometry :func:`calib.image.profiles.detect_geometry`
finds, per lamp, on the frame binned to at most 400 plane samples a side: the first frame of a lamp
in which the band is detected fixes the geometry for that lamp's later frames, until a shorter
frame comes while the geometry's own frame had saturated cells — the geometry is then detected
again on the shorter frame (when it shows the band). A clipped frame can misplace the spot: where
a strong first order clips over a wide stretch and the direct spot is weaker, detection took the
clipped band for the spot, and the spot's true pixels went unmeasured (decision 0186). Frames are
grouped by their directory, which the session layout (``frames/<lamp>/scene-000.dng``) makes the
lamp.

What is measured, per 2×2 cell of the sensor (one plane sample of each channel):

* **direct saturated fraction** — of the cells in the spot's rectangle, those saturated in any
  channel;
* **band signal** — the channel mean above black, minus the median of strips beside the band,
  averaged over the band's bright part (bins along the band at least a quarter of its 98th
  percentile; a lamp's dim ends do not dilute it);
* **band SNR** — that signal over the noise of one cell, measured on the frame itself from the
  differences of neighbouring cells across the band (robust MAD; no noise model needed);
* **band saturated fraction** — of the band's cells, those saturated in any channel;
* **direct and band unmergeable fractions** — of the spot's and the band's cells, grown by one
  cell on every side (the estimator finds its own geometry on the merged image, and samples each
  channel at its own position), those the HDR merge cannot take from this frame in some channel:
  saturated, or the mean of the sample's eight neighbours above the merge's own
  ``prediction_fraction`` of the clipping level (:func:`calib.image.hdr.merge_bracket`,
  :data:`calib.image.hdr.PREDICTION_FRACTION`). A spot or band pixel that no frame of the
  bracket gives the merge makes the estimator's extraction refuse the lamp ("saturated in every
  frame").

A frame whose band cannot be found (an exposure too short to show it) gets a band SNR of 0 and its
spot found as the region above half the frame's peak, so bracketing extends towards longer
exposures; a frame without a spot, or whose spot or band leaves the sensor, cannot be measured and
raises :class:`rig.errors.FrameAnalysisError` with what to change at the rig.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from calib.core.arrays import BoolArray, FloatArray
from calib.core.errors import InputError
from calib.image.hdr import PREDICTION_FRACTION, FrameRecord, HdrImage
from calib.image.profiles import DetectionError, DiffractionGeometry, detect_geometry
from calib.image.profiles.geometry import rectangle_window, sample_positions, to_uv
from calib.image.raw import DEFAULT_SATURATION_FRACTION, RawPlanes, read_raw, read_raw_metadata
from calib.image.sensor_noise import leave_one_out_mean
from rig.analysis import FrameStats
from rig.errors import FrameAnalysisError

#: Bins along the band are this many sensor pixels long.
BAND_BIN_PX = 4.0
#: A bin belongs to the band's bright part from this fraction of the 98th-percentile bin.
BRIGHT_FRACTION = 0.25
#: Fewest neighbour pairs for a noise estimate from the frame itself.
MIN_NOISE_PAIRS = 20
_MAD_TO_SIGMA = 1.4826
#: The frame's peak must stand this many noise sigmas above its median to count as a spot.
MIN_SPOT_SNR = 20.0
#: Frames are binned for detection until their planes are at most this many samples long.
DETECTION_SIZE = 400
#: The spot's and the band's rectangles grow by this many cells for the unmergeable fractions.
UNMERGEABLE_MARGIN_CELLS = 1
#: A frame is shorter than another when its exposure is below the other's by this fraction.
SHORTER_FRAME_RTOL = 0.02
#: Detection failures that mean "expose longer", not "the set-up is wrong".
_BAND_TOO_DIM = ("no_band",)


@dataclass(frozen=True, eq=False)
class _Frame:
    """A decoded frame: its planes, the channel mean per cell, and the any-channel saturation."""

    planes: RawPlanes
    image: HdrImage
    mean_dn: NDArray[np.float32]
    saturated: BoolArray


def _decode(path: Path, saturation_fraction: float) -> _Frame:
    try:
        planes = read_raw(path, saturation_fraction=saturation_fraction)
    except InputError as exc:
        raise FrameAnalysisError(
            str(path), f"cannot be decoded as a RAW frame ({exc}); the camera must deliver RAW"
        ) from None
    saturated: BoolArray = np.any(planes.saturated, axis=0)
    image = HdrImage(
        radiance=planes.signal_dn,
        # Detection reads the radiance and the saturation only; a unit variance keeps the type.
        variance=np.broadcast_to(np.float32(1.0), planes.signal_dn.shape),
        saturated=planes.saturated,
        channel_origin_px=planes.channel_origin_px,
        pixel_pitch_px=2.0,
        cfa_pattern=planes.cfa_pattern,
        frames=(
            FrameRecord(
                path,
                float(planes.metadata.exposure_s),
                (),
                _three(planes.saturated.mean(axis=(1, 2))),
            ),
        ),
    )
    mean_dn = planes.signal_dn.mean(axis=0, dtype=np.float32)
    return _Frame(planes, image, mean_dn, saturated)


def binned_mean(planes: NDArray[np.float32]) -> NDArray[np.float32]:
    """The mean of each 2×2 block of ``planes`` (shape ``(3, 2h, 2w)`` → ``(3, h, w)``, float32).

    The same floats as ``planes.reshape(3, h, 2, w, 2).mean(axis=(2, 4), dtype=np.float32)``
    (tested bit for bit against it), at a tenth of its cost: that reduction over two strided
    axes took 11 ms of a 600×400-sample frame, the four strided slices take 1 ms. NumPy sums a
    block as (top left + top right) + (bottom left + bottom right), except when the blocks form a
    single column (``w == 1``), where it adds the four in turn; that case is left to NumPy.
    """
    if planes.shape[2] <= 2:
        height, width = planes.shape[1] // 2, planes.shape[2] // 2
        shape = (planes.shape[0], height, 2, width, 2)
        mean: NDArray[np.float32] = planes.reshape(shape).mean(axis=(2, 4), dtype=np.float32)
        return mean
    top_left, top_right = planes[:, 0::2, 0::2], planes[:, 0::2, 1::2]
    bottom_left, bottom_right = planes[:, 1::2, 0::2], planes[:, 1::2, 1::2]
    total = top_left + top_right
    total += bottom_left + bottom_right
    total /= np.float32(4.0)
    return total


def binned_any(saturated: BoolArray) -> BoolArray:
    """Whether any sample of each 2×2 block of ``saturated`` is set (``(3, 2h, 2w)`` →
    ``(3, h, w)``); as ``np.any`` over the blocks, without its strided reduction (10 ms → 0.6 ms)."""
    result: BoolArray = saturated[:, 0::2, 0::2] | saturated[:, 0::2, 1::2]
    result |= saturated[:, 1::2, 0::2]
    result |= saturated[:, 1::2, 1::2]
    return result


def _detection_image(image: HdrImage) -> HdrImage:
    """``image`` binned 2×2 (plane samples) while its long side exceeds :data:`DETECTION_SIZE`.

    Detection only needs where the spot and the band are; on a binned image it is several times
    faster, and the geometry stays in sensor pixels (pitch and channel origins follow the binning).
    """
    while max(image.plane_shape) > DETECTION_SIZE:
        height, width = (size // 2 * 2 for size in image.plane_shape)
        radiance = binned_mean(image.radiance[:, :height, :width])
        saturated = binned_any(image.saturated[:, :height, :width])
        pitch = image.pixel_pitch_px
        image = HdrImage(
            radiance=radiance,
            variance=np.broadcast_to(np.float32(1.0), radiance.shape),
            saturated=saturated,
            # A binned sample is the mean of two samples a pitch apart in each direction.
            channel_origin_px=tuple(
                (row + pitch / 2, column + pitch / 2) for row, column in image.channel_origin_px
            ),
            pixel_pitch_px=2 * pitch,
            cfa_pattern=image.cfa_pattern,
            frames=image.frames,
        )
    return image


def _three(values: FloatArray) -> tuple[float, float, float]:
    first, second, third = (float(value) for value in values)
    return first, second, third


def _cells_in(
    frame: _Frame,
    centre: tuple[float, float],
    angle_deg: float,
    u_range: tuple[float, float],
    v_range: tuple[float, float],
) -> tuple[tuple[slice, slice], FloatArray, FloatArray, BoolArray] | None:
    """Window of cells around a ``(u, v)`` rectangle, their cell-centre ``u``, ``v`` and the inside mask."""
    window = rectangle_window(frame.image, centre, angle_deg, u_range, v_range)
    if window is None:
        return None
    # The green sample sits at the centre of its 2×2 cell.
    y, x = sample_positions(frame.image, 1, *window)
    u, v = to_uv(x, y, centre, angle_deg)
    inside = (u >= u_range[0]) & (u <= u_range[1]) & (v >= v_range[0]) & (v <= v_range[1])
    return window, u, v, inside


def _robust_sigma(values: FloatArray) -> float:
    return _MAD_TO_SIGMA * float(np.median(np.abs(values - np.median(values))))


def _unmergeable(
    frame: _Frame, window: tuple[slice, slice], prediction_fraction: float
) -> BoolArray:
    """Cells of ``window`` the HDR merge cannot take from this frame in some channel.

    As :func:`calib.image.hdr.merge_bracket` decides: a sample is left out when it is saturated or
    the mean of its eight neighbours (:func:`calib.image.sensor_noise.leave_one_out_mean`, on the
    whole frame's planes: one cell of context is taken around the window) exceeds
    ``prediction_fraction`` of its channel's clipping level.
    """
    rows, columns = window
    height, width = frame.saturated.shape
    row_lo, row_hi = max(rows.start - 1, 0), min(rows.stop + 1, height)
    column_lo, column_hi = max(columns.start - 1, 0), min(columns.stop + 1, width)
    signal = frame.planes.signal_dn[:, row_lo:row_hi, column_lo:column_hi]
    level = leave_one_out_mean(signal, out=np.empty_like(signal))
    clip_level = np.asarray(frame.planes.clip_level_dn, dtype=np.float32)
    above: BoolArray = np.any(level > prediction_fraction * clip_level[:, None, None], axis=0)
    inner = (
        slice(rows.start - row_lo, rows.stop - row_lo),
        slice(columns.start - column_lo, columns.stop - column_lo),
    )
    result: BoolArray = above[inner] | frame.saturated[window]
    return result


def _direct_fractions(
    frame: _Frame, geometry: DiffractionGeometry, prediction_fraction: float
) -> tuple[float, float]:
    """``(saturated_fraction, unmergeable_fraction)`` of the direct spot's cells."""
    along, across = geometry.spot_half_size_px
    margin = UNMERGEABLE_MARGIN_CELLS * frame.image.pixel_pitch_px
    cells = _cells_in(
        frame,
        geometry.spot_centre_px,
        geometry.primary.angle_deg,
        (-along - margin, along + margin),
        (-across - margin, across + margin),
    )
    if cells is None:
        raise FrameAnalysisError(
            str(frame.planes.metadata.path), "the direct spot is off the frame"
        )
    window, u, v, grown = cells
    inside = grown & (np.abs(u) <= along) & (np.abs(v) <= across)
    count = int(inside.sum())
    saturated = float(frame.saturated[window][inside].sum()) / count if count else 0.0
    unmergeable = _unmergeable(frame, window, prediction_fraction)[grown]
    return saturated, float(unmergeable.mean()) if unmergeable.size else 0.0


def _band_stats(
    frame: _Frame, geometry: DiffractionGeometry, prediction_fraction: float
) -> tuple[float, float, float, float]:
    """``(signal_dn, snr, saturated_fraction, unmergeable_fraction)`` of the primary first order."""
    band = geometry.primary
    centre, angle = geometry.spot_centre_px, band.angle_deg
    offset = band.centre_offset_px
    inner = band.band_half_width_px + geometry.background_gap_px
    outer = inner + geometry.background_width_px
    margin = UNMERGEABLE_MARGIN_CELLS * frame.image.pixel_pitch_px
    cells = _cells_in(
        frame,
        centre,
        angle,
        (band.start_px - margin, band.stop_px + margin),
        (offset - outer, offset + outer),
    )
    if cells is None:
        return 0.0, 0.0, 0.0, 0.0
    window, u, v, grown = cells
    along_band = grown & (u >= band.start_px) & (u <= band.stop_px)
    values = frame.mean_dn[window].astype(np.float64)
    saturated = frame.saturated[window]
    across = np.abs(v - offset)
    in_band = along_band & (across <= band.half_width_px)
    in_strips = along_band & (across >= inner) & ~saturated
    if not in_band.any():
        return 0.0, 0.0, 0.0, 0.0
    grown_band = grown & (across <= band.half_width_px + margin)
    unmergeable = float(_unmergeable(frame, window, prediction_fraction)[grown_band].mean())
    background = float(np.median(values[in_strips])) if in_strips.any() else 0.0
    net = values - background
    bins = np.floor((u - band.start_px) / BAND_BIN_PX).astype(np.int64)
    n_bins = int(bins[in_band].max()) + 1
    sums = np.bincount(bins[in_band], weights=net[in_band], minlength=n_bins)
    counts = np.bincount(bins[in_band], minlength=n_bins)
    means = np.divide(sums, counts, out=np.zeros(n_bins), where=counts > 0)
    top = float(np.percentile(means[counts > 0], 98))
    bright_bins = means >= BRIGHT_FRACTION * top if top > 0 else counts > 0
    bright = in_band & bright_bins[np.clip(bins, 0, n_bins - 1)]
    signal = float(net[bright].mean())
    saturated_fraction = float(saturated[in_band].mean())
    snr = _snr(net, bright & ~saturated, signal, angle)
    return signal, snr, saturated_fraction, unmergeable


def _snr(net: FloatArray, usable: BoolArray, signal: float, angle_deg: float) -> float:
    """Signal over the noise of one cell, from the differences of neighbours across the band."""
    if signal <= 0:
        return 0.0
    # Neighbours across a mostly horizontal band are the cells above/below, else left/right.
    axis = (
        0 if abs(math.cos(math.radians(angle_deg))) >= abs(math.sin(math.radians(angle_deg))) else 1
    )
    first = [slice(None), slice(None)]
    second = [slice(None), slice(None)]
    first[axis], second[axis] = slice(None, -1), slice(1, None)
    pairs = usable[tuple(first)] & usable[tuple(second)]
    differences = (net[tuple(second)] - net[tuple(first)])[pairs]
    if differences.size < MIN_NOISE_PAIRS:
        # Too few unsaturated pairs (a band clipped almost everywhere): shot noise at one
        # electron per DN bounds the noise from below, so this SNR is an upper bound.
        return math.sqrt(signal)
    sigma = _robust_sigma(differences) / math.sqrt(2.0)
    return signal / sigma if sigma > 0 else math.sqrt(signal)


def _spot_only_stats(frame: _Frame, prediction_fraction: float) -> FrameStats:
    """Stats of a frame without a detectable band: the spot is the region above half the peak."""
    values = frame.mean_dn
    background = float(np.median(values))
    sample = values.ravel()[:: max(1, values.size // 200_000)].astype(np.float64)
    noise = max(_robust_sigma(sample), 1e-6)
    peak_index = np.unravel_index(int(np.argmax(values)), values.shape)
    peak = float(values[peak_index])
    if peak - background < MIN_SPOT_SNR * noise:
        raise FrameAnalysisError(
            str(frame.planes.metadata.path),
            f"no direct spot: the brightest cell is only {(peak - background) / noise:.1f} noise "
            "sigmas above the background; check that the lamp is on and the slit is in view",
        )
    labels, _ = ndimage.label(values >= background + 0.5 * (peak - background))
    spot = labels == labels[peak_index]
    rows, columns = ndimage.find_objects(spot.astype(np.int32))[0]
    unmergeable = _unmergeable(frame, (rows, columns), prediction_fraction)[spot[rows, columns]]
    return FrameStats(
        direct_saturated_fraction=float(frame.saturated[spot].mean()),
        band_snr=0.0,
        band_signal_dn=0.0,
        band_saturated_fraction=0.0,
        direct_unmergeable_fraction=float(unmergeable.mean()),
    )


def frame_exposure_s(frame: Path) -> float | None:
    """The exposure (s) a RAW frame's own metadata records; ``None`` when it cannot be read."""
    try:
        return float(read_raw_metadata(frame).exposure_s)
    except (InputError, OSError, ValueError):
        return None


class RawFrameAnalyzer:
    """:class:`rig.analysis.FrameAnalyzer` for RAW frames (any format LibRaw reads).

    Parameters
    ----------
    saturation_fraction
        A sample is saturated from this fraction of the way from black to the clipping level
        (:func:`calib.image.raw.read_raw`).
    prediction_fraction
        The HDR merge's: a sample whose neighbours average above this fraction of the clipping
        level is unmergeable (default: the merge's own, :data:`calib.image.hdr.PREDICTION_FRACTION`).
    """

    def __init__(
        self,
        *,
        saturation_fraction: float = DEFAULT_SATURATION_FRACTION,
        prediction_fraction: float = PREDICTION_FRACTION,
    ) -> None:
        self.saturation_fraction = saturation_fraction
        self.prediction_fraction = prediction_fraction
        self.geometries: dict[str, DiffractionGeometry] = {}
        """The geometry used for each lamp (frame directory), once detected."""
        self._geometry_frames: dict[str, tuple[float, bool]] = {}
        """Per lamp: the exposure (s) of the frame its geometry came from, and whether that frame
        had saturated cells."""

    def _detect_again(self, lamp: str, exposure_s: float) -> bool:
        """Whether a frame of ``exposure_s`` should replace the lamp's geometry: it is shorter than
        the geometry's frame, which had saturated cells."""
        geometry_exposure_s, clipped = self._geometry_frames[lamp]
        return clipped and exposure_s < geometry_exposure_s * (1 - SHORTER_FRAME_RTOL)

    def analyse(self, frame: Path) -> FrameStats:
        """The frame's statistics; :class:`FrameAnalysisError` when it cannot be measured."""
        path = Path(frame)
        decoded = _decode(path, self.saturation_fraction)
        lamp = path.parent.name
        geometry = self.geometries.get(lamp)
        exposure_s = float(decoded.planes.metadata.exposure_s)
        if geometry is None or self._detect_again(lamp, exposure_s):
            try:
                found = detect_geometry(_detection_image(decoded.image))
            except DetectionError as exc:
                if geometry is None:
                    if exc.reason in _BAND_TOO_DIM:
                        return _spot_only_stats(decoded, self.prediction_fraction)
                    raise FrameAnalysisError(str(path), str(exc)) from None
                # the longer frame's geometry stands where the shorter frame cannot place the band
            else:
                geometry = self.geometries[lamp] = found
                self._geometry_frames[lamp] = (exposure_s, bool(decoded.saturated.any()))
        signal, snr, band_saturated, band_unmergeable = _band_stats(
            decoded, geometry, self.prediction_fraction
        )
        direct_saturated, direct_unmergeable = _direct_fractions(
            decoded, geometry, self.prediction_fraction
        )
        return FrameStats(
            direct_saturated_fraction=direct_saturated,
            band_snr=max(snr, 0.0),
            band_signal_dn=signal,
            band_saturated_fraction=band_saturated,
            direct_unmergeable_fraction=direct_unmergeable,
            band_unmergeable_fraction=band_unmergeable,
        )
