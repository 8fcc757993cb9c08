"""calib.wavelength.find_mapping: the pixel→wavelength mapping from fluorescent lines and broadband lamps."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.errors import EstimationError, InputError
from calib.core.lamp_specs import colour_lamp, lamp_from_spec
from calib.core.mapping import QuadraticMapping, TiltedGrating
from calib.core.metrics import mapping_relative_error
from calib.core.observations import LampObservation, robust_noise_sigma
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.evaluation.synthetic import random_efficiency
from calib.model.bases import CameraPrior, fallback_camera_basis
from calib.model.forward import PeakFractionNoise, pixel_edges, render_observation
from calib.wavelength import find_mapping, least_squares, profile_search
from calib.wavelength.families import GratingFamily, GratingPrior, QuadraticFamily
from calib.wavelength.locate import locate_mapping
from calib.wavelength.peaks import fluorescent_starts, lines_and_peaks
from calib.wavelength.profile_search import (
    AMBIGUITY_DELTA_CHI2,
    AMBIGUITY_MIN_DISTANCE_NM,
    BROADBAND_AMBIGUITY_DELTA_CHI2,
    DECIDING_LOCAL_INCIDENCE_DEG,
    DECIDING_LOCAL_SCAN,
    MISFIT_WARN_TEMPER,
    PRIOR_MISFIT_COHERENCE,
    RED_EDGE_MARGIN_NM,
    _end_points,
    _local_end_points,
    bin_pixels,
    prior_misfit_sigma_nm,
    red_edge_nm,
)
from calib.wavelength.response_model import ResponseModel
from calib.wavelength.rig_prior import default_prior

TRUTH = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))


@pytest.fixture(scope="module")
def prior() -> CameraPrior:
    return fallback_camera_basis(exclude=["Canon EOS 5D Mark II"]).prior()


@pytest.fixture(scope="module")
def camera() -> MultiSpectrum:
    return find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity


@pytest.fixture(scope="module")
def nikon() -> tuple[CameraPrior, MultiSpectrum]:
    """A camera the offline prior fits badly (NPL measurement, 5 nm structure)."""
    prior = fallback_camera_basis(exclude=["Nikon 5100"]).prior()
    return prior, find_camera(colour_science_cameras(), "Nikon 5100 (NPL)").sensitivity


def _render(
    lamp_name: str, camera: MultiSpectrum, noise: float = 0.0, seed: int = 3, kind: str = "led"
) -> LampObservation:
    rng = np.random.default_rng(seed)
    rendered = render_observation(
        colour_lamp(lamp_name),
        camera,
        mapping=TRUTH,
        pixel=800,
        grating_efficiency=random_efficiency(np.random.default_rng(11)),
        noise=PeakFractionNoise(noise) if noise else None,
        rng=rng,
        kind=kind,  # type: ignore[arg-type]
    )
    return rendered.observation


def _mapping_re(mapping: QuadraticMapping) -> float:
    pixels = np.arange(800.0)
    truth = TRUTH.wavelength_nm(pixels)
    inside = (truth >= 400) & (truth <= 700)
    return mapping_relative_error(mapping.wavelength_nm(pixels[inside]), truth[inside])


@pytest.mark.parametrize(("lamp", "noise", "limit"), [("D65", 0.0, 5e-4), ("LED-B3", 0.01, 4e-3)])
def test_broadband_lamp_alone(prior, camera, lamp, noise, limit):
    mapping = find_mapping([_render(lamp, camera, noise)], camera=prior)
    assert _mapping_re(mapping) < limit
    assert mapping.details["origin"].startswith("correlation search")
    assert mapping.wavelength_rms_nm is not None and mapping.wavelength_rms_nm > 0


@pytest.mark.parametrize("which", ["canon", "nikon"])
def test_fluorescent_lines_and_led_jointly(prior, camera, nikon, which):
    if which == "nikon":
        prior, camera = nikon
    lamps = [_render("FL2", camera, 0.01, kind="fluorescent"), _render("LED-B3", camera, 0.01)]
    mapping = find_mapping(lamps, camera=prior)
    assert mapping.details["origin"] == "lines of FL2"
    assert mapping.details["mapping_lamps"] == ["FL2", "LED-B3"]
    # The NPL-measured Nikon is far from the offline prior's curves: looser, but still < 1 %.
    assert _mapping_re(mapping) < (2e-3 if which == "canon" else 1e-2)
    # Lines pin the mapping: the ambiguity threshold stays the line lamps' (decision 0094).
    assert mapping.details["ambiguity_delta_chi2"] == AMBIGUITY_DELTA_CHI2


def test_basins_far_behind_lines_are_costed_not_refined(prior, camera, monkeypatch):
    """Decision 0065: with a line lamp, scan basins far behind the best are only costed in the
    deciding stage — the same answer and the same candidates as refining them, fewer
    evaluations, and those candidates are still far behind."""
    lamps = [_render("FL2", camera, 0.01, kind="fluorescent"), _render("D65", camera, 0.01)]
    pruned = profile_search.search_profiles(lamps, prior, DEFAULT_GRID)
    threshold = profile_search.HOPELESS_DELTA_CHI2
    monkeypatch.setattr(profile_search, "HOPELESS_DELTA_CHI2", np.inf)
    refined = profile_search.search_profiles(lamps, prior, DEFAULT_GRID)
    pixel = np.arange(800.0)
    np.testing.assert_array_equal(
        pruned.mapping.wavelength_nm(pixel), refined.mapping.wavelength_nm(pixel)
    )
    assert pruned.mapping.wavelength_rms_nm == refined.mapping.wavelength_rms_nm
    assert len(pruned.candidates) == len(refined.candidates) == 3
    assert pruned.details["evaluations"] < refined.details["evaluations"]
    # The close runner-up (Δχ² 29 here, near the ambiguity threshold) is refined as before; the
    # far one is costed where the scan left it: its Δχ² an upper bound, still far behind.
    close = [c.delta_chi2 for c in refined.candidates if c.delta_chi2 < threshold]
    assert [c.delta_chi2 for c in pruned.candidates[: len(close)]] == close
    far = zip(pruned.candidates[len(close) :], refined.candidates[len(close) :], strict=True)
    assert all(kept.delta_chi2 >= full.delta_chi2 > threshold for kept, full in far)


def test_a_start_far_off_is_corrected_by_the_search(prior, camera):
    """A given start 8 nm off at both ends (a rough geometry guess) still lands on the truth."""
    start = QuadraticMapping(TRUTH.a, TRUTH.b, TRUTH.c + 8.0, pixel_range=TRUTH.pixel_range)
    mapping = find_mapping([_render("D65", camera)], camera=prior, start=start)
    assert mapping.details["origin"] == "given start"
    assert _mapping_re(mapping) < 5e-4


def test_a_profile_missing_part_of_the_first_order_is_refused(prior, camera):
    observation = _render("D65", camera)
    keep = TRUTH.wavelength_nm(observation.pixel) < 600
    cut = replace(observation, pixel=observation.pixel[keep], profile=observation.profile[keep])
    with pytest.raises(EstimationError, match="not covering the grid"):
        find_mapping([cut], camera=prior)


def test_lamps_on_different_pixel_axes_are_refused_naming_each_axis(prior, camera):
    """The refusal names each lamp's pixels and what to do (it said only 'different pixel
    axes; extract them with one geometry')."""
    observation = replace(_render("D65", camera), name="D65")
    shifted = replace(observation, name="other", pixel=observation.pixel + 3.0)
    first, last, size = observation.pixel[0], observation.pixel[-1], observation.n_pixels
    with pytest.raises(InputError) as raised:
        find_mapping([observation, shifted], camera=prior)
    assert str(raised.value) == (
        f"profiles: the lamps' profiles are on different pixel axes (D65: px {first:g}–"
        f"{last:g}, {size} samples; other: px {first + 3:g}–{last + 3:g}, {size} samples); one "
        "mapping needs one axis: export every lamp's profile over the same pixels (one crop and "
        "geometry), or give the profiles in wavelength_nm"
    )


