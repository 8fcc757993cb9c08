"""calib.spd.light_sources: the library, recognition, CCT and white-balance gains."""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.spectra import MultiSpectrum, Spectrum
from calib.spd.light_sources import (
    EQUIVALENT_DISTANCE,
    LightSourceLibrary,
    camera_white_balance,
    colour_library,
    complete_outside_range,
    correlated_colour_temperature,
    recognise_light_source,
    srgb_white_balance_from_cct,
)
from tests.spd_scenes import nikon_camera


def test_the_colour_library_merges_identical_sources() -> None:
    library = colour_library()
    assert len(library) == 112  # 115 names: A = SA, C = SC, Incandescent = 60 A/W
    assert library.entry("SA").name == "A"
    assert set(library.entry("C").names) == {"C", "SC"}
    with pytest.raises(InputError, match="no source named"):
        library.entry("Sodium street lamp")


@pytest.mark.parametrize("metric", ["l2", "weighted"])
@pytest.mark.parametrize("name", ["LED-B3", "FL11", "HP1", "Kinoton 75P"])
def test_a_library_spectrum_recognises_itself(name: str, metric: str) -> None:
    spectrum = colour_lamp(name)
    cut = Spectrum(
        np.arange(410.0, 681.0), spectrum.at(np.arange(410.0, 681.0)) * 3.7, name="measured"
    )
    recognition = recognise_light_source(cut, metric=metric)  # type: ignore[arg-type]
    assert recognition.name == name
    assert recognition.distance < 1e-3 and recognition.margin > 0.01
    assert recognition.range_nm == (415.0, 675.0)  # nodes whose 5 nm hats lie inside
    assert recognition.ranking[0] == (name, recognition.distance)
    assert not recognition.instrument_view


def test_sources_closer_than_the_instrument_can_tell_are_equivalent() -> None:
    wavelength = np.arange(380.0, 731.0, 5.0)
    base = 1.0 + 0.5 * np.sin(wavelength / 40.0)
    tilt = 1.0 + 0.8 * EQUIVALENT_DISTANCE * (wavelength - 555.0) / 175.0  # below the threshold
    library = LightSourceLibrary.from_spectra(
        [
            ("one", "test", Spectrum(wavelength, base)),
            ("near", "test", Spectrum(wavelength, base * tilt)),
            ("other", "test", Spectrum(wavelength, base * (1 + 0.3 * (wavelength > 550)))),
            ("scaled", "test", Spectrum(wavelength, 7.0 * base)),
        ]
    )
    assert library.entry("scaled").name == "one"  # the same shape is an alias
    recognition = recognise_light_source(Spectrum(wavelength, base * 2), library)
    assert recognition.name == "one" and recognition.aliases == ("scaled",)
    assert recognition.equivalents == ("near",)
    assert recognition.margin > 0.05  # measured against "other", not the equivalent
    with pytest.raises(InputError, match="metric"):
        recognise_light_source(Spectrum(wavelength, base), library, metric="cosine")  # type: ignore[arg-type]


def test_an_instrument_view_is_applied_to_the_nearest_entries_only() -> None:
    seen: list[str] = []

    def view(spectrum: Spectrum) -> Spectrum:
        seen.append(spectrum.name)
        return spectrum

    recognition = recognise_light_source(colour_lamp("D65"), view=view, view_top=5)
    assert len(seen) == 5 and recognition.name == "D65" and recognition.instrument_view


@pytest.mark.parametrize(("name", "expected_k"), [("D65", 6504.0), ("A", 2856.0), ("D50", 5003.0)])
def test_cct_agrees_with_the_standard_values(name: str, expected_k: float) -> None:
    result = correlated_colour_temperature(colour_lamp(name))
    assert result.cct_k["Ohno 2013"] == pytest.approx(expected_k, abs=3.0)
    assert result.cct_k["Robertson 1968"] == pytest.approx(expected_k, abs=5.0)
    # McCamy's cubic is good to a few kelvin near the Planckian locus in this range.
    assert result.cct_k["McCamy 1992"] == pytest.approx(expected_k, abs=10.0)
    assert abs(result.duv) < 0.01


def test_cct_refuses_unknown_methods_and_dark_spectra() -> None:
    with pytest.raises(InputError, match="unknown CCT method"):
        correlated_colour_temperature(colour_lamp("A"), methods=["Guess 2024"])
    with pytest.raises(InputError, match="no luminance"):
        correlated_colour_temperature(Spectrum([800.0, 900.0], [1.0, 1.0]))


def test_camera_gains_neutralise_the_lamp() -> None:
    camera = nikon_camera()
    lamp = colour_lamp("A")
    gains = camera_white_balance(lamp, camera)
    assert gains[1] == 1.0 and gains[0] < 1.0 < gains[2]  # warm light: much red, little blue
    wavelength = np.arange(380.0, 780.1, 0.5)  # where lamp and camera overlap
    rgb = [
        np.trapezoid(lamp.at(wavelength) * camera.channel(c).at(wavelength), wavelength)
        for c in camera.channels
    ]
    np.testing.assert_allclose(gains * rgb, rgb[1], rtol=1e-9)
    flat = MultiSpectrum([400.0, 700.0], np.ones((2, 3)))
    np.testing.assert_allclose(camera_white_balance(lamp, flat), 1.0)


def test_srgb_gains_follow_the_colour_temperature() -> None:
    warm = srgb_white_balance_from_cct(3000.0)
    assert warm[1] == 1.0 and warm[0] < 1.0 < warm[2]
    np.testing.assert_allclose(srgb_white_balance_from_cct(6504.0), 1.0, atol=0.08)
    with pytest.raises(InputError, match="sRGB gamut"):
        srgb_white_balance_from_cct(1700.0)


def test_completion_keeps_the_measurement_and_borrows_the_ends() -> None:
    reference = colour_lamp("D65")
    measured = Spectrum(np.arange(420.0, 661.0), 2.0 * reference.at(np.arange(420.0, 661.0)))
    completed = complete_outside_range(measured, reference)
    np.testing.assert_allclose(completed.at(measured.wavelength_nm), measured.values)
    assert completed.range_nm == reference.range_nm
    np.testing.assert_allclose(completed.at([400.0, 700.0]), 2.0 * reference.at([400.0, 700.0]))
