"""The validation protocol's mechanics (calib.evaluation.validation): splits, scenes, scores, runs."""

from __future__ import annotations

import csv
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.cli.app import build_app
from calib.core.datasets import CameraRecord
from calib.core.lamp_specs import gaussian_lamp, lamp_from_spec
from calib.core.mapping import QuadraticMapping, wavelength_rms_from_covariance
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum
from calib.evaluation.validation.budget import EstimateRecord, ratios_by_method
from calib.evaluation.validation.capture import SlitImage, capture_lamp
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    EXTRA_VARIANTS,
    NO_DIRECT_VARIANT,
    UNMEASURED_FL_SPEC,
    MethodVariant,
    ProtocolSettings,
    ValidationRow,
    evaluate_task,
    mapping_scores,
    render_task_scene,
    run_split,
    sensitivity_scores,
    split_tasks,
    tune_rows,
    tuning_score,
    variant_arguments,
    variant_inputs,
    variant_observations,
)
from calib.evaluation.validation.report import (
    markdown_report,
    summarise,
    write_rows_csv,
    write_summary_csv,
)
from calib.evaluation.validation.rig_errors import (
    PhotonBudget,
    RigErrors,
    SensorDraw,
    SpectrometerError,
    SpectrometerReading,
    StrayDraw,
    drifted,
)
from calib.evaluation.validation.scenes import (
    GeometryRanges,
    OrderMapping,
    ScenePlan,
    clean_signals,
    draw_geometry,
    draw_scene_plan,
    render_other_order,
    render_scene,
    true_lamp,
)
from calib.evaluation.validation.splits import (
    LEAVE_ONE_OUT,
    OTHER_COLLECTIONS,
    PAPER_TEST,
    PREDICTION,
    SplitRoleError,
    Splits,
    TestSplit,
    make_splits,
    require_validation,
)
from calib.model.gratings import BlazedGrating, SinusoidalPhaseGrating
from tests.synthetic_cameras import small_data_dir

AXIS = np.arange(380.0, 781.0, 5.0)


def _camera(
    name: str, shift_nm: float, collection: str = "solomatov-akkaynak-2023"
) -> CameraRecord:
    centres = (600.0 + shift_nm, 540.0 + shift_nm / 2, 460.0 - shift_nm / 3)
    values = np.stack(
        [
            np.exp(-0.5 * ((AXIS - c) / w) ** 2)
            for c, w in zip(centres, (40.0, 45.0, 30.0), strict=True)
        ],
        axis=1,
    )
    spectrum = MultiSpectrum(AXIS, values / values.max(), name=name)
    return CameraRecord(name, name.split(" (")[0], collection, spectrum, f"{collection}/{name}")


def _records() -> dict[str, list[CameraRecord]]:
    training = [
        _camera("Canon 10D (Huynh-2007)", 0.0),
        _camera("Canon 10D (Kawakami-et-al-2013)", 2.0),
        _camera("Canon 400D (Lebourgeois-2008)", -6.0),
        _camera("Nikon D70 (Huynh-2007)", 8.0),
        _camera("Sony NEX7 (Berra-et-al-2015)", -10.0),
        _camera("Pentax Q (Jiang-et-al-2013)", 12.0),
    ]
    paper = [_camera("Canon 600D (Jiang-et-al-2013)", 4.0)]
    others = [
        _camera("Canon EOS 600D (rawtoaces-data)", 4.5, "rawtoaces-data"),  # a paper test body
        _camera("Canon Digital Rebel XTi (rawtoaces-data)", -6.0, "rawtoaces-data"),  # = 400D
        _camera("Nikon D7000 (rawtoaces-data)", 6.0, "rawtoaces-data"),
        _camera("nikon d7000 (rawtoaces)", 6.1, "rawtoaces"),  # duplicate of the above
        _camera("Nikon D70 (camspec)", 8.0, "jiang-2013-camspec"),  # a training body
        _camera("Hasselblad H2 (camspec)", -3.0, "jiang-2013-camspec"),
    ]
    predictions = [
        _camera("Canon EOS-600D (Solomatov-Akkaynak-2023 prediction)", 4.2, "predictions"),
        _camera("Canon EOS-10D (Solomatov-Akkaynak-2023 prediction)", 1.0, "predictions"),
        _camera("Fujifilm X-E3 (Solomatov-Akkaynak-2023 prediction)", -2.0, "predictions"),
    ]
    return {"training": training, "paper": paper, "others": others, "predictions": predictions}


