"""calib.use and its commands: IDT, colour correction and ΔE2000, raw-to-raw, the dcamprof route."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.core.camera_curves import CameraCurves, as_camera
from calib.core.formats.dcamprof import write_ssf_json
from calib.core.spectra import WavelengthGrid
from calib.use import camera_for_uses, camera_uses
from calib.use.colour_correction import compare_with_truth, fit_colour_correction
from calib.use.dcamprof import DcamprofError, find_dcamprof, make_profiles
from calib.use.idt import aces_idt
from calib.use.raw_to_raw import raw_to_raw
from tests import fake_dcamprof
from tests.test_cli_spd import run_cli


@pytest.fixture(scope="module")
def nikon() -> CameraCurves:
    import colour

    return as_camera(colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]).normalised()


def _distorted(camera: CameraCurves, shift_nm: float) -> CameraCurves:
    """The camera with its curves shifted along the wavelength axis."""
    return CameraCurves(
        camera.wavelength_nm, camera.at(camera.wavelength_nm - shift_nm), name="shifted"
    )


@pytest.mark.parametrize(
    ("camera", "atol"),
    # colour's default steps on finite differences; the Foveon's matrix is the harder optimum
    [("Nikon 5100 (NPL)", 1e-6), ("Sigma SDMerill (NPL)", 2e-5)],
)
@pytest.mark.parametrize("illuminant", ["D55", "D65", "A"])
def test_the_idt_is_colours_matrix_idt(camera: str, atol: float, illuminant: str) -> None:
    """The exact-gradient objective lands where colour's default optimisation does."""
    import colour

    from calib.core.colour_data import use_illuminant as illuminant_spd

    curves = as_camera(colour.MSDS_CAMERA_SENSITIVITIES[camera]).normalised()
    grid = WavelengthGrid(380.0, 780.0, 5.0)
    curves = CameraCurves(grid.wavelength_nm, curves.at(grid.wavelength_nm), name=camera)
    spd = illuminant_spd(illuminant).resample(grid)
    expected, white = colour.matrix_idt(
        curves.to_colour(), colour.SpectralDistribution(spd.values, spd.wavelength_nm)
    )
    idt = aces_idt(curves, illuminant)
    np.testing.assert_allclose(idt.matrix, expected, atol=atol)
    np.testing.assert_allclose(idt.white_balance, white, rtol=1e-9)
    assert min(idt.white_balance) == pytest.approx(1.0)


def test_the_idt_objectives_gradient_is_its_derivative() -> None:
    """The objective handed to colour.matrix_idt is colour's rawtoaces v1 objective, and its gradient
    is the objective's derivative (finite differences), on both branches of CIELAB's f."""
    import colour
    from scipy.optimize import approx_fprime

    from calib.core.colour_data import _rawtoaces_v1_with_gradient

    x_0, objective, to_lab, finaliser = _rawtoaces_v1_with_gradient()
    _, colours_objective, colours_lab, colours_finaliser = (
        colour.characterisation.optimisation_factory_rawtoaces_v1()
    )
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0.0, 1.0, (190, 3)) ** 3  # dark samples too: the linear branch of f
    xyz = rng.uniform(0.0, 1.0, (190, 3)) ** 3
    np.testing.assert_allclose(to_lab(xyz), colours_lab(xyz), atol=1e-9)
    lab = to_lab(xyz)
    for m in (x_0, np.array([0.9, 0.2, -0.1, 1.1, 0.05, -0.03])):
        np.testing.assert_allclose(finaliser(m), colours_finaliser(m.copy()), atol=1e-15)
        value, gradient = objective(m, rgb, lab)
        assert value == pytest.approx(colours_objective(m, rgb, lab), rel=1e-12)
        numeric = approx_fprime(m, lambda v: objective(v, rgb, lab)[0], 1e-7)
        np.testing.assert_allclose(gradient, numeric, rtol=1e-4, atol=1e-4)


