"""The 2nd order on the 1st order's red end: modelled under a physical grating, else masked,
never fitted as 1st-order light (decision 0032)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

import calib.methods.responses as responses
from calib.core.grating_file import GratingEfficiency
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import MultiSpectrum, WavelengthGrid
from calib.methods.known_grating import estimate_known_grating
from calib.model.bases import fallback_camera_basis
from calib.model.forward import (
    PiecewiseLinearDensity,
    pixel_edges,
    render_observation,
    second_order_onset_nm,
)
from calib.model.gratings import SinusoidalPhaseGrating

GRID = WavelengthGrid(380.0, 780.0, 5.0)
AXIS = np.arange(380.0, 800.5, 1.0)
SHEET = SinusoidalPhaseGrating(1.8)
MAPPING = QuadraticMapping(0.0, 0.5, 370.0, pixel_range=(0.0, 850.0))


def gaussian_camera() -> MultiSpectrum:
    """A camera whose blue channel still sees 380–400 nm (where the 2nd order comes from)."""
    channels = [(600.0, 40.0), (530.0, 40.0), (430.0, 35.0)]
    values = np.stack([np.exp(-0.5 * ((AXIS - c) / w) ** 2) for c, w in channels], axis=1)
    return MultiSpectrum(AXIS, values, name="gaussian")


@dataclass(frozen=True)
class Scene:
    camera: MultiSpectrum
    lamps: list[LampObservation]


@pytest.fixture(scope="module")
def scene() -> Scene:
    camera = gaussian_camera()
    lamps = []
    for name in ("D65", "A"):
        lamp = colour_lamp(name)
        pixel = np.arange(0.0, 851.0)
        first = render_observation(
            lamp,
            camera,
            mapping=MAPPING,
            pixel=pixel,
            grating_efficiency=SHEET.efficiency_spectrum(1, AXIS),
        )
        density = lamp.at(AXIS)[:, None] * SHEET.efficiency(2, AXIS)[:, None] * camera.values
        second = PiecewiseLinearDensity.on_axis(AXIS, density).integrate_pixels(
            MAPPING.wavelength_nm(pixel_edges(pixel)) / 2.0
        )
        profile = first.clean_profile + second
        sigma = np.full_like(profile, 1e-4 * float(profile.max()))
        lamps.append(LampObservation(name, lamp, pixel, profile, profile_sigma=sigma))
    return Scene(camera, lamps)


def estimate(scene: Scene, grating: GratingEfficiency) -> tuple[float, dict[str, object]]:
    basis = fallback_camera_basis(grid=GRID)
    result = estimate_known_grating(
        scene.lamps, grating=grating, basis=basis, grid=GRID, mapping=MAPPING
    )
    truth = scene.camera.resample(GRID).values
    return relative_error(result.sensitivity, truth), dict(result.diagnostics)


MEASURED = GratingEfficiency(AXIS, SHEET.efficiency(1, AXIS))
PHYSICAL = GratingEfficiency(
    AXIS,
    SHEET.efficiency(1, AXIS),
    model={"model": "sinusoidal", "parameters": {"peak_phase_rad": 1.8}},
)


def test_the_onset_is_twice_the_shortest_light_the_camera_can_see() -> None:
    assert second_order_onset_nm(colour_lamp("A")) == 760.0  # lit from 380 (and below)
    assert second_order_onset_nm(colour_lamp("FL2").scaled(0.0)) == math.inf


def test_modelled_under_the_physical_grating_the_2nd_order_costs_nothing(scene: Scene) -> None:
    modelled, diagnostics = estimate(scene, PHYSICAL)
    assert diagnostics["second_order"] == {
        "D65": {"from_nm": 760.0, "treated": "modelled"},
        "A": {"from_nm": 760.0, "treated": "modelled"},
    }
    masked, diagnostics = estimate(scene, MEASURED)
    assert {v["treated"] for v in diagnostics["second_order"].values()} == {"masked"}  # type: ignore[attr-defined]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(responses, "second_order_onset_nm", lambda lamp: math.inf)
        fitted, diagnostics = estimate(scene, PHYSICAL)
    assert "second_order" not in diagnostics
    # Fitting the 2nd order's light as 1st-order signal is what the mask and the model prevent.
    print(
        f"RE ×10⁻²: modelled {100 * modelled:.3f}, masked {100 * masked:.3f}, "
        f"fitted as 1st order {100 * fitted:.3f}"
    )
    assert modelled < 0.002 and masked < 0.5 * fitted and modelled < 0.5 * fitted
