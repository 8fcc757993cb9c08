"""From RAW brackets to profiles: merge each lamp, find the geometry once, extract every lamp with it.

Merging a bracket costs several passes over every plane sample of every frame, but the profiles need
only the direct spot, the first-order band(s) and their background strips: a region of interest that is
often a tenth of the frame. So, for frames of :data:`REGION_MIN_SAMPLES` plane samples or more:

1. the first decoded frame of the first lamp (full planes) is block-averaged to detection's own
   working size (:data:`calib.image.blocks.DETECTION_MAX_SIZE` blocks across, :func:`coarse_image`)
   and the geometry detected on that coarse image
   (:func:`calib.image.profiles.detect_geometry`); the region is every rectangle the extraction will read
   (spot, bands, background strips) with generous margins, extended across the band so that
   background dominates it (detection estimates the background as a median);
2. every frame of every lamp is merged over that region only (:func:`calib.image.hdr.merge_bracket`
   ``region=``), and the geometry detected at full resolution on the merged region of the brightest
   broadband lamp; DNG frames are decoded only where they meet the region (the tiles of
   :mod:`calib.image.dng_tiles`; other formats are unpacked whole by LibRaw);
3. if anything of that fails (no coarse detection, the band reaches the region's edge), the lamp is
   merged over the whole frame instead: the region is an optimisation, never a source of error.

Geometries are kept in whole-sensor coordinates (:func:`shift_geometry` moves them in and out of a
region), so the pixel axes of all lamps agree exactly.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calib.core.errors import EstimationError, InputError
from calib.image.blocks import DETECTION_MAX_SIZE, block_any, block_factor, block_mean
from calib.image.hdr import DecodePlan, HdrImage, Unpacker, decode_order, merge_bracket
from calib.image.profiles import (
    DetectionError,
    DiffractionGeometry,
    Extraction,
    OrderBand,
    detect_geometry,
    extract,
)
from calib.image.profiles.detection import EXTENT_FRACTION
from calib.image.profiles.geometry import rectangle_corners
from calib.image.raw import PlaneRegion, RawDecoder, RawPlanes
from calib.image.sensor_noise import NoiseModel
from calib.pipeline.inputs import LampImages

#: ``frame_done(lamp_name, path)``: one frame of a lamp's bracket is merged.
FrameCallback = Callable[[str, Path], None]

#: Frames with at least this many plane samples per channel are merged over a region of interest.
REGION_MIN_SAMPLES = 2_000_000
#: A region larger than this fraction of the frame is not worth it: the whole frame is merged.
REGION_MAX_FRACTION = 0.6
#: At most this fraction of the region may be lit (spot and bands): detection takes the
#: background as the region's median.
MAX_LIT_FRACTION = 0.35
#: Kinds of lamp whose smooth spectra make good geometry (and band-brightness) references.
BROADBAND_KINDS = ("led", "halogen", "other")
#: Each end of a first order is extended by this fraction of its detected length (see
#: :func:`extend_orders`).
EXTENSION_FRACTION = 0.15


@dataclass(frozen=True, eq=False)
class MergedLamp:
    """One lamp's merged bracket (possibly over a region) and where it came from."""

    lamp: LampImages
    image: HdrImage


@dataclass(frozen=True, eq=False)
class LampExtraction:
    """A lamp's extraction and the image it came from."""

    merged: MergedLamp
    extraction: Extraction


@dataclass(frozen=True, eq=False)
class BracketProfiles:
    """What the RAW part of the pipeline hands on.

    Attributes
    ----------
    geometry
        The geometry in whole-sensor coordinates.
    geometry_lamp
        The lamp it was detected on.
    extractions
        Per lamp, in input order.
    region_origin_px, region_shape_px
        ``(row, column)`` and ``(height, width)`` in sensor pixels of the merged region, or
        ``None`` when whole frames were merged.
    notes
        What was decided along the way (for the result's warnings/notes).
    """

    geometry: DiffractionGeometry
    geometry_lamp: str
    extractions: tuple[LampExtraction, ...]
    region_origin_px: tuple[int, int] | None
    region_shape_px: tuple[int, int] | None
    notes: tuple[str, ...]

    def geometry_image(self) -> tuple[HdrImage, DiffractionGeometry]:
        """The geometry lamp's image and the geometry in that image's coordinates (for plots)."""
        for item in self.extractions:
            if item.merged.lamp.name == self.geometry_lamp:
                image = item.merged.image
                return image, shift_geometry(self.geometry, image)
        raise KeyError(self.geometry_lamp)


