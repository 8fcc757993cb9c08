"""A session from anyone: everything planted in it is refused in one line (exit 2) or harmless.

Each case takes a session that ``rig resume`` would continue, plants what a hostile sender could
(links to files outside, a configuration snapshot naming other ports and files, a FIFO, leftovers
under temporary names), and runs the command a user would run. An outside directory stands for the
rest of the disk: :func:`tests.rig.hostile.watching` fails the test if anything in it changes, and
its audit hook records every file opened, renamed, removed or truncated there and every socket
connected, for the test to assert none.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.base import Disconnected
from drivers.local_files import UnsafeLocalPath, write_atomically
from mocks.bench import TwinFaults
from mocks.fake_gphoto2 import CameraFault
from rig import station
from rig.capture import run_capture
from rig.config import RigConfig
from rig.records import check_session_path
from rig.resume import run_resume
from rig.runner import RetryPolicy
from rig.session import SessionWriter, read_session
from rig.twin import twin_station_builder
from tests.rig.fakes import FakeRig, fake_config, fake_config_data, make_fake_rig, write_config
from tests.rig.hostile import OutsideWatch, watching
from tests.rig.test_cli import run_cli
from tests.rig.twin_setup import twin_config_data

NO_BACKOFF = RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)
SECRET = b"the user's own file, which no session may touch\n"


@pytest.fixture(scope="module")
def failed_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fake-rig session whose camera went away at the second frame: ``rig resume`` continues it."""
    rig = make_fake_rig()
    rig.camera.io.faults["capture"] = [None, Disconnected("FakeCam", "unplugged")]
    directory = tmp_path_factory.mktemp("failed")
    outcome = run_capture(
        fake_config(directory / "sessions"), builder=rig.builder, retry=NO_BACKOFF
    )
    assert outcome.reason == "disconnected"
    return outcome.session


@pytest.fixture
def outside(tmp_path: Path) -> Path:
    """The rest of the user's disk: a file and a directory the session must never reach."""
    directory = tmp_path / "outside"
    (directory / "dir").mkdir(parents=True)
    (directory / "victim").write_bytes(SECRET)
    return directory


@pytest.fixture
def session(failed_session: Path, tmp_path: Path) -> Path:
    """A copy of the failed session, for a test to plant things in."""
    copy = tmp_path / "sessions" / failed_session.name
    shutil.copytree(failed_session, copy, symlinks=True)
    return copy


@pytest.fixture
def user_config(tmp_path: Path) -> Path:
    """The user's own configuration: the one the session was captured with."""
    return write_config(tmp_path / "rig.yaml", fake_config_data("sessions"))


@pytest.fixture
def fake_station(monkeypatch: pytest.MonkeyPatch) -> FakeRig:
    rig = make_fake_rig()
    monkeypatch.setitem(station.STATION_BUILDERS, "twin", rig.builder)
    return rig


