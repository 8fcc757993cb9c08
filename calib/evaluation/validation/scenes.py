"""A validation scene: a physical grating and geometry, the lamps, and the rig's errors — drawn, then
rendered in 1-D.

:func:`draw_scene_plan` draws everything systematic about one scene from one generator — the
grating (:mod:`calib.model.gratings`), the geometry (the grating equation through a lens,
:class:`calib.core.mapping.TiltedGrating`), the sensor, the spectrometer, the stray light, and each
lamp's drift, exposure errors and bracket start — into a :class:`ScenePlan`, a plain record that
the 1-D renderer here and the twin's 2-D renderer (``bench/validate_twin.py``) share.
:func:`render_scene` then turns a plan and a camera into the observations an estimator receives,
drawing the noise from a second generator.

Geometry (:class:`GeometryRanges`): a transmission sheet of 300–1000 lines/mm in front of the lens
at an incidence of ±10°; the first order of wavelength ``λ`` leaves at ``θ'`` with
``sin θ' − sin θ = λ/d`` and lands ``F tan(θ' − θ)`` pixels from the direct spot. The user frames
the spectrum so that 400–700 nm spans 300–800 CFA-plane pixels (what decides ``F``: 10–27 % of a
3000-sample-wide plane, leaving room for the direct spot and the margins); with a CFA-plane pitch
of 6–12 µm (photosites of 3–6 µm) that is a 3–100 mm lens — phone to short telephoto. (Real
captures can be longer — the D7000 crop holds 2474 columns; the range also keeps a full run of
the protocol within ten minutes on two cores while the mapping search costs what it does.) The slit's image is 1.5–6 px wide and the lens adds a Gaussian blur of σ 0.4–1.2 px;
the profile runs from 5–30 nm below the grid to 5–40 nm above it, in pixels from the direct spot
(``pixel_origin="direct_spot"``, as :mod:`calib.image.profiles` measures them), and carries the
true line spread (the spot's cross-section, which the rig measures).

Rendering one lamp (all orders through :func:`calib.model.forward.render_observation`):

1. the lamp as the camera sees it: its true spectrum (:func:`true_lamp`: a tabulated fluorescent
   lamp's mercury lines restored at their wavelengths, ~1 nm wide, as the twin renders them)
   drifted (:class:`~.rig_errors.LampDrift`);
2. the first order through ``η₁``, plus the second order through ``η₂`` on the same pixels (the
   grating equation puts ``λ/2`` of the second order where the first has ``λ``), both blurred by
   the slit and the lens;
3. the direct signal through the 0th order's own ``η₀(λ)``;
4. stray light of the direct spot along the band (:class:`~.rig_errors.StrayLight`);
5. the bracket with shot and read noise and per-frame exposure errors
   (:class:`~.rig_errors.PhotonBudget`), the spot and the band rendered as the slit's image with
   the lens blur's soft edges and merged by the rig's HDR merge
   (:mod:`~.capture`), which also gives the stated σ;
6. the lamp's *reference* spectrum as the spectrometer reports the undrifted lamp
   (:class:`~.rig_errors.SpectrometerError`), with its bandwidth stated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.lamp_specs import lamp_from_spec
from calib.core.line_lists import is_builtin, with_narrow_lines
from calib.core.mapping import TiltedGrating
from calib.core.observations import LampKind, LampObservation
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid
from calib.evaluation.synthetic import lamp_kind
from calib.evaluation.validation.capture import SlitImage, capture_lamp
from calib.evaluation.validation.rig_errors import (
    RigErrors,
    SensorDraw,
    SpectrometerReading,
    StrayDraw,
    drifted,
)
from calib.model.forward import WavelengthMapping, blur_kernel, render_observation
from calib.model.gratings import (
    BlazedGrating,
    CatalogueGrating,
    GratingKind,
    SinusoidalPhaseGrating,
    draw_grating,
)

Grating = SinusoidalPhaseGrating | BlazedGrating | CatalogueGrating


@dataclass(frozen=True)
class GeometryRanges:
    """Ranges of the physical geometry a scene draws (module docstring)."""

    grooves_per_mm_range: tuple[float, float] = (300.0, 1000.0)
    incidence_deg_range: tuple[float, float] = (-10.0, 10.0)
    band_length_px_range: tuple[float, float] = (300.0, 800.0)
    pixel_pitch_um_range: tuple[float, float] = (6.0, 12.0)
    slit_width_px_range: tuple[float, float] = (1.5, 6.0)
    psf_sigma_px_range: tuple[float, float] = (0.4, 1.2)
    margin_below_nm_range: tuple[float, float] = (5.0, 30.0)
    margin_above_nm_range: tuple[float, float] = (5.0, 40.0)


@dataclass(frozen=True)
class SceneGeometry:
    """One scene's geometry: the true mapping and what it was built from.

    Attributes
    ----------
    mapping
        Pixels from the direct spot → wavelength (first order).
    grooves_per_mm, incidence_deg, pixel_pitch_um, focal_length_mm
        The parts: ``focal_length_mm`` is what frames the band as drawn.
    first_pixel, n_pixels
        The profile's pixels: ``first_pixel + 0 … n_pixels − 1``.
    slit_width_px, psf_sigma_px
        The slit's image width and the lens blur (σ), in profile pixels.
    """

    mapping: TiltedGrating
    grooves_per_mm: float
    incidence_deg: float
    pixel_pitch_um: float
    focal_length_mm: float
    first_pixel: int
    n_pixels: int
    slit_width_px: float
    psf_sigma_px: float

    @property
    def pixel(self) -> FloatArray:
        """The profile's pixel coordinates (distance from the direct spot), shape ``(n_pixels,)``."""
        return np.arange(self.first_pixel, self.first_pixel + self.n_pixels, dtype=np.float64)

    @property
    def line_spread(self) -> FloatArray:
        """The camera's line spread at the profile's sampling (odd length, sum 1)."""
        kernel = blur_kernel(self.slit_width_px, self.psf_sigma_px)
        return np.ones(1) if kernel is None else kernel

    def to_dict(self) -> dict[str, Any]:
        return {
            "grooves_per_mm": self.grooves_per_mm,
            "incidence_deg": self.incidence_deg,
            "pixel_pitch_um": self.pixel_pitch_um,
            "focal_length_mm": self.focal_length_mm,
            "first_pixel": self.first_pixel,
            "n_pixels": self.n_pixels,
            "slit_width_px": self.slit_width_px,
            "psf_sigma_px": self.psf_sigma_px,
            "mapping": self.mapping.to_dict(),
        }