def test_binning_keeps_the_truth_the_best_fit(prior, camera):
    """Merged pixels integrate over merged wavelength intervals: the model stays exact when binned."""
    observation = _render("D65", camera, 0.002)
    shifted = QuadraticMapping(TRUTH.a, TRUTH.b, TRUTH.c + 2.0, pixel_range=TRUTH.pixel_range)
    for factor in (1, 4):
        binned = bin_pixels(observation, factor)
        assert binned.n_pixels == 800 // factor
        model = ResponseModel.build(
            binned, DEFAULT_GRID, node_step_nm=5.0, prior=prior, flexibility=0.05
        )
        edges = pixel_edges(binned.pixel)
        truth, off = model.costs(
            np.stack([TRUTH.wavelength_nm(edges), shifted.wavelength_nm(edges)])
        )
        assert truth < off / 3


def test_robust_noise_sigma_measures_white_noise(rng):
    signal = np.stack([np.sin(np.linspace(0, 6, 2000)) * k for k in (1.0, 2.0, 3.0)], axis=1)
    noisy = signal + rng.normal(0.0, [0.01, 0.02, 0.03], size=signal.shape)
    np.testing.assert_allclose(robust_noise_sigma(noisy), [0.01, 0.02, 0.03], rtol=0.1)


def test_paper_icp_reproduces_its_error_level_and_ours_beats_it(prior, camera):
    """The paper's LED-only ICP reports 2.1–2.3 % mapping RE; ours is an order of magnitude lower."""
    observation = _render("D65", camera)
    paper = _mapping_re(find_mapping([observation], camera=prior, method="icp"))
    ours = _mapping_re(find_mapping([observation], camera=prior))
    assert 2e-3 < paper < 6e-2
    assert ours < paper / 10


