"""The estimators' linear algebra runs on one BLAS thread.

The solves here are small (tens to a few hundred unknowns) and many: the mapping search alone makes
hundreds of batched solves per camera. A multi-threaded BLAS gains nothing on such sizes, and when the
machine is busy its spinning threads lose badly: measured on 2 cores with a load average of 6, one
``makabe2025`` estimate took 12.3 s with OpenBLAS' default two threads and 0.9 s with one. So every
public entry point that solves runs under :func:`one_blas_thread` (threadpoolctl; about 0.4 ms to
enter), whatever the caller's process-wide setting; element-wise numpy work (RAW decoding, the HDR
merge) does not use BLAS and is unaffected.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with every loaded BLAS library limited to one thread (restored after)."""

    @functools.wraps(function)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return limited
