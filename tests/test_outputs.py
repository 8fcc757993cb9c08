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
from calib.core.spectra import DEFAULT_GRID, Spectrum, WavelengthGrid
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
        rows = [row for row in csv.reader(stream) if not row[0].startswith("#")]
    assert rows[0] == ["wavelength_nm", "R", "G", "B", "R_sigma", "G_sigma", "B_sigma"]
    values = np.array(rows[1:], dtype=float)
    np.testing.assert_array_equal(values[:, 0], np.arange(400.0, 701.0, 10.0))
    assert values[:, 1:4].max() == pytest.approx(1.0)
    assert values[:, 1:4].min() >= 0.0
    result = outcome.estimate.result
    np.testing.assert_allclose(values[:, 1:4], np.clip(result.sensitivity, 0, None), atol=1e-12)
    assert result.sensitivity_sigma is not None
    np.testing.assert_allclose(values[:, 4:], result.sensitivity_sigma, rtol=1e-12)
    text = outcome.files["sensitivity"].read_text()
    assert "# units: relative; normalisation: maximum over all channels = 1" in text
    import colour  # an independent reader: colour-science's own CSV reader, by column name

    sds = colour.io.read_sds_from_csv_file(outcome.files["sensitivity"])
    np.testing.assert_allclose(sds["G"].values, values[:, 2], atol=1e-15)
    np.testing.assert_allclose(sds["B_sigma"].values, values[:, 6], atol=1e-15)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_result_json_records_everything(outcome: OfflineOutcome, capture: Capture) -> None:
    document = json.loads(outcome.files["result"].read_text())
    assert document["schema"] == "spectral-rig/estimate-result"
    assert document["method"] == "prior"  # auto: two lamps measured directly
    assert document["diagnostics"]["method_choice"]["method"] == "prior"
    assert set(document["sensitivity"]) == {"R", "G", "B"}
    sigma = document["sensitivity_sigma"]
    assert set(sigma) == {"R", "G", "B"}
    assert all(len(sigma[c]) == 31 and min(sigma[c]) >= 0 for c in "RGB")
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


def test_every_camera_file_drops_into_its_consumer(outcome: OfflineOutcome) -> None:
    """rawtoaces (schema 1.0.0, 81 rows at 380–780/5), dcamprof (strict JSON), vkdt (loadtxt)."""
    import jsonschema

    from calib.core.formats.ampas import SCHEMA_FILE, rawtoaces_problems
    from calib.core.formats.dcamprof import ssf_problems
    from calib.pipeline.camera_identity import libraw_names

    path = outcome.files["camera_json"]
    document = json.loads(path.read_text())
    jsonschema.Draft4Validator(json.loads(SCHEMA_FILE.read_text())).validate(document)
    assert rawtoaces_problems(document) == []
    header = document["header"]
    assert header["schema_version"] == "1.0.0"
    first_frame = outcome.estimate.provenance.camera["first_frame"]
    names = libraw_names(Path(first_frame))
    assert names is not None
    expected = (names.normalized_make or names.make, names.normalized_model or names.model)
    assert (header["manufacturer"], header["model"]) == expected == ("spectral-rig", "SimCam")
    assert path.name == "spectral-rig_SimCam_380_780_5.json"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", header["document_creation_date"])
    assert "380–395 nm, 705–780 nm extended" in header["comments"]
    main = document["spectral_data"]["data"]["main"]
    assert list(main) == [str(w) for w in range(380, 781, 5)]
    curves = read_rawtoaces_json(path)
    result = outcome.estimate.result
    inside = (curves.wavelength_nm >= 400) & (curves.wavelength_nm <= 700)
    estimate = np.stack(
        [
            np.interp(curves.wavelength_nm[inside], result.wavelength_nm, c)
            for c in result.physical_sensitivity().T
        ],
        axis=1,
    )
    np.testing.assert_allclose(curves.values[inside], estimate, atol=1e-12)
    ssf = json.loads(outcome.files["dcamprof"].read_text())
    assert ssf_problems(ssf) == [] and ssf["camera_name"] == "spectral-rig SimCam"
    np.testing.assert_allclose(np.array(ssf["green_ssf"]), curves.values[:, 1], atol=1e-12)
    rows = np.loadtxt(outcome.files["vkdt"])
    np.testing.assert_array_equal(rows[:, 0], np.arange(380, 781, 5))
    np.testing.assert_allclose(rows[:, 1:], curves.values, atol=1e-12)


def test_result_json_reads_back_as_the_camera_and_to_colour_agrees(outcome: OfflineOutcome) -> None:
    from calib.core.formats import read_camera

    result = outcome.estimate.result
    again = read_camera(outcome.files["result"].parent)
    np.testing.assert_allclose(again.values, result.physical_sensitivity(), atol=1e-12)
    colour_camera = result.to_colour()
    np.testing.assert_allclose(colour_camera.values, result.physical_sensitivity(), atol=1e-12)
    np.testing.assert_array_equal(colour_camera.wavelengths, result.wavelength_nm)


