"""Physical grating efficiency models (calib.model.gratings)."""

from __future__ import annotations

import doctest
from pathlib import Path

import numpy as np
import pytest

import calib.model.gratings as gratings_module
from calib.core.errors import InputError
from calib.core.spectra import Spectrum
from calib.model.gratings import (
    BlazedGrating,
    CatalogueGrating,
    SinusoidalPhaseGrating,
    draw_grating,
    fit_blaze,
)

WAVELENGTH_NM = np.linspace(380.0, 780.0, 81)


def test_docstring_examples_hold() -> None:
    assert doctest.testmod(gratings_module).failed == 0


def test_sinusoidal_orders_conserve_energy() -> None:
    grating = SinusoidalPhaseGrating(1.6)
    total = grating.efficiency(0, WAVELENGTH_NM) + 2 * sum(
        grating.efficiency(m, WAVELENGTH_NM) for m in range(1, 30)
    )
    np.testing.assert_allclose(total, 1.0, atol=1e-12)
    np.testing.assert_allclose(grating.efficiency(-1, 500.0), grating.efficiency(1, 500.0))


def test_sinusoidal_phase_scales_inversely_with_wavelength() -> None:
    # φ(λ) = φ₀ λ₀/λ: the grating at 2λ₀ behaves like one of half the phase at λ₀.
    grating = SinusoidalPhaseGrating(1.2, reference_nm=450.0)
    half = SinusoidalPhaseGrating(0.6, reference_nm=450.0)
    for order in (0, 1, 2):
        np.testing.assert_allclose(
            grating.efficiency(order, 900.0), half.efficiency(order, 450.0), rtol=1e-12
        )
    # Below the 1.84 rad optimum the first order fades towards the red, the 0th order brightens.
    first = grating.efficiency(1, WAVELENGTH_NM)
    zeroth = grating.efficiency(0, WAVELENGTH_NM)
    assert np.all(np.diff(first) < 0) and np.all(np.diff(zeroth) > 0)


def test_blazed_grating_puts_all_light_in_the_first_order_at_its_blaze() -> None:
    grating = BlazedGrating(520.0)
    np.testing.assert_allclose(
        [grating.efficiency(m, 520.0) for m in (0, 1, 2)], [0.0, 1.0, 0.0], atol=1e-15
    )
    total = sum(grating.efficiency(m, WAVELENGTH_NM) for m in range(-3000, 3001))
    np.testing.assert_allclose(total, 1.0, atol=2e-4)
    # Half a wave of ramp (λ = 2 λ_B): 0th and 1st orders take 4/π² each.
    np.testing.assert_allclose(grating.efficiency(0, 1040.0), 4 / np.pi**2, rtol=1e-12)
    np.testing.assert_allclose(grating.efficiency(1, 1040.0), 4 / np.pi**2, rtol=1e-12)


def test_efficiency_spectrum_is_a_named_spectrum() -> None:
    spectrum = SinusoidalPhaseGrating(1.0).efficiency_spectrum(2, [400.0, 550.0, 700.0])
    assert isinstance(spectrum, Spectrum)
    assert "order 2" in spectrum.name
    np.testing.assert_allclose(spectrum.values[1], 0.114903**2, rtol=1e-5)
    default = BlazedGrating(500.0).efficiency_spectrum(1)
    assert default.range_nm == (300.0, 1100.0)


def test_draws_are_deterministic_and_inside_their_ranges() -> None:
    phases = [
        SinusoidalPhaseGrating.draw(np.random.default_rng(k)).peak_phase_rad for k in range(50)
    ]
    blazes = [BlazedGrating.draw(np.random.default_rng(k)).blaze_nm for k in range(50)]
    assert min(phases) >= 0.5 and max(phases) <= 1.8
    assert min(blazes) >= 400.0 and max(blazes) <= 650.0
    assert draw_grating("sinusoidal", np.random.default_rng(3)) == draw_grating(
        "sinusoidal", np.random.default_rng(3)
    )
    with pytest.raises(InputError, match="maker's efficiency curve"):
        draw_grating("catalogue", np.random.default_rng(0))
    with pytest.raises(InputError, match="unknown grating kind"):
        draw_grating("ruled", np.random.default_rng(0))  # type: ignore[arg-type]


