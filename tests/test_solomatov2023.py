"""solomatov2023: reading DNG colour matrices, the constrained fit, white balance from a chart."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile

import calib.methods
from calib.core.colour_data import colorchecker
from calib.core.datasets import colour_science_cameras
from calib.core.errors import InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import relative_error
from calib.core.observations import ColorMatrixObservation
from calib.core.spectra import DEFAULT_GRID
from calib.methods.baselines.solomatov2023 import (
    estimate_solomatov2023,
    read_color_matrices,
    simulate_color_matrix,
)
from calib.model.bases import fallback_camera_basis
from calib.model.charts import render_chart
from mocks.dng import DngMetadata, write_dng
from tests.synthetic_cameras import as_spectrum

MATRIX_A = np.array([[0.71, -0.12, -0.08], [-0.52, 1.31, 0.22], [-0.15, 0.29, 0.58]])
MATRIX_D65 = np.array([[0.67, -0.06, -0.10], [-0.43, 1.25, 0.20], [-0.09, 0.22, 0.57]])


def _srational(matrix: np.ndarray) -> list[int]:
    return [part for value in matrix.ravel() for part in (round(value * 10000), 10000)]


def _tiff_with_tags(path: Path, tags: list[tuple[int, str, int, object, bool]]) -> Path:
    tifffile.imwrite(path, np.zeros((24, 24), dtype=np.uint16), extratags=tags, metadata=None)
    return path


@pytest.fixture(scope="module")
def offline_camera():
    record = colour_science_cameras()[0]
    truth = record.sensitivity.resample(DEFAULT_GRID, "interpolate", out_of_range="zero")
    return record, truth.values / truth.values.max()


@pytest.fixture(scope="module")
def offline_basis(offline_camera):
    record, _ = offline_camera
    return fallback_camera_basis(exclude=[record.camera])


def _matrices(truth: np.ndarray) -> ColorMatrixObservation:
    return ColorMatrixObservation(
        "camera",
        np.stack([simulate_color_matrix(truth, "A"), simulate_color_matrix(truth, "D65")]),
        ("A", "D65"),
        source="simulated",
    )


# ------------------------------------------------------------------------------- reading


def test_color_matrix1_of_a_dng_is_read_with_its_illuminant(tmp_path):
    path = write_dng(
        tmp_path / "frame.dng",
        np.full((24, 32), 600, dtype=np.uint16),
        DngMetadata(
            exposure_s=0.01,
            make="Acme",
            model="One",
            color_matrix1=tuple((float(r), float(g), float(b)) for r, g, b in MATRIX_D65),
        ),
    )
    observation = read_color_matrices(path)
    assert observation.name == "Acme One"
    assert observation.illuminants == ("D65",)
    np.testing.assert_allclose(observation.matrices[0], MATRIX_D65, atol=1e-4)
    assert "DNG ColorMatrix1" in observation.source


def test_two_matrices_and_their_calibration_illuminants_are_read(tmp_path):
    path = _tiff_with_tags(
        tmp_path / "two.dng",
        [
            (50708, "s", 0, "Acme Two", True),
            (50721, "2i", 9, _srational(MATRIX_A), True),
            (50722, "2i", 9, _srational(MATRIX_D65), True),
            (50778, "H", 1, 17, True),
            (50779, "H", 1, 21, True),
        ],
    )
    observation = read_color_matrices(path)
    assert observation.name == "Acme Two"
    assert observation.illuminants == ("A", "D65")
    np.testing.assert_allclose(observation.matrices, np.stack([MATRIX_A, MATRIX_D65]), atol=1e-4)


def test_unknown_calibration_illuminants_need_an_override(tmp_path):
    path = _tiff_with_tags(
        tmp_path / "other.dng",
        [(50721, "2i", 9, _srational(MATRIX_A), True), (50778, "H", 1, 255, True)],
    )
    with pytest.raises(InputError, match=r"EXIF LightSource 255.*pass illuminants"):
        read_color_matrices(path)
    observation = read_color_matrices(path, illuminants=["D50"])
    assert observation.illuminants == ("D50",)
    missing = _tiff_with_tags(tmp_path / "none.dng", [(50721, "2i", 9, _srational(MATRIX_A), True)])
    with pytest.raises(InputError, match="ColorMatrix1 has no CalibrationIlluminant1"):
        read_color_matrices(missing)


def test_non_dng_raw_files_fall_back_to_libraw_s_matrix(tmp_path, monkeypatch):
    import rawpy

    import calib.methods.baselines.solomatov2023 as module

    path = write_dng(
        tmp_path / "canon.dng",
        np.full((24, 32), 600, dtype=np.uint16),
        DngMetadata(exposure_s=0.01, make="Canon", model="Canon EOS 5D Mark III"),
    )
    with rawpy.imread(str(path)) as raw:
        expected = np.array(raw.rgb_xyz_matrix[:3])
    # As for a CR2 or NEF: no DNG tags to read, so LibRaw's matrix for the camera is used.
    monkeypatch.setattr(module, "_dng_matrices", lambda file: None)
    observation = read_color_matrices(path)
    np.testing.assert_allclose(observation.matrices[0], expected)
    assert observation.illuminants == ("D65",)
    assert "LibRaw built-in matrix" in observation.source


def test_files_without_a_matrix_are_refused(tmp_path):
    plain = _tiff_with_tags(tmp_path / "plain.tif", [])
    with pytest.raises(InputError, match=r"no colour matrix.*Adobe DNG Converter"):
        read_color_matrices(plain)
    text = tmp_path / "notes.txt"
    text.write_text("not a raw file")
    with pytest.raises(InputError, match="no colour matrix"):
        read_color_matrices(text)
    with pytest.raises(InputError, match="file not found"):
        read_color_matrices(tmp_path / "missing.dng")


def test_matrix_observation_validates():
    with pytest.raises(InputError, match="singular"):
        ColorMatrixObservation("c", np.zeros((3, 3)), ("D65",))
    with pytest.raises(InputError, match="2 matrices but 1 illuminants"):
        ColorMatrixObservation("c", np.stack([MATRIX_A, MATRIX_D65]), ("A",))
    with pytest.raises(InputError, match="3×3"):
        ColorMatrixObservation("c", np.eye(2), ("A",))


# --------------------------------------------------------------------------------- model


def test_simulated_matrix_maps_xyz_to_the_camera_for_patches(offline_camera):
    from calib.methods.baselines.solomatov2023 import _cmfs_on_grid
    from calib.model.charts import radiance_rows

    _, truth = offline_camera
    matrix = simulate_color_matrix(truth, "D65")
    rows = radiance_rows(colorchecker("ColorChecker N Ohta"), colour_lamp("D65"), DEFAULT_GRID)
    camera = rows @ truth
    predicted = (rows @ _cmfs_on_grid(DEFAULT_GRID)) @ matrix.T
    # A 3×3 cannot be exact (the camera is not a linear mix of the CIE observer), but close,
    # up to one overall scale.
    scale = float(np.sum(camera * predicted) / np.sum(predicted**2))
    assert np.linalg.norm(scale * predicted - camera) / np.linalg.norm(camera) < 0.1


def test_matrices_and_a_chart_give_a_close_estimate(offline_camera, offline_basis):
    _, truth = offline_camera
    chart = render_chart(colorchecker(), colour_lamp("D65"), as_spectrum(truth))
    result = calib.methods.estimate(
        [_matrices(truth), chart], method="solomatov2023", basis=offline_basis
    )
    assert result.method == "solomatov2023"
    # The offline basis (colour-science curves, this camera left out) limits every basis method
    # here: the colour checker alone (jiang2013) reaches RE 0.109 on this camera.
    assert relative_error(result.sensitivity, truth) < 0.11
    assert result.sensitivity.min() >= -1e-9  # constrained non-negative
    assert len(result.diagnostics["matrix_gains"]) == 3


def test_the_chart_fixes_the_channel_scales(offline_camera, offline_basis):
    """Matrices leave each channel's scale open; the white balance from the chart sets it."""
    _, truth = offline_camera
    gains = np.array([0.4, 1.0, 2.5])
    scaled = truth * gains
    scaled /= scaled.max()
    matrices = _matrices(truth)  # the same matrices: their rows do not know the gains
    chart = render_chart(colorchecker(), colour_lamp("D65"), as_spectrum(scaled))
    balanced = estimate_solomatov2023([matrices, chart], basis=offline_basis)
    reference_chart = render_chart(colorchecker(), colour_lamp("D65"), as_spectrum(truth))
    reference = estimate_solomatov2023([matrices, reference_chart], basis=offline_basis)
    # Same matrices, so the curves differ only by the chart's per-channel gains.
    ratio = balanced.sensitivity[10:25] / reference.sensitivity[10:25]
    np.testing.assert_allclose(ratio / ratio[:, 2:3], np.tile(gains / gains[2], (15, 1)), rtol=1e-9)
    unbalanced = estimate_solomatov2023([matrices], basis=offline_basis, white_balance="none")
    assert relative_error(unbalanced.sensitivity, scaled) > 2 * relative_error(
        balanced.sensitivity, scaled
    )
    full = estimate_solomatov2023([matrices, chart], basis=offline_basis, white_balance="full")
    assert np.shape(full.diagnostics["white_balance_transform"]) == (3, 3)


def test_bad_inputs_say_what_is_wrong(offline_camera, offline_basis):
    _, truth = offline_camera
    matrices = _matrices(truth)
    chart = render_chart(colorchecker(), colour_lamp("D65"), as_spectrum(truth))
    with pytest.raises(InputError, match="give a colour-checker observation"):
        estimate_solomatov2023([matrices], basis=offline_basis)
    with pytest.raises(InputError, match="white_balance must be"):
        estimate_solomatov2023([matrices, chart], basis=offline_basis, white_balance="grey")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="needs exactly one ColorMatrixObservation"):
        calib.methods.estimate([chart], method="solomatov2023", basis=offline_basis)
    with pytest.raises(InputError, match="ridge"):
        estimate_solomatov2023([matrices, chart], basis=offline_basis, ridge=-0.5)
    with pytest.raises(InputError, match="n_vectors"):
        estimate_solomatov2023([matrices, chart], basis=offline_basis, n_vectors=9)
    with pytest.raises(InputError, match="no illuminant or light source named 'D93'"):
        estimate_solomatov2023(
            [ColorMatrixObservation("c", MATRIX_A, ("D93",)), chart], basis=offline_basis
        )
