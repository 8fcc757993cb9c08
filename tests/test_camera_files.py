"""Camera files: readers by column name, every format written and re-read by an independent reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.core.camera_curves import CameraCurves, as_camera
from calib.core.errors import InputError, SpectrumError
from calib.core.formats import read_camera
from calib.core.formats.ampas import (
    CAMERA_DIR,
    SCHEMA_FILE,
    AmpasFormatError,
    AmpasHeader,
    camera_file_name,
    rawtoaces_names,
    read_camera_json,
    reference_cameras,
    write_camera_json,
)
from calib.core.formats.dcamprof import DcamprofFormatError, read_ssf_json, write_ssf_json
from calib.core.formats.rgb_csv import read_camera_csv, write_camera_csv
from calib.core.formats.vkdt import read_vkdt_txt, write_vkdt_txt
from calib.core.spectra import MultiSpectrum, read_spectrum_csv

SHARED_RAWTOACES = (
    Path(__file__).resolve().parents[2] / "shared/data/camera_sensitivities/rawtoaces-data"
)


def _curves(seed: int = 0, *, sigma: bool = True) -> CameraCurves:
    wavelength = np.arange(380.0, 781.0, 5.0)
    rng = np.random.default_rng(seed)
    values = rng.random((wavelength.size, 3))
    return CameraCurves(
        wavelength,
        values / values.max(),
        0.01 + 0.01 * rng.random((wavelength.size, 3)) if sigma else None,
        measured=(wavelength >= 400) & (wavelength <= 700),
        name="test camera",
    )


def _header(**changes: str) -> AmpasHeader:
    fields = {
        "manufacturer": "Nikon",
        "model": "D5100",
        "description": "camera spectral sensitivity data",
        "document_creator": "spectral-rig 0.1.0",
        "document_creation_date": "2026-11-26T10:00:00Z",
        "license": "CC0-1.0",
    }
    fields.update(changes)
    return AmpasHeader(**fields)


# ------------------------------------------------------------------------------ readers by name


@pytest.mark.parametrize(
    "header",
    [
        "wavelength_nm,R,G,B",
        "wavelength,red,green,blue",
        "Wavelength (nm),Blue,Green,Red",
        "b,g,r,nm",
        "wl;g;r;b",
    ],
)
def test_camera_csv_columns_are_found_by_name(tmp_path: Path, header: str) -> None:
    delimiter = ";" if ";" in header else ","
    names = [column.strip() for column in header.split(delimiter)]
    truth = {"r": [0.1, 0.5, 0.9], "g": [0.2, 1.0, 0.3], "b": [0.7, 0.4, 0.0]}
    wavelengths = [400, 550, 700]
    key = {"r": "r", "red": "r", "g": "g", "green": "g", "b": "b", "blue": "b"}
    rows = []
    for i, wavelength in enumerate(wavelengths):
        cells = []
        for name in names:
            lowered = name.lower().split(" ")[0]
            cells.append(str(wavelength) if lowered not in key else str(truth[key[lowered]][i]))
        rows.append(delimiter.join(cells))
    path = tmp_path / "camera.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    curves = read_camera_csv(path)
    np.testing.assert_array_equal(curves.wavelength_nm, wavelengths)
    np.testing.assert_array_equal(curves.values, np.array([truth[c] for c in "rgb"]).T)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("wavelength_nm,r,red,g,b\n400,1,1,1,1\n500,1,1,1,1\n", "'r' and 'red' both name"),
        ("nm,wl,r,g,b\n400,400,1,1,1\n500,500,1,1,1\n", "both name the wavelength"),
        ("wavelength_nm,r,g\n400,1,1\n500,1,1\n", "no column for blue"),
        ("x,r,g,b\n400,1,1,1\n500,1,1,1\n", "no wavelength column among x, r, g, b"),
        ("400,1,1,1\n500,1,1,1\n", "no header line"),
        ("wavelength_nm,r,g,b,ir\n400,1,1,1,1\n500,1,1,1,1\n", "unknown column"),
        ("wavelength_nm,r,g,b,r_sigma\n400,1,1,1,1\n500,1,1,1,1\n", "σ column for every channel"),
    ],
)
def test_ambiguous_or_incomplete_tables_are_refused_in_one_line(
    tmp_path: Path, content: str, message: str
) -> None:
    path = tmp_path / "camera.csv"
    path.write_text(content)
    with pytest.raises(SpectrumError, match=message) as info:
        read_camera_csv(path)
    text = str(info.value)
    assert str(path) in text and "\n" not in text


def test_a_spectrum_csv_finds_its_wavelength_column_by_name(tmp_path: Path) -> None:
    path = tmp_path / "lamp.csv"
    path.write_text("power,wavelength_nm\n1,400\n2,500\n3,600\n")
    spectrum = read_spectrum_csv(path)
    np.testing.assert_array_equal(spectrum.wavelength_nm, [400, 500, 600])
    np.testing.assert_array_equal(spectrum.values, [1, 2, 3])


def test_colour_science_cameras_are_accepted_where_a_camera_is() -> None:
    import colour

    nikon = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    curves = read_camera(nikon)
    np.testing.assert_array_equal(curves.values, nikon.values)
    spectra = MultiSpectrum.from_colour(nikon)
    reordered = MultiSpectrum(
        spectra.wavelength_nm, spectra.values[:, ::-1], ("blue", "green", "red")
    )
    np.testing.assert_array_equal(as_camera(reordered).values, nikon.values)
    back = curves.to_colour()
    assert type(back).__name__ == "RGB_CameraSensitivities"
    assert list(back.labels) == ["red", "green", "blue"]
    np.testing.assert_array_equal(back.values, nikon.values)
    with pytest.raises(InputError, match="not a camera"):
        as_camera(np.zeros(3))


# ------------------------------------------------------------------------- writers, re-read


def test_rawtoaces_json_validates_with_jsonschema_and_reads_back(tmp_path: Path) -> None:
    import jsonschema

    curves = _curves()
    path = write_camera_json(tmp_path / "cam.json", curves, _header())
    document = json.loads(path.read_text())
    jsonschema.Draft4Validator(json.loads(SCHEMA_FILE.read_text())).validate(document)
    main = document["spectral_data"]["data"]["main"]
    assert list(main) == [str(w) for w in range(380, 781, 5)] and len(main) == 81
    assert document["spectral_data"]["index"] == {"main": ["R", "G", "B"]}
    np.testing.assert_array_equal(np.array(list(main.values())), curves.values)
    np.testing.assert_array_equal(read_camera_json(path).curves.values, curves.values)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"license": ""}, "license"),
        ({"document_creator": ""}, "document_creator"),
        ({"document_creation_date": "26.11.2026"}, "RFC 3339"),
    ],
)
def test_a_header_rawtoaces_would_reject_is_not_written(
    tmp_path: Path, change: dict[str, str], message: str
) -> None:
    with pytest.raises(AmpasFormatError, match=message):
        write_camera_json(tmp_path / "cam.json", _curves(), _header(**change))
    assert not (tmp_path / "cam.json").exists()


def test_rawtoaces_needs_380_to_780_at_5_nm(tmp_path: Path) -> None:
    curves = _curves()
    narrow = CameraCurves(curves.wavelength_nm[4:-16], curves.values[4:-16])
    with pytest.raises(AmpasFormatError, match="380–780 nm at 5 nm"):
        write_camera_json(tmp_path / "cam.json", narrow, _header())


def test_every_rawtoaces_data_camera_round_trips_through_our_writer(tmp_path: Path) -> None:
    """Read theirs, write ours, compare: values, labels, names, file name; bundled and shared."""
    cameras = reference_cameras()
    assert len(cameras) == 52
    for theirs in cameras:
        header = theirs.header
        ours = write_camera_json(
            tmp_path / camera_file_name(header["manufacturer"], header["model"]),
            theirs.curves,
            AmpasHeader(
                manufacturer=header["manufacturer"],
                model=header["model"],
                description=header["description"],
                document_creator=header["document_creator"],
                document_creation_date=header["document_creation_date"],
                license=header["license"],
            ),
        )
        original = json.loads((CAMERA_DIR / ours.name).read_text())
        written = json.loads(ours.read_text())
        assert written["spectral_data"]["index"] == original["spectral_data"]["index"]
        assert written["spectral_data"]["data"] == original["spectral_data"]["data"]
        for field in ("manufacturer", "model"):  # we always write schema 1.0.0; some say 0.1.0
            assert written["header"][field] == original["header"][field]
    if SHARED_RAWTOACES.is_dir():  # the bundled copy is byte-identical to the shared data
        for path in sorted((SHARED_RAWTOACES / "data/camera").glob("*.json")):
            assert (CAMERA_DIR / path.name).read_bytes() == path.read_bytes()


def test_aliases_map_names_as_rawtoaces_does() -> None:
    assert rawtoaces_names("Canon", "EOS 400D") == (
        "Canon",
        "Digital Rebel XTi",
        "same model, alternative name",
    )
    assert rawtoaces_names("Nikon Corporation", "D5100")[:2] == ("Nikon", "D5100")
    assert rawtoaces_names("spectral-rig", "TwinCam") == ("spectral-rig", "TwinCam", None)


def test_dcamprof_ssf_is_strict_json_and_reads_back(tmp_path: Path) -> None:
    curves = _curves()
    path = write_ssf_json(tmp_path / "ssf.json", curves, "Nikon D5100")
    document = json.loads(path.read_text())  # strict: no comments, no NaN
    assert document["ssf_bands"] == [380, 780, 5] and document["camera_name"] == "Nikon D5100"
    assert all(len(document[f]) == 81 for f in ("red_ssf", "green_ssf", "blue_ssf"))
    np.testing.assert_array_equal(read_ssf_json(path).values, curves.values)
    with pytest.raises(DcamprofFormatError, match="camera_name"):
        write_ssf_json(tmp_path / "bad.json", curves, " ")


def test_dcamprof_files_with_comments_are_read() -> None:
    example = Path(__file__).resolve().parents[2] / "shared/research/formats"
    path = example / "dcamprof-camera-ssf.example.json"
    if not path.is_file():
        pytest.skip("the shared dcamprof example is not present")
    curves = read_camera(path)
    assert curves.range_nm == (400.0, 720.0) and curves.values.shape == (33, 3)


def test_vkdt_text_reads_back_with_numpy_loadtxt(tmp_path: Path) -> None:
    curves = _curves()
    path = write_vkdt_txt(tmp_path / "Nikon_D5100.txt", curves)
    rows = np.loadtxt(path)
    assert rows.shape == (81, 4)
    np.testing.assert_array_equal(rows[:, 0], np.arange(380, 781, 5))
    np.testing.assert_array_equal(rows[:, 1:], curves.values)
    np.testing.assert_array_equal(read_vkdt_txt(path).values, curves.values)


def test_camera_csv_reads_back_with_colour_and_ours(tmp_path: Path) -> None:
    import colour

    curves = _curves()
    path = write_camera_csv(
        tmp_path / "sensitivity.csv", curves, ["units: relative", "normalisation: max 1"]
    )
    lines = path.read_text().splitlines()
    assert lines[0] == "wavelength_nm,R,G,B,R_sigma,G_sigma,B_sigma"
    assert lines[1] == "# units: relative"
    sds = colour.io.read_sds_from_csv_file(path)
    assert list(sds) == ["R", "G", "B", "R_sigma", "G_sigma", "B_sigma"]
    for k, label in enumerate("RGB"):
        np.testing.assert_array_equal(sds[label].values, curves.values[:, k])
        np.testing.assert_array_equal(sds[label].wavelengths, curves.wavelength_nm)
        assert curves.sigma is not None
        np.testing.assert_array_equal(sds[f"{label}_sigma"].values, curves.sigma[:, k])
    again = read_camera(path)
    np.testing.assert_array_equal(again.values, curves.values)
    assert again.sigma is not None and curves.sigma is not None
    np.testing.assert_array_equal(again.sigma, curves.sigma)


def test_read_camera_refuses_what_is_not_a_camera(tmp_path: Path) -> None:
    path = tmp_path / "thing.json"
    path.write_text('{"hello": 1}')
    with pytest.raises(InputError, match="not a camera file"):
        read_camera(path)
    with pytest.raises(InputError, match=r"no result\.json"):
        read_camera(tmp_path)


def test_colour_spectra_and_cameras_are_accepted_by_the_pipeline_and_the_basis() -> None:
    import colour

    from calib.core.spectra import DEFAULT_GRID, as_spectrum
    from calib.model.bases import camera_basis
    from calib.pipeline.inputs import load_spectrum

    fl2 = colour.SDS_ILLUMINANTS["FL2"]
    loaded = load_spectrum(fl2, "FL2", DEFAULT_GRID)
    np.testing.assert_array_equal(loaded.spectrum.values, fl2.values)
    with pytest.raises(SpectrumError, match="not a spectrum"):
        as_spectrum([1, 2, 3], "lamp")
    cameras = list(colour.MSDS_CAMERA_SENSITIVITIES.values())
    from_colour = camera_basis(cameras, n_vectors=2, cache=False)
    from_spectra = camera_basis(
        [MultiSpectrum.from_colour(camera) for camera in cameras], n_vectors=2, cache=False
    )
    np.testing.assert_allclose(from_colour.mean, from_spectra.mean)
