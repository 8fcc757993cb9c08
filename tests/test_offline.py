"""calib.pipeline: RAW brackets rendered through calib.model.forward → estimate, against the renderer's truth.

Measured on these scenes (exact basis, 0.35 MP frames, 5-frame brackets, shot + read noise) with the
makabe2025 solver of this branch: RE ≈ 0.017 and mapping RE ≈ 5e-4 (LED + fluorescent), the mapping
RE estimate within a factor 2 of the true error. The bounds below are the estimator's own targets
(RE < 0.02 with a found mapping, mapping RE < 0.5 %), with a margin for other noise draws.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.mapping import QuadraticMapping
from calib.image.profiles import DiffractionGeometry
from calib.pipeline import LampImages, OfflineEstimate, OfflineSettings, estimate_offline
from calib.pipeline.brackets import (
    BROADBAND_KINDS,
    BracketProfiles,
    _decode_plans,
    dark_reach,
    extend_orders,
    shift_geometry,
)
from calib.pipeline.report import write_report
from tests.rendered_capture import GRATING, Capture, render_capture, shared_capture

#: The estimator's own target at 1 % noise with the mapping estimated (issue 2: LED+Flu ≤ 3.5 ×10⁻²);
#: measured here 0.9 ×10⁻².
RE_TARGET = 0.035


def _profiles(estimate: OfflineEstimate) -> BracketProfiles:
    assert estimate.profiles is not None
    return estimate.profiles


#: Measured 0.08 % on these shot-noise DNGs (the synthetic protocol's LED+Flu at 1 % noise: 0.07 %).
MAPPING_RE_TARGET = 0.002
#: An LED alone: issue 2's LED-only mapping target (0.5 %); measured 0.1–0.3 % on these scenes.
LED_MAPPING_RE_TARGET = 0.005


def _inputs(capture: Capture, *, darks: bool = True) -> list[LampImages]:
    return [
        LampImages(
            lamp.name,
            lamp.kind,
            lamp.spectrum_csv,
            lamp.frames,
            lamp.darks if darks else (),
        )
        for lamp in capture.lamps
    ]


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(scope="module")
def estimate(capture: Capture) -> OfflineEstimate:
    return estimate_offline(_inputs(capture), OfflineSettings(basis=capture.basis))


def test_round_trip_matches_the_renderers_truth(
    capture: Capture, estimate: OfflineEstimate
) -> None:
    result = estimate.result
    pixel = estimate.observations[0].pixel
    relative, mapping = capture.errors(result, pixel)
    assert relative < RE_TARGET, relative
    assert mapping < MAPPING_RE_TARGET, mapping
    assert isinstance(result.mapping, QuadraticMapping)
    assert result.mapping.method.startswith("lines of")
    # the mapping's own error estimate is honest to a factor of a few
    assert result.mapping_re_estimate is not None
    assert mapping / 4 < result.mapping_re_estimate < mapping * 4
    # both lamps share one pixel axis: distance from the spot in sensor pixels
    np.testing.assert_array_equal(estimate.observations[0].pixel, estimate.observations[1].pixel)
    geometry = _profiles(estimate).geometry
    assert geometry.spot_centre_px == pytest.approx(capture.layout.spot_centre_px, abs=0.1)
    assert geometry.primary.angle_deg == pytest.approx(3.0, abs=0.05)


def test_the_profile_covers_the_grid_beyond_the_lit_band(
    capture: Capture, estimate: OfflineEstimate
) -> None:
    pixel = estimate.observations[0].pixel
    wavelength = GRATING.wavelength_nm(pixel)
    assert wavelength[0] < 395 and wavelength[-1] > 705
    assert any("extended" in note for note in estimate.provenance.notes)


def test_dark_frames_are_matched_and_recorded(capture: Capture, estimate: OfflineEstimate) -> None:
    lamps = {lamp["name"]: lamp for lamp in estimate.provenance.lamps}
    for frame in lamps["LED"]["frames"]:
        assert len(frame["dark_frames"]) == 1
        assert Path(frame["dark_frames"][0]).name.startswith("dark_")
    roles = {record.role for record in estimate.provenance.inputs}
    assert roles == {"frame", "dark", "spectrum"}
    assert all(len(record.sha256) == 64 for record in estimate.provenance.inputs)


def test_lamps_of_one_camera_share_the_noise_model_they_are_planned_to_share(
    capture: Capture, estimate: OfflineEstimate
) -> None:
    # the decode order and the merge agree on which lamps estimate their own noise model (the
    # first lamp given is broadband, so it is merged first)
    assert capture.lamps[0].kind in BROADBAND_KINDS
    plans = _decode_plans(_inputs(capture))
    assert [plan.estimate_noise for plan in plans] == [True] + [False] * (len(plans) - 1)
    sources = []
    for extraction in _profiles(estimate).extractions:
        noise = extraction.merged.image.noise_model
        assert noise is not None
        sources.append("shared with another lamp" in noise.source)
    assert sources == [False] + [True] * (len(sources) - 1)


def test_profiles_and_direct_agree_with_the_renderer_within_their_noise(
    capture: Capture,
    estimate: OfflineEstimate,
) -> None:
    for observation in estimate.observations:
        clean, clean_direct = capture.clean_profile(observation.name, observation.pixel)
        peak = int(np.argmax(clean[:, 1]))
        scale = float(np.sum(observation.profile[:, 1] * clean[:, 1]) / np.sum(clean[:, 1] ** 2))
        assert observation.profile_sigma is not None
        z = (observation.profile - scale * clean) / observation.profile_sigma
        # 0.3 σ, not less: calib.image.profiles takes the background as the median of the strips beside
        # the band, and dark-subtracted values of one long frame lie on a lattice (1 DN / t), so
        # the median can be off by up to half a step (a few DN/s; measured −0.2 σ in B for FL)
        assert np.all(np.abs(z.mean(axis=0)) < 0.3), z.mean(axis=0)
        assert np.all((z.var(axis=0) > 0.7) & (z.var(axis=0) < 1.3)), z.var(axis=0)
        assert observation.profile[peak, 1] > 100 * observation.profile_sigma[peak, 1]
        # the direct RGB has the same colour as the truth (its scale is the 0th-order throughput)
        assert observation.direct_rgb is not None and observation.direct_sigma is not None
        ratio = observation.direct_rgb / clean_direct
        sigma = observation.direct_sigma / clean_direct
        assert np.all(np.abs(ratio - ratio.mean()) < 5 * sigma + 2e-3 * ratio.mean()), ratio


def test_a_spot_clipped_in_long_frames_comes_from_the_short_ones(tmp_path: Path) -> None:
    capture = render_capture(
        tmp_path / "capture", tmp_path / "basis", lamps=("LED",), direct_throughput=5.0, seed=4
    )
    result = estimate_offline(_inputs(capture), OfflineSettings(basis=capture.basis))
    led = _profiles(result).extractions[0]
    longest = max(led.merged.image.frames, key=lambda record: record.exposure_s)
    assert max(longest.saturated_fraction) > 0  # the spot clipped in the longest frame
    observation = result.observations[0]
    _, clean_direct = capture.clean_profile("LED", observation.pixel)
    assert observation.direct_rgb is not None
    ratio = observation.direct_rgb / clean_direct
    # The colour within its σ (the Bayer interleaving's, ≈ 0.3 % on R and B here: decision 0119)
    # and within 1 % (a clipped spot is off by far more).
    assert observation.direct_sigma is not None
    relative = ratio / ratio.mean() - 1
    assert np.all(np.abs(relative) < 3 * observation.direct_sigma / observation.direct_rgb), ratio
    assert np.ptp(ratio) < 1e-2 * ratio.mean(), ratio
    # Nothing to warn about the clipped spot: the spectrometer's bandwidth was not given, and an
    # LED alone may leave the mapping's curvature open between basins (decision 0025): that, and
    # only that, is said.
    others = [
        w
        for w in result.warnings
        if not w.endswith("[no_spectrometer_bandwidth]") and "the mapping is ambiguous" not in w
    ]
    assert others == [], result.warnings


def test_region_of_interest_merge_agrees_with_the_whole_frame(tmp_path: Path) -> None:
    capture = render_capture(
        tmp_path / "capture", tmp_path / "basis", lamps=("LED",), padding_px=300, seed=5
    )
    lamps = _inputs(capture, darks=False)
    whole = estimate_offline(lamps, OfflineSettings(basis=capture.basis, use_region=False))
    region = estimate_offline(lamps, OfflineSettings(basis=capture.basis, use_region=True))
    assert whole.profiles is not None and region.profiles is not None
    assert _profiles(whole).region_origin_px is None
    assert _profiles(region).region_origin_px is not None
    shape = _profiles(region).region_shape_px
    assert shape is not None
    height, width = shape
    assert height * width < 0.6 * capture.sensor.height_px * capture.sensor.width_px
    a, b = _profiles(whole).geometry, _profiles(region).geometry
    assert a.spot_centre_px == pytest.approx(b.spot_centre_px, abs=0.05)
    assert a.primary.angle_deg == pytest.approx(b.primary.angle_deg, abs=0.02)
    first, second = whole.observations[0], region.observations[0]
    for observation in (first, second):  # both agree with the truth within their noise
        clean, _ = capture.clean_profile("LED", observation.pixel)
        scale = float(np.sum(observation.profile * clean) / np.sum(clean**2))
        assert observation.profile_sigma is not None
        z = (observation.profile - scale * clean) / observation.profile_sigma
        assert np.all(np.abs(z.mean(axis=0)) < 0.2) and np.all(z.var(axis=0) < 1.3)
    assert first.direct_rgb is not None and second.direct_rgb is not None
    np.testing.assert_allclose(first.direct_rgb, second.direct_rgb, rtol=2e-3)


@pytest.mark.parametrize(
    ("angle_deg", "pattern"), [(33.0, "BGGR"), (180.0, "GRBG"), (-90.0, "GBRG")]
)
def test_rotated_and_mirrored_geometry(tmp_path: Path, angle_deg: float, pattern: str) -> None:
    capture = render_capture(
        tmp_path / "capture",
        tmp_path / "basis",
        lamps=("LED",),
        angle_deg=angle_deg,
        cfa_pattern=pattern,
        seed=7,
    )
    result = estimate_offline(
        _inputs(capture), OfflineSettings(basis=capture.basis, use_region=True)
    )
    relative, mapping = capture.errors(result.result, result.observations[0].pixel)
    # An LED alone, with no focal length in the files: the curvature of the rainbow may be left
    # open between basins (decision 0025). Then the result must say so and state a σ that covers
    # the error to a factor of two — never a confident wrong mapping.
    found = result.result.mapping
    assert isinstance(found, QuadraticMapping)
    if mapping >= LED_MAPPING_RE_TARGET:
        assert found.details.get("ambiguous"), mapping
        assert found.wavelength_rms_nm is not None
        span = float(result.result.wavelength_nm[-1] - result.result.wavelength_nm[0])
        assert 0.5 <= found.wavelength_rms_nm / (mapping * span) <= 2.0
    else:
        assert relative < RE_TARGET, relative
    detected = _profiles(result).geometry.primary.angle_deg
    assert abs((detected - angle_deg + 180) % 360 - 180) < 0.1


def test_both_first_orders_in_frame_use_the_stronger(tmp_path: Path) -> None:
    capture = render_capture(
        tmp_path / "capture", tmp_path / "basis", lamps=("LED",), minus_first_strength=0.4, seed=8
    )
    result = estimate_offline(_inputs(capture), OfflineSettings(basis=capture.basis))
    geometry = _profiles(result).geometry
    assert [band.side for band in geometry.orders] == [1, -1]
    assert geometry.primary.angle_deg == pytest.approx(3.0, abs=0.1)
    # The result says the other order was seen and left out (its flux share measured: 0.4 drawn).
    (note,) = [n for n in result.provenance.notes if "other first order" in n]
    share = float(note.split("side -1, ")[1].split("%")[0]) / 100
    assert share == pytest.approx(0.4, abs=0.08) and "+1 order alone" in note, note
    relative, mapping = capture.errors(result.result, result.observations[0].pixel)
    assert relative < RE_TARGET and mapping < MAPPING_RE_TARGET, (relative, mapping)
    # With the LED alone, the other order measured the grating's tilt (decision 0197): the
    # rendered grating is at normal incidence.
    assert result.observations[0].other_order is not None
    found = result.result.mapping
    assert isinstance(found, QuadraticMapping)
    measured = found.details["other_order"]
    assert measured["refused"] is None
    assert abs(measured["incidence_deg"]) < 3 * measured["incidence_sigma_deg"], measured
    # The report says what both orders measured.
    page = write_report(tmp_path / "out", result)["report"].read_text()
    assert "both first orders measure" in page and "reported, not used by the mapping" in page


@pytest.mark.slow  # detection's choice is tested on its own by tests/test_profiles.py (make test-all)
def test_a_stronger_order_off_the_frame_gives_way_to_the_whole_other(tmp_path: Path) -> None:
    """The +1 order's lit band runs about 110 px past the frame's edge, the −1 order (0.6 of its
    strength) is whole: the estimate reads the −1 order, says so in its notes, and meets the
    targets a whole +1 order meets (at this seed, with the spot centred: RE 1.2 %, mapping 0.08 %;
    here 0.95 % and 0.09 %)."""
    capture = render_capture(
        tmp_path / "capture",
        tmp_path / "basis",
        lamps=("LED",),
        minus_first_strength=0.6,
        spot_shift_px=350.0,
        seed=8,
    )
    result = estimate_offline(_inputs(capture), OfflineSettings(basis=capture.basis))
    geometry = _profiles(result).geometry
    assert [band.side for band in geometry.orders] == [1]
    assert geometry.primary.angle_deg == pytest.approx(-177.0, abs=0.1)
    (note,) = [n for n in result.provenance.notes if "stronger first order was left out" in n]
    assert "runs off" in note and "other first order" in note, note
    relative, mapping = capture.errors(result.result, result.observations[0].pixel)
    assert relative < RE_TARGET and mapping < MAPPING_RE_TARGET, (relative, mapping)


def test_every_frame_saturating_the_spot_is_refused_with_advice(tmp_path: Path) -> None:
    capture = render_capture(
        tmp_path / "capture",
        tmp_path / "basis",
        lamps=("LED",),
        exposures_s=(0.128, 0.256),
        direct_throughput=5.0,
        seed=9,
    )
    with pytest.raises(InputError, match=r"saturated in every frame.*shorter exposure"):
        estimate_offline(_inputs(capture), OfflineSettings(basis=capture.basis))


def test_mixed_camera_bracket_names_the_odd_file(tmp_path: Path) -> None:
    capture = render_capture(tmp_path / "a", tmp_path / "basis", lamps=("LED",), seed=10)
    other = render_capture(
        tmp_path / "b", tmp_path / "basis", lamps=("LED",), seed=11, model="OtherCam"
    )
    odd = other.lamps[0].frames[2]
    lamp = capture.lamps[0]
    mixed = LampImages("LED", "led", lamp.spectrum_csv, (*lamp.frames[:2], odd))
    with pytest.raises(InputError, match="OtherCam") as error:
        estimate_offline([mixed], OfflineSettings(basis=capture.basis))
    assert error.value.source == str(odd)


def test_lamps_from_different_cameras_are_refused(tmp_path: Path) -> None:
    led = render_capture(tmp_path / "a", tmp_path / "basis", lamps=("LED",), seed=12)
    fluorescent = render_capture(
        tmp_path / "b", tmp_path / "basis", lamps=("FL",), seed=13, model="OtherCam"
    )
    lamps = _inputs(led) + _inputs(fluorescent)
    with pytest.raises(InputError, match="same camera"):
        estimate_offline(lamps, OfflineSettings(basis=led.basis))


def test_truncated_raw_is_refused_with_its_name(tmp_path: Path, capture: Capture) -> None:
    lamp = capture.lamps[0]
    broken = tmp_path / "broken.dng"
    data = lamp.frames[1].read_bytes()
    broken.write_bytes(data[: len(data) // 3])
    damaged = LampImages("LED", "led", lamp.spectrum_csv, (lamp.frames[0], broken))
    with pytest.raises(InputError) as error:
        estimate_offline([damaged], OfflineSettings(basis=capture.basis))
    assert "broken.dng" in str(error.value)


def test_not_a_raw_file_is_refused_with_its_name(tmp_path: Path, capture: Capture) -> None:
    lamp = capture.lamps[0]
    text = tmp_path / "notes.dng"
    text.write_text("not an image\n")
    with pytest.raises(InputError, match=r"notes\.dng"):
        estimate_offline(
            [LampImages("LED", "led", lamp.spectrum_csv, (text,))],
            OfflineSettings(basis=capture.basis),
        )


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("wavelength_nm,value\n400,1\n500,abc\n700,1\n", "'abc' is not a number"),
        ("400,1\n500,nan\n700,1\n", "NaN"),
        ("450,1\n500,2\n650,1\n", "too narrow"),
        ("400,1,2\n700,1,2\n", "two columns"),
    ],
)
def test_bad_spectrum_csv_is_refused_before_decoding(
    tmp_path: Path, capture: Capture, content: str, message: str
) -> None:
    spectrum = tmp_path / "lamp.csv"
    spectrum.write_text(content)
    lamp = capture.lamps[0]
    with pytest.raises(InputError, match=message) as error:
        estimate_offline(
            [LampImages("LED", "led", spectrum, lamp.frames)], OfflineSettings(basis=capture.basis)
        )
    assert str(spectrum) in str(error.value)


def test_small_negative_spectrum_noise_is_clipped_with_a_warning(
    tmp_path: Path, capture: Capture
) -> None:
    lamp = capture.lamps[0]
    rows = lamp.spectrum_csv.read_text().splitlines()
    rows[1] = rows[1].split(",")[0] + ",-0.001"
    spectrum = tmp_path / "led.csv"
    spectrum.write_text("\n".join(rows) + "\n")
    result = estimate_offline(
        [LampImages("LED", "led", spectrum, lamp.frames)], OfflineSettings(basis=capture.basis)
    )
    assert any("negative" in warning for warning in result.warnings)


def test_input_mistakes_are_named(tmp_path: Path, capture: Capture) -> None:
    lamp = capture.lamps[0]
    good = LampImages("LED", "led", lamp.spectrum_csv, lamp.frames)
    settings = OfflineSettings(basis=capture.basis)
    with pytest.raises(InputError, match="given twice"):
        estimate_offline([good, good], settings)
    with pytest.raises(InputError, match="unknown method 'paper2099'"):
        estimate_offline([good], OfflineSettings(basis=capture.basis, method="paper2099"))
    with pytest.raises(InputError, match="no lamp named 'X'"):
        estimate_offline([good], OfflineSettings(basis=capture.basis, mapping_lamp="X"))
    with pytest.raises(InputError, match="file not found"):
        estimate_offline(
            [LampImages("LED", "led", lamp.spectrum_csv, (tmp_path / "x.dng",))], settings
        )
    with pytest.raises(InputError, match="2 exposure times for 5 images"):
        estimate_offline(
            [LampImages("LED", "led", lamp.spectrum_csv, lamp.frames, exposure_s=(0.1, 0.2))],
            settings,
        )


def test_extension_stops_at_the_frame_and_before_a_second_order(
    capture: Capture, estimate: OfflineEstimate
) -> None:
    image, geometry = _profiles(estimate).geometry_image()
    band = geometry.primary
    tight = (image.sensor_shape_px[0], int(geometry.spot_centre_px[0] + band.stop_px + 60))
    extended, _ = extend_orders(geometry, tight)
    assert band.stop_px <= extended.primary.stop_px <= band.stop_px + 60
    second = shift_geometry(_profiles(estimate).geometry, image)
    far, _ = extend_orders(second, (10_000, 10_000), fraction=5.0)
    limit = max(1.9 * second.primary.start_px, second.primary.stop_px)
    assert far.primary.stop_px <= limit + 1e-9
    floor = second.spot_half_size_px[0] + second.background_gap_px
    assert far.primary.start_px == pytest.approx(floor)


def test_a_long_band_extends_into_its_dark_end_and_stops_where_light_rises(
    capture: Capture, estimate: OfflineEstimate
) -> None:
    # A band lit from 100 to 300 px (a camera blind beyond its red end): 1.9 × its start forbids
    # any extension; the pixels beyond its lit end are dark up to 330 px in every lamp's profile,
    # where light rises again (a 2nd order), so the red end extends to 329 px and no further.
    geometry = _profiles(estimate).geometry_image()[1]
    long_band = replace(geometry.primary, start_px=100.0, stop_px=300.0)
    geometry = replace(geometry, orders=(long_band,))

    def extract_all(trial: DiffractionGeometry) -> list[Any]:
        stop = trial.primary.stop_px
        pixel = np.arange(long_band.start_px, stop + 1.0)
        lit = np.where(pixel <= 300.0, 1.0, 0.0)
        tail = np.where((pixel > 300.0) & (pixel <= 303.0), 0.05, 0.0)  # its own first order
        rise = np.where(pixel >= 330.0, 0.2, 0.0)
        dark_lamp = np.column_stack([lit + tail, lit, lit])
        second_order = np.column_stack([lit, lit, lit + rise])
        return [SimpleNamespace(side=1, pixel=pixel, profile=p) for p in (dark_lamp, second_order)]

    shape = (10_000, 10_000)
    reach = dark_reach(geometry, shape, extract_all, fraction=0.5)
    assert reach[1] == pytest.approx(329.0)
    extended, _ = extend_orders(geometry, shape, fraction=0.5, dark_reach=reach)
    assert extended.primary.stop_px == pytest.approx(329.0)
    guessed, _ = extend_orders(geometry, shape, fraction=0.5)
    assert guessed.primary.stop_px == pytest.approx(300.0)
    # without a rise the extension takes its whole fraction
    quiet = dark_reach(geometry, shape, lambda trial: extract_all(trial)[:1], fraction=0.5)
    assert quiet[1] == pytest.approx(400.0)


def test_frames_without_a_spot_or_band_are_an_input_error(capture: Capture) -> None:
    lamp = capture.lamps[0]
    dark = LampImages("LED", "led", lamp.spectrum_csv, lamp.darks[:2])
    with pytest.raises(InputError, match="is the lamp on"):
        estimate_offline([dark], OfflineSettings(basis=capture.basis))


def test_the_sigma_budget_is_one_setting_of_the_offline_pipeline(
    capture: Capture, estimate: OfflineEstimate
) -> None:
    """``OfflineSettings.budget`` reaches the estimator: ``None`` keeps the method's own σ (no
    budget in the result); another budget's floor changes the χ² it judges."""
    from calib.methods.uncertainty import BudgetSettings

    own = estimate_offline(
        _inputs(capture), OfflineSettings(basis=capture.basis, budget=None)
    ).result
    assert not own.quality.uncertainty
    assert estimate.result.quality.uncertainty
    np.testing.assert_allclose(own.sensitivity, estimate.result.sensitivity, atol=1e-9)
    assert own.sensitivity_sigma is not None and estimate.result.sensitivity_sigma is not None
    assert np.all(estimate.result.sensitivity_sigma >= own.sensitivity_sigma)
    floored = estimate_offline(
        _inputs(capture),
        OfflineSettings(basis=capture.basis, budget=BudgetSettings(model_floor=0.2, perturb=False)),
    ).result
    judged, default = (r.quality.uncertainty["reduced_chi2"] for r in (floored, estimate.result))
    assert judged < default