# ----------------------------------------------------------------------------------- geometry


def shift_geometry(geometry: DiffractionGeometry, image: HdrImage) -> DiffractionGeometry:
    """``geometry`` (whole-sensor coordinates) in the coordinates of ``image`` (maybe a region)."""
    row0, column0 = image.region_origin_px
    x, y = geometry.spot_centre_px
    return replace(
        geometry, sensor_shape_px=image.sensor_shape_px, spot_centre_px=(x - column0, y - row0)
    )


def to_sensor(geometry: DiffractionGeometry, image: HdrImage) -> DiffractionGeometry:
    """``geometry`` detected on ``image`` (maybe a region) in whole-sensor coordinates."""
    row0, column0 = image.region_origin_px
    x, y = geometry.spot_centre_px
    return replace(
        geometry,
        sensor_shape_px=image.full_sensor_shape_px or image.sensor_shape_px,
        spot_centre_px=(x + column0, y + row0),
    )


def _rectangles(
    geometry: DiffractionGeometry,
) -> list[tuple[float, tuple[float, float], tuple[float, float]]]:
    """``(angle, u_range, v_range)`` of everything extraction reads: spot, bands, strips."""
    gap, strip = geometry.background_gap_px, geometry.background_width_px
    along, across = geometry.spot_half_size_px
    rectangles = [
        (geometry.primary.angle_deg, (-along, along), (-across - gap - strip, across + gap + strip))
    ]
    for band in geometry.orders:
        reach = band.band_half_width_px + gap + strip
        offset = band.centre_offset_px
        rectangles.append(
            (band.angle_deg, (band.start_px, band.stop_px), (offset - reach, offset + reach))
        )
    return rectangles


def _fits(
    geometry: DiffractionGeometry,
    band: OrderBand,
    start: float,
    stop: float,
    shape: tuple[int, int],
) -> bool:
    """The band from ``start`` to ``stop`` (with its background strips) lies inside ``shape``."""
    reach = band.band_half_width_px + geometry.background_gap_px + geometry.background_width_px
    offset = band.centre_offset_px
    corners = rectangle_corners(
        geometry.spot_centre_px, band.angle_deg, (start, stop), (offset - reach, offset + reach)
    )
    height, width = shape
    return bool(
        corners[:, 0].min() >= 0
        and corners[:, 1].min() >= 0
        and corners[:, 0].max() <= width - 1
        and corners[:, 1].max() <= height - 1
    )