def _splits() -> Splits:
    records = _records()
    foveon = _camera("Foveon-like", 20.0).sensitivity
    return make_splits(
        records["training"],
        records["paper"],
        records["others"],
        [("Sigma SDMerill (NPL)", foveon)],
        records["predictions"],
    )


def test_splits_are_disjoint_and_deduplicated() -> None:
    splits = _splits()
    training_bodies = set(splits.test.training_bodies)
    test_bodies = [camera.body for camera in splits.test.cameras]
    assert not training_bodies & set(test_bodies)
    assert len(test_bodies) == len(set(test_bodies))  # one curve per body
    names = [camera.name for camera in splits.test.cameras]
    assert names == [
        "Canon 600D (Jiang-et-al-2013)",
        "Nikon D7000 (rawtoaces-data)",
        "Hasselblad H2 (camspec)",
        "Sigma SDMerill (NPL)",
    ]
    reasons = {note.camera: note.reason for note in splits.test.notes}
    assert reasons["Canon EOS 600D (rawtoaces-data)"].startswith("duplicate body (kept Canon 600D")
    assert reasons["Canon Digital Rebel XTi (rawtoaces-data)"] == "in training (same body)"
    assert reasons["nikon d7000 (rawtoaces)"].startswith("duplicate body")
    assert reasons["Nikon D70 (camspec)"] == "in training (same body)"
    groups = {camera.name: camera.group for camera in splits.test.cameras}
    assert groups["Canon 600D (Jiang-et-al-2013)"] == PAPER_TEST
    assert groups["Nikon D7000 (rawtoaces-data)"] == OTHER_COLLECTIONS
    # Validation: every training curve, leave-one-body-out; predictions but not of a test body.
    validation = splits.validation
    assert [c.group for c in validation.cameras].count(LEAVE_ONE_OUT) == 6
    predicted = [c.name for c in validation.cameras if c.group == PREDICTION]
    assert predicted == [
        "Canon EOS-10D (Solomatov-Akkaynak-2023 prediction)",
        "Fujifilm X-E3 (Solomatov-Akkaynak-2023 prediction)",
    ]
    canon_10d = validation.cameras[0]
    basis = {record.name for record in validation.basis_records(canon_10d)}
    assert "Canon 10D (Kawakami-et-al-2013)" not in basis  # the body leaves with both curves
    assert len(basis) == 4
    prediction_10d = next(c for c in validation.cameras if c.name.startswith("Canon EOS-10D"))
    assert len(validation.basis_records(prediction_10d)) == 4
    assert len(splits.test.basis_records(splits.test.cameras[0])) == 6
    text = "\n".join(splits.test.describe())
    assert "Split: test" in text and "duplicate body" in text


def test_the_test_split_refuses_a_training_body() -> None:
    splits = _splits()
    leaked = replace(splits.validation.cameras[0], group=OTHER_COLLECTIONS)
    with pytest.raises(SplitRoleError, match="body in the training set"):
        TestSplit((*splits.test.cameras, leaked), splits.test.training, splits.test.training_bodies)


def test_tuning_refuses_the_test_split(tmp_path: Path) -> None:
    splits = _splits()
    assert require_validation(splits.validation) is splits.validation
    settings = ProtocolSettings()
    with pytest.raises(SplitRoleError, match="validation split"):
        require_validation(splits.test)
    with pytest.raises(SplitRoleError, match="got the test split"):
        tune_rows(splits.test, settings, cache_dir=tmp_path)  # type: ignore[arg-type]
    with pytest.raises(SplitRoleError):
        tuning_score(splits.test, settings, "LED+FL", cache_dir=tmp_path)  # type: ignore[arg-type]


def test_sensitivity_coverage_and_sigma_ratio_on_a_constructed_case() -> None:
    truth = np.zeros((DEFAULT_GRID.size, 3))
    truth[:, 0], truth[:, 1], truth[:, 2] = 0.5, 1.0, 0.25
    truth[:5, 2] = 0.0  # a channel with no response at the grid's blue end
    error = np.zeros_like(truth)
    error[:10, 0] = 0.03  # 10 of 31 red values off by 3σ, the rest exact
    error[:30, 1] = -0.015  # 30 green values off by 1.5σ; the peak (1) exact
    error[:5, 2] = -0.03  # a negative lobe of 3σ where the truth is 0: the user gets 0
    result = EstimateResult(
        "constructed",
        DEFAULT_GRID.wavelength_nm,
        truth + error,
        sensitivity_sigma=np.full_like(truth, 0.01),
    )
    channel_re, coverage, ratio = sensitivity_scores(result, truth)
    assert coverage is not None and ratio is not None
    # scored on the delivered curve (negative lobes set to zero): the blue lobe is no error
    np.testing.assert_allclose(coverage, [21 / 31, 1.0, 1.0])
    np.testing.assert_allclose(
        ratio, [np.sqrt(10 / 31) * 3.0, np.sqrt(30 / 31) * 1.5, 0.0], atol=1e-12
    )
    # Eq. 16's terms on the delivered (peak-normalised) curves.
    delivered = result.physical_sensitivity()
    expected = np.sqrt(np.mean((delivered - truth) ** 2, axis=0)) / truth.max(axis=0)
    np.testing.assert_allclose(channel_re, expected, rtol=1e-12)
    assert channel_re[2] == 0.0
    no_sigma = sensitivity_scores(replace(result, sensitivity_sigma=None), truth)
    assert no_sigma[1] is None and no_sigma[2] is None


