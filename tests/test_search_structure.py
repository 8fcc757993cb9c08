"""The searches' starts made cheaper with the same answers (decision 0130): the LED search's
correlation scores both orientations from one transform of the model per dispersion; the line
match judges each line set's placements at once."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy import signal

from calib.core.mapping import QuadraticMapping
from calib.core.spectra import DEFAULT_GRID
from calib.wavelength.peaks import (
    Peak,
    _curves_through,
    _local_maxima,
    coarse_mapping_candidates,
    match_peak_hypotheses,
)


def _scene(mirrored: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A three-channel model per nm and the profile it gives under λ = 0.8 p + 372 (noisy)."""
    model_nm = np.arange(380.0, 721.0)
    centres, widths = (450.0, 540.0, 610.0), (30.0, 35.0, 32.0)
    model = np.stack(
        [np.exp(-0.5 * ((model_nm - c) / w) ** 2) for c, w in zip(centres, widths, strict=True)],
        axis=1,
    )
    model[(model_nm < DEFAULT_GRID.start_nm) | (model_nm > DEFAULT_GRID.stop_nm)] = 0.0
    pixel = np.arange(460.0)
    wavelengths = 0.8 * pixel + 372.0
    profile = np.stack(
        [np.interp(wavelengths, model_nm, model[:, k], left=0.0, right=0.0) for k in range(3)],
        axis=1,
    )
    profile += np.random.default_rng(3).normal(0.0, 0.01, profile.shape)
    return pixel, (profile[::-1] if mirrored else profile), model_nm, model


def _direct_ncc(
    pixel: np.ndarray,
    profile: np.ndarray,
    model_nm: np.ndarray,
    model: np.ndarray,
    slope: float,
    offset: float,
) -> float:
    """The normalised cross-correlation of one placement, channel by channel, from its
    definition: the model sampled at the placement's pixels, both curves centred."""
    wavelengths = slope * pixel + offset
    expected = np.stack(
        [np.interp(wavelengths, model_nm, model[:, k], left=0.0, right=0.0) for k in range(3)],
        axis=1,
    )
    a = profile - profile.mean(axis=0)
    b = expected - expected.mean(axis=0)
    return float(
        np.mean(np.sum(a * b, axis=0) / np.linalg.norm(a, axis=0) / np.linalg.norm(b, axis=0))
    )


@pytest.mark.parametrize("mirrored", [False, True])
def test_each_candidates_score_is_its_placements_correlation(mirrored: bool) -> None:
    pixel, profile, model_nm, model = _scene(mirrored)
    found = coarse_mapping_candidates(
        pixel, profile, model_nm, model, n_candidates=4, n_dispersions=24, allow_reversed=True
    )
    best = found[0]
    # The right placement (the mirrored profile: the falling one) leads.
    assert np.sign(best.b) == (-1.0 if mirrored else 1.0)
    truth = 0.8 * pixel + 372.0
    if mirrored:
        truth = truth[::-1]
    assert np.max(np.abs(best.wavelength_nm(pixel) - truth)) < 6.0
    for mapping in found:
        direct = _direct_ncc(pixel, profile, model_nm, model, mapping.b, mapping.c)
        assert mapping.details["ncc"] == pytest.approx(direct, abs=1e-9)


def test_both_orientations_share_one_transform_of_the_model(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Per dispersion: one forward transform (the model) and one inverse per orientation; the
    window sums are running sums (before: five transforms per dispersion and orientation)."""
    pixel, profile, model_nm, model = _scene(False)
    calls = {"rfft": 0, "irfft": 0}
    rfft, irfft = np.fft.rfft, np.fft.irfft

    def counted_rfft(*args: Any, **kwargs: Any) -> Any:
        calls["rfft"] += 1
        return rfft(*args, **kwargs)

    def counted_irfft(*args: Any, **kwargs: Any) -> Any:
        calls["irfft"] += 1
        return irfft(*args, **kwargs)

    monkeypatch.setattr(np.fft, "rfft", counted_rfft)
    monkeypatch.setattr(np.fft, "irfft", counted_irfft)
    dispersions = 12
    coarse_mapping_candidates(
        pixel, profile, model_nm, model, n_dispersions=dispersions, allow_reversed=True
    )
    # The profile's two transforms, then at most one of the model and two inverses a dispersion.
    assert calls["rfft"] <= 2 + dispersions
    assert calls["irfft"] <= 2 * dispersions
    assert calls["irfft"] > 0


def test_local_maxima_follow_scipys_rule() -> None:
    rng = np.random.default_rng(11)
    for trial in range(400):
        size = int(rng.integers(1, 40))
        values = rng.integers(0, 4, size).astype(float) if trial % 2 else rng.normal(size=size)
        found = np.flatnonzero(_local_maxima(values, 3))
        assert np.array_equal(found, signal.argrelmax(values, order=3)[0])


@pytest.mark.parametrize("points", [2, 3])
def test_curves_through_points_are_the_exact_fits(points: int) -> None:
    rng = np.random.default_rng(points)
    pixel = np.sort(rng.uniform(0.0, 900.0, (50, points)), axis=1)
    wavelength = np.sort(rng.uniform(400.0, 700.0, points))
    a, b, c = _curves_through(pixel, wavelength)
    for k in range(pixel.shape[0]):
        fitted = QuadraticMapping.fit(pixel[k], wavelength, degree=points - 1)
        assert (a[k], b[k], c[k]) == pytest.approx(fitted.coefficients, rel=1e-9, abs=1e-12)


def test_line_match_fits_only_the_hypotheses_it_polishes(monkeypatch: pytest.MonkeyPatch) -> None:
    """Hundreds of line/peak placements are judged without a least-squares fit each (before:
    one per placement); the right one still leads."""
    line_nm = np.array([404.66, 435.83, 487.7, 546.07, 576.96, 611.6])
    truth = QuadraticMapping(2e-5, 0.3, 390.0)
    peak_px = truth.pixel_at(line_nm)
    lines = [Peak(float(nm), 1.0, 1.0 - 0.1 * k) for k, nm in enumerate(line_nm)]
    peaks = [Peak(float(px), 1.0, 1.0 - 0.05 * k) for k, px in enumerate(peak_px)]
    peaks += [Peak(float(px), 0.2, 0.2) for px in (120.0, 333.0, 640.0)]
    fits = {"count": 0}
    fit = QuadraticMapping.fit

    def counted(*args: Any, **kwargs: Any) -> QuadraticMapping:
        fits["count"] += 1
        return fit(*args, **kwargs)

    monkeypatch.setattr(QuadraticMapping, "fit", counted)
    found = match_peak_hypotheses(
        lines, peaks, pixel_range=(0.0, 900.0), dispersion_range_nm_per_px=(0.15, 0.6)
    )
    # ~11 000 placements (pairs and triples of the 6 lines through ordered peaks) are judged;
    # only the candidates polished (three refits each, until 6 distinct ones) are fitted.
    assert fits["count"] < 1000
    probe = np.linspace(0.0, 900.0, 9)
    assert np.max(np.abs(found[0].wavelength_nm(probe) - truth.wavelength_nm(probe))) < 0.01