def extend_orders(
    geometry: DiffractionGeometry,
    shape_px: tuple[int, int],
    fraction: float = EXTENSION_FRACTION,
    dark_reach: Mapping[int, float] | None = None,
) -> tuple[DiffractionGeometry, list[str]]:
    """Extend each first order beyond its detected (lit) extent, where the image allows.

    Detection ends a band where its light falls below 1 % of the maximum, which for many lamps lies
    inside the working grid (no LED emits at 400 nm). A profile that stops there leaves the ends of
    the wavelength range unconstrained, and the mapping refinement drifts by nanometres; with dark
    pixels beyond the grid's ends in the profile it does not. Each end moves out by ``fraction`` of
    the band's length, but not into the direct spot, not so far that the band or its background
    strips leave ``shape_px``, and not into a 2nd order: when ``dark_reach`` gives, per side, how far
    the band stays dark beyond its lit end in every lamp's image (:func:`dark_reach`), up to there;
    without it, not beyond 1.9 × the band's start (where a 2nd order may begin).

    Returns
    -------
    (DiffractionGeometry, list of str)
        The extended geometry (same coordinates) and a note per extended order.
    """
    orders = []
    notes = []
    along, _ = geometry.spot_half_size_px
    floor = along + geometry.background_gap_px
    for band in geometry.orders:
        length = band.stop_px - band.start_px
        wanted_start = max(band.start_px - fraction * length, floor, 0.0)
        wanted_stop = band.stop_px + fraction * length
        if dark_reach is not None and band.side in dark_reach:
            wanted_stop = min(wanted_stop, max(dark_reach[band.side], band.stop_px))
        elif band.start_px > 0:
            wanted_stop = min(wanted_stop, max(1.9 * band.start_px, band.stop_px))
        start, stop = band.start_px, band.stop_px
        for _ in range(24):  # bisect towards the largest extension that fits
            if _fits(geometry, band, wanted_start, wanted_stop, shape_px):
                start, stop = wanted_start, wanted_stop
                break
            if not _fits(geometry, band, wanted_start, band.stop_px, shape_px):
                wanted_start = 0.5 * (wanted_start + band.start_px)
            if not _fits(geometry, band, band.start_px, wanted_stop, shape_px):
                wanted_stop = 0.5 * (wanted_stop + band.stop_px)
        if (start, stop) != (band.start_px, band.stop_px):
            notes.append(
                f"order {band.side:+d} extended from {band.start_px:.0f}–{band.stop_px:.0f} px to "
                f"{start:.0f}–{stop:.0f} px beyond its lit extent, so the profile covers the "
                "working grid's ends"
            )
        orders.append(replace(band, start_px=start, stop_px=stop))
    return replace(geometry, orders=tuple(orders)), notes


def dark_reach(
    geometry: DiffractionGeometry,
    shape_px: tuple[int, int],
    extract_all: Callable[[DiffractionGeometry], Sequence[Extraction]],
    fraction: float = EXTENSION_FRACTION,
) -> dict[int, float]:
    """Per side, how far beyond its lit end each first order stays dark in every lamp's image.

    The detected band ends where the geometry lamp's light falls below ``EXTENT_FRACTION`` of its
    maximum, which on a camera blind beyond ~690 nm lies inside the working grid; its pixels
    beyond are data (the camera's response is ~0 there), as long as no 2nd order has begun. Rather
    than guess where one may begin (1.9 × the band's start, which for a long band forbids any
    extension), look: the band is extracted out to ``fraction`` of its length beyond its stop (as
    far as ``shape_px`` allows) from every lamp's image (``extract_all``); in each lamp's profile,
    after its own first order has fallen below ``EXTENT_FRACTION`` of its maximum, the first
    sample that rises above that level again (a 2nd order, stray light) ends the dark run. The
    reach is the shortest dark run over the lamps; a lamp whose light never falls below the level
    inside the trial (its own first order runs on) does not limit it.
    """
    reach: dict[int, float] = {}
    for band in geometry.orders:
        length = band.stop_px - band.start_px
        trial_stop = band.stop_px + fraction * length
        for _ in range(24):
            if _fits(geometry, band, band.start_px, trial_stop, shape_px):
                break
            trial_stop = 0.5 * (trial_stop + band.stop_px)
        else:
            trial_stop = band.stop_px
        if trial_stop <= band.stop_px:
            continue
        orders = tuple(replace(b, stop_px=trial_stop) if b is band else b for b in geometry.orders)
        limit = trial_stop
        for extraction in extract_all(replace(geometry, orders=orders)):
            if extraction.side != band.side:
                continue
            total = np.nansum(extraction.profile, axis=1)
            pixel = extraction.pixel
            lit = pixel <= band.stop_px
            if not lit.any() or not np.nanmax(total[lit]) > 0:
                continue
            level = EXTENT_FRACTION * float(np.nanmax(total[lit]))
            beyond = np.flatnonzero(pixel > band.stop_px)
            dark = beyond[total[beyond] <= level]
            if dark.size == 0:
                continue
            risen = beyond[(beyond > dark[0]) & (total[beyond] > level)]
            if risen.size:
                limit = min(limit, max(float(pixel[risen[0] - 1]), band.stop_px))
        reach[band.side] = limit
    return reach