@pytest.mark.slow
@pytest.mark.shared_data
def test_a_camera_unlike_the_prior_does_not_pull_the_led_mapping_to_an_alias(shared_camera_data):
    """Olympus E-PL2 under D65 at 1 % noise (the protocol's scene; camera 1, repeat 1).

    The stiff prior of the old local stage preferred the mapping 10 nm off (D65's tabulation
    spacing), where the response looks more like the training cameras': mapping RE 3.4 %, with an
    error estimate of 0.04 %.
    """
    from calib.core.datasets import makabe2025_split
    from calib.evaluation.synthetic import render_scene
    from calib.model.bases import default_camera_basis

    _train, test = makabe2025_split(shared_camera_data)
    basis = default_camera_basis(data_dir=shared_camera_data, exclude=[r.name for r in test])
    olympus = next(r for r in test if r.camera == "Olympus EPL2")
    scene = render_scene(
        olympus.camera,
        olympus.sensitivity,
        np.random.default_rng([0, 1, 0, 1]),
        broadband_lamp=colour_lamp("D65"),
        fluorescent_lamp=colour_lamp("FL2"),
        noise_fraction=0.01,
    )
    observation = scene.broadband.observation
    mapping = find_mapping([observation], camera=basis.prior())
    truth = scene.mapping.wavelength_nm(observation.pixel)
    inside = (truth >= 400) & (truth <= 700)
    error = mapping_relative_error(mapping.wavelength_nm(observation.pixel[inside]), truth[inside])
    assert error < 5e-3


def test_the_physical_scan_draws_gratings_through_the_ends_it_asks_for():
    """With the 0th order pinned, each (first, last wavelength, incidence) of the scan is one
    grating through exactly those ends at that incidence (the focal length solved for), and the
    scan's ends cover the working grid with a band the camera may see beyond it."""
    family = GratingFamily(default_prior(True), orientation=1)
    pixel_range = (308.0, 922.0)
    left, right = np.meshgrid([381.1, 392.0], [737.8, 760.0], indexing="ij")
    points = _end_points(family, pixel_range, left, right, (-8.0, 0.0, 7.4))
    assert points.shape == (2, 2, 3, len(family.names))
    assert np.all(np.isfinite(points))
    for i, j, k in np.ndindex(2, 2, 3):
        ends = family.wavelengths(np.array(pixel_range), points[i, j, k])
        np.testing.assert_allclose(ends, [left[i, j], right[i, j]], atol=1e-6)
        incidence = points[i, j, k, family.names.index("incidence_deg")]
        assert incidence == pytest.approx((-8.0, 0.0, 7.4)[k], abs=0.1)
    # A focal length held by the prior: one grating per pair of ends.
    held = GratingFamily(
        GratingPrior({"zero_order_px": (0.0, 0.0), "log_focal": (np.log(726.0), 0.0)}), 1
    )
    points = _end_points(held, pixel_range, left, right, (-8.0, 0.0, 8.0))
    assert points.shape[2] == 1
    np.testing.assert_allclose(
        held.wavelengths(np.array(pixel_range), points[0, 0, 0]), [381.1, 737.8], atol=1e-6
    )


def _short_lens_led(camera: MultiSpectrum) -> tuple[TiltedGrating, np.ndarray, LampObservation]:
    """LED-B3 through validation's Pentax Q geometry (a 726 px focal length, 7.4° incidence,
    990 lines/mm), 0.5 % noise: the grating, the pixels and the observation."""
    truth = TiltedGrating(1010.4 / 726.0, 726.0, 7.39)
    pixel = np.arange(308.0, 923.0)
    observation = render_observation(
        lamp_from_spec("LED-B3"),
        camera,
        mapping=truth,
        pixel=pixel,
        noise=PeakFractionNoise(0.005),
        rng=np.random.default_rng(5),
        kind="led",
    ).observation
    return truth, pixel, observation


def test_a_short_lens_led_profile_from_the_spot_finds_its_basin(prior, camera, monkeypatch):
    """Validation's Pentax Q geometry (a 726 px focal length, 7.4° incidence, 990 lines/mm): the
    correlation search's starts were 100 nm off at the red end and the old scan over focal
    lengths a factor 1.5 apart landed 12 nm off; the scan over the ends reaches the truth. No
    batch of trial mappings is costed twice in one stage (decision 0076: the follow rule's fine
    grids were)."""
    truth, pixel, observation = _short_lens_led(camera)
    observation = replace(observation, pixel_origin="direct_spot")
    costs = profile_search.StageFit.costs
    seen: list[tuple[int, bytes]] = []

    def recorded(self: profile_search.StageFit, x: np.ndarray) -> np.ndarray:
        if np.atleast_2d(x).shape[0] > 1:
            seen.append((id(self.models), np.asarray(x).tobytes()))
        return costs(self, x)

    monkeypatch.setattr(profile_search.StageFit, "costs", recorded)
    solution = locate_mapping([observation], prior, DEFAULT_GRID)
    assert seen and len(set(seen)) == len(seen)
    true_nm = truth.wavelength_nm(pixel)
    inside = (true_nm >= 400) & (true_nm <= 700)
    error = solution.mapping.wavelength_nm(pixel[inside]) - true_nm[inside]
    assert solution.details["family"] == "grating"
    assert np.max(np.abs(error)) < 2.0


