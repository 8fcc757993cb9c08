"""``calib estimate``: argument groups, exit codes, --json/--quiet, images and profile-level input."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib.cli.estimate import run
from calib.cli.estimate_args import parse_estimate_arguments
from calib.core.errors import EstimationError, InputError
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.grating_file import GratingEfficiency, read_grating_file, write_grating_file
from calib.core.metrics import relative_error
from calib.core.spectra import write_csv
from calib.model.forward import PeakFractionNoise, render_observation
from calib.pipeline import LampImages, LampProfile
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
    out, err = io.StringIO(), io.StringIO()
    code = run(argv, stdout=out, stderr=err)
    return code, out.getvalue(), err.getvalue()


def _image_args(capture: Capture) -> list[str]:
    argv: list[str] = []
    for lamp in capture.lamps:
        argv += ["--lamp", lamp.name, "--kind", lamp.kind, "--images", *map(str, lamp.frames)]
        argv += ["--spectrum", str(lamp.spectrum_csv)]
    return argv


# ---------------------------------------------------------------------------------- the parser


def test_lamp_groups_collect_their_own_options() -> None:
    arguments = parse_estimate_arguments(
        [
            "--out", "out", "--lamp", "A", "--images", "a1.dng", "a2.dng", "--dark", "d.dng",
            "--spectrum", "a.csv", "--kind", "LED", "--exposure", "0.01", "0.1",
            "--lamp", "B", "--kind=fluorescent", "--spectrum=b.csv", "--images", "b.dng",
            "--grid=400:700:5", "--mapping-lamp", "B", "--json",
        ]
    )  # fmt: skip
    first, second = arguments.lamps
    assert isinstance(first, LampImages) and isinstance(second, LampImages)
    assert first.images == (Path("a1.dng"), Path("a2.dng")) and first.darks == (Path("d.dng"),)
    assert first.kind == "led" and first.exposure_s == (0.01, 0.1)
    assert second.kind == "fluorescent" and second.spectrum == Path("b.csv")
    assert arguments.grid.step_nm == 5 and arguments.mapping_lamp == "B"
    assert arguments.json_output and not arguments.quiet


def test_profile_group() -> None:
    arguments = parse_estimate_arguments(
        [
            "--lamp",
            "P",
            "--profile",
            "p.csv",
            "--spectrum",
            "s.csv",
            "--direct",
            "1,2,3.5",
            "--out",
            "o",
        ]
    )
    (lamp,) = arguments.lamps
    assert isinstance(lamp, LampProfile) and lamp.direct_rgb == (1.0, 2.0, 3.5)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "o", "--images", "a.dng"], "--images before any --lamp"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--imgs", "x"], "did you mean --images"),
        (["--out", "o", "--lamp", "A", "--images", "a"], "--spectrum CSV is required"),
        (["--lamp", "A", "--images", "a", "--spectrum", "s"], "--out DIR is required"),
        (["--out", "o", "--lamp", "A", "--spectrum", "s"], "give either --images"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--profile", "p", "--spectrum", "s"], "not both"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--spectrum", "t"], "given twice"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--kind", "led", "x"], "one value, got 2"),
        (["--out", "o", "--lamp", "A", "--images", "--spectrum", "s"], "at least one value"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--kind", "laser"], "unknown lamp kind"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--exposure", "-1"], "must be > 0"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--grid", "700:400:10"], "--grid"),
        (["--out", "o", "--lamp", "A", "--images", "a", "--spectrum", "s", "--direct", "1,2,3"], "--direct goes with --profile"),
        (["--out", "o", "--lamp", "A", "--profile", "p", "--spectrum", "s", "--direct", "1,2"], "three numbers"),
        (["stray", "--out", "o"], "unexpected argument 'stray'"),
        (["--out", "o", "--quiet=yes", "--lamp", "A"], "takes no value"),
    ],
)  # fmt: skip
def test_parser_mistakes_are_named(argv: list[str], message: str) -> None:
    with pytest.raises(InputError, match=message):
        parse_estimate_arguments(argv)


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


def test_an_existing_result_needs_force(capture: Capture, tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    (out_dir / "result.json").write_text("{}")
    code, _, stderr = _call([*_image_args(capture), "--out", str(out_dir), "--quiet"])
    assert code == 2 and "--force" in stderr
    code, stdout, stderr = _call(
        [*_image_args(capture), "--out", str(out_dir), "--quiet", "--force"]
    )
    assert code == 0 and stdout == "", stderr
    assert json.loads((out_dir / "result.json").read_text())["method"] == "prior"


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
    assert code == 1 and "calib estimate: failed: the solve produced" in stderr


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
        done.stderr.strip().startswith("calib estimate: error:")
        and "none.dng: file not found" in done.stderr
    )
    assert done.stderr.count("\n") == 1
    help_text = subprocess.run(
        [str(script), "estimate", "--help"], capture_output=True, text=True, timeout=60, check=False
    )
    assert help_text.returncode == 0 and "--lamp NAME" in help_text.stdout


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


def test_profile_input_with_a_grating_file(capture: Capture, tmp_path: Path) -> None:
    wavelength = np.arange(380.0, 721.0, 2.0)
    grating = write_grating_file(
        tmp_path / "grating.json",
        GratingEfficiency(wavelength, efficiency(wavelength), provenance={"source": "truth"}),
    )
    argv = [*_profile_args(tmp_path, capture, direct=False), "--grating", str(grating)]
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json"])
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["method"] == "known-grating" and _flag_codes(summary) == EXPECTED_FLAGS
    assert summary["uncertainty"] is True
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    truth = capture.truth
    estimated = np.column_stack([document["sensitivity"][c] for c in "RGB"])
    sigma = np.column_stack([document["sensitivity_sigma"][c] for c in "RGB"])
    assert relative_error(estimated, truth) < 0.02
    # the per-wavelength uncertainty is honest: errors mostly within 3 σ
    assert np.mean(np.abs(estimated - truth) <= 3 * sigma + 1e-3) > 0.9
    assert not (tmp_path / "out" / "grating.json").exists()  # given, not estimated


def test_profile_input_without_direct_or_grating_assumes_flat_and_warns(
    capture: Capture, tmp_path: Path
) -> None:
    argv = [*_profile_args(tmp_path, capture, direct=False), "--out", str(tmp_path / "out")]
    code, stdout, stderr = _call(argv)
    assert code == 0
    assert "warning: no direct measurement and no --grating: a flat grating" in stderr
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert any("flat grating" in w for w in document["provenance"]["warnings"])
    assert document["grating_efficiency"] == [1.0] * 31
    page = (tmp_path / "out" / "report.html").read_text()
    assert "flat grating" in page
    assert "estimate: known-grating" in stdout


def test_profile_in_wavelength_uses_the_identity_mapping(capture: Capture, tmp_path: Path) -> None:
    argv = _profile_args(tmp_path, capture, direct=True, axis="wavelength_nm")
    code, stdout, stderr = _call([*argv, "--out", str(tmp_path / "out"), "--json"])
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
    argv = [*_profile_args(tmp_path, capture, direct=True), "--method", "multilamp"]
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
    argv = [*_profile_args(tmp_path, capture, direct=True), "--method", "multilamp"]
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
    argv += ["--grating", str(first / "grating.json")]
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