def region_for(
    geometry: DiffractionGeometry, plane_shape: tuple[int, int], *, coarse_pitch_px: float
) -> PlaneRegion | None:
    """A plane-sample region holding everything extraction reads, with margins; ``None`` if large.

    The margins cover the coarse geometry's error (a few coarse samples), the band's faint ends
    and :func:`extend_orders` (along), and make the region mostly background: detection estimates
    the background as a median, so the lit area (spot and bands) is kept below
    :data:`MAX_LIT_FRACTION` of the region by widening it across the bands where needed.
    """
    margin = max(4.0 * coarse_pitch_px, 48.0)
    rectangles = _rectangles(geometry)
    lit = 4.0 * float(np.prod(geometry.spot_half_size_px)) + sum(
        2.0 * band.band_half_width_px * (band.stop_px - band.start_px) for band in geometry.orders
    )

    def bounds(extra_across: float) -> tuple[slice, slice]:
        xs: list[float] = []
        ys: list[float] = []
        for angle, (u0, u1), (v0, v1) in rectangles:
            length = u1 - u0
            extra_along = margin + (
                (0.15 + EXTENSION_FRACTION) * length if length > 4 * margin else 0.0
            )
            corners = rectangle_corners(
                geometry.spot_centre_px,
                angle,
                (u0 - extra_along, u1 + extra_along),
                (v0 - extra_across, v1 + extra_across),
            )
            xs.extend(corners[:, 0])
            ys.extend(corners[:, 1])
        height, width = plane_shape
        rows = slice(max(math.floor(min(ys) / 2), 0), min(math.ceil(max(ys) / 2) + 1, height))
        columns = slice(max(math.floor(min(xs) / 2), 0), min(math.ceil(max(xs) / 2) + 1, width))
        return rows, columns

    def area_px(region: tuple[slice, slice]) -> float:
        rows, columns = region
        return 4.0 * float(max(rows.stop - rows.start, 0) * max(columns.stop - columns.start, 0))

    extra_across = margin
    region = bounds(extra_across)
    while lit > MAX_LIT_FRACTION * area_px(region) and extra_across < 8 * margin + 2000:
        extra_across *= 1.5
        widened = bounds(extra_across)
        if area_px(widened) <= area_px(region):  # the frame's edges stop it
            break
        region = widened
    height, width = plane_shape
    if area_px(region) <= 0 or area_px(region) > REGION_MAX_FRACTION * 4.0 * height * width:
        return None
    return region


def coarse_image(planes: RawPlanes) -> HdrImage:
    """A block-averaged rate image of one frame, at detection's working size (a first detection).

    Blocks of ``b × b`` plane samples (``b`` so that the image is at most
    :data:`calib.image.blocks.DETECTION_MAX_SIZE` across, so that detection uses it as it is) are
    averaged per channel and divided by the exposure time; a block with any saturated sample is
    flagged saturated. The variance is a rough shot + read estimate (detection does not use it).
    """
    factor = block_factor(planes.plane_shape, DETECTION_MAX_SIZE)
    exposure = planes.metadata.exposure_s
    radiance = block_mean(planes.signal_dn, factor) / exposure
    saturated = block_any(planes.saturated, factor)
    variance = (np.abs(radiance) * exposure + 10.0) / (factor * factor * exposure**2)
    origins = tuple(
        (float(factor - 1) + origin_row, float(factor - 1) + origin_column)
        for origin_row, origin_column in planes.channel_origin_px
    )
    return HdrImage(
        radiance=radiance.astype(np.float32),
        variance=variance.astype(np.float32),
        saturated=saturated,
        channel_origin_px=origins,
        pixel_pitch_px=2.0 * factor,
        cfa_pattern=planes.cfa_pattern,
        camera=planes.metadata.camera,
    )


@dataclass
class RegionChoice:
    """Chooses the region from a lamp's first decoded frame (a :data:`calib.image.hdr.RegionChooser`).

    Frames with fewer than ``min_samples`` plane samples are merged whole.
    """

    min_samples: int = REGION_MIN_SAMPLES
    region: PlaneRegion | None = None
    note: str = ""

    def __call__(self, planes: RawPlanes) -> PlaneRegion | None:
        if planes.plane_shape[0] * planes.plane_shape[1] < self.min_samples:
            return None
        coarse = coarse_image(planes)
        try:
            geometry = detect_geometry(coarse)
        except DetectionError as exc:
            self.note = (
                f"whole frames merged (no coarse detection on {planes.metadata.path.name}: {exc})"
            )
            return None
        self.region = region_for(geometry, planes.full_shape, coarse_pitch_px=coarse.pixel_pitch_px)
        if self.region is None:
            self.note = "whole frames merged (the region of interest would cover most of the frame)"
        return self.region


