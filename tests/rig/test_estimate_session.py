"""rig.estimate: a session (rendered DNG brackets, spectra, log) through calib's offline pipeline."""

from __future__ import annotations

import json
import shutil
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.core.errors import InputError
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.spectra import read_spectrum_csv
from calib.pipeline.run import OfflineOutcome
from rig.cli import app, main
from rig.errors import SessionFormatError
from rig.estimate import estimate_session
from rig.records import PlanInfo, SoftwareInfo, StartRecord, StepRecord, StopRecord
from rig.session import SessionWriter
from tests.rendered_capture import BRACKET_S, Capture, colour_lamps, shared_capture
from tests.rig.hostile import watching

LAMP_CONFIG = [
    {"name": "LED", "channel": 1, "kind": "led"},
    {"name": "FL", "channel": 2, "kind": "fluorescent"},
]


def _step(writer: SessionWriter, key: str, action: str, params: dict, result: dict) -> None:  # type: ignore[type-arg]
    writer.write(
        StepRecord,
        key=key,
        action=action,
        params=params,
        status="done",
        attempts=1,
        started_s=0.0,
        duration_s=0.1,
        result=result,
    )


def _frame(
    writer: SessionWriter, lamp: str, stream: str, index: int, source: Path, exposure_s: float
) -> None:
    key = f"lamp/{lamp}/{stream}/{index:03d}"
    temporary = writer.incoming_path()
    shutil.copyfile(source, temporary)
    record = writer.commit_file(
        temporary,
        f"frames/{lamp}/{stream}-{index:03d}.dng",
        key=key,
        role="dark" if stream == "dark" else "frame",
    )
    params = {"lamp": lamp, "index": index, "exposure_s": exposure_s}
    if stream == "dark":
        params["count"] = len(BRACKET_S)
    result = {
        "time_s": 1.0,
        "file": record.path,
        "exposure_s": exposure_s,
        "reported_exposure_s": exposure_s,
        "camera_path": f"/store/DCIM/{index:04d}.dng",
        "stats": None,
    }
    _step(writer, key, "DarkFrame" if stream == "dark" else "Capture", params, result)