def _csv_columns(path: Path) -> np.ndarray:
    with path.open() as stream:
        rows = [row for row in csv.reader(stream) if not row[0].startswith("#")]
    return np.array(rows[1:], dtype=float)


def test_result_json_and_sensitivity_csv_carry_the_same_curve_and_sigma(
    outcome: OfflineOutcome, tmp_path: Path
) -> None:
    """One curve for users: a solve with negative lobes is clipped alike in both files."""
    from dataclasses import replace

    from calib.pipeline.outputs import write_result_json, write_sensitivity_csv

    result = outcome.estimate.result
    lobed = result.sensitivity.copy()
    lobed[:3, 2] = [-0.04, -0.02, -0.01]  # a solve's ringing at the grid's edge
    estimate = replace(outcome.estimate, result=replace(result, sensitivity=lobed))
    csv_path = write_sensitivity_csv(tmp_path / "sensitivity.csv", estimate.result)
    document = json.loads(write_result_json(tmp_path / "result.json", estimate).read_text())
    columns = _csv_columns(csv_path)
    from_json = np.stack([document["sensitivity"][c] for c in "RGB"], axis=1)
    sigma_json = np.stack([document["sensitivity_sigma"][c] for c in "RGB"], axis=1)
    np.testing.assert_array_equal(from_json, columns[:, 1:4])
    np.testing.assert_array_equal(sigma_json, columns[:, 4:])
    assert from_json[:3, 2].tolist() == [0.0, 0.0, 0.0]
    negative = int(np.count_nonzero(lobed < 0))
    assert document["sensitivity_clipping"].startswith(f"{negative} negative value(s)")
    # the shipped run's files agree too
    shipped = json.loads(outcome.files["result"].read_text())
    columns = _csv_columns(outcome.files["sensitivity"])
    np.testing.assert_allclose(
        np.stack([shipped["sensitivity"][c] for c in "RGB"], axis=1), columns[:, 1:4], rtol=1e-15
    )


def test_the_camera_files_say_what_result_json_holds_of_a_clipped_solve(
    outcome: OfflineOutcome, tmp_path: Path
) -> None:
    """The files' comment on negative lobes agrees with result.json, which holds the clipped curve
    too (decision 0038): it used to say that result.json kept the negative values."""
    from dataclasses import replace

    from calib.pipeline.outputs import deliver, write_result_json

    result = outcome.estimate.result
    lobed = result.sensitivity.copy()
    lobed[:3, 2] = [-0.04, -0.02, -0.01]
    estimate = replace(outcome.estimate, result=replace(result, sensitivity=lobed))
    document = json.loads(write_result_json(tmp_path / "result.json", estimate).read_text())
    assert min(min(document["sensitivity"][c]) for c in "RGB") == 0.0
    [line] = [line for line in deliver(estimate).comments(estimate.result) if "negative" in line]
    negative = int(np.count_nonzero(lobed < 0))
    assert line.startswith(f"{negative} negative value(s) of the solve set to zero")
    assert document["sensitivity_clipping"].startswith(f"{negative} negative value(s)")
    assert "result.json too" in line and "keeps" not in line


def test_grating_json_round_trips_with_its_geometry(outcome: OfflineOutcome) -> None:
    grating = read_grating_file(outcome.files["grating"])
    result = outcome.estimate.result
    np.testing.assert_allclose(grating.wavelength_nm, result.wavelength_nm)
    assert result.grating_efficiency is not None
    np.testing.assert_allclose(grating.efficiency, result.grating_efficiency, atol=1e-12)
    assert grating.geometry["mapping"]["type"] == "quadratic"
    assert "spot_centre_px" in grating.geometry["diffraction"]
    assert grating.provenance["method"] == "prior"


def test_report_is_one_self_contained_page_with_every_plot(
    outcome: OfflineOutcome, capture: Capture
) -> None:
    report = outcome.files["report"]
    page = report.read_text()
    assert page.startswith("<!DOCTYPE html>")
    sources = re.findall(r"src='([^']*)'", page)
    # sensitivity, efficiency, mapping, a fit per lamp, lamp spectra, geometry
    assert len(sources) == 5 + len(capture.lamps)
    for lamp in capture.lamps:
        assert outcome.files[f"plot:fit:{lamp.name}"].is_file()
    assert all(source.startswith("data:image/png;base64,") for source in sources)
    # nothing loaded from elsewhere (the embedded images' base64 may spell "http" by chance)
    text = re.sub(r"src='data:image/png;base64,[A-Za-z0-9+/=]*'", "", page)
    assert "http" not in text.replace("http-equiv", "")
    for key in ("plot:sensitivity", "plot:efficiency", "plot:mapping", "plot:fit:LED"):
        assert outcome.files[key].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert outcome.files["plot:geometry"].exists()
    assert "mapping RE estimate" in page and "prior" in page
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
    assert page.index("1 warning(s)") < page.index("Summary")
    assert page.index("check &lt;the&gt; lamp") < page.index("Summary")


