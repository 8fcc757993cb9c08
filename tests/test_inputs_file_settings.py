"""An inputs file's ``estimate:`` block: the estimate's settings beside its lamps (decision 0179).

A typed option beats the file, the file beats the defaults, in ``calib estimate`` and in each set
of ``calib batch`` alike.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import get_args

import numpy as np
import pytest
from pydantic import ValidationError

from calib.cli.app import main
from calib.cli.estimate import parse_estimate_command
from calib.cli.options import FocalLengthOption, GroovesPerMmOption, PixelPitchOption
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid, write_csv
from calib.model.bases import CameraBasis, camera_basis
from calib.pipeline.estimate import StatedOptics
from calib.pipeline.inputs_file import EstimateBlock
from tests.rendered_capture import Capture, colour_lamps, shared_capture
from tests.synthetic_cameras import as_spectrum, spanning_set
from tests.test_cli_estimate import _call, _write_profile


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(autouse=True)
def exact_basis(
    monkeypatch: pytest.MonkeyPatch, capture: Capture, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """The test's exact basis on the grid asked for (no data directory lookups)."""
    cache = tmp_path_factory.mktemp("basis")

    def on_grid(grid: WavelengthGrid = DEFAULT_GRID, **_: object) -> CameraBasis:
        if grid == capture.basis.grid:
            return capture.basis
        cameras = [as_spectrum(camera, f"c{k}") for k, camera in enumerate(spanning_set())]
        return camera_basis(cameras, grid=grid, n_vectors=7, source="exact", cache_dir=cache)

    monkeypatch.setattr("calib.pipeline.estimate.default_camera_basis", on_grid)