# ------------------------------------------------------------------------------------- merging


def merge_lamp(
    lamp: LampImages,
    region: PlaneRegion | RegionChoice | None,
    frame_done: FrameCallback | None = None,
    noise_model: NoiseModel | None = None,
    unpacker: Unpacker | None = None,
    plan: DecodePlan | None = None,
    decoder: RawDecoder = "auto",
) -> HdrImage:
    """Merge one lamp's bracket (darks subtracted), over ``region`` when given.

    ``noise_model``: the camera's gain and read noise when already known (else estimated from
    the bracket's green pairs). ``unpacker``: shared with the other lamps; ``plan``: the lamp's
    files read ahead (see :func:`calib.image.hdr.merge_bracket`).
    """

    def progress(done: int, total: int, path: Path) -> None:
        if frame_done is not None:
            frame_done(lamp.name, path)

    try:
        return merge_bracket(
            lamp.images,
            darks=lamp.darks,
            exposure_s=lamp.exposure_s,
            dark_exposure_s=lamp.dark_exposure_s if lamp.darks else None,
            progress=progress,
            region=region,
            noise_model=noise_model,
            unpacker=unpacker,
            plan=plan,
            decoder=decoder,
        )
    except EstimationError as exc:  # the frames hold too little signal to measure their noise
        raise InputError(
            f"{exc}; is the lamp on and the first order in the frames?",
            source=f"lamp {lamp.name!r}",
        ) from exc


def band_snr(extraction: Extraction) -> float:
    """Median over the band of the summed-channel profile's signal-to-noise ratio."""
    signal = extraction.profile.sum(axis=1)
    noise = np.sqrt(np.sum(extraction.profile_sigma**2, axis=1))
    ratio = signal / np.where(noise > 0, noise, np.inf)
    return float(np.median(ratio)) if ratio.size else 0.0


def _detect(image: HdrImage) -> DiffractionGeometry:
    return to_sensor(detect_geometry(image), image)


def _inside_region(geometry: DiffractionGeometry, image: HdrImage) -> bool:
    """Every rectangle extraction reads lies inside the merged region (when there is one)."""
    if image.full_sensor_shape_px in (None, image.sensor_shape_px):
        return True
    local = shift_geometry(geometry, image)
    height, width = image.sensor_shape_px
    for angle, u_range, v_range in _rectangles(local):
        corners = rectangle_corners(local.spot_centre_px, angle, u_range, v_range)
        if (
            corners[:, 0].min() < 0
            or corners[:, 1].min() < 0
            or corners[:, 0].max() > width - 1
            or corners[:, 1].max() > height - 1
        ):
            return False
    return True


