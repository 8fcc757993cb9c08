"""Line lists, the mapping from emission and absorption features, either orientation, and the
ambiguity a broadband lamp leaves."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.errors import EstimationError, InputError
from calib.core.lamp_specs import lamp_from_spec
from calib.core.line_lists import blends, builtin_lamp, line_list
from calib.core.mapping import GratingGeometry, QuadraticMapping, TiltedGrating
from calib.core.observations import LampKind, LampObservation
from calib.core.result import mapping_flags
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum
from calib.model.bases import CameraPrior, fallback_camera_basis
from calib.model.forward import PeakFractionNoise, render_observation
from calib.pipeline.inputs import load_spectrum
from calib.wavelength.families import GratingFamily, grating_prior
from calib.wavelength.features import fit_features, map_features
from calib.wavelength.locate import _check_monotonic, _map_lines, locate_mapping
from calib.wavelength.profile_search import (
    AMBIGUITY_MIN_DISTANCE_NM,
    LOCAL_SIGMA_SCALE,
    Candidate,
    basin_sigma,
    prior_misfit_sigma_nm,
    search_profiles,
    stated_covariance,
)

CAMERA_NAME = "Canon EOS 5D Mark II"


@pytest.fixture(scope="module")
def camera() -> MultiSpectrum:
    return find_camera(colour_science_cameras(), CAMERA_NAME).sensitivity


@pytest.fixture(scope="module")
def prior() -> CameraPrior:
    return fallback_camera_basis(exclude=[CAMERA_NAME]).prior()


# ----------------------------------------------------------------------------- line lists


def test_blends_follow_the_resolution():
    cfl = line_list("cfl-triphosphor")
    wide = {b.label: b for b in blends(cfl, 5.0)}
    assert "Tb 542.4 + Hg 546.1" in wide
    pair = wide["Tb 542.4 + Hg 546.1"]
    # The centre a centroid measures is strength-weighted; the reference is the Hg line, whose
    # wavelength is a standard (the phosphor peak's is known to 0.5 nm).
    assert 542.4 < pair.wavelength_nm < 546.1
    assert pair.reference.label == "Hg 546.1"
    assert pair.uncertainty_nm == 0.5
    narrow = {b.label for b in blends(cfl, 2.0)}
    assert {"Tb 542.4", "Hg 546.1"} <= narrow
    # Na D1/D2 (0.6 nm apart) and the Mg b triplet blend at 1 nm, not at 0.3 nm.
    solar = {b.label for b in blends(line_list("solar"), 1.0)}
    assert "Fraunhofer D2 + Fraunhofer D1" in solar
    assert "Fraunhofer D2" in {b.label for b in blends(line_list("solar"), 0.3)}


def test_builtin_specs_and_colour_names_resolve_in_one_place(tmp_path):
    lamp = lamp_from_spec("builtin:hg:1.5")
    assert lamp.name == "builtin:hg"
    at = lamp.at(np.array([546.07, 550.0]))
    assert at[0] > 100 * max(at[1], 1e-12)  # a line, not a band
    with pytest.raises(InputError, match="needs a list name"):
        lamp_from_spec("builtin:")
    with pytest.raises(InputError, match="no built-in line list 'xenon'"):
        lamp_from_spec("builtin:xenon")
    with pytest.raises(InputError, match="width must be > 0"):
        lamp_from_spec("builtin:hg:-1")
    # calib estimate --spectrum FL11 (a colour-science light source, not a file) and builtin:.
    for spec in ("FL11", "builtin:cfl-triphosphor"):
        loaded = load_spectrum(Path(spec), "CFL", DEFAULT_GRID)
        assert loaded.spectrum.covers(DEFAULT_GRID)
    with pytest.raises(InputError, match="not a spectrum file, a colour-science"):
        load_spectrum(Path("nonsense-lamp"), "CFL", DEFAULT_GRID)
    with pytest.raises(InputError):  # a CSV that does not exist is still a missing file
        load_spectrum(tmp_path / "missing.csv", "CFL", DEFAULT_GRID)


# ------------------------------------------------------------------------- feature mapping


def _physical_profile(
    lamp: Spectrum,
    camera: MultiSpectrum,
    truth: TiltedGrating | GratingGeometry,
    seed: int,
    noise: float = 0.002,
    *,
    pixel: np.ndarray | None = None,
    slit_width_px: float = 3.0,
    psf_sigma_px: float = 1.0,
    **extra: Any,
) -> LampObservation:
    """``lamp`` through ``truth`` (by default over the pixels of 370–730 nm)."""
    if pixel is None:
        lo, hi = sorted(truth.pixel_at(np.array([370.0, 730.0])))
        pixel = np.arange(np.floor(lo), np.ceil(hi))
    return render_observation(
        lamp,
        camera,
        mapping=truth,
        pixel=pixel,
        slit_width_px=slit_width_px,
        psf_sigma_px=psf_sigma_px,
        noise=PeakFractionNoise(noise),
        rng=np.random.default_rng(seed),
        fine_step_nm=0.05,  # lines narrower than 1 nm must be sampled finer to render right
        **extra,
    ).observation


def test_fraunhofer_mapping_on_a_synthetic_solar_profile(camera):
    """Sunlight's dips, found continuum-normalised and matched with no start, place the mapping."""
    dips = builtin_lamp("builtin:solar")
    axis = dips.wavelength_nm
    planck = 1.0 / (axis**5 * (np.exp(1.4388e7 / (axis * 5778.0)) - 1.0))
    sun = Spectrum(axis, dips.values * planck / planck.max(), name="sunlight")
    truth = TiltedGrating(1e6 / 600.0 / 7000.0, 7000.0, 3.0, axis_offset_px=-500.0)
    observation = _physical_profile(sun, camera, truth, seed=2)
    family = GratingFamily(
        grating_prior(grooves_per_mm=600.0, focal_length_px=7300.0, axis_offset_px=-500.0),
        axis_offset_px=-500.0,
    )
    found = map_features(
        observation.pixel, observation.profile, line_list("solar"), family=family, fwhm_px=4.0
    )
    table = {row["line"]: row for row in found.table()}
    for name in (
        "Fraunhofer G",
        "Fraunhofer F (H-beta)",
        "Fraunhofer C (H-alpha)",
        "Fraunhofer B (O2)",
    ):
        assert name in table
    error = found.exact.wavelength_nm(observation.pixel) - truth.wavelength_nm(observation.pixel)
    assert float(np.sqrt(np.mean(error**2))) < 0.1
    assert set(table["Fraunhofer C (H-alpha)"]) == {
        "line",
        "wavelength_nm",
        "pixel",
        "fitted_nm",
        "residual_nm",
        "weight",
    }


