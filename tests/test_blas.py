"""The estimators' entry points run their linear algebra on one BLAS thread, then restore it."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from calib.blas import one_blas_thread
from calib.makabe2025 import estimate_makabe2025
from calib.mapping_search import find_mapping
from calib.methods import estimate


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


def test_the_public_estimators_are_limited() -> None:
    for function in (estimate, estimate_makabe2025, find_mapping):
        assert getattr(function, "__wrapped__", None) is not None, function.__name__
