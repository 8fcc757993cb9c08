"""Decision 0158: a broadband-only mapping whose stated ±2σ exceeds the issue's 3 nm somewhere on
the working grid warns (``mapping_imprecise``, decision 0166), naming the end; what the profile reaches beyond
the grid is not read."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from calib.core.datasets import RAWTOACES_DATA, colour_science_cameras, find_camera, load_collection
from calib.core.mapping import QuadraticMapping
from calib.core.result import MAPPING_FAILURE_NM, mapping_flags, mapping_warned
from calib.core.spectra import DEFAULT_GRID
from calib.model.bases import camera_basis
from calib.wavelength import locate
from calib.wavelength.locate import _imprecise_end, _imprecise_warning
from tests.test_mapping_search import _render as render

#: A profile of 800 pixels mapped to 350–749.5 nm: the grid (400–700 nm) is pixels 100–700.
LEAD = SimpleNamespace(pixel=np.arange(800.0), name="LED-BH1", kind="led", pixel_origin="arbitrary")


def _mapping(sigma_a: float = 0.0, sigma_c: float = 0.0) -> QuadraticMapping:
    """λ = 350 + 0.5 p, the stated σ from the curvature's σ (growing as p²) and the offset's."""
    covariance = ((sigma_a**2, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, sigma_c**2))
    return QuadraticMapping(0.0, 0.5, 350.0, pixel_range=(0.0, 799.0), covariance=covariance)


def test_a_uniform_sigma_warns_only_above_the_bar():
    below = _mapping(sigma_c=0.49 * MAPPING_FAILURE_NM)
    above = _mapping(sigma_c=0.51 * MAPPING_FAILURE_NM)
    assert _imprecise_end(below, LEAD, DEFAULT_GRID) is None  # type: ignore[arg-type]
    found = _imprecise_end(above, LEAD, DEFAULT_GRID)  # type: ignore[arg-type]
    assert found is not None
    assert found["sigma_nm"] == pytest.approx(0.51 * MAPPING_FAILURE_NM)


def test_the_widest_point_on_the_grid_is_named_and_beyond_the_grid_is_not_read():
    # σ = σ_a p²: 1.4 nm at pixel 700 (700 nm, the grid's red end), 1.82 nm at the last pixel
    # (749.5 nm, off the grid).
    sigma_a = 1.4 / 700.0**2
    assert _imprecise_end(_mapping(sigma_a), LEAD, DEFAULT_GRID) is None  # type: ignore[arg-type]
    sigma_a = 1.7 / 700.0**2
    found = _imprecise_end(_mapping(sigma_a), LEAD, DEFAULT_GRID)  # type: ignore[arg-type]
    assert found is not None
    assert found["wavelength_nm"] == pytest.approx(700.0, abs=2.0)
    assert found["sigma_nm"] == pytest.approx(1.7, abs=0.02)
    text = _imprecise_warning(found, [LEAD], DEFAULT_GRID)  # type: ignore[list-item]
    assert "imprecise at its red end" in text
    assert "A fluorescent (line) lamp" in text


def test_no_covariance_states_nothing():
    bare = QuadraticMapping(0.0, 0.5, 350.0, pixel_range=(0.0, 799.0))
    assert _imprecise_end(bare, LEAD, DEFAULT_GRID) is None  # type: ignore[arg-type]


def test_an_imprecise_end_has_its_own_quality_code(monkeypatch, tmp_path):
    """The imprecise-end warning (decision 0158) is coded ``mapping_imprecise``, not as competing
    basins (decision 0166); both count as the mapping's warning that it may be off by 3 nm."""
    camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    observation = render("LED-B3", camera)
    # The bundled cameras (an empty data directory) without the 5D Mk II: one basin here.
    kept = [r.sensitivity for r in load_collection(RAWTOACES_DATA, tmp_path) if "5D" not in r.name]
    prior = camera_basis(kept, cache=False).prior()
    assert (
        locate.locate_mapping([observation], prior, DEFAULT_GRID).details["imprecise_end"] is None
    )
    finding = {"wavelength_nm": 690.0, "sigma_nm": 2.4, "pixel": 900.0}
    monkeypatch.setattr(locate, "_imprecise_end", lambda *args: finding)
    solution = locate.locate_mapping([observation], prior, DEFAULT_GRID)
    assert solution.details["imprecise_end"] == finding
    sentence = next(text for text in solution.warnings if "imprecise at its red end" in text)
    codes = solution.details["warning_codes"]
    assert len(codes) == len(solution.warnings)
    assert codes[list(solution.warnings).index(sentence)] == "mapping_imprecise"
    assert "mapping_ambiguous" not in codes
    flags = mapping_flags(solution.mapping)
    assert [flag.code for flag in flags if flag.message == sentence] == ["mapping_imprecise"]
    assert mapping_warned(codes) and mapping_warned(" ".join(codes))
    assert not mapping_warned(["mapping_extrapolated", "mapping_line_residuals"])
