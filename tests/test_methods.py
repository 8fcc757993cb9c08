"""The front function calib.methods.estimate: the registry, option routing, and the auto choice."""

from __future__ import annotations

import inspect
import json
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

import calib.methods
from calib.core.errors import InputError
from calib.core.mapping import QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, Spectrum, WavelengthGrid
from calib.methods import (
    ESTIMATION_METHODS,
    MultilampOptions,
    PriorOptions,
    choose_method,
    method_names,
)
from calib.model.bases import CameraBasis, camera_basis


def _lamp(name: str, *, direct: bool = True) -> LampObservation:
    pixel = np.arange(16.0)
    return LampObservation(
        name=name,
        spectrum=Spectrum(np.array([380.0, 780.0]), np.ones(2)),
        pixel=pixel,
        profile=np.ones((16, 3)),
        direct_rgb=np.ones(3) if direct else None,
    )


def _fake_result(grid: WavelengthGrid, method: str = "fake") -> EstimateResult:
    return EstimateResult(method, grid.wavelength_nm, np.ones((grid.size, 3)))


def test_front_function_routes_the_options_a_method_declares(monkeypatch):
    calls: dict[str, Any] = {}

    def fake(observations, *, grid, answer: int = 0):
        calls["answer"] = answer
        return _fake_result(grid)

    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    result = calib.methods.estimate([], method="FAKE", answer=42)
    assert result.method == "fake" and calls == {"answer": 42}
    assert result.to_dict()["sensitivity"]["R"][0] == 1.0
    assert "method_choice" not in result.diagnostics  # only auto records a choice


def test_an_option_the_method_does_not_declare_is_refused_by_name(monkeypatch):
    def fake(observations, *, grid, answer: int = 0):
        raise AssertionError("must not run")

    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    with pytest.raises(InputError, match=r"method 'fake' takes no option 'weight_rule'") as error:
        calib.methods.estimate([], method="fake", weight_rule="upre")
    assert error.value.source == "weight_rule"
    assert "it takes grid, answer" in str(error.value)


def test_filtering_is_asked_for_explicitly(monkeypatch):
    seen: dict[str, Any] = {}

    def fake(observations, *, grid, answer: int = 0):
        seen["answer"] = answer
        return _fake_result(grid)

    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    calib.methods.estimate([], method="fake", filter_options=True, answer=1, weight_rule="x")
    assert seen == {"answer": 1}


def test_a_real_method_refuses_another_method_s_option():
    with pytest.raises(InputError, match="'jiang2013' takes no option 'mapping'"):
        calib.methods.estimate([], method="jiang2013", basis=_tiny_basis(), mapping=None)
    with pytest.raises(InputError, match="'prior' takes no option 'weight_rule'"):
        calib.methods.estimate([_lamp("LED")], method="prior", weight_rule="upre")


def test_options_of_another_method_s_type_are_refused(monkeypatch):
    def fake(observations, *, grid, options: PriorOptions = PriorOptions()):
        raise AssertionError("must not run")

    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    with pytest.raises(InputError, match="takes PriorOptions, got MultilampOptions"):
        calib.methods.estimate([], method="fake", options=MultilampOptions())


def test_a_missing_required_input_is_named(monkeypatch):
    def fake(observations, *, grid, grating):
        raise AssertionError("must not run")

    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    with pytest.raises(InputError, match="method 'fake' needs grating="):
        calib.methods.estimate([], method="fake")


def test_the_basis_is_resolved_once_for_a_method_that_needs_one(monkeypatch):
    resolved: list[WavelengthGrid] = []
    basis = _tiny_basis()

    def default_basis(grid, *, data_dir=None):
        resolved.append(grid)
        return basis

    def fake(observations, *, grid, basis):
        return _fake_result(grid, basis.source)

    monkeypatch.setattr(calib.methods, "default_camera_basis", default_basis)
    monkeypatch.setitem(ESTIMATION_METHODS, "fake", fake)
    assert calib.methods.estimate([], method="fake").method == basis.source
    assert resolved == [DEFAULT_GRID]
    monkeypatch.setitem(ESTIMATION_METHODS, "free", lambda observations, *, grid: None)
    with pytest.raises(InputError, match="'free' takes no camera basis"):
        calib.methods.estimate([], method="free", basis=basis)


def test_unknown_method_lists_the_known_ones():
    with pytest.raises(InputError, match="auto, prior, makabe2025"):
        calib.methods.estimate([], method="nope")


