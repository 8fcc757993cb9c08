"""``calib spd`` end to end on twin-rendered DNG brackets: outputs, exit codes, one-line reasons."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from calib.cli.app import main
from calib.core.checksums import file_sha256
from calib.core.lamp_specs import colour_lamp
from calib.core.software import current_software
from calib.core.spectra import WavelengthGrid, read_spectrum_csv, write_csv
from calib.spd.pipeline import mapping_lamp_spectrum
from tests.spd_scenes import CalibratedRig, calibrated_rig, render_twin_lamp


@dataclass(frozen=True)
class Scene:
    rig: CalibratedRig
    lamp: list[Path]

    @property
    def camera(self) -> Path:
        return self.rig.camera

    @property
    def fluorescent_spectrum(self) -> Path:
        return self.rig.mapping_spectrum


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Scene:
    root = tmp_path_factory.mktemp("spd-cli")
    rig = calibrated_rig(root, seed=21)
    return Scene(rig, render_twin_lamp(root / "led", colour_lamp("LED-B3"), seed=22))


def run_cli(
    arguments: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> tuple[int, str, str]:
    """Run ``calib`` as the console script does; return (exit code, stdout, stderr)."""
    monkeypatch.setattr("sys.argv", ["calib", *arguments])
    with pytest.raises(SystemExit) as exited:
        main()
    captured = capsys.readouterr()
    code = exited.value.code
    return (code if isinstance(code, int) else 1), captured.out, captured.err


def _paths(paths: list[Path]) -> list[str]:
    return [str(path) for path in paths]


def base_arguments(scene: Scene, out: Path) -> list[str]:
    return [
        "spd",
        "--images",
        *_paths(scene.lamp),
        "--camera",
        str(scene.camera),
        "--grating-efficiency",
        str(scene.rig.efficiency),
        "--out",
        str(out),
    ]


def with_mapping_lamp(scene: Scene, out: Path) -> list[str]:
    return [
        *base_arguments(scene, out),
        "--mapping-lamp-images",
        *_paths(list(scene.rig.mapping_frames)),
        "--mapping-lamp-spectrum",
        str(scene.fluorescent_spectrum),
    ]


def test_spd_writes_csv_json_and_plots(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "out"
    code, stdout, stderr = run_cli(
        [*with_mapping_lamp(scene, out), "--name", "desk LED", "--json"], monkeypatch, capsys
    )
    assert code == 0, stderr
    printed = json.loads(stdout)
    stored = json.loads((out / "spd.json").read_text())
    assert printed == stored
    assert stored["name"] == "desk LED"
    assert stored["recognition"]["name"] == "LED-B3"
    assert stored["recognition"]["instrument_view"] is True
    assert set(stored["cct"]["library match (paper)"]["cct_k"]) == {
        "McCamy 1992",
        "Hernandez 1999",
        "Robertson 1968",
        "Ohno 2013",
    }
    assert stored["cct"]["recovered (completed with the match)"]["cct_k"][
        "Ohno 2013"
    ] == pytest.approx(4102.5, abs=50.0)
    gains = stored["white_balance"]["camera_raw_gains"]["recovered"]
    assert gains[1] == 1.0 and len(gains) == 3
    assert len(stored["white_balance"]["srgb_gains_from_cct"]["gains"]) == 3
    assert stored["mapping"]["origin"] == "mapping lamp"
    assert stored["mapping"]["details"]["lines"] == "measured spectrum"
    assert stored["direct_check"]["angular_error_deg"] < 0.5
    assert [entry["sha256"] for entry in stored["inputs"]["images"]] == [
        file_sha256(path)[1] for path in scene.lamp
    ]
    assert stored["inputs"]["camera"]["path"] == str(scene.camera)
    assert stored["software"] == current_software().to_dict()  # as result.json's provenance
    spd = read_spectrum_csv(out / "spd.csv")
    assert spd.values.max() == pytest.approx(1.0, abs=0.02)
    assert np.all(np.diff(spd.wavelength_nm) == 1.0)
    lo, hi = stored["spd"]["recovered_range_nm"]
    assert lo <= spd.wavelength_nm[0] and spd.wavelength_nm[-1] <= hi
    for png in ("spd.png", "geometry.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "library match" in stderr and "LED-B3" in stderr


def test_a_known_mapping_and_a_grid_can_be_given(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    first = tmp_path / "first"
    code, _, stderr = run_cli(
        [*with_mapping_lamp(scene, first), "--quiet", "--no-plots"], monkeypatch, capsys
    )
    assert code == 0 and stderr == ""
    again = tmp_path / "again"
    arguments = [*base_arguments(scene, again), "--mapping", str(first / "spd.json")]
    code, _, stderr = run_cli(
        [*arguments, "--grid", "450:650:5", "--quiet", "--no-plots"], monkeypatch, capsys
    )
    assert code == 0, stderr
    stored = json.loads((again / "spd.json").read_text())
    assert stored["mapping"]["origin"].startswith("file")
    assert stored["spd"]["grid"] == str(WavelengthGrid(450, 650, 5))
    spd = read_spectrum_csv(again / "spd.csv")
    assert spd.wavelength_nm[0] == 450.0 and spd.wavelength_nm[-1] == 650.0
    assert not (again / "spd.png").exists()


def test_help_lists_the_options(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    code, stdout, _ = run_cli(["spd", "--help"], monkeypatch, capsys)
    assert code == 0
    for option in ("--images", "--camera", "--mapping-lamp-images", "--grating-efficiency"):
        assert option in stdout


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a, s: [x for x in a if x != "--camera" and x != str(s.camera)], "--camera"),
        (lambda a, s: [*a, "--frobnicate"], "No such option: --frobnicate"),
        (lambda a, s: [*a, "--source", "huge"], "'huge' is not one of 'point', 'finite', 'auto'"),
        (lambda a, s: [*a, "--grid", "700:400:10"], "stop (400.0 nm) must be greater"),
        (
            lambda a, s: [*a, "--smoothness", "-1"],
            "'--smoothness': Input should be greater than or equal to 0",
        ),
        (
            lambda a, s: [*a, "--mapping-lamp-spectrum", str(s.fluorescent_spectrum)],
            "needs that lamp's images",
        ),
        (
            lambda a, s: [*a, "--mapping", "m.json", "--mapping-lamp-images", str(s.lamp[0])],
            "either --mapping or --mapping-lamp-images",
        ),
        (lambda a, s: [*a, "--mapping", str(s.camera)], "not a readable JSON file"),
    ],
)
def test_bad_input_exits_2_with_one_line(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    change: object,
    message: str,
) -> None:
    arguments = change(base_arguments(scene, tmp_path / "out"), scene)  # type: ignore[operator]
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 2
    lines = [line for line in stderr.splitlines() if line.startswith("calib:")]
    assert len(lines) == 1 and message in lines[0], stderr


def test_the_mapping_lamp_spectrum_by_name_is_the_table_itself(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``--mapping-lamp-spectrum FL2`` (the scene's lamp is colour's FL2): the same recovery as
    its CSV, the name recorded instead of a file's hash (issue 16: names wherever a lamp spectrum
    is)."""
    results = {}
    for label, given in (("file", str(scene.fluorescent_spectrum)), ("name", "FL2")):
        arguments = with_mapping_lamp(scene, tmp_path / label)
        arguments[arguments.index("--mapping-lamp-spectrum") + 1] = given
        code, _, stderr = run_cli([*arguments, "--no-plots", "-q"], monkeypatch, capsys)
        assert code == 0, stderr
        results[label] = json.loads((tmp_path / label / "spd.json").read_text())
    assert results["name"]["inputs"]["mapping_spectrum"] == {"name": "FL2"}
    assert results["file"]["mapping"]["details"]["lines"] == "measured spectrum"
    assert results["name"]["mapping"]["details"]["lines"].startswith("named spectrum FL2 (")
    assert "sha256" in results["file"]["inputs"]["mapping_spectrum"]
    assert results["name"]["mapping"]["b"] == pytest.approx(results["file"]["mapping"]["b"], 1e-6)
    file_spd = read_spectrum_csv(tmp_path / "file" / "spd.csv").values
    name_spd = read_spectrum_csv(tmp_path / "name" / "spd.csv").values
    np.testing.assert_allclose(name_spd, file_spd, rtol=1e-3, atol=1e-3 * file_spd.max())