def test_a_red_end_stretched_beyond_the_prior_is_flagged(prior, camera):
    """Where an LED's signal ends is the camera's IR cut-off under the lamp, which the prior knows:
    under the true mapping the profile's red edge is within the margin of the prior mean's, under
    one stretched 30 nm at the red end it is beyond it (the failures of decision 0049); the right
    mapping of a search carries the comparison and no warning."""
    truth, pixel, observation = _short_lens_led(camera)
    true_nm = truth.wavelength_nm(pixel)
    found, expected, _ = red_edge_nm(observation, truth, prior) or (np.nan, np.nan, np.nan)
    assert abs(found - expected) < RED_EDGE_MARGIN_NM
    stretch = 30.0 * (pixel - pixel[0]) / (pixel[-1] - pixel[0])
    stretched = QuadraticMapping.fit(pixel, true_nm + stretch)
    edge = red_edge_nm(observation, stretched, prior)
    assert edge is not None and edge[0] - edge[1] > RED_EDGE_MARGIN_NM
    assert edge[1] == expected  # the prior's edge does not depend on the mapping
    # A profile with no signal has no edge.
    dark = replace(observation, profile=np.zeros_like(observation.profile))
    assert red_edge_nm(dark, truth, prior) is None


def test_the_prior_misfit_sigma_is_the_curvature_under_the_fits_excess_misfit():
    """Decision 0117: nothing where the prior describes the profile down to its noise (reduced
    χ² ≤ 1), the curvature σ times the coherence times √(χ²ᵣ − 1) where not — wider for a camera
    fitted worse and for a profile that pins the mapping less."""
    assert prior_misfit_sigma_nm(0.3, 0.05) == 0.0
    assert prior_misfit_sigma_nm(1.0, 0.05) == 0.0
    assert prior_misfit_sigma_nm(5.0, 0.05) == pytest.approx(2.0 * PRIOR_MISFIT_COHERENCE * 0.05)
    assert prior_misfit_sigma_nm(10.0, 0.05) > prior_misfit_sigma_nm(5.0, 0.05)
    assert prior_misfit_sigma_nm(5.0, 0.1) == pytest.approx(2.0 * prior_misfit_sigma_nm(5.0, 0.05))


def test_a_profile_the_prior_fits_badly_warns_and_widens_sigma(prior, camera, monkeypatch):
    """Decision 0054: a camera the prior fits well is not warned about (the short-lens LED's fit
    has a reduced χ² near 1); when the deciding fit's reduced χ² is above the threshold (lowered
    here below this one's, as a camera unlike the prior would raise it) the result carries an
    ambiguity warning and a σ that reaches the nearest other basin and holds the misfit term."""
    _truth, pixel, observation = _short_lens_led(camera)
    observation = replace(observation, pixel_origin="direct_spot")
    quiet = locate_mapping([observation], prior, DEFAULT_GRID)
    temper = quiet.details["temper"]
    assert temper < MISFIT_WARN_TEMPER
    assert not quiet.ambiguous and quiet.warnings == ()
    # A broadband lamp alone: a basin within the wider threshold would be an ambiguity (decision
    # 0094), so every other basin apart from this one stands beyond it.
    assert quiet.details["ambiguity_delta_chi2"] == BROADBAND_AMBIGUITY_DELTA_CHI2
    assert BROADBAND_AMBIGUITY_DELTA_CHI2 > AMBIGUITY_DELTA_CHI2
    for other in quiet.details["candidates"][1:]:
        if other["rms_distance_nm"] > AMBIGUITY_MIN_DISTANCE_NM:
            assert other["delta_chi2"] >= BROADBAND_AMBIGUITY_DELTA_CHI2
    stated = quiet.mapping.wavelength_rms_nm
    assert stated is not None
    # The pull also holds the coarser view's disagreement with the answer (decision 0128).
    view = quiet.details["coarse_view"]["delta_chi2"]
    pull = prior_misfit_sigma_nm(temper, quiet.details["local_rms_nm"], view)
    assert stated >= pull
    assert quiet.details["prior_misfit_sigma_nm"] == pytest.approx(pull)
    monkeypatch.setattr(profile_search, "MISFIT_WARN_TEMPER", 0.5)
    warned = locate_mapping([observation], prior, DEFAULT_GRID)
    assert warned.ambiguous
    (sentence,) = [w for w in warned.warnings if "fits LED-B3's profile badly" in w]
    assert warned.details["warning_codes"][list(warned.warnings).index(sentence)] == (
        "mapping_ambiguous"
    )
    others = [c["rms_distance_nm"] for c in warned.details["candidates"][1:]]
    assert others, "the short-lens scene has competing basins"
    widened = warned.mapping.wavelength_rms_nm
    assert widened is not None and widened >= 0.5 * min(others) - 1e-9
    # The mapping itself is the same: the warning and σ change, not the answer.
    np.testing.assert_allclose(
        warned.mapping.wavelength_nm(pixel), quiet.mapping.wavelength_nm(pixel), atol=1e-9
    )