def test_mapping_scores_on_a_constructed_case() -> None:
    pixel = np.arange(0.0, 601.0)
    true_nm = 380.0 + 0.6 * pixel  # 380–740 nm
    covariance = np.diag([0.0, 0.0, 0.25])  # σ_λ = 0.5 nm everywhere
    mapping = QuadraticMapping(
        0.0,
        0.6,
        381.0 + 0.0,
        pixel_range=(0.0, 600.0),
        covariance=tuple(tuple(row) for row in covariance),
        wavelength_rms_nm=wavelength_rms_from_covariance(covariance, (0.0, 600.0)),
    )
    result = EstimateResult(
        "constructed", DEFAULT_GRID.wavelength_nm, np.ones((31, 3)), mapping=mapping
    )
    mean_abs, relative, coverage, ratio = mapping_scores(result, pixel, true_nm, DEFAULT_GRID)
    assert mean_abs == pytest.approx(1.0)  # 1 nm off everywhere: 2σ
    assert relative == pytest.approx(1.0 / 300.0)
    assert coverage == pytest.approx(1.0)  # |Δλ| = 2σ exactly is inside
    assert ratio == pytest.approx(2.0)
    shifted = replace(result, mapping=replace(mapping, c=381.5))
    assert mapping_scores(shifted, pixel, true_nm, DEFAULT_GRID)[2] == pytest.approx(0.0)


def test_scene_plans_are_deterministic_and_physical() -> None:
    lamps = ("LED-B3", "FL2")
    first = draw_scene_plan(np.random.default_rng(11), lamps)
    again = draw_scene_plan(np.random.default_rng(11), lamps)
    other = draw_scene_plan(np.random.default_rng(12), lamps)
    assert first.to_dict() == again.to_dict()
    assert first.to_dict() != other.to_dict()
    ranges = GeometryRanges()
    for seed in range(40):
        shape = draw_geometry(np.random.default_rng(seed), ranges)
        ends = shape.mapping.wavelength_nm(shape.pixel[[0, -1]])
        assert ends[0] < 400.0 - 4.0 and ends[1] > 700.0 + 4.0
        band = shape.mapping.wavelength_nm(shape.pixel)
        assert np.all(np.diff(band) > 0)
        assert 300 <= ranges.grooves_per_mm_range[0] <= shape.grooves_per_mm <= 1000
        assert 2.5 < shape.focal_length_mm < 110.0
        assert shape.line_spread.size % 2 == 1
    assert isinstance(first.grating, SinusoidalPhaseGrating)


def _flat_camera() -> MultiSpectrum:
    axis = np.arange(350.0, 851.0, 5.0)
    return MultiSpectrum(axis, np.ones((axis.size, 3)) * [1.0, 0.5, 0.25], name="flat")


def _plan(grating, **changes) -> ScenePlan:
    plan = draw_scene_plan(np.random.default_rng(3), ("A",), errors=RigErrors.noise_only())
    return replace(plan, grating=grating, **changes)


def test_the_direct_signal_goes_through_the_zeroth_order() -> None:
    grating = SinusoidalPhaseGrating(1.5)
    lamp = Spectrum(np.arange(360.0, 831.0), np.ones(471))
    _, direct = clean_signals(_plan(grating), lamp, _flat_camera())
    axis = np.arange(360.0, 830.001, 0.01)
    expected = np.trapezoid(grating.efficiency(0, axis), axis) * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(direct, expected, rtol=2e-4)