def _pixel_of(wavelength_nm: float, spacing_nm: float, incidence_deg: float) -> float:
    """``tan(θ' − θ)`` of the first order of ``wavelength_nm`` (pixels per unit focal length)."""
    theta = math.radians(incidence_deg)
    return math.tan(math.asin(wavelength_nm / spacing_nm + math.sin(theta)) - theta)


def draw_geometry(
    rng: np.random.Generator, ranges: GeometryRanges, grid: WavelengthGrid = DEFAULT_GRID
) -> SceneGeometry:
    """A random physical geometry whose profile covers ``grid`` with margins (module docstring)."""
    grooves = float(math.exp(rng.uniform(*np.log(ranges.grooves_per_mm_range))))
    incidence = float(rng.uniform(*ranges.incidence_deg_range))
    band_px = float(rng.uniform(*ranges.band_length_px_range))
    pitch = float(rng.uniform(*ranges.pixel_pitch_um_range))
    spacing_nm = 1e6 / grooves
    span = _pixel_of(grid.stop_nm, spacing_nm, incidence) - _pixel_of(
        grid.start_nm, spacing_nm, incidence
    )
    focal_px = band_px / span
    mapping = TiltedGrating(spacing_nm / focal_px, focal_px, incidence)
    low_nm = grid.start_nm - float(rng.uniform(*ranges.margin_below_nm_range))
    high_nm = grid.stop_nm + float(rng.uniform(*ranges.margin_above_nm_range))
    first = math.ceil(focal_px * _pixel_of(low_nm, spacing_nm, incidence))
    last = math.floor(focal_px * _pixel_of(high_nm, spacing_nm, incidence))
    return SceneGeometry(
        mapping=mapping,
        grooves_per_mm=grooves,
        incidence_deg=incidence,
        pixel_pitch_um=pitch,
        focal_length_mm=focal_px * pitch * 1e-3,
        first_pixel=first,
        n_pixels=last - first + 1,
        slit_width_px=float(rng.uniform(*ranges.slit_width_px_range)),
        psf_sigma_px=float(rng.uniform(*ranges.psf_sigma_px_range)),
    )


