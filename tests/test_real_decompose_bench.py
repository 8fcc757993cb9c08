"""The pieces ``bench/real_decompose.py`` takes the real RMS apart with (decision 0100): a curve common
to the three channels (η, a lamp's or the optics' error) is recovered and, divided out, leaves
nothing; a channel-specific error is not absorbed by it; the perturbed mapping moves the wavelength
by exactly what it says and stays invertible. Synthetic curves only (no shared data)."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from calib.core.mapping import TiltedGrating


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "bench"))
        import real_decompose

        return real_decompose


def _camera(wavelength: np.ndarray) -> np.ndarray:
    centres, widths = (600.0, 530.0, 455.0), (45.0, 40.0, 30.0)
    return np.stack(
        [np.exp(-0.5 * ((wavelength - c) / w) ** 2) for c, w in zip(centres, widths, strict=True)],
        axis=1,
    )


def test_a_curve_common_to_the_channels_is_recovered_and_divides_out(bench: ModuleType) -> None:
    wavelength = bench.WAVELENGTH
    truth = _camera(wavelength)
    eta = 0.6 + 0.4 * np.sin((wavelength - 380.0) / 200.0)
    curves = 3.0 * truth * eta[:, None]
    assert bench.rms(bench.curve_difference(curves, truth, per_channel=False)) > 0.01
    ratio, _ = bench.common_ratio(curves, truth, per_channel=False)
    # Up to the score's free scale, r is η.
    assert np.allclose(ratio / ratio.mean(), eta / eta.mean(), rtol=1e-6)
    assert (
        bench.rms(bench.curve_difference(curves / ratio[:, None], truth, per_channel=False)) < 1e-9
    )
    smooth, wiggle = bench.smooth_ratio(ratio, truth, 4, per_channel=False)
    assert wiggle < 0.01
    assert np.allclose(smooth / smooth.mean(), eta / eta.mean(), rtol=0.02)


def test_an_error_of_one_channel_is_not_taken_for_eta(bench: ModuleType) -> None:
    wavelength = bench.WAVELENGTH
    truth = _camera(wavelength)
    curves = truth.copy()
    # The green channel alone 30 % high where the red is as strong: no common curve explains it.
    curves[:, 1] *= 1.0 + 0.3 * ((wavelength >= 560) & (wavelength <= 620))
    before = bench.rms(bench.curve_difference(curves, truth, per_channel=False))
    ratio, _ = bench.common_ratio(curves, truth, per_channel=False)
    left = bench.rms(bench.curve_difference(curves / ratio[:, None], truth, per_channel=False))
    assert left > 0.3 * before > 0.005


@pytest.mark.parametrize(("offset", "slope"), [(0.5, 0.0), (-1.0, 0.002)])
def test_the_perturbed_mapping_moves_the_wavelength_by_what_it_says(
    bench: ModuleType, offset: float, slope: float
) -> None:
    base = TiltedGrating(
        dispersion_nm_per_px=0.165,
        focal_length_px=10869.0,
        incidence_deg=-6.24,
        zero_order_px=-2153.7,
        orientation=1,
    )
    model = bench.ShiftedModel(base, offset, slope)
    pixel = np.linspace(100.0, 2400.0, 7)
    before = base.wavelength_nm(pixel)
    after = model.wavelength_nm(pixel)
    assert np.allclose(after - before, offset + slope * (before - 550.0))
    assert np.allclose(model.pixel_at(after), pixel, atol=1e-6)
    assert np.allclose(model.dispersion_at(pixel), base.dispersion_at(pixel) * (1 + slope))