def _inputs_file(folder: Path, capture: Capture, estimate: str = "", *, seed: int = 3) -> Path:
    """Two profile lamps with direct RGB in ``folder``/lamps.yaml, then ``estimate`` (YAML)."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for lamp, kind in (("LED", "led"), ("FL", "fluorescent")):
        write_csv(folder / f"{lamp}.csv", colour_lamps()[lamp][1])
        _, rgb = _write_profile(folder / f"{lamp}.prof.csv", capture, lamp, seed=seed)
        direct = ", ".join(f"{v:.10g}" for v in rgb)
        rows.append(
            f"  - {{name: {lamp}, kind: {kind}, profile: {lamp}.prof.csv, spectrum: {lamp}.csv,"
            f" direct_rgb: [{direct}]}}\n"
        )
    file = folder / "lamps.yaml"
    file.write_text("lamps:\n" + "".join(rows) + estimate)
    return file


def _curves(out: Path) -> np.ndarray:
    return read_camera_csv(out / "sensitivity.csv").values


def test_the_files_settings_give_the_curves_of_the_same_options_typed(
    capture: Capture, tmp_path: Path
) -> None:
    file = _inputs_file(
        tmp_path / "cam", capture, "estimate:\n  grid: 400:700:5\n  method: prior\n"
    )
    code, _, stderr = _call(["--inputs", str(file), "--out", str(tmp_path / "f"), "--no-report"])
    assert code == 0, stderr
    plain = tmp_path / "cam" / "plain.yaml"
    plain.write_text(file.read_text().split("estimate:")[0])
    typed = ["--method", "prior", "--grid", "400:700:5", "--no-report"]
    code, _, stderr = _call(["--inputs", str(plain), "--out", str(tmp_path / "t"), *typed])
    assert code == 0, stderr
    np.testing.assert_array_equal(_curves(tmp_path / "f"), _curves(tmp_path / "t"))
    assert _curves(tmp_path / "f").shape[0] == WavelengthGrid.parse("400:700:5").size
    record = json.loads((tmp_path / "f" / "result.json").read_text())
    assert f"{file}'s estimate: {{grid: 400:700:5, method: prior}}" in json.dumps(record)
    # Typed, the default grid wins, said once on stderr.
    argv = ["--inputs", str(file), "--out", str(tmp_path / "d"), "--grid", "400:700:10"]
    code, _, stderr = _call([*argv, "--no-report", "-q"])
    assert code == 0, stderr
    assert stderr.count(f"--grid 400:700:10 overrides {file}'s estimate.grid 400:700:5") == 1
    assert _curves(tmp_path / "d").shape[0] == DEFAULT_GRID.size


def test_a_relative_grating_path_is_the_files_folder(tmp_path: Path) -> None:
    (tmp_path / "cam").mkdir()
    file = tmp_path / "cam" / "lamps.yaml"
    file.write_text(
        "lamps:\n  - {name: A, profile: a.csv, spectrum: FL2}\n"
        "estimate:\n  grating: ../gratings/sheet.json\n  grooves_per_mm: 1000\n"
        "  exclude_camera: Sony*\n  assumed_grating: physical\n  mapping_lamp: A\n"
    )
    settings = parse_estimate_command(["--inputs", str(file), "--out", "o"]).settings
    assert settings.grating == tmp_path / "cam" / "../gratings/sheet.json"
    assert settings.optics == StatedOptics(grooves_per_mm=1000.0)
    assert settings.exclude_cameras == ("Sony*",)
    assert (settings.assumed_grating, settings.mapping_lamp) == ("physical", "A")
    assert settings.warnings == ()
    # The same file typed is no contradiction; another one is.
    same = tmp_path / "gratings" / "sheet.json"
    other = tmp_path / "gratings" / "other.json"
    for typed, warned in ((same, False), (other, True)):
        argv = ["--inputs", str(file), "--out", "o", "--grating", str(typed)]
        settings = parse_estimate_command(argv).settings
        assert settings.grating == typed and bool(settings.warnings) == warned


def test_a_typed_option_beats_the_file_with_a_warning_naming_both(tmp_path: Path) -> None:
    file = tmp_path / "lamps.yaml"
    file.write_text(
        "lamps:\n  - {name: A, profile: a.csv, spectrum: FL2}\n"
        "estimate:\n  grid: 400:700:5\n  method: prior\n  grooves_per_mm: 600\n"
    )
    argv = ["--inputs", str(file), "--out", "o", "--grid", "400:700:10", "--method", "auto"]
    settings = parse_estimate_command([*argv, "--focal-length-mm", "35"]).settings
    assert settings.grid == DEFAULT_GRID and settings.method == "auto"  # typed, as the default
    assert settings.optics == StatedOptics(600.0, 35.0, None)  # one optic each, both kept
    assert settings.warnings == (
        f"--method auto overrides {file}'s estimate.method prior",
        f"--grid 400:700:10 overrides {file}'s estimate.grid 400:700:5",
    )
    # A typed option that says what the file says is no contradiction.
    same = parse_estimate_command(["--inputs", str(file), "--out", "o", "--method", "prior"])
    assert same.settings.warnings == () and same.settings.grid == WavelengthGrid.parse("400:700:5")
    # --weight-rule goes with the file's multilamp.
    file.write_text(file.read_text().replace("method: prior", "method: multilamp"))
    rule = parse_estimate_command(["--inputs", str(file), "--out", "o", "--weight-rule", "upre"])
    assert rule.settings.method == "multilamp" and rule.settings.method_options is not None


def test_the_optics_ranges_are_the_options() -> None:
    """A value means the same in the file as on the command line (one range for both,
    calib.core.optics_ranges): the options' ends are taken, a little beyond them refused."""
    for key, option in (
        ("grooves_per_mm", GroovesPerMmOption),
        ("focal_length_mm", FocalLengthOption),
        ("pixel_pitch_um", PixelPitchOption),
    ):
        info = get_args(option)[1]  # the typer.Option
        for value in (info.min, info.max):
            assert getattr(EstimateBlock.model_validate({key: value}), key) == value
        for value in (info.min * 0.99, info.max * 1.01):
            with pytest.raises(ValidationError):
                EstimateBlock.model_validate({key: value})


def test_a_batch_runs_each_file_as_it_says(capture: Capture, tmp_path: Path) -> None:
    """Two files with different settings: each set's curves are its file's run alone; a typed
    batch option beats a file's, said in that set's result."""
    files = [
        _inputs_file(tmp_path / "cam-a", capture, "estimate: {grid: 400:700:5, method: prior}\n"),
        _inputs_file(
            tmp_path / "cam-b", capture, "estimate: {method: prior, grooves_per_mm: 600}\n", seed=4
        ),
    ]
    out = tmp_path / "batch"
    argv = ["batch", *map(str, files), "--out", str(out), "--jobs", "1", "--no-report", "-q"]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code in (0, None)
    batched = [_curves(out / f"{file.parent.name}-lamps") for file in files]
    assert batched[0].shape[0] == 61 and batched[1].shape[0] == 31
    for file, curves in zip(files, batched, strict=True):
        alone = tmp_path / f"{file.parent.name}-alone"
        code, _, stderr = _call(["--inputs", str(file), "--out", str(alone), "--no-report"])
        assert code == 0, stderr
        np.testing.assert_array_equal(curves, _curves(alone))

    typed = tmp_path / "typed"
    with pytest.raises(SystemExit) as exit_:
        main([*argv[:3], "--out", str(typed), "--grid", "400:700:10", "--jobs", "1", "-q"])
    assert exit_.value.code in (0, None)
    first = json.loads((typed / "cam-a-lamps" / "result.json").read_text())
    assert f"--grid 400:700:10 overrides {files[0]}'s estimate.grid 400:700:5" in json.dumps(first)
    assert _curves(typed / "cam-a-lamps").shape[0] == 31
    second = json.loads((typed / "cam-b-lamps" / "result.json").read_text())
    assert "overrides" not in json.dumps(second)


