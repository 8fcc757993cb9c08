"""Decision 0139: a coarse-view rival that the search's final stage prefers by its bar is the
answer (:func:`calib.wavelength.locate._adopted`): the mapping, its exact form, σ, candidates and
quality flags all follow it; the warning stays only while the first answer is within the search's
ambiguity bar."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from calib.core.mapping import QuadraticMapping
from calib.core.spectra import DEFAULT_GRID
from calib.wavelength import locate
from calib.wavelength.coarse_check import CoarseView
from calib.wavelength.families import QuadraticFamily
from calib.wavelength.least_squares import Solution
from calib.wavelength.profile_search import (
    AMBIGUITY_DELTA_CHI2,
    BROADBAND_AMBIGUITY_DELTA_CHI2,
    MappingSearch,
)
from calib.wavelength.quadratic_view import FinalVerdict

PIXELS = (0.0, 999.0)
FAMILY = QuadraticFamily(PIXELS)


def _run(monkeypatch: Any, final_delta: float, adopts: bool = True) -> Any:
    exact = QuadraticMapping(1e-5, 0.34, 378.0, pixel_range=PIXELS)
    mapping = exact.with_details(
        covariance=[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.04]], wavelength_rms_nm=0.2
    )
    search_details = {
        "spectrometer_scale_sigma_nm": 0.0,
        "candidates": [{"rms_distance_nm": 0.0}],
        "origin": "correlation search on LED",
        "ambiguity_delta_chi2": BROADBAND_AMBIGUITY_DELTA_CHI2,
        "final_cost": 3184.0,
    }
    search = MappingSearch(mapping, exact, (), False, (), search_details)
    rival = FAMILY.parameters(exact).copy()
    rival[-1] -= 5.4  # the red end 5.4 nm lower (the D1x scene's rival)
    rng = np.random.default_rng(0)
    jacobian = rng.normal(size=(2000, 3)) * np.array([30.0, 30.0, 30.0])
    solution = Solution(rival, np.zeros(2000), jacobian, 1900.0, 12)
    verdict = FinalVerdict(solution, 1900.0, 1900.0 + final_delta, 1.0, final_delta, adopts, 14)
    monkeypatch.setattr(
        locate, "quadratic_coarse_view", lambda *a, **k: (CoarseView(rival, 34.0, 2.2, True), 180)
    )
    monkeypatch.setattr(locate, "final_verdict", lambda *a, **k: verdict)
    details: dict[str, Any] = {**search_details, "ambiguous": False}
    warnings: list[str] = []
    led: Any = SimpleNamespace(
        pixel=np.arange(PIXELS[0], PIXELS[1] + 1.0),
        name="LED",
        kind="led",
        pixel_origin="arbitrary",
    )
    prior: Any = None  # the views are replaced: the prior is not read
    out, out_exact = locate._quadratic_coarse_check(
        search, mapping, [led], prior, DEFAULT_GRID, None, details, warnings
    )
    return out, out_exact, exact, rival, details, warnings


def test_a_rival_the_final_stage_prefers_is_the_answer_and_warned_within_the_bar(monkeypatch):
    out, out_exact, first, rival, details, warnings = _run(monkeypatch, 339.0)
    pixels = np.linspace(*PIXELS, 7)
    assert out_exact.wavelength_nm(pixels) == pytest.approx(FAMILY.wavelengths(pixels, rival))
    assert out.wavelength_nm(pixels) == pytest.approx(out_exact.wavelength_nm(pixels), abs=1e-6)
    assert details["quadratic_coarse_view"]["adopted"]
    assert details["quadratic_coarse_view"]["evaluations"] == 180 + 14
    adopted, old = details["candidates"][:2]
    assert adopted["rms_distance_nm"] == 0.0 and adopted["delta_chi2"] == 0.0
    assert old["delta_chi2"] == 339.0 and old["rms_distance_nm"] > 1.0
    assert old["mapping"] == first.to_dict()
    assert details["final_cost"] == 1900.0 and details["ambiguous"]
    assert details["profile_fit"]["c"] == pytest.approx(first.c)
    (sentence,) = warnings
    assert "full-resolution" in sentence
    # σ: the two basins within the broadband bar, so ±2σ reaches the first answer.
    assert out.wavelength_rms_nm == pytest.approx(0.5 * old["rms_distance_nm"], rel=1e-6)


def test_a_rival_beyond_the_bar_is_the_answer_without_a_warning(monkeypatch):
    out, _, _, _, details, warnings = _run(monkeypatch, BROADBAND_AMBIGUITY_DELTA_CHI2 + 100.0)
    assert details["quadratic_coarse_view"]["adopted"] and not details["ambiguous"]
    assert not warnings
    # σ from the adopted basin's own curvature (small: the second basin weighs nothing).
    assert out.wavelength_rms_nm is not None and out.wavelength_rms_nm < 0.5


def test_a_rival_the_final_stage_does_not_prefer_leaves_the_warning(monkeypatch):
    out, out_exact, first, _, details, warnings = _run(
        monkeypatch, AMBIGUITY_DELTA_CHI2 - 5.0, adopts=False
    )
    assert out_exact is first and not details["quadratic_coarse_view"]["adopted"]
    assert details["ambiguous"] and len(warnings) == 1 and "coarser profile" in warnings[0]
    assert out.wavelength_rms_nm == pytest.approx(1.1)