def test_the_deciding_stage_scans_the_ends_around_each_basin():
    """Decision 0071: around a deciding basin, gratings whose profile ends lie on a grid about the
    basin's (every pair of shifts of :data:`DECIDING_LOCAL_SCAN`) at incidences about its own."""
    family = GratingFamily(default_prior(True), orientation=1)
    pixel_range = (308.0, 922.0)
    left, right = np.meshgrid([381.1], [737.8], indexing="ij")
    (x,) = _end_points(family, pixel_range, left, right, (3.0,)).reshape(-1, len(family.names))
    points = _local_end_points(family, x, pixel_range)
    half, step = DECIDING_LOCAL_SCAN
    shifts = np.arange(-half, half + 0.5 * step, step)
    assert points.shape == (shifts.size**2 * len(DECIDING_LOCAL_INCIDENCE_DEG), len(family.names))
    assert np.all(np.isfinite(points))
    ends = family.wavelengths(np.array(pixel_range), points)
    wanted = {(round(381.1 + a, 6), round(737.8 + b, 6)) for a in shifts for b in shifts}
    assert {(round(e[0], 6), round(e[1], 6)) for e in ends} == wanted
    incidences = points[:, family.names.index("incidence_deg")]
    for k in DECIDING_LOCAL_INCIDENCE_DEG:
        assert np.sum(np.abs(incidences - (3.0 + k)) < 0.1) == shifts.size**2


@pytest.mark.slow
@pytest.mark.shared_data
@pytest.mark.parametrize(
    "name",
    [
        "Nikon D1X (Solomatov-Akkaynak-2023 prediction)",
        "Phase One-P30 (Solomatov-Akkaynak-2023 prediction)",
    ],
)
def test_an_led_search_reaches_the_lower_basin_it_used_to_stop_short_of(shared_camera_data, name):
    """Decision 0071: two of validation's predicted cameras (seed 1, 400 predictions; LED only
    with the RAW files' optics) whose IR cut-off lies below the prior's, each mapped 6.9 / 8.3 nm
    off with a stated σ of 0.8 / 0.6 nm and no warning, although the truth's basin fits better at
    every stage of the search. The D1X's descent on the deciding stage's finer profile stopped in
    a minimum a few nm from the lower one (the ends scanned around it reach it); the P30's fine
    scan grid had its lowest point on its edge, 15 nm short of the truth's red end (the grid
    follows it)."""
    from calib.evaluation.validation.protocol import (
        ProtocolSettings,
        split_tasks,
    )
    from calib.evaluation.validation.splits import load_splits

    splits, _ = load_splits(shared_camera_data, predictions=400, seed=1)
    cameras = tuple(c for c in splits.validation.cameras if c.name == name)
    (task,) = split_tasks(replace(splits.validation, cameras=cameras), ProtocolSettings(seed=1))
    assert _led_only_mean_error_nm(task) < 1.0


def test_the_physical_scan_costs_no_fine_grid_twice():
    """Decision 0076: a fine grid the follow rule costed (its lowest point inside it) comes back
    with those costs, for the search to use; only a grid never costed comes back without."""
    family = GratingFamily(default_prior(True), orientation=1)
    pixel_range = (308.0, 922.0)
    target = np.array([393.0, 741.0])

    def cost(points: np.ndarray) -> np.ndarray:
        ends = family.wavelengths(np.array(pixel_range), np.nan_to_num(points, nan=0.0))
        out = np.sum((ends - target) ** 2, axis=-1)
        return np.where(np.all(np.isfinite(points), axis=1), out, np.inf)

    batches: list[int] = []

    class Scan:
        def costs(self, points: np.ndarray) -> np.ndarray:
            batches.append(points.shape[0])
            return cost(points)

    grids, count = profile_search._physical_scan(
        Scan(),  # type: ignore[arg-type]
        family,
        pixel_range,
        DEFAULT_GRID,
        follow=profile_search.PHYSICAL_FOLLOW,
    )
    # The coarse grid, then the fine grid around its one minimum, whose lowest point is inside.
    assert len(batches) == 2 and count == sum(batches)
    ((points, shape, known),) = grids
    assert known is not None and points.shape[0] == batches[1] == int(np.prod(shape))
    np.testing.assert_array_equal(known, cost(points))
    # Without the follow rule nothing is costed here: the caller scans the fine grid.
    ((_, _, unknown),) = profile_search._physical_scan(
        Scan(),  # type: ignore[arg-type]
        family,
        pixel_range,
        DEFAULT_GRID,
        follow=0,
    )[0]
    assert unknown is None and len(batches) == 3


