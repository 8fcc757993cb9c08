"""calib.evaluation.lamp_planning, calib.core.lamp_specs and ``calib plan-lamps``."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.cli.app import build_app, main
from calib.core.errors import InputError
from calib.core.lamp_specs import gaussian_lamp, lamp_from_spec
from calib.core.spectra import write_csv
from calib.evaluation.lamp_planning import MAX_LAMPS, best_additions, rank_subsets
from calib.model.bases import CameraPrior, fallback_camera_basis


@pytest.fixture(scope="module")
def prior() -> CameraPrior:
    return fallback_camera_basis().prior()


def test_a_gaussian_led_has_its_width_at_half_maximum():
    lamp = gaussian_lamp(630.0, 20.0)
    peak, half = lamp.at(np.array([630.0, 640.0]))
    assert half / peak == pytest.approx(0.5, abs=1e-3)
    assert lamp_from_spec("gauss:630:20").name == "gauss:630:20"


@pytest.mark.parametrize("spec", ["gauss:630", "gauss:x:20", "gauss:630:0", "no-such-lamp"])
def test_bad_lamp_specs_are_named(spec):
    with pytest.raises(InputError):
        lamp_from_spec(spec)


def test_subsets_rank_by_predicted_sigma_and_more_spectrally_different_lamps_win(prior):
    lamps = [lamp_from_spec(spec) for spec in ("LED-B3", "FL2", "A", "gauss:630:20")]
    ranked = rank_subsets(lamps, prior)
    assert len(ranked) == 2**4 - 1
    sigmas = [score.efficiency_sigma for score in ranked]
    assert sigmas == sorted(sigmas)
    by_lamps = {score.lamps: score for score in ranked}
    # Fewer equations than Fourier terms: no data-only conditioning.
    assert math.isinf(by_lamps[("LED-B3",)].condition)
    # Adding a lamp never makes the prediction worse (the posterior only gains information).
    assert (
        by_lamps[("LED-B3", "FL2", "A", "gauss:630:20")].efficiency_sigma
        <= by_lamps[("LED-B3", "FL2", "A")].efficiency_sigma
    )
    # The direct equations alone: nothing for a lamp's 3 equations on 7 terms, and never better
    # than with the prior as well.
    assert math.isinf(by_lamps[("LED-B3",)].data_sigma)
    assert by_lamps[("LED-B3",)].to_dict()["data_sigma"] is None
    full = by_lamps[("LED-B3", "FL2", "A", "gauss:630:20")]
    assert full.efficiency_sigma < full.data_sigma < math.inf
    assert all(score.data_sigma >= score.efficiency_sigma for score in ranked)


def test_a_full_set_of_lamps_can_still_be_given_one_more(prior):
    """Adding to MAX_LAMPS lamps scores one set per candidate; it enumerates no subsets."""
    owned = [lamp_from_spec(f"gauss:{400 + 25 * index}:30") for index in range(MAX_LAMPS)]
    additions = best_additions(owned, [lamp_from_spec("A")], prior)
    assert [len(score.lamps) for score in additions] == [MAX_LAMPS + 1]


def test_a_candidate_already_owned_is_not_suggested_again(prior):
    owned = [lamp_from_spec(spec) for spec in ("LED-B3", "gauss:630:20")]
    candidates = [lamp_from_spec(spec) for spec in ("gauss:630:20", "gauss:455:25")]
    additions = best_additions(owned, candidates, prior)
    assert [score.lamps[-1] for score in additions] == ["gauss:455:25"]
    arguments = ["plan-lamps", "--lamp", "LED-B3", "--lamp", "A", "--candidate", "A"]
    result = CliRunner().invoke(build_app(), arguments)
    assert result.exit_code == 0, result.output
    assert "every candidate lamp is already among yours" in result.output


def test_the_suggested_extra_lamp_is_the_one_that_lowers_sigma_most(prior):
    owned = [lamp_from_spec(spec) for spec in ("LED-B1", "LED-B3", "LED-B5")]
    candidates = [lamp_from_spec(spec) for spec in ("LED-B2", "gauss:630:20")]
    additions = best_additions(owned, candidates, prior)
    assert additions[0].efficiency_sigma <= additions[1].efficiency_sigma
    # A red LED differs from three white LEDs far more than a fourth white LED does.
    assert additions[0].lamps[-1] == "gauss:630:20"


def test_cli_prints_a_ranked_table_and_json(tmp_path):
    csv_path = write_csv(tmp_path / "halogen.csv", lamp_from_spec("A"))
    runner = CliRunner()
    arguments = ["plan-lamps", "--lamp", "LED-B3", "--lamp", "FL2", "--lamp", str(csv_path)]
    result = runner.invoke(build_app(), arguments)
    assert result.exit_code == 0, result.output
    assert "best subsets" in result.output and "helps most" in result.output
    result = runner.invoke(build_app(), [*arguments, "--json", "--top", "3"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)  # the basis warning goes to stderr
    assert len(data["subsets"]) == 3 and len(data["additions"]) == 3
    assert data["subsets"][0]["efficiency_sigma"] <= data["subsets"][-1]["efficiency_sigma"]


@pytest.mark.parametrize(
    ("arguments", "named"),
    [
        (["--lamp", "missing.csv"], "missing.csv"),
        (["--lamp", "A", "--candidate", "gauss:630"], "--candidate gauss:630"),
        (["--lamp", "A", "--noise", "-1"], "--noise"),
    ],
)
def test_cli_exit_code_2_names_the_bad_input(arguments, named, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["calib", "plan-lamps", *arguments])
    with pytest.raises(SystemExit) as exited:
        main()
    assert exited.value.code == 2
    stderr = capsys.readouterr().err
    assert named in stderr and len(stderr.strip().splitlines()) == 1


def test_a_physical_grating_is_planned_for_and_a_grating_file_says_which() -> None:
    """Two parameters against the direct equations: far smaller σ(η) than 7 free terms; the model
    a calibration recorded is the one planned for."""
    from calib.core.grating_file import GratingEfficiency
    from calib.evaluation.lamp_planning import recorded_model

    prior = fallback_camera_basis().prior()
    lamps = [lamp_from_spec(spec) for spec in ("LED-B3", "FL2", "A")]
    fourier = rank_subsets(lamps, prior)[0]
    sheet = rank_subsets(lamps, prior, grating_model="sinusoidal", grating_parameter=1.3)[0]
    assert sheet.lamps == ("LED-B3", "FL2", "A")
    assert sheet.efficiency_sigma == pytest.approx(sheet.data_sigma, rel=1e-9)
    assert sheet.efficiency_sigma < 0.2 * fourier.efficiency_sigma
    with pytest.raises(InputError, match="one model"):
        rank_subsets(lamps, prior, grating_model="auto")
    record = {"model": "blazed", "parameters": {"blaze_nm": 480.0, "blaze_nm_sigma": 0.5}}
    file = GratingEfficiency(np.array([400.0, 700.0]), np.ones(2), model=record)
    assert recorded_model(file) == ("blazed", 480.0)
    assert recorded_model(GratingEfficiency(np.array([400.0, 700.0]), np.ones(2))) == (
        "fourier",
        None,
    )
