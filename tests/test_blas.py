"""The estimators' entry points run their linear algebra on one BLAS thread, then restore it."""

from __future__ import annotations

import sys
import types
from typing import Any, cast

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from calib.core.blas import blas_controller, one_blas_thread, pinv_symmetric
from calib.methods import ESTIMATION_METHODS, estimate


def _blas_threads() -> list[int]:
    return [int(entry["num_threads"]) for entry in threadpool_info() if entry["user_api"] == "blas"]


def test_one_blas_thread_inside_and_the_callers_setting_after() -> None:
    np.dot(np.ones((2, 2)), np.ones((2, 2)))  # BLAS is loaded
    seen: list[list[int]] = []

    @one_blas_thread
    def solve(scale: float) -> float:
        seen.append(_blas_threads())
        return scale * float(np.linalg.solve(np.eye(3), np.ones(3)).sum())

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert solve(2.0) == 6.0
        assert _blas_threads() == before
    assert seen and all(threads == [1] * len(threads) for threads in seen)


def test_every_registered_method_runs_on_one_blas_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[list[int]] = []

    def probe(observations: object, **options: object) -> Any:
        seen.append(_blas_threads())
        return "probed"

    monkeypatch.setitem(ESTIMATION_METHODS, "probe", cast(Any, probe))
    with threadpool_limits(limits=2, user_api="blas"):
        assert cast(Any, estimate([], method="probe")) == "probed"
    assert seen and all(threads == [1] * len(threads) for threads in seen)


def test_nested_entry_points_set_the_limit_once_and_restore_it_after() -> None:
    np.dot(np.ones((2, 2)), np.ones((2, 2)))  # BLAS is loaded
    seen: list[list[int]] = []

    @one_blas_thread
    def inner() -> None:
        seen.append(_blas_threads())

    @one_blas_thread
    def outer() -> None:
        inner()
        seen.append(_blas_threads())
        inner()

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        outer()
        assert _blas_threads() == before
        outer()  # the flag was cleared: the next outermost entry limits again
        assert _blas_threads() == before
    assert len(seen) == 6 and all(threads == [1] * len(threads) for threads in seen)


def test_pinv_symmetric_is_numpys_hermitian_pinv_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    for trial in range(60):
        size = int(rng.integers(2, 33))
        rank = int(rng.integers(1, size + 1))
        factor = rng.normal(size=(size, rank)) * 10.0 ** rng.uniform(-5, 5, rank)
        matrix = factor @ factor.T
        if trial % 3 == 0:  # indefinite: the signs move into the right factor
            matrix = matrix - np.eye(size) * float(np.abs(matrix).max()) * 0.3
        assert np.array_equal(pinv_symmetric(matrix), np.linalg.pinv(matrix, hermitian=True))


def test_the_blas_listing_is_made_anew_after_an_import(monkeypatch: pytest.MonkeyPatch) -> None:
    first = blas_controller()
    assert blas_controller() is first  # nothing imported since: the same listing
    monkeypatch.setitem(sys.modules, "calib_test_new_module", types.ModuleType("new"))
    renewed = blas_controller()
    assert renewed is not first
    assert {lib.filepath for lib in renewed.lib_controllers} >= {
        lib.filepath for lib in first.lib_controllers
    }