def bracket_profiles(
    lamps: Sequence[LampImages],
    *,
    use_region: bool | None = None,
    frame_done: FrameCallback | None = None,
    stage: Callable[[str], None] | None = None,
    decoder: RawDecoder = "auto",
) -> BracketProfiles:
    """Merge every lamp's bracket, detect the geometry once, extract every lamp with it.

    Parameters
    ----------
    lamps
        The lamps seen in RAW files (at least one).
    use_region
        ``True``/``False`` forces merging over a region of interest or over whole frames;
        ``None`` decides by the frame size (:data:`REGION_MIN_SAMPLES`).
    frame_done
        Called after every merged frame with the lamp's name and the file.
    stage
        Called with a short description when a new stage starts.
    decoder
        Which decoder reads the pixels (:data:`calib.image.raw.RawDecoder`): by default DNGs go
        through the tile decoder, which decodes only the tiles that meet the region.

    Returns
    -------
    BracketProfiles

    Raises
    ------
    InputError
        Unreadable or inconsistent frames (the file is named), frames of different lamps from
        different cameras or sensor sizes, and :class:`DetectionError` when no spot or band is
        found or the band leaves the frame.
    """
    if not lamps:
        raise InputError("no lamps with images", source="lamps")
    notes: list[str] = []
    order = sorted(range(len(lamps)), key=lambda i: lamps[i].kind not in BROADBAND_KINDS)
    first = lamps[order[0]]
    chooser: RegionChoice | None = None
    if use_region is not False:
        chooser = RegionChoice(min_samples=0 if use_region else REGION_MIN_SAMPLES)
    merged: dict[str, MergedLamp] = {}

    def announce(text: str) -> None:
        if stage is not None:
            stage(text)

    # LibRaw unpacks the next lamp's first frames while one lamp's last frames merge and its
    # geometry is detected
    plans = _decode_plans([lamps[index] for index in order])
    with Unpacker([path for plan in plans for path in plan.paths], decoder=decoder) as unpacker:
        announce(f"merging {first.name}")
        image = merge_lamp(first, chooser, frame_done, unpacker=unpacker, plan=plans[0])
        region = chooser.region if chooser is not None else None
        if chooser is not None and chooser.note:
            notes.append(chooser.note)
        geometry: DiffractionGeometry | None = None
        announce(f"detecting the geometry on {first.name}")
        try:
            geometry = _detect(image)
            if region is not None and not _inside_region(geometry, image):
                raise DetectionError(
                    "the detected band reaches the edge of the region of interest",
                    reason="band_off_frame",
                )
        except DetectionError as exc:
            if region is None:
                raise
            notes.append(
                f"whole frames merged: detection in the region of interest failed ({exc}); "
                f"{first.name} merged again over the whole frame"
            )
            region = None
            announce(f"merging {first.name} again (whole frames)")
            image = merge_lamp(first, None, None, plan=plans[0], decoder=decoder)
            geometry = _detect(image)
        merged[first.name] = MergedLamp(first, image)
        for index, plan in zip(order[1:], plans[1:], strict=True):
            lamp = lamps[index]
            announce(f"merging {lamp.name}")
            merged[lamp.name] = MergedLamp(
                lamp,
                merge_lamp(lamp, region, frame_done, _shared_noise(image, plan), unpacker, plan),
            )
    _check_same_sensor(list(merged.values()))
    notes.extend(_decoder_notes(merged.values()))
    announce("extracting the profiles")
    geometry_lamp = first.name
    candidates = [m for m in merged.values() if m.lamp.kind in BROADBAND_KINDS]
    if len(candidates) > 1:
        snr = {
            m.lamp.name: band_snr(
                extract(m.image, shift_geometry(geometry, m.image), allow_saturated_direct=True)
            )
            for m in candidates
        }
        brightest = max(snr, key=lambda name: snr[name])
        if brightest != geometry_lamp:
            try:
                better = _detect(merged[brightest].image)
                if not _inside_region(better, merged[brightest].image):
                    raise DetectionError("band reaches the region's edge", reason="band_off_frame")
            except DetectionError as exc:
                notes.append(
                    f"geometry kept from {geometry_lamp}: detection on the brighter {brightest} "
                    f"failed ({exc})"
                )
            else:
                geometry, geometry_lamp = better, brightest
    reference = merged[geometry_lamp].image

    def extract_all(trial: DiffractionGeometry) -> list[Extraction]:
        in_sensor = to_sensor(trial, reference)
        return [
            extract(m.image, shift_geometry(in_sensor, m.image), allow_saturated_direct=True)
            for m in merged.values()
        ]

    local = shift_geometry(geometry, reference)
    extended, extension_notes = extend_orders(
        local,
        reference.sensor_shape_px,
        dark_reach=dark_reach(local, reference.sensor_shape_px, extract_all),
    )
    geometry = to_sensor(extended, reference)
    notes.extend(geometry.notes)  # what the detection decided (the other first order …)
    notes.extend(extension_notes)
    extractions = tuple(
        LampExtraction(
            merged[lamp.name],
            extract(
                merged[lamp.name].image,
                shift_geometry(geometry, merged[lamp.name].image),
                allow_saturated_direct=True,
                other_order=True,
            ),
        )
        for lamp in lamps
    )
    origin = shape = None
    if region is not None:
        origin = (2 * region[0].start, 2 * region[1].start)
        shape = (2 * (region[0].stop - region[0].start), 2 * (region[1].stop - region[1].start))
    return BracketProfiles(
        geometry=geometry,
        geometry_lamp=geometry_lamp,
        extractions=extractions,
        region_origin_px=origin,
        region_shape_px=shape,
        notes=tuple(notes),
    )


