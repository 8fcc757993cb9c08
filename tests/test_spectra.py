"""calib.core.spectra: grids, validation, resampling and CSV input/output."""

from __future__ import annotations

from pathlib import Path

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calib.core.errors import SpectrumError
from calib.core.spectra import (
    DEFAULT_GRID,
    MultiSpectrum,
    Spectrum,
    WavelengthGrid,
    read_multispectrum_csv,
    read_spectrum_csv,
    write_csv,
)


def test_default_grid_is_the_papers() -> None:
    assert DEFAULT_GRID.size == 31
    np.testing.assert_array_equal(DEFAULT_GRID.wavelength_nm[[0, -1]], [400.0, 700.0])


@pytest.mark.parametrize(
    ("text", "size"), [("400:700:10", 31), ("380:780:5", 81), ("400.5:402.5:0.5", 5)]
)
def test_grid_parse(text: str, size: int) -> None:
    assert WavelengthGrid.parse(text).size == size


@pytest.mark.parametrize(
    "text", ["400-700-10", "400:700", "a:b:c", "700:400:10", "400:705:10", "400:700:0"]
)
def test_grid_parse_rejects(text: str) -> None:
    with pytest.raises(SpectrumError, match="grid"):
        WavelengthGrid.parse(text)


def test_decreasing_axis_is_reversed() -> None:
    spectrum = Spectrum([700, 600, 500], [3.0, 2.0, 1.0])
    np.testing.assert_array_equal(spectrum.wavelength_nm, [500, 600, 700])
    np.testing.assert_array_equal(spectrum.values, [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("wavelengths", "values", "message"),
    [
        ([400, 500, 450], [1, 1, 1], "not strictly monotonic: 500 nm is followed by 450"),
        ([400, 500, 500], [1, 1, 1], "not strictly monotonic"),
        ([400, np.nan, 600], [1, 1, 1], "not finite"),
        ([400, 500, 600], [1, np.nan, 1], "NaN"),
        ([400, 500, 600], [1, -0.5, 1], "negative value -0.5 at 500 nm"),
        ([0.4, 0.5, 0.6], [1, 1, 1], "nanometres"),
        ([400, 500, 600], [1, 1], "shape"),
    ],
)
def test_bad_spectra_are_rejected_with_the_reason(
    wavelengths: list[float], values: list[float], message: str
) -> None:
    with pytest.raises(SpectrumError, match=message):
        Spectrum(wavelengths, values, name="lamp.csv")


def test_negative_values_can_be_clipped() -> None:
    spectrum = Spectrum([400, 500, 600], [1.0, -1e-4, 1.0], negative="clip")
    assert spectrum.values[1] == 0.0


def test_arrays_are_read_only() -> None:
    spectrum = Spectrum([400, 500, 600], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="read-only"):
        spectrum.values[0] = 5.0


def test_resample_requires_coverage() -> None:
    narrow = Spectrum([420, 500, 690], [1.0, 1.0, 1.0], name="narrow.csv")
    with pytest.raises(
        SpectrumError, match=r"narrow.csv: spectrum covers 420–690 nm but the grid needs 400–700"
    ):
        narrow.resample(DEFAULT_GRID)
    padded = narrow.resample(DEFAULT_GRID, out_of_range="zero")
    assert padded.values[0] == 0.0 and padded.values[-1] == 0.0


def test_interpolate_is_linear_interpolation() -> None:
    spectrum = Spectrum([400, 700], [0.0, 3.0])
    np.testing.assert_allclose(
        spectrum.resample(DEFAULT_GRID).values, np.linspace(0, 3, 31), atol=1e-12
    )


def test_integrate_preserves_a_constant_and_a_line() -> None:
    wavelengths = np.arange(380.0, 781.0)
    for values in (np.full(wavelengths.size, 2.5), 0.01 * wavelengths):
        projected = Spectrum(wavelengths, values).resample(DEFAULT_GRID, method="integrate")
        np.testing.assert_allclose(
            projected.values, np.interp(DEFAULT_GRID.wavelength_nm, wavelengths, values), rtol=1e-12
        )


def test_integrate_is_the_exact_discretisation_of_the_image_formation_sum(
    rng: np.random.Generator,
) -> None:
    """Σ_i e_i s_i Δ equals ∫ e s dλ when s is linear between grid nodes (spiky FL2 lamp)."""
    lamp = Spectrum.from_colour(colour.SDS_ILLUMINANTS["FL2"]).resample(
        WavelengthGrid(380, 780, 1), method="interpolate"
    )
    node_values = rng.random(DEFAULT_GRID.size)
    node_values[[0, -1]] = 0.0  # keep the truth inside the grid so the edges do not matter
    fine = np.linspace(380, 780, 400 * 64 + 1)
    truth = np.trapezoid(
        lamp.at(fine) * np.interp(fine, DEFAULT_GRID.wavelength_nm, node_values), fine
    )
    projected = lamp.resample(DEFAULT_GRID, method="integrate").values
    np.testing.assert_allclose(
        (projected * node_values).sum() * DEFAULT_GRID.step_nm, truth, rtol=1e-6
    )


def test_multispectrum_from_colour_camera() -> None:
    camera = MultiSpectrum.from_colour(colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"])
    assert camera.channels == ("red", "green", "blue")
    resampled = camera.resample(DEFAULT_GRID).normalised()
    assert resampled.values.shape == (31, 3)
    assert resampled.values.max() == pytest.approx(1.0)
    assert resampled.channel("green").values.max() == pytest.approx(1.0)


def test_csv_round_trip(tmp_path: Path) -> None:
    camera = MultiSpectrum(
        DEFAULT_GRID.wavelength_nm, np.random.default_rng(1).random((31, 3)), name="cam"
    )
    path = write_csv(tmp_path / "cam.csv", camera)
    assert path.read_text().splitlines()[0] == "wavelength_nm,r,g,b"
    back = read_multispectrum_csv(path)
    np.testing.assert_allclose(back.values, camera.values, rtol=1e-9)
    assert back.channels == ("r", "g", "b")
    lamp = Spectrum(DEFAULT_GRID.wavelength_nm, np.linspace(1, 2, 31))
    np.testing.assert_allclose(
        read_spectrum_csv(write_csv(tmp_path / "lamp.csv", lamp)).values, lamp.values
    )


@pytest.mark.parametrize(
    "content",
    [
        "400 1.0\n500 2.0\n600 3.0\n",
        "# comment\nwavelength,power\n400;1,0\n500;2,0\n600;3,0\n",
        "\ufeffnm\tW\n400\t1\n500\t2\n600\t3\n",
        "400,1.0,\n500,2.0,\n600,3.0,\n",
        "600,3\n500,2\n400,1\n",
    ],
)
def test_csv_dialects(tmp_path: Path, content: str) -> None:
    path = tmp_path / "lamp.csv"
    path.write_text(content, encoding="utf-8")
    spectrum = read_spectrum_csv(path)
    np.testing.assert_allclose(spectrum.values, [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("400,1\n500,abc\n600,3\n", r"lamp.csv line 2: 'abc' is not a number"),
        ("400,1\n500,nan\n600,3\n", "NaN"),
        ("400,1\n500,2,7\n600,3\n", "line 2: 3 fields but 2 columns"),
        ("", "no data rows"),
        ("wavelength_nm,value\n", "a header but no data rows"),
        ("400,1\n500,-2\n600,3\n", "negative value"),
        ("400,1\n350,2\n600,3\n", "not strictly monotonic"),
        ("wl,a,b\n400,1,1\n500,2,2\n", "choose one with column=NAME"),
    ],
)
def test_bad_csv_names_file_and_problem(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "lamp.csv"
    path.write_text(content, encoding="utf-8")
    with pytest.raises(SpectrumError, match=message) as info:
        read_spectrum_csv(path)
    assert "lamp.csv" in str(info.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SpectrumError, match="file not found"):
        read_spectrum_csv(tmp_path / "nope.csv")


@settings(max_examples=60, deadline=None)
@given(
    scale=st.floats(min_value=1e-6, max_value=1e6),
    seed=st.integers(min_value=0, max_value=2**31),
)
def test_resampling_is_linear_in_the_values(scale: float, seed: int) -> None:
    wavelengths = np.arange(390.0, 711.0, 1.0)
    values = np.random.default_rng(seed).random(wavelengths.size)
    for method in ("interpolate", "integrate"):
        base = Spectrum(wavelengths, values).resample(DEFAULT_GRID, method=method).values
        scaled = Spectrum(wavelengths, scale * values).resample(DEFAULT_GRID, method=method).values
        np.testing.assert_allclose(scaled, scale * base, rtol=1e-10, atol=1e-300)


def test_several_spectra_of_a_lamp_are_averaged_only_where_each_was_measured(
    tmp_path: Path,
) -> None:
    """A second file over 480–620 nm was averaged in over 400–700 nm, its end values held
    constant beyond its range, without a word; it is now refused by name, and files that do
    cover the grid are averaged on their common range only."""
    from calib.core.spectra import DEFAULT_GRID
    from calib.pipeline.inputs import load_spectrum

    wide = tmp_path / "wide.csv"
    wide.write_text("wavelength_nm,value\n" + "".join(f"{w},1\n" for w in range(380, 781, 5)))
    narrow = tmp_path / "narrow.csv"
    narrow.write_text("wavelength_nm,value\n" + "".join(f"{w},3\n" for w in range(480, 621, 5)))
    with pytest.raises(SpectrumError, match=r"narrow\.csv: covers 480–620 nm, too narrow"):
        load_spectrum((wide, narrow), "FL", DEFAULT_GRID)
    inner = tmp_path / "inner.csv"
    inner.write_text("wavelength_nm,value\n" + "".join(f"{w},3\n" for w in range(390, 721, 5)))
    mean = load_spectrum((wide, inner), "FL", DEFAULT_GRID).spectrum
    assert mean.range_nm == (390.0, 720.0)
    np.testing.assert_allclose(mean.values, 2.0)


@pytest.mark.parametrize(
    ("first_lines", "kind", "warned"),
    [
        ("wavelength_nm,value", None, None),
        ("# units: W/(sr·m²·nm)\nwavelength_nm,value", "energy", None),
        ("# units: relative spectral irradiance\nwavelength_nm,value", "energy", None),
        ("# units: relative\nwavelength_nm,value", "relative", None),
        ("wavelength_nm,counts", "counts", None),
        ("wavelength_nm,irradiance", None, None),
        ("# units: reflectance\nwavelength_nm,value", "ratio", None),
        ("# units: µmol/m²/s/nm\nwavelength_nm,value", "photon", "converted to power per nm"),
        ("# units: furlongs\nwavelength_nm,value", "unknown", "are not recognised"),
        ("# units: irradiance\nwavelength_nm,value", "energy", None),  # IES TM-27-14's words
        ("# units: photonIrradiance\nwavelength_nm,value", "photon", "converted to power"),
    ],
)
def test_a_lamp_spectrum_says_what_its_units_measure(
    tmp_path: Path, first_lines: str, kind: str | None, warned: str | None
) -> None:
    """The units of a spectrum file (its '# units:' line, or a value column named for them) are
    read as a quantity; photons are turned into power per nm (÷ λ), units nobody knows warned."""
    from calib.pipeline.inputs import load_spectrum

    wavelength = np.arange(380.0, 781.0, 5.0)
    path = tmp_path / "lamp.csv"
    rows = "\n".join(f"{w:g},1" for w in wavelength)
    path.write_text(f"{first_lines}\n{rows}\n")
    loaded = load_spectrum(path, "L", DEFAULT_GRID)
    assert loaded.units_kind == kind
    if warned is None:
        assert loaded.warnings == []
    else:
        assert len(loaded.warnings) == 1 and warned in loaded.warnings[0]
    expected = 555.0 / wavelength if kind == "photon" else np.ones_like(wavelength)
    np.testing.assert_allclose(loaded.spectrum.at(wavelength), expected, rtol=1e-12)