def test_the_colour_correction_keeps_white_and_predicts_the_colorchecker(
    nikon: CameraCurves,
) -> None:
    for name in ("D50", "D65", "A"):
        correction = fit_colour_correction(nikon, name)
        from calib.use.colour_correction import _scene

        np.testing.assert_allclose(
            correction.matrix @ np.ones(3), _scene(name).white_xyz, rtol=1e-9
        )
        assert len(correction.delta_e.values) == 24
        # a good DSLR: ΔE2000 about 1 on average with a 3×3 matrix, worst patch a few units
        assert 0.3 < correction.delta_e.mean < 2.0 and correction.delta_e.max < 5.0


def test_the_truth_comparison_is_zero_for_the_truth_and_grows_with_the_error(
    nikon: CameraCurves,
) -> None:
    assert compare_with_truth(nikon, nikon, "D65").estimate_vs_truth.max < 1e-6
    errors = [
        compare_with_truth(_distorted(nikon, shift), nikon, "A").estimate_vs_truth.mean
        for shift in (2.0, 6.0, 12.0)
    ]
    assert 0 < errors[0] < errors[1] < errors[2]


def test_camera_uses_cover_the_report_illuminants(nikon: CameraCurves) -> None:
    uses = camera_uses(nikon, truth=_distorted(nikon, 3.0))
    record = uses.to_dict()
    assert set(record["aces_idt"]) == {"D55", "D65", "A"}
    assert set(record["colour_correction"]) == {"D50", "D55", "D65", "A"}
    assert set(record["against_truth"]) == {"D65", "A"}
    json.dumps(record, allow_nan=False)


def test_raw_to_raw_between_two_cameras(nikon: CameraCurves) -> None:
    import colour

    same = raw_to_raw(nikon, nikon)
    np.testing.assert_allclose(same.matrix, np.eye(3), atol=1e-9)
    sigma = colour.MSDS_CAMERA_SENSITIVITIES["Sigma SDMerill (NPL)"]
    other = raw_to_raw(nikon, sigma)
    assert other.n_reflectances == 190
    assert other.relative_residual_median > same.relative_residual_median
    # the matrix reproduces the target's RGB of the perfect white (both at G = 1) closely
    assert other.relative_residual_median < 0.2


def test_an_estimate_on_400_700_is_extended_before_use(nikon: CameraCurves) -> None:
    wavelength = np.arange(400.0, 701.0, 10.0)
    curves, origin = camera_for_uses(CameraCurves(wavelength, nikon.at(wavelength)))
    assert curves.range_nm == (380.0, 780.0) and "extended" in origin


# --------------------------------------------------------------------------------- dcamprof


@pytest.fixture
def fake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    bin_dir = tmp_path / "bin"
    fake_dcamprof.install(bin_dir)
    monkeypatch.setenv("PATH", f"{bin_dir}:/usr/bin:/bin")
    monkeypatch.setenv("FAKE_DCAMPROF_LOG", str(tmp_path / "calls.jsonl"))
    return tmp_path / "calls.jsonl"


def test_the_dcamprof_route_runs_the_documented_steps(
    nikon: CameraCurves, fake: Path, tmp_path: Path
) -> None:
    program = find_dcamprof()
    assert program is not None and program.name == "dcamprof"
    ssf = write_ssf_json(tmp_path / "ssf.json", nikon, "Nikon D5100")
    made = make_profiles(ssf, "Nikon D5100", tmp_path / "out", executable=program)
    assert made.dcp.read_bytes()[:4] == b"IIRC"
    assert made.icc.read_bytes()[36:40] == b"acsp"
    calls = [json.loads(line) for line in fake.read_text().splitlines()]
    assert [call[0] for call in calls] == [
        "make-target",
        "make-profile",
        "make-profile",
        "make-dcp",
        "make-icc",
    ]
    assert (
        calls[1][calls[1].index("-i") + 1] == "StdA" and calls[2][calls[2].index("-i") + 1] == "D65"
    )
    dcp = calls[3]
    assert dcp[dcp.index("-n") + 1] == "Nikon D5100"
    assert dcp[-3].endswith("profile-StdA.json") and dcp[-2].endswith("profile-D65.json")