@pytest.mark.parametrize("orientation", [1, -1])
def test_a_cfl_through_its_builtin_lines_either_way_round(camera, orientation):
    """No spectrum measured, no 0th order in the profile, possibly mirrored: the lines decide."""
    truth = TiltedGrating(
        1e6 / 1000.0 / 3700.0,
        3700.0,
        3.0,
        zero_order_px=-1480.0 if orientation > 0 else 3980.0,
        orientation=orientation,
    )
    pixel = np.arange(0.0, 2500.0)
    observation = render_observation(
        lamp_from_spec("builtin:cfl-triphosphor"),
        camera,
        mapping=truth,
        pixel=pixel,
        slit_width_px=12.0,
        psf_sigma_px=3.0,
        noise=PeakFractionNoise(0.002),
        rng=np.random.default_rng(1),
        fine_step_nm=0.05,
        kind="fluorescent",
    ).observation
    solution = locate_mapping([observation], fallback_camera_basis().prior(), DEFAULT_GRID)
    assert solution.details["orientation" if "orientation" in solution.details else "family"]
    hg = {row["line"]: row for row in solution.matched_lines}
    for line in ("Hg 435.8", "Hg 546.1"):
        true_px = float(truth.pixel_at(np.array([hg[line]["wavelength_nm"]]))[0])
        assert abs(hg[line]["pixel"] - true_px) < 0.5
        assert abs(hg[line]["residual_nm"]) < 0.1
    slope = np.diff(solution.exact.wavelength_nm(pixel[[0, -1]]))[0]
    assert np.sign(slope) == orientation


# ---------------------------------------------------------------------- orientation, folding


