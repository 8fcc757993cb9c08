import numpy as np
import pytest

import calib.methods
from calib.core.errors import InputError
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID
from calib.methods import ESTIMATION_METHODS, register_method


def test_front_function_dispatches_through_the_registry(monkeypatch):
    calls = {}

    def fake(observations, *, grid, basis, mapping, mapping_lamp, **options):
        calls.update(options)
        return EstimateResult("fake", grid.wavelength_nm, np.ones((grid.size, 3)))

    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    result = calib.methods.estimate([], method="FAKE", answer=42)
    assert result.method == "fake" and calls == {"answer": 42}
    assert result.to_dict()["sensitivity"]["R"][0] == 1.0


def test_unknown_method_lists_the_known_ones():
    with pytest.raises(InputError, match="makabe2025"):
        calib.methods.estimate([], method="nope")


def test_registering_twice_needs_replace():
    def first(*args, **kwargs):
        raise AssertionError

    register_method("temporary-test-method", first)
    try:
        with pytest.raises(InputError, match="already registered"):
            register_method("temporary-test-method", lambda *a, **k: None)  # type: ignore[arg-type]
    finally:
        ESTIMATION_METHODS.pop("temporary-test-method")


def test_result_to_dict_is_json_safe():
    import json

    grid = DEFAULT_GRID

    sensitivity = np.ones((grid.size, 3))
    efficiency = np.full(grid.size, np.nan)
    result = EstimateResult(
        "x",
        grid.wavelength_nm,
        sensitivity,
        grating_efficiency=efficiency,
        diagnostics={"a": np.float64(1.5)},
    )
    text = json.dumps(result.to_dict(), allow_nan=False)
    assert '"a": 1.5' in text


def test_comparisons_score_the_curve_calib_estimate_writes(monkeypatch, tmp_path):
    """Negative ringing at a grid edge is clipped in sensitivity.csv; `calib compare`, `rig compare`
    and `calib synthetic` score that same curve, not the solver's raw one."""
    from calib.evaluation.compare import _timed_estimate
    from calib.pipeline.outputs import write_sensitivity_csv

    grid = DEFAULT_GRID
    raw = np.ones((grid.size, 3))
    raw[0] = [-0.3, 0.2, -0.1]  # ringing at the first grid wavelength
    raw[5, 1] = 2.0

    def ringing(observations, *, grid, basis, mapping, mapping_lamp, **options):
        return EstimateResult("ringing", grid.wavelength_nm, raw)

    monkeypatch.setitem(ESTIMATION_METHODS, "ringing", ringing)
    curves, _, failure = _timed_estimate([], "ringing", grid, {})
    assert failure is None and curves is not None
    path = write_sensitivity_csv(
        tmp_path / "sensitivity.csv", EstimateResult("ringing", grid.wavelength_nm, raw)
    )
    written = np.loadtxt(path, delimiter=",", skiprows=1)[:, 1:]
    np.testing.assert_allclose(curves, written, rtol=1e-9)
    assert curves.min() == 0.0 and curves.max() == 1.0
