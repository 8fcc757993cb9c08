"""``calib estimate``: argument groups, exit codes, --json/--quiet, images and profile-level input."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.cli.app import main
from calib.cli.estimate import EstimateRequest, parse_estimate_command
from calib.core.errors import EstimationError, InputError
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.grating_file import GratingEfficiency, read_grating_file, write_grating_file
from calib.core.metrics import relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid, write_csv
from calib.methods import MultilampOptions
from calib.model.forward import PeakFractionNoise, render_observation
from calib.pipeline import LampImages, LampProfile
from calib.pipeline.estimate import StatedOptics
from calib.wavelength import lamps_named
from tests.rendered_capture import (
    GRATING,
    Capture,
    colour_lamps,
    efficiency,
    shared_capture,
)
from tests.synthetic_cameras import as_spectrum


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(autouse=True)
def exact_basis(monkeypatch: pytest.MonkeyPatch, capture: Capture) -> None:
    """The command uses the test's exact basis (no data directory lookups)."""
    monkeypatch.setattr(
        "calib.pipeline.estimate.default_camera_basis", lambda *a, **k: capture.basis
    )


def _call(argv: list[str]) -> tuple[int, str, str]:
    """Run ``calib estimate ARGV`` as the console script does; (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(["estimate", *argv])
        except SystemExit as exit_:
            code = exit_.code
    return (code if isinstance(code, int) else 1), out.getvalue(), err.getvalue()


def _image_args(capture: Capture) -> list[str]:
    argv: list[str] = []
    for lamp in capture.lamps:
        argv += ["--lamp", lamp.name, "--kind", lamp.kind, "--images", *map(str, lamp.frames)]
        argv += ["--spectrum", str(lamp.spectrum_csv)]
    return argv


# ---------------------------------------------------------------------------------- the parser

P = Path

#: Command lines of the hand-written parser this command had, and the settings it gave them
#: (checked against that parser before it was replaced by typer): they still mean the same.
OLD_COMMAND_LINES: list[tuple[list[str], dict[str, object]]] = [
    (
        ["--out", "out", "--lamp", "A", "--images", "a1.dng", "a2.dng", "--dark", "d.dng",
         "--spectrum", "a.csv", "--kind", "LED", "--exposure", "0.01", "0.1",
         "--lamp", "B", "--kind=fluorescent", "--spectrum=b.csv", "--images", "b.dng",
         "--grid=400:700:5", "--mapping-lamp", "B", "--json"],
        {
            "lamps": (
                LampImages("A", "led", P("a.csv"), (P("a1.dng"), P("a2.dng")), (P("d.dng"),), (0.01, 0.1)),
                LampImages("B", "fluorescent", P("b.csv"), (P("b.dng"),)),
            ),
            "out_dir": P("out"), "method": "auto", "method_options": None, "mapping_lamp": "B",
            "grid": WavelengthGrid.parse("400:700:5"), "data_dir": None, "grating": None,
            "force": False, "quiet": False, "json_output": True,
        },
    ),
    (
        ["--lamp", "P", "--profile", "p.csv", "--spectrum", "s.csv", "--direct", "1,2,3.5",
         "--bandwidth", "8", "--out", "o", "--method", "multilamp", "--weight-rule", "typicality",
         "--data-dir", "data", "--grating", "g.json", "--force", "-q"],
        {
            "lamps": (LampProfile("P", "other", P("s.csv"), P("p.csv"), (1.0, 2.0, 3.5), 8.0),),
            "out_dir": P("o"), "method": "multilamp",
            "method_options": MultilampOptions(weight_rule="typicality"), "mapping_lamp": None,
            "grid": DEFAULT_GRID, "data_dir": P("data"), "grating": P("g.json"),
            "force": True, "quiet": True, "json_output": False,
        },
    ),
    (
        # the command's options between a lamp's options; darks with their own exposure times
        ["--lamp", "L", "--images", "x.dng", "--out", "o2", "--spectrum", "l.csv",
         "--dark", "k1.dng", "k2.dng", "--dark-exposure", "0.5", "0.25", "--exposure", "2",
         "--quiet", "--method", "prior"],
        {
            "lamps": (
                LampImages("L", "other", P("l.csv"), (P("x.dng"),), (P("k1.dng"), P("k2.dng")), (2.0,), (0.5, 0.25)),
            ),
            "out_dir": P("o2"), "method": "prior", "method_options": None, "mapping_lamp": None,
            "grid": DEFAULT_GRID, "data_dir": None, "grating": None,
            "force": False, "quiet": True, "json_output": False,
        },
    ),
]  # fmt: skip


def _settings_of(request: EstimateRequest) -> dict[str, object]:
    settings = request.settings
    return {
        "lamps": request.lamps,
        "out_dir": request.out_dir,
        "method": settings.method,
        "method_options": settings.method_options,
        "mapping_lamp": settings.mapping_lamp,
        "grid": settings.grid,
        "data_dir": settings.data_dir,
        "grating": settings.grating,
        "force": request.force,
        "quiet": request.quiet,
        "json_output": request.json_output,
    }


@pytest.mark.parametrize(("argv", "expected"), OLD_COMMAND_LINES)
def test_the_old_command_lines_parse_to_the_same_settings(
    argv: list[str], expected: dict[str, object]
) -> None:
    request = parse_estimate_command(argv)
    assert _settings_of(request) == expected
    assert request.settings.command_line == ("calib", "estimate", *argv)


def test_the_same_lamps_from_an_inputs_file(tmp_path: Path) -> None:
    _, expected = OLD_COMMAND_LINES[0]
    (tmp_path / "lamps.yaml").write_text(
        "lamps:\n"
        "  - {name: A, kind: LED, images: [a1.dng, a2.dng], darks: [d.dng], spectrum: a.csv,\n"
        "     exposure_s: [0.01, 0.1]}\n"
        "  - {name: B, kind: fluorescent, spectrum: b.csv, images: [b.dng]}\n"
    )
    request = parse_estimate_command(
        ["--inputs", str(tmp_path / "lamps.yaml"), "--out", "out", "--grid=400:700:5",
         "--mapping-lamp", "B", "--json"]
    )  # fmt: skip
    relative = tuple(
        replace(
            lamp,
            spectrum=lamp.spectrum.relative_to(tmp_path),
            images=tuple(path.relative_to(tmp_path) for path in lamp.images),
            darks=tuple(path.relative_to(tmp_path) for path in lamp.darks),
        )
        for lamp in request.lamps
        if isinstance(lamp, LampImages) and isinstance(lamp.spectrum, Path)
    )
    assert relative == expected["lamps"]  # paths relative to the file's directory
    assert {**_settings_of(request), "lamps": relative} == expected


def test_an_inputs_file_names_spectra_and_fits_planes_relative_to_itself(tmp_path: Path) -> None:
    """A spectrum's name (FL2, builtin:NAME, gauss:…) stays a name: the file's directory prefixed
    it ('dir/builtin:hg is not a spectrum file'); files, FITS planes among them, are relative to the
    file; ``channel_gains`` reaches the lamp."""
    (tmp_path / "a.csv").write_text("wavelength_nm,value\n380,1\n780,1\n")
    (tmp_path / "lamps.yaml").write_text(
        "lamps:\n"
        "  - {name: A, kind: led, profile: a-profile.csv, spectrum: a.csv}\n"
        "  - {name: B, kind: fluorescent, profile: b-profile.csv, spectrum: builtin:hg}\n"
        "  - {name: C, profile: [c R.fit, c G.fit, c B.fit], spectrum: FL2,\n"
        "     channel_gains: unknown}\n"
    )
    request = parse_estimate_command(["--inputs", str(tmp_path / "lamps.yaml"), "--out", "out"])
    a, b, c = request.lamps
    assert isinstance(a, LampProfile) and isinstance(b, LampProfile) and isinstance(c, LampProfile)
    assert a.spectrum == tmp_path / "a.csv" and a.profile == tmp_path / "a-profile.csv"
    assert b.spectrum == Path("builtin:hg") and c.spectrum == Path("FL2")
    assert c.profile == tuple(tmp_path / f"c {plane}.fit" for plane in "RGB")
    assert (a.channel_gains, c.channel_gains) == ("raw", "unknown")


# The default suite runs the same batch-against-alone comparison, with settings in the files, in
# tests/test_inputs_file_settings.py::test_a_batch_runs_each_file_as_it_says.
@pytest.mark.slow
def test_inputs_files_run_as_a_batch_as_each_runs_alone(capture: Capture, tmp_path: Path) -> None:
    """``calib batch`` takes inputs files (the ``inputs`` reader), named by folder and stem so
    one ``lamps.yaml`` per camera folder stays apart; each set's curves are those of
    ``calib estimate --inputs`` on the same file."""
    files = []
    for folder, seed in (("cam-a", 3), ("cam-b", 4)):
        (tmp_path / folder).mkdir()
        rows = []
        for lamp, kind in (("LED", "led"), ("FL", "fluorescent")):
            write_csv(tmp_path / folder / f"{lamp}.csv", colour_lamps()[lamp][1])
            _, rgb = _write_profile(
                tmp_path / folder / f"{lamp}.prof.csv", capture, lamp, seed=seed
            )
            direct = ", ".join(f"{v:.10g}" for v in rgb)
            rows.append(
                f"  - {{name: {lamp}, kind: {kind}, profile: {lamp}.prof.csv, spectrum: {lamp}.csv,"
                f" direct_rgb: [{direct}]}}\n"
            )
        files.append(tmp_path / folder / "lamps.yaml")
        files[-1].write_text("lamps:\n" + "".join(rows))
    out = tmp_path / "batch"
    argv = ["batch", *map(str, files), "--out", str(out), "--jobs", "1", "--no-report", "-q"]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code in (0, None)
    summary = (out / "summary.csv").read_text()
    assert "cam-a-lamps" in summary and "cam-b-lamps" in summary
    for file in files:
        alone = tmp_path / f"{file.parent.name}-alone"
        code, _, stderr = _call(["--inputs", str(file), "--out", str(alone), "--no-report"])
        assert code == 0, stderr
        batched = read_camera_csv(out / f"{file.parent.name}-lamps" / "sensitivity.csv").values
        np.testing.assert_array_equal(batched, read_camera_csv(alone / "sensitivity.csv").values)


#: An inputs file's one lamp, for the mistakes after it.
ONE_LAMP = "lamps:\n  - {name: A, profile: a.csv, spectrum: FL2}\n"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("lamps:\n  - {name: A, spectrum: a.csv}\n", "lamps.yaml:2: lamps[0]: give either images (a RAW bracket) or profile"),
        ("lamps:\n  - {name: A, spectrum: a.csv, imgs: [a.dng]}\n", "lamps.yaml:2: lamps[0].imgs: unknown key 'imgs' (did you mean 'images'?)"),
        ("lamps:\n  - name: A\n    spectrum: a.csv\n    images: [a.dng]\n    exposure_s: [-1]\n", "lamps.yaml:5: lamps[0].exposure_s[0]: -1 is out of range; must be > 0"),
        ("lamps:\n  - {name: A, spectrum: a.csv, images: [a.dng], kind: laser}\n", "lamps[0].kind: 'laser' is not allowed"),
        ("lamps: []\n", "lamps.yaml:1: lamps: List should have at least 1 item"),
        ("lamp:\n  - {name: A}\n", "unknown key 'lamp' (did you mean 'lamps'?)"),
        ("lamps:\n  - {name: A, spectrum: a.csv, profile: p.csv, direct_rgb: [1, 2]}\n", "lamps[0].direct_rgb"),
        ("lamps:\n  - name: A\n    spectrum: a.csv\n    profile: p.csv\n    bandwidth_nm: 500\n", "lamp 'A': --bandwidth 500 (or an --inputs file's bandwidth_nm) is not a spectrometer's bandwidth"),
        # the estimate: block (decision 0179), checked as the options are
        (f"{ONE_LAMP}estimate:\n  method: prior\n  grid: 400:700:0\n", "lamps.yaml:5: estimate.grid: step must be > 0 nm"),
        (f"{ONE_LAMP}estimate:\n  grid: 400-700\n", "lamps.yaml:4: estimate.grid: expected START:STOP:STEP"),
        (f"{ONE_LAMP}estimate:\n  method: magic\n", "lamps.yaml:4: estimate.method: unknown method 'magic'"),
        (f"{ONE_LAMP}estimate:\n  grids: 400:700:5\n", "lamps.yaml:4: estimate.grids: unknown key 'grids' (did you mean 'grid'?)"),
        (f"{ONE_LAMP}estimate:\n  grooves_per_mm: 0.5\n", "lamps.yaml:4: estimate.grooves_per_mm: 0.5 is out of range"),
        (f"{ONE_LAMP}estimate:\n  assumed_grating: wavy\n", "lamps.yaml:4: estimate.assumed_grating: 'wavy' is not allowed"),
        (f"{ONE_LAMP}estimate:\n  weight_rule: guess\n", "lamps.yaml:4: estimate.weight_rule: 'guess' is not a rule"),
    ],
)  # fmt: skip
def test_an_inputs_file_is_checked_with_one_line_naming_the_field(
    tmp_path: Path, content: str, message: str
) -> None:
    inputs = tmp_path / "lamps.yaml"
    inputs.write_text(content)
    code, _, stderr = _call(["--inputs", str(inputs), "--out", str(tmp_path / "out")])
    assert code == 2 and stderr.count("\n") == 1, stderr
    assert stderr.startswith("calib: error: ") and message in stderr, stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "o", "--images", "a.dng"], "--images before any --lamp"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--imgs", "x"], "did you mean --images"),
        (["--out", "o", "--lamp", "A", "--images", "a"], "lamp 'A' --spectrum: required key is missing"),
        (["--lamp", "A", "--images", "a", "--spectrum", "s"], "Missing option '--out'"),
        (["--out", "o", "--lamp", "A", "--spectrum", "s"], "give either --images"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--profile", "p", "--spectrum", "s"], "not both"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--spectrum", "t"], "given twice"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--kind", "led", "x"], "one value, got 2"),
        (["--out", "o", "--lamp", "A", "--images", "--spectrum", "s"], "at least one value"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--kind", "laser"], "lamp 'A' --kind: 'laser' is not allowed"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--exposure", "-1"], "lamp 'A' --exposure: '-1' is out of range; must be > 0"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--grid", "700:400:10"], "--grid"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--direct", "1,2,3"], "--direct goes with --profile"),
        (["--out", "o", "--lamp", "A", "--profile", "p", "--spectrum", "s", "--direct", "1,2"], "three numbers"),
        (["stray", "--out", "o"], "unexpected extra argument(s) (stray)"),
        (["--out", "o", "--quiet=yes", "--lamp", "A"], "option '--quiet' does not take a value"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--method", "guess"], "unknown method 'guess'; available: auto, prior"),
        (["--out", "o"], "no lamps; give --lamp NAME"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--grooves-per-mm", "0"], "--grooves-per-mm"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--pixel-pitch-um", "x"], "--pixel-pitch-um"),
        (["--out", "o", "--lamp", "A", "--profile", "a.csv", "b.csv", "--spectrum", "s"], "--profile takes one file, or the R, G and B planes of a FITS export as three files"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--channel-gains", "unknown"], "--channel-gains goes with --profile"),
        (["--out", "o", "--lamp", "A", "--profile", "a.csv", "--spectrum", "s", "--channel-gains", "wb"], "lamp 'a' --channel-gains: 'wb' is not allowed"),
    ],
)  # fmt: skip
def test_command_line_mistakes_are_one_line_exit_2(argv: list[str], message: str) -> None:
    code, stdout, stderr = _call(argv)
    assert code == 2, stderr
    assert stderr.startswith("calib: error: ") and stderr.count("\n") == 1, stderr
    assert message.lower() in stderr.lower(), stderr
    assert stdout == ""


def test_the_optics_are_stated_on_the_command_line() -> None:
    """Issue 16: the mapping's physical prior from the command line, in the one option style."""
    request = parse_estimate_command(
        ["--out", "o", "--lamp", "A", "--images", "a.dng", "--spectrum", "a.csv",
         "--grooves-per-mm", "600", "--focal-length-mm", "24", "--pixel-pitch-um", "4.3"]
    )  # fmt: skip
    assert request.settings.optics == StatedOptics(600.0, 24.0, 4.3)
    assert (
        parse_estimate_command(
            ["--out", "o", "--lamp", "A", "--images", "a.dng", "--spectrum", "a.csv"]
        ).settings.optics
        == StatedOptics()
    )
    # Over what the RAW files say, into the optics the mapping's prior reads.
    exif = {"camera": "Nikon D7000", "focal_length_mm": None, "pixel_pitch_um": 4.78}
    optics = StatedOptics(600.0, 24.0, None).over(exif)
    assert optics == {**exif, "grooves_per_mm": 600.0, "focal_length_mm": 24.0}
    stated = StatedOptics(None, None, 5.0).over(exif)
    assert stated["pixel_pitch_um"] == 5.0 and stated["pitch_source"] == "stated"


