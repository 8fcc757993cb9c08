"""Direct RGB and first-order profiles of an HDR image in a fixed geometry.

The direct RGB is the background-subtracted radiance integrated over the spot's aperture (DN/s
integrated over sensor pixels). A sharp spot a few pixels wide falls on different numbers of each
colour's columns, so each plane's sum times the plane pitch squared misses its colour; on a Bayer
sensor the cells' interleaving reads every sensor column's share of the slit image from the green
plane's two sites without a model of its edge (decision 0119); the plain sums are kept where the
slit image has almost no first harmonic at the plane pitch (its blur, or a width of a whole number
of pitches, decision 0140), else one slit-image shape shared by the channels is fitted to every
plane's samples (decision 0114). The
profile is the mean across the central part of the band in bins of ``bin_px`` along it; every
channel's samples are placed at their true sensor position (R, G and B sit at different places of
the 2×2 cell), binned, and resampled linearly to one common ``pixel`` axis, the distance from the
spot centre. Standard deviations are propagated from the HDR variance.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.observations import LampKind, LampObservation, OrderProfile
from calib.core.spectra import Spectrum
from calib.image.hdr import HdrImage
from calib.image.profiles.geometry import (
    CHANNEL_NAMES,
    DetectionError,
    DiffractionGeometry,
    OrderBand,
    Side,
    image_source,
    rectangle_window,
    sample_positions,
    to_uv,
)

ALIASING_LIMIT = 0.005
"""Below this first harmonic of the spot's slit image at the plane pitch (its Fourier transform at
``1/pitch`` over its integral, :func:`_aliasing`), the plane's plain sum × pitch² is the spot's
integral to better than ≈ 1 % (the harmonic enters twice, once per side), so the sum is kept, its
aliasing's RMS over the spot's phase in its σ (:func:`_plain_sum_aliasing`); above it the direct
RGB comes from the Bayer interleaving or the slit-image fit."""


FIT_FAILED = "the slit-image fit failed"
"""The note of a slit-image fit that did not converge (the direct RGB is then the plain sum)."""


@dataclass(frozen=True, eq=False)
class Extraction:
    """Direct RGB and first-order profile of one image in one geometry.

    Parameters
    ----------
    side
        Which first order the profile comes from (``+1`` = the stronger).
    pixel
        Shape ``(n,)``: distance of each profile sample from the spot centre along the order, in
        sensor pixels, increasing away from the spot.
    profile
        Shape ``(n, 3)``: mean radiance across the band (R, G, B), background subtracted, DN/s.
    profile_sigma
        Shape ``(n, 3)``: its standard deviation (neighbouring samples share HDR samples through
        the resampling to the common axis, so their errors are mildly correlated).
    direct_rgb, direct_sigma
        Shape ``(3,)``: the direct spot's radiance summed over its aperture in DN/s · pixel², and its
        standard deviation; ``None`` when the spot was saturated and that was allowed.
    background_rgb, direct_background_rgb
        Shape ``(3,)``: per-sample background subtracted from the profile / the direct spot, DN/s.
    samples_per_pixel
        Shape ``(n, 3)``: HDR plane samples averaged into each profile sample (before resampling).
    line_spread
        The direct spot's cross-section along the dispersion direction at the profile's sampling
        (odd length, sum 1): the camera's line spread; ``None`` when the spot was saturated.
    direct_note
        Why a sharp direct spot's colour rests on the colour planes' plain sums (it may be
        aliased: decision 0114); ``None`` when the spot is resolved or blurred enough.
    other_order
        The other first order's profile (side −1) when the geometry holds it whole and it could
        be read (it measures the lens's focal length and the grating's tilt: decision 0197); else
        ``None``.
    other_order_note
        Why the geometry's other first order was not read, or ``None``.
    geometry
        The geometry used.
    source
        The image's frames, for messages and records.
    """

    side: Side
    pixel: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray
    direct_rgb: FloatArray | None
    direct_sigma: FloatArray | None
    background_rgb: FloatArray
    direct_background_rgb: FloatArray
    samples_per_pixel: NDArray[np.int64]
    geometry: DiffractionGeometry
    source: str = "image"
    frames: tuple[str, ...] = field(default_factory=tuple)
    line_spread: FloatArray | None = None
    direct_note: str | None = None
    other_order: OrderProfile | None = None
    other_order_note: str | None = None

    def to_observation(
        self,
        name: str,
        spectrum: Spectrum,
        *,
        kind: LampKind = "other",
        metadata: Mapping[str, object] | None = None,
    ) -> LampObservation:
        """The estimators' input for this lamp: spectrum, profile, direct RGB and their sigmas.

        Parameters
        ----------
        name
            Lamp name.
        spectrum
            The lamp's measured spectrum.
        kind
            Lamp kind (fluorescent lamps serve the peak-based mapping).
        metadata
            Extra entries for the observation's metadata (the geometry, side, frames and
            backgrounds are recorded anyway).
        """
        record: dict[str, object] = {
            "geometry": self.geometry.to_dict(),
            "side": self.side,
            "frames": list(self.frames),
            "background_rgb": self.background_rgb.tolist(),
            "direct_background_rgb": self.direct_background_rgb.tolist(),
            "pixel_unit": "sensor pixels from the direct spot centre",
            "radiance_unit": "DN/s (direct: DN/s summed over sensor pixels)",
            # The profile is the band's mean across its rows, the direct RGB the whole spot's: the
            # rows the band's column total spreads over (its full width at half maximum), for
            # what relates the two per row (calib.methods.uncertainty.PROFILE_ROWS_KEY).
            "profile_rows": 2.0 * self.geometry.order(self.side).band_half_width_px,
        }
        record.update(metadata or {})
        return LampObservation(
            name=name,
            spectrum=spectrum,
            pixel=self.pixel,
            profile=self.profile,
            direct_rgb=self.direct_rgb,
            profile_sigma=self.profile_sigma,
            direct_sigma=self.direct_sigma,
            kind=kind,
            metadata=record,
            line_spread=self.line_spread,
            pixel_origin="direct_spot",
            other_order=self.other_order,
        )


def _channel_uv(
    image: HdrImage,
    channel: int,
    window: tuple[slice, slice],
    centre: tuple[float, float],
    angle_deg: float,
) -> tuple[FloatArray, FloatArray]:
    y, x = sample_positions(image, channel, *window)
    return to_uv(x, y, centre, angle_deg)


def _strip_background(
    image: HdrImage,
    centre: tuple[float, float],
    angle_deg: float,
    u_range: tuple[float, float],
    v_inner: tuple[float, float],
    width: float,
) -> FloatArray:
    """Per-channel median of the strips ``v ∈ [v_inner[0] − width, v_inner[0]]`` and
    ``[v_inner[1], v_inner[1] + width]`` over ``u_range`` (zero where no strip is on the sensor)."""
    background = np.zeros(3)
    window = rectangle_window(
        image, centre, angle_deg, u_range, (v_inner[0] - width, v_inner[1] + width)
    )
    if window is None:
        return background
    for channel in range(3):
        u, v = _channel_uv(image, channel, window, centre, angle_deg)
        in_strip = (u >= u_range[0]) & (u <= u_range[1])
        in_strip &= ((v >= v_inner[0] - width) & (v <= v_inner[0])) | (
            (v >= v_inner[1]) & (v <= v_inner[1] + width)
        )
        values = image.radiance[channel][window][in_strip & ~image.saturated[channel][window]]
        values = values[np.isfinite(values)]
        if values.size:
            background[channel] = float(np.median(values))
    return background


def _binned_profile(
    image: HdrImage,
    channel: int,
    geometry: DiffractionGeometry,
    band: OrderBand,
    first_edge: float,
    n_bins: int,
    window: tuple[slice, slice],
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per bin: sum of values, sum of positions, count, sum of variances, saturated count."""
    u, v = _channel_uv(image, channel, window, geometry.spot_centre_px, band.angle_deg)
    bins = np.floor((u - first_edge) / geometry.bin_px).astype(np.int64)
    inside = (
        (np.abs(v - band.centre_offset_px) <= band.half_width_px) & (bins >= 0) & (bins < n_bins)
    )
    index = bins[inside]
    values = image.radiance[channel][window][inside].astype(np.float64)
    variances = image.variance[channel][window][inside].astype(np.float64)
    saturated = image.saturated[channel][window][inside]

    def total(weights: FloatArray | None) -> FloatArray:
        return np.bincount(index, weights, minlength=n_bins).astype(np.float64)

    usable = ~saturated & np.isfinite(values) & np.isfinite(variances)
    return (
        total(np.where(usable, values, 0.0)),
        total(np.where(usable, u[inside], 0.0)),
        total(usable.astype(np.float64)),
        total(np.where(usable, variances, 0.0)),
        total(saturated.astype(np.float64)),
    )


