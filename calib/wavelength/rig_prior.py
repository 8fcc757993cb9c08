"""What the rig says about the mapping before any profile is fitted: the grating's line density, the
lens' focal length over the sensor's pixel pitch, the angle of incidence, the 0th order's place.

A capture from :mod:`calib.image.profiles` measures pixels from the direct spot (decision 0007), and its
RAW files carry the lens' focal length and, on many bodies, the focal plane's resolution (EXIF
``FocalLength``, ``FocalPlaneXResolution``/``ResolutionUnit``: :mod:`calib.image.raw_metadata`;
:data:`SENSOR_PITCH_UM` for bodies that do not write it). The grating's line density is a rig value
(configuration, or a grating file measured earlier). Together they give the grating equation through
the lens (:class:`calib.core.mapping.TiltedGrating`) up to the incidence and the focus: a Gaussian
prior (:class:`calib.wavelength.families.GratingPrior`) the search starts from and stays near.

A grating file measured in the same rig (:class:`RigGeometry`, stored in the file's
``geometry.rig``) gives more: the fitted groove spacing always (the sheet is the same), and — when
the camera body and the lens' focal length are the same and the new capture's spot and band sit
where the file's did — the whole geometry, so one LED shot only refines it.

Constants are physics, not tuning: a lens focused on a slit ``z`` away images it at
``v = f·z/(z − f)``, 0–8 % beyond ``f`` for ``z ≥ 13 f`` (:data:`FOCUS_EXTENSION`); EXIF focal lengths
are rounded to 1 mm; film gratings hold their nominal density to ~2 %.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from calib.core.errors import InputError
from calib.core.mapping import TiltedGrating
from calib.core.observations import LampObservation
from calib.wavelength.families import GratingPrior

#: Relative σ of a sheet's nominal line density (film and holographic gratings).
NOMINAL_GROOVES_SIGMA = 0.02
#: Relative σ of the groove spacing fitted in an earlier calibration of the same sheet.
FITTED_GROOVES_SIGMA = 0.005
#: The focal length in the profile's pixels is EXIF's over the pitch times (1 + extension): mean
#: and σ of the extension (focus on a slit 13 f or more away; EXIF's 1 mm rounding).
FOCUS_EXTENSION = (0.03, 0.05)
#: Incidence on the grating when nothing is known: rigs align the sheet roughly square to the lens.
INCIDENCE_PRIOR_DEG = (0.0, 5.0)
#: A reused geometry's σ of the incidence (degrees) and the focal length (relative): what remounting
#: the same parts moves.
REUSED_INCIDENCE_SIGMA_DEG = 1.0
REUSED_FOCAL_SIGMA = 0.01
#: The same, when another body sits behind the same lens and grating (the focal length in pixels
#: scaled by the pitches): the body's flange and focus move the image distance by a percent or
#: two, remounting it tilts the assembly by a degree or two.
LENS_REUSED_FOCAL_SIGMA = 0.02
LENS_REUSED_INCIDENCE_DEG = 2.0
#: σ of the 0th order's distance from the lens axis, in focal lengths, when the capture records the
#: spot's place on the sensor (the axis meets the sensor near its centre, give or take a crop).
AXIS_OFFSET_SIGMA = 0.15
#: A new capture's order must point within this angle (degrees) and its band sit within this
#: fraction of the stored distance from the spot for the stored geometry to be reused whole.
VERIFY_ANGLE_DEG = 1.0
VERIFY_DISTANCE = 0.03

#: Photosite pitch (µm) of bodies whose RAW files do not state their focal plane resolution:
#: sensor width over active columns, from the makers' specifications.
SENSOR_PITCH_UM: dict[str, float] = {
    "NIKON D7000": 23.6e3 / 4928,
    "NIKON D5100": 23.6e3 / 4928,
    "NIKON D90": 23.6e3 / 4288,
    "NIKON D300S": 23.6e3 / 4288,
    "NIKON D700": 36.0e3 / 4256,
    "NIKON D3": 36.0e3 / 4256,
    "NIKON D800": 35.9e3 / 7360,
    "NIKON D750": 35.9e3 / 6016,
    "CANON EOS 600D": 22.3e3 / 5184,
    "CANON EOS 5D MARK II": 36.0e3 / 5616,
    "CANON EOS 10D": 22.7e3 / 3072,
    "SONY ILCE-7M2": 35.8e3 / 6000,
}


@dataclass(frozen=True)
class RigOptics:
    """The optics one capture reports.

    Attributes
    ----------
    camera
        ``"Make Model"`` (upper case), or ``None``.
    focal_length_mm
        EXIF FocalLength, or ``None``.
    pixel_pitch_um
        Photosite pitch (EXIF focal plane resolution, else :data:`SENSOR_PITCH_UM`), or ``None``.
    pitch_source
        Where the pitch came from.
    axis_offset_px
        The 0th order's distance from the sensor centre along the order (``u₀``).
    order_angle_deg, band_distance_px
        The order's direction on the sensor and the middle of its band's extent from the spot
        (what a stored geometry is verified against), or ``None``.
    side
        Which first order the profile is (+1, −1).
    grooves_per_mm
        The sheet's nominal line density as the rig's configuration states it (``optics`` key
        ``grooves_per_mm`` of the observation's metadata), or ``None``.
    """

    camera: str | None = None
    focal_length_mm: float | None = None
    pixel_pitch_um: float | None = None
    pitch_source: str = "unknown"
    axis_offset_px: float = 0.0
    order_angle_deg: float | None = None
    band_distance_px: float | None = None
    side: int = 1
    grooves_per_mm: float | None = None

    @property
    def spot_placed(self) -> bool:
        """Whether the capture records where the spot lies on the sensor (its geometry), which
        places the lens axis relative to it (:attr:`axis_offset_px`)."""
        return self.order_angle_deg is not None

    @property
    def focal_length_px(self) -> float | None:
        """EXIF's focal length over the pitch, or ``None``."""
        if self.focal_length_mm is None or self.pixel_pitch_um is None:
            return None
        return self.focal_length_mm / (self.pixel_pitch_um * 1e-3)

    def to_dict(self) -> dict[str, Any]:
        return {
            "camera": self.camera,
            "focal_length_mm": self.focal_length_mm,
            "pixel_pitch_um": self.pixel_pitch_um,
            "pitch_source": self.pitch_source,
            "axis_offset_px": self.axis_offset_px,
            "order_angle_deg": self.order_angle_deg,
            "band_distance_px": self.band_distance_px,
            "side": self.side,
            "grooves_per_mm": self.grooves_per_mm,
        }


def optics_from_observation(observation: LampObservation) -> RigOptics:
    """The optics in an observation's metadata: ``"optics"`` (the RAW files' EXIF, written by the
    offline pipeline) and ``"geometry"`` (:class:`calib.image.profiles.DiffractionGeometry`)."""
    metadata = observation.metadata
    optics = metadata.get("optics")
    optics = optics if isinstance(optics, Mapping) else {}
    camera = _text(optics.get("camera"))
    focal = _positive(optics.get("focal_length_mm"))
    pitch = _positive(optics.get("pixel_pitch_um"))
    stated = _text(optics.get("pitch_source"))
    source = stated or ("EXIF focal plane resolution" if pitch is not None else "unknown")
    if pitch is None and camera is not None and camera.upper() in SENSOR_PITCH_UM:
        pitch, source = SENSOR_PITCH_UM[camera.upper()], "sensor table"
    side = -1 if metadata.get("side") == -1 else 1
    geometry = metadata.get("geometry")
    offset, angle, distance = 0.0, None, None
    if isinstance(geometry, Mapping):
        offset, angle, distance = _spot_geometry(geometry, side)
    return RigOptics(
        camera=camera.upper() if camera else None,
        focal_length_mm=focal,
        pixel_pitch_um=pitch,
        pitch_source=source,
        axis_offset_px=offset,
        order_angle_deg=angle,
        band_distance_px=distance,
        side=side,
        grooves_per_mm=_positive(optics.get("grooves_per_mm")),
    )


def _spot_geometry(
    geometry: Mapping[str, Any], side: int
) -> tuple[float, float | None, float | None]:
    """``u₀``, the order's angle and its band's middle distance from a geometry record."""
    try:
        height, width = (float(v) for v in geometry["sensor_shape_px"])
        spot_x, spot_y = (float(v) for v in geometry["spot_centre_px"])
        orders = geometry["orders"]
        order = next(o for o in orders if int(o["side"]) == side)
        angle = float(order["angle_deg"])
        distance = 0.5 * (float(order["start_px"]) + float(order["stop_px"]))
    except (KeyError, TypeError, ValueError, StopIteration):
        return 0.0, None, None
    direction = (math.cos(math.radians(angle)), math.sin(math.radians(angle)))
    # The principal point is taken at the sensor's centre (lenses centre it to a few % of F).
    offset = (spot_x - 0.5 * width) * direction[0] + (spot_y - 0.5 * height) * direction[1]
    return float(offset), angle, distance


def _positive(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) and number > 0 else None


def _text(value: Any) -> str | None:
    return value.strip() if isinstance(value, str) and value.strip() else None


@dataclass(frozen=True)
class RigGeometry:
    """A rig's geometry as fitted in one calibration, stored in a grating file (``geometry.rig``).

    Attributes
    ----------
    grating
        The fitted grating through the lens (its groove spacing, focal length in pixels, incidence,
        the 0th order's offset from the axis).
    optics
        The capture's optics (camera, lens, pitch, the spot and band it was verified against).
    grooves_per_mm
        The sheet's nominal line density when the rig's configuration gave one, else ``None``.
    """

    grating: TiltedGrating
    optics: RigOptics
    grooves_per_mm: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "grating": self.grating.to_dict(),
            "optics": self.optics.to_dict(),
            "grooves_per_mm": self.grooves_per_mm,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RigGeometry:
        try:
            optics = data.get("optics") or {}
            return cls(
                grating=TiltedGrating.from_dict(data["grating"]),
                optics=RigOptics(
                    camera=_text(optics.get("camera")),
                    focal_length_mm=_positive(optics.get("focal_length_mm")),
                    pixel_pitch_um=_positive(optics.get("pixel_pitch_um")),
                    pitch_source=str(optics.get("pitch_source", "unknown")),
                    axis_offset_px=float(optics.get("axis_offset_px", 0.0)),
                    order_angle_deg=_finite(optics.get("order_angle_deg")),
                    band_distance_px=_positive(optics.get("band_distance_px")),
                    side=int(optics.get("side", 1)),
                    grooves_per_mm=_positive(optics.get("grooves_per_mm")),
                ),
                grooves_per_mm=_positive(data.get("grooves_per_mm")),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"not a rig geometry record ({exc})", source="geometry.rig") from None


def _finite(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def same_lens(stored: RigOptics, new: RigOptics) -> float | None:
    """The ratio of the stored pitch to the new one when both captures state the same focal length
    (within EXIF's rounding) and both pitches, else ``None``: the same lens and grating, perhaps
    another body."""
    if (
        stored.focal_length_mm is None
        or new.focal_length_mm is None
        or stored.pixel_pitch_um is None
        or new.pixel_pitch_um is None
        or abs(stored.focal_length_mm - new.focal_length_mm) > 0.5
    ):
        return None
    return stored.pixel_pitch_um / new.pixel_pitch_um


def same_setup(stored: RigOptics, new: RigOptics) -> tuple[bool, str]:
    """Whether a new capture is in the stored geometry: same body, same focal length, and its spot
    and band where the stored ones were (:data:`VERIFY_ANGLE_DEG`, :data:`VERIFY_DISTANCE`)."""
    if stored.camera is None or new.camera is None or stored.camera != new.camera:
        return False, f"another camera ({new.camera or 'unknown'}, stored {stored.camera})"
    if (
        stored.focal_length_mm is None
        or new.focal_length_mm is None
        or abs(stored.focal_length_mm - new.focal_length_mm) > 0.5
    ):
        return False, (
            f"another focal length ({new.focal_length_mm} mm, stored {stored.focal_length_mm} mm)"
        )
    if stored.order_angle_deg is None or new.order_angle_deg is None:
        return False, "no spot/band geometry to verify against"
    turn = abs((new.order_angle_deg - stored.order_angle_deg + 180.0) % 360.0 - 180.0)
    if turn > VERIFY_ANGLE_DEG:
        return False, f"the order turned by {turn:.1f}° (camera or grating remounted)"
    if stored.band_distance_px is not None and new.band_distance_px is not None:
        moved = abs(new.band_distance_px / stored.band_distance_px - 1.0)
        if moved > VERIFY_DISTANCE:
            return False, f"the band moved {100 * moved:.0f} % along the order"
    return True, "same camera, lens and geometry"


def rig_prior(
    optics: RigOptics,
    *,
    grooves_per_mm: float | None = None,
    stored: RigGeometry | None = None,
    from_spot: bool = True,
) -> tuple[GratingPrior | None, str]:
    """The grating prior one capture supports, and a sentence saying what it rests on.

    ``grooves_per_mm``: the sheet's nominal density (configuration); ``stored``: the geometry of a
    grating file of the same rig; ``from_spot``: the profile's pixels are measured from the 0th
    order (else its position is free). ``None`` when nothing about the grating is known (the
    search then uses the family's defaults).
    """
    if grooves_per_mm is None:
        grooves_per_mm = optics.grooves_per_mm
    spacing: tuple[float, float] | None = None
    focal: tuple[float, float] | None = None
    incidence = INCIDENCE_PRIOR_DEG
    # The 0th order's distance from the lens axis a reused geometry carries: (mean, σ) in pixels.
    axis: tuple[float, float] | None = None
    reason = []
    if stored is not None:
        spacing = (math.log(stored.grating.groove_spacing_nm), FITTED_GROOVES_SIGMA)
        reason.append("groove spacing from the grating file")
        whole, why = same_setup(stored.optics, optics)
        lens = same_lens(stored.optics, optics)
        # The other first order is the same grating with θ → −θ and u₀ → −u₀.
        flip = optics.side * stored.optics.side
        if whole or lens is not None:
            # The stored incidence and axis offset are reused together: a fit pins the mapping,
            # not each of them (θ and u₀ both bend the order; one calibration's pair, 23° and
            # −929 px where the truth was −9° and 0, gave a 0.1 nm mapping), so the incidence
            # with another u₀ is another mapping. u₀ scales with the pitch like F (the spot
            # keeps its angle from the lens axis) and moves as the incidence's σ tilts it.
            scale = 1.0 if whole else float(lens or 1.0)
            tilt_deg = REUSED_INCIDENCE_SIGMA_DEG if whole else LENS_REUSED_INCIDENCE_DEG
            focal_px = stored.grating.focal_length_px * scale
            axis = (
                stored.grating.axis_offset_px * scale * flip,
                focal_px * math.tan(math.radians(tilt_deg)),
            )
        if whole:
            focal = (math.log(stored.grating.focal_length_px), REUSED_FOCAL_SIGMA)
            incidence = (stored.grating.incidence_deg * flip, REUSED_INCIDENCE_SIGMA_DEG)
            reason.append("focal length and incidence from the grating file (" + why + ")")
        elif lens is not None:
            # Another body behind the same lens and grating: the angles hold, the focal length
            # in pixels scales with the pitch.
            focal = (math.log(stored.grating.focal_length_px * lens), LENS_REUSED_FOCAL_SIGMA)
            incidence = (stored.grating.incidence_deg * flip, LENS_REUSED_INCIDENCE_DEG)
            reason.append(
                "focal length (scaled by the pitch) and incidence from the grating file (the same "
                f"lens; {why})"
            )
        else:
            reason.append("geometry refitted: " + why)
    elif grooves_per_mm is not None:
        spacing = (math.log(1e6 / grooves_per_mm), NOMINAL_GROOVES_SIGMA)
        reason.append(f"{grooves_per_mm:g} lines/mm (nominal)")
    if focal is None and optics.focal_length_px is not None:
        mean, sigma = FOCUS_EXTENSION
        focal = (math.log(optics.focal_length_px * (1.0 + mean)), sigma)
        reason.append(
            f"focal length {optics.focal_length_mm:g} mm over a {optics.pixel_pitch_um:.2f} µm "
            f"pitch ({optics.pitch_source})"
        )
    if spacing is None and focal is None and not from_spot:
        return None, "nothing known about the grating"
    values: dict[str, tuple[float, float]] = {"incidence_deg": incidence}
    offset = 0.0
    if from_spot:
        values["zero_order_px"] = (0.0, 0.0)
        if focal is not None:
            # With the focal length known the curvature cannot hide where the lens axis is:
            # u₀ is fitted, pulled to the spot's distance from the sensor's centre (where the
            # axis meets it, give or take a crop or a shifted lens) with a σ of
            # AXIS_OFFSET_SIGMA focal lengths — when the capture says where the spot is.
            # Otherwise (no focal length, or no record of the spot's place on the sensor)
            # u₀ = 0, the 0th order on the axis: nothing measures u₀, and a profile cannot — the
            # spacing, focal length and incidence refit a u₀ of 0.1 F to < 0.1 nm over
            # 380–780 nm (moving F by ~18 % and θ by ~19°). Fitted from a guess, u₀ gives a few
            # lines the freedom the focal length's and incidence's priors deny, and their
            # small errors bend the mapping beyond them (decision 0066).
            if axis is not None:
                offset = axis[0]
                values["axis_offset_px"] = axis
            elif optics.spot_placed:
                offset = optics.axis_offset_px
                values["axis_offset_px"] = (offset, AXIS_OFFSET_SIGMA * math.exp(focal[0]))
    if spacing is not None:
        values["log_spacing"] = spacing
    if focal is not None:
        values["log_focal"] = focal
    source = "; ".join(reason) or "0th order at the spot"
    return GratingPrior(values, source, offset), source


def rig_geometry(
    mapping_details: Mapping[str, Any],
    observation: LampObservation,
    *,
    grooves_per_mm: float | None = None,
) -> RigGeometry | None:
    """The geometry to store with a calibration, when its mapping was fitted as a grating from the
    0th order (``details["grating"]``), else ``None``."""
    record = mapping_details.get("grating")
    if not isinstance(record, Mapping) or observation.pixel_origin != "direct_spot":
        return None
    grating = TiltedGrating.from_dict(record)
    optics = optics_from_observation(observation)
    return RigGeometry(
        grating, optics, grooves_per_mm if grooves_per_mm is not None else optics.grooves_per_mm
    )


def default_prior(from_spot: bool) -> GratingPrior:
    """The family's prior when the rig says nothing: incidence 0 ± 5°, the 0th order at the spot
    (taken on the lens axis: the incidence and focal length absorb the difference)."""
    values: dict[str, tuple[float, float]] = {"incidence_deg": INCIDENCE_PRIOR_DEG}
    if from_spot:
        values["zero_order_px"] = (0.0, 0.0)
    return GratingPrior(values, "defaults")
