"""calib.pipeline.outputs, calib.pipeline.report and calib.core.grating_file: the files an estimate leaves, read back."""

from __future__ import annotations

import csv
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

from calib.core.datasets import read_rawtoaces_json
from calib.core.grating_file import (
    GRATING_FORMAT_VERSION,
    GratingEfficiency,
    GratingFileError,
    read_grating_file,
    write_grating_file,
)
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.pipeline import LampImages, OfflineSettings, run_offline
from calib.pipeline.run import OfflineOutcome
from tests.rendered_capture import Capture, shared_capture


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(scope="module")
def outcome(capture: Capture, tmp_path_factory: pytest.TempPathFactory) -> OfflineOutcome:
    lamps = [
        LampImages(lamp.name, lamp.kind, lamp.spectrum_csv, lamp.frames) for lamp in capture.lamps
    ]
    settings = OfflineSettings(
        basis=capture.basis, command_line=("calib", "estimate", "--lamp", "LED", "…")
    )
    return run_offline(lamps, tmp_path_factory.mktemp("out"), settings)


def test_sensitivity_csv_is_on_the_grid_with_maximum_one(outcome: OfflineOutcome) -> None:
    with outcome.files["sensitivity"].open() as stream:
        rows = list(csv.reader(stream))
    assert rows[0] == ["wavelength_nm", "r", "g", "b"]
    values = np.array(rows[1:], dtype=float)
    np.testing.assert_array_equal(values[:, 0], np.arange(400.0, 701.0, 10.0))
    assert values[:, 1:].max() == pytest.approx(1.0)
    assert values[:, 1:].min() >= 0.0
    result = outcome.estimate.result
    np.testing.assert_allclose(values[:, 1:], np.clip(result.sensitivity, 0, None), atol=1e-12)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_result_json_records_everything(outcome: OfflineOutcome, capture: Capture) -> None:
    document = json.loads(outcome.files["result"].read_text())
    assert document["schema"] == "spectral-rig/estimate-result"
    assert document["method"] == "makabe2025"
    assert set(document["sensitivity"]) == {"r", "g", "b"}
    sigma = document["sensitivity_sigma"]
    assert set(sigma) == {"r", "g", "b"}
    assert all(len(sigma[c]) == 31 and min(sigma[c]) >= 0 for c in "rgb")
    mapping = document["mapping"]
    assert set(mapping["coefficients_nm"]) == {"a_nm_per_px2", "b_nm_per_px", "c_nm"}
    assert mapping["covariance"] is not None
    assert 0 < document["mapping_re_estimate"] < 0.01
    assert len(document["grating_efficiency"]) == 31
    assert max(document["grating_efficiency"]) == pytest.approx(1.0)
    assert document["geometry"]["detected_on"] == "LED"
    assert set(document["residuals"]) == {"LED"}
    assert document["residuals"]["LED"]["profile_normalised_rms"] == pytest.approx(1.0, abs=0.3)
    provenance = document["provenance"]
    assert provenance["software"]["name"] == "spectral-rig" and provenance["software"]["version"]
    assert provenance["command_line"][:2] == ["calib", "estimate"]
    assert provenance["camera"]["camera"] == "spectral-rig SimCam"
    inputs = {record["path"]: record for record in provenance["inputs"]}
    for lamp in capture.lamps:
        for frame in lamp.frames:
            record = inputs[str(frame)]
            assert record["role"] == "frame" and record["lamp"] == lamp.name
            assert record["sha256"] == _sha256(frame)
            assert record["size"] == frame.stat().st_size
        assert inputs[str(lamp.spectrum_csv)]["sha256"] == _sha256(lamp.spectrum_csv)
    assert document["files"]["sensitivity"] == "sensitivity.csv"


def test_camera_json_is_what_rawtoaces_reads(outcome: OfflineOutcome) -> None:
    path = outcome.files["camera_json"]
    assert path.name == "spectral_rig_simcam_400_700_10.json"
    document = json.loads(path.read_text())
    header = document["header"]
    assert header["schema_version"] == "0.1.0"
    assert (header["manufacturer"], header["model"]) == ("spectral-rig", "simcam")
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", header["document_creation_date"])
    data = document["spectral_data"]
    assert data["units"] == "relative" and data["index"] == {"main": ["R", "G", "B"]}
    assert list(data["data"]["main"])[:2] == ["400", "410"]
    curves = read_rawtoaces_json(path)
    expected = np.clip(outcome.estimate.result.sensitivity, 0, None)
    np.testing.assert_allclose(curves.values, expected / expected.max(), atol=1e-12)


def test_grating_json_round_trips_with_its_geometry(outcome: OfflineOutcome) -> None:
    grating = read_grating_file(outcome.files["grating"])
    result = outcome.estimate.result
    np.testing.assert_allclose(grating.wavelength_nm, result.wavelength_nm)
    assert result.grating_efficiency is not None
    np.testing.assert_allclose(grating.efficiency, result.grating_efficiency, atol=1e-12)
    assert grating.geometry["mapping"]["type"] == "quadratic"
    assert "spot_centre_px" in grating.geometry["diffraction"]
    assert grating.provenance["method"] == "makabe2025"