def test_bad_files_are_named(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    two_columns = tmp_path / "camera.csv"
    two_columns.write_text("wavelength_nm,r,g\n400,0.1,0.2\n500,0.5,0.9\n700,0.2,0.1\n")
    arguments = base_arguments(scene, tmp_path / "out")
    arguments[arguments.index("--camera") + 1] = str(two_columns)
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 2 and str(two_columns) in stderr and "no column for blue" in stderr
    dark = tmp_path / "dark_camera.csv"
    dark.write_text("wavelength_nm,r,g,b\n400,0,0,0\n700,0,0,0\n")
    arguments[arguments.index("--camera") + 1] = str(dark)
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 2 and "dark_camera.csv: channel R has no positive value" in stderr
    not_raw = tmp_path / "frame.dng"
    not_raw.write_text("not a raw file")
    arguments = base_arguments(scene, tmp_path / "out")
    arguments[arguments.index("--images") + 1] = str(not_raw)
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 2 and "frame.dng" in stderr


def test_a_camera_csv_in_another_column_order_gives_the_same_spd(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """colour-science's own CSV writer, channels in the order blue, green, red: read by name."""
    import colour

    from tests.spd_scenes import nikon_camera

    camera = nikon_camera()
    reordered = tmp_path / "camera-bgr.csv"
    colour.write_sds_to_csv_file(
        {
            name: colour.SpectralDistribution(camera.channel(name).values, camera.wavelength_nm)
            for name in ("blue", "green", "red")
        },
        reordered,
    )
    assert reordered.read_text().splitlines()[0].split(",")[1:] == ["blue", "green", "red"]
    spds = []
    for name, path in (("as given", scene.camera), ("reordered", reordered)):
        arguments = base_arguments(scene, tmp_path / name)
        arguments[arguments.index("--camera") + 1] = str(path)
        code, _, stderr = run_cli(arguments, monkeypatch, capsys)
        assert code == 0, stderr
        spds.append(read_spectrum_csv(tmp_path / name / "spd.csv").values)
    np.testing.assert_allclose(spds[1], spds[0], rtol=1e-9, atol=1e-12)


def test_a_lamp_without_a_mapping_exits_2(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    broadband = render_twin_lamp(tmp_path / "a", colour_lamp("A"), seed=5)
    arguments = base_arguments(scene, tmp_path / "out")
    arguments[arguments.index("--images") + 1 : arguments.index("--camera")] = _paths(broadband)
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 2 and "no pixel→wavelength mapping" in stderr


def test_a_mapping_lamp_without_lines_exits_1(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A halogen lamp given as the mapping lamp: no lines, the data cannot deliver a mapping."""
    halogen = render_twin_lamp(tmp_path / "a", colour_lamp("A"), seed=6)
    arguments = [
        *base_arguments(scene, tmp_path / "out"),
        "--mapping-lamp-images",
        *_paths(halogen),
        "--mapping-lamp-spectrum",
        str(write_csv(tmp_path / "a.csv", colour_lamp("A"))),
    ]
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 1
    lines = [line for line in stderr.splitlines() if line.startswith("calib:")]
    assert len(lines) == 1 and "mapping from the fluorescent lamp failed" in lines[0], stderr


def test_the_grating_file_an_estimate_writes_is_the_same_efficiency_as_its_csv(
    scene: Scene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """calib spd --grating-efficiency read grating.json (calib estimate's, rig grating's) as a
    CSV: 'line 2: 2 fields but 1 columns'; it now reads the grating file."""
    from calib.core.grating_file import GratingEfficiency, write_grating_file
    from calib.spd.pipeline import read_grating_efficiency

    csv = read_spectrum_csv(scene.rig.efficiency)
    grating = write_grating_file(
        tmp_path / "grating.json", GratingEfficiency(csv.wavelength_nm, csv.values)
    )
    read = read_grating_efficiency(grating)
    np.testing.assert_array_equal(read.wavelength_nm, csv.wavelength_nm)
    np.testing.assert_allclose(read.values, csv.values / csv.values.max(), rtol=1e-12)
    arguments = [*with_mapping_lamp(scene, tmp_path / "out"), "--no-plots", "-q"]
    arguments[arguments.index("--grating-efficiency") + 1] = str(grating)
    code, _, stderr = run_cli(arguments, monkeypatch, capsys)
    assert code == 0 and stderr == "", stderr
    assert (tmp_path / "out" / "spd.csv").is_file()


def test_the_mapping_spectrum_label_says_whether_it_was_measured(tmp_path: Path) -> None:
    """A CSV is a measurement; a colour table or a built-in line list is named as what it is."""
    csv = tmp_path / "fl.csv"
    csv.write_text("wavelength_nm,value\n400,1\n700,1\n")
    assert mapping_lamp_spectrum(csv)[1] == "measured spectrum"
    assert mapping_lamp_spectrum(Path("builtin:hg"))[1].startswith("built-in line list builtin:hg")
    assert "not a measurement" in mapping_lamp_spectrum(Path("FL11"))[1]