@pytest.fixture
def resume(
    session: Path,
    user_config: Path,
    outside: Path,
    fake_station: FakeRig,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> Iterator[Callable[..., tuple[int, str, OutsideWatch]]]:
    """``rig resume SESSION -c rig.yaml`` watching ``outside``: exit code, stderr, the watch."""

    def run(*extra: str) -> tuple[int, str, OutsideWatch]:
        log_before = (session / "log.jsonl").read_bytes()
        with watching(outside) as watch:
            code = run_cli(
                ["resume", str(session), "-q", "-c", str(user_config), *extra], monkeypatch
            )
        err = capsys.readouterr().err
        assert "Traceback" not in err
        if code == 2:  # refused: one line, and the session as it was
            assert err.count("\n") == 1 and err.startswith("rig: error: "), err
            assert (session / "log.jsonl").read_bytes() == log_before
        assert watch.touches == [] and watch.connections == []
        return code, err, watch

    yield run


def _edit_start_config(session: Path, edit: Callable[[dict[str, Any]], None]) -> None:
    log = session / "log.jsonl"
    lines = log.read_text().splitlines()
    start = json.loads(lines[0])
    edit(start["config"])
    lines[0] = json.dumps(start)
    log.write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------- planted paths


@pytest.mark.parametrize("data_dir", ["frames", "spectra"])
def test_a_lamp_directory_linked_outside_is_refused(
    session: Path, outside: Path, resume: Any, fake_station: FakeRig, data_dir: str
) -> None:
    lamp_dir = session / data_dir / "LED-B3"
    shutil.rmtree(lamp_dir)
    lamp_dir.symlink_to(outside / "dir")
    code, err, _ = resume()
    assert code == 2
    assert f"{data_dir}/LED-B3 is a symbolic link to {outside / 'dir'}" in err
    assert "[session_format]" in err
    assert fake_station.relays.io.calls == {}  # refused before any device was opened
    assert list((outside / "dir").iterdir()) == []


@pytest.mark.parametrize(
    "name",
    [
        "frames/..incoming-2-00001.part.partial",  # the camera driver's temporary of run 2
        "frames/.incoming-2-00001.part",  # the writer's temporary
        "frames/LED-B3/scene-001.dng",  # the next frame's final name
        "spectra/LED-B3/warmup-000.2.csv",
        "transcripts/camera.run2.jsonl",  # the new run's transcript
        ".reserve",
    ],
)
def test_a_link_planted_where_the_rig_writes_is_refused(
    session: Path, outside: Path, resume: Any, name: str
) -> None:
    (session / name).symlink_to(outside / "victim")
    code, err, _ = resume()
    assert code == 2 and f"{name} is a symbolic link to {outside / 'victim'}" in err
    assert (outside / "victim").read_bytes() == SECRET


def test_a_fifo_in_the_session_is_refused_without_blocking(session: Path, resume: Any) -> None:
    os.mkfifo(session / "frames" / "LED-B3" / "scene-007.dng")
    code, err, _ = resume()
    assert code == 2 and "frames/LED-B3/scene-007.dng is a special file" in err


def test_leftovers_of_a_killed_run_are_removed_and_the_session_completes(
    session: Path, resume: Any
) -> None:
    planted = [
        session / "frames" / ".incoming-1-00009.part",
        session / "frames" / "..incoming-1-00009.part.partial",
        session / "spectra" / ".incoming-1-00010.part",
        session / ".reserve",
    ]
    for path in planted:
        path.write_bytes(b"half a download")
    code, _, _ = resume()
    assert code == 0
    assert not any(path.exists() for path in planted)
    assert read_session(session).status == "complete"


def test_a_path_with_a_trailing_newline_is_not_a_plain_name() -> None:
    with pytest.raises(ValueError, match="unsafe component"):
        check_session_path("frames/LED-B3/scene-000.dng\n")
    with pytest.raises(ValueError, match="unsafe component"):
        check_session_path("frames/LED-B3\n/scene-000.dng")


# ------------------------------------------------------------------- the configuration snapshot


def test_without_the_users_configuration_nothing_is_resumed(
    session: Path,
    tmp_path: Path,
    fake_station: FakeRig,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path / "sessions")  # no config.yaml here
    assert run_cli(["resume", str(session), "-q"], monkeypatch) == 2
    err = capsys.readouterr().err
    assert err == (
        "rig: error: config.yaml: file not found; pass --config PATH, or write one with "
        "`rig init` (`rig init --twin` for the digital twin)\n"
    )
    assert fake_station.relays.io.calls == {}


@pytest.mark.parametrize(
    "port",
    [
        "spy://loop://?file={outside}/victim",
        "loop://",
        "socket://127.0.0.1:{port}",
        "rfc2217://127.0.0.1:{port}",
    ],
)
def test_ports_named_by_the_session_are_never_opened(
    session: Path, outside: Path, resume: Any, port: str
) -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        server.settimeout(0.1)
        address = port.format(outside=outside, port=server.getsockname()[1])
        hardware = {
            "spectrometer": {"kind": "pr655", "port": address},
            "relays": {"kind": "lcus", "port": address, "channels": 2},
            "camera": {"kind": "gphoto2", "port": address},
        }
        _edit_start_config(session, lambda config: config.update(devices=hardware))
        code, err, _ = resume()
        with pytest.raises(TimeoutError):
            server.accept()  # nobody connected
    assert code == 2 and err.startswith(
        "rig: error: the configuration changes devices.spectrometer.kind (pr655 → twin), "
        "devices.relays.kind (lcus → twin), devices.camera.kind (gphoto2 → twin); "
    )
    assert (outside / "victim").read_bytes() == SECRET


def test_the_devices_are_opened_as_the_users_configuration_says(
    session: Path,
    tmp_path: Path,
    outside: Path,
    fake_station: FakeRig,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A snapshot that differs only in ports passes; the user's ports are the ones opened."""
    opened: list[RigConfig] = []

    def builder(config: RigConfig, transcripts: Any) -> station.Station:
        opened.append(config)
        return fake_station.builder(config, transcripts)

    monkeypatch.setitem(station.STATION_BUILDERS, "twin", builder)
    _edit_start_config(
        session, lambda config: config["devices"]["spectrometer"].update(timeout_s=1)
    )
    with watching(outside) as watch:
        outcome = run_resume(session, fake_config(tmp_path / "sessions"), retry=NO_BACKOFF)
    assert outcome.exit_status == "success" and watch.touches == []
    assert [config.devices.spectrometer.timeout_s for config in opened] == [5]


@pytest.mark.usefixtures("fast_camera_recovery")
@pytest.mark.parametrize("field", ["state_file", "data_dir"])
def test_a_state_file_or_data_directory_named_by_the_session_is_refused(
    tmp_path: Path, outside: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any, field: str
) -> None:
    """A twin session whose snapshot names files outside: refused before the twin is built."""
    data = twin_config_data(tmp_path / "sessions")
    config = RigConfig.model_validate(data)
    builder = twin_station_builder(faults=TwinFaults(camera=[CameraFault("unplug", skip=1)]))
    failed = run_capture(config, builder=builder, retry=NO_BACKOFF)
    assert failed.reason == "disconnected"
    role = "relays" if field == "state_file" else "camera"
    _edit_start_config(
        failed.session,
        lambda snapshot: snapshot["devices"][role].update({field: str(outside / "victim")}),
    )
    user = write_config(tmp_path / "rig.yaml", config.model_dump(mode="json"))
    with watching(outside) as watch:
        code = run_cli(["resume", str(failed.session), "-q", "-c", str(user)], monkeypatch)
    err = capsys.readouterr().err
    assert code == 2 and f"the configuration changes devices.{role}.{field}" in err
    assert watch.touches == [] and (outside / "victim").read_bytes() == SECRET


# ---------------------------------------------------------------------------- malformed records


def _edit_first(session: Path, key: str, edit: Callable[[dict[str, Any]], object]) -> int:
    log = session / "log.jsonl"
    lines = log.read_text().splitlines()
    for number, line in enumerate(lines):
        record = json.loads(line)
        if record.get("type") == "step" and record["key"] == key:
            edit(record)
            lines[number] = json.dumps(record)
            log.write_text("\n".join(lines) + "\n")
            return number + 1
    raise AssertionError(key)


@pytest.mark.parametrize(
    ("key", "edit", "says"),
    [
        ("lamp/LED-B3/switch-on", lambda r: r["result"].pop("time_s"), "KeyError: 'time_s'"),
        ("lamp/LED-B3/warmup/000", lambda r: r["result"].pop("file"), "KeyError: 'file'"),
        ("lamp/LED-B3/warmup/000", lambda r: r["result"].pop("units"), "KeyError: 'units'"),
        ("lamp/LED-B3/scene/000", lambda r: r["result"].update(time_s=10**400), "OverflowError"),
        ("lamp/LED-B3/scene/000", lambda r: r["params"].update(index="x"), "ValueError"),
        ("lamp/LED-B3/scene/000", lambda r: r["params"].update(index=5), "action and params"),
        ("start/camera", lambda r: r["result"].update(settings=[{"name": 1}]), "TypeError"),
        ("lamp/LED-B3/scene/000", lambda r: r["result"].update(stats={"x": 1}), "TypeError"),
        ("lamp/LED-B3/scene/000/exposure", lambda r: r.update(action="Nope"), "unknown step"),
    ],
)
def test_a_malformed_record_is_a_one_line_refusal(
    session: Path, resume: Any, key: str, edit: Callable[[dict[str, Any]], object], says: str
) -> None:
    line = _edit_first(session, key, edit)
    code, err, _ = resume()
    assert code == 2 and "[session_format]" in err
    assert f"line {line}: step {key}" in err and says in err


def test_an_invalid_configuration_snapshot_is_a_one_line_refusal(
    session: Path, resume: Any
) -> None:
    _edit_start_config(session, lambda config: config["hdr"].update(max_frames="many"))
    code, err, _ = resume()
    assert code == 2 and "line 1: the recorded configuration is invalid: hdr.max_frames" in err


# ------------------------------------------------------------------------ the camera's download


def test_the_camera_never_writes_through_a_planted_temporary(tmp_path: Path, outside: Path) -> None:
    target = tmp_path / "frames" / ".incoming-1-00001.part"
    target.parent.mkdir()
    (target.parent / f".{target.name}.partial").symlink_to(outside / "victim")
    with watching(outside), pytest.raises(UnsafeLocalPath, match="is a symbolic link"):
        write_atomically(target, b"a frame")
    assert not target.exists()


def test_an_unsynced_download_is_synced_by_the_session_before_its_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The rig downloads with sync=False: the session's commit_file syncs the file and its
    # directory before the record that acknowledges it.
    synced: list[str] = []
    for name in ("fsync", "fdatasync"):
        if hasattr(os, name):
            real = getattr(os, name)

            def recording(fd: int, real: Callable[[int], None] = real) -> None:
                synced.append(str(Path(f"/proc/self/fd/{fd}").readlink()))
                real(fd)

            monkeypatch.setattr(os, name, recording)
    writer = SessionWriter(tmp_path / "session")
    temporary = writer.incoming_path("frames/lamp")
    synced.clear()
    write_atomically(temporary, b"a frame", sync=False)
    assert synced == [] and temporary.read_bytes() == b"a frame"
    writer.commit_file(temporary, "frames/lamp/scene-000.dng", key="k", role="frame")
    log = str(tmp_path / "session" / "log.jsonl")
    assert synced.index(str(temporary)) < synced.index(str(temporary.parent)) < synced.index(log)


def test_the_camera_never_writes_into_a_linked_directory(tmp_path: Path, outside: Path) -> None:
    (tmp_path / "frames").symlink_to(outside / "dir")
    with watching(outside), pytest.raises(UnsafeLocalPath, match="frames is a symbolic link"):
        write_atomically(tmp_path / "frames" / "x.dng", b"a frame")


def test_the_session_writer_refuses_a_name_planted_while_it_runs(
    tmp_path: Path, outside: Path
) -> None:
    writer = SessionWriter(tmp_path / "session")
    (tmp_path / "session" / "frames" / "..incoming-1-00001.part.partial").symlink_to(
        outside / "victim"
    )
    with watching(outside), pytest.raises(Exception, match="planted in the session"):
        writer.incoming_path()
    (tmp_path / "session" / "frames" / "LED-B3").symlink_to(outside / "dir")
    temporary = writer.incoming_path()
    temporary.write_bytes(b"a frame")
    with watching(outside), pytest.raises(Exception, match="frames/LED-B3 is a symbolic link"):
        writer.commit_file(temporary, "frames/LED-B3/scene-000.dng", key="k", role="frame")
    writer.close()