#: How far a lens is racked out to focus, as a fraction of its nominal focal length: the image
#: distance a scene draws is ``F (1 + e)`` with ``e`` uniform in this range, while EXIF states ``F``.
FOCUS_EXTENSION_RANGE: tuple[float, float] = (0.0, 0.08)


def exif_optics(geometry: SceneGeometry, rng: np.random.Generator) -> dict[str, float]:
    """The optics a RAW capture of ``geometry`` records, as an observation's ``"optics"`` metadata.

    The lens reports its nominal focal length: the drawn image distance less a focus extension of
    :data:`FOCUS_EXTENSION_RANGE`, as EXIF states it — to 0.1 mm below 10 mm (phones and compacts
    write 4.2 or 4.25 mm), to the whole mm above (interchangeable lenses). The body reports its
    pixel pitch (EXIF focal-plane resolution). :func:`calib.wavelength.rig_prior.
    optics_from_observation` reads it as it reads what ``calib estimate`` takes from a RAW file.
    """
    extension = float(rng.uniform(*FOCUS_EXTENSION_RANGE))
    nominal_mm = geometry.focal_length_mm / (1.0 + extension)
    step_mm = 0.1 if nominal_mm < 10.0 else 1.0
    focal_mm = float(max(round(nominal_mm / step_mm) * step_mm, step_mm))
    return {"focal_length_mm": round(focal_mm, 1), "pixel_pitch_um": geometry.pixel_pitch_um}


def with_exif_optics(
    observations: Mapping[str, LampObservation], geometry: SceneGeometry, rng: np.random.Generator
) -> dict[str, LampObservation]:
    """``observations`` with the optics a RAW capture of ``geometry`` records
    (:func:`exif_optics`, one draw for all: one lens and body) in their metadata."""
    optics = exif_optics(geometry, rng)
    return {
        name: replace(obs, metadata={**dict(obs.metadata), "optics": optics})
        for name, obs in observations.items()
    }


@dataclass(frozen=True)
class LampDraw:
    """One lamp's realised errors: drift, the bracket's start and its frames' exposure errors."""

    drift_gain: float
    drift_tilt_per_100nm: float
    spot_fill: float
    exposure_errors: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "drift_gain": self.drift_gain,
            "drift_tilt_per_100nm": self.drift_tilt_per_100nm,
            "spot_fill": self.spot_fill,
            "exposure_errors": list(self.exposure_errors),
        }


@dataclass(frozen=True, eq=False)
class ScenePlan:
    """Everything systematic about one scene (module docstring); the noise is drawn at rendering."""

    grating: Grating
    geometry: SceneGeometry
    sensor: SensorDraw
    spectrometer: SpectrometerReading | None
    stray: StrayDraw | None
    lamps: Mapping[str, LampDraw]
    errors: RigErrors
    grid: WavelengthGrid = DEFAULT_GRID

    def to_dict(self) -> dict[str, Any]:
        return {
            "grating": self.grating.to_dict(),
            "geometry": self.geometry.to_dict(),
            "sensor": self.sensor.to_dict(),
            "spectrometer": None if self.spectrometer is None else self.spectrometer.to_dict(),
            "stray": None if self.stray is None else self.stray.to_dict(),
            "lamps": {name: draw.to_dict() for name, draw in self.lamps.items()},
        }


