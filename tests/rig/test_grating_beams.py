"""The grating's efficiency measured with the spectrometer (``measure_grating``, decision 0032):
config, plan, dry run, the operator, the twin's beams, resume after ``kill -9``, replay, estimate."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from calib.core.grating_file import read_grating_file
from calib.core.spectra import read_spectrum_csv
from calib.model.gratings import REPLICA_SHEET_PEAK_PHASE_RAD
from rig.capture import run_capture
from rig.config import ConfigError, GratingMeasurement, RigConfig, parse_config
from rig.dryrun import ModelledBench, dry_run, walk
from rig.errors import BeamNotFound
from rig.estimate import estimate_session
from rig.init_config import render_config
from rig.operator import (
    ConsoleOperator,
    ManualAction,
    OperatorDeclined,
    OperatorUnavailable,
    ScriptedOperator,
)
from rig.plan import AIM_STEP_FRACTION, StandardCaptureArgs, first_order_aims, standard_capture
from rig.records import ResumeRecord, StepRecord
from rig.replay import replay_session
from rig.resume import run_resume
from rig.runner import RetryPolicy
from rig.session import find_sessions, read_session
from rig.station_devices import Station, TranscriptFactory
from rig.steps import AimSpectrometer, MeasureBeam, SpectrumMeasured
from rig.twin import read_twin_truth, twin_station_builder, write_twin_truth
from tests.rig.fakes import fake_config_data, wait_for, write_config
from tests.rig.test_cli import run_cli
from tests.rig.test_signals import finish
from tests.rig.twin_setup import twin_config_data

ROOT = Path(__file__).resolve().parents[2]
NO_BACKOFF = RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)
MEASURE = {"lamp": "LED-B3", "grooves_per_mm": 500, "repeats": 2}


def grating_config(directory: Path, **measure: object) -> RigConfig:
    """The small twin measuring its grating with LED-B3; relays persisted in ``relays.state``."""
    data = twin_config_data(directory / "sessions")
    data["devices"]["relays"]["state_file"] = str(directory / "relays.state")
    data["measure_grating"] = MEASURE | measure
    return RigConfig.model_validate(data)


def step_records(path: Path, run: int | None = None) -> list[StepRecord]:
    return [
        record
        for record in read_session(path).records
        if isinstance(record, StepRecord) and (run is None or record.run == run)
    ]


# ------------------------------------------------------------------------------------- config


def test_the_lamp_must_be_a_lamp_and_the_first_order_must_exist() -> None:
    data = fake_config_data()
    data["measure_grating"] = {"lamp": "A", "grooves_per_mm": 500}
    with pytest.raises(ValueError, match=r"measure_grating.lamp 'A' is not a lamp of lamps\[\]"):
        RigConfig.model_validate(data)
    data["measure_grating"] = {"lamp": "FL2", "grooves_per_mm": 1500, "range_nm": [400, 700]}
    with pytest.raises(ValueError, match="no 1st order beyond 667 nm"):
        RigConfig.model_validate(data)


def test_the_shipped_block_is_commented_and_validates_when_filled_in() -> None:
    text = render_config()
    assert "measure_grating: null" in text and (ROOT / "config.yaml").read_text() == text
    block = [line for line in text.splitlines() if line.startswith("#   ")]
    filled = text.replace("measure_grating: null\n", "").replace(
        "# measure_grating:\n", "measure_grating:\n"
    )
    for line in block:
        filled = filled.replace(line, line[2:])
    config = parse_config(filled)
    assert config.measure_grating == GratingMeasurement(lamp="FL2", grooves_per_mm=500)


def test_a_files_spectrometer_cannot_be_aimed(tmp_path: Path) -> None:
    text = render_config(spectrometer="files").replace(
        "measure_grating: null", "measure_grating: {lamp: FL2, grooves_per_mm: 500}"
    )
    with pytest.raises(ConfigError, match="a files spectrometer cannot be aimed"):
        parse_config(text, base_dir=tmp_path)


# --------------------------------------------------------------------------------------- plan


def test_the_aims_tile_the_range_with_overlapping_bands() -> None:
    measure = GratingMeasurement(lamp="FL2", grooves_per_mm=500, field_deg=1.0)
    aims = first_order_aims(measure)
    centres = np.array([centre for centre, _ in aims])
    spacing = 2000.0
    # Each aim's field sees d·cosθ·field nm; neighbours step by half of it.
    band = spacing * np.cos(np.arcsin(centres / spacing)) * np.radians(1.0)
    assert centres[0] - band[0] / 2 <= 400.0 and centres[-1] + band[-1] / 2 >= 700.0
    np.testing.assert_allclose(np.diff(centres), AIM_STEP_FRACTION * band[:-1], rtol=0.01)
    for centre, angle in aims:  # the grating equation at normal incidence
        assert np.sin(np.radians(angle)) * spacing == pytest.approx(centre, rel=1e-9)
    wider = first_order_aims(GratingMeasurement(lamp="FL2", grooves_per_mm=500, field_deg=2.0))
    assert len(wider) < len(aims) / 1.8


def test_the_dry_run_shows_the_operator_steps_in_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config = grating_config(tmp_path)
    report = dry_run(config)
    assert report.ok, report.failure
    steps = [p.step for p in report.steps if isinstance(p.step, AimSpectrometer | MeasureBeam)]
    aims = [step for step in steps if isinstance(step, AimSpectrometer)]
    n_bands = len(first_order_aims(config.measure_grating))  # type: ignore[arg-type]
    assert [aim.beam for aim in aims] == ["direct", "order0", *["order1"] * n_bands, "lamp"]
    assert report.count(MeasureBeam) == 2 * (n_bands + 2)
    keys = [p.step.key for p in report.steps]
    # After LED-B3's reference spectra, before its bracket; nothing for FL2.
    assert keys.index("lamp/LED-B3/reference/001") < keys.index("lamp/LED-B3/grating/aim-direct")
    assert keys.index("lamp/LED-B3/grating/aim-lamp") < keys.index("lamp/LED-B3/scene/000")
    assert not any(key.startswith("lamp/FL2/grating") for key in keys)
    aim_s = sum(p.duration_s for p in report.steps if isinstance(p.step, AimSpectrometer))
    assert aim_s == pytest.approx(len(aims) * config.dry_run.operator_aim_s)
    config_file = write_config(tmp_path / "rig.yaml", config.model_dump(mode="json"))
    assert run_cli(["dry-run", "--config", str(config_file)], monkeypatch) == 0
    out = capsys.readouterr().out
    assert "OPERATOR aims the spectrometer at the 1st-order beam at 409 nm (11.79°" in out
    assert f"{len(aims)} times a person re-aims the spectrometer" in out


def test_a_beam_without_light_fails_the_plan_with_what_to_check(tmp_path: Path) -> None:
    config = grating_config(tmp_path)

    class DarkBeams(ModelledBench):
        def measure_beam(self, step: MeasureBeam) -> SpectrumMeasured:
            result = super().measure_beam(step)
            if step.beam != "order1":
                return result
            return SpectrumMeasured(
                result.time_s, result.file, result.wavelength_nm, 0 * result.values, "", None
            )

    report = walk(standard_capture(StandardCaptureArgs.from_config(config)), DarkBeams(config))
    assert isinstance(report.failure, BeamNotFound)
    assert report.failure.key == "lamp/LED-B3/grating/order1-409nm/000"
    assert "turn the spectrometer by 11.79°" in str(report.failure)


# ----------------------------------------------------------------------------------- operator


@pytest.fixture
def terminal() -> Iterator[tuple[int, ConsoleOperator]]:
    main, other = os.openpty()
    reader = os.fdopen(other, "r")
    writer = Path(os.devnull).open("w")  # noqa: SIM115
    try:
        yield main, ConsoleOperator(reader, writer)
    finally:
        reader.close()
        writer.close()
        os.close(main)


ACTION = ManualAction("lamp/FL2/grating/aim-order0", "aim at the 0th order", "order0")


def test_the_console_operator_waits_for_enter_and_q_declines(
    terminal: tuple[int, ConsoleOperator],
) -> None:
    main, operator = terminal
    os.write(main, b"\n")
    assert operator.perform(ACTION, lambda: False) is True
    os.write(main, b"q\n")
    with pytest.raises(OperatorDeclined, match="declined to aim at the 0th order; resume"):
        operator.perform(ACTION, lambda: False)


def test_the_console_operator_gives_up_waiting_on_a_stop_request(
    terminal: tuple[int, ConsoleOperator],
) -> None:
    _, operator = terminal
    calls = iter([False, False, True])
    assert operator.perform(ACTION, lambda: next(calls)) is False


def test_without_a_terminal_the_operator_is_unavailable(tmp_path: Path) -> None:
    with (
        (tmp_path / "input").open("w+") as reader,
        pytest.raises(OperatorUnavailable, match="without a terminal to ask on"),
    ):
        ConsoleOperator(reader).perform(ACTION, lambda: False)


# ------------------------------------------------------------------------------------ the twin


@dataclass(frozen=True)
class Captured:
    config: RigConfig
    session: Path


@pytest.fixture(scope="module")
def captured(tmp_path_factory: pytest.TempPathFactory) -> Captured:
    directory = tmp_path_factory.mktemp("grating")
    config = grating_config(directory)
    outcome = run_capture(config, retry=NO_BACKOFF)
    assert outcome.exit_status == "success", outcome
    write_twin_truth(config, outcome.session)
    return Captured(config, outcome.session)


def _mean(session: Path, lamp: str, target: str, repeats: int = 2) -> tuple[np.ndarray, np.ndarray]:
    spectra = [
        read_spectrum_csv(session / f"spectra/{lamp}/grating-{target}-{index:03d}.csv")
        for index in range(repeats)
    ]
    return spectra[0].wavelength_nm, np.mean([s.values for s in spectra], axis=0)


def test_the_twin_spectrometer_sees_the_true_orders_through_its_field(captured: Captured) -> None:
    session = captured.session
    records = {r.key: r for r in step_records(session)}
    record = records["lamp/LED-B3/grating/order1-544nm/001"]
    assert (record.action, record.params["beam"], record.params["centre_nm"]) == (
        "MeasureBeam",
        "order1",
        544.4,
    )
    assert record.result is not None
    assert record.result["file"] == "spectra/LED-B3/grating-order1-544nm-001.csv"
    truth = read_twin_truth(session / "twin-truth.json")
    axis, direct = _mean(session, "LED-B3", "direct")
    _, order0 = _mean(session, "LED-B3", "order0")
    _, order1 = _mean(session, "LED-B3", "order1-544nm")
    # Where the lamp is well lit: at the LED's dim edges the spectrometer's bandwidth mixes its
    # slope with the sheet's η₀ slope (J₀² varies 3× across the visible).
    lit = direct > 0.2 * direct.max()
    eta0 = truth.zeroth_order_efficiency.at(axis)
    np.testing.assert_allclose((order0 / np.where(lit, direct, 1))[lit], eta0[lit], rtol=0.05)
    # The 1st order: a band around 544 nm (1° at 500 lines/mm ≈ 33 nm), dark elsewhere.
    core = lit & (np.abs(axis - 544.4) <= 4.0)
    np.testing.assert_allclose(
        order1[core] / direct[core], truth.grating_efficiency.at(axis[core]), rtol=0.03
    )
    assert np.all(order1[lit & (np.abs(axis - 544.4) > 30.0)] < 0.01 * order1.max())


def test_the_estimate_uses_the_measured_grating_and_saves_it(
    captured: Captured, tmp_path: Path
) -> None:
    outcome = estimate_session(captured.session, tmp_path / "estimate", report=False)
    result = outcome.estimate.result
    assert result.method == "known-grating"
    grating = read_grating_file(outcome.files["grating"])
    assert grating.obtained == "measured"
    assert grating.model is not None and grating.model["model"] == "sinusoidal"  # the twin's
    truth = read_twin_truth(captured.session / "twin-truth.json")
    assert grating.model["parameters"]["peak_phase_rad"] == pytest.approx(
        REPLICA_SHEET_PEAK_PHASE_RAD, abs=0.03
    )
    # η₁ (relative, as the file stores it) within its ±2σ band and within 0.01 of the truth.
    true_eta = truth.grating_efficiency.at(grating.wavelength_nm)
    true_eta = true_eta / true_eta.max()
    assert grating.efficiency_sigma is not None
    assert np.all(np.abs(grating.efficiency - true_eta) <= 2 * grating.efficiency_sigma)
    assert np.max(np.abs(grating.efficiency - true_eta)) < 0.01
    assert grating.zeroth_order_efficiency is not None
    inside = (grating.wavelength_nm >= 420) & (grating.wavelength_nm <= 700)
    # The sheet's η₀ (J₀², 0.2 → 0.6): 6 % where LED-B3 is dim (its blue edge, ≤ 440 nm).
    np.testing.assert_allclose(
        grating.zeroth_order_efficiency[inside],
        truth.zeroth_order_efficiency.at(grating.wavelength_nm[inside]),
        rtol=0.06,
    )
    # The camera through it, against the twin's truth (the known-grating path's own floor on
    # this small twin is ≈ 6.6 ×10⁻² with the true η: mapping and profile, not the grating).
    assert outcome.truth_relative_error is not None and outcome.truth_relative_error < 0.075
    notes = json.loads(outcome.files["result"].read_text())["provenance"]["notes"]
    assert any("measured with the spectrometer in its beams (LED-B3, 18" in n for n in notes)


def test_a_replay_of_the_session_is_identical(captured: Captured, tmp_path: Path) -> None:
    replay = replay_session(captured.session, tmp_path / "replay")
    assert replay.identical, replay


# ------------------------------------------------------------------------- declined, resumed


def test_a_declined_aim_stops_the_run_resumably_and_resume_asks_again(tmp_path: Path) -> None:
    config = grating_config(tmp_path)
    twin = twin_station_builder()
    asked: list[str] = []

    def declining(rig_config: RigConfig, transcripts: TranscriptFactory) -> Station:
        opened = twin(rig_config, transcripts)
        hands = opened.operator
        assert isinstance(hands, ScriptedOperator)
        opened.operator = ScriptedOperator(
            act=hands.act, decline=frozenset({"lamp/LED-B3/grating/aim-order1-477nm"})
        )
        return opened

    outcome = run_capture(config, builder=declining, retry=NO_BACKOFF)
    assert (outcome.exit_status, outcome.reason, outcome.lamps_off) == (
        "fail",
        "operator_declined",
        True,
    )
    assert outcome.failed_key == "lamp/LED-B3/grating/aim-order1-477nm"

    def recording(rig_config: RigConfig, transcripts: TranscriptFactory) -> Station:
        opened = twin(rig_config, transcripts)
        hands = opened.operator
        assert isinstance(hands, ScriptedOperator) and hands.act is not None
        act = hands.act

        def act_and_note(action: ManualAction) -> None:
            asked.append(action.key)
            act(action)

        opened.operator = ScriptedOperator(act=act_and_note)
        return opened

    resumed = run_resume(outcome.session, config, builder=recording, retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    run2 = [r.key for r in step_records(outcome.session, run=2)]
    # The lit lamp is warmed up again with the spectrometer back at its target (asked first),
    # the beams measured before are reused, and the declined aim is asked again.
    assert asked[:2] == [
        "lamp/LED-B3/resume/002/aim-lamp",
        "lamp/LED-B3/grating/aim-order1-477nm",
    ]
    assert run2.index("lamp/LED-B3/resume/002/aim-lamp") < run2.index("lamp/LED-B3/warmup/000")
    assert "lamp/LED-B3/grating/order1-460nm/000" not in run2
    assert asked[-1] == "lamp/LED-B3/grating/aim-lamp"
    (resume,) = [r for r in read_session(outcome.session).records if isinstance(r, ResumeRecord)]
    assert resume.resume_key == "lamp/LED-B3/grating/aim-order1-477nm"
    replay = replay_session(outcome.session, tmp_path / "replay")
    assert replay.identical, replay


def test_kill_9_while_the_operator_re_aims_then_rig_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = grating_config(tmp_path)
    config_file = write_config(tmp_path / "rig.yaml", config.model_dump(mode="json"))
    marker = tmp_path / "waiting"
    key = "lamp/LED-B3/grating/aim-order1-544nm"
    process = subprocess.Popen(
        [sys.executable, "-m", "tests.rig.aim_process", str(config_file), key, str(marker)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for(lambda: marker.exists() or process.poll() is not None, 120, "the slow aim")
        assert process.poll() is None, process.communicate()
        assert (tmp_path / "relays.state").read_text().strip() == "10"  # LED-B3 is on
    finally:
        process.kill()
        finish(process)
    (path,) = find_sessions(tmp_path / "sessions")
    assert read_session(path).stop is None
    monkeypatch.chdir(tmp_path)
    assert run_cli(["resume", str(path), "--quiet", "--config", "rig.yaml"], monkeypatch) == 0
    session = read_session(path)
    assert session.status == "complete" and session.verify_files() == []
    (resume,) = [r for r in session.records if isinstance(r, ResumeRecord)]
    assert (resume.previous_reason, resume.relays_found_on, resume.resume_key) == (
        "no_stop_record",
        [1],
        key,
    )
    run2 = [r.key for r in step_records(path, run=2)]
    assert run2.index("lamp/LED-B3/resume/002/aim-lamp") < run2.index("lamp/LED-B3/warmup/000")
    assert key in run2 and "lamp/LED-B3/grating/order1-527nm/001" not in run2
    # Every beam spectrum exactly once, as last done; the estimate finds the same grating.
    done = session.done_steps()
    beams = [k for k in done if "/grating/" in k and done[k].action == "MeasureBeam"]
    assert len(beams) == 2 * (2 + 18)
    grating = read_grating_file(estimate_session(path, report=False).files["grating"])
    assert grating.model is not None
    assert grating.model["parameters"]["peak_phase_rad"] == pytest.approx(
        REPLICA_SHEET_PEAK_PHASE_RAD, abs=0.03
    )
    replay = replay_session(path, tmp_path / "replay")
    assert replay.identical, replay