def test_every_registered_method_declares_what_it_takes():
    """No **kwargs anywhere: the front function can route by the signature alone."""
    names = method_names()
    assert names[0] == "auto" and set(names[1:]) == set(ESTIMATION_METHODS)
    for name, function in ESTIMATION_METHODS.items():
        parameters = list(inspect.signature(function).parameters.values())
        assert parameters[0].kind is inspect.Parameter.POSITIONAL_OR_KEYWORD, name
        assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in parameters[1:]), name
        assert "grid" in [p.name for p in parameters], name
        options = inspect.signature(function).parameters.get("options")
        if options is not None:  # typed options: a frozen instance as the default
            with pytest.raises(AttributeError):
                options.default.__setattr__("x", 1)


@pytest.mark.parametrize(
    ("lamps", "expected"),
    [
        ([_lamp("A"), _lamp("B"), _lamp("C")], "multilamp"),
        ([_lamp("A"), _lamp("B"), _lamp("C", direct=False)], "prior"),
        ([_lamp("A")], "prior"),
        ([_lamp("A"), _lamp("B"), _lamp("C"), _lamp("FL", direct=False)], "multilamp"),
    ],
)
def test_auto_chooses_multilamp_from_three_directly_measured_lamps(lamps, expected):
    choice = choose_method(lamps)
    assert choice.method == expected
    assert choice.to_dict()["requested"] == "auto" and choice.reason


def test_auto_refuses_what_it_cannot_choose_for():
    with pytest.raises(InputError, match="no lamp has a direct"):
        choose_method([_lamp("A", direct=False)])
    with pytest.raises(InputError, match="name the method"):
        choose_method([])


def test_auto_records_what_it_chose_and_why(monkeypatch):
    def fake_prior(observations, *, grid, basis):
        return _fake_result(grid, "prior")

    monkeypatch.setitem(ESTIMATION_METHODS, "prior", fake_prior)
    result = calib.methods.estimate([_lamp("LED")], basis=_tiny_basis())
    assert result.diagnostics["method_choice"] == {
        "requested": "auto",
        "method": "prior",
        "reason": "1 lamp(s) with a direct measurement (LED); multilamp needs at least 3",
        "mapping_only": [],
    }
    json.dumps(result.to_dict())  # recorded in result.json


def test_the_mapping_stage_s_warnings_reach_the_quality_block_through_the_python_api(monkeypatch):
    """A caller of calib.methods.estimate (not only the command lines) sees what the mapping
    stage warned of, by its code."""
    warned = QuadraticMapping(0.0, 0.4, 380.0).with_details(
        details={
            "warnings": ["two basins 6 nm apart fit almost as well"],
            "warning_codes": ["mapping_ambiguous"],
        }
    )

    def fake_prior(observations, *, grid, basis, mapping=None):
        return replace(_fake_result(grid, "prior"), mapping=mapping)

    monkeypatch.setitem(ESTIMATION_METHODS, "prior", fake_prior)
    result = calib.methods.estimate(
        [_lamp("LED")], method="prior", basis=_tiny_basis(), mapping=warned, budget=None
    )
    flags = {flag.code: flag.message for flag in result.quality.flags}
    assert flags["mapping_ambiguous"] == "two basins 6 nm apart fit almost as well"
    assert result.quality.verdict != "ok"
    plain = calib.methods.estimate(
        [_lamp("LED")], method="prior", basis=_tiny_basis(), mapping=QuadraticMapping(0, 0.4, 380)
    )
    assert "mapping_ambiguous" not in {flag.code for flag in plain.quality.flags}


def test_an_unresolved_grating_family_reaches_the_quality_block_for_every_method(monkeypatch):
    """The grating model's record (the prior solve's as multilamp's) gives its warning through
    calib.methods.estimate; a separated choice gives none (decision 0063)."""
    near_tie = {"chosen": "sinusoidal", "choice_weights": {"sinusoidal": 0.7, "blazed": 0.3}}
    separated = {"chosen": "sinusoidal", "choice_weights": {"sinusoidal": 0.99, "blazed": 0.01}}
    for record, expected in ((near_tie, True), (separated, False)):

        def fake_prior(observations, *, grid, basis, mapping=None, record=record):
            fake = _fake_result(grid, "prior")
            return replace(fake, diagnostics={**fake.diagnostics, "grating_model": record})

        monkeypatch.setitem(ESTIMATION_METHODS, "prior", fake_prior)
        result = calib.methods.estimate(
            [_lamp("LED")], method="prior", basis=_tiny_basis(), budget=None
        )
        codes = {flag.code for flag in result.quality.flags}
        assert ("grating_family_unresolved" in codes) is expected, codes


def test_result_to_dict_is_json_safe():
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

    def ringing(observations, *, grid):
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


def _tiny_basis() -> CameraBasis:
    rng = np.random.default_rng(0)
    return camera_basis(
        rng.uniform(0.1, 1.0, (4, DEFAULT_GRID.size, 3)), n_vectors=2, source="tiny", cache=False
    )