def draw_scene_plan(
    rng: np.random.Generator,
    lamps: Sequence[str],
    *,
    grating_kinds: Sequence[GratingKind] = ("sinusoidal",),
    catalogue: CatalogueGrating | None = None,
    errors: RigErrors | None = None,
    geometry: GeometryRanges | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> ScenePlan:
    """Draw one scene (module docstring). The draws come in a fixed order, so a plan depends only
    on the generator's seed and these arguments."""
    errors = RigErrors() if errors is None else errors
    if not grating_kinds:
        raise InputError("no grating kind to draw from", source="grating")
    kind = grating_kinds[int(rng.integers(len(grating_kinds)))]
    grating = draw_grating(kind, rng, catalogue=catalogue)
    shape = draw_geometry(rng, geometry or GeometryRanges(), grid)
    sensor = errors.photons.draw(rng)
    spectrometer = None if errors.spectrometer is None else errors.spectrometer.draw(rng)
    stray = None if errors.stray is None else errors.stray.draw(rng)
    draws: dict[str, LampDraw] = {}
    for name in lamps:
        gain, tilt = (0.0, 0.0) if errors.drift is None else errors.drift.draw(rng)
        fill = errors.photons.draw_spot_fill(rng)
        frames = errors.photons.max_frames
        exposure = (
            np.zeros(frames) if errors.exposure is None else errors.exposure.draw(rng, frames)
        )
        draws[name] = LampDraw(gain, tilt, fill, tuple(float(e) for e in exposure))
    return ScenePlan(grating, shape, sensor, spectrometer, stray, draws, errors, grid)


@dataclass(frozen=True)
class OrderMapping:
    """Order ``m`` of a grating on the first order's pixels: ``λ_m(p) = λ₁(p) / m``.

    Exact for the grating equation ``sin θ_m − sin θ = m λ / d``: the same angle, the same pixel.
    """

    first_order: WavelengthMapping
    order: int

    def wavelength_nm(self, pixel: ArrayLike) -> FloatArray:
        return np.asarray(self.first_order.wavelength_nm(pixel) / self.order, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class RenderedScene:
    """A scene seen by one camera: the observations by lamp name and the truth.

    Attributes
    ----------
    observations
        What the estimators receive, by lamp spec.
    truth
        Shape ``(f, 3)``: the camera on the grid, maximum 1.
    true_wavelength_nm
        Shape ``(n_pixels,)``: the wavelength at each profile pixel.
    clean
        By lamp: the noise-free profile ``(n, 3)`` and direct ``(3,)`` before the photon budget.
    """

    plan: ScenePlan
    observations: Mapping[str, LampObservation]
    truth: FloatArray
    true_wavelength_nm: FloatArray
    clean: Mapping[str, tuple[FloatArray, FloatArray]] = field(default_factory=dict)


def _efficiency(grating: Grating, order: int) -> Any:
    def efficiency(wavelength_nm: FloatArray) -> FloatArray:
        return grating.efficiency(order, wavelength_nm)

    return efficiency


def clean_signals(
    plan: ScenePlan, lamp: Spectrum, camera: MultiSpectrum, side: int = 1
) -> tuple[FloatArray, FloatArray]:
    """Noise-free profile ``(n, 3)`` (first + second order, blurred, with stray light) and direct
    ``(3,)`` of ``lamp`` (as the camera sees it) for ``camera`` in ``plan``.

    ``side=-1``: the other first order (−1, with −2 over it) on the profile's pixels measured
    away from the spot on the other side — the true grating's
    :meth:`~calib.core.mapping.TiltedGrating.other_order` and the grating's own efficiencies of
    those orders (a blazed grating's −1 order is weak and differently shaped; decision 0197)."""
    shape = plan.geometry
    mapping = shape.mapping if side == 1 else shape.mapping.other_order()
    common: dict[str, Any] = {
        "pixel": shape.pixel,
        "slit_width_px": shape.slit_width_px,
        "psf_sigma_px": shape.psf_sigma_px,
    }
    first = render_observation(
        lamp,
        camera,
        mapping=mapping,
        grating_efficiency=_efficiency(plan.grating, side),
        zeroth_order_efficiency=_efficiency(plan.grating, 0),
        **common,
    )
    second = render_observation(
        lamp,
        camera,
        mapping=OrderMapping(mapping, 2),
        grating_efficiency=_efficiency(plan.grating, 2 * side),
        **common,
    )
    profile = first.clean_profile + second.clean_profile
    direct = first.clean_direct
    if plan.stray is not None:
        profile = plan.stray.added(profile, direct, shape.pixel)
    return profile, direct


def render_other_order(
    scene: RenderedScene, camera: MultiSpectrum, spec: str, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """The −1 profile of lamp ``spec`` of ``scene`` (by ``camera``, the scene's) and its σ,
    ``(n, 3)`` each, captured in the bracket :func:`render_scene` captured its +1 order in (the
    same frames, gains and exposure errors: the bracket is laid out on the +1 order's clean
    signals, kept in ``scene.clean``), with noise from ``rng``."""
    plan = scene.plan
    draw = plan.lamps[spec]
    profile, direct = scene.clean[spec]
    seen = drifted(true_lamp(spec), draw.drift_gain, draw.drift_tilt_per_100nm)
    other, _ = clean_signals(plan, seen, camera, side=-1)
    shape = plan.geometry
    slit = SlitImage.of(shape.line_spread, plan.sensor.band_rows, shape.psf_sigma_px)
    gain, factors = plan.errors.photons.bracket(
        profile, direct, plan.sensor, slit.spot_px, draw.spot_fill
    )
    captured = capture_lamp(
        other,
        direct,
        slit,
        plan.errors.photons,
        plan.sensor,
        gain,
        factors,
        draw.exposure_errors,
        rng,
    )
    return captured.profile, captured.profile_sigma


def true_lamp(spec: str) -> Spectrum:
    """The lamp ``spec`` names as it really shines: a fluorescent lamp tabulated in 5 nm bins (the
    CIE FL tables colour-science holds) with its mercury lines restored as narrow lines at their
    true wavelengths (:func:`calib.core.line_lists.with_narrow_lines`), as the twin renders it;
    every other spec as :func:`calib.core.lamp_specs.lamp_from_spec` reads it."""
    spectrum = lamp_from_spec(spec)
    if lamp_kind(spec) != "fluorescent" or is_builtin(spec):
        return spectrum
    return with_narrow_lines(spectrum)


def render_scene(
    plan: ScenePlan,
    camera: MultiSpectrum,
    lamps: Sequence[str],
    rng: np.random.Generator,
    *,
    lamp_spectra: Mapping[str, Spectrum] | None = None,
) -> RenderedScene:
    """The observations of ``lamps`` (specs of :func:`calib.core.lamp_specs.lamp_from_spec`) by
    ``camera`` in ``plan``, with noise from ``rng`` (module docstring, steps 1–6).

    ``lamp_spectra`` may give the true spectra by spec (default: :func:`lamp_from_spec`).
    """
    errors = plan.errors
    shape = plan.geometry
    observations: dict[str, LampObservation] = {}
    clean: dict[str, tuple[FloatArray, FloatArray]] = {}
    for spec in lamps:
        if spec not in plan.lamps:
            raise InputError(f"lamp {spec!r} was not drawn in this scene's plan", source="lamps")
        draw = plan.lamps[spec]
        reference = (lamp_spectra or {}).get(spec) or true_lamp(spec)
        seen = drifted(reference, draw.drift_gain, draw.drift_tilt_per_100nm)
        profile, direct = clean_signals(plan, seen, camera)
        clean[spec] = (profile, direct)
        slit = SlitImage.of(shape.line_spread, plan.sensor.band_rows, shape.psf_sigma_px)
        gain, factors = errors.photons.bracket(
            profile, direct, plan.sensor, slit.spot_px, draw.spot_fill
        )
        captured = capture_lamp(
            profile,
            direct,
            slit,
            errors.photons,
            plan.sensor,
            gain,
            factors,
            draw.exposure_errors,
            rng,
        )
        if plan.spectrometer is not None and errors.spectrometer is not None:
            measured = errors.spectrometer.measure(reference, plan.spectrometer, rng)
            bandwidth: float | None = plan.spectrometer.bandwidth_nm
        else:
            measured, bandwidth = reference, None
        kind: LampKind = lamp_kind(spec)
        observations[spec] = LampObservation(
            name=spec,
            spectrum=measured,
            pixel=shape.pixel,
            profile=captured.profile,
            direct_rgb=captured.direct,
            profile_sigma=captured.profile_sigma,
            direct_sigma=captured.direct_sigma,
            kind=kind,
            metadata={
                "rendered": "validation scene",
                "frames": len(captured.factors),
                "frame_gains": list(captured.frame_gains),
            },
            spectrum_bandwidth_nm=bandwidth,
            line_spread=shape.line_spread,
            pixel_origin="direct_spot",
        )
    truth = camera.resample(plan.grid, "interpolate", out_of_range="zero").values
    peak = float(truth.max())
    if peak <= 0:
        raise InputError("the camera is zero on the grid", source=camera.name)
    return RenderedScene(
        plan,
        observations,
        truth / peak,
        np.asarray(shape.mapping.wavelength_nm(shape.pixel), dtype=np.float64),
        clean,
    )