def test_a_dcamprof_failure_names_the_step_and_its_message(fake: Path, tmp_path: Path) -> None:
    bad = tmp_path / "ssf.json"
    bad.write_text(json.dumps({"camera_name": "x", "ssf_bands": [380, 780, 7]}))
    program = find_dcamprof()
    assert program is not None
    with pytest.raises(DcamprofError, match=r"make-target failed \(exit 1\): Error: ssf_bands"):
        make_profiles(bad, "x", tmp_path / "out", executable=program)


def test_dcamprof_absent_is_skipped_cleanly(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    assert find_dcamprof() is None


# ------------------------------------------------------------------------------- commands


def test_the_commands_read_any_camera_file(
    nikon: CameraCurves,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    fake: Path,
) -> None:
    from calib.core.formats.rgb_csv import write_camera_csv

    camera = write_camera_csv(tmp_path / "nikon.csv", nikon)
    code, out, err = run_cli(
        ["idt", str(camera), "--illuminant", "A", "--json"], monkeypatch, capsys
    )
    assert code == 0, err
    record = json.loads(out)
    np.testing.assert_allclose(
        record["matrix_camera_rgb_to_aces2065_1"], aces_idt(nikon, "A").matrix
    )
    code, out, err = run_cli(["ccm", str(camera)], monkeypatch, capsys)
    assert code == 0 and "ColorChecker ΔE2000: mean" in out
    code, out, err = run_cli(["raw-to-raw", str(camera), str(camera)], monkeypatch, capsys)
    assert code == 0 and "median 0.00 %" in out
    code, out, err = run_cli(["idt", str(camera), "--illuminant", "F11"], monkeypatch, capsys)
    assert code == 2 and "unknown illuminant 'F11'" in err and err.count("\n") == 1
    code, out, err = run_cli(["profile", str(camera)], monkeypatch, capsys)
    assert code == 2 and "--name" in err
    arguments = ["profile", str(camera), "--out", str(tmp_path / "p"), "--name", "Nikon D5100"]
    code, out, err = run_cli(arguments, monkeypatch, capsys)
    assert code == 0, err
    assert (tmp_path / "p" / "Nikon D5100.dcp").read_bytes()[:4] == b"IIRC"
    assert f"DCP: {tmp_path / 'p' / 'Nikon D5100.dcp'}" in out
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    code, out, err = run_cli(arguments, monkeypatch, capsys)
    assert code == 2 and "dcamprof is not installed" in err


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("zero blue", "channel B has no positive value"),
        ("every sign flipped", "channel R has no positive value"),
        ("in micrometres", "wavelengths run from 0.38 to 0.78, outside 100–3000 nm"),
    ],
)
def test_a_camera_file_that_cannot_be_a_camera_is_refused_naming_it(
    nikon: CameraCurves,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    change: str,
    message: str,
) -> None:
    """A dead or sign-flipped channel gave an identity IDT (or the same matrix as the real
    camera) and exit 0; wavelengths in µm said 'the estimate covers 0.4–0.7 nm'. Now one line
    names the file and what is wrong, exit 2."""
    from calib.core.formats.rgb_csv import write_camera_csv

    values, wavelength = np.array(nikon.values), np.array(nikon.wavelength_nm)
    if change == "zero blue":
        values[:, 2] = 0.0
    elif change == "every sign flipped":
        values = -values
    else:
        wavelength = wavelength / 1000.0
    camera = write_camera_csv(
        tmp_path / "camera.csv", CameraCurves(wavelength, values, name="broken")
    )
    for command in ("idt", "ccm"):
        code, out, err = run_cli([command, str(camera)], monkeypatch, capsys)
        assert code == 2 and out == "", (out, err)
        assert f"camera.csv: {message}" in err and err.count("\n") == 1, err