def test_the_second_order_lands_where_the_first_has_twice_the_wavelength() -> None:
    grating = BlazedGrating(450.0)
    lamp = Spectrum(np.arange(360.0, 831.0), np.ones(471))
    plan = _plan(grating)
    profile, _ = clean_signals(plan, lamp, _flat_camera())
    pixel = plan.geometry.pixel
    first_nm = plan.geometry.mapping.wavelength_nm(pixel)
    second = OrderMapping(plan.geometry.mapping, 2).wavelength_nm(pixel)
    np.testing.assert_allclose(second, first_nm / 2)
    # Below 2 × 360 nm only the first order lights a pixel; there, profile ∝ η₁ × dispersion.
    dispersion = np.gradient(first_nm, pixel)
    inside = (first_nm > 420.0) & (first_nm < 700.0)
    ratio = profile[inside, 0] / (grating.efficiency(1, first_nm[inside]) * dispersion[inside])
    np.testing.assert_allclose(ratio, ratio.mean(), rtol=0.01)
    beyond = first_nm > 725.0
    if beyond.any():
        first_only = grating.efficiency(1, first_nm[beyond]) * dispersion[beyond]
        assert np.all(profile[beyond, 0] > first_only * ratio.mean() * 1.001)


def test_the_other_order_is_the_gratings_minus_one_with_its_own_efficiency() -> None:
    """Decision 0197: the −1 order lands where the true grating's other order puts each
    wavelength (the incidence's sign turned), through the grating's own −1 efficiency."""
    grating = BlazedGrating(450.0)
    lamp = Spectrum(np.arange(360.0, 831.0), np.ones(471))
    plan = _plan(grating)
    pixel = plan.geometry.pixel
    assert plan.geometry.incidence_deg != 0.0
    profile, direct = clean_signals(plan, lamp, _flat_camera(), side=-1)
    _, plus_direct = clean_signals(plan, lamp, _flat_camera())
    np.testing.assert_allclose(direct, plus_direct)
    other_nm = plan.geometry.mapping.other_order().wavelength_nm(pixel)
    dispersion = np.gradient(other_nm, pixel)
    efficiency = grating.efficiency(-1, other_nm)
    # Away from the −1 efficiency's zero (sinc²(λ_B/λ + 1) vanishes at 450 nm; the slit's blur
    # fills it), where the second order adds nothing.
    inside = (other_nm > 420.0) & (other_nm < 700.0) & (efficiency > 0.2 * efficiency.max())
    ratio = profile[inside, 0] / (efficiency[inside] * dispersion[inside])
    np.testing.assert_allclose(ratio, np.median(ratio), rtol=0.01)
    # A blazed grating's −1 order is weak: far below the +1 order at the same pixels.
    plus, _ = clean_signals(plan, lamp, _flat_camera())
    assert float(profile[inside, 0].sum()) < 0.1 * float(plus[inside, 0].sum())


def test_the_other_order_is_captured_in_the_first_orders_bracket() -> None:
    """``render_other_order``: the −1 clean signal through the bracket the +1 order's was laid
    out for, its σ the noise it carries (noise-only rig errors: no exposure or gain error)."""
    grating = SinusoidalPhaseGrating(1.5)
    plan = _plan(grating)
    camera = _flat_camera()
    scene = render_scene(plan, camera, ("A",), np.random.default_rng(5))
    profile, sigma = render_other_order(scene, camera, "A", np.random.default_rng(6))
    assert profile.shape == sigma.shape == scene.observations["A"].profile.shape
    draw = plan.lamps["A"]
    seen = drifted(true_lamp("A"), draw.drift_gain, draw.drift_tilt_per_100nm)
    expected, _ = clean_signals(plan, seen, camera, side=-1)
    # The captured profile is in the +1 profile's units: the same scale as its clean signal.
    plus_scale = float(np.median(scene.observations["A"].profile / scene.clean["A"][0]))
    lit = expected[:, 1] > 0.2 * expected[:, 1].max()
    z = (profile[lit, 1] - plus_scale * expected[lit, 1]) / sigma[lit, 1]
    assert abs(float(np.mean(z))) < 0.5 and 0.5 < float(np.std(z)) < 1.5


