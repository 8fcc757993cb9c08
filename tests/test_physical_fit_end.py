"""A physical fit whose scan's best is the scan's end (decision 0125)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

import calib.methods.grating_models as grating_models
from calib.core.spectra import DEFAULT_GRID
from calib.methods.grating_models import REFINE_XATOL, fit_physical, physical_equations
from calib.methods.multilamp import prepare_lamps
from calib.methods.responses import LampData
from calib.model.bases import CameraBasis
from calib.model.gratings import PHYSICAL_PARAMETER_RANGES, PhysicalKind, SinusoidalPhaseGrating
from tests.synthetic_cameras import exact_basis
from tests.test_grating_models import MAPPING, _order, _scene


@pytest.fixture(scope="module")
def basis(tmp_path_factory: pytest.TempPathFactory) -> CameraBasis:
    return exact_basis(tmp_path_factory.mktemp("basis"))[0]


def test_a_fit_that_ends_on_its_ranges_bound_answers_the_bound_without_crawling_to_it(
    basis: CameraBasis, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sinusoidal grating seen through the blazed family: the blaze wants to be below its
    range, the scan's best is the range's low end, and the misfit rises from there. The fit
    answers the end itself (what the bounded refinement, which never evaluates its bound, lost
    to) after one look just inside it per pass, where the refinement took 29 evaluations."""
    grating = SinusoidalPhaseGrating(0.75)
    _, observations = _scene(
        _order(grating, 1), _order(grating, 0), lamps=("A",), seed=2, noise=0.01, direct_noise=0.004
    )
    lamps = prepare_lamps(observations, basis=basis, mapping=MAPPING).lamps
    wavelength = DEFAULT_GRID.wavelength_nm
    low, _ = PHYSICAL_PARAMETER_RANGES["blazed"]
    evaluated: list[float] = []

    def counted(
        lamps: Sequence[LampData], kind: PhysicalKind, parameter: float, *args: Any, **kw: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        evaluated.append(parameter)
        return physical_equations(lamps, kind, parameter, *args, **kw)

    monkeypatch.setattr(grating_models, "physical_equations", counted)
    fit = fit_physical(lamps, "blazed", wavelength, gain_sigma=0.02)
    assert fit.scan is not None
    _, chi2 = fit.scan
    assert int(np.argmin(chi2)) == 0  # the scan's best is the range's end
    assert fit.parameter == low
    # Per pass the look inside and the end's own equations; then the final equations and the
    # derivative's two.
    assert len(evaluated) <= 2 * grating_models.FIT_PASSES + 3
    assert low + REFINE_XATOL in evaluated
