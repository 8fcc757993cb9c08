"""Decision 0128: the camera prior's pull on a broadband-only mapping holds the coarser view's
disagreement with the answer beside the fit's excess misfit, and the offline bench re-states σ
the way the search does."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from calib.wavelength.profile_search import (
    PRIOR_MISFIT_COHERENCE,
    VIEW_DISAGREEMENT_SCALE,
    prior_misfit_sigma_nm,
)
from tests.benches import load_bench


def test_the_views_disagreement_widens_the_pull_as_its_square_root():
    """Nothing where the fit describes its noise and both views agree; √Δχ² of the curvature σ
    (× the scale) where the coarser view puts the answer Δχ² behind its best basin; the two parts
    in quadrature; a view that rates the answer best (Δχ² ≤ 0) or none adds nothing."""
    local = 0.05
    assert prior_misfit_sigma_nm(1.0, local, 0.0) == 0.0
    assert prior_misfit_sigma_nm(1.0, local, 4.0) == pytest.approx(
        2.0 * VIEW_DISAGREEMENT_SCALE * local
    )
    assert prior_misfit_sigma_nm(1.0, local, 16.0) == pytest.approx(
        2.0 * prior_misfit_sigma_nm(1.0, local, 4.0)
    )
    both = prior_misfit_sigma_nm(5.0, local, 9.0)
    assert both == pytest.approx(
        math.hypot(prior_misfit_sigma_nm(5.0, local), prior_misfit_sigma_nm(1.0, local, 9.0))
    )
    assert prior_misfit_sigma_nm(5.0, local) == pytest.approx(2.0 * PRIOR_MISFIT_COHERENCE * local)
    assert prior_misfit_sigma_nm(5.0, local, -3.0) == prior_misfit_sigma_nm(5.0, local)
    assert prior_misfit_sigma_nm(5.0, local, math.nan) == prior_misfit_sigma_nm(5.0, local)


def _row(temper: float, view: float, ambiguous: bool = False) -> dict[str, str]:
    """A stored ``led`` row with a flat σ of 0.3 nm made of its parts (no basins, no floor)."""
    local, scale = 0.05, 0.1
    misfit = prior_misfit_sigma_nm(temper, local, view)
    stated = math.sqrt((2.0 * local) ** 2 + scale**2 + misfit**2)
    errors = np.full(32, 0.5 * stated)
    return {
        "errors_nm": json.dumps(errors.tolist()),
        "sigmas_nm": json.dumps(np.full(32, stated).tolist()),
        "local_rms_nm": str(local),
        "prior_misfit_sigma_nm": str(misfit),
        "temper": str(temper),
        "coarse_delta_chi2": str(view),
        "spectrometer_scale_sigma_nm": str(scale),
        "basins": "[]",
        "basin_spread_nm": "0",
        "stated_nm": str(stated),
        "ratio": "0.5",
        "ambiguous": str(ambiguous),
        "calibrated_ratios": json.dumps([0.8] * 8),
    }


def test_the_offline_bench_restates_the_pull_as_the_search_states_it():
    """Re-stated with the search's own constants, a row's σ is unchanged; without the view term it
    narrows by exactly that term."""
    offline = load_bench("mapping_sigma_offline.py")
    row = _row(temper=3.0, view=12.0)
    stored = np.array(json.loads(row["sigmas_nm"]))
    _errors, same, ratio = offline.restated(
        row, 0.1, 2.0, 3.0, 1.0, coherence=PRIOR_MISFIT_COHERENCE, view=VIEW_DISAGREEMENT_SCALE
    )
    np.testing.assert_allclose(same, stored, rtol=1e-9)
    assert ratio == pytest.approx(0.5)
    _errors, without, _ratio = offline.restated(
        row, 0.1, 2.0, 3.0, 1.0, coherence=PRIOR_MISFIT_COHERENCE, view=0.0
    )
    expected = math.sqrt(stored[0] ** 2 - prior_misfit_sigma_nm(1.0, 0.05, 12.0) ** 2)
    np.testing.assert_allclose(without, expected, rtol=1e-9)


def test_the_spread_of_the_ratios_says_how_well_sigma_tells_the_scenes_apart():
    """1 when σ follows each scene's error exactly; the 10–90 % factor otherwise; a calibrated σ's
    spread from the rows' own draws."""
    offline = load_bench("mapping_sigma_offline.py")
    assert offline.spread([0.5] * 20) == pytest.approx(1.0)
    ratios = list(np.geomspace(0.1, 1.0, 101))
    assert offline.spread(ratios) == pytest.approx(10.0**0.8, rel=1e-6)
    rows = [_row(2.0, 0.0) for _ in range(10)]
    assert offline.calibrated_spread(rows) == pytest.approx(1.0)
