"""rig.plan: plans walked step by step with readings sent back, no devices."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from rig.analysis import FrameStats
from rig.config import HdrPolicy, RigConfig
from rig.errors import (
    BracketImpossible,
    LampDark,
    LampNotStable,
    LimitsExceeded,
    PlanProtocolError,
    WrongFrameFormat,
)
from rig.plan import Plan, StandardCaptureArgs, build_plan, relative_change, standard_capture
from rig.steps import (
    AllLampsOff,
    CameraReady,
    Capture,
    ConfigureCamera,
    ConfigureSpectrometer,
    DarkFrame,
    ExposureSet,
    FrameCaptured,
    MeasureSpectrum,
    RelayState,
    SetExposure,
    SettingReadBack,
    SpectrometerReady,
    SpectrumMeasured,
    Step,
    StepResult,
    SwitchLamp,
    Wait,
    Waited,
)
from tests.rig.fakes import fake_config, fake_config_data

WAVELENGTH_NM = np.linspace(380.0, 780.0, 101)


@dataclass
class Bench:
    """Scripted readings: a linear camera with a white level, a lamp settling exponentially."""

    direct_saturates_at_s: float = 1 / 50
    band_snr_at_1s: float = 40.0
    camera_range_s: tuple[float, float] = (1 / 8000, 30.0)
    n_channels: int = 2
    settle_tau_s: float = 15.0
    never_settles: bool = False
    dark_lamp: bool = False
    exposure_choices_s: list[float] | None = None
    frame_suffix: str = ".dng"
    time_s: float = 0.0
    lit: set[int] = field(default_factory=set)
    switched_on_s: float = 0.0

    def respond(self, step: Step) -> StepResult:
        match step:
            case AllLampsOff():
                self.lit.clear()
                return self._relays()
            case SwitchLamp():
                if step.on:
                    self.lit.add(step.channel)
                    self.switched_on_s = self.time_s
                else:
                    self.lit.discard(step.channel)
                return self._relays()
            case ConfigureCamera():
                settings = tuple(SettingReadBack(n, v, v) for n, v in step.settings)
                return CameraReady(settings, self.camera_range_s)
            case ConfigureSpectrometer():
                return SpectrometerReady(step.exposure_ms)
            case MeasureSpectrum():
                self.time_s += 2.0
                return self._spectrum(step)
            case Wait():
                self.time_s += step.seconds
                return Waited(self.time_s, step.seconds)
            case SetExposure():
                actual = step.exposure_s
                if self.exposure_choices_s is not None:
                    actual = min(self.exposure_choices_s, key=lambda c: abs(math.log(c / actual)))
                return ExposureSet(step.exposure_s, actual)
            case Capture() | DarkFrame():
                return self._frame(step)
        raise AssertionError(f"unexpected step {step}")

    def _relays(self) -> RelayState:
        return RelayState(self.time_s, tuple(c in self.lit for c in range(1, self.n_channels + 1)))

    def _spectrum(self, step: MeasureSpectrum) -> SpectrumMeasured:
        on_for = self.time_s - self.switched_on_s
        if self.never_settles:
            drift = 1.0 + 0.05 * math.sin(on_for / 4.0)
        else:
            drift = 1.0 + 0.3 * math.exp(-on_for / self.settle_tau_s)
        values = np.zeros_like(WAVELENGTH_NM) if self.dark_lamp else drift * (WAVELENGTH_NM / 500)
        file = f"spectra/{step.lamp}/{step.purpose}-{step.index:03d}.csv"
        return SpectrumMeasured(self.time_s, file, WAVELENGTH_NM, values, "W", None)

    def _frame(self, step: Capture | DarkFrame) -> FrameCaptured:
        self.time_s += step.exposure_s + 1.0
        stream = "scene" if isinstance(step, Capture) else "dark"
        file = f"frames/{step.lamp}/{stream}-{step.index:03d}{self.frame_suffix}"
        stats = None
        if isinstance(step, Capture):
            ratio = step.exposure_s / self.direct_saturates_at_s
            saturated = 0.0 if ratio <= 1 else min(1.0, math.log(ratio) / 3)
            snr = self.band_snr_at_1s * math.sqrt(step.exposure_s)
            stats = FrameStats(saturated, snr, snr**2)
        return FrameCaptured(self.time_s, file, step.exposure_s, step.exposure_s, file, stats)


def drive(plan: Plan, respond: Callable[[Step], StepResult]) -> list[Step]:
    """Walk ``plan`` to the end, sending back ``respond(step)`` for every step."""
    steps: list[Step] = []
    step = next(plan)
    while True:
        steps.append(step)
        try:
            step = plan.send(respond(step))
        except StopIteration:
            return steps


def plan_for(config: RigConfig) -> Plan:
    return standard_capture(StandardCaptureArgs.from_config(config))


def one_lamp_config(**hdr: object) -> RigConfig:
    data = fake_config_data()
    data["lamps"] = data["lamps"][:1]
    data["hdr"] = {**data["hdr"], **hdr}
    return RigConfig.model_validate(data)


def bracket_of(steps: list[Step], lamp: str = "LED-B3") -> list[float]:
    return [s.exposure_s for s in steps if isinstance(s, Capture) and s.lamp == lamp]


def check_bracket(bench: Bench, hdr: HdrPolicy, exposures: list[float]) -> None:
    """The bracket meets the policy, and neighbouring frames are at most step_stops apart."""
    ordered = sorted(exposures)
    shortest = bench._frame(Capture("x", 0, ordered[0])).stats
    longest = bench._frame(Capture("x", 0, ordered[-1])).stats
    assert shortest is not None and longest is not None
    assert shortest.direct_saturated_fraction <= hdr.max_direct_saturated_fraction
    assert longest.band_snr >= hdr.min_band_snr
    gaps_stops = np.diff(np.log2(ordered))
    assert np.all(gaps_stops <= hdr.step_stops + 1e-9)
    assert np.all(gaps_stops > 0)


class TestStandardPlan:
    def test_order_of_steps_for_each_lamp(self) -> None:
        config = fake_config()
        steps = drive(plan_for(config), Bench().respond)
        assert [type(s) for s in steps[:4]] == [
            AllLampsOff,
            ConfigureCamera,
            ConfigureSpectrometer,
            SwitchLamp,
        ]
        for lamp in config.lamps:
            mine = [s for s in steps if s.lamp_name == lamp.name]
            kinds = [type(s).__name__ for s in mine]
            on, off = kinds.index("SwitchLamp"), len(kinds) - 1 - kinds[::-1].index("SwitchLamp")
            switch_on, switch_off = mine[on], mine[off]
            assert isinstance(switch_on, SwitchLamp) and switch_on.on
            assert isinstance(switch_off, SwitchLamp) and not switch_off.on
            during = mine[on + 1 : off]
            warmup = [s for s in during if isinstance(s, MeasureSpectrum) and s.purpose == "warmup"]
            reference = [
                s for s in during if isinstance(s, MeasureSpectrum) and s.purpose == "reference"
            ]
            assert len(warmup) >= 1 + lamp.warmup.stable_pairs
            assert len(reference) == config.spectrum.repeats
            # warm-up first, then reference spectra, then the bracket; darks only after switch-off
            assert during.index(reference[0]) > during.index(warmup[-1])
            first_capture = next(i for i, s in enumerate(during) if isinstance(s, Capture))
            assert first_capture > during.index(reference[-1])
            assert not any(isinstance(s, DarkFrame) for s in during)
            darks = [s for s in mine[off:] if isinstance(s, DarkFrame)]
            bracket = sorted(bracket_of(steps, lamp.name))
            assert sorted({d.exposure_s for d in darks}) == bracket
            assert len(darks) == config.dark_frames * len(bracket)
            assert all(d.count == len(darks) for d in darks)

    def test_keys_are_unique_and_the_same_for_the_same_readings(self) -> None:
        first = [s.key for s in drive(plan_for(fake_config()), Bench().respond)]
        second = [s.key for s in drive(plan_for(fake_config()), Bench().respond)]
        assert first == second
        assert len(set(first)) == len(first)
        assert "lamp/LED-B3/scene/000" in first and "lamp/FL2/dark/000" in first

    def test_every_wait_precedes_the_warmup_spectrum_with_its_index(self) -> None:
        steps = drive(plan_for(fake_config()), Bench().respond)
        for position, step in enumerate(steps):
            if isinstance(step, Wait):
                following = steps[position + 1]
                assert isinstance(following, MeasureSpectrum)
                assert (following.lamp, following.index) == (step.lamp, step.index)

    def test_rebuilds_from_its_recorded_arguments(self) -> None:
        config = fake_config()
        args = StandardCaptureArgs.from_config(config).model_dump(mode="json")
        rebuilt = drive(build_plan("standard_capture", args), Bench().respond)
        assert rebuilt == drive(plan_for(config), Bench().respond)

    def test_unknown_plan_name(self) -> None:
        with pytest.raises(PlanProtocolError, match="unknown plan 'nope'"):
            build_plan("nope", {})

    def test_a_wrong_result_type_is_a_protocol_error(self) -> None:
        plan = plan_for(fake_config())
        next(plan)
        with pytest.raises(PlanProtocolError, match="expected a RelayState"):
            plan.send(Waited(0.0, 1.0))


class TestWarmup:
    def test_a_settling_lamp_is_measured_until_stable(self) -> None:
        bench = Bench(settle_tau_s=15.0)
        config = one_lamp_config()
        steps = drive(plan_for(config), bench.respond)
        warmup = [s for s in steps if isinstance(s, MeasureSpectrum) and s.purpose == "warmup"]
        # relative change 0.3·e^(−t/15)·(1 − e^(−10/15)) over 10 s must fall below 0.2 %, twice
        assert 6 <= len(warmup) <= 10

    def test_a_lamp_that_never_settles_fails_with_the_reason(self) -> None:
        bench = Bench(never_settles=True)
        config = one_lamp_config()
        plan = plan_for(config)
        with pytest.raises(LampNotStable) as failure:
            drive(plan, bench.respond)
        policy = config.lamps[0].warmup
        message = str(failure.value)
        assert "LED-B3 did not settle within warmup.timeout_s = 300 s" in message
        assert "tolerance 0.20%" in message
        assert failure.value.reason == "lamp_not_stable"
        # it gave up at the timeout (give or take one 2 s measurement), not before
        on_for_s = bench.time_s - bench.switched_on_s
        assert policy.timeout_s - policy.interval_s - 2.0 <= on_for_s <= policy.timeout_s + 2.0

    def test_a_dark_lamp_fails_at_once(self) -> None:
        bench = Bench(dark_lamp=True)
        with pytest.raises(LampDark, match="gives no light"):
            drive(plan_for(one_lamp_config()), bench.respond)
        assert bench.time_s == 2.0

    def test_relative_change(self) -> None:
        a = SpectrumMeasured(0, "f", WAVELENGTH_NM, np.ones(101), "W", None)
        b = SpectrumMeasured(0, "f", WAVELENGTH_NM, np.full(101, 1.01), "W", None)
        assert relative_change(a, b) == pytest.approx(0.01 / 1.01)
        coarse = SpectrumMeasured(0, "f", WAVELENGTH_NM[::4], np.ones(26), "W", None)
        assert relative_change(coarse, a) == pytest.approx(0.0)
        zero = SpectrumMeasured(0, "f", WAVELENGTH_NM, np.zeros(101), "W", None)
        assert relative_change(a, zero) == math.inf


class TestAutoBracketing:
    def test_converges_from_a_start_that_is_too_short(self) -> None:
        bench = Bench()
        config = one_lamp_config(start_exposure_s="1/4000", min_band_snr=30)
        exposures = bracket_of(drive(plan_for(config), bench.respond))
        assert exposures[0] == pytest.approx(1 / 4000)
        assert exposures == sorted(exposures)  # extended upward only
        check_bracket(bench, config.hdr, exposures)

    def test_converges_from_a_start_that_is_too_long(self) -> None:
        bench = Bench()
        config = one_lamp_config(start_exposure_s=4, min_band_snr=30)
        exposures = bracket_of(drive(plan_for(config), bench.respond))
        assert exposures[0] == 4
        assert exposures == sorted(exposures, reverse=True)  # extended downward only
        check_bracket(bench, config.hdr, exposures)

    def test_extends_both_ways_when_needed(self) -> None:
        bench = Bench()
        config = one_lamp_config(start_exposure_s="1/15", min_band_snr=30)
        exposures = bracket_of(drive(plan_for(config), bench.respond))
        assert min(exposures) < 1 / 15 < max(exposures)
        check_bracket(bench, config.hdr, exposures)

    def test_a_satisfied_first_frame_is_the_whole_bracket(self) -> None:
        bench = Bench(direct_saturates_at_s=1.0, band_snr_at_1s=100)
        config = one_lamp_config(start_exposure_s=0.5, min_band_snr=30)
        assert bracket_of(drive(plan_for(config), bench.respond)) == [0.5]

    def test_default_start_is_the_geometric_mean_of_the_range(self) -> None:
        config = one_lamp_config(start_exposure_s=None, min_exposure_s="1/1000", max_exposure_s=1)
        exposures = bracket_of(drive(plan_for(config), Bench().respond))
        assert exposures[0] == pytest.approx(math.sqrt(1 / 1000))

    def test_snaps_to_the_exposures_the_camera_offers(self) -> None:
        choices = [2.0**k for k in range(-12, 5)]
        bench = Bench(exposure_choices_s=choices)
        config = one_lamp_config(start_exposure_s="1/100", min_band_snr=30)
        exposures = bracket_of(drive(plan_for(config), bench.respond))
        assert all(e in choices for e in exposures)
        check_bracket(bench, config.hdr, exposures)

    def test_saturated_at_the_shortest_exposure(self) -> None:
        bench = Bench(direct_saturates_at_s=1e-5)
        config = one_lamp_config(min_exposure_s="1/4000", start_exposure_s="1/1000")
        with pytest.raises(
            BracketImpossible, match=r"saturated even at the shortest allowed exposure 1/4000 s"
        ):
            drive(plan_for(config), bench.respond)

    def test_too_little_signal_at_the_longest_exposure(self) -> None:
        bench = Bench(band_snr_at_1s=1.0)
        config = one_lamp_config(max_exposure_s=2, max_frames=20)
        with pytest.raises(
            BracketImpossible, match=r"longest allowed exposure 2 s, below hdr.min_band_snr = 30"
        ):
            drive(plan_for(config), bench.respond)

    def test_frame_budget(self) -> None:
        bench = Bench(band_snr_at_1s=5.0)
        config = one_lamp_config(start_exposure_s="1/4000", max_frames=3, max_exposure_s=30)
        with pytest.raises(BracketImpossible, match=r"more than hdr\.max_frames = 3 frames"):
            drive(plan_for(config), bench.respond)

    def test_a_camera_without_a_finer_exposure(self) -> None:
        bench = Bench(exposure_choices_s=[1 / 60, 1 / 15])
        config = one_lamp_config(start_exposure_s="1/60", step_stops=0.5, min_band_snr=30)
        with pytest.raises(BracketImpossible, match="offers no exposure between them"):
            drive(plan_for(config), bench.respond)

    def test_a_jpeg_frame_is_refused(self) -> None:
        bench = Bench(frame_suffix=".JPG")
        with pytest.raises(WrongFrameFormat, match="not a RAW file"):
            drive(plan_for(one_lamp_config()), bench.respond)


class TestLimits:
    def test_exposure_range_beyond_the_camera_fails_before_any_lamp(self) -> None:
        bench = Bench(camera_range_s=(1 / 1000, 4.0))
        config = one_lamp_config(min_exposure_s="1/4000", max_exposure_s=8)
        steps: list[Step] = []

        def respond(step: Step) -> StepResult:
            steps.append(step)
            return bench.respond(step)

        with pytest.raises(LimitsExceeded) as failure:
            drive(plan_for(config), respond)
        assert "shorter than the camera's shortest 1/1000 s" in str(failure.value)
        assert "longer than the camera's longest 4 s" in str(failure.value)
        assert failure.value.exit_code == 2
        assert not any(isinstance(s, SwitchLamp) for s in steps)

    def test_a_lamp_channel_missing_from_the_board_fails_before_any_lamp(self) -> None:
        bench = Bench(n_channels=1)
        with pytest.raises(
            LimitsExceeded, match="the relay board has 1 channels, but FL2 on channel 2"
        ):
            drive(plan_for(fake_config()), bench.respond)
        assert not bench.lit