def test_report_overlays_the_truth_and_gives_the_colour_error(
    outcome: OfflineOutcome, capture: Capture, tmp_path: Path
) -> None:
    from dataclasses import replace

    from calib.core.camera_curves import CameraCurves
    from calib.core.spectra import DEFAULT_GRID
    from calib.core.truth import GroundTruth
    from calib.pipeline.context import EstimateContext, WarmupTrace
    from calib.pipeline.report import write_report
    from tests.rendered_capture import GRATING, efficiency

    wavelength = np.arange(380.0, 781.0, 5.0)
    truth = GroundTruth(
        CameraCurves(DEFAULT_GRID.wavelength_nm, capture.truth, name="rendered camera"),
        grating_efficiency=Spectrum(wavelength, efficiency(wavelength)),
        mapping=GRATING,
        source="the rendered capture's camera",
    )
    warmup = WarmupTrace("LED", (10.0, 20.0, 30.0), (float("nan"), 0.03, 0.004), 0.01)
    lines = [{"lamp": "FL", "pixel": 700.0, "wavelength_nm": 546.07, "residual_nm": 0.1}]
    estimate = replace(
        outcome.estimate,
        result=replace(outcome.estimate.result, diagnostics={"matched_lines": lines}),
    )
    written = write_report(
        tmp_path, estimate, outcome.files, context=EstimateContext(truth, (warmup,))
    )
    page = written["report"].read_text()
    assert "RE against the truth" in page and "mapping RE against the truth" in page
    assert "×10⁻²" in page
    for illuminant in ("D65", "A"):
        assert re.search(
            rf"<tr><td>{illuminant}</td><td class='num'>\d+\.\d\d / \d+\.\d\d</td>", page
        )
    assert "546.07" in page and "Not available" not in page  # the matched lines' table
    assert written["plot:warmup"].is_file()
    own = outcome.files["report"].read_text()
    for key in ("sensitivity", "camera_json", "dcamprof", "vkdt", "result"):
        assert f"<a href='{outcome.files[key].name}'>" in own
        assert f"/{outcome.files[key].name}'>" in page  # relative to where this one was written
    # the truth's ΔE against itself would be zero: the estimate's is not, and is recorded
    result = json.loads(outcome.files["result"].read_text())
    assert result["uses"]["against_truth"] is None  # written without a truth
    assert set(result["uses"]["aces_idt"]) == {"D55", "D65", "A"}


def test_report_lists_the_matched_lines_and_says_when_warmup_is_not_available(
    outcome: OfflineOutcome,
) -> None:
    """The fluorescent lamp's Hg lines, fitted where the mapping puts them, are in the result and
    the report (line, wavelength, pixel, fitted wavelength, residual); the warm-up is not."""
    page = outcome.files["report"].read_text()
    assert "Matched lines" in page and "Hg 546.1" in page and "residual_nm" in page
    result = json.loads(outcome.files["result"].read_text())
    rows = result["mapping"]["details"]["matched_lines"]
    assert {"line", "wavelength_nm", "pixel", "fitted_nm", "residual_nm", "weight"} <= set(rows[0])
    assert "Lamp warm-up: not recorded" in page


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


def test_dcp_and_icc_are_made_when_dcamprof_is_installed(
    outcome: OfflineOutcome, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from calib.pipeline.outputs import write_outputs
    from tests import fake_dcamprof

    assert "not installed" in json.loads(outcome.files["result"].read_text())["dcamprof"]
    assert "dcp" not in outcome.files
    assert "DCP and ICC profiles: not made here" in outcome.files["report"].read_text()
    fake_dcamprof.install(tmp_path / "bin")
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}:/usr/bin:/bin")
    files = write_outputs(tmp_path / "out", outcome.estimate)
    assert files["dcp"].name == "spectral-rig SimCam.dcp" and files["dcp"].parent.name == "dcamprof"
    assert files["icc"].read_bytes()[36:40] == b"acsp"
    assert json.loads(files["result"].read_text())["dcamprof"].startswith("made by")


def test_the_eta_plots_absolute_band_keeps_the_scale_where_the_shape_sigma_is_zero() -> None:
    """The result's σ of η is the max-1 shape's (zero at the peak); on η₁'s absolute scale the
    model's own σ, which carries the scale, stays in the band."""
    from calib.pipeline.report_plots import absolute_first_order_sigma

    record = {
        "first_order_efficiency": [0.2, 0.4, 0.3],
        "first_order_efficiency_sigma": [0.01, 0.02, 0.015],
    }
    shape_sigma = np.array([0.05, 0.0, 0.025])
    sigma = absolute_first_order_sigma(record, shape_sigma)
    np.testing.assert_allclose(sigma, np.hypot([0.01, 0.02, 0.015], shape_sigma * 0.4))
    assert sigma[1] == 0.02  # at the peak: the scale's σ, not zero