def test_bad_parameters_and_orders_are_refused() -> None:
    with pytest.raises(InputError, match="peak_phase_rad"):
        SinusoidalPhaseGrating(0.0)
    with pytest.raises(InputError, match="blaze_nm"):
        BlazedGrating(float("nan"))
    with pytest.raises(InputError, match="integer"):
        BlazedGrating(500.0).efficiency(1.5, 500.0)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="> 0 nm"):
        BlazedGrating(500.0).efficiency(1, [500.0, -1.0])


def test_fit_blaze_recovers_a_scaled_blazed_curve() -> None:
    axis = np.arange(300.0, 901.0, 25.0)
    curve = Spectrum(axis, 0.7 * BlazedGrating(537.0).efficiency(1, axis))
    blaze, scale = fit_blaze(curve)
    assert blaze.blaze_nm == pytest.approx(537.0, abs=0.01)
    assert scale == pytest.approx(0.7, rel=1e-4)


def test_catalogue_curve_from_a_file_in_per_cent(tmp_path: Path) -> None:
    path = tmp_path / "maker.csv"
    axis = np.arange(300.0, 901.0, 25.0)
    per_cent = 100 * 0.65 * BlazedGrating(510.0).efficiency(1, axis)
    path.write_text(
        "w, efficiency\n"
        + "".join(f"{w:g}, {v:.4f}\n" for w, v in zip(axis, per_cent, strict=True))
    )
    grating = CatalogueGrating.from_file(path)
    assert grating.efficiency(1, 500.0) == pytest.approx(per_cent[8] / 100, abs=1e-6)
    assert grating.blaze.blaze_nm == pytest.approx(510.0, abs=0.05)
    np.testing.assert_allclose(
        grating.efficiency(0, [450.0, 700.0]),
        0.65 * BlazedGrating(510.0).efficiency(0, [450.0, 700.0]),
        rtol=1e-3,
    )
    assert grating.draw(np.random.default_rng(0)) is grating
    assert grating.to_dict()["kind"] == "catalogue"
    with pytest.raises(InputError, match="covers 300–900 nm"):
        grating.efficiency(1, [250.0, 500.0])


def test_catalogue_refuses_efficiencies_above_one(tmp_path: Path) -> None:
    path = tmp_path / "maker.csv"
    path.write_text("400,1.2\n500,1.3\n600,1.1\n")
    with pytest.raises(InputError, match="per cent"):
        CatalogueGrating.from_file(path, percent=False)
    with pytest.raises(InputError, match="two columns"):
        (tmp_path / "three.csv").write_text("400,1,2\n500,1,2\n")
        CatalogueGrating.from_file(tmp_path / "three.csv")


@pytest.mark.shared_data
def test_the_lhires_catalogue_curve_fits_a_visible_blaze(shared_real_grating: Path) -> None:
    path = shared_real_grating / "rrogge-canon-eos-10d" / "LHires III Grating Efficiency 150.csv"
    grating = CatalogueGrating.from_file(path)
    assert grating.efficiency(1, 530.0) == pytest.approx(0.67, abs=1e-9)
    # The scalar blazed model describes the maker's curve: a visible blaze, a 0.5–0.8 scale.
    assert 450.0 < grating.blaze.blaze_nm < 600.0
    assert 0.5 < grating.blaze_scale < 0.8
    visible = np.arange(400.0, 701.0, 25.0)
    model = grating.blaze_scale * grating.blaze.efficiency(1, visible)
    assert np.max(np.abs(model - grating.efficiency(1, visible))) < 0.08
