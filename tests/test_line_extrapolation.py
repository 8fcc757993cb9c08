"""A line lamp's span and what lies past it (decisions 0122, 0127): a quadratic fit states its
departure from the straight continuation past the outermost line as its σ there — the mapping
carries it (its line reach), so every consumer reads one σ — and the ambiguity warnings' advice
depends on the lamps that were shot."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.core.mapping import (
    LineReach,
    QuadraticMapping,
    TiltedGrating,
    wavelength_rms_from_covariance,
)
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import Spectrum, WavelengthGrid
from calib.wavelength.locate import _hg_reach_nm, _line_reach, _red_end
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
    mapping = QuadraticMapping(0.0, 0.36, 385.0)
    reach_nm = _hg_reach_nm(lamp, mapping, GRID)
    assert reach_nm is not None
    assert reach_nm[1] == pytest.approx(579.07, abs=0.01)
    reach = _line_reach(reach_nm, mapping, lamp)
    assert reach.curvature_nm_per_px2 == 0.0
    assert np.all(reach.sigma_nm(lamp.pixel) == 0.0)


def test_a_curved_mapping_states_its_curvature_past_the_reddest_line() -> None:
    lamp = _lamp()
    curvature = 4e-5
    mapping = QuadraticMapping(curvature, 0.3, 385.0)
    reach_nm = _hg_reach_nm(lamp, mapping, GRID)
    assert reach_nm is not None
    reach = _line_reach(reach_nm, mapping, lamp)
    pixel = lamp.pixel
    at = mapping.wavelength_nm(pixel)
    last = float(np.interp(reach_nm[1], at, pixel))
    end = float(np.interp(700.0, at, pixel))
    # Past the last line the quadratic leaves its tangent by a (p − p_line)²: decision 0122's
    # term, now the mapping's own (decision 0127).
    assert reach.sigma_nm(np.array([end]))[0] == pytest.approx(curvature * (end - last) ** 2)
    middle = float(np.interp(500.0, at, pixel))
    assert reach.sigma_nm(np.array([middle]))[0] == 0.0


def test_a_grating_familys_red_end_is_its_covariances() -> None:
    grating = TiltedGrating(0.5, 3000.0)
    ends = grating.pixel_at(np.array([390.0, 720.0]))
    lamp = replace(_lamp(origin="direct_spot"), pixel=np.linspace(ends[0], ends[1], 900))
    reach = _line_reach((404.7, 579.1), grating, lamp)
    # The 0th order pins the curvature: nothing past the lines but the covariance's σ.
    assert reach.curvature_nm_per_px2 == 0.0
    assert reach.pixel_range[1] == pytest.approx(
        float(grating.pixel_at(np.array([579.1]))[0]), abs=1e-3
    )


def _stated(reach: LineReach | None) -> QuadraticMapping:
    covariance = ((1e-12, 0.0, 0.0), (0.0, 1e-8, 0.0), (0.0, 0.0, 0.01))
    return QuadraticMapping(
        4e-5, 0.3, 385.0, pixel_range=(0.0, 899.0), covariance=covariance, wavelength_rms_nm=0.1
    ).with_line_reach(reach)


def _sigma(mapping: QuadraticMapping, pixel: np.ndarray) -> np.ndarray:
    sigma = mapping.sigma_nm(pixel)
    assert sigma is not None
    return sigma


REACH = LineReach((60.0, 540.0), (404.7, 579.1), 4e-5)


def test_the_mapping_carries_one_sigma_for_every_consumer() -> None:
    """The covariance's σ within the lines, the extrapolation in quadrature past them, in the
    stated RMS, the report's plot, the validation's scoring and the sensitivity's mapping
    component alike."""
    from calib.evaluation.validation.protocol import mapping_sigma_nm as scored
    from calib.pipeline.report_plots import mapping_sigma_nm as plotted

    plain, reached = _stated(None), _stated(REACH)
    pixel = np.array([300.0, 800.0])
    inside, past = _sigma(reached, pixel)
    assert inside == pytest.approx(_sigma(plain, pixel)[0])
    covariance_past = _sigma(plain, pixel)[1]
    assert past == pytest.approx(np.hypot(covariance_past, 4e-5 * 260.0**2))
    assert reached.wavelength_rms_nm is not None and plain.wavelength_rms_nm is not None
    assert reached.wavelength_rms_nm > 2 * plain.wavelength_rms_nm
    for consumer in (scored, plotted):
        assert np.array_equal(np.asarray(consumer(reached, pixel)), _sigma(reached, pixel))
    # Serialised where the covariance is, and a replaced covariance keeps the reach in its RMS.
    record = reached.to_dict()
    assert record["line_reach"]["curvature_nm_per_px2"] == 4e-5
    assert QuadraticMapping.from_dict(record) == reached
    rescaled = reached.with_details(
        covariance=[[2 * v for v in row] for row in record["covariance"]], wavelength_rms_nm=0.01
    )
    assert rescaled.line_reach == REACH and rescaled.covariance is not None
    assert rescaled.wavelength_rms_nm == pytest.approx(
        wavelength_rms_from_covariance(np.asarray(rescaled.covariance), (0.0, 899.0), REACH)
    )


def test_the_sensitivitys_mapping_component_grows_past_the_lines() -> None:
    from calib.methods.uncertainty import mapping_sigma

    grid = WavelengthGrid(400.0, 700.0, 5.0)
    wavelength = grid.wavelength_nm
    # A sensitivity with the same slope everywhere: the component is σ_λ(λ) times it.
    curves = np.tile(((wavelength - 390.0) / 310.0)[:, None], (1, 3))  # maximum 1

    def component(mapping: QuadraticMapping) -> np.ndarray:
        result = EstimateResult("x", wavelength, curves, mapping=mapping)
        values, note = mapping_sigma(result)
        assert note is None
        return np.asarray(values[:, 1], dtype=np.float64)

    plain, reached = component(_stated(None)), component(_stated(REACH))
    middle = int(np.argmin(np.abs(wavelength - 500.0)))
    assert reached[middle] == pytest.approx(plain[middle])
    assert reached[-1] > 3 * plain[-1]
    mapping = _stated(REACH)
    expected = _sigma(mapping, mapping.pixel_at(wavelength))
    assert reached == pytest.approx(expected / 310.0, rel=1e-6)


def test_the_red_end_note_reads_the_mappings_sigma() -> None:
    record, note = _red_end(_stated(REACH), GRID)
    assert record["sigma_at_grid_ends_nm"][1] > 1.0
    assert note is not None and "quadratic fit" in note and "0th order" in note
    straight = _stated(LineReach((60.0, 540.0), (404.7, 579.1), 0.0))
    record, note = _red_end(straight, GRID)
    assert record["sigma_at_grid_ends_nm"][1] < 1.0 and note is None


@pytest.mark.slow
def test_the_5d_mk_ii_paper_scene_states_its_red_end(shared_camera_data: Path) -> None:
    mapped = mapped_fl_paper_scene(shared_camera_data, "Canon 5D-Mk-II (Jiang", 13)
    error = mapped.error_nm(inside_grid=True)
    rms = float(np.sqrt(np.mean(error**2)))
    mapping = mapped.found.mapping
    stated = mapping.wavelength_rms_nm
    assert stated is not None and mapping.line_reach is not None
    # Base 6d555a8: 1.11 nm RMS (3.0 at 700 nm) against a stated 0.475 nm; base 97d6231 stated
    # 0.764 nm RMS but its per-pixel σ at 700 nm was the covariance's, with no note.
    assert rms <= 2.0 * stated
    truth = mapped.scene.mapping.wavelength_nm(mapped.lamps[0].pixel)
    red = int(np.argmin(np.abs(truth - 700.0)))
    red_error = float(mapped.error_nm()[red])
    assert abs(red_error) > 2.0
    sigma_red = mapping.sigma_nm(mapped.lamps[0].pixel[red : red + 1])[0]
    assert abs(red_error) <= 2.0 * sigma_red
    assert "mapping_extrapolated" in mapped.found.details["warning_codes"]