def test_stray_light_is_a_lorentzian_wing_of_the_direct_spot() -> None:
    pixel = np.array([0.0, 100.0, 1000.0])
    added = StrayDraw(0.01, 100.0).added(np.zeros((3, 3)), np.array([1.0, 2.0, 3.0]), pixel)
    np.testing.assert_allclose(added[0], 0.01 / (np.pi * 100.0) * np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(added[1, 0], 0.01 / (np.pi * 100.0) / 2)


def test_a_band_brighter_than_the_spot_starts_the_bracket(rng: np.random.Generator) -> None:
    # A narrow blue LED through a sheet near its optimum phase: η₀ ≪ η₁, the band outshines the spot.
    budget = PhotonBudget()
    sensor = SensorDraw(20000.0, 3.0, 20)
    profile = np.outer(np.exp(-0.5 * ((np.arange(300) - 150) / 8.0) ** 2), [0.1, 0.3, 5.0])
    direct = np.array([0.5, 1.0, 5.0])
    slit = SlitImage.of(np.array([0.25, 0.5, 0.25]), sensor.band_rows, 0.5)
    assert float(direct.max()) / slit.spot_px < float(profile.max()) / sensor.band_rows
    gain, factors = budget.bracket(profile, direct, sensor, slit.spot_px, 0.9)
    brightest = gain * float(profile.max()) / sensor.band_rows
    assert brightest == pytest.approx(0.9 * budget.clip_fraction * sensor.full_well_e)
    merged = capture_lamp(profile, direct, slit, budget, sensor, gain, factors, np.zeros(8), rng)
    assert np.all(np.isfinite(merged.profile_sigma)) and np.all(np.isfinite(merged.direct_sigma))


def test_a_scene_that_cannot_be_rendered_fails_its_rows_not_the_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import calib.evaluation.validation.protocol as protocol

    def broken(task: object) -> None:
        raise ValueError("no light")

    monkeypatch.setattr(protocol, "render_task_scene", broken)
    splits = _splits()
    (task,) = split_tasks(
        replace(splits.test, cameras=splits.test.cameras[:1]), _tiny_settings(), cache_dir=tmp_path
    )
    (row,) = evaluate_task(task)
    assert row.failure == "ValueError: no light" and row.channel_re is None


def test_the_spectrometer_shifts_and_broadens_a_line() -> None:
    line = gaussian_lamp(550.0, 2.0)
    reading = SpectrometerReading(offset_nm=0.4, bandwidth_nm=6.0, step_nm=1.0)
    measured = SpectrometerError(noise_fraction=0.0, floor_fraction=0.0).measure(
        line, reading, np.random.default_rng(0)
    )
    values = measured.values - measured.values.min()
    centroid = float(np.sum(measured.wavelength_nm * values) / np.sum(values))
    assert centroid == pytest.approx(550.0 - 0.4, abs=0.02)  # reads the light of λ + offset at λ
    spread = np.sqrt(np.sum((measured.wavelength_nm - centroid) ** 2 * values) / np.sum(values))
    # Gaussians add in quadrature: line FWHM 2 nm, slit FWHM 6 nm (σ = FWHM / 2.3548).
    assert spread == pytest.approx(np.hypot(2.0, 6.0) / 2.3548, rel=0.03)


def _tiny_settings(**changes) -> ProtocolSettings:
    variant = next(v for v in DEFAULT_VARIANTS if v.label == "LED only")
    settings = ProtocolSettings(
        seed=5,
        variants=(variant,),
        n_vectors=3,
        geometry=GeometryRanges(band_length_px_range=(150.0, 170.0)),
    )
    return replace(settings, **changes)


def test_an_estimate_depends_on_its_seed_alone(tmp_path: Path) -> None:
    splits = _splits()
    split = replace(splits.test, cameras=splits.test.cameras[1:2])
    settings = _tiny_settings()
    (task,) = split_tasks(split, settings, cache_dir=tmp_path)
    first, second = evaluate_task(task), evaluate_task(task)
    assert first[0].failure is None
    assert [replace(row, time_s=0.0) for row in first] == [
        replace(row, time_s=0.0) for row in second
    ]
    # The same scene whatever the split's order.
    reordered = replace(splits.test, cameras=tuple(reversed(splits.test.cameras)))
    again = next(
        t for t in split_tasks(reordered, settings, cache_dir=tmp_path) if t.camera is task.camera
    )
    assert render_task_scene(task).plan.to_dict() == render_task_scene(again).plan.to_dict()


def test_a_run_of_one_variant_draws_the_full_runs_scene() -> None:
    # ``calib validate --variant X`` must score the scenes the full run scores, or its rows
    # cannot be compared with that run's.
    splits = _splits()
    split = replace(splits.test, cameras=splits.test.cameras[1:2])
    (alone,) = split_tasks(split, _tiny_settings())
    (full,) = split_tasks(split, _tiny_settings(variants=DEFAULT_VARIANTS))
    one, every = render_task_scene(alone), render_task_scene(full)
    assert one.plan.to_dict() == every.plan.to_dict()
    assert set(one.observations) == set(every.observations)
    for lamp, observation in every.observations.items():
        assert np.array_equal(one.observations[lamp].profile, observation.profile), lamp
        assert one.observations[lamp].metadata == observation.metadata, lamp


def test_scenes_carry_the_optics_a_raw_file_records_and_the_no_exif_row_drops_them() -> None:
    splits = _splits()
    split = replace(splits.test, cameras=splits.test.cameras[1:2])
    no_exif = next(v for v in DEFAULT_VARIANTS if v.label == "LED only, no EXIF")
    (task,) = split_tasks(split, _tiny_settings(variants=(no_exif,)))
    scene = render_task_scene(task)
    drawn = scene.plan.geometry
    optics = scene.observations["LED-B3"].metadata["optics"]
    assert isinstance(optics, dict)
    # EXIF: the nominal focal length (the drawn image distance less 0–8 % focus, to 0.1 mm
    # below 10 mm, else whole mm).
    step = 0.1 if optics["focal_length_mm"] < 10.0 else 1.0
    assert optics["focal_length_mm"] == pytest.approx(
        round(optics["focal_length_mm"] / step) * step
    )
    assert drawn.focal_length_mm / 1.08 - step / 2 <= optics["focal_length_mm"]
    assert optics["focal_length_mm"] <= drawn.focal_length_mm + step / 2
    assert optics["pixel_pitch_um"] == drawn.pixel_pitch_um
    (stripped,) = variant_observations(scene, no_exif)
    kept = {k: v for k, v in scene.observations["LED-B3"].metadata.items() if k != "optics"}
    assert stripped.metadata == kept
    # Profile CSVs of unknown origin carry no EXIF.
    arbitrary = render_task_scene(
        replace(task, settings=replace(task.settings, pixel_origin="arbitrary"))
    )
    assert "optics" not in arbitrary.observations["LED-B3"].metadata


def test_the_no_direct_variant_gives_the_first_order_alone_and_the_fl_as_nobody_measured_it() -> (
    None
):
    """The real D7000 set-up (decision 0074): no direct measurement, the FL's spectrum a nominal
    line list marked unknown, ``auto`` allowed the known-grating solve without a grating file."""
    splits = _splits()
    split = replace(splits.test, cameras=splits.test.cameras[1:2])
    (task,) = split_tasks(split, _tiny_settings(variants=(NO_DIRECT_VARIANT,)))
    scene = render_task_scene(task)
    tube, halogen = variant_observations(scene, NO_DIRECT_VARIANT)
    assert (tube.name, halogen.name) == ("FL2", "A")
    assert tube.direct_rgb is None and halogen.direct_rgb is None and halogen.direct_sigma is None
    assert tube.metadata["spectrum_known"] is False and "spectrum_known" not in halogen.metadata
    assert tube.spectrum.name == lamp_from_spec(UNMEASURED_FL_SPEC).name
    np.testing.assert_array_equal(tube.profile, scene.observations["FL2"].profile)
    assert halogen.spectrum is scene.observations["A"].spectrum
    assert variant_arguments(NO_DIRECT_VARIANT) == {"assume_flat_grating": True}
    assert variant_arguments(DEFAULT_VARIANTS[0]) == {}
    assert NO_DIRECT_VARIANT in EXTRA_VARIANTS
    # What the protocol (and every bench) hands calib.methods.estimate for the variant.
    lamps, keywords = variant_inputs(task, scene, NO_DIRECT_VARIANT)
    assert [lamp.name for lamp in lamps] == ["FL2", "A"] and lamps[0].direct_rgb is None
    assert keywords == {
        "method": NO_DIRECT_VARIANT.method,
        "grid": task.settings.grid,
        "basis": task.basis,
        "assume_flat_grating": True,
    }


def _failing_variant() -> MethodVariant:
    # han2012 refuses lamp observations at once: the rows carry the scene records, cheaply.
    return MethodVariant("refused", "han2012", ("LED-B3",))


def test_worker_processes_return_the_rows_of_one_process(tmp_path: Path) -> None:
    splits = _splits()
    settings = _tiny_settings(variants=(_failing_variant(),))
    one = run_split(splits.test, settings, jobs=1, cache_dir=tmp_path)
    two = run_split(splits.test, settings, jobs=2, cache_dir=tmp_path)
    assert [row.camera for row in one] == [camera.name for camera in splits.test.cameras]
    assert all(row.failure is not None and "han2012" in row.failure for row in one)
    assert [replace(row, time_s=0.0) for row in one] == [replace(row, time_s=0.0) for row in two]


@pytest.mark.slow
def test_a_run_of_real_estimates_is_the_same_for_any_number_of_jobs(tmp_path: Path) -> None:
    splits = _splits()
    split = replace(splits.test, cameras=splits.test.cameras[1:3])
    settings = _tiny_settings()
    one = run_split(split, settings, jobs=1, cache_dir=tmp_path)
    two = run_split(split, settings, jobs=2, cache_dir=tmp_path)
    assert len(one) == 2 and all(row.failure is None for row in one)
    assert [replace(row, time_s=0.0) for row in one] == [replace(row, time_s=0.0) for row in two]


def _row(camera: str, variant: str, re: float | None, group: str = PAPER_TEST) -> ValidationRow:
    return ValidationRow(
        split="test",
        camera=camera,
        body=camera.lower(),
        group=group,
        collection="c",
        scene=0,
        variant=variant,
        method="m",
        channel_re=None if re is None else (re, 2 * re, 3 * re),
        coverage=None if re is None else (0.5, 1.0, 0.0),
        sigma_ratio=None if re is None else (1.0, 2.0, 3.0),
        mapping_mean_abs_nm=None if re is None else 100 * re,
        mapping_re=None if re is None else re / 10,
        mapping_coverage=None if re is None else 0.5,
        mapping_sigma_ratio=None if re is None else 4.0,
        time_s=1.0,
        failure="EstimationError: no" if re is None else None,
    )


def test_report_tables_and_csvs(tmp_path: Path) -> None:
    rows = [
        _row("A", "LED+FL", 0.01),
        _row("B", "LED+FL", 0.03, OTHER_COLLECTIONS),
        _row("C", "LED+FL", None),
    ]
    summary = summarise(rows)
    red = next(r for r in summary if r.table == "sensitivity by channel" and r.channel == "r")
    stats = dict(red.statistics)
    assert (red.estimates, red.failures) == (3, 1)
    assert stats["mean RE ×10⁻²"] == pytest.approx(2.0)
    assert stats["±2σ coverage %"] == pytest.approx(50.0)
    whole = next(r for r in summary if r.table == "mapping" and r.group == "all")
    assert dict(whole.statistics)["> 3 nm"] == 0.0
    assert dict(whole.statistics)["mean |Δλ| nm"] == pytest.approx(2.0)
    splits = _splits()
    report = markdown_report([splits.test], rows, ProtocolSettings(), command="calib validate")
    assert "## Split: test" in report and "### test: mapping" in report
    assert "LED+FL on C (scene 0): EstimationError: no" in report
    # Every row of the mapping table has as many cells as its heading ("mean |Δλ| nm" is one).
    table = report.split("### test: mapping")[1].split("\n\n")[1].splitlines()
    assert len(table) >= 3 and "mean \\|Δλ\\| nm" in table[0]
    assert len({len(re.split(r"(?<!\\)\|", line)) for line in table}) == 1, table
    with write_summary_csv(tmp_path / "summary.csv", rows).open() as handle:
        lines = list(csv.DictReader(handle))
    assert {line["split"] for line in lines} == {"test"}
    with write_rows_csv(tmp_path / "rows.csv", rows).open() as handle:
        parsed = list(csv.DictReader(handle))
    assert parsed[0]["re_g"] == "0.02" and parsed[2]["failure"].startswith("EstimationError")


def test_mapping_failures_are_counted_with_and_without_an_ambiguity_warning() -> None:
    """Issue 16's target: no mapping > 3 nm off without an ambiguity warning; the table says how
    many were silent, and rows.csv which."""
    rows = [
        replace(_row("A", "LED only", 0.05), mapping_warned=True),  # 5 nm off, warned
        replace(_row("B", "LED only", 0.04), mapping_warned=False),  # 4 nm off, silent
        replace(_row("C", "LED only", 0.01), mapping_warned=False),  # 1 nm off
    ]
    whole = next(r for r in summarise(rows) if r.table == "mapping" and r.group == "all")
    stats = dict(whole.statistics)
    assert stats["> 3 nm"] == 2.0
    assert stats["> 3 nm unwarned"] == 1.0
    # A warning on a right mapping is a false alarm, counted apart (decision 0085).
    assert stats["≤ 3 nm warned"] == 0.0
    rows.append(replace(_row("D", "LED only", 0.005), mapping_warned=True))  # 0.5 nm off, warned
    whole = next(r for r in summarise(rows) if r.table == "mapping" and r.group == "all")
    assert dict(whole.statistics)["≤ 3 nm warned"] == 1.0


def test_the_mapping_sigma_ratio_is_also_given_without_and_with_a_warning() -> None:
    """A warned mapping's σ spans its competing basins: its ratio is told apart from the others'."""
    rows = [
        replace(_row(name, "LED only", 0.005), mapping_warned=False, mapping_sigma_ratio=ratio)
        for name, ratio in (("A", 0.6), ("B", 0.8), ("C", 1.0))
    ] + [
        replace(_row(name, "LED only", 0.005), mapping_warned=True, mapping_sigma_ratio=ratio)
        for name, ratio in (("D", 0.1), ("E", 0.2), ("F", 0.3))
    ]
    stats = dict(
        next(r for r in summarise(rows) if r.table == "mapping" and r.group == "all").statistics
    )
    assert stats["σ ratio (median)"] == pytest.approx(0.45)
    assert stats["σ ratio unwarned (median)"] == pytest.approx(0.8)
    assert stats["σ ratio warned (median)"] == pytest.approx(0.2)
    unwarned_only = dict(
        next(r for r in summarise(rows[:3]) if r.table == "mapping" and r.group == "all").statistics
    )
    assert unwarned_only["σ ratio warned (median)"] is None


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--split", "train"], "--split"),
        (["--grating", "ruled"], "--grating"),
        (["--grating", "catalogue"], "--catalogue"),
        (["--variant", "9 lamps"], "--variant"),
        (["--errors", "some"], "--errors"),
    ],
)
def test_cli_refuses_bad_options(arguments: list[str], message: str) -> None:
    result = CliRunner().invoke(build_app(), ["validate", *arguments])
    assert result.exit_code != 0
    assert message in str(result.output) + str(result.exception)


