"""The ``rig`` command: capture, sessions, and errors as one line with the right exit code."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig import cli, station, twin
from rig.session import read_session
from tests.rig.fakes import fake_config_data, make_fake_rig, write_config


def run_cli(args: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    monkeypatch.setattr("sys.argv", ["rig", *args])
    with pytest.raises(SystemExit) as done:
        cli.main()
    return int(done.value.code or 0)


@pytest.fixture
def config_file(tmp_path: Path) -> Path:
    return write_config(tmp_path / "rig.yaml", fake_config_data("sessions"))


def test_capture_on_the_fake_rig(
    config_file: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_fake_rig()
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", rig.builder)
    assert run_cli(["capture", "-c", str(config_file), "--quiet"], monkeypatch) == 0
    out = capsys.readouterr().out
    assert "status: complete (completed): the plan completed" in out
    session_path = Path(out.splitlines()[0].removeprefix("session: "))
    assert (
        session_path.parent == config_file.parent / "sessions"
    )  # output_dir is relative to the file
    assert read_session(session_path).status == "complete"

    assert run_cli(["sessions", str(session_path.parent)], monkeypatch) == 0
    listing = capsys.readouterr().out
    assert session_path.name in listing and "complete" in listing


def test_capture_into_another_directory_with_progress(
    config_file: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", make_fake_rig().builder)
    out_dir = tmp_path / "elsewhere"
    assert run_cli(["capture", "-c", str(config_file), "--out", str(out_dir)], monkeypatch) == 0
    captured = capsys.readouterr()
    assert f"session: {out_dir}" in captured.out
    assert "done" in captured.err  # the progress bar's last description


def test_a_failed_capture_exits_1(
    config_file: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_fake_rig()
    rig.spectrometer.flicker["LED-B3"] = 0.05
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", rig.builder)
    assert run_cli(["capture", "-c", str(config_file), "-q"], monkeypatch) == 1
    assert "status: failed (lamp_not_stable): LED-B3 did not settle" in capsys.readouterr().out


def test_a_missing_twin_is_one_line_and_exit_1(
    config_file: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An installation without the twin's entry point (an analysis-only install) says so."""
    monkeypatch.setattr(twin, "entry_points", lambda group: [])
    twin.digital_twin.cache_clear()
    try:
        assert run_cli(["capture", "-c", str(config_file), "-q"], monkeypatch) == 1
    finally:
        twin.digital_twin.cache_clear()
    err = capsys.readouterr().err
    assert err.startswith("rig: error: the digital twin is not part of this installation")
    assert "pip install 'spectral-rig[sim]'" in err and err.count("\n") == 1
    assert not (config_file.parent / "sessions").exists()


def test_a_device_that_cannot_be_opened_leaves_no_session(
    config_file: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from drivers.base import DeviceNotFound

    def builder(config: object, transcripts: object) -> station.Station:
        raise DeviceNotFound("PR-655 on /dev/ttyACM0", "no such port")

    monkeypatch.setitem(station.STATION_BUILDERS, "twin", builder)
    assert run_cli(["capture", "-c", str(config_file), "-q"], monkeypatch) == 1
    err = capsys.readouterr().err
    assert (
        "rig: error: 1 device could not be opened, nothing was recorded: PR-655 on /dev/ttyACM0: "
        "no such port [devices_unavailable]"
    ) in err
    assert "the lamps could not be confirmed off" in err  # no relay board opened to say so
    assert "Traceback" not in err
    assert not (config_file.parent / "sessions").exists() or not any(
        (config_file.parent / "sessions").iterdir()
    )


def test_limits_are_bad_input(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    data = fake_config_data("sessions")
    data["lamps"][0]["channel"] = 4
    path = write_config(tmp_path / "rig.yaml", data)
    assert run_cli(["capture", "-c", str(path), "-q"], monkeypatch) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        "rig: error: lamps[0].channel: LED-B3 is on channel 4, but the relay board has 2"
    )
    assert err.count("\n") == 1


def test_sessions_of_a_missing_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run_cli(["sessions", str(tmp_path / "nope")], monkeypatch) == 2
    assert "is not a directory" in capsys.readouterr().err
    monkeypatch.chdir(tmp_path)
    assert run_cli(["sessions"], monkeypatch) == 0
    assert "no sessions in sessions" in capsys.readouterr().out