def _resample(
    centres: FloatArray, means: FloatArray, variances: FloatArray, grid: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Linear interpolation of bin means (at their mean positions) onto ``grid``, with variance."""
    upper = np.clip(np.searchsorted(centres, grid), 1, centres.size - 1)
    lower = upper - 1
    fraction = (grid - centres[lower]) / (centres[upper] - centres[lower])
    values = (1 - fraction) * means[lower] + fraction * means[upper]
    variance = (1 - fraction) ** 2 * variances[lower] + fraction**2 * variances[upper]
    return values, variance


def _extract_profile(
    image: HdrImage,
    geometry: DiffractionGeometry,
    band: OrderBand,
    background: FloatArray,
    source: str,
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int64]]:
    step = geometry.bin_px
    n_samples = math.floor((band.stop_px - band.start_px) / step)
    if n_samples < 2:
        raise DetectionError(
            f"the band (side {band.side:+d}) is shorter than two {step} px samples",
            reason="no_band",
            source=source,
        )
    first_edge = band.start_px - step  # one extra bin on each side for the resampling
    n_bins = n_samples + 2
    grid: FloatArray = band.start_px + (np.arange(n_samples, dtype=np.float64) + 0.5) * step
    window = rectangle_window(
        image,
        geometry.spot_centre_px,
        band.angle_deg,
        (first_edge, first_edge + n_bins * step),
        (band.centre_offset_px - band.half_width_px, band.centre_offset_px + band.half_width_px),
    )
    if window is None:
        raise DetectionError(
            "the band is outside the image", reason="band_off_frame", source=source
        )
    profile = np.empty((n_samples, 3))
    variance = np.empty((n_samples, 3))
    counts = np.empty((n_samples, 3), dtype=np.int64)
    for channel in range(3):
        sums, positions, count, variance_sums, saturated = _binned_profile(
            image, channel, geometry, band, first_edge, n_bins, window
        )
        if saturated[1:-1].any():
            hit = np.flatnonzero(saturated[1:-1])
            raise DetectionError(
                f"the first-order band (side {band.side:+d}) is saturated in every frame of the "
                f"bracket at {grid[hit[0]]:.0f}–{grid[hit[-1]]:.0f} px from the spot "
                f"({CHANNEL_NAMES[channel]} channel); add a shorter exposure",
                reason="saturated",
                source=source,
            )
        filled = count > 0
        if filled.sum() < 2 or not (filled[0] or filled[1]) or not (filled[-1] or filled[-2]):
            raise DetectionError(
                f"the band (side {band.side:+d}) has no {CHANNEL_NAMES[channel]} samples at its "
                "ends; it leaves the frame",
                reason="band_off_frame",
                source=source,
            )
        mean_positions = np.asarray(positions[filled] / count[filled], dtype=np.float64)
        means = np.asarray(sums[filled] / count[filled] - background[channel], dtype=np.float64)
        mean_variances = np.asarray(variance_sums[filled] / count[filled] ** 2, dtype=np.float64)
        profile[:, channel], variance[:, channel] = _resample(
            mean_positions, means, mean_variances, grid
        )
        counts[:, channel] = count[1:-1].astype(np.int64)
    return grid, profile, np.sqrt(variance), counts


def _extract_direct(
    image: HdrImage,
    geometry: DiffractionGeometry,
    allow_saturated: bool,
    source: str,
    subtract_background: bool,
) -> tuple[FloatArray | None, FloatArray | None, FloatArray, FloatArray | None, str | None]:
    """Direct RGB, its σ, the spot's background, its line spread (see :func:`_line_spread`) and why
    a sharp spot's RGB is the planes' plain sum (see :func:`_resolved_direct`).

    The RGB is the Bayer cells' interleaving (:func:`_interleaved_direct`, with its σ); without an
    interleaving (no two greens per cell, a slit image narrower than the pitch) the plain sum or,
    where the plane sampling aliases the spot, the integral of one slit-image shape
    shared by the channels, the two estimates' difference in its σ."""
    centre = geometry.spot_centre_px
    angle = geometry.primary.angle_deg
    along, across = geometry.spot_half_size_px
    background = np.zeros(3)
    if subtract_background:
        gap = geometry.background_gap_px
        background = _strip_background(
            image,
            centre,
            angle,
            (-along, along),
            (-across - gap, across + gap),
            geometry.background_width_px,
        )
    window = rectangle_window(image, centre, angle, (-along, along), (-across, across))
    if window is None:
        raise DetectionError(
            "the direct spot is outside the image", reason="no_spot", source=source
        )
    area = image.pixel_pitch_px**2
    direct = np.empty(3)
    variance = np.empty(3)
    positions: list[FloatArray] = []
    weights: list[FloatArray] = []
    columns: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    spots: list[tuple[FloatArray, FloatArray]] = []
    across_axis = (
        0 if abs(math.cos(math.radians(angle))) >= abs(math.sin(math.radians(angle))) else 1
    )
    for channel in range(3):
        u, v = _channel_uv(image, channel, window, centre, angle)
        inside = (np.abs(u) <= along) & (np.abs(v) <= across)
        if image.saturated[channel][window][inside].any():
            if allow_saturated:
                return None, None, background, None, None
            raise DetectionError(
                f"the direct spot is saturated in every frame of the bracket "
                f"({CHANNEL_NAMES[channel]} channel); add a shorter exposure",
                reason="saturated",
                source=source,
            )
        values = image.radiance[channel][window][inside].astype(np.float64)
        direct[channel] = area * float((values - background[channel]).sum())
        variance[channel] = area**2 * float(
            image.variance[channel][window][inside].astype(np.float64).sum()
        )
        positions.append(u[inside])
        weights.append((values - background[channel]) / max(float(direct[channel]), 1e-300))
        columns.append(
            _column_sums(
                np.broadcast_to(u, inside.shape),
                inside,
                image.radiance[channel][window].astype(np.float64) - background[channel],
                image.variance[channel][window].astype(np.float64),
                across_axis,
            )
        )
        spots.append(
            (
                np.where(inside, image.radiance[channel][window] - background[channel], 0.0),
                np.where(inside, image.variance[channel][window], 0.0),
            )
        )
    cells, lengths = _cells(spots, across_axis)
    spread = _line_spread(
        np.concatenate(positions), np.concatenate(weights), geometry.bin_px, along
    )
    resolved, note, aliasing = _resolved_direct(
        columns, _site_offsets(image, angle), image.pixel_pitch_px, along
    )
    # A slit image narrower than the plane pitch lights too few cells to check the interleaving
    # by its fit (below: its G against the G plane's sum, its colour against its two halves'). A
    # spot whose slit image has (almost) no first harmonic at the plane pitch, blurred or as wide
    # as a whole number of pitches (``_resolved_direct`` returns neither a fit nor a note), keeps
    # its plain sums, off by at most twice that harmonic (decision 0140): the interleaving would
    # only add its noise and a bias of its own where the slit's image is tilted against the columns
    # (each green sees the slit ±tan θ off the R or B site sharing its column: ±0.37 % at 0.8° on a
    # smooth spot, whose weights a and b the fit then barely separates; decision 0123). Where the
    # interleaving reads the spot, a bound on that term is in its σ (decision 0134).
    narrow = note is not None and note != FIT_FAILED
    smooth = resolved is None and note is None
    tilt = _slit_tilt(angle, across_axis)
    # Where the plain sums are kept (a smooth spot, or a narrow one no interleaving reads), their
    # aliasing over the spot's unknown sub-pixel phase is in their σ, as its RMS over that phase
    # (decision 0148).
    plain_variance = variance
    if aliasing is not None:
        relative = _plain_sum_aliasing(*aliasing, image.pixel_pitch_px, lengths, tilt)
        plain_variance = variance + (relative * direct) ** 2
    if smooth:
        variance = plain_variance
    interleaved = (
        None
        if smooth
        else _interleaved_direct(
            cells, lengths, image.cfa_pattern, image.pixel_pitch_px, tilt, across_axis
        )
    )
    halves = (
        _split_half_variance(
            spots, across_axis, image.cfa_pattern, image.pixel_pitch_px, tilt, interleaved[0]
        )
        if narrow and interleaved is not None and _holds_green(interleaved, direct)
        else None
    )
    if interleaved is not None and halves is not None:
        # A slit image narrower than the plane pitch lights one or two columns of each one-site
        # plane: the interleaving then rests on two cells, whose fit has nothing left over to
        # check its one shape against. The slit's two halves along its length are two such
        # readings (at two phases where the slit is tilted against the columns): what they
        # disagree by in colour beyond their noise goes into the σ (decision 0193).
        direct, sigma_interleaved = interleaved
        variance = sigma_interleaved**2 + halves
        note = (
            f"{note}: the direct RGB is the Bayer cells' interleaving of one or two columns "
            f"(R {_percent(direct, variance, 0)}, B {_percent(direct, variance, 2)}, from its two "
            "halves' agreement); defocus the slit image slightly or widen the slit"
        )
    elif interleaved is not None and not narrow:
        # The spot's integral from the Bayer cells' interleaving, which needs no model of the
        # spot's edge (decision 0119), where the spot is sharp enough for the plane sampling to
        # alias it. (Keeping the plain sums where the two agree within 2σ was tried and made the
        # validation twins far worse: an inflated σ let aliased plain sums through; the spectrum
        # test above does not look at the interleaving's σ.)
        direct, sigma_interleaved = interleaved
        variance = sigma_interleaved**2
        note = None
    elif resolved is not None:
        # Two estimates of the spot's integral, each biased its own way: the plain sum by the
        # plane sampling, the fit by an edge profile that is not the Gaussian it assumes (decision
        # 0114: 5–12 % on a spot whose soft edge is as wide as the slit, where the fit's
        # residuals cannot show it). Their difference goes into the value's σ.
        variance = variance + (resolved - direct) ** 2
        direct = resolved
    elif note is not None:
        # The plain sums, which a sharp spot aliases: a narrow slit image no interleaving holds
        # (none, its G off the G plane's sum, or a half without one), their aliasing for the
        # fitted slit image in their σ — tens of per cent this narrow (decision 0193); or a slit
        # image whose fit failed, with no such σ.
        variance = plain_variance
        size = (
            f"R {_percent(direct, variance, 0)}, B {_percent(direct, variance, 2)}"
            if narrow
            else "its colour may be off by tens of per cent"
        )
        note = (
            f"{note}: the direct RGB is each colour plane's plain sum, which a sharp spot "
            f"aliases ({size}); defocus the slit image slightly or widen the slit"
        )
    return direct, np.sqrt(variance), background, spread, note


#: Where a narrow slit image's interleaving is kept (decision 0193): its G total within this
#: (and 3 of its σ) of the G plane's plain sum, which holds both of each cell's sensor columns and
#: so is near exact for any spot. On slit images 1.2 px wide (and narrower) the two cells' fit
#: breaks down and its G total is 5–13 % off; at 1.5–1.9 px it is within 0.2 %.
INTERLEAVED_GREEN_TOLERANCE = 0.01


def _holds_green(interleaved: tuple[FloatArray, FloatArray], plain: FloatArray) -> bool:
    """Whether an interleaving's G total agrees with the G plane's plain sum
    (:data:`INTERLEAVED_GREEN_TOLERANCE`)."""
    values, sigma = interleaved
    if not (plain[1] > 0 and values[1] > 0):
        return False
    return bool(
        abs(values[1] / plain[1] - 1.0) <= INTERLEAVED_GREEN_TOLERANCE + 3.0 * sigma[1] / values[1]
    )


def _cells(
    spots: list[tuple[FloatArray, FloatArray]], across_axis: int, lines: slice = slice(None)
) -> tuple[list[tuple[FloatArray, FloatArray]], list[FloatArray]]:
    """Per channel, from its spot window's values and variances (zero outside the spot), over the
    plane lines ``lines`` along the slit: each plane column's sum along the slit and the sum's
    variance (:func:`_interleaved_direct`'s ``cells``), and each plane line's sum across it
    (its ``lengths``). ``across_axis``: the axis the slit runs along."""
    cells = []
    lengths = []
    for values, variances in spots:
        part = values[lines] if across_axis == 0 else values[:, lines]
        part_variance = variances[lines] if across_axis == 0 else variances[:, lines]
        cells.append(
            (
                np.asarray(part.sum(axis=across_axis, dtype=np.float64), dtype=np.float64),
                np.asarray(part_variance.sum(axis=across_axis, dtype=np.float64), dtype=np.float64),
            )
        )
        lengths.append(
            np.asarray(part.sum(axis=1 - across_axis, dtype=np.float64), dtype=np.float64)
        )
    return cells, lengths


def _split_half_variance(
    spots: list[tuple[FloatArray, FloatArray]],
    across_axis: int,
    cfa_pattern: str,
    pitch: float,
    tilt: float,
    direct: FloatArray,
) -> FloatArray | None:
    """Per channel: the variance a narrow slit image's interleaving (``direct``) is given from the
    slit's two halves along its length, each interleaved alone (decision 0193).

    The halves' colours (each channel over G) differ by ``Δ``; their noise alone makes
    ``E[Δ²]`` about the sum, over the two halves, of the channel's and G's relative variances (a
    ratio's), and what exceeds it is the model's error, at different phases in the two halves. The
    whole's colour errs by about half of it (the mean of the two halves'): ``(Δ² − noise) / 4``,
    times the value squared. G, the reference, gets none.
    ``None`` where a half has no interleaving (too few cells, a fit that is not positive): then
    nothing checks the whole's."""
    lines = spots[0][0].shape[across_axis]
    halves = [
        _interleaved_direct(
            *_cells(spots, across_axis, part), cfa_pattern, pitch, tilt, across_axis
        )
        for part in (slice(None, lines // 2), slice(lines // 2, None))
    ]
    first_half, second_half = halves
    if first_half is None or second_half is None:
        return None
    (first, first_sigma), (second, second_sigma) = first_half, second_half
    colour_first, colour_second = first / first[1], second / second[1]
    difference = (colour_first - colour_second) / (direct / direct[1])
    relative_first, relative_second = (first_sigma / first) ** 2, (second_sigma / second) ** 2
    noise = relative_first + relative_first[1] + relative_second + relative_second[1]
    excess = np.clip(difference**2 - noise, 0.0, None) / 4.0
    excess[1] = 0.0
    return np.asarray(excess * direct**2, dtype=np.float64)


def _percent(direct: FloatArray, variance: FloatArray, channel: int) -> str:
    """A channel's σ as a percentage of its value, for a note."""
    value = abs(float(direct[channel]))
    if value <= 0:
        return "σ unknown"
    return f"σ {100.0 * math.sqrt(max(float(variance[channel]), 0.0)) / value:.1f} %"


def _plain_sum_aliasing(
    half_width: float, blur: float, pitch: float, lengths: list[FloatArray], tilt: float
) -> FloatArray:
    """Per channel: the RMS, relative to the value, of a plane's plain-sum aliasing error over the
    spot's unknown sub-pixel phase (decision 0148), for the slit image :func:`_resolved_direct`
    fitted (``half_width``, ``blur``) at the dispersion's ``tilt`` (:func:`_slit_tilt`);
    ``lengths``: each plane's sums across the slit per plane line along it.

    A plane sampling the spot every ``pitch`` pixels in both directions sums it to its integral ×
    (1 + 2 Σ Re[F(k)/F(0) e^{iφ_k}]) over the sampling's reciprocal lattice (Poisson summation in
    two dimensions); the first harmonics rule:

    - ``(1/pitch, 0)`` across the columns: :func:`_aliasing` of the fitted slit image (the fit is
      made to the column sums, the slit summed along its length).
    - ``(0, 1/pitch)`` along the slit: its ends, which fall between the plane lines at a phase of
      their own (not in the σ before). A length ``L`` (the equivalent length, sum over peak) of
      rectangle has there ``|sin(π L/pitch)|/(π L/pitch)``, times the blur's factor (the fitted
      blur: the same lens along the slit as across it).

    Each error is ``2|F| cos φ`` at its own unknown phase; over a uniform phase its RMS is
    ``√2 |F|`` (a cosine's RMS is 1/√2 of its amplitude), which is what goes into the σ: the
    bound ``2|F|`` counted as one σ states it √2× too wide, and the error never passes ±√2 σ. The
    ends' ``|sin(π L/pitch)|`` depends on where the length falls between whole pitches, which the
    equivalent length does not tell to a fraction of a pitch: over that unknown it has RMS 1/√2
    too, so their share is ``pitch/(π L)`` × the blur's factor. A Bayer G plane averages two
    diagonal sites, which cancels both harmonics (the diagonal ones, a product of both factors,
    are left): the one-site planes' share over-states it, harmlessly. R's and B's sites sit half a
    period apart, so their errors have opposite signs: a colour ratio of the two errs twice as
    much, which a σ per channel does not say (as before). Where the slit is tilted against the
    columns, the fitted blur also holds the tilt's smear across them, so the ends' share is
    under-stated there (decision 0148)."""
    cosine = 1.0 / math.hypot(1.0, tilt)
    across = _aliasing(half_width, blur, pitch)
    blur_factor = math.exp(-2.0 * math.pi**2 * blur**2 * cosine**2 / pitch**2)
    relative = np.full(len(lengths), math.sqrt(2.0) * across)  # no length measured: no ends
    for channel, profile in enumerate(lengths):
        total = float(profile.sum())
        peak = float(profile.max()) if profile.size else 0.0
        if total > 0 and peak > 0:
            length = pitch * total / peak
            ends = blur_factor * min(1.0, pitch / (math.pi * length * cosine))
            relative[channel] = math.hypot(math.sqrt(2.0) * across, ends)
    return relative


def _column_sums(
    u: FloatArray, inside: NDArray[np.bool_], values: FloatArray, variances: FloatArray, axis: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One channel's spot summed along the slit: per plane column (row when the dispersion runs
    closer to the sensor's y axis), its mean ``u``, its sum and the sum's variance."""
    count = inside.sum(axis=axis)
    used = count > 0
    mean_u = np.where(inside, u, 0.0).sum(axis=axis)[used] / count[used]
    total = np.where(inside, values, 0.0).sum(axis=axis)[used]
    total_variance = np.where(inside, variances, 0.0).sum(axis=axis)[used]
    return (
        np.asarray(mean_u, dtype=np.float64),
        np.asarray(total, dtype=np.float64),
        np.asarray(total_variance, dtype=np.float64),
    )


def _interleaved_direct(
    cells: list[tuple[FloatArray, FloatArray]],
    lengths: list[FloatArray],
    cfa_pattern: str,
    pitch: float,
    tilt: float = 0.0,
    axis: int = 0,
) -> tuple[FloatArray, FloatArray] | None:
    """Per channel: the spot's integral and its σ from the Bayer cells' interleaving, with no
    model of the spot's shape (decision 0119).

    ``cells`` holds, per channel (R, G, B), each plane column's sum along the slit (row where the
    dispersion runs nearer the sensor's y axis) on one common cell index, and its variance. In a
    2×2 Bayer cell R and B sit on the cell's two different sensor columns and the two greens on
    both, so for one slit image ``S`` (the same for every channel, only the level ``A_c`` differs)
    ``R_k = A_R S(2k)``, ``B_k = A_B S(2k + 1)`` (or the other way round) and ``G_k = A_G (S(2k) +
    S(2k + 1)) / 2``: ``G_k = a R_k + b B_k`` with ``a = A_G / (2 A_R)``, ``b = A_G / (2 A_B)``,
    whatever the spot's edge is (a lens' Gaussian, a defocus disc, the twin's raised cosine). With
    ``a`` and ``b`` fitted, every sensor column's share of the slit image is known in one level, so
    the integral over all columns is ``T_R = p (ΣR + (b/a) ΣB)``, ``T_B = p ((a/b) ΣR + ΣB)``,
    ``T_G = 2p (a ΣR + b ΣB)`` (``p`` the plane pitch; the slit's length is taken as sampled alike by
    the planes' rows). ``None`` when the pattern is not a 2×2 Bayer cell with two greens or fewer
    than three cells carry the spot; the σ comes from the fit's covariance and the sums' variances.

    The slit's ends alias the same way along its length: R's rows and B's rows hold the slit's
    length in the ratio ``r = G_o / G_e`` (odd to even sensor rows, ≠ 1 by up to a few per cent
    for a sharp end), which the column fit alone would read as colour (twice). ``lengths`` holds
    each plane's sums across the slit per plane row; in the slit's middle R's and B's rows see the
    same length profile, so ``r`` = (ΣB / ΣR) / (ΣB / ΣR over the middle rows), and with the columns'
    ratio ``f = F_o / F_e = (ΣB / ΣR)(b / a) r`` the integrals are ``T_R = ΣR (1 + f)(1 + r)``,
    ``T_B = ΣB (1 + 1/f)(1 + 1/r)``, ``T_G = 2 ΣG (1 + f)(1 + r) / (f + r)`` (for ``r`` = 1 these
    are the forms above).

    A slit tilted against the columns by ``tilt`` (:func:`_slit_tilt`; ``axis`` is the axis the
    cells were summed along, 1 when the dispersion runs nearer the sensor's y axis) adds a term the
    relation above does not hold; a bound on its effect is in the σ (:func:`_tilt_bias`, decision
    0134).
    """
    pattern = cfa_pattern.upper()
    if pitch != 2.0 or sorted(pattern) != ["B", "G", "G", "R"]:
        return None
    (red, red_var), (green, green_var), (blue, blue_var) = cells
    if not (red.size == green.size == blue.size):
        return None
    # Cells with every plane's samples in the spot's window (the window's corners may miss one).
    used = (red_var > 0) & (green_var > 0) & (blue_var > 0)
    red, green, blue = red[used], green[used], blue[used]
    red_var, green_var, blue_var = red_var[used], green_var[used], blue_var[used]
    if int(used.sum()) < 3:
        return None
    rows = _row_parity_ratio(lengths[0], lengths[2])
    if rows is None:
        return None
    noise = green_var + 0.25 * (red_var + blue_var)
    for _ in range(2):  # weights from every plane's noise at the current coefficients
        fitted = _interleaving_totals(red, green, blue, noise, rows)
        if fitted is None:
            return None
        totals, (a, b), chi_square = fitted
        noise = green_var + a**2 * red_var + b**2 * blue_var
    # First-order propagation through the weighted fit: each cell's value perturbed in turn.
    values = np.concatenate([red, green, blue])
    variances = np.concatenate([red_var, green_var, blue_var])
    steps = 1e-3 * np.sqrt(variances)
    n = red.size
    variance = np.zeros(3)
    for index in range(values.size):
        moved = values.copy()
        moved[index] += steps[index]
        shifted = _interleaving_totals(moved[:n], moved[n : 2 * n], moved[2 * n :], noise, rows)
        if shifted is None:
            return None
        variance += ((shifted[0] - totals) / steps[index]) ** 2 * variances[index]
    # Where one shape does not hold for the three channels (a lens' colour fringes, a slit end
    # sampled unlike by the planes' rows) the residuals show it: the variance follows them.
    if n > 2:
        variance = variance * max(1.0, chi_square / (n - 2))
    bias = _tilt_bias(red, green, blue, noise, rows, pattern, axis, tilt)
    if bias is None:
        return None
    return totals, np.sqrt(variance + bias**2)


def _row_parity_ratio(red_rows: FloatArray, blue_rows: FloatArray) -> float | None:
    """``r = G_o / G_e`` of :func:`_interleaved_direct`: the slit's length as B's rows hold it over
    R's, from the planes' sums across the slit per plane row (``None`` without a middle)."""
    middle = (red_rows > 0.5 * float(red_rows.max())) & (blue_rows > 0.5 * float(blue_rows.max()))
    if int(middle.sum()) < 3 or float(red_rows.sum()) <= 0 or float(blue_rows.sum()) <= 0:
        return None
    # Sums over the middle, not a median of row ratios: a slit tilted against the columns moves
    # across them along its length, and each row's column ratio with it.
    level = float(blue_rows[middle].sum() / red_rows[middle].sum())
    if not level > 0:
        return None
    return float(blue_rows.sum() / red_rows.sum()) / level


def _interleaving_totals(
    red: FloatArray, green: FloatArray, blue: FloatArray, noise: FloatArray, rows: float
) -> tuple[FloatArray, tuple[float, float], float] | None:
    """:func:`_interleaved_direct`'s totals for cells' sums, the G fit's noise variance and the
    row-parity ratio ``rows``: the totals, ``(a, b)`` and the fit's χ²; ``None`` where the fit is
    singular or not positive."""
    design = np.stack([red, blue], axis=1) / np.sqrt(noise)[:, None]
    target = green / np.sqrt(noise)
    normal = design.T @ design
    if np.linalg.cond(normal) > 1e12:
        return None
    a, b = (float(x) for x in np.linalg.solve(normal, design.T @ target))
    if not (a > 0 and b > 0):
        return None
    residual = target - design @ np.array([a, b])
    sum_red, sum_green, sum_blue = float(red.sum()), float(green.sum()), float(blue.sum())
    if not (sum_red > 0 and sum_blue > 0):
        return None
    columns = sum_blue / sum_red * (b / a) * rows
    extent = (1.0 + columns) * (1.0 + rows)
    totals = np.array(
        [
            sum_red * extent,
            2.0 * sum_green * extent / (columns + rows),
            sum_blue * (1.0 + 1.0 / columns) * (1.0 + 1.0 / rows),
        ]
    )
    return totals, (a, b), float(residual @ residual)


def _slit_tilt(angle_deg: float, across_axis: int) -> float:
    """How far across the summed plane columns (rows for ``across_axis`` 1) the slit's image moves
    per sensor line along it, in pixels: ``tan θ`` of the dispersion's angle to the sensor axis it
    runs nearest (the slit is perpendicular to the dispersion)."""
    angle = math.radians(angle_deg)
    if across_axis == 0:
        return math.tan(angle)
    return math.cos(angle) / math.sin(angle)


def _tilt_bias(
    red: FloatArray,
    green: FloatArray,
    blue: FloatArray,
    noise: FloatArray,
    rows: float,
    pattern: str,
    axis: int,
    tilt: float,
) -> FloatArray | None:
    """Per channel: a bound on the bias a tilted slit puts into :func:`_interleaved_direct`'s
    integrals (decision 0134).

    Each green shares its sensor column with R or B but sits on the cell's other sensor line, where
    a slit tilted against the columns lies ``tilt`` pixels further across them; so to first order
    ``G_k = a R_k + b B_k ± tilt (h'(x_R) − h'(x_B))``, ``h`` the columns' profile ``(a R, b B)``
    interleaved at the sites' columns (decision 0123: up to ±0.4 % in colour at 0.8° on a smooth
    spot, where R's and B's columns differ little and the fit reads that small term as colour). The
    term is not corrected: its derivative from 1 px samples errs by the term's own size on a sharp
    edge (decision 0123). Its effect on the integrals — the cells' greens moved by the term, through
    the same fit — is the bound; its sign does not matter, nor then which sensor line holds which
    green."""
    if tilt == 0.0:
        return np.zeros(3)
    fitted = _interleaving_totals(red, green, blue, noise, rows)
    if fitted is None:
        return None
    totals, (a, b), _ = fitted
    red_site = pattern.index("R") // 2 if axis else pattern.index("R") % 2
    blue_site = pattern.index("B") // 2 if axis else pattern.index("B") % 2
    n = red.size
    level = np.zeros(2 * n + 2)  # h on the sensor's columns, one empty column each side
    level[1 + red_site : 1 + 2 * n : 2] = a * red
    level[1 + blue_site : 1 + 2 * n : 2] = b * blue
    slope = 0.5 * (level[2:] - level[:-2])
    term = tilt * (slope[red_site::2] - slope[blue_site::2])
    moved = _interleaving_totals(red, green - term, blue, noise, rows)
    if moved is None:
        return None
    return np.asarray(np.abs(moved[0] - totals), dtype=np.float64)


def _site_offsets(image: HdrImage, angle_deg: float) -> tuple[float, float, float]:
    """Per channel: half the distance along ``u`` between the two sites a plane sample averages.

    A Bayer G plane sample is the mean of the cell's two greens, one pixel apart on a diagonal
    (``calib.image.raw``); R and B are one site each. For a sharp spot the mean of two sites is
    not the value at their middle."""
    pattern = image.cfa_pattern.upper()
    offsets = [0.0, 0.0, 0.0]
    if image.pixel_pitch_px != 2.0 or len(pattern) != 4:
        return (0.0, 0.0, 0.0)
    angle = math.radians(angle_deg)
    for channel, name in enumerate("RGB"):
        sites = [divmod(index, 2) for index, letter in enumerate(pattern) if letter == name]
        if len(sites) == 2:
            (row_a, column_a), (row_b, column_b) = sites
            along = (column_b - column_a) * math.cos(angle) + (row_b - row_a) * math.sin(angle)
            offsets[channel] = 0.5 * abs(along)
    return (offsets[0], offsets[1], offsets[2])


def _spot_shape(u: FloatArray, centre: float, half_width: float, blur: float) -> FloatArray:
    """A slit image across the dispersion: a unit-height rectangle of half-width ``half_width``
    convolved with a Gaussian of σ ``blur`` (its integral over ``u`` is ``2 · half_width``)."""
    from scipy.special import erf  # deferred like the other scipy imports of this package

    scale = blur * math.sqrt(2.0)
    return np.asarray(
        0.5 * (erf((u - centre + half_width) / scale) - erf((u - centre - half_width) / scale)),
        dtype=np.float64,
    )


def _resolved_direct(
    columns: list[tuple[FloatArray, FloatArray, FloatArray]],
    site_offsets: tuple[float, float, float],
    pitch: float,
    half_size: float,
) -> tuple[FloatArray | None, str | None, tuple[float, float] | None]:
    """Per channel: the spot's integral from one slit-image shape shared by the channels.

    Each colour plane samples the spot every ``pitch`` sensor pixels at its own offset, so the
    plane's sum × pitch² is the integral only when the spot is smooth at that pitch. A sharp slit
    image a few pixels wide falls on 2 columns of one channel and 3 of another at the same level
    (decision 0114). The slit's image along the dispersion is the same for every channel (one slit,
    one lens; the colours differ only in level), so one shape — a rectangle ⊗ Gaussian with shared
    centre, width and blur — is fitted to every channel's column sums (the slit's length summed),
    with its own amplitude per channel (a plane that averages two sites, Bayer G, sees the mean of
    the shape at both: ``site_offsets``); the channel's integral is its amplitude × the shape's
    integral × pitch (a column sum holds one sample per ``pitch`` along the slit).

    ``None`` (keep the plain sum) where the plain sum is already exact or the fit cannot be
    trusted: the fitted slit image's first harmonic at the plane pitch (:func:`_aliasing`, width
    and blur together) is smaller than :data:`ALIASING_LIMIT`; the fitted slit image narrower than
    one plane pitch (then no channel resolves its edges); the fit failed. The second item says why
    a sharp spot kept its plain sum (its colour may then be off), ``None`` otherwise; the third is
    the fitted slit image's half-width and blur where the plain sum is kept as exact or the slit
    image is narrower than the pitch (for the plain sums' aliasing σ,
    :func:`_plain_sum_aliasing`), else ``None``.
    """
    from scipy.optimize import least_squares  # deferred like the other scipy imports

    if pitch <= 1.0:
        return None, None, None
    u = np.concatenate([column[0] for column in columns])
    total = np.concatenate([column[1] for column in columns])
    sigma = np.sqrt(np.concatenate([column[2] for column in columns]))
    channel = np.concatenate([np.full(column[0].size, k) for k, column in enumerate(columns)])
    if u.size < 8 or not np.all(np.isfinite(total)) or not np.all(sigma > 0):
        return None, None, None
    weights = 1.0 / sigma

    def amplitudes(shape: FloatArray) -> FloatArray:
        result = np.zeros(3)
        for k in range(3):
            mine = channel == k
            a = shape[mine] * weights[mine]
            denominator = float(a @ a)
            if denominator > 0:
                result[k] = float(a @ (total[mine] * weights[mine])) / denominator
        return result

    offset = np.asarray(site_offsets, dtype=np.float64)[channel]

    def seen(centre: float, half_width: float, blur: float) -> FloatArray:
        """The shape as each plane sample sees it (the mean over its sites)."""
        return 0.5 * (
            _spot_shape(u - offset, centre, half_width, blur)
            + _spot_shape(u + offset, centre, half_width, blur)
        )

    def residuals(parameters: FloatArray) -> FloatArray:
        shape = seen(parameters[0], math.exp(parameters[1]), math.exp(parameters[2]))
        return np.asarray((amplitudes(shape)[channel] * shape - total) * weights, dtype=np.float64)

    level = np.clip(total, 0.0, None)
    if float(level.sum()) <= 0:
        return None, None, None
    mean_u = float((u * level).sum() / level.sum())
    spread = math.sqrt(max(float(((u - mean_u) ** 2 * level).sum() / level.sum()), 0.25))
    # A rectangle of half-width h has an RMS width h/√3; start at that with a third of a pitch blur.
    start = np.array([mean_u, math.log(math.sqrt(3.0) * spread), math.log(pitch / 3.0)])
    try:
        fit = least_squares(residuals, start, method="lm", x_scale=np.array([1.0, 0.3, 0.3]))
    except (ValueError, np.linalg.LinAlgError):
        return None, FIT_FAILED, None
    centre, half_width, blur = fit.x[0], math.exp(fit.x[1]), math.exp(fit.x[2])
    if not fit.success or not np.all(np.isfinite(fit.x)) or abs(centre) > half_size:
        return None, FIT_FAILED, None
    if 2.0 * half_width > 2.0 * half_size:
        return None, FIT_FAILED, None
    aliasing = _aliasing(half_width, blur, pitch)
    if aliasing < ALIASING_LIMIT:
        return None, None, (half_width, blur)
    if 2.0 * half_width < pitch:
        return (
            None,
            (
                f"the slit image is {2.0 * half_width:.1f} px wide and sharp (blur σ "
                f"{blur:.2f} px), narrower than the colour planes' {pitch:g} px pitch"
            ),
            (half_width, blur),
        )
    shape = seen(centre, half_width, blur)
    return np.asarray(amplitudes(shape) * 2.0 * half_width * pitch, dtype=np.float64), None, None


def _aliasing(half_width: float, blur: float, pitch: float) -> float:
    """The first harmonic of a slit image (:func:`_spot_shape`) at the plane pitch: its Fourier
    transform at ``1/pitch`` over its integral, ``|sinc(2π·half_width/pitch)| · exp(−2π²σ²/pitch²)``.

    A plane sampling a spot every ``pitch`` pixels sums it to its integral × (1 + 2 Σₖ its k-th
    harmonic × cos(its phase)) (Poisson summation); the first harmonic rules the error. It is
    small where the blur smooths the spot over the pitch and where the slit image spans a whole
    number of pitches (every offset then covers the same number of samples): what aliases is the
    spot's spectrum at the pitch, not its blur alone (decision 0140)."""
    x = 2.0 * math.pi * half_width / pitch
    return abs(math.sin(x) / x) * math.exp(-2.0 * math.pi**2 * blur**2 / pitch**2)


def _line_spread(
    along_px: FloatArray, weights: FloatArray, step_px: float, half_size_px: float
) -> FloatArray | None:
    """The spot's cross-section along the dispersion direction in profile samples (odd, sum 1).

    The 0th order is the slit's image through the same optics as the first order, so its
    cross-section is the camera's line spread at the profile's sampling. Samples below 1 % of the
    peak at the tails are cut; ``None`` if nothing is left.
    """
    half = max(1, math.ceil(half_size_px / step_px))
    edges = (np.arange(-half, half + 2, dtype=np.float64) - 0.5) * step_px
    histogram, _ = np.histogram(along_px, bins=edges, weights=weights)
    histogram = np.clip(histogram, 0.0, None)
    if float(histogram.max()) <= 0:
        return None
    significant = np.flatnonzero(histogram >= 0.01 * float(histogram.max()))
    reach = int(max(abs(significant[0] - half), abs(significant[-1] - half)))
    kernel = histogram[half - reach : half + reach + 1]
    return np.asarray(kernel / kernel.sum(), dtype=np.float64)


def extract(
    image: HdrImage,
    geometry: DiffractionGeometry,
    *,
    side: Side = 1,
    subtract_background: bool = True,
    allow_saturated_direct: bool = False,
    other_order: bool = False,
) -> Extraction:
    """Direct RGB and first-order profile of ``image`` in a fixed ``geometry``.

    Parameters
    ----------
    image
        Any lamp's merged bracket, taken in the set-up the geometry was detected in.
    geometry
        From :func:`detect_geometry` (typically on the brightest broadband lamp).
    side
        Which first order to extract: ``+1`` (the stronger) or ``-1``.
    subtract_background
        Subtract the per-channel median of strips beside the band / the spot.
    allow_saturated_direct
        Return ``direct_rgb = None`` instead of raising when the spot is saturated in every frame.
    other_order
        Also read the other first order, when the geometry holds it and ``side`` is ``+1``
        (:attr:`Extraction.other_order`; the observations the estimators get: decision 0197).

    Returns
    -------
    Extraction

    Raises
    ------
    DetectionError
        Image size differs from the geometry's; the band or spot is saturated in every frame; the
        band leaves the frame; the order is not in the geometry.
    """
    source = image_source(image)
    if image.sensor_shape_px != geometry.sensor_shape_px:
        raise DetectionError(
            f"image covers {image.sensor_shape_px} sensor pixels, the geometry was detected on "
            f"{geometry.sensor_shape_px}; use a geometry from the same camera set-up",
            reason="mismatch",
            source=source,
        )
    band = geometry.order(side)
    background = _band_background(image, geometry, band, subtract_background)
    pixel, profile, sigma, counts = _extract_profile(image, geometry, band, background, source)
    other, other_note = (
        _other_order(image, geometry, side, subtract_background, source)
        if other_order
        else (None, None)
    )
    direct, direct_sigma, direct_background, line_spread, direct_note = _extract_direct(
        image, geometry, allow_saturated_direct, source, subtract_background
    )
    return Extraction(
        side=side,
        pixel=pixel,
        profile=profile,
        profile_sigma=sigma,
        direct_rgb=direct,
        direct_sigma=direct_sigma,
        background_rgb=background,
        direct_background_rgb=direct_background,
        samples_per_pixel=counts,
        geometry=geometry,
        source=source,
        frames=tuple(str(record.path) for record in image.frames),
        line_spread=line_spread,
        direct_note=direct_note,
        other_order=other,
        other_order_note=other_note,
    )


def _band_background(
    image: HdrImage, geometry: DiffractionGeometry, band: OrderBand, subtract: bool
) -> FloatArray:
    """The per-channel background beside ``band`` (the strips past its gap), or zeros."""
    if not subtract:
        return np.zeros(3)
    inner = band.band_half_width_px + geometry.background_gap_px
    return _strip_background(
        image,
        geometry.spot_centre_px,
        band.angle_deg,
        (band.start_px, band.stop_px),
        (band.centre_offset_px - inner, band.centre_offset_px + inner),
        geometry.background_width_px,
    )


def _other_order(
    image: HdrImage,
    geometry: DiffractionGeometry,
    side: Side,
    subtract_background: bool,
    source: str,
) -> tuple[OrderProfile | None, str | None]:
    """The other first order's profile when ``geometry`` holds it (the +1 order read), as the +1
    one is read; ``None`` and why not when it is saturated or leaves the frame."""
    if side != 1 or not any(band.side == -1 for band in geometry.orders):
        return None, None
    band = geometry.order(-1)
    background = _band_background(image, geometry, band, subtract_background)
    try:
        pixel, profile, sigma, _ = _extract_profile(image, geometry, band, background, source)
    except DetectionError as exc:
        return None, f"the other first order is not read: {exc}"
    return OrderProfile(pixel, profile, sigma), None
