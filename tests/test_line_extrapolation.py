"""A line lamp's span and what lies past it (decision 0122): a quadratic whole-profile fit states
its departure from the straight continuation past the outermost line as its σ there, and the
ambiguity warnings' advice depends on the lamps that were shot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.spectra import Spectrum, WavelengthGrid
from calib.wavelength.locate import _beyond_lines_sigma_nm
from calib.wavelength.profile_search import deciding_shot
from tests.paper_scenes import mapped_fl_paper_scene

GRID = WavelengthGrid(400.0, 700.0, 5.0)


def _lamp(
    kind: str = "fluorescent",
    step_nm: float = 5.0,
    bandwidth_nm: float | None = None,
    origin: str = "arbitrary",
) -> LampObservation:
    axis = np.arange(380.0, 781.0, step_nm)
    values = 0.1 + np.exp(-0.5 * ((axis - 546.0) / 2.0) ** 2)
    pixel = np.arange(0.0, 900.0)
    profile = np.tile(np.exp(-0.5 * ((pixel - 400.0) / 150.0) ** 2)[:, None], (1, 3))
    return LampObservation(
        name="CFL" if kind == "fluorescent" else "D65",
        spectrum=Spectrum(axis, values, name="lamp"),
        pixel=pixel,
        profile=profile,
        kind=kind,  # type: ignore[arg-type]
        spectrum_bandwidth_nm=bandwidth_nm,
        # A camera line 1.5 px wide: a 5 nm table is far coarser, so every Hg line is kept.
        line_spread=np.array([0.25, 0.5, 0.25]),
        pixel_origin=origin,  # type: ignore[arg-type]
    )


def test_the_advice_asks_for_a_line_lamp_only_when_none_was_shot() -> None:
    broadband = _lamp("led")
    alone = deciding_shot([broadband])
    assert alone.startswith("A fluorescent (line) lamp shot")
    coarse = deciding_shot([broadband, _lamp()])
    assert "fluorescent (line) lamp shot" not in coarse
    assert "was in the scene" in coarse and "bandwidth" in coarse and "0th order" in coarse
    fine = deciding_shot([broadband, _lamp(step_nm=0.5, bandwidth_nm=1.0)])
    assert "fluorescent (line) lamp shot" not in fine and "bandwidth" not in fine
    assert "second line lamp" in fine and "0th order" in fine
    spot = deciding_shot([_lamp(step_nm=0.5, bandwidth_nm=1.0, origin="direct_spot")])
    assert "second line lamp" in spot and "0th order" not in spot


def test_a_straight_mapping_has_nothing_past_its_lines() -> None:
    lamp = _lamp()
    beyond = _beyond_lines_sigma_nm(lamp, QuadraticMapping(0.0, 0.36, 385.0), GRID, lamp)
    assert beyond is not None
    assert beyond["rms_nm"] == pytest.approx(0.0, abs=1e-9)
    assert beyond["lines_reach_nm"][1] == pytest.approx(579.07, abs=0.01)


def test_a_curved_mapping_states_its_curvature_past_the_reddest_line() -> None:
    lamp = _lamp()
    curvature = 4e-5
    mapping = QuadraticMapping(curvature, 0.3, 385.0)
    beyond = _beyond_lines_sigma_nm(lamp, mapping, GRID, lamp)
    assert beyond is not None
    pixel = lamp.pixel
    at = mapping.wavelength_nm(pixel)
    last = float(np.interp(beyond["lines_reach_nm"][1], at, pixel))
    end = float(np.interp(700.0, at, pixel))
    # Past the last line the quadratic leaves its tangent by a (p − p_line)².
    assert beyond["sigma_at_grid_ends_nm"][1] == pytest.approx(
        curvature * (end - last) ** 2, rel=0.02
    )
    assert beyond["rms_nm"] > 0.1


@pytest.mark.slow
def test_the_5d_mk_ii_paper_scene_states_its_red_end(shared_camera_data: Path) -> None:
    mapped = mapped_fl_paper_scene(shared_camera_data, "Canon 5D-Mk-II (Jiang", 13)
    rms = float(np.sqrt(np.mean(mapped.error_nm(inside_grid=True) ** 2)))
    stated = mapped.found.mapping.wavelength_rms_nm
    assert stated is not None
    # Base 6d555a8: 1.11 nm RMS (3.0 at 700 nm) against a stated 0.475 nm.
    assert "beyond_lines" in mapped.found.details
    assert rms <= 2.0 * stated