@pytest.mark.slow
def test_a_basin_hopelessly_behind_gets_no_local_scan_in_the_deciding_stage(
    prior, camera, monkeypatch
):
    """Decision 0076: with a broadband lamp alone, the deciding stage's scan of the ends about a
    basin (decision 0071) is made for every basin not hopelessly behind the best descent; the
    short-lens scene's runner-up (Δχ² ~580) loses it when the bound is lowered below that, and
    the answer stays."""
    _truth, pixel, observation = _short_lens_led(camera)
    observation = replace(observation, pixel_origin="direct_spot")
    scans = []
    local = profile_search._local_end_points

    def counted(*args: Any, **kwargs: Any) -> Any:
        scans.append(1)
        return local(*args, **kwargs)

    monkeypatch.setattr(profile_search, "_local_end_points", counted)
    every = locate_mapping([observation], prior, DEFAULT_GRID)
    scanned = len(scans)
    assert scanned >= 2
    monkeypatch.setattr(profile_search, "HOPELESS_DELTA_CHI2", 100.0)
    del scans[:]
    fewer = locate_mapping([observation], prior, DEFAULT_GRID)
    assert len(scans) < scanned
    np.testing.assert_array_equal(
        fewer.mapping.wavelength_nm(pixel), every.mapping.wavelength_nm(pixel)
    )


@pytest.mark.slow
@pytest.mark.shared_data
@pytest.mark.parametrize(
    "name", ["Canon 1D-Mk-III (Jiang-et-al-2013)", "Canon 1Ds-Mk-II (Brady-2009)"]
)
def test_an_led_search_weighs_a_red_end_pulled_in_below_the_priors_edge(shared_camera_data, name):
    """Decision 0085: two validation cameras (seed 3, LED only with the RAW files' optics) behind a
    blue colour filter (a step at 580 nm) end their signal 20–40 nm below the prior mean's edge;
    the scan leaned on the prior's edge and the search stretched the red end 30–45 nm, 18.6 / 10.6
    nm off with a stated σ of 0.7 nm and no warning, although the truth's basin fits the deciding
    stage far better. The red end pulled in below the found edge is now weighed and taken."""
    from calib.evaluation.validation.protocol import (
        ProtocolSettings,
        split_tasks,
    )
    from calib.evaluation.validation.splits import load_splits

    splits, _ = load_splits(shared_camera_data, seed=3)
    (camera,) = (c for c in splits.validation.cameras if c.name == name)
    axis = camera.sensitivity.wavelength_nm
    filtered = (
        camera.sensitivity.values * (0.12 + 0.8 / (1.0 + np.exp((axis - 580.0) / 25.0)))[:, None]
    )
    behind = MultiSpectrum(axis, filtered / filtered.max(), name=f"{name} behind a blue filter")
    cameras = (replace(camera, sensitivity=behind),)
    (task,) = split_tasks(replace(splits.validation, cameras=cameras), ProtocolSettings(seed=3))
    assert _led_only_mean_error_nm(task) < 1.0


def _led_only_mean_error_nm(task: Any) -> float:
    """The protocol's LED-only scene of ``task`` mapped by the search alone: its mean |error| (nm)."""
    return _led_only_solution(task)[0]


def test_a_stage_fits_validity_for_one_point_is_its_batch_validity(prior, camera, monkeypatch):
    # One point is judged by the family alone in StageFit.function (decision 0096); the batch
    # path maps NaN to ∞ and masks non-finite rows. Both must agree on every kind of point.
    truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 399.0))
    lamp = render_observation(
        colour_lamp("LED-B3"),
        camera,
        mapping=truth,
        pixel=400,
        rng=np.random.default_rng(0),
    ).observation
    family = QuadraticFamily((0.0, 399.0))
    fit = profile_search._stage(
        [lamp],
        family,
        DEFAULT_GRID,
        prior,
        bin_nm=2.0,
        nm_per_px=0.43,
        kernel=None,
        node_step_nm=20.0,
        flexibility=1.0,
        sigma_floor=0.0,
        pixel_range=(0.0, 399.0),
    )
    good = family.parameters(truth)
    points = [
        good,
        good[::-1].copy(),  # falling: valid
        np.array([400.0, 700.0, 450.0]),  # folds back: invalid
        np.array([np.nan, 550.0, 700.0]),
        np.array([383.0, np.inf, 700.0]),
        np.array([-np.inf, 550.0, 700.0]),
    ]
    for point in points:
        assert (fit.function(point, False) is not None) == bool(fit.valid(point)[0])
    assert fit.function(good, False) is not None
    assert fit.function(points[2], False) is None
    # The mapping search's stage fits shorten their refused steps.
    options: list[dict[str, object]] = []
    real = least_squares.levenberg_marquardt

    def recording(*args: Any, **kwargs: Any) -> least_squares.Solution:
        options.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(profile_search, "levenberg_marquardt", recording)
    fit.refine(good + 1.0, max_iterations=2)
    assert len(options) == 2 and all(o.get("shorten") is True for o in options)


def _short_lens_fluorescent(camera: MultiSpectrum) -> tuple[TiltedGrating, LampObservation]:
    """FL2 through the short-lens geometry of :func:`_short_lens_led`, seen from its 0th order."""
    truth, pixel, _ = _short_lens_led(camera)
    observation = render_observation(
        colour_lamp("FL2"),
        camera,
        mapping=truth,
        pixel=pixel,
        noise=PeakFractionNoise(0.005),
        rng=np.random.default_rng(6),
        kind="fluorescent",
    ).observation
    return truth, replace(observation, pixel_origin="direct_spot")


