"""rig.config: the shipped configuration, and errors that name the field, the value and what is allowed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from rig.config import ConfigError, RigConfig, load_config, parse_config, parse_exposure_s
from tests.rig.fakes import fake_config_data, write_config

ROOT = Path(__file__).resolve().parents[2]


def issues_for(data: dict[str, Any]) -> list[str]:
    with pytest.raises(ConfigError) as failure:
        parse_config(json.dumps(data, indent=2), source="rig.yaml")
    return str(failure.value).splitlines()


def test_the_shipped_config_loads_and_uses_the_twin() -> None:
    config = load_config(ROOT / "config.yaml")
    assert config.devices.simulated
    assert {lamp.kind for lamp in config.lamps} == {"led", "fluorescent"}
    assert config.hdr.start_exposure_s == pytest.approx(1 / 60)
    assert config.camera.exposure_range_s == pytest.approx((1 / 8000, 30.0))
    assert config.output_dir == ROOT / "sessions"  # relative to the file, not the working directory


def test_every_model_forbids_unknown_keys() -> None:
    def walk(model: type[Any]) -> list[type[Any]]:
        found = [model]
        for field in model.model_fields.values():
            for candidate in _model_types(field.annotation):
                found.extend(walk(candidate))
        return found

    for model in walk(RigConfig):
        assert model.model_config.get("extra") == "forbid", model.__name__


def _model_types(annotation: object) -> list[type[Any]]:
    import typing

    from pydantic import BaseModel

    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [t for arg in typing.get_args(annotation) for t in _model_types(arg)]


class TestReadableErrors:
    def test_a_typo_names_the_closest_key(self) -> None:
        data = fake_config_data()
        data["lamps"][1]["chanel"] = data["lamps"][1].pop("channel")
        issues = issues_for(data)
        assert any(
            "lamps[1].chanel: unknown key 'chanel' (did you mean 'channel'?)" in i for i in issues
        )
        assert any("lamps[1].channel: required key is missing" in i for i in issues)

    def test_a_typo_at_the_top_level(self) -> None:
        data = fake_config_data()
        data["hrd"] = data.pop("hdr")
        (issue,) = issues_for(data)
        assert "hrd: unknown key 'hrd' (did you mean 'hdr'?)" in issue

    def test_a_value_out_of_range_names_the_allowed_range(self) -> None:
        data = fake_config_data()
        data["hdr"]["step_stops"] = 9
        data["lamps"][0]["warmup"]["tolerance"] = 0
        issues = issues_for(data)
        assert any("hdr.step_stops: 9 is out of range; must be > 0 and ≤ 6" in i for i in issues)
        assert any(
            "lamps[0].warmup.tolerance: 0 is out of range; must be > 0 and < 1" in i for i in issues
        )

    def test_a_spectrometer_bandwidth_is_bounded_as_an_estimate_bounds_it(self) -> None:
        """The rig's config took up to 100 nm, which the estimate then refused; one bound now."""
        data = fake_config_data()
        data["devices"]["spectrometer"] = {
            "kind": "files",
            "directory": "spectra",
            "bandwidth_nm": 80,
        }
        issues = issues_for(data)
        assert any(
            "devices.spectrometer.bandwidth_nm: 80 is out of range; must be > 0 and ≤ 50" in i
            for i in issues
        ), issues

    def test_an_unknown_device_kind_suggests_the_closest(self) -> None:
        data = fake_config_data()
        data["devices"]["spectrometer"] = {"kind": "pr665", "port": "/dev/ttyACM0"}
        (issue,) = issues_for(data)
        assert "devices.spectrometer: kind 'pr665' is not known (did you mean 'pr655'?)" in issue
        assert "allowed kinds: pr655, pr670, cs2000, seabreeze, argyll, files, twin" in issue

    def test_a_bad_choice_lists_the_choices(self) -> None:
        data = fake_config_data()
        data["lamps"][0]["kind"] = "florescent"
        (issue,) = issues_for(data)
        assert "lamps[0].kind: 'florescent' is not allowed (did you mean 'fluorescent'?)" in issue
        assert "'led', 'fluorescent', 'halogen', 'narrowband' or 'other'" in issue

    def test_fields_of_a_device_kind_are_checked_for_that_kind(self) -> None:
        data = fake_config_data()
        data["devices"]["relays"] = {"kind": "lcus", "port": "/dev/ttyUSB0", "channels": 3}
        (issue,) = issues_for(data)
        assert "devices.relays.channels: 3 is not allowed; allowed: 1, 2, 4 or 8" in issue

    def test_a_real_camera_may_work_with_twin_lamps(self) -> None:
        data = fake_config_data()
        data["devices"]["camera"] = {"kind": "gphoto2"}
        config = RigConfig.model_validate(data)
        assert config.devices.twin_roles() == ("spectrometer", "relays")

    def test_a_twin_spectrometer_needs_twin_lamps(self) -> None:
        data = fake_config_data()
        data["devices"]["relays"] = {"kind": "lcus", "port": "/dev/ttyUSB0", "channels": 2}
        (issue,) = issues_for(data)
        assert (
            "devices.spectrometer and devices.camera are 'twin' but devices.relays is 'lcus'"
            in issue
        )
        assert "sees only the twin's lamps" in issue

    def test_an_ocean_spectrometer_needs_its_calibration(self) -> None:
        data = fake_config_data()
        data["devices"]["spectrometer"] = {"kind": "seabreeze"}
        data["devices"]["relays"] = {"kind": "lcus", "port": "/dev/ttyUSB0", "channels": 2}
        data["devices"]["camera"] = {"kind": "gphoto2"}
        (issue,) = issues_for(data)
        assert "devices.spectrometer: calibration_file is missing" in issue
        data["devices"]["spectrometer"]["allow_uncalibrated"] = True
        assert RigConfig.model_validate(data).devices.spectrometer_takes_dark

    def test_cross_field_checks(self) -> None:
        data = fake_config_data()
        data["hdr"]["min_exposure_s"] = 2
        data["hdr"]["max_exposure_s"] = 1
        data["lamps"][1]["name"] = "led-b3"
        issues = issues_for(data)
        assert any(
            "hdr: min_exposure_s = 2 s is not below max_exposure_s = 1 s" in i for i in issues
        )
        assert any("repeats lamps[0].name; lamp names must be unique" in i for i in issues)

    def test_unsafe_lamp_names(self) -> None:
        data = fake_config_data()
        data["lamps"][0]["name"] = "../LED"
        (issue,) = issues_for(data)
        assert "lamps[0].name: '../LED' is not allowed; use 1–64 letters, digits" in issue

    def test_errors_carry_the_line_in_the_file(self) -> None:
        text = (ROOT / "config.yaml").read_text().replace("channel: 2", "channel: 0")
        line = next(n for n, t in enumerate(text.splitlines(), 1) if "channel: 0" in t)
        with pytest.raises(ConfigError) as failure:
            parse_config(text, source="config.yaml")
        assert str(failure.value).startswith(
            f"config.yaml:{line}: lamps[1].channel: 0 is out of range"
        )

    def test_yaml_syntax_error_gives_line_and_column(self) -> None:
        with pytest.raises(ConfigError) as failure:
            parse_config("seed: 1\nlamps: [a, b\ndevices: {}\n", source="bad.yaml")
        message = str(failure.value)
        assert message.startswith("bad.yaml:3: invalid YAML, column 8")

    def test_duplicate_keys_are_an_error(self) -> None:
        with pytest.raises(
            ConfigError,
            match=r"bad.yaml:2: invalid YAML, column 1: duplicate key 'seed' \(first on line 1\)",
        ):
            parse_config("seed: 1\nseed: 2\n", source="bad.yaml")

    def test_python_tags_are_refused(self) -> None:
        with pytest.raises(ConfigError, match="invalid YAML"):
            parse_config("seed: !!python/object/apply:os.system ['true']\n", source="evil.yaml")

    def test_empty_and_non_mapping_files(self, tmp_path: Path) -> None:
        with pytest.raises(ConfigError, match="the file is empty"):
            parse_config("", source="empty.yaml")
        with pytest.raises(ConfigError, match="expected a mapping of keys at the top level"):
            parse_config("- 1\n- 2\n", source="list.yaml")
        with pytest.raises(ConfigError, match="file not found; pass --config PATH"):
            load_config(tmp_path / "missing.yaml")

    def test_the_command_prints_one_line_per_issue_and_exits_2(self, tmp_path: Path) -> None:
        data = fake_config_data()
        data["hdr"]["max_frame"] = 4
        data["dark_frames"] = -1
        path = write_config(tmp_path / "rig.yaml", data)
        done = subprocess.run(
            [sys.executable, "-c", "from rig.cli import main; main()", "dry-run", "-c", str(path)],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert done.returncode == 2
        lines = done.stderr.splitlines()
        assert len(lines) == 2, done.stderr
        assert all(line.startswith(f"rig: error: {path}:") for line in lines)
        assert "Traceback" not in done.stderr
        assert "unknown key 'max_frame' (did you mean 'max_frames'?)" in done.stderr
        assert "dark_frames: -1 is out of range; must be ≥ 0" in done.stderr


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("1/125", 1 / 125), ("1/8000s", 1 / 8000), ("2.5s", 2.5), ("40ms", 0.04), ("30", 30.0)],
)
def test_exposure_notations(text: str, seconds: float) -> None:
    assert parse_exposure_s(text) == pytest.approx(seconds)


def test_a_bad_exposure_says_how_to_write_one() -> None:
    data = fake_config_data()
    data["hdr"]["max_exposure_s"] = "one second"
    (issue,) = issues_for(data)
    assert "'one second' is not an exposure time; write seconds like 0.01" in issue