def test_report_is_one_self_contained_page_with_every_plot(outcome: OfflineOutcome) -> None:
    report = outcome.files["report"]
    page = report.read_text()
    assert page.startswith("<!DOCTYPE html>")
    sources = re.findall(r"src='([^']*)'", page)
    assert len(sources) == 5  # sensitivity, efficiency, mapping, fit LED, geometry
    assert all(source.startswith("data:image/png;base64,") for source in sources)
    assert "http" not in page.replace("http-equiv", "")
    for key in ("plot:sensitivity", "plot:efficiency", "plot:mapping", "plot:fit:LED"):
        assert outcome.files[key].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert outcome.files["plot:geometry"].exists()
    assert "mapping RE estimate" in page and "makabe2025" in page
    for record in outcome.estimate.provenance.inputs:
        assert record.sha256 in page


def test_report_shows_warnings_first(outcome: OfflineOutcome, tmp_path: Path) -> None:
    from dataclasses import replace

    from calib.pipeline.report import write_report

    warned = replace(
        outcome.estimate,
        provenance=replace(outcome.estimate.provenance, warnings=("check <the> lamp",)),
    )
    page = write_report(tmp_path, warned)["report"].read_text()
    assert page.index("Warnings") < page.index("Summary")
    assert "check &lt;the&gt; lamp" in page


# ------------------------------------------------------------------------------- grating file


def _grating() -> GratingEfficiency:
    wavelength = np.arange(380.0, 721.0, 5.0)
    return GratingEfficiency(
        wavelength_nm=wavelength,
        efficiency=0.5 + 0.4 * np.sin(wavelength / 60.0) ** 2,
        efficiency_sigma=np.full(wavelength.size, 0.01),
        geometry={"order": 1, "description": "500 l/mm sheet"},
        provenance={"source": "test"},
    )


def test_grating_file_round_trip(tmp_path: Path) -> None:
    grating = _grating()
    path = write_grating_file(tmp_path / "grating.json", grating)
    again = read_grating_file(path)
    np.testing.assert_allclose(again.efficiency, grating.efficiency / grating.efficiency.max())
    assert again.efficiency_sigma is not None
    assert again.geometry["description"] == "500 l/mm sheet"
    assert again.covers(DEFAULT_GRID)
    assert not again.covers(WavelengthGrid(360.0, 700.0, 10.0))


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"schema": "other"}, "schema"),
        ({"format_version": GRATING_FORMAT_VERSION + 1}, "format_version"),
        ({"format_version": "1"}, "format_version"),
        ({"wavelength_nm": [400, 500, 450]}, "wavelength_nm"),
        ({"efficiency": [1.0, None, 1.0]}, "efficiency"),
        ({"efficiency": [1.0, -0.5, 1.0]}, "efficiency"),
        ({"efficiency": [1.0, 1.0]}, "efficiency"),
        ({"efficiency_sigma": [0.1]}, "efficiency_sigma"),
        ({"geometry": [1, 2]}, "geometry"),
    ],
)
def test_grating_file_errors_name_the_field(
    tmp_path: Path, change: dict[str, object], field: str
) -> None:
    document = {
        "schema": "spectral-rig/grating-efficiency",
        "format_version": 1,
        "wavelength_nm": [400, 550, 700],
        "efficiency": [0.8, 1.0, 0.7],
    }
    document.update(change)
    path = tmp_path / "grating.json"
    path.write_text(json.dumps(document))
    with pytest.raises(GratingFileError) as error:
        read_grating_file(path)
    assert error.value.source == f"{path}: {field}"


def test_grating_file_not_json_or_missing(tmp_path: Path) -> None:
    path = tmp_path / "grating.json"
    path.write_text('{"schema": ')
    with pytest.raises(GratingFileError, match=r"not valid JSON.*line 1"):
        read_grating_file(path)
    with pytest.raises(GratingFileError, match="file not found"):
        read_grating_file(tmp_path / "missing.json")
    path.write_text(json.dumps({"schema": "spectral-rig/grating-efficiency", "format_version": 1}))
    with pytest.raises(GratingFileError, match="missing"):
        read_grating_file(path)


def test_a_paused_hasher_hashes_once_started_or_when_asked(tmp_path: Path) -> None:
    from calib.pipeline.provenance import FileHasher

    files = [tmp_path / f"{name}.bin" for name in ("a", "b")]
    for index, path in enumerate(files):
        path.write_bytes(bytes(range(index, index + 100)) * 1000)
    expected = [hashlib.sha256(path.read_bytes()).hexdigest() for path in files]
    with FileHasher(paused=True) as hasher:
        hasher.add(files[0], "frame", "A")
        hasher.start()
        hasher.add(files[1], "frame", "A")
        assert [record.sha256 for record in hasher.results()] == expected
    with FileHasher(paused=True) as hasher:  # results() does not wait for a start() never made
        hasher.add(files[1], "dark", "A")
        assert [record.sha256 for record in hasher.results()] == expected[1:]
    with FileHasher(paused=True) as hasher:  # nor does leaving the block
        hasher.add(files[0], "frame", "A")
