"""The twin's optics: slit, grating, lens and camera sensitivity, from a lamp spectrum to the sensor.

Image formation follows ``calib.model.forward`` (Makabe et al. 2025, Eq. 2–3): the first order spreads
the light so that wavelength ``λ`` lands at ``u = f_px tan(asin(λ/d))`` sensor pixels from the direct
spot (:class:`calib.core.mapping.GratingGeometry`); a pixel collects the integral of ``e·η·s_c`` over
its wavelength interval; the direct spot collects ``η₀ ∫ e·s_c``. The slit's image (``slit_width``
along the dispersion, ``slit_length`` across, raised-cosine edges ``edge``: the lens blur) is the
shape of the direct spot, and every wavelength of the first order is such an image, so the first
order is the pixel integrals convolved with the slit's along-profile and spread across the slit's
length.

:meth:`TwinOptics.first_order` renders a lamp's 1-D first order with
:func:`calib.model.forward.render_observation` (at 0.2 nm, fine enough for narrow lines), takes its
spectral density ``e·η·s`` and turns it into the cumulative integral along ``u`` on a fine axis
(1/64 px), blurs it with the slit profile and hands it to :class:`mocks.scene.PixelIntegratedSignal`,
so that every sensor pixel of the 2-D frame receives the exact integral over its own footprint —
for an unblurred slit, the numbers ``calib.model.forward`` gives for its 1-D profile.

Units: lamps in W/(sr·m²·nm), sensitivities peaking at 1, and ``throughput_e_per_s`` turning their
wavelength integral into photo-electrons per second at f/8; the renderer works in DN/s at ISO 100
(electrons × the sensor's gain).

The grating is a physical model (:mod:`calib.model.gratings`, ``rig.config.TwinGratingConfig``):
a thin sinusoidal phase sheet by default (``η_m = J_m²(φ₀·550/λ)``) or a blazed grating
(``η_m = η_peak · sinc²(λ_blaze/λ − m)``). The direct spot collects ``∫ e·η₀·s_c`` through the 0th
order's own η₀(λ), and the second order lands on the first order's pixels at half their wavelength
(the grating equation: the same angle), added to the first order's cumulative integral.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.datasets import COLOUR_SCIENCE, find_camera, load_collection
from calib.core.errors import InputError
from calib.core.mapping import GratingGeometry
from calib.core.spectra import MultiSpectrum, Spectrum
from calib.model.forward import PiecewiseLinearDensity, RenderedObservation, render_observation
from calib.model.gratings import BlazedGrating, SinusoidalPhaseGrating
from mocks.bench.colour_cache import cached_table
from mocks.bench.flaws import CameraFlaws
from mocks.bench.spec import CameraSpec, GratingSpec, TwinSpecError
from mocks.scene import PixelIntegratedSignal, SceneLayout, SensorModel, soft_box

#: Step of the fine axis along the dispersion on which the first order's cumulative is tabulated.
FINE_STEP_PX = 1.0 / 64.0
#: Spectral step of the 1-D rendering: fine enough for the narrow lines of fluorescent lamps
#: (:data:`calib.core.line_lists.RESTORED_LINE_STEP_NM`), so their spectra are integrated exactly.
SPECTRAL_STEP_NM = 0.2
#: Aperture the throughput refers to.
REFERENCE_F_NUMBER = 8.0
#: ISO at which the sensor's gain is given.
REFERENCE_ISO = 100.0
#: Room left around the spot and band for detection's background strips (sensor pixels).
FRAME_MARGIN_PX = 24.0
#: Wavelength range the efficiency curve is tabulated over, nm.
EFFICIENCY_RANGE_NM = (300.0, 1100.0)


def load_sensitivity(camera: CameraSpec) -> MultiSpectrum:
    """The true camera's RGB sensitivity, normalised to a maximum of 1 over all channels.

    Raises
    ------
    TwinSpecError
        The collection or the camera cannot be found (the message lists candidates).
    """

    def from_collection() -> tuple[FloatArray, FloatArray]:
        records = load_collection(camera.sensitivity_collection, camera.data_dir)
        sensitivity = find_camera(records, camera.sensitivity).sensitivity.normalised()
        return sensitivity.wavelength_nm, sensitivity.values

    try:
        if camera.sensitivity_collection == COLOUR_SCIENCE:  # built in: cached per colour version
            wavelength_nm, values = cached_table(f"camera {camera.sensitivity}", from_collection)
        else:
            wavelength_nm, values = from_collection()
    except InputError as exc:
        raise TwinSpecError(
            f"devices.camera.sensitivity: {exc} (collection {camera.sensitivity_collection!r}"
            + (
                "; colour-science's cameras need no download"
                if camera.sensitivity_collection == COLOUR_SCIENCE
                else "; run `rig data fetch` first"
            )
            + ")"
        ) from None
    return MultiSpectrum(wavelength_nm, values, name=camera.sensitivity)


def blaze_efficiency(
    blaze_nm: float,
    peak_efficiency: float,
    range_nm: tuple[float, float] = EFFICIENCY_RANGE_NM,
    *,
    order: int = 1,
) -> Spectrum:
    """Order ``m``'s efficiency ``η_peak · sinc²(λ_blaze/λ − m)`` at 1 nm over ``range_nm``
    (:class:`calib.model.gratings.BlazedGrating`)."""
    axis = np.arange(range_nm[0], range_nm[1] + 0.5, 1.0)
    values = peak_efficiency * BlazedGrating(blaze_nm).efficiency(order, axis)
    return Spectrum(axis, values, name=f"blaze {blaze_nm:g} nm, order {order}")


def grating_orders(
    grating: GratingSpec, range_nm: tuple[float, float] = EFFICIENCY_RANGE_NM
) -> tuple[Spectrum, Spectrum, Spectrum, dict[str, Any]]:
    """η₀, η₁, η₂ of the twin's grating at 1 nm over ``range_nm``, and its record."""
    axis = np.arange(range_nm[0], range_nm[1] + 0.5, 1.0)
    if grating.model == "blazed":
        orders = [
            blaze_efficiency(
                grating.blaze_nm, grating.first_order_peak_efficiency, range_nm, order=m
            )
            for m in (0, 1, 2)
        ]
        record: dict[str, Any] = {
            **BlazedGrating(grating.blaze_nm).to_dict(),
            "scale": grating.first_order_peak_efficiency,
        }
    else:
        sheet = SinusoidalPhaseGrating(grating.peak_phase_rad)
        orders = [sheet.efficiency_spectrum(m, axis) for m in (0, 1, 2)]
        record = sheet.to_dict()
    if grating.zeroth_order_efficiency is not None:
        orders[0] = Spectrum(
            axis, np.full(axis.size, grating.zeroth_order_efficiency), name="flat 0th order"
        )
        record["flat_zeroth_order_efficiency"] = grating.zeroth_order_efficiency
    return orders[0], orders[1], orders[2], record


