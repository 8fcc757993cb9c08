"""rig.dryrun and ``rig dry-run``: steps, duration and limit violations with no devices."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import get_args

import pytest

from rig import cli
from rig.config import RigConfig, load_config
from rig.dryrun import ModelledBench, StepCostModel, check_limits, dry_run
from rig.errors import PlanProtocolError
from rig.resume import ResumeRules
from rig.steps import (
    STEP_TYPES,
    AnyStep,
    Capture,
    DarkFrame,
    KeepLampTimeline,
    MeasureSpectrum,
    Step,
    SwitchLamp,
    Wait,
    interpret,
)
from tests.rig.fakes import fake_config, fake_config_data, write_config

ROOT = Path(__file__).resolve().parents[2]


def run_cli(args: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    monkeypatch.setattr("sys.argv", ["rig", *args])
    with pytest.raises(SystemExit) as done:
        cli.main()
    return int(done.value.code or 0)


def test_the_shipped_configuration_walks_cleanly() -> None:
    from rig.config import load_config

    report = dry_run(load_config(ROOT / "config.yaml"))
    assert report.ok
    assert report.count(SwitchLamp) == 4
    assert report.count(Capture) >= 2
    assert report.count(DarkFrame) == 2 * report.count(Capture)
    # the duration is the sum of the modelled steps and includes the warm-up waits
    cost = StepCostModel(load_config(ROOT / "config.yaml").dry_run)
    assert report.duration_s == pytest.approx(sum(cost.duration_s(p.step) for p in report.steps))
    waits = sum(p.duration_s for p in report.steps if isinstance(p.step, Wait))
    assert waits >= 60.0
    starts = [p.start_s for p in report.steps]
    assert starts == sorted(starts)


def test_modelled_readings_drive_the_bracket() -> None:
    config = fake_config()
    report = dry_run(config)
    for lamp, frames in report.frames_per_lamp().items():
        exposures = sorted(
            p.step.exposure_s
            for p in report.steps
            if isinstance(p.step, Capture) and p.step.lamp == lamp
        )
        assert len(exposures) == frames
        assert exposures[0] <= config.dry_run.direct_saturates_at_s  # unsaturated shortest frame
    assert report.count(MeasureSpectrum) > 0


def test_limit_violations_are_all_reported() -> None:
    data = fake_config_data()
    data["camera"]["exposure_range_s"] = ["1/1000", 2]
    data["lamps"][1]["channel"] = 3
    data["lamps"].append({"name": "Halogen", "channel": 1, "kind": "halogen"})
    violations = {str(v) for v in check_limits(RigConfig.model_validate(data))}
    assert violations == {
        "hdr.min_exposure_s: 0.00025 s is shorter than the camera's shortest exposure 0.001 s "
        "(camera.exposure_range_s)",
        "hdr.max_exposure_s: 8 s is longer than the camera's longest exposure 2 s "
        "(camera.exposure_range_s)",
        "lamps[1].channel: FL2 is on channel 3, but the relay board has 2 (devices.relays.channels)",
        "lamps[2].channel: Halogen shares relay channel 1 with LED-B3: both would light together",
    }


def test_a_plan_that_fails_on_modelled_readings_is_reported() -> None:
    data = fake_config_data()
    data["hdr"]["max_frames"] = 1
    data["hdr"]["start_exposure_s"] = "1/4000"
    report = dry_run(RigConfig.model_validate(data))
    assert report.failure is not None
    assert report.failure.reason == "bracket_impossible"
    assert not report.ok


def test_the_command_prints_steps_and_summary(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_cli(["dry-run", "-c", str(ROOT / "config.yaml")], monkeypatch) == 0
    out = capsys.readouterr().out
    assert "start/all-lamps-off" in out and "lamp/FL2/dark/000" in out
    assert "estimated duration:" in out
    assert "limit violations: none" in out


def test_the_command_exits_2_on_violations(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    data = fake_config_data()
    data["lamps"][1]["channel"] = 1
    path = write_config(tmp_path / "rig.yaml", data)
    assert run_cli(["dry-run", "--summary", "-c", str(path)], monkeypatch) == 2
    out = capsys.readouterr().out
    assert "1 limit violation(s):" in out
    assert "FL2 shares relay channel 1 with LED-B3" in out
    assert "lamp/" not in out  # --summary lists no steps


# ----------------------------------------------------------------- one interpreter of the steps


def _all_step_classes() -> set[type[Step]]:
    found: set[type[Step]] = set()
    pending: list[type[Step]] = [Step]
    while pending:
        for subclass in pending.pop().__subclasses__():
            if subclass.__module__ == "rig.steps":
                found.add(subclass)
                pending.append(subclass)
    return found


def test_every_step_type_is_in_the_vocabulary_table() -> None:
    """A step class left out of AnyStep would escape mypy's exhaustive dispatch."""
    assert set(get_args(AnyStep)) == _all_step_classes()
    assert set(STEP_TYPES.values()) == _all_step_classes()


@dataclass(frozen=True)
class Unknown(Step):
    """A step of no known type, as a buggy plan might yield."""

    @property
    def key(self) -> str:
        return "unknown"


def test_an_unknown_step_is_an_error_for_every_interpreter() -> None:
    config = load_config(ROOT / "config.yaml")
    interpreters = [StepCostModel(config.dry_run), ModelledBench(config), ResumeRules()]
    for handlers in interpreters:
        with pytest.raises(PlanProtocolError, match="Unknown is not a step of the vocabulary"):
            interpret(Unknown(), handlers)  # type: ignore[arg-type]
    with pytest.raises(PlanProtocolError, match="Unknown is not a step"):
        StepCostModel(config.dry_run).duration_s(Unknown())  # type: ignore[arg-type]


def test_the_dry_run_prices_each_step_type_by_its_own_rule() -> None:
    cost = StepCostModel(load_config(ROOT / "config.yaml").dry_run)
    model = cost.model
    assert cost.duration_s(Wait("L", 0, 7.5)) == 7.5
    assert cost.duration_s(KeepLampTimeline("L", 2, 3.0)) == 3.0
    assert cost.duration_s(Capture("L", 0, 0.25)) == 0.25 + model.frame_download_s
    assert cost.duration_s(DarkFrame("L", 0, 2, 0.5)) == 0.5 + model.frame_download_s
    assert cost.duration_s(SwitchLamp("L", 1, True)) == model.relay_switch_s
    assert cost.duration_s(MeasureSpectrum("L", "warmup", 0)) == model.spectrum_measure_s