def test_cli_runs_the_protocol_on_a_small_data_directory(tmp_path: Path) -> None:
    small_data_dir(tmp_path, 9)
    out = tmp_path / "out"
    result = CliRunner().invoke(
        build_app(),
        [
            "validate",
            "--data-dir",
            str(tmp_path / "data"),
            "--split",
            "validation",
            "--quick",
            "--variant",
            "LED only",
            "--jobs",
            "1",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output + str(result.exception)
    assert "## Split: validation" in result.output
    report = (out / "report.md").read_text()
    assert "Command: `calib validate" in report
    with (out / "rows.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 1 and rows[0]["variant"] == "LED only"


@pytest.mark.shared_data
def test_the_real_splits(shared_camera_data: Path) -> None:
    from calib.evaluation.validation.splits import OUT_OF_BASIS, load_splits

    splits, missing = load_splits(shared_camera_data)
    assert missing == []
    assert len(splits.validation.cameras) == 44
    assert len(set(splits.validation.training_bodies)) == 36
    test = splits.test
    groups = [camera.group for camera in test.cameras]
    assert groups.count(PAPER_TEST) == 5 and groups.count(OUT_OF_BASIS) == 2
    bodies = [camera.body for camera in test.cameras]
    assert len(bodies) == len(set(bodies))
    assert not set(bodies) & set(test.training_bodies)
    names = {camera.name for camera in test.cameras}
    assert "Nikon D7000 (rawtoaces-data)" in names  # the real D7000 data's camera: a test camera
    assert not any("XTi" in name or "xti" in name for name in names)  # the 400D is in training


def test_an_assumed_eta_is_judged_under_its_own_key_only() -> None:
    """The budget run's factor for an assumed η (decision 0074) must not stand for the same method
    through a grating file."""
    assumed = EstimateRecord("known-grating", "no direct", np.zeros(2), {}, family="assumed")
    assert set(ratios_by_method([assumed], 1.0)) == {"known-grating:assumed"}


def test_the_grating_choice_is_read_one_way_for_the_cli_the_budget_and_the_benches(tmp_path):
    from calib.core.errors import InputError
    from calib.evaluation.validation.protocol import protocol_gratings

    assert protocol_gratings("mix", None) == (("sinusoidal", "blazed"), None)
    assert protocol_gratings("blazed, sinusoidal", None) == (("sinusoidal", "blazed"), None)
    with pytest.raises(InputError, match="needs the maker's curve"):
        protocol_gratings("catalogue", None)  # asked for by name: not dropped quietly
    with pytest.raises(InputError, match="unknown grating kind holographic"):
        protocol_gratings("sinusoidal,holographic", None)
    curve = tmp_path / "curve.csv"
    curve.write_text("wavelength_nm,efficiency\n400,0.3\n550,0.5\n700,0.4\n")
    kinds, read = protocol_gratings("mix", curve)
    assert kinds == ("sinusoidal", "blazed", "catalogue") and read is not None