@dataclass(frozen=True, eq=False)
class FirstOrderRendering:
    """One spectrum through the optics, ready for the 2-D renderer.

    Attributes
    ----------
    signal
        The direct total and the first order's cumulative along ``u``, DN/s at ISO 100 and f/8.
    observation
        What ``calib.model.forward`` rendered (unscaled; its ``clean_profile`` holds the unblurred
        per-pixel integrals at integer ``u`` over the band).
    scale_dn_per_s
        DN/s per unit of ``calib.model.forward``'s output for the direct total (the band is this over
        the slit's length).
    """

    signal: PixelIntegratedSignal
    observation: RenderedObservation
    scale_dn_per_s: float


@dataclass(frozen=True, eq=False)
class TwinOptics:
    """Everything between a lamp and the sensor, and the truth an estimate is judged against.

    Attributes
    ----------
    camera_name
        The true camera.
    sensitivity
        Its RGB sensitivity (maximum 1).
    mapping
        Pixel→wavelength of the first order: sensor pixels from the direct spot's centre.
    efficiency
        First-order grating efficiency η(λ).
    zeroth_order_efficiency
        η₀(λ), the direct path's.
    second_order_efficiency
        η₂(λ).
    grating
        The grating's record (model and parameters).
    layout
        Spot position, dispersion angle, slit image size and edges on the sensor.
    sensor
        The Bayer sensor at ISO 100.
    throughput_e_per_s
        Photo-electrons per second per unit of radiance × sensitivity × nm, at f/8.
    slit_width_px, slit_length_px, edge_px
        The slit's image.
    band_range_px
        ``(u_min, u_max)``: where the first order of the sensitivity's range falls.
    """

    camera_name: str
    sensitivity: MultiSpectrum
    mapping: GratingGeometry
    efficiency: Spectrum
    zeroth_order_efficiency: Spectrum
    second_order_efficiency: Spectrum
    grating: dict[str, Any]
    layout: SceneLayout
    sensor: SensorModel
    throughput_e_per_s: float
    slit_width_px: float
    slit_length_px: float
    edge_px: float
    band_range_px: tuple[float, float]

    @classmethod
    def build(cls, camera: CameraSpec, flaws: CameraFlaws | None = None) -> TwinOptics:
        """Set up the optics of ``camera``, placing the spot so the first order fits the frame;
        with ``flaws``, the spot's stray light along the band (:mod:`mocks.bench.flaws`).

        Raises
        ------
        TwinSpecError
            Unknown camera; a first order that leaves the frame or has no 780 nm at this line
            density; a slit image that does not fit; edges wider than the slit.
        """
        optics, grating, sensor = camera.optics, camera.grating, camera.sensor
        if optics.edge_px > optics.slit_width_px:
            raise TwinSpecError(
                f"devices.camera.optics.edge_px = {optics.edge_px:g} is wider than slit_width_px = "
                f"{optics.slit_width_px:g}; the slit image would not reach full brightness"
            )
        sensitivity = load_sensitivity(camera)
        mapping = GratingGeometry(
            grooves_per_mm=grating.grooves_per_mm,
            focal_length_mm=optics.focal_length_mm,
            pixel_pitch_um=camera.pixel_pitch_um,
        )
        try:
            band = mapping.pixel_at(np.array(sensitivity.range_nm))
        except InputError:
            raise TwinSpecError(
                f"devices.camera.grating.grooves_per_mm = {grating.grooves_per_mm:g}: the first "
                f"order of {sensitivity.range_nm[1]:g} nm does not exist (λ ≥ line spacing); use "
                "fewer grooves per mm"
            ) from None
        band_range = (float(band[0]), float(band[1]))
        angle = grating.dispersion_angle_deg
        direction = (math.cos(math.radians(angle)), math.sin(math.radians(angle)))
        if optics.spot_position_px is None:
            middle = band_range[1] / 2.0
            spot = (
                sensor.width_px / 2.0 - direction[0] * middle,
                sensor.height_px / 2.0 - direction[1] * middle,
            )
        else:
            spot = optics.spot_position_px
        layout = SceneLayout(
            spot_centre_px=spot,
            dispersion_angle_deg=angle,
            spot_half_size_px=(optics.slit_width_px / 2.0, optics.slit_length_px / 2.0),
            band_half_width_px=optics.slit_length_px / 2.0,
            edge_px=optics.edge_px,
        )
        if flaws is not None and flaws.stray_fraction > 0:
            layout = replace(
                layout,
                stray_fraction=flaws.stray_fraction,
                stray_wing_px=flaws.stray_wing_band * visible_band_px(mapping),
            )
        _check_fits(layout, sensor, band_range)
        zeroth, first, second, record = grating_orders(grating)
        return cls(
            camera_name=sensitivity.name,
            sensitivity=sensitivity,
            mapping=mapping,
            efficiency=first,
            zeroth_order_efficiency=zeroth,
            second_order_efficiency=second,
            grating=record,
            layout=layout,
            sensor=sensor,
            throughput_e_per_s=optics.throughput_e_per_s,
            slit_width_px=optics.slit_width_px,
            slit_length_px=optics.slit_length_px,
            edge_px=optics.edge_px,
            band_range_px=band_range,
        )

    def slit_profile(self) -> tuple[FloatArray, FloatArray]:
        """The slit image along the dispersion on the fine axis: offsets ``(k,)`` and weights summing to 1."""
        reach = self.slit_width_px / 2.0 + self.edge_px
        steps = math.ceil(reach / FINE_STEP_PX)
        offsets = np.arange(-steps, steps + 1, dtype=np.float64) * FINE_STEP_PX
        weights = soft_box(offsets, self.slit_width_px / 2.0, self.edge_px)
        return offsets, weights / weights.sum()

    def first_order(self, lamp: Spectrum, *, blur: bool = True) -> FirstOrderRendering:
        """Render ``lamp`` through the optics at ISO 100 and f/8 (DN/s).

        Parameters
        ----------
        lamp
            Spectral radiance, W/(sr·m²·nm).
        blur
            Convolve the first order with the slit's image (off: the bare per-pixel integrals of
            ``calib.model.forward``, for checks).
        """
        start, stop = self.band_range_px
        coarse = np.arange(math.floor(start), math.ceil(stop) + 1, dtype=np.float64)
        observation = render_observation(
            lamp,
            self.sensitivity,
            mapping=self.mapping,
            pixel=coarse,
            grating_efficiency=self.efficiency,
            zeroth_order_efficiency=self.zeroth_order_efficiency,
            name=lamp.name,
            fine_step_nm=SPECTRAL_STEP_NM,
        )
        # The second order's spectral density: it lands where the first order has twice its λ.
        second = PiecewiseLinearDensity.on_axis(
            observation.spectral_axis_nm,
            observation.spectral_image
            * (
                self.second_order_efficiency.at(observation.spectral_axis_nm)
                / np.maximum(self.efficiency.at(observation.spectral_axis_nm), 1e-300)
            )[:, None],
        )
        offsets, weights = self.slit_profile() if blur else (np.zeros(1), np.ones(1))
        reach = float(offsets[-1]) + FINE_STEP_PX
        axis_nm = observation.spectral_axis_nm
        low, high = self.mapping.pixel_at(np.array([axis_nm[0], axis_nm[-1]]))
        first = math.floor((float(low) - reach) / FINE_STEP_PX)
        last = math.ceil((float(high) + reach) / FINE_STEP_PX)
        position = np.arange(first, last + 1, dtype=np.float64) * FINE_STEP_PX
        density = PiecewiseLinearDensity.on_axis(axis_nm, observation.spectral_image)
        wavelength = self.mapping.wavelength_nm(position)
        # The second order over the first order's band only (beyond it the frame has no band).
        cumulative = density.cumulative_at(wavelength) + second.cumulative_at(
            np.minimum(wavelength, axis_nm[-1]) / 2.0
        )
        if weights.size > 1:
            per_step = np.diff(cumulative, axis=0)
            blurred = np.stack(
                [np.convolve(per_step[:, k], weights, mode="same") for k in range(3)], axis=1
            )
            cumulative = np.concatenate([np.zeros((1, 3)), np.cumsum(blurred, axis=0)])
        scale = self.throughput_e_per_s * self.sensor.gain_dn_per_electron
        signal = PixelIntegratedSignal(
            direct_rgb=scale * observation.clean_direct,
            position_px=position,
            cumulative=np.maximum.accumulate(scale / self.slit_length_px * cumulative, axis=0),
        )
        return FirstOrderRendering(signal, observation, scale)