def write_session(
    parent: Path,
    capture: Capture,
    *,
    lamps: tuple[str, ...] = ("LED", "FL"),
    darks: bool = True,
    complete: bool = True,
    spectra: int = 2,
    bandwidth_nm: float | None = None,
) -> Path:
    """A session as the runner writes it: start, spectra, bracket and dark steps with files, stop."""
    writer = SessionWriter.create(parent)
    writer.write(
        StartRecord,
        session_id=writer.session_id,
        wall_time=datetime(2025, 11, 21, 12, 0, tzinfo=UTC),
        software=SoftwareInfo(name="spectral-rig", version="0", python="3.11", platform="test"),
        plan=PlanInfo(name="standard_capture", args={}),
        config={"lamps": LAMP_CONFIG, "dark_frames": 1},
        devices={},
        clock="SimulatedClock",
    )
    for name in lamps:
        lamp = capture.lamp(name)
        spectrum = colour_lamps()[name][1]
        for repeat in range(spectra):
            key = f"lamp/{name}/reference/{repeat:03d}"
            record = writer.write_spectrum(
                f"spectra/{name}/reference-{repeat:03d}.csv",
                spectrum,
                key=key,
                units="W/(sr m² nm)",
                bandwidth_nm=bandwidth_nm,
            )
            result = {
                "time_s": 1.0,
                "file": record.path,
                "units": "W/(sr m² nm)",
                "exposure_ms": 100.0,
            }
            _step(
                writer,
                key,
                "MeasureSpectrum",
                {"lamp": name, "purpose": "reference", "index": repeat},
                result,
            )
        for index, (frame, exposure) in enumerate(zip(lamp.frames, BRACKET_S, strict=True)):
            _frame(writer, name, "scene", index, frame, exposure)
        if darks:
            for index, (frame, exposure) in enumerate(zip(lamp.darks, BRACKET_S, strict=True)):
                _frame(writer, name, "dark", index, frame, exposure)
    if complete:
        writer.write(
            StopRecord,
            exit_status="success",
            reason="completed",
            message="done",
            wall_time=datetime(2025, 11, 21, 12, 5, tzinfo=UTC),
            t_s=300.0,
            lamps_off=True,
        )
    writer.close()
    return writer.path


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(scope="module")
def session(capture: Capture, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_session(tmp_path_factory.mktemp("sessions"), capture)


@pytest.fixture(scope="module")
def outcome(session: Path, capture: Capture) -> OfflineOutcome:
    return estimate_session(session, settings={"basis": capture.basis})


def test_a_complete_session_gives_the_outputs_and_the_truth(
    outcome: OfflineOutcome, session: Path, capture: Capture
) -> None:
    assert outcome.files["report"] == session / "estimate" / "report.html"
    for key in ("sensitivity", "result", "camera_json", "grating"):
        assert outcome.files[key].is_file()
    result = outcome.estimate.result
    assert relative_error(result.sensitivity, capture.truth) < 0.05
    assert isinstance(result.mapping, QuadraticMapping)
    assert result.mapping.method.startswith("lines of")
    # no bandwidth stated: the one warning (σ assumes one)
    assert {flag.code for flag in result.quality.flags} == {"no_spectrometer_bandwidth"}
    assert len(outcome.estimate.warnings) == 1
    assert result.diagnostics["method_choice"]["mapping_only"] == []
    assert result.quality.uncertainty["notes"]
    document = json.loads(outcome.files["result"].read_text())
    notes = document["provenance"]["notes"]
    assert any(note.startswith("session ") and "status complete" in note for note in notes)


def test_every_used_file_is_recorded_with_the_logs_hash(
    outcome: OfflineOutcome, session: Path
) -> None:
    inputs = outcome.estimate.provenance.inputs
    roles = sorted({record.role for record in inputs})
    assert roles == ["dark", "frame", "spectrum"]
    assert sum(record.role == "frame" for record in inputs) == 2 * len(BRACKET_S)
    log = [json.loads(line) for line in (session / "log.jsonl").read_text().splitlines()]
    logged = {str(session / r["path"]): r["sha256"] for r in log if r["type"] == "file"}
    for record in inputs:
        assert logged[record.path] == record.sha256


def test_the_spectrum_is_the_mean_of_the_reference_spectra(
    outcome: OfflineOutcome, session: Path
) -> None:
    observation = next(obs for obs in outcome.estimate.observations if obs.name == "LED")
    stored = read_spectrum_csv(session / "spectra" / "LED" / "reference-000.csv")
    np.testing.assert_allclose(observation.spectrum.values, stored.values)
    assert "mean of 2 spectra" in observation.spectrum.name


def test_a_changed_frame_is_refused(capture: Capture, tmp_path: Path) -> None:
    session = write_session(tmp_path, capture, lamps=("LED",), darks=False)
    frame = session / "frames" / "LED" / "scene-002.dng"
    data = bytearray(frame.read_bytes())
    data[-100] ^= 0xFF
    frame.write_bytes(bytes(data))
    with pytest.raises(SessionFormatError, match=r"scene-002\.dng: sha256 differs"):
        estimate_session(session, settings={"basis": capture.basis})
    # cut short (a copy that stopped): the sizes, said once ("… from the log from the log" before)
    frame.write_bytes(bytes(data[:1000]))
    expected = r"scene-002\.dng: 1000 bytes, the log says \d+; the file changed after capture$"
    with pytest.raises(SessionFormatError, match=expected):
        estimate_session(session, settings={"basis": capture.basis})


def test_a_symlinked_frame_is_refused(capture: Capture, tmp_path: Path) -> None:
    session = write_session(tmp_path, capture, lamps=("LED",), darks=False)
    frame = session / "frames" / "LED" / "scene-001.dng"
    outside = tmp_path / "elsewhere.dng"
    frame.rename(outside)
    frame.symlink_to(outside)
    with pytest.raises(SessionFormatError, match="symlink"):
        estimate_session(session, settings={"basis": capture.basis})


def test_an_interrupted_session_uses_the_lamps_it_has(capture: Capture, tmp_path: Path) -> None:
    session = write_session(tmp_path, capture, lamps=("LED",), darks=False, complete=False)
    outcome = estimate_session(
        session, tmp_path / "out", settings={"basis": capture.basis}, report=False
    )
    warnings = outcome.estimate.warnings
    assert any("session is interrupted" in w for w in warnings)
    assert any("lamp 'FL' left out" in w for w in warnings)
    assert [obs.name for obs in outcome.estimate.observations] == ["LED"]
    # LED only: the mapping comes from the broadband search (RE 0.06 measured on this scene)
    mapping = outcome.estimate.result.mapping
    assert isinstance(mapping, QuadraticMapping) and mapping.method.startswith("correlation search")
    assert relative_error(outcome.estimate.result.sensitivity, capture.truth) < 0.1


def test_incomplete_dark_frames_are_left_out(capture: Capture, tmp_path: Path) -> None:
    session = write_session(tmp_path, capture, lamps=("LED",), darks=True)
    log = session / "log.jsonl"
    lines = log.read_text().splitlines()
    # drop the last dark frame's step record and its file record (a run cut short)
    kept = [line for line in lines if "lamp/LED/dark/004" not in line]
    for seq, line in enumerate(kept):
        record = json.loads(line)
        record["seq"] = seq
        kept[seq] = json.dumps(record)
    log.write_text("\n".join(kept) + "\n")
    outcome = estimate_session(
        session, tmp_path / "out", settings={"basis": capture.basis}, report=False
    )
    assert any("dark frames left out" in w for w in outcome.estimate.warnings)
    assert all(not frame["dark_frames"] for frame in outcome.estimate.provenance.lamps[0]["frames"])


def test_a_session_without_brackets_is_an_input_error(capture: Capture, tmp_path: Path) -> None:
    session = write_session(tmp_path, capture, lamps=(), complete=False)
    with pytest.raises(InputError, match=r"no lamp of the session has a captured bracket"):
        estimate_session(session, settings={"basis": capture.basis})


def test_rig_estimate_command(
    session: Path, capture: Capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        "calib.pipeline.estimate.default_camera_basis", lambda *a, **k: capture.basis
    )
    result = CliRunner().invoke(
        app, ["estimate", str(session), "--out", str(tmp_path / "out"), "-q"]
    )
    assert result.exit_code == 0, result.output
    assert f"report: {tmp_path / 'out' / 'report.html'}" in result.output
    assert "mapping RE estimate" in result.output


def test_rig_estimate_of_a_non_session_exits_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sys, "argv", ["rig", "estimate", str(tmp_path)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith("rig: error:") and "not a session" in error
    assert error.count("\n") == 1


def test_rig_estimate_takes_the_multilamp_weight_rule(
    session: Path,
    capture: Capture,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setattr(
        "calib.pipeline.estimate.default_camera_basis", lambda *a, **k: capture.basis
    )
    out = tmp_path / "out"
    arguments = ["estimate", str(session), "--out", str(out), "-q", "--weight-rule", "typicality"]
    result = CliRunner().invoke(app, [*arguments, "--method", "multilamp", "--no-report"])
    assert result.exit_code == 0, result.output
    diagnostics = json.loads((out / "result.json").read_text())["diagnostics"]
    assert diagnostics["prior_weight_rule"] == "typicality"
    monkeypatch.setattr(sys, "argv", ["rig", *arguments])  # the default method, auto
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    assert "--weight-rule: applies to --method multilamp only" in capsys.readouterr().err


# ------------------------------------------------------------------------------ where it writes


@pytest.fixture
def estimate_cli(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> Callable[..., tuple[int, str, list[Path]]]:
    """``rig estimate ARGS``: exit code, stderr, and where the estimate would have been written
    (the estimate itself is stubbed: these tests are about what happens before it)."""
    reached: list[Path] = []

    def estimate_stub(lamps: object, out_dir: Path, *args: object, **kwargs: object) -> None:
        reached.append(out_dir)
        raise InputError("stopped by the test", source="stub")

    monkeypatch.setattr("calib.pipeline.input_sets.run_offline", estimate_stub)

    def run(*arguments: str) -> tuple[int, str, list[Path]]:
        monkeypatch.setattr(sys, "argv", ["rig", "estimate", *arguments, "-q"])
        with pytest.raises(SystemExit) as exit_info:
            main()
        return int(exit_info.value.code or 0), capsys.readouterr().err, reached

    return run


def test_a_planted_estimate_link_is_refused(
    capture: Capture, tmp_path: Path, estimate_cli: Callable[..., tuple[int, str, list[Path]]]
) -> None:
    session = write_session(tmp_path / "sessions", capture, lamps=("LED",), darks=False)
    outside = tmp_path / "outside"
    (outside / "dir").mkdir(parents=True)
    (session / "estimate").symlink_to(outside / "dir")
    with watching(outside):
        for force in ([], ["--force"]):
            code, err, reached = estimate_cli(str(session), *force)
            assert code == 2 and err.count("\n") == 1 and reached == []
            assert f"estimate is a symbolic link to {outside / 'dir'}" in err


def test_earlier_results_are_kept_unless_forced_and_never_written_through_a_link(
    capture: Capture, tmp_path: Path, estimate_cli: Callable[..., tuple[int, str, list[Path]]]
) -> None:
    session = write_session(tmp_path / "sessions", capture, lamps=("LED",), darks=False)
    (session / "estimate" / "plots").mkdir(parents=True)
    (session / "estimate" / "result.json").write_text("{}")
    code, err, reached = estimate_cli(str(session))
    assert code == 2 and reached == []
    assert "already holds the results of an estimate (result.json)" in err and "--force" in err
    victim = tmp_path / "victim"
    victim.write_text("the user's own file")
    (session / "estimate" / "plots" / "geometry.png").symlink_to(victim)
    code, err, reached = estimate_cli(str(session), "--force")
    assert code == 2 and reached == [] and "plots/geometry.png is a symbolic link" in err
    (session / "estimate" / "plots" / "geometry.png").unlink()
    code, err, reached = estimate_cli(str(session), "--force")
    assert reached == [session / "estimate"]  # with --force, on to the estimate
    assert victim.read_text() == "the user's own file"


def test_an_out_directory_that_cannot_be_written_is_refused_before_any_work(
    capture: Capture, tmp_path: Path, estimate_cli: Callable[..., tuple[int, str, list[Path]]]
) -> None:
    session = write_session(tmp_path / "sessions", capture, lamps=("LED",), darks=False)
    (tmp_path / "a-file").write_text("")
    code, err, reached = estimate_cli(str(session), "--out", str(tmp_path / "a-file" / "out"))
    assert code == 2 and reached == []
    assert err.startswith(f"rig: error: --out {tmp_path / 'a-file' / 'out'}: cannot be written")


def test_calib_estimate_on_the_sessions_own_files_matches_rig_estimate(
    capture: Capture,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Issue 15: the same RAW files and spectra give the same curve through both commands — the
    spectra averaged and their bandwidth read from the CSV headers the rig writes."""
    from calib.cli.app import main

    monkeypatch.setattr(
        "calib.pipeline.estimate.default_camera_basis", lambda *a, **k: capture.basis
    )
    session = write_session(tmp_path, capture, bandwidth_nm=2.0)
    through_rig = estimate_session(session, settings={"basis": capture.basis}, report=False)
    argv: list[str] = []
    for lamp in through_rig.estimate.provenance.lamps:
        name = lamp["name"]
        frames = sorted((session / "frames" / name).glob("scene-*.dng"))
        darks = sorted((session / "frames" / name).glob("dark-*.dng"))
        spectra = sorted((session / "spectra" / name).glob("reference-*.csv"))
        argv += ["--lamp", name, "--kind", lamp["kind"], "--images", *map(str, frames)]
        argv += ["--dark", *map(str, darks), "--spectrum", *map(str, spectra)]
    with pytest.raises(SystemExit) as exited:
        main(["estimate", *argv, "--out", str(tmp_path / "calib"), "-q", "--json", "--no-report"])
    assert exited.value.code == 0
    document = json.loads((tmp_path / "calib" / "result.json").read_text())
    from_calib = np.stack([document["sensitivity"][c] for c in "RGB"], axis=1)
    np.testing.assert_allclose(
        from_calib, through_rig.estimate.result.physical_sensitivity(), atol=1e-6
    )
    assert "bandwidth" not in capsys.readouterr().err  # read from the CSV headers
    observation = through_rig.estimate.observations[0]
    assert observation.spectrum_bandwidth_nm == 2.0