def test_the_help_lists_the_lamp_options_and_the_choices() -> None:
    code, stdout, _ = _call(["-h"])
    assert code == 0
    for flag in ("--lamp", "--images", "--spectrum", "--dark-exposure", "--inputs", "-q"):
        assert flag in stdout
    assert "known-grating" in stdout and "typicality" in stdout  # --method, --weight-rule
    assert "fluorescent, halogen" in stdout  # --kind
    # help never fails on a half-typed lamp
    assert _call(["--lamp", "A", "--images", "-h"])[0] == 0


# ------------------------------------------------------------------------- images, end to end


def test_images_end_to_end_with_json_summary(capture: Capture, tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    code, stdout, stderr = _call([*_image_args(capture), "--out", str(out_dir), "--json"])
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["status"] == "ok" and summary["method"] == "prior"
    assert summary["mapping"]["method"].startswith("lines of")
    assert 0 < summary["mapping_re_estimate"] < 0.01
    assert [lamp["name"] for lamp in summary["lamps"]] == ["LED", "FL"]
    for key in ("sensitivity", "result", "report", "camera_json", "grating"):
        assert Path(summary["files"][key]).is_file()
    document = json.loads((out_dir / "result.json").read_text())
    assert document["provenance"]["command_line"][:4] == ["calib", "estimate", "--lamp", "LED"]
    values = read_camera_csv(out_dir / "sensitivity.csv").values
    assert relative_error(values, capture.truth) < 0.05


def test_a_stated_line_density_reaches_the_mapping(capture: Capture, tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    argv = [*_image_args(capture), "--out", str(out_dir), "--quiet", "--grooves-per-mm", "300"]
    argv.append("--no-report")  # the mapping is what is tested
    code, _, stderr = _call(argv)
    assert code == 0, stderr
    details = json.loads((out_dir / "result.json").read_text())["mapping"]["details"]
    assert "300 lines/mm (nominal)" in details["rig_prior"]


def test_an_existing_result_needs_force(capture: Capture, tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    (out_dir / "result.json").write_text("{}")
    code, _, stderr = _call([*_image_args(capture), "--out", str(out_dir), "--quiet"])
    assert code == 2 and "--force" in stderr
    code, stdout, stderr = _call(
        [*_image_args(capture), "--out", str(out_dir), "--quiet", "--force", "--no-report"]
    )
    assert code == 0 and stdout == "", stderr
    assert json.loads((out_dir / "result.json").read_text())["method"] == "prior"
    assert not (out_dir / "report.html").exists()  # --no-report, as in rig estimate


def test_bad_input_exits_2_with_one_line_naming_the_file(capture: Capture, tmp_path: Path) -> None:
    broken = tmp_path / "broken.dng"
    broken.write_bytes(capture.lamps[0].frames[0].read_bytes()[:5000])
    argv = [
        "--lamp",
        "LED",
        "--images",
        str(broken),
        "--spectrum",
        str(capture.lamps[0].spectrum_csv),
    ]
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json"])
    assert code == 2
    assert stderr.count("\n") == 1 and "broken.dng" in stderr
    error = json.loads(stdout)
    assert error["status"] == "error" and error["exit_code"] == 2 and "broken.dng" in error["error"]


def test_estimation_failure_exits_1(
    capture: Capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def fail(*args: object, **kwargs: object) -> None:
        raise EstimationError("the solve produced no positive sensitivity")

    monkeypatch.setattr("calib.pipeline.estimate.estimate", fail)
    code, _, stderr = _call([*_image_args(capture), "--out", str(tmp_path / "out")])
    assert code == 1 and "calib: failed: the solve produced" in stderr


def test_internal_error_exits_1_without_traceback(
    capture: Capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def crash(*args: object, **kwargs: object) -> None:
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr("calib.pipeline.run.estimate_offline", crash)
    monkeypatch.delenv("CALIB_DEBUG", raising=False)
    code, stdout, stderr = _call([*_image_args(capture), "--out", str(tmp_path / "o"), "--json"])
    assert code == 1
    assert "internal error: ZeroDivisionError" in stderr and "Traceback" not in stderr
    assert json.loads(stdout)["exit_code"] == 1


def test_console_script_exit_codes(tmp_path: Path) -> None:
    script = Path(sys.executable).with_name("calib")
    done = subprocess.run(
        [str(script), "estimate", "--lamp", "A", "--images", str(tmp_path / "none.dng"),
         "--spectrum", str(tmp_path / "none.csv"), "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert (
        done.stderr.strip().startswith("calib: error:")
        and "none.dng: file not found" in done.stderr
    )
    assert done.stderr.count("\n") == 1
    help_text = subprocess.run(
        [str(script), "estimate", "--help"], capture_output=True, text=True, timeout=60, check=False
    )
    assert help_text.returncode == 0 and "--lamp" in help_text.stdout


# ------------------------------------------------------------------------------ profile input


def _write_profile(
    path: Path, capture: Capture, lamp: str, *, axis: str = "pixel", seed: int = 3
) -> tuple[Path, np.ndarray]:
    """A noisy rendered profile as CSV (with sigma columns); returns the file and the direct RGB."""
    pixel = np.arange(470.0, 1030.0, 2.0)
    rendered = render_observation(
        colour_lamps()[lamp][1],
        as_spectrum(capture.truth),
        mapping=GRATING,
        pixel=pixel,
        grating_efficiency=efficiency,
        noise=PeakFractionNoise(0.003, 0.0005),
        rng=np.random.default_rng(seed),
    )
    observation = rendered.observation
    first = pixel if axis == "pixel" else GRATING.wavelength_nm(pixel)
    assert observation.profile_sigma is not None and observation.direct_rgb is not None
    table = np.column_stack([first, observation.profile, observation.profile_sigma])
    header = f"{axis},r,g,b,r_sigma,g_sigma,b_sigma"
    np.savetxt(path, table, delimiter=",", header=header, comments="")
    return path, observation.direct_rgb


#: What these profile inputs are warned about: no --bandwidth.
EXPECTED_FLAGS = {"no_spectrometer_bandwidth"}


def _flag_codes(summary: dict[str, object]) -> set[str]:
    warnings = summary["warnings"]
    assert isinstance(warnings, list)
    return {str(line).rsplit("[", 1)[-1].rstrip("]") for line in warnings}


def _profile_args(
    tmp_path: Path, capture: Capture, *, direct: bool, axis: str = "pixel"
) -> list[str]:
    argv: list[str] = []
    for lamp, kind in (("LED", "led"), ("FL", "fluorescent")):
        spectrum = write_csv(tmp_path / f"{lamp}.csv", colour_lamps()[lamp][1])
        profile, rgb = _write_profile(tmp_path / f"{lamp}-profile.csv", capture, lamp, axis=axis)
        argv += [
            "--lamp",
            lamp,
            "--kind",
            kind,
            "--profile",
            str(profile),
            "--spectrum",
            str(spectrum),
        ]
        if direct:
            argv += ["--direct", ",".join(f"{v:.10g}" for v in rgb)]
    return argv


def test_profile_input_with_direct_measurement(capture: Capture, tmp_path: Path) -> None:
    argv = [
        *_profile_args(tmp_path, capture, direct=True),
        "--out",
        str(tmp_path / "out"),
        "--json",
        "--no-report",
    ]
    code, stdout, stderr = _call(argv)
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["method"] == "prior" and _flag_codes(summary) == EXPECTED_FLAGS
    # Two lamps measured directly: auto chose the prior solve and says why.
    assert summary["method_choice"]["requested"] == "auto"
    assert "multilamp needs at least 3" in summary["method_choice"]["reason"]
    values = read_camera_csv(tmp_path / "out" / "sensitivity.csv").values
    assert relative_error(values, capture.truth) < 0.05


@pytest.mark.parametrize("fluorescent", ["FL2", "builtin:hg"])
def test_a_spectrum_given_by_name_is_read_not_opened_as_a_file(
    capture: Capture, tmp_path: Path, fluorescent: str
) -> None:
    """``--spectrum`` takes a colour-science name or a built-in line list (issue 16): no file of
    that name exists, and none is hashed into the provenance (it once failed there, exit 2,
    "builtin:hg: No such file or directory")."""
    argv: list[str] = []
    for lamp, kind, name in (("LED", "led", "LED-B3"), ("FL", "fluorescent", fluorescent)):
        profile, rgb = _write_profile(tmp_path / f"{lamp}-profile.csv", capture, lamp)
        argv += ["--lamp", lamp, "--kind", kind, "--profile", str(profile), "--spectrum", name]
        argv += ["--direct", ",".join(f"{v:.10g}" for v in rgb)]
    out = tmp_path / "out"
    code, _, stderr = _call([*argv, "--out", str(out), "--no-report"])
    assert code == 0, stderr
    result = json.loads((out / "result.json").read_text())
    provenance = result["provenance"]
    assert [lamp["spectrum"] for lamp in provenance["lamps"]] == ["LED-B3", fluorescent]
    # A line list says where the lines are, not how bright the lamp is: mapping only, never the
    # solve (in it, the prior solve fitted Hg lines alone against an FL2 profile: RE 0.35).
    mapping_only = result["method_choice"]["mapping_only"]
    assert mapping_only == (["FL"] if fluorescent.startswith("builtin:") else [])
    codes = {flag["code"] for flag in result["quality"]["flags"]}
    assert ("line_lamp_unmeasured" in codes) == fluorescent.startswith("builtin:")
    assert "coarse_lamp_spectrum" not in codes  # a line list is not a coarse measurement
    assert {record["role"] for record in provenance["inputs"]} == {"profile"}
    values = read_camera_csv(out / "sensitivity.csv").values
    assert relative_error(values, capture.truth) < 0.05


def test_profile_input_with_a_grating_file(capture: Capture, tmp_path: Path) -> None:
    wavelength = np.arange(380.0, 721.0, 2.0)
    grating = write_grating_file(
        tmp_path / "grating.json",
        GratingEfficiency(wavelength, efficiency(wavelength), provenance={"source": "truth"}),
    )
    argv = [*_profile_args(tmp_path, capture, direct=False), "--grating", str(grating)]
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json", "--no-report"])
    assert code == 0, stderr
    summary = json.loads(stdout)
    # and (decision 0044) the known-grating band was never validated, the file states no σ
    unvalidated = {"uncertainty_unvalidated", "grating_sigma_missing"}
    assert summary["method"] == "known-grating"
    assert _flag_codes(summary) == EXPECTED_FLAGS | unvalidated
    assert summary["uncertainty"] is True
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    truth = capture.truth
    estimated = np.column_stack([document["sensitivity"][c] for c in "RGB"])
    sigma = np.column_stack([document["sensitivity_sigma"][c] for c in "RGB"])
    assert relative_error(estimated, truth) < 0.02
    # the per-wavelength uncertainty is honest: errors mostly within 3 σ
    assert np.mean(np.abs(estimated - truth) <= 3 * sigma + 1e-3) > 0.9
    assert not (tmp_path / "out" / "grating.json").exists()  # given, not estimated


def test_a_makers_curve_as_the_grating_and_channel_gains_a_conversion_scaled(
    capture: Capture, tmp_path: Path
) -> None:
    """``--grating`` takes a maker's published curve as a table (per cent, header ``w,
    efficiency`` as LHires III's): η is the curve, obtained "maker's curve", its missing σ warned;
    ``--channel-gains unknown`` takes the channel balance from the camera population and says
    so."""
    wavelength = np.arange(380.0, 721.0, 5.0)
    curve = tmp_path / "maker.csv"
    rows = "".join(
        f"{w:g}, {100 * e:.4f}\n" for w, e in zip(wavelength, efficiency(wavelength), strict=True)
    )
    curve.write_text("w, efficiency\n" + rows)
    grating = read_grating_file(curve)
    assert grating.obtained == "maker's curve" and grating.efficiency_sigma is None
    np.testing.assert_allclose(grating.efficiency.max(), 1.0)
    dark = tmp_path / "dark.csv"
    dark.write_text("w, efficiency\n400, 0\n700, 0\n")
    with pytest.raises(InputError, match="no efficiency above zero"):
        read_grating_file(dark)
    argv = [*_profile_args(tmp_path, capture, direct=False), "--grating", str(curve)]
    argv[argv.index("--spectrum") + 2 : argv.index("--spectrum") + 2] = [
        "--channel-gains",
        "unknown",
    ]
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json", "--no-report"])
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["method"] == "known-grating"
    assert {"grating_sigma_missing", "channel_gains_unknown"} <= _flag_codes(summary)
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert [lamp["channel_gains"] for lamp in document["provenance"]["lamps"]] == ["unknown", "raw"]
    estimated = np.column_stack([document["sensitivity"][c] for c in "RGB"])
    assert relative_error(estimated, capture.truth) < 0.05


def test_a_clipped_profile_is_a_serious_warning_naming_the_lamp_and_the_pixels(
    capture: Capture, tmp_path: Path
) -> None:
    """A profile exported from saturated frames (its band flat at the clip level) gave a curve
    too low there without a word; it is now flagged."""
    argv = _profile_args(tmp_path, capture, direct=True)
    profile = tmp_path / "FL-profile.csv"
    table = np.loadtxt(profile, delimiter=",", skiprows=1)
    table[:, 1:4] = np.minimum(table[:, 1:4], 0.8 * table[:, 1:4].max())
    np.savetxt(
        profile, table, delimiter=",", header="pixel,r,g,b,r_sigma,g_sigma,b_sigma", comments=""
    )
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json", "--no-report"])
    assert code == 0, stderr
    assert _flag_codes(json.loads(stdout)) == EXPECTED_FLAGS | {"saturated_frames"}
    assert "SERIOUS: the first-order band is clipped in the profile of FL (" in stderr
    assert "LED (" not in stderr


def test_a_bandwidth_option_that_contradicts_the_spectrum_file_is_warned(
    capture: Capture, tmp_path: Path
) -> None:
    """--bandwidth replaced the file's '# bandwidth_nm:' without a word (the σ and the slit
    model then use the option's); the contradiction is now said, for that lamp only."""
    argv = _profile_args(tmp_path, capture, direct=True)
    for lamp in ("LED", "FL"):
        spectrum = tmp_path / f"{lamp}.csv"
        spectrum.write_text("# bandwidth_nm: 8\n" + spectrum.read_text())
    second_lamp = argv.index("--lamp", 1)
    argv[second_lamp:second_lamp] = ["--bandwidth", "2"]
    argv += ["--bandwidth", "8", "--out", str(tmp_path / "out"), "--json", "--no-report"]
    code, stdout, stderr = _call(argv)
    assert code == 0, stderr
    said = [line for line in json.loads(stdout)["warnings"] if "--bandwidth" in line]
    assert said == [
        "lamp 'LED': --bandwidth 2 nm overrides its spectrum file's '# bandwidth_nm: 8'; the "
        "--bandwidth is used (drop it to use the file's)"
    ]
    assert f"calib: warning: {said[0]}" in stderr


@pytest.mark.parametrize("where", ["option", "header"])
def test_a_bandwidth_no_spectrometer_has_is_an_input_error_naming_it(
    capture: Capture, tmp_path: Path, where: str
) -> None:
    """--bandwidth 500 (or a file's '# bandwidth_nm: 500') ran the estimate into a mapping
    failure; it is now refused up front, naming the option or the file and the range."""
    argv = _profile_args(tmp_path, capture, direct=True)
    if where == "option":
        argv += ["--bandwidth", "500"]
        source = "lamp 'FL': --bandwidth 500 (or an --inputs file's bandwidth_nm)"
    else:
        spectrum = tmp_path / "FL.csv"
        spectrum.write_text("# bandwidth_nm: 500\n" + spectrum.read_text())
        source = f"{spectrum}: '# bandwidth_nm: 500'"
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--no-report"])
    assert code == 2
    assert stderr == (
        f"calib: error: {source} is not a spectrometer's bandwidth (the FWHM of its slit "
        "function, nm): give one above 0 and at most 50 nm (an i1Pro's is 25 nm, a PR-655's "
        "8 nm)\n"
    )
    assert not (tmp_path / "out").exists()


def test_the_mapping_lamp_is_matched_ignoring_case(
    capture: Capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--mapping-lamp fl was refused when the lamp is FL; it is now that lamp (the estimate is
    stopped where it receives it)."""
    received: dict[str, object] = {}

    def stop(observations: object, method: str, **where: object) -> None:
        received.update(where)
        raise EstimationError("stopped by the test")

    monkeypatch.setattr("calib.pipeline.estimate.estimate", stop)
    argv = [*_profile_args(tmp_path, capture, direct=True), "--mapping-lamp", "fl"]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--no-report"])
    assert "stopped by the test" in stderr and code != 0
    assert received["mapping_lamp"] == "fl"
    # and an estimator, given the name as typed, picks that lamp for its mapping
    spectrum = colour_lamps()["FL"][1]
    observations = [
        LampObservation(name, spectrum, np.arange(4.0), np.ones((4, 3))) for name in ("LED", "FL")
    ]
    assert [obs.name for obs in lamps_named(observations, "fl")] == ["FL"]


def test_a_mapping_lamp_naming_no_lamp_lists_those_it_can_be(
    capture: Capture, tmp_path: Path
) -> None:
    argv = [*_profile_args(tmp_path, capture, direct=True), "--mapping-lamp", "halogen"]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--no-report"])
    assert code == 2
    assert stderr == (
        "calib: error: --mapping-lamp: no lamp named 'halogen' (ignoring case); it can be one "
        "of LED, FL\n"
    )


def test_a_blank_profile_that_fails_the_estimate_is_an_input_error_saying_so(
    capture: Capture, tmp_path: Path
) -> None:
    """A lamp whose profile is noise only (the lamp was off) ended in exit 1 'the best mapping
    puts the profile at 340–651 nm …': the estimate's failure, not its cause. The inputs'
    serious finding is now the one-line error, exit 2."""
    argv = _profile_args(tmp_path, capture, direct=True)
    profile = tmp_path / "FL-profile.csv"
    table = np.loadtxt(profile, delimiter=",", skiprows=1)
    table[:, 1:4] = np.random.default_rng(1).normal(size=(table.shape[0], 3)) * table[:, 4:7]
    np.savetxt(
        profile, table, delimiter=",", header="pixel,r,g,b,r_sigma,g_sigma,b_sigma", comments=""
    )
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--no-report"])
    assert code == 2, stderr
    assert stderr.startswith("calib: error: no first-order signal above the noise for FL ("), stderr
    assert "(the estimate then failed: " in stderr and stderr.count("\n") == 1, stderr


def test_profile_input_without_direct_or_grating_assumes_flat_and_warns(
    capture: Capture, tmp_path: Path
) -> None:
    argv = [*_profile_args(tmp_path, capture, direct=False), "--out", str(tmp_path / "out")]
    code, stdout, stderr = _call(argv)
    assert code == 0
    assert "warning: no direct measurement and no grating file: a flat grating" in (
        " ".join(stderr.split())
    )
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert any("flat grating" in w for w in document["provenance"]["warnings"])
    assert document["grating_efficiency"] == [1.0] * 31
    codes = {flag["code"] for flag in document["quality"]["flags"]}
    assert "flat_grating_assumed" in codes and "grating_assumed" not in codes
    page = (tmp_path / "out" / "report.html").read_text()
    assert "flat grating" in page
    assert "estimate: known-grating" in stdout


def test_assume_grating_physical_marginalises_the_families_and_is_named_where_it_does_nothing(
    capture: Capture, tmp_path: Path
) -> None:
    """``--assume-grating physical`` (decision 0074's option): η₁ over the physical families,
    flagged, saved as an assumed grating; with a direct measurement it has no effect and says so;
    anything else is refused in one line."""
    out = tmp_path / "physical"
    argv = [*_profile_args(tmp_path, capture, direct=False), "--out", str(out)]
    code, _, stderr = _call([*argv, "--assume-grating", "physical"])
    assert code == 0, stderr
    document = json.loads((out / "result.json").read_text())
    codes = {flag["code"] for flag in document["quality"]["flags"]}
    assert "grating_assumed" in codes and "flat_grating_assumed" not in codes
    assert document["grating_efficiency"] != [1.0] * 31
    assert json.loads((out / "grating.json").read_text())["obtained"] == "assumed physical"
    direct = [*_profile_args(tmp_path, capture, direct=True), "--out", str(tmp_path / "direct")]
    code, _, stderr = _call([*direct, "--assume-grating", "physical"])
    assert code == 0 and "--assume-grating has no effect: a direct measurement" in stderr
    code, _, stderr = _call([*argv, "--assume-grating", "sinusoidal", "--force"])
    assert code == 2 and stderr.count("\n") == 1 and "--assume-grating" in stderr, stderr


def _as_rawproc_dat(csv_path: Path, operations: str = "") -> Path:
    """The CSV profile written as rawproc's text export (columns 0 … width−1, no σ), unmirrored;
    ``operations`` are put in its command after the demosaic."""
    table = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    width = table.shape[0]
    rows = [
        f"width: {width}",
        "height: 9",
        f"rawproc-0.9.1Dev lamp.NEF:rawdata=crop;  demosaic:half {operations} crop:0,0.4,1,0.5 ",
        "x," + ",".join(str(k) for k in range(width)),
        *(
            f"{name}," + ",".join(f"{v:.8g}" for v in table[:, 1 + index])
            for index, name in enumerate(("red", "green", "blue"))
        ),
    ]
    path = csv_path.with_suffix(".dat")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_profile_input_as_rawproc_export(capture: Capture, tmp_path: Path) -> None:
    argv = _profile_args(tmp_path, capture, direct=True)
    argv = [
        str(_as_rawproc_dat(Path(value))) if value.endswith("-profile.csv") else value
        for value in argv
    ]
    assert sum(value.endswith(".dat") for value in argv) == 2
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json", "--no-report"])
    assert code == 0, stderr
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    estimated = np.column_stack([document["sensitivity"][c] for c in "RGB"])
    assert relative_error(estimated, capture.truth) < 0.05
    # The provenance shows the rawproc command's operations as read.
    for lamp in document["provenance"]["lamps"]:
        operations = lamp["profile_metadata"]["rawproc"]["operations"]
        assert [op["name"] for op in operations] == ["demosaic", "crop"], lamp
        assert lamp["channel_gains"] == "raw"


def test_a_rawproc_export_made_non_linear_is_one_line_exit_2(
    capture: Capture, tmp_path: Path
) -> None:
    """A gamma in the rawproc command: the data are not the camera's linear channels, refused
    before anything is estimated, naming the file and the operation."""
    argv = _profile_args(tmp_path, capture, direct=True)
    argv = [
        str(_as_rawproc_dat(Path(value), "gamma:2.2" if "FL" in value else ""))
        if value.endswith("-profile.csv")
        else value
        for value in argv
    ]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--no-report"])
    assert code == 2 and stderr.count("\n") == 1, stderr
    assert (
        "FL-profile.dat: the rawproc command applies gamma:2.2, which makes the profile " in stderr
    )
    assert "export the data again without it" in stderr
    assert not (tmp_path / "out").exists()


def test_profile_in_wavelength_uses_the_identity_mapping(capture: Capture, tmp_path: Path) -> None:
    argv = _profile_args(tmp_path, capture, direct=True, axis="wavelength_nm")
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json", "--no-report"])
    assert code == 0, stderr
    mapping = json.loads(stdout)["mapping"]
    assert (mapping["a"], mapping["b"], mapping["c"]) == (0.0, 1.0, 0.0)
    values = read_camera_csv(tmp_path / "out" / "sensitivity.csv").values
    assert relative_error(values, capture.truth) < 0.05


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("1,2,3,4\n" * 10, "needs a header"),
        ("pos,r,g,b\n" + "1,2,3,4\n" * 10, "expected 'pixel' or 'wavelength_nm'"),
        ("pixel,r,g\n" + "1,2,3\n" * 10, "missing column"),
        ("pixel,r,g,b,r_sigma\n" + "1,2,3,4,1\n" * 10, "all three channels"),
        ("pixel,r,g,b\n" + "".join(f"{i},1,nan,1\n" for i in range(10)), "not a finite number"),
        ("pixel,r,g,b\n" + "1,1,1,1\n" * 10, "appears twice"),
        ("pixel,r,g,b\n1,1,1,1\n2,1,1,1\n", "at least 8"),
        ("pixel,r,g,b,w\n" + "".join(f"{i},1,1,1,1\n" for i in range(10)), "unknown column"),
        ("pixel,r,g,b\n" + "".join(f"{i},0,0,0\n" for i in range(10)), "holds no light"),
    ],
)
def test_bad_profile_csv_exits_2(tmp_path: Path, content: str, message: str) -> None:
    profile = tmp_path / "profile.csv"
    profile.write_text(content)
    spectrum = write_csv(tmp_path / "lamp.csv", colour_lamps()["LED"][1])
    argv = ["--lamp", "A", "--profile", str(profile), "--spectrum", str(spectrum)]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out")])
    assert code == 2 and message in stderr and "profile.csv" in stderr, stderr


def test_images_and_profiles_do_not_mix(capture: Capture, tmp_path: Path) -> None:
    profile, _ = _write_profile(tmp_path / "p.csv", capture, "FL")
    spectrum = write_csv(tmp_path / "fl.csv", colour_lamps()["FL"][1])
    lamp = capture.lamps[0]
    argv = [
        "--lamp",
        "LED",
        "--images",
        *map(str, lamp.frames),
        "--spectrum",
        str(lamp.spectrum_csv),
    ]
    argv += ["--lamp", "FL", "--profile", str(profile), "--spectrum", str(spectrum)]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "out")])
    assert code == 2 and "every lamp as RAW images or every lamp as a profile" in stderr


def test_the_prior_weight_rule_is_chosen_on_the_command_line(
    capture: Capture, tmp_path: Path
) -> None:
    argv = [*_profile_args(tmp_path, capture, direct=True), "--method", "multilamp", "--no-report"]
    code, _, stderr = _call([*argv, "--weight-rule", "typicality", "--out", str(tmp_path / "t")])
    assert code == 0, stderr
    diagnostics = json.loads((tmp_path / "t" / "result.json").read_text())["diagnostics"]
    assert diagnostics["prior_weight_rule"] == "typicality"
    code, _, stderr = _call([*argv, "--weight-rule", "evidence", "--out", str(tmp_path / "e")])
    assert code == 0, stderr
    diagnostics = json.loads((tmp_path / "e" / "result.json").read_text())["diagnostics"]
    assert diagnostics["prior_weight_rule"] == "evidence"
    code, _, stderr = _call([*argv, "--weight-rule", "guess", "--out", str(tmp_path / "g")])
    assert code == 2 and "--weight-rule" in stderr and "typicality" in stderr
    argv = [*_profile_args(tmp_path, capture, direct=True), "--weight-rule", "upre"]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "m")])
    assert code == 2 and "applies to --method multilamp only" in stderr


def test_multilamp_writes_a_grating_file_that_a_later_estimate_reuses(
    capture: Capture, tmp_path: Path
) -> None:
    first = tmp_path / "first"
    argv = [*_profile_args(tmp_path, capture, direct=True), "--method", "multilamp", "--no-report"]
    code, stdout, stderr = _call([*argv, "--out", str(first), "--json"])
    assert code == 0, stderr
    assert json.loads(stdout)["method"] == "multilamp"
    document = json.loads((first / "result.json").read_text())
    assert document["sensitivity_sigma"] is not None
    assert document["diagnostics"]["prior_weight_rule"] == "UPRE"
    grating = read_grating_file(first / "grating.json")
    assert grating.efficiency_sigma is not None
    # The next camera (here: the same one) from profiles alone, through the saved grating.
    second = tmp_path / "second"
    argv = [*_profile_args(tmp_path, capture, direct=False), "--method", "multilamp"]
    argv += ["--grating", str(first / "grating.json"), "--no-report"]
    code, stdout, stderr = _call([*argv, "--out", str(second), "--json"])
    assert code == 0, stderr
    assert json.loads(stdout)["method"] == "known-grating"  # s = q̂ / η through the file
    values = read_camera_csv(second / "sensitivity.csv").values
    assert relative_error(values, capture.truth) < 0.05
    assert "weight-rule" not in stderr
    # η is known: a rule for the prior's weight in the η solve has nothing to choose, and says so.
    argv += ["--weight-rule", "typicality", "--out", str(tmp_path / "third")]
    code, _, stderr = _call(argv)
    assert code == 0, stderr
    assert "--weight-rule has no effect with a grating file" in stderr


# ------------------------------------------------------------------------ input limits and frames


@pytest.mark.parametrize(
    ("grid", "says"),
    [
        ("400:700:1e-6", "300,000,001 wavelengths; at most 1001"),
        ("400:700:0.01", "30,001 wavelengths; at most 1001"),
        ("400:700:0.1", "3,001 wavelengths; at most 1001"),
        ("400:700:1e-320", "no countable number of steps"),
        ("400:1e309:1", "must be finite"),
    ],
)
def test_a_grid_too_fine_is_refused_before_any_work(
    capture: Capture, tmp_path: Path, grid: str, says: str
) -> None:
    code, _, stderr = _call([*_image_args(capture), "--out", str(tmp_path / "o"), "--grid", grid])
    assert code == 2 and stderr.count("\n") == 1 and says in stderr, stderr


@pytest.mark.parametrize(
    ("value", "says"), [("1e308", "values reach 1e+308"), ("1e-320", "values reach 9.99989e-321")]
)
def test_a_spectrum_of_extreme_values_is_an_input_error(
    capture: Capture, tmp_path: Path, value: str, says: str
) -> None:
    spectrum = tmp_path / "extreme.csv"
    rows = "".join(f"{nm},{value}\n" for nm in range(380, 781, 5))
    spectrum.write_text("wavelength_nm,value\n" + rows)
    lamp = capture.lamps[0]
    argv = ["--lamp", lamp.name, "--images", *map(str, lamp.frames), "--spectrum", str(spectrum)]
    code, _, stderr = _call([*argv, "--out", str(tmp_path / "o")])
    assert code == 2 and stderr.count("\n") == 1, stderr
    assert "extreme.csv" in stderr and says in stderr


def test_an_oversized_spectrum_file_is_refused_unread(tmp_path: Path) -> None:
    from calib.core.spectra import MAX_TABLE_BYTES, MAX_TABLE_ROWS, read_spectrum_csv

    big = tmp_path / "big.csv"
    with big.open("wb") as stream:
        stream.truncate(MAX_TABLE_BYTES + 1)
    with pytest.raises(InputError, match="more than 32 MiB"):
        read_spectrum_csv(big)
    many = tmp_path / "many.csv"
    many.write_text("".join(f"{400 + k * 1e-3:.3f},1\n" for k in range(MAX_TABLE_ROWS + 1)))
    with pytest.raises(InputError, match=f"{MAX_TABLE_ROWS + 1} data rows; at most"):
        read_spectrum_csv(many)


def test_the_same_frame_twice_in_a_bracket_is_refused(capture: Capture, tmp_path: Path) -> None:
    lamp = capture.lamps[0]
    copy = tmp_path / "copy.dng"
    copy.write_bytes(lamp.frames[1].read_bytes())
    for twice in ([lamp.frames[1], lamp.frames[1]], [lamp.frames[1], copy]):
        argv = ["--lamp", lamp.name, "--images", *map(str, [lamp.frames[0], *twice])]
        argv += ["--spectrum", str(lamp.spectrum_csv), "--out", str(tmp_path / "o")]
        code, _, stderr = _call(argv)
        assert code == 2 and stderr.count("\n") == 1, stderr
        assert f"{twice[0]} and {twice[1]} are the same frame" in stderr


def test_a_blank_frame_in_a_bracket_is_refused_naming_it(capture: Capture, tmp_path: Path) -> None:
    import rawpy

    from calib.image.raw import read_raw_metadata
    from mocks.dng import DngMetadata, write_dng

    lamp = capture.lamps[0]
    metadata = read_raw_metadata(lamp.frames[0])
    with rawpy.imread(str(lamp.frames[0])) as raw:
        shape = raw.raw_image_visible.shape
        black = int(raw.black_level_per_channel[0])
    blank = tmp_path / "blank.dng"
    write_dng(
        blank,
        np.full(shape, black, dtype=np.uint16),
        DngMetadata(
            exposure_s=0.001,
            iso=int(metadata.iso) if metadata.iso else 100,
            f_number=metadata.f_number,
            model=metadata.camera.split(" ", 1)[-1],
            black_level_dn=black,
        ),
    )
    argv = ["--lamp", lamp.name, "--images", *map(str, [*lamp.frames, blank])]
    argv += ["--spectrum", str(lamp.spectrum_csv), "--out", str(tmp_path / "o")]
    code, _, stderr = _call(argv)
    assert code == 2 and stderr.count("\n") == 1, stderr
    assert "blank.dng" in stderr and "the frame is blank" in stderr


def test_exclude_camera_keeps_the_camera_out_of_the_default_basis(
    capture: Capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.undo()  # the real default basis: no data anywhere, so the bundled rawtoaces-data
    monkeypatch.delenv("SPECTRAL_RIG_DATA", raising=False)
    monkeypatch.setattr("calib.core.datasets.default_data_dir", lambda: tmp_path / "no-user-cache")
    argv = [*_profile_args(tmp_path, capture, direct=True), "--out", str(tmp_path / "out")]
    argv += [
        "--exclude-camera",
        "Nikon D5100",
        "--exclude-camera",
        "sony*",
        "--exclude-camera",
        "Nikon D5010",
        "--json",
        "--no-report",
    ]
    code, stdout, stderr = _call(argv)
    assert code == 0, stderr
    basis = json.loads(stdout)["basis"]
    assert basis["exclusions"] == ["Nikon D5100", "sony*", "Nikon D5010"]
    # a pattern naming no camera (a misspelt camera under test) is said, not silently kept in
    assert basis["unmatched_exclusions"] == ["Nikon D5010"]
    assert (
        "calib: warning: --exclude-camera 'Nikon D5010' names none of the 52 cameras the basis "
        "draws on and kept nothing out" in stderr
    )
    assert "'sony*' names none" not in stderr and "'Nikon D5100' names none" not in stderr
    assert "Nikon D5100 (rawtoaces-data)" in basis["excluded_cameras"]
    assert len(basis["excluded_cameras"]) == 12 and basis["n_cameras"] == 52 - 12
    assert not any("D5100" in name or name.startswith("Sony") for name in basis["cameras"])
    # the bundled basis is not the validated one: said on stderr and in the result
    assert "calib: warning: the camera basis comes from the 52 rawtoaces-data cameras" in stderr
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert any("rawtoaces-data" in w for w in document["provenance"]["warnings"])


def test_a_spectrum_in_photons_is_converted_to_power_and_raw_counts_are_serious(
    capture: Capture, tmp_path: Path
) -> None:
    """A spectrum's '# units:' was read and dropped: one in photons per nm gave the per-photon
    sensitivity (tilted by λ across the grid) and raw spectrometer counts went into the solve
    without a word. Photons are now converted to power; counts are a serious flag."""
    runs = {}
    for label, header in (
        ("power", None),
        ("photons", "# units: photons/s/nm"),
        ("photons unsaid", ""),
        ("counts", "# units: counts/ms (uncalibrated)"),
    ):
        folder = tmp_path / label.replace(" ", "-")
        folder.mkdir()
        argv = _profile_args(folder, capture, direct=True)
        if header is not None:
            spectrum = folder / "LED.csv"
            table = np.loadtxt(spectrum, delimiter=",", skiprows=1)
            if "photons" in label:
                table[:, 1] *= table[:, 0] / 555.0  # the same light, counted in photons
            lines = [header] if header else []
            lines.append("wavelength_nm,value")
            lines += [f"{w:.10g},{v:.10g}" for w, v in table]
            spectrum.write_text("\n".join(lines) + "\n")
        code, stdout, stderr = _call([*argv, "--out", str(folder / "out"), "--json", "--no-report"])
        assert code == 0, stderr
        runs[label] = (
            json.loads(stdout),
            stderr,
            read_camera_csv(folder / "out" / "sensitivity.csv").values,
        )
    power, photons, unsaid = (runs[k][2] for k in ("power", "photons", "photons unsaid"))
    assert relative_error(photons, power) < 1e-6
    assert relative_error(unsaid, power) > 5 * relative_error(power, capture.truth)
    assert (
        "lamp 'LED': its spectrum is in 'photons/s/nm' (photons): converted" in runs["photons"][1]
    )
    converted = [line for line in runs["photons"][0]["warnings"] if "converted" in line]
    assert _flag_codes(runs["photons"][0]) == EXPECTED_FLAGS | set(converted)
    recorded = json.loads((tmp_path / "photons" / "out" / "result.json").read_text())
    led = next(lamp for lamp in recorded["provenance"]["lamps"] if lamp["name"] == "LED")
    assert led["spectrum_units"] == {"units": "photons/s/nm", "measures": "photon"}
    counts_summary, counts_stderr, _ = runs["counts"]
    assert _flag_codes(counts_summary) == EXPECTED_FLAGS | {"lamp_spectrum_uncalibrated"}
    assert (
        "SERIOUS: the spectrum of lamp 'LED' (counts/ms (uncalibrated)) is in a spectrometer's raw counts"
        in counts_stderr
    )