def visible_band_px(mapping: GratingGeometry) -> float:
    """Length of the first order's 400–700 nm on the sensor (pixels)."""
    ends = mapping.pixel_at(np.array([400.0, 700.0]))
    return float(abs(ends[1] - ends[0]))


def _check_fits(layout: SceneLayout, sensor: SensorModel, band_range: tuple[float, float]) -> None:
    """Raise :class:`TwinSpecError` unless the spot and the band (with margins) lie on the sensor."""
    along, across = layout.spot_half_size_px
    margin = layout.edge_px + FRAME_MARGIN_PX
    half_across = across * 1.25 + margin
    x0, y0 = layout.spot_centre_px
    dx, dy = layout.direction
    corners = [
        (x0 + u * dx - v * dy, y0 + u * dy + v * dx)
        for u in (-along - margin, band_range[1] + margin)
        for v in (-half_across, half_across)
    ]
    xs, ys = [x for x, _ in corners], [y for _, y in corners]
    if min(xs) < 0 or max(xs) > sensor.width_px or min(ys) < 0 or max(ys) > sensor.height_px:
        raise TwinSpecError(
            f"devices.camera: the direct spot at ({x0:.0f}, {y0:.0f}) px and the first order out "
            f"to {band_range[1]:.0f} px from it (with {margin:.0f} px margins and room for "
            f"background strips across the {2 * across:.0f} px slit image) span x "
            f"{min(xs):.0f}…{max(xs):.0f}, y {min(ys):.0f}…{max(ys):.0f}, beyond the "
            f"{sensor.width_px}×{sensor.height_px} sensor; use a larger sensor, a shorter focal "
            "length, fewer grooves per mm, a shorter slit or another spot_position_px"
        )