def test_a_line_lamps_lines_matched_through_the_grating_equation_land_in_its_basin(
    prior, camera, monkeypatch
):
    """Decision 0097: with the 0th order pinned, FL2's lines matched to the profile's peaks
    through the grating equation (the focal length within the EXIF prior) put a short lens'
    strongly curved first order within a few nanometres of the truth over the whole profile —
    where the quadratic line matches' red end is tens of nanometres off (decision 0076,
    refusal 1) — so the scan starts from single points instead of 507-mapping end grids; with
    too few lines to stand alone the match is no start and the end grids are scanned."""
    truth, observation = _short_lens_fluorescent(camera)
    pixel_range = (float(observation.pixel[0]), float(observation.pixel[-1]))
    family = GratingFamily(
        GratingPrior(
            {
                "zero_order_px": (0.0, 0.0),
                "log_focal": (np.log(726.0 * 1.03), 0.05),
                "incidence_deg": (0.0, 5.0),
            }
        ),
        orientation=1,
    )
    probe = np.linspace(*pixel_range, 9)
    true_nm = truth.wavelength_nm(probe)
    lines, peaks, _ = lines_and_peaks(observation, prior.mean, DEFAULT_GRID)
    match = profile_search._line_match(family, lines, peaks, pixel_range)
    assert match is not None and match.unambiguous and match.matched[0] >= 3
    assert np.max(np.abs(family.wavelengths(probe, match.points[0]) - true_nm)) < 8.0
    starts = fluorescent_starts(observation, prior.mean, DEFAULT_GRID, 2)
    assert min(np.max(np.abs(s.wavelength_nm(probe) - true_nm)) for s in starts) > 15.0
    grids, matched = profile_search._line_start_grids(
        family, starts, observation, prior, DEFAULT_GRID, pixel_range
    )
    assert matched and [shape for _, shape, _ in grids] == [(7, 7, 3)] * len(match.points)
    # Two lines alone leave the geometry unconfirmed (no third line): no start, the end grids.
    two = sorted(lines, key=lambda line: -line.prominence)[:2]
    alone = profile_search._line_match(family, two, peaks, pixel_range)
    assert alone is not None and not alone.unambiguous
    monkeypatch.setattr(profile_search, "lines_and_peaks", lambda *_: (two, peaks, 0.0))
    grids, matched = profile_search._line_start_grids(
        family, starts, observation, prior, DEFAULT_GRID, pixel_range
    )
    assert not matched and [shape for _, shape, _ in grids] == [(13, 13, 3)] * len(starts)


@pytest.mark.slow
@pytest.mark.shared_data
def test_an_led_only_mapping_off_by_more_than_3_nm_on_a_dye_shifted_camera_is_warned(
    shared_camera_data,
):
    """Decision 0104: on the protocol's capture of decision 0098, a physically transformed
    validation camera (the iPhone 10 with its CFA dyes shifted +4/+2/−7 nm; seed 0, 60
    predictions, 100 transformed) is mapped 3.6 nm off from an LED alone with EXIF, its runner-up
    basin 263 behind (tempered Δχ²): silent under the threshold of 100, warned under 400."""
    from calib.evaluation.validation.protocol import ProtocolSettings, split_tasks
    from calib.evaluation.validation.splits import load_splits

    splits, _ = load_splits(shared_camera_data, predictions=60, seed=0, transformed=100)
    name = "iPhone 10 (Tominaga_etal_2021) · dyes +4/+2/-7 nm"
    (camera,) = (c for c in splits.validation.cameras if c.name == name)
    (task,) = split_tasks(replace(splits.validation, cameras=(camera,)), ProtocolSettings(seed=0))
    error_nm, solution = _led_only_solution(task)
    assert error_nm > 3.0
    assert solution.ambiguous
    assert "mapping_ambiguous" in solution.details["warning_codes"]
    assert solution.details["ambiguity_delta_chi2"] == BROADBAND_AMBIGUITY_DELTA_CHI2


def _led_only_solution(task: Any, exif_optics: bool = True) -> tuple[float, Any]:
    """The protocol's LED-only scene of ``task`` (LED-B3, with the RAW files' optics unless
    ``exif_optics`` is off) mapped by the search alone: its mean |error| in nm over the grid, and
    the search's result."""
    error, solution = led_only_errors(task, exif_optics)
    return float(np.mean(np.abs(error))), solution


def led_only_errors(task: Any, exif_optics: bool = True) -> tuple[np.ndarray, Any]:
    """:func:`_led_only_solution`'s mapping error (nm) at each pixel inside the grid, and the
    search's result."""
    from calib.evaluation.validation.protocol import (
        MethodVariant,
        render_task_scene,
        variant_observations,
    )

    scene = render_task_scene(task)
    variant = MethodVariant("LED-B3", "prior", tuple(scene.observations), exif_optics=exif_optics)
    lamps = dict(zip(scene.observations, variant_observations(scene, variant), strict=True))
    led = lamps["LED-B3"]
    grid = task.settings.grid
    solution = locate_mapping([led], task.basis.prior(), grid)
    truth = scene.true_wavelength_nm
    inside = (truth >= grid.start_nm) & (truth <= grid.stop_nm)
    return solution.mapping.wavelength_nm(led.pixel[inside]) - truth[inside], solution


