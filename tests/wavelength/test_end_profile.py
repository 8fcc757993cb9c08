"""Decision 0155: a broadband-only quadratic mapping's ends are stated as the final stage's own
likelihood holds them (its rise at ±4 of each end's curvature σ), not as the parabola the curvature
assumes; an end the likelihood does not hold within that step is warned about."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.wavelength.profile_search import (
    END_PROFILE_STEP,
    END_PROFILE_WARN_DELTA_CHI2,
    end_profile,
)

X = np.array([400.0, 550.0, 700.0])
#: The curvature's covariance (nm²): the ends 0.5 nm, correlated with the middle.
COVARIANCE = np.array([[0.25, 0.05, 0.02], [0.05, 0.04, 0.03], [0.02, 0.03, 0.16]])


class _Valley:  # a stage's costs: a Gaussian valley of covariance ``true`` (in Birge units)
    def __init__(self, true: np.ndarray, scale: float = 1.0) -> None:
        self.precision = np.linalg.inv(true)
        self.scale = scale

    def costs(self, x: np.ndarray) -> np.ndarray:
        d = np.atleast_2d(x) - X
        return np.asarray(1000.0 + self.scale * np.einsum("ij,jk,ik->i", d, self.precision, d))


def test_a_valley_the_curvature_states_is_left_as_it_is():
    widened, ends = end_profile(_Valley(COVARIANCE, 0.9), X, COVARIANCE, 0.9)  # type: ignore[arg-type]
    assert widened == pytest.approx(COVARIANCE)
    assert [e.index for e in ends] == [0, 2]
    assert [e.delta_chi2 for e in ends] == pytest.approx([END_PROFILE_STEP**2] * 2)
    assert [e.factor for e in ends] == pytest.approx([1.0, 1.0])
    assert ends[0].sigma_nm == pytest.approx(0.5)


def test_an_end_the_likelihood_holds_three_times_more_loosely_is_stated_three_times_wider():
    # The truth's valley: the blue end's variance along the covariance's own direction 9 × wider.
    direction = COVARIANCE[:, 0] / 0.5
    true = COVARIANCE + 8.0 * np.outer(direction, direction)
    widened, ends = end_profile(_Valley(true), X, COVARIANCE, 1.0)  # type: ignore[arg-type]
    assert ends[0].factor == pytest.approx(3.0)
    assert widened[0, 0] == pytest.approx(9.0 * COVARIANCE[0, 0], rel=1e-3)
    assert widened == pytest.approx(true, rel=0.2)
    # The red end's rise is that of the wider valley along its own direction: still a parabola,
    # slightly flatter through the correlation, so it is widened a little, not more.
    assert 1.0 <= ends[1].factor < 1.3


def test_an_end_the_likelihood_does_not_hold_is_stated_at_the_step():
    class _Flat(_Valley):
        def costs(self, x: np.ndarray) -> np.ndarray:  # the blue end costs nothing to move
            d = np.atleast_2d(x) - X
            return np.asarray(1000.0 + d[:, 2] ** 2 / 0.16 - 0.5 * np.abs(d[:, 0]))

    _, ends = end_profile(_Flat(COVARIANCE), X, COVARIANCE, 1.0)  # type: ignore[arg-type]
    assert ends[0].delta_chi2 < END_PROFILE_WARN_DELTA_CHI2
    assert ends[0].factor == pytest.approx(END_PROFILE_STEP)


@pytest.mark.slow
@pytest.mark.shared_data
def test_the_canon_40d_paper_scene_under_led_bh1_is_warned(shared_camera_data: Path) -> None:
    """The validation split's paper scene (LED-BH1, seed 0, 1 % noise) of the Canon 40D (Mauer):
    on base 54ab899 its LED-only mapping was 4.4 nm off at the blue end, σ 0.84 nm there, unwarned;
    the final stage's cost does not rise when the blue end moves by four of its σ."""
    from calib.core.spectra import DEFAULT_GRID
    from calib.wavelength.profile_search import search_profiles

    from .paper_scene import paper_scene

    led, prior, truth = paper_scene(
        shared_camera_data, "Canon 40D (Mauer-2009)", "LED-BH1", 0, 0.01
    )
    found = search_profiles([led], prior, DEFAULT_GRID)
    assert found.ambiguous
    assert any("blue end is not held" in w for w in found.warnings)
    blue = float(np.min(led.pixel[truth.wavelength_nm(led.pixel) >= DEFAULT_GRID.start_nm]))
    error = abs(float(found.mapping.wavelength_nm(blue) - truth.wavelength_nm(blue)))
    sigma = found.mapping.sigma_nm(np.array([blue]))
    assert sigma is not None
    assert error < 3.0 * float(sigma[0])