def test_a_mirrored_profile_maps_to_the_same_wavelengths(camera, prior):
    truth = QuadraticMapping(-2.0e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
    rising = render_observation(
        lamp_from_spec("LED-B3"),
        camera,
        mapping=truth,
        pixel=800,
        noise=PeakFractionNoise(0.005),
        rng=np.random.default_rng(4),
    ).observation
    mirrored = LampObservation(
        "LED-B3 mirrored", rising.spectrum, rising.pixel, rising.profile[::-1], kind="led"
    )
    forward = search_profiles([rising], prior, DEFAULT_GRID)
    backward = search_profiles([mirrored], prior, DEFAULT_GRID)
    assert forward.details["orientation"] == "rising"
    assert backward.details["orientation"] == "falling"
    pixels = rising.pixel
    np.testing.assert_allclose(
        backward.exact.wavelength_nm(pixels[::-1]), forward.exact.wavelength_nm(pixels), atol=0.05
    )
    inside = (truth.wavelength_nm(pixels) > 400) & (truth.wavelength_nm(pixels) < 700)
    error = forward.exact.wavelength_nm(pixels) - truth.wavelength_nm(pixels)
    assert float(np.max(np.abs(error[inside]))) < 1.0


def test_a_folding_mapping_is_an_error_not_a_result():
    observation = LampObservation("x", lamp_from_spec("D65"), np.arange(100.0), np.ones((100, 3)))
    folding = QuadraticMapping(-0.01, 1.0, 400.0)  # turns at pixel 50
    with pytest.raises(EstimationError, match="folds back"):
        _check_monotonic(folding, observation)


def test_a_lamp_none_of_whose_lines_shows_is_an_estimation_error_its_caller_falls_back_from():
    # A measured FL lamp whose Hg lines all fall outside what it shows (the protocol's noise-only
    # errors: no line shown) ended in an IndexError that no caller catches; the callers' fallback
    # (the profile fit stands, the next basin) catches EstimationError.
    observation = LampObservation("FL2", lamp_from_spec("FL2"), np.arange(100.0), np.ones((100, 3)))
    with pytest.raises(EstimationError, match="none of its listed lines shows"):
        _map_lines(observation, (), None, start=None, directions=(1,), grid=DEFAULT_GRID)


# ------------------------------------------------------------------------------- ambiguity


def test_two_near_equal_basins_are_stated_and_carried(camera, prior):
    """A lamp whose only structure is a 10 nm comb lets a shift by whole periods fit almost as
    well: the result warns, recommends a line lamp, carries both basins, and its σ includes the
    other."""
    axis = np.arange(360.0, 831.0, 0.5)
    comb = Spectrum(axis, 1.0 + 0.9 * np.cos(2 * np.pi * axis / 10.0), name="comb")
    truth = QuadraticMapping(0.0, 0.4, 380.0, pixel_range=(0.0, 799.0))
    observation = render_observation(
        comb,
        camera,
        mapping=truth,
        pixel=800,
        noise=PeakFractionNoise(0.02),
        rng=np.random.default_rng(5),
    ).observation
    found = search_profiles([observation], prior, DEFAULT_GRID)
    assert found.ambiguous
    assert "fluorescent" in found.warnings[0]
    # Through the one entry, the warning reaches the result's quality as an ambiguity, by its code.
    located = locate_mapping([observation], prior, DEFAULT_GRID, orientation="rising")
    codes = located.mapping.details["warning_codes"]
    assert codes and set(codes) == {"mapping_ambiguous"}
    assert [flag.code for flag in mapping_flags(located.mapping)] == codes
    candidates = found.details["candidates"]
    assert len(candidates) >= 2
    # The comb's aliases: a whole number of its periods away.
    periods = candidates[1]["rms_distance_nm"] / 10.0
    assert round(periods) >= 1 and abs(periods - round(periods)) < 0.1
    assert candidates[1]["delta_chi2"] < found.details.get("ambiguity_delta_chi2", 25.0)
    assert found.mapping.wavelength_rms_nm is not None
    assert found.mapping.wavelength_rms_nm > 3 * found.details["local_rms_nm"]
    # The stated σ spans the basins the warning names: its ±2σ reaches the competing one.
    competing = [
        c
        for c in candidates[1:]
        if c["delta_chi2"] < 25.0 and c["rms_distance_nm"] > AMBIGUITY_MIN_DISTANCE_NM
    ]
    assert competing
    assert 2.0 * found.mapping.wavelength_rms_nm >= max(c["rms_distance_nm"] for c in competing)
    # ... and the result carries both, each with its mapping (what result.json writes).
    carried = located.mapping.to_dict()["details"]["candidates"]
    assert len(carried) >= 2 and all("mapping" in c for c in carried)


def _basin(delta_chi2: float, distance_nm: float) -> Candidate:
    mapping = QuadraticMapping(0.0, 0.4, 380.0 + distance_nm, pixel_range=(0.0, 799.0))
    return Candidate(
        mapping, 100.0 + delta_chi2, delta_chi2, math.exp(-delta_chi2 / 6.0), distance_nm
    )


def test_the_basins_likelihoods_decide_the_stated_sigma():
    """Two close basins 8 nm apart: ambiguous, σ spans them (±2σ reaches the other); the same
    second basin far less likely: not ambiguous, σ from the best basin's parts alone."""
    parts = {"local_nm": 0.1, "scale_nm": 0.2, "misfit_nm": 0.4}
    close = basin_sigma([_basin(0.0, 0.0), _basin(4.0, 8.0)], **parts)
    assert close.competing is not None and close.competing.distance_nm == 8.0
    assert 2.0 * close.stated_nm >= 8.0
    assert close.spread_nm > 1.0
    unlikely = basin_sigma([_basin(0.0, 0.0), _basin(400.0, 8.0)], **parts)
    assert unlikely.competing is None
    assert unlikely.stated_nm == pytest.approx(math.sqrt(0.1**2 + 0.2**2 + 0.4**2), rel=1e-6)
    # A basin a fraction of a nanometre away is the same answer, however likely.
    same = basin_sigma([_basin(0.0, 0.0), _basin(0.5, 0.6)], **parts)
    assert same.competing is None and same.stated_nm < 1.0


def test_a_broadband_mapping_states_the_prior_pull(camera, prior):
    """An LED alone: the stated σ holds the camera prior's pull, measured by the deciding fit's
    excess misfit (decision 0117), and the share of the spectrometer's scale an LED-only mapping
    follows (decision 0108) — here a tabulated spectrum, so none."""
    truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
    led = render_observation(
        lamp_from_spec("LED-B3"),
        camera,
        mapping=truth,
        pixel=800,
        noise=PeakFractionNoise(0.01),
        rng=np.random.default_rng(3),
        kind="led",
    ).observation
    found = search_profiles([led], prior, DEFAULT_GRID, orientation="rising")
    details = found.details
    pull = prior_misfit_sigma_nm(details["temper"], details["local_rms_nm"])
    assert details["prior_misfit_sigma_nm"] == pytest.approx(pull)
    assert details["spectrometer_scale_sigma_nm"] == 0.0
    stated = found.mapping.wavelength_rms_nm
    assert stated is not None
    assert stated >= math.hypot(pull, LOCAL_SIGMA_SCALE * details["local_rms_nm"]) - 1e-9


# ------------------------------------------------------------------ a measured line lamp


def _halophosphate(doublet_ratio: float) -> Spectrum:
    """A measured-lamp truth: FL2's band (its 5 nm table without the line bins' excess) with narrow
    Hg lines at their wavelengths, the 576.96/579.07 doublet split ``1 : doublet_ratio``."""
    table = lamp_from_spec("FL2")
    axis = np.arange(360.0, 800.0, 0.05)
    band = np.interp(axis, table.wavelength_nm, table.values)
    clear = ~np.any(np.abs(axis[:, None] - np.array([405.0, 435.0, 545.0, 580.0])) < 5.0, axis=1)
    band = np.interp(axis, axis[clear], band[clear])
    lines = {404.656: 1.0, 435.833: 2.5, 546.074: 3.0, 576.960: 1.0, 579.066: doublet_ratio}
    sigma = 0.5 / 2.355
    peak = float(band.max())
    for centre, power in lines.items():
        band = band + peak * power * np.exp(-0.5 * ((axis - centre) / sigma) ** 2)
    return Spectrum(axis, band, name="halophosphate with Hg lines")


def _measured(lamp: Spectrum, bandwidth_nm: float, step_nm: float) -> Spectrum:
    """``lamp`` through a Gaussian slit of ``bandwidth_nm``, sampled every ``step_nm``."""
    axis = np.arange(380.0, 780.0 + step_nm / 2, step_nm)
    sigma = bandwidth_nm / 2.355
    weights = np.exp(-0.5 * ((axis[:, None] - lamp.wavelength_nm[None, :]) / sigma) ** 2)
    values = weights @ lamp.values / weights.sum(axis=1)
    return Spectrum(axis, values, name=f"{lamp.name}, measured at {bandwidth_nm:g} nm")


#: The rig-like scene of the measured-lamp tests: a 500 l/mm sheet, 12 mm lens, 4.8 µm pixels.
_RIG_TRUTH = GratingGeometry(grooves_per_mm=500.0, focal_length_mm=12.0, pixel_pitch_um=4.8)
_RIG_PIXEL = np.arange(440.0, 990.0, 1.0)


def _halophosphate_and_led(
    camera: MultiSpectrum, bandwidth_nm: float, step_nm: float, slit_width_px: float = 2.0
) -> list[LampObservation]:
    """A halophosphate lamp and LED-B3 rendered through :data:`_RIG_TRUTH` (0th order at the
    origin) and a camera slit ``slit_width_px`` wide, each with its spectrum as a spectrometer of
    ``bandwidth_nm`` / ``step_nm`` measures it."""
    observations = []
    lamps: tuple[tuple[Spectrum, LampKind], ...] = (
        (_halophosphate(2.5), "fluorescent"),
        (lamp_from_spec("LED-B3"), "led"),
    )
    for lamp, kind in lamps:
        rendered = render_observation(
            lamp,
            camera,
            mapping=_RIG_TRUTH,
            pixel=_RIG_PIXEL,
            slit_width_px=slit_width_px,
            psf_sigma_px=0.8,
            noise=PeakFractionNoise(0.002),
            rng=np.random.default_rng(7),
            fine_step_nm=0.05,
            kind=kind,
        ).observation
        observations.append(
            replace(
                rendered,
                spectrum=_measured(lamp, bandwidth_nm, step_nm),
                spectrum_bandwidth_nm=bandwidth_nm,
                pixel_origin="direct_spot",
            )
        )
    return observations


@pytest.mark.parametrize(("bandwidth_nm", "step_nm"), [(8.0, 4.0), (1.5, 0.4)])
def test_a_measured_fluorescent_lamp_maps_through_its_lines_to_the_red_end(
    camera, prior, bandwidth_nm, step_nm
):
    """Issue 20's twin: a halophosphate lamp (Hg lines up to 579 nm) measured by a spectrometer, a
    camera unlike the prior, the 0th order at the origin and nothing else known. The whole-profile
    fit bends the grating to suit the prior (the twin's landed 5–7 nm off at the red end); the
    lines decide, the 577/579 doublet at its centre with σ for its unknown split, and the grating
    equation carries them to the red end — within its stated σ."""
    truth, pixel = _RIG_TRUTH, _RIG_PIXEL
    observations = _halophosphate_and_led(camera, bandwidth_nm, step_nm)
    solution = locate_mapping(observations, prior, DEFAULT_GRID)
    assert (
        solution.details["line_source"] == "Hg lines of halophosphate with Hg lines (measured lamp)"
    )
    # Decision 0050: the spectrometer's scale is in the σ only when its spectrum placed lines
    # (the fine one); the list's lines sit where mercury has them whatever its scale.
    placed_by_spectrum = bool(solution.details["line_centres_from_spectrum"])
    assert placed_by_spectrum is (bandwidth_nm < 2.0)
    assert ("spectrometer_scale_sigma_nm" in solution.details) is placed_by_spectrum
    assert ("listed_lines_floor_nm" in solution.details) is not placed_by_spectrum
    red_px = float(truth.pixel_at(np.array([DEFAULT_GRID.stop_nm]))[0])
    red_error = float(solution.exact.wavelength_nm(np.array([red_px]))[0]) - DEFAULT_GRID.stop_nm
    assert abs(red_error) < 0.5
    sigma_red = solution.details["red_end"]["sigma_at_grid_ends_nm"][1]
    assert abs(red_error) < 2.0 * sigma_red
    inside = (truth.wavelength_nm(pixel) >= 400.0) & (truth.wavelength_nm(pixel) <= 700.0)
    error = solution.exact.wavelength_nm(pixel) - truth.wavelength_nm(pixel)
    assert float(np.max(np.abs(error[inside]))) < 0.5
    table = {row["line"]: row for row in solution.matched_lines}
    doublet = table["Hg 577.0 + Hg 579.1"]
    # At the list's centre (not the 579.07 line's), with the split's σ in its weight.
    assert 577.5 < doublet["wavelength_nm"] < 578.5
    assert doublet["weight"] < 1.0 / 0.6**2
    # Nothing pins the grating beyond 579 nm but an incidence near 0: the result says so, by code.
    if sigma_red > 1.0:
        assert "mapping_extrapolated" in solution.details["warning_codes"]
        assert "Eu 611" in solution.warnings[-1]
    # The whole-profile fit only started the lines: its distance is recorded, not warned about.
    assert "profile_fit_distance_nm" in solution.details
    assert not any("disagree" in text for text in solution.warnings)


def test_a_red_end_pinned_by_the_line_density_needs_no_warning(camera, prior):
    """The same lamp with the grating's line density known (±2 %): σ at 700 nm falls below 1 nm and
    nothing is warned; without it the extrapolation is stated."""
    truth = GratingGeometry(grooves_per_mm=500.0, focal_length_mm=12.0, pixel_pitch_um=4.8)
    pixel = np.arange(440.0, 990.0, 1.0)
    lamp = _halophosphate(1.0)
    rendered = render_observation(
        lamp,
        camera,
        mapping=truth,
        pixel=pixel,
        slit_width_px=2.0,
        psf_sigma_px=0.8,
        noise=PeakFractionNoise(0.002),
        rng=np.random.default_rng(8),
        fine_step_nm=0.05,
        kind="fluorescent",
    ).observation
    observation = replace(
        rendered,
        spectrum=_measured(lamp, 3.0, 0.5),
        spectrum_bandwidth_nm=3.0,
        pixel_origin="direct_spot",
    )
    known = locate_mapping([observation], prior, DEFAULT_GRID, grooves_per_mm=500.0)
    assert known.details["red_end"]["sigma_at_grid_ends_nm"][1] < 1.0
    assert "mapping_extrapolated" not in known.details["warning_codes"]
    unknown = locate_mapping([observation], prior, DEFAULT_GRID)
    assert (
        unknown.details["red_end"]["sigma_at_grid_ends_nm"][1]
        > known.details["red_end"]["sigma_at_grid_ends_nm"][1]
    )
    for found in (known, unknown):
        red_px = float(truth.pixel_at(np.array([DEFAULT_GRID.stop_nm]))[0])
        red_nm = float(found.exact.wavelength_nm(np.array([red_px]))[0])
        assert abs(red_nm - DEFAULT_GRID.stop_nm) < 0.5


def test_a_profile_fit_the_lines_could_not_correct_states_how_far_it_misplaces_them(
    camera, prior, monkeypatch
):
    """When a measured lamp's line fit fails its checks, the whole-profile fit stands: its σ is
    then at least how far it puts the lamp's lines from where the lamp's spectrum has them. A fit
    4 nm off (forced here) is stated at ~4 nm, never at the curvature's tenths."""
    import calib.wavelength.locate as locate

    truth, pixel = _RIG_TRUTH, _RIG_PIXEL
    observations = _halophosphate_and_led(camera, 1.5, 0.4)
    shift_nm = 4.0
    ends = (float(pixel[0]), float(pixel[-1]))

    def off_by_four(*args, **kwargs):  # the profile fit a camera unlike the prior gives
        found = search_profiles(*args, **kwargs)
        exact = QuadraticMapping.fit(pixel, truth.wavelength_nm(pixel) + shift_nm)
        exact = replace(exact, pixel_range=ends)
        stated = stated_covariance(
            replace(exact, covariance=found.mapping.covariance), 0.2, 0.0, ends
        )
        return replace(found, mapping=stated, exact=exact)

    def refuse(*args, **kwargs):
        raise EstimationError("forced: the line fit is refused")

    monkeypatch.setattr(locate, "search_profiles", off_by_four)
    monkeypatch.setattr(locate, "_check_line_fit", refuse)
    solution = locate_mapping(observations, prior, DEFAULT_GRID)
    assert "measured_lines_failed" in solution.details
    inside = (truth.wavelength_nm(pixel) >= 400.0) & (truth.wavelength_nm(pixel) <= 700.0)
    error = solution.exact.wavelength_nm(pixel[inside]) - truth.wavelength_nm(pixel[inside])
    assert float(np.sqrt(np.mean(error**2))) == pytest.approx(shift_nm, abs=0.2)
    stated = solution.mapping.wavelength_rms_nm
    assert stated is not None
    assert 0.5 * shift_nm <= stated <= 2.0 * shift_nm
    assert solution.details["profile_fit_sigma_nm"] == pytest.approx(0.2, rel=0.05)
    assert solution.details["line_misplacement_nm"] == pytest.approx(shift_nm, abs=1.0)


def test_measured_lines_that_decide_silence_the_profile_fits_basins(camera, prior, monkeypatch):
    """rig demo's twin: the whole-profile fit saw a second basin 1.4 nm away, FL2's measured lines
    then decided the mapping — the result warned "ambiguous … shoot a fluorescent lamp" about a
    run that had one. The lines' mapping carries no ambiguity warning; the fit's is recorded."""
    import calib.wavelength.locate as locate

    observations = _halophosphate_and_led(camera, 1.5, 0.4)
    basin_warning = "the mapping is ambiguous: a second basin 1.4 nm away (forced)"

    def two_basins(*args, **kwargs):
        found = search_profiles(*args, **kwargs)
        return replace(found, warnings=(*found.warnings, basin_warning))

    monkeypatch.setattr(locate, "search_profiles", two_basins)
    solution = locate_mapping(observations, prior, DEFAULT_GRID)
    assert solution.details["measured_lines"] is True
    assert basin_warning not in solution.warnings
    assert "mapping_ambiguous" not in solution.details["warning_codes"]
    assert basin_warning in solution.details["profile_fit_warnings"]
    # A line fit its checks refuse still decides, and says so.

    def refuse(*args, **kwargs):
        raise EstimationError("forced: the line fit is refused")

    monkeypatch.setattr(locate, "_check_line_fit", refuse)
    refused = locate_mapping(observations, prior, DEFAULT_GRID)
    assert "measured_lines" not in refused.details  # (the disagreement warning stays armed)
    assert refused.details["line_checks_failed"] == "forced: the line fit is refused"
    assert basin_warning not in refused.warnings
    # Where no line fit exists (the camera finds none of the lines), the profile fit stands and
    # its warning with it, coded as an ambiguity.

    def no_lines(*args, **kwargs):
        raise EstimationError("forced: no line matches held")

    monkeypatch.setattr(locate, "_measured_lines", no_lines)
    fitted = locate_mapping(observations, prior, DEFAULT_GRID)
    assert fitted.details["measured_lines_failed"] == "forced: no line matches held"
    assert basin_warning in fitted.warnings
    assert "mapping_ambiguous" in fitted.details["warning_codes"]


def test_the_mapping_fit_widens_sigma_where_the_list_or_where_the_model_is_short() -> None:
    from calib.wavelength.families import QuadraticFamily
    from calib.wavelength.features import _fit_with_model_scatter

    family = QuadraticFamily((0.0, 1000.0))
    pixels = np.linspace(50.0, 950.0, 10)
    quadratic = 400.0 + 0.3 * pixels + 2e-5 * pixels**2
    sharp = np.arange(10) % 3 == 0  # 4 sharp lines (σ 0.02 nm), 6 broad ones (σ 0.3 nm)
    stated = np.where(sharp, 0.02, 0.3)
    used = np.ones(10, dtype=bool)
    x0 = family.parameters(QuadraticMapping(2e-5, 0.3, 400.0))
    # The list is short: the broad lines sit ±0.6 nm off their listed places, the sharp ones
    # exactly on a quadratic. Every σ is scaled alike and the fit still passes the sharp lines.
    listed = quadratic + np.where(sharp, 0.0, 0.6 * (-1.0) ** np.arange(10))
    x, _, sigma = _fit_with_model_scatter(family, x0, pixels, listed, stated, used)
    np.testing.assert_allclose(sigma / stated, sigma[0] / stated[0], rtol=1e-9)
    assert sigma[0] > stated[0]
    assert np.max(np.abs(family.wavelengths(pixels, x) - quadratic)[sharp]) < 0.15
    # The model is short: a cubic field term the quadratic lacks, seen by every line alike. One
    # scatter is added to every σ, so the sharp lines' σ grow by a larger factor.
    cubic = quadratic + 4e-9 * (pixels - 500.0) ** 3
    _, _, sigma = _fit_with_model_scatter(family, x0, pixels, cubic, stated, used)
    widening = sigma / stated
    assert widening[sharp].min() > 2.0 * widening[~sharp].max()


# ------------------------------------------------- lines a lamp shows; lines too few to hold


def test_only_the_lines_a_measured_spectrum_shows_are_kept():
    """The twin's FL2 has Hg 404.7, 435.8, 546.1 and the 577/579 doublet, not 407.8 or 491.6 (a
    CIE table's bins hold only those): a camera feature matched to 491.6 there was a phosphor's
    shape 1.0–2.2 nm off, and 407.8 moved the 404.7 blend's centre by 0.24 nm. A lamp that has a
    line at its listed share keeps it."""
    from calib.wavelength.features import lines_shown

    hg = line_list("hg")
    lamp = _halophosphate(2.5)
    for bandwidth_nm, step_nm in ((1.5, 0.4), (4.0, 1.0)):
        measured = _measured(lamp, bandwidth_nm, step_nm)
        shown = lines_shown(measured.wavelength_nm, measured.values, hg, bandwidth_nm)
        assert {line.label for line in shown} == {
            "Hg 404.7",
            "Hg 435.8",
            "Hg 546.1",
            "Hg 577.0",
            "Hg 579.1",
        }
    # 491.6 at its listed share of 435.8 (80 : 4000), which the lamp above draws 2.5 × its band.
    sigma = 0.5 / 2.355
    peak = float(lamp.values.max())
    with_491 = Spectrum(
        lamp.wavelength_nm,
        lamp.values + 0.02 * peak * np.exp(-0.5 * ((lamp.wavelength_nm - 491.607) / sigma) ** 2),
    )
    measured = _measured(with_491, 1.5, 0.4)
    shown = lines_shown(measured.wavelength_nm, measured.values, hg, 1.5)
    assert "Hg 491.6" in {line.label for line in shown}


@pytest.mark.slow
def test_a_measured_lamps_table_has_no_line_the_lamp_lacks(camera, prior):
    """The twin-like case end to end: a camera slit wide enough to blend 404.7 with 407.8 (which
    the lamp lacks); the matched-line table holds the lamp's lines only."""
    observations = _halophosphate_and_led(camera, 4.0, 1.0, slit_width_px=6.0)
    solution = locate_mapping(observations, prior, DEFAULT_GRID)
    labels = {row["line"] for row in solution.matched_lines}
    assert "Hg 404.7" in labels
    assert not any("407.8" in label or "491.6" in label for label in labels)


def test_a_line_spread_narrower_than_two_samples_is_not_one_sample_wide():
    """A 0.19/0.60/0.19 line spread (FWHM ≈ 1.5 samples) has one sample above half its maximum;
    a feature fit one sample wide has too few samples (the validation split's Nikon D40 failed)."""
    from calib.wavelength.locate import MIN_FWHM_PX, fwhm_px

    observation = LampObservation(
        name="FL2",
        pixel=np.arange(10.0),
        profile=np.ones((10, 3)),
        spectrum=lamp_from_spec("FL2"),
        line_spread=np.array([0.0, 0.007, 0.193, 0.599, 0.193, 0.007, 0.0]),
    )
    assert fwhm_px(observation) == MIN_FWHM_PX


def _two_line_profile(camera: MultiSpectrum) -> LampObservation:
    """Hg 435.8 and 546.1 alone (the rest of the list too dim to show) through :data:`_RIG_TRUTH`."""
    hg = builtin_lamp("builtin:hg")
    near = np.min(np.abs(hg.wavelength_nm[:, None] - np.array([435.83, 546.07])), axis=1) < 3.0
    lamp = Spectrum(hg.wavelength_nm, np.where(near, hg.values, 0.0), name="builtin:hg")
    return _physical_profile(
        lamp,
        camera,
        _RIG_TRUTH,
        3,
        pixel=_RIG_PIXEL,
        slit_width_px=2.0,
        psf_sigma_px=0.8,
        kind="fluorescent",
    )


def test_too_few_lines_correct_a_profile_fit_they_are_anchored_to(camera):
    """Two lines cannot hold the grating family (three free parameters): alone they are refused.
    Anchored to a whole-profile fit (here the truth 1.5 nm off at the ends, stated σ 1 nm), the
    joint fit passes through the lines and follows the anchor elsewhere, within its σ."""
    from calib.wavelength.features import ProfileAnchor

    observation = _two_line_profile(camera)
    pixel = observation.pixel
    family = GratingFamily(grating_prior(focal_length_px=2500.0, incidence_sigma_deg=5.0))
    truth_nm = _RIG_TRUTH.wavelength_nm(pixel)
    # The profile fit: the truth stretched about its middle, ±1.5 nm at the ends, stated σ 1 nm
    # at its ends and middle (independently).
    tilt = 1.5 * (pixel - pixel.mean()) / (0.5 * np.ptp(pixel))
    fit = QuadraticMapping.fit(pixel, truth_nm + tilt)
    ends = np.array([pixel[0], pixel.mean(), pixel[-1]])
    anchor = ProfileAnchor(ends, fit.wavelength_nm(ends), np.eye(3))
    arguments = {"family": family, "fwhm_px": 2.5, "start": fit}
    hg = line_list("hg")
    with pytest.raises(EstimationError):
        map_features(pixel, observation.profile, hg, **arguments)  # type: ignore[arg-type]
    found = map_features(pixel, observation.profile, hg, anchor=anchor, **arguments)  # type: ignore[arg-type]
    table = {row["line"]: row for row in found.table()}
    assert set(table) == {"Hg 435.8", "Hg 546.1"}
    for row in table.values():
        assert abs(row["residual_nm"]) < 0.05
    error = found.exact.wavelength_nm(pixel) - truth_nm
    assert float(np.max(np.abs(error))) < 2.0 * 1.5
    # The lines moved the fit towards the truth between them.
    between = (truth_nm > 436.0) & (truth_nm < 546.0)
    assert float(np.max(np.abs(error[between]))) < 0.5 * float(np.max(np.abs(tilt[between])))


@pytest.mark.slow
def test_a_listed_lamp_with_too_few_lines_is_mapped_jointly_with_a_measured_one(camera, prior):
    """Issue 16's "A + FL unmeasured, no direct" failures: an Hg lamp nobody measured
    (``builtin:hg``) that shows two lines, and a halogen lamp with its spectrum. The lines alone
    cannot hold the grating; anchored to the halogen's whole-profile fit they correct it, and the
    stated σ holds the result over the grid."""
    lines = replace(
        _two_line_profile(camera), spectrum=builtin_lamp("builtin:hg"), pixel_origin="direct_spot"
    )
    halogen = render_observation(
        lamp_from_spec("A"),
        camera,
        mapping=_RIG_TRUTH,
        pixel=_RIG_PIXEL,
        slit_width_px=2.0,
        psf_sigma_px=0.8,
        noise=PeakFractionNoise(0.002),
        rng=np.random.default_rng(4),
        fine_step_nm=0.05,
        kind="halogen",
    ).observation
    halogen = replace(halogen, spectrum_bandwidth_nm=1.0, pixel_origin="direct_spot")
    with pytest.raises(EstimationError, match="could not be matched"):
        locate_mapping([lines], prior, DEFAULT_GRID)
    solution = locate_mapping([lines, halogen], prior, DEFAULT_GRID)
    assert "anchored to the whole-profile fit of" in solution.details["line_source"]
    assert {row["line"] for row in solution.matched_lines} == {"Hg 435.8", "Hg 546.1"}
    pixel = _RIG_PIXEL
    truth_nm = _RIG_TRUTH.wavelength_nm(pixel)
    inside = (truth_nm >= DEFAULT_GRID.start_nm) & (truth_nm <= DEFAULT_GRID.stop_nm)
    covariance = np.asarray(solution.mapping.covariance)
    design = np.stack([pixel**2, pixel, np.ones_like(pixel)], axis=1)
    sigma = np.sqrt(np.einsum("ij,jk,ik->i", design, covariance, design))
    error = solution.mapping.wavelength_nm(pixel) - truth_nm
    assert np.all(np.abs(error[inside]) <= 2.0 * sigma[inside])
    assert float(np.max(np.abs(error[inside]))) < 1.0


@pytest.mark.parametrize("miss_px", [2.0, 2.5])
def test_a_line_missed_by_more_than_its_width_is_found_when_restarted(miss_px):
    """Decision 0093: a line 2 px (1.6 σ of a 3 px FWHM) from where the start puts it: fitted from
    the predicted place, the background takes the line and the Gaussian settles on a dip (the
    feature is dropped); restarted half a FWHM to either side, it is found where it is."""
    hg = [line for line in line_list("hg") if abs(line.wavelength_nm - 435.83) < 0.1]
    pixel = np.arange(380.0, 500.0)
    identity = QuadraticMapping(0.0, 1.0, 0.0, pixel_range=(380.0, 499.0))
    fwhm = 3.0
    sigma = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    band = 5.0 * (1.0 + 0.002 * (pixel - 440.0) - 0.0005 * (pixel - 440.0) ** 2)
    signal = band + 10.0 * np.exp(-0.5 * ((pixel - 435.83 - miss_px) / sigma) ** 2)
    features = blends(hg, fwhm)
    kept = fit_features(pixel, signal, 0.02, features, identity, fwhm, background_order=2)
    assert kept == []
    found = fit_features(
        pixel, signal, 0.02, features, identity, fwhm, background_order=2, restart=True
    )
    assert len(found) == 1
    assert abs(found[0].centroid_px - (435.83 + miss_px)) < 0.05


def test_a_line_narrower_than_three_samples_is_fitted_over_enough_samples(monkeypatch):
    """Decision 0192: a mosaic's profile comes in 2 px cells, and a 3 px slit image is then 1.5
    samples wide: ±2 FWHM held 7 samples, too few for a quadratic background with the line's
    height, shift and width, and the line was dropped (the twin's Canon 300D: 1 of 5 Hg features
    found, the mapping left 0.6 nm off). The window holds at least 5 samples a side."""
    from scipy.special import erf

    import calib.wavelength.features as features_module

    hg = [line for line in line_list("hg") if abs(line.wavelength_nm - 435.83) < 0.1]
    pixel = np.arange(380.0, 500.0, 2.0)
    identity = QuadraticMapping(0.0, 1.0, 0.0, pixel_range=(380.0, 498.0))
    fwhm = 3.0
    sigma = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    centre = 435.83 + 0.4
    # each cell's mean over its 2 px, as a sensor's cell integrates the line
    cell = 0.5 * (
        erf((pixel + 1.0 - centre) / (math.sqrt(2.0) * sigma))
        - erf((pixel - 1.0 - centre) / (math.sqrt(2.0) * sigma))
    )
    band = 5.0 * (1.0 + 0.002 * (pixel - 440.0) - 0.0005 * (pixel - 440.0) ** 2)
    signal = band + 10.0 * cell
    features = blends(hg, fwhm)
    found = fit_features(
        pixel, signal, 0.02, features, identity, fwhm, background_order=2, restart=True
    )
    assert len(found) == 1
    assert abs(found[0].centroid_px - centre) < 0.1
    monkeypatch.setattr(features_module, "WINDOW_MIN_SAMPLES", 0.0)  # ±2 FWHM alone, as before
    assert (
        fit_features(
            pixel, signal, 0.02, features, identity, fwhm, background_order=2, restart=True
        )
        == []
    )
