"""rig grating: one grating file refined over sessions of two cameras through the same grating."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.core.errors import InputError
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.grating_file import GratingEfficiency, read_grating_file
from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import random_efficiency, random_mapping, render_lamps
from rig.cli import app, main
from rig.grating import _with_direct, median_relative_sigma, refine_session_grating
from tests.rendered_capture import Capture, efficiency, render_capture, shared_capture
from tests.rig.test_estimate_session import write_session
from tests.synthetic_cameras import as_spectrum


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(scope="module")
def other(capture: Capture, tmp_path_factory: pytest.TempPathFactory) -> Capture:
    """Another camera (another mix of the basis) through the shared capture's grating."""
    root = tmp_path_factory.mktemp("two-cameras")
    rendered = render_capture(
        root / "capture",
        root / "basis",
        dark_frames=True,
        dark_current_dn_per_s=300.0,
        camera_mix=((0, 0.5), (3, 0.5)),
        seed=7,
    )
    assert not np.allclose(rendered.truth, capture.truth)
    return rendered


@pytest.fixture(scope="module")
def sessions(
    capture: Capture, other: Capture, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("sessions")
    return write_session(root, capture), write_session(root, other)


def _efficiency_error(grating: GratingEfficiency) -> float:
    """RMS difference of the file's η from the rendered grating's, both with maximum 1."""
    truth = efficiency(DEFAULT_GRID.wavelength_nm)
    estimate = np.asarray(grating.efficiency)
    return float(np.sqrt(np.mean((estimate / estimate.max() - truth / truth.max()) ** 2)))


def test_two_cameras_refine_one_grating_through_rig_grating(
    sessions: tuple[Path, Path],
    capture: Capture,
    other: Capture,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """One test (the pooled refinement, the suite's costliest step here, runs once): `rig grating`
    pools two cameras' sessions; each camera alone through the Python API; the file the command
    wrote is what `rig estimate --grating` takes; the command's refusals."""
    for module in ("rig.grating", "calib.pipeline.estimate"):
        monkeypatch.setattr(f"{module}.default_camera_basis", lambda *a, **k: capture.basis)
    out = tmp_path / "sheet.json"
    arguments = ["grating", *map(str, sessions), "--out", str(out)]
    result = CliRunner().invoke(app, [*arguments, "--description", "300 l/mm sheet"])
    assert result.exit_code == 0, result.output
    assert f"grating: {out} (median σ" in result.output
    assert f"{sessions[1].name}: camera unknown, lamps LED, FL" in result.output
    before = out.read_bytes()
    pooled = read_grating_file(out)
    singles = [
        refine_session_grating([session], tmp_path / f"{index}.json", basis=capture.basis).grating
        for index, session in enumerate(sessions)
    ]
    # Pooling the two cameras' direct equations narrows η's band below either camera's alone and
    # lands nearer the truth than the worse of them (a flat grating would be 35 % off).
    spread = median_relative_sigma(pooled)
    assert spread is not None
    assert all(spread < (median_relative_sigma(single) or 0.0) for single in singles)
    assert _efficiency_error(pooled) < 0.05
    assert _efficiency_error(pooled) < max(_efficiency_error(single) for single in singles)
    # The file says where it came from.
    recorded = pooled.provenance["sessions"]
    assert [entry["directory"] for entry in recorded] == [path.name for path in sessions]
    assert all(entry["lamps"] == ["LED", "FL"] for entry in recorded)
    assert pooled.geometry["description"] == "300 l/mm sheet"
    assert len(pooled.geometry["mappings"]) == 2
    # The file is what rig estimate --grating takes: the sensitivity from the profiles and η.
    estimated = tmp_path / "estimate"
    arguments_estimate = [
        "estimate",
        str(sessions[1]),
        "--method",
        "multilamp",
        "-q",
        "--no-report",
    ]
    result = CliRunner().invoke(
        app, [*arguments_estimate, "--grating", str(out), "--out", str(estimated)]
    )
    assert result.exit_code == 0, result.output
    document = json.loads((estimated / "result.json").read_text())
    assert document["diagnostics"]["grating"]["source"] == str(out)
    curves = read_camera_csv(estimated / "sensitivity.csv").values
    assert relative_error(curves, other.truth) < 0.015  # measured 0.65 ×10⁻²
    for argv, message in (
        (arguments, f"{out}: exists; pass --force to replace it"),
        (
            ["grating", str(sessions[0]), str(sessions[0]), "--out", str(tmp_path / "x.json")],
            "the same session as",
        ),
        (["grating", str(tmp_path), "--out", str(tmp_path / "y.json")], "not a session"),
        (
            ["grating", str(sessions[0]), "--out", str(tmp_path / "z.json"), "--weight-rule", "x"],
            "--weight-rule",
        ),
    ):
        monkeypatch.setattr(sys, "argv", ["rig", *argv])
        with pytest.raises(SystemExit) as exit_info:
            main()
        assert exit_info.value.code == 2
        error = capsys.readouterr().err
        assert error.startswith("rig: error:") and message in error, error
    assert out.read_bytes() == before
    assert not (tmp_path / "x.json").exists()


def test_lamps_without_a_direct_measurement_are_left_out_and_named() -> None:
    rng = np.random.default_rng(0)
    mapping = random_mapping(rng)
    camera = shared_capture().truth
    lamps = render_lamps(
        ("LED-B3", "FL2"), as_spectrum(camera), mapping, random_efficiency(rng), rng, 0.01
    )
    saturated = replace(lamps[1], direct_rgb=None, direct_sigma=None)
    warnings: list[str] = []
    assert _with_direct("S1", [lamps[0], saturated], warnings) == [lamps[0]]
    assert warnings == ["S1: lamp 'FL2' left out (its direct spot is saturated in every frame)"]
    with pytest.raises(InputError, match="S2: no lamp has a direct"):
        _with_direct("S2", [saturated], [])