def _decoder_notes(merged: Iterable[MergedLamp]) -> list[str]:
    """A note per reason the tile decoder left DNG frames to LibRaw (one per reason, not per frame)."""
    reasons: dict[str, list[str]] = {}
    for item in merged:
        for record in item.image.frames:
            if record.decoding.startswith("LibRaw ("):
                reason = record.decoding.removeprefix("LibRaw (").removesuffix(")")
                reasons.setdefault(reason.removesuffix("; LibRaw decodes it"), []).append(
                    record.path.name
                )
    return [
        f"{len(names)} DNG frame(s) decoded whole by LibRaw, not the tile decoder "
        f"({', '.join(names[:3])}{', …' if len(names) > 3 else ''}): {reason}"
        for reason, names in reasons.items()
    ]


def _decode_plans(lamps: Sequence[LampImages]) -> list[DecodePlan]:
    """Every lamp's files (their metadata read once) in the order :func:`bracket_profiles` will
    decode them: the first lamp estimates the noise model, and every other lamp taken with the same
    camera at the same ISO shares it (:func:`_shared_noise`); the others estimate their own.
    """
    plans = [
        decode_order(
            lamp.images,
            darks=lamp.darks,
            exposure_s=lamp.exposure_s,
            dark_exposure_s=lamp.dark_exposure_s if lamp.darks else None,
        )
        for lamp in lamps
    ]
    return [
        plans[0],
        *(plan.replanned(estimate_noise=not _same_camera(plans[0], plan)) for plan in plans[1:]),
    ]


def _same_camera(reference: DecodePlan, plan: DecodePlan) -> bool:
    """Both brackets were taken by one known camera at one known ISO.

    Gain and read noise belong to the camera and its ISO, not to the scene: estimating them once
    saves a photon-transfer fit per lamp. (Dark frames still subtract per lamp.)
    """
    if not reference.frames or not plan.frames:
        return False
    first, other = reference.frames[0], plan.frames[0]
    same_camera = first.camera == other.camera != "unknown camera"
    same_iso = first.iso is not None and first.iso == other.iso
    return same_camera and same_iso


def _shared_noise(reference: HdrImage, plan: DecodePlan) -> NoiseModel | None:
    """The first lamp's noise model for a lamp planned to share it (:func:`_decode_plans`)."""
    if plan.estimate_noise or reference.noise_model is None:
        return None
    return NoiseModel(
        reference.noise_model.gain_dn_per_electron,
        reference.noise_model.read_noise_dn,
        source=f"{reference.noise_model.source} (camera and ISO shared with another lamp)",
    )


def _check_same_sensor(merged: Sequence[MergedLamp]) -> None:
    """All lamps must come from one camera and sensor size (their pixel axes must agree)."""
    reference = merged[0]
    shape = reference.image.full_sensor_shape_px or reference.image.sensor_shape_px
    for other in merged[1:]:
        other_shape = other.image.full_sensor_shape_px or other.image.sensor_shape_px
        first_file = other.lamp.images[0]
        if other_shape != shape:
            raise InputError(
                f"lamp {other.lamp.name!r} was taken on a {other_shape[1]}×{other_shape[0]} sensor "
                f"area, lamp {reference.lamp.name!r} on {shape[1]}×{shape[0]}; all lamps must be "
                "captured with the same camera and set-up",
                source=str(first_file),
            )
        if other.image.camera != reference.image.camera and "unknown camera" not in (
            other.image.camera,
            reference.image.camera,
        ):
            raise InputError(
                f"lamp {other.lamp.name!r} was taken with {other.image.camera}, lamp "
                f"{reference.lamp.name!r} with {reference.image.camera}; all lamps must be "
                "captured with the same camera",
                source=str(first_file),
            )