def test_the_weight_rule_is_a_key_under_the_same_rule(tmp_path: Path) -> None:
    """``weight_rule`` as ``--weight-rule``: the file beats the default, a typed rule beats the
    file with a warning naming both, and with a method that takes none it is the option's error."""
    from calib.core.errors import InputError
    from calib.methods.multilamp import MultilampOptions

    file = tmp_path / "lamps.yaml"
    file.write_text(
        "lamps:\n  - {name: A, profile: a.csv, spectrum: FL2}\n"
        "estimate:\n  method: multilamp\n  weight_rule: typicality\n"
    )
    base = ["--inputs", str(file), "--out", "o"]
    settings = parse_estimate_command(base).settings
    assert settings.method_options == MultilampOptions(weight_rule="typicality")
    assert settings.warnings == ()
    typed = parse_estimate_command([*base, "--weight-rule", "evidence"]).settings
    assert typed.method_options == MultilampOptions(weight_rule="evidence")
    assert typed.warnings == (
        f"--weight-rule evidence overrides {file}'s estimate.weight_rule typicality",
    )
    same = parse_estimate_command([*base, "--weight-rule", "typicality"]).settings
    assert same.warnings == () and same.method_options == settings.method_options
    # The file's rule with a method that takes none: the command line's error, from the file.
    for argv, method in ((["--method", "prior"], "prior"), ([], "auto")):
        if not argv:
            file.write_text(file.read_text().replace("  method: multilamp\n", ""))
        with pytest.raises(InputError) as refused:
            parse_estimate_command([*base, *argv])
        assert str(refused.value) == (
            f"{file}'s estimate.weight_rule: applies to --method multilamp only "
            f"(the method is {method!r})"
        )
    # Without a method of its own, the file's rule goes with a typed --method multilamp.
    typed_method = parse_estimate_command([*base, "--method", "multilamp"]).settings
    assert typed_method.method_options == MultilampOptions(weight_rule="typicality")
    with pytest.raises(ValidationError, match="'guess' is not a rule"):
        EstimateBlock.model_validate({"weight_rule": "guess"})


def test_a_batch_weight_rule_goes_with_each_files_method(capture: Capture, tmp_path: Path) -> None:
    """``calib batch --weight-rule`` without ``--method``: each file's multilamp takes the typed
    rule (over one file's own, with the warning); the file's own rule is used where none is typed."""
    files = [
        _inputs_file(
            tmp_path / "cam-a", capture, "estimate: {method: multilamp, weight_rule: typicality}\n"
        ),
        _inputs_file(tmp_path / "cam-b", capture, "estimate: {method: multilamp}\n", seed=4),
    ]
    out = tmp_path / "batch"
    argv = ["batch", *map(str, files), "--out", str(out), "--jobs", "1", "--no-report", "-q"]
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--weight-rule", "evidence"])
    assert exit_.value.code in (0, None)
    for file in files:
        document = json.loads((out / f"{file.parent.name}-lamps" / "result.json").read_text())
        assert document["diagnostics"]["prior_weight_rule"] == "evidence"
        overridden = f"--weight-rule evidence overrides {file}'s estimate.weight_rule typicality"
        assert (overridden in json.dumps(document)) is (file == files[0])
    alone = tmp_path / "alone"
    code, _, stderr = _call(["--inputs", str(files[0]), "--out", str(alone), "--no-report"])
    assert code == 0, stderr
    document = json.loads((alone / "result.json").read_text())
    assert document["diagnostics"]["prior_weight_rule"] == "typicality"