def test_a_shortlisted_scan_costs_only_the_coarse_lowest_finely():
    """Decision 0105: the deepening scan is ranked on a coarser profile and only its lowest
    points are costed on the deciding one (the rest ``inf``: only the lowest point is read)."""
    points = np.arange(10.0)[:, None] * np.ones((1, 2))
    points[3] = np.nan
    batches: list[np.ndarray] = []

    class Fit:
        def __init__(self, values: np.ndarray) -> None:
            self.values = values

        def costs(self, x: np.ndarray) -> np.ndarray:
            batches.append(x)
            rows = np.nan_to_num(x[:, 0], nan=-1.0).astype(int)
            return np.where(rows >= 0, self.values[rows], np.inf)

    coarse = Fit(np.array([9.0, 1.0, 8.0, 0.0, 2.0, 7.0, 3.0, 6.0, 5.0, 4.0]))
    fine = Fit(np.array([0.0, 5.0, 0.0, 0.0, 4.0, 0.0, 6.0, 0.0, 0.0, 0.0]))
    costs, count = profile_search._shortlisted_costs(points, coarse, fine, 3)  # type: ignore[arg-type]
    # The coarse ranking's three lowest valid points (1, 4, 6), the invalid one (3) never chosen.
    assert count == 10 + 3 and len(batches) == 2 and batches[1].shape[0] == 3
    np.testing.assert_array_equal(np.flatnonzero(np.isfinite(costs)), [1, 4, 6])
    assert int(np.argmin(costs)) == 4


@pytest.mark.slow
def test_the_deepening_scan_is_ranked_coarsely_and_finds_the_full_scans_answer(
    prior, camera, monkeypatch
):
    """Decision 0105: the deepening scan about each deciding basin is ranked on the scan
    refinement's coarser profile and only :data:`DEEPEN_SHORTLIST` points are costed on the
    deciding one; on the short-lens LED scene the answer is the full scan's to the bit."""
    _truth, pixel, observation = _short_lens_led(camera)
    observation = replace(observation, pixel_origin="direct_spot")
    calls: list[tuple[int, int, int, int]] = []
    original = profile_search._shortlisted_costs

    def spy(points: np.ndarray, coarse: Any, fine: Any, keep: int) -> Any:
        calls.append((points.shape[0], coarse.edges_px.size, fine.edges_px.size, keep))
        return original(points, coarse, fine, keep)

    monkeypatch.setattr(profile_search, "_shortlisted_costs", spy)
    shortlisted = locate_mapping([observation], prior, DEFAULT_GRID)
    assert calls
    for size, coarse_edges, fine_edges, keep in calls:
        assert keep == profile_search.DEEPEN_SHORTLIST < size
        assert coarse_edges < fine_edges
    monkeypatch.setattr(profile_search, "DEEPEN_SHORTLIST", 10_000)
    full = locate_mapping([observation], prior, DEFAULT_GRID)
    np.testing.assert_array_equal(
        shortlisted.mapping.wavelength_nm(pixel), full.mapping.wavelength_nm(pixel)
    )


def test_a_broadband_quadratic_search_refines_few_minima_and_ranks_its_deciding_scans(
    prior, camera, monkeypatch
):
    """Decision 0115: with a broadband lamp alone the quadratic family's scan refines at most
    :data:`BROADBAND_QUADRATIC_REFINED` of its minima (each with its local scan), and each deciding
    scan (the 49 mappings of ``LOCAL_SCAN``) is ranked on the scan refinement's profile with only
    :data:`DECIDING_SHORTLIST` costed on the deciding one."""
    import sys

    local_scans: list[str] = []
    original_points = profile_search._quadratic_points

    def points(*args: Any) -> Any:
        if len(args) == 3 and args[2] == profile_search.LOCAL_SCAN:
            local_scans.append(sys._getframe(1).f_code.co_name)
        return original_points(*args)

    shortlists: list[tuple[int, int, int, int]] = []
    original_shortlist = profile_search._shortlisted_costs

    def shortlist(points: np.ndarray, coarse: Any, fine: Any, keep: int) -> Any:
        shortlists.append((points.shape[0], coarse.edges_px.size, fine.edges_px.size, keep))
        return original_shortlist(points, coarse, fine, keep)

    monkeypatch.setattr(profile_search, "_quadratic_points", points)
    monkeypatch.setattr(profile_search, "_shortlisted_costs", shortlist)
    # This scene's scan has four distinct minima: a cap of two refines two.
    monkeypatch.setattr(profile_search, "BROADBAND_QUADRATIC_REFINED", 2)
    found = profile_search.search_profiles([_render("D65", camera)], prior, DEFAULT_GRID)
    assert _mapping_re(found.mapping) < 5e-4
    assert local_scans.count("scan_grids") == 2
    deciding = local_scans.count("decide")
    assert deciding >= 1 and len(shortlists) == deciding
    for size, coarse_edges, fine_edges, keep in shortlists:
        assert keep == profile_search.DECIDING_SHORTLIST < size
        assert coarse_edges < fine_edges
