"""The colour-science seam (calib.core.colour_data): the only importer of colour, lazily, and exact data."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import colour
import numpy as np
import pytest

from calib.core import colour_data
from calib.core.errors import InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.spectra import MultiSpectrum
from calib.methods.baselines.han2012 import (
    FluorescentPaints,
    render_fluorescent_chart,
    synthetic_fluorescent_paints,
)
from calib.model.charts import chart_rgb, render_chart

ROOT = Path(__file__).resolve().parents[1]
SEAM = ROOT / "calib" / "core" / "colour_data.py"


def _imports_colour(path: Path) -> bool:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(
            alias.name.split(".")[0] == "colour" for alias in node.names
        ):
            return True
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "colour":
            return True
    return False


def test_only_the_seam_imports_colour_science() -> None:
    importers = {
        str(path.relative_to(ROOT))
        for package in ("calib", "mocks")
        for path in (ROOT / package).rglob("*.py")
        if _imports_colour(path)
    }
    assert importers == {str(SEAM.relative_to(ROOT))}


def test_importing_the_seam_and_its_users_does_not_import_colour() -> None:
    code = (
        "import sys\n"
        "import calib.core.colour_data, calib.core.lamp_specs, calib.core.datasets\n"
        "import calib.model.bases, calib.model.charts, calib.spd.light_sources\n"
        "import mocks.bench.lamps\n"
        "print('colour' in sys.modules)\n"
    )
    shown = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert shown.stdout.strip() == "False"


def test_using_colour_science_leaves_numpys_print_style_alone() -> None:
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from calib.core import colour_data\n"
        "before = np.get_printoptions()\n"
        "colour_data.illuminants()\n"
        "print('colour' in sys.modules, np.get_printoptions() == before)\n"
    )
    shown = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert shown.stdout.split() == ["True", "True"]


@pytest.mark.parametrize("name", sorted(colour.SDS_COLOURCHECKERS))
def test_colorchecker_holds_colour_sciences_reflectances(name: str) -> None:
    # The two loaders this replaces stacked the patches on the first patch's axis (han2012) and
    # on the set's common axis (charts); every ColorChecker set shares one axis, so both agree.
    patches = colour.SDS_COLOURCHECKERS[name]
    first = next(iter(patches.values()))
    chart = colour_data.colorchecker(name)
    np.testing.assert_array_equal(chart.wavelength_nm, np.asarray(first.wavelengths))
    np.testing.assert_array_equal(
        chart.values, np.stack([np.asarray(sd.values) for sd in patches.values()], axis=1)
    )
    assert chart.channels == tuple(patches)
    assert chart.name == f"ColorChecker ({name})"


def test_an_unknown_colorchecker_names_the_known_ones() -> None:
    with pytest.raises(InputError, match="BabelColor Average"):
        colour_data.colorchecker("Macbeth 1976")


def test_cie_test_colour_samples_are_interpolated_to_their_common_range() -> None:
    samples = colour_data.cie_test_colour_samples("CIE 2024")
    # TCS15 starts at 380 nm, the others at 360 nm: the set is cut to what all of them cover.
    assert samples.range_nm == (380.0, 780.0)
    assert samples.values.shape[1] == len(colour.quality.datasets.SDS_TCS["CIE 2024"])
    tcs01 = colour.quality.datasets.SDS_TCS["CIE 2024"]["TCS01"]
    np.testing.assert_allclose(
        samples.values[:, 0], np.interp(samples.wavelength_nm, tcs01.wavelengths, tcs01.values)
    )


def test_lamps_by_name_are_colour_sciences_tables() -> None:
    for name, table in (("FL2", colour.SDS_ILLUMINANTS), ("Kinoton 75P", colour.SDS_LIGHT_SOURCES)):
        lamp = colour_lamp(name)
        np.testing.assert_array_equal(lamp.values, np.asarray(table[name].values))
        np.testing.assert_array_equal(lamp.wavelength_nm, np.asarray(table[name].wavelengths))
        assert lamp.name == name
    with pytest.raises(InputError, match="no illuminant or light source named 'FL99'"):
        colour_lamp("FL99")


def test_colour_matching_functions_are_copies_with_their_negative_lobes() -> None:
    wavelength, values = colour_data.colour_matching_functions(
        "Wright & Guild 1931 2 Degree RGB CMFs"
    )
    assert values.shape == (wavelength.size, 3) and values.min() < 0
    values[:] = 0.0
    again = colour_data.colour_matching_functions("Wright & Guild 1931 2 Degree RGB CMFs")[1]
    assert again.min() < 0


def test_cie_daylight_is_named_and_bounded() -> None:
    assert colour_data.cie_daylight(6504.0).name == "D65"
    with pytest.raises(InputError, match="4000–25000 K"):
        colour_data.cie_daylight(3000.0)


def _camera() -> MultiSpectrum:
    wavelength = np.arange(400.0, 701.0, 10.0)
    peaks = (600.0, 540.0, 460.0)
    return MultiSpectrum(
        wavelength,
        np.stack([np.exp(-0.5 * ((wavelength - peak) / 40.0) ** 2) for peak in peaks], axis=1),
    )


def test_the_fluorescent_chart_renders_its_reflected_light_as_any_chart() -> None:
    camera, light = _camera(), colour_data.cie_daylight(6500.0)
    paints = synthetic_fluorescent_paints(np.random.default_rng(5))
    dark = FluorescentPaints(
        paints.absorption, paints.emission, paints.reflectance, np.zeros_like(paints.quantum_yield)
    )
    reference = colour_data.colorchecker()
    chart = render_fluorescent_chart(dark, reference, camera, light)
    np.testing.assert_array_equal(
        chart.reference_rgb, render_chart(reference, light, camera).patch_rgb
    )
    np.testing.assert_array_equal(
        chart.fluorescent_rgb, render_chart(paints.reflectance, light, camera).patch_rgb
    )


def test_chart_rgb_is_the_integral_of_light_patch_and_camera() -> None:
    # Against a brute-force trapezoid on a 0.05 nm axis over the range all three cover.
    camera, light = _camera(), colour_data.cie_daylight(5000.0)
    reference = colour_data.colorchecker()
    axis = np.arange(400.0, 700.0 + 0.025, 0.05)
    sensitivity = np.stack(
        [np.interp(axis, camera.wavelength_nm, camera.values[:, k]) for k in range(3)], axis=1
    )
    patches = np.stack(
        [np.interp(axis, reference.wavelength_nm, column) for column in reference.values.T], 1
    )
    expected = np.trapezoid(
        (patches * light.at(axis)[:, None])[:, :, None] * sensitivity[:, None, :], axis, axis=0
    )
    np.testing.assert_allclose(chart_rgb(reference, light, camera), expected, rtol=2e-4)
