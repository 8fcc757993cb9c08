"""calib.methods.baselines.han2012: each step against synthetic truth, and the paper's finding under unknown light.

Synthetic protocol: 16 seeded fluorescent paints (:func:`synthetic_fluorescent_paints`) and a
ColorChecker, seen by a camera under a light the estimator is not told about. Cameras: colour-science's
built-ins (always available) and, when the shared data is present, measured cameras with a basis of
the *other* cameras (the paper's footnote 2).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from calib.core.colour_data import cie_daylight, colorchecker
from calib.core.datasets import SOLOMATOV, colour_science_cameras, load_collection
from calib.core.errors import EstimationError, InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum
from calib.methods import estimate
from calib.methods.baselines.han2012 import (
    FOURIER,
    FluorescentPaints,
    Han2012Options,
    SensitivityBasis,
    chromaticity_system,
    estimate_han2012,
    recover_daylight,
    recover_han2012,
    reflectance_basis,
    render_fluorescent_chart,
    separate_fluorescence,
    solve_sensitivity,
    synthetic_fluorescent_paints,
)
from calib.model.bases import CameraBasis, default_camera_basis, fourier_basis
from calib.spd.light_sources import correlated_colour_temperature

#: Daylights the estimator is not told about (CCT in K).
UNKNOWN_DAYLIGHTS_K = (4500.0, 5500.0, 6500.0, 8000.0, 12000.0)


def truth_on_grid(camera: MultiSpectrum) -> np.ndarray:
    values = np.asarray(camera.resample(DEFAULT_GRID, out_of_range="zero").values)
    return np.asarray(values / values.max())


def without_reflection(paints: FluorescentPaints) -> FluorescentPaints:
    """The same paints with zero reflectance: what they emit, alone."""
    reflectance = paints.reflectance
    zero = MultiSpectrum(
        reflectance.wavelength_nm, np.zeros_like(reflectance.values), reflectance.channels
    )
    return dataclasses.replace(paints, reflectance=zero)


def ohno(spectrum: Spectrum) -> float:
    return correlated_colour_temperature(spectrum).cct_k["Ohno 2013"]


# ----------------------------------------------------------------------------------- the pieces


def test_paints_are_seeded_and_physical() -> None:
    first = synthetic_fluorescent_paints(np.random.default_rng(1))
    again = synthetic_fluorescent_paints(np.random.default_rng(1))
    np.testing.assert_array_equal(first.emission.values, again.emission.values)
    wavelength = first.emission.wavelength_nm
    areas = np.trapezoid(first.emission.values, wavelength, axis=0)
    np.testing.assert_allclose(areas, 1.0, rtol=1e-6)
    peaks = wavelength[np.argmax(first.emission.values, axis=0)]
    absorbed = wavelength[np.argmax(first.absorption.values * (wavelength[:, None] > 400), axis=0)]
    assert np.all(absorbed < peaks)  # Stokes shift: absorbed at shorter wavelengths
    assert np.all((first.reflectance.values > 0) & (first.reflectance.values < 1))
    assert np.all((first.quantum_yield > 0) & (first.quantum_yield < 1))


def test_the_reflectance_basis_spans_a_colorchecker() -> None:
    basis = reflectance_basis(DEFAULT_GRID, 8)
    np.testing.assert_allclose(basis.T @ basis, np.eye(8), atol=1e-10)
    chart = colorchecker().resample(DEFAULT_GRID).values
    fitted = basis @ (basis.T @ chart)
    assert float(np.sqrt(np.mean((fitted - chart) ** 2))) < 0.02  # the chart is not in its data


def test_separation_recovers_the_fluorescent_part() -> None:
    camera = colour_science_cameras()[0].sensitivity
    paints = synthetic_fluorescent_paints(np.random.default_rng(2))
    light = cie_daylight(6500.0)
    reference = colorchecker()
    chart = render_fluorescent_chart(paints, reference, camera, light)
    pure = render_fluorescent_chart(without_reflection(paints), reference, camera, light)
    separation = separate_fluorescence(chart)
    np.testing.assert_allclose(
        separation.fluorescent_rgb + separation.reflective_rgb, chart.fluorescent_rgb
    )
    error = separation.fluorescent_rgb - pure.fluorescent_rgb
    scale = chart.fluorescent_rgb.sum(axis=1, keepdims=True)
    assert float(np.abs(error / scale).max()) < 0.05  # within 5 % of each patch's signal
    assert np.abs(separation.reference_residual).max() < 0.02 * chart.reference_rgb.max()


def test_a_camera_inside_the_basis_is_recovered_exactly() -> None:
    """Eq. 12–16 are exact when the camera lies in the Fourier span (the implementation check)."""
    coarse = fourier_basis(DEFAULT_GRID, 9)
    truth = truth_on_grid(colour_science_cameras()[0].sensitivity)
    curves = coarse @ np.linalg.lstsq(coarse, truth, rcond=None)[0]
    curves -= min(0.0, float(curves.min()))  # the constant term keeps it in the span
    # On the grid's nodes, linear between them: exactly what the estimator assumes.
    camera = MultiSpectrum(DEFAULT_GRID.wavelength_nm, curves)
    paints = synthetic_fluorescent_paints(np.random.default_rng(3))
    pure = render_fluorescent_chart(
        without_reflection(paints), colorchecker(), camera, cie_daylight(6500)
    )
    basis = SensitivityBasis.fourier(DEFAULT_GRID, 9)
    integrals = basis.emission_integrals(paints.emission)
    coefficients = np.linalg.lstsq(coarse, curves, rcond=None)[0]  # (9, 3)
    predicted = np.einsum("cpm,mc->pc", integrals, coefficients)
    chromaticity = predicted / predicted.sum(axis=1, keepdims=True)
    # The integrals are those of the rendering (Eq. 4 up to each patch's scale) …
    rendered = pure.fluorescent_rgb / pure.fluorescent_rgb.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(chromaticity, rendered, atol=2e-4)
    # … and the algebra returns a camera with exactly these chromaticities. Functions that no
    # emission band sees (t_p · v ≈ 0 for every paint) are invisible to the data, so the camera
    # itself comes back only up to them: that is what the smoothness term is for.
    system = chromaticity_system(chromaticity, integrals)
    for normalise in (None, integrals):
        solution, _ = solve_sensitivity(system, basis.curvature, (0, 0, 0), normalise)
        found = np.einsum("cpm,cm->pc", integrals, solution.reshape(3, 9))
        np.testing.assert_allclose(
            found / found.sum(axis=1, keepdims=True), chromaticity, atol=1e-4
        )
        estimate_curves = np.einsum("cfm,cm->fc", basis.vectors, solution.reshape(3, 9))
        assert relative_error(estimate_curves, curves) < 0.02


def test_daylight_is_recovered_with_the_true_camera() -> None:
    camera = colour_science_cameras()[0].sensitivity
    reference = colorchecker()
    for cct_k in UNKNOWN_DAYLIGHTS_K[:4]:
        light = cie_daylight(cct_k)
        chart = render_fluorescent_chart(
            synthetic_fluorescent_paints(np.random.default_rng(4)), reference, camera, light
        )
        daylight = recover_daylight(chart.reference_rgb, reference, truth_on_grid(camera))
        assert abs(ohno(daylight) - ohno(light)) < 100.0


def test_chart_validation_and_refusals() -> None:
    paints = synthetic_fluorescent_paints(np.random.default_rng(5))
    reference = colorchecker()
    camera = colour_science_cameras()[0].sensitivity
    chart = render_fluorescent_chart(paints, reference, camera, cie_daylight(6500))
    with pytest.raises(InputError, match=r"fluorescent RGB has shape \(15, 3\)"):
        dataclasses.replace(chart, fluorescent_rgb=chart.fluorescent_rgb[:15])
    small = dataclasses.replace(
        chart,
        reference_rgb=chart.reference_rgb[:5],
        reference_reflectance=MultiSpectrum(
            reference.wavelength_nm, reference.values[:, :5], reference.channels[:5]
        ),
    )
    with pytest.raises(InputError, match="5 reference patches cannot fix 8"):
        recover_han2012(small)
    with pytest.raises(InputError, match="smoothness"):
        Han2012Options(smoothness=(1.0, -1.0, 0.0))
    with pytest.raises(InputError, match="normalisation"):
        Han2012Options(normalisation="none")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="noise needs"):
        render_fluorescent_chart(paints, reference, camera, cie_daylight(6500), noise_fraction=0.01)
    with pytest.raises(InputError, match="4000–25000 K"):
        cie_daylight(3000.0)
    # Paints that only reflect (all signal explained by their reflectance): said, not guessed.
    reflective_only = dataclasses.replace(
        chart, fluorescent_rgb=separate_fluorescence(chart).reflective_rgb
    )
    with pytest.raises(EstimationError, match="lacks the short wavelengths"):
        recover_han2012(reflective_only)


def test_registered_behind_the_front_function() -> None:
    camera = colour_science_cameras()[0].sensitivity
    rng = np.random.default_rng(6)
    chart = render_fluorescent_chart(
        synthetic_fluorescent_paints(rng),
        colorchecker(),
        camera,
        cie_daylight(6500),
        rng=rng,
        noise_fraction=0.001,
    )
    result = estimate([chart], method="han2012")
    assert result.method == "han2012" and result.sensitivity.shape == (31, 3)
    assert float(np.abs(result.sensitivity).max()) == pytest.approx(1.0)
    assert result.diagnostics["illuminant"] is not None
    assert result.to_dict()["diagnostics"]["basis"] == "Fourier, 9 terms"
    with pytest.raises(InputError, match="fluorescent and a reference chart"):
        estimate([], method="han2012")
    # the front function adds the σ budget; without it, the method's own result
    assert (
        estimate_han2012([chart]).to_dict()
        == estimate([chart], method="han2012", budget=None).to_dict()
    )


# ---------------------------------------------------------------------- the paper's finding


def _run(
    camera: MultiSpectrum,
    light: Spectrum,
    seed: int,
    basis: CameraBasis | None = None,
    options: Han2012Options = Han2012Options(),
) -> tuple[float, float | None]:
    """RE of the sensitivity and CCT error of the recovered daylight (None for non-daylights)."""
    rng = np.random.default_rng(seed)
    paints = synthetic_fluorescent_paints(np.random.default_rng(seed // 100))  # one chart
    chart = render_fluorescent_chart(
        paints, colorchecker(), camera, light, rng=rng, noise_fraction=0.001
    )
    result = recover_han2012(chart, basis=FOURIER if basis is None else basis, options=options)
    error = relative_error(result.sensitivity, truth_on_grid(camera))
    cct_error = None
    if result.illuminant is not None and light.name.startswith("D"):
        cct_error = ohno(result.illuminant) - ohno(light)
    return error, cct_error


@pytest.mark.parametrize("camera_index", [0, 2])
def test_the_fourier_estimate_does_not_depend_on_the_unknown_daylight(camera_index: int) -> None:
    """Han et al.'s claim with the paper's own basis: the light is not needed."""
    camera = colour_science_cameras()[camera_index].sensitivity
    errors = [
        _run(camera, cie_daylight(cct), 100 * camera_index + k)[0]
        for k, cct in enumerate(UNKNOWN_DAYLIGHTS_K)
    ]
    assert max(errors) < 0.25, errors
    assert max(errors) - min(errors) < 0.10, errors  # the same camera whatever the daylight


def test_with_a_camera_basis_it_works_under_any_light(shared_camera_data: Path) -> None:
    """Footnote 2: eigenvectors of other cameras. Daylights, a fluorescent tube, an LED, tungsten."""
    records = load_collection(SOLOMATOV, shared_camera_data)
    lights = [cie_daylight(cct) for cct in UNKNOWN_DAYLIGHTS_K] + [
        colour_lamp(name) for name in ("FL2", "LED-B3", "A")
    ]
    for record in records[3::15]:  # three measured cameras, each left out of its basis
        basis = default_camera_basis(
            DEFAULT_GRID, data_dir=shared_camera_data, exclude=[record.name]
        )
        results = [
            _run(
                record.sensitivity,
                light,
                1000 + k,
                basis=basis,
                options=Han2012Options(smoothness=(0.03, 0.03, 0.01)),
            )
            for k, light in enumerate(lights)
        ]
        errors = [error for error, _ in results]
        assert max(errors) < 0.20 and float(np.mean(errors)) < 0.12, (record.name, errors)
        cct_errors = [abs(c) for _, c in results if c is not None]
        assert float(np.median(cct_errors)) < 1500.0, (record.name, cct_errors)
