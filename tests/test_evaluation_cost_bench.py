"""``bench/evaluation_cost.py --against``: the recorded calls replayed with another checkout's
response model in turn with this one's, and this one's methods in place afterwards (decision 0157)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from calib.wavelength.response_model import LampColumns, ResponseModel
from tests.benches import BENCH_DIR, load_bench
from tests.led_scene import unblurred_led


def test_the_replay_against_another_checkout_runs_its_methods_and_puts_this_ones_back(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.syspath_prepend(str(BENCH_DIR))  # the bench imports its sibling wavelength_speed
    bench = load_bench("evaluation_cost.py")
    model, family, edges_px, truth = unblurred_led()
    x = family.parameters(truth)
    edges = family.wavelengths(edges_px, x)
    costs_calls = [(model, edges[None, :], True)]
    residual_calls = [(model.reference(edges), edges, family.jacobian(edges_px, x))]
    # This checkout loaded as a module of its own stands in for the other checkout.
    other = bench.methods_of(Path(__file__).resolve().parents[1])
    assert ("LampColumns", "evaluate") in other
    theirs = other[("ResponseModel", "costs")]
    assert theirs is not ResponseModel.__dict__["costs"]
    called: list[int] = []

    def counting(self: ResponseModel, *args: Any, **kwargs: Any) -> Any:
        called.append(1)
        return theirs(self, *args, **kwargs)

    other[("ResponseModel", "costs")] = counting
    # Each side makes the descent's reference band again with its own methods before it runs.
    their_band = other[("ResponseModel", "band")]
    banded: list[int] = []

    def counting_band(self: ResponseModel, *args: Any, **kwargs: Any) -> Any:
        banded.append(1)
        return their_band(self, *args, **kwargs)

    other[("ResponseModel", "band")] = counting_band
    referenced = residual_calls[0][0].referenced
    assert referenced is not None
    recorded_band = referenced[1]
    # A method only the other checkout has is there for its side and gone afterwards.
    other[("ResponseModel", "_only_theirs")] = lambda self: None
    own_costs, own_evaluate = ResponseModel.costs, LampColumns.evaluate
    bench.compare("scene", costs_calls, residual_calls, other, 2)
    assert len(called) == 3  # a warm-up round and two timed rounds, one batch each
    assert len(banded) == 3  # the other side's reference band, once a round
    # Afterwards the reference band is this checkout's again: a new one, the same numbers.
    referenced = residual_calls[0][0].referenced
    assert referenced is not None
    remade = referenced[1]
    assert remade is not recorded_band
    assert (remade.values == recorded_band.values).all()
    assert ResponseModel.costs is own_costs
    assert LampColumns.evaluate is own_evaluate
    assert not hasattr(ResponseModel, "_only_theirs")
    printed = capsys.readouterr().out
    assert printed.startswith("scene") and "other → this checkout" in printed
    assert "costs" in printed and "jacobian" in printed
